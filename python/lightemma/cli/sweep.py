"""``lightemma sweep``: one model over the same frames under several input variants, resumable (docs/run.md#sweeps)."""

from __future__ import annotations

import argparse


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "sweep",
        help="run a model over the same frames under several input variants (clean, corruptions, ablations), resumable",
        description="Run one model over one frame set under each variant of --inputs (clean, no-image, blank-image, "
        "no-history, corrupt:NAME@SEVERITY, history-noise@SIGMA[,SIGMA_K], history-stale@K): one run directory per "
        "variant under --out, linked in OUT/sweep.json. The same command again resumes unfinished variants and skips "
        "finished ones. `lightemma evaluate OUT` then shows the robustness table (each variant paired with the clean "
        "run). Exit status: 0 done, 2 stopped or refused.",
    )
    p.add_argument("--model", required=True, help="registry name, or litellm model string (not a baseline)")
    p.add_argument(
        "--inputs",
        required=True,
        metavar="V1,V2,…",
        help="the variants, comma-separated; must include clean (e.g. clean,corrupt:fog@3,corrupt:fog@5,no-image)",
    )
    p.add_argument(
        "--out", required=True, metavar="DIR", help="the sweep folder (new, empty, or this sweep's to resume it)"
    )
    p.add_argument("--backend", choices=("api", "hf", "vllm"), help="override the backend chosen from the model")
    p.add_argument("--api-base", help="OpenAI-compatible endpoint (as `lightemma run --api-base`)")
    p.add_argument("--api-key-env", metavar="NAME", help="the environment variable holding the key to send")
    p.add_argument(
        "--price",
        nargs=2,
        type=float,
        metavar=("IN", "OUT"),
        help="USD per million input / output tokens of a model served from --api-base",
    )
    data = p.add_argument_group("frames (the same for every variant)")
    data.add_argument("--dataroot", required=True, help="nuScenes directory")
    data.add_argument("--version", default="v1.0-test", help="nuScenes version (default v1.0-test)")
    data.add_argument("--split", help="scenes of the version (a devkit split or all)")
    data.add_argument("--scenes", nargs="+", metavar="SCENE", help="explicit scene names")
    data.add_argument(
        "--window", choices=("reference", "full"), default="reference", help="frame window (default reference)"
    )
    data.add_argument("--limit", type=int, help="only the first N frames")
    data.add_argument(
        "--sample", type=int, metavar="N", help="a reproducible sample of N frames spread over the scenes"
    )
    data.add_argument("--sample-seed", type=int, metavar="S", help="seed of --sample (default 0)")
    data.add_argument(
        "--on-bad-record", choices=("skip", "error"), default="skip", help="a scene with an unusable record"
    )
    ex = p.add_argument_group("execution (may change when the sweep is resumed)")
    ex.add_argument("--concurrency", type=int, help="frames in flight at once (default 16)")
    ex.add_argument("--timeout", type=float, help="deadline per call in seconds (default 120)")
    ex.add_argument("--rpm", type=float, help="client-side limit: requests per minute")
    ex.add_argument("--tpm", type=float, help="client-side limit: tokens per minute")
    ex.add_argument(
        "--cache",
        nargs="?",
        const=True,
        default=None,
        metavar="PATH",
        help="one SQLite response cache for every variant (default path OUT/cache.sqlite)",
    )
    ex.add_argument("--no-progress", action="store_true", help="no progress bar")
    paid = p.add_argument_group("paid runs")
    paid.add_argument(
        "--estimate",
        action="store_true",
        help="print the whole sweep's expected bill (per variant and "
        "in all) without calling or writing anything, and exit",
    )
    paid.add_argument(
        "--max-cost",
        type=float,
        metavar="CENTS",
        help="the whole sweep's limit in US cents: refused "
        "before any call when the sweep is estimated above it; each variant's run stops (resumable) before "
        "the sweep's total would pass it",
    )
    paid.add_argument(
        "--batch", action="store_true", help="through the provider's batch API (as `lightemma run --batch`)"
    )
    gen = p.add_argument_group("prompting (the same for every variant)")
    gen.add_argument("--prompt-set", help="prompt set name or JSON file")
    gen.add_argument("--temperature", type=float, help="sampling temperature (default 0)")
    gen.add_argument("--max-tokens", type=int, help="max output tokens per stage (default 512)")
    gen.add_argument("--max-retries", type=int, help="retries per call (default 6)")
    gen.add_argument("--backoff", type=float, help="base of the exponential backoff in seconds (default 1)")
    gen.add_argument(
        "--reask", choices=("actions", "chain"), help="on a failed answer re-ask stage 3 or the whole chain"
    )
    gen.add_argument("--max-attempts", type=int, help="attempts per frame in all (default 5)")
    gen.add_argument("--integrate", choices=("euler", "midpoint"), help="actions → trajectory (default euler)")
    gen.add_argument("--chain", choices=("independent", "conversation"), help="request variant (default independent)")
    gen.add_argument("--answer-format", choices=("text", "structured"), help="stage-3 answer format (default text)")
    gen.add_argument("--transport", choices=("litellm", "direct"), help="with --api-base: through litellm or directly")
    p.set_defaults(func=main)
    return p


#: the run settings a sweep forwards to every variant's run (flags as ``lightemma run`` names them: cli/run.FLAGS)
_FORWARDED = (
    "backend",
    "price",
    "concurrency",
    "timeout",
    "rpm",
    "tpm",
    "prompt_set",
    "temperature",
    "max_tokens",
    "max_retries",
    "backoff_base",
    "reask",
    "max_attempts",
    "integrate_method",
    "chain",
    "answer_format",
    "transport",
)


def main(args: argparse.Namespace) -> int:
    from lightemma._signals import interrupt_on_stop_signals

    interrupt_on_stop_signals()
    from lightemma.cli.run import _attr, check_limits
    from lightemma.errors import UserError
    from lightemma.pipeline.variant_sweep import parse_variants, sweep

    def log(message: str) -> None:
        import sys

        print(f"lightemma sweep: {message}", file=sys.stderr, flush=True)

    parse_variants(args.inputs)  # bad input first, in one line, before any frame is loaded
    check_limits(args)
    if args.sample_seed is not None and args.sample is None:
        raise UserError("--sample-seed goes with --sample N")
    given = {kw: getattr(args, _attr(kw)) for kw in _FORWARDED}
    options = {kw: (tuple(value) if kw == "price" else value) for kw, value in given.items() if value is not None}
    if args.batch:
        options["batch"] = True
    result = sweep(
        args.model,
        inputs=args.inputs,
        out=args.out,
        dataroot=args.dataroot,
        version=args.version,
        split=args.split,
        scenes=args.scenes,
        window=args.window,
        limit=args.limit,
        sample=args.sample,
        sample_seed=args.sample_seed or 0,
        on_bad_record=args.on_bad_record,
        api_base=args.api_base,
        api_key_env=args.api_key_env,
        cache=args.cache,
        max_cost_cents=args.max_cost,
        estimate_only=args.estimate,
        progress=not args.no_progress,
        log=log,
        **options,
    )
    if args.estimate:
        print("\n".join((result.manifest.get("estimate") or {}).get("lines") or []))
        return 0
    print(result.report())
    return 0
