"""Benchmark: frames/s of the whole three-stage chain with 1, 2, 4, … model replicas over Ray.

Runs ``lightemma.pipeline.run`` over the same frames

* in one process without Ray (the baseline the replicas must not lose to at N = 1), and
* with N replicas as Ray actors (``--replicas N``) for each N of ``--replicas``, frames in
  flight = batch size × N so that every replica can fill its batches,

and reports frames/s (wall time of the frames; starting Ray and loading the models excluded),
the speed-up over one Ray replica, the scaling efficiency (speed-up / N; the target on a GPU
machine is ≥ 0.8) and whether each row's answers equal the in-process answers under greedy
decoding. One local Ray is started for all rows (or ``--ray-address`` joins a cluster).

Without a GPU it uses a tiny random-weight Qwen2-VL built offline (tests/support/local_models.py) on
small synthetic images, one CPU per replica, and says so: on a 2-core machine the driver
(chain, parsing, Ray's own processes) shares the cores with the replicas, so two replicas
cannot reach 2×. On a GPU machine, one GPU per replica:

    HF_HUB_OFFLINE=1 python benches/bench_ray.py --model Qwen/Qwen2.5-VL-7B-Instruct --replicas 1 2 4 8 \\
        --frames 512 --batch-size 16 [--dataroot /data/nuscenes --version v1.0-test --split test]
    python benches/bench_ray.py --backend vllm --model Qwen/Qwen2.5-VL-7B-Instruct --replicas 1 2 4 8 \\
        --frames 1024 --batch-size 64          # in the vLLM environment (pip install 'lightemma[vllm,ray]')
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import tempfile
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from bench_local import add_model_and_frames_arguments, device_name, model_and_frames  # noqa: E402


def run_row(
    model: str,
    frames: Any,
    output: Path,
    *,
    backend: str,
    replicas: int | None,
    address: str | None,
    batch_size: int,
    max_tokens: int,
    max_attempts: int,
    options: dict[str, Any],
) -> dict[str, Any]:
    """One row: ``replicas`` None = in process, else N Ray replicas (joining ``address``)."""
    from lightemma.pipeline import run
    from lightemma.runs.store import read_run

    n = replicas or 1
    placement = {} if replicas is None else {"replicas": replicas, "ray_address": address}
    result = run(
        model,
        backend=backend,
        frames=frames,
        output=output,
        concurrency=batch_size * n,
        max_tokens=max_tokens,
        max_attempts=max_attempts,
        progress=False,
        backend_options={"batch_size": batch_size, **options},
        **placement,
    )
    s = result.summary
    records = read_run(result.run_dir).records
    report = result.manifest["sessions"][-1].get("replicas") or {}
    return {
        "where": "in process" if replicas is None else f"Ray, {replicas} replica(s)",
        "replicas": replicas,
        "frames": s["frames_run"],
        "wall_s": round(s["wall_seconds"], 3),
        "frames_per_s": s["frames_per_second"],
        "frames_per_replica": report.get("frames"),
        "answers": {
            fid: [(c["stage"], c["text"]) for a in r["attempts"] for c in a["calls"]] for fid, r in records.items()
        },
    }


def table(rows: list[dict[str, Any]], device: str, model: str, note: str) -> str:
    base = next((r["frames_per_s"] for r in rows if r["replicas"] == 1), None)
    lines = [
        f"device: {device}",
        f"model: {model}{note}",
        "",
        "| where | frames | wall s | frames/s | speed-up vs 1 replica | efficiency (speed-up / N) | frames per replica | "
        "answers = in process |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        same = "yes" if r["answers"] == rows[0]["answers"] else "no"
        if r["replicas"] is None or base is None:
            speedup = efficiency = "—"
        else:
            speedup = f"{r['frames_per_s'] / base:.2f}×"
            efficiency = f"{r['frames_per_s'] / base / r['replicas']:.2f}"
        spread = "/".join(str(n) for n in r["frames_per_replica"]) if r["frames_per_replica"] else "—"
        lines.append(
            f"| {r['where']} | {r['frames']} | {r['wall_s']:.2f} | {r['frames_per_s']:.2f} | {speedup} | {efficiency} | "
            f"{spread} | {same} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_model_and_frames_arguments(ap, frames=32)
    ap.add_argument("--backend", choices=("hf", "vllm"), default="hf")
    ap.add_argument("--replicas", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--ray-address", help="join this Ray cluster (default: start a local Ray sized to the largest N)")
    ap.add_argument("--batch-size", type=int, default=8, help="requests per forward pass in each replica (default 8)")
    ap.add_argument(
        "--no-in-process", action="store_true", help="skip the in-process row (e.g. a model too big for this node)"
    )
    args = ap.parse_args(argv)

    import ray

    device, on_gpu = device_name()
    if not on_gpu:
        import torch

        torch.set_num_threads(1)  # as each CPU replica runs (Ray sets OMP_NUM_THREADS=1 for a 1-CPU actor)
        device += ", 1 torch thread per replica and in process"
    if args.ray_address:
        ray.init(address=args.ray_address, logging_level=logging.WARNING)
    else:
        cpus = max(args.replicas) if not on_gpu else max(os.cpu_count() or 1, max(args.replicas))
        ray.init(
            num_cpus=cpus, include_dashboard=False, object_store_memory=256 * 1024**2, logging_level=logging.WARNING
        )
    address = ray.get_runtime_context().gcs_address
    with tempfile.TemporaryDirectory(prefix="lightemma-bench-ray-") as tmp:
        tmp_path = Path(tmp)
        model, frames, note = model_and_frames(
            args, tmp_path, on_gpu, measures="the replica machinery", scripted_end=True
        )
        common = dict(
            backend=args.backend,
            address=address,
            batch_size=args.batch_size,
            max_tokens=args.max_tokens,
            max_attempts=args.max_attempts,
            options={} if args.backend == "vllm" else {"dtype": args.dtype},
        )
        rows = [] if args.no_in_process else [run_row(model, frames, tmp_path / "out", replicas=None, **common)]
        for n in args.replicas:
            rows.append(run_row(model, frames, tmp_path / "out", replicas=n, **common))
        print(table(rows, device, model, note))
        print(
            f"\nsettings: {args.backend}, {len(frames)} frames, batch size {args.batch_size} per replica, frames in flight = "
            f"batch size × replicas, max {args.max_tokens} output tokens per stage, {args.max_attempts} attempt(s) per frame, "
            f"greedy; Ray {ray.__version__} ({'joined ' + args.ray_address if args.ray_address else 'local'}); "
            "starting Ray and loading the models excluded"
        )
        if args.json:
            print(json.dumps([{k: v for k, v in r.items() if k != "answers"} for r in rows], indent=2))
    ray.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
