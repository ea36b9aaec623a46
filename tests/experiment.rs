//! The experiment harness: every built-in experiment in its quick version, independence of the
//! number of threads, resuming an interrupted run, errors as rows, and the CLI.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::Command;

use onsager::estimate::RowStatus;
use onsager::experiment::report::parse_results;
use onsager::experiment::{builtin, run, Experiment, RunOptions, BUILTIN};

fn scratch(name: &str) -> PathBuf {
    crate::support::fresh_scratch("experiment", name)
}

fn options(out: &Path, quick: bool, jobs: usize) -> RunOptions {
    let mut o = RunOptions::new(out);
    o.quick = quick;
    o.jobs = jobs;
    o
}

/// The rows of a results.csv as a set of lines without the timing column (`solve_seconds`,
/// the only column that legitimately differs between two runs).
pub(crate) fn row_set(out: &Path) -> BTreeSet<String> {
    let text = std::fs::read_to_string(out.join("results.csv")).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let timing = header.iter().position(|c| *c == "solve_seconds").unwrap();
    let mut reader = csv::ReaderBuilder::new().has_headers(false).from_reader(text.as_bytes());
    reader
        .records()
        .skip(1)
        .map(|r| {
            let r = r.unwrap();
            r.iter().enumerate().filter(|(i, _)| *i != timing).map(|(_, f)| f).collect::<Vec<_>>().join("|")
        })
        .collect()
}

#[test]
fn every_builtin_experiment_runs_quick_with_summary_and_plots() {
    for (name, _) in BUILTIN {
        let out = scratch(&format!("quick-{name}"));
        let experiment = builtin(name).unwrap();
        let report = run(&experiment, &options(&out, true, 2), &|_| {}).unwrap();
        assert!(report.complete && report.written == report.total && report.written > 0, "{name}");
        let text = std::fs::read_to_string(&report.results).unwrap();
        let results = parse_results(&text, &report.results).unwrap();
        assert_eq!(results.rows.len(), report.total);
        // Every row is an estimate (no `error` rows in the built-in experiments) with finite metrics.
        for r in &results.rows {
            assert_ne!(r.status, RowStatus::Error, "{name}: {}", r.message);
            assert!(r.metrics.iter().all(|v| v.is_finite()), "{name}: {r:?}");
        }
        let summary: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(report.summary.unwrap()).unwrap()).unwrap();
        assert_eq!(summary["experiment"], *name);
        assert_eq!(summary["quick"], true);
        // Medians over the usable rows: every metric has one for some estimator of the first
        // scenario (a quick row may legitimately end `numerical-failure`, e.g. holmes-rand's
        // degenerate joint MAP of Σ_y, and is then left out of the statistics).
        let estimators = summary["scenarios"][0]["estimators"].as_array().unwrap();
        for col in &results.metric_columns {
            assert!(estimators.iter().any(|e| e["metrics"][col]["median"].is_number()), "{name}: {col}");
        }
        // A box plot per metric and per estimated parameter, a path plot per scenario.
        let scenarios = experiment.scenarios(true).unwrap().len();
        assert_eq!(
            report.plots.len(),
            results.metric_columns.len() + results.theta_columns.len() + scenarios
        );
        for stem in &report.plots {
            for ext in ["svg", "png"] {
                let file = PathBuf::from(format!("{}.{ext}", stem.display()));
                assert!(std::fs::metadata(&file).map(|m| m.len() > 0).unwrap_or(false), "{}", file.display());
            }
        }
        let _ = std::fs::remove_dir_all(&out);
    }
}

#[test]
fn results_do_not_depend_on_the_number_of_threads() {
    let experiment = builtin("double-well-jumps").unwrap();
    let (one, two) = (scratch("jobs1"), scratch("jobs2"));
    run(&experiment, &options(&one, true, 1), &|_| {}).unwrap();
    run(&experiment, &options(&two, true, 2), &|_| {}).unwrap();
    let (a, b) = (row_set(&one), row_set(&two));
    assert_eq!(a.len(), 16); // 2 replicates × 8 estimators
    assert_eq!(a, b);
    for d in [one, two] {
        let _ = std::fs::remove_dir_all(d);
    }
}

#[test]
fn an_interrupted_run_resumes_to_the_same_rows() {
    let experiment = builtin("tanh-limits").unwrap();
    let (whole, parts) = (scratch("whole"), scratch("parts"));
    run(&experiment, &options(&whole, true, 2), &|_| {}).unwrap();
    // Interrupted after 5 rows, with a half-written line at the end (as if killed mid-write).
    let mut first = options(&parts, true, 1);
    first.max_rows = Some(5);
    let report = run(&experiment, &first, &|_| {}).unwrap();
    assert!(!report.complete && report.written == 5 && report.summary.is_none());
    let results = parts.join("results.csv");
    let mut text = std::fs::read_to_string(&results).unwrap();
    text.push_str("h=0.5,1,eu");
    std::fs::write(&results, text).unwrap();
    // Without --resume an existing results.csv is an error, not overwritten.
    assert!(run(&experiment, &options(&parts, true, 1), &|_| {}).is_err());
    // Resuming with another seed is refused.
    let mut other = options(&parts, true, 1);
    other.resume = true;
    other.seed = Some(99);
    assert!(run(&experiment, &other, &|_| {}).is_err());
    let mut resume = options(&parts, true, 2);
    resume.resume = true;
    let report = run(&experiment, &resume, &|_| {}).unwrap();
    assert!(report.complete && report.resumed == 5 && report.written == report.total - 5);
    assert_eq!(row_set(&whole), row_set(&parts));
    assert!(parts.join("summary.json").exists());
    for d in [whole, parts] {
        let _ = std::fs::remove_dir_all(d);
    }
}

#[test]
fn a_method_error_is_a_row_with_status_error() {
    // The KSP grid does not cover the data: `methods::run` returns an error, recorded as a row.
    let text = r#"
name = "errors"
replicates = 2
metrics = ["rmse", "rmse-to:ksp"]
[model]
name = "double-well"
[simulation]
dt = 0.01
t_end = 2.0
[measurements]
every = 0.5
[[estimators]]
method = "ksp"
options = { grid = "lo=-0.1,hi=0.1,cells=20" }
[[estimators]]
method = "uks"
"#;
    let experiment = Experiment::from_toml(text).unwrap();
    let out = scratch("errors");
    let mut seen = Vec::new();
    let progress = std::sync::Mutex::new(Vec::new());
    let report =
        run(&experiment, &options(&out, false, 1), &|p| progress.lock().unwrap().push(p.done)).unwrap();
    assert!(report.complete);
    let text = std::fs::read_to_string(&report.results).unwrap();
    for r in parse_results(&text, &report.results).unwrap().rows {
        seen.push((r.estimator.clone(), r.status.name()));
        if r.estimator == "ksp" {
            assert_eq!(r.status, RowStatus::Error);
            assert!(r.message.contains("grid"), "{}", r.message);
        } else {
            // The reference is missing: the metric is NaN and the message says why.
            assert_eq!(r.status, RowStatus::Finished(onsager::Status::Converged));
            assert!(r.metrics[1].is_nan() && r.message.contains("ksp"), "{r:?}");
        }
    }
    assert_eq!(seen.len(), 4);
    let mut done = progress.into_inner().unwrap();
    done.sort();
    assert_eq!(done, vec![1, 2, 3, 4], "one progress report per row");
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn cli_lists_runs_and_fails_with_exit_code_1() {
    let bin = env!("CARGO_BIN_EXE_onsager");
    let list = Command::new(bin).args(["experiment", "list"]).output().unwrap();
    assert!(list.status.success());
    let stdout = String::from_utf8_lossy(&list.stdout);
    for (name, _) in BUILTIN {
        assert!(stdout.contains(name), "{stdout}");
    }
    let out = scratch("cli");
    let ok = Command::new(bin)
        .args([
            "experiment",
            "run",
            "double-well-jumps",
            "--quick",
            "--replicates",
            "1",
            "--jobs",
            "1",
            "--out",
        ])
        .arg(&out)
        .output()
        .unwrap();
    assert!(ok.status.success(), "{}", String::from_utf8_lossy(&ok.stderr));
    // Not a terminal: plain progress lines on stderr, one per row.
    assert_eq!(String::from_utf8_lossy(&ok.stderr).lines().filter(|l| l.starts_with('[')).count(), 8);
    assert!(out.join("summary.json").exists());
    let spec = out.join("bad.toml");
    std::fs::write(&spec, "name = \"bad\"\n[model]\nname = \"ou\"\nmodle = 1\n").unwrap();
    let bad = Command::new(bin).args(["experiment", "run"]).arg(&spec).output().unwrap();
    assert_eq!(bad.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("modle"));
    let _ = std::fs::remove_dir_all(&out);
}

/// A run whose cancel flag is set stops: after the first row here (set from the progress
/// callback), no more rows are written, the run is incomplete without a summary, and `resume`
/// finishes it with the rows of an uninterrupted run.
#[test]
fn a_cancelled_run_stops_and_resumes() {
    let out = scratch("cancel");
    let experiment = builtin("tanh-limits").unwrap();
    let cancel = onsager::experiment::Cancel::new();
    let mut o = options(&out, true, 1);
    o.cancel = Some(cancel.clone());
    let report = run(&experiment, &o, &|_| cancel.cancel()).unwrap();
    assert_eq!(report.written, 1);
    assert!(!report.complete && report.summary.is_none());
    let mut o = options(&out, true, 1);
    o.resume = true;
    let resumed = run(&experiment, &o, &|_| {}).unwrap();
    assert!(resumed.complete && resumed.resumed == 1);
    let full = scratch("cancel-full");
    run(&experiment, &options(&full, true, 1), &|_| {}).unwrap();
    assert_eq!(row_set(&out), row_set(&full));
}

/// `lorenz96-smoothing --quick`: every estimator on the 10-state record, and the Gaussian KSP
/// closure equal to the UKS (identity: with a quadratic drift both compute the same closed
/// moment equations, `docs/closures.md`, "Relation to the UKS"), with a calibrated coverage.
#[test]
fn lorenz96_smoothing_quick_runs_and_the_gaussian_ksp_closure_is_the_uks() {
    let out = scratch("lorenz96");
    let experiment = builtin("lorenz96-smoothing").unwrap();
    let report = run(&experiment, &options(&out, true, 1), &|_| {}).unwrap();
    let text = std::fs::read_to_string(&report.results).unwrap();
    let results = parse_results(&text, &report.results).unwrap();
    // The reference (particle) runs first.
    let labels: BTreeSet<&str> = results.rows.iter().map(|r| r.estimator.as_str()).collect();
    assert_eq!(labels, BTreeSet::from(["gaussian-ksp-closure", "uks", "eks", "enks", "particle"]));
    assert!(results.rows.iter().all(|r| r.status == RowStatus::Finished(onsager::Status::Converged)));
    let metric = |label: &str, col: &str| {
        let row = results.rows.iter().find(|r| r.estimator == label).unwrap();
        row.metrics[results.metric_columns.iter().position(|c| c == col).unwrap()]
    };
    for col in ["rmse", "mean_sd", "coverage"] {
        let (closure, uks) = (metric("gaussian-ksp-closure", col), metric("uks", col));
        assert!((closure - uks).abs() <= 1e-6 * uks.abs().max(1.0), "{col}: {closure} vs {uks}");
    }
    assert!((0.8..=1.0).contains(&metric("gaussian-ksp-closure", "coverage")));
    let _ = std::fs::remove_dir_all(&out);
}
