"""Matplotlib set-up shared by the figure modules: headless backend, colours, saving.

Colours: ground truth is always green; every model has **one colour everywhere**
(bubble chart, history bias, frame pictures), a shade of its family's hue —
older generations darker, newer lighter — so that a family reads as a family
and each model stays recognisable. No model colour is green.
"""

from __future__ import annotations

import colorsys
import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

GT_COLOR = "#2ca02c"  # ground truth is always green
PRED_COLORS = ("#d62728", "#1f77b4", "#ff7f0e", "#9467bd", "#e377c2", "#8c564b", "#17becf", "#bcbd22", "#7f7f7f")
FAMILY_COLORS = {
    "GPT": "#d49b00",
    "Claude": "#d9480f",
    "Gemini": "#1f6fc4",
    "Qwen": "#7048c8",
    "LLaMA": "#d6246e",
    "Baseline": "#17becf",  # cyan: every baseline is a shade of it
    "Other": "#7f7f7f",
}
# models of no known family: distinct colours that show on camera images and are no family's hue (no pink, brown, green)
OTHER_COLORS = ("#7f7f7f", "#3d3d3d", "#a39e7a", "#b5b5b5", "#5f6b7a", "#8a7f99")
PAPER_GENERATIONS = 3  # the paper's families have three generations each
FORMATS = ("png", "svg")
DPI = 150


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


def _shade(color: str, position: int, count: int, extra: float = 0.0) -> str:
    """``color`` darker (position 0) to lighter (position count − 1), same hue; ``extra`` shifts the lightness."""
    r, g, b = (int(color[i : i + 2], 16) / 255 for i in (1, 3, 5))
    h, lightness, sat = colorsys.rgb_to_hls(r, g, b)
    offset = 0.0 if count <= 1 else (position / (count - 1) - 0.5) * 0.3
    r, g, b = colorsys.hls_to_rgb(h, min(0.8, max(0.2, lightness + offset + extra)), sat)
    return "#" + "".join(f"{round(255 * v):02x}" for v in (r, g, b))


def model_colors(models: Iterable[Mapping[str, Any] | Any]) -> dict[str, str]:
    """One colour per model label: its family's hue, shaded by generation (older darker).

    ``models``: dicts or objects with ``label`` (or ``model``), ``family`` and
    ``generation``, e.g. :class:`~lightemma.evaluation.ModelResult` or bubble-chart
    points. Within a paper family the shade follows the generation (1–3), so a
    run and the paper's row of the same model share a colour; other families
    shade in the given order; models of family ``Other`` get distinct colours.
    """
    def get(m: Any, key: str) -> Any:
        return m.get(key) if isinstance(m, Mapping) else getattr(m, key, None)

    members: dict[str, list[tuple[str, Any]]] = {}
    for m in models:
        label = get(m, "label") or get(m, "model")
        family = get(m, "family") or "Other"
        if label not in {lab for group in members.values() for lab, _ in group}:
            members.setdefault(family, []).append((str(label), get(m, "generation")))
    out: dict[str, str] = {}
    others = 0  # one running count over models of no known family, so that no two share a colour
    for family, group in members.items():
        if family not in FAMILY_COLORS or family == "Other":
            for label, _ in group:
                out[label] = OTHER_COLORS[others % len(OTHER_COLORS)]
                others += 1
            continue
        gens = [g for _, g in group]
        by_generation = family != "Baseline" and all(isinstance(g, int) and 1 <= g <= PAPER_GENERATIONS for g in gens)
        seen: dict[int, int] = {}
        for i, (label, gen) in enumerate(group):
            if by_generation:
                # two runs of one generation (variants of one model): the second one lighter, the third darker, …
                k = seen[gen] = seen.get(gen, -1) + 1
                extra = 0.0 if k == 0 else (0.1 * ((k + 1) // 2)) * (1 if k % 2 else -1)
                out[label] = _shade(FAMILY_COLORS[family], gen - 1, PAPER_GENERATIONS, extra)
            else:
                out[label] = _shade(FAMILY_COLORS[family], i, len(group))
    return out


def save_figure(fig: Any, stem: str | os.PathLike[str], *, formats: tuple[str, ...] = FORMATS, dpi: int = DPI) -> list[Path]:
    """Write ``fig`` as ``stem.png`` (150 dpi) and ``stem.svg`` (by default), close it, return the paths."""
    stem = Path(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    paths = []
    for fmt in formats:
        path = stem.with_name(f"{stem.name}.{fmt}")  # not with_suffix: "Gemini-2.5-Flash" has a dot of its own
        fig.savefig(path, dpi=dpi)
        paths.append(path)
    pyplot().close(fig)
    return paths
