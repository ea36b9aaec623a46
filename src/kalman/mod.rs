//! Kalman-type baselines: the continuous-discrete extended and unscented Kalman filters
//! (EKF, UKF), their Rauch–Tung–Striebel smoothers (EKS, UKS), and the prediction error method
//! (PEM) — the estimators `002_3b89776223eca539.txt` Sec. 4 and `000_74b95e149527c64e.txt`
//! Sec. 4.1 compare the MAP path with.
//! The ensemble Kalman filter and smoother (EnKF/EnKS, [`enks()`]) share their assumptions on
//! the measurements (Gaussian errors) and their integration step; they are documented in their
//! own module.
//!
//! # Model and approximations
//!
//! The state s = (x, z) follows ds = a(t, s, θ) dt + B dW with a = (f, h) and B = (G(θ); 0)
//! (`000_74b95e149527c64e.txt (2.4)`; clean states have zero noise rows). Between measurement
//! times the filters integrate Gaussian moment ODEs with the classical fourth-order Runge–Kutta
//! method on a grid of step at most [`KalmanOptions::dt`]:
//!
//! - **extended** (Jazwinski 1970, Sec. 9.3): ṁ = a(t, m), Ṗ = F P + P Fᵀ + B Bᵀ,
//!   F = ∂a/∂s(t, m) by automatic differentiation;
//! - **unscented** (Särkkä 2007, eqs. (18)–(19)): ṁ = E[a(t, S)], Ṗ = E[(S − m) a(t, S)ᵀ] +
//!   E[a(t, S)(S − m)ᵀ] + B Bᵀ with the expectations over N(m, P) by sigma points
//!   ([`UnscentedParams`]; the default is the spherical cubature rule of Arasaratnam, Haykin &
//!   Hurd 2010, of which these ODEs are the small-step limit of the discretised prediction).
//!
//! At a measurement time t_k the Gaussian measurement y_k = s_i + N(0, σ²) of the selected
//! states ([`StateMeasurement`]) is assimilated by the Kalman update (exact for both filters,
//! the measurement function being linear); missing (NaN) components are skipped. The
//! prediction-error log-likelihood Σ_k ln N(ν_k; 0, S_k) is reported (Kristensen, Madsen &
//! Jørgensen 2004, eq. (9)).
//!
//! The smoothers run the Rauch–Tung–Striebel backward pass on the integration grid with the
//! cross-covariance Cov(s_j, s_{j+1}) = P_j Φ_jᵀ, where Φ̇ = F Φ is integrated with the moments
//! (F the Jacobian for the EKS, the statistical linearisation Mᵀ P⁻¹ for the UKS — the backward
//! correction of Särkkä 2008). On a linear SDE both filters and smoothers reproduce the exact
//! Kalman filter and RTS smoother ([`linear`]) up to the Runge–Kutta error O(dt⁴).
//!
//! # Assumptions (checked)
//!
//! - Gaussian measurement errors: any other [`Noise`](crate::model::observation::Noise) is an
//!   [`Error::InvalidOption`] (name `likelihood`) — never a silent moment match.
//! - Unbounded Gaussian initial-state priors (an [`Error::InvalidOption`], name `x0-prior`,
//!   otherwise), placed at the problem's initial time `t0`.
//!
//! References: A. H. Jazwinski, *Stochastic Processes and Filtering Theory*, 1970;
//! S. Särkkä, "On unscented Kalman filtering for state estimation of continuous-time nonlinear
//! systems", IEEE TAC 52(9), 2007; S. Särkkä, "Unscented Rauch–Tung–Striebel smoother", IEEE
//! TAC 53(3), 2008; I. Arasaratnam, S. Haykin, T. R. Hurd, "Cubature Kalman filtering for
//! continuous-discrete systems", IEEE TSP 58(10), 2010; N. R. Kristensen, H. Madsen,
//! S. B. Jørgensen, "Parameter estimation in stochastic grey-box models", Automatica 40, 2004.

mod dense;
mod enks;
mod filter;
pub mod gaussian_ksp;
pub mod linear;
pub mod pem;

#[cfg(test)]
mod tests;

use std::time::Instant;

use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

use crate::data::StatePath;
use crate::estimate::{Details, EstimationProblem, Method, MethodRun, PathEstimate, Status};
use crate::estimator::EstimatorOptions;
use crate::model::observation::StateMeasurement;
use crate::model::Sde;
use crate::{Error, Result};

pub use enks::{enks, ensemble_smoother, EnksDetails, EnksOptions, EnksSmoothing};
pub use gaussian_ksp::{gaussian_ksp, ExpectationRule, GaussianKspOptions};
pub use onsager_closures::GaussianRule;
pub use pem::{pem, PemDetails, PemOptions};

pub(crate) use filter::{build_nodes, Node};

/// A Gaussian law: mean and covariance (states in the order noisy then clean).
#[derive(Debug, Clone, PartialEq)]
pub struct Gaussian {
    /// The mean.
    pub mean: Vec<f64>,
    /// The covariance.
    pub cov: DMatrix<f64>,
}

impl Gaussian {
    /// The marginal standard deviations √diag(cov).
    pub fn sd(&self) -> Vec<f64> {
        self.cov.diagonal().iter().map(|v| v.max(0.0).sqrt()).collect()
    }
}

/// The sigma points of the unscented filter for an n-dimensional state: the centre m and
/// m ± √(n + λ) L eⱼ (P = L Lᵀ), λ = α²(n + κ) − n, with mean weights λ/(n + λ) (centre) and
/// 1/(2(n + λ)) (the others) (Julier & Uhlmann 2004; Särkkä 2008, eq. (5)). The covariance
/// weight β of the centre point does not enter the moment ODEs (the centre has zero deviation)
/// and is therefore not a parameter.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct UnscentedParams {
    /// Spread α > 0. Default 1.
    pub alpha: f64,
    /// κ, with n + λ = α²(n + κ) > 0 required. Default 0: with α = 1 the spherical cubature
    /// rule of Arasaratnam, Haykin & Hurd (2010), 2n equally weighted points.
    pub kappa: f64,
}

impl Default for UnscentedParams {
    fn default() -> Self {
        UnscentedParams { alpha: 1.0, kappa: 0.0 }
    }
}

impl UnscentedParams {
    /// (centre weight, weight of each other point, √(n + λ)) for an n-dimensional state.
    fn weights(&self, n: usize) -> (f64, f64, f64) {
        let nf = n as f64;
        let c = self.alpha * self.alpha * (nf + self.kappa);
        let lambda = c - nf;
        (lambda / c, 0.5 / c, c.sqrt())
    }

    /// Checks α > 0 and α²(n + κ) > 0, both finite ([`Error::InvalidOption`]).
    pub fn validate(&self, n: usize) -> Result<()> {
        let c = self.alpha * self.alpha * (n as f64 + self.kappa);
        if !(self.alpha > 0.0 && self.alpha.is_finite() && c > 0.0 && c.is_finite()) {
            return Err(Error::InvalidOption {
                name: "unscented".into(),
                reason: format!(
                    "need alpha > 0 and alpha^2 (n + kappa) > 0 for n = {n}, got alpha = {}, kappa = {}",
                    self.alpha, self.kappa
                ),
            });
        }
        Ok(())
    }
}

/// Options of the Kalman filters and smoothers (the options of `ukf` and `uks`; `ekf` and `eks`
/// take [`ExtendedOptions`]).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(default)]
#[non_exhaustive]
pub struct KalmanOptions {
    /// Largest Runge–Kutta step of the moment ODEs; each interval between consecutive times
    /// is split into equal steps. Default (`None`): a tenth of the median interval between
    /// the initial time and the measurement times (the lower median, so that a few nearly
    /// coincident times do not force a tiny step everywhere), and at most 0.01.
    pub dt: Option<f64>,
    /// Sigma points of the unscented methods (written as the options `alpha` and `kappa`).
    #[serde(flatten)]
    pub unscented: UnscentedParams,
}

/// Checks an optional integration step: positive and finite.
fn check_dt(dt: Option<f64>) -> Result<()> {
    crate::error::check_positive("dt", dt)
}

impl EstimatorOptions for KalmanOptions {
    /// `ukf` or `uks`: [`estimate`].
    fn run<S: Sde + ?Sized>(
        &self,
        method: Method,
        problem: &EstimationProblem<'_, S, StateMeasurement>,
    ) -> Result<MethodRun> {
        let m = if method == Method::Ukf { KalmanMethod::Ukf } else { KalmanMethod::Uks };
        estimate(problem, m, self).map(MethodRun::from)
    }

    /// Checks `dt` (positive, finite) and α (positive, finite), κ (finite); α²(n + κ) > 0 is
    /// checked against the model's dimension when the filter runs.
    fn validate(&self) -> Result<()> {
        check_dt(self.dt)?;
        let u = self.unscented;
        crate::error::check_positive("alpha", u.alpha)?;
        if !u.kappa.is_finite() {
            return Err(Error::InvalidOption {
                name: "kappa".into(),
                reason: format!("must be finite, got {}", u.kappa),
            });
        }
        Ok(())
    }
}

/// Options of the extended Kalman filter and smoother (`ekf`, `eks`).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(default)]
#[non_exhaustive]
pub struct ExtendedOptions {
    /// Largest Runge–Kutta step of the moment ODEs (see [`KalmanOptions::dt`]). Default: a
    /// tenth of the median interval between the measurement times, at most 0.01.
    pub dt: Option<f64>,
}

impl ExtendedOptions {
    /// The filter options.
    pub fn kalman(&self) -> KalmanOptions {
        KalmanOptions { dt: self.dt, unscented: UnscentedParams::default() }
    }
}

impl EstimatorOptions for ExtendedOptions {
    /// `ekf` or `eks`: [`estimate`].
    fn run<S: Sde + ?Sized>(
        &self,
        method: Method,
        problem: &EstimationProblem<'_, S, StateMeasurement>,
    ) -> Result<MethodRun> {
        let m = if method == Method::Ekf { KalmanMethod::Ekf } else { KalmanMethod::Eks };
        estimate(problem, m, &self.kalman()).map(MethodRun::from)
    }

    /// Checks `dt` (positive, finite).
    fn validate(&self) -> Result<()> {
        check_dt(self.dt)
    }
}

/// Why a smoother ends `numerical-failure` after its filter succeeded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum SmootherFailure {
    /// A predicted covariance of the filter is singular, so the RTS gain does not exist.
    #[serde(rename = "a predicted covariance is singular")]
    SingularPrediction,
    /// The UKS at the PEM's estimate failed.
    #[serde(rename = "the UKS failed at the estimate")]
    FailedAtEstimate,
}

/// The details of a Kalman estimate's report.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct KalmanDetails {
    /// The filter's log-likelihood of the data (NaN when it failed).
    pub log_likelihood: f64,
    /// The integration step.
    pub dt: f64,
    /// The initial time.
    pub t0: f64,
    /// Points of the integration grid.
    pub grid_points: usize,
    /// The time at which the filter failed, if it did.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub failed_at: Option<f64>,
    /// Why the smoother failed, if it did.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub smoother: Option<SmootherFailure>,
}

impl KalmanOptions {
    /// Sets the largest integration step.
    pub fn with_dt(mut self, dt: f64) -> Self {
        self.dt = Some(dt);
        self
    }

    /// Sets the sigma-point parameters.
    pub fn with_unscented(mut self, unscented: UnscentedParams) -> Self {
        self.unscented = unscented;
        self
    }

    /// The integration step from `t0` over the measurement `times`: [`KalmanOptions::dt`] or
    /// its default.
    pub fn step(&self, t0: f64, times: &[f64]) -> f64 {
        self.dt.unwrap_or_else(|| default_step(t0, times))
    }
}

/// A tenth of the (lower) median positive interval between `t0` and the `times`, at most
/// 0.01. Intervals shorter than the step get one step each.
pub(crate) fn default_step(t0: f64, times: &[f64]) -> f64 {
    let mut intervals: Vec<f64> = std::iter::once(t0)
        .chain(times.iter().copied())
        .collect::<Vec<f64>>()
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|&d| d > 0.0)
        .collect();
    if intervals.is_empty() {
        return 0.01;
    }
    intervals.sort_by(f64::total_cmp);
    (intervals[(intervals.len() - 1) / 2] / 10.0).min(0.01)
}

/// The four Kalman estimators of the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum KalmanMethod {
    /// Continuous-discrete extended Kalman filter (`ekf`).
    Ekf,
    /// Extended Rauch–Tung–Striebel smoother (`eks`).
    Eks,
    /// Continuous-discrete unscented Kalman filter (`ukf`).
    Ukf,
    /// Unscented Rauch–Tung–Striebel smoother (`uks`).
    Uks,
}

impl KalmanMethod {
    /// The method's name as on the command line.
    pub fn name(self) -> &'static str {
        self.method().name()
    }

    /// The estimator's method.
    pub fn method(self) -> Method {
        match self {
            KalmanMethod::Ekf => Method::Ekf,
            KalmanMethod::Eks => Method::Eks,
            KalmanMethod::Ukf => Method::Ukf,
            KalmanMethod::Uks => Method::Uks,
        }
    }

    fn is_unscented(self) -> bool {
        matches!(self, KalmanMethod::Ukf | KalmanMethod::Uks)
    }

    fn is_smoother(self) -> bool {
        matches!(self, KalmanMethod::Eks | KalmanMethod::Uks)
    }
}

/// The moment approximation of a filter run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Approximation {
    /// Linearisation about the mean (EKF/EKS).
    Extended,
    /// Sigma points (UKF/UKS).
    Unscented(UnscentedParams),
    /// Expectations over N(m, P) by a Gauss–Hermite tensor rule or a spherical–radial cubature
    /// rule (the Gaussian KSP closure, [`gaussian_ksp`]).
    Quadrature(GaussianRule),
}

impl Approximation {
    /// The filter's rule for an `n`-dimensional state. Errors: [`Error::InvalidOption`] (name
    /// `gaussian_points`) for a Gauss–Hermite rule with no points or too many nodes.
    fn rule(self, n: usize) -> Result<filter::Rule> {
        Ok(match self {
            Approximation::Extended => filter::Rule::Extended,
            Approximation::Unscented(u) => filter::Rule::Unscented(u),
            Approximation::Quadrature(rule) => {
                let family =
                    onsager_closures::Gaussian::try_new(n).and_then(|g| g.with_rule(rule)).map_err(|e| {
                        Error::InvalidOption {
                            name: "gaussian_points".into(),
                            reason: format!("no quadrature rule {rule:?} for {n} states: {e}"),
                        }
                    })?;
                filter::Rule::Quadrature(std::sync::Arc::new(family.standard_rule().clone()))
            }
        })
    }
}

/// A filter pass: the predicted and filtered moments on the integration grid (the initial
/// time, the Runge–Kutta points and the measurement times).
#[derive(Debug, Clone)]
pub struct KalmanRun {
    /// Grid times.
    pub times: Vec<f64>,
    /// Whether a measurement was assimilated at each grid time.
    pub measured: Vec<bool>,
    /// Predicted moments (before the measurement update; the prior at the first time).
    pub predicted: Vec<Gaussian>,
    /// Filtered moments (after the measurement update, if any).
    pub filtered: Vec<Gaussian>,
    /// The prediction-error log-likelihood Σ_k ln N(ν_k; 0, S_k).
    pub log_likelihood: f64,
    /// [`Status::Converged`], or [`Status::NumericalFailure`] when a covariance stopped being
    /// positive definite (the moments then end at the failure).
    pub status: Status,
    /// The time of the numerical failure, if any.
    pub failed_at: Option<f64>,
    /// The integration step used (the largest; each interval has equal steps).
    pub dt: f64,
    phi: Vec<DMatrix<f64>>,
}

impl KalmanRun {
    /// The Rauch–Tung–Striebel smoothed moments on the same grid (see the module
    /// documentation). `None` when the filter failed or a predicted covariance is singular.
    pub fn smooth(&self) -> Option<Vec<Gaussian>> {
        if self.failed_at.is_some() {
            return None;
        }
        let store = filter::Store {
            times: self.times.clone(),
            measured: self.measured.clone(),
            predicted: self.predicted.clone(),
            filtered: self.filtered.clone(),
            phi: self.phi.clone(),
        };
        filter::smooth(&store).ok()
    }
}

/// Checks the parts of a problem the Kalman methods use and returns the filter setup.
fn setup<S: Sde + ?Sized>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    theta: &[f64],
    options: &KalmanOptions,
    method: &str,
) -> Result<filter::Setup> {
    problem.validate()?;
    filter::Setup::new(problem, theta, problem.t0, options.step(problem.t0, &problem.data.times), method)
}

/// Runs the continuous-discrete filter `approximation` at θ = `theta` (not
/// `problem.theta`, so that the PEM can filter at its estimate; `problem.estimate` is
/// ignored).
///
/// Errors: those of [`EstimationProblem::validate`]; [`Error::InvalidOption`] for a
/// non-Gaussian likelihood (name `likelihood`), a non-Gaussian initial-state prior (`x0-prior`),
/// a bad step, initial time or sigma-point parameters; [`Error::SingularDiffusion`].
pub fn filter<S: Sde + ?Sized>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    theta: &[f64],
    approximation: Approximation,
    options: &KalmanOptions,
) -> Result<KalmanRun> {
    let name = match approximation {
        Approximation::Extended => "ekf",
        Approximation::Unscented(_) => "ukf",
        Approximation::Quadrature(_) => "gaussian-ksp-closure",
    };
    filter_named(problem, theta, approximation, options, name)
}

/// [`filter`], naming `method` in error messages.
fn filter_named<S: Sde + ?Sized>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    theta: &[f64],
    approximation: Approximation,
    options: &KalmanOptions,
    name: &str,
) -> Result<KalmanRun> {
    let mut full = problem.theta.to_vec();
    crate::model::check_len("theta", full.len(), theta.len())?;
    full.copy_from_slice(theta);
    if let Approximation::Unscented(u) = approximation {
        u.validate(problem.sde.dims().states())?;
    }
    let setup = setup(problem, &full, options, name)?;
    let rule = approximation.rule(setup.states)?;
    let mut store = filter::Store::default();
    let result = filter::run(problem.sde, &setup, problem.data, &rule, &full, Some(&mut store));
    let (log_likelihood, status, failed_at) = match result {
        Ok(ll) => (ll, Status::Converged, None),
        Err(t) => (f64::NAN, Status::NumericalFailure, Some(t)),
    };
    let filter::Store { times, measured, predicted, filtered, phi } = store;
    Ok(KalmanRun {
        times,
        measured,
        predicted,
        filtered,
        log_likelihood,
        status,
        failed_at,
        dt: options.step(problem.t0, &problem.data.times),
        phi,
    })
}

/// The state path of a list of Gaussian moments.
fn path_of(names: Vec<String>, times: &[f64], moments: &[Gaussian]) -> StatePath {
    StatePath {
        names,
        times: times[..moments.len()].to_vec(),
        values: moments.iter().map(|g| g.mean.clone()).collect(),
        sd: Some(moments.iter().map(Gaussian::sd).collect()),
    }
}

/// `problem.estimate` must be empty for methods that do not estimate parameters.
fn no_estimated_parameters<S: Sde + ?Sized>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    method: &str,
) -> Result<()> {
    if problem.estimate.is_empty() {
        Ok(())
    } else {
        Err(Error::InvalidOption {
            name: "estimate".into(),
            reason: format!(
                "`{method}` does not estimate parameters; use `pem` to estimate them with the UKF"
            ),
        })
    }
}

/// Runs the EKF, EKS, UKF or UKS at `problem.theta` and returns the filtered or smoothed
/// path on the integration grid, with standard deviations. The report's details hold the
/// log-likelihood, the step, the initial time and (after a failure) `failed_at`.
///
/// Errors: those of [`filter`]; [`Error::InvalidOption`] (name `estimate`) when
/// `problem.estimate` is not empty (use [`pem()`]).
pub fn estimate<S: Sde + ?Sized>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    method: KalmanMethod,
    options: &KalmanOptions,
) -> Result<PathEstimate> {
    let approximation = if method.is_unscented() {
        Approximation::Unscented(options.unscented)
    } else {
        Approximation::Extended
    };
    estimate_with(problem, method.method(), approximation, options, method.is_smoother())
}

/// The filtered (or, when `smoother`, the RTS-smoothed) path of `approximation` at
/// `problem.theta`, reported as `method`.
fn estimate_with<S: Sde + ?Sized>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    method: Method,
    approximation: Approximation,
    options: &KalmanOptions,
    smoother: bool,
) -> Result<PathEstimate> {
    no_estimated_parameters(problem, method.name())?;
    let start = Instant::now();
    let run = filter_named(problem, problem.theta, approximation, options, method.name())?;
    let mut status = run.status;
    let mut details = run_details(&run, problem.t0);
    let moments = if smoother && run.failed_at.is_none() {
        match run.smooth() {
            Some(s) => s,
            None => {
                status = Status::NumericalFailure;
                details.smoother = Some(SmootherFailure::SingularPrediction);
                run.filtered.clone()
            }
        }
    } else {
        run.filtered.clone()
    };
    Ok(PathEstimate {
        method,
        path: path_of(problem.sde.state_names(), &run.times, &moments),
        theta_names: problem.sde.param_names(),
        theta: problem.theta.to_vec(),
        estimated: Vec::new(),
        theta_sd: None,
        status,
        iterations: 0,
        solve_seconds: start.elapsed().as_secs_f64(),
        details: Details::new(details),
    })
}

fn run_details(run: &KalmanRun, t0: f64) -> KalmanDetails {
    KalmanDetails {
        log_likelihood: run.log_likelihood,
        dt: run.dt,
        t0,
        grid_points: run.times.len(),
        failed_at: run.failed_at,
        smoother: None,
    }
}
