"""Matplotlib set-up shared by the figure modules: headless backend, colours, saving.

Colours: ground truth is always green. Figures that draw runs against each other (bird's-eye views, the
history-bias figure, frame pictures, the HTML frame browser) give each run of the report its own colour
from :data:`RUN_PALETTE` (:func:`run_colors`: every pair at least :data:`MIN_DELTA_E` apart in CIELAB, so
two runs of one family never look alike). The bubble chart colours by family (:func:`model_colors`: a
shade of its family's hue, older generations darker), so that a family reads as a family there.
No run colour is green, white or the collision red.
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
# one colour per run in a figure: tab10 without its green (the truth) and red (collisions), then high-contrast
# extras; every pair is >= MIN_DELTA_E apart (CIE76, D65), and each as far from GT_COLOR, white and COLLISION_RED
RUN_PALETTE = (
    "#1f77b4",
    "#ff7f0e",
    "#9467bd",
    "#8c564b",
    "#e377c2",
    "#17becf",
    "#bcbd22",
    "#7f7f7f",
    "#000080",
    "#ff1493",
    "#000000",
    "#aec7e8",
    "#ffbb78",
    "#6a0000",
    "#808000",
    "#b15928",
    "#1a1a66",
    "#ff9896",
)
MIN_DELTA_E = 25.0
COLLISION_RED = "#e00000"
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


def srgb_to_lab(color: str) -> tuple[float, float, float]:
    """CIELAB (L*, a*, b*) of an sRGB colour (any matplotlib colour spec), D65 white; L* in 0…100."""
    from matplotlib.colors import to_rgb

    linear = [c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4 for c in to_rgb(color)]
    m = ((0.4124564, 0.3575761, 0.1804375), (0.2126729, 0.7151522, 0.0721750), (0.0193339, 0.1191920, 0.9503041))
    white = (0.95047, 1.0, 1.08883)
    x, y, z = (sum(m[i][k] * linear[k] for k in range(3)) / white[i] for i in range(3))
    f = [t ** (1 / 3) if t > (6 / 29) ** 3 else t / (3 * (6 / 29) ** 2) + 4 / 29 for t in (x, y, z)]
    return 116 * f[1] - 16, 500 * (f[0] - f[1]), 200 * (f[1] - f[2])


def delta_e(a: str, b: str) -> float:
    """CIE76 colour difference ΔE*ab between two colours (about 2.3: just noticeable; 25: clearly different hues)."""
    return sum((p - q) ** 2 for p, q in zip(srgb_to_lab(a), srgb_to_lab(b))) ** 0.5


def run_colors(labels: Iterable[str]) -> dict[str, str]:
    """One colour per run label, in the given order, from :data:`RUN_PALETTE` — per run, not per family, so that
    every pair of runs in one figure is at least :data:`MIN_DELTA_E` apart (up to ``len(RUN_PALETTE)`` = 18 runs;
    beyond that the palette repeats: the 19th run shares the first one's colour). A label given twice keeps its
    first colour."""
    out: dict[str, str] = {}
    for label in labels:
        out.setdefault(str(label), RUN_PALETTE[len(out) % len(RUN_PALETTE)])
    return out


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


def save_figure(
    fig: Any, stem: str | os.PathLike[str], *, formats: tuple[str, ...] = FORMATS, dpi: int = DPI
) -> list[Path]:
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
