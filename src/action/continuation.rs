//! Which stationary point of a non-concave dual a closure reports: the one on the branch that
//! starts at the prior, followed in the measurement precision.
//!
//! A Rayleigh–Ritz F need not be convex (`003_d2fc48a470e528fc.txt` Sec. II.1 after (II.16)),
//! so its dual Φ(λ) = Σλ_kᵀr_k − ½Σλ_kᵀR_kλ_k − F(λ) (`(I.57)–(I.60)`) may have several local
//! maxima, and the one a Newton or trust-region iteration reaches depends on where it starts.
//! Scale the measurement precision by s ∈ (0, 1]: the data variances become R/s, and the
//! stationarity condition (`(I.60)`)
//!
//! $$ G(\lambda, s) = R\lambda / s + z(\lambda) - r = 0, \qquad z = \nabla F, $$
//!
//! has, for s → 0, the unique solution λ ≈ s R⁻¹(r − z(0)) next to the prior (λ = 0), where
//! K_s = ∇²F + R/s is positive definite and Φ concave. Multiplied by s, the condition
//! H(λ, s) = Rλ + s(z(λ) − r) = 0 holds at (0, 0) and defines, where its Jacobian
//! [R + s∇²F | z − r] has full rank, a curve through the prior. [`follow_branch`] follows that
//! curve by pseudo-arclength continuation (Keller 1977; Allgower & Georg, *Introduction to
//! Numerical Continuation Methods*, SIAM 2003, Ch. 2: tangent predictor, Newton corrector on
//! the system augmented by the arclength condition), in the standardised multipliers
//! w = R^{1/2}λ, through the folds where K_s is singular and s turns back, to the first point
//! where s = 1: the stationary point of the data's own dual connected to the prior. Where K is
//! positive definite there it is a local maximum of Φ; elsewhere a saddle, a stationary point
//! of the Rayleigh–Ritz action all the same (the report says so: its sd is the density's).
//! For the linear-Gaussian F = μᵀλ + ½λᵀCλ the curve is λ(s) = s(R + sC)⁻¹(r − μ), and its
//! end the Kalman smoother's multipliers.
//!
//! The rule makes the estimate a function of the data alone: no start, no iteration history,
//! no thread count enters it.

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use super::dual::{residual, DualData, EffectiveAction};
use crate::Result;

/// The most points of one branch.
const MAX_POINTS: usize = 400;
/// Newton iterations of one corrector.
const CORRECTOR_ITERATIONS: usize = 6;
/// The corrector's tolerance on max |H̃| (standardised), relative to 1 + max |w|.
const CORRECTOR_TOLERANCE: f64 = 1e-4;
/// The first step advances s by about this.
const FIRST_STEP: f64 = 1e-4;
/// Newton iterations of the last solve at s = 1.
const FINAL_ITERATIONS: usize = 30;

/// Which stationary point of the dual a closure reports (option `branch`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
#[non_exhaustive]
pub enum BranchRule {
    /// The stationary point connected to the prior by the curve of stationary points in the
    /// measurement precision ([`follow_branch`]): a function of the data alone; a failure
    /// when that point is not a maximum of the dual.
    Continuation,
    /// The local maximum that Newton's method (trust-region steps where the dual is not
    /// concave) reaches from the closure's assumed-density filter, retried from λ = 0: it
    /// depends on the start and the iteration. The default.
    #[default]
    Filter,
}

/// How the branch ended.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "kebab-case", tag = "end")]
pub enum BranchEnd {
    /// It reached the data's precision (s = 1) and the stationarity condition holds there to
    /// the requested tolerance; `maximum`: K = ∇²F + R is positive definite there (a local
    /// maximum of Φ, not a saddle).
    Reached {
        /// Whether the point is a local maximum of the dual.
        maximum: bool,
    },
    /// It was lost at `precision` (the last s reached): no corrector converged however short
    /// the step, the last solve at s = 1 did not converge, or the curve ran past
    /// [`MAX_POINTS`] points or back to s ≤ 0.
    Lost {
        /// The last precision s reached.
        precision: f64,
    },
    /// F or its gradient is not finite at λ = 0 (the prior's sweep failed).
    NoPrior,
}

/// The branch of stationary points from the prior, as far as it goes.
#[derive(Debug, Clone, PartialEq)]
pub struct Branch {
    /// λ at the end (at s = 1 when [`BranchEnd::Reached`]).
    pub lambda: Vec<f64>,
    /// How it ended.
    pub end: BranchEnd,
    /// Accepted points of the curve.
    pub points: usize,
    /// Folds passed (sign changes of ds along the curve).
    pub folds: usize,
    /// Newton iterations (correctors and the last solve), rejected ones included.
    pub iterations: usize,
    /// Evaluations of F or ∇²F (sweeps).
    pub evaluations: usize,
}

/// A point (w, s) of the curve with what the corrector needs there.
struct Point {
    /// (w, s), length n + 1.
    y: DVector<f64>,
    /// z(λ) on the present data.
    z: Vec<f64>,
}

/// The curve's system in the standardised multipliers w = R^{1/2}λ on the present data.
struct Curve<'d> {
    data: &'d DualData,
    active: Vec<usize>,
    sq: Vec<f64>,
}

impl Curve<'_> {
    fn n(&self) -> usize {
        self.active.len()
    }

    /// λ (all data, missing entries 0) of w.
    fn lambda(&self, y: &DVector<f64>) -> Vec<f64> {
        let mut l = vec![0.0; self.data.r.len()];
        for (i, &m) in self.active.iter().enumerate() {
            l[m] = y[i] / self.sq[i];
        }
        l
    }

    /// z at y on the present data, or `None` when the sweep has no finite value.
    fn z<A: EffectiveAction + ?Sized>(
        &self,
        action: &mut A,
        y: &DVector<f64>,
        evals: &mut usize,
    ) -> Result<Option<Vec<f64>>> {
        let v = action.evaluate(&self.lambda(y))?;
        *evals += 1;
        let z: Vec<f64> = self.active.iter().map(|&m| v.z[m]).collect();
        Ok((v.value.is_finite() && z.iter().all(|x| x.is_finite())).then_some(z))
    }

    /// H̃ = w + s R^{-1/2}(z − r).
    fn h(&self, y: &DVector<f64>, z: &[f64]) -> DVector<f64> {
        let (n, s) = (self.n(), y[self.n()]);
        DVector::from_fn(n, |i, _| y[i] + s * (z[i] - self.data.r[self.active[i]]) / self.sq[i])
    }

    /// [∂H̃/∂w | ∂H̃/∂s] = [I + s R^{-1/2}∇²F R^{-1/2} | R^{-1/2}(z − r)] (n × (n + 1)), or `None`
    /// when ∇²F has no finite value at y.
    fn jacobian<A: EffectiveAction + ?Sized>(
        &self,
        action: &mut A,
        p: &Point,
        evals: &mut usize,
    ) -> Result<Option<DMatrix<f64>>> {
        let Ok(hess) = action.hessian(&self.lambda(&p.y))? else { return Ok(None) };
        *evals += 1;
        let (n, s) = (self.n(), p.y[self.n()]);
        let (a, q) = (&self.active, &self.sq);
        let j = DMatrix::from_fn(n, n + 1, |i, k| {
            if k == n {
                (p.z[i] - self.data.r[a[i]]) / q[i]
            } else {
                f64::from(u8::from(i == k)) + s * hess[(a[i], a[k])] / (q[i] * q[k])
            }
        });
        Ok(j.iter().all(|v| v.is_finite()).then_some(j))
    }
}

/// The unit tangent t of the curve at a point with Jacobian `j` (n × (n + 1)): J t = 0,
/// oriented so that tᵀ`previous` > 0 (the row `previous`ᵀ appended to J, right-hand side
/// e_{n+1}).
fn tangent(j: &DMatrix<f64>, previous: &DVector<f64>) -> Option<DVector<f64>> {
    let n = j.nrows();
    let mut a = j.clone().insert_row(n, 0.0);
    a.row_mut(n).copy_from(&previous.transpose());
    let mut e = DVector::zeros(n + 1);
    e[n] = 1.0;
    let t = a.lu().solve(&e)?;
    let norm = t.norm();
    (norm.is_finite() && norm > 0.0).then(|| t / norm)
}

/// Newton's method on the augmented system [H̃(y) = 0; τᵀ(y − ŷ) = 0] from the predictor ŷ,
/// [`CORRECTOR_ITERATIONS`] iterations; the corrected point and its Jacobian (at the last
/// iterate), or `None` when it does not converge.
fn correct<A: EffectiveAction + ?Sized>(
    action: &mut A,
    curve: &Curve<'_>,
    (predicted, tau, step): (&DVector<f64>, &DVector<f64>, f64),
    branch: &mut Branch,
) -> Result<Option<(Point, DMatrix<f64>)>> {
    let n = curve.n();
    let mut y = predicted.clone();
    for _ in 0..CORRECTOR_ITERATIONS {
        branch.iterations += 1;
        let Some(z) = curve.z(action, &y, &mut branch.evaluations)? else { return Ok(None) };
        let p = Point { y, z };
        let h = curve.h(&p.y, &p.z);
        let Some(j) = curve.jacobian(action, &p, &mut branch.evaluations)? else { return Ok(None) };
        let scale = 1.0 + p.y.rows(0, n).amax();
        if h.amax() <= CORRECTOR_TOLERANCE * scale {
            // A corrector that moved farther than half the step may have reached another
            // part of the curve.
            let moved = (&p.y - predicted).norm();
            return Ok((moved <= 0.5 * step).then_some((p, j)));
        }
        let mut a = j.insert_row(n, 0.0);
        a.row_mut(n).copy_from(&tau.transpose());
        let mut rhs = -h.insert_row(n, 0.0);
        rhs[n] = -tau.dot(&(&p.y - predicted));
        let Some(d) = a.lu().solve(&rhs) else { return Ok(None) };
        y = p.y + d;
    }
    Ok(None)
}

/// The last solve: Newton's method on H̃(w, 1) = 0 (the Jacobian I + R^{-1/2}∇²F R^{-1/2},
/// steps halved while max |H̃| does not fall) from `w` until the optimality residual is at most
/// `tolerance`; λ and whether K is positive definite there, or `None`.
fn finish<A: EffectiveAction + ?Sized>(
    action: &mut A,
    curve: &Curve<'_>,
    mut y: DVector<f64>,
    tolerance: f64,
    branch: &mut Branch,
) -> Result<Option<(Vec<f64>, bool)>> {
    let n = curve.n();
    y[n] = 1.0;
    let Some(mut z) = curve.z(action, &y, &mut branch.evaluations)? else { return Ok(None) };
    for _ in 0..FINAL_ITERATIONS {
        let lambda = curve.lambda(&y);
        let mut full = vec![0.0; curve.data.r.len()];
        for (i, &m) in curve.active.iter().enumerate() {
            full[m] = z[i];
        }
        let done = residual(&lambda, &full, curve.data, &curve.active) <= tolerance;
        let p = Point { y: y.clone(), z: z.clone() };
        let Some(j) = curve.jacobian(action, &p, &mut branch.evaluations)? else { return Ok(None) };
        if done {
            // J_w = R^{-1/2}KR^{-1/2}: positive definite exactly when K is.
            let jw = j.columns(0, n).into_owned();
            let maximum = ((&jw + jw.transpose()) * 0.5).cholesky().is_some();
            return Ok(Some((lambda, maximum)));
        }
        branch.iterations += 1;
        let h = curve.h(&y, &z);
        let Some(d) = j.columns(0, n).into_owned().lu().solve(&(-&h)) else { return Ok(None) };
        let mut t = 1.0;
        loop {
            let mut trial = y.clone();
            trial.rows_mut(0, n).axpy(t, &d, 1.0);
            if let Some(zt) = curve.z(action, &trial, &mut branch.evaluations)? {
                if curve.h(&trial, &zt).amax() < h.amax() {
                    (y, z) = (trial, zt);
                    break;
                }
            }
            t *= 0.5;
            if t < 1.0 / 64.0 {
                return Ok(None);
            }
        }
    }
    Ok(None)
}

/// Follows the curve of stationary points from the prior (see the
/// [module documentation](self)) to s = 1 and solves there to the optimality residual
/// `tolerance` (max_m |λ_m − (r_m − z_m)/R_m|, as [`super::dual::maximize_dual`]).
///
/// From (w, s) = (0, 0) with the tangent ∝ (R^{-1/2}(r − z(0)), 1) and a first step that
/// advances s by [`FIRST_STEP`], each step is a predictor
/// along the unit tangent and a Newton corrector on the curve's system augmented by the
/// arclength condition ([`CORRECTOR_ITERATIONS`] iterations, max |H̃| ≤
/// [`CORRECTOR_TOLERANCE`] · (1 + max |w|), ending within half the step of the predictor);
/// a step whose corrector fails is halved, one that
/// converged in at most two iterations lengthened by half. When s passes 1, Newton's method
/// at s = 1 from the chord between the last two points ends it. Each corrector iteration
/// costs one evaluation of F and one of ∇²F.
///
/// Errors: misuse (lengths, invalid data), as [`super::dual::maximize_dual`]. Where the
/// curve is lost is the [`BranchEnd`], not an error.
pub fn follow_branch<A: EffectiveAction + ?Sized>(
    action: &mut A,
    data: &DualData,
    tolerance: f64,
) -> Result<Branch> {
    data.validate(action.measurement_times().len())?;
    let active = data.active();
    let sq: Vec<f64> = active.iter().map(|&m| data.variance[m].sqrt()).collect();
    let curve = Curve { data, active, sq };
    let n = curve.n();
    let mut branch = Branch {
        lambda: vec![0.0; data.r.len()],
        end: BranchEnd::NoPrior,
        points: 0,
        folds: 0,
        iterations: 0,
        evaluations: 0,
    };
    let origin = DVector::zeros(n + 1);
    let Some(z0) = curve.z(action, &origin, &mut branch.evaluations)? else { return Ok(branch) };
    let mut here = Point { y: origin, z: z0 };
    let mut tau = DVector::from_fn(n + 1, |i, _| {
        if i == n {
            1.0
        } else {
            (data.r[curve.active[i]] - here.z[i]) / curve.sq[i]
        }
    });
    tau /= tau.norm();
    let mut step = FIRST_STEP / tau[n];
    let min_step = 1e-8 * (1.0 + step);
    branch.end = BranchEnd::Lost { precision: 0.0 };
    while branch.points < MAX_POINTS {
        let predicted = &here.y + &tau * step;
        let before = branch.iterations;
        let res = correct(action, &curve, (&predicted, &tau, step), &mut branch)?;
        match res {
            Some((next, j)) => {
                let s_next = next.y[n];
                if s_next <= 0.0 {
                    return Ok(branch);
                }
                let Some(t) = tangent(&j, &tau) else { return Ok(branch) };
                if t[n] * tau[n] < 0.0 {
                    branch.folds += 1;
                }
                branch.points += 1;
                if s_next >= 1.0 {
                    // The chord between the last two points at s = 1.
                    let f = (1.0 - here.y[n]) / (s_next - here.y[n]);
                    let y1 = &here.y + (&next.y - &here.y) * f;
                    if let Some((l, maximum)) = finish(action, &curve, y1, tolerance, &mut branch)? {
                        (branch.lambda, branch.end) = (l, BranchEnd::Reached { maximum });
                    } else {
                        branch.lambda = curve.lambda(&here.y);
                        branch.end = BranchEnd::Lost { precision: here.y[n] };
                    }
                    return Ok(branch);
                }
                let easy = branch.iterations - before <= 2;
                (here, tau) = (next, t);
                branch.lambda = curve.lambda(&here.y);
                branch.end = BranchEnd::Lost { precision: s_next };
                if easy {
                    step *= 1.5;
                }
            }
            None => {
                step *= 0.5;
                if step < min_step {
                    return Ok(branch);
                }
            }
        }
    }
    Ok(branch)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::action::dual::{ActionValue, History, Swept};
    use approx::assert_relative_eq;

    /// F(λ) = μλ + ½cλ² + ⅙qλ³ at one measurement: a cubic F whose dual
    /// Φ = λr − ½Rλ² − F has the stationary points Rλ + μ + cλ + ½qλ² = r.
    struct Cubic {
        times: Vec<f64>,
        mu: f64,
        c: f64,
        q: f64,
    }

    impl EffectiveAction for Cubic {
        fn measurement_times(&self) -> &[f64] {
            &self.times
        }
        fn output_dim(&self) -> usize {
            1
        }
        fn evaluate(&mut self, lambda: &[f64]) -> Result<ActionValue> {
            let l = lambda[0];
            Ok(ActionValue {
                value: self.mu * l + 0.5 * self.c * l * l + self.q * l * l * l / 6.0,
                z: vec![self.mu + self.c * l + 0.5 * self.q * l * l],
            })
        }
        fn hessian(&mut self, lambda: &[f64]) -> Result<Swept<DMatrix<f64>>> {
            Ok(Ok(DMatrix::from_element(1, 1, self.c + self.q * lambda[0])))
        }
        fn history(&mut self, lambda: &[f64], _cross: bool) -> Result<Swept<History>> {
            let z = self.evaluate(lambda)?.z;
            Ok(Ok(History {
                times: self.times.clone(),
                mean: vec![z],
                variance: vec![vec![self.c]],
                cross: None,
            }))
        }
    }

    #[test]
    fn the_curve_of_a_quadratic_action_ends_at_the_kalman_multipliers() {
        // q = 0: the linear-Gaussian case, λ* = (r − μ)/(R + c) at s = 1, a maximum.
        let mut f = Cubic { times: vec![1.0], mu: 0.5, c: 2.0, q: 0.0 };
        let data = DualData { r: vec![3.0], variance: vec![0.25], output_dim: 1 };
        let b = follow_branch(&mut f, &data, 1e-10).unwrap();
        assert_eq!(b.end, BranchEnd::Reached { maximum: true });
        assert_eq!(b.folds, 0);
        assert_relative_eq!(b.lambda[0], 2.5 / 2.25, max_relative = 1e-9);
    }

    #[test]
    fn a_cubic_action_reaches_the_root_next_to_the_prior_and_is_lost_past_its_fold() {
        // r − μ = 1, R + c = 1, q = −0.2: the stationary points solve 0.1λ² − λ + 1 = 0, λ = 1.127
        // (K = 1 − 0.2λ > 0, the maximum on the prior's curve) and λ = 8.873 (K < 0).
        let mut f = Cubic { times: vec![1.0], mu: 0.0, c: 0.75, q: -0.2 };
        let data = DualData { r: vec![1.0], variance: vec![0.25], output_dim: 1 };
        let b = follow_branch(&mut f, &data, 1e-10).unwrap();
        assert_eq!(b.end, BranchEnd::Reached { maximum: true });
        let root = (1.0 - (1.0f64 - 0.4).sqrt()) / 0.2;
        assert_relative_eq!(b.lambda[0], root, max_relative = 1e-9);
        // r = 5: 0.1λ² − (R/s + 0.75)λ + 5 = 0 has real roots only while (R/s + 0.75)² ≥ 2,
        // i.e. s ≤ 0.25/(√2 − 0.75) = 0.3765: the curve folds there and runs back towards s = 0
        // with λ → ∞; it never reaches the data's precision.
        let data = DualData { r: vec![5.0], ..data };
        let b = follow_branch(&mut f, &data, 1e-10).unwrap();
        let BranchEnd::Lost { precision } = b.end else { panic!("{:?}", b.end) };
        assert_eq!(b.folds, 1);
        assert!(precision < 0.25 / (2.0f64.sqrt() - 0.75), "{precision}");
    }
}
