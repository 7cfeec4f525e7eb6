"""``lightemma run --batch``: the chain through the providers' batch interfaces, at their batch prices.

:class:`BatchBackend` is a backend like any other (:mod:`lightemma.backends.base`): the chain is unchanged.
Every frame of a run is in flight at once; each frame's next request is queued, and once no new request has
arrived for ``idle_seconds`` the queue goes out as one *wave* — stage 1 of every pending frame, then stage 2,
then stage 3, re-asks in further waves. A wave is split into batches within the provider's limits (requests
and bytes per batch, :class:`~lightemma.backends.batch.adapter.BatchAdapter`), each polled with backoff
(``poll_seconds``, ×1.5 per poll, at most ``poll_cap``).

Every request has a custom id derived from what it asks (model, frame, stage, attempt, prompt, earlier turns,
image, parameters): the same request gets the same id in a resumed run. Each batch is journaled in the run
directory before it is created and again once it has an id (:mod:`lightemma.backends.batch.journal`: whole lines,
checked and fsynced; a line that fails creates nothing). A create whose answer is lost (5xx, dropped connection,
--timeout) is looked up by its token (:meth:`BatchAdapter.find`, every page of the provider's list back to the
submission) before it is created again; a resumed run answers a journaled request from its batch (polled again, or
its saved results) — never resubmitted, never billed twice. Results are matched by custom id in whatever order they
come, and must add up to the provider's own counts (read again, then the run stops: what the provider ran is never
asked again). A request the provider never ran (expired) is resubmitted in a new batch up to ``max_resubmits``
times per frame and stage in a session, whatever the attempt, then fails as ``BatchExpired``; a request the
provider answered with an error fails with its reason (``BatchRequestError``), which the chain re-asks like any API
error. A canceled batch stops the run (a resume submits what it never ran). A batch the provider fails as a whole
ran nothing: it is journaled ``failed``; one failed at OpenAI's enqueued-token limit is resubmitted, any other
stops the run with its reason (the resume submits its requests again). With ``--max-cost``, each wave goes out only
while the finished waves' provider-reported cost leaves room for every call the admitted frames hold
(:meth:`BatchBackend._check_budget`).

Adapters: OpenAI (and OpenAI-compatible ``--api-base`` servers), Anthropic Message Batches and Gemini batch mode,
each over its HTTP API, every reply read within :func:`~lightemma.backends.batch.adapter.results_limit` (litellm
1.106.2 creates neither Anthropic nor Gemini batches, and takes no bounded client for OpenAI's). Costs are
the provider-reported tokens at the registry's batch prices, or at ``--price`` (:func:`lightemma.models.prices.run_price`).
A call's ``seconds`` is its batch's turnaround (submission to results): per-frame latency has no meaning in
batch mode, and Table I prints it as ``n/a``.

Keys and endpoints follow :class:`~lightemma.backends.api.APIBackend`, which decides them once: a provider's key
goes only to its own host (or one ``LIGHTEMMA_PROVIDER_HOSTS`` declares); any other ``--api-base`` speaks the
OpenAI batch protocol and gets the key of ``--api-key-env NAME`` or none. Credentials in ``--api-base``
(``user:pw@``) go as Basic auth, never into the journal, a record or a message.
"""

from __future__ import annotations

import asyncio
import functools
import hashlib
import json
import secrets
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from lightemma.backends.base import Backend, ChatRequest, ChatResult, GenerationParams
from lightemma.backends.batch.adapter import (
    FAILED,
    PENDING,
    BatchAdapter,
    BatchHTTPError,
    BatchStatus,
    BatchUnconfirmed,
    checked_results,
    entry_bytes,
    item_result,
    results_limit,
)
from lightemma.backends.batch.journal import BatchJournal
from lightemma.errors import RunFatalError, RunStoreError, UserError

__all__ = ["BatchBackend", "BatchJournal", "adapter_for", "BATCH_PROVIDERS"]

#: seconds without a new request after which the queued requests go out as one wave
IDLE_SECONDS = 0.5
#: how many times the results of an ended batch are read before the run stops with them incomplete
RESULT_READS = 3
#: providers with a batch interface (``openai`` also covers OpenAI-compatible servers at --api-base)
BATCH_PROVIDERS = ("openai", "anthropic", "gemini")


def adapter_for(
    provider: str, model: str, *, api_base: str | None, api_key: str | None, timeout: float
) -> BatchAdapter:
    """The batch adapter for ``provider``, or a :class:`UserError` naming the providers that have one.

    ``api_key`` is the key the run's :class:`~lightemma.backends.api.APIBackend` decided to send
    (:attr:`~lightemma.backends.api.APIBackend.sent_key`; None: no key at all). An adapter sends that key
    and reads none from the environment itself, so a provider's key never reaches another ``--api-base``.
    """
    from lightemma.backends.api import OPENAI_COMPATIBLE

    if provider in OPENAI_COMPATIBLE:
        from lightemma.backends.batch.openai import OpenAIBatches

        return OpenAIBatches(model, api_base=api_base, api_key=api_key, timeout=timeout)
    if provider == "anthropic":
        from lightemma.backends.batch.anthropic import AnthropicBatches

        return AnthropicBatches(model, api_key=api_key, timeout=timeout, base=api_base)
    if provider == "gemini":
        from lightemma.backends.batch.gemini import GeminiBatches

        return GeminiBatches(model, api_key=api_key, timeout=timeout, base=api_base)
    raise UserError(
        f"--batch: {model} is served by {provider}, which has no batch interface in lightemma "
        f"(batch mode covers {', '.join(BATCH_PROVIDERS)}); run it without --batch"
    )


@dataclass
class _Pending:
    """One queued request: its custom id, the request, and the future its chain waits on."""

    base_id: str
    request: ChatRequest
    future: asyncio.Future[ChatResult]
    resubmits: int = 0

    @property
    def custom_id(self) -> str:
        return self.base_id if not self.resubmits else f"{self.base_id}-r{self.resubmits}"


class BatchBackend(Backend):
    """API models through their provider's batch interface (see the module docstring)."""

    name = "api-batch"
    wants_all_frames = True  # the runner puts every frame in flight: a wave holds one stage of every pending frame

    def __init__(
        self,
        model: str,
        *,
        api_base: str | None = None,
        api_key_env: str | None = None,
        timeout: float = 120.0,
        poll_seconds: float = 30.0,
        poll_cap: float = 600.0,
        idle_seconds: float | None = None,
        max_resubmits: int = 2,
        adapter: BatchAdapter | None = None,
        retry: Any = None,
        price: tuple[float, float] | None = None,
    ) -> None:
        from lightemma.backends.api import DEFAULT_IMAGE_LIMIT, IMAGE_LIMITS, APIBackend, _ImageCache
        from lightemma.backends.retry import RetryPolicy
        from lightemma.models.prices import run_price

        # the model and key checks, the key sent (one decision: APIBackend's), the parameters sent
        self.api = APIBackend(model, api_base=api_base, timeout=timeout, api_key_env=api_key_env, price=price)
        self.timeout = float(timeout)  # each batch API call, connect to last byte
        self.model_info = self.api.model_info
        self.provider = self.api.provider
        self.notices = self.api.notices
        self.served_elsewhere, self.api_base_shown = self.api.served_elsewhere, self.api.api_base_shown
        self.adapter = adapter or adapter_for(
            self.provider or "", self.api.model, api_base=api_base, api_key=self.api.sent_key, timeout=timeout
        )
        if poll_seconds <= 0 or poll_cap <= 0:
            raise UserError(f"--batch-poll must be greater than 0, got {poll_seconds:g}")
        self.poll_seconds, self.poll_cap = float(poll_seconds), max(float(poll_cap), float(poll_seconds))
        self.idle_seconds = IDLE_SECONDS if idle_seconds is None else idle_seconds
        self.max_resubmits = max_resubmits
        self.retry = retry or RetryPolicy(max_retries=8, base=1.0, cap=60.0)
        limit_b64, max_side = IMAGE_LIMITS.get(self.provider or "", DEFAULT_IMAGE_LIMIT)
        self._images = _ImageCache(max_b64=limit_b64, max_side=max_side)
        # --price for every call; another --api-base: not the provider's batch price (as APIBackend's list price)
        self.price = run_price(
            self.model_info,
            batch=True,
            given=price,
            served_from=self.api.api_base_shown if self.api.served_elsewhere else None,
        )
        self.journal: BatchJournal | None = None
        self._resubmitted: dict[tuple[str, str], int] = {}  # (frame, stage) -> resubmissions this session, all attempts
        self.budget: Any = None  # the session's --max-cost budget (attach)
        self._observed = [0.0, 0]  # provider-reported cents and calls of this session's finished waves (known costs)
        self._queue: list[_Pending] = []
        self._wake: asyncio.Event | None = None
        self._flusher: asyncio.Task[None] | None = None
        self._tasks: set[asyncio.Task[Any]] = set()
        self.report: dict[str, Any] = {
            "waves": 0,
            "batches_created": 0,
            "batches_resumed": 0,
            "requests_submitted": 0,
            "requests_resubmitted": 0,
            "turnaround_s": [],
        }
        self.log: Callable[[str], None] | None = None

    # --- set by the runner ----------------------------------------------------------------------------------
    def attach(self, run_dir: Any, log: Callable[[str], None] | None = None, budget: Any = None) -> None:
        """Journal this run's batches in ``run_dir`` (reading what an earlier session journaled); ``budget``: the
        session's ``--max-cost`` :class:`~lightemma.pipeline.estimate.Budget`, checked before each wave is sent
        (:meth:`_check_budget`)."""
        self.journal = BatchJournal.open(run_dir, repair=True)
        self.log = log
        self.budget = budget
        done = sum(1 for b in self.journal.batches.values() if b.results is not None)
        if log and self.journal.batches:
            log(
                f"batch journal: {len(self.journal.batches)} batch(es) submitted earlier ({done} with saved results); "
                "their requests are answered from them, not submitted again"
            )

    def structured_output(self) -> dict[str, Any]:
        if self.adapter.provider != "openai":
            raise UserError(
                f"--answer-format structured with --batch: lightemma sends response schemas in batch mode only "
                f"to OpenAI (this model is served by {self.provider}); use --answer-format text or drop --batch"
            )
        return self.api.structured_output()

    def effective_params(self, params: GenerationParams) -> dict[str, Any]:
        return self.api.effective_params(params)

    @property
    def info(self) -> Mapping[str, Any]:
        return {
            **self.api.info,
            "mode": "batch",
            "transport": f"{self.adapter.provider} batch API",
            "batch": {
                "provider": self.adapter.provider,
                "max_requests": self.adapter.max_requests,
                "max_bytes": self.adapter.max_bytes,
                "poll_s": self.poll_seconds,
                "poll_cap_s": self.poll_cap,
                "max_resubmits": self.max_resubmits,
                "journal": "batches.jsonl",
            },
            "cost": f"provider-reported tokens at the batch price ({self.price['source']})",
            "latency": "n/a per call: a call's seconds are its batch's turnaround",
        }

    @property
    def batch_report(self) -> dict[str, Any]:
        """What this session did: waves, batches created / resumed, requests, turnarounds (seconds)."""
        turn = self.report["turnaround_s"]
        return {
            **self.report,
            "turnaround_s": [round(t, 3) for t in turn],
            "turnaround_s_mean": round(sum(turn) / len(turn), 3) if turn else None,
        }

    # --- the Backend interface -------------------------------------------------------------------------------
    async def generate(self, requests: Sequence[ChatRequest]) -> list[ChatResult]:
        if self.journal is None:
            raise RuntimeError("BatchBackend.attach(run_dir) must be called before generate")
        loop = asyncio.get_running_loop()
        if self._wake is None:
            self._wake = asyncio.Event()
            self._flusher = loop.create_task(self._flush_loop())
        pending = [_Pending(self._custom_id(r), r, loop.create_future()) for r in requests]
        self._queue.extend(pending)
        self._wake.set()
        return list(await asyncio.gather(*(p.future for p in pending)))

    async def aclose(self) -> None:
        tasks = [t for t in (self._flusher, *self._tasks) if t is not None]
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        self._flusher, self._wake = None, None
        await self.adapter.aclose()
        await self.api.aclose()

    # --- requests --------------------------------------------------------------------------------------------
    def _params(self, req: ChatRequest) -> dict[str, Any]:
        params = self.effective_params(req.params)
        if req.response_schema is not None:
            from lightemma.backends.structured import openai_response_format

            params["response_format"] = openai_response_format(req.response_schema)
        return params

    def _custom_id(self, req: ChatRequest) -> str:
        """The request's custom id: the same request gets the same id in every session (``le`` + 40 hex digits)."""
        what = [
            self.api.model,
            req.frame_id,
            req.stage,
            req.attempt,
            req.text,
            [list(t) for t in req.turns],
            str(req.image_path or ""),
            self._params(req),
        ]
        return "le" + hashlib.sha256(json.dumps(what, sort_keys=True, default=str).encode()).hexdigest()[:40]

    def _body(self, req: ChatRequest) -> dict[str, Any]:
        from lightemma.backends.api import _mark_cache_breakpoints
        from lightemma.backends.local import conversation

        image_part = None
        if req.image_path:
            url, _ = self._images.get(str(req.image_path))  # OSError: the wave fails with ImageReadError
            image_part = {"type": "image_url", "image_url": {"url": url}}
        messages = conversation(req, image_part)
        if self.provider == "anthropic":
            _mark_cache_breakpoints(messages, image=image_part is not None, end=req.prefix_of_next)
        return {"messages": messages, **self._params(req)}

    def _result(self, item: Mapping[str, Any], seconds: float) -> ChatResult:
        cost = self._cost(item)
        return ChatResult(
            text=item.get("text") if not item.get("error") else None,
            input_tokens=item.get("input_tokens"),
            output_tokens=item.get("output_tokens"),
            seconds=seconds,
            cost_cents=cost,
            error=item.get("error"),
            error_message=item.get("error_message"),
            finish_reason=item.get("finish_reason"),
            reasoning_tokens=item.get("reasoning_tokens"),
            cached_input_tokens=item.get("cached_input_tokens"),
            cache_write_tokens=item.get("cache_write_tokens"),
        )

    def _cost(self, item: Mapping[str, Any]) -> float | None:
        """US cents at the batch price; None when usage or a needed price is unknown."""
        p = self.price
        tin, tout = item.get("input_tokens"), item.get("output_tokens")
        if tin is None or tout is None or p["input_usd_per_mtok"] is None or p["output_usd_per_mtok"] is None:
            return None
        read, written = item.get("cached_input_tokens") or 0, item.get("cache_write_tokens") or 0
        if (read and p["cache_read_usd_per_mtok"] is None) or (written and p["cache_write_usd_per_mtok"] is None):
            return None
        usd = (tin - read - written) * p["input_usd_per_mtok"] + tout * p["output_usd_per_mtok"]
        usd += read * (p["cache_read_usd_per_mtok"] or 0.0) + written * (p["cache_write_usd_per_mtok"] or 0.0)
        return usd / 1e6 * 100.0

    # --- waves -----------------------------------------------------------------------------------------------
    async def _flush_loop(self) -> None:
        assert self._wake is not None
        while True:
            await self._wake.wait()
            while True:  # until no new request has come for idle_seconds: every frame has asked
                size = len(self._queue)
                await asyncio.sleep(self.idle_seconds)
                if len(self._queue) == size:
                    break
            wave, self._queue = self._queue, []
            self._wake.clear()
            if not wave:
                continue
            self.report["waves"] += 1
            task = asyncio.get_running_loop().create_task(self._wave(wave))
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)

    async def _wave(self, wave: list[_Pending]) -> None:
        try:
            try:
                await self._run_wave(wave)
            except RunStoreError as exc:  # the journal could not be written (disk full): nothing was created after it
                raise RunFatalError(
                    f"{exc}; no batch was created after the line that failed (a resume goes on from the journal)",
                    cause="disk",
                    error="JournalWriteError",
                ) from None
        except asyncio.CancelledError:
            raise
        except BaseException as exc:  # noqa: BLE001 - every waiting chain learns why
            for p in wave:
                if not p.future.done():
                    p.future.set_exception(exc)

    async def _run_wave(self, wave: list[_Pending]) -> None:
        journal = self.journal
        assert journal is not None
        known: dict[str, list[_Pending]] = {}
        new: list[_Pending] = []
        for p in wave:
            bid = journal.by_custom_id.get(p.custom_id)
            (known.setdefault(bid, []) if bid else new).append(p)
        for token, submission in list(journal.unconfirmed.items()):  # a submission cut off before its id was journaled
            wanted = set(submission.custom_ids)
            mine = [p for p in new if p.custom_id in wanted]
            if not mine:
                continue
            found = await self._find(token, submission.at, len(wanted), "look up an interrupted submission")
            if found is None:
                journal.abandoned(token, "not found at the provider: never created")
                continue
            journal.submitted(token, found, submission.custom_ids)
            new = [p for p in new if p.custom_id not in wanted]
            known.setdefault(found, []).extend(mine)
        waits = [self._await(bid, ps, resumed=True) for bid, ps in known.items()]
        if new:
            self._check_budget(len(new))
        waits += [self._await(bid, ps) for bid, ps in await self._submit_all(new)]
        await asyncio.gather(*waits)

    def _check_budget(self, n_new: int) -> None:
        """``--max-cost`` before a wave goes out: what the run has spent (its records, and this session's finished waves
        at their provider-reported usage) plus every call its admitted frames still hold, each projected at the larger
        of the admitted cost per call and the mean reported cost per call of this session's finished waves, must stay
        within the limit — else the run stops (cause ``budget``, resumable) and the wave is not sent: a limit holds
        within one wave's worth of uncertainty, however far the estimate was off."""
        budget = self.budget
        if budget is None or budget.per_call_cents <= 0:
            return
        cents, calls = self._observed
        observed = cents / calls if calls else 0.0
        per_call = max(budget.per_call_cents, observed)
        held = max(budget.reserved_cents, 0.0) / budget.per_call_cents  # calls admitted and not yet made (this wave's)
        projected = budget.spent_cents + held * per_call
        if projected > budget.limit_cents + 1e-9:
            raise RunFatalError(
                f"--max-cost {budget.limit_cents:g}: {budget.spent_cents:.2f} ¢ spent (provider-reported), "
                f"and the {held:.0f} call(s) the admitted frames still hold, at {per_call:.3f} ¢ each (the "
                f"finished waves' mean: the estimate was {budget.per_call_cents:.3f} ¢), would pass the "
                f"limit; the next wave ({n_new} request(s)) was not sent",
                cause="budget",
            )

    async def _find(self, token: str, at: float, n_requests: int, what: str) -> str | None:
        """The batch a submission journaled at ``at`` created, looked up by its ``token`` (every page of the provider's
        list back to ``at``), else None; the run stops (``batch-unconfirmed``) where the provider cannot tell."""
        journal = self.journal
        assert journal is not None
        try:
            return await self._call(
                lambda: self.adapter.find(token, at, n_requests, set(journal.batches)), what, requests=n_requests
            )
        except BatchUnconfirmed as exc:
            raise RunFatalError(
                f"a batch submission of {n_requests} request(s) (token {token}) got no answer, and {exc}; "
                "lightemma neither creates it again (it would be paid twice) nor takes a batch it cannot "
                "tell is its own: check the provider's console; if none of them is this run's, delete the "
                f"'submitting' line of {token} from {journal.path} and resume again",
                cause="batch-unconfirmed",
                error="BatchUnconfirmed",
            ) from None

    async def _submit_all(self, pending: list[_Pending]) -> list[tuple[str, list[_Pending]]]:
        """Submit ``pending`` in batches within the provider's limits; (batch id, its requests) per batch."""
        out: list[tuple[str, list[_Pending]]] = []
        chunk: list[_Pending] = []
        entries: list[dict[str, Any]] = []
        size = 0
        for p in pending:
            try:
                entry = self.adapter.entry(p.custom_id, self._body(p.request))
            except OSError as exc:
                from lightemma.backends.retry import short_message

                p.future.set_result(ChatResult(text=None, error="ImageReadError", error_message=short_message(exc)))
                continue
            n = entry_bytes(entry)
            if entries and (len(entries) >= self.adapter.max_requests or size + n > self.adapter.max_bytes):
                out.append((await self._submit(entries, chunk), chunk))
                chunk, entries, size = [], [], 0
            chunk.append(p)
            entries.append(entry)
            size += n
        if entries:
            out.append((await self._submit(entries, chunk), chunk))
        return out

    async def _submit(self, entries: list[dict[str, Any]], chunk: list[_Pending]) -> str:
        """Create one batch, never twice: the intent is journaled durably first (a write that fails creates nothing);
        a create whose answer is lost (a 5xx, a dropped connection, --timeout) is looked up by its token before it is
        created again; one the provider refused (4xx) is journaled as abandoned."""
        journal = self.journal
        assert journal is not None
        ids = [p.custom_id for p in chunk]
        token = f"lightemma-{secrets.token_hex(8)}"
        journal.submitting(token, ids)  # before the provider is asked: an interrupted submission can be found
        at = journal.unconfirmed[token].at
        tries = 0
        while True:
            try:
                bid = str(await self._attempt(lambda: self.adapter.submit(entries, token), requests=len(ids)))
                break
            except BatchHTTPError as exc:
                if not exc.transient or tries >= self.retry.max_retries:
                    fatal = self._fatal(exc, "create a batch", tries)  # its message holds no key or credential
                    if 400 <= exc.status < 500 and exc.status != 429:  # refused: nothing was created
                        journal.abandoned(token, f"the provider refused the batch: {fatal}")
                    raise fatal from None  # else it may exist: a resume looks it up
            await asyncio.sleep(self._pause(tries))  # a batch being created as the answer was lost has time to appear
            tries += 1
            found = await self._find(token, at, len(ids), "look up a batch whose creation got no answer")
            if found is not None:
                bid = found
                break
        journal.submitted(token, bid, ids)  # before the first poll
        for p in chunk:
            if p.resubmits:
                key = (p.request.frame_id, p.request.stage)
                self._resubmitted[key] = self._resubmitted.get(key, 0) + 1
        self.report["batches_created"] += 1
        self.report["requests_submitted"] += len(ids)
        if self.log:
            self.log(f"batch {bid}: {len(ids)} request(s) submitted (journaled in {journal.path.name})")
        return bid

    def _pause(self, tries: int) -> float:
        """Seconds before the next look-up or download of a batch: ``--batch-poll`` doubling, at most the poll cap."""
        return min(self.poll_seconds * (2**tries), self.poll_cap)

    async def _await(self, bid: str, pending: list[_Pending], *, resumed: bool = False) -> None:
        """Poll batch ``bid`` until it ends (or read its saved results), then answer its requests by custom id."""
        journal = self.journal
        assert journal is not None
        if resumed:
            self.report["batches_resumed"] += 1
        batch = journal.batches[bid]
        items = journal.saved_results(bid) if batch.failed is None else []
        state = batch.state
        ended_now = False  # polled to its end in this session (its turnaround is this session's to report)
        canceled = False
        if batch.failed is not None:  # failed as a whole in an earlier session, none of its requests run
            items = self._unrun(bid, batch.custom_ids, f"batch {bid} failed as a whole ({batch.failed})")
        elif items is None:
            delay = self.poll_seconds
            while True:
                status = await self._call(
                    lambda: self.adapter.status(bid), f"poll batch {bid}", requests=len(batch.custom_ids)
                )
                if status.state != PENDING:
                    break
                await asyncio.sleep(delay)
                delay = min(delay * 1.5, self.poll_cap)
            state = status.provider_state
            if status.state == FAILED and status.answered is None:
                raise RunFatalError(
                    f"the provider failed batch {bid} as a whole ({status.provider_state}: "
                    f"{status.reason or 'no reason given'}) without counts of what it ran; lightemma does "
                    "not submit again what may have been billed: check the batch in the provider's "
                    "console",
                    cause="batch-failed",
                    error="BatchFailed",
                )
            if status.state == FAILED and status.answered == 0:  # nothing ran: its requests may go out again
                reason = status.reason or "no reason given"
                journal.failed(bid, status.provider_state, reason)
                if not status.retryable:
                    raise RunFatalError(
                        f"the provider rejected batch {bid} as a whole ({status.provider_state}: {reason}); "
                        "fix what it names and resume: the resume submits its requests again (a failed "
                        "batch ran none of them)",
                        cause="batch-failed",
                        error="BatchFailed",
                    )
                items = self._unrun(bid, batch.custom_ids, f"batch {bid} failed as a whole ({reason})")
            else:
                items = await self._ended_results(bid, status)
                turnaround = max(0.0, time.time() - batch.submitted_at) if batch.submitted_at else None
                journal.save_results(bid, items, status.provider_state, turnaround)
                ended_now, canceled = True, status.canceled
                if self.log:
                    failed = sum(1 for i in items if i.get("error"))
                    self.log(
                        f"batch {bid}: {status.provider_state} after {turnaround or 0:.0f} s, {len(items)} result(s)"
                        f"{f', {failed} with an error' if failed else ''}"
                    )
        turnaround = journal.batches[bid].turnaround_s
        if turnaround is not None and ended_now:
            self.report["turnaround_s"].append(float(turnaround))
        unrun = sum(1 for i in items if i.get("resubmit"))
        if canceled and unrun:  # a cancel made in the provider's console is not undone by resubmitting
            raise RunFatalError(
                f"batch {bid} was canceled at the provider ({state}) with {unrun} of its "
                f"{len(batch.custom_ids)} request(s) not run; lightemma stops rather than undo the cancel "
                "(a resume submits them again; its answered requests are saved)",
                cause="batch-canceled",
                error="BatchCanceled",
            )
        by_id = {str(i.get("custom_id")): i for i in items}
        requeue = []
        whole = batch.failed if batch.failed is not None else None  # failed as a whole: none of its requests ran
        if whole is not None and any(
            self._resubmitted.get((p.request.frame_id, p.request.stage), 0) >= self.max_resubmits for p in pending
        ):
            raise RunFatalError(
                f"the provider failed batch {bid} as a whole ({whole}), and its requests were resubmitted "
                f"{self.max_resubmits} time(s) already; wait until the account's running batches have "
                "finished (OpenAI's enqueued-token limit counts them) or fix what it names, then resume",
                cause="batch-failed",
                error="BatchFailed",
            )
        for p in pending:
            item = by_id.get(p.custom_id)
            if item is None:  # saved results hold every request of their batch (BatchJournal.saved_results)
                raise RunFatalError(
                    f"batch {bid} has no result for request {p.custom_id}; lightemma does not ask it "
                    "again (the provider may have run it)",
                    cause="batch-results",
                    error="BatchResultsIncomplete",
                )
            key = (p.request.frame_id, p.request.stage)
            if item.get("resubmit") and self._resubmitted.get(key, 0) < self.max_resubmits:
                p.resubmits += 1  # a new custom id; a resubmission journaled earlier is followed, not sent again
                requeue.append(p)
                continue
            result = self._result(item, float(turnaround or 0.0))
            if result.cost_cents is not None and ended_now:
                self._observed[0] += result.cost_cents
                self._observed[1] += 1
            p.future.set_result(result)
        if requeue:
            self.report["requests_resubmitted"] += len(requeue)
            assert self._wake is not None
            self._queue.extend(requeue)
            self._wake.set()

    @staticmethod
    def _unrun(bid: str, custom_ids: Sequence[str], why: str) -> list[dict[str, Any]]:
        """Results for requests a batch never ran: each may be resubmitted (:data:`BatchExpired` past the limit)."""
        return [
            item_result(cid, error="BatchExpired", error_message=f"not run: {why}", resubmit=True) for cid in custom_ids
        ]

    async def _ended_results(self, bid: str, status: BatchStatus) -> list[dict[str, Any]]:
        """The results of ended batch ``bid``, complete by the provider's own counts, read up to
        :data:`RESULT_READS` times (polling its status again between reads); a request with no result counts as never
        run only where the provider says so (``status.unrun``). Results that stay incomplete stop the run
        (``batch-results``, resumable: nothing is saved, a resume reads them again) — what the provider says it ran is
        never asked again."""
        journal = self.journal
        assert journal is not None
        ids = journal.batches[bid].custom_ids
        for tries in range(RESULT_READS):
            if tries:
                await asyncio.sleep(self._pause(tries - 1))
                status = await self._call(lambda: self.adapter.status(bid), f"poll batch {bid}", requests=len(ids))
            items = await self._call(
                functools.partial(self._results, bid, status), f"read the results of batch {bid}", requests=len(ids)
            )
            seen = {str(i.get("custom_id")) for i in items}
            missing = [cid for cid in ids if cid not in seen]
            if status.answered is not None and len(items) < status.answered:
                problem = f"the provider reports {status.answered} result(s) and lightemma read {len(items)}"
            elif missing and status.unrun is None:
                problem = (
                    f"{len(missing)} of its {len(ids)} request(s) have no result, and the provider reported no "
                    "counts to tell whether they ran"
                )
            elif len(missing) > (status.unrun or 0):
                problem = (
                    f"{len(missing)} of its {len(ids)} request(s) have no result, and the provider says "
                    f"{status.unrun} were not run"
                )
            else:
                return items + self._unrun(
                    bid, missing, f"not reached before batch {bid} ended ({status.provider_state})"
                )
        raise RunFatalError(
            f"the results of batch {bid} ({status.provider_state}) are incomplete after {RESULT_READS} "
            f"reads: {problem}; lightemma stops rather than ask again what the provider ran (it would be "
            "paid twice); a resume reads them again",
            cause="batch-results",
            error="BatchResultsIncomplete",
        )

    async def _results(self, bid: str, status: Any) -> list[dict[str, Any]]:
        """The adapter's results of batch ``bid`` (:func:`checked_results`)."""
        assert self.journal is not None
        return checked_results(await self.adapter.results(bid, status), self.journal.batches[bid].custom_ids)

    async def _attempt(self, make: Callable[[], Any], *, requests: int = 0) -> Any:
        """One adapter call within the whole --timeout and the reply limit of a batch of ``requests`` requests; any
        failure as :class:`BatchHTTPError`."""
        from lightemma.backends.openai_http import HTTPCallError, body_guard

        try:
            with body_guard(results_limit(requests)):
                return await asyncio.wait_for(make(), self.timeout)  # connect to last byte, as --timeout says
        except TimeoutError:  # a reply trickled (httpx bounds each read, not the whole call): retried
            raise BatchHTTPError(
                0, f"no whole answer within --timeout {self.timeout:g} s (connect to last byte)", deadline=True
            ) from None
        except HTTPCallError as exc:  # the body hooks: past the limit, or an encoding lightemma does not read
            raise BatchHTTPError(
                0, f"{exc} (the limit for a batch of {requests} request(s): docs/run.md, Limits)", answer=True
            ) from None
        except (ValueError, KeyError, TypeError, AttributeError, IndexError, RecursionError, OverflowError) as exc:
            raise BatchHTTPError(
                0,
                f"the answer is not what the {self.adapter.provider} batch API documents "
                f"({type(exc).__name__}: {str(exc)[:120]})",
                answer=True,
            ) from None

    def _fatal(self, exc: BatchHTTPError, what: str, tries: int) -> RunFatalError:
        """The one line that stops the run after a batch call failed for good."""
        from lightemma.backends.retry import short_message

        where = f"{self.adapter.provider} batch API"
        said = short_message(exc, secrets=self.api._secrets)  # no key or --api-base credential in it
        if exc.auth:
            fatal = RunFatalError(
                f"{self.api.model}: cannot {what}: {said} — the {where} rejected the key",
                cause="authentication",
                error="AuthenticationError",
            )
        else:
            fatal = RunFatalError(
                f"{self.api.model}: cannot {what}: {said} ({where}{f', after {tries} retries' if tries else ''})",
                cause="batch-api",
                error="Timeout" if exc.deadline else "BatchAPIError",
            )
        fatal.http_status = exc.status  # type: ignore[attr-defined]  # the failed call's HTTP status, kept on the error
        return fatal

    async def _call(self, make: Callable[[], Any], what: str, *, requests: int = 0) -> Any:
        """An adapter call, transient failures (connection, 429, 5xx) retried with backoff; others stop the run.

        The call reads at most :func:`~lightemma.backends.batch.adapter.results_limit` (``requests``: how many requests
        the batch it is about holds) of any reply; a reply past it, or one that is not what the provider documents,
        stops the run in one line (resumable), never a traceback. Never used to create a batch (:meth:`_submit`)."""
        tries = 0
        while True:
            try:
                return await self._attempt(make, requests=requests)
            except BatchHTTPError as exc:
                if exc.transient and tries < self.retry.max_retries:
                    await asyncio.sleep(self.retry.delay(tries))
                    tries += 1
                    continue
                raise self._fatal(exc, what, tries) from None
