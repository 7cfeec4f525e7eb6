"""What the safety metrics and the planning score read of a nuScenes version, per keyframe: its CAM_FRONT ego pose,
the annotated agents (and static objects) of its next keyframes, and the drivable area of its log's map.

:func:`load_safety_data` reads the tables through the frame reader (:func:`lightemma.nuscenes.frames.load_tables`: the
same dataroot check, the same structural checks, the same CAM_FRONT keyframes) and the maps through
:mod:`lightemma.nuscenes.map_files`; a pose is checked by the frame reader's rule
(:func:`lightemma.nuscenes.frames.ego_pose_xy_yaw`), a box by :func:`_box`. What cannot be used is recorded as a
reason (the frames it touches get n/a), never guessed; the evaluation receives the parsed :class:`SafetyData`.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lightemma.errors import DatasetError, InputError
from lightemma.nuscenes.frames import (
    FUTURE,
    BadRecordError,
    dataset_path,
    ego_pose_xy_yaw,
    load_tables,
    sample_timestamp,
)
from lightemma.nuscenes.geometry import MAX_COORDINATE_M, unit_quaternion, yaw_from_quaternion
from lightemma.nuscenes.json_tables import read_table
from lightemma.nuscenes.map_files import MAP_NAME, DrivableArea, file_problem, read_expansion, read_map_mask

#: annotation boxes longer or wider than this are refused, metres (articulated buses are about 18 m long)
MAX_AGENT_SIZE_M = 100.0

#: which annotation boxes count as agents (docs/definitions.md#safety): ``all`` (default: every vehicle and
#: VRU box, as UniAD's occupancy labels — ``occ_filter_by_valid_flag=False``, ``filter_invisible=False``),
#: ``valid`` (boxes with ``num_lidar_pts + num_radar_pts > 0``: mmdet3d's ``valid_flag``, VAD's ground-truth
#: boxes), ``visible`` (boxes whose visibility is not ``v0-40``: ST-P3's ``FILTER_INVISIBLE_VEHICLES``)
AGENT_FILTERS: tuple[str, ...] = ("all", "valid", "visible")

# agent classes
VEHICLE, VRU, OTHER = 0, 1, 2
CLASS_NAMES = ("vehicle", "vru")
_VRU_VEHICLES = ("vehicle.bicycle", "vehicle.motorcycle")


#: nuScenes categories that are static objects for the planning score (NAVSIM: every tracked object outside nuPlan's
#: ``AGENT_TYPES`` — vehicle, pedestrian, bicycle — is a ``StaticObject``: barrier, traffic cone, construction-zone
#: sign, generic object)
STATIC_OBJECT_PREFIXES = ("movable_object.", "static_object.", "animal")


def static_object(category: str) -> bool:
    """Whether a nuScenes category is a static object of the planning score (docs/definitions.md#planning-score):
    ``movable_object.*`` (barrier, trafficcone, debris, pushable_pullable), ``static_object.*`` (bicycle_rack) and
    ``animal`` — nuPlan's barrier, traffic cone and generic object, none of them in its ``AGENT_TYPES``. An unknown
    or missing category is neither an agent nor a static object."""
    return category.startswith(STATIC_OBJECT_PREFIXES)


def agent_class(category: str) -> int:
    """``VEHICLE`` (``vehicle.*`` but bicycles and motorcycles), ``VRU`` (``human.pedestrian.*``,
    ``vehicle.bicycle``, ``vehicle.motorcycle``: pedestrians, cyclists, motorcyclists) or ``OTHER``
    (barriers, cones, debris, animals, static objects: never counted)."""
    if category.startswith("human.pedestrian") or category.startswith(_VRU_VEHICLES):
        return VRU
    if category.startswith("vehicle."):
        return VEHICLE
    return OTHER


@dataclass
class SafetyData:
    """What the safety metrics need from one nuScenes version, keyed by sample token.

    ``poses``: CAM_FRONT keyframe ego pose (x, y, yaw) — the pose the trajectories are relative to;
    ``future``: the next keyframes of the scene (up to 6); ``map_of``: the map key of the sample's
    log; ``areas``: map key → :class:`DrivableArea`, or the reason there is none; ``boxes`` /
    ``classes`` / ``box_tokens``: the sample's annotated agents (K, 5) (global x, y, yaw, length,
    width), their class codes (K,) and tokens (those the ``agents`` filter keeps); ``annotated``: the version
    has any annotation; ``pose_reasons``: sample → why its ego pose is unusable; ``bad_boxes``: sample → why
    one of its annotations is refused (frames whose six later keyframes include it get collision n/a);
    ``agents``: the filter of :data:`AGENT_FILTERS` applied.
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
    pose_reasons: dict[str, str] = field(default_factory=dict)
    bad_boxes: dict[str, str] = field(default_factory=dict)
    agents: str = "all"
    #: with ``history`` > 0 (the planning score): sample → its earlier keyframes, nearest first; the poses of those
    #: and of the later keyframes are in ``poses`` too, ``box_instances`` holds each box's instance token and
    #: ``timestamps`` each read sample's timestamp (µs)
    past: dict[str, list[str]] = field(default_factory=dict)
    box_instances: dict[str, list[str | None]] = field(default_factory=dict)
    timestamps: dict[str, float] = field(default_factory=dict)
    #: with ``history`` > 0 only (the planning score; the safety metrics never read them): sample → its static
    #: objects' boxes (K, 5) (:func:`static_object`: barriers, cones, debris, …) and their instance tokens, and why
    #: one of its static objects' annotations is refused
    objects: dict[str, np.ndarray] = field(default_factory=dict)
    object_instances: dict[str, list[str | None]] = field(default_factory=dict)
    bad_objects: dict[str, str] = field(default_factory=dict)

    def area_kinds(self) -> list[str]:
        """The kinds of drivable area in use (``expansion``, ``mask``), sorted."""
        return sorted({a.kind for a in self.areas.values() if isinstance(a, DrivableArea)})


def _yaw(q: Any) -> float:
    """Yaw (rad) of a nuScenes rotation under the frame reader's rule
    (:func:`lightemma.nuscenes.geometry.unit_quaternion`): a quaternion that is not a unit one raises ``ValueError``."""
    return float(yaw_from_quaternion(unit_quaternion(q)))


def _finite(values: Any, n: int) -> list[float] | None:
    """The first ``n`` entries of ``values`` as floats when they are finite numbers (bools, text refused), else None."""
    if not isinstance(values, (list, tuple)) or len(values) < n:
        return None
    out = []
    for v in values[:n]:
        if not isinstance(v, (int, float)) or isinstance(v, bool):
            return None
        try:
            f = float(v)
        except OverflowError:
            return None
        if not math.isfinite(f):
            return None
        out.append(f)
    return out


def _three(values: Any) -> list[float] | None:
    """Exactly 3 finite numbers as floats (a nuScenes translation or size), else None."""
    return _finite(values, 3) if isinstance(values, (list, tuple)) and len(values) == 3 else None


def _box(ann: Mapping[str, Any], where: str = "sample_annotation") -> tuple[float, float, float, float, float]:
    """(x, y, yaw, length, width) of a sample_annotation; a box that is not a box raises :class:`DatasetError`
    naming ``where`` (the table file) and the token: a centre that is not finite or beyond
    :data:`MAX_COORDINATE_M`, a size not in (0, :data:`MAX_AGENT_SIZE_M`] m, a rotation that is not a unit
    quaternion (the frame reader's rule), a translation or size that is not exactly 3 numbers."""
    tok = ann.get("token", "?")
    xy, size = _three(ann.get("translation")), _three(ann.get("size"))
    shown = f"size {ann.get('size')}, translation {ann.get('translation')}, rotation {ann.get('rotation')}"
    if xy is None or size is None:
        raise DatasetError(f"{where} {tok}: degenerate box ({shown}); translation and size must be finite numbers")
    w, length = size[0], size[1]  # nuScenes size = (width, length, height)
    sized = 0 < w <= MAX_AGENT_SIZE_M and 0 < length <= MAX_AGENT_SIZE_M
    if not sized or max(abs(xy[0]), abs(xy[1])) > MAX_COORDINATE_M:
        raise DatasetError(
            f"{where} {tok}: degenerate box ({shown}); sizes must be in (0, {MAX_AGENT_SIZE_M:g}] m "
            f"and the centre within ±{MAX_COORDINATE_M:g} m"
        )
    try:
        yaw = _yaw(ann.get("rotation"))
    except ValueError as exc:
        raise DatasetError(f"{where} {tok}: field rotation = {ann.get('rotation')!r} {exc}") from None
    return xy[0], xy[1], yaw, length, w


def _keeps(ann: Mapping[str, Any], agents: str, v0_40: set[str]) -> bool:
    """Whether the ``agents`` filter (:data:`AGENT_FILTERS`) keeps an annotation; counts that are not counts
    raise ``ValueError``."""
    if agents == "valid":
        counts = [ann.get("num_lidar_pts"), ann.get("num_radar_pts")]
        numbers = [c for c in counts if isinstance(c, int) and not isinstance(c, bool) and c >= 0]
        if len(numbers) != len(counts):
            raise InputError(
                f"num_lidar_pts / num_radar_pts = {counts} are not counts (the 'valid' agent filter needs them)"
            )
        return numbers[0] + numbers[1] > 0
    if agents == "visible":
        return _ref(ann, "visibility_token") not in v0_40
    return True


def _ref(record: Mapping[str, Any], field: str) -> str | None:
    """A token a record refers to, or None when the field is not text (a list would not even be a dict key)."""
    value = record.get(field)
    return value if isinstance(value, str) else None


def load_safety_data(
    dataroot: str | os.PathLike[str],
    version: str,
    *,
    samples: set[str] | None = None,
    agents: str = "all",
    history: int = 0,
) -> SafetyData:
    """Read poses, agents and drivable areas of ``dataroot/version`` (only ``samples`` and their futures if given).

    The drivable area of a log is the map expansion's ``drivable_area`` (``maps/expansion/<location>.json``)
    where the dataroot has it, else the base map mask of the ``map`` table that lists the log; an expansion
    path that is there but not a regular file (a FIFO, a link to a device) is that map's n/a reason, not a
    silent fall-back to the mask. Maps that cannot be read, ego poses that are not poses (rotation under the
    frame reader's unit-quaternion rule) and annotation boxes that are not boxes (:func:`_box`) are
    recorded as reasons (the frames they touch get n/a), not raised. ``agents``: which boxes count
    (:data:`AGENT_FILTERS`). ``history`` > 0 (the planning score, :mod:`lightemma.evaluation.planning_score`) also
    reads up to that many earlier keyframes of each sample (``past``), the poses of the earlier and later
    keyframes, the boxes of the keyframe just before, each box's instance token and the samples' timestamps;
    what the safety metrics read is the same either way. A table that is missing, unreadable or holds a record
    that is not an object raises :class:`DatasetError` naming the file.
    """
    if agents not in AGENT_FILTERS:
        raise InputError(f"unknown agent filter {agents!r}; choose one of {', '.join(AGENT_FILTERS)}")
    root = Path(dataroot).expanduser()
    tables = root / version
    read = load_tables(root, version)  # the dataroot check (all 13 tables), the frame reader's structural checks
    data = SafetyData(os.fspath(root), version, agents=agents)
    by_token = read.samples
    wanted = set(by_token) if samples is None else {t for t in samples if t in by_token}
    # the scene's next keyframes
    for tok in list(wanted):
        chain: list[str] = []
        nxt = by_token[tok].get("next", "")
        while isinstance(nxt, str) and nxt and len(chain) < FUTURE and nxt in by_token:
            chain.append(nxt)
            nxt = by_token[nxt].get("next", "")
        data.future[tok] = chain
    needed = wanted | {t for c in data.future.values() for t in c}
    posed, boxed = wanted, needed
    if history > 0:
        for tok in wanted:
            chain, prv = [], by_token[tok].get("prev", "")
            while isinstance(prv, str) and prv and len(chain) < history and prv in by_token:
                chain.append(prv)
                prv = by_token[prv].get("prev", "")
            data.past[tok] = chain
        posed = needed | {t for c in data.past.values() for t in c}
        boxed = needed | {c[0] for c in data.past.values() if c}
        for tok in posed:
            try:
                data.timestamps[tok] = float(sample_timestamp(by_token[tok]))
            except BadRecordError:  # not a whole, non-negative number of µs: no timestamp, as the frame reader rules
                pass
    # each posed sample's CAM_FRONT keyframe pose, under the frame reader's rule
    for st in posed:
        sd_token = read.front_keyframes.get(st)
        pose_token = _ref(read.sample_data[sd_token], "ego_pose_token") if sd_token is not None else None
        ep = read.ego_poses.get(pose_token) if pose_token is not None else None
        if ep is None:
            continue
        try:
            data.poses[st] = ego_pose_xy_yaw(ep)
        except BadRecordError as exc:  # no usable pose: the frame reads n/a with the reason
            data.pose_reasons[st] = f"{tables / 'ego_pose.json'}: {exc}"
    # maps: scene → log → location, map record of the log
    scene_log = {s["token"]: _ref(s, "log_token") for s in read.scenes}
    logs = {lg["token"]: lg for lg in read_table(root, version, "log")}
    # looked up by a scene's log token, None where the scene names none (never a key: nothing is found)
    mask_of_log: dict[str | None, str] = {}
    map_record: dict[str | None, dict[str, Any]] = {}
    for rec in read_table(root, version, "map"):
        log_tokens = rec.get("log_tokens", [])
        for lt in log_tokens if isinstance(log_tokens, list) else []:
            if isinstance(lt, str):
                mask_of_log[lt] = rec.get("filename", "")
                map_record[lt] = rec
    for tok in wanted:
        log_token = scene_log.get(_ref(by_token[tok], "scene_token"))
        log = logs.get(log_token or "")
        if log is None:
            continue
        location = str(log.get("location", ""))
        if not MAP_NAME.fullmatch(location):  # a name, never a path: "../../x" would read a file outside the dataroot
            key = f"location:{location}"
            data.map_of[tok] = key
            data.areas[key] = f"log {log.get('logfile', log_token)}: location {location!r} is not a map name"
            continue
        expansion = root / "maps" / "expansion" / f"{location}.json"
        there = os.path.lexists(expansion)
        key = f"expansion:{location}" if there else f"mask:{mask_of_log.get(log_token, '')}"
        data.map_of[tok] = key
        if key in data.areas:
            continue
        try:
            if key.startswith("expansion:"):
                problem = file_problem(expansion)  # never a silent fall-back to the mask
                data.areas[key] = f"map expansion {problem}" if problem else read_expansion(expansion)
            elif not mask_of_log.get(log_token):
                data.areas[key] = f"log {log.get('logfile', log_token)} has no map record"
            else:
                # inside the dataroot, or n/a with why
                mask_path = Path(dataset_path(root, map_record[log_token], "map"))
                there = os.path.lexists(mask_path)
                data.areas[key] = read_map_mask(mask_path) if there else f"map mask {mask_path} is missing"
        except DatasetError as exc:
            data.areas[key] = str(exc)
    # agents
    annotations = read_table(root, version, "sample_annotation")
    data.annotated = bool(annotations)
    if data.annotated:
        categories = {c["token"]: str(c.get("name", "")) for c in read_table(root, version, "category")}
        instances = read_table(root, version, "instance")
        klass = {i["token"]: agent_class(categories.get(_ref(i, "category_token"), "")) for i in instances}
        static = (
            {i["token"] for i in instances if static_object(categories.get(_ref(i, "category_token"), ""))}
            if history > 0
            else set()
        )
        objects: dict[str, tuple[list, list]] = {}
        v0_40 = set()
        if agents == "visible":
            v0_40 = {v["token"] for v in read_table(root, version, "visibility") if v.get("level") == "v0-40"}
        where = os.fspath(tables / "sample_annotation.json")
        gathered: dict[str, tuple[list, list, list, list]] = {}
        for ann in annotations:
            sample = _ref(ann, "sample_token")
            if sample is None or sample not in boxed:  # boxed holds str tokens only
                continue
            cls = klass.get(_ref(ann, "instance_token"), OTHER)
            if cls == OTHER:
                if _ref(ann, "instance_token") in static:  # the planning score's static objects
                    try:
                        if _keeps(ann, agents, v0_40):
                            ob, oi = objects.setdefault(sample, ([], []))
                            ob.append(_box(ann, where))
                            oi.append(_ref(ann, "instance_token"))
                    except DatasetError as exc:
                        data.bad_objects.setdefault(sample, str(exc))
                    except ValueError as exc:
                        data.bad_objects.setdefault(sample, f"{where} {ann['token']}: {exc}")
                continue
            try:
                if not _keeps(ann, agents, v0_40):
                    continue
                box = _box(ann, where)
            except DatasetError as exc:
                data.bad_boxes.setdefault(sample, str(exc))
                continue
            except ValueError as exc:
                data.bad_boxes.setdefault(sample, f"{where} {ann['token']}: {exc}")
                continue
            b, c, t, inst = gathered.setdefault(sample, ([], [], [], []))
            b.append(box)
            c.append(cls)
            t.append(ann["token"])
            inst.append(_ref(ann, "instance_token"))
        for st in boxed:
            b, c, t, inst = gathered.get(st, ([], [], [], []))
            data.boxes[st] = np.asarray(b, dtype=np.float64).reshape(-1, 5)
            data.classes[st] = np.asarray(c, dtype=np.int8)
            data.box_tokens[st] = t
            if history > 0:
                data.box_instances[st] = inst
                ob, oi = objects.get(st, ([], []))
                data.objects[st] = np.asarray(ob, dtype=np.float64).reshape(-1, 5)
                data.object_instances[st] = oi
    return data
