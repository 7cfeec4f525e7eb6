"""The one reader of nuScenes' JSON tables (``<dataroot>/<version>/<table>.json``): bounded, checked, one-line errors.

Every table any part of lightemma reads (the frames, the safety metrics' poses and agents, the planning score's,
the object audit's) comes through :func:`read_table`, after :func:`check_dataroot` has found the version folder
with all 13 tables, as the devkit requires. Problems are :class:`~lightemma.errors.DatasetError` naming the file.
"""

from __future__ import annotations

import json
import os
from typing import Any

from lightemma._files import FileRefused, read_regular_file
from lightemma.errors import DatasetError

__all__ = ["MAX_TABLE_BYTES", "TABLES", "check_dataroot", "read_table", "table_path"]

#: the 13 tables of a nuScenes version folder (all must be present, as the devkit requires)
TABLES = (
    "category",
    "attribute",
    "visibility",
    "instance",
    "sensor",
    "calibrated_sensor",
    "ego_pose",
    "log",
    "scene",
    "sample",
    "sample_data",
    "sample_annotation",
    "map",
)

#: the largest table read, bytes: far above nuScenes' largest (v1.0-trainval's, under 1 GB each); a larger file, a
#: FIFO or a device is refused before it is read (:func:`lightemma._files.read_regular_file`)
MAX_TABLE_BYTES = 4 * 2**30


def check_dataroot(dataroot: str | os.PathLike[str], version: str) -> str:
    """Check that ``dataroot/version`` holds all 13 tables (:data:`TABLES`); return the absolute dataroot.

    Raises :class:`DatasetError` for a version that is not a non-empty string, a dataroot that does not exist or is
    not a folder, a missing version folder (naming the versions found there) or missing tables (naming each file).
    """
    if not isinstance(version, str) or not version:
        raise DatasetError(f"nuScenes version must be a non-empty string such as 'v1.0-test', got {version!r}")
    root = os.path.abspath(os.fspath(dataroot))
    if not os.path.exists(root):
        raise DatasetError(f"nuScenes dataroot {root} does not exist")
    if not os.path.isdir(root):
        raise DatasetError(f"nuScenes dataroot {root} is not a directory")
    table_root = os.path.join(root, version)
    if not os.path.isdir(table_root):
        present = sorted(d for d in os.listdir(root) if os.path.isfile(os.path.join(root, d, "scene.json")))
        hint = f"; versions found there: {', '.join(present)}" if present else "; no version folders found there"
        raise DatasetError(f"nuScenes version folder {table_root} does not exist{hint}")
    # a table that is there but is no regular file is named by read_table
    missing = [
        os.path.join(table_root, f"{t}.json")
        for t in TABLES
        if not os.path.lexists(os.path.join(table_root, f"{t}.json"))
    ]
    if missing:  # each named in the words of read_table
        raise DatasetError("; ".join(f"nuScenes table {path} is missing" for path in missing))
    return root


def table_path(dataroot: str | os.PathLike[str], version: str, table: str) -> str:
    """``<dataroot>/<version>/<table>.json``."""
    return os.path.join(os.fspath(dataroot), version, f"{table}.json")


def read_table(dataroot: str | os.PathLike[str], version: str, table: str) -> list[dict[str, Any]]:
    """One table: a JSON list of records, each an object with a string ``token``.

    Raises :class:`DatasetError` naming the file for a table that is missing, not a regular file of at most
    :data:`MAX_TABLE_BYTES`, not UTF-8 JSON (nesting too deep included: one line, not a ``RecursionError``), not a
    list, or holding a record that is not an object with a string ``token`` (naming the record's index).
    """
    path = table_path(dataroot, version, table)
    if not os.path.lexists(path):
        raise DatasetError(f"nuScenes table {path} is missing")
    try:
        data = read_regular_file(path, MAX_TABLE_BYTES)
    except FileRefused as exc:
        raise DatasetError(f"nuScenes table {path} {exc.reason}") from None
    try:
        text = data.decode("utf-8")
        del data
        rows = json.loads(text)
    except RecursionError:
        raise DatasetError(f"nuScenes table {path} cannot be read: the JSON is nested too deep") from None
    except ValueError as exc:  # UnicodeDecodeError and JSONDecodeError
        raise DatasetError(f"nuScenes table {path} cannot be read: it is not valid JSON ({exc})") from None
    if not isinstance(rows, list):
        raise DatasetError(f"nuScenes table {path} is not a list of records (a JSON {type(rows).__name__})")
    for i, row in enumerate(rows):
        if not isinstance(row, dict) or not isinstance(row.get("token"), str):
            raise DatasetError(f"nuScenes table {path}: record {i} is not an object with a string token")
    return rows
