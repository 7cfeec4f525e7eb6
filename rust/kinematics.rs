//! Integrating (speed, curvature) actions into trajectories (docs/definitions.md#integration).

use rayon::prelude::*;

use crate::error::{CoreError, CoreResult};
use crate::fastmath;

/// Batches of at least this many frames are split across threads.
pub const PARALLEL_MIN_FRAMES: usize = 16_384;
const FRAMES_PER_TASK: usize = 4_096;

/// The integration scheme.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// The paper's equations 1–3: move along the current heading, then turn.
    Euler,
    /// Move along the heading at the middle of the step (exact for straight lines,
    /// second-order on arcs).
    Midpoint,
}

impl Method {
    pub const NAMES: &'static [&'static str] = &["euler", "midpoint"];

    pub fn from_name(name: &str) -> CoreResult<Self> {
        match name {
            "euler" => Ok(Method::Euler),
            "midpoint" => Ok(Method::Midpoint),
            _ => Err(CoreError::UnknownName {
                kind: "integration method",
                name: name.to_owned(),
                allowed: Self::NAMES,
            }),
        }
    }
}

/// Check a time step: finite and positive.
pub fn check_dt(dt: f64) -> CoreResult<()> {
    if dt.is_finite() && dt > 0.0 {
        Ok(())
    } else {
        Err(CoreError::Argument(format!(
            "dt must be a positive finite number of seconds, got {dt}"
        )))
    }
}

/// Integrate one frame: `actions` holds `T` (v, κ) pairs, `out` receives `T` (x, y)
/// positions after each step (the origin is not included).
#[inline]
pub fn integrate_frame(actions: &[f64], dt: f64, method: Method, out: &mut [f64]) {
    integrate_lanes::<1>(actions, actions.len() / 2, dt, method, out);
}

/// Frames integrated in lockstep: their heading recurrences are independent, so
/// interleaving them hides the latency of each step's `sin_cos`.
const LANES: usize = 8;

/// Integrate `N` consecutive frames of `steps` actions each, interleaved (the one
/// implementation of the scheme: a single frame is `N = 1`).
#[inline(always)]
fn integrate_lanes<const N: usize>(
    actions: &[f64],
    steps: usize,
    dt: f64,
    method: Method,
    out: &mut [f64],
) {
    let frame_len = 2 * steps;
    let (mut x, mut y, mut heading) = ([0.0_f64; N], [0.0_f64; N], [0.0_f64; N]);
    let (mut v, mut turn, mut sin, mut cos) =
        ([0.0_f64; N], [0.0_f64; N], [0.0_f64; N], [0.0_f64; N]);
    for k in 0..steps {
        let mut direction = [0.0_f64; N];
        for lane in 0..N {
            let at = lane * frame_len + 2 * k;
            v[lane] = actions[at];
            turn[lane] = actions[at + 1] * v[lane] * dt;
            direction[lane] = match method {
                Method::Euler => heading[lane],
                Method::Midpoint => heading[lane] + 0.5 * turn[lane],
            };
        }
        // branch-free so that the lanes vectorise; rare out-of-range headings are redone
        for lane in 0..N {
            (sin[lane], cos[lane]) = fastmath::sin_cos_reduced(direction[lane]);
        }
        if !direction.iter().all(|&d| fastmath::in_fast_range(d)) {
            for lane in 0..N {
                (sin[lane], cos[lane]) = fastmath::sin_cos(direction[lane]);
            }
        }
        for lane in 0..N {
            x[lane] += v[lane] * cos[lane] * dt;
            y[lane] += v[lane] * sin[lane] * dt;
            heading[lane] += turn[lane];
            let at = lane * frame_len + 2 * k;
            out[at] = x[lane];
            out[at + 1] = y[lane];
        }
    }
}

/// Integrate groups of `LANES` frames (`actions.len()` a multiple of a group).
#[inline(always)]
fn integrate_groups(actions: &[f64], steps: usize, dt: f64, method: Method, out: &mut [f64]) {
    let group = LANES * 2 * steps;
    for (frames, pos) in actions.chunks_exact(group).zip(out.chunks_exact_mut(group)) {
        integrate_lanes::<LANES>(frames, steps, dt, method, pos);
    }
}

/// The same loop compiled for AVX2, chosen at run time where the CPU has it. No
/// FMA contraction happens (Rust never fuses on its own), so results are
/// bit-identical to the baseline build.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn integrate_groups_avx2(
    actions: &[f64],
    steps: usize,
    dt: f64,
    method: Method,
    out: &mut [f64],
) {
    integrate_groups(actions, steps, dt, method, out)
}

fn integrate_groups_dispatch(
    actions: &[f64],
    steps: usize,
    dt: f64,
    method: Method,
    out: &mut [f64],
) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2, checked just above.
        return unsafe { integrate_groups_avx2(actions, steps, dt, method, out) };
    }
    integrate_groups(actions, steps, dt, method, out)
}

/// Integrate a batch laid out as `N × T × 2` (row-major) into `out` of the same length.
pub fn integrate_batch(
    actions: &[f64],
    steps: usize,
    dt: f64,
    method: Method,
    out: &mut [f64],
) -> CoreResult<()> {
    check_dt(dt)?;
    if steps == 0 || !actions.len().is_multiple_of(2 * steps) || out.len() != actions.len() {
        return Err(CoreError::Shape(format!(
            "actions of length {} cannot be split into frames of {steps} (v, κ) steps",
            actions.len()
        )));
    }
    let frame_len = 2 * steps;
    let run = |a: &[f64], o: &mut [f64]| {
        let group = LANES * frame_len;
        let rest = a.len() / group * group;
        integrate_groups_dispatch(&a[..rest], steps, dt, method, &mut o[..rest]);
        for (frame, pos) in a[rest..]
            .chunks_exact(frame_len)
            .zip(o[rest..].chunks_exact_mut(frame_len))
        {
            integrate_frame(frame, dt, method, pos);
        }
    };
    if actions.len() / frame_len >= PARALLEL_MIN_FRAMES {
        let task = FRAMES_PER_TASK * frame_len;
        actions
            .par_chunks(task)
            .zip(out.par_chunks_mut(task))
            .for_each(|(a, o)| run(a, o));
    } else {
        run(actions, out);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(actions: &[f64], method: Method) -> Vec<f64> {
        let mut out = vec![0.0; actions.len()];
        integrate_batch(actions, actions.len() / 2, 0.5, method, &mut out).unwrap();
        out
    }

    #[test]
    fn straight_line_is_exact_for_both_methods() {
        let actions: Vec<f64> = (0..6).flat_map(|_| [4.0, 0.0]).collect();
        for method in [Method::Euler, Method::Midpoint] {
            let out = run(&actions, method);
            for k in 0..6 {
                assert!((out[2 * k] - 2.0 * (k + 1) as f64).abs() < 1e-12);
                assert_eq!(out[2 * k + 1], 0.0);
            }
        }
    }

    #[test]
    fn euler_takes_the_first_step_straight() {
        let out = run(&[2.0, 0.5, 2.0, 0.5], Method::Euler);
        assert_eq!((out[0], out[1]), (1.0, 0.0));
        // heading after step 1 is 0.5 rad
        assert!((out[2] - (1.0 + 0.5_f64.cos())).abs() < 1e-12);
        assert!((out[3] - 0.5_f64.sin()).abs() < 1e-12);
    }

    #[test]
    fn midpoint_follows_a_circle_closely_and_euler_lags() {
        // 8 m/s on a 50 m radius left turn for 3 s
        let (v, r) = (8.0, 50.0);
        let actions: Vec<f64> = (0..6).flat_map(|_| [v, 1.0 / r]).collect();
        let angle = v * 3.0 / r;
        let (ex, ey) = (r * angle.sin(), r * (1.0 - angle.cos()));
        let err = |out: &[f64]| ((out[10] - ex).powi(2) + (out[11] - ey).powi(2)).sqrt();
        let mid = run(&actions, Method::Midpoint);
        let eul = run(&actions, Method::Euler);
        // midpoint keeps the step length v·dt, so it falls short by the chord factor (≈ 6 mm here)
        assert!(err(&mid) < 1e-2, "midpoint error {}", err(&mid));
        assert!(err(&eul) > 0.5, "euler error {}", err(&eul));
    }

    #[test]
    fn bad_arguments_are_errors() {
        let mut out = vec![0.0; 4];
        assert!(integrate_batch(&[1.0; 4], 2, 0.0, Method::Euler, &mut out).is_err());
        assert!(integrate_batch(&[1.0; 4], 3, 0.5, Method::Euler, &mut out).is_err());
        assert!(Method::from_name("rk4").is_err());
    }
}
