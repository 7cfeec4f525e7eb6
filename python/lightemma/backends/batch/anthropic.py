"""Anthropic Message Batches over HTTP (httpx): litellm 1.106.2 can retrieve an Anthropic batch but not create one.

``POST /v1/messages/batches`` with ``{"requests": [{"custom_id", "params": <a Messages API body>}]}`` (at most
100,000 requests or 256 MB per batch; custom ids ``^[a-zA-Z0-9_-]{1,64}$``), ``GET /v1/messages/batches/{id}``
(``processing_status`` ``in_progress`` → ``canceling`` → ``ended``), then the JSONL at ``results_url``: per line
``{"custom_id", "result": {"type": "succeeded", "message"} | {"type": "errored", "error"} | {"type": "expired"} |
{"type": "canceled"}}``, in any order (docs.anthropic.com/en/docs/build-with-claude/batch-processing).
The base URL is ``--api-base`` when it is Anthropic's own host (or one ``LIGHTEMMA_PROVIDER_HOSTS`` declares;
any other ``--api-base`` is an OpenAI-compatible server, batched by the OpenAI adapter), else
``ANTHROPIC_API_BASE`` / ``ANTHROPIC_BASE_URL`` when set (as litellm reads them), else
``https://api.anthropic.com``; the key the run's API backend decided goes only there, in ``x-api-key``.
"""

from __future__ import annotations

import os
from collections.abc import Collection
from typing import Any

from lightemma.backends.batch.adapter import (
    CLOCK_SKEW_S,
    ENDED,
    MAX_LIST_PAGES,
    BatchHTTPError,
    BatchStatus,
    BatchUnconfirmed,
    ItemUsage,
    batch_client,
    batch_state,
    count,
    endpoint,
    http_call,
    item_result,
    jsonl_rows,
    split_data_url,
    tally,
    url_id,
)

VERSION = "2023-06-01"
TERMINAL, RUNNING = {"ended": ENDED}, ("in_progress", "canceling")  # processing_status, as documented


def base_url() -> str:
    return (
        os.environ.get("ANTHROPIC_API_BASE") or os.environ.get("ANTHROPIC_BASE_URL") or "https://api.anthropic.com"
    ).rstrip("/")


def _part(part: dict[str, Any]) -> dict[str, Any]:
    """An OpenAI content part as Anthropic's (images as base64 sources), its cache breakpoint kept."""
    if part.get("type") == "image_url":
        mime, data = split_data_url(part["image_url"]["url"])
        out: dict[str, Any] = {"type": "image", "source": {"type": "base64", "media_type": mime, "data": data}}
    else:
        out = {"type": "text", "text": part.get("text", "")}
    if "cache_control" in part:
        out["cache_control"] = part["cache_control"]
    return out


class AnthropicBatches:
    """Anthropic's Message Batches API (see the module docstring)."""

    provider = "anthropic"
    max_requests = 100_000
    max_bytes = 256 * 1000 * 1000

    def __init__(self, model: str, *, api_key: str | None, timeout: float = 120.0, base: str | None = None) -> None:
        self.model = model.split("/", 1)[1] if model.startswith("anthropic/") else model
        self.base, headers = endpoint(base, base_url(), api_key, key_header="x-api-key", version="/v1")
        self._client = batch_client(timeout, {**headers, "anthropic-version": VERSION})

    def entry(self, custom_id: str, body: dict[str, Any]) -> dict[str, Any]:
        params: dict[str, Any] = {
            "model": self.model,
            "max_tokens": body["max_tokens"],
            "messages": [{"role": m["role"], "content": [_part(p) for p in m["content"]]} for m in body["messages"]],
        }
        if "temperature" in body:
            params["temperature"] = body["temperature"]
        return {"custom_id": custom_id, "params": params}

    async def _request(self, method: str, url: str, **kw: Any) -> Any:
        response = await http_call(self._client, method, url, **kw)
        return response

    async def submit(self, entries: list[dict[str, Any]], token: str) -> str:
        response = await self._request("POST", f"{self.base}/v1/messages/batches", json={"requests": entries})
        return str(response.json()["id"])

    async def status(self, batch_id: str) -> BatchStatus:
        data = (await self._request("GET", f"{self.base}/v1/messages/batches/{url_id(batch_id)}")).json()
        state = str(data.get("processing_status"))
        counts = data.get("request_counts")
        return BatchStatus(
            state=batch_state(batch_id, state, TERMINAL, RUNNING),
            provider_state=state,
            counts=dict(counts) if isinstance(counts, dict) else {},
            handle={"results_url": data.get("results_url")},
            answered=tally(counts, ("succeeded", "errored", "canceled", "expired")),
            unrun=0 if isinstance(counts, dict) else None,  # every request of an ended batch has a line
            canceled=bool(data.get("cancel_initiated_at")) or state == "canceling",
        )

    async def results(self, batch_id: str, status: BatchStatus) -> list[dict[str, Any]]:
        url = status.handle.get("results_url") or f"{self.base}/v1/messages/batches/{url_id(batch_id)}/results"
        if not str(url).startswith(self.base + "/"):  # the key goes only to the base the user chose
            raise BatchHTTPError(
                0, f"results_url {url!r} is not under {self.base}; not sending the key there", answer=True
            )
        data = (await self._request("GET", url)).content
        out = []
        for row in jsonl_rows(data, f"batch {batch_id}"):
            cid, result = str(row.get("custom_id")), row.get("result") or {}
            kind = result.get("type")
            if kind == "succeeded":
                out.append(_message_result(cid, result.get("message") or {}))
            elif kind in ("expired", "canceled"):
                out.append(
                    item_result(cid, error="BatchExpired", error_message=f"{kind}: not run by the batch", resubmit=True)
                )
            else:
                err = (result.get("error") or {}).get("error") or result.get("error") or {}
                out.append(
                    item_result(
                        cid, error="BatchRequestError", error_message=f"{err.get('type')}: {err.get('message')}"
                    )
                )
        return out

    async def find(self, token: str, since: float, n_requests: int, known: Collection[str] = ()) -> str | None:
        """Anthropic batches carry no name or metadata to find one by: every page of ``GET /v1/messages/batches``
        (newest first, ``after_id`` the last id of a page) down to ``since`` is read for a batch of ``n_requests``
        requests, other than the ``known`` ones (this run's journaled batches). None when there is none (nothing was created: safe to create); :class:`BatchUnconfirmed`, naming
        them, when there is one (it may be this submission's, or another of the account's: lightemma cannot tell)."""
        from datetime import datetime

        params: dict[str, Any] = {"limit": 100}
        candidates: list[str] = []
        for _ in range(MAX_LIST_PAGES):
            page = (await self._request("GET", f"{self.base}/v1/messages/batches", params=params)).json()
            data = page.get("data")
            if not isinstance(data, list):
                raise BatchHTTPError(0, "the batch list has no data list", answer=True)
            older = False
            for batch in data:
                if not isinstance(batch, dict):
                    continue
                try:
                    created = datetime.fromisoformat(str(batch.get("created_at"))).timestamp()
                except ValueError:
                    created = None  # unknown: it may be recent
                if created is not None and created < since - CLOCK_SKEW_S:
                    older = True
                    continue
                if str(batch.get("id")) in known:  # this run's own batches, journaled
                    continue
                if tally(
                    batch.get("request_counts"), ("processing", "succeeded", "errored", "canceled", "expired")
                ) in (n_requests, None):
                    candidates.append(str(batch.get("id")))
            last = page.get("last_id") or (data[-1].get("id") if data and isinstance(data[-1], dict) else None)
            if older or page.get("has_more") is not True or not last:
                break
            params = {"limit": 100, "after_id": str(last)}
        else:
            raise BatchHTTPError(
                0,
                f"the batch list goes on past {MAX_LIST_PAGES} pages without reaching the run's "
                "submission; lightemma cannot tell whether the batch exists",
                answer=True,
            )
        if candidates:
            raise BatchUnconfirmed(
                f"Anthropic batches cannot be looked up by name, and {len(candidates)} batch(es) of "
                f"{n_requests} request(s) were created since: {', '.join(candidates[:5])}"
            )
        return None

    async def aclose(self) -> None:
        await self._client.aclose()


def _message_result(custom_id: str, message: dict[str, Any]) -> dict[str, Any]:
    """An Anthropic message as an item result: input tokens include cache reads and writes (as litellm counts them)."""
    usage = message.get("usage") or {}

    base, out_tokens = count(usage, "input_tokens"), count(usage, "output_tokens")
    read, written = count(usage, "cache_read_input_tokens") or 0, count(usage, "cache_creation_input_tokens") or 0
    total = None if base is None else base + read + written
    text = "".join(b.get("text", "") for b in message.get("content") or [] if b.get("type") == "text")
    kw = ItemUsage(
        finish_reason=message.get("stop_reason"),
        input_tokens=total if total else None,
        output_tokens=out_tokens if total else None,
        cached_input_tokens=read if total else None,
        cache_write_tokens=written if total else None,
    )
    if not text.strip():
        return item_result(
            custom_id,
            error="EmptyResponse",
            error_message=f"no answer text (finish_reason={kw['finish_reason']})",
            **kw,
        )
    return item_result(custom_id, text=text, **kw)
