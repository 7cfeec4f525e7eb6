"""Does it drive safely? Collision with annotated agents and leaving the drivable area (docs/definitions.md#safety).

Three layers:

* geometry (Rust core, :mod:`lightemma._core`): :func:`ego_poses`, :func:`footprints`,
  :func:`box_collisions`, :class:`~lightemma.nuscenes.map_files.DrivableArea` ``.lookup`` — whole batches, the GIL
  released;
* the dataset (:func:`lightemma.nuscenes.annotations.load_safety_data`, the one reader of a dataroot): per keyframe its
  CAM_FRONT ego pose, the annotated agents of the next six keyframes and the drivable area of its log's map (the
  devkit's conventions, no devkit needed); this module receives it parsed and opens no dataset file;
* outcomes and rates (:func:`frame_safety`, :func:`safety_values`): per frame and step, the
  footprint's corners on or off the drivable area and its overlap with vehicles and vulnerable
  road users; the rates of the conventions ``uniad``, ``stp3`` and ``any``.

Conventions (all frames 0.5 s apart, steps k = 1..6 at 0.5 … 3.0 s, ``t`` = 1, 2, 3 s):

* ``uniad`` — UniAD's ``obj_box_col``: the share of frames whose footprint overlaps an agent
  *at* step 2t; a step where the ground truth itself collides is not counted (UniAD masks it);
* ``stp3`` — ST-P3 / VAD: the per-step rate averaged over the prefix 1…2t; ground-truth
  collisions masked as in ST-P3's code;
* ``any`` — the frame collides somewhere in 1…2t (BEV-Planner's "any collision up to t"; the
  frame's outcome); ground-truth collisions not masked (as VADv2, BEV-Planner).

The footprint is the ego box of ST-P3/UniAD, 4.084 m × 1.85 m, rotated by the heading along
the trajectory; its reference point is nuScenes' ``ego_pose`` (the rear-axle centre) and its
centre lies :data:`EGO_OFFSET` ahead of it.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lightemma.definitions import COLLISION_CONVENTIONS, COLLISION_FOR_ADE, EGO_LENGTH, EGO_OFFSET, EGO_WIDTH, MIN_STEP
from lightemma.errors import DatasetError, InputError, ShapeError
from lightemma.nuscenes.annotations import CLASS_NAMES, VEHICLE, VRU, SafetyData, load_safety_data
from lightemma.nuscenes.map_files import DrivableArea, EgoKwargs

STEPS = 6
SECONDS = (1, 2, 3)


@dataclass(frozen=True)
class EgoModel:
    """The ego footprint and heading rule (defaults: ST-P3/UniAD's box, UniAD's offset, BEV-Planner's rule)."""

    length: float = EGO_LENGTH
    width: float = EGO_WIDTH
    offset: float = EGO_OFFSET
    min_step: float = MIN_STEP

    def kwargs(self) -> EgoKwargs:
        """The box as the safety kernels' keyword arguments (``_core.ego_poses`` and the like)."""
        return {"length": self.length, "width": self.width, "offset": self.offset, "min_step": self.min_step}


EGO = EgoModel()


def _traj_poses(traj: Any, poses: Any) -> tuple[np.ndarray, np.ndarray]:
    return np.ascontiguousarray(traj, dtype=np.float64), np.ascontiguousarray(poses, dtype=np.float64)


def ego_poses(traj: Any, poses: Any, ego: EgoModel = EGO) -> np.ndarray:
    """Global (x, y, heading) of every step's reference point.

    ``traj`` (N, T, 2): positions in the ego frame of each keyframe (m); ``poses`` (N, 3): the
    keyframe's global (x, y, yaw) (m, rad). Returns (N, T, 3). The heading of step k is the
    direction of p_{k−1} → p_k (p_0 the origin, heading 0), kept when that step is shorter than
    ``ego.min_step``. Raises ``ValueError`` for wrong shapes or non-finite values (frame, step named).
    """
    from lightemma import _core

    return _core.ego_poses(*_traj_poses(traj, poses), **ego.kwargs())


def footprints(traj: Any, poses: Any, ego: EgoModel = EGO) -> np.ndarray:
    """Global corners (N, T, 4, 2) of the ego footprint: front-left, front-right, rear-right, rear-left (m)."""
    from lightemma import _core

    return _core.footprint_corners(*_traj_poses(traj, poses), **ego.kwargs())


def box_collisions(traj: Any, poses: Any, agents: Any, ego: EgoModel = EGO) -> np.ndarray:
    """(N, T, A) bool: the footprint at step k overlaps agent slot a (exact rotated-rectangle test).

    ``agents`` (N, T, A, 5): global centre x, y (m), yaw (rad), length, width (m) per frame, step
    and slot; NaN centre x marks an empty slot. Touching boxes do not overlap. A non-finite value
    or a size ≤ 0 in a used slot raises ``ValueError`` naming frame, step and slot.
    """
    from lightemma import _core

    t, p = _traj_poses(traj, poses)
    return _core.box_collisions(t, p, np.ascontiguousarray(agents, dtype=np.float64), **ego.kwargs())


# -- the drivable area (read by lightemma.nuscenes.map_files): outcome codes of DrivableArea.lookup ----------------

ON, OFF, OUTSIDE = 1, 0, 2


# -- per-frame outcomes ------------------------------------------------------------------------


@dataclass
class FrameSafety:
    """Per-frame safety outcomes of N trajectories.

    ``area``: (N, 6, 5) uint8 lookups (4 corners, then the reference point), valid where
    ``area_ok``; ``collide``: (N, 6, 2) bool overlap with a vehicle / a vulnerable road user at each
    step, valid where ``coll_ok``; ``area_reason`` / ``coll_reason``: why a frame has no value ("" when
    it has one); ``area_kind``: per frame ``expansion`` / ``mask`` / ""; ``area_version``: per frame the map
    expansion's version (:attr:`DrivableArea.version`), "" for a mask or no value (empty: not recorded).
    """

    area: np.ndarray
    area_ok: np.ndarray
    area_reason: list[str]
    area_kind: list[str]
    collide: np.ndarray
    coll_ok: np.ndarray
    coll_reason: list[str]
    area_version: list[str] = field(default_factory=list)

    @property
    def off_steps(self) -> np.ndarray:
        """(N, 6) bool: some corner of the footprint is off the drivable area (or off the mask image)."""
        return (self.area[:, :, :4] != ON).any(axis=2)

    @property
    def outside_mask(self) -> np.ndarray:
        """(N,) bool: some tested point fell outside the mask image (counted off, reported)."""
        return (self.area == OUTSIDE).any(axis=(1, 2)) & self.area_ok


def frame_safety(traj: Any, sample_tokens: Sequence[str], data: SafetyData, ego: EgoModel = EGO) -> FrameSafety:
    """Outcomes of trajectories (N, 6, 2), each in the ego frame of keyframe ``sample_tokens[i]``.

    Frames without a pose, a map, six future keyframes or annotations (or with a non-finite
    trajectory) get ``*_ok`` False and a reason; nothing is silently 0.
    """
    traj = np.ascontiguousarray(traj, dtype=np.float64)
    n = len(sample_tokens)
    if traj.shape != (n, STEPS, 2):
        raise ShapeError(f"trajectories must have shape ({n}, {STEPS}, 2), got {traj.shape}")
    finite = np.isfinite(traj).all(axis=(1, 2))
    poses = np.zeros((n, 3))
    has_pose = np.zeros(n, dtype=bool)
    for i, st in enumerate(sample_tokens):
        if st in data.poses:
            poses[i], has_pose[i] = data.poses[st], True
    usable = finite & has_pose
    safe_traj = np.where(usable[:, None, None], traj, 0.0)

    def base_reason(i: int) -> str:
        if not has_pose[i]:
            why = data.pose_reasons.get(sample_tokens[i])
            if why:
                return f"unusable CAM_FRONT ego pose: {why}"
            return f"no CAM_FRONT ego pose for sample {sample_tokens[i]} in {data.version}"
        return "" if finite[i] else "no trajectory"

    # drivable area, per map
    area = np.zeros((n, STEPS, 5), dtype=np.uint8)
    area_ok = np.zeros(n, dtype=bool)
    area_reason = [base_reason(i) for i in range(n)]
    area_kind = [""] * n
    area_version = [""] * n
    by_map: dict[str, list[int]] = {}
    for i, st in enumerate(sample_tokens):
        key = data.map_of.get(st)
        if key is None:
            area_reason[i] = area_reason[i] or f"sample {st} has no log/map in {data.version}"
        elif usable[i]:
            by_map.setdefault(key, []).append(i)
    for key, rows in by_map.items():
        found = data.areas.get(key)
        if not isinstance(found, DrivableArea):
            for i in rows:
                area_reason[i] = f"no drivable area: {found}"
            continue
        idx = np.asarray(rows)
        area[idx] = found.lookup(safe_traj[idx], poses[idx], ego)
        area_ok[idx] = True
        for i in rows:
            area_kind[i] = found.kind
            area_version[i] = found.version or ""

    # collisions
    collide = np.zeros((n, STEPS, 2), dtype=bool)
    coll_ok = np.zeros(n, dtype=bool)
    coll_reason = [base_reason(i) for i in range(n)]
    if not data.annotated:
        coll_reason = ["no annotations"] * n
    else:
        rows = []
        for i, st in enumerate(sample_tokens):
            if coll_reason[i]:
                continue
            if len(data.future.get(st, [])) < STEPS:
                coll_reason[i] = f"sample {st} has fewer than {STEPS} later keyframes"
                continue
            bad = next((data.bad_boxes[f] for f in data.future[st] if f in data.bad_boxes), None)
            if bad is not None:
                coll_reason[i] = f"a refused annotation: {bad}"
                continue
            rows.append(i)
        if rows:
            idx = np.asarray(rows)
            slots = max(1, max(len(data.boxes[f]) for i in rows for f in data.future[sample_tokens[i]]))
            agents = np.full((len(rows), STEPS, slots, 5), np.nan)
            classes = np.full((len(rows), STEPS, slots), -1, dtype=np.int8)
            for r, i in enumerate(rows):
                for k, ft in enumerate(data.future[sample_tokens[i]]):
                    b = data.boxes[ft]
                    agents[r, k, : len(b)] = b
                    classes[r, k, : len(b)] = data.classes[ft]
            hits = box_collisions(safe_traj[idx], poses[idx], agents, ego)
            collide[idx, :, 0] = (hits & (classes == VEHICLE)).any(axis=2)
            collide[idx, :, 1] = (hits & (classes == VRU)).any(axis=2)
            coll_ok[idx] = True
    return FrameSafety(area, area_ok, area_reason, area_kind, collide, coll_ok, coll_reason, area_version)


# -- rates ---------------------------------------------------------------------------------------

#: per-frame value keys of :func:`safety_values`, in table order
AREA_KEYS = ("offroad", "offroad_1s", "offroad_2s", "offroad_3s", "offroad_centre")
COLLISION_KEYS = ("collision", "collision_1s", "collision_2s", "collision_3s", "collision_vehicle", "collision_vru")


def _collision_seconds(c: np.ndarray, convention: str) -> np.ndarray:
    """(N, 3) per-frame values at 1/2/3 s from per-step indicators c (N, 6) under a convention."""
    c = c.astype(np.float64)
    if convention == "uniad":
        return c[:, [1, 3, 5]]
    if convention == "stp3":
        return np.column_stack([c[:, : 2 * s].mean(axis=1) for s in SECONDS])
    if convention == "any":
        return np.column_stack([c[:, : 2 * s].max(axis=1) for s in SECONDS])
    raise InputError(f"unknown collision convention {convention!r} (choose from {', '.join(COLLISION_CONVENTIONS)})")


def _summary(sec: np.ndarray, convention: str) -> np.ndarray:
    """The headline value per frame: the frame outcome (3 s) for ``any``, the mean of 1/2/3 s ("Avg.") otherwise."""
    return sec[:, 2] if convention == "any" else sec.mean(axis=1)


def safety_values(fs: FrameSafety, convention: str, *, gt: FrameSafety | None = None) -> dict[str, np.ndarray]:
    """Per-frame values (N,) of :data:`AREA_KEYS` and :data:`COLLISION_KEYS` under a collision convention.

    A rate is the mean of its values over frames; NaN marks a frame without a value (the reasons are
    in ``fs``). Off-road values do not depend on the convention: ``offroad`` = some corner of some step
    off the drivable area (NAVSIM's DAC), ``offroad_Ts`` = at step 2T, ``offroad_centre`` = the reference
    point (the devkit's own off-road test) at some step. With ``gt`` (the ground truth's outcomes on
    the same frames) ``uniad`` and ``stp3`` do not count a step where the ground truth collides too.
    """
    off = fs.off_steps
    na_area = ~fs.area_ok
    out: dict[str, np.ndarray] = {}
    out["offroad"] = off.any(axis=1).astype(np.float64)
    for s in SECONDS:
        out[f"offroad_{s}s"] = off[:, 2 * s - 1].astype(np.float64)
    out["offroad_centre"] = (fs.area[:, :, 4] != ON).any(axis=1).astype(np.float64)
    for key in AREA_KEYS:
        out[key][na_area] = np.nan
    per_class = fs.collide.copy()
    na_coll = ~fs.coll_ok
    if gt is not None and convention in ("uniad", "stp3"):
        gt_any = gt.collide.any(axis=2) & gt.coll_ok[:, None]
        per_class &= ~gt_any[:, :, None]
    both = per_class.any(axis=2)
    sec = _collision_seconds(both, convention)
    out["collision"] = _summary(sec, convention)
    for j, s in enumerate(SECONDS):
        out[f"collision_{s}s"] = sec[:, j]
    for c, name in enumerate(CLASS_NAMES):
        out[f"collision_{name}"] = _summary(_collision_seconds(per_class[:, :, c], convention), convention)
    for key in COLLISION_KEYS:
        out[key] = out[key].astype(np.float64)
        out[key][na_coll] = np.nan
    return out


def rates(values: Mapping[str, np.ndarray]) -> dict[str, float | None]:
    """The mean of each key's values over the frames that have one (None when none has)."""
    out: dict[str, float | None] = {}
    for key, v in values.items():
        ok = np.isfinite(v)
        out[key] = float(v[ok].mean()) if ok.any() else None
    return out


def na_reason(fs: FrameSafety, which: str) -> str | None:
    """Why no frame of ``fs`` has a value for ``which`` (``area`` / ``collision``), or None when some do."""
    ok, reasons = (fs.area_ok, fs.area_reason) if which == "area" else (fs.coll_ok, fs.coll_reason)
    if ok.any() or not len(reasons):
        return None
    counts: dict[str, int] = {}
    for r in reasons:
        if r:
            counts[r] = counts.get(r, 0) + 1
    return max(counts, key=lambda r: counts[r]) if counts else None


def frame_warnings(fs: FrameSafety, frame_ids: Sequence[str], what: str) -> list[str]:
    """One warning per kind of missing value, with a count and an example frame; mask coverage too."""
    out: list[str] = []
    for which, ok, reasons in (("off-road", fs.area_ok, fs.area_reason), ("collision", fs.coll_ok, fs.coll_reason)):
        groups: dict[str, list[int]] = {}
        for i in np.flatnonzero(~ok):
            if reasons[i] and reasons[i] not in ("no trajectory", "no annotations"):
                groups.setdefault(reasons[i], []).append(int(i))
        for reason, rows in groups.items():
            out.append(
                f"{what}: {len(rows)} frame(s) have no {which} value (n/a): {reason} (e.g. {frame_ids[rows[0]]})"
            )
    outside = np.flatnonzero(fs.outside_mask)
    if len(outside):
        out.append(
            f"{what}: the map mask does not cover the footprint of {len(outside)} frame(s) (e.g. {frame_ids[outside[0]]}); "
            "those points count as off the drivable area"
        )
    return out


# -- evaluation of runs ------------------------------------------------------------------------------

#: row keys this module adds to every accuracy row (values are shares 0..1; tables print %)
ROW_KEYS = (
    *AREA_KEYS,
    *COLLISION_KEYS,
    "offroad_ci95",
    "collision_ci95",
    "safety_frames",
    "offroad_frames",
    "collision_frames",
    "area_source",
    "map_version",
    "offroad_na",
    "collision_na",
    "collision_convention",
)
FLOOR_LABEL = "Ground truth (floor)"
_NO_DATAROOT = "no dataroot (pass --dataroot and --version)"


def sample_token_of(frame_id: str) -> str:
    """The sample token in a frame id ``scene/sample_token``."""
    return frame_id.rsplit("/", 1)[-1]


@dataclass
class RunSafety:
    """One run's outcomes on its scored frames (model and ground truth), for tables, tests, tags and figures."""

    frame_ids: list[str]
    rows: np.ndarray
    model: FrameSafety | None
    truth: FrameSafety | None
    reason: str | None = None  # why there is nothing (no dataroot, unreadable dataset)
    data: SafetyData | None = None  # the dataset the outcomes come from (for figures)


@dataclass
class SafetyResult:
    """Safety rows per model and ADE convention, the ground-truth floor, and the per-frame outcomes."""

    rows: dict[str, dict[str, dict[str, Any]]]  # label -> ADE convention -> row keys
    floor: dict[str, dict[str, Any]]  # ADE convention -> row keys (ground truth, unmasked)
    runs: dict[str, RunSafety]
    warnings: list[str] = field(default_factory=list)
    gt_off_scenes: list[str] = field(default_factory=list)  # scenes whose ground truth leaves the drivable area
    gt_collision_scenes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {
            "floor": self.floor,
            "gt_off_road_scenes": self.gt_off_scenes,
            "gt_collision_scenes": self.gt_collision_scenes,
        }


def run_map_versions(rs: RunSafety) -> dict[str, str]:
    """Map key (``expansion:<location>``) -> the version of the map expansion (:attr:`DrivableArea.version`) behind a
    run's off-road values, over the frames that have one; {} for a run without values or scored on masks only."""
    if rs.model is None or rs.data is None:
        return {}
    out: dict[str, str] = {}
    for fid, ok in zip(rs.frame_ids, rs.model.area_ok, strict=True):
        key = rs.data.map_of.get(sample_token_of(fid)) if ok else None
        area = rs.data.areas.get(key) if key is not None else None
        if key is not None and isinstance(area, DrivableArea) and area.version:  # area is None when key is
            out[key] = area.version
    return out


def map_version_conflict(per_run: Mapping[str, Mapping[str, str]]) -> str | None:
    """One line naming the first two runs of ``per_run`` (label -> map key -> expansion version:
    :func:`run_map_versions`, ``RunPlanning.map_versions``) whose numbers were scored against different versions of
    the same map expansion, or None when every map was read at one version. Such runs' off-road and planning scores
    are not comparable."""
    seen: dict[str, tuple[str, str]] = {}  # map key -> (version, first label)
    for label, versions in per_run.items():
        for key, v in sorted(versions.items()):
            first = seen.setdefault(key, (v, label))
            if first[0] != v:
                location = key.removeprefix("expansion:")
                return (
                    f"{first[1]} and {label} were scored against different versions of the {location} map "
                    f"expansion ({first[0]} and {v}); their off-road and planning scores are not comparable: "
                    "score every run against one dataset (--dataroot DIR --version V) or evaluate them apart"
                )
    return None


def _resolve_dataset(run: Any, dataroot: str | os.PathLike[str] | None, version: str | None) -> tuple[str, str] | str:
    """(dataroot, version) for a run: the given ones, else the run's manifest's; or the reason there is none
    (none recorded, or the recorded folder is gone)."""
    if dataroot is not None:
        if not version:
            return "--dataroot needs --version"
        return os.fspath(dataroot), version
    ds = run.info.dataset or {}
    root, ver = ds.get("dataroot"), ds.get("version")
    if isinstance(root, str) and root and isinstance(ver, str) and ver:
        if Path(root, ver).is_dir():
            return root, ver
        gone = root if not Path(root).is_dir() else os.path.join(root, ver)
        return f"recorded dataroot {gone} is gone; pass --dataroot"
    return _NO_DATAROOT


def map_versions(versions: Sequence[str]) -> str | None:
    """The map expansion versions behind some values, one string: the distinct versions sorted and joined by ``+``
    (``"1.3"``, ``"1.2+1.3"``); None when no value came from an expansion (a mask, or no value)."""
    found = sorted({v for v in versions if v})
    return "+".join(found) if found else None


def _row(values: Mapping[str, np.ndarray], fs: FrameSafety, convention: str) -> dict[str, Any]:
    r = rates(values)
    area_ok, coll_ok = np.isfinite(values["offroad"]), np.isfinite(values["collision"])
    kinds = sorted({k for k in fs.area_kind if k})
    return {
        **r,
        "safety_frames": int(len(fs.area_ok)),
        "offroad_frames": int(area_ok.sum()),
        "collision_frames": int(coll_ok.sum()),
        "area_source": "+".join(kinds) if kinds else None,
        "map_version": map_versions(fs.area_version),
        "offroad_na": None if area_ok.any() else (na_reason(fs, "area") or "no frame"),
        "collision_na": None if coll_ok.any() else (na_reason(fs, "collision") or "no frame"),
        "collision_convention": convention,
    }


def _intervals(groups: list[tuple[np.ndarray, np.ndarray]], keys: list[str], resampling: Any) -> np.ndarray:
    from lightemma.evaluation.stats import bootstrap_ci

    if not groups or not resampling.n_resamples:
        return np.full((len(groups), 1, 2), np.nan)
    return bootstrap_ci(groups, keys, resampling)


def _rate_intervals(groups: list[tuple[np.ndarray, np.ndarray]], resampling: Any) -> np.ndarray:
    """(R, 1, 2) intervals of rates: exact binomial on the scene-clustered effective sample size, never [0, 0]
    at a rate of 0 (:func:`lightemma.evaluation.stats.rate_ci`, docs/statistics.md#rates)."""
    from lightemma.evaluation.stats import rate_ci

    return rate_ci(groups, resampling)


def _scenes(frame_ids: Sequence[str]) -> np.ndarray:
    """Scene names of frame ids ``scene/sample_token`` (the clusters of the scene bootstrap)."""
    return np.asarray([f.rsplit("/", 1)[0] for f in frame_ids], dtype=object)


def evaluate_safety(
    entries: Sequence[tuple[str, Any, np.ndarray]],
    conventions: Sequence[str],
    resampling: Any,
    *,
    dataroot: str | os.PathLike[str] | None = None,
    version: str | None = None,
    ego: EgoModel = EGO,
    agents: str = "all",
    history: int = 0,
) -> SafetyResult:
    """Safety rows for evaluated runs: ``entries`` = (label, RunData, scored rows) as in :func:`evaluate_loaded`.

    Each ADE convention's table shows the collision convention of the same name (``lightemma`` → ``any``);
    off-road values are the same in every table. Intervals: :func:`_rate_intervals`. The floor is the
    ground truth's own (unmasked) rates over every frame with usable ground truth in any run. ``agents``:
    which annotation boxes count (:data:`AGENT_FILTERS`). A run whose ground truth moves faster than
    :data:`lightemma.nuscenes.geometry.POSE_JUMP_SPEED` between keyframes gets a warning (a pose jump). ``history``:
    as :func:`load_safety_data` (the planning score reuses the data read here).
    """
    warnings: list[str] = []
    for label, run, _ in entries:  # every frame with ground truth, scored or not
        warnings.extend(pose_jump_warnings(run.gt_positions, run.frame_ids, label))
    datasets: dict[tuple[str, str], list[int]] = {}
    resolved = []
    for i, (_, run, _) in enumerate(entries):
        ds = _resolve_dataset(run, dataroot, version)
        resolved.append(ds)
        if isinstance(ds, tuple):
            datasets.setdefault(ds, []).append(i)
    loaded: dict[tuple[str, str], SafetyData | str] = {}
    for ds, members in datasets.items():
        wanted = {sample_token_of(f) for i in members for f in entries[i][1].frame_ids}
        try:
            loaded[ds] = load_safety_data(ds[0], ds[1], samples=wanted, agents=agents, history=history)
        except DatasetError as exc:
            loaded[ds] = str(exc)
            warnings.append(f"safety metrics: {exc}")
    result = SafetyResult(rows={}, floor={}, runs={}, warnings=warnings)
    groups: list[tuple[np.ndarray, np.ndarray]] = []
    keys: list[str] = []
    slots: list[tuple[str, str, str]] = []
    floor_frames: dict[str, tuple[np.ndarray, str, Any]] = {}
    for (label, run, rows), ds in zip(entries, resolved):
        data = loaded.get(ds) if isinstance(ds, tuple) else None
        reason = ds if isinstance(ds, str) else (data if isinstance(data, str) else None)
        fids = [run.frame_ids[i] for i in rows]
        if reason is not None or not isinstance(data, SafetyData):
            result.runs[label] = RunSafety(fids, rows, None, None, reason)
            na = {k: None for k in ROW_KEYS}
            result.rows[label] = {
                c: {**na, "offroad_na": reason, "collision_na": reason, "collision_convention": COLLISION_FOR_ADE[c]}
                for c in conventions
            }
            continue
        tokens = [sample_token_of(f) for f in fids]
        conflicts = (
            _recorded_pose_conflicts(run, fids, tokens, data, warnings, label)
            if getattr(run.info, "imported", False)
            else {}
        )
        model = frame_safety(run.trajectory[rows], tokens, data, ego)
        truth = frame_safety(run.gt_positions[rows], tokens, data, ego)
        for j, why in conflicts.items():
            for fs in (model, truth):
                fs.area_ok[j] = fs.coll_ok[j] = False
                fs.area_reason[j] = fs.coll_reason[j] = why
        result.runs[label] = RunSafety(fids, rows, model, truth, data=data)
        warnings.extend(frame_warnings(model, fids, label))
        result.rows[label] = {}
        scenes = _scenes(fids)
        for c in conventions:
            cc = COLLISION_FOR_ADE[c]
            values = safety_values(model, cc, gt=truth)
            result.rows[label][c] = _row(values, model, cc)
            for key in ("offroad", "collision"):
                ok = np.isfinite(values[key])
                if ok.sum() > 0:
                    groups.append((values[key][ok], scenes[ok]))
                    keys.append(f"safety|{label}|{cc}|{key}")
                    slots.append((label, c, key))
        for j, fid in enumerate(fids):
            if j in conflicts:
                continue
            floor_frames.setdefault(fid, (run.gt_positions[rows[j]], tokens[j], data))
    # the floor: every frame's ground truth once
    if floor_frames:
        by_data: dict[int, list[str]] = {}
        for fid, (_, _, data) in floor_frames.items():
            by_data.setdefault(id(data), []).append(fid)
        parts = []
        for fids in by_data.values():
            data = floor_frames[fids[0]][2]
            gt = np.stack([floor_frames[f][0] for f in fids])
            parts.append((fids, frame_safety(gt, [floor_frames[f][1] for f in fids], data, ego)))
        fids = [f for p in parts for f in p[0]]
        truth = _concat([p[1] for p in parts])
        scenes = _scenes(fids)
        warnings.extend(frame_warnings(truth, fids, "ground truth"))
        off = truth.off_steps.any(axis=1) & truth.area_ok
        hit = truth.collide.any(axis=(1, 2)) & truth.coll_ok
        result.gt_off_scenes = sorted({f.rsplit("/", 1)[0] for f, o in zip(fids, off) if o})
        result.gt_collision_scenes = sorted({f.rsplit("/", 1)[0] for f, o in zip(fids, hit) if o})
        if result.gt_off_scenes:
            warnings.append(
                f"the ground truth itself leaves the drivable area in {int(off.sum())} frame(s) of scene(s) "
                f"{', '.join(result.gt_off_scenes[:10])}{' …' if len(result.gt_off_scenes) > 10 else ''} (the floor row counts them)"
            )
        for c in conventions:
            cc = COLLISION_FOR_ADE[c]
            values = safety_values(truth, cc)  # unmasked: the ground truth's own rate
            result.floor[c] = {"model": FLOOR_LABEL, **_row(values, truth, cc)}
            for key in ("offroad", "collision"):
                ok = np.isfinite(values[key])
                if ok.sum() > 0:
                    groups.append((values[key][ok], scenes[ok]))
                    keys.append(f"safety|{FLOOR_LABEL}|{cc}|{key}")
                    slots.append((FLOOR_LABEL, c, key))
    ci = _rate_intervals(groups, resampling)
    for (label, c, key), pair in zip(slots, ci[:, 0]):
        target = result.floor[c] if label == FLOOR_LABEL else result.rows[label][c]
        target[f"{key}_ci95"] = [float(pair[0]), float(pair[1])] if np.isfinite(pair).all() else None
    return result


#: nuScenes keyframes are 0.5 s apart (2 Hz): the step of the ground-truth check below
KEYFRAME_SECONDS = 0.5


def pose_jump_warnings(gt: Any, frame_ids: Sequence[str], label: str) -> list[str]:
    """One warning when some frame's ground truth (N, 6, 2) (m, ego frame; p_0 the origin) moves faster than
    :data:`lightemma.nuscenes.geometry.POSE_JUMP_SPEED` over a :data:`KEYFRAME_SECONDS` step: an ego pose that
    jumps in the dataset (its frames' ADE and safety values are then measured against a wrong ground truth)."""
    from lightemma.nuscenes.geometry import POSE_JUMP_SPEED

    if not len(frame_ids):
        return []
    gt = np.asarray(gt, dtype=np.float64).reshape(len(frame_ids), -1, 2)
    pts = np.concatenate([np.zeros((len(gt), 1, 2)), gt], axis=1)
    with np.errstate(invalid="ignore"):
        step = np.linalg.norm(np.diff(pts, axis=1), axis=2).max(axis=1)
    bad = np.flatnonzero(step > POSE_JUMP_SPEED * KEYFRAME_SECONDS)  # NaN (no ground truth) is not a jump
    if not len(bad):
        return []
    worst = int(bad[np.argmax(step[bad])])
    most = POSE_JUMP_SPEED * KEYFRAME_SECONDS
    return [
        (
            f"{label}: the ground truth of {len(bad)} frame(s) moves more than {most:g} m "
            f"in one {KEYFRAME_SECONDS:g} s step (over {POSE_JUMP_SPEED:g} m/s: a physically impossible ego pose jump "
            f"in the dataset; e.g. {frame_ids[worst]}: {step[worst]:.1f} m); their ADE and safety values are measured "
            "against it"
        )
    ]


#: an imported frame whose recorded pose is further than this from the dataroot's is not placed (n/a)
POSE_CONFLICT_M = 5.0
POSE_NOTE_M = 0.05  # smaller differences are sensor timing (CAM_FRONT vs another channel's pose), noted only


def _recorded_pose_conflicts(
    run: Any, fids: list[str], tokens: list[str], data: SafetyData, warnings: list[str], label: str
) -> dict[int, str]:
    """Compare an imported run's recorded global position and heading (``ego_position``, ``ego_heading``) with
    the dataroot's pose of the same sample; frames that disagree by more than :data:`POSE_CONFLICT_M` get n/a."""
    from lightemma.evaluation.loading import read_frame_records

    records = read_frame_records(run.info.run_dir, fids)
    out: dict[int, str] = {}
    worst, noted = 0.0, 0
    for j, (fid, tok) in enumerate(zip(fids, tokens)):
        rec, pose = records.get(fid, {}), data.poses.get(tok)
        pos, heading = rec.get("ego_position"), rec.get("ego_heading")
        if pose is None or not isinstance(pos, list) or len(pos) < 2:
            continue
        try:
            d = math.hypot(float(pos[0]) - pose[0], float(pos[1]) - pose[1])
            dh = abs((float(heading) - pose[2] + math.pi) % (2 * math.pi) - math.pi) if heading is not None else 0.0
        except (TypeError, ValueError):
            continue
        if d > POSE_CONFLICT_M:
            out[j] = (
                f"the recorded ego position is {d:.1f} m from {data.version}'s pose of sample {tok} (another dataset?)"
            )
        elif d > POSE_NOTE_M or dh > 1e-3:
            noted += 1
            worst = max(worst, d)
    if out:
        warnings.append(
            f"{label}: {len(out)} frame(s) have no safety value: {next(iter(out.values()))} (is --dataroot the dataset the run was made on?)"
        )
    if noted:
        warnings.append(
            f"{label}: the recorded pose differs from {data.version}'s CAM_FRONT pose in {noted} frame(s), by up to {worst:.2f} m "
            "(the dataroot's pose is used)"
        )
    return out


def _concat(parts: Sequence[FrameSafety]) -> FrameSafety:
    if len(parts) == 1:
        return parts[0]
    return FrameSafety(
        np.concatenate([p.area for p in parts]),
        np.concatenate([p.area_ok for p in parts]),
        [r for p in parts for r in p.area_reason],
        [k for p in parts for k in p.area_kind],
        np.concatenate([p.collide for p in parts]),
        np.concatenate([p.coll_ok for p in parts]),
        [r for p in parts for r in p.coll_reason],
        [v for p in parts for v in (p.area_version or [""] * len(p.area_ok))],
    )


def pairwise_safety(
    result: SafetyResult, labels: Sequence[str], convention: str, resampling: Any, *, only: set[str] | None = None
) -> list[dict[str, Any]]:
    """Every pair of runs (a before b) on the frames where both have a value: mean paired difference a − b of
    ``offroad`` and of ``collision`` (the collision convention of ``convention``'s table), scene-bootstrap
    interval, sign-flip p-value over scenes, Holm over all pairs and both metrics. Rows as :func:`pairwise_ade`'s,
    with ``metric`` and ``diff``."""
    from lightemma.evaluation.stats import mark_holm, sign_flip_p

    cc = COLLISION_FOR_ADE[convention]
    per: dict[str, dict[str, dict[str, float]]] = {}
    scene_of: dict[str, str] = {}
    for label in labels:
        rs = result.runs.get(label)
        if rs is None or rs.model is None:
            continue
        values = safety_values(rs.model, cc, gt=rs.truth)
        per[label] = {}
        for key in ("offroad", "collision"):
            per[label][key] = {
                f: float(v)
                for f, v in zip(rs.frame_ids, values[key])
                if math.isfinite(v) and (only is None or f in only)
            }
        for f in rs.frame_ids:
            scene_of.setdefault(f, f.rsplit("/", 1)[0])
    codes: dict[str, int] = {}
    out: list[dict[str, Any]] = []
    groups: list[tuple[np.ndarray, np.ndarray]] = []
    keys: list[str] = []
    where: list[int] = []
    for key in ("offroad", "collision"):
        for a in range(len(labels)):
            for b in range(a + 1, len(labels)):
                la, lb = labels[a], labels[b]
                row: dict[str, Any] = {
                    "model_a": la,
                    "model_b": lb,
                    "metric": key,
                    "convention": cc,
                    "frames": 0,
                    "scenes": 0,
                    "diff": None,
                    "ci95": None,
                    "p_value": None,
                }
                if la in per and lb in per:
                    common = sorted(set(per[la][key]) & set(per[lb][key]))
                    if common:
                        d = np.array([per[la][key][f] - per[lb][key][f] for f in common])
                        sc = np.array([codes.setdefault(scene_of[f], len(codes)) for f in common])
                        row.update(frames=len(common), scenes=int(len(np.unique(sc))), diff=float(d.mean()))
                        groups.append((d, sc))
                        keys.append(f"{la}|{lb}|{cc}|{key}")
                        where.append(len(out))
                out.append(row)
    if groups and resampling.n_resamples:
        ci = _intervals(groups, keys, resampling)
        p = sign_flip_p(groups, keys, resampling)
        for k, i in enumerate(where):
            pair = ci[k, 0]
            out[i]["ci95"] = [float(pair[0]), float(pair[1])] if np.isfinite(pair).all() else None
            out[i]["p_value"] = None if np.isnan(p[k]) else float(p[k])
    mark_holm(out, resampling.confidence)
    return out


def frame_tags(rs: RunSafety) -> dict[str, np.ndarray]:
    """Scenario tags of a run's scored frames from the model's own outcomes: ``collides`` (any step, any
    agent) and ``off_road`` (some corner off the drivable area at some step); False where n/a."""
    n = len(rs.frame_ids)
    if rs.model is None:
        return {"collides": np.zeros(n, bool), "off_road": np.zeros(n, bool)}
    return {
        "collides": rs.model.collide.any(axis=(1, 2)) & rs.model.coll_ok,
        "off_road": rs.model.off_steps.any(axis=1) & rs.model.area_ok,
    }
