//! `onsager._onsager`: the Rust side of the Python package `onsager`.
//!
//! A thin layer over the library: models are [`Preset`]s, estimators the typed
//! [`onsager::Estimator`] built from its JSON form, comparisons [`onsager::compare::compare`],
//! experiments [`onsager::experiment::run`]. The Python layer (`python/onsager/__init__.py`)
//! normalises numpy input and turns keyword arguments into the JSON options.
//!
//! Long calls run on a worker thread while the calling thread, without the GIL, waits for the
//! result and re-attaches every [`POLL`] to check for signals: Ctrl-C raises
//! `KeyboardInterrupt` within about that time (an experiment is told to stop; an estimate is
//! left to finish on its thread, its result discarded). A panic anywhere in the library is
//! caught and raised as `RuntimeError`, never an abort.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::mpsc;
use std::time::Duration;

use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use onsager::data::{Dataset, StatePath};
use onsager::model::library::Preset;
use onsager::model::Observation;

mod estimate;
mod experiment;
mod model;

/// How often a waiting call checks for Ctrl-C.
const POLL: Duration = Duration::from_millis(50);

/// A library error as the Python exception of bad input.
fn value_error(e: onsager::Error) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// The message of a caught panic.
fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic without a message".into())
}

/// Runs `job` on a worker thread without the GIL; every [`POLL`] the calling thread checks for
/// signals, and on a pending `KeyboardInterrupt` (or any signal handler's exception) calls
/// `on_interrupt` and returns that exception without waiting for the job. A panic in the job
/// is a `RuntimeError`.
fn interruptible<T: Send + 'static>(
    py: Python<'_>,
    job: impl FnOnce() -> T + Send + 'static,
    on_interrupt: impl FnOnce(),
) -> PyResult<T> {
    let (tx, rx) = mpsc::channel();
    std::thread::Builder::new()
        .name("onsager".into())
        .spawn(move || {
            let _ = tx.send(catch_unwind(AssertUnwindSafe(job)));
        })
        .map_err(|e| PyRuntimeError::new_err(format!("cannot start a worker thread: {e}")))?;
    let mut rx = rx;
    loop {
        // The receiver travels into the GIL-free closure and back (it is Send, not Sync).
        let (back, received) = py.detach(move || {
            let r = rx.recv_timeout(POLL);
            (rx, r)
        });
        rx = back;
        match received {
            Ok(Ok(value)) => return Ok(value),
            Ok(Err(payload)) => {
                return Err(PyRuntimeError::new_err(format!(
                    "internal error in onsager (please report it): {}",
                    panic_message(payload.as_ref())
                )))
            }
            Err(mpsc::RecvTimeoutError::Timeout) => {
                if let Err(e) = py.check_signals() {
                    on_interrupt();
                    return Err(e);
                }
            }
            Err(mpsc::RecvTimeoutError::Disconnected) => {
                return Err(PyRuntimeError::new_err("internal error in onsager: the worker thread ended"))
            }
        }
    }
}

/// Runs `f`, turning a panic into a `RuntimeError` (for the short calls that stay on the
/// calling thread).
fn guarded<T>(f: impl FnOnce() -> PyResult<T>) -> PyResult<T> {
    catch_unwind(AssertUnwindSafe(f)).unwrap_or_else(|payload| {
        Err(PyRuntimeError::new_err(format!(
            "internal error in onsager (please report it): {}",
            panic_message(payload.as_ref())
        )))
    })
}

/// A measurement table from numpy: `t` (n,) and `y` (n, outputs), NaN for a missing value.
fn dataset(
    preset: &Preset,
    t: &PyReadonlyArray1<'_, f64>,
    y: &PyReadonlyArray2<'_, f64>,
) -> PyResult<Dataset> {
    let names = preset.observation.output_names();
    let (t, y) = (t.as_array(), y.as_array());
    if y.nrows() != t.len() || y.ncols() != names.len() {
        return Err(PyValueError::new_err(format!(
            "y: expected shape ({}, {}) (one row per time in t, one column per output {}), got ({}, {})",
            t.len(),
            names.len(),
            names.join(", "),
            y.nrows(),
            y.ncols()
        )));
    }
    if t.is_empty() {
        return Err(PyValueError::new_err("t: expected at least one measurement time, got none"));
    }
    if let Some(i) = t.iter().position(|v| !v.is_finite()) {
        return Err(PyValueError::new_err(format!("t: time {} (index {i}) is not finite", t[i])));
    }
    if let Some(i) = (1..t.len()).find(|&i| t[i] <= t[i - 1]) {
        return Err(PyValueError::new_err(format!(
            "t: times must be strictly increasing: t[{i}] = {} follows t[{}] = {}",
            t[i],
            i - 1,
            t[i - 1]
        )));
    }
    let values = y.rows().into_iter().map(|r| r.to_vec()).collect();
    Dataset::try_new(names, t.to_vec(), values).map_err(value_error)
}

/// A state path from numpy: `t` (n,) and `x` (n, states), for `names`.
fn state_path(
    names: Vec<String>,
    t: &PyReadonlyArray1<'_, f64>,
    x: &PyReadonlyArray2<'_, f64>,
    what: &str,
) -> PyResult<StatePath> {
    let (t, x) = (t.as_array(), x.as_array());
    if x.nrows() != t.len() || x.ncols() != names.len() {
        return Err(PyValueError::new_err(format!(
            "{what}: expected x of shape ({}, {}) (one row per time, one column per state {}), got ({}, {})",
            t.len(),
            names.len(),
            names.join(", "),
            x.nrows(),
            x.ncols()
        )));
    }
    let values = x.rows().into_iter().map(|r| r.to_vec()).collect();
    Ok(StatePath { names, times: t.to_vec(), values, sd: None })
}

/// Rows of equal length as an (n, m) numpy array (`m` columns when there are no rows).
fn matrix<'py>(py: Python<'py>, rows: &[Vec<f64>], m: usize) -> Bound<'py, PyArray2<f64>> {
    let flat: Vec<f64> = rows.iter().flatten().copied().collect();
    Array2::from_shape_vec((rows.len(), m), flat).expect("rows of equal length").into_pyarray(py)
}

/// A vector as a numpy array.
fn vector<'py>(py: Python<'py>, v: &[f64]) -> Bound<'py, PyArray1<f64>> {
    PyArray1::from_slice(py, v)
}

/// A JSON text as Python objects (dicts, lists, floats, …), by the `json` module.
fn from_json<'py>(py: Python<'py>, text: &str) -> PyResult<Bound<'py, PyAny>> {
    py.import("json")?.call_method1("loads", (text,))
}

/// A Python dict of JSON-serialisable values as a JSON object, by the `json` module (the
/// Python layer has already turned numpy scalars into numbers).
fn to_json(
    dict: Option<&Bound<'_, PyDict>>,
    what: &str,
) -> PyResult<serde_json::Map<String, serde_json::Value>> {
    let Some(dict) = dict else { return Ok(serde_json::Map::new()) };
    let text: String = dict.py().import("json")?.call_method1("dumps", (dict,))?.extract()?;
    serde_json::from_str(&text).map_err(|e| PyValueError::new_err(format!("{what}: {e}")))
}

/// The extension module.
#[pymodule]
fn _onsager(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<model::Model>()?;
    m.add_class::<model::Simulation>()?;
    m.add_class::<estimate::Estimate>()?;
    m.add_function(wrap_pyfunction!(estimate::estimate, m)?)?;
    m.add_function(wrap_pyfunction!(estimate::compare, m)?)?;
    m.add_function(wrap_pyfunction!(experiment::run_experiment, m)?)?;
    m.add_function(wrap_pyfunction!(model::builtin_models, m)?)?;
    m.add_function(wrap_pyfunction!(estimate::methods, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
