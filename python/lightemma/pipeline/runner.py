"""Run a model over a frame set: many frames in flight, one whole record per finished frame.

:func:`run` starts a run directory (``<output>/<model>/<run_id>/``, see
:mod:`lightemma.runs.store`) and :func:`resume` finishes one after a crash or
an interrupt, from its manifest alone, without redoing finished frames
(``retry_failed=True`` re-runs the frames whose last record is ``failed``).

Frames run through :func:`lightemma.pipeline.chain.run_frame` on up to
``concurrency`` frames at once, for any backend; each record is appended to
``frames.jsonl`` as soon as its frame finishes, so a crash loses at most the
frames in flight. A process holds the run directory's lock
(:class:`~lightemma.runs.store.RunLock`) while it writes; a second one is refused.

When the backend raises :class:`~lightemma.errors.RunFatalError` (a rejected key,
the same failure on frame after frame, a model that cannot generate) or a record
cannot be written (disk full), the run stops: no new frame and no new call
starts, the calls in flight finish, frames that complete are written, frames
cut off mid-chain are not (a resume redoes them), and :class:`~lightemma.errors.RunStopped`
names the cause, the fix and the ``--resume`` command. A resume also redoes the
frames that ended ``failed`` with the error that stopped the run.
"""

from __future__ import annotations

import asyncio
import math
import os
import platform
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from lightemma._signals import stop_signals
from lightemma._text import unicode_clean
from lightemma.backends import Backend, ChatRequest, ChatResult, GenerationParams, backend_kind, create_backend
from lightemma.errors import (  # Interrupted, STOP_SIGNALS: shared with the importer (which does not load this module)
    STOP_SIGNALS,
    Interrupted,
    RunFatalError,
    RunStopped,
    RunStoreError,
    UserError,
    os_error_line,
)
from lightemma.frames.model import summary_line
from lightemma.pipeline.chain import ChainPolicy, run_frame
from lightemma.pipeline.progress import Progress
from lightemma.pipeline.summary import format_summary, summarize
from lightemma.prompts import DEFAULT_PROMPT_SET, PromptSet, load_prompt_set
from lightemma.registry import resolve
from lightemma.runs.store import (
    FRAMES_FILE,
    LOCK_PID_FILE,
    RecordTooLargeError,
    RunLock,
    RunWriter,
    create_run_dir,
    read_frame_ids,
    read_manifest,
    read_run,
    update_manifest,
)

Log = Callable[[str], None]
DEFAULT_CACHE = "cache.sqlite"  # the response cache's default place, relative to the output directory


@dataclass
class RunResult:
    """What a run or resume produced."""

    run_dir: Path
    manifest: dict[str, Any]
    summary: dict[str, Any]
    frames_run: int  # frames run in this session

    def report(self) -> str:
        """The final summary as text."""
        return format_summary(self.summary, title=f"{self.manifest.get('display_name', self.manifest['model'])} — {self.run_dir}")


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def _git_revision() -> str | None:
    """``git describe`` of the source tree lightemma runs from (None outside a checkout)."""
    try:
        out = subprocess.run(["git", "describe", "--always", "--dirty", "--abbrev=40"], cwd=Path(__file__).resolve().parent,
                             capture_output=True, text=True, timeout=5)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None if out.returncode == 0 else None


def _policy(config: dict[str, Any]) -> ChainPolicy:
    # runs recorded before the plausibility limits existed were parsed without them: a resume keeps it so
    speed_range = config.get("speed_range")
    return ChainPolicy(params=GenerationParams(temperature=config["temperature"], max_tokens=config["max_tokens"]),
                       reask=config["reask"], max_attempts=config["max_attempts"], integrate_method=config["integrate_method"],
                       speed_range=None if speed_range is None else tuple(speed_range),
                       max_abs_curvature=config.get("max_abs_curvature"), **_request_variant(config))


def _request_variant(config: dict[str, Any]) -> dict[str, str]:
    """The run's chain, answer format and inputs (runs recorded before they existed: the paper's, independent,
    text and full)."""
    return {"chain": config.get("chain") or "independent", "answer_format": config.get("answer_format") or "text",
            "inputs": config.get("inputs") or "full"}


def _structured_output(backend: Backend, policy: ChainPolicy) -> dict[str, Any] | None:
    """For a structured run, how the backend constrains stage 3 (for the manifest); a UserError when it cannot."""
    if policy.answer_format != "structured":
        return None
    check = getattr(backend, "structured_output", None)
    if check is None:
        raise UserError(f"--answer-format structured: the {getattr(backend, 'name', 'chosen')} backend cannot constrain "
                        "answers to a JSON schema; use --answer-format text")
    from lightemma.backends.structured import ACTIONS_SCHEMA

    return {**check(), "schema": ACTIONS_SCHEMA.as_dict(), "parse_mode": policy.parse_mode}


def _make_backend(config: dict[str, Any], output: Path, api_base: str | None = None, log: Log | None = None) -> Backend:
    """The backend a run's config names; checks the API key before anything else happens.

    ``api_base`` is the endpoint as the user gave it (the config records it without credentials).
    """
    kind = backend_kind(config["model"], config["backend"], config["api_base"])
    if config.get("price") is not None and kind != "api":
        raise UserError(f"--price is the price of a provider's tokens; {config['model']} runs on the {kind} backend and "
                        "is billed none: drop --price")
    options = dict(config.get("backend_options") or {})
    if config.get("batch"):
        if kind != "api":
            raise UserError(f"--batch is for models behind a provider's API; {config['model']} runs on the {kind} backend")
        ignored = [flag for flag, key in (("--cache", "cache"), ("--rpm", "rpm"), ("--tpm", "tpm")) if config.get(key)]
        if ignored:
            raise UserError(f"{', '.join(ignored)} do(es) not apply to --batch (the provider paces a batch itself, and the "
                            "run's batch journal keeps every result); drop them or drop --batch")
        from lightemma.backends.batch import BatchBackend

        # the endpoint as the user gave it (credentials and all), the key variable named: the same key rule as a normal run
        backend: Backend = BatchBackend(config["model"], api_base=api_base, api_key_env=config.get("api_key_env"),
                                        timeout=config["timeout"], poll_seconds=config.get("batch_poll") or 30.0,
                                        price=tuple(config["price"]) if config.get("price") is not None else None)
        return _with_notices(backend, log)
    if kind == "api":
        if config.get("api_key_env"):
            options["api_key_env"] = config["api_key_env"]
        if config.get("price") is not None:
            options["price"] = tuple(config["price"])
        from lightemma.backends.retry import RetryPolicy
        from lightemma.cache import ResponseCache

        cache = config.get("cache")
        options.update(
            timeout=config["timeout"], rpm=config["rpm"], tpm=config["tpm"], transport=config.get("transport", "litellm"),
            retry=RetryPolicy(max_retries=config["max_retries"], base=config["backoff_base"], cap=config["backoff_cap"]),
            cache=ResponseCache(cache if os.path.isabs(cache) else output / cache, log=log) if cache else None,
        )
    replicas = {"replicas": config.get("replicas") or 1, "ray_address": config.get("ray_address"),
                "gpus_per_replica": config.get("gpus_per_replica")}
    if kind == "hf" and config.get("timeout"):
        # a deadline per batch, in this process or in each replica (docs/run.md#when-a-run-cannot-succeed)
        options.setdefault("timeout", config["timeout"])
    return _with_notices(create_backend(config["model"], backend=kind, api_base=api_base, **replicas, **options), log)


def _with_notices(backend: Backend, log: Log | None) -> Backend:
    """``backend``, its one-line notices (plain http to another host, …) shown once."""
    for notice in getattr(backend, "notices", ()):
        if log:
            log(notice)
        else:
            import warnings

            warnings.warn(notice, stacklevel=4)
    return backend


#: backend options a manifest may carry into a resume by itself: numbers and names that say how the model runs here.
#: Any other (``trust_remote_code``, ``attn_implementation`` — transformers may fetch kernels from the hub —,
#: ``engine_options``, ``runtime_env``, ``vllm``, …) can fetch or run code, so the resume's caller gives it again.
INERT_BACKEND_OPTIONS = frozenset({
    "batch_size", "batch_window", "max_pixels", "dtype", "device", "device_map", "tensor_parallel_size",
    "pipeline_parallel_size", "gpu_memory_utilization", "max_model_len", "seed", "enable_prefix_caching", "fit_split",
    "folds", "max_image_bytes", "max_restarts", "max_sends",
})


def _trusted_settings(run_dir: Path, config: dict[str, Any], api_base: str | None, api_key_env: str | None,
                      cache: str | bool | None, ray_address: str | None = None,
                      backend_options: Mapping[str, Any] | None = None) -> None:
    """Refuse to resume a run whose manifest would choose where requests, keys or writes go, or what code runs.

    A run directory may come from someone else: its endpoint (``api_base``), its key variable
    (``api_key_env``) and its response cache path must be the ones the user gives now (``--api-base``,
    ``--api-key-env``, ``--cache``); a Ray cluster the run's replicas joined (``ray_address``) is joined
    again only when the user names one (``--ray-address``); and backend options outside
    :data:`INERT_BACKEND_OPTIONS` (``trust_remote_code``, …) hold only when ``backend_options`` gives them
    again, equal (``--trust-remote-code``). Otherwise the resume is refused in one line. Nothing is shown or asked.
    """
    from lightemma.backends.retry import redact_url

    recorded = redact_url(config.get("api_base"))  # a manifest written before redaction may hold a password
    options = config.get("backend_options") or {}
    if not isinstance(options, Mapping):
        raise UserError(f"{run_dir}: the manifest's backend_options are not an object; start a new run")
    if "api_key" in options:
        raise UserError(f"{run_dir}: the manifest's backend_options carry an api_key; keys come from the environment only "
                        "(--api-key-env NAME): start a new run")
    if backend_options is not None and not isinstance(backend_options, Mapping):
        raise UserError(f"backend_options must be a mapping of option names to values, got {type(backend_options).__name__}")
    inert = sorted(str(k) for k in (backend_options or {}) if k in INERT_BACKEND_OPTIONS)
    if inert:
        raise UserError(f"{run_dir}: a resume takes {', '.join(inert)} from the run's manifest; drop them from backend_options")
    trust = options.get("trust_remote_code")
    if trust is not None and not isinstance(trust, bool):
        raise UserError(f"{run_dir}: the manifest's trust_remote_code is {_short_repr(trust)}, not true or false; start a new run")

    def active(opts: Mapping[str, Any]) -> dict[str, Any]:  # options that can fetch or run code, unset ones left out
        return {k: v for k, v in opts.items() if k not in INERT_BACKEND_OPTIONS and v is not None and v is not False}

    live, given = active(options), active(backend_options or {})
    differ = sorted(k for k in live.keys() | given.keys() if live.get(k) != given.get(k))
    if differ:
        if differ == ["trust_remote_code"]:
            why = (f"this run loaded {_short_repr(config.get('model'))} with trust_remote_code (the checkpoint's own Python "
                   "code runs); a run directory does not choose what code runs: resume it with --trust-remote-code if you "
                   "trust that checkpoint" if live.get("trust_remote_code") else
                   "this run did not load the model with trust_remote_code; drop --trust-remote-code")
        else:
            shown = ", ".join(f"{_short_repr(k)}: the run's {_short_repr(live[k]) if k in live else '(none)'}, given "
                              f"{_short_repr(given[k]) if k in given else '(none)'}" for k in differ)
            why = (f"backend options that can fetch or run code differ from the run's ({shown}); a run directory does not "
                   "choose what code runs: give the run's own again to resume (lightemma.resume(..., backend_options={...}))")
        raise UserError(f"{run_dir}: {why}")
    recorded_ray = config.get("ray_address")
    if recorded_ray is not None and not (isinstance(recorded_ray, str) and recorded_ray.strip()):
        raise UserError(f"{run_dir}: the manifest's ray_address is {_short_repr(recorded_ray)}, not an address; start a new run")
    if recorded_ray and not ray_address:
        raise UserError(f"{run_dir}: this run's replicas joined the Ray cluster at {_short_repr(recorded_ray)}; a run directory "
                        "does not choose where the model runs: resume it with --ray-address (that one or another)")
    if (redact_url(api_base) or None) != (recorded or None):
        if recorded and not api_base:
            why = (f"this run was made against an --api-base endpoint ({recorded}); a run directory does not choose where "
                   "requests and keys go: resume it with the same --api-base URL")
        elif not recorded:
            why = "this run was not made against an --api-base endpoint; drop --api-base"
        else:
            why = f"the --api-base given is not the run's endpoint ({recorded}); give the run's own, or start a new run"
        raise UserError(f"{run_dir}: {why}")
    if (config.get("api_key_env") or None) != (api_key_env or None):
        named = config.get("api_key_env")
        why = (f"this run sent the key in --api-key-env {named}; resume it with the same --api-key-env" if named and not api_key_env
               else "the --api-key-env given is not the run's; give the run's own (or none if it had none)")
        raise UserError(f"{run_dir}: {why}")
    recorded_cache = config.get("cache")
    output = run_dir.parent.parent
    if recorded_cache is None:
        if cache:
            raise UserError(f"{run_dir}: this run kept no response cache; drop --cache")
        return
    want = (output / recorded_cache if not os.path.isabs(recorded_cache) else Path(recorded_cache)).resolve()
    if cache is None or cache is False:
        raise UserError(f"{run_dir}: this run kept a response cache ({want}), outside the run directory; a run directory "
                        f"does not choose where lightemma writes: resume it with --cache {want}"
                        + (" (or --cache, the default place)" if recorded_cache == DEFAULT_CACHE else ""))
    given = (output / DEFAULT_CACHE if cache is True else Path(cache)).resolve()
    if given != want:
        raise UserError(f"{run_dir}: the --cache given ({given}) is not the run's response cache ({want}); give the run's own")


_NUMBER = (int, float)
#: what each setting of a manifest's config must be for a resume to use it (None allowed where listed)
_CONFIG_TYPES: dict[str, tuple[tuple[type, ...], bool]] = {
    "model": ((str,), False), "backend": ((str,), True), "prompt_set": ((str,), False), "transport": ((str,), True),
    "concurrency": ((int,), False), "max_tokens": ((int,), False), "max_attempts": ((int,), False),
    "max_retries": ((int,), False), "replicas": ((int,), True), "timeout": (_NUMBER, False),
    "temperature": (_NUMBER, False), "backoff_base": (_NUMBER, False), "backoff_cap": (_NUMBER, False),
    "rpm": (_NUMBER, True), "tpm": (_NUMBER, True), "gpus_per_replica": (_NUMBER, True), "batch_poll": (_NUMBER, True),
    "max_cost_cents": (_NUMBER, True), "dataset": ((dict,), True), "backend_options": ((dict,), True),
    "api_key_env": ((str,), True), "api_base": ((str,), True), "cache": ((str,), True), "reask": ((str,), False),
    "integrate_method": ((str,), False), "speed_range": ((list,), True), "max_abs_curvature": (_NUMBER, True),
    "batch": ((bool,), True), "price": ((list,), True), "gpus": ((int,), True),
}
#: settings read as config[...] (a resume of a manifest without them would fail with a KeyError)
_REQUIRED = ("model", "backend", "api_base", "concurrency", "temperature", "max_tokens", "reask", "max_attempts",
             "integrate_method", "prompt_set", "timeout", "max_retries", "backoff_base", "backoff_cap", "rpm", "tpm")
#: the range (inclusive) of each numeric setting, on the command line and in a manifest: beyond it a run would wait
#: without end (a rate of 1e-300 per minute, a 1e-300 s deadline) or retry without end (10**9 attempts)
SETTING_RANGES: dict[str, tuple[float, float]] = {
    "timeout": (0.001, 86_400.0), "rpm": (1.0, 1e9), "tpm": (10.0, 1e12), "max_retries": (0, 100),
    "max_attempts": (1, 100), "backoff_base": (0.0, 600.0), "backoff_cap": (0.0, 3600.0), "concurrency": (1, 4096),
    "max_tokens": (1, 1_000_000), "batch_poll": (0.01, 3600.0), "max_cost_cents": (0.0, 1e9), "replicas": (1, 1024),
    "temperature": (0.0, 100.0),
}
#: numbers that must be above 0, not merely at least 0
_POSITIVE = ("timeout", "rpm", "tpm", "batch_poll", "max_cost_cents")


_DATASET_TYPES: dict[str, tuple[tuple[type, ...], bool]] = {
    "dataroot": ((str,), True), "version": ((str,), True), "split": ((str,), True), "scenes": ((list,), True),
    "window": ((str,), True), "limit": ((int,), True), "on_bad_record": ((str,), True), "sample": ((dict,), True),
}


def _finite(value: Any) -> bool:
    """A number that is no bool, and finite (an integer too large for a float is not)."""
    if isinstance(value, bool) or not isinstance(value, _NUMBER):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:  # an int beyond a float's range
        return False


def _check_config_types(run_dir: Path, config: Mapping[str, Any], table: Mapping[str, tuple[tuple[type, ...], bool]] = _CONFIG_TYPES,
                        where: str = "config") -> None:
    """Refuse, in one line, a manifest config whose settings are not of their kind (a hand-edited file): a number
    that is text, a bool, not finite or below 0, a count below 1, a mapping that is a list, a setting left out."""
    def refuse(name: str, value: Any, kind: str) -> UserError:
        return UserError(f"{run_dir}: the manifest's {where}.{name} is {_short_repr(value)}, not {kind}; start a new run")

    if where == "config":
        missing = [name for name in _REQUIRED if name not in config]
        if missing:
            raise UserError(f"{run_dir}: the manifest's config has no {', '.join(missing)}; start a new run")
        if isinstance(config.get("dataset"), dict):
            _check_config_types(run_dir, config["dataset"], _DATASET_TYPES, "config.dataset")
    for name, (types, nullable) in table.items():
        if name not in config:
            continue
        value = config[name]
        if value is None and nullable:
            continue
        ok = isinstance(value, types) and (types == (bool,) or not isinstance(value, bool))
        if ok and types == _NUMBER:
            ok = _finite(value) and (value > 0 if name in _POSITIVE else value >= 0)
        if ok and types == (int,):
            ok = value >= (0 if name in ("max_retries", "gpus") else 1)
        if ok and isinstance(value, str) and "\x00" in value:
            ok = False
        low, high = SETTING_RANGES.get(name, (None, None)) if where == "config" else (None, None)
        if ok and low is not None and not low <= value <= high:
            raise refuse(name, value, f"between {low:g} and {high:g}")
        if not ok:
            kind = {(str,): "text", (int,): "a whole number", _NUMBER: "a finite number", (dict,): "an object",
                    (list,): "a list", (bool,): "true or false"}[types]
            if types == _NUMBER and _finite(value):
                kind = "a number greater than 0" if name in _POSITIVE else "a number of at least 0"
            if isinstance(value, str) and "\x00" in value:
                kind = "text without NUL characters"
            raise refuse(name, value, kind)
    if where == "config":
        from lightemma.backends.api import MAX_PRICE

        pairs = (("speed_range", lambda v: len(v) == 2 and all(map(_finite, v)) and v[0] < v[1], "[low, high]"),
                 ("price", lambda v: len(v) == 2 and all(_finite(x) and 0 <= x <= MAX_PRICE for x in v),
                  f"[input, output] USD per million, each 0..{MAX_PRICE:g}"))
        for name, good, kind in pairs:
            value = config.get(name)
            if value is not None and not good(value):
                raise refuse(name, value, kind)
    else:
        scenes, sample = config.get("scenes"), config.get("sample")
        if scenes is not None and not all(isinstance(s, str) for s in scenes):
            raise refuse("scenes", scenes, "a list of scene names")
        if sample:
            n, seed = sample.get("n"), sample.get("seed")
            if type(n) is not int or n < 1 or (seed is not None and type(seed) is not int):
                raise refuse("sample", sample, '{"n": N, "seed": S} (whole numbers)')


def _short_repr(value: Any, limit: int = 60) -> str:
    """``repr(value)`` cut to ``limit`` characters: a manifest's value shown in a one-line message."""
    if isinstance(value, int) and not isinstance(value, bool) and value.bit_length() > 200:
        return f"a whole number of {len(str(value)) if value.bit_length() < 13_000 else 'thousands of'} digits"
    try:
        text = repr(value)
    except (ValueError, RecursionError):  # a number of over 4,300 digits inside, or nested beyond the stack
        return f"a {type(value).__name__} that cannot be shown"
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _served_model_info(info: Any, price: tuple[float, float] | None, gpus: int | None, *, served: bool) -> dict[str, Any]:
    """The registry entry as a model served from another ``--api-base`` records it: not the provider's list price nor
    the registry's GPU count (the paper's hardware), but what ``--price`` / ``--gpus`` say (else unknown / 0)."""
    out = info.to_dict()
    if served:
        out.update(input_usd_per_mtok=None, output_usd_per_mtok=None, cache_read_usd_per_mtok=None,
                   cache_write_usd_per_mtok=None, price_source=None, price_read=None, gpus=0)
    if price is not None:
        out.update(input_usd_per_mtok=float(price[0]), output_usd_per_mtok=float(price[1]), price_source="--price")
    if gpus is not None:
        out["gpus"] = int(gpus)
    return out


def _load_frames(dataset: dict[str, Any]) -> Sequence[Any]:
    """Load the frames a manifest's ``dataset`` describes (dataroot, version, split/scenes, window, limit)."""
    if not dataset.get("dataroot") or not dataset.get("version"):
        raise UserError("this run was made from frames passed in memory; pass frames=... to resume it",
                        cli="this run was made from frames passed in memory, not from a dataset; resume it from "
                        "Python: lightemma.resume(RUN_DIR, frames=FRAMES)")
    from lightemma import load_frames

    frames = load_frames(dataset["dataroot"], dataset["version"], split=dataset.get("split"), scenes=dataset.get("scenes"),
                         window=dataset.get("window", "reference"), on_bad_record=dataset.get("on_bad_record") or "skip")
    return _subset(frames, dataset)


def _subset(frames: Any, dataset: Mapping[str, Any]) -> Sequence[Any]:
    """The frames a dataset request keeps: ``limit`` (the first N) or ``sample`` (N spread over scenes, seeded)."""
    sample = dataset.get("sample")
    if sample:
        from lightemma.frames.sample import sample_frames

        if dataset.get("limit") is not None:
            raise UserError("--sample and --limit are exclusive: --limit takes the first N frames, --sample N spreads N over the scenes")
        n = int(sample["n"])
        if n > len(frames):  # a sample cannot hold more frames than the set: refused, not recorded as N frames
            raise UserError(f"--sample {n} is more than the {len(frames)} frames of the set; drop --sample to take them all")
        return sample_frames(frames, n, int(sample.get("seed") or 0))
    return _head(frames, dataset.get("limit"))


def _require_frames(frames: Sequence[Any]) -> None:
    """An empty frame set is an error (it would make an empty run), naming why it is empty where that is known."""
    if len(frames):
        return
    skipped = list(getattr(frames, "skipped_scenes", []) or [])
    missing = list(getattr(frames, "missing_images", []) or [])
    if missing and not skipped:  # the frames exist; their images do not
        raise UserError(f"no frames to run: the CAM_FRONT image of every frame ({len(missing)}) is missing (see the "
                        "warning above); --dataroot must be the folder holding samples/CAM_FRONT/*.jpg")
    why = f": every scene was skipped ({', '.join(skipped[:5])}{', …' if len(skipped) > 5 else ''}; see the warnings above)" if skipped else ""
    raise UserError(f"no frames to run{why}; choose other scenes (--split, --scenes) or --window full")


def _head(frames: Any, limit: int | None) -> Sequence[Any]:
    if limit is None:
        return frames
    if limit < 1:
        raise UserError(f"--limit must be at least 1, got {limit}")
    return frames.head(limit) if hasattr(frames, "head") else list(frames)[:limit]


def _describe(frames: Any, dataset: dict[str, Any]) -> dict[str, Any]:
    described = dict(frames.describe()) if hasattr(frames, "describe") else {}
    out = {**described, **{k: v for k, v in dataset.items() if v is not None}, "n_frames": len(frames)}
    if dataset.get("sample"):
        from lightemma.frames.sample import describe_sample

        out["sample"] = {**describe_sample(frames, dataset["sample"]["n"], dataset["sample"].get("seed") or 0)}
    from lightemma.frames.fingerprint import of_dataset  # which frames, as one checkable id (docs/evaluate.md)

    out["fingerprint"] = of_dataset(out, getattr(frames, "frame_ids", None) or [f.frame_id for f in frames])
    return out




def resume_command(run_dir: str | os.PathLike[str], config: Mapping[str, Any] | None = None) -> str:
    """The ``lightemma run --resume`` command that continues ``run_dir``, with what a resume must be given again
    (:func:`resume` refuses it otherwise): the run's ``--api-base`` (as recorded, credentials replaced by ``***``:
    give the real ones), ``--api-key-env``, ``--cache`` (its path), ``--ray-address`` and ``--trust-remote-code``.
    ``config`` is the run's config (the manifest's); without it, the bare command."""
    import shlex

    parts = ["lightemma", "run", "--resume", os.fspath(run_dir)]
    config = config or {}
    if config.get("api_base"):
        parts += ["--api-base", str(config["api_base"])]
    if config.get("api_key_env"):
        parts += ["--api-key-env", str(config["api_key_env"])]
    cache = config.get("cache")
    if isinstance(cache, str) and cache:
        output = Path(run_dir).parent.parent
        parts += ["--cache", os.fspath((Path(cache) if os.path.isabs(cache) else output / cache).resolve())]
    if config.get("ray_address"):
        parts += ["--ray-address", str(config["ray_address"])]
    options = config.get("backend_options")
    if isinstance(options, Mapping) and options.get("trust_remote_code") is True:
        parts.append("--trust-remote-code")
    return shlex.join(parts)


def _exit_now(run_dir: Path, signum: int, command: str | None = None) -> None:
    """A second stop signal: remove ``.lock.pid``, say so in one line (``command``: how to continue), exit 128 + the
    signal at once."""
    try:
        (run_dir / LOCK_PID_FILE).unlink(missing_ok=True)
    except OSError:
        pass
    os.write(2, f"lightemma run: {signal.Signals(signum).name} again: exiting now; finished frames are saved. "
                f"Continue with: {command or resume_command(run_dir)}\n".encode())
    os._exit(128 + signum)


class _Stopped(Exception):
    """Raised into a frame's chain once the run has stopped: the frame is left unfinished (not written)."""


class _Guard:
    """The backend as the chain sees it during a session: once the run stops, no new call starts.

    With a ``budget`` (``--max-cost``), a frame starts only while its chain fits
    (:class:`~lightemma.pipeline.estimate.Budget`); the first that does not stops the run (cause ``budget``,
    resumable): no new frame starts, the frames in flight finish.
    """

    def __init__(self, backend: Backend, budget: Any = None) -> None:
        self.backend = backend
        self.name = getattr(backend, "name", "backend")
        self.stopped = False
        self.admitting = True  # False once the budget is spent: frames in flight go on, no new frame starts
        self.budget = budget

    @property
    def info(self) -> Any:
        return self.backend.info

    async def generate(self, requests: Sequence[ChatRequest]) -> list[ChatResult]:
        if self.stopped:
            raise _Stopped
        if self.budget is None:
            return await self.backend.generate(requests)
        reserved = 0.0
        for req in requests:
            held = self.budget.reserve(req.frame_id, first_call=req.stage == "scene" and req.attempt == 1)
            if held is None:
                self.budget.settle(reserved, 0.0)
                raise RunFatalError(self.budget.message(), cause="budget")
            reserved += held
        spent = 0.0
        try:
            results = await self.backend.generate(requests)
            # a call of unknown cost (no usage reported, a price not known for its cached tokens) counts at the
            # estimate, never as free: the limit holds whatever a provider leaves out (a cache hit costs nothing)
            spent = sum(r.cost_cents if r.cost_cents is not None else (0.0 if r.cached else self.budget.per_call_cents)
                        for r in results)
            return results
        finally:
            self.budget.settle(reserved, spent)

    def frame_done(self, frame_id: str) -> None:
        if self.budget is not None:
            self.budget.release(frame_id)

    async def aclose(self) -> None:
        await self.backend.aclose()


@dataclass
class _Outcome:
    done: int = 0  # frames written in this session
    stop: RunFatalError | None = None  # why the session stopped early, if it did
    interrupted: int | None = None  # the signal (SIGINT, SIGTERM, SIGHUP) that stopped it, if one did


async def _execute(frames: Sequence[Any], backend: Backend, writer: RunWriter, prompts: PromptSet, policy: ChainPolicy,
                   concurrency: int, bar: Progress, earlier: Mapping[str, dict[str, Any]], budget: Any = None,
                   command: str | None = None) -> _Outcome:
    """Run every frame, ``concurrency`` at a time, appending each record as it finishes; stop on a run-fatal cause.

    ``earlier``: frame id -> the failed record a frame is run again after (its attempts are kept).
    """
    iterator = iter(frames)
    guard = _Guard(backend, budget)
    outcome = _Outcome()

    def halt(cause: RunFatalError) -> None:
        if outcome.stop is None:
            outcome.stop = cause
        if cause.cause == "budget":
            guard.admitting = False  # the spending limit: the frames in flight finish, no new one starts
        else:
            guard.stopped = True

    async def worker() -> None:
        for frame in iterator:  # shared: each frame goes to exactly one worker
            if guard.stopped or not guard.admitting:
                return
            try:
                record = await run_frame(frame, guard, prompts, policy, earlier.get(frame.frame_id))
            except _Stopped:
                return  # cut off mid-chain by a stop: not written, so a resume runs it again
            except RunFatalError as exc:
                halt(exc)
                return
            finally:
                guard.frame_done(frame.frame_id)
            try:
                writer.append(record)
            except OSError as exc:
                halt(RunFatalError(os_error_line(exc, "write a frame record to"), cause="disk"))
                return
            except RecordTooLargeError as exc:  # never written to be skipped unread later: the run says so and stops
                halt(RunFatalError(f"{exc}: the model's answers are that long; not written (a resume asks that frame "
                                   "again; a smaller --max-tokens bounds the answers)", cause="record-too-large",
                                   error="RecordTooLargeError"))
                return
            bar.update(record)
            outcome.done += 1

    main = asyncio.current_task()
    loop = asyncio.get_running_loop()

    def on_signal(signum: int) -> None:  # in the loop, between steps: the session is cancelled cleanly
        if outcome.interrupted is not None:
            _exit_now(writer.path.parent, signum, command)  # a second signal while stopping: leave at once
        outcome.interrupted = signum
        if main is not None:
            main.cancel()

    installed = []
    if threading.current_thread() is threading.main_thread():
        for sig in STOP_SIGNALS:
            try:
                loop.add_signal_handler(sig, on_signal, sig)
                installed.append(sig)
            except (NotImplementedError, RuntimeError, ValueError):
                pass
    tasks = [asyncio.create_task(worker()) for _ in range(max(1, min(concurrency, len(frames))))]
    try:
        await asyncio.gather(*tasks)
    except asyncio.CancelledError:
        if outcome.interrupted is None:
            raise
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        await backend.aclose()
        for sig in installed:  # back to the session's own handlers (stop_signals), not the defaults
            loop.remove_signal_handler(sig)
    return outcome


def _in_set(records: dict[str, dict[str, Any]], frame_ids: list[str] | None) -> list[dict[str, Any]]:
    """The records of frames in the run's frame set (all records for runs written without one)."""
    if frame_ids is None:
        return list(records.values())
    allowed = set(frame_ids)
    return [r for fid, r in records.items() if fid in allowed]


def _write_manifest(run_dir: Path, _command: str | None = None, **fields: Any) -> dict[str, Any]:
    """update_manifest, with an OS failure (disk full, permissions) as one line that says what is safe (``_command``:
    how to continue, :func:`resume_command`)."""
    try:
        return update_manifest(run_dir, **fields)
    except OSError as exc:
        raise RunStoreError(os_error_line(exc, "update the manifest in") + f"; the frames written so far are safe in "
                            f"{run_dir / FRAMES_FILE}; after freeing space, continue with: "
                            f"{_command or resume_command(run_dir)}") from None


def _session(run_dir: Path, todo: Sequence[Any], backend: Backend, prompts: PromptSet, config: dict[str, Any],
             progress: bool, kind: str, already: int, log: Log | None,
             earlier: Mapping[str, dict[str, Any]] | None = None) -> RunResult:
    """Run ``todo`` into ``run_dir`` and mark the run finished; the shared tail of run and resume.

    ``earlier``: the failed records of frames run again (frame id -> record), whose attempts the new records keep.

    Raises :class:`RunStopped` (after saving the session) when the run stopped for a run-fatal cause.
    """
    try:
        budget = _budget(run_dir, config, todo, backend, prompts, resuming=kind != "run")
    except BaseException:
        asyncio.run(backend.aclose())
        raise
    manifest = read_manifest(run_dir)
    command = resume_command(run_dir, config)
    sessions = list(manifest.get("sessions", []))
    sessions.append({"kind": kind, "started_at": _now(), "frames_todo": len(todo), "concurrency": config["concurrency"],
                     "timeout": config.get("timeout"), "rpm": config.get("rpm"), "tpm": config.get("tpm"), "pid": os.getpid()})
    _write_manifest(run_dir, command, sessions=sessions, finished_at=None)
    try:
        writer = RunWriter(run_dir)
    except OSError as exc:
        asyncio.run(backend.aclose())
        raise RunStoreError(os_error_line(exc, "open the frame records")
                            + f"; continue later with: {command}") from None
    attach = getattr(backend, "attach", None)
    if attach is not None:  # a batch backend journals its batches in the run directory
        attach(run_dir, log, budget=budget)  # and checks each finished wave's reported cost against --max-cost
    concurrency = max(1, len(todo)) if getattr(backend, "wants_all_frames", False) else config["concurrency"]
    bar = Progress(already + len(todo), enabled=progress, initial=already)
    start = time.perf_counter()
    # SIGINT, SIGTERM, SIGHUP stop the session like Ctrl-C: the frames in flight are cut off, the session's wall time
    # is recorded, the lock released; a second one exits at once (frames are whole lines, .lock.pid removed first)
    with stop_signals(lambda signum: _exit_now(run_dir, signum, command)):
        try:
            with writer:
                if todo:
                    outcome = asyncio.run(_execute(todo, backend, writer, prompts, _policy(config), concurrency, bar, earlier or {},
                                                   budget, command))
                    if outcome.interrupted is not None:
                        raise Interrupted(outcome.interrupted)
                else:
                    outcome = _Outcome()
                    asyncio.run(backend.aclose())
        except KeyboardInterrupt as exc:
            # the session's time is known: record it, so the run's wall time stays the sum of its sessions
            sessions[-1].update(interrupted=True, wall_seconds=round(time.perf_counter() - start, 3))
            if isinstance(exc, Interrupted):
                sessions[-1]["signal"] = exc.name
            try:
                update_manifest(run_dir, sessions=sessions)
            except OSError:
                pass  # the frames are safe; the run's wall time will just be unknown
            if log:
                how = f" by {exc.name}" if isinstance(exc, Interrupted) else ""
                log(f"interrupted{how}; finished frames are saved. Continue with: {command}")
                exc.reported = True  # type: ignore[attr-defined]  # said: the command line adds no second line
            raise
        finally:
            bar.close()
    wall = time.perf_counter() - start
    _refresh_sidecar(run_dir, log)
    contents = read_run(run_dir)
    summary = summarize(_in_set(contents.records, read_frame_ids(run_dir)), wall_seconds=wall, frames_run=outcome.done)
    sessions[-1].update(finished_at=_now(), frames_run=outcome.done, wall_seconds=round(wall, 3))
    replicas = getattr(backend, "replica_report", None)
    if replicas:
        sessions[-1]["replicas"] = replicas
    batches = getattr(backend, "batch_report", None)
    if batches:
        sessions[-1]["batch"] = batches
        summary.update(batch=True, batch_turnaround_s=batches.get("turnaround_s_mean"))
    failed_cache = getattr(getattr(backend, "cache", None), "failure", None)
    if failed_cache:
        sessions[-1]["cache_failure"] = failed_cache  # the session ran uncached from then on
    images = getattr(backend, "image_report", None)
    if images:
        sessions[-1]["images_reencoded"] = images
        if log:
            log(f"{images['count']} image(s) were larger than the provider accepts and were re-encoded to fit "
                "(see images_reencoded in the manifest)")
    stop = outcome.stop
    if stop is not None:
        sessions[-1]["stopped"] = {"cause": stop.cause, "error": stop.error, "message": str(stop)}
        _write_manifest(run_dir, command, sessions=sessions, summary=summary)
        if stop.cause == "reasoning-budget":  # the fix changes what is asked, which a resume keeps
            after = "a resume keeps the run's --max-tokens: start a new run with the larger budget"
        elif stop.error == "Timeout":
            after = f"continue with a longer wait: {command} --timeout SECONDS"
        else:
            after = f"after the fix, continue with: {command}"
        raise RunStopped(f"{stop} — the run stopped; {outcome.done} frame(s) finished in this session are saved in {run_dir}; "
                         f"{after}",
                         cause=stop.cause, error=stop.error, run_dir=run_dir, frames_run=outcome.done)
    manifest = _write_manifest(run_dir, command, sessions=sessions, finished_at=_now(), summary=summary)
    return RunResult(run_dir=run_dir, manifest=manifest, summary=summary, frames_run=outcome.done)


def _budget(run_dir: Path, config: Mapping[str, Any], todo: Sequence[Any], backend: Backend, prompts: PromptSet, *,
            resuming: bool = False) -> Any:
    """The session's ``--max-cost`` budget (None without one): the run's recorded spending, what each call is
    admitted at (:func:`_admitted_cents_per_call`)."""
    limit = config.get("max_cost_cents")
    if limit is None:
        return None
    from lightemma.pipeline.estimate import Budget

    per_call = _admitted_cents_per_call(config, todo, backend, prompts, resuming=resuming)
    spent = sum(float(r.get("cost_cents") or 0.0) for r in read_run(run_dir).records.values())
    return Budget(float(limit), per_call, spent)


def _admitted_cents_per_call(config: Mapping[str, Any], todo: Sequence[Any], backend: Backend, prompts: PromptSet, *,
                             resuming: bool = False) -> float:
    """The cents ``--max-cost`` admits each call of ``todo`` at (the estimate per call, or its upper bound where the
    model's image tokens are unknown: :meth:`~lightemma.pipeline.estimate.Estimate.admitted_cents_per_call`); a
    one-line :class:`UserError` where no spending can be bounded. Reads and writes nothing: a new run checks it before
    its run directory exists."""
    from lightemma.pipeline.estimate import estimate

    info = resolve(config["model"])
    planned = estimate(todo, info, getattr(backend, "provider", None), prompts, max_tokens=config["max_tokens"],
                       chain=config.get("chain") or "independent", inputs=config.get("inputs") or "full",
                       given_price=config.get("price"),
                       served_from=getattr(backend, "api_base_shown", None) if getattr(backend, "served_elsewhere", False) else None)
    batch = bool(config.get("batch"))
    per_call = planned.admitted_cents_per_call(batch)
    if per_call is not None:
        return per_call
    bound = planned.batch_bound if batch else planned.bound
    if bound is None or bound.unknown == "price":
        fix = ("a resume keeps the run's price (it has none): drop --max-cost, or start a new run with --price IN OUT"
               if resuming else "give it with --price IN OUT, or drop --max-cost")
        raise UserError(f"--max-cost: the price of {config['model']} is unknown ({planned.price_source}), so no spending "
                        f"can be bounded; {fix}")
    raise UserError(f"--max-cost: the image tokens of {config['model']} are unknown (no published image rule) and "
                    f"{bound.source}, so no spending can be bounded: drop --max-cost (--estimate shows what is known)")


def estimate_run(model: str, *, frames: Sequence[Any], prompt_set: str = DEFAULT_PROMPT_SET, chain: str = "independent",
                 answer_format: str = "text", inputs: str = "full", max_tokens: int = 512, api_base: str | None = None,
                 backend: str | None = None, price: Sequence[float] | None = None) -> Any:
    """The :class:`~lightemma.pipeline.estimate.Estimate` of running ``model`` over ``frames`` with the prompts and
    images of ``inputs`` — nothing is called.

    A model with no provider bill (a baseline, a local ``hf`` / ``vllm`` backend) raises a one-line
    :class:`~lightemma.errors.UserError` (:func:`~lightemma.pipeline.estimate.no_bill`); so does a model a
    real run would refuse (not in the registry and no provider litellm knows).
    """
    from lightemma.backends.api import check_model, litellm_model
    from lightemma.inputs import check_inputs
    from lightemma.pipeline.estimate import estimate, no_bill

    try:
        check_inputs(inputs)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    info = resolve(model)
    kind = backend_kind(model, backend, api_base)
    if kind != "api":
        raise UserError(no_bill(model, kind, len(frames)))
    provider = check_model(litellm_model(info, api_base), model, api_base)  # the unknown-model error of a real run
    prompts = load_prompt_set(prompt_set).select(chain, answer_format, inputs)
    from lightemma.backends.api import is_provider_host
    from lightemma.backends.retry import redact_url

    if price is not None:
        from lightemma.backends.api import check_price

        check_price(price)
    served_from = redact_url(api_base) if api_base and not is_provider_host(provider, api_base) else None
    return estimate(frames, info, provider, prompts, max_tokens=max_tokens, chain=chain, inputs=inputs,
                    given_price=price, served_from=served_from)


def _refresh_sidecar(run_dir: Path, log: Log | None) -> None:
    """End of a session: write the evaluation sidecar (frames.jsonl stays the record of truth; never fatal)."""
    from lightemma.evaluation.loading import refresh_sidecar

    try:
        refresh_sidecar(run_dir)
    except (RunStoreError, OSError, ValueError) as exc:  # a cache: evaluate reads frames.jsonl without it
        if log:
            log(f"could not write the evaluation sidecar of {run_dir} ({exc}); evaluate will read frames.jsonl")


def run(
    model: str,
    *,
    dataroot: str | os.PathLike[str] | None = None,
    version: str = "v1.0-test",
    split: str | None = None,
    scenes: Sequence[str] | None = None,
    window: str = "reference",
    limit: int | None = None,
    frames: Sequence[Any] | None = None,
    output: str | os.PathLike[str] = "runs",
    backend: str | None = None,
    api_base: str | None = None,
    concurrency: int = 16,
    temperature: float = 0.0,
    max_tokens: int = 512,
    reask: str = "actions",
    max_attempts: int = 5,
    integrate_method: str = "euler",
    speed_range: tuple[float, float] | None = (-10.0, 50.0),
    max_abs_curvature: float | None = 1.0,
    chain: str = "independent",
    answer_format: str = "text",
    inputs: str = "full",
    prompt_set: str = DEFAULT_PROMPT_SET,
    on_bad_record: str = "skip",
    timeout: float = 120.0,
    max_retries: int = 6,
    backoff_base: float = 1.0,
    backoff_cap: float = 60.0,
    rpm: float | None = None,
    tpm: float | None = None,
    cache: str | bool | None = None,
    transport: str = "litellm",
    api_key_env: str | None = None,
    price: tuple[float, float] | None = None,
    gpus: int | None = None,
    backend_options: dict[str, Any] | None = None,
    replicas: int = 1,
    ray_address: str | None = None,
    gpus_per_replica: float | None = None,
    batch: bool = False,
    batch_poll: float = 30.0,
    max_cost_cents: float | None = None,
    sample: int | None = None,
    sample_seed: int = 0,
    name: str | None = None,
    progress: bool = True,
    log: Log | None = None,
) -> RunResult:
    """Run ``model`` over a frame set through the three-stage chain; returns the run's summary.

    Frames come from ``frames`` (any sequence of Frame-like objects, e.g. a
    :class:`~lightemma.frames.FrameSet`) or are loaded with
    :func:`lightemma.load_frames` from ``dataroot``/``version``/``split``/
    ``scenes``/``window``; ``limit`` keeps the first N. ``cache=True`` keeps a
    response cache at ``<output>/cache.sqlite`` (or give a path). ``transport="direct"``
    talks to an OpenAI-compatible ``api_base`` without litellm (less CPU per call).
    ``on_bad_record`` (``skip`` or ``error``) is what loading does with a scene whose
    pose or timestamp is invalid (see :func:`lightemma.load_frames`). ``replicas``,
    ``ray_address`` and ``gpus_per_replica`` run a local model (hf, vllm) as replicas over
    Ray (:mod:`lightemma.backends.ray`; docs/local.md).
    ``chain`` (``independent``, the paper's, or ``conversation``) and ``answer_format``
    (``text``, the paper's, or ``structured``: stage 3 constrained to a JSON schema) choose
    the request variant (docs/run.md); a backend that cannot constrain its answers is a
    :class:`~lightemma.errors.UserError` before any work. ``inputs`` is the input ablation
    (:mod:`lightemma.inputs`: ``full``, the paper's, ``no-image``, ``blank-image`` or ``no-history``,
    the last through the prompt set's no-history variant); recorded in the manifest, kept by a resume.

    A missing API key, an unknown model or an empty frame set raises
    :class:`~lightemma.errors.UserError` before any work. A run-fatal cause met while
    running raises :class:`~lightemma.errors.RunStopped` once what finished is saved.
    ``speed_range`` (m/s) and ``max_abs_curvature`` (1/m) are the parser's plausibility
    limits (None disables one; see :func:`lightemma.parse_actions`), recorded in the
    manifest as ``params.parse`` and kept by a resume.

    ``batch=True`` sends the chain through the provider's batch interface at its batch price
    (:mod:`lightemma.backends.batch`; first poll after ``batch_poll`` seconds). ``max_cost_cents``
    stops the run (resumable) before a call would take its spending past the limit. ``sample`` keeps
    N frames spread over the scenes (seeded by ``sample_seed``, :mod:`lightemma.frames.sample`),
    recorded in the manifest. ``name`` is the run's name, shown in tables instead of its id.
    """
    if concurrency < 1:
        raise UserError(f"--concurrency must be at least 1, got {concurrency}")
    if frames is None and dataroot is None:
        raise UserError("give --dataroot (a nuScenes directory) or frames=...")
    if backend_options and "api_key" in backend_options:
        raise UserError("backend_options are recorded in the run manifest, so they cannot carry an api_key; "
                        "set the provider's environment variable instead")
    info = resolve(model)
    from lightemma.backends.retry import redact_url

    config: dict[str, Any] = {
        "model": model, "backend": backend, "api_base": redact_url(api_base), "api_key_env": api_key_env,
        "price": None if price is None else [float(p) for p in price], "gpus": gpus, "concurrency": concurrency, "temperature": temperature,
        "max_tokens": max_tokens, "reask": reask, "max_attempts": max_attempts, "integrate_method": integrate_method,
        "speed_range": None if speed_range is None else [float(x) for x in speed_range],
        "max_abs_curvature": None if max_abs_curvature is None else float(max_abs_curvature),
        "chain": chain, "answer_format": answer_format, "inputs": inputs, "prompt_set": prompt_set, "timeout": timeout, "max_retries": max_retries, "backoff_base": backoff_base,
        "backoff_cap": backoff_cap, "rpm": rpm, "tpm": tpm, "transport": transport, "backend_options": backend_options or {},
        "cache": (DEFAULT_CACHE if cache is True else (os.fspath(Path(cache).resolve()) if cache else None)),
        "replicas": replicas, "ray_address": ray_address, "gpus_per_replica": gpus_per_replica,
        "batch": bool(batch), "batch_poll": float(batch_poll) if batch else None, "max_cost_cents": max_cost_cents,
    }
    if max_cost_cents is not None and not (math.isfinite(max_cost_cents) and max_cost_cents > 0):
        raise UserError(f"--max-cost must be a number of cents greater than 0, got {max_cost_cents:g}")
    if name is not None and (not name.strip() or len(name) > 80 or any(ord(ch) < 32 for ch in name)
                             or unicode_clean(name) != name):  # bytes that are not UTF-8 (a Latin-1 terminal)
        raise UserError(f"--name must be 1 to 80 printable characters of UTF-8 text, got {name!r}")
    if prompt_set.endswith(".json"):  # a prompt-set file: by absolute path, so that a resume finds it from anywhere
        config["prompt_set"] = os.fspath(Path(prompt_set).resolve())
    try:
        policy = _policy(config)  # validates reask / attempts / method / chain / answer format before any work
    except ValueError as exc:
        raise UserError(str(exc)) from None
    if policy.inputs != "full" and backend_kind(model, backend, api_base) == "baseline":
        raise UserError(f"--inputs {policy.inputs} is an ablation of what a model is shown; {model} reads the frame's "
                        "numbers itself and is shown nothing: drop --inputs")
    prompts = load_prompt_set(prompt_set).select(policy.chain, policy.answer_format, policy.inputs)
    output = Path(output)
    instance = _make_backend(config, output, api_base, log)
    dataset = {"dataroot": os.fspath(Path(dataroot).resolve()) if dataroot else None, "version": version if dataroot else None,
               "split": split, "scenes": list(scenes) if scenes else None, "window": window, "limit": limit,
               "on_bad_record": on_bad_record, "sample": {"n": int(sample), "seed": int(sample_seed)} if sample is not None else None}
    config["dataset"] = dataset  # the request, as given: what a resume loads again
    try:
        structured = _structured_output(instance, policy)
        if hasattr(instance, "check_endpoint"):
            instance.check_endpoint()  # a dead --api-base is refused now, not after minutes of retries
        if frames is None:
            frames = _load_frames(dataset)
        else:
            frames = _subset(frames, dataset)
        _require_frames(frames)
        if max_cost_cents is not None:  # a limit that bounds nothing or admits no frame: refused before anything exists
            from lightemma.pipeline.estimate import Budget

            per_call = _admitted_cents_per_call(config, frames, instance, prompts)
            if max_cost_cents < Budget.CHAIN_CALLS * per_call:
                frame = Budget.CHAIN_CALLS * per_call
                raise UserError(f"--max-cost {max_cost_cents:g}: not one frame fits within it (a frame is admitted at "
                                f"{frame:.3f} ¢, its three calls at {per_call:.3f} ¢ each); give at least --max-cost "
                                f"{math.ceil(frame * 1000) / 1000:g}, or drop it")
        planned = None
        if getattr(instance, "info", {}).get("kind") == "api":  # a paid run: its bill first, in one line
            planned = estimate_run(model, frames=frames, prompt_set=prompt_set, chain=chain, answer_format=answer_format,
                                   inputs=inputs, max_tokens=max_tokens, api_base=api_base, backend=backend, price=price)
        _prepare(instance, frames, dataset, log=log)
        manifest = {
            "model": model,
            **({"name": name.strip()} if name else {}),
            "display_name": info.display_name,
            "model_info": info.to_dict(),
            "backend": dict(instance.info),
            "config": config,
            "params": {**policy.to_dict(), "sent": instance.effective_params(policy.params) if hasattr(instance, "effective_params") else None},
            "prompt_set": prompts.describe(),
            **({"structured_output": structured} if structured else {}),
            "dataset": _describe(frames, dataset),
            "lightemma_version": _version(),
            "git_revision": _git_revision(),
            "python": platform.python_version(),
            "started_at": _now(),
            "finished_at": None,
            **({"estimate": planned.to_dict()} if planned is not None else {}),
        }
        if getattr(instance, "served_elsewhere", False) or gpus is not None:
            manifest["model_info"] = _served_model_info(info, price, gpus, served=getattr(instance, "served_elsewhere", False))
            if gpus is not None:
                manifest["gpus"] = gpus
        run_dir = create_run_dir(output, model, manifest, frame_ids=[f.frame_id for f in frames])
        lock = RunLock(run_dir).acquire()
    except BaseException:
        asyncio.run(instance.aclose())
        raise
    with lock:
        try:
            if log:
                log(f"frames: {summary_line(manifest['dataset'])}")
                if planned is not None:
                    log(planned.line())
                mode = "batch mode" if batch else f"concurrency {concurrency}"
                log(f"run directory: {run_dir}  ({len(frames)} frames, {mode})")
            return _session(run_dir, frames, instance, prompts, config, progress, "run", 0, log)
        except KeyboardInterrupt as exc:  # before the session's own handlers: said here, with the resume
            if log and not getattr(exc, "reported", False):
                how = f" by {exc.name}" if isinstance(exc, Interrupted) else ""
                log(f"interrupted{how}; finished frames are saved. Continue with: {resume_command(run_dir, config)}")
                exc.reported = True  # type: ignore[attr-defined]
            raise


def resume(run_dir: str | os.PathLike[str], *, retry_failed: bool = False, frames: Sequence[Any] | None = None,
           concurrency: int | None = None, replicas: int | None = None, ray_address: str | None = None,
           gpus_per_replica: float | None = None, max_cost_cents: float | None = None, api_base: str | None = None,
           api_key_env: str | None = None, cache: str | bool | None = None, backend_options: Mapping[str, Any] | None = None,
           timeout: float | None = None, rpm: float | None = None, tpm: float | None = None, progress: bool = True,
           log: Log | None = None) -> RunResult:
    """Finish the run in ``run_dir`` from its manifest, skipping frames already recorded.

    ``retry_failed`` also re-runs frames whose last record is ``failed`` (new
    records are appended; readers keep the last). Frames that ended ``failed``
    with the error that stopped the previous session (a rejected key, …) are
    re-run in any case: they failed for the run's cause, not their own. The
    prompt set must be the one the run started with (same content hash), and
    the frames loaded must be the run's frame set. ``frames`` is needed only
    for runs started from in-memory frames. Another process writing the run
    makes this raise :class:`~lightemma.errors.RunStoreError` (naming its PID).
    ``concurrency``, ``replicas``, ``ray_address`` and ``gpus_per_replica`` replace the run's own
    for this session (where the model runs, not what it is asked); so do ``timeout`` (how long a call
    or a local batch may take), ``rpm`` and ``tpm`` (how fast requests go) — the fixes a timeout or
    rate-limit stop names — and ``max_cost_cents`` (the run's whole spending limit, records of earlier
    sessions included). A batch run polls the batches its
    journal names before submitting anything (:mod:`lightemma.backends.batch`).

    The manifest never chooses where requests, keys or writes go, nor what code runs: ``api_base``,
    ``api_key_env`` and ``cache`` must be given as the run had them (its endpoint, key variable and
    response cache); a run whose replicas joined a Ray cluster needs a ``ray_address`` given now; and
    backend options that can fetch or run code (``trust_remote_code``, ``engine_options``, …: all but
    :data:`INERT_BACKEND_OPTIONS`) must be given again, equal, in ``backend_options``. Else a one-line
    :class:`~lightemma.errors.UserError` before anything is sent, loaded or written.
    """
    run_dir = Path(run_dir)
    manifest = read_manifest(run_dir)
    raw = manifest.get("config")
    if not isinstance(raw, Mapping) or not raw.get("model"):
        raise RunStoreError(f"{run_dir}: the manifest has no run config; it was not written by `lightemma run`")
    config = dict(raw)
    for name, value in (("timeout", timeout), ("rpm", rpm), ("tpm", tpm)):
        if value is not None:
            low, high = SETTING_RANGES[name]
            if not (math.isfinite(value) and low <= value <= high):
                raise UserError(f"--{name} must be a finite number between {low:g} and {high:g}, got {value:g}")
            config[name] = float(value)
    _check_config_types(run_dir, config)
    for name, kind, what, needed in (("model", str, "text", True), ("prompt_set", dict, "an object", False),
                                     ("dataset", dict, "an object", False), ("sessions", list, "a list", False)):
        value = manifest.get(name)
        if (needed or value is not None) and not isinstance(value, kind):  # the manifest's own blocks, beside config
            raise UserError(f"{run_dir}: the manifest's {name} is {_short_repr(value)}, not {what}; start a new run")
    _trusted_settings(run_dir, config, api_base, api_key_env, cache, ray_address, backend_options)
    if concurrency is not None:
        if concurrency < 1:
            raise UserError(f"--concurrency must be at least 1, got {concurrency}")
        config["concurrency"] = concurrency
    if max_cost_cents is not None:
        if not (math.isfinite(max_cost_cents) and max_cost_cents > 0):
            raise UserError(f"--max-cost must be a number of cents greater than 0, got {max_cost_cents:g}")
        config["max_cost_cents"] = max_cost_cents
    placement = {"replicas": replicas, "ray_address": ray_address, "gpus_per_replica": gpus_per_replica}
    config.update({k: v for k, v in placement.items() if v is not None})
    recorded = manifest.get("prompt_set", {})
    # a shipped name or a file's path (the recorded name is the set's own), as the run's variant uses it
    prompts = load_prompt_set(config["prompt_set"]).select(**_request_variant(config))
    if prompts.hash != recorded.get("hash") or prompts.variant_hash != recorded.get("variant_hash"):
        run_hash, now_hash = ((recorded.get("hash"), prompts.hash) if prompts.hash != recorded.get("hash") else
                              (recorded.get("variant_hash"), prompts.variant_hash))
        raise UserError(f"{run_dir}: prompt set {prompts.name!r} has changed since this run started "
                        f"(run: {run_hash}, now: {now_hash}); start a new run instead of resuming")
    with RunLock(run_dir):  # before anything is read for the todo list: a second writer would redo the same frames
        manifest = read_manifest(run_dir)  # as the last writer left it
        try:
            instance = _make_backend(config, run_dir.parent.parent, api_base, log)
        except (TypeError, AttributeError) as exc:  # a hand-edited manifest: another backend's option, a wrong type
            raise UserError(f"{run_dir}: the manifest's settings cannot build the run's backend ({type(exc).__name__}: "
                            f"{_short_repr(str(exc), 160)}); start a new run") from None
        try:
            _structured_output(instance, _policy(config))
            dataset = dict(config.get("dataset") or {})
            if dataset.get("split") is None and not dataset.get("scenes"):
                # the split the run resolved when it started, not today's default for the version
                dataset["split"] = (manifest.get("dataset") or {}).get("split")
            all_frames = _subset(frames, dataset) if frames is not None else _load_frames(dataset)
            _same_frame_set(run_dir, all_frames)
            _prepare(instance, all_frames, dataset, recorded=manifest.get("backend"), run_dir=run_dir, log=log)
            contents = read_run(run_dir)
            for warning in contents.warnings():
                if log and "not finished" not in warning:
                    log(warning)
            records = contents.records
            stopped_by = _stopped_error(manifest)

            def redo(record: dict[str, Any]) -> bool:
                failed = record.get("status") == "failed"
                return failed and (retry_failed or (stopped_by is not None and record.get("error") == stopped_by))

            todo = [f for f in all_frames if f.frame_id not in records or redo(records[f.frame_id])]
            again = sum(1 for f in all_frames if f.frame_id in records and redo(records[f.frame_id]) and not retry_failed)
            if todo and hasattr(instance, "check_endpoint"):
                instance.check_endpoint()  # a dead --api-base is refused now, not after minutes of retries
        except BaseException:
            asyncio.run(instance.aclose())
            raise
        if log:
            log(f"frames: {summary_line(_describe(all_frames, dataset))}")
            extra = f", of which {again} failed with {stopped_by}, the error that stopped the run" if again else ""
            log(f"resuming {run_dir}: {len(records)} frame(s) recorded, {len(todo)} to run{extra}")
        earlier = {f.frame_id: records[f.frame_id] for f in todo if f.frame_id in records}
        return _session(run_dir, todo, instance, prompts, config, progress, "retry-failed" if retry_failed else "resume",
                        len(all_frames) - len(todo), log, earlier)


def _prepare(backend: Backend, frames: Sequence[Any], dataset: Mapping[str, Any], *, recorded: Any = None,
             run_dir: Path | None = None, log: Log | None = None) -> None:
    """Let a backend that learns from the frame set (``baseline:ego``) fit before the run; on a resume, refuse a fit
    whose predictions differ from the recorded ones (``recorded``: the manifest's ``backend``). A fit's warnings
    (cross-fitted on a ``--sample`` / ``--limit`` subset: ``fit.subset.warning``; fitted on few scenes or frames:
    ``fit.warning``) are shown in one line each."""
    prepare = getattr(backend, "prepare", None)
    if prepare is None:
        return
    prepare(frames, dataset)
    fit = dict(backend.info).get("fit")
    subset = fit.get("subset") if isinstance(fit, Mapping) else None
    for warning in (subset.get("warning") if isinstance(subset, Mapping) else None,  # a --sample / --limit subset
                    fit.get("warning") if isinstance(fit, Mapping) else None):  # a fit on few scenes or frames
        if not warning:
            continue
        if log:
            log(str(warning))
        else:
            import warnings

            warnings.warn(str(warning), stacklevel=3)
    before = recorded.get("fit") if isinstance(recorded, Mapping) else None
    if run_dir is not None and isinstance(fit, Mapping) and isinstance(before, Mapping) \
            and fit.get("predictions_sha256") != before.get("predictions_sha256"):
        raise UserError(f"{run_dir}: {backend.name}'s fit gives other predictions now than when the run started "
                        f"(run: {before.get('predictions_sha256')}, now: {fit.get('predictions_sha256')}); start a new run "
                        "instead of resuming")


def _stopped_error(manifest: dict[str, Any]) -> str | None:
    """The error class that stopped the last session, if it stopped for one."""
    sessions = manifest.get("sessions") or []
    last = sessions[-1] if sessions and isinstance(sessions[-1], dict) else {}
    stopped = last.get("stopped")
    return stopped.get("error") if isinstance(stopped, dict) else None


def _same_frame_set(run_dir: Path, frames: Sequence[Any]) -> None:
    """Refuse to resume over frames that are not the run's frame set (the dataset changed since)."""
    recorded = read_frame_ids(run_dir)
    if recorded is None:
        return
    now = {f.frame_id for f in frames}
    before = set(recorded)
    if now != before:
        gone, new = len(before - now), len(now - before)
        raise UserError(f"{run_dir}: the frames loaded now are not the run's frame set ({gone} of its {len(before)} frames "
                        f"missing, {new} new): the dataset changed since the run started; start a new run instead of resuming")


def _version() -> str:
    from lightemma import __version__

    return __version__


def stderr_log(message: str) -> None:
    """The CLI's logger: one line to stderr."""
    print(f"lightemma run: {message}", file=sys.stderr, flush=True)
