"""A loopback emulation of the providers' batch endpoints, on 127.0.0.1 — no internet.

One server speaks all three:

* OpenAI Batch API: ``POST /v1/files`` (multipart, purpose ``batch``), ``POST /v1/batches``,
  ``GET /v1/batches/{id}``, ``GET /v1/batches`` (list), ``GET /v1/files/{id}/content``;
  status ``validating`` → ``in_progress`` → ``completed`` (or ``expired`` / ``failed``), results in an
  output file and failures in an error file;
* Anthropic Message Batches: ``POST /v1/messages/batches``, ``GET /v1/messages/batches/{id}``,
  ``GET /v1/messages/batches/{id}/results`` (JSONL; ``succeeded`` / ``errored`` / ``expired``);
* Gemini batch mode: ``POST /v1beta/models/{model}:batchGenerateContent`` (inlined requests),
  ``GET /v1beta/batches/{id}``, ``GET /v1beta/batches`` (list); ``BATCH_STATE_PENDING`` →
  ``RUNNING`` → ``SUCCEEDED`` (or ``EXPIRED`` / ``FAILED``), ``inlinedResponses`` matched by metadata key.

Each status request moves a batch one step on (``steps`` polls from created to ended). Answers come
from :func:`fake_openai.default_reply` (or ``script(Received) -> Reply``) in each protocol's shape, in a
shuffled order (``shuffle``, seeded). ``fail`` (custom id → message) answers those requests with an error;
``expire`` (a set of custom ids) leaves them unprocessed, as an expired batch does; ``batch_state`` forces a
whole batch's end state (``"failed"`` with a validation error, ``"expired"``); ``hold_from`` keeps batches from
that number on running until it is set to None. Every created batch is in
``server.batches``; ``server.created`` counts them. ``require_key`` answers 401 to any request whose key
header (``Authorization``, ``x-api-key``, ``x-goog-api-key``) does not hold that key (its message:
``refusal``); ``server.keys`` records the key headers seen.
"""

from __future__ import annotations

import json
import random
import re
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

from fake_openai import Received, Reply, _completion, default_reply


@dataclass
class FakeBatch:
    id: str
    protocol: str  # openai | anthropic | gemini
    requests: list[tuple[str, dict[str, Any]]]  # (custom id, body in the provider's request shape)
    metadata: dict[str, Any] = field(default_factory=dict)
    polls: int = 0
    end_state: str = "completed"
    number: int = 0  # creation order, from 1
    results: list[dict[str, Any]] | None = None  # computed once, when it ends


class FakeBatchServer:
    """The loopback batch server; a context manager. ``url`` is an OpenAI ``api_base`` (``…/v1``)."""

    def __init__(self, script: Callable[[Received], Reply] | None = None, *, steps: int = 2, shuffle: bool = True,
                 seed: int = 0, fail: dict[str, str] | None = None, expire: set[str] | None = None,
                 batch_state: str | None = None, require_key: str | None = None, hold_from: int | None = None,
                 refusal: str = "invalid x-api-key", bloat: int = 0, duplicate: bool = False) -> None:
        self.bloat = bloat  # bytes of padding in every answer (a bloated reply)
        self.duplicate = duplicate  # the results hold the first answered request twice
        self.script = script or default_reply
        self.require_key = require_key  # answer 401 to a request whose key header does not hold it
        self.refusal = refusal  # the message of that 401 (providers echo what they were sent: keys, URLs)
        self.hold_from = hold_from  # batches numbered from this on (1 = the first) stay running until it is set to None
        self.steps = steps
        self.shuffle = shuffle
        self.rng = random.Random(seed)
        self.fail = dict(fail or {})
        self.expire = set(expire or ())
        self.batch_state = batch_state
        self.batches: dict[str, FakeBatch] = {}
        self.files: dict[str, bytes] = {}
        self.created = 0
        self.polls = 0
        self.keys: list[str] = []
        self.lock = threading.Lock()
        self._server = ThreadingHTTPServer(("127.0.0.1", 0), self._handler())
        self._thread = threading.Thread(target=self._server.serve_forever, daemon=True)

    @property
    def root(self) -> str:
        return f"http://127.0.0.1:{self._server.server_address[1]}"

    @property
    def url(self) -> str:
        return self.root + "/v1"

    def __enter__(self) -> FakeBatchServer:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._server.shutdown()
        self._server.server_close()

    # --- the model -------------------------------------------------------------------------------------------
    def _answer(self, protocol: str, custom_id: str, body: dict[str, Any], index: int) -> dict[str, Any]:
        path = {"openai": "/v1/chat/completions", "anthropic": "/v1/messages",
                "gemini": "/v1beta/models/m:generateContent"}[protocol]
        received = Received(path=path, headers={}, body=body, index=index)
        answer = _completion(received, self.script(received))
        if self.bloat:
            answer["padding"] = "x" * self.bloat
        return answer

    def _create(self, protocol: str, requests: list[tuple[str, dict[str, Any]]], metadata: dict[str, Any]) -> FakeBatch:
        with self.lock:
            self.created += 1
            prefix = {"openai": "batch_", "anthropic": "msgbatch_", "gemini": "batches/"}[protocol]
            batch = FakeBatch(id=f"{prefix}{self.created:04d}", protocol=protocol, requests=requests, metadata=metadata,
                              end_state=self.batch_state or "completed", number=self.created)
            self.batches[batch.id] = batch
            return batch

    def _results(self, batch: FakeBatch) -> list[dict[str, Any]]:
        """(custom id, kind, payload) per request once the batch has ended: kind ok / error / expired."""
        if batch.results is None:
            out = []
            for index, (cid, body) in enumerate(batch.requests):
                if cid in self.expire or (batch.end_state == "expired" and index % 2 == 1):
                    out.append({"custom_id": cid, "kind": "expired"})
                elif cid in self.fail:
                    out.append({"custom_id": cid, "kind": "error", "message": self.fail[cid]})
                else:
                    out.append({"custom_id": cid, "kind": "ok", "body": self._answer(batch.protocol, cid, body, index)})
            if self.shuffle:
                self.rng.shuffle(out)
            first = next((r for r in out if r["kind"] == "ok"), None)
            if self.duplicate and first is not None:
                out.append(json.loads(json.dumps(first)))  # the same request again (lightemma refuses even a copy)
            batch.results = out
        return batch.results

    def _step(self, batch: FakeBatch) -> bool:
        """One poll: True once the batch has ended."""
        with self.lock:
            self.polls += 1
            held = self.hold_from is not None and batch.number >= self.hold_from
            if not held or batch.polls + 1 < self.steps:
                batch.polls += 1
            return batch.polls >= self.steps

    # --- HTTP ------------------------------------------------------------------------------------------------
    def _handler(self) -> type[BaseHTTPRequestHandler]:
        server = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, *args: Any) -> None:
                pass

            def _send(self, status: int, payload: Any, content_type: str = "application/json") -> None:
                data = payload if isinstance(payload, bytes) else json.dumps(payload).encode()
                self.send_response(status)
                self.send_header("Content-Type", content_type)
                self.send_header("Content-Length", str(len(data)))
                self.end_headers()
                self.wfile.write(data)

            def _body(self) -> bytes:
                return self.rfile.read(int(self.headers.get("Content-Length") or 0))

            def _refused(self) -> bool:
                key = " ".join(self.headers.get(h, "") for h in ("Authorization", "x-api-key", "x-goog-api-key")).strip()
                with server.lock:
                    server.keys.append(key)
                if server.require_key is not None and server.require_key not in key:
                    self._send(401, {"error": {"type": "authentication_error", "message": server.refusal}})
                    return True
                return False

            def do_POST(self) -> None:  # noqa: N802
                path = self.path.split("?")[0]
                raw = self._body()
                if self._refused():
                    return
                if path == "/v1/files":
                    content = _multipart_file(raw, self.headers.get("Content-Type", ""))
                    with server.lock:
                        fid = f"file-{len(server.files) + 1:04d}"
                        server.files[fid] = content
                    return self._send(200, {"id": fid, "object": "file", "bytes": len(content), "created_at": int(time.time()),
                                            "filename": "batch.jsonl", "purpose": "batch", "status": "processed"})
                body = json.loads(raw or b"{}")
                if path == "/v1/batches":
                    lines = [json.loads(line) for line in server.files[body["input_file_id"]].decode().splitlines() if line.strip()]
                    batch = server._create("openai", [(ln["custom_id"], ln["body"]) for ln in lines], body.get("metadata") or {})
                    return self._send(200, _openai_batch(server, batch, body["input_file_id"]))
                if path == "/v1/messages/batches":
                    batch = server._create("anthropic", [(r["custom_id"], r["params"]) for r in body["requests"]], {})
                    return self._send(200, _anthropic_batch(server, batch))
                match = re.fullmatch(r"/v1beta/models/([^/:]+):batchGenerateContent", path)
                if match:
                    spec = body["batch"]
                    reqs = spec["inputConfig"]["requests"]["requests"]
                    batch = server._create("gemini", [(r["metadata"]["key"], r["request"]) for r in reqs],
                                           {"displayName": spec.get("displayName"), "model": match.group(1)})
                    return self._send(200, _gemini_operation(server, batch))
                self._send(404, {"error": {"message": f"no route {path}"}})

            def do_GET(self) -> None:  # noqa: N802
                path = self.path.split("?")[0]
                if self._refused():
                    return
                if path == "/v1/batches":
                    return self._send(200, {"object": "list", "data": [_openai_batch(server, b, None, peek=True)
                                                                      for b in server.batches.values() if b.protocol == "openai"],
                                            "has_more": False})
                match = re.fullmatch(r"/v1/batches/([^/]+)", path)
                if match and match.group(1) in server.batches:
                    batch = server.batches[match.group(1)]
                    server._step(batch)
                    return self._send(200, _openai_batch(server, batch, None))
                match = re.fullmatch(r"/v1/files/([^/]+)/content", path)
                if match and match.group(1) in server.files:
                    return self._send(200, server.files[match.group(1)], "application/octet-stream")
                match = re.fullmatch(r"/v1/messages/batches/([^/]+)(/results)?", path)
                if match and match.group(1) in server.batches:
                    batch = server.batches[match.group(1)]
                    if match.group(2):
                        return self._send(200, _anthropic_results(server, batch), "application/x-jsonl")
                    server._step(batch)
                    return self._send(200, _anthropic_batch(server, batch))
                if path == "/v1beta/batches":
                    return self._send(200, {"operations": [_gemini_operation(server, b, peek=True)
                                                           for b in server.batches.values() if b.protocol == "gemini"]})
                match = re.fullmatch(r"/v1beta/(batches/[^/]+)", path)
                if match and match.group(1) in server.batches:
                    batch = server.batches[match.group(1)]
                    server._step(batch)
                    return self._send(200, _gemini_operation(server, batch))
                self._send(404, {"error": {"message": f"no route {path}"}})

        return Handler


def _multipart_file(raw: bytes, content_type: str) -> bytes:
    """The ``file`` part of a multipart/form-data body."""
    boundary = content_type.split("boundary=", 1)[1].strip('"').encode()
    for part in raw.split(b"--" + boundary):
        head, _, content = part.partition(b"\r\n\r\n")
        if b'name="file"' in head:
            return content.rsplit(b"\r\n", 1)[0]
    raise ValueError("no file part")


def _openai_batch(server: FakeBatchServer, batch: FakeBatch, input_file: str | None, *, peek: bool = False) -> dict[str, Any]:
    ended = batch.polls >= server.steps
    status = "validating" if batch.polls == 0 else ("in_progress" if not ended else batch.end_state)
    out: dict[str, Any] = {"id": batch.id, "object": "batch", "endpoint": "/v1/chat/completions", "errors": None,
                           "input_file_id": input_file or "file-x", "completion_window": "24h", "status": status,
                           "output_file_id": None, "error_file_id": None, "created_at": int(time.time()),
                           "request_counts": {"total": len(batch.requests), "completed": 0, "failed": 0},
                           "metadata": batch.metadata}
    if ended and not peek:
        if batch.end_state == "failed":
            out["errors"] = {"object": "list", "data": [{"code": "invalid_request", "message": "line 1: bad model", "line": 1}]}
            return out
        results = server._results(batch)
        ok, bad = [], []
        for r in results:
            if r["kind"] == "ok":
                ok.append({"id": f"batch_req_{r['custom_id']}", "custom_id": r["custom_id"],
                           "response": {"status_code": 200, "request_id": "req", "body": r["body"]}, "error": None})
            elif r["kind"] == "error":
                bad.append({"id": f"batch_req_{r['custom_id']}", "custom_id": r["custom_id"],
                            "response": {"status_code": 400, "request_id": "req",
                                         "body": {"error": {"message": r["message"], "type": "invalid_request_error"}}},
                            "error": None})
            else:
                bad.append({"id": f"batch_req_{r['custom_id']}", "custom_id": r["custom_id"], "response": None,
                            "error": {"code": "batch_expired", "message": "This request could not be executed before the "
                                                                          "completion window expired."}})
        with server.lock:
            if ok:
                server.files[f"out-{batch.id}"] = "".join(json.dumps(x) + "\n" for x in ok).encode()
                out["output_file_id"] = f"out-{batch.id}"
            if bad:
                server.files[f"err-{batch.id}"] = "".join(json.dumps(x) + "\n" for x in bad).encode()
                out["error_file_id"] = f"err-{batch.id}"
        out["request_counts"] = {"total": len(results), "completed": len(ok), "failed": len(bad)}
    return out


def _anthropic_batch(server: FakeBatchServer, batch: FakeBatch) -> dict[str, Any]:
    ended = batch.polls >= server.steps
    return {"id": batch.id, "type": "message_batch", "processing_status": "ended" if ended else "in_progress",
            "request_counts": {"processing": 0 if ended else len(batch.requests), "succeeded": 0, "errored": 0,
                               "canceled": 0, "expired": 0},
            "results_url": f"{server.root}/v1/messages/batches/{batch.id}/results" if ended else None,
            "created_at": "2026-12-01T00:00:00Z", "ended_at": None, "expires_at": "2026-12-02T00:00:00Z"}


def _anthropic_results(server: FakeBatchServer, batch: FakeBatch) -> bytes:
    lines = []
    for r in server._results(batch):
        if r["kind"] == "ok":
            result = {"type": "succeeded", "message": r["body"]}
        elif r["kind"] == "error":
            result = {"type": "errored", "error": {"type": "error", "error": {"type": "invalid_request_error",
                                                                              "message": r["message"]}}}
        else:
            result = {"type": "expired"}
        lines.append(json.dumps({"custom_id": r["custom_id"], "result": result}))
    return ("\n".join(lines) + "\n").encode()


def _gemini_operation(server: FakeBatchServer, batch: FakeBatch, *, peek: bool = False) -> dict[str, Any]:
    ended = batch.polls >= server.steps and not peek
    state = {"completed": "BATCH_STATE_SUCCEEDED", "expired": "BATCH_STATE_EXPIRED", "failed": "BATCH_STATE_FAILED"}
    end_state = batch.end_state
    if end_state == "completed" and any(cid in server.expire for cid, _ in batch.requests):
        end_state = "expired"  # Gemini expires a batch as a whole: the requests it did not reach get no response
    meta = {"@type": "type.googleapis.com/google.ai.generativelanguage.v1main.GenerateContentBatch", "name": batch.id,
            "displayName": batch.metadata.get("displayName"), "model": f"models/{batch.metadata.get('model')}",
            "state": state[end_state] if ended else ("BATCH_STATE_PENDING" if batch.polls == 0 else "BATCH_STATE_RUNNING")}
    out: dict[str, Any] = {"name": batch.id, "metadata": meta, "done": ended}
    if ended and batch.end_state == "failed":
        out["error"] = {"code": 400, "message": "invalid model"}
    elif ended:
        responses = []
        for r in server._results(batch):
            if r["kind"] == "ok":
                responses.append({"response": r["body"], "metadata": {"key": r["custom_id"]}})
            elif r["kind"] == "error":
                responses.append({"error": {"code": 400, "message": r["message"]}, "metadata": {"key": r["custom_id"]}})
            # expired requests get no response at all
        out["response"] = {"@type": "type.googleapis.com/google.ai.generativelanguage.v1main.GenerateContentBatchOutput",
                           "inlinedResponses": {"inlinedResponses": responses}}
    return out
