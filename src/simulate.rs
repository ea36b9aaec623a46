//! Simulation of SDE paths and of measurements.
//!
//! The model class is that of `000_74b95e149527c64e.txt (2.4)`: noisy states x with additive
//! noise and clean states z,
//!
//! $$ dX = f(t, X, Z, \theta)\,dt + G(\theta)\,dW, \qquad dZ = h(t, X, Z, \theta)\,dt. $$
//!
//! Written for the full state $s = (x, z)$ it is $ds = a(t, s)\,dt + B\,dW$ with drift
//! $a = (f, h)$ and the constant noise matrix $B = (G; 0)$ (zero rows for the clean states), an
//! SDE with *additive* noise. Two schemes are provided ([`Scheme`]):
//!
//! - Euler–Maruyama, `000_74b95e149527c64e.txt (3.1)` (Kloeden & Platen 1992, Sec. 9.1 / 10.2),
//!   strong order 1 for additive noise;
//! - the strong order 1.5 Itô–Taylor scheme for additive noise (Kloeden & Platen 1992,
//!   Sec. 10.4, eq. (10.4.6); Sec. 11.2 for its derivative-free variant, the scheme used for
//!   every simulated example of `000_74b95e149527c64e.txt` Sec. 4.1), with its derivatives
//!   taken from the model by automatic differentiation.
//!
//! [`simulate`] draws the Brownian increments and integrates; [`integrate`] integrates with
//! externally supplied increments ([`BrownianIncrements`]), which can be coarse-grained
//! ([`BrownianIncrements::coarsen`]) so that several step sizes are driven by one Brownian path.
//! [`sample_measurements`] and [`sample_measurements_at`] draw measurements from a simulated
//! path with an [`Observation`] model; [`sample_record`] draws a continuous-time record
//! ([`ContinuousRecord`]) of a path's measured states.
//!
//! Reference: P. E. Kloeden and E. Platen, *Numerical Solution of Stochastic Differential
//! Equations*, Springer, 1992 (cited by `000_74b95e149527c64e.txt` Sec. 4.1).

use std::fmt;
use std::str::FromStr;

use num_dual::{Dual2_64, Dual64};
use rand::Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

use crate::data::continuous::{cell_midpoints, ContinuousRecord};
use crate::data::{Dataset, StatePath};
use crate::model::observation::StateMeasurement;
use crate::model::{check_len, Observation, Sde};
use crate::{Error, Result};

/// The largest number of integration steps accepted (10⁸); more is treated as a mistaken
/// option rather than an attempt to fill the memory.
pub const MAX_STEPS: usize = 100_000_000;

/// Relative tolerance within which `(t_end − t0)/dt` (and `every/dt`) must be an integer.
const RATIO_TOL: f64 = 1e-9;

/// An integration scheme for SDEs with additive noise.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Scheme {
    /// Euler–Maruyama, `000_74b95e149527c64e.txt (3.1)` (Kloeden & Platen 1992, Sec. 9.1):
    ///
    /// $$ s_{k+1} = s_k + a(t_k, s_k)\,\Delta + B\,\Delta W_k. $$
    ///
    /// Strong order 1 and weak order 1 for additive noise (Kloeden & Platen 1992, Sec. 10.2
    /// and 14.1). Its name is `euler-maruyama`.
    #[serde(rename = "euler-maruyama")]
    EulerMaruyama,
    /// The strong order 1.5 Itô–Taylor scheme for additive noise (Kloeden & Platen 1992,
    /// Sec. 10.4, eq. (10.4.6)):
    ///
    /// $$ s_{k+1} = s_k + a\,\Delta + B\,\Delta W + \sum_{j} (L^j a)\,\Delta Z_j
    ///    + (L^0 a)\,\tfrac12\Delta^2, $$
    ///
    /// with every coefficient at $(t_k, s_k)$, the operators
    ///
    /// $$ L^j = \sum_k B_{kj}\,\partial_{s_k}, \qquad
    ///    L^0 = \partial_t + \sum_k a_k\,\partial_{s_k}
    ///    + \tfrac12 \sum_{k,l} (BB^\top)_{kl}\,\partial^2_{s_k s_l}, $$
    ///
    /// and the double integrals $\Delta Z_j = \int_{t_k}^{t_{k+1}} (W^j_s - W^j_{t_k})\,ds$
    /// (see [`BrownianIncrements`]). The term $(L^0 B)(\Delta W\,\Delta - \Delta Z)$ of the
    /// general scheme vanishes because B is constant. Its name is `ito-taylor-1.5`.
    #[serde(rename = "ito-taylor-1.5")]
    ItoTaylor15,
}

impl Scheme {
    /// Every scheme, in a fixed order.
    pub const ALL: [Scheme; 2] = [Scheme::EulerMaruyama, Scheme::ItoTaylor15];

    /// The scheme's name as accepted by [`FromStr`]: `euler-maruyama` or `ito-taylor-1.5`.
    pub fn name(self) -> &'static str {
        match self {
            Scheme::EulerMaruyama => "euler-maruyama",
            Scheme::ItoTaylor15 => "ito-taylor-1.5",
        }
    }

    /// The scheme's strong order of convergence for additive noise: 1 for Euler–Maruyama
    /// (Kloeden & Platen 1992, Sec. 10.2), 1.5 for the Itô–Taylor scheme (Sec. 10.4).
    pub fn strong_order(self) -> f64 {
        match self {
            Scheme::EulerMaruyama => 1.0,
            Scheme::ItoTaylor15 => 1.5,
        }
    }
}

impl fmt::Display for Scheme {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Scheme {
    type Err = Error;

    fn from_str(s: &str) -> Result<Scheme> {
        Scheme::ALL.into_iter().find(|sc| sc.name() == s).ok_or_else(|| Error::UnknownName {
            kind: "scheme".into(),
            name: s.into(),
            known: Scheme::ALL.iter().map(|sc| sc.name().to_string()).collect(),
        })
    }
}

/// Options of [`simulate`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
#[non_exhaustive]
pub struct SimulateOptions {
    /// The integration scheme. Default: [`Scheme::ItoTaylor15`] (the scheme of
    /// `000_74b95e149527c64e.txt` Sec. 4.1).
    pub scheme: Scheme,
    /// Initial time. Default: 0.
    pub t0: f64,
    /// Final time, greater than `t0`. Default: 1.
    pub t_end: f64,
    /// Step size, positive, with `(t_end − t0)/dt` an integer (within 10⁻⁹ relative) of at
    /// most [`MAX_STEPS`]. Default: 0.01.
    pub dt: f64,
}

impl Default for SimulateOptions {
    fn default() -> Self {
        SimulateOptions { scheme: Scheme::ItoTaylor15, t0: 0.0, t_end: 1.0, dt: 0.01 }
    }
}

impl SimulateOptions {
    /// Options for the interval `[t0, t_end]` with step `dt` and the default scheme.
    pub fn new(t0: f64, t_end: f64, dt: f64) -> Self {
        SimulateOptions { t0, t_end, dt, ..Default::default() }
    }

    /// Sets the scheme.
    pub fn with_scheme(mut self, scheme: Scheme) -> Self {
        self.scheme = scheme;
        self
    }

    /// Validates the options and returns the number of steps `(t_end − t0)/dt`.
    ///
    /// Errors: [`Error::InvalidOption`] when `t0` is not finite, `dt` is not positive and
    /// finite, `t_end` is not finite and greater than `t0`, or the ratio is not an integer
    /// within 10⁻⁹ relative or exceeds [`MAX_STEPS`].
    pub fn n_steps(&self) -> Result<usize> {
        if !self.t0.is_finite() {
            return Err(invalid("t0", format!("must be finite, got {}", self.t0)));
        }
        if !(self.t_end.is_finite() && self.t_end > self.t0) {
            return Err(invalid(
                "t_end",
                format!("must be finite and greater than t0 = {}, got {}", self.t0, self.t_end),
            ));
        }
        let n = integer_ratio(self.t_end - self.t0, self.dt, "dt", "(t_end - t0) / dt")?;
        if n > MAX_STEPS {
            return Err(invalid(
                "dt",
                format!("(t_end - t0) / dt = {n} steps exceeds the limit of {MAX_STEPS}"),
            ));
        }
        Ok(n)
    }
}

fn invalid(name: &str, reason: String) -> Error {
    Error::InvalidOption { name: name.into(), reason }
}

/// `span / step` as a positive integer (within [`RATIO_TOL`] relative), or an
/// `InvalidOption` error naming `name`.
fn integer_ratio(span: f64, step: f64, name: &str, what: &str) -> Result<usize> {
    if !(step.is_finite() && step > 0.0) {
        return Err(invalid(name, format!("must be positive and finite, got {step}")));
    }
    let ratio = span / step;
    if !ratio.is_finite() || ratio > 1e15 {
        return Err(invalid(name, format!("{what} = {ratio} is too large")));
    }
    let n = ratio.round();
    if n < 1.0 || (ratio - n).abs() > RATIO_TOL * ratio {
        return Err(invalid(name, format!("{what} = {ratio} is not a positive integer")));
    }
    Ok(n as usize)
}

/// Brownian increments on a uniform grid, with the double integrals needed by the strong
/// order 1.5 scheme (Kloeden & Platen 1992, Sec. 10.4):
///
/// $$ \Delta W_k = W_{t_{k+1}} - W_{t_k}, \qquad
///    \Delta Z_k = \int_{t_k}^{t_{k+1}} (W_s - W_{t_k})\,ds, $$
///
/// component by component. Stored step-major: the increments of step k are
/// `dw()[k*dim..(k+1)*dim]` and `dz()[k*dim..(k+1)*dim]`.
#[derive(Debug, Clone, PartialEq)]
pub struct BrownianIncrements {
    dim: usize,
    dt: f64,
    n_steps: usize,
    dw: Vec<f64>,
    dz: Vec<f64>,
}

impl BrownianIncrements {
    /// Wraps given increments, checking that `dt` is positive and finite, that `dw` and `dz`
    /// both have `dim * n_steps` entries, and that they are finite.
    pub fn try_new(dim: usize, dt: f64, n_steps: usize, dw: Vec<f64>, dz: Vec<f64>) -> Result<Self> {
        if !(dt.is_finite() && dt > 0.0) {
            return Err(invalid("dt", format!("must be positive and finite, got {dt}")));
        }
        let len =
            dim.checked_mul(n_steps).ok_or_else(|| invalid("n_steps", "dim * n_steps overflows".into()))?;
        check_len("Brownian increments dw", len, dw.len())?;
        check_len("Brownian double integrals dz", len, dz.len())?;
        if dw.iter().chain(&dz).any(|v| !v.is_finite()) {
            return Err(Error::NonFinite { what: "Brownian increments".into() });
        }
        Ok(BrownianIncrements { dim, dt, n_steps, dw, dz })
    }

    /// Draws `n_steps` increments of a `dim`-dimensional standard Wiener process on a grid of
    /// step `dt`, jointly with the double integrals, by Kloeden & Platen 1992, (10.4.3):
    ///
    /// $$ \Delta W = U_1 \sqrt{\Delta}, \qquad
    ///    \Delta Z = \tfrac12 \Delta^{3/2} \left(U_1 + U_2/\sqrt3\right), $$
    ///
    /// with $U_1, U_2$ independent standard normals (drawn in the order U₁, U₂ per component
    /// per step), so that Var ΔZ = Δ³/3 and Cov(ΔW, ΔZ) = Δ²/2.
    ///
    /// Errors: [`Error::InvalidOption`] when `dt` is not positive and finite or `n_steps`
    /// exceeds [`MAX_STEPS`].
    pub fn sample<R: Rng + ?Sized>(dim: usize, dt: f64, n_steps: usize, rng: &mut R) -> Result<Self> {
        if !(dt.is_finite() && dt > 0.0) {
            return Err(invalid("dt", format!("must be positive and finite, got {dt}")));
        }
        if n_steps > MAX_STEPS {
            return Err(invalid("n_steps", format!("{n_steps} exceeds the limit of {MAX_STEPS}")));
        }
        let len = dim * n_steps;
        let (sq, c) = (dt.sqrt(), 0.5 * dt.powf(1.5));
        let inv_sqrt3 = 1.0 / 3f64.sqrt();
        let mut dw = Vec::with_capacity(len);
        let mut dz = Vec::with_capacity(len);
        for _ in 0..len {
            let u1: f64 = StandardNormal.sample(rng);
            let u2: f64 = StandardNormal.sample(rng);
            dw.push(u1 * sq);
            dz.push(c * (u1 + u2 * inv_sqrt3));
        }
        Ok(BrownianIncrements { dim, dt, n_steps, dw, dz })
    }

    /// Dimension of the Wiener process.
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// Step size Δ.
    pub fn dt(&self) -> f64 {
        self.dt
    }

    /// Number of steps.
    pub fn n_steps(&self) -> usize {
        self.n_steps
    }

    /// All increments ΔW, step-major (`n_steps × dim`).
    pub fn dw(&self) -> &[f64] {
        &self.dw
    }

    /// All double integrals ΔZ, step-major (`n_steps × dim`).
    pub fn dz(&self) -> &[f64] {
        &self.dz
    }

    /// The same Brownian path on a grid `factor` times coarser.
    ///
    /// A coarse step $[t_k, t_k + m\delta]$ is made of the fine steps
    /// $[s_j, s_j + \delta]$, $s_j = t_k + j\delta$, $j = 0, \dots, m-1$. The increment is
    /// $\Delta W = \sum_j \Delta W_j$, and splitting $W_s - W_{t_k} = (W_s - W_{s_j}) +
    /// (W_{s_j} - W_{t_k})$ on each fine step gives
    ///
    /// $$ \Delta Z = \sum_j \int_{s_j}^{s_j+\delta} (W_s - W_{t_k})\,ds
    ///    = \sum_j \left[\Delta Z_j + (W_{s_j} - W_{t_k})\,\delta\right], $$
    ///
    /// where $W_{s_j} - W_{t_k} = \sum_{i<j} \Delta W_i$ is the increment accumulated before
    /// fine step j. The result is exact: the coarse (ΔW, ΔZ) are those of the same path.
    ///
    /// Errors: [`Error::InvalidOption`] unless `factor ≥ 1` divides `n_steps`.
    pub fn coarsen(&self, factor: usize) -> Result<Self> {
        if factor == 0 || !self.n_steps.is_multiple_of(factor) {
            return Err(invalid(
                "factor",
                format!("must be a positive divisor of n_steps = {}, got {factor}", self.n_steps),
            ));
        }
        let (d, n) = (self.dim, self.n_steps / factor);
        let mut dw = vec![0.0; d * n];
        let mut dz = vec![0.0; d * n];
        for k in 0..n {
            for j in 0..factor {
                let fine = (k * factor + j) * d;
                for i in 0..d {
                    // dw[k*d + i] holds W_{s_j} − W_{t_k} before it is incremented.
                    dz[k * d + i] += self.dz[fine + i] + dw[k * d + i] * self.dt;
                    dw[k * d + i] += self.dw[fine + i];
                }
            }
        }
        Ok(BrownianIncrements { dim: d, dt: self.dt * factor as f64, n_steps: n, dw, dz })
    }
}

/// One-step integrator with its work buffers (allocated once per path).
struct Stepper<'a, S: ?Sized> {
    sde: &'a S,
    scheme: Scheme,
    /// Number of noisy states (= Wiener dimension).
    n: usize,
    /// G, `n × n`, column-major.
    g: Vec<f64>,
    theta: &'a [f64],
    theta_d1: Vec<Dual64>,
    theta_d2: Vec<Dual2_64>,
    a: Vec<f64>,
    s_d1: Vec<Dual64>,
    out_d1: Vec<Dual64>,
    s_d2: Vec<Dual2_64>,
    out_d2: Vec<Dual2_64>,
    /// L⁰a.
    l0: Vec<f64>,
    /// Σ_j (Lʲa) ΔZ_j.
    lz: Vec<f64>,
}

impl<'a, S: Sde + ?Sized> Stepper<'a, S> {
    fn new(sde: &'a S, theta: &'a [f64], g: Vec<f64>, scheme: Scheme) -> Self {
        let d = sde.dims();
        let m = d.states();
        Stepper {
            sde,
            scheme,
            n: d.noisy,
            g,
            theta,
            theta_d1: theta.iter().map(|&v| Dual64::from(v)).collect(),
            theta_d2: theta.iter().map(|&v| Dual2_64::from(v)).collect(),
            a: vec![0.0; m],
            s_d1: vec![Dual64::from(0.0); m],
            out_d1: vec![Dual64::from(0.0); m],
            s_d2: vec![Dual2_64::from(0.0); m],
            out_d2: vec![Dual2_64::from(0.0); m],
            l0: vec![0.0; m],
            lz: vec![0.0; m],
        }
    }

    /// Advances `s` from t to t + dt with increments `dw`, `dz` (length n).
    fn step(&mut self, t: f64, dt: f64, s: &mut [f64], dw: &[f64], dz: &[f64]) {
        self.sde.state_drift(t, s, self.theta, &mut self.a);
        match self.scheme {
            Scheme::EulerMaruyama => {
                for (i, si) in s.iter_mut().enumerate() {
                    *si += self.a[i] * dt + self.noise(i, dw);
                }
            }
            Scheme::ItoTaylor15 => {
                self.ito_taylor_terms(t, s, dz);
                let half_dt2 = 0.5 * dt * dt;
                for (i, si) in s.iter_mut().enumerate() {
                    *si += self.a[i] * dt + self.noise(i, dw) + self.lz[i] + self.l0[i] * half_dt2;
                }
            }
        }
    }

    /// (B ΔW)_i: Σ_j G_ij ΔW_j for a noisy state, 0 for a clean one.
    fn noise(&self, i: usize, dw: &[f64]) -> f64 {
        if i < self.n {
            dw.iter().enumerate().map(|(j, &w)| self.g[i + j * self.n] * w).sum()
        } else {
            0.0
        }
    }

    /// Fills `l0` with L⁰a and `lz` with Σ_j (Lʲa) ΔZ_j at (t, s), `a` already holding a(t, s).
    ///
    /// ∂_t a + (a·∇)a is one [`Dual64`] pass seeded along (1, a) in (t, s); for each noise
    /// column b_j = (G e_j, 0) one [`Dual2_64`] pass seeded along b_j gives Lʲa = (b_j·∇)a
    /// (first part) and (b_j·∇)²a (second part), and
    /// ½ Σ_{kl} (BBᵀ)_{kl} ∂²a/∂s_k∂s_l = ½ Σ_j (b_j·∇)²a. In all n + 2 evaluations of a.
    fn ito_taylor_terms(&mut self, t: f64, s: &[f64], dz: &[f64]) {
        let n = self.n;
        for ((sd, &si), &ai) in self.s_d1.iter_mut().zip(s).zip(&self.a) {
            *sd = Dual64::new(si, ai);
        }
        self.sde.state_drift(Dual64::new(t, 1.0), &self.s_d1, &self.theta_d1, &mut self.out_d1);
        for (l, o) in self.l0.iter_mut().zip(&self.out_d1) {
            *l = o.eps;
        }
        self.lz.iter_mut().for_each(|v| *v = 0.0);
        for (j, &dzj) in dz.iter().enumerate() {
            for (i, (sd, &si)) in self.s_d2.iter_mut().zip(s).enumerate() {
                let b = if i < n { self.g[i + j * n] } else { 0.0 };
                *sd = Dual2_64::new(si, b, 0.0);
            }
            self.sde.state_drift(Dual2_64::from(t), &self.s_d2, &self.theta_d2, &mut self.out_d2);
            for (i, o) in self.out_d2.iter().enumerate() {
                self.lz[i] += o.v1 * dzj;
                self.l0[i] += 0.5 * o.v2;
            }
        }
    }
}

/// Checks θ, x0, z0 against the model and returns G(θ) column-major.
fn check_model_inputs<S: Sde + ?Sized>(sde: &S, theta: &[f64], x0: &[f64], z0: &[f64]) -> Result<Vec<f64>> {
    let d = sde.dims();
    check_len("theta", d.params, theta.len())?;
    check_len("x0", d.noisy, x0.len())?;
    check_len("z0", d.clean, z0.len())?;
    for (what, v) in [("theta", theta), ("x0", x0), ("z0", z0)] {
        if v.iter().any(|u| !u.is_finite()) {
            return Err(Error::NonFinite { what: what.into() });
        }
    }
    Ok(sde.diffusion_matrix(theta)?.as_slice().to_vec())
}

/// Integrates the SDE from `(x0, z0)` at `t0` with the given Brownian increments and scheme;
/// the path has `noise.n_steps() + 1` rows at the times `t0 + k * noise.dt()`.
///
/// The update of each scheme is given at [`Scheme`]: Euler–Maruyama
/// (`000_74b95e149527c64e.txt (3.1)`) or the strong order 1.5 Itô–Taylor scheme for additive
/// noise (Kloeden & Platen 1992, (10.4.6)), whose derivatives ∂a/∂t, (a·∇)a, (b_j·∇)a and
/// (b_j·∇)²a come from the model by forward-mode automatic differentiation (n + 2 evaluations
/// of the drift per step for n noisy states). Euler–Maruyama ignores `noise.dz()`.
///
/// Errors: [`Error::DimensionMismatch`] for θ, x0, z0 or a noise dimension different from the
/// number of noisy states; [`Error::NonFinite`] for non-finite θ, x0, z0, or when the path
/// leaves the finite numbers (naming the time); [`Error::SingularDiffusion`] when G(θ) is
/// singular; [`Error::InvalidOption`] for a non-finite `t0`.
pub fn integrate<S: Sde + ?Sized>(
    sde: &S,
    theta: &[f64],
    x0: &[f64],
    z0: &[f64],
    t0: f64,
    scheme: Scheme,
    noise: &BrownianIncrements,
) -> Result<StatePath> {
    let g = check_model_inputs(sde, theta, x0, z0)?;
    let n = sde.dims().noisy;
    check_len("Brownian increments (dimension)", n, noise.dim())?;
    if !t0.is_finite() {
        return Err(invalid("t0", format!("must be finite, got {t0}")));
    }
    let dt = noise.dt();
    let steps = noise.n_steps();
    let mut stepper = Stepper::new(sde, theta, g, scheme);
    let mut s: Vec<f64> = x0.iter().chain(z0).copied().collect();
    let mut times = Vec::with_capacity(steps + 1);
    let mut values = Vec::with_capacity(steps + 1);
    times.push(t0);
    values.push(s.clone());
    for k in 0..steps {
        let t = t0 + k as f64 * dt;
        let inc = k * n..(k + 1) * n;
        stepper.step(t, dt, &mut s, &noise.dw()[inc.clone()], &noise.dz()[inc]);
        let t_next = t0 + (k + 1) as f64 * dt;
        if s.iter().any(|v| !v.is_finite()) {
            return Err(Error::NonFinite { what: format!("simulated path at t = {t_next}") });
        }
        times.push(t_next);
        values.push(s.clone());
    }
    Ok(StatePath { names: sde.state_names(), times, values, sd: None })
}

/// Simulates a path of the SDE from `(x0, z0)` on `[t0, t_end]` with step `dt` and the chosen
/// scheme (see [`Scheme`] and [`integrate`]), drawing the Brownian increments from `rng` with
/// [`BrownianIncrements::sample`]. Both schemes draw the same numbers, so with equal seeds
/// they are driven by the same Brownian path.
///
/// The path's names are `sde.state_names()`, its times `t0 + k * dt` for k = 0, …, N with
/// N = (t_end − t0)/dt, its rows the noisy then the clean states.
///
/// Errors: those of [`SimulateOptions::n_steps`] and of [`integrate`].
pub fn simulate<S: Sde + ?Sized, R: Rng + ?Sized>(
    sde: &S,
    theta: &[f64],
    x0: &[f64],
    z0: &[f64],
    options: &SimulateOptions,
    rng: &mut R,
) -> Result<StatePath> {
    let steps = options.n_steps()?;
    check_model_inputs(sde, theta, x0, z0)?;
    let noise = BrownianIncrements::sample(sde.dims().noisy, options.dt, steps, rng)?;
    integrate(sde, theta, x0, z0, options.t0, options.scheme, &noise)
}

/// Checks a path's shape and times and that it has at least `n_noisy` states.
fn check_path(path: &StatePath, n_noisy: usize) -> Result<()> {
    if path.times.is_empty() {
        return Err(invalid("path", "has no times".into()));
    }
    check_len("path rows", path.times.len(), path.values.len())?;
    for row in &path.values {
        check_len("path row", path.names.len(), row.len())?;
    }
    if n_noisy > path.names.len() {
        return Err(invalid(
            "n_noisy",
            format!("{n_noisy} exceeds the {} states of the path", path.names.len()),
        ));
    }
    for (i, &t) in path.times.iter().enumerate() {
        if !t.is_finite() || (i > 0 && t <= path.times[i - 1]) {
            return Err(invalid(
                "path",
                format!("times must be finite and strictly increasing (row {i}, t = {t})"),
            ));
        }
    }
    Ok(())
}

/// Draws measurements from `path` at the path times `t0, t0 + every, t0 + 2 every, …` up to the
/// last path time, with y ~ ψ(· | x(t), z(t), θ) by [`Observation::sample`]; the first
/// `n_noisy` columns of the path are x, the rest z. The dataset's times are
/// `t0 + i * every` and it has no missing values.
///
/// Errors: [`Error::InvalidOption`] when `every` is not positive and finite, when `every / dt`
/// (dt the path's first step) is not an integer within 10⁻⁹ relative, or for the reasons of
/// [`sample_measurements_at`]; the other errors of [`sample_measurements_at`].
pub fn sample_measurements<O: Observation + ?Sized, R: Rng + ?Sized>(
    obs: &O,
    theta: &[f64],
    path: &StatePath,
    n_noisy: usize,
    every: f64,
    rng: &mut R,
) -> Result<Dataset> {
    check_path(path, n_noisy)?;
    if !(every.is_finite() && every > 0.0) {
        return Err(invalid("every", format!("must be positive and finite, got {every}")));
    }
    let t0 = path.times[0];
    if path.times.len() >= 2 {
        integer_ratio(every, path.times[1] - path.times[0], "every", "every / dt")?;
    }
    let span = path.times[path.times.len() - 1] - t0;
    let count = (span / every * (1.0 + RATIO_TOL)).floor() as usize + 1;
    let times: Vec<f64> = (0..count).map(|i| t0 + i as f64 * every).collect();
    sample_measurements_at(obs, theta, path, n_noisy, &times, rng)
}

/// Draws measurements from `path` at the given `times`, each of which must be a path time
/// (within 10⁻⁶ of the path's smallest step, plus rounding), with y ~ ψ(· | x(t), z(t), θ) by
/// [`Observation::sample`]; the first `n_noisy` columns of the path are x, the rest z. The
/// dataset's times are `times`, its names `obs.output_names()`.
///
/// Errors: [`Error::InvalidOption`] when the path is empty or its times are not strictly
/// increasing, when `n_noisy` exceeds its number of states, or when `times` are not finite,
/// strictly increasing and on the path's grid; [`Error::DimensionMismatch`] for a ragged path;
/// [`Error::NonFinite`] for a non-finite θ, path row or sampled measurement.
pub fn sample_measurements_at<O: Observation + ?Sized, R: Rng + ?Sized>(
    obs: &O,
    theta: &[f64],
    path: &StatePath,
    n_noisy: usize,
    times: &[f64],
    rng: &mut R,
) -> Result<Dataset> {
    check_path(path, n_noisy)?;
    if theta.iter().any(|v| !v.is_finite()) {
        return Err(Error::NonFinite { what: "theta".into() });
    }
    let h_min = path.times.windows(2).map(|w| w[1] - w[0]).fold(f64::INFINITY, f64::min);
    let mut rows = Vec::with_capacity(times.len());
    for (i, &t) in times.iter().enumerate() {
        if !t.is_finite() || (i > 0 && t <= times[i - 1]) {
            return Err(invalid(
                "times",
                format!("must be finite and strictly increasing (index {i}, t = {t})"),
            ));
        }
        let tol = 8.0 * f64::EPSILON * t.abs() + if h_min.is_finite() { 1e-6 * h_min } else { 1e-12 };
        let k = path.times.partition_point(|&p| p < t - tol);
        if k == path.times.len() || (path.times[k] - t).abs() > tol {
            return Err(invalid("times", format!("t = {t} is not a time of the simulated path")));
        }
        rows.push(k);
    }
    let m = obs.output_dim();
    let mut values = Vec::with_capacity(times.len());
    for (&k, &t) in rows.iter().zip(times) {
        let row = &path.values[k];
        if row.iter().any(|v| !v.is_finite()) {
            return Err(Error::NonFinite { what: format!("path at t = {}", path.times[k]) });
        }
        let (x, z) = row.split_at(n_noisy);
        let mut y = vec![0.0; m];
        obs.sample(t, x, z, theta, rng, &mut y);
        if y.iter().any(|v| !v.is_finite()) {
            return Err(Error::NonFinite { what: format!("sampled measurement at t = {t}") });
        }
        values.push(y);
    }
    Dataset::try_new(obs.output_names(), times.to_vec(), values)
}

/// Draws a continuous-time record dY = s[states] dt + R^{1/2} dW of the states that `obs`
/// measures (`003_d2fc48a470e528fc.txt` (I.26), B the selection of `obs.states`) from `path`,
/// seen on cells of width `cell` starting at the path's first time: each value is the cell
/// average of the measured state (trapezoidal rule on the path's steps) plus an independent
/// N(0, R/Δ) error, the increment of R^{1/2} W over the cell divided by Δ; the times are the
/// cell midpoints ([`cell_midpoints`]), the names `obs.names`. `obs.noise` is not used.
///
/// Errors: [`Error::InvalidOption`] naming `every` when `cell` is not a positive integer
/// multiple of the path's step (within 10⁻⁹ relative) or when fewer than two cells fit in the
/// path's span, naming `R` when `intensity` is not positive and finite; those of
/// [`sample_measurements_at`] for the path and the measured states; [`Error::NonFinite`] for a
/// non-finite path value.
pub fn sample_record<R: Rng + ?Sized>(
    obs: &StateMeasurement,
    path: &StatePath,
    n_noisy: usize,
    cell: f64,
    intensity: f64,
    rng: &mut R,
) -> Result<ContinuousRecord> {
    check_path(path, n_noisy)?;
    if !(intensity.is_finite() && intensity > 0.0) {
        return Err(invalid("R", format!("the intensity must be positive and finite, got {intensity}")));
    }
    if let Some(&i) = obs.states.iter().find(|&&i| i >= path.names.len()) {
        return Err(invalid(
            "states",
            format!("state index {i} exceeds the path's {} states", path.names.len()),
        ));
    }
    if path.times.len() < 2 {
        return Err(invalid("path", "needs at least two times".into()));
    }
    let dt = path.times[1] - path.times[0];
    let m = integer_ratio(cell, dt, "every", "the cell width / dt")?;
    let t0 = path.times[0];
    let times = cell_midpoints(t0, path.times[path.times.len() - 1], cell);
    if times.len() < 2 {
        return Err(invalid(
            "every",
            format!("the cell width {cell} leaves fewer than two cells in the path's span"),
        ));
    }
    let sd = (intensity / cell).sqrt();
    let mut values = Vec::with_capacity(times.len());
    for (k, &mid) in times.iter().enumerate() {
        let (a, b) = (k * m, (k + 1) * m);
        let tol = 1e-6 * dt;
        if b >= path.times.len() || (path.times[b] - (t0 + (k + 1) as f64 * cell)).abs() > tol {
            return Err(invalid("path", format!("is not on a regular grid of step {dt} near cell {k}")));
        }
        let mut row = Vec::with_capacity(obs.states.len());
        for &i in &obs.states {
            let s = |j: usize| path.values[j][i];
            let sum: f64 =
                (a..b).map(|j| 0.5 * (s(j) + s(j + 1)) * (path.times[j + 1] - path.times[j])).sum();
            if !sum.is_finite() {
                return Err(Error::NonFinite { what: format!("path in the cell at t = {mid}") });
            }
            let e: f64 = StandardNormal.sample(rng);
            row.push(sum / cell + sd * e);
        }
        values.push(row);
    }
    let data = Dataset::try_new(obs.names.clone(), times, values)?;
    ContinuousRecord::try_new(intensity, data)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::library::Ou;
    use crate::model::Scalar;
    use crate::test_models::{CubicDampedDuffing, TwoNoisyOneClean, UnforcedDuffing, UnscaledDoubleWell};
    use approx::assert_relative_eq;
    use rand::rngs::StdRng;
    use rand::SeedableRng;

    /// Gaussian measurement of every state: y = s + r ε.
    struct AllStates {
        r: f64,
        names: Vec<String>,
    }
    impl Observation for AllStates {
        fn output_names(&self) -> Vec<String> {
            self.names.clone()
        }
        fn log_likelihood<D: Scalar>(&self, _t: f64, _y: &[f64], _x: &[D], _z: &[D], _th: &[D]) -> D {
            D::from(0.0)
        }
        fn sample<R: Rng + ?Sized>(
            &self,
            _t: f64,
            x: &[f64],
            z: &[f64],
            _th: &[f64],
            rng: &mut R,
            y: &mut [f64],
        ) {
            for (yi, &si) in y.iter_mut().zip(x.iter().chain(z)) {
                let e: f64 = StandardNormal.sample(rng);
                *yi = si + self.r * e;
            }
        }
    }

    #[test]
    fn scheme_names_round_trip() {
        for s in Scheme::ALL {
            assert_eq!(s.to_string().parse::<Scheme>().unwrap(), s);
            let json = serde_json::to_string(&s).unwrap();
            assert_eq!(json, format!("\"{}\"", s.name()));
        }
        assert_eq!("ito-taylor-1.5".parse::<Scheme>().unwrap(), Scheme::ItoTaylor15);
        let opts: SimulateOptions =
            serde_json::from_str(r#"{"scheme": "euler-maruyama", "dt": 0.1}"#).unwrap();
        assert_eq!(opts, SimulateOptions::new(0.0, 1.0, 0.1).with_scheme(Scheme::EulerMaruyama));
        assert!(serde_json::from_str::<SimulateOptions>(r#"{"step": 0.1}"#).is_err());
        match "milstein".parse::<Scheme>() {
            Err(Error::UnknownName { kind, known, .. }) => {
                assert_eq!(kind, "scheme");
                assert_eq!(known, vec!["euler-maruyama", "ito-taylor-1.5"]);
            }
            other => panic!("expected UnknownName, got {other:?}"),
        }
    }

    #[test]
    fn ito_taylor_step_matches_formula_from_jacobians() {
        // One step of (10.4.6) assembled by hand: ∂a/∂t, ∂a/∂s from Sde::drift_jacobians /
        // clean_drift_jacobians (AD), the directional second derivatives (b_j·∇)²a by central
        // differences of the Jacobian along b_j (error O(ε²) ≈ 1e-10, hence the tolerance).
        let sde = TwoNoisyOneClean;
        let theta = [0.7, 0.5, 0.4];
        let (x, z, t, dt) = ([0.3, -0.8], [1.1], 0.6, 0.05);
        let (dw, dz) = ([0.21, -0.13], [0.004, -0.002]);
        let g = [0.5, -0.2, 0.3, 0.4];
        let jac = |x: &[f64], z: &[f64]| {
            let f = sde.drift_jacobians(t, x, z, &theta);
            let h = sde.clean_drift_jacobians(t, x, z, &theta);
            let a: Vec<f64> = f.value.iter().chain(&h.value).copied().collect();
            let at: Vec<f64> = f.dt.iter().chain(&h.dt).copied().collect();
            // ∂a/∂s, 3 × 3, row i = output, column k = state.
            let j = [
                [f.dx[(0, 0)], f.dx[(0, 1)], f.dz[(0, 0)]],
                [f.dx[(1, 0)], f.dx[(1, 1)], f.dz[(1, 0)]],
                [h.dx[(0, 0)], h.dx[(0, 1)], h.dz[(0, 0)]],
            ];
            (a, at, j)
        };
        let (a, at, j) = jac(&x, &z);
        let mut expected = [x[0], x[1], z[0]];
        let eps = 1e-5;
        for i in 0..3 {
            let mut l0 = at[i] + (0..3).map(|k| a[k] * j[i][k]).sum::<f64>();
            let mut lz = 0.0;
            for col in 0..2 {
                let b = [g[2 * col], g[2 * col + 1]];
                let lj = j[i][0] * b[0] + j[i][1] * b[1];
                lz += lj * dz[col];
                let xp = [x[0] + eps * b[0], x[1] + eps * b[1]];
                let xm = [x[0] - eps * b[0], x[1] - eps * b[1]];
                let (_, _, jp) = jac(&xp, &z);
                let (_, _, jm) = jac(&xm, &z);
                let second = ((jp[i][0] - jm[i][0]) * b[0] + (jp[i][1] - jm[i][1]) * b[1]) / (2.0 * eps);
                l0 += 0.5 * second;
            }
            let noise = if i < 2 { g[i] * dw[0] + g[i + 2] * dw[1] } else { 0.0 };
            expected[i] += a[i] * dt + noise + lz + l0 * dt * dt / 2.0;
        }
        let noise = BrownianIncrements::try_new(2, dt, 1, dw.to_vec(), dz.to_vec()).unwrap();
        let path = integrate(&sde, &theta, &x, &z, t, Scheme::ItoTaylor15, &noise).unwrap();
        assert_eq!(path.times, vec![t, t + dt]);
        assert_eq!(path.names, vec!["x1", "x2", "z"]);
        for i in 0..3 {
            assert_relative_eq!(path.values[1][i], expected[i], epsilon = 1e-9, max_relative = 1e-9);
        }
        // Euler–Maruyama, (3.1) of 000_74b95e149527c64e.txt.
        let em = integrate(&sde, &theta, &x, &z, t, Scheme::EulerMaruyama, &noise).unwrap();
        let s0 = [x[0], x[1], z[0]];
        for i in 0..3 {
            let noise = if i < 2 { g[i] * dw[0] + g[i + 2] * dw[1] } else { 0.0 };
            assert_relative_eq!(
                em.values[1][i],
                s0[i] + a[i] * dt + noise,
                epsilon = 1e-14,
                max_relative = 1e-14
            );
        }
    }

    #[test]
    fn increments_have_the_joint_moments_of_kp_10_4_3() {
        // Kloeden & Platen (10.4.3): E ΔW² = Δ, E ΔZ² = Δ³/3, E ΔW ΔZ = Δ²/2. With 20000 draws
        // the relative Monte Carlo error of a second moment is ≈ √(2/20000) ≈ 1%; 5% is > 4 SE.
        let mut rng = StdRng::seed_from_u64(7);
        let dt = 0.1;
        let inc = BrownianIncrements::sample(2, dt, 10_000, &mut rng).unwrap();
        let m = inc.dw().len() as f64;
        let ww = inc.dw().iter().map(|w| w * w).sum::<f64>() / m;
        let zz = inc.dz().iter().map(|z| z * z).sum::<f64>() / m;
        let wz = inc.dw().iter().zip(inc.dz()).map(|(w, z)| w * z).sum::<f64>() / m;
        assert_relative_eq!(ww, dt, max_relative = 0.05);
        assert_relative_eq!(zz, dt.powi(3) / 3.0, max_relative = 0.05);
        assert_relative_eq!(wz, dt.powi(2) / 2.0, max_relative = 0.05);
    }

    #[test]
    fn coarsening_is_exact_on_a_piecewise_linear_brownian_path() {
        // A fine path whose W is linear on each fine step: ΔW_j = c_j δ, ΔZ_j = c_j δ²/2
        // (∫₀^δ c s ds). Coarsened by 2, the closed forms are ΔW = (c₀ + c₁)δ and
        // ΔZ = ∫₀^{2δ} (W_s − W_0) ds = c₀δ²/2 + (c₀δ)δ + c₁δ²/2.
        let (d, c) = (0.1, [3.0, -1.0, 0.5, 2.0]);
        let dw: Vec<f64> = c.iter().map(|ci| ci * d).collect();
        let dz: Vec<f64> = c.iter().map(|ci| ci * d * d / 2.0).collect();
        let fine = BrownianIncrements::try_new(1, d, 4, dw, dz).unwrap();
        let coarse = fine.coarsen(2).unwrap();
        assert_eq!(coarse.n_steps(), 2);
        assert_relative_eq!(coarse.dt(), 0.2, epsilon = 1e-15);
        for k in 0..2 {
            let (c0, c1) = (c[2 * k], c[2 * k + 1]);
            assert_relative_eq!(coarse.dw()[k], (c0 + c1) * d, epsilon = 1e-15);
            let z = c0 * d * d / 2.0 + c0 * d * d + c1 * d * d / 2.0;
            assert_relative_eq!(coarse.dz()[k], z, epsilon = 1e-15);
        }
        // Coarsening by 2 twice equals coarsening by 4 (up to rounding).
        let twice = coarse.coarsen(2).unwrap();
        let once = fine.coarsen(4).unwrap();
        assert_relative_eq!(twice.dw()[0], once.dw()[0], epsilon = 1e-15);
        assert_relative_eq!(twice.dz()[0], once.dz()[0], epsilon = 1e-15);
        assert!(matches!(fine.coarsen(3), Err(Error::InvalidOption { .. })));
        assert!(matches!(fine.coarsen(0), Err(Error::InvalidOption { .. })));
    }

    /// Step sizes h = 2^-L of the strong-order tests, on [0, 1].
    const LEVELS: [u32; 6] = [2, 3, 4, 5, 6, 7];
    /// The reference step 2^-12: its IT1.5 error (≈ C 2^-18) is far below the coarse errors.
    const REF_LEVEL: u32 = 12;
    /// Number of Brownian paths of the strong-order tests.
    const PATHS: usize = 300;

    /// Mean over `PATHS` of |s_T^h − s_T^ref| (Euclidean) at T = 1, for each level L in
    /// `LEVELS` (h = 2^-L) and both schemes, the reference being the Itô–Taylor 1.5 solution
    /// with step 2^-REF_LEVEL driven by the same Brownian path (coarse increments by
    /// `BrownianIncrements::coarsen`). Returns (errors of EM, errors of IT1.5).
    fn strong_errors<S: Sde>(
        sde: &S,
        theta: &[f64],
        x0: &[f64],
        z0: &[f64],
        seed: u64,
    ) -> (Vec<f64>, Vec<f64>) {
        let (levels, ref_level, paths) = (LEVELS, REF_LEVEL, PATHS);
        let mut rng = StdRng::seed_from_u64(seed);
        let n = sde.dims().noisy;
        let fine_dt = 2f64.powi(-(ref_level as i32));
        let (mut em, mut it) = (vec![0.0; levels.len()], vec![0.0; levels.len()]);
        for _ in 0..paths {
            let noise = BrownianIncrements::sample(n, fine_dt, 1 << ref_level, &mut rng).unwrap();
            let reference = integrate(sde, theta, x0, z0, 0.0, Scheme::ItoTaylor15, &noise).unwrap();
            let s_ref = reference.values.last().unwrap();
            for (l, &level) in levels.iter().enumerate() {
                let coarse = noise.coarsen(1 << (ref_level - level)).unwrap();
                for (scheme, acc) in [(Scheme::EulerMaruyama, &mut em), (Scheme::ItoTaylor15, &mut it)] {
                    let p = integrate(sde, theta, x0, z0, 0.0, scheme, &coarse).unwrap();
                    let s = p.values.last().unwrap();
                    let e2: f64 = s.iter().zip(s_ref).map(|(a, b)| (a - b).powi(2)).sum();
                    acc[l] += e2.sqrt() / paths as f64;
                }
            }
        }
        (em, it)
    }

    /// Least-squares slope of ln(err) against ln(h).
    fn loglog_slope(levels: &[u32], err: &[f64]) -> f64 {
        let xs: Vec<f64> = levels.iter().map(|&l| -(l as f64) * 2f64.ln()).collect();
        let ys: Vec<f64> = err.iter().map(|e| e.ln()).collect();
        let n = xs.len() as f64;
        let (mx, my) = (xs.iter().sum::<f64>() / n, ys.iter().sum::<f64>() / n);
        let sxy: f64 = xs.iter().zip(&ys).map(|(x, y)| (x - mx) * (y - my)).sum();
        let sxx: f64 = xs.iter().map(|x| (x - mx).powi(2)).sum();
        sxy / sxx
    }

    /// Checks the fitted strong orders: 1 for Euler–Maruyama with additive noise (Kloeden &
    /// Platen 1992, Sec. 10.2) and `it_order` for the Itô–Taylor scheme (10.4.6), each ± 0.2.
    /// Returns the slopes (EM, IT1.5).
    fn check_strong_orders<S: Sde>(
        sde: &S,
        theta: &[f64],
        x0: &[f64],
        z0: &[f64],
        it_order: f64,
        seed: u64,
    ) -> (f64, f64) {
        let levels = LEVELS;
        let (em, it) = strong_errors(sde, theta, x0, z0, seed);
        let (s_em, s_it) = (loglog_slope(&levels, &em), loglog_slope(&levels, &it));
        let msg = format!("slopes EM {s_em:.3}, IT1.5 {s_it:.3}; errors EM {em:?}, IT1.5 {it:?}");
        assert!((s_em - 1.0).abs() < 0.2, "{msg}");
        assert!((s_it - it_order).abs() < 0.2, "{msg}");
        // At every step size the higher-order scheme is the more accurate one.
        assert!(em.iter().zip(&it).all(|(e, i)| i < e), "{msg}");
        (s_em, s_it)
    }

    #[test]
    fn strong_orders_on_double_well() {
        // Strong order 1.5 (Kloeden & Platen 1992, Sec. 10.4).
        check_strong_orders(&UnscaledDoubleWell, &[0.5], &[0.2], &[], 1.5, 11);
    }

    #[test]
    fn strong_orders_with_a_clean_state() {
        // Strong order 1.5 (Kloeden & Platen 1992, Sec. 10.4), with a clean state.
        check_strong_orders(&CubicDampedDuffing, &[1.0], &[0.0], &[1.0], 1.5, 12);
    }

    #[test]
    fn strong_order_two_when_the_drift_is_linear_in_the_noisy_state() {
        // For additive noise the only term of the strong order 2.0 Itô–Taylor scheme
        // (Kloeden & Platen 1992, Sec. 10.5; hierarchical set l(α) + n(α) ≤ 4) missing from
        // (10.4.6) is (L¹L¹a) I_(1,1,0). The Duffing drift is linear in the noisy state, so
        // L¹a = σ ∂a/∂v = (−0.2σ, σ) is constant, L¹L¹a = 0, and the scheme has strong order 2.
        check_strong_orders(&UnforcedDuffing, &[0.3], &[0.0], &[1.0], 2.0, 13);
    }

    #[test]
    fn weak_moments_of_ornstein_uhlenbeck() {
        // Closed form for dX = −θX dt + σ dW, X_0 = x0: E X_1 = x0 e^{−θ},
        // Var X_1 = σ²/(2θ) (1 − e^{−2θ}). Tolerance: 4 Monte Carlo standard errors, s/√n for the
        // mean and √((m₄ − s⁴)/n) (fourth-moment based) for the variance. The discretization
        // bias at Δ = 0.01 (EM mean: x0 (1 − θΔ)^100 vs x0 e^{−θ}, a difference of 1.8e-3) is
        // well below these (4 SE ≈ 0.021 and ≈ 0.010), as is the EM variance bias
        // (σ²Δ (1 − (1 − θΔ)^200) / (2θΔ − θ²Δ²) − Var X_1 ≈ 7e-4).
        let (th, sigma, x0): (f64, f64, f64) = (1.0, 0.5, 1.0);
        let mean = x0 * (-th).exp();
        let var = sigma * sigma / (2.0 * th) * (1.0 - (-2.0 * th).exp());
        let n = 4000;
        for (seed, scheme) in [(21, Scheme::EulerMaruyama), (22, Scheme::ItoTaylor15)] {
            let mut rng = StdRng::seed_from_u64(seed);
            let opts = SimulateOptions::new(0.0, 1.0, 0.01).with_scheme(scheme);
            let xs: Vec<f64> = (0..n)
                .map(|_| {
                    let p = simulate(&Ou, &[th, sigma], &[x0], &[], &opts, &mut rng).unwrap();
                    assert_eq!(p.times.len(), 101);
                    p.values[100][0]
                })
                .collect();
            let nf = n as f64;
            let m = xs.iter().sum::<f64>() / nf;
            let v = xs.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (nf - 1.0);
            let m4 = xs.iter().map(|x| (x - m).powi(4)).sum::<f64>() / nf;
            let (se_m, se_v) = ((v / nf).sqrt(), ((m4 - v * v) / nf).sqrt());
            let msg = format!(
                "{scheme}: mean {m:.5} vs {mean:.5} (SE {se_m:.2e}), var {v:.5} vs {var:.5} (SE {se_v:.2e})"
            );
            assert!((m - mean).abs() < 4.0 * se_m, "{msg}");
            assert!((v - var).abs() < 4.0 * se_v, "{msg}");
        }
    }

    #[test]
    fn simulate_is_reproducible_and_on_the_stated_grid() {
        let opts = SimulateOptions::new(0.5, 1.5, 0.1);
        let a =
            simulate(&UnforcedDuffing, &[0.3], &[0.1], &[1.0], &opts, &mut StdRng::seed_from_u64(3)).unwrap();
        let b =
            simulate(&UnforcedDuffing, &[0.3], &[0.1], &[1.0], &opts, &mut StdRng::seed_from_u64(3)).unwrap();
        assert_eq!(a, b);
        assert_eq!(a.names, vec!["v", "q"]);
        assert_eq!(a.times.len(), 11);
        for (k, &t) in a.times.iter().enumerate() {
            assert_eq!(t, 0.5 + k as f64 * 0.1);
        }
        assert_eq!(a.values[0], vec![0.1, 1.0]);
        assert!(a.sd.is_none());
    }

    #[test]
    fn bad_inputs_are_errors() {
        let mut rng = StdRng::seed_from_u64(1);
        let ok = SimulateOptions::new(0.0, 1.0, 0.1);
        let run = |opts: &SimulateOptions, theta: &[f64], x0: &[f64], rng: &mut StdRng| {
            simulate(&Ou, theta, x0, &[], opts, rng)
        };
        let invalid_name = |r: Result<StatePath>| match r {
            Err(Error::InvalidOption { name, .. }) => name,
            other => panic!("expected InvalidOption, got {other:?}"),
        };
        assert_eq!(
            invalid_name(run(&SimulateOptions::new(0.0, 1.0, 0.0), &[1.0, 1.0], &[0.0], &mut rng)),
            "dt"
        );
        assert_eq!(
            invalid_name(run(&SimulateOptions::new(0.0, 1.0, -0.1), &[1.0, 1.0], &[0.0], &mut rng)),
            "dt"
        );
        assert_eq!(
            invalid_name(run(&SimulateOptions::new(0.0, 1.0, f64::NAN), &[1.0, 1.0], &[0.0], &mut rng)),
            "dt"
        );
        assert_eq!(
            invalid_name(run(&SimulateOptions::new(0.0, 1.0, 0.3), &[1.0, 1.0], &[0.0], &mut rng)),
            "dt"
        );
        assert_eq!(
            invalid_name(run(&SimulateOptions::new(0.0, 1.0, 1e-12), &[1.0, 1.0], &[0.0], &mut rng)),
            "dt"
        );
        assert_eq!(
            invalid_name(run(&SimulateOptions::new(1.0, 1.0, 0.1), &[1.0, 1.0], &[0.0], &mut rng)),
            "t_end"
        );
        assert_eq!(
            invalid_name(run(&SimulateOptions::new(f64::NAN, 1.0, 0.1), &[1.0, 1.0], &[0.0], &mut rng)),
            "t0"
        );
        // 1/3 steps of 1/3 are an integer within rounding.
        assert_eq!(SimulateOptions::new(0.0, 1.0, 1.0 / 3.0).n_steps().unwrap(), 3);
        match run(&ok, &[1.0, 1.0], &[0.0, 0.0], &mut rng) {
            Err(Error::DimensionMismatch { what, expected: 1, got: 2 }) => assert_eq!(what, "x0"),
            other => panic!("expected DimensionMismatch, got {other:?}"),
        }
        match run(&ok, &[1.0], &[0.0], &mut rng) {
            Err(Error::DimensionMismatch { what, expected: 2, got: 1 }) => assert_eq!(what, "theta"),
            other => panic!("expected DimensionMismatch, got {other:?}"),
        }
        assert!(matches!(run(&ok, &[1.0, f64::NAN], &[0.0], &mut rng), Err(Error::NonFinite { .. })));
        assert!(matches!(run(&ok, &[1.0, 1.0], &[f64::INFINITY], &mut rng), Err(Error::NonFinite { .. })));
        assert!(matches!(run(&ok, &[1.0, 0.0], &[0.0], &mut rng), Err(Error::SingularDiffusion { .. })));
        // A path that blows up: dX = −θX dt with θΔ = 30 multiplies X by −29 each step.
        match simulate(&Ou, &[300.0, 1.0], &[1.0], &[], &SimulateOptions::new(0.0, 100.0, 0.1), &mut rng) {
            Err(Error::NonFinite { what }) => assert!(what.starts_with("simulated path at t = "), "{what}"),
            other => panic!("expected NonFinite, got {other:?}"),
        }
        let noise = BrownianIncrements::sample(2, 0.1, 3, &mut rng).unwrap();
        assert!(matches!(
            integrate(&Ou, &[1.0, 1.0], &[0.0], &[], 0.0, Scheme::EulerMaruyama, &noise),
            Err(Error::DimensionMismatch { .. })
        ));
        assert!(matches!(
            BrownianIncrements::try_new(1, 0.1, 2, vec![0.0; 2], vec![0.0; 3]),
            Err(Error::DimensionMismatch { .. })
        ));
    }

    #[test]
    fn sample_measurements_on_the_grid() {
        let opts = SimulateOptions::new(0.0, 1.0, 0.01);
        let path =
            simulate(&UnforcedDuffing, &[0.3], &[0.1], &[1.0], &opts, &mut StdRng::seed_from_u64(5)).unwrap();
        let obs = AllStates { r: 0.1, names: vec!["yv".into(), "yq".into()] };
        let d1 = sample_measurements(&obs, &[0.3], &path, 1, 0.1, &mut StdRng::seed_from_u64(9)).unwrap();
        let d2 = sample_measurements(&obs, &[0.3], &path, 1, 0.1, &mut StdRng::seed_from_u64(9)).unwrap();
        assert_eq!(d1, d2);
        assert_eq!(d1.names, vec!["yv", "yq"]);
        assert_eq!(d1.times.len(), 11);
        for (i, &t) in d1.times.iter().enumerate() {
            assert_relative_eq!(t, 0.1 * i as f64, epsilon = 1e-12);
        }
        assert!(d1.values.iter().flatten().all(|v| v.is_finite()));
        // With r = 0 the measurements are the path's states at rows 0, 10, 20, …
        let exact = AllStates { r: 0.0, names: obs.names.clone() };
        let d0 = sample_measurements(&exact, &[0.3], &path, 1, 0.1, &mut StdRng::seed_from_u64(9)).unwrap();
        for (i, row) in d0.values.iter().enumerate() {
            assert_eq!(row, &path.values[10 * i]);
        }
        let at = sample_measurements_at(
            &exact,
            &[0.3],
            &path,
            1,
            &[0.05, 0.3, 0.99],
            &mut StdRng::seed_from_u64(9),
        )
        .unwrap();
        assert_eq!(at.times, vec![0.05, 0.3, 0.99]);
        assert_eq!(at.values[1], path.values[30]);
        assert_eq!(at.values[2], path.values[99]);
        let mut rng = StdRng::seed_from_u64(9);
        let name = |r: Result<Dataset>| match r {
            Err(Error::InvalidOption { name, .. }) => name,
            other => panic!("expected InvalidOption, got {other:?}"),
        };
        assert_eq!(name(sample_measurements(&obs, &[0.3], &path, 1, 0.015, &mut rng)), "every");
        assert_eq!(name(sample_measurements(&obs, &[0.3], &path, 1, 0.0, &mut rng)), "every");
        assert_eq!(name(sample_measurements(&obs, &[0.3], &path, 3, 0.1, &mut rng)), "n_noisy");
        assert_eq!(name(sample_measurements_at(&obs, &[0.3], &path, 1, &[0.105], &mut rng)), "times");
        assert_eq!(name(sample_measurements_at(&obs, &[0.3], &path, 1, &[0.2, 0.1], &mut rng)), "times");
        assert_eq!(name(sample_measurements_at(&obs, &[0.3], &path, 1, &[1.01], &mut rng)), "times");
    }

    #[test]
    fn sample_record_is_the_cell_average_plus_noise_of_variance_r_over_delta() {
        // A path x(t) = t², z = 1 on [0, 200] with step 0.01; cells of 0.1, R = 0.04.
        let times: Vec<f64> = (0..=20_000).map(|i| i as f64 * 0.01).collect();
        let path = StatePath {
            names: vec!["x".into(), "z".into()],
            values: times.iter().map(|&t| vec![t * t, 1.0]).collect(),
            times,
            sd: None,
        };
        let obs = StateMeasurement::new(
            vec![0],
            vec!["y".into()],
            crate::model::observation::Noise::Gaussian { sigma: crate::model::Param::Fixed(1.0) },
        );
        let (cell, r) = (0.1, 0.04);
        let rec = sample_record(&obs, &path, 1, cell, r, &mut StdRng::seed_from_u64(3)).unwrap();
        assert_eq!(rec.data.len(), 2000);
        assert_relative_eq!(rec.data.times[0], 0.05, epsilon = 1e-12);
        assert_relative_eq!(rec.cell(), cell, epsilon = 1e-12);
        assert_eq!(rec.intensity, r);
        // The trapezoidal cell average of t² on [a, a + Δ] with 10 steps of h:
        // a² + aΔ + Δ²/3 + h²Δ/(6Δ)·… = (exact average) + h²/6.
        let residuals: Vec<f64> = rec
            .data
            .times
            .iter()
            .zip(&rec.data.values)
            .map(|(&t, v)| {
                let a = t - cell / 2.0;
                v[0] - (a * a + a * cell + cell * cell / 3.0 + 0.01 * 0.01 / 6.0)
            })
            .collect();
        let n = residuals.len() as f64;
        let mean = residuals.iter().sum::<f64>() / n;
        let var = residuals.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / (n - 1.0);
        // Standard errors: mean √(0.4/2000) = 0.014, variance 0.4·√(2/2000) = 0.013.
        assert!(mean.abs() < 0.05, "mean {mean}");
        assert!((var - r / cell).abs() < 0.05, "variance {var} vs R/Δ = {}", r / cell);
        let name = |res: Result<ContinuousRecord>| match res {
            Err(Error::InvalidOption { name, .. }) => name,
            other => panic!("expected InvalidOption, got {other:?}"),
        };
        let mut rng = StdRng::seed_from_u64(1);
        assert_eq!(name(sample_record(&obs, &path, 1, 0.015, r, &mut rng)), "every");
        assert_eq!(name(sample_record(&obs, &path, 1, 150.0, r, &mut rng)), "every");
        assert_eq!(name(sample_record(&obs, &path, 1, cell, 0.0, &mut rng)), "R");
    }
}
