"""Re-simulation and comfort kernels (docs/definitions.md#re-simulation-and-comfort) against NumPy.

    python benches/bench_planning_sim.py [--frames 50804] [--numpy-frames 100000 (0: skip 2.)] [--chunk 5000]

1. The benchmark's size: 3,908 frames × 13 (the reference set under 13 runs) = 50,804 plans of six 0.5 s poses,
   each simulated (30 steps of 0.1 s, LQR + kinematic bicycle) then scored for comfort ``c`` (31 states), history
   comfort ``hc`` (14 derived past states + 31) and extended comfort ``ec`` (each frame against the one before it, as
   consecutive keyframes are: one simulation per frame serves both); wall and
   CPU seconds of each call (CPU = all threads of this process).
2. The same definitions in NumPy/SciPy (the oracle of tests/unit/planning/test_planning_simulation.py: batched pseudo-inverse
   fits, batched LQR, ``scipy.signal.savgol_filter``) on ``--numpy-frames`` plans in chunks of ``--chunk`` frames
   (memory), against the Rust kernels on the same plans; the results are checked to agree first.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lightemma.planning import simulation as sim  # noqa: E402
from tests.unit.planning.test_planning_simulation import oracle_comfort, oracle_extended, oracle_simulate, random_plans  # noqa: E402


def timed(f):
    t0, c0 = time.perf_counter(), time.process_time()
    out = f()
    return out, time.perf_counter() - t0, time.process_time() - c0


def rust_all(poses, init, past):
    states = sim.simulate(poses, init)
    c = sim.comfort(states)
    hc = sim.history_comfort(past, states).comfortable
    ec = sim.extended_comfort(states[1:], states[:-1])
    return states, c, hc, ec


def numpy_all(poses, init, past, chunk):
    n = len(poses)
    states = np.concatenate(
        [oracle_simulate(poses[s : s + chunk], init[s : s + chunk], sim.ZOE) for s in range(0, n, chunk)]
    )
    c, hc, ec = [], [], []
    for s in range(0, n, chunk):
        sl = slice(s, s + chunk)
        c.append(oracle_comfort(states[sl])[0].all(axis=1))
        hc.append(oracle_comfort(np.concatenate([past[sl], states[sl]], axis=1))[0].all(axis=1))
        now, prev = states[1:][sl], states[:-1][sl]
        ec.append((oracle_extended(now, prev) <= [0.7, 0.5, 0.1, 0.1]).all(axis=1))
    return states, np.concatenate(c), np.concatenate(hc), np.concatenate(ec)


def inputs(n, seed):
    rng = np.random.default_rng(seed)
    poses, init = random_plans(rng, n)
    t = np.arange(-7, 1) * 0.5
    hist = np.stack([init[:, 3:4] * t + rng.normal(0, 0.05, (n, 8)), rng.normal(0, 0.05, (n, 8))], -1)
    hist[:, -1] = 0.0
    past = sim.history_states(hist).states
    return poses, init, past


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=3908 * 13)
    parser.add_argument("--numpy-frames", type=int, default=100_000)
    parser.add_argument("--chunk", type=int, default=5000)
    args = parser.parse_args()

    poses, init, past = inputs(args.frames, 0)
    rust_all(poses[:100], init[:100], past[:100])  # warm up (thread pool)
    print(f"1. {args.frames} frames (3,908 × 13 = 50,804 by default)")
    states = sim.simulate(poses, init)
    total_wall = total_cpu = 0.0
    for name, f in [
        ("simulate (31 states)", lambda: sim.simulate(poses, init)),
        ("comfort c (31 states)", lambda: sim.comfort(states)),
        ("history comfort hc (14 + 31)", lambda: sim.history_comfort(past, states)),
        ("extended comfort ec (26 + 26)", lambda: sim.extended_comfort(states[1:], states[:-1])),
    ]:
        _, wall, cpu = timed(f)
        total_wall, total_cpu = total_wall + wall, total_cpu + cpu
        print(f"   {name:32s} wall {wall:6.3f} s   cpu {cpu:6.3f} s")
    print(f"   {'all':32s} wall {total_wall:6.3f} s   cpu {total_cpu:6.3f} s")

    n = args.numpy_frames
    if n <= 0:
        return
    poses, init, past = inputs(n, 1)
    print(f"2. {n} frames: Rust against NumPy/SciPy (simulate, c, hc, ec)")
    check = slice(0, min(n, 2000))
    r = rust_all(poses[check], init[check], past[check])
    o = numpy_all(poses[check], init[check], past[check], args.chunk)
    diff = np.abs(r[0] - o[0])
    diff[..., 2] = np.abs(np.arctan2(np.sin(r[0][..., 2] - o[0][..., 2]), np.cos(r[0][..., 2] - o[0][..., 2])))
    agree = [float((np.asarray(a, float) == np.asarray(b, float)).mean()) for a, b in zip(r[1:], o[1:])]
    print(f"   agreement on {check.stop} frames: states max |Δ| {diff.max():.1e}; c, hc, ec equal on {agree}")
    _, rust_wall, rust_cpu = timed(lambda: rust_all(poses, init, past))
    _, np_wall, np_cpu = timed(lambda: numpy_all(poses, init, past, args.chunk))
    print(f"   Rust   wall {rust_wall:7.3f} s   cpu {rust_cpu:7.3f} s")
    print(f"   NumPy  wall {np_wall:7.3f} s   cpu {np_cpu:7.3f} s")
    print(f"   speed-up: wall {np_wall / rust_wall:.1f}×, cpu {np_cpu / rust_cpu:.1f}×")


if __name__ == "__main__":
    main()
