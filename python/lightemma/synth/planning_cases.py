"""Plans with known faults for synthetic frames: each breaks a NAVSIM sub-score at a known time.

For a keyframe of a synthetic scene on a straight stretch of road (its ego lane runs along the ego frame's +x axis
with the centreline through the origin: :mod:`lightemma.synth.maps`), each function returns a :class:`PlanCase`: six
poses (x, y, heading in the keyframe's ego frame, at 0.5 … 3.0 s) and the time at which the plan breaks its
sub-score, computed on the plan's **reference** — the origin and the six poses resampled every 0.1 s (x, y and heading
linear in time), which the re-simulation (:func:`lightemma.planning.simulation.simulate`) tracks. The simulated
states differ: the tracker looks 10 steps (1 s) ahead, so it starts to follow a change before the reference makes it,
and it lags sideways, so a lateral fault is reached later; tests/test_synth_lanes.py re-simulates every case and
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

No case breaks ``ttc``: NAVSIM projects the footprint 0.3, 0.6, 0.9 s ahead only from steps 0 … 21 (2.1 s of the 3 s
horizon), and the re-simulation's tracker brakes ahead of a late-braking plan, so a plan that comes within 0.9 s of a
car without touching it leaves no robust margin (tried: approaching a stopped car at 4–5 m/s and braking at
3–8 m/s² to 0.3–1 m behind it; the simulated states trigger ttc only at 0.3 m, in one frame of one seed).

None of them leaves the drivable area or touches an agent. The ego box is lightemma's (4.084 m × 1.85 m, centre
1.444 m ahead of the rear axle; :class:`lightemma.planning.scores.EgoBox`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lightemma.synth.scenarios import LANE_WIDTH, Scenario

#: the plan's pose times (s after the keyframe) and the reference's step (s)
POSE_TIMES = np.arange(1, 7) * 0.5
REFERENCE_DT = 0.1
#: lightemma's ego box: rear axle → centre, half length, half width (m)
CENTRE_OFFSET, HALF_LENGTH, HALF_WIDTH = 1.444, 4.084 / 2, 1.85 / 2
#: deceleration of ``hard_brake`` (m/s²): beyond NAVSIM's comfort bound of 4.05
HARD_BRAKE = 6.0
#: deceleration of ``stop_short`` (m/s²): well within the comfort bounds, its onset included
STOP_DECEL = 1.5
#: lateral offset (m) of ``wrong_way``'s rear axle from 1 s on: in the oncoming lane (beyond LANE_WIDTH / 2), short of
#: its centre so that the tracker's overshoot keeps the footprint on the road
DRIFT = 0.8 * LANE_WIDTH
#: lateral offset (m) of ``swerve``'s rear axle from 1 s on
SWERVE_OFFSET = 1.5


@dataclass(frozen=True)
class PlanCase:
    """A plan for one synthetic keyframe that breaks ``subscore`` at ``break_time`` s (a multiple of 0.1 s on the
    plan's reference; ``break_step`` = break_time / 0.1). ``poses`` (6, 3): x, y (m), heading (rad) in the
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

    @property
    def break_step(self) -> int:
        return int(round(self.break_time / REFERENCE_DT))


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
        raise ValueError(f"scene {scn.name} has no keyframe {keyframe} (it has {len(scn.keyframe_times_us)})")
    t0 = float(scn.seconds(scn.keyframe_times_us[keyframe]))
    s0 = float(scn.profile.s(t0))
    ahead = float(scn.profile.s(t0 + 3.0)) + 2 * CENTRE_OFFSET + 10.0
    k = scn.path.curvature(np.linspace(s0 - 5.0, ahead, 200))
    if np.any(k != 0.0):
        raise ValueError(f"scene {scn.name} keyframe {keyframe}: the road curves within the plan's reach; the plan "
                         "cases need a straight stretch")
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
        raise ValueError(f"scene {scn.name} keyframe {keyframe}: speed {v:.2f} m/s; wrong_way needs ≥ 6 m/s")
    lat = DRIFT * (1 - np.cos(np.pi * np.minimum(POSE_TIMES, 1.0))) / 2
    poses = _poses(v * POSE_TIMES, lat)
    c = centres(reference(poses))
    out = np.abs(c[:, 1]) > LANE_WIDTH / 2
    travel = np.where(out[1:], np.hypot(*np.diff(c, axis=0).T), 0.0)
    window = np.array([travel[max(0, t - 10) : t].sum() for t in range(1, 31)])
    step = int(np.argmax(window >= 6.0)) + 1
    return PlanCase("wrong-way", "ddc", scn.name, keyframe, v, poses, _time(step),
                    f"drifts into the oncoming lane at {v:.2f} m/s", {"oncoming_from": float(np.argmax(out)) / 10})


def hard_brake(scn: Scenario, keyframe: int) -> PlanCase:
    """Keep the keyframe's speed for 1 s, then brake at :data:`HARD_BRAKE` m/s² to rest: breaks ``c`` at 1.0 s
    (NAVSIM's longitudinal-acceleration bound is −4.05 m/s², its longitudinal-jerk bound ±4.13 m/s³). Raises
    ValueError below 3 m/s (the brake would last under half a second)."""
    t0 = _keyframe(scn, keyframe)
    v = float(scn.speed(t0))
    if v < 3.0:
        raise ValueError(f"scene {scn.name} keyframe {keyframe}: speed {v:.2f} m/s; hard_brake needs ≥ 3 m/s")
    x = _braking(v, HARD_BRAKE, 1.0, POSE_TIMES)
    return PlanCase("hard-brake", "c", scn.name, keyframe, v, _poses(x, np.zeros(6)), 1.0,
                    f"brakes at {HARD_BRAKE} m/s² from {v:.2f} m/s after 1 s", {"rest_at": 1.0 + v / HARD_BRAKE})


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
        raise ValueError(f"scene {scn.name} keyframe {keyframe}: speed {v:.2f} m/s; swerve needs ≥ 9.5 m/s")
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
    return PlanCase("swerve", "lk", scn.name, keyframe, v, poses, _time(step),
                    f"swerves {SWERVE_OFFSET} m left and stays at {v:.2f} m/s",
                    {"far_steps": float(far.sum()), "far_from": float(np.argmax(far)) / 10})


def stop_short(scn: Scenario, keyframe: int) -> PlanCase:
    """Brake gently at :data:`STOP_DECEL` m/s² from the keyframe's speed (to rest, or to the end of the horizon):
    the progress falls short of the scene's. ``ep`` is decided at the last step (3.0 s, ``break_time``):
    ``known["progress"]`` is the plan's exact progress (m) over 3 s, ``known["gt_progress"]`` the scene's and
    ``known["rest_at"]`` the time of rest (may lie beyond 3 s). Needs a frame at constant speed (acceleration 0, so
    that the brake's onset stays within NAVSIM's jerk bound) and ≥ 2 m/s; raises ValueError otherwise."""
    t0 = _keyframe(scn, keyframe)
    v = float(scn.speed(t0))
    if v < 2.0 or float(scn.profile.a(t0)) != 0.0:
        raise ValueError(f"scene {scn.name} keyframe {keyframe}: speed {v:.2f} m/s, acceleration "
                         f"{float(scn.profile.a(t0)):.2f} m/s²; stop_short needs ≥ 2 m/s at constant speed")
    x = _braking(v, STOP_DECEL, 0.0, POSE_TIMES)
    gt = float(scn.profile.s(t0 + 3.0) - scn.profile.s(t0))
    return PlanCase("stop-short", "ep", scn.name, keyframe, v, _poses(x, np.zeros(6)), 3.0,
                    f"brakes at {STOP_DECEL} m/s² and covers {x[-1]:.2f} m (the scene drives {gt:.2f} m)",
                    {"progress": float(x[-1]), "gt_progress": gt, "rest_at": v / STOP_DECEL})


#: every case: (function, the scenario kind it is written for)
CASES = {"wrong-way": (wrong_way, "cruise"), "hard-brake": (hard_brake, "cruise"), "swerve": (swerve, "cruise"),
         "stop-short": (stop_short, "cruise")}
