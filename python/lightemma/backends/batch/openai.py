"""OpenAI's Batch API over HTTP (httpx), as litellm 1.106.2's batch functions call it, but through a client that
reads at most what :func:`lightemma.backends.batch.adapter.results_limit` allows (litellm's batch and file functions
take no client of their own for OpenAI, so their replies could not be bounded).

Input: a JSONL file of ``{"custom_id", "method": "POST", "url": "/v1/chat/completions", "body"}`` lines, at most
50,000 requests and 200 MB (platform.openai.com/docs/guides/batch, "Rate limits" / "Batch API"), uploaded with
``POST /files`` (``purpose=batch``), then ``POST /batches``. Status (``GET /batches/{id}``): ``validating`` →
``in_progress`` → ``finalizing`` → ``completed`` (or ``failed``, ``expired``, ``cancelled``). Results
(``GET /files/{id}/content``): the output file (one line per answered request, ``response.body`` a chat
completion) and the error file (``error.code`` such as ``batch_expired``, or ``response.status_code`` ≥ 400), in
any order. The base URL is ``--api-base`` (an OpenAI-compatible server's ``…/v1``), else ``OPENAI_BASE_URL`` /
``OPENAI_API_BASE`` when set (as litellm reads them; the API backend refuses one that is not a declared host),
else ``https://api.openai.com/v1``; the key the run's API backend decided goes only there, as a Bearer token.
"""

from __future__ import annotations

import json
import os
from collections.abc import Collection
from typing import Any

from lightemma.backends.api import _usage
from lightemma.backends.batch.adapter import (
    CLOCK_SKEW_S,
    ENDED,
    FAILED,
    MAX_LIST_PAGES,
    BatchHTTPError,
    BatchStatus,
    batch_client,
    batch_state,
    endpoint,
    http_call,
    item_result,
    jsonl_rows,
    tally,
    url_id,
)

TERMINAL = {"completed": ENDED, "expired": ENDED, "cancelled": ENDED, "failed": FAILED}
RUNNING = ("validating", "in_progress", "finalizing", "cancelling")  # any other status: not documented
UNRUN = ("batch_expired", "batch_cancelled")  # error codes of requests the batch never ran
RETRYABLE = {"token_limit_exceeded"}  # a failed batch's error codes that pass: the enqueued-token limit
DEFAULT_BASE = "https://api.openai.com/v1"


def base_url() -> str:
    """The base litellm's OpenAI batch and file calls use when no ``api_base`` is given."""
    return (os.environ.get("OPENAI_BASE_URL") or os.environ.get("OPENAI_API_BASE") or DEFAULT_BASE).rstrip("/")


class OpenAIBatches:
    """OpenAI's Batch API (see the module docstring)."""

    provider = "openai"
    max_requests = 50_000
    max_bytes = 200 * 1000 * 1000

    def __init__(self, model: str, *, api_base: str | None, api_key: str | None, timeout: float = 120.0) -> None:
        """``api_key``: the key to send, as the run's API backend decided it; None sends none (no key is read from the
        environment here). ``user:pw@`` in ``api_base`` is sent as Basic auth on every call, in place of the key (as
        the HTTP client litellm used sends it); messages are scrubbed of it by
        :class:`~lightemma.backends.batch.BatchBackend`."""
        self.model = model.split("/", 1)[1] if model.startswith(("openai/", "hosted_vllm/")) else model
        self.base, headers = endpoint(
            api_base, base_url(), f"Bearer {api_key}" if api_key else None, key_header="Authorization", version=""
        )  # Basic auth, when given, replaces it
        self._client = batch_client(timeout, headers)

    def entry(self, custom_id: str, body: dict[str, Any]) -> dict[str, Any]:
        body = dict(body, model=self.model)
        if "max_tokens" in body:  # the Batch API's chat bodies take max_completion_tokens (max_tokens is deprecated)
            body["max_completion_tokens"] = body.pop("max_tokens")
        return {"custom_id": custom_id, "method": "POST", "url": "/v1/chat/completions", "body": body}

    async def _json(self, method: str, path: str, **kw: Any) -> dict[str, Any]:
        response = await http_call(self._client, method, f"{self.base}{path}", **kw)
        try:
            data = response.json()
        except ValueError:
            raise BatchHTTPError(0, f"{method} {path}: the answer is not JSON", answer=True) from None
        if not isinstance(data, dict):
            raise BatchHTTPError(0, f"{method} {path}: the answer is not a JSON object", answer=True)
        return data

    async def submit(self, entries: list[dict[str, Any]], token: str) -> str:
        data = "".join(json.dumps(e, separators=(",", ":"), ensure_ascii=False) + "\n" for e in entries).encode("utf-8")
        upload = await self._json("POST", "/files", files={"file": (f"{token}.jsonl", data)}, data={"purpose": "batch"})
        batch = await self._json(
            "POST",
            "/batches",
            json={
                "input_file_id": upload.get("id"),
                "completion_window": "24h",
                "endpoint": "/v1/chat/completions",
                "metadata": {"lightemma_token": token},
            },
        )
        if not batch.get("id"):
            raise BatchHTTPError(0, "the created batch has no id", answer=True)
        return str(batch["id"])

    async def status(self, batch_id: str) -> BatchStatus:
        batch = await self._json("GET", f"/batches/{url_id(batch_id)}")
        state = str(batch.get("status"))
        ours = batch_state(batch_id, state, TERMINAL, RUNNING)
        reason = None
        errors = (batch.get("errors") or {}).get("data") if isinstance(batch.get("errors"), dict) else None
        if errors:
            reason = "; ".join(
                f"{e.get('code')}: {e.get('message')}" + (f" (line {e['line']})" if e.get("line") else "")
                for e in errors[:3]
                if isinstance(e, dict)
            )
        counts = batch.get("request_counts")
        answered = tally(counts, ("completed", "failed"))
        total = tally(counts, ("total",))
        codes = {str(e.get("code")) for e in errors or () if isinstance(e, dict)}
        return BatchStatus(
            state=ours,
            provider_state=state,
            counts=dict(counts) if isinstance(counts, dict) else {},
            reason=reason,
            handle={"output_file_id": batch.get("output_file_id"), "error_file_id": batch.get("error_file_id")},
            answered=answered,
            unrun=None if answered is None or total is None else max(0, total - answered),
            canceled=state in ("cancelled", "cancelling"),
            retryable=bool(codes) and codes <= RETRYABLE,
        )

    async def _content(self, file_id: str | None) -> bytes:
        if not file_id:
            return b""
        response = await http_call(self._client, "GET", f"{self.base}/files/{url_id(file_id)}/content")
        return bytes(response.content)

    async def results(self, batch_id: str, status: BatchStatus) -> list[dict[str, Any]]:
        out = []
        files = [
            (fid, await self._content(fid))
            for fid in (status.handle.get("output_file_id"), status.handle.get("error_file_id"))
        ]
        for line in (row for fid, data in files for row in jsonl_rows(data, f"file {fid}")):
            cid = str(line.get("custom_id"))
            error, response = line.get("error"), line.get("response") or {}
            if error:
                code = str(error.get("code") or "error")
                out.append(
                    item_result(
                        cid,
                        error="BatchExpired" if code in UNRUN else "BatchRequestError",
                        error_message=f"{code}: {error.get('message')}",
                        resubmit=code in UNRUN,
                    )
                )
                continue
            body = response.get("body") or {}
            http_status = response.get("status_code")
            if not isinstance(http_status, int) or isinstance(http_status, bool) or not 100 <= http_status <= 599:
                raise ValueError(f"request {cid[:80]}: status_code {str(http_status)[:40]} is no HTTP status")
            if http_status >= 400 or not isinstance(body, dict) or "choices" not in body:
                message = (
                    (body.get("error") or {}).get("message") if isinstance(body, dict) else None
                ) or "no completion"
                out.append(
                    item_result(
                        cid, error="BatchRequestError", error_message=f"HTTP {response.get('status_code')}: {message}"
                    )
                )
                continue
            out.append(_completion_result(cid, body))
        return out

    async def find(self, token: str, since: float, n_requests: int, known: Collection[str] = ()) -> str | None:
        """Every page of ``GET /batches`` (newest first, ``after`` the last id of a page) down to ``since``."""
        params: dict[str, Any] = {"limit": 100}
        for _ in range(MAX_LIST_PAGES):
            page = await self._json("GET", "/batches", params=params)
            data = page.get("data")
            if not isinstance(data, list):
                raise BatchHTTPError(0, "the batch list has no data list", answer=True)
            older = False
            for batch in data:
                if not isinstance(batch, dict):
                    continue
                metadata = batch.get("metadata")
                if isinstance(metadata, dict) and metadata.get("lightemma_token") == token and batch.get("id"):
                    return str(batch["id"])
                created = batch.get("created_at")
                older = older or (isinstance(created, (int, float)) and created < since - CLOCK_SKEW_S)
            last = page.get("last_id") or (data[-1].get("id") if data and isinstance(data[-1], dict) else None)
            if older or page.get("has_more") is not True or not last:
                return None
            params = {"limit": 100, "after": str(last)}
        raise BatchHTTPError(
            0,
            f"the batch list goes on past {MAX_LIST_PAGES} pages without reaching the run's "
            "submission; lightemma cannot tell whether the batch exists",
            answer=True,
        )

    async def aclose(self) -> None:
        await self._client.aclose()


def _completion_result(custom_id: str, body: dict[str, Any]) -> dict[str, Any]:
    """An OpenAI chat completion as an item result (usage as :func:`lightemma.backends.api._usage` reads it)."""
    choice = (body.get("choices") or [{}])[0]
    text = (choice.get("message") or {}).get("content")
    if text is not None and not isinstance(text, str):  # a chat completion's content is a string (or null)
        raise TypeError(f"request {custom_id[:80]}: message content is a {type(text).__name__}, not text")
    usage = _usage(body.get("usage"), "openai")
    kw = dict(
        finish_reason=choice.get("finish_reason"),
        input_tokens=usage.input,
        output_tokens=usage.output,
        reasoning_tokens=usage.reasoning,
        cached_input_tokens=usage.cached,
        cache_write_tokens=usage.written,
    )
    if not text or not str(text).strip():
        return item_result(
            custom_id,
            error="EmptyResponse",
            error_message=f"no answer text (finish_reason={kw['finish_reason']})",
            **kw,
        )
    return item_result(custom_id, text=str(text), **kw)
