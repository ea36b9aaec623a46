//! The tanh motivating example of `001_8aefdf0570c96f51.txt` Sec. 2.

use super::names;
use crate::model::{Dims, DriftDerivatives, Scalar, Sde};

/// The scalar SDE of the motivating example, `001_8aefdf0570c96f51.txt` Sec. 2 (Fig. 1):
///
/// $$ dX = \tanh(X)\,dt + \sigma\,dW, $$
///
/// one noisy state `x`, parameter θ = (`sigma`), σ = 1 in the paper. Its transition density is
/// known exactly (Daum, 1986, cited there). The divergence
/// $\operatorname{div} f = 1 - \tanh^2 x$ is largest at the origin, which is why the Euler
/// (minimum-energy) and Onsager–Machlup MAP paths differ visibly for this model.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Tanh;

impl Tanh {
    /// Parameter names, in the order of θ.
    pub const PARAMS: [&'static str; 1] = ["sigma"];
    /// Nominal values: σ = 1 (`001_8aefdf0570c96f51.txt` Sec. 2, the SDE has unit noise).
    pub const NOMINAL: [f64; 1] = [1.0];
    /// Index of `sigma` in θ.
    pub const SIGMA: usize = 0;
}

impl Sde for Tanh {
    fn dims(&self) -> Dims {
        Dims { noisy: 1, clean: 0, params: 1 }
    }

    fn noisy_names(&self) -> Vec<String> {
        names(&["x"])
    }

    fn param_names(&self) -> Vec<String> {
        names(&Self::PARAMS)
    }

    /// $f(x) = \tanh x$.
    fn drift<D: Scalar>(&self, _t: D, x: &[D], _z: &[D], _theta: &[D], out: &mut [D]) {
        out[0] = x[0].tanh();
    }

    /// $\operatorname{div} f = 1 - \tanh^2 x$, in closed form.
    fn divergence<D: Scalar>(&self, _t: D, x: &[D], _z: &[D], _theta: &[D]) -> D {
        let th = x[0].tanh();
        D::from(1.0) - th * th
    }

    /// f = tanh x and div f = 1 − tanh² x with their derivatives in closed form: with
    /// τ = tanh x, f′ = 1 − τ², f″ = −2τ(1 − τ²), (div f)″ = (6τ² − 2)(1 − τ²).
    fn drift_derivatives(
        &self,
        _t: f64,
        x: &[f64],
        _z: &[f64],
        _theta: &[f64],
        out: &mut DriftDerivatives,
    ) -> bool {
        let tau = x[0].tanh();
        let q = 1.0 - tau * tau;
        out.first(0, 0, q);
        out.second(0, 0, 0, -2.0 * tau * q);
        out.first(1, 0, -2.0 * tau * q);
        out.second(1, 0, 0, (6.0 * tau * tau - 2.0) * q);
        true
    }

    /// Σ enters G only.
    fn drift_uses_param(&self, i: usize) -> bool {
        i != Self::SIGMA
    }

    /// The drift does not read t.
    fn drift_is_autonomous(&self) -> bool {
        true
    }

    /// $G = [\sigma]$.
    fn diffusion<D: Scalar>(&self, theta: &[D], out: &mut [D]) {
        out[0] = theta[Self::SIGMA];
    }
}
