//! The primal–dual interior-point method with a filter line search (Wächter & Biegler 2006).

// Componentwise loops over the variables mirror the paper's formulas, which index several
// vectors (x, l, u, z, d) at once.
#![allow(clippy::needless_range_loop)]

use std::ops::ControlFlow;
use std::time::Instant;

use super::band::BandLdlt;
use super::kkt::{AutoLdlt, FaerLdlt, KktSolver, KktStructure, KktValues};
use super::options::{IterationSummary, LinearSolver, NlpOptions, Verbosity};
use super::problem::NlpProblem;
use super::report::{EvaluationCounts, NlpReport, NlpSolution, PhaseTimes, Status};
use crate::{Error, Result};

// Constants of Wächter & Biegler (2006); the section of each is noted.
/// Sect. 2.1, barrier problem tolerance factor κ_ε.
const KAPPA_EPS: f64 = 10.0;
/// Sect. 2.1, eq. (7): linear decrease factor κ_μ of the barrier parameter.
const KAPPA_MU: f64 = 0.2;
/// Sect. 2.1, eq. (7): superlinear decrease exponent θ_μ.
const THETA_MU: f64 = 1.5;
/// Sect. 2.1, eq. (8): smallest fraction-to-the-boundary parameter τ_min.
const TAU_MIN: f64 = 0.99;
/// Sect. 2.1 (paragraph after eq. (6)): s_max of the scaled optimality error (eq. (5)).
const S_MAX: f64 = 100.0;
/// Sect. 2.2, eq. (16): κ_Σ of the bound-multiplier reset.
const KAPPA_SIGMA: f64 = 1e10;
/// Sect. 2.3: filter margins γ_θ, γ_φ.
const GAMMA_THETA: f64 = 1e-5;
const GAMMA_PHI: f64 = 1e-8;
/// Sect. 2.3, eq. (19): switching-condition constants δ, s_θ, s_φ.
const DELTA_SWITCH: f64 = 1.0;
const S_THETA: f64 = 1.1;
const S_PHI: f64 = 2.3;
/// Sect. 2.3, eq. (20): Armijo constant η_φ.
const ETA_PHI: f64 = 1e-8;
/// Sect. 2.3, eq. (23): safety factor γ_α of the minimum step.
const GAMMA_ALPHA: f64 = 0.05;
/// Sect. 2.4: maximum number of second-order corrections p_max and κ_soc.
const SOC_MAX: usize = 4;
const KAPPA_SOC: f64 = 0.99;
/// Sect. 3.1: inertia-correction constants.
const DELTA_W_0: f64 = 1e-4;
const DELTA_W_MIN: f64 = 1e-20;
const DELTA_W_MAX: f64 = 1e40;
const KAPPA_W_MINUS: f64 = 1.0 / 3.0;
const KAPPA_W_PLUS: f64 = 8.0;
const KAPPA_W_PLUS_BAR: f64 = 100.0;
const DELTA_C_BAR: f64 = 1e-8;
const KAPPA_C: f64 = 0.25;
/// Sect. 3.7: κ_d, damping of variables bounded on one side only.
const KAPPA_D: f64 = 1e-4;
/// Sect. 3.6 (initialisation): κ_1, κ_2 for moving the initial point into the interior.
const KAPPA_1: f64 = 1e-2;
const KAPPA_2: f64 = 1e-2;
/// Sect. 3.6: largest accepted least-squares multiplier estimate.
const Y_MAX_INIT: f64 = 1e3;
/// Sect. 3.8: target gradient size of the automatic scaling.
const G_MAX: f64 = 100.0;
/// Sect. 3.2: consecutive filter rejections of the full step that reset the filter, and the
/// largest number of resets.
const FILTER_RESET_TRIGGER: usize = 5;
const FILTER_RESETS_MAX: usize = 5;
/// Largest number of Levenberg–Marquardt steps of one restoration phase.
const RESTORATION_MAX: usize = 200;

/// The interior-point solver: validated options plus a reusable entry point.
#[derive(Debug)]
pub struct InteriorPoint {
    options: NlpOptions,
}

/// Solves `problem` with `options`; shorthand for
/// `InteriorPoint::try_new(options)?.solve(problem)`.
///
/// # Errors
/// See [`InteriorPoint::solve`].
pub fn solve<P: NlpProblem + ?Sized>(problem: &mut P, options: NlpOptions) -> Result<NlpSolution> {
    InteriorPoint::try_new(options)?.solve(problem)
}

impl InteriorPoint {
    /// Validates the options.
    ///
    /// # Errors
    /// [`Error::InvalidOption`] for an option outside its domain.
    pub fn try_new(options: NlpOptions) -> Result<Self> {
        options.validate()?;
        Ok(Self { options })
    }

    /// The options.
    pub fn options(&self) -> &NlpOptions {
        &self.options
    }

    /// Solves `problem` with the KKT solver chosen by [`NlpOptions::linear_solver`].
    ///
    /// # Errors
    /// Only for misuse: [`Error::DimensionMismatch`] for a pattern index out of range or no
    /// variables, [`Error::InvalidOption`] for `l > u` or a NaN bound, [`Error::NonFinite`]
    /// for a non-finite initial point. Numerical outcomes are in the report's [`Status`].
    pub fn solve<P: NlpProblem + ?Sized>(&mut self, problem: &mut P) -> Result<NlpSolution> {
        match self.options.linear_solver {
            LinearSolver::Auto => self.solve_with(problem, &mut AutoLdlt::new()),
            LinearSolver::Faer => self.solve_with(problem, &mut FaerLdlt::new()),
            LinearSolver::Band => self.solve_with(problem, &mut BandLdlt::new()),
        }
    }

    /// Solves `problem` with a given KKT solver.
    ///
    /// # Errors
    /// As [`solve`](Self::solve).
    pub fn solve_with<P: NlpProblem + ?Sized, K: KktSolver + ?Sized>(
        &mut self,
        problem: &mut P,
        kkt: &mut K,
    ) -> Result<NlpSolution> {
        let start = Instant::now();
        let mut ipm = Ipm::new(problem, kkt, &mut self.options, start)?;
        let status = ipm.run();
        Ok(ipm.finish(status))
    }
}

/// The search direction of one Newton step (scaled problem): (dx, dy) as the KKT solve left
/// them in one vector, and the bound-multiplier steps of the bounded variables only, in the
/// order of [`Ipm::bounded`] (zero for a missing bound).
#[derive(Clone, Debug, Default)]
struct Direction {
    n: usize,
    dxy: Vec<f64>,
    dzl: Vec<f64>,
    dzu: Vec<f64>,
}

impl Direction {
    fn dx(&self) -> &[f64] {
        &self.dxy[..self.n]
    }

    fn dy(&self) -> &[f64] {
        &self.dxy[self.n..]
    }
}

/// An evaluated trial point: (w, f, c), scaled; its ∇f and J values are already in the
/// iterate's arrays ([`Ipm::eval_derivatives`]).
type Trial = (Vec<f64>, f64, Vec<f64>);

enum LineSearch {
    Accepted,
    Failed,
}

/// The iterate's side of the filter line search's tests (eqs. (18)–(21)): θ(x_k) = ‖c(x_k)‖₁,
/// the barrier function φ_μ(x_k) and its directional derivative ∇φ_μ(x_k)ᵀd_x along the step.
#[derive(Debug, Clone, Copy)]
struct LineSearchOrigin {
    theta: f64,
    phi: f64,
    gd: f64,
}

struct Ipm<'a, P: ?Sized, K: ?Sized> {
    problem: &'a mut P,
    kkt: &'a mut K,
    opt: &'a mut NlpOptions,
    start: Instant,
    n: usize,
    m: usize,
    /// The variables with at least one finite bound, ascending: the barrier terms, Σ, the
    /// bound multipliers and their steps are nonzero only there, so the per-iteration loops over
    /// them skip the free variables (all of a transcription's states and noises). The bounds,
    /// their flags and multipliers (`l`, `u`, `has_l`, `has_u`, `zl`, `zu`) are stored for
    /// these variables only, in this order.
    bounded: Vec<usize>,
    l: Vec<f64>,
    u: Vec<f64>,
    has_l: Vec<bool>,
    has_u: Vec<bool>,
    n_bounds: usize,
    /// The Jacobian pattern, (row, column) of each entry, as the problem gave it (kept for the
    /// products with J and the row scaling).
    jac_pat: Vec<(u32, u32)>,
    // scaling (Sect. 3.8)
    sf: f64,
    sc: Vec<f64>,
    // iterate (scaled problem)
    x: Vec<f64>,
    y: Vec<f64>,
    zl: Vec<f64>,
    zu: Vec<f64>,
    f: f64,
    grad: Vec<f64>,
    c: Vec<f64>,
    jac: Vec<f64>,
    /// Hessian values of the last [`Self::eval_hess`] (which runs at the start of every
    /// iteration), or zeros after a factorisation that needs no Hessian (least-squares
    /// multipliers, restoration) zeroed them in place.
    hess: Vec<f64>,
    /// False while `hess` holds those zeros; a Newton factorisation then evaluates the Hessian
    /// first (not reached in the iteration, where an evaluation precedes every step).
    hess_current: bool,
    sigma: Vec<f64>,
    // barrier and filter
    mu: f64,
    tau: f64,
    filter: Vec<(f64, f64)>,
    theta_max: f64,
    theta_min: f64,
    delta_w_last: f64,
    delta_w: f64,
    delta_c: f64,
    // bookkeeping
    iter: usize,
    acceptable_count: usize,
    counts: EvaluationCounts,
    times: PhaseTimes,
    numeric: usize,
    inertia_extra: usize,
    other_factor: usize,
    soc_count: usize,
    restoration_steps: usize,
    non_finite_trials: usize,
    last_alpha: f64,
    last_alpha_z: f64,
    last_step_norm: f64,
    last_trials: usize,
    notes: String,
    tiny_step: bool,
    symbolic: usize,
    max_residual: f64,
    filter_rejections: usize,
    filter_resets: usize,
}

fn norm_inf(v: &[f64]) -> f64 {
    v.iter().fold(0.0f64, |a, &b| a.max(b.abs()))
}

/// Whether every entry is finite: x − x is 0 for finite x and NaN otherwise, summed with four
/// independent accumulators so that the loop vectorises (no early exit: the check is for
/// vectors that are almost always finite).
#[allow(clippy::eq_op)] // x − x is the test
fn all_finite(v: &[f64]) -> bool {
    let chunks = v.chunks_exact(4);
    let tail = chunks.remainder().iter().fold(0.0, |s, &a| s + (a - a));
    let mut acc = [0.0f64; 4];
    for c in chunks {
        for k in 0..4 {
            acc[k] += c[k] - c[k];
        }
    }
    (acc[0] + acc[1]) + (acc[2] + acc[3]) + tail == 0.0
}

fn invalid(name: &str, reason: String) -> Error {
    Error::InvalidOption { name: name.into(), reason }
}

/// The bounds (l, u) of the problem's `n` variables. Errors for a NaN bound, l > u, l = +∞ or
/// u = −∞.
fn checked_bounds<P: NlpProblem + ?Sized>(problem: &P, n: usize) -> Result<(Vec<f64>, Vec<f64>)> {
    let mut l = vec![f64::NEG_INFINITY; n];
    let mut u = vec![f64::INFINITY; n];
    problem.bounds(&mut l, &mut u);
    for i in 0..n {
        if l[i].is_nan() || u[i].is_nan() {
            return Err(invalid("bounds", format!("bound of variable {i} is NaN")));
        }
        if l[i] > u[i] {
            return Err(invalid(
                "bounds",
                format!("lower bound {} > upper bound {} for variable {i}", l[i], u[i]),
            ));
        }
        if l[i] == f64::INFINITY || u[i] == f64::NEG_INFINITY {
            return Err(invalid("bounds", format!("variable {i} has an infinite bound on the wrong side")));
        }
    }
    Ok((l, u))
}

/// The problem's Hessian pattern on `n` variables, each entry (row, column) turned into the
/// lower triangle. Errors for an index out of range.
fn checked_hessian_structure<P: NlpProblem + ?Sized>(problem: &P, n: usize) -> Result<Vec<(u32, u32)>> {
    let mut hess_pat = problem.hessian_structure();
    for p in hess_pat.iter_mut() {
        if p.0 as usize >= n || p.1 as usize >= n {
            return Err(Error::DimensionMismatch {
                what: format!("Hessian pattern entry ({}, {}) index", p.0, p.1),
                expected: n,
                got: p.0.max(p.1) as usize,
            });
        }
        if p.0 < p.1 {
            *p = (p.1, p.0);
        }
    }
    Ok(hess_pat)
}

/// The problem's Jacobian pattern of `m` constraints in `n` variables. Errors for a row or a
/// column out of range.
fn checked_jacobian_structure<P: NlpProblem + ?Sized>(
    problem: &P,
    n: usize,
    m: usize,
) -> Result<Vec<(u32, u32)>> {
    let jac_pat = problem.jacobian_structure();
    for &(r, c) in &jac_pat {
        if r as usize >= m {
            return Err(Error::DimensionMismatch {
                what: format!("Jacobian pattern entry ({r}, {c}) row"),
                expected: m,
                got: r as usize,
            });
        }
        if c as usize >= n {
            return Err(Error::DimensionMismatch {
                what: format!("Jacobian pattern entry ({r}, {c}) column"),
                expected: n,
                got: c as usize,
            });
        }
    }
    Ok(jac_pat)
}

impl<'a, P: NlpProblem + ?Sized, K: KktSolver + ?Sized> Ipm<'a, P, K> {
    fn new(problem: &'a mut P, kkt: &'a mut K, opt: &'a mut NlpOptions, start: Instant) -> Result<Self> {
        let n = problem.num_variables();
        let m = problem.num_constraints();
        if n.max(m) > u32::MAX as usize {
            return Err(invalid("size", format!("{n} variables and {m} constraints: at most 2^32 - 1 each")));
        }
        if n == 0 {
            return Err(Error::DimensionMismatch {
                what: "number of variables (must be positive)".into(),
                expected: 1,
                got: 0,
            });
        }
        let (mut l, mut u) = checked_bounds(&*problem, n)?;
        let mut x = vec![0.0; n];
        problem.initial_point(&mut x);
        if !all_finite(&x) {
            return Err(Error::NonFinite { what: "initial point".into() });
        }
        let hess_pat = checked_hessian_structure(&*problem, n)?;
        let jac_pat = checked_jacobian_structure(&*problem, n, m)?;
        let order = problem.kkt_order();
        if let Some(order) = &order {
            super::kkt::check_order(order, n + m)?;
        }
        kkt.analyse(&KktStructure::new(n, m, &hess_pat, &jac_pat).with_order(order.as_deref()))?;
        // Fixed variables (l = u) have no interior: relax their bounds slightly, as IPOPT's
        // bound relaxation does; the solution then satisfies them to about 1e-8.
        for i in 0..n {
            if l[i] == u[i] {
                let r = 1e-8 * l[i].abs().max(1.0);
                l[i] -= r;
                u[i] += r;
            }
        }
        let bounded: Vec<usize> = (0..n).filter(|&i| l[i].is_finite() || u[i].is_finite()).collect();
        let l: Vec<f64> = bounded.iter().map(|&i| l[i]).collect();
        let u: Vec<f64> = bounded.iter().map(|&i| u[i]).collect();
        let has_l: Vec<bool> = l.iter().map(|v| v.is_finite()).collect();
        let has_u: Vec<bool> = u.iter().map(|v| v.is_finite()).collect();
        let n_bounds = has_l.iter().filter(|&&b| b).count() + has_u.iter().filter(|&&b| b).count();
        // Sect. 3.6: move the initial point strictly inside the bounds.
        for (j, &i) in bounded.iter().enumerate() {
            let (lo, hi) = (l[j], u[j]);
            if has_l[j] && has_u[j] {
                let pl = (KAPPA_1 * lo.abs().max(1.0)).min(KAPPA_2 * (hi - lo));
                let pu = (KAPPA_1 * hi.abs().max(1.0)).min(KAPPA_2 * (hi - lo));
                x[i] = x[i].max(lo + pl).min(hi - pu);
            } else if has_l[j] {
                x[i] = x[i].max(lo + KAPPA_1 * lo.abs().max(1.0));
            } else {
                x[i] = x[i].min(hi - KAPPA_1 * hi.abs().max(1.0));
            }
        }
        let hess_len = hess_pat.len();
        let jac_len = jac_pat.len();
        let zl = has_l.iter().map(|&b| if b { 1.0 } else { 0.0 }).collect();
        let zu = has_u.iter().map(|&b| if b { 1.0 } else { 0.0 }).collect();
        let mu = opt.mu_init;
        let times = PhaseTimes { setup: start.elapsed(), ..PhaseTimes::default() };
        Ok(Self {
            problem,
            kkt,
            start,
            n,
            m,
            l,
            u,
            has_l,
            has_u,
            bounded,
            n_bounds,
            jac_pat,
            sf: 1.0,
            sc: vec![1.0; m],
            x,
            y: vec![0.0; m],
            zl,
            zu,
            f: 0.0,
            grad: vec![0.0; n],
            c: vec![0.0; m],
            jac: vec![0.0; jac_len],
            hess: vec![0.0; hess_len],
            hess_current: false,
            sigma: vec![0.0; n],
            mu,
            tau: TAU_MIN.max(1.0 - mu),
            filter: Vec::new(),
            theta_max: 0.0,
            theta_min: 0.0,
            delta_w_last: 0.0,
            delta_w: 0.0,
            delta_c: 0.0,
            iter: 0,
            acceptable_count: 0,
            counts: EvaluationCounts::default(),
            times,
            numeric: 0,
            inertia_extra: 0,
            other_factor: 0,
            soc_count: 0,
            restoration_steps: 0,
            non_finite_trials: 0,
            last_alpha: 0.0,
            last_alpha_z: 0.0,
            last_step_norm: 0.0,
            last_trials: 0,
            notes: String::new(),
            tiny_step: false,
            symbolic: 1,
            max_residual: 0.0,
            filter_rejections: 0,
            filter_resets: 0,
            opt,
        })
    }

    // ---------------------------------------------------------------- evaluations

    fn eval_f(&mut self, x: &[f64]) -> f64 {
        let t = Instant::now();
        self.counts.objective += 1;
        let v = self.problem.objective(x) * self.sf;
        self.times.evaluation += t.elapsed();
        v
    }

    fn eval_c(&mut self, x: &[f64], out: &mut [f64]) {
        let t = Instant::now();
        self.counts.constraints += 1;
        self.problem.constraints(x, out);
        for (v, s) in out.iter_mut().zip(&self.sc) {
            *v *= s;
        }
        self.times.evaluation += t.elapsed();
    }

    fn eval_grad(&mut self, x: &[f64], out: &mut [f64]) {
        let t = Instant::now();
        self.counts.gradient += 1;
        self.problem.gradient(x, out);
        for v in out.iter_mut() {
            *v *= self.sf;
        }
        self.times.evaluation += t.elapsed();
    }

    fn eval_jac(&mut self, x: &[f64], out: &mut [f64]) {
        let t = Instant::now();
        self.counts.jacobian += 1;
        self.problem.jacobian_values(x, out);
        for (v, &(r, _)) in out.iter_mut().zip(&self.jac_pat) {
            *v *= self.sc[r as usize];
        }
        self.times.evaluation += t.elapsed();
    }

    fn eval_hess(&mut self) -> bool {
        let t = Instant::now();
        self.counts.hessian += 1;
        let lambda: Vec<f64> = self.y.iter().zip(&self.sc).map(|(y, s)| y * s).collect();
        let mut h = std::mem::take(&mut self.hess);
        self.problem.hessian_values(&self.x, self.sf, &lambda, &mut h);
        let ok = all_finite(&h);
        self.hess = h;
        self.hess_current = true;
        self.times.evaluation += t.elapsed();
        ok
    }

    // ---------------------------------------------------------------- measures

    /// θ(x) = ‖c(x)‖₁ (Sect. 2.3).
    fn theta(c: &[f64]) -> f64 {
        c.iter().map(|v| v.abs()).sum()
    }

    /// Barrier function φ_μ(x) (eq. (3)) with the one-sided damping of Sect. 3.7.
    fn phi(&self, f: f64, x: &[f64]) -> f64 {
        let mut b = 0.0;
        for (j, &i) in self.bounded.iter().enumerate() {
            if self.has_l[j] {
                b -= (x[i] - self.l[j]).ln();
                if !self.has_u[j] {
                    b += KAPPA_D * (x[i] - self.l[j]);
                }
            }
            if self.has_u[j] {
                b -= (self.u[j] - x[i]).ln();
                if !self.has_l[j] {
                    b += KAPPA_D * (self.u[j] - x[i]);
                }
            }
        }
        f + self.mu * b
    }

    /// ∇φ_μ at the current point.
    fn grad_phi(&self) -> Vec<f64> {
        let mut g = self.grad.clone();
        for (j, &i) in self.bounded.iter().enumerate() {
            if self.has_l[j] {
                g[i] -= self.mu / (self.x[i] - self.l[j]);
                if !self.has_u[j] {
                    g[i] += KAPPA_D * self.mu;
                }
            }
            if self.has_u[j] {
                g[i] += self.mu / (self.u[j] - self.x[i]);
                if !self.has_l[j] {
                    g[i] -= KAPPA_D * self.mu;
                }
            }
        }
        g
    }

    /// out += Jᵀ v (scaled Jacobian).
    fn jt_times(&self, v: &[f64], out: &mut [f64]) {
        for (&a, &(r, c)) in self.jac.iter().zip(&self.jac_pat) {
            out[c as usize] += a * v[r as usize];
        }
    }

    /// ∇f + Jᵀy − z_L + z_U (scaled).
    fn dual_residual(&self) -> Vec<f64> {
        let mut r = self.grad.clone();
        self.jt_times(&self.y, &mut r);
        for (j, &i) in self.bounded.iter().enumerate() {
            r[i] += self.zu[j] - self.zl[j];
        }
        r
    }

    /// Scaled optimality error E_μ (eq. (5)).
    fn optimality_error(&self, mu: f64) -> f64 {
        self.optimality_error_with(mu, norm_inf(&self.dual_residual()))
    }

    /// [`Self::optimality_error`] given ‖∇f + Jᵀy − z_L + z_U‖∞ (scaled) at the current point,
    /// which does not depend on μ.
    fn optimality_error_with(&self, mu: f64, dual: f64) -> f64 {
        let primal = norm_inf(&self.c);
        let mut compl = 0.0f64;
        let mut z1 = 0.0;
        for (j, &i) in self.bounded.iter().enumerate() {
            if self.has_l[j] {
                compl = compl.max((self.zl[j] * (self.x[i] - self.l[j]) - mu).abs());
                z1 += self.zl[j].abs();
            }
            if self.has_u[j] {
                compl = compl.max((self.zu[j] * (self.u[j] - self.x[i]) - mu).abs());
                z1 += self.zu[j].abs();
            }
        }
        let y1: f64 = self.y.iter().map(|v| v.abs()).sum();
        let nm = self.m + self.n_bounds;
        let s_d = if nm > 0 { S_MAX.max((y1 + z1) / nm as f64) / S_MAX } else { 1.0 };
        let s_c = if self.n_bounds > 0 { S_MAX.max(z1 / self.n_bounds as f64) / S_MAX } else { 1.0 };
        (dual / s_d).max(primal).max(compl / s_c)
    }

    fn unscaled_primal(&self) -> f64 {
        self.c.iter().zip(&self.sc).fold(0.0f64, |a, (c, s)| a.max((c / s).abs()))
    }

    fn unscaled_dual(&self) -> f64 {
        norm_inf(&self.dual_residual()) / self.sf
    }

    fn unscaled_compl(&self) -> f64 {
        let mut v = 0.0f64;
        for (j, &i) in self.bounded.iter().enumerate() {
            if self.has_l[j] {
                v = v.max(self.zl[j] * (self.x[i] - self.l[j]));
            }
            if self.has_u[j] {
                v = v.max(self.zu[j] * (self.u[j] - self.x[i]));
            }
        }
        v / self.sf
    }

    fn timed_out(&self) -> bool {
        self.opt.time_limit.is_some_and(|limit| self.start.elapsed() >= limit)
    }

    fn note(&mut self, s: impl FnOnce() -> String) {
        if self.opt.verbosity == Verbosity::Detailed {
            if !self.notes.is_empty() {
                self.notes.push_str("; ");
            }
            self.notes.push_str(&s());
        }
    }

    // ---------------------------------------------------------------- linear algebra

    /// Factorises the KKT matrix with the current Jacobian, the Hessian at the current iterate
    /// or (`zero_hessian`) a zero Hessian, the primal diagonal and the regularisations.
    fn factor(
        &mut self,
        zero_hessian: bool,
        primal_diag: &[f64],
        dw: f64,
        dc: f64,
    ) -> Option<super::kkt::FactorInfo> {
        let t = Instant::now();
        if zero_hessian {
            self.hess.fill(0.0);
            self.hess_current = false;
        } else if !self.hess_current && !self.eval_hess() {
            // not reached: every Newton factorisation follows a Hessian evaluation
            return None;
        }
        let info = self.kkt.factorize(&KktValues {
            hessian: &self.hess,
            jacobian: &self.jac,
            primal_diagonal: primal_diag,
            delta_w: dw,
            delta_c: dc,
        });
        self.times.factorization += t.elapsed();
        info
    }

    fn kkt_solve(&mut self, rhs: &mut [f64]) -> f64 {
        let t = Instant::now();
        let r = self.kkt.solve_in_place(rhs);
        self.times.solve += t.elapsed();
        r
    }

    /// Least-squares multiplier estimate (Sect. 3.6): solves
    /// [I Jᵀ; J 0][w; y] = [−(∇f − z_L + z_U); 0].
    fn least_squares_multipliers(&mut self) {
        if self.m == 0 {
            return;
        }
        let ones = vec![1.0; self.n];
        self.other_factor += 1;
        let ok = self.factor(true, &ones, 0.0, 1e-12).is_some_and(|i| i.regularized_pivots == 0);
        if !ok {
            self.y.fill(0.0);
            return;
        }
        let mut rhs = vec![0.0; self.n + self.m];
        for (r, g) in rhs.iter_mut().zip(&self.grad) {
            *r = -g;
        }
        for (j, &i) in self.bounded.iter().enumerate() {
            rhs[i] = -(self.grad[i] - self.zl[j] + self.zu[j]);
        }
        self.kkt_solve(&mut rhs);
        let y = &rhs[self.n..];
        if all_finite(y) && norm_inf(y) <= Y_MAX_INIT {
            self.y.copy_from_slice(y);
        } else {
            self.y.fill(0.0);
        }
    }

    /// Σ = X_L⁻¹ Z_L + X_U⁻¹ Z_U.
    fn update_sigma(&mut self) {
        for (j, &i) in self.bounded.iter().enumerate() {
            let mut s = 0.0;
            if self.has_l[j] {
                s += self.zl[j] / (self.x[i] - self.l[j]);
            }
            if self.has_u[j] {
                s += self.zu[j] / (self.u[j] - self.x[i]);
            }
            self.sigma[i] = s;
        }
    }

    /// Factorises the KKT matrix with inertia correction (Sect. 3.1, Algorithm IC) and
    /// computes the Newton direction for the residuals (r_x, r_c). Returns `None` if no
    /// regularisation gives a usable factorisation.
    ///
    /// A factorisation is usable when its inertia is (n, m, 0). If faer had to replace
    /// numerically zero pivots (which happens without pivoting even for nonsingular
    /// matrices, e.g. a variable with no curvature eliminated before its constraint), the
    /// inertia is uncertain: the factorisation is kept only if iterative refinement against
    /// the assembled matrix reaches a backward error of 1e-10, otherwise the matrix is
    /// treated as singular (δ_c > 0) and δ_w is increased.
    fn direction_with_inertia_correction(&mut self, rx: &[f64], rc: &[f64]) -> Option<Direction> {
        self.update_sigma();
        let sigma = std::mem::take(&mut self.sigma);
        let (n, m) = (self.n, self.m);
        let mut dw = 0.0;
        let mut dc = 0.0;
        let mut first = true;
        let mut result = None;
        loop {
            if first {
                self.numeric += 1;
            } else {
                self.inertia_extra += 1;
            }
            let info = self.factor(false, &sigma, dw, dc);
            let inertia_ok = info
                .is_some_and(|i| i.inertia.positive == n && i.inertia.negative == m && i.inertia.zero == 0);
            let regularized = info.is_some_and(|i| i.regularized_pivots > 0);
            let mut singular =
                info.is_none() || info.is_some_and(|i| i.inertia.zero > 0 || i.inertia.negative < m);
            if inertia_ok {
                let (dir, residual) = self.direction_from_rhs(rx, rc);
                match dir {
                    Some(d) if !regularized || residual <= 1e-8 => {
                        self.max_residual = self.max_residual.max(residual);
                        result = Some(d);
                        break;
                    }
                    _ => singular = true,
                }
            } else if regularized {
                singular = true;
            }
            if first {
                // IC-2 / IC-3
                first = false;
                if singular && m > 0 {
                    dc = DELTA_C_BAR * self.mu.powf(KAPPA_C);
                }
                dw = if self.delta_w_last == 0.0 {
                    DELTA_W_0
                } else {
                    DELTA_W_MIN.max(KAPPA_W_MINUS * self.delta_w_last)
                };
            } else {
                // IC-5
                dw *= if self.delta_w_last == 0.0 { KAPPA_W_PLUS_BAR } else { KAPPA_W_PLUS };
                // IC-6
                if dw > DELTA_W_MAX {
                    break;
                }
            }
        }
        if result.is_some() && dw > 0.0 {
            self.delta_w_last = dw;
            self.note(|| format!("inertia correction dw={dw:.1e} dc={dc:.1e}"));
        }
        self.sigma = sigma;
        self.delta_w = dw;
        self.delta_c = dc;
        result
    }

    /// Solves for the step given the primal-dual rhs (−r_x, −r_c) with the current factors
    /// and recovers the bound-multiplier steps (Sect. 2.2 / 3.4).
    fn direction_from_rhs(&mut self, rx: &[f64], rc: &[f64]) -> (Option<Direction>, f64) {
        let (n, m) = (self.n, self.m);
        let mut rhs = Vec::with_capacity(n + m);
        rhs.extend(rx.iter().map(|v| -v));
        rhs.extend(rc.iter().map(|v| -v));
        let residual = self.kkt_solve(&mut rhs);
        if !all_finite(&rhs) {
            return (None, residual);
        }
        let (dzl, dzu) = self.bound_steps(&rhs[..n]);
        (Some(Direction { n, dxy: rhs, dzl, dzu }), residual)
    }

    /// The bound-multiplier steps (eq. (11)) of the bounded variables, in the order of
    /// [`Self::bounded`].
    fn bound_steps(&self, dx: &[f64]) -> (Vec<f64>, Vec<f64>) {
        let nb = self.bounded.len();
        let mut dzl = vec![0.0; nb];
        let mut dzu = vec![0.0; nb];
        for (j, &i) in self.bounded.iter().enumerate() {
            if self.has_l[j] {
                let s = self.x[i] - self.l[j];
                dzl[j] = (self.mu - self.zl[j] * s - self.zl[j] * dx[i]) / s;
            }
            if self.has_u[j] {
                let s = self.u[j] - self.x[i];
                dzu[j] = (self.mu - self.zu[j] * s + self.zu[j] * dx[i]) / s;
            }
        }
        (dzl, dzu)
    }

    /// Largest α ≤ 1 keeping x + α dx at least a fraction (1 − τ) inside the bounds (eq. (15)).
    fn max_step_primal(&self, x: &[f64], dx: &[f64], tau: f64) -> f64 {
        let mut a = 1.0f64;
        for (j, &i) in self.bounded.iter().enumerate() {
            if self.has_l[j] && dx[i] < 0.0 {
                a = a.min(-tau * (x[i] - self.l[j]) / dx[i]);
            }
            if self.has_u[j] && dx[i] > 0.0 {
                a = a.min(tau * (self.u[j] - x[i]) / dx[i]);
            }
        }
        a
    }

    fn max_step_dual(&self, dzl: &[f64], dzu: &[f64]) -> f64 {
        let mut a = 1.0f64;
        for j in 0..self.bounded.len() {
            if self.has_l[j] && dzl[j] < 0.0 {
                a = a.min(-self.tau * self.zl[j] / dzl[j]);
            }
            if self.has_u[j] && dzu[j] < 0.0 {
                a = a.min(-self.tau * self.zu[j] / dzu[j]);
            }
        }
        a
    }

    fn filter_acceptable(&self, theta: f64, phi: f64) -> bool {
        theta <= self.theta_max && self.filter.iter().all(|&(tf, pf)| theta < tf || phi < pf)
    }

    fn augment_filter(&mut self, theta: f64, phi: f64) {
        let entry = ((1.0 - GAMMA_THETA) * theta, phi - GAMMA_PHI * theta);
        // drop dominated entries
        self.filter.retain(|&(tf, pf)| !(tf >= entry.0 && pf >= entry.1));
        self.filter.push(entry);
    }

    // ---------------------------------------------------------------- main loop

    fn initialize(&mut self) -> Option<Status> {
        let x = std::mem::take(&mut self.x);
        let status = self.evaluate_start(&x);
        self.x = x;
        if status.is_some() {
            return status;
        }
        let theta0 = Self::theta(&self.c);
        self.theta_max = 1e4 * theta0.max(1.0);
        self.theta_min = 1e-4 * theta0.max(1.0);
        self.least_squares_multipliers();
        None
    }

    /// f, ∇f, c and J at the starting point `x`, into the iterate's arrays, and the scaling
    /// (Sect. 3.8) they determine.
    fn evaluate_start(&mut self, x: &[f64]) -> Option<Status> {
        // the scaling is 1 until set below
        let mut g = std::mem::take(&mut self.grad);
        self.eval_grad(x, &mut g);
        self.grad = g;
        let mut jac = std::mem::take(&mut self.jac);
        self.eval_jac(x, &mut jac);
        self.jac = jac;
        if !all_finite(&self.grad) || !all_finite(&self.jac) {
            return Some(Status::EvaluationError);
        }
        // Sect. 3.8: gradient-based scaling
        if self.opt.scaling {
            let gmax = norm_inf(&self.grad);
            self.sf = if gmax > G_MAX { G_MAX / gmax } else { 1.0 };
            let mut row_max = vec![0.0f64; self.m];
            for (&(r, _), v) in self.jac_pat.iter().zip(&self.jac) {
                let r = r as usize;
                row_max[r] = row_max[r].max(v.abs());
            }
            for r in 0..self.m {
                self.sc[r] = if row_max[r] > G_MAX { G_MAX / row_max[r] } else { 1.0 };
            }
        }
        for v in self.grad.iter_mut() {
            *v *= self.sf;
        }
        for (v, &(r, _)) in self.jac.iter_mut().zip(&self.jac_pat) {
            *v *= self.sc[r as usize];
        }
        self.f = self.eval_f(x);
        let mut c = std::mem::take(&mut self.c);
        self.eval_c(x, &mut c);
        self.c = c;
        if !self.f.is_finite() || !all_finite(&self.c) {
            return Some(Status::EvaluationError);
        }
        None
    }

    fn run(&mut self) -> Status {
        if let Some(s) = self.initialize() {
            return s;
        }
        loop {
            // convergence test (Sect. 2.1)
            let residual = self.dual_residual();
            let dual = norm_inf(&residual);
            let e0 = self.optimality_error_with(0.0, dual);
            let primal_unscaled = self.unscaled_primal();
            let f_unscaled = self.f / self.sf;
            if self.callback() {
                return Status::UserStop;
            }
            if e0 <= self.opt.tolerance
                && primal_unscaled <= self.opt.constraint_tolerance
                && dual / self.sf <= 1.0
            {
                return Status::Converged;
            }
            if e0 <= self.opt.acceptable_tolerance {
                self.acceptable_count += 1;
                if self.acceptable_count >= self.opt.acceptable_iterations {
                    return Status::Acceptable;
                }
            } else {
                self.acceptable_count = 0;
            }
            if f_unscaled < self.opt.unbounded_objective && primal_unscaled <= self.opt.constraint_tolerance {
                return Status::Unbounded;
            }
            if self.iter >= self.opt.max_iterations {
                return Status::MaxIterations;
            }
            if self.timed_out() {
                return Status::TimeLimit;
            }
            // barrier update (Sect. 2.1, eqs. (7)-(8)), repeated while the barrier problem is
            // already solved
            let mu_min = self.opt.tolerance / 10.0;
            while (self.optimality_error_with(self.mu, dual) <= KAPPA_EPS * self.mu || self.tiny_step)
                && self.mu > mu_min
            {
                self.tiny_step = false;
                self.mu = mu_min.max((KAPPA_MU * self.mu).min(self.mu.powf(THETA_MU)));
                self.tau = TAU_MIN.max(1.0 - self.mu);
                self.filter.clear();
                let mu = self.mu;
                self.note(|| format!("mu -> {mu:.2e}"));
            }
            if self.tiny_step {
                // tiny step with μ already minimal: nothing more can be gained
                return if e0 <= self.opt.acceptable_tolerance {
                    Status::Acceptable
                } else {
                    Status::NumericalFailure
                };
            }
            self.iter += 1;
            self.notes.clear();
            if !self.eval_hess() {
                return Status::EvaluationError;
            }
            let status = self.step(residual).err();
            if let Some(s) = status {
                return s;
            }
        }
    }

    /// One iteration: direction, line search (or restoration), update. `dual_residual` is
    /// ∇f + Jᵀy − z_L + z_U at the iterate ([`Self::dual_residual`]).
    fn step(&mut self, dual_residual: Vec<f64>) -> std::result::Result<(), Status> {
        let gphi = self.grad_phi();
        // r_x = ∇φ_μ + Jᵀy, which without bounds is the dual residual, entry for entry
        let rx = if self.bounded.is_empty() {
            dual_residual
        } else {
            let mut rx = gphi.clone();
            self.jt_times(&self.y, &mut rx);
            rx
        };
        let rc = self.c.clone();
        let dir = self.direction_with_inertia_correction(&rx, &rc);
        let Some(dir) = dir else {
            self.note(|| "no usable direction; restoration".into());
            return self.restore();
        };
        self.last_step_norm = norm_inf(dir.dx());
        // Sect. 3.9: tiny steps
        let tiny =
            dir.dx().iter().zip(&self.x).all(|(d, x)| d.abs() <= 10.0 * f64::EPSILON * (1.0 + x.abs()));
        if tiny {
            self.tiny_step = true;
            let alpha = self.max_step_primal(&self.x, dir.dx(), self.tau);
            self.accept(&dir, alpha, None)?;
            return Ok(());
        }
        match self.line_search(&dir, &gphi, &rx)? {
            LineSearch::Accepted => Ok(()),
            LineSearch::Failed => self.restore(),
        }
    }

    /// Applies a step: x += α dx (or the given trial point), y += α dy, z += α_z dz, then the
    /// bound-multiplier reset (eq. (16)).
    fn accept(
        &mut self,
        dir: &Direction,
        alpha: f64,
        trial: Option<Trial>,
    ) -> std::result::Result<(), Status> {
        let alpha_z = self.max_step_dual(&dir.dzl, &dir.dzu);
        match trial {
            Some((x, f, c)) => {
                self.x = x;
                self.f = f;
                self.c = c;
            }
            None => {
                for (x, dx) in self.x.iter_mut().zip(dir.dx()) {
                    *x += alpha * dx;
                }
                let x = self.x.clone();
                self.f = self.eval_f(&x);
                let mut c = vec![0.0; self.m];
                self.eval_c(&x, &mut c);
                self.c = c;
                self.eval_derivatives_into_iterate(&x);
                if !self.f.is_finite()
                    || !all_finite(&self.c)
                    || !all_finite(&self.grad)
                    || !all_finite(&self.jac)
                {
                    return Err(Status::EvaluationError);
                }
            }
        }
        for (y, dy) in self.y.iter_mut().zip(dir.dy()) {
            *y += alpha * dy;
        }
        for j in 0..self.bounded.len() {
            if self.has_l[j] {
                self.zl[j] += alpha_z * dir.dzl[j];
            }
            if self.has_u[j] {
                self.zu[j] += alpha_z * dir.dzu[j];
            }
        }
        self.reset_bound_multipliers();
        self.last_alpha = alpha;
        self.last_alpha_z = alpha_z;
        Ok(())
    }

    /// Eq. (16): keep Σ within a factor κ_Σ of μ X⁻². Before that, bounds whose slack has
    /// fallen below ε_mach μ are moved out by ε_mach^{3/4} max(1, |bound|), so that slacks never
    /// vanish in floating point (Sect. 3.5).
    fn reset_bound_multipliers(&mut self) {
        let tiny = f64::EPSILON * self.mu;
        let shift = f64::EPSILON.powf(0.75);
        for (j, &i) in self.bounded.iter().enumerate() {
            if self.has_l[j] && self.x[i] - self.l[j] < tiny {
                self.l[j] -= shift * self.l[j].abs().max(1.0);
            }
            if self.has_u[j] && self.u[j] - self.x[i] < tiny {
                self.u[j] += shift * self.u[j].abs().max(1.0);
            }
        }
        for (j, &i) in self.bounded.iter().enumerate() {
            if self.has_l[j] {
                let s = self.x[i] - self.l[j];
                self.zl[j] = self.zl[j].min(KAPPA_SIGMA * self.mu / s).max(self.mu / (KAPPA_SIGMA * s));
            }
            if self.has_u[j] {
                let s = self.u[j] - self.x[i];
                self.zu[j] = self.zu[j].min(KAPPA_SIGMA * self.mu / s).max(self.mu / (KAPPA_SIGMA * s));
            }
        }
    }

    /// Evaluates f and c at a trial point; None if non-finite.
    fn eval_trial(&mut self, x: &[f64]) -> Option<(f64, Vec<f64>)> {
        let f = self.eval_f(x);
        let mut c = vec![0.0; self.m];
        self.eval_c(x, &mut c);
        if f.is_finite() && all_finite(&c) {
            Some((f, c))
        } else {
            self.non_finite_trials += 1;
            None
        }
    }

    /// ∇f and the Jacobian values at `x` into the iterate's arrays, which the problem
    /// overwrites ([`NlpProblem::gradient`], [`NlpProblem::jacobian_values`]).
    fn eval_derivatives_into_iterate(&mut self, x: &[f64]) {
        let mut g = std::mem::take(&mut self.grad);
        let mut j = std::mem::take(&mut self.jac);
        self.eval_grad(x, &mut g);
        self.eval_jac(x, &mut j);
        self.grad = g;
        self.jac = j;
    }

    /// ∇f and the Jacobian values at the trial point `x`, written over the iterate's: true when
    /// they are finite. Otherwise (rare: f and c were finite there) those of the iterate are
    /// evaluated again, so that the arrays still hold them, and false is returned. One pair of
    /// arrays instead of a spare pair for the trial point: on Duffing with 36,000 pieces a spare
    /// Jacobian is 13 MB, whose pages every fresh solve faults in.
    fn eval_derivatives(&mut self, x: &[f64]) -> bool {
        self.eval_derivatives_into_iterate(x);
        if all_finite(&self.grad) && all_finite(&self.jac) {
            return true;
        }
        self.non_finite_trials += 1;
        let current = std::mem::take(&mut self.x);
        self.eval_derivatives_into_iterate(&current);
        self.x = current;
        false
    }

    /// Filter line search with second-order corrections (Sects. 2.3–2.4, Algorithm A steps
    ///
    fn line_search(
        &mut self,
        dir: &Direction,
        gphi: &[f64],
        rx: &[f64],
    ) -> std::result::Result<LineSearch, Status> {
        let theta = Self::theta(&self.c);
        let phi = self.phi(self.f, &self.x);
        if !phi.is_finite() {
            return Ok(LineSearch::Failed);
        }
        let gd: f64 = gphi.iter().zip(dir.dx()).map(|(a, b)| a * b).sum();
        let origin = LineSearchOrigin { theta, phi, gd };
        let alpha_max = self.max_step_primal(&self.x, dir.dx(), self.tau);
        // eq. (23): minimum step
        let alpha_min = GAMMA_ALPHA
            * if gd < 0.0 {
                if theta <= self.theta_min {
                    GAMMA_THETA
                        .min(GAMMA_PHI * theta / -gd)
                        .min(DELTA_SWITCH * theta.powf(S_THETA) / (-gd).powf(S_PHI))
                } else {
                    GAMMA_THETA.min(GAMMA_PHI * theta / -gd)
                }
            } else {
                GAMMA_THETA
            };
        let mut alpha = alpha_max;
        let mut trials = 0usize;
        let mut x_trial = vec![0.0; self.n];
        loop {
            // the step has become negligible: x + α d_x would not move x
            let negligible = dir
                .dx()
                .iter()
                .zip(&self.x)
                .all(|(d, x)| (alpha * d).abs() <= 10.0 * f64::EPSILON * (1.0 + x.abs()));
            if (alpha < alpha_min || negligible) && trials > 0 {
                self.last_trials = trials;
                return Ok(LineSearch::Failed);
            }
            trials += 1;
            for ((xt, x), d) in x_trial.iter_mut().zip(&self.x).zip(dir.dx()) {
                *xt = x + alpha * d;
            }
            let Some((f_t, c_t)) = self.eval_trial(&x_trial) else {
                alpha *= 0.5;
                continue;
            };
            let theta_t = Self::theta(&c_t);
            let phi_t = self.phi(f_t, &x_trial);
            if trials == 1 {
                // Sect. 3.2, Case I: a filter that keeps rejecting full steps is reset
                if self.filter_acceptable(theta_t, phi_t) {
                    self.filter_rejections = 0;
                } else {
                    self.filter_rejections += 1;
                    if self.filter_rejections >= FILTER_RESET_TRIGGER
                        && self.filter_resets < FILTER_RESETS_MAX
                    {
                        self.filter.clear();
                        self.filter_resets += 1;
                        self.filter_rejections = 0;
                        self.note(|| "filter reset".into());
                    }
                }
            }
            let verdict = self.acceptance(origin, alpha, theta_t, phi_t);
            if let Some(f_type) = verdict {
                if self.eval_derivatives(&x_trial) {
                    if !f_type {
                        self.augment_filter(theta, phi);
                    }
                    self.last_trials = trials;
                    self.accept(dir, alpha, Some((x_trial, f_t, c_t)))?;
                    return Ok(LineSearch::Accepted);
                }
                alpha *= 0.5;
                continue;
            }
            // Sect. 2.4: second-order correction on the first trial
            if trials == 1 && theta_t >= theta && self.m > 0 {
                if let Some(done) = self.second_order_correction(rx, alpha, &c_t, origin, alpha_max)? {
                    self.last_trials = trials;
                    return Ok(done);
                }
            }
            alpha *= 0.5;
            if self.timed_out() {
                return Err(Status::TimeLimit);
            }
        }
    }

    /// Acceptance test of a trial point (eqs. (18)–(21)) at step `alpha` from `origin`:
    /// Some(true) for an f-type (Armijo) acceptance, Some(false) for a θ-type acceptance, None if
    /// rejected.
    fn acceptance(&self, origin: LineSearchOrigin, alpha: f64, theta_t: f64, phi_t: f64) -> Option<bool> {
        let LineSearchOrigin { theta, phi, gd } = origin;
        if !self.filter_acceptable(theta_t, phi_t) {
            return None;
        }
        let switching = gd < 0.0 && alpha * (-gd).powf(S_PHI) > DELTA_SWITCH * theta.powf(S_THETA);
        if theta <= self.theta_min && switching {
            // Armijo (20)
            let slack = 10.0 * f64::EPSILON * phi.abs().max(1.0);
            if phi_t <= phi + ETA_PHI * alpha * gd + slack {
                Some(true)
            } else {
                None
            }
        } else if theta_t <= (1.0 - GAMMA_THETA) * theta || phi_t <= phi - GAMMA_PHI * theta {
            Some(false)
        } else {
            None
        }
    }

    /// Second-order corrections (Sect. 2.4) after the first trial step `alpha0` was rejected with
    /// constraint values `c_trial`: each corrected step (from the primal right-hand side `rx`)
    /// is tested for acceptance from `origin` with α = `alpha_max`. `Some(LineSearch::Accepted)`
    /// when one is accepted, `None` otherwise.
    fn second_order_correction(
        &mut self,
        rx: &[f64],
        alpha0: f64,
        c_trial: &[f64],
        origin: LineSearchOrigin,
        alpha_max: f64,
    ) -> std::result::Result<Option<LineSearch>, Status> {
        let LineSearchOrigin { theta, phi, .. } = origin;
        let mut c_soc: Vec<f64> = self.c.iter().zip(c_trial).map(|(c0, ct)| alpha0 * c0 + ct).collect();
        let mut theta_old = Self::theta(c_trial);
        for _ in 0..SOC_MAX {
            self.soc_count += 1;
            let Some(soc) = self.direction_from_rhs(rx, &c_soc).0 else {
                return Ok(None);
            };
            let a_soc = self.max_step_primal(&self.x, soc.dx(), self.tau);
            let x_soc: Vec<f64> = self.x.iter().zip(soc.dx()).map(|(x, d)| x + a_soc * d).collect();
            let Some((f_s, c_s)) = self.eval_trial(&x_soc) else {
                return Ok(None);
            };
            let theta_s = Self::theta(&c_s);
            let phi_s = self.phi(f_s, &x_soc);
            if let Some(f_type) = self.acceptance(origin, alpha_max, theta_s, phi_s) {
                if !self.eval_derivatives(&x_soc) {
                    return Ok(None);
                }
                if !f_type {
                    self.augment_filter(theta, phi);
                }
                self.note(|| "second-order correction accepted".into());
                self.accept(&soc, a_soc, Some((x_soc, f_s, c_s)))?;
                return Ok(Some(LineSearch::Accepted));
            }
            if theta_s > KAPPA_SOC * theta_old {
                break;
            }
            theta_old = theta_s;
            for (cs, c) in c_soc.iter_mut().zip(&c_s) {
                *cs = a_soc * *cs + c;
            }
        }
        Ok(None)
    }

    /// Simplified feasibility restoration (in place of Sect. 3.3): Levenberg–Marquardt steps
    /// on ½‖c(w)‖² in the interior of the bounds, until the point is acceptable to the filter
    /// with θ reduced by 10 %. Declares the problem infeasible when the violation cannot be
    /// reduced and the projected gradient of ½‖c‖² vanishes.
    fn restore(&mut self) -> std::result::Result<(), Status> {
        if self.m == 0 || self.unscaled_primal() <= self.opt.constraint_tolerance {
            // nothing to restore: the line search failed at a (nearly) feasible point
            return Err(self.stalled_status());
        }
        let theta0 = Self::theta(&self.c);
        let phi0 = self.phi(self.f, &self.x);
        self.augment_filter(theta0, phi0);
        let mut rho = 1e-4 * norm_inf(&self.c).clamp(1e-8, 1.0);
        for _ in 0..RESTORATION_MAX {
            if self.timed_out() {
                return Err(Status::TimeLimit);
            }
            let theta = Self::theta(&self.c);
            let phi = self.phi(self.f, &self.x);
            if theta <= 0.9 * theta0 && self.filter_acceptable(theta, phi) {
                self.after_restoration();
                return Ok(());
            }
            if self.infeasibility_stationary() {
                return Err(Status::Infeasible);
            }
            self.update_sigma();
            let diag: Vec<f64> = self.sigma.iter().map(|s| s + rho).collect();
            self.other_factor += 1;
            let info = self.factor(true, &diag, 0.0, 1.0);
            if info.is_none() {
                return Err(self.stalled_status());
            }
            let mut rhs = vec![0.0; self.n + self.m];
            for r in 0..self.m {
                rhs[self.n + r] = -self.c[r];
            }
            self.kkt_solve(&mut rhs);
            if !all_finite(&rhs) {
                return Err(self.stalled_status());
            }
            let d = rhs[..self.n].to_vec();
            let a = self.max_step_primal(&self.x, &d, self.tau);
            // predicted decrease of ½‖c‖²: ½‖c‖² − ½‖c + a J d‖²
            let mut jd = vec![0.0; self.m];
            for k in 0..self.jac.len() {
                let (r, c) = self.jac_pat[k];
                jd[r as usize] += self.jac[k] * d[c as usize];
            }
            let c2: f64 = self.c.iter().map(|v| v * v).sum::<f64>() * 0.5;
            let pred = c2 - 0.5 * self.c.iter().zip(&jd).map(|(c, j)| (c + a * j).powi(2)).sum::<f64>();
            let x_t: Vec<f64> = (0..self.n).map(|i| self.x[i] + a * d[i]).collect();
            let trial = self.eval_trial(&x_t);
            let ared = trial.as_ref().map(|(_, c)| c2 - 0.5 * c.iter().map(|v| v * v).sum::<f64>());
            match (trial, ared) {
                (Some((f_t, c_t)), Some(ared)) if pred > 0.0 && ared >= 1e-4 * pred => {
                    if !self.eval_derivatives(&x_t) {
                        rho *= 10.0;
                        continue;
                    }
                    self.restoration_steps += 1;
                    self.x = x_t;
                    self.f = f_t;
                    self.c = c_t;
                    self.reset_bound_multipliers();
                    if ared >= 0.75 * pred {
                        rho = (rho / 3.0).max(1e-12);
                    } else if ared < 0.25 * pred {
                        rho *= 4.0;
                    }
                }
                _ => {
                    rho *= 10.0;
                    if rho > 1e20 {
                        return Err(if self.infeasibility_stationary_loose() {
                            Status::Infeasible
                        } else {
                            self.stalled_status()
                        });
                    }
                }
            }
        }
        Err(self.stalled_status())
    }

    fn after_restoration(&mut self) {
        self.note(|| "restoration succeeded".into());
        self.reset_bound_multipliers();
        self.least_squares_multipliers();
        self.delta_w_last = 0.0;
    }

    /// ‖w − P[w − Jᵀc]‖∞ relative to ‖c‖∞: the projected gradient of ½‖c‖².
    fn projected_infeasibility_gradient(&self) -> f64 {
        let mut g = vec![0.0; self.n];
        self.jt_times(&self.c, &mut g);
        let mut pg = 0.0f64;
        let mut bounds = self.bounded.iter().zip(self.l.iter().zip(&self.u)).peekable();
        for i in 0..self.n {
            let mut p = self.x[i] - g[i];
            if let Some((_, (&l, &u))) = bounds.next_if(|&(&b, _)| b == i) {
                p = p.max(l).min(u);
            }
            pg = pg.max((self.x[i] - p).abs());
        }
        pg / norm_inf(&self.c).max(f64::MIN_POSITIVE)
    }

    fn infeasibility_stationary(&self) -> bool {
        self.unscaled_primal() > self.opt.constraint_tolerance
            && self.projected_infeasibility_gradient() <= 1e-6
    }

    fn infeasibility_stationary_loose(&self) -> bool {
        self.unscaled_primal() > self.opt.constraint_tolerance
            && self.projected_infeasibility_gradient() <= 1e-3
    }

    fn stalled_status(&self) -> Status {
        if self.optimality_error(0.0) <= self.opt.acceptable_tolerance {
            Status::Acceptable
        } else {
            Status::NumericalFailure
        }
    }

    /// Calls the user callback; true if it asks to stop.
    fn callback(&mut self) -> bool {
        crate::estimate::progress::emit(crate::estimate::progress::ProgressEvent::Iteration {
            iteration: self.iter,
            merit: self.f / self.sf,
        });
        if self.opt.callback.is_none() {
            return false;
        }
        let summary = IterationSummary {
            iteration: self.iter,
            objective: self.f / self.sf,
            primal_infeasibility: self.unscaled_primal(),
            dual_infeasibility: norm_inf(&self.dual_residual()),
            mu: self.mu,
            step_norm: if self.iter == 0 { 0.0 } else { self.last_step_norm },
            delta_w: self.delta_w,
            alpha_primal: self.last_alpha,
            alpha_dual: self.last_alpha_z,
            line_search_trials: self.last_trials,
            log: match self.opt.verbosity {
                Verbosity::Quiet => None,
                v => {
                    let mut s = String::new();
                    if self.iter == 0 {
                        s += &format!(
                            "{:>5} {:>16} {:>9} {:>9} {:>6} {:>9} {:>9} {:>9} {:>3}\n",
                            "iter",
                            "objective",
                            "inf_pr",
                            "inf_du",
                            "lg(mu)",
                            "||d||",
                            "delta_w",
                            "alpha",
                            "ls"
                        );
                    }
                    s += &format!(
                        "{:5} {:+16.8e} {:9.2e} {:9.2e} {:6.1} {:9.2e} {:9.2e} {:9.2e} {:3}",
                        self.iter,
                        self.f / self.sf,
                        self.unscaled_primal(),
                        norm_inf(&self.dual_residual()),
                        self.mu.log10(),
                        self.last_step_norm,
                        self.delta_w,
                        self.last_alpha,
                        self.last_trials
                    );
                    if v == Verbosity::Detailed && !self.notes.is_empty() {
                        s.push_str("  ");
                        s.push_str(&self.notes);
                    }
                    Some(s)
                }
            },
        };
        let cb = self.opt.callback.as_mut().expect("checked above");
        matches!(cb(&summary), ControlFlow::Break(()))
    }

    /// The unscaled bound multipliers `z` (stored for the bounded variables) as a vector over
    /// all variables, zero for the free ones.
    fn full_length(&self, z: &[f64]) -> Vec<f64> {
        let mut out = vec![0.0; self.n];
        for (&i, z) in self.bounded.iter().zip(z) {
            out[i] = z / self.sf;
        }
        out
    }

    fn finish(mut self, status: Status) -> NlpSolution {
        // never report a non-finite point as a success
        let finite = all_finite(&self.x)
            && all_finite(&self.y)
            && all_finite(&self.zl)
            && all_finite(&self.zu)
            && self.f.is_finite();
        let status = if !finite && matches!(status, Status::Converged | Status::Acceptable) {
            Status::NumericalFailure
        } else {
            status
        };
        self.times.total = self.start.elapsed();
        let lambda: Vec<f64> = self.y.iter().zip(&self.sc).map(|(y, s)| y * s / self.sf).collect();
        let report = NlpReport {
            status,
            iterations: self.iter,
            objective: self.f / self.sf,
            primal_infeasibility: self.unscaled_primal(),
            dual_infeasibility: self.unscaled_dual(),
            complementarity: self.unscaled_compl(),
            mu: self.mu,
            objective_scaling: self.sf,
            evaluations: self.counts,
            symbolic_factorizations: self.symbolic,
            numeric_factorizations: self.numeric,
            inertia_correction_factorizations: self.inertia_extra,
            other_factorizations: self.other_factor,
            second_order_corrections: self.soc_count,
            restoration_steps: self.restoration_steps,
            non_finite_trials: self.non_finite_trials,
            max_kkt_residual: self.max_residual,
            linear_solver: self.kkt.name(),
            kkt_nnz: self.kkt.nnz().0,
            factor_nnz: self.kkt.nnz().1,
            times: self.times,
        };
        NlpSolution {
            w: std::mem::take(&mut self.x),
            lambda,
            z_lower: self.full_length(&self.zl),
            z_upper: self.full_length(&self.zu),
            report,
        }
    }
}
