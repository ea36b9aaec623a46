//! `onsager estimate --method jme|mee`: the path-space MAP estimators.

use onsager::estimate::PathEstimate;
use onsager::{Error, Result};

use super::estimate::{CliProblem, EstimateArgs};

/// Runs a path-space MAP method.
pub fn run(args: &EstimateArgs, problem: &CliProblem<'_>) -> Result<PathEstimate> {
    let _ = problem;
    Err(Error::InvalidOption {
        name: "--method".into(),
        reason: format!("method `{:?}` is not available yet (issue 4)", args.method).to_lowercase(),
    })
}
