//! Joint path and parameter estimation on the Duffing oscillator (`000_74b95e149527c64e.txt`
//! Sec. 4.1.1, Table 4.1): for each seed, simulate the `duffing` preset on [0, 100] (order 1.5
//! scheme, step 0.005, x0 and z0 from the priors (4.3)), measure z every 0.1 with Σ_y = 0.1,
//! and estimate θ = (a, b, d, σ_y) jointly with the path by the Onsager–Machlup (JME) and the
//! minimum-energy (MEE) merits, Hermite–Simpson with the default step (measurement spacing / 20
//! = 0.005, 20,000 pieces), from the smoothing-spline path guess (x = the spline's derivative
//! of z) and the regression guess of θ (000 Sec. 4.1: least squares of the spline's second
//! derivative on the drift's θ columns; Σ_y from the spline residuals).
//!
//! Prints one row per seed, the medians and quartiles of the estimates, and the two checks of
//! issue 4: the median d̂ of MEE is below that of JME (the damping bias of the minimum-energy
//! estimator, 000 Sec. 4.1.1, Fig. 4.5) and the median d̂ of JME is within 0.03 of d = 0.2.
//!
//! Run with `cargo run --release --example duffing_joint [SEEDS]` (default 20 seeds, 1..=SEEDS).

use onsager::estimate::EstimationProblem;
use onsager::model::library::preset;
use onsager::path::{
    estimate_path, regression_theta_guess, spline_guess, Laplace, Merit, PathOptions, Transcription,
};
use onsager::test_models::PresetRecord;

/// The estimated parameters, in the order printed.
const ESTIMATED: [&str; 4] = ["a", "b", "d", "sigma_y"];

/// The q-quantile of `values` by linear interpolation between order statistics (NaN-free input).
fn quantile(values: &[f64], q: f64) -> f64 {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let pos = q * (v.len() - 1) as f64;
    let (lo, hi) = (pos.floor() as usize, pos.ceil() as usize);
    v[lo] + (pos - lo as f64) * (v[hi] - v[lo])
}

fn main() -> onsager::Result<()> {
    let seeds: u64 = std::env::args().nth(1).and_then(|s| s.parse().ok()).unwrap_or(20);
    let p = preset("duffing")?;
    let estimate: Vec<usize> = ESTIMATED.iter().map(|n| p.param_index(n)).collect::<Result<_, _>>()?;
    let merits = [("JME", Merit::OnsagerMachlup), ("MEE", Merit::Energy)];
    // estimates[m][k]: the values of ESTIMATED[k] under merit m over the seeds.
    let mut estimates = vec![vec![Vec::new(); ESTIMATED.len()]; merits.len()];

    println!("Duffing joint estimation, T = {}, Hermite-Simpson, default step, {seeds} seeds", p.t_end);
    println!("nominal (Table 4.1): a = 1, b = -1, d = 0.2, sigma_y = 0.1");
    print!("{:>4}", "seed");
    for (name, _) in &merits {
        print!(" | {:<16}", format!("{name} status/it"));
        for n in ESTIMATED {
            print!(" {:>8}", format!("{n}"));
        }
    }
    println!(" | {:>6}", "s");
    for seed in 1..=seeds {
        let record = PresetRecord::simulate(p.clone(), seed)?;
        let data = &record.data;
        let start =
            regression_theta_guess(&p.model, &p.observation, &p.theta, &p.theta_prior, &estimate, data)?;
        let problem = EstimationProblem { theta: &start.theta, ..record.problem(&estimate) };
        let t0 = problem.t0;
        let step = onsager::path::default_step(t0, data);
        let t_end = data.times.last().copied().unwrap_or(t0);
        let nodes = ((t_end - t0) / step).round() as usize;
        let times: Vec<f64> = (0..=nodes).map(|k| t0 + k as f64 * step).collect();
        let guess = spline_guess(&p.model, &start.theta, &p.observation.states, data, &times)?;

        print!("{seed:>4}");
        let mut seconds = 0.0;
        for (m, (_, merit)) in merits.iter().enumerate() {
            let options = PathOptions::new(*merit, Transcription::HermiteSimpson)
                .with_laplace(Laplace::Off)
                .with_initial_path(guess.clone());
            let est = estimate_path(&problem, options)?.estimate;
            seconds += est.solve_seconds;
            print!(" | {:<16}", format!("{}/{}", est.status, est.iterations));
            for (k, &i) in estimate.iter().enumerate() {
                print!(" {:>8.4}", est.theta[i]);
                if est.status.is_success() {
                    estimates[m][k].push(est.theta[i]);
                }
            }
        }
        println!(" | {seconds:>6.2}");
    }

    println!();
    println!("{:>8} {:>7} {:>9} {:>9} {:>9}", "merit", "param", "q25", "median", "q75");
    for (m, (name, _)) in merits.iter().enumerate() {
        for (k, n) in ESTIMATED.iter().enumerate() {
            let v = &estimates[m][k];
            println!(
                "{name:>8} {n:>7} {:>9.4} {:>9.4} {:>9.4}   ({} converged)",
                quantile(v, 0.25),
                quantile(v, 0.5),
                quantile(v, 0.75),
                v.len()
            );
        }
    }
    let d = ESTIMATED.iter().position(|&n| n == "d").expect("d is estimated");
    let (d_jme, d_mee) = (quantile(&estimates[0][d], 0.5), quantile(&estimates[1][d], 0.5));
    let verdict = |ok: bool| if ok { "PASS" } else { "FAIL" };
    println!();
    println!("check 1: median d MEE ({d_mee:.4}) < median d JME ({d_jme:.4}): {}", verdict(d_mee < d_jme));
    println!(
        "check 2: |median d JME - 0.2| = {:.4} <= 0.03: {}",
        (d_jme - 0.2).abs(),
        verdict((d_jme - 0.2).abs() <= 0.03)
    );
    Ok(())
}
