//! Every estimator by name, with one set of options: the single entry point shared by
//! `onsager estimate`, `onsager compare` and the experiment runner, so that the methods run on
//! equal terms wherever they are called from.
//!
//! ```
//! use onsager::methods::{run, Method, MethodOptions};
//! use onsager::model::library::preset;
//! use onsager::simulate::{sample_measurements, simulate, SimulateOptions};
//! use rand::SeedableRng;
//!
//! let p = preset("double-well")?;
//! let mut rng = rand::rngs::StdRng::seed_from_u64(1);
//! let truth = simulate(&p.model, &p.theta, &[1.0], &[], &SimulateOptions::new(0.0, 4.0, 0.01), &mut rng)?;
//! let data = sample_measurements(&p.observation, &p.theta, &truth, 1, 0.5, &mut rng)?;
//! let problem = p.problem(&data, &[]);
//! let run = run(Method::Uks, &problem, &MethodOptions::default())?;
//! assert_eq!(run.estimate.method, "uks");
//! # Ok::<(), onsager::Error>(())
//! ```

use std::fmt;
use std::str::FromStr;

use rand::rngs::StdRng;
use rand::SeedableRng;
use serde::{Deserialize, Serialize};

use crate::action::exact::check_grid_covers;
use crate::action::fokker_planck::check_model_fits_grid;
use crate::action::{
    closure_estimate, ksp_path_estimate, ksp_smoother, mean_optimal, mean_optimal_path_estimate, ClosureKind,
    ClosureOptions, ExactOptions, Grid, GridSpec,
};
use crate::estimate::{EstimationProblem, PathEstimate};
use crate::kalman::{self, KalmanMethod, KalmanOptions, PemOptions};
use crate::model::observation::StateMeasurement;
use crate::model::Sde;
use crate::particle::{self, ParticleOptions};
use crate::path::{
    self, estimate_path, regression_theta_guess, spline_guess, Merit, PathOptions, Transcription,
};
use crate::{Error, Result};

/// The estimators of the library, by their command-line names.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
#[non_exhaustive]
pub enum Method {
    /// Exact Kushner–Stratonovich–Pardoux smoother on a grid (`003_d2fc48a470e528fc.txt (0.3)–(0.7)`).
    Ksp,
    /// Exact mean-optimal (effective-action) estimator on a grid (`003 (I.60)–(I.76)`).
    MeanOptimal,
    /// Continuous-discrete extended Kalman filter.
    Ekf,
    /// Extended Rauch–Tung–Striebel smoother.
    Eks,
    /// Continuous-discrete unscented Kalman filter.
    Ukf,
    /// Unscented Rauch–Tung–Striebel smoother.
    Uks,
    /// Prediction error method (UKF likelihood) followed by the UKS at θ̂.
    Pem,
    /// Bootstrap particle filter with a backward-simulation smoother.
    Particle,
    /// Joint Onsager–Machlup MAP path and parameters (`000_74b95e149527c64e.txt (2.49)–(2.51)`).
    Jme,
    /// Minimum-energy path and parameters (`000 (2.58)–(2.60)`).
    Mee,
    /// Gaussian Rayleigh–Ritz closure of the mean-optimal estimator (`003 (II.36)–(II.53)`).
    GaussianClosure,
    /// Exponential-family closure: the polynomial moments of total degree `moments` (1-D: x, …, x^moments;
    /// 2-D: the monomials x^i y^j, i + j ≤ moments) (`003 (II.36)–(II.53)`).
    ExpClosure,
    /// Closure of the KSP smoother (`003 (II.64)–(II.65)`).
    KspClosure,
    /// Double-exponential closure (`003 (II.54)–(II.63)`).
    DoubleExpClosure,
}

impl Method {
    /// Every method, in the order of the tables.
    pub const ALL: [Method; 14] = [
        Method::Ksp,
        Method::MeanOptimal,
        Method::GaussianClosure,
        Method::ExpClosure,
        Method::KspClosure,
        Method::DoubleExpClosure,
        Method::Jme,
        Method::Mee,
        Method::Ekf,
        Method::Eks,
        Method::Ukf,
        Method::Uks,
        Method::Pem,
        Method::Particle,
    ];

    /// The command-line name (also the `method` of the [`PathEstimate`]).
    pub fn name(self) -> &'static str {
        match self {
            Method::Ksp => "ksp",
            Method::MeanOptimal => "mean-optimal",
            Method::Ekf => "ekf",
            Method::Eks => "eks",
            Method::Ukf => "ukf",
            Method::Uks => "uks",
            Method::Pem => "pem",
            Method::Particle => "particle",
            Method::Jme => "jme",
            Method::Mee => "mee",
            Method::GaussianClosure => "gaussian-closure",
            Method::ExpClosure => "exp-closure",
            Method::KspClosure => "ksp-closure",
            Method::DoubleExpClosure => "double-exp-closure",
        }
    }

    /// One line describing the method.
    pub fn description(self) -> &'static str {
        match self {
            Method::Ksp => "exact Kushner-Stratonovich-Pardoux smoother on a grid (003 eq. 0.3-0.7)",
            Method::MeanOptimal => {
                "exact mean-optimal (effective-action) estimator on a grid (003 I.60-I.76)"
            }
            Method::Ekf => "continuous-discrete extended Kalman filter",
            Method::Eks => "extended Rauch-Tung-Striebel smoother",
            Method::Ukf => "continuous-discrete unscented Kalman filter",
            Method::Uks => "unscented Rauch-Tung-Striebel smoother",
            Method::Pem => "prediction error method (UKF likelihood), then the UKS at the estimate",
            Method::Particle => "bootstrap particle filter with a backward-simulation smoother",
            Method::Jme => "joint Onsager-Machlup MAP path and parameters (000 eq. 2.49-2.51)",
            Method::Mee => "minimum-energy path and parameters (000 eq. 2.58-2.60)",
            Method::GaussianClosure => {
                "Gaussian Rayleigh-Ritz closure of the mean-optimal estimator (003 II.36-II.53)"
            }
            Method::ExpClosure => "exponential-family closure, polynomial moments up to degree `moments`, 1-D or 2-D (003 II.36-II.53)",
            Method::KspClosure => "closure of the KSP smoother (003 II.64-II.65)",
            Method::DoubleExpClosure => "double-exponential closure (003 II.54-II.63)",
        }
    }

    /// Whether the method runs on a state-space grid (one or two noisy states).
    pub fn uses_grid(self) -> bool {
        matches!(self, Method::Ksp | Method::MeanOptimal)
    }

    /// Whether the method is a Rayleigh–Ritz closure.
    pub fn is_closure(self) -> bool {
        matches!(
            self,
            Method::GaussianClosure | Method::ExpClosure | Method::KspClosure | Method::DoubleExpClosure
        )
    }

    /// Whether the method estimates parameters (`--estimate`); the others take θ as given.
    pub fn estimates_parameters(self) -> bool {
        matches!(self, Method::Jme | Method::Mee | Method::Pem)
    }
}

impl fmt::Display for Method {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Method {
    type Err = Error;

    fn from_str(s: &str) -> Result<Method> {
        Method::ALL.into_iter().find(|m| m.name() == s.trim()).ok_or_else(|| Error::UnknownName {
            kind: "method".into(),
            name: s.trim().into(),
            known: Method::ALL.iter().map(|m| m.name().to_string()).collect(),
        })
    }
}

/// The options of every method; each method reads the ones that concern it and rejects, with an
/// error, the ones that do not (a flag must never be silently ignored).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
#[non_exhaustive]
pub struct MethodOptions {
    /// Grid of the exact methods (`lo=L,hi=H,cells=N`; two states `lo=L1;L2,hi=H1;H2,cells=N1;N2`).
    /// Default: [`default_grid`].
    pub grid: Option<String>,
    /// Time step of the method's time integration (grid, Kalman and particle methods).
    pub dt: Option<f64>,
    /// Number of particles of the particle smoother.
    pub particles: Option<usize>,
    /// Transcription of the path-space MAP methods: `hermite-simpson` (default), `trapezoidal`,
    /// `euler`.
    pub transcription: Option<String>,
    /// Step of the path-space MAP transcription (default: measurement spacing / 20).
    pub step: Option<f64>,
    /// Seed of the methods that draw random numbers (the particle smoother).
    pub seed: u64,
    /// Parameters whose given values are kept as the initial guess of a joint estimate (otherwise
    /// the regression guess of 000 Sec. 4.1 replaces the preset value).
    pub keep_initial: Vec<String>,
    /// Degree of the exponential closure's moments (default 4: the quartic family).
    pub moments: Option<usize>,
    /// Gauss–Hermite points per dimension of the Gaussian closures (`gaussian-closure`,
    /// `ksp-closure`, `double-exp-closure`); default automatic (see
    /// [`ClosureOptions::gaussian_points`]).
    pub gaussian_points: Option<usize>,
    /// Largest number of node states for which the path methods compute the Laplace sd
    /// (default 4000; 0 switches it off).
    pub laplace_max_states: Option<usize>,
}

impl MethodOptions {
    /// The options that `method` does not read but that are set: each is an error.
    fn check_applicable(&self, method: Method) -> Result<()> {
        let reject = |name: &str, applies: &str| -> Result<()> {
            Err(Error::InvalidOption {
                name: name.into(),
                reason: format!("is an option of {applies}, not of `{method}`"),
            })
        };
        if self.grid.is_some() && !method.uses_grid() {
            return reject("grid", "the grid methods (ksp, mean-optimal)");
        }
        if self.particles.is_some() && method != Method::Particle {
            return reject("particles", "`particle`");
        }
        let path = matches!(method, Method::Jme | Method::Mee);
        if self.transcription.is_some() && !path {
            return reject("transcription", "the path-space MAP methods (jme, mee)");
        }
        if self.step.is_some() && !path {
            return reject("step", "the path-space MAP methods (jme, mee)");
        }
        if self.moments.is_some() && method != Method::ExpClosure {
            return reject("moments", "`exp-closure`");
        }
        let gaussian =
            matches!(method, Method::GaussianClosure | Method::KspClosure | Method::DoubleExpClosure);
        if self.gaussian_points.is_some() && !gaussian {
            return reject(
                "gaussian points",
                "the Gaussian closures (gaussian-closure, ksp-closure, double-exp-closure)",
            );
        }
        if self.laplace_max_states.is_some() && !path {
            return reject("laplace_max_states", "the path-space MAP methods (jme, mee)");
        }
        if self.dt.is_some() && (path || method.is_closure()) {
            return reject("dt", "the grid, Kalman and particle methods");
        }
        if let Some(dt) = self.dt {
            if !(dt.is_finite() && dt > 0.0) {
                return Err(Error::InvalidOption {
                    name: "dt".into(),
                    reason: format!("must be > 0, got {dt}"),
                });
            }
        }
        Ok(())
    }
}

/// A method's estimate with the notes a user should read (e.g. what a transcription converges
/// to, or a skipped computation). The library does not print them; the CLI does.
#[derive(Debug, Clone)]
pub struct MethodRun {
    /// The estimate.
    pub estimate: PathEstimate,
    /// Notes for the user.
    pub notes: Vec<String>,
}

/// The default grid of the exact methods when none is given: every state must be measured
/// directly; each axis spans the data range widened by a quarter of it and by four measurement
/// sd on each side (and by at least 0.5), with 400 cells in one dimension and 120 per axis in two.
///
/// Errors: [`Error::InvalidOption`] (name `grid`) when a state is not measured or the model has
/// more than two states.
pub fn default_grid<S: Sde + ?Sized>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
) -> Result<GridSpec> {
    let n = problem.sde.dims().states();
    let need = |why: String| Error::InvalidOption {
        name: "grid".into(),
        reason: format!("{why}; give one, e.g. `lo=-2.5,hi=2.5,cells=500`"),
    };
    if n > 2 {
        return Err(need(format!("the grid methods take one or two states, the model has {n}")));
    }
    let sd = problem.observation.noise.gaussian_sd(problem.theta).unwrap_or(0.0);
    let (mut lo, mut hi) = (vec![0.0; n], vec![0.0; n]);
    for a in 0..n {
        let column = problem.observation.states.iter().position(|&s| s == a).ok_or_else(|| {
            need(format!("state `{}` is not measured, so no default grid", problem.sde.state_names()[a]))
        })?;
        let values = problem.data.values.iter().map(|row| row[column]).filter(|y| y.is_finite());
        let (min, max) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), y| (l.min(y), h.max(y)));
        if !(min.is_finite() && max.is_finite()) {
            return Err(need(format!("no finite data of state `{}`", problem.sde.state_names()[a])));
        }
        let margin = (0.25 * (max - min) + 4.0 * sd).max(0.5);
        lo[a] = min - margin;
        hi[a] = max + margin;
    }
    let cells = if n == 1 { vec![400] } else { vec![120; n] };
    Ok(GridSpec { lo, hi, cells })
}

/// Runs `method` on `problem` with `options`.
///
/// Errors: an option the method does not take; those of the method (bad grid, non-Gaussian
/// likelihood for the mean-optimal estimator, parameters to estimate for a method that takes θ
/// as given, …). A numerical failure is not an error: it is the estimate's status.
pub fn run<S: Sde + ?Sized>(
    method: Method,
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    options: &MethodOptions,
) -> Result<MethodRun> {
    options.check_applicable(method)?;
    if !problem.estimate.is_empty() && !method.estimates_parameters() {
        return Err(Error::InvalidOption {
            name: "estimate".into(),
            reason: format!("`{method}` takes the parameters as given; jme, mee and pem estimate them"),
        });
    }
    let mut notes = Vec::new();
    let estimate = match method {
        Method::Ksp | Method::MeanOptimal => run_grid(method, problem, options, &mut notes)?,
        Method::Ekf | Method::Eks | Method::Ukf | Method::Uks => {
            let kalman_method = match method {
                Method::Ekf => KalmanMethod::Ekf,
                Method::Eks => KalmanMethod::Eks,
                Method::Ukf => KalmanMethod::Ukf,
                _ => KalmanMethod::Uks,
            };
            kalman::estimate(problem, kalman_method, &kalman_options(options))?
        }
        Method::Pem => kalman::pem(problem, &PemOptions::default().with_kalman(kalman_options(options)))?,
        Method::Particle => {
            let mut particle_options = ParticleOptions::default();
            if let Some(n) = options.particles {
                particle_options = particle_options.with_particles(n);
            }
            if let Some(dt) = options.dt {
                particle_options = particle_options.with_dt(dt);
            }
            let mut rng = StdRng::seed_from_u64(options.seed);
            particle::estimate(problem, &particle_options, &mut rng)?
        }
        Method::Jme | Method::Mee => run_path(method, problem, options, &mut notes)?,
        Method::GaussianClosure | Method::ExpClosure | Method::KspClosure | Method::DoubleExpClosure => {
            let kind = ClosureKind::parse(method.name(), options.moments)?;
            let mut closure_options = ClosureOptions::new();
            closure_options.gaussian_points = options.gaussian_points;
            closure_estimate(problem, &kind, &closure_options)?
        }
    };
    Ok(MethodRun { estimate, notes })
}

fn kalman_options(options: &MethodOptions) -> KalmanOptions {
    match options.dt {
        Some(dt) => KalmanOptions::default().with_dt(dt),
        None => KalmanOptions::default(),
    }
}

fn run_grid<S: Sde + ?Sized>(
    method: Method,
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    options: &MethodOptions,
    notes: &mut Vec<String>,
) -> Result<PathEstimate> {
    let spec = match &options.grid {
        Some(spec) => GridSpec::parse(spec)?,
        None => {
            let spec = default_grid(problem)?;
            notes.push(format!(
                "grid lo={},hi={},cells={} (the default: data range with margins)",
                join(&spec.lo),
                join(&spec.hi),
                spec.cells.iter().map(|c| c.to_string()).collect::<Vec<_>>().join(";")
            ));
            spec
        }
    };
    let mut exact = ExactOptions::new(spec.clone());
    if let Some(dt) = options.dt {
        exact = exact.with_dt(dt);
    }
    let grid = Grid::try_new(spec)?;
    check_model_fits_grid(problem.sde, &grid)?;
    check_grid_covers(&grid, problem.observation, problem.data)?;
    if method == Method::Ksp {
        Ok(ksp_path_estimate(problem, &ksp_smoother(problem, &exact)?))
    } else {
        Ok(mean_optimal_path_estimate(problem, &mean_optimal(problem, &exact)?))
    }
}

fn join(v: &[f64]) -> String {
    v.iter().map(|x| format!("{x:.4}")).collect::<Vec<_>>().join(";")
}

fn run_path<S: Sde + ?Sized>(
    method: Method,
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    options: &MethodOptions,
    notes: &mut Vec<String>,
) -> Result<PathEstimate> {
    let merit = if method == Method::Jme { Merit::OnsagerMachlup } else { Merit::Energy };
    let transcription = match &options.transcription {
        Some(name) => Transcription::parse(name)?,
        None => Transcription::HermiteSimpson,
    };
    match (transcription, merit) {
        (Transcription::Euler, Merit::OnsagerMachlup) => notes.push(
            "the Euler MAP path converges to the minimum-energy path, not the Onsager-Machlup one (001 Thm 18)"
                .into(),
        ),
        (Transcription::Trapezoidal, Merit::Energy) => notes.push(
            "the trapezoidal MAP path converges to the Onsager-Machlup path, not the minimum-energy one \
             (001 Thm 18)"
                .into(),
        ),
        _ => {}
    }
    let t0 = problem.t0;
    let step = options.step.unwrap_or_else(|| path::default_step(t0, problem.data));
    if !(step.is_finite() && step > 0.0) {
        return Err(Error::InvalidOption { name: "step".into(), reason: format!("must be > 0, got {step}") });
    }
    let t_end = problem.data.times.last().copied().unwrap_or(t0);
    let nodes = ((t_end - t0) / step).round().max(1.0) as usize;
    let times: Vec<f64> = (0..=nodes).map(|k| t0 + k as f64 * step).collect();
    let names = problem.sde.param_names();
    for name in &options.keep_initial {
        if !names.contains(name) {
            return Err(Error::UnknownName { kind: "parameter".into(), name: name.clone(), known: names });
        }
    }
    let mut theta = problem.theta.to_vec();
    if !problem.estimate.is_empty() {
        let g = regression_theta_guess(
            problem.sde,
            problem.observation,
            problem.theta,
            problem.theta_prior,
            problem.estimate,
            problem.data,
        )?;
        for &i in problem.estimate {
            if !options.keep_initial.contains(&names[i]) {
                theta[i] = g.theta[i];
            }
        }
    }
    let problem = &EstimationProblem { theta: &theta, ..*problem };
    let guess = spline_guess(problem.sde, problem.theta, &problem.observation.states, problem.data, &times)?;
    let mut path_options = PathOptions::new(merit, transcription).with_step(step).with_initial_path(guess);
    let max_states = options.laplace_max_states.unwrap_or(4000);
    let states = nodes * problem.sde.dims().states();
    if states > max_states {
        notes.push(format!("skipping the Laplace sd ({states} node states > {max_states})"));
        path_options = path_options.with_laplace(false);
    }
    Ok(estimate_path(problem, path_options)?.estimate)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::library::preset;
    use crate::simulate::{sample_measurements, simulate, SimulateOptions};

    #[test]
    fn names_round_trip_and_unknown_names_are_errors() {
        for m in Method::ALL {
            assert_eq!(m.name().parse::<Method>().unwrap(), m);
            assert_eq!(serde_json::to_string(&m).unwrap(), format!("\"{}\"", m.name()));
        }
        let e = "kalman".parse::<Method>().unwrap_err().to_string();
        assert!(e.contains("kalman") && e.contains("mean-optimal"), "{e}");
    }

    #[test]
    fn options_a_method_does_not_take_are_errors() {
        let p = preset("double-well").unwrap();
        let mut rng = StdRng::seed_from_u64(3);
        let truth =
            simulate(&p.model, &p.theta, &[1.0], &[], &SimulateOptions::new(0.0, 4.0, 0.01), &mut rng)
                .unwrap();
        let data = sample_measurements(&p.observation, &p.theta, &truth, 1, 0.5, &mut rng).unwrap();
        let problem = p.problem(&data, &[]);
        let cases = [
            (Method::Uks, MethodOptions { particles: Some(10), ..Default::default() }, "particles"),
            (Method::Ksp, MethodOptions { step: Some(0.1), ..Default::default() }, "step"),
            (Method::Jme, MethodOptions { dt: Some(0.1), ..Default::default() }, "dt"),
            (
                Method::Jme,
                MethodOptions { grid: Some("lo=-1,hi=1,cells=9".into()), ..Default::default() },
                "grid",
            ),
            (Method::Ekf, MethodOptions { dt: Some(-1.0), ..Default::default() }, "dt"),
            (
                Method::ExpClosure,
                MethodOptions { gaussian_points: Some(3), ..Default::default() },
                "gaussian points",
            ),
            (
                Method::GaussianClosure,
                MethodOptions { gaussian_points: Some(0), ..Default::default() },
                "gaussian points",
            ),
        ];
        for (method, options, name) in cases {
            match run(method, &problem, &options) {
                Err(Error::InvalidOption { name: n, .. }) => assert_eq!(n, name),
                other => panic!("{method} with {name}: expected an error, got {other:?}"),
            }
        }
        let theta_index = p.param_index(&p.model.param_names()[0]).unwrap();
        let estimate = [theta_index];
        let problem = p.problem(&data, &estimate);
        assert!(matches!(
            run(Method::Ukf, &problem, &MethodOptions::default()),
            Err(Error::InvalidOption { ref name, .. }) if name == "estimate"
        ));
    }

    #[test]
    fn default_grid_covers_the_data_and_runs() {
        let p = preset("double-well").unwrap();
        let mut rng = StdRng::seed_from_u64(5);
        let truth =
            simulate(&p.model, &p.theta, &[1.0], &[], &SimulateOptions::new(0.0, 6.0, 0.01), &mut rng)
                .unwrap();
        let data = sample_measurements(&p.observation, &p.theta, &truth, 1, 1.0, &mut rng).unwrap();
        let problem = p.problem(&data, &[]);
        let spec = default_grid(&problem).unwrap();
        let min = data.values.iter().map(|r| r[0]).fold(f64::INFINITY, f64::min);
        let max = data.values.iter().map(|r| r[0]).fold(f64::NEG_INFINITY, f64::max);
        assert!(spec.lo[0] < min - 0.5 && spec.hi[0] > max + 0.5);
        let run = run(Method::Ksp, &problem, &MethodOptions::default()).unwrap();
        assert!(run.estimate.status.is_success());
        assert_eq!(run.notes.len(), 1);
        // Duffing's velocity is not measured: no default grid.
        let d = preset("duffing").unwrap();
        let truth =
            simulate(&d.model, &d.theta, &[0.0], &[1.0], &SimulateOptions::new(0.0, 2.0, 0.01), &mut rng)
                .unwrap();
        let data = sample_measurements(&d.observation, &d.theta, &truth, 1, 0.5, &mut rng).unwrap();
        let e = default_grid(&d.problem(&data, &[])).unwrap_err().to_string();
        assert!(e.contains("not measured"), "{e}");
    }
}
