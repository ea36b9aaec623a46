//! Closure estimators (issue 7): double well (D = 0.5), 40 measurements y_k ~ N(x(k), 0.2²) on
//! [1, 40]: the Gaussian closure (target ≤ 20 ms), the quartic exponential closure (target
//! ≤ 200 ms) and the exact grid mean-optimal estimator (1000 cells on [−2.5, 2.5], the default
//! steps) in the same run, so that the ratios are the machine-independent figures (target: each
//! closure ≥ 10× faster than the exact estimator). Default closure options (dispersion included).

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};
use rand::rngs::StdRng;
use rand::SeedableRng;

use onsager::action::{closure_estimate, mean_optimal, ClosureKind, ClosureOptions, ExactOptions, GridSpec};
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
    let options = ClosureOptions::new();
    let exact = ExactOptions::new(GridSpec::new_1d(-2.5, 2.5, 1000));
    let mut group = c.benchmark_group("closure_double_well_40_measurements");
    group.sample_size(10).warm_up_time(Duration::from_millis(1)).measurement_time(Duration::from_secs(1));
    group.bench_function("gaussian_closure", |b| {
        b.iter(|| black_box(closure_estimate(&problem, &ClosureKind::Gaussian, &options).expect("gaussian")))
    });
    group.bench_function("quartic_closure", |b| {
        b.iter(|| {
            black_box(
                closure_estimate(&problem, &ClosureKind::Exponential { degree: 4 }, &options)
                    .expect("quartic"),
            )
        })
    });
    group.bench_function("exact_mean_optimal", |b| {
        b.iter(|| black_box(mean_optimal(&problem, &exact).expect("mean-optimal")))
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
