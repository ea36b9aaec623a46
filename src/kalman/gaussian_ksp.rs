//! The Gaussian closure of the Kushner–Stratonovich–Pardoux (KSP) smoother in any number of
//! states (`gaussian-ksp-closure`).
//!
//! # Theory
//!
//! The optimal smoother integrates the forward Kushner–Stratonovich (Kolmogorov) equation for
//! the filtering density between the measurement times, jumps at each measurement by Bayes'
//! rule, and runs the backward (Pardoux) equation; the smoothed density is the product of the
//! two (`003_d2fc48a470e528fc.txt (I.80)–(I.84)`, Appendix 1). Closed on the moments
//! M = (s, s ⊗ s) of a Gaussian — the closure of the KSP smoother of
//! `003_d2fc48a470e528fc.txt (II.64)–(II.65)`, whose jumps add R⁻¹r to the linear natural
//! parameter and −½R⁻¹ to the quadratic one — this becomes:
//!
//! - **between measurements**, the moment equations of the forward density (the same as those
//!   of the mean-optimal Gaussian closure's forward pass):
//!   ṁ = E[a(t, S)], Ṗ = E[(S − m) a(t, S)ᵀ] + E[a(t, S)(S − m)ᵀ] + B Bᵀ, S ~ N(m, P),
//!   with a = (f, h) and B = (G; 0), so clean states (zero noise rows) need no special case;
//! - **at a measurement time**, the jump (I.80) closed on Gaussians: the Gaussian (assumed
//!   density) Bayes update. For the library's measurements y = s[i] + N(0, σ²) the likelihood
//!   is Gaussian and linear in s, so the updated density is Gaussian and the Kalman update is
//!   the exact Bayes step — it *narrows* the density (the posterior precision is the prior's
//!   plus R⁻¹, (II.65)); this is what keeps the moments bounded on chaotic models, where the
//!   mean-optimal closure's exponential tilts (`003 (II.46)`) do not;
//! - **backward**, the Rauch–Tung–Striebel pass of the continuous-discrete Gaussian smoother
//!   (Särkkä 2008; Särkkä & Sarmavuori 2013), with the cross-covariance of consecutive grid
//!   points from the statistical linearisation F = Mᵀ P⁻¹, M = E[(S − m) a(t, S)ᵀ].
//!
//! The expectations over N(m, P) are quadrature rules for N(0, I) mapped by S = m + L ξ
//! (P = L Lᵀ), [`GaussianRule`]: with a drift of total degree d the integrands are polynomials
//! of degree ≤ d + 1 in ξ, so a Gauss–Hermite tensor rule of p points per axis (exact for
//! ∏ ξᵢ^{aᵢ} with every aᵢ ≤ 2p − 1) gives the exact moment equations when 2p − 1 ≥ d + 1, the
//! degree-3 spherical–radial cubature rule when d ≤ 2 and the degree-5 rule when d ≤ 4. The
//! moment ODEs are integrated by the classical Runge–Kutta method of the Kalman baselines
//! ([`super`]), and on a linear SDE the closure is the Kalman filter and RTS smoother up to the
//! Runge–Kutta error O(dt⁴).
//!
//! With a drift of degree ≤ 2 (Lorenz-63, Lorenz-96) every rule of degree ≥ 3 computes the same
//! closed moment equations, which are then also those of the UKS with its default spherical
//! cubature points: the two estimators differ only for drifts of higher degree (Duffing, the
//! double well) or non-polynomial drifts, where the closure's rule is exact or refinable.
//!
//! References: S. Särkkä, "Unscented Rauch–Tung–Striebel smoother", IEEE TAC 53(3), 2008;
//! S. Särkkä, J. Sarmavuori, "Gaussian filtering and smoothing for continuous-discrete dynamic
//! systems", Signal Processing 93(2), 2013; K. Ito, K. Xiong, "Gaussian filters for nonlinear
//! filtering problems", IEEE TAC 45(5), 2000.

use serde::{Deserialize, Serialize};

use super::{check_dt, estimate_with, Approximation, GaussianRule, KalmanOptions, UnscentedParams};
use crate::action::closure::drift::gaussian_closure_rule;
use crate::estimate::{EstimationProblem, Method, MethodRun, PathEstimate};
use crate::estimator::EstimatorOptions;
use crate::model::observation::StateMeasurement;
use crate::model::Sde;
use crate::{Error, Result};

/// The quadrature of the Gaussian expectations (option `rule`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
#[non_exhaustive]
pub enum ExpectationRule {
    /// Gauss–Hermite tensor rules up to 3 states, with `gaussian_points` per axis or, when not
    /// given, the fewest that are exact for a drift declared polynomial (else 16, 8, 5 per axis
    /// for 1, 2, 3 states); beyond 3 states the degree-5 cubature rule (as the mean-optimal
    /// `gaussian-closure`, [`gaussian_closure_rule`]).
    #[default]
    Auto,
    /// Gauss–Hermite tensor rule with `gaussian_points` per axis (default 5): pⁿ nodes, exact
    /// for drifts of degree ≤ 2p − 2 in each state.
    GaussHermite,
    /// Degree-3 spherical–radial cubature, 2n nodes: exact for drifts of total degree ≤ 2.
    Cubature3,
    /// Degree-5 cubature (Stroud), 2n² + 1 nodes: exact for drifts of total degree ≤ 4.
    Cubature5,
}

/// Options of `gaussian-ksp-closure` ([`gaussian_ksp`]).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(default)]
#[non_exhaustive]
pub struct GaussianKspOptions {
    /// Largest Runge–Kutta step of the moment ODEs (as [`KalmanOptions::dt`]). Default: a tenth
    /// of the median interval between the measurement times, at most 0.01.
    pub dt: Option<f64>,
    /// The quadrature of the expectations. Default [`ExpectationRule::Auto`].
    pub rule: ExpectationRule,
    /// Gauss–Hermite points per axis (at least 1) for `auto` (up to 3 states) and
    /// `gauss-hermite`. Default `None`: see [`ExpectationRule`].
    pub gaussian_points: Option<usize>,
}

impl GaussianKspOptions {
    /// Sets the largest integration step.
    pub fn with_dt(mut self, dt: f64) -> Self {
        self.dt = Some(dt);
        self
    }

    /// Sets the rule and the Gauss–Hermite points per axis.
    pub fn with_rule(mut self, rule: ExpectationRule, gaussian_points: Option<usize>) -> Self {
        self.rule = rule;
        self.gaussian_points = gaussian_points;
        self
    }

    /// The quadrature rule on a model `sde` with `n` states.
    pub fn quadrature<S: Sde + ?Sized>(&self, sde: &S, n: usize) -> GaussianRule {
        match self.rule {
            ExpectationRule::Auto => gaussian_closure_rule(sde, n, self.gaussian_points),
            ExpectationRule::GaussHermite => {
                GaussianRule::GaussHermite { points_per_dim: self.gaussian_points.unwrap_or(5) }
            }
            ExpectationRule::Cubature3 => GaussianRule::Cubature3,
            ExpectationRule::Cubature5 => GaussianRule::Cubature5,
        }
    }

    fn kalman(&self) -> KalmanOptions {
        KalmanOptions { dt: self.dt, unscented: UnscentedParams::default() }
    }
}

impl EstimatorOptions for GaussianKspOptions {
    /// `gaussian-ksp-closure`: [`gaussian_ksp`].
    fn run<S: Sde + ?Sized>(
        &self,
        _method: Method,
        problem: &EstimationProblem<'_, S, StateMeasurement>,
    ) -> Result<MethodRun> {
        gaussian_ksp(problem, self).map(MethodRun::from)
    }

    /// Checks `dt` (positive, finite) and `gaussian_points` (at least 1).
    fn validate(&self) -> Result<()> {
        check_dt(self.dt)?;
        if self.gaussian_points == Some(0) {
            return Err(Error::InvalidOption {
                name: "gaussian_points".into(),
                reason: "must be at least 1, got 0".into(),
            });
        }
        Ok(())
    }
}

/// The Gaussian closure of the KSP smoother at `problem.theta` (see the module documentation):
/// the smoothed mean and standard deviations on the integration grid. The status is
/// [`Status::Converged`](crate::status::Status::Converged) (one forward and one backward sweep,
/// no iteration), or [`Status::NumericalFailure`](crate::status::Status::NumericalFailure)
/// when a covariance stops being positive definite (the details name the time).
///
/// Errors: those of [`super::filter`] (Gaussian measurement errors and unbounded Gaussian
/// initial-state priors are required); [`Error::InvalidOption`] (name `gaussian_points`) for a
/// rule with no points or more than 10⁷ nodes; (name `estimate`) when parameters are to be
/// estimated.
pub fn gaussian_ksp<S: Sde + ?Sized>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    options: &GaussianKspOptions,
) -> Result<PathEstimate> {
    options.validate()?;
    let n = problem.sde.dims().states();
    let rule = options.quadrature(problem.sde, n);
    estimate_with(
        problem,
        Method::GaussianKspClosure,
        Approximation::Quadrature(rule),
        &options.kalman(),
        true,
    )
}

#[cfg(test)]
mod tests;
