//! The effective-action interface and the dual (mean-optimal) estimator written once against it.
//!
//! # The interface a closure implements
//!
//! An [`EffectiveAction`] is anything that, for multipliers λ = (λ_1, …, λ_n) at the
//! measurement times t_1 < … < t_n (λ_k ∈ ℝˢ, s = the dimension of the measured variable Z),
//! can run the forward sweep with the jump conditions and return
//!
//! - the cumulant generating function F(λ) = Σ_k log W(t_k−)
//!   (`003_d2fc48a470e528fc.txt (I.55), (I.73)–(I.75)`; a closure's F is (II.51));
//! - its gradient z_k = ∂F/∂λ_k, obtained from the backward (adjoint) sweep as the history
//!   z(t_k) = ⟨Z A P⟩ (`(I.76)`, `(A.30)`; closures: (II.40), (II.53));
//! - optionally ∇²F, the multi-time covariance of Z under the tilted path measure (`(I.87)`).
//!   The provided default takes central differences of the gradient; the exact grid supplies it
//!   by tangent sweeps;
//! - the history of the state estimate at its output times ([`History`]), with, when it can,
//!   the covariances Cov(x_i(τ), Z_m) that give the ensemble dispersion between measurement
//!   times ([`super::dispersion::posterior_variance`]).
//!
//! Multipliers and gradients are laid out time-major: index `k · s + a` is component a of
//! λ_k. [`maximize_dual`] then finds the mean-optimal estimate and
//! [`super::dispersion`] its dispersion, for any implementation.
//!
//! # The dual problem
//!
//! With Gaussian measurement errors r_k = Z(t_k) + ρ_k, ρ_k ~ N(0, R_k) (`(I.51)–(I.53)`), the
//! estimate minimises H_*(z) = H_Z(z) + ½ Σ (r_k − z_k)ᵀR_k⁻¹(r_k − z_k) (`(I.59)`), where
//! H_Z is the Legendre transform of F (`(I.57)`). Its concave dual is
//!
//! $$ \Phi(\lambda) = \sum_k \lambda_k^\top r_k - \tfrac12 \sum_k \lambda_k^\top R_k \lambda_k - F(\lambda), $$
//!
//! maximised where λ_k = R_k⁻¹(r_k − z_k) (`(I.60)`); the estimate is z_k = ∂F/∂λ_k at the
//! optimum. [`maximize_dual`] runs Newton's method on Φ with a backtracking line search and stops
//! when the optimality residual max |λ_k − R_k⁻¹(r_k − z_k)| is below the tolerance.
//!
//! A Rayleigh–Ritz F need not be convex (`003_d2fc48a470e528fc.txt` Sec. II.1 after (II.16)):
//! where K = ∇²F + R is not positive definite Φ is not locally concave, the Newton direction is
//! not an ascent direction, and a line search along a barely regularised Newton direction
//! wanders. There [`maximize_dual`] takes trust-region steps instead (the exact subproblem by
//! an eigen-decomposition of K, Moré & Sorensen 1983; Nocedal & Wright, *Numerical
//! Optimization*, 2nd ed., Ch. 4, Alg. 4.1 and Thm 4.1), in the metric of R scaled by the
//! curvature (the multipliers D R^{1/2}λ, with D_ii = max(|K̃_ii|, 1)^{1/2} from the diagonal of
//! K̃ = R^{-1/2}KR^{-1/2}; Sec. 4.5),
//! which follow the negative-curvature directions of K uphill and converge to a local maximiser
//! (K positive semi-definite). Where K is positive
//! definite the Newton step with the line search is kept unchanged (the exact grid's F is a
//! cumulant generating function, convex, and never leaves this branch).

use std::fmt;

use nalgebra::{DMatrix, DVector, SymmetricEigen};
use serde::{Deserialize, Serialize};

use crate::estimate::Status;
use crate::{Error, Result};

/// F(λ) and its gradient z = ∂F/∂λ (time-major, length n · s).
#[derive(Debug, Clone, PartialEq)]
pub struct ActionValue {
    /// F(λ) = Σ_k log W(t_k−), `003_d2fc48a470e528fc.txt (I.73)–(I.75)`.
    pub value: f64,
    /// z_k = ∂F/∂λ_k = z(t_k), `(I.76)`, from the adjoint sweep.
    pub z: Vec<f64>,
}

/// The estimated history at the implementation's output times.
#[derive(Debug, Clone, PartialEq)]
pub struct History {
    /// Output times (including the measurement times).
    pub times: Vec<f64>,
    /// Estimate of every state (noisy then clean) at each time, ⟨x_i A P⟩ (`(I.76)` with Z = x_i).
    pub mean: Vec<Vec<f64>>,
    /// Variance of every state under the tilted measure A P at each time (not the ensemble
    /// dispersion: see [`super::dispersion::posterior_variance`]).
    pub variance: Vec<Vec<f64>>,
    /// When available: for each time, the matrix (states × n·s) of Cov(x_i(τ), Z_m) under the
    /// tilted path measure.
    pub cross: Option<Vec<DMatrix<f64>>>,
}

/// A discretised (exact or closure) effective action: see the [module documentation](self).
pub trait EffectiveAction {
    /// The measurement times t_1 < … < t_n.
    fn measurement_times(&self) -> &[f64];

    /// The dimension s of the measured variable Z.
    fn output_dim(&self) -> usize;

    /// F(λ) and z = ∂F/∂λ by one forward and one backward sweep. Where the sweep has no value
    /// (it fails, or its values overflow) F is returned non-finite and the caller backtracks;
    /// misuse (wrong length) is an error.
    fn evaluate(&mut self, lambda: &[f64]) -> Result<ActionValue>;

    /// ∇²F(λ) (n·s × n·s), or why the sweeps have none at λ. The default takes central
    /// differences of [`EffectiveAction::evaluate`] with steps 10⁻⁵(1 + |λ_m|) and symmetrises;
    /// override it when an exact Hessian is available.
    fn hessian(&mut self, lambda: &[f64]) -> Result<Swept<DMatrix<f64>>> {
        let m = lambda.len();
        let mut h = DMatrix::zeros(m, m);
        let mut l = lambda.to_vec();
        for j in 0..m {
            let step = 1e-5 * (1.0 + lambda[j].abs());
            l[j] = lambda[j] + step;
            let plus = self.evaluate(&l)?.z;
            l[j] = lambda[j] - step;
            let minus = self.evaluate(&l)?.z;
            l[j] = lambda[j];
            for i in 0..m {
                h[(i, j)] = (plus[i] - minus[i]) / (2.0 * step);
            }
        }
        Ok(Ok((&h + h.transpose()) * 0.5))
    }

    /// The history of the estimate at λ, or why the sweeps have none; with `cross`, also the
    /// cross-covariances Cov(x_i(τ), Z_m) when the implementation can compute them.
    fn history(&mut self, lambda: &[f64], cross: bool) -> Result<Swept<History>>;

    /// The history at λ with its cross-covariances, and ∇²F: what the ensemble dispersion needs
    /// ([`super::dispersion::posterior_variance`]). The default calls
    /// [`EffectiveAction::history`] and [`EffectiveAction::hessian`]; an implementation that
    /// gets both from the same tangent sweeps overrides it.
    fn history_and_hessian(&mut self, lambda: &[f64]) -> Result<Swept<(History, DMatrix<f64>)>> {
        let history = match self.history(lambda, true)? {
            Ok(h) => h,
            Err(e) => return Ok(Err(e)),
        };
        Ok(self.hessian(lambda)?.map(|h| (history, h)))
    }

    /// Where and why the last sweep that had no value failed, in words for the report (a
    /// closure's first unrealizable stage, say); `None` by default or when none failed.
    fn last_failure(&self) -> Option<&str> {
        None
    }

    /// The sweeps' relative and absolute tolerances, for an action whose sweeps have them (an
    /// adaptive integrator); `None` by default.
    fn tolerances(&self) -> Option<(f64, f64)> {
        None
    }

    /// Sets the sweeps' tolerances (see [`EffectiveAction::tolerances`]); the default ignores
    /// them. Errors: tolerances that are not positive and finite.
    fn set_tolerances(&mut self, _rtol: f64, _atol: f64) -> Result<()> {
        Ok(())
    }

    /// The sweeps run so far and their integration steps, for an action that counts them;
    /// `None` by default.
    fn work(&self) -> Option<Work> {
        None
    }
}

/// The work of an action's sweeps ([`EffectiveAction::work`]), a machine-independent measure of
/// its cost.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Work {
    /// Forward sweeps.
    pub sweeps: usize,
    /// Accepted integration steps.
    pub steps: usize,
    /// Integration steps attempted and rejected, by the error control or because a stage could
    /// not be evaluated (0 with fixed steps).
    pub rejected: usize,
}

impl std::ops::AddAssign for Work {
    fn add_assign(&mut self, other: Work) {
        self.sweeps += other.sweeps;
        self.steps += other.steps;
        self.rejected += other.rejected;
    }
}

/// Gaussian measurements of the dual problem, time-major (`k · s + a`): the data r and the
/// variances (diagonal of R_k). A NaN datum is missing: its multiplier is held at its starting
/// value (0 by default), i.e. R⁻¹ = 0 there (`003_d2fc48a470e528fc.txt` after (I.87)).
#[derive(Debug, Clone, PartialEq)]
pub struct DualData {
    /// The measurements r_k (NaN = missing).
    pub r: Vec<f64>,
    /// The measurement-error variances (positive and finite where r is not missing).
    pub variance: Vec<f64>,
    /// The dimension s of each r_k.
    pub output_dim: usize,
}

impl DualData {
    /// Checks lengths and that every present datum has a positive, finite variance.
    pub fn validate(&self, n_times: usize) -> Result<()> {
        let m = n_times * self.output_dim;
        crate::model::check_len("dual data r", m, self.r.len())?;
        crate::model::check_len("dual data variances", m, self.variance.len())?;
        for (i, (&r, &v)) in self.r.iter().zip(&self.variance).enumerate() {
            let present_ok = r.is_finite() && v.is_finite() && v > 0.0;
            if !r.is_nan() && !present_ok {
                return Err(Error::InvalidOption {
                    name: "measurement".into(),
                    reason: format!(
                        "entry {i}: need a finite datum and a positive finite variance, got r = {r}, R = {v}"
                    ),
                });
            }
        }
        Ok(())
    }

    /// Indices of the present (not missing) data.
    pub fn active(&self) -> Vec<usize> {
        (0..self.r.len()).filter(|&i| !self.r[i].is_nan()).collect()
    }
}

/// Options of [`maximize_dual`] (the option `dual` of the mean-optimal estimator and the dual
/// closures: `dual = { tolerance = 1e-8, max_iterations = 100 }`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
#[non_exhaustive]
pub struct DualOptions {
    /// Stop when max_m |λ_m − (r_m − z_m)/R_m| ≤ `tolerance` (the optimality condition
    /// `003_d2fc48a470e528fc.txt (I.60)`). Default 1e-9.
    pub tolerance: f64,
    /// Maximum Newton iterations. Default 50.
    pub max_iterations: usize,
    /// When set to k ≥ 1: stop, as `Acceptable`, once k full Newton steps (K positive definite,
    /// t = 1) have been taken since the optimality residual last fell to half of its reference
    /// value, the reference being the residual at the start, after that halving, or after the
    /// last trust-region step (which may raise it); damped Newton steps neither count nor reset.
    /// This is where the evaluation's own noise (e.g. coarse sweeps: F is smooth only piecewise in
    /// λ) stops the convergence. Default `None`.
    pub stall_iterations: Option<usize>,
    /// A stop short of `tolerance` (no ascent along the Newton direction, the trust region
    /// shrinking to nothing) is `Acceptable`, not `NumericalFailure`, when the optimality
    /// residual is at most this. Default `None`: 10³ × `tolerance`.
    pub acceptable_tolerance: Option<f64>,
}

impl Default for DualOptions {
    fn default() -> Self {
        DualOptions {
            tolerance: 1e-9,
            max_iterations: 50,
            stall_iterations: None,
            acceptable_tolerance: None,
        }
    }
}

impl DualOptions {
    /// Sets the tolerance.
    pub fn with_tolerance(mut self, tolerance: f64) -> Self {
        self.tolerance = tolerance;
        self
    }

    /// Sets the iteration limit.
    pub fn with_max_iterations(mut self, max_iterations: usize) -> Self {
        self.max_iterations = max_iterations;
        self
    }

    /// Sets the stall limit ([`DualOptions::stall_iterations`]).
    pub fn with_stall_iterations(mut self, stall_iterations: Option<usize>) -> Self {
        self.stall_iterations = stall_iterations;
        self
    }

    /// Sets the acceptable residual ([`DualOptions::acceptable_tolerance`]).
    pub fn with_acceptable_tolerance(mut self, acceptable: Option<f64>) -> Self {
        self.acceptable_tolerance = acceptable;
        self
    }

    /// The residual up to which a stop short of the tolerance is `Acceptable`.
    pub fn acceptable(&self) -> f64 {
        self.acceptable_tolerance.unwrap_or(1e3 * self.tolerance)
    }

    /// Checks a positive finite tolerance, a finite acceptable tolerance not below it and a stall
    /// limit of at least 1.
    pub fn validate(&self) -> Result<()> {
        if self.stall_iterations == Some(0) {
            return Err(Error::InvalidOption {
                name: "stall_iterations".into(),
                reason: "must be at least 1 (or none)".into(),
            });
        }
        if !(self.tolerance.is_finite() && self.tolerance > 0.0) {
            return Err(Error::InvalidOption {
                name: "tolerance".into(),
                reason: format!("must be positive and finite, got {}", self.tolerance),
            });
        }
        if let Some(a) = self.acceptable_tolerance {
            if !(a.is_finite() && a >= self.tolerance) {
                return Err(Error::InvalidOption {
                    name: "acceptable_tolerance".into(),
                    reason: format!("must be finite and at least the tolerance {}, got {a}", self.tolerance),
                });
            }
        }
        Ok(())
    }
}

/// The maximiser of the dual and how it was found.
#[derive(Debug, Clone, PartialEq)]
pub struct DualSolution {
    /// λ* (time-major).
    pub lambda: Vec<f64>,
    /// z* = ∂F/∂λ at λ*: the mean-optimal estimate at the measurement times.
    pub z: Vec<f64>,
    /// F(λ*).
    pub f_value: f64,
    /// Φ(λ*).
    pub phi: f64,
    /// The optimality residual max |λ_m − (r_m − z_m)/R_m| at λ*.
    pub residual: f64,
    /// Newton iterations.
    pub iterations: usize,
    /// Evaluations of F (sweeps), line-search trials included.
    pub evaluations: usize,
    /// The outcome.
    pub status: Status,
    /// ∇²F at the last iterate where [`EffectiveAction::hessian`] was computed (never a chord
    /// approximation of [`maximize_dual_chord`]), when one was.
    pub hessian: Option<DMatrix<f64>>,
    /// Why the maximisation stopped short of the tolerance (`None` when it converged or hit
    /// the iteration limit; set for `Acceptable` and `NumericalFailure`).
    pub reason: Option<DualStop>,
}

/// Why an effective action has no value at some multipliers: a numerical outcome of its sweeps
/// (reported in a status), not misuse.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
#[non_exhaustive]
pub enum SweepFailure {
    /// A closure's sweep left its family's moment space (unrealizable moments,
    /// `003_d2fc48a470e528fc.txt` Sec. II.1).
    Unrealizable,
}

impl fmt::Display for SweepFailure {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SweepFailure::Unrealizable => {
                f.write_str("the sweep left the family's moment space (unrealizable moments)")
            }
        }
    }
}

/// A value of an effective action's sweep, or why the sweep has none.
pub type Swept<T> = std::result::Result<T, SweepFailure>;

/// Why [`maximize_dual`] stopped short of its tolerance (with the optimality residual there);
/// written in reports as its sentence.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub enum DualStop {
    /// F or its gradient is not finite at the starting multipliers.
    NonFiniteStart,
    /// [`DualOptions::stall_iterations`] full Newton steps without halving the residual.
    Stalled {
        /// The full Newton steps.
        steps: usize,
        /// The optimality residual.
        residual: f64,
    },
    /// The line search along the Newton direction found no ascent.
    NoAscent {
        /// The optimality residual.
        residual: f64,
    },
    /// The trust region shrank to nothing without an increase of Φ.
    TrustRegionCollapsed {
        /// The optimality residual.
        residual: f64,
    },
    /// The quadratic model of Φ predicts no increase.
    NoModelIncrease {
        /// The optimality residual.
        residual: f64,
    },
    /// ∇²F is not finite, or the eigen-decomposition of ∇²F + R failed.
    CurvatureFailure {
        /// The optimality residual.
        residual: f64,
    },
    /// The curve of stationary points from the prior was lost before the data's precision
    /// ([`super::continuation::follow_branch`]).
    BranchLost {
        /// The last precision s reached (the data variances R/s).
        precision: f64,
        /// The folds it passed.
        folds: usize,
    },
    /// The curve of stationary points from the prior reached the data's precision at a saddle
    /// of the dual, not a maximum ([`super::continuation::follow_branch`]).
    Saddle {
        /// The folds it passed.
        folds: usize,
    },
    /// The sweep of ∇²F failed.
    Sweep {
        /// Why.
        failure: SweepFailure,
        /// The optimality residual.
        residual: f64,
    },
}

impl DualStop {
    fn of(why: NoStep, residual: f64) -> DualStop {
        match why {
            NoStep::NoAscent => DualStop::NoAscent { residual },
            NoStep::TrustRegionCollapsed => DualStop::TrustRegionCollapsed { residual },
            NoStep::NoModelIncrease => DualStop::NoModelIncrease { residual },
            NoStep::CurvatureFailure => DualStop::CurvatureFailure { residual },
        }
    }

    /// Whether the iteration stalled at the noise floor of its evaluations
    /// ([`DualOptions::stall_iterations`]).
    pub fn is_stall(&self) -> bool {
        matches!(self, DualStop::Stalled { .. })
    }
}

impl fmt::Display for DualStop {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            DualStop::NonFiniteStart => f.write_str("F or its gradient is not finite at the starting multipliers"),
            DualStop::Stalled { steps, residual } => write!(
                f,
                "stalled: {steps} full Newton steps without halving the optimality residual ({residual:.3e})"
            ),
            DualStop::NoAscent { residual } => write!(
                f,
                "the line search along the Newton direction found no ascent (optimality residual {residual:.3e})"
            ),
            DualStop::TrustRegionCollapsed { residual } => write!(
                f,
                "the trust region shrank to nothing without an increase of Φ (optimality residual {residual:.3e})"
            ),
            DualStop::NoModelIncrease { residual } => write!(
                f,
                "the quadratic model of Φ predicts no increase (optimality residual {residual:.3e})"
            ),
            DualStop::CurvatureFailure { residual } => write!(
                f,
                "non-finite ∇²F or a failed eigen-decomposition of ∇²F + R (optimality residual {residual:.3e})"
            ),
            DualStop::BranchLost { precision, folds } => write!(
                f,
                "the curve of stationary points from the prior was lost at {precision:.3e} of the data's precision, after {folds} fold(s): no estimate on that branch; the option branch = \"filter\" looks for another stationary point"
            ),
            DualStop::Saddle { folds } => write!(
                f,
                "the curve of stationary points from the prior reached the data's precision after {folds} fold(s) at a saddle of the dual (∇²F + R not positive definite), not a maximum: no estimate on that branch"
            ),
            DualStop::Sweep { failure, residual } => {
                write!(f, "the sweep of ∇²F failed: {failure} (optimality residual {residual:.3e})")
            }
        }
    }
}

impl Serialize for DualStop {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> std::result::Result<S::Ok, S::Error> {
        serializer.collect_str(self)
    }
}

/// Φ(λ) on the present data `active` with F(λ) = `f`.
pub(crate) fn phi(lambda: &[f64], data: &DualData, active: &[usize], f: f64) -> f64 {
    active
        .iter()
        .map(|&m| lambda[m] * data.r[m] - 0.5 * data.variance[m] * lambda[m] * lambda[m])
        .sum::<f64>()
        - f
}

/// The optimality residual max |λ_m − (r_m − z_m)/R_m| on the present data `active`.
pub(crate) fn residual(lambda: &[f64], z: &[f64], data: &DualData, active: &[usize]) -> f64 {
    active.iter().map(|&m| (lambda[m] - (data.r[m] - z[m]) / data.variance[m]).abs()).fold(0.0, f64::max)
}

/// [`trust_region_step_with`] with its eigen-decomposition of K (`None` when it fails).
#[cfg(test)]
fn trust_region_step(k: &DMatrix<f64>, g: &DVector<f64>, radius: f64) -> Option<(DVector<f64>, f64)> {
    let eig = eigen_of(k, g)?;
    trust_region_step_with(&eig, k, g, radius)
}

/// The eigen-decomposition of K for [`trust_region_step_with`]; `None` when K or g has
/// non-finite entries or the decomposition fails.
fn eigen_of(k: &DMatrix<f64>, g: &DVector<f64>) -> Option<SymmetricEigen<f64, nalgebra::Dyn>> {
    if k.iter().chain(g.iter()).any(|v| !v.is_finite()) {
        return None;
    }
    SymmetricEigen::try_new(k.clone(), f64::EPSILON, 0)
}

/// The trust-region subproblem of the dual: the step p maximising the quadratic model
/// m(p) = gᵀp − ½pᵀKp of Φ over ‖p‖ ≤ `radius` (K symmetric, possibly indefinite), with the
/// model increase m(p). By Moré & Sorensen (1983) (Nocedal & Wright, 2nd ed., Thm 4.1) p solves
/// (K + σI)p = g with σ ≥ 0, K + σI positive semi-definite and σ(radius − ‖p‖) = 0; with the
/// eigen-decomposition K = QΛQᵀ, p(σ) = Σ_i (q_iᵀg)/(Λ_i + σ) q_i and σ is the root of
/// 1/‖p(σ)‖ = 1/radius (Newton's method safeguarded by bisection); in the "hard case" (g
/// orthogonal to the eigenspace of the smallest eigenvalue) the step is completed along that
/// eigenvector to the boundary (N&W Sec. 4.3). The eigen-decomposition `eig` of K is given
/// ([`eigen_of`]), so that the retries with smaller radii of one iteration decompose K once.
/// `None` for a radius that is not positive or a non-finite step.
fn trust_region_step_with(
    eig: &SymmetricEigen<f64, nalgebra::Dyn>,
    k: &DMatrix<f64>,
    g: &DVector<f64>,
    radius: f64,
) -> Option<(DVector<f64>, f64)> {
    let n = g.len();
    if radius.is_nan() || radius <= 0.0 {
        return None;
    }
    let (lam, q) = (&eig.eigenvalues, &eig.eigenvectors);
    let c = q.transpose() * g;
    let lmin = lam.min();
    let scale = lam.amax().max(f64::MIN_POSITIVE);
    let gnorm = g.norm();
    let model = |p: &DVector<f64>| g.dot(p) - 0.5 * p.dot(&(k * p));
    let step = |sigma: f64, skip: &dyn Fn(usize) -> bool| {
        let mut p = DVector::zeros(n);
        for i in (0..n).filter(|&i| !skip(i)) {
            p.axpy(c[i] / (lam[i] + sigma), &q.column(i), 1.0);
        }
        p
    };
    let norm_at = |sigma: f64| (0..n).map(|i| (c[i] / (lam[i] + sigma)).powi(2)).sum::<f64>().sqrt();
    // Interior Newton step.
    if lmin > 1e-12 * scale && norm_at(0.0) <= radius {
        let p = step(0.0, &|_| false);
        let m = model(&p);
        return Some((p, m));
    }
    let sigma_lo = (-lmin).max(0.0);
    // Hard case: the smallest eigenspace carries (numerically) no gradient and the rest of the
    // step at σ = −Λ_1 stays inside the region.
    let degenerate = |i: usize| lam[i] <= lmin + 1e-12 * scale;
    let hard = lmin <= 1e-12 * scale
        && (0..n).filter(|&i| degenerate(i)).all(|i| c[i].abs() <= 1e-12 * gnorm.max(f64::MIN_POSITIVE));
    if hard {
        let rest = (0..n)
            .filter(|&i| !degenerate(i))
            .map(|i| (c[i] / (lam[i] + sigma_lo)).powi(2))
            .sum::<f64>()
            .sqrt();
        if rest <= radius {
            let mut p = step(sigma_lo, &degenerate);
            let j = (0..n).find(|&i| degenerate(i))?;
            let tau = (radius * radius - rest * rest).max(0.0).sqrt();
            p.axpy(tau, &q.column(j), 1.0);
            let m = model(&p);
            return Some((p, m));
        }
    }
    // ‖p(σ)‖ decreases on (σ_lo, ∞) and ‖p(σ_lo + ‖g‖/radius)‖ ≤ radius: bracket [lo, hi].
    let (mut lo, mut hi) = (sigma_lo, sigma_lo + gnorm / radius);
    let mut sigma = hi;
    for _ in 0..100 {
        let nrm = norm_at(sigma);
        let phi = 1.0 / nrm - 1.0 / radius;
        if phi.abs() <= 1e-10 / radius || hi - lo <= 1e-15 * hi.max(f64::MIN_POSITIVE) {
            break;
        }
        if phi < 0.0 {
            lo = sigma;
        } else {
            hi = sigma;
        }
        // d(1/‖p‖)/dσ = Σ c_i²/(Λ_i + σ)³ / ‖p‖³.
        let d3: f64 = (0..n).map(|i| c[i] * c[i] / (lam[i] + sigma).powi(3)).sum();
        let next = sigma - phi * nrm.powi(3) / d3;
        sigma = if next > lo && next < hi { next } else { 0.5 * (lo + hi) };
    }
    let p = step(sigma, &|_| false);
    if p.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let m = model(&p);
    Some((p, m))
}

/// The shortest fraction t of the Newton step that the line search tries (t = 1, ½, …, 2⁻¹⁰).
/// Where K is positive definite and no such step raises Φ (Armijo) or halves the residual, F is
/// far from its quadratic model or the evaluation's own noise is in the way (a closure's coarse
/// sweeps), and a shorter step is no progress: a step of 10⁻⁸ of Newton's accepted on Φ
/// differences of round-off size would be repeated by the next iteration. It applies to every
/// dual, the exact grid's included.
const MIN_STEP_FRACTION: f64 = 1.0 / 1024.0;

/// The first trust-region radius in the scaled multipliers D R^{1/2}λ: one standardised
/// residual (where D = 1).
const INITIAL_RADIUS: f64 = 1.0;

/// The diagonal scaling D of the trust region, from K̃ = R^{-1/2}KR^{-1/2} (K in the
/// standardised multipliers R^{1/2}λ; `sq` holds R_ii^{1/2}): D_ii = max(|K̃_ii|, 1)^{1/2}, so
/// that the region ‖D R^{1/2}Δλ‖ ≤ Δ is an ellipsoid, shorter along the multipliers on which Φ
/// is strongly curved and never longer than the unscaled ball (Nocedal & Wright, 2nd ed.,
/// Sec. 4.5, "Scaling": D from the diagonal of the Hessian, so that the quadratic model is
/// about equally trustworthy along every scaled direction). On long bistable records the
/// Gaussian closure's K is strongly curved along a few multipliers (those that decide a
/// transition) and mildly along the others, and an unscaled ball, limited by the former, makes
/// the iteration crawl.
fn trust_region_scaling(k: &DMatrix<f64>, sq: &[f64]) -> Vec<f64> {
    sq.iter().enumerate().map(|(i, q)| (k[(i, i)].abs() / (q * q)).max(1.0).sqrt()).collect()
}

/// The quadratic model of Φ in the multipliers Sλ for a diagonal S (`s`): K̂ = S⁻¹KS⁻¹ and
/// ĝ = S⁻¹g, so that the ball ‖p̂‖ ≤ Δ is the ellipsoid ‖Sp‖ ≤ Δ for the step p = S⁻¹p̂
/// ([`unscaled_step`]).
fn scaled_model(k: &DMatrix<f64>, g: &DVector<f64>, s: &[f64]) -> (DMatrix<f64>, DVector<f64>) {
    let n = s.len();
    (DMatrix::from_fn(n, n, |i, j| k[(i, j)] / (s[i] * s[j])), DVector::from_fn(n, |i, _| g[i] / s[i]))
}

/// Component i of the step p = S⁻¹p̂ in the multipliers of a step p̂ of [`scaled_model`].
fn unscaled_step(ph: &DVector<f64>, s: &[f64], i: usize) -> f64 {
    ph[i] / s[i]
}

/// Trust-region radius control (Nocedal & Wright, 2nd ed., Alg. 4.1): shrink to a quarter of the
/// step when the model predicted the change of Φ poorly (ρ < ¼), double it after a good step
/// (ρ > ¾) that reached the boundary.
fn update_radius(radius: f64, step_norm: f64, rho: f64) -> f64 {
    if rho < 0.25 {
        0.25 * step_norm
    } else if rho > 0.75 && step_norm >= 0.99 * radius {
        2.0 * radius
    } else {
        radius
    }
}

/// Maximises the dual Φ(λ) (see the [module documentation](self)) from `start` (default λ = 0):
/// where K = ∇²F + R is positive definite, Newton's method (Hessian −K) with a backtracking
/// (Armijo) line search; elsewhere a trust-region step ([`trust_region_step_with`], radius kept across
/// iterations). Components of missing data stay at their starting values.
///
/// Errors: misuse (lengths, invalid data or options). Non-convergence is a [`Status`]:
/// `MaxIterations`, or `NumericalFailure` with [`DualSolution::reason`] (no ascent along the
/// Newton direction down to [`MIN_STEP_FRACTION`] of the step, the trust region shrinking to
/// nothing, non-finite values), `Acceptable` when such a stop happens with the residual within
/// [`DualOptions::acceptable`] (default 10³ × the tolerance), and `Acceptable` (with a reason
/// starting "stalled") at the stall limit of [`DualOptions::stall_iterations`] whatever the
/// residual.
pub fn maximize_dual<A: EffectiveAction + ?Sized>(
    action: &mut A,
    data: &DualData,
    options: &DualOptions,
    start: Option<&[f64]>,
) -> Result<DualSolution> {
    maximize(action, data, options, start, None)
}

/// The symmetric rank-one update of the block `idx` × `idx` of `h` with the secant pair (s, y)
/// on those indices, y ≈ ∇²F s: h + vvᵀ/(vᵀs), v = y − hs, skipped (h unchanged) when
/// |vᵀs| < 10⁻⁸‖s‖‖v‖ (Nocedal & Wright, 2nd ed., Sec. 6.2, (6.24)–(6.26)); the other rows and
/// columns are left alone.
fn sr1(mut h: DMatrix<f64>, idx: &[usize], s: &DVector<f64>, y: &DVector<f64>) -> DMatrix<f64> {
    let v = DVector::from_fn(idx.len(), |i, _| {
        y[i] - idx.iter().zip(s.iter()).map(|(&j, sj)| h[(idx[i], j)] * sj).sum::<f64>()
    });
    let denom = v.dot(s);
    if denom.abs() >= 1e-8 * s.norm() * v.norm() && denom != 0.0 {
        for (a, &i) in idx.iter().enumerate() {
            for (b, &j) in idx.iter().enumerate() {
                h[(i, j)] += v[a] * v[b] / denom;
            }
        }
    }
    h
}

/// The factor by which a chord step of [`maximize_dual_chord`] must reduce the optimality
/// residual for the next iteration to keep its ∇²F approximation.
pub const CHORD_CONTRACTION: f64 = 0.1;

/// [`maximize_dual`] from `start` with a given approximation `hessian` of ∇²F (n·s × n·s), e.g.
/// ∇²F of the same action computed with coarser sweeps: the chord method (Kelley, *Iterative
/// Methods for Linear and Nonlinear Equations*, SIAM 1995, Sec. 5.4), whose Newton steps use
/// `hessian` (symmetrised) instead of a new ∇²F at every iterate, corrected after each step by
/// the symmetric rank-one update with the step's secant pair (Δλ, Δz) on the present data
/// (Nocedal & Wright, 2nd ed., Sec. 6.2: the updated matrix maps the last step Δλ to Δz, the
/// change of the exact gradient). It is kept while K = `hessian` + R is positive definite and
/// every chord step is a full step (t = 1) that reduces the optimality residual by at least
/// [`CHORD_CONTRACTION`]; from the first iteration where it is not, [`maximize_dual`]'s
/// iteration takes over with ∇²F at every iterate (a chord step whose line search finds no
/// ascent is taken again with ∇²F). The stationarity condition is that of [`maximize_dual`];
/// on a non-concave F the chord's steps may end at another stationary point than Newton's from
/// the same start. Errors as [`maximize_dual`], and a `hessian` of the wrong size or with
/// non-finite entries.
pub fn maximize_dual_chord<A: EffectiveAction + ?Sized>(
    action: &mut A,
    data: &DualData,
    options: &DualOptions,
    start: &[f64],
    hessian: DMatrix<f64>,
) -> Result<DualSolution> {
    let m = action.measurement_times().len() * action.output_dim();
    crate::model::check_len("chord Hessian rows", m, hessian.nrows())?;
    crate::model::check_len("chord Hessian columns", m, hessian.ncols())?;
    if hessian.iter().any(|v| !v.is_finite()) {
        return Err(Error::NonFinite { what: "chord Hessian".into() });
    }
    let symmetric = (&hessian + hessian.transpose()) * 0.5;
    maximize(action, data, options, Some(start), Some(symmetric))
}

/// The present data of a dual problem, with Φ and the optimality residual on them.
struct Present<'a> {
    data: &'a DualData,
    active: Vec<usize>,
}

impl Present<'_> {
    fn phi(&self, lambda: &[f64], f: f64) -> f64 {
        phi(lambda, self.data, &self.active, f)
    }

    fn residual(&self, lambda: &[f64], z: &[f64]) -> f64 {
        residual(lambda, z, self.data, &self.active)
    }

    /// K = ∇²F + R on the present data.
    fn k_of(&self, h: &DMatrix<f64>) -> DMatrix<f64> {
        let (active, data) = (&self.active, self.data);
        let na = active.len();
        DMatrix::from_fn(na, na, |i, j| {
            h[(active[i], active[j])] + if i == j { data.variance[active[i]] } else { 0.0 }
        })
    }

    /// g = r − Rλ − z on the present data.
    fn gradient(&self, lambda: &[f64], z: &[f64]) -> DVector<f64> {
        let (active, data) = (&self.active, self.data);
        DVector::from_fn(active.len(), |i, _| {
            let mi = active[i];
            data.r[mi] - data.variance[mi] * lambda[mi] - z[mi]
        })
    }

    /// λ + the step `p` (on the present data) scaled componentwise by `f(i, p_i)`.
    fn moved(&self, lambda: &[f64], p: impl Fn(usize) -> f64) -> Vec<f64> {
        let mut trial = lambda.to_vec();
        for (i, &mi) in self.active.iter().enumerate() {
            trial[mi] += p(i);
        }
        trial
    }
}

/// Why a step of one iteration found no increase of Φ.
#[derive(Debug, Clone, Copy, PartialEq)]
enum NoStep {
    NoAscent,
    TrustRegionCollapsed,
    NoModelIncrease,
    CurvatureFailure,
}

/// An accepted step: the new λ, its value, and whether it was the full Newton step.
type Step = (Vec<f64>, ActionValue, bool);

fn finite_value(v: &ActionValue) -> bool {
    v.value.is_finite() && v.z.iter().all(|x| x.is_finite())
}

/// The Newton step for K positive definite (Cholesky `ch`) with the Armijo backtracking line
/// search down to [`MIN_STEP_FRACTION`]; near the optimum Φ differences drown in rounding, so a
/// step that halves the optimality residual is also accepted.
fn newton_step<A: EffectiveAction + ?Sized>(
    action: &mut A,
    present: &Present<'_>,
    (lambda, cur): (&[f64], &ActionValue),
    (ch, g): (nalgebra::Cholesky<f64, nalgebra::Dyn>, &DVector<f64>),
    evaluations: &mut usize,
) -> Result<std::result::Result<Step, NoStep>> {
    let phi0 = present.phi(lambda, cur.value);
    let res0 = present.residual(lambda, &cur.z);
    let step = ch.solve(g);
    let slope = g.dot(&step);
    let mut t = 1.0;
    while t >= MIN_STEP_FRACTION {
        let trial = present.moved(lambda, |i| t * step[i]);
        let val = action.evaluate(&trial)?;
        *evaluations += 1;
        if finite_value(&val) {
            let phi1 = present.phi(&trial, val.value);
            if phi1 >= phi0 + 1e-4 * t * slope || present.residual(&trial, &val.z) < 0.5 * res0 {
                return Ok(Ok((trial, val, t == 1.0)));
            }
        }
        t *= 0.5;
    }
    Ok(Err(NoStep::NoAscent))
}

/// A trust-region step in the scaled multipliers D R^{1/2}λ (K̂ = S⁻¹KS⁻¹, ĝ = S⁻¹g with
/// S = D R^{1/2}, [`trust_region_scaling`]), accepted on the ratio ρ of the actual to the
/// predicted increase of Φ; `radius` is updated ([`update_radius`]).
fn trust_region_step_of<A: EffectiveAction + ?Sized>(
    action: &mut A,
    present: &Present<'_>,
    (lambda, cur): (&[f64], &ActionValue),
    (k, g): (&DMatrix<f64>, &DVector<f64>),
    radius: &mut f64,
    evaluations: &mut usize,
) -> Result<std::result::Result<Step, NoStep>> {
    let phi0 = present.phi(lambda, cur.value);
    let sq: Vec<f64> = present.active.iter().map(|&m| present.data.variance[m].sqrt()).collect();
    let d = trust_region_scaling(k, &sq);
    let s: Vec<f64> = sq.iter().zip(&d).map(|(a, b)| a * b).collect();
    let (ks, gs) = scaled_model(k, g, &s);
    let size = 1.0 + present.active.iter().zip(&s).map(|(&m, q)| (q * lambda[m]).powi(2)).sum::<f64>().sqrt();
    let eig = eigen_of(&ks, &gs);
    for _ in 0..60 {
        let Some((ps, predicted)) =
            eig.as_ref().and_then(|eig| trust_region_step_with(eig, &ks, &gs, *radius))
        else {
            return Ok(Err(NoStep::CurvatureFailure));
        };
        if predicted.is_nan() || predicted <= 0.0 {
            return Ok(Err(NoStep::NoModelIncrease));
        }
        let trial = present.moved(lambda, |i| unscaled_step(&ps, &s, i));
        let val = action.evaluate(&trial)?;
        *evaluations += 1;
        let rho = if finite_value(&val) {
            (present.phi(&trial, val.value) - phi0) / predicted
        } else {
            f64::NEG_INFINITY
        };
        *radius = update_radius(*radius, ps.norm(), rho);
        if rho > 1e-4 {
            return Ok(Ok((trial, val, false)));
        }
        if *radius <= 1e-12 * size {
            break;
        }
    }
    Ok(Err(NoStep::TrustRegionCollapsed))
}

/// The starting multipliers: `start` (checked) or zeros.
fn starting_multipliers(start: Option<&[f64]>, mdim: usize) -> Result<Vec<f64>> {
    match start {
        Some(l) => {
            crate::model::check_len("starting multipliers", mdim, l.len())?;
            if l.iter().any(|v| !v.is_finite()) {
                return Err(Error::NonFinite { what: "starting multipliers".into() });
            }
            Ok(l.to_vec())
        }
        None => Ok(vec![0.0; mdim]),
    }
}

/// The counters of [`maximize`]'s iteration that decide when it stalls
/// ([`DualOptions::stall_iterations`]): full Newton steps since the residual last fell to half
/// of `reference`.
struct Stall {
    slow: usize,
    reference: f64,
}

fn maximize<A: EffectiveAction + ?Sized>(
    action: &mut A,
    data: &DualData,
    options: &DualOptions,
    start: Option<&[f64]>,
    mut chord: Option<DMatrix<f64>>,
) -> Result<DualSolution> {
    options.validate()?;
    let n = action.measurement_times().len();
    let s = action.output_dim();
    crate::model::check_len("dual data output dimension", s, data.output_dim)?;
    data.validate(n)?;
    let mut lambda = starting_multipliers(start, n * s)?;
    let present = Present { data, active: data.active() };
    let mut cur = action.evaluate(&lambda)?;
    let mut evaluations = 1;
    let mut hessian = None;
    let mut iterations = 0;
    let mut reason = None;
    if !finite_value(&cur) {
        return Ok(DualSolution {
            residual: f64::NAN,
            phi: f64::NAN,
            f_value: cur.value,
            z: cur.z,
            lambda,
            iterations,
            evaluations,
            status: Status::NumericalFailure,
            hessian,
            reason: Some(DualStop::NonFiniteStart),
        });
    }
    // The trust-region radius (scaled multipliers), set when K is first not positive definite and
    // kept across iterations: each iteration reads it in its own metric D R^{1/2} (D from that
    // iteration's K, [`trust_region_scaling`]; Nocedal & Wright, Sec. 4.5).
    let mut tr_radius: Option<f64> = None;
    let mut stall = Stall { slow: 0, reference: present.residual(&lambda, &cur.z) };
    let status = loop {
        let res = present.residual(&lambda, &cur.z);
        if res <= options.tolerance {
            break Status::Converged;
        }
        if options.stall_iterations.is_some_and(|k| stall.slow >= k) {
            reason = Some(DualStop::Stalled { steps: stall.slow, residual: res });
            break Status::Acceptable;
        }
        if iterations >= options.max_iterations {
            break Status::MaxIterations;
        }
        iterations += 1;
        crate::estimate::progress::emit(crate::estimate::progress::ProgressEvent::Iteration {
            iteration: iterations,
            merit: res,
        });
        let g = present.gradient(&lambda, &cur.z);
        // The chord's K must be positive definite; otherwise ∇²F at λ from here on.
        let chord_k = chord.take().map(|h| {
            let k = present.k_of(&h);
            (h, k)
        });
        let (h, k, is_chord) = match chord_k {
            Some((h, k)) if k.clone().cholesky().is_some() => (h, k, true),
            _ => match action.hessian(&lambda)? {
                Ok(h) => {
                    let k = present.k_of(&h);
                    hessian = Some(h.clone());
                    (h, k, false)
                }
                Err(failure) => {
                    reason = Some(DualStop::Sweep { failure, residual: res });
                    break if res <= options.acceptable() {
                        Status::Acceptable
                    } else {
                        Status::NumericalFailure
                    };
                }
            },
        };
        let res0 = res;
        let here = (lambda.as_slice(), &cur);
        // Whether the accepted step is a Newton step at all (K positive definite).
        let (newton, accepted) = match k.clone().cholesky() {
            Some(ch) => (true, newton_step(action, &present, here, (ch, &g), &mut evaluations)?),
            None => {
                let radius = tr_radius.get_or_insert(INITIAL_RADIUS);
                (false, trust_region_step_of(action, &present, here, (&k, &g), radius, &mut evaluations)?)
            }
        };
        match accepted {
            Ok((l, v, full)) => {
                let res1 = present.residual(&l, &v.z);
                // A chord step keeps its ∇²F only as a full step that contracted; then with the
                // step's secant (s = Δλ, y = Δz on the present data) by the symmetric rank-one
                // update.
                if is_chord && full && res1 <= CHORD_CONTRACTION * res0 {
                    let active = &present.active;
                    let s = DVector::from_fn(active.len(), |i, _| l[active[i]] - lambda[active[i]]);
                    let y = DVector::from_fn(active.len(), |i, _| v.z[active[i]] - cur.z[active[i]]);
                    chord = Some(sr1(h, active, &s, &y));
                }
                lambda = l;
                cur = v;
                if res1 <= 0.5 * stall.reference || !newton {
                    stall = Stall { slow: 0, reference: res1 };
                } else if full {
                    stall.slow += 1;
                }
            }
            // A chord step that found no ascent: ∇²F at λ and the iteration again.
            Err(_) if is_chord => {}
            Err(why) => {
                reason = Some(DualStop::of(why, res0));
                break if res0 <= options.acceptable() {
                    Status::Acceptable
                } else {
                    Status::NumericalFailure
                };
            }
        }
    };
    Ok(DualSolution {
        residual: present.residual(&lambda, &cur.z),
        phi: present.phi(&lambda, cur.value),
        f_value: cur.value,
        z: cur.z,
        lambda,
        iterations,
        evaluations,
        status,
        hessian,
        reason,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    /// A Gaussian "effective action" F(λ) = μᵀλ + ½ λᵀCλ: the linear-Gaussian case, whose dual
    /// optimum is the Gaussian conditioning z* = μ + C(C + R)⁻¹(r − μ).
    struct Quadratic {
        times: Vec<f64>,
        mu: DVector<f64>,
        c: DMatrix<f64>,
    }

    impl EffectiveAction for Quadratic {
        fn measurement_times(&self) -> &[f64] {
            &self.times
        }
        fn output_dim(&self) -> usize {
            1
        }
        fn evaluate(&mut self, lambda: &[f64]) -> Result<ActionValue> {
            let l = DVector::from_column_slice(lambda);
            let z = &self.mu + &self.c * &l;
            Ok(ActionValue {
                value: self.mu.dot(&l) + 0.5 * l.dot(&(&self.c * &l)),
                z: z.iter().copied().collect(),
            })
        }
        fn history(&mut self, lambda: &[f64], _cross: bool) -> Result<Swept<History>> {
            let z = self.evaluate(lambda)?.z;
            Ok(Ok(History {
                times: self.times.clone(),
                mean: z.iter().map(|&v| vec![v]).collect(),
                variance: (0..z.len()).map(|i| vec![self.c[(i, i)]]).collect(),
                cross: None,
            }))
        }
    }

    #[test]
    fn quadratic_dual_is_gaussian_conditioning() {
        // C_ij = e^{−|t_i − t_j|} (a stationary OU covariance), μ = 0.3, R = 0.2 I.
        let times = vec![0.0, 0.5, 1.5, 2.0];
        let c = DMatrix::from_fn(4, 4, |i, j| (-(times[i] - times[j] as f64).abs()).exp());
        let mut q = Quadratic { times, mu: DVector::from_element(4, 0.3), c: c.clone() };
        let data = DualData { r: vec![1.0, -0.5, f64::NAN, 0.7], variance: vec![0.2; 4], output_dim: 1 };
        let sol = maximize_dual(&mut q, &data, &DualOptions::default(), None).unwrap();
        assert_eq!(sol.status, Status::Converged);
        assert!(sol.residual <= 1e-9);
        // Newton is exact on a quadratic: one step.
        assert_eq!(sol.iterations, 1);
        // Reference: conditioning on the three present data (indices 0, 1, 3).
        let a = [0usize, 1, 3];
        let caa = DMatrix::from_fn(3, 3, |i, j| c[(a[i], a[j])] + if i == j { 0.2 } else { 0.0 });
        let resid = DVector::from_fn(3, |i, _| data.r[a[i]] - 0.3);
        let w = caa.cholesky().unwrap().solve(&resid);
        for k in 0..4 {
            let expect = 0.3 + (0..3).map(|i| c[(k, a[i])] * w[i]).sum::<f64>();
            assert_relative_eq!(sol.z[k], expect, epsilon = 1e-12);
        }
        assert_eq!(sol.lambda[2], 0.0);
    }

    impl Quadratic {
        /// The trait's default (central-difference) Hessian of any action.
        fn default_hessian_of<A: EffectiveAction>(action: &mut A, lambda: &[f64]) -> DMatrix<f64> {
            struct Fd<'a, A>(&'a mut A);
            impl<A: EffectiveAction> EffectiveAction for Fd<'_, A> {
                fn measurement_times(&self) -> &[f64] {
                    self.0.measurement_times()
                }
                fn output_dim(&self) -> usize {
                    self.0.output_dim()
                }
                fn evaluate(&mut self, lambda: &[f64]) -> Result<ActionValue> {
                    self.0.evaluate(lambda)
                }
                fn history(&mut self, lambda: &[f64], cross: bool) -> Result<Swept<History>> {
                    self.0.history(lambda, cross)
                }
            }
            Fd(action).hessian(lambda).unwrap().unwrap()
        }
    }

    /// A convex, not quadratic F: μᵀλ + ½λᵀCλ + sΣ_i(e^{λ_i} − 1 − λ_i), with its exact Hessian
    /// C + s·diag(e^{λ_i}) and a count of Hessian evaluations.
    struct Exponentials {
        quadratic: Quadratic,
        s: f64,
        hessians: usize,
    }

    impl EffectiveAction for Exponentials {
        fn measurement_times(&self) -> &[f64] {
            &self.quadratic.times
        }
        fn output_dim(&self) -> usize {
            1
        }
        fn evaluate(&mut self, lambda: &[f64]) -> Result<ActionValue> {
            let mut v = self.quadratic.evaluate(lambda)?;
            for (zi, &l) in v.z.iter_mut().zip(lambda) {
                v.value += self.s * (l.exp() - 1.0 - l);
                *zi += self.s * (l.exp() - 1.0);
            }
            Ok(v)
        }
        fn hessian(&mut self, lambda: &[f64]) -> Result<Swept<DMatrix<f64>>> {
            self.hessians += 1;
            let mut h = self.quadratic.c.clone();
            for (i, &l) in lambda.iter().enumerate() {
                h[(i, i)] += self.s * l.exp();
            }
            Ok(Ok(h))
        }
        fn history(&mut self, lambda: &[f64], cross: bool) -> Result<Swept<History>> {
            self.quadratic.history(lambda, cross)
        }
    }

    #[test]
    fn chord_steps_save_hessians_and_reach_the_same_maximiser() {
        let times = vec![0.0, 0.5, 1.5, 2.0];
        let c = DMatrix::from_fn(4, 4, |i, j| (-(times[i] - times[j] as f64).abs()).exp());
        let mut f = Exponentials {
            quadratic: Quadratic { times, mu: DVector::from_element(4, 0.3), c },
            s: 0.5,
            hessians: 0,
        };
        let data = DualData { r: vec![1.0, -0.5, 2.0, 0.7], variance: vec![0.2; 4], output_dim: 1 };
        let options = DualOptions::default();
        let exact = maximize_dual(&mut f, &data, &options, None).unwrap();
        assert_eq!(exact.status, Status::Converged);
        assert!(exact.iterations >= 3, "not a test of the chord: {} Newton iterations", exact.iterations);
        // From a nearby start with ∇²F there: Newton needs a Hessian per iteration, the chord none.
        let start: Vec<f64> = exact.lambda.iter().map(|l| l + 0.01).collect();
        let h_start = f.hessian(&start).unwrap().unwrap();
        f.hessians = 0;
        let newton = maximize_dual(&mut f, &data, &options, Some(&start)).unwrap();
        assert_eq!((newton.status, f.hessians), (Status::Converged, newton.iterations));
        f.hessians = 0;
        let chord = maximize_dual_chord(&mut f, &data, &options, &start, h_start.clone()).unwrap();
        assert_eq!(chord.status, Status::Converged);
        assert_eq!(f.hessians, 0, "the chord computed ∇²F");
        for (a, b) in chord.lambda.iter().zip(&exact.lambda) {
            assert_relative_eq!(a, b, epsilon = 1e-10);
        }
        // A poor approximation (∇²F × 4) contracts too slowly: fresh Hessians take over.
        f.hessians = 0;
        let poor = maximize_dual_chord(&mut f, &data, &options, &start, h_start * 4.0).unwrap();
        assert_eq!(poor.status, Status::Converged);
        assert!(f.hessians >= 1 && f.hessians < poor.iterations, "{} of {}", f.hessians, poor.iterations);
        for (a, b) in poor.lambda.iter().zip(&exact.lambda) {
            assert_relative_eq!(a, b, epsilon = 1e-10);
        }
        // A Hessian of the wrong size is misuse.
        assert!(maximize_dual_chord(&mut f, &data, &options, &start, DMatrix::zeros(3, 3)).is_err());
    }

    /// [`Quadratic`] with ∇²F reported as 5C + 4R, so that K is reported as 5(C + R): every
    /// Newton step is a fifth of the true one, a full step (Φ rises along it), and leaves exactly
    /// 4/5 of the optimality residual (g ↦ (I − K(5K)⁻¹)g), the slow convergence of an
    /// evaluation whose derivatives do not match its values.
    struct Overstated(Quadratic, f64);

    impl EffectiveAction for Overstated {
        fn measurement_times(&self) -> &[f64] {
            self.0.measurement_times()
        }
        fn output_dim(&self) -> usize {
            1
        }
        fn evaluate(&mut self, lambda: &[f64]) -> Result<ActionValue> {
            self.0.evaluate(lambda)
        }
        fn hessian(&mut self, _lambda: &[f64]) -> Result<Swept<DMatrix<f64>>> {
            let n = self.0.c.nrows();
            Ok(Ok(&self.0.c * 5.0 + DMatrix::identity(n, n) * (4.0 * self.1)))
        }
        fn history(&mut self, lambda: &[f64], cross: bool) -> Result<Swept<History>> {
            self.0.history(lambda, cross)
        }
    }

    #[test]
    fn a_stalled_newton_iteration_stops_as_acceptable() {
        let times = vec![0.0, 0.5, 1.5, 2.0];
        let c = DMatrix::from_fn(4, 4, |i, j| (-(times[i] - times[j] as f64).abs()).exp());
        let mut slow = Overstated(Quadratic { times, mu: DVector::from_element(4, 0.3), c }, 0.2);
        let data = DualData { r: vec![1.0, -0.5, 2.0, 0.7], variance: vec![0.2; 4], output_dim: 1 };
        let plain = maximize_dual(&mut slow, &data, &DualOptions::default(), None).unwrap();
        assert_eq!(plain.status, Status::MaxIterations);
        let start = plain.residual / 0.8f64.powi(50);
        // Three full steps leave 0.8³ = 0.512 of the residual: stalled after the third.
        let options = DualOptions::default().with_stall_iterations(Some(3));
        let stalled = maximize_dual(&mut slow, &data, &options, None).unwrap();
        assert_eq!((stalled.status, stalled.iterations), (Status::Acceptable, 3));
        assert!(stalled.reason.unwrap().is_stall());
        assert!(stalled.reason.unwrap().to_string().starts_with("stalled"));
        assert_relative_eq!(stalled.residual, 0.512 * start, max_relative = 1e-9);
        // Four allowed: every fourth step halves the reference (0.8⁴ < ½) and the count restarts.
        let four = DualOptions::default().with_stall_iterations(Some(4));
        let later = maximize_dual(&mut slow, &data, &four, None).unwrap();
        assert_eq!(later.status, Status::MaxIterations);
        // A stall limit of 0 would stop before the first step.
        let zero = DualOptions::default().with_stall_iterations(Some(0));
        assert!(maximize_dual(&mut slow, &data, &zero, None).is_err());
    }

    /// F(λ) = ½aλ² (one multiplier) whose reported gradient is off by ε with the sign of
    /// λ − λ* (λ* = r/(R + a), the maximiser of the true Φ): the noise of a coarse sweep.
    struct Biased {
        times: Vec<f64>,
        a: f64,
        lambda_star: f64,
        eps: f64,
    }

    impl EffectiveAction for Biased {
        fn measurement_times(&self) -> &[f64] {
            &self.times
        }
        fn output_dim(&self) -> usize {
            1
        }
        fn evaluate(&mut self, lambda: &[f64]) -> Result<ActionValue> {
            let l = lambda[0];
            let bias = if l > self.lambda_star { self.eps } else { -self.eps };
            Ok(ActionValue { value: 0.5 * self.a * l * l, z: vec![self.a * l + bias] })
        }
        fn hessian(&mut self, _lambda: &[f64]) -> Result<Swept<DMatrix<f64>>> {
            Ok(Ok(DMatrix::from_element(1, 1, self.a)))
        }
        fn history(&mut self, lambda: &[f64], _cross: bool) -> Result<Swept<History>> {
            let z = self.evaluate(lambda)?.z;
            Ok(Ok(History {
                times: self.times.clone(),
                mean: vec![z],
                variance: vec![vec![self.a]],
                cross: None,
            }))
        }
    }

    #[test]
    fn the_line_search_stops_at_its_shortest_step() {
        // R = a = r = 1, λ* = ½, ε = 10⁻³, from λ* − δ: the Newton step p ≈ ε/(R + a) overshoots
        // λ*, the residual does not halve along it, and Armijo's test
        // Φ(λ + tp) − Φ(λ) = (R + a)(2δ − tp)tp/2 ≥ 10⁻⁴ t g p holds only for
        // t ≤ 2(R + a)δ/ε − 2·10⁻⁴ = 10⁻⁴ < 2⁻¹⁰. So no step is taken: one iteration of 11
        // trials (t = 1, …, 2⁻¹⁰), where 40 halvings accepted t = 2⁻¹⁴ and went on.
        let (a, eps) = (1.0, 1e-3);
        let delta = 3e-4 * eps / (2.0 * (1.0 + a));
        let mut action = Biased { times: vec![1.0], a, lambda_star: 0.5, eps };
        let data = DualData { r: vec![1.0], variance: vec![1.0], output_dim: 1 };
        let sol = maximize_dual(&mut action, &data, &DualOptions::default(), Some(&[0.5 - delta])).unwrap();
        assert_eq!(sol.status, Status::NumericalFailure);
        assert!(matches!(sol.reason, Some(DualStop::NoAscent { .. })), "{:?}", sol.reason);
        assert!(sol.reason.unwrap().to_string().contains("no ascent"));
        assert_eq!((sol.iterations, sol.evaluations), (1, 12));
        assert_eq!(sol.lambda, vec![0.5 - delta]);
        // Near the tolerance the same stop is `Acceptable`: within 10³ × the tolerance by
        // default, or within the acceptable tolerance given.
        let loose = DualOptions::default().with_tolerance(1e-5);
        let sol = maximize_dual(&mut action, &data, &loose, Some(&[0.5 - delta])).unwrap();
        assert_eq!(sol.status, Status::Acceptable);
        let wide = DualOptions::default().with_acceptable_tolerance(Some(1e-2));
        let sol = maximize_dual(&mut action, &data, &wide, Some(&[0.5 - delta])).unwrap();
        assert_eq!(sol.status, Status::Acceptable);
        let narrow = loose.clone().with_acceptable_tolerance(Some(1e-4));
        let sol = maximize_dual(&mut action, &data, &narrow, Some(&[0.5 - delta])).unwrap();
        assert_eq!(sol.status, Status::NumericalFailure);
        let below = loose.with_acceptable_tolerance(Some(1e-6));
        assert!(maximize_dual(&mut action, &data, &below, None).is_err());
    }

    #[test]
    fn sr1_meets_the_secant_condition_and_skips_a_degenerate_pair() {
        let h = DMatrix::from_row_slice(2, 2, &[2.0, 0.3, 0.3, 1.0]);
        let (s, y) = (DVector::from_vec(vec![0.5, -0.2]), DVector::from_vec(vec![1.4, 0.1]));
        let u = sr1(h.clone(), &[0, 1], &s, &y);
        let secant = &u * &s - &y;
        assert!(secant.amax() < 1e-14, "{secant}");
        assert!((&u - u.transpose()).amax() == 0.0);
        // y = hs: nothing to correct.
        assert_eq!(sr1(h.clone(), &[0, 1], &s, &(&h * &s)), h);
        // On a block: the other rows and columns stay.
        let h3 = DMatrix::from_row_slice(3, 3, &[2.0, 0.7, 0.3, 0.7, 5.0, 0.2, 0.3, 0.2, 1.0]);
        let u3 = sr1(h3.clone(), &[0, 2], &s, &y);
        assert_eq!((u3.row(1), u3.column(1)), (h3.row(1), h3.column(1)));
        let block = DMatrix::from_fn(2, 2, |i, j| u3[(2 * i, 2 * j)]);
        assert!((&block * &s - &y).amax() < 1e-14);
    }

    #[test]
    fn default_hessian_is_the_covariance() {
        let times = vec![0.0, 1.0];
        let c = DMatrix::from_row_slice(2, 2, &[2.0, 0.5, 0.5, 1.0]);
        let mut q = Quadratic { times, mu: DVector::zeros(2), c: c.clone() };
        let h = q.hessian(&[0.3, -0.2]).unwrap().unwrap();
        for i in 0..2 {
            for j in 0..2 {
                assert_relative_eq!(h[(i, j)], c[(i, j)], epsilon = 1e-9);
            }
        }
    }

    /// A non-concave dual: F(λ) = −Σ_i a_i cos((Qλ)_i − c_i) with Q orthogonal (a rotation), so
    /// that with R = ρI and r = ρQᵀc, Φ(λ) = ½ρ‖c‖² + Σ_i [a_i cos(μ_i − c_i) − ½ρ(μ_i − c_i)²],
    /// μ = Qλ. For 0 < a_i < 4ρ the only stationary point is μ = c (a_i|sin x| < ρ|x| for x ≠ 0),
    /// the global maximiser λ* = Qᵀc, while K = ∇²F + ρI = Qᵀdiag(ρ + a_i cos(μ_i − c_i))Q is
    /// indefinite wherever cos(μ_i − c_i) < −ρ/a_i.
    struct Cosines {
        times: Vec<f64>,
        q: DMatrix<f64>,
        a: Vec<f64>,
        c: Vec<f64>,
    }

    impl Cosines {
        fn new() -> Self {
            let (t1, t2) = (0.7f64, -0.4f64);
            let r1 = DMatrix::from_row_slice(
                3,
                3,
                &[t1.cos(), -t1.sin(), 0.0, t1.sin(), t1.cos(), 0.0, 0.0, 0.0, 1.0],
            );
            let r2 = DMatrix::from_row_slice(
                3,
                3,
                &[1.0, 0.0, 0.0, 0.0, t2.cos(), -t2.sin(), 0.0, t2.sin(), t2.cos()],
            );
            Cosines {
                times: vec![0.0, 1.0, 2.0],
                q: r1 * r2,
                a: vec![3.0, 2.5, 1.5],
                c: vec![0.5, -1.0, 0.25],
            }
        }
        fn lambda_star(&self) -> DVector<f64> {
            self.q.transpose() * DVector::from_column_slice(&self.c)
        }
        fn data(&self, rho: f64) -> DualData {
            DualData {
                r: (self.lambda_star() * rho).iter().copied().collect(),
                variance: vec![rho; 3],
                output_dim: 1,
            }
        }
    }

    impl EffectiveAction for Cosines {
        fn measurement_times(&self) -> &[f64] {
            &self.times
        }
        fn output_dim(&self) -> usize {
            1
        }
        fn evaluate(&mut self, lambda: &[f64]) -> Result<ActionValue> {
            let mu = &self.q * DVector::from_column_slice(lambda);
            let value = -(0..3).map(|i| self.a[i] * (mu[i] - self.c[i]).cos()).sum::<f64>();
            let dmu = DVector::from_fn(3, |i, _| self.a[i] * (mu[i] - self.c[i]).sin());
            Ok(ActionValue { value, z: (self.q.transpose() * dmu).iter().copied().collect() })
        }
        fn hessian(&mut self, lambda: &[f64]) -> Result<Swept<DMatrix<f64>>> {
            let mu = &self.q * DVector::from_column_slice(lambda);
            let d = DMatrix::from_fn(
                3,
                3,
                |i, j| if i == j { self.a[i] * (mu[i] - self.c[i]).cos() } else { 0.0 },
            );
            Ok(Ok(self.q.transpose() * d * &self.q))
        }
        fn history(&mut self, lambda: &[f64], _cross: bool) -> Result<Swept<History>> {
            let z = self.evaluate(lambda)?.z;
            Ok(Ok(History {
                times: self.times.clone(),
                mean: z.iter().map(|&v| vec![v]).collect(),
                variance: vec![vec![0.0]; 3],
                cross: None,
            }))
        }
    }

    #[test]
    fn cosine_action_derivatives_match_differences() {
        let mut f = Cosines::new();
        let l = [0.3, 2.9, -1.7];
        let v = f.evaluate(&l).unwrap();
        let h = f.hessian(&l).unwrap().unwrap();
        let fd = Quadratic::default_hessian_of(&mut f, &l);
        for m in 0..3 {
            let mut lp = l;
            let mut lm = l;
            lp[m] += 1e-6;
            lm[m] -= 1e-6;
            let d = (f.evaluate(&lp).unwrap().value - f.evaluate(&lm).unwrap().value) / 2e-6;
            assert_relative_eq!(v.z[m], d, epsilon = 1e-8);
            for j in 0..3 {
                assert_relative_eq!(h[(m, j)], fd[(m, j)], epsilon = 1e-7);
            }
        }
    }

    #[test]
    fn non_concave_dual_converges_to_the_maximiser_where_plain_newton_does_not() {
        let rho = 1.0;
        let mut f = Cosines::new();
        let data = f.data(rho);
        // Start where every cos(μ_i − c_i) = −1: K = Qᵀdiag(ρ − a_i)Q is negative definite.
        let start: Vec<f64> = (f.q.transpose() * DVector::from_fn(3, |i, _| f.c[i] + std::f64::consts::PI))
            .iter()
            .copied()
            .collect();
        let k0 = f.hessian(&start).unwrap().unwrap() + DMatrix::identity(3, 3) * rho;
        assert!(k0.clone().cholesky().is_none());
        // Plain Newton, λ ← λ + K⁻¹g, heads for the stationary points of Φ regardless of their
        // type and does not reach λ*.
        let star = f.lambda_star();
        let mut l = DVector::from_column_slice(&start);
        for _ in 0..50 {
            let v = f.evaluate(l.as_slice()).unwrap();
            let g = DVector::from_fn(3, |i, _| data.r[i] - rho * l[i] - v.z[i]);
            let k = f.hessian(l.as_slice()).unwrap().unwrap() + DMatrix::identity(3, 3) * rho;
            match k.lu().solve(&g) {
                Some(step) => l += step,
                None => break,
            }
        }
        assert!((&l - &star).amax() > 1e-3, "plain Newton reached λ* from this start");
        // The trust-region steps follow the negative curvature uphill to λ*.
        let sol = maximize_dual(&mut f, &data, &DualOptions::default(), Some(&start)).unwrap();
        assert_eq!(sol.status, Status::Converged, "{:?}", sol.reason);
        assert!(sol.residual <= 1e-9);
        for i in 0..3 {
            assert_relative_eq!(sol.lambda[i], star[i], epsilon = 1e-9);
        }
        // Φ(λ*) = ½ρ‖c‖² + Σ a_i.
        let phi_star = 0.5 * rho * f.c.iter().map(|c| c * c).sum::<f64>() + f.a.iter().sum::<f64>();
        assert_relative_eq!(sol.phi, phi_star, epsilon = 1e-10);
        assert!(sol.reason.is_none());
    }

    /// Checks the optimality conditions of the trust-region subproblem (Nocedal & Wright, 2nd ed.,
    /// Thm 4.1): (K + σI)p = g, ‖p‖ ≤ Δ, σ(Δ − ‖p‖) = 0, K + σI ⪰ 0, σ ≥ 0; and the model value.
    fn check_subproblem(k: &DMatrix<f64>, g: &DVector<f64>, radius: f64, expect_boundary: bool) {
        let (p, m) = trust_region_step(k, g, radius).unwrap();
        let n = g.len();
        assert!(p.norm() <= radius * (1.0 + 1e-9));
        assert_relative_eq!(m, g.dot(&p) - 0.5 * p.dot(&(k * &p)), epsilon = 1e-12);
        // σ from the residual of (K + σI)p = g along p.
        let kp = k * &p;
        let sigma = if p.norm() > 0.0 { (g - &kp).dot(&p) / p.dot(&p) } else { 0.0 };
        assert!(sigma >= -1e-9);
        for i in 0..n {
            assert_relative_eq!(kp[i] + sigma * p[i], g[i], epsilon = 1e-8);
        }
        let min_eig = SymmetricEigen::new(k.clone()).eigenvalues.min();
        assert!(min_eig + sigma >= -1e-8);
        if expect_boundary {
            assert_relative_eq!(p.norm(), radius, epsilon = 1e-8);
        } else {
            assert!(sigma.abs() <= 1e-9);
        }
        // No point of a few random directions on the boundary does better.
        for s in 0..20 {
            let d = DVector::from_fn(n, |i, _| ((i * 7 + s * 3) % 11) as f64 - 5.0);
            let q = &d * (radius / d.norm());
            assert!(g.dot(&q) - 0.5 * q.dot(&(k * &q)) <= m + 1e-10);
        }
    }

    #[test]
    fn the_scaled_trust_region_step_solves_the_ellipsoidal_subproblem() {
        // D from the diagonal of K̃ = R^{-1/2}KR^{-1/2}, at least 1.
        let k = DMatrix::from_row_slice(3, 3, &[40.0, 0.5, 0.0, 0.5, -0.02, 0.3, 0.0, 0.3, -900.0]);
        let r_sqrt = [0.2, 0.2, 0.5];
        let d = trust_region_scaling(&k, &r_sqrt);
        assert_relative_eq!(d[0], 1000.0f64.sqrt(), max_relative = 1e-15);
        assert_eq!(d[1], 1.0);
        assert_relative_eq!(d[2], 3600.0f64.sqrt(), max_relative = 1e-15);
        // The ball ‖p̂‖ ≤ Δ of the scaled model is the ellipsoid ‖Sp‖ ≤ Δ: the step p = S⁻¹p̂
        // meets Moré and Sorensen's conditions for it, (K + σS²)p = g with σ ≥ 0, K + σS²
        // positive semi-definite and ‖Sp‖ = Δ (K is indefinite), and the model increase is
        // gᵀp − ½pᵀKp.
        let s: Vec<f64> = r_sqrt.iter().zip(&d).map(|(a, b)| a * b).collect();
        let g = DVector::from_column_slice(&[1.0, -0.5, 0.25]);
        let (ks, gs) = scaled_model(&k, &g, &s);
        for radius in [0.01, 0.3, 5.0] {
            let (ph, m) = trust_region_step(&ks, &gs, radius).unwrap();
            let p = DVector::from_fn(3, |i, _| unscaled_step(&ph, &s, i));
            let s2 = DMatrix::from_diagonal(&DVector::from_fn(3, |i, _| s[i] * s[i]));
            let sp = DVector::from_fn(3, |i, _| s[i] * p[i]);
            assert_relative_eq!(sp.norm(), radius, max_relative = 1e-9);
            // σ from the residual g − Kp = σS²p, the same in every component.
            let res = &g - &k * &p;
            let sigma = res.dot(&(&s2 * &p)) / (&s2 * &p).norm_squared();
            assert!(sigma >= 0.0);
            assert!((&res - sigma * (&s2 * &p)).amax() <= 1e-8 * g.amax());
            let shifted = &k + sigma * &s2;
            assert!(shifted.symmetric_eigenvalues().min() >= -1e-8 * shifted.amax());
            assert_relative_eq!(m, g.dot(&p) - 0.5 * p.dot(&(&k * &p)), max_relative = 1e-12);
        }
        // A positive definite K and a region that holds the Newton step: the step is K⁻¹g.
        let kp = DMatrix::from_row_slice(3, 3, &[40.0, 0.5, 0.0, 0.5, 0.3, 0.1, 0.0, 0.1, 900.0]);
        let s: Vec<f64> = r_sqrt.iter().zip(trust_region_scaling(&kp, &r_sqrt)).map(|(a, b)| a * b).collect();
        let newton = kp.clone().cholesky().unwrap().solve(&g);
        let (ks, gs) = scaled_model(&kp, &g, &s);
        let (ph, _) = trust_region_step(&ks, &gs, 1e3).unwrap();
        for i in 0..3 {
            assert_relative_eq!(unscaled_step(&ph, &s, i), newton[i], max_relative = 1e-12);
        }
    }

    #[test]
    fn trust_region_step_solves_the_subproblem() {
        let k = DMatrix::from_row_slice(3, 3, &[2.0, 0.5, 0.0, 0.5, -1.0, 0.3, 0.0, 0.3, 0.5]);
        let g = DVector::from_column_slice(&[1.0, -0.5, 0.25]);
        // Indefinite K: always on the boundary.
        check_subproblem(&k, &g, 0.1, true);
        check_subproblem(&k, &g, 3.0, true);
        // Positive definite K: the Newton step inside a large region, on the boundary otherwise.
        let kp = DMatrix::from_row_slice(3, 3, &[2.0, 0.5, 0.0, 0.5, 1.0, 0.3, 0.0, 0.3, 0.5]);
        let newton = kp.clone().cholesky().unwrap().solve(&g);
        check_subproblem(&kp, &g, 2.0 * newton.norm(), false);
        let (p, _) = trust_region_step(&kp, &g, 2.0 * newton.norm()).unwrap();
        assert_relative_eq!((p - &newton).amax(), 0.0, epsilon = 1e-12);
        check_subproblem(&kp, &g, 0.5 * newton.norm(), true);
        // The hard case: g orthogonal to the eigenvector of the smallest eigenvalue.
        let kh = DMatrix::from_diagonal(&DVector::from_column_slice(&[-2.0, 1.0, 3.0]));
        let gh = DVector::from_column_slice(&[0.0, 1.0, 1.0]);
        check_subproblem(&kh, &gh, 5.0, true);
        let (p, _) = trust_region_step(&kh, &gh, 5.0).unwrap();
        assert!(p[0].abs() > 1.0);
        // Non-finite input is refused.
        assert!(trust_region_step(
            &DMatrix::from_element(1, 1, f64::NAN),
            &DVector::from_element(1, 1.0),
            1.0
        )
        .is_none());
    }
}
