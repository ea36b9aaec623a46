//! The exact grid: forward and backward Kolmogorov sweeps with jump conditions, shared by the
//! KSP smoother and the exact effective action.
//!
//! Between the event times (the output times, which include the measurement times) the density
//! P evolves by the forward step of [`FokkerPlanck`] and the adjoint A by its exact transpose
//! (`003_d2fc48a470e528fc.txt (I.16), (I.17)`). At a measurement time t_k both jump by the same
//! positive cell weights e_k (`(I.61), (I.62)` with e_k = exp(λ_kᵀZ); `(A.4), (A.9)` with
//! e_k = ψ(r_k | x)), normalised by W_k = Σ e_k P(t_k−) (`(I.63)`, `(A.5)`):
//!
//! $$ P(t_k+) = e_k P(t_k-)/W_k, \qquad A(t_k-) = e_k A(t_k+)/W_k, \qquad A(t_f) = 1, $$
//!
//! so that A P is continuous across the jumps and ⟨A, P⟩ = 1 at every step. The sum
//! Σ_k log W_k is F(λ) (`(I.73)–(I.75)`) or the log marginal likelihood of the data.

use std::time::Instant;

use nalgebra::DMatrix;
use onsager_closures::dot;

use serde::{Deserialize, Serialize};

use crate::data::{Dataset, EventTimes, StatePath};
use crate::error::check_positive;
use crate::estimate::{Details, EstimationProblem, Method, MethodRun, PathEstimate, Status};
use crate::estimator::EstimatorOptions;
use crate::model::observation::StateMeasurement;
use crate::model::prior::{Prior, PriorDensity};
use crate::model::{Observation, Sde};
use crate::{Error, Result};

use super::dual::{ActionValue, DualData, DualOptions, DualSolution, EffectiveAction, History, Swept};
use super::fokker_planck::{check_model_fits_grid, FokkerPlanck, StepKind, TimeScheme};
use super::grid::{Grid, GridSpec, MAX_AXES};
use super::mean_optimal::{DualDetails, DualStart, Plan, SdKind};

/// Options of the exact grid methods: the discretisation (the options of `ksp`; `mean-optimal`
/// adds the dual's, [`MeanOptimalOptions`]).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default)]
#[non_exhaustive]
pub struct ExactOptions {
    /// The grid; its axes are the states (noisy then clean). Default ([`default_grid`]): every
    /// state measured directly, each axis over the data range widened by a quarter of it and by
    /// four measurement sd on each side (at least 0.5), 400 cells in one dimension, 120 per axis
    /// in two and 40 per axis in three.
    pub grid: Option<GridSpec>,
    /// Time step. Default: the output step / 2 with [`TimeScheme::TrBdf2`], the output step / 4
    /// with [`TimeScheme::ImplicitEuler`].
    pub dt: Option<f64>,
    /// The time scheme: second-order TR-BDF2 (default) or first-order implicit Euler.
    pub scheme: TimeScheme,
    /// Step of the output grid. Default: the mean measurement spacing / 10 (the horizon / 10
    /// with a single measurement).
    /// The densities P and A are stored at every output time, so (output times) × (cells) is
    /// limited to 2.5·10⁷.
    pub output_step: Option<f64>,
    /// Further output times (finite, ≥ the problem's `t0`; later than the last datum extends the horizon).
    /// Default none.
    pub extra_times: Vec<f64>,
}

impl ExactOptions {
    /// Options with the given grid and every other default.
    pub fn new(grid: GridSpec) -> Self {
        ExactOptions { grid: Some(grid), ..Default::default() }
    }

    /// Sets the time step.
    pub fn with_dt(mut self, dt: f64) -> Self {
        self.dt = Some(dt);
        self
    }

    /// Sets the time scheme.
    pub fn with_scheme(mut self, scheme: TimeScheme) -> Self {
        self.scheme = scheme;
        self
    }

    /// Sets the output step.
    pub fn with_output_step(mut self, step: f64) -> Self {
        self.output_step = Some(step);
        self
    }

    /// Adds output times (sorted or not).
    pub fn with_extra_times(mut self, times: &[f64]) -> Self {
        self.extra_times.extend_from_slice(times);
        self
    }

    /// The mean-optimal estimator's options with these and the dual's defaults.
    pub fn with_dual(self, dual: DualOptions) -> MeanOptimalOptions {
        MeanOptimalOptions { exact: self, dual }
    }
}

impl EstimatorOptions for ExactOptions {
    /// `ksp`: [`ksp_estimate`].
    fn run<S: Sde + ?Sized>(
        &self,
        _: Method,
        problem: &EstimationProblem<'_, S, StateMeasurement>,
    ) -> Result<MethodRun> {
        ksp_estimate(problem, self)
    }

    /// Checks the grid, positive finite `dt` and `output_step`, finite `extra_times`.
    fn validate(&self) -> Result<()> {
        if let Some(g) = &self.grid {
            g.validate()?;
        }
        check_positive("dt", self.dt)?;
        check_positive("output_step", self.output_step)?;
        match self.extra_times.iter().find(|t| !t.is_finite()) {
            Some(t) => Err(invalid("extra_times", format!("must be finite, got {t}"))),
            None => Ok(()),
        }
    }
}

/// Options of the exact mean-optimal estimator (`mean-optimal`): the discretisation and the
/// dual's options.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default)]
#[non_exhaustive]
pub struct MeanOptimalOptions {
    /// The discretisation (the options `grid`, `dt`, `output_step`, `extra_times`).
    #[serde(flatten)]
    pub exact: ExactOptions,
    /// The dual maximisation (the option `dual`).
    pub dual: DualOptions,
}

impl From<ExactOptions> for MeanOptimalOptions {
    fn from(exact: ExactOptions) -> Self {
        MeanOptimalOptions { exact, dual: DualOptions::default() }
    }
}

impl From<&ExactOptions> for MeanOptimalOptions {
    fn from(exact: &ExactOptions) -> Self {
        exact.clone().into()
    }
}

impl From<&MeanOptimalOptions> for MeanOptimalOptions {
    fn from(options: &MeanOptimalOptions) -> Self {
        options.clone()
    }
}

impl EstimatorOptions for MeanOptimalOptions {
    /// `mean-optimal`: [`mean_optimal_estimate`].
    fn run<S: Sde + ?Sized>(
        &self,
        _: Method,
        problem: &EstimationProblem<'_, S, StateMeasurement>,
    ) -> Result<MethodRun> {
        mean_optimal_estimate(problem, self)
    }

    /// Checks the discretisation and the dual's options.
    fn validate(&self) -> Result<()> {
        self.exact.validate()?;
        self.dual.validate().map_err(|e| e.within("dual"))
    }
}

/// The default grid of the exact methods for `problem`: every state must be measured
/// directly; each axis spans the data range widened by a quarter of it and by four measurement
/// sd on each side (and by at least 0.5), and the initial-state prior's mean ± 6 sd (a
/// Gaussian prior, within its bounds; the bounds of another prior when both are finite). One
/// dimension has 400 cells, or more (up to 4000) so that the cells are no wider than 400 cells
/// on the data range alone would be; two dimensions 120 per axis (up to 360); three dimensions
/// 40 per axis (up to 80: a 3-D grid stores cells × times, docs/effective-action.md).
///
/// Errors: [`Error::InvalidOption`] (name `grid`) when a state is not measured or the model has
/// more than [`MAX_AXES`] states.
pub fn default_grid<S: Sde + ?Sized, O: Observation + ?Sized>(
    problem: &EstimationProblem<'_, S, O>,
) -> Result<GridSpec> {
    let n = problem.sde.dims().states();
    // An example grid with one axis per state (`;` between the axes), for up to three states.
    let example = match n {
        2 => "`lo=-2.5;-2.5,hi=2.5;2.5,cells=120;120`",
        3 => "`lo=-2.5;-2.5;-2.5,hi=2.5;2.5;2.5,cells=40;40;40`",
        _ => "`lo=-2.5,hi=2.5,cells=500`",
    };
    let need = |why: String| invalid("grid", format!("{why}; give one, e.g. {example}"));
    if !(1..=MAX_AXES).contains(&n) {
        return Err(need(format!("the grid methods take 1 to {MAX_AXES} states, the model has {n}")));
    }
    let sd = problem.observation.gaussian_error_sd(problem.theta).unwrap_or(0.0);
    let (mut lo, mut hi) = (vec![0.0; n], vec![0.0; n]);
    // Cells per axis, and the most a prior wider than the data may ask for, by dimension.
    const BASE: [usize; MAX_AXES] = [400, 120, 40];
    const MOST: [usize; MAX_AXES] = [4000, 360, 80];
    let base = BASE[n - 1];
    let mut cells = vec![base; n];
    let outputs = problem.observation.output_dim();
    let priors: Vec<&Prior> = problem.x0_prior.iter().chain(problem.z0_prior).collect();
    for a in 0..n {
        let column =
            (0..outputs).find(|&c| problem.observation.measured_state(c) == Some(a)).ok_or_else(|| {
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
        let data_width = hi[a] - lo[a];
        if let Some((l, h)) = priors.get(a).and_then(|p| prior_range(p)) {
            lo[a] = lo[a].min(l);
            hi[a] = hi[a].max(h);
        }
        let wider = ((hi[a] - lo[a]) / data_width * base as f64).ceil() as usize;
        cells[a] = wider.clamp(base, MOST[n - 1]);
    }
    Ok(GridSpec { lo, hi, cells })
}

/// The range a default grid gives a prior: mean ± 6 sd of a Gaussian (within its bounds), or
/// the bounds when both are finite; `None` otherwise.
fn prior_range(prior: &Prior) -> Option<(f64, f64)> {
    let (l, u) = (prior.lower, prior.upper);
    match prior.density {
        PriorDensity::Gaussian { mean, sd } => {
            let (a, b) = ((mean - 6.0 * sd).max(l), (mean + 6.0 * sd).min(u));
            (a.is_finite() && b.is_finite() && a < b).then_some((a, b))
        }
        _ => (l.is_finite() && u.is_finite()).then_some((l, u)),
    }
}

/// Where an estimate's density reaches the edge of its grid: the largest mass in the outer
/// cells of an axis at any output time, above [`EDGE_MASS`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct GridEdge {
    /// The axis (state index).
    pub axis: usize,
    /// The output time.
    pub time: f64,
    /// The mass in the outer cells of that axis (both ends).
    pub mass: f64,
}

/// The mass in the outer cells (the outer max(1, n/100) cells at each end of an axis of n
/// cells) above which a density reaches the grid's edge.
pub const EDGE_MASS: f64 = 1e-3;

/// The largest mass in the outer cells of each axis over `densities` (one per time in
/// `times`), when one exceeds [`EDGE_MASS`].
pub fn grid_edge(grid: &Grid, times: &[f64], densities: &[Vec<f64>]) -> Option<GridEdge> {
    let cells = grid.cells();
    let mut worst: Option<GridEdge> = None;
    for (&time, q) in times.iter().zip(densities) {
        for (axis, &n) in cells.iter().enumerate() {
            let band = (n / 100).max(1);
            let mass: f64 = q
                .iter()
                .enumerate()
                .filter(|&(c, _)| {
                    let i = grid.index_on(axis, c);
                    i < band || i >= n - band
                })
                .map(|(_, m)| m)
                .sum();
            if mass > EDGE_MASS && worst.is_none_or(|w| mass > w.mass) {
                worst = Some(GridEdge { axis, time, mass });
            }
        }
    }
    worst
}

/// Marks an estimate whose density reaches the grid's edge [`Status::GridEdge`], with a note.
fn flag_edge(estimate: &mut PathEstimate, edge: Option<GridEdge>, grid: &GridSpec, notes: &mut Vec<String>) {
    if let Some(e) = edge {
        let name = &estimate.path.names[e.axis];
        notes.push(format!(
            "the density reaches the edge of the grid {grid}: {:.1e} of its mass in the outer cells of `{name}` \
             at t = {}; give a wider --grid",
            e.mass, e.time
        ));
        if estimate.status.is_success() {
            estimate.status = Status::GridEdge;
        }
    }
}

/// How far apart (relative) two step sizes may be and still share one factorisation.
const STEP_SNAP: f64 = 1e-10;

/// Gives the step sizes of `substeps` (count, size) that agree to [`STEP_SNAP`] relative one
/// value, the smallest of them, and returns the distinct sizes, increasing. Intervals of equal
/// length between event times (an output grid, measurements on it) give sizes that differ only
/// by the rounding of t_{k+1} − t_k; each distinct size is factored and kept for the whole
/// estimate (144 bytes per cell in three dimensions), so without this an output step of 0.1
/// on [0, 10] keeps eight. The interval then ends within 10⁻¹⁰ × its length of the event
/// time, far below the time scheme's error.
fn snap_step_sizes(substeps: &mut [(usize, f64)]) -> Vec<f64> {
    let mut dts: Vec<f64> = substeps.iter().map(|s| s.1).collect();
    dts.sort_by(f64::total_cmp);
    dts.dedup_by(|h, kept| *h - *kept <= STEP_SNAP * *kept);
    for s in substeps.iter_mut() {
        // The largest kept size at or below s.1 is within STEP_SNAP of it.
        let k = dts.partition_point(|&h| h <= s.1);
        s.1 = dts[k - 1];
    }
    dts
}

/// The grid of `options`, or the default one with a note saying so.
fn grid_of<S: Sde + ?Sized, O: Observation + ?Sized>(
    problem: &EstimationProblem<'_, S, O>,
    options: &ExactOptions,
) -> Result<(GridSpec, Option<String>)> {
    let (g, note) = match &options.grid {
        Some(g) => (g.clone(), None),
        None => {
            let g = default_grid(problem)?;
            let note = format!("grid {g} (the default: data range with margins and the initial prior)");
            (g, Some(note))
        }
    };
    check_grid_memory(problem, &g, options)?;
    Ok((g, note))
}

/// The time discretisation of the exact methods: horizon, output step, implicit step, and the
/// sorted extra output times.
struct TimeSteps {
    t_end: f64,
    span: f64,
    output_step: f64,
    dt: f64,
    extra: Vec<f64>,
}

impl TimeSteps {
    /// The options' output step and `dt` (or their defaults) for `problem`. Errors:
    /// [`Error::InvalidOption`] for extra times before `t0`, a non-positive step.
    fn of<S: Sde + ?Sized, O: Observation + ?Sized>(
        problem: &EstimationProblem<'_, S, O>,
        options: &ExactOptions,
    ) -> Result<TimeSteps> {
        let data = problem.data;
        let (t0, t_last) = (problem.t0, data.times.last().copied().unwrap_or(problem.t0));
        if let Some(&t) = options.extra_times.iter().find(|&&t| !t.is_finite() || t < t0) {
            return Err(invalid("output times", format!("must be finite and not before t0 = {t0}, got {t}")));
        }
        let mut extra = options.extra_times.clone();
        extra.sort_by(f64::total_cmp);
        let t_end = extra.iter().copied().fold(t_last.max(t0), f64::max);
        let span = t_end - t0;
        let output_step = match options.output_step {
            Some(s) => s,
            None if data.len() > 1 => (t_last - data.times[0]) / (data.len() - 1) as f64 / 10.0,
            None if span > 0.0 => span / 10.0,
            None => 1.0,
        };
        if !(output_step.is_finite() && output_step > 0.0) {
            return Err(invalid("output step", format!("must be positive and finite, got {output_step}")));
        }
        let dt = options.dt.unwrap_or(match options.scheme {
            TimeScheme::TrBdf2 => output_step / 2.0,
            TimeScheme::ImplicitEuler => output_step / 4.0,
        });
        if !(dt.is_finite() && dt > 0.0) {
            return Err(invalid("dt", format!("must be positive and finite, got {dt}")));
        }
        Ok(TimeSteps { t_end, span, output_step, dt, extra })
    }
}

/// Bytes per cell and stored time of the exact methods (the densities P and A and their
/// products at every output time, the log-likelihoods at the measurements): six `f64`.
const GRID_BYTES_PER_CELL_TIME: f64 = 48.0;

/// Bytes per cell independent of the times (coordinates, the operator and the factorisations of
/// [`STEP_SIZES_BUDGETED`] step sizes).
const GRID_BYTES_PER_CELL: f64 = 512.0;

/// Bytes per cell and axis of the factors of one step size, kept for the whole estimate when the
/// drift is autonomous (three `f64` for the two-stage step, three for the damped step).
const GRID_BYTES_PER_CELL_AXIS_STEP: f64 = 48.0;

/// The step sizes whose factors [`GRID_BYTES_PER_CELL`] covers; each further one is counted.
const STEP_SIZES_BUDGETED: usize = 2;

/// Checks the memory of the exact methods on `spec` against the problem's
/// [`MemoryLimit`](crate::estimate::MemoryLimit), before anything of the grid is allocated:
/// cells × (stored times × 48 B + 512 B). Errors: [`Error::MemoryLimit`].
pub fn check_grid_memory<S: Sde + ?Sized, O: Observation + ?Sized>(
    problem: &EstimationProblem<'_, S, O>,
    spec: &GridSpec,
    options: &ExactOptions,
) -> Result<()> {
    check_grid_memory_with_steps(problem, spec, options, STEP_SIZES_BUDGETED)
}

/// [`check_grid_memory`] with the factors of `step_sizes` distinct step sizes kept.
fn check_grid_memory_with_steps<S: Sde + ?Sized, O: Observation + ?Sized>(
    problem: &EstimationProblem<'_, S, O>,
    spec: &GridSpec,
    options: &ExactOptions,
    step_sizes: usize,
) -> Result<()> {
    match grid_memory(problem, spec, options, step_sizes) {
        Some((bytes, size)) => problem.max_memory.check("the grid", size, bytes),
        None => Ok(()), // reported with its own message by the discretisation
    }
}

/// The memory estimate of [`check_grid_memory`] in bytes, and the sizes it counts: the step
/// sizes beyond [`STEP_SIZES_BUDGETED`] add cells × axes × 48 B each (measurement times off the
/// output grid make two sizes each). `None` when the time steps are not valid.
fn grid_memory<S: Sde + ?Sized, O: Observation + ?Sized>(
    problem: &EstimationProblem<'_, S, O>,
    spec: &GridSpec,
    options: &ExactOptions,
    step_sizes: usize,
) -> Option<(f64, String)> {
    let cells: f64 = spec.cells.iter().map(|&c| c as f64).product();
    let ts = TimeSteps::of(problem, options).ok()?;
    let times = ts.span / ts.output_step + (ts.extra.len() + problem.data.len() + 2) as f64;
    let extra_steps = step_sizes.saturating_sub(STEP_SIZES_BUDGETED) as f64;
    let per_cell = times * GRID_BYTES_PER_CELL_TIME
        + GRID_BYTES_PER_CELL
        + extra_steps * spec.cells.len() as f64 * GRID_BYTES_PER_CELL_AXIS_STEP;
    let mut size = format!("{cells:.0} grid cells × {:.0} stored times", times.ceil());
    if step_sizes > STEP_SIZES_BUDGETED {
        size.push_str(&format!(", the factors of {step_sizes} time-step sizes"));
    }
    Some((cells * per_cell, size))
}

fn invalid(name: &str, reason: impl Into<String>) -> Error {
    Error::InvalidOption { name: name.into(), reason: reason.into() }
}

/// Stored result of a forward sweep.
#[derive(Debug, Clone)]
struct Forward {
    /// P(t+) at every event.
    p: Vec<Vec<f64>>,
    /// Jump weights e_k (shifted so that their maximum is 1), per measurement.
    e: Vec<Vec<f64>>,
    /// W'_k = Σ e_k P(t_k−) with the shifted weights, per measurement.
    w: Vec<f64>,
    /// log W_k (unshifted), per measurement.
    log_w: Vec<f64>,
}

/// The exact discretisation of one problem: grid, operator, initial density, event times.
pub struct ExactGrid<'a, S: Sde + ?Sized> {
    fp: FokkerPlanck<'a, S>,
    grid: Grid,
    p0: Vec<f64>,
    /// Event (output) times.
    times: Vec<f64>,
    /// Measurement index of each event.
    meas_of_event: Vec<Option<usize>>,
    /// Event index of each measurement.
    event_of_meas: Vec<usize>,
    /// Measurement times.
    meas_times: Vec<f64>,
    /// Substeps (count, size) from event e to e + 1.
    substeps: Vec<(usize, f64)>,
    /// Coordinate of every state at every cell.
    coords: Vec<Vec<f64>>,
}

impl<S: Sde + ?Sized> std::fmt::Debug for ExactGrid<'_, S> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ExactGrid").field("grid", &self.grid).field("events", &self.times.len()).finish()
    }
}

/// The product of the priors at the cell centres, normalised on the grid (log-sum-exp safe).
fn initial_density(grid: &Grid, priors: &[Prior]) -> Result<Vec<f64>> {
    let mut c = vec![0.0; grid.dim()];
    let logs: Vec<f64> = (0..grid.len())
        .map(|i| {
            grid.coords(i, &mut c);
            priors.iter().zip(&c).map(|(p, &x)| p.log_density(x)).sum::<f64>()
        })
        .collect();
    let mut p = vec![0.0; logs.len()];
    match onsager_closures::normalize_log_weights(&logs, &mut p) {
        Some(_) => Ok(p),
        None => {
            Err(invalid("x0 prior", "the initial prior puts no mass on the grid (does the grid cover it?)"))
        }
    }
}

impl<'a, S: Sde + ?Sized> ExactGrid<'a, S> {
    /// Discretises the problem: the grid (axes = states, noisy then clean), the initial density
    /// (the product of the x0 and z0 priors at the cell centres, normalised on the grid), the
    /// event times (`t0`, the output grid, the measurement times) and the substeps.
    ///
    /// Errors ([`Error::InvalidOption`] unless noted): more than [`MAX_AXES`] noisy states or a
    /// grid whose axes are not the states; parameters to estimate (the grid methods take θ as
    /// given); data before `t0`; non-positive `dt` or output step; a prior with no mass on the
    /// grid; [`Error::SingularDiffusion`] for a bad G(θ).
    pub fn try_new<O: Observation + ?Sized>(
        problem: &EstimationProblem<'a, S, O>,
        options: &ExactOptions,
    ) -> Result<Self> {
        problem.validate()?;
        let (spec, _) = grid_of(problem, options)?;
        let grid = Grid::try_new(spec.clone())?;
        check_model_fits_grid(problem.sde, &grid)?;
        if !problem.estimate.is_empty() {
            return Err(invalid(
                "estimate",
                "the grid methods do not estimate parameters; θ is taken as given",
            ));
        }
        let data = problem.data;
        let TimeSteps { t_end, span, output_step, dt, extra } = TimeSteps::of(problem, options)?;
        let t0 = problem.t0;
        let n_ratio = span / output_step + 1e-9;
        // The stored densities (output times × cells) are checked against the memory limit by
        // `grid_of`; the time steps here.
        if span / dt > 1e8 {
            return Err(invalid(
                "dt",
                format!("{} time steps is too many; use a larger dt", (span / dt).ceil()),
            ));
        }
        let n_out = n_ratio.floor() as usize;
        let grid_times: Vec<f64> = (0..=n_out).map(|k| t0 + k as f64 * output_step).collect();
        let others: Vec<f64> = grid_times.iter().chain(&extra).copied().chain([t_end]).collect();
        let EventTimes { times, measurement: meas_of_event, index_of_measurement: event_of_meas } =
            EventTimes::merge(&data.times, &others);
        let mut substeps: Vec<(usize, f64)> = times
            .windows(2)
            .map(|w| {
                let delta = w[1] - w[0];
                let n = ((delta / dt) - 1e-9).ceil().max(1.0) as usize;
                (n, delta / n as f64)
            })
            .collect();
        let dts = snap_step_sizes(&mut substeps);
        let probes = [t0, t0 + 0.37 * span + 0.1, t_end + 0.71];
        let mut fp =
            FokkerPlanck::try_new(problem.sde, problem.theta, &grid, &probes)?.with_scheme(options.scheme);
        if fp.is_autonomous() {
            check_grid_memory_with_steps(problem, &spec, options, dts.len())?;
        }
        fp.prepare(&dts);
        let priors: Vec<Prior> = problem.x0_prior.iter().chain(problem.z0_prior).copied().collect();
        let p0 = initial_density(&grid, &priors)?;
        let coords = (0..grid.dim()).map(|a| grid.coordinate(a)).collect();
        Ok(ExactGrid {
            fp,
            grid,
            p0,
            times,
            meas_of_event,
            event_of_meas,
            meas_times: data.times.clone(),
            substeps,
            coords,
        })
    }

    /// The grid.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// The event (output) times, measurement times included.
    pub fn times(&self) -> &[f64] {
        &self.times
    }

    /// The measurement times.
    pub fn measurement_times(&self) -> &[f64] {
        &self.meas_times
    }

    /// The initial density (cell masses).
    pub fn initial_density(&self) -> &[f64] {
        &self.p0
    }

    /// The value of state `a` at every cell.
    pub fn coordinate(&self, a: usize) -> &[f64] {
        &self.coords[a]
    }

    /// Total number of implicit time steps of one sweep.
    pub fn n_steps(&self) -> usize {
        self.substeps.iter().map(|s| s.0).sum()
    }

    /// The tridiagonal solves of the sweeps so far ([`FokkerPlanck::solves`]).
    pub fn solves(&self) -> usize {
        self.fp.solves()
    }

    /// The scheme of step j (1-based) of the interval after event e: damped for the first step
    /// after t0 and after every measurement, the second-order step otherwise.
    fn step_kind(&self, e: usize, j: usize) -> StepKind {
        if j == 1 && (e == 0 || self.meas_of_event[e].is_some()) {
            StepKind::Damped
        } else {
            StepKind::Smooth
        }
    }

    fn propagate(&self, e: usize, m: &mut [f64], mut each: impl FnMut(&[f64])) {
        let (n, dt) = self.substeps[e];
        for j in 1..=n {
            self.fp.step(self.times[e] + j as f64 * dt, dt, self.step_kind(e, j), m);
            each(m);
        }
    }

    fn propagate_back(&self, e: usize, a: &mut [f64], mut each: impl FnMut(&[f64], usize)) {
        let (n, dt) = self.substeps[e];
        for j in (1..=n).rev() {
            self.fp.step_adjoint(self.times[e] + j as f64 * dt, dt, self.step_kind(e, j), a);
            each(a, j - 1);
        }
    }

    /// The forward sweep with log jump weights `log_e[k][cell]`; errors when a jump has zero
    /// total weight (the data are not covered by the grid). `each_step` sees P after every
    /// implicit step (diagnostics).
    fn forward(&self, log_e: &[Vec<f64>], mut each_step: impl FnMut(&[f64])) -> Result<Forward> {
        let nm = self.meas_times.len();
        let mut p = self.p0.clone();
        let mut out = Forward {
            p: Vec::with_capacity(self.times.len()),
            e: Vec::with_capacity(nm),
            w: Vec::with_capacity(nm),
            log_w: Vec::with_capacity(nm),
        };
        for ev in 0..self.times.len() {
            if let Some(k) = self.meas_of_event[ev] {
                let lw = &log_e[k];
                let max = lw
                    .iter()
                    .zip(&p)
                    .filter(|(_, &pi)| pi > 0.0)
                    .map(|(&l, _)| l)
                    .filter(|l| !l.is_nan())
                    .fold(f64::NEG_INFINITY, f64::max);
                if max == f64::NEG_INFINITY {
                    return Err(invalid(
                        "data",
                        format!(
                            "the measurement at t = {} has zero weight on the whole grid (does the grid cover the data?)",
                            self.meas_times[k]
                        ),
                    ));
                }
                let e: Vec<f64> =
                    lw.iter().map(|&l| if l.is_nan() { 0.0 } else { (l - max).exp() }).collect();
                let w: f64 = e.iter().zip(&p).map(|(a, b)| a * b).sum();
                if w.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) || !max.is_finite() {
                    return Err(invalid(
                        "data",
                        format!(
                            "the jump at t = {} is not finite or has zero weight (does the grid cover the data?)",
                            self.meas_times[k]
                        ),
                    ));
                }
                p.iter_mut().zip(&e).for_each(|(pi, ei)| *pi *= ei / w);
                out.log_w.push(max + w.ln());
                out.e.push(e);
                out.w.push(w);
            }
            out.p.push(p.clone());
            if ev + 1 < self.times.len() {
                self.propagate(ev, &mut p, &mut each_step);
            }
        }
        Ok(out)
    }

    /// The backward sweep: A(t+) at every event.
    fn backward(&self, fw: &Forward, mut each_step: impl FnMut(usize, usize, &[f64])) -> Vec<Vec<f64>> {
        let ne = self.times.len();
        let mut a = vec![1.0; self.grid.len()];
        let mut out = vec![Vec::new(); ne];
        for ev in (0..ne).rev() {
            out[ev] = a.clone();
            if let Some(k) = self.meas_of_event[ev] {
                let (e, w) = (&fw.e[k], fw.w[k]);
                a.iter_mut().zip(e).for_each(|(ai, ei)| *ai *= ei / w);
            }
            if ev > 0 {
                self.propagate_back(ev - 1, &mut a, |a, j| each_step(ev - 1, j, a));
            }
        }
        out
    }

    /// Mean and variance of every state under the cell masses `q`.
    fn moments(&self, q: &[f64]) -> (Vec<f64>, Vec<f64>) {
        let d = self.coords.len();
        let mut mean = vec![0.0; d];
        let mut var = vec![0.0; d];
        for a in 0..d {
            let m: f64 = self.coords[a].iter().zip(q).map(|(x, w)| x * w).sum();
            let v: f64 = self.coords[a].iter().zip(q).map(|(x, w)| (x - m) * (x - m) * w).sum();
            mean[a] = m;
            var[a] = v.max(0.0);
        }
        (mean, var)
    }
}

/// Cov(x_i(τ), Z_m) per event τ (states × multipliers).
type CrossCovariances = Vec<DMatrix<f64>>;

/// Per-step diagnostics of one forward–backward sweep (see [`ExactAction::diagnostics`]).
#[derive(Debug, Clone, PartialEq)]
pub struct SweepDiagnostics {
    /// Total mass Σ P after every implicit step of the forward sweep.
    pub mass: Vec<f64>,
    /// The largest negative mass Σ max(−P, 0) after an implicit step of the forward sweep,
    /// relative to the total (the second-order step keeps positivity only approximately).
    pub negative_mass: f64,
    /// ⟨A, P⟩ after every implicit step of the backward sweep (paired with the stored P of the
    /// same step).
    pub pairing: Vec<f64>,
    /// ⟨A(t_k±), P(t_k±)⟩ on both sides of every jump.
    pub pairing_at_jumps: Vec<(f64, f64)>,
    /// z(t_k−) and z(t_k+) = ⟨Z A P⟩ on both sides of every jump (first measured component).
    pub z_at_jumps: Vec<(f64, f64)>,
    /// max |P(t_k+) − P(t_k−)| and max |A(t_k+) − A(t_k−)| at every jump.
    pub jumps: Vec<(f64, f64)>,
}

/// The exact effective action of a problem with Gaussian measurements of states: an
/// [`EffectiveAction`] on an [`ExactGrid`] with Z = the measured states
/// (`003_d2fc48a470e528fc.txt (I.61)–(I.76)`).
pub struct ExactAction<'a, S: Sde + ?Sized> {
    grid: ExactGrid<'a, S>,
    /// Z_a at every cell, per measured component a.
    z_cells: Vec<Vec<f64>>,
    cache: Option<(Vec<f64>, Forward, Vec<Vec<f64>>)>,
}

impl<S: Sde + ?Sized> std::fmt::Debug for ExactAction<'_, S> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ExactAction").field("grid", &self.grid).finish()
    }
}

/// Checks that every measurement of a gridded state lies inside the grid.
pub fn check_grid_covers(grid: &Grid, observation: &StateMeasurement, data: &Dataset) -> Result<()> {
    let inside = |state: usize, y: f64| state >= grid.dim() || grid.covers(state, y);
    match observation.first_datum_outside(data, inside) {
        Some((state, datum)) => Err(invalid(
            "grid",
            format!(
                "the grid [{}, {}] of axis {state} does not cover the datum {datum}",
                grid.spec().lo[state],
                grid.spec().hi[state]
            ),
        )),
        None => Ok(()),
    }
}

/// The dual data of a problem with Gaussian state measurements; [`Error::InvalidOption`] for a
/// non-Gaussian likelihood.
pub fn gaussian_dual_data<S: Sde + ?Sized>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
) -> Result<DualData> {
    let obs = problem.observation;
    let sigma = obs.noise.gaussian_sigma(
        &problem.sde.param_names(),
        "the mean-optimal estimator (003 I.52)",
        "use --method ksp for other likelihoods",
    )?;
    let sd = sigma
        .value(problem.theta)
        .ok_or_else(|| invalid("likelihood", "the measurement sd refers to a parameter out of range"))?;
    if !(sd.is_finite() && sd > 0.0) {
        return Err(invalid("likelihood", format!("the Gaussian sd must be positive and finite, got {sd}")));
    }
    let r: Vec<f64> = problem.data.values.iter().flat_map(|row| row.iter().copied()).collect();
    let variance = vec![sd * sd; r.len()];
    Ok(DualData { r, variance, output_dim: obs.states.len() })
}

impl<'a, S: Sde + ?Sized> ExactAction<'a, S> {
    /// The exact action of `problem` (Gaussian measurements of states) on the options' grid.
    /// Errors as [`ExactGrid::try_new`] and [`check_grid_covers`].
    pub fn try_new(
        problem: &EstimationProblem<'a, S, StateMeasurement>,
        options: &ExactOptions,
    ) -> Result<Self> {
        let grid = ExactGrid::try_new(problem, options)?;
        problem.observation.validate(problem.sde.dims(), problem.theta)?;
        check_grid_covers(grid.grid(), problem.observation, problem.data)?;
        let z_cells = problem.observation.states.iter().map(|&s| grid.coords[s].clone()).collect();
        Ok(ExactAction { grid, z_cells, cache: None })
    }

    /// The underlying grid discretisation.
    pub fn exact_grid(&self) -> &ExactGrid<'a, S> {
        &self.grid
    }

    fn log_weights(&self, lambda: &[f64]) -> Vec<Vec<f64>> {
        let s = self.z_cells.len();
        (0..self.grid.meas_times.len())
            .map(|k| {
                (0..self.grid.grid.len())
                    .map(|i| (0..s).map(|a| lambda[k * s + a] * self.z_cells[a][i]).sum())
                    .collect()
            })
            .collect()
    }

    fn sweep(&mut self, lambda: &[f64]) -> Result<()> {
        crate::model::check_len(
            "multipliers",
            self.grid.meas_times.len() * self.z_cells.len(),
            lambda.len(),
        )?;
        if let Some((l, _, _)) = &self.cache {
            if l.as_slice() == lambda {
                return Ok(());
            }
        }
        if lambda.iter().any(|v| !v.is_finite()) {
            return Err(Error::NonFinite { what: "multipliers".into() });
        }
        let fw = self.grid.forward(&self.log_weights(lambda), |_| {})?;
        let a = self.grid.backward(&fw, |_, _, _| {});
        self.cache = Some((lambda.to_vec(), fw, a));
        Ok(())
    }

    /// Runs one sweep at λ and records the discrete identities at every step: total mass,
    /// ⟨A, P⟩, and both sides of every jump.
    pub fn diagnostics(&mut self, lambda: &[f64]) -> Result<SweepDiagnostics> {
        let g = &self.grid;
        let mut ps: Vec<Vec<f64>> = Vec::new();
        let mut mass = Vec::new();
        let mut negative_mass = 0.0f64;
        let fw = g.forward(&self.log_weights(lambda), |p| {
            let total: f64 = p.iter().sum();
            negative_mass = negative_mass.max(p.iter().map(|&v| (-v).max(0.0)).sum::<f64>() / total);
            mass.push(total);
            ps.push(p.to_vec());
        })?;
        // Index of the first step of each interval in `ps`.
        let mut first = Vec::with_capacity(g.substeps.len());
        let mut acc = 0;
        for s in &g.substeps {
            first.push(acc);
            acc += s.0;
        }
        let mut pairing = Vec::new();
        let a = g.backward(&fw, |e, j, a| {
            // After the adjoint step ending at substep j + 1 of interval e, a is at substep j.
            let p: &[f64] = if j == 0 { &fw.p[e] } else { &ps[first[e] + j - 1] };
            pairing.push(dot(a, p));
        });
        let mut pairing_at_jumps = Vec::new();
        let mut z_at_jumps = Vec::new();
        let mut jumps = Vec::new();
        for (k, &ev) in g.event_of_meas.iter().enumerate() {
            let (e, w) = (&fw.e[k], fw.w[k]);
            let p_plus = &fw.p[ev];
            let p_minus: Vec<f64> =
                p_plus.iter().zip(e).map(|(p, ei)| if *ei > 0.0 { p * w / ei } else { 0.0 }).collect();
            let a_plus = &a[ev];
            let a_minus: Vec<f64> = a_plus.iter().zip(e).map(|(ai, ei)| ai * ei / w).collect();
            pairing_at_jumps.push((dot(&a_minus, &p_minus), dot(a_plus, p_plus)));
            let z = &self.z_cells[0];
            let zm: f64 = (0..z.len()).map(|i| z[i] * a_minus[i] * p_minus[i]).sum();
            let zp: f64 = (0..z.len()).map(|i| z[i] * a_plus[i] * p_plus[i]).sum();
            z_at_jumps.push((zm, zp));
            let dp = p_plus.iter().zip(&p_minus).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
            let da = a_plus.iter().zip(&a_minus).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
            jumps.push((dp, da));
        }
        Ok(SweepDiagnostics { mass, negative_mass, pairing, pairing_at_jumps, z_at_jumps, jumps })
    }

    /// The tangent sweeps of the covariances under the tilted measure: the Hessian ∇²F (`(I.87)`)
    /// and, with `cross`, Cov(x_i(τ), Z_m) at every event τ.
    ///
    /// The forward tangent of multiplier (k, b) starts at t_k from (Z_b − z_kb) P(t_k+) and is
    /// propagated and jumped like P; ⟨A, g T⟩ at a later time τ is Cov(g(X_τ), Z_kb). The backward
    /// tangent starts from (Z_b − z_kb) A(t_k−) and is propagated and jumped like A; ⟨g U, P⟩ at an
    /// earlier τ is the same covariance. All tangents run in lockstep (interleaved storage).
    fn covariances(
        &mut self,
        lambda: &[f64],
        cross: bool,
    ) -> Result<(DMatrix<f64>, Option<CrossCovariances>)> {
        self.sweep(lambda)?;
        let (_, fw, a) = self.cache.as_ref().expect("swept");
        let g = &self.grid;
        let s = self.z_cells.len();
        let nm = g.meas_times.len();
        let ns = g.coords.len();
        let ne = g.times.len();
        let nc = g.grid.len();
        let m = nm * s;
        let mut zk = vec![0.0; m];
        for k in 0..nm {
            let ev = g.event_of_meas[k];
            for b in 0..s {
                zk[k * s + b] = (0..nc).map(|i| self.z_cells[b][i] * a[ev][i] * fw.p[ev][i]).sum();
            }
        }
        let mut h = DMatrix::zeros(m, m);
        let mut cr = if cross { Some(vec![DMatrix::zeros(ns, m); ne]) } else { None };
        let mut acc = vec![0.0; m];
        // Σ_cell weight[cell] · x[cell · m + v] for v < active.
        let contract = |weight: &dyn Fn(usize) -> f64, x: &[f64], active: usize, acc: &mut [f64]| {
            acc[..active].iter_mut().for_each(|v| *v = 0.0);
            for cell in 0..nc {
                let w = weight(cell);
                if w != 0.0 {
                    for (o, xv) in acc[..active].iter_mut().zip(&x[cell * m..cell * m + active]) {
                        *o += w * xv;
                    }
                }
            }
        };
        let jump = |x: &mut [f64], j: usize, active: usize| {
            let (e, w) = (&fw.e[j], fw.w[j]);
            for cell in 0..nc {
                let f = e[cell] / w;
                x[cell * m..cell * m + active].iter_mut().for_each(|v| *v *= f);
            }
        };
        // Forward tangents, vector v = k · s + b.
        let mut t = vec![0.0; nc * m];
        let mut active = 0;
        for ev in 0..ne {
            if ev > 0 && active > 0 {
                let (n, dt) = g.substeps[ev - 1];
                for jstep in 1..=n {
                    let kind = g.step_kind(ev - 1, jstep);
                    g.fp.step_batch(g.times[ev - 1] + jstep as f64 * dt, dt, kind, &mut t, m, active);
                }
                if let Some(j) = g.meas_of_event[ev] {
                    jump(&mut t, j, active);
                }
            }
            if let Some(k) = g.meas_of_event[ev] {
                for b in 0..s {
                    let v = k * s + b;
                    for cell in 0..nc {
                        t[cell * m + v] = (self.z_cells[b][cell] - zk[v]) * fw.p[ev][cell];
                    }
                }
                active = (k + 1) * s;
                for c in 0..s {
                    let zc = &self.z_cells[c];
                    contract(&|cell| zc[cell] * a[ev][cell], &t, active, &mut acc);
                    for v in 0..active {
                        h[(k * s + c, v)] = acc[v];
                    }
                }
            }
            if let Some(cr) = cr.as_mut() {
                if active > 0 {
                    for i in 0..ns {
                        let xi = &g.coords[i];
                        contract(&|cell| xi[cell] * a[ev][cell], &t, active, &mut acc);
                        for v in 0..active {
                            cr[ev][(i, v)] = acc[v];
                        }
                    }
                }
            }
        }
        // The forward tangents fill the lower triangle (row time ≥ column time); mirror it.
        for c in 0..m {
            for r in 0..c {
                h[(r, c)] = h[(c, r)];
            }
        }
        if let Some(cr) = cr.as_mut() {
            // Backward tangents, vector v = (nm − 1 − k) · s + b (they start in reverse time order).
            let col = |v: usize| (nm - 1 - v / s) * s + v % s;
            let mut u = vec![0.0; nc * m];
            let mut active = 0;
            for ev in (0..ne).rev() {
                if ev + 1 < ne && active > 0 {
                    let (n, dt) = g.substeps[ev];
                    for jstep in (1..=n).rev() {
                        let kind = g.step_kind(ev, jstep);
                        g.fp.step_adjoint_batch(g.times[ev] + jstep as f64 * dt, dt, kind, &mut u, m, active);
                    }
                    for i in 0..ns {
                        let xi = &g.coords[i];
                        contract(&|cell| xi[cell] * fw.p[ev][cell], &u, active, &mut acc);
                        for v in 0..active {
                            cr[ev][(i, col(v))] = acc[v];
                        }
                    }
                }
                if let Some(k) = g.meas_of_event[ev] {
                    if active > 0 {
                        jump(&mut u, k, active);
                    }
                    let (e, w) = (&fw.e[k], fw.w[k]);
                    for b in 0..s {
                        let v = (nm - 1 - k) * s + b;
                        let zv = zk[k * s + b];
                        for cell in 0..nc {
                            u[cell * m + v] = (self.z_cells[b][cell] - zv) * a[ev][cell] * e[cell] / w;
                        }
                    }
                    active = (nm - k) * s;
                }
            }
        }
        Ok((h, cr))
    }
}

impl<S: Sde + ?Sized> EffectiveAction for ExactAction<'_, S> {
    fn measurement_times(&self) -> &[f64] {
        &self.grid.meas_times
    }

    fn output_dim(&self) -> usize {
        self.z_cells.len()
    }

    /// F(λ) = Σ log W_k (`(I.73)–(I.75)`) and z_k = ⟨Z A P⟩(t_k) (`(I.76)`), exact derivatives of
    /// the discrete F (the backward step is the transpose of the forward step).
    fn evaluate(&mut self, lambda: &[f64]) -> Result<ActionValue> {
        self.sweep(lambda)?;
        let (_, fw, a) = self.cache.as_ref().expect("swept");
        let g = &self.grid;
        let s = self.z_cells.len();
        let mut z = Vec::with_capacity(lambda.len());
        for &ev in &g.event_of_meas {
            for zc in &self.z_cells {
                z.push((0..g.grid.len()).map(|i| zc[i] * a[ev][i] * fw.p[ev][i]).sum());
            }
        }
        debug_assert_eq!(z.len(), g.meas_times.len() * s);
        Ok(ActionValue { value: fw.log_w.iter().sum(), z })
    }

    /// The exact Hessian of the discrete F by one forward tangent sweep per multiplier.
    fn hessian(&mut self, lambda: &[f64]) -> Result<Swept<DMatrix<f64>>> {
        Ok(Ok(self.covariances(lambda, false)?.0))
    }

    /// The history and ∇²F from the same tangent sweeps.
    fn history_and_hessian(&mut self, lambda: &[f64]) -> Result<Swept<(History, DMatrix<f64>)>> {
        let (hessian, cross) = self.covariances(lambda, true)?;
        let history = self.history(lambda, false)?.map(|h| History { cross, ..h });
        Ok(history.map(|h| (h, hessian)))
    }

    fn history(&mut self, lambda: &[f64], cross: bool) -> Result<Swept<History>> {
        let cr = if cross { self.covariances(lambda, true)?.1 } else { None };
        self.sweep(lambda)?;
        let (_, fw, a) = self.cache.as_ref().expect("swept");
        let g = &self.grid;
        let (mut mean, mut variance) = (Vec::new(), Vec::new());
        for (a_ev, p_ev) in a.iter().zip(&fw.p) {
            let q: Vec<f64> = a_ev.iter().zip(p_ev).map(|(x, y)| x * y).collect();
            let (m, v) = g.moments(&q);
            mean.push(m);
            variance.push(v);
        }
        Ok(Ok(History { times: g.times.clone(), mean, variance, cross: cr }))
    }
}

/// The result of the exact mean-optimal estimator.
#[derive(Debug, Clone, PartialEq)]
pub struct MeanOptimal {
    /// The estimate z(t) of every state at the output times, with the tilted-measure moments.
    pub history: History,
    /// The standard deviation of every state at the output times: the ensemble dispersion
    /// ([`super::dispersion::posterior_variance`]) when the dual succeeded (see `sd_kind`).
    pub sd: Vec<Vec<f64>>,
    /// What `sd` is.
    pub sd_kind: SdKind,
    /// The dual solution (λ*, z*, residual, iterations, status).
    pub dual: DualSolution,
    /// The estimate's status.
    pub status: Status,
    /// The report's details.
    pub details: DualDetails,
    /// Seconds spent in the solve.
    pub solve_seconds: f64,
    /// Where the KSP densities on the same grid reach its edge, if they do.
    pub edge: Option<GridEdge>,
}

/// The exact mean-optimal (effective-action) estimator on a grid, `003_d2fc48a470e528fc.txt`
/// Sec. I.5: maximises the dual Φ(λ) ([`super::dual::maximize_dual`]) on the [`ExactAction`], starting from
/// λ_k = R_k⁻¹(r_k − z_k^KSP) with the KSP smoothed mean, and reports the history z(t) (`(I.76)`)
/// and the ensemble dispersion (`(I.85)–(I.90)`) by [`super::mean_optimal::solve`].
///
/// When the dual does not succeed the history at the last λ is reported with the
/// tilted-measure sd instead of the dispersion.
///
/// Errors: those of [`ExactAction::try_new`]; a non-Gaussian likelihood
/// ([`gaussian_dual_data`]).
pub fn mean_optimal<S: Sde + ?Sized>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    options: impl Into<MeanOptimalOptions>,
) -> Result<MeanOptimal> {
    let options = &options.into();
    let start = Instant::now();
    options.dual.validate()?;
    let data = gaussian_dual_data(problem)?;
    let mut action = ExactAction::try_new(problem, &options.exact)?;
    // Start from λ_k = R_k⁻¹(r_k − z_k) with z_k the KSP smoothed mean (one extra sweep): the
    // condition (I.60) evaluated at the optimal estimate's nearest neighbour (cf. (I.79)).
    let ksp = ksp_smoother(problem, &options.exact)?;
    let s = data.output_dim;
    let mut lambda0 = vec![0.0; data.r.len()];
    for (k, &ev) in action.grid.event_of_meas.iter().enumerate() {
        for (b, &state) in problem.observation.states.iter().enumerate() {
            let m = k * s + b;
            if !data.r[m].is_nan() {
                lambda0[m] = (data.r[m] - ksp.smoothed_mean[ev][state]) / data.variance[m];
            }
        }
    }
    let plan = Plan { dual: options.dual.clone(), stages: None, retry_from_zero: false, dispersion: true };
    let sol = super::mean_optimal::solve(&mut action, &data, (lambda0, DualStart::Ksp), &plan)?;
    let mut details = sol.details(None, action.work(), &plan);
    details.tridiagonal_solves = Some(ksp.solves + action.grid.solves());
    Ok(MeanOptimal {
        history: sol.history,
        sd: sol.sd,
        sd_kind: sol.sd_kind,
        dual: sol.dual,
        status: sol.status,
        details,
        solve_seconds: start.elapsed().as_secs_f64(),
        edge: ksp.edge,
    })
}

/// The result of the KSP smoother on a grid.
#[derive(Debug, Clone, PartialEq)]
pub struct KspSmoothing {
    /// Output times (measurement times included).
    pub times: Vec<f64>,
    /// Filtered densities P_*(t) = P(t | r_k, t_k ≤ t) (cell masses) at the output times.
    pub filtered: Vec<Vec<f64>>,
    /// Smoothed densities A_* P_* = P(t | all data) (cell masses) at the output times (`(0.6)`).
    pub smoothed: Vec<Vec<f64>>,
    /// Filtered mean of every state.
    pub filtered_mean: Vec<Vec<f64>>,
    /// Filtered standard deviation of every state.
    pub filtered_sd: Vec<Vec<f64>>,
    /// Smoothed mean of every state.
    pub smoothed_mean: Vec<Vec<f64>>,
    /// Smoothed standard deviation of every state.
    pub smoothed_sd: Vec<Vec<f64>>,
    /// log p(r_1, …, r_n) = Σ_k log ∫ψ(r_k | x) P_*(x, t_k−) dx (`(A.5)`).
    pub log_likelihood: f64,
    /// Seconds spent in the solve.
    pub solve_seconds: f64,
    /// Where the smoothed densities reach the grid's edge, if they do.
    pub edge: Option<GridEdge>,
    /// Tridiagonal solves of the two sweeps ([`FokkerPlanck::solves`]).
    pub solves: usize,
}

/// The Kushner–Stratonovich–Pardoux smoother on a grid with any measurement likelihood
/// (`003_d2fc48a470e528fc.txt (0.3)–(0.7)`, `(I.80)–(I.84)`, Appendix 1 (A.4), (A.9)): one
/// forward sweep with the Bayes jumps P_*(t_k+) ∝ ψ(r_k | x) P_*(t_k−) and one backward sweep
/// with A_*(t_k−) ∝ ψ(r_k | x) A_*(t_k+); the smoothed density is A_* P_*.
///
/// Errors: those of [`ExactGrid::try_new`]; a measurement with zero likelihood on the whole grid
/// (the grid does not cover the data).
pub fn ksp_smoother<S: Sde + ?Sized, O: Observation + ?Sized>(
    problem: &EstimationProblem<'_, S, O>,
    options: &ExactOptions,
) -> Result<KspSmoothing> {
    let start = Instant::now();
    let g = ExactGrid::try_new(problem, options)?;
    let d = problem.sde.dims();
    let mut c = vec![0.0; g.grid.dim()];
    let theta = problem.theta;
    let log_e: Vec<Vec<f64>> = problem
        .data
        .times
        .iter()
        .zip(&problem.data.values)
        .map(|(&t, y)| {
            (0..g.grid.len())
                .map(|i| {
                    g.grid.coords(i, &mut c);
                    let (x, z) = c.split_at(d.noisy);
                    problem.observation.log_likelihood(t, y, x, z, theta)
                })
                .collect()
        })
        .collect();
    let fw = g.forward(&log_e, |_| {})?;
    let a = g.backward(&fw, |_, _, _| {});
    let mut out = KspSmoothing {
        times: g.times.clone(),
        filtered: Vec::new(),
        smoothed: Vec::new(),
        filtered_mean: Vec::new(),
        filtered_sd: Vec::new(),
        smoothed_mean: Vec::new(),
        smoothed_sd: Vec::new(),
        log_likelihood: fw.log_w.iter().sum(),
        solve_seconds: 0.0,
        edge: None,
        solves: g.solves(),
    };
    for (a_ev, p_ev) in a.iter().zip(&fw.p) {
        let q: Vec<f64> = a_ev.iter().zip(p_ev).map(|(x, y)| x * y).collect();
        let (fm, fv) = g.moments(p_ev);
        let (sm, sv) = g.moments(&q);
        out.filtered_mean.push(fm);
        out.filtered_sd.push(fv.iter().map(|v| v.sqrt()).collect());
        out.smoothed_mean.push(sm);
        out.smoothed_sd.push(sv.iter().map(|v| v.sqrt()).collect());
        out.filtered.push(p_ev.clone());
        out.smoothed.push(q);
    }
    out.edge = grid_edge(&g.grid, &out.times, &out.smoothed);
    out.solve_seconds = start.elapsed().as_secs_f64();
    Ok(out)
}

/// The details of a KSP estimate's report.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct KspDetails {
    /// log p(r_1, …, r_n) (`(A.5)`).
    pub log_likelihood: f64,
    /// The number of output times.
    pub output_times: usize,
}

/// The grid of `options` for the problem of an estimator, checked against the model and the
/// data, and the note on a default grid.
fn estimator_grid<S: Sde + ?Sized>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    options: &ExactOptions,
) -> Result<(ExactOptions, Vec<String>)> {
    let (spec, note) = grid_of(problem, options)?;
    let grid = Grid::try_new(spec.clone())?;
    check_model_fits_grid(problem.sde, &grid)?;
    check_grid_covers(&grid, problem.observation, problem.data)?;
    Ok((ExactOptions { grid: Some(spec), ..options.clone() }, note.into_iter().collect()))
}

fn estimate_of<S: Sde + ?Sized, O: Observation + ?Sized>(
    method: Method,
    problem: &EstimationProblem<'_, S, O>,
    (times, mean, sd): (&[f64], &[Vec<f64>], &[Vec<f64>]),
) -> PathEstimate {
    PathEstimate {
        method,
        path: StatePath {
            names: problem.sde.state_names(),
            times: times.to_vec(),
            values: mean.to_vec(),
            sd: Some(sd.to_vec()),
        },
        theta_names: problem.sde.param_names(),
        theta: problem.theta.to_vec(),
        estimated: Vec::new(),
        theta_sd: None,
        status: Status::Converged,
        iterations: 0,
        solve_seconds: 0.0,
        details: Details::default(),
    }
}

/// The KSP result as the common [`PathEstimate`] (method `ksp`): the smoothed mean and sd at
/// the output times; details: [`KspDetails`].
pub fn ksp_path_estimate<S: Sde + ?Sized, O: Observation + ?Sized>(
    problem: &EstimationProblem<'_, S, O>,
    ksp: &KspSmoothing,
) -> PathEstimate {
    let mut est = estimate_of(Method::Ksp, problem, (&ksp.times, &ksp.smoothed_mean, &ksp.smoothed_sd));
    est.solve_seconds = ksp.solve_seconds;
    est.details =
        Details::new(KspDetails { log_likelihood: ksp.log_likelihood, output_times: ksp.times.len() });
    est
}

/// The mean-optimal result as the common [`PathEstimate`] (method `mean-optimal`): the history
/// z(t) and its sd at the output times; details: [`DualDetails`].
pub fn mean_optimal_path_estimate<S: Sde + ?Sized, O: Observation + ?Sized>(
    problem: &EstimationProblem<'_, S, O>,
    mo: &MeanOptimal,
) -> PathEstimate {
    let h = &mo.history;
    let mut est = estimate_of(Method::MeanOptimal, problem, (&h.times, &h.mean, &mo.sd));
    est.status = mo.status;
    est.iterations = mo.dual.iterations;
    est.solve_seconds = mo.solve_seconds;
    est.details = Details::new(mo.details.clone());
    est
}

/// `ksp` as an estimator: [`ksp_smoother`] on the options' grid (by default [`default_grid`],
/// with a note), which must hold the model's states and cover the data.
pub fn ksp_estimate<S: Sde + ?Sized>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    options: &ExactOptions,
) -> Result<MethodRun> {
    let (options, mut notes) = estimator_grid(problem, options)?;
    let ksp = ksp_smoother(problem, &options)?;
    let mut estimate = ksp_path_estimate(problem, &ksp);
    flag_edge(&mut estimate, ksp.edge, options.grid.as_ref().expect("set by estimator_grid"), &mut notes);
    Ok(MethodRun { estimate, notes })
}

/// `mean-optimal` as an estimator: [`mean_optimal`] on the options' grid (as [`ksp_estimate`]).
pub fn mean_optimal_estimate<S: Sde + ?Sized>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    options: &MeanOptimalOptions,
) -> Result<MethodRun> {
    let (exact, mut notes) = estimator_grid(problem, &options.exact)?;
    let grid = exact.grid.clone().expect("set by estimator_grid");
    let mo = mean_optimal(problem, MeanOptimalOptions { exact, dual: options.dual.clone() })?;
    let mut estimate = mean_optimal_path_estimate(problem, &mo);
    flag_edge(&mut estimate, mo.edge, &grid, &mut notes);
    Ok(MethodRun { estimate, notes })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn step_sizes_that_differ_by_rounding_share_one_value() {
        // An output grid of 0.1 on [0, 10] with Δt = 0.05: two substeps per interval, whose sizes
        // differ only by the rounding of t_{k+1} − t_k.
        let times: Vec<f64> = (0..=100).map(|k| k as f64 * 0.1).collect();
        let mut substeps: Vec<(usize, f64)> = times.windows(2).map(|w| (2, (w[1] - w[0]) / 2.0)).collect();
        let mut raw: Vec<f64> = substeps.iter().map(|s| s.1).collect();
        raw.sort_by(f64::total_cmp);
        raw.dedup();
        assert!(raw.len() > 1, "{raw:?}");
        let before = substeps.clone();
        let dts = snap_step_sizes(&mut substeps);
        assert_eq!(dts.len(), 1, "{dts:?}");
        for ((n, h), (n0, h0)) in substeps.iter().zip(&before) {
            assert_eq!((n, *h), (n0, dts[0]));
            assert!((h - h0).abs() <= STEP_SNAP * h0);
        }
        // Sizes further apart stay apart, each step taking its own; a chain of near sizes keeps
        // every step within the tolerance of its own size.
        let h = 0.05;
        let mut steps = [(1, h), (3, 2.0 * h), (1, h * (1.0 + 0.6e-10)), (1, h * (1.0 + 1.2e-10))];
        let dts = snap_step_sizes(&mut steps);
        assert_eq!(dts, [h, h * (1.0 + 1.2e-10), 2.0 * h]);
        assert_eq!(steps.map(|s| s.1), [h, 2.0 * h, h, h * (1.0 + 1.2e-10)]);
    }

    #[test]
    fn the_grid_keeps_one_factorisation_per_step_size_and_counts_them_in_its_memory() {
        use crate::test_models::OuRecord;
        let record = OuRecord::new().unwrap();
        let options =
            ExactOptions { output_step: Some(0.1), ..ExactOptions::new(GridSpec::new_1d(-3.0, 3.0, 60)) }
                .with_dt(0.05);
        // Measurements on the output grid (every 0.5): one size, Δt = 0.05.
        let grid = ExactGrid::try_new(&record.problem(), &options).unwrap();
        assert_eq!(grid.fp.factored_step_sizes(), 1);
        // Off the grid, each at its own offset: each measurement splits an output interval in two
        // sizes of its own.
        let mut data = record.data.clone();
        for (i, t) in data.times.iter_mut().enumerate() {
            *t += 0.007 * (i + 1) as f64;
        }
        let problem = EstimationProblem { data: &data, ..record.problem() };
        let sizes = ExactGrid::try_new(&problem, &options).unwrap().fp.factored_step_sizes();
        assert!(sizes > 10, "{sizes}");
        // A limit that the stored densities fit but the factors of every size do not.
        let spec = options.grid.as_ref().unwrap();
        let (budgeted, _) = grid_memory(&problem, spec, &options, STEP_SIZES_BUDGETED).unwrap();
        let (all, size) = grid_memory(&problem, spec, &options, sizes).unwrap();
        assert!(size.contains(&format!("{sizes} time-step sizes")), "{size}");
        let limit = crate::estimate::MemoryLimit::new((0.5 * (budgeted + all)) as u64);
        let limited = EstimationProblem { max_memory: limit, ..problem };
        check_grid_memory(&limited, spec, &options).unwrap();
        let err = ExactGrid::try_new(&limited, &options).err().unwrap();
        assert!(
            matches!(err, Error::MemoryLimit { .. }) && err.to_string().contains("time-step sizes"),
            "{err}"
        );
    }
}
