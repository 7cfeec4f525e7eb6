"""The metric registry: what every column lightemma prints is, as data (docs/evaluate.md#what-each-number-is).

Each column of ``lightemma evaluate``'s tables maps to a :class:`Descriptor` with an id of the form
``name@variant/version`` (``ade@lightemma/1``, ``l2@uniad/1``, ``miss@2m/1``, ``collision@uniad/1``), its unit, the
range its values can take, whether lower is better, its source and the ``docs/definitions.md`` anchor that defines it.
A change to how a metric is computed bumps its version here; tests/unit/metrics/test_golden_metrics.py pins each metric's value on a
small fixed input under its id, so a value that moves without a bump fails there.

:func:`column_descriptors` gives the descriptors of a table's columns (the ``columns`` block of
``evaluate --format json``), :func:`provenance` the block that says where the numbers come from, and
:func:`check_evaluation_json` refuses, in one line naming the file and the field, a JSON document that this version of
lightemma did not write or whose values break their descriptors (a rate above 1).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeGuard

from lightemma.errors import InputError, UserError

#: the ``format`` of ``lightemma evaluate --format json`` documents (bumped when a key changes meaning or goes away)
EVALUATE_FORMAT = "lightemma-evaluate/1"

_DEFS = "docs/definitions.md"


@dataclass(frozen=True)
class Descriptor:
    """What one column is.

    ``id``: ``name@variant/version`` (or ``name/version``); ``unit``: ``m``, ``share`` (0 … 1), ``%`` (0 … 100), ``s``,
    ``¢``, ``tokens``, ``frames``, ``1/s`` … or None for a label; ``range``: (low, high) the values lie in, either end
    None when unbounded; ``lower_is_better``: None for a column that is not a score (a count, a label); ``kind``:
    ``metric``, ``rate``, ``count``, ``interval``, ``test`` or ``label``; ``source``: where the definition comes from;
    ``anchor``: the section of ``docs/definitions.md`` (or another page) that defines it.
    """

    id: str
    title: str
    kind: str
    unit: str | None
    range: tuple[float | None, float | None] | None
    lower_is_better: bool | None
    source: str
    anchor: str

    @property
    def name(self) -> str:
        """The id without its version: ``ade@lightemma``."""
        return self.id.rsplit("/", 1)[0]

    @property
    def version(self) -> int:
        """The definition's version (the number after the last ``/``)."""
        return int(self.id.rsplit("/", 1)[1])

    def to_dict(self) -> dict[str, Any]:
        """JSON-able: every field, ``range`` as a two-element list (null ends) or null."""
        return {
            "id": self.id,
            "title": self.title,
            "kind": self.kind,
            "unit": self.unit,
            "range": list(self.range) if self.range is not None else None,
            "lower_is_better": self.lower_is_better,
            "version": self.version,
            "source": self.source,
            "anchor": self.anchor,
        }


def _d(
    id: str,
    title: str,
    kind: str,
    unit: str | None,
    range: tuple[float | None, float | None] | None,
    lower: bool | None,
    source: str,
    anchor: str,
) -> Descriptor:
    return Descriptor(id, title, kind, unit, range, lower, source, anchor)


_M = f"{_DEFS}#metrics"
_S = f"{_DEFS}#safety"
_U = f"{_DEFS}#uncertainty-and-paired-comparisons"
_E = f"{_DEFS}#efficiency"
_F = f"{_DEFS}#format-errors"
_P = f"{_DEFS}#planning-score"
_A = f"{_DEFS}#input-ablations"
_FRAME_SETS = "docs/evaluate.md#runs-on-different-frame-sets"
_X = f"{_DEFS}#explanation-audit"
_O = f"{_DEFS}#described-objects"
_METERS = (0.0, None)
_SHARE = (0.0, 1.0)
_PCT = (0.0, 100.0)

#: every metric lightemma computes, by id (the versions tests/unit/metrics/test_golden_metrics.py pins)
METRICS: dict[str, Descriptor] = {
    d.id: d
    for d in (
        _d(
            "ade@lightemma/1",
            "ADE, lightemma convention (mean of the errors in each second; avg: mean(e1 … e6))",
            "metric",
            "m",
            _METERS,
            True,
            "LightEMMA paper, Table II",
            _M,
        ),
        _d(
            "l2@stp3/1",
            "L2, ST-P3 convention (mean of the errors over 0.5 s … T; avg: mean of the three columns)",
            "metric",
            "m",
            _METERS,
            True,
            "ST-P3 / VAD metric_stp3.py",
            _M,
        ),
        _d(
            "l2@uniad/1",
            "L2, UniAD convention (the error at T; avg: mean of the three columns)",
            "metric",
            "m",
            _METERS,
            True,
            "UniAD planning metric",
            _M,
        ),
        _d(
            "fde/1",
            "FDE: the error at 3 s (e6)",
            "metric",
            "m",
            _METERS,
            True,
            "standard (final displacement error)",
            _M,
        ),
        _d(
            "fe@paper/1",
            "Format-error rate: first received answer not ok",
            "rate",
            "%",
            _PCT,
            True,
            "LightEMMA paper, Table II",
            _F,
        ),
        _d(
            "fe_corr@paper/1",
            "Format-error rate after correction: first received answer failed",
            "rate",
            "%",
            _PCT,
            True,
            "LightEMMA paper, Table II",
            _F,
        ),
        _d(
            "collision@uniad/1",
            "Collision rate at 1 / 2 / 3 s (UniAD obj_box_col); ground-truth collisions masked",
            "rate",
            "share",
            _SHARE,
            True,
            "UniAD obj_box_col",
            _S,
        ),
        _d(
            "collision@stp3/1",
            "Collision rate averaged over 0.5 s … T (ST-P3 / VAD); ground-truth collisions masked",
            "rate",
            "share",
            _SHARE,
            True,
            "ST-P3 / VAD metric_stp3.py",
            _S,
        ),
        _d(
            "collision@any/1",
            "Share of frames colliding anywhere in 0.5 s … T (not masked)",
            "rate",
            "share",
            _SHARE,
            True,
            "BEV-Planner, VADv2",
            _S,
        ),
        _d(
            "offroad@footprint/1",
            "Share of frames with some footprint corner off the drivable area (at some step, or at T)",
            "rate",
            "share",
            _SHARE,
            True,
            "NAVSIM DAC (any ego corner, any step)",
            _S,
        ),
        _d(
            "offroad@centre/1",
            "Share of frames whose reference point leaves the drivable area at some step",
            "rate",
            "share",
            _SHARE,
            True,
            "nuScenes devkit off-road test of ego poses",
            _S,
        ),
        _d(
            "pdms@nuscenes/1",
            "NAVSIM PDMS (v1) on nuScenes keyframes",
            "metric",
            "share",
            _SHARE,
            False,
            "NAVSIM pdm_scorer.py",
            _P,
        ),
        _d(
            "epdms@nuscenes/1",
            "NAVSIM EPDMS (v2) on nuScenes keyframes, human-penalty filter",
            "metric",
            "share",
            _SHARE,
            False,
            "NAVSIM pdm_scorer.py",
            _P,
        ),
        _d(
            "epdms_map@nuscenes/1",
            "EPDMS without agents (v1.0-test): dac·ddc·(5ep + 2lk + 2hc + 2ec)/11",
            "metric",
            "share",
            _SHARE,
            False,
            "lightemma, after NAVSIM",
            _P,
        ),
        *(
            _d(f"{key}@navsim/1", title, "metric", "share", _SHARE, False, "NAVSIM pdm_scorer.py", _P)
            for key, title in (
                ("nc", "No at-fault collision (NC)"),
                ("dac", "Drivable-area compliance (DAC)"),
                ("ddc", "Driving-direction compliance (DDC)"),
                ("tlc", "Traffic-light compliance (TLC; n/a on nuScenes)"),
                ("ep", "Ego progress (EP), the ground truth standing in for PDM-Closed"),
                ("ttc", "Time to collision (TTC)"),
                ("lk", "Lane keeping (LK)"),
            )
        ),
        *(
            _d(
                f"{key}@navsim/1",
                title,
                "metric",
                "share",
                _SHARE,
                False,
                "NAVSIM pdm_comfort_metrics.py",
                f"{_DEFS}#re-simulation-and-comfort",
            )
            for key, title in (
                ("c", "Comfort (C), NAVSIM v1"),
                ("hc", "History comfort (HC), NAVSIM v2"),
                ("ec", "Extended comfort (EC), NAVSIM v2"),
            )
        ),
    )
}

#: the planning score's columns (lightemma.evaluation.planning_score.KEYS) -> descriptor id
PLANNING_BY_KEY: dict[str, str] = {
    "pdms": "pdms@nuscenes/1",
    "epdms": "epdms@nuscenes/1",
    "epdms_map": "epdms_map@nuscenes/1",
    **{k: f"{k}@navsim/1" for k in ("nc", "dac", "ddc", "tlc", "ep", "ttc", "lk", "c", "hc", "ec")},
}

#: the version of the miss-rate definition; its id carries the threshold: ``miss@2m/1``
MISS_VERSION = 1


def miss_descriptor(threshold: float) -> Descriptor:
    """The miss rate at ``threshold`` metres: ``miss@2m/1`` (a share of frames; docs/definitions.md#metrics)."""
    if not (isinstance(threshold, (int, float)) and math.isfinite(threshold) and threshold > 0):
        raise InputError(f"miss threshold must be a positive number of metres, got {threshold!r}")
    return _d(
        f"miss@{threshold:g}m/{MISS_VERSION}",
        f"Miss rate: share of frames whose largest error exceeds {threshold:g} m",
        "rate",
        "share",
        _SHARE,
        True,
        "standard (miss rate)",
        _M,
    )


#: the ADE / L2 descriptor of each convention (``lightemma evaluate --convention``)
ADE_BY_CONVENTION: dict[str, str] = {"lightemma": "ade@lightemma/1", "stp3": "l2@stp3/1", "uniad": "l2@uniad/1"}
#: the columns of a ``--samples K`` run (docs/definitions.md#k-samples), by row key; ``minade`` per ADE convention
_K = f"{_DEFS}#k-samples"
_BEST_OF_K = "best of K samples (Alpamayo-R1 minADE over sampled trajectories; WOD-E2E)"
SAMPLE_METRICS: dict[str, Descriptor] = {
    **{
        f"minade@{c}": _d(
            f"minade@{c}/1",
            f"minADE@K: per frame the lowest ADE avg ({c} convention) of its K samples",
            "metric",
            "m",
            _METERS,
            True,
            _BEST_OF_K,
            _K,
        )
        for c in ("lightemma", "stp3", "uniad")
    },
    "minfde": _d(
        "minfde/1", "minFDE@K: per frame the lowest FDE of its K samples", "metric", "m", _METERS, True, _BEST_OF_K, _K
    ),
    "spread_m": _d(
        "spread@final/1",
        "Mean pairwise distance of the K samples' final points",
        "metric",
        "m",
        _METERS,
        None,
        "lightemma",
        _K,
    ),
    "samples": _d("samples/1", "Samples per frame (K)", "count", None, (1, None), None, "lightemma", _K),
    "sampled_frames": _d(
        "sampled_frames/1",
        "Scored frames with a usable sample beyond sample 0",
        "count",
        "frames",
        (0, None),
        None,
        "lightemma",
        _K,
    ),
    "best": _d(
        "best_sample/1",
        "Safety and planning keys of the best sample (by ADE avg)",
        "label",
        None,
        None,
        None,
        "lightemma",
        _K,
    ),
    "mean": _d(
        "mean_sample/1",
        "Safety and planning keys of the mean of the K samples",
        "label",
        None,
        None,
        None,
        "lightemma",
        _K,
    ),
}
#: the collision descriptor of each collision convention (a row's ``collision_convention``)
COLLISION_BY_CONVENTION: dict[str, str] = {
    "uniad": "collision@uniad/1",
    "stp3": "collision@stp3/1",
    "any": "collision@any/1",
}

#: columns that are not metrics: counts, efficiency, statistics, labels
FIELDS: dict[str, Descriptor] = {
    k: d
    for k, d in {
        # counts
        "frames": _d(
            "frames/1", "Frames behind the values of the row", "count", "frames", (0, None), None, "lightemma", _M
        ),
        "frames_accounted": _d(
            "frames_accounted/1",
            "Frames accounted: scored + failed + implausible + API errors (+ other)",
            "count",
            "frames",
            (0, None),
            None,
            "lightemma",
            _M,
        ),
        "frames_in_run": _d(
            "frames_in_run/1", "Frames recorded in the run", "count", "frames", (0, None), None, "lightemma", _M
        ),
        "scored": _d(
            "scored/1",
            "Frames scored (plausible parsed answer, finite trajectory, usable ground truth)",
            "count",
            "frames",
            (0, None),
            None,
            "lightemma",
            _M,
        ),
        "failed": _d(
            "failed/1",
            "Frames with no usable answer after every re-ask",
            "count",
            "frames",
            (0, None),
            None,
            "lightemma",
            _M,
        ),
        "implausible": _d(
            "implausible/1",
            "Frames whose answer broke the plausibility limits",
            "count",
            "frames",
            (0, None),
            None,
            "lightemma",
            _M,
        ),
        "api_errors": _d(
            "api_errors/1",
            "Frames that never got an answer (API errors)",
            "count",
            "frames",
            (0, None),
            None,
            "lightemma",
            _M,
        ),
        "unscored_other": _d(
            "unscored_other/1",
            "Frames neither scored, failed, implausible nor API errors",
            "count",
            "frames",
            (0, None),
            None,
            "lightemma",
            _M,
        ),
        "scored_pct": _d("scored_pct/1", "Share of accounted frames scored", "rate", "%", _PCT, False, "lightemma", _M),
        "low_coverage": _d(
            "low_coverage/1", "Fewer than half of the frames scored", "label", None, None, None, "lightemma", _M
        ),
        "scenes": _d(
            "scenes/1", "Scenes behind a paired comparison", "count", "scenes", (0, None), None, "lightemma", _U
        ),
        "safety_frames": _d(
            "safety_frames/1", "Frames behind the safety columns", "count", "frames", (0, None), None, "lightemma", _S
        ),
        "offroad_frames": _d(
            "offroad_frames/1", "Frames with an off-road value", "count", "frames", (0, None), None, "lightemma", _S
        ),
        # the explanation audit (lightemma.evaluation.intent_audit.KEYS): shares of frames
        **{
            key: _d(
                f"{key}@intent_lightemma/1",
                title,
                "rate",
                "share",
                _SHARE,
                lower,
                "lightemma (rules intent@lightemma/1)",
                _X,
            )
            for key, title, lower in (
                ("consistent", "Share of frames whose stated intent is consistent with the plan", False),
                ("contradicts", "Share of frames whose stated intent contradicts the plan", True),
                ("intent_unknown", "Share of frames whose stated intent cannot be checked against the plan", True),
                (
                    "intent_accuracy",
                    "Share of frames whose stated intent is consistent with the ground truth's behaviour",
                    False,
                ),
                ("intent_changed", "Share of frames whose stated intent changes under the ablation", None),
            )
        },
        **{
            f"{key}_na": _d("na/1", "Why the value is missing", "label", None, None, None, "lightemma", _X)
            for key in ("consistent", "contradicts", "intent_unknown", "intent_accuracy", "intent_changed")
        },
        **{
            f"{key}_ci95": _d(
                "ci95@scene_bootstrap/1",
                "95 % scene-level bootstrap interval of the share",
                "interval",
                "share",
                _SHARE,
                None,
                "lightemma (cluster bootstrap over scenes)",
                _U,
            )
            for key in ("consistent", "contradicts", "intent_unknown", "intent_accuracy", "intent_changed")
        },
        "explanation_frames": _d(
            "explanation_frames/1",
            "Frames behind the explanation audit",
            "count",
            "frames",
            (0, None),
            None,
            "lightemma",
            _X,
        ),
        # the described objects (lightemma.evaluation.object_audit): shares of frames / of mentions
        **{
            key: _d(
                f"{key}@objects_lightemma/1",
                title,
                "rate",
                "share",
                _SHARE,
                lower,
                "lightemma (rules objects@lightemma/1; nuScenes annotations in view of CAM_FRONT)",
                _O,
            )
            for key, title, lower in (
                (
                    "hallucinated_pedestrian",
                    "Share of frames whose description affirms a pedestrian none of the image's boxes is",
                    True,
                ),
                (
                    "missed_pedestrian",
                    "Share of frames with a pedestrian in view whose description does not affirm one",
                    True,
                ),
                ("mention_precision", "Share of affirmed class mentions whose class is in view", False),
                ("mention_recall", "Share of frames with the class in view whose description affirms it", False),
            )
        },
        **{
            f"{key}_na": _d("na/1", "Why the value is missing", "label", None, None, None, "lightemma", _O)
            for key in ("hallucinated_pedestrian", "missed_pedestrian", "mention_precision", "mention_recall")
        },
        **{
            f"{key}_ci95": _d(
                "ci95@scene_bootstrap/1",
                "95 % scene-level bootstrap interval of the share",
                "interval",
                "share",
                _SHARE,
                None,
                "lightemma (cluster bootstrap over scenes)",
                _U,
            )
            for key in ("hallucinated_pedestrian", "missed_pedestrian", "mention_precision", "mention_recall")
        },
        "object_frames": _d(
            "object_frames/1",
            "Frames with a readable description and annotation states",
            "count",
            "frames",
            (0, None),
            None,
            "lightemma",
            _O,
        ),
        "mentions": _d(
            "mentions@objects_lightemma/1",
            "Frames whose description affirms the class",
            "count",
            "frames",
            (0, None),
            None,
            "lightemma (rules objects@lightemma/1)",
            _O,
        ),
        "in_view": _d(
            "in_view@objects_lightemma/1",
            "Frames with the class in view of CAM_FRONT",
            "count",
            "frames",
            (0, None),
            None,
            "lightemma (nuScenes annotations)",
            _O,
        ),
        "class": _d("class/1", "Object class", "label", None, None, None, "lightemma", _O),
        "planning_frames": _d(
            "planning_frames/1", "Frames behind the planning score", "count", "frames", (0, None), None, "lightemma", _P
        ),
        "planning_map": _d(
            "planning_map/1", "Map layers the planning score read", "label", None, None, None, "lightemma", _P
        ),
        "map_version": _d(
            "map_version/1",
            "Version(s) of the map expansion behind the row's off-road or planning values (None: a mask, or no value)",
            "label",
            None,
            None,
            None,
            "nuScenes map expansion (its JSON's version field)",
            _S,
        ),
        "collision_frames": _d(
            "collision_frames/1", "Frames with a collision value", "count", "frames", (0, None), None, "lightemma", _S
        ),
        # efficiency (the paper's Table I)
        "seconds_per_frame": _d(
            "time@frame/1",
            "Wall time per frame, all stages and attempts",
            "metric",
            "s",
            (0, None),
            True,
            "LightEMMA paper, Table I",
            _E,
        ),
        "cost_cents_per_frame": _d(
            "cost@frame/1",
            "Cost per frame at the provider's prices",
            "metric",
            "¢",
            (0, None),
            True,
            "LightEMMA paper, Table I",
            _E,
        ),
        "cost_known_pct": _d(
            "cost_known/1", "Share of frames whose cost is known", "rate", "%", _PCT, None, "lightemma", _E
        ),
        "input_tokens": _d(
            "input_tokens@frame/1",
            "Input tokens per frame, as the provider reported them",
            "metric",
            "tokens",
            (0, None),
            True,
            "LightEMMA paper, Table I",
            _E,
        ),
        "output_tokens": _d(
            "output_tokens@frame/1",
            "Output tokens per frame, as the provider reported them",
            "metric",
            "tokens",
            (0, None),
            True,
            "LightEMMA paper, Table I",
            _E,
        ),
        "cached_pct": _d(
            "cached@frame/1", "Σ cached input tokens ÷ Σ input tokens", "rate", "%", _PCT, None, "lightemma", _E
        ),
        "gpus": _d("gpus/1", "GPUs of a local model", "count", "GPUs", (0, None), None, "LightEMMA paper, Table I", _E),
        "run_wall_seconds": _d(
            "wall@run/1",
            "The run's wall time, summed over its sessions",
            "metric",
            "s",
            (0, None),
            True,
            "lightemma",
            _E,
        ),
        "frames_per_second": _d(
            "throughput@run/1",
            "Frames per second at the run's concurrency",
            "metric",
            "1/s",
            (0, None),
            False,
            "lightemma",
            _E,
        ),
        "concurrency": _d("concurrency/1", "Requests in flight", "count", None, (0, None), None, "lightemma", _E),
        "batch_turnaround_s": _d(
            "batch_turnaround/1",
            "Mean time from a batch's submission to its results",
            "metric",
            "s",
            (0, None),
            True,
            "lightemma",
            _E,
        ),
        # statistics
        "ade_avg_ci95": _d(
            "ci95@scene_bootstrap/1",
            "95 % scene-level bootstrap interval of ADE avg",
            "interval",
            "m",
            _METERS,
            None,
            "lightemma (cluster bootstrap over scenes)",
            _U,
        ),
        "fde_ci95": _d(
            "ci95@scene_bootstrap/1",
            "95 % scene-level bootstrap interval of FDE",
            "interval",
            "m",
            _METERS,
            None,
            "lightemma (cluster bootstrap over scenes)",
            _U,
        ),
        "offroad_ci95": _d(
            "ci95@clopper_pearson/1",
            "Exact binomial 95 % interval on the scene-clustered effective sample size",
            "interval",
            "share",
            _SHARE,
            None,
            "Clopper–Pearson",
            _U,
        ),
        "collision_ci95": _d(
            "ci95@clopper_pearson/1",
            "Exact binomial 95 % interval on the scene-clustered effective sample size",
            "interval",
            "share",
            _SHARE,
            None,
            "Clopper–Pearson",
            _U,
        ),
        "ci95": _d(
            "ci95@scene_bootstrap/1",
            "95 % scene-bootstrap interval of the paired difference",
            "interval",
            None,
            None,
            None,
            "lightemma (cluster bootstrap over scenes)",
            _U,
        ),
        "p_value": _d(
            "p@signflip/1", "Sign-flip p-value of scene-level differences", "test", None, _SHARE, None, "lightemma", _U
        ),
        "p_holm": _d("p@holm/1", "Holm-adjusted p-value", "test", None, _SHARE, None, "Holm (1979)", _U),
        "significant": _d("significant/1", "p (Holm) ≤ 1 − confidence", "label", None, None, None, "lightemma", _U),
        "ade_avg_diff": _d(
            "diff@paired/1",
            "Mean paired difference of ADE avg, A − B",
            "metric",
            "m",
            (None, None),
            None,
            "lightemma",
            _U,
        ),
        "diff": _d(
            "diff@paired/1",
            "Mean paired difference of a share (a rate or a score), A − B",
            "metric",
            "share",
            (-1.0, 1.0),
            None,
            "lightemma",
            _U,
        ),
        "reliance_pct": _d(
            "reliance@ade/1",
            "Visual reliance: 100 · (ADE avg without the image − clean) / clean ADE avg, paired frames",
            "metric",
            "%",
            (None, None),
            None,
            "lightemma",
            f"{_DEFS}#robustness-sweeps",
        ),
        "change": _d(
            "diff@paired/1", "Newer − older generation, ADE avg", "metric", "m", (None, None), None, "lightemma", _U
        ),
        # labels
        **{
            key: _d(f"{key}/1", title, "label", None, None, None, "lightemma", anchor)
            for key, title, anchor in (
                ("model", "The run's display label", _M),
                ("model_a", "Model A of a pair", _U),
                ("model_b", "Model B of a pair", _U),
                ("family", "Model family", _M),
                ("predecessor", "The older generation", _U),
                ("verdict", "Newer generation is", _U),
                ("convention", "ADE convention of the row", _M),
                ("parse", "Parse definition behind statuses and metrics", f"{_DEFS}#parsing"),
                ("chain", "Request variant", f"{_DEFS}#the-three-stages"),
                ("answer_format", "Stage-3 answer format", f"{_DEFS}#parsing"),
                ("inputs", "Input ablation", _A),
                ("dataset_kind", "nuscenes or synthetic", f"{_DEFS}#frames-and-windows"),
                ("source", "paper, diff, floor or ground-truth rows (none: a run)", _M),
                ("frame_set", "Frame-set fingerprint id of the row's run", _FRAME_SETS),
                ("note", "Note after the model's name", _M),
                ("anomalous", "Cells the paper marks with a dagger", _E),
                ("ci95_unavailable", "Why a row has no interval", _U),
                ("area_source", "Drivable area read: expansion or mask", _S),
                ("collision_convention", "Collision convention", _S),
                ("offroad_na", "Why off-road is missing", _S),
                ("collision_na", "Why collision is missing", _S),
                ("metric", "Metric compared", _U),
                ("ablation", "The ablation of the ablated run", _A),
                ("ablated", "The ablated run", _A),
                ("baseline", "The best baseline on the common frames", _A),
                ("not_applicable", "Columns that do not apply to the row", _E),
                ("sweep", "The sweep folder of the row's runs", f"{_DEFS}#robustness-sweeps"),
                ("variant", "The sweep variant of the row's run", f"{_DEFS}#robustness-sweeps"),
                ("clean", "The sweep's clean run the variant is paired with", f"{_DEFS}#robustness-sweeps"),
                (
                    "corruption",
                    "The image corruption of the variant (none: not a corruption)",
                    f"{_DEFS}#robustness-sweeps",
                ),
                ("severity", "The corruption's severity, 1-5 (none: not a corruption)", f"{_DEFS}#robustness-sweeps"),
            )
        },
    }.items()
}

#: paired-metric column suffixes (lightemma.evaluation.ablations): {metric}_{suffix}
_PAIRED_SUFFIXES: dict[str, str] = {
    "full": "value",
    "ablated": "value",
    "clean": "value",
    "variant": "value",
    "model": "value",
    "baseline": "value",
    "diff": "diff",
    "gain": "diff",
    "ci95": "ci95",
    "p": "p_value",
    "p_holm": "p_holm",
    "significant": "significant",
}

#: the collision convention shown in each ADE convention's table (lightemma.evaluation.safety.COLLISION_FOR_ADE)
_COLLISION_OF_TABLE = {"lightemma": "any", "stp3": "stp3", "uniad": "uniad"}
#: columns whose descriptor depends on the table's ADE convention or the rows' collision convention
_ADE_KEYS = ("ade_1s", "ade_2s", "ade_3s", "ade_avg")
_COLLISION_KEYS = ("collision", "collision_1s", "collision_2s", "collision_3s", "collision_vehicle", "collision_vru")
_OFFROAD_KEYS = ("offroad", "offroad_1s", "offroad_2s", "offroad_3s")


def describe(
    key: str, *, convention: str | None = None, collision_convention: str | None = None, miss_threshold: float = 2.0
) -> Descriptor | None:
    """The descriptor of column ``key`` in a table of ADE ``convention`` (``lightemma``, ``stp3``, ``uniad``) whose rows
    use ``collision_convention`` (``uniad``, ``stp3``, ``any``); None for a key the registry does not know (a test
    asserts every column ``lightemma evaluate`` prints has one)."""
    if key in _ADE_KEYS:
        return METRICS[ADE_BY_CONVENTION[convention or "lightemma"]]
    if key == "fde":
        return METRICS["fde/1"]
    if key == "minade":
        return SAMPLE_METRICS[f"minade@{convention or 'lightemma'}"]
    if key in SAMPLE_METRICS:
        return SAMPLE_METRICS[key]
    if key == "miss_rate":
        return miss_descriptor(miss_threshold)
    if key == "fe_pct":
        return METRICS["fe@paper/1"]
    if key == "fe_corr_pct":
        return METRICS["fe_corr@paper/1"]
    if key in _COLLISION_KEYS:
        cc = collision_convention or _COLLISION_OF_TABLE[convention or "lightemma"]  # a row without one: its table's
        return METRICS[COLLISION_BY_CONVENTION[cc]]
    if key in _OFFROAD_KEYS:
        return METRICS["offroad@footprint/1"]
    if key == "offroad_centre":
        return METRICS["offroad@centre/1"]
    if key in PLANNING_BY_KEY:
        return METRICS[PLANNING_BY_KEY[key]]
    if key.endswith("_ci95") and key[: -len("_ci95")] in PLANNING_BY_KEY:
        return _d(
            "ci95@scene_bootstrap/1",
            "95 % scene-level bootstrap interval of the planning score",
            "interval",
            "share",
            _SHARE,
            None,
            "lightemma (cluster bootstrap over scenes)",
            _U,
        )
    if key.endswith("_na") and key[: -len("_na")] in PLANNING_BY_KEY:
        return _d("na/1", "Why the value is missing", "label", None, None, None, "lightemma", _P)
    if key in FIELDS:
        return FIELDS[key]
    head, _, suffix = key.rpartition("_")
    if head and key.endswith("_p_holm"):
        head, suffix = key[: -len("_p_holm")], "p_holm"
    if head and suffix in _PAIRED_SUFFIXES:  # {metric}_{side}: ade_avg_full, ade_avg_gain, ade_avg_p_holm …
        base = describe(
            head, convention=convention, collision_convention=collision_convention, miss_threshold=miss_threshold
        )
        if base is None:
            return None
        role = _PAIRED_SUFFIXES[suffix]
        if role == "value":
            return base
        if role == "diff":
            return _d(
                "diff@paired/1",
                f"Mean paired difference of {base.id}",
                "metric",
                base.unit,
                (None, None),
                None,
                "lightemma",
                _U,
            )
        return FIELDS["ci95" if role == "ci95" else role]
    return None


#: columns whose values depend on the map they were scored against: their descriptors carry ``map`` (:func:`map_block`)
MAP_KEYS: frozenset[str] = frozenset(
    (*_OFFROAD_KEYS, "offroad_centre", "offroad_ci95", *PLANNING_BY_KEY, *(f"{k}_ci95" for k in PLANNING_BY_KEY))
)


def map_block(rows: Sequence[Mapping[str, Any]]) -> dict[str, str | None]:
    """The ``map`` of a map-dependent column's descriptor (:data:`MAP_KEYS`): ``drivable_area``, the kinds of drivable
    area behind the table's values (the rows' ``area_source`` or ``planning_map``: ``expansion``, ``mask``, joined by
    ``+``), and ``expansion_version``, the map expansion's version(s) (the rows' ``map_version``, joined by ``+``);
    None where no row has one. Two evaluations whose maps differ have different descriptors: they are not merged."""

    def joined(keys: tuple[str, ...]) -> str | None:
        found = sorted({part for r in rows for k in keys if isinstance(r.get(k), str) for part in r[k].split("+")})
        return "+".join(found) if found else None

    return {"drivable_area": joined(("area_source", "planning_map")), "expansion_version": joined(("map_version",))}


def _table_convention(name: str) -> str | None:
    for convention in ADE_BY_CONVENTION:
        if name.endswith(f"_{convention}"):
            return convention
    return None


def column_descriptors(
    table_name: str, rows: Sequence[Mapping[str, Any]], *, convention: str | None = None, miss_threshold: float = 2.0
) -> dict[str, dict[str, Any] | None]:
    """Key -> descriptor dict (:meth:`Descriptor.to_dict`) of every key in ``rows`` of table ``table_name``
    (``accuracy_stp3``, ``efficiency``, ``pairwise_ade`` …); None for a key without one. The ADE convention is the
    table's (its name's suffix, or the rows' ``convention``), the collision convention the rows'
    ``collision_convention``."""
    keys: list[str] = []
    for row in rows:
        keys.extend(k for k in row if k not in keys)
    conv = (
        convention
        or _table_convention(table_name)
        or next((r.get("convention") for r in rows if r.get("convention") in ADE_BY_CONVENTION), None)
    )
    ccs = {r.get("collision_convention") for r in rows if r.get("collision_convention")}
    if len(ccs) > 1:
        raise UserError(
            f"table {table_name}: rows under different collision conventions "
            f"({', '.join(sorted(str(c) for c in ccs))}) in one table"
        )
    cc = next(iter(ccs), None)
    maps = map_block(rows) if any(k in MAP_KEYS for k in keys) else None
    out: dict[str, dict[str, Any] | None] = {}
    for key in keys:
        d = describe(key, convention=conv, collision_convention=cc, miss_threshold=miss_threshold)
        if (
            table_name in ("input_ablations", "baseline_gains", "robustness", "visual_reliance")
            and key.endswith("_ci95")
            and d is not None
        ):
            # these tables' intervals are of the paired difference (lightemma.evaluation.ablations): any sign
            base = describe(
                key[: -len("_ci95")], convention=conv, collision_convention=cc, miss_threshold=miss_threshold
            )
            if base is not None:
                d = _d(
                    "ci95@scene_bootstrap/1",
                    f"95 % scene-level bootstrap interval of the paired difference of {base.id}",
                    "interval",
                    base.unit,
                    (None, None),
                    None,
                    "lightemma (cluster bootstrap over scenes)",
                    _U,
                )
        entry = d.to_dict() if d is not None else None
        out[key] = entry
        if entry is not None and key in MAP_KEYS and maps is not None:
            entry["map"] = maps  # the map the values were scored against (docs/evaluate.md#what-each-number-is)
    return out


# ---------------------------------------------------------------------------------------------------------- provenance


def _software() -> dict[str, Any]:
    from lightemma import __version__
    from lightemma.pipeline.runner import _git_revision

    return {"lightemma_version": __version__, "git_revision": _git_revision()}


def provenance(
    evaluation: Any, *, with_paper: bool = False, dataroot: str | None = None, version: str | None = None
) -> dict[str, Any]:
    """Where the numbers of ``evaluation`` come from: lightemma's version and git revision, each frame set's fingerprint
    (:mod:`lightemma.frames.fingerprint`, by id), per run its frame set, prompt set, parse mode, integrator, the
    software that made it and the map / annotation source of its safety columns, and with ``with_paper`` the paper's
    own definitions behind its rows. ``dataroot``/``version``: the ones given for every run (``--dataroot``), else each
    run's manifest's."""
    from lightemma.models.paper import PAPER_CONVENTION, PAPER_FRAMES

    frame_sets: dict[str, Any] = {}
    runs = []
    safety = getattr(evaluation, "safety", None)
    for model in evaluation.models:
        fp = model.fingerprint
        if fp is not None:
            frame_sets[fp["id"]] = fp
        manifest = model.manifest or {}
        dataset_value = manifest.get("dataset")
        dataset: dict[str, Any] = dataset_value if isinstance(dataset_value, dict) else {}
        prompt_value = manifest.get("prompt_set")
        prompt: dict[str, Any] = prompt_value if isinstance(prompt_value, dict) else {}
        rows = {c: model.safety.get(c, {}) for c in evaluation.conventions} if model.safety else {}
        first: Mapping[str, Any] = next(iter(rows.values()), {}) if rows else {}
        runs.append(
            {
                "model": model.label,
                "run_dir": str(model.run_dir),
                "run_id": manifest.get("run_id"),
                "frame_set": fp["id"] if fp is not None else None,
                "prompt_set": {k: prompt.get(k) for k in ("name", "hash", "variant", "variant_hash") if k in prompt},
                "parse": model.parse.get("label"),
                "parse_definition": {k: v for k, v in model.parse.items() if k != "label"},
                "integrator": model.integrator,
                "chain": model.chain,
                "answer_format": model.answer_format,
                "inputs": model.inputs,
                "lightemma_version": manifest.get("lightemma_version"),
                "git_revision": manifest.get("git_revision"),
                "imported": isinstance(manifest.get("imported"), dict),
                "safety_source": None
                if safety is None
                else {
                    "dataroot": str(dataroot) if dataroot else dataset.get("dataroot"),
                    "version": version if dataroot else dataset.get("version"),
                    "drivable_area": first.get("area_source"),
                    "map_expansion_version": first.get("map_version"),
                    "offroad_na": first.get("offroad_na"),
                    "annotations": "sample_annotation.json" if first.get("collision_na") is None else None,
                    "collision_na": first.get("collision_na"),
                    "agents": "all",
                    "collision_conventions": {c: r.get("collision_convention") for c, r in rows.items()},
                },
                "planning_source": None
                if getattr(evaluation, "planning", None) is None
                else {
                    "map": (getattr(model, "planning", None) or {}).get("planning_map"),
                    "map_expansion_version": (getattr(model, "planning", None) or {}).get("map_version"),
                    "annotations": "sample_annotation.json"
                    if getattr(evaluation.planning, "headline", None) == "epdms"
                    else None,
                    "headline": getattr(evaluation.planning, "headline", None),
                },
            }
        )
    out: dict[str, Any] = {
        **_software(),
        "frame_sets": frame_sets,
        "runs": runs,
        "miss_threshold_m": getattr(evaluation, "miss_threshold", 2.0),
    }
    if with_paper:
        out["paper"] = {
            "source": "LightEMMA paper (paper/lightemma-paper.tex), Tables I and II",
            "frame_set": {"version": "v1.0-test", "split": "test", "window": "reference", "n_frames": PAPER_FRAMES},
            "convention": PAPER_CONVENTION,
            "ade": ADE_BY_CONVENTION[PAPER_CONVENTION],
            "fde": "fde/1",
            "fe": "fe@paper/1",
            "fe_corr": "fe_corr@paper/1",
            "integrator": "euler",
            "parse": "paper",
            "implausible": "kept (the paper averaged every answer its scripts read)",
            "efficiency": "time, cost and tokens per frame as the paper's Table I printed them",
        }
    return out


def evaluation_document(
    tables: Sequence[Any],
    evaluation: Any,
    *,
    with_paper: bool = False,
    dataroot: str | None = None,
    version: str | None = None,
) -> dict[str, Any]:
    """The keys ``evaluate --format json`` adds beside its tables: ``format``, ``provenance`` and ``columns``
    (table name -> key -> descriptor)."""
    threshold = getattr(evaluation, "miss_threshold", 2.0)
    return {
        "format": EVALUATE_FORMAT,
        "provenance": provenance(evaluation, with_paper=with_paper, dataroot=dataroot, version=version),
        "columns": {t.name: column_descriptors(t.name, t.rows, miss_threshold=threshold) for t in tables},
    }


def footer_lines(evaluation: Any) -> list[str]:
    """The compact provenance footer of Markdown, LaTeX and CSV output: software, frame sets, metric ids."""
    prov = provenance(evaluation)
    lines = [f"lightemma {prov['lightemma_version']}" + (f" ({prov['git_revision']})" if prov["git_revision"] else "")]
    from lightemma.frames.fingerprint import describe_fingerprint

    for fp in prov["frame_sets"].values():
        users = [r["model"] for r in prov["runs"] if r["frame_set"] == fp["id"]]
        lines.append(f"Frame set {describe_fingerprint(fp)}: {', '.join(users)}")
    ids = [ADE_BY_CONVENTION[c] for c in evaluation.conventions] + [
        "fde/1",
        miss_descriptor(prov["miss_threshold_m"]).id,
        "fe@paper/1",
    ]
    if getattr(evaluation, "safety", None) is not None:
        from lightemma.definitions import COLLISION_FOR_ADE

        ids += sorted({COLLISION_BY_CONVENTION[COLLISION_FOR_ADE[c]] for c in evaluation.conventions})
        ids += ["offroad@footprint/1", "offroad@centre/1"]
    planning = getattr(evaluation, "planning", None)
    if planning is not None:
        ids += [
            PLANNING_BY_KEY[k]
            for k in dict.fromkeys((getattr(planning, "headline", "epdms"), "pdms"))
            if k in PLANNING_BY_KEY
        ]
    maps = map_line(evaluation)
    if maps:
        lines.append(maps)
    lines.append("Metrics: " + ", ".join(dict.fromkeys(ids)) + " (docs/evaluate.md#what-each-number-is)")
    return lines


def map_line(evaluation: Any) -> str | None:
    """One line saying which maps the off-road and planning values were scored against: ``Maps: drivable area
    expansion, map expansion 1.3`` (``mask``: base map masks, which carry no version); None when neither was computed
    or no run has a value."""
    rows: list[Mapping[str, Any]] = []
    for model in evaluation.models:
        if getattr(evaluation, "safety", None) is not None:
            rows += list((model.safety or {}).values())
        if getattr(evaluation, "planning", None) is not None:
            rows.append(getattr(model, "planning", None) or {})
    block = map_block(rows)
    if block["drivable_area"] is None:
        return None
    version = block["expansion_version"]
    return f"Maps: drivable area {block['drivable_area']}, " + (
        f"map expansion {version}" if version else "no map expansion (base map masks carry no version)"
    )


# ------------------------------------------------------------------------------------------------------- reading back


def _refuse(path: Any, field: str, why: str) -> UserError:
    return UserError(f"{path}: {field}: {why}")


def check_evaluation_json(doc: Any, path: str | Path = "<json>") -> dict[str, Any]:
    """Check a ``lightemma evaluate --format json`` document and return it; a document of another format (an older or
    newer lightemma), a frame-set fingerprint whose id does not match its fields (hand-edited), a column without a
    descriptor or whose descriptor is not this version's, a value its descriptor does not allow (:func:`_check_range`:
    a rate above 1, a string or bool for a number, a fractional count, a reversed interval) or counts out of order
    (:func:`_check_counts`: more frames scored than accounted) raises :class:`~lightemma.errors.UserError` in one
    line naming ``path`` and the field. Nothing is returned half-read: the whole document is checked first."""
    from lightemma.frames.fingerprint import check_fingerprint

    if not isinstance(doc, dict):
        raise _refuse(path, "(top)", "not a JSON object")
    fmt = doc.get("format")
    if fmt != EVALUATE_FORMAT:
        raise _refuse(
            path,
            "format",
            f"{fmt!r} is not {EVALUATE_FORMAT!r} (written by another lightemma version; "
            "evaluate the runs again with this one)",
        )
    prov = doc.get("provenance")
    if not isinstance(prov, dict) or not isinstance(prov.get("frame_sets"), dict):
        raise _refuse(path, "provenance.frame_sets", "missing")
    for key, fp in prov["frame_sets"].items():
        check_fingerprint(fp, f"{path}: provenance.frame_sets.{key}")
        if fp.get("id") != key:
            raise _refuse(path, f"provenance.frame_sets.{key}", f"keyed by {key!r} but its id is {fp.get('id')!r}")
    threshold = prov.get("miss_threshold_m")
    if (
        isinstance(threshold, bool)
        or not isinstance(threshold, (int, float))
        or not math.isfinite(threshold)
        or threshold <= 0
    ):
        raise _refuse(path, "provenance.miss_threshold_m", f"{threshold!r} is not a positive number of metres")
    columns = doc.get("columns")
    tables = doc.get("tables")
    if not isinstance(columns, dict) or not isinstance(tables, list):
        raise _refuse(path, "columns" if not isinstance(columns, dict) else "tables", "missing")
    for t, table in enumerate(tables):
        name = table.get("name") if isinstance(table, dict) else None
        rows = table.get("rows") if isinstance(table, dict) else None
        described = columns.get(name) if isinstance(name, str) else None
        if not isinstance(described, dict) or not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
            raise _refuse(
                path,
                f"tables[{t}]" if not isinstance(described, dict) and not isinstance(name, str) else f"columns.{name}",
                "no descriptors for this table"
                if not isinstance(described, dict)
                else "rows are not a list of objects",
            )
        assert isinstance(name, str)  # described is looked up by a str name only
        expected = column_descriptors(name, rows, miss_threshold=threshold)
        for key, want in expected.items():
            have = described.get(key)
            if not isinstance(have, dict):
                raise _refuse(path, f"columns.{name}.{key}", "no descriptor for this column")
            if want is None:
                raise _refuse(
                    path,
                    f"columns.{name}.{key}.id",
                    f"{have.get('id')!r}: this lightemma has no definition of this column (another version)",
                )
            if have != want:
                differs = next(k for k in want if have.get(k) != want[k])
                raise _refuse(
                    path,
                    f"columns.{name}.{key}.{differs}",
                    f"{have.get(differs)!r} is not this lightemma's {want[differs]!r} ({want['id']})",
                )
        for r, row in enumerate(rows):
            diff = row.get("source") == "diff"
            for key, value in row.items():
                described_key = expected[key]
                assert described_key is not None  # a column without a descriptor was refused above
                d = describe_dict(described_key)
                _check_range(path, f"tables[{t}].rows[{r}].{key}", value, d, diff)
            if not diff:
                _check_counts(path, f"tables[{t}].rows[{r}]", row)
    return doc


def describe_dict(d: Mapping[str, Any]) -> Descriptor:
    """A :class:`Descriptor` from its :meth:`Descriptor.to_dict`."""
    rng = d.get("range")
    return Descriptor(
        d["id"],
        d["title"],
        d["kind"],
        d["unit"],
        tuple(rng) if rng is not None else None,
        d["lower_is_better"],
        d["source"],
        d["anchor"],
    )


#: descriptor kinds whose values are numbers (or null); ``label`` values are free
_NUMERIC_KINDS = ("metric", "rate", "count", "test")
#: (smaller, larger) count columns of one row that must be ordered: the accounting identity
#: ``frames_accounted = scored + failed + implausible + api_errors (+ other)`` over frames of the run. ``frames`` is
#: not among them: in an accuracy row it is the frames behind the means, which under ``--common`` can be fewer than
#: ``scored``.
_ORDERED_COUNTS = (("scored", "frames_accounted"), ("frames_accounted", "frames_in_run"))


def _is_number(v: Any) -> TypeGuard[int | float]:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _check_range(path: Any, field: str, value: Any, d: Descriptor, diff: bool) -> None:
    """Refuse (one line naming ``path`` and ``field``) a value its descriptor does not allow: a value of a numeric kind
    (``metric``, ``rate``, ``count``, ``test``) must be a finite number (not a bool) or null, a ``count`` an integer; an
    ``interval`` is null or a list of two such numbers (either null) with low ≤ high (an interval of a paired
    difference may be negative, still ordered); every number within the descriptor's ``range`` (a ``diff`` row's
    within ± the range's width). ``label`` values are not checked."""
    if d.kind == "interval":
        if value is None:
            return
        if not isinstance(value, list) or len(value) != 2:
            raise _refuse(path, field, f"{value!r} is not an interval [low, high] ({d.id})")
        values: list[Any] = value
    elif d.kind in _NUMERIC_KINDS:
        values = [value]
    else:
        return
    for v in values:
        if v is None:
            continue
        if not _is_number(v) or not math.isfinite(v):
            raise _refuse(path, field, f"{v!r} is not a finite number ({d.id}, unit {d.unit})")
        if d.kind == "count" and not (isinstance(v, int) or float(v).is_integer()):
            raise _refuse(path, field, f"{v!r} is not a whole number ({d.id}, unit {d.unit})")
        if d.range is None:
            continue
        lo, hi = d.range
        if diff:  # a difference from the paper's row: within the width of the range
            width = (hi - lo) if lo is not None and hi is not None else None
            if width is not None and abs(v) > width:
                raise _refuse(path, field, f"{v!r} is outside ±{width:g} ({d.id}, unit {d.unit})")
            continue
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            span = f"[{'-inf' if lo is None else f'{lo:g}'}, {'inf' if hi is None else f'{hi:g}'}]"
            raise _refuse(path, field, f"{v!r} is outside {span} ({d.id}, unit {d.unit})")
    if d.kind == "interval" and value[0] is not None and value[1] is not None and value[0] > value[1]:
        raise _refuse(path, field, f"{value!r} is reversed: low {value[0]!r} > high {value[1]!r} ({d.id})")


def _check_counts(path: Any, where: str, row: Mapping[str, Any]) -> None:
    """Refuse a row whose counts break the accounting (:data:`_ORDERED_COUNTS`), e.g. more frames scored than
    accounted; the counts were each checked by :func:`_check_range` before."""
    for small, large in _ORDERED_COUNTS:
        a, b = row.get(small), row.get(large)
        if _is_number(a) and _is_number(b) and a > b:
            raise _refuse(path, f"{where}.{small}", f"{a!r} is more than {large} {b!r}")


def read_evaluation_json(path: str | Path) -> dict[str, Any]:
    """Read and check (:func:`check_evaluation_json`) a ``lightemma evaluate --format json`` file."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise UserError(f"{path}: not readable JSON ({exc})") from None
    return check_evaluation_json(doc, path)


def schema() -> dict[str, Any]:
    """The JSON Schema of ``lightemma evaluate --format json`` (``lightemma/evaluation/schema.json``)."""
    return json.loads((Path(__file__).with_name("schema.json")).read_text(encoding="utf-8"))
