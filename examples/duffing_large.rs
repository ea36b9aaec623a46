//! One large joint path and parameter solve (issue 4's second performance target): the Duffing
//! oscillator of `000_74b95e149527c64e.txt` Sec. 4.1.1 (Table 4.1) on [0, 100], data simulated
//! with seed 1 exactly as in `examples/duffing_joint.rs`, θ = (a, b, d, σ_y) estimated jointly
//! with the path by the Onsager–Machlup merit (JME), Hermite–Simpson with 36 pieces per
//! measurement interval (step 0.1/36, 36,000 pieces, 216,006 unknowns), from the spline path
//! guess and the regression guess of θ (000 Sec. 4.1).
//!
//! Prints solve_seconds (the NLP solve, as in the CLI report) and the time of the whole
//! `estimate_path` call (program construction included, what `benches/path.rs` times),
//! iterations, factorisation counts, the KKT solver and its matrix and factor sizes. Measure the peak memory with
//! `/usr/bin/time -v target/release/examples/duffing_large`.
//!
//! Run with `cargo run --release --example duffing_large [auto|band|faer] [SEED] [PIECES]`
//! (PIECES per measurement interval, default 36; a smaller value gives a smaller problem of the
//! same kind, e.g. for `valgrind --tool=callgrind`).

use onsager::estimate::EstimationProblem;
use onsager::model::library::preset;
use onsager::nlp::{LinearSolver, NlpOptions};
use onsager::path::{
    estimate_path, regression_theta_guess, spline_guess, Laplace, Merit, PathOptions, Transcription,
};
use onsager::test_models::PresetRecord;

/// Default pieces per measurement interval (0.1 / 36 ≈ 0.00278).
const PIECES_PER_SAMPLE: usize = 36;

fn main() -> onsager::Result<()> {
    let solver = match std::env::args().nth(1).as_deref() {
        Some("band") => LinearSolver::Band,
        Some("faer") => LinearSolver::Faer,
        _ => LinearSolver::Auto,
    };
    let seed: u64 = std::env::args().nth(2).and_then(|s| s.parse().ok()).unwrap_or(1);
    let pieces: usize = std::env::args().nth(3).and_then(|s| s.parse().ok()).unwrap_or(PIECES_PER_SAMPLE);
    let record = PresetRecord::simulate(preset("duffing")?, seed)?;
    let (p, data) = (&record.preset, &record.data);
    let estimate: Vec<usize> =
        ["a", "b", "d", "sigma_y"].iter().map(|n| p.param_index(n)).collect::<Result<_, _>>()?;
    let start = regression_theta_guess(&p.model, &p.observation, &p.theta, &p.theta_prior, &estimate, data)?;
    let problem = EstimationProblem { theta: &start.theta, ..record.problem(&estimate) };
    let t0 = problem.t0;
    let step = p.sample_every / pieces as f64;
    let t_end = data.times.last().copied().unwrap_or(t0);
    let nodes = ((t_end - t0) / step).round() as usize;
    let times: Vec<f64> = (0..=nodes).map(|k| t0 + k as f64 * step).collect();
    let guess = spline_guess(&p.model, &start.theta, &p.observation.states, data, &times)?;
    let options = PathOptions::new(Merit::OnsagerMachlup, Transcription::HermiteSimpson)
        .with_step(step)
        .with_laplace(Laplace::Off)
        .with_initial_path(guess)
        .with_nlp(NlpOptions::default().with_linear_solver(solver));
    let begin = std::time::Instant::now();
    let sol = estimate_path(&problem, options)?;
    let total_seconds = begin.elapsed().as_secs_f64();
    let r = &sol.report;
    println!("pieces {nodes}, unknowns {}", sol.estimate.details["unknowns"]);
    println!("status {}, iterations {}", r.status, r.iterations);
    println!(
        "factorizations: numeric {}, inertia corrections {}, other {}",
        r.numeric_factorizations, r.inertia_correction_factorizations, r.other_factorizations
    );
    println!("kkt solver {}: nnz(K) {}, nnz(L) {}", r.linear_solver, r.kkt_nnz, r.factor_nnz);
    println!(
        "solve_seconds {:.3} (evaluation {:.3}, factorization {:.3}, kkt solves {:.3}); \
         estimate_path {total_seconds:.3}",
        sol.estimate.solve_seconds,
        r.times.evaluation.as_secs_f64(),
        r.times.factorization.as_secs_f64(),
        r.times.solve.as_secs_f64()
    );
    let names = ["a", "b", "d", "sigma_y"];
    let theta: Vec<String> =
        estimate.iter().zip(names).map(|(&i, n)| format!("{n} = {:.4}", sol.estimate.theta[i])).collect();
    println!("theta: {}", theta.join(", "));
    Ok(())
}
