"""The batch journal: which requests went into which provider batch, written before any polling.

``<run_dir>/batches.jsonl`` holds one JSON object per line, appended whole and fsynced:

* ``{"event": "submitting", "token": T, "custom_ids": [...], "at": ...}`` — before a batch is created
  (``T`` is also the batch's name/metadata at the provider, so an interrupted submission can be found);
* ``{"event": "submitted", "token": T, "batch_id": B, "custom_ids": [...], "at": ...}`` — as soon as
  the provider returned the batch id, before the first poll;
* ``{"event": "abandoned", "token": T, "reason": ...}`` — a submission the provider refused, or that an
  earlier session cut off and the provider does not know: nothing was created;
* ``{"event": "completed", "batch_id": B, "state": S, "results": "batches/<B>.jsonl", "turnaround_s": ...}`` —
  once its results are saved (temp file + rename) under ``batches/``.

A killed run is resumed by reading the journal: a request whose custom id is journaled under a batch
is answered by that batch (polled again, or its saved results read back) — never resubmitted, never
billed twice. A torn last line (the process killed mid-write) is ignored: it journaled nothing.
"""

from __future__ import annotations

import json
import os
import re
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lightemma.errors import RunStoreError

JOURNAL_FILE = "batches.jsonl"
RESULTS_DIR = "batches"


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
    state: str | None = None  # the terminal state once completed
    results: str | None = None  # results file, relative to the run directory
    turnaround_s: float | None = None


@dataclass
class BatchJournal:
    """Append-only journal of a run's batches (see the module docstring)."""

    run_dir: Path
    batches: dict[str, JournaledBatch] = field(default_factory=dict)  # batch id -> batch
    by_custom_id: dict[str, str] = field(default_factory=dict)  # custom id -> batch id
    unconfirmed: dict[str, list[str]] = field(default_factory=dict)  # token -> custom ids: submitting, no id journaled

    @classmethod
    def open(cls, run_dir: str | os.PathLike[str]) -> BatchJournal:
        """The journal of ``run_dir`` as written so far (empty when there is none)."""
        journal = cls(Path(run_dir))
        path = journal.path
        if not path.exists():
            return journal
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise RunStoreError(f"cannot read the batch journal {path}: {exc.strerror or exc}") from None
        lines = data.split(b"\n")
        for number, line in enumerate(lines, 1):
            if not line.strip():
                continue
            try:
                event = json.loads(line)
            except json.JSONDecodeError:
                if number == len(lines):  # the torn last line of a killed write (no newline after it)
                    continue
                raise RunStoreError(f"{path}:{number}: not a JSON line; the batch journal is damaged") from None
            journal._apply(event, f"{path}:{number}")
        return journal

    @property
    def path(self) -> Path:
        return self.run_dir / JOURNAL_FILE

    def _apply(self, event: Any, where: str) -> None:
        if not isinstance(event, dict) or event.get("event") not in ("submitting", "submitted", "abandoned", "completed"):
            raise RunStoreError(f"{where}: not a batch journal event")
        kind = event["event"]
        if kind == "submitting":
            self.unconfirmed[str(event["token"])] = [str(c) for c in event.get("custom_ids") or []]
        elif kind == "abandoned":
            self.unconfirmed.pop(str(event["token"]), None)
        elif kind == "submitted":
            batch = JournaledBatch(batch_id=str(event["batch_id"]), token=str(event.get("token")),
                                   custom_ids=[str(c) for c in event.get("custom_ids") or []],
                                   submitted_at=float(event.get("at") or 0.0))
            self.unconfirmed.pop(batch.token, None)
            self.batches[batch.batch_id] = batch
            for cid in batch.custom_ids:
                self.by_custom_id[cid] = batch.batch_id
        else:
            batch = self.batches.get(str(event.get("batch_id")))
            if batch is None:
                raise RunStoreError(f"{where}: completes batch {event.get('batch_id')!r}, which the journal never submitted")
            batch.state, batch.results = event.get("state"), event.get("results")
            batch.turnaround_s = event.get("turnaround_s")

    def _append(self, event: dict[str, Any]) -> None:
        line = (json.dumps(event, ensure_ascii=False, separators=(",", ":")) + "\n").encode("utf-8")
        fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
        try:
            os.write(fd, line)  # one write of one whole line
            os.fsync(fd)
        finally:
            os.close(fd)
        self._apply(event, str(self.path))

    def submitting(self, token: str, custom_ids: Iterable[str]) -> None:
        """Journal a batch about to be created (before the provider is asked)."""
        self._append({"event": "submitting", "token": token, "custom_ids": list(custom_ids), "at": time.time()})

    def submitted(self, token: str, batch_id: str, custom_ids: Iterable[str]) -> None:
        """Journal a created batch's id (before it is polled)."""
        self._append({"event": "submitted", "token": token, "batch_id": batch_id, "custom_ids": list(custom_ids),
                      "at": time.time()})

    def abandoned(self, token: str, reason: str) -> None:
        """Journal a submission that created nothing (refused, or unknown to the provider)."""
        self._append({"event": "abandoned", "token": token, "reason": reason, "at": time.time()})

    def save_results(self, batch_id: str, items: list[dict[str, Any]], state: str, turnaround_s: float | None) -> None:
        """Save a finished batch's results (temp file + rename), then journal it as completed."""
        from lightemma.runs.store import write_text_atomic

        folder = self.run_dir / RESULTS_DIR
        folder.mkdir(exist_ok=True)
        relative = f"{RESULTS_DIR}/{_safe(batch_id)}.jsonl"
        write_text_atomic(self.run_dir / relative, "".join(json.dumps(i, ensure_ascii=False) + "\n" for i in items))
        self._append({"event": "completed", "batch_id": batch_id, "state": state, "results": relative,
                      "turnaround_s": turnaround_s, "at": time.time()})

    def saved_results(self, batch_id: str) -> list[dict[str, Any]] | None:
        """The saved results of a completed batch, or None when it has not completed (poll it)."""
        batch = self.batches.get(batch_id)
        if batch is None or batch.results is None:
            return None
        relative = Path(str(batch.results))
        if relative.is_absolute() or ".." in relative.parts:  # never read outside the run directory
            raise RunStoreError(f"{self.path}: batch {batch_id} names results outside the run directory")
        path = self.run_dir / relative
        from lightemma.backends.batch.base import BatchHTTPError, checked_results, results_limit
        from lightemma.runs.store import read_small_text

        if path.is_symlink():
            return None  # not the file lightemma wrote (a link, to /dev/zero or anywhere): poll the batch again
        try:  # a regular file within what its batch's results may be: never a FIFO or /dev/zero
            items = [json.loads(line) for line in read_small_text(path, results_limit(len(batch.custom_ids))).splitlines()
                     if line.strip()]
            if not all(isinstance(i, dict) for i in items):
                return None
            return checked_results(items, batch.custom_ids)  # each of its requests once, as when it was saved
        except (RunStoreError, json.JSONDecodeError, RecursionError, BatchHTTPError):
            return None  # lost or damaged: poll the batch again (the provider keeps its results)
