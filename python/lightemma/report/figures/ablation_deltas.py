"""The "does the model look at the road?" figure: paired differences with their intervals, one row per comparison."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from lightemma.report.figures._mpl import pyplot


def ablation_figure(
    ablations: Sequence[Mapping[str, Any]],
    gains: Sequence[Mapping[str, Any]],
    *,
    metric: str = "ade_avg",
    unit: str = "m",
) -> Any:
    """Two panels of horizontal intervals (rows of :func:`~lightemma.evaluation.ablations.input_ablations` and
    :func:`~lightemma.evaluation.ablations.baseline_gains`): left, full − ablated per ablation run (left of 0: the
    model uses what was taken away); right, each model's gain over the best baseline (right of 0: it beats the
    history alone). A filled marker is significant after Holm's adjustment, a hollow one is not; a row without an
    interval (fewer than 2 scenes) shows its point alone.
    """
    plt = pyplot()
    panels = [
        (
            ablations,
            "diff",
            lambda r: f"{r['model']} − {r['ablation']}",
            f"full − ablated, {metric} ({unit})",
            "← the model uses what the ablation removes",
        ),
        (
            gains,
            "gain",
            lambda r: f"{r['model']} vs {r['baseline']}",
            f"gain over the best baseline, {metric} ({unit})",
            "the model beats the history alone →",
        ),
    ]
    panels = [p for p in panels if p[0]]
    if not panels:
        raise ValueError("no ablation or baseline comparison to draw")
    height = max(2.4, 0.45 * max(len(p[0]) for p in panels) + 1.4)
    fig, axes = plt.subplots(1, len(panels), figsize=(7.0 * len(panels), height), squeeze=False)
    for ax, (rows, diff, name, xlabel, title) in zip(axes[0], panels):
        y = list(range(len(rows)))[::-1]
        for yi, row in zip(y, rows):
            value = row.get(f"{metric}_{diff}")
            if value is None:
                continue
            ci = row.get(f"{metric}_ci95")
            err = [[value - ci[0]], [ci[1] - value]] if ci else None
            significant = bool(row.get(f"{metric}_significant"))
            ax.errorbar(
                [value],
                [yi],
                xerr=err,
                fmt="o",
                color="C0" if significant else "0.45",
                capsize=3,
                markerfacecolor="C0" if significant else "white",
                zorder=3,
            )
        ax.axvline(0.0, color="0.3", linewidth=1.0, zorder=1)
        ax.set_yticks(y)
        ax.set_yticklabels([name(r) for r in rows], fontsize=7)
        ax.set_ylim(-0.8, len(rows) - 0.2)
        ax.set_xlabel(xlabel + ", 95 % scene-bootstrap CI")
        ax.set_title(title, fontsize=10)
    fig.tight_layout()
    return fig
