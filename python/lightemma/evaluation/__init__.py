"""Evaluate runs: the paper's Tables I and II from run directories (docs/definitions.md#metrics, #efficiency).

>>> from lightemma.evaluation import evaluate_runs
>>> ev = evaluate_runs(["runs/"], convention="all", common=True)
>>> ev.accuracy_rows("lightemma")   # list of dicts, one per model
"""

from lightemma.evaluation.core import (
    CONVENTION_NAMES,
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
    "CONVENTION_NAMES",
    "Evaluation",
    "ModelResult",
    "RunData",
    "RunInfo",
    "accuracy_table",
    "columns",
    "common_frames",
    "efficiency_table",
    "evaluate_loaded",
    "evaluate_runs",
    "evaluation_tables",
    "expand_run_dirs",
    "generations_table",
    "load_run",
    "pairwise_table",
    "read_frame_records",
    "run_info",
]

# The tables of an evaluation are built in lightemma.report.evaluation_tables (presentation); they stay
# importable from here, lazily (that module imports this package).
_TABLES = ("accuracy_table", "efficiency_table", "evaluation_tables", "generations_table", "pairwise_table")


def __getattr__(name: str):  # noqa: ANN202
    if name in _TABLES:
        from lightemma.report import evaluation_tables

        return getattr(evaluation_tables, name)
    raise AttributeError(f"module 'lightemma.evaluation' has no attribute {name!r}")
