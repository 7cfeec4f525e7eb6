"""The evaluation sidecar a session leaves beside its records (:func:`lightemma.runs.columns.refresh_sidecar`).

``frames.jsonl`` stays the record of truth: the sidecar is a cache evaluate reads when it is current, so failing to
write it is never fatal to a run.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from lightemma.errors import RunStoreError
from lightemma.runs.columns import refresh_sidecar


def refresh(run_dir: Path, log: Callable[[str], None] | None) -> None:
    """End of a session: write the evaluation sidecar of ``run_dir``; an error is one ``log`` line, never raised."""
    try:
        refresh_sidecar(run_dir)
    except (RunStoreError, OSError, ValueError) as exc:  # a cache: evaluate reads frames.jsonl without it
        if log:
            log(f"could not write the evaluation sidecar of {run_dir} ({exc}); evaluate will read frames.jsonl")
