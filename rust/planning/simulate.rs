//! Re-simulation of a plan as NAVSIM does it (docs/definitions.md#re-simulation-and-comfort).
//!
//! A plan's poses (x, y, heading at `plan_dt` spacing after the initial pose) are resampled at `dt`
//! (linear in x, y; heading unwrapped then linear, as nuPlan's `InterpolatedTrajectory`), then
//! tracked step by step by nuPlan's LQR tracker (NAVSIM's `batch_lqr.py`) driving a kinematic
//! bicycle model about the rear axle (NAVSIM's `batch_kinematic_bicycle.py`), from the frame's
//! initial ego state. The result has `T + 1` states (the initial one first) in NAVSIM's 11-column
//! layout ([`X`] … [`ANGULAR_ACCELERATION`]).
//!
//! The tracker's reference velocity and curvature come from two regularised least-squares fits to
//! the resampled poses (NAVSIM's `batch_lqr_utils.py`, which takes pseudo-inverses of the normal
//! matrices). The velocity fit's normal matrix does not depend on the poses (each displacement's
//! heading row has unit norm), so it is Cholesky-factorised once per call; the curvature fit is solved
//! in the curvatures themselves (an invertible change of unknowns: the same minimiser), whose normal
//! equations are tridiagonal.
//!
//! A frame whose poses or initial state hold a NaN or infinity is not simulated: all of its output
//! is NaN (the caller reports it as not available). Everything here is plain Rust, tested without
//! Python; `python/planning_sim.rs` binds it.

use std::f64::consts::PI;

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

use crate::error::{CoreError, CoreResult};
use crate::fastmath;

/// Values per state (NAVSIM's `StateIndex`).
pub const STATE_SIZE: usize = 11;
pub const X: usize = 0;
pub const Y: usize = 1;
pub const HEADING: usize = 2;
pub const VELOCITY_X: usize = 3;
pub const VELOCITY_Y: usize = 4;
pub const ACCELERATION_X: usize = 5;
pub const ACCELERATION_Y: usize = 6;
pub const STEERING_ANGLE: usize = 7;
pub const STEERING_RATE: usize = 8;
pub const ANGULAR_VELOCITY: usize = 9;
pub const ANGULAR_ACCELERATION: usize = 10;

/// Frames per parallel task.
const FRAMES_PER_TASK: usize = 64;

/// The vehicle as the motion model sees it (nuPlan's `VehicleParameters` and
/// `KinematicBicycleModel` arguments).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Vehicle {
    /// Rear axle to front axle, metres.
    pub wheel_base: f64,
    /// Rear axle to the centre of the vehicle box, metres (used by the comfort scores).
    pub rear_axle_to_center: f64,
    /// Largest absolute steering angle, radians (nuPlan: π/3).
    pub max_steering_angle: f64,
    /// First-order lag of the acceleration command, seconds (nuPlan: 0.2).
    pub accel_time_constant: f64,
    /// First-order lag of the steering angle, seconds (nuPlan: 0.05).
    pub steering_angle_time_constant: f64,
}

impl Vehicle {
    /// nuScenes' ego, a Renault Zoe: wheelbase 2.588 m (Renault's published data), box centre
    /// 1.444 m ahead of the rear axle (lightemma's ego box, docs/definitions.md#safety); nuPlan's
    /// motion-model defaults for the rest.
    pub const ZOE: Vehicle = Vehicle {
        wheel_base: 2.588,
        rear_axle_to_center: 1.444,
        max_steering_angle: PI / 3.0,
        accel_time_constant: 0.2,
        steering_angle_time_constant: 0.05,
    };
    /// nuPlan's Chrysler Pacifica (`get_pacifica_parameters`), NAVSIM's default: for checks
    /// against NAVSIM's own code.
    pub const PACIFICA: Vehicle = Vehicle {
        wheel_base: 3.089,
        rear_axle_to_center: 1.461,
        max_steering_angle: PI / 3.0,
        accel_time_constant: 0.2,
        steering_angle_time_constant: 0.05,
    };

    pub fn check(&self) -> CoreResult<()> {
        let positive = |v: f64| v.is_finite() && v > 0.0;
        let non_negative = |v: f64| v.is_finite() && v >= 0.0;
        let ok = positive(self.wheel_base)
            && positive(self.max_steering_angle)
            && self.rear_axle_to_center.is_finite()
            && non_negative(self.accel_time_constant)
            && non_negative(self.steering_angle_time_constant);
        if !ok {
            return Err(CoreError::Argument(format!(
                "vehicle parameters must be finite, wheel_base and max_steering_angle > 0, time constants ≥ 0; got {self:?}"
            )));
        }
        Ok(())
    }
}

/// nuPlan's LQR tracker settings (NAVSIM's `BatchLQRTracker` defaults).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tracker {
    pub q_longitudinal: f64,
    pub r_longitudinal: f64,
    /// Weights of lateral error, heading error, steering angle.
    pub q_lateral: [f64; 3],
    pub r_lateral: f64,
    /// Steps of lookahead of both LQR problems.
    pub horizon: usize,
    pub jerk_penalty: f64,
    pub curvature_rate_penalty: f64,
    pub stopping_proportional_gain: f64,
    /// Below this speed (m/s), with a reference below it too, a P controller stops the car.
    pub stopping_velocity: f64,
}

/// Regularisation of the initial curvature in the curvature fit (nuPlan's `INITIAL_CURVATURE_PENALTY`).
const INITIAL_CURVATURE_PENALTY: f64 = 1e-10;

impl Default for Tracker {
    fn default() -> Self {
        Tracker {
            q_longitudinal: 10.0,
            r_longitudinal: 1.0,
            q_lateral: [1.0, 10.0, 0.0],
            r_lateral: 1.0,
            horizon: 10,
            jerk_penalty: 1e-4,
            curvature_rate_penalty: 1e-2,
            stopping_proportional_gain: 0.5,
            stopping_velocity: 0.2,
        }
    }
}

/// Angle in [-π, π) (nuPlan's `principal_value`).
#[inline]
pub fn principal_value(angle: f64) -> f64 {
    (angle + PI).rem_euclid(2.0 * PI) - PI
}

/// Angle in (-π, π] (NAVSIM's `normalize_angle`, `arctan2(sin, cos)`); an angle already in range is returned
/// as it is (arctan2 would return it within an ulp).
#[inline]
pub fn normalize_angle(angle: f64) -> f64 {
    if angle > -PI && angle <= PI {
        angle
    } else {
        angle.sin().atan2(angle.cos())
    }
}

/// Number of simulation steps for `plan_steps` poses at `plan_dt`, resampled at `dt`.
pub fn resampled_steps(plan_steps: usize, plan_dt: f64, dt: f64) -> CoreResult<usize> {
    let ok = |v: f64| v.is_finite() && v > 0.0;
    if !ok(plan_dt) || !ok(dt) {
        return Err(CoreError::Argument(format!(
            "plan_dt and dt must be positive finite seconds, got plan_dt {plan_dt}, dt {dt}"
        )));
    }
    let ratio = plan_steps as f64 * plan_dt / dt;
    let steps = ratio.round();
    if (ratio - steps).abs() > 1e-9 * ratio.max(1.0) || steps < 2.0 {
        return Err(CoreError::Argument(format!(
            "the plan's horizon {plan_steps} × {plan_dt} s must be a whole number (≥ 2) of dt = {dt} s steps"
        )));
    }
    Ok(steps as usize)
}

/// Resample one plan: `initial` (x, y, heading) at t = 0 then `poses` (K × 3, flat) at
/// `plan_dt`, …, `K plan_dt`; returns `steps + 1` poses at 0, `dt`, …, `steps dt` (flat).
/// x, y are linear in time; the heading is unwrapped along the plan, interpolated linearly and
/// wrapped to [-π, π).
pub fn resample_poses(
    initial: [f64; 3],
    poses: &[f64],
    plan_dt: f64,
    dt: f64,
    steps: usize,
) -> Vec<f64> {
    let k = poses.len() / 3;
    // knots: initial then the plan, headings unwrapped (numpy's unwrap: steps of more than π)
    let mut knots = Vec::with_capacity(3 * (k + 1));
    knots.extend_from_slice(&initial);
    knots.extend_from_slice(poses);
    let mut correction = 0.0;
    for i in 1..=k {
        let original_previous = if i == 1 {
            initial[2]
        } else {
            poses[3 * (i - 2) + 2]
        };
        let delta = poses[3 * (i - 1) + 2] - original_previous;
        let mut wrapped = (delta + PI).rem_euclid(2.0 * PI) - PI;
        if wrapped == -PI && delta > 0.0 {
            wrapped = PI;
        }
        if delta.abs() >= PI {
            correction += wrapped - delta;
        }
        knots[3 * i + 2] += correction;
    }
    let mut out = Vec::with_capacity(3 * (steps + 1));
    for s in 0..=steps {
        let t = (s as f64 * dt / plan_dt).min(k as f64);
        let i = (t.floor() as usize).min(k.saturating_sub(1));
        let f = t - i as f64;
        for c in 0..3 {
            let a = knots[3 * i + c];
            let b = knots[3 * (i + 1) + c];
            out.push(a + (b - a) * f);
        }
        let last = out.len() - 1;
        out[last] = principal_value(out[last]);
    }
    out
}

/// The velocity fit's normal matrix: Σ_i w_i w_iᵀ + λ RᵀR with w_i0 = dt, w_ij = dt² (1 ≤ j ≤ i),
/// R the differences of consecutive accelerations; `m` displacements. Factorised once per call.
struct VelocityFit {
    solver: nalgebra::Cholesky<f64, nalgebra::Dyn>,
    m: usize,
}

/// Σ_i c_i w_i w_iᵀ for weights c (length m), through suffix sums S_j = Σ_{i ≥ j} c_i.
fn weighted_gram(c: &[f64], dt: f64) -> DMatrix<f64> {
    let m = c.len();
    let mut suffix = vec![0.0; m + 1];
    for i in (0..m).rev() {
        suffix[i] = suffix[i + 1] + c[i];
    }
    let (dt2, dt3, dt4) = (dt * dt, dt * dt * dt, dt * dt * dt * dt);
    DMatrix::from_fn(m, m, |j, k| match (j, k) {
        (0, 0) => dt2 * suffix[0],
        (0, k) => dt3 * suffix[k],
        (j, 0) => dt3 * suffix[j],
        (j, k) => dt4 * suffix[j.max(k)],
    })
}

/// wᵀ-weighted sums Σ_i y_i w_i (length m).
fn weighted_rhs(y: &[f64], dt: f64) -> DVector<f64> {
    let m = y.len();
    let mut rhs = DVector::zeros(m);
    let mut suffix = 0.0;
    for j in (1..m).rev() {
        suffix += y[j];
        rhs[j] = dt * dt * suffix;
    }
    rhs[0] = dt * (suffix + y[0]);
    rhs
}

impl VelocityFit {
    fn new(m: usize, dt: f64, jerk_penalty: f64) -> CoreResult<Self> {
        let mut gram = weighted_gram(&vec![1.0; m], dt);
        // RᵀR: rows r = 0..m-3 hold -1 at column r+1 and +1 at column r+2
        for r in 0..m.saturating_sub(2) {
            let (a, b) = (r + 1, r + 2);
            gram[(a, a)] += jerk_penalty;
            gram[(b, b)] += jerk_penalty;
            gram[(a, b)] -= jerk_penalty;
            gram[(b, a)] -= jerk_penalty;
        }
        let solver = gram.cholesky().ok_or_else(|| {
            CoreError::Argument("the velocity fit's normal matrix is not positive definite".into())
        })?;
        Ok(VelocityFit { solver, m })
    }
}

/// Integrate a profile: initial value then cumulative sums of `derivatives × dt` (length + 1).
fn profile(initial: f64, derivatives: &[f64], dt: f64) -> Vec<f64> {
    let mut out = Vec::with_capacity(derivatives.len() + 1);
    let mut value = initial;
    out.push(value);
    for d in derivatives {
        value += d * dt;
        out.push(value);
    }
    out
}

/// Reference velocity (length m) and curvature (length m) profiles of resampled poses
/// (`m + 1` poses, flat), NAVSIM's `get_velocity_curvature_profiles_with_derivatives_from_poses`.
fn reference_profiles(
    poses: &[f64],
    dt: f64,
    fit: &VelocityFit,
    tracker: &Tracker,
) -> Option<(Vec<f64>, Vec<f64>)> {
    let m = fit.m;
    let mut along = vec![0.0; m];
    let mut turns = vec![0.0; m];
    for i in 0..m {
        let (x0, y0, h0) = (poses[3 * i], poses[3 * i + 1], poses[3 * i + 2]);
        let (x1, y1, h1) = (poses[3 * i + 3], poses[3 * i + 4], poses[3 * i + 5]);
        let (sin, cos) = fastmath::sin_cos(h0);
        along[i] = cos * (x1 - x0) + sin * (y1 - y0);
        turns[i] = normalize_angle(h1 - h0);
    }
    let x = fit.solver.solve(&weighted_rhs(&along, dt));
    let velocity = profile(x[0], &x.as_slice()[1..], dt);

    // The curvature fit in the curvatures κ_i themselves (κ'_j = (κ_{j+1} − κ_j) / dt, an invertible change
    // of unknowns, so the same minimiser): Σ (y_i − v_i dt κ_i)² + ε κ_0² + λ Σ κ'_j² has tridiagonal normal
    // equations, solved by LDLᵀ (Thomas) in O(m).
    let penalty = tracker.curvature_rate_penalty / (dt * dt);
    let mut diag: Vec<f64> = velocity.iter().map(|v| v * v * dt * dt).collect();
    diag[0] += INITIAL_CURVATURE_PENALTY;
    for j in 0..m - 1 {
        diag[j] += penalty;
        diag[j + 1] += penalty;
    }
    let mut rhs: Vec<f64> = turns
        .iter()
        .zip(&velocity)
        .map(|(y, v)| y * v * dt)
        .collect();
    let off = -penalty;
    let curvature = solve_tridiagonal(&mut diag, off, &mut rhs)?;
    Some((velocity, curvature))
}

/// Solve the symmetric positive-definite tridiagonal system (diagonal `diag`, every off-diagonal entry `off`)
/// for `rhs`, in place (both are overwritten); `None` when a pivot is not positive.
fn solve_tridiagonal(diag: &mut [f64], off: f64, rhs: &mut [f64]) -> Option<Vec<f64>> {
    let m = diag.len();
    for i in 1..m {
        if diag[i - 1].is_nan() || diag[i - 1] <= 0.0 {
            return None;
        }
        let factor = off / diag[i - 1];
        diag[i] -= factor * off;
        rhs[i] -= factor * rhs[i - 1];
    }
    if diag[m - 1].is_nan() || diag[m - 1] <= 0.0 {
        return None;
    }
    let mut x = vec![0.0; m];
    x[m - 1] = rhs[m - 1] / diag[m - 1];
    for i in (0..m - 1).rev() {
        x[i] = (rhs[i] - off * x[i + 1]) / diag[i];
    }
    Some(x)
}

/// One tracker step: (acceleration, steering rate) commands from `state` towards the reference.
#[allow(clippy::too_many_arguments)]
fn track(
    state: &[f64],
    reference: &[f64],
    index: usize,
    velocity: &[f64],
    curvature: &[f64],
    dt: f64,
    vehicle: &Vehicle,
    tracker: &Tracker,
) -> (f64, f64) {
    let h = tracker.horizon;
    let m = velocity.len();
    let (rx, ry, rh) = (
        reference[3 * index],
        reference[3 * index + 1],
        reference[3 * index + 2],
    );
    let (dx, dy) = (state[X] - rx, state[Y] - ry);
    let (sin, cos) = fastmath::sin_cos(rh);
    let lateral = -dx * sin + dy * cos;
    let heading_error = normalize_angle(state[HEADING] - rh);
    let v0 = state[VELOCITY_X];

    let reference_idx = (index + h).min(m - 1);
    let reference_velocity = velocity[reference_idx];

    if reference_velocity <= tracker.stopping_velocity && v0 <= tracker.stopping_velocity {
        return (
            -tracker.stopping_proportional_gain * (v0 - reference_velocity),
            0.0,
        );
    }

    // longitudinal: v_N = v_0 + (N dt) a
    let b = h as f64 * dt;
    let error = v0 - reference_velocity;
    let accel = -(b * tracker.q_longitudinal * error)
        / (b * tracker.q_longitudinal * b + tracker.r_longitudinal);

    // lateral: linear time-varying dynamics over the horizon, speeds from v_0 + k a dt. Each step's matrix is
    // I + v dt e₀e₁ᵀ + (v dt / L) e₁e₂ᵀ: the zero-input response (A x₀ + g) and the input response B are
    // propagated as vectors (NAVSIM multiplies the 3 × 3 matrices out; the products are the same).
    let x0 = [lateral, heading_error, state[STEERING_ANGLE]];
    let mut e = x0;
    let mut bv = [0.0_f64; 3];
    for step in 0..h {
        let v = v0 + accel * dt * step as f64;
        let kappa = if index + step < reference_idx {
            curvature[index + step]
        } else {
            curvature[reference_idx]
        };
        let (a01, a12) = (v * dt, v * dt / vehicle.wheel_base);
        e = [e[0] + a01 * e[1], e[1] + a12 * e[2] - v * kappa * dt, e[2]];
        bv = [bv[0] + a01 * bv[1], bv[1] + a12 * bv[2], bv[2] + dt];
    }
    e[1] = normalize_angle(e[1]);
    e[2] = normalize_angle(e[2]);
    let q = tracker.q_lateral;
    let bq = [bv[0] * q[0], bv[1] * q[1], bv[2] * q[2]];
    let num = bq[0] * e[0] + bq[1] * e[1] + bq[2] * e[2];
    let den = bq[0] * bv[0] + bq[1] * bv[1] + bq[2] * bv[2] + tracker.r_lateral;
    let steering_rate = -num / den;
    (accel, steering_rate)
}

/// One motion-model step (NAVSIM's `BatchKinematicBicycleModel.propagate_state`).
pub fn propagate(
    state: &[f64],
    accel_cmd: f64,
    steering_rate_cmd: f64,
    dt: f64,
    vehicle: &Vehicle,
    out: &mut [f64],
) {
    // first-order lags on the commands
    let accel = state[ACCELERATION_X];
    let steering = state[STEERING_ANGLE];
    let ideal_steering = dt * steering_rate_cmd + steering;
    let new_accel = dt / (dt + vehicle.accel_time_constant) * (accel_cmd - accel) + accel;
    let new_steering =
        dt / (dt + vehicle.steering_angle_time_constant) * (ideal_steering - steering) + steering;
    let new_steering_rate = (new_steering - steering) / dt;

    let v = state[VELOCITY_X];
    let heading = state[HEADING];
    let yaw_rate = v * steering.tan() / vehicle.wheel_base;

    let (sin, cos) = fastmath::sin_cos(heading);
    out[X] = state[X] + v * cos * dt;
    out[Y] = state[Y] + v * sin * dt;
    out[HEADING] = principal_value(heading + yaw_rate * dt);
    out[VELOCITY_X] = v + new_accel * dt;
    out[VELOCITY_Y] = 0.0;
    out[STEERING_ANGLE] = (steering + new_steering_rate * dt)
        .clamp(-vehicle.max_steering_angle, vehicle.max_steering_angle);
    out[ANGULAR_VELOCITY] = out[VELOCITY_X] * out[STEERING_ANGLE].tan() / vehicle.wheel_base;
    out[ACCELERATION_X] = new_accel;
    out[ACCELERATION_Y] = 0.0;
    out[ANGULAR_ACCELERATION] = (out[ANGULAR_VELOCITY] - state[ANGULAR_VELOCITY]) / dt;
    out[STEERING_RATE] = new_steering_rate;
}

/// Simulate one frame into `out` ((steps + 1) × 11); NaN throughout when an input is not finite
/// or the curvature fit is singular.
#[allow(clippy::too_many_arguments)]
fn simulate_frame(
    poses: &[f64],
    initial: &[f64],
    plan_dt: f64,
    dt: f64,
    steps: usize,
    fit: &VelocityFit,
    vehicle: &Vehicle,
    tracker: &Tracker,
    out: &mut [f64],
) {
    if !poses.iter().chain(initial).all(|v| v.is_finite()) {
        out.fill(f64::NAN);
        return;
    }
    let reference = resample_poses(
        [initial[X], initial[Y], initial[HEADING]],
        poses,
        plan_dt,
        dt,
        steps,
    );
    let Some((velocity, curvature)) = reference_profiles(&reference, dt, fit, tracker) else {
        out.fill(f64::NAN);
        return;
    };
    out[..STATE_SIZE].copy_from_slice(initial);
    for i in 0..steps {
        let (head, tail) = out.split_at_mut((i + 1) * STATE_SIZE);
        let state = &head[i * STATE_SIZE..];
        let (accel, rate) = track(
            state, &reference, i, &velocity, &curvature, dt, vehicle, tracker,
        );
        propagate(state, accel, rate, dt, vehicle, &mut tail[..STATE_SIZE]);
    }
    if !out.iter().all(|v| v.is_finite()) {
        out.fill(f64::NAN);
    }
}

/// Simulate `N` plans: `poses` (N × K × 3, flat: x, y, heading at `plan_dt`, …, `K plan_dt`, in the
/// frame of the initial state's pose), `initial` (N × 11, NAVSIM's layout). Returns
/// N × (T + 1) × 11 states, T = K plan_dt / dt; a frame with a non-finite input is all NaN.
pub fn simulate(
    poses: &[f64],
    initial: &[f64],
    plan_steps: usize,
    plan_dt: f64,
    dt: f64,
    vehicle: &Vehicle,
    tracker: &Tracker,
) -> CoreResult<Vec<f64>> {
    vehicle.check()?;
    check_tracker(tracker)?;
    if plan_steps == 0 {
        return Err(CoreError::Shape(
            "poses must hold at least one step (N, K ≥ 1, 3)".into(),
        ));
    }
    if !poses.len().is_multiple_of(3 * plan_steps) {
        return Err(CoreError::Shape(format!(
            "poses has {} values, not a whole number of frames of {plan_steps} × 3",
            poses.len()
        )));
    }
    let n = poses.len() / (3 * plan_steps);
    if initial.len() != n * STATE_SIZE {
        return Err(CoreError::Shape(format!(
            "initial_state must have shape ({n}, {STATE_SIZE}), got {} values",
            initial.len()
        )));
    }
    let steps = resampled_steps(plan_steps, plan_dt, dt)?;
    let fit = VelocityFit::new(steps, dt, tracker.jerk_penalty)?;
    let frame_out = (steps + 1) * STATE_SIZE;
    let mut out = vec![0.0; n * frame_out];
    out.par_chunks_mut(FRAMES_PER_TASK * frame_out)
        .enumerate()
        .for_each(|(task, chunk)| {
            for (j, frame) in chunk.chunks_mut(frame_out).enumerate() {
                let f = task * FRAMES_PER_TASK + j;
                simulate_frame(
                    &poses[f * 3 * plan_steps..(f + 1) * 3 * plan_steps],
                    &initial[f * STATE_SIZE..(f + 1) * STATE_SIZE],
                    plan_dt,
                    dt,
                    steps,
                    &fit,
                    vehicle,
                    tracker,
                    frame,
                );
            }
        });
    Ok(out)
}

fn check_tracker(t: &Tracker) -> CoreResult<()> {
    let positive = |v: f64| v.is_finite() && v > 0.0;
    let ok = t.horizon > 1
        && positive(t.r_longitudinal)
        && positive(t.r_lateral)
        && t.q_longitudinal.is_finite()
        && t.q_longitudinal >= 0.0
        && t.q_lateral.iter().all(|q| q.is_finite() && *q >= 0.0)
        && positive(t.jerk_penalty)
        && positive(t.curvature_rate_penalty)
        && positive(t.stopping_proportional_gain)
        && positive(t.stopping_velocity);
    if ok {
        Ok(())
    } else {
        Err(CoreError::Argument(format!(
            "tracker settings out of range (horizon > 1, weights ≥ 0, penalties and R > 0): {t:?}"
        )))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn straight(n_steps: usize, speed: f64, plan_dt: f64) -> Vec<f64> {
        (1..=n_steps)
            .flat_map(|k| [speed * plan_dt * k as f64, 0.0, 0.0])
            .collect()
    }

    fn initial(speed: f64) -> Vec<f64> {
        let mut s = vec![0.0; STATE_SIZE];
        s[VELOCITY_X] = speed;
        s
    }

    #[test]
    fn straight_constant_speed_is_tracked_exactly() {
        let poses = straight(6, 8.0, 0.5);
        let out = simulate(
            &poses,
            &initial(8.0),
            6,
            0.5,
            0.1,
            &Vehicle::ZOE,
            &Tracker::default(),
        )
        .unwrap();
        assert_eq!(out.len(), 31 * STATE_SIZE);
        for k in 0..=30 {
            let s = &out[k * STATE_SIZE..(k + 1) * STATE_SIZE];
            let expected_x = 8.0 * 0.1 * k as f64;
            assert!(
                (s[X] - expected_x).abs() < 1e-9,
                "step {k}: x {} vs {expected_x}",
                s[X]
            );
            assert!(s[Y].abs() < 1e-12 && s[HEADING].abs() < 1e-12);
            assert!((s[VELOCITY_X] - 8.0).abs() < 1e-9);
            assert!(s[ACCELERATION_X].abs() < 1e-9 && s[STEERING_ANGLE].abs() < 1e-12);
        }
    }

    #[test]
    fn constant_curvature_converges() {
        // a circle of radius 20 m at 6 m/s, started on it with the matching steering angle
        let (r, v, plan_dt) = (20.0_f64, 6.0_f64, 0.5_f64);
        let poses: Vec<f64> = (1..=6)
            .flat_map(|k| {
                let a = v * plan_dt * k as f64 / r;
                [r * a.sin(), r * (1.0 - a.cos()), a]
            })
            .collect();
        let mut init = initial(v);
        init[STEERING_ANGLE] = (Vehicle::ZOE.wheel_base / r).atan();
        let out = simulate(
            &poses,
            &init,
            6,
            plan_dt,
            0.1,
            &Vehicle::ZOE,
            &Tracker::default(),
        )
        .unwrap();
        let last = &out[30 * STATE_SIZE..];
        let a = v * 3.0 / r;
        let (ex, ey) = (r * a.sin(), r * (1.0 - a.cos()));
        // chords shorten the arc by < 0.5 %; the tracker ends within a few decimetres
        assert!(
            (last[X] - ex).hypot(last[Y] - ey) < 0.3,
            "end {:?} vs ({ex}, {ey})",
            &last[..3]
        );
        assert!((last[HEADING] - a).abs() < 0.05);
        let radius_now = Vehicle::ZOE.wheel_base / last[STEERING_ANGLE].tan();
        assert!((radius_now - r).abs() < 2.0, "radius {radius_now}");
    }

    #[test]
    fn steering_is_clipped() {
        let mut state = initial(5.0);
        state[STEERING_ANGLE] = 1.0;
        let mut out = vec![0.0; STATE_SIZE];
        propagate(&state, 0.0, 50.0, 0.1, &Vehicle::ZOE, &mut out);
        assert_eq!(out[STEERING_ANGLE], Vehicle::ZOE.max_steering_angle);
        propagate(&state, 0.0, -100.0, 0.1, &Vehicle::ZOE, &mut out);
        assert_eq!(out[STEERING_ANGLE], -Vehicle::ZOE.max_steering_angle);
    }

    #[test]
    fn bicycle_step_matches_its_equations() {
        let mut s = initial(10.0);
        s[HEADING] = 0.3;
        s[STEERING_ANGLE] = 0.05;
        s[ACCELERATION_X] = 1.0;
        let mut out = vec![0.0; STATE_SIZE];
        propagate(&s, 2.0, 0.1, 0.1, &Vehicle::ZOE, &mut out);
        let a = 0.1 / 0.3 * (2.0 - 1.0) + 1.0;
        assert!((out[ACCELERATION_X] - a).abs() < 1e-15);
        assert!((out[VELOCITY_X] - (10.0 + a * 0.1)).abs() < 1e-14);
        assert!((out[X] - 10.0 * 0.3_f64.cos() * 0.1).abs() < 1e-14);
        let yaw = 10.0 * 0.05_f64.tan() / 2.588;
        assert!((out[HEADING] - (0.3 + yaw * 0.1)).abs() < 1e-14);
        let steer = 0.05 + 0.1 / 0.15 * (0.1 * 0.1);
        assert!((out[STEERING_ANGLE] - steer).abs() < 1e-14);
    }

    #[test]
    fn stopped_plan_uses_the_stopping_controller() {
        let poses = straight(6, 0.0, 0.5);
        let out = simulate(
            &poses,
            &initial(0.1),
            6,
            0.5,
            0.1,
            &Vehicle::ZOE,
            &Tracker::default(),
        )
        .unwrap();
        // P controller: a = -0.5 (v - 0), lagged; speed decays, no steering
        assert!(out[STATE_SIZE + ACCELERATION_X] < 0.0);
        assert!(out.chunks(STATE_SIZE).all(|s| s[STEERING_ANGLE] == 0.0));
    }

    #[test]
    fn non_finite_frame_is_nan_and_others_are_not() {
        let mut poses = straight(6, 5.0, 0.5);
        poses.extend(straight(6, 5.0, 0.5));
        poses[3 * 6 + 4] = f64::NAN;
        let mut init = initial(5.0);
        init.extend(initial(5.0));
        let out = simulate(
            &poses,
            &init,
            6,
            0.5,
            0.1,
            &Vehicle::ZOE,
            &Tracker::default(),
        )
        .unwrap();
        let frame = 31 * STATE_SIZE;
        assert!(out[..frame].iter().all(|v| v.is_finite()));
        assert!(out[frame..].iter().all(|v| v.is_nan()));
    }

    #[test]
    fn bad_arguments_are_refused() {
        let poses = straight(6, 5.0, 0.5);
        assert!(simulate(
            &poses,
            &initial(5.0),
            6,
            0.5,
            0.07,
            &Vehicle::ZOE,
            &Tracker::default()
        )
        .is_err());
        assert!(simulate(
            &poses,
            &initial(5.0)[..5],
            6,
            0.5,
            0.1,
            &Vehicle::ZOE,
            &Tracker::default()
        )
        .is_err());
        let bad = Vehicle {
            wheel_base: 0.0,
            ..Vehicle::ZOE
        };
        assert!(simulate(
            &poses,
            &initial(5.0),
            6,
            0.5,
            0.1,
            &bad,
            &Tracker::default()
        )
        .is_err());
    }

    #[test]
    fn resampling_unwraps_headings() {
        let poses = [1.0, 0.0, 3.0, 2.0, 0.0, -3.0];
        let out = resample_poses([0.0, 0.0, 3.0], &poses, 1.0, 0.5, 4);
        // between 3.0 and -3.0 (= 3.283) the midpoint is 3.1416…, wrapped to about -π
        let mid = out[3 * 3 + 2];
        assert!((normalize_angle(mid - (3.0 + (2.0 * PI - 6.0) / 2.0))).abs() < 1e-12);
        assert!((out[3 * 3] - 1.5).abs() < 1e-12);
    }
}
