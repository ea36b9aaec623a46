//! The ensemble Kalman filter with perturbed observations and the ensemble Kalman smoother
//! (`enks`) for the continuous-discrete model ds = a(t, s, θ) dt + B dW, a = (f, h),
//! B = (G(θ); 0), measured by y_k = s(t_k)[i] + N(0, σ²) ([`StateMeasurement`]).
//!
//! # Filter (Evensen 2003; Burgers, van Leeuwen & Evensen 1998)
//!
//! N members s_1, …, s_N are drawn from the initial-state priors at t₀ (any proper prior) and
//! propagated between consecutive times (t₀ and the measurement times) by Euler–Maruyama
//! substeps of equal size h ≤ [`EnksOptions::dt`] (`000_74b95e149527c64e.txt (3.1)`):
//!
//! (E1) s_i ← s_i + a(t, s_i) h + B ΔW_i,  ΔW_i ~ N(0, h I) independent.
//!
//! At a measurement time with at least one measured component, the forecast anomalies are
//! first scaled by √ρ (multiplicative covariance inflation, Anderson & Anderson 1999):
//!
//! (E2) s_i ← s̄ + √ρ (s_i − s̄),
//!
//! then, with H the selection of the measured, non-missing components (m of them), the
//! anomaly matrices A (N × n, rows s_i − s̄) and HA (N × m), the ensemble covariances
//!
//! (E3) P Hᵀ = Aᵀ HA / (N − 1),  S = HAᵀ HA / (N − 1) + σ² I,
//!
//! give the analysis of every member against its own perturbed observation:
//!
//! (E4) s_i ← s_i + P Hᵀ S⁻¹ (y + ε_i − H s_i),  ε_i ~ N(0, σ² I) independent
//!
//! (the perturbations make the analysis ensemble's covariance (I − K H) P, Burgers et al. 1998).
//! Missing (NaN) components are left out of H; a time with none measured has no analysis.
//!
//! # Smoother (Evensen & van Leeuwen 2000)
//!
//! The analysis at t_k also updates the stored ensemble of every earlier time t_j < t_k with
//! the same innovations, through the ensemble cross-covariance of s(t_j) with H s(t_k):
//!
//! (E5) s_i(t_j) ← s_i(t_j) + Cov(s(t_j), H s(t_k)) S⁻¹ (y + ε_i − H s_i(t_k)),
//!      Cov(s(t_j), H s(t_k)) = A_jᵀ HA / (N − 1),
//!
//! A_j the anomalies of the ensemble at t_j as smoothed by the analyses before t_k. After the
//! last analysis the ensemble at t_j represents p(s(t_j) | all y) (the fixed-interval
//! smoother); the estimate is its mean and standard deviation at t₀ and the measurement times.
//! On a linear-Gaussian model the filter and the smoother converge, as N → ∞, to the Kalman
//! filter and the RTS smoother of the Euler-discretised model (Le Gland, Monbet & Tran 2011;
//! Evensen & van Leeuwen 2000, Sec. 3), itself within O(h) of the exact ones
//! ([`super::linear::kalman_rts`]).
//!
//! # Likelihood
//!
//! The Gaussian approximation of the prediction-error decomposition with the ensemble
//! moments, Σ_k ln N(y_k − H s̄_k; 0, S_k) (s̄_k the forecast mean after inflation), is
//! reported as `log_likelihood`.
//!
//! # Cost and limits
//!
//! Propagation costs N drift evaluations per substep; the analysis at t_k costs
//! O(N n m + m³) for the filter and O(N n m) for each earlier stored time, so a record of K
//! measurement times costs O(K² N n m) in all (O(N n²) per stored time and analysis at most),
//! and the stored ensembles take K N n numbers. The method assumes Gaussian measurement
//! errors (checked, as the Kalman methods); it handles any drift and any proper initial law,
//! but each analysis is a linear update, exact only for Gaussian forecasts: with few members
//! or strongly non-Gaussian (e.g. bimodal) forecasts it is biased, and sampling error in the
//! covariances shrinks the spread (which ρ > 1 counteracts).
//!
//! References: G. Evensen, "The ensemble Kalman filter: theoretical formulation and practical
//! implementation", Ocean Dynamics 53, 2003; G. Burgers, P. J. van Leeuwen, G. Evensen,
//! "Analysis scheme in the ensemble Kalman filter", Mon. Weather Rev. 126, 1998; G. Evensen,
//! P. J. van Leeuwen, "An ensemble Kalman smoother for nonlinear dynamics", Mon. Weather Rev.
//! 128, 2000; J. L. Anderson, S. L. Anderson, "A Monte Carlo implementation of the nonlinear
//! filtering problem to produce ensemble assimilations and forecasts", Mon. Weather Rev. 127,
//! 1999; F. Le Gland, V. Monbet, V.-D. Tran, "Large sample asymptotics for the ensemble Kalman
//! filter", in *The Oxford Handbook of Nonlinear Filtering*, 2011.

#[cfg(test)]
mod tests;

use std::time::Instant;

use nalgebra::{DMatrix, DVector};
use rand::Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

use super::filter::gaussian_sigma;
use super::{build_nodes, check_dt, default_step, no_estimated_parameters, Node};
use crate::data::StatePath;
use crate::estimate::{Details, EstimationProblem, Method, MethodRun, PathEstimate, Status};
use crate::estimator::EstimatorOptions;
use crate::model::observation::StateMeasurement;
use crate::model::Sde;
use crate::{Error, Result};

/// ln(2π).
const LN_2PI: f64 = 1.837_877_066_409_345_5;

/// Options of the ensemble Kalman smoother (`enks`). Its random numbers come from the
/// problem's seed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
#[non_exhaustive]
pub struct EnksOptions {
    /// Number of ensemble members N ≥ 2. Default 100.
    pub members: usize,
    /// Largest Euler–Maruyama substep. Default (`None`): a tenth of the median interval
    /// between the initial time and the measurement times, at most 0.01 (as the other Kalman
    /// methods, [`super::KalmanOptions::dt`]).
    pub dt: Option<f64>,
    /// Multiplicative covariance inflation ρ ≥ 1: the forecast anomalies are scaled by √ρ
    /// before each analysis (E2). Default 1 (no inflation).
    pub inflation: f64,
}

impl Default for EnksOptions {
    fn default() -> Self {
        EnksOptions { members: 100, dt: None, inflation: 1.0 }
    }
}

impl EnksOptions {
    /// Sets the number of members.
    pub fn with_members(mut self, members: usize) -> Self {
        self.members = members;
        self
    }

    /// Sets the largest substep.
    pub fn with_dt(mut self, dt: f64) -> Self {
        self.dt = Some(dt);
        self
    }

    /// Sets the inflation factor.
    pub fn with_inflation(mut self, inflation: f64) -> Self {
        self.inflation = inflation;
        self
    }
}

impl EstimatorOptions for EnksOptions {
    /// `enks`: [`enks()`]; `enkf`: [`enkf()`]; with their random numbers seeded by the problem's
    /// seed.
    fn run<S: Sde + ?Sized>(
        &self,
        method: Method,
        problem: &EstimationProblem<'_, S, StateMeasurement>,
    ) -> Result<MethodRun> {
        let mut rng = <rand::rngs::StdRng as rand::SeedableRng>::seed_from_u64(problem.seed);
        if method == Method::Enkf {
            return enkf(problem, self, &mut rng).map(MethodRun::from);
        }
        enks(problem, self, &mut rng).map(MethodRun::from)
    }

    /// Checks N ≥ 2, ρ ≥ 1 and finite, and a positive finite `dt`.
    fn validate(&self) -> Result<()> {
        if self.members < 2 {
            return Err(Error::InvalidOption {
                name: "members".into(),
                reason: format!("must be at least 2, got {}", self.members),
            });
        }
        if !(self.inflation >= 1.0 && self.inflation.is_finite()) {
            return Err(Error::InvalidOption {
                name: "inflation".into(),
                reason: format!("must be at least 1 and finite, got {}", self.inflation),
            });
        }
        check_dt(self.dt)
    }
}

/// The details of an ensemble Kalman smoother's report.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EnksDetails {
    /// N.
    pub members: usize,
    /// ρ.
    pub inflation: f64,
    /// The substep (the largest; each interval has equal substeps).
    pub dt: f64,
    /// The number of analyses: measurement times with at least one measured component.
    pub analyses: usize,
    /// The ensemble Gaussian approximation of ln p(y | θ) (NaN after a failure).
    pub log_likelihood: f64,
    /// The time at which the ensemble became non-finite, if it did.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub failed_at: Option<f64>,
}

/// The output of [`ensemble_smoother`]: the smoothed ensembles at t₀ and the measurement
/// times, and the filter's moments there.
#[derive(Debug, Clone)]
pub struct EnksSmoothing {
    /// t₀ (when before the first measurement) and the measurement times, up to a failure.
    pub times: Vec<f64>,
    /// Number of states n (noisy then clean).
    pub states: usize,
    /// The smoothed ensembles: `smoothed[k]` holds member i's state at `times[k]` in
    /// `[i * states..(i + 1) * states]`.
    pub smoothed: Vec<Vec<f64>>,
    /// The mean of the filter's ensemble at each time (after its analysis).
    pub filtered_mean: Vec<Vec<f64>>,
    /// The standard deviation of the filter's ensemble at each time (after its analysis).
    pub filtered_sd: Vec<Vec<f64>>,
    /// The ensemble Gaussian approximation of ln p(y | θ) (NaN after a failure).
    pub log_likelihood: f64,
    /// The number of analyses.
    pub analyses: usize,
    /// [`Status::Converged`], or [`Status::NumericalFailure`] when the ensemble became
    /// non-finite (the times then end before `failed_at`).
    pub status: Status,
    /// The time at which the ensemble became non-finite, if it did.
    pub failed_at: Option<f64>,
    /// The substep used (the largest; each interval has equal substeps).
    pub dt: f64,
}

impl EnksSmoothing {
    /// The mean and standard deviation (divisor N − 1) of the smoothed ensemble at each time.
    pub fn mean_and_sd(&self) -> (Vec<Vec<f64>>, Vec<Vec<f64>>) {
        self.smoothed.iter().map(|e| ensemble_moments(e, self.states)).unzip()
    }
}

/// The mean and standard deviation (divisor N − 1) of an ensemble of `dim`-vectors stored
/// member after member.
fn ensemble_moments(ensemble: &[f64], dim: usize) -> (Vec<f64>, Vec<f64>) {
    let n = (ensemble.len() / dim.max(1)) as f64;
    let mean = ensemble_mean(ensemble, dim);
    let mut var = vec![0.0; dim];
    for s in ensemble.chunks_exact(dim.max(1)) {
        for r in 0..dim {
            var[r] += (s[r] - mean[r]).powi(2);
        }
    }
    (mean, var.iter().map(|v| (v / (n - 1.0).max(1.0)).sqrt()).collect())
}

/// The mean of an ensemble of `dim`-vectors stored member after member.
fn ensemble_mean(ensemble: &[f64], dim: usize) -> Vec<f64> {
    let mut mean = vec![0.0; dim];
    let mut count = 0.0;
    for s in ensemble.chunks_exact(dim.max(1)) {
        for r in 0..dim {
            mean[r] += s[r];
        }
        count += 1.0;
    }
    mean.iter_mut().for_each(|m| *m /= f64::max(count, 1.0));
    mean
}

/// The model of a run: the SDE at θ with G, and the sizes.
struct Dynamics<'a, S: Sde + ?Sized> {
    sde: &'a S,
    theta: &'a [f64],
    g: DMatrix<f64>,
    noisy: usize,
    dim: usize,
}

impl<S: Sde + ?Sized> Dynamics<'_, S> {
    /// Propagates every member from `t_prev` to `node` by `node.steps` equal Euler–Maruyama
    /// substeps (E1), one member after the other.
    fn propagate<R: Rng + ?Sized>(&self, ensemble: &mut [f64], t_prev: f64, node: &Node, rng: &mut R) {
        if node.steps == 0 {
            return;
        }
        let h = (node.t - t_prev) / node.steps as f64;
        let sqrt_h = h.sqrt();
        let mut drift = vec![0.0; self.dim];
        let mut dw = vec![0.0; self.noisy];
        for s in ensemble.chunks_exact_mut(self.dim) {
            for step in 0..node.steps {
                let t = t_prev + step as f64 * h;
                self.sde.state_drift(t, s, self.theta, &mut drift);
                for v in dw.iter_mut() {
                    let e: f64 = StandardNormal.sample(rng);
                    *v = e * sqrt_h;
                }
                for r in 0..self.dim {
                    let noise = if r < self.noisy {
                        (0..self.noisy).map(|c| self.g[(r, c)] * dw[c]).sum()
                    } else {
                        0.0
                    };
                    s[r] += drift[r] * h + noise;
                }
            }
        }
    }
}

/// Scales the anomalies of the ensemble by √ρ (E2).
fn inflate(ensemble: &mut [f64], dim: usize, inflation: f64) {
    if inflation == 1.0 {
        return;
    }
    let mean = ensemble_mean(ensemble, dim);
    let scale = inflation.sqrt();
    for s in ensemble.chunks_exact_mut(dim) {
        for r in 0..dim {
            s[r] = mean[r] + scale * (s[r] - mean[r]);
        }
    }
}

/// One analysis, shared by the filter and every earlier time (E4, E5): the anomalies HA of
/// the predicted measurements and the whitened innovations S⁻¹(y + ε_i − H s_i), both N × m
/// stored member after member.
struct Analysis {
    /// m.
    outputs: usize,
    /// HA, rows H s_i − H s̄.
    ha: Vec<f64>,
    /// Rows S⁻¹ (y + ε_i − H s_i).
    innovations: Vec<f64>,
    /// ln N(y − H s̄; 0, S).
    log_likelihood: f64,
}

/// The analysis of the forecast `ensemble` against the measurement `y` of the states
/// `measured` (NaN components skipped) with error sd `sigma` (E3, E4), drawing the perturbed
/// observations. `None` when nothing is measured, or S is not positive definite or the
/// result not finite.
fn analyse<R: Rng + ?Sized>(
    ensemble: &[f64],
    dim: usize,
    (measured, y, sigma): (&[usize], &[f64], f64),
    rng: &mut R,
) -> Option<Analysis> {
    let obs: Vec<(usize, f64)> =
        measured.iter().zip(y).filter(|(_, v)| !v.is_nan()).map(|(&i, &v)| (i, v)).collect();
    let m = obs.len();
    let n = ensemble.len() / dim;
    if m == 0 || n < 2 {
        return None;
    }
    let mut hbar = vec![0.0; m];
    for s in ensemble.chunks_exact(dim) {
        for (c, &(i, _)) in obs.iter().enumerate() {
            hbar[c] += s[i] / n as f64;
        }
    }
    let mut ha = vec![0.0; n * m];
    for (row, s) in ha.chunks_exact_mut(m).zip(ensemble.chunks_exact(dim)) {
        for (c, &(i, _)) in obs.iter().enumerate() {
            row[c] = s[i] - hbar[c];
        }
    }
    // S = HAᵀ HA / (N − 1) + σ² I (E3).
    let mut cov = DMatrix::from_diagonal_element(m, m, sigma * sigma);
    for row in ha.chunks_exact(m) {
        for a in 0..m {
            for b in 0..m {
                cov[(a, b)] += row[a] * row[b] / (n - 1) as f64;
            }
        }
    }
    let chol = cov.cholesky()?;
    let nu = DVector::from_iterator(m, obs.iter().zip(&hbar).map(|(&(_, yv), hb)| yv - hb));
    let log_det: f64 = chol.l().diagonal().iter().map(|d| 2.0 * d.ln()).sum();
    let log_likelihood = -0.5 * (nu.dot(&chol.solve(&nu)) + log_det + m as f64 * LN_2PI);
    let mut innovations = vec![0.0; n * m];
    let mut r = DVector::zeros(m);
    for (row, s) in innovations.chunks_exact_mut(m).zip(ensemble.chunks_exact(dim)) {
        for (c, &(i, yv)) in obs.iter().enumerate() {
            let e: f64 = StandardNormal.sample(rng);
            r[c] = yv + sigma * e - s[i];
        }
        row.copy_from_slice(chol.solve(&r).as_slice());
    }
    let finite = innovations.iter().chain(&ha).all(|v| v.is_finite()) && log_likelihood.is_finite();
    finite.then_some(Analysis { outputs: m, ha, innovations, log_likelihood })
}

/// Applies `analysis` to the ensemble of one time (the forecast itself, E4, or an earlier
/// time, E5): s_i ← s_i + C S⁻¹(y + ε_i − H s_i) with C = Aᵀ HA / (N − 1) from this ensemble's
/// anomalies A. Returns whether the result is finite.
fn update(ensemble: &mut [f64], dim: usize, analysis: &Analysis) -> bool {
    let m = analysis.outputs;
    let n = ensemble.len() / dim;
    let mean = ensemble_mean(ensemble, dim);
    // C (dim × m), row-major.
    let mut c = vec![0.0; dim * m];
    for (s, row) in ensemble.chunks_exact(dim).zip(analysis.ha.chunks_exact(m)) {
        for r in 0..dim {
            let a = (s[r] - mean[r]) / (n - 1) as f64;
            for k in 0..m {
                c[r * m + k] += a * row[k];
            }
        }
    }
    for (s, d) in ensemble.chunks_exact_mut(dim).zip(analysis.innovations.chunks_exact(m)) {
        for r in 0..dim {
            s[r] += (0..m).map(|k| c[r * m + k] * d[k]).sum::<f64>();
        }
    }
    ensemble.iter().all(|v| v.is_finite())
}

/// The initial ensemble: `members` draws from the initial-state priors (noisy then clean).
/// Errors: [`Error::InvalidOption`] (name `x0-prior`) for an improper prior.
fn initial_ensemble<S, R>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    members: usize,
    rng: &mut R,
) -> Result<Vec<f64>>
where
    S: Sde + ?Sized,
    R: Rng + ?Sized,
{
    let priors: Vec<_> = problem.x0_prior.iter().chain(problem.z0_prior).collect();
    let names = problem.sde.state_names();
    if let Some(k) = priors.iter().position(|p| !p.is_proper()) {
        return Err(Error::InvalidOption {
            name: "x0-prior".into(),
            reason: format!(
                "`enks` draws its initial ensemble from the priors; the prior `{}` of `{}` is improper \
                 (give it finite bounds or a proper density)",
                priors[k], names[k]
            ),
        });
    }
    let mut ensemble = Vec::with_capacity(members * priors.len());
    for _ in 0..members {
        for p in &priors {
            ensemble.push(p.sample(rng)?);
        }
    }
    Ok(ensemble)
}

/// What [`ensemble_smoother`] needs besides the problem: the integration nodes, σ, the
/// model at θ, and the options.
struct Plan<'a, S: Sde + ?Sized> {
    nodes: Vec<Node>,
    sigma: f64,
    dynamics: Dynamics<'a, S>,
    dt: f64,
}

/// Checks the problem and the options and builds the [`Plan`].
fn plan<'a, S: Sde + ?Sized>(
    problem: &EstimationProblem<'a, S, StateMeasurement>,
    options: &EnksOptions,
) -> Result<Plan<'a, S>> {
    problem.validate()?;
    options.validate()?;
    let EstimationProblem { sde, observation, theta, data, t0, .. } = *problem;
    let d = sde.dims();
    let sigma = gaussian_sigma(sde, observation, theta, Method::Enks.name())?;
    let sigma = sigma.value(theta).ok_or_else(|| Error::InvalidOption {
        name: "likelihood".into(),
        reason: "the measurement sd refers to a parameter out of range".into(),
    })?;
    let g = sde.diffusion_matrix(theta)?;
    let dt = options.dt.unwrap_or_else(|| default_step(t0, &data.times));
    let nodes = build_nodes(&data.times, t0, dt)?;
    let bytes = nodes.len() as f64 * options.members as f64 * d.states() as f64 * 16.0;
    let size =
        format!("{} members (`members`) × {} times × {} states", options.members, nodes.len(), d.states());
    problem.max_memory.check(&format!("`{}`", Method::Enks.name()), size, bytes)?;
    let dynamics = Dynamics { sde, theta, g, noisy: d.noisy, dim: d.states() };
    Ok(Plan { nodes, sigma, dynamics, dt })
}

/// Runs the ensemble Kalman filter and smoother at `problem.theta` (see the module
/// documentation).
///
/// Errors: those of [`EstimationProblem::validate`]; [`Error::InvalidOption`] for bad options,
/// a non-Gaussian likelihood (name `likelihood`), an improper initial-state prior
/// (`x0-prior`), an initial time after the first measurement, or ensembles too large to store
/// (`members`); [`Error::SingularDiffusion`]. A non-finite ensemble is not an error: the status
/// is then [`Status::NumericalFailure`].
pub fn ensemble_smoother<S, R>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    options: &EnksOptions,
    rng: &mut R,
) -> Result<EnksSmoothing>
where
    S: Sde + ?Sized,
    R: Rng + ?Sized,
{
    ensemble_pass(problem, options, rng, true)
}

/// The forward pass of the ensemble Kalman filter, and with `smooth` the smoother's updates of
/// the stored earlier ensembles (E5); without, `smoothed` is empty and the cost is linear in
/// the number of measurement times. The random numbers drawn are the same either way.
fn ensemble_pass<S, R>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    options: &EnksOptions,
    rng: &mut R,
    smooth: bool,
) -> Result<EnksSmoothing>
where
    S: Sde + ?Sized,
    R: Rng + ?Sized,
{
    let Plan { nodes, sigma, dynamics, dt } = plan(problem, options)?;
    let dim = dynamics.dim;
    let mut ensemble = initial_ensemble(problem, options.members, rng)?;
    let mut store: Vec<Vec<f64>> = Vec::with_capacity(nodes.len());
    let mut filtered = Vec::with_capacity(nodes.len());
    let (mut log_likelihood, mut analyses, mut failed_at) = (0.0, 0, None);
    let mut t_prev = nodes[0].t;
    for node in &nodes {
        dynamics.propagate(&mut ensemble, t_prev, node, rng);
        t_prev = node.t;
        let mut finite = ensemble.iter().all(|v| v.is_finite());
        let y = node.row.map(|row| problem.data.values[row].as_slice()).unwrap_or_default();
        if finite && y.iter().any(|v| !v.is_nan()) {
            inflate(&mut ensemble, dim, options.inflation);
            match analyse(&ensemble, dim, (&problem.observation.states, y, sigma), rng) {
                Some(a) => {
                    log_likelihood += a.log_likelihood;
                    analyses += 1;
                    finite = update(&mut ensemble, dim, &a);
                    for past in store.iter_mut() {
                        finite &= update(past, dim, &a);
                    }
                }
                None => finite = false,
            }
        }
        if !finite {
            failed_at = Some(node.t);
            // Keep the times whose smoothed (or filtered) ensembles are still finite.
            let good = match smooth {
                true => store.iter().position(|e| e.iter().any(|v| !v.is_finite())).unwrap_or(store.len()),
                false => filtered.len(),
            };
            store.truncate(good);
            filtered.truncate(good);
            break;
        }
        filtered.push(ensemble_moments(&ensemble, dim));
        if smooth {
            store.push(ensemble.clone());
        }
    }
    let times = nodes[..filtered.len()].iter().map(|nd| nd.t).collect();
    let (filtered_mean, filtered_sd) = filtered.into_iter().unzip();
    Ok(EnksSmoothing {
        times,
        states: dim,
        smoothed: store,
        filtered_mean,
        filtered_sd,
        log_likelihood: if failed_at.is_some() { f64::NAN } else { log_likelihood },
        analyses,
        status: if failed_at.is_some() { Status::NumericalFailure } else { Status::Converged },
        failed_at,
        dt,
    })
}

/// The ensemble Kalman smoother as an estimator: the mean and standard deviation of the
/// smoothed ensemble at t₀ and the measurement times, at `problem.theta`. The details hold N,
/// ρ, the substep, the number of analyses and the log-likelihood approximation.
///
/// Errors: those of [`ensemble_smoother`]; [`Error::InvalidOption`] (name `estimate`) when
/// `problem.estimate` is not empty.
pub fn enks<S, R>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    options: &EnksOptions,
    rng: &mut R,
) -> Result<PathEstimate>
where
    S: Sde + ?Sized,
    R: Rng + ?Sized,
{
    ensemble_estimate(problem, options, rng, Method::Enks)
}

/// The ensemble Kalman filter as an estimator (`enkf`): the mean and standard deviation of the
/// analysed ensemble at t₀ and the measurement times (E1–E4 without the smoother's updates; the
/// filtered part of [`enks()`] with the same random numbers, at a cost linear in the number of
/// measurement times). Details and errors as [`enks()`].
pub fn enkf<S, R>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    options: &EnksOptions,
    rng: &mut R,
) -> Result<PathEstimate>
where
    S: Sde + ?Sized,
    R: Rng + ?Sized,
{
    ensemble_estimate(problem, options, rng, Method::Enkf)
}

/// `enks` (the smoothed ensembles) or `enkf` (the filtered ones) as a [`PathEstimate`].
fn ensemble_estimate<S, R>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    options: &EnksOptions,
    rng: &mut R,
    method: Method,
) -> Result<PathEstimate>
where
    S: Sde + ?Sized,
    R: Rng + ?Sized,
{
    no_estimated_parameters(problem, method.name())?;
    let start = Instant::now();
    let smooth = method != Method::Enkf;
    let out = ensemble_pass(problem, options, rng, smooth)?;
    let (mean, sd) =
        if smooth { out.mean_and_sd() } else { (out.filtered_mean.clone(), out.filtered_sd.clone()) };
    let details = EnksDetails {
        members: options.members,
        inflation: options.inflation,
        dt: out.dt,
        analyses: out.analyses,
        log_likelihood: out.log_likelihood,
        failed_at: out.failed_at,
    };
    Ok(PathEstimate {
        method,
        path: StatePath { names: problem.sde.state_names(), times: out.times, values: mean, sd: Some(sd) },
        theta_names: problem.sde.param_names(),
        theta: problem.theta.to_vec(),
        estimated: Vec::new(),
        theta_sd: None,
        status: out.status,
        iterations: 0,
        solve_seconds: start.elapsed().as_secs_f64(),
        details: Details::new(details),
    })
}
