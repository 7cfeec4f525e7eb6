"""Rust core vs vectorised NumPy vs a per-frame pure-Python loop (the paper's style).

For N = 1e3, 1e5, 1e6 frames: integrate + evaluate, and parse (vs a Python
regex + ``ast.literal_eval`` parser, like the reference scripts). Prints a
Markdown table of best-of-k wall times and ratios, and the peak extra memory of
the Rust path relative to its output arrays.

    python benches/bench_core.py            # all sizes (the per-frame loop is skipped at 1e6)
    python benches/bench_core.py --sizes 1000 100000
"""

from __future__ import annotations

import argparse
import ast
import math
import re
import time

import numpy as np

import lightemma


# ---------------------------------------------------------------- references
def numpy_integrate(actions: np.ndarray, dt: float = 0.5) -> np.ndarray:
    v, kappa = actions[..., 0], actions[..., 1]
    heading = np.concatenate([np.zeros((len(actions), 1)), np.cumsum(kappa * v * dt, axis=1)[:, :-1]], axis=1)
    x = np.cumsum(v * np.cos(heading) * dt, axis=1)
    y = np.cumsum(v * np.sin(heading) * dt, axis=1)
    return np.stack([x, y], axis=-1)


def numpy_evaluate(pred: np.ndarray, gt: np.ndarray) -> dict:
    e = np.hypot(*(pred - gt).transpose(2, 0, 1))
    return {
        "ade_1s": e[:, 0:2].mean(),
        "ade_2s": e[:, 2:4].mean(),
        "ade_3s": e[:, 4:6].mean(),
        "ade_avg": e.mean(),
        "fde": e[:, 5].mean(),
        "miss_rate": (e.max(1) > 2.0).mean(),
    }


def numpy_evaluate_all(pred: np.ndarray, gt: np.ndarray) -> dict:
    """All three conventions from one NumPy error matrix (docs/definitions.md#metrics)."""
    e = np.hypot(*(pred - gt).transpose(2, 0, 1))
    miss = (e.max(1) > 2.0).mean()
    stp3 = [e[:, : 2 * s].mean(1).mean() for s in (1, 2, 3)]
    uniad = [e[:, 2 * s - 1].mean() for s in (1, 2, 3)]
    out = {"lightemma": numpy_evaluate(pred, gt)}
    for name, cols in (("stp3", stp3), ("uniad", uniad)):
        out[name] = {
            "ade_1s": cols[0],
            "ade_2s": cols[1],
            "ade_3s": cols[2],
            "ade_avg": sum(cols) / 3,
            "fde": e[:, 5].mean(),
            "miss_rate": miss,
        }
    return out


def loop_integrate_evaluate(actions: list, gts: list) -> float:
    """One frame at a time in plain Python, as the paper's scripts do."""
    total = 0.0
    for frame, gt in zip(actions, gts):
        x = y = heading = 0.0
        errors = []
        for (v, kappa), (gx, gy) in zip(frame, gt):
            x += v * math.cos(heading) * 0.5
            y += v * math.sin(heading) * 0.5
            heading += kappa * v * 0.5
            errors.append(math.hypot(x - gx, y - gy))
        total += sum(errors) / len(errors)
    return total / len(actions)


PAIR = re.compile(r"\[\s*\(.*\)\s*\]", re.S)
NUMBER = re.compile(r"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")


def python_parse(text: str):
    """The reference scripts' way: regex out the list, ``ast.literal_eval`` it, else 12 numbers."""
    match = PAIR.search(text)
    if match:
        try:
            value = ast.literal_eval(match.group(0))
            if len(value) == 6:
                return [tuple(map(float, p)) for p in value]
        except (ValueError, SyntaxError, TypeError):
            pass
    numbers = NUMBER.findall(text)
    if len(numbers) >= 12:
        values = list(map(float, numbers[:12]))
        return list(zip(values[::2], values[1::2]))
    return None


# ---------------------------------------------------------------- harness
def _status_bytes(field: str) -> int:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(field + ":"):
                return int(line.split()[1]) * 1024
    raise RuntimeError(f"no {field} in /proc/self/status")


def reset_peak_rss() -> int:
    """Reset the peak resident set size (VmHWM) to the current RSS; return it."""
    with open("/proc/self/clear_refs", "w") as fh:
        fh.write("5")
    return _status_bytes("VmRSS")


def peak_rss() -> int:
    return _status_bytes("VmHWM")


def best_of(fn, repeat: int) -> float:
    best = math.inf
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def answers(n: int) -> list[str]:
    strict = "[(5.0, 0.01), (5.5, 0.0), (6.0, -0.02), (6.5, 0.0), (7.0, 0.0), (7.5, 0.003)]"
    fenced = "Here are the actions:\n```\n" + strict + "\n```\nDrive safely."
    labels = "v1 = 5.0, c1 = 0.01; v2 = 5.5, c2 = 0.0; v3 = 6.0, c3 = -0.02; v4 = 6.5, c4 = 0; v5 = 7, c5 = 0; v6 = 7.5, c6 = 0.003"
    return [(strict, fenced, labels)[i % 3] for i in range(n)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[1_000, 100_000, 1_000_000])
    parser.add_argument("--repeat", type=int, default=20, help="best of this many runs (this VM is noisy)")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    rows = []
    for n in args.sizes:
        actions = np.stack([rng.uniform(0, 15, (n, 6)), rng.uniform(-0.1, 0.1, (n, 6))], axis=-1)
        gt = numpy_integrate(actions + rng.normal(0, 0.05, actions.shape))

        def rust_ie():
            lightemma.evaluate(lightemma.integrate(actions), gt)

        def numpy_ie():
            numpy_evaluate(numpy_integrate(actions), gt)

        # sanity: the three agree
        ours = lightemma.evaluate(lightemma.integrate(actions), gt).ade_avg
        assert abs(ours - numpy_evaluate(numpy_integrate(actions), gt)["ade_avg"]) < 1e-9
        t_rust = best_of(rust_ie, args.repeat)
        t_numpy = best_of(numpy_ie, args.repeat)
        t_loop = None
        if n <= 100_000:
            frames, gts = actions.tolist(), gt.tolist()
            assert abs(loop_integrate_evaluate(frames, gts) - ours) < 1e-9
            t_loop = best_of(lambda: loop_integrate_evaluate(frames, gts), 1)
        rows.append(("integrate + evaluate", n, t_rust, t_numpy, t_loop))

        # every convention: one evaluate_all call into a reused trajectory buffer vs three evaluate calls
        from lightemma.metrics import evaluate_all

        buffer = np.empty_like(actions)

        def rust_all():
            evaluate_all(lightemma.integrate(actions, out=buffer), gt)

        def rust_three():
            traj = lightemma.integrate(actions)
            for convention in lightemma.CONVENTIONS:
                lightemma.evaluate(traj, gt, convention=convention)

        def numpy_all():
            numpy_evaluate_all(numpy_integrate(actions), gt)

        ours_all = evaluate_all(lightemma.integrate(actions), gt)
        theirs_all = numpy_evaluate_all(numpy_integrate(actions), gt)
        for convention, metrics in ours_all.items():
            assert abs(metrics.ade_avg - theirs_all[convention]["ade_avg"]) < 1e-9, convention
            assert metrics == lightemma.evaluate(lightemma.integrate(actions), gt, convention=convention)
        t_numpy_all = best_of(numpy_all, args.repeat)
        rows.append(
            ("integrate + evaluate_all (3 conventions, out=)", n, best_of(rust_all, args.repeat), t_numpy_all, None)
        )
        rows.append(("integrate + 3 × evaluate (before)", n, best_of(rust_three, args.repeat), t_numpy_all, None))

        texts = answers(n)
        ours_parse = lightemma.parse_actions(texts)
        assert (ours_parse.status != "failed").all()
        t_parse = best_of(lambda: lightemma.parse_actions(texts), args.repeat)
        t_py = None
        if n <= 100_000:
            assert all(python_parse(t) is not None for t in texts[:3])
            t_py = best_of(lambda: [python_parse(t) for t in texts], 1)
        rows.append(("parse (lenient)", n, t_parse, None, t_py))
        # with each frame's history (issue 19: a list equal to it is a quotation); builds without it skip the row
        histories = np.stack([rng.uniform(0, 15, (n, 6)), rng.uniform(-0.1, 0.1, (n, 6))], axis=-1).round(3)
        try:
            with_history = lightemma.parse_actions(texts, history=histories)
        except TypeError:
            continue
        assert (with_history.status == ours_parse.status).all()
        t_hist = best_of(lambda: lightemma.parse_actions(texts, history=histories), args.repeat)
        rows.append(("parse (lenient, with histories)", n, t_hist, None, None))

    # memory: growth of the process's peak RSS during the Rust path vs its output array
    n = args.sizes[-1]
    actions = np.stack([rng.uniform(0, 15, (n, 6)), rng.uniform(-0.1, 0.1, (n, 6))], axis=-1)
    gt = numpy_integrate(actions)
    before = reset_peak_rss()
    traj = lightemma.integrate(actions)
    lightemma.evaluate(traj, gt)
    peak = peak_rss() - before

    print("| kernel | N | Rust (s) | NumPy (s) | per-frame Python (s) | vs NumPy | vs Python |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for name, n, t_rust, t_numpy, t_slow in rows:
        fmt = lambda t: "—" if t is None else f"{t:.4f}"  # noqa: E731
        ratio = lambda t: "—" if t is None else f"{t / t_rust:.1f}×"  # noqa: E731
        print(
            f"| {name} | {n:,} | {t_rust:.4f} | {fmt(t_numpy)} | {fmt(t_slow)} | {ratio(t_numpy)} | {ratio(t_slow)} |"
        )
    print(
        f"\nmemory at N={n:,}: peak RSS grew by {peak / 2**20:.1f} MiB "
        f"for an output trajectory array of {traj.nbytes / 2**20:.1f} MiB"
    )


if __name__ == "__main__":
    main()
