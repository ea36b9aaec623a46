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
//! - [`ExponentialDrift`]: the fixed nodes of an [`Exponential`] family, where
//!   ∂π_k/∂λ = π_k(M_k − μ) gives ∂V/∂λ = Cov(L*M, M) and ∂C/∂λ = the third cumulant
//!   (`(II.43)`) in closed form.

use num_dual::{Dual2SVec64, Dual2_64, Dual64, DualSVec64, HyperDual64};
use onsager_closures::{
    cholesky_into, cholesky_solve_in_place, dot, Exponential, Gaussian, GaussianRule, TrialFamily,
};

use super::jet::{Jet, OneStateScalar};
use crate::model::{Scalar, Sde};
use crate::{Error, Result};

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

/// Gauss–Hermite points per dimension that make the Gaussian closures' averages exact for a
/// state drift of total degree `degree` in the state: ⌊(d + 1)/2⌋ + 1.
///
/// The only quantities the Gaussian closures average over the nodes m + Lξ are ⟨f⟩ and
/// ⟨f (s − m)ᵀ⟩ (the moment equations ṁ = ⟨f⟩, Σ̇ = ⟨f(s − m)ᵀ⟩ + ⟨(s − m)fᵀ⟩ + 2D, i.e.
/// V = ⟨L*M⟩ of `003_d2fc48a470e528fc.txt (II.3)` for M = (s_i, s_is_j), and the same averages
/// in the moment-path action (II.56)); D is constant and the cumulants, the prior and the
/// measurement terms are closed forms. With f of total degree d, both integrands are
/// polynomials in ξ of total degree ≤ d + 1, so each exponent of ξ_i is ≤ d + 1, and the
/// tensor rule of k points per dimension, exact for ∏ξ_i^{a_i} with every a_i ≤ 2k − 1, is
/// exact when 2k − 1 ≥ d + 1. The derivatives in λ (or in (μ, v)) are then derivatives of
/// the exact polynomial expressions in (m, L), so W, ∂W/∂λ and ∇²(κᵀW) are exact too.
pub fn exact_gauss_hermite_points(degree: usize) -> usize {
    degree.div_ceil(2) + 1
}

/// The quadrature of the Gaussian closures on a `dim`-dimensional state: `points_per_dim`
/// Gauss–Hermite points per dimension when given; otherwise, when the model declares a
/// polynomial drift ([`Sde::drift_polynomial_degree`]) and `dim` ≤ 3, the fewest that make the
/// averages exact ([`exact_gauss_hermite_points`]: 2 points for a linear or quadratic drift,
/// 3 for a cubic) if that is fewer than [`GaussianRule::Auto`]'s 16 / 8 / 5; else
/// [`GaussianRule::Auto`].
pub fn gaussian_closure_rule<S: Sde + ?Sized>(
    sde: &S,
    dim: usize,
    points_per_dim: Option<usize>,
) -> GaussianRule {
    if let Some(k) = points_per_dim {
        return GaussianRule::GaussHermite { points_per_dim: k };
    }
    let auto = match dim {
        1 => 16,
        2 => 8,
        3 => 5,
        _ => return GaussianRule::Auto,
    };
    match sde.drift_polynomial_degree().map(exact_gauss_hermite_points) {
        Some(k) if k < auto => GaussianRule::GaussHermite { points_per_dim: k },
        _ => GaussianRule::Auto,
    }
}

/// The Gaussian closure of any model: M = (x_i, x_ix_j (i ≤ j)) on the full state [x; z]
/// ([`Gaussian`]). Between measurements the closure is the moment equation
/// ṁ = ⟨f⟩, Σ̇ = ⟨f(x − m)ᵀ⟩ + ⟨(x − m)fᵀ⟩ + 2D, the node averages taken by the family's rule
/// ([`gaussian_closure_rule`]: Gauss–Hermite or cubature; for a drift declared polynomial, the
/// smallest Gauss–Hermite rule that takes them exactly); it is mapped to the natural
/// parameters (a, b) = (Pm, −½P_ii, −P_ij) with Ṗ = −PΣ̇P, ȧ = Ṗm + Pṁ, which is W = C⁻¹V
/// (`003_d2fc48a470e528fc.txt (II.46)`) without forming C. Exact for linear drifts.
pub struct GaussianDrift<'a, S: Sde + ?Sized> {
    sde: &'a S,
    theta: Vec<f64>,
    family: Gaussian,
    diffusion: Vec<f64>,
}

impl<S: Sde + ?Sized> std::fmt::Debug for GaussianDrift<'_, S> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GaussianDrift").field("family", &self.family).finish()
    }
}

impl<'a, S: Sde + ?Sized> GaussianDrift<'a, S> {
    /// The Gaussian closure of `sde` at θ on the full state, with the automatic quadrature of
    /// [`gaussian_closure_rule`]. Errors: a singular or non-finite G.
    pub fn try_new(sde: &'a S, theta: &[f64]) -> Result<Self> {
        Self::try_with_points(sde, theta, None)
    }

    /// As [`GaussianDrift::try_new`] with `points_per_dim` Gauss–Hermite points per dimension
    /// (`None`: automatic, [`gaussian_closure_rule`]). Errors: a singular or non-finite G;
    /// [`Error::InvalidOption`] (`gaussian points`) for 0 points, more than the Gauss–Hermite
    /// rules have, or a tensor rule of more than 10⁷ nodes.
    pub fn try_with_points(sde: &'a S, theta: &[f64], points_per_dim: Option<usize>) -> Result<Self> {
        let n = sde.dims().states();
        let family = Gaussian::try_new(n)
            .map_err(|e| Error::InvalidOption {
                name: "model".into(),
                reason: format!("Gaussian closure: {e}"),
            })?
            .with_rule(gaussian_closure_rule(sde, n, points_per_dim))
            .map_err(|e| Error::InvalidOption {
                name: "gaussian points".into(),
                reason: format!("Gaussian closure quadrature: {e}"),
            })?;
        Ok(GaussianDrift { sde, theta: theta.to_vec(), family, diffusion: diffusion_matrix(sde, theta)? })
    }

    /// The family.
    pub fn family(&self) -> &Gaussian {
        &self.family
    }

    /// W(λ, t) generic over the scalar (see the type's documentation); one state by
    /// [`GaussianDrift::w_one_state`].
    fn w_generic<D: Scalar>(
        &self,
        t: f64,
        lambda: &[D],
        out: &mut [D],
    ) -> std::result::Result<(), Unrealizable> {
        if self.family.dim() == 1 {
            self.w_one_state(t, lambda, out)
        } else {
            self.w_any_dimension(t, lambda, out)
        }
    }

    /// W(λ, t) of [`GaussianDrift::w_any_dimension`] written out for one state, where the
    /// matrices are scalars: with λ = (a, b), P = −2b, v = 1/P, m = av and the nodes m + √v ξ_k,
    /// ṁ = ⟨f⟩, v̇ = 2⟨f(x − m)⟩ + 2D, Ṗ = −P²v̇, W = (Ṗm + Pṁ, −½Ṗ): the formulas of the
    /// general form without its buffers, Cholesky factors and matrix loops (this runs at every
    /// Runge–Kutta stage, in jets or dual numbers); equal to it to round-off.
    fn w_one_state<D: OneStateScalar>(
        &self,
        t: f64,
        lambda: &[D],
        out: &mut [D],
    ) -> std::result::Result<(), Unrealizable> {
        let q = self.family.quadratic_index(0, 0).expect("one state");
        let p = -(lambda[q] * 2.0);
        if !(p.value() > 0.0 && p.value().is_finite()) {
            return Err(Unrealizable(
                "the precision matrix P (P_ii = -2 b_ii, P_ij = -b_ij) is not positive definite".into(),
            ));
        }
        let v = p.reciprocal();
        let m = v * lambda[0];
        let sd = v.square_root();
        if !(m.value().is_finite() && v.value().is_finite()) {
            return Err(Unrealizable("the mean or covariance overflows".into()));
        }
        // The node sums in numbers at (m₀, s₀) = the values of (m, √v): A(m, s) = ⟨f⟩ =
        // Σ_k w_k f(m + sξ_k) and G(m, s) = Σ_k (w_kξ_k) f(m + sξ_k) (so ⟨f(x − m)⟩ = sG) with
        // their first and second partial derivatives, node sums of f, f′ and f″
        // (∂/∂m f(x_k) = f′(x_k), ∂/∂s f(x_k) = ξ_k f′(x_k)) taken in one pass of a scalar
        // second-order dual number in x; their dependence on λ by the second-order Taylor lift
        // of [`OneStateScalar::lift`], exact (to round-off) for every scalar of derivative
        // order ≤ 2. A non-finite sum (f′ or f″ not finite at a node) makes W non-finite, an
        // error, for every scalar.
        let (m0, s0) = (m.value(), sd.value());
        let mut a = [0.0; 6];
        let mut g = [0.0; 6];
        self.one_state_node_sums(t, m0, s0, &mut a, &mut g);
        let fbar = D::lift(&a, m, sd);
        let fx = D::lift(&g, m, sd) * sd;
        let vdot = fx + fx + self.diffusion[0] * 2.0;
        let pdot = -(p * vdot * p);
        out[0] = pdot * m + p * fbar;
        out[q] = -pdot * 0.5;
        if out.iter().any(|v| !v.value().is_finite()) {
            return Err(Unrealizable("the Gaussian closure drift is not finite".into()));
        }
        Ok(())
    }

    /// The node sums of [`GaussianDrift::w_one_state`] at the nodes m + sξ_k: for A = Σ w_k f(x_k)
    /// and G = Σ (w_kξ_k) f(x_k), (value, ∂_m, ∂_s, ∂²_m, ∂_m∂_s, ∂²_s) into `a` and `g`.
    fn one_state_node_sums(&self, t: f64, m: f64, s: f64, a: &mut [f64; 6], g: &mut [f64; 6]) {
        let nt = self.theta.len();
        crate::model::ad::with_zeros(nt + 2, |buf: &mut [Dual2_64]| {
            let (theta, rest) = buf.split_at_mut(nt);
            let (x, f) = rest.split_at_mut(1);
            for (t, &v) in theta.iter_mut().zip(&self.theta) {
                *t = Dual2_64::from(v);
            }
            // One state: the rule's points are the ξ_k themselves.
            debug_assert_eq!(self.family.dim(), 1);
            let rule = self.family.standard_rule();
            for (&xi, &w) in rule.points().iter().zip(rule.weights()) {
                x[0] = Dual2_64::new(m + s * xi, 1.0, 0.0);
                self.sde.state_drift(Dual2_64::from(t), x, theta, f);
                let (f0, f1, f2) = (f[0].re, f[0].v1, f[0].v2);
                let (wx, wxx) = (w * xi, w * xi * xi);
                let node = [f0 * w, f1 * w, f1 * wx, f2 * w, f2 * wx, f2 * wxx];
                let moved = [f0 * wx, f1 * wx, f1 * wxx, f2 * wx, f2 * wxx, f2 * wxx * xi];
                for c in 0..6 {
                    a[c] += node[c];
                    g[c] += moved[c];
                }
            }
        })
    }

    /// W(λ, t) in any dimension, generic over the scalar (see the type's documentation).
    fn w_any_dimension<D: Scalar>(
        &self,
        t: f64,
        lambda: &[D],
        out: &mut [D],
    ) -> std::result::Result<(), Unrealizable> {
        let n = self.family.dim();
        let nt = self.theta.len();
        // All work vectors in one buffer of zeros (on the stack for small models: this runs at
        // every Runge–Kutta stage).
        crate::model::ad::with_zeros(8 * n * n + 5 * n + nt, |buf: &mut [D]| {
            let (m, rest) = buf.split_at_mut(n);
            let (s, rest) = rest.split_at_mut(n * n);
            let (p, rest) = rest.split_at_mut(n * n);
            let (lp, rest) = rest.split_at_mut(n * n);
            let (l, rest) = rest.split_at_mut(n * n);
            self.family.mean_cov_precision_into(lambda, m, s, p, lp).map_err(unrealizable)?;
            // Nodes m + Lξ_k of the family's standard rule (Σ = LLᵀ), formed one at a time.
            cholesky_into(s, n, l).map_err(unrealizable)?;
            self.w_nodes(t, m, p, l, rest, out)
        })
    }

    /// The node averages and the map to natural parameters of [`GaussianDrift::w_generic`],
    /// given m, P = Σ⁻¹ and the factor L of Σ; `buf` (zeros, length ≥ nθ + 4n + 4n²) holds
    /// the work vectors.
    fn w_nodes<D: Scalar>(
        &self,
        t: f64,
        m: &[D],
        p: &[D],
        l: &[D],
        buf: &mut [D],
        out: &mut [D],
    ) -> std::result::Result<(), Unrealizable> {
        let n = self.family.dim();
        let nt = self.theta.len();
        let (theta, rest) = buf.split_at_mut(nt);
        let (f, rest) = rest.split_at_mut(n);
        let (fbar, rest) = rest.split_at_mut(n);
        let (x, rest) = rest.split_at_mut(n);
        let (dx, rest) = rest.split_at_mut(n);
        let (fx, rest) = rest.split_at_mut(n * n);
        let (sdot, rest) = rest.split_at_mut(n * n);
        let (ps, pdot) = rest.split_at_mut(n * n);
        for (t, &v) in theta.iter_mut().zip(&self.theta) {
            *t = D::from(v);
        }
        for (xi, w) in self.family.standard_rule().iter() {
            for i in 0..n {
                let mut v = D::zero();
                for (k, &xik) in xi.iter().enumerate().take(i + 1) {
                    v += l[i * n + k] * xik;
                }
                dx[i] = v;
                x[i] = m[i] + v;
            }
            self.sde.state_drift(D::from(t), x, theta, f);
            for i in 0..n {
                let fw = f[i] * w;
                fbar[i] += fw;
                for j in 0..n {
                    fx[i * n + j] += fw * dx[j];
                }
            }
        }
        // Σ̇ = ⟨f(x − m)ᵀ⟩ + ⟨(x − m)fᵀ⟩ + 2D; P = Σ⁻¹; Ṗ = −PΣ̇P; ȧ = Ṗm + Pṁ.
        for k in 0..n * n {
            sdot[k] = fx[k] + fx[(k % n) * n + k / n] + self.diffusion[k] * 2.0;
        }
        for i in 0..n {
            for j in 0..n {
                ps[i * n + j] = (0..n).map(|k| p[i * n + k] * sdot[k * n + j]).sum();
            }
        }
        for i in 0..n {
            for j in 0..n {
                pdot[i * n + j] = -(0..n).map(|k| ps[i * n + k] * p[k * n + j]).sum::<D>();
            }
        }
        for i in 0..n {
            out[i] = (0..n).map(|j| pdot[i * n + j] * m[j] + p[i * n + j] * fbar[j]).sum();
        }
        for i in 0..n {
            for j in i..n {
                let q = self.family.quadratic_index(i, j).expect("in range");
                out[q] = if i == j { -pdot[i * n + i] * 0.5 } else { -pdot[i * n + j] };
            }
        }
        if out.iter().any(|v| !v.re().is_finite()) {
            return Err(Unrealizable("the Gaussian closure drift is not finite".into()));
        }
        Ok(())
    }
}

impl<S: Sde + ?Sized> GaussianDrift<'_, S> {
    /// W and ∂W/∂λ by one dual-number pass per column (any R).
    fn w_jacobian_columns(
        &self,
        t: f64,
        lambda: &[f64],
        w: &mut [f64],
        jac: &mut [f64],
    ) -> std::result::Result<(), Unrealizable> {
        let r = lambda.len();
        let mut ld: Vec<Dual64> = lambda.iter().map(|&v| Dual64::from(v)).collect();
        let mut out = vec![Dual64::from(0.0); r];
        for b in 0..r {
            ld[b].eps = 1.0;
            self.w_generic(t, &ld, &mut out)?;
            ld[b].eps = 0.0;
            for a in 0..r {
                jac[a * r + b] = out[a].eps;
                w[a] = out[a].re;
            }
        }
        Ok(())
    }

    /// W, ∂W/∂λ and ∇²(κᵀW) by one hyper-dual pass per pair a ≤ b (any R).
    fn w_second_pairs(
        &self,
        t: f64,
        lambda: &[f64],
        kappa: &[f64],
        w: &mut [f64],
        jac: &mut [f64],
        hess: &mut [f64],
    ) -> std::result::Result<(), Unrealizable> {
        let r = lambda.len();
        let mut ld: Vec<HyperDual64> = lambda.iter().map(|&v| HyperDual64::from(v)).collect();
        let mut out = vec![HyperDual64::from(0.0); r];
        for a in 0..r {
            for b in a..r {
                ld[a].eps1 = 1.0;
                ld[b].eps2 = 1.0;
                self.w_generic(t, &ld, &mut out)?;
                ld[a].eps1 = 0.0;
                ld[b].eps2 = 0.0;
                if b == a {
                    for c in 0..r {
                        jac[c * r + a] = out[c].eps1;
                        w[c] = out[c].re;
                    }
                }
                let h: f64 = (0..r).map(|c| kappa[c] * out[c].eps1eps2).sum();
                hess[a * r + b] = h;
                hess[b * r + a] = h;
            }
        }
        Ok(())
    }

    /// W and ∂W/∂λ of one state (R = 2) in one pass of [`Jet`]s (the formulas of
    /// [`GaussianDrift::w_one_state`]); the jets of W, whose second-order parts are those of
    /// ∇²W_a when `SECOND`.
    fn one_state_jets<const SECOND: bool>(
        &self,
        t: f64,
        lambda: &[f64],
        w: &mut [f64],
        jac: &mut [f64],
    ) -> std::result::Result<[Jet<SECOND>; 2], Unrealizable> {
        let ld = [Jet::variable(lambda[0], 0), Jet::variable(lambda[1], 1)];
        let mut out = ld;
        self.w_one_state(t, &ld, &mut out)?;
        for (a, o) in out.iter().enumerate() {
            w[a] = o.v;
            jac[2 * a..2 * a + 2].copy_from_slice(&o.g);
        }
        Ok(out)
    }

    /// W, ∂W/∂λ and ∇²(κᵀW) of one state (R = 2) in one pass of second-order [`Jet`]s.
    fn one_state_second(
        &self,
        t: f64,
        lambda: &[f64],
        kappa: &[f64],
        w: &mut [f64],
        jac: &mut [f64],
        hess: &mut [f64],
    ) -> std::result::Result<(), Unrealizable> {
        let out = self.one_state_jets::<true>(t, lambda, w, jac)?;
        let h: [f64; 3] = std::array::from_fn(|k| kappa[0] * out[0].h[k] + kappa[1] * out[1].h[k]);
        hess[..4].copy_from_slice(&[h[0], h[1], h[1], h[2]]);
        Ok(())
    }

    /// W and ∂W/∂λ in one pass of [`DualSVec64`] (R = N).
    fn w_jacobian_fixed<const N: usize>(
        &self,
        t: f64,
        lambda: &[f64],
        w: &mut [f64],
        jac: &mut [f64],
    ) -> std::result::Result<(), Unrealizable> {
        let ld: [DualSVec64<N>; N] =
            std::array::from_fn(|i| DualSVec64::<N>::from_re(lambda[i]).derivative(i));
        let mut out: [DualSVec64<N>; N] = crate::model::ad::zeros();
        self.w_generic(t, &ld, &mut out)?;
        for (a, o) in out.iter().enumerate() {
            w[a] = o.re;
            let row = &mut jac[a * N..(a + 1) * N];
            match &o.eps.0 {
                Some(g) => row.copy_from_slice(g.as_slice()),
                None => row.fill(0.0),
            }
        }
        Ok(())
    }

    /// W, ∂W/∂λ and ∇²(κᵀW) in one pass of [`Dual2SVec64`] (R = N).
    fn w_second_fixed<const N: usize>(
        &self,
        t: f64,
        lambda: &[f64],
        kappa: &[f64],
        w: &mut [f64],
        jac: &mut [f64],
        hess: &mut [f64],
    ) -> std::result::Result<(), Unrealizable> {
        let ld: [Dual2SVec64<N>; N] =
            std::array::from_fn(|i| Dual2SVec64::<N>::from_re(lambda[i]).derivative(i));
        let mut out: [Dual2SVec64<N>; N] = crate::model::ad::zeros();
        self.w_generic(t, &ld, &mut out)?;
        hess[..N * N].fill(0.0);
        for (a, o) in out.iter().enumerate() {
            w[a] = o.re;
            let row = &mut jac[a * N..(a + 1) * N];
            match &o.v1.0 {
                Some(g) => row.copy_from_slice(g.as_slice()),
                None => row.fill(0.0),
            }
            // The Hessian of a scalar is symmetric, so its column-major storage is also row-major.
            if let Some(h) = &o.v2.0 {
                for (hij, &v) in hess.iter_mut().zip(h.as_slice()) {
                    *hij += kappa[a] * v;
                }
            }
        }
        Ok(())
    }
}

impl<S: Sde + ?Sized> ClosureDrift for GaussianDrift<'_, S> {
    fn n_params(&self) -> usize {
        self.family.n_moments()
    }

    fn state_dim(&self) -> usize {
        self.family.dim()
    }

    fn w(&self, t: f64, lambda: &[f64], out: &mut [f64]) -> std::result::Result<(), Unrealizable> {
        self.w_generic(t, lambda, out)
    }

    /// ∂W/∂λ through the moving nodes: one pass of first-order [`Jet`]s for one state (R = 2),
    /// of fixed-size vector dual numbers for two or three (R = 5, 9), otherwise one dual-number
    /// pass per column.
    fn w_jacobian(
        &self,
        t: f64,
        lambda: &[f64],
        w: &mut [f64],
        jac: &mut [f64],
    ) -> std::result::Result<(), Unrealizable> {
        match lambda.len() {
            2 => self.one_state_jets::<false>(t, lambda, w, jac).map(|_| ()),
            5 => self.w_jacobian_fixed::<5>(t, lambda, w, jac),
            9 => self.w_jacobian_fixed::<9>(t, lambda, w, jac),
            _ => self.w_jacobian_columns(t, lambda, w, jac),
        }
    }

    /// Through the moving nodes: one pass of second-order [`Jet`]s for one state (R = 2), of
    /// fixed-size second-order vector dual numbers for two or three (R = 5, 9), otherwise one
    /// hyper-dual pass per pair a ≤ b.
    fn w_second(
        &self,
        t: f64,
        lambda: &[f64],
        kappa: &[f64],
        w: &mut [f64],
        jac: &mut [f64],
        hess: &mut [f64],
    ) -> std::result::Result<(), Unrealizable> {
        match lambda.len() {
            2 => self.one_state_second(t, lambda, kappa, w, jac, hess),
            5 => self.w_second_fixed::<5>(t, lambda, kappa, w, jac, hess),
            9 => self.w_second_fixed::<9>(t, lambda, kappa, w, jac, hess),
            _ => self.w_second_pairs(t, lambda, kappa, w, jac, hess),
        }
    }

    /// One state (R = 2): the second-order jets cost about 1.8× the first-order ones, and every
    /// forward sweep pays that extra 0.8× and 48 more numbers per step (also the sweeps of
    /// rejected trial steps, of the filter start and of histories without the dispersion); it
    /// saves a Hessian's sweep the evaluation of every stage (1.8×). So it pays while Hessians
    /// are asked for after more than about 0.45 of the forward sweeps: 20 of 28 on the benchmark
    /// record of docs/closures.md (fifth session), where it saves 5 % of the instructions.
    fn keeps_hessians(&self) -> bool {
        self.family.n_moments() == 2
    }

    /// One state: one pass of second-order [`Jet`]s; otherwise the default.
    fn w_jacobian_hessians(
        &self,
        t: f64,
        lambda: &[f64],
        w: &mut [f64],
        jac: &mut [f64],
        hessians: &mut [f64],
    ) -> std::result::Result<(), Unrealizable> {
        if lambda.len() != 2 {
            return hessians_by_unit_contractions(self, t, lambda, w, jac, hessians);
        }
        let out = self.one_state_jets::<true>(t, lambda, w, jac)?;
        for (o, h) in out.iter().zip(hessians.chunks_exact_mut(4)) {
            h.copy_from_slice(&[o.h[0], o.h[1], o.h[1], o.h[2]]);
        }
        Ok(())
    }

    fn moments(&self, lambda: &[f64]) -> std::result::Result<FamilyMoments, Unrealizable> {
        let c = self.family.cumulants(lambda).map_err(unrealizable)?;
        Ok(FamilyMoments { log_partition: c.log_partition, mean: c.mean, covariance: c.covariance })
    }

    fn linear_index(&self, state: usize) -> Option<usize> {
        (state < self.family.dim()).then_some(state)
    }

    fn square_index(&self, state: usize) -> Option<usize> {
        self.family.quadratic_index(state, state)
    }
}

/// An exponential-family closure on the fixed nodes of an [`Exponential`] family (1-D or 2-D,
/// the family's state = the model's full state). The generator averages
/// g_k = f(x_k)·∇M(x_k) + D:∇∇M(x_k) (`003_d2fc48a470e528fc.txt (II.3)`) are formed at the
/// nodes, with ∇M and ∇∇M computed once; then V = Σπ_k g_k, W = C⁻¹V and
///
/// $$ \partial W/\partial\lambda = C^{-1}\sum_k \pi_k\,(g_k - (d_k\cdot W)\,d_k)\,d_k^\top,
///    \qquad d_k = M(x_k) - \mu , $$
///
/// from ∂V/∂λ = Σπ_k g_k d_kᵀ and ∂C_ab/∂λ_j = Σπ_k d_a d_b d_j (`(II.43)`).
///
/// The drift keeps the work buffers of one evaluation in a `RefCell`, so it is not `Sync`:
/// threads that evaluate closures in parallel (Monte Carlo replicates) each build their own.
pub struct ExponentialDrift<'a, S: Sde + ?Sized> {
    sde: &'a S,
    theta: Vec<f64>,
    family: Exponential,
    diffusion: Vec<f64>,
    /// The hot loops run over the nodes with one contiguous row per moment ("moment-major"):
    /// M_a(x_k) at row a is the family's [`Exponential::moment_table_by_moment`], and
    /// ∂M_a/∂x_i(x_k) at row a·dim + i.
    jac: Vec<f64>,
    /// D : ∇∇M_a(x_k) at row a.
    second: Vec<f64>,
    linear: Vec<Option<usize>>,
    square: Vec<Option<usize>>,
    /// The buffers of one evaluation, reused (the drift is evaluated at every Runge–Kutta stage).
    work: std::cell::RefCell<ExpWork>,
}

impl<S: Sde + ?Sized> std::fmt::Debug for ExponentialDrift<'_, S> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ExponentialDrift").field("family", &self.family).finish()
    }
}

impl<'a, S: Sde + ?Sized> ExponentialDrift<'a, S> {
    /// The closure of `sde` at θ with `family` (whose dimension must be the model's number of
    /// states and whose moment functions must have derivatives). Errors:
    /// [`Error::InvalidOption`] for a dimension mismatch or missing derivatives; a singular G.
    pub fn try_new(sde: &'a S, theta: &[f64], family: Exponential) -> Result<Self> {
        let n = sde.dims().states();
        if family.dim() != n {
            return Err(Error::InvalidOption {
                name: "method".into(),
                reason: format!(
                    "the exponential family has dimension {} but the model has {n} states",
                    family.dim()
                ),
            });
        }
        let diffusion = diffusion_matrix(sde, theta)?;
        let r = family.n_moments();
        let nodes = family.grid().len();
        let mut jac = vec![0.0; nodes * r * n];
        let mut second = vec![0.0; nodes * r];
        let mut h = vec![0.0; r * n * n];
        let grid = family.grid().clone();
        for (k, (x, _)) in grid.iter().enumerate() {
            family.moment_derivatives(x, &mut jac[k * r * n..(k + 1) * r * n], &mut h).map_err(|e| {
                Error::InvalidOption { name: "method".into(), reason: format!("exponential closure: {e}") }
            })?;
            for a in 0..r {
                second[k * r + a] = (0..n * n).map(|ij| diffusion[ij] * h[a * n * n + ij]).sum::<f64>();
            }
        }
        // Find x_i and x_i² among the moments numerically on the nodes.
        let table = family.moment_table();
        let find = |g: &dyn Fn(&[f64]) -> f64| -> Option<usize> {
            (0..r).find(|&a| {
                grid.iter().enumerate().all(|(k, (x, _))| {
                    let v = g(x);
                    (table[k * r + a] - v).abs() <= 1e-12 * (1.0 + v.abs())
                })
            })
        };
        let linear = (0..n).map(|i| find(&|x: &[f64]| x[i])).collect();
        let square = (0..n).map(|i| find(&|x: &[f64]| x[i] * x[i])).collect();
        // Node-major → moment-major.
        let transpose = |m: &[f64], rows: usize| -> Vec<f64> {
            let mut out = vec![0.0; m.len()];
            for k in 0..nodes {
                for a in 0..rows {
                    out[a * nodes + k] = m[k * rows + a];
                }
            }
            out
        };
        let (jac, second) = (transpose(&jac, r * n), transpose(&second, r));
        Ok(ExponentialDrift {
            sde,
            theta: theta.to_vec(),
            family,
            diffusion,
            jac,
            second,
            linear,
            square,
            work: Default::default(),
        })
    }

    /// The family.
    pub fn family(&self) -> &Exponential {
        &self.family
    }

    /// The diffusion D = ½GGᵀ of the full state (row-major).
    pub fn diffusion(&self) -> &[f64] {
        &self.diffusion
    }
}

/// The Jacobi-scaled Cholesky factor of a moment covariance C (entries of very different
/// sizes): C = S⁻¹LLᵀS⁻¹ with S = diag(1/√C_aa).
#[derive(Debug, Default)]
struct SpdFactor {
    scale: Vec<f64>,
    scaled: Vec<f64>,
    l: Vec<f64>,
}

impl SpdFactor {
    /// Factors C (row-major R × R) in place of the previous factor.
    fn factor(&mut self, c: &[f64], r: usize) -> std::result::Result<(), Unrealizable> {
        self.scale.clear();
        self.scale.extend((0..r).map(|a| 1.0 / c[a * r + a].max(f64::MIN_POSITIVE).sqrt()));
        self.scaled.clear();
        let scale = &self.scale;
        self.scaled.extend((0..r * r).map(|ab| c[ab] * scale[ab / r] * scale[ab % r]));
        self.l.resize(r * r, 0.0);
        cholesky_into(&self.scaled, r, &mut self.l)
            .map_err(|_| Unrealizable("the moment covariance C is not positive definite".into()))
    }

    /// x = C⁻¹b in place.
    fn solve(&self, x: &mut [f64]) {
        for (v, s) in x.iter_mut().zip(&self.scale) {
            *v *= s;
        }
        cholesky_solve_in_place(&self.l, x).expect("the factor and x have matching sizes");
        for (v, s) in x.iter_mut().zip(&self.scale) {
            *v *= s;
        }
    }
}

/// What W and ∂W/∂λ of an exponential closure are made of (see [`ExponentialDrift`]), flat:
/// node probabilities π, centred moments d = M(x_k) − μ, πd, generator values g_k (each
/// moment-major: one row of node values per moment; g is 0 where π is), V, the factor of C, W.
#[derive(Debug, Default)]
struct FirstOrder {
    p: Vec<f64>,
    d: Vec<f64>,
    pd: Vec<f64>,
    g: Vec<f64>,
    v: Vec<f64>,
    c: SpdFactor,
    w: Vec<f64>,
}

/// The buffers of one evaluation of an [`ExponentialDrift`]: [`FirstOrder`] and the scratch of
/// the log-weights, the drift at the nodes, C, and the node and moment vectors of ∂W/∂λ and
/// ∇²(κᵀW).
#[derive(Debug, Default)]
struct ExpWork {
    z: FirstOrder,
    s: Vec<f64>,
    fs: Vec<f64>,
    f: Vec<f64>,
    cov: Vec<f64>,
    /// π on all nodes, before the restriction to the nodes with mass.
    p_all: Vec<f64>,
    nodes: [Vec<f64>; 5],
    col: Vec<f64>,
    u: Vec<f64>,
    tm: Vec<f64>,
    tj: Vec<f64>,
}

impl<S: Sde + ?Sized> ExponentialDrift<'_, S> {
    /// π, d, g, V, C and W = C⁻¹V at (t, λ) into `z`, with the scratch of `work`, on the nodes
    /// `lo..hi` from the first to the last of non-zero probability: the node vectors of `z` are
    /// that range, compact. A concentrated density has no mass that counts on most of a wide
    /// grid, and the family gives probability 0 to nodes below e⁻⁵⁰ of the largest
    /// ([`onsager_closures::NEGLIGIBLE_LOG_WEIGHT`]), so W, ∂W/∂λ and ∇²(κᵀW) remain the
    /// exact derivatives of one another.
    fn zeroth(&self, t: f64, lambda: &[f64], work: &mut ExpWork) -> std::result::Result<(), Unrealizable> {
        let n = self.family.dim();
        let r = self.family.n_moments();
        let ExpWork { z, s, fs, f, cov, p_all, .. } = work;
        self.family.node_probabilities_into(lambda, s, p_all).map_err(unrealizable)?;
        let all = p_all.len();
        let lo = p_all.iter().position(|&pk| pk > 0.0).unwrap_or(0);
        let hi = p_all.iter().rposition(|&pk| pk > 0.0).map_or(all, |k| k + 1);
        z.p.clear();
        z.p.extend_from_slice(&p_all[lo..hi]);
        let p = &z.p;
        let nodes = p.len();
        // Row `row` of a table of rows of `all` node values, restricted to lo..hi.
        let active = |row: usize| row * all + lo..row * all + hi;
        // The drift at the nodes that carry mass, state-major.
        fs.clear();
        fs.resize(n * nodes, 0.0);
        f.clear();
        f.resize(n, 0.0);
        let points = &self.family.grid().points()[lo * n..hi * n];
        for (k, &pk) in p.iter().enumerate() {
            if pk != 0.0 {
                self.sde.state_drift(t, &points[k * n..(k + 1) * n], &self.theta, f);
                for i in 0..n {
                    fs[i * nodes + k] = f[i];
                }
            }
        }
        let table = self.family.moment_table_by_moment();
        let massless = p.contains(&0.0);
        let (d, pd, g, v) = (&mut z.d, &mut z.pd, &mut z.g, &mut z.v);
        d.clear();
        pd.clear();
        g.clear();
        v.clear();
        v.resize(r, 0.0);
        for (a, va) in v.iter_mut().enumerate() {
            let row = a * nodes..(a + 1) * nodes;
            let ma = &table[active(a)];
            let mu = dot(p, ma);
            d.extend(ma.iter().map(|&mk| mk - mu));
            pd.extend(p.iter().zip(&d[row.clone()]).map(|(&pk, &dk)| pk * dk));
            g.extend_from_slice(&self.second[active(a)]);
            let ga = &mut g[row];
            for i in 0..n {
                let ji = &self.jac[active(a * n + i)];
                let fi = &fs[i * nodes..(i + 1) * nodes];
                for ((gk, &jk), &fk) in ga.iter_mut().zip(ji).zip(fi) {
                    *gk += jk * fk;
                }
            }
            if massless {
                for (gk, &pk) in ga.iter_mut().zip(p) {
                    if pk == 0.0 {
                        *gk = 0.0;
                    }
                }
            }
            *va = dot(p, ga);
        }
        if !v.iter().all(|x| x.is_finite()) {
            return Err(Unrealizable("the drift is not finite on the family's grid".into()));
        }
        cov.clear();
        cov.resize(r * r, 0.0);
        for a in 0..r {
            for b in a..r {
                let cab = dot(&pd[a * nodes..(a + 1) * nodes], &d[b * nodes..(b + 1) * nodes]);
                cov[a * r + b] = cab;
                cov[b * r + a] = cab;
            }
        }
        z.c.factor(cov, r)?;
        z.w.clear();
        z.w.extend_from_slice(v);
        z.c.solve(&mut z.w);
        Ok(())
    }

    /// Σ_k s_k d_a(x_k) d_b(x_k) for all a, b (symmetric, row-major r × r) of a node weight s;
    /// `sd` is scratch.
    fn weighted_second_moments(z: &FirstOrder, s: &[f64], out: &mut [f64], sd: &mut Vec<f64>) {
        let r = z.w.len();
        let nodes = z.p.len();
        sd.clear();
        sd.resize(nodes, 0.0);
        for a in 0..r {
            let da = &z.d[a * nodes..(a + 1) * nodes];
            for ((x, &sk), &dk) in sd.iter_mut().zip(s).zip(da) {
                *x = sk * dk;
            }
            for b in a..r {
                let v = dot(sd, &z.d[b * nodes..(b + 1) * nodes]);
                out[a * r + b] = v;
                out[b * r + a] = v;
            }
        }
    }

    /// Σ_a c_a m_a(x_k) at every node of moment-major rows m, into `out`.
    fn project(rows: &[f64], c: &[f64], out: &mut Vec<f64>) {
        let nodes = rows.len() / c.len().max(1);
        out.clear();
        out.resize(nodes, 0.0);
        for (row, &ca) in rows.chunks_exact(nodes).zip(c) {
            for (o, &mk) in out.iter_mut().zip(row) {
                *o += ca * mk;
            }
        }
    }

    /// ∂W/∂λ = C⁻¹Σπ_k(g_k − (d_k·W)d_k)d_kᵀ into `jac` (row-major), of `work.z`.
    fn jacobian_of(work: &mut ExpWork, jac: &mut [f64]) {
        let ExpWork { z, nodes: [wd, e, ..], col, .. } = work;
        let r = z.w.len();
        let nodes = z.p.len();
        Self::project(&z.d, &z.w, wd);
        e.clear();
        e.resize(nodes, 0.0);
        for a in 0..r {
            let row = a * nodes..(a + 1) * nodes;
            for (((ek, &pk), &gk), (&pdk, &u)) in
                e.iter_mut().zip(&z.p).zip(&z.g[row.clone()]).zip(z.pd[row].iter().zip(wd.iter()))
            {
                *ek = pk * gk - u * pdk;
            }
            for j in 0..r {
                jac[a * r + j] = dot(e, &z.d[j * nodes..(j + 1) * nodes]);
            }
        }
        col.clear();
        col.resize(r, 0.0);
        for j in 0..r {
            for a in 0..r {
                col[a] = jac[a * r + j];
            }
            z.c.solve(col);
            for a in 0..r {
                jac[a * r + j] = col[a];
            }
        }
    }

    /// ∇²(κᵀW) of [`ClosureDrift::w_second`] into `hess`, from the node values of `work.z` and
    /// J = ∂W/∂λ.
    fn hessian_of(&self, work: &mut ExpWork, kappa: &[f64], jac: &[f64], hess: &mut [f64]) {
        let r = self.family.n_moments();
        let ExpWork { z, nodes: [ud, wd, ug, psi, tu], u, tm, tj, f: sd, .. } = work;
        u.clear();
        u.extend_from_slice(kappa);
        z.c.solve(u);
        // hess = ⟨ψ d dᵀ⟩, tm = T, with ψ_k = π_k(uᵀg_k − (uᵀd_k)(Wᵀd_k)) and π_k uᵀd_k.
        Self::project(&z.d, u, ud);
        Self::project(&z.d, &z.w, wd);
        Self::project(&z.g, u, ug);
        psi.clear();
        psi.extend((0..z.p.len()).map(|k| z.p[k] * (ug[k] - ud[k] * wd[k])));
        tu.clear();
        tu.extend(z.p.iter().zip(ud.iter()).map(|(p, u)| p * u));
        tm.clear();
        tm.resize(r * r, 0.0);
        Self::weighted_second_moments(z, psi, hess, sd);
        Self::weighted_second_moments(z, tu, tm, sd);
        tj.clear();
        tj.resize(r * r, 0.0);
        for a in 0..r {
            for j in 0..r {
                tj[a * r + j] = (0..r).map(|b| tm[a * r + b] * jac[b * r + j]).sum();
            }
        }
        for a in 0..r {
            for j in 0..r {
                hess[a * r + j] += -tj[a * r + j] - tj[j * r + a] + kappa[a] * z.v[j] + z.v[a] * kappa[j];
            }
        }
    }
}

impl<S: Sde + ?Sized> ClosureDrift for ExponentialDrift<'_, S> {
    fn n_params(&self) -> usize {
        self.family.n_moments()
    }

    fn state_dim(&self) -> usize {
        self.family.dim()
    }

    fn w(&self, t: f64, lambda: &[f64], out: &mut [f64]) -> std::result::Result<(), Unrealizable> {
        let work = &mut *self.work.borrow_mut();
        self.zeroth(t, lambda, work)?;
        out.copy_from_slice(&work.z.w);
        Ok(())
    }

    fn w_jacobian(
        &self,
        t: f64,
        lambda: &[f64],
        w: &mut [f64],
        jac: &mut [f64],
    ) -> std::result::Result<(), Unrealizable> {
        let work = &mut *self.work.borrow_mut();
        self.zeroth(t, lambda, work)?;
        Self::jacobian_of(work, jac);
        w.copy_from_slice(&work.z.w);
        Ok(())
    }

    /// In closed form on the fixed nodes: with u = C⁻¹κ, d_k = M(x_k) − μ and
    /// ψ_k = uᵀg_k − (uᵀd_k)(Wᵀd_k) (so that ∂(κᵀW)/∂λ_j = ⟨ψ d_j⟩ and ⟨ψ⟩ = 0),
    ///
    /// $$ \nabla^2(\kappa^\top W) = \langle \psi\, d d^\top\rangle - TJ - (TJ)^\top
    ///    + \kappa V^\top + V \kappa^\top, \qquad T = \langle (u^\top d)\, d d^\top\rangle, $$
    ///
    /// J = ∂W/∂λ, from ∂⟨h⟩/∂λ_j = ⟨∂_j h⟩ + ⟨h d_j⟩ and ∂d/∂λ_j = −C_{·j}.
    fn w_second(
        &self,
        t: f64,
        lambda: &[f64],
        kappa: &[f64],
        w: &mut [f64],
        jac: &mut [f64],
        hess: &mut [f64],
    ) -> std::result::Result<(), Unrealizable> {
        let work = &mut *self.work.borrow_mut();
        self.zeroth(t, lambda, work)?;
        Self::jacobian_of(work, jac);
        self.hessian_of(work, kappa, jac, hess);
        w.copy_from_slice(&work.z.w);
        Ok(())
    }

    /// The Jacobian of [`ClosureDrift::w_jacobian`] is the same computation
    /// (`jacobian_of` of the same node values): `jac` is used as given.
    fn w_second_with_jacobian(
        &self,
        t: f64,
        lambda: &[f64],
        kappa: &[f64],
        w: &mut [f64],
        jac: &mut [f64],
        hess: &mut [f64],
    ) -> std::result::Result<(), Unrealizable> {
        let work = &mut *self.work.borrow_mut();
        self.zeroth(t, lambda, work)?;
        self.hessian_of(work, kappa, jac, hess);
        w.copy_from_slice(&work.z.w);
        Ok(())
    }

    fn moments(&self, lambda: &[f64]) -> std::result::Result<FamilyMoments, Unrealizable> {
        let c = self.family.cumulants(lambda).map_err(unrealizable)?;
        Ok(FamilyMoments { log_partition: c.log_partition, mean: c.mean, covariance: c.covariance })
    }

    fn linear_index(&self, state: usize) -> Option<usize> {
        self.linear.get(state).copied().flatten()
    }

    fn square_index(&self, state: usize) -> Option<usize> {
        self.square.get(state).copied().flatten()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::library::{DoubleWell, Duffing, HolmesRand, Lorenz63, Ou, Tanh, VanDerPol};
    use approx::assert_relative_eq;

    fn fd_jacobian<Dr: ClosureDrift>(dr: &Dr, t: f64, lambda: &[f64]) -> Vec<f64> {
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

    #[test]
    fn kept_hessians_are_those_of_the_contractions() {
        // W, ∂W/∂λ and ∇²W_a of `w_jacobian_hessians` against `w_jacobian` and `w_second` with
        // κ = e_a; for any κ, Σ_a κ_a∇²W_a = ∇²(κᵀW). One state (the jets' pass, kept by the
        // sweeps) and two states (the default, not kept).
        let check = |dr: &dyn ClosureDrift, lambda: &[f64]| {
            let r = lambda.len();
            let (mut w, mut jac, mut hs) = (vec![0.0; r], vec![0.0; r * r], vec![0.0; r * r * r]);
            dr.w_jacobian_hessians(0.3, lambda, &mut w, &mut jac, &mut hs).unwrap();
            let (mut w1, mut jac1) = (vec![0.0; r], vec![0.0; r * r]);
            dr.w_jacobian(0.3, lambda, &mut w1, &mut jac1).unwrap();
            for (a, b) in w.iter().chain(&jac).zip(w1.iter().chain(&jac1)) {
                assert_relative_eq!(*a, *b, max_relative = 1e-13, epsilon = 1e-13);
            }
            let kappa: Vec<f64> = (0..r).map(|a| 0.5 - 0.3 * a as f64).collect();
            let mut hk = vec![0.0; r * r];
            dr.w_second(0.3, lambda, &kappa, &mut w1, &mut jac1, &mut hk).unwrap();
            for q in 0..r * r {
                let sum: f64 = (0..r).map(|a| kappa[a] * hs[a * r * r + q]).sum();
                assert_relative_eq!(sum, hk[q], max_relative = 1e-12, epsilon = 1e-12 * hk[q].abs().max(1.0));
            }
            for a in 0..r {
                let mut e = vec![0.0; r];
                e[a] = 1.0;
                dr.w_second(0.3, lambda, &e, &mut w1, &mut jac1, &mut hk).unwrap();
                assert_eq!(&hs[a * r * r..(a + 1) * r * r], &hk[..]);
            }
        };
        let one = GaussianDrift::try_new(&DoubleWell, &[0.5]).unwrap();
        assert!(one.keeps_hessians());
        check(&one, &[-1.0 / 0.09, -0.5 / 0.09]);
        check(&one, &[3.0, -2.0]);
        let two = GaussianDrift::try_new(&Duffing, &Duffing::NOMINAL).unwrap();
        assert!(!two.keeps_hessians());
        let lambda = two.family().natural_from_mean_cov(&[0.3, -0.2], &[0.5, 0.1, 0.1, 0.4]).unwrap();
        check(&two, &lambda);
    }

    #[test]
    fn gaussian_drift_of_ou_is_the_exact_moment_equation() {
        // OU dX = −θX dt + σ dW (θ = 1, σ = 0.5): ṁ = −m, v̇ = −2v + σ² (closed form). In natural
        // parameters a = m/v, b = −1/(2v): ȧ = ṁ/v − m v̇/v², ḃ = v̇/(2v²).
        let dr = GaussianDrift::try_new(&Ou, &[1.0, 0.5]).unwrap();
        let (m, v) = (0.7, 0.3);
        let lambda = [m / v, -0.5 / v];
        let mut w = [0.0; 2];
        dr.w(0.0, &lambda, &mut w).unwrap();
        let (mdot, vdot) = (-m, -2.0 * v + 0.25);
        assert_relative_eq!(w[0], mdot / v - m * vdot / (v * v), epsilon = 1e-12);
        assert_relative_eq!(w[1], vdot / (2.0 * v * v), epsilon = 1e-12);
        let (mut w2, mut jac) = ([0.0; 2], [0.0; 4]);
        dr.w_jacobian(0.0, &lambda, &mut w2, &mut jac).unwrap();
        let fd = fd_jacobian(&dr, 0.0, &lambda);
        for k in 0..4 {
            assert_relative_eq!(jac[k], fd[k], epsilon = 1e-6, max_relative = 1e-6);
        }
    }

    /// CW = V for the double well (D = 0.5) and the quartic family, with V by the family's own
    /// quadrature on all its nodes: V = ⟨f M' + D M''⟩ with f = 4x − 4x³, M = x^a, i.e.
    /// V_a = ⟨a x^{a−1} f + a(a−1)/2 x^{a−2}⟩.
    fn assert_w_is_c_inverse_v(family: &Exponential, lambda: &[f64], w: &[f64]) {
        let rule = family.quadrature(lambda).unwrap();
        let c = family.covariance(lambda).unwrap();
        for a in 1..=4i32 {
            let v = rule.integrate(|x| {
                let x = x[0];
                let f = 4.0 * x - 4.0 * x.powi(3);
                a as f64 * x.powi(a - 1) * f + 0.5 * (a * (a - 1)) as f64 * x.powi((a - 2).max(0))
            });
            let cw: f64 = (0..4).map(|b| c[(a as usize - 1) * 4 + b] * w[b]).sum();
            assert_relative_eq!(cw, v, epsilon = 1e-9, max_relative = 1e-9);
        }
    }

    #[test]
    fn exponential_drift_jacobian_matches_finite_differences_and_w_is_c_inverse_v() {
        let family = Exponential::quartic(-3.0, 3.0).unwrap();
        let dr = ExponentialDrift::try_new(&DoubleWell, &[0.5], family.clone()).unwrap();
        let lambda = [0.3, 1.0, -0.2, -0.8];
        let (mut w, mut jac) = ([0.0; 4], [0.0; 16]);
        dr.w_jacobian(0.0, &lambda, &mut w, &mut jac).unwrap();
        let fd = fd_jacobian(&dr, 0.0, &lambda);
        for k in 0..16 {
            assert_relative_eq!(jac[k], fd[k], epsilon = 1e-5, max_relative = 1e-5);
        }
        assert_w_is_c_inverse_v(&family, &lambda, &w);
        assert_eq!(dr.linear_index(0), Some(0));
        assert_eq!(dr.square_index(0), Some(1));
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

    /// The one-pass forms — jets for one state (R = 2), fixed-size vector duals for two and
    /// three (R = 5, 9) — give what one dual pass per column and one hyper-dual pass per pair
    /// give (independent evaluations of the same derivatives).
    #[test]
    fn one_pass_gaussian_derivatives_equal_the_per_direction_passes() {
        fn compare<S: Sde>(g: &GaussianDrift<'_, S>, lambda: &[f64], kappa: &[f64]) {
            let r = lambda.len();
            let z = || (vec![0.0; r], vec![0.0; r * r], vec![0.0; r * r]);
            let ((mut w1, mut j1, _), (mut w2, mut j2, _)) = (z(), z());
            g.w_jacobian(0.3, lambda, &mut w1, &mut j1).unwrap();
            g.w_jacobian_columns(0.3, lambda, &mut w2, &mut j2).unwrap();
            let ((mut w3, mut j3, mut h3), (mut w4, mut j4, mut h4)) = (z(), z());
            g.w_second(0.3, lambda, kappa, &mut w3, &mut j3, &mut h3).unwrap();
            g.w_second_pairs(0.3, lambda, kappa, &mut w4, &mut j4, &mut h4).unwrap();
            for (a, b) in w1
                .iter()
                .chain(&j1)
                .chain(&w3)
                .chain(&j3)
                .chain(&h3)
                .zip(w2.iter().chain(&j2).chain(&w4).chain(&j4).chain(&h4))
            {
                assert_relative_eq!(*a, *b, epsilon = 1e-12, max_relative = 1e-12);
            }
        }
        let dw = GaussianDrift::try_new(&DoubleWell, &[0.5]).unwrap();
        compare(&dw, &[0.4 / 0.3, -0.5 / 0.3], &[0.7, -1.3]);
        compare(&dw, &[-25.0, -12.5], &[-0.4, 2.1]);
        // A drift that is not a polynomial (its 16-point rule).
        compare(
            &GaussianDrift::try_new(&Tanh, &Tanh::NOMINAL).unwrap(),
            &[0.4 / 0.3, -0.5 / 0.3],
            &[0.7, -1.3],
        );
        // The errors of the one-state form (P ≤ 0, a non-finite λ) through the jets too.
        for bad in [[1.0, 0.0], [1.0, 0.5], [f64::INFINITY, -0.5]] {
            let (mut w, mut j, mut h) = ([0.0; 2], [0.0; 4], [0.0; 4]);
            assert!(dw.w_jacobian(0.0, &bad, &mut w, &mut j).is_err());
            assert!(dw.w_second(0.0, &bad, &[1.0, 1.0], &mut w, &mut j, &mut h).is_err());
        }
        // Van der Pol, N(m, Σ) with m = (0.3, −0.5), Σ = [[0.2, 0.05], [0.05, 0.1]]:
        // P = Σ⁻¹, a = Pm, b_ii = −½P_ii, b_01 = −P_01.
        let vdp = GaussianDrift::try_new(&VanDerPol, &VanDerPol::NOMINAL).unwrap();
        let det = 0.2 * 0.1 - 0.05 * 0.05;
        let p = [0.1 / det, -0.05 / det, -0.05 / det, 0.2 / det];
        let m = [0.3, -0.5];
        let mut lambda = vec![0.0; 5];
        for i in 0..2 {
            lambda[i] = p[i * 2] * m[0] + p[i * 2 + 1] * m[1];
        }
        let q = |i, j| vdp.family().quadratic_index(i, j).unwrap();
        lambda[q(0, 0)] = -0.5 * p[0];
        lambda[q(1, 1)] = -0.5 * p[3];
        lambda[q(0, 1)] = -p[1];
        compare(&vdp, &lambda, &[0.7, -1.3, 0.2, 0.4, -0.6]);
        // Lorenz-63 (R = 9): precision P = [[5, 1, 0], [1, 4, 0.5], [0, 0.5, 3]] (diagonally
        // dominant, so positive definite), a = P m with m = (0.3, −0.5, 1.0).
        let l63 = GaussianDrift::try_new(&Lorenz63, &Lorenz63::NOMINAL).unwrap();
        let p = [5.0, 1.0, 0.0, 1.0, 4.0, 0.5, 0.0, 0.5, 3.0];
        let m = [0.3, -0.5, 1.0];
        let mut lambda = vec![0.0; 9];
        for i in 0..3 {
            lambda[i] = (0..3).map(|j| p[i * 3 + j] * m[j]).sum();
            for j in i..3 {
                let q = l63.family().quadratic_index(i, j).unwrap();
                lambda[q] = if i == j { -0.5 * p[i * 3 + i] } else { -p[i * 3 + j] };
            }
        }
        compare(&l63, &lambda, &[0.7, -1.3, 0.2, 0.4, -0.6, 0.1, 0.9, -0.2, 0.5]);
    }

    /// The one-state form of the Gaussian closure drift gives what the general form gives, with
    /// the first and second derivatives (fixed-size duals through both), on the double well
    /// with its exact 3-point rule and with the 16-point rule, on the tanh model (not a
    /// polynomial), and an error where P ≤ 0.
    #[test]
    fn one_state_gaussian_drift_equals_the_general_form() {
        fn pass<S: Sde, D: Scalar>(g: &GaussianDrift<'_, S>, lambda: &[D], general: bool) -> Vec<D> {
            let mut out = crate::model::ad::zeros::<D, 2>().to_vec();
            if general {
                g.w_any_dimension(0.3, lambda, &mut out).unwrap();
            } else {
                g.w_one_state(0.3, lambda, &mut out).unwrap();
            }
            out
        }
        fn check<S: Sde>(g: &GaussianDrift<'_, S>) {
            for lambda in [[0.4 / 0.3, -0.5 / 0.3], [-25.0, -12.5], [0.0, -0.01]] {
                let ld: [Dual2SVec64<2>; 2] =
                    std::array::from_fn(|i| Dual2SVec64::<2>::from_re(lambda[i]).derivative(i));
                let (one, general) = (pass(g, &ld, false), pass(g, &ld, true));
                for (a, b) in one.iter().zip(&general) {
                    let (a1, b1) = (a.v1.0.unwrap(), b.v1.0.unwrap());
                    let (a2, b2) = (a.v2.0.unwrap(), b.v2.0.unwrap());
                    let pairs = [(a.re, b.re)].into_iter().chain(a1.iter().copied().zip(b1.iter().copied()));
                    for (x, y) in pairs.chain(a2.iter().copied().zip(b2.iter().copied())) {
                        // (Σ = 1/P and √Σ are formed by other operations than the Cholesky
                        // factors and inverse of the general form: round-off apart.)
                        assert_relative_eq!(x, y, epsilon = 1e-10, max_relative = 1e-10);
                    }
                }
            }
            let mut out = [0.0; 2];
            assert!(g.w_one_state(0.0, &[1.0, 0.0], &mut out).is_err());
            assert!(g.w_one_state(0.0, &[1.0, 0.5], &mut out).is_err());
            assert!(g.w_one_state(0.0, &[f64::INFINITY, -0.5], &mut out).is_err());
        }
        for points in [None, Some(16)] {
            check(&GaussianDrift::try_with_points(&DoubleWell, &[0.5], points).unwrap());
        }
        // A drift that is not a polynomial (its 16-point rule).
        check(&GaussianDrift::try_new(&Tanh, &Tanh::NOMINAL).unwrap());
    }

    /// f(x) = ∛x, whose f′ and f″ are infinite at x = 0.
    struct CubeRoot;

    impl Sde for CubeRoot {
        fn dims(&self) -> crate::model::Dims {
            crate::model::Dims { noisy: 1, clean: 0, params: 1 }
        }
        fn noisy_names(&self) -> Vec<String> {
            vec!["x".into()]
        }
        fn param_names(&self) -> Vec<String> {
            vec!["sigma".into()]
        }
        fn drift<D: Scalar>(&self, _t: D, x: &[D], _z: &[D], _theta: &[D], out: &mut [D]) {
            out[0] = x[0].cbrt();
        }
        fn diffusion<D: Scalar>(&self, theta: &[D], out: &mut [D]) {
            out[0] = theta[0];
        }
    }

    /// A drift whose derivatives are not finite at a node (∛x at the middle node x = m = 0 of
    /// the 3-point rule) is an error of W, ∂W/∂λ and ∇²(κᵀW) alike, not a non-finite Jacobian
    /// or Hessian: the jets' lift carries a non-finite node sum into W's value, as the generic
    /// lift does.
    #[test]
    fn a_drift_with_infinite_derivatives_at_a_node_is_unrealizable() {
        let g = GaussianDrift::try_with_points(&CubeRoot, &[1.0], Some(3)).unwrap();
        let lambda = [0.0, -0.5];
        let (mut w, mut j, mut h) = ([0.0; 2], [0.0; 4], [0.0; 4]);
        assert!(g.w(0.0, &lambda, &mut w).is_err());
        assert!(g.w_jacobian(0.0, &lambda, &mut w, &mut j).is_err());
        assert!(g.w_second(0.0, &lambda, &[1.0, 1.0], &mut w, &mut j, &mut h).is_err());
        // Away from 0 the nodes are regular.
        assert!(g.w_jacobian(0.0, &[0.5, -0.5], &mut w, &mut j).is_ok());
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

    /// A density concentrated on a small part of a wide grid (N(1, 0.2²) on [−6, 6], 512 nodes):
    /// the drift works on the nodes of non-zero probability only (most of the grid has
    /// probability 0 under the e⁻⁵⁰ cut), and W = C⁻¹V still holds against the family's
    /// own all-node quadrature, with ∂W/∂λ and ∇²(κᵀW) against finite differences.
    #[test]
    fn exponential_drift_on_the_nodes_with_mass_of_a_concentrated_density() {
        let family = Exponential::quartic(-6.0, 6.0).unwrap();
        let (m, v) = (1.0, 0.04);
        let lambda = [m / v, -0.5 / v, 0.0, 0.0];
        let p = family.node_probabilities(&lambda).unwrap().0;
        let zero = p.iter().filter(|&&pk| pk == 0.0).count();
        assert!(zero > p.len() / 2, "{zero} of {} nodes have probability 0", p.len());
        let dr = ExponentialDrift::try_new(&DoubleWell, &[0.5], family.clone()).unwrap();
        let (mut w, mut jac) = ([0.0; 4], [0.0; 16]);
        dr.w_jacobian(0.0, &lambda, &mut w, &mut jac).unwrap();
        assert_w_is_c_inverse_v(&family, &lambda, &w);
        // ∂W/∂λ and ∇²(κᵀW) against fourth-order central differences, relative to their
        // largest entries (the small entries are below the differences' round-off at these λ).
        let kappa = [0.5, -0.25, 0.1, 0.8];
        let (mut w2, mut j2, mut hess) = ([0.0; 4], [0.0; 16], [0.0; 16]);
        dr.w_second(0.0, &lambda, &kappa, &mut w2, &mut j2, &mut hess).unwrap();
        let at = |j: usize, dl: f64| {
            let (mut l, mut w, mut jac) = (lambda, [0.0; 4], [0.0; 16]);
            l[j] += dl;
            dr.w_jacobian(0.0, &l, &mut w, &mut jac).unwrap();
            (w, jac)
        };
        let (mut fd_j, mut fd_h) = ([0.0; 16], [0.0; 16]);
        for j in 0..4 {
            let h = 1e-4 * (1.0 + lambda[j].abs());
            let pts = [(2.0, -1.0), (1.0, 8.0), (-1.0, -8.0), (-2.0, 1.0)].map(|(s, c)| (at(j, s * h), c));
            for i in 0..4 {
                fd_j[i * 4 + j] = pts.iter().map(|((w, _), c)| c * w[i]).sum::<f64>() / (12.0 * h);
                fd_h[i * 4 + j] = pts
                    .iter()
                    .map(|((_, jac), c)| c * (0..4).map(|a| kappa[a] * jac[a * 4 + i]).sum::<f64>())
                    .sum::<f64>()
                    / (12.0 * h);
            }
        }
        for (exact, fd) in [(&jac, &fd_j), (&hess, &fd_h)] {
            let scale = exact.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            for (a, b) in exact.iter().zip(fd) {
                assert!((a - b).abs() <= 1e-6 * scale, "{a} vs {b} (largest entry {scale})");
            }
        }
        assert_eq!(j2, jac);
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

    /// W, ∂W/∂λ and ∇²(κᵀW) of a Gaussian closure at N(m, Σ), Σ = diag(var) + 0.05 off the
    /// diagonal, t = 0.7 (so that the time-dependent forcing of Duffing and Holmes–Rand enters).
    fn second_at<S: Sde + ?Sized>(g: &GaussianDrift<'_, S>, m: &[f64], var: &[f64]) -> Vec<f64> {
        let n = m.len();
        let cov: Vec<f64> = (0..n * n).map(|k| if k / n == k % n { var[k / n] } else { 0.05 }).collect();
        let lambda = g.family().natural_from_mean_cov(m, &cov).unwrap();
        let r = lambda.len();
        let kappa: Vec<f64> = (0..r).map(|a| 0.3 + 0.4 * (a as f64).sin()).collect();
        let (mut w, mut jac, mut hess) = (vec![0.0; r], vec![0.0; r * r], vec![0.0; r * r]);
        g.w_second(0.7, &lambda, &kappa, &mut w, &mut jac, &mut hess).unwrap();
        w.into_iter().chain(jac).chain(hess).collect()
    }

    fn max_difference(a: &[f64], b: &[f64]) -> (f64, f64) {
        let scale = a.iter().fold(0.0f64, |s, v| s.max(v.abs()));
        (a.iter().zip(b).fold(0.0f64, |d, (u, v)| d.max((u - v).abs())), scale)
    }

    /// For every built-in model with a declared polynomial drift of degree d, the automatic rule
    /// is Gauss–Hermite with ⌊(d + 1)/2⌋ + 1 points per dimension, and W, ∂W/∂λ and ∇²(κᵀW) with it
    /// equal those of the general rule (16 / 8 / 5 points per dimension) to round-off: the
    /// averages ⟨f⟩, ⟨f(x − m)ᵀ⟩ are integrals of polynomials of degree ≤ d + 1 in the standard
    /// normal ξ, which both rules integrate exactly (`003_d2fc48a470e528fc.txt (II.3)`). One
    /// point fewer is not exact (the check is sensitive). `tanh` keeps the
    /// general rule.
    #[test]
    fn exact_reduced_rule_equals_the_general_rule_for_polynomial_drifts() {
        fn check<S: Sde>(sde: &S, theta: &[f64], m: &[f64], var: &[f64], k: usize) {
            let n = m.len();
            let auto = [16, 8, 5][n - 1];
            let reduced = GaussianDrift::try_new(sde, theta).unwrap();
            assert_eq!(reduced.family().rule_kind(), GaussianRule::GaussHermite { points_per_dim: k });
            let full = GaussianDrift::try_with_points(sde, theta, Some(auto)).unwrap();
            let (a, b) = (second_at(&reduced, m, var), second_at(&full, m, var));
            let (diff, scale) = max_difference(&a, &b);
            assert!(diff <= 1e-12 * scale, "k = {k}: difference {diff}, scale {scale}");
            if k > 1 {
                let coarse = GaussianDrift::try_with_points(sde, theta, Some(k - 1)).unwrap();
                let (diff, scale) = max_difference(&second_at(&coarse, m, var), &b);
                assert!(diff > 1e-6 * scale, "k − 1 = {} points are already exact", k - 1);
            }
        }
        check(&Ou, &Ou::NOMINAL, &[0.4], &[0.3], 2);
        check(&DoubleWell, &[0.5], &[0.4], &[0.3], 3);
        check(&VanDerPol, &VanDerPol::NOMINAL, &[0.3, -0.5], &[0.2, 0.1], 3);
        check(&Duffing, &Duffing::NOMINAL, &[0.3, -0.5], &[0.2, 0.1], 3);
        check(&HolmesRand, &HolmesRand::NOMINAL, &[0.3, -0.5], &[0.2, 0.1], 3);
        check(&Lorenz63, &Lorenz63::NOMINAL, &[0.3, -0.5, 1.0], &[0.2, 0.25, 0.3], 2);
        let tanh = GaussianDrift::try_new(&Tanh, &Tanh::NOMINAL).unwrap();
        assert_eq!(tanh.family().rule_kind(), GaussianRule::Auto);
    }

    /// The rule choice: an explicit size wins; no reduction from 4 states on (the cubature)
    /// or where the exact rule would not be smaller than the general one; 0 points is an
    /// invalid option, not a panic.
    #[test]
    fn gaussian_closure_rule_choices() {
        let gh = |k| GaussianRule::GaussHermite { points_per_dim: k };
        assert_eq!(gaussian_closure_rule(&DoubleWell, 1, Some(7)), gh(7));
        assert_eq!(gaussian_closure_rule(&DoubleWell, 1, None), gh(3));
        assert_eq!(gaussian_closure_rule(&DoubleWell, 4, None), GaussianRule::Auto);
        assert_eq!(gaussian_closure_rule(&Tanh, 1, None), GaussianRule::Auto);
        assert_eq!(exact_gauss_hermite_points(1), 2);
        assert_eq!(exact_gauss_hermite_points(2), 2);
        assert_eq!(exact_gauss_hermite_points(3), 3);
        assert_eq!(exact_gauss_hermite_points(4), 3);
        assert_eq!(exact_gauss_hermite_points(7), 5);
        // A declared degree of 9 in 3-D needs 6 points: not fewer than the general rule's 5.
        struct Nonic;
        impl Sde for Nonic {
            fn dims(&self) -> crate::model::Dims {
                crate::model::Dims { noisy: 3, clean: 0, params: 0 }
            }
            fn noisy_names(&self) -> Vec<String> {
                vec!["a".into(), "b".into(), "c".into()]
            }
            fn param_names(&self) -> Vec<String> {
                Vec::new()
            }
            fn drift<D: Scalar>(&self, _t: D, x: &[D], _z: &[D], _theta: &[D], out: &mut [D]) {
                for (o, &v) in out.iter_mut().zip(x) {
                    *o = -v.powi(9);
                }
            }
            fn diffusion<D: Scalar>(&self, _theta: &[D], out: &mut [D]) {
                for (k, o) in out.iter_mut().enumerate() {
                    *o = D::from(if k % 4 == 0 { 1.0 } else { 0.0 });
                }
            }
            fn drift_polynomial_degree(&self) -> Option<usize> {
                Some(9)
            }
        }
        assert_eq!(gaussian_closure_rule(&Nonic, 3, None), GaussianRule::Auto);
        for bad in [0, 10_000] {
            assert!(matches!(
                GaussianDrift::try_with_points(&DoubleWell, &[0.5], Some(bad)),
                Err(Error::InvalidOption { name, .. }) if name == "gaussian points"
            ));
        }
    }
}
