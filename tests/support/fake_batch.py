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

Faults (issue 33), each as the campaign reproduced it: ``lose_create`` — the next N creates make the batch but
answer 500 (``create_delay``: answer only after that many seconds, past a client's ``--timeout``);
``page_size`` — list endpoints answer one page at a time (OpenAI ``limit``/``after``, Anthropic ``limit``/``after_id``,
Gemini ``pageSize``/``pageToken``), and :meth:`FakeBatchServer.add_foreign` puts other batches of the account, newer
than the run's, in front; ``results_fault`` — ``"empty"`` (a 0-byte results file), ``"no_file"`` (OpenAI
``completed`` with a null output file; Anthropic/Gemini: no answers), ``"half"`` (half the lines missing),
``"responses_file"`` (Gemini results in a ``responsesFile``; not a fault: documented) — while set, or for the
first ``fault_reads`` deliveries;
``cancel`` — batch numbers canceled in the provider's console (none of their requests run); ``fail_code`` — the
error code of a batch failed as a whole (``batch_state="failed"``, or batch numbers in ``fail_batches``);
``raw_text`` — results written without escaping non-ASCII (U+2028, U+0085 stay raw bytes).

``server.submissions`` counts the batches each custom id went into; :meth:`FakeBatchServer.billed` counts, per
custom id, how many times a batch ran it — what the provider bills. Tests assert both stay at 1.
"""

from __future__ import annotations

import json
import random
import re
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

from tests.support.fake_openai import Received, Reply, _completion, default_reply


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
    created_at: float = field(default_factory=time.time)
    foreign: bool = False  # another client's batch in the same account (never polled by the run)
    canceled: bool = False  # canceled in the provider's console: none of its requests run


class FakeBatchServer:
    """The loopback batch server; a context manager. ``url`` is an OpenAI ``api_base`` (``…/v1``)."""

    def __init__(
        self,
        script: Callable[[Received], Reply] | None = None,
        *,
        steps: int = 2,
        shuffle: bool = True,
        seed: int = 0,
        fail: dict[str, str] | None = None,
        expire: set[str] | None = None,
        batch_state: str | None = None,
        require_key: str | None = None,
        hold_from: int | None = None,
        refusal: str = "invalid x-api-key",
        bloat: int = 0,
        duplicate: bool = False,
        lose_create: int = 0,
        create_delay: float = 0.0,
        page_size: int | None = None,
        results_fault: str | None = None,
        cancel: set[int] | None = None,
        fail_code: str = "invalid_request",
        fail_batches: set[int] | None = None,
        raw_text: bool = False,
        fail_create: int = 0,
        unrun: Callable[[str, dict[str, Any]], bool] | None = None,
        fault_reads: int | None = None,
    ) -> None:
        self.lose_create = lose_create  # the next N creates make the batch and answer 500
        self.create_delay = create_delay  # seconds before a lost create is answered (the batch exists at once)
        self.fail_create = fail_create  # the next N creates answer 500 and make nothing
        self.unrun = unrun  # (custom id, body) -> True: the provider never runs it (expired)
        self.page_size = page_size  # list endpoints page at most this many batches (None: one page of all)
        self.results_fault = results_fault
        self.fault_reads = fault_reads  # None: the fault lasts while results_fault is set
        self.cancel = set(cancel or ())
        self.fail_code = fail_code
        self.fail_batches = set(fail_batches or ())
        self.raw_text = raw_text
        self.submissions: Counter[str] = Counter()
        self.list_calls = 0
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
        path = {
            "openai": "/v1/chat/completions",
            "anthropic": "/v1/messages",
            "gemini": "/v1beta/models/m:generateContent",
        }[protocol]
        received = Received(path=path, headers={}, body=body, index=index)
        answer = _completion(received, self.script(received))
        if self.bloat:
            answer["padding"] = "x" * self.bloat
        return answer

    def _create(self, protocol: str, requests: list[tuple[str, dict[str, Any]]], metadata: dict[str, Any]) -> FakeBatch:
        with self.lock:
            self.created += 1
            prefix = {"openai": "batch_", "anthropic": "msgbatch_", "gemini": "batches/"}[protocol]
            number = self.created
            failed = self.batch_state == "failed" or number in self.fail_batches
            batch = FakeBatch(
                id=f"{prefix}{number:04d}",
                protocol=protocol,
                requests=requests,
                metadata=metadata,
                end_state="failed" if failed else (self.batch_state or "completed"),
                number=number,
                canceled=number in self.cancel,
            )
            self.batches[batch.id] = batch
            for cid, _ in requests:
                self.submissions[cid] += 1
            return batch

    def _expired(self, batch: FakeBatch, index: int) -> bool:
        cid, body = batch.requests[index]
        return (
            cid in self.expire
            or (batch.end_state == "expired" and index % 2 == 1)
            or (self.unrun is not None and self.unrun(cid, body))
        )

    def add_foreign(self, n: int, protocol: str, size: int = 1) -> None:
        """``n`` batches of another client in the account, created after everything so far (newest first in lists)."""
        with self.lock:
            for i in range(n):
                prefix = {"openai": "batch_", "anthropic": "msgbatch_", "gemini": "batches/"}[protocol]
                batch = FakeBatch(
                    id=f"{prefix}x{len(self.batches):05d}",
                    protocol=protocol,
                    requests=[(f"other-{i}-{j}", {}) for j in range(size)],
                    metadata={"displayName": f"other-{i}", "lightemma_token": f"other-{i}"},
                    foreign=True,
                )
                self.batches[batch.id] = batch

    def listed(self, protocol: str, after: str | None, limit: int | None) -> tuple[list[FakeBatch], bool]:
        """A page of the account's batches, newest first, after the batch ``after``: (page, more follow)."""
        with self.lock:
            self.list_calls += 1
            ordered = [b for b in reversed(list(self.batches.values())) if b.protocol == protocol]
        if after is not None:
            ids = [b.id for b in ordered]
            ordered = ordered[ids.index(after) + 1 :] if after in ids else []
        size = limit or len(ordered) or 1
        return ordered[:size], len(ordered) > size

    def billed(self) -> Counter[str]:
        """How many times a batch ran each request (by custom id; a re-ask is a new id, so tests also count batches
        created): a batch failed as a whole or canceled runs
        none; an expired one runs the requests it reached. A batch is billed once created, read or not."""
        out: Counter[str] = Counter()
        for batch in self.batches.values():
            if batch.foreign or batch.canceled or batch.end_state == "failed":
                continue
            for index, (cid, _body) in enumerate(batch.requests):
                if self._expired(batch, index):
                    continue
                out[cid] += 1
        return out

    def paid_twice(self) -> list[str]:
        """Requests a batch ran more than once, and custom ids submitted in more than one batch."""
        return [f"request {k} billed {n}x" for k, n in self.billed().items() if n > 1] + [
            f"custom id {k} submitted {n}x" for k, n in self.submissions.items() if n > 1
        ]

    def _results(self, batch: FakeBatch) -> list[dict[str, Any]]:
        """(custom id, kind, payload) per request once the batch has ended: kind ok / error / expired."""
        if batch.results is None:
            out = []
            for index, (cid, body) in enumerate(batch.requests):
                if batch.canceled:
                    out.append({"custom_id": cid, "kind": "canceled"})
                elif self._expired(batch, index):
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
                key = " ".join(
                    self.headers.get(h, "") for h in ("Authorization", "x-api-key", "x-goog-api-key")
                ).strip()
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
                    return self._send(
                        200,
                        {
                            "id": fid,
                            "object": "file",
                            "bytes": len(content),
                            "created_at": int(time.time()),
                            "filename": "batch.jsonl",
                            "purpose": "batch",
                            "status": "processed",
                        },
                    )
                body = json.loads(raw or b"{}")
                if path in ("/v1/batches", "/v1/messages/batches") or path.endswith(":batchGenerateContent"):
                    with server.lock:
                        refuse = server.fail_create > 0
                        server.fail_create -= 1 if refuse else 0
                    if refuse:
                        return self._send(503, {"error": {"message": "overloaded", "type": "server_error"}})
                if path == "/v1/batches":
                    lines = [
                        json.loads(line)
                        for line in server.files[body["input_file_id"]].decode().split("\n")
                        if line.strip()
                    ]
                    batch = server._create(
                        "openai", [(ln["custom_id"], ln["body"]) for ln in lines], body.get("metadata") or {}
                    )
                    return self._created(_openai_batch(server, batch, body["input_file_id"]))
                if path == "/v1/messages/batches":
                    batch = server._create("anthropic", [(r["custom_id"], r["params"]) for r in body["requests"]], {})
                    return self._created(_anthropic_batch(server, batch))
                match = re.fullmatch(r"/v1beta/models/([^/:]+):batchGenerateContent", path)
                if match:
                    spec = body["batch"]
                    reqs = spec["inputConfig"]["requests"]["requests"]
                    batch = server._create(
                        "gemini",
                        [(r["metadata"]["key"], r["request"]) for r in reqs],
                        {"displayName": spec.get("displayName"), "model": match.group(1)},
                    )
                    return self._created(_gemini_operation(server, batch))
                self._send(404, {"error": {"message": f"no route {path}"}})

            def _created(self, payload: Any) -> None:
                """The answer to a create: lost (500, after the batch was made) while ``lose_create`` lasts."""
                with server.lock:
                    lose = server.lose_create > 0
                    server.lose_create -= 1 if lose else 0
                if lose:
                    time.sleep(server.create_delay)  # past the client's --timeout: it has given up
                    return self._send(500, {"error": {"message": "internal error", "type": "server_error"}})
                self._send(200, payload)

            def _query(self) -> dict[str, str]:
                from urllib.parse import parse_qs, urlsplit

                return {k: v[-1] for k, v in parse_qs(urlsplit(self.path).query).items()}

            def do_GET(self) -> None:  # noqa: N802
                path = self.path.split("?")[0]
                if self._refused():
                    return
                if path == "/v1/batches":
                    q = self._query()
                    page, more = server.listed(
                        "openai", q.get("after"), min(int(q.get("limit", 20)), server.page_size or 10**9)
                    )
                    data = [_openai_batch(server, b, None, peek=True) for b in page]
                    return self._send(
                        200,
                        {
                            "object": "list",
                            "data": data,
                            "has_more": more,
                            "first_id": data[0]["id"] if data else None,
                            "last_id": data[-1]["id"] if data else None,
                        },
                    )
                if path == "/v1/messages/batches":
                    q = self._query()
                    page, more = server.listed(
                        "anthropic", q.get("after_id"), min(int(q.get("limit", 20)), server.page_size or 10**9)
                    )
                    data = [_anthropic_batch(server, b, peek=True) for b in page]
                    return self._send(
                        200,
                        {
                            "data": data,
                            "has_more": more,
                            "first_id": data[0]["id"] if data else None,
                            "last_id": data[-1]["id"] if data else None,
                        },
                    )
                match = re.fullmatch(r"/download/v1beta/(files/[^/:]+):download", path)
                if match and match.group(1) in server.files:
                    return self._send(200, server.files[match.group(1)], "application/octet-stream")
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
                    q = self._query()
                    page, more = server.listed("gemini", q.get("pageToken"), server.page_size)
                    out = {"operations": [_gemini_operation(server, b, peek=True) for b in page]}
                    if more:
                        out["nextPageToken"] = page[-1].id
                    return self._send(200, out)
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


def _dumps(server: FakeBatchServer, value: Any) -> str:
    return json.dumps(value, ensure_ascii=not server.raw_text)


def _faulty(server: FakeBatchServer, lines: list[Any]) -> list[Any]:
    """The results lines as ``results_fault`` delivers them (``fault_reads``: for that many deliveries, then whole)."""
    if server.results_fault is not None and server.fault_reads is not None:
        if server.fault_reads <= 0:
            server.results_fault = None
        server.fault_reads -= 1
    if server.results_fault in ("empty", "no_file"):
        return []
    if server.results_fault == "half":
        return lines[: len(lines) // 2]
    return lines


def _iso(seconds: float) -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(seconds)) + f".{int(seconds % 1 * 1e6):06d}Z"


def _openai_batch(
    server: FakeBatchServer, batch: FakeBatch, input_file: str | None, *, peek: bool = False
) -> dict[str, Any]:
    ended = batch.polls >= server.steps
    final = "cancelled" if batch.canceled else batch.end_state
    status = "validating" if batch.polls == 0 else ("in_progress" if not ended else final)
    out: dict[str, Any] = {
        "id": batch.id,
        "object": "batch",
        "endpoint": "/v1/chat/completions",
        "errors": None,
        "input_file_id": input_file or "file-x",
        "completion_window": "24h",
        "status": status,
        "output_file_id": None,
        "error_file_id": None,
        "created_at": int(batch.created_at),
        "request_counts": {"total": len(batch.requests), "completed": 0, "failed": 0},
        "metadata": batch.metadata,
    }
    if ended and not peek:
        if batch.end_state == "failed":
            message = (
                "Enqueued token limit reached for gpt-4o in organization org-x."
                if server.fail_code == "token_limit_exceeded"
                else "line 1: bad model"
            )
            out["errors"] = {
                "object": "list",
                "data": [
                    {
                        "code": server.fail_code,
                        "message": message,
                        "line": None if server.fail_code == "token_limit_exceeded" else 1,
                    }
                ],
            }
            return out
        results = server._results(batch)
        ok, bad = [], []
        for r in results:
            if r["kind"] == "ok":
                ok.append(
                    {
                        "id": f"batch_req_{r['custom_id']}",
                        "custom_id": r["custom_id"],
                        "response": {"status_code": 200, "request_id": "req", "body": r["body"]},
                        "error": None,
                    }
                )
            elif r["kind"] == "error":
                bad.append(
                    {
                        "id": f"batch_req_{r['custom_id']}",
                        "custom_id": r["custom_id"],
                        "response": {
                            "status_code": 400,
                            "request_id": "req",
                            "body": {"error": {"message": r["message"], "type": "invalid_request_error"}},
                        },
                        "error": None,
                    }
                )
            else:
                code = "batch_cancelled" if r["kind"] == "canceled" else "batch_expired"
                bad.append(
                    {
                        "id": f"batch_req_{r['custom_id']}",
                        "custom_id": r["custom_id"],
                        "response": None,
                        "error": {
                            "code": code,
                            "message": "This request could not be executed before the completion window expired.",
                        },
                    }
                )
        with server.lock:
            if ok and server.results_fault != "no_file":
                server.files[f"out-{batch.id}"] = "".join(
                    _dumps(server, x) + "\n" for x in _faulty(server, [*ok])
                ).encode()
                out["output_file_id"] = f"out-{batch.id}"
            if bad:
                server.files[f"err-{batch.id}"] = "".join(json.dumps(x) + "\n" for x in bad).encode()
                out["error_file_id"] = f"err-{batch.id}"
        out["request_counts"] = {"total": len(results), "completed": len(ok), "failed": len(bad)}
    return out


def _anthropic_batch(server: FakeBatchServer, batch: FakeBatch, *, peek: bool = False) -> dict[str, Any]:
    ended = batch.polls >= server.steps and not peek
    counts = {"processing": len(batch.requests), "succeeded": 0, "errored": 0, "canceled": 0, "expired": 0}
    if ended:
        kinds = Counter(r["kind"] for r in server._results(batch))
        counts = {
            "processing": 0,
            "succeeded": kinds["ok"],
            "errored": kinds["error"],
            "canceled": kinds["canceled"],
            "expired": kinds["expired"],
        }
    return {
        "id": batch.id,
        "type": "message_batch",
        "processing_status": "ended" if ended else "in_progress",
        "request_counts": counts,
        "results_url": f"{server.root}/v1/messages/batches/{batch.id}/results" if ended else None,
        "created_at": _iso(batch.created_at),
        "ended_at": None,
        "expires_at": "2026-12-02T00:00:00Z",
        "cancel_initiated_at": _iso(batch.created_at) if batch.canceled and ended else None,
    }


def _anthropic_results(server: FakeBatchServer, batch: FakeBatch) -> bytes:
    lines = []
    for r in server._results(batch):
        if r["kind"] == "ok":
            result = {"type": "succeeded", "message": r["body"]}
        elif r["kind"] == "error":
            result = {
                "type": "errored",
                "error": {"type": "error", "error": {"type": "invalid_request_error", "message": r["message"]}},
            }
        else:
            result = {"type": r["kind"]}
        lines.append(_dumps(server, {"custom_id": r["custom_id"], "result": result}))
    lines = _faulty(server, lines)
    return ("\n".join(lines) + "\n").encode() if lines else b""


def _gemini_operation(server: FakeBatchServer, batch: FakeBatch, *, peek: bool = False) -> dict[str, Any]:
    ended = batch.polls >= server.steps and not peek
    state = {
        "completed": "BATCH_STATE_SUCCEEDED",
        "expired": "BATCH_STATE_EXPIRED",
        "failed": "BATCH_STATE_FAILED",
        "cancelled": "BATCH_STATE_CANCELLED",
    }
    end_state = "cancelled" if batch.canceled else batch.end_state
    if end_state == "completed" and any(server._expired(batch, i) for i in range(len(batch.requests))):
        end_state = "expired"  # Gemini expires a batch as a whole: the requests it did not reach get no response
    meta = {
        "@type": "type.googleapis.com/google.ai.generativelanguage.v1main.GenerateContentBatch",
        "name": batch.id,
        "displayName": batch.metadata.get("displayName"),
        "model": f"models/{batch.metadata.get('model')}",
        "createTime": _iso(batch.created_at),
        "state": state[end_state] if ended else ("BATCH_STATE_PENDING" if batch.polls == 0 else "BATCH_STATE_RUNNING"),
    }
    out: dict[str, Any] = {"name": batch.id, "metadata": meta, "done": ended}
    if ended and batch.end_state == "failed":
        out["error"] = {"code": 400, "message": "invalid model"}
        meta["batchStats"] = {"requestCount": str(len(batch.requests)), "pendingRequestCount": str(len(batch.requests))}
    elif ended:
        responses = []
        for r in server._results(batch):
            if r["kind"] == "ok":
                responses.append({"response": r["body"], "metadata": {"key": r["custom_id"]}})
            elif r["kind"] == "error":
                responses.append({"error": {"code": 400, "message": r["message"]}, "metadata": {"key": r["custom_id"]}})
            # expired and canceled requests get no response at all
        # int64 counts are JSON strings in Google's APIs
        ok = sum(1 for r in responses if "response" in r)
        meta["batchStats"] = {
            "requestCount": str(len(batch.requests)),
            "successfulRequestCount": str(ok),
            "failedRequestCount": str(len(responses) - ok),
            "pendingRequestCount": str(len(batch.requests) - len(responses)),
        }
        output: dict[str, Any] = {
            "@type": "type.googleapis.com/google.ai.generativelanguage.v1main.GenerateContentBatchOutput"
        }
        if server.results_fault == "responses_file":
            name = f"files/batch-{batch.id.split('/')[-1]}"
            with server.lock:
                server.files[name] = "".join(
                    _dumps(server, {"key": r["metadata"]["key"], **{k: v for k, v in r.items() if k != "metadata"}})
                    + "\n"
                    for r in responses
                ).encode()
            output["responsesFile"] = name
        else:
            kept = [json.loads(x) for x in _faulty(server, [json.dumps(r) for r in responses])]
            output["inlinedResponses"] = {"inlinedResponses": kept}
        out["response"] = output
    return out
