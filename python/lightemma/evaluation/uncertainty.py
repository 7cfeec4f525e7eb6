"""Intervals for every accuracy row and paired comparisons between runs (docs/statistics.md).

* :func:`model_intervals` — scene-bootstrap 95 % intervals of ADE avg and FDE,
  every model and convention in one core call;
* :func:`pairwise_ade` — every pair of runs on the frames scored in both:
  mean paired ADE-avg difference (a − b), its scene-bootstrap interval, a
  sign-flip permutation p-value over scenes and Holm's adjustment over all pairs;
* :func:`generation_verdicts` — per family, each generation against its
  predecessor: better, worse, or not distinguishable.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from lightemma.evaluation.loading import RunData
from lightemma.evaluation.stats import Resampling, bootstrap_ci, mark_holm, sign_flip_p
from lightemma.metrics import frame_metrics

INTERVAL_KEYS: tuple[str, ...] = ("ade_avg", "fde")
_COLUMNS = (3, 4)  # ade_avg, fde in lightemma.metrics.FRAME_METRICS
BLOCK = 1 << 16


def frame_values(run: RunData, rows: np.ndarray, convention: str) -> np.ndarray:
    """(len(rows), 2): per-frame ADE avg and FDE of scored ``rows`` under ``convention`` (Rust core, in blocks)."""
    out = np.empty((len(rows), len(_COLUMNS)))
    for start in range(0, len(rows), BLOCK):
        block = rows[start : start + BLOCK]
        values = frame_metrics(
            np.ascontiguousarray(run.trajectory[block]),
            np.ascontiguousarray(run.gt_positions[block]),
            convention=convention,
        )
        out[start : start + len(block)] = values[:, _COLUMNS]
    return out


def _interval(pair: np.ndarray) -> list[float] | None:
    return [float(pair[0]), float(pair[1])] if np.isfinite(pair).all() else None


def too_large(values: np.ndarray, scenes: np.ndarray, what: str = "ADE avg") -> str | None:
    """Why ``values`` (N,) or (N, M) cannot be resampled, or None when they can.

    A resample sums up to one cluster sum per scene drawn, so every such sum must stay finite: with
    huge finite errors (an answer of 1e300 m/s read under ``--keep-implausible``) it does not, and the
    interval is unavailable rather than the whole evaluation stopped. The reason gives the largest
    value in short scientific notation.
    """
    if values.size == 0:
        return None
    with np.errstate(over="ignore", invalid="ignore"):
        worst = np.abs(values).sum(axis=0) * max(len(np.unique(scenes)), 1)
    if np.isfinite(worst).all():
        return None
    largest = float(np.max(np.abs(values[:, 0] if values.ndim == 2 else values)))
    return f"interval unavailable: values too large to resample ({what} up to {largest:.3g} m)"


def model_intervals(
    entries: Sequence[tuple[str, RunData, np.ndarray]], conventions: Sequence[str], resampling: Resampling
) -> list[dict[str, dict[str, list[float] | None]]]:
    """Per entry (label, run, scored rows): {convention: {"ade_avg": [low, high], "fde": [low, high]}}.

    One core call for every model and convention; a model's random numbers
    depend on its label only, so its FDE interval is the same in every
    convention's table. None where there is no interval (fewer than 2 scenes);
    where values too large to resample leave none, ``"unavailable"`` says why
    (:func:`too_large`) and the other rows are computed as usual.
    """
    groups, keys, why = [], [], []
    for convention in conventions:
        for label, run, rows in entries:
            values, scenes = frame_values(run, rows, convention), run.scenes()[rows]
            reason = too_large(values, scenes)
            groups.append((np.zeros_like(values) if reason else values, scenes))
            keys.append(label)
            why.append(reason)
    ci = bootstrap_ci(groups, keys, resampling) if groups else np.zeros((0, 2, 2))
    out: list[dict[str, dict[str, Any]]] = [{} for _ in entries]
    for c, convention in enumerate(conventions):
        for i in range(len(entries)):
            k = c * len(entries) + i
            row = ci[k]
            out[i][convention] = {key: None if why[k] else _interval(row[j]) for j, key in enumerate(INTERVAL_KEYS)}
            if why[k]:
                out[i][convention]["unavailable"] = why[k]
    return out


def _global_columns(runs: Sequence[RunData], convention: str, only: set[str] | None) -> tuple[np.ndarray, np.ndarray]:
    """Per run, ADE avg over one shared frame axis (NaN where not scored), and a scene code per frame."""
    universe: dict[str, int] = {}
    for run in runs:
        for fid in run.frame_ids:
            universe.setdefault(fid, len(universe))
    values = np.full((len(runs), len(universe)), np.nan)
    scene = np.full(len(universe), -1, dtype=np.int64)
    scene_codes: dict[str, int] = {}
    for r, run in enumerate(runs):
        where = np.fromiter((universe[f] for f in run.frame_ids), dtype=np.int64, count=len(run))
        rows = np.flatnonzero(run.valid)
        if only is not None:
            rows = rows[np.fromiter((run.frame_ids[i] in only for i in rows), dtype=bool, count=len(rows))]
        values[r, where[rows]] = frame_values(run, rows, convention)[:, 0]
        names = (
            np.asarray(run.scene_names, dtype=object)[run.scenes()]
            if run.scene_names
            else np.asarray(run.frame_ids, dtype=object)
        )
        unset = scene[where] < 0
        scene[where[unset]] = [scene_codes.setdefault(n, len(scene_codes)) for n in names[unset]]
    return values, scene


def pairwise_ade(
    runs: Sequence[RunData],
    labels: Sequence[str],
    convention: str,
    resampling: Resampling,
    *,
    only: set[str] | None = None,
) -> list[dict[str, Any]]:
    """Every pair (a, b) of runs, a listed before b, on the frames scored in both (within ``only`` if given).

    Row keys: ``model_a``, ``model_b``, ``convention``, ``frames``, ``scenes``,
    ``ade_avg_diff`` (mean over common frames of ADE avg of a − of b; negative:
    a is better), ``ci95`` (scene bootstrap), ``p_value`` (sign flips of scene
    differences), ``p_holm`` (Holm over all pairs), ``significant``
    (``p_holm`` ≤ 1 − confidence). Pairs without a common frame get None.
    """
    values, scene = _global_columns(runs, convention, only)
    pairs, groups, keys, why = [], [], [], []
    for a in range(len(runs)):
        for b in range(a + 1, len(runs)):
            common = np.isfinite(values[a]) & np.isfinite(values[b])
            pairs.append((a, b, common))
            if common.any():
                with np.errstate(over="ignore", invalid="ignore"):
                    diff = values[a, common] - values[b, common]
                reason = too_large(diff, scene[common], "ADE avg difference")
                groups.append((np.zeros_like(diff) if reason else diff, scene[common]))
                keys.append(f"{labels[a]}|{labels[b]}|{convention}")
                why.append(reason)
    ci = bootstrap_ci(groups, keys, resampling) if groups else np.zeros((0, 1, 2))
    p = sign_flip_p(groups, keys, resampling) if groups else np.zeros(0)
    rows, k = [], 0
    for a, b, common in pairs:
        row: dict[str, Any] = {
            "model_a": labels[a],
            "model_b": labels[b],
            "convention": convention,
            "frames": int(common.sum()),
            "scenes": int(len(np.unique(scene[common]))),
        }
        if common.any() and why[k]:
            with np.errstate(over="ignore", invalid="ignore"):
                mean = float(np.sum((values[a, common] - values[b, common]) / int(common.sum())))
            row.update(ade_avg_diff=mean if np.isfinite(mean) else None, ci95=None, p_value=None, note=why[k])
            k += 1
        elif common.any():
            diff = groups[k][0]
            row.update(
                ade_avg_diff=float(diff.mean()),
                ci95=_interval(ci[k, 0]),
                p_value=None if np.isnan(p[k]) else float(p[k]),
            )
            k += 1
        else:
            row.update(ade_avg_diff=None, ci95=None, p_value=None)
        rows.append(row)
    mark_holm(rows, resampling.confidence)
    return rows


def generation_verdicts(models: Sequence[Any], pairwise: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per family, each generation against the one before it present in the runs.

    ``models``: objects with ``label``, ``family``, ``generation`` (e.g.
    :class:`~lightemma.evaluation.ModelResult`), in table order. A verdict is
    ``better`` / ``worse`` when the pairwise difference is significant after
    Holm's adjustment, else ``not distinguishable``. ``change`` is the ADE avg
    of the newer model minus the older (negative: the newer one is better).
    Baselines and models without a generation are left out.
    """
    by_pair = {(r["model_a"], r["model_b"]): r for r in pairwise}
    families: dict[str, list[Any]] = {}
    for m in models:
        if m.generation and m.family not in ("Baseline", "Other"):
            families.setdefault(m.family, [])
            if all(o.generation != m.generation for o in families[m.family]):
                families[m.family].append(m)
    out = []
    for family, members in families.items():
        members = sorted(members, key=lambda m: m.generation)
        for older, newer in zip(members, members[1:]):
            row = by_pair.get((older.label, newer.label))
            flip = 1.0
            if row is None:
                row, flip = by_pair.get((newer.label, older.label)), -1.0
            if row is None or row["ade_avg_diff"] is None:
                continue
            change = -flip * row["ade_avg_diff"]  # newer − older
            ci = row["ci95"]
            ci_change = None if ci is None else sorted([-flip * ci[0], -flip * ci[1]])
            verdict = ("better" if change < 0 else "worse") if row["significant"] else "not distinguishable"
            out.append(
                {
                    "family": family,
                    "model": newer.label,
                    "predecessor": older.label,
                    "frames": row["frames"],
                    "change": change,
                    "ci95": ci_change,
                    "p_holm": row["p_holm"],
                    "verdict": verdict,
                }
            )
    return out
