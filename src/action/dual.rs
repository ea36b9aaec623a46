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

use nalgebra::{DMatrix, DVector};

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

    /// F(λ) and z = ∂F/∂λ by one forward and one backward sweep. A non-finite F is returned as
    /// such (the caller backtracks); misuse (wrong length) is an error.
    fn evaluate(&mut self, lambda: &[f64]) -> Result<ActionValue>;

    /// ∇²F(λ) (n·s × n·s). The default takes central differences of [`EffectiveAction::evaluate`]
    /// with steps 10⁻⁵(1 + |λ_m|) and symmetrises; override it when an exact Hessian is
    /// available.
    fn hessian(&mut self, lambda: &[f64]) -> Result<DMatrix<f64>> {
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
        Ok((&h + h.transpose()) * 0.5)
    }

    /// The history of the estimate at λ; with `cross`, also the cross-covariances
    /// Cov(x_i(τ), Z_m) when the implementation can compute them.
    fn history(&mut self, lambda: &[f64], cross: bool) -> Result<History>;
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

/// Options of [`maximize_dual`].
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct DualOptions {
    /// Stop when max_m |λ_m − (r_m − z_m)/R_m| ≤ `tolerance` (the optimality condition
    /// `003_d2fc48a470e528fc.txt (I.60)`). Default 1e-9.
    pub tolerance: f64,
    /// Maximum Newton iterations. Default 50.
    pub max_iterations: usize,
}

impl Default for DualOptions {
    fn default() -> Self {
        DualOptions { tolerance: 1e-9, max_iterations: 50 }
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

    /// Checks a positive finite tolerance.
    pub fn validate(&self) -> Result<()> {
        if !(self.tolerance.is_finite() && self.tolerance > 0.0) {
            return Err(Error::InvalidOption {
                name: "tolerance".into(),
                reason: format!("must be positive and finite, got {}", self.tolerance),
            });
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
    /// ∇²F at the last Newton iterate, when one was computed.
    pub hessian: Option<DMatrix<f64>>,
}

fn phi(lambda: &[f64], data: &DualData, active: &[usize], f: f64) -> f64 {
    active
        .iter()
        .map(|&m| lambda[m] * data.r[m] - 0.5 * data.variance[m] * lambda[m] * lambda[m])
        .sum::<f64>()
        - f
}

fn residual(lambda: &[f64], z: &[f64], data: &DualData, active: &[usize]) -> f64 {
    active.iter().map(|&m| (lambda[m] - (data.r[m] - z[m]) / data.variance[m]).abs()).fold(0.0, f64::max)
}

/// Solves K s = g by Cholesky; when K = ∇²F + R is not positive definite (a Rayleigh–Ritz F
/// need not be convex, `003_d2fc48a470e528fc.txt` Sec. II.1 after (II.16)) the diagonal is
/// shifted Levenberg–Marquardt style, τ = 10⁻⁸·max K_ii growing tenfold, so the step stays an
/// ascent direction with curvature information; the gradient itself as a last resort.
fn regularized_solve(k: &DMatrix<f64>, g: &DVector<f64>) -> DVector<f64> {
    if let Some(ch) = k.clone().cholesky() {
        return ch.solve(g);
    }
    let scale = k.diagonal().iter().fold(0.0f64, |m, v| m.max(v.abs())).max(f64::MIN_POSITIVE);
    let mut tau = 1e-8 * scale;
    for _ in 0..20 {
        let mut shifted = k.clone();
        for i in 0..k.nrows() {
            shifted[(i, i)] += tau;
        }
        if let Some(ch) = shifted.cholesky() {
            return ch.solve(g);
        }
        tau *= 10.0;
    }
    g.clone()
}

/// Maximises the dual Φ(λ) (see the [module documentation](self)) by Newton's method with the
/// Hessian −(∇²F + R) and a backtracking (Armijo) line search, from `start` (default λ = 0).
/// Components of missing data stay at their starting values.
///
/// Errors: misuse (lengths, invalid data or options). Non-convergence is a [`Status`].
pub fn maximize_dual<A: EffectiveAction + ?Sized>(
    action: &mut A,
    data: &DualData,
    options: &DualOptions,
    start: Option<&[f64]>,
) -> Result<DualSolution> {
    options.validate()?;
    let n = action.measurement_times().len();
    let s = action.output_dim();
    crate::model::check_len("dual data output dimension", s, data.output_dim)?;
    data.validate(n)?;
    let mdim = n * s;
    let mut lambda = match start {
        Some(l) => {
            crate::model::check_len("starting multipliers", mdim, l.len())?;
            if l.iter().any(|v| !v.is_finite()) {
                return Err(Error::NonFinite { what: "starting multipliers".into() });
            }
            l.to_vec()
        }
        None => vec![0.0; mdim],
    };
    let active = data.active();
    let mut cur = action.evaluate(&lambda)?;
    let mut evaluations = 1;
    if !cur.value.is_finite() || cur.z.iter().any(|v| !v.is_finite()) {
        return Ok(DualSolution {
            residual: f64::NAN,
            phi: f64::NAN,
            f_value: cur.value,
            z: cur.z,
            lambda,
            iterations: 0,
            evaluations,
            status: Status::NumericalFailure,
            hessian: None,
        });
    }
    let mut hessian = None;
    let mut iterations = 0;
    let status = loop {
        let res = residual(&lambda, &cur.z, data, &active);
        if res <= options.tolerance {
            break Status::Converged;
        }
        if iterations >= options.max_iterations {
            break Status::MaxIterations;
        }
        iterations += 1;
        let h = action.hessian(&lambda)?;
        let na = active.len();
        let mut k = DMatrix::zeros(na, na);
        let mut g = DVector::zeros(na);
        for (i, &mi) in active.iter().enumerate() {
            g[i] = data.r[mi] - data.variance[mi] * lambda[mi] - cur.z[mi];
            for (j, &mj) in active.iter().enumerate() {
                k[(i, j)] = h[(mi, mj)];
            }
            k[(i, i)] += data.variance[mi];
        }
        hessian = Some(h);
        let step = regularized_solve(&k, &g);
        let slope = g.dot(&step);
        let phi0 = phi(&lambda, data, &active, cur.value);
        let mut t = 1.0;
        let mut accepted = None;
        for _ in 0..40 {
            let mut trial = lambda.clone();
            for (i, &mi) in active.iter().enumerate() {
                trial[mi] += t * step[i];
            }
            let val = action.evaluate(&trial)?;
            evaluations += 1;
            let ok_values = val.value.is_finite() && val.z.iter().all(|v| v.is_finite());
            if ok_values {
                let phi1 = phi(&trial, data, &active, val.value);
                // Armijo; near the optimum Φ differences drown in rounding, so also accept a step
                // that decreases the optimality residual.
                if phi1 >= phi0 + 1e-4 * t * slope
                    || residual(&trial, &val.z, data, &active)
                        < 0.5 * residual(&lambda, &cur.z, data, &active)
                {
                    accepted = Some((trial, val));
                    break;
                }
            }
            t *= 0.5;
        }
        match accepted {
            Some((l, v)) => {
                lambda = l;
                cur = v;
            }
            None => {
                break if residual(&lambda, &cur.z, data, &active) <= 1e3 * options.tolerance {
                    Status::Acceptable
                } else {
                    Status::NumericalFailure
                };
            }
        }
    };
    Ok(DualSolution {
        residual: residual(&lambda, &cur.z, data, &active),
        phi: phi(&lambda, data, &active, cur.value),
        f_value: cur.value,
        z: cur.z,
        lambda,
        iterations,
        evaluations,
        status,
        hessian,
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
        fn history(&mut self, lambda: &[f64], _cross: bool) -> Result<History> {
            let z = self.evaluate(lambda)?.z;
            Ok(History {
                times: self.times.clone(),
                mean: z.iter().map(|&v| vec![v]).collect(),
                variance: (0..z.len()).map(|i| vec![self.c[(i, i)]]).collect(),
                cross: None,
            })
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

    #[test]
    fn default_hessian_is_the_covariance() {
        let times = vec![0.0, 1.0];
        let c = DMatrix::from_row_slice(2, 2, &[2.0, 0.5, 0.5, 1.0]);
        let mut q = Quadratic { times, mu: DVector::zeros(2), c: c.clone() };
        let h = q.hessian(&[0.3, -0.2]).unwrap();
        for i in 0..2 {
            for j in 0..2 {
                assert_relative_eq!(h[(i, j)], c[(i, j)], epsilon = 1e-9);
            }
        }
    }
}
