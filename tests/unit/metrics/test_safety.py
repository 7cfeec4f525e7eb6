"""Safety metrics: footprints, collisions, drivable area (docs/definitions.md#safety).

Numbers are hand computations; shapely is the oracle for random geometry; the devkit is the oracle
for the map conventions (mask pixels, expansion polygons) where it is installed.
"""

import json
import math
import shutil

import numpy as np
import pytest

from lightemma.errors import DatasetError
from lightemma.evaluation import safety as S
from lightemma.nuscenes import annotations as A
from lightemma.nuscenes import map_files as M

L, W, OFF = S.EGO_LENGTH, S.EGO_WIDTH, S.EGO_OFFSET


def _rect(cx, cy, yaw, length, width):
    from shapely import affinity
    from shapely.geometry import box

    return affinity.rotate(
        box(cx - length / 2, cy - width / 2, cx + length / 2, cy + width / 2), yaw, origin=(cx, cy), use_radians=True
    )


# -- geometry ------------------------------------------------------------------------------------


def test_rotated_rectangle_overlap_matches_shapely_on_random_pairs():
    rng = np.random.default_rng(1)
    n = 4000
    ego = np.column_stack([rng.uniform(-3, 3, n), rng.uniform(-3, 3, n)])  # one step from the origin pose
    poses = np.column_stack([rng.uniform(-50, 50, (n, 2)), rng.uniform(-np.pi, np.pi, n)])
    traj = ego[:, None, :]
    agents = np.column_stack(
        [
            poses[:, :2] + rng.uniform(-6, 6, (n, 2)),
            rng.uniform(-np.pi, np.pi, n),
            rng.uniform(0.3, 6, n),
            rng.uniform(0.3, 3, n),
        ]
    )
    hits = S.box_collisions(traj, poses, agents[:, None, None, :])[:, 0, 0]
    gp = S.ego_poses(traj, poses)[:, 0]
    want = []
    for i in range(n):
        x, y, h = gp[i]
        e = _rect(x + OFF * math.cos(h), y + OFF * math.sin(h), h, L, W)
        a = _rect(*agents[i])
        want.append(e.intersection(a).area > 1e-9)
    assert hits.sum() > 300 and (hits == np.array(want)).all()


def test_footprint_by_hand():
    # keyframe at (10, 20) facing +y; one step 3 m forward in the ego frame → reference (10, 23), heading π/2
    traj, poses = np.array([[[3.0, 0.0]]]), np.array([[10.0, 20.0, math.pi / 2]])
    gp = S.ego_poses(traj, poses)[0, 0]
    np.testing.assert_allclose(gp, [10.0, 23.0, math.pi / 2], atol=1e-12)
    c = S.footprints(traj, poses)[0, 0]
    front, rear = 23.0 + OFF + L / 2, 23.0 + OFF - L / 2  # along +y
    np.testing.assert_allclose(
        c, [[10 - W / 2, front], [10 + W / 2, front], [10 + W / 2, rear], [10 - W / 2, rear]], atol=1e-12
    )


def test_short_steps_keep_the_heading():
    # 2 m diagonal (45°), then 0.6 m sideways (< 1 m: keep 45°), then 3 m straight ahead (0°)
    traj = np.array([[[2.0, 2.0], [2.0, 2.6], [5.0, 2.6]]])
    h = S.ego_poses(traj, np.zeros((1, 3)))[0, :, 2]
    np.testing.assert_allclose(h, [math.pi / 4, math.pi / 4, 0.0], atol=1e-12)
    h = S.ego_poses(traj, np.zeros((1, 3)), S.EgoModel(min_step=0.5))[0, :, 2]
    np.testing.assert_allclose(h, [math.pi / 4, math.pi / 2, 0.0], atol=1e-12)


def test_rotated_footprint_where_an_axis_aligned_box_is_wrong():
    # ego reference at (2, 2) heading 45°; footprint centre 1.443713 m further along the diagonal
    traj, poses = np.array([[[2.0, 2.0]]]), np.zeros((1, 3))
    c = 2.0 + OFF / math.sqrt(2)
    # A: inside the heading-ignoring (axis-aligned) box, but 1.556 − 0.354 = 1.20 m across the rotated one (> 0.925)
    a = [c + 1.6, c - 0.6, 0.0, 0.5, 0.5]
    # B: outside the axis-aligned box (1.2 − 0.25 = 0.95 > 0.925 across), on the rotated box's centre line
    b = [c + 1.2, c + 1.2, 0.0, 0.5, 0.5]
    hits = S.box_collisions(traj, poses, np.array([[[a, b]]]))[0, 0]
    assert hits.tolist() == [False, True]


def test_degenerate_agent_boxes_are_refused():
    traj, poses = np.zeros((1, 1, 2)) + [[[5.0, 0.0]]], np.zeros((1, 3))
    with pytest.raises(ValueError, match="frame 0, step 0, slot 1"):
        S.box_collisions(traj, poses, np.array([[[[9, 0, 0, 4, 2], [9, 0, 0, -1, 2]]]], dtype=float))
    with pytest.raises(DatasetError, match="sample_annotation tok1: degenerate box"):
        A._box({"token": "tok1", "translation": [0, 0, 0], "size": [1.8, 0.0, 1.5], "rotation": [1, 0, 0, 0]})
    with pytest.raises(DatasetError, match="sample_annotation tok2"):
        A._box({"token": "tok2", "translation": [0, float("nan"), 0], "size": [1.8, 4, 1.5], "rotation": [1, 0, 0, 0]})


# -- conventions -----------------------------------------------------------------------------------


def _fs(collide, gt_collide=None):
    n = len(collide)
    col = np.zeros((n, 6, 2), dtype=bool)
    col[:, :, 0] = np.asarray(collide, dtype=bool)
    fs = S.FrameSafety(
        np.ones((n, 6, 5), np.uint8), np.ones(n, bool), [""] * n, ["mask"] * n, col, np.ones(n, bool), [""] * n
    )
    return fs


def test_collision_conventions_by_hand():
    model = _fs(
        [
            [0, 1, 0, 0, 0, 0],  # collides at 1.0 s only
            [0, 0, 0, 0, 0, 1],  # at 3.0 s only
            [0, 0, 0, 1, 0, 0],
        ]
    )  # at 2.0 s, where the ground truth collides too
    gt = _fs([[0, 0, 0, 0, 0, 0], [0, 0, 0, 0, 0, 0], [0, 0, 0, 1, 0, 0]])
    uniad = S.rates(S.safety_values(model, "uniad", gt=gt))
    # at the instants 1/2/3 s (steps 2, 4, 6); frame 3's step 4 masked by the ground truth
    assert (uniad["collision_1s"], uniad["collision_2s"], uniad["collision_3s"]) == pytest.approx((1 / 3, 0.0, 1 / 3))
    assert uniad["collision"] == pytest.approx(2 / 9)
    stp3 = S.rates(S.safety_values(model, "stp3", gt=gt))
    # prefix means: 1 s: (1/2, 0, 0)/3; 2 s: (1/4, 0, 0)/3; 3 s: (1/6, 1/6, 0)/3
    assert (stp3["collision_1s"], stp3["collision_2s"], stp3["collision_3s"]) == pytest.approx((1 / 6, 1 / 12, 1 / 9))
    anyc = S.rates(S.safety_values(model, "any", gt=gt))
    # any collision up to t, not masked: 1 s frame 1; 2 s frames 1, 3; 3 s all three
    assert (anyc["collision_1s"], anyc["collision_2s"], anyc["collision_3s"], anyc["collision"]) == pytest.approx(
        (1 / 3, 2 / 3, 1.0, 1.0)
    )
    assert anyc["collision_vehicle"] == 1.0 and anyc["collision_vru"] == 0.0


def test_offroad_values_and_na():
    fs = _fs([[0] * 6] * 3)
    fs.area[0, 3, 2] = S.OFF  # frame 0: rear-right corner at step 4 (2.0 s)
    fs.area[1, 5, 4] = S.OFF  # frame 1: the reference point at step 6 (corners on)
    fs.area_ok[2] = False  # frame 2: no map
    fs.area_reason[2] = "no drivable area: map mask x.png is missing"
    v = S.rates(S.safety_values(fs, "any"))
    assert v["offroad"] == 0.5 and v["offroad_2s"] == 0.5 and v["offroad_3s"] == 0.0 and v["offroad_centre"] == 0.5
    fs.area_ok[:] = False
    assert S.rates(S.safety_values(fs, "any"))["offroad"] is None
    assert S.na_reason(fs, "area").startswith("no drivable area")


# -- the devkit's map conventions, on synthetic maps ---------------------------------------------------


@pytest.fixture(scope="module")
def safety_root(tmp_path_factory):
    from lightemma.synth import write_dataset

    return write_dataset(tmp_path_factory.mktemp("safety"), scenes=8, keyframes=24, images=False, sweeps=False)


def test_mask_and_expansion_agree_with_the_devkit(safety_root):
    nuscenes = pytest.importorskip("nuscenes")  # noqa: F841
    from nuscenes.map_expansion.map_api import NuScenesMap
    from nuscenes.utils.map_mask import MapMask

    maps = json.loads((safety_root / "v1.0-mini" / "map.json").read_text())
    rng = np.random.default_rng(0)
    for rec in maps:
        ours = M.read_map_mask(safety_root / rec["filename"])
        h, w = ours.mask.shape
        pts = rng.uniform([-3, -3], [w * 0.1 + 3, h * 0.1 + 3], size=(100_000, 2))
        # points exactly half a pixel off: NumPy's half-to-even rounding
        pts[:1000] = np.round(pts[:1000] * 10) / 10 + 0.05
        dev = MapMask(str(safety_root / rec["filename"])).is_on_mask(pts[:, 0], pts[:, 1])
        got = ours.contains(pts)
        assert ((got == S.ON) == dev).all() and 0.01 < dev.mean() < 0.5
        assert (got[(pts[:, 0] < -0.05) | (pts[:, 1] > h * 0.1 + 0.05)] == S.OUTSIDE).all()
    for location in ("boston-seaport", "singapore-onenorth"):
        nmap = NuScenesMap(str(safety_root), location)
        ours = M.read_expansion(safety_root / "maps" / "expansion" / f"{location}.json")
        lo, hi = ours.xy.min(axis=0), ours.xy.max(axis=0)
        pts = rng.uniform(lo - 5, hi + 5, size=(600, 2))
        dev = np.array([bool(nmap.layers_on_point(x, y, ["drivable_area"])["drivable_area"]) for x, y in pts])
        assert ((ours.contains(pts) == S.ON) == dev).all() and dev.any()


# -- end to end on synthetic data -------------------------------------------------------------------


@pytest.fixture(scope="module")
def frames(safety_root):
    from lightemma import load_frames

    return load_frames(safety_root, "v1.0-mini", split="all", on_missing_image="keep")


@pytest.fixture(scope="module")
def data(safety_root):
    return S.load_safety_data(safety_root, "v1.0-mini")


def test_ground_truth_stays_on_its_road_and_collides_with_nothing(frames, data):
    gt = S.frame_safety(frames.gt_positions, frames.sample_tokens, data)
    assert gt.area_ok.all() and gt.coll_ok.all() and set(gt.area_kind) == {"expansion"}
    assert not gt.off_steps.any() and not gt.collide.any()
    # on the straight roads, a trajectory 6 m to the right of the ground truth is off the road at every step
    straight = np.array(["cruise" in n or "accelerate" in n or "brake" in n for n in frames.scene_names])
    off = S.frame_safety(frames.gt_positions + [0.0, -6.0], frames.sample_tokens, data)
    assert straight.sum() >= 30 and off.off_steps[straight].all()


def test_swerve_into_a_parked_car_by_hand(safety_root, frames, data):
    from lightemma.synth import build_scenarios
    from lightemma.synth.maps import scene_agents

    scn = build_scenarios(8, seed=0, keyframes=24)[1]
    assert scn.kind == "accelerate"  # straight road; parked cars at arc 25 m and 60 m, lateral −2.9 m
    parked = scene_agents(scn)[0]
    assert (parked.s0, parked.lateral, parked.length, parked.width) == (25.0, -2.9, 4.5, 1.9)
    rows = [i for i, name in enumerate(frames.scene_names) if name == scn.name]
    secs = scn.seconds(frames.timestamps[rows])
    ahead = parked.s0 - (scn.profile.s(secs) - scn.profile.s(0.0))  # arc of the car ahead of each frame's ego
    pick = next(j for j, r in enumerate(ahead) if 12.0 < r < 26.0)
    i, r = rows[pick], float(ahead[pick])
    # 4 m steps; the first jumps 1.5 m right (heading atan2(−1.5, 4)), the others straight (heading 0)
    traj = np.array([[[4.0 * k, -1.5] for k in range(1, 7)]])
    out = S.frame_safety(traj, [frames.sample_tokens[i]], data)
    # steps 2..6: footprint arc [4k + 1.4437 − 2.042, 4k + 1.4437 + 2.042], lateral [−2.425, −0.575];
    # the car: arc [r − 2.25, r + 2.25], lateral [−3.85, −1.95] → overlap iff |4k + 1.4437 − r| < 4.292
    want = [False] + [abs(4.0 * k + OFF - r) < L / 2 + 2.25 for k in range(2, 7)]
    assert out.collide[0, :, 0].tolist() == want and any(want)
    assert not out.collide[0, :, 1].any()  # no pedestrian in this scene
    # every step has a corner beyond the lane edge (−1.75 m): right edge −0.575 − 1.85 = −2.425 from step 2 on,
    # front-right corner at step 1: −1.5 + 3.4857·sin(−20.56°) − 0.925·cos(20.56°) = −3.59
    assert out.off_steps[0].all()
    # ... while the reference point (−1.5 m) is on the road at every step: the centre-point check misses it
    assert (out.area[0, :, 4] == S.ON).all()
    v = S.rates(S.safety_values(out, "any"))
    assert v["offroad"] == 1.0 and v["offroad_centre"] == 0.0 and v["collision"] == 1.0


def test_na_reasons(safety_root, tmp_path, frames):
    root = tmp_path / "copy"
    shutil.copytree(safety_root, root)
    (root / "v1.0-mini" / "sample_annotation.json").write_text("[]")  # like v1.0-test
    shutil.rmtree(root / "maps" / "expansion")  # base masks only
    first_mask = json.loads((root / "v1.0-mini" / "map.json").read_text())[0]
    (root / first_mask["filename"]).unlink()
    data = S.load_safety_data(root, "v1.0-mini")
    out = S.frame_safety(frames.gt_positions, frames.sample_tokens, data)
    assert not out.coll_ok.any() and set(out.coll_reason) == {"no annotations"}
    assert S.na_reason(out, "collision") == "no annotations"
    assert out.area_ok.any() and not out.area_ok.all() and set(out.area_kind) == {"mask", ""}
    missing = [r for r in out.area_reason if r]
    assert missing and all("is missing" in r for r in missing)
    warnings = S.frame_warnings(out, frames.frame_ids, "GT")
    assert any("no off-road value (n/a)" in w and "is missing" in w for w in warnings)
    # the semantic prior (mask) holds the sidewalks: 3 m right of the lane centre is on it, 6 m is not
    on = out.area_ok
    cruise = on & np.array(["cruise" in n for n in frames.scene_names])  # ≥ 3.5 m per step, straight road
    assert cruise.any()
    # step 2 turns 3 (6) m right, steps 3..6 run parallel to the lane: on the sidewalk (beyond it)
    for shift, off in ((-3.0, False), (-6.0, True)):
        traj = frames.gt_positions + [0.0, shift]
        traj[:, 0, 1] = 0.0
        out_side = S.frame_safety(traj, frames.sample_tokens, data)
        assert (out_side.off_steps[cruise][:, 2:] == off).all()
    # far away from the map: outside the mask image, counted off and reported
    far = S.frame_safety(frames.gt_positions + [0.0, 5000.0], frames.sample_tokens, data)
    assert far.off_steps[on].all() and far.outside_mask[on].all()
    assert any("does not cover" in w for w in S.frame_warnings(far, frames.frame_ids, "M"))
    # an unknown sample: no pose
    none = S.frame_safety(frames.gt_positions[:1], ["f" * 32], data)
    assert not none.area_ok[0] and "no CAM_FRONT ego pose" in none.area_reason[0]
