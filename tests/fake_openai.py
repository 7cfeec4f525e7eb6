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

Run as a script (``python tests/fake_openai.py --latency 1.0``) it serves the
default script forever and prints its URL on the first line of stdout.
"""

from __future__ import annotations

import argparse
import itertools
import json
import socket
import struct
import sys
import threading
import time
from collections.abc import Callable, Sequence
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
        return any(p.get("type") in ("image_url", "image") or "inline_data" in p or "inlineData" in p for p in self._parts())

    @property
    def stage(self) -> str:
        """Which stage of the chain this is, recognised from the prompt wording."""
        text = self.text
        if "(v1, c1)" in text:
            return "actions"
        if "past 3 seconds" in text:
            return "intent"
        return "scene"


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

    @classmethod
    def error(cls, status: int, message: str = "scripted error", *, retry_after: float | None = None, delay: float = 0.0) -> Reply:
        headers = {"Retry-After": str(retry_after)} if retry_after is not None else {}
        kind = {429: "rate_limit_exceeded", 401: "invalid_api_key"}.get(status, "server_error")
        return cls(status=status, headers=headers, delay=delay, body={"error": {"message": message, "type": kind, "code": kind}})


def default_reply(req: Received) -> Reply:
    """A well-behaved model: scene, intent and a well-formed action list."""
    return Reply({"scene": SCENE_TEXT, "intent": INTENT_TEXT, "actions": GOOD_ACTIONS}[req.stage])


Script = Callable[[Received], Reply] | Sequence[Reply]


_FINISH = {"anthropic": {"stop": "end_turn", "length": "max_tokens"}, "gemini": {"stop": "STOP", "length": "MAX_TOKENS"}}


def _completion(req: Received, reply: Reply) -> dict[str, Any]:
    """A successful answer in the request's protocol."""
    finish = _FINISH.get(req.protocol, {}).get(reply.finish_reason, reply.finish_reason)
    if req.protocol == "anthropic":
        out = {"id": f"msg_{req.index}", "type": "message", "role": "assistant", "model": req.body.get("model", "fake"),
               "content": [{"type": "text", "text": reply.content}], "stop_reason": finish, "stop_sequence": None,
               "usage": {"input_tokens": reply.prompt_tokens, "output_tokens": reply.completion_tokens}}
    elif req.protocol == "gemini":
        # Gemini counts thoughts apart from the answer's (candidates) tokens; the total holds both
        thoughts = reply.reasoning_tokens or 0
        usage = {"promptTokenCount": reply.prompt_tokens, "candidatesTokenCount": reply.completion_tokens - thoughts,
                 "totalTokenCount": reply.prompt_tokens + reply.completion_tokens}
        if reply.reasoning_tokens is not None:
            usage["thoughtsTokenCount"] = thoughts
        out = {"candidates": [{"content": {"parts": [{"text": reply.content}], "role": "model"}, "finishReason": finish, "index": 0}],
               "usageMetadata": usage}
    else:
        usage = {"prompt_tokens": reply.prompt_tokens, "completion_tokens": reply.completion_tokens,
                 "total_tokens": reply.prompt_tokens + reply.completion_tokens}
        if reply.reasoning_tokens is not None:
            usage["completion_tokens_details"] = {"reasoning_tokens": reply.reasoning_tokens}
        out = {
            "id": f"chatcmpl-{req.index}",
            "object": "chat.completion",
            "created": int(time.time()),
            "model": req.body.get("model", "fake"),
            "choices": [{"index": 0, "message": {"role": "assistant", "content": reply.content}, "finish_reason": finish}],
            "usage": usage,
        }
    if not reply.usage:
        for key in ("usage", "usageMetadata"):
            out.pop(key, None)
    return out


class FakeOpenAIServer:
    """The loopback server; a context manager. ``url`` ends in ``/v1`` (an OpenAI ``api_base``)."""

    def __init__(self, script: Script | None = None, *, latency: float = 0.0, host: str = "127.0.0.1", port: int = 0, record: bool = True) -> None:
        self.latency = latency  # added to every reply's own delay
        self.requests: list[Received] = []
        self.record = record
        self._lock = threading.Lock()
        self._counter = itertools.count()
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
                req = Received(path=self.path, headers={k.lower(): v for k, v in self.headers.items()}, body=body, index=next(server._counter))
                if server.record:
                    with server._lock:
                        server.requests.append(req)
                reply = server._next(req)
                wait = server.latency + reply.delay
                if wait > 0:
                    time.sleep(wait)
                if reply.reset:
                    self.connection.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
                    self.connection.close()  # RST instead of FIN
                    self.close_connection = True
                    return
                payload = reply.body if reply.body is not None else _completion(req, reply)
                data = json.dumps(payload).encode("utf-8")
                try:
                    self.send_response(reply.status)
                    self.send_header("Content-Type", "application/json")
                    self.send_header("Content-Length", str(len(data)))
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
                            self.wfile.write(data[i:i + 1])
                            self.wfile.flush()
                        return
                    self.wfile.write(data)
                except (BrokenPipeError, ConnectionResetError, OSError):
                    self.close_connection = True

        return Handler

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
