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
use crate::plot::{quantile, BoxGroup, BoxPlot, LinePlot, Panels, Series};
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

/// Box plots of each metric (one panel per scenario, one box per estimator) and of each
/// estimated parameter with its nominal value as a reference line, as in
/// `000_74b95e149527c64e.txt` Figs. 4.4–4.5 and `001_8aefdf0570c96f51.txt` Fig. 3. Returns the
/// stems written (`DIR/metric_COL`, `DIR/theta_NAME`).
pub fn summary_plots(scenarios: &[Scenario], results: &Results, dir: &Path) -> Result<Vec<PathBuf>> {
    let mut stems = Vec::new();
    let ok = |r: &&Row| r.status.is_success();
    for (k, col) in results.metric_columns.iter().enumerate() {
        let panels: Vec<BoxPlot> = scenarios
            .iter()
            .map(|s| BoxPlot {
                title: s.name.clone(),
                y_label: col.clone(),
                groups: s
                    .estimators
                    .iter()
                    .map(|e| BoxGroup {
                        label: e.label.clone(),
                        values: results
                            .rows
                            .iter()
                            .filter(ok)
                            .filter(|r| r.scenario == s.name && r.estimator == e.label)
                            .map(|r| r.metrics[k])
                            .collect(),
                        ..BoxGroup::default()
                    })
                    .collect(),
                log_y: col != "well_side" && !col.starts_with("well_side_"),
                width: 520,
                height: 360,
                ..BoxPlot::default()
            })
            .collect();
        let stem = dir.join(format!("metric_{}", file_name(col)));
        Panels { title: col.clone(), columns: columns_for(panels.len()), panels, ..Panels::default() }
            .write(&stem)?;
        stems.push(stem);
    }
    for (k, name) in results.theta_columns.iter().enumerate() {
        let mut panels = Vec::new();
        for s in scenarios {
            let groups: Vec<BoxGroup> = s
                .estimators
                .iter()
                .filter(|e| e.estimate.iter().any(|&i| e.preset.param_names()[i] == *name))
                .map(|e| BoxGroup {
                    label: e.label.clone(),
                    values: results
                        .rows
                        .iter()
                        .filter(ok)
                        .filter(|r| r.scenario == s.name && r.estimator == e.label)
                        .filter_map(|r| r.theta[k])
                        .collect(),
                    ..BoxGroup::default()
                })
                .collect();
            let nominal = s.truth.param_index(name).ok().map(|i| s.truth.theta[i]);
            panels.push(BoxPlot {
                title: s.name.clone(),
                y_label: name.clone(),
                groups,
                reference_lines: nominal.map(|v| vec![("nominal".to_string(), v)]).unwrap_or_default(),
                width: 520,
                height: 360,
                ..BoxPlot::default()
            });
        }
        let stem = dir.join(format!("theta_{}", file_name(name)));
        Panels {
            title: format!("estimates of {name}"),
            columns: columns_for(panels.len()),
            panels,
            ..Panels::default()
        }
        .write(&stem)?;
        stems.push(stem);
    }
    Ok(stems)
}

/// One panel per state: the truth, the measurements of that state and every estimate of one
/// replicate (`000_74b95e149527c64e.txt` Figs. 4.2, 4.6; `001_8aefdf0570c96f51.txt` Fig. 4).
pub fn path_plot(
    scenario: &Scenario,
    truth: &StatePath,
    data: &Dataset,
    estimates: &[(String, PathEstimate)],
    stem: &Path,
) -> Result<()> {
    // At most ~4000 points of the truth (the simulation grid can be much finer).
    let stride = truth.times.len().div_ceil(4000).max(1);
    let mut panels = Vec::new();
    for (j, name) in truth.names.iter().enumerate() {
        let mut series = vec![Series::line(
            "truth",
            truth.times.iter().step_by(stride).copied().collect(),
            truth.values.iter().step_by(stride).map(|r| r[j]).collect(),
        )];
        for (col, &state) in scenario.truth.observation.states.iter().enumerate() {
            if state == j {
                series.push(Series::points(
                    format!("data {}", data.names[col]),
                    data.times.clone(),
                    data.values.iter().map(|r| r[col]).collect(),
                ));
            }
        }
        for (label, e) in estimates {
            if let Some(k) = e.path.names.iter().position(|n| n == name) {
                series.push(Series::line(
                    label.clone(),
                    e.path.times.clone(),
                    e.path.values.iter().map(|r| r[k]).collect(),
                ));
            }
        }
        panels.push(LinePlot {
            title: format!("{} ({}, replicate 0)", name, scenario.name),
            x_label: "t".into(),
            y_label: name.clone(),
            series,
            ..LinePlot::default()
        });
    }
    Panels { title: String::new(), columns: 1, panels, ..Panels::default() }.write(stem)
}
