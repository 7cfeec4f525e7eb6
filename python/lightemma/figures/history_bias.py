"""History-bias figure: does predicted curvature follow the last history curvature more than
the truth does? (the paper's Case 1, measured over all frames instead of one)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from lightemma.figures._mpl import GT_COLOR, pred_color, pyplot


def history_bias_figure(runs: Sequence[Any], *, max_points: int = 4000) -> Any:
    """Left: predicted (per model) and true mean future curvature against the last history
    curvature, with least-squares lines. Right: on frames going straight just after a turn, the
    share of the last history curvature carried into the prediction, and into the truth."""
    from lightemma.evaluation.core import unique_labels
    from lightemma.scenarios import bias_row, curvature_samples

    plt = pyplot()
    labels = unique_labels(list(runs))
    samples = [curvature_samples(run) for run in runs]
    stats = [bias_row(label, k) for label, k in zip(labels, samples)]
    fig, (scatter, bars) = plt.subplots(1, 2, figsize=(12, 4.8), gridspec_kw={"width_ratios": [1.4, 1]})
    rng = np.random.default_rng(0)
    truth_drawn = False
    for i, (label, k, stat) in enumerate(zip(labels, samples, stats)):
        if len(k["history"]) == 0:
            continue
        keep = rng.permutation(len(k["history"]))[:max_points]
        if not truth_drawn:
            scatter.scatter(k["history"][keep], k["true"][keep], s=8, color=GT_COLOR, alpha=0.5, zorder=3, label=f"truth (slope {_fmt(stat['slope_true'])})")
            _fit_line(scatter, k["history"], k["true"], GT_COLOR, zorder=5)
            truth_drawn = True
        color = pred_color(i)
        scatter.scatter(k["history"][keep], k["pred"][keep], s=8, color=color, alpha=0.35, label=f"{label} (slope {_fmt(stat['slope_pred'])})")
        _fit_line(scatter, k["history"], k["pred"], color)
    scatter.axhline(0, color="0.7", linewidth=0.8)
    scatter.axvline(0, color="0.7", linewidth=0.8)
    scatter.set_xlabel("last history curvature (1/m)")
    scatter.set_ylabel("mean future curvature, 0–3 s (1/m)")
    scatter.set_title("predicted vs true curvature against history", fontsize=10)
    if scatter.get_legend_handles_labels()[0]:
        scatter.legend(fontsize=7, loc="upper left")
    with_turns = [s for s in stats if s["carry_pred"] is not None]
    if with_turns:
        x = np.arange(len(with_turns))
        bars.bar(x, [s["carry_pred"] for s in with_turns], color=[pred_color(labels.index(s["model"])) for s in with_turns])
        truth = float(np.mean([s["carry_true"] for s in with_turns]))
        bars.axhline(truth, color=GT_COLOR, linewidth=2, label=f"truth ({truth:.2f})")
        bars.set_xticks(x)
        bars.set_xticklabels([f"{s['model']}\n(n={s['after_turn_frames']})" for s in with_turns], rotation=30, ha="right", fontsize=7)
        bars.legend(fontsize=8)
    else:
        bars.text(0.5, 0.5, "no frame goes straight just after a turn", ha="center", va="center", transform=bars.transAxes, color="0.4")
    bars.set_ylabel("history curvature carried over (share)")
    bars.set_title("straight just after a turn (Case 1)", fontsize=10)
    fig.tight_layout()
    return fig


def _fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def _fit_line(ax: Any, x: np.ndarray, y: np.ndarray, color: str, zorder: float = 4) -> None:
    if len(x) >= 2 and np.ptp(x) > 0:
        slope, intercept = np.polyfit(x, y, 1)
        xs = np.array([x.min(), x.max()])
        ax.plot(xs, slope * xs + intercept, color=color, linewidth=1.8, zorder=zorder)
