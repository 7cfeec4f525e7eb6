"""Load run directories into compact per-frame columns, streaming.

A run's ``frames.jsonl`` is read line by line (:func:`lightemma.runs.store.iter_records`);
each record is reduced at once to a few numbers (trajectory, ground truth,
statuses, time, tokens, cost), gathered in NumPy chunks, so memory holds
about 0.5 kB per frame and never the decoded records themselves. Stage
texts are fetched later, only for the frames a figure needs
(:func:`read_frame_records`).
"""

from __future__ import annotations

import itertools
import math
import os
import tempfile
import time
import zipfile
from collections.abc import Iterable, Mapping
from contextlib import suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lightemma.errors import RunStoreError
from lightemma.evaluation.manifest import RunInfo, run_info
from lightemma.evaluation.outcomes import FAILURE_CODES, Plausibility, failure_code, final_failure, implausible_actions, outcome_counts, plausibility_for
from lightemma.evaluation.rescore import ParseDefinition, recorded_parse, rescored
from lightemma.runs.store import FRAMES_FILE, RunContents, iter_records, read_frame_ids
from lightemma.runs.records import MAX_POSITION_M, answer_received, first_answer_status, gc_paused

STATUS_CODES = {"ok": 0, "corrected": 1, "failed": 2}
UNKNOWN_STATUS = -1
API_ERROR_STATUS = -2  # first_status of a frame whose calls all failed at the provider: no answer, not a format error
_NAN6x2 = [[math.nan, math.nan]] * 6
_CHUNK = 2048


@dataclass
class RunData:
    """The frames of one run as columns (rows in first-seen frame order, last record wins)."""

    info: RunInfo
    frame_ids: list[str]
    trajectory: np.ndarray  # (N, 6, 2), NaN where the run has no valid prediction
    gt_positions: np.ndarray  # (N, 6, 2)
    status: np.ndarray  # (N,) int8: 0 ok, 1 corrected, 2 failed, -1 unknown
    first_status: np.ndarray  # (N,) int8: status of the first received answer; -2 none received (API errors), -1 unknown
    seconds: np.ndarray  # (N,) float64, NaN unknown
    input_tokens: np.ndarray
    output_tokens: np.ndarray
    cost_cents: np.ndarray
    cached_input_tokens: np.ndarray | None = None  # (N,) float64 of input_tokens served from a prompt cache, NaN unknown
    history_actions: np.ndarray | None = None  # (N, 6, 2) with details=True
    actions: np.ndarray | None = None  # (N, 6, 2) predicted, with details=True
    failure: np.ndarray | None = None  # (N,) int8 code of outcomes.FAILURES: why a frame is not scored (0: it is)
    scene_index: np.ndarray | None = None  # (N,) int32 into scene_names
    scene_names: list[str] = field(default_factory=list)
    caught_implausible: int = 0  # frames evaluation found implausible that the run had not marked
    plausibility: Plausibility = field(default_factory=Plausibility)
    corrupt_lines: int = 0
    corrupt_example: str | None = None  # why the first corrupt line was skipped, e.g. "line 7: status is ['ok'], …"
    truncated_tail: bool = False
    duplicates: int = 0
    bad_records: int = 0  # well-formed JSON lacking usable ground truth (skipped, or kept with NaN and never scored)
    foreign_records: int = 0  # records of frames outside the run's frame set (dropped)
    foreign_example: str | None = None
    frame_set_size: int | None = None  # frames in the run's frame set (frame_ids.txt), None for runs without one
    warnings: list[str] = field(default_factory=list)
    parse: ParseDefinition = field(default_factory=ParseDefinition)  # how the statuses and actions were read
    rescored: bool = False  # True when the stored answers were parsed again (a definition was asked for)

    def __len__(self) -> int:
        return len(self.frame_ids)

    @property
    def valid(self) -> np.ndarray:
        """Scored frames: a usable final prediction (not failed, not implausible, finite trajectory) and usable ground truth."""
        finite = np.isfinite(self.trajectory).all(axis=(1, 2)) & np.isfinite(self.gt_positions).all(axis=(1, 2))
        ok = (self.status != STATUS_CODES["failed"]) & finite
        return ok if self.failure is None else ok & (self.failure == 0)

    def outcomes(self, rows: np.ndarray | None = None) -> dict[str, int]:
        """Frames (of ``rows``, default all) scored / failed / implausible / lost to API errors."""
        failure = self.failure if self.failure is not None else np.where(self.status == STATUS_CODES["failed"], FAILURE_CODES["format"], 0)
        valid = self.valid
        if rows is not None:
            failure, valid = failure[rows], valid[rows]
        return outcome_counts(failure, valid)

    def scenes(self) -> np.ndarray:
        """(N,) scene code per frame (for scene-level resampling); each frame its own scene when unknown."""
        return self.scene_index if self.scene_index is not None else np.arange(len(self), dtype=np.int32)

    def index(self) -> dict[str, int]:
        """frame_id → row."""
        return {fid: i for i, fid in enumerate(self.frame_ids)}


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
    NAMES = (*PAIRS, "status", "first", "seconds", "inp", "out", "cost", "cached", "failure", "scene", "traj_none", "gt_ok")
    DTYPES = {"status": np.int8, "first": np.int8, "failure": np.int8, "scene": np.int32, "traj_none": bool, "gt_ok": bool}

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
        p["status"].append(STATUS_CODES.get(record.get("status"), UNKNOWN_STATUS))
        p["first"].append(STATUS_CODES.get(first_answer_status(record), UNKNOWN_STATUS) if answer_received(record)
                          else API_ERROR_STATUS)
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
                    if name == "gt":  # beyond 100 km is no position (1e308 overflows every distance): no usable ground truth
                        with np.errstate(invalid="ignore"):
                            far = (np.abs(chunk) > MAX_POSITION_M).any(axis=(1, 2))
                        if far.any():
                            chunk[far] = np.nan
                else:
                    chunk = np.asarray(values, dtype=self.DTYPES.get(name, np.float64))
                self.chunks[name].append(chunk)
                values.clear()

    def finish(self, corrupt_lines: int = 0, truncated_tail: bool = False, corrupt_example: str | None = None) -> RawColumns:
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
    counts = np.array([len(raw.frame_ids), len(raw.scene_names), raw.corrupt_lines, int(raw.truncated_tail)], dtype=np.int64)
    example = np.frombuffer((raw.corrupt_example or "").encode("utf-8", "surrogatepass"), dtype=np.uint8)
    fd, tmp = tempfile.mkstemp(prefix=f".{SIDECAR_FILE}.", suffix=".tmp", dir=run_dir) if run_dir.is_dir() else (None, None)
    if fd is None:
        return False
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
            raw = RawColumns(_split_names(z["frame_ids"], n), columns, _split_names(z["scene_names"], n_scenes), corrupt, bool(truncated),
                             example)
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
    raw = _read_records(Path(run_dir), None)
    return key_unchanged(run_dir, key) and write_sidecar(run_dir, raw, key)


def key_unchanged(run_dir: str | os.PathLike[str], key: np.ndarray) -> bool:
    now = source_key(run_dir)
    return now is not None and np.array_equal(now, key)


def _read_records(run_dir: Path, parse: ParseDefinition | None) -> RawColumns:
    """Stream ``frames.jsonl`` into :class:`RawColumns` (re-parsed under ``parse`` when given)."""
    counts = RunContents(run_dir=run_dir, manifest={}, records={})
    columns = _Columns()
    try:
        with gc_paused():  # decoded records hold no cycles; collecting while streaming only costs time
            records = iter_records(run_dir, counts=counts)
            for record in records if parse is None else rescored(records, parse):
                columns.add(record)
    except OSError as exc:
        raise RunStoreError(f"{run_dir}: cannot read frames: {exc}") from None
    return columns.finish(len(counts.corrupt_lines), counts.truncated_tail, counts.corrupt_example)


def load_run(run_dir: str | os.PathLike[str], *, details: bool = False, parse: ParseDefinition | None = None,
             keep_implausible: bool = False, sidecar: bool = True) -> RunData:
    """Read one run directory into :class:`RunData`, streaming ``frames.jsonl``.

    ``details=True`` also keeps history and predicted actions (for scenario
    analysis). ``parse`` re-scores the stored answers under that definition
    (:mod:`lightemma.evaluation.rescore`); by default the run's recorded
    statuses stand (parsed ``paper`` for imported runs). Actions outside the
    plausibility limits are marked ``implausible`` and never scored, unless
    ``keep_implausible`` (:func:`lightemma.evaluation.outcomes.plausibility_for`).
    Corrupt lines, a truncated tail, records without usable ground truth,
    records of frames outside the run's frame set (``frame_ids.txt``: dropped)
    and an unfinished run are counted and described in ``warnings``. Raises
    :class:`RunStoreError` for a missing, unreadable or foreign directory.

    ``frames.jsonl`` stays the record of truth. Without ``parse``, the columns
    are read from the run's sidecar (:data:`SIDECAR_FILE`, NumPy ``.npz``) when it
    was made from the current ``frames.jsonl`` (same size, mtime, inode and last
    64 KiB), and the sidecar is (re)written otherwise; the numbers are the same
    either way. ``sidecar=False`` reads ``frames.jsonl`` and writes nothing.
    """
    run_dir = Path(run_dir)
    info = run_info(run_dir)
    own = recorded_parse(info.manifest)
    definition = own if parse is None else parse
    limits = plausibility_for(definition, keep_implausible=keep_implausible)
    recorded_set = read_frame_ids(run_dir)
    raw = None
    key = source_key(run_dir) if sidecar and parse is None else None
    if key is not None:
        raw = read_sidecar(run_dir, key)
    if raw is None:
        raw = _read_records(run_dir, parse)
        if key is not None and key_unchanged(run_dir, key):  # not appended to while it was read
            write_sidecar(run_dir, raw, key)
    return _assemble(info, raw, details=details, definition=definition, rescored_=parse is not None, limits=limits,
                     recorded_set=recorded_set)


def _assemble(info: RunInfo, raw: RawColumns, *, details: bool, definition: ParseDefinition, rescored_: bool,
              limits: Plausibility, recorded_set: list[str] | None) -> RunData:
    """:class:`RunData` from all records' columns: the frame set, usable ground truth, last record wins."""
    cols = raw.columns
    ids = raw.frame_ids
    gt_ok = cols["gt_ok"]
    foreign, foreign_example = 0, None
    if recorded_set is not None:
        allowed = set(recorded_set)
        in_set = np.fromiter((fid in allowed for fid in ids), dtype=bool, count=len(ids))
        foreign = int((~in_set).sum())  # not frames of this run: scoring them would mix frame sets
        if foreign:
            foreign_example = ids[int(np.argmin(in_set))]
        keep = in_set & gt_ok
        bad = int((in_set & ~gt_ok).sum())
    else:
        keep = gt_ok
        bad = int((~gt_ok).sum())
    if keep.all():
        frame_ids = list(ids)
        col = cols.__getitem__
    else:
        rows = np.flatnonzero(keep)
        frame_ids = [ids[i] for i in rows]

        def col(name: str) -> np.ndarray:
            return cols[name][rows]

    # scene codes in first-seen order over the kept records
    scene = col("scene")
    scene_names = raw.scene_names
    if len(scene):
        codes, first = np.unique(scene, return_index=True)
        by_first = codes[np.argsort(first)]
        if not np.array_equal(by_first, np.arange(len(raw.scene_names))):
            remap = np.empty(len(raw.scene_names), dtype=np.int32)
            remap[by_first] = np.arange(len(by_first), dtype=np.int32)
            scene = remap[scene]
            scene_names = [raw.scene_names[c] for c in by_first]
    else:
        scene_names = []
    unique = set(frame_ids)
    duplicates = len(frame_ids) - len(unique)
    del unique
    keep_all = duplicates == 0
    if not keep_all:  # last record wins, rows in first-seen order (the rare path: a --retry-failed pass)
        last: dict[str, int] = {}
        for row, fid in enumerate(frame_ids):
            last[fid] = row
        frame_ids = list(last)
        order = np.fromiter(last.values(), dtype=np.int64, count=len(last))

    def take(value: np.ndarray) -> np.ndarray:
        return value if keep_all else value[order]

    trajectory = col("trajectory")
    all_actions = col("actions")
    gate = implausible_actions(all_actions, limits)
    if details:
        actions = all_actions
    else:
        traj_none = col("traj_none") & np.isfinite(all_actions).any(axis=(1, 2))
        actions = np.where(traj_none[:, None, None], all_actions, np.nan) if traj_none.any() else None
    if actions is not None:
        trajectory = _fill_from_actions(trajectory, actions, info.integrator)
    trajectory = take(trajectory)
    gt = take(col("gt"))
    bad += int((~np.isfinite(gt).all(axis=(1, 2))).sum())
    status = take(col("status"))
    failure, caught = final_failure(take(col("failure")), status == STATUS_CODES["failed"], trajectory, take(gate), limits)
    data = RunData(
        info=info,
        frame_ids=frame_ids,
        trajectory=trajectory,
        gt_positions=gt,
        status=status,
        first_status=take(col("first")),
        seconds=take(col("seconds")),
        input_tokens=take(col("inp")),
        output_tokens=take(col("out")),
        cost_cents=take(col("cost")),
        cached_input_tokens=take(col("cached")),
        history_actions=take(col("history")) if details else None,
        actions=take(actions) if details else None,
        corrupt_lines=raw.corrupt_lines,
        corrupt_example=raw.corrupt_example,
        truncated_tail=raw.truncated_tail,
        duplicates=duplicates,
        bad_records=bad,
        parse=definition,
        rescored=rescored_,
        failure=failure,
        scene_index=take(scene),
        scene_names=scene_names,
        caught_implausible=int(caught.sum()),
        plausibility=limits,
        foreign_records=foreign,
        foreign_example=foreign_example,
        frame_set_size=len(recorded_set) if recorded_set is not None else None,
    )
    data.warnings = _warnings(data)
    return data


def _warnings(data: RunData) -> list[str]:
    """One line per problem met while loading: truncated tail, corrupt lines, unfinished run, …"""
    where = data.info.run_dir
    out = []
    if data.truncated_tail:
        out.append(f"{where}: ignored a truncated last line (the run was interrupted)")
    if data.corrupt_lines:
        out.append(f"{where}: skipped {data.corrupt_lines} corrupt line(s) of frames.jsonl"
                   + (f" ({data.corrupt_example})" if data.corrupt_example else ""))
    if data.bad_records:
        out.append(f"{where}: skipped {data.bad_records} record(s) without usable ground truth (gt_positions: 6 pairs of "
                   f"finite numbers within {MAX_POSITION_M:g} m)")
    if data.caught_implausible:
        lim = data.plausibility
        out.append(
            f"{where}: {data.caught_implausible} frame(s) answered outside the plausibility limits (speed {lim.min_speed:g} to "
            f"{lim.max_speed:g} m/s, |curvature| ≤ {lim.max_curvature:g} 1/m) without being marked; counted as implausible, not scored"
        )
    if data.foreign_records:
        out.append(f"{where}: dropped {data.foreign_records} record(s) whose frame id is not in the run's frame set "
                   f"(frame_ids.txt), e.g. {data.foreign_example!r}")
    if not data.info.complete:
        out.append(f"{where}: run still in progress or interrupted (no finished_at); evaluating the {len(data)} frame(s) finished so far")
    elif data.frame_set_size is not None and len(data) + data.bad_records < data.frame_set_size:
        missing = data.frame_set_size - len(data) - data.bad_records
        out.append(f"{where}: the run is marked finished but {missing} of its {data.frame_set_size} frame(s) have no record in "
                   f"frames.jsonl (lines lost?); evaluating the {len(data)} recorded; lightemma run --resume {where} runs the rest")
    if not data.frame_ids:
        out.append(f"{where}: no frames to evaluate")
    return out


def _fill_from_actions(trajectory: np.ndarray, actions: np.ndarray, method: str) -> np.ndarray:
    """Integrate actions (through the Rust core) for records that carry actions but no trajectory."""
    missing = ~np.isfinite(trajectory).all(axis=(1, 2)) & np.isfinite(actions).all(axis=(1, 2))
    if missing.any():
        from lightemma import integrate

        trajectory = trajectory.copy()
        trajectory[missing] = integrate(np.ascontiguousarray(actions[missing]), method=method)
    return trajectory


def read_frame_records(run_dir: str | os.PathLike[str], frame_ids: Iterable[str]) -> dict[str, dict[str, Any]]:
    """The full last record of each wanted frame (stage texts included), streaming the file."""
    wanted = set(frame_ids)
    found: dict[str, dict[str, Any]] = {}
    for record in iter_records(run_dir):
        if record["frame_id"] in wanted:
            found[record["frame_id"]] = record
    return found


def discover_runs(paths: Iterable[str | os.PathLike[str]]) -> tuple[list[Path], list[str]]:
    """The run directories named by ``paths`` (each a run directory or a folder holding runs), and warnings.

    Within a folder, a run whose manifest cannot be read is left out with a warning naming it and why (one corrupt
    manifest does not block the others), and so is a symbolic link to a folder holding runs (never followed: a link
    can lead anywhere, or in a circle; give the run by its own path to include it). A run directory named itself
    whose manifest cannot be read raises :class:`RunStoreError`, as does a path holding no run.
    """
    from lightemma._text import printable
    from lightemma.evaluation.core import expand_run_dirs
    from lightemma.runs.store import MANIFEST_FILE, find_run_dirs, read_manifest

    given = [Path(p) for p in paths]
    warnings: list[str] = []
    for path in given:
        if not path.is_dir() or (path / MANIFEST_FILE).is_file():
            continue
        for root, dirs, _files in os.walk(path):
            for name in sorted(dirs):
                link = Path(root) / name
                if link.is_symlink() and not name.startswith("."):
                    with suppress(OSError, RunStoreError):
                        held = find_run_dirs(link)
                        if held:
                            warnings.append(f"left out {printable(link)}: a symbolic link to {printable(os.readlink(link))} holding "
                                            f"{len(held)} run(s), not followed; give it by its own path to include it")
    found = expand_run_dirs(given)
    named = {Path(os.path.abspath(p)) for p in given if (p / MANIFEST_FILE).is_file()}
    dirs: list[Path] = []
    for run_dir in found:
        try:
            read_manifest(run_dir)
        except RunStoreError as exc:
            if Path(os.path.abspath(run_dir)) in named:
                raise
            warnings.append(f"left out {printable(run_dir)}: {printable(exc)}")
            continue
        dirs.append(run_dir)
    if not dirs:
        raise RunStoreError(f"no readable lightemma run in {', '.join(printable(p) for p in given)}: {warnings[-1]}")
    return dirs, warnings
