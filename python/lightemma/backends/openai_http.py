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
                body = await response.read()
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

    async def aclose(self) -> None:
        if self._session is not None and not self._session.closed and self._loop is asyncio.get_running_loop():
            await self._session.close()
        self._session = None
