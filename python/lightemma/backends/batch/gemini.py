"""Gemini batch mode over HTTP (httpx): litellm 1.106.2 batches Gemini only through Vertex AI, not the Gemini API.

``POST /v1beta/models/{model}:batchGenerateContent`` with ``{"batch": {"displayName", "inputConfig": {"requests":
{"requests": [{"request": <a GenerateContentRequest>, "metadata": {"key": custom id}}]}}}}`` — inlined requests,
at most 20 MB per batch request (ai.google.dev/gemini-api/docs/batch-mode); ``GET /v1beta/{batches/ID}`` returns
an operation whose ``metadata.state`` goes ``BATCH_STATE_PENDING`` → ``RUNNING`` → ``SUCCEEDED`` (or ``FAILED``,
``CANCELLED``, ``EXPIRED``), with ``response.inlinedResponses.inlinedResponses[]`` (``response`` or ``error``,
each with its request's ``metadata``) once done — or in a JSONL ``response.responsesFile``, which is read too;
``metadata.batchStats`` counts what it ran. Results are matched by the metadata key, never by position.
The base URL is ``--api-base`` when it is Gemini's own host (or one ``LIGHTEMMA_PROVIDER_HOSTS`` declares; any
other ``--api-base`` is an OpenAI-compatible server, batched by the OpenAI adapter), else ``GEMINI_API_BASE`` when
set (as litellm reads it), else ``https://generativelanguage.googleapis.com``; the key the run's API backend
decided goes only there, in ``x-goog-api-key``.
"""

from __future__ import annotations

import os
from collections.abc import Collection
from typing import Any

from lightemma.backends.batch.adapter import (
    CLOCK_SKEW_S,
    ENDED,
    FAILED,
    MAX_LIST_PAGES,
    BatchHTTPError,
    BatchStatus,
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

TERMINAL = {
    "BATCH_STATE_SUCCEEDED": ENDED,
    "BATCH_STATE_EXPIRED": ENDED,
    "BATCH_STATE_CANCELLED": ENDED,
    "BATCH_STATE_FAILED": FAILED,
}
RUNNING = ("BATCH_STATE_UNSPECIFIED", "BATCH_STATE_PENDING", "BATCH_STATE_RUNNING")  # any other state: not documented


def base_url() -> str:
    return (os.environ.get("GEMINI_API_BASE") or "https://generativelanguage.googleapis.com").rstrip("/")


def _part(part: dict[str, Any]) -> dict[str, Any]:
    if part.get("type") == "image_url":
        mime, data = split_data_url(part["image_url"]["url"])
        return {"inline_data": {"mime_type": mime, "data": data}}
    return {"text": part.get("text", "")}


class GeminiBatches:
    """The Gemini API's batch mode (see the module docstring)."""

    provider = "gemini"
    max_requests = 100_000
    max_bytes = 19 * 1000 * 1000  # the 20 MB inline limit, with room for the envelope

    def __init__(self, model: str, *, api_key: str | None, timeout: float = 120.0, base: str | None = None) -> None:
        self.model = model.split("/", 1)[1] if model.startswith("gemini/") else model
        self.base, headers = endpoint(base, base_url(), api_key, key_header="x-goog-api-key", version="/v1beta")
        self._client = batch_client(timeout, headers)

    def entry(self, custom_id: str, body: dict[str, Any]) -> dict[str, Any]:
        config: dict[str, Any] = {"maxOutputTokens": body["max_tokens"]}
        if "temperature" in body:
            config["temperature"] = body["temperature"]
        contents = [
            {"role": "model" if m["role"] == "assistant" else "user", "parts": [_part(p) for p in m["content"]]}
            for m in body["messages"]
        ]
        return {"request": {"contents": contents, "generationConfig": config}, "metadata": {"key": custom_id}}

    async def _request(self, method: str, url: str, **kw: Any) -> Any:
        response = await http_call(self._client, method, url, **kw)
        return response.json()

    async def submit(self, entries: list[dict[str, Any]], token: str) -> str:
        body = {"batch": {"displayName": token, "inputConfig": {"requests": {"requests": entries}}}}
        data = await self._request("POST", f"{self.base}/v1beta/models/{self.model}:batchGenerateContent", json=body)
        name = data.get("name") or (data.get("metadata") or {}).get("name")
        if not name:
            raise BatchHTTPError(0, "the batch was created without a name in the answer", answer=True)
        return str(name)

    async def status(self, batch_id: str) -> BatchStatus:
        data = await self._request("GET", f"{self.base}/v1beta/{url_id(batch_id, slash=True)}")
        meta = data.get("metadata") or {}
        state = str(meta.get("state"))
        error = data.get("error")
        stats = (
            {k: _int(v) for k, v in (meta.get("batchStats") or {}).items()}
            if isinstance(meta.get("batchStats"), dict)
            else None
        )
        zero = {"successfulRequestCount": 0, "failedRequestCount": 0}  # proto3 JSON leaves zero counts out
        answered = tally({**zero, **stats} if stats is not None else None, tuple(zero))
        total = tally(stats, ("requestCount",))
        return BatchStatus(
            state=batch_state(batch_id, state, TERMINAL, RUNNING),
            provider_state=state,
            counts=dict(stats or {}),
            reason=f"{error.get('code')}: {error.get('message')}" if isinstance(error, dict) else None,
            handle={"operation": data},
            answered=answered,
            unrun=None if answered is None or total is None else max(0, total - answered),
            canceled=state == "BATCH_STATE_CANCELLED",
        )

    async def results(self, batch_id: str, status: BatchStatus) -> list[dict[str, Any]]:
        """The batch's responses from every place Gemini documents: inlined in the operation
        (``response.inlinedResponses``) and the JSONL ``response.responsesFile`` (``GET /download/v1beta/{file}:download
        ?alt=media``, one ``{"key", "response" | "error"}`` per line)."""
        data = status.handle.get("operation") or await self._request(
            "GET", f"{self.base}/v1beta/{url_id(batch_id, slash=True)}"
        )
        output = data.get("response") or {}
        rows = list(((output.get("inlinedResponses") or {}).get("inlinedResponses")) or [])
        if output.get("responsesFile"):
            name = url_id(output["responsesFile"], slash=True)
            response = await http_call(
                self._client, "GET", f"{self.base}/download/v1beta/{name}:download", params={"alt": "media"}
            )
            rows.extend(jsonl_rows(response.content, f"batch {batch_id} responses file"))
        out = []
        for row in rows:
            cid = (row.get("metadata") or {}).get("key") or row.get("key")
            if not cid:
                raise BatchHTTPError(
                    0, f"batch {batch_id}: a response without its request's metadata key; cannot match it", answer=True
                )
            if "error" in row:
                err = row["error"] or {}
                out.append(
                    item_result(
                        str(cid), error="BatchRequestError", error_message=f"{err.get('code')}: {err.get('message')}"
                    )
                )
            else:
                out.append(_response_result(str(cid), row.get("response") or {}))
        return out

    async def find(self, token: str, since: float, n_requests: int, known: Collection[str] = ()) -> str | None:
        """Every page of ``GET /v1beta/batches`` (``pageToken`` the last page's ``nextPageToken``), newest first, down
        to ``since``, for the batch whose display name is ``token``."""
        from datetime import datetime

        params: dict[str, Any] = {"pageSize": 100}
        for _ in range(MAX_LIST_PAGES):
            data = await self._request("GET", f"{self.base}/v1beta/batches", params=params)
            operations = data.get("operations") or []
            if not isinstance(operations, list):
                raise BatchHTTPError(0, "the batch list has no operations list", answer=True)
            older = False
            for op in operations:
                meta = op.get("metadata") if isinstance(op, dict) else None
                if not isinstance(meta, dict):
                    continue
                if meta.get("displayName") == token and op.get("name"):
                    return str(op["name"])
                try:
                    created = datetime.fromisoformat(str(meta.get("createTime"))).timestamp()
                    older = older or created < since - CLOCK_SKEW_S
                except ValueError:
                    pass
            following = data.get("nextPageToken")
            if older or not following:
                return None
            params = {"pageSize": 100, "pageToken": str(following)}
        raise BatchHTTPError(
            0,
            f"the batch list goes on past {MAX_LIST_PAGES} pages without reaching the run's "
            "submission; lightemma cannot tell whether the batch exists",
            answer=True,
        )

    async def aclose(self) -> None:
        await self._client.aclose()


def _int(value: Any) -> Any:
    """A count as Gemini sends it (int64 fields are JSON strings, ``"16"``): an int, else the value unchanged."""
    return int(value) if isinstance(value, str) and value.isdigit() and len(value) < 19 else value


def _response_result(custom_id: str, response: dict[str, Any]) -> dict[str, Any]:
    """A GenerateContentResponse as an item result: output = candidates + thoughts (as litellm counts them)."""
    usage = response.get("usageMetadata") or {}

    prompt, answer = count(usage, "promptTokenCount"), count(usage, "candidatesTokenCount")
    thoughts = count(usage, "thoughtsTokenCount")
    known = bool(prompt) and answer is not None
    candidate = (response.get("candidates") or [{}])[0]
    text = "".join(
        p.get("text", "") for p in (candidate.get("content") or {}).get("parts") or [] if not p.get("thought")
    )
    kw = dict(
        finish_reason=candidate.get("finishReason"),
        input_tokens=prompt if known else None,
        output_tokens=(answer + (thoughts or 0)) if known and answer is not None else None,  # known: answer is
        reasoning_tokens=thoughts if known else None,
        cached_input_tokens=(count(usage, "cachedContentTokenCount") or 0) if known else None,
        cache_write_tokens=0 if known else None,
    )
    if not text.strip():
        return item_result(
            custom_id,
            error="EmptyResponse",
            error_message=f"no answer text (finish_reason={kw['finish_reason']})",
            **kw,
        )
    return item_result(custom_id, text=text, **kw)
