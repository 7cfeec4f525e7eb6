"""What evaluation reads from a run's manifest, defensively (missing keys are None).

Manifests written by the run pipeline carry ``display_name``, ``model_info``
(family, generation, GPUs), ``backend``, ``config`` (integrate method,
concurrency), ``sessions`` (wall time of each run/resume) and ``dataset``;
older or foreign manifests may lack any of them. The display name and family
fall back to the paper's models (:mod:`lightemma.models.names`) or the
model string.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

from lightemma.frames.model import SYNTH_MARKER
from lightemma.models.names import FAMILIES, infer_family, known_model
from lightemma.runs.store import read_manifest


@dataclass(frozen=True)
class RunInfo:
    """What a manifest says about a run; missing keys are None."""

    run_dir: Path
    model: str
    label: str
    family: str
    generation: int | None
    gpus: int | None
    integrator: str
    wall_seconds: float | None
    concurrency: int | None
    complete: bool
    dataset: Mapping[str, Any] | None
    manifest: Mapping[str, Any]
    imported: bool = False  # made by `lightemma import` from the reference scripts' results
    dataset_kind: str | None = None  # "nuscenes", "synthetic", or None when the manifest cannot tell
    chain: str = "independent"  # request variant: independent stages (the paper's) or one conversation
    answer_format: str = "text"  # stage-3 answers as text (the paper's) or structured JSON
    name: str | None = None  # the run's name (``lightemma run --name``), shown instead of its id
    batch: bool = False  # run through a provider's batch API (``--batch``): per-frame latency has no meaning
    batch_turnaround_s: float | None = None  # mean seconds from a batch's submission to its results
    inputs: str = "full"  # input ablation (lightemma.inputs): full (the paper's), no-image, blank-image, no-history

    @property
    def variant(self) -> str:
        """The request variant in words, e.g. ``independent, text`` (the paper's) or ``conversation, structured``."""
        return f"{self.chain}, {self.answer_format}"


def _get(mapping: Any, *keys: str) -> Any:
    for key in keys:
        if not isinstance(mapping, Mapping):
            return None
        mapping = mapping.get(key)
    return mapping


def _as_int(value: Any) -> int | None:
    try:
        return int(value) if value is not None else None
    except (TypeError, ValueError):
        return None


def _parse_time(value: Any) -> datetime | None:
    if not isinstance(value, str):
        return None
    try:
        return datetime.fromisoformat(value.replace("Z", "+00:00"))
    except ValueError:
        return None


def _wall_seconds(manifest: Mapping[str, Any]) -> float | None:
    """Run wall time: the sum over sessions (a resumed run has several), else what the manifest says.

    A session that records no wall time (killed, interrupted, or still running) makes the run's
    wall time unknown (None): the last session's time, which the summary holds, is not the run's.
    """
    sessions = manifest.get("sessions")
    if isinstance(sessions, list):
        walls = [s.get("wall_seconds") for s in sessions if isinstance(s, Mapping)]
        if walls:
            numbers = [w for w in walls if isinstance(w, (int, float)) and not isinstance(w, bool)]
            if len(numbers) == len(walls) and sum(numbers) > 0:
                return float(sum(numbers))
            return None
    for value in (manifest.get("wall_seconds"), _get(manifest, "summary", "wall_seconds")):
        if isinstance(value, (int, float)) and not isinstance(value, bool) and value > 0:
            return float(value)
    start, end = _parse_time(manifest.get("started_at")), _parse_time(manifest.get("finished_at"))
    if start and end and end > start:
        return (end - start).total_seconds()
    return None


def _integrator(manifest: Mapping[str, Any]) -> str:
    for value in (
        manifest.get("integrator"),
        _get(manifest, "config", "integrate_method"),
        _get(manifest, "params", "integrate_method"),
        _get(manifest, "params", "integrator"),
    ):
        if isinstance(value, Mapping):
            value = value.get("method")
        if isinstance(value, str):
            return value
    return "euler"


def _setting(manifest: Mapping[str, Any], key: str, default: str) -> str:
    """A run setting from the config (else the recorded params), ``default`` for runs that predate it."""
    for value in (_get(manifest, "config", key), _get(manifest, "params", key)):
        if isinstance(value, str) and value:
            return value
    return default


def _family(manifest: Mapping[str, Any], model: str, known: Any) -> str:
    """Family in the spelling of :data:`FAMILIES` (manifests may say ``baseline`` or ``other``)."""
    value = manifest.get("family") or _get(manifest, "model_info", "family")
    if isinstance(value, str) and value:
        return next((f for f in FAMILIES if f.lower() == value.lower()), value)
    return known.family if known else infer_family(model)


def _gpus(manifest: Mapping[str, Any]) -> int | None:
    """GPUs the run used: the backend's report, else the registry's (0 means none: an API)."""
    for value in (
        manifest.get("gpus"),
        _get(manifest, "backend", "gpus"),
        _get(manifest, "backend_info", "gpus"),
        _get(manifest, "model_info", "gpus"),
    ):
        gpus = _as_int(value)
        if gpus:
            return gpus
    return None


def dataset_kind(manifest: Mapping[str, Any]) -> str | None:
    """What data a run was made on: ``synthetic``, ``nuscenes``, or None when the manifest does not say.

    The manifest's ``dataset.kind`` when recorded; else a dataroot holding the
    synthetic dataset's marker file is ``synthetic``, any other dataroot
    ``nuscenes``; runs of synthetic records (``backend.kind == "synthetic"``)
    are ``synthetic``.
    """
    dataset_value = manifest.get("dataset")
    dataset: Mapping[str, Any] = dataset_value if isinstance(dataset_value, Mapping) else {}
    kind = dataset.get("kind")
    if isinstance(kind, str) and kind:
        return kind
    if _get(manifest, "backend", "kind") == "synthetic":
        return "synthetic"
    dataroot = dataset.get("dataroot")
    if isinstance(dataroot, str) and dataroot:
        return "synthetic" if (Path(dataroot) / SYNTH_MARKER).is_file() else "nuscenes"
    return None


def run_info(run_dir: str | os.PathLike[str], manifest: Mapping[str, Any] | None = None) -> RunInfo:
    """Read what evaluation needs from a run's manifest, defensively."""
    run_dir = Path(run_dir)
    manifest = dict(manifest if manifest is not None else read_manifest(run_dir))
    model = str(manifest.get("model") or run_dir.parent.name or "unknown")
    known = known_model(model) if not model.startswith("baseline:") else None
    label = manifest.get("display_name") or (known.display_name if known else model)
    generation = _as_int(manifest.get("generation")) or _as_int(_get(manifest, "model_info", "generation"))
    dataset = manifest.get("dataset") if isinstance(manifest.get("dataset"), Mapping) else None
    return RunInfo(
        run_dir=run_dir,
        model=model,
        label=str(label),
        family=_family(manifest, model, known),
        generation=generation or (known.generation if known else None),
        gpus=_gpus(manifest),
        integrator=_integrator(manifest),
        wall_seconds=_wall_seconds(manifest),
        concurrency=_as_int(manifest.get("concurrency")) or _as_int(_get(manifest, "config", "concurrency")),
        complete=bool(manifest.get("finished_at")),
        dataset=dataset,
        manifest=manifest,
        imported=bool(manifest.get("imported")),
        dataset_kind=dataset_kind(manifest),
        chain=_setting(manifest, "chain", "independent"),
        answer_format=_setting(manifest, "answer_format", "text"),
        name=str(manifest["name"]) if isinstance(manifest.get("name"), str) and manifest["name"].strip() else None,
        batch=_get(manifest, "config", "batch") is True,
        batch_turnaround_s=_batch_turnaround(manifest),
        inputs=_setting(manifest, "inputs", "full"),
    )


def _batch_turnaround(manifest: Mapping[str, Any]) -> float | None:
    """Mean turnaround (submission to results, seconds) over the batches of a batch run's sessions; None when none."""
    turns: list[float] = []
    for session in manifest.get("sessions") or []:
        report = session.get("batch") if isinstance(session, Mapping) else None
        if isinstance(report, Mapping):
            turns += [
                float(t)
                for t in report.get("turnaround_s") or []
                if isinstance(t, (int, float)) and not isinstance(t, bool)
            ]
    return sum(turns) / len(turns) if turns else None
