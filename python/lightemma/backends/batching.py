"""Micro-batching for local backends: many single-request ``generate`` calls, one batched forward pass.

The runner drives every backend the same way: one three-stage chain per frame,
up to ``concurrency`` frames in flight, each stage awaiting
``backend.generate([request])``. A local model is only fast when it answers
many prompts at once, so :class:`MicroBatcher` sits between the two:

* ``submit`` puts each request on a queue and awaits its future;
* one worker thread — the only thread that touches the model — takes the
  oldest pending request, waits at most ``batch_window`` seconds for the queue
  to hold ``batch_size`` requests that can share its batch, runs ONE batched
  call of ``run_batch`` and resolves each request's future with its result.

Requests share a batch only when they are of the same stage and carry the same
:class:`~lightemma.backends.base.GenerationParams` (and the same response schema, if any); when several stages are
pending, the batch is built around the stage of the *oldest* pending request,
and requests of other stages wait, in order, for a later batch. Because frames
move through the chain in lockstep (all stage-1 requests arrive together, then
their stage-2 requests, …), this is stage-synchronous batching in practice:
stage 1 for a batch of frames, then stage 2, then stage 3, then re-asks.

The batcher is loop-agnostic (results are handed back with
``call_soon_threadsafe`` to the loop that submitted them), so one backend can
serve several ``asyncio.run`` sessions (a run, then a resume). If ``run_batch``
raises, each request of that batch gets a
:class:`~lightemma.backends.base.ChatResult` carrying the error class and message
(a per-frame failure: the chain re-asks). When the *identical* exception (class
and message) ends two consecutive batches holding at least two distinct frames,
the model cannot generate at all (a library regression, a broken checkpoint):
the batcher turns fatal, and that batch's requests, every queued one and every
later ``submit`` raise :class:`~lightemma.errors.RunFatalError` with the line
``describe_fatal`` makes of the exception.
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from lightemma.backends.base import ChatRequest, ChatResult
from lightemma.backends.retry import short_message
from lightemma.errors import InputError, RunFatalError

RunBatch = Callable[[Sequence[ChatRequest]], list[ChatResult]]
DescribeFatal = Callable[[BaseException], str]

DEFAULT_BATCH_WINDOW = 0.01  # seconds the worker waits for a batch to fill
CLOSE_GRACE = 5.0  # seconds aclose waits for a running batch before leaving its (daemon) thread behind


class Timeout(Exception):
    """A batch that ran past its deadline (``--timeout``); recorded as error class ``Timeout``."""


@dataclass
class BatchStats:
    """What the worker has done so far: batches run, requests answered, the size of each batch."""

    batches: int = 0
    requests: int = 0
    seconds: float = 0.0
    sizes: list[int] = field(default_factory=list)

    def to_dict(self) -> dict[str, float | int]:
        return {
            "batches": self.batches,
            "requests": self.requests,
            "seconds": round(self.seconds, 4),
            "mean_batch_size": round(self.requests / self.batches, 3) if self.batches else 0.0,
            "max_batch_size": max(self.sizes, default=0),
        }


def _retrieved(future: asyncio.Future[ChatResult]) -> None:
    """Mark a finished future's exception as seen (the caller that awaits it, if any, still gets it)."""
    if not future.cancelled():
        future.exception()


@dataclass
class _Pending:
    request: ChatRequest
    future: asyncio.Future[ChatResult]
    loop: asyncio.AbstractEventLoop

    @property
    def key(self) -> tuple[str, object, object]:
        return (self.request.stage, self.request.params, self.request.response_schema)


def error_result(exc: BaseException, seconds: float = 0.0) -> ChatResult:
    """A failed call as a result: the exception's class and a one-line message, never model text."""
    message = short_message(exc) or type(exc).__name__
    return ChatResult(text=None, seconds=seconds, error=type(exc).__name__, error_message=message)


class MicroBatcher:
    """Gather concurrently submitted requests into batches of ``batch_size`` run by one worker thread."""

    def __init__(
        self,
        run_batch: RunBatch,
        *,
        batch_size: int = 8,
        batch_window: float = DEFAULT_BATCH_WINDOW,
        name: str = "lightemma-batcher",
        describe_fatal: DescribeFatal | None = None,
        deadline: float | None = None,
    ) -> None:
        if batch_size < 1:
            raise InputError(f"batch_size must be at least 1, got {batch_size}")
        if batch_window < 0:
            raise InputError(f"batch_window must be >= 0 seconds, got {batch_window}")
        self.batch_size = batch_size
        self.batch_window = batch_window
        self.stats = BatchStats()
        self._run_batch = run_batch
        self._name = name
        self._queue: deque[_Pending] = deque()
        self._cond = threading.Condition()
        self._thread: threading.Thread | None = None
        self._closed = False
        self._describe_fatal = describe_fatal or (lambda exc: f"{type(exc).__name__}: {short_message(exc)}")
        self.fatal: RunFatalError | None = None  # set once the model is found unable to generate
        # seconds one batch may run (the backend stops generation there itself); a batch still running
        # ``deadline + grace`` seconds after it started is hung, and the batcher turns fatal (watchdog)
        self.deadline = deadline
        self.grace = max(5.0, min(10.0, deadline)) if deadline else 0.0
        self._running_since: float | None = None
        self.abandoned = False  # aclose left a worker thread stuck in the model behind
        self._failure: tuple[str, str] | None = None  # the exception that ended the last batch(es)
        self._failure_batches = 0
        self._failure_frames: set[str] = set()

    # -- the asyncio side -------------------------------------------------------------------------

    async def submit(self, requests: Sequence[ChatRequest]) -> list[ChatResult]:
        """Queue ``requests`` and wait for their results, in order."""
        if not requests:
            return []
        loop = asyncio.get_running_loop()
        pending = [_Pending(r, loop.create_future(), loop) for r in requests]
        with self._cond:
            if self.fatal is not None:
                raise self.fatal
            if self._closed:
                raise RuntimeError("the backend is closed")
            self._queue.extend(pending)
            self._ensure_worker()
            self._cond.notify()
        futures = [p.future for p in pending]
        for future in futures:  # a run that stops leaves these unawaited: no "Future exception was never retrieved"
            future.add_done_callback(_retrieved)
        if self.deadline is None:
            return list(await asyncio.gather(*futures))
        while True:  # the watchdog: a batch that never returns turns the batcher fatal instead of hanging the run
            await asyncio.wait(futures, timeout=min(0.5, self.deadline))
            if all(f.done() for f in futures):
                return [f.result() for f in futures]
            self._check_hung()
            if self.fatal is not None:
                raise self.fatal

    def _check_hung(self) -> None:
        since = self._running_since
        if self.fatal is not None or since is None or self.deadline is None:
            return
        if time.monotonic() - since <= self.deadline + self.grace:
            return
        self.fatal = RunFatalError(
            f"the model did not finish a batch within --timeout {self.deadline:g} s (+{self.grace:g} s grace) and its "
            "generation cannot be interrupted; the run stops here (finished frames are saved) — raise --timeout, or lower "
            "--batch-size / --max-tokens",
            cause="local-timeout",
            error="Timeout",
        )
        with self._cond:
            leftover = list(self._queue)
            self._queue.clear()
        for p in leftover:
            self._resolve(p, self.fatal)

    async def aclose(self) -> None:
        """Stop the worker after the batch it is running; requests still queued get an error result."""
        with self._cond:
            self._closed = True
            leftover = list(self._queue)
            self._queue.clear()
            self._cond.notify_all()
            thread = self._thread
        for p in leftover:
            self._resolve(p, error_result(RuntimeError("the backend was closed before this request ran")))
        if thread is not None and thread is not threading.current_thread():
            # bounded: a worker stuck in the model (a generate that never returns) is left behind, a daemon
            # thread that ends with the process, rather than holding the run (and Ctrl-C) forever
            grace = 0.0 if self.fatal is not None and self.fatal.cause == "local-timeout" else CLOSE_GRACE
            end = time.monotonic() + grace
            while thread.is_alive() and time.monotonic() < end:
                await asyncio.sleep(0.02)
            self.abandoned = thread.is_alive()

    def _ensure_worker(self) -> None:
        if self._thread is None or not self._thread.is_alive():
            self._thread = threading.Thread(target=self._work, name=self._name, daemon=True)
            self._thread.start()

    # -- the worker thread ------------------------------------------------------------------------

    def _take_batch(self) -> list[_Pending] | None:
        """Block for the next batch (None when closed): the oldest request plus same-key requests."""
        with self._cond:
            while not self._queue and not self._closed:
                self._cond.wait()
            if self._closed:
                return None
            key = self._queue[0].key
            deadline = time.monotonic() + self.batch_window
            while sum(p.key == key for p in self._queue) < self.batch_size and not self._closed:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    break
                self._cond.wait(remaining)
            if self._closed:
                return None
            batch: list[_Pending] = []
            rest: deque[_Pending] = deque()
            for p in self._queue:
                (batch if p.key == key and len(batch) < self.batch_size else rest).append(p)
            self._queue = rest
            return batch

    def _work(self) -> None:
        while (batch := self._take_batch()) is not None:
            live = [p for p in batch if not p.future.cancelled()]
            if not live:
                continue
            if self.fatal is not None:
                for p in live:
                    self._resolve(p, self.fatal)
                continue
            start = time.perf_counter()
            self._running_since = time.monotonic()
            try:
                results = self._run_batch([p.request for p in live])
                if len(results) != len(live):
                    raise RuntimeError(f"run_batch returned {len(results)} results for {len(live)} requests")
                self._failure, self._failure_batches, self._failure_frames = None, 0, set()
            except BaseException as exc:  # noqa: BLE001 - every request of the batch gets the error, none raises;
                # even SystemExit: it would end this thread with the batch's futures never resolved
                results = [error_result(exc, time.perf_counter() - start) for _ in live]
                self._note_failure(exc, live)
            finally:
                self._running_since = None
            elapsed = time.perf_counter() - start
            self.stats.batches += 1
            self.stats.requests += len(live)
            self.stats.seconds += elapsed
            self.stats.sizes.append(len(live))
            for p, result in zip(live, results):
                self._resolve(p, self.fatal if self.fatal is not None else result)

    def _note_failure(self, exc: BaseException, batch: list[_Pending]) -> None:
        """Count consecutive batches ended by the identical exception; turn fatal at two batches, two frames."""
        signature = (type(exc).__name__, short_message(exc))
        if signature != self._failure:
            self._failure, self._failure_batches, self._failure_frames = signature, 0, set()
        self._failure_batches += 1
        self._failure_frames.update(p.request.frame_id for p in batch)
        if self._failure_batches >= 2 and len(self._failure_frames) >= 2:
            try:
                line = self._describe_fatal(exc)
            except Exception:  # noqa: BLE001 - the description must not hide the failure
                line = f"{signature[0]}: {signature[1]}"
            self.fatal = RunFatalError(line, cause="local-model", error=signature[0])

    @staticmethod
    def _resolve(p: _Pending, result: ChatResult | BaseException) -> None:
        def settle() -> None:
            if p.future.done():
                return
            if isinstance(result, BaseException):
                p.future.set_exception(result)
            else:
                p.future.set_result(result)

        try:
            p.loop.call_soon_threadsafe(settle)
        except RuntimeError:  # the submitting loop is gone; nobody is waiting
            pass
