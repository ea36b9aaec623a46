//! The `onsager` command-line tool.
//!
//! With no subcommand it runs the main job on the built-in default: it simulates the
//! double-well model (fixed seed), writes its measurements and true path under `out/`, and
//! compares the estimators on them (`onsager compare`: table, `out/compare/compare.png`).

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// `println!` that ignores a closed standard output (e.g. `onsager models | head`) instead of
/// panicking.
macro_rules! outln {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stdout(), $($arg)*);
    }};
}

mod cli;

use cli::{compare::CompareArgs, estimate::EstimateArgs, experiment::ExperimentArgs, simulate::SimulateArgs};

/// The exit codes and the statuses, under `--help`.
fn after_help() -> String {
    format!(
        "Exit codes:\n  0  success (every estimate converged or acceptable)\n  1  bad input or configuration \
         (the message names the flag, or the file and line)\n  2  an estimator ran and did not converge or \
         failed numerically (its status says how)\n\nStatuses of an estimate (reports, tables):\n{}",
        onsager::Status::glossary()
    )
}

#[derive(Parser)]
#[command(name = "onsager", version, about = "State-path and parameter estimation in nonlinear SDEs")]
#[command(after_help = after_help())]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand)]
enum Command {
    /// List the built-in models with their states, parameters and defaults, or check a model
    /// file and print what it declares (`--check FILE.toml`).
    Models(cli::ModelsArgs),
    /// Simulate a model and write its measurements (and optionally the true path) as CSV.
    #[command(allow_negative_numbers = true, after_help = after_help())]
    Simulate(SimulateArgs),
    /// Estimate the state path (and parameters) of a model from measurements.
    #[command(allow_negative_numbers = true, after_help = after_help())]
    Estimate(EstimateArgs),
    /// Run several estimators on the same data: one table (RMSE against the truth, the exact KSP
    /// mean and the exact mean-optimal estimate), the paths and a plot.
    #[command(allow_negative_numbers = true, after_help = after_help())]
    Compare(CompareArgs),
    /// Run Monte Carlo experiments (built-in reproductions of the papers or TOML specs).
    #[command(allow_negative_numbers = true, after_help = after_help())]
    Experiment(ExperimentArgs),
}

/// The main job on the built-in default: simulate the double well (fixed seed), then compare
/// the estimators on its measurements against the true path.
fn main_job() -> onsager::Result<bool> {
    let Some(Command::Simulate(mut sim)) = Cli::parse_from(["onsager", "simulate"]).command else {
        unreachable!("`onsager simulate` parses as the simulate command")
    };
    sim.out = PathBuf::from("out/double-well.csv");
    sim.truth = Some(PathBuf::from("out/double-well-truth.csv"));
    cli::simulate::run(&sim)?;
    let Some(Command::Compare(mut cmp)) =
        Cli::parse_from(["onsager", "compare", "--data", "out/double-well.csv"]).command
    else {
        unreachable!("`onsager compare` parses as the compare command")
    };
    cmp.truth = sim.truth;
    cli::compare::run(&cmp)
}

fn main() -> ExitCode {
    // Usage errors exit with 1 like every other error (clap's own code, 2, means "did not
    // converge" here); --help and --version exit with 0.
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            let _ = e.print();
            return if e.use_stderr() { ExitCode::FAILURE } else { ExitCode::SUCCESS };
        }
    };
    let result = match cli.command {
        Some(Command::Models(args)) => cli::models(&args).map(|()| true),
        Some(Command::Simulate(args)) => cli::simulate::run(&args).map(|()| true),
        Some(Command::Estimate(args)) => cli::estimate::run(&args),
        Some(Command::Compare(args)) => cli::compare::run(&args),
        Some(Command::Experiment(args)) => match cli::experiment::run_command(&args) {
            Ok(cli::experiment::Finished::Done) => Ok(true),
            // A merge with missing rows: they are listed on stderr; nothing was written.
            Ok(cli::experiment::Finished::Incomplete) => return ExitCode::FAILURE,
            Err(e) => Err(e),
        },
        None => main_job(),
    };
    match result {
        Ok(true) => ExitCode::SUCCESS,
        // The command ran but its numerical outcome is not a success (e.g. not converged).
        Ok(false) => ExitCode::from(2),
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
