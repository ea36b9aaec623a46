//! `onsager simulate`.

use std::path::PathBuf;

use clap::Args;
use rand::rngs::StdRng;
use rand::SeedableRng;

use onsager::simulate::Scheme;
use onsager::Result;

use super::{create_parent, ModelArgs};

/// Flags of `onsager simulate`.
#[derive(Args, Debug, Clone)]
pub struct SimulateArgs {
    #[command(flatten)]
    pub model: ModelArgs,
    /// Final time (default: the model's).
    #[arg(long, allow_negative_numbers = true)]
    pub t_end: Option<f64>,
    /// Simulation step (default: the model's).
    #[arg(long, allow_negative_numbers = true)]
    pub dt: Option<f64>,
    /// Measurement spacing, a multiple of the step (default: the model's).
    #[arg(long, allow_negative_numbers = true)]
    pub sample_every: Option<f64>,
    /// Integration scheme: `ito-taylor-1.5` or `euler-maruyama`.
    #[arg(long, default_value = "ito-taylor-1.5")]
    pub scheme: Scheme,
    /// Seed of the random number generator.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Write a continuous-time record of intensity R (dY = x dt + R^{1/2} dW of the measured
    /// states; docs/effective-action.md, "Continuous-time records") instead of discrete
    /// measurements: the cell averages on cells of width `--sample-every` from t = 0, at the
    /// cell midpoints, under the first line `# continuous: R=<R>`. The model's likelihood is
    /// not used.
    #[arg(long, value_name = "R", allow_negative_numbers = true)]
    pub continuous: Option<f64>,
    /// Where to write the measurements.
    #[arg(long, default_value = "out/data.csv")]
    pub out: PathBuf,
    /// Where to write the true path (not written if absent).
    #[arg(long)]
    pub truth: Option<PathBuf>,
}

/// The preset's settings and the flags of `onsager simulate` that set them.
const SIMULATE_FLAGS: &[(&str, &str)] = &[
    ("t_end", "--t-end"),
    ("dt", "--dt"),
    ("sample_every", "--sample-every"),
    ("every", "--sample-every"),
    ("first_sample", "--t-end"),
    ("R", "--continuous"),
];

/// Runs `onsager simulate`.
pub fn run(args: &SimulateArgs) -> Result<()> {
    let mut p = args.model.preset()?;
    if let Some(t) = args.t_end {
        p.t_end = t;
    }
    if let Some(dt) = args.dt {
        p.dt = dt;
    }
    if let Some(s) = args.sample_every {
        p.sample_every = s;
    }
    p.validate().map_err(|e| super::as_flags(e, SIMULATE_FLAGS))?;
    let mut rng = StdRng::seed_from_u64(args.seed);
    let flags = |e| super::as_flags(e, SIMULATE_FLAGS);
    let (path, written) = match args.continuous {
        None => {
            let (path, data) = p.simulate(args.scheme, &mut rng).map_err(flags)?;
            create_parent(&args.out)?;
            data.write_csv(&args.out)?;
            (path, format!("{} measurements of {}", data.len(), data.names.join(", ")))
        }
        Some(r) => {
            let (path, record) = p.simulate_record(args.scheme, r, &mut rng).map_err(flags)?;
            create_parent(&args.out)?;
            record.write_csv(&args.out)?;
            let what = format!(
                "a continuous record of {} (R = {r}): {} cell averages on cells of {}",
                record.data.names.join(", "),
                record.data.len(),
                record.cell()
            );
            (path, what)
        }
    };
    outln!(
        "simulated `{}` to t = {} with {} steps of {} ({}), seed {}",
        p.name,
        p.t_end,
        path.len() - 1,
        p.dt,
        args.scheme,
        args.seed
    );
    outln!("wrote {written} to {}", args.out.display());
    if let Some(truth) = &args.truth {
        create_parent(truth)?;
        path.write_csv(truth)?;
        outln!("wrote the true path ({}) to {}", path.names.join(", "), truth.display());
    }
    Ok(())
}
