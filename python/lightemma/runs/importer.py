"""``lightemma import``: reference result folders become lightemma runs.

One run per model folder, at ``<output>/<model>/ref-<hash>/``, in the normal run
format (``manifest.json`` + ``frames.jsonl``, the record fields the chain writes),
so that ``evaluate``, ``report``, ``--common`` and the figures read it as any run.

* **Identity.** A folder's identity is the SHA-256 of its scene files (names and
  bytes), recorded in the manifest as ``imported.source_hash``; the run id is
  derived from it. Importing the same folder again finds the run and writes
  nothing.
* **Atomic.** A run is built in a hidden temporary folder beside its final
  place and renamed into place only when complete; any failure removes it.
* **Checked.** Frames are checked by :mod:`lightemma.runs.reference`; a file or
  frame that fails is named in a warning and skipped, never scored.
* **As the paper scored it.** The stage-3 answer is parsed with
  ``mode="paper"`` (the paper's FE / FE corr rules) and integrated with Euler;
  the manifest says so, and ``evaluate`` uses that definition by default.
* **Prompts.** Every prompt the reference sent is kept, exactly: the text each
  stage's prompts share once in the manifest (``prompt_set.templates``), each
  frame's own part in its calls (:mod:`lightemma.runs.stored_prompts`).
"""

from __future__ import annotations

import hashlib
import math
import os
import re
import secrets
import shutil
import signal
import sys
import threading
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from lightemma import __version__
from lightemma._signals import stop_signals
from lightemma._text import unicode_clean
from lightemma.actions import history_rows, parse_actions
from lightemma.errors import UserError
from lightemma.frames.fingerprint import of_dataset
from lightemma.kinematics import integrate
from lightemma.models.catalog import ModelInfo, reference_model
from lightemma.models.names import infer_family
from lightemma.models.prices import price_per_token
from lightemma.runs.columns import RecordColumns, source_key, write_sidecar
from lightemma.runs.records import bounded_values, gc_paused, loads_bounded
from lightemma.runs.reference import (
    SOURCE_FORMAT,
    WINDOW_OFFSET,
    ModelFolder,
    ReferenceFileError,
    ReferenceFrame,
    SceneFile,
    StageCall,
    find_model_folders,
    iter_scene_files,
    read_regular_file,
)
from lightemma.runs.schema import CallRecord, FrameRecord, attempt_record, call_record, frame_record
from lightemma.runs.store import (
    FORMAT,
    FRAMES_FILE,
    MANIFEST_FILE,
    encode_line,
    pid_alive,
    read_manifest,
    slugify,
    write_json_atomic,
)
from lightemma.runs.stored_prompts import PromptTemplates

IMPORT_PARSE = {"mode": "paper"}  # how an imported run is scored unless evaluate is told otherwise
IMPORT_INTEGRATOR = "euler"
CALL_FAILURE = "ReferenceCallError"  # error class of a call whose "text" is the reference's error message
DATASET_KINDS = ("nuscenes", "synthetic")
MAX_FRAME_WARNINGS = 20  # per file; the rest are counted in one line
DUPLICATE_EXAMPLES = 3  # frame ids named in the one line about a file's frames already read from another file
TRAJECTORY_TOLERANCE = 1e-6  # metres: the reference's own stored trajectory vs ours

Warn = Callable[[str], None]


@dataclass
class ImportResult:
    """What importing one model folder did."""

    source: Path
    model: str  # the model string of the run (registry key, or the source name)
    run_dir: Path
    outcome: str  # "imported" | "already imported" | "nothing to import"
    frames: int = 0
    files: int = 0
    files_skipped: int = 0
    frames_skipped: int = 0
    summary: dict[str, Any] = field(default_factory=dict)

    def describe(self) -> str:
        """One line for the terminal."""
        if self.outcome == "already imported":
            return f"{self.source}: already imported as {self.run_dir}; nothing written"
        if self.outcome == "nothing to import":
            return f"{self.source}: no usable frame in {self.files} scene file(s); no run written"
        s = self.summary
        skipped = (
            f", skipped {self.files_skipped} file(s) and {self.frames_skipped} frame(s)"
            if self.files_skipped or self.frames_skipped
            else ""
        )
        fe = (
            f"FE {s['fe_percent']:.2f} %, FE corr {s['fe_corr_percent']:.2f} %"
            if s.get("fe_percent") is not None
            else "no answer received"
        )
        return f"{self.source}: {self.frames} frame(s) from {self.files} scene file(s) → {self.run_dir} ({fe}, paper rules{skipped})"


def source_hash(files: Sequence[Path], root: Path) -> str:
    """``sha256:<hex>`` over the scene files' names (relative to ``root``) and bytes, in name order."""
    digest = hashlib.sha256(SOURCE_FORMAT.encode())
    for path in files:
        try:
            content = hashlib.sha256(read_regular_file(path)).hexdigest()
        except ReferenceFileError as exc:  # changed since it was listed: skipped (and named) when read
            content = f"unreadable: {exc}"
        digest.update(
            b"\0" + os.fsencode(path.relative_to(root).as_posix()) + f"\0{content}".encode()
        )  # names as bytes
    return "sha256:" + digest.hexdigest()


def _model(folder: ModelFolder, metadata_model: str | None) -> tuple[str, ModelInfo | None]:
    """The run's model string and registry entry: from the folder name, else the files' metadata."""
    for name in (folder.model_name, metadata_model):
        info = reference_model(name) if name else None
        if info is not None:
            return info.key, info
    return folder.model_name, None


def _first_metadata_model(folder: ModelFolder) -> str | None:
    """``metadata.model`` of the first scene file that has one (read only when the folder name is not known)."""
    for path in folder.files[:5]:
        try:
            doc = loads_bounded(read_regular_file(path))
        except (ReferenceFileError, ValueError):
            continue
        model = (
            doc.get("metadata", {}).get("model")
            if isinstance(doc, dict) and isinstance(doc.get("metadata"), dict)
            else None
        )
        if isinstance(model, str) and model:
            return model
    return None


def _existing(model_dir: Path, digest: str) -> Path | None:
    """A run under ``model_dir`` imported from the same source files, if any."""
    for manifest_path in sorted(model_dir.glob(f"*/{MANIFEST_FILE}")):
        try:
            manifest = read_manifest(manifest_path.parent)
        except UserError:
            continue
        if (manifest.get("imported") or {}).get("source_hash") == digest:
            return manifest_path.parent
    return None


def _prices(info: ModelInfo | None) -> tuple[float, float] | None:
    """USD per (input, output) token for a priced API model of the registry, else None."""
    if info is None or info.backend != "api":
        return None
    return price_per_token(info)


def _sum_known(values: Iterable[Any]) -> Any:
    """The sum, or None (unknown) when a value is unknown or the sum is not finite (seconds near 1e308 each)."""
    values = list(values)
    if None in values:
        return None
    total = sum(values)
    return total if math.isfinite(total) else None


def _call_record(call: StageCall, prices: tuple[float, float] | None, prompt: dict[str, Any]) -> CallRecord:
    cost = None
    if prices is not None and call.input_tokens is not None and call.output_tokens is not None:
        cost = (call.input_tokens * prices[0] + call.output_tokens * prices[1]) * 100.0
    return call_record(
        stage=call.stage,
        **prompt,  # the prompt whole, or its template and this frame's fill (lightemma.runs.stored_prompts)
        text=None if call.call_failed else call.text,
        error=CALL_FAILURE if call.call_failed else None,
        error_message=call.text if call.call_failed else None,
        input_tokens=call.input_tokens,
        output_tokens=call.output_tokens,
        seconds=call.seconds,
        cost_cents=cost,
        cached=False,
        retries=0,
        finish_reason=None,
        reasoning_tokens=None,
        cached_input_tokens=None,
    )


def _record(
    frame: ReferenceFrame,
    source_file: str,
    parse: tuple[str, str, str] | None,
    actions: Any,
    trajectory: Any,
    prices: tuple[float, float] | None,
    templates: PromptTemplates,
) -> FrameRecord:
    """The run record of one frame (the chain's fields, plus what only the reference has)."""
    texts = {"scene": frame.calls[0].text, "intent": frame.calls[1].text}  # as the reference had them, failed calls too
    calls = [_call_record(c, prices, templates.encode(c.stage, c.prompt, texts)) for c in frame.calls]
    totals = {
        "input_tokens": _sum_known(c["input_tokens"] for c in calls),
        "output_tokens": _sum_known(c["output_tokens"] for c in calls),
        "seconds": _sum_known(c["seconds"] for c in calls),
        "cost_cents": _sum_known(c["cost_cents"] for c in calls),
    }
    if parse is None:  # the stage-3 call failed: no answer was received
        status, reason, failure, answer, error = "failed", f"API error: {CALL_FAILURE}", "api_error", None, CALL_FAILURE
    else:
        (status, reason, failure), answer, error = parse, frame.answer, None
    attempt = attempt_record(
        attempt=1, calls=calls, answer=answer, status=status, reason=reason, failure=failure, error=error, **totals
    )
    scene_text, intent_text = (None if c.call_failed else c.text for c in frame.calls[:2])
    return frame_record(
        frame_id=frame.frame_id,
        scene_name=frame.scene_name,
        sample_token=frame.sample_token,
        status=status,
        first_status=status,
        failure=failure,
        n_attempts=1,
        attempts=[attempt],
        actions=actions,
        trajectory=trajectory,
        gt_positions=frame.gt_positions,
        history_actions=frame.history_actions,
        history_positions=frame.history_positions,
        gt_actions=frame.gt_actions,
        scene_text=scene_text,
        intent_text=intent_text,
        answer=answer,
        error=error,
        seconds=totals["seconds"],
        call_seconds=totals["seconds"],
        input_tokens=totals["input_tokens"],
        output_tokens=totals["output_tokens"],
        cost_cents=totals["cost_cents"],
        cached=False,
        cached_calls=0,
        retries=0,
        keyframe_index=None if frame.frame_index is None else frame.frame_index + WINDOW_OFFSET,
        timestamp=frame.timestamp,
        image_name=frame.image_name,
        image_path=frame.image_path,
        camera_params=frame.camera,
        ego_position=frame.position,
        ego_heading=frame.heading,
        source={"file": source_file, "frame_index": frame.frame_index},
    )


class _Tally:
    """Counts for the manifest summary."""

    def __init__(self) -> None:
        self.status = {"ok": 0, "corrected": 0, "failed": 0}
        self.api_errors = 0
        self.received = 0
        self.first_not_ok = 0
        self.first_failed = 0

    def add(self, record: Mapping[str, Any]) -> None:
        self.status[record["status"]] += 1
        if record["failure"] == "api_error":
            self.api_errors += 1
            return
        self.received += 1
        self.first_not_ok += record["status"] != "ok"
        self.first_failed += record["status"] == "failed"

    def summary(self) -> dict[str, Any]:
        n = sum(self.status.values())
        pct = (lambda k: 100.0 * k / self.received) if self.received else (lambda k: None)
        return {
            "frames": n,
            **self.status,
            "api_errors": self.api_errors,
            "answers_received": self.received,
            "fe_percent": pct(self.first_not_ok),
            "fe_corr_percent": pct(self.first_failed),
            "parse": dict(IMPORT_PARSE),
        }


def _scene_records(
    scene: SceneFile, prices: tuple[float, float] | None, warn: Warn, templates: PromptTemplates
) -> list[FrameRecord]:
    """Records of one scene file's frames: answers parsed in one batch, trajectories integrated in one."""
    frames = scene.frames
    received = [i for i, f in enumerate(frames) if not f.calls[-1].call_failed]
    parses: list[tuple[str, str, str] | None] = [None] * len(frames)
    actions: list[Any] = [None] * len(frames)
    trajectories: list[Any] = [None] * len(frames)
    if received:
        parsed = parse_actions(
            [frames[i].answer for i in received],
            n=6,
            mode=IMPORT_PARSE["mode"],
            history=history_rows(frames[i].history_actions for i in received),
        )
        ok = parsed.status != "failed"
        paths = integrate(np.where(ok[:, None, None], parsed.actions, 0.0), method=IMPORT_INTEGRATOR)
        mismatched, worst = 0, 0.0
        for j, i in enumerate(received):
            parses[i] = (str(parsed.status[j]), str(parsed.reason[j]), str(parsed.failure[j]))
            if ok[j]:
                actions[i] = parsed.actions[j].tolist()
                if not np.isfinite(paths[j]).all():  # numbers so large that the positions overflow
                    warn(
                        f"{scene.path}: frame {frames[i].frame_index}: its actions integrate to non-finite positions; "
                        "recorded without a trajectory, never scored"
                    )
                    continue
                trajectories[i] = paths[j].tolist()
                theirs = frames[i].reference_trajectory
                if parsed.status[j] == "ok" and _is_6x2(theirs):
                    gap = float(np.abs(np.asarray(theirs, dtype=np.float64) - paths[j]).max())
                    if gap > TRAJECTORY_TOLERANCE:
                        mismatched, worst = mismatched + 1, max(worst, gap)
        if mismatched:
            warn(
                f"{scene.path}: {mismatched} frame(s) whose stored predictions.trajectory differs from the Euler "
                f"integration of their answer (up to {worst:.3g} m); the answer is what is scored"
            )
    return [
        _record(f, unicode_clean(scene.path.name), parses[i], actions[i], trajectories[i], prices, templates)
        for i, f in enumerate(frames)
    ]


def _is_6x2(value: Any) -> bool:
    try:
        return np.asarray(value, dtype=np.float64).shape == (6, 2)
    except (TypeError, ValueError):
        return False


def _report_problems(scene: SceneFile, warn: Warn) -> None:
    for problem in scene.problems[:MAX_FRAME_WARNINGS]:
        warn(f"{scene.path.parent}/{problem}; frame skipped")
    if len(scene.problems) > MAX_FRAME_WARNINGS:
        warn(
            f"{scene.path}: {len(scene.problems) - MAX_FRAME_WARNINGS} more frame(s) skipped for the same kinds of reason"
        )
    soft = [f for f in scene.frames if f.soft_problems]
    if soft:
        first = soft[0]
        warn(
            f"{scene.path}: {len(soft)} frame(s) with unreadable token or time counts, recorded as unknown "
            f"(frame {first.frame_index}: {'; '.join(first.soft_problems)})"
        )


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


def _manifest(
    folder: ModelFolder,
    model: str,
    info: ModelInfo | None,
    digest: str,
    run_id: str,
    metadata_model: str | None,
    stamp: str | None,
    scenes: list[str],
    tally: _Tally,
    files_skipped: list[str],
    frames_skipped: int,
    dataset_kind: str,
    prices: tuple[float, float] | None,
    templates: PromptTemplates,
) -> dict[str, Any]:
    return {
        "format": FORMAT,
        "run_id": run_id,
        "model": model,
        "display_name": info.display_name if info else model,
        "model_info": info.to_dict() if info else None,
        "family": info.family if info else infer_family(model),
        "imported": {
            "format": SOURCE_FORMAT,
            "from": unicode_clean(os.fspath(folder.path.resolve())),
            "source_model": folder.model_name,
            "source_folder": folder.folder_name,
            "metadata_model": metadata_model,
            "registry_model": info.key if info else None,
            "reference_timestamp": stamp,
            "source_hash": digest,
            "files": len(folder.files),
            "files_skipped": files_skipped,
            "frames_skipped": frames_skipped,
            "imported_at": _now(),
        },
        "backend": {
            "kind": "imported",
            "gpus": info.gpus if info else None,
            "token_counting": "provider-reported, as the reference scripts stored them",
            "cost": "registry price × stored tokens" if prices else None,
        },
        "params": {
            "integrate_method": IMPORT_INTEGRATOR,
            "parse": dict(IMPORT_PARSE),
            "reask": None,
            "max_attempts": 1,
        },
        "integrator": IMPORT_INTEGRATOR,
        # the reference's prompts: each stage's shared text once here, each frame's own part in its calls
        "prompt_set": {
            "name": "reference scripts (prompts stored per frame)",
            "hash": None,
            "templates": templates.to_manifest(),
        },
        "dataset": {
            "kind": dataset_kind,
            "dataroot": None,
            "version": None,
            "split": None,
            "scenes": scenes,
            "window": "reference",
            "n_frames": sum(tally.status.values()),
        },
        "lightemma_version": __version__,
        "started_at": None,
        "finished_at": _now(),
        "summary": {
            **tally.summary(),
            "files": len(folder.files) - len(files_skipped),
            "files_skipped": len(files_skipped),
            "frames_skipped": frames_skipped,
        },
    }


def import_folder(
    folder: ModelFolder,
    output: str | os.PathLike[str],
    *,
    dataset_kind: str = "nuscenes",
    warn: Warn = lambda _: None,
    on_file: Callable[[], None] = lambda: None,
) -> ImportResult:
    """Import one model folder into ``output``; see the module docstring. Returns what was done."""
    if dataset_kind not in DATASET_KINDS:
        raise UserError(f"--dataset-kind must be one of {', '.join(DATASET_KINDS)}, got {dataset_kind!r}")
    known = reference_model(folder.model_name)
    metadata_model = None if known is not None else _first_metadata_model(folder)
    model, info = _model(folder, metadata_model)
    digest = source_hash(folder.files, folder.path)
    run_id = "ref-" + digest.split(":", 1)[1][:12]
    model_dir = Path(output) / slugify(model)
    final = model_dir / run_id
    result = ImportResult(source=folder.path, model=model, run_dir=final, outcome="imported", files=len(folder.files))
    found = _existing(model_dir, digest) if model_dir.is_dir() else None
    if found is not None:
        result.run_dir, result.outcome = found, "already imported"
        for _ in folder.files:
            on_file()
        return result
    if final.exists():
        raise UserError(f"{final} exists but was not imported from {folder.path}; move it away and import again")
    prices = _prices(info)
    created = [d for d in (model_dir, *model_dir.parents) if not d.exists()]  # removed again if no run comes of it
    # The partial folder is named before it is made, and every folder is made inside the ``try``: a stop signal raises
    # Interrupted at the first instruction after a ``mkdir``, and the cleanup below already knows what to remove.
    tmp = model_dir / f".{run_id}.{os.getpid()}.{secrets.token_hex(8)}{PARTIAL_SUFFIX}"
    try:
        model_dir.mkdir(parents=True, exist_ok=True)
        remove_stale_partials(model_dir, warn)
        tmp.mkdir(mode=0o700)  # 64 random bits after this process's pid: no other import makes this name
        tally, scenes, seen, templates = _Tally(), [], set(), PromptTemplates()
        files_skipped: list[str] = []
        for entry, why in folder.skipped:
            warn(f"{entry}: {why}; file skipped")
            files_skipped.append(unicode_clean(entry.name))
        frames_skipped = 0
        stamp = None
        columns = RecordColumns()  # the evaluation sidecar, from the records in hand (no second read)
        with open(tmp / FRAMES_FILE, "wb") as fh, gc_paused():  # scene files are trees without cycles
            for path, scene in iter_scene_files(folder):
                on_file()
                if isinstance(scene, ReferenceFileError):
                    warn(f"{path}: {scene}; file skipped")
                    files_skipped.append(unicode_clean(path.name))
                    continue
                _report_problems(scene, warn)
                frames_skipped += len(scene.problems)
                stamp = stamp or scene.timestamp
                metadata_model = metadata_model or scene.metadata_model
                lines = []
                unknown_named = False
                duplicates: list[str] = []
                for built in _scene_records(scene, prices, warn, templates):
                    if built["frame_id"] in seen:
                        duplicates.append(built["frame_id"])
                        frames_skipped += 1
                        continue
                    seen.add(built["frame_id"])
                    problems: list[str] = []
                    record = bounded_values(
                        built, problems
                    )  # what frames.jsonl will hold, for the tally and the sidecar too
                    if problems and not unknown_named:  # a frame's totals beyond the bounds (each call was within them)
                        unknown_named = True
                        warn(
                            f"{path}: frame {record['frame_id']}: {'; '.join(problems[:3])}; recorded as unknown "
                            "(later frames of this file with such values are not named)"
                        )
                    tally.add(record)
                    columns.add(record)
                    lines.append(encode_line(record, bounded=True))
                if duplicates:  # one line per file, however many frames it repeats
                    first = ", ".join(duplicates[:DUPLICATE_EXAMPLES])
                    more = (
                        f" (first {DUPLICATE_EXAMPLES}: {first})"
                        if len(duplicates) > DUPLICATE_EXAMPLES
                        else f" ({first})"
                    )
                    warn(f"{path}: {len(duplicates)} frame(s) already read from another file{more}; skipped")
                if lines:
                    scenes.append(scene.scene_name)
                    fh.write(b"".join(lines))
        result.frames, result.files_skipped, result.frames_skipped = len(seen), len(files_skipped), frames_skipped
        if not seen:
            shutil.rmtree(tmp)
            _remove_empty(created)
            result.outcome = "nothing to import"
            return result
        manifest = _manifest(
            folder,
            model,
            info,
            digest,
            run_id,
            metadata_model,
            stamp,
            sorted(set(scenes)),
            tally,
            files_skipped,
            frames_skipped,
            dataset_kind,
            prices,
            templates,
        )

        manifest["dataset"]["fingerprint"] = {
            **of_dataset(manifest["dataset"], seen),
            "derived": True,
            "from": "import",
        }
        write_json_atomic(tmp / MANIFEST_FILE, manifest)
        write_sidecar(tmp, columns.finish(), source_key(tmp))
        os.rename(tmp, final)
        result.summary = manifest["summary"]
        return result
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        _remove_empty(created)
        raise


PARTIAL_SUFFIX = ".partial"
_PARTIAL = re.compile(
    r"^\.ref-[0-9a-f]{12}\.(\d+)\.[A-Za-z0-9_]+\.partial$"
)  # .<run id>.<pid of the importer>.<random>.partial


def remove_stale_partials(model_dir: Path, warn: Warn = lambda _: None) -> list[Path]:
    """Remove the hidden ``.ref-….partial`` folders that a killed import left in ``model_dir``.

    A partial folder is named after the process building it; it is removed when
    that process no longer exists (an import still running elsewhere keeps its own).
    Returns the folders removed (each named through ``warn``).
    """
    removed = []
    for entry in model_dir.iterdir():
        match = _PARTIAL.match(entry.name)
        if match is None or not entry.is_dir() or entry.is_symlink():
            continue
        pid = int(match.group(1))
        if pid == os.getpid() or pid_alive(pid):
            continue
        shutil.rmtree(entry, ignore_errors=True)
        if not entry.exists():
            warn(f"{entry}: removed what an interrupted import (process {pid}) left half-written")
            removed.append(entry)
    return removed


def _remove_empty(folders: list[Path]) -> None:
    """Remove the folders an import created (innermost first) where they are still empty."""
    for folder in folders:
        try:
            folder.rmdir()
        except OSError:
            return


def _import_quietly(folder: ModelFolder, output: str, dataset_kind: str) -> tuple[ImportResult, list[str]]:
    """One folder in a worker process: its result and its warnings (printed by the parent, in order)."""
    warnings: list[str] = []
    return import_folder(folder, output, dataset_kind=dataset_kind, warn=warnings.append), warnings


def _die_with_parent(parent: int) -> None:
    """Worker initializer: the worker ends when the importing process does, however it ends (SIGKILL included).

    On Linux the kernel sends SIGKILL to the worker when its parent dies
    (``PR_SET_PDEATHSIG``); elsewhere, and as a second guard, a daemon thread
    ends the worker once its parent process is gone (its parent pid changes).
    """
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, signal.SIGKILL, 0, 0, 0)  # PR_SET_PDEATHSIG = 1
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent:  # the parent died before the prctl took effect
        os._exit(1)
    for name in ("SIGINT", "SIGHUP"):  # sent to the whole process group (Ctrl-C, a closed terminal): the parent stops
        if hasattr(signal, name):  # the import, kills its workers and removes their partial folders (SIGTERM is left
            signal.signal(getattr(signal, name), signal.SIG_IGN)  # as it is: a broken pool ends its workers with it)

    def watch() -> None:
        while os.getppid() == parent:
            threading.Event().wait(0.5)
        os._exit(1)

    threading.Thread(target=watch, daemon=True, name="lightemma-import-parent-watch").start()


def _stop_resource_tracker() -> None:
    """Stop and reap the resource-tracker process the spawned pool started, which would otherwise outlive
    the command for a moment (a leftover child); a later pool starts a new one."""
    try:
        from multiprocessing import resource_tracker

        resource_tracker._resource_tracker._stop()  # type: ignore[attr-defined]  # noqa: SLF001 - private, not typed
    except (AttributeError, OSError, ChildProcessError):
        pass


def default_jobs(folders: int) -> int:
    """Worker processes for ``folders`` model folders: one per folder, at most the CPUs and at most 4 (memory)."""
    return max(1, min(folders, os.cpu_count() or 1, 4))


def import_reference(
    sources: Iterable[str | os.PathLike[str]],
    output: str | os.PathLike[str] = "runs",
    *,
    dataset_kind: str = "nuscenes",
    warn: Warn = lambda _: None,
    progress: bool = False,
    jobs: int = 1,
) -> list[ImportResult]:
    """Import reference result folders (each a model folder or a folder holding several) into ``output``.

    Returns one :class:`ImportResult` per model folder. Skipped files and frames
    are passed to ``warn`` (one line each). ``jobs`` > 1 imports that many model
    folders at once in worker processes (see :func:`default_jobs`). Raises
    :class:`UserError` when a source holds no reference results.
    """
    if dataset_kind not in DATASET_KINDS:
        raise UserError(f"--dataset-kind must be one of {', '.join(DATASET_KINDS)}, got {dataset_kind!r}")
    if jobs < 1:
        raise UserError(f"--jobs must be at least 1, got {jobs}")
    folders = [f for src in sources for f in find_model_folders(src)]
    if not folders:
        raise UserError("no source folder given")
    from tqdm import tqdm

    bar = tqdm(
        total=sum(len(f.files) for f in folders), unit="file", desc="import", disable=not progress, dynamic_ncols=True
    )

    def say(line: str) -> None:
        bar.clear()
        warn(line)

    results: list[ImportResult] = []
    workers: list[Any] = []  # the worker processes (jobs > 1), for the stop-signal handler and the cleanup
    try:
        with stop_signals(lambda signum: _exit_now(workers, signum)):  # Interrupted: the caller stops the workers
            if jobs == 1 or len(folders) == 1:
                for f in folders:  # a stop signal inside import_folder removes its partial folder there
                    results.append(
                        import_folder(f, output, dataset_kind=dataset_kind, warn=say, on_file=lambda: bar.update(1))
                    )
                return results
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor

            context = multiprocessing.get_context("spawn")  # no fork of a process with threads (the progress bar's)
            pool = ProcessPoolExecutor(
                max_workers=min(jobs, len(folders)),
                mp_context=context,
                initializer=_die_with_parent,
                initargs=(os.getpid(),),
            )
            futures: list[Any] = []
            try:
                for f in folders:
                    futures.append(pool.submit(_import_quietly, f, os.fspath(output), dataset_kind))
                    workers[:] = _pool_processes(pool, workers)
                for folder, future in zip(folders, futures):
                    result, warnings = future.result()
                    for line in warnings:
                        say(line)
                    bar.update(len(folder.files))
                    results.append(result)
            except KeyboardInterrupt:  # Ctrl-C, SIGTERM, SIGHUP: stop the workers now, before they write more runs
                _stop_workers(pool, _pool_processes(pool, workers), futures, output)
                results += [
                    f.result()[0]
                    for f in futures[len(results) :]
                    if f.done() and not f.cancelled() and f.exception() is None
                ]
                raise
            finally:
                pool.shutdown(wait=True)
                _stop_resource_tracker()
            return results
    except KeyboardInterrupt as exc:  # the caller learns how far the import got (the CLI says so in one line)
        exc.runs_done, exc.runs_total = len(results), len(folders)  # type: ignore[attr-defined]  # for cli/import_
        raise
    finally:
        bar.close()


def _pool_processes(pool: Any, known: Sequence[Any] = ()) -> list[Any]:
    """The worker processes of ``pool`` (those in ``known`` too: the pool forgets them once it is broken)."""
    found = {p.pid: p for p in known}
    found.update({p.pid: p for p in list((getattr(pool, "_processes", None) or {}).values())})  # noqa: SLF001
    return list(found.values())


def _kill(processes: Iterable[Any]) -> None:
    """SIGKILL each process (a worker dies at once, between two of its writes; its partial folder is left to remove)."""
    for process in processes:
        try:
            process.kill()
        except (OSError, ValueError, AttributeError):
            pass


def _stop_workers(pool: Any, processes: Sequence[Any], futures: Sequence[Any], output: str | os.PathLike[str]) -> None:
    """An interrupted parallel import: cancel what has not started, kill the workers, wait for them, remove the
    partial folders they were building (named after their pids), leave the runs already renamed into place."""
    for future in futures:
        future.cancel()
    _kill(processes)
    for process in processes:
        try:
            process.join(timeout=10)
        except (OSError, ValueError, AssertionError):
            pass
    pool.shutdown(wait=True, cancel_futures=True)
    remove_partials_of({p.pid for p in processes if p.pid is not None}, output)


def remove_partials_of(pids: set[int], output: str | os.PathLike[str]) -> list[Path]:
    """Remove the ``.ref-….partial`` folders under ``output/<model>/`` that the processes ``pids`` were building
    (and a model folder that only held one). Returns the folders removed."""
    removed: list[Path] = []
    root = Path(output)
    try:
        model_dirs = [d for d in root.iterdir() if d.is_dir() and not d.is_symlink()]
    except OSError:
        return removed
    for model_dir in model_dirs:
        try:
            entries = list(model_dir.iterdir())
        except OSError:
            continue
        for entry in entries:
            match = _PARTIAL.match(entry.name)
            if match is None or int(match.group(1)) not in pids or entry.is_symlink() or not entry.is_dir():
                continue
            shutil.rmtree(entry, ignore_errors=True)
            if not entry.exists():
                removed.append(entry)
                _remove_empty([model_dir])
    return removed


def _exit_now(workers: Sequence[Any], signum: int) -> None:
    """A second stop signal during an import: kill the workers, say so in one line, exit 128 + the signal at once (the
    next import removes what is left half-written)."""
    _kill(workers)
    os.write(
        2,
        f"lightemma import: {signal.Signals(signum).name} again: exiting now; "
        "run the same command again to import the rest\n".encode(),
    )
    os._exit(128 + signum)
