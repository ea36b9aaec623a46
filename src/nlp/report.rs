//! Outcome of a solve: status, solution and report.

use std::fmt;
use std::time::Duration;

pub use crate::status::Status;

/// Number of calls of each problem function.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct EvaluationCounts {
    /// Objective evaluations.
    pub objective: usize,
    /// Gradient evaluations.
    pub gradient: usize,
    /// Constraint evaluations.
    pub constraints: usize,
    /// Jacobian evaluations.
    pub jacobian: usize,
    /// Hessian evaluations.
    pub hessian: usize,
}

/// Wall-clock time per phase.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PhaseTimes {
    /// Checking the problem, building the KKT pattern and the symbolic analysis.
    pub setup: Duration,
    /// Calls of the problem's functions.
    pub evaluation: Duration,
    /// Numeric factorisations.
    pub factorization: Duration,
    /// Triangular solves with iterative refinement.
    pub solve: Duration,
    /// Everything.
    pub total: Duration,
}

/// Everything a solve reports besides the point itself.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct NlpReport {
    /// How the solver ended.
    pub status: Status,
    /// Number of iterations (Newton steps taken).
    pub iterations: usize,
    /// Objective at the returned point (unscaled).
    pub objective: f64,
    /// $\lVert c(w)\rVert_\infty$ at the returned point (unscaled).
    pub primal_infeasibility: f64,
    /// $\lVert\nabla f + J^\top\lambda - z_L + z_U\rVert_\infty$ at the returned point
    /// (unscaled).
    pub dual_infeasibility: f64,
    /// $\max_i \max(z_{L,i}(w_i - l_i), z_{U,i}(u_i - w_i))$ at the returned point (unscaled).
    pub complementarity: f64,
    /// Final barrier parameter.
    pub mu: f64,
    /// Objective scaling factor used internally.
    pub objective_scaling: f64,
    /// Number of calls of each problem function.
    pub evaluations: EvaluationCounts,
    /// Symbolic analyses of the KKT matrix (one per problem).
    pub symbolic_factorizations: usize,
    /// Numeric factorisations, one per iteration (the first attempt of each Newton step).
    pub numeric_factorizations: usize,
    /// Additional numeric factorisations made by the inertia correction.
    pub inertia_correction_factorizations: usize,
    /// Other numeric factorisations (initial multiplier estimate, restoration steps).
    pub other_factorizations: usize,
    /// Second-order correction steps tried.
    pub second_order_corrections: usize,
    /// Restoration steps taken.
    pub restoration_steps: usize,
    /// Trial points rejected because the functions returned non-finite values.
    pub non_finite_trials: usize,
    /// Largest relative residual $\lVert b - K x\rVert_\infty / \lVert b\rVert_\infty$ of
    /// the Newton-step solves (after iterative refinement).
    pub max_kkt_residual: f64,
    /// The KKT solver that was used ([`KktSolver::name`](super::KktSolver::name)).
    pub linear_solver: &'static str,
    /// Number of nonzeros in the upper triangle of the KKT matrix.
    pub kkt_nnz: usize,
    /// Number of nonzeros in the factor $L$.
    pub factor_nnz: usize,
    /// Wall-clock time per phase.
    pub times: PhaseTimes,
}

impl fmt::Display for NlpReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let e = &self.evaluations;
        let t = &self.times;
        writeln!(f, "{:<26}{}", "status", self.status)?;
        writeln!(f, "{:<26}{}", "iterations", self.iterations)?;
        writeln!(f, "{:<26}{:.10e}", "objective", self.objective)?;
        writeln!(
            f,
            "{:<26}{:.2e} / {:.2e} / {:.2e}",
            "primal / dual / compl.",
            self.primal_infeasibility,
            self.dual_infeasibility,
            self.complementarity
        )?;
        writeln!(
            f,
            "{:<26}f {} | grad {} | c {} | jac {} | hess {}",
            "evaluations", e.objective, e.gradient, e.constraints, e.jacobian, e.hessian
        )?;
        writeln!(
            f,
            "{:<26}symbolic {} | numeric {} | inertia corr. {} | other {}",
            "factorizations",
            self.symbolic_factorizations,
            self.numeric_factorizations,
            self.inertia_correction_factorizations,
            self.other_factorizations
        )?;
        writeln!(
            f,
            "{:<26}soc {} | restoration {} | non-finite trials {}",
            "steps", self.second_order_corrections, self.restoration_steps, self.non_finite_trials
        )?;
        writeln!(
            f,
            "{:<26}{} | nnz(K) {} | nnz(L) {} | max residual {:.1e}",
            "kkt", self.linear_solver, self.kkt_nnz, self.factor_nnz, self.max_kkt_residual
        )?;
        write!(
            f,
            "{:<26}setup {:.3?} | eval {:.3?} | factor {:.3?} | solve {:.3?} | total {:.3?}",
            "time", t.setup, t.evaluation, t.factorization, t.solve, t.total
        )
    }
}

/// The result of a solve: the last point with its multipliers, and the report.
///
/// The multipliers are those of the Lagrangian
/// $\mathcal{L} = f + \lambda^\top c - z_L^\top (w - l) - z_U^\top (u - w)$ of the unscaled
/// problem; bound multipliers of infinite bounds are zero.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct NlpSolution {
    /// The primal point $w$.
    pub w: Vec<f64>,
    /// Constraint multipliers $\lambda$ (length $m$).
    pub lambda: Vec<f64>,
    /// Lower-bound multipliers $z_L \ge 0$ (length $n$).
    pub z_lower: Vec<f64>,
    /// Upper-bound multipliers $z_U \ge 0$ (length $n$).
    pub z_upper: Vec<f64>,
    /// Status, counts and timings.
    pub report: NlpReport,
}
