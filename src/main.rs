//! The `onsager` command-line tool.
//!
//! With no subcommand it runs the main job on the built-in default: it simulates the
//! double-well model and writes its measurements and true path as CSV files under `out/`.

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

use cli::{estimate::EstimateArgs, experiment::ExperimentArgs, simulate::SimulateArgs};

#[derive(Parser)]
#[command(name = "onsager", version, about = "State-path and parameter estimation in nonlinear SDEs")]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand)]
enum Command {
    /// List the built-in models with their states, parameters and defaults.
    Models,
    /// Simulate a model and write its measurements (and optionally the true path) as CSV.
    Simulate(SimulateArgs),
    /// Estimate the state path (and parameters) of a model from measurements.
    Estimate(EstimateArgs),
    /// Run Monte Carlo experiments (built-in reproductions of the papers or TOML specs).
    Experiment(ExperimentArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Some(Command::Models) => {
            cli::print_models();
            Ok(true)
        }
        Some(Command::Simulate(args)) => cli::simulate::run(&args).map(|()| true),
        Some(Command::Estimate(args)) => cli::estimate::run(&args),
        Some(Command::Experiment(args)) => cli::experiment::run_command(&args).map(|()| true),
        None => {
            // The main job on the built-in default.
            let Some(Command::Simulate(mut args)) = Cli::parse_from(["onsager", "simulate"]).command else {
                unreachable!("`onsager simulate` parses as the simulate command")
            };
            args.out = PathBuf::from("out/double-well.csv");
            args.truth = Some(PathBuf::from("out/double-well-truth.csv"));
            cli::simulate::run(&args).map(|()| true)
        }
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
