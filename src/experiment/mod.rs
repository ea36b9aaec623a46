//! Monte Carlo experiments: the papers' comparisons as TOML specs, run in parallel with
//! resumable results, summaries and plots.
//!
//! An [`Experiment`] (a TOML document; [`ExperimentSpec`] per scenario) names a model — a
//! built-in one (`[model] name = "duffing"`) or a model file (`[model] file = "my-model.toml"`,
//! relative to the spec's folder) — with parameter overrides, how the true path is
//! simulated (scheme, step, horizon, initial law), how it is measured (times, the likelihood
//! that generates the data and the one the estimators use), the estimators (any
//! [`Estimator`](crate::estimator::Estimator): a method with its options, run through
//! [`Estimator::run`](crate::estimator::Estimator::run)), the metrics, the grid of scenarios, the
//! number of replicates and the seed. [`run`] simulates every (scenario, replicate) with a seed
//! derived from (seed, scenario, replicate) ([`replicate_seed`]), so the results do not depend
//! on the number of threads, and appends one row per estimator to `results.csv` as soon as it
//! finishes:
//!
//! `scenario,replicate,estimator,method,status,iterations,solve_seconds,<metrics>,theta_<p>...,message`
//!
//! A method's error is a row with status `error` and its message; a non-converged estimate is
//! a row with its status. An interrupted run resumes ([`RunOptions::resume`]) without redoing
//! or losing rows. At the end come `summary.json` ([`report::summary`]) and box plots of the
//! metrics and of θ̂ with the nominal values, plus one path plot per scenario.
//!
//! The metrics ([`Metric`]) are computed by [`crate::metrics`]: the normalised ISE of
//! `000_74b95e149527c64e.txt (4.1)`, the RMSE to the truth over the estimate's times, the RMSE
//! to another estimator of the same replicate, the fraction of time on the true well's side, the
//! mean posterior sd and the ±2 sd coverage; against the truth they are evaluated on the
//! simulation grid, or at the measurement times only (`metrics_at = "measurements"`,
//! [`MetricsAt`]), where the particle and ensemble smoothers report their paths.
//!
//! The built-in experiments ([`builtin()`], [`BUILTIN`]) reproduce the papers' Monte Carlo
//! studies; each has a quick version for tests.

pub mod builtin;
pub mod report;
pub mod runner;
pub mod shard;
pub mod slurm;
pub mod spec;

#[cfg(test)]
mod tests;

pub use builtin::{builtin, load, BUILTIN};
pub use runner::{default_out, replicate_seed, run, Cancel, Progress, Row, RunOptions, RunReport};
pub use shard::{merge, MergeOptions, MergeReport, MergeStatus, Missing, Shard};
pub use spec::{EstimatorSpec, Experiment, ExperimentSpec, Metric, MetricsAt, Scenario, ScenarioEstimator};
