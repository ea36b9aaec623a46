//! The Gaussian closure drift ([`GaussianDrift`]) and the choice of its quadrature rule
//! ([`gaussian_closure_rule`]).

use num_dual::{Dual2SVec64, Dual2_64, Dual64, DualSVec64, HyperDual64};
use onsager_closures::{cholesky_into, Gaussian, GaussianRule, TrialFamily};

use super::{diffusion_matrix, hessians_by_unit_contractions, unrealizable};
use super::{ClosureDrift, FamilyMoments, Unrealizable};
use crate::action::closure::jet::{Jet, OneStateScalar};
use serde::{Deserialize, Serialize};

use super::gaussian_prior;
use crate::action::closure::{ClosureFamily, FamilySetup};
use crate::estimate::{EstimationProblem, Method};
use crate::model::observation::StateMeasurement;
use crate::model::prior::Prior;
use crate::model::{Scalar, Sde};
use crate::{Error, Result};

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
                name: "gaussian_points".into(),
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
    /// are asked for after more than about 0.45 of the forward sweeps, as in the dual's Newton
    /// iterations (one Hessian per iteration, one or two forward sweeps).
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

/// The Gaussian family M = (x_i, x_ix_j) on all states, any dimension (`gaussian-closure`).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default)]
#[non_exhaustive]
pub struct GaussianFamily {
    /// Gauss–Hermite points per dimension of the averages, k^n nodes on n states; at least 1.
    /// Default `None`: automatic ([`gaussian_closure_rule`]): for a model that declares
    /// a polynomial drift of degree d ([`Sde::drift_polynomial_degree`]) and 1–3 states,
    /// ⌊(d + 1)/2⌋ + 1 points, which take the averages exactly (3 for the cubic double well);
    /// otherwise 16 / 8 / 5 points per dimension for 1 / 2 / 3 states and a fifth-degree
    /// cubature from 4 states.
    pub gaussian_points: Option<usize>,
}

impl GaussianFamily {
    /// Sets the Gauss–Hermite points per dimension.
    pub fn with_gaussian_points(mut self, points_per_dim: usize) -> Self {
        self.gaussian_points = Some(points_per_dim);
        self
    }
}

impl ClosureFamily for GaussianFamily {
    type Drift<'a, S: Sde + ?Sized + 'a> = GaussianDrift<'a, S>;
    const METHOD: Method = Method::GaussianClosure;

    fn describe(&self) -> String {
        "Gaussian".into()
    }

    fn validate(&self) -> Result<()> {
        if self.gaussian_points == Some(0) {
            return Err(Error::invalid("gaussian_points", "must be at least 1, got 0"));
        }
        Ok(())
    }

    fn setup<'a, S: Sde + ?Sized>(
        &self,
        problem: &EstimationProblem<'a, S, StateMeasurement>,
    ) -> Result<FamilySetup<GaussianDrift<'a, S>>> {
        let (drift, lambda0) = gaussian_setup(problem, self.gaussian_points)?;
        Ok(FamilySetup { drift, lambda0, measured: problem.observation.states.clone() })
    }
}

fn gaussian_setup<'a, S: Sde + ?Sized>(
    problem: &EstimationProblem<'a, S, StateMeasurement>,
    points_per_dim: Option<usize>,
) -> Result<(GaussianDrift<'a, S>, Vec<f64>)> {
    let names = problem.sde.state_names();
    let priors: Vec<&Prior> = problem.x0_prior.iter().chain(problem.z0_prior).collect();
    let n = priors.len();
    let mut mean = vec![0.0; n];
    let mut cov = vec![0.0; n * n];
    for (i, p) in priors.iter().enumerate() {
        let (m, v) = gaussian_prior(p, &names[i])?;
        mean[i] = m;
        cov[i * n + i] = v;
    }
    let drift = GaussianDrift::try_with_points(problem.sde, problem.theta, points_per_dim)?;
    let lambda0 = drift
        .family()
        .natural_from_mean_cov(&mean, &cov)
        .map_err(|e| Error::invalid("x0 prior", format!("Gaussian closure: {e}")))?;
    Ok((drift, lambda0))
}

#[cfg(test)]
mod tests {
    use super::super::tests::fd_jacobian;
    use super::*;
    use crate::model::library::{DoubleWell, Duffing, HolmesRand, Lorenz63, Ou, Tanh, VanDerPol};
    use approx::assert_relative_eq;

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

    /// f(x) = ∛x, whose f′ and f″ are infinite at x = 0. (Kept here rather than in `test_models`:
    /// it exists only to reach the error below.)
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
        // A declared degree of 9 in 3-D needs 6 points: not fewer than the general rule's 5 (a
        // declaration only this check needs, so the model stays here).
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
                Err(Error::InvalidOption { name, .. }) if name == "gaussian_points"
            ));
        }
    }
}
