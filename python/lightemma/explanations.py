"""Does the model do what it says? The stated intent of stage 2 against the plan of stage 3.

LightEMMA's chain is a scene description, a driving intent and six actions. This module reads the intent
without a judge model and checks it against the actions (docs/parsing.md#intents,
docs/definitions.md#explanation-audit; rules ``intent@lightemma/1``):

* :func:`read_intents` — stage-2 texts → the stated longitudinal and lateral intent of the *planned* part
  (Rust core, ``rust/intent.rs``), each with the sentence it came from, or ``"unknown"`` with a reason;
* :func:`planned_intents` — stage-3 actions, the history and the integrated trajectory → the same classes,
  by the documented :class:`Thresholds`;
* :func:`intent_consistency` — per frame ``consistent`` / ``contradicts`` / ``unknown``, per axis and overall,
  with a reason;
* :func:`run_consistency` — the same for a run directory's records;
* :func:`summarize_consistency` — per model the consistency and contradiction rates with scene-bootstrap
  intervals, confusion matrices (stated × planned), and paired sign-flip tests between models (Holm-adjusted);
* :func:`read_objects` — stage-1 texts → the object classes each affirms, negates or hedges about, with stated counts
  (Rust core, ``rust/objects.rs``, rules ``objects@lightemma/1``, docs/definitions.md#described-objects); the check
  against the annotations is :mod:`lightemma.evaluation.object_audit`.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from numpy.typing import ArrayLike

from lightemma import _core
from lightemma.definitions import STEP_SECONDS
from lightemma.errors import InputError, ShapeError
from lightemma.evaluation.manifest import _integrator
from lightemma.evaluation.stats import Resampling, bootstrap_ci, holm, sign_flip_p
from lightemma.kinematics import integrate
from lightemma.runs.store import read_run

#: a float64 array (shapes in each docstring)
FloatArray = npt.NDArray[np.float64]

INTENT_RULES: str = _core.INTENT_RULES
LONGITUDINAL: tuple[str, ...] = tuple(_core.INTENT_LONGITUDINAL)
LATERAL: tuple[str, ...] = tuple(_core.INTENT_LATERAL)
UNKNOWN = "unknown"
VERDICTS: tuple[str, ...] = ("consistent", "contradicts", "unknown")
_LON_NAMES = np.array([*LONGITUDINAL, UNKNOWN], dtype=object)
_LAT_NAMES = np.array([*LATERAL, UNKNOWN], dtype=object)


def _names(codes: npt.NDArray[np.uint8], names: npt.NDArray[np.object_]) -> npt.NDArray[np.str_]:
    index = np.where(codes == _core.INTENT_UNKNOWN, len(names) - 1, codes).astype(np.intp)
    return names[index].astype(str)


@dataclass(frozen=True)
class Intents:
    """Stated intents of N stage-2 texts (rules :data:`INTENT_RULES`).

    ``longitudinal`` (N,) str: one of :data:`LONGITUDINAL` or ``"unknown"``; ``lateral`` (N,) str: one of
    :data:`LATERAL` or ``"unknown"``; ``reason``: per text, "" when both axes were read plainly, else what
    was ignored or why an axis is unknown (``"longitudinal: only negated 'not accelerate'"``);
    ``longitudinal_sentence`` / ``lateral_sentence``: the sentence each class came from ("" when unknown).
    """

    longitudinal: npt.NDArray[np.str_]
    lateral: npt.NDArray[np.str_]
    reason: list[str]
    longitudinal_sentence: list[str]
    lateral_sentence: list[str]
    rules: str = INTENT_RULES

    def __len__(self) -> int:
        return len(self.longitudinal)


def _texts(texts: str | Iterable[str | None] | npt.NDArray[np.str_ | np.object_]) -> tuple[list[str], list[int]]:
    if isinstance(texts, str):
        items: list[Any] = [texts]
    elif isinstance(texts, np.ndarray):
        if texts.ndim != 1:
            raise ShapeError(f"texts must be a 1-D array of str, got shape {texts.shape}")
        items = texts.tolist()
    elif isinstance(texts, (bytes, bytearray)) or not isinstance(texts, Iterable):
        raise InputError(f"texts must be a str or an iterable of str, got {type(texts).__name__}")
    else:
        items = list(texts)
    missing = [i for i, t in enumerate(items) if t is None]
    for i, t in enumerate(items):
        if t is not None and not isinstance(t, str):
            raise InputError(f"texts must be str (or None for a missing text): item {i} is {type(t).__name__}")
    return ["" if t is None else t for t in items], missing


def read_intents(texts: str | Iterable[str | None] | npt.NDArray[np.str_ | np.object_]) -> Intents:
    """Read the stated intent of stage-2 texts (one pass in Rust, all cores for large batches).

    ``texts``: one str, an iterable of str, or a 1-D array of str; ``None`` marks a missing text (the stage
    failed) and reads as unknown, "no stage-2 text". Only the planned part is read, not the recap of the past
    (docs/parsing.md#intents). Negated, conditional, hedged or contradictory statements, and texts that are
    empty, longer than 64 KiB, not valid UTF-8, an echo of the prompt or not English are ``"unknown"`` with a
    reason — never guessed. Raises ``ValueError`` naming the first item that is not str or None.
    """
    items, missing = _texts(texts)
    lon, lat, reasons, lon_s, lat_s = _core.read_intents(items)
    for i in missing:
        reasons[i] = "no stage-2 text"
    return Intents(_names(lon, _LON_NAMES), _names(lat, _LAT_NAMES), reasons, lon_s, lat_s)


@dataclass(frozen=True)
class Thresholds:
    """The documented thresholds that classify a plan (docs/definitions.md#explanation-audit). Units: m/s, m/s², rad, m."""

    dt: float = STEP_SECONDS  # s per action
    stopped: float = 0.5  # a speed below this is standing still
    moving: float = 1.0  # "start": from standing, a final speed at least this
    accelerate: float = 0.3  # mean acceleration over the horizon ≥ this: accelerate (≤ −this: decelerate)
    keep: float = 0.15  # |mean acceleration| ≤ this: keep speed; between keep and accelerate: unknown
    min_path: float = 2.0  # lateral needs at least this path length
    turn: float = 0.35  # |heading change| ≥ this: turn
    lane_change: float = 1.2  # |offset beyond the arc| ≥ this (and no turn): lane change
    follow: float = 0.5  # |offset beyond the arc| < this (and no turn): follow the lane
    direction: float = 0.1  # |heading change| ≥ this gives the side of a gentle curve

    def to_dict(self) -> dict[str, float]:
        return asdict(self)


@dataclass(frozen=True)
class PlannedIntents:
    """The intent a plan shows, by :class:`Thresholds` (all arrays (N,)).

    ``longitudinal`` / ``lateral`` str: the classes of :data:`LONGITUDINAL` / :data:`LATERAL` or ``"unknown"``;
    ``side`` int8: +1 left, −1 right, 0 neither (the side of the path's curve or offset); ``reason``: why an
    axis is unknown ("" otherwise). Measures: ``initial_speed`` (the last history speed, m/s),
    ``final_speed`` (m/s), ``mean_acceleration`` ((final − initial) / horizon, m/s²), ``path_length`` (m),
    ``heading_change`` (Σ κ v dt, rad, left +), ``lateral_offset`` (final y of the trajectory, m, left +) and
    ``arc_excess`` (lateral offset minus that of the same speeds at one constant curvature giving the same
    heading change, m: what a constant-curvature arc does not explain).
    """

    longitudinal: npt.NDArray[np.str_]
    lateral: npt.NDArray[np.str_]
    side: npt.NDArray[np.int8]
    reason: list[str]
    initial_speed: FloatArray
    final_speed: FloatArray
    mean_acceleration: FloatArray
    path_length: FloatArray
    heading_change: FloatArray
    lateral_offset: FloatArray
    arc_excess: FloatArray
    thresholds: Thresholds = field(default_factory=Thresholds)


def _frames(array: ArrayLike | None, n: int | None, name: str) -> FloatArray:
    a = np.asarray(array, dtype=np.float64)
    if a.ndim != 3 or a.shape[2] != 2 or (n is not None and a.shape[0] != n):
        want = f"({n}, T, 2)" if n is not None else "(N, T, 2)"
        raise ShapeError(f"{name} must have shape {want}, got {a.shape}")
    return a


def planned_intents(
    actions: ArrayLike,
    history: ArrayLike,
    trajectory: ArrayLike | None = None,
    thresholds: Thresholds = Thresholds(),
    method: str = "euler",
) -> PlannedIntents:
    """Classify the plans: ``actions`` (N, T, 2) speed m/s and curvature 1/m at ``thresholds.dt`` s, ``history``
    (N, H, 2) the actions the prompt printed (its last speed is the current speed), ``trajectory`` (N, T, 2) the
    integrated positions in the ego frame (x forward, y left, m; integrated here with ``method`` when None).
    The arc excess compares the trajectory's final y with the same speeds at the constant curvature
    heading change / path length, integrated with ``method`` (the run's integrator).

    Longitudinal: standing (initial < stopped) and max speed < stopped → stay_stopped; standing and final ≥
    moving → start; moving and final < stopped → stop; else mean acceleration ≥ accelerate → accelerate, ≤
    −accelerate → decelerate, |·| ≤ keep → keep_speed; anything between → unknown (borderline). Lateral
    (path ≥ min_path): |heading change| ≥ turn → turn to its side; else |arc excess| ≥ lane_change → lane
    change to its side; |arc excess| < follow → follow_lane; between → unknown. A frame with a non-finite
    action, history speed or position is unknown on the axes that need it. ``ValueError`` for shapes.
    """
    t = thresholds
    a = _frames(actions, None, "actions")
    n = a.shape[0]
    h = _frames(history, n, "history")
    finite = np.where(np.isfinite(a), a, np.nan)
    if trajectory is None:
        traj = integrate(finite, dt=t.dt, method=method) if a.size else np.zeros_like(a)
    else:
        traj = _frames(trajectory, n, "trajectory")
        if traj.shape[1] != a.shape[1]:
            raise ShapeError(f"trajectory must have {a.shape[1]} steps like actions, got {traj.shape[1]}")
    horizon = a.shape[1] * t.dt
    speed = a[..., 0] if a.shape[1] else np.full((n, 1), np.nan)
    v0 = h[:, -1, 0] if h.shape[1] else np.full(n, np.nan)
    v_end = speed[:, -1]
    v_max = speed.max(axis=1) if a.shape[1] else np.full(n, np.nan)
    with np.errstate(invalid="ignore", over="ignore"):
        acc = (v_end - v0) / horizon if horizon > 0 else np.full(n, np.nan)
        path = np.abs(speed).sum(axis=1) * t.dt
        dpsi = (a[..., 0] * a[..., 1]).sum(axis=1) * t.dt
        y = traj[:, -1, 1] if traj.shape[1] else np.full(n, np.nan)
        arc = finite.copy()
        arc[..., 1] = np.where(path > 0, dpsi / np.where(path > 0, path, 1.0), 0.0)[:, None]
        arc_y = (
            integrate(np.where(np.isfinite(arc), arc, np.nan), dt=t.dt, method=method)[:, -1, 1]
            if a.size
            else np.full(n, np.nan)
        )
        excess = y - arc_y
    actions_ok = np.isfinite(a).all(axis=(1, 2)) & (a.shape[1] > 0)
    lon_ok = actions_ok & np.isfinite(v0)
    lat_ok = actions_ok & np.isfinite(traj).all(axis=(1, 2)) & np.isfinite(excess) & np.isfinite(dpsi)

    lon = np.full(n, UNKNOWN, dtype=object)
    standing = v0 < t.stopped
    with np.errstate(invalid="ignore"):
        rules = [
            (standing & (v_max < t.stopped), "stay_stopped"),
            (standing & (v_end >= t.moving), "start"),
            (~standing & (v_end < t.stopped), "stop"),
            (~standing & (v_end >= t.stopped) & (acc >= t.accelerate), "accelerate"),
            (~standing & (v_end >= t.stopped) & (acc <= -t.accelerate), "decelerate"),
            (~standing & (v_end >= t.stopped) & (np.abs(acc) <= t.keep), "keep_speed"),
        ]
    for mask, name in reversed(rules):
        lon[mask & lon_ok] = name
    side_turn = np.sign(dpsi)
    side_shift = np.sign(excess)
    lat = np.full(n, UNKNOWN, dtype=object)
    long_enough = path >= t.min_path
    with np.errstate(invalid="ignore"):
        turning = np.abs(dpsi) >= t.turn
        shifting = ~turning & (np.abs(excess) >= t.lane_change)
        following = ~turning & (np.abs(excess) < t.follow)
    ok = lat_ok & long_enough
    lat[ok & turning & (side_turn > 0)] = "turn_left"
    lat[ok & turning & (side_turn < 0)] = "turn_right"
    lat[ok & shifting & (side_shift > 0)] = "change_lane_left"
    lat[ok & shifting & (side_shift < 0)] = "change_lane_right"
    lat[ok & following] = "follow_lane"
    with np.errstate(invalid="ignore"):
        side = np.where(
            turning | (np.abs(dpsi) >= t.direction), side_turn, np.where(np.abs(excess) >= t.follow, side_shift, 0.0)
        )
    side = np.where(ok, side, 0.0).astype(np.int8)

    reasons = []
    for i in range(n):
        parts = []
        if not actions_ok[i]:
            parts.append("no planned actions (failed or non-finite)")
        else:
            if not np.isfinite(v0[i]):
                parts.append("longitudinal: no current speed (history)")
            elif lon[i] == UNKNOWN:
                parts.append(
                    f"longitudinal: borderline (initial {v0[i]:.2f} m/s, final {v_end[i]:.2f} m/s, mean acceleration {acc[i]:+.2f} m/s²)"
                )
            if not lat_ok[i]:
                parts.append("lateral: no finite trajectory")
            elif not long_enough[i]:
                parts.append(f"lateral: path of {path[i]:.2f} m, under {t.min_path} m")
            elif lat[i] == UNKNOWN:
                parts.append(
                    f"lateral: borderline (heading change {dpsi[i]:+.3f} rad, offset beyond the arc {excess[i]:+.2f} m)"
                )
        reasons.append("; ".join(parts))
    return PlannedIntents(lon.astype(str), lat.astype(str), side, reasons, v0, v_end, acc, path, dpsi, y, excess, t)


# (stated, planned) pairs that agree though the classes differ
_LON_AGREE = {
    ("decelerate", "stop"),
    ("stop", "decelerate"),
    ("accelerate", "start"),
    ("start", "accelerate"),
    ("stop", "stay_stopped"),
    ("stay_stopped", "stop"),
    ("keep_speed", "stay_stopped"),
    ("decelerate", "stay_stopped"),
}
_SIDE = {"turn_left": 1, "change_lane_left": 1, "turn_right": -1, "change_lane_right": -1}


def _lon_verdict(stated: str, planned: str) -> tuple[str, str]:
    if stated == UNKNOWN:
        return UNKNOWN, "no stated longitudinal intent"
    if planned == UNKNOWN:
        return UNKNOWN, "planned longitudinal behaviour unknown"
    if stated == planned or (stated, planned) in _LON_AGREE:
        return "consistent", ""
    return "contradicts", f"says {stated}, plans {planned}"


def _lat_verdict(stated: str, planned: str, side: int) -> tuple[str, str]:
    if stated == UNKNOWN:
        return UNKNOWN, "no stated lateral intent"
    if stated == "follow_lane":
        if planned == "follow_lane":
            return "consistent", ""
        if planned.startswith("change_lane"):
            return "contradicts", f"says follow_lane, plans {planned}"
        if planned == UNKNOWN:
            return UNKNOWN, "planned lateral behaviour unknown"
        return UNKNOWN, f"says follow_lane, plans {planned} (the lane may bend)"
    want = _SIDE[stated]
    if side == -want:
        return (
            "contradicts",
            f"says {stated}, plans {planned if planned != UNKNOWN else 'a path'} to the {'right' if want > 0 else 'left'}",
        )
    if planned == UNKNOWN:
        return UNKNOWN, "planned lateral behaviour unknown"
    if _SIDE.get(planned) == want or side == want:
        return "consistent", ""
    return UNKNOWN, f"says {stated}, plans {planned} (the manoeuvre may begin after the horizon)"


@dataclass(frozen=True)
class Consistency:
    """Per frame: the stated intent against the plan (all arrays (N,) str of :data:`VERDICTS`).

    ``verdict``: ``contradicts`` when an axis contradicts; ``consistent`` when no axis contradicts, at least one
    is consistent and the other is consistent or states nothing firm (unknown, but not by contradictory
    statements); else ``unknown``. ``longitudinal`` /
    ``lateral``: the verdict of each axis. ``reason``: why (e.g. "longitudinal: says stop, plans keep_speed").
    """

    verdict: npt.NDArray[np.str_]
    longitudinal: npt.NDArray[np.str_]
    lateral: npt.NDArray[np.str_]
    reason: list[str]
    stated: Intents
    planned: PlannedIntents
    rules: str = INTENT_RULES

    def __len__(self) -> int:
        return len(self.verdict)


def intent_consistency(
    texts: Intents | str | Iterable[str | None] | npt.NDArray[np.str_ | np.object_],
    actions: ArrayLike,
    history: ArrayLike,
    trajectory: ArrayLike | None = None,
    thresholds: Thresholds = Thresholds(),
    method: str = "euler",
) -> Consistency:
    """Check each frame's stated intent (stage-2 ``texts``, or :class:`Intents` already read) against its plan
    (see :func:`planned_intents` for ``actions``, ``history``, ``trajectory``).

    Agreeing pairs besides equal classes: decelerate/stop, accelerate/start, stop/stay_stopped (either way),
    keep_speed or decelerate stated and stay_stopped planned; a turn or lane change stated and a plan to the
    same side. A plan to the opposite side contradicts a turn or lane change; a lane change contradicts
    follow_lane; a stated turn with a straight plan, or follow_lane with a turning plan (the lane may bend), is
    unknown. ``ValueError`` when the counts or shapes differ.
    """
    stated = texts if isinstance(texts, Intents) else read_intents(texts)
    planned = planned_intents(actions, history, trajectory, thresholds, method)
    n = len(planned.longitudinal)
    if len(stated) != n:
        raise InputError(f"{len(stated)} stated intent(s) but {n} plan(s)")
    verdict = np.empty(n, dtype=object)
    lon_v = np.empty(n, dtype=object)
    lat_v = np.empty(n, dtype=object)
    reasons = []
    for i in range(n):
        lv, lr = _lon_verdict(stated.longitudinal[i], planned.longitudinal[i])
        av, ar = _lat_verdict(stated.lateral[i], planned.lateral[i], int(planned.side[i]))
        lon_v[i], lat_v[i] = lv, av
        silent_lat = stated.lateral[i] == UNKNOWN and "contradictory" not in _axis_part(stated.reason[i], "lateral")
        silent_lon = stated.longitudinal[i] == UNKNOWN and "contradictory" not in _axis_part(
            stated.reason[i], "longitudinal"
        )
        if "contradicts" in (lv, av):
            verdict[i] = "contradicts"
        elif (
            (lv, av) == ("consistent", "consistent")
            or (lv == "consistent" and silent_lat)
            or (av == "consistent" and silent_lon)
        ):
            verdict[i] = "consistent"
        else:
            verdict[i] = UNKNOWN
        parts = []
        for axis, v, r, stated_reason, planned_reason in (
            ("longitudinal", lv, lr, stated.reason[i], planned.reason[i]),
            ("lateral", av, ar, stated.reason[i], planned.reason[i]),
        ):
            if v == "consistent":
                continue
            detail = r
            if r.startswith("no stated"):
                why = _axis_part(stated_reason, axis)
                detail = f"{r} ({why})" if why else r
            elif r.startswith("planned") and planned_reason:
                why = _axis_part(planned_reason, axis)
                detail = f"{r} ({why})" if why else r
            parts.append(f"{axis}: {detail}")
        reasons.append("; ".join(parts))
    return Consistency(verdict.astype(str), lon_v.astype(str), lat_v.astype(str), reasons, stated, planned)


def _axis_part(reason: str, axis: str) -> str:
    """The part of a reason about ``axis`` (without its prefix), or the whole reason when it names no axis."""
    parts = [p.strip() for p in reason.split("; ") if p.strip()]
    mine = [p[len(axis) + 2 :] for p in parts if p.startswith(axis + ": ")]
    if mine:
        return "; ".join(mine)
    return "; ".join(p for p in parts if not p.startswith(("longitudinal: ", "lateral: ")))


@dataclass(frozen=True)
class RunConsistency:
    """:func:`intent_consistency` of a run's records, with each frame's id and scene (for the scene bootstrap)."""

    frame_ids: list[str]
    scenes: npt.NDArray[np.object_]
    consistency: Consistency


def _rows(record: Mapping[str, Any], key: str, steps: int) -> FloatArray:
    value = record.get(key)
    try:
        a = np.asarray(value, dtype=np.float64) if value is not None else None
    except (TypeError, ValueError):
        a = None
    if a is None or a.shape != (steps, 2):
        return np.full((steps, 2), np.nan)
    return a


def run_consistency(
    run_dir: str | os.PathLike[str], thresholds: Thresholds = Thresholds(), steps: int = 6
) -> RunConsistency:
    """:func:`intent_consistency` of every frame of a run directory (the last record of each frame).

    Reads ``intent_text`` (None: the stage failed), ``actions``, ``history_actions`` and ``trajectory`` of each
    record (docs/definitions.md#run-records); a missing or malformed array reads as NaN, so that frame's plan is
    unknown. ``RunStoreError`` when the directory holds no ``frames.jsonl``.
    """
    contents = read_run(run_dir)
    records = list(contents.records.values())
    method = _integrator(contents.manifest)  # the run's integrator, as evaluation reads it
    texts = [r.get("intent_text") if isinstance(r.get("intent_text"), str) else None for r in records]
    actions = np.stack([_rows(r, "actions", steps) for r in records]) if records else np.zeros((0, steps, 2))
    history = np.stack([_rows(r, "history_actions", steps) for r in records]) if records else np.zeros((0, steps, 2))
    trajectory = np.stack([_rows(r, "trajectory", steps) for r in records]) if records else np.zeros((0, steps, 2))
    scenes = np.array([str(r.get("scene_name") or r["frame_id"]) for r in records], dtype=object)
    consistency = intent_consistency(texts, actions, history, trajectory, thresholds, method)
    return RunConsistency([r["frame_id"] for r in records], scenes, consistency)


def confusion(stated: ArrayLike, planned: ArrayLike, classes: Sequence[str]) -> dict[str, Any]:
    """Counts of (stated, planned) pairs: {"stated": labels, "planned": labels, "counts": [[int]]}, rows stated,
    columns planned, over ``classes`` plus ``"unknown"``. ``ValueError`` for a label outside them."""
    labels = [*classes, UNKNOWN]
    index = {c: i for i, c in enumerate(labels)}
    s, p = np.asarray(stated).astype(str), np.asarray(planned).astype(str)
    counts = np.zeros((len(labels), len(labels)), dtype=np.int64)
    for a, b in zip(s, p, strict=True):
        if a not in index or b not in index:
            raise InputError(f"confusion: label {a if a not in index else b!r} is not one of {labels}")
        counts[index[a], index[b]] += 1
    return {"stated": labels, "planned": labels, "counts": counts.tolist()}


def _interval(pair: FloatArray) -> list[float] | None:
    return [float(pair[0]), float(pair[1])] if np.isfinite(pair).all() else None


def summarize_consistency(
    entries: Sequence[tuple[str, RunConsistency]], resampling: Resampling | None = None
) -> dict[str, Any]:
    """Per model (label, :class:`RunConsistency`): frames, counts of each verdict, the consistency rate and the
    contradiction rate (shares of all frames) with scene-bootstrap intervals (one core call,
    ``lightemma._core.cluster_bootstrap``), and the confusion matrices stated × planned of both axes. Per pair of
    models, on the frames both hold: the mean paired difference (a − b) of each rate, a sign-flip p-value over
    scenes and Holm's adjustment over all pairs and both rates. Intervals are None with fewer than 2 scenes.
    ``resampling`` defaults to :class:`Resampling` () (10,000 resamples, seed 0, 95 %). ``ValueError`` for
    duplicate labels.
    """
    resampling = resampling or Resampling()
    labels = [label for label, _ in entries]
    if len(set(labels)) != len(labels):
        raise InputError(f"duplicate model label(s): {sorted({x for x in labels if labels.count(x) > 1})}")
    groups, keys = [], []
    for label, run in entries:
        v = run.consistency.verdict
        values = np.stack([v == "consistent", v == "contradicts"], axis=1).astype(np.float64)
        groups.append((values, run.scenes))
        keys.append(f"intent-consistency:{label}")
    ci = bootstrap_ci(groups, keys, resampling) if groups else np.zeros((0, 2, 2))
    models = []
    for k, (label, run) in enumerate(entries):
        c = run.consistency
        n = len(c)
        counts = {v: int((c.verdict == v).sum()) for v in VERDICTS}
        models.append(
            {
                "label": label,
                "frames": n,
                "scenes": len(set(run.scenes.tolist())),
                **counts,
                "consistency_rate": counts["consistent"] / n if n else math.nan,
                "consistency_ci": _interval(ci[k, 0]) if n else None,
                "contradiction_rate": counts["contradicts"] / n if n else math.nan,
                "contradiction_ci": _interval(ci[k, 1]) if n else None,
                "confusion": {
                    "longitudinal": confusion(c.stated.longitudinal, c.planned.longitudinal, LONGITUDINAL),
                    "lateral": confusion(c.stated.lateral, c.planned.lateral, LATERAL),
                },
            }
        )
    pairs, pgroups, pkeys = [], [], []
    for i in range(len(entries)):
        for j in range(i + 1, len(entries)):
            (la, ra), (lb, rb) = entries[i], entries[j]
            rows_b = {fid: r for r, fid in enumerate(rb.frame_ids)}
            common = [(r, rows_b[fid]) for r, fid in enumerate(ra.frame_ids) if fid in rows_b]
            ia = np.array([a for a, _ in common], dtype=np.intp)
            ib = np.array([b for _, b in common], dtype=np.intp)
            scenes = ra.scenes[ia] if len(ia) else np.zeros(0, dtype=object)
            entry: dict[str, Any] = {"a": la, "b": lb, "frames": len(common), "scenes": len(set(scenes.tolist()))}
            for name, verdict in (("consistency", "consistent"), ("contradiction", "contradicts")):
                d = (ra.consistency.verdict[ia] == verdict).astype(np.float64) - (
                    rb.consistency.verdict[ib] == verdict
                ).astype(np.float64)
                entry[f"{name}_diff"] = float(d.mean()) if len(d) else math.nan
                pgroups.append((d, scenes))
                pkeys.append(f"intent-{name}:{la}|{lb}")
            pairs.append(entry)
    if pgroups:
        p = sign_flip_p(pgroups, pkeys, resampling)
        adjusted = holm(p)
        for k, entry in enumerate(pairs):
            for m, name in enumerate(("consistency", "contradiction")):
                entry[f"{name}_p"] = float(p[2 * k + m])
                entry[f"{name}_p_holm"] = float(adjusted[2 * k + m])
    return {
        "rules": INTENT_RULES,
        "thresholds": Thresholds().to_dict(),
        "resampling": resampling.to_dict(),
        "models": models,
        "pairs": pairs,
    }


# -- described objects (stage 1) --------------------------------------------------------------------------------------

OBJECT_RULES: str = _core.OBJECT_RULES
#: the classes a scene description is read for (docs/definitions.md#described-objects), in column order
OBJECT_CLASSES: tuple[str, ...] = tuple(_core.OBJECT_CLASSES)
#: mention codes 0..3 by name; 255 is "unknown" (the text could not be read)
MENTIONS: tuple[str, ...] = tuple(_core.OBJECT_MENTIONS)
_MENTION_NAMES = np.array([*MENTIONS, UNKNOWN], dtype=str)


@dataclass(frozen=True)
class DescribedObjects:
    """The object classes N stage-1 texts mention (rules :data:`OBJECT_RULES`).

    ``mentions`` (N, C) str, C = len(:data:`OBJECT_CLASSES`): ``affirmed`` (the text says one is there),
    ``negated`` ("no pedestrians"), ``hedged`` ("watch for any pedestrians": not a claim), ``not_mentioned``, or
    ``unknown`` on every class of a text that cannot be read; ``counts`` (N, C) int: the stated count of the affirmed
    mentions, −1 where none is stated; ``reason``: per text why it is unknown or what was hedged ("" otherwise).
    """

    mentions: npt.NDArray[np.str_]
    counts: npt.NDArray[np.int64]
    reason: list[str]
    rules: str = OBJECT_RULES

    def __len__(self) -> int:
        return len(self.reason)

    def column(self, name: str) -> npt.NDArray[np.str_]:
        """(N,) str: the mentions of class ``name``; ``ValueError`` for a class not in :data:`OBJECT_CLASSES`."""
        if name not in OBJECT_CLASSES:
            raise InputError(f"unknown object class {name!r}; choose one of {', '.join(OBJECT_CLASSES)}")
        return self.mentions[:, OBJECT_CLASSES.index(name)]


def read_objects(texts: str | Iterable[str | None] | npt.NDArray[np.str_ | np.object_]) -> DescribedObjects:
    """Read which object classes stage-1 scene descriptions mention (one pass in Rust, ``rust/objects.rs``).

    ``texts`` as for :func:`read_intents`; ``None`` (the stage failed) reads as unknown, "no stage-1 text". Rules:
    docs/definitions.md#described-objects (negation, hedges, places such as "bus stop", the ego vehicle, counts).
    Raises ``ValueError`` naming the first item that is not str or None.
    """
    items, missing = _texts(texts)
    codes, counts, reasons = _core.read_objects(items)
    for i in missing:
        reasons[i] = "no stage-1 text"
    codes = np.asarray(codes)
    index = np.where(codes == _core.OBJECT_UNKNOWN, len(MENTIONS), codes).astype(np.intp)
    names = _MENTION_NAMES[index] if codes.size else np.zeros((len(items), len(OBJECT_CLASSES)), dtype=str)
    if missing:
        names[missing] = UNKNOWN
    return DescribedObjects(names.reshape(len(items), len(OBJECT_CLASSES)), np.asarray(counts, dtype=np.int64), reasons)
