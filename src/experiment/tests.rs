use std::path::Path;

use super::report::parse_results;
use super::runner::{metric_values, replicate_seed, simulate_replicate};
use super::spec::{Experiment, Metric};
use super::BUILTIN;
use crate::estimate::RowStatus;
use crate::plot::{Color, Prim, DATA, TRUTH};
use crate::{Error, Status};

/// A small valid spec; `extra` is appended (TOML tables after the top-level keys).
fn spec(top: &str, extra: &str) -> String {
    format!(
        r#"name = "t"
replicates = 2
{top}

[model]
name = "double-well"

[simulation]
dt = 0.01
t_end = 2.0

[measurements]
every = 0.5

[[estimators]]
method = "uks"

[[estimators]]
method = "jme"
options = {{ step = 0.1 }}
{extra}
"#
    )
}

/// The name of the option an error is about.
fn key_of(text: &str) -> String {
    match Experiment::from_toml(text) {
        Err(Error::InvalidOption { name, reason }) => format!("{name}: {reason}"),
        Err(other) => panic!("expected InvalidOption, got {other}"),
        Ok(_) => panic!("expected an error for\n{text}"),
    }
}

#[test]
fn every_builtin_parses_in_both_versions() {
    for (name, text) in BUILTIN {
        let e = Experiment::from_toml(text).unwrap_or_else(|err| panic!("{name}: {err}"));
        assert_eq!(e.spec.name, *name);
        assert!(!e.spec.source.is_empty(), "{name} cites its source");
        let full = e.scenarios(false).unwrap();
        let quick = e.scenarios(true).unwrap();
        assert!(quick.len() <= full.len(), "{name}");
        assert!(quick[0].spec.replicates <= full[0].spec.replicates, "{name}");
    }
}

#[test]
fn spec_errors_name_the_key() {
    let base = spec("", "");
    assert!(Experiment::from_toml(&base).is_ok());
    let cases = [
        (base.replace("every = 0.5", "evry = 0.5"), "measurements.evry"),
        (base.replace("every = 0.5", "every = \"often\""), "measurements.every"),
        (base.replace("every = 0.5", "every = -0.5"), "measurements.every"),
        (base.replace("dt = 0.01", "dt = 0.0"), "simulation.dt"),
        (base.replace("t_end = 2.0", "t_end = \"x\""), "simulation.t_end"),
        (base.replace("replicates = 2", "replicates = -1"), "replicates"),
        (base.replace("replicates = 2", "replicas = 2"), "replicas"),
        (base.replace("name = \"double-well\"", "name = \"triple-well\""), "model.name"),
        (base.replace("options = { step = 0.1 }", "options = { stpe = 0.1 }"), "estimators.jme.options.stpe"),
        (
            base.replace("options = { step = 0.1 }", "options = { step = \"x\" }"),
            "estimators.jme.options.step",
        ),
        (base.replace("options = { step = 0.1 }", "estimate = [\"Q\"]"), "estimators.jme.estimate"),
        (base.replace("method = \"uks\"", "method = \"kalman\""), "estimators.kalman.method"),
        (base.replace("method = \"uks\"", "method = \"uks\"\nestimate = [\"D\"]"), "estimators.uks.estimate"),
        (base.replace("method = \"jme\"", "method = \"uks\""), "estimators.uks.label"),
        (spec("metrics = [\"ise\", \"mse\"]", ""), "metrics"),
        (spec("metrics = [\"rmse-to:ksp\"]", ""), "metrics"),
        (spec("", "[grid]\nq = [1, 2]"), "grid.q"),
        (spec("", "[grid]\n\"simulation.t_end\" = 3.0"), "grid.simulation.t_end"),
        (spec("", "[quick]\n\"estimators.ksp.options.step\" = 0.2"), "quick.estimators.ksp.options.step"),
        (base.replace("every = 0.5", "every = 0.5\ngenerate = \"gaussian:sd=-1\""), "measurements.generate"),
        (
            base.replace("[simulation]", "[simulation]\ninitial = { y = \"normal:0,1\" }"),
            "simulation.initial.y",
        ),
    ];
    for (text, key) in cases {
        let got = key_of(&text);
        assert!(got.starts_with(&format!("{key}:")), "expected key `{key}`, got `{got}`");
    }
    // A syntax error shows the line.
    let got = key_of("name = \n");
    assert!(got.contains("line 1"), "{got}");
    // An error in one scenario of the grid names the key and the scenario.
    let got = key_of(&spec("", "[grid]\n\"measurements.every\" = [0.5, -1.0]"));
    assert!(got.starts_with("measurements.every:") && got.contains("measurements.every=-1"), "{got}");
}

#[test]
fn grid_is_the_cartesian_product_with_variables_and_dotted_keys() {
    let text = spec(
        "",
        r#"[grid]
sd = [0.1, 0.3]
"estimators.jme.options.step" = [0.1, 0.05, 0.025]
"#,
    )
    .replace("every = 0.5", "every = 0.5\ngenerate = \"gaussian:sigma={sd}\"");
    let e = Experiment::from_toml(&text).unwrap();
    let s = e.scenarios(false).unwrap();
    assert_eq!(s.len(), 6);
    // The last key varies fastest.
    assert_eq!(s[0].name, "estimators.jme.options.step=0.1,sd=0.1");
    assert_eq!(s[1].name, "estimators.jme.options.step=0.1,sd=0.3");
    assert_eq!(s[5].name, "estimators.jme.options.step=0.025,sd=0.3");
    assert_eq!(step_of(&s[5].estimators[1]), Some(0.025));
    assert_eq!(s[5].truth.observation.noise.gaussian_sd(&s[5].truth.theta), Some(0.3));
    // The estimators use the generating likelihood unless told otherwise.
    assert_eq!(s[1].estimators[0].preset.observation.noise.gaussian_sd(&[0.5]), Some(0.3));
    // A whole-string variable keeps the value's type.
    let typed = spec("", "[grid]\nh = [0.2]").replace("step = 0.1", "step = \"{h}\"");
    let s = Experiment::from_toml(&typed).unwrap().scenarios(false).unwrap();
    assert_eq!(step_of(&s[0].estimators[1]), Some(0.2));
}

#[test]
fn quick_overrides_apply_only_when_asked() {
    let text = spec(
        "",
        "[quick]\nreplicates = 1\n\"simulation.t_end\" = 1.0\n\"estimators.jme.options.step\" = 0.25",
    );
    let e = Experiment::from_toml(&text).unwrap();
    let full = &e.scenarios(false).unwrap()[0];
    let quick = &e.scenarios(true).unwrap()[0];
    assert_eq!((full.spec.replicates, full.truth.t_end), (2, 2.0));
    assert_eq!((quick.spec.replicates, quick.truth.t_end), (1, 1.0));
    assert_eq!(step_of(&quick.estimators[1]), Some(0.25));
    assert_eq!(quick.times, vec![0.0, 0.5, 1.0]);
    let e = e.with_replicates(7).with_seed(u64::MAX);
    let s = &e.scenarios(true).unwrap()[0];
    assert_eq!((s.spec.replicates, s.spec.seed), (7, u64::MAX), "the given replicates win; any u64 seed");
    assert_eq!(e.scenarios(false).unwrap()[0].spec.replicates, 7);
}

#[test]
fn metrics_parse_and_name_their_columns() {
    assert_eq!(Metric::parse("ise").unwrap(), Metric::Ise);
    assert_eq!(Metric::parse("rmse-to:ksp").unwrap().column(), "rmse_to_ksp");
    assert_eq!(Metric::parse("well-side").unwrap().column(), "well_side");
    assert_eq!(Metric::parse("well-side:z").unwrap().column(), "well_side_z");
    assert!(Metric::parse("rmse-to:").is_err());
    assert!(Metric::parse("iae").is_err());
}

#[test]
fn replicate_seeds_depend_on_seed_scenario_and_replicate_only() {
    let a = replicate_seed(1, "p=0.1", 0);
    assert_eq!(a, replicate_seed(1, "p=0.1", 0));
    let others =
        [replicate_seed(2, "p=0.1", 0), replicate_seed(1, "p=0.2", 0), replicate_seed(1, "p=0.1", 1)];
    for o in others {
        assert_ne!(a, o);
    }
}

#[test]
fn results_parse_back_with_quoted_names_empty_and_nan_cells() {
    let text = "scenario,replicate,estimator,method,status,iterations,solve_seconds,ise,theta_d,message\n\
                \"p=0.1,s=1\",3,jme,jme,converged,12,0.5,NaN,0.21,\n\
                default,0,uks,uks,error,0,0,,,\"bad, really\"\n";
    let r = parse_results(text, Path::new("results.csv")).unwrap();
    assert_eq!(r.metric_columns, vec!["ise"]);
    assert_eq!(r.theta_columns, vec!["d"]);
    assert_eq!(r.rows[0].scenario, "p=0.1,s=1");
    assert_eq!((r.rows[0].replicate, r.rows[0].iterations, r.rows[0].theta[0]), (3, 12, Some(0.21)));
    assert!(r.rows[0].metrics[0].is_nan() && r.rows[1].metrics[0].is_nan());
    assert_eq!((r.rows[1].theta[0], r.rows[1].message.as_str()), (None, "bad, really"));
    let short =
        "scenario,replicate,estimator,method,status,iterations,solve_seconds,message\ndefault,0,uks\n";
    assert!(matches!(parse_results(short, Path::new("r.csv")), Err(Error::Data { line: 2, .. })));
}

/// The transcription step of a MAP estimator of a scenario.
fn step_of(e: &super::ScenarioEstimator) -> Option<f64> {
    match &e.estimator {
        crate::Estimator::Jme(o) | crate::Estimator::Mee(o) => o.step,
        other => panic!("not a MAP estimator: {other:?}"),
    }
}

/// Results of `scenarios` with `rows` rows per scenario and estimator, the first `failed[k]`
/// of the k-th estimator failed (status `error`), the others converged with metric value
/// 0.1 × (k + 1) and θ̂ = 0.5.
fn results_of(scenarios: &[super::Scenario], rows: usize, failed: &[usize]) -> super::report::Results {
    let mut out = Vec::new();
    for s in scenarios {
        for (k, e) in s.estimators.iter().enumerate() {
            for r in 0..rows {
                let ok = r >= failed[k];
                let status = if ok { RowStatus::Finished(Status::Converged) } else { RowStatus::Error };
                out.push(super::Row {
                    scenario: s.name.clone(),
                    replicate: r,
                    estimator: e.label.clone(),
                    method: e.estimator.method(),
                    status,
                    iterations: 1,
                    solve_seconds: 0.0,
                    metrics: vec![if ok { 0.1 * (k + 1) as f64 } else { f64::NAN }],
                    theta: vec![(ok && !e.estimate.is_empty()).then_some(0.5)],
                    message: String::new(),
                });
            }
        }
    }
    super::report::Results {
        header: Vec::new(),
        metric_columns: vec!["ise".into()],
        theta_columns: vec!["D".into()],
        rows: out,
    }
}

#[test]
fn an_estimator_has_one_colour_in_every_figure_of_an_experiment_and_boxes_state_their_rows() {
    use super::report::{looks, path_figure, summary_figures, ReplicatePaths};
    // uks; euler, a second jme; jme estimating D (trapezoidal, as D scales the noise).
    let text = spec("", "[grid]\n\"measurements.every\" = [0.5, 1.0]")
        .replace("options = { step = 0.1 }", "options = { step = 0.1, transcription = \"trapezoidal\" }")
        .replace("method = \"jme\"", "method = \"jme\"\nestimate = [\"D\"]")
        .replace("[[estimators]]\nmethod = \"uks\"", "[[estimators]]\nmethod = \"uks\"\n\n[[estimators]]\nlabel = \"euler\"\nmethod = \"jme\"\noptions = { transcription = \"euler\", step = 0.1 }");
    let scenarios = Experiment::from_toml(&text).unwrap().scenarios(false).unwrap();
    let looks = looks(&scenarios);
    let labels: Vec<&str> = scenarios[0].estimators.iter().map(|e| e.label.as_str()).collect();
    assert_eq!(labels, ["uks", "euler", "jme"]);
    // The colour of each estimator in the path figures of both scenarios (euler fails on the
    // second: its error is stated in its panel).
    let mut colours: Vec<(String, Color)> = Vec::new();
    for (i, s) in scenarios.iter().enumerate() {
        let (truth, data) = simulate_replicate(s, replicate_seed(1, &s.name, 0)).unwrap();
        let mut estimates = Vec::new();
        let mut errors = Vec::new();
        for e in &s.estimators {
            if i == 1 && e.label == "euler" {
                errors.push((e.label.clone(), "it failed".to_string()));
                continue;
            }
            let est = e.estimator.run(&e.preset.problem(&data, &e.estimate)).unwrap().estimate;
            estimates.push((e.label.clone(), est));
        }
        let paths = ReplicatePaths { truth: &truth, data: &data, estimates: &estimates, errors: &errors };
        let fig = path_figure(s, 0, paths, &looks);
        for q in fig.header.iter().chain(&fig.panels) {
            for series in q.series.iter().filter(|x| labels.contains(&x.label.as_str())) {
                colours.push((series.label.clone(), series.color.unwrap()));
            }
            if q.title.starts_with("euler\n") && i == 1 {
                assert_eq!(q.title, "euler\nno estimate: it failed");
            }
        }
    }
    // 33 of 50 rows of uks succeed; jme and euler all 50.
    let results = results_of(&scenarios, 50, &[17, 0, 0]);
    let figures = summary_figures(&scenarios, &results, &looks);
    let names: Vec<&str> = figures.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["metric_ise", "theta_D"]);
    for (_, fig) in &figures {
        for q in &fig.panels {
            for g in &q.groups {
                colours.push((g.label.clone(), g.color.unwrap()));
            }
            let scene = q.scene().unwrap();
            let texts: Vec<&str> = scene
                .prims
                .iter()
                .filter_map(|p| if let Prim::Text { text, .. } = p { Some(text.as_str()) } else { None })
                .collect();
            for g in &q.groups {
                let rows =
                    if g.label == "uks" { ["n = 33/50", "17 failed"].as_slice() } else { &["n = 50/50"] };
                assert!(rows.iter().all(|r| texts.contains(r)), "{}: {texts:?}", g.label);
            }
        }
        assert!(fig.title.contains("n = drawn/rows"));
    }
    // The box of uks counts its failed rows; the θ̂ panels have only the estimators of D.
    let uks = &figures[0].1.panels[0].groups[0];
    assert_eq!((uks.label.as_str(), uks.values.len(), uks.failed), ("uks", 33, 17));
    assert_eq!(figures[1].1.panels[0].groups.iter().map(|g| g.label.as_str()).collect::<Vec<_>>(), ["jme"]);
    for label in &labels {
        let mine: Vec<Color> = colours.iter().filter(|(l, _)| l == label).map(|(_, c)| *c).collect();
        assert!(mine.len() >= 4, "{label}: {mine:?}");
        assert!(mine.iter().all(|c| *c == looks.look(label).color && *c != TRUTH && *c != DATA), "{label}");
    }
}

/// A failed estimate without a path gets one message saying so, not one confusing message per
/// metric about reference times.
#[test]
fn an_estimate_without_a_path_gets_one_message_and_nan_metrics() {
    let e = Experiment::from_toml(&spec("", "")).unwrap();
    let scenario = &e.scenarios(true).unwrap()[0];
    let cols: Vec<String> = scenario.metrics.iter().map(Metric::column).collect();
    let empty = crate::data::StatePath { names: vec!["x".into()], times: vec![], values: vec![], sd: None };
    let truth = crate::data::StatePath {
        names: vec!["x".into()],
        times: vec![0.0, 1.0],
        values: vec![vec![0.0], vec![1.0]],
        sd: None,
    };
    let mut messages = Vec::new();
    let values = metric_values(scenario, &cols, &empty, &truth, &[], &mut messages);
    assert!(values.iter().all(|v| v.is_nan()));
    assert_eq!(messages, ["no metrics: the estimator returned no path"]);
}

/// `metrics_at = "measurements"` judges every estimate at the measurement times: the truth is
/// cut down to those times (interpolated), and an unknown value names the key.
#[test]
fn metrics_at_the_measurement_times() {
    let e = Experiment::from_toml(&spec("metrics_at = \"measurements\"", "")).unwrap();
    assert_eq!(e.scenarios(true).unwrap()[0].spec.metrics_at, super::MetricsAt::Measurements);
    let default = Experiment::from_toml(&spec("", "")).unwrap();
    assert_eq!(default.scenarios(true).unwrap()[0].spec.metrics_at, super::MetricsAt::Truth);
    let err = Experiment::from_toml(&spec("metrics_at = \"grid\"", "")).unwrap_err().to_string();
    assert!(err.contains("metrics_at"), "{err}");

    let path = crate::data::StatePath {
        names: vec!["x".into(), "y".into()],
        times: vec![0.0, 1.0, 2.0],
        values: vec![vec![0.0, 10.0], vec![1.0, 20.0], vec![4.0, 30.0]],
        sd: Some(vec![vec![1.0, 1.0], vec![2.0, 2.0], vec![3.0, 3.0]]),
    };
    let at = path.at_times(&[-1.0, 0.5, 1.5, 2.0, 3.0]);
    assert_eq!(at.times, [0.5, 1.5, 2.0]);
    assert_eq!(at.values, [vec![0.5, 15.0], vec![2.5, 25.0], vec![4.0, 30.0]]);
    assert_eq!(at.sd.unwrap(), [vec![1.5, 1.5], vec![2.5, 2.5], vec![3.0, 3.0]]);
}
