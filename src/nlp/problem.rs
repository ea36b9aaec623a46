//! The interface through which a nonlinear program supplies its data to the solver.

/// A sparse nonlinear program
///
/// $$\min_{w \in \mathbb{R}^n} f(w) \quad \text{s.t.} \quad c(w) = 0, \quad l \le w \le u,$$
///
/// with $c : \mathbb{R}^n \to \mathbb{R}^m$ and bounds that may be infinite.
///
/// The sparsity patterns of the constraint Jacobian and of the Hessian of the Lagrangian are
/// queried once, before the first iteration; afterwards the solver asks only for values, written
/// into slices in the order of the pattern. Repeated entries in a pattern are allowed and are
/// summed.
///
/// Evaluation functions never fail explicitly: a value that cannot be computed (outside the
/// domain of a logarithm, an overflow, ...) is reported by writing NaN or an infinity, and the
/// solver then shortens the step (or ends with
/// [`Status::EvaluationError`](super::Status::EvaluationError) when there is nothing to fall
/// back to).
pub trait NlpProblem {
    /// Number of variables $n$.
    fn num_variables(&self) -> usize;

    /// Number of equality constraints $m$ (may be zero).
    fn num_constraints(&self) -> usize;

    /// Writes the bounds $l$ and $u$ (each of length $n$). Use `f64::NEG_INFINITY` and
    /// `f64::INFINITY` for absent bounds. The default leaves every variable free.
    fn bounds(&self, lower: &mut [f64], upper: &mut [f64]) {
        lower.fill(f64::NEG_INFINITY);
        upper.fill(f64::INFINITY);
    }

    /// Writes the initial point $w_0$ (length $n$). It need not satisfy the bounds strictly:
    /// the solver moves it into their interior.
    fn initial_point(&self, w: &mut [f64]);

    /// The objective $f(w)$.
    fn objective(&mut self, w: &[f64]) -> f64;

    /// Writes the gradient $\nabla f(w)$ (length $n$): every entry, since `grad` holds the
    /// values of an earlier call (or zeros).
    fn gradient(&mut self, w: &[f64], grad: &mut [f64]);

    /// Writes the constraint values $c(w)$ (length $m$), every entry.
    fn constraints(&mut self, w: &[f64], c: &mut [f64]);

    /// The pattern of the Jacobian $\partial c / \partial w$ as `(row, column)` pairs,
    /// `row < m`, `column < n`. Queried once. Indices are `u32`, as IPOPT's `Index` is 32-bit:
    /// the patterns of the largest transcriptions have millions of entries, and the solver
    /// keeps the Jacobian's (the solver rejects problems with more than 2³² − 1 variables or
    /// constraints).
    fn jacobian_structure(&self) -> Vec<(u32, u32)>;

    /// Writes the Jacobian values in the order of
    /// [`jacobian_structure`](Self::jacobian_structure): every entry, since `values` holds
    /// those of an earlier call (or zeros).
    fn jacobian_values(&mut self, w: &[f64], values: &mut [f64]);

    /// The pattern of the lower triangle of the Hessian of the Lagrangian as `(row, column)`
    /// pairs with `row >= column` (a pair with `row < column` is read as its mirror image).
    /// Queried once; `u32` indices as in [`jacobian_structure`](Self::jacobian_structure).
    fn hessian_structure(&self) -> Vec<(u32, u32)>;

    /// Writes the values of
    /// $\sigma_f \nabla^2 f(w) + \sum_j \lambda_j \nabla^2 c_j(w)$
    /// in the order of [`hessian_structure`](Self::hessian_structure): every entry, since
    /// `values` holds those of an earlier call (or zeros).
    fn hessian_values(&mut self, w: &[f64], obj_factor: f64, lambda: &[f64], values: &mut [f64]);

    /// An elimination order of the KKT matrix that keeps it banded, when the problem knows one
    /// (a transcription: its variables and constraints in time order): `order[p]` is the KKT
    /// row at position `p`, variable `i` as `i` and constraint `r` as `n + r`, a permutation of
    /// `0..n + m`. The band solver ([`BandLdlt`](super::BandLdlt)) then eliminates in this
    /// order: no reverse Cuthill–McKee search, no placement of the constraints, no detection of
    /// dense variables (the order puts them where it wants them, normally last); faer's solver
    /// ignores it. Since that factorisation does not pivot, an order that eliminates each
    /// variable without curvature after a constraint that holds it avoids the zero pivots it
    /// would otherwise regularise (and the refinement step each solve then needs). Queried
    /// once. The default `None` leaves the ordering to the solver.
    fn kkt_order(&self) -> Option<Vec<usize>> {
        None
    }
}
