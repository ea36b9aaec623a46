//! `run_experiment`: a built-in experiment or a spec file, as `onsager experiment run`.

use std::collections::BTreeMap;
use std::path::PathBuf;

use pyo3::prelude::*;

use onsager::experiment::{default_out, load, run, Cancel, RunOptions};

use crate::{interruptible, value_error};

/// Runs an experiment (by built-in name or TOML spec path) into `out` (default
/// `out/experiments/NAME[/quick]`); returns what it wrote: `results`, `summary` (None when
/// incomplete), `plots`, and the counts `written`, `resumed`, `total`, `complete`. Ctrl-C
/// stops the run (the rows written so far stay; `resume=True` continues it).
#[pyfunction]
#[pyo3(signature = (name_or_path, replicates = None, jobs = 0, out = None, quick = false, resume = false, seed = None, plots = true))]
#[allow(clippy::too_many_arguments)]
pub fn run_experiment(
    py: Python<'_>,
    name_or_path: &str,
    replicates: Option<usize>,
    jobs: usize,
    out: Option<PathBuf>,
    quick: bool,
    resume: bool,
    seed: Option<u64>,
    plots: bool,
) -> PyResult<BTreeMap<&'static str, Py<PyAny>>> {
    let experiment = load(name_or_path).map_err(value_error)?;
    let out = out.unwrap_or_else(|| default_out(&experiment.spec.name, quick));
    let cancel = Cancel::new();
    let mut options = RunOptions::new(out);
    options.replicates = replicates;
    options.jobs = jobs;
    options.quick = quick;
    options.resume = resume;
    options.seed = seed;
    options.plots = plots;
    options.cancel = Some(cancel.clone());
    let report = interruptible(py, move || run(&experiment, &options, &|_| {}), move || cancel.cancel())?
        .map_err(value_error)?;
    let mut d: BTreeMap<&'static str, Py<PyAny>> = BTreeMap::new();
    let path = |p: &PathBuf| p.display().to_string();
    d.insert("results", path(&report.results).into_pyobject(py)?.into_any().unbind());
    d.insert("summary", report.summary.as_ref().map(path).into_pyobject(py)?.into_any().unbind());
    d.insert(
        "plots",
        report.plots.iter().map(path).collect::<Vec<_>>().into_pyobject(py)?.into_any().unbind(),
    );
    d.insert("written", report.written.into_pyobject(py)?.into_any().unbind());
    d.insert("resumed", report.resumed.into_pyobject(py)?.into_any().unbind());
    d.insert("total", report.total.into_pyobject(py)?.into_any().unbind());
    d.insert("complete", pyo3::types::PyBool::new(py, report.complete).to_owned().into_any().unbind());
    Ok(d)
}
