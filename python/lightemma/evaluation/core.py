"""Evaluate runs: per model, metrics through the Rust core plus FE and efficiency accounting.

``evaluate_runs`` is the Python entry point; ``lightemma evaluate`` formats its
result. Each model is scored on its own valid frames, or with ``common=True``
on the frames valid for every model (docs/definitions.md#metrics). All frames of a model go to the
core in one batched call per convention.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lightemma._text import printable
from lightemma.definitions import CONVENTIONS
from lightemma.errors import RunStoreError, UserError
from lightemma.evaluation.accounting import efficiency, format_errors
from lightemma.evaluation.loading import RunData, load_run
from lightemma.evaluation.rescore import ParseDefinition
from lightemma.evaluation.stats import Resampling
from lightemma.frames.fingerprint import run_fingerprint
from lightemma.metrics import evaluate, evaluate_all
from lightemma.models.names import family_rank
from lightemma.runs.store import find_run_dirs

METRIC_KEYS: tuple[str, ...] = ("ade_1s", "ade_2s", "ade_3s", "ade_avg", "fde", "miss_rate")
LOW_COVERAGE = 0.5  # a model with fewer scored frames than this share is flagged in every table


@dataclass
class ModelResult:
    """One run's row: identity, frames, metrics per convention, FE and efficiency accounting."""

    label: str
    model: str
    family: str
    generation: int | None
    run_dir: Path
    integrator: str
    complete: bool
    frames_in_run: int
    frames_accounted: int  # frames behind FE and efficiency: all, or with --common those in every run
    frames_evaluated: int  # frames behind the metrics
    metrics: dict[str, dict[str, float | None]]  # convention -> metric -> value (None: no scored frame)
    accounting: dict[str, Any]  # fe_pct, fe_corr_pct (over frames with an answer), failed_final, api_error_frames
    efficiency: dict[str, Any]
    parse: dict[str, Any] = field(default_factory=dict)  # the parse definition behind statuses and metrics
    dataset_kind: str | None = None  # "nuscenes", "synthetic" or None (from the manifest)
    outcomes: dict[str, int] = field(
        default_factory=dict
    )  # of the accounted frames: scored, failed, implausible, api_errors
    # convention -> ade_avg/fde -> [low, high] (None: no interval; "unavailable" -> why, when values too large to resample)
    intervals: dict[str, dict[str, Any]] = field(default_factory=dict)
    chain: str = "independent"  # request variant (docs/run.md): independent stages or one conversation
    answer_format: str = "text"  # stage-3 answers as text or structured JSON
    inputs: str = "full"  # input ablation (docs/run.md#input-ablations): full, no-image, blank-image, no-history
    safety: dict[str, dict[str, Any]] = field(
        default_factory=dict
    )  # convention -> off-road / collision keys (evaluation/safety.py)
    planning: dict[str, Any] = field(
        default_factory=dict
    )  # planning-score keys (evaluation/planning_score.py ROW_KEYS)
    explanations: dict[str, Any] = field(
        default_factory=dict
    )  # explanation-audit keys (evaluation/intent_audit.py ROW_KEYS)
    fingerprint: dict[str, Any] | None = None  # the run's frame set (lightemma.frames.fingerprint.run_fingerprint)
    manifest: dict[str, Any] = field(
        default_factory=dict
    )  # the run's manifest, for provenance (evaluation/descriptors.py)
    # --samples K > 1: convention -> samples, minade, minfde, spread_m, sampled_frames (lightemma.evaluation.samples);
    # "best" / "mean" -> the safety and planning keys of the best sample and of the mean trajectory; empty for K = 1
    sampling: dict[str, Any] = field(default_factory=dict)

    @property
    def scored_pct(self) -> float | None:
        """Share of the accounted frames that were scored, in %."""
        return 100.0 * self.outcomes.get("scored", 0) / self.frames_accounted if self.frames_accounted else None

    @property
    def low_coverage(self) -> bool:
        """Fewer than half of the frames scored: every table flags the model."""
        pct = self.scored_pct
        return pct is None or pct < 100.0 * LOW_COVERAGE

    def _coverage(self) -> dict[str, Any]:
        return {"scored_pct": self.scored_pct, "low_coverage": self.low_coverage}

    def accuracy_row(self, convention: str) -> dict[str, Any]:
        """A flat dict: model, family, frames, outcome counts, FE, FE corr, ADE 1s/2s/3s/avg, FDE, miss rate, intervals."""
        ci = self.intervals.get(convention, {})
        return {
            "model": self.label,
            "family": self.family,
            "convention": convention,
            "frames": self.frames_evaluated,  # behind the means
            "frames_accounted": self.frames_accounted,  # = scored + failed + implausible + api_errors (+ unscorable)
            "frames_in_run": self.frames_in_run,
            **{key: self.outcomes.get(key) for key in ("scored", "failed", "implausible", "api_errors")},
            **self._coverage(),
            "fe_pct": self.accounting["fe_pct"],
            "fe_corr_pct": self.accounting["fe_corr_pct"],
            **{key: self.metrics[convention][key] for key in METRIC_KEYS},
            "parse": self.parse.get("label"),
            "dataset_kind": self.dataset_kind,
            "chain": self.chain,
            "answer_format": self.answer_format,
            "inputs": self.inputs,
            "ade_avg_ci95": ci.get("ade_avg"),
            "fde_ci95": ci.get("fde"),
            **self.safety.get(convention, {}),
            "ci95_unavailable": ci.get("unavailable"),
            **self.sampling.get(convention, {}),  # minade, minfde with samples: K (only for a run of K > 1 samples)
            **{key: self.sampling[key] for key in ("best", "mean") if key in self.sampling},
        }

    def efficiency_row(self) -> dict[str, Any]:
        """A flat dict: model, family, time, cost, tokens, GPUs, run wall time, frames/s."""
        return {
            "model": self.label,
            "family": self.family,
            "frames": self.frames_accounted,
            **self._coverage(),
            **self.efficiency,
            "dataset_kind": self.dataset_kind,
            "chain": self.chain,
            "answer_format": self.answer_format,
            "inputs": self.inputs,
        }


@dataclass
class Evaluation:
    """Everything ``lightemma evaluate`` prints; rows are plain dicts (DataFrame-friendly)."""

    models: list[ModelResult]
    conventions: tuple[str, ...]
    common: bool
    n_common: int | None
    warnings: list[str] = field(default_factory=list)
    resampling: Resampling = field(default_factory=Resampling)
    pairwise: list[dict[str, Any]] | None = None  # see lightemma.evaluation.uncertainty.pairwise_ade
    # "does the image matter?": see lightemma.evaluation.ablations (empty when the runs hold nothing to compare)
    input_ablations: list[dict[str, Any]] = field(default_factory=list)
    baseline_gains: list[dict[str, Any]] = field(default_factory=list)
    safety: Any = None  # lightemma.evaluation.safety.SafetyResult when safety metrics were computed
    pairwise_safety: list[dict[str, Any]] | None = None  # see lightemma.evaluation.safety.pairwise_safety
    planning: Any = None  # lightemma.evaluation.planning_score.PlanningResult when the planning score was computed
    explanations: Any = (
        None  # lightemma.evaluation.intent_audit.ExplanationResult when the explanation audit was computed
    )
    miss_threshold: float = 2.0  # metres, behind miss_rate (its descriptor: miss@<threshold>m/1)
    robustness: Any = None  # lightemma.evaluation.robustness.RobustnessResult when sweep runs were evaluated

    @property
    def main_convention(self) -> str:
        """The convention of figures and paired comparisons: ``lightemma`` when evaluated, else the first."""
        return "lightemma" if "lightemma" in self.conventions else self.conventions[0]

    def generations(self) -> list[dict[str, Any]]:
        """Per family, each generation against its predecessor (needs ``pairwise``; empty without it)."""
        from lightemma.evaluation.uncertainty import generation_verdicts

        return generation_verdicts(self.models, self.pairwise or [])

    def accuracy_rows(self, convention: str = "lightemma") -> list[dict[str, Any]]:
        """Table II rows for one convention, one dict per model."""
        if convention not in self.conventions:
            raise UserError(f"convention {convention!r} was not evaluated (have {', '.join(self.conventions)})")
        return [m.accuracy_row(convention) for m in self.models]

    def efficiency_rows(self) -> list[dict[str, Any]]:
        """Table I rows, one dict per model."""
        return [m.efficiency_row() for m in self.models]

    def to_dict(self) -> dict[str, Any]:
        """JSON-able summary: accuracy rows per convention, efficiency rows, warnings."""
        out = {
            "common": self.common,
            "n_common": self.n_common,
            "resampling": self.resampling.to_dict(),
            "accuracy": {c: self.accuracy_rows(c) for c in self.conventions},
            "efficiency": self.efficiency_rows(),
            "warnings": list(self.warnings),
        }
        if self.pairwise is not None:
            out["pairwise_ade"] = self.pairwise
            out["generations"] = self.generations()
        if self.input_ablations:
            out["input_ablations"] = self.input_ablations
        if self.baseline_gains:
            out["baseline_gains"] = self.baseline_gains
        if self.safety is not None:
            out["safety"] = self.safety.to_dict()
        if self.pairwise_safety is not None:
            out["pairwise_safety"] = self.pairwise_safety
        if self.planning is not None:
            out["planning"] = {**self.planning.to_dict(), "pairwise": self.planning.pairwise}
        if self.explanations is not None:
            out["explanations"] = self.explanations.to_dict()
        if self.robustness is not None:
            out["robustness"] = self.robustness.to_dict()
        return out


def columns(rows: Sequence[dict[str, Any]]) -> dict[str, list[Any]]:
    """Rows (list of dicts) as a dict of columns, e.g. for ``pandas.DataFrame(columns(rows))``."""
    keys: list[str] = []
    for row in rows:
        keys.extend(k for k in row if k not in keys)
    return {k: [row.get(k) for row in rows] for k in keys}


def expand_run_dirs(paths: Iterable[str | os.PathLike[str]]) -> list[Path]:
    """Run directories named by ``paths`` (each a run dir or a folder holding runs), without repeats."""
    found: list[Path] = []
    for path in paths:
        dirs = find_run_dirs(path)
        if not dirs:
            raise RunStoreError(f"{path} holds no lightemma run (no manifest.json at or below it)")
        found.extend(d for d in dirs if d.resolve() not in {f.resolve() for f in found})
    if not found:
        raise UserError("no run directories given")
    return found


def _conventions(convention: str | Sequence[str]) -> tuple[str, ...]:
    names = (
        CONVENTIONS if convention == "all" else ((convention,) if isinstance(convention, str) else tuple(convention))
    )
    for name in names:
        if name not in CONVENTIONS:
            raise UserError(f"unknown convention {name!r} (choose from {', '.join(CONVENTIONS)} or all)")
    return names


#: the paper's protocol: a run's label names each setting in which it departs from these (docs/evaluate.md)
PAPER_SETTINGS: tuple[tuple[str, str], ...] = (
    ("window", "reference"),
    ("integrator", "euler"),
    ("chain", "independent"),
    ("answer_format", "text"),
    ("inputs", "full"),
)


def _window(info: Any) -> str:
    """The run's frame window (``reference``, the paper's, or ``full``) as its manifest records it."""
    manifest = getattr(info, "manifest", None) or {}
    config_value = manifest.get("config")
    config: dict[str, Any] = config_value if isinstance(config_value, dict) else {}
    for dataset in (manifest.get("dataset"), config.get("dataset")):
        window = dataset.get("window") if isinstance(dataset, dict) else None
        if isinstance(window, str) and window:
            return window
    return "reference"


def _compose(info: Any, extra: Sequence[str] = ()) -> str:
    settings = {
        "window": _window(info),
        "integrator": info.integrator,
        "chain": info.chain,
        "answer_format": info.answer_format,
        "inputs": getattr(info, "inputs", "full"),
    }
    parts = [
        f"{settings[key]} window" if key == "window" else settings[key]
        for key, paper in PAPER_SETTINGS
        if settings[key] != paper
    ]
    parts += extra
    name = getattr(info, "name", None)
    return printable(info.label + (f" [{', '.join(parts)}]" if parts else "") + (f' "{name}"' if name else ""))


def run_label(info: Any) -> str:
    """A run's display label, from the run alone: the model's display name, then in brackets every setting in which the
    run departs from the paper's protocol (:data:`PAPER_SETTINGS`, in that order: ``full window``, the integrator, the
    chain, the answer format, the inputs), then its name (``lightemma run --name``) in double quotes:
    ``GPT-4o``, ``GPT-4o [no-image]``, ``Baseline (oracle actions) [midpoint]``,
    ``GPT-4o [full window, conversation, structured] "second try"``. One line (:func:`~lightemma._text.printable`)."""
    return _compose(info)


def unique_labels(runs: list[RunData]) -> list[str]:
    """Display labels (:func:`run_label`), each from its own run alone, so a run keeps its label (and its bootstrap
    stream, which is keyed by it) whatever other runs are evaluated beside it. Only runs alike in model, every setting
    and name share a label; those get their run id (their folder's path where the ids are alike too) as a last part:
    ``GPT-4o [run 20261130T025909Z-e2c662]``."""
    labels = [run_label(r.info) for r in runs]
    out = list(labels)
    for i, run in enumerate(runs):
        clashes = [j for j, lab in enumerate(labels) if lab == labels[i]]
        if len(clashes) > 1:
            ids = [runs[j].info.run_dir.name for j in clashes]
            own = run.info.run_dir.name if ids.count(run.info.run_dir.name) == 1 else str(run.info.run_dir)
            out[i] = _compose(run.info, [f"run {own}"])
    return out


def frame_set_warning(runs: Sequence[RunData]) -> str | None:
    """A warning when the runs do not all cover the same frames (None when they do)."""
    if len(runs) < 2:
        return None
    sets = [set(r.frame_ids) for r in runs]
    union, inter = set.union(*sets), set.intersection(*sets)
    if len(union) == len(inter):
        return None
    return (
        f"the runs cover different frame sets: {len(union) - len(inter)} of {len(union)} frames are not in every run; "
        f"each model is scored on its own frames (pass --common to compare on the frames scored in every run)"
    )


def common_frames(runs: Sequence[RunData]) -> list[str]:
    """Frame ids valid (scored) in every run, in the first run's order."""
    valid_sets = [set(np.asarray(r.frame_ids, dtype=object)[r.valid].tolist()) for r in runs[1:]]
    first = runs[0]
    return [fid for fid, ok in zip(first.frame_ids, first.valid) if ok and all(fid in s for s in valid_sets)]


SCORE_BLOCK = 1 << 16  # frames per core call: bounded copies, still one call per large batch


def score(
    run: RunData, rows: np.ndarray, conventions: Sequence[str], miss_threshold: float
) -> dict[str, dict[str, float | None]]:
    """Metrics of ``rows`` of a run per convention through the Rust core.

    Frames go to the core in blocks of :data:`SCORE_BLOCK` (one batched call per
    block, all conventions from one error matrix) and the block results are combined frame-weighted,
    which is exact for these means; memory for the copies stays bounded.
    """
    if len(rows) == 0:
        return {c: {key: None for key in METRIC_KEYS} for c in conventions}
    sums = {c: dict.fromkeys(METRIC_KEYS, 0.0) for c in conventions}
    for start in range(0, len(rows), SCORE_BLOCK):
        block = rows[start : start + SCORE_BLOCK]
        pred = np.ascontiguousarray(run.trajectory[block])
        gt = np.ascontiguousarray(run.gt_positions[block])
        if len(conventions) > 1:  # one error matrix for every convention
            every = evaluate_all(pred, gt, miss_threshold=miss_threshold)
            results = {c: every[c].to_dict() for c in conventions}
        else:
            results = {
                c: evaluate(pred, gt, convention=c, miss_threshold=miss_threshold).to_dict() for c in conventions
            }
        for convention, metrics in results.items():
            for key in METRIC_KEYS:
                sums[convention][key] += float(metrics[key]) * len(block)
    return {c: {key: total / len(rows) for key, total in sums[c].items()} for c in conventions}


def evaluate_loaded(
    runs: Sequence[RunData],
    *,
    convention: str | Sequence[str] = "lightemma",
    common: bool = False,
    miss_threshold: float = 2.0,
    resampling: Resampling = Resampling(),
    pairwise: bool = False,
    safety: bool = True,
    planning: bool = True,
    dataroot: str | os.PathLike[str] | None = None,
    version: str | None = None,
    explanations: bool = True,
) -> Evaluation:
    """Evaluate already loaded runs (see :func:`evaluate_runs`).

    Metrics use each run's scored frames, or with ``common`` the frames scored in
    every run; FE, efficiency and outcome counts use all frames of a run, or with
    ``common`` the frames present in every run.
    """
    conventions = _conventions(convention)
    runs = sorted(runs, key=lambda r: (family_rank(r.info.family), r.info.generation or 99, r.info.label))
    fingerprints = [
        run_fingerprint(r.info.run_dir, r.info.manifest or {}, r.frame_ids) for r in runs
    ]  # a bad one: refused
    warnings = [w for r in runs for w in r.warnings]
    shared: list[str] | None = None
    present: set[str] | None = None
    if common:
        shared = common_frames(runs)
        if not shared:
            raise UserError("no frame is valid for every run; nothing to compare with --common")
        present = set.intersection(*(set(r.frame_ids) for r in runs))
    else:
        note = frame_set_warning(runs)
        if note:
            warnings.append(note)
    results: list[ModelResult] = []
    entries: list[tuple[str, RunData, np.ndarray]] = []
    for run, label in zip(runs, unique_labels(runs)):
        if shared is not None and present is not None:
            index = run.index()
            scored = np.fromiter((index[f] for f in shared), dtype=np.int64, count=len(shared))
            rows = np.flatnonzero(np.fromiter((f in present for f in run.frame_ids), dtype=bool, count=len(run)))
        else:
            rows = np.arange(len(run))
            scored = np.flatnonzero(run.valid)
        results.append(
            ModelResult(
                label=label,
                model=run.info.model,
                family=run.info.family,
                generation=run.info.generation,
                run_dir=run.info.run_dir,
                integrator=run.info.integrator,
                complete=run.info.complete,
                frames_in_run=len(run),
                frames_accounted=len(rows),
                frames_evaluated=len(scored),
                metrics=score(run, scored, conventions, miss_threshold),
                accounting=format_errors(run, rows),
                efficiency=efficiency(run, rows),
                parse={**run.parse.to_dict(), "label": run.parse.label(), "rescored": run.rescored},
                dataset_kind=run.info.dataset_kind,
                outcomes=run.outcomes(rows),
                chain=run.info.chain,
                answer_format=run.info.answer_format,
                inputs=run.info.inputs,
                fingerprint=fingerprints[len(results)],
                manifest=dict(run.info.manifest or {}),
            )
        )
        entries.append((label, run, scored))
    _with_samples(results, entries, conventions)
    evaluation = _with_uncertainty(
        Evaluation(
            results,
            conventions,
            common,
            len(shared) if shared is not None else None,
            warnings,
            resampling,
            miss_threshold=miss_threshold,
        ),
        entries,
        shared,
        pairwise,
    )
    if safety:
        _with_safety(
            evaluation, entries, shared, pairwise, dataroot, version, history=_PLANNING_HISTORY if planning else 0
        )
    if planning:
        _with_planning(evaluation, entries, shared, pairwise, dataroot, version)
    if safety or planning:
        _with_sample_scores(evaluation, entries, shared, dataroot, version, safety=safety, planning=planning)
    _refuse_mixed_maps(evaluation)
    if explanations:
        _with_explanations(evaluation, entries, shared, dataroot, version)
    _with_robustness(evaluation, entries, shared)
    return evaluation


def _with_samples(
    results: list[ModelResult], entries: list[tuple[str, RunData, np.ndarray]], conventions: tuple[str, ...]
) -> None:
    """--samples K runs: minADE@K, minFDE@K and the spread of the samples per convention (lightemma.evaluation.samples)."""
    from lightemma.evaluation.samples import sample_metrics

    for result, (_, run, scored) in zip(results, entries):
        result.sampling = sample_metrics(run, scored, conventions)


def _with_sample_scores(
    evaluation: Evaluation,
    entries: list[tuple[str, RunData, np.ndarray]],
    shared: list[str] | None,
    dataroot: str | os.PathLike[str] | None,
    version: str | None,
    *,
    safety: bool,
    planning: bool,
) -> None:
    """--samples K runs: the safety and planning scores of the best sample (by ADE) and of the mean trajectory, as
    ``sampling["best"]`` / ``sampling["mean"]`` (the keys of the run's own safety and planning rows)."""
    from lightemma.evaluation.samples import best_and_mean, run_samples

    sampled = [(label, run, scored) for label, run, scored in entries if run_samples(run) > 1]
    if not sampled:
        return
    only = set(shared) if shared is not None else None
    no_intervals = Resampling(
        n_resamples=0, seed=evaluation.resampling.seed, confidence=evaluation.resampling.confidence
    )
    for label, run, scored in sampled:
        pair = best_and_mean(run, scored, evaluation.main_convention)
        if pair is None:
            continue
        model = next(m for m in evaluation.models if m.label == label)
        for name, variant in zip(("best", "mean"), pair):
            row: dict[str, Any] = {}
            derived = [(label, variant, scored)]
            if safety:
                from lightemma.evaluation.safety import evaluate_safety

                result = evaluate_safety(
                    derived,
                    (evaluation.main_convention,),
                    no_intervals,
                    dataroot=dataroot,
                    version=version,
                    history=_PLANNING_HISTORY if planning else 0,
                )
                row.update(result.rows.get(label, {}).get(evaluation.main_convention, {}))
            if planning:
                from lightemma.evaluation.planning_score import evaluate_planning

                planning_result = evaluate_planning(
                    derived, no_intervals, dataroot=dataroot, version=version, safety=None, pairwise=False, only=only
                )
                row.update(planning_result.rows.get(label, {}))
            model.sampling[name] = row


def _with_robustness(
    evaluation: Evaluation, entries: list[tuple[str, RunData, np.ndarray]], shared: list[str] | None
) -> None:
    """Sweep runs: each variant paired with its sweep's clean run (lightemma.evaluation.robustness)."""
    from lightemma.evaluation.robustness import evaluate_robustness

    evaluation.robustness = evaluate_robustness(
        entries,
        evaluation.main_convention,
        evaluation.resampling,
        safety=evaluation.safety,
        planning=evaluation.planning,
        only=set(shared) if shared is not None else None,
    )
    if evaluation.robustness is not None:
        evaluation.warnings.extend(evaluation.robustness.warnings)


def _refuse_mixed_maps(evaluation: Evaluation) -> None:
    """Runs whose off-road or planning values were scored against different versions of one map expansion are not
    compared: :class:`UserError` in one line naming both runs and versions (docs/evaluate.md#what-each-number-is)."""
    from lightemma.evaluation.safety import map_version_conflict, run_map_versions

    per_run: dict[str, dict[str, str]] = {}
    for model in evaluation.models:
        found = per_run.setdefault(model.label, {})
        if evaluation.safety is not None and model.label in evaluation.safety.runs:
            found.update(run_map_versions(evaluation.safety.runs[model.label]))
        if evaluation.planning is not None and model.label in evaluation.planning.runs:
            found.update(evaluation.planning.runs[model.label].map_versions)
    conflict = map_version_conflict(per_run)
    if conflict:
        raise UserError(conflict)


_PLANNING_HISTORY = (
    4  # earlier keyframes the planning score reads (lightemma.evaluation.planning_score.HISTORY_KEYFRAMES)
)


def _with_planning(
    evaluation: Evaluation,
    entries: list[tuple[str, RunData, np.ndarray]],
    shared: list[str] | None,
    pairwise: bool,
    dataroot: str | os.PathLike[str] | None,
    version: str | None,
) -> None:
    """NAVSIM's planning score (PDMS / EPDMS and sub-scores) per model and the ground truth's (docs/definitions.md#planning-score)."""
    from lightemma.evaluation.planning_score import evaluate_planning

    result = evaluate_planning(
        entries,
        evaluation.resampling,
        dataroot=dataroot,
        version=version,
        safety=evaluation.safety,
        pairwise=pairwise,
        only=set(shared) if shared is not None else None,
    )
    for model in evaluation.models:
        model.planning = result.rows.get(model.label, {})
    evaluation.planning = result
    evaluation.warnings.extend(result.warnings)


def _with_explanations(
    evaluation: Evaluation,
    entries: list[tuple[str, RunData, np.ndarray]],
    shared: list[str] | None,
    dataroot: str | os.PathLike[str] | None,
    version: str | None,
) -> None:
    """The explanation audit: stated intent against the plan, the ground truth and the ablations
    (docs/definitions.md#explanation-audit)."""
    from lightemma.evaluation.intent_audit import evaluate_explanations

    only = None
    if shared is not None:  # the frames present in every run, as FE and efficiency count them
        only = set.intersection(*(set(run.frame_ids) for _, run, _ in entries))
    result = evaluate_explanations(entries, evaluation.resampling, dataroot=dataroot, version=version, only=only)
    for model in evaluation.models:
        model.explanations = result.rows.get(model.label, {})
    evaluation.explanations = result
    evaluation.warnings.extend(result.warnings)


def _with_safety(
    evaluation: Evaluation,
    entries: list[tuple[str, RunData, np.ndarray]],
    shared: list[str] | None,
    pairwise: bool,
    dataroot: str | os.PathLike[str] | None,
    version: str | None,
    history: int = 0,
) -> None:
    """Off-road and collision rates beside ADE, the ground-truth floor, and paired tests (docs/definitions.md#safety)."""
    from lightemma.evaluation.safety import evaluate_safety, pairwise_safety

    result = evaluate_safety(
        entries, evaluation.conventions, evaluation.resampling, dataroot=dataroot, version=version, history=history
    )
    for model in evaluation.models:
        model.safety = result.rows.get(model.label, {})
    evaluation.safety = result
    evaluation.warnings.extend(result.warnings)
    if pairwise:
        labels = [label for label, _, _ in entries]
        evaluation.pairwise_safety = pairwise_safety(
            result,
            labels,
            evaluation.main_convention,
            evaluation.resampling,
            only=set(shared) if shared is not None else None,
        )


def _with_uncertainty(
    evaluation: Evaluation, entries: list[tuple[str, RunData, np.ndarray]], shared: list[str] | None, pairwise: bool
) -> Evaluation:
    """Scene-bootstrap intervals for every row and, when asked, the paired comparisons (docs/statistics.md)."""
    from lightemma.evaluation.uncertainty import model_intervals, pairwise_ade

    for result, intervals in zip(
        evaluation.models, model_intervals(entries, evaluation.conventions, evaluation.resampling)
    ):
        result.intervals = intervals
    runs, labels = [run for _, run, _ in entries], [label for label, _, _ in entries]
    if pairwise:
        evaluation.pairwise = pairwise_ade(
            runs,
            labels,
            evaluation.main_convention,
            evaluation.resampling,
            only=set(shared) if shared is not None else None,
        )
    _with_ablations(evaluation, runs, labels, shared)
    return evaluation


def _with_ablations(evaluation: Evaluation, runs: list[RunData], labels: list[str], shared: list[str] | None) -> None:
    """ "Does the image matter?": the input ablations against their full runs, each model against the best baseline."""
    from lightemma.evaluation.ablations import baseline_gains, input_ablations

    only = set(shared) if shared is not None else None
    evaluation.input_ablations = input_ablations(
        runs, labels, evaluation.main_convention, evaluation.resampling, only=only, warnings=evaluation.warnings
    )
    evaluation.baseline_gains = baseline_gains(
        runs, labels, evaluation.main_convention, evaluation.resampling, only=only
    )


def evaluate_runs(
    run_dirs: Iterable[str | os.PathLike[str]],
    *,
    convention: str | Sequence[str] = "lightemma",
    common: bool = False,
    miss_threshold: float = 2.0,
    parse: ParseDefinition | None = None,
    resampling: Resampling = Resampling(),
    pairwise: bool = False,
    keep_implausible: bool = False,
    safety: bool = True,
    planning: bool = True,
    dataroot: str | os.PathLike[str] | None = None,
    version: str | None = None,
    explanations: bool = True,
) -> Evaluation:
    """Evaluate run directories (or folders holding runs): Tables I and II as rows of dicts.

    ``convention`` is one of ``lightemma``, ``stp3``, ``uniad``, a sequence of
    them, or ``all``. ``common=True`` scores every model on the frames scored in
    all of them. Only scored frames (not failed, not implausible) enter a mean;
    each row counts frames scored / failed / implausible / lost to API errors and
    carries scene-bootstrap intervals (``resampling``: resamples, seed,
    confidence). ``pairwise=True`` adds every pair's paired comparison
    (``Evaluation.pairwise``). ``parse`` re-scores every run's stored answers
    under that definition (default: each run's own; ``paper`` for imported
    runs). Actions outside the plausibility limits (the definition's, or the
    defaults for ``paper``) are counted as implausible and never averaged;
    ``keep_implausible=True`` averages every readable answer, as the paper's own
    evaluation did. Unfinished runs are evaluated on their finished frames; corrupt lines
    are skipped; both are reported in ``Evaluation.warnings``. ``safety`` adds off-road and collision
    rates beside ADE (docs/definitions.md#safety) from ``dataroot``/``version`` (default: each run's
    manifest's dataset); without one the columns say why they are empty. ``planning`` adds NAVSIM's planning
    score (``Evaluation.planning``, docs/definitions.md#planning-score) from the same dataset. ``explanations`` adds
    the explanation audit (``Evaluation.explanations``, docs/definitions.md#explanation-audit).
    """
    from lightemma.evaluation.loading import discover_runs

    conventions = _conventions(convention)  # check the arguments before reading any run
    dirs, left_out = discover_runs(run_dirs)  # a corrupt manifest or a linked run: left out with a warning
    runs = [
        load_run(d, parse=parse, keep_implausible=keep_implausible, details=planning) for d in dirs
    ]  # actions: plan headings
    evaluation = evaluate_loaded(
        runs,
        convention=conventions,
        common=common,
        miss_threshold=miss_threshold,
        resampling=resampling,
        pairwise=pairwise,
        safety=safety,
        planning=planning,
        dataroot=dataroot,
        version=version,
        explanations=explanations,
    )
    evaluation.warnings[:0] = left_out
    return evaluation
