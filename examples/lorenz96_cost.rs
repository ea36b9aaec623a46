//! The cost of the Gaussian KSP closure (`gaussian-ksp-closure`) in the number of states, on
//! stochastic Lorenz-96 in the setting of the `lorenz96-smoothing` experiment: forcing 8,
//! G = √0.1 I (noise variance 0.1 per unit time on each state), every state measured every 0.1
//! with variance 1 on [0, 4], the initial state N(x0, I) around a point x0 of the attractor (the
//! end of a 20-unit run of the same SDE from x = F with x1 + 0.01, seed 96).
//!
//! For n = 5, 10, 20, 40 states it simulates one record (seed 1) and times the closure with its
//! default rule (`auto`: the degree-5 cubature, 2n² + 1 nodes, from 4 states) and, in the same
//! run, the UKS (2n cubature points) on the same record, then prints n, seconds, nodes, the
//! ratio, and the exponent p of seconds ∝ nᵖ fitted by least squares on log–log. Each time is the
//! shortest of three runs (one for n = 40).
//!
//! With `--mean-optimal` it also runs the mean-optimal `gaussian-closure` on n = 5 with
//! `dual.max_iterations = 10`, and reports it if it finishes within 60 s.
//!
//! Run: `cargo run --release --example lorenz96_cost [-- --mean-optimal]`.

use std::sync::mpsc;
use std::time::{Duration, Instant};

use onsager::closures::Gaussian;
use onsager::estimator::Estimator;
use onsager::kalman::GaussianKspOptions;
use onsager::model::library::{preset, Lorenz96, Model, Preset};
use onsager::model::observation::{Noise, Param, StateMeasurement};
use onsager::model::prior::Prior;
use onsager::simulate::{simulate, SimulateOptions};
use onsager::test_models::PresetRecord;
use rand::rngs::StdRng;
use rand::SeedableRng;

const SIZES: [usize; 4] = [5, 10, 20, 40];
const T_END: f64 = 4.0;

/// The `lorenz96` preset with `n` states, every state measured with variance 1 every 0.1 on
/// [0, 4], the initial state N(x0, I) around a point x0 of the attractor.
fn setting(n: usize) -> Preset {
    let mut p = preset("lorenz96").expect("preset");
    let model = Lorenz96::new(n).expect("n ≥ 4");
    p.model = Model::Lorenz96(model);
    p.observation = StateMeasurement::new(
        (0..n).collect(),
        (1..=n).map(|i| format!("y{i}")).collect(),
        Noise::Gaussian { sigma: Param::Fixed(1.0) },
    );
    p.t_end = T_END;
    let mut start = vec![p.theta[Lorenz96::FORCING]; n];
    start[0] += 0.01;
    let mut rng = StdRng::seed_from_u64(96);
    let burn_in =
        simulate(&p.model, &p.theta, &start, &[], &SimulateOptions::new(0.0, 20.0, 0.001), &mut rng)
            .expect("burn-in");
    let x0 = burn_in.values.last().expect("a state").clone();
    p.x0_prior = x0.iter().map(|&m| Prior::gaussian(m, 1.0)).collect();
    p
}

/// The shortest of `repeats` runs of `estimator` on `record`, in seconds (and the status).
fn time(estimator: &Estimator, record: &PresetRecord, repeats: usize) -> (f64, String) {
    let problem = record.preset.problem(&record.data, &[]);
    let mut best = f64::INFINITY;
    let mut status = String::new();
    for _ in 0..repeats {
        let start = Instant::now();
        let run = estimator.run(&problem).expect("estimate");
        best = best.min(start.elapsed().as_secs_f64());
        status = run.estimate.status.to_string();
    }
    (best, status)
}

/// The least-squares slope of ln y against ln x.
fn exponent(x: &[f64], y: &[f64]) -> f64 {
    let (lx, ly): (Vec<f64>, Vec<f64>) = x.iter().zip(y).map(|(a, b)| (a.ln(), b.ln())).unzip();
    let k = lx.len() as f64;
    let (mx, my) = (lx.iter().sum::<f64>() / k, ly.iter().sum::<f64>() / k);
    let sxy: f64 = lx.iter().zip(&ly).map(|(a, b)| (a - mx) * (b - my)).sum();
    let sxx: f64 = lx.iter().map(|a| (a - mx) * (a - mx)).sum();
    sxy / sxx
}

/// Runs the mean-optimal Gaussian closure on `record` in a thread; its time and status, or
/// `None` after `limit`.
fn mean_optimal_within(record: PresetRecord, limit: Duration) -> Option<(f64, String, usize)> {
    let (send, receive) = mpsc::channel();
    std::thread::spawn(move || {
        let e = Estimator::parse("gaussian-closure:dual.max_iterations=10").expect("estimator");
        let problem = record.preset.problem(&record.data, &[]);
        let start = Instant::now();
        let out = e.run(&problem).map(|r| (r.estimate.status.to_string(), r.estimate.iterations));
        let _ = send.send((start.elapsed().as_secs_f64(), out));
    });
    match receive.recv_timeout(limit) {
        Ok((seconds, Ok((status, iterations)))) => Some((seconds, status, iterations)),
        Ok((seconds, Err(e))) => Some((seconds, format!("error: {e}"), 0)),
        Err(_) => None,
    }
}

fn main() {
    let mean_optimal = std::env::args().any(|a| a == "--mean-optimal");
    let closure = Estimator::GaussianKspClosure(GaussianKspOptions::default());
    let uks = Estimator::parse("uks").expect("uks");
    println!("Lorenz-96, T = {T_END}, all states every 0.1 (variance 1), G = sqrt(0.1) I; one record per n");
    println!(
        "{:>4} {:>7} {:>12} {:>10} {:>8} {:>12}  status",
        "n", "nodes", "closure [s]", "uks [s]", "ratio", "measurements"
    );
    let (mut ns, mut closure_s, mut uks_s) = (Vec::new(), Vec::new(), Vec::new());
    let mut five = None;
    for n in SIZES {
        let record = PresetRecord::simulate(setting(n), 1).expect("record");
        let rule = GaussianKspOptions::default().quadrature(&record.preset.model, n);
        let nodes = Gaussian::try_new(n).and_then(|g| g.with_rule(rule)).expect("rule").standard_rule().len();
        let repeats = if n >= 40 { 1 } else { 3 };
        let (c, status) = time(&closure, &record, repeats);
        let (u, _) = time(&uks, &record, repeats);
        let measured = record.data.times.len() * n;
        println!("{n:>4} {nodes:>7} {c:>12.3} {u:>10.3} {:>8.1} {measured:>12}  {status}", c / u);
        ns.push(n as f64);
        closure_s.push(c);
        uks_s.push(u);
        if n == 5 {
            five = Some(record);
        }
    }
    println!(
        "fitted exponent (seconds ∝ n^p, least squares on log–log): closure p = {:.2}, uks p = {:.2}",
        exponent(&ns, &closure_s),
        exponent(&ns, &uks_s)
    );
    if mean_optimal {
        let limit = Duration::from_secs(60);
        match mean_optimal_within(five.expect("n = 5"), limit) {
            Some((s, status, it)) => {
                println!("gaussian-closure (mean-optimal), n = 5, dual.max_iterations = 10: {status} after {it} iterations, {s:.1} s")
            }
            None => {
                println!("gaussian-closure (mean-optimal), n = 5: not finished within {} s", limit.as_secs())
            }
        }
        // The closure's thread may still be running: end the process.
        std::process::exit(0);
    }
}
