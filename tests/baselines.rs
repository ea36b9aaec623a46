//! The baselines (issue 8): EKF/EKS and UKF/UKS against the exact Kalman filter and RTS
//! smoother, the particle smoother against the RTS mean within its Monte Carlo error, the PEM on
//! the Duffing oscillator, and the rejection of non-Gaussian likelihoods by the Kalman methods.

use std::process::Command;

use approx::assert_relative_eq;
use nalgebra::{DMatrix, DVector};
use rand::rngs::StdRng;
use rand::SeedableRng;

use onsager::data::{Dataset, StatePath};
use onsager::estimate::Status;
use onsager::kalman::linear::{kalman_rts, KalmanSmoothing, LinearGaussianModel};
use onsager::kalman::{self, Approximation, KalmanMethod, KalmanOptions, PemOptions, UnscentedParams};
use onsager::model::library::{preset, Preset};
use onsager::model::observation::{Noise, Param};
use onsager::particle::{self, ParticleOptions};
use onsager::test_models::PresetRecord;
use onsager::Error;

/// The preset `name` simulated on [0, t_end] with its own step and sampling, x0 from its prior
/// (`test_models::PresetRecord`).
fn simulated(name: &str, t_end: f64, seed: u64) -> PresetRecord {
    let mut p = preset(name).unwrap();
    p.t_end = t_end;
    PresetRecord::simulate(p, seed).unwrap()
}

/// The exact Kalman filter and RTS smoother of the `ou` preset (x0 ~ N(0, 1) at t = 0).
fn ou_reference(p: &Preset, data: &Dataset) -> KalmanSmoothing {
    let model = LinearGaussianModel::from_sde(
        &p.model,
        &p.theta,
        &p.observation,
        0.0,
        DVector::from_element(1, 0.0),
        DMatrix::from_element(1, 1, 1.0),
    )
    .unwrap();
    kalman_rts(&model, data, &[]).unwrap()
}

#[test]
fn kalman_methods_equal_the_exact_kalman_filter_and_rts_smoother_on_ou() {
    // Identity (linear-Gaussian): the EKF/UKF moment ODEs are exact for the OU drift, so with
    // RK4 at dt = 0.005 (error O(dt⁴) ≈ 1e-10) they equal the exact Kalman filter, and the
    // EKS/UKS the RTS smoother, of kalman::linear (Van Loan discretisation) to 1e-8.
    let PresetRecord { preset: p, data, .. } = simulated("ou", 5.0, 42);
    let reference = ou_reference(&p, &data);
    let options = KalmanOptions::default().with_dt(0.005);
    for method in [KalmanMethod::Ekf, KalmanMethod::Eks, KalmanMethod::Ukf, KalmanMethod::Uks] {
        let est = kalman::estimate(&p.problem(&data, &[]), method, &options).unwrap();
        assert_eq!(est.status, Status::Converged);
        let smoothed = matches!(method, KalmanMethod::Eks | KalmanMethod::Uks);
        let sd = est.path.sd.as_ref().unwrap();
        let mut checked = 0;
        let mut worst = 0.0f64;
        for &t in &data.times {
            let j = est.path.times.iter().position(|&s| (s - t).abs() < 1e-9).unwrap();
            let r = reference.index_of(t).unwrap();
            let (mean, cov) = if smoothed {
                (reference.smoothed_mean[r][0], reference.smoothed_cov[r][(0, 0)])
            } else {
                (reference.filtered_mean[r][0], reference.filtered_cov[r][(0, 0)])
            };
            worst = worst.max((est.path.values[j][0] - mean).abs()).max((sd[j][0] * sd[j][0] - cov).abs());
            assert_relative_eq!(est.path.values[j][0], mean, epsilon = 1e-8);
            assert_relative_eq!(sd[j][0] * sd[j][0], cov, epsilon = 1e-8);
            checked += 1;
        }
        assert_eq!(checked, 51);
        eprintln!("{}: largest deviation from the exact Kalman/RTS moments {worst:.2e}", method.name());
        let ll = est.details["log_likelihood"].as_f64().unwrap();
        assert_relative_eq!(ll, reference.log_likelihood, epsilon = 1e-8);
    }
}

#[test]
fn particle_smoother_mean_is_within_four_monte_carlo_standard_errors_of_the_rts_mean() {
    // Monte Carlo test (STYLE.md): R = 16 independent FFBSi runs with N = 2000 particles and
    // M = 250 backward paths on OU (T = 2, 21 measurements). The Monte Carlo standard error of
    // one run's mean at t_k is estimated by the spread of the R runs; the average of the R runs
    // must lie within 4 SE/√R of the exact RTS mean at every measurement time. The Euler
    // substep 0.004 keeps the Euler discretisation bias (relative O(θ dt) ≈ 0.4 %) below it.
    let PresetRecord { preset: p, data, .. } = simulated("ou", 2.0, 7);
    let reference = ou_reference(&p, &data);
    let options = ParticleOptions::default().with_particles(2000).with_backward_paths(250).with_dt(0.004);
    let r = 16;
    let runs: Vec<Vec<f64>> = (0..r)
        .map(|rep| {
            let mut rng = StdRng::seed_from_u64(1000 + rep);
            let est = particle::estimate(&p.problem(&data, &[]), &options, &mut rng).unwrap();
            assert_eq!(est.status, Status::Converged);
            assert_eq!(est.details["smoother"], "ffbsi");
            assert_eq!(est.path.times, data.times);
            est.path.values.iter().map(|v| v[0]).collect()
        })
        .collect();
    let mut worst = 0.0f64;
    for (k, &t) in data.times.iter().enumerate() {
        let rts = reference.smoothed_mean[reference.index_of(t).unwrap()][0];
        let mean = runs.iter().map(|v| v[k]).sum::<f64>() / r as f64;
        let se_run = (runs.iter().map(|v| (v[k] - mean).powi(2)).sum::<f64>() / (r - 1) as f64).sqrt();
        let se = se_run / (r as f64).sqrt();
        worst = worst.max((mean - rts).abs() / se);
        assert!(
            (mean - rts).abs() < 4.0 * se,
            "t = {t}: particle mean {mean:.5} vs RTS {rts:.5}, 4 SE = {:.5} (one run's SE {se_run:.5})",
            4.0 * se
        );
        // The single-run error is small compared with the smoothing sd (a sanity bound, not the
        // acceptance): SE ≤ sd/√10 with the RTS sd.
        let sd = reference.smoothed_cov[reference.index_of(t).unwrap()][(0, 0)].sqrt();
        assert!(se_run < sd / 10f64.sqrt(), "t = {t}: one run's SE {se_run} vs posterior sd {sd}");
    }
    eprintln!("particle vs RTS on OU: largest |mean - RTS| / SE over the 21 times = {worst:.2}");
}

#[test]
fn pem_recovers_the_duffing_parameters_on_a_short_record() {
    // 000_74b95e149527c64e.txt Sec. 4.1.1 with T = 30 (the full T = 100 run is the example
    // `pem_duffing`): θ = (a, b, d, σ_y) from the nominal start; each estimate must lie within
    // 4 of its Laplace standard deviations of the nominal value (Table 4.1).
    let PresetRecord { preset: p, data, .. } = simulated("duffing", 30.0, 1);
    let estimate: Vec<usize> = ["a", "b", "d", "sigma_y"].iter().map(|n| p.param_index(n).unwrap()).collect();
    let est = kalman::pem(&p.problem(&data, &estimate), &PemOptions::default()).unwrap();
    assert!(est.status.is_success(), "{}", est.status);
    assert_eq!(est.estimated, estimate);
    let sd = est.theta_sd.clone().unwrap();
    for (k, &i) in estimate.iter().enumerate() {
        let nominal = p.theta[i];
        eprintln!(
            "PEM, Duffing T = 30: {} = {:.5} ± {:.5} (nominal {nominal})",
            p.param_names()[i],
            est.theta[i],
            sd[k]
        );
        assert!(
            (est.theta[i] - nominal).abs() < 4.0 * sd[k],
            "{} = {} ± {} (nominal {nominal})",
            p.param_names()[i],
            est.theta[i],
            sd[k]
        );
    }
    // The UKS path at θ̂ covers the grid with standard deviations.
    assert_eq!(est.path.names, vec!["x".to_string(), "z".to_string()]);
    assert!(est.path.sd.as_ref().unwrap().iter().flatten().all(|v| *v > 0.0));
}

#[test]
fn non_gaussian_likelihoods_are_rejected_by_the_kalman_methods_and_accepted_by_the_particle_smoother() {
    let PresetRecord { preset: mut p, data, .. } = simulated("ou", 1.0, 3);
    p.observation.noise = Noise::StudentT { nu: Param::Fixed(4.0), scale: Param::Fixed(0.2) };
    let check = |r: onsager::Result<onsager::estimate::PathEstimate>| match r {
        Err(Error::InvalidOption { name, reason }) => {
            assert_eq!(name, "likelihood");
            assert!(reason.contains("Gaussian measurement errors"), "{reason}");
        }
        other => panic!("expected a clear error, got {other:?}"),
    };
    for method in [KalmanMethod::Ekf, KalmanMethod::Eks, KalmanMethod::Ukf, KalmanMethod::Uks] {
        check(kalman::estimate(&p.problem(&data, &[]), method, &KalmanOptions::default()));
    }
    check(kalman::pem(&p.problem(&data, &[0]), &PemOptions::default()));
    assert!(kalman::filter(
        &p.problem(&data, &[]),
        &p.theta,
        Approximation::Unscented(UnscentedParams::default()),
        &KalmanOptions::default()
    )
    .is_err());
    let mut rng = StdRng::seed_from_u64(5);
    let est =
        particle::estimate(&p.problem(&data, &[]), &ParticleOptions::default().with_particles(200), &mut rng)
            .unwrap();
    assert_eq!(est.status, Status::Converged);
    assert!(est.details["log_likelihood"].as_f64().unwrap().is_finite());
}

#[test]
fn cli_eks_writes_the_library_path() {
    // The command line runs the same estimator: `onsager estimate --method eks` on a simulated
    // OU dataset writes the path of kalman::estimate at the default options.
    let PresetRecord { preset: p, data, .. } = simulated("ou", 1.0, 9);
    let dir = std::env::temp_dir().join(format!("onsager-baselines-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (data_csv, out_csv) = (dir.join("data.csv"), dir.join("eks.csv"));
    data.write_csv(&data_csv).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_onsager"))
        .args(["estimate", "--model", "ou", "--method", "eks", "--data"])
        .arg(&data_csv)
        .arg("--out")
        .arg(&out_csv)
        .output()
        .unwrap();
    assert!(out.status.success(), "stderr: {}", String::from_utf8_lossy(&out.stderr));
    let path = StatePath::read_csv(&out_csv).unwrap();
    let lib = kalman::estimate(&p.problem(&data, &[]), KalmanMethod::Eks, &KalmanOptions::default()).unwrap();
    assert_eq!(path.times.len(), lib.path.times.len());
    for (a, b) in path.values.iter().zip(&lib.path.values) {
        assert_relative_eq!(a[0], b[0], epsilon = 1e-12, max_relative = 1e-12);
    }
    // A Student-t likelihood makes the command fail with the library's message.
    let out = Command::new(env!("CARGO_BIN_EXE_onsager"))
        .args([
            "estimate",
            "--model",
            "ou",
            "--method",
            "ukf",
            "--likelihood",
            "student-t:nu=4,scale=0.2",
            "--data",
        ])
        .arg(&data_csv)
        .arg("--out")
        .arg(dir.join("ukf.csv"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("Gaussian measurement errors"));
}
