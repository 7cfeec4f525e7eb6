"""Hostile table values for the frame reader: JSON integers beyond any float, timestamps beyond int64, and
file names that point outside the dataroot. Each is one bad-record line naming scene, table, token and field,
under on_bad_record (skip: the scene is left out; error: the load stops) — never an OverflowError, and never a
path outside the dataroot handed to a backend."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest

from lightemma.errors import DatasetError
from lightemma.nuscenes import dataset_path, load_frames
from lightemma.nuscenes.frames import TIMESTAMP_MAX, BadRecordError, _timestamp
from lightemma.synth import write_dataset
from tests.support.frames_fixtures import read_table

VERSION = "v1.0-mini"
HUGE = "1" + "0" * 400  # a valid JSON integer that no float holds
MARK = "@@MARK@@"


@pytest.fixture(scope="module")
def hostile_root(tmp_path_factory) -> Path:
    """3 scenes x 20 keyframes, small images, no sweeps (a scene skipped still leaves frames)."""
    return write_dataset(
        tmp_path_factory.mktemp("synth-hostile"), scenes=3, seed=5, keyframes=20, image_size=(64, 36), sweeps=False
    )


@pytest.fixture(scope="module")
def clean(hostile_root):
    return load_frames(hostile_root, VERSION, split="all")


@pytest.fixture
def root(hostile_root, tmp_path) -> Path:
    dst = tmp_path / "copy"
    shutil.copytree(hostile_root, dst)
    return dst


def _keyframe(root: Path, scene_index: int = 1, keyframe: int = 9) -> tuple[str, dict]:
    """(scene name, CAM_FRONT keyframe sample_data record) of a keyframe inside the frame window of a scene."""
    scenes = sorted(read_table(root, VERSION, "scene"), key=lambda s: s["name"])
    samples = {s["token"]: s for s in read_table(root, VERSION, "sample")}
    sensors = {s["token"]: s["channel"] for s in read_table(root, VERSION, "sensor")}
    channel = {c["token"]: sensors[c["sensor_token"]] for c in read_table(root, VERSION, "calibrated_sensor")}
    sds = {
        sd["sample_token"]: sd
        for sd in read_table(root, VERSION, "sample_data")
        if sd["is_key_frame"] and channel[sd["calibrated_sensor_token"]] == "CAM_FRONT"
    }
    token = scenes[scene_index]["first_sample_token"]
    for _ in range(keyframe):
        token = samples[token]["next"]
    return scenes[scene_index]["name"], sds[token]


def _set_raw(root: Path, table: str, token: str, field: str, raw: str) -> None:
    """Write ``raw`` (JSON text, e.g. a 400-digit integer) as ``field`` of the record ``token`` of ``table``."""
    path = root / VERSION / f"{table}.json"
    rows = json.loads(path.read_text())
    (row,) = [r for r in rows if r["token"] == token]
    row[field] = MARK
    path.write_text(json.dumps(rows).replace(json.dumps(MARK), raw))


def _check_bad(root: Path, clean, scene: str, table: str, token: str, field: str, why: str) -> None:
    """skip: only that scene is left out, named in one line; error: the same line, raised."""
    loaded = load_frames(root, VERSION, split="all")
    assert scene in loaded.skipped_scenes and scene not in loaded.scenes
    assert len(loaded) == len(clean) - sum(1 for s in clean.scene_names if s == scene)
    (note,) = loaded.bad_records
    assert note.startswith(f"scene {scene}: {table} {token}: field {field} = "), note
    assert why in note and "\n" not in note
    with pytest.raises(BadRecordError) as info:
        load_frames(root, VERSION, split="all", on_bad_record="error")
    message = str(info.value)
    assert "\n" not in message and message.startswith(f"scene {scene}: {table} {token}: field {field} = "), message
    assert why in message and "on_bad_record='skip'" in message
    assert "--on-bad-record skip" in info.value.for_cli()
    assert isinstance(info.value, DatasetError)


# --------------------------------------------------------------------------- numbers beyond float and int64


EGO_POSE_VALUES = {
    "400-digit translation": ("translation", f"[{HUGE}, 1.0, 0.0]", "is not finite"),
    "negative 400-digit translation": ("translation", f"[1.0, -{HUGE}, 0.0]", "is not finite"),
    "400-digit rotation": ("rotation", f"[{HUGE}, 0, 0, 0]", "is not finite"),
    "400-digit timestamp": ("timestamp", HUGE, "is not a finite, whole, non-negative number of microseconds"),
    "1.5e300 timestamp": ("timestamp", "1.5e300", "is not a finite, whole, non-negative number of microseconds"),
    "2**63 timestamp": ("timestamp", str(2**63), "is not a finite, whole, non-negative number of microseconds"),
    "9.3e18 float timestamp": ("timestamp", "9.3e18", "is not a finite, whole, non-negative number of microseconds"),
}


@pytest.mark.parametrize("kind", list(EGO_POSE_VALUES))
def test_an_ego_pose_number_beyond_float_or_int64_is_a_bad_record(root, clean, kind):
    field, raw, why = EGO_POSE_VALUES[kind]
    scene, sd = _keyframe(root)
    _set_raw(root, "ego_pose", sd["ego_pose_token"], field, raw)
    _check_bad(root, clean, scene, "ego_pose", sd["ego_pose_token"], field, why)


CAMERA_VALUES = {
    "400-digit intrinsic": (
        "camera_intrinsic",
        f"[[{HUGE}, 0, 0], [0, 1, 0], [0, 0, 1]]",
        "is not a finite 3x3 matrix",
    ),
    "infinite intrinsic": (
        "camera_intrinsic",
        "[[1, 0, 0], [0, Infinity, 0], [0, 0, 1]]",
        "is not a finite 3x3 matrix",
    ),
    "400-digit camera translation": ("translation", f"[{HUGE}, 0, 0]", "is not finite"),
    "400-digit camera rotation": ("rotation", f"[0, 0, 0, {HUGE}]", "is not finite"),
}


@pytest.mark.parametrize("kind", list(CAMERA_VALUES))
def test_a_camera_calibration_number_beyond_float_is_a_bad_record(root, kind):
    field, raw, why = CAMERA_VALUES[kind]
    _, sd = _keyframe(root)
    token = sd["calibrated_sensor_token"]
    _set_raw(root, "calibrated_sensor", token, field, raw)
    # one CAM_FRONT calibration serves every scene: each scene is skipped, the load names the record
    loaded = load_frames(root, VERSION, split="all")
    assert len(loaded) == 0 and loaded.bad_records
    assert all(f": calibrated_sensor {token}: field {field} = " in note and why in note for note in loaded.bad_records)
    with pytest.raises(BadRecordError) as info:
        load_frames(root, VERSION, split="all", on_bad_record="error")
    message = str(info.value)
    assert "\n" not in message and f"calibrated_sensor {token}: field {field} = " in message and why in message


def test_intrinsics_given_as_integers_are_read_as_floats(root, clean):
    _, sd = _keyframe(root)
    path = root / VERSION / "calibrated_sensor.json"
    rows = json.loads(path.read_text())
    (front,) = [r for r in rows if r["token"] == sd["calibrated_sensor_token"]]
    front["camera_intrinsic"] = [[int(round(v)) for v in row] for row in front["camera_intrinsic"]]
    path.write_text(json.dumps(rows))
    loaded = load_frames(root, VERSION, split="all")
    assert loaded.frame_ids == clean.frame_ids and not loaded.bad_records
    assert loaded.camera_intrinsics.dtype.kind == "f"
    assert loaded.camera_intrinsics[0].tolist() == [[float(v) for v in row] for row in front["camera_intrinsic"]]


@pytest.mark.parametrize(
    "value, ok",
    [
        (0, True),
        (1532402927647951, True),
        (1532402927647951.0, True),
        (TIMESTAMP_MAX, True),
        (TIMESTAMP_MAX + 1, False),
        (10**400, False),
        (1.5e300, False),
        (float(2**63), False),
        (-1, False),
        (0.5, False),
        (float("nan"), False),
        (float("inf"), False),
        (True, False),
        ("1", False),
        (None, False),
    ],
    ids=lambda v: repr(v)[:24] if not isinstance(v, bool) else str(v),
)
def test_timestamps_are_whole_microseconds_within_int64(value, ok):
    record = {"token": "tok", "timestamp": value}
    if ok:
        assert _timestamp(record, "ego_pose") == int(value)
        assert type(_timestamp(record, "ego_pose")) is int
    else:
        with pytest.raises(BadRecordError, match=r"^ego_pose tok: field timestamp = .* is not a finite, whole"):
            _timestamp(record, "ego_pose")


# --------------------------------------------------------------------------- file names outside the dataroot


OUTSIDE = {
    "absolute path": ("/etc/passwd", "is an absolute path"),
    "absolute path to an image": ("/tmp/x/samples/CAM_FRONT/a.jpg", "is an absolute path"),
    "double-slash path": ("//etc/hostname", "is an absolute path"),
    "climbing path": ("../../../../etc/hostname", "leaves the dataroot"),
    "parent folder": ("..", "leaves the dataroot"),
    "climbing through a sample folder": ("samples/CAM_FRONT/../../../outside.jpg", "leaves the dataroot"),
    "the dataroot itself": ("samples/..", "names the dataroot itself"),
    "empty": ("", "is not a file name"),
    "NUL byte": ("samples/CAM_FRONT/a\0.jpg", "is not a file name"),
}


@pytest.mark.parametrize("kind", list(OUTSIDE))
def test_a_sample_data_filename_outside_the_dataroot_is_a_bad_record(root, clean, kind):
    name, why = OUTSIDE[kind]
    scene, sd = _keyframe(root)
    _set_raw(root, "sample_data", sd["token"], "filename", json.dumps(name))
    _check_bad(root, clean, scene, "sample_data", sd["token"], "filename", why)


def test_a_filename_outside_the_dataroot_is_refused_even_where_the_file_exists(root, clean, tmp_path):
    """The image of a frame outside the window is still named: the outside file must never become an image path."""
    secret = tmp_path / "secret.jpg"
    shutil.copy(clean.image_paths[0], secret)
    scene, sd = _keyframe(root, keyframe=0)  # a history-only keyframe: no frame of its own
    _set_raw(root, "sample_data", sd["token"], "filename", json.dumps(os.path.relpath(secret, root)))
    loaded = load_frames(root, VERSION, split="all", on_missing_image="keep")
    assert scene in loaded.skipped_scenes
    assert all(os.path.normpath(p).startswith(str(root) + os.sep) for p in loaded.image_paths)
    assert str(secret) not in loaded.image_paths


def test_a_filename_that_stays_inside_the_dataroot_is_kept(root, clean):
    scene, sd = _keyframe(root)
    inside = f"samples/../{sd['filename']}"
    _set_raw(root, "sample_data", sd["token"], "filename", json.dumps(inside))
    loaded = load_frames(root, VERSION, split="all", on_missing_image="error")
    assert loaded.frame_ids == clean.frame_ids and not loaded.bad_records and not loaded.skipped_scenes
    assert os.path.join(str(root), inside) in loaded.image_paths


def test_symlinks_inside_the_dataroot_are_followed(root, clean, tmp_path):
    """A user may keep the images elsewhere and link them in: the check is on the name, not the resolved path."""
    elsewhere = tmp_path / "images-elsewhere"
    shutil.move(str(root / "samples"), elsewhere)
    os.symlink(elsewhere, root / "samples")
    loaded = load_frames(root, VERSION, split="all", on_missing_image="error")
    assert loaded.frame_ids == clean.frame_ids and not loaded.bad_records
    assert all(p.startswith(str(root) + os.sep) and os.path.isfile(p) for p in loaded.image_paths)


@pytest.mark.parametrize(
    "name, ok",
    [
        ("samples/CAM_FRONT/a.jpg", True),
        ("maps/53992ee3023e5494b90c316c183be829.png", True),
        ("./maps/m.png", True),
        ("maps/../maps/m.png", True),
        ("a..b/c", True),
        ("..a/b", True),
        ("/etc/passwd", False),
        ("../x", False),
        ("maps/../../x", False),
        ("", False),
        (None, False),
        (3, False),
        (".", False),
    ],
)
def test_dataset_path_is_the_one_check_for_any_table_filename(tmp_path, name, ok):
    record = {"token": "m1", "filename": name}
    if ok:
        assert dataset_path(tmp_path, record, "map") == os.path.join(str(tmp_path), name)
    else:
        with pytest.raises(BadRecordError, match=r"^map m1: field filename = ") as info:
            dataset_path(tmp_path, record, "map")
        assert "\n" not in str(info.value)
