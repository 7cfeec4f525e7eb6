"""An on-disk response cache (SQLite) for deterministic requests.

The key is a SHA-256 over the model string, the API base, the decoding
parameters and the messages, where an image is represented by the SHA-256 of
its bytes (so keys are cheap to compute and never hold image data). Only
deterministic requests (temperature 0) and the draws of a sampled run
(``--samples K`` > 1, keyed by sample index) are cached; the caller decides.

Stored per key: the answer text and the provider-reported usage and cost of the
original call. A hit is reported as such (``ChatResult.cached``) with the time
the lookup took, so timings in a run stay honest.

A cache that fails once it is open (``database or disk is full``, ``database is
locked`` after :data:`BUSY_TIMEOUT` seconds, a damaged file) is switched off for
the rest of the run: one line says so (``log``, else stderr), ``failure`` keeps the
reason, lookups miss and answers are no longer stored — the run goes on uncached.

A row whose values are of the wrong kind or out of range (a ``text`` that is a BLOB or not UTF-8 text, token
counts that are not whole numbers 0..10^9 — :data:`lightemma.runs.records.MAX_TOKENS` —, a cost that is not a
number ≥ 0) is no answer: the lookup misses, the call is made again and its answer replaces the row. One
warning line per cache (``log``, else stderr) says so; ``bad_rows`` counts them.
"""

from __future__ import annotations

import hashlib
import json
import os
import sqlite3
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from lightemma.runs.records import MAX_COST_CENTS, in_bounds, token_count

BUSY_TIMEOUT = 5.0  # seconds SQLite waits for another writer's lock before "database is locked"

_SCHEMA = """
CREATE TABLE IF NOT EXISTS responses (
    key TEXT PRIMARY KEY,
    model TEXT NOT NULL,
    text TEXT NOT NULL,
    input_tokens INTEGER,
    output_tokens INTEGER,
    cost_cents REAL,
    created REAL NOT NULL
)
"""


def request_key(
    model: str,
    api_base: str | None,
    params: dict[str, Any],
    text: str,
    image_digest: str | None,
    turns: tuple[tuple[str, str], ...] = (),
    attempt: int = 1,
    inputs: str = "full",
    sample: int = 0,
) -> str:
    """The cache key of one request: ``text`` after the earlier ``turns`` (a single-turn request keeps its old key).

    ``attempt`` > 1 (a re-ask) is part of the key: a re-ask must reach the provider, not replay the cached
    answer it was asked again for; a first ask keeps its old key. ``inputs`` (an input ablation other than
    ``full``, :mod:`lightemma.inputs`) is part of the key too: an ablated request never shares an answer
    with a full one, even where its text and image happen to match; a full request keeps its old key.
    ``sample`` > 0 (another of a frame's K independent samples, ``--samples``) is part of the key too: each sample
    is its own draw; sample 0 keeps the old key, so a cache written before sampling still hits.
    """
    parts: list[Any] = [model, api_base or "", params, text, image_digest or ""]
    if turns:
        parts.append([list(t) for t in turns])
    if attempt > 1:
        parts.append({"attempt": attempt})
    if inputs != "full":
        parts.append({"inputs": inputs})
    if sample > 0:
        parts.append({"sample": sample})
    payload = json.dumps(parts, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(payload.encode("utf-8")).hexdigest()


def _text_or_bytes(data: bytes) -> str | bytes:
    """SQLite TEXT as str; bytes that are not UTF-8 stay bytes (the row is then no answer: :func:`_row_problem`)."""
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data


def _row_problem(row: tuple[Any, ...]) -> str | None:
    """Why a stored row (text, input_tokens, output_tokens, cost_cents) is no answer to replay, else None."""
    text, input_tokens, output_tokens, cost_cents = row
    if type(text) is not str:
        return f"text is {type(text).__name__}, expected text"
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return "text is not UTF-8 text"
    for name, value in (("input_tokens", input_tokens), ("output_tokens", output_tokens)):
        if value is not None and (type(value) is not int or token_count(value) is None):
            return f"{name} = {str(value)[:30]!r}, expected a whole number 0..10^9 or NULL"
    if cost_cents is not None and not in_bounds(cost_cents, MAX_COST_CENTS):
        return f"cost_cents = {str(cost_cents)[:30]!r}, expected a number 0..{MAX_COST_CENTS:g} or NULL"
    return None


class ResponseCache:
    """A thread-safe SQLite store of answers by request key."""

    def __init__(self, path: str | os.PathLike[str], log: Callable[[str], None] | None = None) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()
        self.log = log
        self.failure: str | None = None  # why the cache was switched off mid-run, if it was
        try:
            self._db = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None, timeout=BUSY_TIMEOUT)
            self._db.text_factory = _text_or_bytes  # a row whose text is not UTF-8 is one bad row, not a failed cache
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=NORMAL")
            self._db.execute(_SCHEMA)
        except sqlite3.DatabaseError as exc:
            raise OSError(f"response cache {self.path} is unusable: {exc}") from None
        self.hits = 0
        self.misses = 0
        self.bad_rows = 0  # rows read back with values of the wrong kind or out of range (treated as misses)

    def get(self, key: str) -> dict[str, Any] | None:
        """The stored answer for ``key`` (text, input_tokens, output_tokens, cost_cents), or None."""
        if self.failure is not None:
            return None
        try:
            with self._lock:
                row = self._db.execute(
                    "SELECT text, input_tokens, output_tokens, cost_cents FROM responses WHERE key = ?", (key,)
                ).fetchone()
        except sqlite3.Error as exc:
            self._switch_off(exc)
            return None
        if row is None:
            self.misses += 1
            return None
        problem = _row_problem(row)
        if problem is not None:
            self.misses += 1
            self._bad_row(problem)
            return None
        self.hits += 1
        return {"text": row[0], "input_tokens": row[1], "output_tokens": row[2], "cost_cents": row[3]}

    def _bad_row(self, problem: str) -> None:
        """Count a row that is no answer; say so once per cache."""
        with self._lock:
            self.bad_rows += 1
            if self.bad_rows > 1:
                return
        self._say(
            f"warning: the response cache {self.path} holds rows that are no answer ({problem}); such a request "
            "is sent again and its row replaced (later rows like it are not named)"
        )

    def _say(self, line: str) -> None:
        if self.log is not None:
            self.log(line)
        else:
            import sys

            print(f"lightemma: {line}", file=sys.stderr, flush=True)

    def put(
        self,
        key: str,
        model: str,
        text: str,
        input_tokens: int | None,
        output_tokens: int | None,
        cost_cents: float | None,
    ) -> None:
        """Store one successful answer (an error is never cached)."""
        if self.failure is not None:
            return
        try:
            with self._lock:
                self._db.execute(
                    "INSERT OR REPLACE INTO responses VALUES (?, ?, ?, ?, ?, ?, ?)",
                    (key, model, text, input_tokens, output_tokens, cost_cents, time.time()),
                )
        except sqlite3.Error as exc:
            self._switch_off(exc)

    def _switch_off(self, exc: sqlite3.Error) -> None:
        """Stop using the cache after an SQLite error; say so once."""
        if self.failure is not None:
            return
        self.failure = f"{type(exc).__name__}: {exc}"
        self._say(
            f"warning: the response cache {self.path} failed ({exc}); the run goes on without caching "
            "(answers from here on are neither looked up nor stored)"
        )

    def __len__(self) -> int:
        with self._lock:
            return int(self._db.execute("SELECT COUNT(*) FROM responses").fetchone()[0])

    def close(self) -> None:
        with self._lock:
            try:
                self._db.close()
            except sqlite3.Error:
                pass
