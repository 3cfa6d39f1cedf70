"""The plots of a run: per-category bars (mIoU, Part Sel., Suc.) and the GeoFusion vs GeoSpreading threshold curve."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

#: (file stem, title, per-category values of a method's summary entry); Part Sel. and Suc. over all slots.
PANELS: tuple[tuple[str, str, Callable[[dict], dict]], ...] = (
    ("miou", "mIoU", lambda m: m.get("miou", {}).get("categories", {})),
    ("part_selection", "Part Sel. (all slots)",
     lambda m: {c: v["part_selection_all_slots"] for c, v in m.get("categories", {}).items()}),
    ("success", "Suc. (all slots)", lambda m: {c: v["success_all_slots"] for c, v in m.get("categories", {}).items()}),
)


def write_plots(summary: dict, plot_dir: Path) -> list[Path]:
    """Per-category bars and the threshold curve, as PNG files; returns the files written."""
    import matplotlib

    matplotlib.use("Agg")
    plot_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for key, title, values_of in PANELS:
        per_method = {name: values_of(m) for name, m in summary["methods"].items() if values_of(m)}
        if per_method:
            written.append(_bars(per_method, title, plot_dir / f"{key}_per_category.png"))
    curve = summary.get("curve") or {}
    if curve.get("thresholds"):
        written.append(_curve(curve, plot_dir / "threshold_curve.png"))
    return written


def _bars(per_method: dict[str, dict], title: str, path: Path) -> Path:
    import matplotlib.pyplot as plt

    categories = sorted({c for v in per_method.values() for c in v})
    fig, ax = plt.subplots(figsize=(max(6.0, 1.2 * len(categories) + 2), 3.8))
    width = 0.8 / len(per_method)
    for i, (name, values) in enumerate(per_method.items()):
        heights = [values.get(c) if values.get(c) is not None else 0.0 for c in categories]
        ax.bar(np.arange(len(categories)) + i * width - 0.4 + width / 2, heights, width, label=name)
    ax.set_xticks(np.arange(len(categories)), categories, rotation=30, ha="right")
    ax.set_ylim(0, 1.05)
    ax.set_ylabel(title)
    ax.set_title(f"{title} per category")
    ax.legend(fontsize="small", ncols=min(len(per_method), 4))
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _curve(curve: dict, path: Path) -> Path:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 3.8))
    ax.plot(curve["thresholds"], curve["spread"], "o-", label="GeoSpreading (one decomposition)")
    ax.plot(curve["thresholds"], curve["full"], "s-", label="GeoFusion (from this threshold up)")
    ax.set_xscale("log")
    ax.set_xlabel("CoACD concavity threshold")
    ax.set_ylabel("mIoU")
    ax.set_title("GeoFusion vs GeoSpreading")
    ax.legend(fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
