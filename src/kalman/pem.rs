//! The prediction error method (PEM): the parameters maximising the UKF's prediction-error
//! likelihood times the prior, then the UKS path at the estimate (Kristensen, Madsen &
//! Jørgensen 2004; the comparison baseline of `002_3b89776223eca539.txt` Sec. 4 and
//! `000_74b95e149527c64e.txt` Sec. 4.1).
//!
//! The objective is the log-posterior of the estimated components θ_E,
//!
//! $$ \ell(\theta_E) = \sum_k \ln N(\nu_k; 0, S_k) + \sum_{i \in E} \ln \pi_i(\theta_i), $$
//!
//! with the innovations ν_k and their covariances S_k of the continuous-discrete UKF
//! ([`super`]). Its gradient comes by forward-mode automatic differentiation through the whole
//! filter (one `Dual64` pass per estimated component: the filter is generic over the scalar).
//! It is maximised by BFGS with an Armijo backtracking line search, started at the nominal θ
//! as in `000_74b95e149527c64e.txt` Sec. 4.1 ("the nominal parameter values were used as the
//! optimization's start point"). Components with a bounded support (the prior's bounds, the
//! positive half-line for gamma and log-normal priors and for the measurement σ) are optimised
//! in unbounded coordinates: log(θ − l), log(u − θ) or logit((θ − l)/(u − l)).
//!
//! The standard deviations of θ̂ are the square roots of the diagonal of the inverse of
//! −∇²ℓ(θ̂), the Hessian by central differences of the exact gradient (a Laplace
//! approximation of the marginal posterior of θ).

use std::time::Instant;

use nalgebra::DMatrix;
use num_dual::Dual64;

use super::filter::{self, Rule, Setup};
use serde::{Deserialize, Serialize};

use super::{path_of, run_details, KalmanDetails, KalmanOptions, KalmanRun, SmootherFailure};
use crate::estimate::{Details, EstimationProblem, Method, MethodRun, PathEstimate, Status};
use crate::estimator::EstimatorOptions;
use crate::model::observation::{Noise, StateMeasurement};
use crate::model::prior::{Prior, PriorDensity};
use crate::model::{Param, Scalar, Sde};
use crate::{Error, Result};

/// Options of [`pem()`] (`pem`: the options `dt`, `alpha`, `kappa` of the UKF and those below).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
#[non_exhaustive]
pub struct PemOptions {
    /// Options of the UKF inside the objective and of the final UKS.
    #[serde(flatten)]
    pub kalman: KalmanOptions,
    /// Largest number of BFGS iterations. Default 200.
    pub max_iterations: usize,
    /// Convergence when max_i |∂ℓ/∂u_i| ≤ `gradient_tolerance` · max(1, |ℓ|) in the optimisation
    /// coordinates u. Default 1e-8.
    pub gradient_tolerance: f64,
    /// Whether to compute the standard deviations of θ̂ (p extra gradient pairs). Default true.
    pub theta_sd: bool,
}

impl Default for PemOptions {
    fn default() -> Self {
        PemOptions {
            kalman: KalmanOptions::default(),
            max_iterations: 200,
            gradient_tolerance: 1e-8,
            theta_sd: true,
        }
    }
}

impl PemOptions {
    /// Sets the Kalman options.
    pub fn with_kalman(mut self, kalman: KalmanOptions) -> Self {
        self.kalman = kalman;
        self
    }

    /// Sets the iteration limit.
    pub fn with_max_iterations(mut self, max_iterations: usize) -> Self {
        self.max_iterations = max_iterations;
        self
    }
}

impl EstimatorOptions for PemOptions {
    /// `pem`: [`pem()`].
    fn run<S: Sde + ?Sized>(
        &self,
        _: Method,
        problem: &EstimationProblem<'_, S, StateMeasurement>,
    ) -> Result<MethodRun> {
        pem(problem, self).map(MethodRun::from)
    }

    /// Checks the UKF's options, a positive finite `gradient_tolerance` and at least one
    /// iteration.
    fn validate(&self) -> Result<()> {
        self.kalman.validate()?;
        if self.max_iterations == 0 {
            return Err(Error::InvalidOption {
                name: "max_iterations".into(),
                reason: "must be at least 1, got 0".into(),
            });
        }
        crate::error::check_positive("gradient_tolerance", self.gradient_tolerance)
    }
}

/// The map from an unbounded coordinate u to a parameter with support [l, u].
#[derive(Debug, Clone, Copy, PartialEq)]
enum Transform {
    Identity,
    Lower(f64),
    Upper(f64),
    Interval(f64, f64),
}

impl Transform {
    fn of_support(lower: f64, upper: f64) -> Transform {
        match (lower.is_finite(), upper.is_finite()) {
            (false, false) => Transform::Identity,
            (true, false) => Transform::Lower(lower),
            (false, true) => Transform::Upper(upper),
            (true, true) => Transform::Interval(lower, upper),
        }
    }

    fn to_theta<D: Scalar>(self, u: D) -> D {
        match self {
            Transform::Identity => u,
            Transform::Lower(l) => u.exp() + l,
            Transform::Upper(h) => -u.exp() + h,
            Transform::Interval(l, h) => ((-u).exp() + 1.0).recip() * (h - l) + l,
        }
    }

    fn inverse(self, x: f64) -> Option<f64> {
        let u = match self {
            Transform::Identity => x,
            Transform::Lower(l) => (x - l).ln(),
            Transform::Upper(h) => (h - x).ln(),
            Transform::Interval(l, h) => {
                let r = (x - l) / (h - l);
                (r / (1.0 - r)).ln()
            }
        };
        u.is_finite().then_some(u)
    }
}

/// The negative log-posterior of the estimated components.
pub(super) struct Objective<'a, S: ?Sized> {
    sde: &'a S,
    setup: Setup,
    data: &'a crate::data::Dataset,
    rule: Rule,
    theta: Vec<f64>,
    estimate: Vec<usize>,
    priors: Vec<Prior>,
    transforms: Vec<Transform>,
}

impl<S: Sde + ?Sized> Objective<'_, S> {
    /// −ℓ(θ_E) in any scalar; `None` on a filter failure or outside the prior's support.
    fn neg_log_post<D: Scalar>(&self, theta_e: &[D]) -> Option<D> {
        let mut theta: Vec<D> = self.theta.iter().map(|&v| D::from(v)).collect();
        let mut log_prior = D::from(0.0);
        for ((&i, &v), prior) in self.estimate.iter().zip(theta_e).zip(&self.priors) {
            theta[i] = v;
            log_prior += prior.log_density(v);
        }
        let ll = filter::run(self.sde, &self.setup, self.data, &self.rule, &theta, None).ok()?;
        let value = -(ll + log_prior);
        value.re().is_finite().then_some(value)
    }

    fn theta_of_u<D: Scalar>(&self, u: &[D]) -> Vec<D> {
        u.iter().zip(&self.transforms).map(|(&v, t)| t.to_theta(v)).collect()
    }

    pub(super) fn value_u(&self, u: &[f64]) -> Option<f64> {
        self.neg_log_post(&self.theta_of_u(u))
    }

    /// Value and gradient in the coordinates u (one `Dual64` pass per coordinate).
    pub(super) fn gradient_u(&self, u: &[f64]) -> Option<(f64, Vec<f64>)> {
        let p = u.len();
        if p == 0 {
            return Some((self.value_u(u)?, Vec::new()));
        }
        let mut ud: Vec<Dual64> = u.iter().map(|&v| Dual64::from(v)).collect();
        let mut g = vec![0.0; p];
        let mut value = 0.0;
        for i in 0..p {
            ud[i].eps = 1.0;
            let r = self.neg_log_post(&self.theta_of_u(&ud))?;
            ud[i].eps = 0.0;
            value = r.re;
            g[i] = r.eps;
        }
        Some((value, g))
    }

    /// Gradient with respect to θ_E itself.
    fn gradient_theta(&self, theta_e: &[f64]) -> Option<Vec<f64>> {
        let mut td: Vec<Dual64> = theta_e.iter().map(|&v| Dual64::from(v)).collect();
        let mut g = vec![0.0; theta_e.len()];
        for i in 0..theta_e.len() {
            td[i].eps = 1.0;
            g[i] = self.neg_log_post(&td)?.eps;
            td[i].eps = 0.0;
        }
        Some(g)
    }
}

/// The outcome of the BFGS minimisation.
struct Minimum {
    u: Vec<f64>,
    value: f64,
    gradient: Vec<f64>,
    iterations: usize,
    evaluations: usize,
    status: Status,
}

/// BFGS with Armijo backtracking (Nocedal & Wright 2006, Alg. 6.1 with the initial scaling
/// (6.20)), minimising `obj.value_u` from `u0`.
fn bfgs<S: Sde + ?Sized>(obj: &Objective<'_, S>, u0: Vec<f64>, options: &PemOptions) -> Minimum {
    let p = u0.len();
    // Filter passes: one per value, one (dual) per coordinate for a gradient.
    let passes = p.max(1);
    let mut evaluations = passes;
    let Some((mut f, mut g)) = obj.gradient_u(&u0) else {
        return Minimum {
            u: u0,
            value: f64::NAN,
            gradient: vec![f64::NAN; p],
            iterations: 0,
            evaluations,
            status: Status::NumericalFailure,
        };
    };
    let mut u = u0;
    let mut h = DMatrix::<f64>::identity(p, p);
    let mut first = true;
    let norm_inf = |v: &[f64]| v.iter().fold(0.0f64, |a, &b| a.max(b.abs()));
    for iteration in 0..options.max_iterations {
        if norm_inf(&g) <= options.gradient_tolerance * f.abs().max(1.0) {
            return Minimum {
                u,
                value: f,
                gradient: g,
                iterations: iteration,
                evaluations,
                status: Status::Converged,
            };
        }
        let gv = nalgebra::DVector::from_column_slice(&g);
        let mut d = -(&h * &gv);
        let mut slope = d.dot(&gv);
        if slope.is_nan() || slope >= 0.0 {
            h = DMatrix::identity(p, p);
            d = -gv.clone();
            slope = d.dot(&gv);
        }
        // The first step is scaled so that no coordinate moves by more than 0.1.
        let mut alpha = if first { (0.1 / norm_inf(d.as_slice())).min(1.0) } else { 1.0 };
        let mut accepted = None;
        for _ in 0..40 {
            let trial: Vec<f64> = u.iter().zip(d.iter()).map(|(a, b)| a + alpha * b).collect();
            evaluations += 1;
            if let Some(ft) = obj.value_u(&trial) {
                if ft <= f + 1e-4 * alpha * slope {
                    accepted = Some((trial, ft));
                    break;
                }
            }
            alpha *= 0.5;
        }
        let Some((u_new, _)) = accepted else {
            // No decrease along a descent direction: the gradient test is as good as it gets.
            let loose = norm_inf(&g) <= 1e-4 * f.abs().max(1.0);
            let status = if loose { Status::Acceptable } else { Status::NumericalFailure };
            return Minimum { u, value: f, gradient: g, iterations: iteration, evaluations, status };
        };
        evaluations += passes;
        let Some((f_new, g_new)) = obj.gradient_u(&u_new) else {
            return Minimum {
                u,
                value: f,
                gradient: g,
                iterations: iteration,
                evaluations,
                status: Status::NumericalFailure,
            };
        };
        let s = nalgebra::DVector::from_iterator(p, u_new.iter().zip(&u).map(|(a, b)| a - b));
        let y = nalgebra::DVector::from_iterator(p, g_new.iter().zip(&g).map(|(a, b)| a - b));
        let sy = s.dot(&y);
        if sy > 1e-12 * s.norm() * y.norm() {
            if first {
                h = DMatrix::identity(p, p) * (sy / y.dot(&y));
            }
            let rho = 1.0 / sy;
            let i = DMatrix::<f64>::identity(p, p);
            let left = &i - &s * y.transpose() * rho;
            let right = &i - &y * s.transpose() * rho;
            h = &left * &h * &right + &s * s.transpose() * rho;
            first = false;
        }
        u = u_new;
        f = f_new;
        g = g_new;
    }
    let status = if norm_inf(&g) <= options.gradient_tolerance * f.abs().max(1.0) {
        Status::Converged
    } else {
        Status::MaxIterations
    };
    Minimum { u, value: f, gradient: g, iterations: options.max_iterations, evaluations, status }
}

/// Standard deviations from −∇²ℓ at θ̂ (central differences of the AD gradient); `None` when
/// the Hessian is not positive definite or a gradient fails.
fn theta_sd<S: Sde + ?Sized>(obj: &Objective<'_, S>, theta_e: &[f64]) -> Option<Vec<f64>> {
    let p = theta_e.len();
    let mut hess = DMatrix::zeros(p, p);
    for j in 0..p {
        let step = 1e-5 * theta_e[j].abs().max(1e-3);
        let mut plus = theta_e.to_vec();
        let mut minus = theta_e.to_vec();
        plus[j] += step;
        minus[j] -= step;
        let (gp, gm) = (obj.gradient_theta(&plus)?, obj.gradient_theta(&minus)?);
        for i in 0..p {
            hess[(i, j)] = (gp[i] - gm[i]) / (2.0 * step);
        }
    }
    let hess = (&hess + hess.transpose()) * 0.5;
    let inv = hess.cholesky()?.inverse();
    let sd: Vec<f64> = inv.diagonal().iter().map(|v| v.sqrt()).collect();
    sd.iter().all(|v| v.is_finite()).then_some(sd)
}

/// The support of an estimated component: the prior's bounds, intersected with (0, ∞) for
/// gamma and log-normal priors and for the standard deviation of the measurement noise.
fn support(prior: &Prior, positive: bool) -> (f64, f64) {
    let mut lower = prior.lower;
    if positive || matches!(prior.density, PriorDensity::Gamma { .. } | PriorDensity::LogNormal { .. }) {
        lower = lower.max(0.0);
    }
    (lower, prior.upper)
}

/// The PEM objective of a problem and the starting point in the optimisation coordinates.
pub(super) fn objective<'a, S: Sde + ?Sized>(
    problem: &EstimationProblem<'a, S, StateMeasurement>,
    options: &PemOptions,
) -> Result<(Objective<'a, S>, Vec<f64>)> {
    let setup = super::setup(problem, problem.theta, &options.kalman, "pem")?;
    let noise_sigma = match problem.observation.noise {
        Noise::Gaussian { sigma: Param::Theta(i) } => Some(i),
        _ => None,
    };
    let mut estimate: Vec<usize> = Vec::with_capacity(problem.estimate.len());
    for &i in problem.estimate {
        if !estimate.contains(&i) {
            estimate.push(i);
        }
    }
    let priors: Vec<Prior> = estimate.iter().map(|&i| problem.theta_prior[i]).collect();
    let transforms: Vec<Transform> = estimate
        .iter()
        .zip(&priors)
        .map(|(&i, prior)| {
            let (l, h) = support(prior, noise_sigma == Some(i));
            Transform::of_support(l, h)
        })
        .collect();
    let names = problem.sde.param_names();
    let mut u0 = Vec::with_capacity(estimate.len());
    for (k, &i) in estimate.iter().enumerate() {
        let bad_start = || Error::InvalidOption {
            name: "theta".into(),
            reason: format!(
                "the starting value {} of `{}` is outside the support of its prior `{}`",
                problem.theta[i], names[i], priors[k]
            ),
        };
        let u = transforms[k].inverse(problem.theta[i]).ok_or_else(bad_start)?;
        if !priors[k].log_density(problem.theta[i]).is_finite() {
            return Err(bad_start());
        }
        u0.push(u);
    }
    let obj = Objective {
        sde: problem.sde,
        setup,
        data: problem.data,
        rule: Rule::Unscented(options.kalman.unscented),
        theta: problem.theta.to_vec(),
        estimate,
        priors,
        transforms,
    };
    if obj.value_u(&u0).is_none() {
        return Err(Error::InvalidOption {
            name: "theta".into(),
            reason: "the UKF fails at the starting parameters (a covariance is not positive definite)".into(),
        });
    }
    Ok((obj, u0))
}

/// The prediction error method: θ̂_E = argmax of the UKF log-likelihood plus the log-prior
/// over the components `problem.estimate`, started at `problem.theta`, then the UKS path at θ̂
/// (see the module documentation). The estimate's `theta_sd` are the Laplace standard
/// deviations (when [`PemOptions::theta_sd`] and the Hessian is positive definite); the
/// details hold the log-likelihood and log-posterior at θ̂, the final gradient norm, the
/// number of filter evaluations and the UKS's step.
///
/// The status is that of the optimiser ([`Status::Converged`], [`Status::Acceptable`] when the
/// line search stalls at a small gradient, [`Status::MaxIterations`],
/// [`Status::NumericalFailure`]), or [`Status::NumericalFailure`] when the final UKS fails.
///
/// Errors: those of [`super::filter`]; [`Error::InvalidOption`] (name `estimate`) when no
/// component is to be estimated, or (name `theta`) when the start is outside a prior's
/// support or the objective cannot be evaluated there.
pub fn pem<S: Sde + ?Sized>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    options: &PemOptions,
) -> Result<PathEstimate> {
    let start = Instant::now();
    options.validate()?;
    options.kalman.unscented.validate(problem.sde.dims().states())?;
    if problem.estimate.is_empty() {
        return Err(Error::InvalidOption {
            name: "estimate".into(),
            reason: "`pem` needs parameters to estimate (e.g. `--estimate a,b,d,sigma_y`)".into(),
        });
    }
    let (obj, u0) = objective(problem, options)?;
    let estimate = obj.estimate.clone();
    let names = problem.sde.param_names();
    let min = bfgs(&obj, u0, options);
    let theta_e = obj.theta_of_u(&min.u);
    let mut theta = problem.theta.to_vec();
    for (&i, &v) in estimate.iter().zip(&theta_e) {
        theta[i] = v;
    }
    let sd = if options.theta_sd { theta_sd(&obj, &theta_e) } else { None };
    let approximation = super::Approximation::Unscented(options.kalman.unscented);
    let run: KalmanRun = super::filter_named(problem, &theta, approximation, &options.kalman, "pem")?;
    let mut status = min.status;
    let mut run_details = run_details(&run, problem.t0);
    let moments = match run.smooth() {
        Some(s) => s,
        None => {
            status = Status::NumericalFailure;
            run_details.smoother = Some(SmootherFailure::FailedAtEstimate);
            run.filtered.clone()
        }
    };
    let details = PemDetails {
        run: run_details,
        log_posterior: -min.value,
        gradient_norm: min.gradient.iter().fold(0.0f64, |a, &b| a.max(b.abs())),
        filter_evaluations: min.evaluations,
        theta_start: problem.theta.to_vec(),
    };
    Ok(PathEstimate {
        method: Method::Pem,
        path: path_of(problem.sde.state_names(), &run.times, &moments),
        theta_names: names,
        theta,
        estimated: estimate,
        theta_sd: sd,
        status,
        iterations: min.iterations,
        solve_seconds: start.elapsed().as_secs_f64(),
        details: Details::new(details),
    })
}

/// The details of a PEM estimate's report: those of the UKS at θ̂ and of the optimisation.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PemDetails {
    /// The UKS at θ̂.
    #[serde(flatten)]
    pub run: KalmanDetails,
    /// The log-posterior at θ̂.
    pub log_posterior: f64,
    /// max |∂ℓ/∂u| at the end, in the optimisation coordinates.
    pub gradient_norm: f64,
    /// Filter runs of the optimisation.
    pub filter_evaluations: usize,
    /// θ at the start.
    pub theta_start: Vec<f64>,
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn transforms_round_trip() {
        // Identity: θ = u; Lower(l): θ = l + eᵘ; Upper(h): θ = h − eᵘ; Interval: logistic.
        for (t, x) in [
            (Transform::Identity, -2.5),
            (Transform::Lower(0.0), 0.1),
            (Transform::Lower(-1.0), 3.0),
            (Transform::Upper(2.0), -4.0),
            (Transform::Interval(-1.0, 3.0), 0.2),
        ] {
            let u = t.inverse(x).unwrap();
            assert_relative_eq!(t.to_theta(u), x, epsilon = 1e-14, max_relative = 1e-14);
        }
        assert!(Transform::Lower(0.0).inverse(0.0).is_none());
        assert!(Transform::Interval(0.0, 1.0).inverse(1.5).is_none());
    }
}
