//! Flight-path reconstruction (issue 37, `000_74b95e149527c64e.txt` Sec. 4.2): the JME solve on
//! a 751-sample record (22 states, 8 parameters, Hermite–Simpson with the sample period as
//! step, started from the measurements, Laplace sd of the parameters) and the output-error
//! method on the same record, in the same run, so that their ratio is the machine-independent
//! figure.
//!
//! The record is the ATTAS manoeuvre `fAttasAil1_pqrDot.asc` when it is found (the file named
//! by `ONSAGER_ATTAS`, else `../shared/data/attas/fAttasAil1_pqrDot.asc` beside the checkout)
//! with the noise levels measured from it (`FlightPathSetup::for_record`); otherwise the
//! synthetic record of seed 1 (`FlightPathSetup::new`, 30 s at 25 Hz). The bench prints which,
//! and the JME's status, iterations and `solve_seconds` once before timing; run it under
//! `/usr/bin/time -v` for the peak memory:
//!
//! ```sh
//! /usr/bin/time -v cargo bench --bench flight
//! ```

use std::hint::black_box;
use std::path::PathBuf;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};
use rand::SeedableRng;

use onsager::data::Dataset;
use onsager::model::library::{output_error, read_flight_record, FlightColumns, FlightPathSetup, OemOptions};
use onsager::path::Merit;

/// The record and its setup, and a sentence saying which.
fn record() -> (FlightPathSetup, Dataset, String) {
    let path = std::env::var_os("ONSAGER_ATTAS").map(PathBuf::from).unwrap_or_else(|| {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data/attas/fAttasAil1_pqrDot.asc")
    });
    if path.is_file() {
        let data = read_flight_record(&path, &FlightColumns::ATTAS).expect("the ATTAS record reads");
        let setup = FlightPathSetup::for_record(&data).expect("noise levels of the record");
        return (setup, data, format!("the ATTAS record {}", path.display()));
    }
    let setup = FlightPathSetup::new();
    let (_, data) =
        setup.simulate_in_envelope(&mut rand::rngs::StdRng::seed_from_u64(1), 100).expect("simulation");
    (setup, data, format!("the synthetic record of seed 1 ({} not found)", path.display()))
}

fn bench(c: &mut Criterion) {
    let (setup, data, which) = record();
    let e = setup.estimate(&data, Merit::OnsagerMachlup).expect("JME").estimate;
    eprintln!(
        "flight bench on {which}: {} samples; JME {} after {} iterations, solve_seconds {:.2}",
        data.times.len(),
        e.status,
        e.iterations,
        e.solve_seconds
    );
    let mut group = c.benchmark_group("flight_path");
    group.sample_size(10).warm_up_time(Duration::from_millis(1)).measurement_time(Duration::from_secs(1));
    group.bench_function("jme", |b| {
        b.iter(|| black_box(setup.estimate(&data, Merit::OnsagerMachlup).unwrap()))
    });
    group.bench_function("output_error", |b| {
        b.iter(|| {
            black_box(output_error(&setup.model, &setup.observation, &data, &OemOptions::default()).unwrap())
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
