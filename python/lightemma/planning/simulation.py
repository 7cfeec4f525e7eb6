"""Re-simulation of plans and their comfort, as NAVSIM computes them (docs/definitions.md#re-simulation-and-comfort).

The kernels are in Rust (``rust/planning/simulate.rs``, ``rust/planning/comfort.rs``); this module is their typed
public layer plus the derivation of a frame's initial ego state and recorded-past states from its history.

States use NAVSIM's 11-column layout (``STATE_COLUMNS``): x, y (m), heading (rad), velocity x, y (m/s),
acceleration x, y (m/s², body frame of the rear axle), steering angle (rad), steering rate (rad/s), yaw rate
(rad/s), yaw acceleration (rad/s²); the reference point is the rear-axle centre (nuScenes' ego frame).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from numpy.typing import ArrayLike

from lightemma import _core
from lightemma.definitions import STEP_SECONDS, ZOE_REAR_AXLE_TO_CENTER
from lightemma.errors import InputError, ShapeError
from lightemma.kinematics import integrate

#: a float64 array (shapes in each docstring)
FloatArray = npt.NDArray[np.float64]

STATE_COLUMNS: tuple[str, ...] = (
    "x",
    "y",
    "heading",
    "velocity_x",
    "velocity_y",
    "acceleration_x",
    "acceleration_y",
    "steering_angle",
    "steering_rate",
    "yaw_rate",
    "yaw_acceleration",
)
#: NAVSIM's six comfort bounds, in order, with their exclusive (lower, upper) limits.
COMFORT_BOUNDS: tuple[str, ...] = tuple(_core.COMFORT_BOUNDS)
COMFORT_LIMITS: tuple[tuple[float, float], ...] = tuple((lo, hi) for lo, hi in _core.COMFORT_LIMITS)
#: NAVSIM v2's extended-comfort features, in order, with their inclusive RMS-difference limits.
EXTENDED_COMFORT_FEATURES: tuple[str, ...] = tuple(_core.EXTENDED_COMFORT_FEATURES)
EXTENDED_COMFORT_LIMITS: tuple[float, ...] = tuple(_core.EXTENDED_COMFORT_LIMITS)

#: NAVSIM's bound on the spacing of the two frames of extended comfort, seconds (exclusive).
MAX_INTERVAL = 0.55
#: NAVSIM's recorded past for history comfort: 1.5 s before the present.
HISTORY_SECONDS = 1.5


@dataclass(frozen=True)
class Vehicle:
    """The ego as the motion model and the comfort scores see it.

    Attributes:
        wheel_base: rear axle to front axle, m.
        rear_axle_to_center: rear axle to the centre of the vehicle box, m (moves the longitudinal
            acceleration to the centre in the comfort bounds, as NAVSIM does).
        max_steering_angle: |steering| limit of the bicycle model, rad.
        accel_time_constant: first-order lag of the acceleration command, s.
        steering_angle_time_constant: first-order lag of the steering angle, s.
    """

    wheel_base: float
    rear_axle_to_center: float
    max_steering_angle: float = float(np.pi / 3)
    accel_time_constant: float = 0.2
    steering_angle_time_constant: float = 0.05

    def as_tuple(self) -> tuple[float, float, float, float, float]:
        return (
            float(self.wheel_base),
            float(self.rear_axle_to_center),
            float(self.max_steering_angle),
            float(self.accel_time_constant),
            float(self.steering_angle_time_constant),
        )


#: nuScenes' ego, a Renault Zoe: wheelbase 2.588 m (Renault ZOE technical data), box centre 1.444 m ahead of the
#: rear axle (lightemma's ego box, docs/definitions.md#safety); nuPlan's motion-model defaults for the rest.
ZOE = Vehicle(wheel_base=2.588, rear_axle_to_center=ZOE_REAR_AXLE_TO_CENTER)
#: nuPlan's Chrysler Pacifica (``get_pacifica_parameters``), NAVSIM's default: for checks against NAVSIM's code.
PACIFICA = Vehicle(wheel_base=3.089, rear_axle_to_center=1.461)


def _array(value: ArrayLike, name: str, ndim: int, last: int, shape_text: str) -> FloatArray:
    try:
        array = np.asarray(value)
    except Exception as exc:  # ragged lists and the like
        raise InputError(f"{name} cannot be turned into an array: {exc}") from None
    if array.dtype == object or not np.issubdtype(array.dtype, np.number) or np.iscomplexobj(array):
        raise InputError(f"{name} must hold real numbers, got dtype {array.dtype} (shape {array.shape})")
    if array.ndim != ndim or array.shape[-1] != last:
        raise ShapeError(f"{name} must have shape {shape_text}, got {array.shape}")
    return np.ascontiguousarray(array, dtype=np.float64)


def plan_poses(actions: ArrayLike, *, dt: float = STEP_SECONDS, method: str = "euler") -> FloatArray:
    """A plan's poses: the integrated trajectory of (speed, curvature) actions with its headings.

    Args:
        actions: (N, K, 2) speed m/s, curvature 1/m (lightemma's actions).
        dt: seconds per action.
        method: integration method of :func:`lightemma.integrate`.

    Returns:
        (N, K, 3) x, y (m, ego frame) and heading (rad) after each step: heading_k = Σ_{j≤k} κ_j v_j dt, the heading
        both integration methods end each step with. NaN actions give NaN poses.
    """
    array = _array(actions, "actions", 3, 2, "(N, K, 2)")
    positions = integrate(array, dt=dt, method=method)
    headings = np.cumsum(array[..., 0] * array[..., 1] * dt, axis=1)
    return np.concatenate([positions, headings[..., None]], axis=2)


def simulate(
    poses: ArrayLike,
    initial_state: ArrayLike,
    *,
    plan_dt: float = STEP_SECONDS,
    dt: float = 0.1,
    vehicle: Vehicle | None = None,
) -> FloatArray:
    """Re-simulate plans as NAVSIM does: resample at ``dt``, track with nuPlan's LQR on a kinematic bicycle.

    Args:
        poses: (N, K, 3) x, y (m), heading (rad) at ``plan_dt``, 2 ``plan_dt``, …, K ``plan_dt`` s, in the frame of
            the initial state's pose (lightemma: the keyframe's ego frame, initial pose at the origin).
        initial_state: (N, 11) the state at t = 0 in NAVSIM's layout (:data:`STATE_COLUMNS`), e.g. from
            :func:`initial_state`.
        plan_dt: seconds between plan poses (0.5 for nuScenes keyframes).
        dt: simulation step, seconds (NAVSIM: 0.1); K ``plan_dt`` must be a whole number T ≥ 2 of steps.
        vehicle: motion-model parameters; ``None`` is :data:`ZOE`.

    Returns:
        (N, T + 1, 11) simulated states, the initial state first (T = 30 for six 0.5 s poses). A frame whose poses or
        initial state hold a NaN or infinity is NaN throughout (not available: say so, never score it).

    Raises:
        ValueError: wrong shapes, non-numeric input, a horizon that is not a whole number of steps, bad vehicle.
    """
    p = _array(poses, "poses", 3, 3, "(N, K, 3)")
    s = _array(initial_state, "initial_state", 2, 11, "(N, 11)")
    v = (vehicle or ZOE).as_tuple()
    return _core.simulate(p, s, float(plan_dt), float(dt), v)


@dataclass(frozen=True)
class ComfortResult:
    """Comfort of N frames of states.

    Attributes:
        comfortable: (N,) 1.0 when all six bounds hold, 0.0 when one does not, NaN when the states are not finite.
        within: (N, 6) bool, each bound of :data:`COMFORT_BOUNDS` met (False for a non-finite frame).
        extremes: (N, 6, 2) each filtered signal's (min, max) over the frame (m/s², m/s³, rad/s², rad/s; NaN for a
            non-finite frame). A bound holds when lower < min and max < upper (:data:`COMFORT_LIMITS`).
    """

    comfortable: FloatArray
    within: npt.NDArray[np.bool_]
    extremes: FloatArray


def comfort_details(states: ArrayLike, *, dt: float = 0.1, vehicle: Vehicle | None = None) -> ComfortResult:
    """nuPlan's six comfort bounds on states, as NAVSIM's ``ego_is_comfortable`` (v1 ``c``; ``hc`` on
    :func:`history_states` followed by the simulated states).

    Args:
        states: (N, T, 11) states at ``dt`` spacing, T ≥ 4.
        dt: seconds between states.
        vehicle: only its ``rear_axle_to_center`` is used; ``None`` is :data:`ZOE` (NAVSIM uses the Pacifica's).

    Raises:
        ValueError: wrong shape, T < 4, bad ``dt``.
    """
    return _comfort(states, dt, vehicle, None)


def _comfort(states: ArrayLike, dt: float, vehicle: Vehicle | None, history: FloatArray | None) -> ComfortResult:
    s = _array(states, "states", 3, 11, "(N, T, 11)")
    r = float((vehicle or ZOE).rear_axle_to_center)
    within, extremes = _core.comfort(s, float(dt), r, history)
    finite = np.isfinite(extremes).all(axis=(1, 2))
    comfortable = np.where(finite, within.all(axis=1).astype(np.float64), np.nan)
    return ComfortResult(comfortable=comfortable, within=within, extremes=extremes)


def comfort(states: ArrayLike, *, dt: float = 0.1, vehicle: Vehicle | None = None) -> FloatArray:
    """(N,) 1.0 comfortable / 0.0 not / NaN not available: all six nuPlan bounds (see :func:`comfort_details`)."""
    return comfort_details(states, dt=dt, vehicle=vehicle).comfortable


@dataclass(frozen=True)
class ExtendedComfortResult:
    """NAVSIM v2's two-frame extended comfort of N frame pairs.

    Attributes:
        comfortable: (N,) 1.0 when every RMS difference is within its limit, 0.0 otherwise, NaN not available.
        rms: (N, 4) RMS over the overlap of the per-instant difference of each feature of
            :data:`EXTENDED_COMFORT_FEATURES` (m/s², m/s³, rad/s, rad/s²); limits :data:`EXTENDED_COMFORT_LIMITS`
            (inclusive).
    """

    comfortable: FloatArray
    rms: FloatArray


def extended_comfort_details(
    states_now: ArrayLike, states_prev: ArrayLike, *, dt: float = 0.1, interval: float = STEP_SECONDS
) -> ExtendedComfortResult:
    """Two-frame extended comfort (``ec``), NAVSIM's ``SceneAggregator._compute_two_frame_comfort``.

    The previous keyframe's plan started ``interval`` seconds earlier: its states from step s = round(interval / dt)
    on cover the same instants as this frame's states up to T − s; on that overlap (T − s states) the features are
    computed as NAVSIM's ``extract_features`` (acceleration magnitude, jerk, yaw rate, yaw acceleration) and
    compared by RMS difference. Features use no position or absolute heading, so each plan may be in its own
    keyframe's ego frame.

    Args:
        states_now, states_prev: (N, T, 11) simulated states of this and the previous keyframe.
        dt: seconds between states.
        interval: seconds between the two keyframes' timestamps (nuScenes: about 0.5, NAVSIM's spacing); the shift
            is ``round(interval / dt)`` steps, as NAVSIM rounds it.

    Raises:
        ValueError: shapes differ or are wrong; ``interval`` outside (0, 0.55) s (NAVSIM asserts it) or under half a
            step; a shift as long as the plan.
    """
    a = _array(states_now, "states_now", 3, 11, "(N, T, 11)")
    b = _array(states_prev, "states_prev", 3, 11, "(N, T, 11)")
    interval, dt = float(interval), float(dt)
    if not (0.0 < interval < MAX_INTERVAL) or not (np.isfinite(dt) and dt > 0.0):
        raise InputError(f"interval must be in (0, {MAX_INTERVAL}) s (NAVSIM's check) and dt > 0, got {interval}, {dt}")
    shift = round(interval / dt)  # NAVSIM: round(observation_interval / interval_length)
    if shift < 1:
        raise InputError(f"interval {interval} s is shorter than half a step of dt = {dt} s")
    rms = _core.extended_comfort(a, b, float(dt), int(shift))
    limits = np.asarray(EXTENDED_COMFORT_LIMITS)
    finite = np.isfinite(rms).all(axis=1)
    comfortable = np.where(finite, (rms <= limits).all(axis=1).astype(np.float64), np.nan)
    return ExtendedComfortResult(comfortable=comfortable, rms=rms)


def extended_comfort(
    states_now: ArrayLike, states_prev: ArrayLike, *, dt: float = 0.1, interval: float = STEP_SECONDS
) -> FloatArray:
    """(N,) 1.0 / 0.0 / NaN: NAVSIM v2's two-frame extended comfort (see :func:`extended_comfort_details`)."""
    return extended_comfort_details(states_now, states_prev, dt=dt, interval=interval).comfortable


@dataclass(frozen=True)
class DerivedStates:
    """States derived from recorded past positions.

    Attributes:
        states: (N, …, 11) NAVSIM-layout states; NaN rows where not derivable.
        reasons: one entry per frame: ``None`` when derived, else why not (one line).
    """

    states: FloatArray
    reasons: list[str | None]

    @property
    def available(self) -> npt.NDArray[np.bool_]:
        """(N,) bool: the frame's states were derived."""
        return np.array([r is None for r in self.reasons], dtype=bool)


#: Below this speed (m/s) a motion direction, curvature and steering angle are not derived (set to 0).
_STANDSTILL = 0.2


def _check_history(
    history_positions: ArrayLike, need: int, times: ArrayLike | None, dt: float
) -> tuple[FloatArray, FloatArray, list[str | None]]:
    """Positions (N, P, 2), their times (N, P) in seconds relative to the last one (``dt`` apart when ``times`` is
    ``None``) and per frame why its last ``need`` positions cannot be used (``None`` when they can)."""
    h = _array(history_positions, "history_positions", 3, 2, "(N, P, 2)")
    if h.shape[1] < need:
        raise ShapeError(f"history_positions must hold at least {need} positions per frame, got {h.shape[1]}")
    if times is None:
        dt = float(dt)
        if not (np.isfinite(dt) and dt > 0.0):
            raise InputError(f"dt must be a positive number of seconds, got {dt}")
        t = np.broadcast_to(np.arange(1 - h.shape[1], 1) * dt, h.shape[:2]).copy()
    else:
        t = np.asarray(times, dtype=np.float64)
        if t.shape != h.shape[:2]:
            raise ShapeError(f"times must have shape {h.shape[:2]} (one per history position), got {t.shape}")
        with np.errstate(invalid="ignore"):
            t = t - t[:, -1:]
    reasons: list[str | None] = []
    for i, frame in enumerate(h):
        if not np.isfinite(frame[-need:]).all():
            reasons.append(f"frame {i}: the last {need} history positions hold a NaN or infinity")
        elif np.abs(frame[-1]).max() > 1e-6:
            reasons.append(f"frame {i}: the last history position {frame[-1].tolist()} is not the ego-frame origin")
        elif not np.isfinite(t[i, -need:]).all():
            reasons.append(f"frame {i}: the times of the last {need} history positions hold a NaN or infinity")
        elif not (np.diff(t[i, -need:]) > 0.0).all():
            reasons.append(f"frame {i}: the times of the last {need} history positions are not increasing")
        else:
            reasons.append(None)
    return h, t, reasons


def _quadratic_weights(t: FloatArray, at: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Weights (…, 3) of three samples at times ``t`` (…, 3) giving the first derivative at ``at`` (…) and the second
    derivative of the quadratic through them (Lagrange; exact for any spacing, the usual central/backward
    differences when the spacing is even)."""
    t0, t1, t2 = t[..., 0], t[..., 1], t[..., 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        d0, d1, d2 = (t0 - t1) * (t0 - t2), (t1 - t0) * (t1 - t2), (t2 - t0) * (t2 - t1)
        first = np.stack([(2 * at - t1 - t2) / d0, (2 * at - t0 - t2) / d1, (2 * at - t0 - t1) / d2], axis=-1)
        second = np.stack([2 / d0, 2 / d1, 2 / d2], axis=-1)
    return first, second


def _keyframe_states(h: FloatArray, times: FloatArray, vehicle: Vehicle) -> FloatArray:
    """(N, 4, 11) states at the last four keyframes (nominally −1.5, −1.0, −0.5, 0 s) from positions (N, P ≥ 5, 2)
    at ``times`` (N, P) seconds."""
    n = h.shape[0]
    p = h[:, -5:]  # nominally t = -2.0 … 0
    tt = times[:, -5:]
    vel = np.empty((n, 4, 2))
    acc = np.empty((n, 4, 2))
    # keyframes −1.5, −1.0, −0.5: the quadratic through each and its neighbours, at it (central differences for even
    # spacing); the present: the quadratic through the last three (the backward three-point formulas)
    for k in range(4):
        lo = min(k, 2)
        first, second = _quadratic_weights(tt[:, lo : lo + 3], tt[:, k + 1])
        vel[:, k] = np.einsum("nj,njc->nc", first, p[:, lo : lo + 3])
        acc[:, k] = np.einsum("nj,njc->nc", second, p[:, lo : lo + 3])
    speed = np.hypot(vel[..., 0], vel[..., 1])
    moving = speed > _STANDSTILL
    heading = np.where(moving, np.arctan2(vel[..., 1], vel[..., 0]), np.nan)
    heading[:, 3] = 0.0  # the ego frame's x axis is the present heading
    for k in (2, 1, 0):  # a standing car keeps the heading of the next keyframe
        heading[:, k] = np.where(np.isnan(heading[:, k]), heading[:, k + 1], heading[:, k])
    cos, sin = np.cos(heading), np.sin(heading)
    v_lon = cos * vel[..., 0] + sin * vel[..., 1]
    a_lon = cos * acc[..., 0] + sin * acc[..., 1]
    a_lat = -sin * acc[..., 0] + cos * acc[..., 1]
    cross = vel[..., 0] * acc[..., 1] - vel[..., 1] * acc[..., 0]
    safe = np.where(moving, speed, 1.0)
    yaw_rate = np.where(moving, cross / safe**2, 0.0)
    curvature = np.where(moving, cross / safe**3, 0.0)
    states = np.zeros((n, 4, 11))
    states[..., 0] = p[:, 1:, 0]
    states[..., 1] = p[:, 1:, 1]
    states[..., 2] = heading
    states[..., 3] = v_lon
    states[..., 5] = a_lon
    states[..., 6] = a_lat
    states[..., 7] = np.arctan(vehicle.wheel_base * curvature)
    states[..., 9] = yaw_rate
    return states


#: Largest difference (m/s) between the CAN bus speed and the speed derived from positions that is accepted: the
#: backward three-point formula is exact under constant acceleration; 2.5 m/s is 5 m/s² of unmodelled change over
#: its 0.5 s.
CAN_SPEED_TOLERANCE = 2.5


def initial_state(
    history_positions: ArrayLike,
    *,
    can: ArrayLike | None = None,
    dt: float = STEP_SECONDS,
    times: ArrayLike | None = None,
    vehicle: Vehicle | None = None,
) -> DerivedStates:
    """A frame's initial ego state (t = 0) derived from its recorded past positions, and from the CAN bus if given.

    The ego frame puts the rear axle at the origin heading along +x, so x = y = heading = 0. With p₀ = the present
    and p₋₁, p₋₂ the two keyframes before, at their ``times`` (``dt`` apart when ``times`` is ``None``), the
    quadratic through them gives the velocity at t = 0 and its acceleration — for even spacing
    v = (3p₀ − 4p₋₁ + p₋₂) / 2dt and a = (p₀ − 2p₋₁ + p₋₂) / dt²; for uneven spacing (nuScenes keyframes are
    0.47–0.52 s apart) the same quadratic with the real intervals (ego frame). velocity_x = vₓ,
    acceleration_x = aₓ, acceleration_y = a_y (velocity_y = 0: the bicycle model has none); yaw rate = (v × a) / |v|²
    and steering angle = atan(wheel_base · (v × a) / |v|³) (the bicycle model's yaw rate v tan δ / L); both 0 below
    0.2 m/s. Steering rate and yaw acceleration are 0.

    With ``can`` (a row of finite CAN bus readings at the keyframe), velocity_x, acceleration_x, acceleration_y and
    the yaw rate are the readings and the steering angle is atan(wheel_base · yaw rate / speed) (0 below 0.2 m/s);
    a reading whose speed differs from the positions' by more than :data:`CAN_SPEED_TOLERANCE` makes the frame not
    available (two readings disagree: neither is chosen).

    Limits: keyframes are about 0.5 s apart, so positions give averages over the last second — a brake or a steering
    input that began within it is seen late and smoothed; this function reads no files (the caller passes the CAN bus
    readings of the frames whose dataroot has them).

    Args:
        history_positions: (N, P ≥ 3, 2) positions at ``dt`` spacing, oldest first, the last one the ego-frame
            origin (a Frame's ``history_positions``, (8, 2) each).
        can: optional (N, 4) CAN bus readings at the keyframe: speed (m/s), longitudinal and lateral acceleration
            (m/s²), yaw rate (rad/s) — nuScenes' ``can_bus`` ``pose`` message ``vel[0]``, ``accel[0]``, ``accel[1]``,
            ``rotation_rate[2]``; a row with a NaN is not used (the positions' values stand).
        dt: seconds between positions when ``times`` is ``None``.
        times: optional (N, P) timestamps of the positions, seconds (any origin; the keyframes' ``timestamp`` / 1e6);
            they replace ``dt``.
        vehicle: for the wheelbase; ``None`` is :data:`ZOE`.

    Returns:
        :class:`DerivedStates` with ``states`` (N, 11); a frame with a non-finite position or time among its last
        three, times not increasing, a last position that is not the origin, or a CAN bus speed that disagrees, has a
        NaN row and its reason.

    Raises:
        ValueError: shapes (fewer than 3 positions, ``can`` not (N, 4), ``times`` not (N, P)), ``dt`` not positive.
    """
    h, t, reasons = _check_history(history_positions, 3, times, dt)
    veh = vehicle or ZOE
    padded = np.concatenate([np.zeros((h.shape[0], 2, 2)), h[:, -3:]], axis=1)
    padded_t = np.concatenate([t[:, -3:-2] - 2.0, t[:, -3:-2] - 1.0, t[:, -3:]], axis=1)  # unused earlier slots
    states = _keyframe_states(padded, padded_t, veh)[:, 3].copy()
    states[:, 2] = 0.0
    if can is not None:
        readings = _array(can, "can", 2, 4, "(N, 4)")
        if readings.shape[0] != h.shape[0]:
            raise ShapeError(f"can has {readings.shape[0]} rows but history_positions has {h.shape[0]} frames")
        for i, row in enumerate(readings):
            if reasons[i] is not None or not np.isfinite(row).all():
                continue
            speed, a_lon, a_lat, yaw_rate = (float(x) for x in row)
            derived = float(states[i, 3])
            if abs(speed - derived) > CAN_SPEED_TOLERANCE:
                reasons[i] = (
                    f"frame {i}: the CAN bus speed {speed:.2f} m/s and the positions' {derived:.2f} m/s disagree "
                    f"by more than {CAN_SPEED_TOLERANCE} m/s"
                )
                continue
            states[i, 3], states[i, 5], states[i, 6], states[i, 9] = speed, a_lon, a_lat, yaw_rate
            moving = abs(speed) > _STANDSTILL
            states[i, 7] = np.arctan(veh.wheel_base * yaw_rate / speed) if moving else 0.0
    states[np.array([r is not None for r in reasons], dtype=bool)] = np.nan
    return DerivedStates(states=states, reasons=reasons)


def history_states(
    history_positions: ArrayLike,
    *,
    sim_dt: float = 0.1,
    dt: float = STEP_SECONDS,
    times: ArrayLike | None = None,
    vehicle: Vehicle | None = None,
) -> DerivedStates:
    """The recorded past that NAVSIM puts before the simulated states for history comfort (``hc``).

    NAVSIM takes the ego states of the keyframes at −1.5, −1.0, −0.5 and 0 s, interpolates them linearly (heading
    unwrapped) at ``numpy.arange(−1.5, 0, 0.1)`` and drops the last instant (``[:-1]``): 14 states at −1.5 … −0.2 s,
    followed directly by the simulated states from 0 s (its timestamps then count them 0.1 s apart). This function
    does the same with keyframe states derived from positions: velocity and acceleration by central differences
    (the present keyframe by the backward formulas of :func:`initial_state`), heading = direction of motion (the
    present: 0; a car below 0.2 m/s keeps the next keyframe's heading), yaw rate (v × a)/|v|², steering angle
    atan(L κ); steering rate and yaw acceleration 0 (not derivable at 2 Hz). With ``times`` the derivatives use the
    real keyframe spacing (the quadratic through each keyframe and its neighbours) and the keyframe states are placed
    at their real times before the linear interpolation; an instant before the oldest keyframe (at most a few
    hundredths of a second for nuScenes) extends its first segment linearly.

    Args:
        history_positions: (N, P ≥ 5, 2) positions at ``dt`` spacing, the last one the ego-frame origin.
        sim_dt: the simulation step, seconds.
        dt: seconds between positions when ``times`` is ``None``.
        times: optional (N, P) timestamps of the positions, seconds (any origin); they replace ``dt``.
        vehicle: for the wheelbase; ``None`` is :data:`ZOE`.

    Returns:
        :class:`DerivedStates` with ``states`` (N, 14, 11) for NAVSIM's spacing; NaN where not derivable (a non-finite
        position or time among the last five, times not increasing, or a last position that is not the origin).

    Raises:
        ValueError: shapes (fewer than 5 positions, ``times`` not (N, P)), ``dt`` not positive.
    """
    h, t, reasons = _check_history(history_positions, 5, times, dt)
    veh = vehicle or ZOE
    keys = _keyframe_states(h, t, veh)  # (N, 4, 11) at nominally -1.5 … 0
    instants = np.arange(-HISTORY_SECONDS, 0.0, sim_dt)[:-1]  # (S,)
    knots = t[:, -4:]  # (N, 4) the keyframes' times, the present 0
    keys = keys.copy()
    keys[..., 2] = np.unwrap(keys[..., 2], axis=1)
    # the segment of each instant: the last knot at or before it (the first segment before the oldest knot)
    index = np.clip((instants[None, :] >= knots[:, 1:2]).astype(np.int64) + (instants[None, :] >= knots[:, 2:3]), 0, 2)
    rows = np.arange(h.shape[0])[:, None]
    lo, hi = knots[rows, index], knots[rows, index + 1]
    with np.errstate(invalid="ignore", divide="ignore"):
        fraction = ((instants[None, :] - lo) / (hi - lo))[..., None]
    states = keys[rows, index] + (keys[rows, index + 1] - keys[rows, index]) * fraction
    states[..., 2] = np.arctan2(np.sin(states[..., 2]), np.cos(states[..., 2]))
    states[np.array([r is not None for r in reasons], dtype=bool)] = np.nan
    return DerivedStates(states=states, reasons=reasons)


def history_comfort(
    history: ArrayLike, states: ArrayLike, *, dt: float = 0.1, vehicle: Vehicle | None = None
) -> ComfortResult:
    """History comfort ``hc``: the six bounds on the recorded past (N, H, 11) followed by simulated states (N, T, 11),
    as NAVSIM's ``_calculate_history_comfort`` (one ``dt``-spaced sequence of H + T states)."""
    past = _array(history, "history", 3, 11, "(N, H, 11)")
    return _comfort(states, dt, vehicle, past)
