"""The explanation audit per model: consistency with the plan and intent accuracy against the ground truth, with their
95 % scene-bootstrap intervals (docs/definitions.md#explanation-audit)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from lightemma.report.figures._mpl import pyplot

#: the bars drawn per model, in order (keys of lightemma.evaluation.intent_audit.KEYS)
BARS: tuple[str, ...] = ("consistent", "intent_accuracy")
_TITLES = {"consistent": "Consistent with its plan", "intent_accuracy": "Intent accuracy (ground truth)"}


def explanations_figure(
    rows: Sequence[Mapping[str, Any]],
    *,
    colors: Mapping[str, str] | None = None,
    notes: Mapping[str, str] | None = None,
) -> Any:
    """Grouped bars: per row (model) its ``consistent`` and ``intent_accuracy`` rates (in [0, 1]) with their
    ``<key>_ci95`` intervals as error bars. ``rows``: explanation rows (``model`` and the keys of
    :data:`lightemma.evaluation.intent_audit.ROW_KEYS`); ``colors``: model label → colour; ``notes``: a flag after a
    model's name. A value that is n/a is drawn as no bar with "n/a" at its foot. Raises ``ValueError`` without rows."""
    if not rows:
        raise ValueError("explanations_figure needs at least one row")
    plt = pyplot()
    n, m = len(BARS), len(rows)
    width = 0.8 / m
    fig, ax = plt.subplots(figsize=(max(6.0, 1.2 * m + 3), 4.0), layout="constrained")
    x = np.arange(n)
    for j, row in enumerate(rows):
        label = str(row.get("model", "?"))
        values = np.array([np.nan if row.get(k) is None else float(row[k]) for k in BARS])
        low = np.array([np.nan if not row.get(f"{k}_ci95") else float(row[f"{k}_ci95"][0]) for k in BARS])
        high = np.array([np.nan if not row.get(f"{k}_ci95") else float(row[f"{k}_ci95"][1]) for k in BARS])
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
            color=(colors or {}).get(label),
            label=label + (notes or {}).get(label, ""),
            error_kw={"elinewidth": 0.8},
        )
        for p, v in zip(pos, values):
            if not np.isfinite(v):
                ax.text(p, 0.02, "n/a", rotation=90, ha="center", va="bottom", fontsize=6, color="0.4")
    ax.set_xticks(x)
    ax.set_xticklabels([_TITLES[k] for k in BARS], fontsize=8)
    ax.set_ylim(0.0, 1.05)
    ax.set_ylabel("share of frames")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))  # beside the axes: never over an "n/a"
    fig.suptitle("Does the model do what it says? (95 % scene-bootstrap intervals)", fontsize=10)
    return fig
