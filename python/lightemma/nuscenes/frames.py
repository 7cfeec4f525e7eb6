"""Load frames from a nuScenes dataroot (docs/definitions.md#frames-and-windows).

lightemma reads the nuScenes JSON tables itself — ``scene`` → its chain of
``sample`` records → each sample's CAM_FRONT keyframe ``sample_data`` → its
``ego_pose`` and ``calibrated_sensor`` — exactly as ``nuscenes-devkit``'s
``NuScenes`` indexes them (tests/unit/nuscenes/test_frames.py checks the two readings agree
on the same dataroot), so that loading frames needs only numpy (1 or 2) and no
devkit; the devkit stays an optional extra (``lightemma[nuscenes]``) for maps
and rendering. The predefined splits are the devkit's ``create_splits_scenes()``,
copied into ``splits.json`` beside this module.

Two steps, usable separately: :func:`load_tables` checks the dataroot and
reads the tables the frames need (the slow part: seconds on the real
dataset); :func:`extract_frames` turns chosen scenes of the loaded
:class:`Tables` into a :class:`FrameSet` with vectorised NumPy.
:func:`load_frames` does both.
"""

from __future__ import annotations

import functools
import json
import logging
import math
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from lightemma.errors import DatasetError, InputError
from lightemma.frames.model import FrameSet
from lightemma.nuscenes import geometry
from lightemma.nuscenes.json_tables import check_dataroot, read_table

log = logging.getLogger("lightemma.frames")

#: the tables the frame reader reads
READ_TABLES = ("scene", "sample", "sample_data", "ego_pose", "calibrated_sensor", "sensor")

#: largest allowed deviation of a rotation quaternion's norm from 1 (the one rule of every reader:
#: :func:`lightemma.nuscenes.geometry.unit_quaternion`)
QUATERNION_TOLERANCE = geometry.QUATERNION_TOLERANCE

#: versions whose scenes the devkit's hard-coded splits name
KNOWN_VERSIONS = ("v1.0-test", "v1.0-trainval", "v1.0-mini")

#: split used when neither ``split`` nor ``scenes`` is given: the paper's 150 test scenes, the 150
#: held-out val scenes of trainval, and every scene of v1.0-mini (a 10-scene trial set, not a benchmark)
DEFAULT_SPLITS = {"v1.0-test": "test", "v1.0-trainval": "val", "v1.0-mini": "all"}

#: which version holds each predefined split's scenes (for error messages)
SPLIT_VERSIONS = {
    "test": "v1.0-test",
    "val": "v1.0-trainval",
    "train": "v1.0-trainval",
    "train_detect": "v1.0-trainval",
    "train_track": "v1.0-trainval",
    "mini_train": "v1.0-mini",
    "mini_val": "v1.0-mini",
}

ALL_SCENES = "all"
CAMERA = "CAM_FRONT"
HISTORY = 7  # keyframes before the current one (p_{c-7} … p_c)
FUTURE = 6  # keyframes after it (p_{c+1} … p_{c+6})

#: window mode -> keyframes left unused at the end of a scene after the last gt keyframe
WINDOWS = {"reference": 1, "full": 0}
ON_MISSING_IMAGE = ("skip", "error", "keep")
ON_BAD_RECORD = ("skip", "error")


def _check_window(window: str) -> None:
    if window not in WINDOWS:
        raise InputError(f"unknown window {window!r}; choose one of {', '.join(WINDOWS)}")


def _check_options(window: str, on_missing_image: str, on_bad_record: str = "skip") -> None:
    _check_window(window)
    if on_missing_image not in ON_MISSING_IMAGE:
        raise InputError(f"unknown on_missing_image {on_missing_image!r}; choose one of {', '.join(ON_MISSING_IMAGE)}")
    if on_bad_record not in ON_BAD_RECORD:
        raise InputError(f"unknown on_bad_record {on_bad_record!r}; choose one of {', '.join(ON_BAD_RECORD)}")


class BadRecordError(DatasetError):
    """A table record whose value cannot be used (a pose that is not a pose); names table, token and field."""


def _bad(table: str, token: str, field: str, value: Any, why: str) -> BadRecordError:
    shown = repr(value)
    shown = shown if len(shown) <= 80 else shown[:77] + "..."
    return BadRecordError(f"{table} {token}: field {field} = {shown} {why}")


def _float(value: int | float) -> float:
    """A JSON number as a float: an integer too large for a float (JSON has no bound) is infinite, not an OverflowError."""
    try:
        return float(value)
    except OverflowError:
        return math.inf


def _is_finite_number(value: Any) -> bool:
    """A finite int or float (bools, text and integers beyond the float range are not)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(_float(value))


def _numbers(record: dict[str, Any], table: str, field: str, size: int, what: str) -> np.ndarray:
    """The record's ``field`` as exactly ``size`` finite numbers (bools and text refused)."""
    value = record.get(field)
    token = record.get("token", "?")
    if not isinstance(value, (list, tuple)) or not all(
        isinstance(v, (int, float)) and not isinstance(v, bool) for v in value
    ):
        raise _bad(table, token, field, value, f"is not a list of {size} numbers ({what})")
    if len(value) != size:
        raise _bad(table, token, field, value, f"has {len(value)} value(s), needs {size} ({what})")
    array = np.asarray([_float(v) for v in value], dtype=np.float64)
    if not np.isfinite(array).all():
        raise _bad(table, token, field, value, "is not finite")
    return array


def _translation(record: dict[str, Any], table: str) -> np.ndarray:
    """The record's ``translation``: exactly 3 finite numbers (x, y, z in metres), x and y within
    :data:`lightemma.nuscenes.geometry.MAX_COORDINATE_M` (the safety reader's bound, one rule for both)."""
    xyz = _numbers(record, table, "translation", 3, "x, y, z in metres")
    if max(abs(xyz[0]), abs(xyz[1])) > geometry.MAX_COORDINATE_M:
        raise _bad(
            table,
            record.get("token", "?"),
            "translation",
            record.get("translation"),
            f"is beyond ±{geometry.MAX_COORDINATE_M:g} m (x, y in metres)",
        )
    return xyz


def _rotation(record: dict[str, Any], table: str) -> np.ndarray:
    """The record's ``rotation``: a unit quaternion (w, x, y, z) within :data:`QUATERNION_TOLERANCE`, renormalised
    (:func:`lightemma.nuscenes.geometry.unit_quaternion`, the rule the safety metrics apply too)."""
    q = _numbers(record, table, "rotation", 4, "a quaternion w, x, y, z")
    try:
        return geometry.unit_quaternion(q)
    except ValueError as exc:
        raise _bad(table, record.get("token", "?"), "rotation", record.get("rotation"), str(exc)) from None


#: largest timestamp (µs) the frame arrays hold (int64)
TIMESTAMP_MAX = int(np.iinfo(np.int64).max)


def _timestamp(record: dict[str, Any], table: str) -> int:
    """The record's ``timestamp``: a finite, whole, non-negative number of microseconds within int64."""
    value = record.get("timestamp")
    whole: int | None = None
    if isinstance(value, float) and value.is_integer():  # NaN and infinities are not whole
        whole = int(value)
    elif isinstance(value, int) and not isinstance(value, bool):
        whole = value
    if whole is None or not 0 <= whole <= TIMESTAMP_MAX:
        raise _bad(
            table,
            record.get("token", "?"),
            "timestamp",
            value,
            "is not a finite, whole, non-negative number of microseconds within int64",
        )
    return whole


def ego_pose_xy_yaw(record: dict[str, Any], table: str = "ego_pose") -> tuple[float, float, float]:
    """Global (x, y, yaw) of an ``ego_pose`` record (m, m, rad) under the frame reader's rules: ``translation``
    exactly 3 finite numbers, x and y within ±1e6 m; ``rotation`` a unit quaternion (:func:`_rotation`). Raises
    :class:`BadRecordError` naming table, token and field (what the safety metrics record as the frame's n/a reason)."""
    position = _translation(record, table)
    yaw = geometry.yaw_from_quaternion(_rotation(record, table).reshape(1, 4))[0]
    return float(position[0]), float(position[1]), float(yaw)


def sample_timestamp(record: dict[str, Any], table: str = "sample") -> int:
    """A record's ``timestamp`` (µs) under the frame reader's rule (:func:`_timestamp`: whole, non-negative, within
    int64); raises :class:`BadRecordError` otherwise."""
    return _timestamp(record, table)


def dataset_path(dataroot: str | os.PathLike[str], record: dict[str, Any], table: str, field: str = "filename") -> str:
    """The path of the file a table record names in ``field`` (``sample_data``/``map`` ``filename``).

    The name must be a relative path that stays inside the dataroot: an absolute path, or one whose
    normalised form climbs out through ``..``, raises :class:`BadRecordError` naming table, token and
    field (an API run would otherwise read that file and send it to a provider). The check is lexical
    (``os.path.normpath``), so symlinks the user set up inside the dataroot are followed as before.
    Returns ``os.path.join(dataroot, name)``.
    """
    name = record.get(field)
    token = record.get("token", "?")
    if not isinstance(name, str) or not name or "\0" in name:
        raise _bad(table, token, field, name, "is not a file name (a path relative to the dataroot)")
    if os.path.isabs(name) or os.path.splitdrive(name)[0] or name.startswith(("/", "\\")):
        raise _bad(table, token, field, name, "is an absolute path; a dataset file must lie inside the dataroot")
    norm = os.path.normpath(name)
    if norm == os.curdir:
        raise _bad(table, token, field, name, "names the dataroot itself, not a file in it")
    if (
        norm == os.pardir
        or norm.startswith(os.pardir + os.sep)
        or (os.altsep and norm.startswith(os.pardir + os.altsep))
    ):
        raise _bad(table, token, field, name, "leaves the dataroot; a dataset file must lie inside it")
    return os.path.join(os.fspath(dataroot), name)


def window_range(n_keyframes: int, window: str) -> range:
    """Current keyframe indices ``c`` of a scene with ``n_keyframes`` keyframes.

    ``reference`` (the paper): 7 … N−8, N−14 frames; ``full``: 7 … N−7, N−13 frames.
    """
    _check_window(window)
    last = n_keyframes - 1 - FUTURE - WINDOWS[window]
    return range(HISTORY, max(HISTORY, last + 1))


# -- tables ----------------------------------------------------------------------


@dataclass(frozen=True)
class Tables:
    """The nuScenes tables the frames need, read from ``<dataroot>/<version>/*.json`` by :func:`load_tables`.

    ``scenes``: the ``scene`` records in file order; ``samples``, ``sample_data``, ``ego_poses``,
    ``calibrated_sensors``: records by token (``sample_data``, ``ego_poses``, ``calibrated_sensors``
    only those of CAM_FRONT keyframes); ``front_keyframes``: sample token → its CAM_FRONT keyframe
    ``sample_data`` token (what the devkit puts in ``sample["data"]["CAM_FRONT"]``). Records are the
    tables' own dicts, unvalidated: :func:`extract_frames` checks each field it uses.
    """

    dataroot: str
    version: str
    scenes: list[dict[str, Any]]
    samples: dict[str, dict[str, Any]]
    sample_data: dict[str, dict[str, Any]]
    ego_poses: dict[str, dict[str, Any]]
    calibrated_sensors: dict[str, dict[str, Any]]
    front_keyframes: dict[str, str]

    def get(self, table: str, token: str) -> dict[str, Any]:
        """A record by table name (``sample``, ``sample_data``, ``ego_pose``, ``calibrated_sensor``) and token."""
        rows = {
            "sample": self.samples,
            "sample_data": self.sample_data,
            "ego_pose": self.ego_poses,
            "calibrated_sensor": self.calibrated_sensors,
        }[table]
        try:
            return rows[token]
        except (KeyError, TypeError):
            raise DatasetError(
                f"{table} {token!r} is not in {os.path.join(self.dataroot, self.version, table)}.json"
            ) from None


def _field(record: dict[str, Any], table: str, field: str, kind: type | tuple[type, ...] = str) -> Any:
    """``record[field]``, which must exist and be of ``kind``; else a DatasetError naming table, token and field."""
    value = record.get(field, KeyError)
    if value is KeyError:
        raise DatasetError(f"{table} {record['token']}: field {field} is missing")
    if not isinstance(value, kind) or isinstance(value, bool) and kind is not bool:
        shown = repr(value) if len(repr(value)) <= 80 else repr(value)[:77] + "..."
        names = kind.__name__ if isinstance(kind, type) else " or ".join(k.__name__ for k in kind)
        raise DatasetError(f"{table} {record['token']}: field {field} = {shown} is not a {names}")
    return value


def _inconsistent(table_root: str, what: str) -> DatasetError:
    return DatasetError(
        f"nuScenes tables in {table_root} are inconsistent: {what}; is this an unmodified nuScenes version folder?"
    )


def load_tables(dataroot: str | os.PathLike[str], version: str) -> Tables:
    """Check the dataroot and read the tables the frames need (no devkit; numpy 1 or 2).

    Indexes them as ``nuscenes-devkit``'s ``NuScenes`` does: a sample's CAM_FRONT keyframe is the
    ``sample_data`` record with ``is_key_frame`` true whose ``calibrated_sensor``'s ``sensor`` has
    channel ``CAM_FRONT``. Problems raise :class:`DatasetError` naming the path, table, token or
    field: a missing or invalid table, a token that points nowhere, two CAM_FRONT keyframes for one
    sample. Pose values are checked later, per scene, by :func:`extract_frames`.
    """
    root = check_dataroot(dataroot, version)
    table_root = os.path.join(root, version)
    sensors = {r["token"]: r for r in read_table(root, version, "sensor")}
    calibrated = {r["token"]: r for r in read_table(root, version, "calibrated_sensor")}
    channel_of: dict[str, Any] = {}  # calibrated_sensor token -> channel
    for token, cs in calibrated.items():
        sensor = sensors.get(_field(cs, "calibrated_sensor", "sensor_token"))
        if sensor is None:
            raise _inconsistent(
                table_root, f"calibrated_sensor {token} names sensor {cs['sensor_token']}, which is not in sensor.json"
            )
        channel_of[token] = sensor.get("channel")
    samples = {r["token"]: r for r in read_table(root, version, "sample")}
    front: dict[str, str] = {}
    front_sd: dict[str, dict[str, Any]] = {}
    for sd in read_table(root, version, "sample_data"):
        cs_token = sd.get("calibrated_sensor_token")
        if cs_token not in channel_of:
            raise _inconsistent(
                table_root,
                f"sample_data {sd['token']} names calibrated_sensor {cs_token!r}, "
                "which is not in calibrated_sensor.json",
            )
        if sd.get("is_key_frame") is not True or channel_of[cs_token] != CAMERA:
            continue
        sample_token = _field(sd, "sample_data", "sample_token")
        if sample_token not in samples:
            raise _inconsistent(
                table_root, f"sample_data {sd['token']} names sample {sample_token}, which is not in sample.json"
            )
        if sample_token in front:
            raise DatasetError(
                f"sample {sample_token} has two {CAMERA} keyframes in sample_data: "
                f"{front[sample_token]} and {sd['token']}"
            )
        front[sample_token] = sd["token"]
        front_sd[sd["token"]] = sd
    wanted = {sd.get("ego_pose_token") for sd in front_sd.values()}
    poses = {r["token"]: r for r in read_table(root, version, "ego_pose") if r["token"] in wanted}
    scenes = read_table(root, version, "scene")
    for scene in scenes:
        _field(scene, "scene", "name")
        _field(scene, "scene", "first_sample_token")
    return Tables(
        dataroot=root,
        version=version,
        scenes=scenes,
        samples=samples,
        sample_data=front_sd,
        ego_poses=poses,
        calibrated_sensors={t: calibrated[t] for t in {sd["calibrated_sensor_token"] for sd in front_sd.values()}},
        front_keyframes=front,
    )


# -- scenes ------------------------------------------------------------------------


SPLITS_FILE = os.path.join(os.path.dirname(__file__), "splits.json")


@functools.cache
def _splits() -> dict[str, tuple[str, ...]]:
    with open(SPLITS_FILE, encoding="utf-8") as f:
        return {name: tuple(scenes) for name, scenes in json.load(f)["splits"].items()}


def predefined_splits() -> dict[str, list[str]]:
    """The devkit's scene splits: name → scene names, as ``nuscenes.utils.splits.create_splits_scenes()``
    (nuscenes-devkit 1.2.0) returns them — copied into ``lightemma/nuscenes/splits.json``, so no devkit is needed."""
    return {name: list(scenes) for name, scenes in _splits().items()}


def default_split(version: str) -> str:
    """The split used when neither ``split`` nor ``scenes`` is given."""
    try:
        return DEFAULT_SPLITS[version]
    except KeyError:
        why = f"the devkit's splits only name scenes of {', '.join(KNOWN_VERSIONS)}"
        raise DatasetError(
            f"version {version!r} has no default split: pass split='all' to use every scene of it, "
            f"or scenes=[...] ({why})",
            cli=f"version {version!r} has no default split: add --split all to use every scene of it, "
            f"or --scenes NAME ... ({why})",
        ) from None


def resolve_scenes(
    available: Iterable[str],
    version: str,
    *,
    split: str | None = None,
    scenes: Sequence[str] | None = None,
) -> tuple[str | None, list[str]]:
    """Choose scene names: ``(split recorded, sorted scene names)``.

    - neither given: the version's default split (``test``, ``val``, ``all`` for v1.0-mini);
    - ``split``: a devkit split name, or ``"all"`` for every scene of the version;
    - ``scenes``: an explicit list (filters the split if both are given).
    """
    available_set = set(available)
    if isinstance(scenes, str):
        scenes = [scenes]
    if split is None and scenes is None:
        split = default_split(version)
    chosen: list[str] | None = None
    if split is not None:
        if split == ALL_SCENES:
            chosen = sorted(available_set)
        else:
            splits = predefined_splits()
            if split not in splits:
                raise DatasetError(f"unknown split {split!r}; choose one of {', '.join([ALL_SCENES, *splits])}")
            wanted = splits[split]
            absent = [s for s in wanted if s not in available_set]
            if absent:
                where = SPLIT_VERSIONS.get(split)
                hint = f"; split {split!r} belongs to version {where}" if where and where != version else ""
                synthetic = any(s.startswith("synth-") for s in available_set)
                shown = ", ".join(absent[:5]) + (f" and {len(absent) - 5} more" if len(absent) > 5 else "")
                message = f"{len(absent)} of the {len(wanted)} scenes of split {split!r} are not in version {version}: {shown}{hint}"
                raise DatasetError(
                    message
                    + (
                        "; a synthetic dataset is loaded with split='all' or an explicit scene list"
                        if synthetic
                        else ""
                    ),
                    cli=message
                    + ("; a synthetic dataset is loaded with --split all or --scenes NAME ..." if synthetic else ""),
                )
            chosen = sorted(wanted)
    if scenes is not None:
        names = list(dict.fromkeys(scenes))
        if not names:
            raise DatasetError("the scene list is empty")
        unknown = [s for s in names if s not in available_set]
        if unknown:
            raise DatasetError(f"unknown scene(s) in version {version}: {', '.join(unknown)}")
        if chosen is not None:
            outside = [s for s in names if s not in set(chosen)]
            if outside:
                raise DatasetError(f"scene(s) not in split {split!r}: {', '.join(outside)}")
        chosen = sorted(names)
    assert chosen is not None
    return split, chosen


# -- extraction --------------------------------------------------------------------


def _scene_keyframes(tables: Tables, scene: dict[str, Any], cs_cache: dict[str, tuple]) -> dict[str, Any]:
    """Walk a scene's sample chain; collect CAM_FRONT pose, time, image and calibration per keyframe.

    Structural problems (a chain that loops or points nowhere, a missing keyframe) raise
    :class:`DatasetError`; an unusable value (pose, timestamp, calibration, an image filename outside
    the dataroot) raises :class:`BadRecordError`.
    """
    name = scene["name"]
    tokens: list[str] = []
    xy: list[tuple[float, float]] = []
    quats: list[np.ndarray] = []
    times: list[int] = []
    files: list[str] = []
    cs_tokens: list[str] = []
    token = scene["first_sample_token"]
    seen: set[str] = set()
    while token:
        if token in seen:
            raise DatasetError(f"scene {name}: the sample chain loops at sample {token}")
        seen.add(token)
        sample = tables.samples.get(token)
        if sample is None:
            raise DatasetError(f"scene {name}: sample {token} is not in the sample table")
        sd_token = tables.front_keyframes.get(token)
        if sd_token is None:
            raise DatasetError(f"scene {name}: sample {token} has no {CAMERA} keyframe in sample_data")
        sd = tables.sample_data[sd_token]
        pose_token = _field(sd, "sample_data", "ego_pose_token")
        pose = tables.ego_poses.get(pose_token)
        if pose is None:
            raise DatasetError(f"scene {name}: ego_pose {pose_token} of sample_data {sd_token} is missing")
        cs_token = sd["calibrated_sensor_token"]
        if cs_token not in cs_cache:
            cs = tables.calibrated_sensors[cs_token]
            intrinsic = cs.get("camera_intrinsic")
            rows = intrinsic if isinstance(intrinsic, list) and len(intrinsic) == 3 else None
            if rows is None or not all(
                isinstance(r, list) and len(r) == 3 and all(_is_finite_number(v) for v in r) for r in rows
            ):
                raise _bad(
                    "calibrated_sensor",
                    cs_token,
                    "camera_intrinsic",
                    intrinsic,
                    f"is not a finite 3x3 matrix (needed for {CAMERA})",
                )
            extrinsic = geometry.extrinsic_matrix(
                _translation(cs, "calibrated_sensor"), _rotation(cs, "calibrated_sensor")
            )
            cs_cache[cs_token] = (np.asarray([[_float(v) for v in r] for r in rows], dtype=np.float64), extrinsic)
        position = _translation(pose, "ego_pose")
        tokens.append(token)
        xy.append((position[0], position[1]))
        quats.append(_rotation(pose, "ego_pose"))
        times.append(_timestamp(pose, "ego_pose"))
        files.append(dataset_path(tables.dataroot, sd, "sample_data"))
        cs_tokens.append(cs_token)
        token = _field(sample, "sample", "next")
    return {
        "name": name,
        "token": scene["token"],
        "sample_tokens": tokens,
        "xy": np.asarray(xy, dtype=np.float64).reshape(-1, 2),
        "yaw": geometry.yaw_from_quaternion(np.asarray(quats, dtype=np.float64).reshape(-1, 4)),
        "t": np.asarray(times, dtype=np.int64),
        "files": files,
        "cs_tokens": cs_tokens,
    }


def extract_frames(
    tables: Tables,
    *,
    split: str | None = None,
    scenes: Sequence[str] | None = None,
    window: str = "reference",
    on_missing_image: str = "skip",
    on_bad_record: str = "skip",
) -> FrameSet:
    """Frames of the chosen scenes of tables read by :func:`load_tables` (see :func:`load_frames`)."""
    if not isinstance(tables, Tables):
        raise TypeError(
            f"extract_frames takes the Tables of lightemma.nuscenes.load_tables(dataroot, version), "
            f"not {type(tables).__name__} (frames are no longer read through the devkit's NuScenes)"
        )
    _check_options(window, on_missing_image, on_bad_record)
    dataroot = tables.dataroot
    by_name: dict[str, dict[str, Any]] = {}
    for scene in tables.scenes:
        if scene["name"] in by_name:
            raise DatasetError(
                f"scene name {scene['name']} is used by two scenes: {by_name[scene['name']]['token']} "
                f"and {scene['token']}"
            )
        by_name[scene["name"]] = scene
    split, names = resolve_scenes(by_name, tables.version, split=split, scenes=scenes)

    cs_cache: dict[str, tuple] = {}
    xy_parts, yaw_parts, t_parts, current_parts = [], [], [], []
    meta: dict[str, list] = {
        k: [] for k in ("frame_ids", "scene_names", "scene_tokens", "sample_tokens", "image_paths", "cs")
    }
    kf_index: list[int] = []
    skipped: list[str] = []
    bad_records: list[str] = []
    used: list[str] = []
    offset = 0
    for name in names:
        try:
            kf = _scene_keyframes(tables, by_name[name], cs_cache)
        except BadRecordError as exc:
            if on_bad_record == "error":
                raise BadRecordError(
                    f"scene {name}: {exc} (pass on_bad_record='skip' to skip such scenes)",
                    cli=f"scene {name}: {exc} (pass --on-bad-record skip to skip such scenes)",
                ) from None
            log.warning("scene %s skipped: %s", name, exc)
            skipped.append(name)
            bad_records.append(f"scene {name}: {exc}")
            continue
        n = len(kf["sample_tokens"])
        if n >= 2 and np.any(np.diff(kf["t"]) <= 0):
            bad = int(np.argmax(np.diff(kf["t"]) <= 0))
            raise DatasetError(
                f"scene {name}: keyframe timestamps do not increase at keyframe {bad + 1} "
                f"(sample {kf['sample_tokens'][bad + 1]})"
            )
        cs = window_range(n, window)
        if len(cs) == 0:
            need = HISTORY + FUTURE + 1 + WINDOWS[window]
            log.warning(
                "scene %s has %d keyframes, fewer than the %d a %r window needs; skipped", name, n, need, window
            )
            skipped.append(name)
            continue
        used.append(name)
        for k, dist, dt in geometry.pose_jumps(kf["xy"], kf["t"]):
            log.warning(
                "scene %s: the %s ego pose of sample %s (keyframe %d) is %.1f m from the keyframe before it, "
                "%.2f s earlier (%.0f m/s, beyond the %g m/s bound of a physically possible move): the frames "
                "around it have a wrong history or ground truth",
                name,
                CAMERA,
                kf["sample_tokens"][k],
                k,
                dist,
                dt,
                dist / dt,
                geometry.POSE_JUMP_SPEED,
            )
        xy_parts.append(kf["xy"])
        yaw_parts.append(kf["yaw"])
        t_parts.append(kf["t"])
        current_parts.append(np.asarray(cs, dtype=np.int64) + offset)
        offset += n
        for c in cs:
            st = kf["sample_tokens"][c]
            meta["frame_ids"].append(f"{name}/{st}")
            meta["scene_names"].append(name)
            meta["scene_tokens"].append(kf["token"])
            meta["sample_tokens"].append(st)
            meta["image_paths"].append(kf["files"][c])  # dataset_path: inside the dataroot
            meta["cs"].append(kf["cs_tokens"][c])
            kf_index.append(c)

    if current_parts:
        xy = np.concatenate(xy_parts)
        yaw = np.concatenate(yaw_parts)
        t = np.concatenate(t_parts)
        cur = np.concatenate(current_parts)
    else:
        xy, yaw, t, cur = np.zeros((0, 2)), np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int64)
    # every step below is vectorised and also holds for no frames at all (F = 0)
    idx = cur[:, None] + np.arange(-HISTORY, FUTURE + 1)[None, :]  # (F, 14): c-7 … c+6
    ego = geometry.to_ego_frame(xy[idx], xy[cur], yaw[cur])
    ts = t[idx]
    history_positions = ego[:, : HISTORY + 1]
    gt_positions = ego[:, HISTORY + 1 :]
    history_actions = geometry.postprocess_reference(geometry.raw_actions(ego[:, :8], ts[:, :8]))
    gt_actions = geometry.raw_actions(ego[:, 6:14], ts[:, 6:14])
    ego_poses = np.stack([xy[cur, 0], xy[cur, 1], yaw[cur]], axis=-1)
    intr = np.stack([cs_cache[c][0] for c in meta["cs"]]) if meta["cs"] else np.zeros((0, 3, 3))
    extr = np.stack([cs_cache[c][1] for c in meta["cs"]]) if meta["cs"] else np.zeros((0, 4, 4))

    fs = FrameSet(
        frame_ids=meta["frame_ids"],
        scene_names=meta["scene_names"],
        scene_tokens=meta["scene_tokens"],
        sample_tokens=meta["sample_tokens"],
        keyframe_indices=np.asarray(kf_index, dtype=np.int64),
        timestamps=t[cur],
        image_paths=meta["image_paths"],
        camera_intrinsics=intr,
        camera_extrinsics=extr,
        ego_poses=ego_poses,
        history_positions=history_positions,
        history_actions=history_actions,
        gt_positions=gt_positions,
        gt_actions=gt_actions,
        dataroot=dataroot,
        version=tables.version,
        split=split,
        scenes=used,
        window=window,
        skipped_scenes=skipped,
        bad_records=bad_records,
    )
    return _handle_missing_images(fs, on_missing_image)


def _handle_missing_images(fs: FrameSet, policy: str) -> FrameSet:
    missing = [i for i, p in enumerate(fs.image_paths) if not os.path.isfile(p)]
    if not missing:
        return fs
    ids = [fs.frame_ids[i] for i in missing]
    listing = ", ".join(ids[:10]) + (f" and {len(ids) - 10} more" if len(ids) > 10 else "")
    example = fs.image_paths[missing[0]]
    if policy == "error":
        raise DatasetError(f"{len(missing)} of {len(fs)} frame image(s) missing (first: {example}): {listing}")
    if policy == "keep":
        log.warning(
            "%d of %d frame image(s) missing (first: %s), frames kept: %s", len(missing), len(fs), example, listing
        )
        object.__setattr__(fs, "missing_images", ids)
        return fs
    log.warning(
        "%d of %d frame image(s) missing (first: %s), frames skipped: %s", len(missing), len(fs), example, listing
    )
    drop = set(missing)
    kept = fs._take([i for i in range(len(fs)) if i not in drop])
    object.__setattr__(kept, "missing_images", ids)
    return kept


def load_frames(
    dataroot: str | os.PathLike[str],
    version: str,
    *,
    split: str | None = None,
    scenes: Sequence[str] | None = None,
    window: str = "reference",
    on_missing_image: str = "skip",
    on_bad_record: str = "skip",
) -> FrameSet:
    """Load the frames of a nuScenes version (docs/definitions.md#frames-and-windows); no devkit needed.

    Args:
        dataroot: folder holding ``<version>/`` (the tables), ``samples/``, ``maps/``.
        version: ``v1.0-test`` (the paper), ``v1.0-trainval``, ``v1.0-mini`` or another folder name.
        split: a devkit split (``test``, ``val``, ``train``, ``mini_val``, …) or ``"all"`` for
            every scene of the version. With neither ``split`` nor ``scenes``: ``test`` for
            v1.0-test, ``val`` for v1.0-trainval, ``"all"`` (its 10 scenes) for v1.0-mini; other
            versions must say which scenes. Synthetic datasets use ``"all"`` or a scene list.
        scenes: explicit scene names (within ``split`` if both are given).
        window: ``reference`` (the paper: c = 7 … N−8, N−14 frames per scene) or
            ``full`` (c = 7 … N−7, N−13 frames per scene).
        on_missing_image: ``skip`` (default: drop those frames, log and list them in
            ``missing_images``), ``error`` (raise), or ``keep`` (keep them, still listed).
        on_bad_record: what to do with a scene holding a record that cannot be used — an
            ``ego_pose`` or ``calibrated_sensor`` whose ``translation`` is not exactly 3 finite
            numbers, whose ``rotation`` is not a unit quaternion (4 finite numbers, |norm − 1| ≤
            :data:`QUATERNION_TOLERANCE`), whose ``timestamp`` is not a finite, whole, non-negative
            number within int64, a CAM_FRONT ``camera_intrinsic`` that is not a finite 3×3 matrix, or
            a CAM_FRONT ``sample_data`` ``filename`` that is absolute or leaves the dataroot
            (:func:`dataset_path`): ``skip``
            (default: the scene is left out with a warning naming table, token and field, and
            listed in ``skipped_scenes`` and ``bad_records``) or ``error`` (raise
            :class:`BadRecordError`, one line naming scene, table, token and field).

    Frames are ordered by scene name, then keyframe. ``FrameSet.summary_line()`` says which
    split, how many scenes and how many frames were taken.
    """
    _check_options(window, on_missing_image, on_bad_record)  # before the slow table load
    tables = load_tables(dataroot, version)
    frames = extract_frames(
        tables,
        split=split,
        scenes=scenes,
        window=window,
        on_missing_image=on_missing_image,
        on_bad_record=on_bad_record,
    )
    log.info("loaded %s", frames.summary_line())
    return frames
