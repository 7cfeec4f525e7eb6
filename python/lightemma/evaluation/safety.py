"""Does it drive safely? Collision with annotated agents and leaving the drivable area (docs/definitions.md#safety).

Three layers, one home:

* geometry (Rust core, :mod:`lightemma._core`): :func:`ego_poses`, :func:`footprints`,
  :func:`box_collisions`, :class:`DrivableArea` ``.lookup`` — whole batches, the GIL released;
* the dataset (:func:`load_safety_data`): per keyframe its CAM_FRONT ego pose, the annotated
  agents of the next six keyframes and the drivable area of its log's map, read from the
  dataroot's JSON tables and map files directly (the devkit's conventions, no devkit needed);
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

import json
import math
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lightemma.errors import DatasetError

#: ego box of ST-P3 / UniAD: length × width, metres (the Renault Zoe is 4.084 m long and 1.73 m wide
#: without mirrors; 1.85 m is their margin)
EGO_LENGTH = 4.084
EGO_WIDTH = 1.85
#: the box centre lies this far ahead of the ego_pose reference point (the rear-axle centre), metres:
#: nuScenes' LIDAR_TOP sits 0.943713 m ahead of the rear axle (calibrated_sensor) and UniAD shifts the
#: ego box 0.5 m forward in the LiDAR frame
EGO_OFFSET = 0.943713 + 0.5
#: a step shorter than this keeps the previous heading (BEV-Planner's rule), metres
MIN_STEP = 1.0
#: the base map masks' native resolution (the devkit's MapMask), metres per pixel
MASK_RESOLUTION = 0.1
MASK_FOREGROUND = 255
STEPS = 6
SECONDS = (1, 2, 3)

COLLISION_CONVENTIONS: tuple[str, ...] = ("uniad", "stp3", "any")
#: which collision convention an ADE table shows beside it (the ADE conventions carry the same names)
COLLISION_FOR_ADE = {"uniad": "uniad", "stp3": "stp3", "lightemma": "any"}

# agent classes
VEHICLE, VRU, OTHER = 0, 1, 2
CLASS_NAMES = ("vehicle", "vru")
_VRU_VEHICLES = ("vehicle.bicycle", "vehicle.motorcycle")


def agent_class(category: str) -> int:
    """``VEHICLE`` (``vehicle.*`` but bicycles and motorcycles), ``VRU`` (``human.pedestrian.*``,
    ``vehicle.bicycle``, ``vehicle.motorcycle``: pedestrians, cyclists, motorcyclists) or ``OTHER``
    (barriers, cones, debris, animals, static objects: never counted)."""
    if category.startswith("human.pedestrian") or category.startswith(_VRU_VEHICLES):
        return VRU
    if category.startswith("vehicle."):
        return VEHICLE
    return OTHER


@dataclass(frozen=True)
class EgoModel:
    """The ego footprint and heading rule (defaults: ST-P3/UniAD's box, UniAD's offset, BEV-Planner's rule)."""

    length: float = EGO_LENGTH
    width: float = EGO_WIDTH
    offset: float = EGO_OFFSET
    min_step: float = MIN_STEP

    def kwargs(self) -> dict[str, float]:
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


# -- the drivable area --------------------------------------------------------------------------

ON, OFF, OUTSIDE = 1, 0, 2


@dataclass
class DrivableArea:
    """A map's drivable area: the map expansion's ``drivable_area`` polygons, or a base map mask.

    ``kind``: ``expansion`` (exact point-in-polygon against the union of the layer's polygons,
    holes honoured) or ``mask`` (the devkit's ``MapMask``: pixel (round(x/0.1), round(−y/0.1 + H)),
    NumPy's round, drivable where the pixel is 255 — the *semantic prior*, drivable surface and
    sidewalks). ``source``: the file read.
    """

    kind: str
    source: str
    mask: np.ndarray | None = None  # (H, W) uint8
    xy: np.ndarray | None = None  # (V, 2)
    rings: np.ndarray | None = None  # (R + 1,) int64
    polygons: np.ndarray | None = None  # (P + 1,) int64

    def lookup(self, traj: Any, poses: Any, ego: EgoModel = EGO) -> np.ndarray:
        """(N, T, 5) uint8 of ``ON`` / ``OFF`` / ``OUTSIDE`` (the point is not covered by the mask
        image: counted off the drivable area, and reported) for the footprint's 4 corners (front-left,
        front-right, rear-right, rear-left) and then its reference point, at every step."""
        from lightemma import _core

        t, p = _traj_poses(traj, poses)
        if self.kind == "mask":
            return _core.mask_area(t, p, self.mask, MASK_RESOLUTION, MASK_FOREGROUND, **ego.kwargs())
        return _core.polygon_area(t, p, self.xy, self.rings, self.polygons, **ego.kwargs())

    def contains(self, points: Any) -> np.ndarray:
        """(M,) uint8 ``ON`` / ``OFF`` / ``OUTSIDE`` codes of global points (M, 2)."""
        pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 2)
        from lightemma import _core

        if self.kind == "mask":
            return _core.mask_lookup(pts, self.mask, MASK_RESOLUTION, MASK_FOREGROUND)
        poses = np.column_stack([pts, np.zeros(len(pts))])  # a one-step trajectory at the origin of each point
        return self.lookup(np.zeros((len(pts), 1, 2)), poses, EgoModel(offset=0.0))[:, 0, 4]


def read_map_mask(path: str | os.PathLike[str]) -> DrivableArea:
    """A base map mask (``maps/<token>.png``) as the devkit's ``MapMask`` reads it at 0.1 m/px (PIL, no resize)."""
    from PIL import Image

    Image.MAX_IMAGE_PIXELS = None  # the real masks are ~ 20k × 20k (the devkit lifts the limit too)
    try:
        with Image.open(path) as img:
            mask = np.array(img)
    except (OSError, ValueError) as exc:
        raise DatasetError(f"map mask {path} cannot be read: {exc}") from None
    if mask.ndim != 2:
        raise DatasetError(f"map mask {path} has shape {mask.shape}; expected a one-channel image")
    return DrivableArea("mask", os.fspath(path), mask=np.ascontiguousarray(mask, dtype=np.uint8))


def read_expansion(path: str | os.PathLike[str]) -> DrivableArea:
    """The ``drivable_area`` layer of a map-expansion JSON (``maps/expansion/<location>.json``) as polygons.

    Each drivable_area record lists ``polygon_tokens``; each polygon has ``exterior_node_tokens``
    and ``holes`` (``node_tokens``); nodes carry global ``x``, ``y`` (the devkit's ``NuScenesMap``).
    """
    try:
        with open(path, encoding="utf-8") as f:
            doc = json.load(f)
        nodes = {n["token"]: (float(n["x"]), float(n["y"])) for n in doc["node"]}
        polys = {p["token"]: p for p in doc["polygon"]}
        xy: list[tuple[float, float]] = []
        rings, polygons = [0], [0]
        for record in doc["drivable_area"]:
            for ptok in record["polygon_tokens"]:
                poly = polys[ptok]
                for ring in [poly["exterior_node_tokens"], *(h["node_tokens"] for h in poly.get("holes", []))]:
                    xy.extend(nodes[t] for t in ring)
                    rings.append(len(xy))
                polygons.append(len(rings) - 1)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise DatasetError(f"map expansion {path}: cannot read its drivable_area layer ({type(exc).__name__}: {exc})") from None
    return DrivableArea("expansion", os.fspath(path), xy=np.asarray(xy, dtype=np.float64).reshape(-1, 2),
                        rings=np.asarray(rings, dtype=np.int64), polygons=np.asarray(polygons, dtype=np.int64))


# -- the dataset ----------------------------------------------------------------------------------


@dataclass
class SafetyData:
    """What the safety metrics need from one nuScenes version, keyed by sample token.

    ``poses``: CAM_FRONT keyframe ego pose (x, y, yaw) — the pose the trajectories are relative to;
    ``future``: the next keyframes of the scene (up to 6); ``map_of``: the map key of the sample's
    log; ``areas``: map key → :class:`DrivableArea`, or the reason there is none; ``boxes`` /
    ``classes`` / ``box_tokens``: the sample's annotated agents (K, 5) (global x, y, yaw, length,
    width), their class codes (K,) and tokens; ``annotated``: the version has any annotation.
    """

    dataroot: str
    version: str
    poses: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    future: dict[str, list[str]] = field(default_factory=dict)
    map_of: dict[str, str] = field(default_factory=dict)
    areas: dict[str, DrivableArea | str] = field(default_factory=dict)
    boxes: dict[str, np.ndarray] = field(default_factory=dict)
    classes: dict[str, np.ndarray] = field(default_factory=dict)
    box_tokens: dict[str, list[str]] = field(default_factory=dict)
    annotated: bool = False
    warnings: list[str] = field(default_factory=list)

    def area_kinds(self) -> list[str]:
        """The kinds of drivable area in use (``expansion``, ``mask``), sorted."""
        return sorted({a.kind for a in self.areas.values() if isinstance(a, DrivableArea)})


def _table(root: Path, name: str) -> list[dict[str, Any]]:
    path = root / f"{name}.json"
    try:
        with open(path, encoding="utf-8") as f:
            rows = json.load(f)
    except FileNotFoundError:
        raise DatasetError(f"nuScenes table {path} is missing") from None
    except (OSError, ValueError) as exc:
        raise DatasetError(f"nuScenes table {path} cannot be read: {exc}") from None
    if not isinstance(rows, list):
        raise DatasetError(f"nuScenes table {path} is not a list of records")
    return rows


def _yaw(q: Sequence[float]) -> float:
    w, x, y, z = (float(v) for v in q)
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def _box(ann: Mapping[str, Any]) -> tuple[float, float, float, float, float]:
    """(x, y, yaw, length, width) of a sample_annotation; a degenerate box raises naming its token."""
    tok = ann.get("token", "?")
    try:
        x, y = float(ann["translation"][0]), float(ann["translation"][1])
        w, length = float(ann["size"][0]), float(ann["size"][1])  # nuScenes size = (width, length, height)
        q = [float(v) for v in ann["rotation"]]
    except (KeyError, IndexError, TypeError, ValueError):
        raise DatasetError(f"sample_annotation {tok}: translation, size or rotation is missing or not numeric") from None
    values = (x, y, w, length, *q)
    if not all(math.isfinite(v) for v in values) or w <= 0 or length <= 0 or len(q) != 4 or not any(q):
        raise DatasetError(f"sample_annotation {tok}: degenerate box (size {ann['size']}, translation {ann['translation']}, "
                           f"rotation {ann['rotation']}); sizes must be positive and values finite")
    return x, y, _yaw(q), length, w


#: a map location as nuScenes names them (singapore-onenorth, boston-seaport): letters, digits, - and _, no path
_MAP_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,99}")


def load_safety_data(dataroot: str | os.PathLike[str], version: str, *, samples: set[str] | None = None) -> SafetyData:
    """Read poses, agents and drivable areas of ``dataroot/version`` (only ``samples`` and their futures if given).

    The drivable area of a log is the map expansion's ``drivable_area`` (``maps/expansion/<location>.json``)
    where the dataroot has it, else the base map mask of the ``map`` table that lists the log. Maps that
    cannot be read are recorded as reasons (frames on them get n/a), not raised; a degenerate
    annotation box raises :class:`DatasetError` naming its token.
    """
    root = Path(dataroot).expanduser()
    tables = root / version
    if not tables.is_dir():
        raise DatasetError(f"{tables} is not a folder: no nuScenes version {version!r} under {root}")
    data = SafetyData(os.fspath(root), version)
    channel_of_sensor = {s["token"]: s.get("channel") for s in _table(tables, "sensor")}
    channel_of_cs = {c["token"]: channel_of_sensor.get(c.get("sensor_token")) for c in _table(tables, "calibrated_sensor")}
    sample_rows = _table(tables, "sample")
    by_token = {s["token"]: s for s in sample_rows}
    wanted = set(by_token) if samples is None else {t for t in samples if t in by_token}
    # the scene's next keyframes
    for tok in list(wanted):
        chain, nxt = [], by_token[tok].get("next", "")
        while nxt and len(chain) < STEPS and nxt in by_token:
            chain.append(nxt)
            nxt = by_token[nxt].get("next", "")
        data.future[tok] = chain
    needed = wanted | {t for c in data.future.values() for t in c}
    pose_token: dict[str, str] = {}
    for sd in _table(tables, "sample_data"):
        if sd.get("is_key_frame") and sd.get("sample_token") in wanted and channel_of_cs.get(sd.get("calibrated_sensor_token")) == "CAM_FRONT":
            pose_token[sd["sample_token"]] = sd["ego_pose_token"]
    by_pose = {tok: st for st, tok in pose_token.items()}
    for ep in _table(tables, "ego_pose"):
        st = by_pose.get(ep.get("token"))
        if st is None:
            continue
        try:
            x, y = float(ep["translation"][0]), float(ep["translation"][1])
            yaw = _yaw(ep["rotation"])
        except (KeyError, IndexError, TypeError, ValueError):
            continue  # no usable pose: the frame reads n/a with the reason
        if all(math.isfinite(v) for v in (x, y, yaw)):
            data.poses[st] = (x, y, yaw)
    # maps: scene → log → location, map record of the log
    scene_log = {s["token"]: s.get("log_token") for s in _table(tables, "scene")}
    logs = {lg["token"]: lg for lg in _table(tables, "log")}
    mask_of_log: dict[str, str] = {}
    map_record: dict[str, dict] = {}
    for rec in _table(tables, "map"):
        for lt in rec.get("log_tokens", []):
            mask_of_log[lt] = rec.get("filename", "")
            map_record[lt] = rec
    for tok in wanted:
        log_token = scene_log.get(by_token[tok].get("scene_token"))
        log = logs.get(log_token or "")
        if log is None:
            continue
        location = str(log.get("location", ""))
        if not _MAP_NAME.fullmatch(location):  # a name, never a path: "../../x" would read a file outside the dataroot
            key = f"location:{location}"
            data.map_of[tok] = key
            data.areas[key] = f"log {log.get('logfile', log_token)}: location {location!r} is not a map name"
            continue
        expansion = root / "maps" / "expansion" / f"{location}.json"
        key = f"expansion:{location}" if expansion.is_file() else f"mask:{mask_of_log.get(log_token, '')}"
        data.map_of[tok] = key
        if key in data.areas:
            continue
        try:
            if key.startswith("expansion:"):
                data.areas[key] = read_expansion(expansion)
            elif not mask_of_log.get(log_token):
                data.areas[key] = f"log {log.get('logfile', log_token)} has no map record"
            else:
                from lightemma.frames import dataset_path

                mask_path = Path(dataset_path(root, map_record[log_token], "map"))  # inside the dataroot, or n/a with why
                data.areas[key] = read_map_mask(mask_path) if mask_path.is_file() else f"map mask {mask_path} is missing"
        except DatasetError as exc:
            data.areas[key] = str(exc)
    # agents
    annotations = _table(tables, "sample_annotation")
    data.annotated = bool(annotations)
    if data.annotated:
        categories = {c["token"]: c.get("name", "") for c in _table(tables, "category")}
        klass = {i["token"]: agent_class(categories.get(i.get("category_token"), "")) for i in _table(tables, "instance")}
        gathered: dict[str, tuple[list, list, list]] = {}
        for ann in annotations:
            st = ann.get("sample_token")
            if st not in needed:
                continue
            cls = klass.get(ann.get("instance_token"), OTHER)
            if cls == OTHER:
                continue
            b, c, t = gathered.setdefault(st, ([], [], []))
            b.append(_box(ann))
            c.append(cls)
            t.append(ann.get("token", "?"))
        for st in needed:
            b, c, t = gathered.get(st, ([], [], []))
            data.boxes[st] = np.asarray(b, dtype=np.float64).reshape(-1, 5)
            data.classes[st] = np.asarray(c, dtype=np.int8)
            data.box_tokens[st] = t
    return data


# -- per-frame outcomes ------------------------------------------------------------------------


@dataclass
class FrameSafety:
    """Per-frame safety outcomes of N trajectories.

    ``area``: (N, 6, 5) uint8 lookups (4 corners, then the reference point), valid where
    ``area_ok``; ``collide``: (N, 6, 2) bool overlap with a vehicle / a vulnerable road user at each
    step, valid where ``coll_ok``; ``area_reason`` / ``coll_reason``: why a frame has no value ("" when
    it has one); ``area_kind``: per frame ``expansion`` / ``mask`` / "".
    """

    area: np.ndarray
    area_ok: np.ndarray
    area_reason: list[str]
    area_kind: list[str]
    collide: np.ndarray
    coll_ok: np.ndarray
    coll_reason: list[str]

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
        raise ValueError(f"trajectories must have shape ({n}, {STEPS}, 2), got {traj.shape}")
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
            return f"no CAM_FRONT ego pose for sample {sample_tokens[i]} in {data.version}"
        return "" if finite[i] else "no trajectory"

    # drivable area, per map
    area = np.zeros((n, STEPS, 5), dtype=np.uint8)
    area_ok = np.zeros(n, dtype=bool)
    area_reason = [base_reason(i) for i in range(n)]
    area_kind = [""] * n
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
    return FrameSafety(area, area_ok, area_reason, area_kind, collide, coll_ok, coll_reason)


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
    raise ValueError(f"unknown collision convention {convention!r} (choose from {', '.join(COLLISION_CONVENTIONS)})")


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
    return max(counts, key=counts.get) if counts else None


def frame_warnings(fs: FrameSafety, frame_ids: Sequence[str], what: str) -> list[str]:
    """One warning per kind of missing value, with a count and an example frame; mask coverage too."""
    out = []
    for which, ok, reasons in (("off-road", fs.area_ok, fs.area_reason), ("collision", fs.coll_ok, fs.coll_reason)):
        groups: dict[str, list[int]] = {}
        for i in np.flatnonzero(~ok):
            if reasons[i] and reasons[i] not in ("no trajectory", "no annotations"):
                groups.setdefault(reasons[i], []).append(int(i))
        for reason, rows in groups.items():
            out.append(f"{what}: {len(rows)} frame(s) have no {which} value (n/a): {reason} (e.g. {frame_ids[rows[0]]})")
    outside = np.flatnonzero(fs.outside_mask)
    if len(outside):
        out.append(f"{what}: the map mask does not cover the footprint of {len(outside)} frame(s) (e.g. {frame_ids[outside[0]]}); "
                   "those points count as off the drivable area")
    return out


# -- evaluation of runs ------------------------------------------------------------------------------

#: row keys this module adds to every accuracy row (values are shares 0..1; tables print %)
ROW_KEYS = (*AREA_KEYS, *COLLISION_KEYS, "offroad_ci95", "collision_ci95", "safety_frames", "offroad_frames", "collision_frames",
            "area_source", "offroad_na", "collision_na", "collision_convention")
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
        return {"floor": self.floor, "gt_off_road_scenes": self.gt_off_scenes, "gt_collision_scenes": self.gt_collision_scenes}


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


def _row(values: Mapping[str, np.ndarray], fs: FrameSafety, convention: str) -> dict[str, Any]:
    r = rates(values)
    area_ok, coll_ok = np.isfinite(values["offroad"]), np.isfinite(values["collision"])
    kinds = sorted({k for k in fs.area_kind if k})
    return {**r, "safety_frames": int(len(fs.area_ok)), "offroad_frames": int(area_ok.sum()), "collision_frames": int(coll_ok.sum()),
            "area_source": "+".join(kinds) if kinds else None, "offroad_na": None if area_ok.any() else (na_reason(fs, "area") or "no frame"),
            "collision_na": None if coll_ok.any() else (na_reason(fs, "collision") or "no frame"), "collision_convention": convention}


def _intervals(groups: list[tuple[np.ndarray, np.ndarray]], keys: list[str], resampling: Any) -> np.ndarray:
    from lightemma.evaluation.stats import bootstrap_ci

    if not groups or not resampling.n_resamples:
        return np.full((len(groups), 1, 2), np.nan)
    return bootstrap_ci(groups, keys, resampling)


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
) -> SafetyResult:
    """Safety rows for evaluated runs: ``entries`` = (label, RunData, scored rows) as in :func:`evaluate_loaded`.

    Each ADE convention's table shows the collision convention of the same name (``lightemma`` → ``any``);
    off-road values are the same in every table. Intervals: scene bootstrap as for ADE. The floor is the
    ground truth's own (unmasked) rates over every frame with usable ground truth in any run.
    """
    warnings: list[str] = []
    datasets: dict[tuple[str, str], list[int]] = {}
    resolved = []
    for i, (_, run, _) in enumerate(entries):
        ds = _resolve_dataset(run, dataroot, version)
        resolved.append(ds)
        if isinstance(ds, tuple):
            datasets.setdefault(ds, []).append(i)
    loaded: dict[tuple[str, str], SafetyData | str] = {}
    for ds, members in datasets.items():
        tokens = {sample_token_of(f) for i in members for f in entries[i][1].frame_ids}
        try:
            loaded[ds] = load_safety_data(ds[0], ds[1], samples=tokens)
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
            result.rows[label] = {c: {**na, "offroad_na": reason, "collision_na": reason, "collision_convention": COLLISION_FOR_ADE[c]} for c in conventions}
            continue
        tokens = [sample_token_of(f) for f in fids]
        conflicts = _recorded_pose_conflicts(run, fids, tokens, data, warnings, label) if getattr(run.info, "imported", False) else {}
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
            warnings.append(f"the ground truth itself leaves the drivable area in {int(off.sum())} frame(s) of scene(s) "
                            f"{', '.join(result.gt_off_scenes[:10])}{' …' if len(result.gt_off_scenes) > 10 else ''} (the floor row counts them)")
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
    ci = _intervals(groups, keys, resampling)
    for (label, c, key), pair in zip(slots, ci[:, 0]):
        target = result.floor[c] if label == FLOOR_LABEL else result.rows[label][c]
        target[f"{key}_ci95"] = [float(pair[0]), float(pair[1])] if np.isfinite(pair).all() else None
    return result


#: an imported frame whose recorded pose is further than this from the dataroot's is not placed (n/a)
POSE_CONFLICT_M = 5.0
POSE_NOTE_M = 0.05  # smaller differences are sensor timing (CAM_FRONT vs another channel's pose), noted only


def _recorded_pose_conflicts(run: Any, fids: list[str], tokens: list[str], data: SafetyData, warnings: list[str], label: str) -> dict[int, str]:
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
            out[j] = f"the recorded ego position is {d:.1f} m from {data.version}'s pose of sample {tok} (another dataset?)"
        elif d > POSE_NOTE_M or dh > 1e-3:
            noted += 1
            worst = max(worst, d)
    if out:
        warnings.append(f"{label}: {len(out)} frame(s) have no safety value: {next(iter(out.values()))} (is --dataroot the dataset the run was made on?)")
    if noted:
        warnings.append(f"{label}: the recorded pose differs from {data.version}'s CAM_FRONT pose in {noted} frame(s), by up to {worst:.2f} m "
                        "(the dataroot's pose is used)")
    return out


def _concat(parts: Sequence[FrameSafety]) -> FrameSafety:
    if len(parts) == 1:
        return parts[0]
    return FrameSafety(np.concatenate([p.area for p in parts]), np.concatenate([p.area_ok for p in parts]), [r for p in parts for r in p.area_reason],
                       [k for p in parts for k in p.area_kind], np.concatenate([p.collide for p in parts]),
                       np.concatenate([p.coll_ok for p in parts]), [r for p in parts for r in p.coll_reason])


def pairwise_safety(result: SafetyResult, labels: Sequence[str], convention: str, resampling: Any, *, only: set[str] | None = None) -> list[dict[str, Any]]:
    """Every pair of runs (a before b) on the frames where both have a value: mean paired difference a − b of
    ``offroad`` and of ``collision`` (the collision convention of ``convention``'s table), scene-bootstrap
    interval, sign-flip p-value over scenes, Holm over all pairs and both metrics. Rows as :func:`pairwise_ade`'s,
    with ``metric`` and ``diff``."""
    from lightemma.evaluation.stats import holm, sign_flip_p

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
            per[label][key] = {f: float(v) for f, v in zip(rs.frame_ids, values[key]) if math.isfinite(v) and (only is None or f in only)}
        for f in rs.frame_ids:
            scene_of.setdefault(f, f.rsplit("/", 1)[0])
    codes: dict[str, int] = {}
    out, groups, keys, where = [], [], [], []
    for key in ("offroad", "collision"):
        for a in range(len(labels)):
            for b in range(a + 1, len(labels)):
                la, lb = labels[a], labels[b]
                row: dict[str, Any] = {"model_a": la, "model_b": lb, "metric": key, "convention": cc, "frames": 0, "scenes": 0, "diff": None, "ci95": None, "p_value": None}
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
    adjusted = holm([np.nan if r["p_value"] is None else r["p_value"] for r in out]) if out else []
    alpha = 1.0 - resampling.confidence
    for row, adj in zip(out, adjusted):
        row["p_holm"] = None if np.isnan(adj) else float(adj)
        row["significant"] = bool(row["p_holm"] is not None and row["p_holm"] <= alpha)
    return out


def frame_tags(rs: RunSafety) -> dict[str, np.ndarray]:
    """Scenario tags of a run's scored frames from the model's own outcomes: ``collides`` (any step, any
    agent) and ``off_road`` (some corner off the drivable area at some step); False where n/a."""
    n = len(rs.frame_ids)
    if rs.model is None:
        return {"collides": np.zeros(n, bool), "off_road": np.zeros(n, bool)}
    return {"collides": rs.model.collide.any(axis=(1, 2)) & rs.model.coll_ok, "off_road": rs.model.off_steps.any(axis=1) & rs.model.area_ok}
