//! `onsager experiment list | run`.

use std::io::{IsTerminal, Write};
use std::path::PathBuf;
use std::sync::Mutex;

use clap::{Args, Subcommand};

use onsager::experiment::builtin::builtin_text;
use onsager::experiment::{run, Experiment, Progress, RunOptions, BUILTIN};
use onsager::{Error, Result};

/// `onsager experiment`.
#[derive(Args, Debug, Clone)]
pub struct ExperimentArgs {
    #[command(subcommand)]
    pub command: ExperimentCommand,
}

/// The subcommands of `onsager experiment`.
#[derive(Subcommand, Debug, Clone)]
pub enum ExperimentCommand {
    /// List the built-in experiments.
    List,
    /// Run a built-in experiment (by name) or a spec file (`FILE.toml`).
    Run(RunArgs),
}

/// Flags of `onsager experiment run`.
#[derive(Args, Debug, Clone)]
pub struct RunArgs {
    /// A built-in experiment (see `onsager experiment list`) or a TOML spec file.
    pub experiment: String,
    /// Replicates per scenario (default: the spec's).
    #[arg(long)]
    pub replicates: Option<usize>,
    /// Seed (default: the spec's).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Worker threads (default: one per core). The results do not depend on it.
    #[arg(long, default_value_t = 0)]
    pub jobs: usize,
    /// Output folder (default `out/experiments/NAME`).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Continue an interrupted run in the output folder.
    #[arg(long)]
    pub resume: bool,
    /// Run the spec's quick version (few replicates, short horizons).
    #[arg(long)]
    pub quick: bool,
}

fn load(experiment: &str) -> Result<Experiment> {
    if experiment.ends_with(".toml") || std::path::Path::new(experiment).is_file() {
        Experiment::from_path(std::path::Path::new(experiment)).map_err(|e| match e {
            Error::InvalidOption { name, reason } => {
                Error::InvalidOption { name, reason: format!("in {experiment}: {reason}") }
            }
            other => other,
        })
    } else {
        Experiment::from_toml(builtin_text(experiment)?)
    }
}

fn duration(s: f64) -> String {
    let s = s.max(0.0).round() as u64;
    if s >= 3600 {
        format!("{}h{:02}m", s / 3600, (s % 3600) / 60)
    } else {
        format!("{}m{:02}s", s / 60, s % 60)
    }
}

/// Runs `onsager experiment`.
pub fn run_command(args: &ExperimentArgs) -> Result<()> {
    match &args.command {
        ExperimentCommand::List => {
            for (name, text) in BUILTIN {
                let experiment = Experiment::from_toml(text)?;
                let spec = &experiment.spec;
                outln!("{name} — {}", spec.description);
                if !spec.source.is_empty() {
                    outln!("  source: {}", spec.source);
                }
                let estimators: Vec<String> = spec.estimators.iter().map(|e| e.label()).collect();
                outln!("  estimators: {}", estimators.join(", "));
                let scenarios = experiment.scenarios(false)?.len();
                outln!("  scenarios: {scenarios}, replicates: {}, seed: {}", spec.replicates, spec.seed);
            }
            Ok(())
        }
        ExperimentCommand::Run(a) => run_experiment(a),
    }
}

fn run_experiment(a: &RunArgs) -> Result<()> {
    let experiment = load(&a.experiment)?;
    let spec = &experiment.spec;
    let out = a.out.clone().unwrap_or_else(|| {
        let dir = PathBuf::from("out/experiments").join(&spec.name);
        if a.quick {
            dir.join("quick")
        } else {
            dir
        }
    });
    let mut options = RunOptions::new(out.clone());
    options.jobs = a.jobs;
    options.resume = a.resume;
    options.quick = a.quick;
    options.replicates = a.replicates;
    options.seed = a.seed;
    let terminal = std::io::stderr().is_terminal();
    let last_width = Mutex::new(0usize);
    let progress = |p: &Progress| {
        let r = &p.row;
        let new = p.done - p.resumed;
        let eta = if new > 0 { p.elapsed / new as f64 * (p.total - p.done) as f64 } else { f64::NAN };
        let mut err = std::io::stderr().lock();
        if terminal {
            let width = 30;
            let filled = (p.done * width).checked_div(p.total).unwrap_or(width);
            let line = format!(
                "\r[{}{}] {}/{} rows  {} elapsed  ETA {}  {} r{} {}: {}",
                "#".repeat(filled),
                "-".repeat(width - filled),
                p.done,
                p.total,
                duration(p.elapsed),
                if eta.is_finite() { duration(eta) } else { "?".into() },
                r.scenario,
                r.replicate,
                r.estimator,
                r.status
            );
            let mut last = last_width.lock().unwrap_or_else(|e| e.into_inner());
            let pad = last.saturating_sub(line.len());
            *last = line.len();
            let _ = write!(err, "{line}{}", " ".repeat(pad));
            if p.done == p.total {
                let _ = writeln!(err);
            }
        } else {
            let _ = writeln!(
                err,
                "[{}/{}] {} replicate {} {}: {} ({:.2} s){}",
                p.done,
                p.total,
                r.scenario,
                r.replicate,
                r.estimator,
                r.status,
                r.solve_seconds,
                if r.message.is_empty() { String::new() } else { format!(" — {}", r.message) }
            );
        }
    };
    outln!("experiment `{}`{} → {}", spec.name, if a.quick { " (quick)" } else { "" }, out.display());
    let report = run(&experiment, &options, &progress)?;
    if report.resumed > 0 {
        outln!("kept {} rows of the earlier run", report.resumed);
    }
    outln!("wrote {} rows to {}", report.written, report.results.display());
    if let Some(s) = &report.summary {
        outln!("summary: {}", s.display());
    }
    if !report.plots.is_empty() {
        outln!("plots: {} figures (SVG and PNG) in {}", report.plots.len(), out.join("plots").display());
    }
    Ok(())
}
