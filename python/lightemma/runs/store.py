"""Crash-safe storage of runs.

A run directory is ``<output>/<model-slug>/<run-id>/`` holding

* ``manifest.json`` — what was run (model, backend, parameters, prompt set and
  hash, dataset, lightemma version, …), always replaced atomically;
* ``frames.jsonl`` — one whole JSON object per finished frame, appended as a
  single ``write`` of a complete line and flushed;
* ``frame_ids.txt`` — the run's frame set, one frame id per line (what
  evaluation scores: a record of another frame is dropped with a warning);
* ``.lock`` (and ``.lock.pid``) — the OS file lock a writing process holds
  (:class:`RunLock`), so that two processes never write one run.

The directory is created whole: its files are written into a temporary
directory beside it, which is then renamed into place, so a run directory
never exists without its manifest.

A crash can at worst leave a truncated last line. Readers ignore it (and say
so); :class:`RunWriter` cuts it off before appending, so the file never holds
a line glued onto a fragment. When a frame appears more than once (a
``--retry-failed`` pass appends a fresh record) the last record wins.
"""

from __future__ import annotations

import json
import math
import os
import re
import secrets
import shutil
import tempfile
import threading
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import orjson

from lightemma._files import FileRefused, read_regular_file
from lightemma.errors import RunStoreError, os_error_line
from lightemma.runs.records import MAX_NUMBER_DIGITS, bounded_values, loads_bounded, record_problem


class RecordTooLargeError(RunStoreError):
    """A frame record whose line would pass :data:`MAX_LINE_BYTES` (answers of that size): not written."""


MANIFEST_FILE = "manifest.json"
FRAMES_FILE = "frames.jsonl"
FRAME_IDS_FILE = "frame_ids.txt"
LOCK_FILE = ".lock"
LOCK_PID_FILE = ".lock.pid"
FORMAT = "lightemma-run/1"


def _to_jsonable(value: Any) -> Any:
    """The JSON encoders' fallback: paths become strings, NumPy arrays and scalars plain lists and numbers."""
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"object of type {type(value).__name__} is not JSON serializable")


_MAX_INT = 10**MAX_NUMBER_DIGITS - 1  # the largest integer the readers take (records.loads_bounded)


def _sanitize(value: Any, dropped: list[int] | None = None) -> Any:
    """Plain lists and numbers for NumPy arrays and scalars, ``None`` for non-finite floats: strict JSON.

    With ``dropped`` (a record line), integers of more than :data:`~lightemma.runs.records.MAX_NUMBER_DIGITS` digits,
    which the readers refuse, become ``None`` too, their digit counts appended to ``dropped``.
    """
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if dropped is not None and type(value) is int and not -_MAX_INT <= value <= _MAX_INT:
        dropped.append(len(str(abs(value))) if abs(value) < 10**4000 else 4000)
        return None
    if isinstance(value, dict):
        return {k: _sanitize(v, dropped) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_sanitize(v, dropped) for v in value]
    if isinstance(value, np.ndarray):
        return _sanitize(value.tolist(), dropped)
    if isinstance(value, np.generic):
        return _sanitize(value.item(), dropped)
    return value


def encode_line(record: Mapping[str, Any], problems: list[str] | None = None, *, bounded: bool = False) -> bytes:
    """One record as one line of strict JSON in UTF-8 (NaN/inf become null), newline-terminated.

    Never a line the readers refuse (:func:`iter_records`): token counts, times and costs that are not numbers within
    their bounds (:data:`lightemma.runs.records.VALUE_BOUNDS`) and integers of more than 18 digits anywhere are
    written as null (unknown); each replacement is described in ``problems`` when given.

    Through orjson: a record is mostly numbers and small containers, whose encoding costs the
    standard library ~5× more (what an import of reference results spends its time on). What orjson
    refuses — an integer beyond 53 bits (``OPT_STRICT_INTEGER``), a key that is not a string, a lone surrogate —
    is encoded by ``json`` instead (in ASCII escapes), with the same meaning. ``bounded=True``: the caller already
    passed the record through :func:`~lightemma.runs.records.bounded_values` (the importer, which tallies it).
    """
    if not bounded:
        record = bounded_values(record, problems)
    try:
        return orjson.dumps(record, default=_to_jsonable, option=orjson.OPT_APPEND_NEWLINE | orjson.OPT_STRICT_INTEGER)
    except (
        orjson.JSONEncodeError
    ):  # ASCII escapes: a lone surrogate (from a reference file's "\ud83d") reads back as it was
        dropped: list[int] = []
        clean = _sanitize(record, dropped)
        if problems is not None and dropped:
            problems.append(f"{len(dropped)} integer(s) of more than {MAX_NUMBER_DIGITS} digits (up to {max(dropped)})")
        text = json.dumps(clean, default=_to_jsonable, allow_nan=False, ensure_ascii=True)
        return text.encode("ascii") + b"\n"


def write_json_atomic(path: str | os.PathLike[str], data: Mapping[str, Any]) -> None:
    """Write ``data`` as pretty JSON to ``path`` via a temporary file and ``os.replace``."""
    text = json.dumps(_sanitize(dict(data)), default=_to_jsonable, indent=2, allow_nan=False, ensure_ascii=False)
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:  # a lone surrogate (a reference prompt's "\ud83d"): ASCII escapes read back as it was
        text = json.dumps(_sanitize(dict(data)), default=_to_jsonable, indent=2, allow_nan=False, ensure_ascii=True)
    write_text_atomic(path, text + "\n")


def pid_alive(pid: int) -> bool:
    """Whether process ``pid`` exists (on this machine): leftovers of a killed writer are removed only when it is gone."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # it exists, owned by another user
        return True
    return True


def slugify(name: str) -> str:
    """A model string as a directory name: ``openai/gpt-4o`` -> ``openai--gpt-4o``."""
    slug = re.sub(r"[^A-Za-z0-9._-]+", "-", name.replace("/", "--").replace(":", "-")).strip("-.")
    return slug or "model"


def new_run_id(now: datetime | None = None) -> str:
    """A sortable, unique run id such as ``20261122T021700Z-3fa9c1``."""
    now = now or datetime.now(UTC)
    return f"{now.strftime('%Y%m%dT%H%M%SZ')}-{secrets.token_hex(3)}"


def _output_dir(path: Path) -> None:
    """``mkdir -p path``, or a :class:`RunStoreError` saying in one line why it cannot be."""
    for part in (path, *path.parents):
        if part.exists() and not part.is_dir():
            raise RunStoreError(
                f"cannot create the output directory {path}: {part} is a file, not a directory (choose another --output)"
            )
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RunStoreError(os_error_line(exc, "create the output directory") + " (choose another --output)") from None


def create_run_dir(
    output: str | os.PathLike[str],
    model: str,
    manifest: Mapping[str, Any],
    *,
    run_id: str | None = None,
    frame_ids: list[str] | None = None,
) -> Path:
    """Create ``<output>/<slug(model)>/<run_id>/`` with its manifest, an empty ``frames.jsonl`` and ``frame_ids.txt``.

    All or nothing: the files are written into a temporary directory that is then renamed into place.
    A disk that is full, a path that is a file, a directory without write permission: a one-line
    :class:`RunStoreError`, and nothing left behind.
    """
    parent = Path(output) / slugify(model)
    run_dir = parent / (run_id or new_run_id())
    if run_dir.exists():
        raise RunStoreError(f"run directory {run_dir} already exists; pass --resume {run_dir} to continue it")
    _output_dir(parent)
    full = {"format": FORMAT, "run_id": run_dir.name, **manifest}
    tmp: Path | None = None
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{run_dir.name}.", suffix=".tmp", dir=parent))
        write_json_atomic(tmp / MANIFEST_FILE, full)
        (tmp / FRAMES_FILE).touch()
        if frame_ids is not None:
            write_text_atomic(tmp / FRAME_IDS_FILE, "".join(f"{fid}\n" for fid in frame_ids))
        os.rename(tmp, run_dir)
        tmp = None
    except OSError as exc:
        raise RunStoreError(
            os_error_line(exc, "create the run directory") + f" (under {parent}); nothing was written"
        ) from None
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    return run_dir


def write_text_atomic(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` to ``path`` via a temporary file and ``os.replace``."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def read_frame_ids(run_dir: str | os.PathLike[str]) -> list[str] | None:
    """The run's frame set from ``frame_ids.txt``, or None for runs written without one."""
    path = Path(run_dir) / FRAME_IDS_FILE
    if not path.exists() and not path.is_symlink():
        return None
    text = read_small_text(path, MAX_SMALL_FILE_BYTES)
    return [line for line in text.splitlines() if line]


#: the largest manifest.json or frame_ids.txt read (a run of a million frames has a frame_ids.txt of ~60 MB)
MAX_SMALL_FILE_BYTES = 256 * 1024 * 1024


def read_small_text(path: Path, limit: int) -> str:
    """The UTF-8 text of a regular file of at most ``limit`` bytes, or a one-line :class:`RunStoreError`: a FIFO, a
    device (a link to ``/dev/zero``) or a larger file is never read (it would hang or fill the memory;
    :func:`lightemma._files.read_regular_file`)."""
    try:
        return read_regular_file(path, limit).decode("utf-8")
    except FileRefused as exc:
        if exc.kind == "too-large":
            raise RunStoreError(
                f"{path} is {exc.size:,} bytes, over the {limit:,} a run directory's file may be"
            ) from None
        if exc.kind == "grew":
            raise RunStoreError(f"{path} is over the {limit:,} bytes a run directory's file may be") from None
        raise RunStoreError(f"{path} {exc.reason}") from None  # is unreadable (…), is not a regular file (…)
    except UnicodeDecodeError as exc:
        raise RunStoreError(f"{path} is unreadable: {exc}") from None


class RunLock:
    """An OS file lock on a run directory for as long as this process writes it.

    ``flock`` on ``<run_dir>/.lock`` (through the ``filelock`` package): the kernel releases
    it when the process ends, however it ends, so a crash never leaves a stale lock. The
    holder's PID is written beside it (``.lock.pid``) for the message a second writer gets:
    a one-line :class:`RunStoreError` naming that PID. Use as a context manager.
    """

    def __init__(self, run_dir: str | os.PathLike[str]) -> None:
        self.run_dir = Path(run_dir)
        self._lock: Any = None

    def acquire(self) -> RunLock:
        from filelock import FileLock, Timeout

        lock = FileLock(self.run_dir / LOCK_FILE, thread_local=False)
        try:
            lock.acquire(timeout=0)
        except Timeout:
            raise RunStoreError(
                f"{self.run_dir} is being written by another lightemma process (PID {self.holder() or 'unknown'}); "
                "wait for it to finish (or stop it) before running this again"
            ) from None
        except OSError as exc:
            raise RunStoreError(os_error_line(exc, "lock the run directory")) from None
        self._lock = lock
        try:
            write_text_atomic(self.run_dir / LOCK_PID_FILE, f"{os.getpid()}\n")
        except OSError:
            pass  # the PID is only for messages; the lock itself holds
        return self

    def holder(self) -> int | None:
        """The PID recorded by the process holding the lock (None if it cannot be read)."""
        try:
            return int((self.run_dir / LOCK_PID_FILE).read_text(encoding="utf-8").strip())
        except (OSError, ValueError):
            return None

    def release(self) -> None:
        if self._lock is None:
            return
        try:
            (self.run_dir / LOCK_PID_FILE).unlink(missing_ok=True)
        except OSError:
            pass
        self._lock.release()
        self._lock = None

    def __enter__(self) -> RunLock:
        return self if self._lock is not None else self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


def read_manifest(run_dir: str | os.PathLike[str]) -> dict[str, Any]:
    """The manifest of a run directory; a clear :class:`RunStoreError` if it is missing or foreign."""
    run_dir = Path(run_dir)
    path = run_dir / MANIFEST_FILE
    if not run_dir.is_dir():
        raise RunStoreError(f"{run_dir} is not a directory (expected a lightemma run directory)")
    if not path.is_file():
        raise RunStoreError(f"{run_dir} is not a lightemma run directory: no {MANIFEST_FILE}")
    try:
        manifest = json.loads(read_small_text(path, MAX_SMALL_FILE_BYTES))
    except (json.JSONDecodeError, RecursionError) as exc:
        why = "nested too deeply" if isinstance(exc, RecursionError) else exc
        raise RunStoreError(f"{path} is unreadable: {why}") from None
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise RunStoreError(
            f"{path} is not a lightemma run manifest (format {manifest.get('format') if isinstance(manifest, dict) else None!r}, expected {FORMAT!r})"
        )
    return manifest


def update_manifest(run_dir: str | os.PathLike[str], **fields: Any) -> dict[str, Any]:
    """Merge ``fields`` into the manifest and rewrite it atomically; returns the new manifest."""
    manifest = read_manifest(run_dir)
    manifest.update(fields)
    write_json_atomic(Path(run_dir) / MANIFEST_FILE, manifest)
    return manifest


#: the longest line of frames.jsonl read (a record is a few KiB; its answers are bounded by the 8 MiB reply limit)
MAX_LINE_BYTES = 64 * 1024 * 1024


def _iter_lines(path: Path) -> Iterator[tuple[int, bytes | None, bool]]:
    """Yield (line number, raw line, complete) for each line of ``path``; a line longer than :data:`MAX_LINE_BYTES`
    is skipped unread (never held in memory) and yielded as ``None``."""
    with open(path, "rb") as fh:
        number = 0
        while True:
            raw = fh.readline(MAX_LINE_BYTES + 1)
            if not raw:
                return
            number += 1
            if len(raw) > MAX_LINE_BYTES and not raw.endswith(b"\n"):
                while raw and not raw.endswith(b"\n"):  # the rest of the line, a bounded chunk at a time
                    raw = fh.readline(1 << 20)
                yield number, None, bool(raw)
                continue
            yield number, raw, raw.endswith(b"\n")


@dataclass
class RunContents:
    """What :func:`read_run` found in a run directory."""

    run_dir: Path
    manifest: dict[str, Any]
    records: dict[str, dict[str, Any]]  # frame_id -> last record, in first-seen order
    corrupt_lines: list[int] = field(default_factory=list)
    truncated_tail: bool = False
    duplicates: int = 0
    corrupt_example: str | None = None  # why the first corrupt line was skipped ("line 7: status is ['ok'], …")

    @property
    def complete(self) -> bool:
        """True when the manifest says the run finished (``finished_at`` set)."""
        return bool(self.manifest.get("finished_at"))

    def warnings(self) -> list[str]:
        out = []
        if self.truncated_tail:
            out.append(f"{self.run_dir}: ignored a truncated last line (the run was interrupted)")
        if self.corrupt_lines:
            shown = ", ".join(map(str, self.corrupt_lines[:10]))
            out.append(
                f"{self.run_dir}: skipped {len(self.corrupt_lines)} corrupt line(s) of {FRAMES_FILE} (line {shown}{', …' if len(self.corrupt_lines) > 10 else ''})"
                + (f"; {self.corrupt_example}" if self.corrupt_example else "")
            )
        if not self.complete:
            out.append(f"{self.run_dir}: run not finished; using the {len(self.records)} frame(s) done so far")
        return out


def iter_records(run_dir: str | os.PathLike[str], *, counts: RunContents | None = None) -> Iterator[dict[str, Any]]:
    """Stream the records of ``frames.jsonl`` in file order (duplicates included), skipping bad lines.

    Bad lines are counted into ``counts`` when given (the first one's reason in ``counts.corrupt_example``): a line
    that is not a JSON object with a ``frame_id`` string, and one whose values are of the wrong kind or out of bounds
    (:func:`lightemma.runs.records.record_problem`: a status that is a list, seconds of -1e308, …). Memory stays
    flat in the number of frames.
    """
    path = Path(run_dir) / FRAMES_FILE
    if not path.is_file():
        raise RunStoreError(f"{Path(run_dir)} has no {FRAMES_FILE}")
    for number, raw, complete in _iter_lines(path):
        if not complete:
            if counts is not None:
                counts.truncated_tail = True
            continue
        if raw is None:
            if counts is not None:
                counts.corrupt_lines.append(number)
                if counts.corrupt_example is None:
                    counts.corrupt_example = f"line {number}: longer than {MAX_LINE_BYTES:,} bytes, not read"
            continue
        if not raw.strip():
            continue
        try:
            record = loads_bounded(raw)  # a line nested too deep or holding a 400-digit number is corrupt, not fatal
            problem = record_problem(record)
        except ValueError as exc:  # JSONDecodeError and UnicodeDecodeError included
            problem = f"not usable JSON ({str(exc)[:120]})"
        if problem is not None:
            if counts is not None:
                counts.corrupt_lines.append(number)
                if counts.corrupt_example is None:
                    counts.corrupt_example = f"line {number}: {problem}"
            continue
        yield record


def read_run(run_dir: str | os.PathLike[str]) -> RunContents:
    """Read a whole run: manifest plus the last record of each frame."""
    run_dir = Path(run_dir)
    contents = RunContents(run_dir=run_dir, manifest=read_manifest(run_dir), records={})
    for record in iter_records(run_dir, counts=contents):
        if record["frame_id"] in contents.records:
            contents.duplicates += 1
        contents.records[record["frame_id"]] = record
    return contents


def find_run_dirs(path: str | os.PathLike[str]) -> list[Path]:
    """Run directories at or below ``path`` (a run dir, a model dir or an output dir), sorted."""
    path = Path(path)
    if (path / MANIFEST_FILE).is_file():
        return [path]
    if not path.is_dir():
        if path.exists():
            raise RunStoreError(
                f"{path} is a file, not a run directory; give the folder that holds {MANIFEST_FILE} "
                f"({path.parent if path.name in (MANIFEST_FILE, FRAMES_FILE) else 'a run directory'})"
            )
        raise RunStoreError(f"{path} does not exist")
    # hidden directories are a run directory still being created (or one whose creation was cut off)
    return sorted(
        p.parent
        for p in path.glob(f"**/{MANIFEST_FILE}")
        if not any(part.startswith(".") for part in p.parent.relative_to(path).parts)
    )


class RunWriter:
    """Append whole lines to ``frames.jsonl``; safe to share between threads and asyncio tasks.

    Opening repairs a truncated last line left by a crash (it is cut off, since
    the frame it belonged to was not finished and will be redone).
    """

    def __init__(
        self, run_dir: str | os.PathLike[str], *, fsync: bool = False, log: Callable[[str], None] | None = None
    ) -> None:
        self.path = Path(run_dir) / FRAMES_FILE
        self._fsync = fsync
        self.log = log  # where the one warning about values recorded as unknown goes (else stderr)
        self.unknown_values = 0  # records written with a value out of kind or range replaced by null
        self._lock = threading.Lock()
        self.repaired_bytes = self._repair_tail()
        self._fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)

    def _repair_tail(self) -> int:
        if not self.path.exists():
            return 0
        size = self.path.stat().st_size
        if size == 0:
            return 0
        with open(self.path, "rb+") as fh:
            fh.seek(-1, os.SEEK_END)
            if fh.read(1) == b"\n":
                return 0
            # find the last newline; everything after it is a fragment
            block = 1 << 16
            pos = size
            keep = 0
            while pos > 0:
                start = max(0, pos - block)
                fh.seek(start)
                chunk = fh.read(pos - start)
                idx = chunk.rfind(b"\n")
                if idx >= 0:
                    keep = start + idx + 1
                    break
                pos = start
            fh.truncate(keep)
            return size - keep

    def append(self, record: Mapping[str, Any]) -> None:
        """Write one record as one complete line (a single ``write`` call) and flush it.

        A token count, time or cost out of kind or range is written as null (:func:`encode_line`); the first such
        record of this writer is named in one warning line (``log``, else stderr), the rest are counted in ``unknown_values``.
        """
        problems: list[str] = []
        data = encode_line(record, problems)
        if len(data) > MAX_LINE_BYTES:  # a line no reader would read back: refused, never written to be skipped later
            raise RecordTooLargeError(
                f"frame {str(record.get('frame_id'))[:120]!r}: its record is {len(data):,} bytes, over "
                f"the {MAX_LINE_BYTES:,} a line of {FRAMES_FILE} may be"
            )
        if problems:
            self._warn_unknown(record, problems)
        with self._lock:
            view = memoryview(data)
            while view:
                written = os.write(self._fd, view)
                view = view[written:]
            if self._fsync:
                os.fsync(self._fd)

    def _warn_unknown(self, record: Mapping[str, Any], problems: list[str]) -> None:
        with self._lock:
            self.unknown_values += 1
            if self.unknown_values > 1:
                return
        line = (
            f"warning: {self.path}: frame {record.get('frame_id')!r}: {'; '.join(problems[:3])}{'; …' if len(problems) > 3 else ''} "
            "— recorded as unknown (null); later records with such values are not named"
        )
        if self.log is not None:
            self.log(line)
        else:
            import sys

            print(f"lightemma: {line}", file=sys.stderr, flush=True)

    def close(self) -> None:
        with self._lock:
            if self._fd >= 0:
                os.close(self._fd)
                self._fd = -1

    def __enter__(self) -> RunWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
