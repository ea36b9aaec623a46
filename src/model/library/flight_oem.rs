//! The output-error method (OEM) of flight-path reconstruction, the reference estimator that
//! `000_74b95e149527c64e.txt` Sec. 4.2 compares the path-space MAP estimators with
//! (Jategaonkar, *Flight Vehicle System Identification*, 2nd ed., Ch. 4 and Sec. 10.5).
//!
//! The kinematics are driven by the measured rates and specific forces as inputs, corrected by
//! the sensor biases; there is no process noise. The unknowns are β = (b_p, b_q, b_r, b_ax,
//! b_ay, b_az, φ₀, θ₀, ψ₀, h₀, u₀, v₀, w₀): the six biases and the seven initial states. The
//! cost is the maximum-likelihood cost of output errors with an unknown noise covariance,
//! det R with R = (1/N) Σ e eᵀ (diagonal here, Jategaonkar (4.15)–(4.20)), minimised by
//! relaxation: R from the residuals of the current β, then a Gauss–Newton step on
//! ½ Σ eᵀ R⁻¹ e with R fixed (Jategaonkar (4.27)–(4.33)), with sensitivities by central
//! differences and step halving. The standard deviations are the Cramér–Rao bounds
//! √diag(M⁻¹), M = Σ Sᵀ R⁻¹ S, at the solution. They treat the inputs as exact: noise of sd σ
//! on a rate or acceleration channel sampled every Δ adds a scatter of about σ√(3Δ/T) to its
//! bias over a record of length T, which on simulated 10 s records is 2–4 times the bound.
//!
//! Between samples the inputs are linear in time and the states advance by one classical
//! Runge–Kutta step per sample interval. The kinematics and the output equations are those of
//! the flight-path model ([`rigid_body_kinematics`], [`FlightPathObservation::outputs`]), so the
//! OEM and the MAP estimators fit the same equations.

use nalgebra::{DMatrix, DVector};

use super::flight_path::{rigid_body_kinematics, state, FlightPath, FlightPathObservation};
use crate::data::Dataset;
use crate::status::Status;
use crate::{Error, Result};

/// The OEM's outputs, a subset of [`FlightPathObservation::OUTPUTS`] (its first seven).
pub const OEM_OUTPUTS: [&str; 7] = ["v_m", "alpha_m", "beta_m", "phi_m", "theta_m", "psi_m", "h_m"];
/// The OEM's inputs, measured rates and specific forces (names of the data's outputs).
pub const OEM_INPUTS: [&str; 6] = ["p_m", "q_m", "r_m", "ax_m", "ay_m", "az_m"];
/// The OEM's states, in the order of [`OemEstimate::initial`].
pub const OEM_STATES: [&str; 7] = ["phi", "theta", "psi", "h", "u", "v", "w"];
/// Number of unknowns: six biases and seven initial states.
const UNKNOWNS: usize = 13;
/// Where each OEM state sits in the model's clean state.
const CLEAN: [usize; 7] = [state::PHI, state::THETA, state::PSI, state::H, state::U, state::V, state::W];

/// Options of the output-error method.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct OemOptions {
    /// Most Gauss–Newton iterations. Default 50.
    pub max_iterations: usize,
    /// Converged when every component of the Gauss–Newton step is below `tolerance` times its
    /// Cramér–Rao standard deviation. Default 10⁻⁴.
    pub tolerance: f64,
}

impl Default for OemOptions {
    fn default() -> Self {
        OemOptions { max_iterations: 50, tolerance: 1e-4 }
    }
}

/// The OEM's estimate.
#[derive(Debug, Clone, PartialEq)]
pub struct OemEstimate {
    /// b_p, b_q, b_r (rad/s), b_ax, b_ay, b_az (m/s²), as in [`FlightPath::PARAMS`].
    pub biases: [f64; 6],
    /// Their Cramér–Rao standard deviations.
    pub bias_sd: [f64; 6],
    /// The initial states, in the order of [`OEM_STATES`].
    pub initial: [f64; 7],
    /// Their Cramér–Rao standard deviations.
    pub initial_sd: [f64; 7],
    /// √R: the estimated noise standard deviation of each output of [`OEM_OUTPUTS`].
    pub residual_sd: [f64; 7],
    /// The fitted outputs at the data's times.
    pub outputs: Vec<[f64; 7]>,
    /// The fitted states at the data's times, in the order of [`OEM_STATES`].
    pub states: Vec<[f64; 7]>,
    /// Gauss–Newton iterations.
    pub iterations: usize,
    /// `Converged`, `MaxIterations`, or `NumericalFailure` (a singular information matrix, or a
    /// step that does not decrease the cost).
    pub status: Status,
}

/// The states and outputs of one run of the kinematics, by time.
type Run = (Vec<[f64; 7]>, Vec<[f64; 7]>);

/// The inputs and outputs of a record, by time.
struct Record {
    times: Vec<f64>,
    inputs: Vec<[f64; 6]>,
    outputs: Vec<[f64; 7]>,
}

impl Record {
    /// The record of `data`, whose outputs must include [`OEM_INPUTS`] (finite at every time)
    /// and [`OEM_OUTPUTS`] (NaN where missing).
    fn new(data: &Dataset) -> Result<Record> {
        let column = |name: &str| {
            data.names.iter().position(|n| n == name).ok_or_else(|| Error::UnknownName {
                kind: "output of the flight record".into(),
                name: name.into(),
                known: data.names.clone(),
            })
        };
        let inputs: Vec<usize> = OEM_INPUTS.iter().map(|n| column(n)).collect::<Result<_>>()?;
        let outputs: Vec<usize> = OEM_OUTPUTS.iter().map(|n| column(n)).collect::<Result<_>>()?;
        if data.times.len() < 2 {
            return Err(Error::invalid("data", "the output-error method needs at least two samples"));
        }
        let mut rec = Record { times: data.times.clone(), inputs: Vec::new(), outputs: Vec::new() };
        for (t, row) in data.times.iter().zip(&data.values) {
            let u: [f64; 6] = std::array::from_fn(|i| row[inputs[i]]);
            if let Some(i) = u.iter().position(|v| !v.is_finite()) {
                return Err(Error::NonFinite {
                    what: format!("input `{}` of the output-error method at t = {t}", OEM_INPUTS[i]),
                });
            }
            rec.inputs.push(u);
            rec.outputs.push(std::array::from_fn(|i| row[outputs[i]]));
        }
        Ok(rec)
    }
}

/// The kinematics and outputs of the OEM for one observation geometry.
struct Kinematics<'a> {
    model: &'a FlightPath,
    observation: &'a FlightPathObservation,
}

impl Kinematics<'_> {
    /// The model's clean state at OEM state `y` and measured inputs `u`, corrected by `bias`:
    /// rates p = p_m − b_p, …; specific forces at the centre of gravity from the accelerometer's
    /// by removing its bias and lever-arm terms (the inverse of [`FlightPathObservation`]'s).
    fn clean(&self, y: &[f64; 7], u: &[f64; 6], bias: &[f64]) -> [f64; 16] {
        let mut z = [0.0; 16];
        for (k, &c) in CLEAN.iter().enumerate() {
            z[c] = y[k];
        }
        let (p, q, r) = (u[0] - bias[0], u[1] - bias[1], u[2] - bias[2]);
        let acc = self.observation.accelerometer;
        z[state::P] = p;
        z[state::Q] = q;
        z[state::R] = r;
        z[state::AX] = u[3] - bias[3] - (q * acc.z - r * acc.y);
        z[state::AY] = u[4] - bias[4] - (r * acc.x - p * acc.z);
        z[state::AZ] = u[5] - bias[5] - (p * acc.y - q * acc.x);
        z
    }

    /// ẏ at `y` with inputs `u`.
    fn rate(&self, y: &[f64; 7], u: &[f64; 6], bias: &[f64]) -> [f64; 7] {
        let z = self.clean(y, u, bias);
        let mut out = [0.0; 16];
        let coefficients = self.model.inertia.coefficients();
        rigid_body_kinematics(&coefficients, self.model.gravity, &z, &[0.0; 6], &mut out);
        std::array::from_fn(|k| out[CLEAN[k]])
    }

    /// The outputs of [`OEM_OUTPUTS`] at `y` with inputs `u`.
    fn outputs(&self, y: &[f64; 7], u: &[f64; 6], bias: &[f64]) -> [f64; 7] {
        let z = self.clean(y, u, bias);
        let mut theta = [0.0; 8];
        theta[..6].copy_from_slice(bias);
        let all = self.observation.outputs(&z, &theta);
        std::array::from_fn(|k| all[k])
    }

    /// The states and outputs at the record's times for unknowns `beta`; `None` where they
    /// stop being finite.
    fn simulate(&self, rec: &Record, beta: &[f64]) -> Option<Run> {
        let bias = &beta[..6];
        let mut y: [f64; 7] = std::array::from_fn(|k| beta[6 + k]);
        let (mut states, mut outputs) = (Vec::with_capacity(rec.times.len()), Vec::new());
        for k in 0..rec.times.len() {
            let out = self.outputs(&y, &rec.inputs[k], bias);
            if !(y.iter().chain(&out).all(|v| v.is_finite())) {
                return None;
            }
            states.push(y);
            outputs.push(out);
            if k + 1 < rec.times.len() {
                y = self.rk4(&y, (&rec.inputs[k], &rec.inputs[k + 1]), rec.times[k + 1] - rec.times[k], bias);
            }
        }
        Some((states, outputs))
    }

    /// One classical Runge–Kutta step of length `h` with inputs linear from `u0` to `u1`.
    fn rk4(&self, y: &[f64; 7], (u0, u1): (&[f64; 6], &[f64; 6]), h: f64, bias: &[f64]) -> [f64; 7] {
        let um: [f64; 6] = std::array::from_fn(|i| 0.5 * (u0[i] + u1[i]));
        let add =
            |a: &[f64; 7], b: &[f64; 7], s: f64| -> [f64; 7] { std::array::from_fn(|i| a[i] + s * b[i]) };
        let k1 = self.rate(y, u0, bias);
        let k2 = self.rate(&add(y, &k1, 0.5 * h), &um, bias);
        let k3 = self.rate(&add(y, &k2, 0.5 * h), &um, bias);
        let k4 = self.rate(&add(y, &k3, h), u1, bias);
        std::array::from_fn(|i| y[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]))
    }
}

/// The start: zero biases; attitude and altitude measured at the first sample; body velocities
/// from the measured airspeed V, α and β: u = V cos α cos β, v = V sin β, w = V sin α cos β.
fn start(rec: &Record) -> Result<[f64; UNKNOWNS]> {
    let first = |k: usize| {
        rec.outputs.iter().map(|o| o[k]).find(|v| v.is_finite()).ok_or_else(|| Error::NonFinite {
            what: format!("output `{}` (no finite sample to start the output-error method)", OEM_OUTPUTS[k]),
        })
    };
    let (v, a, b) = (first(0)?, first(1)?, first(2)?);
    let mut beta = [0.0; UNKNOWNS];
    beta[6..10].copy_from_slice(&[first(3)?, first(4)?, first(5)?, first(6)?]);
    beta[10..].copy_from_slice(&[v * a.cos() * b.cos(), v * b.sin(), v * a.sin() * b.cos()]);
    Ok(beta)
}

/// The magnitude below which unknown `j` counts as small: 0.01 for the biases (rad/s, m/s²),
/// 1 for the initial states.
fn scale(j: usize) -> f64 {
    if j < 6 {
        1e-2
    } else {
        1.0
    }
}

/// ½ Σ eᵀ R⁻¹ e over the present outputs, with `weight` = R⁻¹ (diagonal).
fn weighted_cost(rec: &Record, fitted: &[[f64; 7]], weight: &[f64; 7]) -> f64 {
    let mut j = 0.0;
    for (o, f) in rec.outputs.iter().zip(fitted) {
        for k in 0..7 {
            if o[k].is_finite() {
                j += 0.5 * weight[k] * (o[k] - f[k]).powi(2);
            }
        }
    }
    j
}

/// R⁻¹ from the residuals: 1 / the mean square residual per output (floored at 10⁻³⁰).
fn residual_weight(rec: &Record, fitted: &[[f64; 7]]) -> [f64; 7] {
    std::array::from_fn(|k| {
        let (mut s, mut n) = (0.0, 0usize);
        for (o, f) in rec.outputs.iter().zip(fitted) {
            if o[k].is_finite() {
                s += (o[k] - f[k]).powi(2);
                n += 1;
            }
        }
        1.0 / (s / n.max(1) as f64).max(1e-30)
    })
}

/// The information matrix M = Σ Sᵀ R⁻¹ S and the gradient g = Σ Sᵀ R⁻¹ e at `beta`, with the
/// sensitivities S = ∂ŷ/∂β by central differences; `None` if a perturbed run is not finite.
fn normal_equations(
    kin: &Kinematics,
    rec: &Record,
    beta: &[f64; UNKNOWNS],
    fitted: &[[f64; 7]],
    weight: &[f64; 7],
) -> Option<(DMatrix<f64>, DVector<f64>)> {
    let mut sens = Vec::with_capacity(UNKNOWNS);
    for j in 0..UNKNOWNS {
        let h = 1e-6 * beta[j].abs().max(scale(j));
        let (mut up, mut down) = (*beta, *beta);
        up[j] += h;
        down[j] -= h;
        let (_, yu) = kin.simulate(rec, &up)?;
        let (_, yd) = kin.simulate(rec, &down)?;
        let s: Vec<[f64; 7]> =
            yu.iter().zip(&yd).map(|(a, b)| std::array::from_fn(|k| (a[k] - b[k]) / (2.0 * h))).collect();
        sens.push(s);
    }
    let mut m = DMatrix::zeros(UNKNOWNS, UNKNOWNS);
    let mut g = DVector::zeros(UNKNOWNS);
    for (i, (o, f)) in rec.outputs.iter().zip(fitted).enumerate() {
        for k in (0..7).filter(|&k| o[k].is_finite()) {
            let e = o[k] - f[k];
            for a in 0..UNKNOWNS {
                let sa = sens[a][i][k] * weight[k];
                g[a] += sa * e;
                for b in 0..=a {
                    m[(a, b)] += sa * sens[b][i][k];
                }
            }
        }
    }
    m.fill_upper_triangle_with_lower_triangle();
    Some((m, g))
}

/// The output-error estimate of the biases and initial states of the flight path on `data`
/// (outputs named as [`FlightPathObservation::OUTPUTS`]; the rates and accelerations are the
/// inputs, the air data, attitude and altitude the fitted outputs), with the kinematics of
/// `model` and the sensor geometry of `observation` (its standard deviations are not used: R
/// is estimated).
///
/// Errors: a missing column ([`Error::UnknownName`]), a non-finite input, fewer than two
/// samples, or a start at which the kinematics are not finite. Non-convergence is the
/// estimate's status.
pub fn output_error(
    model: &FlightPath,
    observation: &FlightPathObservation,
    data: &Dataset,
    options: &OemOptions,
) -> Result<OemEstimate> {
    let rec = Record::new(data)?;
    let kin = Kinematics { model, observation };
    let mut beta = start(&rec)?;
    let (mut states, mut fitted) = kin.simulate(&rec, &beta).ok_or_else(|| Error::NonFinite {
        what: "the kinematics at the output-error method's start".into(),
    })?;
    let mut status = Status::MaxIterations;
    let mut iterations = 0;
    let mut info = None;
    while iterations < options.max_iterations {
        iterations += 1;
        let weight = residual_weight(&rec, &fitted);
        let Some((m, g)) = normal_equations(&kin, &rec, &beta, &fitted, &weight) else {
            status = Status::NumericalFailure;
            break;
        };
        let Some(chol) = m.clone().cholesky() else {
            status = Status::NumericalFailure;
            break;
        };
        let step = chol.solve(&g);
        let inverse = chol.inverse();
        info = Some(inverse.clone());
        let small = (0..UNKNOWNS).all(|j| step[j].abs() <= options.tolerance * inverse[(j, j)].sqrt());
        let before = weighted_cost(&rec, &fitted, &weight);
        let mut accepted = false;
        let mut alpha = 1.0;
        for _ in 0..20 {
            let trial: [f64; UNKNOWNS] = std::array::from_fn(|j| beta[j] + alpha * step[j]);
            if let Some((s, f)) = kin.simulate(&rec, &trial) {
                if weighted_cost(&rec, &f, &weight) <= before {
                    (beta, states, fitted, accepted) = (trial, s, f, true);
                    break;
                }
            }
            alpha *= 0.5;
        }
        // With outputs that fit to round-off, no step decreases the cost: converged when the
        // step is within round-off of β.
        let stagnant =
            !accepted && (0..UNKNOWNS).all(|j| step[j].abs() <= 1e-6 * beta[j].abs().max(scale(j)));
        if small || stagnant {
            status = Status::Converged;
            break;
        }
        if !accepted {
            status = Status::NumericalFailure;
            break;
        }
    }
    let weight = residual_weight(&rec, &fitted);
    let sd = |j: usize| info.as_ref().map_or(f64::NAN, |i: &DMatrix<f64>| i[(j, j)].sqrt());
    Ok(OemEstimate {
        biases: std::array::from_fn(|j| beta[j]),
        bias_sd: std::array::from_fn(sd),
        initial: std::array::from_fn(|k| beta[6 + k]),
        initial_sd: std::array::from_fn(|k| sd(6 + k)),
        residual_sd: std::array::from_fn(|k| weight[k].recip().sqrt()),
        outputs: fitted,
        states,
        iterations,
        status,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::library::FlightPathSetup;
    use rand::rngs::StdRng;
    use rand::SeedableRng;

    /// A synthetic record of the flight-path model (10 s) and its true path; with `noise`
    /// false the outputs are the noise-free ones.
    fn record(seed: u64, noise: bool) -> (FlightPathSetup, Dataset, crate::data::StatePath) {
        let mut setup = FlightPathSetup::new();
        setup.t_end = 10.0;
        let mut rng = StdRng::seed_from_u64(seed);
        let (path, mut data) = setup.simulate(&mut rng).unwrap();
        if !noise {
            for (t, row) in data.times.iter().zip(data.values.iter_mut()) {
                let i = path.times.iter().position(|s| (s - t).abs() < 1e-9).unwrap();
                let z = &path.values[i][6..];
                *row = setup.observation.outputs(z, &setup.theta).to_vec();
            }
        }
        (setup, data, path)
    }

    #[test]
    fn noise_free_outputs_give_the_true_biases_and_initial_states() {
        let (setup, data, path) = record(1, false);
        let est = output_error(&setup.model, &setup.observation, &data, &OemOptions::default()).unwrap();
        assert_eq!(
            est.status,
            Status::Converged,
            "{:?} {:?} after {}",
            est.biases,
            est.bias_sd,
            est.iterations
        );
        for j in 0..6 {
            let scale = if j < 3 { 1e-3 } else { 1e-2 };
            assert!(
                (est.biases[j] - setup.theta[j]).abs() < 0.05 * scale,
                "{}: {} against {}",
                FlightPath::PARAMS[j],
                est.biases[j],
                setup.theta[j]
            );
        }
        let z0 = &path.values[0][6..];
        for (k, &c) in CLEAN.iter().enumerate() {
            assert!((est.initial[k] - z0[c]).abs() < 1e-3 * (1.0 + z0[c].abs()), "{}", OEM_STATES[k]);
        }
    }

    /// The Cramér–Rao sds ignore the noise of the inputs. Integrated, rate or acceleration
    /// noise of sd σ per sample (step Δ) makes the estimated slope of a bias scatter by about
    /// σ√(3Δ/T) over a record of length T (the least-squares slope of a random walk): on
    /// 10 s records 2–4 times the Cramér–Rao sd. Each bias must lie within 4 of the combined sd.
    #[test]
    fn noisy_outputs_give_biases_within_their_spread() {
        let (setup, data, _) = record(2, true);
        let est = output_error(&setup.model, &setup.observation, &data, &OemOptions::default()).unwrap();
        assert_eq!(
            est.status,
            Status::Converged,
            "{:?} {:?} after {}",
            est.biases,
            est.bias_sd,
            est.iterations
        );
        let sd = setup.observation.sd.per_output();
        let span = 3.0 * setup.sample_every / setup.t_end;
        for j in 0..6 {
            let input = sd[7 + j] * span.sqrt();
            let combined = est.bias_sd[j].hypot(input);
            assert!(
                (est.biases[j] - setup.theta[j]).abs() < 4.0 * combined,
                "{}: {} ± {} (inputs {input}) against {}",
                FlightPath::PARAMS[j],
                est.biases[j],
                est.bias_sd[j],
                setup.theta[j]
            );
        }
    }

    #[test]
    fn a_missing_input_channel_is_named() {
        let (setup, mut data, _) = record(3, false);
        data.names[8] = "pitch".into();
        let err = output_error(&setup.model, &setup.observation, &data, &OemOptions::default()).unwrap_err();
        assert!(err.to_string().contains("q_m"), "{err}");
        let (setup, mut data, _) = record(3, false);
        data.values[5][7] = f64::NAN;
        let err = output_error(&setup.model, &setup.observation, &data, &OemOptions::default()).unwrap_err();
        assert!(err.to_string().contains("`p_m`") && err.to_string().contains("t = 0.2"), "{err}");
    }
}
