"""Exported AURORA weights: what inference needs of a trained stage, checked by SHA-256.

``v2xbench aurora export --run RUN --stage 5 --out agents/aurora/weights/aurora`` writes::

    OUT/weights.safetensors   every tensor of the stage's system (ego and roadside branches,
                              CQAF + fused heads, base LM + LoRA + bridge, planner); floating
                              tensors stored as ``dtype`` (float16 by default: half the size;
                              a tensor float16 cannot hold stays float32), loaded back as float32
    OUT/lm/                   the base LM's config.json and tokenizer files (no weights: the
                              LM's weights are in weights.safetensors)
    OUT/aurora.json           the stage's run file (model config, fusion, camera size, data, ...)
    OUT/manifest.json         every file above with its SHA-256 and size, the source run and
                              stage, the export command, the git commit, the date (UTC)

Of a run's stage folder (checkpoint, optimizer state, logs, plots, adapter copy, the base LM's
own weight file) the export keeps only the model's tensors, once. Loading
(:func:`load_export`) first checks every file of the manifest (a missing file or another
SHA-256 is an error naming the file), then builds the model from ``lm/config.json`` and
``aurora.json`` and loads the weights (strict). The registered agents ``aurora`` and
``no_fusion`` load :data:`SHIPPED` ``/ aurora`` and ``/ no_fusion`` when no run is given.
"""

from __future__ import annotations

import datetime
import json
import shutil
import subprocess
import sys
from pathlib import Path

import torch
from v2xbench.collectors.agent_fingerprint import sha256_file

from v2xbench.files import atomic_write_bytes, atomic_write_json

FORMAT = "v2xbench-aurora-export/1"
MANIFEST = "manifest.json"
WEIGHTS = "weights.safetensors"
LM_DIR = "lm"
RUN_FILE = "aurora.json"
#: Files of a Hugging Face folder that describe the LM without its weights.
LM_FILES = ("config.json", "tokenizer.json", "tokenizer_config.json", "special_tokens_map.json")
#: Where the repository's shipped weights live (``aurora``, ``no_fusion``).
SHIPPED = Path(__file__).resolve().parent / "weights"
DTYPES = {"float16": torch.float16, "bfloat16": torch.bfloat16, "float32": torch.float32}
_F16_MAX = 65504.0


def _git(*args: str) -> str | None:
    try:
        r = subprocess.run(["git", "-C", str(Path(__file__).resolve().parent), *args],
                           capture_output=True, text=True, timeout=20, check=True)
    except (OSError, subprocess.SubprocessError):
        return None
    return r.stdout.strip()


def _stored(t: torch.Tensor, dtype: torch.dtype) -> torch.Tensor:
    """``t`` as stored: floating tensors in ``dtype`` unless it would overflow (kept float32)."""
    t = t.detach().cpu().contiguous()
    if not t.is_floating_point() or dtype == torch.float32:
        return t.clone()
    if dtype == torch.float16 and t.numel() and float(t.abs().max()) > _F16_MAX:
        return t.float().clone()
    return t.to(dtype)


def export_run(run: str | Path, stage: int | None, out: str | Path, *,
               dtype: str = "float16", command: str | None = None) -> dict:
    """Export stage ``stage`` (default: the run's latest of 3-5) of ``run`` into ``out``
    (module docstring; ``out`` is replaced atomically). Returns the manifest.

    Raises:
        FileNotFoundError: no such run or stage. ValueError: unknown ``dtype``.
    """
    from safetensors.torch import save

    from .system import load_system

    if dtype not in DTYPES:
        raise ValueError(f"aurora export: dtype {dtype!r}; known: {', '.join(DTYPES)}")
    system, _, info = load_system(run, stage)
    out = check_export_target(out, run, "aurora export")
    tmp = out.with_name(out.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    (tmp / LM_DIR).mkdir(parents=True)
    tensors, kept32 = {}, []
    for k, v in system.state_dict().items():
        tensors[k] = _stored(v, DTYPES[dtype])
        if v.is_floating_point() and tensors[k].dtype == torch.float32 and dtype != "float32":
            kept32.append(k)
    atomic_write_bytes(tmp / WEIGHTS, save(tensors, metadata={"format": FORMAT}))
    lm_dir = Path(info["lm_dir"])
    for name in LM_FILES:
        if (lm_dir / name).is_file():
            shutil.copyfile(lm_dir / name, tmp / LM_DIR / name)
    run_info = {k: v for k, v in info.items() if k not in ("checkpoint", "lm_dir")}
    atomic_write_json(tmp / RUN_FILE, run_info, indent=1)
    manifest = {
        "format": FORMAT, "dtype": dtype, "float32_tensors": kept32,
        "scale": info["scale"], "stage": int(info["stage"]), "fusion": bool(info["fusion"]),
        "planner": info["config"]["planner"],
        "parameters": int(sum(t.numel() for t in tensors.values())),
        "source": {"run": str(Path(run).resolve()), "stage": int(info["stage"]),
                   "checkpoint": info["checkpoint"],
                   "checkpoint_sha256": sha256_file(info["checkpoint"]),
                   "base_lm": info["lm"]},
    }
    return finish_export(tmp, out, manifest, command)


def check_export_target(out: str | Path, run: str | Path, who: str) -> Path:
    """``out`` as a path, after refusing (``ValueError``) a folder the export would wrongly
    replace: the run itself or a folder holding it, or an existing folder that is not an
    export (no ``manifest.json``)."""
    out, src = Path(out).resolve(), Path(run).resolve()
    if out == src or out in src.parents:
        raise ValueError(f"{who}: --out {out} is or holds the run {src}; the export replaces "
                         "its folder: choose another")
    if out.exists() and not (out / MANIFEST).is_file():
        raise ValueError(f"{who}: --out {out} exists and is not an export (no {MANIFEST}); "
                         "the export replaces its folder: choose another or remove it")
    return out


def finish_export(tmp: Path, out: Path, manifest: dict, command: str | None) -> dict:
    """Write ``manifest`` plus every file of ``tmp`` (SHA-256, size), the command, the git commit
    and the date into ``tmp/manifest.json``, then replace ``out`` by ``tmp``; returns the
    manifest. (AURORA's and the baselines' exports.)"""
    files = {}
    for p in sorted(x for x in tmp.rglob("*") if x.is_file()):
        rel = p.relative_to(tmp).as_posix()
        files[rel] = {"sha256": sha256_file(p), "bytes": p.stat().st_size}
    dirty = _git("status", "--porcelain", "--untracked-files=no")
    manifest = {
        **manifest, "files": files,
        "command": command if command is not None else " ".join(sys.argv),
        "git_commit": _git("rev-parse", "HEAD"),
        "git_dirty": None if dirty is None else bool(dirty),
        "created_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
    }
    atomic_write_json(tmp / MANIFEST, manifest, indent=1)
    shutil.rmtree(out, ignore_errors=True)
    tmp.rename(out)
    return manifest


def verify_export(path: str | Path, fmt: str = FORMAT, who: str = "AURORA weights",
                  how: str = "v2xbench aurora export --run RUN --out DIR") -> dict:
    """The manifest of an exported folder after checking every file it lists (size and SHA-256);
    ``fmt`` the format it must have, ``who`` and ``how`` (the export command) for messages.

    Raises:
        FileNotFoundError: no folder, manifest or listed file (named). ValueError: a file whose
            size or SHA-256 differs from the manifest (the message names it and both digests).
    """
    path = Path(path)
    if not (path / MANIFEST).is_file():
        raise FileNotFoundError(f"{who}: {path / MANIFEST} does not exist (export a "
                                f"run with `{how}`)")
    manifest = json.loads((path / MANIFEST).read_text())
    if manifest.get("format") != fmt:
        raise ValueError(f"{who}: {path / MANIFEST} has format "
                         f"{manifest.get('format')!r}, not {fmt!r}")
    for rel, want in manifest["files"].items():
        f = path / rel
        if not f.is_file():
            raise FileNotFoundError(f"{who}: {f} is listed in {MANIFEST} but missing")
        got = sha256_file(f)
        if got != want["sha256"] or f.stat().st_size != want["bytes"]:
            raise ValueError(f"{who}: {f} fails its SHA-256 check (manifest "
                             f"{want['sha256']}, file {got}): the file changed since the export;"
                             " export again or restore it")
    return manifest


def load_export(path: str | Path, device: str = "cpu"):
    """``(system, tokenizer, info)`` of an exported folder, like :func:`~.system.load_system`
    (eval mode, float32); every file is checked first (:func:`verify_export`)."""
    from safetensors.torch import load_file
    from transformers import AutoConfig, AutoModelForCausalLM

    from .config import AuroraConfig
    from .language import AuroraLM, add_lora
    from .system import AuroraSystem
    from .tokenizer import load_tokenizer

    path = Path(path)
    manifest = verify_export(path)
    info = json.loads((path / RUN_FILE).read_text())
    cfg = AuroraConfig.from_dict(info["config"])
    tok = load_tokenizer(path / LM_DIR)
    base = AutoModelForCausalLM.from_config(AutoConfig.from_pretrained(str(path / LM_DIR)))
    system = AuroraSystem(cfg, AuroraLM(add_lora(base, cfg), tok, cfg.lm_width),
                          bool(info.get("fusion", True)))
    state = {k: v.float() if v.is_floating_point() else v
             for k, v in load_file(str(path / WEIGHTS)).items()}
    try:
        system.load_state_dict(state, strict=True)
    except RuntimeError as e:
        raise ValueError(f"AURORA weights: {path / WEIGHTS} does not fit the model of "
                         f"{path / RUN_FILE}: {e}") from None
    info = dict(info, checkpoint=str(path / WEIGHTS), lm_dir=str(path / LM_DIR),
                stage=manifest["stage"], export=str(path))
    return system.to(device).eval(), tok, info


__all__ = ["FORMAT", "MANIFEST", "SHIPPED", "WEIGHTS", "check_export_target", "export_run",
           "finish_export", "load_export", "sha256_file", "verify_export"]
