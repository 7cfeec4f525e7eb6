"""Benchmark ``lightemma evaluate`` on large synthetic runs: time and peak memory.

Writes synthetic runs of N frame records (JSONL as docs/definitions.md#run-records says, ~2 kB a line with
short stage texts) and, each in a fresh subprocess so that peak RSS is clean,
measures:

* ``json``     — only reading the file and ``json.loads`` of every line (the floor);
* ``evaluate`` — ``evaluate_runs(run, convention="all")``: streaming load into
  columns, metrics of all three conventions through the Rust core, FE and
  efficiency accounting.

Peak memory is the subprocess's max RSS minus that of a process that only
imported lightemma and NumPy. Usage::

    python benches/bench_evaluate.py                 # N = 1e5 and 1e6
    python benches/bench_evaluate.py --frames 200000 --keep /tmp/bench-runs
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CHILD = r"""
import json, resource, sys, time
import numpy, lightemma
from lightemma.evaluation import evaluate_runs
mode, run_dir = sys.argv[1], sys.argv[2]
start = time.perf_counter()
if mode == "json":
    n = 0
    with open(run_dir + "/frames.jsonl", "rb") as fh:
        for line in fh:
            json.loads(line)
            n += 1
    result = n
elif mode == "evaluate":
    ev = evaluate_runs([run_dir], convention="all")
    result = ev.models[0].frames_in_run
else:
    result = 0
seconds = time.perf_counter() - start
print(json.dumps({"seconds": seconds, "maxrss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, "frames": result}))
"""


def measure(mode: str, run_dir: Path) -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, mode, str(run_dir)], check=True, capture_output=True, text=True)
    return json.loads(out.stdout)


def main() -> int:
    from lightemma.evaluation.synthetic import write_synthetic_run

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, nargs="+", default=[100_000, 1_000_000])
    parser.add_argument("--keep", type=Path, help="write the runs here and keep them (default: a temporary folder)")
    args = parser.parse_args()
    root = args.keep or Path(tempfile.mkdtemp(prefix="bench-evaluate-"))
    try:
        base = measure("import", root)["maxrss_mb"]
        print(f"baseline process (python + numpy + lightemma): {base:.0f} MB RSS")
        print(
            f"{'frames':>10} {'file MB':>8} {'write s':>8} {'json s':>8} {'eval s':>8} {'eval/json':>9} {'json MB':>8} {'eval MB':>8} {'B/frame':>8}"
        )
        for n in args.frames:
            start = time.perf_counter()
            run_dir = write_synthetic_run(root, f"bench/model-{n}", n, seed=1)
            written = time.perf_counter() - start
            size = (run_dir / "frames.jsonl").stat().st_size / 1e6
            js = measure("json", run_dir)
            ev = measure("evaluate", run_dir)
            assert ev["frames"] == js["frames"] == n, (ev, js)
            extra = ev["maxrss_mb"] - base
            print(
                f"{n:>10} {size:>8.0f} {written:>8.1f} {js['seconds']:>8.1f} {ev['seconds']:>8.1f} {ev['seconds'] / js['seconds']:>9.2f} "
                f"{js['maxrss_mb'] - base:>8.0f} {extra:>8.0f} {extra * 1e6 / n:>8.0f}",
                flush=True,
            )
    finally:
        if args.keep is None:
            shutil.rmtree(root, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
