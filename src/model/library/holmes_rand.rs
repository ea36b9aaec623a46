//! The stochastic Holmes–Rand oscillator of `000_74b95e149527c64e.txt` Sec. 4.1.3.

use super::names;
use crate::model::{Dims, DriftDerivatives, Scalar, Sde};

/// The forced stochastic Holmes–Rand oscillator, `000_74b95e149527c64e.txt (4.8)`
/// (Sec. 4.1.3), which contains the Duffing and Van der Pol oscillators as special cases:
///
/// $$ dX = \left[-(a + \gamma Z^2) X - b Z - d Z^3 + \phi \cos t\right] dt + \sigma_D\,dW,
///    \qquad dZ = X\,dt, $$
///
/// one noisy state `x`, one clean state `z`, parameters
/// θ = (`a`, `b`, `gamma`, `d`, `phi`, `sigma_d`, `sigma_y`) — the thesis's order
/// [a, b, γ, d, σ_y] with the known φ and σ_D inserted before σ_y. The divergence is
/// $\operatorname{div}_x f = -(a + \gamma z^2)$.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct HolmesRand;

impl HolmesRand {
    /// Parameter names, in the order of θ.
    pub const PARAMS: [&'static str; 7] = ["a", "b", "gamma", "d", "phi", "sigma_d", "sigma_y"];
    /// Nominal values, `000_74b95e149527c64e.txt` Table 4.3: a = 0.2, b = −1, γ = 0.2, d = 1,
    /// φ = 0.4, σ_D = 0.1. The thesis varies Σ_y across scenarios; 0.005 is the value of its
    /// Figs. 4.15–4.16 (Σ_y ≪ l_b = 0.05, the case where quantization matters most).
    pub const NOMINAL: [f64; 7] = [0.2, -1.0, 0.2, 1.0, 0.4, 0.1, 0.005];
    /// Index of `a` in θ.
    pub const A: usize = 0;
    /// Index of `b` in θ.
    pub const B: usize = 1;
    /// Index of `gamma` in θ.
    pub const GAMMA: usize = 2;
    /// Index of `d` in θ.
    pub const D: usize = 3;
    /// Index of `phi` in θ.
    pub const PHI: usize = 4;
    /// Index of `sigma_d` in θ.
    pub const SIGMA_D: usize = 5;
    /// Index of `sigma_y` in θ.
    pub const SIGMA_Y: usize = 6;
}

impl Sde for HolmesRand {
    fn dims(&self) -> Dims {
        Dims { noisy: 1, clean: 1, params: 7 }
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

    /// $f = -(a + \gamma z^2) x - b z - d z^3 + \phi \cos t$, `000_74b95e149527c64e.txt (4.8a)`.
    fn drift<D: Scalar>(&self, t: D, x: &[D], z: &[D], theta: &[D], out: &mut [D]) {
        let (a, b, gamma, d, phi) =
            (theta[Self::A], theta[Self::B], theta[Self::GAMMA], theta[Self::D], theta[Self::PHI]);
        let z = z[0];
        out[0] = -(a + gamma * z * z) * x[0] - b * z - d * z.powi(3) + phi * t.cos();
    }

    /// $h = x$, `000_74b95e149527c64e.txt (4.8b)`.
    fn clean_drift<D: Scalar>(&self, _t: D, x: &[D], _z: &[D], _theta: &[D], out: &mut [D]) {
        out[0] = x[0];
    }

    /// $\operatorname{div}_x f = -(a + \gamma z^2)$ (`000_74b95e149527c64e.txt (4.8a)`), in closed form.
    fn divergence<D: Scalar>(&self, _t: D, _x: &[D], z: &[D], theta: &[D]) -> D {
        -(theta[Self::A] + theta[Self::GAMMA] * z[0] * z[0])
    }

    /// f, h, div_x f and their derivatives in (x, z, θ) in closed form:
    /// ∂f/∂(x, z, a, b, γ, d, φ) = (−(a + γz²), −2γzx − b − 3dz², −x, −z, −z²x, −z³, cos t),
    /// ∂²f/∂x∂z = −2γz, ∂²f/∂x∂a = −1, ∂²f/∂x∂γ = −z², ∂²f/∂z² = −2γx − 6dz, ∂²f/∂z∂b = −1,
    /// ∂²f/∂z∂γ = −2zx, ∂²f/∂z∂d = −3z²; ∂h/∂x = 1; ∂(div_x f)/∂(z, a, γ) = (−2γz, −1, −z²),
    /// ∂²(div_x f)/∂z² = −2γ, ∂²(div_x f)/∂z∂γ = −2z.
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
        let (a, b, gamma, d) = (theta[Self::A], theta[Self::B], theta[Self::GAMMA], theta[Self::D]);
        let (x, z) = (x[0], z[0]);
        out.first(0, X, -(a + gamma * z * z));
        out.first(0, Z, -2.0 * gamma * z * x - b - 3.0 * d * z * z);
        out.first(0, th(Self::A), -x);
        out.first(0, th(Self::B), -z);
        out.first(0, th(Self::GAMMA), -z * z * x);
        out.first(0, th(Self::D), -z * z * z);
        out.first(0, th(Self::PHI), t.cos());
        out.second(0, X, Z, -2.0 * gamma * z);
        out.second(0, X, th(Self::A), -1.0);
        out.second(0, X, th(Self::GAMMA), -z * z);
        out.second(0, Z, Z, -2.0 * gamma * x - 6.0 * d * z);
        out.second(0, Z, th(Self::B), -1.0);
        out.second(0, Z, th(Self::GAMMA), -2.0 * z * x);
        out.second(0, Z, th(Self::D), -3.0 * z * z);
        out.first(1, X, 1.0);
        out.first(2, Z, -2.0 * gamma * z);
        out.first(2, th(Self::A), -1.0);
        out.first(2, th(Self::GAMMA), -z * z);
        out.second(2, Z, Z, -2.0 * gamma);
        out.second(2, Z, th(Self::GAMMA), -2.0 * z);
        true
    }

    /// f = −(a + γz²)x − bz − dz³ + φ cos t and h = x: a cubic in (x, z).
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
