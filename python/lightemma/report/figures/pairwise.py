"""The paired-comparison matrix: ADE avg of the row model minus the column model, on their common frames."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from lightemma.report.figures._mpl import pyplot


def pairwise_figure(
    rows: Sequence[Mapping[str, Any]],
    labels: Sequence[str],
    *,
    notes: Mapping[str, str] | None = None,
    title: str | None = None,
) -> Any:
    """A matrix of ``pairwise_ade`` rows (see :func:`lightemma.evaluation.uncertainty.pairwise_ade`).

    Cell (row r, column c) = mean paired ADE avg of r − of c (m), coloured (blue:
    the row model is better, red: worse) and starred where the difference is
    significant after Holm's adjustment, pale grey where it is not. ``notes``
    add a flag after a model's name (e.g. fewer than half of its frames scored).
    """
    plt = pyplot()
    index = {label: i for i, label in enumerate(labels)}
    n = len(labels)
    diff = np.full((n, n), np.nan)
    significant = np.zeros((n, n), dtype=bool)
    for row in rows:
        a, b, d = index.get(row["model_a"]), index.get(row["model_b"]), row.get("ade_avg_diff")
        if a is None or b is None or d is None:
            continue
        diff[a, b], diff[b, a] = d, -d
        significant[a, b] = significant[b, a] = bool(row.get("significant"))
    reach = float(np.nanmax(np.abs(diff))) if np.isfinite(diff).any() else 1.0
    size = max(4.5, 0.55 * n + 2.5)
    # constrained layout keeps the title, the tick labels and the colourbar label inside the figure and apart
    fig, ax = plt.subplots(figsize=(max(7.0, size + 1.6), size + 0.6), layout="constrained")
    image = ax.imshow(np.where(significant, diff, np.nan), cmap="RdBu_r", vmin=-reach, vmax=reach)
    pale = np.where(np.isfinite(diff) & ~significant, 1.3, np.nan)
    ax.imshow(pale, cmap="Greys", vmin=0.0, vmax=10.0)  # not significant: a pale grey cell
    for r in range(n):
        for c in range(n):
            if r == c or not np.isfinite(diff[r, c]):
                continue
            strong = significant[r, c] and abs(diff[r, c]) > 0.6 * reach
            color = "white" if strong else ("black" if significant[r, c] else "0.45")
            ax.text(
                c,
                r,
                f"{diff[r, c]:+.2f}{'*' if significant[r, c] else ''}",
                ha="center",
                va="center",
                fontsize=7 if n <= 10 else 6,
                color=color,
            )
    names = [f"{label}{(notes or {}).get(label, '')}" for label in labels]
    ax.set_xticks(range(n))
    ax.set_xticklabels(names, rotation=45, ha="right", fontsize=8)
    ax.set_yticks(range(n))
    ax.set_yticklabels(names, fontsize=8)
    ax.set_xlabel("column model")
    ax.set_ylabel("row model")
    bar = fig.colorbar(image, ax=ax, fraction=0.046, pad=0.03)
    bar.set_label("ADE avg, row − column (m)\n< 0: the row model is better", fontsize=8)
    fig.suptitle(
        title
        or "Paired ADE avg differences on common frames\ncoloured with *: significant after Holm; grey: not distinguishable",
        fontsize=10,
    )
    return fig
