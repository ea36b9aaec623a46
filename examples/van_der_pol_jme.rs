//! One Van der Pol JME solve, the problem of `benches/path.rs` (issue 4's performance target):
//! Student-t likelihood (ν = 4, scale 0.5), Hermite–Simpson with step 0.005 on [0, 16]
//! (3200 pieces, 25,602 unknowns; 001_8aefdf0570c96f51.txt Sec. 9), data simulated with seed 1,
//! spline guess, no Laplace sd.
//!
//! Prints, for each of REPEATS solves, the status, iterations, factorisation counts, the time of
//! the whole `estimate_path` call (`total_s`: what `benches/path.rs` measures, program
//! construction included), the NLP's `solve_seconds` and its time per phase, so that the solve can be profiled (`valgrind --tool=callgrind`) or timed
//! outside criterion.
//!
//! Run with `cargo run --release --example van_der_pol_jme [REPEATS] [jme|mee] [auto|band|faer] [keep]`
//! (the third argument chooses the KKT solver, default auto; `keep` passes one solver to every
//! repeat through `estimate_path_with`, so that the band solver analyses the KKT pattern once,
//! as a Monte Carlo run can). An argument `--data-out=PATH` also writes the data as CSV, so that
//! the same problem can be timed through the CLI (`onsager estimate --model van-der-pol --data
//! PATH --method jme --likelihood student-t:nu=4,scale=0.5 --step 0.005 --report R.json`).

use onsager::nlp::{AutoLdlt, BandLdlt, FaerLdlt, KktSolver, LinearSolver, NlpOptions};
use onsager::path::{
    estimate_path, estimate_path_with, spline_guess, Laplace, Merit, PathOptions, Transcription,
};
use onsager::test_models::van_der_pol_student_t;

fn main() -> onsager::Result<()> {
    let repeats: usize = std::env::args().nth(1).and_then(|s| s.parse().ok()).unwrap_or(1);
    let merit = match std::env::args().nth(2).as_deref() {
        Some("mee") => Merit::Energy,
        _ => Merit::OnsagerMachlup,
    };
    let solver = match std::env::args().nth(3).as_deref() {
        Some("band") => LinearSolver::Band,
        Some("faer") => LinearSolver::Faer,
        _ => LinearSolver::Auto,
    };
    let keep = std::env::args().nth(4).as_deref() == Some("keep");
    let mut kept: Box<dyn KktSolver> = match solver {
        LinearSolver::Band => Box::new(BandLdlt::new()),
        LinearSolver::Faer => Box::new(FaerLdlt::new()),
        _ => Box::new(AutoLdlt::new()),
    };
    // Simulated with the preset's outlier mixture from (0, 0), seed 1; estimated with Student-t.
    let record = van_der_pol_student_t(1)?;
    let (p, data) = (&record.preset, &record.data);
    if let Some(path) = std::env::args().find_map(|a| a.strip_prefix("--data-out=").map(String::from)) {
        data.write_csv(&path)?;
    }
    let problem = record.problem(&[]);
    let times: Vec<f64> = (0..=3200).map(|k| k as f64 * 0.005).collect();
    let guess = spline_guess(&p.model, &p.theta, &p.observation.states, data, &times)?;
    println!(
        "{:>3} {:>10} {:>5} {:>5} {:>5} {:>5} {:>9} {:>9} {:>9} {:>9} {:>9}",
        "run",
        "status",
        "iter",
        "fact",
        "ic",
        "other",
        "total_s",
        "solve_s",
        "eval_s",
        "factor_s",
        "kktsol_s"
    );
    for run in 0..repeats {
        let options = PathOptions::new(merit, Transcription::HermiteSimpson)
            .with_step(0.005)
            .with_laplace(Laplace::Off)
            .with_initial_path(guess.clone())
            .with_nlp(NlpOptions::default().with_linear_solver(solver));
        let start = std::time::Instant::now();
        let sol = if keep {
            estimate_path_with(&problem, options, kept.as_mut())?
        } else {
            estimate_path(&problem, options)?
        };
        let total_seconds = start.elapsed().as_secs_f64();
        let r = &sol.report;
        println!(
            "{run:>3} {:>10} {:>5} {:>5} {:>5} {:>5} {:>9.4} {:>9.4} {:>9.4} {:>9.4} {:>9.4}",
            r.status.name(),
            r.iterations,
            r.numeric_factorizations,
            r.inertia_correction_factorizations,
            r.other_factorizations,
            total_seconds,
            sol.estimate.solve_seconds,
            r.times.evaluation.as_secs_f64(),
            r.times.factorization.as_secs_f64(),
            r.times.solve.as_secs_f64(),
        );
        if run + 1 == repeats {
            println!(
                "unknowns {}, kkt solver {}, kkt nnz {}, factor nnz {}",
                sol.estimate.details["unknowns"], r.linear_solver, r.kkt_nnz, r.factor_nnz
            );
        }
    }
    Ok(())
}
