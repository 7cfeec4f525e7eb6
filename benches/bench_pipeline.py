"""Benchmark of `lightemma run` over the API backend against the loopback server.

3,908 synthetic frames (the paper's v1.0-test count), a scripted OpenAI-compatible
server in a separate process answering every call after ``--latency`` seconds,
``--concurrency`` frames in flight. Reports wall time, frames/s, efficiency =
achieved frames/s ÷ (concurrency ÷ (3 × latency)) — the ideal when every frame
needs three sequential calls — lightemma's own CPU time per frame (this
process only; the server runs elsewhere), and resident memory over the run.

Process CPU includes litellm's per-call work (request building, logging,
cost); lightemma's own share is measured separately by the same run over an
in-process backend that answers instantly (``pipeline_cpu_ms_per_frame``).

    python benches/bench_pipeline.py [--frames 3908] [--latency 1.0] [--concurrency 64] [--transport litellm|direct]
                                        [--image-size 1600x900] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("LITELLM_LOCAL_MODEL_COST_MAP", "True")
ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from tests.support.memframes import make_frames  # noqa: E402


def rss_mib() -> float:
    """Resident set size of this process in MiB (Linux)."""
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


class MemorySampler(threading.Thread):
    """Samples RSS every ``interval`` seconds until stopped."""

    def __init__(self, interval: float = 1.0) -> None:
        super().__init__(daemon=True)
        self.interval = interval
        self.samples: list[tuple[float, float]] = []
        self._halt = threading.Event()

    def run(self) -> None:
        start = time.perf_counter()
        while not self._halt.is_set():
            self.samples.append((time.perf_counter() - start, rss_mib()))
            self._halt.wait(self.interval)

    def stop(self) -> None:
        self._halt.set()
        self.join()


from lightemma.backends import Backend  # noqa: E402


class InstantBackend(Backend):
    """Answers every stage at once with the loopback server's default texts (no HTTP, no litellm)."""

    name = "instant"

    @property
    def info(self):
        return {"kind": "instant"}

    async def generate(self, requests):
        import asyncio

        from lightemma.backends import ChatResult
        from tests.support.fake_openai import GOOD_ACTIONS, INTENT_TEXT, SCENE_TEXT

        await asyncio.sleep(0)
        texts = {"scene": SCENE_TEXT, "intent": INTENT_TEXT, "actions": GOOD_ACTIONS}
        return [ChatResult(text=texts[r.stage], input_tokens=1000, output_tokens=50, cost_cents=0.3) for r in requests]

    async def aclose(self) -> None:
        pass


def pipeline_cpu_ms_per_frame(frames, output: Path, concurrency: int) -> float:
    """CPU per frame of lightemma alone: chain, parse, integrate, records, summary — over an instant backend."""
    import lightemma.pipeline.runner as runner

    original = runner.run_backend
    runner.run_backend = lambda *args, **kwargs: InstantBackend()
    try:
        cpu0 = time.process_time()
        runner.run(
            "openai/bench-model",
            api_base="http://unused",
            frames=frames,
            output=output,
            concurrency=concurrency,
            progress=False,
        )
        return 1000 * (time.process_time() - cpu0) / len(frames)
    finally:
        runner.run_backend = original


def start_server(latency: float) -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen(
        [sys.executable, str(ROOT / "tests" / "support" / "fake_openai.py"), "--latency", str(latency)],
        stdout=subprocess.PIPE,
        text=True,
    )
    url = proc.stdout.readline().strip()
    if not url.startswith("http"):
        proc.kill()
        raise RuntimeError("the loopback server did not start")
    return proc, url


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=3908)
    parser.add_argument("--latency", type=float, default=1.0)
    parser.add_argument("--concurrency", type=int, default=64)
    parser.add_argument(
        "--transport",
        choices=("litellm", "direct"),
        default="litellm",
        help="litellm (default) or the direct aiohttp client for OpenAI-compatible servers",
    )
    parser.add_argument("--image-size", help="camera-sized JPEGs, e.g. 1600x900 (default: 8x8 images)")
    parser.add_argument("--json", help="also write the figures to this file")
    args = parser.parse_args(argv)

    from lightemma.pipeline import run

    server, url = start_server(args.latency)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            tmp = Path(tmp)
            (tmp / "img").mkdir()
            size = tuple(int(v) for v in args.image_size.lower().split("x")) if args.image_size else None
            frames = make_frames(tmp / "img", args.frames, image_size=size)
            image_kib = sum(os.path.getsize(f.image_path) for f in frames) / len(frames) / 1024
            # warm-up: imports, litellm's first-call setup (not timed)
            run(
                "openai/bench-model",
                api_base=url,
                frames=frames[:2],
                output=tmp / "warm",
                concurrency=2,
                progress=False,
                transport=args.transport,
            )
            sampler = MemorySampler()
            sampler.start()
            cpu0, wall0 = time.process_time(), time.perf_counter()
            result = run(
                "openai/bench-model",
                api_base=url,
                frames=frames,
                output=tmp / "runs",
                concurrency=args.concurrency,
                progress=False,
                timeout=60.0,
                transport=args.transport,
            )
            wall = time.perf_counter() - wall0
            cpu = time.process_time() - cpu0
            sampler.stop()
            own_ms = pipeline_cpu_ms_per_frame(frames, tmp / "instant", args.concurrency)
    finally:
        server.kill()
        server.wait()

    fps = args.frames / wall
    ideal = args.concurrency / (3 * args.latency)
    rss = [r for _, r in sampler.samples]
    quarter = max(1, len(rss) // 4)
    figures = {
        "frames": args.frames,
        "transport": args.transport,
        "image_kib": round(image_kib, 1),
        "latency_s": args.latency,
        "concurrency": args.concurrency,
        "wall_s": round(wall, 2),
        "frames_per_s": round(fps, 3),
        "ideal_frames_per_s": round(ideal, 3),
        "efficiency": round(fps / ideal, 4),
        "cpu_ms_per_frame": round(1000 * cpu / args.frames, 3),
        "pipeline_cpu_ms_per_frame": round(own_ms, 3),
        "rss_mib_first_quarter_mean": round(float(np.mean(rss[:quarter])), 1),
        "rss_mib_last_quarter_mean": round(float(np.mean(rss[-quarter:])), 1),
        "rss_mib_peak": round(max(rss), 1),
        "ok_frames": result.summary["ok"],
        "failed_frames": result.summary["failed"],
        "api_errors": result.summary["api_errors"],
        "cpu_count": os.cpu_count(),
        "python": sys.version.split()[0],
    }
    print(json.dumps(figures, indent=2))
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
