"""Frames as docs/definitions.md#frames-and-windows defines them, loaded through the real nuscenes-devkit from synthetic scenes."""

from __future__ import annotations

import json
import logging
import math
import os
import shutil

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

import lightemma
from lightemma.errors import DatasetError
from lightemma.frames import Frame, FrameSet, format_history, format_number
from lightemma.frames.model import summary_line
from lightemma.nuscenes import geometry, load_frames, window_range
from lightemma.nuscenes.frames import Tables, extract_frames, load_tables, predefined_splits
from lightemma.synth import build_scenarios
from tests.support.frames_fixtures import (  # noqa: F401
    SMALL,
    make_small_dataset,
    read_table,
    reference_frames,
    small_copy,
    small_root,
)

VERSION = "v1.0-mini"


@pytest.fixture(scope="module")
def fs(small_root) -> FrameSet:
    return load_frames(small_root, VERSION, split="all")


@pytest.fixture(scope="module")
def truth():
    return {s.name: s for s in build_scenarios(SMALL["scenes"], seed=SMALL["seed"], keyframes=SMALL["keyframes"])}


# --------------------------------------------------------------------------- geometry


@settings(deadline=None)
@given(st.floats(-math.pi + 1e-9, math.pi - 1e-9))
def test_yaw_from_quaternion_inverts_a_yaw_rotation(yaw):
    q = np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])
    assert geometry.yaw_from_quaternion(q) == pytest.approx(yaw, abs=1e-12)


@settings(deadline=None)
@given(
    st.floats(2.0, 500.0),
    st.floats(-math.pi, math.pi),
    st.floats(0.05, 1.0),
    st.sampled_from([1.0, -1.0]),
)
def test_menger_curvature_of_points_on_a_circle_is_signed_inverse_radius(radius, start, step, sign):
    angles = start + sign * np.array([0.0, step, 2 * step])  # counter-clockwise when sign > 0
    pts = np.stack([radius * np.cos(angles), radius * np.sin(angles)], axis=-1)
    k = geometry.menger_curvature(pts[0], pts[1], pts[2])
    assert k == pytest.approx(sign / radius, rel=1e-6)


def test_menger_curvature_is_zero_for_straight_or_repeated_points():
    a, b, c = np.array([0.0, 0.0]), np.array([1.0, 1.0]), np.array([2.0, 2.0])
    assert geometry.menger_curvature(a, b, c) == 0.0
    assert geometry.menger_curvature(a, a, c) == 0.0  # a side of length zero
    assert geometry.menger_curvature(a, a, a) == 0.0


def test_to_ego_frame_puts_the_heading_on_plus_x():
    origin = np.array([[10.0, 5.0]])
    yaw = np.array([math.pi / 2])  # facing global +y
    pts = np.array([[[10.0, 8.0], [7.0, 5.0]]])  # 3 m ahead, 3 m to the left
    out = geometry.to_ego_frame(pts, origin, yaw)
    np.testing.assert_allclose(out[0], [[3.0, 0.0], [0.0, 3.0]], atol=1e-12)


@settings(deadline=None)
@given(st.lists(st.floats(-50, 50, allow_nan=False), min_size=1, max_size=20))
def test_round_like_python_matches_builtin_round(values):
    out = geometry.round_like_python(np.array(values))
    for v, r in zip(values, out.tolist()):
        assert r == round(v, 3)
        assert math.copysign(1.0, r) == 1.0 or r != 0.0  # never -0.0


def test_round_like_python_differs_from_numpy_where_python_is_exact():
    # decimal midpoints are not exact in binary; Python rounds the stored value correctly
    values = np.array([9.9745, 3.0555, 8.2495, 6.6645])
    assert [round(v, 3) for v in values.tolist()] == [9.975, 3.055, 8.249, 6.665]
    assert np.round(values, 3).tolist() != [9.975, 3.055, 8.249, 6.665]
    assert geometry.round_like_python(values).tolist() == [9.975, 3.055, 8.249, 6.665]


def test_reference_postprocessing_zeroes_rather_than_clips():
    raw = np.array([[0.1999, 0.2], [0.2, 0.2001], [5.4321, -0.25], [3.0, -0.0001], [0.19996, 0.19996]])
    out = geometry.postprocess_reference(raw)
    expected = [[0.0, 0.2], [0.2, 0.0], [5.432, 0.0], [3.0, 0.0], [0.0, 0.2]]
    np.testing.assert_array_equal(out, expected)
    assert not np.signbit(out[3, 1])  # -0.0001 rounds to 0.0, not -0.0
    # rounding is Python's round(x, 3), also at binary-inexact decimal midpoints
    mid = geometry.postprocess_reference(np.array([[9.9745, 0.0245], [3.0555, -0.1995]]))
    assert mid.tolist() == [[round(9.9745, 3), round(0.0245, 3)], [round(3.0555, 3), round(-0.1995, 3)]]


# --------------------------------------------------------------------------- rendering


def test_format_number_is_plain_decimal():
    assert format_number(np.float64(4.512)) == "4.512"
    assert format_number(-0.0) == "0.0"
    assert format_number(np.float32(0.5)) == "0.5"
    assert format_number(12) == "12.0"
    assert format_number(1e-5) == "0.00001"
    assert format_number(-3.2e-7) == "-0.00000032"
    with pytest.raises(ValueError):
        format_number(float("nan"))
    with pytest.raises(ValueError):
        format_number(float("inf"))


@settings(deadline=None)
@given(st.floats(allow_nan=False, allow_infinity=False))
@example(5.960464477539063e-08)
@example(1e300)
@example(-5e-324)
def test_format_number_round_trips_without_exponent(x):
    text = format_number(x)
    assert "e" not in text and "E" not in text and "np." not in text
    assert float(text) == x


def test_format_history_renders_pairs_most_recent_last():
    actions = np.array([[4.512, 0.0], [4.6, -0.012], [4.7, -0.0], [5.0, 0.003], [5.1, 0.0], [5.25, 0.1]])
    assert format_history(actions) == (
        "[(4.512, 0.0), (4.6, -0.012), (4.7, 0.0), (5.0, 0.003), (5.1, 0.0), (5.25, 0.1)]"
    )
    with pytest.raises(ValueError, match=r"\(6, 3\)"):
        format_history(np.zeros((6, 3)))


def test_format_history_of_loaded_frames_has_no_library_reprs(fs):
    for frame in fs:
        text = format_history(frame.history_actions)
        assert "np." not in text and "float" not in text and "-0.0," not in text and "-0.0)" not in text
        assert [tuple(map(float, p.strip("()").split(", "))) for p in text[1:-1].split("), (")] == [
            tuple(a) for a in frame.history_actions.tolist()
        ]


# --------------------------------------------------------------------------- windows and counts


def test_window_ranges_follow_the_spec():
    assert window_range(40, "reference") == range(7, 33)  # 7 … N−8
    assert window_range(40, "full") == range(7, 34)  # 7 … N−7
    assert len(window_range(14, "reference")) == 0 and len(window_range(15, "reference")) == 1
    assert len(window_range(13, "full")) == 0 and len(window_range(14, "full")) == 1
    with pytest.raises(ValueError, match="window"):
        window_range(40, "paper")


def test_frame_counts_are_n_minus_14_and_n_minus_13_per_scene(small_root, fs):
    n_scenes = SMALL["scenes"]
    n = SMALL["keyframes"]
    assert len(fs) == n_scenes * (n - 14)
    full = load_frames(small_root, VERSION, split="all", window="full")
    assert len(full) == n_scenes * (n - 13)
    for name in fs.scenes:
        ks = [f.keyframe_index for f in fs if f.scene_name == name]
        assert ks == list(range(7, n - 7))
        ks_full = [f.keyframe_index for f in full if f.scene_name == name]
        assert ks_full == list(range(7, n - 6))


def test_order_is_scene_name_then_keyframe_and_ids_name_scene_and_sample(fs):
    keys = [(f.scene_name, f.keyframe_index) for f in fs]
    assert keys == sorted(keys)
    assert fs.scenes == sorted(fs.scenes)
    for f in fs:
        assert f.frame_id == f"{f.scene_name}/{f.sample_token}"
    assert fs.frame_ids == [f.frame_id for f in fs]
    assert fs.scene_names == [f.scene_name for f in fs]


# --------------------------------------------------------------------------- against an independent computation


def test_frames_match_an_independent_reading_of_the_raw_tables(small_root, fs):
    ref = reference_frames(small_root, VERSION)
    assert list(ref) == fs.frame_ids
    for f in fs:
        r = ref[f.frame_id]
        assert f.keyframe_index == r["c"]
        assert f.timestamp == r["timestamp"]
        assert f.image_path == r["image"]
        np.testing.assert_allclose(f.history_positions, r["history_positions"], atol=1e-9)
        np.testing.assert_allclose(f.gt_positions, r["gt_positions"], atol=1e-9)
        np.testing.assert_allclose(f.gt_actions, r["gt_actions"], atol=1e-9)
        # post-processed history: identical values (same thresholds, Python rounding)
        assert f.history_actions.tolist() == [list(p) for p in r["history_actions"]]


def test_full_window_matches_the_independent_reading_too(small_root):
    full = load_frames(small_root, VERSION, split="all", window="full")
    ref = reference_frames(small_root, VERSION, window="full")
    assert list(ref) == full.frame_ids
    last = full[len(full) - 1]
    np.testing.assert_allclose(last.gt_positions, ref[last.frame_id]["gt_positions"], atol=1e-9)


# --------------------------------------------------------------------------- against the devkit's own reading


def _devkit():
    return pytest.importorskip(
        "nuscenes.nuscenes",
        reason="nuscenes-devkit (lightemma[nuscenes]) is not installed; "
        "CI installs it (the README's main install includes the nuscenes extra)",
    )


@pytest.mark.parametrize("window", ["reference", "full"])
def test_the_frame_reader_agrees_with_the_devkits_reading_of_the_same_dataroot(small_root, window):
    from pyquaternion import Quaternion  # a devkit dependency

    nusc = _devkit().NuScenes(version=VERSION, dataroot=str(small_root), verbose=False)
    tables = load_tables(small_root, VERSION)
    # the index: every sample's CAM_FRONT keyframe, as the devkit's sample["data"] holds it
    assert tables.front_keyframes == {s["token"]: s["data"]["CAM_FRONT"] for s in nusc.sample}
    assert [s["name"] for s in tables.scenes] == [s["name"] for s in nusc.scene]
    frames = extract_frames(tables, split="all", window=window)
    assert len(frames) == sum(len(window_range(s["nbr_samples"], window)) for s in nusc.scene)
    # each frame's keyframe chain, pose, time, image and calibration through the devkit's own get()
    chains = {}
    for scene in nusc.scene:
        chain, token = [], scene["first_sample_token"]
        while token:
            chain.append(token)
            token = nusc.get("sample", token)["next"]
        chains[scene["name"]] = chain
    for i, frame in enumerate(frames):
        chain = chains[frame.scene_name]
        assert chain[frame.keyframe_index] == frame.sample_token
        sd = nusc.get("sample_data", nusc.get("sample", frame.sample_token)["data"]["CAM_FRONT"])
        pose = nusc.get("ego_pose", sd["ego_pose_token"])
        cs = nusc.get("calibrated_sensor", sd["calibrated_sensor_token"])
        assert frame.image_path == nusc.get_sample_data_path(sd["token"])
        assert frame.timestamp == pose["timestamp"] == sd["timestamp"]
        np.testing.assert_allclose(frame.ego_pose[:2], pose["translation"][:2], rtol=0, atol=1e-9)
        assert frame.ego_pose[2] == pytest.approx(Quaternion(pose["rotation"]).yaw_pitch_roll[0], abs=1e-12)
        np.testing.assert_array_equal(frame.camera_intrinsic, cs["camera_intrinsic"])
        np.testing.assert_allclose(
            frame.camera_extrinsic[:3, :3], Quaternion(cs["rotation"]).rotation_matrix, atol=1e-12
        )
        np.testing.assert_allclose(frame.camera_extrinsic[:3, 3], cs["translation"], atol=1e-12)
        # the future positions from the devkit's poses of keyframes c+1 … c+6, in the ego frame
        future = [
            nusc.get("ego_pose", nusc.get("sample_data", nusc.get("sample", t)["data"]["CAM_FRONT"])["ego_pose_token"])
            for t in chain[frame.keyframe_index + 1 : frame.keyframe_index + 7]
        ]
        x, y, yaw = frame.ego_pose
        d = np.array([p["translation"][:2] for p in future]) - [x, y]
        c, s = math.cos(yaw), math.sin(yaw)
        np.testing.assert_allclose(
            frames.gt_positions[i], np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], -1), atol=1e-9
        )


def test_the_split_lists_are_the_devkits():
    splits = pytest.importorskip(
        "nuscenes.utils.splits", reason="nuscenes-devkit (lightemma[nuscenes]) is not installed"
    )
    assert predefined_splits() == splits.create_splits_scenes()
    assert {k: len(v) for k, v in predefined_splits().items()} == {
        "train": 700,
        "val": 150,
        "test": 150,
        "mini_train": 8,
        "mini_val": 2,
        "train_detect": 350,
        "train_track": 350,
    }


@pytest.mark.slow
def test_frames_and_splits_load_without_the_devkit_or_its_dependencies(renamed_mini, tmp_path):
    import subprocess
    import sys

    root, splits = renamed_mini
    code = f"""
import sys
for name in ("nuscenes", "pyquaternion", "cv2", "shapely", "sklearn"):
    sys.modules[name] = None  # any import of them fails
import lightemma
fs = lightemma.load_frames({str(root)!r}, {VERSION!r}, split="mini_val")
print(len(fs), fs.scenes)
try:
    lightemma.load_frames({str(root)!r}, {VERSION!r}, split="val")
except lightemma.errors.DatasetError as exc:
    print(exc)
from lightemma.cli import main
print(main(["run", "--model", "baseline:cv", "--dataroot", {str(root)!r}, "--version", {VERSION!r}, "--split", "mini_val",
            "--output", {str(tmp_path / "runs")!r}, "--no-progress"]))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.splitlines()
    assert out[-1] == "0"  # a whole run, without the devkit
    assert out[0] == f"{2 * (SMALL['keyframes'] - 14)} {sorted(splits['mini_val'])}"
    assert "of the 150 scenes of split 'val' are not in version v1.0-mini" in out[1] and "v1.0-trainval" in out[1]


def test_extract_frames_takes_the_readers_tables_only(small_root):
    tables = load_tables(small_root, VERSION)
    assert isinstance(tables, Tables) and tables.version == VERSION and tables.dataroot == str(small_root)
    with pytest.raises(TypeError, match="load_tables"):
        extract_frames(object(), split="all")
    with pytest.raises(DatasetError, match="ego_pose 'nope' is not in"):
        tables.get("ego_pose", "nope")


# --------------------------------------------------------------------------- against the closed form


def _ego(truth_pose_now, pts):
    x, y, yaw = truth_pose_now
    d = pts[:, :2] - np.array([x, y])
    c, s = math.cos(yaw), math.sin(yaw)
    return np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=-1)


def test_positions_and_pose_match_the_closed_form(small_root, fs, truth):
    samples = {s["token"]: s for s in read_table(small_root, VERSION, "sample")}
    for f in fs:
        scn = truth[f.scene_name]
        # keyframe timestamps of c−7 … c+6 from the sample chain
        toks = [f.sample_token]
        for _ in range(6):
            toks.append(samples[toks[-1]]["next"])
        back = [f.sample_token]
        for _ in range(7):
            back.append(samples[back[-1]]["prev"])
        ts_future = np.array([samples[t]["timestamp"] for t in toks[1:]])
        ts_hist = np.array([samples[t]["timestamp"] for t in reversed(back)])
        now = scn.pose(scn.seconds(f.timestamp))
        np.testing.assert_allclose(f.ego_pose[:2], now[:2], atol=1e-6)
        assert math.remainder(f.ego_pose[2] - now[2], 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
        np.testing.assert_allclose(f.gt_positions, _ego(now, scn.pose(scn.seconds(ts_future))), atol=1e-6)
        np.testing.assert_allclose(f.history_positions, _ego(now, scn.pose(scn.seconds(ts_hist))), atol=1e-6)


def test_history_speeds_and_curvatures_match_the_closed_form(small_root, fs, truth):
    samples = {s["token"]: s for s in read_table(small_root, VERSION, "sample")}
    checked_arcs = 0
    for f in fs:
        scn = truth[f.scene_name]
        back = [f.sample_token]
        for _ in range(7):
            back.append(samples[back[-1]]["prev"])
        t = scn.seconds([samples[x]["timestamp"] for x in reversed(back)])  # t_{c-7} … t_c
        s = scn.profile.s(t)
        for k in range(1, 7):
            a, b = k, k + 1  # the segment leaving keyframe c−7+k
            mean_speed = (s[b] - s[a]) / (t[b] - t[a])
            v = f.history_actions[k - 1, 0]
            if mean_speed < 0.19:
                assert v == 0.0
            elif mean_speed > 0.21:
                # chord vs arc on a curve: relative error about (Δθ)²/24 < 1 %; rounding 0.0005
                assert v == pytest.approx(mean_speed, rel=0.01, abs=6e-4)
            kappa = f.history_actions[k - 1, 1]
            k_true = scn.path.curvature(s[k - 1 : k + 2])
            on_one_arc = np.all(k_true == k_true[0]) and _same_segment(scn, s[k - 1 : k + 2])
            moving = s[k + 1] - s[k - 1] > 0.05
            if on_one_arc and moving:
                # three points on one circle: Menger curvature is exactly 1/R (up to rounding)
                expected = k_true[0] if abs(k_true[0]) <= 0.2 else 0.0
                assert kappa == pytest.approx(expected, abs=6e-4)
                checked_arcs += k_true[0] != 0
            else:
                lo, hi = min(0.0, k_true.min()), max(0.0, k_true.max())
                assert lo - 6e-4 <= kappa <= hi + 6e-4
    assert checked_arcs > 0


def _same_segment(scn, s):
    starts = np.cumsum([0.0] + [length for length, _ in scn.path.segments])
    idx = np.searchsorted(starts, s, side="right")
    return bool(np.all(idx == idx[0]))


def test_turn_signs_and_stops_show_in_the_history(fs, truth):
    by_kind = {}
    for f in fs:
        by_kind.setdefault(truth[f.scene_name].kind, []).append(f)
    left = np.concatenate([f.history_actions[:, 1] for f in by_kind["left-turn"]])
    right = np.concatenate([f.history_actions[:, 1] for f in by_kind["right-turn"]])
    assert left.max() > 0.05 and left.min() >= 0.0
    assert right.min() < -0.05 and right.max() <= 0.0
    waiting = by_kind["wait-then-go-green"][0]
    assert waiting.history_actions[:, 0].tolist() == [0.0] * 6  # stopped at the red light
    braking = by_kind["brake-red-light"][-1]
    assert braking.gt_actions[-1, 0] == pytest.approx(0.0, abs=1e-9)  # at rest by the end


def test_gt_actions_integrate_back_to_the_gt_positions_on_straight_cruise(fs, truth):
    f = next(f for f in fs if truth[f.scene_name].kind == "cruise")
    v = f.gt_actions[:, 0]
    assert np.all(np.abs(f.gt_actions[:, 1]) < 1e-9)
    np.testing.assert_allclose(f.gt_positions[:, 1], 0.0, atol=1e-6)
    # real timestamps: the cumulative distance uses the jittered spacing, not 0.5 s
    assert not np.allclose(np.diff(f.gt_positions[:, 0]), v[1:] * 0.5, atol=1e-9)


# --------------------------------------------------------------------------- frames and sets


def test_frame_fields_types_and_calibration(small_root, fs):
    cal = read_table(small_root, VERSION, "calibrated_sensor")[0]
    f = fs[0]
    assert isinstance(f, Frame)
    assert os.path.isabs(f.image_path) and os.path.isfile(f.image_path)
    np.testing.assert_array_equal(f.camera_intrinsic, cal["camera_intrinsic"])
    np.testing.assert_allclose(f.camera_extrinsic[:3, 3], cal["translation"])
    r = f.camera_extrinsic[:3, :3]
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(f.camera_extrinsic[3], [0, 0, 0, 1])
    # the camera looks forward: its optical axis (z) is the ego's +x
    np.testing.assert_allclose(r[:, 2], [1, 0, 0], atol=0.01)
    for name, shape in [
        ("history_positions", (8, 2)),
        ("history_actions", (6, 2)),
        ("gt_positions", (6, 2)),
        ("gt_actions", (6, 2)),
        ("ego_pose", (3,)),
    ]:
        assert getattr(f, name).shape == shape
    np.testing.assert_allclose(f.history_positions[-1], [0.0, 0.0], atol=1e-12)
    d = f.to_dict()
    json.dumps(d)
    assert d["frame_id"] == f.frame_id and len(d["gt_positions"]) == 6
    with pytest.raises(AttributeError):
        f.scene_name = "x"  # frozen


def test_stacked_arrays_are_read_only_and_consistent(fs):
    n = len(fs)
    assert fs.history_actions.shape == (n, 6, 2)
    assert fs.gt_positions.shape == (n, 6, 2)
    assert fs.gt_actions.shape == (n, 6, 2)
    assert fs.history_positions.shape == (n, 8, 2)
    assert fs.history_actions.dtype == np.float64
    with pytest.raises(ValueError):
        fs.gt_positions[0, 0, 0] = 1.0
    np.testing.assert_array_equal(fs.history_actions[5], fs[5].history_actions)
    np.testing.assert_array_equal(fs[-1].gt_positions, fs.gt_positions[n - 1])
    with pytest.raises(IndexError):
        fs[n]


def test_select_head_describe(small_root, fs):
    ids = [fs.frame_ids[9], fs.frame_ids[2]]
    sub = fs.select(ids)
    assert sub.frame_ids == [fs.frame_ids[2], fs.frame_ids[9]]  # the set's order
    np.testing.assert_array_equal(sub.gt_positions[1], fs.gt_positions[9])
    assert fs.head(3).frame_ids == fs.frame_ids[:3]
    assert len(fs.head(10_000)) == len(fs)
    with pytest.raises(DatasetError, match="nope/123"):
        fs.select(["nope/123"])
    d = fs.describe()
    json.dumps(d)
    assert d["dataroot"] == str(small_root)
    assert (d["version"], d["split"], d["window"], d["n_frames"]) == (VERSION, "all", "reference", len(fs))
    assert d["scenes"] == sorted(d["scenes"]) and len(d["scenes"]) == SMALL["scenes"]
    assert fs.head(3).describe()["scenes"] == [fs.scene_names[0]]


def test_frame_sets_pickle(fs):
    import pickle

    back = pickle.loads(pickle.dumps(fs))
    assert back.frame_ids == fs.frame_ids and back.describe() == fs.describe()
    np.testing.assert_array_equal(back.gt_positions, fs.gt_positions)
    assert back.get(fs.frame_ids[4]).frame_id == fs.frame_ids[4]


def test_loading_is_deterministic(small_root, fs):
    again = lightemma.load_frames(small_root, VERSION, split="all")
    assert again.frame_ids == fs.frame_ids
    np.testing.assert_array_equal(again.history_actions, fs.history_actions)
    np.testing.assert_array_equal(again.gt_positions, fs.gt_positions)


def test_public_exports():
    assert lightemma.load_frames is load_frames
    assert lightemma.FrameSet is FrameSet and lightemma.Frame is Frame


# --------------------------------------------------------------------------- splits and scene filters


def test_scene_filter_keeps_only_those_scenes_sorted(small_root, fs):
    names = [fs.scenes[5], fs.scenes[1]]
    sub = load_frames(small_root, VERSION, scenes=names)
    assert sub.scenes == sorted(names)
    assert set(sub.scene_names) == set(names)
    assert sub.split is None
    assert sub.frame_ids == [f for f in fs.frame_ids if f.split("/")[0] in names]


def test_unknown_scene_is_named(small_root):
    with pytest.raises(DatasetError, match="scene-9999"):
        load_frames(small_root, VERSION, scenes=["scene-9999"])


def test_v1_0_mini_without_a_split_takes_all_of_its_scenes(small_root, fs, caplog):
    # v1.0-mini is a trial set: by default every scene, not the 2-scene mini_val
    with caplog.at_level(logging.INFO, logger="lightemma.frames"):
        default = load_frames(small_root, VERSION)
    assert f"loaded {default.summary_line()}" in caplog.messages
    assert default.split == "all" and default.frame_ids == fs.frame_ids
    assert len(default.scenes) == SMALL["scenes"] == 8
    assert (
        default.summary_line()
        == f"v1.0-mini, split all: 8 scenes, {8 * (SMALL['keyframes'] - 14)} frames, reference window"
    )


def test_summary_line_names_subsets_limits_and_what_was_left_out(small_root, fs):
    two = fs.select_scenes(fs.scenes[:2])
    assert two.summary_line() == "v1.0-mini, split all: 2 scenes, 12 frames, reference window"
    by_name = load_frames(small_root, VERSION, scenes=[fs.scenes[0]], window="full")
    assert by_name.summary_line() == "v1.0-mini, scenes given by name: 1 scene, 7 frames, full window"
    described = {**fs.describe(), "limit": 5, "n_frames": 5, "skipped_scenes": ["a"], "missing_images": ["x", "y"]}
    assert summary_line(described) == (
        "v1.0-mini, split all: 8 scenes, 5 frames, reference window (first 5 frames); "
        "1 scene too short for a frame, skipped; 2 frames without an image file"
    )
    assert summary_line({"n_frames": 3, "window": "reference"}) == "3 frames passed in memory"


def test_a_named_mini_split_on_synthetic_data_says_how_to_load_it(small_root):
    with pytest.raises(DatasetError, match="mini_val") as exc:
        load_frames(small_root, VERSION, split="mini_val")
    assert "split='all'" in str(exc.value)
    assert "--split all" in exc.value.for_cli() and "split='all'" not in exc.value.for_cli()


def test_unknown_split_lists_the_choices(small_root):
    with pytest.raises(DatasetError, match="unknown split 'nightly'.*mini_val"):
        load_frames(small_root, VERSION, split="nightly")


def test_split_of_another_version_says_which(small_root):
    with pytest.raises(DatasetError, match="belongs to version v1.0-trainval"):
        load_frames(small_root, VERSION, split="val")


def test_custom_version_needs_an_explicit_choice(tmp_path):
    root = make_small_dataset(tmp_path / "custom", scenes=2, version="v9-synth", images=False)
    with pytest.raises(DatasetError, match="no default split") as exc:
        load_frames(root, "v9-synth")
    assert "split='all'" in str(exc.value) and "--split all" in exc.value.for_cli()
    assert len(load_frames(root, "v9-synth", split="all", on_missing_image="keep")) == 2 * 6


@pytest.fixture
def renamed_mini(small_copy):
    """The small dataset with scenes renamed to nuScenes' real mini split names."""
    splits = predefined_splits()
    names = splits["mini_val"] + splits["mini_train"][:6]
    path = small_copy / VERSION / "scene.json"
    scenes = json.loads(path.read_text())
    for scene, name in zip(sorted(scenes, key=lambda s: s["name"]), names):
        scene["name"] = name
    path.write_text(json.dumps(scenes))
    return small_copy, splits


def test_default_split_and_named_splits_resolve_by_the_devkits_split_lists(renamed_mini):
    root, splits = renamed_mini
    fs = load_frames(root, VERSION)  # v1.0-mini defaults to all 10 of its scenes (here 8)
    assert fs.split == "all"
    assert fs.scenes == sorted(splits["mini_val"] + splits["mini_train"][:6])
    assert len(fs) == 8 * (SMALL["keyframes"] - 14)
    val = load_frames(root, VERSION, split="mini_val")
    assert val.scenes == sorted(splits["mini_val"]) and len(val) == 2 * (SMALL["keyframes"] - 14)
    with pytest.raises(DatasetError, match="2 of the 8 scenes of split 'mini_train'"):
        load_frames(root, VERSION, split="mini_train")
    one = load_frames(root, VERSION, split="mini_val", scenes=[splits["mini_val"][1]])
    assert one.scenes == [splits["mini_val"][1]] and one.split == "mini_val"
    with pytest.raises(DatasetError, match="not in split 'mini_val'"):
        load_frames(root, VERSION, split="mini_val", scenes=[splits["mini_train"][0]])


# --------------------------------------------------------------------------- bad input


def test_missing_dataroot_is_named(tmp_path):
    with pytest.raises(DatasetError, match=f"dataroot {tmp_path / 'nowhere'} does not exist"):
        load_frames(tmp_path / "nowhere", VERSION)


def test_missing_version_folder_lists_the_versions_there(small_root):
    with pytest.raises(DatasetError, match=r"v1.0-test does not exist; versions found there: v1.0-mini"):
        load_frames(small_root, "v1.0-test")


def test_missing_table_is_named(small_copy):
    os.remove(small_copy / VERSION / "ego_pose.json")
    with pytest.raises(DatasetError, match=r"ego_pose\.json"):
        load_frames(small_copy, VERSION, split="all")


def test_corrupt_table_is_named(small_copy):
    (small_copy / VERSION / "sample.json").write_text('[{"token": ')
    with pytest.raises(DatasetError, match=r"sample\.json"):
        load_frames(small_copy, VERSION, split="all")


def test_frames_do_not_need_the_map_files(small_copy, fs):
    # the devkit refuses a dataroot without its map masks; frames use no map, so they load the same
    shutil.rmtree(small_copy / "maps")
    loaded = load_frames(small_copy, VERSION, split="all")
    assert loaded.frame_ids == fs.frame_ids
    np.testing.assert_array_equal(loaded.gt_positions, fs.gt_positions)


def test_inconsistent_tables_are_a_dataset_error_not_a_key_error(small_copy):
    path = small_copy / VERSION / "sample_data.json"
    rows = json.loads(path.read_text())
    rows[0]["calibrated_sensor_token"] = "0" * 32
    path.write_text(json.dumps(rows))
    with pytest.raises(DatasetError, match="inconsistent"):
        load_frames(small_copy, VERSION, split="all")


def _remove_images(root, fs, k):
    gone = [fs.frame_ids[i] for i in (3, 20, 21)[:k]]
    for fid in gone:
        os.remove(fs.get(fid).image_path.replace(str(fs.dataroot), str(root)))
    return gone


def test_missing_images_are_listed_and_skipped(small_copy, fs, caplog):
    gone = _remove_images(small_copy, fs, 3)
    with caplog.at_level(logging.WARNING, logger="lightemma.frames"):
        got = load_frames(small_copy, VERSION, split="all")
    assert got.missing_images == gone
    assert len(got) == len(fs) - 3
    assert not set(gone) & set(got.frame_ids)
    assert got.describe()["missing_images"] == gone
    assert gone[0] in caplog.text


def test_missing_images_can_stop_the_load_or_be_kept(small_copy, fs):
    gone = _remove_images(small_copy, fs, 2)
    with pytest.raises(DatasetError, match="2 of .* frame image") as exc:
        load_frames(small_copy, VERSION, split="all", on_missing_image="error")
    assert gone[0] in str(exc.value) and gone[1] in str(exc.value)
    kept = load_frames(small_copy, VERSION, split="all", on_missing_image="keep")
    assert len(kept) == len(fs) and kept.missing_images == gone


def test_scene_too_short_is_logged_and_skipped(tmp_path, caplog):
    root = make_small_dataset(tmp_path / "short", scenes=2, keyframes=14, images=False)
    with caplog.at_level(logging.WARNING, logger="lightemma.frames"):
        ref = load_frames(root, VERSION, split="all", on_missing_image="keep")
    assert len(ref) == 0
    assert ref.skipped_scenes == ["synth-0000-cruise", "synth-0001-accelerate"]
    assert "synth-0000-cruise has 14 keyframes" in caplog.text
    full = load_frames(root, VERSION, split="all", window="full", on_missing_image="keep")
    assert len(full) == 2 and full.skipped_scenes == []
    assert [f.keyframe_index for f in full] == [7, 7]


def test_scene_without_a_front_camera_keyframe_is_named(small_copy):
    path = small_copy / VERSION / "sample_data.json"
    rows = json.loads(path.read_text())
    scenes = json.loads((small_copy / VERSION / "scene.json").read_text())
    first = scenes[0]["first_sample_token"]
    for r in rows:
        if r["sample_token"] == first and r["is_key_frame"]:
            r["is_key_frame"] = False
    path.write_text(json.dumps(rows))
    with pytest.raises(DatasetError, match=f"scene {scenes[0]['name']}: sample {first} has no CAM_FRONT"):
        load_frames(small_copy, VERSION, split="all")


def test_bad_arguments_are_value_errors(small_root):
    with pytest.raises(ValueError, match="window"):
        load_frames(small_root, VERSION, split="all", window="paper")
    with pytest.raises(ValueError, match="on_missing_image"):
        load_frames(small_root, VERSION, split="all", on_missing_image="ignore")
    with pytest.raises(DatasetError, match="empty"):
        load_frames(small_root, VERSION, scenes=[])


def test_keyframe_timestamps_that_do_not_increase_are_named(small_copy):
    path = small_copy / VERSION / "ego_pose.json"
    poses = json.loads(path.read_text())
    scenes = sorted(json.loads((small_copy / VERSION / "scene.json").read_text()), key=lambda s: s["name"])
    samples = {s["token"]: s for s in read_table(small_copy, VERSION, "sample")}
    sds = {sd["sample_token"]: sd for sd in read_table(small_copy, VERSION, "sample_data") if sd["is_key_frame"]}
    first = scenes[0]["first_sample_token"]
    second = samples[first]["next"]
    by_token = {p["token"]: p for p in poses}
    by_token[sds[second]["ego_pose_token"]]["timestamp"] = by_token[sds[first]["ego_pose_token"]]["timestamp"]
    path.write_text(json.dumps(poses))
    with pytest.raises(DatasetError, match=f"scene {scenes[0]['name']}: keyframe timestamps do not increase"):
        load_frames(small_copy, VERSION, split="all")


# --------------------------------------------------------------------------- unusable pose records


def _keyframe_pose(root, scene_index: int, keyframe: int):
    """(all ego poses, the pose record of a keyframe of the scene_index-th scene by name, that scene's name)."""
    poses = json.loads((root / VERSION / "ego_pose.json").read_text())
    scenes = sorted(json.loads((root / VERSION / "scene.json").read_text()), key=lambda s: s["name"])
    samples = {s["token"]: s for s in read_table(root, VERSION, "sample")}
    sds = {sd["sample_token"]: sd for sd in read_table(root, VERSION, "sample_data") if sd["is_key_frame"]}
    token = scenes[scene_index]["first_sample_token"]
    for _ in range(keyframe):
        token = samples[token]["next"]
    by_token = {p["token"]: p for p in poses}
    return poses, by_token[sds[token]["ego_pose_token"]], scenes[scene_index]["name"]


BAD_POSES = {
    "zero quaternion": ("rotation", [0.0, 0.0, 0.0, 0.0], "is not a unit quaternion (norm 0;"),
    "scaled quaternion": ("rotation", [2.0, 0.0, 0.0, 0.0], "is not a unit quaternion (norm 2;"),
    "quaternion just outside the tolerance": ("rotation", [1.0 + 2e-5, 0.0, 0.0, 0.0], "|norm - 1| <= 1e-05"),
    "three-value quaternion": ("rotation", [1.0, 0.0, 0.0], "has 3 value(s), needs 4"),
    "NaN quaternion": ("rotation", [float("nan"), 0.0, 0.0, 1.0], "not finite"),
    "text quaternion": ("rotation", "1 0 0 0", "is not a list of 4 numbers"),
    "one-value translation": ("translation", [412.5], "has 1 value(s), needs 3"),
    "two-value translation": ("translation", [412.5, 1180.2], "has 2 value(s), needs 3"),
    "four-value translation": ("translation", [412.5, 1180.2, 0.0, 1.0], "has 4 value(s), needs 3"),
    "NaN translation": ("translation", [float("nan"), 1.0, 0.0], "not finite"),
    "infinite translation": ("translation", [float("inf"), 1.0, 0.0], "not finite"),
    "text translation": ("translation", ["a", "b", "c"], "is not a list of 3 numbers"),
    "boolean translation": ("translation", [True, 1.0, 0.0], "is not a list of 3 numbers"),
    "missing translation": ("translation", None, "is not a list of 3 numbers"),
    "NaN timestamp": ("timestamp", float("nan"), "not a finite, whole, non-negative number"),
    "fractional timestamp": ("timestamp", 1.5e15 + 0.5, "not a finite, whole, non-negative number"),
    "negative timestamp": ("timestamp", -5, "not a finite, whole, non-negative number"),
    "text timestamp": ("timestamp", "1532402927647951", "not a finite, whole, non-negative number"),
}


@pytest.mark.parametrize("kind", list(BAD_POSES))
def test_an_unusable_pose_is_named_by_table_token_and_field_and_its_scene_skipped(small_copy, fs, kind, caplog):
    field, value, why = BAD_POSES[kind]
    poses, pose, scene = _keyframe_pose(small_copy, 1, 9)
    pose[field] = value
    (small_copy / VERSION / "ego_pose.json").write_text(json.dumps(poses))  # NaN is written as the literal NaN
    with caplog.at_level(logging.WARNING, logger="lightemma.frames"):
        loaded = load_frames(small_copy, VERSION, split="all")
    assert scene not in loaded.scenes and scene in loaded.skipped_scenes
    assert len(loaded) == len(fs) - sum(1 for s in fs.scene_names if s == scene)
    (note,) = loaded.bad_records
    assert note.startswith(f"scene {scene}: ego_pose {pose['token']}: field {field} = ") and why in note
    assert loaded.describe()["bad_records"] == [note]
    assert any(pose["token"] in r.message and field in r.message for r in caplog.records)
    # the other scenes are untouched
    kept = fs.select_scenes(loaded.scenes)
    np.testing.assert_array_equal(loaded.gt_positions, kept.gt_positions)
    with pytest.raises(DatasetError) as info:
        load_frames(small_copy, VERSION, split="all", on_bad_record="error")
    message = str(info.value)
    assert "\n" not in message and message.startswith(f"scene {scene}: ego_pose {pose['token']}: field {field}")
    assert why in message and "on_bad_record='skip'" in message  # the Python API names the argument
    assert "--on-bad-record skip" in info.value.for_cli()  # the command line names the flag


def test_quaternions_within_the_tolerance_are_renormalised_and_give_the_same_frames(small_copy, fs):
    poses = json.loads((small_copy / VERSION / "ego_pose.json").read_text())
    for pose in poses:
        pose["rotation"] = [(1 + 0.9e-5) * q for q in pose["rotation"]]  # inside QUATERNION_TOLERANCE = 1e-5
    (small_copy / VERSION / "ego_pose.json").write_text(json.dumps(poses))
    loaded = load_frames(small_copy, VERSION, split="all")
    assert loaded.frame_ids == fs.frame_ids and not loaded.bad_records
    np.testing.assert_allclose(loaded.gt_positions, fs.gt_positions, atol=1e-9)
    np.testing.assert_allclose(loaded.history_actions, fs.history_actions, atol=1e-9)


CAMERA_FIELDS = {
    "two-value translation": ("translation", [1.7, 0.0], "has 2 value(s), needs 3"),
    "scaled quaternion": ("rotation", [1.0, 1.0, 1.0, 1.0], "is not a unit quaternion (norm 2;"),
    "2x3 intrinsic": ("camera_intrinsic", [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], "is not a finite 3x3 matrix"),
}


@pytest.mark.parametrize("kind", list(CAMERA_FIELDS))
def test_an_unusable_camera_calibration_is_named_too(small_copy, kind):
    field, value, why = CAMERA_FIELDS[kind]
    path = small_copy / VERSION / "calibrated_sensor.json"
    sensors = {s["token"]: s["channel"] for s in read_table(small_copy, VERSION, "sensor")}
    rows = json.loads(path.read_text())
    (front,) = [r for r in rows if sensors[r["sensor_token"]] == "CAM_FRONT"]
    front[field] = value
    path.write_text(json.dumps(rows))
    with pytest.raises(DatasetError) as info:
        load_frames(small_copy, VERSION, split="all", on_bad_record="error")
    message = str(info.value)
    assert "\n" not in message and f"calibrated_sensor {front['token']}: field {field} = " in message and why in message


def test_on_bad_record_must_be_skip_or_error(small_root):
    with pytest.raises(ValueError, match="on_bad_record"):
        load_frames(small_root, VERSION, split="all", on_bad_record="ignore")
