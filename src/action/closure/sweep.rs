//! The forward–backward sweeps of an exponential-family closure with jump conditions, as an
//! [`EffectiveAction`].
//!
//! Forward (`003_d2fc48a470e528fc.txt (II.46), (II.49)`): λ̇ = W(λ, t) from λ(t_0) = λ_0, and
//! at each measurement time λ(t_k+) = λ(t_k−) + E λ_k, where E places the multiplier of the
//! measured state x_i on the family's linear moment x_i. F(λ_1, …, λ_n) = Σ_k ΔF_k with
//! ΔF_k = F(λ(t_k+)) − F(λ(t_k−)) (`(II.51)`).
//!
//! Backward (`(II.47), (II.50)`): γ̇ + (∂W/∂λ)ᵀγ = 0 between measurements, γ(t_f) = 0,
//! γ(t_k−) = γ(t_k+) + (μ_k+ − μ_k−). The history is m(t) = μ(λ(t)) + γ(t) (`(II.48)`),
//! continuous across the jumps (`(II.44)`), and ∂F/∂λ_k = Eᵀ(μ_k+ + γ_k+) = Eᵀm(t_k)
//! (`(A.30)`).
//!
//! The ODE is integrated by Tsitouras' 5(4) pair (the constants `A`, `C`, `E`) with error control (the step-size
//! control of Hairer, Nørsett, Wanner, *Solving ODEs I*, 2nd ed., Sec. II.4); the backward sweep is the exact
//! discrete adjoint of the accepted Runge–Kutta steps (the stages are stored), so the gradient
//! is that of the computed F for the accepted step sequence to round-off (the sequence itself
//! depends on λ through the error control, so F has tolerance-sized jumps where it changes) and
//! that of the continuous (II.47) to the ODE tolerance.
//! ∇²F (and the cross-covariances of the dispersion) are the exact derivatives of the computed
//! gradient: per interval between events, the flow's Jacobian by a tangent-linear sweep and its
//! adjoint-weighted Hessian by the tangent of the discrete adjoint (which needs the Hessians of
//! the stage-adjoint contractions k̄ᵀW: [`ClosureDrift::w_second`] at every stage, or, for a
//! family that keeps them, Σ_a k̄_a∇²W_a from the Hessians ∇²W_a of the forward sweep's stages,
//! [`ClosureDrift::keeps_hessians`]), chained over the events for all multipliers at once.
//! A step whose stage leaves the family's moment space (W not defined) is rejected and
//! retried smaller; a sweep that cannot proceed returns a non-finite F, which the dual solver
//! treats by backtracking (never a NaN path in a result).

use std::sync::atomic::{AtomicUsize, Ordering::Relaxed};

use nalgebra::DMatrix;

use super::FailureAt;
use crate::action::dual::{
    ActionValue, DualData, EffectiveAction, History, SweepFailure as Failure, Swept, Work,
};
use crate::action::exact::{GridEdge, EDGE_MASS};
use crate::{Error, Result};

use super::drift::{ClosureDrift, Unrealizable};

/// Tsitouras' 5(4) pair (Ch. Tsitouras, "Runge–Kutta pairs of order 5(4) satisfying only the
/// first column simplifying assumption", *Comput. Math. Appl.* 62 (2011) 770–775, Table 1): seven
/// stages, first same as last, like Dormand–Prince but with smaller error coefficients (see
/// `docs/closures.md`, "Integrator").
/// The nodes C, the stage matrix A (its last row holds the fifth-order weights: FSAL).
const C: [f64; 7] = [0.0, 0.161, 0.327, 0.9, 0.9800255409045097, 1.0, 1.0];
const A: [[f64; 6]; 7] = [
    [0.0; 6],
    [0.161, 0.0, 0.0, 0.0, 0.0, 0.0],
    [-0.008480655492356989, 0.335480655492357, 0.0, 0.0, 0.0, 0.0],
    [2.8971530571054935, -6.359448489975075, 4.3622954328695815, 0.0, 0.0, 0.0],
    [5.325864828439257, -11.748883564062828, 7.4955393428898365, -0.09249506636175525, 0.0, 0.0],
    [5.86145544294642, -12.92096931784711, 8.159367898576159, -0.071584973281401, -0.028269050394068383, 0.0],
    [0.09646076681806523, 0.01, 0.4798896504144996, 1.379008574103742, -3.290069515436081, 2.324710524099774],
];
/// Fifth-order weights (= the last row of A; the seventh stage only serves the error estimate).
const B: [f64; 6] = A[6];
/// B − B̂ (fifth minus fourth order), seven stages.
const E: [f64; 7] = [
    0.0017800110522257772,
    0.0008164344596567469,
    -0.007880878010261995,
    0.1447110071732629,
    -0.5823571654525552,
    0.45808210592918697,
    -1.0 / 66.0,
];

/// How many relaxation times 1/ρ before a measurement the history's steps resolve the adjoint
/// ([`ClosureAction::integrate`]): beyond, its transient has decayed to e⁻⁸ ≈ 3·10⁻⁴ of the jump,
/// and a step of hρ ≤ 1.4 there errs by at most 3·10⁻⁶ of it (2.7, the largest seen on the
/// benchmark record, by 10⁻³).
const ADJOINT_WINDOW: f64 = 8.0;

/// The largest z = hρ (at most the real-axis stability limit) at which one step of the pair
/// reproduces the decay e^{−z} of a mode of rate ρ to relative error `rtol`: with the stability
/// polynomial R(z) = 1 + Σ_{k=1}^{6} bᵀA^{k−1}𝟙 z^k, by bisection on |R(−z)e^z − 1| ≤ rtol
/// (0.42 at rtol 10⁻⁶).
fn mode_step(rtol: f64) -> f64 {
    // Coefficients bᵀA^{k−1}𝟙 of the stability polynomial.
    let mut v = [1.0; 6];
    let mut coef = [0.0; 7];
    coef[0] = 1.0;
    for c in coef.iter_mut().skip(1) {
        *c = (0..6).map(|i| B[i] * v[i]).sum();
        let prev = v;
        for (i, vi) in v.iter_mut().enumerate() {
            *vi = (0..i).map(|j| A[i][j] * prev[j]).sum();
        }
    }
    let err = |z: f64| {
        let r: f64 = coef.iter().enumerate().map(|(k, c)| c * (-z).powi(k as i32)).sum();
        (r * z.exp() - 1.0).abs()
    };
    let (mut lo, mut hi) = (0.0, 3.0);
    if err(hi) <= rtol {
        return hi;
    }
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if err(mid) <= rtol {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    lo
}

/// The grid of [`graded_mode_steps`]: steps of 1/4 relaxation time.
const GRADE_STEP: f64 = 0.25;

/// [`mode_step`] of rtol·e^{x} at x = 0, ¼, ½, …, [`ADJOINT_WINDOW`]: the largest hρ at which a
/// step ending x relaxation times before a measurement resolves the adjoint's transient to rtol
/// of the jump (the transient there is e^{−x} of it, so one step may err by rtol·e^{x} of its
/// own size).
fn graded_mode_steps(rtol: f64) -> Vec<f64> {
    let n = (ADJOINT_WINDOW / GRADE_STEP).round() as usize;
    (0..=n).map(|j| mode_step(rtol * (j as f64 * GRADE_STEP).exp())).collect()
}

/// The spectral radius of the row-major r × r matrix `m`, or an upper bound: the eigenvalues by
/// a Schur decomposition of at most 200 iterations, ‖m‖∞ (≥ the spectral radius) if it does not
/// converge; 0 if an entry is not finite (no eigen-solver runs on it: with NaN the QR iteration
/// need not end).
fn spectral_radius(m: &[f64], r: usize) -> f64 {
    if !m.iter().all(|v| v.is_finite()) {
        return 0.0;
    }
    match nalgebra::Schur::try_new(DMatrix::from_row_slice(r, r, m), f64::EPSILON, 200) {
        Some(schur) => schur.complex_eigenvalues().iter().map(|z| z.norm()).fold(0.0, f64::max),
        None => row_sum_norm(m, r),
    }
}

/// ‖m‖∞, the largest absolute row sum of the row-major r × r matrix `m`.
fn row_sum_norm(m: &[f64], r: usize) -> f64 {
    m.chunks(r).map(|row| row.iter().map(|v| v.abs()).sum::<f64>()).fold(0.0, f64::max)
}

/// Evaluates `$body` with `$r` bound to the literal 2, 3, 4 or 5 when `$size` is one of them (the
/// Gaussian family in one or two states, the cubic and quartic families), to `$size` otherwise:
/// the step loops over R, in functions marked `#[inline(always)]`, are then compiled for a
/// constant R and unrolled. The same code runs either way.
macro_rules! with_size {
    ($size:expr, $r:ident => $body:expr) => {
        match $size {
            2 => {
                let $r = 2;
                $body
            }
            3 => {
                let $r = 3;
                $body
            }
            4 => {
                let $r = 4;
                $body
            }
            5 => {
                let $r = 5;
                $body
            }
            $r => $body,
        }
    };
}

/// The Runge–Kutta tolerances of a [`ClosureAction`]'s sweeps: a step from y to y′ is accepted
/// when its error estimate e has RMS_a(e_a / (atol + rtol·max(|y_a|, |y′_a|))) ≤ 1.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SweepTolerances {
    /// The relative tolerance (> 0).
    pub rtol: f64,
    /// The absolute tolerance (> 0).
    pub atol: f64,
}

fn check_tolerances(rtol: f64, atol: f64) -> Result<()> {
    for (name, v) in [("rtol", rtol), ("atol", atol)] {
        if !(v.is_finite() && v > 0.0) {
            return Err(Error::InvalidOption {
                name: name.into(),
                reason: format!("must be positive and finite, got {v}"),
            });
        }
    }
    Ok(())
}

/// The accepted Runge–Kutta steps of one sweep, flat: start time and size of step s, its six
/// stage arguments Y_i (6R values from `6Rs`) and stage Jacobians J_i = ∂W/∂λ(Y_i) (6 R × R
/// row-major blocks from `6R²s`), formed with W in the forward sweep so that the adjoint sweep
/// need not evaluate the drift again. The steps of the interval between events e and e + 1 are
/// `start[e]..start[e + 1]`.
#[derive(Debug, Clone)]
struct Steps {
    t: Vec<f64>,
    h: Vec<f64>,
    stages: Vec<f64>,
    jac: Vec<f64>,
    /// The stage Hessians ∇²W_a (6 R × R × R per step) when the family keeps them
    /// ([`ClosureDrift::keeps_hessians`]), else empty.
    hess: Vec<f64>,
    start: Vec<usize>,
    /// Steps attempted and rejected (by the error control or a stage that could not be evaluated).
    rejected: usize,
}

impl Steps {
    /// Room for `n` steps of R = `r` parameters in `events` events, without reallocating (and
    /// for their stage Hessians with `hessians`).
    fn with_capacity(n: usize, r: usize, events: usize, hessians: bool) -> Self {
        let mut start = Vec::with_capacity(events);
        start.push(0);
        Steps {
            t: Vec::with_capacity(n),
            h: Vec::with_capacity(n),
            stages: Vec::with_capacity(6 * r * n),
            jac: Vec::with_capacity(6 * r * r * n),
            hess: Vec::with_capacity(if hessians { 6 * r * r * r * n } else { 0 }),
            start,
            rejected: 0,
        }
    }

    fn len(&self) -> usize {
        self.h.len()
    }

    /// The steps of interval `e` (between events e and e + 1).
    fn interval(&self, e: usize) -> std::ops::Range<usize> {
        self.start[e]..self.start[e + 1]
    }
}

/// The workspace of [`ClosureAction::rk_step`], reused across the steps of a sweep: the seven
/// stage slopes K_i (7R), their Jacobians (7 R × R), their Hessians when the family keeps them
/// (7 R × R × R, else empty), the stage arguments Y_1..Y_6 (6R) and the current argument (R; the
/// fifth-order solution after the step). On entry K_1, its Jacobian (and its Hessians) hold W
/// and its derivatives at the step's start; after an accepted step the seventh
/// (first-same-as-last) stage's are moved there. `k1_time`: the time at which K_1 holds W at the current state (`None`
/// after a jump or before the first evaluation).
struct RkWork {
    k: Vec<f64>,
    jac: Vec<f64>,
    hess: Vec<f64>,
    stages: Vec<f64>,
    arg: Vec<f64>,
    k1_time: Option<f64>,
    /// Why the last stage that could not be evaluated could not.
    trouble: Option<String>,
}

impl RkWork {
    fn new(r: usize, hessians: bool) -> Self {
        RkWork {
            k: vec![0.0; 7 * r],
            jac: vec![0.0; 7 * r * r],
            hess: vec![0.0; if hessians { 7 * r * r * r } else { 0 }],
            stages: vec![0.0; 6 * r],
            arg: vec![0.0; r],
            k1_time: None,
            trouble: None,
        }
    }
}

/// A stored forward sweep.
#[derive(Debug, Clone)]
struct Forward {
    /// The accepted steps, by interval between consecutive events.
    steps: Steps,
    /// λ at every event before the jump (= after it at other events).
    lambda_minus: Vec<Vec<f64>>,
    /// μ(t_k−) and μ(t_k+), per measurement.
    mu_minus: Vec<Vec<f64>>,
    mu_plus: Vec<Vec<f64>>,
    /// C(t_k−), per measurement.
    cov_minus: Vec<Vec<f64>>,
    /// μ (after the jump) and C at every event.
    mu: Vec<Vec<f64>>,
    cov: Vec<Vec<f64>>,
    /// F = Σ ΔF_k.
    f: f64,
    /// On the history's sweeps, the largest [`ClosureDrift::edge_mass`] over the events (before
    /// and after each jump), when the family has a box.
    edge: Option<GridEdge>,
}

/// The stage derivatives of the accepted steps that the tangent sweeps need, indexed as
/// [`Steps`]: the stage Jacobians J_i = ∂W/∂λ(Y_i) and the Hessians H_i = ∇²(k̄_iᵀW)(Y_i) of the
/// stage adjoints' contractions (6 R × R blocks per step each, row-major).
#[derive(Debug, Clone, Default)]
struct StepDerivs {
    jac: Vec<f64>,
    hess: Vec<f64>,
}

/// The workspace of [`ClosureAction::interval_derivatives`]: the stage tangents of the
/// interval's steps (6 R × R per step) and the step routines' buffers.
#[derive(Debug, Default)]
struct IntervalWork {
    dys: Vec<f64>,
    dks: Vec<f64>,
    stage_tangents: Vec<f64>,
    adjoint: AdjointTangentWork,
}

/// The workspaces of [`ClosureAction::adjoint_tangent_step`]: δk̄ (6 R × R) and δȲ_i (R × R).
#[derive(Debug, Default)]
struct AdjointTangentWork {
    dk: Vec<f64>,
    dyb: Vec<f64>,
}

/// The interval between two consecutive events that [`ClosureAction::integrate`] integrates:
/// from `start` to `end`, with the time of the next measurement at or after `end` when the
/// steps resolve the adjoint before it (the history's sweeps).
#[derive(Debug, Clone, Copy)]
struct EventInterval {
    start: f64,
    end: f64,
    next_measurement: Option<f64>,
}

/// How the forward sweep picks the multiplier of measurement k from λ(t_k−).
type Choose<'c> = dyn FnMut(usize, &[f64]) -> std::result::Result<Vec<f64>, FailureAt> + 'c;

/// γ at every event and the stage derivatives of every step.
type Adjoint = (Vec<Vec<f64>>, StepDerivs);

/// The derivatives ∂m/∂λ_j of the moments at every event, in one buffer (`[j][event][moment]`):
/// n multipliers × the events × R values, allocated once per Hessian.
struct Tangents {
    values: Vec<f64>,
    events: usize,
    r: usize,
}

impl Tangents {
    fn zeros(multipliers: usize, events: usize, r: usize) -> Self {
        Tangents { values: vec![0.0; multipliers * events * r], events, r }
    }

    /// ∂m(t_e)/∂λ_j, the R moments.
    fn at(&self, j: usize, e: usize) -> &[f64] {
        let start = (j * self.events + e) * self.r;
        &self.values[start..start + self.r]
    }

    fn at_mut(&mut self, j: usize, e: usize) -> &mut [f64] {
        let start = (j * self.events + e) * self.r;
        &mut self.values[start..start + self.r]
    }
}

/// The closure effective action of one problem: the drift, the initial natural parameters, the
/// event times (t_0, output times, measurement times) and the measured moments.
pub struct ClosureAction<D: ClosureDrift> {
    drift: D,
    lambda0: Vec<f64>,
    /// Measurement times.
    meas_times: Vec<f64>,
    /// Event times of [`EffectiveAction::evaluate`]: t_0 and the measurement times.
    fit_events: Events,
    /// Event times of [`EffectiveAction::history`]: t_0, output and measurement times.
    out_events: Events,
    /// Moment index of each measured component (the matrix E).
    measured: Vec<usize>,
    rtol: f64,
    /// [`graded_mode_steps`] of `rtol`.
    mode_steps: Vec<f64>,
    atol: f64,
    cache: Option<(Vec<f64>, Forward, Vec<Vec<f64>>)>,
    /// `sweeps` when the cached sweep ran: the tangents reuse it only if no sweep ran since (a
    /// failed trial sweep leaves the cache alone but may move nodes that follow the density).
    cache_sweeps: usize,
    /// The steps of the last forward sweep (the next sweep's room in its step arrays).
    step_hint: AtomicUsize,
    /// [`ClosureDrift::keeps_hessians`] of the drift.
    keep_hessians: bool,
    sweeps: usize,
    steps: usize,
    rejected: usize,
    /// Whether a fresh start (after a jump) begins within the mode step (see
    /// [`ClosureAction::integrate`]); false only in a test, for the step left from the last
    /// interval.
    fresh_start_cap: bool,
    /// Where and why the last sweep that failed failed.
    last_failure: Option<String>,
    /// [`ClosureAction::failure_edge`].
    failure_edge: Option<GridEdge>,
    /// [`Forward::edge`] of the last history sweep.
    edge: Option<GridEdge>,
}

impl<D: ClosureDrift> std::fmt::Debug for ClosureAction<D> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ClosureAction").field("measurements", &self.meas_times.len()).finish()
    }
}

#[derive(Debug, Clone)]
struct Events {
    times: Vec<f64>,
    meas: Vec<Option<usize>>,
    /// Resolve the adjoint's relaxation before each measurement (the history's sweeps): see
    /// [`ClosureAction::integrate`].
    resolve_adjoint: bool,
}

impl Events {
    fn new(t0: f64, meas_times: &[f64], extra: &[f64]) -> Events {
        let m = crate::data::EventTimes::merge(meas_times, &[&[t0], extra].concat());
        Events { times: m.times, meas: m.measurement, resolve_adjoint: false }
    }
}

/// The moment paths of [`ClosureAction::moment_paths`] at the output times.
#[derive(Debug, Clone, PartialEq)]
pub struct MomentPaths {
    /// The output times.
    pub times: Vec<f64>,
    /// m(t) = μ(λ(t)) + γ(t), every moment at every output time (`(II.48)`).
    pub m: Vec<Vec<f64>>,
    /// μ(λ(t)) on the forward sweep alone.
    pub mu: Vec<Vec<f64>>,
}

impl<D: ClosureDrift> ClosureAction<D> {
    /// The action of `drift` from λ(t_0) = `lambda0`, measurements at `meas_times` of the
    /// moments `measured` (one index into M per measured component), history reported at
    /// `output_times` as well, with the Runge–Kutta `tolerances`.
    ///
    /// Errors ([`Error::InvalidOption`]): lengths, non-finite λ_0, a measurement before t_0,
    /// non-positive tolerances.
    pub fn try_new(
        drift: D,
        t0: f64,
        lambda0: Vec<f64>,
        meas_times: &[f64],
        measured: Vec<usize>,
        output_times: &[f64],
        tolerances: SweepTolerances,
    ) -> Result<Self> {
        let SweepTolerances { rtol, atol } = tolerances;
        let r = drift.n_params();
        crate::model::check_len("initial natural parameters", r, lambda0.len())?;
        if lambda0.iter().any(|v| !v.is_finite()) {
            return Err(Error::NonFinite { what: "initial natural parameters".into() });
        }
        if let Some(&a) = measured.iter().find(|&&a| a >= r) {
            return Err(Error::InvalidOption {
                name: "measured".into(),
                reason: format!("moment index {a} out of range ({r} moments)"),
            });
        }
        if meas_times.is_empty() || meas_times.iter().any(|&t| !(t >= t0 && t.is_finite())) {
            return Err(Error::InvalidOption {
                name: "t0".into(),
                reason: format!("the measurement times must be finite and not before t0 = {t0}"),
            });
        }
        if meas_times.windows(2).any(|w| w[1] <= w[0]) {
            return Err(Error::InvalidOption {
                name: "measurement times".into(),
                reason: "must be strictly increasing".into(),
            });
        }
        check_tolerances(rtol, atol)?;
        let outs: Vec<f64> = output_times.iter().copied().filter(|&t| t >= t0).collect();
        let keep_hessians = drift.keeps_hessians();
        Ok(ClosureAction {
            fit_events: Events::new(t0, meas_times, &[]),
            out_events: Events { resolve_adjoint: true, ..Events::new(t0, meas_times, &outs) },
            drift,
            lambda0,
            meas_times: meas_times.to_vec(),
            measured,
            rtol,
            atol,
            mode_steps: graded_mode_steps(rtol),
            cache: None,
            cache_sweeps: 0,
            step_hint: AtomicUsize::new(0),
            keep_hessians,
            sweeps: 0,
            steps: 0,
            rejected: 0,
            fresh_start_cap: true,
            last_failure: None,
            failure_edge: None,
            edge: None,
        })
    }

    /// Sets the Runge–Kutta tolerances of the following sweeps and, when they change, forgets the
    /// cached sweep, whose F belongs to the old ones. Errors as [`ClosureAction::try_new`].
    pub fn set_tolerances(&mut self, rtol: f64, atol: f64) -> Result<()> {
        check_tolerances(rtol, atol)?;
        if (rtol, atol) == (self.rtol, self.atol) {
            return Ok(());
        }
        self.rtol = rtol;
        self.atol = atol;
        self.mode_steps = graded_mode_steps(rtol);
        self.cache = None;
        Ok(())
    }

    /// The Runge–Kutta tolerances (rtol, atol).
    pub fn tolerances(&self) -> (f64, f64) {
        (self.rtol, self.atol)
    }

    /// The mode step x relaxation times before a measurement ([`graded_mode_steps`], at the grid
    /// point below x).
    fn graded_mode_step(&self, x: f64) -> f64 {
        let j = ((x / GRADE_STEP).floor().max(0.0) as usize).min(self.mode_steps.len() - 1);
        self.mode_steps[j]
    }

    /// The drift.
    pub fn drift(&self) -> &D {
        &self.drift
    }

    /// Forward sweeps run so far.
    pub fn sweeps(&self) -> usize {
        self.sweeps
    }

    /// Runge–Kutta steps taken by all sweeps so far.
    pub fn steps(&self) -> usize {
        self.steps
    }

    /// The output (event) times of [`EffectiveAction::history`].
    pub fn output_times(&self) -> &[f64] {
        &self.out_events.times
    }

    fn check(&self, lambda: &[f64]) -> Result<()> {
        crate::model::check_len("multipliers", self.meas_times.len() * self.measured.len(), lambda.len())?;
        if lambda.iter().any(|v| !v.is_finite()) {
            return Err(Error::NonFinite { what: "multipliers".into() });
        }
        Ok(())
    }

    /// One Runge–Kutta step (Tsitouras 5(4)) from (t, y) of size h, with K_1 = W(t, y) and its
    /// Jacobian in `work` (see [`RkWork`]): the stages, slopes and Jacobians into `work`, the new
    /// state into `work.arg`; returns the error norm, `None` when a stage is not realizable.
    fn rk_step(&self, t: f64, y: &[f64], h: f64, work: &mut RkWork) -> Option<f64> {
        with_size!(y.len(), r => self.rk_step_sized(r, t, y, h, work))
    }

    /// [`Self::rk_step`] for R = `r` = `y.len()` (see [`with_size`]).
    #[inline(always)]
    fn rk_step_sized(&self, r: usize, t: f64, y: &[f64], h: f64, work: &mut RkWork) -> Option<f64> {
        let rr = r * r;
        let RkWork { k, jac, hess, stages, arg, trouble, .. } = work;
        stages[..r].copy_from_slice(y);
        for i in 1..7 {
            for a in 0..r {
                arg[a] = y[a] + h * (0..i).map(|j| A[i][j] * k[j * r + a]).sum::<f64>();
            }
            if i < 6 {
                stages[i * r..(i + 1) * r].copy_from_slice(arg);
            }
            let ki = &mut k[i * r..(i + 1) * r];
            let ji = &mut jac[i * rr..(i + 1) * rr];
            let hi = if self.keep_hessians { &mut hess[i * rr * r..(i + 1) * rr * r] } else { &mut [][..] };
            if let Err(e) = self.stage_derivatives(t + C[i] * h, arg, ki, ji, hi) {
                *trouble = Some(e.0);
                return None;
            }
        }
        // The seventh stage argument is the fifth-order solution (FSAL).
        let y_new = &*arg;
        let mut err = 0.0;
        for a in 0..r {
            let e = h * (0..7).map(|i| E[i] * k[i * r + a]).sum::<f64>();
            let sc = self.atol + self.rtol * y[a].abs().max(y_new[a].abs());
            err += (e / sc) * (e / sc);
        }
        let err = (err / r as f64).sqrt();
        if !err.is_finite() || y_new.iter().any(|v| !v.is_finite()) {
            return None;
        }
        Some(err)
    }

    /// W and ∂W/∂λ at (t, y), and the Hessians ∇²W_a into `hess` when the family keeps them.
    fn stage_derivatives(
        &self,
        t: f64,
        y: &[f64],
        w: &mut [f64],
        jac: &mut [f64],
        hess: &mut [f64],
    ) -> std::result::Result<(), Unrealizable> {
        if self.keep_hessians {
            self.drift.w_jacobian_hessians(t, y, w, jac, hess)
        } else {
            self.drift.w_jacobian(t, y, w, jac)
        }
    }

    /// Integrates over `interval`, from t = its `start` to t_end = its `end`, with error control,
    /// pushing the accepted steps (with their stage Hessians when the family keeps them). W and
    /// ∂W/∂λ (and those Hessians) at (t, y) are evaluated unless `work` holds them already (the
    /// seventh stage of the last step, ending exactly at t, with no jump since: an output time
    /// between measurements).
    ///
    /// A fresh start (the sweep's first interval, or after a jump) begins with a step of at most
    /// hρ = z(0) = [`mode_step`] of rtol, ρ the spectral radius of ∂W/∂λ there: the jump
    /// excites the fast modes of ∂W/∂λ, which the long step left standing from the last interval
    /// does not resolve.
    ///
    /// With its `next_measurement` (the history's sweeps), the steps that would end within
    /// [`ADJOINT_WINDOW`] relaxation times 1/ρ of the next measurement are also limited to
    /// hρ ≤ z(x), ρ the spectral radius of ∂W/∂λ at the step's start, x = ρ·(the step end's
    /// distance to the measurement) and z(x) = [`mode_step`] of rtol·e^x ([`graded_mode_steps`]:
    /// there the adjoint's transient is e^{−x} of the jump, so a step may err by rtol·e^x of it;
    /// at rtol 10⁻⁶, 0.42 at the measurement and 1.23 eight relaxation times before it). A
    /// step shortened to end on an event leaves the proposed step size standing for the next one.
    /// The error control sees λ only, but the adjoint γ (and the dispersion's second-order adjoint)
    /// relaxes backward from each measurement's jump at the rate of ∂W/∂λ, where λ has long
    /// relaxed and the steps are long: the limit resolves the history just before a
    /// measurement (`docs/closures.md`, "Accuracy of the history just before a measurement").
    fn integrate(
        &self,
        interval: EventInterval,
        y: &mut [f64],
        h_guess: &mut f64,
        steps: &mut Steps,
        work: &mut RkWork,
    ) -> std::result::Result<(), FailureAt> {
        let EventInterval { start: t, end: t_end, next_measurement } = interval;
        let span = t_end - t;
        if span <= 0.0 {
            return Ok(());
        }
        let mut tc = t;
        let mut h = h_guess.min(span);
        let mut rejections = 0usize;
        // Whether the last attempt failed in a stage (its reason in `work.trouble`, which holds
        // the last stage failure of this interval).
        let mut stage_failed: bool;
        work.trouble = None;
        // the step cap below is per interval between events, as before the steps were flat
        let first_step = steps.len();
        let r = y.len();
        let rr = r * r;
        // The spectral radius of ∂W/∂λ at tc (work.jac[..rr]), kept until a step is accepted:
        // a rejected step leaves tc and its Jacobian as they were.
        let mut rho_at_tc: Option<f64> = None;
        if work.k1_time != Some(tc) {
            work.k1_time = None;
            let hess = if self.keep_hessians { &mut work.hess[..rr * r] } else { &mut [][..] };
            self.stage_derivatives(tc, y, &mut work.k[..r], &mut work.jac[..rr], hess)
                .map_err(|e| FailureAt::at(tc, e.0))?;
            work.k1_time = Some(tc);
            let rho = *rho_at_tc.insert(spectral_radius(&work.jac[..rr], r));
            if self.fresh_start_cap && rho > 0.0 {
                h = h.min(self.mode_steps[0] / rho);
            }
        }
        while tc < t_end {
            // A step that would end within the window before the next measurement.
            if let Some(tm) = next_measurement {
                let rho = *rho_at_tc.get_or_insert_with(|| spectral_radius(&work.jac[..rr], r));
                let h0 = h.min(t_end - tc);
                if rho > 0.0 && (tm - tc - h0) * rho < ADJOINT_WINDOW {
                    // The cap at the step's end, a fixed point of h = cap(tm − tc − h); the odd
                    // iterates from the shortest distance are below it.
                    let mut hc = h0;
                    for _ in 0..3 {
                        hc = h0.min(self.graded_mode_step((tm - tc - hc).max(0.0) * rho) / rho);
                    }
                    h = hc;
                }
            }
            let last = tc + h >= t_end - 1e-12 * span.max(1.0);
            let hh = if last { t_end - tc } else { h };
            match self.rk_step(tc, y, hh, work) {
                Some(err) if err <= 1.0 => {
                    steps.t.push(tc);
                    steps.h.push(hh);
                    steps.stages.extend_from_slice(&work.stages);
                    steps.jac.extend_from_slice(&work.jac[..6 * rr]);
                    y.copy_from_slice(&work.arg);
                    work.k.copy_within(6 * r..7 * r, 0);
                    work.jac.copy_within(6 * rr..7 * rr, 0);
                    if self.keep_hessians {
                        steps.hess.extend_from_slice(&work.hess[..6 * rr * r]);
                        work.hess.copy_within(6 * rr * r..7 * rr * r, 0);
                    }
                    work.k1_time = Some(tc + C[6] * hh);
                    rho_at_tc = None;
                    stage_failed = false;
                    tc = if last { t_end } else { tc + hh };
                    let fac = if err == 0.0 { 5.0 } else { (0.9 * err.powf(-0.2)).clamp(0.2, 5.0) };
                    // A step shortened to end on the event leaves the proposal h standing.
                    h = if hh < h { h.max(hh * fac) } else { hh * fac };
                    *h_guess = h;
                }
                Some(err) => {
                    h = hh * (0.9 * err.powf(-0.2)).clamp(0.1, 0.9);
                    rejections += 1;
                    stage_failed = false;
                }
                None => {
                    h = hh * 0.25;
                    rejections += 1;
                    stage_failed = true;
                }
            }
            if h < 1e-13 * span.max(1.0) || rejections > 10_000 || steps.len() - first_step > 2_000_000 {
                let why = match work.trouble.take() {
                    Some(why) if stage_failed => format!("{why} (the steps fell to {h:.1e})"),
                    _ if steps.len() - first_step > 2_000_000 => "more than 2,000,000 steps".to_string(),
                    Some(why) => format!(
                        "the error control rejected {rejections} steps, down to {h:.1e}; the last stage that \
                         could not be evaluated: {why}"
                    ),
                    None => format!("the error control rejected {rejections} steps, down to {h:.1e}"),
                };
                return Err(self.at_edge(FailureAt::at(tc, why), tc, y));
            }
        }
        steps.rejected += rejections;
        Ok(())
    }

    fn forward(&self, events: &Events, lambda: &[f64]) -> std::result::Result<Forward, FailureAt> {
        let s = self.measured.len();
        self.forward_with(events, &mut |k, _| Ok(lambda[k * s..(k + 1) * s].to_vec()))
    }

    /// The forward sweep with the multiplier of measurement k chosen by `choose(k, λ(t_k−))`.
    fn forward_with(
        &self,
        events: &Events,
        choose: &mut Choose<'_>,
    ) -> std::result::Result<Forward, FailureAt> {
        let ne = events.times.len();
        let span = events.times[ne - 1] - events.times[0];
        let mut h = if span > 0.0 { 1e-3 * span } else { 1.0 };
        let mut out = Forward {
            // A quarter more steps than the last sweep took: the step arrays grow in place.
            steps: Steps::with_capacity(
                self.step_hint.load(Relaxed) * 5 / 4,
                self.lambda0.len(),
                ne,
                self.keep_hessians,
            ),
            lambda_minus: Vec::with_capacity(ne),
            mu_minus: Vec::new(),
            mu_plus: Vec::new(),
            cov_minus: Vec::new(),
            mu: Vec::with_capacity(ne),
            cov: Vec::with_capacity(ne),
            f: 0.0,
            edge: None,
        };
        self.drift.start_sweep();
        let mut y = self.lambda0.clone();
        let mut work = RkWork::new(y.len(), self.keep_hessians);
        // For the history's sweeps, the next measurement time at or after each event.
        let mut next = vec![None; ne];
        if events.resolve_adjoint {
            for j in (0..ne).rev() {
                next[j] = if events.meas[j].is_some() {
                    Some(events.times[j])
                } else {
                    next.get(j + 1).copied().flatten()
                };
            }
        }
        // The box's edge is weighed on the history's sweeps, before and after each jump.
        let weigh_edge = |y: &[f64], time: f64, edge: &mut Option<GridEdge>| {
            if !events.resolve_adjoint {
                return;
            }
            if let Some((axis, mass)) = self.drift.edge_mass(y) {
                if edge.is_none_or(|w| mass > w.mass) {
                    *edge = Some(GridEdge { axis, time, mass });
                }
            }
        };
        for (e, &next_measurement) in next.iter().enumerate() {
            if e > 0 {
                let interval =
                    EventInterval { start: events.times[e - 1], end: events.times[e], next_measurement };
                self.integrate(interval, &mut y, &mut h, &mut out.steps, &mut work)?;
                out.steps.start.push(out.steps.len());
            }
            out.lambda_minus.push(y.clone());
            let te = events.times[e];
            weigh_edge(&y, te, &mut out.edge);
            let mut m =
                self.drift.moments(&y).map_err(|why| self.at_edge(FailureAt::at(te, why.0), te, &y))?;
            if let Some(k) = events.meas[e] {
                let before = m;
                let lk = choose(k, &y)?;
                for (b, &a) in self.measured.iter().enumerate() {
                    y[a] += lk[b];
                }
                work.k1_time = None;
                m = self
                    .drift
                    .moments(&y)
                    .map_err(|why| FailureAt::at(te, format!("after the jump, {}", why.0)))?;
                out.f += m.log_partition - before.log_partition;
                weigh_edge(&y, te, &mut out.edge);
                out.mu_minus.push(before.mean);
                out.cov_minus.push(before.covariance);
                out.mu_plus.push(m.mean.clone());
            }
            out.mu.push(m.mean);
            out.cov.push(m.covariance);
        }
        self.step_hint.store(out.steps.len(), Relaxed);
        if !out.f.is_finite() {
            return Err(FailureAt::at(events.times[ne - 1], "the log-partition increments are not finite"));
        }
        Ok(out)
    }

    /// The discrete adjoint: γ at every event (after the jump at measurement events, i.e.
    /// γ(t_k+)); with `second`, also the stage derivatives of every step for the tangents
    /// (flat, indexed like the forward sweep's steps: [`Steps::interval`]).
    fn backward(
        &self,
        events: &Events,
        fw: &Forward,
        second: bool,
    ) -> std::result::Result<Adjoint, FailureAt> {
        with_size!(self.drift.n_params(), r => self.backward_sized(r, events, fw, second))
    }

    /// [`Self::backward`] for R = `r` (see [`with_size`]).
    #[inline(always)]
    fn backward_sized(
        &self,
        r: usize,
        events: &Events,
        fw: &Forward,
        second: bool,
    ) -> std::result::Result<Adjoint, FailureAt> {
        let rr = r * r;
        let ne = events.times.len();
        let mut gamma = vec![0.0; r];
        let mut out = vec![Vec::new(); ne];
        let mut w = vec![0.0; r];
        let steps = &fw.steps;
        let ns = if second { steps.len() } else { 0 };
        let mut derivs = StepDerivs { jac: vec![0.0; 6 * rr * ns], hess: vec![0.0; 6 * rr * ns] };
        let mut kbar = vec![0.0; 6 * r];
        let mut ybar = vec![0.0; r];
        for e in (0..ne).rev() {
            out[e] = gamma.clone();
            if let Some(k) = events.meas[e] {
                for ((g, p), m) in gamma.iter_mut().zip(&fw.mu_plus[k]).zip(&fw.mu_minus[k]) {
                    *g += p - m;
                }
            }
            if e == 0 {
                break;
            }
            for s in steps.interval(e - 1).rev() {
                let h = steps.h[s];
                for i in 0..6 {
                    for a in 0..r {
                        kbar[i * r + a] = h * B[i] * gamma[a];
                    }
                }
                let stages = &steps.stages[6 * r * s..6 * r * (s + 1)];
                for i in (0..6).rev() {
                    let (ti, yi) = (steps.t[s] + C[i] * h, &stages[i * r..(i + 1) * r]);
                    let block = (6 * s + i) * rr..(6 * s + i + 1) * rr;
                    let ji = if second {
                        let ki = &kbar[i * r..(i + 1) * r];
                        let (ji, hi) = (&mut derivs.jac[block.clone()], &mut derivs.hess[block.clone()]);
                        // The forward sweep's J_i, which a family may keep (see
                        // `ClosureDrift::w_second_with_jacobian`).
                        ji.copy_from_slice(&steps.jac[block]);
                        if self.keep_hessians {
                            // H_i = Σ_a k̄_ia ∇²W_a(Y_i) from the forward sweep's Hessians.
                            let kept = &steps.hess[(6 * s + i) * rr * r..(6 * s + i + 1) * rr * r];
                            for (q, hq) in hi.iter_mut().enumerate() {
                                *hq = (0..r).map(|a| ki[a] * kept[a * rr + q]).sum();
                            }
                        } else {
                            self.drift
                                .w_second_with_jacobian(ti, yi, ki, &mut w, ji, hi)
                                .map_err(|why| FailureAt::at(ti, why.0))?;
                        }
                        &*ji
                    } else {
                        &steps.jac[block]
                    };
                    // Ȳ_i = J_iᵀ k̄_i.
                    for (b, yb) in ybar.iter_mut().enumerate() {
                        *yb = (0..r).map(|a| ji[a * r + b] * kbar[i * r + a]).sum();
                    }
                    for a in 0..r {
                        gamma[a] += ybar[a];
                    }
                    for j in 0..i {
                        let c = h * A[i][j];
                        if c != 0.0 {
                            for a in 0..r {
                                kbar[j * r + a] += c * ybar[a];
                            }
                        }
                    }
                }
            }
        }
        if let Some(e) = out.iter().position(|g| g.iter().any(|v| !v.is_finite())) {
            return Err(FailureAt::at(events.times[e], "the adjoint is not finite"));
        }
        Ok((out, derivs))
    }

    fn z_of(&self, events: &Events, fw: &Forward, gamma: &[Vec<f64>]) -> Vec<f64> {
        let mut z = Vec::with_capacity(self.meas_times.len() * self.measured.len());
        for (e, m) in events.meas.iter().enumerate() {
            if m.is_some() {
                for &a in &self.measured {
                    z.push(fw.mu[e][a] + gamma[e][a]);
                }
            }
        }
        z
    }

    /// F and z at λ on `events`; with `second`, the stage derivatives for the tangents.
    #[allow(clippy::type_complexity)]
    fn value(
        &mut self,
        events: &Events,
        lambda: &[f64],
        second: bool,
    ) -> std::result::Result<(Forward, Vec<Vec<f64>>, StepDerivs), FailureAt> {
        self.sweeps += 1;
        if events.resolve_adjoint {
            self.edge = None;
        }
        let fw = self.forward(events, lambda)?;
        self.steps += fw.steps.len();
        self.rejected += fw.steps.rejected;
        if events.resolve_adjoint {
            self.edge = fw.edge;
        }
        let (g, derivs) = self.backward(events, &fw, second)?;
        Ok((fw, g, derivs))
    }

    /// m(t) = μ + γ of all moments at every event.
    fn moments_at_events(fw: &Forward, gamma: &[Vec<f64>]) -> Vec<Vec<f64>> {
        fw.mu.iter().zip(gamma).map(|(mu, ga)| mu.iter().zip(ga).map(|(a, b)| a + b).collect()).collect()
    }

    /// ∂m(t)/∂λ_j at every event for every multiplier j, exactly (to round-off) for the computed
    /// sweep, `out[j][event][moment]`: the tangent-linear forward sweep δλ and the tangent of the
    /// discrete adjoint (second-order adjoint, "forward over reverse"), run per interval on the R
    /// unit directions and chained over the events for all multipliers. With δY_i,
    /// δK_i = J_iδY_i the stage tangents of a step (Y_i = y + hΣ_j a_ij K_j) and δk̄_i = hb_iδγ + Σ_{l>i} h a_li δȲ_l the tangents of its stage
    /// adjoints, δȲ_i = J_iᵀδk̄_i + H_iδY_i with H_i = ∇²(k̄_iᵀW)(Y_i); across a measurement
    /// δγ(t_k−) = δγ(t_k+) + C(t_k+)δλ(t_k+) − C(t_k−)δλ(t_k−) (the tangent of (II.50)), and
    /// δm = Cδλ + δγ (of (II.48)). The steps are not swept once per multiplier: each interval
    /// between events is reduced to its flow's Jacobian J_e and adjoint-weighted Hessian Q_e
    /// ([`Self::interval_derivatives`], R tangent columns each way), and the multipliers' tangents
    /// are chained over the events: δλ(end) = J_e δλ(start), δγ(start) = J_eᵀδγ(end) +
    /// Q_eδλ(start); the same derivatives as a sweep of all multipliers through every step
    /// (the products associate differently). Cost: one sweep with second-order stage
    /// derivatives, O(R³) work per stage and O(R² n) per event for n multipliers.
    fn tangents(
        &mut self,
        events: &Events,
        lambda: &[f64],
    ) -> std::result::Result<(Vec<Vec<f64>>, Tangents), FailureAt> {
        // The forward sweep of the last evaluation at λ (the accepted Newton iterate) is reused:
        // taken out of the cache and put back at the end.
        let kept = match self.cache.take() {
            Some((l, fw, g))
                if l.as_slice() == lambda
                    && self.cache_sweeps == self.sweeps
                    && events.times == self.fit_events.times
                    && events.resolve_adjoint == self.fit_events.resolve_adjoint =>
            {
                Some((l, fw, g))
            }
            other => {
                self.cache = other;
                None
            }
        };
        let (fw, g, derivs, restore) = match kept {
            Some((l, fw, g0)) => match self.backward(events, &fw, true) {
                Ok((g, derivs)) => (fw, g, derivs, Some((l, g0))),
                Err(e) => {
                    self.cache = Some((l, fw, g0));
                    return Err(e);
                }
            },
            None => {
                let (fw, g, derivs) = self.value(events, lambda, true)?;
                (fw, g, derivs, None)
            }
        };
        let base = Self::moments_at_events(&fw, &g);
        let r = self.drift.n_params();
        let rr = r * r;
        let nm = lambda.len();
        let ne = events.times.len();
        // Per interval (e − 1, e): its flow's J_e and Q_e (R × R each).
        let mut flow = vec![0.0; 2 * rr * ne];
        let mut work = IntervalWork::default();
        for e in 1..ne {
            let (je, qe) = flow[2 * rr * e..2 * rr * (e + 1)].split_at_mut(rr);
            with_size!(r, r => Self::interval_derivatives(&fw.steps, e - 1, &derivs, r, &mut work, je, qe));
        }
        let flow_of = |e: usize| flow[2 * rr * e..2 * rr * (e + 1)].split_at(rr);
        // Forward tangent δλ (R × nm, row-major) after each event; before each measurement's jump.
        let mut dl = vec![0.0; r * nm];
        let mut dl_after = Vec::with_capacity(ne);
        let mut dl_before = Vec::new();
        for (e, meas) in events.meas.iter().enumerate() {
            if e > 0 {
                dl = Self::mat_mul(flow_of(e).0, &dl, r, nm, false);
            }
            if let Some(k) = *meas {
                dl_before.push(dl.clone());
                for (b, &a) in self.measured.iter().enumerate() {
                    dl[a * nm + k * self.measured.len() + b] += 1.0;
                }
            }
            dl_after.push(dl.clone());
        }
        // Backward tangent δγ (R × nm), γ after the jump at each event.
        let mut out = Tangents::zeros(nm, ne, r);
        let mut dg = vec![0.0; r * nm];
        for e in (0..ne).rev() {
            let c = &fw.cov[e];
            for j in 0..nm {
                for (a, o) in out.at_mut(j, e).iter_mut().enumerate() {
                    *o = dg[a * nm + j] + (0..r).map(|b| c[a * r + b] * dl_after[e][b * nm + j]).sum::<f64>();
                }
            }
            if let Some(k) = events.meas[e] {
                let cm = &fw.cov_minus[k];
                for a in 0..r {
                    for j in 0..nm {
                        dg[a * nm + j] += (0..r)
                            .map(|b| {
                                c[a * r + b] * dl_after[e][b * nm + j]
                                    - cm[a * r + b] * dl_before[k][b * nm + j]
                            })
                            .sum::<f64>();
                    }
                }
            }
            if e == 0 {
                break;
            }
            // δγ(start) = J_eᵀ δγ(end) + Q_e δλ(start).
            let (j, q) = flow_of(e);
            let mut next = Self::mat_mul(j, &dg, r, nm, true);
            for (v, w) in next.iter_mut().zip(Self::mat_mul(q, &dl_after[e - 1], r, nm, false)) {
                *v += w;
            }
            dg = next;
        }
        if let Some((l, g0)) = restore {
            self.cache = Some((l, fw, g0));
        }
        if out.values.iter().any(|v| !v.is_finite()) {
            return Err(FailureAt::anywhere("the tangents of the sweep are not finite"));
        }
        Ok((base, out))
    }

    /// M X (or Mᵀ X with `transpose`) for an R × R matrix M and an R × n matrix X, row-major.
    fn mat_mul(m: &[f64], x: &[f64], r: usize, n: usize, transpose: bool) -> Vec<f64> {
        let mut out = vec![0.0; r * n];
        for a in 0..r {
            let row = &mut out[a * n..(a + 1) * n];
            for b in 0..r {
                let c = if transpose { m[b * r + a] } else { m[a * r + b] };
                for (v, &w) in row.iter_mut().zip(&x[b * n..(b + 1) * n]) {
                    *v += c * w;
                }
            }
        }
        out
    }

    /// The derivatives of the discrete flow y(t_{e+1}−) = Φ_e(y(t_e+)) of interval `e` (its
    /// accepted steps), R × R row-major: J = ∂Φ_e/∂y into `jac` and Q = ∇²(γ(t_{e+1}−)ᵀΦ_e) into
    /// `q`, with γ(t_{e+1}−) the base adjoint at the interval's end (which enters through the
    /// stage Hessians H_i = ∇²(k̄_iᵀW) of `derivs`). J is the tangent-linear sweep and Q the
    /// second-order adjoint sweep from δγ(end) = 0, each on the R unit directions of y(t_e+);
    /// the tangent of the interval's adjoint is then δγ(start) = Jᵀδγ(end) + Qδy(start).
    #[inline(always)]
    fn interval_derivatives(
        steps: &Steps,
        e: usize,
        derivs: &StepDerivs,
        r: usize,
        work: &mut IntervalWork,
        jac: &mut [f64],
        q: &mut [f64],
    ) {
        let rr = r * r;
        let IntervalWork { dys, dks, stage_tangents, adjoint } = work;
        // J: δy from the identity through the steps, keeping the stage tangents.
        jac.fill(0.0);
        for a in 0..r {
            jac[a * r + a] = 1.0;
        }
        stage_tangents.clear();
        for st in steps.interval(e) {
            Self::tangent_step(steps.h[st], &derivs.jac[6 * rr * st..6 * rr * (st + 1)], r, jac, dys, dks);
            stage_tangents.extend_from_slice(dys);
        }
        // Q: δγ from zero back through the steps.
        q.fill(0.0);
        adjoint.dk.resize(6 * rr, 0.0);
        adjoint.dyb.resize(rr, 0.0);
        for (st, dy) in steps.interval(e).zip(stage_tangents.chunks_exact(6 * rr)).rev() {
            let block = 6 * rr * st..6 * rr * (st + 1);
            Self::adjoint_tangent_step(
                steps.h[st],
                &derivs.jac[block.clone()],
                &derivs.hess[block],
                r,
                q,
                dy,
                adjoint,
            );
        }
    }

    /// One step (size `h`, stage Jacobians `jac`: 6 R × R blocks) of the tangent-linear
    /// Runge–Kutta sweep on the R columns of δy (R × R, row-major): the stage tangents δY_i into
    /// `dys` (6 R × R), δy advanced in place; `dks` is a workspace.
    #[inline(always)]
    fn tangent_step(h: f64, jac: &[f64], r: usize, dy: &mut [f64], dys: &mut Vec<f64>, dks: &mut Vec<f64>) {
        let rr = r * r;
        dys.resize(6 * rr, 0.0);
        // Six stage blocks and one row of Σ_i b_i δK_i.
        dks.resize(6 * rr + r, 0.0);
        // Row by row; each entry is summed in the order of the stage formulas.
        for i in 0..6 {
            let (done, rest) = dks.split_at_mut(i * rr);
            // δY_i = δy + h Σ_{l<i} a_il δK_l.
            for a in 0..r {
                let yi = &mut dys[i * rr + a * r..i * rr + (a + 1) * r];
                yi.copy_from_slice(&dy[a * r..(a + 1) * r]);
                for l in 0..i {
                    let c = h * A[i][l];
                    for (v, &k) in yi.iter_mut().zip(&done[l * rr + a * r..l * rr + (a + 1) * r]) {
                        *v += c * k;
                    }
                }
            }
            // δK_i = J_i δY_i.
            let ji = &jac[i * rr..(i + 1) * rr];
            let yi = &dys[i * rr..(i + 1) * rr];
            for a in 0..r {
                let ki = &mut rest[a * r..(a + 1) * r];
                let c = ji[a * r];
                for (v, &y) in ki.iter_mut().zip(&yi[..r]) {
                    *v = c * y;
                }
                for b in 1..r {
                    let c = ji[a * r + b];
                    for (v, &y) in ki.iter_mut().zip(&yi[b * r..(b + 1) * r]) {
                        *v += c * y;
                    }
                }
            }
        }
        // δy += h Σ_i b_i δK_i.
        let (stages, acc) = dks.split_at_mut(6 * rr);
        let acc = &mut acc[..r];
        for a in 0..r {
            for (v, &k) in acc.iter_mut().zip(&stages[a * r..(a + 1) * r]) {
                *v = B[0] * k;
            }
            for i in 1..6 {
                for (v, &k) in acc.iter_mut().zip(&stages[i * rr + a * r..i * rr + (a + 1) * r]) {
                    *v += B[i] * k;
                }
            }
            for (v, &s) in dy[a * r..(a + 1) * r].iter_mut().zip(acc.iter()) {
                *v += h * s;
            }
        }
    }

    /// One step of the tangent of the discrete adjoint (the second-order adjoint), backwards,
    /// on R columns: with δγ (`dg`, R × R) after the step and the step's stage tangents δY_i
    /// (`dy`, 6 R × R), δk̄_i = h b_i δγ + Σ_{l>i} h a_li δȲ_l, δȲ_i = J_iᵀ δk̄_i + H_i δY_i
    /// (J_i, H_i: `jac`, `hess`, 6 R × R blocks) and δγ += Σ_i δȲ_i in place. `work` holds δk̄
    /// (6 R × R) and δȲ_i (R × R).
    #[inline(always)]
    fn adjoint_tangent_step(
        h: f64,
        jac: &[f64],
        hess: &[f64],
        r: usize,
        dg: &mut [f64],
        dy: &[f64],
        work: &mut AdjointTangentWork,
    ) {
        let (dk, dyb) = (&mut work.dk[..], &mut work.dyb[..]);
        let rr = r * r;
        for i in 0..6 {
            for q in 0..rr {
                dk[i * rr + q] = h * B[i] * dg[q];
            }
        }
        for i in (0..6).rev() {
            let ji = &jac[i * rr..(i + 1) * rr];
            let hi = &hess[i * rr..(i + 1) * rr];
            let dki = &dk[i * rr..(i + 1) * rr];
            let dyi = &dy[i * rr..(i + 1) * rr];
            // δȲ_i = J_iᵀ δk̄_i + H_i δY_i, row by row.
            for b in 0..r {
                let row = &mut dyb[b * r..(b + 1) * r];
                row.fill(0.0);
                for a in 0..r {
                    let c = ji[a * r + b];
                    for (v, &k) in row.iter_mut().zip(&dki[a * r..(a + 1) * r]) {
                        *v += c * k;
                    }
                }
                for a in 0..r {
                    let c = hi[b * r + a];
                    for (v, &y) in row.iter_mut().zip(&dyi[a * r..(a + 1) * r]) {
                        *v += c * y;
                    }
                }
            }
            for q in 0..rr {
                dg[q] += dyb[q];
            }
            for jj in 0..i {
                let cc = h * A[i][jj];
                if cc != 0.0 {
                    for q in 0..rr {
                        dk[jj * rr + q] += cc * dyb[q];
                    }
                }
            }
        }
    }

    /// The closure's assumed-density filter as a starting point of the dual: measurements
    /// taken in time order, each multiplier chosen with the earlier ones fixed and the later ones
    /// ignored, i.e. solving the filter condition μ_Z(λ(t_k−) + Eλ_k) = r_k − R_kλ_k
    /// (`003_d2fc48a470e528fc.txt (I.60)` with the history replaced by the filtered mean) by
    /// Newton's method (its Jacobian EᵀCE + R is positive definite, so the root is unique).
    /// Missing data get λ_k = 0. The sweep, with its adjoint, is left as the cached evaluation of
    /// F at the returned multipliers. `None` when the sweep or its adjoint fails.
    pub fn filter_start(&mut self, data: &DualData) -> Option<Vec<f64>> {
        let s = self.measured.len();
        if data.output_dim != s || data.r.len() != self.meas_times.len() * s {
            return None;
        }
        let mut chosen = vec![0.0; data.r.len()];
        let events = self.fit_events.clone();
        let measured = self.measured.clone();
        let drift = &self.drift;
        let meas_times = &self.meas_times;
        let r_dim = drift.n_params();
        let mut choose = |k: usize, y: &[f64]| -> std::result::Result<Vec<f64>, FailureAt> {
            let idx: Vec<usize> = (0..s).filter(|&b| !data.r[k * s + b].is_nan()).collect();
            let mut lk = vec![0.0; s];
            for _ in 0..50 {
                let mut yy = y.to_vec();
                for (b, &a) in measured.iter().enumerate() {
                    yy[a] += lk[b];
                }
                let m = drift.moments(&yy).map_err(|why| FailureAt::at(meas_times[k], why.0))?;
                let na = idx.len();
                let mut jac = DMatrix::zeros(na, na);
                let mut g = nalgebra::DVector::zeros(na);
                for (i, &b) in idx.iter().enumerate() {
                    let (mb, v) = (k * s + b, data.variance[k * s + b]);
                    g[i] = m.mean[measured[b]] + v * lk[b] - data.r[mb];
                    for (j, &c) in idx.iter().enumerate() {
                        jac[(i, j)] = m.covariance[measured[b] * r_dim + measured[c]];
                    }
                    jac[(i, i)] += v;
                }
                let scale: f64 = idx.iter().map(|&b| data.variance[k * s + b]).fold(0.0, f64::max);
                if g.iter().any(|v| !v.is_finite()) {
                    return Err(FailureAt::at(meas_times[k], "the filter's jump is not finite"));
                }
                if g.amax() <= 1e-12 * (1.0 + scale) {
                    break;
                }
                let d = jac
                    .cholesky()
                    .ok_or_else(|| {
                        FailureAt::at(meas_times[k], "the filter's jump has no positive curvature")
                    })?
                    .solve(&g);
                for (i, &b) in idx.iter().enumerate() {
                    lk[b] -= d[i];
                }
            }
            if lk.iter().any(|v| !v.is_finite()) {
                return Err(FailureAt::at(meas_times[k], "the filter's jump is not finite"));
            }
            chosen[k * s..(k + 1) * s].copy_from_slice(&lk);
            Ok(lk)
        };
        self.sweeps += 1;
        let fw = self.forward_with(&events, &mut choose);
        let fw = self.failed(fw)?;
        self.steps += fw.steps.len();
        self.rejected += fw.steps.rejected;
        // The sweep is the forward sweep of F at the chosen multipliers: with its adjoint (no
        // drift evaluations) it is the cached evaluation there.
        let g = self.backward(&events, &fw, false);
        let (g, _) = self.failed(g)?;
        self.cache = Some((chosen.clone(), fw, g));
        self.cache_sweeps = self.sweeps;
        Some(chosen)
    }

    /// The history m(t) = μ(λ(t)) + γ(t) of all moments at the output times, with μ(t)
    /// separately (`003_d2fc48a470e528fc.txt (II.48)`), or why the sweep has none at λ.
    /// Errors: misuse (λ of the wrong length or not finite).
    pub fn moment_paths(&mut self, lambda: &[f64]) -> Result<Swept<MomentPaths>> {
        self.check(lambda)?;
        let events = self.out_events.clone();
        let value = self.value(&events, lambda, false);
        let Some((fw, g, _)) = self.failed(value) else { return Ok(Err(Failure::Unrealizable)) };
        Ok(Ok(MomentPaths { m: Self::moments_at_events(&fw, &g), mu: fw.mu, times: events.times }))
    }

    /// Where the density of the last history sweep reaches the edge of the family's box: the
    /// largest mass near an edge ([`ClosureDrift::edge_mass`]) at an output or measurement time
    /// (before or after the jump), when it exceeds [`EDGE_MASS`]; `None` for a family without
    /// a box or before any history sweep.
    pub fn box_edge(&self) -> Option<GridEdge> {
        self.edge.filter(|e| e.mass > EDGE_MASS)
    }

    /// The value of a sweep, or `None` with its failure kept as [`EffectiveAction::last_failure`]
    /// (and its edge as [`ClosureAction::failure_edge`]).
    fn failed<T>(&mut self, swept: std::result::Result<T, FailureAt>) -> Option<T> {
        swept
            .map_err(|FailureAt { why, edge }| {
                self.last_failure = Some(why);
                self.failure_edge = edge;
            })
            .ok()
    }

    /// `failure` with the density at λ = `y`, the last point the sweep reached (time `t`),
    /// where more than [`EDGE_MASS`] of its mass lies near its box's edge
    /// ([`ClosureDrift::edge_mass`]).
    fn at_edge(&self, mut failure: FailureAt, t: f64, y: &[f64]) -> FailureAt {
        failure.edge = (self.drift.edge_mass(y))
            .filter(|&(_, mass)| mass > EDGE_MASS)
            .map(|(axis, mass)| GridEdge { axis, time: t, mass });
        failure
    }

    /// Where the density stood against its box's edge when the last sweep that failed stopped
    /// (more than [`EDGE_MASS`] of its mass near an end of an axis, at the last λ it reached):
    /// the likely cause of that failure, which a wider box removes. `None` when the last
    /// failure was elsewhere, or for a family without a fixed box.
    pub fn failure_edge(&self) -> Option<GridEdge> {
        self.failure_edge
    }

    /// The linear moment of every state (index into M).
    fn linear_moments(&self) -> Result<Vec<usize>> {
        (0..self.drift.state_dim())
            .map(|i| {
                self.drift.linear_index(i).ok_or_else(|| Error::InvalidOption {
                    name: "closure".into(),
                    reason: format!("the family has no linear moment of state {i}"),
                })
            })
            .collect()
    }
}

impl<D: ClosureDrift> EffectiveAction for ClosureAction<D> {
    fn measurement_times(&self) -> &[f64] {
        &self.meas_times
    }

    fn output_dim(&self) -> usize {
        self.measured.len()
    }

    /// F(λ) = Σ ΔF_k (`(II.51)`) and z_k = Eᵀ(μ_k+ + γ_k+) (`(A.30)`); a sweep that leaves the
    /// moment space gives F = NaN.
    fn evaluate(&mut self, lambda: &[f64]) -> Result<ActionValue> {
        self.check(lambda)?;
        if let Some((l, fw, g)) = &self.cache {
            if l.as_slice() == lambda {
                return Ok(ActionValue { value: fw.f, z: self.z_of(&self.fit_events, fw, g) });
            }
        }
        let events = self.fit_events.clone();
        let value = self.value(&events, lambda, false);
        match self.failed(value) {
            Some((fw, g, _)) => {
                let z = self.z_of(&events, &fw, &g);
                let value = fw.f;
                self.cache = Some((lambda.to_vec(), fw, g));
                self.cache_sweeps = self.sweeps;
                Ok(ActionValue { value, z })
            }
            None => Ok(ActionValue { value: f64::NAN, z: vec![f64::NAN; lambda.len()] }),
        }
    }

    /// ∇²F = ∂z/∂λ of the computed F, exactly to round-off, by the tangent sweeps of
    /// `tangents` (each interval's J_e and Q_e, chained over the events for all
    /// multipliers); symmetrised.
    fn hessian(&mut self, lambda: &[f64]) -> Result<Swept<DMatrix<f64>>> {
        self.check(lambda)?;
        let events = self.fit_events.clone();
        let tangents = self.tangents(&events, lambda);
        let Some((_, tangents)) = self.failed(tangents) else { return Ok(Err(Failure::Unrealizable)) };
        let m = lambda.len();
        let event_of: Vec<usize> =
            events.meas.iter().enumerate().filter_map(|(e, mm)| mm.map(|_| e)).collect();
        let s = self.measured.len();
        let h = DMatrix::from_fn(m, m, |i, j| tangents.at(j, event_of[i / s])[self.measured[i % s]]);
        Ok(Ok((&h + h.transpose()) * 0.5))
    }

    /// m(t) of every state at the output times (`(II.48)`); the variance is m_{x²} − m_x² when
    /// the family has the square moments; `cross` (Cov(x_i(τ), Z_j) = ∂m_{x_i}(τ)/∂λ_j) by
    /// the tangent sweeps of [`EffectiveAction::hessian`].
    fn history(&mut self, lambda: &[f64], cross: bool) -> Result<Swept<History>> {
        self.check(lambda)?;
        let n = self.drift.state_dim();
        let events = self.out_events.clone();
        let lin = self.linear_moments()?;
        let (m, cr) = if cross {
            let tangents = self.tangents(&events, lambda);
            let Some((m, t)) = self.failed(tangents) else { return Ok(Err(Failure::Unrealizable)) };
            let nm = lambda.len();
            let cr =
                (0..m.len()).map(|e| DMatrix::from_fn(n, nm, |i, j| t.at(j, e)[lin[i]])).collect::<Vec<_>>();
            (m, Some(cr))
        } else {
            let value = self.value(&events, lambda, false);
            let Some((fw, g, _)) = self.failed(value) else { return Ok(Err(Failure::Unrealizable)) };
            (Self::moments_at_events(&fw, &g), None)
        };
        let sq: Vec<Option<usize>> = (0..n).map(|i| self.drift.square_index(i)).collect();
        let mean: Vec<Vec<f64>> = m.iter().map(|mt| lin.iter().map(|&a| mt[a]).collect()).collect();
        let variance = m
            .iter()
            .map(|mt| {
                (0..n)
                    .map(|i| sq[i].map_or(f64::NAN, |q| (mt[q] - mt[lin[i]] * mt[lin[i]]).max(0.0)))
                    .collect()
            })
            .collect();
        Ok(Ok(History { times: events.times, mean, variance, cross: cr }))
    }

    /// The history with its cross-covariances, and ∇²F read from the same tangents:
    /// Cov(Z_k, Z_j) is the cross-covariance of the measured states at t_k.
    fn history_and_hessian(&mut self, lambda: &[f64]) -> Result<Swept<(History, DMatrix<f64>)>> {
        let history = match self.history(lambda, true)? {
            Ok(h) => h,
            Err(e) => return Ok(Err(e)),
        };
        let cross = history.cross.as_ref().expect("asked for the cross-covariances");
        let lin = self.linear_moments()?;
        let states: Vec<usize> = self
            .measured
            .iter()
            .map(|&a| lin.iter().position(|&l| l == a).expect("a measured moment is a linear moment"))
            .collect();
        let (s, m) = (states.len(), lambda.len());
        let mut h = DMatrix::zeros(m, m);
        for (k, &tk) in self.meas_times.iter().enumerate() {
            let e = history.times.iter().position(|&t| t == tk).ok_or_else(|| Error::InvalidOption {
                name: "closure".into(),
                reason: "a measurement time is missing from the output times".into(),
            })?;
            for (b, &state) in states.iter().enumerate() {
                for j in 0..m {
                    h[(k * s + b, j)] = cross[e][(state, j)];
                }
            }
        }
        let h = (&h + h.transpose()) * 0.5;
        Ok(Ok((history, h)))
    }

    fn tolerances(&self) -> Option<(f64, f64)> {
        Some(ClosureAction::tolerances(self))
    }

    fn last_failure(&self) -> Option<&str> {
        self.last_failure.as_deref()
    }

    fn set_tolerances(&mut self, rtol: f64, atol: f64) -> Result<()> {
        ClosureAction::set_tolerances(self, rtol, atol)
    }

    fn work(&self) -> Option<Work> {
        Some(Work { sweeps: self.sweeps, steps: self.steps, rejected: self.rejected })
    }
}

#[cfg(test)]
mod tests {
    use super::{ClosureAction, SweepTolerances, A, B, C, E};
    use crate::action::closure::drift::{ClosureDrift, FamilyMoments, GaussianDrift, Unrealizable};
    use crate::action::dual::EffectiveAction;
    use crate::model::library::DoubleWell;

    /// A drift that forwards to another but does not keep the stage Hessians
    /// ([`ClosureDrift::keeps_hessians`] false): its Hessian sweeps evaluate ∇²(κᵀW) at every stage.
    struct Evaluating<D>(D);

    impl<D: ClosureDrift> ClosureDrift for Evaluating<D> {
        fn n_params(&self) -> usize {
            self.0.n_params()
        }
        fn state_dim(&self) -> usize {
            self.0.state_dim()
        }
        fn start_sweep(&self) {
            self.0.start_sweep()
        }
        fn w(&self, t: f64, lambda: &[f64], out: &mut [f64]) -> Result<(), Unrealizable> {
            self.0.w(t, lambda, out)
        }
        fn w_jacobian(&self, t: f64, l: &[f64], w: &mut [f64], jac: &mut [f64]) -> Result<(), Unrealizable> {
            self.0.w_jacobian(t, l, w, jac)
        }
        fn w_second(
            &self,
            t: f64,
            l: &[f64],
            kappa: &[f64],
            w: &mut [f64],
            jac: &mut [f64],
            hess: &mut [f64],
        ) -> Result<(), Unrealizable> {
            self.0.w_second(t, l, kappa, w, jac, hess)
        }
        fn moments(&self, lambda: &[f64]) -> Result<FamilyMoments, Unrealizable> {
            self.0.moments(lambda)
        }
        fn linear_index(&self, state: usize) -> Option<usize> {
            self.0.linear_index(state)
        }
        fn square_index(&self, state: usize) -> Option<usize> {
            self.0.square_index(state)
        }
    }

    #[test]
    fn kept_stage_hessians_give_the_same_second_derivatives() {
        // The one-state Gaussian closure of the double well keeps its stage Hessians; ∇²F and the
        // history's cross-covariances from them equal those of sweeps that evaluate ∇²(κᵀW) at
        // every stage (the same numbers, summed in the same order).
        let drift = || GaussianDrift::try_new(&DoubleWell, &[0.5]).unwrap();
        assert!(drift().keeps_hessians());
        let lambda0 = vec![-1.0 / 0.09, -0.5 / 0.09];
        let times = [1.0, 2.0, 3.0];
        let outputs = [0.5, 1.0, 1.5, 2.0, 2.5, 3.0];
        let tolerances = SweepTolerances { rtol: 1e-8, atol: 1e-10 };
        let mut kept =
            ClosureAction::try_new(drift(), 0.0, lambda0.clone(), &times, vec![0], &outputs, tolerances)
                .unwrap();
        let mut evaluated =
            ClosureAction::try_new(Evaluating(drift()), 0.0, lambda0, &times, vec![0], &outputs, tolerances)
                .unwrap();
        assert!(kept.keep_hessians && !evaluated.keep_hessians);
        for lambda in [[1.5, -2.0, 0.7], [-20.0, 25.0, 3.0]] {
            assert_eq!(kept.hessian(&lambda).unwrap(), evaluated.hessian(&lambda).unwrap());
            let (a, b) = (
                kept.history(&lambda, true).unwrap().unwrap(),
                evaluated.history(&lambda, true).unwrap().unwrap(),
            );
            assert_eq!(a.cross, b.cross);
            assert_eq!(a.mean, b.mean);
        }
    }

    #[test]
    fn a_fresh_start_begins_within_the_mode_step() {
        // Forty jumps on the one-state double well: the first step after each starts within hρ ≤
        // mode_step(rtol), not from the last interval's long step. Most rejections go (26 of 74
        // remain, with as many steps accepted), and F, z and the history agree with the
        // uncapped steps' to the tolerance's level.
        let drift = || GaussianDrift::try_new(&DoubleWell, &[0.5]).unwrap();
        let lambda0 = vec![-1.0 / 0.09, -0.5 / 0.09];
        let times: Vec<f64> = (1..=40).map(|k| 0.5 * k as f64).collect();
        let lambda: Vec<f64> = (0..40).map(|k| (0.7 * k as f64).sin()).collect();
        // The closures' default tolerances.
        let tolerances = SweepTolerances { rtol: 1e-6, atol: 1e-9 };
        let run = |cap: bool| {
            let mut action =
                ClosureAction::try_new(drift(), 0.0, lambda0.clone(), &times, vec![0], &times, tolerances)
                    .unwrap();
            action.fresh_start_cap = cap;
            let value = action.evaluate(&lambda).unwrap();
            let history = action.history(&lambda, false).unwrap().unwrap();
            let work = action.work().unwrap();
            (value, history.mean, work.rejected, work.steps)
        };
        let (capped, capped_mean, capped_rejected, capped_steps) = run(true);
        let (free, free_mean, free_rejected, free_steps) = run(false);
        assert!(
            2 * capped_rejected < free_rejected,
            "rejected steps: {capped_rejected} capped, {free_rejected} not (accepted {capped_steps}, {free_steps})"
        );
        assert!(capped_rejected + capped_steps < free_rejected + free_steps);
        assert!((capped.value - free.value).abs() < 1e-6 * free.value.abs().max(1.0));
        let largest = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
        assert!(largest(&capped.z, &free.z) < 1e-6, "{}", largest(&capped.z, &free.z));
        for (a, b) in capped_mean.iter().zip(&free_mean) {
            assert!(largest(a, b) < 1e-6, "{}", largest(a, b));
        }
    }

    /// Σ_i w_i φ_i for stage vectors w, φ.
    fn sum(w: &[f64], phi: &[f64]) -> f64 {
        w.iter().zip(phi).map(|(a, b)| a * b).sum()
    }

    /// (A φ)_i over the seven stages.
    fn a_times(phi: &[f64]) -> Vec<f64> {
        (0..7).map(|i| (0..i.min(6)).map(|j| A[i][j] * phi[j]).sum()).collect()
    }

    /// The 17 order conditions of order ≤ 5 for the weights `w` (Butcher trees; Hairer, Nørsett,
    /// Wanner, *Solving ODEs I*, Sec. II.2, Table 2.2): the residuals Σ w Φ(t) − 1/γ(t),
    /// grouped by order.
    fn order_residuals(w: &[f64]) -> Vec<Vec<f64>> {
        let c = C.to_vec();
        let pow = |k: i32| c.iter().map(|x| x.powi(k)).collect::<Vec<_>>();
        let mul = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).collect::<Vec<_>>();
        let one = vec![1.0; 7];
        let ac = a_times(&c);
        let ac2 = a_times(&pow(2));
        let aac = a_times(&ac);
        vec![
            vec![sum(w, &one) - 1.0],
            vec![sum(w, &c) - 1.0 / 2.0],
            vec![sum(w, &pow(2)) - 1.0 / 3.0, sum(w, &ac) - 1.0 / 6.0],
            vec![
                sum(w, &pow(3)) - 1.0 / 4.0,
                sum(w, &mul(&c, &ac)) - 1.0 / 8.0,
                sum(w, &ac2) - 1.0 / 12.0,
                sum(w, &aac) - 1.0 / 24.0,
            ],
            vec![
                sum(w, &pow(4)) - 1.0 / 5.0,
                sum(w, &mul(&pow(2), &ac)) - 1.0 / 10.0,
                sum(w, &mul(&c, &ac2)) - 1.0 / 15.0,
                sum(w, &mul(&c, &aac)) - 1.0 / 30.0,
                sum(w, &mul(&ac, &ac)) - 1.0 / 20.0,
                sum(w, &a_times(&pow(3))) - 1.0 / 20.0,
                sum(w, &a_times(&mul(&c, &ac))) - 1.0 / 40.0,
                sum(w, &a_times(&ac2)) - 1.0 / 60.0,
                sum(w, &a_times(&aac)) - 1.0 / 120.0,
            ],
        ]
    }

    /// The mode step against the stability function formed independently, stage by stage: the
    /// relative error of e^{−z} is within `rtol` at the bound and exceeds it 1 % further.
    #[test]
    fn the_mode_step_resolves_a_decay_to_the_tolerance() {
        let err = |z: f64| {
            // R(−z) by the stages: Y_i = 1 − z Σ_j a_ij Y_j, R = 1 − z Σ b_i Y_i.
            let mut y = [0.0; 6];
            for i in 0..6 {
                y[i] = 1.0 - z * (0..i).map(|j| A[i][j] * y[j]).sum::<f64>();
            }
            let r = 1.0 - z * (0..6).map(|i| B[i] * y[i]).sum::<f64>();
            (r * z.exp() - 1.0).abs()
        };
        for rtol in [1e-4, 1e-6, 1e-8] {
            let z = super::mode_step(rtol);
            assert!(err(z) <= rtol && err(z * 1.01) > rtol, "rtol {rtol}: z {z}, error {}", err(z));
        }
        let z6 = super::mode_step(1e-6);
        assert!((0.35..0.45).contains(&z6), "{z6}");
        // A tolerance that every z ≤ 3 meets: the search interval's end (below the real-axis
        // stability limit, 3.5).
        assert_eq!(super::mode_step(1e3), 3.0);
        // The graded bounds: x relaxation times before a measurement a step may err by rtol·e^x
        // of the transient there; they start at the mode step and grow with x.
        let graded = super::graded_mode_steps(1e-6);
        assert_eq!(graded.len(), 33);
        assert_eq!(graded[0], z6);
        assert!(graded.windows(2).all(|w| w[0] < w[1] || w[1] == 3.0), "{graded:?}");
        for (j, &z) in graded.iter().enumerate() {
            let tol = 1e-6 * (j as f64 * super::GRADE_STEP).exp();
            // (to rounding: the bisection ends on the boundary of the polynomial's form)
            let ok = err(z) <= tol * (1.0 + 1e-9) && (z == 3.0 || err(z * 1.01) > tol);
            assert!(ok, "x = {}: z {z}, error {}, tolerance {tol}", j as f64 / 4.0, err(z));
        }
    }

    #[test]
    fn the_pair_has_orders_five_and_four() {
        // Row sums of A are the nodes (the simplifying assumption every explicit pair uses).
        for i in 0..7 {
            assert!((A[i].iter().sum::<f64>() - C[i]).abs() < 1e-14, "row {i}");
        }
        let b: Vec<f64> = B.iter().copied().chain([0.0]).collect();
        for (order, group) in order_residuals(&b).iter().enumerate() {
            for (t, r) in group.iter().enumerate() {
                assert!(r.abs() < 1e-13, "fifth-order weights, order {} tree {t}: residual {r:e}", order + 1);
            }
        }
        // The embedded weights B̂ = B − E: order four exactly, order five not (else the error
        // estimate would vanish to leading order).
        let bhat: Vec<f64> = b.iter().zip(&E).map(|(x, e)| x - e).collect();
        let res = order_residuals(&bhat);
        for (order, group) in res[..4].iter().enumerate() {
            for (t, r) in group.iter().enumerate() {
                assert!(
                    r.abs() < 1e-13,
                    "fourth-order weights, order {} tree {t}: residual {r:e}",
                    order + 1
                );
            }
        }
        assert!(res[4].iter().any(|r| r.abs() > 1e-4), "{:?}", res[4]);
    }
}
