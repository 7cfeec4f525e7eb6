"""OpenAI Batch API through litellm's batch functions (``acreate_file``, ``acreate_batch``, ``aretrieve_batch``,
``afile_content``, ``alist_batches``: litellm 1.106.2 serves them for OpenAI and OpenAI-compatible bases).

Input: a JSONL file of ``{"custom_id", "method": "POST", "url": "/v1/chat/completions", "body"}`` lines, at most
50,000 requests and 200 MB (platform.openai.com/docs/guides/batch, "Rate limits" / "Batch API"). Status:
``validating`` → ``in_progress`` → ``finalizing`` → ``completed`` (or ``failed``, ``expired``, ``cancelled``).
Results: the output file (one line per answered request, ``response.body`` a chat completion) and the error
file (``error.code`` such as ``batch_expired``, or ``response.status_code`` ≥ 400), in any order.
"""

from __future__ import annotations

import json
from typing import Any

from lightemma._litellm import litellm
from lightemma.backends.batch.base import ENDED, FAILED, PENDING, BatchHTTPError, BatchStatus, item_result

TERMINAL = {"completed": ENDED, "expired": ENDED, "cancelled": ENDED, "failed": FAILED}
UNRUN = ("batch_expired", "batch_cancelled")  # error codes of requests the batch never ran


def _http_error(exc: Exception) -> BatchHTTPError:
    status = getattr(exc, "status_code", None)
    return BatchHTTPError(status if isinstance(status, int) else 0, str(exc).splitlines()[0][:300] if str(exc) else type(exc).__name__)


class OpenAIBatches:
    """OpenAI's Batch API (see the module docstring)."""

    provider = "openai"
    max_requests = 50_000
    max_bytes = 200 * 1000 * 1000

    def __init__(self, model: str, *, api_base: str | None, api_key: str | None) -> None:
        """``api_key``: the key to send, as the run's API backend decided it; None sends none (litellm is given a
        placeholder, so it reads no key from the environment). ``user:pw@`` in ``api_base`` stays in the URL: the
        HTTP client sends it as Basic auth on every call (litellm's ``alist_batches`` and ``afile_content`` drop
        ``extra_headers``); messages are scrubbed of it by :class:`~lightemma.backends.batch.BatchBackend`."""
        from lightemma.backends.api import NO_KEY

        self.model = model.split("/", 1)[1] if model.startswith(("openai/", "hosted_vllm/")) else model
        self._where = {"custom_llm_provider": "openai", "api_base": api_base, "api_key": api_key or NO_KEY}

    def entry(self, custom_id: str, body: dict[str, Any]) -> dict[str, Any]:
        body = dict(body, model=self.model)
        if "max_tokens" in body:  # the Batch API's chat bodies take max_completion_tokens (max_tokens is deprecated)
            body["max_completion_tokens"] = body.pop("max_tokens")
        return {"custom_id": custom_id, "method": "POST", "url": "/v1/chat/completions", "body": body}

    async def submit(self, entries: list[dict[str, Any]], token: str) -> str:
        data = "".join(json.dumps(e, separators=(",", ":"), ensure_ascii=False) + "\n" for e in entries).encode("utf-8")
        try:
            upload = await litellm.acreate_file(file=(f"{token}.jsonl", data), purpose="batch", **self._where)
            batch = await litellm.acreate_batch(completion_window="24h", endpoint="/v1/chat/completions",
                                                input_file_id=upload.id, metadata={"lightemma_token": token}, **self._where)
        except Exception as exc:  # noqa: BLE001 - every provider error is reported with its status
            raise _http_error(exc) from None
        return str(batch.id)

    async def status(self, batch_id: str) -> BatchStatus:
        try:
            batch = await litellm.aretrieve_batch(batch_id=batch_id, **self._where)
        except Exception as exc:  # noqa: BLE001
            raise _http_error(exc) from None
        state = str(batch.status)
        counts = batch.request_counts.model_dump() if getattr(batch, "request_counts", None) is not None else {}
        reason = None
        errors = getattr(batch, "errors", None)
        if errors is not None and getattr(errors, "data", None):
            reason = "; ".join(f"{e.code}: {e.message}" + (f" (line {e.line})" if getattr(e, "line", None) else "")
                               for e in errors.data[:3])
        return BatchStatus(state=TERMINAL.get(state, PENDING), provider_state=state, counts=counts, reason=reason,
                           handle={"output_file_id": batch.output_file_id, "error_file_id": batch.error_file_id})

    async def _lines(self, file_id: str | None) -> list[dict[str, Any]]:
        if not file_id:
            return []
        try:
            content = await litellm.afile_content(file_id=file_id, **self._where)
        except Exception as exc:  # noqa: BLE001
            raise _http_error(exc) from None
        return [json.loads(line) for line in content.content.decode("utf-8").splitlines() if line.strip()]

    async def results(self, batch_id: str, status: BatchStatus) -> list[dict[str, Any]]:
        out = []
        lines = await self._lines(status.handle.get("output_file_id")) + await self._lines(status.handle.get("error_file_id"))
        for line in lines:
            cid = str(line.get("custom_id"))
            error, response = line.get("error"), line.get("response") or {}
            if error:
                code = str(error.get("code") or "error")
                out.append(item_result(cid, error="BatchExpired" if code in UNRUN else "BatchRequestError",
                                       error_message=f"{code}: {error.get('message')}", resubmit=code in UNRUN))
                continue
            body = response.get("body") or {}
            if int(response.get("status_code") or 0) >= 400 or "choices" not in body:
                message = ((body.get("error") or {}).get("message") if isinstance(body, dict) else None) or "no completion"
                out.append(item_result(cid, error="BatchRequestError",
                                       error_message=f"HTTP {response.get('status_code')}: {message}"))
                continue
            out.append(_completion_result(cid, body))
        return out

    async def find(self, token: str) -> str | None:
        try:
            page = await litellm.alist_batches(limit=100, **self._where)
        except Exception as exc:  # noqa: BLE001
            raise _http_error(exc) from None
        for batch in getattr(page, "data", None) or []:
            if (getattr(batch, "metadata", None) or {}).get("lightemma_token") == token:
                return str(batch.id)
        return None

    async def aclose(self) -> None:
        return None


def _completion_result(custom_id: str, body: dict[str, Any]) -> dict[str, Any]:
    """An OpenAI chat completion as an item result (usage as :func:`lightemma.backends.api._usage` reads it)."""
    from lightemma.backends.api import _usage

    choice = (body.get("choices") or [{}])[0]
    text = (choice.get("message") or {}).get("content")
    usage = _usage(body.get("usage"), "openai")
    kw = dict(finish_reason=choice.get("finish_reason"), input_tokens=usage.input, output_tokens=usage.output,
              reasoning_tokens=usage.reasoning, cached_input_tokens=usage.cached, cache_write_tokens=usage.written)
    if not text or not str(text).strip():
        return item_result(custom_id, error="EmptyResponse", error_message=f"no answer text (finish_reason={kw['finish_reason']})", **kw)
    return item_result(custom_id, text=str(text), **kw)
