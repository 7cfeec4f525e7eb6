"""The planning score of evaluated runs: NAVSIM's PDMS / EPDMS and sub-scores (docs/definitions.md#planning-score).

This module assembles, per nuScenes version and map, what the kernels of :mod:`lightemma.planning` need and calls
them once per batch for every run together:

* from the dataroot (read by :func:`lightemma.evaluation.safety.load_safety_data`, no second reader): each keyframe's
  CAM_FRONT ego pose, the poses of its four earlier and six later keyframes, the annotated agents of the present and
  the six later keyframes (tracked by instance; static objects — barriers, cones, … — among them as NAVSIM's
  ``StaticObject``: :func:`lightemma.evaluation.safety.static_object`), and the map layers (:func:`lightemma.planning.scores.read_planning_map`
  for a map expansion, the base map mask otherwise);
* per frame: the initial ego state and the recorded past (:func:`~lightemma.planning.simulation.initial_state`,
  :func:`~lightemma.planning.simulation.history_states`) from the earlier keyframes' poses and timestamps; the
  ground truth's poses (positions and headings of the six later keyframes) simulated from that state like a plan;
* per run: each scored frame's plan (its actions integrated with headings, :func:`plan_poses`), simulated
  (:func:`simulate`), its comfort ``c``, history comfort ``hc``, extended comfort ``ec`` against the same run's plan
  of the previous keyframe, then :func:`~lightemma.planning.scores.drive_scores` for the sub-scores and aggregates.

The ground truth's own row ("Ground truth (human)") is the ground truth scored by the same code as a plan, on every
frame any run is evaluated on. A value that cannot be decided is n/a with its reason (counted and named in the
warnings), never a traceback and never a silent 0 or 1.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lightemma.errors import DatasetError

#: the JSON / row keys of the planning score, aggregates first (values are means in [0, 1])
KEYS: tuple[str, ...] = ("pdms", "epdms", "epdms_map", "nc", "dac", "ddc", "tlc", "ep", "ttc", "lk", "c", "hc", "ec")
AGGREGATE_KEYS: tuple[str, ...] = ("pdms", "epdms", "epdms_map")
#: every key a planning row has: ``<key>``, ``<key>_ci95``, ``<key>_na`` per key, and the frame counts
ROW_KEYS: tuple[str, ...] = (
    *KEYS,
    *(f"{k}_ci95" for k in KEYS),
    *(f"{k}_na" for k in KEYS),
    "planning_frames",
    "planning_map",
    "map_version",
)
GT_LABEL = "Ground truth (human)"
#: earlier keyframes read per frame: 2 for the initial state, 4 for the 1.5 s of recorded past of history comfort
HISTORY_KEYFRAMES = 4
STEPS = 6
#: a run's recorded ground truth further than this from the dataroot's later poses is another dataset: n/a (m)
GT_TOLERANCE_M = 1.0
#: a run's trajectory further than this from the integration of its own actions: the two readings disagree (m)
TRAJECTORY_TOLERANCE_M = 1e-3
#: frames per call of the sub-score kernel (bounds the (frames, 31, agents, 8) box array)
CHUNK_FRAMES = 512
_NO_DATAROOT = "no dataroot (pass --dataroot and --version)"
#: reasons that are not worth a warning: said in every table (tlc) or the other aggregate is the score
_QUIET = (
    "nuScenes has no traffic-light states",
    "annotations given: the score is epdms",
    "no annotations (agents' boxes) for this version: see epdms_map",
)


@dataclass
class RunPlanning:
    """One run's planning outcomes on its scored frames.

    ``values[key]`` (n,) float64 with NaN where n/a and ``reasons[key]`` (n,) the sentence where n/a, for every key of
    :data:`KEYS`; ``states`` (n, 31, 11) the simulated plans in the global frame (NaN where not simulated), for figures
    and the frame browser; ``reason``: why the run has nothing at all (no dataroot, unreadable dataset)."""

    frame_ids: list[str]
    rows: np.ndarray
    values: dict[str, np.ndarray] = field(default_factory=dict)
    reasons: dict[str, list[str | None]] = field(default_factory=dict)
    states: np.ndarray | None = None
    reason: str | None = None
    map_kinds: list[str] = field(default_factory=list)  # drivable area behind the values: expansion, mask
    #: map key (``expansion:<location>``) -> the map expansion's version behind the values (safety.DrivableArea.version)
    map_versions: dict[str, str] = field(default_factory=dict)
    path: np.ndarray | None = (
        None  # (n, 31, 2) the simulated plans' x, y in their keyframes' ego frames (m), NaN where none
    )


@dataclass
class PlanningResult:
    """Per model label its planning row (:data:`ROW_KEYS`), the ground truth's row, per-frame outcomes, warnings;
    ``headline``: the aggregate the table leads with and ``--pairwise`` compares (``epdms`` with annotations,
    ``epdms_map`` without, ``pdms`` when neither has a value)."""

    rows: dict[str, dict[str, Any]]
    ground_truth: dict[str, Any] | None
    runs: dict[str, RunPlanning]
    warnings: list[str] = field(default_factory=list)
    headline: str = "epdms"
    pairwise: list[dict[str, Any]] | None = None

    @property
    def shown(self) -> bool:
        """Whether the tables show the score: some run was read against a dataset, or some dataset could not be read
        (its n/a reason is news); runs without any dataroot give no table (their rows only say so)."""
        return self.ground_truth is not None or any(
            rp.reason not in (None, _NO_DATAROOT) and not rp.values for rp in self.runs.values()
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-able: the headline aggregate, each model's row (by label) and the ground truth's row."""
        return {"headline": self.headline, "rows": self.rows, "ground_truth": self.ground_truth}


# -- per-frame inputs from the dataroot ----------------------------------------------------------------------------


def _wrap(angle: np.ndarray) -> np.ndarray:
    return (angle + np.pi) % (2 * np.pi) - np.pi


@dataclass
class _Frames:
    """The scene frames of one dataset: per frame (F) its inputs in its keyframe's ego frame, or why not."""

    tokens: list[str]
    pose: np.ndarray  # (F, 3) global x, y, yaw of the keyframe
    history: np.ndarray  # (F, 5, 2) positions at -2.0 … 0 s, NaN where there is no earlier keyframe
    gt_poses: np.ndarray  # (F, 6, 3) the later keyframes' x, y, heading
    reason: list[str | None]  # why the frame has no pose, no initial state or no ground truth
    init: np.ndarray  # (F, 11)
    past: np.ndarray  # (F, 14, 11) recorded past for hc
    past_reason: list[str | None]
    prev: list[str | None]  # the previous keyframe's token
    interval: np.ndarray  # (F,) seconds since the previous keyframe (NaN unknown)


def _can(data: Any, tokens: list[str], scenes: list[str]) -> tuple[np.ndarray | None, dict[int, str]]:
    """CAN bus readings (F, 4) of the frames (NaN rows where none; ``None`` without the dataroot's ``can_bus`` folder)
    and per frame why its scene's file cannot be read (those frames get no initial state: never a silent fall-back)."""
    from lightemma.nuscenes.can_bus import can_bus_folder, can_readings

    if can_bus_folder(data.dataroot) is None:
        return None, {}
    out = np.full((len(tokens), 4), np.nan)
    broken: dict[int, str] = {}
    by_scene: dict[str, list[int]] = {}
    for i, (tok, scene) in enumerate(zip(tokens, scenes)):
        if tok in data.timestamps:
            by_scene.setdefault(scene, []).append(i)
    for scene, rows in by_scene.items():
        try:
            got = can_readings(data.dataroot, [scene] * len(rows), [data.timestamps[tokens[i]] for i in rows])
        except DatasetError as exc:
            for i in rows:
                broken[i] = f"the CAN bus readings cannot be read: {exc}"
            continue
        if got is not None:
            out[rows] = got.values
    return out, broken


def _frames(data: Any, tokens: list[str], scenes: list[str]) -> _Frames:
    from lightemma.nuscenes.geometry import to_ego_frame
    from lightemma.planning.simulation import history_states, initial_state

    f = len(tokens)
    pose = np.full((f, 3), np.nan)
    hist = np.full((f, HISTORY_KEYFRAMES + 1, 2), np.nan)
    hist_t = np.full((f, HISTORY_KEYFRAMES + 1), np.nan)  # the history keyframes' timestamps, s
    gt = np.full((f, STEPS, 3), np.nan)
    reason: list[str | None] = [None] * f
    past_reason: list[str | None] = [None] * f
    prev: list[str | None] = [None] * f
    interval = np.full(f, np.nan)
    for i, tok in enumerate(tokens):
        if tok not in data.poses:
            why = data.pose_reasons.get(tok)
            reason[i] = (
                f"unusable CAM_FRONT ego pose: {why}"
                if why
                else f"no CAM_FRONT ego pose for sample {tok} in {data.version}"
            )
            continue
        pose[i] = data.poses[tok]
        earlier = []
        for p in data.past.get(tok, []):
            if p not in data.poses:
                break
            earlier.append(data.poses[p])
        chain = data.past.get(tok, [])
        prev[i] = chain[0] if chain else None
        if prev[i] is not None and tok in data.timestamps and prev[i] in data.timestamps:
            interval[i] = (data.timestamps[tok] - data.timestamps[prev[i]]) / 1e6
        pts = np.array([data.poses[tok][:2]] + [e[:2] for e in earlier], dtype=np.float64)[::-1]  # oldest first
        local = to_ego_frame(pts[None], pose[i, None, :2], pose[i, 2:3])[0]
        hist[i, -len(local) :] = local
        hist[i, -1] = 0.0  # exactly the origin
        stamps = [data.timestamps.get(k, np.nan) for k in [tok, *data.past.get(tok, [])[: len(earlier)]]]
        hist_t[i, -len(local) :] = np.array(stamps, dtype=np.float64)[::-1] / 1e6  # oldest first, as pts
        if len(earlier) < 2:
            reason[i] = (
                f"sample {tok} has {len(earlier)} earlier keyframe(s) with a pose; the initial ego state "
                "needs 2 (the first second of a scene)"
            )
        elif len(earlier) < HISTORY_KEYFRAMES:
            past_reason[i] = (
                f"sample {tok} has {len(earlier)} earlier keyframe(s) with a pose; history comfort needs "
                f"{HISTORY_KEYFRAMES} (1.5 s of recorded past)"
            )
        later = [t for t in data.future.get(tok, []) if t in data.poses]
        if len(later) < STEPS:
            reason[i] = reason[i] or (
                f"sample {tok} has {len(later)} later keyframe(s) with a pose; the ground truth needs {STEPS}"
            )
            continue
        fut = np.array([data.poses[t] for t in later[:STEPS]], dtype=np.float64)
        gt[i, :, :2] = to_ego_frame(fut[None, :, :2], pose[i, None, :2], pose[i, 2:3])[0]
        gt[i, :, 2] = _wrap(fut[:, 2] - pose[i, 2])
    can, broken = _can(data, tokens, scenes)
    # the keyframes' real spacing (0.47–0.52 s); the CAN bus replaces the derived speed, accelerations and yaw rate
    init = initial_state(hist, can=can, times=hist_t)
    states = init.states.copy()
    for i, why in broken.items():
        reason[i] = reason[i] or why
    for i, why in enumerate(init.reasons):
        if why is not None and reason[i] is None:
            reason[i] = f"no initial ego state: {why.split(': ', 1)[-1]}"
    past = history_states(hist, times=hist_t)
    for i, why in enumerate(past.reasons):
        if why is not None and past_reason[i] is None:
            past_reason[i] = reason[i] or f"no recorded past: {why.split(': ', 1)[-1]}"
    for i, why in enumerate(reason):
        if why is not None:
            states[i] = np.nan
    return _Frames(tokens, pose, hist, gt, reason, states, past.states, past_reason, prev, interval)


def _to_global(states: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """States (N, S, 11) in their keyframes' ego frames → the global frame (x, y rotated and moved, heading turned;
    velocities and accelerations are in the body frame and stay)."""
    out = states.copy()
    c, s = np.cos(pose[:, 2])[:, None], np.sin(pose[:, 2])[:, None]
    x, y = states[..., 0], states[..., 1]
    out[..., 0] = pose[:, 0:1] + c * x - s * y
    out[..., 1] = pose[:, 1:2] + s * x + c * y
    out[..., 2] = _wrap(states[..., 2] + pose[:, 2:3])
    return out


def _instance_codes(data: Any, sample: str, cache: dict[str, np.ndarray], ids: dict[str, int]) -> np.ndarray:
    """(K,) int64 code of each box's instance in :func:`_keyframe_boxes` (one code per instance token of the
    dataset)."""
    codes = cache.get(sample)
    if codes is None:
        insts = [*data.box_instances.get(sample, []), *getattr(data, "object_instances", {}).get(sample, [])]
        codes = np.array([ids.setdefault(inst, len(ids)) for inst in insts], dtype=np.int64)
        cache[sample] = codes
    return codes


_NO_BOXES = np.zeros((0, 5))


def _keyframe_boxes(data: Any, sample: str) -> tuple[np.ndarray, np.ndarray]:
    """A keyframe's boxes (K, 5): its agents (vehicles, pedestrians, cyclists: kind 0), then its static objects
    (``data.objects``: barriers, cones, …: kind 1, NAVSIM's ``StaticObject``), and their kinds (K,)."""
    agents = data.boxes.get(sample, _NO_BOXES)
    objects = getattr(data, "objects", {}).get(sample, _NO_BOXES)
    kinds = np.concatenate([np.zeros(len(agents)), np.ones(len(objects))])
    return (np.concatenate([agents, objects]) if len(objects) else agents), kinds


def _agents(
    data: Any, tokens: list[str], idx: np.ndarray, cache: dict[str, np.ndarray], ids: dict[str, int]
) -> tuple[np.ndarray, dict[int, str]]:
    """Boxes (len(idx), 7, A, 8) of the frames ``idx`` at their keyframe and the six later ones, tracked by instance
    (one slot per instance), with velocities from the track's neighbouring keyframes, the keyframe before included
    (central difference where both exist, else one-sided; NaN — a degenerate box, n/a — for a track seen at one
    keyframe only); and per frame (row of ``idx``) why its agents cannot be used (a refused annotation)."""
    bad: dict[int, str] = {}
    per_frame: list[np.ndarray | None] = []
    for r, i in enumerate(idx.tolist()):
        tok = tokens[i]
        keys = [tok, *data.future.get(tok, [])[:STEPS]]
        bad_objects = getattr(data, "bad_objects", {})
        refused = next(
            (
                data.bad_boxes[k] if k in data.bad_boxes else bad_objects[k]
                for k in keys
                if k in data.bad_boxes or k in bad_objects
            ),
            None,
        )
        if refused is not None:
            bad[r] = f"a refused annotation: {refused}"
        if len(keys) < STEPS + 1:
            per_frame.append(None)
            continue
        prev = data.past.get(tok, [])
        chain = ([prev[0]] if prev else []) + keys
        first = 1 if prev else 0
        codes = [_instance_codes(data, k, cache, ids) for k in chain]
        boxes, kinds = zip(*(_keyframe_boxes(data, k) for k in chain), strict=True)
        window = np.unique(np.concatenate(codes[first:]))  # the instances seen at the keyframe or later
        t, a = len(chain), len(window)
        centres = np.full((t, a, 2), np.nan)
        out = np.full((STEPS + 1, a, 8), np.nan)
        static = np.zeros(a, dtype=bool)
        for j, (c, b, kd) in enumerate(zip(codes, boxes, kinds, strict=True)):
            pos = np.searchsorted(window, c)
            ok = pos < a
            ok[ok] = window[pos[ok]] == c[ok]
            centres[j, pos[ok]] = b[ok, :2]
            static[pos[ok]] |= kd[ok] == 1.0
            if j >= first:
                out[j - first, pos[ok], :5] = b[ok]
                out[j - first, pos[ok], 7] = kd[ok]  # 0: vehicle / pedestrian / bicycle, 1: a static object
        times = np.array([data.timestamps.get(k, np.nan) for k in chain]) / 1e6
        seen = np.isfinite(centres[..., 0])  # (t, a)
        before = np.zeros_like(seen)
        before[1:] = seen[:-1]
        after = np.zeros_like(seen)
        after[:-1] = seen[1:]
        step = np.arange(t)[:, None]
        lo, hi = np.where(before, step - 1, step), np.where(after, step + 1, step)
        slot = np.arange(a)[None, :]
        dt = times[hi] - times[lo]
        with np.errstate(invalid="ignore", divide="ignore"):
            velocity = (centres[hi, slot] - centres[lo, slot]) / dt[..., None]
        velocity[~(seen & (hi > lo) & np.isfinite(dt) & (dt > 0))] = np.nan
        velocity[:, static] = np.where(seen[:, static, None], 0.0, np.nan)  # NAVSIM's static objects have no velocity
        out[..., 5:7] = velocity[first:]
        per_frame.append(out)
    slots = max([1, *(b.shape[1] for b in per_frame if b is not None)])
    result = np.full((len(idx), STEPS + 1, slots + (1 if bad else 0), 8), np.nan)
    for r, b in enumerate(per_frame):
        if b is not None:
            result[r, :, : b.shape[1]] = b
    for r in bad:  # a refused annotation: a degenerate box in a slot of its own makes nc and ttc n/a (reason below)
        result[r, 0, slots] = [0.0, 0.0, 0.0, np.nan, np.nan, 0.0, 0.0, 0.0]
    return result, bad


# -- one dataset: all runs together ----------------------------------------------------------------------------------


@dataclass
class _Plans:
    """Every run's plans on one dataset, concatenated: the frame of each plan and its simulated states."""

    run: list[int]
    row: list[int]
    frame: np.ndarray
    states: np.ndarray  # (N, 31, 11) ego frame
    reason: list[str | None]


def _plan_actions(run: Any, rows: np.ndarray) -> tuple[np.ndarray | None, str | None]:
    """The actions (len(rows), 6, 2) of a run's rows: its loaded ones, or read again with ``details`` when the run was
    loaded without them; None and why when the run holds none."""
    actions = getattr(run, "actions", None)
    if actions is None:
        from lightemma.evaluation.loading import load_run

        try:
            again = load_run(run.info.run_dir, details=True, parse=run.parse if run.rescored else None)
        except Exception as exc:  # a run that cannot be read again: n/a, said
            return None, f"the run's actions cannot be read ({type(exc).__name__}: {exc})"
        index = again.index()
        actions = np.full((len(run), STEPS, 2), np.nan)
        for j, fid in enumerate(run.frame_ids):
            k = index.get(fid)
            if k is not None and again.actions is not None:
                actions[j] = again.actions[k]
    return np.asarray(actions, dtype=np.float64)[rows], None


def _plans(
    entries: Sequence[tuple[str, Any, np.ndarray]],
    members: list[int],
    frames: _Frames,
    position: dict[str, int],
    data: Any,
) -> _Plans:
    from lightemma.evaluation.safety import _recorded_pose_conflicts
    from lightemma.planning.simulation import plan_poses, simulate

    runs, rows, fr, poses, reasons = [], [], [], [], []
    for m in members:
        label, run, scored = entries[m]
        actions, why = _plan_actions(run, scored)
        conflicts: dict[int, str] = {}
        if getattr(run.info, "imported", False):  # its recorded poses against the dataroot's (the safety columns' rule)
            fids = [run.frame_ids[r] for r in scored.tolist()]
            conflicts = _recorded_pose_conflicts(run, fids, [f.rsplit("/", 1)[-1] for f in fids], data, [], label)
        integrator = getattr(run.info, "integrator", "euler") or "euler"
        if actions is None:
            p = np.full((len(scored), STEPS, 3), np.nan)
        else:
            finite = np.isfinite(actions).all(axis=(1, 2))
            p = np.full((len(scored), STEPS, 3), np.nan)
            if finite.any():
                p[finite] = plan_poses(actions[finite], method=integrator)
        for j, r in enumerate(scored.tolist()):
            fid = run.frame_ids[r]
            f = position[fid.rsplit("/", 1)[-1]]
            runs.append(m)
            rows.append(j)
            fr.append(f)
            poses.append(p[j])
            reason = frames.reason[f] or conflicts.get(j)
            if reason is None:
                if actions is None:
                    reason = why or "the run holds no actions"
                elif not np.isfinite(actions[j]).all():
                    reason = "the plan's actions hold a NaN or infinity"
                else:
                    traj = np.asarray(run.trajectory[r], dtype=np.float64)
                    gap = float(np.max(np.abs(traj - p[j, :, :2]))) if np.isfinite(traj).all() else math.inf
                    gt_gap = float(np.max(np.abs(np.asarray(run.gt_positions[r]) - frames.gt_poses[f, :, :2])))
                    if not gap <= TRAJECTORY_TOLERANCE_M:
                        reason = (
                            f"the run's trajectory is {gap:.3g} m from the integration of its actions "
                            f"({integrator}): two readings of the plan disagree"
                        )
                    elif not gt_gap <= GT_TOLERANCE_M:
                        reason = (
                            f"the run's ground truth is {gt_gap:.3g} m from the dataroot's later poses of sample "
                            f"{fid.rsplit('/', 1)[-1]} (is the dataroot the dataset the run was made on?)"
                        )
            reasons.append(reason)
    n = len(runs)
    frame = np.asarray(fr, dtype=np.int64)
    pose_arr = np.asarray(poses, dtype=np.float64).reshape(n, STEPS, 3)
    bad = np.array([r is not None for r in reasons], dtype=bool)
    pose_arr[bad] = np.nan
    states = simulate(pose_arr, frames.init[frame]) if n else np.zeros((0, 31, 11))
    return _Plans(runs, rows, frame, states, reasons)


def _comforts(
    states: np.ndarray, frame: np.ndarray, frames: _Frames, prev_row: list[int | None], first_reason: list[str | None]
) -> dict[str, tuple[np.ndarray, list[str | None]]]:
    """c, hc, ec of plans (ego frame states) with reasons; ``prev_row[i]``: the row of the plan of the same run at the
    previous keyframe, or None (``first_reason[i]`` says why)."""
    from lightemma.planning.simulation import MAX_INTERVAL, comfort, extended_comfort, history_comfort

    n = len(states)
    c = comfort(states) if n else np.zeros(0)
    hc = history_comfort(frames.past[frame], states).comfortable if n else np.zeros(0)
    hc_reason: list[str | None] = [None] * n
    for i, f in enumerate(frame.tolist()):
        if frames.past_reason[f] is not None:
            hc[i] = np.nan
            hc_reason[i] = frames.past_reason[f]
    ec = np.full(n, np.nan)
    ec_reason: list[str | None] = list(first_reason)
    pairs = []
    for i, p in enumerate(prev_row):
        if p is None:
            continue
        gap = frames.interval[frame[i]]
        if not (np.isfinite(gap) and 0.0 < gap < MAX_INTERVAL and round(gap / 0.1) == 5):
            ec_reason[i] = f"the previous keyframe is {gap:.3f} s earlier; extended comfort compares plans 0.5 s apart"
            continue
        pairs.append((i, p))
    if pairs:
        now = np.stack([states[i] for i, _ in pairs])
        before = np.stack([states[p] for _, p in pairs])
        value = extended_comfort(now, before)
        for (i, _), v in zip(pairs, value.tolist()):
            ec[i] = v
    out: dict[str, tuple[np.ndarray, list[str | None]]] = {
        "c": (c, [None] * n),
        "hc": (hc, hc_reason),
        "ec": (ec, ec_reason),
    }
    for v, why in out.values():
        for i in np.flatnonzero(~np.isfinite(v)).tolist():
            if why[i] is None:
                why[i] = "the plan's simulated states hold a NaN or infinity"
    return out


def _planning_map(area: Any, cache: dict[str, Any]) -> tuple[Any, str | None]:
    """The PlanningMap of a frame's drivable area record (a DrivableArea or the reason there is none)."""
    from lightemma.evaluation.safety import DrivableArea
    from lightemma.planning.scores import DrivableMask, PlanningMap, read_planning_map

    if not isinstance(area, DrivableArea):
        return PlanningMap(), f"no drivable area: {area}"
    if area.source in cache:
        return cache[area.source]
    found: tuple[PlanningMap, str | None]
    if area.kind == "mask":
        assert area.mask is not None  # a mask area holds its mask (read_map_mask)
        found = (PlanningMap(drivable=DrivableMask(area.mask)), None)
    else:
        try:
            found = (read_planning_map(area.source), None)
        except DatasetError as exc:
            found = (PlanningMap(), f"map layers cannot be read: {exc}")
    cache[area.source] = found
    return found


_KERNEL_BOX = re.compile(r"frame \d+ has a degenerate agent box \(step (\d+), slot (\d+)[^)]*\)")


def _score_dataset(
    data: Any, entries: Sequence[tuple[str, Any, np.ndarray]], members: list[int], ego: Any, map_cache: dict[str, Any]
) -> tuple[dict[int, RunPlanning], dict[str, Any]]:
    """Score every run of ``members`` on one dataset; returns per entry its RunPlanning and the ground truth's values
    (``frame_ids``, ``values``, ``reasons``) on every frame of those runs."""
    from lightemma.planning.scores import drive_scores, interpolate_boxes, route_lanes
    from lightemma.planning.simulation import simulate

    fid_of: dict[str, str] = {}
    for m in members:
        _, run, scored = entries[m]
        for r in scored.tolist():
            fid_of.setdefault(run.frame_ids[r].rsplit("/", 1)[-1], run.frame_ids[r])
    tokens = list(fid_of)
    position = {t: i for i, t in enumerate(tokens)}
    frames = _frames(data, tokens, [fid_of[t].rsplit("/", 1)[0] for t in tokens])
    f_count = len(tokens)
    gt_ok = np.array([r is None for r in frames.reason], dtype=bool)
    gt_poses = np.where(gt_ok[:, None, None], frames.gt_poses, np.nan)
    gt_ego = simulate(gt_poses, frames.init) if f_count else np.zeros((0, 31, 11))
    plans = _plans(entries, members, frames, position, data)
    n = len(plans.frame)
    # the previous keyframe's plan of the same run (ec), and the ground truth's
    at = {(plans.run[i], int(plans.frame[i])): i for i in range(n)}
    prev_row: list[int | None] = []
    first: list[str | None] = []
    for i in range(n):
        p = frames.prev[plans.frame[i]]
        if p is None:
            prev_row.append(None)
            first.append("the first keyframe of its scene: no previous plan")
        elif p not in position or (plans.run[i], position[p]) not in at:
            prev_row.append(None)
            first.append(
                "no scored plan of this run at the previous keyframe (the first frame of the run's window, "
                "or that frame was not scored)"
            )
        else:
            prev_row.append(at[(plans.run[i], position[p])])
            first.append(None)
    gt_prev: list[int | None] = []
    gt_first: list[str | None] = []
    for f in range(f_count):
        p = frames.prev[f]
        gt_prev.append(position.get(p) if p is not None else None)
        gt_first.append(
            None
            if gt_prev[-1] is not None
            else (
                "the first keyframe of its scene: no previous plan"
                if p is None
                else "the previous keyframe is not among the evaluated frames (the first frame of the window)"
            )
        )
    comfort_plan = _comforts(plans.states, plans.frame, frames, prev_row, first)
    comfort_gt = _comforts(gt_ego, np.arange(f_count), frames, gt_prev, gt_first)
    plan_global = _to_global(plans.states, frames.pose[plans.frame]) if n else plans.states
    gt_global = _to_global(gt_ego, frames.pose) if f_count else gt_ego
    # one kernel call per map and chunk of frames, every run's plans and the ground truth's together
    values = {k: np.full(n, np.nan) for k in KEYS}
    reasons: dict[str, list[str | None]] = {k: [None] * n for k in KEYS}
    gt_values = {k: np.full(f_count, np.nan) for k in KEYS}
    gt_reasons: dict[str, list[str | None]] = {k: [None] * f_count for k in KEYS}
    by_map: dict[str, list[int]] = {}
    for f, tok in enumerate(tokens):
        by_map.setdefault(data.map_of.get(tok, ""), []).append(f)
    code_cache: dict[str, np.ndarray] = {}
    instance_ids: dict[str, int] = {}
    plans_of_frame: dict[int, list[int]] = {}
    for i, f in enumerate(plans.frame.tolist()):
        plans_of_frame.setdefault(f, []).append(i)
    kind_of = [""] * f_count
    map_of = [""] * f_count  # the map key of a frame whose map layers were read
    versions: dict[str, str] = {}  # map key -> the expansion's version
    for key, fs in by_map.items():
        area = (
            data.areas.get(key, f"sample has no log/map in {data.version}")
            if key
            else f"sample has no log/map in {data.version}"
        )
        pmap, map_reason = _planning_map(area, map_cache)
        for f in fs:
            kind_of[f] = getattr(area, "kind", "") if map_reason is None else ""
            map_of[f] = key if map_reason is None else ""
        version = getattr(area, "version", None) if map_reason is None else None  # area: a DrivableArea here
        if version:
            versions[key] = version
        for start in range(0, len(fs), CHUNK_FRAMES):
            idx = np.asarray(fs[start : start + CHUNK_FRAMES], dtype=np.int64)
            local = {int(f): j for j, f in enumerate(idx.tolist())}
            rows = [i for f in idx.tolist() for i in plans_of_frame.get(f, [])]
            rows_a = np.asarray(rows, dtype=np.int64)
            gt_chunk = gt_global[idx]
            states = np.concatenate([plan_global[rows_a], gt_chunk]) if len(rows) else gt_chunk
            frame = np.concatenate(
                [
                    np.array([local[int(plans.frame[i])] for i in rows], dtype=np.int64),
                    np.arange(len(idx), dtype=np.int64),
                ]
            )
            h = gt_chunk[..., 2]
            centres = gt_chunk[..., :2] + ego.rear_axle_to_center * np.stack([np.cos(h), np.sin(h)], -1)
            bad: dict[int, str] = {}
            agents = None
            if data.annotated:
                boxes, bad = _agents(data, tokens, idx, code_cache, instance_ids)
                agents = interpolate_boxes(boxes)
            lanes = route_lanes(pmap.lanes, gt_chunk, ego) if pmap.lanes is not None else None

            def part(name: str, which: dict[str, tuple[np.ndarray, list[str | None]]], sel: Any) -> np.ndarray:
                return which[name][0][sel]

            c = np.concatenate([part("c", comfort_plan, rows_a), part("c", comfort_gt, idx)])
            hc = np.concatenate([part("hc", comfort_plan, rows_a), part("hc", comfort_gt, idx)])
            ec = np.concatenate([part("ec", comfort_plan, rows_a), part("ec", comfort_gt, idx)])
            out = drive_scores(
                states,
                gt_chunk,
                frame=frame,
                agents=agents,
                map=pmap,
                frame_lanes=lanes,
                route=centres,
                centreline=centres,
                c=c,
                hc=hc,
                ec=ec,
                ego=ego,
            )
            targets = [*rows, *(-1 - idx).tolist()]  # a plan's row, or -1 - frame for the ground truth's
            for k in KEYS:
                v = out.values[k]
                values[k][rows_a] = v[: len(rows)]
                gt_values[k][idx] = v[len(rows) :]
                if k == "tlc":  # always n/a, one reason
                    for j, i in enumerate(targets):
                        if i < 0:
                            gt_reasons[k][-1 - i] = out.reasons[k][j]
                        else:
                            reasons[k][i] = out.reasons[k][j]
                    continue
                for j in np.flatnonzero(~np.isfinite(v)).tolist():  # the reasons of the values that are n/a
                    i = targets[j]
                    is_gt = i < 0
                    f = (-1 - i) if is_gt else int(plans.frame[i])
                    why = out.reasons[k][j]
                    if k in ("c", "hc", "ec") and why is not None:
                        why = (comfort_gt if is_gt else comfort_plan)[k][1][f if is_gt else i] or why
                    root = frames.reason[f] if is_gt else plans.reason[i]
                    if root is not None:
                        why = root
                    elif map_reason is not None and why is not None and "drivable" in why:
                        why = why.replace("no drivable area given (map expansion or mask)", map_reason)
                    if why is not None and local[f] in bad:
                        why = _KERNEL_BOX.sub(bad[local[f]], why)
                    elif why is not None and "degenerate agent box" in why:
                        why = _KERNEL_BOX.sub(
                            lambda mt: (
                                f"an agent seen at one keyframe only has no velocity (step {mt.group(1)}, "
                                f"slot {mt.group(2)}) or a degenerate box"
                            ),
                            why,
                        )
                    if is_gt:
                        gt_reasons[k][f] = why
                    else:
                        reasons[k][i] = why
    per_run: dict[int, RunPlanning] = {}
    for m in members:
        _, run, scored = entries[m]
        order = np.flatnonzero(np.asarray(plans.run, dtype=np.int64) == m) if n else np.zeros(0, np.int64)
        sel = order.tolist()
        per_run[m] = RunPlanning(
            [run.frame_ids[r] for r in scored.tolist()],
            scored,
            {k: values[k][order] for k in KEYS},
            {k: [reasons[k][i] for i in sel] for k in KEYS},
            plan_global[order] if n else np.zeros((0, 31, 11)),
            map_kinds=sorted({kind_of[int(plans.frame[i])] for i in sel} - {""}),
            map_versions={k: versions[k] for k in sorted({map_of[int(plans.frame[i])] for i in sel}) if k in versions},
            path=plans.states[order][..., :2] if n else np.zeros((0, 31, 2)),
        )
    gt = {
        "frame_ids": [fid_of[t] for t in tokens],
        "values": gt_values,
        "reasons": gt_reasons,
        "path": gt_ego[..., :2],
        "map_kinds": sorted(set(kind_of) - {""}),
        "map_versions": {k: versions[k] for k in sorted(set(map_of)) if k in versions},
    }
    return per_run, gt


# -- rows, intervals, warnings ---------------------------------------------------------------------------------------


def _scenes(frame_ids: Sequence[str]) -> np.ndarray:
    return np.asarray([f.rsplit("/", 1)[0] for f in frame_ids], dtype=object)


def _row(values: dict[str, np.ndarray], reasons: dict[str, list[str | None]], n: int) -> dict[str, Any]:
    row: dict[str, Any] = {"planning_frames": n}
    for k in KEYS:
        v = values[k]
        ok = np.isfinite(v)
        row[k] = float(v[ok].mean()) if ok.any() else None
        row[f"{k}_ci95"] = None
        row[f"{k}_na"] = None if ok.any() else (_commonest(reasons[k]) or "no frame")
    return row


def _commonest(reasons: Sequence[str | None]) -> str | None:
    counts: dict[str, int] = {}
    for r in reasons:
        if r:
            counts[r] = counts.get(r, 0) + 1
    return max(counts, key=lambda r: counts[r]) if counts else None


def _warnings(rp: RunPlanning, label: str) -> list[str]:
    """One warning per reason: how many frames lack which keys, with an example frame."""
    groups: dict[str, tuple[list[str], set[int]]] = {}
    for k in KEYS:
        for i in np.flatnonzero(~np.isfinite(rp.values[k])).tolist():
            why = rp.reasons[k][i]
            if not why or any(why.startswith(q) for q in _QUIET) or why.startswith("n/a: "):
                continue  # an aggregate's reason repeats its terms'
            keys, rows = groups.setdefault(why, ([], set()))
            if k not in keys:
                keys.append(k)
            rows.add(i)
    out = []
    for why, (keys, rows) in groups.items():
        first = rp.frame_ids[min(rows)]
        out.append(
            f"{label}: planning score: {len(rows)} frame(s) have no {', '.join(keys)} (n/a): {why} (e.g. {first})"
        )
    return out


def _headline(rows: Sequence[dict[str, Any]]) -> str:
    for key in ("epdms", "epdms_map"):
        if any(r.get(key) is not None for r in rows):
            return key
    with_agents = any(r.get("epdms_na") and "see epdms_map" not in str(r.get("epdms_na")) for r in rows)
    return "epdms" if with_agents else "epdms_map"


def evaluate_planning(
    entries: Sequence[tuple[str, Any, np.ndarray]],
    resampling: Any,
    *,
    dataroot: str | os.PathLike[str] | None = None,
    version: str | None = None,
    safety: Any = None,
    pairwise: bool = False,
    only: set[str] | None = None,
) -> PlanningResult:
    """The planning score of evaluated runs: ``entries`` = (label, RunData, scored rows) as in
    :func:`lightemma.evaluation.evaluate_loaded`.

    Per run a row of :data:`ROW_KEYS`: each key's mean over the frames that have a value, its scene-bootstrap 95 %
    interval (``resampling``) and, when no frame has a value, the reason (``<key>_na``); the ground truth's own row
    (:data:`GT_LABEL`) on every frame of any run. ``dataroot``/``version`` as the safety columns (default: each
    run's manifest); ``safety``: an evaluation's :class:`~lightemma.evaluation.safety.SafetyResult` whose data (read
    with ``history``) is reused. ``pairwise`` compares every pair of runs on the headline aggregate (paired on the
    frames both have; ``only``: the common frames of ``--common``). Never raises for bad data: n/a with reasons.
    """
    from lightemma.evaluation.safety import _resolve_dataset, load_safety_data, map_versions, sample_token_of
    from lightemma.evaluation.stats import bootstrap_ci
    from lightemma.planning.scores import EgoBox

    ego = EgoBox()
    warnings: list[str] = []
    result = PlanningResult(rows={}, ground_truth=None, runs={}, warnings=warnings)
    datasets: dict[tuple[str, str], list[int]] = {}
    reasons: dict[int, str] = {}
    for m, (_label, run, _) in enumerate(entries):
        ds = _resolve_dataset(run, dataroot, version)
        if isinstance(ds, str):
            reasons[m] = ds
        else:
            datasets.setdefault(ds, []).append(m)
    per_run: dict[int, RunPlanning] = {}
    gt_parts: list[dict[str, Any]] = []
    map_cache: dict[str, Any] = {}
    for ds, members in datasets.items():
        data = None
        if safety is not None:
            for m in members:
                rs = safety.runs.get(entries[m][0])
                if rs is not None and rs.data is not None and rs.data.past:  # read with history
                    data = rs.data
                    break
        if data is None:
            tokens = {sample_token_of(f) for m in members for f in entries[m][1].frame_ids}
            try:
                data = load_safety_data(ds[0], ds[1], samples=tokens, history=HISTORY_KEYFRAMES)
            except DatasetError as exc:
                for m in members:
                    reasons[m] = str(exc)
                warnings.append(f"planning score: {exc}")
                continue
        runs_here, gt = _score_dataset(data, entries, members, ego, map_cache)
        per_run.update(runs_here)
        gt_parts.append(gt)
    groups: list[tuple[np.ndarray, np.ndarray]] = []
    keys: list[str] = []
    slots: list[tuple[str, str]] = []
    for m, (label, run, scored) in enumerate(entries):
        if m not in per_run:
            why = reasons.get(m, _NO_DATAROOT)
            rp = RunPlanning([run.frame_ids[r] for r in scored.tolist()], scored, reason=why)
            result.runs[label] = rp
            result.rows[label] = {
                "planning_frames": 0,
                **{k: None for k in KEYS},
                **{f"{k}_ci95": None for k in KEYS},
                **{f"{k}_na": why for k in KEYS},
                "planning_map": None,
                "map_version": None,
            }
            continue
        rp = per_run[m]
        result.runs[label] = rp
        warnings.extend(_warnings(rp, label))
        row = _row(rp.values, rp.reasons, len(rp.frame_ids))
        row["planning_map"] = "+".join(rp.map_kinds) or None
        row["map_version"] = map_versions(list(rp.map_versions.values()))
        result.rows[label] = row
        scenes = _scenes(rp.frame_ids)
        for k in KEYS:
            ok = np.isfinite(rp.values[k])
            if ok.sum() > 0:
                groups.append((rp.values[k][ok], scenes[ok]))
                keys.append(f"planning|{label}|{k}")
                slots.append((label, k))
    if gt_parts:
        fids = [f for g in gt_parts for f in g["frame_ids"]]
        values = {k: np.concatenate([g["values"][k] for g in gt_parts]) for k in KEYS}
        gt_why = {k: [r for g in gt_parts for r in g["reasons"][k]] for k in KEYS}
        kinds = sorted({k for g in gt_parts for k in g["map_kinds"]})
        gt_versions = {k: v for g in gt_parts for k, v in g["map_versions"].items()}
        gt_rp = RunPlanning(
            fids,
            np.arange(len(fids)),
            values,
            gt_why,
            map_kinds=kinds,
            map_versions=gt_versions,
            path=np.concatenate([g["path"] for g in gt_parts]),
        )
        result.runs[GT_LABEL] = gt_rp
        warnings.extend(_warnings(gt_rp, GT_LABEL))
        result.ground_truth = {
            "model": GT_LABEL,
            **_row(values, gt_why, len(fids)),
            "planning_map": "+".join(kinds) or None,
            "map_version": map_versions(list(gt_versions.values())),
        }
        scenes = _scenes(fids)
        for k in KEYS:
            ok = np.isfinite(values[k])
            if ok.sum() > 0:
                groups.append((values[k][ok], scenes[ok]))
                keys.append(f"planning|{GT_LABEL}|{k}")
                slots.append((GT_LABEL, k))
    if groups and resampling.n_resamples:
        ci = bootstrap_ci(groups, keys, resampling)
        for (label, k), pair in zip(slots, ci[:, 0]):
            target = result.ground_truth if label == GT_LABEL else result.rows[label]
            assert target is not None
            target[f"{k}_ci95"] = [float(pair[0]), float(pair[1])] if np.isfinite(pair).all() else None
    result.headline = _headline([*result.rows.values(), *([result.ground_truth] if result.ground_truth else [])])
    if pairwise:
        result.pairwise = pairwise_planning(result, [label for label, _, _ in entries], resampling, only=only)
    return result


def pairwise_planning(
    result: PlanningResult, labels: Sequence[str], resampling: Any, *, only: set[str] | None = None
) -> list[dict[str, Any]]:
    """Every pair of runs (a before b) on the headline aggregate, on the frames where both have a value: mean paired
    difference a − b, scene-bootstrap interval, sign-flip p over scenes, Holm over all pairs. Rows as
    :func:`lightemma.evaluation.safety.pairwise_safety`'s (``metric`` is the aggregate's key)."""
    from lightemma.evaluation.stats import bootstrap_ci, mark_holm, sign_flip_p

    key = result.headline
    per: dict[str, dict[str, float]] = {}
    for label in labels:
        rp = result.runs.get(label)
        if rp is None or not rp.values:
            continue
        per[label] = {
            f: float(v)
            for f, v in zip(rp.frame_ids, rp.values[key])
            if math.isfinite(v) and (only is None or f in only)
        }
    codes: dict[str, int] = {}
    out: list[dict[str, Any]] = []
    groups: list[tuple[np.ndarray, np.ndarray]] = []
    keys: list[str] = []
    where: list[int] = []
    for a in range(len(labels)):
        for b in range(a + 1, len(labels)):
            la, lb = labels[a], labels[b]
            row: dict[str, Any] = {
                "model_a": la,
                "model_b": lb,
                "metric": key,
                "frames": 0,
                "scenes": 0,
                "diff": None,
                "ci95": None,
                "p_value": None,
            }
            if la in per and lb in per:
                common = sorted(set(per[la]) & set(per[lb]))
                if common:
                    d = np.array([per[la][f] - per[lb][f] for f in common])
                    sc = np.array([codes.setdefault(f.rsplit("/", 1)[0], len(codes)) for f in common])
                    row.update(frames=len(common), scenes=int(len(np.unique(sc))), diff=float(d.mean()))
                    groups.append((d, sc))
                    keys.append(f"{la}|{lb}|planning|{key}")
                    where.append(len(out))
            out.append(row)
    if groups and resampling.n_resamples:
        ci = bootstrap_ci(groups, keys, resampling)
        p = sign_flip_p(groups, keys, resampling)
        for k, i in enumerate(where):
            pair = ci[k, 0]
            out[i]["ci95"] = [float(pair[0]), float(pair[1])] if np.isfinite(pair).all() else None
            out[i]["p_value"] = None if np.isnan(p[k]) else float(p[k])
    mark_holm(out, resampling.confidence)
    return out


#: scenario tags from the planning score (per model, from its own plan)
PLANNING_TAGS: tuple[str, ...] = ("wrong-way", "uncomfortable", "no-progress")


def frame_tags(rp: RunPlanning) -> dict[str, np.ndarray]:
    """Scenario tags of a run's scored frames from its planning sub-scores: ``wrong-way`` (driving-direction
    compliance ddc < 1: the centre travelled against the route's lanes), ``uncomfortable`` (comfort c = 0: a nuPlan
    bound broken), ``no-progress`` (ep = 0: no progress along the route while the ground truth made > 5 m); False
    where the sub-score is n/a."""
    n = len(rp.frame_ids)
    if not rp.values:
        return {tag: np.zeros(n, bool) for tag in PLANNING_TAGS}
    with np.errstate(invalid="ignore"):
        return {
            "wrong-way": np.isfinite(rp.values["ddc"]) & (rp.values["ddc"] < 1.0),
            "uncomfortable": rp.values["c"] == 0.0,
            "no-progress": rp.values["ep"] == 0.0,
        }
