//! The closure drift W(λ, t) = C⁻¹V of an exponential-family Ansatz and its Jacobian ∂W/∂λ.
//!
//! For a trial density p(x; λ) ∝ exp(λᵀM(x)) p_*(x) (`003_d2fc48a470e528fc.txt (II.36)`) the
//! moment equation of the closure is μ̇ = V(λ, t) with
//!
//! $$ V_a(\lambda, t) = \langle (\partial_t + \hat L^*) M_a \rangle_\lambda
//!    = \langle f\cdot\nabla M_a + D : \nabla\nabla M_a \rangle_\lambda , $$
//!
//! (`(II.3)`, D = ½GGᵀ, time-independent M) and, since μ̇ = C λ̇ with C = ∂μ/∂λ, the natural
//! parameters evolve by λ̇ = W(λ, t) := C⁻¹V (`(II.45)–(II.46)`). The averages are taken through
//! the family's quadrature nodes:
//!
//! - [`GaussianDrift`]: nodes m + Lξ_k that move with the mean and covariance; W is written once
//!   over the scalar and differentiated by dual numbers through the nodes (for one state, by the
//!   two-variable jets of [`super::jet`]);
//! - [`ExponentialDrift`]: the fixed nodes of an
//!   [`Exponential`](onsager_closures::Exponential) family, where ∂π_k/∂λ = π_k(M_k − μ) gives
//!   ∂V/∂λ = Cov(L*M, M) and ∂C/∂λ = the third cumulant (`(II.43)`) in closed form.
//!
//! Each family is one file of this folder (`gaussian.rs`, `exponential.rs`) that implements
//! [`ClosureDrift`] and, for its estimator, [`ClosureFamily`](super::ClosureFamily); this file
//! holds the trait, the outcomes it shares and their helpers.

mod exponential;
mod gaussian;
mod tensor;

pub use exponential::{ExponentialDrift, ExponentialFamily, NodeRule};
pub use gaussian::{exact_gauss_hermite_points, gaussian_closure_rule, GaussianDrift, GaussianFamily};

use crate::model::prior::{Prior, PriorDensity};
use crate::model::Sde;
use crate::{Error, Result};

/// (mean, variance) of a Gaussian, unbounded prior; an error naming the state otherwise.
pub(crate) fn gaussian_prior(p: &Prior, state: &str) -> Result<(f64, f64)> {
    match p.density {
        PriorDensity::Gaussian { mean, sd } if p.lower == f64::NEG_INFINITY && p.upper == f64::INFINITY => {
            Ok((mean, sd * sd))
        }
        _ => Err(Error::InvalidOption {
            name: "x0 prior".into(),
            reason: format!("the closures need a Gaussian initial prior (untruncated) for state `{state}`"),
        }),
    }
}

/// The band at each end of an axis of a closure's box, as a fraction of its width, in which
/// [`ClosureDrift::edge_mass`] weighs the density: with eight Gauss–Legendre points per panel,
/// it holds the outermost node for any number of panels and the three outermost at 12 (the
/// exact grid weighs its outer 1 % of cells, [`crate::action::exact::EDGE_MASS`]).
pub const EDGE_BAND: f64 = 0.02;

/// Why W could not be evaluated at λ: the density is not normalizable or its moments are not
/// realizable (a numerical outcome of a sweep, not misuse).
#[derive(Debug, Clone, PartialEq)]
pub struct Unrealizable(pub String);

/// The log-partition function and the first two cumulants of M at λ.
#[derive(Debug, Clone, PartialEq)]
pub struct FamilyMoments {
    /// F(λ) = log N(λ), `003_d2fc48a470e528fc.txt (II.38)`.
    pub log_partition: f64,
    /// μ = ∂F/∂λ.
    pub mean: Vec<f64>,
    /// C = ∂μ/∂λ (row-major R × R).
    pub covariance: Vec<f64>,
}

/// The dynamics of a closure in its natural parameters: λ̇ = W(λ, t), with the family's
/// cumulants (`003_d2fc48a470e528fc.txt (II.38), (II.46)`).
pub trait ClosureDrift {
    /// The number R of moment functions (the length of λ).
    fn n_params(&self) -> usize;

    /// The dimension of the state x of the family.
    fn state_dim(&self) -> usize;

    /// The box the family's densities are truncated to, one interval per state, if they are
    /// (an exponential family on a fixed box); `None` for a support of all of Rⁿ or one that is
    /// not known.
    fn support(&self) -> Option<Vec<(f64, f64)>> {
        None
    }

    /// Called at the start of every forward sweep, which begins at the initial λ: a family
    /// whose nodes follow the density puts them back on the initial density's frame, so that a
    /// sweep does not start on the frame where the last one ended (possibly far away, after a
    /// trial λ of the dual's line search). The default does nothing.
    fn start_sweep(&self) {}

    /// The largest mass of the density at λ near the edge of its box (within
    /// [`EDGE_BAND`] of the box's width from either end of an axis), with that axis, for a
    /// family truncated to a fixed box; `None` otherwise.
    fn edge_mass(&self, _lambda: &[f64]) -> Option<(usize, f64)> {
        None
    }

    /// W(λ, t) into `out`.
    fn w(&self, t: f64, lambda: &[f64], out: &mut [f64]) -> std::result::Result<(), Unrealizable>;

    /// W(λ, t) into `w` and ∂W/∂λ into `jac` (row-major R × R: `jac[a * R + b]` = ∂W_a/∂λ_b).
    fn w_jacobian(
        &self,
        t: f64,
        lambda: &[f64],
        w: &mut [f64],
        jac: &mut [f64],
    ) -> std::result::Result<(), Unrealizable>;

    /// W(λ, t) into `w`, ∂W/∂λ into `jac` (as [`ClosureDrift::w_jacobian`]) and the Hessian of
    /// the contraction κᵀW, ∂²(Σ_a κ_a W_a)/∂λ_i∂λ_j, into `hess` (row-major R × R, symmetric):
    /// what the tangent of the adjoint sweep needs (second-order adjoint).
    fn w_second(
        &self,
        t: f64,
        lambda: &[f64],
        kappa: &[f64],
        w: &mut [f64],
        jac: &mut [f64],
        hess: &mut [f64],
    ) -> std::result::Result<(), Unrealizable>;

    /// [`ClosureDrift::w_second`] at a point where the caller already has ∂W/∂λ in `jac` (from
    /// [`ClosureDrift::w_jacobian`] at the same (t, λ)): a family whose Jacobian is the same
    /// computation in both may skip it and leave `jac` as given; the default recomputes it.
    fn w_second_with_jacobian(
        &self,
        t: f64,
        lambda: &[f64],
        kappa: &[f64],
        w: &mut [f64],
        jac: &mut [f64],
        hess: &mut [f64],
    ) -> std::result::Result<(), Unrealizable> {
        self.w_second(t, lambda, kappa, w, jac, hess)
    }

    /// Whether the sweeps keep the Hessians ∇²W_a of every forward stage
    /// ([`ClosureDrift::w_jacobian_hessians`] instead of [`ClosureDrift::w_jacobian`]) and form
    /// the second-order adjoint's ∇²(κᵀW) = Σ_a κ_a∇²W_a from them, instead of evaluating W again
    /// at every stage of a Hessian's sweep ([`ClosureDrift::w_second_with_jacobian`]): worth it
    /// for a family whose R Hessians cost little more than its Jacobian and take few numbers
    /// (R³ per stage) to keep. Default false.
    fn keeps_hessians(&self) -> bool {
        false
    }

    /// W(λ, t) into `w`, ∂W/∂λ into `jac` (as [`ClosureDrift::w_jacobian`]) and the R Hessians
    /// ∇²W_a into `hessians` (R × R × R: ∂²W_a/∂λ_i∂λ_j at `hessians[(a * R + i) * R + j]`). The
    /// default takes them from [`ClosureDrift::w_second`] with κ = e_a, one call per a.
    fn w_jacobian_hessians(
        &self,
        t: f64,
        lambda: &[f64],
        w: &mut [f64],
        jac: &mut [f64],
        hessians: &mut [f64],
    ) -> std::result::Result<(), Unrealizable> {
        hessians_by_unit_contractions(self, t, lambda, w, jac, hessians)
    }

    /// F(λ), μ(λ), C(λ).
    fn moments(&self, lambda: &[f64]) -> std::result::Result<FamilyMoments, Unrealizable>;

    /// Index in M of the linear moment x_i (state i), if the family has it.
    fn linear_index(&self, state: usize) -> Option<usize>;

    /// Index in M of the square x_i², if the family has it.
    fn square_index(&self, state: usize) -> Option<usize>;
}

/// W, ∂W/∂λ and the R Hessians ∇²W_a by [`ClosureDrift::w_second`] with κ = e_a, one call per a
/// (the default of [`ClosureDrift::w_jacobian_hessians`]).
fn hessians_by_unit_contractions<C: ClosureDrift + ?Sized>(
    drift: &C,
    t: f64,
    lambda: &[f64],
    w: &mut [f64],
    jac: &mut [f64],
    hessians: &mut [f64],
) -> std::result::Result<(), Unrealizable> {
    let r = lambda.len();
    let mut kappa = vec![0.0; r];
    for (a, h) in hessians[..r * r * r].chunks_exact_mut(r * r).enumerate() {
        kappa[a] = 1.0;
        drift.w_second(t, lambda, &kappa, w, jac, h)?;
        kappa[a] = 0.0;
    }
    Ok(())
}

/// D = ½GGᵀ of the full state [x; z] (zero rows and columns for the clean states).
fn diffusion_matrix<S: Sde + ?Sized>(sde: &S, theta: &[f64]) -> Result<Vec<f64>> {
    let d = sde.dims();
    let g = sde.diffusion_matrix(theta)?;
    let gg = &g * g.transpose() * 0.5;
    let n = d.states();
    let mut out = vec![0.0; n * n];
    for i in 0..d.noisy {
        for j in 0..d.noisy {
            out[i * n + j] = gg[(i, j)];
        }
    }
    Ok(out)
}

fn unrealizable(e: onsager_closures::Error) -> Unrealizable {
    Unrealizable(e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::library::DoubleWell;
    use approx::assert_relative_eq;
    use onsager_closures::Exponential;

    pub(super) fn fd_jacobian<Dr: ClosureDrift>(dr: &Dr, t: f64, lambda: &[f64]) -> Vec<f64> {
        let r = lambda.len();
        let mut out = vec![0.0; r * r];
        let (mut wp, mut wm) = (vec![0.0; r], vec![0.0; r]);
        for b in 0..r {
            let h = 1e-6 * (1.0 + lambda[b].abs());
            let mut l = lambda.to_vec();
            l[b] += h;
            dr.w(t, &l, &mut wp).unwrap();
            l[b] -= 2.0 * h;
            dr.w(t, &l, &mut wm).unwrap();
            for a in 0..r {
                out[a * r + b] = (wp[a] - wm[a]) / (2.0 * h);
            }
        }
        out
    }

    /// ∇²(κᵀW) of `w_second` against central differences of κᵀ(∂W/∂λ) from `w_jacobian`,
    /// and its W, ∂W/∂λ against `w_jacobian`.
    fn check_second<Dr: ClosureDrift>(dr: &Dr, lambda: &[f64], kappa: &[f64], tol: f64) {
        let r = lambda.len();
        let (mut w, mut jac, mut hess) = (vec![0.0; r], vec![0.0; r * r], vec![0.0; r * r]);
        dr.w_second(0.3, lambda, kappa, &mut w, &mut jac, &mut hess).unwrap();
        let (mut w1, mut jac1) = (vec![0.0; r], vec![0.0; r * r]);
        dr.w_jacobian(0.3, lambda, &mut w1, &mut jac1).unwrap();
        for a in 0..r {
            assert_relative_eq!(w[a], w1[a], epsilon = 1e-12, max_relative = 1e-12);
        }
        for k in 0..r * r {
            assert_relative_eq!(jac[k], jac1[k], epsilon = 1e-10, max_relative = 1e-10);
        }
        let (mut jp, mut jm) = (vec![0.0; r * r], vec![0.0; r * r]);
        for j in 0..r {
            let h = 1e-6 * (1.0 + lambda[j].abs());
            let mut l = lambda.to_vec();
            l[j] += h;
            dr.w_jacobian(0.3, &l, &mut w1, &mut jp).unwrap();
            l[j] -= 2.0 * h;
            dr.w_jacobian(0.3, &l, &mut w1, &mut jm).unwrap();
            for i in 0..r {
                // ∂/∂λ_j of Σ_a κ_a ∂W_a/∂λ_i.
                let fd: f64 = (0..r).map(|a| kappa[a] * (jp[a * r + i] - jm[a * r + i]) / (2.0 * h)).sum();
                assert_relative_eq!(hess[i * r + j], fd, epsilon = tol, max_relative = tol);
                assert_relative_eq!(hess[i * r + j], hess[j * r + i], epsilon = 1e-12, max_relative = 1e-10);
            }
        }
    }

    #[test]
    fn second_order_drift_derivatives_match_finite_differences() {
        let g = GaussianDrift::try_new(&DoubleWell, &[0.5]).unwrap();
        let (m, v) = (0.4, 0.3);
        check_second(&g, &[m / v, -0.5 / v], &[0.7, -1.3], 1e-6);
        let family = Exponential::quartic(-3.0, 3.0).unwrap();
        let e = ExponentialDrift::try_new(&DoubleWell, &[0.5], family).unwrap();
        check_second(&e, &[0.3, 1.0, -0.2, -0.8], &[0.5, -0.25, 0.1, 0.8], 1e-5);
    }

    /// `w_second_with_jacobian` given the Jacobian of `w_jacobian` returns what `w_second`
    /// returns, bit for bit (the exponential family keeps the given Jacobian; the Gaussian
    /// recomputes it), also after an evaluation elsewhere (the reused work buffers).
    #[test]
    fn second_derivatives_with_a_given_jacobian_equal_w_second() {
        fn compare<Dr: ClosureDrift>(dr: &Dr, lambda: &[f64], kappa: &[f64]) {
            let r = lambda.len();
            let z = || (vec![0.0; r], vec![0.0; r * r], vec![0.0; r * r]);
            let ((mut w1, mut j1, mut h1), (mut w2, mut j2, mut h2)) = (z(), z());
            dr.w_second(0.3, lambda, kappa, &mut w1, &mut j1, &mut h1).unwrap();
            dr.w_jacobian(0.3, lambda, &mut w2, &mut j2).unwrap();
            let other: Vec<f64> = lambda.iter().map(|v| v * 0.9).collect();
            dr.w_jacobian(0.1, &other, &mut w2.clone(), &mut j2.clone()).unwrap();
            dr.w_second_with_jacobian(0.3, lambda, kappa, &mut w2, &mut j2, &mut h2).unwrap();
            for (a, b) in w1.iter().chain(&j1).chain(&h1).zip(w2.iter().chain(&j2).chain(&h2)) {
                assert_eq!(a.to_bits(), b.to_bits());
            }
        }
        let family = Exponential::quartic(-3.0, 3.0).unwrap();
        let e = ExponentialDrift::try_new(&DoubleWell, &[0.5], family).unwrap();
        compare(&e, &[0.3, 1.0, -0.2, -0.8], &[0.5, -0.25, 0.1, 0.8]);
        let g = GaussianDrift::try_new(&DoubleWell, &[0.5]).unwrap();
        compare(&g, &[0.4 / 0.3, -0.5 / 0.3], &[0.7, -1.3]);
    }
}
