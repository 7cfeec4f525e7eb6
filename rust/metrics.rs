//! Displacement errors and their aggregation (docs/definitions.md#metrics).
//!
//! Per frame `e_k = ‖pred_k − gt_k‖`, k = 1..6 (0.5 … 3.0 s). Totals are
//! frame-weighted means over the evaluated frames.
//!
//! "ADE avg" follows each convention's own papers: `lightemma` averages all six
//! errors (equal to the mean of its three columns); `stp3` and `uniad` average
//! their three columns, as ST-P3/VAD and UniAD print "Avg.".

use rayon::prelude::*;

use crate::error::{CoreError, CoreResult};
use crate::kinematics::PARALLEL_MIN_FRAMES;

/// Frames per partial sum. Partial sums are added in a fixed order, so results do
/// not depend on the number of threads.
const FRAMES_PER_BLOCK: usize = 4_096;

/// The number of steps every convention is defined on (0.5 s … 3.0 s).
pub const HORIZON: usize = 6;

/// How ADE at 1 s, 2 s and 3 s are defined.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Convention {
    /// The paper's table: mean of the two errors inside each second.
    Lightemma,
    /// ST-P3: average over the horizon up to that second.
    Stp3,
    /// UniAD: the error at that instant.
    Uniad,
}

impl Convention {
    pub const NAMES: &'static [&'static str] = &["lightemma", "stp3", "uniad"];

    pub fn from_name(name: &str) -> CoreResult<Self> {
        match name {
            "lightemma" => Ok(Convention::Lightemma),
            "stp3" => Ok(Convention::Stp3),
            "uniad" => Ok(Convention::Uniad),
            _ => Err(CoreError::UnknownName {
                kind: "convention",
                name: name.to_owned(),
                allowed: Self::NAMES,
            }),
        }
    }

    /// The (first, last) step indices (0-based, inclusive) averaged for second `s` (1..=3).
    pub fn window(self, s: usize) -> (usize, usize) {
        let last = 2 * s - 1;
        match self {
            Convention::Lightemma => (last - 1, last),
            Convention::Stp3 => (0, last),
            Convention::Uniad => (last, last),
        }
    }
}

/// Aggregated metrics over a batch of frames.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Summary {
    pub ade_1s: f64,
    pub ade_2s: f64,
    pub ade_3s: f64,
    pub ade_avg: f64,
    pub fde: f64,
    pub miss_rate: f64,
    pub n_frames: usize,
}

#[inline(always)]
fn distance(dx: f64, dy: f64) -> f64 {
    let d = (dx * dx + dy * dy).sqrt();
    if d.is_finite() {
        d
    } else {
        // a huge finite error (1e200 m): the squares overflow, hypot does not
        dx.hypot(dy)
    }
}

/// The mean of `values`, finite whenever they are (huge values are scaled before summing).
#[inline(always)]
fn mean(values: &[f64]) -> f64 {
    let n = values.len() as f64;
    let m = values.iter().sum::<f64>() / n;
    if m.is_finite() {
        m
    } else {
        values.iter().map(|v| v / n).sum()
    }
}

/// Values per frame, in this order: ADE 1s, ADE 2s, ADE 3s, ADE avg, FDE.
pub const FRAME_VALUES: usize = 5;

/// The six errors of one frame (`2 × HORIZON` numbers each) and the largest.
#[inline(always)]
fn frame_errors(p: &[f64], g: &[f64]) -> ([f64; HORIZON], f64) {
    let mut e = [0.0_f64; HORIZON];
    let mut worst = 0.0_f64;
    for k in 0..HORIZON {
        e[k] = distance(p[2 * k] - g[2 * k], p[2 * k + 1] - g[2 * k + 1]);
        worst = worst.max(e[k]);
    }
    (e, worst)
}

/// A frame's values under `convention` from its six errors.
#[inline(always)]
fn values_of(
    e: &[f64; HORIZON],
    windows: &[(usize, usize); 3],
    convention: Convention,
) -> [f64; FRAME_VALUES] {
    let mut out = [0.0_f64; FRAME_VALUES];
    for (value, &(a, b)) in out.iter_mut().zip(windows.iter()) {
        *value = mean(&e[a..=b]);
    }
    out[3] = match convention {
        Convention::Lightemma => mean(e),
        Convention::Stp3 | Convention::Uniad => mean(&out[..3]),
    };
    out[4] = e[HORIZON - 1];
    out
}

/// The per-frame values of one frame (`2 × HORIZON` numbers each) and its largest error.
#[inline(always)]
fn frame_values(
    p: &[f64],
    g: &[f64],
    windows: &[(usize, usize); 3],
    convention: Convention,
) -> ([f64; FRAME_VALUES], f64) {
    let (e, worst) = frame_errors(p, g);
    (values_of(&e, windows, convention), worst)
}

/// Partial sums over a block of frames: ADE 1s/2s/3s, ADE avg and FDE sums, and misses.
#[derive(Default, Clone, Copy)]
struct Partial {
    sums: [f64; FRAME_VALUES],
    misses: usize,
}

/// `mask`, when given, holds one entry per frame of the block; frames marked `false` are skipped.
fn block_sums(
    pred: &[f64],
    gt: &[f64],
    mask: Option<&[bool]>,
    windows: &[(usize, usize); 3],
    convention: Convention,
    miss_threshold: f64,
) -> Partial {
    let mut acc = Partial::default();
    for (i, (p, g)) in pred
        .chunks_exact(2 * HORIZON)
        .zip(gt.chunks_exact(2 * HORIZON))
        .enumerate()
    {
        if mask.is_some_and(|m| !m[i]) {
            continue;
        }
        let (values, worst) = frame_values(p, g, windows, convention);
        for (sum, v) in acc.sums.iter_mut().zip(values) {
            *sum += v;
        }
        if worst > miss_threshold {
            acc.misses += 1;
        }
    }
    acc
}

/// Check that `values` (`N × T × 2`) holds only finite numbers, naming the first offender.
fn check_finite(values: &[f64], steps: usize, what: &'static str) -> CoreResult<()> {
    // a branch-free fold per chunk vectorises; the offender is located only on failure
    let all_finite = |chunk: &[f64]| chunk.iter().fold(true, |ok, v| ok & v.is_finite());
    let ok = if values.len() / (2 * steps) >= PARALLEL_MIN_FRAMES {
        values.par_chunks(1 << 16).all(all_finite)
    } else {
        values.chunks(1 << 12).all(all_finite)
    };
    match ok {
        true => Ok(()),
        false => {
            let idx = values.iter().position(|v| !v.is_finite()).unwrap_or(0);
            Err(CoreError::NonFinite {
                what,
                frame: idx / (2 * steps),
                step: (idx / 2) % steps,
            })
        }
    }
}

/// Check the frames of `values` (`N × T × 2`) that `mask` keeps, naming the first offender.
fn check_finite_masked(
    values: &[f64],
    steps: usize,
    mask: &[bool],
    what: &'static str,
) -> CoreResult<()> {
    let bad = |(frame, &keep): (&[f64], &bool)| keep && !frame.iter().all(|v| v.is_finite());
    let first = if mask.len() >= PARALLEL_MIN_FRAMES {
        values
            .par_chunks_exact(2 * steps)
            .zip(mask.par_iter())
            .position_first(bad)
    } else {
        values
            .chunks_exact(2 * steps)
            .zip(mask.iter())
            .position(bad)
    };
    match first {
        None => Ok(()),
        Some(frame) => {
            let values = &values[frame * 2 * steps..(frame + 1) * 2 * steps];
            let idx = values.iter().position(|v| !v.is_finite()).unwrap_or(0);
            Err(CoreError::NonFinite {
                what,
                frame,
                step: idx / 2,
            })
        }
    }
}

/// Per-step Euclidean errors, `N × T`, written into `out`.
pub fn displacement_errors(pred: &[f64], gt: &[f64], out: &mut [f64]) -> CoreResult<()> {
    if pred.len() != gt.len() || out.len() * 2 != pred.len() {
        return Err(CoreError::Shape(format!(
            "prediction ({} numbers) and ground truth ({} numbers) differ in size",
            pred.len(),
            gt.len()
        )));
    }
    for ((p, g), e) in pred
        .chunks_exact(2)
        .zip(gt.chunks_exact(2))
        .zip(out.iter_mut())
    {
        *e = distance(p[0] - g[0], p[1] - g[1]);
    }
    Ok(())
}

/// Check a batch of `N × steps × 2` predictions against ground truth of the same size:
/// six steps, matching sizes, and (the frames `mask` keeps, all when `None`) finite values. Returns N.
fn check_batch(pred: &[f64], gt: &[f64], steps: usize, mask: Option<&[bool]>) -> CoreResult<usize> {
    if steps != HORIZON {
        return Err(CoreError::Shape(format!(
            "metrics are defined on {HORIZON} steps (0.5 … 3.0 s), got T={steps}"
        )));
    }
    if pred.len() != gt.len() {
        return Err(CoreError::Shape(format!(
            "prediction ({} numbers) and ground truth ({} numbers) differ in size",
            pred.len(),
            gt.len()
        )));
    }
    let n = pred.len() / (2 * steps);
    match mask {
        None => {
            check_finite(gt, steps, "ground truth")?;
            check_finite(pred, steps, "prediction")?;
        }
        Some(m) => {
            if m.len() != n {
                return Err(CoreError::Shape(format!(
                    "mask has {} entries for {n} frames; it needs one per frame",
                    m.len()
                )));
            }
            check_finite_masked(gt, steps, m, "ground truth")?;
            check_finite_masked(pred, steps, m, "prediction")?;
        }
    }
    Ok(n)
}

/// Per-frame values under `convention`, `N × FRAME_VALUES` written into `out`:
/// ADE 1s, ADE 2s, ADE 3s, ADE avg, FDE (the numbers whose frame-weighted means
/// [`evaluate`] returns). An empty batch gives an empty result.
pub fn frame_metrics(
    pred: &[f64],
    gt: &[f64],
    steps: usize,
    convention: Convention,
    out: &mut [f64],
) -> CoreResult<()> {
    let n = check_batch(pred, gt, steps, None)?;
    if out.len() != n * FRAME_VALUES {
        return Err(CoreError::Shape(format!(
            "output holds {} numbers, {n} frames need {}",
            out.len(),
            n * FRAME_VALUES
        )));
    }
    let windows = [1, 2, 3].map(|s| convention.window(s));
    let fill = |(p, o): (&[f64], &mut [f64]), g: &[f64]| {
        o.copy_from_slice(&frame_values(p, g, &windows, convention).0);
    };
    let frame = 2 * HORIZON;
    if n >= PARALLEL_MIN_FRAMES {
        pred.par_chunks(frame)
            .zip(out.par_chunks_mut(FRAME_VALUES))
            .zip(gt.par_chunks(frame))
            .for_each(|(po, g)| fill(po, g));
    } else {
        pred.chunks(frame)
            .zip(out.chunks_mut(FRAME_VALUES))
            .zip(gt.chunks(frame))
            .for_each(|(po, g)| fill(po, g));
    }
    Ok(())
}

/// The checks `evaluate` and `evaluate_all` share: a valid miss threshold, a well-formed non-empty batch and a mask
/// keeping some frame. Returns (frames in the batch, frames the mask keeps).
fn check_evaluation(
    pred: &[f64],
    gt: &[f64],
    mask: Option<&[bool]>,
    steps: usize,
    miss_threshold: f64,
) -> CoreResult<(usize, usize)> {
    if !(miss_threshold.is_finite() && miss_threshold >= 0.0) {
        return Err(CoreError::Argument(format!(
            "miss_threshold must be a non-negative number of metres, got {miss_threshold}"
        )));
    }
    let n = check_batch(pred, gt, steps, mask)?;
    if n == 0 {
        return Err(CoreError::Shape(
            "cannot evaluate an empty batch (0 frames)".to_owned(),
        ));
    }
    let kept = mask.map_or(n, |m| m.iter().filter(|&&k| k).count());
    if kept == 0 {
        return Err(CoreError::Shape(format!(
            "the mask keeps none of the {n} frames; nothing to evaluate"
        )));
    }
    Ok((n, kept))
}

/// Aggregate `N × 6` trajectories under `convention`; a frame misses when any
/// step's error exceeds `miss_threshold` metres.
pub fn evaluate(
    pred: &[f64],
    gt: &[f64],
    steps: usize,
    convention: Convention,
    miss_threshold: f64,
) -> CoreResult<Summary> {
    evaluate_masked(pred, gt, None, steps, convention, miss_threshold)
}

/// [`evaluate`] over the frames `mask` marks `true` (one entry per frame; `None`: all).
/// Frames left out are neither checked nor counted: they may hold NaN (a failed parse).
pub fn evaluate_masked(
    pred: &[f64],
    gt: &[f64],
    mask: Option<&[bool]>,
    steps: usize,
    convention: Convention,
    miss_threshold: f64,
) -> CoreResult<Summary> {
    let (n, kept) = check_evaluation(pred, gt, mask, steps, miss_threshold)?;
    let windows = [1, 2, 3].map(|s| convention.window(s));
    let block = FRAMES_PER_BLOCK * 2 * HORIZON;
    // the mask entries of block b
    let block_mask = |b: usize, p: &[f64]| {
        mask.map(|m| &m[b * FRAMES_PER_BLOCK..b * FRAMES_PER_BLOCK + p.len() / (2 * HORIZON)])
    };
    let sums_of = |(b, (p, g)): (usize, (&[f64], &[f64]))| {
        block_sums(p, g, block_mask(b, p), &windows, convention, miss_threshold)
    };
    let partials: Vec<Partial> = if n >= PARALLEL_MIN_FRAMES {
        pred.par_chunks(block)
            .zip(gt.par_chunks(block))
            .enumerate()
            .map(sums_of)
            .collect()
    } else {
        pred.chunks(block)
            .zip(gt.chunks(block))
            .enumerate()
            .map(sums_of)
            .collect()
    };
    let mut sums = [0.0_f64; FRAME_VALUES];
    let mut misses = 0_usize;
    for partial in &partials {
        for (total, part) in sums.iter_mut().zip(partial.sums) {
            *total += part;
        }
        misses += partial.misses;
    }
    let nf = kept as f64;
    if !sums.iter().all(|v| v.is_finite()) {
        // huge finite errors overflowed the sums: a second pass sums each frame's share
        sums = [0.0; FRAME_VALUES];
        let frames = pred
            .chunks_exact(2 * HORIZON)
            .zip(gt.chunks_exact(2 * HORIZON));
        for (i, (p, g)) in frames.enumerate() {
            if mask.is_some_and(|m| !m[i]) {
                continue;
            }
            let (values, _) = frame_values(p, g, &windows, convention);
            for (sum, v) in sums.iter_mut().zip(values) {
                *sum += v / nf;
            }
        }
        return Ok(Summary {
            ade_1s: sums[0],
            ade_2s: sums[1],
            ade_3s: sums[2],
            ade_avg: sums[3],
            fde: sums[4],
            miss_rate: misses as f64 / nf,
            n_frames: kept,
        });
    }
    Ok(Summary {
        ade_1s: sums[0] / nf,
        ade_2s: sums[1] / nf,
        ade_3s: sums[2] / nf,
        ade_avg: sums[3] / nf,
        fde: sums[4] / nf,
        miss_rate: misses as f64 / nf,
        n_frames: kept,
    })
}

/// The three conventions in [`Convention::NAMES`] order, as [`evaluate_all`] returns them.
pub const ALL: [Convention; 3] = [Convention::Lightemma, Convention::Stp3, Convention::Uniad];

/// Partial sums of every convention over a block: one error vector per frame, three sets of sums.
#[derive(Default, Clone, Copy)]
struct PartialAll {
    sums: [[f64; FRAME_VALUES]; 3],
    misses: usize,
}

fn block_sums_all(
    pred: &[f64],
    gt: &[f64],
    mask: Option<&[bool]>,
    windows: &[[(usize, usize); 3]; 3],
    miss_threshold: f64,
) -> PartialAll {
    let mut acc = PartialAll::default();
    for (i, (p, g)) in pred
        .chunks_exact(2 * HORIZON)
        .zip(gt.chunks_exact(2 * HORIZON))
        .enumerate()
    {
        if mask.is_some_and(|m| !m[i]) {
            continue;
        }
        let (e, worst) = frame_errors(p, g);
        for ((sums, w), convention) in acc.sums.iter_mut().zip(windows).zip(ALL) {
            for (sum, v) in sums.iter_mut().zip(values_of(&e, w, convention)) {
                *sum += v;
            }
        }
        if worst > miss_threshold {
            acc.misses += 1;
        }
    }
    acc
}

/// [`evaluate_masked`] under all three conventions at once (in [`ALL`] order), from one
/// error vector per frame: the same numbers, bit for bit, as three separate calls.
pub fn evaluate_all(
    pred: &[f64],
    gt: &[f64],
    mask: Option<&[bool]>,
    steps: usize,
    miss_threshold: f64,
) -> CoreResult<[Summary; 3]> {
    let (n, kept) = check_evaluation(pred, gt, mask, steps, miss_threshold)?;
    let windows = ALL.map(|c| [1, 2, 3].map(|s| c.window(s)));
    let block = FRAMES_PER_BLOCK * 2 * HORIZON;
    let block_mask = |b: usize, p: &[f64]| {
        mask.map(|m| &m[b * FRAMES_PER_BLOCK..b * FRAMES_PER_BLOCK + p.len() / (2 * HORIZON)])
    };
    let sums_of = |(b, (p, g)): (usize, (&[f64], &[f64]))| {
        block_sums_all(p, g, block_mask(b, p), &windows, miss_threshold)
    };
    let partials: Vec<PartialAll> = if n >= PARALLEL_MIN_FRAMES {
        pred.par_chunks(block)
            .zip(gt.par_chunks(block))
            .enumerate()
            .map(sums_of)
            .collect()
    } else {
        pred.chunks(block)
            .zip(gt.chunks(block))
            .enumerate()
            .map(sums_of)
            .collect()
    };
    let mut sums = [[0.0_f64; FRAME_VALUES]; 3];
    let mut misses = 0_usize;
    for partial in &partials {
        for (total, part) in sums.iter_mut().zip(partial.sums) {
            for (t, v) in total.iter_mut().zip(part) {
                *t += v;
            }
        }
        misses += partial.misses;
    }
    let nf = kept as f64;
    Ok(sums.map(|s| Summary {
        ade_1s: s[0] / nf,
        ade_2s: s[1] / nf,
        ade_3s: s[2] / nf,
        ade_avg: s[3] / nf,
        fde: s[4] / nf,
        miss_rate: misses as f64 / nf,
        n_frames: kept,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn huge_finite_errors_give_finite_metrics() {
        let (mut pred, gt) = batch(&[[1.0; 6], [1.0; 6], [1.0; 6]]);
        for v in pred[..12].iter_mut() {
            *v = 1e307; // both coordinates: the squares overflow, and so would the sums
        }
        let s = evaluate(&pred, &gt, 6, Convention::Lightemma, 2.0).unwrap();
        let d = 1e307_f64.hypot(1e307);
        assert!((s.ade_avg - (d + 2.0) / 3.0).abs() <= 1e-12 * d, "{s:?}");
        assert!(s.fde.is_finite() && s.ade_1s.is_finite());
        let mut out = vec![0.0; 3 * FRAME_VALUES];
        frame_metrics(&pred, &gt, 6, Convention::Uniad, &mut out).unwrap();
        assert!(out.iter().all(|v| v.is_finite()) && (out[4] - d).abs() <= 1e-12 * d);
        let mut e = vec![0.0; 18];
        displacement_errors(&pred, &gt, &mut e).unwrap();
        assert_eq!(e[0], d);
    }

    /// Ground truth at the origin; predictions displaced along y by the given errors.
    fn batch(errors: &[[f64; 6]]) -> (Vec<f64>, Vec<f64>) {
        let pred = errors
            .iter()
            .flat_map(|e| e.iter().flat_map(|&d| [0.0, d]))
            .collect();
        (pred, vec![0.0; errors.len() * 12])
    }

    #[test]
    fn conventions_on_one_frame() {
        let (p, g) = batch(&[[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]]);
        let l = evaluate(&p, &g, 6, Convention::Lightemma, 2.0).unwrap();
        assert_eq!((l.ade_1s, l.ade_2s, l.ade_3s), (1.5, 3.5, 5.5));
        assert_eq!((l.ade_avg, l.fde, l.miss_rate), (3.5, 6.0, 1.0));
        let s = evaluate(&p, &g, 6, Convention::Stp3, 2.0).unwrap();
        assert_eq!((s.ade_1s, s.ade_2s, s.ade_3s), (1.5, 2.5, 3.5));
        let u = evaluate(&p, &g, 6, Convention::Uniad, 2.0).unwrap();
        assert_eq!((u.ade_1s, u.ade_2s, u.ade_3s), (2.0, 4.0, 6.0));
    }

    #[test]
    fn ade_avg_is_the_mean_of_each_conventions_columns() {
        let (p, g) = batch(&[
            [1.0, 2.0, 3.0, 4.0, 5.0, 6.0],
            [0.5, 0.0, 4.0, 1.0, 2.0, 9.0],
        ]);
        for convention in [Convention::Lightemma, Convention::Stp3, Convention::Uniad] {
            let m = evaluate(&p, &g, 6, convention, 2.0).unwrap();
            let columns = (m.ade_1s + m.ade_2s + m.ade_3s) / 3.0;
            assert!((m.ade_avg - columns).abs() < 1e-12, "{convention:?}");
        }
        // one frame: stp3 (1.5 + 2.5 + 3.5) / 3 = 2.5, uniad (2 + 4 + 6) / 3 = 4, lightemma 21 / 6
        let (p, g) = batch(&[[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]]);
        let avg = |c| evaluate(&p, &g, 6, c, 2.0).unwrap().ade_avg;
        assert_eq!(avg(Convention::Stp3), 2.5);
        assert_eq!(avg(Convention::Uniad), 4.0);
        assert_eq!(avg(Convention::Lightemma), 3.5);
    }

    #[test]
    fn frame_metrics_average_to_evaluate() {
        let rows = [
            [1.0, 2.0, 3.0, 4.0, 5.0, 6.0],
            [0.5, 0.0, 4.0, 1.0, 2.0, 9.0],
            [0.0; 6],
        ];
        let (p, g) = batch(&rows);
        for convention in [Convention::Lightemma, Convention::Stp3, Convention::Uniad] {
            let mut out = vec![0.0; 3 * FRAME_VALUES];
            frame_metrics(&p, &g, 6, convention, &mut out).unwrap();
            let m = evaluate(&p, &g, 6, convention, 2.0).unwrap();
            let means: Vec<f64> = (0..FRAME_VALUES)
                .map(|j| out.iter().skip(j).step_by(FRAME_VALUES).sum::<f64>() / 3.0)
                .collect();
            let want = [m.ade_1s, m.ade_2s, m.ade_3s, m.ade_avg, m.fde];
            for (got, want) in means.iter().zip(want) {
                assert!((got - want).abs() < 1e-12, "{convention:?}");
            }
        }
        let mut out = vec![0.0; 3 * FRAME_VALUES];
        frame_metrics(&p, &g, 6, Convention::Uniad, &mut out).unwrap();
        assert_eq!(&out[..5], &[2.0, 4.0, 6.0, 4.0, 6.0]);
        assert!(frame_metrics(&p, &g, 6, Convention::Uniad, &mut out[..4]).is_err());
        assert!(frame_metrics(&[], &[], 6, Convention::Uniad, &mut []).is_ok());
    }

    #[test]
    fn totals_are_frame_weighted_and_misses_counted() {
        let (p, g) = batch(&[[0.0; 6], [1.0; 6], [3.0, 0.0, 0.0, 0.0, 0.0, 0.0]]);
        let m = evaluate(&p, &g, 6, Convention::Lightemma, 2.0).unwrap();
        assert_eq!(m.n_frames, 3);
        assert!((m.ade_avg - (0.0 + 1.0 + 0.5) / 3.0).abs() < 1e-12);
        assert!((m.miss_rate - 1.0 / 3.0).abs() < 1e-12);
    }

    #[test]
    fn a_mask_leaves_frames_out_even_when_they_hold_nan() {
        let (mut p, g) = batch(&[[1.0; 6], [5.0; 6], [3.0; 6]]);
        p[12..24].fill(f64::NAN); // frame 1: a failed parse
        let mask = [true, false, true];
        let m = evaluate_masked(&p, &g, Some(&mask), 6, Convention::Lightemma, 2.0).unwrap();
        assert_eq!(m.n_frames, 2);
        assert_eq!((m.ade_avg, m.fde, m.miss_rate), (2.0, 2.0, 0.5));
        // the same as evaluating the kept frames alone
        let (kp, kg) = batch(&[[1.0; 6], [3.0; 6]]);
        assert_eq!(
            m,
            evaluate(&kp, &kg, 6, Convention::Lightemma, 2.0).unwrap()
        );
        // all kept = no mask; a NaN in a kept frame is named by its index in the batch
        let all = [true; 3];
        let err = evaluate_masked(&p, &g, Some(&all), 6, Convention::Stp3, 2.0).unwrap_err();
        assert_eq!(
            err,
            CoreError::NonFinite {
                what: "prediction",
                frame: 1,
                step: 0
            }
        );
        assert!(evaluate_masked(&p, &g, Some(&[true, false]), 6, Convention::Uniad, 2.0).is_err());
        assert!(evaluate_masked(&p, &g, Some(&[false; 3]), 6, Convention::Uniad, 2.0).is_err());
    }

    #[test]
    fn a_mask_over_many_blocks_matches_the_kept_frames_alone() {
        // more frames than one block and than the parallel threshold: blocks and threads split the mask
        let n = PARALLEL_MIN_FRAMES + 3 * FRAMES_PER_BLOCK + 7;
        let errors: Vec<[f64; 6]> = (0..n).map(|i| [(i % 13) as f64 * 0.25; 6]).collect();
        let mask: Vec<bool> = (0..n).map(|i| i % 3 != 1).collect();
        let (mut p, g) = batch(&errors);
        for (i, frame) in p.chunks_exact_mut(12).enumerate() {
            if !mask[i] {
                frame.fill(f64::NAN);
            }
        }
        let kept: Vec<[f64; 6]> = errors
            .iter()
            .zip(&mask)
            .filter(|(_, &k)| k)
            .map(|(e, _)| *e)
            .collect();
        let (kp, kg) = batch(&kept);
        let masked = evaluate_masked(&p, &g, Some(&mask), 6, Convention::Stp3, 2.0).unwrap();
        let alone = evaluate(&kp, &kg, 6, Convention::Stp3, 2.0).unwrap();
        assert_eq!(masked.n_frames, kept.len());
        assert!((masked.ade_avg - alone.ade_avg).abs() < 1e-12);
        assert!((masked.miss_rate - alone.miss_rate).abs() < 1e-12);
    }

    #[test]
    fn evaluate_all_equals_three_calls_bit_for_bit() {
        let n = PARALLEL_MIN_FRAMES + FRAMES_PER_BLOCK + 11;
        let errors: Vec<[f64; 6]> = (0..n)
            .map(|i| [0.1, 0.7, 1.3, 2.9, 0.3, 4.1].map(|x| x * ((i % 17) as f64 + 0.37)))
            .collect();
        let (mut p, g) = batch(&errors);
        for (i, v) in p.iter_mut().enumerate() {
            *v += (i % 7) as f64 * 0.013; // x offsets too: no error along one axis only
        }
        let mask: Vec<bool> = (0..n).map(|i| i % 5 != 2).collect();
        for m in [None, Some(mask.as_slice())] {
            let all = evaluate_all(&p, &g, m, 6, 2.0).unwrap();
            for (got, convention) in all.iter().zip(ALL) {
                let want = evaluate_masked(&p, &g, m, 6, convention, 2.0).unwrap();
                assert_eq!(*got, want, "{convention:?}");
            }
        }
        assert!(evaluate_all(&[], &[], None, 6, 2.0).is_err());
        assert!(evaluate_all(&p, &g, None, 6, -1.0).is_err());
    }

    #[test]
    fn non_finite_and_shapes_are_errors() {
        let (p, mut g) = batch(&[[0.0; 6], [0.0; 6]]);
        g[12 + 7] = f64::NAN;
        let err = evaluate(&p, &g, 6, Convention::Lightemma, 2.0).unwrap_err();
        assert_eq!(
            err,
            CoreError::NonFinite {
                what: "ground truth",
                frame: 1,
                step: 3
            }
        );
        assert!(evaluate(&[], &[], 6, Convention::Lightemma, 2.0).is_err());
        assert!(evaluate(&p[..8], &g[..8], 4, Convention::Lightemma, 2.0).is_err());
        assert!(Convention::from_name("nuscenes").is_err());
        let mut out = vec![0.0; 3];
        assert!(displacement_errors(&p, &g, &mut out).is_err());
    }
}
