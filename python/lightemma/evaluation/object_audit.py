"""Described objects against the annotations: the classes a stage-1 scene description mentions against the annotated
objects in view of CAM_FRONT at that keyframe (docs/definitions.md#described-objects, rules ``objects@lightemma/1``).

* :func:`front_objects` — per sample, per class of :data:`CHECKED`: ``present`` (a box of the class in view: some
  corner projects into the CAM_FRONT image with the keyframe's calibration, nuScenes visibility ≥ 40 %, within the
  class's range), ``absent`` (no box of the class projects into the image at all, whatever its visibility or
  distance), or ``ambiguous`` (only boxes that are less visible, farther, or of a category that may or may not be
  the class, e.g. a police car for "car");
* :func:`object_check` — mentions (``lightemma.explanations.read_objects``) against those states: per frame and class
  whether the mention counts for precision / recall and whether it is right; the tags ``hallucinated-pedestrian``
  (affirms a pedestrian, none in the image) and ``missed-pedestrian`` (a pedestrian in view, not affirmed);
* :func:`object_rows` — per model the tag rates and per class the mention precision and recall, with scene-bootstrap
  intervals; n/a with the reason where there is no value.

Traffic lights and signs are map objects with no per-keyframe annotation (and no state): their mentions are read
and counted, never scored (n/a with that reason).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lightemma.errors import DatasetError

#: the classes checked against annotations (the reader's classes but traffic lights and signs), in order
CHECKED: tuple[str, ...] = ("pedestrian", "cyclist", "motorcycle", "car", "truck", "bus", "traffic_cone", "barrier")
#: classes read but never scored: map objects without per-keyframe annotations or state
UNCHECKABLE: dict[str, str] = {
    "traffic_light": "traffic lights are map objects: no per-keyframe annotation and no state in nuScenes",
    "traffic_sign": "traffic signs are map objects: no per-keyframe annotation in nuScenes",
}
#: nuScenes category (prefix) → (class, definite). A definite box makes its class present; an indefinite one makes
#: it ambiguous (neither present nor absent): a police car may be called a car or not, a trailer a truck or not
CATEGORY_CLASSES: tuple[tuple[str, str, bool], ...] = (
    ("human.pedestrian.adult", "pedestrian", True),
    ("human.pedestrian.child", "pedestrian", True),
    ("human.pedestrian.construction_worker", "pedestrian", True),
    ("human.pedestrian.police_officer", "pedestrian", True),
    ("human.pedestrian.", "pedestrian", False),  # personal_mobility, stroller, wheelchair
    ("vehicle.bicycle", "cyclist", True),
    ("vehicle.motorcycle", "motorcycle", True),
    ("vehicle.car", "car", True),
    ("vehicle.emergency.police", "car", False),
    ("vehicle.emergency.ambulance", "car", False),
    ("vehicle.emergency.ambulance", "truck", False),
    ("vehicle.truck", "truck", True),
    ("vehicle.trailer", "truck", False),
    ("vehicle.construction", "truck", False),
    ("vehicle.bus.", "bus", True),
    ("movable_object.trafficcone", "traffic_cone", True),
    ("movable_object.barrier", "barrier", True),
)
#: how far (m, horizontal, from the ego) a box of each class counts as in view: the nuScenes detection benchmark's
#: class ranges (nuscenes/eval/detection/configs/detection_cvpr_2019.json ``class_range``)
RANGE_M: dict[str, float] = {
    "pedestrian": 40.0,
    "cyclist": 40.0,
    "motorcycle": 40.0,
    "car": 50.0,
    "truck": 50.0,
    "bus": 50.0,
    "traffic_cone": 30.0,
    "barrier": 30.0,
}
#: visibility levels of at least 40 % (nuScenes' ``visibility`` table); v0-40 and unknown levels are not in view
VISIBLE_LEVELS: frozenset[str] = frozenset({"v40-60", "v60-80", "v80-100"})
#: a corner counts in the image when it projects inside it and lies this far (m) in front of the camera
#: (the devkit's ``box_in_image`` with ``BoxVisibility.ANY``)
MIN_DEPTH_M = 1.0
PRESENT, ABSENT, AMBIGUOUS = 1, 0, -1
STATE_NAMES = {PRESENT: "present", ABSENT: "absent", AMBIGUOUS: "ambiguous"}
#: the scenario tags of this audit
TAGS: tuple[str, ...] = ("hallucinated-pedestrian", "missed-pedestrian")


def classes_of(category: str) -> list[tuple[str, bool]]:
    """(class, definite) pairs a nuScenes category name maps to (:data:`CATEGORY_CLASSES`; [] for the rest: animals,
    debris, bicycle racks, pushable objects)."""
    out: list[tuple[str, bool]] = []
    for prefix, cls, definite in CATEGORY_CLASSES:
        if category == prefix or (prefix.endswith(".") and category.startswith(prefix)):
            if not any(c == cls for c, _ in out):
                out.append((cls, definite))
    return out


@dataclass
class FrontObjects:
    """Per sample token: ``states`` (len(CHECKED),) int8 of PRESENT / ABSENT / AMBIGUOUS and ``in_view`` (len(CHECKED),)
    the number of boxes in view per class; ``reasons``: sample → why it has no states (no CAM_FRONT keyframe, no
    calibration, a refused box); ``annotated``: whether the version has any annotation."""

    states: dict[str, np.ndarray] = field(default_factory=dict)
    in_view: dict[str, np.ndarray] = field(default_factory=dict)
    reasons: dict[str, str] = field(default_factory=dict)
    annotated: bool = False


def _corners(centre: np.ndarray, size: Sequence[float], rotation: np.ndarray) -> np.ndarray:
    """(8, 3) corners of a nuScenes box: ``size`` = (width, length, height), x along its length."""
    w, length, h = size
    x = np.array([1, 1, 1, 1, -1, -1, -1, -1]) * length / 2
    y = np.array([1, -1, -1, 1, 1, -1, -1, 1]) * w / 2
    z = np.array([1, 1, -1, -1, 1, 1, -1, -1]) * h / 2
    return np.stack([x, y, z], axis=1) @ rotation.T + centre


def in_image(corners_cam: np.ndarray, intrinsic: np.ndarray, width: float, height: float) -> bool:
    """Whether some corner (camera frame: x right, y down, z forward, m) lies ``MIN_DEPTH_M`` in front of the camera
    and projects strictly inside the ``width`` × ``height`` image (the devkit's ``box_in_image``, ``ANY``)."""
    z = corners_cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uvw = corners_cam @ intrinsic.T
        u, v = uvw[:, 0] / z, uvw[:, 1] / z
    ok = (z > MIN_DEPTH_M) & (u > 0) & (u < width) & (v > 0) & (v < height)
    return bool(ok.any())


def front_objects(dataroot: str | os.PathLike[str], version: str, samples: set[str]) -> FrontObjects:
    """The class states of ``samples`` (sample tokens) of ``dataroot/version`` (see the module docstring).

    Reads the nuScenes tables (``lightemma.nuscenes.json_tables``) with the annotation reader's checks
    (``lightemma.nuscenes.annotations``, as the safety metrics): a box that is not a
    box or a rotation that is not a unit quaternion makes its sample n/a with the reason, never a guess. A table that
    is missing or unreadable raises :class:`~lightemma.errors.DatasetError` naming the file.
    """
    from lightemma.nuscenes.annotations import _box, _finite, _ref
    from lightemma.nuscenes.geometry import quaternion_to_matrix, unit_quaternion
    from lightemma.nuscenes.json_tables import check_dataroot, read_table

    root = Path(dataroot).expanduser()
    tables = root / version
    check_dataroot(root, version)  # the frame reader's check: the version folder with all 13 tables
    out = FrontObjects()
    annotations = read_table(root, version, "sample_annotation")
    out.annotated = bool(annotations)
    if not out.annotated:
        return out
    channel_of_sensor = {s["token"]: s.get("channel") for s in read_table(root, version, "sensor")}
    calib = {
        c["token"]: c
        for c in read_table(root, version, "calibrated_sensor")
        if channel_of_sensor.get(_ref(c, "sensor_token")) == "CAM_FRONT"
    }
    front: dict[str, dict[str, Any]] = {}
    for sd in read_table(root, version, "sample_data"):
        st = _ref(sd, "sample_token")
        if st in samples and sd.get("is_key_frame") and _ref(sd, "calibrated_sensor_token") in calib:
            front[st] = sd
    pose_tokens = {_ref(sd, "ego_pose_token") for sd in front.values()}
    poses = {p["token"]: p for p in read_table(root, version, "ego_pose") if p["token"] in pose_tokens}
    cameras: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, float]] = {}
    for st in samples:
        cam_sd = front.get(st)
        if cam_sd is None:
            out.reasons[st] = f"no CAM_FRONT keyframe for sample {st} in {version}"
            continue
        cs, ep = calib[cam_sd["calibrated_sensor_token"]], poses.get(_ref(cam_sd, "ego_pose_token") or "")
        where = f"{tables}: sample_data {cam_sd['token']}"
        try:
            if ep is None:
                raise ValueError("its ego_pose is missing")
            k = np.asarray(cs.get("camera_intrinsic"), dtype=np.float64)
            if k.shape != (3, 3) or not np.isfinite(k).all():
                raise ValueError(f"camera_intrinsic {cs.get('camera_intrinsic')!r} is not a finite 3x3 matrix")
            size = _finite([cam_sd.get("width"), cam_sd.get("height")], 2)
            if size is None or min(size) <= 0:
                raise ValueError(
                    f"image size {cam_sd.get('width')!r} x {cam_sd.get('height')!r} is not positive numbers"
                )
            ego_t, cam_t = _finite(ep.get("translation"), 3), _finite(cs.get("translation"), 3)
            if ego_t is None or cam_t is None:
                raise ValueError("an ego pose or camera translation is not three finite numbers")
            r_ego = quaternion_to_matrix(unit_quaternion(ep.get("rotation")))
            r_cam = quaternion_to_matrix(unit_quaternion(cs.get("rotation")))
        except ValueError as exc:
            out.reasons[st] = f"{where}: {exc}"
            continue
        cameras[st] = (np.asarray(ego_t), r_ego, np.asarray(cam_t), r_cam, k, size[0], size[1])
    categories = {c["token"]: str(c.get("name", "")) for c in read_table(root, version, "category")}
    instance_classes = {
        i["token"]: classes_of(categories.get(_ref(i, "category_token") or "", ""))
        for i in read_table(root, version, "instance")
    }
    levels = {v["token"]: v.get("level") for v in read_table(root, version, "visibility")}
    n = len(CHECKED)
    states = {st: np.full(n, ABSENT, dtype=np.int8) for st in cameras}
    counts = {st: np.zeros(n, dtype=np.int64) for st in cameras}
    where = os.fspath(tables / "sample_annotation.json")
    for ann in annotations:
        st = _ref(ann, "sample_token")
        if st not in cameras:
            continue
        pairs = instance_classes.get(_ref(ann, "instance_token") or "", [])
        if not pairs:
            continue
        try:
            _box(ann, where)  # the safety reader's refusals (sizes, centre, rotation)
            centre = _finite(ann.get("translation"), 3)
            dims = _finite(ann.get("size"), 3)
            if centre is None or dims is None or dims[2] <= 0:
                raise DatasetError(
                    f"{where} {ann['token']}: translation and size must be three finite numbers, "
                    f"height > 0 (got {ann.get('translation')!r}, {ann.get('size')!r})"
                )
            rot = quaternion_to_matrix(unit_quaternion(ann.get("rotation")))
        except (DatasetError, ValueError) as exc:
            cameras.pop(st)
            states.pop(st)
            out.reasons[st] = str(exc) if isinstance(exc, DatasetError) else f"{where} {ann['token']}: {exc}"
            continue
        t_ego, r_ego, t_cam, r_cam, k, width, height = cameras[st]
        corners = _corners(np.asarray(centre), dims, rot)
        ego = (corners - t_ego) @ r_ego  # global → ego (row vectors: R^T (p − t))
        cam = (ego - t_cam) @ r_cam  # ego → camera
        if not in_image(cam, k, width, height):
            continue
        centre_ego = (np.asarray(centre) - t_ego) @ r_ego
        distance = float(np.hypot(centre_ego[0], centre_ego[1]))
        visible = levels.get(_ref(ann, "visibility_token") or "") in VISIBLE_LEVELS
        for cls, definite in pairs:
            c = CHECKED.index(cls)
            if definite and visible and distance <= RANGE_M[cls]:
                states[st][c] = PRESENT
                counts[st][c] += 1
            elif states[st][c] != PRESENT:
                states[st][c] = AMBIGUOUS
    out.states, out.in_view = states, {st: counts[st] for st in states}
    return out


@dataclass(frozen=True)
class ObjectCheck:
    """Per frame (N) and class (len(CHECKED)): ``precision_eligible`` (affirmed, and the class present or absent),
    ``recall_eligible`` (present, and the class affirmed, negated or not mentioned: a hedge is no answer),
    ``correct`` (affirmed and present); tags (N,) bool: ``hallucinated_pedestrian`` (affirms a pedestrian, none in
    the image), ``missed_pedestrian`` (a pedestrian in view, not affirmed); ``checked`` (N,) bool: a readable text
    and annotation states."""

    precision_eligible: np.ndarray
    recall_eligible: np.ndarray
    correct: np.ndarray
    hallucinated_pedestrian: np.ndarray
    missed_pedestrian: np.ndarray
    checked: np.ndarray


def object_check(mentions: np.ndarray, states: np.ndarray) -> ObjectCheck:
    """Mentions (N, C) str of the reader's classes (``DescribedObjects.mentions``) against ``states`` (N,
    len(CHECKED)) int of PRESENT / ABSENT / AMBIGUOUS (a row of AMBIGUOUS where a frame has none). ``ValueError``
    for shapes."""
    from lightemma.explanations import OBJECT_CLASSES, UNKNOWN

    m = np.asarray(mentions).astype(str)
    s = np.asarray(states)
    if m.ndim != 2 or m.shape[1] != len(OBJECT_CLASSES) or s.shape != (m.shape[0], len(CHECKED)):
        raise ValueError(
            f"mentions must be (N, {len(OBJECT_CLASSES)}) and states (N, {len(CHECKED)}), got {m.shape} and {s.shape}"
        )
    cols = [OBJECT_CLASSES.index(c) for c in CHECKED]
    mc = m[:, cols]
    readable = (mc != UNKNOWN).all(axis=1)
    affirmed = mc == "affirmed"
    answered = np.isin(mc, ("affirmed", "negated", "not_mentioned"))
    present, absent = s == PRESENT, s == ABSENT
    ped = CHECKED.index("pedestrian")
    return ObjectCheck(
        precision_eligible=affirmed & (present | absent),
        recall_eligible=present & answered,
        correct=affirmed & present,
        hallucinated_pedestrian=affirmed[:, ped] & absent[:, ped],
        missed_pedestrian=present[:, ped] & answered[:, ped] & ~affirmed[:, ped],
        checked=readable,
    )


@dataclass
class RunObjects:
    """One run's object audit: ``frame_ids`` (n,), ``scenes`` (n,), the mentions, the states (n, len(CHECKED)) and
    ``check``; ``has_states`` (n,) bool; ``reason``: why the run has no states at all (None otherwise)."""

    frame_ids: list[str]
    scenes: np.ndarray
    mentions: np.ndarray
    states: np.ndarray
    has_states: np.ndarray
    check: ObjectCheck
    reason: str | None = None


#: keys the Explanations rows gain
ROW_KEYS: tuple[str, ...] = ("hallucinated_pedestrian", "missed_pedestrian")
#: columns of a "Described objects" row
CLASS_KEYS: tuple[str, ...] = ("mention_precision", "mention_recall")


def audit_run(
    frame_ids: Sequence[str], scenes: np.ndarray, texts: Sequence[str | None], front: FrontObjects | str
) -> RunObjects:
    """The object audit of one run's frames (ids ``scene/sample_token``) from their stage-1 ``texts`` and the
    annotation states ``front`` (or the reason there are none)."""
    from lightemma.evaluation.safety import sample_token_of
    from lightemma.explanations import read_objects

    n = len(frame_ids)
    mentions = read_objects(list(texts)).mentions if n else np.zeros((0, len(CHECKED) + len(UNCHECKABLE)), dtype=str)
    states = np.full((n, len(CHECKED)), AMBIGUOUS, dtype=np.int8)
    has = np.zeros(n, dtype=bool)
    reason = front if isinstance(front, str) else None
    if not isinstance(front, str):
        if not front.annotated:
            reason = "no annotations in this version"
        for i, fid in enumerate(frame_ids):
            st = sample_token_of(fid)
            if st in front.states:
                states[i], has[i] = front.states[st], True
        if reason is None and not has.any():
            reason = next(iter(front.reasons.values()), "no frame with annotation states")
    check = object_check(mentions, states)
    check = ObjectCheck(
        check.precision_eligible & has[:, None],
        check.recall_eligible & has[:, None],
        check.correct & has[:, None],
        check.hallucinated_pedestrian & has,
        check.missed_pedestrian & has,
        check.checked & has,
    )
    return RunObjects(list(frame_ids), scenes, mentions, states, has, check, reason)


def _interval(pair: np.ndarray) -> list[float] | None:
    return [float(pair[0]), float(pair[1])] if np.isfinite(pair).all() else None


def object_rows(
    audits: Mapping[str, RunObjects], resampling: Any, no_texts: Mapping[str, str]
) -> tuple[dict[str, dict[str, Any]], list[dict[str, Any]]]:
    """Per model label its tag rates (:data:`ROW_KEYS` with ``_ci95`` / ``_na``, ``object_frames``) and the
    "Described objects" rows (model × class: ``frames``, ``mentions``, ``in_view``, :data:`CLASS_KEYS` with ``_ci95``
    and ``_na``). ``no_texts``: label → why it has no stage-1 texts (a baseline): every value n/a with that reason."""
    from lightemma.evaluation.stats import bootstrap_ci

    groups: list[tuple[np.ndarray, np.ndarray]] = []
    keys: list[str] = []
    slots: list[tuple[dict[str, Any], str]] = []
    rows: dict[str, dict[str, Any]] = {}
    class_rows: list[dict[str, Any]] = []
    for label, a in audits.items():
        c = a.check
        why_none = no_texts.get(label) or a.reason
        frames = int(c.checked.sum())
        row: dict[str, Any] = {"object_frames": frames}
        for key in ROW_KEYS:
            row.update({key: None, f"{key}_ci95": None, f"{key}_na": None})
        if why_none or frames == 0:
            for key in ROW_KEYS:
                row[f"{key}_na"] = why_none or "no frame with a readable description and annotation states"
        else:
            sel = c.checked
            for key, tag in (
                ("hallucinated_pedestrian", c.hallucinated_pedestrian),
                ("missed_pedestrian", c.missed_pedestrian),
            ):
                values = tag[sel].astype(np.float64)
                row[key] = float(values.mean())
                groups.append((values, a.scenes[sel]))
                keys.append(f"objects:{key}:{label}")
                slots.append((row, key))
        rows[label] = row
        for j, cls in enumerate([*CHECKED, *UNCHECKABLE]):
            col = a.mentions[:, j] if len(a.mentions) else np.zeros(0, dtype=str)
            crow: dict[str, Any] = {
                "model": label,
                "class": cls,
                "frames": frames,
                "mentions": None if no_texts.get(label) else int((col == "affirmed").sum()),
                "in_view": None,
            }
            for key in CLASS_KEYS:
                crow.update({key: None, f"{key}_ci95": None, f"{key}_na": None})
            if cls in UNCHECKABLE:
                for key in CLASS_KEYS:
                    crow[f"{key}_na"] = UNCHECKABLE[cls]
            elif why_none:
                for key in CLASS_KEYS:
                    crow[f"{key}_na"] = why_none
            else:
                crow["in_view"] = int((a.states[:, j] == PRESENT)[a.has_states].sum())
                for key, eligible in (
                    ("mention_precision", c.precision_eligible[:, j]),
                    ("mention_recall", c.recall_eligible[:, j]),
                ):
                    if not eligible.any():
                        crow[f"{key}_na"] = (
                            "no affirmed mention of the class checkable against the annotations"
                            if key == "mention_precision"
                            else "the class is never in view"
                        )
                        continue
                    values = c.correct[eligible, j].astype(np.float64)
                    crow[key] = float(values.mean())
                    groups.append((values, a.scenes[eligible]))
                    keys.append(f"objects:{key}:{cls}:{label}")
                    slots.append((crow, key))
            class_rows.append(crow)
    if groups:
        ci = bootstrap_ci(groups, keys, resampling)
        for g, (row, key) in enumerate(slots):
            row[f"{key}_ci95"] = _interval(ci[g, 0])
    return rows, class_rows


def load_front(dataroot: str | os.PathLike[str], version: str, samples: set[str]) -> FrontObjects | str:
    """:func:`front_objects`, or the reason it cannot be read (a run on it is n/a with it)."""
    try:
        return front_objects(dataroot, version, samples)
    except DatasetError as exc:
        return f"the dataset {dataroot} ({version}) cannot be read: {exc}"
