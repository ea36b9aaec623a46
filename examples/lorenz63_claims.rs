//! Checks the claims on `lorenz63-smoothing` (stochastic Lorenz-63, G = √10 I, window 20) on
//! the summary written by
//! `cargo run --release -- experiment run lorenz63-smoothing --replicates 20 --jobs 1 --out out/l63`:
//!
//! - dense setting (all states every 0.2, variance 2): the Gaussian KSP closure
//!   (`gaussian-ksp-closure`) converges on every replicate, its median RMSE to the truth is
//!   within 5 % of the particle smoother's, and its median ±2 sd coverage is in [0.90, 0.98].
//!
//! Prints the medians of every estimator in both settings (RMSE, mean sd, coverage, the fraction
//! of time on the true lobe, seconds, successful rows), then one line per claim (PASS, FAIL, or
//! MISSING) and exits with status 1 if a claim fails.
//!
//! Run: `cargo run --release --example lorenz63_claims [SUMMARY]` (default
//! `out/l63/summary.json`).

use serde_json::Value;

const CLOSURE: &str = "gaussian-ksp-closure";
const REFERENCE: &str = "particle";
const COLUMNS: [&str; 5] = ["rmse", "mean_sd", "coverage", "well_side_x1", "solve_seconds"];

fn estimator<'a>(scenario: &'a Value, label: &str) -> Option<&'a Value> {
    scenario["estimators"].as_array()?.iter().find(|e| e["estimator"] == label)
}

fn median(scenario: &Value, label: &str, key: &str) -> Option<f64> {
    estimator(scenario, label)?["metrics"][key]["median"].as_f64()
}

fn print_table(scenario: &Value) {
    println!("{}", scenario["scenario"].as_str().unwrap_or("?"));
    println!(
        "  {:<22} {:>8} {:>8} {:>9} {:>8} {:>9} {:>8}",
        "estimator", "rmse", "mean_sd", "coverage", "lobe", "seconds", "ok/rows"
    );
    for e in scenario["estimators"].as_array().into_iter().flatten() {
        let label = e["estimator"].as_str().unwrap_or("?");
        let cells: Vec<String> = COLUMNS
            .iter()
            .map(|c| e["metrics"][c]["median"].as_f64().map_or("-".into(), |v| format!("{v:.3}")))
            .collect();
        println!(
            "  {label:<22} {:>8} {:>8} {:>9} {:>8} {:>9} {:>8}",
            cells[0],
            cells[1],
            cells[2],
            cells[3],
            cells[4],
            format!("{}/{}", e["success"], e["rows"])
        );
    }
}

/// PASS/FAIL/MISSING of one claim; returns whether it failed.
fn report(name: &str, outcome: Option<(bool, String)>) -> bool {
    match outcome {
        Some((true, detail)) => {
            println!("PASS     {name}: {detail}");
            false
        }
        Some((false, detail)) => {
            println!("FAIL     {name}: {detail}");
            true
        }
        None => {
            println!("MISSING  {name}");
            false
        }
    }
}

fn main() {
    let path = std::env::args().nth(1).unwrap_or_else(|| "out/l63/summary.json".into());
    let Some(summary) =
        std::fs::read_to_string(&path).ok().and_then(|t| serde_json::from_str::<Value>(&t).ok())
    else {
        println!("MISSING  {path}");
        return;
    };
    let scenarios = summary["scenarios"].as_array().cloned().unwrap_or_default();
    for s in &scenarios {
        print_table(s);
    }
    let dense =
        scenarios.iter().find(|s| s["vars"]["setting"] == "dense" || s["scenario"] == "setting=dense");
    let mut failed = false;
    failed |= report(
        "dense: the Gaussian KSP closure converges on every replicate",
        dense.and_then(|s| estimator(s, CLOSURE)).map(|e| {
            let (ok, rows) = (e["success"].as_u64().unwrap_or(0), e["rows"].as_u64().unwrap_or(0));
            (ok == rows && rows > 0, format!("{ok} of {rows}"))
        }),
    );
    failed |= report(
        "dense: median RMSE within 5 % of the particle smoother's",
        dense
            .and_then(|s| Some((median(s, CLOSURE, "rmse")?, median(s, REFERENCE, "rmse")?)))
            .map(|(c, p)| (c <= 1.05 * p, format!("{c:.3} vs {p:.3} (ratio {:.3})", c / p))),
    );
    failed |= report(
        "dense: median ±2 sd coverage in [0.90, 0.98]",
        dense
            .and_then(|s| median(s, CLOSURE, "coverage"))
            .map(|c| ((0.90..=0.98).contains(&c), format!("{c:.3}"))),
    );
    if failed {
        std::process::exit(1);
    }
}
