//! The Ornstein–Uhlenbeck process, the linear-Gaussian reference model.

use super::names;
use crate::model::{Dims, DriftDerivatives, Scalar, Sde};

/// The Ornstein–Uhlenbeck process
///
/// $$ dX = -\theta X\,dt + \sigma\,dW, $$
///
/// one noisy state `x`, parameters θ = (`theta`, `sigma`).
///
/// Its transition density and smoothing distribution are Gaussian and known in closed form,
/// which makes it the reference model of the cross-method identities: for linear dynamics the
/// effective action is the Onsager–Machlup action (`003_d2fc48a470e528fc.txt` Sec. I.3), so the
/// MAP path, the RTS smoother mean, the Gaussian-closure estimate and the KSP mean coincide.
/// Its divergence is the constant $\operatorname{div} f = -\theta$.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Ou;

impl Ou {
    /// Parameter names, in the order of θ.
    pub const PARAMS: [&'static str; 2] = ["theta", "sigma"];
    /// Default parameter values (our choice, not from a paper): θ = 1 (unit relaxation time),
    /// σ = 0.5 (stationary standard deviation σ/√(2θ) ≈ 0.354).
    pub const NOMINAL: [f64; 2] = [1.0, 0.5];
    /// Index of `theta` in θ.
    pub const THETA: usize = 0;
    /// Index of `sigma` in θ.
    pub const SIGMA: usize = 1;
}

impl Sde for Ou {
    fn dims(&self) -> Dims {
        Dims { noisy: 1, clean: 0, params: 2 }
    }

    fn noisy_names(&self) -> Vec<String> {
        names(&["x"])
    }

    fn param_names(&self) -> Vec<String> {
        names(&Self::PARAMS)
    }

    /// $f(x) = -\theta x$.
    fn drift<D: Scalar>(&self, _t: D, x: &[D], _z: &[D], theta: &[D], out: &mut [D]) {
        out[0] = -theta[Self::THETA] * x[0];
    }

    /// $\operatorname{div} f = -\theta$, in closed form.
    fn divergence<D: Scalar>(&self, _t: D, _x: &[D], _z: &[D], theta: &[D]) -> D {
        -theta[Self::THETA]
    }

    /// f = −θx and div f = −θ with their derivatives in (x, θ, σ) in closed form:
    /// ∂f/∂(x, θ) = (−θ, −x), ∂²f/∂x∂θ = −1, ∂(div f)/∂θ = −1.
    fn drift_derivatives(
        &self,
        _t: f64,
        x: &[f64],
        _z: &[f64],
        theta: &[f64],
        out: &mut DriftDerivatives,
    ) -> bool {
        const TH: usize = 1 + Ou::THETA;
        out.first(0, 0, -theta[Self::THETA]);
        out.first(0, TH, -x[0]);
        out.second(0, 0, TH, -1.0);
        out.first(1, TH, -1.0);
        true
    }

    /// The drift does not read t.
    fn drift_is_autonomous(&self) -> bool {
        true
    }

    /// f = −θx: linear.
    fn drift_polynomial_degree(&self) -> Option<usize> {
        Some(1)
    }

    /// Σ enters G only.
    fn drift_uses_param(&self, i: usize) -> bool {
        i != Self::SIGMA
    }

    /// $G = [\sigma]$.
    fn diffusion<D: Scalar>(&self, theta: &[D], out: &mut [D]) {
        out[0] = theta[Self::SIGMA];
    }
}
