//! The data-set fixtures: seeded simulations and deterministic records, each owning what an
//! [`EstimationProblem`] borrows, with the settings of the tests that first used them.

use nalgebra::{DMatrix, DVector};
use rand::rngs::StdRng;
use rand::SeedableRng;

use super::models::{LinearOscillator, RotationWithLag, RotationWithPosition};
use crate::data::{Dataset, StatePath};
use crate::estimate::EstimationProblem;
use crate::kalman::linear::{kalman_rts, KalmanSmoothing, LinearGaussianModel};
use crate::model::library::{DoubleWell, Model, Ou, Preset};
use crate::model::observation::{Noise, Param, StateMeasurement};
use crate::model::prior::Prior;
use crate::model::Sde;
use crate::simulate::{sample_measurements, sample_measurements_at, simulate, SimulateOptions};
use crate::{Error, Result};

/// Gaussian measurements y = `s[state]` + ε, ε ~ N(0, sd²), of one state, with one output `y`.
pub fn gaussian_measurement(state: usize, sd: f64) -> StateMeasurement {
    StateMeasurement::new(vec![state], vec!["y".into()], Noise::Gaussian { sigma: Param::Fixed(sd) })
}

/// Deterministic smooth data y(t) = `amplitude` · cos(1.3 t) + `offset` at `times`, one output
/// called `name`: for the identities that hold for any data (derivatives against finite
/// differences, linear-Gaussian equalities), where no randomness is needed.
pub fn cosine_data(name: &str, times: &[f64], amplitude: f64, offset: f64) -> Result<Dataset> {
    let values = times.iter().map(|&t| vec![amplitude * (1.3 * t).cos() + offset]).collect();
    Dataset::try_new(vec![name.into()], times.to_vec(), values)
}

/// A simulated record of [`LinearOscillator`]: θ = (k, c, u, σ, σ_y) = (0.7, 1.5, 0.3, 0.4,
/// 0.15), the path from (v, q)(0) = (0.2, −0.5) on [0, 4] (step 0.01, seed 11; every simulation
/// here uses the default scheme of [`SimulateOptions::new`], the order 1.5 Itô–Taylor scheme),
/// the position q measured with N(0, σ_y²)
/// errors every 0.2 from t = 0 (21 measurements), the eighth (t = 1.4) removed (NaN) so that a
/// filter skips an update; flat θ priors, v(0) ~ N(0.1, 0.5²), q(0) ~ N(−0.3, 0.6²) at t0 = 0.
///
/// Known answers: the exact Kalman filter and RTS smoother (the model is linear), with
/// m0 = (0.1, −0.3) and P0 = diag(0.25, 0.36) (`kalman::linear`).
#[derive(Debug, Clone)]
pub struct OscillatorRecord {
    /// θ = (k, c, u, σ, σ_y).
    pub theta: Vec<f64>,
    /// Flat priors on every θ component.
    pub theta_prior: Vec<Prior>,
    /// v(0) ~ N(0.1, 0.5²).
    pub x0_prior: Vec<Prior>,
    /// q(0) ~ N(−0.3, 0.6²).
    pub z0_prior: Vec<Prior>,
    /// q measured with Gaussian errors of sd σ_y (a component of θ).
    pub observation: StateMeasurement,
    /// The measurements, one of them missing.
    pub data: Dataset,
}

impl OscillatorRecord {
    /// Simulates the record.
    pub fn new() -> Result<OscillatorRecord> {
        let theta = vec![0.7, 1.5, 0.3, 0.4, 0.15];
        let sigma = Param::Theta(LinearOscillator::SIGMA_Y);
        let observation = StateMeasurement::new(vec![1], vec!["y".into()], Noise::Gaussian { sigma });
        let mut rng = StdRng::seed_from_u64(11);
        let options = SimulateOptions::new(0.0, 4.0, 0.01);
        let path = simulate(&LinearOscillator, &theta, &[0.2], &[-0.5], &options, &mut rng)?;
        let mut data = sample_measurements(&observation, &theta, &path, 1, 0.2, &mut rng)?;
        // A missing measurement exercises the skipped update.
        data.values[7][0] = f64::NAN;
        Ok(OscillatorRecord {
            theta,
            theta_prior: vec![Prior::flat(); 5],
            x0_prior: vec![Prior::gaussian(0.1, 0.5)],
            z0_prior: vec![Prior::gaussian(-0.3, 0.6)],
            observation,
            data,
        })
    }

    /// The estimation problem: every θ fixed, t0 = 0, seed 0.
    pub fn problem(&self) -> EstimationProblem<'_, LinearOscillator, StateMeasurement> {
        EstimationProblem {
            sde: &LinearOscillator,
            observation: &self.observation,
            theta: &self.theta,
            theta_prior: &self.theta_prior,
            estimate: &[],
            x0_prior: &self.x0_prior,
            z0_prior: &self.z0_prior,
            data: &self.data,
            t0: 0.0,
            seed: 0,
            max_memory: Default::default(),
        }
    }
}

/// A simulated record of the Ornstein–Uhlenbeck process (the built-in [`Ou`]): θ = (θ, σ) =
/// (1, 0.5), the path from x(0) = 0.3 on [0, 5] (step 0.01, seed 6), y ~ N(x, 0.2²) every 0.5
/// from t = 0 (11 measurements); θ priors flat and flat on σ ≥ 0 by default, x(0) ~ N(0, 0.5²) at
/// t0 = 0.
///
/// Known answers: linear dynamics, so the RTS smoother ([`OuRecord::rts`]) is the exact
/// smoothing law, and the KSP mean, the mean-optimal estimate, the Gaussian closure and the MAP
/// paths coincide with its mean (`003_d2fc48a470e528fc.txt` Sec. I.3).
#[derive(Debug, Clone)]
pub struct OuRecord {
    /// The simulated path.
    pub truth: StatePath,
    /// y ~ N(x, 0.2²).
    pub observation: StateMeasurement,
    /// The measurements.
    pub data: Dataset,
    /// θ = (θ, σ) = (1, 0.5).
    pub theta: [f64; 2],
    /// The θ priors (flat, and flat on σ ≥ 0, unless changed).
    pub theta_prior: [Prior; 2],
    /// x(0) ~ N(0, 0.5²).
    pub x0_prior: [Prior; 1],
}

impl OuRecord {
    /// θ = (θ, σ) of the record.
    pub const THETA: [f64; 2] = [1.0, 0.5];

    /// Simulates the record.
    pub fn new() -> Result<OuRecord> {
        let observation = gaussian_measurement(0, 0.2);
        let theta = Self::THETA;
        let mut rng = StdRng::seed_from_u64(6);
        let truth = simulate(&Ou, &theta, &[0.3], &[], &SimulateOptions::new(0.0, 5.0, 0.01), &mut rng)?;
        let data = sample_measurements(&observation, &theta, &truth, 1, 0.5, &mut rng)?;
        Ok(OuRecord {
            truth,
            observation,
            data,
            theta,
            theta_prior: [Prior::flat(), Prior::flat().with_bounds(0.0, f64::INFINITY)],
            x0_prior: [Prior::gaussian(0.0, 0.5)],
        })
    }

    /// The record with other θ priors (θ is never estimated by the problem; the priors are only
    /// checked).
    pub fn with_theta_prior(mut self, theta_prior: [Prior; 2]) -> OuRecord {
        self.theta_prior = theta_prior;
        self
    }

    /// The estimation problem: θ fixed, t0 = 0, seed 0.
    pub fn problem(&self) -> EstimationProblem<'_, Ou, StateMeasurement> {
        EstimationProblem {
            sde: &Ou,
            observation: &self.observation,
            theta: &self.theta,
            theta_prior: &self.theta_prior,
            estimate: &[],
            x0_prior: &self.x0_prior,
            z0_prior: &[],
            data: &self.data,
            t0: 0.0,
            seed: 0,
            max_memory: Default::default(),
        }
    }

    /// The exact Kalman filter and RTS smoother of the problem (m0 = 0, P0 = 0.25 at t = 0),
    /// with moments also at `times` ([`kalman_rts`]).
    pub fn rts(&self, times: &[f64]) -> Result<KalmanSmoothing> {
        let m0 = DVector::from_element(1, 0.0);
        let p0 = DMatrix::from_element(1, 1, 0.25);
        let model = LinearGaussianModel::from_sde(&Ou, &self.theta, &self.observation, 0.0, m0, p0)?;
        kalman_rts(&model, &self.data, times)
    }
}

/// Where the path of a [`DoubleWellRecord`] starts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Start {
    /// At this state.
    At(f64),
    /// Drawn from x(0) ~ N(−1, 0.2²), the record's x0 prior, as the first draw of the seed.
    Drawn,
}

/// A simulated record of the built-in [`DoubleWell`] (dX = (4X − 4X³) dt + √(2D) dW) with
/// D = 0.5: the path on [0, t_end] with step 0.005, y ~ N(x, 0.2²) (R = 0.04) at given times; a
/// flat prior on D ≥ 0 and x(0) ~ N(−1, 0.2²) at t0 = 0 by default (the `double-well` preset's,
/// with measurements twice as precise).
///
/// Known answers: none in closed form; the references are the exact grid estimators
/// (`action::ksp_smoother`, `action::mean_optimal`), and with a path that changes wells
/// ([`DoubleWellRecord::changes_wells`]) the estimates should follow the true well.
#[derive(Debug, Clone)]
pub struct DoubleWellRecord {
    /// The simulated path.
    pub truth: StatePath,
    /// y ~ N(x, 0.2²).
    pub observation: StateMeasurement,
    /// The measurements.
    pub data: Dataset,
    /// θ = (D) = (0.5).
    pub theta: [f64; 1],
    /// The prior of D (flat on D ≥ 0 unless changed; D is never estimated by the problem).
    pub theta_prior: [Prior; 1],
    /// The x(0) prior (N(−1, 0.2²) unless changed).
    pub x0_prior: [Prior; 1],
}

impl DoubleWellRecord {
    /// The record of the closure tests and benchmarks: x(0) = −1, measurements at
    /// t = 1, 2, …, t_end (with t_end a whole number), random numbers from `seed`.
    pub fn new(seed: u64, t_end: f64) -> Result<DoubleWellRecord> {
        let times: Vec<f64> = (1..=t_end as usize).map(|k| k as f64).collect();
        Self::simulate(seed, Start::At(-1.0), t_end, &times)
    }

    /// The record with its path from `start` on [0, t_end] and measurements at `times` (points
    /// of the simulation grid), all random numbers from `seed`: x(0) if drawn, the Brownian
    /// increments, then the measurement errors.
    pub fn simulate(seed: u64, start: Start, t_end: f64, times: &[f64]) -> Result<DoubleWellRecord> {
        let observation = gaussian_measurement(0, 0.2);
        let theta = DoubleWell::NOMINAL;
        let x0_prior = Prior::gaussian(-1.0, 0.2);
        let mut rng = StdRng::seed_from_u64(seed);
        let x0 = match start {
            Start::At(x) => x,
            Start::Drawn => x0_prior.sample(&mut rng)?,
        };
        let options = SimulateOptions::new(0.0, t_end, 0.005);
        let truth = simulate(&DoubleWell, &theta, &[x0], &[], &options, &mut rng)?;
        let data = sample_measurements_at(&observation, &theta, &truth, 1, times, &mut rng)?;
        Ok(DoubleWellRecord {
            truth,
            observation,
            data,
            theta,
            theta_prior: [Prior::flat().with_bounds(0.0, f64::INFINITY)],
            x0_prior: [x0_prior],
        })
    }

    /// The record with another prior of D.
    pub fn with_theta_prior(mut self, prior: Prior) -> DoubleWellRecord {
        self.theta_prior = [prior];
        self
    }

    /// The record with another x(0) prior (the simulation is unchanged).
    pub fn with_x0_prior(mut self, prior: Prior) -> DoubleWellRecord {
        self.x0_prior = [prior];
        self
    }

    /// Whether the true path visits both wells (x > 0.8 and x < −0.8 at some times).
    pub fn changes_wells(&self) -> bool {
        let x = self.truth.values.iter().map(|row| row[0]);
        x.clone().any(|v| v > 0.8) && x.into_iter().any(|v| v < -0.8)
    }

    /// The estimation problem: D fixed, t0 = 0, seed 0.
    pub fn problem(&self) -> EstimationProblem<'_, DoubleWell, StateMeasurement> {
        EstimationProblem {
            sde: &DoubleWell,
            observation: &self.observation,
            theta: &self.theta,
            theta_prior: &self.theta_prior,
            estimate: &[],
            x0_prior: &self.x0_prior,
            z0_prior: &[],
            data: &self.data,
            t0: 0.0,
            seed: 0,
            max_memory: Default::default(),
        }
    }
}

/// A built-in model's preset simulated and measured as the preset says: the path on
/// [0, `t_end`] with the preset's step `dt` (the default scheme of [`SimulateOptions::new`]),
/// measured with the preset's measurement model every `sample_every` from t = 0 on the
/// simulation grid. Change the preset's settings (`t_end`, `dt`, `sample_every`, θ, …) before
/// simulating; change its measurement model after simulating to estimate with another
/// likelihood than the generating one.
#[derive(Debug, Clone)]
pub struct PresetRecord {
    /// The preset: model, θ, priors and measurement model of the problem.
    pub preset: Preset,
    /// The simulated path.
    pub truth: StatePath,
    /// The measurements.
    pub data: Dataset,
}

impl PresetRecord {
    /// Simulates `preset` with the initial states drawn from its priors (noisy, then clean) as
    /// the first draws of `seed`. Errors: those of the simulation and the sampling, and
    /// [`Error::InvalidOption`] when the preset's first measurement is not at t = 0.
    pub fn simulate(preset: Preset, seed: u64) -> Result<PresetRecord> {
        let mut rng = StdRng::seed_from_u64(seed);
        let x0 = preset.x0_prior.iter().map(|q| q.sample(&mut rng)).collect::<Result<Vec<f64>>>()?;
        let z0 = preset.z0_prior.iter().map(|q| q.sample(&mut rng)).collect::<Result<Vec<f64>>>()?;
        Self::run(preset, &x0, &z0, rng)
    }

    /// Simulates `preset` from the initial states `x0` (noisy) and `z0` (clean), all random
    /// numbers from `seed`. Errors as [`PresetRecord::simulate`].
    pub fn simulate_from(preset: Preset, seed: u64, x0: &[f64], z0: &[f64]) -> Result<PresetRecord> {
        Self::run(preset, x0, z0, StdRng::seed_from_u64(seed))
    }

    fn run(preset: Preset, x0: &[f64], z0: &[f64], mut rng: StdRng) -> Result<PresetRecord> {
        if preset.first_sample != 0.0 {
            return Err(Error::invalid(
                "first_sample",
                format!("a preset record measures from t = 0, got {}", preset.first_sample),
            ));
        }
        let p = &preset;
        let options = SimulateOptions::new(0.0, p.t_end, p.dt);
        let truth = simulate(&p.model, &p.theta, x0, z0, &options, &mut rng)?;
        let n = p.model.dims().noisy;
        let data = sample_measurements(&p.observation, &p.theta, &truth, n, p.sample_every, &mut rng)?;
        Ok(PresetRecord { preset, truth, data })
    }

    /// The preset's estimation problem on the record ([`Preset::problem`]: t0 from
    /// [`default_initial_time`](crate::estimate::default_initial_time), here 0, and seed 0).
    pub fn problem<'a>(&'a self, estimate: &'a [usize]) -> EstimationProblem<'a, Model, StateMeasurement> {
        self.preset.problem(&self.data, estimate)
    }
}

/// The Van der Pol problem of `001_8aefdf0570c96f51.txt` Sec. 9 and of the path benchmarks: the
/// `van-der-pol` preset (μ = 2, σ = 0.1, T = 16, step 5·10⁻⁴) simulated from (u, v)(0) = (0, 0)
/// with `seed`, u measured every 0.1 with the preset's Gaussian-mixture outliers (p_o = 0.25,
/// σ = 0.5, σ_o = 3), and estimated with a Student-t likelihood (ν = 4, scale 0.5) instead, as
/// the paper does: the record's preset has that likelihood.
pub fn van_der_pol_student_t(seed: u64) -> Result<PresetRecord> {
    let mut record =
        PresetRecord::simulate_from(crate::model::library::preset("van-der-pol")?, seed, &[0.0, 0.0], &[])?;
    record.preset.observation.noise = Noise::StudentT { nu: Param::Fixed(4.0), scale: Param::Fixed(0.5) };
    Ok(record)
}

/// [`RotationWithPosition`] (three states, z clean) with x2 and z measured with N(0, 0.2²)
/// errors every 0.25 on [0.25, 4], one datum missing; x(0) ~ N((0.5, −0.2), diag(0.5², 0.4²)),
/// z(0) ~ N(0, 0.6²).
///
/// Known answer: the exact Kalman filter and RTS smoother ([`RotationRecord::rts`]).
#[derive(Debug, Clone)]
pub struct RotationRecord {
    /// The measurement times.
    pub times: Vec<f64>,
    /// The initial priors of x1, x2.
    pub x0_prior: Vec<Prior>,
    /// The initial prior of z.
    pub z0_prior: Vec<Prior>,
    /// x2 and z measured with sd 0.2 (outputs `y2`, `yz`).
    pub observation: StateMeasurement,
    /// The measurements.
    pub data: Dataset,
}

impl RotationRecord {
    /// Simulates the record (seed 5).
    pub fn new() -> Result<RotationRecord> {
        let observation = StateMeasurement::new(
            vec![1, 2],
            vec!["y2".into(), "yz".into()],
            Noise::Gaussian { sigma: Param::Fixed(0.2) },
        );
        let mut rng = StdRng::seed_from_u64(5);
        let options = SimulateOptions::new(0.0, 4.0, 0.01);
        let path = simulate(&RotationWithPosition, &[], &[0.8, -0.4], &[0.3], &options, &mut rng)?;
        let times: Vec<f64> = (1..=16).map(|k| 0.25 * k as f64).collect();
        let mut data = sample_measurements_at(&observation, &[], &path, 2, &times, &mut rng)?;
        data.values[5][0] = f64::NAN;
        Ok(RotationRecord {
            times,
            x0_prior: vec![Prior::gaussian(0.5, 0.5), Prior::gaussian(-0.2, 0.4)],
            z0_prior: vec![Prior::gaussian(0.0, 0.6)],
            observation,
            data,
        })
    }

    /// The estimation problem: t0 = 0, seed 0.
    pub fn problem(&self) -> EstimationProblem<'_, RotationWithPosition, StateMeasurement> {
        EstimationProblem {
            sde: &RotationWithPosition,
            observation: &self.observation,
            theta: &[],
            theta_prior: &[],
            estimate: &[],
            x0_prior: &self.x0_prior,
            z0_prior: &self.z0_prior,
            data: &self.data,
            t0: 0.0,
            seed: 0,
            max_memory: Default::default(),
        }
    }

    /// The exact Kalman filter and RTS smoother of the record, with `extra_times` in its grid.
    pub fn rts(&self, extra_times: &[f64]) -> Result<KalmanSmoothing> {
        let m0 = DVector::from_vec(vec![0.5, -0.2, 0.0]);
        let p0 = DMatrix::from_diagonal(&DVector::from_vec(vec![0.25, 0.16, 0.36]));
        let model =
            LinearGaussianModel::from_sde(&RotationWithPosition, &[], &self.observation, 0.0, m0, p0)?;
        kalman_rts(&model, &self.data, extra_times)
    }
}

/// [`RotationWithLag`] (three noisy states) simulated from (0.5, −0.3, 0) with seed 2, x₁ and x₃
/// measured with sd 0.2 at t = 0.5, 1, …, 0.5 n; initial priors N(0.5, 0.3²), N(−0.3, 0.3²),
/// N(0, 0.3²).
///
/// Known answer: the exact Kalman filter and RTS smoother ([`LagRecord::rts`]).
#[derive(Debug, Clone)]
pub struct LagRecord {
    /// The initial priors of x₁, x₂, x₃.
    pub x0_prior: Vec<Prior>,
    /// x₁ and x₃ measured with sd 0.2 (outputs `y1`, `y3`).
    pub observation: StateMeasurement,
    /// The measurements.
    pub data: Dataset,
}

impl LagRecord {
    /// Simulates the record with `measurements` measurement times (seed 2, path on
    /// [0, 0.5 · measurements]).
    pub fn new(measurements: usize) -> Result<LagRecord> {
        let observation = StateMeasurement::new(
            vec![0, 2],
            vec!["y1".into(), "y3".into()],
            Noise::Gaussian { sigma: Param::Fixed(0.2) },
        );
        let mut rng = StdRng::seed_from_u64(2);
        let options = SimulateOptions::new(0.0, 0.5 * measurements as f64, 0.01);
        let path = simulate(&RotationWithLag, &[], &[0.5, -0.3, 0.0], &[], &options, &mut rng)?;
        let times: Vec<f64> = (1..=measurements).map(|k| 0.5 * k as f64).collect();
        let data = sample_measurements_at(&observation, &[], &path, 3, &times, &mut rng)?;
        let x0_prior = vec![Prior::gaussian(0.5, 0.3), Prior::gaussian(-0.3, 0.3), Prior::gaussian(0.0, 0.3)];
        Ok(LagRecord { x0_prior, observation, data })
    }

    /// The estimation problem: t0 = 0, seed 0.
    pub fn problem(&self) -> EstimationProblem<'_, RotationWithLag, StateMeasurement> {
        EstimationProblem {
            sde: &RotationWithLag,
            observation: &self.observation,
            theta: &[],
            theta_prior: &[],
            estimate: &[],
            x0_prior: &self.x0_prior,
            z0_prior: &[],
            data: &self.data,
            t0: 0.0,
            seed: 0,
            max_memory: Default::default(),
        }
    }

    /// The exact Kalman filter and RTS smoother of the record, with `extra_times` in its grid.
    pub fn rts(&self, extra_times: &[f64]) -> Result<KalmanSmoothing> {
        let m0 = DVector::from_vec(vec![0.5, -0.3, 0.0]);
        let p0 = DMatrix::from_diagonal(&DVector::from_element(3, 0.09));
        let model = LinearGaussianModel::from_sde(&RotationWithLag, &[], &self.observation, 0.0, m0, p0)?;
        kalman_rts(&model, &self.data, extra_times)
    }
}
