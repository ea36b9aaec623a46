//! `onsager compare`: several estimators on the same data, one table, one plot.

use std::path::PathBuf;

use clap::Args;

use onsager::action::GridSpec;
use onsager::compare::{compare, default_estimators, CompareOptions, Comparison};
use onsager::data::StatePath;
use onsager::estimate::{EstimationProblem, RowStatus};
use onsager::estimator::{parse_list, read_list, Labelled, NotApplicable};
use onsager::model::Sde;
use onsager::{Error, Result};

use super::{create_parent, LimitArgs, ModelArgs};

/// The estimators of `--methods`, parsed at the door.
#[derive(Debug, Clone)]
pub struct EstimatorList(pub Vec<Labelled>);

/// Parses `--methods` ([`parse_list`]).
fn parse_methods(s: &str) -> std::result::Result<EstimatorList, String> {
    parse_list(s).map(EstimatorList).map_err(|e| e.to_string())
}

/// Flags of `onsager compare`.
#[derive(Args, Debug, Clone)]
pub struct CompareArgs {
    #[command(flatten)]
    pub model: ModelArgs,
    /// Measurements CSV (`t,<outputs>`).
    #[arg(long)]
    pub data: PathBuf,
    /// The true path (`t,<states>`), e.g. from `onsager simulate --truth`: adds the RMSE against
    /// it and, for bistable models, the fraction of times on the true well's side.
    #[arg(long)]
    pub truth: Option<PathBuf>,
    /// Estimators to compare, each with its own options:
    /// `METHOD[:NAME=VALUE,…],METHOD…`, e.g. `exp-closure:moments=6,jme:transcription=trapezoidal,uks`
    /// (a value with commas in double quotes; `label=…` names a row). Default: those of ksp,
    /// mean-optimal, the five closures, jme, mee and uks that apply to the model, its likelihood
    /// and `--estimate`; the others are listed under the table with the reason. A method named
    /// here that does not apply is an error.
    #[arg(long, value_name = "LIST", value_parser = parse_methods)]
    pub methods: Option<EstimatorList>,
    /// The estimators from a file instead: TOML `[[estimators]]` tables with `method`, `label`
    /// and `options = { … }` (as in experiment specs), or JSON `{"estimators": [...]}`.
    #[arg(long, value_name = "FILE", conflicts_with = "methods")]
    pub estimators: Option<PathBuf>,
    /// Parameters to estimate, comma-separated names: given to the methods that estimate
    /// parameters (jme, mee, pem); the others do not apply and are skipped (or refused when
    /// asked for by name).
    #[arg(long, value_delimiter = ',')]
    pub estimate: Vec<String>,
    /// Grid of the exact methods that do not set their own (default: the data range with
    /// margins). With it, the default estimators include the grid methods on three-state models
    /// and on models with a state that is not measured.
    #[arg(long, value_parser = super::estimate::parse_grid)]
    pub grid: Option<GridSpec>,
    #[command(flatten)]
    pub limits: LimitArgs,
    /// Seed of the methods that draw random numbers.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Memory limit of each estimator's structures (`4GiB`, `512MB`, `unlimited`).
    #[arg(long, default_value = "4GiB", value_name = "SIZE")]
    pub max_memory: onsager::estimate::MemoryLimit,
    /// Where to write paths.csv, summary.json, compare.svg and compare.png.
    #[arg(long, default_value = "out/compare")]
    pub out_dir: PathBuf,
}

impl CompareArgs {
    /// The estimators of the flags (`--methods`, `--estimators` or the defaults), with `--grid`
    /// given to the exact methods that have no grid of their own.
    fn estimators(
        &self,
        problem: &EstimationProblem<'_, impl Sde, onsager::model::observation::StateMeasurement>,
    ) -> Result<(Vec<Labelled>, Vec<NotApplicable>)> {
        let (mut list, skipped, flag) = match (&self.methods, &self.estimators) {
            (Some(list), _) => (list.0.clone(), Vec::new(), "--methods"),
            (None, Some(file)) => (read_list(file)?, Vec::new(), "--estimators"),
            (None, None) => {
                let (chosen, skipped) = default_estimators(problem, self.grid.as_ref());
                (chosen, skipped, "")
            }
        };
        if let Some(grid) = &self.grid {
            for e in &mut list {
                e.estimator = e.estimator.clone().with_default_grid(grid);
            }
        }
        for e in &mut list {
            e.estimator = e.estimator.clone().with_limits(self.limits.limits())?;
        }
        if !flag.is_empty() {
            for e in &list {
                e.estimator.applies_to(problem).map_err(|why| Error::InvalidOption {
                    name: flag.into(),
                    reason: format!("`{}`: {}", e.label, why.reason),
                })?;
            }
        }
        Ok((list, skipped))
    }
}

fn cell(x: Option<f64>, digits: usize) -> String {
    x.filter(|v| v.is_finite()).map_or("-".into(), |v| format!("{v:.digits$}"))
}

/// Prints the comparison table.
pub fn print_table(c: &Comparison, with_truth: bool, bistable: bool) {
    let width = c.rows.iter().map(|r| r.label.chars().count()).max().unwrap_or(0).max(19);
    let mut header = format!("{:<width$} {:<17}", "method", "status");
    if with_truth {
        header.push_str(&format!(" {:>10}", "rmse_truth"));
    }
    header.push_str(&format!(" {:>9} {:>11}", "rmse_ksp", "rmse_m-opt"));
    if with_truth && bistable {
        header.push_str(&format!(" {:>9}", "same_well"));
    }
    header.push_str(&format!(" {:>9}", "seconds"));
    outln!("{header}");
    outln!("{}", "-".repeat(header.chars().count()));
    for r in &c.rows {
        let mut line = format!("{:<width$} {:<17}", r.label, r.status.name());
        if with_truth {
            line.push_str(&format!(" {:>10}", cell(r.rmse_truth, 4)));
        }
        line.push_str(&format!(" {:>9} {:>11}", cell(r.rmse_ksp, 4), cell(r.rmse_mean_optimal, 4)));
        if with_truth && bistable {
            line.push_str(&format!(" {:>9}", cell(r.same_well, 3)));
        }
        line.push_str(&format!(" {:>9.3}", r.seconds));
        outln!("{line}");
    }
    for r in &c.rows {
        if let Some(e) = &r.error {
            outln!("  {}: {e}", r.label);
        }
        for n in &r.notes {
            outln!("  {}: note: {n}", r.label);
        }
    }
    if !c.skipped.is_empty() {
        outln!("not compared (they do not apply):");
        for s in &c.skipped {
            outln!("  {}: {}", s.method, s.reason);
        }
    }
}

/// Runs `onsager compare`; `Ok(false)` when an estimator did not converge or failed
/// numerically; an error (after writing the table and files) when an estimator could not run.
pub fn run(args: &CompareArgs) -> Result<bool> {
    let mut preset = args.model.preset()?;
    let data = super::read_data(&args.data, &mut preset, args.model.likelihood.is_some())?;
    let truth = args.truth.as_ref().map(StatePath::read_csv).transpose()?;
    if let (Some(t), Some(file)) = (&truth, &args.truth) {
        super::warn_if_truth_short(t, file, &data);
    }
    let estimate = super::estimate::parameter_indices(&preset, &args.estimate)?;
    let problem = EstimationProblem {
        seed: args.seed,
        max_memory: args.max_memory,
        ..preset.problem(&data, &estimate)
    };
    problem.validate()?;
    let (estimators, skipped) = args.estimators(&problem)?;
    let mut options = CompareOptions::default();
    options.barrier = preset.well_barrier();
    let names = preset.model.state_names();
    if let Some(t) = &truth {
        if t.names != names {
            return Err(Error::InvalidOption {
                name: "--truth".into(),
                reason: format!(
                    "has states {} but `{}` has {}",
                    t.names.join(", "),
                    preset.name,
                    names.join(", ")
                ),
            });
        }
    }
    outln!(
        "comparing {} on {} ({} measurements of {})",
        estimators.iter().map(|e| e.label.as_str()).collect::<Vec<_>>().join(", "),
        preset.name,
        data.len(),
        data.names.join(", ")
    );
    let mut c = compare(&problem, &estimators, truth.as_ref(), &options)?;
    c.skipped = skipped;
    print_table(&c, truth.is_some(), options.barrier.is_some());
    let dir = &args.out_dir;
    create_parent(&dir.join("x"))?;
    c.write_paths_csv(&dir.join("paths.csv"), &names)?;
    let summary = serde_json::to_string_pretty(&c.summary()).expect("a summary serialises");
    let summary_path = dir.join("summary.json");
    std::fs::write(&summary_path, summary + "\n")
        .map_err(|source| Error::Io { path: summary_path, source })?;
    let title = format!("{}: {} measurements", preset.name, data.len());
    c.figure(&names, &data, &preset.observation, truth.as_ref(), &title).write(&dir.join("compare"))?;
    outln!("wrote {0}/paths.csv, {0}/summary.json, {0}/compare.svg and {0}/compare.png", dir.display());
    let failed: Vec<&str> =
        c.rows.iter().filter(|r| r.status == RowStatus::Error).map(|r| r.label.as_str()).collect();
    if !failed.is_empty() {
        return Err(Error::InvalidOption {
            name: if args.estimators.is_some() { "--estimators" } else { "--methods" }.into(),
            reason: format!("{} could not run (see the messages under the table)", failed.join(", ")),
        });
    }
    Ok(c.rows.iter().all(|r| r.status.is_success()))
}
