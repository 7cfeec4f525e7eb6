//! Comfort of simulated states (docs/definitions.md#re-simulation-and-comfort): nuPlan's six
//! comfort bounds as NAVSIM computes them (`pdm_comfort_metrics.py`, `ego_is_comfortable`) and
//! NAVSIM v2's two-frame extended comfort (`ego_is_two_frame_extended_comfort`).
//!
//! Every signal is smoothed or differentiated by a Savitzky–Golay filter exactly as SciPy's
//! `savgol_filter(mode="interp")` does it: interior samples by the least-squares polynomial over a
//! window centred on them (an even window is centred half a sample late, as SciPy's convolution puts
//! it), the first and last `window // 2` samples by the polynomial fitted to the first or last
//! window. Windows are NAVSIM's, capped at the number of states: accelerations 8 (order 2), jerks 15
//! (order 2, first derivative of the rounded smoothed acceleration), yaw rate and yaw acceleration
//! 5 (NAVSIM passes its 15 to no one: `_extract_ego_yaw_rate` calls `_approximate_derivatives`
//! with its default window 5). Values are rounded to 8 decimals where NAVSIM rounds them.
//!
//! A frame holding a NaN or infinity gets NaN values and is not comfortable. Plain Rust, tested
//! without Python; `python/planning_sim.rs` binds it.

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

use super::simulate::{
    ACCELERATION_X, ACCELERATION_Y, ANGULAR_ACCELERATION, ANGULAR_VELOCITY, HEADING, STATE_SIZE,
};
use crate::error::{CoreError, CoreResult};

/// Frames per parallel task.
const FRAMES_PER_TASK: usize = 256;

/// The six bounds, in NAVSIM's order.
pub const BOUND_NAMES: [&str; 6] = [
    "lon_acceleration",
    "lat_acceleration",
    "jerk",
    "lon_jerk",
    "yaw_acceleration",
    "yaw_rate",
];
/// (lower, upper) of each bound, exclusive (nuPlan's `ego_is_comfortable` limits): m/s², m/s², m/s³,
/// m/s³, rad/s², rad/s.
pub const BOUNDS: [(f64, f64); 6] = [
    (-4.05, 2.40),
    (-4.89, 4.89),
    (-8.37, 8.37),
    (-4.13, 4.13),
    (-1.93, 1.93),
    (-0.95, 0.95),
];
/// The four extended-comfort features and their RMS-difference limits (inclusive), NAVSIM v2:
/// acceleration m/s², jerk m/s³, yaw rate rad/s, yaw acceleration rad/s².
pub const EXTENDED_NAMES: [&str; 4] = ["acceleration", "jerk", "yaw_rate", "yaw_acceleration"];
pub const EXTENDED_LIMITS: [f64; 4] = [0.7, 0.5, 0.1, 0.1];

/// A Savitzky–Golay filter over `n` samples as one linear map: each output is a dot product of
/// `window` consecutive inputs starting at `starts[i]`.
#[derive(Debug, Clone)]
pub struct SavGol {
    window: usize,
    starts: Vec<usize>,
    coeffs: Vec<f64>,
}

/// Weights over `window` samples (positions 0..window) of the `deriv`-th derivative, at position
/// `at`, of the least-squares polynomial of order `order` (positions centred and scaled for
/// conditioning; `delta` the sample spacing).
fn fit_weights(window: usize, order: usize, deriv: usize, at: f64, delta: f64) -> Vec<f64> {
    let centre = (window as f64 - 1.0) / 2.0;
    let scale = centre.max(1.0);
    let cols = order + 1;
    let v = DMatrix::from_fn(window, cols, |k, j| {
        ((k as f64 - centre) / scale).powi(j as i32)
    });
    let gram = v.transpose() * &v;
    let u = (at - centre) / scale;
    // d^deriv/du^deriv of u^j at u, then chain rule for the scaling and the spacing
    let mut d = DVector::zeros(cols);
    for j in deriv..cols {
        let falling: f64 = ((j - deriv + 1)..=j).map(|x| x as f64).product();
        d[j] = falling * u.powi((j - deriv) as i32);
    }
    let factor = 1.0 / (scale * delta).powi(deriv as i32);
    let z = gram
        .lu()
        .solve(&d)
        .expect("a Vandermonde Gram matrix of distinct positions is invertible");
    let w = v * z;
    w.iter().map(|x| x * factor).collect()
}

impl SavGol {
    /// SciPy's `savgol_filter(x, window, order, deriv, delta, mode="interp")` for `n` samples.
    pub fn new(
        n: usize,
        window: usize,
        order: usize,
        deriv: usize,
        delta: f64,
    ) -> CoreResult<Self> {
        if window > n || order >= window || deriv > order {
            return Err(CoreError::Argument(format!(
                "Savitzky–Golay filter needs order < window ≤ samples and deriv ≤ order; got order {order}, window {window}, {n} samples, deriv {deriv}"
            )));
        }
        let half = window / 2;
        let pos = (window as f64 - 1.0) / 2.0;
        let interior = fit_weights(window, order, deriv, pos, delta);
        let mut starts = Vec::with_capacity(n);
        let mut coeffs = Vec::with_capacity(n * window);
        for i in 0..n {
            if i < half {
                starts.push(0);
                coeffs.extend(fit_weights(window, order, deriv, i as f64, delta));
            } else if i >= n - half {
                let start = n - window;
                starts.push(start);
                coeffs.extend(fit_weights(window, order, deriv, (i - start) as f64, delta));
            } else {
                starts.push(i - (window - 1) / 2);
                coeffs.extend_from_slice(&interior);
            }
        }
        Ok(SavGol {
            window,
            starts,
            coeffs,
        })
    }

    pub fn apply(&self, x: &[f64], out: &mut [f64]) {
        let w = self.window;
        for (i, (start, c)) in self
            .starts
            .iter()
            .zip(self.coeffs.chunks_exact(w))
            .enumerate()
        {
            out[i] = x[*start..*start + w]
                .iter()
                .zip(c)
                .map(|(a, b)| a * b)
                .sum();
        }
    }
}

/// NumPy's `round(x, 8)`: scale, round half to even, unscale.
#[inline]
pub fn round8(x: f64) -> f64 {
    (x * 1e8).round_ties_even() / 1e8
}

/// NAVSIM's `_phase_unwrap`: successive differences brought within π by whole turns.
fn phase_unwrap(headings: &[f64], out: &mut [f64]) {
    let two_pi = 2.0 * std::f64::consts::PI;
    let mut adjust = 0.0;
    out[0] = headings[0];
    for k in 1..headings.len() {
        adjust += ((headings[k] - headings[k - 1]) / two_pi).round_ties_even();
        out[k] = headings[k] - two_pi * adjust;
    }
}

/// The filters of one horizon length (built once per call).
struct Filters {
    smooth: SavGol,
    jerk: SavGol,
    yaw_rate: SavGol,
    yaw_accel_3: SavGol,
    yaw_accel_2: SavGol,
}

impl Filters {
    fn new(n: usize, dt: f64) -> CoreResult<Self> {
        if n < 4 {
            return Err(CoreError::Shape(format!(
                "comfort needs at least 4 states per frame (NAVSIM's filters), got {n}"
            )));
        }
        // NAVSIM: dx = mean(diff(arange(n) * dt))
        let times: Vec<f64> = (0..n).map(|k| k as f64 * dt).collect();
        let delta = times.windows(2).map(|w| w[1] - w[0]).sum::<f64>() / (n - 1) as f64;
        Ok(Filters {
            smooth: SavGol::new(n, n.min(8), 2, 0, 1.0)?,
            jerk: SavGol::new(n, n.min(15), 2, 1, delta)?,
            yaw_rate: SavGol::new(n, n.min(5), 2, 1, delta)?,
            yaw_accel_3: SavGol::new(n, n.min(5), 3, 2, delta)?,
            yaw_accel_2: SavGol::new(n, n.min(5), 2, 2, delta)?,
        })
    }
}

/// Filter then round every value.
fn filtered(filter: &SavGol, x: &[f64], out: &mut [f64]) {
    filter.apply(x, out);
    out.iter_mut().for_each(|v| *v = round8(*v));
}

fn column(states: &[f64], index: usize) -> Vec<f64> {
    states.chunks_exact(STATE_SIZE).map(|s| s[index]).collect()
}

/// The six comfort signals of one frame (n states), in [`BOUND_NAMES`] order.
fn comfort_signals(states: &[f64], filters: &Filters, rear_axle_to_center: f64) -> [Vec<f64>; 6] {
    let n = states.len() / STATE_SIZE;
    let mut lon_raw = vec![0.0; n];
    let mut lat_raw = vec![0.0; n];
    let mut mag_raw = vec![0.0; n];
    let mut headings = vec![0.0; n];
    for (k, s) in states.chunks_exact(STATE_SIZE).enumerate() {
        let (w, alpha) = (s[ANGULAR_VELOCITY], s[ANGULAR_ACCELERATION]);
        // NAVSIM's get_acceleration_shifted with displacement (r, 0): a + r ω² + r α on both axes
        lon_raw[k] = s[ACCELERATION_X] + rear_axle_to_center * w * w + rear_axle_to_center * alpha;
        lat_raw[k] = s[ACCELERATION_Y];
        mag_raw[k] = s[ACCELERATION_X].hypot(s[ACCELERATION_Y]);
        headings[k] = s[HEADING];
    }
    let mut lon = vec![0.0; n];
    let mut lat = vec![0.0; n];
    let mut mag = vec![0.0; n];
    filtered(&filters.smooth, &lon_raw, &mut lon);
    filtered(&filters.smooth, &lat_raw, &mut lat);
    filtered(&filters.smooth, &mag_raw, &mut mag);
    let mut jerk = vec![0.0; n];
    let mut lon_jerk = vec![0.0; n];
    filtered(&filters.jerk, &mag, &mut jerk);
    filtered(&filters.jerk, &lon, &mut lon_jerk);
    let mut unwrapped = vec![0.0; n];
    phase_unwrap(&headings, &mut unwrapped);
    let mut yaw_accel = vec![0.0; n];
    let mut yaw_rate = vec![0.0; n];
    filtered(&filters.yaw_accel_3, &unwrapped, &mut yaw_accel);
    filtered(&filters.yaw_rate, &unwrapped, &mut yaw_rate);
    [lon, lat, jerk, lon_jerk, yaw_accel, yaw_rate]
}

/// Per frame of [`comfort`]: each bound met, and each signal's (min, max).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Comfort {
    pub within: [bool; 6],
    pub extremes: [(f64, f64); 6],
}

impl Comfort {
    pub fn is_comfortable(&self) -> bool {
        self.within.iter().all(|w| *w)
    }
}

fn check_states(states: &[f64], steps: usize, dt: f64) -> CoreResult<usize> {
    if !(dt.is_finite() && dt > 0.0) {
        return Err(CoreError::Argument(format!(
            "dt must be a positive finite number of seconds, got {dt}"
        )));
    }
    let frame = steps * STATE_SIZE;
    if frame == 0 || !states.len().is_multiple_of(frame) {
        return Err(CoreError::Shape(format!(
            "states must have shape (N, {steps}, {STATE_SIZE}), got {} values",
            states.len()
        )));
    }
    Ok(states.len() / frame)
}

/// nuPlan's comfort bounds on `N` frames of `steps` states each (`states`: N × steps × 11, flat,
/// NAVSIM's layout at `dt` spacing), each preceded by `history_steps` recorded states (`history`:
/// N × history_steps × 11, empty for none: history comfort `hc`); `rear_axle_to_center` places the
/// longitudinal acceleration at the vehicle's centre. A frame with a non-finite value: NaN extremes, no
/// bound met.
pub fn comfort(
    states: &[f64],
    steps: usize,
    history: &[f64],
    history_steps: usize,
    dt: f64,
    rear_axle_to_center: f64,
) -> CoreResult<Vec<Comfort>> {
    let n = check_states(states, steps, dt)?;
    if history.len() != n * history_steps * STATE_SIZE {
        return Err(CoreError::Shape(format!(
            "history must have shape ({n}, {history_steps}, {STATE_SIZE}), got {} values",
            history.len()
        )));
    }
    if !rear_axle_to_center.is_finite() {
        return Err(CoreError::Argument(format!(
            "rear_axle_to_center must be finite, got {rear_axle_to_center}"
        )));
    }
    let filters = Filters::new(history_steps + steps, dt)?;
    let frame = steps * STATE_SIZE;
    let past = history_steps * STATE_SIZE;
    let mut out = vec![
        Comfort {
            within: [false; 6],
            extremes: [(f64::NAN, f64::NAN); 6]
        };
        n
    ];
    out.par_chunks_mut(FRAMES_PER_TASK)
        .enumerate()
        .for_each(|(task, chunk)| {
            let mut joined = Vec::with_capacity(past + frame);
            for (j, slot) in chunk.iter_mut().enumerate() {
                let f = task * FRAMES_PER_TASK + j;
                let mut s = &states[f * frame..(f + 1) * frame];
                if past > 0 {
                    joined.clear();
                    joined.extend_from_slice(&history[f * past..(f + 1) * past]);
                    joined.extend_from_slice(s);
                    s = &joined;
                }
                if !s.iter().all(|v| v.is_finite()) {
                    continue;
                }
                let signals = comfort_signals(s, &filters, rear_axle_to_center);
                for (b, signal) in signals.iter().enumerate() {
                    let lo = signal.iter().copied().fold(f64::INFINITY, f64::min);
                    let hi = signal.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                    slot.extremes[b] = (lo, hi);
                    slot.within[b] = lo > BOUNDS[b].0 && hi < BOUNDS[b].1;
                }
            }
        });
    Ok(out)
}

/// The four extended-comfort features of one frame (NAVSIM's `extract_features`).
fn extended_features(states: &[f64], filters: &Filters) -> [Vec<f64>; 4] {
    let n = states.len() / STATE_SIZE;
    let mag_raw: Vec<f64> = states
        .chunks_exact(STATE_SIZE)
        .map(|s| s[ACCELERATION_X].hypot(s[ACCELERATION_Y]))
        .collect();
    let mut mag = vec![0.0; n];
    filtered(&filters.smooth, &mag_raw, &mut mag);
    let mut jerk = vec![0.0; n];
    filtered(&filters.jerk, &mag, &mut jerk);
    let mut unwrapped = vec![0.0; n];
    phase_unwrap(&column(states, HEADING), &mut unwrapped);
    let mut yaw_rate = vec![0.0; n];
    let mut yaw_accel = vec![0.0; n];
    filtered(&filters.yaw_rate, &unwrapped, &mut yaw_rate);
    filtered(&filters.yaw_accel_2, &unwrapped, &mut yaw_accel);
    [mag, jerk, yaw_rate, yaw_accel]
}

/// NAVSIM v2's two-frame extended comfort: this frame's states `now` against the previous
/// keyframe's `prev` (both N × steps × 11 at `dt`), `shift` = the keyframes' spacing in steps
/// (0.5 s / 0.1 s = 5). The overlap is now[..steps − shift] against prev[shift..] (the same
/// instants); per feature the RMS over the overlap of the difference. Returns N × 4 RMS values
/// ([`EXTENDED_NAMES`] order); NaN for a frame with a non-finite value.
pub fn extended_comfort(
    now: &[f64],
    prev: &[f64],
    steps: usize,
    dt: f64,
    shift: usize,
) -> CoreResult<Vec<[f64; 4]>> {
    let n = check_states(now, steps, dt)?;
    if prev.len() != now.len() {
        return Err(CoreError::Shape(format!(
            "states_prev must have the shape of states_now (N, {steps}, {STATE_SIZE}): {} values against {}",
            prev.len(),
            now.len()
        )));
    }
    if shift == 0 || shift >= steps {
        return Err(CoreError::Argument(format!(
            "the two frames' spacing must be 1 to {} steps of dt, got {shift}",
            steps.saturating_sub(1)
        )));
    }
    let overlap = steps - shift;
    let filters = Filters::new(overlap, dt)?;
    let frame = steps * STATE_SIZE;
    let mut out = vec![[f64::NAN; 4]; n];
    out.par_chunks_mut(FRAMES_PER_TASK)
        .enumerate()
        .for_each(|(task, chunk)| {
            for (j, slot) in chunk.iter_mut().enumerate() {
                let f = task * FRAMES_PER_TASK + j;
                let a = &now[f * frame..f * frame + overlap * STATE_SIZE];
                let b = &prev[f * frame + shift * STATE_SIZE..(f + 1) * frame];
                if !a.iter().chain(b).all(|v| v.is_finite()) {
                    continue;
                }
                let fa = extended_features(a, &filters);
                let fb = extended_features(b, &filters);
                for k in 0..4 {
                    let mean_square = fa[k]
                        .iter()
                        .zip(&fb[k])
                        .map(|(x, y)| (x - y) * (x - y))
                        .sum::<f64>()
                        / overlap as f64;
                    slot[k] = mean_square.sqrt();
                }
            }
        });
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::planning::simulate::{STEERING_ANGLE, VELOCITY_X};

    #[test]
    fn savgol_is_exact_on_polynomials() {
        // a quadratic is reproduced, its derivatives exactly, interior and edges, odd and even windows
        let n = 20;
        let dt = 0.1;
        let x: Vec<f64> = (0..n)
            .map(|k| {
                let t = k as f64 * dt;
                1.0 + 2.0 * t - 3.0 * t * t
            })
            .collect();
        for window in [5, 8, 15] {
            let mut out = vec![0.0; n];
            SavGol::new(n, window, 2, 1, dt)
                .unwrap()
                .apply(&x, &mut out);
            for (k, v) in out.iter().enumerate() {
                let centre = if window % 2 == 0 && k >= window / 2 && k < n - window / 2 {
                    k as f64 + 0.5
                } else {
                    k as f64
                };
                let expected = 2.0 - 6.0 * centre * dt;
                assert!(
                    (v - expected).abs() < 1e-9,
                    "window {window}, k {k}: {v} vs {expected}"
                );
            }
            SavGol::new(n, window, 2, 2, dt)
                .unwrap()
                .apply(&x, &mut out);
            assert!(out.iter().all(|v| (v + 6.0).abs() < 1e-8));
        }
    }

    fn cruising(n: usize, v: f64, steering: f64) -> Vec<f64> {
        let mut s = vec![0.0; n * STATE_SIZE];
        for k in 0..n {
            s[k * STATE_SIZE + VELOCITY_X] = v;
            s[k * STATE_SIZE + STEERING_ANGLE] = steering;
        }
        s
    }

    #[test]
    fn steady_cruise_is_comfortable_and_a_hard_brake_is_not() {
        let calm = cruising(31, 10.0, 0.0);
        let c = comfort(&calm, 31, &[], 0, 0.1, 1.444).unwrap();
        assert!(c[0].is_comfortable());
        let mut brake = calm.clone();
        for k in 10..31 {
            brake[k * STATE_SIZE + ACCELERATION_X] = -6.0;
        }
        let c = comfort(&brake, 31, &[], 0, 0.1, 1.444).unwrap();
        assert!(!c[0].within[0], "lon acceleration below -4.05 must fail");
        // the step smoothed over 0.8 s then differentiated over 1.5 s: a longitudinal jerk of about 5 m/s³
        assert!(!c[0].within[3], "lon jerk {:?}", c[0].extremes[3]);
        assert!(c[0].within[1] && c[0].within[2] && c[0].within[4] && c[0].within[5]);
    }

    #[test]
    fn yaw_rate_bound() {
        let mut s = cruising(31, 10.0, 0.0);
        for k in 0..31 {
            s[k * STATE_SIZE + HEADING] =
                super::super::simulate::principal_value(1.2 * 0.1 * k as f64);
        }
        let c = comfort(&s, 31, &[], 0, 0.1, 1.444).unwrap();
        assert!(!c[0].within[5]);
        assert!(
            (c[0].extremes[5].1 - 1.2).abs() < 1e-6,
            "unwrapped across ±π: {:?}",
            c[0].extremes[5]
        );
    }

    #[test]
    fn history_is_the_same_as_a_joined_sequence() {
        let mut past = cruising(14, 9.0, 0.0);
        for k in 0..14 {
            past[k * STATE_SIZE + ACCELERATION_X] = 0.3 * k as f64;
        }
        let now = cruising(31, 10.0, 0.01);
        let joined: Vec<f64> = past.iter().chain(&now).copied().collect();
        let a = comfort(&now, 31, &past, 14, 0.1, 1.444).unwrap();
        let b = comfort(&joined, 45, &[], 0, 0.1, 1.444).unwrap();
        assert_eq!(a, b);
        assert!(comfort(&now, 31, &past[..11], 14, 0.1, 1.444).is_err());
    }

    #[test]
    fn identical_frames_have_no_extended_discomfort() {
        let s = cruising(31, 10.0, 0.0);
        let r = extended_comfort(&s, &s, 31, 0.1, 5).unwrap();
        assert!(r[0].iter().all(|v| *v == 0.0));
        assert!(extended_comfort(&s, &s, 31, 0.1, 31).is_err());
    }

    #[test]
    fn non_finite_frames_are_not_scored() {
        let mut s = cruising(31, 10.0, 0.0);
        s[7] = f64::NAN;
        let c = comfort(&s, 31, &[], 0, 0.1, 1.444).unwrap();
        assert!(!c[0].is_comfortable() && c[0].extremes[0].0.is_nan());
        assert!(extended_comfort(&s, &s, 31, 0.1, 5).unwrap()[0][0].is_nan());
    }
}
