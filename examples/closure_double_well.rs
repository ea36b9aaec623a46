//! Gaussian and quartic exponential closures against the exact mean-optimal estimate on the
//! double well (`003_d2fc48a470e528fc.txt` Part II; issue 7).
//!
//! Model: the `double-well` preset (dX = (4X − 4X³) dt + √(2D) dW, D = 0.5, x0 ~ N(−1, 0.2²)),
//! measurements y_k ~ N(x(t_k), 0.2²) (R = 0.04) at t = 1, 2, …, 10 (horizon 10). Ten seeds are taken, in
//! order, among those whose simulated path changes wells (visits x > 0.8 and x < −0.8). For each,
//! the table gives the RMSE over the output grid (step 0.1) of the Gaussian-closure and of the
//! quartic-closure (M = (x, x², x³, x⁴)) mean-optimal estimates against the exact grid
//! mean-optimal estimate (`action::mean_optimal`, 600 cells on [−3, 3], dt = 0.005), and the
//! solve times.
//!
//! Run: `cargo run --release --example closure_double_well`

use onsager::action::{closure_estimate, mean_optimal, Closure, ClosureOptions, ExactOptions, GridSpec};
use onsager::test_models::{DoubleWellRecord, Start};

/// The first `n` seeds whose double-well path changes wells on [0, 10], with their records (the
/// `double-well` preset's problem with R = 0.04).
fn seeds_with_transitions(n: usize) -> Vec<(u64, DoubleWellRecord)> {
    let times: Vec<f64> = (1..=T_END as usize).map(|k| k as f64).collect();
    (0..)
        .map(|seed| {
            (seed, DoubleWellRecord::simulate(seed, Start::Drawn, T_END, &times).expect("valid settings"))
        })
        .filter(|(_, record)| record.changes_wells())
        .take(n)
        .collect()
}

/// The horizon: measurements at 1, 2, …, `T_END`.
const T_END: f64 = 10.0;

fn rmse(a: &[Vec<f64>], b: &[Vec<f64>]) -> f64 {
    (a.iter().zip(b).map(|(x, y)| (x[0] - y[0]).powi(2)).sum::<f64>() / a.len() as f64).sqrt()
}

fn main() -> onsager::Result<()> {
    let exact_options =
        ExactOptions::new(GridSpec::new_1d(-3.0, 3.0, 600)).with_dt(0.005).with_output_step(0.1);
    let options = ClosureOptions::new().with_output_step(0.1).with_dispersion(false);
    println!(
        "{:>5} {:>14} {:>14} {:>8} {:>11} {:>11} {:>11}",
        "seed", "RMSE gaussian", "RMSE quartic", "closer", "t exact/s", "t gauss/s", "t quart/s"
    );
    let mut wins = 0;
    let seeds = seeds_with_transitions(10);
    for (seed, record) in &seeds {
        let problem = record.problem();
        let exact = mean_optimal(&problem, &exact_options)?;
        let g = closure_estimate(&problem, &Closure::gaussian(options.clone()))?;
        let q = closure_estimate(&problem, &Closure::exponential(4, options.clone()))?;
        let (eg, eq) = (rmse(&g.path.values, &exact.history.mean), rmse(&q.path.values, &exact.history.mean));
        let closer = eq < eg;
        wins += usize::from(closer);
        println!(
            "{seed:>5} {eg:>14.5} {eq:>14.5} {:>8} {:>11.3} {:>11.3} {:>11.3}   ({}, {})",
            if closer { "quartic" } else { "gaussian" },
            exact.solve_seconds,
            g.solve_seconds,
            q.solve_seconds,
            g.status,
            q.status
        );
    }
    println!("quartic closer on {wins} of {} seeds", seeds.len());
    Ok(())
}
