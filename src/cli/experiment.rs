//! `onsager experiment list | run | merge | slurm`.

use std::io::{IsTerminal, Write};
use std::path::PathBuf;
use std::sync::Mutex;

use clap::{Args, Subcommand};

use onsager::experiment::slurm::{self, SlurmOptions};
use onsager::experiment::{
    merge, run, Experiment, MergeOptions, MergeReport, MergeStatus, Missing, Progress, RunOptions, Shard,
    BUILTIN,
};
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
    /// Run a built-in experiment (by name) or a spec file (`FILE.toml`), whole or one shard.
    Run(RunArgs),
    /// Merge the shards of an output folder (`DIR/shards/I-of-N`) into `results.csv`,
    /// `summary.json` and the plots, as an unsharded run writes them; lists the missing
    /// replicates (exit code 1) when shards are missing or unfinished.
    Merge(MergeArgs),
    /// Write Slurm scripts for a sharded run: a job array (one shard per task, `--resume`) and
    /// a merge job that waits for it; prints the `sbatch` commands.
    Slurm(SlurmArgs),
}

/// Flags of `onsager experiment merge`.
#[derive(Args, Debug, Clone)]
pub struct MergeArgs {
    /// The output folder the shards wrote to (`--out` of `experiment run --shard`).
    pub dir: PathBuf,
}

/// Flags of `onsager experiment slurm`.
#[derive(Args, Debug, Clone)]
pub struct SlurmArgs {
    /// A built-in experiment (see `onsager experiment list`) or a TOML spec file.
    pub experiment: String,
    /// Number of shards, one job-array task each.
    #[arg(long, default_value_t = 10)]
    pub shards: usize,
    /// CPUs per task: the worker threads of each shard.
    #[arg(long, default_value_t = 1)]
    pub cpus_per_task: usize,
    /// Wall-time limit per task (Slurm format: MM, HH:MM:SS, D-HH:MM, …; default: the
    /// partition's).
    #[arg(long)]
    pub time: Option<String>,
    /// Partition (default: the cluster's default).
    #[arg(long)]
    pub partition: Option<String>,
    /// Output folder, on a file system the compute nodes share (default
    /// `out/experiments/NAME`).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Replicates per scenario (default: the spec's).
    #[arg(long)]
    pub replicates: Option<usize>,
    /// Seed (default: the spec's).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Run the spec's quick version.
    #[arg(long)]
    pub quick: bool,
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
    /// Run only shard I of N (from 0) into `OUT/shards/I-of-N`: the (scenario, replicate)
    /// units k = replicate·S + scenario (S scenarios) with (k + ⌊k/L⌋) mod N = I, L = lcm(S, N)
    /// (docs/cluster.md); merge the shards with `onsager experiment merge OUT`.
    #[arg(long, value_name = "I/N")]
    pub shard: Option<Shard>,
}

/// How `onsager experiment` ended, beyond errors.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Finished {
    /// Done.
    Done,
    /// A merge found rows missing (listed on stderr): exit code 1.
    Incomplete,
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
pub fn run_command(args: &ExperimentArgs) -> Result<Finished> {
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
            Ok(Finished::Done)
        }
        ExperimentCommand::Run(a) => run_experiment(a).map(|()| Finished::Done),
        ExperimentCommand::Merge(a) => merge_shards(a),
        ExperimentCommand::Slurm(a) => write_slurm(a).map(|()| Finished::Done),
    }
}

fn run_experiment(a: &RunArgs) -> Result<()> {
    let experiment = onsager::experiment::load(&a.experiment)?;
    let spec = &experiment.spec;
    let out = a.out.clone().unwrap_or_else(|| onsager::experiment::default_out(&spec.name, a.quick));
    let mut options = RunOptions::new(out.clone());
    options.jobs = a.jobs;
    options.resume = a.resume;
    options.quick = a.quick;
    options.replicates = a.replicates;
    options.seed = a.seed;
    options.shard = a.shard;
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
    match a.shard {
        Some(s) => outln!(
            "experiment `{}`{}, shard {s} → {}",
            spec.name,
            if a.quick { " (quick)" } else { "" },
            s.folder(&out).display()
        ),
        None => {
            outln!("experiment `{}`{} → {}", spec.name, if a.quick { " (quick)" } else { "" }, out.display())
        }
    }
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
    if let (Some(s), true) = (a.shard, report.complete) {
        outln!(
            "shard {s} complete ({} rows); once every shard is: onsager experiment merge {}",
            report.total,
            out.display()
        );
    }
    Ok(())
}

/// Replicates as ranges: `0-3, 7, 9-10`.
fn ranges(replicates: &[usize]) -> String {
    let mut parts: Vec<String> = Vec::new();
    let mut i = 0;
    while i < replicates.len() {
        let mut j = i;
        while j + 1 < replicates.len() && replicates[j + 1] == replicates[j] + 1 {
            j += 1;
        }
        parts.push(if j > i {
            format!("{}-{}", replicates[i], replicates[j])
        } else {
            replicates[i].to_string()
        });
        i = j + 1;
    }
    parts.join(", ")
}

/// The missing rows on stderr, by shard and scenario, with the commands that rerun them.
fn print_missing(dir: &std::path::Path, report: &MergeReport, missing: &[Missing]) {
    let count = report.count;
    let mut err = std::io::stderr().lock();
    let mut shards: Vec<usize> = missing.iter().map(|m| m.shard.index()).collect();
    shards.dedup();
    for &i in &shards {
        let of_shard: Vec<&Missing> = missing.iter().filter(|m| m.shard.index() == i).collect();
        let rows: usize = of_shard.iter().map(|m| m.estimators.len()).sum();
        let _ = writeln!(err, "shard {i}/{count}: {rows} rows missing");
        let mut scenarios: Vec<&str> = of_shard.iter().map(|m| m.scenario.as_str()).collect();
        scenarios.sort();
        scenarios.dedup();
        for s in scenarios {
            let reps: Vec<usize> = of_shard.iter().filter(|m| m.scenario == s).map(|m| m.replicate).collect();
            let _ = writeln!(err, "  scenario {s}: replicates {}", ranges(&reps));
        }
    }
    let list: Vec<String> = shards.iter().map(|i| i.to_string()).collect();
    let which =
        if list.len() == 1 { format!("shard {}", list[0]) } else { format!("shards {}", list.join(", ")) };
    let shard = if list.len() == 1 { format!("{}/{count}", list[0]) } else { format!("I/{count}") };
    let _ = writeln!(
        err,
        "rerun {which} with `onsager experiment run {} --replicates {} --seed {}{} --shard {shard} --resume --out {}` \
         (on Slurm: sbatch --array={} {}/array.sbatch), then merge again",
        if BUILTIN.iter().any(|(n, _)| *n == report.experiment) { report.experiment.as_str() } else { "SPEC.toml" },
        report.replicates,
        report.seed,
        if report.quick { " --quick" } else { "" },
        dir.display(),
        list.join(","),
        slurm::folder(dir).display()
    );
}

fn merge_shards(a: &MergeArgs) -> Result<Finished> {
    let report = merge(&MergeOptions::new(&a.dir))?;
    let present: Vec<String> = report.shards.iter().map(|s| s.shard.index().to_string()).collect();
    outln!(
        "experiment `{}`{}: {} of {} shards found ({}), {} of {} rows",
        report.experiment,
        if report.quick { " (quick)" } else { "" },
        report.shards.len(),
        report.count,
        present.join(", "),
        report.rows,
        report.total
    );
    match &report.status {
        MergeStatus::Complete { results, summary, plots } => {
            outln!("merged {} rows into {}", report.rows, results.display());
            outln!("summary: {}", summary.display());
            if !plots.is_empty() {
                outln!("plots: {} figures (SVG and PNG) in {}", plots.len(), a.dir.join("plots").display());
            }
            Ok(Finished::Done)
        }
        MergeStatus::Incomplete { missing } => {
            let rows: usize = missing.iter().map(|m| m.estimators.len()).sum();
            eprintln!(
                "error: cannot merge {}: {rows} of {} rows are missing (nothing written)",
                a.dir.display(),
                report.total
            );
            print_missing(&a.dir, &report, missing);
            Ok(Finished::Incomplete)
        }
    }
}

/// An absolute form of `path` (relative to the current folder), without `.` components.
fn absolute(path: &std::path::Path, flag: &str) -> Result<PathBuf> {
    let abs = std::path::absolute(path).map_err(|source| Error::Io { path: path.to_path_buf(), source })?;
    if abs.as_os_str().is_empty() {
        return Err(Error::invalid(flag, "empty path"));
    }
    Ok(abs)
}

fn write_slurm(a: &SlurmArgs) -> Result<()> {
    let experiment = onsager::experiment::load(&a.experiment)?;
    let name = if std::path::Path::new(&a.experiment).is_file() {
        absolute(std::path::Path::new(&a.experiment), "EXPERIMENT")?.to_string_lossy().into_owned()
    } else {
        a.experiment.clone()
    };
    let out = absolute(
        &a.out.clone().unwrap_or_else(|| onsager::experiment::default_out(&experiment.spec.name, a.quick)),
        "--out",
    )?;
    let program = std::env::current_exe()
        .and_then(|p| p.canonicalize())
        .map_err(|source| Error::Io { path: PathBuf::from("onsager"), source })?;
    let mut options = SlurmOptions::new(name, program, out.clone());
    options.shards = a.shards;
    options.cpus_per_task = a.cpus_per_task;
    options.time = a.time.clone();
    options.partition = a.partition.clone();
    options.quick = a.quick;
    options.replicates = a.replicates;
    options.seed = a.seed;
    let mut experiment = experiment;
    if let Some(r) = a.replicates {
        experiment = experiment.with_replicates(r);
    }
    let scenarios = experiment.scenarios(a.quick)?;
    let units = scenarios.len() * scenarios[0].spec.replicates;
    let files = slurm::write(&options)?;
    outln!(
        "experiment `{}`{}: {} scenarios × {} replicates = {units} units over {} shards",
        experiment.spec.name,
        if a.quick { " (quick)" } else { "" },
        scenarios.len(),
        scenarios[0].spec.replicates,
        a.shards
    );
    if a.shards > units {
        outln!("note: {} of the {} shards get no unit (more shards than units)", a.shards - units, a.shards);
    }
    outln!("wrote {}, {} and {}", files.array.display(), files.merge.display(), files.submit.display());
    outln!("submit both (the merge runs once every task ended well):");
    outln!("  sh {}", files.submit.display());
    outln!("or by hand:");
    outln!("  sbatch --parsable {}    # prints the array's job id, JOB", files.array.display());
    outln!("  sbatch --dependency=afterok:JOB --kill-on-invalid-dep=yes {}", files.merge.display());
    outln!(
        "after a failed or pre-empted task I: sbatch --array=I {}, then the merge again",
        files.array.display()
    );
    Ok(())
}
