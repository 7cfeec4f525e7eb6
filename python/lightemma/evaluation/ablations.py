"""Does the model look at the road? Input ablations and each model's gain over the best baseline (docs/evaluate.md).

* :func:`input_ablations` — for each model that has ablation runs (``--inputs no-image|blank-image|no-history``)
  beside its full run (same model, integrator, chain, answer format, prompt set), paired on the frames scored in both:
  the mean of full − ablated per metric (negative ADE: the full input helps, so the model uses what the
  ablation took away), its scene-bootstrap interval, a sign-flip p over scenes and Holm's adjustment over
  every row of the table (per metric);
* :func:`baseline_gains` — each model run against the best of the baselines ``constant``, ``cv`` and
  ``ego`` (the one with the lowest mean on the frames scored in both), paired the same way:
  gain = baseline − model (positive: the model beats every baseline by that much).

The statistics are those of :mod:`lightemma.evaluation.stats` (the Rust core's cluster bootstrap and sign-flip test,
docs/statistics.md). The metrics are rows of :data:`PAIRED_METRICS`: per-frame values where lower is
better; a new metric (e.g. a safety rate) is one more entry there and becomes more columns of both tables.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from lightemma.evaluation.loading import RunData
from lightemma.evaluation.stats import Resampling, bootstrap_ci, holm, sign_flip_p
from lightemma.evaluation.uncertainty import frame_values
from lightemma.inputs import is_perturbation

ABLATIONS: tuple[str, ...] = ("no-image", "blank-image", "no-history")
GAIN_BASELINES: tuple[str, ...] = ("baseline:constant", "baseline:cv", "baseline:ego")


@dataclass(frozen=True)
class PairedMetric:
    """A per-frame metric the paired tables compare: ``values(run, rows, convention)`` -> (len(rows),), lower is better."""

    key: str
    title: str
    unit: str
    values: Callable[[RunData, np.ndarray, str], np.ndarray]


def _ade_avg(run: RunData, rows: np.ndarray, convention: str) -> np.ndarray:
    return frame_values(run, rows, convention)[:, 0]


PAIRED_METRICS: list[PairedMetric] = [PairedMetric("ade_avg", "ADE avg", "m", _ade_avg)]


def comparison_key(info: Any) -> tuple[Any, ...]:
    """What an ablation run shares with the full run it is paired with: model, integrator, chain, answer format and
    prompt set (a :class:`~lightemma.evaluation.RunInfo`)."""
    prompt_set = (getattr(info, "manifest", None) or {}).get("prompt_set")
    return (
        info.model,
        info.integrator,
        info.chain,
        info.answer_format,
        prompt_set.get("name") if isinstance(prompt_set, Mapping) else None,
    )


def _variant_key(run: RunData) -> tuple[Any, ...]:
    return comparison_key(run.info)


def _scored(run: RunData, only: set[str] | None) -> np.ndarray:
    rows = np.flatnonzero(run.valid)
    if only is not None:
        rows = rows[np.fromiter((run.frame_ids[i] in only for i in rows), dtype=bool, count=len(rows))]
    return rows


class _Columns:
    """Per run: metric values of its scored frames, looked up by frame id; scene name per frame."""

    def __init__(self, runs: Sequence[RunData], convention: str, only: set[str] | None) -> None:
        self.convention = convention
        self.values: list[dict[str, dict[str, float]]] = []  # run -> metric -> frame id -> value
        self.scene: dict[str, str] = {}
        for run in runs:
            rows = _scored(run, only)
            ids = [run.frame_ids[i] for i in rows]
            names = [run.scene_names[c] if run.scene_names else fid for c, fid in zip(run.scenes()[rows], ids)]
            for fid, name in zip(ids, names):
                self.scene.setdefault(fid, str(name))
            self.values.append(
                {m.key: dict(zip(ids, m.values(run, rows, convention).tolist())) for m in PAIRED_METRICS}
            )

    def paired(self, a: int, b: int, metric: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(values of a, values of b, scene names) on the frames scored in both, in a's order."""
        va, vb = self.values[a][metric], self.values[b][metric]
        common = [f for f in va if f in vb]
        return (
            np.array([va[f] for f in common]),
            np.array([vb[f] for f in common]),
            np.array([self.scene[f] for f in common], dtype=object),
        )


def _with_statistics(
    rows: list[dict[str, Any]],
    groups: dict[str, list[tuple[np.ndarray, np.ndarray] | None]],
    keys: dict[str, list[str]],
    diff_name: str,
    resampling: Resampling,
) -> None:
    """Add ``<metric>_ci95``, ``_p``, ``_p_holm``, ``_significant`` to ``rows``: per metric one core call, Holm over the rows."""
    alpha = 1.0 - resampling.confidence
    for metric in PAIRED_METRICS:
        k = metric.key
        present = [i for i, g in enumerate(groups[k]) if g is not None]
        data = [g for g in groups[k] if g is not None]  # the groups of present, in order
        ci = bootstrap_ci(data, [keys[k][i] for i in present], resampling) if data else np.zeros((0, 1, 2))
        p = sign_flip_p(data, [keys[k][i] for i in present], resampling) if data else np.zeros(0)
        p_all = np.full(len(rows), np.nan)
        ci_all: list[list[float] | None] = [None] * len(rows)
        for j, i in enumerate(present):
            p_all[i] = p[j]
            if np.isfinite(ci[j, 0]).all():
                ci_all[i] = [float(ci[j, 0, 0]), float(ci[j, 0, 1])]
        adjusted = holm(p_all)
        for i, row in enumerate(rows):
            row[f"{k}_ci95"] = ci_all[i]
            row[f"{k}_p"] = None if np.isnan(p_all[i]) else float(p_all[i])
            row[f"{k}_p_holm"] = None if np.isnan(adjusted[i]) else float(adjusted[i])
            row[f"{k}_significant"] = (
                bool(row[f"{k}_p_holm"] is not None and row[f"{k}_p_holm"] <= alpha)
                if row.get(f"{k}_{diff_name}") is not None
                else None
            )


def input_ablations(
    runs: Sequence[RunData],
    labels: Sequence[str],
    convention: str,
    resampling: Resampling,
    *,
    only: set[str] | None = None,
    warnings: list[str] | None = None,
) -> list[dict[str, Any]]:
    """One row per ablation run that has a full run of the same model and variant (see the module docstring).

    Row keys: ``model`` (the full run's label), ``ablation`` (``no-image`` …), ``ablated`` (its label),
    ``convention``, ``frames``, ``scenes``, and per metric ``m`` of :data:`PAIRED_METRICS`: ``m_full``,
    ``m_ablated``, ``m_diff`` (full − ablated), ``m_ci95``, ``m_p``, ``m_p_holm``, ``m_significant``.
    A model with more than one full run is left out (which one to pair with would be a guess), with a warning.
    """
    full: dict[tuple[Any, ...], list[int]] = {}
    for i, run in enumerate(runs):
        if run.info.inputs == "full":
            full.setdefault(_variant_key(run), []).append(i)
    pairs = []
    for i, run in enumerate(runs):
        if run.info.inputs not in ABLATIONS and not is_perturbation(run.info.inputs):  # corrupt:…, history-…
            continue
        candidates = full.get(_variant_key(run), [])
        if len(candidates) == 1:
            pairs.append((candidates[0], i))
        elif warnings is not None:
            what = (
                "no full run"
                if not candidates
                else f"{len(candidates)} full runs ({', '.join(labels[c] for c in candidates)})"
            )
            warnings.append(
                f"{labels[i]}: {what} of the same model and variant to pair the ablation with; left out of "
                '"does the image matter?"' + ("" if not candidates else " (evaluate one full run with it)")
            )
    if not pairs:
        return []
    cols = _Columns(runs, convention, only)
    rows: list[dict[str, Any]] = []
    groups: dict[str, list[Any]] = {m.key: [] for m in PAIRED_METRICS}
    keys: dict[str, list[str]] = {m.key: [] for m in PAIRED_METRICS}
    for a, b in pairs:
        row: dict[str, Any] = {
            "model": labels[a],
            "ablation": runs[b].info.inputs,
            "ablated": labels[b],
            "convention": convention,
        }
        for metric in PAIRED_METRICS:
            va, vb, scenes = cols.paired(a, b, metric.key)
            if metric is PAIRED_METRICS[0]:
                row.update(frames=len(va), scenes=len(set(scenes.tolist())))
            _add_pair(
                row,
                groups,
                keys,
                metric.key,
                (("full", va), ("ablated", vb)),
                "diff",
                va - vb,
                scenes,
                f"ablation|{labels[a]}|{labels[b]}|{metric.key}|{convention}",
            )
        rows.append(row)
    _with_statistics(rows, groups, keys, "diff", resampling)
    return rows


def _add_pair(
    row: dict[str, Any],
    groups: dict[str, list[Any]],
    keys: dict[str, list[str]],
    metric: str,
    sides: tuple[tuple[str, np.ndarray], tuple[str, np.ndarray]],
    diff_name: str,
    diff: np.ndarray,
    scenes: np.ndarray,
    key: str,
) -> None:
    """One metric of one paired row: each side's mean, the mean difference (None without common frames), and the
    per-frame differences with their scenes and the bootstrap key for :func:`_with_statistics`."""
    has = len(diff) > 0
    row.update({f"{metric}_{name}": float(values.mean()) if has else None for name, values in sides})
    row[f"{metric}_{diff_name}"] = float(diff.mean()) if has else None
    groups[metric].append((diff, scenes) if has else None)
    keys[metric].append(key)


def baseline_gains(
    runs: Sequence[RunData],
    labels: Sequence[str],
    convention: str,
    resampling: Resampling,
    *,
    only: set[str] | None = None,
) -> list[dict[str, Any]]:
    """Per model run (every non-baseline run, ablated ones too), its gain over the best baseline (see the module docstring).

    The best baseline is, among the runs of :data:`GAIN_BASELINES`, the one with the lowest mean of the first
    metric (ADE avg) on the frames scored in both it and the model — the hardest one to beat on those frames.
    Row keys: ``model``, ``inputs``, ``baseline``, ``convention``, ``frames``, ``scenes``, and per metric
    ``m``: ``m_model``, ``m_baseline``, ``m_gain`` (baseline − model), ``m_ci95``, ``m_p``, ``m_p_holm``,
    ``m_significant``. Empty without a baseline run or a model run.
    """
    base = [i for i, r in enumerate(runs) if r.info.model in GAIN_BASELINES]
    models = [i for i, r in enumerate(runs) if not r.info.model.startswith("baseline:")]
    if not base or not models:
        return []
    cols = _Columns(runs, convention, only)
    first = PAIRED_METRICS[0].key
    rows: list[dict[str, Any]] = []
    groups: dict[str, list[Any]] = {m.key: [] for m in PAIRED_METRICS}
    keys: dict[str, list[str]] = {m.key: [] for m in PAIRED_METRICS}
    for m in models:
        scores = []
        for b in base:
            vm, vb, _ = cols.paired(m, b, first)
            if len(vm):
                scores.append((float(vb.mean()), b))
        best = min(scores, key=lambda s: (s[0], labels[s[1]]))[1] if scores else None
        row: dict[str, Any] = {
            "model": labels[m],
            "inputs": runs[m].info.inputs,
            "baseline": labels[best] if best is not None else None,
            "convention": convention,
            "frames": 0,
            "scenes": 0,
        }
        for metric in PAIRED_METRICS:
            if best is None:
                vm = vb = np.zeros(0)
                scenes = np.zeros(0, dtype=object)
            else:
                vm, vb, scenes = cols.paired(m, best, metric.key)
            if metric.key == first:
                row.update(frames=len(vm), scenes=len(set(scenes.tolist())))
            _add_pair(
                row,
                groups,
                keys,
                metric.key,
                (("model", vm), ("baseline", vb)),
                "gain",
                vb - vm,
                scenes,
                f"gain|{labels[m]}|{labels[best] if best is not None else ''}|{metric.key}|{convention}",
            )
        rows.append(row)
    _with_statistics(rows, groups, keys, "gain", resampling)
    return rows
