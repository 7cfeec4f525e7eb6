"""Load run directories into compact per-frame columns, streaming.

A run's ``frames.jsonl`` is read line by line (:func:`lightemma.runs.store.iter_records`);
each record is reduced at once to a few numbers (trajectory, ground truth,
statuses, time, tokens, cost), gathered in NumPy chunks, so memory holds
about 0.5 kB per frame and never the decoded records themselves. Stage
texts are fetched later, only for the frames a figure needs
(:func:`read_frame_records`).
"""

from __future__ import annotations

import gc
import itertools
import math
import os
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lightemma.errors import RunStoreError
from lightemma.evaluation.manifest import RunInfo, run_info
from lightemma.evaluation.outcomes import FAILURE_CODES, Plausibility, failure_code, final_failure, implausible_actions, outcome_counts, plausibility_for
from lightemma.evaluation.rescore import ParseDefinition, recorded_parse, rescored
from lightemma.runs.store import RunContents, iter_records, read_frame_ids
from lightemma.runs.records import answer_received, first_answer_status

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
    """Accumulates per-record values in lists and flushes them to NumPy chunks of :data:`_CHUNK` rows."""

    PAIRS = ("trajectory", "actions", "gt", "history")
    NAMES = (*PAIRS, "status", "first", "seconds", "inp", "out", "cost", "cached", "failure", "scene", "gate")
    DTYPES = {"status": np.int8, "first": np.int8, "failure": np.int8, "scene": np.int32, "gate": bool}

    def __init__(self, details: bool, limits: Plausibility) -> None:
        self.details = details
        self.limits = limits
        self.pending: dict[str, list[Any]] = {n: [] for n in self.NAMES}
        self.chunks: dict[str, list[np.ndarray]] = {n: [] for n in self.NAMES}
        self.rows = 0
        self.unintegrated: dict[int, Any] = {}  # row -> actions, for records lacking a trajectory
        self.scenes: dict[str, int] = {}

    def add(self, record: Mapping[str, Any], gt: list[Any]) -> None:
        p = self.pending
        trajectory = record.get("trajectory")
        p["trajectory"].append(_NAN6x2 if trajectory is None else trajectory)
        actions = record.get("actions")
        p["actions"].append(_NAN6x2 if actions is None else actions)  # judged against the limits at flush
        if self.details:
            history = record.get("history_actions")
            p["history"].append(_NAN6x2 if history is None else history)
        elif trajectory is None and actions is not None:
            self.unintegrated[self.rows] = actions
        scene = record.get("scene_name")
        if not isinstance(scene, str) or not scene:
            scene = record["frame_id"].rpartition("/")[0] or record["frame_id"]
        p["scene"].append(self.scenes.setdefault(scene, len(self.scenes)))
        failure = record.get("failure")
        if failure is None and record.get("status") == "failed" and not answer_received(record):
            failure = "api_error"  # a record older than `failure`: failed without ever receiving an answer
        p["failure"].append(failure_code(failure))
        p["gt"].append(gt)
        p["status"].append(STATUS_CODES.get(record.get("status"), UNKNOWN_STATUS))
        p["first"].append(STATUS_CODES.get(first_answer_status(record), UNKNOWN_STATUS) if answer_received(record)
                          else API_ERROR_STATUS)
        p["seconds"].append(_number(record.get("seconds")))
        p["inp"].append(_number(record.get("input_tokens")))
        p["out"].append(_number(record.get("output_tokens")))
        p["cost"].append(_number(record.get("cost_cents")))
        p["cached"].append(_number(record.get("cached_input_tokens")))
        self.rows += 1
        if len(p["status"]) >= _CHUNK:
            self.flush()

    def flush(self) -> None:
        for name, values in self.pending.items():
            if values:
                if name in self.PAIRS:
                    chunk = pairs_array(values)
                else:
                    chunk = np.asarray(values, dtype=self.DTYPES.get(name, np.float64))
                if name == "actions":
                    self.chunks["gate"].append(implausible_actions(chunk, self.limits))
                    if not self.details:
                        values.clear()
                        continue  # only the verdict is kept
                self.chunks[name].append(chunk)
                values.clear()

    def column(self, name: str, shape: tuple[int, ...]) -> np.ndarray:
        self.flush()
        parts = self.chunks.pop(name)
        dtype = self.DTYPES.get(name, np.float64)
        return np.concatenate(parts) if parts else np.empty((0, *shape), dtype=dtype)


@contextmanager
def _gc_paused() -> Iterator[None]:
    """Pause the cyclic garbage collector (restoring its previous state afterwards)."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def load_run(run_dir: str | os.PathLike[str], *, details: bool = False, parse: ParseDefinition | None = None,
             keep_implausible: bool = False) -> RunData:
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
    """
    run_dir = Path(run_dir)
    info = run_info(run_dir)
    own = recorded_parse(info.manifest)
    definition = own if parse is None else parse
    counts = RunContents(run_dir=run_dir, manifest=dict(info.manifest), records={})
    limits = plausibility_for(definition, keep_implausible=keep_implausible)
    columns = _Columns(details, limits)
    recorded_set = read_frame_ids(run_dir)
    allowed = set(recorded_set) if recorded_set is not None else None
    seen: set[str] = set()
    frame_ids: list[str] = []  # one per kept record, in file order (duplicates included)
    bad = duplicates = foreign = 0
    foreign_example = None
    try:
        with _gc_paused():  # decoded records hold no cycles; collecting while streaming only costs time
            records = iter_records(run_dir, counts=counts)
            for record in records if parse is None else rescored(records, definition):
                fid = record["frame_id"]
                if allowed is not None and fid not in allowed:
                    foreign += 1  # not a frame of this run: scoring it would mix frame sets
                    foreign_example = foreign_example or fid
                    continue
                gt = record.get("gt_positions")
                if type(gt) is not list or len(gt) != 6:
                    bad += 1  # deeper damage (a bad pair) shows as NaN ground truth below
                    continue
                if fid in seen:
                    duplicates += 1
                else:
                    seen.add(fid)
                frame_ids.append(fid)
                columns.add(record, gt)
    except OSError as exc:
        raise RunStoreError(f"{run_dir}: cannot read frames: {exc}") from None
    del seen
    keep_all = duplicates == 0
    if not keep_all:  # last record wins, rows in first-seen order (the rare path: a --retry-failed pass)
        last: dict[str, int] = {}
        for row, fid in enumerate(frame_ids):
            last[fid] = row
        frame_ids = list(last)
        order = np.fromiter(last.values(), dtype=np.int64, count=len(last))

    def take(name: str, shape: tuple[int, ...]) -> np.ndarray:
        col = columns.column(name, shape)
        return col if keep_all else col[order]

    trajectory = columns.column("trajectory", (6, 2))
    if details:
        actions = columns.column("actions", (6, 2))
    elif columns.unintegrated:
        actions = np.full((len(trajectory), 6, 2), np.nan)
        actions[list(columns.unintegrated)] = pairs_array(list(columns.unintegrated.values()))
    else:
        actions = None
    if actions is not None:
        trajectory = _fill_from_actions(trajectory, actions, info.integrator)
    if not keep_all:
        trajectory = trajectory[order]
        actions = actions[order] if details else None
    gt = take("gt", (6, 2))
    bad += int((~np.isfinite(gt).all(axis=(1, 2))).sum())
    status = take("status", ())
    failure, caught = final_failure(take("failure", ()), status == STATUS_CODES["failed"], trajectory, take("gate", ()), limits)
    data = RunData(
        info=info,
        frame_ids=frame_ids,
        trajectory=trajectory,
        gt_positions=gt,
        status=status,
        first_status=take("first", ()),
        seconds=take("seconds", ()),
        input_tokens=take("inp", ()),
        output_tokens=take("out", ()),
        cost_cents=take("cost", ()),
        cached_input_tokens=take("cached", ()),
        history_actions=take("history", (6, 2)) if details else None,
        actions=actions if details else None,
        corrupt_lines=len(counts.corrupt_lines),
        truncated_tail=counts.truncated_tail,
        duplicates=duplicates,
        bad_records=bad,
        parse=definition,
        rescored=parse is not None,
        failure=failure,
        scene_index=take("scene", ()),
        scene_names=list(columns.scenes),
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
        out.append(f"{where}: skipped {data.corrupt_lines} corrupt line(s) of frames.jsonl")
    if data.bad_records:
        out.append(f"{where}: skipped {data.bad_records} record(s) without usable ground truth (gt_positions)")
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
