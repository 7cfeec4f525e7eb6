"""A run's records as compact columns, and the columnar sidecar a session leaves beside ``frames.jsonl``.

Every well-formed record of ``frames.jsonl`` (:func:`lightemma.runs.store.iter_records`) is reduced at once to a few
numbers (trajectory, ground truth, statuses, time, tokens, cost), gathered in NumPy chunks of :data:`_CHUNK` rows
(:class:`RecordColumns`, :class:`RawColumns`), so memory holds about 0.5 kB per frame and never the decoded records.
The sidecar (:data:`SIDECAR_FILE`) keeps those columns with the identity of the ``frames.jsonl`` they were read from
(:func:`source_key`): ``frames.jsonl`` stays the record of truth, the sidecar is a cache that evaluate
(:func:`lightemma.evaluation.loading.load_run`) reads when it is current. Writers that hold their records (the
importer) fill :class:`RecordColumns` as they go; a session refreshes it at its end (:func:`refresh_sidecar`).
"""

from __future__ import annotations

import itertools
import math
import os
import tempfile
import time
import zipfile
from collections.abc import Callable, Iterable, Iterator, Mapping
from contextlib import suppress
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lightemma.definitions import OUTCOME_CODES, STATUS_CODES
from lightemma.errors import RunStoreError
from lightemma.runs.records import MAX_POSITION_M, answer_received, first_answer_status, gc_paused
from lightemma.runs.store import FRAMES_FILE, RunContents, iter_records

UNKNOWN_STATUS = -1
API_ERROR_STATUS = -2  # first_status of a frame whose calls all failed at the provider: no answer, not a format error
NOT_RECORDED = -1  # failure code of a record without a failure field (older runs)
_NAN6x2 = [[math.nan, math.nan]] * 6
_CHUNK = 2048


def failure_code(value: Any) -> int:
    """Code of a record's ``failure`` field (:data:`lightemma.definitions.OUTCOME_CODES`): :data:`NOT_RECORDED` when
    absent, 1 (format) for an unknown non-empty reason."""
    if value is None:
        return NOT_RECORDED
    return OUTCOME_CODES.get(value, OUTCOME_CODES["format"]) if value else 0


_NUMERIC = (int, float)


def _number(value: Any) -> float:
    return value if type(value) in _NUMERIC else math.nan  # exact types: bool is not a number here


def pairs_array(values: list[Any]) -> np.ndarray:
    """(n, 6, 2) float64 from a list of 6×2 nested lists; an entry that is mis-shaped or not numeric becomes NaN.

    When every entry has 6 pairs of 2 the numbers are streamed into one array at
    once; otherwise (or when a value is not a number) entries are converted one by one.
    """
    chain = itertools.chain.from_iterable
    try:
        if set(map(len, values)) == {6} and set(map(len, chain(values))) == {2}:
            return np.fromiter(chain(chain(values)), dtype=np.float64, count=12 * len(values)).reshape(-1, 6, 2)
    except (TypeError, ValueError):
        pass
    out = np.full((len(values), 6, 2), np.nan)
    for i, value in enumerate(values):
        try:
            array = np.array(value, dtype=np.float64)
        except (ValueError, TypeError):
            continue
        if array.shape == (6, 2):
            out[i] = array
    return out


class _Columns:
    """Accumulates per-record values in lists and flushes them to NumPy chunks of :data:`_CHUNK` rows.

    Every well-formed record becomes a row (the frame set, ground truth and
    duplicates are judged later, in :func:`_assemble`), so that the columns depend
    on ``frames.jsonl`` alone and can be kept in the sidecar.
    """

    PAIRS = ("trajectory", "actions", "gt", "history")
    NAMES = (
        *PAIRS,
        "status",
        "first",
        "seconds",
        "inp",
        "out",
        "cost",
        "cached",
        "failure",
        "scene",
        "traj_none",
        "gt_ok",
    )
    DTYPES = {
        "status": np.int8,
        "first": np.int8,
        "failure": np.int8,
        "scene": np.int32,
        "traj_none": bool,
        "gt_ok": bool,
    }

    def __init__(self) -> None:
        self.pending: dict[str, list[Any]] = {n: [] for n in self.NAMES}
        self.chunks: dict[str, list[np.ndarray]] = {n: [] for n in self.NAMES}
        self.frame_ids: list[str] = []
        self.scenes: dict[str, int] = {}

    def add(self, record: Mapping[str, Any]) -> None:
        p = self.pending
        fid = record["frame_id"]
        self.frame_ids.append(fid)
        gt = record.get("gt_positions")
        gt_ok = type(gt) is list and len(gt) == 6  # deeper damage (a bad pair) shows as NaN ground truth
        p["gt_ok"].append(gt_ok)
        p["gt"].append(gt if gt_ok else _NAN6x2)
        trajectory = record.get("trajectory")
        p["traj_none"].append(trajectory is None)
        p["trajectory"].append(_NAN6x2 if trajectory is None else trajectory)
        actions = record.get("actions")
        p["actions"].append(_NAN6x2 if actions is None else actions)
        history = record.get("history_actions")
        p["history"].append(_NAN6x2 if history is None else history)
        scene = record.get("scene_name")
        if not isinstance(scene, str) or not scene:
            scene = fid.rpartition("/")[0] or fid
        p["scene"].append(self.scenes.setdefault(scene, len(self.scenes)))
        failure = record.get("failure")
        if failure is None and record.get("status") == "failed" and not answer_received(record):
            failure = "api_error"  # a record older than `failure`: failed without ever receiving an answer
        p["failure"].append(failure_code(failure))
        recorded_status = record.get("status")
        p["status"].append(STATUS_CODES.get(recorded_status, UNKNOWN_STATUS))  # type: ignore[arg-type]  # else: unknown
        p["first"].append(
            STATUS_CODES.get(first_answer_status(record), UNKNOWN_STATUS)
            if answer_received(record)
            else API_ERROR_STATUS
        )
        p["seconds"].append(_number(record.get("seconds")))
        p["inp"].append(_number(record.get("input_tokens")))
        p["out"].append(_number(record.get("output_tokens")))
        p["cost"].append(_number(record.get("cost_cents")))
        p["cached"].append(_number(record.get("cached_input_tokens")))
        if len(p["status"]) >= _CHUNK:
            self.flush()

    def flush(self) -> None:
        for name, values in self.pending.items():
            if values:
                if name in self.PAIRS:
                    chunk = pairs_array(values)
                    if (
                        name == "gt"
                    ):  # beyond 100 km is no position (1e308 overflows every distance): no usable ground truth
                        with np.errstate(invalid="ignore"):
                            far = (np.abs(chunk) > MAX_POSITION_M).any(axis=(1, 2))
                        if far.any():
                            chunk[far] = np.nan
                else:
                    chunk = np.asarray(values, dtype=self.DTYPES.get(name, np.float64))
                self.chunks[name].append(chunk)
                values.clear()

    def finish(
        self, corrupt_lines: int = 0, truncated_tail: bool = False, corrupt_example: str | None = None
    ) -> RawColumns:
        self.flush()
        columns = {}
        for name in self.NAMES:
            parts = self.chunks.pop(name)
            shape = (6, 2) if name in self.PAIRS else ()
            dtype = self.DTYPES.get(name, np.float64)
            columns[name] = np.concatenate(parts) if parts else np.empty((0, *shape), dtype=dtype)
        return RawColumns(self.frame_ids, columns, list(self.scenes), corrupt_lines, truncated_tail, corrupt_example)


@dataclass
class RawColumns:
    """Every well-formed record of ``frames.jsonl`` as columns, in file order: what the sidecar holds."""

    frame_ids: list[str]
    columns: dict[str, np.ndarray]  # the names of _Columns.NAMES, one row per record
    scene_names: list[str]  # scene code -> name, in first-seen order over all rows
    corrupt_lines: int = 0
    truncated_tail: bool = False
    corrupt_example: str | None = None  # why the first corrupt line was skipped (records.record_problem)


RecordColumns = _Columns  # for writers that hold their records: add() each, finish(), then write_sidecar()


# ---------------------------------------------------------------- the columnar sidecar

SIDECAR_FILE = "frames.columns.npz"
SIDECAR_FORMAT = 2  # bump when RawColumns or the reading of a record changes: older sidecars are rebuilt
_TAIL_BYTES = 1 << 16


def source_key(run_dir: str | os.PathLike[str]) -> np.ndarray | None:
    """What identifies the current ``frames.jsonl``: format, size, mtime (ns), inode and a digest of its last 64 KiB.

    None when the file cannot be read. A sidecar whose key differs is stale.
    """
    import hashlib

    path = Path(run_dir) / FRAMES_FILE
    try:
        with open(path, "rb") as fh:
            st = os.fstat(fh.fileno())
            fh.seek(max(0, st.st_size - _TAIL_BYTES))
            tail = hashlib.sha256(fh.read(_TAIL_BYTES)).digest()
    except OSError:
        return None
    head = np.array([SIDECAR_FORMAT, st.st_size, st.st_mtime_ns, st.st_ino], dtype=np.int64).view(np.uint8)
    return np.concatenate([head, np.frombuffer(tail, dtype=np.uint8)])


def _join_names(names: list[str]) -> np.ndarray | None:
    if any("\n" in name for name in names):
        return None  # never met in practice; such a run is simply read from frames.jsonl each time
    return np.frombuffer("\n".join(names).encode("utf-8", "surrogatepass"), dtype=np.uint8)


def _split_names(blob: np.ndarray, n: int) -> list[str]:
    names = blob.tobytes().decode("utf-8", "surrogatepass").split("\n") if n else []
    if len(names) != n:
        raise ValueError("names do not match the rows")
    return names


def write_sidecar(run_dir: str | os.PathLike[str], raw: RawColumns, key: np.ndarray | None) -> bool:
    """Write ``raw`` as ``run_dir``/:data:`SIDECAR_FILE` (temporary file + rename); False when it cannot be written.

    ``key`` is :func:`source_key` of the ``frames.jsonl`` that ``raw`` was read from. A
    run folder that cannot be written to (read-only, full) just has no sidecar.
    """
    ids, scenes = _join_names(raw.frame_ids), _join_names(raw.scene_names)
    if key is None or ids is None or scenes is None:
        return False
    run_dir = Path(run_dir)
    _remove_stale_temporaries(run_dir)
    arrays = {f"col_{name}": value for name, value in raw.columns.items()}
    counts = np.array(
        [len(raw.frame_ids), len(raw.scene_names), raw.corrupt_lines, int(raw.truncated_tail)], dtype=np.int64
    )
    example = np.frombuffer((raw.corrupt_example or "").encode("utf-8", "surrogatepass"), dtype=np.uint8)
    if not run_dir.is_dir():
        return False
    fd, tmp = tempfile.mkstemp(prefix=f".{SIDECAR_FILE}.", suffix=".tmp", dir=run_dir)
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, key=key, counts=counts, frame_ids=ids, scene_names=scenes, corrupt_example=example, **arrays)
        os.replace(tmp, run_dir / SIDECAR_FILE)
        return True
    except OSError:
        with suppress(OSError):
            os.unlink(tmp)
        return False


_STALE_TEMPORARY_SECONDS = 600.0


def _remove_stale_temporaries(run_dir: Path) -> None:
    """Remove sidecar temporaries that a killed writer left (older than 10 minutes: not another writer's, still in use)."""
    now = time.time()
    for leftover in run_dir.glob(f".{SIDECAR_FILE}.*.tmp"):
        with suppress(OSError):
            if now - leftover.lstat().st_mtime > _STALE_TEMPORARY_SECONDS:
                leftover.unlink()


def read_sidecar(run_dir: str | os.PathLike[str], key: np.ndarray | None) -> RawColumns | None:
    """The sidecar's columns when it exists and was made from the ``frames.jsonl`` that ``key`` identifies, else None.

    Anything unexpected in it (another format, wrong shapes, a damaged file) makes it stale, never an error.
    """
    path = Path(run_dir) / SIDECAR_FILE
    if key is None or not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            if not np.array_equal(z["key"], key):
                return None
            n, n_scenes, corrupt, truncated = (int(v) for v in z["counts"])
            columns = {}
            for name in _Columns.NAMES:
                value = z[f"col_{name}"]
                shape = (n, 6, 2) if name in _Columns.PAIRS else (n,)
                if value.shape != shape or value.dtype != np.dtype(_Columns.DTYPES.get(name, np.float64)):
                    return None
                columns[name] = value
            example = z["corrupt_example"].tobytes().decode("utf-8", "surrogatepass") or None
            raw = RawColumns(
                _split_names(z["frame_ids"], n),
                columns,
                _split_names(z["scene_names"], n_scenes),
                corrupt,
                bool(truncated),
                example,
            )
        if n and (columns["scene"].min() < 0 or columns["scene"].max() >= n_scenes):
            return None
        return raw
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, UnicodeDecodeError):
        return None


def refresh_sidecar(run_dir: str | os.PathLike[str]) -> bool:
    """Write the sidecar of ``run_dir`` from its ``frames.jsonl`` unless a current one exists (end of a session)."""
    key = source_key(run_dir)
    if key is None or read_sidecar(run_dir, key) is not None:
        return False
    raw = read_columns(Path(run_dir))
    return key_unchanged(run_dir, key) and write_sidecar(run_dir, raw, key)


def key_unchanged(run_dir: str | os.PathLike[str], key: np.ndarray) -> bool:
    now = source_key(run_dir)
    return now is not None and np.array_equal(now, key)


def read_columns(
    run_dir: Path, transform: Callable[[Iterable[dict[str, Any]]], Iterator[dict[str, Any]]] | None = None
) -> RawColumns:
    """Stream ``frames.jsonl`` into :class:`RawColumns`; ``transform`` maps the records first (a re-parse) when given.

    :class:`~lightemma.errors.RunStoreError` when the file cannot be read."""
    counts = RunContents(run_dir=run_dir, manifest={}, records={})
    columns = _Columns()
    try:
        with gc_paused():  # decoded records hold no cycles; collecting while streaming only costs time
            records = iter_records(run_dir, counts=counts)
            for record in records if transform is None else transform(records):
                columns.add(record)
    except OSError as exc:
        raise RunStoreError(f"{run_dir}: cannot read frames: {exc}") from None
    return columns.finish(len(counts.corrupt_lines), counts.truncated_tail, counts.corrupt_example)
