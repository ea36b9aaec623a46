//! Laplace approximation of the posterior at a constrained MAP point.
//!
//! At a local maximum of the log-merit J subject to c(w) = 0, the Laplace approximation of the
//! posterior of w is Gaussian with covariance Z (Zᵀ H Z)⁻¹ Zᵀ, where H is the Hessian of the
//! Lagrangian of −J and the columns of Z span the null space of the constraint Jacobian A.
//! That matrix is the primal block of the inverse of the KKT matrix
//!
//! $$ K = \begin{pmatrix} H & A^\top \\ A & 0 \end{pmatrix}, $$
//!
//! so a variance is one solve with the factorised K and a unit right-hand side (no dense
//! inverse). The factorisation is checked to have inertia (n, m, 0): H positive definite on the
//! null space of A, i.e. a strict local maximum.

use crate::nlp::{KktSolver, KktStructure, KktValues, NlpProblem};

/// The largest backward error ‖eᵢ − K x‖∞ / (1 + ‖K‖∞ ‖x‖∞) of a variance solve with a
/// regularised factorisation that is accepted as is: x then solves a system within 10⁻¹⁰ of K,
/// as a backward-stable unregularised solve would.
const BACKWARD_ERROR: f64 = 1e-10;

/// The relative accuracy a variance must otherwise have: the first-order error estimate |xᵀr|
/// of [`corrected_variance`] must be at most this fraction of the variance (its sd is then
/// correct to half of it, 5·10⁻⁵).
const VARIANCE_ACCURACY: f64 = 1e-4;

/// Posterior variances of the variables `wanted` at the point `w` with constraint multipliers
/// `lambda` (the convention of [`crate::nlp`]: ∇f + Jᵀλ = 0), with the KKT solver `solver`
/// (typically the one of the NLP solve, whose analysis of the same pattern it can reuse).
/// `None` when the KKT matrix cannot be factorised or does not have the inertia of a strict
/// local minimum of −J.
pub(super) fn laplace_variances<P: NlpProblem, K: KktSolver + ?Sized>(
    nlp: &mut P,
    w: &[f64],
    lambda: &[f64],
    wanted: &[usize],
    solver: &mut K,
) -> Option<Vec<f64>> {
    let (n, m) = (nlp.num_variables(), nlp.num_constraints());
    let hs = nlp.hessian_structure();
    let js = nlp.jacobian_structure();
    let mut hv = vec![0.0; hs.len()];
    let mut jv = vec![0.0; js.len()];
    nlp.hessian_values(w, 1.0, lambda, &mut hv);
    nlp.jacobian_values(w, &mut jv);
    let order = nlp.kkt_order();
    solver.analyse(&KktStructure::new(n, m, &hs, &js).with_order(order.as_deref())).ok()?;
    let zeros = vec![0.0; n];
    let info = solver.factorize(&KktValues {
        hessian: &hv,
        jacobian: &jv,
        primal_diagonal: &zeros,
        delta_w: 0.0,
        delta_c: 0.0,
    })?;
    if info.inertia.positive != n || info.inertia.negative != m {
        return None;
    }
    // Without pivoting, a variable without curvature eliminated before its constraint gives a
    // numerically zero pivot that faer regularises; as in the NLP solver, the factorisation is
    // then trusted as is if iterative refinement brings the solve's residual below 1e-8.
    // Otherwise (refinement stagnates near ε·cond(K) on badly scaled KKT systems, e.g. the
    // flight-path model's, whose entries span 10⁻⁴ to 10⁵), a variance is kept if its solve is
    // backward stable (BACKWARD_ERROR) or, corrected by its first-order error, that error is
    // below VARIANCE_ACCURACY of it.
    let regularized = info.regularized_pivots > 0;
    let kkt = Kkt { n, hs: &hs, js: &js, hv: &hv, jv: &jv };
    let norm_k = if regularized { kkt.norm_inf(m) } else { 0.0 };
    let mut rhs = vec![0.0; n + m];
    let mut out = Vec::with_capacity(wanted.len());
    for &i in wanted {
        rhs.fill(0.0);
        rhs[i] = 1.0;
        let residual = solver.solve_in_place(&mut rhs);
        if !rhs[i].is_finite() || residual.is_nan() {
            return None;
        }
        let v = if regularized && residual > 1e-8 {
            let (corrected, error, backward) = corrected_variance(&kkt, norm_k, &rhs, i);
            if backward <= BACKWARD_ERROR {
                rhs[i]
            } else if corrected.is_finite() && error <= VARIANCE_ACCURACY * corrected {
                corrected
            } else {
                return None;
            }
        } else {
            rhs[i]
        };
        out.push(v.max(0.0));
    }
    Some(out)
}

/// The KKT matrix K of [`laplace_variances`] by its patterns and values (lower-triangle
/// Hessian pairs, Jacobian pairs (constraint, variable)).
struct Kkt<'a> {
    n: usize,
    hs: &'a [(u32, u32)],
    js: &'a [(u32, u32)],
    hv: &'a [f64],
    jv: &'a [f64],
}

impl Kkt<'_> {
    /// ‖K‖∞, the largest absolute row sum, with `m` constraints.
    fn norm_inf(&self, m: usize) -> f64 {
        let mut rows = vec![0.0f64; self.n + m];
        for (&(r, c), &v) in self.hs.iter().zip(self.hv) {
            let (r, c) = (r as usize, c as usize);
            rows[r] += v.abs();
            if r != c {
                rows[c] += v.abs();
            }
        }
        for (&(r, c), &v) in self.js.iter().zip(self.jv) {
            rows[self.n + r as usize] += v.abs();
            rows[c as usize] += v.abs();
        }
        rows.into_iter().fold(0.0, f64::max)
    }

    /// y = K x.
    fn apply(&self, x: &[f64], y: &mut [f64]) {
        y.fill(0.0);
        for (&(r, c), &v) in self.hs.iter().zip(self.hv) {
            let (r, c) = (r as usize, c as usize);
            y[r] += v * x[c];
            if r != c {
                y[c] += v * x[r];
            }
        }
        for (&(r, c), &v) in self.js.iter().zip(self.jv) {
            let (r, c) = (self.n + r as usize, c as usize);
            y[r] += v * x[c];
            y[c] += v * x[r];
        }
    }
}

/// The variance (K⁻¹)ᵢᵢ from an approximate solution `x` of K x = eᵢ, corrected by its
/// first-order error; the size of that correction; and the backward error
/// ‖r‖∞ / (1 + `norm_k` ‖x‖∞). With r = eᵢ − K x and K symmetric,
/// (K⁻¹)ᵢᵢ = xᵢ + eᵢᵀK⁻¹r = xᵢ + xᵀr + rᵀK⁻¹r: the corrected value xᵢ + xᵀr is exact up to a
/// term quadratic in the residual (the adjoint, or dual-weighted residual, correction of a
/// linear functional of a solution), and |xᵀr| estimates the error of xᵢ.
fn corrected_variance(kkt: &Kkt<'_>, norm_k: f64, x: &[f64], i: usize) -> (f64, f64, f64) {
    let mut r = vec![0.0; x.len()];
    kkt.apply(x, &mut r);
    for v in &mut r {
        *v = -*v;
    }
    r[i] += 1.0;
    let correction: f64 = x.iter().zip(&r).map(|(a, b)| a * b).sum();
    let r_norm = r.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    let x_norm = x.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    (x[i] + correction, correction.abs(), r_norm / (1.0 + norm_k * x_norm))
}

#[cfg(test)]
mod tests {
    use super::{corrected_variance, Kkt};

    /// K = [[2, 1, 1], [1, 3, 1], [1, 1, 0]] (H 2×2, one constraint x₀ + x₁): the corrected
    /// variance of a perturbed solution of K x = e₀ is exact up to the square of the
    /// perturbation, and the reported error is the first-order one.
    #[test]
    fn corrected_variance_is_exact_to_second_order() {
        let hs = [(0, 0), (1, 0), (1, 1)];
        let hv = [2.0, 1.0, 3.0];
        let js = [(0, 0), (0, 1)];
        let jv = [1.0, 1.0];
        let kkt = Kkt { n: 2, hs: &hs, js: &js, hv: &hv, jv: &jv };
        // K⁻¹ e₀ by hand: the null space of A is (1, −1), Zᵀ H Z = 2 − 2 + 3 = 3, so the
        // primal block is Z Zᵀ / 3 and (K⁻¹)₀₀ = 1/3; K⁻¹ e₀ = (1/3, −1/3, 2/3).
        let exact = [1.0 / 3.0, -1.0 / 3.0, 2.0 / 3.0];
        let mut y = [0.0; 3];
        kkt.apply(&exact, &mut y);
        assert!((y[0] - 1.0).abs() < 1e-15 && y[1].abs() < 1e-15 && y[2].abs() < 1e-15, "{y:?}");
        for eps in [1e-3, 1e-5] {
            let x = [exact[0] + eps, exact[1] - 2.0 * eps, exact[2] + 0.5 * eps];
            let (v, error, backward) = corrected_variance(&kkt, kkt.norm_inf(1), &x, 0);
            assert!((v - 1.0 / 3.0).abs() < 10.0 * eps * eps, "eps {eps}: {v}");
            assert!(error > 0.1 * eps && error < 10.0 * eps, "eps {eps}: error {error}");
            // r = −K δ with δ = eps (1, −2, 1/2): (−0.5, 4.5, 1) eps; ‖K‖∞ = 5, ‖x‖∞ = x₂
            assert!((backward - 4.5 * eps / (1.0 + 5.0 * x[2].abs())).abs() < 1e-12);
        }
        let (_, error, backward) = corrected_variance(&kkt, 5.0, &exact, 0);
        assert!(error < 1e-15 && backward < 1e-15);
    }
}
