"""The synthetic nuScenes-format dataset: devkit-loadable, deterministic, true to its closed form."""

from __future__ import annotations

import hashlib
import json
import math
import os

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from lightemma.cli import main
from lightemma.errors import UserError
from lightemma.nuscenes.json_tables import TABLES
from lightemma.synth import KINDS, Camera, Path, SpeedProfile, build_scenarios, render_frame, write_dataset
from lightemma.synth.drawing import LAMP_ON
from tests.support.frames_fixtures import SMALL, read_table, small_root  # noqa: F401

VERSION = "v1.0-mini"


def _digest(root) -> dict[str, str]:
    out = {}
    for folder, _, files in os.walk(root):
        for name in files:
            path = os.path.join(folder, name)
            with open(path, "rb") as f:
                out[os.path.relpath(path, root)] = hashlib.sha256(f.read()).hexdigest()
    return out


# --------------------------------------------------------------------------- closed-form kinematics


@settings(deadline=None)
@given(st.floats(0, 15), st.floats(0.1, 3), st.floats(0.5, 8), st.floats(0, 30))
def test_speed_profile_is_consistent(v0, accel, duration, t):
    prof = SpeedProfile(v0, ((duration, accel), (2.0, 0.0)))
    h = 1e-4
    # ds/dt = v everywhere (central difference, exact for piecewise quadratics away from breaks)
    if abs(t - duration) > 2 * h and t > 2 * h:
        assert (prof.s(t + h) - prof.s(t - h)) / (2 * h) == pytest.approx(float(prof.v(t)), rel=1e-6, abs=1e-6)
    assert float(prof.v(duration + 1.0)) == pytest.approx(v0 + accel * duration)


def test_speed_profile_refuses_negative_speed():
    with pytest.raises(ValueError, match="negative"):
        SpeedProfile(5.0, ((3.0, -2.0),))


@settings(deadline=None)
@given(st.floats(5, 40), st.sampled_from([1.0, -1.0]), st.floats(-math.pi, math.pi))
def test_quarter_arc_turns_by_a_right_angle_and_keeps_unit_speed(radius, sign, yaw0):
    path = Path(10.0, -4.0, yaw0, ((7.0, 0.0), (math.pi / 2 * radius, sign / radius)))
    end = path.pose(path.length)
    assert math.remainder(end[2] - yaw0 - sign * math.pi / 2, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
    s = np.linspace(-3.0, path.length + 5.0, 400)
    xy = path.pose(s)[:, :2]
    step = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    assert np.all(step <= np.diff(s) + 1e-9)  # chords never longer than the arc
    assert np.all(step >= np.diff(s) * np.cos(np.diff(s) / (2 * radius)) - 1e-9)
    # the path is continuous across segment boundaries
    for b in (7.0, path.length):
        np.testing.assert_allclose(path.pose(b - 1e-9)[:2], path.pose(b + 1e-9)[:2], atol=1e-6)
    assert float(path.curvature(7.0 + 0.5)) == sign / radius
    assert float(path.curvature(path.length + 1.0)) == 0.0


def test_scenarios_cycle_through_the_kinds_and_say_what_happens():
    scns = build_scenarios(10, seed=1, keyframes=40)
    assert [s.kind for s in scns] == list(KINDS) + list(KINDS[:2])
    assert scns[5].name == "synth-0005-left-turn"
    assert all(s.name.startswith(f"synth-{i:04d}-") for i, s in enumerate(scns))
    assert {
        "cruise",
        "accelerate",
        "brake-red-light",
        "wait-then-go-green",
        "stopped-behind-lead-green",
        "left-turn",
        "right-turn",
        "straight-after-turn",
    } == set(KINDS)


@pytest.mark.parametrize("seed", [0, 1, 7])
def test_scenario_semantics(seed):
    scns = {s.kind: s for s in build_scenarios(8, seed=seed, keyframes=40)}
    end = scns["cruise"].duration
    t = np.linspace(0.0, end, 200)

    cruise = scns["cruise"]
    assert np.ptp(cruise.speed(t)) == 0.0 and np.all(cruise.curvature(t) == 0.0)
    assert np.all(np.diff(cruise.speed(t)) == 0)

    acc = scns["accelerate"]
    assert np.all(np.diff(acc.speed(t)) >= 0) and acc.speed(end) > acc.speed(0.0) + 5

    brake = scns["brake-red-light"]
    assert brake.speed(0.0) > 7 and brake.speed(end) == 0.0
    assert brake.light_colour(end) == "red"
    stop_s = float(brake.profile.s(end))
    assert stop_s < brake.light.stop_s  # stops before the stop line

    wait = scns["wait-then-go-green"]
    t_green = wait.params["t_green"]
    assert wait.light_colour(t_green - 0.1) == "red" and wait.light_colour(t_green + 0.1) == "green"
    assert np.all(wait.speed(t[t < t_green]) == 0.0) and wait.speed(end) > 3

    lead = scns["stopped-behind-lead-green"]
    t_green = lead.params["t_green"]
    assert lead.speed(t_green) == 0.0 and lead.lead_speed(t_green) == 0.0
    assert lead.lead_speed(t_green + 1.5) > 0.0 and lead.speed(t_green + 1.5) == 0.0  # lead moves first
    gap = lead.lead.gap + lead.lead.profile.s(t) - lead.profile.s(t)
    assert np.all(gap >= lead.lead.gap - 1e-9)  # never closes in on it

    assert scns["left-turn"].curvature(t).max() > 0 and scns["left-turn"].curvature(t).min() == 0
    assert scns["right-turn"].curvature(t).min() < 0 and scns["right-turn"].curvature(t).max() == 0
    after = scns["straight-after-turn"]
    # the turn is over within the first ~6 s; then straight until the end
    late = t[t > 6.5]
    assert np.all(after.curvature(late) == 0) and np.any(after.curvature(t[t < 3.5]) != 0)


# --------------------------------------------------------------------------- the written dataset


def test_unmodified_devkit_loads_all_tables(small_root):
    # the devkit is the nuscenes extra, which the README's main install and CI include
    NuScenes = pytest.importorskip(
        "nuscenes.nuscenes", reason="nuscenes-devkit (lightemma[nuscenes]) is not installed"
    ).NuScenes

    nusc = NuScenes(version=VERSION, dataroot=str(small_root), verbose=False)
    for t in TABLES:
        assert os.path.isfile(small_root / VERSION / f"{t}.json")
    assert len(nusc.scene) == SMALL["scenes"]
    assert len(nusc.sample) == SMALL["scenes"] * SMALL["keyframes"]
    # keyframes at 2 Hz plus 5 sweeps between consecutive keyframes (12 Hz)
    assert len(nusc.sample_data) == SMALL["scenes"] * (SMALL["keyframes"] + 5 * (SMALL["keyframes"] - 1))
    for scene in nusc.scene:
        sample = nusc.get("sample", scene["first_sample_token"])
        assert set(sample["data"]) == {"CAM_FRONT"}
        sd = nusc.get("sample_data", sample["data"]["CAM_FRONT"])
        assert sd["is_key_frame"] and sd["channel"] == "CAM_FRONT" and sd["sensor_modality"] == "camera"
        path = nusc.get_sample_data_path(sd["token"])
        with Image.open(path) as img:
            assert img.size == (320, 180) and img.format == "JPEG"
        sweep = nusc.get("sample_data", sd["next"])
        assert not sweep["is_key_frame"] and sweep["filename"].startswith("sweeps/CAM_FRONT/")
        assert os.path.isfile(os.path.join(small_root, sweep["filename"]))
        assert scene["nbr_samples"] == SMALL["keyframes"]
    log = nusc.get("log", nusc.scene[0]["log_token"])
    assert log["map_token"] in {m["token"] for m in nusc.map}
    # the lead, parked and oncoming vehicles are annotated as cars, the pedestrians as adults
    anns = [a for a in nusc.sample_annotation]
    names = {a["category_name"] for a in anns}
    assert anns and "vehicle.car" in names and names <= {"vehicle.car", "human.pedestrian.adult"}


def test_keyframe_timing_is_real_looking(small_root):
    samples = read_table(small_root, VERSION, "sample")
    by_scene = {}
    for s in samples:
        by_scene.setdefault(s["scene_token"], []).append(s["timestamp"])
    for ts in by_scene.values():
        dt = np.diff(sorted(ts)) * 1e-6
        assert np.all(np.abs(dt - 0.5) <= 0.04 + 1e-6)
        assert np.ptp(dt) > 0  # jittered, not exactly 0.5 s


def test_ego_poses_of_every_sample_data_follow_the_closed_form(small_root):
    scns = {s.name: s for s in build_scenarios(SMALL["scenes"], seed=SMALL["seed"], keyframes=SMALL["keyframes"])}
    scenes = read_table(small_root, VERSION, "scene")
    samples = {s["token"]: s for s in read_table(small_root, VERSION, "sample")}
    poses = {p["token"]: p for p in read_table(small_root, VERSION, "ego_pose")}
    scene_of_sample = {tok: s["scene_token"] for tok, s in samples.items()}
    name_of_scene = {s["token"]: s["name"] for s in scenes}
    n = 0
    for sd in read_table(small_root, VERSION, "sample_data"):
        scn = scns[name_of_scene[scene_of_sample[sd["sample_token"]]]]
        pose = poses[sd["ego_pose_token"]]
        assert pose["timestamp"] == sd["timestamp"]
        x, y, yaw = scn.pose(scn.seconds(sd["timestamp"]))
        assert pose["translation"][:2] == pytest.approx([x, y], abs=1e-9)
        w, _, _, z = pose["rotation"]
        assert math.remainder(2 * math.atan2(z, w) - yaw, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
        n += 1
    assert n == SMALL["scenes"] * (SMALL["keyframes"] * 6 - 5)


def test_same_seed_same_bytes_other_seed_other_data(tmp_path):
    kw = dict(scenes=2, keyframes=15, image_size=(160, 90), sweeps=False)
    a = _digest(write_dataset(tmp_path / "a", seed=5, **kw))
    b = _digest(write_dataset(tmp_path / "b", seed=5, **kw))
    c = _digest(write_dataset(tmp_path / "c", seed=6, **kw))
    assert a == b
    assert a.keys() != c.keys() or a != c
    assert a[f"{VERSION}/ego_pose.json"] != c[f"{VERSION}/ego_pose.json"]
    assert not any(".tmp-" in k for k in a)  # no temporary files left behind


def test_refuses_to_overwrite_unless_asked(tmp_path):
    write_dataset(tmp_path / "d", scenes=1, keyframes=15, images=False)
    with pytest.raises(UserError, match="already exists"):
        write_dataset(tmp_path / "d", scenes=1, keyframes=15, images=False)
    write_dataset(tmp_path / "d", scenes=2, keyframes=15, images=False, overwrite=True)
    assert len(read_table(tmp_path / "d", VERSION, "scene")) == 2


def _shared_digest(root) -> dict[str, str]:
    """sha256 of every file outside the version folders (maps, expansion, can_bus, images)."""
    return {k: v for k, v in _digest(root).items() if not k.startswith("v1.0-") and k != "lightemma-synth.json"}


def test_another_dataset_never_overwrites_the_shared_files_of_a_root(tmp_path, capsys):
    """The new-user repro: a second synth of another seed under a new --version into the same root rewrote
    maps, expansion, CAN bus and images of the first (its run's off-road went from 0 % to 100 %); now refused
    in one line naming the file, before anything is written, with or without --force."""
    d3 = tmp_path / "d3"
    small = ["--scenes", "3", "--no-sweeps", "--keyframes", "15", "--image-size", "160x90"]
    assert main(["synth", str(d3), *small]) == 0
    capsys.readouterr()
    before = _digest(d3)
    shared_before = _shared_digest(d3)
    assert any(k.startswith("maps/expansion/") for k in shared_before)
    assert any(k.startswith("can_bus/") for k in shared_before)
    assert any(k.startswith("samples/") for k in shared_before)
    for force in ([], ["--force"]):
        rc = main(["synth", str(d3), "--version", "v1.0-other", "--seed", "7", *small, *force])
        err = capsys.readouterr().err.strip()
        assert rc == 2 and "\n" not in err
        assert "already exists with other contents" in err and "another dataset" in err and str(d3) in err
        assert _digest(d3) == before  # nothing written, not even the other version's folder
    # --force on the same version with another seed may not rewrite the shared files either
    with pytest.raises(UserError, match=r"(maps|can_bus|samples)/.* already exists with other contents"):
        write_dataset(d3, scenes=3, seed=7, keyframes=15, sweeps=False, image_size=(160, 90), overwrite=True)
    assert _digest(d3) == before
    # a real-looking map expansion that the synthetic one would replace: refused, kept byte for byte
    real = tmp_path / "real"
    (real / "maps" / "expansion").mkdir(parents=True)
    for loc in ("boston-seaport", "singapore-onenorth"):
        (real / "maps" / "expansion" / f"{loc}.json").write_text('{"version": "1.3"}')
    with pytest.raises(UserError, match=r"expansion/.*\.json already exists with other contents"):
        write_dataset(real, scenes=3, keyframes=15, images=False, version="v1.0-new")
    assert sorted(p.name for p in real.rglob("*")) == [
        "boston-seaport.json",
        "expansion",
        "maps",
        "singapore-onenorth.json",
    ]
    # the same dataset under another version keeps identical shared files and adds its own folder
    write_dataset(d3, scenes=3, seed=0, keyframes=15, sweeps=False, image_size=(160, 90), version="v1.0-same")
    assert _shared_digest(d3) == shared_before and (d3 / "v1.0-same" / "scene.json").is_file()
    assert {k: v for k, v in _digest(d3).items() if k.startswith(VERSION + "/")} == {
        k: v for k, v in before.items() if k.startswith(VERSION + "/")
    }


def test_tables_only_mode_writes_no_images(tmp_path):
    root = write_dataset(tmp_path / "t", scenes=2, keyframes=16, images=False)
    assert not (root / "samples").exists() and not (root / "sweeps").exists()
    assert (root / "maps").is_dir() and len(os.listdir(root / "maps")) >= 1
    info = json.loads((root / "lightemma-synth.json").read_text())
    assert [s["kind"] for s in info["scenes"]] == ["cruise", "accelerate"] and info["images"] is False


def test_calibration_is_real_looking_and_scaled_to_the_image(small_root):
    (cal,) = read_table(small_root, VERSION, "calibrated_sensor")
    k = np.array(cal["camera_intrinsic"])
    assert k[0, 0] == pytest.approx(1266.417203046554 * 320 / 1600)
    assert 0.45 * 320 < k[0, 2] < 0.55 * 320 and 0.45 * 180 < k[1, 2] < 0.6 * 180
    assert 1.0 < cal["translation"][0] < 2.5 and 1.2 < cal["translation"][2] < 2.0  # on the roof, at the front
    assert np.linalg.norm(cal["rotation"]) == pytest.approx(1.0)


# --------------------------------------------------------------------------- images a model can read


def _share(img: Image.Image, rgb, tol=60) -> float:
    a = np.asarray(img.convert("RGB")).astype(int)
    return float(np.mean(np.abs(a - np.array(rgb)).sum(axis=-1) < tol))


def test_traffic_light_colour_is_visible_and_changes_at_green():
    wait = next(s for s in build_scenarios(8, seed=2, keyframes=40) if s.kind == "wait-then-go-green")
    cam = Camera(400, 225)
    t_green = wait.params["t_green"]
    red = render_frame(wait, t_green - 1.0, cam)
    green = render_frame(wait, t_green + 0.2, cam)
    assert _share(red, LAMP_ON["red"]) > 0.0005 and _share(red, LAMP_ON["green"]) == 0.0
    assert _share(green, LAMP_ON["green"]) > 0.0005 and _share(green, LAMP_ON["red"]) == 0.0


def test_road_and_lead_vehicle_are_drawn():
    scn = next(s for s in build_scenarios(8, seed=2, keyframes=40) if s.kind == "stopped-behind-lead-green")
    img = render_frame(scn, 1.0, Camera(400, 225))
    assert _share(img, (88, 88, 92), tol=20) > 0.1  # asphalt
    assert _share(img, scn.lead.color, tol=40) > 0.01  # the car ahead, a few metres away
    assert _share(img, (255, 30, 30), tol=40) > 0.0005  # its brake lights are on while it waits


def test_written_jpeg_shows_the_red_light(small_root):
    scns = build_scenarios(SMALL["scenes"], seed=SMALL["seed"], keyframes=SMALL["keyframes"])
    brake = next(s for s in scns if s.kind == "brake-red-light")
    scene = next(s for s in read_table(small_root, VERSION, "scene") if s["name"] == brake.name)
    samples = {s["token"]: s for s in read_table(small_root, VERSION, "sample")}
    sds = {sd["sample_token"]: sd for sd in read_table(small_root, VERSION, "sample_data") if sd["is_key_frame"]}
    tok = scene["last_sample_token"]
    assert brake.light_colour(brake.seconds(samples[tok]["timestamp"])) == "red"
    with Image.open(small_root / sds[tok]["filename"]) as img:
        assert _share(img, LAMP_ON["red"], tol=90) > 0.0003
        assert _share(img, LAMP_ON["green"], tol=60) == 0.0


# --------------------------------------------------------------------------- CLI


def test_cli_synth_writes_a_loadable_dataset(tmp_path, capsys):
    out = tmp_path / "cli"
    rc = main(
        [
            "synth",
            str(out),
            "--scenes",
            "2",
            "--seed",
            "4",
            "--keyframes",
            "16",
            "--image-size",
            "160x90",
            "--no-sweeps",
        ]
    )
    assert rc == 0
    out_text = capsys.readouterr().out
    assert f"lightemma run --model baseline:cv --dataroot {out} --version {VERSION}\n" in out_text
    assert "4 frames in the reference window" in out_text
    names = sorted(s["name"] for s in read_table(out, VERSION, "scene"))
    assert names == ["synth-0000-cruise", "synth-0001-accelerate"]
    from lightemma.nuscenes import load_frames

    assert len(load_frames(out, VERSION, split="all")) == 2 * 2
    rc = main(["synth", str(out), "--scenes", "2"])
    assert rc == 2 and "already exists" in capsys.readouterr().err
    # a second version of the same dataset (same seed, scenes, keyframes) shares the files outside its folder
    rc = main(
        [
            "synth",
            str(out),
            "--scenes",
            "2",
            "--seed",
            "4",
            "--keyframes",
            "16",
            "--version",
            "v1.0-test",
            "--no-images",
        ]
    )
    assert rc == 0 and len(read_table(out, "v1.0-test", "scene")) == 2
    # another dataset (other seed and keyframes) would rewrite them: refused, nothing written, --force or not
    for force in ([], ["--force"]):
        rc = main(
            ["synth", str(out), "--scenes", "1", "--keyframes", "15", "--version", "v1.0-other", "--no-images", *force]
        )
        err = capsys.readouterr().err
        assert rc == 2 and "already exists with other contents" in err and "another dataset" in err
        assert not (out / "v1.0-other").exists()


def test_cli_rejects_bad_arguments(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["synth", str(tmp_path / "x"), "--scenes", "0"])
    with pytest.raises(SystemExit):
        main(["synth", str(tmp_path / "x"), "--image-size", "big"])
    assert "800x450" in capsys.readouterr().err


def test_cli_synth_says_when_its_dataset_cannot_be_run(tmp_path, capsys):
    """Too few keyframes for a window, or no images: no hint to run a baseline that would find no frame."""
    assert (
        main(
            [
                "synth",
                str(tmp_path / "short"),
                "--scenes",
                "1",
                "--keyframes",
                "14",
                "--no-sweeps",
                "--image-size",
                "32x18",
            ]
        )
        == 0
    )
    out, err = capsys.readouterr()
    assert "0 frames in the reference window" in out
    assert (
        err.startswith("lightemma synth: warning: a scene needs at least 15 keyframes")
        and "only --window full has frames (1)" in err
    )
    assert main(["synth", str(tmp_path / "shorter"), "--scenes", "1", "--keyframes", "5", "--no-images"]) == 0
    out, err = capsys.readouterr()
    assert "there is no frame to run" in err
    assert main(["synth", str(tmp_path / "tables"), "--scenes", "1", "--keyframes", "15", "--no-images"]) == 0
    out, err = capsys.readouterr()
    assert "run a baseline" not in out and "on_missing_image='keep'" in out and err == ""
