//! Options of the interior-point solver and the per-iteration callback.

use std::fmt;
use std::ops::ControlFlow;
use std::time::Duration;

use crate::{Error, Result};

/// How much the solver writes into [`IterationSummary::log`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum Verbosity {
    /// No log lines (the callback still receives the numbers).
    #[default]
    Quiet,
    /// One line per iteration.
    Iterations,
    /// One line per iteration plus notes on inertia correction, second-order corrections,
    /// restoration and barrier updates.
    Detailed,
}

/// Which linear solver factorises the KKT matrix.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum LinearSolver {
    /// The variable-band [`BandLdlt`](super::BandLdlt) when the matrix can be ordered into a
    /// narrow band (mean envelope width at most
    /// [`DEFAULT_MAX_MEAN_WIDTH`](super::band::DEFAULT_MAX_MEAN_WIDTH)), otherwise
    /// [`FaerLdlt`](super::FaerLdlt).
    #[default]
    Auto,
    /// faer's general sparse LDLᵀ, [`FaerLdlt`](super::FaerLdlt) (the reference).
    Faer,
    /// The variable-band LDLᵀ [`BandLdlt`](super::BandLdlt); a solve fails with
    /// [`Error::InvalidOption`] when the matrix is not banded.
    Band,
}

/// What the callback receives after each iteration (and once for the initial point, as
/// iteration 0).
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct IterationSummary {
    /// Iteration number (0 = initial point).
    pub iteration: usize,
    /// Objective $f(w)$ (unscaled).
    pub objective: f64,
    /// Primal infeasibility $\lVert c(w)\rVert_\infty$ (unscaled).
    pub primal_infeasibility: f64,
    /// Dual infeasibility of the scaled problem, $\lVert\nabla_w \mathcal{L}\rVert_\infty$.
    pub dual_infeasibility: f64,
    /// Barrier parameter $\mu$.
    pub mu: f64,
    /// $\lVert d_w\rVert_\infty$ of the last step (0 at iteration 0).
    pub step_norm: f64,
    /// Hessian regularisation $\delta_w$ of the last step.
    pub delta_w: f64,
    /// Primal step length $\alpha$ of the last step.
    pub alpha_primal: f64,
    /// Dual step length $\alpha_z$ of the last step.
    pub alpha_dual: f64,
    /// Number of backtracking trials in the last line search.
    pub line_search_trials: usize,
    /// Log text according to [`NlpOptions::verbosity`]; `None` when quiet.
    pub log: Option<String>,
}

/// Per-iteration callback: return `ControlFlow::Break(())` to stop the solver
/// ([`Status::UserStop`](super::Status::UserStop)).
pub type IterationCallback = Box<dyn FnMut(&IterationSummary) -> ControlFlow<()> + Send>;

/// Options of [`InteriorPoint`](super::InteriorPoint). Validated once by
/// [`InteriorPoint::try_new`](super::InteriorPoint::try_new).
#[non_exhaustive]
pub struct NlpOptions {
    /// Convergence tolerance on the scaled optimality error $E_0$ (Wächter & Biegler 2006,
    /// eq. (5)). Default `1e-8`.
    pub tolerance: f64,
    /// Acceptable tolerance: if $E_0$ stays below it for
    /// [`acceptable_iterations`](Self::acceptable_iterations) consecutive iterations the solver
    /// stops with [`Status::Acceptable`](super::Status::Acceptable). Default `1e-6`.
    pub acceptable_tolerance: f64,
    /// Consecutive acceptable iterations needed to stop early. Default `15`.
    pub acceptable_iterations: usize,
    /// Tolerance on the unscaled constraint violation $\lVert c\rVert_\infty$ required in
    /// addition to [`tolerance`](Self::tolerance) for convergence. Default `1e-6`.
    pub constraint_tolerance: f64,
    /// Maximum number of iterations. Default `3000`.
    pub max_iterations: usize,
    /// Wall-clock limit. Default `None` (no limit).
    pub time_limit: Option<Duration>,
    /// Initial barrier parameter $\mu_0$. Default `0.1`.
    pub mu_init: f64,
    /// Objective value (unscaled) below which a feasible iterate declares the problem
    /// unbounded. Default `-1e20`.
    pub unbounded_objective: f64,
    /// Use gradient-based scaling of the objective and constraints (Wächter & Biegler 2006,
    /// Sect. 3.8). Default `true`.
    pub scaling: bool,
    /// What goes into [`IterationSummary::log`]. Default [`Verbosity::Quiet`].
    pub verbosity: Verbosity,
    /// The KKT solver. Default [`LinearSolver::Auto`].
    pub linear_solver: LinearSolver,
    /// Called after each iteration. Default `None`.
    pub callback: Option<IterationCallback>,
}

impl Default for NlpOptions {
    fn default() -> Self {
        Self {
            tolerance: 1e-8,
            acceptable_tolerance: 1e-6,
            acceptable_iterations: 15,
            constraint_tolerance: 1e-6,
            max_iterations: 3000,
            time_limit: None,
            mu_init: 0.1,
            unbounded_objective: -1e20,
            scaling: true,
            verbosity: Verbosity::Quiet,
            linear_solver: LinearSolver::Auto,
            callback: None,
        }
    }
}

impl fmt::Debug for NlpOptions {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("NlpOptions")
            .field("tolerance", &self.tolerance)
            .field("acceptable_tolerance", &self.acceptable_tolerance)
            .field("acceptable_iterations", &self.acceptable_iterations)
            .field("constraint_tolerance", &self.constraint_tolerance)
            .field("max_iterations", &self.max_iterations)
            .field("time_limit", &self.time_limit)
            .field("mu_init", &self.mu_init)
            .field("unbounded_objective", &self.unbounded_objective)
            .field("scaling", &self.scaling)
            .field("verbosity", &self.verbosity)
            .field("linear_solver", &self.linear_solver)
            .field("callback", &self.callback.as_ref().map(|_| "FnMut"))
            .finish()
    }
}

impl NlpOptions {
    /// Sets [`tolerance`](Self::tolerance).
    pub fn with_tolerance(mut self, tolerance: f64) -> Self {
        self.tolerance = tolerance;
        self
    }

    /// Sets [`max_iterations`](Self::max_iterations).
    pub fn with_max_iterations(mut self, max_iterations: usize) -> Self {
        self.max_iterations = max_iterations;
        self
    }

    /// Sets [`time_limit`](Self::time_limit).
    pub fn with_time_limit(mut self, limit: Duration) -> Self {
        self.time_limit = Some(limit);
        self
    }

    /// Sets [`verbosity`](Self::verbosity).
    pub fn with_verbosity(mut self, verbosity: Verbosity) -> Self {
        self.verbosity = verbosity;
        self
    }

    /// Sets [`linear_solver`](Self::linear_solver).
    pub fn with_linear_solver(mut self, linear_solver: LinearSolver) -> Self {
        self.linear_solver = linear_solver;
        self
    }

    /// Sets [`callback`](Self::callback).
    pub fn with_callback(
        mut self,
        callback: impl FnMut(&IterationSummary) -> ControlFlow<()> + Send + 'static,
    ) -> Self {
        self.callback = Some(Box::new(callback));
        self
    }

    /// Checks every option's domain.
    ///
    /// # Errors
    /// [`Error::InvalidOption`] naming the first option out of its domain.
    pub fn validate(&self) -> Result<()> {
        let bad =
            |name: &str, reason: &str| Err(Error::InvalidOption { name: name.into(), reason: reason.into() });
        let positive = |x: f64| x.is_finite() && x > 0.0;
        if !positive(self.tolerance) {
            return bad("tolerance", "must be finite and positive");
        }
        if !positive(self.acceptable_tolerance) || self.acceptable_tolerance < self.tolerance {
            return bad("acceptable_tolerance", "must be finite and not smaller than `tolerance`");
        }
        if !positive(self.constraint_tolerance) {
            return bad("constraint_tolerance", "must be finite and positive");
        }
        if !positive(self.mu_init) {
            return bad("mu_init", "must be finite and positive");
        }
        if !(self.unbounded_objective.is_finite() && self.unbounded_objective < 0.0) {
            return bad("unbounded_objective", "must be finite and negative");
        }
        if self.time_limit == Some(Duration::ZERO) {
            return bad("time_limit", "must be positive when given");
        }
        Ok(())
    }
}
