//! Unit tests of the Kalman baselines against the exact linear reference ([`super::linear`]).

use approx::assert_relative_eq;
use nalgebra::{DMatrix, DVector};
use rand::rngs::StdRng;
use rand::SeedableRng;

use super::linear::{kalman_rts, LinearGaussianModel};
use super::*;
use crate::model::observation::{Noise, StateMeasurement};
use crate::model::prior::Prior;
use crate::model::{Dims, Param, Scalar};
use crate::simulate::{sample_measurements, simulate, SimulateOptions};

/// Damped integrated noise with a clean state and a time-independent offset:
/// dX = (−k X − c Z + u) dt + σ dW, dZ = X dt, θ = (k, c, u, σ, σ_y) — linear, so the exact
/// Kalman filter is the reference, and it exercises the clean-state rows.
struct Oscillator;

impl Sde for Oscillator {
    fn dims(&self) -> Dims {
        Dims { noisy: 1, clean: 1, params: 5 }
    }
    fn noisy_names(&self) -> Vec<String> {
        vec!["v".into()]
    }
    fn clean_names(&self) -> Vec<String> {
        vec!["q".into()]
    }
    fn param_names(&self) -> Vec<String> {
        ["k", "c", "u", "sigma", "sigma_y"].iter().map(|s| s.to_string()).collect()
    }
    fn drift<D: Scalar>(&self, _t: D, x: &[D], z: &[D], th: &[D], out: &mut [D]) {
        out[0] = -th[0] * x[0] - th[1] * z[0] + th[2];
    }
    fn clean_drift<D: Scalar>(&self, _t: D, x: &[D], _z: &[D], _th: &[D], out: &mut [D]) {
        out[0] = x[0];
    }
    fn diffusion<D: Scalar>(&self, th: &[D], out: &mut [D]) {
        out[0] = th[3];
    }
}

struct Case {
    theta: Vec<f64>,
    theta_prior: Vec<Prior>,
    x0: Vec<Prior>,
    z0: Vec<Prior>,
    obs: StateMeasurement,
    data: crate::data::Dataset,
}

fn oscillator_case() -> Case {
    let theta = vec![0.7, 1.5, 0.3, 0.4, 0.15];
    let obs = StateMeasurement::new(vec![1], vec!["y".into()], Noise::Gaussian { sigma: Param::Theta(4) });
    let mut rng = StdRng::seed_from_u64(11);
    let path =
        simulate(&Oscillator, &theta, &[0.2], &[-0.5], &SimulateOptions::new(0.0, 4.0, 0.01), &mut rng)
            .unwrap();
    let mut data = sample_measurements(&obs, &theta, &path, 1, 0.2, &mut rng).unwrap();
    // A missing measurement exercises the skipped update.
    data.values[7][0] = f64::NAN;
    Case {
        theta,
        theta_prior: vec![Prior::flat(); 5],
        x0: vec![Prior::gaussian(0.1, 0.5)],
        z0: vec![Prior::gaussian(-0.3, 0.6)],
        obs,
        data,
    }
}

fn problem(case: &Case) -> EstimationProblem<'_, Oscillator, StateMeasurement> {
    EstimationProblem {
        sde: &Oscillator,
        observation: &case.obs,
        theta: &case.theta,
        theta_prior: &case.theta_prior,
        estimate: &[],
        x0_prior: &case.x0,
        z0_prior: &case.z0,
        data: &case.data,
        t0: 0.0,
        seed: 0,
    }
}

fn reference(case: &Case) -> crate::kalman::linear::KalmanSmoothing {
    let m0 = DVector::from_vec(vec![0.1, -0.3]);
    let p0 = DMatrix::from_diagonal(&DVector::from_vec(vec![0.25, 0.36]));
    let model = LinearGaussianModel::from_sde(&Oscillator, &case.theta, &case.obs, 0.0, m0, p0).unwrap();
    kalman_rts(&model, &case.data, &[]).unwrap()
}

#[test]
fn extended_and_unscented_match_the_exact_kalman_filter_and_smoother_with_clean_states() {
    // Identity: on a linear SDE the moment ODEs are exact, so with RK4 at dt = 0.005 the
    // EKF/UKF and EKS/UKS equal the exact Kalman filter and RTS smoother up to O(dt⁴).
    let case = oscillator_case();
    let reference = reference(&case);
    let opts = KalmanOptions::default().with_dt(0.005);
    for approx in [Approximation::Extended, Approximation::Unscented(UnscentedParams::default())] {
        let run = filter(&problem(&case), &case.theta, approx, &opts).unwrap();
        assert_eq!(run.status, Status::Converged);
        assert_relative_eq!(run.log_likelihood, reference.log_likelihood, epsilon = 1e-8);
        let smooth = run.smooth().unwrap();
        for (k, &t) in case.data.times.iter().enumerate() {
            let j = run.times.iter().position(|&s| (s - t).abs() < 1e-12).unwrap();
            let r = reference.index_of(t).unwrap();
            assert_eq!(run.measured[j], !case.data.values[k][0].is_nan());
            for i in 0..2 {
                assert_relative_eq!(run.filtered[j].mean[i], reference.filtered_mean[r][i], epsilon = 1e-8);
                assert_relative_eq!(smooth[j].mean[i], reference.smoothed_mean[r][i], epsilon = 1e-8);
                for c in 0..2 {
                    assert_relative_eq!(
                        run.filtered[j].cov[(i, c)],
                        reference.filtered_cov[r][(i, c)],
                        epsilon = 1e-8
                    );
                    assert_relative_eq!(
                        smooth[j].cov[(i, c)],
                        reference.smoothed_cov[r][(i, c)],
                        epsilon = 1e-8
                    );
                }
            }
        }
    }
}

#[test]
fn unscented_kappa_does_not_change_a_linear_problem() {
    // Identity: sigma-point moments of a linear drift are exact for every valid (alpha, kappa).
    let case = oscillator_case();
    let a = filter(
        &problem(&case),
        &case.theta,
        Approximation::Unscented(UnscentedParams::default()),
        &KalmanOptions::default(),
    )
    .unwrap();
    let params = UnscentedParams { alpha: 0.5, kappa: 1.0 };
    let b = filter(&problem(&case), &case.theta, Approximation::Unscented(params), &KalmanOptions::default())
        .unwrap();
    let last = a.filtered.len() - 1;
    assert_relative_eq!(a.filtered[last].mean[1], b.filtered[last].mean[1], epsilon = 1e-12);
    assert_relative_eq!(a.log_likelihood, b.log_likelihood, epsilon = 1e-10);
    let bad = UnscentedParams { alpha: 1.0, kappa: -2.0 };
    assert!(filter(&problem(&case), &case.theta, Approximation::Unscented(bad), &KalmanOptions::default())
        .is_err());
}

#[test]
fn non_gaussian_likelihood_and_prior_are_errors() {
    let mut case = oscillator_case();
    case.obs.noise = Noise::StudentT { nu: Param::Fixed(4.0), scale: Param::Fixed(0.1) };
    for method in [KalmanMethod::Ekf, KalmanMethod::Uks] {
        match estimate(&problem(&case), method, &KalmanOptions::default()) {
            Err(Error::InvalidOption { name, reason }) => {
                assert_eq!(name, "likelihood");
                assert!(reason.contains("Gaussian") && reason.contains("student-t"), "{reason}");
            }
            other => panic!("expected an error, got {other:?}"),
        }
    }
    let mut case = oscillator_case();
    case.x0 = vec![Prior::flat()];
    assert!(matches!(
        estimate(&problem(&case), KalmanMethod::Eks, &KalmanOptions::default()),
        Err(Error::InvalidOption { name, .. }) if name == "x0-prior"
    ));
}

#[test]
fn estimate_reports_the_path_on_the_grid_with_sd() {
    let case = oscillator_case();
    let est = estimate(&problem(&case), KalmanMethod::Uks, &KalmanOptions::default().with_dt(0.05)).unwrap();
    assert_eq!(est.method, crate::Method::Uks);
    assert_eq!(est.status, Status::Converged);
    // t0 = 0 is the first measurement time; 20 intervals of 0.2 with 4 steps each.
    assert_eq!(est.path.times.len(), 81);
    assert_relative_eq!(est.path.times[80], 4.0, epsilon = 1e-12);
    assert_eq!(est.path.names, vec!["v".to_string(), "q".to_string()]);
    let sd = est.path.sd.as_ref().unwrap();
    assert!(sd.iter().flatten().all(|v| *v > 0.0));
    // Estimating parameters is the PEM's job.
    let mut p = problem(&case);
    p.estimate = &[0];
    assert!(estimate(&p, KalmanMethod::Ekf, &KalmanOptions::default()).is_err());
    // The initial time must not follow the first measurement.
    let late = EstimationProblem { t0: 0.5, ..problem(&case) };
    assert!(estimate(&late, KalmanMethod::Ekf, &KalmanOptions::default()).is_err());
}

#[test]
fn default_step_is_a_tenth_of_the_median_interval_capped() {
    assert_relative_eq!(default_step(0.0, &[0.0, 0.1, 0.3]), 0.01, epsilon = 1e-15);
    assert_relative_eq!(default_step(0.0, &[0.05, 0.5]), 0.005, epsilon = 1e-15);
    assert_relative_eq!(default_step(0.0, &[5.0]), 0.01, epsilon = 1e-15);
    // One nearly coincident pair does not set the step for the whole record.
    assert_relative_eq!(default_step(0.0, &[0.05, 0.1, 0.1 + 1e-10, 0.15]), 0.005, epsilon = 1e-10);
}

#[test]
fn pem_recovers_a_linear_model_within_its_laplace_sd() {
    // The maximiser on simulated data: the estimate of (k, sigma_y) lies within 3 Laplace sd of
    // the truth (a loose, two-sided check of the Laplace approximation).
    let case = oscillator_case();
    let priors = [Prior::flat(), Prior::flat(), Prior::flat(), Prior::flat(), Prior::gamma(1.1, 10.0)];
    let mut p = problem(&case);
    p.theta_prior = &priors;
    p.estimate = &[0, 4];
    let est = pem(&p, &PemOptions::default()).unwrap();
    assert!(est.status.is_success(), "{:?}", est.status);
    let sd = est.theta_sd.clone().unwrap();
    assert!((est.theta[0] - 0.7).abs() < 3.0 * sd[0], "{} ± {}", est.theta[0], sd[0]);
    assert!((est.theta[4] - 0.15).abs() < 3.0 * sd[1], "{} ± {}", est.theta[4], sd[1]);
    assert!(est.details["gradient_norm"].as_f64().unwrap() < 1e-4);
}

#[test]
fn pem_gradient_matches_central_differences() {
    // AD through the UKF against central differences (step 1e-5, truncation O(h²) ≈ 1e-10
    // relative) of the same objective, at a point away from the optimum, in the optimisation
    // coordinates (log sigma_y for the gamma prior).
    let case = oscillator_case();
    let priors =
        [Prior::gaussian(0.0, 10.0), Prior::flat(), Prior::flat(), Prior::flat(), Prior::gamma(1.1, 10.0)];
    let theta = vec![0.9, 1.5, 0.3, 0.4, 0.2];
    let mut p = problem(&case);
    p.theta = &theta;
    p.theta_prior = &priors;
    p.estimate = &[0, 4, 1];
    let (obj, u0) = pem::objective(&p, &PemOptions::default()).unwrap();
    let (value, grad) = obj.gradient_u(&u0).unwrap();
    assert_relative_eq!(value, obj.value_u(&u0).unwrap(), max_relative = 1e-14);
    for i in 0..u0.len() {
        let h = 1e-5;
        let (mut up, mut um) = (u0.clone(), u0.clone());
        up[i] += h;
        um[i] -= h;
        let fd = (obj.value_u(&up).unwrap() - obj.value_u(&um).unwrap()) / (2.0 * h);
        assert_relative_eq!(grad[i], fd, epsilon = 1e-6, max_relative = 1e-6);
    }
}

#[test]
fn an_initial_time_before_the_first_measurement_is_a_prediction_only_node() {
    // Identity: with the prior at t0 = −0.5 the grid starts with a node without measurement;
    // the filter and smoother still equal the exact ones started at −0.5.
    let case = oscillator_case();
    let m0 = DVector::from_vec(vec![0.1, -0.3]);
    let p0 = DMatrix::from_diagonal(&DVector::from_vec(vec![0.25, 0.36]));
    let model = LinearGaussianModel::from_sde(&Oscillator, &case.theta, &case.obs, -0.5, m0, p0).unwrap();
    let reference = kalman_rts(&model, &case.data, &[]).unwrap();
    let opts = KalmanOptions::default().with_dt(0.005);
    let early = EstimationProblem { t0: -0.5, ..problem(&case) };
    let run = filter(&early, &case.theta, Approximation::Extended, &opts).unwrap();
    assert_relative_eq!(run.times[0], -0.5);
    assert!(!run.measured[0]);
    assert_relative_eq!(run.log_likelihood, reference.log_likelihood, epsilon = 1e-8);
    let smooth = run.smooth().unwrap();
    for (j, r) in [(0, reference.index_of(-0.5).unwrap()), (run.times.len() - 1, reference.times.len() - 1)] {
        for i in 0..2 {
            assert_relative_eq!(smooth[j].mean[i], reference.smoothed_mean[r][i], epsilon = 1e-8);
            assert_relative_eq!(smooth[j].cov[(i, i)], reference.smoothed_cov[r][(i, i)], epsilon = 1e-8);
        }
    }
}
