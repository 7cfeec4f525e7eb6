"""The planning score broken into its sub-scores: one group of bars per sub-score, one bar per model and the ground
truth (docs/definitions.md#planning-score)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from lightemma.report.figures._mpl import GT_COLOR, pyplot

#: the bars drawn, in order: the aggregates, then the sub-scores (tlc is always n/a on nuScenes: left out)
BARS: tuple[str, ...] = ("pdms", "epdms", "epdms_map", "nc", "dac", "ddc", "ep", "ttc", "lk", "c", "hc", "ec")
_TITLES = {
    "pdms": "PDMS",
    "epdms": "EPDMS",
    "epdms_map": "EPDMS-map",
    "nc": "NC",
    "dac": "DAC",
    "ddc": "DDC",
    "ep": "EP",
    "ttc": "TTC",
    "lk": "LK",
    "c": "C",
    "hc": "HC",
    "ec": "EC",
}


def planning_figure(
    rows: Sequence[Mapping[str, Any]],
    *,
    colors: Mapping[str, str] | None = None,
    notes: Mapping[str, str] | None = None,
    gt_label: str | None = None,
) -> Any:
    """Grouped bars of each row's planning means (values in [0, 1]) with their 95 % intervals as error bars.

    ``rows``: planning rows (``model`` and the keys of :data:`lightemma.evaluation.planning_score.ROW_KEYS`), the ground
    truth's last; ``colors``: model label → colour (the ground truth is green); ``notes``: a flag after a model's name.
    A value that is n/a is drawn as no bar with "n/a" at its foot; keys no row has are left out. Raises ``ValueError``
    when there is no row.
    """
    if not rows:
        raise ValueError("planning_figure needs at least one row")
    plt = pyplot()
    keys = [k for k in BARS if any(r.get(k) is not None for r in rows)] or list(BARS[:3])
    n, m = len(keys), len(rows)
    width = 0.8 / m
    fig, ax = plt.subplots(figsize=(max(7.0, 0.7 * n * max(1, m) / 2 + 3), 4.2), layout="constrained")
    x = np.arange(n)
    for j, row in enumerate(rows):
        label = str(row.get("model", "?"))
        color = GT_COLOR if label == gt_label else (colors or {}).get(label)
        values = np.array([np.nan if row.get(k) is None else float(row[k]) for k in keys])
        low = np.array([np.nan if not row.get(f"{k}_ci95") else float(row[f"{k}_ci95"][0]) for k in keys])
        high = np.array([np.nan if not row.get(f"{k}_ci95") else float(row[f"{k}_ci95"][1]) for k in keys])
        err = np.vstack(
            [np.where(np.isfinite(low), values - low, 0.0), np.where(np.isfinite(high), high - values, 0.0)]
        )
        err = np.where(np.isfinite(err), np.maximum(err, 0.0), 0.0)
        pos = x - 0.4 + width * (j + 0.5)
        ax.bar(
            pos,
            np.nan_to_num(values),
            width * 0.9,
            yerr=err,
            capsize=2,
            color=color,
            label=label + (notes or {}).get(label, ""),
            error_kw={"elinewidth": 0.8},
        )
        for p, v in zip(pos, values):
            if not np.isfinite(v):
                ax.text(p, 0.02, "n/a", rotation=90, ha="center", va="bottom", fontsize=6, color="0.4")
    ax.set_xticks(x)
    ax.set_xticklabels([_TITLES[k] for k in keys], fontsize=8)
    ax.set_ylim(0.0, 1.05)
    ax.set_ylabel("mean over frames with a value")
    aggregates = sum(k in ("pdms", "epdms", "epdms_map") for k in keys)
    if 0 < aggregates < n:
        ax.axvline(aggregates - 0.5, color="0.7", linewidth=0.8)
    ax.legend(fontsize=7, loc="lower left", ncol=max(1, min(3, m)))
    fig.suptitle(
        "Planning score (NAVSIM) by sub-score: aggregates, then each sub-score (95 % scene-bootstrap intervals)",
        fontsize=10,
    )
    return fig
