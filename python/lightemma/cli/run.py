"""``lightemma run``: a model over a frame set through the three-stage chain (or ``--resume`` one)."""

from __future__ import annotations

import argparse
import math
from typing import Any

from lightemma.pipeline.config import InvalidSetting, default, problem, requirement, setting, shown, span_text
from lightemma.prompts import DEFAULT_PROMPT_SET

#: each run setting (the parameter of lightemma.run, a row of lightemma.pipeline.config.SETTINGS) -> its flag; the
#: flag's argparse attribute is the flag without its dashes ("--max-cost" -> args.max_cost)
FLAGS: dict[str, str] = {
    "model": "--model",
    "backend": "--backend",
    "api_base": "--api-base",
    "api_key_env": "--api-key-env",
    "price": "--price",
    "gpus": "--gpus",
    "dataroot": "--dataroot",
    "version": "--version",
    "split": "--split",
    "scenes": "--scenes",
    "window": "--window",
    "limit": "--limit",
    "sample": "--sample",
    "sample_seed": "--sample-seed",
    "on_bad_record": "--on-bad-record",
    "concurrency": "--concurrency",
    "timeout": "--timeout",
    "max_retries": "--max-retries",
    "backoff_base": "--backoff",
    "rpm": "--rpm",
    "tpm": "--tpm",
    "cache": "--cache",
    "transport": "--transport",
    "name": "--name",
    "batch": "--batch",
    "batch_poll": "--batch-poll",
    "max_cost_cents": "--max-cost",
    "batch_size": "--batch-size",
    "max_pixels": "--max-pixels",
    "tensor_parallel_size": "--tensor-parallel-size",
    "gpu_memory_utilization": "--gpu-memory-utilization",
    "pipeline_parallel_size": "--pipeline-parallel-size",
    "replicas": "--replicas",
    "ray_address": "--ray-address",
    "gpus_per_replica": "--gpus-per-replica",
    "prompt_set": "--prompt-set",
    "temperature": "--temperature",
    "max_tokens": "--max-tokens",
    "reask": "--reask",
    "max_attempts": "--max-attempts",
    "integrate_method": "--integrate",
    "speed_range": "--speed-range",
    "max_abs_curvature": "--max-curvature",
    "answer_format": "--answer-format",
    "chain": "--chain",
    "inputs": "--inputs",
    "samples": "--samples",
}


def _attr(parameter: str) -> str:
    return FLAGS[parameter][2:].replace("-", "_")


def _range(parameter: str) -> str:
    """`` (1..4096)``: a flag's range for its help, read from the settings table."""
    return f" (range {span_text(parameter)})" if span_text(parameter) else ""


def for_cli(exc: InvalidSetting) -> Exception:
    """The library's error naming a parameter (``concurrency must be…``), as the command line says it: naming the
    flag (``--concurrency must be…``)."""
    from lightemma.errors import UserError

    flag = FLAGS.get(exc.parameter, exc.parameter)
    return UserError(f"{flag} must be {exc.requirement}, got {shown(exc.value)}")


def _inputs_arg(value: str) -> str:
    """--inputs, checked when parsed: one line naming what is wrong, before any work."""
    from lightemma.inputs import check_inputs

    try:
        return check_inputs(value)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("--inputs ")) from None


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "run",
        help="run a model over nuScenes frames (three-stage chain), crash-safe and resumable",
        description="Run a vision-language model over a frame set through the three-stage chain "
        "(scene → intent → actions). Records go to OUTPUT/<model>/<run_id>/frames.jsonl as frames finish; "
        "an interrupted run is finished with --resume RUN_DIR. A run that cannot succeed (a rejected key, an unknown "
        "model, the same failure on frame after frame) stops with one line naming the cause and the fix, keeping what "
        "finished. Exit status: 0 done, 1 done without one valid frame, 2 stopped or refused.",
    )
    p.add_argument(
        "--model",
        help="registry name (gpt-4o, claude-3.7-sonnet, …), litellm model string, or baseline:constant|cv|oracle|ego",
    )
    p.add_argument(
        "--backend", choices=("api", "hf", "vllm", "baseline"), help="override the backend chosen from the model"
    )
    p.add_argument(
        "--api-base",
        help="OpenAI-compatible endpoint (e.g. a vLLM server: http://host:8000/v1); no provider key "
        "is sent there unless --api-key-env names one",
    )
    p.add_argument(
        "--price",
        nargs=2,
        type=float,
        metavar=("IN", "OUT"),
        help="USD per million input / output tokens of a model served from --api-base (default: unknown; the "
        "provider's list price applies only on the provider's own host)",
    )
    p.add_argument(
        "--gpus",
        type=int,
        metavar="N",
        help="GPUs serving the model behind --api-base (recorded and shown in tables; default: none shown)",
    )
    p.add_argument(
        "--api-key-env",
        metavar="NAME",
        help="the environment variable holding the key to send (to --api-base, "
        "or to the provider); default: the provider's own variable, sent only to the provider's own host",
    )
    data = p.add_argument_group("frames")
    data.add_argument("--dataroot", help="nuScenes directory")
    data.add_argument("--version", help="nuScenes version (default v1.0-test, the paper's set)")
    data.add_argument(
        "--split",
        help="scenes of the version: a devkit split (test, val, mini_val, …) or all; default test for "
        "v1.0-test, val for v1.0-trainval, all for v1.0-mini (docs/definitions.md#frames-and-windows)",
    )
    data.add_argument("--scenes", nargs="+", metavar="SCENE", help="explicit scene names")
    data.add_argument(
        "--window",
        choices=("reference", "full"),
        help="reference (the paper: N-14 frames per scene, default) or full (N-13) "
        "(docs/definitions.md#frames-and-windows)",
    )
    data.add_argument("--limit", type=int, help="only the first N frames (in scene order; see --sample)")
    data.add_argument(
        "--sample",
        type=int,
        metavar="N",
        help="a reproducible sample of N frames spread over as many scenes "
        "as possible, recorded in the manifest (docs/run.md#samples)",
    )
    data.add_argument("--sample-seed", type=int, metavar="S", help="seed of --sample (default 0)")
    data.add_argument(
        "--on-bad-record",
        choices=("skip", "error"),
        help="a scene with an unusable pose or timestamp: skip it with a warning (default) or stop loading",
    )
    ex = p.add_argument_group("execution")
    ex.add_argument(
        "--concurrency",
        type=int,
        help="frames in flight at once (default 16; on --resume, the run's own)" + _range("concurrency"),
    )
    ex.add_argument("--output", help="output directory (default ./runs)")
    ex.add_argument("--resume", metavar="RUN_DIR", help="finish this run (everything else is read from its manifest)")
    ex.add_argument("--retry-failed", action="store_true", help="with --resume: also re-run frames that ended failed")
    ex.add_argument(
        "--timeout",
        type=float,
        help="deadline per call in seconds, connect to last byte (default 120; on "
        "--resume, the run's own unless given)" + _range("timeout"),
    )
    ex.add_argument(
        "--max-retries",
        type=int,
        help="retries of 429/5xx/timeouts/dropped connections per call (default 6)" + _range("max_retries"),
    )
    ex.add_argument(
        "--backoff", type=float, help="base of the exponential backoff in seconds (default 1)" + _range("backoff_base")
    )
    ex.add_argument("--rpm", type=float, help="client-side limit: requests per minute" + _range("rpm"))
    ex.add_argument("--tpm", type=float, help="client-side limit: tokens per minute" + _range("tpm"))
    ex.add_argument(
        "--cache",
        nargs="?",
        const=True,
        default=None,
        metavar="PATH",
        help="SQLite response cache for temperature-0 requests (default path OUTPUT/cache.sqlite)",
    )
    ex.add_argument(
        "--transport",
        choices=("litellm", "direct"),
        help="with --api-base: call the OpenAI-compatible server through litellm (default) or directly (less CPU per call)",
    )
    ex.add_argument("--no-progress", action="store_true", help="no progress bar")
    ex.add_argument("--name", help="a name for the run, shown in every table instead of its timestamp id")
    paid = p.add_argument_group("paid runs (docs/run.md#paid-runs)")
    paid.add_argument(
        "--batch",
        action="store_true",
        help="through the provider's batch API (OpenAI, Anthropic, Gemini) at "
        "its batch price (about 50 %%); results within 24 h; a killed run resumes by polling the same batches",
    )
    paid.add_argument(
        "--batch-poll",
        type=float,
        metavar="SECONDS",
        help="with --batch: first poll after SECONDS "
        "(default 30), then ×1.5 per poll up to 10 min" + _range("batch_poll"),
    )
    paid.add_argument(
        "--estimate",
        action="store_true",
        help="print the frames, calls, tokens and expected cost "
        "(normal and --batch) without calling anything, and exit; image tokens by the model's published "
        "rule, 'unknown' where none is published",
    )
    paid.add_argument(
        "--max-cost",
        type=float,
        metavar="CENTS",
        help="stop cleanly (resumable) before the run would spend "
        "more than CENTS US cents (on --resume: the run's whole limit, earlier sessions included); a frame "
        "is admitted at the estimate, or at its upper bound where the model's image tokens are unknown",
    )
    local = p.add_argument_group("local models (--backend hf | vllm)")
    local.add_argument(
        "--batch-size", type=int, help="requests per batched forward pass (default 8; 1 is the paper's way)"
    )
    local.add_argument("--max-pixels", type=int, help="cap on image pixels (width × height) fed to the model")
    local.add_argument(
        "--dtype",
        choices=("auto", "bfloat16", "float16", "float32"),
        help="weights dtype (default auto: bf16 on GPU, fp32 on CPU)",
    )
    local.add_argument(
        "--device", help="hf: cuda (all visible GPUs, device_map=auto), cuda:N or cpu (default cuda when present)"
    )
    local.add_argument("--tensor-parallel-size", type=int, help="vllm: GPUs to shard the model over (default 1)")
    local.add_argument(
        "--gpu-memory-utilization", type=float, help="vllm: share of GPU memory vLLM may use (default 0.9)"
    )
    local.add_argument(
        "--pipeline-parallel-size", type=int, help="vllm: GPUs to split the model's layers over (default 1)"
    )
    local.add_argument(
        "--trust-remote-code",
        action="store_true",
        default=None,
        help="run the checkpoint's own Python code (transformers' / vLLM's trust_remote_code), for models "
        "that need it; only for checkpoints you trust. A resume of such a run needs it again",
    )
    ray = p.add_argument_group("replicas over Ray (--backend hf | vllm; pip install 'lightemma[ray]'; docs/local.md)")
    ray.add_argument(
        "--replicas",
        type=int,
        metavar="N",
        help="model replicas, each a Ray actor with its own GPU(s), frames spread across "
        "them (default 1: in this process, no Ray)" + _range("replicas"),
    )
    ray.add_argument(
        "--ray-address",
        metavar="ADDRESS",
        help="join this running Ray cluster (auto, HOST:PORT, ray://HOST:PORT); "
        "default: start a local Ray sized to the replicas",
    )
    ray.add_argument(
        "--gpus-per-replica",
        type=float,
        metavar="G",
        help="hf: GPUs per replica (default 1 where the cluster has GPUs, else 0); "
        "vllm uses --tensor-parallel-size × --pipeline-parallel-size",
    )
    gen = p.add_argument_group("prompting")
    gen.add_argument("--prompt-set", help=f"prompt set name or JSON file (default {DEFAULT_PROMPT_SET})")
    gen.add_argument(
        "--temperature",
        type=float,
        help="sampling temperature where the provider allows it (default 0)" + _range("temperature"),
    )
    gen.add_argument("--max-tokens", type=int, help="max output tokens per stage (default 512)" + _range("max_tokens"))
    gen.add_argument(
        "--samples",
        type=int,
        metavar="K",
        help="K independent chains per frame, scored as minADE@K / minFDE@K (default 1; give "
        "--temperature above 0; docs/run.md#k-samples)" + _range("samples"),
    )
    gen.add_argument(
        "--reask",
        choices=("actions", "chain"),
        help="on a failed answer re-ask stage 3 (default) or the whole chain (docs/definitions.md#re-asks)",
    )
    gen.add_argument("--max-attempts", type=int, help="attempts per frame in all (default 5)" + _range("max_attempts"))
    gen.add_argument(
        "--integrate",
        choices=("euler", "midpoint"),
        help="actions → trajectory (default euler, the paper's; docs/definitions.md#integration)",
    )
    gen.add_argument(
        "--speed-range",
        nargs=2,
        type=float,
        metavar=("LO", "HI"),
        help="plausible speeds in m/s; an answer outside fails as implausible (default -10 50)",
    )
    gen.add_argument(
        "--max-curvature",
        type=float,
        metavar="K",
        help="plausible |curvature| in 1/m; an answer above fails as implausible (default 1)",
    )
    gen.add_argument(
        "--answer-format",
        choices=("text", "structured"),
        help="stage 3 answers as text (default, the paper's) or as JSON constrained to a schema by the provider's "
        "structured outputs / vLLM / xgrammar; a model that cannot follow one is refused (docs/run.md#structured-answers)",
    )
    gen.add_argument(
        "--chain",
        choices=("independent", "conversation"),
        help="independent stages, each with the image (default, the paper's), or one conversation continued "
        "through stages 2 and 3, the image in its first turn (docs/run.md#request-variants-and-prompt-caching)",
    )
    gen.add_argument(
        "--inputs",
        type=_inputs_arg,
        metavar="INPUTS",
        help="what the model is shown: full (default, the paper's), no-image (no image in any stage), "
        "blank-image (a uniform grey image of the frame's size), no-history (the prompt set's no-history "
        "variant: no history numbers), corrupt:NAME@SEVERITY (the image corrupted, severity 1-5), "
        "history-noise@SIGMA[,SIGMA_K] (noise on the printed speeds m/s [and curvatures 1/m]), "
        "history-stale@K (the history K steps of 0.5 s late) (docs/definitions.md#input-ablations)",
    )
    base = p.add_argument_group("baselines")
    base.add_argument(
        "--fit-split",
        metavar="SPLIT",
        help="baseline:ego: fit on this split of --version (train on v1.0-trainval) instead of cross-fitting "
        "by scene on the evaluated frames (docs/definitions.md#the-ego-status-baseline)",
    )
    p.set_defaults(func=main)
    return p


# Run settings and their defaults (RunConfig's own). On the command line they default to None, so that
# `--resume` can tell a setting that was given (and would be ignored) from one that was not.
RUN_DEFAULTS: dict[str, Any] = {
    **{
        _attr(p): default(p)
        for p in (
            "version",
            "window",
            "timeout",
            "max_retries",
            "backoff_base",
            "transport",
            "prompt_set",
            "temperature",
            "max_tokens",
            "reask",
            "max_attempts",
            "integrate_method",
            "on_bad_record",
            "speed_range",
            "max_abs_curvature",
            "answer_format",
            "chain",
            "inputs",
            "samples",
        )
    },
    "output": "runs",
}
# what `--resume` may be given: everything else comes from the run's manifest
RESUME_OPTIONS = {
    "command",
    "func",
    "resume",
    "retry_failed",
    "concurrency",
    "no_progress",
    "replicas",
    "ray_address",
    "gpus_per_replica",
    "max_cost",
    "batch",
    "estimate",  # where the model runs, not what it is asked
    "api_base",
    "api_key_env",
    "cache",  # where requests, keys and writes go: the user's word, not the manifest's
    "trust_remote_code",  # what code runs: likewise
    "timeout",
    "rpm",
    "tpm",
}  # how long and how fast calls go: the fixes a timeout or rate-limit stop names


def run_settings(args: argparse.Namespace) -> dict[str, Any]:
    """The run settings: what was given on the command line, else the defaults."""
    return {
        name: default if getattr(args, name) is None else getattr(args, name) for name, default in RUN_DEFAULTS.items()
    }


def check_limits(args: argparse.Namespace) -> None:
    """Refuse a numeric option out of its setting's kind or range (:data:`lightemma.pipeline.config.SETTINGS`), naming
    the flag, before anything is loaded or sent."""
    from lightemma.errors import UserError

    for parameter, flag in FLAGS.items():
        value = getattr(args, _attr(parameter), None)
        row = setting(parameter)
        if value is None or row is None or row.kind not in ("int", "number"):
            continue
        what = problem(row, value)
        if what is not None:
            raise UserError(f"{flag} must be {requirement(row, what)}, got {shown(value)}")


# option -> backends that take it
LOCAL_OPTIONS = {
    "batch_size": ("hf", "vllm"),
    "max_pixels": ("hf", "vllm"),
    "dtype": ("hf", "vllm"),
    "device": ("hf",),
    "tensor_parallel_size": ("vllm",),
    "gpu_memory_utilization": ("vllm",),
    "pipeline_parallel_size": ("vllm",),
    "trust_remote_code": ("hf", "vllm"),
}


def local_backend_options(args: argparse.Namespace) -> dict[str, object]:
    """The local-model options given on the command line, checked against the backend that will run."""
    from lightemma.backends import backend_kind
    from lightemma.errors import UserError

    given = {name: getattr(args, name) for name in LOCAL_OPTIONS if getattr(args, name, None) is not None}
    if not given:
        return {}
    kind = backend_kind(args.model, args.backend, args.api_base)
    wrong = [name for name in given if kind not in LOCAL_OPTIONS[name]]
    if wrong:
        flags = ", ".join("--" + name.replace("_", "-") for name in wrong)
        raise UserError(
            f"{flags} do(es) not apply to the {kind} backend (they are for "
            f"{' / '.join(sorted({b for n in wrong for b in LOCAL_OPTIONS[n]}))})"
        )
    return given


def print_estimate(args: argparse.Namespace) -> int:
    """``--estimate``: load the frames the run would take and print its expected bill; nothing is called."""
    from lightemma.errors import UserError
    from lightemma.pipeline.runner import _load_frames, _require_frames, estimate_run

    if args.resume:
        raise UserError("--estimate is for a new run; drop --resume")
    if not args.model or not args.dataroot:
        raise UserError("--estimate needs --model and --dataroot (the run it estimates)")
    settings = run_settings(args)
    dataset = {
        "dataroot": args.dataroot,
        "version": settings["version"],
        "split": args.split,
        "scenes": args.scenes,
        "window": settings["window"],
        "limit": args.limit,
        "on_bad_record": settings["on_bad_record"],
        "sample": {"n": args.sample, "seed": args.sample_seed or 0} if args.sample is not None else None,
    }
    from lightemma.backends import backend_kind
    from lightemma.models.catalog import resolve
    from lightemma.pipeline.estimate import no_bill

    resolve(args.model)  # an unknown baseline is refused as a run refuses it
    kind = backend_kind(args.model, args.backend, args.api_base)
    if kind == "baseline" and settings["inputs"] != "full":
        raise UserError(
            f"--inputs {settings['inputs']} is an ablation of what a model is shown; {args.model} reads the "
            "frame's numbers itself and is shown nothing: drop --inputs"
        )
    frames = _load_frames(dataset)
    _require_frames(frames)
    if kind != "api":  # a baseline or a local model: no call to a provider, no bill
        print(no_bill(args.model, kind, len(frames)))
        return 0
    planned = estimate_run(
        args.model,
        frames=frames,
        prompt_set=settings["prompt_set"],
        chain=settings["chain"],
        answer_format=settings["answer_format"],
        inputs=settings["inputs"],
        max_tokens=settings["max_tokens"],
        api_base=args.api_base,
        backend=args.backend,
        price=tuple(args.price) if args.price else None,
        samples=settings["samples"],
    )
    print(planned.report())
    return 0


def main(args: argparse.Namespace) -> int:
    from lightemma._signals import interrupt_on_stop_signals

    interrupt_on_stop_signals()  # before the session's own handlers: no silent death while loading or starting
    from lightemma.errors import UserError
    from lightemma.pipeline.runner import resume, run, stderr_log

    progress = not args.no_progress
    check_limits(args)
    if args.batch is False:
        args.batch = None  # a flag not given: --resume takes the run's own mode
    if args.batch_poll is not None and not args.batch and not args.resume:  # a resume: the manifest decides (below)
        raise UserError("--batch-poll goes with --batch")
    if args.sample_seed is not None and args.sample is None:
        raise UserError("--sample-seed goes with --sample N")
    if args.sample is not None and args.limit is not None:
        raise UserError(
            "--sample and --limit are exclusive: --limit takes the first N frames, --sample N spreads N over the scenes"
        )
    if args.estimate:
        return print_estimate(args)
    if args.resume:
        given = sorted(
            "--" + name.replace("_", "-")
            for name, value in vars(args).items()
            if name not in RESUME_OPTIONS and value is not None
        )
        if given:
            raise UserError(f"--resume takes every setting from the run's manifest; drop {', '.join(given)}")
        if args.batch:
            raise UserError("--resume takes the run's mode (batch or not) from its manifest; drop --batch")
        try:
            result = resume(
                args.resume,
                retry_failed=args.retry_failed,
                progress=progress,
                log=stderr_log,
                concurrency=args.concurrency,
                replicas=args.replicas,
                ray_address=args.ray_address,
                gpus_per_replica=args.gpus_per_replica,
                max_cost_cents=args.max_cost,
                api_base=args.api_base,
                api_key_env=args.api_key_env,
                cache=args.cache,
                backend_options={"trust_remote_code": True} if args.trust_remote_code else None,
                timeout=args.timeout,
                rpm=args.rpm,
                tpm=args.tpm,
            )
        except InvalidSetting as exc:
            raise for_cli(exc) from None
    else:
        if args.retry_failed:
            raise UserError("--retry-failed needs --resume RUN_DIR")
        if not args.model:
            raise UserError("--model is required (or --resume RUN_DIR)")
        if not args.dataroot:
            raise UserError("--dataroot is required (a nuScenes directory)")
        options = local_backend_options(args)
        if args.fit_split is not None:
            if not args.model.strip().lower().startswith("baseline:ego"):
                raise UserError(f"--fit-split is for baseline:ego (a fitted baseline); {args.model} is not fitted")
            options["fit_split"] = args.fit_split
        # local backends batch across frames in flight: keep at least one batch's worth of frames going (per replica)
        replicas = args.replicas or 1
        batch_size = options.get("batch_size", 0)
        assert isinstance(batch_size, int)  # --batch-size is type=int
        concurrency = args.concurrency if args.concurrency is not None else max(16, batch_size) * replicas
        settings = run_settings(args)
        lo, hi = settings["speed_range"]
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise UserError(f"--speed-range LO HI needs two finite numbers with LO < HI, got {lo:g} {hi:g}")
        if not (math.isfinite(settings["max_curvature"]) and settings["max_curvature"] > 0):
            raise UserError(f"--max-curvature must be a finite number > 0, got {settings['max_curvature']:g}")
        try:
            result = run(
                args.model,
                dataroot=args.dataroot,
                version=settings["version"],
                split=args.split,
                scenes=args.scenes,
                window=settings["window"],
                limit=args.limit,
                output=settings["output"],
                backend=args.backend,
                api_base=args.api_base,
                concurrency=concurrency,
                temperature=settings["temperature"],
                max_tokens=settings["max_tokens"],
                reask=settings["reask"],
                max_attempts=settings["max_attempts"],
                integrate_method=settings["integrate"],
                speed_range=tuple(settings["speed_range"]),
                max_abs_curvature=settings["max_curvature"],
                prompt_set=settings["prompt_set"],
                timeout=settings["timeout"],
                max_retries=settings["max_retries"],
                backoff_base=settings["backoff"],
                rpm=args.rpm,
                tpm=args.tpm,
                cache=args.cache,
                transport=settings["transport"],
                api_key_env=args.api_key_env,
                progress=progress,
                log=stderr_log,
                price=tuple(args.price) if args.price else None,
                gpus=args.gpus,
                backend_options=options,
                on_bad_record=settings["on_bad_record"],
                replicas=replicas,
                ray_address=args.ray_address,
                gpus_per_replica=args.gpus_per_replica,
                chain=settings["chain"],
                answer_format=settings["answer_format"],
                batch=bool(args.batch),
                batch_poll=args.batch_poll or 30.0,
                max_cost_cents=args.max_cost,
                sample=args.sample,
                sample_seed=args.sample_seed or 0,
                name=args.name,
                inputs=settings["inputs"],
                samples=settings["samples"],
            )
        except InvalidSetting as exc:
            raise for_cli(exc) from None
    print(result.report())
    summary = result.summary
    if summary.get("frames") and not summary.get("ade_frames"):
        reason = f" (last: {summary['top_failure']})" if summary.get("top_failure") else ""
        stderr_log(
            f"error: no valid frame: all {summary['frames']} frame(s) of {result.run_dir} failed{reason}; "
            "see their records in frames.jsonl"
        )
        return 1
    return 0
