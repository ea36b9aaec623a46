//! The baselines (issue 8) on the Duffing oscillator of `000_74b95e149527c64e.txt` Sec. 4.1.1
//! (Table 4.1), T = 20, 201 measurements, default steps (RK4 / Euler 0.01): the UKS, the EKS,
//! the PEM of (a, b, d, σ_y) from the nominal start, and the particle smoother (N = 500,
//! ancestral paths since the model has a clean state) — and the OU particle FFBSi smoother
//! (N = 1000, M = 500, T = 10).

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use rand::rngs::StdRng;
use rand::SeedableRng;

use onsager::kalman::{estimate, pem, KalmanMethod, KalmanOptions, PemOptions};
use onsager::model::library::preset;
use onsager::particle::{self, ParticleOptions};
use onsager::test_models::PresetRecord;

/// The preset `name` simulated on [0, t_end] with seed 1, x0 from its prior, its own step and
/// sampling (`test_models::PresetRecord`).
fn record(name: &str, t_end: f64) -> PresetRecord {
    let mut p = preset(name).expect("preset");
    p.t_end = t_end;
    PresetRecord::simulate(p, 1).expect("simulation")
}

fn bench(c: &mut Criterion) {
    let PresetRecord { preset: p, data: d, .. } = record("duffing", 20.0);
    let est: Vec<usize> =
        ["a", "b", "d", "sigma_y"].iter().map(|n| p.param_index(n).expect("name")).collect();
    let mut group = c.benchmark_group("baselines_duffing_t20");
    group.sample_size(10);
    let opts = KalmanOptions::default();
    group.bench_function("uks", |b| {
        b.iter(|| black_box(estimate(&p.problem(&d, &[]), KalmanMethod::Uks, &opts).expect("uks")))
    });
    group.bench_function("eks", |b| {
        b.iter(|| black_box(estimate(&p.problem(&d, &[]), KalmanMethod::Eks, &opts).expect("eks")))
    });
    group.bench_function("pem", |b| {
        b.iter(|| black_box(pem(&p.problem(&d, &est), &PemOptions::default()).expect("pem")))
    });
    group.bench_function("particle_500", |b| {
        b.iter(|| {
            let mut rng = StdRng::seed_from_u64(2);
            let options = ParticleOptions::default().with_particles(500);
            black_box(particle::estimate(&p.problem(&d, &[]), &options, &mut rng).expect("particle"))
        })
    });
    group.finish();

    let PresetRecord { preset: ou, data: d, .. } = record("ou", 10.0);
    let problem = ou.problem(&d, &[]);
    let mut group = c.benchmark_group("baselines_ou_t10");
    group.sample_size(10);
    group.bench_function("particle_ffbsi_1000_500", |b| {
        b.iter(|| {
            let mut rng = StdRng::seed_from_u64(3);
            let options = ParticleOptions::default().with_particles(1000).with_backward_paths(500);
            black_box(particle::estimate(&problem, &options, &mut rng).expect("particle"))
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
