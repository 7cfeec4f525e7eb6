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
import os
import platform
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from lightemma import __version__
from lightemma._signals import stop_signals
from lightemma.backends import Backend, ChatRequest, ChatResult, GenerationParams, backend_kind
from lightemma.backends.api import check_model, check_price, is_provider_host, litellm_model
from lightemma.backends.factory import run_backend
from lightemma.backends.retry import redact_url
from lightemma.backends.structured import ACTIONS_SCHEMA
from lightemma.errors import (  # Interrupted, STOP_SIGNALS: shared with the importer (which does not load this module)
    STOP_SIGNALS,
    Interrupted,
    RunFatalError,
    RunStopped,
    RunStoreError,
    UserError,
    os_error_line,
)
from lightemma.frames.fingerprint import of_dataset
from lightemma.frames.model import summary_line
from lightemma.frames.sample import describe_sample, sample_frames
from lightemma.inputs import check_inputs
from lightemma.models.catalog import resolve
from lightemma.nuscenes import load_frames
from lightemma.pipeline.budget import check_admits_a_frame, session_budget
from lightemma.pipeline.chain import ChainPolicy, run_frame
from lightemma.pipeline.config import RunConfig, short_repr
from lightemma.pipeline.estimate import estimate, no_bill
from lightemma.pipeline.progress import Progress
from lightemma.pipeline.sidecar import refresh as refresh_sidecar
from lightemma.pipeline.summary import format_summary, summarize
from lightemma.pipeline.trust import check_trusted
from lightemma.prompts import DEFAULT_PROMPT_SET, PromptSet, load_prompt_set
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


@dataclass
class RunResult:
    """What a run or resume produced."""

    run_dir: Path
    manifest: dict[str, Any]
    summary: dict[str, Any]
    frames_run: int  # frames run in this session

    def report(self) -> str:
        """The final summary as text."""
        return format_summary(
            self.summary, title=f"{self.manifest.get('display_name', self.manifest['model'])} — {self.run_dir}"
        )


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


def _git_revision() -> str | None:
    """``git describe`` of the source tree lightemma runs from (None outside a checkout)."""
    try:
        out = subprocess.run(
            ["git", "describe", "--always", "--dirty", "--abbrev=40"],
            cwd=Path(__file__).resolve().parent,
            capture_output=True,
            text=True,
            timeout=5,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None if out.returncode == 0 else None


def _policy(config: RunConfig) -> ChainPolicy:
    """The chain's policy ``config`` sets (a ValueError for a mode the chain does not know)."""
    p = config.prompting
    return ChainPolicy(
        params=GenerationParams(temperature=p.temperature, max_tokens=p.max_tokens),
        reask=p.reask,
        max_attempts=p.max_attempts,
        integrate_method=p.integrate_method,
        speed_range=p.speed_range,
        max_abs_curvature=p.max_abs_curvature,
        chain=p.chain,
        answer_format=p.answer_format,
        inputs=p.inputs,
        samples=p.samples,
    )


def _check_sampling(backend: Backend, config: RunConfig, log: Log | None) -> None:
    """``--samples K`` > 1: a backend that cannot sample is a one-line :class:`UserError` before any call; K > 1 at
    temperature 0 draws the same answer K times where decoding is deterministic (one warning line, the run goes on)."""
    k, temperature = config.prompting.samples, config.prompting.temperature
    if k == 1:
        return
    if backend.sampling() is None:
        raise UserError(
            f"--samples {k}: the {backend.name} backend cannot sample ({config.model} gives one answer per "
            "frame); drop --samples"
        )
    if temperature == 0 and log:
        log(
            f"warning: --samples {k} at --temperature 0: a deterministic model gives the same answer {k} times "
            "(set --temperature above 0 for independent samples); the run goes on"
        )


def _structured_output(backend: Backend, policy: ChainPolicy) -> dict[str, Any] | None:
    """For a structured run, how the backend constrains stage 3 (for the manifest); a UserError when it cannot."""
    if policy.answer_format != "structured":
        return None

    return {**backend.structured_output(), "schema": ACTIONS_SCHEMA.as_dict(), "parse_mode": policy.parse_mode}


def _served_model_info(
    info: Any, price: tuple[float, float] | None, gpus: int | None, *, served: bool
) -> dict[str, Any]:
    """The registry entry as a model served from another ``--api-base`` records it: not the provider's list price nor
    the registry's GPU count (the paper's hardware), but what ``--price`` / ``--gpus`` say (else unknown / 0)."""
    out = info.to_dict()
    if served:
        out.update(
            input_usd_per_mtok=None,
            output_usd_per_mtok=None,
            cache_read_usd_per_mtok=None,
            cache_write_usd_per_mtok=None,
            price_source=None,
            price_read=None,
            gpus=0,
        )
    if price is not None:
        out.update(input_usd_per_mtok=float(price[0]), output_usd_per_mtok=float(price[1]), price_source="--price")
    if gpus is not None:
        out["gpus"] = int(gpus)
    return out


def _load_frames(dataset: dict[str, Any]) -> Sequence[Any]:
    """Load the frames a manifest's ``dataset`` describes (dataroot, version, split/scenes, window, limit)."""
    if not dataset.get("dataroot") or not dataset.get("version"):
        raise UserError(
            "this run was made from frames passed in memory; pass frames=... to resume it",
            cli="this run was made from frames passed in memory, not from a dataset; resume it from "
            "Python: lightemma.resume(RUN_DIR, frames=FRAMES)",
        )

    frames = load_frames(
        dataset["dataroot"],
        dataset["version"],
        split=dataset.get("split"),
        scenes=dataset.get("scenes"),
        window=dataset.get("window", "reference"),
        on_bad_record=dataset.get("on_bad_record") or "skip",
    )
    return _subset(frames, dataset)


def _subset(frames: Any, dataset: Mapping[str, Any]) -> Sequence[Any]:
    """The frames a dataset request keeps: ``limit`` (the first N) or ``sample`` (N spread over scenes, seeded)."""
    sample = dataset.get("sample")
    if sample:
        if dataset.get("limit") is not None:
            raise UserError(
                "--sample and --limit are exclusive: --limit takes the first N frames, --sample N spreads N over the scenes"
            )
        n = int(sample["n"])
        if n > len(frames):  # a sample cannot hold more frames than the set: refused, not recorded as N frames
            raise UserError(
                f"--sample {n} is more than the {len(frames)} frames of the set; drop --sample to take them all"
            )
        return sample_frames(frames, n, int(sample.get("seed") or 0))
    return _head(frames, dataset.get("limit"))


def _require_frames(frames: Sequence[Any]) -> None:
    """An empty frame set is an error (it would make an empty run), naming why it is empty where that is known."""
    if len(frames):
        return
    skipped = list(getattr(frames, "skipped_scenes", []) or [])
    missing = list(getattr(frames, "missing_images", []) or [])
    if missing and not skipped:  # the frames exist; their images do not
        raise UserError(
            f"no frames to run: the CAM_FRONT image of every frame ({len(missing)}) is missing (see the "
            "warning above); --dataroot must be the folder holding samples/CAM_FRONT/*.jpg"
        )
    why = (
        f": every scene was skipped ({', '.join(skipped[:5])}{', …' if len(skipped) > 5 else ''}; see the warnings above)"
        if skipped
        else ""
    )
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
        out["sample"] = {**describe_sample(frames, dataset["sample"]["n"], dataset["sample"].get("seed") or 0)}

    out["fingerprint"] = of_dataset(out, getattr(frames, "frame_ids", None) or [f.frame_id for f in frames])
    return out


def resume_command(run_dir: str | os.PathLike[str], config: RunConfig | Mapping[str, Any] | None = None) -> str:
    """The ``lightemma run --resume`` command that continues ``run_dir``, with what a resume must be given again
    (:func:`resume` refuses it otherwise): the run's ``--api-base`` (as recorded, credentials replaced by ``***``:
    give the real ones), ``--api-key-env``, ``--cache`` (its path), ``--ray-address`` and ``--trust-remote-code``.
    ``config`` is the run's config (or the manifest's config block); without it, the bare command."""
    import shlex

    parts = ["lightemma", "run", "--resume", os.fspath(run_dir)]
    config = config.to_manifest() if isinstance(config, RunConfig) else (config or {})
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
    os.write(
        2,
        f"lightemma run: {signal.Signals(signum).name} again: exiting now; finished frames are saved. "
        f"Continue with: {command or resume_command(run_dir)}\n".encode(),
    )
    os._exit(128 + signum)


class _Stopped(Exception):
    """Raised into a frame's chain once the run has stopped: the frame is left unfinished (not written)."""


class _Guard(Backend):
    """The backend as the chain sees it during a session: once the run stops, no new call starts.

    With a ``budget`` (``--max-cost``), a frame starts only while its chain fits
    (:class:`~lightemma.pipeline.estimate.Budget`); the first that does not stops the run (cause ``budget``,
    resumable): no new frame starts, the frames in flight finish.
    """

    def __init__(self, backend: Backend, budget: Any = None) -> None:
        self.backend = backend
        self.name = backend.name
        self.stopped = False
        self.admitting = True  # False once the budget is spent: frames in flight go on, no new frame starts
        self.budget = budget

    @property
    def info(self) -> Any:
        return self.backend.info

    def sampling(self) -> str | None:
        return self.backend.sampling()

    async def generate_samples(self, request: ChatRequest, k: int) -> list[ChatResult]:
        """K samples through the backend's own way (one request with ``n``), each admitted like a call."""
        if k == 1 or self.backend.sampling() != "n":
            return await super().generate_samples(request, k)  # k requests through generate
        from dataclasses import replace

        admitted = [replace(request, sample=i, samples=k) for i in range(k)]
        return await self._admitted(admitted, lambda: self.backend.generate_samples(request, k))

    async def generate(self, requests: Sequence[ChatRequest]) -> list[ChatResult]:
        return await self._admitted(requests, lambda: self.backend.generate(requests))

    async def _admitted(self, requests: Sequence[ChatRequest], call: Callable[[], Any]) -> list[ChatResult]:
        """``call()``'s results, once every one of ``requests`` is admitted by the budget (``--max-cost``)."""
        if self.stopped:
            raise _Stopped
        if self.budget is None:
            return list(await call())
        reserved = 0.0
        for req in requests:
            held = self.budget.reserve(req.frame_id, first_call=req.stage == "scene" and req.attempt == 1)
            if held is None:
                self.budget.settle(reserved, 0.0)
                raise RunFatalError(self.budget.message(), cause="budget")
            reserved += held
        spent = 0.0
        try:
            results = list(await call())
            # a call of unknown cost (no usage reported, a price not known for its cached tokens) counts at the
            # estimate, never as free: the limit holds whatever a provider leaves out (a cache hit costs nothing)
            spent = sum(
                r.cost_cents if r.cost_cents is not None else (0.0 if r.cached else self.budget.per_call_cents)
                for r in results
            )
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


async def _execute(
    frames: Sequence[Any],
    backend: Backend,
    writer: RunWriter,
    prompts: PromptSet,
    policy: ChainPolicy,
    concurrency: int,
    bar: Progress,
    earlier: Mapping[str, dict[str, Any]],
    budget: Any = None,
    command: str | None = None,
) -> _Outcome:
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
                halt(
                    RunFatalError(
                        f"{exc}: the model's answers are that long; not written (a resume asks that frame "
                        "again; a smaller --max-tokens bounds the answers)",
                        cause="record-too-large",
                        error="RecordTooLargeError",
                    )
                )
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
        raise RunStoreError(
            os_error_line(exc, "update the manifest in") + f"; the frames written so far are safe in "
            f"{run_dir / FRAMES_FILE}; after freeing space, continue with: "
            f"{_command or resume_command(run_dir)}"
        ) from None


def _session(
    run_dir: Path,
    todo: Sequence[Any],
    backend: Backend,
    prompts: PromptSet,
    config: RunConfig,
    progress: bool,
    kind: str,
    already: int,
    log: Log | None,
    earlier: Mapping[str, dict[str, Any]] | None = None,
) -> RunResult:
    """Run ``todo`` into ``run_dir`` and mark the run finished; the shared tail of run and resume.

    ``earlier``: the failed records of frames run again (frame id -> record), whose attempts the new records keep.

    Raises :class:`RunStopped` (after saving the session) when the run stopped for a run-fatal cause.
    """
    try:
        budget = session_budget(run_dir, config, todo, backend, prompts, resuming=kind != "run")
    except BaseException:
        asyncio.run(backend.aclose())
        raise
    manifest = read_manifest(run_dir)
    command = resume_command(run_dir, config)
    sessions = list(manifest.get("sessions", []))
    sessions.append(
        {
            "kind": kind,
            "started_at": _now(),
            "frames_todo": len(todo),
            "concurrency": config.concurrency,
            "timeout": config.timeout,
            "rpm": config.api.rpm,
            "tpm": config.api.tpm,
            "pid": os.getpid(),
        }
    )
    _write_manifest(run_dir, command, sessions=sessions, finished_at=None)
    try:
        writer = RunWriter(run_dir)
    except OSError as exc:
        asyncio.run(backend.aclose())
        raise RunStoreError(
            os_error_line(exc, "open the frame records") + f"; continue later with: {command}"
        ) from None
    # a batch backend journals its batches in the run directory and checks each finished wave's reported cost
    # against --max-cost
    backend.attach(run_dir, log, budget=budget)
    concurrency = max(1, len(todo)) if backend.wants_all_frames else config.concurrency
    bar = Progress(already + len(todo), enabled=progress, initial=already)
    start = time.perf_counter()
    # SIGINT, SIGTERM, SIGHUP stop the session like Ctrl-C: the frames in flight are cut off, the session's wall time
    # is recorded, the lock released; a second one exits at once (frames are whole lines, .lock.pid removed first)
    with stop_signals(lambda signum: _exit_now(run_dir, signum, command)):
        try:
            with writer:
                if todo:
                    outcome = asyncio.run(
                        _execute(
                            todo,
                            backend,
                            writer,
                            prompts,
                            _policy(config),
                            concurrency,
                            bar,
                            earlier or {},
                            budget,
                            command,
                        )
                    )
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
    refresh_sidecar(run_dir, log)
    contents = read_run(run_dir)
    summary = summarize(_in_set(contents.records, read_frame_ids(run_dir)), wall_seconds=wall, frames_run=outcome.done)
    sessions[-1].update(finished_at=_now(), frames_run=outcome.done, wall_seconds=round(wall, 3))
    replicas = backend.replica_report
    if replicas:
        sessions[-1]["replicas"] = replicas
    batches = backend.batch_report
    if batches:
        sessions[-1]["batch"] = batches
        summary.update(batch=True, batch_turnaround_s=batches.get("turnaround_s_mean"))
    failed_cache = backend.cache_failure
    if failed_cache:
        sessions[-1]["cache_failure"] = failed_cache  # the session ran uncached from then on
    images = backend.image_report
    if images:
        sessions[-1]["images_reencoded"] = images
        if log:
            log(
                f"{images['count']} image(s) were larger than the provider accepts and were re-encoded to fit "
                "(see images_reencoded in the manifest)"
            )
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
        raise RunStopped(
            f"{stop} — the run stopped; {outcome.done} frame(s) finished in this session are saved in {run_dir}; "
            f"{after}",
            cause=stop.cause,
            error=stop.error,
            run_dir=run_dir,
            frames_run=outcome.done,
        )
    manifest = _write_manifest(run_dir, command, sessions=sessions, finished_at=_now(), summary=summary)
    return RunResult(run_dir=run_dir, manifest=manifest, summary=summary, frames_run=outcome.done)


def estimate_run(
    model: str,
    *,
    frames: Sequence[Any],
    prompt_set: str = DEFAULT_PROMPT_SET,
    chain: str = "independent",
    answer_format: str = "text",
    inputs: str = "full",
    max_tokens: int = 512,
    api_base: str | None = None,
    backend: str | None = None,
    price: Sequence[float] | None = None,
    samples: int = 1,
) -> Any:
    """The :class:`~lightemma.pipeline.estimate.Estimate` of running ``model`` over ``frames`` with the prompts and
    images of ``inputs`` — nothing is called; ``samples`` K chains per frame count K times.

    A model with no provider bill (a baseline, a local ``hf`` / ``vllm`` backend) raises a one-line
    :class:`~lightemma.errors.UserError` (:func:`~lightemma.pipeline.estimate.no_bill`); so does a model a
    real run would refuse (not in the registry and no provider litellm knows).
    """
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

    if price is not None:
        check_price(price)
    served_from = redact_url(api_base) if api_base and not is_provider_host(provider, api_base) else None
    return estimate(
        frames,
        info,
        provider,
        prompts,
        max_tokens=max_tokens,
        chain=chain,
        inputs=inputs,
        given_price=price,
        served_from=served_from,
        samples=samples,
    )


def _backend(config: RunConfig, output: Path, log: Log | None) -> Backend:
    """The backend ``config`` names (:func:`lightemma.backends.factory.run_backend`): the API key is checked before
    anything else happens. ``output``: the directory a relative response-cache path is under."""
    api, local = config.api, config.local
    return run_backend(
        config.model,
        backend=config.backend,
        api_base=api.api_base,
        output=output,
        timeout=config.timeout,
        rpm=api.rpm,
        tpm=api.tpm,
        max_retries=api.max_retries,
        backoff_base=api.backoff_base,
        backoff_cap=api.backoff_cap,
        transport=api.transport or "litellm",
        api_key_env=api.api_key_env,
        price=api.price,
        cache=api.cache,
        backend_options=dict(local.backend_options),
        replicas=local.replicas or 1,
        ray_address=local.ray_address,
        gpus_per_replica=local.gpus_per_replica,
        batch=config.batch.enabled,
        batch_poll=config.batch.poll if config.batch.enabled else None,
        log=log,
    )


def run(
    model: str | None = None,
    *,
    config: RunConfig | None = None,
    frames: Sequence[Any] | None = None,
    output: str | os.PathLike[str] = "runs",
    progress: bool = True,
    log: Log | None = None,
    **settings: Any,
) -> RunResult:
    """Run ``model`` over a frame set through the three-stage chain; returns the run's summary.

    The run's settings are a :class:`~lightemma.pipeline.config.RunConfig`: given as ``config=``, or built from
    ``model`` and the keyword ``settings`` (:meth:`RunConfig.of <lightemma.pipeline.config.RunConfig.of>`: every
    setting by its name — ``dataroot``, ``version`` (default ``v1.0-test``), ``split``, ``scenes``, ``window``
    (``reference``), ``limit``, ``sample`` / ``sample_seed``, ``on_bad_record`` (``skip``); ``backend``,
    ``api_base``, ``api_key_env``, ``price``, ``gpus``, ``timeout`` (120 s), ``max_retries`` (6), ``backoff_base`` /
    ``backoff_cap``, ``rpm``, ``tpm``, ``cache``, ``transport``; ``concurrency`` (16); ``temperature`` (0),
    ``max_tokens`` (512), ``reask``, ``max_attempts`` (5), ``integrate_method`` (``euler``), ``speed_range``
    ((-10, 50) m/s), ``max_abs_curvature`` (1 1/m), ``chain``, ``answer_format``, ``inputs``, ``prompt_set``;
    ``backend_options``, ``replicas``, ``ray_address``, ``gpus_per_replica``; ``batch``, ``batch_poll`` (30 s);
    ``max_cost_cents``; ``name``). A setting out of its kind or range raises
    :class:`~lightemma.pipeline.config.InvalidSetting` naming it, before any work.

    Frames come from ``frames`` (any sequence of Frame-like objects, e.g. a
    :class:`~lightemma.frames.FrameSet`) or are loaded with :func:`lightemma.load_frames` from
    ``dataroot``/``version``/``split``/``scenes``/``window``; ``limit`` keeps the first N, ``sample`` N frames
    spread over the scenes (seeded by ``sample_seed``, :mod:`lightemma.frames.sample`). ``output``: the directory
    the run directory is made in. ``cache=True`` keeps a response cache at ``<output>/cache.sqlite`` (or give a
    path). ``transport="direct"`` talks to an OpenAI-compatible ``api_base`` without litellm (less CPU per call).
    ``on_bad_record`` (``skip`` or ``error``) is what loading does with a scene whose pose or timestamp is invalid.
    ``replicas``, ``ray_address`` and ``gpus_per_replica`` run a local model (hf, vllm) as replicas over Ray
    (:mod:`lightemma.backends.ray`; docs/local.md). ``chain`` (``independent``, the paper's, or ``conversation``)
    and ``answer_format`` (``text``, the paper's, or ``structured``) choose the request variant (docs/run.md); a
    backend that cannot constrain its answers is a :class:`~lightemma.errors.UserError` before any work.
    ``inputs`` is the input ablation (:mod:`lightemma.inputs`), recorded in the manifest, kept by a resume.
    ``speed_range`` (m/s) and ``max_abs_curvature`` (1/m) are the parser's plausibility limits (None disables one;
    see :func:`lightemma.parse_actions`), recorded as ``params.parse`` and kept by a resume. ``batch=True`` sends
    the chain through the provider's batch interface at its batch price (:mod:`lightemma.backends.batch`).
    ``max_cost_cents`` stops the run (resumable) before a call would take its spending past the limit
    (:mod:`lightemma.pipeline.budget`). ``name`` is the run's name, shown in tables instead of its id.

    A missing API key, an unknown model or an empty frame set raises :class:`~lightemma.errors.UserError` before
    any work. A run-fatal cause met while running raises :class:`~lightemma.errors.RunStopped` once what finished
    is saved.
    """
    if config is None:
        if model is None:
            raise TypeError("run() needs a model (or config=RunConfig(...))")
        config = RunConfig.of(model, **settings)
    elif model is not None or settings:
        raise TypeError("run(config=...) takes every setting from the config: give no model or setting beside it")
    elif not isinstance(config, RunConfig):
        raise TypeError(f"config must be a RunConfig, got {type(config).__name__}")
    if frames is None and config.dataset.dataroot is None:
        raise UserError(
            "give dataroot (a nuScenes directory) or frames=...", cli="give --dataroot (a nuScenes directory)"
        )
    info = resolve(config.model)
    try:
        policy = _policy(config)  # validates reask / attempts / method / chain / answer format before any work
    except ValueError as exc:
        raise UserError(str(exc)) from None
    if policy.inputs != "full" and backend_kind(config.model, config.backend, config.api.api_base) == "baseline":
        raise UserError(
            f"--inputs {policy.inputs} is an ablation of what a model is shown; {config.model} reads the "
            "frame's numbers itself and is shown nothing: drop --inputs"
        )
    prompts = load_prompt_set(config.prompting.prompt_set).select(policy.chain, policy.answer_format, policy.inputs)
    output = Path(output)
    instance = _backend(config, output, log)
    settings_block = config.to_manifest()
    dataset = settings_block["dataset"]  # the request, as given: what a resume loads again
    price, gpus = config.api.price, config.api.gpus
    try:
        structured = _structured_output(instance, policy)
        _check_sampling(instance, config, log)  # a backend that cannot sample: refused before any call
        instance.check_endpoint()  # a dead --api-base is refused now, not after minutes of retries
        frames = _load_frames(dataset) if frames is None else _subset(frames, dataset)
        _require_frames(frames)
        check_admits_a_frame(config, frames, instance, prompts)  # a limit that admits no frame: refused now
        planned = None
        if instance.info.get("kind") == "api":  # a paid run: its bill first, in one line
            p = config.prompting
            planned = estimate_run(
                config.model,
                frames=frames,
                prompt_set=p.prompt_set,
                chain=p.chain,
                answer_format=p.answer_format,
                inputs=p.inputs,
                max_tokens=p.max_tokens,
                api_base=config.api.api_base,
                backend=config.backend,
                price=price,
                samples=p.samples,
            )
        _prepare(instance, frames, dataset, log=log)
        manifest = {
            "model": config.model,
            **({"name": config.name.strip()} if config.name else {}),
            "display_name": info.display_name,
            "model_info": info.to_dict(),
            "backend": dict(instance.info),
            "config": settings_block,
            "params": {**policy.to_dict(), "sent": instance.effective_params(policy.params)},
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
        if instance.served_elsewhere or gpus is not None:
            manifest["model_info"] = _served_model_info(info, price, gpus, served=instance.served_elsewhere)
            if gpus is not None:
                manifest["gpus"] = gpus
        run_dir = create_run_dir(output, config.model, manifest, frame_ids=[f.frame_id for f in frames])
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
                mode = "batch mode" if config.batch.enabled else f"concurrency {config.concurrency}"
                log(f"run directory: {run_dir}  ({len(frames)} frames, {mode})")
            return _session(run_dir, frames, instance, prompts, config, progress, "run", 0, log)
        except KeyboardInterrupt as exc:  # before the session's own handlers: said here, with the resume
            if log and not getattr(exc, "reported", False):
                how = f" by {exc.name}" if isinstance(exc, Interrupted) else ""
                log(f"interrupted{how}; finished frames are saved. Continue with: {resume_command(run_dir, config)}")
                exc.reported = True  # type: ignore[attr-defined]  # said: the command line adds no second line
            raise


def resume(
    run_dir: str | os.PathLike[str],
    *,
    retry_failed: bool = False,
    frames: Sequence[Any] | None = None,
    concurrency: int | None = None,
    replicas: int | None = None,
    ray_address: str | None = None,
    gpus_per_replica: float | None = None,
    max_cost_cents: float | None = None,
    api_base: str | None = None,
    api_key_env: str | None = None,
    cache: str | bool | None = None,
    backend_options: Mapping[str, Any] | None = None,
    timeout: float | None = None,
    rpm: float | None = None,
    tpm: float | None = None,
    progress: bool = True,
    log: Log | None = None,
) -> RunResult:
    """Finish the run in ``run_dir`` from its manifest (:meth:`RunConfig.from_manifest
    <lightemma.pipeline.config.RunConfig.from_manifest>`), skipping frames already recorded.

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
    sessions included); each is checked as :func:`run` checks it (:class:`~lightemma.pipeline.config.InvalidSetting`).
    A batch run polls the batches its journal names before submitting anything (:mod:`lightemma.backends.batch`).

    The manifest never chooses where requests, keys or writes go, nor what code runs
    (:func:`lightemma.pipeline.trust.check_trusted`): ``api_base``, ``api_key_env`` and ``cache`` must be given as
    the run had them (its endpoint, key variable and response cache); a run whose replicas joined a Ray cluster
    needs a ``ray_address`` given now; and backend options that can fetch or run code (``trust_remote_code``,
    ``engine_options``, …: all but :data:`~lightemma.pipeline.trust.INERT_BACKEND_OPTIONS`) must be given again,
    equal, in ``backend_options``. Else a one-line :class:`~lightemma.errors.UserError` before anything is sent,
    loaded or written.
    """
    run_dir = Path(run_dir)
    manifest = read_manifest(run_dir)
    raw = manifest.get("config")
    if not isinstance(raw, Mapping) or not raw.get("model"):
        raise RunStoreError(f"{run_dir}: the manifest has no run config; it was not written by `lightemma run`")
    config = RunConfig.from_manifest(raw, run_dir)
    for name, kind, what, needed in (
        ("model", str, "text", True),
        ("prompt_set", dict, "an object", False),
        ("dataset", dict, "an object", False),
        ("sessions", list, "a list", False),
    ):
        value = manifest.get(name)
        if (needed or value is not None) and not isinstance(value, kind):  # the manifest's own blocks, beside config
            raise UserError(f"{run_dir}: the manifest's {name} is {short_repr(value)}, not {what}; start a new run")
    check_trusted(run_dir, config, api_base, api_key_env, cache, ray_address, backend_options)
    given = {
        "timeout": timeout,
        "rpm": rpm,
        "tpm": tpm,
        "concurrency": concurrency,
        "max_cost_cents": max_cost_cents,
        "replicas": replicas,
        "ray_address": ray_address,
        "gpus_per_replica": gpus_per_replica,
    }
    session = {
        k: float(v) if k in ("timeout", "rpm", "tpm") and isinstance(v, int | float) else v
        for k, v in given.items()
        if v is not None
    }
    config = config.replace(**session, api_base=api_base)  # the endpoint as given (the trust policy's check)
    recorded = manifest.get("prompt_set", {})
    # a shipped name or a file's path (the recorded name is the set's own), as the run's variant uses it
    p = config.prompting
    prompts = load_prompt_set(p.prompt_set).select(p.chain, p.answer_format, p.inputs)
    if prompts.hash != recorded.get("hash") or prompts.variant_hash != recorded.get("variant_hash"):
        run_hash, now_hash = (
            (recorded.get("hash"), prompts.hash)
            if prompts.hash != recorded.get("hash")
            else (recorded.get("variant_hash"), prompts.variant_hash)
        )
        raise UserError(
            f"{run_dir}: prompt set {prompts.name!r} has changed since this run started "
            f"(run: {run_hash}, now: {now_hash}); start a new run instead of resuming"
        )
    with RunLock(run_dir):  # before anything is read for the todo list: a second writer would redo the same frames
        manifest = read_manifest(run_dir)  # as the last writer left it
        try:
            instance = _backend(config, run_dir.parent.parent, log)
        except (TypeError, AttributeError) as exc:  # a hand-edited manifest: another backend's option, a wrong type
            raise UserError(
                f"{run_dir}: the manifest's settings cannot build the run's backend ({type(exc).__name__}: "
                f"{short_repr(str(exc), 160)}); start a new run"
            ) from None
        try:
            _structured_output(instance, _policy(config))
            _check_sampling(instance, config, log)
            dataset = config.dataset.to_manifest()
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
            again = sum(
                1 for f in all_frames if f.frame_id in records and redo(records[f.frame_id]) and not retry_failed
            )
            if todo:
                instance.check_endpoint()  # a dead --api-base is refused now, not after minutes of retries
        except BaseException:
            asyncio.run(instance.aclose())
            raise
        if log:
            log(f"frames: {summary_line(_describe(all_frames, dataset))}")
            extra = f", of which {again} failed with {stopped_by}, the error that stopped the run" if again else ""
            log(f"resuming {run_dir}: {len(records)} frame(s) recorded, {len(todo)} to run{extra}")
        earlier = {f.frame_id: records[f.frame_id] for f in todo if f.frame_id in records}
        return _session(
            run_dir,
            todo,
            instance,
            prompts,
            config,
            progress,
            "retry-failed" if retry_failed else "resume",
            len(all_frames) - len(todo),
            log,
            earlier,
        )


def _prepare(
    backend: Backend,
    frames: Sequence[Any],
    dataset: Mapping[str, Any],
    *,
    recorded: Any = None,
    run_dir: Path | None = None,
    log: Log | None = None,
) -> None:
    """Let a backend that learns from the frame set (``baseline:ego``) fit before the run; on a resume, refuse a fit
    whose predictions differ from the recorded ones (``recorded``: the manifest's ``backend``). A fit's warnings
    (cross-fitted on a ``--sample`` / ``--limit`` subset: ``fit.subset.warning``; fitted on few scenes or frames:
    ``fit.warning``) are shown in one line each."""
    backend.prepare(frames, dataset)
    fit = dict(backend.info).get("fit")
    subset = fit.get("subset") if isinstance(fit, Mapping) else None
    for warning in (
        subset.get("warning") if isinstance(subset, Mapping) else None,  # a --sample / --limit subset
        fit.get("warning") if isinstance(fit, Mapping) else None,
    ):  # a fit on few scenes or frames
        if not warning:
            continue
        if log:
            log(str(warning))
        else:
            import warnings

            warnings.warn(str(warning), stacklevel=3)
    before = recorded.get("fit") if isinstance(recorded, Mapping) else None
    if (
        run_dir is not None
        and isinstance(fit, Mapping)
        and isinstance(before, Mapping)
        and fit.get("predictions_sha256") != before.get("predictions_sha256")
    ):
        raise UserError(
            f"{run_dir}: {backend.name}'s fit gives other predictions now than when the run started "
            f"(run: {before.get('predictions_sha256')}, now: {fit.get('predictions_sha256')}); start a new run "
            "instead of resuming"
        )


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
        raise UserError(
            f"{run_dir}: the frames loaded now are not the run's frame set ({gone} of its {len(before)} frames "
            f"missing, {new} new): the dataset changed since the run started; start a new run instead of resuming"
        )


def _version() -> str:
    return __version__


def stderr_log(message: str) -> None:
    """The CLI's logger: one line to stderr."""
    print(f"lightemma run: {message}", file=sys.stderr, flush=True)
