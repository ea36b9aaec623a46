//! The Markdown table of an experiment's `summary.json`, in the form of `docs/results.md`: one
//! line per scenario and estimator with `ok/rows` (rows with status converged or acceptable),
//! each metric's median and quartiles (4 and 3 significant digits) and each estimated
//! parameter's median.
//!
//! ```sh
//! cargo run --release --example summary_table -- out/experiments/tanh-limits/summary.json
//! # only some metrics, in this order
//! cargo run --release --example summary_table -- out/experiments/tanh-limits/summary.json \
//!     rmse_to_om rmse_to_energy
//! ```
//!
//! Without metric names, every metric but `solve_seconds` is shown, in alphabetical order.

use std::process::ExitCode;

use serde_json::Value;

/// `v` with `digits` significant digits, trailing zeros dropped (`0.06995`, `0.000438`, `3.382`).
fn significant(v: f64, digits: i32) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let decimals = (digits - 1 - v.abs().log10().floor() as i32).max(0) as usize;
    let text = format!("{v:.decimals$}");
    if text.contains('.') {
        text.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        text
    }
}

/// `median [q25, q75]` of a statistics object, or `-` when it has no value.
fn quartiles(stats: Option<&Value>) -> String {
    let get = |k: &str| stats.and_then(|s| s.get(k)).and_then(Value::as_f64);
    match (get("median"), get("q25"), get("q75")) {
        (Some(m), Some(a), Some(b)) => {
            format!("{} [{}, {}]", significant(m, 4), significant(a, 3), significant(b, 3))
        }
        _ => "-".into(),
    }
}

fn table(summary: &Value, chosen: &[String]) -> Result<String, String> {
    let scenarios = summary["scenarios"].as_array().ok_or("no `scenarios` array")?;
    let first = scenarios.first().and_then(|s| s["estimators"].get(0)).ok_or("no estimators")?;
    let metrics: Vec<String> = if chosen.is_empty() {
        let all = first["metrics"].as_object().ok_or("no `metrics` object")?;
        all.keys().filter(|k| *k != "solve_seconds").cloned().collect()
    } else {
        chosen.to_vec()
    };
    let mut theta: Vec<String> = Vec::new();
    for e in scenarios.iter().flat_map(|s| s["estimators"].as_array().into_iter().flatten()) {
        for k in e["theta"].as_object().into_iter().flat_map(|t| t.keys()) {
            if !theta.contains(k) {
                theta.push(k.clone());
            }
        }
    }
    let mut head = vec!["scenario".to_string(), "estimator".into(), "ok/rows".into()];
    head.extend(metrics.iter().map(|m| format!("{m} median [q25, q75]")));
    head.extend(theta.iter().map(|p| format!("{p} median")));
    let mut out = format!("| {} |\n|{}\n", head.join(" | "), "---|".repeat(head.len()));
    for s in scenarios {
        for e in s["estimators"].as_array().into_iter().flatten() {
            let mut cells = vec![
                s["scenario"].as_str().unwrap_or("?").to_string(),
                e["estimator"].as_str().unwrap_or("?").to_string(),
                format!("{}/{}", e["success"], e["rows"]),
            ];
            cells.extend(metrics.iter().map(|m| quartiles(e["metrics"].get(m))));
            cells.extend(theta.iter().map(|p| {
                e["theta"].get(p).and_then(|t| t["median"].as_f64()).map_or("-".into(), |v| significant(v, 4))
            }));
            out.push_str(&format!("| {} |\n", cells.join(" | ")));
        }
    }
    Ok(out)
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(path) = args.first() else {
        eprintln!("usage: summary_table SUMMARY.json [METRIC ...]");
        return ExitCode::FAILURE;
    };
    let summary = std::fs::read_to_string(path)
        .map_err(|e| e.to_string())
        .and_then(|text| serde_json::from_str::<Value>(&text).map_err(|e| e.to_string()));
    match summary.and_then(|s| table(&s, &args[1..])) {
        Ok(t) => {
            print!("{t}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("{path}: {e}");
            ExitCode::FAILURE
        }
    }
}
