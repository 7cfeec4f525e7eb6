"""Where users wait, side by side with an anchor tree: evaluate (the columnar sidecar), start-up, import.

Each row runs a command of this tree (A) and the same command of an anchor tree (B: another
checkout's ``python/`` folder, e.g. main's) in turn, A B A B …, each in a fresh process, and
prints the medians of wall and CPU seconds (the process and its children), the ratio B / A
of the CPU medians and the differences A − B (CPU: the robust figure on a shared machine).

* ``evaluate`` — ``lightemma evaluate`` over 13 stand-in runs × 3,908 frames (the paper's 13
  models on v1.0-test): reference result folders written by ``bench_import.write_results``
  (150 scene files per model, texts of realistic length), imported once by each tree; this
  tree's runs come with their sidecar (``frames.columns.npz``), the anchor's do not.
* ``startup`` — ``lightemma --help``; ``lightemma run --limit 1`` with a baseline and with the
  direct transport against the loopback server (tests/support/fake_openai.py), each beside loading the
  same frames alone (``load_frames``): the difference is what ``run`` adds before its first frame.
* ``import`` — ``lightemma import --jobs 1`` of one stand-in model folder (3,908 frames).

    python benches/bench_speed.py --anchor /work/main/python                # all rows, 13 models
    python benches/bench_speed.py --anchor ../main/python --only startup --repeat 5
    python benches/bench_speed.py --anchor ../main/python --keep /tmp/bench-speed   # reuse the stand-ins
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
TREE = HERE.parent / "python"
sys.path.insert(0, str(HERE))


def timed(cmd: list[str], pythonpath: Path) -> tuple[float, float]:
    """(wall s, CPU s of the process and its children) of one run of ``cmd`` under ``pythonpath``; fails loudly."""
    env = {**os.environ, "PYTHONPATH": str(pythonpath), "HF_HUB_OFFLINE": "1", "LITELLM_LOCAL_MODEL_COST_MAP": "True"}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"failed ({done.returncode}): {' '.join(cmd)}\n{done.stderr[-2000:]}")
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def side_by_side(name: str, a: tuple[list[str], Path], b: tuple[list[str], Path], repeat: int) -> dict:
    """Run A and B in turn ``repeat`` times (after one warm-up each); medians and the CPU ratio B / A."""
    timed(*a), timed(*b)
    runs_a, runs_b = [], []
    for _ in range(repeat):
        runs_a.append(timed(*a))
        runs_b.append(timed(*b))
    med = lambda runs, k: statistics.median(r[k] for r in runs)  # noqa: E731
    row = {
        "name": name,
        "a_wall": med(runs_a, 0),
        "a_cpu": med(runs_a, 1),
        "b_wall": med(runs_b, 0),
        "b_cpu": med(runs_b, 1),
    }
    print(
        f"| {name} | {row['a_wall']:.2f} | {row['a_cpu']:.2f} | {row['b_wall']:.2f} | {row['b_cpu']:.2f} | "
        f"{row['b_cpu'] / row['a_cpu']:.1f}× | {row['a_cpu'] - row['b_cpu']:+.2f} | {row['a_wall'] - row['b_wall']:+.2f} |",
        flush=True,
    )
    return row


def lightemma(*args: str) -> list[str]:
    return [sys.executable, "-m", "lightemma", *args]


def stand_ins(root: Path, models: int) -> Path:
    """The reference result folders (reused when ``root`` already holds them)."""
    import bench_import

    results = root / "results"
    if not results.is_dir():
        start = time.perf_counter()
        frames, megabytes = bench_import.write_results(results, models)
        print(
            f"wrote {models} model folder(s) × {frames} frames, {megabytes:.0f} MB, in {time.perf_counter() - start:.0f} s"
        )
    return results


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--anchor", type=Path, required=True, help="the anchor tree's python/ folder (e.g. main's)")
    ap.add_argument(
        "--only", nargs="+", choices=["evaluate", "startup", "import"], default=["evaluate", "startup", "import"]
    )
    ap.add_argument("--models", type=int, default=13, help="stand-in model folders for evaluate (default 13)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--keep", type=Path, help="write the stand-ins here and keep them (reused next time)")
    args = ap.parse_args()
    root = args.keep or Path(tempfile.mkdtemp(prefix="bench-speed-"))
    root.mkdir(parents=True, exist_ok=True)
    anchor = args.anchor.resolve()
    print(
        f"A = this tree ({TREE}), B = anchor ({anchor}); medians of {args.repeat} interleaved runs; "
        f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs\n"
    )
    print("| step | A wall (s) | A CPU (s) | B wall (s) | B CPU (s) | B / A (CPU) | A − B CPU (s) | A − B wall (s) |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    try:
        if "evaluate" in args.only:
            results = stand_ins(root, args.models)
            for tree, out in ((TREE, root / "runs-a"), (anchor, root / "runs-b")):
                if not out.is_dir():
                    timed(lightemma("import", str(results), "--output", str(out), "--quiet"), tree)
            side_by_side(
                f"evaluate, {args.models} runs × 3,908 frames",
                (lightemma("evaluate", str(root / "runs-a")), TREE),
                (lightemma("evaluate", str(root / "runs-b")), anchor),
                args.repeat,
            )
        if "startup" in args.only:
            startup(root, anchor, args.repeat)
        if "import" in args.only:
            folder = next(iter(sorted(stand_ins(root, args.models).iterdir())))
            out_a, out_b = root / "import-a", root / "import-b"
            wipe = "import shutil, sys; shutil.rmtree(sys.argv[1], ignore_errors=True)"
            cmd = lambda out: [  # noqa: E731
                "sh",
                "-c",
                f'"$0" -c "{wipe}" "$1" && exec "$0" -m lightemma import "$2" --output "$1" --quiet --jobs 1',
                sys.executable,
                str(out),
                str(folder),
            ]
            side_by_side(
                "import --jobs 1, one folder × 3,908 frames", (cmd(out_a), TREE), (cmd(out_b), anchor), args.repeat
            )
    finally:
        if args.keep is None:
            shutil.rmtree(root, ignore_errors=True)
    return 0


def startup(root: Path, anchor: Path, repeat: int) -> None:
    """--help, and run --limit 1 (baseline; direct transport) against loading the frames alone."""
    synth = root / "synth"
    if not synth.is_dir():
        subprocess.run(
            lightemma("synth", str(synth), "--scenes", "10", "--keyframes", "40"),
            check=True,
            env={**os.environ, "PYTHONPATH": str(TREE)},
            stdout=subprocess.DEVNULL,
        )
    side_by_side("lightemma --help", (lightemma("--help"), TREE), (lightemma("--help"), anchor), repeat)
    frames = ["--dataroot", str(synth), "--version", "v1.0-mini", "--split", "all"]
    load_only = [
        sys.executable,
        "-c",
        f"import lightemma; lightemma.load_frames({str(synth)!r}, 'v1.0-mini', split='all')",
    ]
    baseline = lightemma(
        "run",
        "--model",
        "baseline:constant",
        *frames,
        "--limit",
        "1",
        "--output",
        str(root / "startup-runs"),
        "--no-progress",
    )
    side_by_side(
        "run baseline --limit 1 (A) vs loading the frames alone (B = A's tree)",
        (baseline, TREE),
        (load_only, TREE),
        repeat,
    )
    side_by_side("run baseline --limit 1", (baseline, TREE), (baseline, anchor), repeat)
    server = subprocess.Popen(
        [sys.executable, str(HERE.parent / "tests" / "support" / "fake_openai.py")],
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": str(TREE)},
    )
    try:
        url = server.stdout.readline().strip()
        direct = lightemma(
            "run",
            "--model",
            "openai/test-model",
            "--api-base",
            url,
            "--transport",
            "direct",
            *frames,
            "--limit",
            "1",
            "--output",
            str(root / "startup-runs"),
            "--no-progress",
        )
        side_by_side(
            "run --transport direct --limit 1 (A) vs loading the frames alone (B = A's tree)",
            (direct, TREE),
            (load_only, TREE),
            repeat,
        )
        side_by_side("run --transport direct --limit 1", (direct, TREE), (direct, anchor), repeat)
    finally:
        server.kill()
        server.wait()


if __name__ == "__main__":
    sys.exit(main())
