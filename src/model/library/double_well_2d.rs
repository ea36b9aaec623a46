//! A two-state double well: a bistable state x driving a relaxing state v.

use super::names;
use crate::model::{Dims, DriftDerivatives, Scalar, Sde};

/// The double well of [`DoubleWell`](super::DoubleWell) driving a second, relaxing state
/// (Eyink's notation, `003_d2fc48a470e528fc.txt (0.1)`, dX = f dt + (2D)^{1/2} dW, in two
/// dimensions):
///
/// $$ f(x, v) = \begin{bmatrix} 4x - 4x^3 \\ x - v \end{bmatrix}, \qquad
///    G = \sqrt{2D}\, I_2 , $$
///
/// two noisy states `x`, `v`, parameter θ = (`D`). x jumps between the wells ±1 at the Kramers
/// rate of the one-state model, v follows x with relaxation time 1, so between measurements of
/// x the posterior is bimodal in x and its modes are correlated with v: a two-state test
/// problem on which the exact two-dimensional grid still runs. The divergence is
/// $\operatorname{div} f = 3 - 12x^2$; the drift is a cubic.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DoubleWell2d;

impl DoubleWell2d {
    /// Parameter names, in the order of θ.
    pub const PARAMS: [&'static str; 1] = ["D"];
    /// Default D = 0.5 (our choice, as for the one-state double well): G = I.
    pub const NOMINAL: [f64; 1] = [0.5];
    /// Index of `D` in θ.
    pub const D: usize = 0;
}

impl Sde for DoubleWell2d {
    fn dims(&self) -> Dims {
        Dims { noisy: 2, clean: 0, params: 1 }
    }

    fn noisy_names(&self) -> Vec<String> {
        names(&["x", "v"])
    }

    fn param_names(&self) -> Vec<String> {
        names(&Self::PARAMS)
    }

    /// $f = (4x - 4x^3,\; x - v)$.
    fn drift<D: Scalar>(&self, _t: D, x: &[D], _z: &[D], _theta: &[D], out: &mut [D]) {
        let (u, v) = (x[0], x[1]);
        out[0] = u * 4.0 - u.powi(3) * 4.0;
        out[1] = u - v;
    }

    /// $\operatorname{div} f = 3 - 12 x^2$, in closed form.
    fn divergence<D: Scalar>(&self, _t: D, x: &[D], _z: &[D], _theta: &[D]) -> D {
        D::from(3.0) - x[0] * x[0] * 12.0
    }

    /// f = (4x − 4x³, x − v) and div f = 3 − 12x² with their derivatives in closed form:
    /// ∂f₁/∂x = 4 − 12x², ∂²f₁/∂x² = −24x, ∂f₂/∂(x, v) = (1, −1), (div f)′ = −24x,
    /// (div f)″ = −24.
    fn drift_derivatives(
        &self,
        _t: f64,
        x: &[f64],
        _z: &[f64],
        _theta: &[f64],
        out: &mut DriftDerivatives,
    ) -> bool {
        let u = x[0];
        out.first(0, 0, 4.0 - 12.0 * u * u);
        out.second(0, 0, 0, -24.0 * u);
        out.first(1, 0, 1.0);
        out.first(1, 1, -1.0);
        out.first(2, 0, -24.0 * u);
        out.second(2, 0, 0, -24.0);
        true
    }

    /// The drift does not read t.
    fn drift_is_autonomous(&self) -> bool {
        true
    }

    /// f is a cubic in (x, v).
    fn drift_polynomial_degree(&self) -> Option<usize> {
        Some(3)
    }

    /// D enters G only.
    fn drift_uses_param(&self, i: usize) -> bool {
        i != Self::D
    }

    /// $G = \sqrt{2D}\,I_2$ (row-major), so that ½GGᵀ = D I.
    fn diffusion<D: Scalar>(&self, theta: &[D], out: &mut [D]) {
        let g = (theta[Self::D] * 2.0).sqrt();
        out[0] = g;
        out[1] = D::from(0.0);
        out[2] = D::from(0.0);
        out[3] = g;
    }
}
