//! The SDE fixtures: small models with known answers that the built-in models do not cover.
//!
//! Each implements only the required methods of [`Sde`] (no closed-form divergence or
//! derivatives, no declared polynomial degree), so every derivative a solver takes of them comes
//! by automatic differentiation — part of what the tests that use them check.

use crate::model::{Dims, Scalar, Sde};

/// Owned names from string literals.
fn names(list: &[&str]) -> Vec<String> {
    list.iter().map(|s| s.to_string()).collect()
}

/// Damped integrated noise with a constant forcing: a linear oscillator with a clean position,
///
/// $$ dV = (-k V - c Q + u)\,dt + \sigma\,dW, \qquad dQ = V\,dt, $$
///
/// noisy state `v` (velocity), clean state `q` (position), θ = (`k`, `c`, `u`, `sigma`,
/// `sigma_y`); `sigma_y` is left to the measurement model (the drift does not use it).
///
/// Known answers: the drift is linear with additive noise, so
/// [`LinearGaussianModel::from_sde`](crate::kalman::linear::LinearGaussianModel::from_sde) gives
/// its exact Kalman filter and RTS smoother: the EKF/UKF moment ODEs are exact, the EKS/UKS equal
/// the RTS smoother up to the ODE error, and the particle smoother converges to the RTS mean. The
/// clean state exercises the rows of z in all of them. With u = 0 it is the unforced oscillator
/// dV = (−kV − cQ) dt + σ dW (the drift's value is the same up to the sign of a zero).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LinearOscillator;

impl LinearOscillator {
    /// Parameter names, in the order of θ.
    pub const PARAMS: [&'static str; 5] = ["k", "c", "u", "sigma", "sigma_y"];
    /// Index of the damping `k` in θ.
    pub const K: usize = 0;
    /// Index of the stiffness `c` in θ.
    pub const C: usize = 1;
    /// Index of the forcing `u` in θ.
    pub const U: usize = 2;
    /// Index of the noise scale `sigma` in θ.
    pub const SIGMA: usize = 3;
    /// Index of the measurement sd `sigma_y` in θ.
    pub const SIGMA_Y: usize = 4;
}

impl Sde for LinearOscillator {
    fn dims(&self) -> Dims {
        Dims { noisy: 1, clean: 1, params: 5 }
    }

    fn noisy_names(&self) -> Vec<String> {
        names(&["v"])
    }

    fn clean_names(&self) -> Vec<String> {
        names(&["q"])
    }

    fn param_names(&self) -> Vec<String> {
        names(&Self::PARAMS)
    }

    /// f = −k v − c q + u.
    fn drift<D: Scalar>(&self, _t: D, x: &[D], z: &[D], th: &[D], out: &mut [D]) {
        out[0] = -th[Self::K] * x[0] - th[Self::C] * z[0] + th[Self::U];
    }

    /// h = v.
    fn clean_drift<D: Scalar>(&self, _t: D, x: &[D], _z: &[D], _th: &[D], out: &mut [D]) {
        out[0] = x[0];
    }

    /// G = (σ).
    fn diffusion<D: Scalar>(&self, th: &[D], out: &mut [D]) {
        out[0] = th[Self::SIGMA];
    }
}

/// The double well without the scale factor of the built-in
/// [`DoubleWell`](crate::model::library::DoubleWell), and with the noise scale itself as the
/// parameter:
///
/// $$ dX = (X - X^3)\,dt + \sigma\,dW, $$
///
/// one noisy state `x`, θ = (`sigma`). Its drift is −V′ for V(x) = x⁴/4 − x²/2 (wells at ±1,
/// barrier 1/4 at 0): a quarter of the built-in drift 4x − 4x³.
///
/// Known answers: the noise is additive and the drift nonlinear in x, so Euler–Maruyama has
/// strong order 1 and the Itô–Taylor scheme (Kloeden & Platen 1992, (10.4.6)) strong order 1.5
/// (Kloeden & Platen 1992, Secs. 10.2 and 10.4), no more.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct UnscaledDoubleWell;

impl Sde for UnscaledDoubleWell {
    fn dims(&self) -> Dims {
        Dims { noisy: 1, clean: 0, params: 1 }
    }

    fn noisy_names(&self) -> Vec<String> {
        names(&["x"])
    }

    fn param_names(&self) -> Vec<String> {
        names(&["sigma"])
    }

    /// f = x − x³.
    fn drift<D: Scalar>(&self, _t: D, x: &[D], _z: &[D], _th: &[D], out: &mut [D]) {
        out[0] = x[0] - x[0].powi(3);
    }

    /// G = (σ).
    fn diffusion<D: Scalar>(&self, th: &[D], out: &mut [D]) {
        out[0] = th[0];
    }
}

/// The unforced Duffing oscillator of the built-in
/// [`Duffing`](crate::model::library::Duffing) at a = 1, b = −1, d = 0.2, γ = 0, with the noise
/// scale as its only parameter:
///
/// $$ dV = (-Q^3 + Q - 0.2\,V)\,dt + \sigma\,dW, \qquad dQ = V\,dt, $$
///
/// noisy state `v` (velocity), clean state `q` (position), θ = (`sigma`).
///
/// Known answers: the drift is linear in the noisy state, so L¹a = σ ∂a/∂v is constant and the
/// one term of the strong order 2.0 Itô–Taylor scheme missing from the order 1.5 scheme,
/// (L¹L¹a) I₍₁,₁,₀₎, vanishes: the Itô–Taylor scheme (10.4.6) has strong order 2 on it and
/// Euler–Maruyama strong order 1 (Kloeden & Platen 1992, Secs. 10.2 and 10.5).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct UnforcedDuffing;

impl Sde for UnforcedDuffing {
    fn dims(&self) -> Dims {
        Dims { noisy: 1, clean: 1, params: 1 }
    }

    fn noisy_names(&self) -> Vec<String> {
        names(&["v"])
    }

    fn clean_names(&self) -> Vec<String> {
        names(&["q"])
    }

    fn param_names(&self) -> Vec<String> {
        names(&["sigma"])
    }

    /// f = −q³ + q − 0.2 v.
    fn drift<D: Scalar>(&self, _t: D, x: &[D], z: &[D], _th: &[D], out: &mut [D]) {
        out[0] = -z[0].powi(3) + z[0] - x[0] * 0.2;
    }

    /// h = v.
    fn clean_drift<D: Scalar>(&self, _t: D, x: &[D], _z: &[D], _th: &[D], out: &mut [D]) {
        out[0] = x[0];
    }

    /// G = (σ).
    fn diffusion<D: Scalar>(&self, th: &[D], out: &mut [D]) {
        out[0] = th[0];
    }
}

/// [`UnforcedDuffing`] with an added cubic damping −V³, so that its drift is nonlinear in the
/// noisy state:
///
/// $$ dV = (-Q^3 + Q - 0.2\,V - V^3)\,dt + \sigma\,dW, \qquad dQ = V\,dt, $$
///
/// noisy state `v`, clean state `q`, θ = (`sigma`).
///
/// Known answers: with L¹L¹a = σ² ∂²f/∂v² = −6σ²v ≠ 0 the Itô–Taylor scheme (10.4.6) has strong
/// order 1.5, no more, and Euler–Maruyama strong order 1 (Kloeden & Platen 1992, Secs. 10.2
/// and 10.4), with a clean state.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CubicDampedDuffing;

impl Sde for CubicDampedDuffing {
    fn dims(&self) -> Dims {
        Dims { noisy: 1, clean: 1, params: 1 }
    }

    fn noisy_names(&self) -> Vec<String> {
        names(&["v"])
    }

    fn clean_names(&self) -> Vec<String> {
        names(&["q"])
    }

    fn param_names(&self) -> Vec<String> {
        names(&["sigma"])
    }

    /// f = −q³ + q − 0.2 v − v³.
    fn drift<D: Scalar>(&self, _t: D, x: &[D], z: &[D], _th: &[D], out: &mut [D]) {
        out[0] = -z[0].powi(3) + z[0] - x[0] * 0.2 - x[0].powi(3);
    }

    /// h = v.
    fn clean_drift<D: Scalar>(&self, _t: D, x: &[D], _z: &[D], _th: &[D], out: &mut [D]) {
        out[0] = x[0];
    }

    /// G = (σ).
    fn diffusion<D: Scalar>(&self, th: &[D], out: &mut [D]) {
        out[0] = th[0];
    }
}

/// A model with every feature a scheme or a derivative must handle at once: two noisy states,
/// a clean state, explicit time dependence, products, powers, sin, cos and exp, and a full
/// (non-diagonal) noise matrix with two parameters in it:
///
/// $$ f_1 = a \sin(x_1)\,x_2 + z\,t, \qquad f_2 = -x_1^3 + \cos(t)\,x_2 z + x_1 x_2^2, \qquad
///    h = x_1 x_2 - z + e^{x_2}, \qquad G = \begin{pmatrix} b & 0.3 \\ -0.2 & c \end{pmatrix}, $$
///
/// noisy states `x1`, `x2`, clean state `z`, θ = (`a`, `b`, `c`).
///
/// Known answers: none in closed form; what it checks is an identity, e.g. one Itô–Taylor step
/// (Kloeden & Platen 1992, (10.4.6)) equals the formula assembled from its Jacobians and finite
/// differences, with no term of the scheme vanishing for it.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct TwoNoisyOneClean;

impl Sde for TwoNoisyOneClean {
    fn dims(&self) -> Dims {
        Dims { noisy: 2, clean: 1, params: 3 }
    }

    fn noisy_names(&self) -> Vec<String> {
        names(&["x1", "x2"])
    }

    fn clean_names(&self) -> Vec<String> {
        names(&["z"])
    }

    fn param_names(&self) -> Vec<String> {
        names(&["a", "b", "c"])
    }

    /// f = (a sin(x₁) x₂ + z t, −x₁³ + cos(t) x₂ z + x₁ x₂²).
    fn drift<D: Scalar>(&self, t: D, x: &[D], z: &[D], th: &[D], out: &mut [D]) {
        out[0] = x[0].sin() * x[1] * th[0] + z[0] * t;
        out[1] = -x[0].powi(3) + t.cos() * x[1] * z[0] + x[0] * x[1] * x[1];
    }

    /// h = x₁ x₂ − z + e^{x₂}.
    fn clean_drift<D: Scalar>(&self, _t: D, x: &[D], z: &[D], _th: &[D], out: &mut [D]) {
        out[0] = x[0] * x[1] - z[0] + x[1].exp();
    }

    /// G = [[b, 0.3], [−0.2, c]], column-major.
    fn diffusion<D: Scalar>(&self, th: &[D], out: &mut [D]) {
        out[0] = th[1];
        out[1] = D::from(-0.2);
        out[2] = D::from(0.3);
        out[3] = th[2];
    }
}

/// A damped rotation in the plane with isotropic noise, no parameters:
///
/// $$ dX = A X\,dt + G\,dW, \qquad A = \begin{pmatrix} -1 & 0.5 \\ -0.5 & -1 \end{pmatrix},
///    \qquad G = 0.5\,I, $$
///
/// noisy states `x1`, `x2`.
///
/// Known answers: linear with additive noise, so its smoothing laws are Gaussian (RTS) and the
/// Gaussian closure is exact for it, as is the degree-2 exponential family (the Gaussian family
/// in 2-D); A = −I + 0.5 J with J antisymmetric, so the stationary covariance, the solution of
/// AΣ + ΣAᵀ + GGᵀ = 0, is Σ = 0.125 I and the mean decays as e^{−t} while turning at rate 0.5.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DampedRotation;

impl Sde for DampedRotation {
    fn dims(&self) -> Dims {
        Dims { noisy: 2, clean: 0, params: 0 }
    }

    fn noisy_names(&self) -> Vec<String> {
        names(&["x1", "x2"])
    }

    fn param_names(&self) -> Vec<String> {
        Vec::new()
    }

    /// f = A x = (−x₁ + 0.5 x₂, −0.5 x₁ − x₂).
    fn drift<D: Scalar>(&self, _t: D, x: &[D], _z: &[D], _theta: &[D], out: &mut [D]) {
        out[0] = -x[0] + x[1] * 0.5;
        out[1] = -x[0] * 0.5 - x[1];
    }

    /// G = 0.5 I.
    fn diffusion<D: Scalar>(&self, _theta: &[D], out: &mut [D]) {
        out[0] = D::from(0.5);
        out[1] = D::from(0.0);
        out[2] = D::from(0.0);
        out[3] = D::from(0.5);
    }
}

/// The damped rotation of [`DampedRotation`] with a clean state that integrates the first noisy
/// state, no parameters:
///
/// $$ dX = A X\,dt + 0.5\,dW, \qquad dZ = X_1\,dt, \qquad
///    A = \begin{pmatrix} -1 & 0.5 \\ -0.5 & -1 \end{pmatrix}, $$
///
/// noisy states `x1`, `x2`, clean state `z`: three states, of which the clean one has no noise
/// (a singular diffusion on the full state).
///
/// Known answers: linear with additive noise, so
/// [`LinearGaussianModel::from_sde`](crate::kalman::linear::LinearGaussianModel::from_sde) gives
/// its exact Kalman filter and RTS smoother, and the Gaussian closure is exact for it.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RotationWithPosition;

impl Sde for RotationWithPosition {
    fn dims(&self) -> Dims {
        Dims { noisy: 2, clean: 1, params: 0 }
    }

    fn noisy_names(&self) -> Vec<String> {
        names(&["x1", "x2"])
    }

    fn clean_names(&self) -> Vec<String> {
        names(&["z"])
    }

    fn param_names(&self) -> Vec<String> {
        Vec::new()
    }

    /// f = A x, as [`DampedRotation`].
    fn drift<D: Scalar>(&self, t: D, x: &[D], z: &[D], theta: &[D], out: &mut [D]) {
        DampedRotation.drift(t, x, z, theta, out);
    }

    /// h = x₁.
    fn clean_drift<D: Scalar>(&self, _t: D, x: &[D], _z: &[D], _theta: &[D], out: &mut [D]) {
        out[0] = x[0];
    }

    /// G = 0.5 I, as [`DampedRotation`].
    fn diffusion<D: Scalar>(&self, theta: &[D], out: &mut [D]) {
        DampedRotation.diffusion(theta, out);
    }
}

/// The damped rotation of [`DampedRotation`] with a third noisy state that relaxes to the first,
/// no parameters:
///
/// $$ dX_{1,2} = A X_{1,2}\,dt + 0.5\,dW_{1,2}, \qquad dX_3 = (X_1 - X_3)\,dt + 0.5\,dW_3, $$
///
/// noisy states `x1`, `x2`, `x3`: three states, all noisy (an invertible diffusion).
///
/// Known answers: linear with additive noise, so
/// [`LinearGaussianModel::from_sde`](crate::kalman::linear::LinearGaussianModel::from_sde) gives
/// its exact Kalman filter and RTS smoother; the Gaussian closure is exact for it, and so is every
/// polynomial exponential family of even degree in three states (it holds the Gaussians).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RotationWithLag;

impl Sde for RotationWithLag {
    fn dims(&self) -> Dims {
        Dims { noisy: 3, clean: 0, params: 0 }
    }

    fn noisy_names(&self) -> Vec<String> {
        names(&["x1", "x2", "x3"])
    }

    fn param_names(&self) -> Vec<String> {
        Vec::new()
    }

    /// f = (A x₁₂, x₁ − x₃).
    fn drift<D: Scalar>(&self, t: D, x: &[D], z: &[D], theta: &[D], out: &mut [D]) {
        DampedRotation.drift(t, &x[..2], z, theta, &mut out[..2]);
        out[2] = x[0] - x[2];
    }

    /// G = 0.5 I.
    fn diffusion<D: Scalar>(&self, _theta: &[D], out: &mut [D]) {
        for (k, g) in out.iter_mut().enumerate().take(9) {
            *g = D::from(if k % 4 == 0 { 0.5 } else { 0.0 });
        }
    }
}
