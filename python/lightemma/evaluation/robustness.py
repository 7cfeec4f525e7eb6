"""How robust is it? Each variant of a sweep paired with the sweep's clean run (docs/definitions.md#robustness-sweeps).

A run belongs to a sweep (:mod:`lightemma.pipeline.variant_sweep`) when the folder two levels above its model folder holds a
``sweep.json`` naming its variant folder (``OUT/<variant>/<model>/<run_id>``). For each sweep among the evaluated
runs whose clean run is evaluated too, every other variant's run is paired with the clean run on the frames that have
a value in both, per metric of :func:`robustness_metrics` (ADE avg; off-road and collision where the safety metrics
were computed; the planning score's headline where it was; a metric without a value in any pair is left out):

* ``m_clean``, ``m_variant``: each run's mean on those frames; ``m_diff`` = variant − clean (the degradation: for
  ADE, off-road and collision > 0 is worse; for the planning score < 0 is worse);
* ``m_ci95``: the scene-bootstrap interval of the mean difference, ``m_p``: the sign-flip p over scenes, and
  ``m_p_holm`` / ``m_significant``: Holm's adjustment over every row of the table, per metric — the paired test and
  Holm code of :mod:`lightemma.evaluation.stats` (docs/statistics.md).

The visual-reliance summary (:func:`visual_reliance`) is the rows of ``no-image`` and ``blank-image`` variants with
``reliance_pct`` = 100 · (ADE avg without the image − clean) / clean ADE avg.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lightemma.corruptions import parse_corruption
from lightemma.definitions import COLLISION_FOR_ADE
from lightemma.errors import UserError
from lightemma.evaluation.descriptors import ADE_BY_CONVENTION, COLLISION_BY_CONVENTION, PLANNING_BY_KEY
from lightemma.evaluation.safety import safety_values
from lightemma.evaluation.stats import Resampling, bootstrap_ci, holm, sign_flip_p
from lightemma.evaluation.uncertainty import frame_values
from lightemma.pipeline.variant_sweep import read_sweep

#: the image ablations of the visual-reliance summary
IMAGE_ABLATIONS = ("no-image", "blank-image")
#: the row keys that are not per-metric
LABEL_KEYS = ("sweep", "model", "variant", "corruption", "severity", "clean", "convention", "frames", "scenes")


@dataclass(frozen=True)
class SweepMember:
    """A run's place in a sweep: the sweep folder, its manifest and the run's (canonical) variant."""

    sweep_dir: Path
    manifest: dict[str, Any]
    variant: str


def sweep_member(run_dir: str | Path) -> SweepMember | None:
    """The sweep ``run_dir`` belongs to (``SWEEP/<variant folder>/<model>/<run_id>``), or None when it belongs to none
    (no ``sweep.json`` there, an unreadable one, or one that does not list the run's variant folder)."""
    path = Path(run_dir).resolve()
    if len(path.parents) < 3:
        return None
    sweep_dir = path.parents[2]
    try:
        doc = read_sweep(sweep_dir)
    except UserError:
        return None
    if doc is None:
        return None
    folder = path.relative_to(sweep_dir).parts[0]
    for entry in doc["variants"]:
        if entry.get("folder") == folder:
            return SweepMember(sweep_dir, doc, entry["variant"])
    return None


@dataclass(frozen=True)
class RobustnessMetric:
    """One paired metric: row-key prefix, title, unit, descriptor id, and whether lower is better."""

    key: str
    title: str
    unit: str
    id: str
    lower_is_better: bool


@dataclass
class RobustnessResult:
    """The robustness table's rows, the visual-reliance rows, the metrics compared, the sweeps, warnings."""

    rows: list[dict[str, Any]]
    reliance: list[dict[str, Any]]
    metrics: list[RobustnessMetric]
    sweeps: list[dict[str, Any]]
    warnings: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able: ``metrics`` (row-key prefix -> metric id), the difference's sign, the Holm family, the sweeps,
        ``rows`` and ``visual_reliance``."""
        return {
            "metrics": {m.key: m.id for m in self.metrics},
            "difference": "variant - clean, on the frames with a value in both (paired)",
            "holm_family": "the rows of the robustness table, per metric",
            "sweeps": self.sweeps,
            "rows": self.rows,
            "visual_reliance": self.reliance,
        }


def robustness_metrics(convention: str, safety: Any, planning: Any) -> list[RobustnessMetric]:
    """ADE avg of ``convention``; off-road and collision (that convention's collision rule) with ``safety``; the
    planning score's headline with ``planning`` (as evaluated)."""
    out = [RobustnessMetric("ade_avg", "ADE avg", "m", ADE_BY_CONVENTION[convention], True)]
    if safety is not None and any(rs.model is not None for rs in safety.runs.values()):
        out.append(RobustnessMetric("offroad", "Off-road", "share", "offroad@footprint/1", True))
        out.append(
            RobustnessMetric(
                "collision", "Collision", "share", COLLISION_BY_CONVENTION[COLLISION_FOR_ADE[convention]], True
            )
        )
    if planning is not None and any(rp.values for rp in planning.runs.values()):
        headline = planning.headline
        out.append(
            RobustnessMetric(
                headline, headline.upper().replace("_MAP", " (map)"), "share", PLANNING_BY_KEY[headline], False
            )
        )
    return out


def _per_frame(
    label: str,
    run: Any,
    rows: np.ndarray,
    metric: RobustnessMetric,
    convention: str,
    safety: Any,
    planning: Any,
    only: set[str] | None,
) -> dict[str, float]:
    """frame id -> the run's value of ``metric`` on its scored ``rows`` (frames without a value left out)."""
    if metric.key == "ade_avg":
        ids = [run.frame_ids[i] for i in rows]
        values = frame_values(run, rows, convention)[:, 0] if len(rows) else np.zeros(0)
    elif metric.key in ("offroad", "collision"):
        rs = safety.runs.get(label) if safety is not None else None
        if rs is None or rs.model is None:
            return {}
        ids, values = rs.frame_ids, safety_values(rs.model, COLLISION_FOR_ADE[convention], gt=rs.truth)[metric.key]
    else:
        rp = planning.runs.get(label) if planning is not None else None
        if rp is None or metric.key not in rp.values:
            return {}
        ids, values = rp.frame_ids, rp.values[metric.key]
    return {f: float(v) for f, v in zip(ids, values, strict=True) if math.isfinite(v) and (only is None or f in only)}


def _scene_names(run: Any) -> dict[str, str]:
    codes = run.scenes()
    return {fid: (run.scene_names[c] if run.scene_names else fid) for fid, c in zip(run.frame_ids, codes, strict=True)}


def _variant_parts(variant: str) -> tuple[str | None, int | None]:
    try:
        parsed = parse_corruption(variant)
    except ValueError:
        return None, None
    return (parsed[0], parsed[1]) if parsed is not None else (None, None)


def evaluate_robustness(
    entries: Sequence[tuple[str, Any, np.ndarray]],
    convention: str,
    resampling: Resampling,
    *,
    safety: Any = None,
    planning: Any = None,
    only: set[str] | None = None,
) -> RobustnessResult | None:
    """The robustness table of the sweeps among ``entries`` ((label, RunData, scored rows) as in
    :func:`~lightemma.evaluation.evaluate_loaded`); None when no evaluated run belongs to a sweep.

    Row keys: :data:`LABEL_KEYS` (``model``: the variant run's label, ``clean``: the clean run's, ``frames`` /
    ``scenes``: behind the ADE pair) and per metric ``m``: ``m_clean``, ``m_variant``, ``m_diff`` (variant − clean),
    ``m_ci95``, ``m_p``, ``m_p_holm``, ``m_significant`` (None where the pair has no frame with a value in both).
    A sweep whose clean run is not evaluated gets a warning and no rows.
    """
    members: dict[Path, list[tuple[str, Any, np.ndarray, SweepMember]]] = {}
    for label, run, rows in entries:
        member = sweep_member(run.info.run_dir)
        if member is not None:
            members.setdefault(member.sweep_dir, []).append((label, run, rows, member))
    if not members:
        return None
    metrics = robustness_metrics(convention, safety, planning)
    result = RobustnessResult(rows=[], reliance=[], metrics=metrics, sweeps=[])
    groups: dict[str, list[tuple[np.ndarray, np.ndarray] | None]] = {m.key: [] for m in metrics}
    keys: dict[str, list[str]] = {m.key: [] for m in metrics}
    for sweep_dir, runs in members.items():
        clean = [r for r in runs if r[3].variant == "clean"]
        order = [e["variant"] for e in runs[0][3].manifest["variants"]]
        result.sweeps.append(
            {
                "sweep": str(sweep_dir),
                "model": runs[0][3].manifest.get("model"),
                "clean": clean[0][0] if len(clean) == 1 else None,
                "variants": {r[3].variant: r[0] for r in runs},
            }
        )
        if len(clean) != 1:
            what = (
                "its clean run is not among the runs evaluated"
                if not clean
                else f"{len(clean)} clean runs are evaluated"
            )
            result.warnings.append(
                f"sweep {sweep_dir}: {what}; no robustness rows for it (evaluate the whole sweep folder)"
            )
            continue
        c_label, c_run, c_rows, _ = clean[0]
        scene_of = _scene_names(c_run)
        clean_values = {
            m.key: _per_frame(c_label, c_run, c_rows, m, convention, safety, planning, only) for m in metrics
        }
        for label, run, rows, member in sorted(
            (r for r in runs if r[3].variant != "clean"),
            key=lambda r: order.index(r[3].variant) if r[3].variant in order else len(order),
        ):
            name, severity = _variant_parts(member.variant)
            row: dict[str, Any] = {
                "sweep": str(sweep_dir),
                "model": label,
                "variant": member.variant,
                "corruption": name,
                "severity": severity,
                "clean": c_label,
                "convention": convention,
            }
            for metric in metrics:
                mine = _per_frame(label, run, rows, metric, convention, safety, planning, only)
                theirs = clean_values[metric.key]
                common = [f for f in theirs if f in mine]
                variant_v = np.array([mine[f] for f in common])
                clean_v = np.array([theirs[f] for f in common])
                scenes = np.array([scene_of.get(f, f.rsplit("/", 1)[0]) for f in common], dtype=object)
                if metric.key == "ade_avg":
                    row.update(frames=len(common), scenes=len(set(scenes.tolist())))
                has = len(common) > 0
                diff = variant_v - clean_v
                row.update(
                    {
                        f"{metric.key}_clean": float(clean_v.mean()) if has else None,
                        f"{metric.key}_variant": float(variant_v.mean()) if has else None,
                        f"{metric.key}_diff": float(diff.mean()) if has else None,
                    }
                )
                groups[metric.key].append((diff, scenes) if has else None)
                keys[metric.key].append(f"robustness|{c_label}|{label}|{metric.key}|{convention}")
            result.rows.append(row)
    _statistics(result.rows, metrics, groups, keys, resampling)
    # a metric no pair has a value of (no map, no annotations for it): no columns of dashes
    empty = [m for m in metrics[1:] if result.rows and all(r.get(f"{m.key}_diff") is None for r in result.rows)]
    for m in empty:
        for row in result.rows:
            for suffix in ("clean", "variant", "diff", "ci95", "p", "p_holm", "significant"):
                row.pop(f"{m.key}_{suffix}", None)
    result.metrics = [m for m in metrics if m not in empty]
    result.reliance = visual_reliance(result.rows)
    return result


def _statistics(
    rows: list[dict[str, Any]],
    metrics: Sequence[RobustnessMetric],
    groups: dict[str, list[tuple[np.ndarray, np.ndarray] | None]],
    keys: dict[str, list[str]],
    resampling: Resampling,
) -> None:
    """``m_ci95``, ``m_p``, ``m_p_holm``, ``m_significant`` of every row: one bootstrap and one sign-flip call per
    metric
    (:mod:`lightemma.evaluation.stats`), Holm over the rows per metric."""
    alpha = 1.0 - resampling.confidence
    for metric in metrics:
        k = metric.key
        present = [i for i, g in enumerate(groups[k]) if g is not None]
        data = [g for g in groups[k] if g is not None]
        names = [keys[k][i] for i in present]
        ci = bootstrap_ci(data, names, resampling) if data else np.zeros((0, 1, 2))
        p = sign_flip_p(data, names, resampling) if data else np.zeros(0)
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
                if row.get(f"{k}_diff") is not None
                else None
            )


def visual_reliance(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """The rows of the image ablations (:data:`IMAGE_ABLATIONS`) with their ADE columns and ``reliance_pct`` = 100 ·
    ADE diff / clean ADE (None where the clean ADE is 0 or missing)."""
    out = []
    for row in rows:
        if row["variant"] not in IMAGE_ABLATIONS:
            continue
        clean, diff = row.get("ade_avg_clean"), row.get("ade_avg_diff")
        out.append(
            {
                **{k: row[k] for k in ("sweep", "model", "variant", "clean", "convention", "frames", "scenes")},
                **{
                    f"ade_avg_{s}": row.get(f"ade_avg_{s}")
                    for s in ("clean", "variant", "diff", "ci95", "p_holm", "significant")
                },
                "reliance_pct": 100.0 * diff / clean if clean and diff is not None else None,
            }
        )
    return out
