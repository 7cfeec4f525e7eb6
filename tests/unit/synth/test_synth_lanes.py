"""The synthetic map expansion's lanes, lane connectors, road segments and car parks, the CAN-bus-like history and
the plans with known faults (lightemma.synth.maps, lightemma.synth.can_pose, lightemma.nuscenes.can_bus,
lightemma.synth.planning_cases)."""

from __future__ import annotations

import dataclasses
import json
import math
import os

import numpy as np
import pytest
from scipy.spatial import cKDTree

import lightemma
from lightemma.errors import DatasetError
from lightemma.nuscenes import can_bus, load_frames
from lightemma.planning import simulation as sim
from lightemma.planning.scores import read_planning_map, route_lanes, subscores
from lightemma.synth import build_scenarios, write_dataset
from lightemma.synth import can_pose as synth_can
from lightemma.synth import maps as synth_maps
from lightemma.synth import planning_cases as pc
from lightemma.synth.dataset import token
from lightemma.synth.situations import LANE_WIDTH, build_scenario


def _devkit():
    """The devkit's map API and arcline utilities, and shapely (lightemma[nuscenes]); the test skips without them."""
    map_api = pytest.importorskip("nuscenes.map_expansion.map_api", reason="nuscenes-devkit is not installed")
    arcline = pytest.importorskip("nuscenes.map_expansion.arcline_path_utils")
    return map_api, arcline, pytest.importorskip("shapely.geometry"), pytest.importorskip("shapely.ops").unary_union


SCENES, KEYFRAMES = 8, 20


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    """Every scenario kind once, tables and maps only."""
    return write_dataset(
        tmp_path_factory.mktemp("lanes"), scenes=SCENES, keyframes=KEYFRAMES, images=False, sweeps=False
    )


@pytest.fixture(scope="module")
def scenarios():
    return build_scenarios(SCENES, keyframes=KEYFRAMES)


def _doc(root, location):
    with open(root / "maps" / "expansion" / f"{location}.json", encoding="utf-8") as f:
        return json.load(f)


def _polygon(doc, ptok):
    shapely = _devkit()[2]
    nodes = {n["token"]: (n["x"], n["y"]) for n in doc["node"]}
    poly = next(p for p in doc["polygon"] if p["token"] == ptok)
    return shapely.Polygon([nodes[t] for t in poly["exterior_node_tokens"]])


def test_the_devkit_loads_the_layers_and_discretises_onto_the_centrelines(root, scenarios):
    map_api, arcline, shapely, _ = _devkit()
    for location in sorted({s.location for s in scenarios}):
        nmap = map_api.NuScenesMap(str(root), location)
        here = [s for s in scenarios if s.location == location]
        doc = _doc(root, location)
        lanes = nmap.lane + nmap.lane_connector
        assert len(lanes) == sum(2 * len(synth_maps.road_pieces(s)) for s in here)
        assert set(nmap.arcline_path_3) == set(nmap.connectivity) == {r["token"] for r in lanes}
        for scn in here:
            for i, piece in enumerate(synth_maps.road_pieces(scn)):
                for oncoming in (False, True):
                    t = token(0, "lane", location, scn.index, f"{'oncoming' if oncoming else 'ego'}-{i}")
                    layer = "lane_connector" if piece.curved else "lane"
                    assert any(r["token"] == t for r in getattr(nmap, layer))
                    # the devkit's discretisation lies on the exact centreline, in the driving direction
                    got = np.array(arcline.discretize_lane(nmap.get_arcline_path(t), 0.5))
                    exact = synth_maps.lane_centreline(scn, piece, oncoming, step=0.01)
                    dist, nearest = cKDTree(exact[:, :2]).query(got[:, :2])
                    assert dist.max() < 0.01, (scn.name, t)
                    dyaw = (got[:, 2] - exact[nearest, 2] + math.pi) % (2 * math.pi) - math.pi
                    assert np.abs(dyaw).max() < 1e-3
                    assert np.all(np.diff(nearest) >= 0)  # from the start to the end
                    np.testing.assert_allclose(got[[0, -1], :2], exact[[0, -1], :2], atol=1e-6)
                    length = arcline.length_of_lane(nmap.get_arcline_path(t))
                    assert abs(length - np.hypot(*np.diff(exact[:, :2], axis=0).T).sum()) < 1e-3
                    # the centreline lies inside the lane polygon, LANE_WIDTH / 2 from its long edges
                    rec = next(r for r in lanes if r["token"] == t)
                    poly = _polygon(doc, rec["polygon_token"])
                    mid = shapely.Point(*exact[len(exact) // 2, :2])
                    assert poly.contains(mid) and abs(poly.exterior.distance(mid) - LANE_WIDTH / 2) < 0.02


def test_lanes_road_segments_and_car_parks_lie_in_the_unchanged_drivable_area(root, scenarios):
    unary_union = _devkit()[3]
    for location in sorted({s.location for s in scenarios}):
        doc = _doc(root, location)
        for scn in (s for s in scenarios if s.location == location):
            area_tok = token(0, "drivable_area", location, scn.index)
            area = next(a for a in doc["drivable_area"] if a["token"] == area_tok)
            drivable = _polygon(doc, area["polygon_tokens"][0])
            # the drivable area is the road outline it always was (the safety numbers depend on it)
            outline = synth_maps.road_outline(scn, synth_maps.ROAD_RIGHT, synth_maps.ROAD_LEFT)
            np.testing.assert_array_equal(np.asarray(drivable.exterior.coords)[:-1], outline)
            segments = [r for r in doc["road_segment"] if r["drivable_area_token"] == area_tok]
            pieces = synth_maps.road_pieces(scn)
            assert [r["is_intersection"] for r in segments] == [p.curved for p in pieces]
            turns = scn.kind in ("left-turn", "right-turn", "straight-after-turn")
            assert any(r["is_intersection"] for r in segments) == turns
            carpark = next(
                r for r in doc["carpark_area"] if r["token"] == token(0, "carpark_area", location, scn.index)
            )
            shapes = [_polygon(doc, r["polygon_token"]) for r in segments] + [_polygon(doc, carpark["polygon_token"])]
            for i in range(len(pieces)):
                for d in ("ego", "oncoming"):
                    t = token(0, "lane", location, scn.index, f"{d}-{i}")
                    rec = next(r for r in doc["lane"] + doc["lane_connector"] if r["token"] == t)
                    shapes.append(_polygon(doc, rec["polygon_token"]))
            for shape in shapes:  # within 2 cm: both are 1 m chords of the exact curves (sagitta ≤ 1 / (8 · 7.25 m))
                assert shape.is_valid and drivable.buffer(0.02).contains(shape)
            # road segments and the car park tile the drivable area
            union = unary_union(shapes[: len(segments) + 1])
            assert abs(union.area - drivable.area) < 1e-3 * drivable.area
            # each direction is one chain of lanes; the oncoming one runs the other way
            ego = [token(0, "lane", location, scn.index, f"ego-{i}") for i in range(len(pieces))]
            onc = [token(0, "lane", location, scn.index, f"oncoming-{i}") for i in range(len(pieces))][::-1]
            for chain in (ego, onc):
                for a, b in zip(chain, chain[1:]):
                    assert doc["connectivity"][a]["outgoing"] == [b] and doc["connectivity"][b]["incoming"] == [a]
            first = doc["arcline_path_3"][ego[0]][0]
            start = scn.path.pose(pieces[0].s_from)
            np.testing.assert_allclose(first["start_pose"][:2], start[:2], atol=1e-9)
            assert math.isclose(math.cos(first["start_pose"][2] - start[2]), 1.0, abs_tol=1e-9)
            back = doc["arcline_path_3"][onc[-1]][0]["end_pose"]
            assert math.isclose(math.cos(back[2] - start[2]), -1.0, abs_tol=1e-9)


def test_read_planning_map_reads_the_synthetic_layers(root, scenarios):
    for location in sorted({s.location for s in scenarios}):
        doc = _doc(root, location)
        pm = read_planning_map(root / "maps" / "expansion" / f"{location}.json")
        assert pm.lanes is not None and len(pm.lanes.polygons) - 1 == len(doc["lane"]) + len(doc["lane_connector"])
        crossings = [r for r in doc["road_segment"] if r["is_intersection"]]
        if crossings:
            assert pm.intersections is not None and len(pm.intersections.polygons) - 1 == len(crossings)
        else:
            assert pm.intersections is None
        assert pm.drivable is not None and len(pm.drivable.polygons) - 1 == len(doc["drivable_area"])


def test_can_bus_round_trip(root, scenarios):
    frames = load_frames(root, "v1.0-mini", on_missing_image="keep")
    got = can_bus.frame_can_readings(frames)
    assert got is not None and got.available.all()
    by_name = {s.name: s for s in scenarios}
    for i in range(len(frames)):
        scn = by_name[frames.scene_names[i]]
        assert abs(got.utime[i] - frames.timestamps[i]) <= synth_can.POSE_PERIOD_US // 2
        np.testing.assert_allclose(got.values[i], synth_can.kinematics(scn, [got.utime[i]])[0], rtol=0, atol=1e-12)
    # the messages are the devkit's format, 50 Hz, covering the scene
    scn = scenarios[5]
    with open(root / "can_bus" / f"{scn.name}_pose.json", encoding="utf-8") as f:
        msgs = json.load(f)
    assert set(msgs[0]) == {"utime", "pos", "orientation", "vel", "accel", "rotation_rate"}
    assert np.all(np.diff([m["utime"] for m in msgs]) == 20_000)
    assert msgs[0]["utime"] == scn.keyframe_times_us[0] and msgs[-1]["utime"] >= scn.keyframe_times_us[-1]
    turning = [m for m in msgs if m["rotation_rate"][2] != 0.0]
    assert turning and all(math.isclose(m["accel"][1], m["vel"][0] * m["rotation_rate"][2]) for m in turning)
    # the readings feed the initial state: speed, accelerations, yaw rate are the CAN bus's
    state = sim.initial_state(frames.history_positions, can=got.values)
    assert all(r is None for r in state.reasons)
    np.testing.assert_array_equal(state.states[:, [3, 5, 6, 9]], got.values)


def test_can_bus_absent_missing_and_malformed(root, tmp_path, monkeypatch):
    assert can_bus.can_readings(tmp_path, ["synth-0000-cruise"], [1]) is None
    folder = tmp_path / "can_bus"
    folder.mkdir()
    scene = "synth-0000-cruise"
    src = root / "can_bus" / f"{scene}_pose.json"
    msgs = json.loads(src.read_text())
    t_mid = msgs[10]["utime"]
    got = can_bus.can_readings(tmp_path, [scene], [t_mid])
    assert got is not None and np.isnan(got.values).all() and "no CAN bus pose file" in got.reasons[0]
    path = folder / f"{scene}_pose.json"
    path.write_text(json.dumps(msgs))
    # a keyframe far from every message is not available, with the distance
    got = can_bus.can_readings(tmp_path, [scene, scene], [t_mid + 9, msgs[-1]["utime"] + 60_000])
    assert got.reasons[0] is None and got.utime[0] == t_mid
    assert np.isnan(got.values[1]).all() and "60000 µs away" in got.reasons[1]
    for bad, why in (
        ("{", "not valid JSON"),
        ("[]", "not a non-empty list"),
        (json.dumps([{**msgs[0], "vel": [1.0, "x", 0.0]}]), "message 0 has vel"),
        (json.dumps([msgs[1], msgs[0]]), "message 1 has utime"),
        (json.dumps([{**msgs[0], "utime": True}]), "message 0 has utime"),
        (json.dumps([{**msgs[0], "accel": [1.0, 2.0]}]), "message 0 has accel"),
    ):
        path.write_text(bad)
        with pytest.raises(DatasetError, match=f"CAN bus file {path}.*{why}"):
            can_bus.can_readings(tmp_path, [scene], [t_mid])
    path.write_text(json.dumps(msgs))
    monkeypatch.setattr(can_bus, "MAX_CAN_FILE_BYTES", 100)
    with pytest.raises(DatasetError, match="above the limit of 100"):
        can_bus.can_readings(tmp_path, [scene], [t_mid])
    monkeypatch.undo()
    path.unlink()
    os.mkfifo(path)  # a FIFO in place of the file never blocks the reader
    with pytest.raises(DatasetError, match="not a regular file"):
        can_bus.can_readings(tmp_path, [scene], [t_mid])
    with pytest.raises(DatasetError, match="cannot name a CAN bus file"):
        can_bus.can_readings(tmp_path, ["../x"], [t_mid])


# -- plans with known faults ---------------------------------------------------------------------------------------


def _ego(scn, t0, times):
    p0 = scn.pose(t0)
    pts = scn.pose(times)
    c, s = math.cos(p0[2]), math.sin(p0[2])
    d = pts[:, :2] - p0[:2]
    return np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], pts[:, 2] - p0[2]], -1)


def _global(states, p0):
    out = states.copy()
    c, s = math.cos(p0[2]), math.sin(p0[2])
    out[..., 0] = p0[0] + c * states[..., 0] - s * states[..., 1]
    out[..., 1] = p0[1] + s * states[..., 0] + c * states[..., 1]
    out[..., 2] = states[..., 2] + p0[2]
    return out


def _score(scn, case, tmp_path):
    """Re-simulate the case and the scene's ground truth from the frame's history; score both on the synthetic map."""
    t0 = float(scn.seconds(scn.keyframe_times_us[case.keyframe]))
    init = sim.initial_state(_ego(scn, t0, t0 + np.arange(-7, 1) * 0.5)[None, :, :2]).states
    plan = lightemma.simulate(case.poses[None], init)
    gt = lightemma.simulate(_ego(scn, t0, t0 + np.arange(1, 7) * 0.5)[None], init)
    p0 = scn.pose(t0)
    # the scene's road beside a left turn's: a map without any intersection makes ddc and lk n/a
    turn = dataclasses.replace(build_scenario(5, keyframes=KEYFRAMES), location=scn.location)
    placed = synth_maps.place_scenarios([scn, turn])
    assert placed[0].path.x0 == pytest.approx(scn.path.x0, abs=1e-9) and placed[1].kind == "left-turn"
    path = tmp_path / f"{scn.name}.json"
    path.write_text(json.dumps(synth_maps.expansion_json(placed, scn.location, lambda *p: token(0, *p))))
    m = read_planning_map(path)
    plan_g, gt_g = _global(plan, p0), _global(gt, p0)
    line = scn.path.pose(np.linspace(scn.profile.s(t0) - 10, scn.profile.s(t0) + 60, 141))[:, :2][None]
    times = t0 + np.arange(31) * 0.1
    boxes = np.full((1, 31, 1, 8), np.nan)
    if case.agents is not None:  # the case's own agent, from the keyframe's ego frame
        a = case.agents
        c, s = math.cos(p0[2]), math.sin(p0[2])
        boxes[0, :, 0] = np.column_stack(
            [
                p0[0] + c * a[:, 0] - s * a[:, 1],
                p0[1] + s * a[:, 0] + c * a[:, 1],
                a[:, 2] + p0[2],
                a[:, 3],
                a[:, 4],
                c * a[:, 5] - s * a[:, 6],
                s * a[:, 5] + c * a[:, 6],
                a[:, 7],
            ]
        )
    elif scn.lead is not None:
        lp, lv = scn.lead_pose(times), scn.lead_speed(times)
        boxes[0, :, 0] = np.column_stack(
            [
                lp,
                np.full(31, scn.lead.length),
                np.full(31, scn.lead.width),
                lv * np.cos(lp[:, 2]),
                lv * np.sin(lp[:, 2]),
                np.zeros(31),
            ]
        )
    kw = dict(map=m, frame_lanes=route_lanes(m.lanes, gt_g), route=line, centreline=line, agents=boxes)
    values, reasons = subscores(np.concatenate([plan_g, gt_g]), [0, 0], n_frames=1, **kw)
    out = {k: v[0] for k, v in values.items()}
    out["c"] = float(lightemma.comfort(plan)[0])
    truth = {k: v[1] for k, v in values.items()}
    truth["c"] = float(lightemma.comfort(gt)[0])
    return out, truth, plan[0]


def _case_scene(name):
    """Scene 0 (cruise) of the first seed whose speed suits the case (swerve needs ≥ 9.5 m/s, follow-too-close
    7 m/s), keyframe 7."""
    need = {"swerve": 9.5, "follow-too-close": 7.0}.get(name, 6.0)
    seed = next(s for s in range(100) if build_scenario(0, seed=s, keyframes=KEYFRAMES).params["speed"] >= need)
    return build_scenarios(1, seed=seed, keyframes=KEYFRAMES)[0], 7


@pytest.mark.parametrize("name", list(pc.CASES))
def test_each_plan_case_breaks_its_subscore_in_the_simulated_states(name, tmp_path):
    fn, kind = pc.CASES[name]
    scn, keyframe = _case_scene(name)
    assert scn.kind == kind
    case = fn(scn, keyframe)
    assert (
        case.poses.shape == (6, 3)
        and 0 < case.break_step <= 30
        or (name == "follow-too-close" and case.break_step == 0)
    )
    got, truth, states = _score(scn, case, tmp_path)
    # the ground truth passes everything this case breaks (but the case's own slow lead is in its way), and nothing
    # leaves the road or collides
    assert case.subscore == "ep" or case.agents is not None or truth[case.subscore] == 1.0
    assert got["dac"] == 1.0 and got["nc"] == 1.0
    if case.subscore == "ep":
        assert got["ep_raw"] < truth["ep_raw"] - 5.0  # short of the scene's progress
        assert abs(case.known["progress"] - truth["ep_raw"] * case.known["progress"] / case.known["gt_progress"]) < 1
        assert abs(got["ep_raw"] - case.known["progress"]) < 2.0
        assert all(got[k] == 1.0 for k in ("ddc", "lk", "ttc", "c"))
        return
    assert got[case.subscore] == 0.0, got
    # where: the simulated states break it at the reference's step or later (the tracker lags), checked by hand
    centre = pc.centres(states[:, :3])
    if name == "wrong-way":
        out = np.abs(centre[:, 1]) > LANE_WIDTH / 2
        travel = np.where(out[1:], np.hypot(*np.diff(centre, axis=0).T), 0.0)
        window = np.array([travel[max(0, t - 10) : t].sum() for t in range(1, 31)])
        assert np.argmax(window >= 6.0) + 1 >= case.break_step
    elif name == "swerve":
        far = np.abs(centre[:, 1]) > 0.5
        runs = np.convolve(far, np.ones(20, dtype=int), "valid")
        assert np.argmax(runs == 20) + 19 >= case.break_step
        assert got["c"] == 1.0 and got["ttc"] == 1.0
    elif name == "follow-too-close":
        assert _navsim_ttc(states, case.agents) == (0.0, 0) and got["ddc"] == got["lk"] == 1.0
    elif name == "hard-brake":
        assert all(got[k] == 1.0 for k in ("ddc", "lk", "ttc"))
        within = sim.comfort_details(states[None]).within[0]  # the longitudinal jerk fails, lateral and yaw hold
        assert not within[3] and within[[1, 4, 5]].all()


def test_plan_cases_refuse_unsuitable_frames():
    scs = {s.kind: s for s in build_scenarios(SCENES, keyframes=KEYFRAMES)}
    with pytest.raises(ValueError, match="road curves"):
        pc.wrong_way(scs["left-turn"], 8)
    with pytest.raises(ValueError, match="constant speed"):
        pc.stop_short(scs["accelerate"], 7)
    with pytest.raises(ValueError, match="no keyframe 99"):
        pc.hard_brake(scs["cruise"], 99)


def _navsim_ttc(states, lead):
    """Hand computation of NAVSIM's TTC for a straight run behind a lead on the same line (the ego frame's x axis):
    (score, first step of an event or -1). ``states`` (31, 11) rear-axle states, ``lead`` (31, 8) boxes.

    Followed: navsim ``pdm_scorer.py`` at commit 0a380a9 (autonomousvision/navsim), ``_calculate_ttc``:
    l. 504 ``future_time_idcs = np.arange(0, int(1.0 * 10), 3)`` → projections of 0, 3, 6, 9 steps;
    l. 512–529 each footprint moved by its state's speed × (cos, sin)(heading) × 0.1 s × the projection;
    l. 536–538 from steps 0 … num_poses − 9 (30 − 9 = 21) against the observation at step + projection;
    l. 549–554 a step whose speed is below ``stopped_speed_threshold`` (0.005 m/s, l. 56) is skipped;
    l. 560–575 an overlapping track ahead (nuPlan's ``is_agent_ahead``: its centre within 30° of the heading seen
    from the unmoved rear axle) sets the score to 0. Here both boxes lie on the x axis (asserted): the footprint's
    front x is x + 1.444 + 4.084 / 2, the lead's rear its centre − length / 2, and the lead's centre is dead ahead."""
    assert np.abs(states[:, [1, 2, 4]]).max() < 1e-9 and np.abs(lead[:, [1, 2]]).max() == 0.0
    front = states[:, 0] + pc.CENTRE_OFFSET + pc.HALF_LENGTH
    rear = lead[:, 0] - lead[:, 3] / 2
    speed = np.hypot(states[:, 3], states[:, 4])
    for s in range(31 - 9):
        if speed[s] < 0.005:
            continue
        for k in (0, 3, 6, 9):
            if front[s] + speed[s] * k * 0.1 > rear[s + k]:
                return 0.0, s
    return 1.0, -1


def test_follow_too_close_breaks_ttc_and_a_safe_follow_does_not():
    """The scorer's ttc against a hand computation of NAVSIM's definition (:func:`_navsim_ttc`) on the re-simulated
    states, with the case's lead and no map (a track dead ahead needs none); nc by hand: navsim ``pdm_scorer.py``
    l. 374–415 (commit 0a380a9) — a moving ego whose footprint meets a moving track ahead collides at its front
    bumper (``get_collision_type``, ``pdm_scorer_utils.py``), at fault, 0 — so nc is 1 exactly when the footprint's
    front stays behind the lead's rear at every one of the 31 states."""
    scn, keyframe = _case_scene("follow-too-close")
    t0 = float(scn.seconds(scn.keyframe_times_us[keyframe]))
    init = sim.initial_state(_ego(scn, t0, t0 + np.arange(-7, 1) * 0.5)[None, :, :2]).states
    cases = [pc.follow_too_close(scn, keyframe), pc.safe_follow(scn, keyframe)]
    states = lightemma.simulate(np.stack([c.poses for c in cases]), np.repeat(init, 2, axis=0))
    boxes = np.stack([c.agents for c in cases])[:, :, None, :]
    values, reasons = subscores(states, [0, 1], n_frames=2, agents=boxes)
    close, safe = cases
    # the too-close case: NAVSIM's TTC fires from the initial state (0.9 s × the closing speed exceeds the gap) …
    assert close.known["closing"] > close.known["gap"] > 0 and close.break_step == 0
    assert _navsim_ttc(states[0], close.agents) == (0.0, 0)
    assert values["ttc"][0] == 0.0 and reasons["ttc"][0] is None
    # … while the hard brake keeps the footprint off the lead: no collision, by hand and by the scorer
    gap = close.agents[:, 0] - close.agents[:, 3] / 2 - (states[0, :, 0] + pc.CENTRE_OFFSET + pc.HALF_LENGTH)
    assert gap.min() > 0.3, gap.min()
    assert values["nc"][0] == 1.0
    # the safe follow: no TTC event by hand or by the scorer, no collision
    assert math.isnan(safe.break_time) and safe.break_step == -1
    assert _navsim_ttc(states[1], safe.agents) == (1.0, -1)
    assert values["ttc"][1] == 1.0 and values["nc"][1] == 1.0
    # the same lead moved 0.5 m nearer than the too-close case's gap … but with the safe plan's gentle brake: the
    # collision the scorer must see (nc 0, at fault) is the hand computation's too
    near = safe.agents.copy()
    near[:, 0] -= safe.known["gap"] - close.known["gap"] + 0.5
    v2, _ = subscores(states[1:], [0], n_frames=1, agents=near[None, :, None, :])
    hand_gap = near[:, 0] - near[:, 3] / 2 - (states[1, :, 0] + pc.CENTRE_OFFSET + pc.HALF_LENGTH)
    assert hand_gap.min() < 0 and v2["nc"][0] == 0.0 and v2["ttc"][0] == 0.0
    with pytest.raises(ValueError, match="needs ≥ 7 m/s"):
        pc.follow_too_close(
            next(s for s in build_scenarios(SCENES, keyframes=KEYFRAMES) if s.kind == "stopped-behind-lead-green"), 0
        )
