//! The mean-optimal estimator of an effective action, written once for the exact grid and every
//! dual closure (`003_d2fc48a470e528fc.txt` Sec. I.5–I.6 and Part II): from a start, the dual
//! Φ(λ) is maximised ([`maximize_dual`], `(I.57)–(I.60)`), in two stages when the action's sweeps
//! have tolerances (coarse sweeps first, then chord steps at the requested tolerance,
//! [`maximize_dual_chord`]), with a retry from λ = 0 when asked; at the solution the history
//! z(t) is the estimate (`(I.76)`, `(II.48)`) and the ensemble dispersion
//! ((∇²F)⁻¹ + R⁻¹)⁻¹ (`(I.85)–(I.90)`, [`posterior_variance`]) its standard deviation.

use serde::Serialize;

use super::continuation::{follow_branch, BranchEnd};
use super::dispersion::posterior_variance;
use super::dual::{
    maximize_dual, maximize_dual_chord, DualData, DualOptions, DualSolution, DualStop, EffectiveAction,
    History, SweepFailure, Swept, Work,
};
use crate::estimate::Status;
use crate::Result;

/// Where the dual's iteration started.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
#[non_exhaustive]
pub enum DualStart {
    /// λ_k = R_k⁻¹(r_k − z_k) with z_k the exact KSP smoothed mean (the exact grid).
    Ksp,
    /// The closure's assumed-density filter (each λ_k from the filter condition with the
    /// earlier multipliers fixed).
    Filter,
    /// λ_k = ½R_k⁻¹(r_k − z_k(0)) from the prior prediction (when the filter fails).
    Prior,
    /// λ = 0 (the retry after a failed start).
    Zero,
    /// The end of the branch of stationary points from the prior, followed in the measurement
    /// precision ([`follow_branch`]).
    Continuation,
    /// The solution on a closure's coarser nodes, whose quadrature moved the estimate
    /// ([`crate::action::closure::ClosureFamily::refined`]).
    Coarser,
    /// The solution on a closure's narrower box, whose edge cut the density off and moved the
    /// estimate ([`crate::action::closure::ClosureFamily::widened`]).
    Narrower,
}

/// What the standard deviations of a mean-optimal estimate are.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[non_exhaustive]
pub enum SdKind {
    /// The ensemble dispersion ((∇²F)⁻¹ + R⁻¹)⁻¹ (`(I.85)–(I.90)`).
    #[serde(rename = "ensemble dispersion")]
    EnsembleDispersion,
    /// The variance of the estimator's own density at the solution (the tilted density on the
    /// grid, the closure's trial density): the dispersion was not asked for, or the dual did not
    /// succeed.
    #[serde(rename = "density variance")]
    DensityVariance,
    /// The density's variance, because ∇²F + R is not positive definite at the solution (a
    /// non-concave Rayleigh–Ritz dual), where the dispersion is undefined.
    #[serde(rename = "density variance (∇²F + R is not positive definite at the solution)")]
    Indefinite,
    /// The density's variance, because the tangent sweeps of the dispersion failed.
    #[serde(rename = "density variance (the dispersion's sweeps failed)")]
    DispersionFailed,
    /// None: the history's sweep failed at the solution (the path is empty).
    #[serde(rename = "none (the history's sweep failed)")]
    None,
}

/// The coarse first stage of a two-stage dual.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct CoarseStage {
    /// Its status.
    pub status: Status,
    /// Its Newton iterations.
    pub iterations: usize,
    /// The relative tolerance of its sweeps.
    pub rtol: f64,
}

/// The quadrature check of a closure estimate on refinable nodes, in the report's details
/// ([`crate::action::closure::closure_estimate`]).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct QuadratureCheck {
    /// The nodes of the estimate.
    pub nodes: String,
    /// The finer nodes of the last check.
    pub checked_on: String,
    /// The largest shift of a state's mean from the coarser to the finer nodes of the last
    /// check, at the coarser estimate's multipliers, in units of the state's typical standard
    /// deviation on the path (`None` when a sweep failed on either).
    pub shift: Option<f64>,
    /// The check's tolerance.
    pub tolerance: f64,
    /// How many times the nodes were refined.
    pub refinements: usize,
    /// Whether the estimate's own nodes (`nodes`) passed the check on the finer `checked_on`;
    /// false when the refinements allowed ran out, so that the estimate on the last nodes is not
    /// checked, or when the estimate failed.
    pub accepted: bool,
}

/// How to solve: the dual's options at the requested tolerances, and what else to do.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    /// The dual's options (of the last stage).
    pub dual: DualOptions,
    /// The sweeps' (rtol, atol) of a coarse first stage, and those of the second; `None`: one
    /// stage at the action's tolerances.
    pub stages: Option<((f64, f64), (f64, f64))>,
    /// Whether a failed start is retried from λ = 0 in one stage.
    pub retry_from_zero: bool,
    /// Whether to compute the ensemble dispersion (otherwise the density's variance).
    pub dispersion: bool,
}

/// The mean-optimal estimate of an effective action.
#[derive(Debug, Clone, PartialEq)]
pub struct Solution {
    /// The history at the output times (without cross-covariances); empty when its sweep failed.
    pub history: History,
    /// The standard deviation of every state at the output times.
    pub sd: Vec<Vec<f64>>,
    /// What `sd` is.
    pub sd_kind: SdKind,
    /// The dual's solution (iterations and evaluations summed over the stages and the retry).
    pub dual: DualSolution,
    /// The estimate's status: the dual's, or `NumericalFailure` when the history's sweep failed.
    pub status: Status,
    /// Where the reported dual solution started.
    pub start: DualStart,
    /// The coarse stage from the first start, when there was one.
    pub coarse_stage: Option<CoarseStage>,
    /// Why the history has no value at λ*, if so (the path is then empty).
    pub history_failure: Option<SweepFailure>,
    /// For a `NumericalFailure`: where and why the last sweep that failed failed
    /// ([`EffectiveAction::last_failure`]).
    pub sweep_failure: Option<String>,
}

/// The first stage's dual tolerance (optimality residual).
const COARSE_DUAL_TOLERANCE: f64 = 1e-3;
/// The first stage ends after this many full Newton steps without halving the residual: the
/// coarse sweeps' noise floor lies above its tolerance (`DualOptions::stall_iterations`).
const COARSE_STALL: usize = 3;

/// The dual from one start: with two stages, the first with coarse sweeps to
/// [`COARSE_DUAL_TOLERANCE`] (stopping at its noise floor, [`COARSE_STALL`]), then at the
/// requested tolerances by chord steps ([`maximize_dual_chord`]), or, when the chord steps fail,
/// the one-stage iteration from `start`; when the first stage fails (its iteration limit in a
/// trust-region crawl, say), the one-stage iteration from where it got to, where Φ is usually
/// higher. Iterations and evaluations are summed over the stages.
fn attempt<A: EffectiveAction + ?Sized>(
    action: &mut A,
    data: &DualData,
    start: &[f64],
    plan: &Plan,
) -> Result<(DualSolution, Option<CoarseStage>)> {
    let fine = &plan.dual;
    let Some(((coarse_rtol, coarse_atol), (rtol, atol))) = plan.stages else {
        return Ok((maximize_dual(action, data, fine, Some(start))?, None));
    };
    action.set_tolerances(coarse_rtol, coarse_atol)?;
    let loose = fine
        .clone()
        .with_tolerance(fine.tolerance.max(COARSE_DUAL_TOLERANCE))
        .with_acceptable_tolerance(None)
        .with_stall_iterations(Some(COARSE_STALL));
    let first = maximize_dual(action, data, &loose, Some(start))?;
    action.set_tolerances(rtol, atol)?;
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
    Ok((second, Some(CoarseStage { status: first.status, iterations: first.iterations, rtol: coarse_rtol })))
}

/// A history with the standard deviations of its states and what they are.
type HistoryWithSd = (History, Vec<Vec<f64>>, SdKind);

/// The square roots of the variances, negative round-off clipped.
fn sqrt_of(variance: &[Vec<f64>]) -> Vec<Vec<f64>> {
    variance.iter().map(|v| v.iter().map(|x| x.max(0.0).sqrt()).collect()).collect()
}

/// The history at λ* with its standard deviations: the ensemble dispersion when the dual
/// succeeded and `plan.dispersion`, else (or where the dispersion is undefined or its sweeps
/// fail) the density's variance; why not, when the history's sweep fails.
fn history_at<A: EffectiveAction + ?Sized>(
    action: &mut A,
    data: &DualData,
    lambda: &[f64],
    dispersion: bool,
) -> Result<Swept<HistoryWithSd>> {
    let mut kind = SdKind::DensityVariance;
    if dispersion {
        match action.history_and_hessian(lambda)? {
            Ok((mut history, hessian)) => {
                let var = posterior_variance(&history, &hessian, data)?;
                history.cross = None;
                match var {
                    Some(var) => return Ok(Ok((history, sqrt_of(&var), SdKind::EnsembleDispersion))),
                    None => {
                        let sd = sqrt_of(&history.variance);
                        return Ok(Ok((history, sd, SdKind::Indefinite)));
                    }
                }
            }
            Err(_) => kind = SdKind::DispersionFailed,
        }
    }
    Ok(action.history(lambda, false)?.map(|history| {
        let sd = sqrt_of(&history.variance);
        (history, sd, kind)
    }))
}

/// The mean-optimal estimate of `action` on `data` from `start` (see the
/// [module documentation](self)).
///
/// Errors: misuse (lengths, invalid options, a history without cross-covariances when the
/// action's [`EffectiveAction::history_and_hessian`] is the default one and cannot give them).
/// Non-convergence, a failed sweep or an undefined dispersion are the solution's status and
/// [`SdKind`].
pub fn solve<A: EffectiveAction + ?Sized>(
    action: &mut A,
    data: &DualData,
    start: (Vec<f64>, DualStart),
    plan: &Plan,
) -> Result<Solution> {
    let (dual, from) = solve_dual(action, data, start, plan)?;
    finish(action, data, dual, from, plan.dispersion)
}

/// The dual of [`solve`] without the history: its solution, where it started (`Zero` when the
/// retry from λ = 0 is the one reported) and its coarse stage. Errors: as [`solve`].
pub fn solve_dual<A: EffectiveAction + ?Sized>(
    action: &mut A,
    data: &DualData,
    (start, start_kind): (Vec<f64>, DualStart),
    plan: &Plan,
) -> Result<(DualSolution, (DualStart, Option<CoarseStage>))> {
    let (mut dual, coarse_stage) = attempt(action, data, &start, plan)?;
    let mut start = start_kind;
    if plan.retry_from_zero && !dual.status.is_success() {
        let retry = maximize_dual(action, data, &plan.dual, None)?;
        let totals = (dual.iterations + retry.iterations, dual.evaluations + retry.evaluations);
        if retry.status.is_success() || retry.residual < dual.residual {
            (dual, start) = (retry, DualStart::Zero);
        }
        (dual.iterations, dual.evaluations) = totals;
    }
    Ok((dual, (start, coarse_stage)))
}

/// The estimate at the dual's solution `dual`: the history at λ* with the ensemble dispersion
/// when `dispersion` and the dual succeeded (else the density's variance), the status, and where
/// and why a sweep failed. `from` is where the dual started and its coarse stage. Errors: as
/// [`solve`].
pub fn finish<A: EffectiveAction + ?Sized>(
    action: &mut A,
    data: &DualData,
    dual: DualSolution,
    (start, coarse_stage): (DualStart, Option<CoarseStage>),
    dispersion: bool,
) -> Result<Solution> {
    let with_dispersion = dispersion && dual.status.is_success();
    let (history, sd, sd_kind, history_failure) =
        match history_at(action, data, &dual.lambda, with_dispersion)? {
            Ok((history, sd, kind)) => (history, sd, kind, None),
            Err(failure) => {
                let empty =
                    History { times: Vec::new(), mean: Vec::new(), variance: Vec::new(), cross: None };
                (empty, Vec::new(), SdKind::None, Some(failure))
            }
        };
    let status = if history_failure.is_some() { Status::NumericalFailure } else { dual.status };
    let sweep_failure = failure_of(action, status);
    Ok(Solution { history, sd, sd_kind, dual, status, start, coarse_stage, history_failure, sweep_failure })
}

/// [`EffectiveAction::last_failure`] of `action` for an estimate that ended `NumericalFailure`.
fn failure_of<A: EffectiveAction + ?Sized>(action: &A, status: Status) -> Option<String> {
    (status == Status::NumericalFailure).then(|| action.last_failure().map(str::to_owned)).flatten()
}

/// The mean-optimal estimate at the stationary point connected to the prior by the curve of
/// stationary points in the measurement precision ([`follow_branch`], at the requested sweep
/// tolerances — the last stage's of `plan` — to `plan.dual.tolerance`): a function of the data
/// alone. `plan.retry_from_zero` is ignored (a retry would leave the branch). When the curve
/// is lost before the data's precision, the estimate is a `NumericalFailure` with the reason
/// [`DualStop::BranchLost`] and the history at the last point reached; when the point it
/// reaches is a saddle of the dual (∇²F + R not positive definite), a `NumericalFailure` with
/// the reason [`DualStop::Saddle`] and the history there.
///
/// Errors: as [`solve`].
pub fn solve_on_branch<A: EffectiveAction + ?Sized>(
    action: &mut A,
    data: &DualData,
    plan: &Plan,
) -> Result<Solution> {
    if let Some((_, (rtol, atol))) = plan.stages {
        action.set_tolerances(rtol, atol)?;
    }
    let branch = follow_branch(action, data, plan.dual.tolerance)?;
    let reached = matches!(branch.end, BranchEnd::Reached { .. });
    let last = Plan {
        dual: plan.dual.clone().with_max_iterations(0),
        stages: None,
        retry_from_zero: false,
        dispersion: plan.dispersion && reached,
    };
    let mut sol = solve(action, data, (branch.lambda, DualStart::Continuation), &last)?;
    sol.dual.iterations += branch.iterations;
    sol.dual.evaluations += branch.evaluations;
    let lost = match branch.end {
        BranchEnd::Reached { maximum: true } => None,
        BranchEnd::Reached { maximum: false } => Some(DualStop::Saddle { folds: branch.folds }),
        BranchEnd::Lost { precision } => Some(DualStop::BranchLost { precision, folds: branch.folds }),
        BranchEnd::NoPrior => Some(DualStop::NonFiniteStart),
    };
    if let Some(why) = lost {
        sol.dual.reason = Some(why);
        (sol.dual.status, sol.status) = (Status::NumericalFailure, Status::NumericalFailure);
        sol.sweep_failure = failure_of(action, sol.status);
    }
    Ok(sol)
}

/// The report's details of a mean-optimal estimate (the exact grid's and the dual closures').
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DualDetails {
    /// The closure's family, for a closure.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub closure: Option<String>,
    /// λ* (time-major).
    pub lambda: Vec<f64>,
    /// z* = ∂F/∂λ at λ*: the estimate at the measurement times.
    pub z_at_measurements: Vec<f64>,
    /// max |λ_m − (r_m − z_m)/R_m| at λ*.
    pub optimality_residual: f64,
    /// F(λ*).
    pub f_value: f64,
    /// Φ(λ*).
    pub phi: f64,
    /// Why the dual stopped short of its tolerance, if it did.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dual_reason: Option<DualStop>,
    /// The tolerance the dual ran to.
    pub dual_tolerance: f64,
    /// Where it started.
    pub dual_start: DualStart,
    /// Sweeps of the action (F evaluations of the dual when the action does not count them).
    pub sweeps: usize,
    /// Accepted integration steps of those sweeps, when counted.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rk_steps: Option<usize>,
    /// Integration steps of those sweeps that were rejected (by the error control, or because a
    /// stage could not be evaluated), when counted.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rk_rejected: Option<usize>,
    /// Tridiagonal solves of the exact grid's sweeps (the KSP start, the dual and the dispersion;
    /// one per vector and axis sub-step), a machine-independent measure of its work.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tridiagonal_solves: Option<usize>,
    /// The coarse first stage, when there was one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub coarse_stage: Option<CoarseStage>,
    /// What the sd columns are.
    pub sd: SdKind,
    /// Why the history has no value at λ*, if so.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub history_failure: Option<SweepFailure>,
    /// For a `numerical-failure`: where and why the last sweep that failed failed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sweep_failure: Option<String>,
    /// A closure's quadrature check, on nodes that can be refined.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub quadrature: Option<QuadratureCheck>,
    /// The box a closure's family is truncated to, one interval [a, b] per state (its `domain`,
    /// given or default), for a family on a fixed box.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub domain: Option<Vec<(f64, f64)>>,
    /// For a closure on a box: where its density reaches the box's edge (more than
    /// [`EDGE_MASS`](crate::action::exact::EDGE_MASS) of its mass near an end of an axis at
    /// some time, on the sweep of the history), if it does. With `edge_shift` within the
    /// tolerance the estimate stands; otherwise a converged estimate is `grid-edge`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub edge: Option<crate::action::exact::GridEdge>,
    /// For a closure on a box whose density reaches its edge: the largest shift of a state's
    /// mean on the box with that axis widened, at the estimate's multipliers (as
    /// [`QuadratureCheck::shift`]; `None` when that sweep failed). Within the quadrature check's
    /// tolerance (`refine_tolerance`) the estimate stands.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub edge_shift: Option<f64>,
    /// For a closure on a box: how many times the box was widened because the density reached
    /// its edge (`widen`).
    #[serde(skip_serializing_if = "is_zero")]
    pub widenings: usize,
}

fn is_zero(n: &usize) -> bool {
    *n == 0
}

impl Solution {
    /// The report's details; `closure` names the closure's family, `work` is the action's
    /// [`EffectiveAction::work`].
    pub fn details(&self, closure: Option<String>, work: Option<Work>, plan: &Plan) -> DualDetails {
        let d = &self.dual;
        DualDetails {
            closure,
            lambda: d.lambda.clone(),
            z_at_measurements: d.z.clone(),
            optimality_residual: d.residual,
            f_value: d.f_value,
            phi: d.phi,
            dual_reason: d.reason,
            dual_tolerance: plan.dual.tolerance,
            dual_start: self.start,
            sweeps: work.map_or(d.evaluations, |w| w.sweeps),
            rk_steps: work.map(|w| w.steps),
            rk_rejected: work.map(|w| w.rejected),
            tridiagonal_solves: None,
            coarse_stage: self.coarse_stage,
            sd: self.sd_kind,
            history_failure: self.history_failure,
            sweep_failure: self.sweep_failure.clone(),
            quadrature: None,
            domain: None,
            edge: None,
            edge_shift: None,
            widenings: 0,
        }
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::DMatrix;

    use super::*;
    use crate::action::dual::ActionValue;

    /// F(λ) = μλ + ½cλ² at one measurement of one state, whose sweeps can be made to fail, and
    /// whose reported ∇²F can be overridden (a non-concave Rayleigh–Ritz F).
    struct Scalar {
        times: Vec<f64>,
        mu: f64,
        c: f64,
        hessian: Option<f64>,
        fail_history: bool,
        fail_tangents: bool,
    }

    impl EffectiveAction for Scalar {
        fn measurement_times(&self) -> &[f64] {
            &self.times
        }
        fn output_dim(&self) -> usize {
            1
        }
        fn evaluate(&mut self, lambda: &[f64]) -> Result<ActionValue> {
            let l = lambda[0];
            Ok(ActionValue { value: self.mu * l + 0.5 * self.c * l * l, z: vec![self.mu + self.c * l] })
        }
        fn hessian(&mut self, _: &[f64]) -> Result<Swept<DMatrix<f64>>> {
            if self.fail_tangents {
                return Ok(Err(SweepFailure::Unrealizable));
            }
            Ok(Ok(DMatrix::from_element(1, 1, self.hessian.unwrap_or(self.c))))
        }
        fn history(&mut self, lambda: &[f64], cross: bool) -> Result<Swept<History>> {
            if self.fail_history {
                return Ok(Err(SweepFailure::Unrealizable));
            }
            let z = self.evaluate(lambda)?.z[0];
            let cov = DMatrix::from_element(1, 1, self.hessian.unwrap_or(self.c));
            Ok(Ok(History {
                times: self.times.clone(),
                mean: vec![vec![z]],
                variance: vec![vec![self.c]],
                cross: cross.then(|| vec![cov]),
            }))
        }
    }

    fn scalar() -> Scalar {
        Scalar { times: vec![1.0], mu: 0.5, c: 2.0, hessian: None, fail_history: false, fail_tangents: false }
    }

    fn plan() -> Plan {
        Plan { dual: DualOptions::default(), stages: None, retry_from_zero: false, dispersion: true }
    }

    #[test]
    fn the_solution_is_gaussian_conditioning_with_its_dispersion() {
        // Prior N(0.5, 2), datum 1.5 with R = 0.5: posterior mean 0.5 + 2/2.5 · 1 = 1.3, variance
        // 2 − 4/2.5 = 0.4 (the linear-Gaussian identity of (I.85)–(I.90)).
        let data = DualData { r: vec![1.5], variance: vec![0.5], output_dim: 1 };
        let sol = solve(&mut scalar(), &data, (vec![0.0], DualStart::Zero), &plan()).unwrap();
        assert_eq!((sol.status, sol.sd_kind), (Status::Converged, SdKind::EnsembleDispersion));
        assert!((sol.history.mean[0][0] - 1.3).abs() < 1e-12, "{:?}", sol.history.mean);
        assert!((sol.sd[0][0] - 0.4f64.sqrt()).abs() < 1e-12, "{:?}", sol.sd);
        assert!(sol.history.cross.is_none() && sol.history_failure.is_none());
    }

    #[test]
    fn numerical_outcomes_are_statuses_and_sd_kinds_not_errors() {
        let data = DualData { r: vec![1.5], variance: vec![0.5], output_dim: 1 };
        let start = || (vec![0.0], DualStart::Zero);
        // ∇²F + R not positive definite at the solution: the density's variance, flagged.
        let mut indefinite = Scalar { hessian: Some(-1.0), ..scalar() };
        let sol = solve(
            &mut indefinite,
            &data,
            start(),
            &Plan { dual: DualOptions::default().with_max_iterations(0), ..plan() },
        )
        .unwrap();
        assert_eq!(sol.status, Status::MaxIterations);
        assert_eq!(sol.sd_kind, SdKind::DensityVariance, "no dispersion without a solution");
        let mut indefinite = Scalar { hessian: Some(-1.0), ..scalar() };
        let h = history_at(&mut indefinite, &data, &[0.4], true).unwrap().unwrap();
        assert_eq!(h.2, SdKind::Indefinite);
        assert!((h.1[0][0] - 2f64.sqrt()).abs() < 1e-12);
        // The dispersion's tangent sweeps fail: the density's variance, flagged.
        let mut tangents = Scalar { fail_tangents: true, ..scalar() };
        let h = history_at(&mut tangents, &data, &[0.4], true).unwrap().unwrap();
        assert_eq!(h.2, SdKind::DispersionFailed);
        // The history's sweep fails at the solution: numerical-failure, an empty path, the reason.
        let mut history = Scalar { fail_history: true, ..scalar() };
        let sol = solve(&mut history, &data, start(), &plan()).unwrap();
        assert_eq!(sol.status, Status::NumericalFailure);
        assert_eq!((sol.sd_kind, sol.history_failure), (SdKind::None, Some(SweepFailure::Unrealizable)));
        assert!(sol.history.times.is_empty() && sol.sd.is_empty());
        let details = serde_json::to_value(sol.details(None, None, &plan())).unwrap();
        assert_eq!(details["history_failure"], "unrealizable");
        assert_eq!(details["dual_start"], "zero");
    }
}
