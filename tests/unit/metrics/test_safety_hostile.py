"""Hostile maps and annotations for the safety columns (issue 32, items 3–5; docs/definitions.md#safety).

Each bad input is one line naming the file, or n/a with the reason for the frames of that map or annotation
only — never a traceback, never a number read from a misread file. Inputs are synthetic datasets
(:func:`lightemma.synth.write_dataset`) altered in ``tmp_path``.
"""

from __future__ import annotations

import json
import logging
import math
import os
import shutil
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

from lightemma.errors import DatasetError
from lightemma.evaluation import safety as S
from lightemma.nuscenes import annotations as A
from lightemma.nuscenes import geometry, load_frames
from lightemma.nuscenes import map_files as M

VERSION = "v1.0-mini"


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Path:
    """2 scenes × 20 keyframes (12 reference frames), one per location (boston-seaport, singapore-onenorth)."""
    from lightemma.synth import write_dataset

    return write_dataset(
        tmp_path_factory.mktemp("safety-hostile"), scenes=2, keyframes=20, image_size=(64, 36), sweeps=False
    )


@pytest.fixture
def root(base, tmp_path) -> Path:
    dst = tmp_path / "copy"
    shutil.copytree(base, dst)
    return dst


@pytest.fixture(scope="module")
def frames(base):
    return load_frames(base, VERSION, split="all", on_missing_image="keep")


@pytest.fixture(scope="module")
def oracle(base, tmp_path_factory) -> Path:
    """The run directory of baseline:oracle (trajectory = ground truth) on the clean dataset."""
    from lightemma.cli import main
    from lightemma.runs.store import find_run_dirs

    out = tmp_path_factory.mktemp("oracle-runs")
    assert (
        main(
            [
                "run",
                "--model",
                "baseline:oracle",
                "--dataroot",
                str(base),
                "--version",
                VERSION,
                "--split",
                "all",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    return find_run_dirs(out)[0]


def _table(root: Path, name: str) -> list[dict]:
    return json.loads((root / VERSION / f"{name}.json").read_text())


def _write(root: Path, name: str, rows) -> None:
    (root / VERSION / f"{name}.json").write_text(json.dumps(rows))


def _png(
    path: Path, width: int, height: int, depth: int, colour: int, rows: bytes | None = None, *, level: int = 6
) -> None:
    """A PNG written by hand (signature, IHDR, one IDAT, IEND); ``rows`` None: all-zero rows, compressed as a stream."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    if rows is None:
        c = zlib.compressobj(level)
        row = b"\0" * (1 + (width * depth + 7) // 8)
        idat = b"".join(c.compress(row) for _ in range(height)) + c.flush()
    else:
        idat = zlib.compress(rows, level)
    ihdr = struct.pack(">IIBBBBB", width, height, depth, colour, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b""))


def _masks_only(root: Path) -> list[dict]:
    """Remove the map expansions (the base masks are read then); returns the map table."""
    shutil.rmtree(root / "maps" / "expansion")
    return _table(root, "map")


# -- item 3: decompression bombs, deep nesting, rows that are not objects, non-finite nodes ------------------------


def test_a_decompression_bomb_mask_is_refused_from_its_header_and_pil_keeps_its_limit(root):
    from PIL import Image

    limit = Image.MAX_IMAGE_PIXELS
    maps = _masks_only(root)
    first = root / maps[0]["filename"]
    assert isinstance(M.read_map_mask(first), S.DrivableArea)
    assert Image.MAX_IMAGE_PIXELS == limit  # never lifted process-wide
    # a 1-bit PNG claiming 60,000² pixels: 437 KB on disk, 3.6 GB decoded
    _png(first, 60_000, 60_000, 1, 0, level=9)
    assert first.stat().st_size < 500_000
    with pytest.raises(DatasetError, match=r"claims 60000 × 60000 pixels, more than the 1,500,000,000 .*not decoded"):
        M.read_map_mask(first)
    data = S.load_safety_data(root, VERSION)
    reasons = [a for a in data.areas.values() if isinstance(a, str)]
    assert len(reasons) == 1 and str(first) in reasons[0] and "claims 60000 × 60000" in reasons[0]
    assert any(isinstance(a, S.DrivableArea) for a in data.areas.values())  # the other map still counts
    assert Image.MAX_IMAGE_PIXELS == limit


def test_deeply_nested_json_is_one_line_naming_the_file(root, frames):
    deep = "[" * 1_000_000 + "]" * 1_000_000
    (expansion,) = sorted((root / "maps" / "expansion").glob("boston*.json"))
    expansion.write_text(deep)
    data = S.load_safety_data(root, VERSION)
    (reason,) = [a for a in data.areas.values() if isinstance(a, str)]
    assert reason == f"map expansion {expansion}: cannot read its drivable_area layer (the JSON is nested too deep)"
    out = S.frame_safety(frames.gt_positions, frames.sample_tokens, data)
    assert out.area_ok.any() and not out.area_ok.all()
    assert {r for r in out.area_reason if r} == {f"no drivable area: {reason}"}
    # a nuScenes table nested as deep: one line naming the table, not a RecursionError
    (root / VERSION / "sensor.json").write_text(deep)
    with pytest.raises(DatasetError, match=r"sensor\.json cannot be read: the JSON is nested too deep"):
        S.load_safety_data(root, VERSION)


def test_table_rows_that_are_not_objects_name_the_table(root, frames):
    from lightemma.evaluation.stats import Resampling

    sensors = _table(root, "sensor")
    _write(root, "sensor", [[s["token"], s["channel"]] for s in sensors])
    with pytest.raises(
        DatasetError, match=rf"nuScenes table {root / VERSION / 'sensor.json'}: record 0 is not an object"
    ):
        S.load_safety_data(root, VERSION)
    # through evaluate_safety: a warning naming the file, the safety cells n/a with it, no TypeError
    run = _Run(frames, {"dataroot": str(root), "version": VERSION})
    res = S.evaluate_safety([("m", run, np.arange(len(frames)))], ["lightemma"], Resampling(n_resamples=0))
    assert any("sensor.json: record 0 is not an object" in w for w in res.warnings)
    row = res.rows["m"]["lightemma"]
    assert row["offroad"] is None and "sensor.json" in row["offroad_na"]


def test_non_finite_and_huge_map_nodes_and_two_node_polygons_give_that_map_na(root, oracle):
    """NaN/inf/1e300 coordinates and 2-node rings refuse that map (frames on it n/a, the reason naming file and
    node); the evaluation of the other map, and ADE, go on."""
    from lightemma.evaluation import evaluate_loaded, load_run
    from lightemma.evaluation.stats import Resampling

    (expansion,) = sorted((root / "maps" / "expansion").glob("boston*.json"))
    clean = json.loads(expansion.read_text())
    used = clean["polygon"][0]["exterior_node_tokens"][3]
    for value, shown in (
        (float("nan"), "nan"),
        (float("inf"), "inf"),
        (1e300, "1e+300"),
        ("12.5", "'12.5'"),
        (True, "True"),
    ):
        doc = json.loads(json.dumps(clean))
        next(n for n in doc["node"] if n["token"] == used)["x"] = value
        expansion.write_text(json.dumps(doc))
        data = S.load_safety_data(root, VERSION)
        (reason,) = [a for a in data.areas.values() if isinstance(a, str)]
        assert reason == (
            f"map expansion {expansion}: node {used} has x = {shown}; a coordinate must be a finite number "
            f"within ±1e+06 m"
        ), reason
    doc = json.loads(json.dumps(clean))
    doc["polygon"][0]["exterior_node_tokens"] = doc["polygon"][0]["exterior_node_tokens"][:2]
    expansion.write_text(json.dumps(doc))
    data = S.load_safety_data(root, VERSION)
    (reason,) = [a for a in data.areas.values() if isinstance(a, str)]
    assert f"polygon {doc['polygon'][0]['token']} has a ring of 2 node(s); a ring needs at least 3" in reason
    # end to end with a NaN node: ADE and the other map's off-road are there, this map's frames are n/a and said so
    doc = json.loads(json.dumps(clean))
    next(n for n in doc["node"] if n["token"] == used)["y"] = float("nan")
    expansion.write_text(json.dumps(doc))
    clean = evaluate_loaded([load_run(oracle)], resampling=Resampling(n_resamples=0)).accuracy_rows("lightemma")[0]
    ev = evaluate_loaded([load_run(oracle)], resampling=Resampling(n_resamples=0), dataroot=root, version=VERSION)
    row = ev.accuracy_rows("lightemma")[0]
    assert clean["offroad_frames"] == row["frames"] and math.isfinite(clean["ade_avg"])
    assert (
        row["ade_avg"] == clean["ade_avg"] and row["offroad"] is not None and 0 < row["offroad_frames"] < row["frames"]
    )
    assert any(
        f"map expansion {expansion}: node {used} has y = nan" in w and "no off-road value (n/a)" in w
        for w in ev.warnings
    )


# -- item 4: mask encodings ----------------------------------------------------------------------------------------


def test_mask_encodings_are_read_right_or_refused(root, frames):
    from PIL import Image

    maps = _masks_only(root)
    path = root / maps[0]["filename"]
    want = M.read_map_mask(path).mask
    assert set(np.unique(want)) == {0, 255}
    truth = S.frame_safety(frames.gt_positions, frames.sample_tokens, S.load_safety_data(root, VERSION))
    on = truth.area_ok.copy()
    assert on.any() and not truth.off_steps[on].all()
    img = Image.fromarray(want)
    # what PNG optimisers write for a two-valued image: 1-bit grayscale, a gray palette
    for mode in ("1", "P"):
        img.convert(mode).save(path)
        with Image.open(path) as check:
            assert check.mode == mode
        np.testing.assert_array_equal(M.read_map_mask(path).mask, want)
        again = S.frame_safety(frames.gt_positions, frames.sample_tokens, S.load_safety_data(root, VERSION))
        np.testing.assert_array_equal(again.area, truth.area)  # the same off-road outcomes, not 100 % off
    # refused, one line naming the file: 16-bit 0/65280, colour, a float TIFF, a mask with no 255
    h, w = want.shape
    sixteen = (want.astype(">u2") << 8).astype(">u2")
    _png(path, w, h, 16, 0, b"".join(b"\0" + sixteen[r].tobytes() for r in range(h)))
    with pytest.raises(DatasetError, match=rf"^map mask {path} is a 16-bit grayscale PNG; a base map mask is 8-bit"):
        M.read_map_mask(path)
    img.convert("RGB").save(path)
    with pytest.raises(DatasetError, match=r"is a 8-bit RGB PNG"):
        M.read_map_mask(path)
    Image.fromarray((want > 0).astype(np.float32)).save(path, format="TIFF")
    with pytest.raises(DatasetError, match=rf"^map mask {path} is not a PNG image"):
        M.read_map_mask(path)
    Image.fromarray((want > 0).astype(np.uint8)).save(path)
    with pytest.raises(DatasetError, match=r"has no pixel of value 255 \(drivable\); its largest value is 1"):
        M.read_map_mask(path)
    data = S.load_safety_data(root, VERSION)
    reasons = [a for a in data.areas.values() if isinstance(a, str)]
    assert len(reasons) == 1 and "has no pixel of value 255" in reasons[0]
    colours = Image.fromarray((want > 0).astype(np.uint8)).convert("P")  # indices 0 and 1
    colours.putpalette([0, 0, 0, 255, 0, 0] + [0] * 762)  # index 1 is red
    colours.save(path)
    with pytest.raises(DatasetError, match=r"palette PNG with colours"):
        M.read_map_mask(path)


def test_expansion_that_is_a_fifo_or_a_device_link_says_so(root, frames):
    (expansion,) = sorted((root / "maps" / "expansion").glob("boston*.json"))
    expansion.unlink()
    os.mkfifo(expansion)
    data = S.load_safety_data(root, VERSION)  # never opens the FIFO (it would block)
    (key,) = [k for k, a in data.areas.items() if isinstance(a, str)]
    assert (
        key.startswith("expansion:") and data.areas[key] == f"map expansion {expansion} is not a regular file (a FIFO)"
    )
    out = S.frame_safety(frames.gt_positions, frames.sample_tokens, data)
    assert set(out.area_kind) == {"expansion", ""}  # no silent fall-back to the mask
    assert {r for r in out.area_reason if r} == {
        f"no drivable area: map expansion {expansion} is not a regular file (a FIFO)"
    }
    expansion.unlink()
    expansion.symlink_to("/dev/zero")
    data = S.load_safety_data(root, VERSION)
    assert data.areas[key] == f"map expansion {expansion} is not a regular file (a character device)"
    # the mask reader refuses them too (never reads /dev/zero)
    with pytest.raises(DatasetError, match=r"is not a regular file \(a character device\)"):
        M.read_map_mask(expansion)


# -- item 4: one quaternion rule, refused boxes, pose jumps ----------------------------------------------------------


def _scaled(q: list[float], k: float) -> list[float]:
    return [k * v for v in q]


def test_one_quaternion_rule_for_the_frame_reader_and_the_safety_reader(root, frames):
    half = math.radians(15.0)
    unit = [math.cos(half), 0.0, 0.0, math.sin(half)]
    assert math.degrees(A._yaw(unit)) == pytest.approx(30.0)
    assert math.degrees(float(geometry.yaw_from_quaternion(np.array(_scaled(unit, 2.0))))) == pytest.approx(
        76.9, abs=0.05
    )
    with pytest.raises(ValueError, match=r"is not a unit quaternion \(norm 2; allowed \|norm - 1\| <= 1e-05\)"):
        A._yaw(_scaled(unit, 2.0))
    # an annotation whose quaternion is 30° scaled by 2: refused naming file and token; frames whose six later
    # keyframes hold it get collision n/a, the others keep their values
    anns = _table(root, "sample_annotation")
    later = S.load_safety_data(root, VERSION).future[frames.sample_tokens[-1]][
        0
    ]  # in the future of scene 1's last frames
    target = next(a for a in anns if a["sample_token"] == later)
    target["rotation"] = _scaled(target["rotation"], 2.0)
    _write(root, "sample_annotation", anns)
    data = S.load_safety_data(root, VERSION)
    where = root / VERSION / "sample_annotation.json"
    assert list(data.bad_boxes) == [target["sample_token"]]
    assert data.bad_boxes[target["sample_token"]] == (
        f"{where} {target['token']}: field rotation = {target['rotation']!r} "
        "is not a unit quaternion (norm 2; allowed |norm - 1| <= 1e-05)"
    )
    out = S.frame_safety(frames.gt_positions, frames.sample_tokens, data)
    hit = np.array([target["sample_token"] in data.future[t] for t in frames.sample_tokens])
    assert (
        hit.any()
        and (~out.coll_ok[hit]).all()
        and out.coll_ok[~hit & np.array([len(data.future[t]) == 6 for t in frames.sample_tokens])].all()
    )
    assert all(r.startswith("a refused annotation: ") and str(where) in r for r, h in zip(out.coll_reason, hit) if h)
    # the same defect in an ego pose: the frame reader and the safety reader give the same rule's words
    poses = _table(root, "ego_pose")
    sds = [
        sd for sd in _table(root, "sample_data") if sd["sample_token"] == frames.sample_tokens[0] and sd["is_key_frame"]
    ]
    front = next(sd for sd in sds if sd["filename"].startswith("samples/CAM_FRONT/"))
    pose = next(p for p in poses if p["token"] == front["ego_pose_token"])
    pose["rotation"] = _scaled(pose["rotation"], 2.0)
    _write(root, "ego_pose", poses)
    rule = "is not a unit quaternion (norm 2; allowed |norm - 1| <= 1e-05)"
    skipped = load_frames(root, VERSION, split="all", on_missing_image="keep")
    assert any(rule in r and pose["token"] in r for r in skipped.bad_records)
    data = S.load_safety_data(root, VERSION)
    assert (
        rule in data.pose_reasons[frames.sample_tokens[0]]
        and pose["token"] in data.pose_reasons[frames.sample_tokens[0]]
    )
    out = S.frame_safety(frames.gt_positions[:1], frames.sample_tokens[:1], data)
    assert (
        not out.area_ok[0]
        and out.area_reason[0].startswith("unusable CAM_FRONT ego pose: ")
        and "ego_pose.json" in out.area_reason[0]
    )


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("size", [1e9, 4.5, 1.6], r"sizes must be in \(0, 100\] m"),
        ("size", [1.9, 0.0, 1.6], r"sizes must be in \(0, 100\] m"),
        ("translation", [1e300, 0.0, 0.8], r"centre within ±1e\+06 m"),
        ("translation", [float("nan"), 0.0, 0.8], r"translation and size must be finite numbers"),
        ("rotation", [0.0, 0.0, 0.0, 0.0], r"is not a unit quaternion \(norm 0"),
    ],
)
def test_boxes_that_are_not_boxes_are_refused_naming_file_and_token(field, value, message):
    ann = {"token": "tok9", "translation": [1.0, 2.0, 0.8], "size": [1.9, 4.5, 1.6], "rotation": [1.0, 0.0, 0.0, 0.0]}
    assert A._box(ann) == pytest.approx((1.0, 2.0, 0.0, 4.5, 1.9))
    ann[field] = value
    with pytest.raises(DatasetError, match=r"^sample_annotation tok9: .*" + message):
        A._box(ann)


def test_a_pose_jump_is_flagged_by_the_frame_reader_run_and_evaluate(root, base, frames, oracle, tmp_path, caplog):
    from lightemma.cli import main
    from lightemma.evaluation import evaluate_loaded, load_run
    from lightemma.evaluation.stats import Resampling
    from lightemma.runs.store import find_run_dirs

    # move one keyframe's CAM_FRONT ego pose 1 km (inside the frame window of scene 0)
    token = frames.sample_tokens[3]
    sd = next(
        sd
        for sd in _table(root, "sample_data")
        if sd["sample_token"] == token and sd["is_key_frame"] and sd["filename"].startswith("samples/CAM_FRONT/")
    )
    poses = _table(root, "ego_pose")
    pose = next(p for p in poses if p["token"] == sd["ego_pose_token"])
    pose["translation"][0] += 1000.0
    _write(root, "ego_pose", poses)
    with caplog.at_level(logging.WARNING, logger="lightemma.frames"):
        assert (
            main(
                [
                    "run",
                    "--model",
                    "baseline:oracle",
                    "--dataroot",
                    str(root),
                    "--version",
                    VERSION,
                    "--split",
                    "all",
                    "--out",
                    str(tmp_path / "runs"),
                ]
            )
            == 0
        )
    jumps = [r.getMessage() for r in caplog.records if "beyond the 70 m/s bound" in r.getMessage()]
    assert len(jumps) == 2 and all(
        m.startswith(f"scene {frames.scene_names[3]}: ") for m in jumps
    )  # into the jump, back out
    assert f"sample {token} (keyframe 10) is 997.5 m from the keyframe before it, 0.50 s earlier (1994 m/s" in jumps[0]
    # evaluate: the ground truth of the frames around it jumps; a warning says so
    ev = evaluate_loaded([load_run(find_run_dirs(tmp_path / "runs")[0])], resampling=Resampling(n_resamples=0))
    (warning,) = [w for w in ev.warnings if "pose jump" in w]
    assert (
        "moves more than 35 m in one 0.5 s step (over 70 m/s" in warning and f"e.g. {frames.scene_names[3]}/" in warning
    )
    # the clean dataset: no such warning from either
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="lightemma.frames"):
        load_frames(base, VERSION, split="all", on_missing_image="keep")
    assert not [r for r in caplog.records if "m/s bound" in r.getMessage()]
    clean = evaluate_loaded([load_run(oracle)], resampling=Resampling(n_resamples=0))
    assert not [w for w in clean.warnings if "pose jump" in w]


# -- item 5: which boxes count ---------------------------------------------------------------------------------------


def test_agent_filters_follow_the_sources(root, frames):
    """``all`` (UniAD's occupancy labels), ``valid`` (lidar + radar points > 0: VAD), ``visible`` (not v0-40: ST-P3)."""
    data = S.load_safety_data(root, VERSION)
    # a trajectory that parks on an agent's centre at every step: collides at step 1 at least
    i = next(
        i for i, t in enumerate(frames.sample_tokens) if len(data.future[t]) == 6 and len(data.boxes[data.future[t][0]])
    )
    st = frames.sample_tokens[i]
    box, tok = data.boxes[data.future[st][0]][0], data.box_tokens[data.future[st][0]][0]
    x, y, yaw = data.poses[st]
    dx, dy = box[0] - x, box[1] - y
    local = [math.cos(yaw) * dx + math.sin(yaw) * dy - S.EGO_OFFSET, -math.sin(yaw) * dx + math.cos(yaw) * dy]
    traj = np.array([[local] * 6])
    assert S.frame_safety(traj, [st], data).collide[0, 0].any()
    anns = _table(root, "sample_annotation")
    ann = next(a for a in anns if a["token"] == tok)
    ann["num_lidar_pts"], ann["num_radar_pts"] = 0, 0
    ann["visibility_token"] = next(v["token"] for v in _table(root, "visibility") if v["level"] == "v0-40")
    _write(root, "sample_annotation", anns)
    kept = {agents: S.load_safety_data(root, VERSION, agents=agents) for agents in A.AGENT_FILTERS}
    assert tok in kept["all"].box_tokens[data.future[st][0]]
    assert all(tok not in kept[a].box_tokens[data.future[st][0]] for a in ("valid", "visible"))
    assert S.frame_safety(traj, [st], kept["all"]).collide[0, 0].any()
    for agents in ("valid", "visible"):
        out = S.frame_safety(traj, [st], kept[agents])
        assert out.coll_ok[0] and not out.collide[0, 0].any(), agents
    # the default counts every box: the numbers of existing runs do not move
    assert S.load_safety_data(root, VERSION).agents == "all"
    with pytest.raises(ValueError, match="unknown agent filter 'some'; choose one of all, valid, visible"):
        S.load_safety_data(root, VERSION, agents="some")
    # a count that is not a count under the 'valid' filter: that annotation is refused, its frames n/a
    ann["num_lidar_pts"] = "many"
    _write(root, "sample_annotation", anns)
    bad = S.load_safety_data(root, VERSION, agents="valid")
    assert "num_lidar_pts / num_radar_pts = ['many', 0] are not counts" in bad.bad_boxes[data.future[st][0]]


class _Run:
    """The part of a loaded run that evaluate_safety reads, from frames: trajectory = ground truth."""

    def __init__(self, frames, dataset):
        from types import SimpleNamespace

        self.frame_ids = list(frames.frame_ids)
        self.gt_positions = np.asarray(frames.gt_positions, dtype=np.float64)
        self.trajectory = self.gt_positions.copy()
        self.info = SimpleNamespace(dataset=dataset, imported=False)


def test_an_expansion_with_an_empty_drivable_area_layer_gives_that_map_na_not_all_off_road(root):
    """A drivable_area layer with no polygon would put every position off-road (100 %): that map is n/a instead."""
    (expansion,) = sorted((root / "maps" / "expansion").glob("boston*.json"))
    doc = json.loads(expansion.read_text())
    doc["drivable_area"] = []
    expansion.write_text(json.dumps(doc))
    data = S.load_safety_data(root, VERSION)
    (reason,) = [a for a in data.areas.values() if isinstance(a, str)]
    assert reason == f"map expansion {expansion}: its drivable_area layer holds no polygon", reason
