//! Benchmark of the path-space MAP estimators (`onsager::path`): Van der Pol JME with a
//! Student-t likelihood, Hermite–Simpson with step 0.005 on [0, 16] (3200 pieces, 25,602
//! unknowns; 001_8aefdf0570c96f51.txt Sec. 9), data simulated with seed 1. The target is
//! a median solve ≤ 35 ms on 2 cores.
//!
//! `path_van_der_pol/jme_hermite_simpson` reports the whole `estimate_path` call without the
//! Laplace sd (program construction, NLP solve, merit parts).
//!
//! Measured on the development machine (2 shared cores) on 2026-11-21 with the CLI's
//! `solve_seconds` (seed 1 data, spline guess): 0.59 s for JME (9 iterations: 0.22 s
//! derivative evaluation, 0.18 s KKT factorisations) and 0.40 s for MEE (9 iterations).

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};
use rand::SeedableRng;

use onsager::estimate::EstimationProblem;
use onsager::model::library::preset;
use onsager::model::observation::{Noise, Param};
use onsager::path::{estimate_path, spline_guess, Merit, PathOptions, Transcription};
use onsager::simulate::{sample_measurements, simulate, SimulateOptions};

fn van_der_pol(c: &mut Criterion) {
    let p = preset("van-der-pol").unwrap();
    let mut rng = rand::rngs::StdRng::seed_from_u64(1);
    let truth =
        simulate(&p.model, &p.theta, &[0.0, 0.0], &[], &SimulateOptions::new(0.0, 16.0, 5e-4), &mut rng)
            .unwrap();
    let data = sample_measurements(&p.observation, &p.theta, &truth, 2, 0.1, &mut rng).unwrap();
    let mut observation = p.observation.clone();
    observation.noise = Noise::StudentT { nu: Param::Fixed(4.0), scale: Param::Fixed(0.5) };
    let problem = EstimationProblem {
        sde: &p.model,
        observation: &observation,
        theta: &p.theta,
        theta_prior: &p.theta_prior,
        estimate: &[],
        x0_prior: &p.x0_prior,
        z0_prior: &p.z0_prior,
        data: &data,
    };
    let times: Vec<f64> = (0..=3200).map(|k| k as f64 * 0.005).collect();
    let guess = spline_guess(&p.model, &p.theta, &observation.states, &data, &times).unwrap();
    let mut group = c.benchmark_group("path_van_der_pol");
    group.sample_size(10).measurement_time(Duration::from_secs(60));
    group.bench_function("jme_hermite_simpson", |b| {
        b.iter(|| {
            let options = PathOptions::new(Merit::OnsagerMachlup, Transcription::HermiteSimpson)
                .with_step(0.005)
                .with_laplace(false)
                .with_initial_path(guess.clone());
            black_box(estimate_path(&problem, options).unwrap())
        })
    });
    group.finish();
}

criterion_group!(benches, van_der_pol);
criterion_main!(benches);
