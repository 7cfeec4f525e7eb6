"""Benchmark: local-model throughput of the whole three-stage chain, batch size 1 vs batched hf vs vLLM.

Runs ``lightemma.pipeline.run`` over the same frames with

* ``hf`` at batch size 1, one frame at a time (the paper's way),
* ``hf`` micro-batched at each ``--batch-sizes`` value (frames in flight = batch size),
* ``vllm`` at the largest batch size, where vLLM is installed and a GPU is present,

and reports frames/s (wall time of the frames, model loading excluded), mean seconds
per frame, tokens per frame, **calls per frame** and the share of frames that went
through all three stages, and whether each configuration's answers equal batch
size 1's under greedy decoding. The device is named in the output.

A frame is three-stage work only when every stage's answer ends: a stage cut off at
``--max-tokens`` stops its frame (docs/run.md). The tiny random-weight model never
ends an answer by itself, so without ``--model`` it is first taught a scripted end
(tests/support/local_models.py ``teach_to_answer``: 300 Adam steps on the first frame's three
prompts, to answer each with a strict action list and its end-of-turn token); the table
says so, and a row whose frames did not all make 3 calls is flagged as not measuring the chain.

On a GPU, pass a real checkpoint (``--model Qwen/Qwen2.5-VL-7B-Instruct``) and
frames (``--dataroot``/``--version``/``--split``, default: a synthetic set at
nuScenes' 1600×900). Without a GPU it uses a tiny random-weight Qwen2-VL built
offline (tests/support/local_models.py) on small synthetic images, and says so: those
figures measure the batching machinery, not a real model.
Target on a GPU: batched ≥ 10× the batch-1 throughput.

    HF_HUB_OFFLINE=1 python benches/bench_local.py [--model M] [--frames 16] [--batch-sizes 8 16]
        [--max-tokens 64] [--dataroot DIR --version V --split S] [--no-vllm] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent


def device_name() -> tuple[str, bool]:
    """(what runs the model, whether it is a GPU)."""
    import torch

    if torch.cuda.is_available():
        n = torch.cuda.device_count()
        return f"{n}× {torch.cuda.get_device_name(0)} (torch {torch.__version__})", True
    return (
        f"CPU: {platform.processor() or platform.machine()}, {os.cpu_count()} cores (torch {torch.__version__})",
        False,
    )


def vllm_missing(on_gpu: bool) -> str | None:
    """Why vLLM cannot be benchmarked here (None when it can)."""
    if not on_gpu:
        return "no GPU"
    try:
        import vllm  # noqa: F401
    except ImportError:
        return "vllm not installed (pip install 'lightemma[vllm]' in its own environment)"
    return None


def synthetic_frames(root: Path, n_frames: int, image_size: tuple[int, int]) -> Any:
    """``n_frames`` reference frames from synthetic scenes of 30 keyframes (16 frames each)."""
    from lightemma import load_frames
    from lightemma.nuscenes import window_range
    from lightemma.synth import write_dataset

    keyframes = 30
    scenes = -(-n_frames // len(window_range(keyframes, "reference")))
    write_dataset(root, scenes=scenes, keyframes=keyframes, image_size=image_size, sweeps=False)
    return load_frames(root, "v1.0-mini", split="all").head(n_frames)


SCRIPTED_ANSWER = "[(5.0, 0.0), (5.0, 0.0), (5.0, 0.0), (5.0, 0.0), (5.0, 0.0), (5.0, 0.0)]"
TEACHING_STEPS = (
    300  # Adam steps: enough for the tiny model to say the whole list and end (50 suffice for a short phrase)
)


def tiny_checkpoint(root: Path, frames: Any = None) -> str:
    """A tiny random-weight Qwen2-VL; with ``frames``, taught to end every stage's answer (:data:`SCRIPTED_ANSWER`)."""
    sys.path.insert(0, str(HERE.parent))
    from tests.support.local_models import build_tiny_model, teach_to_answer

    path = build_tiny_model("qwen2_vl", root / "tiny-qwen2-vl")
    if frames is not None:
        from lightemma.frames import history_placeholders
        from lightemma.prompts import load_prompt_set

        prompts = load_prompt_set()
        history = history_placeholders(frames[0].history_actions)
        texts = [
            prompts.render("scene"),
            prompts.render("intent", scene=SCRIPTED_ANSWER, **history),
            prompts.render("actions", scene=SCRIPTED_ANSWER, intent=SCRIPTED_ANSWER, **history),
        ]
        teach_to_answer(path, SCRIPTED_ANSWER, prompts=texts, image=frames[0].image_path, steps=TEACHING_STEPS)
    return str(path)


def add_model_and_frames_arguments(ap: argparse.ArgumentParser, *, frames: int) -> None:
    """The options :func:`model_and_frames` reads, and the chain settings every row of a local benchmark shares."""
    ap.add_argument("--model", help="checkpoint or hub id (default: a real Qwen2.5-VL-7B on GPU, a tiny model on CPU)")
    ap.add_argument("--dataroot", help="nuScenes directory (default: a synthetic set)")
    ap.add_argument("--version", default="v1.0-mini")
    ap.add_argument("--split", default="all")
    ap.add_argument("--frames", type=int, default=frames)
    ap.add_argument("--max-tokens", type=int, default=64, help="output tokens per stage (default 64)")
    ap.add_argument(
        "--max-attempts", type=int, default=1, help="attempts per frame (default 1: the same work for every row)"
    )
    ap.add_argument("--dtype", default="auto")
    ap.add_argument("--json", action="store_true", help="print the rows as JSON too")


def model_and_frames(
    args: argparse.Namespace, tmp_path: Path, on_gpu: bool, *, measures: str, scripted_end: bool = False
) -> tuple[str, Any, str]:
    """The checkpoint (``--model``; else a tiny random-weight Qwen2-VL on CPU, Qwen2.5-VL-7B on GPU), the frames
    (``--dataroot``; else synthetic ones) and a note for the table when the model is the tiny one.

    ``scripted_end`` teaches the tiny model to end its answers, so that every frame runs all three stages."""
    if args.dataroot:
        from lightemma import load_frames

        frames = load_frames(args.dataroot, args.version, split=args.split).head(args.frames)
    else:
        frames = synthetic_frames(tmp_path / "synth", args.frames, (1600, 900) if on_gpu else (64, 48))
    model, note = args.model, ""
    if model is None and not on_gpu:
        model = tiny_checkpoint(tmp_path, frames if scripted_end else None)
        note = f" — a tiny random-weight Qwen2-VL (~85k parameters) on CPU: measures {measures}, not a real model"
        if scripted_end:
            note += "; taught a scripted end (every stage answers a strict action list, then its end token)"
    elif model is None:
        model = "Qwen/Qwen2.5-VL-7B-Instruct"
    return model, frames, note


def run_config(
    model: str,
    frames: Any,
    output: Path,
    *,
    backend: str,
    batch_size: int,
    max_tokens: int,
    max_attempts: int,
    options: dict[str, Any],
) -> dict[str, Any]:
    """One benchmark row: the run's throughput and its answers (frame id -> stage texts)."""
    from lightemma.pipeline import run
    from lightemma.runs.store import read_run

    result = run(
        model,
        backend=backend,
        frames=frames,
        output=output,
        concurrency=batch_size,
        max_tokens=max_tokens,
        max_attempts=max_attempts,
        progress=False,
        backend_options={"batch_size": batch_size, **options},
    )
    s = result.summary
    records = read_run(result.run_dir).records
    calls = [sum(len(a.get("calls") or []) for a in r.get("attempts") or []) for r in records.values()]
    three_stage = sum(
        1 for r in records.values() for a in (r.get("attempts") or [])[:1] if len(a.get("calls") or []) == 3
    )
    return {
        "calls_per_frame": sum(calls) / len(calls) if calls else 0.0,
        "three_stage_frames": three_stage,
        "backend": backend,
        "batch_size": batch_size,
        "frames": s["frames_run"],
        "wall_s": round(s["wall_seconds"], 3),
        "frames_per_s": s["frames_per_second"],
        "s_per_frame": s["mean_seconds_per_frame"],
        "in_tokens": s["mean_input_tokens"],
        "out_tokens": s["mean_output_tokens"],
        "answers": {fid: (r["scene_text"], r["intent_text"], r["answer"]) for fid, r in records.items()},
    }


def table(rows: list[dict[str, Any]], device: str, model: str, note: str) -> str:
    base = rows[0]["frames_per_s"]
    lines = [
        f"device: {device}",
        f"model: {model}{note}",
        "",
        "| backend | batch size | frames | frames/s | speed-up | s/frame (chain) | calls/frame | 3-stage frames "
        "| in tok/frame | out tok/frame | answers = batch 1 |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        same = "yes" if r["answers"] == rows[0]["answers"] else "no"
        lines.append(
            f"| {r['backend']} | {r['batch_size']} | {r['frames']} | {r['frames_per_s']:.3f} | "
            f"{r['frames_per_s'] / base:.1f}× | {r['s_per_frame']:.2f} | {r['calls_per_frame']:.2f} | "
            f"{r['three_stage_frames']}/{r['frames']} | {r['in_tokens']:.0f} | {r['out_tokens']:.0f} | {same} |"
        )
    partial = [r for r in rows if r["three_stage_frames"] < r["frames"]]
    if partial:
        lines.append(
            f"\nWARNING: {len(partial)} row(s) did not run every frame through all three stages (a stage was cut off "
            "at --max-tokens): their frames/s are not three-stage frames"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_model_and_frames_arguments(ap, frames=16)
    ap.add_argument("--batch-sizes", type=int, nargs="+", default=[8, 16])
    ap.add_argument(
        "--threads",
        type=int,
        help="torch intra-op threads (default: 1 on CPU, where the tiny model is "
        "overhead-bound and more threads only add contention; torch's default on GPU)",
    )
    ap.add_argument("--no-vllm", action="store_true")
    args = ap.parse_args(argv)

    device, on_gpu = device_name()
    import torch

    threads = args.threads or (None if on_gpu else 1)
    if threads:
        torch.set_num_threads(threads)
        device += f", {threads} torch thread(s)"
    with tempfile.TemporaryDirectory(prefix="lightemma-bench-local-") as tmp:
        tmp_path = Path(tmp)
        model, frames, note = model_and_frames(args, tmp_path, on_gpu, measures="batching", scripted_end=True)
        common = dict(max_tokens=args.max_tokens, max_attempts=args.max_attempts)
        hf_options = {"dtype": args.dtype}
        rows = [run_config(model, frames, tmp_path / "out", backend="hf", batch_size=1, options=hf_options, **common)]
        for b in args.batch_sizes:
            rows.append(
                run_config(model, frames, tmp_path / "out", backend="hf", batch_size=b, options=hf_options, **common)
            )
        why_not = "--no-vllm" if args.no_vllm else vllm_missing(on_gpu)
        if why_not is None:
            rows.append(
                run_config(
                    model,
                    frames,
                    tmp_path / "out",
                    backend="vllm",
                    batch_size=max(args.batch_sizes),
                    options={},
                    **common,
                )
            )
        print(table(rows, device, model, note))
        print(f"\nvllm: {'measured' if why_not is None else 'not measured — ' + why_not}")
        print(
            f"settings: {len(frames)} frames, max {args.max_tokens} output tokens per stage, {args.max_attempts} attempt(s) "
            "per frame, greedy; frames in flight = batch size; model loading excluded"
        )
        if args.json:
            print(json.dumps([{k: v for k, v in r.items() if k != "answers"} for r in rows], indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
