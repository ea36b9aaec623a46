//! Benchmark of the sparse NLP solver (`onsager::nlp`) on a large banded problem: discretised
//! double-well smoothing with K = 50 000 steps (n = 100 001 variables, m = 50 000 equality
//! constraints), x_{k+1} = x_k + h (x_k − x_k³) + h w_k, minimising
//! ½ h Σ w_k² + ½ Σ_{k ∈ obs} (y_k − x_k)² / r, started with every state in the left well.
//!
//! `nlp_double_well/time_per_iteration` reports the wall-clock time of one interior-point
//! iteration (total solve time divided by the iteration count) with the default KKT solver;
//! `nlp_double_well/solve` and `nlp_double_well/solve_faer` the whole solve (20 iterations,
//! including the one analysis) with the default solver (here the variable-band
//! `onsager::nlp::BandLdlt`) and with faer's sparse LDLᵀ, in the same run.
//!
//! Peak memory: 51 640 kB (about 52 MB) maximum resident set size for one solve of this
//! problem with faer, measured with `/usr/bin/time -v` on the release test binary running only
//! `nlp::tests::large_banded_double_well` (the same problem; the test binary running a trivial
//! test peaks at 3.4 MB). The KKT matrix has 300 001 stored entries and its factor 350 000.

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, Criterion};
use onsager::nlp::{solve, LinearSolver, NlpOptions, NlpProblem, Status};

// The problem (shared with the unit tests of `onsager::nlp`).
include!("../src/nlp/banded_double_well.rs");

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
    for (name, solver) in [("solve", LinearSolver::Auto), ("solve_faer", LinearSolver::Faer)] {
        group.bench_function(name, |b| {
            b.iter(|| {
                let mut problem = DoubleWell::new(50_000);
                let options = NlpOptions::default().with_linear_solver(solver);
                black_box(solve(&mut problem, options).expect("valid problem"))
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench_double_well);
criterion_main!(benches);
