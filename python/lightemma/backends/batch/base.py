"""The one small interface every provider's batch adapter implements, and what it returns.

An adapter turns OpenAI-style chat bodies (``model``, ``messages`` with ``image_url`` data URLs,
``max_tokens``, ``temperature``, ``response_format``) into its provider's batch entries, creates a
batch, reports its state and reads its results back as :class:`ItemResult` dicts keyed by custom id.
It never decides anything about the run: waves, splitting, polling, the journal and resubmission live in
:class:`lightemma.backends.batch.BatchBackend`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any, Protocol

#: states of a batch as lightemma sees it: still running, or one terminal state
PENDING, ENDED, FAILED = "pending", "ended", "failed"

#: what one reply of a batch API may be, decoded (docs/run.md, "Limits"): RESULT_BYTES_PER_REQUEST for every request
#: of the batch it is about (an answer of 64k tokens fits), and never less than MIN_REPLY_BYTES. A status poll, a
#: results file or a listing past it fails that call (the run stops, resumable); an endless or bloated body never
#: fills memory. Online replies have their own limit (:data:`lightemma.backends.openai_http.MAX_BODY_BYTES`).
RESULT_BYTES_PER_REQUEST = 256 << 10
MIN_REPLY_BYTES = 64 << 20


def results_limit(n_requests: int) -> int:
    """The most bytes lightemma reads of one reply about a batch of ``n_requests`` requests (see above)."""
    return max(MIN_REPLY_BYTES, int(n_requests) * RESULT_BYTES_PER_REQUEST)


class BatchHTTPError(Exception):
    """A provider's batch endpoint answered with an error (``status`` 0: no answer at all)."""

    def __init__(self, status: int, message: str, *, answer: bool = False) -> None:
        super().__init__(f"HTTP {status}: {message}" if status else message)
        self.status = status
        self.answer = answer  # the provider answered, with something lightemma must not use (not worth a retry)

    @property
    def transient(self) -> bool:
        """Worth retrying: a dropped connection, a rate limit, a server error."""
        return not self.answer and (self.status == 0 or self.status == 429 or self.status >= 500)

    @property
    def auth(self) -> bool:
        return self.status in (401, 403)


@dataclass
class BatchStatus:
    """Where a batch stands: ``state`` (pending / ended / failed), the provider's own word, counts, a reason."""

    state: str
    provider_state: str
    counts: dict[str, Any] = field(default_factory=dict)
    reason: str | None = None  # why a batch failed (validation errors, …)
    handle: dict[str, Any] = field(default_factory=dict)  # what reading its results needs (file ids, URLs)


def item_result(custom_id: str, *, text: str | None = None, finish_reason: str | None = None,
                input_tokens: int | None = None, output_tokens: int | None = None, reasoning_tokens: int | None = None,
                cached_input_tokens: int | None = None, cache_write_tokens: int | None = None, error: str | None = None,
                error_message: str | None = None, resubmit: bool = False) -> dict[str, Any]:
    """One request's result as saved in ``batches/<id>.jsonl``: text or error, usage as reported (None = unknown).

    ``resubmit``: the provider never ran it (expired, canceled): it may be sent again in a new batch.
    """
    return {"custom_id": custom_id, "text": text, "finish_reason": finish_reason, "input_tokens": input_tokens,
            "output_tokens": output_tokens, "reasoning_tokens": reasoning_tokens, "cached_input_tokens": cached_input_tokens,
            "cache_write_tokens": cache_write_tokens, "error": error, "error_message": error_message, "resubmit": resubmit}


async def http_call(client: Any, method: str, url: str, **kw: Any) -> Any:
    """One request on an ``httpx.AsyncClient``; the response, or :class:`BatchHTTPError` with the provider's message."""
    import httpx

    try:
        response = await client.request(method, url, **kw)
    except httpx.HTTPError as exc:
        raise BatchHTTPError(0, f"{type(exc).__name__}: {exc}") from None
    if response.status_code >= 400:
        try:
            message = response.json().get("error", {}).get("message") or response.text[:300]
        except (ValueError, AttributeError):
            message = response.text[:300]
        raise BatchHTTPError(response.status_code, str(message))
    return response


def endpoint(api_base: str | None, default: str, api_key: str | None, *, key_header: str,
             version: str) -> tuple[str, dict[str, str]]:
    """The base URL and headers of a provider's own batch HTTP API (Anthropic, Gemini).

    The base is ``api_base`` without credentials and a trailing ``version`` (``/v1``, ``/v1beta``), else
    ``default``; the headers carry ``api_key`` — the key the run's API backend decided to send, None for none —
    in ``key_header``, and ``user:pw@`` of ``api_base`` as Basic auth. No key is read from the environment here.
    """
    from lightemma.backends.retry import split_credentials

    url, basic = split_credentials(api_base) if api_base else (default, None)
    url = url.rstrip("/")
    if url.endswith(version):
        url = url[: -len(version)]
    headers = {key_header: api_key} if api_key else {}
    if basic:
        headers["Authorization"] = basic
    return url, headers


def count(usage: dict[str, Any], name: str) -> int | None:
    """A token count a provider reported: a non-negative int, else None (unknown, never zero)."""
    value = usage.get(name)
    return value if isinstance(value, int) and not isinstance(value, bool) and value >= 0 else None


def entry_bytes(entry: Any) -> int:
    """Bytes one entry takes in a batch (its JSON line)."""
    return len(json.dumps(entry, separators=(",", ":"), ensure_ascii=False).encode("utf-8")) + 1


def split_data_url(url: str) -> tuple[str, str]:
    """(mime type, base64 data) of a ``data:<mime>;base64,<data>`` URL."""
    head, _, data = url.partition(",")
    mime = head[5:].split(";", 1)[0] if head.startswith("data:") else "image/jpeg"
    return mime or "image/jpeg", data


class BatchAdapter(Protocol):
    """One provider's batch interface (see the module docstring)."""

    provider: str
    max_requests: int  # requests per batch the provider accepts
    max_bytes: int  # bytes per batch (input file or request body) the provider accepts

    def entry(self, custom_id: str, body: dict[str, Any]) -> dict[str, Any]:
        """The provider's batch entry for one OpenAI-style chat body."""
        ...

    async def submit(self, entries: list[dict[str, Any]], token: str) -> str:
        """Create a batch of ``entries`` named/tagged ``token``; its id."""
        ...

    async def status(self, batch_id: str) -> BatchStatus:
        ...

    async def results(self, batch_id: str, status: BatchStatus) -> list[dict[str, Any]]:
        """Every result of an ended batch (:func:`item_result` dicts), in whatever order the provider gives them."""
        ...

    async def find(self, token: str) -> str | None:
        """The id of a batch created with ``token`` (a submission cut off before its id was journaled), if found."""
        ...

    async def aclose(self) -> None:
        ...
