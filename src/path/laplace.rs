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

/// The largest relative residual ‖e_i − K v‖∞ of a variance solve with a regularised
/// factorisation. Refinement stagnates near ε·cond(K): up to 2·10⁻⁶ on the flight-path model
/// (`000_74b95e149527c64e.txt` Sec. 4.2), whose KKT entries span 10⁻⁴ (the jerks' diffusion)
/// to 10⁵ (attitude measurements of sd 0.002 rad), where its Laplace sds agree with the spread
/// of the estimates over replicates (`examples/flight_path.rs`); 10⁻⁵ admits that and still
/// rejects a factorisation whose regularisation changed the solution.
const REFINED_RESIDUAL: f64 = 1e-5;

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
    // numerically zero pivot that faer regularises; the factorisation is then trusted only if
    // iterative refinement brings every solve's residual below REFINED_RESIDUAL.
    let regularized = info.regularized_pivots > 0;
    let mut rhs = vec![0.0; n + m];
    let mut out = Vec::with_capacity(wanted.len());
    for &i in wanted {
        rhs.fill(0.0);
        rhs[i] = 1.0;
        let residual = solver.solve_in_place(&mut rhs);
        let v = rhs[i];
        if !v.is_finite() || (regularized && (residual.is_nan() || residual > REFINED_RESIDUAL)) {
            return None;
        }
        out.push(v.max(0.0));
    }
    Some(out)
}
