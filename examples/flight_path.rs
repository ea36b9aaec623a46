//! Flight-path reconstruction (`000_74b95e149527c64e.txt` Sec. 4.2) on synthetic records: for
//! each replicate (seed 1, 2, …), simulate 30 s at 25 Hz of the flight-path model with known
//! sensor biases ([`FlightPathSetup::TRUTH`]), then estimate the path jointly with the eight
//! parameters by JME and MEE (Hermite–Simpson, step = sample period, started from the
//! measurements), with the Laplace standard deviations.
//!
//! Prints one line per replicate and estimator (status, iterations, solve seconds) and, per
//! estimator and bias, the truth, the mean estimate, the mean Laplace sd, the spread (sd of the
//! estimates over the replicates), the ratio Laplace sd / spread, and the largest
//! |estimate − truth| / Laplace sd over the replicates.
//!
//! Run with `cargo run --release --example flight_path -- [--replicates N] [--t-end T]
//! [--jme-only]` (defaults 20 replicates, T = 30 s, both estimators).

use onsager::model::library::{FlightPath, FlightPathSetup};
use onsager::path::{Merit, PathDetails};
use rand::rngs::StdRng;
use rand::SeedableRng;

/// The command line: `--replicates N`, `--t-end T`, `--jme-only`.
struct Args {
    replicates: u64,
    t_end: f64,
    jme_only: bool,
}

fn parse_args() -> Result<Args, String> {
    let mut args = Args { replicates: 20, t_end: 30.0, jme_only: false };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = |flag: &str| it.next().ok_or_else(|| format!("{flag} needs a value"));
        match flag.as_str() {
            "--replicates" => {
                let v = value("--replicates")?;
                args.replicates = v.parse().map_err(|_| format!("--replicates: not a count: `{v}`"))?;
            }
            "--t-end" => {
                let v = value("--t-end")?;
                args.t_end = v.parse().map_err(|_| format!("--t-end: not a number: `{v}`"))?;
            }
            "--jme-only" => args.jme_only = true,
            other => return Err(format!("unknown flag `{other}` (--replicates N, --t-end T, --jme-only)")),
        }
    }
    Ok(args)
}

/// Mean and sample sd (NaN for fewer than two values).
fn mean_sd(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, var.sqrt())
}

/// One estimator's results over the replicates: per bias the estimates and Laplace sds.
#[derive(Default)]
struct Tally {
    converged: usize,
    estimates: Vec<Vec<f64>>,
    sds: Vec<Vec<f64>>,
    seconds: Vec<f64>,
    iterations: Vec<usize>,
}

fn print_table(name: &str, tally: &Tally, replicates: u64) {
    let (mean_s, _) = mean_sd(&tally.seconds);
    let mean_it = tally.iterations.iter().sum::<usize>() as f64 / tally.iterations.len().max(1) as f64;
    println!(
        "\n{name}: converged {}/{replicates}, mean solve {mean_s:.1} s, mean iterations {mean_it:.1}",
        tally.converged
    );
    println!(
        "{:>5} {:>10} {:>11} {:>11} {:>11} {:>8} {:>9}",
        "bias", "truth", "mean est", "Laplace sd", "spread", "ratio", "max |z|"
    );
    for (i, name) in FlightPath::PARAMS[..6].iter().enumerate() {
        let truth = FlightPathSetup::TRUTH[i];
        let est: Vec<f64> = tally.estimates.iter().map(|e| e[i]).collect();
        let sd: Vec<f64> = tally.sds.iter().map(|s| s[i]).collect();
        if est.is_empty() {
            continue;
        }
        let (mean, spread) = mean_sd(&est);
        let (mean_laplace, _) = mean_sd(&sd);
        let max_z = est.iter().zip(&sd).map(|(e, s)| ((e - truth) / s).abs()).fold(0.0, f64::max);
        println!(
            "{name:>5} {truth:>10.5} {mean:>11.6} {mean_laplace:>11.3e} {spread:>11.3e} {:>8.3} {max_z:>9.2}",
            mean_laplace / spread
        );
    }
}

fn main() -> onsager::Result<()> {
    let args = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(2);
        }
    };
    let setup = FlightPathSetup { t_end: args.t_end, ..FlightPathSetup::new() };
    let mut merits = vec![("JME", Merit::OnsagerMachlup)];
    if !args.jme_only {
        merits.push(("MEE", Merit::Energy));
    }
    let mut tallies: Vec<Tally> = merits.iter().map(|_| Tally::default()).collect();
    println!(
        "flight-path: {} replicates, {} s at {} Hz, Hermite-Simpson, step {} s",
        args.replicates,
        setup.t_end,
        1.0 / setup.sample_every,
        setup.sample_every
    );
    for seed in 1..=args.replicates {
        let mut rng = StdRng::seed_from_u64(seed);
        let (_, data) = setup.simulate(&mut rng)?;
        for ((name, merit), tally) in merits.iter().zip(&mut tallies) {
            let solution = setup.estimate(&data, *merit)?;
            let e = &solution.estimate;
            println!(
                "seed {seed:>3} {name}: {} after {} iterations, {:.1} s",
                e.status, e.iterations, e.solve_seconds
            );
            match (&e.theta_sd, e.status.is_success()) {
                (Some(sd), true) => {
                    tally.converged += 1;
                    tally.estimates.push(e.theta[..6].to_vec());
                    tally.sds.push(sd[..6].to_vec());
                    tally.seconds.push(e.solve_seconds);
                    tally.iterations.push(e.iterations);
                }
                _ => {
                    let sd = e.details.get::<PathDetails>().map(|d| d.sd.to_string()).unwrap_or_default();
                    println!("  not tallied: {sd}");
                }
            }
        }
    }
    for ((name, _), tally) in merits.iter().zip(&tallies) {
        print_table(name, tally, args.replicates);
    }
    Ok(())
}
