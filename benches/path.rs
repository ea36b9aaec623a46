//! Benchmarks of the path-space MAP estimators (`onsager::path`), issue 4's performance targets.
//!
//! `path_van_der_pol/*`: Van der Pol JME with a Student-t likelihood, Hermite–Simpson with step
//! 0.005 on [0, 16] (3200 pieces, 25,602 unknowns; 001_8aefdf0570c96f51.txt Sec. 9), data
//! simulated with seed 1, spline guess; the whole `estimate_path` call without the Laplace sd
//! (program construction, NLP solve, merit parts). `jme_hermite_simpson` uses the default KKT
//! solver (the variable-band LDLᵀ, `onsager::nlp::BandLdlt`), `jme_hermite_simpson_faer` faer's
//! sparse LDLᵀ, `jme_hermite_simpson_kept_solver` the band solver kept across the iterations
//! (`estimate_path_with`: the KKT pattern is analysed once, as in a Monte Carlo run), in the
//! same run. Target: median ≤ 35 ms on 2 cores. `jme_hermite_simpson_model_file` solves the same
//! problem with the model read from `examples/models/van-der-pol.toml` (an expression model:
//! compiled tapes, symbolic derivatives) instead of the built-in one; target: at most 1.5 times
//! `jme_hermite_simpson` in the same run.
//!
//! `path_duffing_joint_36k/jme_hermite_simpson`: Duffing joint JME (000_74b95e149527c64e.txt
//! Sec. 4.1.1, θ = (a, b, d, σ_y) estimated), Hermite–Simpson with 36 pieces per measurement
//! interval (36,000 pieces, 216,006 unknowns), seed-1 data as in `examples/duffing_large.rs`.
//! Target: ≤ 0.5 s and ≤ 300 MB.
//!
//! The measured figures and how to read them: `docs/map.md`, "Measured performance".

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};

use onsager::estimate::EstimationProblem;
use onsager::model::library::preset;
use onsager::nlp::{AutoLdlt, LinearSolver, NlpOptions};
use onsager::path::{
    estimate_path, estimate_path_with, regression_theta_guess, spline_guess, Laplace, Merit, PathOptions,
    Transcription,
};
use onsager::test_models::{model_file, van_der_pol_student_t, PresetRecord};

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
                    .with_laplace(Laplace::Off)
                    .with_initial_path(guess.clone())
                    .with_nlp(NlpOptions::default().with_linear_solver(solver));
                black_box(estimate_path(&problem, options).unwrap())
            })
        });
    }
    // the same problem with the model of the model file
    let mut from_file = record.clone();
    from_file.preset.model = model_file("van-der-pol").unwrap().model;
    let file_problem = from_file.problem(&[]);
    group.bench_function("jme_hermite_simpson_model_file", |b| {
        b.iter(|| {
            let options = PathOptions::new(Merit::OnsagerMachlup, Transcription::HermiteSimpson)
                .with_step(0.005)
                .with_laplace(Laplace::Off)
                .with_initial_path(guess.clone());
            black_box(estimate_path(&file_problem, options).unwrap())
        })
    });
    // one band solver kept across the iterations, as a Monte Carlo run can keep it: the KKT
    // pattern is analysed once (`onsager::path::estimate_path_with`)
    let mut kept = AutoLdlt::new();
    group.bench_function("jme_hermite_simpson_kept_solver", |b| {
        b.iter(|| {
            let options = PathOptions::new(Merit::OnsagerMachlup, Transcription::HermiteSimpson)
                .with_step(0.005)
                .with_laplace(Laplace::Off)
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
                .with_laplace(Laplace::Off)
                .with_initial_path(guess.clone());
            black_box(estimate_path(&problem, options).unwrap())
        })
    });
    group.finish();
}

criterion_group!(benches, van_der_pol, duffing_joint_36k);
criterion_main!(benches);
