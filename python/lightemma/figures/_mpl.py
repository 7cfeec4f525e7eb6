"""Matplotlib set-up shared by the figure modules: headless backend, colours, saving."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

GT_COLOR = "#2ca02c"  # ground truth is always green
PRED_COLORS = ("#d62728", "#1f77b4", "#ff7f0e", "#9467bd", "#e377c2", "#8c564b", "#17becf", "#bcbd22", "#7f7f7f")
FAMILY_COLORS = {
    "GPT": "#10a37f",
    "Claude": "#d97757",
    "Gemini": "#4285f4",
    "Qwen": "#7b4fd6",
    "LLaMA": "#e0245e",
    "Baseline": "#7f7f7f",
    "Other": "#8c564b",
}
FORMATS = ("png", "svg")


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the headless Agg backend (imported only when a figure is drawn)."""
    import matplotlib

    if not os.environ.get("MPLBACKEND"):
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def pred_color(index: int) -> str:
    """The colour of the ``index``-th predicted trajectory (never green)."""
    return PRED_COLORS[index % len(PRED_COLORS)]


def family_color(family: str) -> str:
    return FAMILY_COLORS.get(family, FAMILY_COLORS["Other"])


def save_figure(fig: Any, stem: str | os.PathLike[str], *, formats: tuple[str, ...] = FORMATS, dpi: int = 100) -> list[Path]:
    """Write ``fig`` as ``stem.png`` and ``stem.svg`` (by default), close it, return the paths."""
    stem = Path(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    paths = []
    for fmt in formats:
        path = stem.with_suffix(f".{fmt}")
        fig.savefig(path, dpi=dpi)
        paths.append(path)
    pyplot().close(fig)
    return paths
