//! `onsager compare`: several estimators on the same data, one table, one plot.

use std::path::PathBuf;

use clap::Args;

use onsager::compare::{compare, default_methods, CompareOptions, Comparison};
use onsager::data::{Dataset, StatePath};
use onsager::methods::Method;
use onsager::model::{Observation, Sde};
use onsager::{Error, Result};

use super::estimate::parse_method;
use super::{create_parent, ModelArgs};

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
    /// Methods to compare, comma-separated (default: ksp and mean-optimal for one or two
    /// states, the four closures for one state, jme, mee, uks).
    #[arg(long, value_delimiter = ',', value_parser = parse_method)]
    pub methods: Vec<Method>,
    /// Grid of the exact methods (default: the data range with margins).
    #[arg(long)]
    pub grid: Option<String>,
    /// Seed of the methods that draw random numbers.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Where to write paths.csv, summary.json, compare.svg and compare.png.
    #[arg(long, default_value = "out/compare")]
    pub out_dir: PathBuf,
}

fn cell(x: Option<f64>, digits: usize) -> String {
    x.filter(|v| v.is_finite()).map_or("-".into(), |v| format!("{v:.digits$}"))
}

/// Prints the comparison table.
pub fn print_table(c: &Comparison, with_truth: bool, bistable: bool) {
    let mut header = format!("{:<19} {:<17}", "method", "status");
    if with_truth {
        header.push_str(&format!(" {:>10}", "rmse_truth"));
    }
    header.push_str(&format!(" {:>9} {:>11}", "rmse_ksp", "rmse_m-opt"));
    if with_truth && bistable {
        header.push_str(&format!(" {:>9}", "same_well"));
    }
    header.push_str(&format!(" {:>9}", "seconds"));
    outln!("{header}");
    outln!("{}", "-".repeat(header.len()));
    for r in &c.rows {
        let mut line = format!("{:<19} {:<17}", r.method.name(), r.status);
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
            outln!("  {}: {e}", r.method.name());
        }
        for n in &r.notes {
            outln!("  {}: note: {n}", r.method.name());
        }
    }
}

/// Runs `onsager compare`; `Ok(false)` when a method failed or did not converge.
pub fn run(args: &CompareArgs) -> Result<bool> {
    let preset = args.model.preset()?;
    let data = Dataset::read_csv_for(&args.data, &preset.observation.output_names())?;
    let truth = args.truth.as_ref().map(StatePath::read_csv).transpose()?;
    let problem = preset.problem(&data, &[]);
    problem.validate()?;
    let methods = if args.methods.is_empty() { default_methods(&problem) } else { args.methods.clone() };
    let mut options = CompareOptions::default();
    options.grid = args.grid.clone();
    options.seed = args.seed;
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
        methods.iter().map(|m| m.name()).collect::<Vec<_>>().join(", "),
        preset.name,
        data.len(),
        data.names.join(", ")
    );
    let c = compare(&problem, &methods, truth.as_ref(), &options)?;
    print_table(&c, truth.is_some(), options.barrier.is_some());
    let dir = &args.out_dir;
    create_parent(&dir.join("x"))?;
    c.write_paths_csv(&dir.join("paths.csv"), &names)?;
    let summary = serde_json::to_string_pretty(&c.summary_json()).expect("a JSON value serialises");
    let summary_path = dir.join("summary.json");
    std::fs::write(&summary_path, summary + "\n")
        .map_err(|source| Error::Io { path: summary_path, source })?;
    let title = format!("{}: {} measurements", preset.name, data.len());
    c.figure(&names, &data, &preset.observation, truth.as_ref(), &title).write(&dir.join("compare"))?;
    outln!("wrote {0}/paths.csv, {0}/summary.json, {0}/compare.svg and {0}/compare.png", dir.display());
    Ok(c.rows.iter().all(|r| r.status == "converged" || r.status == "acceptable"))
}
