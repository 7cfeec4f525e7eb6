"""Benchmark: frames for a synthetic dataset the size of nuScenes v1.0-test.

Writes (once, tables only, no images) 150 scenes x 40 keyframes with CAM_FRONT
sweeps, then reports separately:

* lightemma's table read (``lightemma.nuscenes.load_tables``: the JSON tables, indexed as the devkit does),
  and, where nuscenes-devkit is installed, the devkit's own ``NuScenes(...)`` load for comparison,
* lightemma's frame extraction (``extract_frames``: scene chains, windows, geometry,
  image existence checks) — wall time (best of ``--repeat``) and peak Python/NumPy
  memory (tracemalloc, a separate run).

Target: extraction under 2 s on top of the table read.

    PYTHONPATH=python python benches/bench_frames.py [--scenes 150] [--keyframes 40] [--root DIR] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
import tracemalloc

VERSION = "v1.0-test"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", type=int, default=150)
    ap.add_argument("--keyframes", type=int, default=40)
    ap.add_argument("--root", help="dataset folder to reuse or create (default: a temporary folder)")
    ap.add_argument("--repeat", type=int, default=3, help="extraction runs; the best is reported")
    ap.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = ap.parse_args(argv)

    import logging

    from lightemma.nuscenes import extract_frames, load_tables

    logging.getLogger("lightemma.frames").setLevel(logging.ERROR)  # no images on purpose
    from lightemma.synth import write_dataset

    tmp = None
    root = args.root
    if root is None:
        tmp = tempfile.TemporaryDirectory(prefix="lightemma-bench-")
        root = tmp.name
    gen_s = None
    if not os.path.isfile(os.path.join(root, VERSION, "scene.json")):
        t0 = time.perf_counter()
        write_dataset(root, scenes=args.scenes, keyframes=args.keyframes, version=VERSION, images=False, seed=0)
        gen_s = time.perf_counter() - t0

    t0 = time.perf_counter()
    tables = load_tables(root, VERSION)
    load_s = time.perf_counter() - t0
    devkit_s = None
    try:
        from nuscenes.nuscenes import NuScenes  # import cost is not table load time
    except ImportError:
        NuScenes = None
    if NuScenes is not None:
        t0 = time.perf_counter()
        NuScenes(version=VERSION, dataroot=root, verbose=False)
        devkit_s = time.perf_counter() - t0

    times = []
    fs = None
    for _ in range(max(1, args.repeat)):
        t0 = time.perf_counter()
        fs = extract_frames(tables, split="all", on_missing_image="keep")
        times.append(time.perf_counter() - t0)
    assert fs is not None

    tracemalloc.start()
    extract_frames(tables, split="all", on_missing_image="keep")
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()

    figures = {
        "scenes": args.scenes,
        "keyframes_per_scene": args.keyframes,
        "frames": len(fs),
        "cam_front_keyframes": len(tables.sample_data),
        "generate_s": None if gen_s is None else round(gen_s, 2),
        "table_read_s": round(load_s, 3),
        "devkit_table_load_s": None if devkit_s is None else round(devkit_s, 3),
        "extraction_s_best": round(min(times), 3),
        "extraction_s_runs": [round(t, 3) for t in times],
        "extraction_peak_mib": round(peak / 2**20, 1),
        "target_extraction_s": 2.0,
        "python": platform.python_version(),
        "cpu_count": os.cpu_count(),
    }
    if args.json:
        print(json.dumps(figures, indent=2))
    else:
        print(
            f"synthetic {VERSION}-sized dataset: {args.scenes} scenes x {args.keyframes} keyframes, "
            f"{figures['cam_front_keyframes']} CAM_FRONT keyframes -> {len(fs)} frames (reference window)"
        )
        if gen_s is not None:
            print(f"  generate tables (no images):   {gen_s:7.2f} s")
        print(f"  lightemma table read:          {load_s:7.3f} s")
        if devkit_s is not None:
            print(f"  devkit table load (NuScenes):  {devkit_s:7.3f} s (for comparison; not used)")
        print(
            f"  lightemma frame extraction:    {min(times):7.3f} s best of {len(times)} "
            f"(target < 2 s)  runs: {', '.join(f'{t:.3f}' for t in times)}"
        )
        print(f"  extraction peak memory:        {peak / 2**20:7.1f} MiB (tracemalloc)")
    if tmp is not None:
        tmp.cleanup()
    return 0 if min(times) < 2.0 else 1


if __name__ == "__main__":
    sys.exit(main())
