"""Scenario analysis: tag frames from ground truth and history, score models per tag,
measure history bias, and find the frames where models disagree most or all fail.

Tags follow the failure cases of the paper's Section V (trajectory carried over
from a finished turn, missed turns, stops, starts). They are computed from the
run records alone — ground-truth positions (6, 2) and history actions (6, 2) —
so they need no dataset:

==========================  ===============================================================
stopped                     now < 0.5 m/s and stays below 0.5 m/s for 3 s
starting                    now < 0.5 m/s, at least 1 m/s at 3 s (Case 5)
braking                     now ≥ 1 m/s, at least 2 m/s slower at 3 s (Cases 3, 4)
accelerating                now ≥ 0.5 m/s, at least 2 m/s faster at 3 s
turning_left / _right       heading at 3 s turned by more than 15° (Case 2)
straight_after_left_turn    heading within 5° for 3 s while the last three history
/ straight_after_right_turn curvatures include one beyond ±0.03 1/m (Case 1)
cruising                    moving ≥ 1 m/s, straight, steady speed, no other tag
==========================  ===============================================================

With the safety outcomes of an evaluation (docs/definitions.md#safety), two more tags, per model
from its own trajectory: ``collides`` (its footprint overlaps an annotated agent at some step) and
``off_road`` (a footprint corner leaves the drivable area at some step).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from lightemma.definitions import STEP_SECONDS
from lightemma.errors import InputError
from lightemma.evaluation.core import common_frames, unique_labels
from lightemma.evaluation.intent_audit import says_stop_drives_on
from lightemma.evaluation.loading import RunData
from lightemma.evaluation.safety import frame_tags
from lightemma.metrics import evaluate

TAGS: tuple[str, ...] = (
    "stopped",
    "starting",
    "braking",
    "accelerating",
    "turning_left",
    "turning_right",
    "straight_after_left_turn",
    "straight_after_right_turn",
    "cruising",
)
#: tags from a model's own safety outcomes (need the evaluation's ``safety``)
SAFETY_TAGS: tuple[str, ...] = ("collides", "off_road")
#: tags from a model's own planning sub-scores (need the evaluation's ``planning``; lightemma.evaluation.planning_score.frame_tags):
#: ``wrong-way``, ``uncomfortable``, ``no-progress``
from lightemma.evaluation.planning_score import PLANNING_TAGS  # noqa: E402  (beside the other tag lists)

#: tags from a model's explanation audit (need the evaluation's ``explanations``; lightemma.evaluation.intent_audit):
#: ``says-stop-drives-on`` (its stage-2 text says stop, its plan does not stop); from the described-objects audit
#: (lightemma.evaluation.object_audit) ``hallucinated-pedestrian`` (its stage-1 text affirms a pedestrian, none in the
#: image) and ``missed-pedestrian`` (a pedestrian in view, not affirmed).
EXPLANATION_TAGS: tuple[str, ...] = ("says-stop-drives-on", "hallucinated-pedestrian", "missed-pedestrian")
# tags whose worst frames illustrate the paper's failure cases
CASE_TAGS: tuple[str, ...] = (
    "straight_after_right_turn",
    "straight_after_left_turn",
    "turning_left",
    "turning_right",
    "braking",
    "starting",
)


@dataclass(frozen=True)
class Thresholds:
    """The numbers behind the tags (SI units: m/s, rad, 1/m)."""

    stopped_speed: float = 0.5
    moving_speed: float = 1.0
    speed_change: float = 2.0
    turn_heading: float = np.deg2rad(15.0)
    straight_heading: float = np.deg2rad(5.0)
    turn_curvature: float = 0.03
    min_path: float = 2.0  # m: a future path shorter than this defines no curvature (history-bias analysis)


def _with_origin(positions: np.ndarray) -> np.ndarray:
    positions = np.asarray(positions, dtype=np.float64)
    return np.concatenate([np.zeros((len(positions), 1, 2)), positions], axis=1)


def future_speeds(gt_positions: np.ndarray) -> np.ndarray:
    """(N, 6) speeds of the segments origin→p1 … p5→p6."""
    return np.linalg.norm(np.diff(_with_origin(gt_positions), axis=1), axis=2) / STEP_SECONDS


def heading_change(positions: np.ndarray, *, min_step: float = 0.05) -> np.ndarray:
    """(N,) heading (rad, left positive) of the last moving segment of a trajectory from the origin."""
    steps = np.diff(_with_origin(positions), axis=1)
    lengths = np.linalg.norm(steps, axis=2)
    out = np.zeros(len(steps))
    for k in range(steps.shape[1]):
        moving = lengths[:, k] > min_step
        out[moving] = np.arctan2(steps[moving, k, 1], steps[moving, k, 0])
    return out


def menger_curvature(points: np.ndarray) -> np.ndarray:
    """(N, K−2) signed three-point curvature of consecutive triples (left turn positive; 0 if degenerate)."""
    a, b, c = points[:, :-2], points[:, 1:-1], points[:, 2:]
    cross = (b[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1]) - (b[..., 1] - a[..., 1]) * (c[..., 0] - a[..., 0])
    sides = np.linalg.norm(b - a, axis=-1) * np.linalg.norm(c - b, axis=-1) * np.linalg.norm(c - a, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        curvature = np.where(sides > 1e-9, 2.0 * cross / sides, 0.0)
    return curvature


def path_length(positions: np.ndarray) -> np.ndarray:
    """(N,) length (m) of a trajectory from the origin through its points."""
    return np.linalg.norm(np.diff(_with_origin(positions), axis=1), axis=2).sum(axis=1)


def mean_curvature(positions: np.ndarray) -> np.ndarray:
    """(N,) mean curvature along a trajectory from the origin (1/m), weighted by arc length.

    Each three-point (Menger) curvature counts with the length of path around its
    middle point (half of each adjacent segment), so the mean is about the heading
    change divided by the distance travelled, and the near-zero segments of a
    halting vehicle (whose jitter gives curvatures of ±100 1/m) weigh next to
    nothing. 0 for a trajectory that does not move.
    """
    points = _with_origin(positions)
    segments = np.linalg.norm(np.diff(points, axis=1), axis=2)
    weights = (segments[:, :-1] + segments[:, 1:]) / 2.0
    total = weights.sum(axis=1)
    weighted = (menger_curvature(points) * weights).sum(axis=1)
    return np.divide(weighted, total, out=np.zeros_like(total), where=total > 0)


def tag_frames(
    gt_positions: np.ndarray, history_actions: np.ndarray, thresholds: Thresholds = Thresholds()
) -> dict[str, np.ndarray]:
    """Boolean masks (N,) per tag in :data:`TAGS`; a frame may carry several tags or none."""
    th = thresholds
    history = np.asarray(history_actions, dtype=np.float64)
    now = history[:, -1, 0]
    recent_curv = history[:, -3:, 1]
    speeds = future_speeds(gt_positions)
    heading = heading_change(gt_positions)
    moving = now >= th.moving_speed
    straight = (np.abs(heading) < th.straight_heading) & (speeds.mean(axis=1) >= th.moving_speed)
    tags = {
        "stopped": (now < th.stopped_speed) & (speeds.max(axis=1) < th.stopped_speed),
        "starting": (now < th.stopped_speed) & (speeds[:, -1] >= th.moving_speed),
        "braking": moving & (speeds[:, -1] <= now - th.speed_change),
        "accelerating": (now >= th.stopped_speed) & (speeds[:, -1] >= now + th.speed_change),
        "turning_left": (heading > th.turn_heading) & (speeds.mean(axis=1) >= th.stopped_speed),
        "turning_right": (heading < -th.turn_heading) & (speeds.mean(axis=1) >= th.stopped_speed),
        "straight_after_left_turn": straight & (recent_curv.max(axis=1) > th.turn_curvature),
        "straight_after_right_turn": straight & (recent_curv.min(axis=1) < -th.turn_curvature),
    }
    tagged = np.logical_or.reduce(list(tags.values()))
    tags["cruising"] = moving & straight & (np.abs(speeds[:, -1] - now) < 1.0) & ~tagged
    return {name: tags[name] for name in TAGS}


def _require_history(run: RunData) -> np.ndarray:
    if run.history_actions is None:
        raise InputError(f"{run.info.run_dir}: load the run with details=True for scenario analysis")
    return run.history_actions


def _rows_of(run: RunData, frame_ids: Sequence[str] | None) -> np.ndarray:
    if frame_ids is None:
        return np.flatnonzero(run.valid)
    index = run.index()
    return np.fromiter((index[f] for f in frame_ids), dtype=np.int64, count=len(frame_ids))


def _aligned_tags(
    result: Any, names: Sequence[str], tags_of: Any, run: RunData, rows: np.ndarray
) -> dict[str, np.ndarray]:
    """Tags ``names`` of ``rows`` of a run from ``tags_of(result)`` (arrays over ``result.frame_ids``), aligned by
    frame id; False where ``result`` is None or lacks the frame."""
    out = {tag: np.zeros(len(rows), dtype=bool) for tag in names}
    if result is None:
        return out
    tags = tags_of(result)
    where = {f: i for i, f in enumerate(result.frame_ids)}
    for j, r in enumerate(rows):
        i = where.get(run.frame_ids[r])
        if i is not None:
            for tag in names:
                out[tag][j] = tags[tag][i]
    return out


def _safety_masks(safety: Any, label: str, run: RunData, rows: np.ndarray) -> dict[str, np.ndarray]:
    """``collides`` / ``off_road`` of ``rows`` of a run from its safety outcomes (False where it has none)."""
    rs = safety.runs.get(label) if safety is not None else None
    return _aligned_tags(rs, SAFETY_TAGS, frame_tags, run, rows)


def _planning_masks(planning: Any, label: str, run: RunData, rows: np.ndarray) -> dict[str, np.ndarray]:
    """``wrong-way`` / ``uncomfortable`` / ``no-progress`` of ``rows`` of a run from its planning sub-scores (False where n/a)."""
    from lightemma.evaluation.planning_score import frame_tags

    rp = planning.runs.get(label) if planning is not None else None
    return _aligned_tags(rp, PLANNING_TAGS, frame_tags, run, rows)


def _explanation_masks(explanations: Any, label: str, run: RunData, rows: np.ndarray) -> dict[str, np.ndarray]:
    """:data:`EXPLANATION_TAGS` of ``rows`` of a run from its explanation audit (False where it has none)."""

    def aligned(frame_ids: Sequence[str], tag: np.ndarray) -> np.ndarray:
        out = np.zeros(len(rows), dtype=bool)
        where = {f: i for i, f in enumerate(frame_ids)}
        for j, r in enumerate(rows):
            i = where.get(run.frame_ids[r])
            out[j] = i is not None and bool(tag[i])
        return out

    audit = explanations.runs.get(label) if explanations is not None else None
    none = np.zeros(len(rows), dtype=bool)
    masks = {tag: none for tag in EXPLANATION_TAGS}
    if audit is not None:
        masks["says-stop-drives-on"] = aligned(audit.frame_ids, says_stop_drives_on(audit))
    objects = getattr(explanations, "objects", {}).get(label) if explanations is not None else None
    if objects is not None:
        masks["hallucinated-pedestrian"] = aligned(objects.frame_ids, objects.check.hallucinated_pedestrian)
        masks["missed-pedestrian"] = aligned(objects.frame_ids, objects.check.missed_pedestrian)
    return masks


def per_tag_metrics(
    runs: Sequence[RunData],
    *,
    convention: str = "lightemma",
    frame_ids: Sequence[str] | None = None,
    safety: Any = None,
    planning: Any = None,
    explanations: Any = None,
) -> list[dict[str, Any]]:
    """One row per tag (and ``all``): frames and, per model, ADE avg / FDE / miss rate on them.

    Each model is scored on its valid frames, or on ``frame_ids`` (e.g. the
    common frames) when given; one batched core call per model and tag. With ``safety``
    (an evaluation's :class:`~lightemma.evaluation.safety.SafetyResult`) the tags ``collides`` and
    ``off_road`` follow, per model from its own outcomes ("frames" counts the first model's); with ``planning`` (an
    evaluation's :class:`~lightemma.evaluation.planning_score.PlanningResult`) the tags ``wrong-way``, ``uncomfortable`` and
    ``no-progress`` the same way; with ``explanations`` (an evaluation's
    :class:`~lightemma.evaluation.intent_audit.ExplanationResult`) the tags of :data:`EXPLANATION_TAGS`.
    """
    labels = unique_labels(list(runs))
    per_model = []
    for run, label in zip(runs, labels):
        rows = _rows_of(run, frame_ids)
        masks = tag_frames(run.gt_positions[rows], _require_history(run)[rows])
        if safety is not None:
            masks.update(_safety_masks(safety, label, run, rows))
        if planning is not None:
            masks.update(_planning_masks(planning, label, run, rows))
        if explanations is not None:
            masks.update(_explanation_masks(explanations, label, run, rows))
        per_model.append((run, rows, {"all": np.ones(len(rows), dtype=bool), **masks}))
    out = []
    for tag in (
        "all",
        *TAGS,
        *(SAFETY_TAGS if safety is not None else ()),
        *(PLANNING_TAGS if planning is not None else ()),
        *(EXPLANATION_TAGS if explanations is not None else ()),
    ):
        row: dict[str, Any] = {"tag": tag, "frames": int(per_model[0][2][tag].sum()) if per_model else 0}
        for label, (run, rows, masks) in zip(labels, per_model):
            chosen = rows[masks[tag]]
            row[f"{label} frames"] = len(chosen)
            if len(chosen):
                m = evaluate(
                    np.ascontiguousarray(run.trajectory[chosen]),
                    np.ascontiguousarray(run.gt_positions[chosen]),
                    convention=convention,
                ).to_dict()
                row[label] = {
                    "ade_avg": float(m["ade_avg"]),
                    "fde": float(m["fde"]),
                    "miss_rate": float(m["miss_rate"]),
                }
            else:
                row[label] = None
        out.append(row)
    return out


MAX_FIT_FRAMES = 1000  # Theil–Sen costs O(n² log n): larger samples are thinned (fixed seed) to this many frames


def robust_slope(
    x: np.ndarray, y: np.ndarray, *, confidence: float = 0.95, max_frames: int = MAX_FIT_FRAMES
) -> dict[str, Any] | None:
    """Theil–Sen slope of y on x with its confidence interval (``scipy.stats.theilslopes``).

    The median of the slopes between all pairs of points: a single point far off
    (a curvature of 90 1/m) cannot move it. More than ``max_frames`` points are
    thinned to a fixed-seed random sample of that size (the estimator is
    quadratic). None with fewer than 3 points or no spread in x.
    """
    from scipy.stats import theilslopes

    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    if len(x) < 3 or np.ptp(x) == 0:
        return None
    if len(x) > max_frames:
        keep = np.sort(np.random.default_rng(0).choice(len(x), max_frames, replace=False))
        x, y = x[keep], y[keep]
    with np.errstate(invalid="ignore"):  # heavy ties in x can leave no interval (NaN), said as None
        fit = theilslopes(y, x, alpha=confidence)
    ci = [float(fit.low_slope), float(fit.high_slope)]
    return {
        "slope": float(fit.slope),
        "intercept": float(fit.intercept),
        "ci95": ci if all(np.isfinite(ci)) else None,
        "n": len(x),
    }


def curvature_samples(run: RunData, thresholds: Thresholds = Thresholds()) -> dict[str, np.ndarray]:
    """Per scored moving frame whose true and predicted future paths are both ≥ ``min_path``:
    last history curvature, predicted and true mean future curvature, and whether the
    frame goes straight just after a turn. ``short_path`` counts the moving frames left
    out because a path was too short to define a curvature."""
    history = _require_history(run)
    moving = np.flatnonzero(run.valid & (history[:, -1, 0] >= thresholds.moving_speed))
    long_enough = (path_length(run.gt_positions[moving]) >= thresholds.min_path) & (
        path_length(run.trajectory[moving]) >= thresholds.min_path
    )
    rows = moving[long_enough]
    k_hist = history[rows, -1, 1]
    tags = tag_frames(run.gt_positions[rows], history[rows], thresholds)
    after = (tags["straight_after_left_turn"] | tags["straight_after_right_turn"]) & (np.abs(k_hist) > 1e-6)
    return {
        "history": k_hist,
        "pred": mean_curvature(run.trajectory[rows]),
        "true": mean_curvature(run.gt_positions[rows]),
        "after_turn": after,
        "short_path": np.array(int((~long_enough).sum())),
    }


def truth_samples(run: RunData, thresholds: Thresholds = Thresholds()) -> dict[str, np.ndarray]:
    """Last history curvature and true mean future curvature of every moving frame with a true path ≥ ``min_path``
    (predictions not needed: the truth of a frame set, whatever the model)."""
    history = _require_history(run)
    usable = np.isfinite(run.gt_positions).all(axis=(1, 2)) & np.isfinite(history).all(axis=(1, 2))
    rows = np.flatnonzero(usable & (history[:, -1, 0] >= thresholds.moving_speed))
    rows = rows[path_length(run.gt_positions[rows]) >= thresholds.min_path]
    return {"history": history[rows, -1, 1], "true": mean_curvature(run.gt_positions[rows])}


def truth_over_runs(runs: Sequence[RunData], thresholds: Thresholds = Thresholds()) -> dict[str, np.ndarray]:
    """:func:`truth_samples` over every frame of any of ``runs`` (each frame once, the first run's record),
    with ``after_turn``: the frames going straight just after a turn. The truth of the frames shown,
    whatever frames each run covers."""
    seen: set[str] = set()
    gt, hist = [], []
    for run in runs:
        history = _require_history(run)
        rows = [i for i, fid in enumerate(run.frame_ids) if fid not in seen]
        seen.update(run.frame_ids)
        gt.append(run.gt_positions[rows])
        hist.append(history[rows])
    if not gt:
        return {"history": np.zeros(0), "true": np.zeros(0), "after_turn": np.zeros(0, dtype=bool)}
    gt_all, hist_all = np.concatenate(gt), np.concatenate(hist)
    usable = np.isfinite(gt_all).all(axis=(1, 2)) & np.isfinite(hist_all).all(axis=(1, 2))
    keep = np.flatnonzero(usable & (hist_all[:, -1, 0] >= thresholds.moving_speed))
    keep = keep[path_length(gt_all[keep]) >= thresholds.min_path]
    k_hist = hist_all[keep, -1, 1]
    tags = tag_frames(gt_all[keep], hist_all[keep], thresholds)
    after = (tags["straight_after_left_turn"] | tags["straight_after_right_turn"]) & (np.abs(k_hist) > 1e-6)
    return {"history": k_hist, "true": mean_curvature(gt_all[keep]), "after_turn": after}


def history_bias(runs: Sequence[RunData], thresholds: Thresholds = Thresholds()) -> list[dict[str, Any]]:
    """Per model: how far predicted curvature follows the last history curvature, against the truth.

    On scored frames moving now (≥ 1 m/s) whose true and predicted 3 s paths are
    both at least ``min_path`` (2 m) long — shorter paths define no curvature:
    ``slope_pred`` / ``slope_true`` (with ``*_ci95``): Theil–Sen slope of the
    predicted / true mean future curvature on the last history curvature;
    ``sign_agree_pred`` / ``sign_agree_true``: on turning frames (|last history
    curvature| ≥ ``turn_curvature``), the share whose future curvature has the
    history's sign (the turn goes on); ``carry_pred`` / ``carry_true``: on frames
    that go straight just after a turn, the share of the last history curvature
    still present (1 = the turn carried on unchanged, 0 = straight).
    """
    return [
        bias_row(label, curvature_samples(run, thresholds), thresholds)
        for label, run in zip(unique_labels(list(runs)), runs)
    ]


def _share(mask: np.ndarray) -> float | None:
    return float(mask.mean()) if mask.size else None


def bias_row(label: str, k: dict[str, np.ndarray], thresholds: Thresholds = Thresholds()) -> dict[str, Any]:
    """One :func:`history_bias` row from a run's :func:`curvature_samples`."""
    after = k["after_turn"]
    sign = np.sign(k["history"][after])
    scale = np.abs(k["history"][after]).mean() if after.any() else np.nan
    pred, true = robust_slope(k["history"], k["pred"]), robust_slope(k["history"], k["true"])
    turning = np.abs(k["history"]) >= thresholds.turn_curvature
    turn_sign = np.sign(k["history"][turning])
    return {
        "model": label,
        "frames": len(k["history"]),
        "short_path_frames": int(k["short_path"]),
        "slope_pred": pred and pred["slope"],
        "slope_pred_ci95": pred and pred["ci95"],
        "intercept_pred": pred and pred["intercept"],
        "slope_true": true and true["slope"],
        "slope_true_ci95": true and true["ci95"],
        "intercept_true": true and true["intercept"],
        "fit_frames": pred["n"] if pred else 0,
        "turn_frames": int(turning.sum()),
        "sign_agree_pred": _share(np.sign(k["pred"][turning]) == turn_sign),
        "sign_agree_true": _share(np.sign(k["true"][turning]) == turn_sign),
        "after_turn_frames": int(after.sum()),
        "carry_pred": float((k["pred"][after] * sign).mean() / scale) if after.any() else None,
        "carry_true": float((k["true"][after] * sign).mean() / scale) if after.any() else None,
    }


def _shared_valid(runs: Sequence[RunData]) -> list[str]:
    return common_frames(runs) if runs else []


MIN_SPREAD = 1.0  # m: frames whose models' 3 s endpoints lie closer than this are not "disagreements"


def _scene_of(run: RunData, rows: np.ndarray, frame_ids: Sequence[str]) -> list[str]:
    """Scene name per row (the run's scene index), else the frame id up to its last ``/``."""
    if run.scene_index is not None and run.scene_names:
        names = run.scene_names
        return [
            names[s] if 0 <= s < len(names) else fid.rsplit("/", 1)[0]
            for s, fid in zip(run.scene_index[rows].tolist(), frame_ids)
        ]
    return [fid.rsplit("/", 1)[0] for fid in frame_ids]


def disagreements(
    runs: Sequence[RunData], *, top: int = 5, exclude_baselines: bool = True, min_spread: float = MIN_SPREAD
) -> list[dict[str, Any]]:
    """The ``top`` frames (valid in every compared run) whose predicted 3 s endpoints spread most,
    at most one per scene and each spread at least ``min_spread`` metres.

    Baselines are left out of the comparison when at least two other models
    are present. Each entry: frame_id, scene, spread (max pairwise endpoint
    distance among ``models``, m), ``models`` (the labels compared — draw
    exactly these beside the number) and per-model FDE.
    """
    compared = [r for r in runs if r.info.family != "Baseline"] if exclude_baselines else list(runs)
    if len(compared) < 2:
        compared = list(runs)
    if len(compared) < 2:
        return []
    labels = dict(zip(map(id, runs), unique_labels(list(runs))))
    shared = _shared_valid(compared)
    if not shared:
        return []
    rows = [_rows_of(r, shared) for r in compared]
    ends = np.stack([r.trajectory[idx, -1] for r, idx in zip(compared, rows)])  # (M, F, 2)
    spread = np.linalg.norm(ends[:, None] - ends[None, :], axis=-1).max(axis=(0, 1))
    gt_end = compared[0].gt_positions[rows[0], -1]
    scenes = _scene_of(compared[0], rows[0], shared)
    out: list[dict[str, Any]] = []
    seen: set[str] = set()
    for i in np.argsort(-spread, kind="stable"):
        if len(out) >= top or spread[i] < min_spread:
            break
        if scenes[i] in seen:
            continue
        seen.add(scenes[i])
        out.append(
            {
                "frame_id": shared[i],
                "scene": scenes[i],
                "spread_m": float(spread[i]),
                "models": [labels[id(r)] for r in compared],
                "fde": {labels[id(r)]: float(np.linalg.norm(ends[m, i] - gt_end[i])) for m, r in enumerate(compared)},
            }
        )
    return out


def worst_frame_per_tag(runs: Sequence[RunData], tags: Sequence[str] = CASE_TAGS) -> list[dict[str, Any]]:
    """For each tag, the frame (valid in every run) with the highest mean FDE over the models."""
    shared = _shared_valid(runs)
    if not shared:
        return []
    rows = [_rows_of(r, shared) for r in runs]
    fde = np.stack(
        [np.linalg.norm(r.trajectory[idx, -1] - r.gt_positions[idx, -1], axis=1) for r, idx in zip(runs, rows)]
    ).mean(axis=0)
    masks = tag_frames(runs[0].gt_positions[rows[0]], _require_history(runs[0])[rows[0]])
    out = []
    for tag in tags:
        candidates = np.flatnonzero(masks[tag])
        if len(candidates):
            i = candidates[np.argmax(fde[candidates])]
            out.append(
                {"tag": tag, "frame_id": shared[i], "mean_fde": float(fde[i]), "frames_with_tag": len(candidates)}
            )
    return out
