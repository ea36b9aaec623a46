//! `estimate`, `compare` and the `Estimate` they return.

use std::collections::BTreeMap;

use numpy::{PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use onsager::compare::{compare as compare_estimators, default_estimators, CompareOptions};
use onsager::estimate::{EstimationProblem, MethodRun, PathEstimate};
use onsager::estimator::{keep_set_parameters, list_from_json, parse_list, Estimator, Labelled, Method};
use onsager::model::Sde;

use crate::model::Model;
use crate::{dataset, from_json, interruptible, matrix, state_path, to_json, value_error, vector};

/// The result of an estimator: the path, its standard deviations, the parameters and the report.
#[pyclass(module = "onsager._onsager", frozen, get_all)]
pub struct Estimate {
    /// The method's name.
    method: String,
    /// Times of the path, shape (n,).
    t: Py<PyArray1<f64>>,
    /// The estimated path, shape (n, states): noisy states, then clean states.
    x: Py<PyArray2<f64>>,
    /// Standard deviations of the path, shape (n, states), or None when the method gives none.
    sd: Option<Py<PyArray2<f64>>>,
    /// State names (columns of `x`).
    states: Vec<String>,
    /// Every parameter by name: the estimate for estimated ones, the given value otherwise.
    theta: BTreeMap<String, f64>,
    /// Standard deviations of the estimated parameters by name, or None when not known.
    theta_sd: Option<BTreeMap<String, f64>>,
    /// The numerical outcome: `converged`, `acceptable`, `max-iterations`, …
    status: String,
    /// Whether the status is `converged` or `acceptable`.
    success: bool,
    /// Iterations of the method's outer loop (0 for direct methods).
    iterations: usize,
    /// Solve time in seconds.
    solve_seconds: f64,
    /// The JSON report of `onsager estimate --report`, as a dict.
    report: Py<PyAny>,
    /// Notes for the user (default choices made, what the method converges to).
    notes: Vec<String>,
}

impl Estimate {
    fn new(py: Python<'_>, run: MethodRun) -> PyResult<Estimate> {
        let e: PathEstimate = run.estimate;
        let n = e.path.names.len();
        let report =
            serde_json::to_string(&e.report()).map_err(|err| PyValueError::new_err(err.to_string()))?;
        let theta_sd = e
            .theta_sd
            .as_ref()
            .map(|sd| e.estimated.iter().zip(sd).map(|(&i, &s)| (e.theta_names[i].clone(), s)).collect());
        Ok(Estimate {
            method: e.method.name().to_string(),
            t: vector(py, &e.path.times).unbind(),
            x: matrix(py, &e.path.values, n).unbind(),
            sd: e.path.sd.as_ref().map(|sd| matrix(py, sd, n).unbind()),
            states: e.path.names.clone(),
            theta: e.theta_names.iter().cloned().zip(e.theta.iter().copied()).collect(),
            theta_sd,
            status: e.status.name().to_string(),
            success: e.status.is_success(),
            iterations: e.iterations,
            solve_seconds: e.solve_seconds,
            report: from_json(py, &report)?.unbind(),
            notes: run.notes,
        })
    }
}

#[pymethods]
impl Estimate {
    fn __repr__(&self) -> String {
        format!(
            "Estimate({}: {}, {} iterations, {:.3} s, states {})",
            self.method,
            self.status,
            self.iterations,
            self.solve_seconds,
            self.states.join(", ")
        )
    }
}

/// Parses a method name.
fn method_of(name: &str) -> PyResult<Method> {
    name.parse::<Method>().map_err(value_error)
}

/// Runs one estimator on `t`, `y` with the JSON `options` (the names of the CLI's `--option`
/// and of the experiment specs), estimating the parameters named in `estimate`.
#[pyfunction]
#[pyo3(signature = (model, t, y, method, options = None, estimate = None, seed = 1, t0 = None))]
#[allow(clippy::too_many_arguments)]
pub fn estimate(
    py: Python<'_>,
    model: &Model,
    t: PyReadonlyArray1<'_, f64>,
    y: PyReadonlyArray2<'_, f64>,
    method: &str,
    options: Option<&Bound<'_, PyDict>>,
    estimate: Option<Vec<String>>,
    seed: u64,
    t0: Option<f64>,
) -> PyResult<Estimate> {
    let method = method_of(method)?;
    let mut options = to_json(options, "options")?;
    keep_set_parameters(method, &mut options, &model.set);
    let estimator = Estimator::from_options(method, &options).map_err(value_error)?;
    let preset = model.preset.clone();
    let indices = estimate
        .unwrap_or_default()
        .iter()
        .map(|name| preset.param_index(name))
        .collect::<onsager::Result<Vec<usize>>>()
        .map_err(value_error)?;
    let data = dataset(&preset, &t, &y)?;
    let run = interruptible(
        py,
        move || {
            let base = preset.problem(&data, &indices);
            let problem = EstimationProblem { seed, t0: t0.unwrap_or(base.t0), ..base };
            problem.validate()?;
            estimator.run(&problem)
        },
        || {},
    )?
    .map_err(value_error)?;
    Estimate::new(py, run)
}

/// The estimators of `methods`: None (the defaults of `onsager compare`), a text
/// `METHOD[:NAME=VALUE,…],…`, or a list of such texts or of dicts `{"method": …,
/// "options": {…}, "label": …}`.
fn estimators(
    methods: Option<&Bound<'_, PyAny>>,
    defaults: impl FnOnce() -> Vec<Labelled>,
) -> PyResult<Vec<Labelled>> {
    let Some(methods) = methods else { return Ok(defaults()) };
    if let Ok(text) = methods.extract::<String>() {
        return parse_list(&text).map_err(value_error);
    }
    let list = methods.cast::<PyList>().map_err(|_| {
        PyValueError::new_err("methods: expected a string, a list of strings or a list of dicts")
    })?;
    if let Ok(texts) = list.extract::<Vec<String>>() {
        return parse_list(&texts.join(",")).map_err(value_error);
    }
    let wrapped = PyDict::new(list.py());
    wrapped.set_item("estimators", list)?;
    let value = serde_json::Value::Object(to_json(Some(&wrapped), "methods")?);
    list_from_json(value, "methods").map_err(value_error)
}

/// Several estimators on the same data (`onsager compare`): the rows of its `summary.json`
/// (as a JSON text) and each estimator's label and estimate (None where it could not run).
#[pyfunction]
#[pyo3(signature = (model, t, y, methods = None, truth_t = None, truth_x = None, seed = 1))]
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
pub fn compare(
    py: Python<'_>,
    model: &Model,
    t: PyReadonlyArray1<'_, f64>,
    y: PyReadonlyArray2<'_, f64>,
    methods: Option<&Bound<'_, PyAny>>,
    truth_t: Option<PyReadonlyArray1<'_, f64>>,
    truth_x: Option<PyReadonlyArray2<'_, f64>>,
    seed: u64,
) -> PyResult<(Py<PyAny>, Vec<(String, Option<Estimate>)>)> {
    let preset = model.preset.clone();
    let data = dataset(&preset, &t, &y)?;
    let truth = match (&truth_t, &truth_x) {
        (Some(tt), Some(tx)) => Some(state_path(preset.model.state_names(), tt, tx, "truth")?),
        (None, None) => None,
        _ => return Err(PyValueError::new_err("truth: expected both the times and the path, or neither")),
    };
    let list = {
        let problem = EstimationProblem { seed, ..preset.problem(&data, &[]) };
        problem.validate().map_err(value_error)?;
        estimators(methods, || default_estimators(&problem, None).0)?
    };
    let comparison = interruptible(
        py,
        move || {
            let problem = EstimationProblem { seed, ..preset.problem(&data, &[]) };
            let mut options = CompareOptions::default();
            options.barrier = preset.well_barrier();
            compare_estimators(&problem, &list, truth.as_ref(), &options)
        },
        || {},
    )?
    .map_err(value_error)?;
    let summary =
        serde_json::to_value(comparison.summary()).map_err(|e| PyValueError::new_err(e.to_string()))?;
    let rows = from_json(py, &summary["methods"].to_string())?.unbind();
    let mut estimates = Vec::with_capacity(comparison.rows.len());
    for (row, e) in comparison.rows.iter().zip(comparison.estimates) {
        let e =
            e.map(|e| Estimate::new(py, MethodRun { estimate: e, notes: row.notes.clone() })).transpose()?;
        estimates.push((row.label.clone(), e));
    }
    Ok((rows, estimates))
}

/// Every method: (name, description, option names).
#[pyfunction]
pub fn methods() -> Vec<(&'static str, &'static str, Vec<String>)> {
    Method::ALL.iter().map(|&m| (m.name(), m.description(), Estimator::option_names(m))).collect()
}
