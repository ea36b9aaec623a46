//! What every estimator takes and returns, so that any two can be compared on the same data.
//!
//! An estimator takes an [`EstimationProblem`] (model, measurement model, parameters, priors,
//! data) and its own options, and returns a [`PathEstimate`]: times, the estimated path (noisy
//! then clean states) with an optional standard-deviation path, the parameters (estimated or
//! fixed), a [`Status`] and a report. Misuse is an [`Error`]; a numerical outcome such as
//! non-convergence is a [`Status`] (DESIGN.md).

use std::any::Any;
use std::collections::BTreeMap;
use std::fmt;
use std::path::Path;
use std::sync::Arc;

use serde::Serialize;
use serde_json::{Map, Value};

use crate::data::{Dataset, StatePath};
pub use crate::estimator::Method;
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
    /// The memory an estimator may allocate for its own structures: each estimator estimates
    /// its needs from the problem's size before it allocates and refuses above this limit
    /// ([`Error::MemoryLimit`]). Default [`MemoryLimit::DEFAULT`] (4 GiB).
    pub max_memory: MemoryLimit,
}

/// An upper bound on the memory of an estimator's structures (grid densities, the NLP's
/// unknowns and its sparse KKT system, particles, ensemble members, covariance paths), checked
/// before they are allocated. Written `4GiB`, `512MiB`, `2GB`, `1e9` (bytes) or `unlimited`
/// (command-line flag `--max-memory`, experiment spec key `max_memory`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MemoryLimit {
    bytes: u64,
}

impl Default for MemoryLimit {
    fn default() -> MemoryLimit {
        MemoryLimit::DEFAULT
    }
}

/// Bytes as text with a binary unit (`1.5 GiB`).
pub fn format_bytes(bytes: f64) -> String {
    const UNITS: [&str; 5] = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut v = bytes;
    let mut u = 0;
    while v >= 1024.0 && u + 1 < UNITS.len() {
        v /= 1024.0;
        u += 1;
    }
    if u == 0 {
        format!("{v:.0} B")
    } else {
        format!("{v:.1} {}", UNITS[u])
    }
}

impl MemoryLimit {
    /// The default limit: 4 GiB.
    pub const DEFAULT: MemoryLimit = MemoryLimit { bytes: 4 << 30 };

    /// No limit.
    pub const UNLIMITED: MemoryLimit = MemoryLimit { bytes: u64::MAX };

    /// A limit of `bytes` bytes.
    pub fn new(bytes: u64) -> MemoryLimit {
        MemoryLimit { bytes }
    }

    /// The limit in bytes.
    pub fn bytes(self) -> u64 {
        self.bytes
    }

    /// A limit that would admit `estimate` bytes, rounded up to a power of two of GiB (for
    /// messages).
    pub fn suggestion(estimate: f64) -> f64 {
        let gib = (estimate / f64::from(1u32 << 30)).max(1.0);
        2f64.powi(gib.log2().ceil() as i32) * f64::from(1u32 << 30)
    }

    /// Parses `4GiB`, `512MiB`, `2GB`, `300kB`, `1e9` (bytes) or `unlimited`. Errors:
    /// [`Error::InvalidOption`] named `--max-memory`.
    pub fn parse(text: &str) -> Result<MemoryLimit> {
        let t = text.trim();
        if t.eq_ignore_ascii_case("unlimited") || t.eq_ignore_ascii_case("none") {
            return Ok(MemoryLimit::UNLIMITED);
        }
        let split = t.find(|c: char| c.is_ascii_alphabetic() && c != 'e' && c != 'E').unwrap_or(t.len());
        let (number, unit) = t.split_at(split);
        let scale: f64 = match unit.trim().to_ascii_lowercase().as_str() {
            "" | "b" => 1.0,
            "k" | "kb" => 1e3,
            "m" | "mb" => 1e6,
            "g" | "gb" => 1e9,
            "t" | "tb" => 1e12,
            "kib" => 1024.0,
            "mib" => 1024f64.powi(2),
            "gib" => 1024f64.powi(3),
            "tib" => 1024f64.powi(4),
            other => {
                return Err(Error::invalid(
                    "--max-memory",
                    format!(
                        "unknown unit `{other}` in `{t}` (use B, kB, MB, GB, KiB, MiB, GiB or `unlimited`)"
                    ),
                ))
            }
        };
        let value: f64 = number.trim().parse().map_err(|_| {
            Error::invalid(
                "--max-memory",
                format!("cannot read `{t}` as a size (e.g. `4GiB`, `512MB`, `1e9`)"),
            )
        })?;
        let bytes = value * scale;
        if !(bytes.is_finite() && bytes >= 1.0) {
            return Err(Error::invalid("--max-memory", format!("must be a positive size, got `{t}`")));
        }
        Ok(MemoryLimit { bytes: if bytes >= u64::MAX as f64 { u64::MAX } else { bytes as u64 } })
    }

    /// Checks that `estimate` bytes (for `what`, whose sizes are `size`) fit in the limit.
    /// Errors: [`Error::MemoryLimit`] naming `what`, the size, the estimate and the limit.
    pub fn check(self, what: &str, size: impl fmt::Display, estimate: f64) -> Result<()> {
        if estimate.is_nan() || estimate > self.bytes as f64 {
            return Err(Error::MemoryLimit {
                what: what.to_string(),
                size: size.to_string(),
                estimate,
                limit: self.bytes,
            });
        }
        Ok(())
    }
}

impl fmt::Display for MemoryLimit {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.bytes == u64::MAX {
            f.write_str("unlimited")
        } else {
            f.write_str(&format_bytes(self.bytes as f64).replace(".0 ", "").replace(' ', ""))
        }
    }
}

impl std::str::FromStr for MemoryLimit {
    type Err = Error;

    fn from_str(s: &str) -> Result<MemoryLimit> {
        MemoryLimit::parse(s)
    }
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

/// The method-specific part of an estimate's report: a typed struct of its estimator (e.g.
/// [`crate::kalman::KalmanDetails`], read back with [`Details::get`]), written as the report's
/// `details` object (read by key with `details["log_likelihood"]`).
#[derive(Clone, Default)]
pub struct Details(Option<Arc<Written>>);

/// Typed details with their JSON form.
struct Written {
    typed: Box<dyn Typed>,
    json: Map<String, Value>,
}

/// A details struct behind the type erasure: readable back as itself, printable.
trait Typed: Any + fmt::Debug + Send + Sync {
    fn as_any(&self) -> &dyn Any;
}

impl<T: Any + fmt::Debug + Send + Sync> Typed for T {
    fn as_any(&self) -> &dyn Any {
        self
    }
}

impl Details {
    /// Details from a typed struct (serialised as a JSON object; non-finite numbers are null).
    pub fn new<T: Serialize + fmt::Debug + Send + Sync + 'static>(details: T) -> Details {
        let json = match serde_json::to_value(&details) {
            Ok(Value::Object(map)) => map,
            _ => Map::new(),
        };
        Details(Some(Arc::new(Written { typed: Box::new(details), json })))
    }

    /// The typed details, when they are a `T`.
    pub fn get<T: 'static>(&self) -> Option<&T> {
        // Through `&dyn Typed`: the box itself is `Typed` too, and its `as_any` is not the content's.
        let typed: &dyn Typed = &*self.0.as_ref()?.typed;
        typed.as_any().downcast_ref::<T>()
    }

    /// The details as a JSON object (empty when there are none).
    pub fn json(&self) -> &Map<String, Value> {
        static EMPTY: std::sync::OnceLock<Map<String, Value>> = std::sync::OnceLock::new();
        match &self.0 {
            Some(w) => &w.json,
            None => EMPTY.get_or_init(Map::new),
        }
    }

    /// Why an estimate ended short, as the details say it: the dual's reason (`dual_reason`),
    /// then where and why a sweep failed (`sweep_failure`), each with its key, when present.
    pub fn failure_reasons(&self) -> Vec<(&'static str, &str)> {
        ["dual_reason", "sweep_failure"]
            .into_iter()
            .filter_map(|key| Some((key, self.json().get(key)?.as_str()?)))
            .collect()
    }

    /// Whether the JSON form has the entry `key`.
    pub fn contains_key(&self, key: &str) -> bool {
        self.json().contains_key(key)
    }
}

impl std::ops::Index<&str> for Details {
    type Output = Value;

    /// The JSON value of entry `key` (null when absent).
    fn index(&self, key: &str) -> &Value {
        self.json().get(key).unwrap_or(&Value::Null)
    }
}

impl fmt::Debug for Details {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.0 {
            Some(w) => w.typed.fmt(f),
            None => f.write_str("Details(none)"),
        }
    }
}

impl PartialEq for Details {
    fn eq(&self, other: &Details) -> bool {
        self.json() == other.json()
    }
}

impl Serialize for Details {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> std::result::Result<S::Ok, S::Error> {
        self.json().serialize(serializer)
    }
}

/// The result of every estimator.
#[derive(Debug, Clone, PartialEq)]
pub struct PathEstimate {
    /// The method.
    pub method: Method,
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
    /// The method's own report entries (log-likelihood, multipliers, residuals, …).
    pub details: Details,
}

/// One parameter in a [`Report`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ThetaReport {
    /// Its value (the estimate, or the given value).
    pub value: f64,
    /// Whether it was estimated.
    pub estimated: bool,
    /// Its standard deviation, when estimated and known.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sd: Option<f64>,
}

/// The JSON report of an estimate (`onsager estimate --report`; schema in `docs/results.md`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Report<'a> {
    /// The method.
    pub method: Method,
    /// The numerical outcome.
    pub status: Status,
    /// Iterations of the method's outer loop.
    pub iterations: usize,
    /// Solve time in seconds.
    pub solve_seconds: f64,
    /// Every parameter by name.
    pub theta: BTreeMap<&'a str, ThetaReport>,
    /// The method's own entries.
    pub details: &'a Details,
    /// Why the path is partial ([`PathEstimate::partial`]); absent when it is complete.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub partial: Option<String>,
}

impl PathEstimate {
    /// The report: method, status, iterations, `solve_seconds`, θ (with the sd of the estimated
    /// components where known) and the method's details.
    pub fn report(&self) -> Report<'_> {
        let theta = self
            .theta_names
            .iter()
            .enumerate()
            .map(|(i, name)| {
                let k = self.estimated.iter().position(|&e| e == i);
                let sd = k.and_then(|k| self.theta_sd.as_ref().map(|sd| sd[k]));
                (name.as_str(), ThetaReport { value: self.theta[i], estimated: k.is_some(), sd })
            })
            .collect();
        Report {
            method: self.method,
            status: self.status,
            iterations: self.iterations,
            solve_seconds: self.solve_seconds,
            theta,
            details: &self.details,
            partial: self.partial(),
        }
    }

    /// Why the path is partial, when it is: a filter that failed at a time (its details'
    /// `failed_at`: the path stops there), or a smoother that failed (`smoother`: the path is the
    /// filtered one, not the smoothed one). `None` for a complete path.
    pub fn partial(&self) -> Option<String> {
        let d = &self.details;
        if let Some(t) = d["failed_at"].as_f64() {
            return Some(format!("`{}` failed at t = {t}: the path stops before it", self.method));
        }
        // The Kalman-type smoothers report why their backward pass failed under `smoother`
        // ([`crate::kalman::SmootherFailure`]); the particle smoother names its algorithm there.
        let kalman =
            matches!(self.method, Method::Eks | Method::Uks | Method::Pem | Method::GaussianKspClosure);
        if kalman && !d["smoother"].is_null() {
            return Some(format!(
                "the smoother of `{}` failed ({}): the path is the filtered one, not smoothed",
                self.method, d["smoother"]
            ));
        }
        None
    }

    /// Writes [`PathEstimate::report`] to a file as pretty-printed JSON.
    pub fn write_report(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        let text = serde_json::to_string_pretty(&self.report()).expect("a report serialises");
        std::fs::write(path, text + "\n").map_err(|source| Error::Io { path: path.to_path_buf(), source })
    }
}

/// How one estimator's run on one problem ended: with an estimate and its numerical status, or
/// with an error (bad input for that estimator). Written as the status's name or `error`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RowStatus {
    /// The estimator ran; its estimate's status.
    Finished(Status),
    /// The estimator could not run (the row's message says why).
    Error,
}

impl RowStatus {
    /// Whether the row holds a usable estimate (converged or acceptable).
    pub fn is_success(self) -> bool {
        matches!(self, RowStatus::Finished(s) if s.is_success())
    }

    /// The name written in tables: the status's name, or `error`.
    pub fn name(self) -> &'static str {
        match self {
            RowStatus::Finished(s) => s.name(),
            RowStatus::Error => "error",
        }
    }
}

impl fmt::Display for RowStatus {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for RowStatus {
    type Err = Error;

    /// Parses a name written by [`RowStatus::name`].
    fn from_str(s: &str) -> Result<RowStatus> {
        if s == "error" {
            return Ok(RowStatus::Error);
        }
        Status::ALL.iter().find(|st| st.name() == s).map(|&st| RowStatus::Finished(st)).ok_or_else(|| {
            Error::UnknownName {
                kind: "status".into(),
                name: s.into(),
                known: Status::ALL
                    .iter()
                    .map(|st| st.name().to_string())
                    .chain(["error".to_string()])
                    .collect(),
            }
        })
    }
}

impl Serialize for RowStatus {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> std::result::Result<S::Ok, S::Error> {
        serializer.serialize_str(self.name())
    }
}

/// Marks `estimate` [`Status::Degenerate`] (when it ended as a success) if an estimated
/// parameter sits on a bound of its prior (`theta_prior`; within 10⁻⁶ (1 + |bound|)) or its
/// standard deviation is not finite or above 10⁴ max(1, |θᵢ|) (a near-singular Hessian at the
/// solution), with one note per parameter naming it. Returns whether it did.
pub fn flag_degenerate(estimate: &mut PathEstimate, theta_prior: &[Prior], notes: &mut Vec<String>) -> bool {
    let mut reasons = Vec::new();
    for (k, &i) in estimate.estimated.iter().enumerate() {
        let (v, p, name) = (estimate.theta[i], &theta_prior[i], &estimate.theta_names[i]);
        let near = |b: f64| b.is_finite() && (v - b).abs() <= 1e-6 * (1.0 + b.abs());
        if near(p.lower) || near(p.upper) {
            let bound = if near(p.lower) { p.lower } else { p.upper };
            reasons.push(format!("`{name}` = {v} ran to the bound {bound} of its prior"));
            continue;
        }
        if let Some(sd) = estimate.theta_sd.as_ref().map(|sd| sd[k]) {
            if !(sd.is_finite() && sd <= 1e4 * v.abs().max(1.0)) {
                reasons.push(format!(
                    "`{name}` = {v} has standard deviation {sd} (the Hessian at the solution is near singular)"
                ));
            }
        }
    }
    if reasons.is_empty() || !estimate.status.is_success() {
        return false;
    }
    estimate.status = Status::Degenerate;
    for r in reasons {
        notes.push(format!("degenerate estimate: {r}"));
    }
    true
}

/// An estimate with the notes a user should read (what a transcription converges to, the
/// default grid chosen, a skipped computation). The library does not print them; the CLI does.
#[derive(Debug, Clone, PartialEq)]
pub struct MethodRun {
    /// The estimate.
    pub estimate: PathEstimate,
    /// Notes for the user.
    pub notes: Vec<String>,
}

impl From<PathEstimate> for MethodRun {
    fn from(estimate: PathEstimate) -> MethodRun {
        MethodRun { estimate, notes: Vec::new() }
    }
}

/// Progress of a long estimate, for a front end that shows it (the command line's progress line
/// on a terminal). The library never prints: an estimate run through
/// [`Estimator::run_observed`](crate::estimator::Estimator::run_observed) calls the observer
/// from its iterations, on the calling thread; an estimate run otherwise costs one thread-local
/// look-up per iteration.
pub mod progress {
    use std::cell::RefCell;
    use std::sync::Arc;

    /// What an estimator reports as it runs.
    #[derive(Debug, Clone, Copy, PartialEq)]
    #[non_exhaustive]
    pub enum ProgressEvent {
        /// An iteration of the interior-point NLP (`jme`, `mee`, `ksp-closure`,
        /// `double-exp-closure`) or of the dual maximisation (`gaussian-closure`, `exp-closure`,
        /// `mean-optimal`) begins: its number (0 for the starting point of the NLP, counting
        /// from 1 for the dual's Newton steps) and its merit (the NLP's objective; the dual's
        /// optimality residual max_m |λ_m − (r_m − z_m)/R_m|).
        Iteration {
            /// The iteration's number; it restarts at each solve of a run that solves more
            /// than one problem.
            iteration: usize,
            /// The merit at the iteration's start.
            merit: f64,
        },
    }

    /// An observer of [`ProgressEvent`]s.
    pub type Observer = Arc<dyn Fn(ProgressEvent) + Send + Sync>;

    thread_local! {
        static OBSERVER: RefCell<Option<Observer>> = const { RefCell::new(None) };
    }

    /// Runs `f` with `observer` receiving the events of this thread (the previous observer, if
    /// any, comes back afterwards, also when `f` panics).
    pub fn observe<R>(observer: Observer, f: impl FnOnce() -> R) -> R {
        struct Restore(Option<Observer>);
        impl Drop for Restore {
            fn drop(&mut self) {
                let previous = self.0.take();
                OBSERVER.with(|o| *o.borrow_mut() = previous);
            }
        }
        let _restore = Restore(OBSERVER.with(|o| o.borrow_mut().replace(observer)));
        f()
    }

    /// Sends `event` to the observer of this thread, if any (no allocation).
    pub fn emit(event: ProgressEvent) {
        OBSERVER.with(|o| {
            if let Some(observer) = o.borrow().as_ref() {
                observer(event);
            }
        });
    }
}
