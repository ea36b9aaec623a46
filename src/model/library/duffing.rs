//! The stochastic Duffing oscillator of `000_74b95e149527c64e.txt` Sec. 4.1.1.

use super::names;
use crate::model::{Dims, DriftDerivatives, Scalar, Sde};

/// The forced stochastic Duffing oscillator, `000_74b95e149527c64e.txt (4.2)`, `(4.6)`:
///
/// $$ dX = \left[-a Z^3 - b Z - d X + \gamma \cos t\right] dt + \sigma_D\,dW, \qquad dZ = X\,dt, $$
///
/// one noisy state `x` (the velocity), one clean state `z` (the position), parameters
/// θ = (`a`, `b`, `d`, `gamma`, `sigma_d`, `sigma_y`); `sigma_y` is the measurement standard
/// deviation Σ_y, which the dynamics do not use (measurement parameters share θ). The
/// divergence with respect to the noisy state is the constant $\operatorname{div}_x f = -d$.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Duffing;

impl Duffing {
    /// Parameter names, in the order of θ.
    pub const PARAMS: [&'static str; 6] = ["a", "b", "d", "gamma", "sigma_d", "sigma_y"];
    /// Nominal values, `000_74b95e149527c64e.txt` Table 4.1: a = 1, b = −1, d = 0.2,
    /// γ = 0.3, σ_D = 0.1, Σ_y = 0.1.
    pub const NOMINAL: [f64; 6] = [1.0, -1.0, 0.2, 0.3, 0.1, 0.1];
    /// Index of `a` in θ.
    pub const A: usize = 0;
    /// Index of `b` in θ.
    pub const B: usize = 1;
    /// Index of `d` in θ.
    pub const D: usize = 2;
    /// Index of `gamma` in θ.
    pub const GAMMA: usize = 3;
    /// Index of `sigma_d` in θ.
    pub const SIGMA_D: usize = 4;
    /// Index of `sigma_y` in θ.
    pub const SIGMA_Y: usize = 5;
}

impl Sde for Duffing {
    fn dims(&self) -> Dims {
        Dims { noisy: 1, clean: 1, params: 6 }
    }

    fn noisy_names(&self) -> Vec<String> {
        names(&["x"])
    }

    fn clean_names(&self) -> Vec<String> {
        names(&["z"])
    }

    fn param_names(&self) -> Vec<String> {
        names(&Self::PARAMS)
    }

    /// $f = -a z^3 - b z - d x + \gamma \cos t$, `000_74b95e149527c64e.txt (4.6)`.
    fn drift<D: Scalar>(&self, t: D, x: &[D], z: &[D], theta: &[D], out: &mut [D]) {
        let (a, b, d, gamma) = (theta[Self::A], theta[Self::B], theta[Self::D], theta[Self::GAMMA]);
        let z = z[0];
        out[0] = -a * z.powi(3) - b * z - d * x[0] + gamma * t.cos();
    }

    /// $h = x$, `000_74b95e149527c64e.txt (4.6)`.
    fn clean_drift<D: Scalar>(&self, _t: D, x: &[D], _z: &[D], _theta: &[D], out: &mut [D]) {
        out[0] = x[0];
    }

    /// $\operatorname{div}_x f = -d$ (`000_74b95e149527c64e.txt (4.6)`), in closed form.
    fn divergence<D: Scalar>(&self, _t: D, _x: &[D], _z: &[D], theta: &[D]) -> D {
        -theta[Self::D]
    }

    /// f, h, div_x f and their derivatives in (x, z, θ) in closed form:
    /// ∂f/∂(x, z, a, b, d, γ) = (−d, −3az² − b, −z³, −z, −x, cos t), ∂²f/∂z² = −6az,
    /// ∂²f/∂z∂a = −3z², ∂²f/∂z∂b = −1, ∂²f/∂x∂d = −1; ∂h/∂x = 1; ∂(div_x f)/∂d = −1.
    fn drift_derivatives(
        &self,
        t: f64,
        x: &[f64],
        z: &[f64],
        theta: &[f64],
        out: &mut DriftDerivatives,
    ) -> bool {
        const X: usize = 0;
        const Z: usize = 1;
        let th = |i: usize| 2 + i;
        let (a, b, d, zz) = (theta[Self::A], theta[Self::B], theta[Self::D], z[0]);
        out.first(0, X, -d);
        out.first(0, Z, -3.0 * a * zz * zz - b);
        out.first(0, th(Self::A), -zz * zz * zz);
        out.first(0, th(Self::B), -zz);
        out.first(0, th(Self::D), -x[0]);
        out.first(0, th(Self::GAMMA), t.cos());
        out.second(0, Z, Z, -6.0 * a * zz);
        out.second(0, Z, th(Self::A), -3.0 * zz * zz);
        out.second(0, Z, th(Self::B), -1.0);
        out.second(0, X, th(Self::D), -1.0);
        out.first(1, X, 1.0);
        out.first(2, th(Self::D), -1.0);
        true
    }

    /// f = −az³ − bz − dx + γ cos t and h = x: a cubic in (x, z).
    fn drift_polynomial_degree(&self) -> Option<usize> {
        Some(3)
    }

    /// Σ_D enters G only, Σ_y the measurements only.
    fn drift_uses_param(&self, i: usize) -> bool {
        i != Self::SIGMA_D && i != Self::SIGMA_Y
    }

    /// $G = [\sigma_D]$.
    fn diffusion<D: Scalar>(&self, theta: &[D], out: &mut [D]) {
        out[0] = theta[Self::SIGMA_D];
    }
}
