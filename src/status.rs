//! The numerical outcome of a solver or an estimator, shared by every module.
//!
//! Misuse is an [`Error`](crate::Error); a numerical outcome — converged or not — is a
//! [`Status`] in a report (DESIGN.md, "Misuse is an error, non-convergence is a status").

use serde::{Deserialize, Serialize};

/// How a solver or an estimator ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
#[non_exhaustive]
pub enum Status {
    /// Converged to the requested tolerance (for an NLP: the optimality error below
    /// `tolerance` and the constraint violation below `constraint_tolerance`).
    Converged,
    /// Converged to a looser, "acceptable" tolerance (for an NLP: the optimality error stayed
    /// below `acceptable_tolerance` for `acceptable_iterations` iterations, or the solver
    /// stalled at such a point).
    Acceptable,
    /// Stopped at the iteration limit.
    MaxIterations,
    /// Stopped at the time limit.
    TimeLimit,
    /// The problem was found (locally) infeasible: the constraint violation cannot be reduced
    /// and the gradient of $\tfrac12\lVert c\rVert^2$ (projected on the bounds) vanishes.
    Infeasible,
    /// The objective was found unbounded (below the unbounded threshold at a feasible point).
    Unbounded,
    /// A numerical failure (singular system, failed line search, unrealizable moments, …)
    /// from which no recovery worked.
    NumericalFailure,
    /// The problem's functions returned non-finite values where no fallback was possible
    /// (at the initial point, or in the Hessian).
    EvaluationError,
    /// Stopped by a user callback.
    UserStop,
    /// The estimator ended, but its estimate is degenerate: an estimated parameter ran to a
    /// bound of its prior, its standard deviation is not finite or huge (the Hessian at the
    /// solution is near singular), or a noise parameter was estimated jointly with the path by
    /// the euler or trapezoidal transcription (a joint MAP that shrinks G(θ) towards zero). A
    /// note names the parameter and the reason.
    Degenerate,
    /// The estimate's density reaches the edge of the grid of an exact grid method (more than
    /// 10⁻³ of its mass in the outer cells at some time), or of the box of a closure on a box
    /// (more than 10⁻³ of its mass near an end of an axis, and a wider box moves the means
    /// beyond the check's tolerance, or the sweeps failed with the density there, after the
    /// widenings allowed): the grid cuts the density off
    /// and the estimate is not to be trusted. A note or the report's `edge` names the axis and
    /// the time; give a wider `--grid` (a closure's `domain`).
    GridEdge,
    /// A closure's quadrature nodes did not resolve its density: the estimate's nodes failed the
    /// quadrature check (on finer nodes the means moved by more than its tolerance, or the
    /// sweeps failed) and the refinements allowed ran out, so the estimate on the last nodes is
    /// not verified. The report's `quadrature` details give the shift; raise `refine` or
    /// `panels`.
    Unresolved,
}

impl Status {
    /// Every status.
    pub const ALL: [Status; 12] = [
        Status::Converged,
        Status::Acceptable,
        Status::MaxIterations,
        Status::TimeLimit,
        Status::Infeasible,
        Status::Unbounded,
        Status::NumericalFailure,
        Status::EvaluationError,
        Status::UserStop,
        Status::Degenerate,
        Status::GridEdge,
        Status::Unresolved,
    ];

    /// Whether the result can be used as a converged one.
    pub fn is_success(self) -> bool {
        matches!(self, Status::Converged | Status::Acceptable)
    }

    /// What the status means, in one sentence for users (`onsager --help`, README).
    pub fn description(self) -> &'static str {
        match self {
            Status::Converged => "converged to the requested tolerance",
            Status::Acceptable => {
                "converged to a looser, acceptable tolerance (the solver stalled close to the requested one); \
                 usable, counted as a success"
            }
            Status::MaxIterations => "stopped at the iteration limit before converging",
            Status::TimeLimit => "stopped at the time limit before converging",
            Status::Infeasible => "the problem was found (locally) infeasible",
            Status::Unbounded => "the objective was found unbounded below",
            Status::NumericalFailure => {
                "a numerical failure (singular system, failed line search, unrealizable moments, …) \
                 from which no recovery worked; a path, if written, is partial or unreliable"
            }
            Status::EvaluationError => "the model returned non-finite values where no fallback was possible",
            Status::UserStop => "stopped by a user callback",
            Status::Degenerate => {
                "an estimated parameter ran to a bound of its prior or its sd is not finite, or a noise \
                 parameter was estimated where the transcription cannot identify it; the report's notes \
                 name it"
            }
            Status::GridEdge => {
                "the density of a grid estimator reaches the grid's edge (or that of a closure its box's), so \
                 the estimate is cut off; widen `--grid` (a closure's `domain`)"
            }
            Status::Unresolved => {
                "a closure's nodes did not resolve its density (finer nodes moved the estimate by more than the \
                 check's tolerance, or its sweeps failed on them, and the refinements ran out); raise `refine` or \
                 `panels`"
            }
        }
    }

    /// The statuses with their descriptions, one per line (`  name  description`), for help
    /// texts.
    pub fn glossary() -> String {
        let width = Status::ALL.iter().map(|s| s.name().len()).max().unwrap_or(0);
        Status::ALL.iter().map(|s| format!("  {:<width$}  {}\n", s.name(), s.description())).collect()
    }

    /// The status's name as written in reports and tables.
    pub fn name(self) -> &'static str {
        match self {
            Status::Converged => "converged",
            Status::Acceptable => "acceptable",
            Status::MaxIterations => "max-iterations",
            Status::TimeLimit => "time-limit",
            Status::Infeasible => "infeasible",
            Status::Unbounded => "unbounded",
            Status::NumericalFailure => "numerical-failure",
            Status::EvaluationError => "evaluation-error",
            Status::UserStop => "user-stop",
            Status::Degenerate => "degenerate",
            Status::GridEdge => "grid-edge",
            Status::Unresolved => "unresolved",
        }
    }
}

impl std::fmt::Display for Status {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_the_serde_names() {
        for s in Status::ALL {
            assert_eq!(serde_json::to_string(&s).unwrap(), format!("\"{}\"", s.name()));
            assert_eq!(s.is_success(), matches!(s, Status::Converged | Status::Acceptable));
            let line =
                Status::glossary().lines().find(|l| l.trim_start().starts_with(s.name())).map(String::from);
            assert!(line.unwrap().ends_with(s.description()), "{s} in the glossary");
        }
    }

    #[test]
    fn the_readme_defines_every_status() {
        let readme = include_str!("../README.md");
        for s in Status::ALL {
            let row = format!("| `{}` | {} |", s.name(), s.description());
            assert!(readme.contains(&row), "README.md lacks the row {row}");
        }
    }
}
