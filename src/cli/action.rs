//! `onsager estimate --method ksp|mean-optimal`: the exact effective-action estimators.

use onsager::estimate::PathEstimate;
use onsager::Result;

use super::estimate::{not_available, CliProblem, EstimateArgs};

/// Runs an exact grid method.
pub fn run(args: &EstimateArgs, problem: &CliProblem<'_>) -> Result<PathEstimate> {
    let _ = problem;
    Err(not_available(args.method, 6))
}
