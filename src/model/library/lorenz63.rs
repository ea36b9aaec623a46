//! The Lorenz-63 system with additive noise.

use super::names;
use crate::model::{Dims, DriftDerivatives, Scalar, Sde};

/// The stochastic Lorenz-63 system with additive isotropic noise (Lorenz, *Deterministic
/// nonperiodic flow*, J. Atmos. Sci. 20, 1963, for the drift):
///
/// $$ f(x) = \begin{bmatrix} s (x_2 - x_1) \\ x_1 (r - x_3) - x_2 \\ x_1 x_2 - b x_3 \end{bmatrix},
///    \qquad G = \sigma_w I_3, $$
///
/// three noisy states named `x1`, `x2`, `x3` (not x, y, z: `y` names measured outputs),
/// parameters θ = (`sigma`, `rho`, `beta`, `sigma_w`) = (s, r, b, σ_w). The divergence is the
/// constant $\operatorname{div} f = -(s + 1 + b)$, the phase-space contraction rate.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Lorenz63;

impl Lorenz63 {
    /// Parameter names, in the order of θ.
    pub const PARAMS: [&'static str; 4] = ["sigma", "rho", "beta", "sigma_w"];
    /// Nominal values: Lorenz's classical s = 10, r = 28, b = 8/3 (chaotic regime); the
    /// noise level σ_w = 1 is our choice.
    pub const NOMINAL: [f64; 4] = [10.0, 28.0, 8.0 / 3.0, 1.0];
    /// Index of `sigma` (s) in θ.
    pub const SIGMA: usize = 0;
    /// Index of `rho` (r) in θ.
    pub const RHO: usize = 1;
    /// Index of `beta` (b) in θ.
    pub const BETA: usize = 2;
    /// Index of `sigma_w` in θ.
    pub const SIGMA_W: usize = 3;
}

impl Sde for Lorenz63 {
    fn dims(&self) -> Dims {
        Dims { noisy: 3, clean: 0, params: 4 }
    }

    fn noisy_names(&self) -> Vec<String> {
        names(&["x1", "x2", "x3"])
    }

    fn param_names(&self) -> Vec<String> {
        names(&Self::PARAMS)
    }

    /// $f = (s(x_2 - x_1),\; x_1(r - x_3) - x_2,\; x_1 x_2 - b x_3)$.
    fn drift<D: Scalar>(&self, _t: D, x: &[D], _z: &[D], theta: &[D], out: &mut [D]) {
        let (s, r, b) = (theta[Self::SIGMA], theta[Self::RHO], theta[Self::BETA]);
        let (x1, x2, x3) = (x[0], x[1], x[2]);
        out[0] = s * (x2 - x1);
        out[1] = x1 * (r - x3) - x2;
        out[2] = x1 * x2 - b * x3;
    }

    /// $\operatorname{div} f = -s - 1 - b$, in closed form.
    fn divergence<D: Scalar>(&self, _t: D, _x: &[D], _z: &[D], theta: &[D]) -> D {
        -(theta[Self::SIGMA] + theta[Self::BETA] + 1.0)
    }

    /// f, div f and their derivatives in (x₁, x₂, x₃, θ) in closed form (f is quadratic: its
    /// second derivatives are the constants ∂²f₁/∂x₁∂s = −1, ∂²f₁/∂x₂∂s = 1,
    /// ∂²f₂/∂x₁∂x₃ = −1, ∂²f₂/∂x₁∂ρ = 1, ∂²f₃/∂x₁∂x₂ = 1, ∂²f₃/∂x₃∂β = −1); div f = −s − 1 − β.
    fn drift_derivatives(
        &self,
        _t: f64,
        x: &[f64],
        _z: &[f64],
        theta: &[f64],
        out: &mut DriftDerivatives,
    ) -> bool {
        const S: usize = 3 + Lorenz63::SIGMA;
        const R: usize = 3 + Lorenz63::RHO;
        const B: usize = 3 + Lorenz63::BETA;
        let (s, r, b) = (theta[Self::SIGMA], theta[Self::RHO], theta[Self::BETA]);
        let (x1, x2, x3) = (x[0], x[1], x[2]);
        out.first(0, 0, -s);
        out.first(0, 1, s);
        out.first(0, S, x2 - x1);
        out.second(0, 0, S, -1.0);
        out.second(0, 1, S, 1.0);
        out.first(1, 0, r - x3);
        out.first(1, 1, -1.0);
        out.first(1, 2, -x1);
        out.first(1, R, x1);
        out.second(1, 0, 2, -1.0);
        out.second(1, 0, R, 1.0);
        out.first(2, 0, x2);
        out.first(2, 1, x1);
        out.first(2, 2, -b);
        out.first(2, B, -x3);
        out.second(2, 0, 1, 1.0);
        out.second(2, 2, B, -1.0);
        out.first(3, S, -1.0);
        out.first(3, B, -1.0);
        true
    }

    /// The drift does not read t.
    fn drift_is_autonomous(&self) -> bool {
        true
    }

    /// f is quadratic (the products x₁x₃ and x₁x₂).
    fn drift_polynomial_degree(&self) -> Option<usize> {
        Some(2)
    }

    /// Σ_w enters G only.
    fn drift_uses_param(&self, i: usize) -> bool {
        i != Self::SIGMA_W
    }

    /// $G = \sigma_w I_3$ (column-major).
    fn diffusion<D: Scalar>(&self, theta: &[D], out: &mut [D]) {
        let s = theta[Self::SIGMA_W];
        for (k, g) in out.iter_mut().enumerate() {
            *g = if k % 4 == 0 { s } else { D::from(0.0) };
        }
    }
}
