//! The stochastic Van der Pol oscillator of `001_8aefdf0570c96f51.txt` Sec. 9.

use super::names;
use crate::model::{Dims, DriftDerivatives, Scalar, Sde};

/// The stochastic Van der Pol oscillator, `001_8aefdf0570c96f51.txt` Sec. 9, with states
/// x = (u, v):
///
/// $$ f(t, x) = \begin{bmatrix} v \\ -u + \mu (1 - u^2) v \end{bmatrix}, \qquad
///    G = \begin{bmatrix} \sigma & 0 \\ 0 & \sigma \end{bmatrix}, $$
///
/// two noisy states `u`, `v`, parameters θ = (`mu`, `sigma`); the paper fixes μ = 2 and
/// σ = 0.1. Its divergence $\operatorname{div} f = \mu (1 - u^2)$ (= 2(1 − u²) in the paper) is
/// highest near the origin, so the MAP merit favours paths with larger |u| while the energy
/// merit does not.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct VanDerPol;

impl VanDerPol {
    /// Parameter names, in the order of θ.
    pub const PARAMS: [&'static str; 2] = ["mu", "sigma"];
    /// Nominal values μ = 2, σ = 0.1 (`001_8aefdf0570c96f51.txt` Sec. 9).
    pub const NOMINAL: [f64; 2] = [2.0, 0.1];
    /// Index of `mu` in θ.
    pub const MU: usize = 0;
    /// Index of `sigma` in θ.
    pub const SIGMA: usize = 1;
}

impl Sde for VanDerPol {
    fn dims(&self) -> Dims {
        Dims { noisy: 2, clean: 0, params: 2 }
    }

    fn noisy_names(&self) -> Vec<String> {
        names(&["u", "v"])
    }

    fn param_names(&self) -> Vec<String> {
        names(&Self::PARAMS)
    }

    /// $f = (v,\; -u + \mu(1 - u^2) v)$.
    fn drift<D: Scalar>(&self, _t: D, x: &[D], _z: &[D], theta: &[D], out: &mut [D]) {
        let (u, v) = (x[0], x[1]);
        let mu = theta[Self::MU];
        out[0] = v;
        out[1] = -u + mu * (D::from(1.0) - u * u) * v;
    }

    /// $\operatorname{div} f = \mu (1 - u^2)$ (`001_8aefdf0570c96f51.txt` Sec. 9), in closed form.
    fn divergence<D: Scalar>(&self, _t: D, x: &[D], _z: &[D], theta: &[D]) -> D {
        theta[Self::MU] * (D::from(1.0) - x[0] * x[0])
    }

    /// f, div f and their derivatives in (u, v, μ, σ) in closed form: ∂f₂/∂(u, v, μ) =
    /// (−1 − 2μuv, μ(1 − u²), (1 − u²)v), ∂²f₂/∂u² = −2μv, ∂²f₂/∂u∂v = −2μu,
    /// ∂²f₂/∂u∂μ = −2uv, ∂²f₂/∂v∂μ = 1 − u²; div f = μ(1 − u²).
    fn drift_derivatives(
        &self,
        _t: f64,
        x: &[f64],
        _z: &[f64],
        theta: &[f64],
        out: &mut DriftDerivatives,
    ) -> bool {
        const U: usize = 0;
        const V: usize = 1;
        const MU: usize = 2 + VanDerPol::MU;
        let (u, v, mu) = (x[0], x[1], theta[Self::MU]);
        let q = 1.0 - u * u;
        out.first(0, V, 1.0);
        out.first(1, U, -1.0 - 2.0 * mu * u * v);
        out.first(1, V, mu * q);
        out.first(1, MU, q * v);
        out.second(1, U, U, -2.0 * mu * v);
        out.second(1, U, V, -2.0 * mu * u);
        out.second(1, U, MU, -2.0 * u * v);
        out.second(1, V, MU, q);
        out.first(2, U, -2.0 * mu * u);
        out.first(2, MU, q);
        out.second(2, U, U, -2.0 * mu);
        out.second(2, U, MU, -2.0 * u);
        true
    }

    /// The drift does not read t.
    fn drift_is_autonomous(&self) -> bool {
        true
    }

    /// f = (v, −u + μ(1 − u²)v): a cubic (the term u²v).
    fn drift_polynomial_degree(&self) -> Option<usize> {
        Some(3)
    }

    /// Σ enters G only.
    fn drift_uses_param(&self, i: usize) -> bool {
        i != Self::SIGMA
    }

    /// $G = \sigma I_2$ (column-major).
    fn diffusion<D: Scalar>(&self, theta: &[D], out: &mut [D]) {
        let s = theta[Self::SIGMA];
        out.copy_from_slice(&[s, D::from(0.0), D::from(0.0), s]);
    }
}
