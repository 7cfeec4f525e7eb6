"""Gemini batch mode over HTTP (httpx): litellm 1.106.2 batches Gemini only through Vertex AI, not the Gemini API.

``POST /v1beta/models/{model}:batchGenerateContent`` with ``{"batch": {"displayName", "inputConfig": {"requests":
{"requests": [{"request": <a GenerateContentRequest>, "metadata": {"key": custom id}}]}}}}`` — inlined requests,
at most 20 MB per batch request (ai.google.dev/gemini-api/docs/batch-mode); ``GET /v1beta/{batches/ID}`` returns
an operation whose ``metadata.state`` goes ``BATCH_STATE_PENDING`` → ``RUNNING`` → ``SUCCEEDED`` (or ``FAILED``,
``CANCELLED``, ``EXPIRED``), with ``response.inlinedResponses.inlinedResponses[]`` (``response`` or ``error``,
each with its request's ``metadata``) once done. Results are matched by the metadata key, never by position.
The base URL is ``--api-base`` when it is Gemini's own host (or one ``LIGHTEMMA_PROVIDER_HOSTS`` declares; any
other ``--api-base`` is an OpenAI-compatible server, batched by the OpenAI adapter), else ``GEMINI_API_BASE`` when
set (as litellm reads it), else ``https://generativelanguage.googleapis.com``; the key the run's API backend
decided goes only there, in ``x-goog-api-key``.
"""

from __future__ import annotations

import os
from typing import Any

from lightemma.backends.batch.base import (
    ENDED,
    FAILED,
    BatchHTTPError,
    BatchStatus,
    batch_client,
    batch_state,
    count,
    endpoint,
    http_call,
    item_result,
    split_data_url,
    url_id,
)

TERMINAL = {"BATCH_STATE_SUCCEEDED": ENDED, "BATCH_STATE_EXPIRED": ENDED, "BATCH_STATE_CANCELLED": ENDED,
            "BATCH_STATE_FAILED": FAILED}
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
        contents = [{"role": "model" if m["role"] == "assistant" else "user", "parts": [_part(p) for p in m["content"]]}
                    for m in body["messages"]]
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
        return BatchStatus(state=batch_state(batch_id, state, TERMINAL, RUNNING), provider_state=state, counts=dict(meta.get("batchStats") or {}),
                           reason=f"{error.get('code')}: {error.get('message')}" if isinstance(error, dict) else None,
                           handle={"operation": data})

    async def results(self, batch_id: str, status: BatchStatus) -> list[dict[str, Any]]:
        data = status.handle.get("operation") or await self._request("GET", f"{self.base}/v1beta/{url_id(batch_id, slash=True)}")
        rows = (((data.get("response") or {}).get("inlinedResponses") or {}).get("inlinedResponses")) or []
        out = []
        for row in rows:
            cid = (row.get("metadata") or {}).get("key")
            if not cid:
                raise BatchHTTPError(0, f"batch {batch_id}: a response without its request's metadata key; cannot match it", answer=True)
            if "error" in row:
                err = row["error"] or {}
                out.append(item_result(str(cid), error="BatchRequestError", error_message=f"{err.get('code')}: {err.get('message')}"))
            else:
                out.append(_response_result(str(cid), row.get("response") or {}))
        return out

    async def find(self, token: str) -> str | None:
        data = await self._request("GET", f"{self.base}/v1beta/batches")
        for op in data.get("operations") or []:
            if (op.get("metadata") or {}).get("displayName") == token:
                return str(op.get("name"))
        return None

    async def aclose(self) -> None:
        await self._client.aclose()


def _response_result(custom_id: str, response: dict[str, Any]) -> dict[str, Any]:
    """A GenerateContentResponse as an item result: output = candidates + thoughts (as litellm counts them)."""
    usage = response.get("usageMetadata") or {}

    prompt, answer = count(usage, "promptTokenCount"), count(usage, "candidatesTokenCount")
    thoughts = count(usage, "thoughtsTokenCount")
    known = bool(prompt) and answer is not None
    candidate = (response.get("candidates") or [{}])[0]
    text = "".join(p.get("text", "") for p in (candidate.get("content") or {}).get("parts") or [] if not p.get("thought"))
    kw = dict(finish_reason=candidate.get("finishReason"), input_tokens=prompt if known else None,
              output_tokens=(answer + (thoughts or 0)) if known else None, reasoning_tokens=thoughts if known else None,
              cached_input_tokens=(count(usage, "cachedContentTokenCount") or 0) if known else None,
              cache_write_tokens=0 if known else None)
    if not text.strip():
        return item_result(custom_id, error="EmptyResponse", error_message=f"no answer text (finish_reason={kw['finish_reason']})", **kw)
    return item_result(custom_id, text=text, **kw)
