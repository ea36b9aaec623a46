//! Exact grid estimators (issue 6): 1-D double well, 1000 cells, 40 measurements on [0, 40]:
//! the KSP smoother (target ≤ 0.2 s) and the mean-optimal estimator (target ≤ 2 s), with the
//! default time step (output step / 4 = 0.025) and output step (spacing / 10 = 0.1). The record:
//! `test_models::DoubleWellRecord::new(0, 40.0)` (D = 0.5, x(0) = −1, y ~ N(x(k), 0.2²) at
//! k = 1, …, 40, seed 0; a flat prior on D ≥ 0, x0 ~ N(−1, 0.2²)).

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};

use onsager::action::{ksp_smoother, mean_optimal, ExactOptions, GridSpec};
use onsager::test_models::DoubleWellRecord;

fn bench(c: &mut Criterion) {
    let record = DoubleWellRecord::new(0, 40.0).expect("record");
    let problem = record.problem();
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
