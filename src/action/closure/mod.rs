//! Rayleigh–Ritz closures of the effective action (`003_d2fc48a470e528fc.txt` Part II): the
//! mean-optimal estimator with the density restricted to an exponential family
//! p(x; λ) ∝ exp(λᵀM(x)) p_*(x) (`(II.36)`).
//!
//! - [`drift`]: the closure drift W = C⁻¹⟨L*M⟩ (`(II.3)`, `(II.46)`) for the Gaussian family in
//!   any dimension and for exponential families on fixed nodes (user moment sets, e.g. the
//!   quartic M = (x, x², x³, x⁴));
//! - `jet`: the two-variable jets that differentiate the one-state Gaussian closure drift;
//! - [`sweep`]: the forward sweep with the jumps λ(t_k+) = λ(t_k−) + λ_k (`(II.49)`), F = ΣΔF_k
//!   (`(II.51)`), the backward (adjoint) sweep with the jumps (`(II.47)`, `(II.50)`), the history
//!   m(t) = μ + γ (`(II.48)`) and ∂F/∂λ_k = m(t_k) (`(A.30)`), as an
//!   [`EffectiveAction`](super::dual::EffectiveAction), so the dual estimator
//!   ([`maximize_dual`](super::dual::maximize_dual)) and the ensemble dispersion
//!   ([`super::dispersion`]) are those of the exact grid;
//! - [`closure_estimate`]: the estimator as a [`PathEstimate`];
//! - [`area`]: the scalar area-rule closure (one state, one moment, one measured output,
//!   `(II.17)–(II.35)`), its own [`EffectiveAction`](super::dual::EffectiveAction).
//!
//! See `docs/closures.md`.

pub mod area;
pub mod drift;
mod jet;
pub mod om;
pub mod sweep;

pub use drift::{
    ClosureDrift, ExponentialDrift, ExponentialFamily, FamilyMoments, GaussianDrift, GaussianFamily,
    NodeRule, Unrealizable,
};
pub use sweep::{ClosureAction, SweepTolerances};

use std::fmt::Debug;
use std::time::Instant;

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use crate::error::check_positive;
use crate::estimate::{Details, EstimationProblem, Method, MethodRun, PathEstimate};
use crate::estimator::EstimatorOptions;
use crate::model::observation::StateMeasurement;
use crate::model::Sde;
use crate::{Error, Result};

use super::continuation::BranchRule;
use super::dual::DualSolution;
use super::dual::{DualData, DualOptions, EffectiveAction, History, Work};
use super::exact::{gaussian_dual_data, GridEdge};
use super::mean_optimal::{self, CoarseStage, DualStart, Plan, QuadratureCheck};
use crate::Status;

/// How a closure's sweep failed (a numerical outcome): where and why, in words for the report
/// ([`EffectiveAction::last_failure`]), and where the density stood against its box's edge
/// when that is a likely cause (see [`ClosureAction::failure_edge`]).
#[derive(Debug, Clone)]
struct FailureAt {
    why: String,
    edge: Option<GridEdge>,
}

impl FailureAt {
    /// A failure at time `t` of the sweep.
    fn at(t: f64, why: impl std::fmt::Display) -> Self {
        let t = match t.abs() {
            0.0 => "0".to_string(),
            a if a >= 1e-3 => format!("{t:.4}"),
            _ => format!("{t:.2e}"),
        };
        FailureAt { why: format!("at t = {t}: {why}"), edge: None }
    }

    /// A failure whose time is not known.
    fn anywhere(why: impl Into<String>) -> Self {
        FailureAt { why: why.into(), edge: None }
    }
}

/// What a family of trial densities brings to a closure estimator: its options (the struct
/// itself, written flat beside the [`ClosureOptions`] as the estimator's options), its drift
/// on a model, and the initial natural parameters. A new family is its drift and one of these,
/// registered as an [`Estimator`](crate::estimator::Estimator) (docs/extending.md).
pub trait ClosureFamily: Serialize + DeserializeOwned + Default + Clone + Debug + PartialEq {
    /// The closure drift of the family on a model with parameters θ.
    type Drift<'a, S: Sde + ?Sized + 'a>: ClosureDrift;

    /// The estimator's method.
    const METHOD: Method;

    /// The family as written in reports (`Gaussian`, `Exponential { degree: 4 }`).
    fn describe(&self) -> String;

    /// Checks the family's options. Errors: [`Error::InvalidOption`] naming the option.
    fn validate(&self) -> Result<()>;

    /// The drift on `problem`'s model, λ(t₀) of the initial law (the x0 and z0 priors), and for
    /// each measured output the index of its state's linear moment.
    ///
    /// Errors: a model or prior the family cannot take.
    fn setup<'a, S: Sde + ?Sized>(
        &self,
        problem: &EstimationProblem<'a, S, StateMeasurement>,
    ) -> Result<FamilySetup<Self::Drift<'a, S>>>;

    /// The family on finer nodes, to check an estimate's quadrature against and to solve on
    /// when the check fails ([`closure_estimate`]); `None` (the default) for a family whose
    /// expectations are not refined, or when no further refinement is allowed.
    fn refined(&self) -> Option<Refinement<Self>> {
        None
    }

    /// The family on a wider box, to check the estimate on these nodes against when its
    /// density reaches the edge of `support` (the box of the family's drift) as `edge` says,
    /// and to solve on if the means move ([`closure_estimate`]); `start` is the family the
    /// estimate started from (the refinements and widenings it allows). `None` (the default)
    /// for a family without a box.
    fn widened(&self, _start: &Self, _support: &[(f64, f64)], _edge: &GridEdge) -> Option<Widening<Self>> {
        None
    }

    /// How far, in standard deviations of the density, the family's expectations may move when
    /// its nodes move with the density: 0 (the default) for nodes that do not move. The nodes
    /// move with λ in discrete steps, so the computed F and the history carry noise of about
    /// this size, which no dual iteration resolves; the dual's tolerance is matched to it
    /// ([`ClosureOptions::dual_matched_to_sweeps`]). Finite and ≥ 0.
    fn quadrature_noise(&self) -> f64 {
        0.0
    }
}

/// A finer quadrature of a family's expectations ([`ClosureFamily::refined`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Refinement<F> {
    /// The family on the finer nodes.
    pub finer: F,
    /// The largest shift of a state's mean, at the estimate's multipliers, from the nodes to the
    /// finer nodes that the check accepts, in units of the state's typical standard deviation
    /// on the path (the root mean square over the output times).
    pub tolerance: f64,
    /// The nodes and the finer nodes, as written in reports (`12 panels`, `18 panels`).
    pub nodes: (String, String),
}

/// A wider box of a family's expectations ([`ClosureFamily::widened`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Widening<F> {
    /// The family on the wider box with the estimate's last nodes, to check it on.
    pub check: F,
    /// The family on the wider box with the nodes, refinements and widenings (one fewer) the
    /// estimate started with, to solve on.
    pub wider: F,
    /// The largest shift of a state's mean, at the estimate's multipliers, from the box to the
    /// wider box that lets the estimate stand (as [`Refinement::tolerance`]).
    pub tolerance: f64,
    /// Whether the estimate may be solved again on the wider box when the means move by more
    /// (a widening is left).
    pub may_solve: bool,
}

/// A family's drift on a model with its start (see [`ClosureFamily::setup`]).
#[derive(Debug)]
pub struct FamilySetup<D> {
    /// The drift.
    pub drift: D,
    /// λ(t₀): the natural parameters of the initial law.
    pub lambda0: Vec<f64>,
    /// The linear moment of each measured output's state.
    pub measured: Vec<usize>,
}

/// Options of the dual closures, common to every family.
#[non_exhaustive]
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ClosureOptions {
    /// Step of the output grid. Default: the mean measurement spacing / 10 (the horizon / 10
    /// with a single measurement).
    pub output_step: Option<f64>,
    /// Relative tolerance of the Runge–Kutta integration. Default 1e-6. Below 1e-4 the dual's
    /// first iterations run at min(100 · rtol, 1e-4) (and atol × the same factor) and only the
    /// last ones, the history and the dispersion at rtol (see `docs/closures.md`, "Two-stage
    /// dual").
    pub rtol: f64,
    /// Absolute tolerance of the Runge–Kutta integration. Default 1e-9.
    pub atol: f64,
    /// Further output times (finite, ≥ the problem's `t0`). Default none.
    pub extra_times: Vec<f64>,
    /// Whether to compute the ensemble dispersion (sd columns) at the output times
    /// (`(I.85)–(I.90)`, from the tangent sweeps of ∇²F); otherwise the closure density's
    /// variance. Default true.
    pub dispersion: bool,
    /// Whether the dual may also stop where its optimality residual is a tenth of the sweeps'
    /// accuracy, in measurement units: max_m |λ_m − (r_m − z_m)/R_m| ≤
    /// 0.1 · min_a (rtol · max_k |r_ka| + atol + q · max_k R_ka^{1/2}) / max_k R_ka, per measured
    /// output a over its present data, with q the family's [`ClosureFamily::quadrature_noise`]
    /// in standard deviations of the density, R^{1/2} standing in for the density's sd (0 on
    /// fixed nodes; reported as the detail `dual_tolerance`, the larger of this and
    /// `dual.tolerance`; a stop short of it is `Acceptable` within 10 × it). The remaining Newton
    /// correction of a residual ε is K⁻¹Rε, which moves z by ∇²F K⁻¹ Rε: at most Rε in the
    /// R⁻¹-weighted norm where ∇²F is positive semi-definite, about as much for the estimate in
    /// between, more where F is not convex (hence the tenth). Below this level the further Newton
    /// steps buy digits the sweeps do not have (inexact Newton). Default true; false:
    /// `dual.tolerance` alone (see `docs/closures.md`, "The dual's tolerance, its shortest step
    /// and its fallbacks").
    pub dual_matched_to_sweeps: bool,
    /// Which stationary point of the dual is the estimate: `filter` (default), the maximum
    /// Newton's method reaches from the closure's filter (retried from λ = 0); `continuation`,
    /// the one on the branch from the prior followed in the measurement precision, a function
    /// of the data alone (none when the branch is lost or ends at a saddle). See
    /// `docs/closures.md`, "Which stationary point".
    pub branch: BranchRule,
    /// Options of the dual maximisation.
    pub dual: DualOptions,
}

impl Default for ClosureOptions {
    fn default() -> Self {
        ClosureOptions {
            output_step: None,
            rtol: 1e-6,
            atol: 1e-9,
            extra_times: Vec::new(),
            dispersion: true,
            dual_matched_to_sweeps: true,
            branch: BranchRule::default(),
            dual: DualOptions::default(),
        }
    }
}

impl ClosureOptions {
    /// The defaults.
    pub fn new() -> Self {
        Self::default()
    }

    /// Sets the output step.
    pub fn with_output_step(mut self, step: f64) -> Self {
        self.output_step = Some(step);
        self
    }

    /// Sets the Runge–Kutta tolerances.
    pub fn with_tolerances(mut self, rtol: f64, atol: f64) -> Self {
        self.rtol = rtol;
        self.atol = atol;
        self
    }

    /// Adds output times.
    pub fn with_extra_times(mut self, times: &[f64]) -> Self {
        self.extra_times.extend_from_slice(times);
        self
    }

    /// Whether to compute the dispersion.
    pub fn with_dispersion(mut self, dispersion: bool) -> Self {
        self.dispersion = dispersion;
        self
    }

    /// Whether the dual may stop at a tenth of the sweeps' accuracy (see
    /// [`ClosureOptions::dual_matched_to_sweeps`]).
    pub fn with_dual_matched_to_sweeps(mut self, matched: bool) -> Self {
        self.dual_matched_to_sweeps = matched;
        self
    }

    /// Sets the rule that picks the dual's stationary point ([`ClosureOptions::branch`]).
    pub fn with_branch(mut self, branch: BranchRule) -> Self {
        self.branch = branch;
        self
    }

    /// Sets the dual options.
    pub fn with_dual(mut self, dual: DualOptions) -> Self {
        self.dual = dual;
        self
    }

    fn validate(&self) -> Result<()> {
        check_positive("output_step", self.output_step)?;
        check_positive("rtol", self.rtol)?;
        check_positive("atol", self.atol)?;
        if let Some(&t) = self.extra_times.iter().find(|&&t| !t.is_finite()) {
            return Err(invalid("extra_times", format!("must be finite, got {t}")));
        }
        self.dual.validate().map_err(|e| e.within("dual"))
    }
}

/// A dual closure estimator: the family's options and the common ones, written flat
/// (`{"moments": 6, "rtol": 1e-8}`).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default)]
#[non_exhaustive]
pub struct Closure<F> {
    /// The family and its options.
    #[serde(flatten)]
    pub family: F,
    /// The options common to the dual closures.
    #[serde(flatten)]
    pub options: ClosureOptions,
}

impl<F: ClosureFamily> Closure<F> {
    /// The closure of `family` with `options`.
    pub fn new(family: F, options: ClosureOptions) -> Self {
        Closure { family, options }
    }
}

impl Closure<GaussianFamily> {
    /// The Gaussian closure with `options`.
    pub fn gaussian(options: ClosureOptions) -> Self {
        Closure::new(GaussianFamily::default(), options)
    }
}

impl Closure<ExponentialFamily> {
    /// The polynomial exponential closure of `degree` with `options`.
    pub fn exponential(degree: usize, options: ClosureOptions) -> Self {
        Closure::new(ExponentialFamily::of_degree(degree), options)
    }
}

impl<F: ClosureFamily> EstimatorOptions for Closure<F> {
    /// The closure's estimator: [`closure_estimate`].
    fn run<S: Sde + ?Sized>(
        &self,
        _: Method,
        problem: &EstimationProblem<'_, S, StateMeasurement>,
    ) -> Result<MethodRun> {
        closure_estimate(problem, self).map(MethodRun::from)
    }

    /// Checks the family's and the common options.
    fn validate(&self) -> Result<()> {
        self.family.validate()?;
        self.options.validate()
    }
}

fn invalid(name: &str, reason: impl Into<String>) -> Error {
    Error::InvalidOption { name: name.into(), reason: reason.into() }
}

/// The default support [a, b] of a family on a box, for one state: the range of its data
/// `values` (non-finite ones skipped) and of its prior mean ± 5 sd, widened by half its width
/// plus 1 on each side (the `domain` option of the exponential and area-rule closures).
pub(crate) fn default_domain(values: &[f64], mean: f64, var: f64) -> (f64, f64) {
    let sd = var.sqrt();
    let (mut a, mut b) = (mean - 5.0 * sd, mean + 5.0 * sd);
    for &v in values.iter().filter(|v| v.is_finite()) {
        a = a.min(v);
        b = b.max(v);
    }
    let w = b - a;
    (a - 0.5 * w - 1.0, b + 0.5 * w + 1.0)
}

/// Checks that the box `domain` (one interval per state) covers every datum of a measured
/// state: a family on the box is truncated to it, so a datum outside would be explained by a
/// density that cannot reach it. Error ([`Error::InvalidOption`] `domain`): the first datum
/// outside, its state and the box.
pub(crate) fn check_box_covers_data<S: Sde + ?Sized>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    domain: &[(f64, f64)],
) -> Result<()> {
    let inside = |state: usize, y: f64| domain.get(state).is_none_or(|&(a, b)| (a..=b).contains(&y));
    match problem.observation.first_datum_outside(problem.data, inside) {
        Some((state, datum)) => {
            let (a, b) = domain[state];
            Err(invalid(
                "domain",
                format!(
                    "the box [{a}, {b}] of state `{}` does not cover the datum {datum}: the box truncates the \
                     density to it; widen `domain`",
                    problem.sde.state_names()[state]
                ),
            ))
        }
        None => Ok(()),
    }
}

/// The output grid t0 + kΔ up to the last measurement (and the extra times, none before t0).
fn output_times(t0: f64, data_times: &[f64], options: &ClosureOptions) -> Result<Vec<f64>> {
    if let Some(&t) = options.extra_times.iter().find(|&&t| t < t0) {
        return Err(invalid("output times", format!("must not be before t0 = {t0}, got {t}")));
    }
    let t_last = *data_times.last().expect("validated non-empty");
    let t_end = options.extra_times.iter().copied().fold(t_last.max(t0), f64::max);
    let span = t_end - t0;
    let n = data_times.len();
    let step = match options.output_step {
        Some(s) => s,
        None if n > 1 => (t_last - data_times[0]) / (n - 1) as f64 / 10.0,
        None if span > 0.0 => span / 10.0,
        None => 1.0,
    };
    if !(step.is_finite() && step > 0.0) || span / step > 1e7 {
        return Err(invalid("output step", format!("{step} gives too many output times")));
    }
    let k = (span / step + 1e-9).floor() as usize;
    let mut out: Vec<f64> = (0..=k).map(|i| t0 + i as f64 * step).collect();
    out.extend(&options.extra_times);
    out.push(t_end);
    Ok(out)
}

/// The dual's first stage runs its sweeps at this multiple of the relative (and absolute)
/// tolerance, ...
const COARSE_FACTOR: f64 = 100.0;
/// ... but at a relative tolerance of at most this (at 10⁻³ the step-size noise in F defeats the
/// line search on the double-well duals).
const COARSE_RTOL: f64 = 1e-4;
/// The quadrature check's sweeps run at a relative tolerance of at most this fraction of the
/// check's tolerance (and at most [`COARSE_RTOL`], at least the estimate's `rtol`): their error
/// then moves the means by far less than the shift the check looks for.
const CHECK_RTOL_FRACTION: f64 = 1e-2;
/// The dual's residual, in measurement units, may stop at this fraction of the sweeps'
/// accuracy ([`ClosureOptions::dual_matched_to_sweeps`]).
const SWEEP_MATCH: f64 = 0.1;

/// The dual's options at the requested sweep tolerances: `options.dual`, and with
/// [`ClosureOptions::dual_matched_to_sweeps`] the tolerance raised to
/// [`SWEEP_MATCH`] · min_a (rtol · max_k |r_ka| + atol + q · max_k R_ka^{1/2}) / max_k R_ka
/// (per measured output a, over its present data; q = `noise`, the family's
/// [`ClosureFamily::quadrature_noise`] in standard deviations of the density, with the
/// measurement's sd R^{1/2} standing in for the density's) when that is larger, and stops short
/// of it `Acceptable` only within 10 × that (or the default band 10³ × `dual.tolerance`, if
/// larger).
fn fine_dual_options(
    data: &DualData,
    rtol: f64,
    atol: f64,
    noise: f64,
    options: &ClosureOptions,
) -> DualOptions {
    let strict = options.dual.clone();
    if !options.dual_matched_to_sweeps {
        return strict;
    }
    let s = data.output_dim.max(1);
    let active = data.active();
    let matched = (0..s)
        .filter_map(|a| {
            let present = || active.iter().copied().filter(|m| m % s == a);
            let r_max = present().map(|m| data.r[m].abs()).fold(0.0, f64::max);
            let var_max = present().map(|m| data.variance[m]).fold(0.0, f64::max);
            let t = SWEEP_MATCH * (rtol * r_max + atol + noise * var_max.sqrt()) / var_max;
            t.is_finite().then_some(t)
        })
        .fold(f64::INFINITY, f64::min);
    if !(matched.is_finite() && matched > strict.tolerance) {
        return strict;
    }
    let acceptable = strict.acceptable().max(10.0 * matched);
    strict.with_tolerance(matched).with_acceptable_tolerance(Some(acceptable))
}

/// The closure's start of the dual: its assumed-density filter (each λ_k from the filter
/// condition with the earlier multipliers fixed); on long bistable records the closure's prior
/// prediction (λ = 0) is far from the data, and a non-convex Rayleigh–Ritz F lets Newton's
/// method wander from there. Fallback: λ_k = ½R⁻¹(r_k − z_k(0)).
fn dual_start<D: ClosureDrift>(
    action: &mut ClosureAction<D>,
    data: &DualData,
) -> Result<(Vec<f64>, DualStart)> {
    if let Some(l) = action.filter_start(data) {
        return Ok((l, DualStart::Filter));
    }
    let zero = vec![0.0; data.r.len()];
    let prior = action.evaluate(&zero)?;
    let half = if prior.z.iter().all(|v| v.is_finite()) {
        (0..zero.len())
            .map(|m| if data.r[m].is_nan() { 0.0 } else { 0.5 * (data.r[m] - prior.z[m]) / data.variance[m] })
            .collect()
    } else {
        zero
    };
    Ok((half, DualStart::Prior))
}

/// The closure's [`ClosureAction`] for a problem, built as [`closure_estimate`] builds it (for
/// tests, diagnostics and custom solvers). Errors as [`closure_estimate`].
pub fn closure_action<'a, S: Sde + ?Sized, F: ClosureFamily>(
    problem: &EstimationProblem<'a, S, StateMeasurement>,
    closure: &Closure<F>,
) -> Result<ClosureAction<F::Drift<'a, S>>> {
    common_checks(problem, closure)?;
    action_of(problem, &closure.family, &closure.options)
}

/// The [`ClosureAction`] of `family` with `options` on a checked problem.
fn action_of<'a, S: Sde + ?Sized, F: ClosureFamily>(
    problem: &EstimationProblem<'a, S, StateMeasurement>,
    family: &F,
    options: &ClosureOptions,
) -> Result<ClosureAction<F::Drift<'a, S>>> {
    let setup = family.setup(problem)?;
    let outs = output_times(problem.t0, &problem.data.times, options)?;
    let tolerances = SweepTolerances { rtol: options.rtol, atol: options.atol };
    ClosureAction::try_new(
        setup.drift,
        problem.t0,
        setup.lambda0,
        &problem.data.times,
        setup.measured,
        &outs,
        tolerances,
    )
}

fn common_checks<S: Sde + ?Sized, F: ClosureFamily>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    closure: &Closure<F>,
) -> Result<()> {
    problem.validate()?;
    closure.validate()?;
    problem.observation.validate(problem.sde.dims(), problem.theta)?;
    if !problem.estimate.is_empty() {
        return Err(invalid("estimate", "the closures do not estimate parameters; θ is taken as given"));
    }
    Ok(())
}

/// The mean-optimal estimate of a Rayleigh–Ritz closure (`003_d2fc48a470e528fc.txt` Part II)
/// as the common [`PathEstimate`] (method of the family): the history m(t) of every state at
/// the output times (`(II.48)`), the ensemble dispersion as sd columns (`(I.85)–(I.90)` with the
/// closure's F), the status and Newton iterations of the dual; details:
/// [`mean_optimal::DualDetails`].
///
/// The dual starts from the closure's assumed-density filter and runs in two stages (coarse
/// sweeps at min(100 · rtol, 10⁻⁴), then chord steps at `rtol`, to the tolerance matched to the
/// sweeps, [`ClosureOptions::dual_matched_to_sweeps`]); if that fails, once more from λ = 0
/// ([`mean_optimal::solve`]).
///
/// The measurements must be Gaussian measurements of states (as for the exact mean-optimal
/// estimator, the dual needs Gaussian errors, `(I.52)`), the initial priors Gaussian.
///
/// Errors ([`Error::InvalidOption`] unless noted): a non-Gaussian likelihood or prior, parameters
/// to estimate, invalid options, a model the family cannot take (the exponential closure on more
/// than two states). Non-convergence of the dual, or sweeps that leave the moment space, are
/// the estimate's [`Status`](crate::Status); so is a converged estimate whose density reaches
/// the edge of the family's box on the history's sweep ([`ClosureAction::box_edge`]) where a
/// wider box moves the means and no widening is left ([`Status::GridEdge`]; also an estimate
/// whose sweeps failed with the density against the box's edge,
/// [`ClosureAction::failure_edge`], when no widening is left), or on nodes that
/// did not pass the quadrature check when no refinement was left ([`Status::Unresolved`]).
pub fn closure_estimate<S: Sde + ?Sized, F: ClosureFamily>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    closure: &Closure<F>,
) -> Result<PathEstimate> {
    let start = Instant::now();
    common_checks(problem, closure)?;
    let data = gaussian_dual_data(problem)?;
    let options = &closure.options;
    // The refinements and widenings below keep the family's node rule, and with it its noise.
    let plan = dual_plan(&data, options, closure.family.quadrature_noise());
    let (mut family, mut warm, mut widenings) = (closure.family.clone(), None, 0);
    let mut failed_at_edge = false;
    let (mut iterations, mut evaluations, mut work) = (0, 0, Work::default());
    // The last estimate whose box cut its density off, with the shift of its means on a wider
    // box (beyond the tolerance).
    let mut cut: Option<(Checked<'_, S, F>, Option<f64>)> = None;
    // The estimate, the shift of its means on a wider box, and whether that lets it stand.
    let (Checked { family, action, mut sol, check, edge, .. }, edge_shift, kept) = loop {
        let mut checked = solve_checked(problem, family.clone(), &data, &plan, options, warm)?;
        checked.sol.dual.iterations += iterations;
        checked.sol.dual.evaluations += evaluations;
        work += checked.work;
        // A sweep that failed with the density against the box's edge (the estimate's numerical
        // failure): solved again on the box widened at that axis while widenings are left, else
        // it ends there.
        let failed = checked.sol.status == Status::NumericalFailure;
        if let (true, None, Some(e)) = (failed, &cut, checked.action.failure_edge()) {
            let support = checked.action.drift().support();
            match support.and_then(|s| checked.family.widened(&family, &s, &e)) {
                Some(Widening { wider, may_solve: true, .. }) => {
                    (iterations, evaluations) = (checked.sol.dual.iterations, checked.sol.dual.evaluations);
                    (family, warm, widenings) = (wider, None, widenings + 1);
                    continue;
                }
                _ => {
                    failed_at_edge = true;
                    checked.edge = Some(e);
                    break (checked, None, false);
                }
            }
        }
        // A wider box that fails falls back on the estimate whose box cut the density off.
        if !checked.sol.status.is_success() {
            let Some((mut last, shift)) = cut else { break (checked, None, false) };
            last.sol.dual.iterations = checked.sol.dual.iterations;
            last.sol.dual.evaluations = checked.sol.dual.evaluations;
            break (last, shift, false);
        }
        // Where the density reaches the box's edge, the history at the estimate's multipliers
        // is computed again on a wider box (on the estimate's last nodes); if a mean moves by
        // more than the tolerance, the estimate is solved again on the wider box (on the nodes
        // it started with) from its solution, while the family allows it.
        let widening = (checked.edge.as_ref())
            .and_then(|e| checked.family.widened(&family, &checked.action.drift().support()?, e));
        let Some(Widening { check, wider, tolerance, may_solve }) = widening else {
            break (checked, None, false);
        };
        let mut wide = action_of(problem, &check, options)?;
        let shift =
            mean_shift(&checked.sol.history, &mut wide, &checked.sol.dual.lambda, tolerance, options)?;
        work += wide.work().unwrap_or_default();
        let kept = shift.is_some_and(|s| s <= tolerance);
        if kept || !may_solve {
            break (checked, shift, kept);
        }
        (iterations, evaluations) = (checked.sol.dual.iterations, checked.sol.dual.evaluations);
        let narrower = (checked.sol.dual.lambda.clone(), DualStart::Narrower);
        (family, warm, widenings) = (wider, Some(narrower), widenings + 1);
        cut = Some((checked, shift));
    };
    // An estimate whose box cuts the density off in a way that moves the means, or on nodes
    // that did not pass the quadrature check, is not labelled converged.
    if (sol.status.is_success() && edge.is_some() && !kept) || failed_at_edge {
        sol.status = Status::GridEdge;
    }
    if sol.status.is_success() && check.as_ref().is_some_and(|c| !c.accepted) {
        sol.status = Status::Unresolved;
    }
    let mut details = sol.details(Some(family.describe()), Some(work), &plan);
    details.quadrature = check;
    details.domain = action.drift().support();
    details.edge = edge;
    details.edge_shift = edge_shift;
    details.widenings = widenings;
    Ok(dual_path_estimate(problem, F::METHOD, sol, details, start))
}

/// A closure estimate on a family's nodes after the quadrature check: the family and action
/// it ended on, the solution, the check, where the density reaches the box's edge, and the
/// sweeps and steps of every action it took.
struct Checked<'a, S: Sde + ?Sized + 'a, F: ClosureFamily> {
    family: F,
    action: ClosureAction<F::Drift<'a, S>>,
    sol: mean_optimal::Solution,
    check: Option<QuadratureCheck>,
    edge: Option<GridEdge>,
    work: Work,
}

/// The estimate on `family`'s nodes, from `warm` (a solution on a narrower box) when given, else
/// from the closure's filter; then the quadrature check: a converged estimate's history is
/// computed again on the finer nodes of [`ClosureFamily::refined`] and, where it moves by more
/// than the tolerance, the estimate is solved again there, while refinements remain. A failed
/// estimate is retried once, on the first finer nodes, and not on a branch (whose failures are
/// folds and saddles, not the nodes).
fn solve_checked<'a, S: Sde + ?Sized, F: ClosureFamily>(
    problem: &EstimationProblem<'a, S, StateMeasurement>,
    mut family: F,
    data: &DualData,
    plan: &Plan,
    options: &ClosureOptions,
    warm: Option<(Vec<f64>, DualStart)>,
) -> Result<Checked<'a, S, F>> {
    let mut action = action_of(problem, &family, options)?;
    let (dual, from) = solve_dual(&mut action, data, plan, options.branch, warm)?;
    let mut sol = mean_optimal::finish(&mut action, data, dual, from, options.dispersion)?;
    let (mut check, mut refinements, mut work) = (None, 0, Work::default());
    while let Some(refinement) = family.refined() {
        let converged = sol.status.is_success();
        // (A failure at the box's edge is for a wider box, not finer nodes.)
        let retry = sol.status == Status::NumericalFailure
            && refinements == 0
            && options.branch == BranchRule::Filter
            && action.failure_edge().is_none();
        if !(converged || retry) {
            break;
        }
        let mut finer = action_of(problem, &refinement.finer, options)?;
        let shift = converged
            .then(|| mean_shift(&sol.history, &mut finer, &sol.dual.lambda, refinement.tolerance, options))
            .transpose()?;
        let accepted = matches!(shift, Some(Some(s)) if s <= refinement.tolerance);
        refinements += usize::from(!accepted);
        let (nodes, finer_nodes) = refinement.nodes;
        check = Some(QuadratureCheck {
            nodes: if accepted { nodes } else { finer_nodes.clone() },
            checked_on: finer_nodes,
            shift: shift.flatten(),
            tolerance: refinement.tolerance,
            refinements,
            accepted,
        });
        if accepted {
            work += finer.work().unwrap_or_default();
            break;
        }
        // The coarser solution is the start on the finer nodes when there is one.
        let warm = shift.is_some().then(|| (sol.dual.lambda.clone(), DualStart::Coarser));
        let (mut dual, from) = solve_dual(&mut finer, data, plan, options.branch, warm)?;
        dual.iterations += sol.dual.iterations;
        dual.evaluations += sol.dual.evaluations;
        sol = mean_optimal::finish(&mut finer, data, dual, from, options.dispersion)?;
        work += action.work().unwrap_or_default();
        (family, action) = (refinement.finer, finer);
    }
    work += action.work().unwrap_or_default();
    let edge = action.box_edge();
    Ok(Checked { family, action, sol, check, edge, work })
}

/// The dual's plan of a closure: two stages (inexact Newton, the sweeps' accuracy matched to the
/// distance from the optimum) when a coarser tolerance than `rtol` exists, a retry from λ = 0;
/// the dispersion is [`mean_optimal::finish`]'s.
fn dual_plan(data: &DualData, options: &ClosureOptions, noise: f64) -> Plan {
    let (rtol, atol) = (options.rtol, options.atol);
    let coarse_rtol = (COARSE_FACTOR * rtol).min(COARSE_RTOL);
    let coarse = (coarse_rtol > rtol).then_some(scaled_tolerances(options, coarse_rtol));
    Plan {
        dual: fine_dual_options(data, rtol, atol, noise, options),
        stages: coarse.map(|c| (c, (rtol, atol))),
        retry_from_zero: true,
        dispersion: false,
    }
}

/// The dual's solution on `action` by `branch`, from `warm` (a solution on other nodes) when
/// given, else from the closure's filter; with where it started and its coarse stage.
fn solve_dual<D: ClosureDrift>(
    action: &mut ClosureAction<D>,
    data: &DualData,
    plan: &Plan,
    branch: BranchRule,
    warm: Option<(Vec<f64>, DualStart)>,
) -> Result<(DualSolution, (DualStart, Option<CoarseStage>))> {
    // The filter start runs with the first stage's coarse sweeps.
    if let Some(((rtol, atol), _)) = plan.stages {
        action.set_tolerances(rtol, atol)?;
    }
    match (branch, warm) {
        (BranchRule::Continuation, _) => {
            let sol = mean_optimal::solve_on_branch(action, data, plan)?;
            Ok((sol.dual, (sol.start, sol.coarse_stage)))
        }
        (BranchRule::Filter, Some(start)) => mean_optimal::solve_dual(action, data, start, plan),
        (BranchRule::Filter, None) => {
            let begin = dual_start(action, data)?;
            mean_optimal::solve_dual(action, data, begin, plan)
        }
    }
}

/// (rtol, atol) of `options` with rtol replaced by `rtol` and atol scaled with it.
fn scaled_tolerances(options: &ClosureOptions, rtol: f64) -> (f64, f64) {
    (rtol, options.atol * rtol / options.rtol)
}

/// The largest shift of a state's mean over the output times from `history` (at λ) to
/// `finer`'s history at λ, in units of the state's typical standard deviation on the path (the
/// root mean square over the output times of `finer`'s √variance, negative values taken as 0:
/// a mean-optimal history's variance is not that of a density and may vanish); `None` when
/// `finer`'s sweep fails. The sweeps run at rtol = [`CHECK_RTOL_FRACTION`] · `tolerance` (at
/// most [`COARSE_RTOL`], at least `options.rtol`); `finer` is left at `options`' tolerances.
fn mean_shift<D: ClosureDrift>(
    history: &History,
    finer: &mut ClosureAction<D>,
    lambda: &[f64],
    tolerance: f64,
    options: &ClosureOptions,
) -> Result<Option<f64>> {
    let (rtol, atol) =
        scaled_tolerances(options, (CHECK_RTOL_FRACTION * tolerance).min(COARSE_RTOL).max(options.rtol));
    finer.set_tolerances(rtol, atol)?;
    let swept = finer.history(lambda, false);
    finer.set_tolerances(options.rtol, options.atol)?;
    let Ok(fine) = swept? else { return Ok(None) };
    let n = fine.mean.first().map_or(0, Vec::len);
    let times = fine.variance.len().max(1) as f64;
    let shift = (0..n)
        .map(|i| {
            let scale = (fine.variance.iter().map(|v| v[i].max(0.0)).sum::<f64>() / times).sqrt();
            let moved =
                history.mean.iter().zip(&fine.mean).map(|(a, b)| (a[i] - b[i]).abs()).fold(0.0, f64::max);
            moved / scale.max(f64::MIN_POSITIVE)
        })
        .fold(0.0, f64::max);
    Ok(Some(shift))
}

/// The [`PathEstimate`] of a dual closure from its solution: the history as the path with the
/// solution's sd, θ as given (nothing estimated), the dual's status and iterations, the time
/// since `start`.
pub(crate) fn dual_path_estimate<S: Sde + ?Sized>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    method: Method,
    sol: mean_optimal::Solution,
    details: mean_optimal::DualDetails,
    start: Instant,
) -> PathEstimate {
    PathEstimate {
        method,
        path: crate::data::StatePath {
            names: problem.sde.state_names(),
            times: sol.history.times,
            values: sol.history.mean,
            sd: Some(sol.sd),
        },
        theta_names: problem.sde.param_names(),
        theta: problem.theta.to_vec(),
        estimated: Vec::new(),
        theta_sd: None,
        status: sol.status,
        iterations: sol.dual.iterations,
        solve_seconds: start.elapsed().as_secs_f64(),
        details: Details::new(details),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_matched_dual_tolerance_is_that_of_the_tightest_output() {
        // Two outputs (s = 2, two times): output 0 with |r| ≤ 2 and R = 0.04, output 1 with
        // |r| ≤ 100 and R = 1 (its third value missing): 0.1(10⁻⁶·2 + 10⁻⁹)/0.04 = 5.0025·10⁻⁶
        // against 0.1(10⁻⁶·100 + 10⁻⁹)/1 ≈ 10⁻⁵; the smaller stands, and the acceptable band is
        // ten times it.
        let data = DualData {
            r: vec![1.0, 100.0, -2.0, f64::NAN],
            variance: vec![0.04, 1.0, 0.04, 1.0],
            output_dim: 2,
        };
        let options = ClosureOptions::new();
        let fine = fine_dual_options(&data, 1e-6, 1e-9, 0.0, &options);
        let expect = 0.1 * (1e-6 * 2.0 + 1e-9) / 0.04;
        assert!((fine.tolerance - expect).abs() <= 1e-15 * expect, "{}", fine.tolerance);
        assert_eq!(fine.acceptable(), 10.0 * fine.tolerance);
        assert!(fine.validate().is_ok());
        // Off, a larger dual tolerance, or no present data: the dual's options as given.
        let off = options.clone().with_dual_matched_to_sweeps(false);
        assert_eq!(fine_dual_options(&data, 1e-6, 1e-9, 0.0, &off), off.dual);
        let tol = options.clone().with_dual(DualOptions::default().with_tolerance(1e-3));
        assert_eq!(fine_dual_options(&data, 1e-6, 1e-9, 0.0, &tol), tol.dual);
        // Nodes that move with the density (quadrature noise q = 10⁻⁴ sd): output 0's sweeps
        // err by 10⁻⁶·2 + 10⁻⁹ + 10⁻⁴·0.2 in z, giving 5.5·10⁻⁵, output 1's by
        // 10⁻⁶·100 + 10⁻⁹ + 10⁻⁴·1, giving 2.0·10⁻⁵: now output 1's stands.
        let noisy = fine_dual_options(&data, 1e-6, 1e-9, 1e-4, &options);
        let expect = 0.1 * (1e-6 * 100.0 + 1e-9 + 1e-4 * 1.0) / 1.0;
        assert!((noisy.tolerance - expect).abs() <= 1e-15 * expect, "{}", noisy.tolerance);
        let missing = DualData { r: vec![f64::NAN; 4], ..data };
        assert_eq!(fine_dual_options(&missing, 1e-6, 1e-9, 0.0, &options), options.dual);
    }
}
