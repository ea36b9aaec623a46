//! One estimator description through three front doors: the command line (`estimate`,
//! `compare --methods`), an estimators file (`compare --estimators`) and an experiment spec
//! build the same `Estimator`, give the same estimates, and reject a wrong option with an error
//! that names the estimator, the option and what is allowed.

use std::path::PathBuf;
use std::process::Output;

use onsager::compare::{compare, CompareOptions};
use onsager::estimator::{parse_list, read_list, Estimator, Method};
use onsager::experiment::report::parse_results;
use onsager::experiment::runner::simulate_replicate;
use onsager::experiment::{replicate_seed, run, Experiment, RunOptions};
use onsager::Error;

use crate::support::onsager;

fn scratch(name: &str) -> PathBuf {
    crate::support::scratch("estimators", name)
}

/// Simulated double-well data (9 measurements) and its truth in `dir`.
fn double_well(dir: &std::path::Path) -> (PathBuf, PathBuf) {
    let (data, truth) = (dir.join("dw.csv"), dir.join("dw-truth.csv"));
    let sim = onsager()
        .args(["simulate", "--t-end", "4", "--sample-every", "0.5", "--seed", "3", "--out"])
        .arg(&data)
        .arg("--truth")
        .arg(&truth)
        .output()
        .unwrap();
    assert!(sim.status.success(), "{}", String::from_utf8_lossy(&sim.stderr));
    (data, truth)
}

/// The command failed with exit code 1 (not a panic) and its error mentions every `needle`.
fn assert_usage_error(out: &Output, needles: &[&str]) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    for needle in needles {
        assert!(err.contains(needle), "`{err}` should mention `{needle}`");
    }
}

const TWO_WITH_OPTIONS: &str = "exp-closure:moments=6,panels=16,jme:transcription=trapezoidal,step=0.05,uks";

const TWO_WITH_OPTIONS_TOML: &str = r#"
[[estimators]]
method = "exp-closure"
options = { moments = 6, panels = 16 }

[[estimators]]
method = "jme"
options = { transcription = "trapezoidal", step = 0.05 }

[[estimators]]
method = "uks"
"#;

#[test]
fn the_text_the_file_and_the_json_forms_are_the_same_estimators() {
    let from_text = parse_list(TWO_WITH_OPTIONS).unwrap();
    let dir = scratch("forms");
    let file = dir.join("estimators.toml");
    std::fs::write(&file, TWO_WITH_OPTIONS_TOML).unwrap();
    let from_file = read_list(&file).unwrap();
    assert_eq!(from_text, from_file);
    assert_eq!(from_text.iter().map(|e| e.label.as_str()).collect::<Vec<_>>(), ["exp-closure", "jme", "uks"]);
    match &from_text[0].estimator {
        Estimator::ExpClosure(c) => assert_eq!((c.family.moments, c.family.panels), (6, 16)),
        other => panic!("{other:?}"),
    }
    // JSON round trip (the form other languages pass).
    for e in &from_text {
        let json = serde_json::to_string(&e.estimator).unwrap();
        let back: Estimator = serde_json::from_str(&json).unwrap();
        assert_eq!(back, e.estimator, "{json}");
    }
    // The example file of the README.
    let example = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/estimators.toml");
    let labels: Vec<String> = read_list(&example).unwrap().into_iter().map(|e| e.label).collect();
    assert_eq!(labels, ["ksp", "sextic", "gaussian-closure", "jme-trapezoidal", "uks"]);
    // Two estimators of one method are labelled by their text.
    let two =
        parse_list("jme,jme:transcription=euler,ksp:grid=\"lo=-3,hi=3,cells=50\",label=coarse").unwrap();
    let labels: Vec<&str> = two.iter().map(|e| e.label.as_str()).collect();
    assert_eq!(labels, ["jme", "jme:transcription=euler", "coarse"]);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn compare_runs_estimators_with_their_own_options_from_the_command_line_and_from_a_file() {
    let dir = scratch("compare");
    let (data, truth) = double_well(&dir);
    let file = dir.join("estimators.toml");
    std::fs::write(&file, TWO_WITH_OPTIONS_TOML).unwrap();
    let mut summaries = Vec::new();
    for (flag, value) in
        [("--methods", TWO_WITH_OPTIONS.to_string()), ("--estimators", file.display().to_string())]
    {
        let out_dir = dir.join(flag.trim_start_matches('-'));
        let out = onsager()
            .args(["compare", "--data"])
            .arg(&data)
            .arg("--truth")
            .arg(&truth)
            .args([flag, &value, "--out-dir"])
            .arg(&out_dir)
            .output()
            .unwrap();
        assert!(out.status.success(), "{flag}: {}", String::from_utf8_lossy(&out.stderr));
        let stdout = String::from_utf8_lossy(&out.stdout);
        for label in ["exp-closure", "jme", "uks"] {
            assert!(stdout.lines().any(|l| l.starts_with(label)), "no row {label}: {stdout}");
        }
        let summary: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out_dir.join("summary.json")).unwrap()).unwrap();
        summaries.push(summary);
    }
    // The same estimates through both doors (solve times aside).
    for s in &mut summaries {
        for row in s["methods"].as_array_mut().unwrap() {
            row["solve_seconds"] = serde_json::Value::Null;
        }
    }
    assert_eq!(summaries[0], summaries[1]);
    let rows = summaries[0]["methods"].as_array().unwrap();
    assert_eq!(rows.len(), 3);
    assert!(
        rows.iter().all(|r| r["status"] == "converged" && r["rmse_truth"].as_f64().unwrap() < 1.0),
        "{rows:?}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_wrong_option_names_the_estimator_the_option_and_what_is_allowed_at_every_door() {
    let dir = scratch("wrong");
    let (data, _) = double_well(&dir);
    let estimate = |args: &[&str]| {
        onsager()
            .arg("estimate")
            .arg("--data")
            .arg(&data)
            .args(args)
            .arg("--out")
            .arg(dir.join("e.csv"))
            .output()
            .unwrap()
    };
    // The command line of `estimate`: an option of another method, a value outside the choices.
    assert_usage_error(
        &estimate(&["--method", "uks", "--moments", "6"]),
        &["moments", "uks", "alpha, dt, kappa"],
    );
    assert_usage_error(
        &estimate(&["--method", "uks", "--option", "moments=6"]),
        &["moments", "uks", "alpha"],
    );
    assert_usage_error(
        &estimate(&["--method", "jme", "--option", "transcription=simpson"]),
        &["transcription", "jme", "simpson", "hermite-simpson", "trapezoidal", "euler"],
    );
    assert_usage_error(
        &estimate(&["--method", "jme", "--transcription", "simpson"]),
        &["simpson", "hermite-simpson"],
    );
    assert_usage_error(
        &estimate(&["--method", "exp-closure", "--option", "moments=1"]),
        &["moments", "exp-closure", "2 to 12"],
    );
    // `compare --methods` and `compare --estimators`.
    let compare_with =
        |args: &[&str]| onsager().arg("compare").arg("--data").arg(&data).args(args).output().unwrap();
    assert_usage_error(&compare_with(&["--methods", "ksp,uks:moments=6"]), &["moments", "uks", "alpha"]);
    assert_usage_error(
        &compare_with(&["--methods", "jme:transcription=simpson"]),
        &["transcription", "jme", "euler"],
    );
    let file = dir.join("bad.toml");
    std::fs::write(&file, "[[estimators]]\nmethod = \"uks\"\noptions = { moments = 6 }\n").unwrap();
    assert_usage_error(
        &compare_with(&["--estimators", file.to_str().unwrap()]),
        &["estimators.uks.options.moments", "uks", "alpha"],
    );
    // An experiment spec, through the command line and the library.
    let spec = dir.join("spec.toml");
    let text = "name = \"bad\"\n[model]\nname = \"double-well\"\n[[estimators]]\nmethod = \"jme\"\n\
                options = { transcription = \"simpson\" }\n";
    std::fs::write(&spec, text).unwrap();
    let out =
        onsager().args(["experiment", "run"]).arg(&spec).arg("--out").arg(dir.join("x")).output().unwrap();
    assert_usage_error(&out, &["estimators.jme.options.transcription", "jme", "simpson", "hermite-simpson"]);
    match Experiment::from_toml(text) {
        Err(Error::InvalidOption { name, reason }) => {
            assert_eq!(name, "estimators.jme.options.transcription");
            assert!(reason.contains("euler") && reason.contains("jme"), "{reason}");
        }
        other => panic!("{other:?}"),
    }
    // The library's own parser.
    match Estimator::parse("uks:moments=6") {
        Err(Error::EstimatorOption { method, option, reason }) => {
            assert_eq!((method.as_str(), option.as_str()), ("uks", "moments"));
            assert!(reason.contains("alpha, dt, kappa"), "{reason}");
        }
        other => panic!("{other:?}"),
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn an_experiment_spec_with_the_same_options_gives_the_same_estimates_as_compare() {
    let text = r#"
name = "same"
replicates = 1
seed = 7
metrics = ["rmse"]
[model]
name = "double-well"
[simulation]
dt = 0.01
t_end = 4.0
[measurements]
every = 0.5
[[estimators]]
method = "exp-closure"
options = { moments = 6, panels = 16 }
[[estimators]]
method = "jme"
options = { transcription = "trapezoidal", step = 0.05 }
[[estimators]]
method = "uks"
"#;
    let experiment = Experiment::from_toml(text).unwrap();
    let dir = scratch("same");
    let mut options = RunOptions::new(&dir);
    options.jobs = 1;
    options.plots = false;
    let report = run(&experiment, &options, &|_| {}).unwrap();
    let rows =
        parse_results(&std::fs::read_to_string(&report.results).unwrap(), &report.results).unwrap().rows;
    // The same replicate's data, and the same estimators from the command-line text.
    let scenario = &experiment.scenarios(false).unwrap()[0];
    let (truth, data) = simulate_replicate(scenario, replicate_seed(7, &scenario.name, 0)).unwrap();
    let problem = scenario.estimators[0].preset.problem(&data, &[]);
    let estimators = parse_list(TWO_WITH_OPTIONS).unwrap();
    for (spec, text) in scenario.estimators.iter().zip(&estimators) {
        assert_eq!(spec.estimator, text.estimator);
    }
    let c = compare(&problem, &estimators, Some(&truth), &CompareOptions::default()).unwrap();
    for (row, r) in c.rows.iter().zip(&rows) {
        assert_eq!(row.label, r.estimator);
        assert_eq!(row.method, r.method);
        assert!(matches!(row.method, Method::ExpClosure | Method::Jme | Method::Uks));
        assert_eq!(row.status, r.status);
        assert_eq!(row.rmse_truth.unwrap(), r.metrics[0], "{}", row.label);
    }
    let _ = std::fs::remove_dir_all(&dir);
}
