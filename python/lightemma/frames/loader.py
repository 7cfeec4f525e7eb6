"""Load frames from a nuScenes dataroot through ``nuscenes-devkit`` (docs/definitions.md#frames-and-windows).

Two steps, usable separately: :func:`load_tables` checks the dataroot and
loads the devkit's ``NuScenes`` tables (the slow part, seconds to minutes on
the real dataset); :func:`extract_frames` turns chosen scenes of a loaded
``NuScenes`` into a :class:`FrameSet` with vectorised NumPy.
:func:`load_frames` does both.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from lightemma.errors import DatasetError, UserError
from lightemma.frames import geometry
from lightemma.frames.model import FrameSet

if TYPE_CHECKING:  # pragma: no cover
    from nuscenes.nuscenes import NuScenes

log = logging.getLogger("lightemma.frames")

#: the 13 tables the devkit loads
TABLES = (
    "category",
    "attribute",
    "visibility",
    "instance",
    "sensor",
    "calibrated_sensor",
    "ego_pose",
    "log",
    "scene",
    "sample",
    "sample_data",
    "sample_annotation",
    "map",
)

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
        raise ValueError(f"unknown window {window!r}; choose one of {', '.join(WINDOWS)}")


def _check_options(window: str, on_missing_image: str, on_bad_record: str = "skip") -> None:
    _check_window(window)
    if on_missing_image not in ON_MISSING_IMAGE:
        raise ValueError(
            f"unknown on_missing_image {on_missing_image!r}; choose one of {', '.join(ON_MISSING_IMAGE)}"
        )
    if on_bad_record not in ON_BAD_RECORD:
        raise ValueError(f"unknown on_bad_record {on_bad_record!r}; choose one of {', '.join(ON_BAD_RECORD)}")


class BadRecordError(DatasetError):
    """A table record whose value cannot be used (a pose that is not a pose); names table, token and field."""


def _bad(table: str, token: str, field: str, value: Any, why: str) -> BadRecordError:
    shown = repr(value)
    shown = shown if len(shown) <= 80 else shown[:77] + "..."
    return BadRecordError(f"{table} {token}: field {field} = {shown} {why}")


def _translation(record: dict[str, Any], table: str, min_len: int) -> np.ndarray:
    """The record's ``translation`` as finite floats (at least ``min_len`` of them)."""
    value = record.get("translation")
    try:
        array = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise _bad(table, record.get("token", "?"), "translation", value, "is not a list of numbers") from None
    if array.size < min_len:
        raise _bad(table, record.get("token", "?"), "translation", value, f"has {array.size} value(s), needs at least {min_len}")
    if not np.isfinite(array).all():
        raise _bad(table, record.get("token", "?"), "translation", value, "is not finite")
    return array


def _rotation(record: dict[str, Any], table: str) -> np.ndarray:
    """The record's ``rotation`` quaternion (w, x, y, z), normalised to unit length."""
    value = record.get("rotation")
    try:
        q = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise _bad(table, record.get("token", "?"), "rotation", value, "is not a quaternion (w, x, y, z)") from None
    if q.size != 4 or not np.isfinite(q).all():
        raise _bad(table, record.get("token", "?"), "rotation", value, "is not a quaternion of 4 finite numbers (w, x, y, z)")
    norm = float(np.linalg.norm(q))
    if not norm > 1e-6:
        raise _bad(table, record.get("token", "?"), "rotation", value, "has no rotation (norm 0): it cannot be normalised")
    return q / norm


def _timestamp(record: dict[str, Any], table: str) -> int:
    """The record's ``timestamp`` (integer microseconds), which must be finite and whole."""
    value = record.get("timestamp")
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or float(value) != int(value):
        raise _bad(table, record.get("token", "?"), "timestamp", value, "is not a finite whole number of microseconds")
    return int(value)


def window_range(n_keyframes: int, window: str) -> range:
    """Current keyframe indices ``c`` of a scene with ``n_keyframes`` keyframes.

    ``reference`` (the paper): 7 … N−8, N−14 frames; ``full``: 7 … N−7, N−13 frames.
    """
    _check_window(window)
    last = n_keyframes - 1 - FUTURE - WINDOWS[window]
    return range(HISTORY, max(HISTORY, last + 1))


# -- tables ----------------------------------------------------------------------


def check_dataroot(dataroot: str | os.PathLike[str], version: str) -> str:
    """Check that ``dataroot/version`` holds all 13 tables; return the absolute dataroot."""
    if not isinstance(version, str) or not version:
        raise DatasetError(f"nuScenes version must be a non-empty string such as 'v1.0-test', got {version!r}")
    root = os.path.abspath(os.fspath(dataroot))
    if not os.path.exists(root):
        raise DatasetError(f"nuScenes dataroot {root} does not exist")
    if not os.path.isdir(root):
        raise DatasetError(f"nuScenes dataroot {root} is not a directory")
    table_root = os.path.join(root, version)
    if not os.path.isdir(table_root):
        present = sorted(
            d for d in os.listdir(root) if os.path.isfile(os.path.join(root, d, "scene.json"))
        )
        hint = f"; versions found there: {', '.join(present)}" if present else "; no version folders found there"
        raise DatasetError(f"nuScenes version folder {table_root} does not exist{hint}")
    missing = [t for t in TABLES if not os.path.isfile(os.path.join(table_root, f"{t}.json"))]
    if missing:
        paths = ", ".join(os.path.join(table_root, f"{t}.json") for t in missing)
        raise DatasetError(f"nuScenes table(s) missing: {paths}")
    return root


def _bad_json_table(table_root: str) -> str | None:
    for t in TABLES:
        path = os.path.join(table_root, f"{t}.json")
        try:
            with open(path, encoding="utf-8") as f:
                json.load(f)
        except (ValueError, UnicodeDecodeError) as exc:
            return f"{path}: {exc}"
    return None


def load_tables(dataroot: str | os.PathLike[str], version: str) -> NuScenes:
    """Check the dataroot and load its tables with the devkit's ``NuScenes`` (quietly).

    Problems become :class:`DatasetError` naming the path, never an assertion
    or ``KeyError`` from inside the devkit.
    """
    root = check_dataroot(dataroot, version)
    try:
        from nuscenes.nuscenes import NuScenes  # lazy: the devkit pulls in cv2, sklearn, matplotlib
    except ImportError as exc:
        raise UserError(
            f"loading nuScenes needs nuscenes-devkit (pip install nuscenes-devkit==1.2.0): {exc}"
        ) from exc

    table_root = os.path.join(root, version)
    try:
        return NuScenes(version=version, dataroot=root, verbose=False)
    except json.JSONDecodeError:
        raise DatasetError(f"nuScenes table is not valid JSON: {_bad_json_table(table_root)}") from None
    except AssertionError as exc:
        raise DatasetError(f"nuScenes devkit could not load {table_root}: {exc}") from None
    except (KeyError, IndexError, TypeError, AttributeError) as exc:
        raise DatasetError(
            f"nuScenes tables in {table_root} are inconsistent "
            f"({type(exc).__name__}: {exc}); is this an unmodified nuScenes version folder?"
        ) from None


# -- scenes ------------------------------------------------------------------------


def predefined_splits() -> dict[str, list[str]]:
    """The devkit's scene splits (``create_splits_scenes()``)."""
    from nuscenes.utils.splits import create_splits_scenes

    return create_splits_scenes()


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
                raise DatasetError(
                    f"unknown split {split!r}; choose one of {', '.join([ALL_SCENES, *splits])}"
                )
            wanted = splits[split]
            absent = [s for s in wanted if s not in available_set]
            if absent:
                where = SPLIT_VERSIONS.get(split)
                hint = f"; split {split!r} belongs to version {where}" if where and where != version else ""
                synthetic = any(s.startswith("synth-") for s in available_set)
                shown = ", ".join(absent[:5]) + (f" and {len(absent) - 5} more" if len(absent) > 5 else "")
                message = f"{len(absent)} of the {len(wanted)} scenes of split {split!r} are not in version {version}: {shown}{hint}"
                raise DatasetError(
                    message + ("; a synthetic dataset is loaded with split='all' or an explicit scene list" if synthetic else ""),
                    cli=message + ("; a synthetic dataset is loaded with --split all or --scenes NAME ..." if synthetic else ""),
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


def _scene_keyframes(nusc: NuScenes, scene: dict[str, Any], cs_cache: dict[str, tuple]) -> dict[str, Any]:
    """Walk a scene's sample chain; collect CAM_FRONT pose, time, image and calibration per keyframe."""
    name = scene["name"]
    tokens: list[str] = []
    xy: list[tuple[float, float]] = []
    quats: list[list[float]] = []
    times: list[int] = []
    files: list[str] = []
    cs_tokens: list[str] = []
    token = scene["first_sample_token"]
    seen: set[str] = set()
    while token:
        if token in seen:
            raise DatasetError(f"scene {name}: the sample chain loops at sample {token}")
        seen.add(token)
        try:
            sample = nusc.get("sample", token)
        except KeyError:
            raise DatasetError(f"scene {name}: sample {token} is not in the sample table") from None
        sd_token = sample["data"].get(CAMERA)
        if sd_token is None:
            raise DatasetError(f"scene {name}: sample {token} has no {CAMERA} keyframe in sample_data")
        sd = nusc.get("sample_data", sd_token)
        try:
            pose = nusc.get("ego_pose", sd["ego_pose_token"])
        except KeyError:
            raise DatasetError(
                f"scene {name}: ego_pose {sd['ego_pose_token']} of sample_data {sd_token} is missing"
            ) from None
        cs_token = sd["calibrated_sensor_token"]
        if cs_token not in cs_cache:
            cs = nusc.get("calibrated_sensor", cs_token)
            try:
                intrinsic = np.asarray(cs["camera_intrinsic"], dtype=np.float64)
            except (TypeError, ValueError):
                intrinsic = np.zeros(0)
            if intrinsic.shape != (3, 3) or not np.isfinite(intrinsic).all():
                raise _bad("calibrated_sensor", cs_token, "camera_intrinsic", cs.get("camera_intrinsic"),
                           f"is not a finite 3x3 matrix (needed for {CAMERA})")
            translation = _translation(cs, "calibrated_sensor", 3)
            cs_cache[cs_token] = (intrinsic, geometry.extrinsic_matrix(translation, _rotation(cs, "calibrated_sensor")))
        position = _translation(pose, "ego_pose", 2)
        tokens.append(token)
        xy.append((position[0], position[1]))
        quats.append(_rotation(pose, "ego_pose"))
        times.append(_timestamp(pose, "ego_pose"))
        files.append(sd["filename"])
        cs_tokens.append(cs_token)
        token = sample["next"]
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
    nusc: NuScenes,
    *,
    split: str | None = None,
    scenes: Sequence[str] | None = None,
    window: str = "reference",
    on_missing_image: str = "skip",
    on_bad_record: str = "skip",
) -> FrameSet:
    """Frames of the chosen scenes of an already loaded ``NuScenes`` (see :func:`load_frames`)."""
    _check_options(window, on_missing_image, on_bad_record)
    dataroot = os.path.abspath(nusc.dataroot)
    by_name = {s["name"]: s for s in nusc.scene}
    split, names = resolve_scenes(by_name, nusc.version, split=split, scenes=scenes)

    cs_cache: dict[str, tuple] = {}
    xy_parts, yaw_parts, t_parts, current_parts = [], [], [], []
    meta: dict[str, list] = {k: [] for k in ("frame_ids", "scene_names", "scene_tokens", "sample_tokens", "image_paths", "cs")}
    kf_index: list[int] = []
    skipped: list[str] = []
    bad_records: list[str] = []
    used: list[str] = []
    offset = 0
    for name in names:
        try:
            kf = _scene_keyframes(nusc, by_name[name], cs_cache)
        except BadRecordError as exc:
            if on_bad_record == "error":
                raise BadRecordError(f"scene {name}: {exc} (pass on_bad_record='skip' to skip such scenes)",
                                     cli=f"scene {name}: {exc} (pass --on-bad-record skip to skip such scenes)") from None
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
            log.warning("scene %s has %d keyframes, fewer than the %d a %r window needs; skipped", name, n, need, window)
            skipped.append(name)
            continue
        used.append(name)
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
            meta["image_paths"].append(os.path.join(dataroot, kf["files"][c]))
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
        version=nusc.version,
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
        raise DatasetError(
            f"{len(missing)} of {len(fs)} frame image(s) missing (first: {example}): {listing}"
        )
    if policy == "keep":
        log.warning("%d of %d frame image(s) missing (first: %s), frames kept: %s", len(missing), len(fs), example, listing)
        object.__setattr__(fs, "missing_images", ids)
        return fs
    log.warning("%d of %d frame image(s) missing (first: %s), frames skipped: %s", len(missing), len(fs), example, listing)
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
    """Load the frames of a nuScenes version through the devkit (docs/definitions.md#frames-and-windows).

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
            ``ego_pose`` or ``calibrated_sensor`` whose translation is not ≥ 2 finite numbers
            (3 for a sensor), whose rotation is not a quaternion that normalises (4 finite
            numbers, norm > 0), or whose timestamp is not a finite whole number: ``skip``
            (default: the scene is left out with a warning naming table, token and field, and
            listed in ``skipped_scenes`` and ``bad_records``) or ``error`` (raise
            :class:`BadRecordError`, one line naming scene, table, token and field).

    Frames are ordered by scene name, then keyframe. ``FrameSet.summary_line()`` says which
    split, how many scenes and how many frames were taken.
    """
    _check_options(window, on_missing_image, on_bad_record)  # before the slow table load
    nusc = load_tables(dataroot, version)
    frames = extract_frames(nusc, split=split, scenes=scenes, window=window, on_missing_image=on_missing_image,
                            on_bad_record=on_bad_record)
    log.info("loaded %s", frames.summary_line())
    return frames
