"""``lightemma run --batch``: the chain through the providers' batch interfaces, at their batch prices.

:class:`BatchBackend` is a backend like any other (:mod:`lightemma.backends.base`): the chain is unchanged.
Every frame of a run is in flight at once; each frame's next request is queued, and once no new request has
arrived for ``idle_seconds`` the queue goes out as one *wave* — stage 1 of every pending frame, then stage 2,
then stage 3, re-asks in further waves. A wave is split into batches within the provider's limits (requests
and bytes per batch, :class:`~lightemma.backends.batch.base.BatchAdapter`), each polled with backoff
(``poll_seconds``, ×1.5 per poll, at most ``poll_cap``).

Every request has a custom id derived from what it asks (model, frame, stage, attempt, prompt, earlier turns,
image, parameters): the same request gets the same id in a resumed run. Batch ids are journaled in the run
directory before any polling (:mod:`lightemma.backends.batch.journal`); a resumed run answers a journaled
request from its batch (polled again, or its saved results) — never resubmitted, never billed twice. Results
are matched by custom id in whatever order they come. A request the provider never ran (expired, canceled)
is resubmitted in a new batch up to ``max_resubmits`` times, then fails as ``BatchExpired``; a request the
provider answered with an error fails with its reason (``BatchRequestError``), which the chain re-asks like
any API error. A batch the provider rejects as a whole (validation) stops the run with its reason.

Adapters: OpenAI (and OpenAI-compatible ``--api-base`` servers), Anthropic Message Batches and Gemini batch mode,
each over its HTTP API, every reply read within :func:`~lightemma.backends.batch.base.results_limit` (litellm
1.106.2 creates neither Anthropic nor Gemini batches, and takes no bounded client for OpenAI's). Costs are
the provider-reported tokens at the registry's batch prices, or at ``--price`` (:func:`lightemma.registry.run_price`).
A call's ``seconds`` is its batch's turnaround (submission to results): per-frame latency has no meaning in
batch mode, and Table I prints it as ``n/a``.

Keys and endpoints follow :class:`~lightemma.backends.api.APIBackend`, which decides them once: a provider's key
goes only to its own host (or one ``LIGHTEMMA_PROVIDER_HOSTS`` declares); any other ``--api-base`` speaks the
OpenAI batch protocol and gets the key of ``--api-key-env NAME`` or none. Credentials in ``--api-base``
(``user:pw@``) go as Basic auth, never into the journal, a record or a message.
"""

from __future__ import annotations

import asyncio
import hashlib
import json
import secrets
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from lightemma.backends.base import ChatRequest, ChatResult, GenerationParams
from lightemma.backends.batch.base import (
    FAILED,
    PENDING,
    BatchAdapter,
    BatchHTTPError,
    checked_results,
    entry_bytes,
    results_limit,
)
from lightemma.backends.batch.journal import BatchJournal
from lightemma.errors import RunFatalError, UserError

__all__ = ["BatchBackend", "BatchJournal", "adapter_for", "BATCH_PROVIDERS"]

#: seconds without a new request after which the queued requests go out as one wave
IDLE_SECONDS = 0.5
#: providers with a batch interface (``openai`` also covers OpenAI-compatible servers at --api-base)
BATCH_PROVIDERS = ("openai", "anthropic", "gemini")


def adapter_for(provider: str, model: str, *, api_base: str | None, api_key: str | None, timeout: float) -> BatchAdapter:
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
    raise UserError(f"--batch: {model} is served by {provider}, which has no batch interface in lightemma "
                    f"(batch mode covers {', '.join(BATCH_PROVIDERS)}); run it without --batch")


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


class BatchBackend:
    """API models through their provider's batch interface (see the module docstring)."""

    name = "api-batch"
    wants_all_frames = True  # the runner puts every frame in flight: a wave holds one stage of every pending frame

    def __init__(self, model: str, *, api_base: str | None = None, api_key_env: str | None = None, timeout: float = 120.0,
                 poll_seconds: float = 30.0, poll_cap: float = 600.0, idle_seconds: float | None = None,
                 max_resubmits: int = 2, adapter: BatchAdapter | None = None, retry: Any = None,
                 price: tuple[float, float] | None = None) -> None:
        from lightemma.backends.api import APIBackend, IMAGE_LIMITS, DEFAULT_IMAGE_LIMIT, _ImageCache
        from lightemma.backends.retry import RetryPolicy
        from lightemma.registry import run_price

        # the model and key checks, the key sent (one decision: APIBackend's), the parameters sent
        self.api = APIBackend(model, api_base=api_base, timeout=timeout, api_key_env=api_key_env, price=price)
        self.timeout = float(timeout)  # each batch API call, connect to last byte
        self.model_info = self.api.model_info
        self.provider = self.api.provider
        self.notices = self.api.notices
        self.served_elsewhere, self.api_base_shown = self.api.served_elsewhere, self.api.api_base_shown
        self.adapter = adapter or adapter_for(self.provider or "", self.api.model, api_base=api_base,
                                              api_key=self.api.sent_key, timeout=timeout)
        if poll_seconds <= 0 or poll_cap <= 0:
            raise UserError(f"--batch-poll must be greater than 0, got {poll_seconds:g}")
        self.poll_seconds, self.poll_cap = float(poll_seconds), max(float(poll_cap), float(poll_seconds))
        self.idle_seconds = IDLE_SECONDS if idle_seconds is None else idle_seconds
        self.max_resubmits = max_resubmits
        self.retry = retry or RetryPolicy(max_retries=8, base=1.0, cap=60.0)
        limit_b64, max_side = IMAGE_LIMITS.get(self.provider or "", DEFAULT_IMAGE_LIMIT)
        self._images = _ImageCache(max_b64=limit_b64, max_side=max_side)
        # --price for every call; another --api-base: not the provider's batch price (as APIBackend's list price)
        self.price = run_price(self.model_info, batch=True, given=price,
                               served_from=self.api.api_base_shown if self.api.served_elsewhere else None)
        self.journal: BatchJournal | None = None
        self._queue: list[_Pending] = []
        self._wake: asyncio.Event | None = None
        self._flusher: asyncio.Task[None] | None = None
        self._tasks: set[asyncio.Task[Any]] = set()
        self.report: dict[str, Any] = {"waves": 0, "batches_created": 0, "batches_resumed": 0, "requests_submitted": 0,
                                       "requests_resubmitted": 0, "turnaround_s": []}
        self.log: Callable[[str], None] | None = None

    # --- set by the runner ----------------------------------------------------------------------------------
    def attach(self, run_dir: Any, log: Callable[[str], None] | None = None) -> None:
        """Journal this run's batches in ``run_dir`` (reading what an earlier session journaled)."""
        self.journal = BatchJournal.open(run_dir)
        self.log = log
        done = sum(1 for b in self.journal.batches.values() if b.results is not None)
        if log and self.journal.batches:
            log(f"batch journal: {len(self.journal.batches)} batch(es) submitted earlier ({done} with saved results); "
                "their requests are answered from them, not submitted again")

    def structured_output(self) -> dict[str, Any]:
        if self.adapter.provider != "openai":
            raise UserError(f"--answer-format structured with --batch: lightemma sends response schemas in batch mode only "
                            f"to OpenAI (this model is served by {self.provider}); use --answer-format text or drop --batch")
        return self.api.structured_output()

    def effective_params(self, params: GenerationParams) -> dict[str, Any]:
        return self.api.effective_params(params)

    @property
    def info(self) -> Mapping[str, Any]:
        return {**self.api.info, "mode": "batch", "transport": f"{self.adapter.provider} batch API",
                "batch": {"provider": self.adapter.provider, "max_requests": self.adapter.max_requests,
                          "max_bytes": self.adapter.max_bytes, "poll_s": self.poll_seconds, "poll_cap_s": self.poll_cap,
                          "max_resubmits": self.max_resubmits, "journal": "batches.jsonl"},
                "cost": f"provider-reported tokens at the batch price ({self.price['source']})",
                "latency": "n/a per call: a call's seconds are its batch's turnaround"}

    @property
    def batch_report(self) -> dict[str, Any]:
        """What this session did: waves, batches created / resumed, requests, turnarounds (seconds)."""
        turn = self.report["turnaround_s"]
        return {**self.report, "turnaround_s": [round(t, 3) for t in turn],
                "turnaround_s_mean": round(sum(turn) / len(turn), 3) if turn else None}

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
        what = [self.api.model, req.frame_id, req.stage, req.attempt, req.text, [list(t) for t in req.turns],
                str(req.image_path or ""), self._params(req)]
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
        return ChatResult(text=item.get("text") if not item.get("error") else None, input_tokens=item.get("input_tokens"),
                          output_tokens=item.get("output_tokens"), seconds=seconds, cost_cents=cost, error=item.get("error"),
                          error_message=item.get("error_message"), finish_reason=item.get("finish_reason"),
                          reasoning_tokens=item.get("reasoning_tokens"), cached_input_tokens=item.get("cached_input_tokens"),
                          cache_write_tokens=item.get("cache_write_tokens"))

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
            await self._run_wave(wave)
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
        for token, ids in list(journal.unconfirmed.items()):  # a submission cut off before its id was journaled
            wanted = set(ids)
            mine = [p for p in new if p.custom_id in wanted]
            if not mine:
                continue
            found = await self._call(lambda token=token: self.adapter.find(token), "look up an interrupted submission",
                                     requests=len(ids))
            if found is None and self.adapter.provider == "anthropic":
                raise RunFatalError(f"a batch submission of {len(ids)} request(s) (token {token}) was cut off before its id "
                                    "was journaled, and Anthropic batches cannot be looked up by name; check the console's "
                                    "Batches page for it: if there is none, delete that 'submitting' line from "
                                    f"{journal.path} and resume again", cause="batch-unconfirmed")
            if found is None:
                journal.abandoned(token, "not found at the provider: never created")
                continue
            journal.submitted(token, found, ids)
            new = [p for p in new if p.custom_id not in wanted]
            known.setdefault(found, []).extend(mine)
        waits = [self._await(bid, ps, resumed=True) for bid, ps in known.items()]
        waits += [self._await(bid, ps) for bid, ps in await self._submit_all(new)]
        await asyncio.gather(*waits)

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
        journal = self.journal
        assert journal is not None
        ids = [p.custom_id for p in chunk]
        token = f"lightemma-{secrets.token_hex(8)}"
        journal.submitting(token, ids)  # before the provider is asked: an interrupted submission can be found
        try:
            bid = await self._call(lambda: self.adapter.submit(entries, token), "create a batch", requests=len(ids))
        except RunFatalError as exc:
            if 400 <= getattr(exc, "http_status", 0) < 500:  # refused: nothing was created
                journal.abandoned(token, f"the provider refused the batch: {exc}")
            raise  # else it may exist: a resume looks it up by its token
        journal.submitted(token, bid, ids)  # before the first poll
        self.report["batches_created"] += 1
        self.report["requests_submitted"] += len(ids)
        if self.log:
            self.log(f"batch {bid}: {len(ids)} request(s) submitted (journaled in {journal.path.name})")
        return bid

    async def _await(self, bid: str, pending: list[_Pending], *, resumed: bool = False) -> None:
        """Poll batch ``bid`` until it ends (or read its saved results), then answer its requests by custom id."""
        journal = self.journal
        assert journal is not None
        if resumed:
            self.report["batches_resumed"] += 1
        items = journal.saved_results(bid)
        batch = journal.batches[bid]
        state = batch.state
        ended_now = items is None  # polled to its end in this session (its turnaround is this session's to report)
        if items is None:
            delay = self.poll_seconds
            while True:
                status = await self._call(lambda: self.adapter.status(bid), f"poll batch {bid}", requests=len(batch.custom_ids))
                if status.state != PENDING:
                    break
                await asyncio.sleep(delay)
                delay = min(delay * 1.5, self.poll_cap)
            if status.state == FAILED:
                raise RunFatalError(f"the provider rejected batch {bid} as a whole ({status.provider_state}: "
                                    f"{status.reason or 'no reason given'}); fix what it names and resume",
                                    cause="batch-failed", error="BatchFailed")
            items = await self._call(lambda: self._results(bid, status), f"read the results of batch {bid}",
                                     requests=len(batch.custom_ids))
            turnaround = max(0.0, time.time() - batch.submitted_at) if batch.submitted_at else None
            journal.save_results(bid, items, status.provider_state, turnaround)
            state = status.provider_state
            if self.log:
                failed = sum(1 for i in items if i.get("error"))
                self.log(f"batch {bid}: {status.provider_state} after {turnaround or 0:.0f} s, {len(items)} result(s)"
                         f"{f', {failed} with an error' if failed else ''}")
        turnaround = journal.batches[bid].turnaround_s
        if turnaround is not None and ended_now:
            self.report["turnaround_s"].append(float(turnaround))
        never_ran = str(state).lower() in ("expired", "cancelled", "canceled", "batch_state_expired", "batch_state_cancelled")
        by_id = {str(i.get("custom_id")): i for i in items}
        requeue = []
        for p in pending:
            item = by_id.get(p.custom_id)
            if item is None:
                item = ({"custom_id": p.custom_id, "error": "BatchExpired", "resubmit": True,
                         "error_message": f"not run before batch {bid} ended ({state})"} if never_ran else
                        {"custom_id": p.custom_id, "error": "BatchMissingResult",
                         "error_message": f"batch {bid} ended ({state}) without a result for this request"})
            if item.get("resubmit") and p.resubmits < self.max_resubmits:
                p.resubmits += 1
                requeue.append(p)
                continue
            p.future.set_result(self._result(item, float(turnaround or 0.0)))
        if requeue:
            self.report["requests_resubmitted"] += len(requeue)
            assert self._wake is not None
            self._queue.extend(requeue)
            self._wake.set()

    async def _results(self, bid: str, status: Any) -> list[dict[str, Any]]:
        """The adapter's results of batch ``bid`` (:func:`checked_results`)."""
        assert self.journal is not None
        return checked_results(await self.adapter.results(bid, status), self.journal.batches[bid].custom_ids)

    async def _call(self, make: Callable[[], Any], what: str, *, requests: int = 0) -> Any:
        """An adapter call, transient failures (connection, 429, 5xx) retried with backoff; others stop the run.

        The call reads at most :func:`~lightemma.backends.batch.base.results_limit` (``requests``: how many requests
        the batch it is about holds) of any reply; a reply past it, or one that is not what the provider documents,
        stops the run in one line (resumable), never a traceback."""
        from lightemma.backends.openai_http import HTTPCallError, body_guard

        limit = results_limit(requests)
        tries = 0
        while True:
            try:
                try:
                    with body_guard(limit):
                        return await asyncio.wait_for(make(), self.timeout)  # connect to last byte, as --timeout says
                except asyncio.TimeoutError:  # a reply trickled (httpx bounds each read, not the whole call): retried
                    raise BatchHTTPError(0, f"no whole answer within --timeout {self.timeout:g} s (connect to last byte)",
                                         deadline=True) from None
                except HTTPCallError as exc:  # the body hooks: past the limit, or an encoding lightemma does not read
                    raise BatchHTTPError(0, f"{exc} (the limit for a batch of {requests} request(s): docs/run.md, "
                                            "Limits)", answer=True) from None
                except (ValueError, KeyError, TypeError, AttributeError, IndexError, RecursionError, OverflowError) as exc:
                    raise BatchHTTPError(0, f"the answer is not what the {self.adapter.provider} batch API documents "
                                            f"({type(exc).__name__}: {str(exc)[:120]})", answer=True) from None
            except BatchHTTPError as exc:
                if exc.transient and tries < self.retry.max_retries:
                    await asyncio.sleep(self.retry.delay(tries))
                    tries += 1
                    continue
                from lightemma.backends.retry import short_message

                where = f"{self.adapter.provider} batch API"
                said = short_message(exc, secrets=self.api._secrets)  # no key or --api-base credential in it
                if exc.auth:
                    fatal = RunFatalError(f"{self.api.model}: cannot {what}: {said} — the {where} rejected the key",
                                          cause="authentication", error="AuthenticationError")
                else:
                    fatal = RunFatalError(f"{self.api.model}: cannot {what}: {said} ({where}"
                                          f"{f', after {tries} retries' if tries else ''})", cause="batch-api",
                                          error="Timeout" if exc.deadline else "BatchAPIError")
                fatal.http_status = exc.status  # type: ignore[attr-defined]
                raise fatal from None
