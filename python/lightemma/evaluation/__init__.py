"""Evaluate runs: the paper's Tables I and II from run directories (docs/definitions.md#metrics, #efficiency).

>>> from lightemma.evaluation import evaluate_runs
>>> ev = evaluate_runs(["runs/"], convention="all", common=True)
>>> ev.accuracy_rows("lightemma")   # list of dicts, one per model
"""

from lightemma.evaluation.core import (
    Evaluation,
    ModelResult,
    columns,
    common_frames,
    evaluate_loaded,
    evaluate_runs,
    expand_run_dirs,
)
from lightemma.evaluation.loading import RunData, load_run, read_frame_records
from lightemma.evaluation.manifest import RunInfo, run_info

__all__ = [
    "Evaluation",
    "ModelResult",
    "RunData",
    "RunInfo",
    "columns",
    "common_frames",
    "evaluate_loaded",
    "evaluate_runs",
    "expand_run_dirs",
    "load_run",
    "read_frame_records",
    "run_info",
]
