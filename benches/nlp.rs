//! Benchmark of the sparse NLP solver (`onsager::nlp`) on a large banded problem: discretised
//! double-well smoothing with K = 50 000 steps (n = 100 001 variables, m = 50 000 equality
//! constraints), x_{k+1} = x_k + h (x_k − x_k³) + h w_k, minimising
//! ½ h Σ w_k² + ½ Σ_{k ∈ obs} (y_k − x_k)² / r, started with every state in the left well.
//!
//! `nlp_double_well/time_per_iteration` reports the wall-clock time of one interior-point
//! iteration (total solve time divided by the iteration count); `nlp_double_well/solve` the
//! whole solve (20 iterations, including the one symbolic analysis).
//!
//! Peak memory: 51 640 kB (about 52 MB) maximum resident set size for one solve of this
//! problem, measured with `/usr/bin/time -v` on the release test binary running only
//! `nlp::tests::large_banded_double_well` (the same problem; the test binary running a trivial
//! test peaks at 3.4 MB). The KKT matrix has 300 001 stored entries and its factor 350 000.
//!
//! Measured on the development machine (2 shared cores, load average about 4) on 2026-11-21:
//! 44 ms per iteration (criterion's estimate, 95 % interval 42–47 ms) and 1.3 s per solve
//! (20 iterations, 23 extra inertia-correction factorisations).

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, Criterion};
use onsager::nlp::{solve, NlpOptions, NlpProblem, Status};

/// The double-well smoothing problem; variables ordered (x₀..x_K, w₀..w_{K−1}).
struct DoubleWell {
    k: usize,
    h: f64,
    r: f64,
    stride: usize,
    y: Vec<f64>,
}

impl DoubleWell {
    fn new(k: usize) -> Self {
        let h = 0.05;
        let y = (0..=k)
            .map(|i| {
                let t = i as f64 * h;
                (3.0 * (0.02 * t).sin()).tanh() + 0.5 * ((i as f64) * 12.9898).sin()
            })
            .collect();
        Self { k, h, r: 0.1, stride: 20, y }
    }

    fn observed(&self, i: usize) -> bool {
        i.is_multiple_of(self.stride)
    }
}

impl NlpProblem for DoubleWell {
    fn num_variables(&self) -> usize {
        2 * self.k + 1
    }
    fn num_constraints(&self) -> usize {
        self.k
    }
    fn initial_point(&self, w: &mut [f64]) {
        let k = self.k;
        w[..=k].fill(-1.0);
        w[k + 1..].fill(0.0);
    }
    fn objective(&mut self, w: &[f64]) -> f64 {
        let (x, nz) = w.split_at(self.k + 1);
        let mut f = 0.5 * self.h * nz.iter().map(|v| v * v).sum::<f64>();
        for i in (0..=self.k).filter(|&i| self.observed(i)) {
            f += 0.5 * (self.y[i] - x[i]).powi(2) / self.r;
        }
        f
    }
    fn gradient(&mut self, w: &[f64], grad: &mut [f64]) {
        let k = self.k;
        grad.fill(0.0);
        for i in (0..=k).filter(|&i| self.observed(i)) {
            grad[i] = (w[i] - self.y[i]) / self.r;
        }
        for j in 0..k {
            grad[k + 1 + j] = self.h * w[k + 1 + j];
        }
    }
    fn constraints(&mut self, w: &[f64], c: &mut [f64]) {
        let k = self.k;
        for j in 0..k {
            let x = w[j];
            c[j] = w[j + 1] - x - self.h * (x - x * x * x) - self.h * w[k + 1 + j];
        }
    }
    fn jacobian_structure(&self) -> Vec<(usize, usize)> {
        let k = self.k;
        (0..k).flat_map(|j| [(j, j), (j, j + 1), (j, k + 1 + j)]).collect()
    }
    fn jacobian_values(&mut self, w: &[f64], values: &mut [f64]) {
        for j in 0..self.k {
            let x = w[j];
            values[3 * j] = -1.0 - self.h * (1.0 - 3.0 * x * x);
            values[3 * j + 1] = 1.0;
            values[3 * j + 2] = -self.h;
        }
    }
    fn hessian_structure(&self) -> Vec<(usize, usize)> {
        (0..2 * self.k + 1).map(|i| (i, i)).collect()
    }
    fn hessian_values(&mut self, w: &[f64], s: f64, lambda: &[f64], values: &mut [f64]) {
        let k = self.k;
        for i in 0..=k {
            let mut v = if self.observed(i) { s / self.r } else { 0.0 };
            if i < k {
                v += lambda[i] * 6.0 * self.h * w[i];
            }
            values[i] = v;
        }
        for j in 0..k {
            values[k + 1 + j] = s * self.h;
        }
    }
}

fn bench_double_well(c: &mut Criterion) {
    let mut group = c.benchmark_group("nlp_double_well");
    group.sample_size(10);
    group.warm_up_time(Duration::from_secs(1));
    group.measurement_time(Duration::from_secs(10));
    group.bench_function("time_per_iteration", |b| {
        b.iter_custom(|iters| {
            let mut total = Duration::ZERO;
            for _ in 0..iters {
                let mut problem = DoubleWell::new(50_000);
                let start = Instant::now();
                let sol = solve(&mut problem, NlpOptions::default()).expect("valid problem");
                let elapsed = start.elapsed();
                assert_eq!(sol.report.status, Status::Converged);
                total += elapsed / sol.report.iterations.max(1) as u32;
                black_box(sol);
            }
            total
        })
    });
    group.bench_function("solve", |b| {
        b.iter(|| {
            let mut problem = DoubleWell::new(50_000);
            black_box(solve(&mut problem, NlpOptions::default()).expect("valid problem"))
        })
    });
    group.finish();
}

criterion_group!(benches, bench_double_well);
criterion_main!(benches);
