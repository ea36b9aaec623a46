//! Built-in models and the registry of presets the CLI and the examples use.
//!
//! Each model is a unit struct implementing [`Sde`], written once and generic over the scalar,
//! with θ passed in (so every derivative comes by automatic differentiation). The registry
//! ([`preset`], [`NAMES`]) bundles a model with its nominal θ, priors, measurement model and
//! simulation settings, each default documented with its source. See `docs/models.md` for the
//! equations and the conventions.
//!
//! | name | model | source |
//! |---|---|---|
//! | `ou` | [`Ou`] | closed-form reference (our defaults) |
//! | `tanh` | [`Tanh`] | `001_8aefdf0570c96f51.txt` Sec. 2 |
//! | `van-der-pol` | [`VanDerPol`] | `001_8aefdf0570c96f51.txt` Sec. 9 |
//! | `duffing` | [`Duffing`] | `000_74b95e149527c64e.txt` Sec. 4.1.1, (4.2), Table 4.1 |
//! | `holmes-rand` | [`HolmesRand`] | `000_74b95e149527c64e.txt` Sec. 4.1.3, (4.8), Table 4.3 |
//! | `double-well` | [`DoubleWell`] | `003_d2fc48a470e528fc.txt (0.1)` notation (our defaults) |
//! | `double-well-2d` | [`DoubleWell2d`] | `003_d2fc48a470e528fc.txt (0.1)` notation, two states (our defaults) |
//! | `lorenz63` | [`Lorenz63`] | Lorenz (1963) drift (our noise defaults) |
//! | `lorenz96` | [`Lorenz96`] | Lorenz (1996) drift, 10 states (our noise defaults) |

mod double_well;
mod double_well_2d;
mod duffing;
mod flight_oem;
mod flight_path;
mod holmes_rand;
mod lorenz63;
mod lorenz96;
mod ou;
mod tanh;
mod van_der_pol;

#[cfg(test)]
mod tests;

pub use double_well::DoubleWell;
pub use double_well_2d::DoubleWell2d;
pub use duffing::Duffing;
pub use flight_oem::{output_error, OemEstimate, OemOptions, OEM_INPUTS, OEM_OUTPUTS, OEM_STATES};
pub use flight_path::{
    integrated_noise_intensity, noise_sd, read_flight_record, read_flight_record_from, rigid_body_kinematics,
    state as flight_state, FlightColumns, FlightPath, FlightPathObservation, FlightPathSetup, Inertia,
    MomentCoefficients, OutputResiduals, Position, RecordLevels, SensorSd, Unit, ROUGHNESS_LAG,
};
pub use holmes_rand::HolmesRand;
pub use lorenz63::Lorenz63;
pub use lorenz96::Lorenz96;
pub use ou::Ou;
pub use tanh::Tanh;
pub use van_der_pol::VanDerPol;

use super::observation::{Noise, StateMeasurement};
use super::prior::Prior;
use std::sync::Arc;

use super::expression::ExpressionModel;
use super::{check_len, Dims, DriftDerivatives, Param, Scalar, Sde};
use crate::data::{Dataset, StatePath};
use crate::estimate::EstimationProblem;
use crate::{Error, Result};

/// Owned names from string literals.
fn names(list: &[&str]) -> Vec<String> {
    list.iter().map(|s| s.to_string()).collect()
}

/// The names [`preset`] accepts, in the order of the table in the module documentation.
pub const NAMES: &[&str] = &[
    "ou",
    "tanh",
    "van-der-pol",
    "duffing",
    "holmes-rand",
    "double-well",
    "double-well-2d",
    "lorenz63",
    "lorenz96",
];

/// A model chosen at run time: one of the built-in models, or a model read from a file
/// ([`ExpressionModel`], [`Preset::from_path`]). Implements [`Sde`] by delegating to the model
/// it holds.
#[derive(Debug, Clone, PartialEq)]
pub enum Model {
    /// [`Ou`], `ou`.
    Ou(Ou),
    /// [`Tanh`], `tanh`.
    Tanh(Tanh),
    /// [`VanDerPol`], `van-der-pol`.
    VanDerPol(VanDerPol),
    /// [`Duffing`], `duffing`.
    Duffing(Duffing),
    /// [`HolmesRand`], `holmes-rand`.
    HolmesRand(HolmesRand),
    /// [`DoubleWell`], `double-well`.
    DoubleWell(DoubleWell),
    /// [`DoubleWell2d`], `double-well-2d`.
    DoubleWell2d(DoubleWell2d),
    /// [`Lorenz63`], `lorenz63`.
    Lorenz63(Lorenz63),
    /// [`Lorenz96`], `lorenz96`.
    Lorenz96(Lorenz96),
    /// A model given by expressions, read from a model file.
    Expression(Arc<ExpressionModel>),
}

/// Runs `$body` with `$m` bound to the model inside a [`Model`].
macro_rules! delegate {
    ($self:expr, $m:ident => $body:expr) => {
        match $self {
            Model::Ou($m) => $body,
            Model::Tanh($m) => $body,
            Model::VanDerPol($m) => $body,
            Model::Duffing($m) => $body,
            Model::HolmesRand($m) => $body,
            Model::DoubleWell($m) => $body,
            Model::DoubleWell2d($m) => $body,
            Model::Lorenz63($m) => $body,
            Model::Lorenz96($m) => $body,
            Model::Expression($m) => $body,
        }
    };
}

impl Model {
    /// The model's registry name (one of [`NAMES`]), `None` for a model from a file.
    pub fn builtin_name(&self) -> Option<&'static str> {
        Some(match self {
            Model::Ou(_) => "ou",
            Model::Tanh(_) => "tanh",
            Model::VanDerPol(_) => "van-der-pol",
            Model::Duffing(_) => "duffing",
            Model::HolmesRand(_) => "holmes-rand",
            Model::DoubleWell(_) => "double-well",
            Model::DoubleWell2d(_) => "double-well-2d",
            Model::Lorenz63(_) => "lorenz63",
            Model::Lorenz96(_) => "lorenz96",
            Model::Expression(_) => return None,
        })
    }
}

impl Sde for Model {
    fn dims(&self) -> Dims {
        delegate!(self, m => m.dims())
    }

    fn noisy_names(&self) -> Vec<String> {
        delegate!(self, m => m.noisy_names())
    }

    fn clean_names(&self) -> Vec<String> {
        delegate!(self, m => m.clean_names())
    }

    fn param_names(&self) -> Vec<String> {
        delegate!(self, m => m.param_names())
    }

    fn drift<D: Scalar>(&self, t: D, x: &[D], z: &[D], theta: &[D], out: &mut [D]) {
        delegate!(self, m => m.drift(t, x, z, theta, out))
    }

    fn clean_drift<D: Scalar>(&self, t: D, x: &[D], z: &[D], theta: &[D], out: &mut [D]) {
        delegate!(self, m => m.clean_drift(t, x, z, theta, out))
    }

    fn diffusion<D: Scalar>(&self, theta: &[D], out: &mut [D]) {
        delegate!(self, m => m.diffusion(theta, out))
    }

    fn drift_uses_param(&self, i: usize) -> bool {
        delegate!(self, m => m.drift_uses_param(i))
    }

    fn divergence<D: Scalar>(&self, t: D, x: &[D], z: &[D], theta: &[D]) -> D {
        delegate!(self, m => m.divergence(t, x, z, theta))
    }

    fn drift_derivatives(
        &self,
        t: f64,
        x: &[f64],
        z: &[f64],
        theta: &[f64],
        out: &mut DriftDerivatives,
    ) -> bool {
        delegate!(self, m => m.drift_derivatives(t, x, z, theta, out))
    }

    fn drift_polynomial_degree(&self) -> Option<usize> {
        delegate!(self, m => m.drift_polynomial_degree())
    }

    fn drift_is_autonomous(&self) -> bool {
        delegate!(self, m => m.drift_is_autonomous())
    }
}

/// A built-in model with everything needed to simulate it and to estimate its states and
/// parameters: nominal θ, priors, measurement model, horizon and sampling. Every default is
/// documented with its source in [`preset`] and `docs/models.md`.
///
/// Measurement times are `first_sample + k · sample_every` for k = 0, 1, … while ≤ `t_end`
/// (up to rounding); the state path starts at t = 0.
#[derive(Debug, Clone)]
pub struct Preset {
    /// Registry name (one of [`NAMES`]), or the name a model file declares.
    pub name: String,
    /// One-line description.
    pub description: String,
    /// Where the model and its defaults come from (paper file and section/equation/table).
    pub source: String,
    /// The dynamics.
    pub model: Model,
    /// Nominal parameter vector θ (dynamics and measurement parameters), in the order of
    /// [`Sde::param_names`].
    pub theta: Vec<f64>,
    /// Prior of each component of θ (same length as `theta`). Parameters the source treats as
    /// known have flat priors and `estimate = false`.
    pub theta_prior: Vec<Prior>,
    /// Whether the source estimates each component of θ (the default set of estimated
    /// parameters; same length as `theta`).
    pub estimate: Vec<bool>,
    /// Prior of each noisy initial state x(0) (length `dims().noisy`); also the distribution
    /// initial states are simulated from.
    pub x0_prior: Vec<Prior>,
    /// Prior of each clean initial state z(0) (length `dims().clean`).
    pub z0_prior: Vec<Prior>,
    /// The measurement model; its state indices refer to s = [x; z].
    pub observation: StateMeasurement,
    /// Final time of the experiment (the path starts at t = 0).
    pub t_end: f64,
    /// Simulation time step (of the SDE integrator, not of the estimators' grids).
    pub dt: f64,
    /// Time of the first measurement.
    pub first_sample: f64,
    /// Time between measurements.
    pub sample_every: f64,
}

/// The most measurement times a preset or an experiment may ask for (`sample_every`,
/// `measurements.every`): checked before the times are allocated.
pub const MAX_MEASUREMENT_TIMES: usize = 10_000_000;

impl Preset {
    /// For a bistable model, the barrier between the wells of its first state (0 for the double
    /// well, whose drift 4x − 4x³ has stable points ±1); `None` otherwise.
    pub fn well_barrier(&self) -> Option<f64> {
        (self.name == "double-well" || self.name == "double-well-2d").then_some(0.0)
    }

    /// The model's dimensions.
    pub fn dims(&self) -> Dims {
        self.model.dims()
    }

    /// Names of the parameters θ, in order.
    pub fn param_names(&self) -> Vec<String> {
        self.model.param_names()
    }

    /// Index of the parameter called `name` in θ; [`Error::UnknownName`] (kind
    /// `"parameter"`) when the model has no such parameter.
    pub fn param_index(&self, name: &str) -> Result<usize> {
        let known = self.param_names();
        known.iter().position(|p| p == name).ok_or_else(|| Error::UnknownName {
            kind: "parameter".into(),
            name: name.into(),
            known,
        })
    }

    /// Sets the nominal value of the parameter called `name`. Errors: [`Error::UnknownName`]
    /// for an unknown parameter, [`Error::NonFinite`] for a NaN or infinite value.
    pub fn set_param(&mut self, name: &str, value: f64) -> Result<()> {
        let i = self.param_index(name)?;
        if !value.is_finite() {
            return Err(Error::NonFinite { what: format!("value of parameter `{name}`") });
        }
        self.theta[i] = value;
        Ok(())
    }

    /// The measurement times `first_sample + k · sample_every`, k = 0, 1, …, up to `t_end`
    /// (a time within 10⁻⁹ · `sample_every` of `t_end` counts as reaching it, so that rounding
    /// does not drop the last measurement). Computed as products, not by accumulation, so the
    /// times are exact multiples up to one rounding. Empty when the settings are invalid
    /// (see [`Preset::validate`]).
    pub fn measurement_times(&self) -> Vec<f64> {
        let (t0, h, t1) = (self.first_sample, self.sample_every, self.t_end);
        if !(t0.is_finite() && h.is_finite() && t1.is_finite() && h > 0.0 && t0 <= t1) {
            return Vec::new();
        }
        let n = ((t1 - t0) / h + 1e-9).floor() as usize;
        (0..=n).map(|k| t0 + k as f64 * h).collect()
    }

    /// The estimation problem of this preset's model, measurement model, θ and priors on
    /// `data`, estimating the θ components `estimate`, with the initial time
    /// [`default_initial_time`](crate::estimate::default_initial_time) and seed 0.
    pub fn problem<'a>(
        &'a self,
        data: &'a Dataset,
        estimate: &'a [usize],
    ) -> EstimationProblem<'a, Model, StateMeasurement> {
        EstimationProblem {
            sde: &self.model,
            observation: &self.observation,
            theta: &self.theta,
            theta_prior: &self.theta_prior,
            estimate,
            x0_prior: &self.x0_prior,
            z0_prior: &self.z0_prior,
            data,
            t0: crate::estimate::default_initial_time(data),
            seed: 0,
            max_memory: Default::default(),
        }
    }

    /// Checks the preset after user changes: lengths of θ, priors and flags against the
    /// model's dimensions ([`Error::DimensionMismatch`]), finite θ ([`Error::NonFinite`]),
    /// every prior ([`Prior::validate`]), the measurement model
    /// ([`StateMeasurement::validate`]), G(θ) finite and invertible
    /// ([`Error::SingularDiffusion`]), and the time settings: `t_end`, `dt`, `sample_every`
    /// positive and finite, `first_sample` in [0, `t_end`] ([`Error::InvalidOption`]).
    pub fn validate(&self) -> Result<()> {
        let d = self.dims();
        check_len("theta", d.params, self.theta.len())?;
        check_len("theta priors", d.params, self.theta_prior.len())?;
        check_len("estimate flags", d.params, self.estimate.len())?;
        check_len("x0 priors", d.noisy, self.x0_prior.len())?;
        check_len("z0 priors", d.clean, self.z0_prior.len())?;
        if let Some(i) = self.theta.iter().position(|v| !v.is_finite()) {
            return Err(Error::NonFinite { what: format!("parameter `{}`", self.param_names()[i]) });
        }
        for prior in self.theta_prior.iter().chain(&self.x0_prior).chain(&self.z0_prior) {
            prior.validate()?;
        }
        self.observation.validate(d, &self.theta)?;
        self.model.diffusion_matrix(&self.theta)?;
        let positive = |name: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(Error::InvalidOption {
                    name: name.into(),
                    reason: format!("must be positive and finite, got {v}"),
                })
            }
        };
        positive("t_end", self.t_end)?;
        positive("dt", self.dt)?;
        positive("sample_every", self.sample_every)?;
        let count = (self.t_end - self.first_sample) / self.sample_every;
        if count > MAX_MEASUREMENT_TIMES as f64 {
            return Err(Error::InvalidOption {
                name: "sample_every".into(),
                reason: format!(
                    "{} gives {count:.3e} measurement times on [{}, {}]; at most {MAX_MEASUREMENT_TIMES} \
                     are allowed",
                    self.sample_every, self.first_sample, self.t_end
                ),
            });
        }
        if !(0.0..=self.t_end).contains(&self.first_sample) {
            return Err(Error::InvalidOption {
                name: "first_sample".into(),
                reason: format!(
                    "the first measurement time {} must lie in [0, t_end = {}]",
                    self.first_sample, self.t_end
                ),
            });
        }
        Ok(())
    }

    /// Simulates the preset (what `onsager simulate` writes): the initial states drawn from
    /// the initial-state priors (noisy then clean), the path from t = 0 to `t_end` with step
    /// `dt` by `scheme`, and measurements at [`Preset::measurement_times`] drawn from the
    /// measurement model, all from `rng` in this order. Returns the true path and the
    /// measurements. Errors: as [`Preset::validate`] and [`crate::simulate::simulate`].
    pub fn simulate<R: rand::Rng + ?Sized>(
        &self,
        scheme: crate::simulate::Scheme,
        rng: &mut R,
    ) -> Result<(StatePath, Dataset)> {
        let path = self.simulate_path(scheme, rng)?;
        // The measurements are taken at points of the simulated path, every dt from 0 (the
        // spacing matters only where there is more than one); checked after the path, whose
        // own step error comes first.
        let steps = self.sample_every / self.dt;
        let several = self.t_end - self.first_sample >= self.sample_every;
        if several && (steps - steps.round()).abs() > 1e-6 * steps.max(1.0) {
            return Err(Error::InvalidOption {
                name: "sample_every".into(),
                reason: format!(
                    "must be a multiple of the simulation step dt = {}, got {}",
                    self.dt, self.sample_every
                ),
            });
        }
        let times = self.measurement_times();
        let data = crate::simulate::sample_measurements_at(
            &self.observation,
            &self.theta,
            &path,
            self.dims().noisy,
            &times,
            rng,
        )?;
        Ok((path, data))
    }

    /// Simulates the path as [`Preset::simulate`] and draws a continuous-time record of
    /// intensity `intensity` of the measured states on cells of width `sample_every` from t = 0
    /// ([`crate::simulate::sample_record`]) instead of discrete measurements. Errors: as
    /// [`Preset::simulate`] and [`crate::simulate::sample_record`].
    pub fn simulate_record<R: rand::Rng + ?Sized>(
        &self,
        scheme: crate::simulate::Scheme,
        intensity: f64,
        rng: &mut R,
    ) -> Result<(StatePath, crate::data::continuous::ContinuousRecord)> {
        let path = self.simulate_path(scheme, rng)?;
        let record = crate::simulate::sample_record(
            &self.observation,
            &path,
            self.dims().noisy,
            self.sample_every,
            intensity,
            rng,
        )?;
        Ok((path, record))
    }

    /// The initial states drawn from the priors and the path on [0, `t_end`] (the first draws
    /// of [`Preset::simulate`]).
    fn simulate_path<R: rand::Rng + ?Sized>(
        &self,
        scheme: crate::simulate::Scheme,
        rng: &mut R,
    ) -> Result<StatePath> {
        use crate::simulate::{simulate, SimulateOptions};
        self.validate()?;
        let x0 = self.x0_prior.iter().map(|p| p.sample(rng)).collect::<Result<Vec<f64>>>()?;
        let z0 = self.z0_prior.iter().map(|p| p.sample(rng)).collect::<Result<Vec<f64>>>()?;
        let options = SimulateOptions::new(0.0, self.t_end, self.dt).with_scheme(scheme);
        simulate(&self.model, &self.theta, &x0, &z0, &options, rng)
    }
}

/// The Van der Pol measurements of u, `001_8aefdf0570c96f51.txt` Sec. 9 (Fig. 4): the mixture
/// (1 − p_o) N(u, 0.5²) + p_o N(u, σ_o²) with p_o = 0.25, σ_o = 3.
fn van_der_pol_outliers() -> StateMeasurement {
    let noise = Noise::Mixture {
        p_outlier: Param::Fixed(0.25),
        sigma: Param::Fixed(0.5),
        sigma_outlier: Param::Fixed(3.0),
    };
    StateMeasurement::new(vec![0], names(&["y"]), noise)
}

/// A prior N(mean, sd²).
fn normal(mean: f64, sd: f64) -> Prior {
    Prior::gaussian(mean, sd)
}

/// A flat prior on (0, ∞), for scale parameters the source treats as known.
fn positive() -> Prior {
    Prior::flat().with_bounds(0.0, f64::INFINITY)
}

/// Gaussian measurements y = s[state] + ε, ε ~ N(0, sigma²), with one output named `y`.
fn gaussian_of(state: usize, sigma: Param) -> StateMeasurement {
    StateMeasurement::new(vec![state], names(&["y"]), Noise::Gaussian { sigma })
}

/// The preset called `name` (one of [`NAMES`]); [`Error::UnknownName`] (kind `"model"`)
/// otherwise.
///
/// Defaults and their sources:
///
/// - `ou` — [`Ou`], θ = (θ, σ) = (1, 0.5), x0 ~ N(0, 1), y ~ N(x, 0.2²) every 0.1 from t = 0
///   to 10, simulation step 0.01. All our choice (no paper fixes them): a linear-Gaussian
///   reference with a closed-form solution.
/// - `tanh` — [`Tanh`], σ = 1, x0 ~ N(0, 0.16), a single measurement y ~ N(x(5), 0.16) at
///   t = 5 (`first_sample = sample_every = t_end = 5`), `001_8aefdf0570c96f51.txt` Sec. 2 (the
///   paper's data is the single value y = 1.5); simulation step 0.005 (our choice).
/// - `van-der-pol` — [`VanDerPol`], μ = 2, σ = 0.1, x0 ~ N(0, 0.01 I), T = 16, measurements of
///   u every 0.1 from t = 0 from the mixture (1 − p_o) N(u, 0.5²) + p_o N(u, σ_o²) with
///   p_o = 0.25, σ_o = 3 (Fig. 4), simulation step 5·10⁻⁴ (the paper's, with the order 1.5
///   scheme), all `001_8aefdf0570c96f51.txt` Sec. 9. The mixture parameters are fixed
///   (`Param::Fixed`); the paper estimates with a Student-t likelihood instead (its (ν = 4,
///   scale σ_y) log-likelihood), which the CLI selects with `--likelihood`.
/// - `duffing` — [`Duffing`], `000_74b95e149527c64e.txt` Sec. 4.1.1, (4.2)–(4.7), Table 4.1:
///   a = 1, b = −1, d = 0.2, γ = 0.3, σ_D = 0.1, Σ_y = 0.1; x0, z0 ~ N(0, 0.4²);
///   a, b, d ~ N(0, 10²) (4.4); Σ_y ~ Gamma(shape 1.1, scale 10) (4.5); γ, σ_D known (flat
///   priors, not estimated); y ~ N(z, Σ_y²) every t_s = 0.1 from t = 0; t_f = 100 (the thesis
///   uses 50, 100 and 200); simulation step 0.005 (Sec. 4.1).
/// - `holmes-rand` — [`HolmesRand`], `000_74b95e149527c64e.txt` Sec. 4.1.3, (4.8), Table 4.3:
///   a = 0.2, b = −1, γ = 0.2, d = 1, φ = 0.4, σ_D = 0.1, Σ_y = 0.005 (Figs. 4.15–4.16; the
///   thesis varies it); x0, z0 ~ N(0, 0.1²); a, b, γ, d ~ N(0, 10²); Σ_y ~ Gamma(4, l_b/3);
///   φ, σ_D known; measurements of z rounded to multiples of l_b = 0.05 after Gaussian noise
///   of sd Σ_y, every 0.1 from t = 0 to t_f = 50 (501 measurements); simulation step 0.005
///   (Sec. 4.1).
/// - `double-well` — [`DoubleWell`], D = 0.5, x0 ~ N(−1, 0.2²) (the left well),
///   y ~ N(x, 0.4²) every 0.5 from t = 0 to 20, simulation step 0.005. Our choice: 003 gives
///   the notation (`003_d2fc48a470e528fc.txt (0.1)`) but no numerical example.
/// - `double-well-2d` — [`DoubleWell2d`], D = 0.5, x0 ~ N(−1, 0.2²), v0 ~ N(−1, 0.2²) (the
///   left well, v at rest), x measured as y ~ N(x, 0.5²) every 1 from t = 0 to 10, simulation
///   step 0.005. Our choice, for the two-state closures against the exact two-dimensional grid.
/// - `lorenz63` — [`Lorenz63`], s = 10, r = 28, b = 8/3 (Lorenz 1963), σ_w = 1,
///   x0 ~ N((1, 1, 1), I), all three states measured as y1, y2, y3 ~ N(x_i, 1) every 0.1 from
///   t = 0 to 10, simulation step 0.001. Noise levels, initial prior and sampling are our
///   choice.
/// - `lorenz96` — [`Lorenz96`] with 10 states, F = 8 (Lorenz 1996), σ_w = √0.1 (noise
///   variance 0.1 per unit time), x0 ~ N(2.3, 3.6²) per state (about the mean and sd of a state
///   on the attractor at F = 8), every state measured as y1, …, y10 ~ N(x_i, 1) every 0.1 from
///   t = 0 to 5, simulation step 0.001. Noise levels, initial prior and sampling are our
///   choice.
pub fn preset(name: &str) -> Result<Preset> {
    let unknown = || Error::UnknownName { kind: "model".into(), name: name.into(), known: names(NAMES) };
    let p = match name {
        "ou" => Preset {
            name: "ou".into(),
            description: "Ornstein-Uhlenbeck process dX = -theta X dt + sigma dW, Gaussian measurements of x"
                .into(),
            source: "closed-form reference model; defaults are our choice".into(),
            model: Model::Ou(Ou),
            theta: Ou::NOMINAL.to_vec(),
            theta_prior: vec![Prior::flat(), positive()],
            estimate: vec![false; 2],
            x0_prior: vec![normal(0.0, 1.0)],
            z0_prior: vec![],
            observation: gaussian_of(0, Param::Fixed(0.2)),
            t_end: 10.0,
            dt: 0.01,
            first_sample: 0.0,
            sample_every: 0.1,
        },
        "tanh" => Preset {
            name: "tanh".into(),
            description: "dX = tanh(X) dt + sigma dW with one measurement at t = 5".into(),
            source: "001_8aefdf0570c96f51.txt Sec. 2 (motivating example, Fig. 1)".into(),
            model: Model::Tanh(Tanh),
            theta: Tanh::NOMINAL.to_vec(),
            theta_prior: vec![positive()],
            estimate: vec![false],
            // X0 ~ N(0, 0.16): sd 0.4.
            x0_prior: vec![normal(0.0, 0.4)],
            z0_prior: vec![],
            // Y | X5 ~ N(X5, 0.16): sd 0.4.
            observation: gaussian_of(0, Param::Fixed(0.4)),
            t_end: 5.0,
            dt: 0.005,
            first_sample: 5.0,
            sample_every: 5.0,
        },
        "van-der-pol" => Preset {
            name: "van-der-pol".into(),
            description: "stochastic Van der Pol oscillator, u measured with Gaussian-mixture outliers"
                .into(),
            source: "001_8aefdf0570c96f51.txt Sec. 9 (Figs. 3-4)".into(),
            model: Model::VanDerPol(VanDerPol),
            theta: VanDerPol::NOMINAL.to_vec(),
            theta_prior: vec![Prior::flat(), positive()],
            estimate: vec![false; 2],
            // N([0, 0], I/100): sd 0.1 each.
            x0_prior: vec![normal(0.0, 0.1), normal(0.0, 0.1)],
            z0_prior: vec![],
            observation: van_der_pol_outliers(),
            t_end: 16.0,
            dt: 5e-4,
            first_sample: 0.0,
            sample_every: 0.1,
        },
        "duffing" => Preset {
            name: "duffing".into(),
            description: "forced stochastic Duffing oscillator, noisy velocity x, clean position z measured"
                .into(),
            source: "000_74b95e149527c64e.txt Sec. 4.1.1, eqs. (4.2)-(4.7), Table 4.1".into(),
            model: Model::Duffing(Duffing),
            theta: Duffing::NOMINAL.to_vec(),
            // (4.4): N(0, sigma_theta^2), sigma_theta = 10; (4.5): Gamma(r = 1.1, s = 10).
            theta_prior: vec![
                normal(0.0, 10.0),
                normal(0.0, 10.0),
                normal(0.0, 10.0),
                Prior::flat(),
                positive(),
                Prior::gamma(1.1, 10.0),
            ],
            estimate: vec![true, true, true, false, false, true],
            x0_prior: vec![normal(0.0, 0.4)],
            z0_prior: vec![normal(0.0, 0.4)],
            observation: gaussian_of(1, Param::Theta(Duffing::SIGMA_Y)),
            t_end: 100.0,
            dt: 0.005,
            first_sample: 0.0,
            sample_every: 0.1,
        },
        "holmes-rand" => Preset {
            name: "holmes-rand".into(),
            description:
                "forced stochastic Holmes-Rand oscillator, clean position z measured with quantization".into(),
            source: "000_74b95e149527c64e.txt Sec. 4.1.3, eq. (4.8), Table 4.3".into(),
            model: Model::HolmesRand(HolmesRand),
            theta: HolmesRand::NOMINAL.to_vec(),
            // N(0, sigma_theta^2), sigma_theta = 10; Sigma_y ~ Gamma(r = 4, l_b / 3).
            theta_prior: vec![
                normal(0.0, 10.0),
                normal(0.0, 10.0),
                normal(0.0, 10.0),
                normal(0.0, 10.0),
                Prior::flat(),
                positive(),
                Prior::gamma(4.0, HOLMES_RAND_BIT / 3.0),
            ],
            estimate: vec![true, true, true, true, false, false, true],
            x0_prior: vec![normal(0.0, 0.1)],
            z0_prior: vec![normal(0.0, 0.1)],
            observation: StateMeasurement::new(
                vec![1],
                names(&["y"]),
                Noise::Quantized { sigma: Param::Theta(HolmesRand::SIGMA_Y), bit: HOLMES_RAND_BIT },
            ),
            t_end: 50.0,
            dt: 0.005,
            first_sample: 0.0,
            sample_every: 0.1,
        },
        "double-well" => Preset {
            name: "double-well".into(),
            description:
                "double-well diffusion dX = (4X - 4X^3) dt + sqrt(2D) dW, Gaussian measurements of x".into(),
            source: "notation of 003_d2fc48a470e528fc.txt (0.1); defaults are our choice".into(),
            model: Model::DoubleWell(DoubleWell),
            theta: DoubleWell::NOMINAL.to_vec(),
            theta_prior: vec![positive()],
            estimate: vec![false],
            x0_prior: vec![normal(-1.0, 0.2)],
            z0_prior: vec![],
            observation: gaussian_of(0, Param::Fixed(0.4)),
            t_end: 20.0,
            dt: 0.005,
            first_sample: 0.0,
            sample_every: 0.5,
        },
        "double-well-2d" => double_well_2d_preset(),
        "lorenz63" => Preset {
            name: "lorenz63".into(),
            description: "Lorenz-63 system with additive noise sigma_w I, all three states measured".into(),
            source: "Lorenz (1963) drift; noise and sampling defaults are our choice".into(),
            model: Model::Lorenz63(Lorenz63),
            theta: Lorenz63::NOMINAL.to_vec(),
            theta_prior: vec![Prior::flat(), Prior::flat(), Prior::flat(), positive()],
            estimate: vec![false; 4],
            x0_prior: vec![normal(1.0, 1.0), normal(1.0, 1.0), normal(1.0, 1.0)],
            z0_prior: vec![],
            observation: StateMeasurement::new(
                vec![0, 1, 2],
                names(&["y1", "y2", "y3"]),
                Noise::Gaussian { sigma: Param::Fixed(1.0) },
            ),
            t_end: 10.0,
            dt: 0.001,
            first_sample: 0.0,
            sample_every: 0.1,
        },
        "lorenz96" => lorenz96_preset(),
        _ => return Err(unknown()),
    };
    Ok(p)
}

/// The `double-well-2d` preset of [`preset`]: [`DoubleWell2d`], x measured.
fn double_well_2d_preset() -> Preset {
    Preset {
        name: "double-well-2d".into(),
        description:
            "two-state double well dX = (4X - 4X^3) dt + sqrt(2D) dW1, dV = (X - V) dt + sqrt(2D) dW2, \
                      Gaussian measurements of x"
                .into(),
        source: "notation of 003_d2fc48a470e528fc.txt (0.1); defaults are our choice".into(),
        model: Model::DoubleWell2d(DoubleWell2d),
        theta: DoubleWell2d::NOMINAL.to_vec(),
        theta_prior: vec![positive()],
        estimate: vec![false],
        x0_prior: vec![normal(-1.0, 0.2), normal(-1.0, 0.2)],
        z0_prior: vec![],
        observation: gaussian_of(0, Param::Fixed(0.5)),
        t_end: 10.0,
        dt: 0.005,
        first_sample: 0.0,
        sample_every: 1.0,
    }
}

/// The `lorenz96` preset of [`preset`]: [`Lorenz96`] with 10 states, every state measured.
fn lorenz96_preset() -> Preset {
    let model = Lorenz96::default();
    let n = model.states();
    Preset {
        name: "lorenz96".into(),
        description:
            "Lorenz-96 system with 10 states, forcing F and additive noise sigma_w I, all states measured"
                .into(),
        source: "Lorenz (1996) drift; noise and sampling defaults are our choice".into(),
        model: Model::Lorenz96(model),
        theta: Lorenz96::NOMINAL.to_vec(),
        theta_prior: vec![Prior::flat(), positive()],
        estimate: vec![false; 2],
        x0_prior: vec![normal(2.3, 3.6); n],
        z0_prior: vec![],
        observation: StateMeasurement::new(
            (0..n).collect(),
            (1..=n).map(|i| format!("y{i}")).collect(),
            Noise::Gaussian { sigma: Param::Fixed(1.0) },
        ),
        t_end: 5.0,
        dt: 0.001,
        first_sample: 0.0,
        sample_every: 0.1,
    }
}

/// Bit length l_b of the Holmes–Rand quantized measurements, `000_74b95e149527c64e.txt`
/// Table 4.3.
const HOLMES_RAND_BIT: f64 = 0.05;
