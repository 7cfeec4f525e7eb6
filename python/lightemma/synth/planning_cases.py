"""Plans with known faults for synthetic frames: each breaks a NAVSIM sub-score at a known time.

For a keyframe of a synthetic scene on a straight stretch of road (its ego lane runs along the ego frame's +x axis
with the centreline through the origin: :mod:`lightemma.synth.maps`), each function returns a :class:`PlanCase`: six
poses (x, y, heading in the keyframe's ego frame, at 0.5 … 3.0 s) and the time at which the plan breaks its
sub-score, computed on the plan's **reference** — the origin and the six poses resampled every 0.1 s (x, y and heading
linear in time), which the re-simulation (:func:`lightemma.planning.simulation.simulate`) tracks. The simulated
states differ: the tracker looks 10 steps (1 s) ahead, so it starts to follow a change before the reference makes it,
and it lags sideways, so a lateral fault is reached later; tests/unit/synth/test_synth_lanes.py re-simulates every case and
checks that its sub-score is 0 there (``ep``: short of the scene's progress), and for ``ddc`` and ``lk`` that the
simulated step is the reference's or later.

Cases (the scene kinds they are written for in :data:`CASES`; each raises ValueError for an unsuitable frame):

* :func:`wrong_way` (``ddc``, cruise ≥ 6 m/s): moves :data:`DRIFT` m left, into the oncoming lane, by 1 s and stays;
  breaks at the first step whose 11-step window holds 6 m of the centre's travel outside the ego lane. It also breaks
  ``lk`` (2 s off the centreline).
* :func:`hard_brake` (``c``, cruise ≥ 3 m/s): keeps its speed for 1 s, then brakes at :data:`HARD_BRAKE` m/s²
  (NAVSIM's bound: −4.05 m/s²); breaks at 1.0 s. The tracker smooths the brake: the simulated states break the
  longitudinal-jerk bound (±4.13 m/s³), their acceleration may stay within its bound.
* :func:`swerve` (``lk``, cruise ≥ 9.5 m/s): swerves :data:`SWERVE_OFFSET` m left and stays; breaks at the 20th
  consecutive step with the centre over 0.5 m from the centreline. The tracker overshoots into the oncoming lane near
  the end, so ``ddc`` may break too (0 in the test's frame).
* :func:`stop_short` (``ep``, cruise): brakes gently at :data:`STOP_DECEL` m/s²; its progress (known exactly) falls
  short of the scene's, decided at 3.0 s.

* :func:`follow_too_close` (``ttc``, cruise ≥ 7 m/s): a slower lead vehicle (:data:`LEAD_SPEED_FRACTION` of the
  ego's speed) in the ego lane, its rear :data:`FOLLOW_GAP_FRACTION` × 0.9 s × the closing speed ahead of the ego's
  front bumper at the keyframe (``PlanCase.agents``); the plan brakes at :data:`FOLLOW_BRAKE` m/s² to rest. Breaks
  ``ttc`` at 0.0 s: the footprint projected 0.9 s ahead at the initial speed overlaps the lead's box 0.9 s later,
  while the brake keeps the simulated footprint off the lead (``nc`` = 1). :func:`safe_follow` is its counterpart
  (``ttc`` = 1): the same lead :data:`SAFE_HEADWAY` s ahead and a gentle brake to its speed.

Why the TTC case fires from its first state: NAVSIM projects the footprint 0.3, 0.6, 0.9 s ahead only from steps
0 … 21 (2.1 s of the 3 s horizon), and the re-simulation's tracker takes about 1 s to follow a brake (it tracks the
speed 1 s ahead), so a plan that closes on a car after the keyframe and brakes late enough to come within 0.9 s of
it also touches it (tried: approaching a stopped car at 4–5 m/s and braking at 3–8 m/s² to 0.3–1 m behind it, and
braking from a constant approach to a slower car's speed). Closing from the keyframe on with a hard brake below the
lead's speed leaves margins of about 0.7 m (the simulated gap) and 0.7 m (the projected overlap) at 7 m/s, more at
higher speeds.

None of the fault cases leaves the drivable area or touches an agent. The ego box is lightemma's (4.084 m × 1.85 m,
centre 1.444 m ahead of the rear axle; :class:`lightemma.planning.scores.EgoBox`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lightemma.definitions import EGO_LENGTH, EGO_WIDTH, STEP_SECONDS, ZOE_REAR_AXLE_TO_CENTER
from lightemma.errors import InputError
from lightemma.synth.situations import LANE_WIDTH, Scenario

#: the plan's pose times (s after the keyframe) and the reference's step (s)
POSE_TIMES = np.arange(1, 7) * STEP_SECONDS
REFERENCE_DT = 0.1
#: lightemma's ego box: rear axle → centre, half length, half width (m)
CENTRE_OFFSET, HALF_LENGTH, HALF_WIDTH = ZOE_REAR_AXLE_TO_CENTER, EGO_LENGTH / 2, EGO_WIDTH / 2
#: deceleration of ``hard_brake`` (m/s²): beyond NAVSIM's comfort bound of 4.05
HARD_BRAKE = 6.0
#: deceleration of ``stop_short`` (m/s²): well within the comfort bounds, its onset included
STOP_DECEL = 1.5
#: lateral offset (m) of ``wrong_way``'s rear axle from 1 s on: in the oncoming lane (beyond LANE_WIDTH / 2), short of
#: its centre so that the tracker's overshoot keeps the footprint on the road
DRIFT = 0.8 * LANE_WIDTH
#: lateral offset (m) of ``swerve``'s rear axle from 1 s on
SWERVE_OFFSET = 1.5
#: ``follow_too_close``: the lead's speed as a fraction of the ego's, the bumper gap as a fraction of the closing
#: distance over 0.9 s (NAVSIM's longest TTC projection), the plan's brake to rest (m/s²)
LEAD_SPEED_FRACTION = 0.6
FOLLOW_GAP_FRACTION = 0.75
FOLLOW_BRAKE = 8.0
#: ``safe_follow``: the bumper gap as a time headway at the ego's speed (s) and the brake to the lead's speed (m/s²)
SAFE_HEADWAY = 1.5
SAFE_BRAKE = 2.0
#: the lead vehicle's box (m): the synthetic scenes' lead (lightemma.synth.situations.Lead)
LEAD_LENGTH, LEAD_WIDTH = 4.5, 1.9
#: NAVSIM's TTC: projections (steps of 0.1 s) and the last step projected from (30 states: 30 − 9)
TTC_PROJECTIONS = (0, 3, 6, 9)
TTC_LAST_STEP = 21


@dataclass(frozen=True)
class PlanCase:
    """A plan for one synthetic keyframe that breaks ``subscore`` at ``break_time`` s (a multiple of 0.1 s on the
    plan's reference; ``break_step`` = break_time / 0.1; NaN and -1 for a counterpart that breaks nothing, such as
    :func:`safe_follow`). ``poses`` (6, 3): x, y (m), heading (rad) in the
    keyframe's ego frame at 0.5 … 3.0 s; ``speed`` the ego's speed at the keyframe (m/s); ``known`` further exact
    values of the case (e.g. ``stop_short``'s progress)."""

    name: str
    subscore: str
    scene: str
    keyframe: int
    speed: float
    poses: np.ndarray
    break_time: float
    description: str
    known: dict[str, float] = field(default_factory=dict)
    #: (31, 8) the case's own agent at every 0.1 s step from the keyframe, in the keyframe's ego frame (centre x, y,
    #: yaw, length, width, velocity x, y, kind 0: ``lightemma.planning.scores`` box layout); None: the scene's own
    #: agents apply
    agents: np.ndarray | None = None

    @property
    def break_step(self) -> int:
        return -1 if np.isnan(self.break_time) else int(round(self.break_time / REFERENCE_DT))


def _time(step: int) -> float:
    """The time (s) of reference step ``step``, rounded to the 0.1 s grid."""
    return round(step * REFERENCE_DT, 6)


def reference(poses: np.ndarray) -> np.ndarray:
    """(31, 3) the plan's reference: the origin and ``poses`` (6, 3) linearly resampled every 0.1 s (heading
    unwrapped), as the re-simulation resamples them."""
    knots = np.vstack([np.zeros((1, 3)), np.asarray(poses, dtype=np.float64)])
    knots[:, 2] = np.unwrap(knots[:, 2])
    t = np.concatenate([[0.0], POSE_TIMES])
    fine = np.arange(31) * REFERENCE_DT
    return np.column_stack([np.interp(fine, t, knots[:, j]) for j in range(3)])


def centres(ref: np.ndarray) -> np.ndarray:
    """(S, 2) the ego box centre of reference poses (S, 3)."""
    return ref[:, :2] + CENTRE_OFFSET * np.column_stack([np.cos(ref[:, 2]), np.sin(ref[:, 2])])


def _keyframe(scn: Scenario, keyframe: int) -> float:
    if not 0 <= keyframe < len(scn.keyframe_times_us):
        raise InputError(f"scene {scn.name} has no keyframe {keyframe} (it has {len(scn.keyframe_times_us)})")
    t0 = float(scn.seconds(scn.keyframe_times_us[keyframe]))
    s0 = float(scn.profile.s(t0))
    ahead = float(scn.profile.s(t0 + 3.0)) + 2 * CENTRE_OFFSET + 10.0
    k = scn.path.curvature(np.linspace(s0 - 5.0, ahead, 200))
    if np.any(k != 0.0):
        raise InputError(
            f"scene {scn.name} keyframe {keyframe}: the road curves within the plan's reach; the plan "
            "cases need a straight stretch"
        )
    return t0


def _poses(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(6, 3) poses at :data:`POSE_TIMES` from positions, heading = the direction of the central difference of the
    neighbouring positions (the origin before the first; the last segment's direction at the end; 0 at rest)."""
    pts = np.column_stack([np.concatenate([[0.0], x]), np.concatenate([[0.0], y])])
    d = np.empty((6, 2))
    d[:5] = pts[2:] - pts[:-2]
    d[5] = pts[6] - pts[5]
    heading = np.where(np.hypot(d[:, 0], d[:, 1]) > 1e-9, np.arctan2(d[:, 1], d[:, 0]), 0.0)
    return np.column_stack([x, y, heading])


def _braking(v: float, decel: float, t_from: float, t) -> np.ndarray:
    """Distance (m) by time(s) ``t`` at speed ``v`` until ``t_from``, then braking at ``decel`` to rest."""
    t = np.asarray(t, dtype=np.float64)
    tau = np.clip(t - t_from, 0.0, v / decel)
    return v * np.minimum(t, t_from) + v * tau - 0.5 * decel * tau**2


def wrong_way(scn: Scenario, keyframe: int) -> PlanCase:
    """Drift into the oncoming lane: the lateral offset follows (1 − cos(π t / 1 s)) / 2 · :data:`DRIFT` until 1 s,
    then stays, at the keyframe's speed along the road. Breaks ``ddc`` (0) at the first reference step whose
    window of 11 steps holds ≥ 6 m of travel of the centre outside the ego lane (lateral > LANE_WIDTH / 2).
    Raises ValueError when the ego is slower than 6 m/s (1 s in the oncoming lane must be ≥ 6 m)."""
    t0 = _keyframe(scn, keyframe)
    v = float(scn.speed(t0))
    if v < 6.0:
        raise InputError(f"scene {scn.name} keyframe {keyframe}: speed {v:.2f} m/s; wrong_way needs ≥ 6 m/s")
    lat = DRIFT * (1 - np.cos(np.pi * np.minimum(POSE_TIMES, 1.0))) / 2
    poses = _poses(v * POSE_TIMES, lat)
    c = centres(reference(poses))
    out = np.abs(c[:, 1]) > LANE_WIDTH / 2
    travel = np.where(out[1:], np.hypot(*np.diff(c, axis=0).T), 0.0)
    window = np.array([travel[max(0, t - 10) : t].sum() for t in range(1, 31)])
    step = int(np.argmax(window >= 6.0)) + 1
    return PlanCase(
        "wrong-way",
        "ddc",
        scn.name,
        keyframe,
        v,
        poses,
        _time(step),
        f"drifts into the oncoming lane at {v:.2f} m/s",
        {"oncoming_from": float(np.argmax(out)) / 10},
    )


def hard_brake(scn: Scenario, keyframe: int) -> PlanCase:
    """Keep the keyframe's speed for 1 s, then brake at :data:`HARD_BRAKE` m/s² to rest: breaks ``c`` at 1.0 s
    (NAVSIM's longitudinal-acceleration bound is −4.05 m/s², its longitudinal-jerk bound ±4.13 m/s³). Raises
    ValueError below 3 m/s (the brake would last under half a second)."""
    t0 = _keyframe(scn, keyframe)
    v = float(scn.speed(t0))
    if v < 3.0:
        raise InputError(f"scene {scn.name} keyframe {keyframe}: speed {v:.2f} m/s; hard_brake needs ≥ 3 m/s")
    x = _braking(v, HARD_BRAKE, 1.0, POSE_TIMES)
    return PlanCase(
        "hard-brake",
        "c",
        scn.name,
        keyframe,
        v,
        _poses(x, np.zeros(6)),
        1.0,
        f"brakes at {HARD_BRAKE} m/s² from {v:.2f} m/s after 1 s",
        {"rest_at": 1.0 + v / HARD_BRAKE},
    )


def swerve(scn: Scenario, keyframe: int) -> PlanCase:
    """Swerve left to :data:`SWERVE_OFFSET` m from the centreline and stay there, at the keyframe's speed: poses
    (x = v t, y = 1.0, 1.5, 1.5, … m, heading 0.25, 0.05, 0, … rad). The footprint leaves the ego lane from about
    0.5 s. Breaks ``lk`` at the 20th consecutive reference step whose centre is more than 0.5 m from the
    centreline. The tracker is slow sideways: its centre passes 0.5 m near 1 s and overshoots towards 2 m (into the
    oncoming lane by up to about 0.3 m near the end, so ``ddc`` may be 0.5 or 0); a 3 s horizon leaves just over 20
    steps, so the case needs ≥ 9.5 m/s (ValueError below)."""
    t0 = _keyframe(scn, keyframe)
    v = float(scn.speed(t0))
    if v < 9.5:
        raise InputError(f"scene {scn.name} keyframe {keyframe}: speed {v:.2f} m/s; swerve needs ≥ 9.5 m/s")
    poses = np.column_stack([v * POSE_TIMES, [1.0] + [SWERVE_OFFSET] * 5, [0.25, 0.05, 0.0, 0.0, 0.0, 0.0]])
    far = np.abs(centres(reference(poses))[:, 1]) > 0.5
    run, step = 0, -1
    for i, flag in enumerate(far.tolist()):
        run = run + 1 if flag else 0
        if run == 20:
            step = i
            break
    if step < 0:  # pragma: no cover - the poses above are 0.5 m off from the first step on
        raise AssertionError("swerve: no run of 20 steps")
    return PlanCase(
        "swerve",
        "lk",
        scn.name,
        keyframe,
        v,
        poses,
        _time(step),
        f"swerves {SWERVE_OFFSET} m left and stays at {v:.2f} m/s",
        {"far_steps": float(far.sum()), "far_from": float(np.argmax(far)) / 10},
    )


def stop_short(scn: Scenario, keyframe: int) -> PlanCase:
    """Brake gently at :data:`STOP_DECEL` m/s² from the keyframe's speed (to rest, or to the end of the horizon):
    the progress falls short of the scene's. ``ep`` is decided at the last step (3.0 s, ``break_time``):
    ``known["progress"]`` is the plan's exact progress (m) over 3 s, ``known["gt_progress"]`` the scene's and
    ``known["rest_at"]`` the time of rest (may lie beyond 3 s). Needs a frame at constant speed (acceleration 0, so
    that the brake's onset stays within NAVSIM's jerk bound) and ≥ 2 m/s; raises ValueError otherwise."""
    t0 = _keyframe(scn, keyframe)
    v = float(scn.speed(t0))
    if v < 2.0 or float(scn.profile.a(t0)) != 0.0:
        raise InputError(
            f"scene {scn.name} keyframe {keyframe}: speed {v:.2f} m/s, acceleration "
            f"{float(scn.profile.a(t0)):.2f} m/s²; stop_short needs ≥ 2 m/s at constant speed"
        )
    x = _braking(v, STOP_DECEL, 0.0, POSE_TIMES)
    gt = float(scn.profile.s(t0 + 3.0) - scn.profile.s(t0))
    return PlanCase(
        "stop-short",
        "ep",
        scn.name,
        keyframe,
        v,
        _poses(x, np.zeros(6)),
        3.0,
        f"brakes at {STOP_DECEL} m/s² and covers {x[-1]:.2f} m (the scene drives {gt:.2f} m)",
        {"progress": float(x[-1]), "gt_progress": gt, "rest_at": v / STOP_DECEL},
    )


def _lead_boxes(gap: float, speed: float) -> np.ndarray:
    """(31, 8) a lead vehicle on the ego lane's centreline (the ego frame's x axis) at constant ``speed`` (m/s), its
    rear ``gap`` m ahead of the ego's front bumper at the keyframe, every 0.1 s."""
    t = np.arange(31) * REFERENCE_DT
    boxes = np.zeros((31, 8))
    boxes[:, 0] = CENTRE_OFFSET + HALF_LENGTH + gap + LEAD_LENGTH / 2 + speed * t
    boxes[:, 3], boxes[:, 4], boxes[:, 5] = LEAD_LENGTH, LEAD_WIDTH, speed
    return boxes


def _ttc_step(x: np.ndarray, speed: np.ndarray, lead: np.ndarray) -> int:
    """The first step (0 … :data:`TTC_LAST_STEP`) at which a straight ego run along the x axis — rear-axle positions
    ``x`` (31,) and speeds ``speed`` (31,) — projected 0, 0.3, 0.6, 0.9 s ahead at its speed reaches the lead's box
    ``lead`` (31, 8) at the projected step (NAVSIM's ``_calculate_ttc`` in one dimension: both boxes on the x axis,
    the lead straight ahead); -1 when none does."""
    front = x + CENTRE_OFFSET + HALF_LENGTH
    rear = lead[:, 0] - lead[:, 3] / 2
    for s in range(TTC_LAST_STEP + 1):
        if speed[s] < 5e-3:
            continue
        if any(front[s] + speed[s] * k * REFERENCE_DT > rear[s + k] for k in TTC_PROJECTIONS):
            return s
    return -1


def _brake_to(v: float, v_end: float, decel: float, t) -> tuple[np.ndarray, np.ndarray]:
    """Distance (m) and speed (m/s) by time(s) ``t`` braking from ``v`` at ``decel`` to ``v_end``, then holding it."""
    t = np.asarray(t, dtype=np.float64)
    tau = np.minimum(t, (v - v_end) / decel)
    return v * tau - 0.5 * decel * tau**2 + v_end * (t - tau), v - decel * tau


def _follow(scn: Scenario, keyframe: int, name: str) -> tuple[float, float, float]:
    t0 = _keyframe(scn, keyframe)
    v = float(scn.speed(t0))
    if v < 7.0:
        raise InputError(f"scene {scn.name} keyframe {keyframe}: speed {v:.2f} m/s; {name} needs ≥ 7 m/s")
    return v, LEAD_SPEED_FRACTION * v, t0


def follow_too_close(scn: Scenario, keyframe: int) -> PlanCase:
    """Close on a slower lead vehicle too fast and brake hard: a lead at :data:`LEAD_SPEED_FRACTION` of the
    keyframe's speed v in the ego lane, its rear gap g = :data:`FOLLOW_GAP_FRACTION` × 0.9 s × (v − v_lead) ahead of
    the ego's front bumper (``agents``; the scene's own lead is not used); the plan brakes at :data:`FOLLOW_BRAKE`
    m/s² to rest. Breaks ``ttc`` (0) at 0.0 s: the footprint moved 0.9 s ahead at v reaches 0.9 v while the lead's
    rear moves 0.9 v_lead, and 0.9 (v − v_lead) > g. ``known``: ``gap`` g (m), ``lead_speed`` (m/s), ``closing``
    0.9 (v − v_lead) (m). The brake keeps the footprint off the lead (``nc`` = 1 on the simulated states: about
    0.7 m to spare at 7 m/s). Raises ValueError below 7 m/s."""
    v, v_lead, _ = _follow(scn, keyframe, "follow_too_close")
    closing = 0.9 * (v - v_lead)
    gap = FOLLOW_GAP_FRACTION * closing
    lead = _lead_boxes(gap, v_lead)
    x, _ = _brake_to(v, 0.0, FOLLOW_BRAKE, POSE_TIMES)
    fine = np.arange(31) * REFERENCE_DT
    xr, ur = _brake_to(v, 0.0, FOLLOW_BRAKE, fine)
    step = _ttc_step(xr, ur, lead)
    if step < 0:  # pragma: no cover - 0.9 (v − v_lead) > gap at step 0 by construction
        raise AssertionError("follow_too_close: no TTC event on the reference")
    return PlanCase(
        "follow-too-close",
        "ttc",
        scn.name,
        keyframe,
        v,
        _poses(x, np.zeros(6)),
        _time(step),
        f"{gap:.2f} m behind a car at {v_lead:.2f} m/s, closing at {v - v_lead:.2f} m/s; brakes at {FOLLOW_BRAKE} m/s²",
        {"gap": gap, "lead_speed": v_lead, "closing": closing},
        lead,
    )


def safe_follow(scn: Scenario, keyframe: int) -> PlanCase:
    """:func:`follow_too_close`'s counterpart that passes ``ttc``: the same slower lead, its rear
    :data:`SAFE_HEADWAY` s × v ahead of the front bumper; the plan brakes at :data:`SAFE_BRAKE` m/s² to the lead's
    speed and follows. ``subscore`` is ``ttc`` with ``break_time`` NaN (it breaks nothing); ``known`` as
    :func:`follow_too_close`'s. Raises ValueError below 7 m/s."""
    v, v_lead, _ = _follow(scn, keyframe, "safe_follow")
    gap = SAFE_HEADWAY * v
    lead = _lead_boxes(gap, v_lead)
    x, _ = _brake_to(v, v_lead, SAFE_BRAKE, POSE_TIMES)
    xr, ur = _brake_to(v, v_lead, SAFE_BRAKE, np.arange(31) * REFERENCE_DT)
    if _ttc_step(xr, ur, lead) >= 0:  # pragma: no cover - 1.5 s of headway against at most 0.9 s of closing
        raise AssertionError("safe_follow: a TTC event on the reference")
    return PlanCase(
        "safe-follow",
        "ttc",
        scn.name,
        keyframe,
        v,
        _poses(x, np.zeros(6)),
        float("nan"),
        f"{gap:.2f} m behind a car at {v_lead:.2f} m/s; brakes at {SAFE_BRAKE} m/s² to its speed",
        {"gap": gap, "lead_speed": v_lead, "closing": 0.9 * (v - v_lead)},
        lead,
    )


#: every case: (function, the scenario kind it is written for)
CASES = {
    "wrong-way": (wrong_way, "cruise"),
    "hard-brake": (hard_brake, "cruise"),
    "swerve": (swerve, "cruise"),
    "stop-short": (stop_short, "cruise"),
    "follow-too-close": (follow_too_close, "cruise"),
}
