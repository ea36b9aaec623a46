//! What every estimator takes and returns, so that any two can be compared on the same data.
//!
//! An estimator takes an [`EstimationProblem`] (model, measurement model, parameters, priors,
//! data) and its own options, and returns a [`PathEstimate`]: times, the estimated path (noisy
//! then clean states) with an optional standard-deviation path, the parameters (estimated or
//! fixed), a [`Status`] and a report. Misuse is an [`Error`]; a numerical outcome such as
//! non-convergence is a [`Status`] (DESIGN.md).

use std::path::Path;

use serde_json::{json, Map, Value};

use crate::data::{Dataset, StatePath};
use crate::model::prior::Prior;
use crate::model::{check_len, Observation, Sde};
pub use crate::status::Status;
use crate::{Error, Result};

/// The time of the initial-state prior that every estimator uses unless told otherwise:
/// t = 0, or the first measurement time if that is earlier.
pub fn default_initial_time(data: &Dataset) -> f64 {
    data.times.first().map_or(0.0, |&t| t.min(0.0))
}

/// Everything an estimator needs to know about the model and the data.
#[derive(Debug)]
pub struct EstimationProblem<'a, S: Sde + ?Sized, O: Observation + ?Sized> {
    /// The SDE.
    pub sde: &'a S,
    /// The measurement model.
    pub observation: &'a O,
    /// Parameter values: the fixed values, and the starting point of estimated parameters.
    pub theta: &'a [f64],
    /// Prior of each θ component (used by estimators that estimate parameters).
    pub theta_prior: &'a [Prior],
    /// Indices of the θ components to estimate (empty: all fixed).
    pub estimate: &'a [usize],
    /// Prior of each noisy initial state x0.
    pub x0_prior: &'a [Prior],
    /// Prior of each clean initial state z0.
    pub z0_prior: &'a [Prior],
    /// The measurements; columns in the order of the observation's outputs.
    pub data: &'a Dataset,
    /// Time of the initial-state priors, at or before the first measurement; every estimator
    /// starts its path here. [`default_initial_time`] is the usual choice (what
    /// [`Preset::problem`](crate::model::library::Preset::problem) sets).
    pub t0: f64,
    /// Seed of the estimators that draw random numbers (the particle smoother); each run with
    /// the same seed gives the same estimate. An experiment derives one per replicate and
    /// estimator.
    pub seed: u64,
}

impl<S: Sde + ?Sized, O: Observation + ?Sized> EstimationProblem<'_, S, O> {
    /// Checks that all the pieces agree in size, that θ is finite, that the priors are valid,
    /// that the data has the observation's outputs and at least one time, and that `t0` is
    /// finite and not after the first measurement.
    pub fn validate(&self) -> Result<()> {
        let d = self.sde.dims();
        check_len("theta", d.params, self.theta.len())?;
        check_len("theta prior", d.params, self.theta_prior.len())?;
        check_len("x0 prior", d.noisy, self.x0_prior.len())?;
        check_len("z0 prior", d.clean, self.z0_prior.len())?;
        if self.theta.iter().any(|v| !v.is_finite()) {
            return Err(Error::NonFinite { what: "theta".into() });
        }
        for &i in self.estimate {
            if i >= d.params {
                return Err(Error::InvalidOption {
                    name: "estimate".into(),
                    reason: format!("parameter index {i} is out of range (the model has {})", d.params),
                });
            }
        }
        for p in self.theta_prior.iter().chain(self.x0_prior).chain(self.z0_prior) {
            p.validate()?;
        }
        let outputs = self.observation.output_names();
        if self.data.names != outputs {
            return Err(Error::InvalidOption {
                name: "data".into(),
                reason: format!(
                    "the data's columns ({}) are not the model's outputs ({})",
                    self.data.names.join(", "),
                    outputs.join(", ")
                ),
            });
        }
        if self.data.is_empty() {
            return Err(Error::InvalidOption { name: "data".into(), reason: "has no measurements".into() });
        }
        if !(self.t0.is_finite() && self.t0 <= self.data.times[0]) {
            return Err(Error::InvalidOption {
                name: "t0".into(),
                reason: format!(
                    "the initial time must be finite and not after the first measurement at {}, got {}",
                    self.data.times[0], self.t0
                ),
            });
        }
        Ok(())
    }
}

/// The result of every estimator.
#[derive(Debug, Clone, PartialEq)]
pub struct PathEstimate {
    /// The method's name (as on the command line, e.g. `uks`, `ksp`).
    pub method: String,
    /// The estimated path (noisy then clean states) with optional standard deviations.
    pub path: StatePath,
    /// Parameter names.
    pub theta_names: Vec<String>,
    /// Parameter values: estimates for the estimated components, the given values otherwise.
    pub theta: Vec<f64>,
    /// Indices of the estimated components.
    pub estimated: Vec<usize>,
    /// Standard deviations of the estimated components (same order as `estimated`), if known.
    pub theta_sd: Option<Vec<f64>>,
    /// The numerical outcome.
    pub status: Status,
    /// Iterations of the method's outer loop (0 for direct methods).
    pub iterations: usize,
    /// Time spent solving, excluding data loading and output, in seconds.
    pub solve_seconds: f64,
    /// Method-specific report entries (log-likelihood, multipliers, residuals, …).
    pub details: Map<String, Value>,
}

impl PathEstimate {
    /// The JSON report: method, status, iterations, `solve_seconds`, θ̂ (with sd where known)
    /// and the method's details.
    pub fn report_json(&self) -> Value {
        let mut theta = Map::new();
        for (i, name) in self.theta_names.iter().enumerate() {
            let mut entry = Map::new();
            entry.insert("value".into(), json!(self.theta[i]));
            let k = self.estimated.iter().position(|&e| e == i);
            entry.insert("estimated".into(), json!(k.is_some()));
            if let (Some(k), Some(sd)) = (k, &self.theta_sd) {
                entry.insert("sd".into(), json!(sd[k]));
            }
            theta.insert(name.clone(), Value::Object(entry));
        }
        json!({
            "method": self.method,
            "status": self.status.name(),
            "iterations": self.iterations,
            "solve_seconds": self.solve_seconds,
            "theta": theta,
            "details": self.details,
        })
    }

    /// Writes [`PathEstimate::report_json`] to a file, pretty-printed.
    pub fn write_report(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        let text = serde_json::to_string_pretty(&self.report_json()).expect("a JSON value serialises");
        std::fs::write(path, text + "\n").map_err(|source| Error::Io { path: path.to_path_buf(), source })
    }
}
