"""Per-model accounting beside the metrics: format errors and efficiency.

Definitions: docs/definitions.md#format-errors and #efficiency.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from lightemma.definitions import STATUS_CODES
from lightemma.evaluation.loading import RunData
from lightemma.runs.columns import API_ERROR_STATUS


def _pct(mask: np.ndarray) -> float | None:
    return float(100.0 * mask.mean()) if mask.size else None


def format_errors(run: RunData, rows: np.ndarray) -> dict[str, Any]:
    """FE % (first received answer not ``ok``) and FE corr % (first received answer ``failed``) over ``rows``.

    Frames whose calls all failed at the provider (no answer received) are not format
    errors: they are left out of both rates and counted as ``api_error_frames``. Frames
    whose first status is unknown are left out too.
    """
    first = run.first_status[rows]
    api_errors = int((first == API_ERROR_STATUS).sum())
    first = first[first >= 0]
    return {
        "fe_pct": _pct(first != STATUS_CODES["ok"]),
        "fe_corr_pct": _pct(first == STATUS_CODES["failed"]),
        "failed_final": int((run.status[rows] == STATUS_CODES["failed"]).sum()),
        "api_error_frames": api_errors,
    }


def _mean(values: np.ndarray) -> float | None:
    known = values[np.isfinite(values)]
    return float(known.mean()) if known.size else None


def efficiency(run: RunData, rows: np.ndarray) -> dict[str, Any]:
    """Mean time, cost and tokens per frame over ``rows``; GPUs, run wall time, frames/s.

    For an imported run the means are over those of ``rows`` whose answer could
    be read (not ``failed``): the reference's evaluation summed time and tokens
    only over the frames it could score. ``frames`` says how many.
    Cost is None when no frame's cost is known (local models, unknown prices);
    ``cost_known_pct`` says how many frames the mean rests on. ``cached_pct`` is the share
    of input tokens served from a prompt cache (provider or vLLM prefix cache): Σ cached ÷
    Σ input over the frames that report both (None when none does).
    """
    if run.info.imported:  # read = not failed; implausible answers were read, and count here as they did there
        rows = rows[run.status[rows] != STATUS_CODES["failed"]]
    cost = run.cost_cents[rows]
    wall = run.info.wall_seconds
    n_run = len(run)
    batch = bool(getattr(run.info, "batch", False))
    return {
        # a batch run's frames wait for their batches: per-frame latency is n/a, the batch turnaround is shown instead
        "seconds_per_frame": None if batch else _mean(run.seconds[rows]),
        **(
            {"batch_turnaround_s": run.info.batch_turnaround_s, "not_applicable": ["seconds_per_frame"]}
            if batch
            else {}
        ),
        "cost_cents_per_frame": _mean(cost),
        "cost_known_pct": _pct(np.isfinite(cost)),
        "input_tokens": _mean(run.input_tokens[rows]),
        "cached_pct": _cached_pct(run, rows),
        "output_tokens": _mean(run.output_tokens[rows]),
        "gpus": run.info.gpus,
        "run_wall_seconds": wall,
        "frames_per_second": (n_run / wall) if wall and n_run and math.isfinite(wall) else None,
        "concurrency": run.info.concurrency,
        "frames": int(len(rows)),  # the frames the means rest on
    }


def _cached_pct(run: RunData, rows: np.ndarray) -> float | None:
    """100 × Σ cached input tokens ÷ Σ input tokens over ``rows`` that report both; None when none does."""
    if run.cached_input_tokens is None:
        return None
    cached, total = run.cached_input_tokens[rows], run.input_tokens[rows]
    known = np.isfinite(cached) & np.isfinite(total) & (total > 0)
    return float(100.0 * cached[known].sum() / total[known].sum()) if known.any() else None
