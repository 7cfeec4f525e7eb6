"""The explanation audit of evaluated runs: the stated intent against the plan, the ground truth and the ablations.

Per run (docs/definitions.md#explanation-audit, rules ``intent@lightemma/1``, :mod:`lightemma.explanations`):

* ``consistent`` / ``contradicts`` / ``intent_unknown`` — the shares of the run's frames whose stated intent (stage 2)
  is consistent with, contradicts, or cannot be checked against its own plan (stage 3);
* ``intent_accuracy`` — the share of the run's frames whose stated intent is consistent with what the car did: the
  same verdict rules with the ground truth's behaviour in place of the plan, classified by
  :func:`~lightemma.explanations.planned_intents` on the frame's ground-truth actions (``gt_actions`` of the dataroot's
  frames, docs/definitions.md#ground-truth), its history and its ground-truth positions (Euler, the paper's
  integrator, for the arc excess). It needs the dataroot; a run whose recorded ground truth differs from the dataroot's
  is n/a with the reason, never compared against another dataset;

each a rate in [0, 1] over the run's accounted frames (all its frames, or with ``--common`` those in every run), with a
scene-bootstrap interval ``<key>_ci95`` and ``<key>_na`` (why there is no value, else None). A run without stage-2
texts (a baseline) is n/a on every key, never 0.

and from the stage-1 texts (:mod:`lightemma.evaluation.object_audit`, docs/definitions.md#described-objects) the shares
``hallucinated_pedestrian`` / ``missed_pedestrian`` and the "Described objects" rows (per class mention precision and
recall against the annotations in view of CAM_FRONT).

Per ablation run (``no-image`` / ``blank-image``) paired with the full run of the same model and variant
(:func:`lightemma.evaluation.ablations.comparison_key`): ``intent_changed``, the share of the frames both runs answered
with a stage-2 text whose stated intent (longitudinal and lateral class, ``unknown`` included) differs.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lightemma.evaluation.ablations import comparison_key
from lightemma.evaluation.object_audit import RANGE_M, audit_run, load_front, object_rows
from lightemma.evaluation.safety import _resolve_dataset, sample_token_of
from lightemma.evaluation.stats import Resampling, bootstrap_ci
from lightemma.explanations import INTENT_RULES, OBJECT_RULES, Intents, Thresholds, intent_consistency, run_consistency
from lightemma.nuscenes import load_frames
from lightemma.runs.store import read_run

#: the JSON / row keys of the audit (rates in [0, 1])
KEYS: tuple[str, ...] = ("consistent", "contradicts", "intent_unknown", "intent_accuracy")
#: every key an explanations row has
ROW_KEYS: tuple[str, ...] = (
    *KEYS,
    *(f"{k}_ci95" for k in KEYS),
    *(f"{k}_na" for k in KEYS),
    "explanation_frames",
    # the described objects (lightemma.evaluation.object_audit.ROW_KEYS)
    *(f"{k}{s}" for k in ("hallucinated_pedestrian", "missed_pedestrian") for s in ("", "_ci95", "_na")),
    "object_frames",
)
#: the ablations whose stated intents are compared with the full run's
INTENT_ABLATIONS: tuple[str, ...] = ("no-image", "blank-image")
NO_TEXTS = "no stage-2 texts (a baseline, or a run without them)"  # a baseline's placeholder texts are none
NO_SCENE_TEXTS = "no stage-1 texts (a baseline)"
#: a run's recorded ground truth further than this from the dataroot's is another dataset: n/a (m)
GT_TOLERANCE_M = 1e-3


@dataclass
class RunAudit:
    """One run's audit per frame: ``frame_ids`` (n,), ``scenes`` (n,), ``verdict`` (n,) str against the plan,
    ``reason`` per frame, ``truth_verdict`` (n,) str against the ground truth (None when n/a), stated intents."""

    frame_ids: list[str]
    scenes: np.ndarray
    verdict: np.ndarray
    reason: list[str]
    stated_longitudinal: np.ndarray
    stated_lateral: np.ndarray
    has_text: np.ndarray
    longitudinal_verdict: np.ndarray | None = None  # (n,) str: the longitudinal axis's verdict against the plan
    stated_reason: list[str] = field(default_factory=list)
    truth_verdict: np.ndarray | None = None
    truth_reason: str | None = None  # why truth_verdict is None


@dataclass
class ExplanationResult:
    """Per model label its row (:data:`ROW_KEYS`), the ablation rows, per-frame audits and warnings."""

    rows: dict[str, dict[str, Any]]
    ablations: list[dict[str, Any]] = field(default_factory=list)
    runs: dict[str, RunAudit] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    #: per label the described-objects audit (lightemma.evaluation.object_audit.RunObjects)
    objects: dict[str, Any] = field(default_factory=dict)
    #: the "Described objects" rows: model × class mention precision and recall
    object_classes: list[dict[str, Any]] = field(default_factory=list)

    @property
    def shown(self) -> bool:
        """Whether some run has stage-2 texts (else the table would hold only n/a)."""
        return any(row.get("explanation_frames") and row.get("consistent_na") is None for row in self.rows.values())

    @property
    def objects_shown(self) -> bool:
        """Whether some run has a frame with a readable stage-1 text and annotation states (else the "Described
        objects" table would hold only n/a)."""
        return any(bool(a.check.checked.any()) for a in self.objects.values())

    def to_dict(self) -> dict[str, Any]:
        """JSON-able: the rules, the thresholds, each model's row (by label) and the ablation rows."""
        return {
            "rules": INTENT_RULES,
            "thresholds": Thresholds().to_dict(),
            "rows": self.rows,
            "ablations": self.ablations,
            "objects": {"rules": OBJECT_RULES, "range_m": RANGE_M, "classes": self.object_classes},
        }


def says_stop_drives_on(audit: RunAudit) -> np.ndarray:
    """(n,) bool: the frames whose stage-2 text says stop (``stop`` / ``stay_stopped``) while the plan does not stop
    (the longitudinal axis contradicts): the scenario tag ``says-stop-drives-on``."""
    if audit.longitudinal_verdict is None:
        return np.zeros(len(audit.frame_ids), dtype=bool)
    says_stop = np.isin(audit.stated_longitudinal, ("stop", "stay_stopped"))
    return says_stop & (audit.longitudinal_verdict == "contradicts") & audit.has_text


def _interval(pair: np.ndarray) -> list[float] | None:
    return [float(pair[0]), float(pair[1])] if np.isfinite(pair).all() else None


def _audit(run: Any, keep: set[str]) -> RunAudit:
    rc = run_consistency(run.info.run_dir)
    rows = [i for i, fid in enumerate(rc.frame_ids) if fid in keep]
    idx = np.array(rows, dtype=np.intp)
    c = rc.consistency
    has_text = np.array([c.stated.reason[i] != "no stage-2 text" for i in rows], dtype=bool)
    return RunAudit(
        [rc.frame_ids[i] for i in rows],
        rc.scenes[idx] if len(idx) else np.zeros(0, dtype=object),
        c.verdict[idx],
        [c.reason[i] for i in rows],
        c.stated.longitudinal[idx],
        c.stated.lateral[idx],
        has_text,
        c.longitudinal[idx],
        [c.stated.reason[i] for i in rows],
    )


def _truth(
    audits: dict[str, tuple[Any, RunAudit]], dataroot: str | os.PathLike[str] | None, version: str | None
) -> None:
    """Fill each audit's ``truth_verdict`` from its dataset's frames (loaded once per dataset), or its
    ``truth_reason``."""
    wanted: dict[tuple[str, str], set[str]] = {}
    where: dict[str, tuple[str, str]] = {}
    for label, (run, audit) in audits.items():
        ds = _resolve_dataset(run, dataroot, version)
        if isinstance(ds, str):
            audit.truth_reason = ds
            continue
        where[label] = ds
        wanted.setdefault(ds, set()).update(str(s) for s in audit.scenes.tolist())
    loaded: dict[tuple[str, str], Any] = {}
    for ds, scenes in wanted.items():
        try:
            loaded[ds] = load_frames(
                ds[0], ds[1], split="all", scenes=sorted(scenes), window="full", on_missing_image="keep"
            )
        except Exception as exc:  # an unreadable dataset: every run on it is n/a with the reason
            loaded[ds] = f"the dataset {ds[0]} ({ds[1]}) cannot be read: {exc}"
    for label, ds in where.items():
        run, audit = audits[label]
        fs = loaded[ds]
        if isinstance(fs, str):
            audit.truth_reason = fs
            continue
        index = {fid: i for i, fid in enumerate(fs.frame_ids)}
        missing = [fid for fid in audit.frame_ids if fid not in index]
        if missing:
            audit.truth_reason = f"{len(missing)} frame(s) are not in {ds[0]} ({ds[1]}), e.g. {missing[0]}"
            continue
        rows = np.array([index[fid] for fid in audit.frame_ids], dtype=np.intp)
        own = run.index()
        recorded = run.gt_positions[np.array([own[fid] for fid in audit.frame_ids], dtype=np.intp)]
        with np.errstate(invalid="ignore"):
            off = np.abs(recorded - fs.gt_positions[rows]).max(axis=(1, 2)) if len(rows) else np.zeros(0)
        bad = ~(off <= GT_TOLERANCE_M)
        if bad.any():
            audit.truth_reason = (
                f"the run's ground truth differs from {ds[0]} ({ds[1]}) at {int(bad.sum())} "
                "frame(s), "
                f"e.g. {audit.frame_ids[int(np.argmax(bad))]}: another dataset?"
            )
            continue
        blank = [""] * len(rows)
        stated = Intents(audit.stated_longitudinal, audit.stated_lateral, audit.stated_reason, blank, blank)
        truth = intent_consistency(stated, fs.gt_actions[rows], fs.history_actions[rows], fs.gt_positions[rows])
        audit.truth_verdict = truth.verdict


def _rates(audit: RunAudit, label: str, resampling: Resampling) -> dict[str, Any]:
    n = len(audit.frame_ids)
    row: dict[str, Any] = {"explanation_frames": n}
    for key in KEYS:
        row.update({key: None, f"{key}_ci95": None, f"{key}_na": None})
    if n == 0 or not audit.has_text.any():
        reason = "no frames" if n == 0 else NO_TEXTS
        for key in KEYS:
            row[f"{key}_na"] = reason
        return row
    columns = [audit.verdict == "consistent", audit.verdict == "contradicts", audit.verdict == "unknown"]
    if audit.truth_verdict is not None:
        columns.append(audit.truth_verdict == "consistent")
    values = np.stack(columns, axis=1).astype(np.float64)
    ci = bootstrap_ci([(values, audit.scenes)], [f"explanations:{label}"], resampling)[0]
    for k, key in enumerate(KEYS[: values.shape[1]]):
        row[key] = float(values[:, k].mean())
        row[f"{key}_ci95"] = _interval(ci[k])
    if audit.truth_verdict is None:
        row["intent_accuracy_na"] = audit.truth_reason or "no ground truth"
    return row


def _ablations(
    entries: Sequence[tuple[str, Any, np.ndarray]], audits: dict[str, RunAudit], resampling: Resampling
) -> list[dict[str, Any]]:
    full: dict[tuple[Any, ...], list[str]] = {}
    for label, run, _ in entries:
        if run.info.inputs == "full":
            full.setdefault(comparison_key(run.info), []).append(label)
    rows, groups, keys = [], [], []
    for label, run, _ in entries:
        if run.info.inputs not in INTENT_ABLATIONS:
            continue
        candidates = full.get(comparison_key(run.info), [])
        if len(candidates) != 1:  # no full run, or which one would be a guess (input_ablations warns)
            continue
        a, b = audits[candidates[0]], audits[label]
        in_b = {fid: i for i, fid in enumerate(b.frame_ids)}
        pairs = [
            (i, in_b[fid])
            for i, fid in enumerate(a.frame_ids)
            if fid in in_b and a.has_text[i] and b.has_text[in_b[fid]]
        ]
        ia = np.array([p for p, _ in pairs], dtype=np.intp)
        ib = np.array([q for _, q in pairs], dtype=np.intp)
        row: dict[str, Any] = {
            "model": candidates[0],
            "ablation": run.info.inputs,
            "ablated": label,
            "frames": len(pairs),
            "intent_changed": None,
            "intent_changed_ci95": None,
            "intent_changed_na": None,
        }
        if not pairs:
            row["intent_changed_na"] = "no frame with a stage-2 text in both runs"
        else:
            changed = (
                (a.stated_longitudinal[ia] != b.stated_longitudinal[ib])
                | (a.stated_lateral[ia] != b.stated_lateral[ib])
            ).astype(np.float64)
            row["intent_changed"] = float(changed.mean())
            groups.append((changed, a.scenes[ia]))
            keys.append(f"intent-changed:{candidates[0]}|{label}")
            row["_g"] = len(groups) - 1
        rows.append(row)
    if groups:
        ci = bootstrap_ci(groups, keys, resampling)
        for row in rows:
            if "_g" in row:
                row["intent_changed_ci95"] = _interval(ci[row.pop("_g"), 0])
    return rows


def _objects(
    audits: dict[str, tuple[Any, RunAudit]], dataroot: str | os.PathLike[str] | None, version: str | None
) -> dict[str, Any]:
    """Per label the described-objects audit (:func:`lightemma.evaluation.object_audit.audit_run`) of the audited
    frames: stage-1 texts (``scene_text``) of the run's records against the annotations of its dataset (loaded
    once per dataset), or n/a with the reason."""
    where: dict[str, tuple[str, str] | str] = {}
    wanted: dict[tuple[str, str], set[str]] = {}
    for label, (run, audit) in audits.items():
        ds = _resolve_dataset(run, dataroot, version)
        where[label] = ds
        if not isinstance(ds, str):
            wanted.setdefault(ds, set()).update(sample_token_of(f) for f in audit.frame_ids)
    loaded = {ds: load_front(ds[0], ds[1], samples) for ds, samples in wanted.items()}
    out = {}
    for label, (run, audit) in audits.items():
        records = read_run(run.info.run_dir).records
        texts = [
            r.get("scene_text") if isinstance(r.get("scene_text"), str) else None
            for r in (records.get(fid, {}) for fid in audit.frame_ids)
        ]
        ds = where[label]
        out[label] = audit_run(audit.frame_ids, audit.scenes, texts, ds if isinstance(ds, str) else loaded[ds])
    return out


def evaluate_explanations(
    entries: Sequence[tuple[str, Any, np.ndarray]],
    resampling: Resampling,
    *,
    dataroot: str | os.PathLike[str] | None = None,
    version: str | None = None,
    only: set[str] | None = None,
) -> ExplanationResult:
    """The audit of every run: ``entries`` are (label, :class:`~lightemma.evaluation.loading.RunData`, scored rows) as
    :func:`lightemma.evaluation.core.evaluate_loaded` builds them; ``only`` restricts every run to those frame ids
    (``--common``). The ground truth comes from ``dataroot``/``version`` (default: each run's manifest's dataset).
    Returns rows keyed by label (:data:`ROW_KEYS`), ablation rows and per-frame audits. Raises what reading a run
    directory raises (``RunStoreError``)."""
    audits: dict[str, tuple[Any, RunAudit]] = {}
    for label, run, _ in entries:
        keep = set(run.frame_ids) if only is None else set(run.frame_ids) & only
        audit = _audit(run, keep)
        if run.info.family == "Baseline":  # its stage texts are placeholders ("baseline: no driving intent")
            audit.has_text[:] = False
        audits[label] = (run, audit)
    texted = {label: pair for label, pair in audits.items() if pair[1].has_text.any()}
    _truth(texted, dataroot, version)
    rows = {label: _rates(audit, label, resampling) for label, (_, audit) in audits.items()}
    objects = _objects(audits, dataroot, version)

    baselines = {label: NO_SCENE_TEXTS for label, (run, _) in audits.items() if run.info.family == "Baseline"}
    object_row, object_classes = object_rows(objects, resampling, baselines)
    for label, row in rows.items():
        row.update(object_row[label])
    result = ExplanationResult(
        rows,
        _ablations(entries, {k: a for k, (_, a) in audits.items()}, resampling),
        {k: a for k, (_, a) in audits.items()},
        objects=objects,
        object_classes=object_classes,
    )
    for label, row in rows.items():
        reason = row.get("intent_accuracy_na")
        if reason and row.get("consistent_na") is None and not reason.startswith("no dataroot"):
            result.warnings.append(f"{label}: intent accuracy n/a: {reason}")
    return result
