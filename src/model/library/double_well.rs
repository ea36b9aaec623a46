//! A bistable (double-well) diffusion in Eyink's notation, `003_d2fc48a470e528fc.txt (0.1)`.

use super::names;
use crate::model::{Dims, DriftDerivatives, Scalar, Sde};

/// Gradient dynamics in the quartic double-well potential V(x) = x⁴ − 2x², written with
/// Eyink's diffusion coefficient D (`003_d2fc48a470e528fc.txt (0.1)`,
/// dX = f dt + (2D)^{1/2} dW):
///
/// $$ dX = (4X - 4X^3)\,dt + \sqrt{2D}\,dW, $$
///
/// one noisy state `x`, parameter θ = (`D`). The wells are at x = ±1, the barrier at 0 has
/// height ΔV = 1, and transitions between wells happen at the Kramers rate
/// ≈ (√(V''(1)·|V''(0)|)/2π) e^{−ΔV/D} = (√32/2π) e^{−1/D}. This drift is the standard
/// double-well test problem of nonlinear data assimilation; 003 develops the theory without a
/// numerical example, so the defaults are our choice. The divergence is
/// $\operatorname{div} f = 4 - 12 x^2$.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DoubleWell;

impl DoubleWell {
    /// Parameter names, in the order of θ.
    pub const PARAMS: [&'static str; 1] = ["D"];
    /// Default D = 0.5 (our choice): G = √(2D) = 1 and a Kramers rate of about 0.12 per unit
    /// time, i.e. a few well-to-well transitions in the default horizon of 20.
    pub const NOMINAL: [f64; 1] = [0.5];
    /// Index of `D` in θ.
    pub const D: usize = 0;
}

impl Sde for DoubleWell {
    fn dims(&self) -> Dims {
        Dims { noisy: 1, clean: 0, params: 1 }
    }

    fn noisy_names(&self) -> Vec<String> {
        names(&["x"])
    }

    fn param_names(&self) -> Vec<String> {
        names(&Self::PARAMS)
    }

    /// $f(x) = 4x - 4x^3 = -V'(x)$.
    fn drift<D: Scalar>(&self, _t: D, x: &[D], _z: &[D], _theta: &[D], out: &mut [D]) {
        let x = x[0];
        out[0] = x * 4.0 - x.powi(3) * 4.0;
    }

    /// $\operatorname{div} f = 4 - 12 x^2$, in closed form.
    fn divergence<D: Scalar>(&self, _t: D, x: &[D], _z: &[D], _theta: &[D]) -> D {
        D::from(4.0) - x[0] * x[0] * 12.0
    }

    /// f = 4x − 4x³ and div f = 4 − 12x² with their derivatives in closed form:
    /// f′ = 4 − 12x², f″ = −24x, (div f)′ = −24x, (div f)″ = −24.
    fn drift_derivatives(
        &self,
        _t: f64,
        x: &[f64],
        _z: &[f64],
        _theta: &[f64],
        out: &mut DriftDerivatives,
    ) -> bool {
        let x = x[0];
        out.first(0, 0, 4.0 - 12.0 * x * x);
        out.second(0, 0, 0, -24.0 * x);
        out.first(1, 0, -24.0 * x);
        out.second(1, 0, 0, -24.0);
        true
    }

    /// The drift does not read t.
    fn drift_is_autonomous(&self) -> bool {
        true
    }

    /// f = 4x − 4x³: a cubic.
    fn drift_polynomial_degree(&self) -> Option<usize> {
        Some(3)
    }

    /// D enters G only.
    fn drift_uses_param(&self, i: usize) -> bool {
        i != Self::D
    }

    /// $G = [\sqrt{2D}]$, so that ½GGᵀ = D (`003_d2fc48a470e528fc.txt (0.1)`). Not finite
    /// (hence rejected by [`Sde::diffusion_matrix`]) for D < 0, and singular for D = 0.
    fn diffusion<D: Scalar>(&self, theta: &[D], out: &mut [D]) {
        out[0] = (theta[Self::D] * 2.0).sqrt();
    }
}
