"""A lean OpenAI chat-completions client over aiohttp, for high-throughput OpenAI-compatible servers.

litellm spends several milliseconds of CPU per call (request transformation,
logging, cost bookkeeping). Against a local vLLM server answering hundreds of
requests at once that becomes the bottleneck, so the API backend can talk to an
``--api-base`` endpoint directly (``transport="direct"``). Errors are raised as
exceptions named like litellm's (``RateLimitError``, ``Timeout``,
``APIConnectionError``, …) so retries, fatal errors and records work the same.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Mapping
from typing import Any

import aiohttp

MAX_BODY_BYTES = 8 << 20  # the largest response body read (a chat completion is a few KiB); beyond it the call fails


class HTTPCallError(Exception):
    """A failed call; subclasses carry litellm's error class names. ``headers`` holds the response headers."""

    def __init__(self, message: str, *, status: int | None = None, headers: Mapping[str, str] | None = None) -> None:
        super().__init__(message)
        self.status = status
        self.headers = dict(headers or {})


class BadRequestError(HTTPCallError): ...
class AuthenticationError(HTTPCallError): ...
class PermissionDeniedError(HTTPCallError): ...
class NotFoundError(HTTPCallError): ...
class UnprocessableEntityError(HTTPCallError): ...
class RateLimitError(HTTPCallError): ...
class InternalServerError(HTTPCallError): ...
class BadGatewayError(HTTPCallError): ...
class ServiceUnavailableError(HTTPCallError): ...
class Timeout(HTTPCallError): ...
class APIConnectionError(HTTPCallError): ...
class APIError(HTTPCallError): ...
class ResponseTooLargeError(HTTPCallError): ...  # not retried: the same request would get the same body


_BY_STATUS: dict[int, type[HTTPCallError]] = {
    400: BadRequestError, 401: AuthenticationError, 403: PermissionDeniedError, 404: NotFoundError, 408: Timeout,
    422: UnprocessableEntityError, 429: RateLimitError, 500: InternalServerError, 502: BadGatewayError,
    503: ServiceUnavailableError, 504: Timeout,
}


def _error_for(status: int, headers: Mapping[str, str], body: bytes) -> HTTPCallError:
    """The exception for an HTTP error status, with the server's message when it sent one."""
    try:
        message = json.loads(body)["error"]["message"]
    except (ValueError, KeyError, TypeError):
        message = body[:200].decode("utf-8", "replace")
    cls = _BY_STATUS.get(status) or (InternalServerError if status >= 500 else BadRequestError)
    return cls(f"HTTP {status}: {message}", status=status, headers=headers)


class OpenAIHTTPClient:
    """POSTs ``/chat/completions`` under ``api_base``; one aiohttp session per event loop."""

    def __init__(self, api_base: str, api_key: str | None, timeout: float, max_body: int = MAX_BODY_BYTES) -> None:
        from lightemma.backends.retry import split_credentials

        base, basic = split_credentials(api_base)  # user:password@ in the URL: sent as Basic auth, never in the URL
        self.url = base.rstrip("/") + "/chat/completions"
        self._headers = {"Content-Type": "application/json"}
        if basic:
            self._headers["Authorization"] = basic
        elif api_key:
            self._headers["Authorization"] = f"Bearer {api_key}"
        self.max_body = max_body
        self._timeout = aiohttp.ClientTimeout(total=timeout)
        self._session: aiohttp.ClientSession | None = None
        self._loop: asyncio.AbstractEventLoop | None = None

    def _client(self) -> aiohttp.ClientSession:
        loop = asyncio.get_running_loop()
        if self._session is None or self._loop is not loop or self._session.closed:
            self._session = aiohttp.ClientSession(connector=aiohttp.TCPConnector(limit=0), headers=self._headers)
            self._loop = loop
        return self._session

    async def chat(self, model: str, messages: list[dict[str, Any]], params: Mapping[str, Any]) -> dict[str, Any]:
        """One chat completion; returns the response JSON or raises an :class:`HTTPCallError`."""
        payload = json.dumps({"model": model, "messages": messages, **params})
        try:
            async with self._client().post(self.url, data=payload, timeout=self._timeout) as response:
                body = await self._read(response)
                if response.status >= 400:
                    raise _error_for(response.status, response.headers, body)
        except HTTPCallError:
            raise
        except asyncio.TimeoutError:
            raise Timeout(f"no answer within {self._timeout.total} s") from None
        except aiohttp.ClientError as exc:
            raise APIConnectionError(f"connection error: {type(exc).__name__}: {exc}") from None
        try:
            data = json.loads(body)
        except ValueError:
            raise APIError(f"HTTP {response.status}: the body is not JSON") from None
        if not isinstance(data, dict):
            raise APIError(f"HTTP {response.status}: unexpected body")
        return data

    async def _read(self, response: aiohttp.ClientResponse) -> bytes:
        """The body, read in chunks and never past :attr:`max_body` bytes (a larger one fails the call)."""
        def too_large(size: str) -> ResponseTooLargeError:
            return ResponseTooLargeError(f"HTTP {response.status}: the response body is {size}, more than the "
                                         f"{self.max_body} bytes lightemma reads", status=response.status)

        if response.content_length is not None and response.content_length > self.max_body:
            raise too_large(f"{response.content_length} bytes")
        body = bytearray()
        async for chunk in response.content.iter_chunked(1 << 16):
            body += chunk
            if len(body) > self.max_body:
                raise too_large(f"over {self.max_body} bytes")
        return bytes(body)

    async def aclose(self) -> None:
        if self._session is not None and not self._session.closed and self._loop is asyncio.get_running_loop():
            await self._session.close()
        self._session = None


# -- the same bound for litellm's clients (httpx): its OpenAI SDK client and its native Anthropic / Gemini ones ---

BODY_GUARD: Any = None  # set below: a ContextVar holding the current call's {"too_large": message} slot


def _guard() -> Any:
    global BODY_GUARD
    if BODY_GUARD is None:
        import contextvars

        BODY_GUARD = contextvars.ContextVar("lightemma_body_guard", default=None)
    return BODY_GUARD


def body_limit_hook(max_body: int = MAX_BODY_BYTES) -> Any:
    """An httpx ``response`` event hook that lets a client read at most ``max_body`` bytes of a response body.

    A ``Content-Length`` over the limit fails at once; a body without one is counted chunk by chunk as the
    client reads it and the read ends past the limit. Either way the call's slot in :data:`BODY_GUARD`
    (set by the caller) says why, so the caller records :class:`ResponseTooLargeError` whatever error
    the client library wraps it in. A hook (not a transport) keeps each client's own connection pool,
    TLS and proxy settings.
    """
    import httpx

    class _Stream(httpx.AsyncByteStream):
        def __init__(self, inner: Any, slot: Any) -> None:
            self.inner, self.slot = inner, slot

        async def __aiter__(self) -> Any:
            size = 0
            async for chunk in self.inner:
                size += len(chunk)
                if size > max_body:
                    raise _too_large(self.slot, f"the response body is over {max_body} bytes, more than lightemma reads")
                yield chunk

        async def aclose(self) -> None:
            await self.inner.aclose()

    async def hook(response: Any) -> None:
        slot = _guard().get()
        length = response.headers.get("content-length")
        if length and length.isdigit() and int(length) > max_body:
            raise _too_large(slot, f"the response body is {length} bytes, more than the {max_body} bytes lightemma reads")
        response.stream = _Stream(response.stream, slot)

    return hook


def _too_large(slot: dict[str, str] | None, message: str) -> ResponseTooLargeError:
    if slot is not None:
        slot["too_large"] = message
    return ResponseTooLargeError(message)


def limited_openai_client(api_key: str, base_url: str | None, max_body: int = MAX_BODY_BYTES) -> Any:
    """The OpenAI SDK's async client (litellm's ``client=`` for the OpenAI protocol), reading at most ``max_body``
    bytes of a body (:func:`body_limit_hook`); no retries of its own."""
    from openai import AsyncOpenAI, DefaultAsyncHttpxClient

    http = DefaultAsyncHttpxClient(event_hooks={"response": [body_limit_hook(max_body)]})
    return AsyncOpenAI(api_key=api_key, base_url=base_url, max_retries=0, http_client=http)


def limited_litellm_handler(max_body: int = MAX_BODY_BYTES) -> Any:
    """litellm's ``AsyncHTTPHandler`` reading at most ``max_body`` bytes of a body (:func:`body_limit_hook`): the
    ``client=`` litellm's native Anthropic (``/v1/messages``) and Gemini (``generateContent``) clients post through."""
    from litellm.llms.custom_httpx.http_handler import AsyncHTTPHandler

    return AsyncHTTPHandler(event_hooks={"response": [body_limit_hook(max_body)]})
