"""Run directories: ``manifest.json`` plus one JSON line per finished frame (docs/definitions.md#run-records)."""

from lightemma.runs.store import (
    FRAMES_FILE,
    MANIFEST_FILE,
    RunContents,
    RunWriter,
    create_run_dir,
    find_run_dirs,
    read_manifest,
    read_run,
    update_manifest,
    write_json_atomic,
)

__all__ = [
    "FRAMES_FILE",
    "MANIFEST_FILE",
    "RunContents",
    "RunWriter",
    "create_run_dir",
    "find_run_dirs",
    "read_manifest",
    "read_run",
    "update_manifest",
    "write_json_atomic",
]
