//! `onsager estimate --method ekf|eks|ukf|uks|pem|particle`: the baselines.

use onsager::estimate::PathEstimate;
use onsager::Result;

use super::estimate::{not_available, CliProblem, EstimateArgs};

/// Runs a baseline method.
pub fn run(args: &EstimateArgs, problem: &CliProblem<'_>) -> Result<PathEstimate> {
    let _ = problem;
    Err(not_available(args.method, 8))
}
