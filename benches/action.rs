//! Exact grid estimators (issue 6): 1-D double well, 1000 cells, 40 measurements on [0, 40]:
//! the KSP smoother (target ≤ 0.2 s) and the mean-optimal estimator (target ≤ 2 s), with the
//! default time step (output step / 4 = 0.025) and output step (spacing / 10 = 0.1).

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use rand::rngs::StdRng;
use rand::SeedableRng;

use onsager::action::{ksp_smoother, mean_optimal, ExactOptions, GridSpec};
use onsager::data::Dataset;
use onsager::estimate::EstimationProblem;
use onsager::model::library::DoubleWell;
use onsager::model::observation::{Noise, StateMeasurement};
use onsager::model::prior::Prior;
use onsager::model::Param;
use onsager::simulate::{sample_measurements_at, simulate, SimulateOptions};

fn setup() -> (StateMeasurement, Dataset) {
    let obs = StateMeasurement::new(vec![0], vec!["y".into()], Noise::Gaussian { sigma: Param::Fixed(0.2) });
    let mut rng = StdRng::seed_from_u64(0);
    let path = simulate(&DoubleWell, &[0.5], &[-1.0], &[], &SimulateOptions::new(0.0, 40.0, 0.005), &mut rng)
        .expect("simulation");
    let times: Vec<f64> = (1..=40).map(|k| k as f64).collect();
    let data = sample_measurements_at(&obs, &[0.5], &path, 1, &times, &mut rng).expect("measurements");
    (obs, data)
}

fn bench(c: &mut Criterion) {
    let (obs, data) = setup();
    let priors = [Prior::flat().with_bounds(0.0, f64::INFINITY)];
    let x0 = [Prior::gaussian(-1.0, 0.2)];
    let problem = EstimationProblem {
        sde: &DoubleWell,
        observation: &obs,
        theta: &[0.5],
        theta_prior: &priors,
        estimate: &[],
        x0_prior: &x0,
        z0_prior: &[],
        data: &data,
    };
    let options = ExactOptions::new(GridSpec::new_1d(-2.5, 2.5, 1000));
    let mut group = c.benchmark_group("action_double_well_1000_cells_40_measurements");
    group.sample_size(10);
    group.bench_function("ksp_smoother", |b| {
        b.iter(|| black_box(ksp_smoother(&problem, &options).expect("ksp")))
    });
    group.bench_function("mean_optimal", |b| {
        b.iter(|| black_box(mean_optimal(&problem, &options).expect("mean-optimal")))
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
