//! `onsager estimate --method jme|mee`: the path-space MAP estimators.

use onsager::estimate::{EstimationProblem, PathEstimate};
use onsager::model::Sde;
use onsager::path::{estimate_path, regression_theta_guess, spline_guess, Merit, PathOptions, Transcription};
use onsager::{Error, Result};

use super::estimate::{CliProblem, EstimateArgs, Method};

/// Largest number of node states for which the CLI computes the Laplace sd.
const LAPLACE_MAX_SOLVES: usize = 4000;

/// Runs a path-space MAP method: `--transcription` (default `hermite-simpson`), `--step`
/// (default: measurement spacing / 20). The initial path is [`spline_guess`] (smoothing
/// spline of each measured state, its derivative for a state that is the derivative of a
/// measured one, zeros otherwise); an estimated θ component starts at its `--param` value if
/// given, else at the regression guess of 000 Sec. 4.1 ([`regression_theta_guess`], falling
/// back to the prior mean where the model is not affine in it). The
/// path's sd columns and θ's sd are the Laplace approximation (for up to
/// [`LAPLACE_MAX_SOLVES`] node states).
pub fn run(args: &EstimateArgs, problem: &CliProblem<'_>) -> Result<PathEstimate> {
    let merit = match args.method {
        Method::Jme => Merit::OnsagerMachlup,
        Method::Mee => Merit::Energy,
        other => {
            return Err(Error::InvalidOption {
                name: "--method".into(),
                reason: format!("`{other:?}` is not a path-space MAP method (jme, mee)"),
            })
        }
    };
    let transcription = match &args.transcription {
        Some(name) => Transcription::parse(name)?,
        None => Transcription::HermiteSimpson,
    };
    match (transcription, merit) {
        (Transcription::Euler, Merit::OnsagerMachlup) => {
            outln!("note: the Euler MAP path converges to the minimum-energy path, not the Onsager-Machlup one (001 Thm 18)")
        }
        (Transcription::Trapezoidal, Merit::Energy) => {
            outln!("note: the trapezoidal MAP path converges to the Onsager-Machlup path, not the minimum-energy one (001 Thm 18)")
        }
        _ => {}
    }
    let t0 = onsager::estimate::default_initial_time(problem.data);
    let step = args.step.unwrap_or_else(|| onsager::path::default_step(t0, problem.data));
    let t_end = problem.data.times.last().copied().unwrap_or(t0);
    let nodes = ((t_end - t0) / step).round().max(1.0) as usize;
    let times: Vec<f64> = (0..=nodes).map(|k| t0 + k as f64 * step).collect();
    // The starting θ: `--param` values where given, the regression guess otherwise.
    let user_set: Vec<String> = args
        .model
        .params
        .iter()
        .filter_map(|s| s.split_once('='))
        .map(|(k, _)| k.trim().to_string())
        .collect();
    let names = problem.sde.param_names();
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
            if !user_set.contains(&names[i]) {
                theta[i] = g.theta[i];
            }
        }
    }
    let problem = &EstimationProblem { theta: &theta, ..*problem };
    let guess = spline_guess(problem.sde, problem.theta, &problem.observation.states, problem.data, &times)?;
    let mut options =
        PathOptions::new(merit, transcription).with_t0(t0).with_step(step).with_initial_path(guess);
    // The Laplace sd costs one KKT solve per node state (selected inversion is future work):
    // computed up to LAPLACE_MAX_SOLVES of them.
    let solves = nodes * problem.sde.dims().states();
    if solves > LAPLACE_MAX_SOLVES {
        outln!("note: skipping the Laplace sd ({solves} node states > {LAPLACE_MAX_SOLVES})");
        options = options.with_laplace(false);
    }
    Ok(estimate_path(problem, options)?.estimate)
}
