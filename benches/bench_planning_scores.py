"""NAVSIM sub-scores and aggregates (lightemma.planning.scores): a paper-sized study and a NumPy/shapely baseline.

    python benches/bench_planning_scores.py [--plans 50804] [--frames 3908] [--agents 40] [--big 100000]
                                            [--shapely-frames 1000]

1. A full paper-sized study: 13 models × 3,908 frames = 50,804 plans of 31 states (3 s at 0.1 s) on 3,908 scene
   frames with ``--agents`` boxes each (interpolated to 10 Hz), a drivable area of 60 polygons (≈ 200 vertices
   each), 2,000 lane polygons (≈ 12 candidates per frame, the ground truth's on route), 80 intersections, route
   and centreline polylines. ``drive_scores`` (plans and ground truths, every sub-score, the aggregates with the
   human-penalty filter): wall and CPU seconds.
2. ``subscores`` on ``--big`` plans (of the study's frames) against a NumPy/shapely 2 implementation of the same definitions
   (vectorised ``shapely.intersects`` / ``contains_xy`` / STRtree queries / ``line_locate_point``, the
   sequential at-fault and TTC rules only on the pairs that touch). shapely runs on ``--shapely-frames`` plans
   and is extrapolated linearly (its cost is per plan); both are checked to agree on those plans first.
"""

from __future__ import annotations

import argparse
import math
import os
import time

import numpy as np

from lightemma.planning.scores import (
    FrameLanes,
    PlanningMap,
    PolygonSet,
    drive_scores,
    interpolate_boxes,
    subscores,
)

S = 31


def timed(f, repeat: int = 3):
    """Best wall time of ``repeat`` calls, that call's CPU seconds (all threads), and its result."""
    best = None
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        out = f()
        w, c = time.perf_counter() - t0, time.process_time() - c0
        if best is None or w < best[0]:
            best = (w, c, out)
    return best


def world(rng, n_lanes=2000):
    """A 1 km² map: drivable blobs, lanes, intersections (as PolygonSets and shapely polygons)."""
    blobs = []
    for _ in range(60):
        cx, cy, r = rng.uniform(0, 1000), rng.uniform(0, 1000), rng.uniform(60, 160)
        t = np.linspace(0, 2 * np.pi, 200, endpoint=False)
        rr = r * (1 + 0.15 * np.sin(5 * t + rng.uniform(0, 6)))
        blobs.append(np.column_stack([cx + rr * np.cos(t), cy + rr * np.sin(t)]))
    lanes = []
    for _ in range(n_lanes):
        cx, cy, h = rng.uniform(0, 1000), rng.uniform(0, 1000), rng.uniform(-np.pi, np.pi)
        c, s = math.cos(h), math.sin(h)
        lanes.append(
            np.array(
                [
                    (cx + lo * c - la * s, cy + lo * s + la * c)
                    for lo, la in ((25, 1.75), (-25, 1.75), (-25, -1.75), (25, -1.75))
                ]
            )
        )
    inter = []
    for _ in range(80):
        cx, cy = rng.uniform(0, 1000), rng.uniform(0, 1000)
        inter.append(np.array([(cx - 10, cy - 10), (cx + 10, cy - 10), (cx + 10, cy + 10), (cx - 10, cy + 10)]))
    m = PlanningMap(
        drivable=PolygonSet.from_rings([[b] for b in blobs]),
        lanes=PolygonSet.from_rings([[ln] for ln in lanes]),
        intersections=PolygonSet.from_rings([[i] for i in inter]),
    )
    return m, blobs, lanes, inter


def frames(rng, f, agents, lanes):
    """Per scene frame: the ground truth's states, agents' boxes at 10 Hz, candidate lanes, route."""
    x0 = rng.uniform(100, 900, (f, 2))
    h0 = rng.uniform(-np.pi, np.pi, f)
    v = rng.uniform(0, 14, f)
    yr = rng.normal(0, 0.08, f)
    t = 0.1 * np.arange(S)
    gt = np.zeros((f, S, 11))
    h = h0[:, None] + yr[:, None] * t
    gt[:, :, 2] = h
    gt[:, :, 3] = v[:, None]
    gt[:, :, 0] = x0[:, :1] + np.cumsum(np.cos(h) * v[:, None] * 0.1, axis=1) - np.cos(h[:, :1]) * v[:, None] * 0.1
    gt[:, :, 1] = x0[:, 1:] + np.cumsum(np.sin(h) * v[:, None] * 0.1, axis=1) - np.sin(h[:, :1]) * v[:, None] * 0.1
    # boxes at 2 Hz (7 keyframes) scattered within 30 m of the ground truth, then interpolated
    k = np.arange(0, S, 5)
    b = np.zeros((f, len(k), agents, 8))
    start = gt[:, :1, :2][:, :, None, :] + rng.uniform(-30, 30, (f, 1, agents, 2))
    yaw = rng.uniform(-np.pi, np.pi, (f, 1, agents))
    sp = rng.choice([0.0, 1.0], (f, 1, agents)) * rng.uniform(0, 12, (f, 1, agents))
    b[..., 0] = start[..., 0] + np.cos(yaw) * sp * 0.1 * k[None, :, None]
    b[..., 1] = start[..., 1] + np.sin(yaw) * sp * 0.1 * k[None, :, None]
    b[..., 2] = yaw
    b[..., 3] = rng.uniform(0.6, 5.0, (f, 1, agents))
    b[..., 4] = rng.uniform(0.6, 2.2, (f, 1, agents))
    b[..., 5], b[..., 6] = np.cos(yaw) * sp, np.sin(yaw) * sp
    b[..., 7] = (rng.random((f, 1, agents)) < 0.15).astype(float)
    boxes = interpolate_boxes(b)
    # candidate lanes: the 12 lanes nearest the frame's start; the 3 nearest on route
    lane_c = np.array([ln.mean(axis=0) for ln in lanes])
    d = np.linalg.norm(lane_c[None] - x0[:, None], axis=-1)
    near = np.argsort(d, axis=1)[:, :12]
    fl = FrameLanes(
        np.arange(0, 12 * f + 1, 12, dtype=np.int64),
        near.reshape(-1).astype(np.int64),
        np.tile(np.array([1, 1, 1] + [0] * 9, np.uint8), f),
    )
    route = np.full((f, 20, 2), np.nan)
    ahead = gt[:, -1:, :2] + 5 * np.stack([np.cos(h[:, -1:]), np.sin(h[:, -1:])], -1)
    route[:, :17] = np.concatenate([gt[:, ::2, :2], ahead], 1)
    return gt, boxes, fl, route


def plans_of(rng, gt, models):
    """`models` plans per frame: the ground truth perturbed in speed and heading."""
    f = len(gt)
    p = np.repeat(gt, models, axis=0)
    scale = rng.uniform(0.6, 1.3, (f * models, 1))
    dh = rng.normal(0, 0.05, (f * models, 1)) * np.arange(S) * 0.1
    h = p[:, :, 2] + dh
    v = p[:, :, 3:4][..., 0] * scale
    p[:, :, 0] = p[:, :1, 0] + np.cumsum(np.cos(h) * v * 0.1, axis=1) - np.cos(h[:, :1]) * v[:, :1] * 0.1
    p[:, :, 1] = p[:, :1, 1] + np.cumsum(np.sin(h) * v * 0.1, axis=1) - np.sin(h[:, :1]) * v[:, :1] * 0.1
    p[:, :, 2], p[:, :, 3] = h, v
    return p, np.repeat(np.arange(f), models)


# ---------------------------------------------------------------- the NumPy/shapely implementation


def shapely_subscores(states, frame, boxes, blobs, lanes, inter, fl, route, ego=(4.084, 1.85, 1.444)):
    """nc, dac, ddc, ep_raw, ttc, lk with shapely 2 (vectorised where the definitions allow)."""
    import shapely

    length, width, off = ego
    n = len(states)
    x, y, h = states[..., 0], states[..., 1], states[..., 2]
    c, s = np.cos(h), np.sin(h)
    cx, cy = x + off * c, y + off * s
    hl, hw = length / 2, width / 2
    lo = np.array([hl, hl, -hl, -hl])
    la = np.array([hw, -hw, -hw, hw])
    corners = np.stack(
        [cx[..., None] + lo * c[..., None] - la * s[..., None], cy[..., None] + lo * s[..., None] + la * c[..., None]],
        -1,
    )  # (N, S, 4, 2) FL FR RR RL
    ego_poly = shapely.polygons(corners)
    drivable = shapely.union_all([shapely.Polygon(b) for b in blobs])
    shapely.prepare(drivable)
    crossing = shapely.union_all([shapely.Polygon(i) for i in inter])
    shapely.prepare(crossing)
    on = shapely.contains_xy(drivable, corners[..., 0], corners[..., 1])
    non_drivable = ~on.all(-1)
    dac = np.where(non_drivable.any(-1), 0.0, 1.0)
    # lanes: STRtree point-in-lane pairs, kept where the lane is a candidate of the plan's frame
    lane_polys = [shapely.Polygon(ln) for ln in lanes]
    tree = shapely.STRtree(lane_polys)
    pts = np.concatenate([corners, np.stack([cx, cy], -1)[:, :, None]], 2).reshape(-1, 2)
    pi, li = tree.query(shapely.points(pts), predicate="within")
    plan_of = pi // (S * 5)
    cand = {}
    for f in np.unique(frame):
        ids = fl.ids[fl.offsets[f] : fl.offsets[f + 1]]
        cand[f] = dict(zip(ids.tolist(), fl.on_route[fl.offsets[f] : fl.offsets[f + 1]].tolist()))
    keep = np.array([li_ in cand[frame[p]] for p, li_ in zip(plan_of.tolist(), li.tolist())], bool)
    pi, li = pi[keep], li[keep]
    route_flag = np.array([cand[frame[p]][q] for p, q in zip((pi // (S * 5)).tolist(), li.tolist())], bool)
    step, point = pi // 5, pi % 5
    in_corner = np.zeros((n * S, len(lanes), 4), bool)
    cm = point < 4
    in_corner[step[cm], li[cm], point[cm]] = True
    touched = in_corner.any(-1).sum(-1)
    has_all = in_corner.all(-1).any(-1)
    multiple = ((touched > 1) & ~has_all).reshape(n, S)
    centre_on_route = np.zeros(n * S, bool)
    centre_on_route[step[(point == 4) & route_flag]] = True
    oncoming = ~centre_on_route.reshape(n, S)
    centre_x = shapely.contains_xy(crossing, cx, cy)
    axle_x = shapely.contains_xy(crossing, x, y)
    exposed_nc = multiple | non_drivable
    speed = np.hypot(states[..., 3], states[..., 4])

    def box_polys(b):
        bc, bs = np.cos(b[..., 2]), np.sin(b[..., 2])
        bl, bw = b[..., 3:4] / 2 * np.array([1, -1, -1, 1]), b[..., 4:5] / 2 * np.array([1, 1, -1, -1])
        return shapely.polygons(
            np.stack(
                [
                    b[..., 0:1] + bl * bc[..., None] - bw * bs[..., None],
                    b[..., 1:2] + bl * bs[..., None] + bw * bc[..., None],
                ],
                -1,
            )
        )

    agents = boxes[frame]  # (N, S, A, 8)
    present = ~np.isnan(agents[..., 0])
    apoly = np.full(agents.shape[:3], None, object)
    apoly[present] = box_polys(agents[present])

    def rel(ax, ay, ah, px, py):
        vx, vy = px - ax, py - ay
        return np.arccos(np.clip((np.cos(ah) * vx + np.sin(ah) * vy) / np.hypot(vx, vy), -1, 1))

    # nc: all (plan, step, agent) pairs at once, then the rules in time order on the hits
    hit = np.zeros(agents.shape[:3], bool)
    hit[present] = shapely.intersects(np.broadcast_to(ego_poly[..., None], agents.shape[:3])[present], apoly[present])
    nc = np.ones(n)
    for p in np.unique(np.nonzero(hit)[0]):
        ignored = set()
        for st_, a in zip(*np.nonzero(hit[p])):
            if a in ignored:
                continue
            b = agents[p, st_, a]
            if speed[p, st_] <= 0.05:
                fault = False
            elif b[7] != 0 or math.hypot(b[5], b[6]) <= 0.05:
                fault = True
            elif rel(x[p, st_], y[p, st_], h[p, st_], b[0], b[1]) > math.radians(150):
                fault = False
            elif shapely.intersects(shapely.LineString(corners[p, st_, :2]), apoly[p, st_, a]):
                fault = True
            else:
                fault = bool(exposed_nc[p, st_])
            if fault:
                nc[p] = min(nc[p], 0.0 if b[7] == 0 else 0.5)
            else:
                ignored.add(a)
    # ttc: projected footprints against the boxes 0, 3, 6, 9 steps later
    ev = S - 9
    ttc = np.ones(n)
    hits = []
    for k in (0, 3, 6, 9):
        d = np.stack([c[:, :ev] * speed[:, :ev], s[:, :ev] * speed[:, :ev]], -1) * k * 0.1
        proj = shapely.polygons(corners[:, :ev] + d[:, :, None])
        later = apoly[:, k : k + ev]
        pres = present[:, k : k + ev]
        hk = np.zeros(pres.shape, bool)
        hk[pres] = shapely.intersects(np.broadcast_to(proj[..., None], pres.shape)[pres], later[pres])
        hits.append(hk)
    hits = np.stack(hits, 2)  # (N, ev, 4, A)
    for p in np.unique(np.nonzero(hits)[0]):
        ignored = set()
        for st_, j, a in zip(*np.nonzero(hits[p])):
            if a in ignored or speed[p, st_] < 5e-3:
                continue
            b = agents[p, st_ + 3 * j, a]
            ang = rel(x[p, st_], y[p, st_], h[p, st_], b[0], b[1])
            if ang < math.radians(30) or ((exposed_nc[p, st_] or axle_x[p, st_]) and not ang > math.radians(150)):
                ttc[p] = 0.0
                break
            ignored.add(a)
    # ddc
    prog = np.zeros((n, S))
    prog[:, 1:] = np.hypot(np.diff(cx, axis=1), np.diff(cy, axis=1))
    prog[~oncoming | centre_x] = 0.0
    csum = np.concatenate([np.zeros((n, 1)), np.cumsum(prog, 1)], 1)
    window = csum[:, 1:] - csum[:, np.maximum(0, np.arange(S) - 10)]
    worst = window.max(1)
    ddc = np.where(worst < 2, 1.0, np.where(worst < 6, 0.5, 0.0))
    # ep and lk along the frame's polyline
    lines = np.array([shapely.LineString(r[~np.isnan(r[:, 0])]) for r in route], object)[frame]
    ep = np.maximum(
        0.0,
        shapely.line_locate_point(lines, shapely.points(cx[:, -1], cy[:, -1]))
        - shapely.line_locate_point(lines, shapely.points(cx[:, 0], cy[:, 0])),
    )
    dev = shapely.distance(lines[:, None], shapely.points(cx, cy)) > 0.5
    lk = np.ones(n)
    for p in np.nonzero((dev & ~centre_x).sum(1) >= 20)[0]:
        run = 0
        for st_ in range(S):
            if centre_x[p, st_]:
                continue
            run = run + 1 if dev[p, st_] else 0
            if run >= 20:
                lk[p] = 0.0
                break
    return {"nc": nc, "dac": dac, "ddc": ddc, "ep_raw": ep, "ttc": ttc, "lk": lk}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--plans", type=int, default=13 * 3908)
    ap.add_argument("--frames", type=int, default=3908)
    ap.add_argument("--agents", type=int, default=40)
    ap.add_argument("--big", type=int, default=100_000)
    ap.add_argument("--shapely-frames", type=int, default=1000)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    m, blobs, lanes, inter = world(rng)
    print(f"cores: {os.cpu_count()}  (CPU seconds are summed over threads)")

    # 1. the paper-sized study
    gt, boxes, fl, route = frames(rng, args.frames, args.agents, lanes)
    models = max(1, args.plans // args.frames)
    plans, frame = plans_of(rng, gt, models)
    ones = np.ones(len(plans))
    wall, cpu, r = timed(
        lambda: drive_scores(
            plans,
            gt,
            frame=frame,
            agents=boxes,
            map=m,
            frame_lanes=fl,
            route=route,
            centreline=route,
            c=ones,
            hc=ones,
            ec=ones,
        )
    )
    print(
        f"study: {len(plans):,} plans on {args.frames:,} frames, {args.agents} agents, 31 states: "
        f"drive_scores {wall:.2f} s wall, {cpu:.2f} s CPU"
    )
    for k in ("nc", "dac", "ddc", "ep", "ttc", "lk", "pdms", "epdms"):
        v = r[k]
        print(f"  {k:6s} mean {np.nanmean(v):.3f}  n/a {np.isnan(v).sum()}")

    # 2. subscores on --big plans (of the study's frames) against NumPy/shapely on the first --shapely-frames
    big, big_frame = plans_of(rng, gt, -(-args.big // args.frames))
    big, big_frame = big[: args.big], big_frame[: args.big]
    sub = args.shapely_frames
    kw = dict(agents=boxes, map=m, frame_lanes=fl, route=route, centreline=route, n_frames=args.frames)
    got, _ = subscores(big[:sub], big_frame[:sub], **kw)
    t0, c0 = time.perf_counter(), time.process_time()
    want = shapely_subscores(big[:sub], big_frame[:sub], boxes, blobs, lanes, inter, fl, route)
    sw, sc = time.perf_counter() - t0, time.process_time() - c0
    for k, v in want.items():
        same = np.isclose(got[k], v, atol=1e-9) | (np.isnan(got[k]) & np.isnan(v))
        assert same.all(), (k, np.nonzero(~same)[0][:10])
    print(
        f"shapely agrees on {sub:,} plans; it took {sw:.2f} s wall, {sc:.2f} s CPU "
        f"→ {sw * args.big / sub:.1f} s wall at {args.big:,} (linear)"
    )
    wall, cpu, _ = timed(lambda: subscores(big, big_frame, **kw))
    print(
        f"subscores on {args.big:,} plans: {wall:.2f} s wall, {cpu:.2f} s CPU; "
        f"speed-up over shapely {sw * args.big / sub / wall:.0f}x (wall), {sc * args.big / sub / cpu:.0f}x (CPU)"
    )


if __name__ == "__main__":
    main()
