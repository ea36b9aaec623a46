//! Benchmarks of the path-space MAP estimators (`onsager::path`), issue 4's performance targets.
//!
//! `path_van_der_pol/*`: Van der Pol JME with a Student-t likelihood, Hermite–Simpson with step
//! 0.005 on [0, 16] (3200 pieces, 25,602 unknowns; 001_8aefdf0570c96f51.txt Sec. 9), data
//! simulated with seed 1, spline guess; the whole `estimate_path` call without the Laplace sd
//! (program construction, NLP solve, merit parts). `jme_hermite_simpson` uses the default KKT
//! solver (the variable-band LDLᵀ, `onsager::nlp::BandLdlt`), `jme_hermite_simpson_faer` faer's
//! sparse LDLᵀ, `jme_hermite_simpson_kept_solver` the band solver kept across the iterations
//! (`estimate_path_with`: the KKT pattern is analysed once, as in a Monte Carlo run), in the
//! same run. Target: median ≤ 35 ms on 2 cores.
//!
//! `path_duffing_joint_36k/jme_hermite_simpson`: Duffing joint JME (000_74b95e149527c64e.txt
//! Sec. 4.1.1, θ = (a, b, d, σ_y) estimated), Hermite–Simpson with 36 pieces per measurement
//! interval (36,000 pieces, 216,006 unknowns), seed-1 data as in `examples/duffing_large.rs`.
//! Target: ≤ 0.5 s and ≤ 300 MB.
//!
//! Measured on the development machine (2 shared cores, load average 5–6 from other jobs, so
//! wall times are inflated and noisy) on 2026-11-22, with machine-independent counts
//! (`valgrind --tool=callgrind` on the examples; same-run before/after of the derivative
//! caching in docs/map.md, "One second-order pass per Lobatto point, cached"):
//! - `path_van_der_pol`: 7 iterations, 7 numeric factorisations (plus one for the initial
//!   multipliers); one solve of `examples/van_der_pol_jme.rs` is 0.881 × 10⁹ instructions in
//!   `nlp::solve` (0.892 × 10⁹ before the caching, 3.37 × 10⁹ before the band solver and the
//!   allocation-free derivatives), of which derivatives (gradient + Jacobian + Hessian)
//!   0.228 × 10⁹ (0.240 × 10⁹ before), trial objective and constraints 0.045 × 10⁹, the band
//!   factorisation 0.197 × 10⁹ (with the calls it makes; at 484887c, see docs/map.md). Criterion at
//!   a770b22: band 154 ms median, faer 192 ms, band kept across solves 109 ms (same run).
//! - `path_duffing_joint_36k`: 5 iterations, 5 numeric factorisations (plus one); native
//!   `examples/duffing_large.rs` under that load: `solve_seconds` 9.9 s against 12.3 s before
//!   the caching (same session; user CPU of the process 1.72 s against 1.83 s), peak resident
//!   memory 296 MB against 257 MB (the per-point derivative cache, 47.5 MB). On the 6,000-piece
//!   variant (`duffing_large auto 1 6`) the derivatives are 0.86 × 10⁹ instructions against
//!   1.03 × 10⁹ before, the whole example 2.11 × 10⁹ against 2.31 × 10⁹.
//!
//! Latest (main at 32385bb, otherwise idle machine, 2026-11-22): `path_van_der_pol` band
//! 91.3 ms median, faer 119.0 ms, band kept across solves 62.7 ms (same run; callgrind of three
//! kept-solver solves 1.87 × 10⁹ instructions, 1.79 × 10⁹ after the interior-point changes of
//! ab85dec and 1fb8029); Duffing 36k (`examples/duffing_large auto 1 36`): `solve_seconds`
//! 0.96–1.09 s, peak resident memory 267 MB (254 MB after 1fb8029), 5 iterations.
//!
//! Latest (main after 011bbe8: the transcription's time order instead of the RCM search, one
//! `u32` slot map for the KKT scatter; idle machine, 2026-11-25, same run): `path_van_der_pol`
//! band 43.0 ms median (45.2 ms before, same session), faer 65.1 ms (66.3), band kept across
//! solves 31.7 ms (35.0); `path_duffing_joint_36k` 559 ms. Callgrind of one fresh Van der Pol
//! solve 687.0 × 10⁶ → 630.6 × 10⁶ instructions; Duffing 36k peak resident memory 244 MB, 231 MB
//! after the `u32` index lists of the interior-point method (`solve_seconds` 0.86 × that of
//! 356a176, alternated runs).
//!
//! Latest (main after 48212a9: the transcription orders the whole KKT matrix so that no pivot
//! is structurally zero, `NlpProblem::kkt_order`; load ≈ 1.6, 2026-11-25, same run):
//! `path_van_der_pol` band 34.16 ms median (41.9 ms the run before the change), faer 63.0 ms
//! (band/faer 0.54, was 0.63), band kept across solves 27.65 ms; `path_duffing_joint_36k`
//! 506.6 ms median, whose `solve_seconds` (`examples/duffing_large auto 1 36`) is 0.482–0.488 s
//! against 0.578–0.597 s for the binary before (alternated runs), peak resident memory 220 MB.
//! Callgrind of one fresh Van der Pol solve 554.1 × 10⁶ → 451.7 × 10⁶ instructions in
//! `InteriorPoint::solve_with`. A second run with the machine about 5 % slower (faer 67.2 ms):
//! band 35.36 ms, kept 27.84 ms, Duffing 36k 514.9 ms. The fresh Van der Pol solve is at the
//! 35 ms target and the Duffing call at 0.5 s, within the machine's noise; the kept solver is
//! well under. docs/map.md ("Performance") has the details.
//!
//! Latest (main after 963f14d: no spare derivative arrays, one (θ_d, θ_d) Hessian block for all
//! pieces, `u32` NLP patterns; load ≈ 1, 2026-11-25, same run): `path_duffing_joint_36k` 483.9 ms
//! median (peak resident memory 198 MB, 54,600 page faults against 71,600); `path_van_der_pol`
//! band 34.39 ms, faer 64.91 ms (band/faer 0.53), kept 27.86 ms. The Duffing call is under 0.5 s
//! by about 3 %; the fresh Van der Pol call is unchanged, at the 35 ms line.
//!
//! Latest (main at ec6eba3: bounds and bound multipliers stored for the bounded variables only,
//! `u32` band indices, no zeroing of the derivative arrays, one Jᵀy pass per iteration fewer;
//! 2026-11-25, two runs): `path_van_der_pol` band 31.20 / 32.64 ms, faer 66.22 / 67.79 ms
//! (band/faer 0.47 / 0.48), kept 27.61 / 30.10 ms; `path_duffing_joint_36k` 448.6 / 476.5 ms (peak
//! resident memory 178 MB). Callgrind of `van_der_pol_jme 1`: 533.5 → 499.8 × 10⁶ instructions.
//! Both targets are met in both runs: Van der Pol by 7–11 %, Duffing by 5–10 %.

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};

use onsager::estimate::EstimationProblem;
use onsager::model::library::preset;
use onsager::nlp::{AutoLdlt, LinearSolver, NlpOptions};
use onsager::path::{
    estimate_path, estimate_path_with, regression_theta_guess, spline_guess, Merit, PathOptions,
    Transcription,
};
use onsager::test_models::{van_der_pol_student_t, PresetRecord};

fn van_der_pol(c: &mut Criterion) {
    let record = van_der_pol_student_t(1).unwrap();
    let (p, problem) = (&record.preset, record.problem(&[]));
    let times: Vec<f64> = (0..=3200).map(|k| k as f64 * 0.005).collect();
    let guess = spline_guess(&p.model, &p.theta, &p.observation.states, &record.data, &times).unwrap();
    let mut group = c.benchmark_group("path_van_der_pol");
    group.sample_size(10).measurement_time(Duration::from_secs(60));
    for (name, solver) in
        [("jme_hermite_simpson", LinearSolver::Auto), ("jme_hermite_simpson_faer", LinearSolver::Faer)]
    {
        group.bench_function(name, |b| {
            b.iter(|| {
                let options = PathOptions::new(Merit::OnsagerMachlup, Transcription::HermiteSimpson)
                    .with_step(0.005)
                    .with_laplace(false)
                    .with_initial_path(guess.clone())
                    .with_nlp(NlpOptions::default().with_linear_solver(solver));
                black_box(estimate_path(&problem, options).unwrap())
            })
        });
    }
    // one band solver kept across the iterations, as a Monte Carlo run can keep it: the KKT
    // pattern is analysed once (`onsager::path::estimate_path_with`)
    let mut kept = AutoLdlt::new();
    group.bench_function("jme_hermite_simpson_kept_solver", |b| {
        b.iter(|| {
            let options = PathOptions::new(Merit::OnsagerMachlup, Transcription::HermiteSimpson)
                .with_step(0.005)
                .with_laplace(false)
                .with_initial_path(guess.clone());
            black_box(estimate_path_with(&problem, options, &mut kept).unwrap())
        })
    });
    group.finish();
}

fn duffing_joint_36k(c: &mut Criterion) {
    let record = PresetRecord::simulate(preset("duffing").unwrap(), 1).unwrap();
    let (p, data) = (&record.preset, &record.data);
    let estimate: Vec<usize> = ["a", "b", "d", "sigma_y"].iter().map(|n| p.param_index(n).unwrap()).collect();
    let start =
        regression_theta_guess(&p.model, &p.observation, &p.theta, &p.theta_prior, &estimate, data).unwrap();
    let problem = EstimationProblem { theta: &start.theta, ..record.problem(&estimate) };
    let t0 = onsager::estimate::default_initial_time(data);
    let step = p.sample_every / 36.0;
    let nodes = ((data.times.last().unwrap() - t0) / step).round() as usize;
    let times: Vec<f64> = (0..=nodes).map(|k| t0 + k as f64 * step).collect();
    let guess = spline_guess(&p.model, &start.theta, &p.observation.states, data, &times).unwrap();
    let mut group = c.benchmark_group("path_duffing_joint_36k");
    group.sample_size(10).measurement_time(Duration::from_secs(60));
    group.bench_function("jme_hermite_simpson", |b| {
        b.iter(|| {
            let options = PathOptions::new(Merit::OnsagerMachlup, Transcription::HermiteSimpson)
                .with_step(step)
                .with_laplace(false)
                .with_initial_path(guess.clone());
            black_box(estimate_path(&problem, options).unwrap())
        })
    });
    group.finish();
}

criterion_group!(benches, van_der_pol, duffing_joint_36k);
criterion_main!(benches);
