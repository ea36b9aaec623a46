//! Path-space MAP estimators: the Onsager–Machlup MAP path (JME) and the minimum-energy path
//! (MEE), jointly with any subset of the parameters, by Euler, trapezoidal and Hermite–Simpson
//! transcriptions solved with [`crate::nlp`].
//!
//! # Merits
//!
//! For a path x(·) on [t_0, t_N] with noise w = G⁻¹(ẋ − f) (clean states z obey ż = h exactly),
//! the log-merits are (`000_74b95e149527c64e.txt (2.49)`, `(2.60)`;
//! `002_3b89776223eca539.txt (6)`, `(7)`)
//!
//! $$ J(x, \theta) = \sum_k \ln\psi(y_k \mid x(t_k), \theta) + \ln p(x_0, z_0) + \ln p(\theta)
//!    - \tfrac12\int |w|^2\,dt - \tfrac12\int \operatorname{div}_x f\,dt \quad\text{(Onsager–Machlup)} $$
//!
//! and the energy merit without the last term. A parameter that enters div_x f with a flat
//! prior can make the Onsager–Machlup merit unbounded (Van der Pol's μ: −½∫div f grows without
//! bound in μ along paths where the damping term is negative); give such parameters a proper
//! prior or bounds.
//!
//! # Transcriptions
//!
//! - [`Transcription::Euler`]: the Euler-discretized MAP problem, `001_8aefdf0570c96f51.txt
//!   (16)`, `(19)`; as the step vanishes it converges to the minimum-energy problem, not to the
//!   Onsager–Machlup one (001 Sec. 2, Thm 18).
//! - [`Transcription::Trapezoidal`]: the trapezoidal-discretized MAP problem with its
//!   Σ ln det(I − ½δ∇_x f(t_{k+1}, x_{k+1})) term, `001_8aefdf0570c96f51.txt (21)`, `(22)`;
//!   converges to the Onsager–Machlup problem.
//! - [`Transcription::HermiteSimpson`]: 3-point Lobatto (Hermite–Simpson) collocation of the
//!   continuous merit chosen by [`Merit`] (000 Ch. 4, (2.50)–(2.51)), with the noise linear in
//!   time on each piece, w(t_k + σh) = a_k + (σ − ½) b_k. This basis represents every linear
//!   function of time, and Simpson's rule integrates ½|w|² exactly on it
//!   (h(½|a|² + |b|²/24)), so the discrete energy converges to ∫½|w|² dt. (A basis such as
//!   span{\[1,4,1\], \[1,0,−1\]} on the three points cannot represent a constant and converges to a
//!   problem with the energy weighted 11/9.)
//!
//! Measurement times must fall on grid nodes (the step divides the distance of every
//! measurement time to t_0); clean states are equality constraints in all three
//! transcriptions. The discrete transcriptions include the normalisation −N ln|det G(θ)| of the
//! transition densities (001 (21)); the continuous merits have none, so parameters of G cannot
//! be estimated with Hermite–Simpson (an error).

mod guess;
mod laplace;
mod map;
mod transcription;

#[cfg(test)]
mod tests;

use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::data::{Dataset, StatePath};
use crate::estimate::{Details, EstimationProblem, Method, PathEstimate, Status};
use crate::model::{Observation, Sde};
use crate::nlp::{self, NlpOptions, NlpProblem, NlpReport};
use crate::{Error, Result};

pub use guess::{derivative_states, regression_theta_guess, spline_guess, ThetaGuess, ThetaSource};
pub use map::{map_estimate, MapOptions, PathStart};
pub use transcription::{MeritParts, PathNlp};

/// Which continuous-time merit the path maximises.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Merit {
    /// The Onsager–Machlup merit, with −½∫div_x f dt (JME; `000_74b95e149527c64e.txt (2.49)`).
    OnsagerMachlup,
    /// The energy merit, without the divergence (MEE; `000_74b95e149527c64e.txt (2.60)`).
    Energy,
}

impl Merit {
    /// The method's command-line name: `jme` or `mee`.
    pub fn method_name(self) -> &'static str {
        self.method().name()
    }

    /// The estimator's method: `jme` or `mee`.
    pub fn method(self) -> Method {
        match self {
            Merit::OnsagerMachlup => Method::Jme,
            Merit::Energy => Method::Mee,
        }
    }
}

/// The transcription of the path into a finite-dimensional program (written `hermite-simpson`,
/// `trapezoidal` or `euler`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Transcription {
    /// The Euler-discretized MAP (`001_8aefdf0570c96f51.txt (19)`); the [`Merit`] is ignored
    /// (the scheme has no divergence term and converges to the energy merit).
    Euler,
    /// The trapezoidal-discretized MAP (`001_8aefdf0570c96f51.txt (22)`); the [`Merit`] is
    /// ignored (the scheme's volume term converges to the Onsager–Machlup divergence).
    Trapezoidal,
    /// Hermite–Simpson collocation of the chosen continuous merit (the default).
    #[default]
    HermiteSimpson,
}

impl Transcription {
    /// Parses `hermite-simpson`, `trapezoidal` or `euler`.
    pub fn parse(name: &str) -> Result<Transcription> {
        match name.trim() {
            "hermite-simpson" => Ok(Transcription::HermiteSimpson),
            "trapezoidal" => Ok(Transcription::Trapezoidal),
            "euler" => Ok(Transcription::Euler),
            other => Err(Error::UnknownName {
                kind: "transcription".into(),
                name: other.into(),
                known: ["hermite-simpson", "trapezoidal", "euler"].map(String::from).to_vec(),
            }),
        }
    }

    /// The command-line name.
    pub fn name(self) -> &'static str {
        match self {
            Transcription::HermiteSimpson => "hermite-simpson",
            Transcription::Trapezoidal => "trapezoidal",
            Transcription::Euler => "euler",
        }
    }
}

/// A uniform time grid t_k = t_0 + k h, k = 0..N, with the node of every measurement.
#[derive(Debug, Clone, PartialEq)]
pub struct Grid {
    /// Initial time t_0 (the time of the x0 prior).
    pub t0: f64,
    /// Step h.
    pub step: f64,
    /// Number of intervals N.
    pub intervals: usize,
    /// Grid node of each data row.
    pub measurement_nodes: Vec<usize>,
}

impl Grid {
    /// The grid from `t0` with step `step` up to the last time of `times`; every time must be
    /// ≥ t0 and lie on a node (within 1e-8 of a step), else [`Error::InvalidOption`].
    pub fn try_new(t0: f64, step: f64, times: &[f64]) -> Result<Grid> {
        let bad = |reason: String| Error::InvalidOption { name: "step".into(), reason };
        if !(step.is_finite() && step > 0.0) {
            return Err(bad(format!("must be positive and finite, got {step}")));
        }
        if !t0.is_finite() {
            return Err(Error::NonFinite { what: "t0".into() });
        }
        let mut nodes = Vec::with_capacity(times.len());
        for &t in times {
            let k = (t - t0) / step;
            let kr = k.round();
            if k.is_nan() || k <= -1e-8 || (k - kr).abs() > 1e-8 * (1.0 + kr) {
                return Err(bad(format!(
                    "the measurement time {t} is not on the grid t0 + k·h (t0 = {t0}, h = {step}); \
                     the step must divide the measurement spacing"
                )));
            }
            nodes.push(kr as usize);
        }
        let intervals = nodes.last().copied().unwrap_or(0).max(1);
        Ok(Grid { t0, step, intervals, measurement_nodes: nodes })
    }

    /// t_k.
    pub fn time(&self, k: usize) -> f64 {
        self.t0 + k as f64 * self.step
    }

    /// All node times.
    pub fn times(&self) -> Vec<f64> {
        (0..=self.intervals).map(|k| self.time(k)).collect()
    }
}

/// Options of [`estimate_path`].
#[derive(Debug)]
#[non_exhaustive]
pub struct PathOptions {
    /// The merit (default: Onsager–Machlup).
    pub merit: Merit,
    /// The transcription (default: Hermite–Simpson).
    pub transcription: Transcription,
    /// The step (default: the shortest spacing of t0 and the measurement times / 20).
    pub step: Option<f64>,
    /// The initial state path, interpolated linearly onto the grid (default: zeros). Build it
    /// with [`spline_guess`] (000 Sec. 4.1; what the CLI uses) or [`interpolation_guess`].
    pub initial_path: Option<StatePath>,
    /// Which Laplace standard deviations to compute (default: of the path and of the
    /// estimated θ); see [`PathSolution`].
    pub laplace: Laplace,
    /// Options of the NLP solver (default: its defaults).
    pub nlp: NlpOptions,
}

impl Default for PathOptions {
    fn default() -> Self {
        PathOptions {
            merit: Merit::OnsagerMachlup,
            transcription: Transcription::HermiteSimpson,
            step: None,
            initial_path: None,
            laplace: Laplace::default(),
            nlp: NlpOptions::default(),
        }
    }
}

impl PathOptions {
    /// Options with the given merit and transcription, the rest default.
    pub fn new(merit: Merit, transcription: Transcription) -> Self {
        PathOptions { merit, transcription, ..Default::default() }
    }

    /// Sets the step.
    pub fn with_step(mut self, step: f64) -> Self {
        self.step = Some(step);
        self
    }

    /// Sets the initial path.
    pub fn with_initial_path(mut self, path: StatePath) -> Self {
        self.initial_path = Some(path);
        self
    }

    /// Sets which Laplace standard deviations to compute.
    pub fn with_laplace(mut self, laplace: Laplace) -> Self {
        self.laplace = laplace;
        self
    }

    /// Sets the NLP options.
    pub fn with_nlp(mut self, nlp: NlpOptions) -> Self {
        self.nlp = nlp;
        self
    }
}

/// Which Laplace standard deviations a path-space MAP solve computes. Each sd is one solve
/// with the factorised KKT matrix (`laplace.rs`): the parameters cost one solve each, the
/// path one per node and state, which dominates the whole estimate on long grids of many
/// states (the 22-state flight-path model on 751 nodes: 16,522 solves, minutes against
/// seconds for the NLP).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Laplace {
    /// None.
    Off,
    /// Of the estimated θ only.
    Parameters,
    /// Of the path at every node and of the estimated θ (the default).
    #[default]
    PathAndParameters,
}

/// The full result of a path-space MAP solve.
///
/// When [`PathOptions::laplace`] asks for them and the solve succeeded, the path's `sd` and
/// `theta_sd` are the Laplace standard deviations: square roots of the diagonal of the inverse
/// reduced Hessian of −J at the optimum, from solves with the factorised KKT matrix (see
/// `laplace.rs`); they are absent when the KKT matrix does not have the inertia of a strict
/// maximum.
#[derive(Debug, Clone)]
pub struct PathSolution {
    /// The common estimate (path at the grid nodes, θ, status, details).
    pub estimate: PathEstimate,
    /// The parts of the log-merit at the optimum.
    pub parts: MeritParts<f64>,
    /// The NLP solver's report.
    pub report: NlpReport,
    /// The grid.
    pub grid: Grid,
}

/// The default step: the shortest positive spacing of t0 and the measurement times, / 20.
pub fn default_step(t0: f64, data: &Dataset) -> f64 {
    let mut last = t0;
    let mut spacing = f64::INFINITY;
    for &t in &data.times {
        if t - last > 0.0 {
            spacing = spacing.min(t - last);
        }
        last = t;
    }
    if spacing.is_finite() {
        spacing / 20.0
    } else {
        0.05
    }
}

/// An initial state path from the data: for each state measured directly (output `k` measures
/// state `measured[k]`, indices into s = [x; z]), linear interpolation of its measurements
/// (constant beyond the first and last); zeros for the other states. Times are t0 and the
/// measurement times. The fallback of [`spline_guess`] for outputs with fewer than three
/// measurements.
pub fn interpolation_guess(
    names: Vec<String>,
    n_states: usize,
    measured: &[usize],
    data: &Dataset,
    t0: f64,
) -> StatePath {
    let mut times = vec![t0];
    times.extend(data.times.iter().copied().filter(|&t| t > t0));
    let mut values = vec![vec![0.0; n_states]; times.len()];
    for (k, &s) in measured.iter().enumerate() {
        if s >= n_states {
            continue;
        }
        let pts: Vec<(f64, f64)> = data
            .times
            .iter()
            .zip(&data.values)
            .map(|(&t, row)| (t, row[k]))
            .filter(|p| p.1.is_finite())
            .collect();
        for (i, &t) in times.iter().enumerate() {
            values[i][s] = interpolate(&pts, t);
        }
    }
    StatePath { names, times, values, sd: None }
}

/// Linear interpolation through sorted points, constant outside; 0 without points.
fn interpolate(pts: &[(f64, f64)], t: f64) -> f64 {
    match pts {
        [] => 0.0,
        [p, ..] if t <= p.0 => p.1,
        [.., p] if t >= p.0 => p.1,
        _ => {
            let j = pts.partition_point(|p| p.0 <= t);
            let ((ta, ya), (tb, yb)) = (pts[j - 1], pts[j]);
            ya + (yb - ya) * (t - ta) / (tb - ta)
        }
    }
}

fn guess_on_grid(path: Option<&StatePath>, grid: &Grid, n_states: usize) -> Result<Vec<Vec<f64>>> {
    let times = grid.times();
    let Some(path) = path else { return Ok(vec![vec![0.0; n_states]; times.len()]) };
    crate::model::check_len("initial path states", n_states, path.names.len())?;
    if path.values.iter().flatten().any(|v| !v.is_finite()) || path.times.is_empty() {
        return Err(Error::NonFinite { what: "initial path".into() });
    }
    Ok(path_on_times(path, &times))
}

/// The states of `path` at `times` by linear interpolation (constant outside); the
/// interpolation points of each state are gathered once, not once per time.
fn path_on_times(path: &StatePath, times: &[f64]) -> Vec<Vec<f64>> {
    let columns: Vec<Vec<(f64, f64)>> = (0..path.names.len())
        .map(|s| path.times.iter().zip(&path.values).map(|(&t, r)| (t, r[s])).collect())
        .collect();
    times.iter().map(|&t| columns.iter().map(|pts| interpolate(pts, t)).collect()).collect()
}

/// The estimated parameters (of `estimate`) that change the noise matrix G(θ) (a relative
/// change of G above 10⁻¹² for a step of 10⁻³ (1 + |θᵢ|)).
pub fn noise_parameters<S: Sde + ?Sized>(sde: &S, theta: &[f64], estimate: &[usize]) -> Result<Vec<usize>> {
    let g0 = sde.diffusion_matrix(theta)?;
    let mut found = Vec::new();
    for &i in estimate {
        let mut th = theta.to_vec();
        th[i] += 1e-3 * (1.0 + th[i].abs());
        let g1 = sde.diffusion_matrix(&th)?;
        if (g1 - &g0).amax() > 1e-12 * (1.0 + g0.amax()) {
            found.push(i);
        }
    }
    Ok(found)
}

/// Why a parameter of G(θ) is not estimated with the path by any transcription.
pub(crate) const NOISE_PARAMETER_REASON: &str = "the joint MAP of the path and the noise matrix G is \
     degenerate: a smoother path with a smaller G always scores better, so the estimate of G runs \
     towards zero as the step shrinks";

/// Checks that no estimated parameter changes G(θ) (Hermite–Simpson only).
fn check_g_fixed<S: Sde + ?Sized>(sde: &S, theta: &[f64], estimate: &[usize]) -> Result<()> {
    if let Some(&i) = noise_parameters(sde, theta, estimate)?.first() {
        return Err(Error::InvalidOption {
            name: "--estimate".into(),
            reason: format!(
                "parameter `{}` changes the noise matrix G; its continuous-time path merit has no \
                 normalisation in G, so it cannot be estimated with Hermite–Simpson, and with euler or \
                 trapezoidal {NOISE_PARAMETER_REASON}: estimate it with `pem` (the filter's likelihood \
                 integrates the path out), or fix it with `--param`",
                sde.param_names()[i]
            ),
        });
    }
    Ok(())
}

/// Builds the transcribed program of `problem` (checked) with `options` (step, t0 and initial
/// path; the NLP options are not used). Exposed so that its derivatives can be tested.
pub fn build_nlp<'a, S: Sde + ?Sized, O: Observation + ?Sized>(
    problem: &'a EstimationProblem<'a, S, O>,
    options: &PathOptions,
) -> Result<PathNlp<'a, S, O>> {
    problem.validate()?;
    let d = problem.sde.dims();
    problem.sde.diffusion_matrix(problem.theta)?;
    for (row, v) in problem.data.values.iter().enumerate() {
        crate::model::check_len(&format!("data row {row}"), problem.observation.output_dim(), v.len())?;
    }
    for &i in problem.estimate {
        let p = &problem.theta_prior[i];
        let v = problem.theta[i];
        if v < p.lower || v > p.upper {
            return Err(Error::InvalidOption {
                name: "theta".into(),
                reason: format!(
                    "the initial value {v} of `{}` violates its bounds [{}, {}]",
                    problem.sde.param_names()[i],
                    p.lower,
                    p.upper
                ),
            });
        }
    }
    if options.transcription == Transcription::HermiteSimpson {
        check_g_fixed(problem.sde, problem.theta, problem.estimate)?;
    }
    let t0 = problem.t0;
    let step = options.step.unwrap_or_else(|| default_step(t0, problem.data));
    check_path_memory(problem, step)?;
    let grid = Grid::try_new(t0, step, &problem.data.times)?;
    // the NLP's patterns index variables and constraints as `u32` (`nlp::NlpProblem`); the
    // Hermite–Simpson bound (nodes, midpoints, noise coefficients, θ) covers the other two
    let n = grid.intervals;
    let unknowns = (2 * n + 1) * d.states() + 2 * n * d.noisy + problem.estimate.len();
    if unknowns.max(2 * n * d.states()) > u32::MAX as usize {
        return Err(Error::InvalidOption {
            name: "step".into(),
            reason: format!("{n} intervals give more than 2^32 - 1 unknowns; take a longer step"),
        });
    }
    let guess = guess_on_grid(options.initial_path.as_ref(), &grid, d.states())?;
    Ok(PathNlp::new(problem, options.merit, options.transcription, grid, &guess))
}

/// Bytes per unknown of the transcribed NLP: the iterates, multipliers and directions, the
/// sparse KKT matrix and its banded factor (about 400 B measured on the double well with
/// Hermite–Simpson, 8·10⁵ unknowns).
const PATH_BYTES_PER_UNKNOWN: f64 = 400.0;

/// Checks the memory of the transcription of `problem` with `step` against the problem's
/// [`MemoryLimit`](crate::estimate::MemoryLimit) before anything is allocated: the
/// Hermite–Simpson count of unknowns ((2n + 1)·states + 2n·noisy + parameters for n intervals)
/// × 400 B. Errors: [`Error::MemoryLimit`]; a step that is not positive and finite
/// ([`Error::InvalidOption`]).
pub fn check_path_memory<S: Sde + ?Sized, O: Observation + ?Sized>(
    problem: &EstimationProblem<'_, S, O>,
    step: f64,
) -> Result<()> {
    crate::error::check_positive("step", step)?;
    let d = problem.sde.dims();
    let t_end = problem.data.times.last().copied().unwrap_or(problem.t0);
    let n = ((t_end - problem.t0) / step).ceil().max(1.0);
    let unknowns =
        (2.0 * n + 1.0) * d.states() as f64 + 2.0 * n * d.noisy as f64 + problem.estimate.len() as f64;
    let size = format!("{n:.0} intervals of step {step} × {} states ({unknowns:.0} unknowns)", d.states());
    problem.max_memory.check("the path transcription", size, unknowns * PATH_BYTES_PER_UNKNOWN)
}

/// Estimates the MAP path (and the estimated parameters) of `problem` with `options`.
///
/// Errors for inconsistent inputs (see [`EstimationProblem::validate`]), measurement times off
/// the grid, an initial θ outside its bounds; non-convergence is the status of the result.
pub fn estimate_path<S: Sde + ?Sized, O: Observation + ?Sized>(
    problem: &EstimationProblem<'_, S, O>,
    options: PathOptions,
) -> Result<PathSolution> {
    match options.nlp.linear_solver {
        nlp::LinearSolver::Auto => estimate_path_with(problem, options, &mut nlp::AutoLdlt::new()),
        nlp::LinearSolver::Faer => estimate_path_with(problem, options, &mut nlp::FaerLdlt::new()),
        nlp::LinearSolver::Band => estimate_path_with(problem, options, &mut nlp::BandLdlt::new()),
    }
}

/// [`estimate_path`] with a given KKT solver (`options.nlp.linear_solver` is then ignored),
/// used for the NLP solve and the Laplace sd. A [`nlp::BandLdlt`] or [`nlp::AutoLdlt`] that
/// already analysed a transcription with the same grid keeps its ordering
/// ([`nlp::BandLdlt::reuse_analysis`]): pass the same solver to the estimates of a Monte Carlo
/// run to analyse the KKT pattern once.
///
/// # Errors
/// As [`estimate_path`].
pub fn estimate_path_with<S: Sde + ?Sized, O: Observation + ?Sized, K: nlp::KktSolver + ?Sized>(
    problem: &EstimationProblem<'_, S, O>,
    options: PathOptions,
    kkt: &mut K,
) -> Result<PathSolution> {
    let mut nlp_problem = build_nlp(problem, &options)?;
    let start = Instant::now();
    let solution = nlp::InteriorPoint::try_new(options.nlp)?.solve_with(&mut nlp_problem, kkt)?;
    let solve_seconds = start.elapsed().as_secs_f64();
    let w = &solution.w;
    let ns = problem.sde.dims().states();
    let n_nodes = nlp_problem.grid().intervals + 1;
    let ne = problem.estimate.len();
    let (mut path_sd, mut theta_sd) = (None, None);
    let mut sd = if options.laplace == Laplace::Off { LaplaceSd::Off } else { LaplaceSd::NotSolved };
    if options.laplace != Laplace::Off && solution.report.status.is_success() {
        let n = nlp_problem.num_variables();
        let path_nodes = if options.laplace == Laplace::PathAndParameters { n_nodes } else { 0 };
        let wanted: Vec<usize> = (0..path_nodes * ns).chain(n - ne..n).collect();
        sd = LaplaceSd::NotAMaximum;
        if let Some(var) = laplace::laplace_variances(&mut nlp_problem, w, &solution.lambda, &wanted, kkt) {
            let sd_all: Vec<f64> = var.iter().map(|v| v.sqrt()).collect();
            theta_sd = Some(sd_all[path_nodes * ns..].to_vec());
            sd = if path_nodes > 0 {
                path_sd = Some(sd_all[..n_nodes * ns].chunks(ns).map(|c| c.to_vec()).collect());
                LaplaceSd::Computed
            } else {
                LaplaceSd::ParametersOnly
            };
        }
    }
    let parts = nlp_problem.merit_parts(w);
    let grid = nlp_problem.grid().clone();
    let theta = nlp_problem.theta(w);
    let report = solution.report;
    let details = PathDetails {
        transcription: options.transcription,
        step: grid.step,
        t0: grid.t0,
        merit: parts.total(),
        log_likelihood: parts.log_likelihood,
        log_prior: parts.log_prior,
        minus_half_int_energy: parts.energy,
        minus_half_int_div: parts.divergence,
        nlp_status: report.status,
        nlp_iterations: report.iterations,
        primal_infeasibility: report.primal_infeasibility,
        dual_infeasibility: report.dual_infeasibility,
        unknowns: w.len(),
        evaluation_seconds: report.times.evaluation.as_secs_f64(),
        factorization_seconds: report.times.factorization.as_secs_f64(),
        kkt_solve_seconds: report.times.solve.as_secs_f64(),
        numeric_factorizations: report.numeric_factorizations,
        inertia_correction_factorizations: report.inertia_correction_factorizations,
        other_factorizations: report.other_factorizations,
        evaluations: report.evaluations,
        linear_solver: report.linear_solver,
        kkt_nnz: report.kkt_nnz,
        factor_nnz: report.factor_nnz,
        sd,
    };
    let estimate = PathEstimate {
        method: options.merit.method(),
        path: StatePath {
            names: problem.sde.state_names(),
            times: grid.times(),
            values: nlp_problem.node_states(w),
            sd: path_sd,
        },
        theta_names: problem.sde.param_names(),
        theta,
        estimated: problem.estimate.to_vec(),
        theta_sd,
        status: report.status,
        iterations: report.iterations,
        solve_seconds,
        details: Details::new(details),
    };
    Ok(PathSolution { estimate, parts, report, grid })
}

/// The details of a path-space MAP estimate's report.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PathDetails {
    /// The transcription.
    pub transcription: Transcription,
    /// The grid's step.
    pub step: f64,
    /// The grid's initial time.
    pub t0: f64,
    /// The log-merit J at the optimum.
    pub merit: f64,
    /// Its measurement part Σ ln ψ.
    pub log_likelihood: f64,
    /// Its prior part.
    pub log_prior: f64,
    /// −½∫|w|² dt (discretised).
    pub minus_half_int_energy: f64,
    /// −½∫div f dt (discretised; 0 for the energy merit).
    pub minus_half_int_div: f64,
    /// The NLP solver's status.
    pub nlp_status: Status,
    /// Its iterations.
    pub nlp_iterations: usize,
    /// Constraint violation at the end.
    pub primal_infeasibility: f64,
    /// Optimality error at the end.
    pub dual_infeasibility: f64,
    /// Unknowns of the program.
    pub unknowns: usize,
    /// Seconds in function evaluations.
    pub evaluation_seconds: f64,
    /// Seconds in factorisations.
    pub factorization_seconds: f64,
    /// Seconds in KKT solves.
    pub kkt_solve_seconds: f64,
    /// Numeric factorisations.
    pub numeric_factorizations: usize,
    /// Factorisations for the inertia correction.
    pub inertia_correction_factorizations: usize,
    /// Other factorisations.
    pub other_factorizations: usize,
    /// Evaluations of each function.
    pub evaluations: nlp::EvaluationCounts,
    /// The KKT solver.
    pub linear_solver: &'static str,
    /// Non-zeros of the KKT matrix.
    pub kkt_nnz: usize,
    /// Non-zeros of its factor.
    pub factor_nnz: usize,
    /// What the path's `sd` is, or why it has none.
    pub sd: LaplaceSd,
}

/// The standard deviations of a MAP estimate: the Laplace sd, or why there is none. Written in
/// reports as a sentence (the `sd` entry of the details).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum LaplaceSd {
    /// The Laplace sd: square roots of the diagonal of the inverse reduced Hessian of −J.
    Computed,
    /// Not asked for ([`Laplace::Off`]).
    Off,
    /// Of the estimated θ only ([`Laplace::Parameters`]); the path has none.
    ParametersOnly,
    /// Skipped by [`map_estimate`] because the grid has more node states than the option
    /// `laplace_max_states` allows.
    Skipped {
        /// Nodes × states of the grid.
        node_states: usize,
        /// The option `laplace_max_states`.
        max_states: usize,
    },
    /// The solve did not succeed.
    NotSolved,
    /// The KKT matrix at the solution does not have the inertia of a strict maximum.
    NotAMaximum,
}

impl std::fmt::Display for LaplaceSd {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LaplaceSd::Computed => f.write_str("Laplace"),
            LaplaceSd::Off => f.write_str("none: not asked for"),
            LaplaceSd::ParametersOnly => f.write_str("none for the path: Laplace sd of the parameters only"),
            LaplaceSd::Skipped { max_states: 0, .. } => f.write_str("none: laplace_max_states = 0"),
            LaplaceSd::Skipped { node_states, max_states } => {
                write!(
                    f,
                    "none: Laplace skipped ({node_states} node states > laplace_max_states = {max_states})"
                )
            }
            LaplaceSd::NotSolved => f.write_str("none: the solve did not succeed"),
            LaplaceSd::NotAMaximum => f.write_str("none: not a strict maximum (KKT inertia)"),
        }
    }
}

impl Serialize for LaplaceSd {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> std::result::Result<S::Ok, S::Error> {
        serializer.collect_str(self)
    }
}
