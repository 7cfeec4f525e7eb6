"""The batch journal: which requests went into which provider batch, written before any provider is asked.

``<run_dir>/batches.jsonl`` holds one JSON object per line, each appended whole, checked and fsynced
(:meth:`BatchJournal._append`: a short write or a full disk is cut back off and raised, so no batch is created after
a line that did not reach the disk):

* ``{"event": "submitting", "token": T, "custom_ids": [...], "at": ...}`` — before a batch is created
  (``T`` is also the batch's name/metadata at the provider, so an interrupted submission can be found;
  ``at``: the local time, which bounds the look-up);
* ``{"event": "submitted", "token": T, "batch_id": B, "custom_ids": [...], "at": ...}`` — as soon as
  the provider returned the batch id (or a look-up found it), before the first poll;
* ``{"event": "abandoned", "token": T, "reason": ...}`` — a submission the provider refused, or that an
  earlier session cut off and the provider does not know: nothing was created;
* ``{"event": "failed", "batch_id": B, "state": S, "reason": ...}`` — a batch the provider failed as a whole
  before running any of its requests (validation, OpenAI's enqueued-token limit): its requests may go out again;
* ``{"event": "completed", "batch_id": B, "state": S, "results": "batches/<B>.jsonl", "turnaround_s": ...}`` —
  once its results are saved (temp file + rename) under ``batches/``.

A killed run is resumed by reading the journal: a request whose custom id is journaled under a batch
is answered by that batch (polled again, or its saved results read back) — never resubmitted, never
billed twice. The journal is read like every other run file (:func:`lightemma.runs.store.read_small_text`:
a regular file within :data:`MAX_JOURNAL_BYTES`, each line within :data:`MAX_JOURNAL_LINE_BYTES`, every event
checked field by field); a problem is one :class:`~lightemma.errors.RunStoreError` line naming the file and line.
A torn last line (the process killed mid-write: no newline after it) journaled nothing and is cut off when the
journal is opened for a session, so the next line starts whole.
"""

from __future__ import annotations

import json
import math
import os
import re
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lightemma.errors import RunStoreError, os_error_line
from lightemma.runs.records import loads_bounded
from lightemma.runs.store import read_small_text, write_text_atomic

JOURNAL_FILE = "batches.jsonl"
RESULTS_DIR = "batches"
#: the largest journal read: ~50 bytes per request and event, room for millions of requests
MAX_JOURNAL_BYTES = 256 * 1024 * 1024
#: the longest journal line read: one batch's custom ids (100,000 requests of ~50 bytes each, with room)
MAX_JOURNAL_LINE_BYTES = 16 * 1024 * 1024
EVENTS = ("submitting", "submitted", "abandoned", "failed", "completed")


def _safe(batch_id: str) -> str:
    """A batch id as a file name (provider ids hold ``/`` for Gemini: ``batches/123``)."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", batch_id).strip("._") or "batch"


@dataclass
class JournaledBatch:
    """One batch as the journal knows it."""

    batch_id: str
    token: str
    custom_ids: list[str]
    submitted_at: float
    state: str | None = None  # the terminal state once completed (or failed)
    results: str | None = None  # results file, relative to the run directory
    turnaround_s: float | None = None
    failed: str | None = None  # why the provider failed it as a whole (none of its requests ran)


@dataclass
class Submission:
    """A submission journaled as ``submitting`` and not yet confirmed: its custom ids and when it was journaled."""

    custom_ids: list[str]
    at: float


def _text(event: dict[str, Any], name: str, where: str, *, optional: bool = False) -> str | None:
    value = event.get(name)
    if value is None and optional:
        return None
    if not isinstance(value, str) or not value:
        raise RunStoreError(f"{where}: {name} is {type(value).__name__}, not a text; the batch journal is damaged")
    return value


def _number(event: dict[str, Any], name: str, where: str) -> float | None:
    value = event.get(name)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
        raise RunStoreError(
            f"{where}: {name} is {str(value)[:40]!r}, not a time in seconds; the batch journal is damaged"
        )
    return float(value)


def _ids(event: dict[str, Any], where: str) -> list[str]:
    value = event.get("custom_ids")
    if not isinstance(value, list) or not all(isinstance(c, str) and c for c in value):
        raise RunStoreError(f"{where}: custom_ids is not a list of texts; the batch journal is damaged")
    return value


@dataclass
class BatchJournal:
    """Append-only journal of a run's batches (see the module docstring)."""

    run_dir: Path
    batches: dict[str, JournaledBatch] = field(default_factory=dict)  # batch id -> batch
    by_custom_id: dict[str, str] = field(default_factory=dict)  # custom id -> batch id
    unconfirmed: dict[str, Submission] = field(default_factory=dict)  # token -> submitting, no id journaled

    @classmethod
    def open(cls, run_dir: str | os.PathLike[str], *, repair: bool = False) -> BatchJournal:
        """The journal of ``run_dir`` as written so far (empty when there is none); ``repair``: a torn last line is
        cut off the file (a session about to append). Anything else wrong: one :class:`RunStoreError` line."""
        journal = cls(Path(run_dir))
        path = journal.path
        if not path.exists() and not path.is_symlink():
            return journal
        if path.is_symlink():
            raise RunStoreError(f"{path} is a link, not the batch journal lightemma writes")
        text = read_small_text(path, MAX_JOURNAL_BYTES)  # a regular file within the limit: never a FIFO or /dev/zero
        lines = text.split("\n")  # "\n" only: U+2028 or U+0085 inside a JSON string is no line break
        torn = lines.pop()  # after the last newline: "" when the file ends whole
        for number, line in enumerate(lines, 1):
            where = f"{path}:{number}"
            if len(line) > MAX_JOURNAL_LINE_BYTES // 4 and len(line.encode("utf-8")) > MAX_JOURNAL_LINE_BYTES:
                raise RunStoreError(
                    f"{where}: a line over {MAX_JOURNAL_LINE_BYTES:,} bytes; the batch journal is damaged"
                )
            if not line.strip():
                continue
            try:
                event = loads_bounded(line)
            except ValueError as exc:
                raise RunStoreError(
                    f"{where}: not a JSON line ({str(exc)[:80]}); the batch journal is damaged"
                ) from None
            journal._apply(event, where)
        if not torn.strip():
            return journal
        try:  # a last line without its newline: whole (applied), or torn by a killed write (it journaled nothing)
            event = loads_bounded(torn)
            journal._apply(event, f"{path}:{len(lines) + 1}")
            whole = True
        except (ValueError, RunStoreError):
            whole = False
        if repair:  # the next line must start on a line of its own
            try:
                if whole:
                    with open(path, "ab") as handle:
                        handle.write(b"\n")
                        handle.flush()
                        os.fsync(handle.fileno())
                else:
                    os.truncate(path, len(text.encode("utf-8")) - len(torn.encode("utf-8")))
            except OSError as exc:
                raise RunStoreError(os_error_line(exc, "repair the torn last line of the batch journal")) from None
        return journal

    @property
    def path(self) -> Path:
        return self.run_dir / JOURNAL_FILE

    def _apply(self, event: Any, where: str) -> None:
        if not isinstance(event, dict) or event.get("event") not in EVENTS:
            raise RunStoreError(f"{where}: not a batch journal event; the batch journal is damaged")
        kind = event["event"]
        if kind == "submitting":
            token = _text(event, "token", where)
            assert token is not None
            self.unconfirmed[token] = Submission(_ids(event, where), _number(event, "at", where) or 0.0)
        elif kind == "abandoned":
            self.unconfirmed.pop(str(_text(event, "token", where)), None)
        elif kind == "submitted":
            batch = JournaledBatch(
                batch_id=str(_text(event, "batch_id", where)),
                token=str(_text(event, "token", where)),
                custom_ids=_ids(event, where),
                submitted_at=_number(event, "at", where) or 0.0,
            )
            self.unconfirmed.pop(batch.token, None)
            self.batches[batch.batch_id] = batch
            for cid in batch.custom_ids:
                self.by_custom_id[cid] = batch.batch_id
        else:
            bid = _text(event, "batch_id", where)
            ended = self.batches.get(str(bid))
            if ended is None:
                raise RunStoreError(
                    f"{where}: ends batch {str(bid)[:80]!r}, which the journal never submitted; "
                    "the batch journal is damaged"
                )
            ended.state = _text(event, "state", where)
            if kind == "failed":
                ended.failed = _text(event, "reason", where, optional=True) or "no reason given"
            else:
                ended.results = _text(event, "results", where)
                ended.turnaround_s = _number(event, "turnaround_s", where)

    def _append(self, event: dict[str, Any]) -> None:
        """Append one event as one whole line, checked and fsynced; on a short write or any OS error the file is cut
        back to where it was and :class:`RunStoreError` says why (nothing half-written stays, nothing is assumed)."""
        line = (json.dumps(event, ensure_ascii=True, separators=(",", ":")) + "\n").encode("ascii")
        new = not self.path.exists()
        try:
            fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
        except OSError as exc:
            raise RunStoreError(os_error_line(exc, "write the batch journal")) from None
        try:
            start = os.fstat(fd).st_size
            try:
                written = os.write(fd, line)  # one write of one whole line
                if written != len(line):
                    raise OSError(28, f"short write: {written} of {len(line)} bytes", str(self.path))
                os.fsync(fd)
            except OSError as exc:
                try:
                    os.ftruncate(fd, start)  # the partial line is cut off: the journal ends whole
                except OSError:
                    pass
                raise RunStoreError(os_error_line(exc, "write the batch journal")) from None
        finally:
            os.close(fd)
        if new:  # the journal's name in its directory reaches the disk too
            try:
                dir_fd = os.open(self.run_dir, os.O_RDONLY)
                try:
                    os.fsync(dir_fd)
                finally:
                    os.close(dir_fd)
            except OSError as exc:
                raise RunStoreError(os_error_line(exc, "write the batch journal")) from None
        self._apply(event, str(self.path))

    def submitting(self, token: str, custom_ids: Iterable[str]) -> None:
        """Journal a batch about to be created (before the provider is asked)."""
        self._append({"event": "submitting", "token": token, "custom_ids": list(custom_ids), "at": time.time()})

    def submitted(self, token: str, batch_id: str, custom_ids: Iterable[str]) -> None:
        """Journal a created batch's id (before it is polled)."""
        self._append(
            {
                "event": "submitted",
                "token": token,
                "batch_id": batch_id,
                "custom_ids": list(custom_ids),
                "at": time.time(),
            }
        )

    def abandoned(self, token: str, reason: str) -> None:
        """Journal a submission that created nothing (refused, or unknown to the provider)."""
        self._append({"event": "abandoned", "token": token, "reason": reason, "at": time.time()})

    def failed(self, batch_id: str, state: str, reason: str) -> None:
        """Journal a batch the provider failed as a whole, none of its requests run: they may go out again."""
        self._append({"event": "failed", "batch_id": batch_id, "state": state, "reason": reason, "at": time.time()})

    def save_results(self, batch_id: str, items: list[dict[str, Any]], state: str, turnaround_s: float | None) -> None:
        """Save a finished batch's results (temp file + rename), then journal it as completed."""
        folder = self.run_dir / RESULTS_DIR
        folder.mkdir(exist_ok=True)
        relative = f"{RESULTS_DIR}/{_safe(batch_id)}.jsonl"
        write_text_atomic(self.run_dir / relative, "".join(json.dumps(i, ensure_ascii=True) + "\n" for i in items))
        self._append(
            {
                "event": "completed",
                "batch_id": batch_id,
                "state": state,
                "results": relative,
                "turnaround_s": turnaround_s,
                "at": time.time(),
            }
        )

    def saved_results(self, batch_id: str) -> list[dict[str, Any]] | None:
        """The saved results of a completed batch, or None when it has not completed (poll it)."""
        batch = self.batches.get(batch_id)
        if batch is None or batch.results is None:
            return None
        relative = Path(str(batch.results))
        if relative.is_absolute() or ".." in relative.parts:  # never read outside the run directory
            raise RunStoreError(f"{self.path}: batch {batch_id} names results outside the run directory")
        path = self.run_dir / relative
        from lightemma.backends.batch.adapter import BatchHTTPError, checked_results, results_limit

        if path.is_symlink():
            return None  # not the file lightemma wrote (a link, to /dev/zero or anywhere): poll the batch again
        try:  # a regular file within what its batch's results may be: never a FIFO or /dev/zero
            text = read_small_text(path, results_limit(len(batch.custom_ids)))
            items = [json.loads(line) for line in text.split("\n") if line.strip()]  # "\n" only, as written
            if not all(isinstance(i, dict) for i in items):
                return None
            items = checked_results(items, batch.custom_ids)  # each of its requests once, as when it was saved
            return items if len(items) == len(set(batch.custom_ids)) else None  # one missing: not as saved, poll again
        except (RunStoreError, json.JSONDecodeError, RecursionError, BatchHTTPError):
            return None  # lost or damaged: poll the batch again (the provider keeps its results)
