//! `onsager estimate --method ksp|mean-optimal`: the exact effective-action estimators on a grid.

use onsager::action::exact::check_grid_covers;
use onsager::action::fokker_planck::check_model_fits_grid;
use onsager::action::{
    ksp_path_estimate, ksp_smoother, mean_optimal, mean_optimal_path_estimate, ExactOptions, Grid, GridSpec,
};
use onsager::estimate::{default_initial_time, PathEstimate};
use onsager::{Error, Result};

use super::estimate::{CliProblem, EstimateArgs, Method};

/// Runs an exact grid method: `--grid` (required), `--dt` (default: the output step / 4, the
/// output step being the measurement spacing / 10). The initial density is the x0 prior, at
/// [`default_initial_time`] as for every method.
pub fn run(args: &EstimateArgs, problem: &CliProblem<'_>) -> Result<PathEstimate> {
    let spec = args.grid.as_deref().ok_or_else(|| Error::InvalidOption {
        name: "--grid".into(),
        reason: "the grid methods need a grid, e.g. `--grid lo=-2.5,hi=2.5,cells=500` (two states: \
                 `--grid lo=-3;-4,hi=3;4,cells=200;200`)"
            .into(),
    })?;
    let grid = GridSpec::parse(spec)?;
    let mut options = ExactOptions::new(grid.clone()).with_t0(default_initial_time(problem.data));
    if let Some(dt) = args.dt {
        options = options.with_dt(dt);
    }
    let grid = Grid::try_new(grid)?;
    check_model_fits_grid(problem.sde, &grid)?;
    check_grid_covers(&grid, problem.observation, problem.data)?;
    match args.method {
        Method::Ksp => {
            let ksp = ksp_smoother(problem, &options)?;
            Ok(ksp_path_estimate(problem, &ksp))
        }
        Method::MeanOptimal => {
            let mo = mean_optimal(problem, &options)?;
            Ok(mean_optimal_path_estimate(problem, &mo))
        }
        other => Err(Error::InvalidOption {
            name: "--method".into(),
            reason: format!("`{other:?}` is not a grid method (ksp, mean-optimal)"),
        }),
    }
}
