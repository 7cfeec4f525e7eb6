"""What became of each frame of a run: scored, failed, implausible, or lost to API errors.

Only **scored** frames enter a mean, an interval, a figure or the frame picker;
the others are counted and shown beside every table (docs/statistics.md).

A run record says why a frame failed in its ``failure`` field: ``""`` (not
failed), ``"format"``, ``"truncated"``, ``"ambiguous"`` (readings of the answer disagree:
docs/parsing.md), ``"implausible"`` or ``"api_error"``.
Runs written before that field existed lack it: a ``failed`` frame without it
counts as ``"format"``.

Evaluation also applies the plausibility limits itself, so that a run made
without them (or imported from elsewhere) cannot put an absurd prediction into
a mean: a frame whose predicted actions leave the limits (speed outside
[−10, 50] m/s, |curvature| > 1 1/m by default), or whose trajectory goes further
from the start than the fastest allowed speed could carry it
(``max(|min_speed|, max_speed) × 0.5 s × k`` at step k), counts as
``implausible``. A run's own limits, when its manifest records them under
``plausibility`` (top level, ``params`` or ``config``), replace the defaults.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from lightemma.definitions import OUTCOME_CODES, STEP_SECONDS, UNREADABLE


@dataclass(frozen=True)
class Plausibility:
    """Limits of a physically plausible answer: speeds in m/s, curvature in 1/m."""

    min_speed: float = -10.0
    max_speed: float = 50.0
    max_curvature: float = 1.0

    @property
    def reach_speed(self) -> float:
        """The fastest allowed speed in either direction (m/s)."""
        return max(abs(self.min_speed), abs(self.max_speed))

    def to_dict(self) -> dict[str, float]:
        return {"min_speed": self.min_speed, "max_speed": self.max_speed, "max_curvature": self.max_curvature}


def plausibility_for(definition: Any, *, keep_implausible: bool = False) -> Plausibility:
    """The limits evaluation holds a run's actions to, from the parse definition in effect
    (:class:`lightemma.evaluation.rescore.ParseDefinition`): its own limits for ``lenient`` and
    ``strict``; the defaults where it has none (the paper's rules), so that implausible actions the
    paper's rules read are counted as ``implausible`` and never averaged. ``keep_implausible=True``
    sets no limit at all (every readable answer is averaged, as the paper's evaluation did)."""
    if keep_implausible:
        return Plausibility(min_speed=-math.inf, max_speed=math.inf, max_curvature=math.inf)
    speed = getattr(definition, "speed_range", None)
    curvature = getattr(definition, "max_abs_curvature", None)
    default = Plausibility()
    return Plausibility(
        min_speed=default.min_speed if speed is None else float(speed[0]),
        max_speed=default.max_speed if speed is None else float(speed[1]),
        max_curvature=default.max_curvature if curvature is None else float(curvature),
    )


def implausible_actions(actions: np.ndarray, limits: Plausibility) -> np.ndarray:
    """(N,) True where finite (N, 6, 2) actions leave the limits (NaN actions are not judged)."""
    speed, curvature = actions[..., 0], actions[..., 1]
    with np.errstate(invalid="ignore"):
        out = (speed < limits.min_speed) | (speed > limits.max_speed) | (np.abs(curvature) > limits.max_curvature)
    return out.any(axis=1)


def implausible_trajectory(trajectory: np.ndarray, limits: Plausibility) -> np.ndarray:
    """(N,) True where a finite (N, T, 2) trajectory goes further than the fastest allowed speed reaches."""
    steps = np.arange(1, trajectory.shape[1] + 1)
    reach = limits.reach_speed * STEP_SECONDS * steps * (1.0 + 1e-9) + 1e-6
    with np.errstate(invalid="ignore", over="ignore"):
        # hypot: a huge finite position (1e200 m) has a finite distance, and no overflow warning
        return (np.hypot(trajectory[..., 0], trajectory[..., 1]) > reach).any(axis=1)


def final_failure(
    recorded: np.ndarray, failed: np.ndarray, trajectory: np.ndarray, actions_gate: np.ndarray, limits: Plausibility
) -> tuple[np.ndarray, np.ndarray]:
    """Per frame, why it is not scored (an outcome code, :data:`lightemma.definitions.OUTCOMES`; 0 = scored if ground truth is usable).

    ``recorded`` holds the records' own codes (-1 when absent), ``failed`` whether
    the final status is ``failed``, ``actions_gate`` the frames whose actions
    left the limits. Returns (codes, caught) where ``caught`` marks the frames
    that evaluation itself found implausible (the run had not marked them).
    """
    codes = np.where(recorded > 0, recorded, 0).astype(np.int8)
    unmarked = recorded <= 0
    codes[unmarked & failed] = OUTCOME_CODES["format"]
    open_ = unmarked & ~failed
    finite = np.isfinite(trajectory).all(axis=(1, 2))
    caught = open_ & (
        actions_gate | (finite & implausible_trajectory(np.where(finite[:, None, None], trajectory, 0.0), limits))
    )
    codes[caught] = OUTCOME_CODES["implausible"]
    codes[open_ & ~caught & ~finite] = OUTCOME_CODES["format"]  # "ok" yet no usable trajectory
    return codes, caught


def outcome_counts(failure: np.ndarray, valid: np.ndarray) -> dict[str, int]:
    """Frames scored / failed (format, truncated or ambiguous) / implausible / lost to API errors."""
    return {
        "scored": int(valid.sum()),
        "failed": int(np.isin(failure, [OUTCOME_CODES[k] for k in UNREADABLE]).sum()),
        "implausible": int((failure == OUTCOME_CODES["implausible"]).sum()),
        "api_errors": int((failure == OUTCOME_CODES["api_error"]).sum()),
    }
