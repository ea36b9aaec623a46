//! Reading `results.csv` back, `summary.json` (medians, quartiles and failure counts per
//! scenario, estimator and metric) and the plots.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde_json::{json, Map, Value};

use super::runner::{Row, KEY_COLUMNS};
use super::spec::{ExperimentSpec, Scenario};
use crate::data::{Dataset, StatePath};
use crate::estimate::{PathEstimate, RowStatus};
use crate::estimator::Method;
use crate::figures::{box_group, EstimatorLooks, Outcome, PathFigure};
use crate::plot::{quantile, BoxGroup, BoxPlot, LinePlot, Panels};
use crate::{Error, Result};

/// The rows of a `results.csv` with its header.
#[derive(Debug, Clone, PartialEq)]
pub struct Results {
    /// The header.
    pub header: Vec<String>,
    /// Metric columns (after the key columns).
    pub metric_columns: Vec<String>,
    /// Parameter names of the `theta_NAME` columns.
    pub theta_columns: Vec<String>,
    /// The rows.
    pub rows: Vec<Row>,
}

/// A number of `results.csv` (`NaN` allowed; empty is NaN).
fn parse_number(s: &str) -> std::result::Result<f64, String> {
    if s.is_empty() {
        return Ok(f64::NAN);
    }
    s.parse::<f64>().map_err(|_| format!("`{s}` is not a number"))
}

/// Parses the text of a `results.csv` (every line complete).
///
/// Errors: [`Error::Data`] naming the line of a malformed row.
pub fn parse_results(text: &str, path: &Path) -> Result<Results> {
    let err =
        |line: usize, reason: String| Error::Data { path: path.to_path_buf(), line, column: None, reason };
    let mut reader = csv::ReaderBuilder::new().has_headers(false).flexible(true).from_reader(text.as_bytes());
    let mut records = reader.records();
    let header: Vec<String> = match records.next() {
        Some(Ok(h)) => h.iter().map(|s| s.to_string()).collect(),
        Some(Err(e)) => return Err(err(1, e.to_string())),
        None => return Err(err(1, "no header".into())),
    };
    let n_key = KEY_COLUMNS.len();
    if header.len() < n_key + 1
        || header[..n_key] != KEY_COLUMNS
        || header.last().map(String::as_str) != Some("message")
    {
        return Err(err(1, format!("not a results header: `{}`", header.join(","))));
    }
    let middle = &header[n_key..header.len() - 1];
    let split = middle.iter().position(|c| c.starts_with("theta_")).unwrap_or(middle.len());
    let metric_columns = middle[..split].to_vec();
    let theta_columns: Vec<String> =
        middle[split..].iter().map(|c| c.trim_start_matches("theta_").to_string()).collect();
    let mut rows = Vec::new();
    for (i, rec) in records.enumerate() {
        let line = i + 2;
        let rec = rec.map_err(|e| err(line, e.to_string()))?;
        if rec.len() != header.len() {
            return Err(err(line, format!("{} fields, the header has {}", rec.len(), header.len())));
        }
        let f = |k: usize| rec[k].to_string();
        let num =
            |k: usize| parse_number(&rec[k]).map_err(|r| err(line, format!("column `{}`: {r}", header[k])));
        let replicate = rec[1].parse::<usize>().map_err(|_| err(line, "bad replicate".into()))?;
        let iterations = rec[5].parse::<usize>().map_err(|_| err(line, "bad iterations".into()))?;
        let metrics = (0..metric_columns.len()).map(|k| num(n_key + k)).collect::<Result<Vec<_>>>()?;
        let theta = (0..theta_columns.len())
            .map(|k| {
                let c = n_key + metric_columns.len() + k;
                if rec[c].is_empty() {
                    Ok(None)
                } else {
                    num(c).map(Some)
                }
            })
            .collect::<Result<Vec<_>>>()?;
        let method = rec[3].parse::<Method>().map_err(|e| err(line, format!("column `method`: {e}")))?;
        let status = rec[4].parse::<RowStatus>().map_err(|e| err(line, format!("column `status`: {e}")))?;
        rows.push(Row {
            scenario: f(0),
            replicate,
            estimator: f(2),
            method,
            status,
            iterations,
            solve_seconds: num(6)?,
            metrics,
            theta,
            message: f(header.len() - 1),
        });
    }
    Ok(Results { header, metric_columns, theta_columns, rows })
}

/// n, median, quartiles and the number of non-finite values of a sample.
fn stats(values: &[f64]) -> Value {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    v.sort_by(f64::total_cmp);
    let q = |p: f64| quantile(&v, p).ok().map_or(Value::Null, |x| json!(x));
    json!({
        "n": v.len(),
        "non_finite": values.len() - v.len(),
        "q25": q(0.25),
        "median": q(0.5),
        "q75": q(0.75),
    })
}

/// The `summary.json` of an experiment: per scenario (with its grid values and nominal θ) and
/// estimator, the number of rows, the count of each non-success status, and for each metric
/// and estimated parameter the median and quartiles over the successful rows (converged or
/// acceptable) with finite values.
pub fn summary(spec: &ExperimentSpec, scenarios: &[Scenario], results: &Results, quick: bool) -> Value {
    let mut out = Vec::new();
    for s in scenarios {
        let mut estimators = Vec::new();
        for e in &s.estimators {
            let rows: Vec<&Row> =
                results.rows.iter().filter(|r| r.scenario == s.name && r.estimator == e.label).collect();
            let ok: Vec<&Row> = rows.iter().copied().filter(|r| r.status.is_success()).collect();
            let mut failures = BTreeMap::new();
            for r in rows.iter().filter(|r| !r.status.is_success()) {
                *failures.entry(r.status.name().to_string()).or_insert(0usize) += 1;
            }
            let mut metrics = Map::new();
            for (k, c) in results.metric_columns.iter().enumerate() {
                metrics.insert(c.clone(), stats(&ok.iter().map(|r| r.metrics[k]).collect::<Vec<_>>()));
            }
            metrics.insert(
                "solve_seconds".into(),
                stats(&ok.iter().map(|r| r.solve_seconds).collect::<Vec<_>>()),
            );
            let mut theta = Map::new();
            for (k, c) in results.theta_columns.iter().enumerate() {
                let v: Vec<f64> = ok.iter().filter_map(|r| r.theta[k]).collect();
                if rows.iter().any(|r| r.theta[k].is_some()) {
                    theta.insert(c.clone(), stats(&v));
                }
            }
            estimators.push(json!({
                "estimator": e.label,
                "method": e.estimator.name(),
                "rows": rows.len(),
                "success": ok.len(),
                "failures": failures,
                "metrics": metrics,
                "theta": theta,
            }));
        }
        let vars: Map<String, Value> = s.vars.iter().map(|(k, v)| (k.clone(), json!(v))).collect();
        let nominal: Map<String, Value> =
            s.truth.param_names().into_iter().zip(&s.truth.theta).map(|(n, v)| (n, json!(v))).collect();
        out.push(json!({ "scenario": s.name, "vars": vars, "nominal": nominal, "estimators": estimators }));
    }
    json!({
        "experiment": spec.name,
        "description": spec.description,
        "source": spec.source,
        "quick": quick,
        "seed": spec.seed,
        "replicates": scenarios.first().map_or(0, |s| s.spec.replicates),
        "statistics": "over rows with status converged or acceptable and a finite value; type-7 quantiles",
        "scenarios": out,
    })
}

/// A scenario name as a file name: characters other than ASCII letters, digits, `.`, `-`, `=`
/// become `_`.
pub fn file_name(name: &str) -> String {
    name.chars().map(|c| if c.is_ascii_alphanumeric() || ".-=".contains(c) { c } else { '_' }).collect()
}

fn columns_for(n: usize) -> usize {
    n.clamp(1, 3)
}

/// The looks of the estimators of `scenarios` (one per label, in the order of the spec), the
/// same in every figure of the experiment.
pub fn looks(scenarios: &[Scenario]) -> EstimatorLooks {
    EstimatorLooks::new(
        scenarios.iter().flat_map(|s| s.estimators.iter().map(|e| (e.label.as_str(), e.estimator.method()))),
    )
}

/// The box of one scenario's estimator: `value` of its successful rows, the others counted as
/// failed.
fn group(
    results: &Results,
    scenario: &str,
    label: &str,
    value: impl Fn(&Row) -> Option<f64>,
    looks: &EstimatorLooks,
) -> BoxGroup {
    let rows: Vec<&Row> =
        results.rows.iter().filter(|r| r.scenario == scenario && r.estimator == label).collect();
    let ok: Vec<&Row> = rows.iter().copied().filter(|r| r.status.is_success()).collect();
    box_group(label, ok.iter().filter_map(|r| value(r)).collect(), rows.len() - ok.len(), looks)
}

/// Box plots of each metric (one panel per scenario, one box per estimator over its
/// successful rows, labelled `n = drawn/rows` with its failed rows) and of each estimated
/// parameter with its nominal value as a reference line, as in `000_74b95e149527c64e.txt`
/// Figs. 4.4–4.5 and `001_8aefdf0570c96f51.txt` Fig. 3; each estimator in its look of
/// `looks`. Returns each figure with its file stem (`metric_COL`, `theta_NAME`).
pub fn summary_figures(
    scenarios: &[Scenario],
    results: &Results,
    looks: &EstimatorLooks,
) -> Vec<(String, Panels<BoxPlot>)> {
    let mut figures = Vec::new();
    let panels = |title: String, panels: Vec<BoxPlot>| Panels {
        title,
        columns: columns_for(panels.len()),
        panels,
        ..Panels::default()
    };
    for (k, col) in results.metric_columns.iter().enumerate() {
        let boxes: Vec<BoxPlot> = scenarios
            .iter()
            .map(|s| BoxPlot {
                title: s.name.clone(),
                y_label: col.clone(),
                groups: s
                    .estimators
                    .iter()
                    .map(|e| group(results, &s.name, &e.label, |r| Some(r.metrics[k]), looks))
                    .collect(),
                log_y: col != "well_side" && !col.starts_with("well_side_"),
                width: 520,
                height: 380,
                ..BoxPlot::default()
            })
            .collect();
        let title = format!("{col} over the successful rows (n = drawn/rows)");
        figures.push((format!("metric_{}", file_name(col)), panels(title, boxes)));
    }
    for (k, name) in results.theta_columns.iter().enumerate() {
        let mut boxes = Vec::new();
        for s in scenarios {
            let groups: Vec<BoxGroup> = s
                .estimators
                .iter()
                .filter(|e| e.estimate.iter().any(|&i| e.preset.param_names()[i] == *name))
                .map(|e| group(results, &s.name, &e.label, |r| r.theta[k], looks))
                .collect();
            let nominal = s.truth.param_index(name).ok().map(|i| s.truth.theta[i]);
            boxes.push(BoxPlot {
                title: s.name.clone(),
                y_label: name.clone(),
                groups,
                reference_lines: nominal.map(|v| vec![("nominal".to_string(), v)]).unwrap_or_default(),
                width: 520,
                height: 380,
                ..BoxPlot::default()
            });
        }
        let title = format!("estimates of {name} over the successful rows (n = drawn/rows)");
        figures.push((format!("theta_{}", file_name(name)), panels(title, boxes)));
    }
    figures
}

/// Writes the [`summary_figures`] into `dir`; returns the stems written (`DIR/metric_COL`,
/// `DIR/theta_NAME`).
///
/// Errors: [`Error::Io`] for a file that could not be written.
pub fn summary_plots(scenarios: &[Scenario], results: &Results, dir: &Path) -> Result<Vec<PathBuf>> {
    let looks = looks(scenarios);
    let mut stems = Vec::new();
    for (name, figure) in summary_figures(scenarios, results, &looks) {
        let stem = dir.join(name);
        figure.write(&stem)?;
        stems.push(stem);
    }
    Ok(stems)
}

/// The estimates of one replicate of a scenario, for its path figure.
#[derive(Debug, Clone, Copy)]
pub struct ReplicatePaths<'a> {
    /// The true path.
    pub truth: &'a StatePath,
    /// The measurements.
    pub data: &'a Dataset,
    /// The estimates by label.
    pub estimates: &'a [(String, PathEstimate)],
    /// The estimators that failed, by label, with the error's message.
    pub errors: &'a [(String, String)],
}

/// The paths of one replicate ([`PathFigure`]): per state an overview of the truth, the
/// measurements and every estimate, then one panel per estimator with its ±2 sd band where it
/// has one (`000_74b95e149527c64e.txt` Figs. 4.2, 4.6; `001_8aefdf0570c96f51.txt` Fig. 4), in
/// the looks of the experiment. An estimator of the scenario without an estimate has a panel
/// saying why (its error, or that its row is from an earlier run).
pub fn path_figure(
    scenario: &Scenario,
    replicate: usize,
    paths: ReplicatePaths<'_>,
    looks: &EstimatorLooks,
) -> Panels<LinePlot> {
    let outcomes = scenario
        .estimators
        .iter()
        .map(|e| {
            let estimate = paths.estimates.iter().find(|(l, _)| *l == e.label);
            let error = paths.errors.iter().find(|(l, _)| *l == e.label);
            let outcome = match (estimate, error) {
                (Some((_, est)), _) => Outcome::Estimate(est),
                (None, Some((_, why))) => Outcome::Missing(why),
                (None, None) => Outcome::Missing("not run now: its row is from an earlier run"),
            };
            (e.label.as_str(), outcome)
        })
        .collect();
    PathFigure {
        title: format!("{}, replicate {replicate}", scenario.name),
        states: &paths.truth.names,
        truth: Some(paths.truth),
        data: paths.data,
        measured: &scenario.truth.observation.states,
        estimates: outcomes,
        looks,
    }
    .panels()
}
