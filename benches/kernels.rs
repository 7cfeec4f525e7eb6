//! Criterion benches of the Rust kernels (no Python): `cargo bench`.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use lightemma_core::kinematics::{integrate_batch, Method};
use lightemma_core::metrics::{evaluate, Convention};
use lightemma_core::parse::{parse_batch, Limits, Mode};

/// Deterministic pseudo-random actions (xorshift), `n` frames of 6 steps.
fn actions(n: usize) -> Vec<f64> {
    let mut state = 0x9E37_79B9_7F4A_7C15_u64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..n * 6)
        .flat_map(|_| [15.0 * next(), 0.2 * next() - 0.1])
        .collect()
}

fn answers(n: usize) -> Vec<String> {
    let strict = "[(5.0, 0.01), (5.5, 0.0), (6.0, -0.02), (6.5, 0.0), (7.0, 0.0), (7.5, 0.003)]";
    let prose = "Sure! Based on the scene, here are the actions:\n```\n[(5.0, 0.01), (5.5, 0.0), (6.0, -0.02), (6.5, 0.0), (7.0, 0.0), (7.5, 0.003)]\n```";
    let labels = "v1 = 5.0, c1 = 0.01; v2 = 5.5, c2 = 0.0; v3 = 6.0, c3 = -0.02; v4 = 6.5, c4 = 0; v5 = 7, c5 = 0; v6 = 7.5, c6 = 0.003";
    (0..n)
        .map(|i| [strict, prose, labels][i % 3].to_owned())
        .collect()
}

fn kernels(c: &mut Criterion) {
    for n in [1_000usize, 100_000] {
        let a = actions(n);
        let gt = actions(n);
        let mut out = vec![0.0; a.len()];
        let mut group = c.benchmark_group("kernels");
        group.throughput(Throughput::Elements(n as u64));
        group.bench_with_input(BenchmarkId::new("integrate_euler", n), &a, |b, a| {
            b.iter(|| integrate_batch(black_box(a), 6, 0.5, Method::Euler, &mut out).unwrap())
        });
        group.bench_with_input(BenchmarkId::new("evaluate_lightemma", n), &a, |b, a| {
            b.iter(|| evaluate(black_box(a), &gt, 6, Convention::Lightemma, 2.0).unwrap())
        });
        let texts = answers(n);
        group.bench_with_input(BenchmarkId::new("parse_lenient", n), &texts, |b, t| {
            b.iter(|| parse_batch(black_box(t), 6, Mode::Lenient, &Limits::DEFAULT, None).unwrap())
        });
        group.finish();
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = kernels
}
criterion_main!(benches);
