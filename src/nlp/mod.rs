//! A sparse nonlinear programming solver: a primal–dual interior-point method with a filter
//! line search on faer's sparse LDLᵀ.
//!
//! It solves
//!
//! $$\min_{w \in \mathbb{R}^n} f(w) \quad \text{s.t.} \quad c(w) = 0, \quad l \le w \le u$$
//!
//! for problems described through [`NlpProblem`] (exact first and second derivatives in fixed
//! sparsity patterns). The algorithm follows A. Wächter and L. T. Biegler, "On the
//! implementation of an interior-point filter line-search algorithm for large-scale nonlinear
//! programming", *Math. Program.* 106 (2006) 25–57 (IPOPT); section numbers below refer to that
//! paper.
//!
//! - **Barrier problem** (Sect. 2.1): the bounds are replaced by the logarithmic barrier
//!   $\varphi_\mu(w) = f(w) - \mu\sum_i \ln(w_i - l_i) - \mu\sum_i \ln(u_i - w_i)$, solved
//!   approximately for a decreasing sequence of $\mu$ (monotone Fiacco–McCormick update,
//!   eqs. (7)–(8)): $\mu$ is decreased when the barrier optimality error $E_\mu$ (eq. (5)) is
//!   below $\kappa_\varepsilon\mu$. Convergence is declared when $E_0 \le$ `tolerance`.
//! - **Newton step** (Sect. 2.2, eqs. (11)–(13)): the primal–dual system is reduced to the
//!   symmetric KKT system in $(d_w, d_y)$ solved by [`kkt`]; the bound multipliers' steps are
//!   recovered afterwards (Sect. 3.4 for lower and upper bounds). Steps are cut by the
//!   fraction-to-the-boundary rule (eq. (15)) with $\tau = \max(0.99, 1-\mu)$, and the bound
//!   multipliers are kept within a factor $\kappa_\Sigma$ of $\mu/s$ (eq. (16)).
//! - **Inertia correction** (Sect. 3.1, Algorithm IC): the KKT matrix must have $n$ positive
//!   and $m$ negative eigenvalues; otherwise $\delta_w I$ is added to the Hessian block
//!   (growing geometrically, remembered between iterations) and, when the matrix is singular,
//!   $-\delta_c I$ with $\delta_c = 10^{-8}\mu^{1/4}$ to the constraint block. The inertia is
//!   read from the signs of $D$ in the LDLᵀ factorisation. When the factorisation had to
//!   regularise numerically zero pivots (which happens without pivoting even for nonsingular
//!   matrices, e.g. for a variable without curvature eliminated before its constraint), its
//!   inertia is uncertain: it is kept only if it has the right signs *and* iterative
//!   refinement against the assembled matrix brings the relative residual below $10^{-8}$;
//!   otherwise the matrix is treated as singular ($\delta_c > 0$) and $\delta_w$ is increased.
//! - **Filter line search** (Sect. 2.3): a trial point is accepted if the filter accepts
//!   its pair $(\theta, \varphi_\mu)$, with $\theta = \lVert c\rVert_1$, and it either gives
//!   sufficient decrease in $\theta$ or $\varphi_\mu$ (eq. (18)) or, when the switching
//!   condition (eq. (19)) holds, satisfies the Armijo condition (eq. (20)); the filter is
//!   augmented after θ-type steps (eq. (22)) and the minimum step is eq. (23).
//! - **Second-order correction** (Sect. 2.4): when the first trial point is rejected and
//!   increases θ, up to four corrected steps using $c(w + \alpha d_w)$ are tried.
//! - **Filter reset** (Sect. 3.2, Case I): when the filter rejects the full step in
//!   five consecutive iterations it is cleared (at most five times per solve).
//! - **Restoration and infeasibility** (in place of Sect. 3.3): when the line search fails,
//!   Levenberg–Marquardt steps on $\tfrac12\lVert c\rVert^2$ in the interior of the bounds
//!   are taken until the filter accepts the point. If the violation cannot be reduced and the
//!   projected gradient of $\tfrac12\lVert c\rVert^2$ vanishes, the status is
//!   [`Status::Infeasible`]. (IPOPT's restoration is a full interior-point solve of an
//!   ℓ₁-penalty problem; this simpler phase is a known difference.)
//! - **Initialisation, scaling, one-sided bounds** (Sect. 3): the initial point is moved into
//!   the interior of the bounds and the constraint multipliers are initialised by least
//!   squares (Sect. 3.6); objective and constraints are scaled so that their gradients at the
//!   initial point are at most 100 in max-norm (Sect. 3.8); variables with one bound get the
//!   small linear damping term $\kappa_d\mu$ (Sect. 3.7); bounds whose slack underflows are
//!   relaxed by $\varepsilon_{mach}^{3/4}$ and fixed variables ($l = u$) by $10^{-8}$ (Sect. 3.5);
//!   tiny steps trigger a barrier update (Sect. 3.9).
//! - **Unboundedness**: a feasible iterate with $f < $ `unbounded_objective` (default
//!   $-10^{20}$) ends with [`Status::Unbounded`].
//! - **Non-finite values**: a trial point where the objective, the constraints or their
//!   derivatives are NaN or infinite is rejected and the step shortened; non-finite values at
//!   the initial point or in the Hessian end with [`Status::EvaluationError`].
//!
//! The KKT matrix pattern is built once with index maps from the problem's triplets to the
//! matrix slots, analysed symbolically once, and factorised numerically once per iteration
//! (plus the extra factorisations of the inertia correction, counted separately in
//! [`NlpReport`]).

#![deny(missing_docs)]
pub mod band;
mod ipm;
pub mod kkt;
mod options;
mod problem;
mod report;

pub use band::BandLdlt;
pub use ipm::{solve, InteriorPoint};
pub use kkt::{AutoLdlt, FactorInfo, FaerLdlt, Inertia, KktSolver, KktStructure, KktValues};
pub use options::{IterationCallback, IterationSummary, LinearSolver, NlpOptions, Verbosity};
pub use problem::NlpProblem;
pub use report::{EvaluationCounts, NlpReport, NlpSolution, PhaseTimes, Status};

#[cfg(test)]
mod tests;
