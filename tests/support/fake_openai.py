"""A real HTTP server on 127.0.0.1 that speaks the OpenAI chat-completions protocol.

It also answers the native protocols of the providers the registry routes natively through
litellm: Anthropic messages (``POST …/v1/messages``) and Gemini ``…:generateContent``; the
protocol is chosen by the request path, and the same script drives all three.

Scripted per request, for tests and benchmarks of the API backend — no internet:

    def script(req: Received) -> Reply:
        if req.stage == "actions":
            return Reply("[(5.0, 0.0), (5.0, 0.0), (5.0, 0.0), (5.0, 0.0), (5.0, 0.0), (5.0, 0.0)]")
        return Reply("a quiet street")

    with FakeOpenAIServer(script) as server:
        ...  # point litellm at model "openai/test-model", api_base=server.url

``script`` may also be a list of replies (served in order, then :func:`default_reply`).
A reply can be an HTTP error with headers (``Reply.error(429, retry_after=1)``),
slow (``delay``), cut off mid-body (``truncate=True``), a connection reset (``reset=True``), or a body
trickled one byte every ``trickle`` seconds (a server that never stalls long enough for a read timeout).
A completion says why it stopped (``finish_reason``: "stop" or "length", in each protocol's spelling),
may report reasoning tokens (``reasoning_tokens``) or no usage at all (``usage=False``). Every request is
recorded in ``server.requests`` (a :class:`Received`), thread-safely.

A request asking for a JSON schema (OpenAI ``response_format``, Anthropic ``output_format`` or litellm's
``json_tool_call`` tool, Gemini's response schema) is answered with the actions as JSON by the default
script (:attr:`Received.schema`); a forced tool call is answered as a ``tool_use`` block, as Anthropic does.

``FakeOpenAIServer(count_tokens=True)`` counts each request's tokens instead of the script's fixed
1000 / 50 (:class:`TokenCounter`: text ≈ 4 UTF-8 bytes per token, 4 per message, images by each
provider's published rule from the image's pixel size), and ``prefix_cache=True`` also emulates the
providers' prompt caches (:class:`PrefixCache`) and reports cached tokens in each protocol's spelling.

Run as a script (``python tests/support/fake_openai.py --latency 1.0``) it serves the
default script forever and prints its URL on the first line of stdout.
"""

from __future__ import annotations

import argparse
import base64
import dataclasses
import hashlib
import io
import itertools
import json
import math
import socket
import struct
import sys
import threading
import time
import zlib
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

GOOD_ACTIONS = "[(5.0, 0.0), (5.2, 0.001), (5.4, 0.002), (5.6, 0.0), (5.8, -0.001), (6.0, 0.0)]"
SCENE_TEXT = "A two-lane urban road; a white van is parked on the right; the traffic light ahead is green."
INTENT_TEXT = "The ego vehicle has been cruising at about 5 m/s in its lane; keep the lane and accelerate gently."


@dataclass
class Received:
    """One request as the server saw it."""

    path: str
    headers: dict[str, str]  # names lower-cased
    body: dict[str, Any]
    index: int  # arrival order, from 0
    counted: bool = False  # the server counted its tokens (count_tokens=True)
    prompt_tokens: int | None = None  # as counted (count_tokens=True)
    cached_tokens: int = 0  # as the emulated prefix cache served them (prefix_cache=True)
    cache_write_tokens: int = 0

    @property
    def protocol(self) -> str:
        """``openai``, ``anthropic`` or ``gemini``, from the path."""
        if ":generateContent" in self.path:
            return "gemini"
        if self.path.split("?")[0].endswith("/messages"):
            return "anthropic"
        return "openai"

    def _parts(self) -> list[dict[str, Any]]:
        """The content parts of the last user turn, whatever the protocol."""
        if self.protocol == "gemini":
            return list(self.body.get("contents", [{}])[-1].get("parts", []))
        content = self.body.get("messages", [{}])[-1].get("content", "")
        return [{"type": "text", "text": content}] if isinstance(content, str) else list(content)

    @property
    def text(self) -> str:
        """The concatenated text parts of the last user message."""
        return "\n".join(p["text"] for p in self._parts() if isinstance(p.get("text"), str))

    @property
    def has_image(self) -> bool:
        return any(
            p.get("type") in ("image_url", "image") or "inline_data" in p or "inlineData" in p for p in self._parts()
        )

    @property
    def stage(self) -> str:
        """Which stage of the chain this is, recognised from the wording of the last user turn."""
        text = self.text
        if "v1, c1" in text:  # "[(v1, c1), …]" or the JSON form "[[v1, c1], …]"
            return "actions"
        if "past 3 seconds" in text or "recent intent" in text:  # the latter: the no-history prompts' intent stage
            return "intent"
        return "scene"

    def messages(self) -> list[tuple[str, list[dict[str, Any]]]]:
        """Every turn as (role, parts), whatever the protocol: roles ``system``/``user``/``assistant``; parts
        ``{"kind": "text", "text": …}`` or ``{"kind": "image", "data": <base64>}``, with ``"cache": True`` on a
        part that carries an Anthropic cache breakpoint."""
        out: list[tuple[str, list[dict[str, Any]]]] = []
        if self.protocol == "gemini":
            system = self.body.get("systemInstruction") or self.body.get("system_instruction")
            if system:
                out.append(("system", [_gemini_part(p) for p in system.get("parts", [])]))
            for turn in self.body.get("contents", []):
                role = "assistant" if turn.get("role") == "model" else "user"
                out.append((role, [_gemini_part(p) for p in turn.get("parts", [])]))
            return out
        system = self.body.get("system")
        if system:
            out.append(
                (
                    "system",
                    [_part(p) for p in ([{"type": "text", "text": system}] if isinstance(system, str) else system)],
                )
            )
        for turn in self.body.get("messages", []):
            content = turn.get("content", "")
            parts = [{"type": "text", "text": content}] if isinstance(content, str) else content
            out.append((turn.get("role", "user"), [_part(p) for p in parts]))
        return out

    @property
    def schema(self) -> dict[str, Any] | None:
        """The JSON schema the request asks the answer to follow (None when it asks for none)."""
        body = self.body
        if self.protocol == "openai":
            fmt = body.get("response_format") or {}
            return (fmt.get("json_schema") or {}).get("schema") if fmt.get("type") == "json_schema" else None
        if self.protocol == "anthropic":
            if isinstance(body.get("output_format"), dict):
                return body["output_format"].get("schema")
            tool = next((t for t in body.get("tools", []) if t.get("name") == JSON_TOOL), None)
            return tool.get("input_schema") if tool else None
        config = body.get("generationConfig") or {}
        for key in ("responseJsonSchema", "responseSchema", "response_json_schema", "response_schema"):
            if key in config:
                return config[key]
        return None

    @property
    def forced_tool(self) -> bool:
        """An Anthropic request that forces litellm's JSON tool: the answer must come back as its ``tool_use``."""
        choice = self.body.get("tool_choice") or {}
        return self.protocol == "anthropic" and choice.get("name") == JSON_TOOL


@dataclass
class Reply:
    """What the server answers to one request."""

    content: str | None = None
    status: int = 200
    prompt_tokens: int = 1000
    completion_tokens: int = 50
    delay: float = 0.0  # seconds to wait before answering
    headers: dict[str, str] = field(default_factory=dict)
    truncate: bool = False  # send half the body, then drop the connection
    reset: bool = False  # drop the connection without answering (a connection reset)
    body: Any = None  # a raw JSON body to send instead of a completion
    trickle: float = 0.0  # seconds between the body's bytes (0: all at once)
    finish_reason: str = "stop"  # "stop" or "length" (sent as end_turn/max_tokens, STOP/MAX_TOKENS natively)
    reasoning_tokens: int | None = None  # of completion_tokens, those spent reasoning (reported when set)
    usage: bool = True  # False: the completion has no usage block
    cached_tokens: int = 0  # of prompt_tokens, read from the prompt cache (set by the server's PrefixCache)
    cache_write_tokens: int = 0  # of prompt_tokens, written to the prompt cache (Anthropic)
    bulk: int = 0  # > 0: the answer text is this many "x" bytes, streamed in 64 KiB pieces (``content`` unused)
    chunked: bool = False  # with bulk: no Content-Length, chunked transfer encoding (the size is never declared)
    # the body sent compressed: "gzip", "deflate", "raw-deflate" (sent as deflate), "gzip-members" (two gzip members),
    # "gzip-cut" (its end missing), "gzip-corrupt" (a byte of its data changed), or a name only declared (br, ...)
    encoding: str | None = None
    trailing: int = 0  # bytes of zeros sent after the body (after the end of a compressed stream)
    choices: list[str] | None = None  # OpenAI protocol: these answers as the completion's choices (a request with n)

    @classmethod
    def error(
        cls, status: int, message: str = "scripted error", *, retry_after: float | None = None, delay: float = 0.0
    ) -> Reply:
        headers = {"Retry-After": str(retry_after)} if retry_after is not None else {}
        kind = {429: "rate_limit_exceeded", 401: "invalid_api_key"}.get(status, "server_error")
        return cls(
            status=status,
            headers=headers,
            delay=delay,
            body={"error": {"message": message, "type": kind, "code": kind}},
        )


GOOD_ACTIONS_JSON = json.dumps(
    {"actions": [[5.0, 0.0], [5.2, 0.001], [5.4, 0.002], [5.6, 0.0], [5.8, -0.001], [6.0, 0.0]]}
)
JSON_TOOL = "json_tool_call"  # the tool litellm forces for Anthropic models without native structured outputs


def default_reply(req: Received) -> Reply:
    """A well-behaved model: scene, intent and a well-formed action list (JSON when the request asks for a schema)."""
    if req.stage == "actions" and req.schema is not None:
        return Reply(GOOD_ACTIONS_JSON)
    return Reply({"scene": SCENE_TEXT, "intent": INTENT_TEXT, "actions": GOOD_ACTIONS}[req.stage])


def _part(part: dict[str, Any]) -> dict[str, Any]:
    """An OpenAI or Anthropic content part, normalised (see :meth:`Received.messages`)."""
    out: dict[str, Any]
    if part.get("type") == "image_url":
        url = part["image_url"]["url"] if isinstance(part.get("image_url"), dict) else part.get("image_url", "")
        out = {"kind": "image", "data": url.split(",", 1)[-1]}
    elif part.get("type") == "image":
        out = {"kind": "image", "data": (part.get("source") or {}).get("data", "")}
    else:
        out = {"kind": "text", "text": str(part.get("text", ""))}
    if part.get("cache_control"):
        out["cache"] = True
    return out


def _gemini_part(part: dict[str, Any]) -> dict[str, Any]:
    inline = part.get("inline_data") or part.get("inlineData")
    if inline:
        return {"kind": "image", "data": inline.get("data", "")}
    return {"kind": "text", "text": str(part.get("text", ""))}


class TokenCounter:
    """Counts a request's tokens the way a benchmark needs: plausibly, cheaply, the same for every variant.

    Text: one token per 4 UTF-8 bytes (rounded up), plus 4 tokens of role markers per message. Images, by each
    provider's published rule for the decoded pixel size: OpenAI (high detail) fits the image in 2048 × 2048,
    scales its short side to 768 and counts 85 + 170 per 512-pixel tile; Anthropic scales the long side to at
    most 1568 and counts width × height / 750; Gemini counts 258 per 768-pixel tile (258 for an image within
    384 × 384). A 1600 × 900 camera image: 1105 (OpenAI), 1844 (Anthropic), 1548 (Gemini).
    """

    MESSAGE_TOKENS = 4

    def __init__(self) -> None:
        self._sizes: dict[str, tuple[int, int]] = {}
        self._lock = threading.Lock()

    @staticmethod
    def text(text: str) -> int:
        return math.ceil(len(text.encode("utf-8")) / 4)

    def image(self, data: str, protocol: str) -> int:
        key = hashlib.sha256(data.encode("ascii", "replace")).hexdigest()
        with self._lock:
            size = self._sizes.get(key)
        if size is None:
            from PIL import Image

            with Image.open(io.BytesIO(base64.b64decode(data))) as img:
                size = img.size
            with self._lock:
                self._sizes[key] = size
        return image_tokens(*size, protocol)


def image_tokens(width: int, height: int, protocol: str) -> int:
    """Input tokens of one ``width`` × ``height`` image under ``protocol``'s rule (see :class:`TokenCounter`)."""
    if protocol == "anthropic":
        scale = min(1.0, 1568 / max(width, height))
        return math.ceil(round(width * scale) * round(height * scale) / 750)
    if protocol == "gemini":
        if width <= 384 and height <= 384:
            return 258
        return 258 * math.ceil(width / 768) * math.ceil(height / 768)
    scale = min(1.0, 2048 / max(width, height))
    w, h = width * scale, height * scale
    scale = min(1.0, 768 / min(w, h))
    w, h = w * scale, h * scale
    return 85 + 170 * math.ceil(w / 512) * math.ceil(h / 512)


@dataclass
class _Block:
    tokens: int
    key: str  # digest of the prompt up to and including this block
    cache: bool  # an Anthropic cache breakpoint ends here


class PrefixCache:
    """The providers' prompt caches, emulated (thread-safe), per protocol and model.

    A request is a sequence of blocks (each message's role markers, then each of its parts); a cached prefix is
    identified by the digest of everything up to a block boundary.

    * OpenAI (automatic): the longest prefix of at least 1024 tokens that an earlier request also had is served
      from the cache, counted in steps of 128 tokens; every prefix of every request is remembered.
    * Gemini (implicit, 2.5 and later): the same, minimum 1024 tokens, counted exactly.
    * Anthropic (explicit): only prefixes ending at a ``cache_control`` breakpoint are written; a request reads
      the longest written prefix at or before its last breakpoint and writes the rest up to that breakpoint
      (``cache_creation_input_tokens``), when that prefix is at least 1024 tokens long.

    Entries never expire (a run's three requests of a frame come seconds apart, well within every provider's
    five-minute lifetime).
    """

    MINIMUM = 1024

    def __init__(self) -> None:
        self._seen: set[tuple[str, str, str]] = set()
        self._lock = threading.Lock()

    def lookup(self, protocol: str, model: str, blocks: list[_Block]) -> tuple[int, int]:
        """(cached, written) tokens of a request made of ``blocks``, remembering what it leaves in the cache."""
        ends = list(itertools.accumulate(b.tokens for b in blocks))
        with self._lock:
            if protocol == "anthropic":
                marks = [i for i, b in enumerate(blocks) if b.cache]
                if not marks or ends[marks[-1]] < self.MINIMUM:
                    return 0, 0
                last = marks[-1]
                hit = max((i for i in range(last + 1) if (protocol, model, blocks[i].key) in self._seen), default=None)
                read = ends[hit] if hit is not None else 0
                for i in marks:
                    self._seen.add((protocol, model, blocks[i].key))
                return read, ends[last] - read
            hit = max((i for i, b in enumerate(blocks) if (protocol, model, b.key) in self._seen), default=None)
            for b in blocks:
                self._seen.add((protocol, model, b.key))
        read = ends[hit] if hit is not None else 0
        if read < self.MINIMUM:
            return 0, 0
        return (read // 128 * 128 if protocol == "openai" else read), 0


def _blocks(req: Received, counter: TokenCounter) -> list[_Block]:
    """The request as prompt-cache blocks (see :class:`PrefixCache`), in order."""
    digest = hashlib.sha256(f"{req.protocol}|{req.body.get('model', '')}".encode())
    blocks = []
    for role, parts in req.messages():
        digest.update(f"<{role}>".encode())
        blocks.append(_Block(TokenCounter.MESSAGE_TOKENS, digest.hexdigest(), False))
        for part in parts:
            if part["kind"] == "image":
                digest.update(b"<image>" + hashlib.sha256(part["data"].encode("ascii", "replace")).digest())
                tokens = counter.image(part["data"], req.protocol)
            else:
                digest.update(b"<text>" + part["text"].encode("utf-8"))
                tokens = TokenCounter.text(part["text"])
            blocks.append(_Block(tokens, digest.hexdigest(), bool(part.get("cache"))))
    return blocks


Script = Callable[[Received], Reply] | Sequence[Reply]


_FINISH = {
    "anthropic": {"stop": "end_turn", "length": "max_tokens"},
    "gemini": {"stop": "STOP", "length": "MAX_TOKENS"},
}


def _completion(req: Received, reply: Reply) -> dict[str, Any]:
    """A successful answer in the request's protocol."""
    finish = _FINISH.get(req.protocol, {}).get(reply.finish_reason, reply.finish_reason)
    if req.protocol == "anthropic":
        content: list[dict[str, Any]] = [{"type": "text", "text": reply.content}]
        if req.forced_tool and reply.content is not None:
            try:
                content = [
                    {
                        "type": "tool_use",
                        "id": f"toolu_{req.index}",
                        "name": JSON_TOOL,
                        "input": json.loads(reply.content),
                    }
                ]
                finish = "tool_use" if reply.finish_reason == "stop" else finish
            except json.JSONDecodeError:
                pass  # not JSON: answered as text, as a model ignoring the tool would
        # Anthropic's input_tokens leave out the tokens read from and written to the cache
        usage = {
            "input_tokens": reply.prompt_tokens - reply.cached_tokens - reply.cache_write_tokens,
            "output_tokens": reply.completion_tokens,
            "cache_read_input_tokens": reply.cached_tokens,
            "cache_creation_input_tokens": reply.cache_write_tokens,
        }
        out = {
            "id": f"msg_{req.index}",
            "type": "message",
            "role": "assistant",
            "model": req.body.get("model", "fake"),
            "content": content,
            "stop_reason": finish,
            "stop_sequence": None,
            "usage": usage,
        }
    elif req.protocol == "gemini":
        # Gemini counts thoughts apart from the answer's (candidates) tokens; the total holds both
        thoughts = reply.reasoning_tokens or 0
        usage = {
            "promptTokenCount": reply.prompt_tokens,
            "candidatesTokenCount": reply.completion_tokens - thoughts,
            "totalTokenCount": reply.prompt_tokens + reply.completion_tokens,
        }
        if reply.reasoning_tokens is not None:
            usage["thoughtsTokenCount"] = thoughts
        if reply.cached_tokens:  # Gemini leaves zero counts out
            usage["cachedContentTokenCount"] = reply.cached_tokens
        out = {
            "candidates": [
                {"content": {"parts": [{"text": reply.content}], "role": "model"}, "finishReason": finish, "index": 0}
            ],
            "usageMetadata": usage,
        }
    else:
        usage = {
            "prompt_tokens": reply.prompt_tokens,
            "completion_tokens": reply.completion_tokens,
            "total_tokens": reply.prompt_tokens + reply.completion_tokens,
        }
        if reply.reasoning_tokens is not None:
            usage["completion_tokens_details"] = {"reasoning_tokens": reply.reasoning_tokens}
        if reply.cached_tokens or req.counted:
            usage["prompt_tokens_details"] = {"cached_tokens": reply.cached_tokens}
        out = {
            "id": f"chatcmpl-{req.index}",
            "object": "chat.completion",
            "created": int(time.time()),
            "model": req.body.get("model", "fake"),
            "choices": [
                {"index": i, "message": {"role": "assistant", "content": text}, "finish_reason": finish}
                for i, text in enumerate(reply.choices if reply.choices is not None else [reply.content])
            ],
            "usage": usage,
        }
    if not reply.usage:
        for key in ("usage", "usageMetadata"):
            out.pop(key, None)
    return out


def _compressed(chunks: Iterable[bytes], encoding: str) -> bytes:
    """``chunks`` as one body in ``encoding`` (see :attr:`Reply.encoding`); a name the server only declares (br, …)
    leaves the bytes as they are."""
    wbits = {"gzip": 16 + zlib.MAX_WBITS, "deflate": zlib.MAX_WBITS, "raw-deflate": -zlib.MAX_WBITS}.get(
        _wire_name(encoding) if encoding.startswith("gzip") else encoding
    )
    if wbits is None:
        return b"".join(chunks)

    def pack(parts: Iterable[bytes]) -> bytes:
        packer = zlib.compressobj(6, zlib.DEFLATED, wbits)
        return b"".join(packer.compress(c) for c in parts) + packer.flush()

    if encoding == "gzip-members":
        body = b"".join(chunks)
        return pack([body[: len(body) // 2]]) + pack([body[len(body) // 2 :]])
    data = pack(chunks)
    if encoding == "gzip-cut":
        return data[:-12]
    if encoding == "gzip-corrupt":
        middle = len(data) // 2
        return data[:middle] + bytes([data[middle] ^ 0xFF]) + data[middle + 1 :]
    return data


def _wire_name(encoding: str) -> str:
    """The Content-Encoding a test encoding is sent as."""
    return "deflate" if encoding == "raw-deflate" else ("gzip" if encoding.startswith("gzip") else encoding)


class FakeOpenAIServer:
    """The loopback server; a context manager. ``url`` ends in ``/v1`` (an OpenAI ``api_base``)."""

    def __init__(
        self,
        script: Script | None = None,
        *,
        latency: float = 0.0,
        host: str = "127.0.0.1",
        port: int = 0,
        record: bool = True,
        count_tokens: bool = False,
        prefix_cache: bool = False,
    ) -> None:
        self.latency = latency  # added to every reply's own delay
        self.requests: list[Received] = []
        self.bulk_sent: list[int] = []  # per reply with ``bulk``: body bytes written before the client stopped reading
        self.record = record
        self.counter = TokenCounter() if (count_tokens or prefix_cache) else None
        self.cache = PrefixCache() if prefix_cache else None
        self._lock = threading.Lock()
        self._counter = itertools.count()
        self.in_flight = 0  # requests being served now
        self.max_in_flight = 0  # the most served at once (replies waiting out their delay included)
        if script is None:
            self._next: Callable[[Received], Reply] = default_reply
        elif callable(script):
            self._next = script
        else:
            queue = list(script)

            def from_list(req: Received) -> Reply:
                with self._lock:
                    return queue.pop(0) if queue else default_reply(req)

            self._next = from_list
        self._httpd = ThreadingHTTPServer((host, port), self._handler_class())
        self._httpd.daemon_threads = True
        self._thread: threading.Thread | None = None

    @property
    def root_url(self) -> str:
        """``http://127.0.0.1:PORT`` (an ``api_base`` for the native protocols)."""
        host, port = self._httpd.server_address[:2]
        return f"http://{host}:{port}"

    @property
    def url(self) -> str:
        """``http://127.0.0.1:PORT/v1``: an OpenAI ``api_base``."""
        return f"{self.root_url}/v1"

    def _handler_class(self) -> type[BaseHTTPRequestHandler]:
        server = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, *args: Any) -> None:  # quiet
                pass

            def do_POST(self) -> None:  # noqa: N802 - http.server naming
                length = int(self.headers.get("Content-Length") or 0)
                raw = self.rfile.read(length)
                try:
                    body = json.loads(raw or b"{}")
                except json.JSONDecodeError:
                    body = {}
                req = Received(
                    path=self.path,
                    headers={k.lower(): v for k, v in self.headers.items()},
                    body=body,
                    index=next(server._counter),
                )
                if server.record:
                    with server._lock:
                        server.requests.append(req)
                reply = server._account(req, server._next(req))
                wait = server.latency + reply.delay
                if wait > 0:
                    with server._lock:
                        server.in_flight += 1
                        server.max_in_flight = max(server.max_in_flight, server.in_flight)
                    try:
                        time.sleep(wait)
                    finally:
                        with server._lock:
                            server.in_flight -= 1
                if reply.reset:
                    self.connection.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
                    self.connection.close()  # RST instead of FIN
                    self.close_connection = True
                    return
                if reply.bulk:
                    self._send_bulk(reply, req)
                    return
                payload = reply.body if reply.body is not None else _completion(req, reply)
                data = json.dumps(payload).encode("utf-8")
                if reply.encoding:
                    data = _compressed([data], reply.encoding)
                data += b"\0" * reply.trailing
                try:
                    self.send_response(reply.status)
                    self.send_header("Content-Type", "application/json")
                    self.send_header("Content-Length", str(len(data)))
                    if reply.encoding:
                        self.send_header("Content-Encoding", _wire_name(reply.encoding))
                    for key, value in reply.headers.items():
                        self.send_header(key, value)
                    self.end_headers()
                    if reply.truncate:
                        self.wfile.write(data[: len(data) // 2])
                        self.wfile.flush()
                        self.connection.shutdown(socket.SHUT_RDWR)
                        self.close_connection = True
                        return
                    if reply.trickle > 0:
                        self.wfile.flush()
                        for i in range(len(data)):
                            time.sleep(reply.trickle)
                            self.wfile.write(data[i : i + 1])
                            self.wfile.flush()
                        return
                    self.wfile.write(data)
                except (BrokenPipeError, ConnectionResetError, OSError):
                    self.close_connection = True

            def _send_bulk(self, reply: Reply, req: Received) -> None:
                """A completion whose text is ``reply.bulk`` bytes, written piece by piece until the client stops
                reading (compressed whole first when ``reply.encoding``: small on the wire, ``bulk`` bytes decoded);
                the bytes written are appended to ``server.bulk_sent``."""
                marker = "@@BULK@@"
                head, tail = (
                    part.encode()
                    for part in json.dumps(_completion(req, dataclasses.replace(reply, content=marker))).split(marker)
                )
                piece = b"x" * (1 << 16)
                count, rest = divmod(reply.bulk, len(piece))

                def body() -> Iterator[bytes]:
                    yield head
                    for _ in range(count):
                        yield piece
                    if rest:
                        yield piece[:rest]
                    yield tail

                pieces: Iterable[bytes] = [_compressed(body(), reply.encoding)] if reply.encoding else body()
                length = len(pieces[0]) if isinstance(pieces, list) else len(head) + reply.bulk + len(tail)
                sent = 0
                try:
                    self.send_response(reply.status)
                    self.send_header("Content-Type", "application/json")
                    if reply.encoding:
                        self.send_header("Content-Encoding", _wire_name(reply.encoding))
                    if reply.chunked:
                        self.send_header("Transfer-Encoding", "chunked")
                    else:
                        self.send_header("Content-Length", str(length))
                    self.end_headers()
                    for data in pieces:
                        self.wfile.write(b"%x\r\n%b\r\n" % (len(data), data) if reply.chunked else data)
                        sent += len(data)
                    if reply.chunked:
                        self.wfile.write(b"0\r\n\r\n")
                except (BrokenPipeError, ConnectionResetError, OSError):
                    pass
                self.close_connection = True
                with server._lock:
                    server.bulk_sent.append(sent)

        return Handler

    def _account(self, req: Received, reply: Reply) -> Reply:
        """The reply with the request's counted tokens and emulated cache hits (when the server counts them)."""
        if self.counter is None or reply.status != 200 or reply.body is not None:
            return reply
        blocks = _blocks(req, self.counter)
        cached, written = (
            self.cache.lookup(req.protocol, str(req.body.get("model", "")), blocks) if self.cache else (0, 0)
        )
        req.counted, req.prompt_tokens = True, sum(b.tokens for b in blocks)
        req.cached_tokens, req.cache_write_tokens = cached, written
        completion = TokenCounter.text(reply.content or "") + (reply.reasoning_tokens or 0)
        return dataclasses.replace(
            reply,
            prompt_tokens=req.prompt_tokens,
            completion_tokens=completion,
            cached_tokens=cached,
            cache_write_tokens=written,
        )

    def start(self) -> FakeOpenAIServer:
        self._thread = threading.Thread(target=self._httpd.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._httpd.shutdown()
        self._httpd.server_close()

    def stages(self) -> list[str]:
        """The stage of every request received so far, in arrival order."""
        with self._lock:
            return [r.stage for r in self.requests]

    def __enter__(self) -> FakeOpenAIServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def main(argv: Sequence[str] | None = None) -> int:
    """Serve the default script (plus ``--latency`` seconds per call) until killed."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--latency", type=float, default=0.0)
    parser.add_argument("--port", type=int, default=0)
    args = parser.parse_args(argv)
    server = FakeOpenAIServer(latency=args.latency, port=args.port, record=False)
    print(server.url, flush=True)
    try:
        server._httpd.serve_forever(poll_interval=0.05)
    except KeyboardInterrupt:
        pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
