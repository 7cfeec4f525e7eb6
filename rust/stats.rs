//! Scene-level (cluster) resampling: bootstrap intervals of frame-weighted means
//! and sign-flip permutation p-values of paired differences.
//!
//! Frames of one scene are correlated, so the unit of resampling is the scene
//! (a *cluster*). Each row (a model, or a pair of models) is given as its
//! clusters' sums of per-frame values and frame counts; a frame-weighted mean
//! over any set of clusters is then `Σ sums / Σ counts`.
//!
//! Random numbers come from a counter-based construction: the generator of
//! resample `b` of row `r` is seeded from `(seed, stream[r], b)` alone, so
//! results are identical for any number of threads and a row's interval does
//! not depend on which other rows are in the call.

use rayon::prelude::*;

use crate::error::{CoreError, CoreResult};

/// Resamples per parallel task.
const RESAMPLES_PER_TASK: usize = 256;
/// Domain separation: the permutation test never reuses a bootstrap stream.
const PERMUTATION_DOMAIN: u64 = 0x5349_474E_464C_4950; // "SIGNFLIP"

/// The SplitMix64 output function (Steele, Lea & Flood, OOPSLA 2014).
#[inline(always)]
fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// SplitMix64: a small, fast generator that passes BigCrush; plenty for resampling.
#[derive(Debug, Clone)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    /// The generator of draw sequence `index` of `stream` under `seed`.
    pub fn for_counter(seed: u64, stream: u64, index: u64) -> Self {
        SplitMix64(mix64(mix64(mix64(seed) ^ stream) ^ index))
    }

    #[inline(always)]
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        mix64(self.0)
    }

    /// Uniform in `0..n` (Lemire's multiply-shift; bias below `n / 2^64`).
    #[inline(always)]
    pub fn below(&mut self, n: usize) -> usize {
        ((u128::from(self.next_u64()) * n as u128) >> 64) as usize
    }

    /// Two draws uniform in `0..n` (`n` < 2^32) from one 64-bit output: multiply-shift on each
    /// 32-bit half (bias below `n / 2^32`, under 1e-6 for any number of scenes a dataset has).
    #[inline(always)]
    pub fn two_below(&mut self, n: u32) -> (usize, usize) {
        let x = self.next_u64();
        let n = u64::from(n);
        let lo = ((x & 0xFFFF_FFFF) * n) >> 32;
        let hi = ((x >> 32) * n) >> 32;
        (lo as usize, hi as usize)
    }
}

/// Clusters of several rows: row `r` owns clusters `offsets[r] .. offsets[r + 1]`;
/// cluster `k` has `counts[k]` frames and per-metric sums `sums[k * metrics ..][.. metrics]`.
#[derive(Debug, Clone, Copy)]
pub struct Clusters<'a> {
    pub sums: &'a [f64],
    pub counts: &'a [f64],
    pub offsets: &'a [usize],
    pub metrics: usize,
}

impl Clusters<'_> {
    pub fn rows(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    fn range(&self, row: usize) -> std::ops::Range<usize> {
        self.offsets[row]..self.offsets[row + 1]
    }

    /// Check shapes, offsets and values; every cluster must hold at least one frame.
    pub fn check(&self) -> CoreResult<()> {
        let k = self.counts.len();
        if self.metrics == 0 || self.sums.len() != k * self.metrics {
            return Err(CoreError::Shape(format!(
                "sums must have shape (clusters, metrics) = ({k}, ≥ 1), got {} numbers for {} metric(s)",
                self.sums.len(),
                self.metrics
            )));
        }
        if self.offsets.first() != Some(&0) || self.offsets.last() != Some(&k) {
            return Err(CoreError::Shape(format!(
                "offsets must run from 0 to the number of clusters ({k}), got {:?} … {:?}",
                self.offsets.first(),
                self.offsets.last()
            )));
        }
        if let Some(r) = self.offsets.windows(2).position(|w| w[1] < w[0]) {
            return Err(CoreError::Shape(format!(
                "offsets must not decrease (row {r}: {} then {})",
                self.offsets[r],
                self.offsets[r + 1]
            )));
        }
        if let Some(c) = self
            .counts
            .iter()
            .position(|&n| !(n.is_finite() && n > 0.0))
        {
            return Err(CoreError::Argument(format!(
                "cluster {c} has frame count {}; every cluster needs a positive count",
                self.counts[c]
            )));
        }
        if let Some(i) = self.sums.iter().position(|v| !v.is_finite()) {
            return Err(CoreError::Argument(format!(
                "cluster {} has a non-finite sum (metric {})",
                i / self.metrics,
                i % self.metrics
            )));
        }
        Ok(())
    }
}

fn check_streams(streams: &[u64], rows: usize) -> CoreResult<()> {
    if streams.len() != rows {
        return Err(CoreError::Shape(format!(
            "{rows} row(s) need {rows} stream id(s), got {}",
            streams.len()
        )));
    }
    Ok(())
}

fn check_count(n: usize, what: &str) -> CoreResult<()> {
    if n == 0 {
        return Err(CoreError::Argument(format!("{what} must be at least 1")));
    }
    Ok(())
}

/// The `q`-quantile of `values` with linear interpolation (NumPy's default "linear");
/// reorders `values` (selection, not a full sort).
fn quantile(values: &mut [f64], q: f64) -> f64 {
    let h = q * (values.len() - 1) as f64;
    let lo = h.floor() as usize;
    let (_, &mut below, above) = values.select_nth_unstable_by(lo, f64::total_cmp);
    let next = above
        .iter()
        .copied()
        .min_by(f64::total_cmp)
        .unwrap_or(below);
    below + (h - lo as f64) * (next - below)
}

/// Clusters of one row packed as `[count, sum_0, …, sum_{m−1}]` each, for cache-friendly draws.
fn packed(c: &Clusters<'_>, row: usize) -> Vec<f64> {
    let m = c.metrics;
    c.range(row)
        .flat_map(|k| {
            std::iter::once(c.counts[k]).chain(c.sums[k * m..(k + 1) * m].iter().copied())
        })
        .collect()
}

/// One resample's `Σ counts` and `Σ sums` (into `acc`, length `1 + m`) over `s` clusters drawn with replacement.
#[inline(always)]
fn draw_into(rng: &mut SplitMix64, table: &[f64], s: usize, acc: &mut [f64]) {
    match acc.len() {
        2 => draw_fixed::<2>(rng, table, s, acc),
        3 => draw_fixed::<3>(rng, table, s, acc),
        width => {
            acc.iter_mut().for_each(|a| *a = 0.0);
            for _ in 0..s {
                let k = rng.below(s);
                for (a, v) in acc.iter_mut().zip(&table[k * width..(k + 1) * width]) {
                    *a += v;
                }
            }
        }
    }
}

/// [`draw_into`] for a fixed width (1 or 2 metrics): the accumulator lives in registers.
#[inline(always)]
fn draw_fixed<const W: usize>(rng: &mut SplitMix64, table: &[f64], s: usize, acc: &mut [f64]) {
    let rows: &[[f64; W]] = {
        let (head, _) = table.as_chunks::<W>();
        head
    };
    let mut sum = [0.0_f64; W];
    let mut add = |k: usize| {
        let row = &rows[k];
        for j in 0..W {
            sum[j] += row[j];
        }
    };
    for _ in 0..s / 2 {
        let (a, b) = rng.two_below(s as u32);
        add(a);
        add(b);
    }
    if s % 2 == 1 {
        add(rng.below(s));
    }
    acc.copy_from_slice(&sum);
}

/// The bootstrap estimates of one row: `n_resamples × metrics`, resample-major.
fn row_estimates(
    c: &Clusters<'_>,
    row: usize,
    stream: u64,
    n_resamples: usize,
    seed: u64,
) -> Vec<f64> {
    let m = c.metrics;
    let s = c.range(row).len();
    let table = packed(c, row);
    let mut out = vec![0.0; n_resamples * m];
    out.par_chunks_mut(RESAMPLES_PER_TASK * m)
        .enumerate()
        .for_each(|(task, chunk)| {
            let mut acc = vec![0.0_f64; 1 + m];
            for (i, est) in chunk.chunks_exact_mut(m).enumerate() {
                let b = (task * RESAMPLES_PER_TASK + i) as u64;
                let mut rng = SplitMix64::for_counter(seed, stream, b);
                draw_into(&mut rng, &table, s, &mut acc);
                for (e, x) in est.iter_mut().zip(&acc[1..]) {
                    *e = x / acc[0];
                }
            }
        });
    out
}

/// Percentile bootstrap intervals, resampling clusters with replacement.
///
/// For each row and metric, `n_resamples` times: draw as many clusters as the
/// row has, with replacement, and take the frame-weighted mean `Σ sums / Σ counts`;
/// the interval is the `(1 − confidence) / 2` and `(1 + confidence) / 2`
/// quantiles of those means. Returns `rows × metrics × 2` (low, high); a row
/// without clusters gets NaN.
pub fn cluster_bootstrap(
    clusters: &Clusters<'_>,
    streams: &[u64],
    n_resamples: usize,
    seed: u64,
    confidence: f64,
) -> CoreResult<Vec<f64>> {
    clusters.check()?;
    check_streams(streams, clusters.rows())?;
    check_count(n_resamples, "n_resamples")?;
    if clusters.counts.len() >= u32::MAX as usize {
        return Err(CoreError::Shape(format!(
            "{} clusters: at most 2^32 − 1 are supported",
            clusters.counts.len()
        )));
    }
    if !(confidence > 0.0 && confidence < 1.0) {
        return Err(CoreError::Argument(format!(
            "confidence must lie strictly between 0 and 1, got {confidence}"
        )));
    }
    let m = clusters.metrics;
    let alpha = 1.0 - confidence;
    let rows: Vec<Vec<f64>> = (0..clusters.rows())
        .into_par_iter()
        .map(|row| {
            if clusters.range(row).is_empty() {
                return vec![f64::NAN; 2 * m];
            }
            let est = row_estimates(clusters, row, streams[row], n_resamples, seed);
            let mut out = Vec::with_capacity(2 * m);
            let mut column = vec![0.0; n_resamples];
            for j in 0..m {
                for (x, e) in column.iter_mut().zip(est.iter().skip(j).step_by(m)) {
                    *x = *e;
                }
                out.push(quantile(&mut column, alpha / 2.0));
                out.push(quantile(&mut column, 1.0 - alpha / 2.0));
            }
            out
        })
        .collect();
    Ok(rows.concat())
}

/// Two-sided p-values of "the mean paired difference is zero" by sign flips of clusters.
///
/// Each row's clusters carry the sum of per-frame differences (a − b) of one
/// scene (`metrics` must be 1). Under the null hypothesis the sign of each
/// scene's difference is exchangeable; the statistic is `|Σ sums|` (the total
/// frame count is the same for every flip). With `B = n_permutations` random
/// sign assignments, p = (1 + #{|Σ ±sums| ≥ |Σ sums|}) / (1 + B), never 0.
/// A row without clusters gets NaN.
pub fn sign_flip_pvalues(
    clusters: &Clusters<'_>,
    streams: &[u64],
    n_permutations: usize,
    seed: u64,
) -> CoreResult<Vec<f64>> {
    clusters.check()?;
    check_streams(streams, clusters.rows())?;
    check_count(n_permutations, "n_permutations")?;
    if clusters.metrics != 1 {
        return Err(CoreError::Shape(format!(
            "the sign-flip test takes one value per cluster, got {} metrics",
            clusters.metrics
        )));
    }
    let out = (0..clusters.rows())
        .into_par_iter()
        .map(|row| {
            let d = &clusters.sums[clusters.range(row)];
            if d.is_empty() {
                return f64::NAN;
            }
            let observed = d.iter().sum::<f64>().abs();
            // flips that reproduce the observed statistic up to rounding count as "as extreme"
            let tolerance = 1e-12 * d.iter().map(|v| v.abs()).sum::<f64>();
            let stream = streams[row] ^ PERMUTATION_DOMAIN;
            let extreme: usize = (0..n_permutations)
                .into_par_iter()
                .with_min_len(RESAMPLES_PER_TASK)
                .filter(|&b| {
                    let mut rng = SplitMix64::for_counter(seed, stream, b as u64);
                    let mut total = 0.0;
                    for block in d.chunks(64) {
                        let bits = rng.next_u64();
                        for (i, v) in block.iter().enumerate() {
                            // flip the sign bit where the random bit is 1: branch-free
                            total += f64::from_bits(v.to_bits() ^ (((bits >> i) & 1) << 63));
                        }
                    }
                    total.abs() >= observed - tolerance
                })
                .count();
            (1 + extreme) as f64 / (1 + n_permutations) as f64
        })
        .collect();
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn one_row<'a>(sums: &'a [f64], counts: &'a [f64], offsets: &'a [usize]) -> Clusters<'a> {
        Clusters {
            sums,
            counts,
            offsets,
            metrics: sums.len() / counts.len().max(1),
        }
    }

    #[test]
    fn generator_is_uniform_enough_and_counter_based() {
        let mut rng = SplitMix64::for_counter(7, 3, 0);
        let mut hist = [0usize; 10];
        for _ in 0..100_000 {
            hist[rng.below(10)] += 1;
        }
        assert!(
            hist.iter().all(|&h| (9_500..10_500).contains(&h)),
            "{hist:?}"
        );
        let a: Vec<u64> = (0..4)
            .map(|b| SplitMix64::for_counter(1, 2, b).next_u64())
            .collect();
        let again: Vec<u64> = (0..4)
            .map(|b| SplitMix64::for_counter(1, 2, b).next_u64())
            .collect();
        assert_eq!(a, again);
        assert_ne!(a[0], SplitMix64::for_counter(1, 3, 0).next_u64());
        assert_ne!(a[0], SplitMix64::for_counter(2, 2, 0).next_u64());
    }

    #[test]
    fn quantiles_interpolate_like_numpy() {
        let q = |values: &[f64], p: f64| quantile(&mut values.to_vec(), p);
        let x = [4.0, 2.0, 1.0, 3.0];
        assert_eq!(q(&x, 0.0), 1.0);
        assert_eq!(q(&x, 1.0), 4.0);
        assert!((q(&x, 0.5) - 2.5).abs() < 1e-15);
        assert!((q(&x, 0.025) - 1.075).abs() < 1e-12);
        assert_eq!(q(&[7.0], 0.975), 7.0);
    }

    #[test]
    fn paired_draws_are_uniform() {
        let mut rng = SplitMix64::for_counter(3, 1, 0);
        let mut hist = [0usize; 7];
        for _ in 0..70_000 {
            let (a, b) = rng.two_below(7);
            hist[a] += 1;
            hist[b] += 1;
        }
        assert!(
            hist.iter().all(|&h| (19_400..20_600).contains(&h)),
            "{hist:?}"
        );
    }

    #[test]
    fn bootstrap_interval_brackets_the_mean_and_is_deterministic() {
        // 40 scenes of 5 frames, scene means spread 0 .. 3.9
        let counts = vec![5.0; 40];
        let sums: Vec<f64> = (0..40).flat_map(|s| [5.0 * 0.1 * s as f64, 5.0]).collect();
        let c = Clusters {
            sums: &sums,
            counts: &counts,
            offsets: &[0, 40],
            metrics: 2,
        };
        let ci = cluster_bootstrap(&c, &[11], 2_000, 42, 0.95).unwrap();
        let mean = 1.95;
        assert!(ci[0] < mean && mean < ci[1], "{ci:?}");
        // standard error of the mean of 0, 0.1, …, 3.9 is about 0.18: the 95 % interval is about ±0.36
        assert!((ci[1] - ci[0] - 2.0 * 1.96 * 0.1826).abs() < 0.1, "{ci:?}");
        assert_eq!((ci[2], ci[3]), (1.0, 1.0)); // a constant metric has a zero-width interval
        assert_eq!(ci, cluster_bootstrap(&c, &[11], 2_000, 42, 0.95).unwrap());
        assert_ne!(ci, cluster_bootstrap(&c, &[11], 2_000, 43, 0.95).unwrap());
    }

    #[test]
    fn a_rows_interval_does_not_depend_on_the_other_rows() {
        let counts = [1.0, 2.0, 1.0, 3.0, 1.0];
        let sums = [1.0, 4.0, 0.5, 9.0, 2.0];
        let both = Clusters {
            sums: &sums,
            counts: &counts,
            offsets: &[0, 2, 5],
            metrics: 1,
        };
        let second = one_row(&sums[2..], &counts[2..], &[0, 3]);
        let together = cluster_bootstrap(&both, &[1, 2], 500, 9, 0.9).unwrap();
        let alone = cluster_bootstrap(&second, &[2], 500, 9, 0.9).unwrap();
        assert_eq!(&together[2..], &alone[..]);
    }

    #[test]
    fn sign_flip_p_values() {
        // all scenes favour a: the exact p-value is 2 / 2^12; Monte Carlo gives about that
        let d = vec![1.0; 12];
        let counts = vec![1.0; 12];
        let p = sign_flip_pvalues(&one_row(&d, &counts, &[0, 12]), &[0], 20_000, 1).unwrap()[0];
        assert!(p < 0.002, "{p}");
        // differences that cancel: p = 1
        let d = [1.0, -1.0, 2.0, -2.0];
        let p = sign_flip_pvalues(&one_row(&d, &[1.0; 4], &[0, 4]), &[0], 1_000, 1).unwrap()[0];
        assert!(p > 0.99, "{p}");
        // 70 scenes (two 64-bit blocks of signs) of pure noise: p spread over (0, 1]
        let noise: Vec<f64> = (0..70)
            .map(|i| ((i * 37 % 17) as f64 - 8.0) / 3.0)
            .collect();
        let p =
            sign_flip_pvalues(&one_row(&noise, &[1.0; 70], &[0, 70]), &[0], 4_000, 1).unwrap()[0];
        assert!(p > 0.05, "{p}");
    }

    #[test]
    fn bad_input_is_refused() {
        let ok = [1.0, 2.0];
        let bad_counts = one_row(&ok, &[1.0, 0.0], &[0, 2]);
        assert!(cluster_bootstrap(&bad_counts, &[0], 10, 0, 0.95).is_err());
        let bad_offsets = one_row(&ok, &[1.0, 1.0], &[0, 3]);
        assert!(cluster_bootstrap(&bad_offsets, &[0], 10, 0, 0.95).is_err());
        let good = one_row(&ok, &[1.0, 1.0], &[0, 2]);
        assert!(cluster_bootstrap(&good, &[0, 1], 10, 0, 0.95).is_err());
        assert!(cluster_bootstrap(&good, &[0], 0, 0, 0.95).is_err());
        assert!(cluster_bootstrap(&good, &[0], 10, 0, 1.0).is_err());
        let nan = one_row(&[1.0, f64::NAN], &[1.0, 1.0], &[0, 2]);
        assert!(sign_flip_pvalues(&nan, &[0], 10, 0).is_err());
        let empty = Clusters {
            sums: &[],
            counts: &[],
            offsets: &[0, 0],
            metrics: 1,
        };
        assert!(cluster_bootstrap(&empty, &[0], 10, 0, 0.95).unwrap()[0].is_nan());
        assert!(sign_flip_pvalues(&empty, &[0], 10, 0).unwrap()[0].is_nan());
    }
}
