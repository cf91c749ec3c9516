"""The plots of ``v2xbench experiments report`` (matplotlib, ``Agg``; written atomically):
DS against added latency and against packet loss (one curve per method, bootstrap 95% CI as
error bars) and BPS against DS for every closed-loop run (the bandwidth-performance frontier)."""

from __future__ import annotations

from pathlib import Path

from v2xbench.files import atomic_write

from .config import Config

CURVES = (("latency_ms", "ds_vs_latency.png", "added latency (ms)"),
          ("loss_pct", "ds_vs_loss.png", "packet loss (%)"))


def _num(x) -> float:
    return float("nan") if x is None or isinstance(x, str) else float(x)


def _save(fig, path: Path) -> str:
    import matplotlib.pyplot as plt

    with atomic_write(path, "wb") as f:
        fig.savefig(f, format="png")
    plt.close(fig)
    return str(path)


def write_plots(data: dict, cfg: Config, out: Path) -> list[str]:
    """The plots of the report's ``data`` (``robustness`` and ``bps_vs_ds``) into ``out``;
    returns their paths (none when the config has no robustness table)."""
    rob = data.get("robustness")
    if not isinstance(rob, dict):
        return []
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    paths = []
    for key, name, xlabel in CURVES:
        curves = rob.get(key) or {}
        if not any(curves.values()):
            continue
        fig, ax = plt.subplots(figsize=(5.0, 3.4), dpi=100)
        for m, pts in curves.items():
            if not pts:  # the method has no sweep of this setting
                continue
            x = np.array([p["x"] for p in pts], float)
            y = np.array([_num(p["driving_score"]) for p in pts])
            lo = np.array([_num(p["ci_low"]) for p in pts])
            hi = np.array([_num(p["ci_high"]) for p in pts])
            if pts[0].get("reference"):  # no sweep: its main run as a flat reference line
                ax.plot(x, y, linestyle="--", label=cfg.label(m) + " (no sweep)")
                continue
            err = np.nan_to_num(np.stack([y - lo, hi - y]), nan=0.0).clip(min=0.0)
            ax.errorbar(x, y, yerr=err, marker="o", capsize=3, label=cfg.label(m))
        ax.set_xlabel(xlabel)
        ax.set_ylabel("driving score")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        paths.append(_save(fig, out / name))
    pts = data.get("bps_vs_ds") or []
    if pts:
        fig, ax = plt.subplots(figsize=(5.0, 3.4), dpi=100)
        for m in dict.fromkeys(p["method"] for p in pts):
            mine = [p for p in pts if p["method"] == m]
            ax.scatter([_num(p["bps"]) for p in mine], [_num(p["driving_score"]) for p in mine],
                       label=cfg.label(m))
        ax.set_xlabel("V2X bytes per second (BPS)")
        ax.set_ylabel("driving score")
        ax.set_title("bandwidth against performance, every closed-loop run", fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        paths.append(_save(fig, out / "bps_vs_ds.png"))
    return paths


__all__ = ["write_plots"]
