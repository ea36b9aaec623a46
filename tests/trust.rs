//! Results a user can trust: estimators refuse problems too large for the memory limit before
//! allocating, the default grid covers the initial prior, an estimate that reaches the grid's
//! edge or a degenerate parameter is never reported as converged.

use std::path::{Path, PathBuf};

use onsager::data::Dataset;
use onsager::estimate::{EstimationProblem, MemoryLimit};
use onsager::estimator::Estimator;
use onsager::model::library::preset;
use onsager::model::Observation;
use onsager::simulate::{sample_measurements, simulate, SimulateOptions};
use onsager::Error;
use rand::SeedableRng;

use crate::support::onsager;

fn scratch(name: &str) -> PathBuf {
    crate::support::scratch("trust", name)
}

/// Double-well measurements every 0.5 to t = 20 (41 points), seed `seed`.
fn double_well_data(seed: u64) -> Dataset {
    let p = preset("double-well").unwrap();
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let truth =
        simulate(&p.model, &p.theta, &[1.0], &[], &SimulateOptions::new(0.0, 20.0, 0.005), &mut rng).unwrap();
    sample_measurements(&p.observation, &p.theta, &truth, 1, 0.5, &mut rng).unwrap()
}

/// The error is a memory refusal naming `what` and the flag.
fn assert_refused(result: onsager::Result<onsager::estimate::MethodRun>, what: &str) {
    match result {
        Err(e @ Error::MemoryLimit { .. }) => {
            let text = e.to_string();
            assert!(text.contains(what) && text.contains("--max-memory"), "{text}");
        }
        Err(e) => panic!("expected a memory refusal, got the error {e}"),
        Ok(run) => panic!("expected a memory refusal, got an estimate with status {}", run.estimate.status),
    }
}

#[test]
fn memory_limit_parses_and_prints_sizes() {
    assert_eq!(MemoryLimit::default(), MemoryLimit::DEFAULT);
    assert_eq!(MemoryLimit::DEFAULT.bytes(), 4 << 30);
    assert_eq!(MemoryLimit::parse("4GiB").unwrap(), MemoryLimit::DEFAULT);
    assert_eq!(MemoryLimit::parse("512MB").unwrap().bytes(), 512_000_000);
    assert_eq!(MemoryLimit::parse("1e9").unwrap().bytes(), 1_000_000_000);
    assert_eq!(MemoryLimit::parse("unlimited").unwrap(), MemoryLimit::UNLIMITED);
    assert_eq!(MemoryLimit::DEFAULT.to_string(), "4GiB");
    assert_eq!(MemoryLimit::parse(&MemoryLimit::DEFAULT.to_string()).unwrap(), MemoryLimit::DEFAULT);
    for bad in ["", "-1GB", "4 parsecs", "NaN", "0"] {
        let e = MemoryLimit::parse(bad).unwrap_err();
        assert!(e.to_string().contains("--max-memory"), "{bad}: {e}");
    }
}

#[test]
fn a_tiny_transcription_step_is_refused_before_allocating() {
    let p = preset("double-well").unwrap();
    let data = double_well_data(3);
    let problem = p.problem(&data, &[]);
    assert_refused(Estimator::parse("jme:step=1e-7").unwrap().run(&problem), "path transcription");
    // The same problem runs with a limit that admits it.
    let roomy =
        EstimationProblem { max_memory: MemoryLimit::parse("1GiB").unwrap(), ..p.problem(&data, &[]) };
    assert!(Estimator::parse("jme:step=0.05").unwrap().run(&roomy).is_ok());
    let tight =
        EstimationProblem { max_memory: MemoryLimit::parse("10kB").unwrap(), ..p.problem(&data, &[]) };
    assert_refused(Estimator::parse("jme:step=0.05").unwrap().run(&tight), "path transcription");
}

#[test]
fn a_huge_grid_is_refused_before_allocating() {
    let p = preset("double-well").unwrap();
    let data = double_well_data(3);
    let problem = p.problem(&data, &[]);
    for method in ["ksp", "mean-optimal"] {
        let e = Estimator::parse(&format!("{method}:grid=\"lo=-3,hi=3,cells=1000000000\"")).unwrap();
        assert_refused(e.run(&problem), "grid cells");
    }
}

#[test]
fn kalman_particle_and_ensemble_storage_is_bounded() {
    let p = preset("double-well").unwrap();
    let data = double_well_data(3);
    let tight =
        EstimationProblem { max_memory: MemoryLimit::parse("100kB").unwrap(), ..p.problem(&data, &[]) };
    for method in ["ekf", "eks", "ukf", "uks"] {
        assert_refused(
            Estimator::parse(&format!("{method}:dt=1e-5")).unwrap().run(&tight),
            "integration steps",
        );
    }
    assert_refused(Estimator::parse("particle:particles=100000").unwrap().run(&tight), "particles");
    assert_refused(Estimator::parse("enks:members=100000").unwrap().run(&tight), "members");
}

/// A measurement file of `rows` rows of the double well's output.
fn write_rows(path: &Path, rows: usize) {
    let mut text = String::from("t,y\n");
    for k in 0..rows {
        text.push_str(&format!("{},{}\n", k as f64 * 0.01, (k as f64 * 0.001).sin()));
    }
    std::fs::write(path, text).unwrap();
}

#[test]
fn the_cli_refuses_with_exit_code_1_and_names_the_flag() {
    let dir = scratch("cli-memory");
    let data = dir.join("rows.csv");
    write_rows(&data, 20_000);
    for (method, limit) in [("jme", "20MB"), ("uks", "2MB")] {
        let out = onsager()
            .args(["estimate", "--model", "double-well", "--method", method, "--max-memory", limit, "--data"])
            .arg(&data)
            .arg("--out")
            .arg(dir.join("out.csv"))
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{method}: {stderr}");
        assert!(stderr.contains("--max-memory") && stderr.contains("needs about"), "{method}: {stderr}");
    }
}

#[test]
fn the_default_grid_covers_the_initial_prior_and_a_narrow_grid_is_flagged() {
    let dir = scratch("tanh");
    let (data, truth) = (dir.join("tanh.csv"), dir.join("tanh-truth.csv"));
    let sim = onsager()
        .args(["simulate", "--model", "tanh", "--seed", "5", "--out"])
        .arg(&data)
        .arg("--truth")
        .arg(&truth)
        .output()
        .unwrap();
    assert!(sim.status.success(), "{}", String::from_utf8_lossy(&sim.stderr));
    let p = preset("tanh").unwrap();
    let d = Dataset::read_csv_for(&data, &p.observation.output_names()).unwrap();
    let problem = p.problem(&d, &[]);
    let truth = onsager::data::StatePath::read_csv(&truth).unwrap();
    for method in ["ksp", "mean-optimal"] {
        let run = Estimator::parse(method).unwrap().run(&problem).unwrap();
        let grid = run.notes.iter().find(|n| n.starts_with("grid lo=")).expect("a default grid note");
        let lo: f64 = grid["grid lo=".len()..].split(',').next().unwrap().parse().unwrap();
        assert!(lo <= -2.3, "the default grid leaves out the prior N(0, 0.4²): {grid}");
        let est = &run.estimate.path;
        let sq: f64 = est
            .times
            .iter()
            .zip(&est.values)
            .map(|(&t, v)| {
                let k = truth.times.iter().position(|&s| (s - t).abs() < 1e-9).unwrap_or(0);
                (v[0] - truth.values[k][0]).powi(2)
            })
            .sum();
        let rmse = (sq / est.times.len() as f64).sqrt();
        assert!(rmse < 1.5, "{method}: RMSE {rmse} to the truth");
        assert!(
            run.estimate.status.is_success() || run.estimate.status == onsager::estimate::Status::GridEdge,
            "{method}: {}",
            run.estimate.status
        );
        // A grid on the data range alone leaves out the prior: flagged, never converged.
        let narrow = Estimator::parse(&format!("{method}:grid=\"lo=4.93,hi=8.13,cells=400\"")).unwrap();
        let run = narrow.run(&problem).unwrap();
        assert_eq!(run.estimate.status, onsager::estimate::Status::GridEdge, "{method}");
        assert!(run.notes.iter().any(|n| n.contains("edge of the grid")), "{:?}", run.notes);
    }
}

#[test]
fn a_noise_parameter_estimated_with_the_path_is_degenerate_with_exit_code_2() {
    let dir = scratch("degenerate");
    let data = dir.join("dw.csv");
    let sim = onsager()
        .args(["simulate", "--model", "double-well", "--seed", "3", "--out"])
        .arg(&data)
        .output()
        .unwrap();
    assert!(sim.status.success(), "{}", String::from_utf8_lossy(&sim.stderr));
    let out = onsager()
        .args([
            "estimate",
            "--model",
            "double-well",
            "--method",
            "jme",
            "--transcription",
            "euler",
            "--estimate",
            "D",
        ])
        .arg("--data")
        .arg(&data)
        .arg("--out")
        .arg(dir.join("out.csv"))
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(2), "{stdout}");
    assert!(
        stdout.contains("status degenerate") && stdout.contains("`D`") && stdout.contains("pem"),
        "{stdout}"
    );
    // Hermite–Simpson refuses it and sends users to `pem`, not to another transcription.
    let hs = onsager()
        .args(["estimate", "--model", "double-well", "--method", "jme", "--estimate", "D", "--data"])
        .arg(&data)
        .arg("--out")
        .arg(dir.join("out.csv"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&hs.stderr);
    assert_eq!(hs.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("pem") && stderr.contains("degenerate"), "{stderr}");
}
