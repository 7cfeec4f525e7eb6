"""What a frame's requests send and cost: `independent` vs `conversation`, with and without prompt-cache hits.

For each provider protocol (OpenAI: GPT-4o; Anthropic: Claude-4.6-Sonnet; Gemini: Gemini-2.5-Flash) and each
chain, ``--frames`` frames with 1600 × 900 camera-sized JPEGs run through `lightemma run` against the loopback
server (tests/support/fake_openai.py) in this process, which

* counts every request's tokens (:class:`fake_openai.TokenCounter`: text at 4 UTF-8 bytes per token plus 4 per
  message; each image by its provider's published pixel rule: 1105 tokens at 1600 × 900 for OpenAI, 1844 for
  Anthropic, 1548 for Gemini), and
* with ``cache on``, emulates the provider's prompt cache (:class:`fake_openai.PrefixCache`: OpenAI's automatic
  cache in 128-token steps from 1024 tokens, Gemini's implicit cache from 1024 tokens, Anthropic's explicit
  breakpoints with cache writes) and reports the cached tokens in the provider's own usage fields.

Answers have realistic lengths (a 600-character scene description, a 400-character intent, the actions list).
Reported per frame (means over the frames): image bytes sent (base64, all requests), input tokens, of which
cached, and the cost lightemma records — litellm's bundled list prices with cached and cache-write tokens at
their own prices, i.e. what the provider would bill.

    python benches/bench_requests.py [--frames 200] [--concurrency 16] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("LITELLM_LOCAL_MODEL_COST_MAP", "True")
ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from tests.support.fake_openai import FakeOpenAIServer, Reply, default_reply  # noqa: E402
from tests.support.memframes import make_frames  # noqa: E402

MODELS = (
    ("gpt-4o", "OPENAI_API_KEY"),
    ("claude-4.6-sonnet", "ANTHROPIC_API_KEY"),
    ("gemini-2.5-flash", "GEMINI_API_KEY"),
)
SCENE = (
    "A two-lane urban road in daylight with light traffic. A white delivery van is parked at the right curb about "
    "20 m ahead with its hazard lights on; a cyclist rides in the bike lane to its left. A silver sedan is stopped "
    "at the traffic light at the intersection ahead, which shows green for our direction. Two pedestrians wait at "
    "the crosswalk on the left corner; the lane markings are clear, a dashed white centre line and a solid line at "
    "the curb. Parked cars line the left side of the street and a bus stop with one person waiting is on the right. "
)
INTENT = (
    "The ego vehicle has been cruising at about 5 m/s in its lane with almost zero curvature, neither accelerating "
    "nor braking noticeably. Over the next 3 seconds it should keep its lane, pass the parked van with a little "
    "extra clearance from the cyclist, and accelerate gently toward the green light while watching the crosswalk. "
)


def realistic(req):
    """The default script's answers, at the lengths real models give them."""
    if req.stage == "scene":
        return Reply(SCENE)
    if req.stage == "intent":
        return Reply(INTENT)
    return default_reply(req)


def one(model: str, chain: str, cache: bool, frames, output: Path, concurrency: int) -> dict:
    from lightemma.pipeline import run
    from lightemma.runs.store import read_run

    with FakeOpenAIServer(realistic, count_tokens=True, prefix_cache=cache) as server:
        base = server.url if model.startswith("gpt") else server.root_url
        start = time.perf_counter()
        result = run(
            model,
            api_base=base,
            frames=frames,
            output=output,
            chain=chain,
            concurrency=concurrency,
            progress=False,
            timeout=60.0,
        )
        wall = time.perf_counter() - start
    records = list(read_run(result.run_dir).records.values())
    n = len(records)
    image_chars = sum(
        len(p["data"]) for r in server.requests for _, parts in r.messages() for p in parts if p["kind"] == "image"
    )
    return {
        "model": model,
        "chain": chain,
        "cache": cache,
        "frames": n,
        "requests_per_frame": len(server.requests) / n,
        "image_bytes_per_frame": image_chars / n,
        "input_tokens_per_frame": sum(r["input_tokens"] for r in records) / n,
        "cached_tokens_per_frame": sum(r["cached_input_tokens"] for r in records) / n,
        "cache_write_tokens_per_frame": sum(r["cache_write_tokens"] or 0 for r in records)
        / n,  # OpenAI: none reported (not billed)
        "output_tokens_per_frame": sum(r["output_tokens"] for r in records) / n,
        "cost_cents_per_frame": sum(r["cost_cents"] for r in records) / n,
        "ok": sum(r["status"] == "ok" for r in records),
        "wall_s": wall,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--concurrency", type=int, default=16)
    parser.add_argument("--json", help="write the rows here")
    args = parser.parse_args(argv)
    for _, variable in MODELS:
        os.environ.setdefault(variable, "bench-key-not-secret-0123456789")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        frames = make_frames(Path(tmp), args.frames, image_size=(1600, 900))
        for model, _ in MODELS:
            for chain in ("independent", "conversation"):
                for cache in (False, True):
                    row = one(model, chain, cache, frames, Path(tmp) / "runs", args.concurrency)
                    rows.append(row)
                    print(json.dumps(row), file=sys.stderr, flush=True)
    print(f"{args.frames} frames, 1600 × 900 JPEG per frame, concurrency {args.concurrency}\n")
    print(
        "| model | chain | cache hits | image bytes/frame | input tokens/frame | of which cached | cache writes | "
        "output tokens/frame | cost/frame (¢) |"
    )
    print("|---|---|---|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(
            f"| {r['model']} | {r['chain']} | {'yes' if r['cache'] else 'no'} | {r['image_bytes_per_frame'] / 1e3:,.0f} kB | "
            f"{r['input_tokens_per_frame']:,.0f} | {r['cached_tokens_per_frame']:,.0f} "
            f"({100 * r['cached_tokens_per_frame'] / r['input_tokens_per_frame']:.0f} %) | {r['cache_write_tokens_per_frame']:,.0f} | "
            f"{r['output_tokens_per_frame']:,.0f} | {r['cost_cents_per_frame']:.3f} |"
        )
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
