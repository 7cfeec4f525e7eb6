"""Load run directories into compact per-frame columns, streaming.

A run's ``frames.jsonl`` is read line by line (:func:`lightemma.runs.store.iter_records`);
each record is reduced at once to a few numbers (trajectory, ground truth,
statuses, time, tokens, cost), gathered in NumPy chunks, so memory holds
about 0.5 kB per frame and never the decoded records themselves. Stage
texts are fetched later, only for the frames a figure needs
(:func:`read_frame_records`).
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from contextlib import suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lightemma._text import printable
from lightemma.definitions import OUTCOME_CODES, STATUS_CODES
from lightemma.errors import RunStoreError
from lightemma.evaluation.manifest import RunInfo, run_info
from lightemma.evaluation.outcomes import (
    Plausibility,
    final_failure,
    implausible_actions,
    outcome_counts,
    plausibility_for,
)
from lightemma.evaluation.rescore import ParseDefinition, recorded_parse, rescored
from lightemma.kinematics import integrate
from lightemma.runs.columns import RawColumns, key_unchanged, read_columns, read_sidecar, source_key, write_sidecar
from lightemma.runs.records import MAX_POSITION_M
from lightemma.runs.store import MANIFEST_FILE, find_run_dirs, iter_records, read_frame_ids, read_manifest


@dataclass
class RunData:
    """The frames of one run as columns (rows in first-seen frame order, last record wins)."""

    info: RunInfo
    frame_ids: list[str]
    trajectory: np.ndarray  # (N, 6, 2), NaN where the run has no valid prediction
    gt_positions: np.ndarray  # (N, 6, 2)
    status: np.ndarray  # (N,) int8: 0 ok, 1 corrected, 2 failed, -1 unknown
    first_status: (
        np.ndarray
    )  # (N,) int8: status of the first received answer; -2 none received (API errors), -1 unknown
    seconds: np.ndarray  # (N,) float64, NaN unknown
    input_tokens: np.ndarray
    output_tokens: np.ndarray
    cost_cents: np.ndarray
    cached_input_tokens: np.ndarray | None = (
        None  # (N,) float64 of input_tokens served from a prompt cache, NaN unknown
    )
    history_actions: np.ndarray | None = None  # (N, 6, 2) with details=True
    actions: np.ndarray | None = None  # (N, 6, 2) predicted, with details=True
    failure: np.ndarray | None = (
        None  # (N,) int8 outcome code (definitions.OUTCOMES): why a frame is not scored (0: it is)
    )
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
        failure = (
            self.failure
            if self.failure is not None
            else np.where(self.status == STATUS_CODES["failed"], OUTCOME_CODES["format"], 0)
        )
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


def _read_records(run_dir: Path, parse: ParseDefinition | None) -> RawColumns:
    """Stream ``frames.jsonl`` into :class:`~lightemma.runs.columns.RawColumns` (re-parsed under ``parse`` when given)."""
    return read_columns(run_dir, None if parse is None else (lambda records: rescored(records, parse)))


def load_run(
    run_dir: str | os.PathLike[str],
    *,
    details: bool = False,
    parse: ParseDefinition | None = None,
    keep_implausible: bool = False,
    sidecar: bool = True,
) -> RunData:
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
    return _assemble(
        info,
        raw,
        details=details,
        definition=definition,
        rescored_=parse is not None,
        limits=limits,
        recorded_set=recorded_set,
    )


def _assemble(
    info: RunInfo,
    raw: RawColumns,
    *,
    details: bool,
    definition: ParseDefinition,
    rescored_: bool,
    limits: Plausibility,
    recorded_set: list[str] | None,
) -> RunData:
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
    actions: np.ndarray | None
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
    failure, caught = final_failure(
        take(col("failure")), status == STATUS_CODES["failed"], trajectory, take(gate), limits
    )
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
        actions=take(all_actions) if details else None,  # actions is all_actions with details
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
        out.append(
            f"{where}: skipped {data.corrupt_lines} corrupt line(s) of frames.jsonl"
            + (f" ({data.corrupt_example})" if data.corrupt_example else "")
        )
    if data.bad_records:
        out.append(
            f"{where}: skipped {data.bad_records} record(s) without usable ground truth (gt_positions: 6 pairs of "
            f"finite numbers within {MAX_POSITION_M:g} m)"
        )
    if data.caught_implausible:
        lim = data.plausibility
        out.append(
            f"{where}: {data.caught_implausible} frame(s) answered outside the plausibility limits (speed {lim.min_speed:g} to "
            f"{lim.max_speed:g} m/s, |curvature| ≤ {lim.max_curvature:g} 1/m) without being marked; counted as implausible, not scored"
        )
    if data.foreign_records:
        out.append(
            f"{where}: dropped {data.foreign_records} record(s) whose frame id is not in the run's frame set "
            f"(frame_ids.txt), e.g. {data.foreign_example!r}"
        )
    if not data.info.complete:
        out.append(
            f"{where}: run still in progress or interrupted (no finished_at); evaluating the {len(data)} frame(s) finished so far"
        )
    elif data.frame_set_size is not None and len(data) + data.bad_records < data.frame_set_size:
        missing = data.frame_set_size - len(data) - data.bad_records
        out.append(
            f"{where}: the run is marked finished but {missing} of its {data.frame_set_size} frame(s) have no record in "
            f"frames.jsonl (lines lost?); evaluating the {len(data)} recorded; lightemma run --resume {where} runs the rest"
        )
    if not data.frame_ids:
        out.append(f"{where}: no frames to evaluate")
    return out


def _fill_from_actions(trajectory: np.ndarray, actions: np.ndarray, method: str) -> np.ndarray:
    """Integrate actions (through the Rust core) for records that carry actions but no trajectory."""
    missing = ~np.isfinite(trajectory).all(axis=(1, 2)) & np.isfinite(actions).all(axis=(1, 2))
    if missing.any():
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
    from lightemma.evaluation.core import expand_run_dirs

    given = [Path(p) for p in paths]
    warnings: list[str] = []
    for path in given:
        if not path.is_dir() or (path / MANIFEST_FILE).is_file():
            continue
        for root, subdirs, _files in os.walk(path):
            for name in sorted(subdirs):
                link = Path(root) / name
                if link.is_symlink() and not name.startswith("."):
                    with suppress(OSError, RunStoreError):
                        held = find_run_dirs(link)
                        if held:
                            warnings.append(
                                f"left out {printable(link)}: a symbolic link to {printable(os.readlink(link))} holding "
                                f"{len(held)} run(s), not followed; give it by its own path to include it"
                            )
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
