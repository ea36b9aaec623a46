//! The motivating example of `001_8aefdf0570c96f51.txt` Sec. 2 (Fig. 1): dX = tanh(X) dt + dW,
//! X0 ~ N(0, 0.16), one measurement y = 1.5 at t = 5 with error N(0, 0.16).
//!
//! The Euler-discretized MAP paths converge to the minimum-energy path (MEE), the
//! trapezoidal-discretized ones to the Onsager–Machlup path (OM, JME), as N grows
//! (001 Thm 18). The references are Hermite–Simpson solutions of the continuous merits on a
//! fine grid (4000 pieces), whose own change under halving of the step is printed first.
//!
//! Run with `cargo run --release --example tanh_discretization_limits`.

use onsager::data::{Dataset, StatePath};
use onsager::estimate::EstimationProblem;
use onsager::model::library::preset;
use onsager::path::{estimate_path, Laplace, Merit, PathOptions, Transcription};

fn main() -> onsager::Result<()> {
    let p = preset("tanh")?;
    let data = Dataset::try_new(p.observation.names.clone(), vec![5.0], vec![vec![1.5]])?;
    let problem = EstimationProblem {
        sde: &p.model,
        observation: &p.observation,
        theta: &p.theta,
        theta_prior: &p.theta_prior,
        estimate: &[],
        x0_prior: &p.x0_prior,
        z0_prior: &p.z0_prior,
        data: &data,
        t0: 0.0,
        seed: 0,
        max_memory: Default::default(),
    };
    // Initial path: the straight line from the prior mean to the measurement.
    let guess = StatePath {
        names: vec!["x".into()],
        times: vec![0.0, 5.0],
        values: vec![vec![0.0], vec![1.5]],
        sd: None,
    };
    let solve = |merit: Merit, transcription: Transcription, n: usize| -> onsager::Result<Vec<f64>> {
        let options = PathOptions::new(merit, transcription)
            .with_step(5.0 / n as f64)
            .with_laplace(Laplace::Off)
            .with_initial_path(guess.clone());
        let sol = estimate_path(&problem, options)?;
        if !sol.estimate.status.is_success() {
            eprintln!("warning: {merit:?} {transcription:?} N = {n}: {}", sol.estimate.status);
        }
        Ok(sol.estimate.path.values.iter().map(|v| v[0]).collect())
    };
    // Sup-norm distance of a path on N intervals to a reference on `fine` intervals (N | fine).
    let dist = |coarse: &[f64], fine: &[f64]| {
        let stride = (fine.len() - 1) / (coarse.len() - 1);
        coarse.iter().enumerate().map(|(k, &v)| (v - fine[k * stride]).abs()).fold(0.0, f64::max)
    };

    let fine = 4000;
    let om = solve(Merit::OnsagerMachlup, Transcription::HermiteSimpson, fine)?;
    let mee = solve(Merit::Energy, Transcription::HermiteSimpson, fine)?;
    let om_half = solve(Merit::OnsagerMachlup, Transcription::HermiteSimpson, fine / 2)?;
    let mee_half = solve(Merit::Energy, Transcription::HermiteSimpson, fine / 2)?;
    println!("# Hermite-Simpson references, N = {fine}: change under halving of h");
    println!("#   OM:  {:.3e}", dist(&om_half, &om));
    println!("#   MEE: {:.3e}", dist(&mee_half, &mee));
    println!("#   distance OM to MEE: {:.3e}", dist(&om, &mee));
    println!(
        "{:>5} {:>13} {:>13} {:>13} {:>13}",
        "N", "euler_to_mee", "euler_to_om", "trap_to_om", "trap_to_mee"
    );
    for n in [10, 20, 50, 100, 200, 500, 1000, 2000] {
        let euler = solve(Merit::Energy, Transcription::Euler, n)?;
        let trap = solve(Merit::OnsagerMachlup, Transcription::Trapezoidal, n)?;
        println!(
            "{n:>5} {:>13.4e} {:>13.4e} {:>13.4e} {:>13.4e}",
            dist(&euler, &mee),
            dist(&euler, &om),
            dist(&trap, &om),
            dist(&trap, &mee)
        );
    }
    Ok(())
}
