"""A keyframe as a person sees it: the seven camera images in one picture and its QA pairs.

``v2xbench qa show DATA --out keyframe.png`` picks a keyframe (``--keyframe <episode>_t<tick>``,
or the most informative one: with spatial-alignment questions, critical objects and an active
RSU), writes a mosaic of its images (ego cameras in their mounting layout, the roadside camera
below) and prints its QA pairs as Markdown.
"""

from __future__ import annotations

from pathlib import Path

from .export import CAMERA_LABELS

LAYOUT = (("cam_front_left", "cam_front", "cam_front_right"),
          ("cam_back_left", "cam_back", "cam_back_right"))


def pick_keyframe(items: list[dict]) -> str:
    """The keyframe with the most alignment / critical-object content (ties: the earliest)."""
    score: dict[str, tuple] = {}
    for it in items:
        k = it["keyframe"]
        a, c, r = score.get(k, (0, 0, 0))
        a += it["type"] == "rsu_to_ego"
        c += it["type"] == "critical_objects" and bool(it["label"]["objects"])
        r = r or ("no roadside unit" not in it.get("hints", it["context"]))
        score[k] = (a, c, r)
    if not score:
        raise ValueError("no QA items")
    return max(score, key=lambda k: (min(score[k][0], 2), score[k][1], score[k][2]))


def keyframe_mosaic(root: str | Path, images: list[str], scale: int = 3):
    """``PIL.Image``: the 6 ego cameras (2 x 3, as mounted) and the roadside camera, labelled."""
    from PIL import Image, ImageDraw

    root = Path(root)
    by_cam = {}
    for p in images:
        cam = next(c for c in CAMERA_LABELS if p.endswith(f"_{c}.png"))
        by_cam[cam] = Image.open(root / p).convert("RGB")
    w, h = next(iter(by_cam.values())).size
    w, h = w * scale, h * scale
    pad, label = 4, 14
    cell_h = h + label
    out = Image.new("RGB", (3 * w + 4 * pad, 3 * cell_h + 4 * pad), (24, 24, 28))
    draw = ImageDraw.Draw(out)
    cells = [(cam, pad + c * (w + pad), pad + r * (cell_h + pad)) for r, row in enumerate(LAYOUT)
             for c, cam in enumerate(row)]
    cells.append(("rsu_cam", pad + (w + pad), pad + 2 * (cell_h + pad)))
    for cam, x, y in cells:
        if cam in by_cam:
            out.paste(by_cam[cam].resize((w, h), Image.NEAREST), (x, y + label))
        draw.text((x + 2, y + 1), CAMERA_LABELS[cam], fill=(235, 235, 235))
    return out


def keyframe_markdown(items: list[dict]) -> str:
    """The keyframe's context and QA pairs as Markdown."""
    first = items[0]
    lines = [f"**Keyframe `{first['keyframe']}`** (route `{first['route_id']}`, {first['town']}, "
             f"scenarios: {', '.join(first['scenarios']) or 'none'})", "", "Prompt context:", "", "```",
             first["context"], "```", ""]
    if "hints" in first:
        lines += ["Hints (ground truth, an annotation that is not in the prompt):", "", "```",
                  first["hints"], "```", ""]
    lines += ["| level | type | question | answer |", "|---|---|---|---|"]
    for it in items:
        q = it["question"].replace("|", "\\|")
        a = it["answer"].replace("|", "\\|")
        lines.append(f"| {it['level']} | {it['type']} | {q} | {a} |")
    return "\n".join(lines)


def show(root: str | Path, out: str | Path, keyframe: str | None = None, scale: int = 3) -> str:
    """Write the mosaic of a keyframe to ``out`` and return its Markdown (module docstring)."""
    from .export import load_items

    items = load_items(root)
    kid = keyframe or pick_keyframe(items)
    mine = [it for it in items if it["keyframe"] == kid]
    if not mine:
        raise ValueError(f"no keyframe {kid!r} in {root}")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    keyframe_mosaic(root, mine[0]["images"], scale).save(out)
    return keyframe_markdown(mine)


__all__ = ["keyframe_markdown", "keyframe_mosaic", "pick_keyframe", "show"]
