"""Safety kernels (docs/definitions.md#safety): collisions against shapely, and the mask lookups' cost against
their memory traffic.

    python benches/bench_safety.py [--frames 100000] [--agents 30] [--shapely-frames 2000]

1. ``box_collisions`` on frames × 6 steps × agents (exact rotated rectangles, one core call) against a
   shapely 2 implementation (vectorised ``shapely.intersects`` of the same footprints and boxes, the
   footprints built with NumPy). shapely runs on a subsample of frames and is extrapolated linearly (its
   cost is per pair); both are checked to agree on that subsample first.
2. ``mask_area`` (4 corners + the reference point per step) on a 10,000 × 10,000 px mask (100 MB, far
   beyond the caches): each lookup reads one random byte, i.e. one 64-byte cache line. Compared with a
   NumPy gather of the same pixels (the same memory traffic, no geometry) and with streaming bandwidth.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from lightemma import integrate
from lightemma.evaluation import safety as S

CPU: list[float] = []  # CPU seconds (all threads) of the best-wall call of each best()


def best(f, repeat: int = 3) -> float:
    """Best wall time of ``repeat`` calls; its CPU time goes to ``CPU`` (the machine may be shared)."""
    times = []
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        f()
        times.append((time.perf_counter() - t0, time.process_time() - c0))
    wall, cpu = min(times)
    CPU.append(cpu)
    return wall


def scene(n: int, agents: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    actions = np.stack([rng.uniform(0, 12, (n, 6)), rng.normal(0, 0.02, (n, 6))], axis=-1)
    traj = integrate(actions)
    poses = np.column_stack([rng.uniform(0, 900, (n, 2)), rng.uniform(-np.pi, np.pi, n)])
    g = S.ego_poses(traj, poses)
    # agents scattered within 12 m of the ego's path at each step: a few percent of the pairs overlap
    boxes = np.empty((n, 6, agents, 5))
    boxes[..., :2] = g[:, :, None, :2] + rng.uniform(-12, 12, (n, 6, agents, 2))
    boxes[..., 2] = rng.uniform(-np.pi, np.pi, (n, 6, agents))
    boxes[..., 3] = rng.uniform(0.6, 5.0, (n, 6, agents))
    boxes[..., 4] = rng.uniform(0.6, 2.2, (n, 6, agents))
    return traj, poses, boxes


def shapely_collisions(traj, poses, boxes):
    """The same test with shapely: footprint and box polygons, ``shapely.intersects`` pair by pair (vectorised)."""
    import shapely

    from lightemma.report.figures.bev import box_corners

    n, t, a, _ = boxes.shape
    ego = S.footprints(traj, poses).reshape(n * t, 4, 2)
    ego_polys = shapely.polygons(ego)
    agent_polys = shapely.polygons(box_corners(boxes.reshape(-1, 5)))
    hits = shapely.intersects(np.repeat(ego_polys, a), agent_polys)
    return hits.reshape(n, t, a)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=100_000)
    p.add_argument("--agents", type=int, default=30)
    p.add_argument("--shapely-frames", type=int, default=2_000)
    args = p.parse_args()
    n, a, m = args.frames, args.agents, args.shapely_frames
    traj, poses, boxes = scene(n, a)
    pairs = n * 6 * a
    print(f"collisions: {n:,} frames × 6 steps × {a} agents = {pairs:,} box pairs")
    sub = slice(0, m)
    ours = S.box_collisions(traj[sub], poses[sub], boxes[sub])
    ref = shapely_collisions(traj[sub], poses[sub], boxes[sub])
    assert (ours == ref).all(), f"{(ours != ref).sum()} of {ours.size} pairs disagree with shapely"
    print(f"  agree with shapely on {ours.size:,} pairs ({ours.mean() * 100:.2f} % overlap)")
    t_rust = best(lambda: S.box_collisions(traj, poses, boxes))
    t_shp = best(lambda: shapely_collisions(traj[sub], poses[sub], boxes[sub]), repeat=2) * n / m
    c_rust, c_shp = CPU[-2], CPU[-1] * n / m
    print(
        f"  Rust (one call, all frames): {t_rust:.3f} s wall, {c_rust:.3f} s CPU ({t_rust / pairs * 1e9:.1f} ns per pair)"
    )
    print(f"  shapely: {t_shp:.1f} s wall, {c_shp:.1f} s CPU (measured on {m:,} frames, × {n / m:g})")
    print(f"  speed-up: {t_shp / t_rust:.0f}× wall, {c_shp / c_rust:.0f}× CPU")

    # mask lookups
    side = 10_000
    rng = np.random.default_rng(1)
    mask = np.zeros((side, side), dtype=np.uint8)
    mask[rng.random((side, side)) < 0.3] = 255
    poses_m = np.column_stack([rng.uniform(50, side * 0.1 - 50, (n, 2)), rng.uniform(-np.pi, np.pi, n)])
    look = n * 6 * 5
    t_mask = best(lambda: S.DrivableArea("mask", "bench", mask=mask).lookup(traj, poses_m))
    c_mask = CPU[-1]
    corners = S.footprints(traj, poses_m)
    ref_pts = S.ego_poses(traj, poses_m)[..., :2]
    pts = np.concatenate([corners.reshape(-1, 2), ref_pts.reshape(-1, 2)])
    px = np.round(pts[:, 0] * 10).astype(np.int64)
    py = np.round(-pts[:, 1] * 10 + side).astype(np.int64)
    flat = mask.reshape(-1)
    index = py * side + px
    t_gather = best(lambda: flat[index])
    c_gather = CPU[-1]
    t_points = best(lambda: S.DrivableArea("mask", "bench", mask=mask).contains(pts))
    c_points = CPU[-1]
    big = np.ones(1 << 27, dtype=np.uint8)
    t_copy = best(lambda: big.copy())
    stream = 2 * big.nbytes / t_copy / 1e9
    traffic = look * 64 / 1e9
    print(
        f"mask: {side:,} × {side:,} px ({mask.nbytes / 1e6:.0f} MB); {look:,} lookups (4 corners + reference point × 6 steps × {n:,} frames)"
    )
    print(
        f"  mask_area (geometry + lookups): {t_mask:.3f} s wall, {c_mask:.3f} s CPU, {t_mask / look * 1e9:.1f} ns per lookup"
    )
    print(
        f"  mask_lookup of the same points (lookups only): {t_points:.3f} s wall, {c_points:.3f} s CPU, {t_points / look * 1e9:.1f} ns per lookup"
    )
    print(
        f"  NumPy gather of the same pixels, indices precomputed (the memory traffic alone, one thread): {t_gather:.3f} s wall, "
        f"{c_gather:.3f} s CPU, {t_gather / look * 1e9:.1f} ns per pixel"
    )
    print(
        f"  traffic: one 64-byte line per lookup = {traffic:.2f} GB → {traffic / t_points:.1f} GB/s achieved by mask_lookup; "
        f"streaming copy bandwidth {stream:.1f} GB/s"
    )


if __name__ == "__main__":
    main()
