//! The path-space MAP estimators `jme` and `mee` as estimators: the spline initial guess, the
//! regression guess of the estimated parameters, the transcription grid and the notes on what
//! a transcription converges to.

use serde::{Deserialize, Serialize};

use super::{
    default_step, estimate_path, regression_theta_guess, spline_guess, Laplace, LaplaceSd, Merit,
    PathDetails, PathOptions, Transcription,
};
use crate::data::StatePath;
use crate::estimate::{flag_degenerate, Details, EstimationProblem, Method, MethodRun, Status};
use crate::estimator::EstimatorOptions;
use crate::kalman::{KalmanMethod, KalmanOptions};
use crate::model::observation::StateMeasurement;
use crate::model::Sde;
use crate::{Error, Result};

/// Options of the path-space MAP estimators `jme` and `mee`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
#[non_exhaustive]
pub struct MapOptions {
    /// The transcription. Default `hermite-simpson`; `euler` converges to the minimum-energy
    /// path and `trapezoidal` to the Onsager–Machlup path whatever the merit
    /// (`001_8aefdf0570c96f51.txt` Thm 18).
    pub transcription: Transcription,
    /// The step of the transcription grid. Default: the shortest spacing of t0 and the
    /// measurement times / 20.
    pub step: Option<f64>,
    /// Largest number of node states (nodes × states) for which the Laplace standard deviations
    /// are computed. Default 4000; 0 switches them off.
    pub laplace_max_states: usize,
    /// Parameters whose given values are the initial guess of a joint estimate; the others to
    /// estimate start from the regression guess of `000_74b95e149527c64e.txt` Sec. 4.1. Default
    /// none (the command line fills it from `--param`).
    pub keep_initial: Vec<String>,
    /// Iteration limit of the interior-point solver. Default `None`: the solver's (3000).
    pub max_iterations: Option<usize>,
    /// Tolerance of the interior-point solver on its scaled optimality error. Default `None`:
    /// the solver's (1e-8).
    pub tolerance: Option<f64>,
    /// Where the solver starts the path. Default [`PathStart::Spline`].
    pub start: PathStart,
}

/// The initial path of the interior-point solver (docs/map.md, "The initial path").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PathStart {
    /// Smoothing splines through the measured states ([`spline_guess`]); the other states at
    /// zero, except derivatives of measured states.
    #[default]
    Spline,
    /// The path of the unscented RTS smoother with the initial θ (one Kalman pass; Gaussian
    /// likelihoods only): for models whose unmeasured states a zero start puts in the wrong
    /// basin, e.g. Lorenz-63 with x alone measured.
    Uks,
}

impl Default for MapOptions {
    fn default() -> Self {
        MapOptions {
            transcription: Transcription::HermiteSimpson,
            step: None,
            laplace_max_states: 4000,
            keep_initial: Vec::new(),
            max_iterations: None,
            tolerance: None,
            start: PathStart::Spline,
        }
    }
}

impl EstimatorOptions for MapOptions {
    /// `jme` (the Onsager–Machlup merit) or `mee` (the energy merit): [`map_estimate`].
    fn run<S: Sde + ?Sized>(
        &self,
        method: Method,
        problem: &EstimationProblem<'_, S, StateMeasurement>,
    ) -> Result<MethodRun> {
        let merit = if method == Method::Mee { Merit::Energy } else { Merit::OnsagerMachlup };
        map_estimate(problem, merit, self)
    }

    /// Checks a positive finite `step` and `tolerance`.
    fn validate(&self) -> Result<()> {
        crate::error::check_positive("step", self.step)?;
        crate::error::check_positive("tolerance", self.tolerance)
    }
}

/// What a transcription converges to when it is not the merit's own (`001` Thm 18).
fn convergence_note(transcription: Transcription, merit: Merit) -> Option<&'static str> {
    match (transcription, merit) {
        (Transcription::Euler, Merit::OnsagerMachlup) => Some(
            "the Euler MAP path converges to the minimum-energy path, not the Onsager-Machlup one (001 Thm 18)",
        ),
        (Transcription::Trapezoidal, Merit::Energy) => Some(
            "the trapezoidal MAP path converges to the Onsager-Machlup path, not the minimum-energy one \
             (001 Thm 18)",
        ),
        _ => None,
    }
}

/// The MAP path of `merit` (`jme`: Onsager–Machlup, `mee`: energy) and the estimated parameters
/// of `problem` (`000_74b95e149527c64e.txt (2.49)–(2.51)`, `(2.58)–(2.60)`), from the initial
/// path of [`MapOptions::start`] and, for the parameters to estimate, the regression guess (except
/// those in [`MapOptions::keep_initial`]). Notes: what the transcription converges to, and a
/// skipped Laplace sd.
///
/// Errors: those of [`estimate_path`] and [`regression_theta_guess`]; an unknown name in
/// `keep_initial`.
pub fn map_estimate<S: Sde + ?Sized>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    merit: Merit,
    options: &MapOptions,
) -> Result<MethodRun> {
    options.validate()?;
    let mut notes: Vec<String> =
        convergence_note(options.transcription, merit).into_iter().map(String::from).collect();
    let t0 = problem.t0;
    let step = options.step.unwrap_or_else(|| default_step(t0, problem.data));
    super::check_path_memory(problem, step)?;
    let t_end = problem.data.times.last().copied().unwrap_or(t0);
    let nodes = ((t_end - t0) / step).round().max(1.0) as usize;
    let times: Vec<f64> = (0..=nodes).map(|k| t0 + k as f64 * step).collect();
    let names = problem.sde.param_names();
    if let Some(name) = options.keep_initial.iter().find(|n| !names.contains(n)) {
        return Err(Error::UnknownName { kind: "parameter".into(), name: name.clone(), known: names });
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
    let guess = match options.start {
        PathStart::Spline => {
            spline_guess(problem.sde, problem.theta, &problem.observation.states, problem.data, &times)?
        }
        PathStart::Uks => {
            let uks = crate::kalman::estimate(problem, KalmanMethod::Uks, &KalmanOptions::default())
                .map_err(|e| Error::InvalidOption {
                    name: "start".into(),
                    reason: format!("`uks` starts from the UKS path, which failed: {e}"),
                })?;
            StatePath { sd: None, ..uks.path }
        }
    };
    let mut path_options =
        PathOptions::new(merit, options.transcription).with_step(step).with_initial_path(guess);
    path_options.nlp.max_iterations = options.max_iterations.unwrap_or(path_options.nlp.max_iterations);
    if let Some(tolerance) = options.tolerance {
        // The acceptable level is never stricter than the requested one.
        path_options.nlp.tolerance = tolerance;
        path_options.nlp.acceptable_tolerance = path_options.nlp.acceptable_tolerance.max(tolerance);
    }
    let states = nodes * problem.sde.dims().states();
    let skipped = states > options.laplace_max_states;
    if skipped {
        notes
            .push(format!("skipping the Laplace sd ({states} node states > {})", options.laplace_max_states));
        path_options = path_options.with_laplace(Laplace::Off);
    }
    let mut estimate = estimate_path(problem, path_options)?.estimate;
    if skipped {
        // The reason reaches the report and the figures with the estimate.
        if let Some(details) = estimate.details.get::<PathDetails>() {
            let sd = LaplaceSd::Skipped { node_states: states, max_states: options.laplace_max_states };
            estimate.details = Details::new(PathDetails { sd, ..details.clone() });
        }
    }
    let names = problem.sde.param_names();
    if options.transcription != Transcription::HermiteSimpson && estimate.status.is_success() {
        // HS refuses these parameters before solving (`check_g_fixed`).
        let noisy = super::noise_parameters(problem.sde, problem.theta, problem.estimate)?;
        if !noisy.is_empty() {
            estimate.status = Status::Degenerate;
            for i in noisy {
                notes.push(format!(
                    "degenerate estimate: `{}` = {} changes the noise matrix G, and {}; estimate it with \
                     `pem`, or fix it with `--param`",
                    names[i],
                    estimate.theta[i],
                    super::NOISE_PARAMETER_REASON
                ));
            }
        }
    }
    flag_degenerate(&mut estimate, problem.theta_prior, &mut notes);
    Ok(MethodRun { estimate, notes })
}
