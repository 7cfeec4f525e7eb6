"""NAVSIM's sub-scores and aggregates (lightemma.planning.scores, rust/planning/scores.rs).

Hand-made scenes with hand-computed outcomes, an independent NumPy/shapely oracle written here from NAVSIM's
``pdm_scorer.py`` / ``pdm_scorer_utils.py`` on random scenes, the aggregates with the human-penalty filter, and bad
input. States are constructed here (NAVSIM's StateIndex layout), not simulated.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from shapely.geometry import LineString, Point, Polygon

from lightemma.planning.scores import (
    AGENT_KIND,
    OBJECT_KIND,
    DrivableMask,
    EgoBox,
    FrameLanes,
    PlanningMap,
    PolygonSet,
    drive_scores,
    interpolate_boxes,
    read_planning_map,
    route_lanes,
    subscores,
)

S = 31  # 3 s at 0.1 s, the initial state first
EGO = EgoBox(length=4.0, width=2.0, rear_axle_to_center=1.0)


def run(x0: float, y: float, speed: float, heading: float = 0.0, steps: int = S) -> np.ndarray:
    """Straight constant-speed states (S, 11) along `heading` from (x0, y)."""
    st = np.zeros((steps, 11))
    t = 0.1 * np.arange(steps)
    st[:, 0] = x0 + speed * t * math.cos(heading)
    st[:, 1] = y + speed * t * math.sin(heading)
    st[:, 2] = heading
    st[:, 3] = speed
    return st


def track(x0: float, y0: float, vx: float, vy: float = 0.0, kind: float = AGENT_KIND, yaw: float = 0.0):
    """A box (S, 8) moving at constant velocity."""
    t = 0.1 * np.arange(S)
    b = np.zeros((S, 8))
    b[:, 0], b[:, 1], b[:, 2] = x0 + vx * t, y0 + vy * t, yaw
    b[:, 3], b[:, 4], b[:, 5], b[:, 6], b[:, 7] = 4.0, 2.0, vx, vy, kind
    return b


def agents_of(*tracks) -> np.ndarray:
    return np.stack(tracks, axis=1)[None]  # (1, S, A, 8)


def rect(x0, y0, x1, y1):
    return [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]


ROAD = PolygonSet.from_rings([[rect(-200, -6, 400, 6)]])
# two lanes: lane 0 (y ∈ [−3.5, 0], on route, the ego drives at y = −1.75) and lane 1 (y ∈ [0, 3.5], oncoming)
LANES = PolygonSet.from_rings([[rect(-200, -3.5, 400, 0)], [rect(-200, 0, 400, 3.5)]])
NO_INTERSECTIONS = PolygonSet.from_rings([])
FULL_MAP = PlanningMap(drivable=ROAD, lanes=LANES, intersections=NO_INTERSECTIONS)
ONE_FRAME_LANES = FrameLanes(np.array([0, 2]), np.array([0, 1]), np.array([1, 0], np.uint8))
ROUTE = np.array([[[-50.0, -1.75], [300.0, -1.75]]])


def scores_of(states, **kw):
    values, reasons = subscores(np.asarray(states)[None] if np.ndim(states) == 2 else states, ego=EGO, **kw)
    return values, reasons


# ---------------------------------------------------------------- hand-made scenes


def test_hitting_a_stopped_car_is_at_fault_a_static_object_counts_half():
    ego = run(0, 0, 10)
    v, r = scores_of(ego, agents=agents_of(track(20, 0, 0)))
    assert v["nc"][0] == 0.0 and r["nc"][0] is None
    v, _ = scores_of(ego, agents=agents_of(track(20, 0, 0, kind=OBJECT_KIND)))
    assert v["nc"][0] == 0.5
    # a moving object is still "stopped" (nuPlan: anything but an agent is), still 0.5
    v, _ = scores_of(ego, agents=agents_of(track(20, 0, 3.0, kind=OBJECT_KIND)))
    assert v["nc"][0] == 0.5
    # nothing in the way
    v, _ = scores_of(ego, agents=agents_of(track(20, 30, 0)))
    assert v["nc"][0] == 1.0 and v["ttc"][0] == 1.0


def test_a_rear_end_by_a_following_car_is_not_at_fault():
    ego = run(0, 0, 5)
    v, _ = scores_of(ego, agents=agents_of(track(-12, 0, 15)))
    assert v["nc"][0] == 1.0
    # hitting a slower car ahead from behind is the ego's (active front)
    v, _ = scores_of(run(0, 0, 15), agents=agents_of(track(12, 0, 5)))
    assert v["nc"][0] == 0.0


def test_a_stopped_ego_is_never_at_fault():
    ego = run(0, 0, 0.0)
    v, _ = scores_of(ego, agents=agents_of(track(-12, 0, 15)))
    assert v["nc"][0] == 1.0
    # and a stopped ego has no TTC events (speed < 0.005 m/s)
    assert v["ttc"][0] == 1.0


def test_a_lateral_collision_is_at_fault_only_across_lanes_or_off_road():
    # a car beside the ego (its centre 0.5 m ahead of the rear axle, 75° off the heading) drifting into it
    ego = run(0, -1.75, 5)
    t = 0.1 * np.arange(S)
    side = track(0.5, 1.75, 5, -1.0)
    side[:, 1] = 1.75 - t * 1.0
    # without lanes or drivable area the class cannot be decided: n/a, not a guess
    v, r = scores_of(ego, agents=agents_of(side))
    assert math.isnan(v["nc"][0]) and "at-fault class" in r["nc"][0]
    # the ego inside its lane: not at fault
    v, _ = scores_of(ego, agents=agents_of(side), map=FULL_MAP, frame_lanes=ONE_FRAME_LANES)
    assert v["nc"][0] == 1.0
    # the ego straddling both lanes: at fault
    straddle = run(0, -0.3, 5)
    side2 = side.copy()
    side2[:, 1] += 1.45
    v, _ = scores_of(straddle, agents=agents_of(side2), map=FULL_MAP, frame_lanes=ONE_FRAME_LANES)
    assert v["nc"][0] == 0.0


def test_ttc_projects_the_ego_at_constant_speed():
    # the ego brakes hard from 10 m/s to a stop at x = 8 (front bumper at 11) before a stopped car whose rear is
    # at 14: no collision, but at 0.3 s its 0.9 s constant-speed projection (front at 3 + 9 + 3 = 15) reaches it
    ego = run(0, 0, 10)
    ego[:, 0] = np.minimum(ego[:, 0], 8.0)
    ego[9:, 3] = 0.0
    v, _ = scores_of(ego, agents=agents_of(track(16, 0, 0)))
    assert v["nc"][0] == 1.0 and v["ttc"][0] == 0.0
    # the car 7 m further: the last projection at 10 m/s (from x = 8: front at 8 + 9 + 3 = 20) stops short
    v, _ = scores_of(ego, agents=agents_of(track(23, 0, 0)))
    assert v["ttc"][0] == 1.0


def test_one_footprint_corner_off_the_road_at_one_step_gives_dac_0():
    ego = run(0, 0, 10)
    v, _ = scores_of(ego, map=PlanningMap(drivable=ROAD))
    assert v["dac"][0] == 1.0
    bent = ego.copy()
    bent[17, 1] = 5.5  # the left corners at y = 6.5 > 6 at step 17 only
    v, _ = scores_of(bent, map=PlanningMap(drivable=ROAD))
    assert v["dac"][0] == 0.0
    # the same with the road as a devkit mask (0.1 m pixels covering x ∈ [-10, 40], y ∈ [-6, 6])
    h, w = 200, 500
    mask = np.zeros((h, w), np.uint8)
    # pixel (px, py) of (x, y) = (round(x / 0.1), round(-y / 0.1 + H)); shift the scene by (+10, +10)
    mask[round(-16 / 0.1 + h) : round(-4 / 0.1 + h) + 1, :] = 255
    shifted = ego.copy()
    shifted[:, 0] += 10
    shifted[:, 1] += 10
    v, _ = scores_of(shifted, map=PlanningMap(drivable=DrivableMask(mask)))
    assert v["dac"][0] == 1.0
    shifted[17, 1] += 5.5
    v, _ = scores_of(shifted, map=PlanningMap(drivable=DrivableMask(mask)))
    assert v["dac"][0] == 0.0


def test_oncoming_travel_of_3_m_in_1_s_gives_ddc_one_half():
    # 3 m/s in the oncoming lane for 1 s: 10 segments of 0.3 m = 3 m
    v, _ = scores_of(run(0, 1.75, 3.0)[:11], map=FULL_MAP, frame_lanes=ONE_FRAME_LANES)
    assert v["ddc"][0] == 0.5
    v, _ = scores_of(run(0, 1.75, 1.5)[:11], map=FULL_MAP, frame_lanes=ONE_FRAME_LANES)  # 1.5 m in 1 s
    assert v["ddc"][0] == 1.0
    v, _ = scores_of(run(0, 1.75, 7.0)[:11], map=FULL_MAP, frame_lanes=ONE_FRAME_LANES)  # 7 m
    assert v["ddc"][0] == 0.0
    # in its own lane: fine at any speed
    v, _ = scores_of(run(0, -1.75, 20.0), map=FULL_MAP, frame_lanes=ONE_FRAME_LANES)
    assert v["ddc"][0] == 1.0
    # inside an intersection oncoming travel does not count
    crossing = PlanningMap(ROAD, LANES, PolygonSet.from_rings([[rect(-10, -10, 100, 10)]]))
    v, _ = scores_of(run(0, 1.75, 7.0)[:11], map=crossing, frame_lanes=ONE_FRAME_LANES)
    assert v["ddc"][0] == 1.0


def test_progress_and_lane_keeping():
    ego = run(0, -1.75, 10)
    v, _ = scores_of(ego, route=ROUTE, centreline=ROUTE, map=FULL_MAP, frame_lanes=ONE_FRAME_LANES)
    assert v["ep_raw"][0] == pytest.approx(30.0)
    assert v["lk"][0] == 1.0
    # 0.6 m off the centreline for 2 s (20 steps) fails, for 1.9 s passes
    off = ego.copy()
    off[5:25, 1] += 0.6
    v, _ = scores_of(off, centreline=ROUTE, map=FULL_MAP, frame_lanes=ONE_FRAME_LANES)
    assert v["lk"][0] == 0.0
    off = ego.copy()
    off[5:24, 1] += 0.6
    v, _ = scores_of(off, centreline=ROUTE, map=FULL_MAP, frame_lanes=ONE_FRAME_LANES)
    assert v["lk"][0] == 1.0
    # backwards along the route: progress clipped at 0
    v, _ = scores_of(run(0, -1.75, -5), route=ROUTE)
    assert v["ep_raw"][0] == 0.0


# ---------------------------------------------------------------- the oracle (NAVSIM's definitions, shapely)


def _corners(state, ego: EgoBox):
    """NAVSIM's state_array_to_coords_array: FL, RL, RR, FR, centre."""
    x, y, h = state[0], state[1], state[2]
    c, s = math.cos(h), math.sin(h)
    cx, cy = x + ego.rear_axle_to_center * c, y + ego.rear_axle_to_center * s
    hl, hw = ego.length / 2, ego.width / 2

    def at(lon, lat):
        return (cx + lon * c - lat * s, cy + lon * s + lat * c)

    return [at(hl, hw), at(-hl, hw), at(-hl, -hw), at(hl, -hw)], (cx, cy)


def _box_poly(b):
    c, s = math.cos(b[2]), math.sin(b[2])
    hl, hw = b[3] / 2, b[4] / 2
    offsets = ((hl, hw), (-hl, hw), (-hl, -hw), (hl, -hw))
    return Polygon([(b[0] + lo * c - la * s, b[1] + lo * s + la * c) for lo, la in offsets])


def _rel_angle(ego_xyh, p):
    v = np.array([p[0] - ego_xyh[0], p[1] - ego_xyh[1]])
    d = np.dot([math.cos(ego_xyh[2]), math.sin(ego_xyh[2])], v / np.linalg.norm(v))
    return float(np.arccos(np.clip(d, -1, 1)))


def oracle(states, agents, drivable, lanes, on_route, crossings, route, centreline, ego: EgoBox):
    """One plan's nc, dac, ddc, ep_raw, ttc, lk, as NAVSIM's pdm_scorer computes them (shapely geometry)."""
    n_s = len(states)
    polys, centres, areas = [], [], []
    for s in range(n_s):
        corners, centre = _corners(states[s], ego)
        polys.append(Polygon(corners))
        centres.append(centre)
        in_lane = np.array([[lane.contains(Point(c)) for c in corners] for lane in lanes])  # (L, 4)
        multiple = (in_lane.sum(axis=1) > 0).sum() > 1 and np.all(in_lane.sum(axis=1) != 4)
        non_drivable = sum(drivable.contains(Point(c)) for c in corners) < 4
        oncoming = not any(lane.contains(Point(centre)) for lane, r in zip(lanes, on_route) if r)
        areas.append((multiple or non_drivable, non_drivable, oncoming))
    in_x = lambda p: crossings.contains(Point(p))  # noqa: E731
    boxes = [[_box_poly(agents[s, a]) for a in range(agents.shape[1])] for s in range(n_s)]
    speed = np.hypot(states[:, 3], states[:, 4])

    # nc
    nc, ignored = 1.0, set()
    for s in range(n_s):
        for a in range(agents.shape[1]):
            b = agents[s, a]
            if a in ignored or not polys[s].intersects(boxes[s][a]):
                continue
            axle = states[s, :3]
            if speed[s] <= 0.05:
                kind = "stopped_ego"
            elif b[7] != AGENT_KIND or math.hypot(b[5], b[6]) <= 0.05:
                kind = "stopped_track"
            elif _rel_angle(axle, b[:2]) > math.radians(150):
                kind = "rear"
            elif LineString([polys[s].exterior.coords[0], polys[s].exterior.coords[3]]).intersects(boxes[s][a]):
                kind = "front"
            else:
                kind = "lateral"
            if kind in ("stopped_track", "front") or (kind == "lateral" and areas[s][0]):
                nc = min(nc, 0.0 if b[7] == AGENT_KIND else 0.5)
            else:
                ignored.add(a)

    dac = 0.0 if any(a[1] for a in areas) else 1.0

    # ddc
    prog = np.zeros(n_s)
    for s in range(1, n_s):
        prog[s] = math.dist(centres[s], centres[s - 1])
        if not areas[s][2] or in_x(centres[s]):
            prog[s] = 0.0
    worst = max(prog[max(0, t - 10) : t + 1].sum() for t in range(n_s))
    ddc = 1.0 if worst < 2 else 0.5 if worst < 6 else 0.0

    line = LineString(route)
    ep = max(0.0, line.project(Point(centres[-1])) - line.project(Point(centres[0])))

    # ttc
    ttc, ignored = 1.0, set()
    for s in range(n_s - 9):
        for k in (0, 3, 6, 9):
            corners, _ = _corners(states[s], ego)
            d = np.array([math.cos(states[s, 2]), math.sin(states[s, 2])]) * speed[s] * k * 0.1
            poly = Polygon(np.array(corners) + d)
            for a in range(agents.shape[1]):
                b = agents[s + k, a]
                if a in ignored or speed[s] < 5e-3 or not poly.intersects(boxes[s + k][a]):
                    continue
                ang = _rel_angle(states[s, :3], b[:2])
                exposed = areas[s][0] or in_x(states[s, :2])
                if ang < math.radians(30) or (exposed and not ang > math.radians(150)):
                    ttc = 0.0
                else:
                    ignored.add(a)

    # lk
    lk, run_ = 1.0, 0
    cl = LineString(centreline)
    for s in range(n_s):
        if in_x(centres[s]):
            continue
        run_ = run_ + 1 if Point(centres[s]).distance(cl) > 0.5 else 0
        if run_ >= 20:
            lk = 0.0
            break
    return {"nc": nc, "dac": dac, "ddc": ddc, "ep_raw": ep, "ttc": ttc, "lk": lk}


def random_scene(rng):
    """A curving ego, agents around its path (agents and objects, some stopped), a road, two lanes, a crossing."""
    v0 = rng.uniform(0, 12)
    acc = rng.uniform(-2, 2)
    yaw_rate = rng.uniform(-0.3, 0.3)
    st = np.zeros((S, 11))
    h, x, y, v = 0.0, 0.0, rng.uniform(-3, 1), v0
    for s in range(S):
        st[s, :5] = x, y, h, v, 0.0
        x += v * 0.1 * math.cos(h)
        y += v * 0.1 * math.sin(h)
        h += yaw_rate * 0.1
        v = max(0.0, v + acc * 0.1)
    tracks = []
    for _ in range(rng.integers(2, 7)):
        s0 = rng.integers(0, S)
        px, py = st[s0, 0] + rng.normal(0, 6), st[s0, 1] + rng.normal(0, 3)
        speed = rng.choice([0.0, rng.uniform(0, 12)])
        yaw = rng.uniform(-math.pi, math.pi)
        kind = rng.choice([AGENT_KIND, OBJECT_KIND], p=[0.8, 0.2])
        b = track(px, py, speed * math.cos(yaw), speed * math.sin(yaw), kind=kind, yaw=yaw)
        b[:, 0] -= speed * math.cos(yaw) * 0.1 * s0
        b[:, 1] -= speed * math.sin(yaw) * 0.1 * s0
        b[:, 3], b[:, 4] = rng.uniform(0.5, 5), rng.uniform(0.5, 2.5)
        tracks.append(b)
    agents = np.stack(tracks, axis=1)
    w = rng.uniform(4, 9)
    road = [rect(-100, -w, 200, w)]
    lanes = [rect(-100, -3.5, 200, 0), rect(-100, 0, 200, 3.5)]
    on_route = [True, bool(rng.integers(0, 2))]
    if rng.random() < 0.5:  # a wide lane over both (a merge): a footprint inside it is in one lane
        x0 = rng.uniform(-10, 30)
        lanes.append(rect(x0, -3.5, x0 + rng.uniform(5, 30), 3.5))
        on_route.append(False)
    cx = rng.uniform(0, 40)
    crossing = rect(cx, -20, cx + rng.uniform(3, 15), 20)
    route = np.array([[-20, -1.75], [30, -1.75], [60, rng.uniform(-10, 10)], [150, rng.uniform(-20, 20)]])
    return st, agents, road, lanes, on_route, crossing, route


@pytest.mark.parametrize("seed", range(3))
def test_kernel_agrees_with_a_shapely_oracle_of_navsims_definitions(seed):
    rng = np.random.default_rng(seed)
    n = 40
    scenes = [random_scene(rng) for _ in range(n)]
    seen = {k: set() for k in ("nc", "dac", "ddc", "ttc", "lk")}
    for st, agents, road, lanes, on_route, crossing, route in scenes:
        want = oracle(
            st,
            agents,
            Polygon(road[0]),
            [Polygon(r) for r in lanes],
            on_route,
            Polygon(crossing),
            route,
            route,
            EGO,
        )
        m = PlanningMap(
            drivable=PolygonSet.from_rings([road]),
            lanes=PolygonSet.from_rings([[r] for r in lanes]),
            intersections=PolygonSet.from_rings([[crossing]]),
        )
        fl = FrameLanes(np.array([0, len(lanes)]), np.arange(len(lanes)), np.array(on_route, np.uint8))
        got, reasons = subscores(
            st[None], agents=agents[None], map=m, frame_lanes=fl, route=route[None], centreline=route[None], ego=EGO
        )
        for k, v in want.items():
            assert reasons[k][0] is None
            assert got[k][0] == pytest.approx(v, abs=1e-9), (k, seed)
            if k in seen:
                seen[k].add(v)
    # the random cases exercise both outcomes of each binary sub-score
    for k in ("nc", "dac", "ttc", "lk"):
        assert {0.0, 1.0} <= seen[k], (k, seen[k])


def test_batches_share_frames_and_equal_one_by_one_calls():
    rng = np.random.default_rng(7)
    scenes = [random_scene(rng) for _ in range(3)]
    plans = np.stack([sc[0] for sc in scenes for _ in range(2)])  # 6 plans, 2 per frame
    plans[1::2, :, 1] += 0.7
    slots = max(sc[1].shape[1] for sc in scenes)
    agents = np.full((3, S, slots, 8), np.nan)
    for f, sc in enumerate(scenes):
        agents[f, :, : sc[1].shape[1]] = sc[1]
    routes = np.full((3, 5, 2), np.nan)
    for f, sc in enumerate(scenes):
        routes[f, :4] = sc[6]
    frame = np.repeat(np.arange(3), 2)
    # a map of many small pieces: each frame's plans test only the pieces near them
    tiles = [[rect(x, y, x + 10, y + 4)] for x in range(-50, 150, 10) for y in range(-12, 12, 4)]
    crossings = [[rect(x, -20, x + 5, 20)] for x in range(-40, 150, 30)]
    m = PlanningMap(PolygonSet.from_rings(tiles), LANES, PolygonSet.from_rings(crossings))
    fl = FrameLanes(np.array([0, 2, 4, 6]), np.array([0, 1, 0, 1, 0, 1]), np.array([1, 0, 1, 1, 1, 0], np.uint8))
    got, _ = subscores(plans, frame, agents=agents, route=routes, centreline=routes, map=m, frame_lanes=fl, ego=EGO)
    for i in range(6):
        f = frame[i]
        one_fl = FrameLanes(np.array([0, 2]), fl.ids[2 * f : 2 * f + 2], fl.on_route[2 * f : 2 * f + 2])
        one, _ = subscores(
            plans[i : i + 1],
            agents=agents[f : f + 1],
            route=routes[f : f + 1],
            centreline=routes[f : f + 1],
            map=m,
            frame_lanes=one_fl,
            ego=EGO,
        )
        for k in got:
            np.testing.assert_equal(got[k][i], one[k][0])
        # and the same as the union of the tiles tested by a one-polygon map
        whole, _ = subscores(
            plans[i : i + 1], map=PlanningMap(PolygonSet.from_rings([[rect(-50, -12, 150, 12)]])), ego=EGO
        )
        assert whole["dac"][0] == one["dac"][0]


# ---------------------------------------------------------------- aggregates


def _drive(plan, gt, **kw):
    kw.setdefault("map", FULL_MAP)
    kw.setdefault("frame_lanes", ONE_FRAME_LANES)
    kw.setdefault("route", ROUTE)
    kw.setdefault("centreline", ROUTE)
    return drive_scores(plan[None], gt[None], ego=EGO, c=[1.0], hc=[1.0], ec=[0.0], **kw)


def test_aggregates_by_hand():
    gt = run(0, -1.75, 10)  # 30 m of progress
    plan = run(0, -1.75, 5)  # 15 m: ep = 15 / 30
    r = _drive(plan, gt, agents=agents_of(track(100, 30, 0)))
    assert r["ep"][0] == pytest.approx(0.5)
    assert (r["nc"][0], r["dac"][0], r["ddc"][0], r["ttc"][0], r["lk"][0]) == (1, 1, 1, 1, 1)
    assert r["pdms"][0] == pytest.approx((5 * 0.5 + 5 + 2) / 12)
    assert r["epdms"][0] == pytest.approx((5 * 0.5 + 5 + 2 + 2 + 0) / 16)
    assert math.isnan(r["tlc"][0]) and "traffic-light" in r.reasons["tlc"][0]
    assert math.isnan(r["epdms_map"][0]) and "epdms" in r.reasons["epdms_map"][0]
    # without annotations: epdms is n/a and epdms_map is given
    r = _drive(plan, gt)
    assert math.isnan(r["epdms"][0]) and "annotations" in r.reasons["epdms"][0]
    assert math.isnan(r["nc"][0]) and math.isnan(r["pdms"][0])
    assert r["epdms_map"][0] == pytest.approx((5 * 0.5 + 2 + 2 + 0) / 11)
    # the ground truth going less than 5 m: progress is 1 for everyone
    r = _drive(plan, run(0, -1.75, 1), agents=agents_of(track(100, 30, 0)))
    assert r["ep"][0] == 1.0


def test_the_human_penalty_filter():
    # the plan and the ground truth both run into a stopped car: the plan is not penalised in epdms (v2), it is in
    # pdms (v1, no filter)
    car = agents_of(track(25, -1.75, 0))
    r = _drive(run(0, -1.75, 10), run(0, -1.75, 9.5), agents=car)
    assert r["nc"][0] == 0.0 and r.gt["nc"][0] == 0.0
    assert r["pdms"][0] == 0.0
    assert r["epdms"][0] > 0.0
    # the ground truth stopping short: the plan's collision counts
    r = _drive(run(0, -1.75, 10), run(0, -1.75, 2), agents=car)
    assert r.gt["nc"][0] == 1.0 and r["epdms"][0] == 0.0
    # a plan in the oncoming lane at 7 m/s (ddc 0) where the ground truth also drives there: not penalised
    onc = run(0, 1.75, 7.0)
    far = agents_of(track(100, 30, 0))
    r = _drive(onc, onc, agents=far)
    assert r["ddc"][0] == 0.0 and r["epdms"][0] > 0
    r = _drive(onc, run(0, -1.75, 7.0), agents=far)
    assert r["epdms"][0] == 0.0


# ---------------------------------------------------------------- bad input


def test_bad_input_is_na_with_a_reason():
    plans = np.stack([run(0, -1.75, 10), run(0, -1.75, 10)])
    plans[1, 12, 0] = np.nan
    gt = run(0, -1.75, 10)[None]
    r = drive_scores(
        plans,
        gt,
        frame=[0, 0],
        agents=agents_of(track(100, 30, 0)),
        map=FULL_MAP,
        frame_lanes=ONE_FRAME_LANES,
        route=ROUTE,
        centreline=ROUTE,
        ego=EGO,
        c=[1, 1],
        hc=[1, 1],
        ec=[1, 1],
    )
    assert np.isfinite(r["epdms"][0])
    for k in ("nc", "dac", "ddc", "ttc", "lk", "ep", "pdms", "epdms"):
        assert math.isnan(r[k][1]), k
    assert "NaN or infinity" in r.reasons["nc"][1]
    assert "nc" in r.reasons["epdms"][1]
    # a degenerate box: nc and ttc n/a naming the frame, step and slot
    car = agents_of(track(100, 30, 0), track(200, 30, 0))
    car[0, 4, 1, 3] = 0.0
    v, why = subscores(run(0, 0, 10)[None], agents=car, ego=EGO)
    assert math.isnan(v["nc"][0]) and math.isnan(v["ttc"][0])
    assert "frame 0" in why["nc"][0] and "step 4, slot 1" in why["nc"][0]
    car[0, 4, 1, 3] = 4.0
    car[0, 4, 1, 7] = 3.0  # an unknown kind
    v, why = subscores(run(0, 0, 10)[None], agents=car, ego=EGO)
    assert math.isnan(v["nc"][0]) and "unknown kind" in why["nc"][0]
    # missing layers: n/a with what is missing
    v, why = subscores(run(0, 0, 10)[None], ego=EGO)
    assert "drivable" in why["dac"][0] and "lane" in why["ddc"][0] and "route" in why["ep_raw"][0]
    assert "annotations" in why["nc"][0] and "centreline" in why["lk"][0]
    # a route with a NaN before its padding
    bad_route = np.array([[[0, 0], [np.nan, np.nan], [10, 0]]], float)
    v, why = subscores(run(0, 0, 10)[None], route=bad_route, ego=EGO)
    assert math.isnan(v["ep_raw"][0]) and "route" in why["ep_raw"][0]
    # comfort not given
    r = drive_scores(
        run(0, -1.75, 5)[None],
        gt,
        agents=agents_of(track(100, 30, 0)),
        map=FULL_MAP,
        frame_lanes=ONE_FRAME_LANES,
        route=ROUTE,
        centreline=ROUTE,
        ego=EGO,
    )
    assert math.isnan(r["epdms"][0]) and "hc (hc not given)" in r.reasons["epdms"][0]


def test_shapes_that_disagree_raise_one_line_errors():
    st = run(0, 0, 10)[None]
    with pytest.raises(ValueError, match=r"states must have shape \(N, S, 11\)"):
        subscores(st[..., :10])
    with pytest.raises(ValueError, match="agents have 30 steps but states have 31"):
        subscores(st, agents=agents_of(track(0, 0, 0))[:, :30])
    with pytest.raises(ValueError, match="disagree on the number of frames"):
        subscores(st, agents=agents_of(track(0, 0, 0)), route=np.zeros((2, 2, 2)))
    with pytest.raises(ValueError, match="frame index 3 is out of range"):
        subscores(st, [3], route=ROUTE)
    with pytest.raises(ValueError, match="frame_lanes"):
        subscores(st, map=FULL_MAP)
    with pytest.raises(ValueError, match="gt_states must have shape"):
        drive_scores(st, st[:, :10])
    with pytest.raises(ValueError, match="frame indices must lie in 0..0"):
        drive_scores(np.concatenate([st, st]), st, frame=[0, 1])
    with pytest.raises(ValueError, match="at least 2 steps"):
        subscores(st[:, :1])


def test_interpolate_boxes_to_10_hz():
    b = np.full((1, 3, 2, 8), np.nan)
    b[0, 0, 0] = [0, 0, math.pi - 0.1, 4, 2, 1, 0, 0]
    b[0, 1, 0] = [5, 1, -math.pi + 0.1, 4, 2, 3, 0, 0]
    b[0, 2, 0] = [10, 2, -math.pi + 0.1, 4, 2, 3, 0, 0]
    b[0, 0, 1] = [0, 0, 0, 1, 1, 0, 0, 1]  # absent at keyframe 1: absent in between
    out = interpolate_boxes(b)
    assert out.shape == (1, 11, 2, 8)
    np.testing.assert_allclose(out[0, 2, 0, :2], [2.0, 0.4])
    np.testing.assert_allclose(out[0, 2, 0, 5], 1.8)
    # the yaw goes the short way through ±π
    assert abs(abs(out[0, 2, 0, 2]) - (math.pi - 0.02)) < 1e-12 or abs(out[0, 2, 0, 2] - (math.pi + 0.02)) < 1e-12
    assert np.isnan(out[0, 1:5, 1, 0]).all() and out[0, 0, 1, 7] == 1
    with pytest.raises(ValueError, match=r"\(F, K, A, 8\)"):
        interpolate_boxes(np.zeros((3, 8)))


# ---------------------------------------------------------------- reading the map expansion


def _expansion(tmp_path, lanes=True, crossing=True):
    """A tiny map expansion: a road, two lanes (one a lane connector), one intersection road segment."""
    nodes, polygons = [], []

    def poly(name, pts):
        toks = []
        for j, (x, y) in enumerate(pts):
            nodes.append({"token": f"{name}-n{j}", "x": x, "y": y})
            toks.append(f"{name}-n{j}")
        polygons.append({"token": name, "exterior_node_tokens": toks, "holes": []})
        return name

    doc = {
        "version": "1.3",
        "node": nodes,
        "polygon": polygons,
        "drivable_area": [{"token": "da", "polygon_tokens": [poly("road", rect(-200, -6, 400, 6))]}],
        "lane": [{"token": "l0", "polygon_token": poly("lane0", rect(-200, -3.5, 400, 0))}] if lanes else [],
        "lane_connector": [{"token": "l1", "polygon_token": poly("lane1", rect(-200, 0, 400, 3.5))}] if lanes else [],
        "road_segment": [
            {"token": "rs0", "polygon_token": poly("seg0", rect(100, -6, 120, 6)), "is_intersection": True},
            {"token": "rs1", "polygon_token": poly("seg1", rect(-200, -6, 100, 6)), "is_intersection": False},
        ]
        if crossing
        else [],
    }
    path = tmp_path / "boston-seaport.json"
    import json

    path.write_text(json.dumps(doc))
    return path


def test_read_planning_map_and_route_lanes(tmp_path):
    m = read_planning_map(_expansion(tmp_path))
    assert len(m.drivable.polygons) == 2 and len(m.lanes.polygons) == 3 and len(m.intersections.polygons) == 2
    gt = run(0, -1.75, 10)[None]
    fl = route_lanes(m.lanes, gt, ego=EGO)
    np.testing.assert_array_equal(fl.offsets, [0, 2])
    np.testing.assert_array_equal(fl.ids, [0, 1])
    np.testing.assert_array_equal(fl.on_route, [1, 0])  # the ground truth drives in lane 0 only
    r = drive_scores(
        run(0, 1.75, 7.0)[None], gt, map=m, frame_lanes=fl, route=ROUTE, centreline=ROUTE, ego=EGO, hc=[1.0], ec=[1.0]
    )
    assert r["ddc"][0] == 0.0 and r["dac"][0] == 1.0
    assert np.isfinite(r["epdms_map"][0])
    # an expansion without lanes or intersections (before v1.3, or synthetic): those sub-scores are n/a, not scored
    # on an empty layer
    bare = read_planning_map(_expansion(tmp_path, lanes=False, crossing=False))
    assert bare.lanes is None and bare.intersections is None and bare.drivable is not None
    v, why = subscores(gt, map=bare, ego=EGO, centreline=ROUTE)
    assert math.isnan(v["ddc"][0]) and "lane polygons" in why["ddc"][0]
    assert math.isnan(v["lk"][0]) and "intersection" in why["lk"][0]
    assert v["dac"][0] == 1.0


def test_a_frame_whose_ground_truth_is_in_no_lane_has_no_ddc(tmp_path):
    m = read_planning_map(_expansion(tmp_path))
    gt = run(0, 30, 10)[None]  # off every lane
    fl = route_lanes(m.lanes, gt, ego=EGO)
    assert fl.on_route.sum() == 0
    v, why = subscores(run(0, -1.75, 10)[None], map=m, frame_lanes=fl, ego=EGO)
    assert math.isnan(v["ddc"][0]) and "on the route" in why["ddc"][0]


def test_the_synthetic_expansion_has_lanes(synth_root):
    # synth_root's two scenes (cruise, accelerate) are straight: lanes, no intersection (tests/unit/synth/test_synth_lanes.py)
    paths = sorted((synth_root / "maps" / "expansion").glob("*.json"))
    assert paths
    m = read_planning_map(paths[0])
    assert m.drivable is not None and m.lanes is not None and m.intersections is None
