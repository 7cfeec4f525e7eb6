"""Benchmark the scene-level resampling: the Rust core against a vectorised NumPy restatement.

The size of a real comparison: 13 models × 3,908 frames in 150 scenes, 10,000 resamples.

* ``intervals`` — scene-bootstrap 95 % intervals of ADE avg and FDE for every model (13 rows × 2 metrics);
* ``pairwise``  — every pair of models (78 rows): bootstrap interval of the paired difference
  and the sign-flip permutation p-value (10,000 flips each).

Both implementations start from per-frame values and scene labels (the per-scene sums are
part of the timing) and are checked to agree before timing (within Monte Carlo error: they
draw different random numbers). Best of ``--repeat`` runs. Usage::

    python benches/bench_bootstrap.py [--resamples 10000] [--repeat 5]
"""

from __future__ import annotations

import argparse
import itertools
import os
import time

import numpy as np

from lightemma.evaluation.stats import Resampling, bootstrap_ci, cluster_sums, sign_flip_p

MODELS, FRAMES, SCENES = 13, 3908, 150


def fixture(seed: int = 0) -> tuple[list[np.ndarray], np.ndarray]:
    """Per model (FRAMES, 2) values (ADE avg, FDE) sharing scene labels; scene effects as in real runs."""
    rng = np.random.default_rng(seed)
    scenes = np.sort(rng.integers(0, SCENES, FRAMES))
    difficulty = np.exp(rng.normal(0, 0.35, SCENES))
    values = []
    for m in range(MODELS):
        ade = (1.0 + 0.05 * m) * difficulty[scenes] * np.exp(rng.normal(0, 0.6, FRAMES))
        values.append(np.stack([ade, 2.2 * ade * np.exp(rng.normal(0, 0.2, FRAMES))], axis=1))
    return values, scenes


def numpy_intervals(groups, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    out = []
    for values, labels in groups:
        sums, counts = cluster_sums(values, labels)
        idx = rng.integers(0, len(counts), (n, len(counts)))
        means = sums[idx].sum(axis=1) / counts[idx].sum(axis=1)[:, None]  # (n, M)
        out.append(np.quantile(means, [0.025, 0.975], axis=0).T)
    return np.array(out)


def numpy_sign_flip(groups, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    out = []
    for values, labels in groups:
        d = cluster_sums(values, labels)[0][:, 0]
        flips = rng.integers(0, 2, (n, len(d)), dtype=np.int8) * 2 - 1
        out.append((1 + np.sum(np.abs(flips @ d) >= abs(d.sum()) - 1e-12 * np.abs(d).sum())) / (1 + n))
    return np.array(out)


def best(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resamples", type=int, default=10_000)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    n = args.resamples
    values, scenes = fixture()
    models = [(v, scenes) for v in values]
    keys = [f"model {i}" for i in range(MODELS)]
    pairs = [(values[a][:, 0] - values[b][:, 0], scenes) for a, b in itertools.combinations(range(MODELS), 2)]
    pair_keys = [f"pair {a}-{b}" for a, b in itertools.combinations(range(MODELS), 2)]
    resampling = Resampling(n_resamples=n, seed=1)

    # agreement first (different random numbers: within Monte Carlo error)
    ours, ref = bootstrap_ci(models, keys, resampling), numpy_intervals(models, n, 1)
    width = ref[..., 1] - ref[..., 0]
    assert np.all(np.abs(ours - ref) <= 0.05 * width[..., None] + 1e-3), "intervals disagree"
    p_ours, p_ref = sign_flip_p(pairs, pair_keys, resampling), numpy_sign_flip(pairs, n, 1)
    assert np.all(np.abs(p_ours - p_ref) <= np.maximum(0.01, 0.2 * p_ref)), "p-values disagree"

    rows = [
        (
            "intervals: 13 models × ADE avg, FDE",
            lambda: bootstrap_ci(models, keys, resampling),
            lambda: numpy_intervals(models, n, 1),
        ),
        (
            "pairwise: 78 pairs, bootstrap interval",
            lambda: bootstrap_ci(pairs, pair_keys, resampling),
            lambda: numpy_intervals(pairs, n, 1),
        ),
        (
            "pairwise: 78 pairs, sign-flip p-value",
            lambda: sign_flip_p(pairs, pair_keys, resampling),
            lambda: numpy_sign_flip(pairs, n, 1),
        ),
    ]
    print(
        f"{MODELS} models × {FRAMES} frames in {SCENES} scenes, {n} resamples, best of {args.repeat}; {os.cpu_count()} CPU(s)\n"
    )
    print("| step | Rust core (s) | NumPy (s) | NumPy / Rust |")
    print("|---|---:|---:|---:|")
    total_rust = total_numpy = 0.0
    for name, rust, numpy_fn in rows:
        r, p = best(rust, args.repeat), best(numpy_fn, args.repeat)
        total_rust += r
        total_numpy += p
        print(f"| {name} | {r:.3f} | {p:.3f} | {p / r:.1f}× |")
    print(f"| **all of it** | **{total_rust:.3f}** | {total_numpy:.3f} | {total_numpy / total_rust:.1f}× |")


if __name__ == "__main__":
    main()
