"""A lean OpenAI chat-completions client over aiohttp, for high-throughput OpenAI-compatible servers.

litellm spends several milliseconds of CPU per call (request transformation,
logging, cost bookkeeping). Against a local vLLM server answering hundreds of
requests at once that becomes the bottleneck, so the API backend can talk to an
``--api-base`` endpoint directly (``transport="direct"``). Errors are raised as
exceptions named like litellm's (``RateLimitError``, ``Timeout``,
``APIConnectionError``, …) so retries, fatal errors and records work the same.

Every reply, through this client or litellm's (OpenAI SDK, native Anthropic and Gemini), is read
within :data:`MAX_BODY_BYTES` decoded bytes: here by :meth:`OpenAIHTTPClient._read`, for litellm by
the httpx hooks of :func:`body_limit_hooks` (docs/run.md, "Limits"); a call may set its own limit with
:func:`body_guard` (a batch's results: :func:`lightemma.backends.batch.adapter.results_limit`).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import re
import zlib
from collections.abc import Iterator, Mapping
from typing import Any

import aiohttp

from lightemma.backends.retry import split_credentials

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


class ResponseEncodingError(HTTPCallError): ...  # a body in an encoding not asked for, or not decodable: not retried


_BY_STATUS: dict[int, type[HTTPCallError]] = {
    400: BadRequestError,
    401: AuthenticationError,
    403: PermissionDeniedError,
    404: NotFoundError,
    408: Timeout,
    422: UnprocessableEntityError,
    429: RateLimitError,
    500: InternalServerError,
    502: BadGatewayError,
    503: ServiceUnavailableError,
    504: Timeout,
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
        base, basic = split_credentials(api_base)  # user:password@ in the URL: sent as Basic auth, never in the URL
        self.url = base.rstrip("/") + "/chat/completions"
        # the encodings aiohttp inflates (as it reads: the body limit counts decoded bytes); any other is refused unread
        self._headers = {"Content-Type": "application/json", "Accept-Encoding": "gzip, deflate"}
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
        encoding = ""
        try:
            async with self._client().post(self.url, data=payload, timeout=self._timeout) as response:
                encoding = response.headers.get("Content-Encoding", "").strip().lower()
                encoding = "" if encoding == "identity" else encoding
                body = await self._read(response)
                if response.status >= 400:
                    raise _error_for(response.status, response.headers, body)
        except HTTPCallError:
            raise
        except TimeoutError:
            raise Timeout(f"no answer within {self._timeout.total} s") from None
        except aiohttp.ClientError as exc:
            # aiohttp inflates as it parses: a coding it cannot decode, or a corrupt, cut-off or overlong compressed
            # body, is an error of the reply (the same request gets the same), not of the connection
            named = re.search(r"content-encoding: ?([\w-]+)(?: \(([\w-]+)\))?", str(exc), re.IGNORECASE)
            coding = (named.group(2) or named.group(1)).lower() if named else encoding
            if coding and coding not in _INFLATE:
                raise ResponseEncodingError(
                    f"the response body is encoded as {coding!r}, which lightemma did not ask for and does not decode"
                ) from None
            if coding and (named or isinstance(exc, aiohttp.ClientPayloadError)):
                raise ResponseEncodingError(f"the response body is not valid {coding} ({type(exc).__name__})") from None
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
            return ResponseTooLargeError(
                f"HTTP {response.status}: the response body is {size}, more than the "
                f"{self.max_body} bytes lightemma reads",
                status=response.status,
            )

        if response.content_length is not None and response.content_length > self.max_body:
            raise too_large(f"{response.content_length} bytes")
        body = bytearray()
        async for chunk in response.content.iter_chunked(1 << 16):  # inflated by aiohttp as it reads: counted decoded
            body += chunk
            if len(body) > self.max_body:
                raise too_large(f"over {self.max_body} bytes")
        return bytes(body)

    async def aclose(self) -> None:
        if self._session is not None and not self._session.closed and self._loop is asyncio.get_running_loop():
            await self._session.close()
        self._session = None


# -- the same bound for litellm's clients (httpx): its OpenAI SDK client and its native Anthropic / Gemini ones ---

BODY_GUARD: Any = None  # set below: a ContextVar holding the current call's {"error": HTTPCallError} slot


def _guard() -> Any:
    global BODY_GUARD
    if BODY_GUARD is None:
        import contextvars

        BODY_GUARD = contextvars.ContextVar("lightemma_body_guard", default=None)
    return BODY_GUARD


@contextlib.contextmanager
def body_guard(max_body: int | None = None) -> Iterator[dict[str, Any]]:
    """The calls made inside (in this task) through a client with :func:`body_limit_hooks` read at most ``max_body``
    bytes of a body (None: the client's own limit), and an error those hooks raise (:class:`ResponseTooLargeError`,
    :class:`ResponseEncodingError`) leaves the block as itself, whatever the client library wrapped it in."""
    slot: dict[str, Any] = {} if max_body is None else {"max_body": int(max_body)}
    token = _guard().set(slot)
    try:
        yield slot
    except Exception:
        if "error" in slot:
            raise slot["error"] from None
        raise
    finally:
        _guard().reset(token)


#: the encodings lightemma asks for and decodes itself, within the limit (httpx decodes without one)
ACCEPTED_ENCODINGS = "gzip, deflate"


def body_limit_hooks(max_body: int = MAX_BODY_BYTES) -> dict[str, list[Any]]:
    """httpx ``event_hooks`` that let a client read at most ``max_body`` bytes of a response body, decoded.

    A ``Content-Length`` over the limit fails at once; a body is otherwise counted chunk by chunk as the
    client reads it and the read ends past the limit. A gzip or deflate body is decoded here, chunk by
    chunk with a bound on each chunk's output, and counted decoded (and on the wire): httpx would
    inflate a 1 MB "gzip bomb" to gigabytes before anyone counted. Requests ask for those two encodings
    only; a body in another one, or one that does not decode (corrupt, cut off), fails the call as
    :class:`ResponseEncodingError`. The call's slot in :data:`BODY_GUARD` (set by the caller) holds the
    error, so the caller raises it whatever error the client library wraps it in. Hooks (not a
    transport) keep each client's own connection pool, TLS and proxy settings.
    """
    import httpx

    class _Stream(httpx.AsyncByteStream):
        def __init__(self, inner: Any, slot: Any, encoding: str | None, limit: int) -> None:
            self.inner, self.slot, self.limit = inner, slot, limit
            self.decoder = _Inflate(encoding, limit) if encoding else None

        async def __aiter__(self) -> Any:
            size = wire = 0
            max_body = self.limit
            try:
                async for chunk in self.inner:
                    wire += len(chunk)
                    if self.decoder is not None:
                        chunk = self.decoder.feed(chunk)
                    size += len(chunk)
                    if size > max_body or wire > max_body:
                        raise _failed(
                            self.slot,
                            ResponseTooLargeError(
                                f"the response body is over {max_body:,} bytes{' decoded' if size > max_body and self.decoder else ''}, "
                                "more than lightemma reads"
                            ),
                        )
                    yield chunk
                if self.decoder is not None:
                    yield self.decoder.flush()
            except _TooLarge:
                raise _failed(
                    self.slot,
                    ResponseTooLargeError(
                        f"the response body is over {self.limit:,} bytes decoded, more than lightemma reads"
                    ),
                ) from None
            except zlib.error as exc:
                raise _failed(
                    self.slot,
                    ResponseEncodingError(
                        f"the response body is not valid {self.decoder.encoding if self.decoder else ''} ({exc})"
                    ),
                ) from None

        async def aclose(self) -> None:
            await self.inner.aclose()

    async def on_request(request: Any) -> None:
        request.headers["Accept-Encoding"] = ACCEPTED_ENCODINGS

    async def on_response(response: Any) -> None:
        slot = _guard().get()
        limit = slot.get("max_body", max_body) if slot is not None else max_body  # a call's own limit (body_guard)
        length = response.headers.get("content-length")
        if length and length.isdigit() and int(length) > limit:
            raise _failed(
                slot,
                ResponseTooLargeError(
                    f"the response body is {int(length):,} bytes, more than the {limit:,} bytes lightemma reads"
                ),
            )
        codings = [c.strip().lower() for c in response.headers.get("content-encoding", "").split(",")]
        codings = [c for c in codings if c and c != "identity"]
        if len(codings) > 1 or (codings and codings[0] not in _INFLATE):
            raise _failed(
                slot,
                ResponseEncodingError(
                    f"the response body is encoded as {', '.join(codings)!r}, which "
                    "lightemma did not ask for and does not decode"
                ),
            )
        if codings:
            del response.headers["content-encoding"]  # decoded below, within the limit: httpx must not decode it again
        response.stream = _Stream(response.stream, slot, codings[0] if codings else None, limit)

    return {"request": [on_request], "response": [on_response]}


_INFLATE = {"gzip": 16 + zlib.MAX_WBITS, "x-gzip": 16 + zlib.MAX_WBITS, "deflate": zlib.MAX_WBITS}
_GZIP_MAGIC = b"\x1f\x8b"


class _TooLarge(Exception):
    """Raised by :class:`_Inflate` when its output passes the limit."""


class _Inflate:
    """A gzip or deflate body decoded chunk by chunk, never more than ``limit`` + 1 bytes of output in all (a chunk
    that would inflate past it stops there: :class:`_TooLarge`). gzip members that follow one another are one body;
    bytes after the end of the stream are counted against the limit and dropped (zlib would keep them all); a
    body that is corrupt or ends early raises ``zlib.error``."""

    def __init__(self, encoding: str, limit: int) -> None:
        self.encoding, self.limit, self.size, self.trailing = encoding, limit, 0, 0
        self.raw_deflate = False
        self.pending = b""  # the start of what may be the next gzip member's header
        self._d = zlib.decompressobj(_INFLATE[encoding])

    def feed(self, chunk: bytes) -> bytes:
        out = bytearray()
        data, self.pending = self.pending + chunk, b""
        while data:
            if self._d.eof:  # after a whole stream: the next gzip member, or trailing bytes
                if self.encoding != "deflate" and data[:2] == _GZIP_MAGIC:
                    self._d = zlib.decompressobj(_INFLATE[self.encoding])
                    continue
                if self.encoding != "deflate" and len(data) < 2 and _GZIP_MAGIC.startswith(data):
                    self.pending = data  # one byte of a member header: the rest comes with the next chunk
                    break
                self.trailing += len(data)
                if self.size + self.trailing > self.limit:
                    raise _TooLarge
                break
            try:
                piece = self._d.decompress(data, self.limit + 1 - self.size)  # >= 1: an output bound, never 0 (none)
            except zlib.error:
                if self.encoding != "deflate" or self.raw_deflate or self.size:
                    raise
                self.raw_deflate = True  # "deflate" without its zlib header, as some servers send it (httpx allows it)
                self._d = zlib.decompressobj(-zlib.MAX_WBITS)
                continue
            self.size += len(piece)
            out += piece
            if self.size > self.limit:
                raise _TooLarge
            data = self._d.unused_data if self._d.eof else self._d.unconsumed_tail
        return bytes(out)

    def flush(self) -> bytes:
        if not self._d.eof or self.pending:
            raise zlib.error("the compressed stream ends early")
        return b""


def _failed(slot: dict[str, Any] | None, error: HTTPCallError) -> HTTPCallError:
    """``error``, kept in the call's slot for the caller to raise (the client library may wrap what we raise)."""
    if slot is not None:
        slot["error"] = error
    return error


def limited_openai_client(api_key: str, base_url: str | None, max_body: int = MAX_BODY_BYTES) -> Any:
    """The OpenAI SDK's async client (litellm's ``client=`` for the OpenAI protocol), reading at most ``max_body``
    bytes of a body (:func:`body_limit_hooks`); no retries of its own."""
    from openai import AsyncOpenAI, DefaultAsyncHttpxClient

    http = DefaultAsyncHttpxClient(event_hooks=body_limit_hooks(max_body))
    return AsyncOpenAI(api_key=api_key, base_url=base_url, max_retries=0, http_client=http)


def limited_litellm_handler(max_body: int = MAX_BODY_BYTES) -> Any:
    """litellm's ``AsyncHTTPHandler`` reading at most ``max_body`` bytes of a body (:func:`body_limit_hooks`): the
    ``client=`` litellm's native Anthropic (``/v1/messages``) and Gemini (``generateContent``) clients post through."""
    from litellm.llms.custom_httpx.http_handler import AsyncHTTPHandler

    return AsyncHTTPHandler(event_hooks=body_limit_hooks(max_body))
