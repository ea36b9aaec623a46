//! Flight-path reconstruction (`000_74b95e149527c64e.txt` Sec. 4.2).
//!
//! **Synthetic** (no `--data`): for each replicate (seed 1, 2, …), simulate 30 s at 25 Hz of the
//! flight-path model with known sensor biases ([`FlightPathSetup::TRUTH`]), conditioned on
//! staying in the flight envelope ([`FlightPathSetup::simulate_in_envelope`]), then estimate the
//! path jointly with the eight parameters by JME and MEE (Hermite–Simpson, step = sample
//! period, started from the measurements), with the Laplace standard deviations of the
//! parameters. Prints one line per replicate and estimator (status, iterations, solve seconds)
//! and, per estimator and bias, the truth, the mean estimate, the mean Laplace sd, the spread (sd of the estimates
//! over the replicates), the ratio Laplace sd / spread, and the largest
//! |estimate − truth| / Laplace sd over the replicates.
//!
//! **Flight data** (`--data FILE`): reads a record in the ASCII layout of Jategaonkar's
//! *Flight Vehicle System Identification* (ATTAS channels, [`FlightColumns::ATTAS`]), writes it
//! as the project's measurement CSV with `--out`, estimates by JME and MEE with step = the
//! sample period, and prints per estimator the status, iterations, solve seconds, the biases
//! with their Laplace sds and the residual RMS of every channel against its range; the
//! measured and reconstructed outputs are drawn per channel group (altitude, air data,
//! attitude, rates, accelerations) as SVG and PNG in `--plots DIR` (default
//! `flight-path-plots`).
//!
//! On a flight record the noise levels are measured from the record (`RecordLevels::measure`:
//! sensor sds from third differences, σ_a and σ_m from the roughness of the specific forces and
//! rates); `--sigma-a S`, `--sigma-m S` and `--sensor-sd OUTPUT=SD` (repeatable, OUTPUT one of
//! the measurement CSV's columns) override them, also where they cannot be measured.
//!
//! Run with `cargo run --release --example flight_path -- [--replicates N] [--t-end T]
//! [--jme-only] [--data FILE [--out CSV] [--plots DIR] [--sigma-a S] [--sigma-m S]
//! [--sensor-sd OUTPUT=SD]...]` (defaults 20 replicates, T = 30 s, both estimators).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use onsager::data::Dataset;
use onsager::estimate::progress;
use onsager::model::library::{
    output_error, read_flight_record, FlightColumns, FlightPath, FlightPathObservation, FlightPathSetup,
    OemEstimate, OemOptions, RecordLevels, OEM_OUTPUTS,
};
use onsager::path::{Merit, PathDetails, PathSolution};
use onsager::plot::{LinePlot, Panels, Series, DATA};
use rand::rngs::StdRng;
use rand::SeedableRng;

/// The command line: `--replicates N`, `--t-end T`, `--jme-only`, `--data FILE`, `--out CSV`,
/// `--plots DIR`.
struct Args {
    replicates: u64,
    t_end: f64,
    jme_only: bool,
    data: Option<PathBuf>,
    out: Option<PathBuf>,
    plots: PathBuf,
    sigma_a: Option<f64>,
    sigma_m: Option<f64>,
    sensor_sd: Vec<(usize, f64)>,
}

fn parse_args() -> Result<Args, String> {
    let mut args = Args {
        replicates: 20,
        t_end: 30.0,
        jme_only: false,
        data: None,
        out: None,
        plots: PathBuf::from("flight-path-plots"),
        sigma_a: None,
        sigma_m: None,
        sensor_sd: Vec::new(),
    };
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
            "--data" => args.data = Some(value("--data")?.into()),
            "--out" => args.out = Some(value("--out")?.into()),
            "--plots" => args.plots = value("--plots")?.into(),
            "--sensor-sd" => {
                let v = value("--sensor-sd")?;
                let (name, sd) = v.split_once('=').ok_or_else(|| format!("--sensor-sd: expected OUTPUT=SD, got `{v}`"))?;
                let j = FlightPathObservation::OUTPUTS.iter().position(|o| *o == name).ok_or_else(|| {
                    format!("--sensor-sd: unknown output `{name}` (one of {})", FlightPathObservation::OUTPUTS.join(", "))
                })?;
                args.sensor_sd.push((j, positive(&format!("--sensor-sd {name}"), sd)?));
            }
            "--sigma-a" | "--sigma-m" => {
                let x = positive(&flag, &value(&flag)?)?;
                if flag == "--sigma-a" {
                    args.sigma_a = Some(x);
                } else {
                    args.sigma_m = Some(x);
                }
            }
            other => {
                return Err(format!(
                    "unknown flag `{other}` (--replicates N, --t-end T, --jme-only, --data FILE, --out CSV, --plots DIR, --sigma-a S, --sigma-m S, --sensor-sd OUTPUT=SD)"
                ))
            }
        }
    }
    Ok(args)
}

/// `text` as a positive finite number, or the error naming `what`.
fn positive(what: &str, text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(x) if x > 0.0 && x.is_finite() => Ok(x),
        Ok(_) => Err(format!("{what}: must be positive and finite, got {text}")),
        Err(_) => Err(format!("{what}: not a number: `{text}`")),
    }
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
    let mut merits = vec![("JME", Merit::OnsagerMachlup)];
    if !args.jme_only {
        merits.push(("MEE", Merit::Energy));
    }
    if let Some(file) = &args.data {
        return flight_data(file, &args, &merits);
    }
    if args.sigma_a.is_some() || args.sigma_m.is_some() || !args.sensor_sd.is_empty() {
        eprintln!("error: --sigma-a, --sigma-m and --sensor-sd set the levels of a flight record: use them with --data");
        std::process::exit(2);
    }
    let setup = FlightPathSetup { t_end: args.t_end, ..FlightPathSetup::new() };
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
        let (_, data) = setup.simulate_in_envelope(&mut rng, 100)?;
        for ((name, merit), tally) in merits.iter().zip(&mut tallies) {
            let solution = with_progress(name, || setup.estimate(&data, *merit))?;
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
                    if let Some(d) = e.details.get::<PathDetails>() {
                        println!(
                            "  NLP {} after {} iterations: constraint violation {:.2e}, optimality error {:.2e}",
                            d.nlp_status, d.nlp_iterations, d.primal_infeasibility, d.dual_infeasibility
                        );
                    }
                    println!("  theta {:?}", e.theta);
                }
            }
        }
    }
    for ((name, _), tally) in merits.iter().zip(&tallies) {
        print_table(name, tally, args.replicates);
    }
    Ok(())
}

/// Runs `solve`, reporting every 10th NLP iteration on stderr.
fn with_progress<R>(name: &str, solve: impl FnOnce() -> R) -> R {
    let name = name.to_string();
    let observer: progress::Observer = Arc::new(move |event| {
        if let progress::ProgressEvent::Iteration { iteration, merit } = event {
            if iteration % 10 == 0 {
                eprintln!("  {name} iteration {iteration}: merit {merit:.6e}");
            }
        }
    });
    progress::observe(observer, solve)
}

/// Per output: display scale from SI, unit, and the channel group (plot file) it is drawn in.
const DISPLAY: [(f64, &str, &str); 13] = [
    (1.0, "m/s", "air-data"),
    (57.295_779_513_082_32, "deg", "air-data"),
    (57.295_779_513_082_32, "deg", "air-data"),
    (57.295_779_513_082_32, "deg", "attitude"),
    (57.295_779_513_082_32, "deg", "attitude"),
    (57.295_779_513_082_32, "deg", "attitude"),
    (1.0, "m", "altitude"),
    (57.295_779_513_082_32, "deg/s", "rates"),
    (57.295_779_513_082_32, "deg/s", "rates"),
    (57.295_779_513_082_32, "deg/s", "rates"),
    (1.0, "m/s^2", "accelerations"),
    (1.0, "m/s^2", "accelerations"),
    (1.0, "m/s^2", "accelerations"),
];

/// `--data FILE`: read the record, estimate by each of `merits`, print the tables and draw the
/// channel groups.
fn flight_data(file: &Path, args: &Args, merits: &[(&str, Merit)]) -> onsager::Result<()> {
    let data = read_flight_record(file, &FlightColumns::ATTAS)?;
    if let Some(out) = &args.out {
        data.write_csv(out)?;
        println!("wrote {}", out.display());
    }
    let mut levels = RecordLevels::measure(&data)?;
    levels.sigma_a = args.sigma_a.or(levels.sigma_a);
    levels.sigma_m = args.sigma_m.or(levels.sigma_m);
    for &(j, sd) in &args.sensor_sd {
        levels.sensor_sd.0[j] = sd;
    }
    let setup = levels.setup()?;
    println!(
        "flight-path: {} ({} samples, t = {} .. {} s, step {:.4} s), Hermite-Simpson",
        file.display(),
        data.times.len(),
        data.times[0],
        data.times[data.times.len() - 1],
        setup.sample_every
    );
    println!(
        "sigma_a {:.4} m/s^3/sqrt(s), sigma_m {:.4} rad/s^3/sqrt(s)",
        setup.model.sigma_a, setup.model.sigma_m
    );
    println!("{:>8} {:>11}  (SI units)", "output", "sensor sd");
    for (out, sd) in FlightPathObservation::OUTPUTS.iter().zip(setup.observation.sd.per_output()) {
        println!("{out:>8} {sd:>11.4e}");
    }
    let oem = print_oem(&setup, &data)?;
    let mut solutions = Vec::new();
    for (name, merit) in merits {
        let solution = with_progress(name, || setup.estimate(&data, *merit))?;
        print_flight_estimate(name, &setup, &data, &solution)?;
        solutions.push((*name, solution));
    }
    print_bias_table(&oem, &solutions);
    plot_flight(&setup, &data, &solutions, &args.plots)?;
    println!("\nplots in {}", args.plots.display());
    Ok(())
}

/// The output-error method on the same record: biases with Cramér–Rao sds, residual sd per
/// fitted output.
fn print_oem(setup: &FlightPathSetup, data: &Dataset) -> onsager::Result<OemEstimate> {
    let begin = std::time::Instant::now();
    let oem = output_error(&setup.model, &setup.observation, data, &OemOptions::default())?;
    println!(
        "\noem: {} after {} iterations, {:.2} s",
        oem.status,
        oem.iterations,
        begin.elapsed().as_secs_f64()
    );
    println!("{:>5} {:>12} {:>11}", "param", "estimate", "CR sd");
    for (i, p) in FlightPath::PARAMS[..6].iter().enumerate() {
        println!("{p:>5} {:>12.6} {:>11.3e}", oem.biases[i], oem.bias_sd[i]);
    }
    println!("{:>8} {:>11}", "output", "residual sd");
    for (k, out) in OEM_OUTPUTS.iter().enumerate() {
        println!("{out:>8} {:>11.4e}", oem.residual_sd[k]);
    }
    Ok(oem)
}

/// The biases of the OEM and of each estimator side by side, with the difference to the OEM
/// in units of the estimator's sd and of the combined sd √(sd² + sd_OEM²).
fn print_bias_table(oem: &OemEstimate, solutions: &[(&str, PathSolution)]) {
    println!("\nbiases: estimate +- sd; difference to the OEM in sds (estimator's, combined)");
    for (i, p) in FlightPath::PARAMS[..6].iter().enumerate() {
        let mut line = format!("{p:>5}  OEM {:>10.6} +- {:.1e}", oem.biases[i], oem.bias_sd[i]);
        for (name, s) in solutions {
            let e = &s.estimate;
            let sd = e.theta_sd.as_ref().map_or(f64::NAN, |v| v[i]);
            let d = e.theta[i] - oem.biases[i];
            let combined = (sd * sd + oem.bias_sd[i] * oem.bias_sd[i]).sqrt();
            line += &format!(
                " | {name} {:>10.6} +- {sd:.1e} ({:.1}, {:.1})",
                e.theta[i],
                d.abs() / sd,
                d.abs() / combined
            );
        }
        println!("{line}");
    }
}

/// One estimator's status, biases with Laplace sds and residual RMS per channel.
fn print_flight_estimate(
    name: &str,
    setup: &FlightPathSetup,
    data: &Dataset,
    s: &PathSolution,
) -> onsager::Result<()> {
    let e = &s.estimate;
    println!(
        "\n{name}: {} after {} iterations, solve {:.1} s, {} grid nodes",
        e.status,
        e.iterations,
        e.solve_seconds,
        e.path.times.len()
    );
    if e.theta_sd.is_none() {
        let sd = e.details.get::<PathDetails>().map(|d| d.sd.to_string()).unwrap_or_default();
        println!("  no Laplace sd: {sd}");
    }
    println!("{:>5} {:>12} {:>11}", "param", "estimate", "Laplace sd");
    for (i, p) in FlightPath::PARAMS.iter().enumerate() {
        let sd = e.theta_sd.as_ref().map_or(f64::NAN, |s| s[i]);
        println!("{p:>5} {:>12.6} {sd:>11.3e}", e.theta[i]);
    }
    let res = setup.residuals(data, &e.path, &e.theta)?;
    println!("{:>8} {:>11} {:>11} {:>9}  (SI units)", "channel", "RMS", "range", "RMS/range");
    for (j, out) in FlightPathObservation::OUTPUTS.iter().enumerate() {
        println!("{out:>8} {:>11.4e} {:>11.4e} {:>9.4}", res.rms[j], res.range[j], res.rms[j] / res.range[j]);
    }
    Ok(())
}

/// Measured against reconstructed outputs, one figure per channel group (as the thesis's Figs.
/// 4.18–4.22), in display units.
fn plot_flight(
    setup: &FlightPathSetup,
    data: &Dataset,
    solutions: &[(&str, PathSolution)],
    dir: &Path,
) -> onsager::Result<()> {
    let outputs: Vec<Vec<[f64; 13]>> =
        solutions.iter().map(|(_, s)| setup.outputs_along(&s.estimate.path, &s.estimate.theta)).collect();
    for group in ["altitude", "air-data", "attitude", "rates", "accelerations"] {
        let mut panels = Vec::new();
        for (j, &(scale, unit, g)) in DISPLAY.iter().enumerate() {
            if g != group {
                continue;
            }
            let measured: Vec<f64> = data.values.iter().map(|row| row[j] * scale).collect();
            let mut series =
                vec![Series::points("measured", data.times.clone(), measured)
                    .with_look(DATA, Default::default())];
            for ((name, s), out) in solutions.iter().zip(&outputs) {
                let y = out.iter().map(|o| o[j] * scale).collect();
                series.push(Series::line(*name, s.estimate.path.times.clone(), y));
            }
            panels.push(LinePlot {
                title: FlightPathObservation::OUTPUTS[j].to_string(),
                x_label: "t (s)".into(),
                y_label: unit.into(),
                series,
                legend: panels.is_empty(),
                height: 320,
                ..LinePlot::default()
            });
        }
        let figure =
            Panels { title: format!("flight path: {group}"), panels, columns: 1, ..Panels::default() };
        figure.write(&dir.join(group))?;
    }
    Ok(())
}
