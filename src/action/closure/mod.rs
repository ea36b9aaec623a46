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
//! - [`closure_estimate`]: the estimator as a [`PathEstimate`].
//!
//! See `docs/closures.md`.

pub mod drift;
mod jet;
pub mod om;
pub mod sweep;

pub use drift::{ClosureDrift, ExponentialDrift, FamilyMoments, GaussianDrift, Unrealizable};
pub use sweep::{ClosureAction, SweepTolerances};

use std::time::Instant;

use nalgebra::DMatrix;
use onsager_closures::{Exponential, LegendreOptions, TrialFamily};
use serde_json::json;

use crate::data::StatePath;
use crate::estimate::{EstimationProblem, PathEstimate, Status};
use crate::model::observation::StateMeasurement;
use crate::model::prior::{Prior, PriorDensity};
use crate::model::Sde;
use crate::{Error, Result};

use super::dual::{maximize_dual, maximize_dual_chord, DualData, DualOptions, DualSolution, EffectiveAction};
use super::exact::gaussian_dual_data;

/// Which closure.
#[non_exhaustive]
#[derive(Debug, Clone, PartialEq)]
pub enum ClosureKind {
    /// The Gaussian family M = (x_i, x_ix_j) on all states (any dimension).
    Gaussian,
    /// The polynomial exponential family M = (x, x², …, x^degree) (1-D models), e.g. the
    /// quartic family (degree 4) for the double well.
    Exponential {
        /// The highest power (≥ 2).
        degree: usize,
    },
    /// The closure of the KSP smoother (`(II.64)–(II.65)`), a moment-path problem ([`om`];
    /// one-state models).
    Ksp,
    /// The double-exponential closure (`(II.54)–(II.63)`), a moment-path problem ([`om`];
    /// one-state models).
    DoubleExponential,
}

impl ClosureKind {
    /// The method's name on the command line.
    pub fn method_name(&self) -> &'static str {
        match self {
            ClosureKind::Gaussian => "gaussian-closure",
            ClosureKind::Exponential { .. } => "exp-closure",
            ClosureKind::Ksp => "ksp-closure",
            ClosureKind::DoubleExponential => "double-exp-closure",
        }
    }

    /// The kind of a method name (`gaussian-closure`, `exp-closure`, `ksp-closure`,
    /// `double-exp-closure`); `degree` is the exponential family's degree (default 4).
    /// Errors: [`Error::UnknownName`] for another name, [`Error::InvalidOption`] for a degree
    /// given to another closure or a degree below 2.
    pub fn parse(method: &str, degree: Option<usize>) -> Result<ClosureKind> {
        let kind = match method {
            "gaussian-closure" => ClosureKind::Gaussian,
            "exp-closure" => ClosureKind::Exponential { degree: degree.unwrap_or(4) },
            "ksp-closure" => ClosureKind::Ksp,
            "double-exp-closure" => ClosureKind::DoubleExponential,
            _ => {
                return Err(Error::UnknownName {
                    kind: "closure method".into(),
                    name: method.into(),
                    known: ["gaussian-closure", "exp-closure", "ksp-closure", "double-exp-closure"]
                        .map(String::from)
                        .to_vec(),
                })
            }
        };
        match (&kind, degree) {
            (ClosureKind::Exponential { degree }, _) if *degree < 2 => Err(Error::InvalidOption {
                name: "moments".into(),
                reason: format!("the exponential closure needs degree ≥ 2, got {degree}"),
            }),
            (ClosureKind::Exponential { .. }, _) | (_, None) => Ok(kind),
            (_, Some(_)) => Err(Error::InvalidOption {
                name: "moments".into(),
                reason: format!("--moments applies to exp-closure only, not {method}"),
            }),
        }
    }
}

/// Options of [`closure_estimate`].
#[non_exhaustive]
#[derive(Debug, Clone, PartialEq)]
pub struct ClosureOptions {
    /// Time of the initial law (the x0 prior). Default 0.
    pub t0: f64,
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
    /// Support of the exponential family (its quadrature grid): one interval [a, b] per state,
    /// or empty for the default: per state, the range of its data and of its initial prior
    /// (mean ± 5 sd), widened by half its width plus 1 on each side. Set it for a state that is
    /// not measured and whose range the prior does not cover.
    pub domain: Vec<(f64, f64)>,
    /// Panels × 8 Gauss–Legendre points per dimension of the exponential family's grid.
    /// Default 12 (96 nodes in 1-D; the double-well estimates of `benches/closure.rs` agree with
    /// 24 panels to 1e-5); in 2-D half as many per dimension (6 × 8 = 48, 2304 nodes).
    pub panels: usize,
    /// Further output times (finite, ≥ `t0`). Default none.
    pub extra_times: Vec<f64>,
    /// Gauss–Hermite points per dimension of the Gaussian closures' averages (`gaussian-closure`
    /// and, on its moment path, `double-exp-closure` / `ksp-closure`), k^n nodes on n states;
    /// at least 1. Default `None`: automatic ([`drift::gaussian_closure_rule`]): for a model that
    /// declares a polynomial drift of degree d ([`Sde::drift_polynomial_degree`]) and 1–3 states,
    /// ⌊(d + 1)/2⌋ + 1 points, which take the averages exactly (3 for the cubic double well);
    /// otherwise 16 / 8 / 5 points per dimension for 1 / 2 / 3 states and a fifth-degree
    /// cubature from 4 states.
    pub gaussian_points: Option<usize>,
    /// Whether to compute the ensemble dispersion (sd columns) at the output times
    /// (`(I.85)–(I.90)`; costs 2 history sweeps per measurement). Default true.
    pub dispersion: bool,
    /// Whether the dual may also stop where its optimality residual is a tenth of the sweeps'
    /// accuracy, in measurement units: max_m |λ_m − (r_m − z_m)/R_m| ≤
    /// 0.1 · min_a (rtol · max_k |r_ka| + atol) / max_k R_ka, per measured output a over its
    /// present data (reported as the detail `dual_tolerance`, the larger of this and
    /// `dual.tolerance`; a stop short of it is `Acceptable` within 10 × it). The remaining Newton
    /// correction of a residual ε is K⁻¹Rε, which moves z by ∇²F K⁻¹ Rε: at most Rε in the
    /// R⁻¹-weighted norm where ∇²F is positive semi-definite, about as much for the estimate in
    /// between, more where F is not convex (hence the tenth). Below this level the further Newton
    /// steps buy digits the sweeps do not have (inexact Newton). Default true; false:
    /// `dual.tolerance` alone (see `docs/closures.md`, "The dual's tolerance, its shortest step
    /// and its fallbacks").
    pub dual_matched_to_sweeps: bool,
    /// Options of the dual maximisation.
    pub dual: DualOptions,
}

impl Default for ClosureOptions {
    fn default() -> Self {
        ClosureOptions {
            t0: 0.0,
            output_step: None,
            rtol: 1e-6,
            atol: 1e-9,
            domain: Vec::new(),
            panels: 12,
            extra_times: Vec::new(),
            gaussian_points: None,
            dispersion: true,
            dual_matched_to_sweeps: true,
            dual: DualOptions::default(),
        }
    }
}

impl ClosureOptions {
    /// The defaults.
    pub fn new() -> Self {
        Self::default()
    }

    /// Sets the initial time.
    pub fn with_t0(mut self, t0: f64) -> Self {
        self.t0 = t0;
        self
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

    /// Sets the exponential family's support, one interval per state.
    pub fn with_domain(mut self, domain: &[(f64, f64)]) -> Self {
        self.domain = domain.to_vec();
        self
    }

    /// Sets the number of Gauss–Legendre panels of the exponential family's grid.
    pub fn with_panels(mut self, panels: usize) -> Self {
        self.panels = panels;
        self
    }

    /// Adds output times.
    pub fn with_extra_times(mut self, times: &[f64]) -> Self {
        self.extra_times.extend_from_slice(times);
        self
    }

    /// Sets the Gauss–Hermite points per dimension of the Gaussian closures (see
    /// [`ClosureOptions::gaussian_points`]).
    pub fn with_gaussian_points(mut self, points_per_dim: usize) -> Self {
        self.gaussian_points = Some(points_per_dim);
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

    /// Sets the dual options.
    pub fn with_dual(mut self, dual: DualOptions) -> Self {
        self.dual = dual;
        self
    }

    fn validate(&self) -> Result<()> {
        let bad = |name: &str, reason: String| Err(Error::InvalidOption { name: name.into(), reason });
        if !self.t0.is_finite() {
            return bad("t0", format!("must be finite, got {}", self.t0));
        }
        if let Some(s) = self.output_step {
            if !(s.is_finite() && s > 0.0) {
                return bad("output step", format!("must be positive and finite, got {s}"));
            }
        }
        for &(a, b) in &self.domain {
            if !(a.is_finite() && b.is_finite() && a < b) {
                return bad("domain", format!("need finite a < b, got [{a}, {b}]"));
            }
        }
        if self.panels == 0 {
            return bad("panels", "must be at least 1".into());
        }
        if self.gaussian_points == Some(0) {
            return bad("gaussian points", "must be at least 1".into());
        }
        if let Some(&t) = self.extra_times.iter().find(|&&t| !t.is_finite() || t < self.t0) {
            return bad("output times", format!("must be finite and not before t0 = {}, got {t}", self.t0));
        }
        self.dual.validate()
    }
}

fn invalid(name: &str, reason: impl Into<String>) -> Error {
    Error::InvalidOption { name: name.into(), reason: reason.into() }
}

/// (mean, variance) of a Gaussian, unbounded prior; an error naming the state otherwise.
fn gaussian_prior(p: &Prior, state: &str) -> Result<(f64, f64)> {
    match p.density {
        PriorDensity::Gaussian { mean, sd } if p.lower == f64::NEG_INFINITY && p.upper == f64::INFINITY => {
            Ok((mean, sd * sd))
        }
        _ => Err(invalid(
            "x0 prior",
            format!("the closures need a Gaussian initial prior (untruncated) for state `{state}`"),
        )),
    }
}

/// The output grid t0 + kΔ up to the last measurement (and the extra times).
fn output_times(data_times: &[f64], options: &ClosureOptions) -> Result<Vec<f64>> {
    let t0 = options.t0;
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

/// The support of the exponential family (see [`ClosureOptions::domain`]).
fn default_domain(values: &[f64], mean: f64, var: f64) -> (f64, f64) {
    let sd = var.sqrt();
    let (mut a, mut b) = (mean - 5.0 * sd, mean + 5.0 * sd);
    for &v in values.iter().filter(|v| v.is_finite()) {
        a = a.min(v);
        b = b.max(v);
    }
    let w = b - a;
    (a - 0.5 * w - 1.0, b + 0.5 * w + 1.0)
}

/// The dual's coarse first stage: its status, Newton iterations and relative tolerance.
type CoarseStage = (Status, usize, f64);

/// The mean-optimal estimate of a closure: the action, the dual solution and the estimate.
#[derive(Debug)]
struct Solved {
    history: crate::action::dual::History,
    sd: Vec<Vec<f64>>,
    /// What the sd columns are.
    sd_kind: &'static str,
    dual: DualSolution,
    sweeps: usize,
    /// Accepted Runge–Kutta steps of those sweeps.
    rk_steps: usize,
    /// The coarse first stage of the dual from the first start, when there was one (also when the
    /// retry from λ = 0 gave the estimate: its iterations are in the total).
    coarse_stage: Option<CoarseStage>,
    /// The tolerance the dual ran to ([`ClosureOptions::dual_matched_to_sweeps`]).
    dual_tolerance: f64,
    /// The start of the reported dual solution: "filter" (the assumed-density filter's
    /// multipliers), "prior" (½R⁻¹(r − z(0)), when the filter fails) or "zero" (the retry).
    dual_start: &'static str,
}

/// The dual's first stage runs its sweeps at this multiple of the relative (and absolute)
/// tolerance, ...
const COARSE_FACTOR: f64 = 100.0;
/// ... but at a relative tolerance of at most this (at 10⁻³ the double-well duals no longer
/// converged: the step-size noise in F defeats the line search).
const COARSE_RTOL: f64 = 1e-4;
/// The first stage's dual tolerance (optimality residual; the default's 10⁻⁹ is the second's).
const COARSE_DUAL_TOLERANCE: f64 = 1e-3;
/// The dual's residual, in measurement units, may stop at this fraction of the sweeps'
/// accuracy ([`ClosureOptions::dual_matched_to_sweeps`]).
const SWEEP_MATCH: f64 = 0.1;
/// The first stage ends after this many full Newton steps without halving the residual: the
/// coarse sweeps' noise floor lies above its tolerance (`DualOptions::stall_iterations`).
const COARSE_STALL: usize = 3;

/// The dual's options at the requested sweep tolerances: `options.dual`, and with
/// [`ClosureOptions::dual_matched_to_sweeps`] the tolerance raised to
/// [`SWEEP_MATCH`] · min_a (rtol · max_k |r_ka| + atol) / max_k R_ka (per measured output a,
/// over its present data) when that is larger, and stops short of it `Acceptable` only within
/// 10 × that (or the default band 10³ × `dual.tolerance`, if larger).
fn fine_dual_options(data: &DualData, rtol: f64, atol: f64, options: &ClosureOptions) -> DualOptions {
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
            let t = SWEEP_MATCH * (rtol * r_max + atol) / var_max;
            t.is_finite().then_some(t)
        })
        .fold(f64::INFINITY, f64::min);
    if !(matched.is_finite() && matched > strict.tolerance) {
        return strict;
    }
    let acceptable = strict.acceptable().max(10.0 * matched);
    strict.with_tolerance(matched).with_acceptable_tolerance(Some(acceptable))
}

/// The dual from one start: with `coarse` tolerances (rtol, atol), the first stage with those
/// sweeps to [`COARSE_DUAL_TOLERANCE`], then at `tolerances` by chord steps
/// ([`maximize_dual_chord`]), or, when the chord steps fail, the one-stage iteration from
/// `start`; when the first stage fails (its iteration limit in a trust-region crawl, say), the
/// one-stage iteration from where it got to (which has usually raised Φ: every trust-region and
/// Armijo step does, a Newton step accepted for halving the residual need not). Without
/// `coarse`, the one-stage iteration from `start`. Iterations and evaluations are summed over
/// the stages; the coarse stage's status and iterations are returned with its rtol.
fn attempt<D: ClosureDrift>(
    action: &mut ClosureAction<D>,
    data: &DualData,
    start: &[f64],
    fine: &DualOptions,
    tolerances: (f64, f64),
    coarse: Option<(f64, f64)>,
) -> Result<(DualSolution, Option<CoarseStage>)> {
    let Some((coarse_rtol, coarse_atol)) = coarse else {
        return Ok((maximize_dual(action, data, fine, Some(start))?, None));
    };
    action.set_tolerances(coarse_rtol, coarse_atol)?;
    let loose = fine
        .clone()
        .with_tolerance(fine.tolerance.max(COARSE_DUAL_TOLERANCE))
        .with_acceptable_tolerance(None)
        .with_stall_iterations(Some(COARSE_STALL));
    let first = maximize_dual(action, data, &loose, Some(start))?;
    action.set_tolerances(tolerances.0, tolerances.1)?;
    let mut second = match (&first.hessian, first.status.is_success()) {
        (Some(h), true) => {
            let chord = maximize_dual_chord(action, data, fine, &first.lambda, h.clone())?;
            if chord.status.is_success() {
                chord
            } else {
                let mut one = maximize_dual(action, data, fine, Some(start))?;
                one.iterations += chord.iterations;
                one.evaluations += chord.evaluations;
                one
            }
        }
        _ if first.phi.is_finite() => maximize_dual(action, data, fine, Some(&first.lambda))?,
        _ => maximize_dual(action, data, fine, Some(start))?,
    };
    second.iterations += first.iterations;
    second.evaluations += first.evaluations;
    Ok((second, Some((first.status, first.iterations, coarse_rtol))))
}

fn solve<D: ClosureDrift>(
    mut action: ClosureAction<D>,
    data: &DualData,
    measured_states: &[usize],
    options: &ClosureOptions,
) -> Result<Solved> {
    // Start from the closure's assumed-density filter (each λ_k from the filter condition with
    // the earlier multipliers fixed): on long bistable records the closure's prior prediction
    // (λ = 0) is far from the data, and a non-convex Rayleigh–Ritz F lets Newton's method wander
    // from there. Fallback: λ_k = ½R⁻¹(r_k − z_k(0)).
    //
    // Two stages (inexact Newton, the sweeps' accuracy matched to the distance from the optimum):
    // the dual to a residual of 10⁻³ with coarse sweeps (rtol × 100, at most 10⁻⁴: about half
    // the steps), then at the requested tolerances by chord steps with the first stage's last
    // ∇²F (`maximize_dual_chord`; full Newton once a chord step does not contract), to the dual
    // tolerance matched to the sweeps (`fine_dual_options`); see `attempt` for the fallbacks. Without
    // a coarser tolerance (rtol ≥ 10⁻⁴) one stage. If the start from the filter fails, one stage
    // from λ = 0. Each stage has `options.dual.max_iterations`; the reported iterations and
    // evaluations are the sum over all.
    let (rtol, atol) = action.tolerances();
    let fine = fine_dual_options(data, rtol, atol, options);
    let coarse_rtol = (COARSE_FACTOR * rtol).min(COARSE_RTOL);
    let coarse = (coarse_rtol > rtol).then_some((coarse_rtol, atol * coarse_rtol / rtol));
    if let Some((c_rtol, c_atol)) = coarse {
        action.set_tolerances(c_rtol, c_atol)?;
    }
    let (start, start_kind): (Vec<f64>, &'static str) = match action.filter_start(data) {
        Some(l) => (l, "filter"),
        None => {
            let zero = vec![0.0; data.r.len()];
            let prior = action.evaluate(&zero)?;
            let half = if prior.z.iter().all(|v| v.is_finite()) {
                (0..zero.len())
                    .map(|m| {
                        if data.r[m].is_nan() {
                            0.0
                        } else {
                            0.5 * (data.r[m] - prior.z[m]) / data.variance[m]
                        }
                    })
                    .collect()
            } else {
                zero
            };
            (half, "prior")
        }
    };
    let (mut dual, coarse_stage) = attempt(&mut action, data, &start, &fine, (rtol, atol), coarse)?;
    let mut dual_start = start_kind;
    if !dual.status.is_success() {
        // Retry from λ = 0 (the closure's prior prediction), in one stage (in two, on one of the
        // 24 double-well records of docs/closures.md, it failed where this converged).
        let retry = maximize_dual(&mut action, data, &fine, None)?;
        let totals = (dual.iterations + retry.iterations, dual.evaluations + retry.evaluations);
        if retry.status.is_success() || retry.residual < dual.residual {
            (dual, dual_start) = (retry, "zero");
        }
        (dual.iterations, dual.evaluations) = totals;
    }
    let ok = dual.status.is_success();
    let mut history = action.history(&dual.lambda, ok && options.dispersion)?;
    let mut sd_note = None;
    let sd = match &history.cross {
        Some(cross) => {
            // ∇²F from the same tangents: Cov(Z_k, Z_j) is the cross-covariance at t_k.
            let s = data.output_dim;
            let m = data.r.len();
            let times = action.measurement_times().to_vec();
            let mut h = DMatrix::zeros(m, m);
            for (k, &tk) in times.iter().enumerate() {
                let e = history.times.iter().position(|&t| t == tk).ok_or_else(|| {
                    invalid("closure", "a measurement time is missing from the output times")
                })?;
                for b in 0..s {
                    for j in 0..m {
                        h[(k * s + b, j)] = cross[e][(measured_states[b], j)];
                    }
                }
            }
            let h = (&h + h.transpose()) * 0.5;
            match super::dispersion::posterior_variance(&history, &h, data) {
                Ok(var) => var.iter().map(|v| v.iter().map(|x| x.max(0.0).sqrt()).collect()).collect(),
                // At a stationary point where ∇²F + R is not positive definite the ensemble
                // dispersion is undefined: report the closure's own variance. Other errors pass.
                Err(Error::InvalidOption { name, .. }) if name == "hessian" => {
                    sd_note = Some("closure variance (∇²F + R is not positive definite at the solution)");
                    history.variance.iter().map(|v| v.iter().map(|x| x.sqrt()).collect()).collect()
                }
                Err(e) => return Err(e),
            }
        }
        None => history.variance.iter().map(|v| v.iter().map(|x| x.sqrt()).collect()).collect(),
    };
    history.cross = None;
    let sd_kind = match (sd_note, ok && options.dispersion) {
        (Some(note), _) => note,
        (None, true) => "ensemble dispersion",
        (None, false) => "closure variance",
    };
    Ok(Solved {
        history,
        sd,
        sd_kind,
        dual,
        sweeps: action.sweeps(),
        rk_steps: action.steps(),
        coarse_stage,
        dual_tolerance: fine.tolerance,
        dual_start,
    })
}

/// The closure's [`ClosureAction`] for a problem, built as [`closure_estimate`] builds it (for
/// tests, diagnostics and custom solvers). Errors as [`closure_estimate`].
pub fn gaussian_closure_action<'a, S: Sde + ?Sized>(
    problem: &EstimationProblem<'a, S, StateMeasurement>,
    options: &ClosureOptions,
) -> Result<ClosureAction<GaussianDrift<'a, S>>> {
    let (drift, lambda0) = gaussian_setup(problem, options.gaussian_points)?;
    let measured = problem.observation.states.clone();
    action_of(problem, options, drift, lambda0, measured)
}

/// The polynomial exponential closure's [`ClosureAction`] of `degree` for a 1-D problem.
/// Errors as [`closure_estimate`].
pub fn exponential_closure_action<'a, S: Sde + ?Sized>(
    problem: &EstimationProblem<'a, S, StateMeasurement>,
    degree: usize,
    options: &ClosureOptions,
) -> Result<ClosureAction<ExponentialDrift<'a, S>>> {
    let (drift, lambda0) = exponential_setup(problem, degree, options)?;
    let measured = problem
        .observation
        .states
        .iter()
        .map(|&s| drift.linear_index(s).ok_or_else(|| invalid("method", "no linear moment")))
        .collect::<Result<Vec<_>>>()?;
    action_of(problem, options, drift, lambda0, measured)
}

fn common_checks<S: Sde + ?Sized>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    options: &ClosureOptions,
) -> Result<()> {
    problem.validate()?;
    options.validate()?;
    problem.observation.validate(problem.sde.dims(), problem.theta)?;
    if !problem.estimate.is_empty() {
        return Err(invalid("estimate", "the closures do not estimate parameters; θ is taken as given"));
    }
    if problem.data.times[0] < options.t0 {
        return Err(invalid(
            "t0",
            format!("the data start at {} before the initial time {}", problem.data.times[0], options.t0),
        ));
    }
    Ok(())
}

fn action_of<S: Sde + ?Sized, D: ClosureDrift>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    options: &ClosureOptions,
    drift: D,
    lambda0: Vec<f64>,
    measured: Vec<usize>,
) -> Result<ClosureAction<D>> {
    let outs = output_times(&problem.data.times, options)?;
    let tolerances = SweepTolerances { rtol: options.rtol, atol: options.atol };
    ClosureAction::try_new(drift, options.t0, lambda0, &problem.data.times, measured, &outs, tolerances)
}

fn gaussian_setup<'a, S: Sde + ?Sized>(
    problem: &EstimationProblem<'a, S, StateMeasurement>,
    points_per_dim: Option<usize>,
) -> Result<(GaussianDrift<'a, S>, Vec<f64>)> {
    let names = problem.sde.state_names();
    let priors: Vec<&Prior> = problem.x0_prior.iter().chain(problem.z0_prior).collect();
    let n = priors.len();
    let mut mean = vec![0.0; n];
    let mut cov = vec![0.0; n * n];
    for (i, p) in priors.iter().enumerate() {
        let (m, v) = gaussian_prior(p, &names[i])?;
        mean[i] = m;
        cov[i * n + i] = v;
    }
    let drift = GaussianDrift::try_with_points(problem.sde, problem.theta, points_per_dim)?;
    let lambda0 = drift
        .family()
        .natural_from_mean_cov(&mean, &cov)
        .map_err(|e| invalid("x0 prior", format!("Gaussian closure: {e}")))?;
    Ok((drift, lambda0))
}

fn exponential_setup<'a, S: Sde + ?Sized>(
    problem: &EstimationProblem<'a, S, StateMeasurement>,
    degree: usize,
    options: &ClosureOptions,
) -> Result<(ExponentialDrift<'a, S>, Vec<f64>)> {
    let n = problem.sde.dims().states();
    if !(1..=2).contains(&n) {
        return Err(invalid(
            "method",
            format!(
                "the exponential closure handles models with one or two states (this model has {n}); use gaussian-closure"
            ),
        ));
    }
    let max_degree = if n == 1 { 12 } else { 6 };
    if !(2..=max_degree).contains(&degree) {
        return Err(invalid(
            "moments",
            format!("the exponential closure in {n}-D needs degree 2 to {max_degree}, got {degree}"),
        ));
    }
    if !options.domain.is_empty() && options.domain.len() != n {
        return Err(invalid(
            "domain",
            format!("one interval per state: the model has {n}, got {}", options.domain.len()),
        ));
    }
    let names = problem.sde.state_names();
    let priors: Vec<&Prior> = problem.x0_prior.iter().chain(problem.z0_prior).collect();
    let mut moments = Vec::with_capacity(n);
    let mut domain = Vec::with_capacity(n);
    for i in 0..n {
        let (m0, v0) = gaussian_prior(priors[i], &names[i])?;
        moments.push((m0, v0));
        let values: Vec<f64> = problem
            .observation
            .states
            .iter()
            .enumerate()
            .filter(|&(_, &s)| s == i)
            .flat_map(|(b, _)| problem.data.values.iter().map(move |row| row[b]))
            .collect();
        domain.push(options.domain.get(i).copied().unwrap_or_else(|| default_domain(&values, m0, v0)));
    }
    let panels = if n == 1 { options.panels } else { options.panels.div_ceil(2) };
    let grid =
        onsager_closures::panel_grid(&domain, panels, 8).map_err(|e| invalid("domain", e.to_string()))?;
    let family = Exponential::polynomial(grid, onsager_closures::Reference::Lebesgue, degree as u32)
        .map_err(|e| invalid("moments", e.to_string()))?;
    // λ_0: the (independent) Gaussian prior is the member with m_i/v_i on x_i, −1/(2v_i) on
    // x_i² and 0 elsewhere; polished by the Legendre inverse of its moments on the grid (moment
    // matching, (II.39)).
    let exponents = family.exponents().ok_or_else(|| invalid("moments", "no polynomial exponents"))?;
    let guess: Vec<f64> = exponents
        .iter()
        .map(|e| {
            let total: u32 = e.iter().sum();
            match e.iter().position(|&p| p > 0) {
                Some(i) if total == e[i] && e[i] == 1 => moments[i].0 / moments[i].1,
                Some(i) if total == e[i] && e[i] == 2 => -0.5 / moments[i].1,
                _ => 0.0,
            }
        })
        .collect();
    let mu0 = family.mean(&guess).map_err(|e| invalid("x0 prior", e.to_string()))?;
    let lambda0 = family
        .legendre(&mu0, &LegendreOptions::default().with_initial(guess.clone()))
        .map(|s| s.lambda)
        .unwrap_or(guess);
    let drift = ExponentialDrift::try_new(problem.sde, problem.theta, family)?;
    Ok((drift, lambda0))
}

/// The mean-optimal estimate of a Rayleigh–Ritz closure (`003_d2fc48a470e528fc.txt` Part II)
/// as the common [`PathEstimate`] (method = `kind.method_name()`): the history m(t) of every
/// state at the output times (`(II.48)`), the ensemble dispersion as sd columns
/// (`(I.85)–(I.90)` with the closure's F), the dual status and Newton iterations; details:
/// λ*, z* at the measurement times, the optimality residual, F(λ*), Φ(λ*), sweeps, the family,
/// the dual's tolerance (`dual_tolerance`), its start (`dual_start`: `filter`, `prior` or
/// `zero`) and its coarse stage (`coarse_stage`).
///
/// The measurements must be Gaussian measurements of states (as for the exact mean-optimal
/// estimator, the dual needs Gaussian errors, `(I.52)`), the initial priors Gaussian.
/// `ksp-closure` and `double-exp-closure` are not dual problems: their estimate is the
/// minimising moment path of [`om::moment_path_estimate`] (grid step = `output_step`).
///
/// Errors ([`Error::InvalidOption`] unless noted): a non-Gaussian likelihood or prior, parameters
/// to estimate, data before `t0`, invalid options, an exponential closure on a model with more
/// than two states, `ksp-closure` and `double-exp-closure` on a model with more than one state
/// (see [`om::moment_path_estimate`]).
/// Non-convergence of the dual, or sweeps that leave the moment space, are a [`Status`].
pub fn closure_estimate<S: Sde + ?Sized>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    kind: &ClosureKind,
    options: &ClosureOptions,
) -> Result<PathEstimate> {
    let start = Instant::now();
    common_checks(problem, options)?;
    let data = gaussian_dual_data(problem)?;
    let states = &problem.observation.states;
    let solved = match kind {
        ClosureKind::Gaussian => solve(gaussian_closure_action(problem, options)?, &data, states, options)?,
        ClosureKind::Exponential { degree } => {
            solve(exponential_closure_action(problem, *degree, options)?, &data, states, options)?
        }
        ClosureKind::Ksp | ClosureKind::DoubleExponential => {
            let mut o = om::MomentPathOptions::new().with_t0(options.t0);
            if let Some(s) = options.output_step {
                o = o.with_step(s);
            }
            o.gaussian_points = options.gaussian_points;
            return om::moment_path_estimate(problem, kind, &o);
        }
    };
    let path = StatePath {
        names: problem.sde.state_names(),
        times: solved.history.times.clone(),
        values: solved.history.mean.clone(),
        sd: Some(solved.sd.clone()),
    };
    let mut est = super::base_estimate(kind.method_name(), problem, path);
    let dual = &solved.dual;
    est.status = dual.status;
    est.iterations = dual.iterations;
    est.solve_seconds = start.elapsed().as_secs_f64();
    let finite =
        |v: &[f64]| v.iter().map(|x| if x.is_finite() { json!(x) } else { json!(null) }).collect::<Vec<_>>();
    est.details.insert("closure".into(), json!(format!("{kind:?}")));
    est.details.insert("lambda".into(), json!(finite(&dual.lambda)));
    est.details.insert("z_at_measurements".into(), json!(finite(&dual.z)));
    est.details.insert("optimality_residual".into(), json!(finite(&[dual.residual])[0]));
    est.details.insert("f_value".into(), json!(finite(&[dual.f_value])[0]));
    est.details.insert("phi".into(), json!(finite(&[dual.phi])[0]));
    if let Some(reason) = &dual.reason {
        est.details.insert("dual_reason".into(), json!(reason));
    }
    est.details.insert("dual_tolerance".into(), json!(solved.dual_tolerance));
    est.details.insert("dual_start".into(), json!(solved.dual_start));
    est.details.insert("sweeps".into(), json!(solved.sweeps));
    est.details.insert("rk_steps".into(), json!(solved.rk_steps));
    if let Some((status, iterations, rtol)) = solved.coarse_stage {
        est.details.insert(
            "coarse_stage".into(),
            json!({"status": status.name(), "iterations": iterations, "rtol": rtol}),
        );
    }
    est.details.insert("sd".into(), json!(solved.sd_kind));
    Ok(est)
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
        let fine = fine_dual_options(&data, 1e-6, 1e-9, &options);
        let expect = 0.1 * (1e-6 * 2.0 + 1e-9) / 0.04;
        assert!((fine.tolerance - expect).abs() <= 1e-15 * expect, "{}", fine.tolerance);
        assert_eq!(fine.acceptable(), 10.0 * fine.tolerance);
        assert!(fine.validate().is_ok());
        // Off, a larger dual tolerance, or no present data: the dual's options as given.
        let off = options.clone().with_dual_matched_to_sweeps(false);
        assert_eq!(fine_dual_options(&data, 1e-6, 1e-9, &off), off.dual);
        let tol = options.clone().with_dual(DualOptions::default().with_tolerance(1e-3));
        assert_eq!(fine_dual_options(&data, 1e-6, 1e-9, &tol), tol.dual);
        let missing = DualData { r: vec![f64::NAN; 4], ..data };
        assert_eq!(fine_dual_options(&missing, 1e-6, 1e-9, &options), options.dual);
    }
}
