//! The Lorenz-96 system with additive noise, any number of states.

use crate::model::{Dims, DriftDerivatives, Scalar, Sde};

/// The stochastic Lorenz-96 system with additive isotropic noise (Lorenz, *Predictability — a
/// problem partly solved*, ECMWF Seminar on Predictability, 1996, eq. (1), for the drift):
///
/// $$ f_i(x) = (x_{i+1} - x_{i-2})\,x_{i-1} - x_i + F, \qquad i = 1, \dots, n
///    \text{ (indices mod } n), \qquad G = \sigma_w I_n, $$
///
/// n ≥ 4 noisy states named `x1`, …, `xn`, parameters θ = (`forcing`, `sigma_w`) = (F, σ_w).
/// The quadratic terms conserve the energy ½|x|² (Σ_i x_i(x_{i+1} − x_{i−2})x_{i−1} = 0), the
/// linear term damps it and F drives it; with F = 8 the deterministic system is chaotic for
/// n ≥ 5 or so. The divergence is the constant −n.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Lorenz96 {
    states: usize,
}

impl Default for Lorenz96 {
    /// Ten states.
    fn default() -> Self {
        Lorenz96 { states: 10 }
    }
}

impl Lorenz96 {
    /// Parameter names, in the order of θ.
    pub const PARAMS: [&'static str; 2] = ["forcing", "sigma_w"];
    /// Nominal values: Lorenz's F = 8 (chaotic regime) and σ_w = √0.1 (noise variance 0.1 per
    /// unit time on each state, our choice).
    pub const NOMINAL: [f64; 2] = [8.0, 0.316_227_766_016_837_94];
    /// Index of `forcing` (F) in θ.
    pub const FORCING: usize = 0;
    /// Index of `sigma_w` in θ.
    pub const SIGMA_W: usize = 1;
    /// The fewest states for which the stencil (i − 2, i − 1, i, i + 1) has distinct indices.
    pub const MIN_STATES: usize = 4;

    /// The system with `states` states; `None` below [`Lorenz96::MIN_STATES`].
    pub fn new(states: usize) -> Option<Lorenz96> {
        (states >= Self::MIN_STATES).then_some(Lorenz96 { states })
    }

    /// The number of states n.
    pub fn states(&self) -> usize {
        self.states
    }
}

impl Sde for Lorenz96 {
    fn dims(&self) -> Dims {
        Dims { noisy: self.states, clean: 0, params: 2 }
    }

    fn noisy_names(&self) -> Vec<String> {
        (1..=self.states).map(|i| format!("x{i}")).collect()
    }

    fn param_names(&self) -> Vec<String> {
        Self::PARAMS.iter().map(|s| s.to_string()).collect()
    }

    /// $f_i = (x_{i+1} - x_{i-2}) x_{i-1} - x_i + F$, indices mod n.
    fn drift<D: Scalar>(&self, _t: D, x: &[D], _z: &[D], theta: &[D], out: &mut [D]) {
        let n = self.states;
        let forcing = theta[Self::FORCING];
        for i in 0..n {
            let (next, prev, prev2) = (x[(i + 1) % n], x[(i + n - 1) % n], x[(i + n - 2) % n]);
            out[i] = (next - prev2) * prev - x[i] + forcing;
        }
    }

    /// $\operatorname{div} f = -n$.
    fn divergence<D: Scalar>(&self, _t: D, _x: &[D], _z: &[D], _theta: &[D]) -> D {
        D::from(-(self.states as f64))
    }

    /// f, div f and their derivatives in (x, θ) in closed form: ∂f_i/∂x_{i+1} = x_{i−1},
    /// ∂f_i/∂x_{i−1} = x_{i+1} − x_{i−2}, ∂f_i/∂x_{i−2} = −x_{i−1}, ∂f_i/∂x_i = −1,
    /// ∂f_i/∂F = 1; the second derivatives are the constants ∂²f_i/∂x_{i+1}∂x_{i−1} = 1 and
    /// ∂²f_i/∂x_{i−2}∂x_{i−1} = −1; div f = −n has none.
    fn drift_derivatives(
        &self,
        _t: f64,
        x: &[f64],
        _z: &[f64],
        _theta: &[f64],
        out: &mut DriftDerivatives,
    ) -> bool {
        let n = self.states;
        for i in 0..n {
            let (next, prev, prev2) = ((i + 1) % n, (i + n - 1) % n, (i + n - 2) % n);
            out.first(i, next, x[prev]);
            out.first(i, prev, x[next] - x[prev2]);
            out.first(i, prev2, -x[prev]);
            out.first(i, i, -1.0);
            out.first(i, n + Self::FORCING, 1.0);
            out.second(i, next, prev, 1.0);
            out.second(i, prev2, prev, -1.0);
        }
        true
    }

    /// The drift does not read t.
    fn drift_is_autonomous(&self) -> bool {
        true
    }

    /// f is quadratic (the products x_{i±1}x_{i−1}, x_{i−2}x_{i−1}).
    fn drift_polynomial_degree(&self) -> Option<usize> {
        Some(2)
    }

    /// σ_w enters G only.
    fn drift_uses_param(&self, i: usize) -> bool {
        i != Self::SIGMA_W
    }

    /// $G = \sigma_w I_n$ (column-major).
    fn diffusion<D: Scalar>(&self, theta: &[D], out: &mut [D]) {
        let s = theta[Self::SIGMA_W];
        let n = self.states;
        for (k, g) in out.iter_mut().enumerate() {
            *g = if k % (n + 1) == 0 { s } else { D::from(0.0) };
        }
    }
}
