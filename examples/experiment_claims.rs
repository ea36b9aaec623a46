//! Checks the papers' claims (issue 9, Acceptance) on the summaries of the built-in
//! experiments, as written by
//! `cargo run --release -- experiment run NAME --jobs 2` (50 replicates per scenario) into
//! `out/experiments/NAME/summary.json`:
//!
//! - `vdp-robust` (`001_8aefdf0570c96f51.txt` Sec. 9, Fig. 3): the median ISE of JME and MEE is
//!   below the UKS's for p_o ≥ 0.25;
//! - `duffing-gaussian` (`000_74b95e149527c64e.txt` Sec. 4.1.1, Fig. 4.5): the median d̂ of MEE
//!   is below JME's (the damping bias of the minimum-energy estimator);
//! - `holmes-rand-quantized` (`000_74b95e149527c64e.txt` Sec. 4.1.3, Fig. 4.14): the PEM's
//!   median ISE is above JME's when Σ_y ≪ l_b (Σ_y = 0.005, l_b = 0.05);
//! - `duffing-outliers` (`000_74b95e149527c64e.txt` Sec. 4.1.2, Fig. 4.8): with the Student-t
//!   likelihood, the median ISE of JME and MEE is below the PEM's (Gaussian likelihood) for
//!   every outlier probability p_o;
//! - `tanh-limits` (`001_8aefdf0570c96f51.txt` Sec. 2, Thm 18): as h shrinks, the Euler MAP
//!   path approaches the minimum-energy path and the trapezoidal one the Onsager–Machlup path;
//! - `double-well-jumps` (issue 9): the exponential closure closer to the exact mean-optimal
//!   estimate than the Gaussian closure (when the closures are among its estimators).
//!
//! Prints one line per check (PASS, FAIL, or MISSING when the summary or the estimator is not
//! there) and exits with status 1 if any check fails.
//!
//! Run: `cargo run --release --example experiment_claims [DIR]` (default `out/experiments`).

use std::path::{Path, PathBuf};

use serde_json::Value;

fn load(dir: &Path, name: &str) -> Option<Value> {
    let text = std::fs::read_to_string(dir.join(name).join("summary.json")).ok()?;
    serde_json::from_str(&text).ok()
}

/// The median of `what` (`metrics` or `theta`) `key` of `estimator` in `scenario`.
fn median(scenario: &Value, estimator: &str, what: &str, key: &str) -> Option<f64> {
    let e = scenario["estimators"].as_array()?.iter().find(|e| e["estimator"] == estimator)?;
    e[what][key]["median"].as_f64()
}

fn var(scenario: &Value, name: &str) -> Option<f64> {
    scenario["vars"][name].as_str()?.parse().ok()
}

struct Checks {
    failed: usize,
}

impl Checks {
    fn report(&mut self, experiment: &str, scenario: &str, claim: &str, values: Option<(bool, String)>) {
        match values {
            Some((ok, detail)) => {
                if !ok {
                    self.failed += 1;
                }
                println!("{} {experiment} [{scenario}] {claim}: {detail}", if ok { "PASS" } else { "FAIL" });
            }
            None => println!("MISSING {experiment} [{scenario}] {claim}"),
        }
    }
}

fn scenarios(summary: &Option<Value>) -> Vec<Value> {
    summary.as_ref().and_then(|s| s["scenarios"].as_array().cloned()).unwrap_or_default()
}

fn main() {
    let dir = PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| "out/experiments".into()));
    let mut checks = Checks { failed: 0 };

    let vdp = load(&dir, "vdp-robust");
    if vdp.is_none() {
        checks.report("vdp-robust", "-", "summary.json", None);
    }
    for s in scenarios(&vdp) {
        let name = s["scenario"].as_str().unwrap_or("?").to_string();
        if var(&s, "p_o").is_none_or(|p| p < 0.25) {
            continue;
        }
        let v = (|| {
            let (jme, mee, uks) = (
                median(&s, "jme", "metrics", "ise")?,
                median(&s, "mee", "metrics", "ise")?,
                median(&s, "uks", "metrics", "ise")?,
            );
            Some((jme < uks && mee < uks, format!("median ISE jme {jme:.4}, mee {mee:.4}, uks {uks:.4}")))
        })();
        checks.report("vdp-robust", &name, "median ISE of JME and MEE below UKS", v);
    }

    let duffing = load(&dir, "duffing-gaussian");
    if duffing.is_none() {
        checks.report("duffing-gaussian", "-", "summary.json", None);
    }
    for s in scenarios(&duffing) {
        let name = s["scenario"].as_str().unwrap_or("?").to_string();
        let v = (|| {
            let (jme, mee) = (median(&s, "jme", "theta", "d")?, median(&s, "mee", "theta", "d")?);
            Some((mee < jme, format!("median d: mee {mee:.4}, jme {jme:.4} (nominal 0.2)")))
        })();
        checks.report("duffing-gaussian", &name, "median d of MEE below JME's", v);
    }

    let holmes = load(&dir, "holmes-rand-quantized");
    if holmes.is_none() {
        checks.report("holmes-rand-quantized", "-", "summary.json", None);
    }
    for s in scenarios(&holmes) {
        let name = s["scenario"].as_str().unwrap_or("?").to_string();
        let Some(sd) = var(&s, "sigma_y") else { continue };
        let v = (|| {
            let (pem, jme) = (median(&s, "pem", "metrics", "ise")?, median(&s, "jme", "metrics", "ise")?);
            Some((pem > jme, format!("median ISE pem {pem:.3e}, jme {jme:.3e}")))
        })();
        if sd <= 0.01 {
            checks.report("holmes-rand-quantized", &name, "PEM's median ISE above JME's (sigma_y << l_b)", v);
        } else if let Some((_, detail)) = v {
            println!("INFO holmes-rand-quantized [{name}] (sigma_y ~ l_b, no claim): {detail}");
        }
        // Why the claim fails when Sigma_y is estimated: the joint MAP's Sigma_y-hat (docs/results.md).
        for label in ["jme", "mee"] {
            let sy = median(&s, label, "theta", "sigma_y");
            let e = s["estimators"].as_array().and_then(|a| a.iter().find(|e| e["estimator"] == label));
            if let (Some(sy), Some(e)) = (sy, e) {
                println!(
                    "INFO holmes-rand-quantized [{name}] {label}: median Sigma_y-hat {sy:.3e} (true {sd}), \
                     {}/{} rows converged or acceptable",
                    e["success"], e["rows"]
                );
            }
        }
        // Diagnostic rows (not in the thesis): JME and MEE with Sigma_y fixed at its true value.
        let known = (|| {
            let (pem, jme, mee) = (
                median(&s, "pem", "metrics", "ise")?,
                median(&s, "jme-sy-known", "metrics", "ise")?,
                median(&s, "mee-sy-known", "metrics", "ise")?,
            );
            Some(format!("median ISE with Sigma_y known: jme {jme:.3e}, mee {mee:.3e}; pem {pem:.3e}"))
        })();
        if let Some(detail) = known {
            println!("INFO holmes-rand-quantized [{name}] {detail}");
        }
    }

    let outliers = load(&dir, "duffing-outliers");
    if outliers.is_none() {
        checks.report("duffing-outliers", "-", "summary.json", None);
    }
    for s in scenarios(&outliers) {
        let name = s["scenario"].as_str().unwrap_or("?").to_string();
        let v = (|| {
            let (jme, mee, pem) = (
                median(&s, "jme", "metrics", "ise")?,
                median(&s, "mee", "metrics", "ise")?,
                median(&s, "pem", "metrics", "ise")?,
            );
            Some((jme < pem && mee < pem, format!("median ISE jme {jme:.3e}, mee {mee:.3e}, pem {pem:.3e}")))
        })();
        checks.report("duffing-outliers", &name, "median ISE of JME and MEE below PEM's", v);
    }

    let tanh = load(&dir, "tanh-limits");
    let tanh_scenarios = scenarios(&tanh);
    let by_h = |estimator: &str, col: &str| -> Option<Vec<(f64, f64)>> {
        let mut v: Vec<(f64, f64)> = tanh_scenarios
            .iter()
            .map(|s| Some((var(s, "h")?, median(s, estimator, "metrics", col)?)))
            .collect::<Option<_>>()?;
        v.sort_by(|a, b| b.0.total_cmp(&a.0));
        (v.len() >= 2).then_some(v)
    };
    for (estimator, col, limit) in
        [("euler", "rmse_to_energy", "minimum-energy"), ("trapezoidal", "rmse_to_om", "Onsager-Machlup")]
    {
        let v = by_h(estimator, col).map(|v| {
            let decreasing = v.windows(2).all(|w| w[1].1 < w[0].1);
            let text = v.iter().map(|(h, m)| format!("h={h}: {m:.4}")).collect::<Vec<_>>().join(", ");
            (decreasing, format!("median RMSE to the {limit} path {text}"))
        });
        checks.report("tanh-limits", "all h", &format!("{estimator} path tends to the {limit} path"), v);
    }

    let dw = load(&dir, "double-well-jumps");
    if dw.is_none() {
        checks.report("double-well-jumps", "-", "summary.json", None);
    }
    for s in scenarios(&dw) {
        let name = s["scenario"].as_str().unwrap_or("?").to_string();
        for e in s["estimators"].as_array().into_iter().flatten() {
            let (label, m) = (e["estimator"].as_str().unwrap_or("?"), &e["metrics"]);
            println!(
                "INFO double-well-jumps [{name}] {label}: median RMSE to truth {:.4}, to KSP {:.4}, to mean-optimal {:.4}, well side {:.3}",
                m["rmse"]["median"].as_f64().unwrap_or(f64::NAN),
                m["rmse_to_ksp"]["median"].as_f64().unwrap_or(f64::NAN),
                m["rmse_to_mean-optimal"]["median"].as_f64().unwrap_or(f64::NAN),
                m["well_side"]["median"].as_f64().unwrap_or(f64::NAN),
            );
        }
        let v = (|| {
            let g = median(&s, "gaussian-closure", "metrics", "rmse_to_mean-optimal")?;
            let x = median(&s, "exp-closure", "metrics", "rmse_to_mean-optimal")?;
            Some((x < g, format!("median RMSE to mean-optimal: exp {x:.4}, gaussian {g:.4}")))
        })();
        checks.report(
            "double-well-jumps",
            &name,
            "exponential closure closer to mean-optimal than Gaussian",
            v,
        );
    }

    if checks.failed > 0 {
        println!("{} check(s) failed", checks.failed);
        std::process::exit(1);
    }
}
