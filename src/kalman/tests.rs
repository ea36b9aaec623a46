//! Unit tests of the Kalman baselines against the exact linear reference ([`super::linear`]).

use approx::assert_relative_eq;
use nalgebra::{DMatrix, DVector};

use super::linear::{kalman_rts, LinearGaussianModel};
use super::*;
use crate::model::observation::Noise;
use crate::model::prior::Prior;
use crate::model::Param;
use crate::test_models::{LinearOscillator, OscillatorRecord};

/// The exact Kalman filter and RTS smoother of the record of the linear oscillator with a clean
/// state (`test_models::OscillatorRecord`, whose clean state exercises the z rows).
fn reference(case: &OscillatorRecord) -> crate::kalman::linear::KalmanSmoothing {
    let m0 = DVector::from_vec(vec![0.1, -0.3]);
    let p0 = DMatrix::from_diagonal(&DVector::from_vec(vec![0.25, 0.36]));
    let model = LinearGaussianModel::from_sde(&LinearOscillator, &case.theta, &case.observation, 0.0, m0, p0)
        .unwrap();
    kalman_rts(&model, &case.data, &[]).unwrap()
}

#[test]
fn extended_and_unscented_match_the_exact_kalman_filter_and_smoother_with_clean_states() {
    // Identity: on a linear SDE the moment ODEs are exact, so with RK4 at dt = 0.005 the
    // EKF/UKF and EKS/UKS equal the exact Kalman filter and RTS smoother up to O(dt⁴).
    let case = OscillatorRecord::new().unwrap();
    let reference = reference(&case);
    let opts = KalmanOptions::default().with_dt(0.005);
    for approx in [Approximation::Extended, Approximation::Unscented(UnscentedParams::default())] {
        let run = filter(&case.problem(), &case.theta, approx, &opts).unwrap();
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
    let case = OscillatorRecord::new().unwrap();
    let a = filter(
        &case.problem(),
        &case.theta,
        Approximation::Unscented(UnscentedParams::default()),
        &KalmanOptions::default(),
    )
    .unwrap();
    let params = UnscentedParams { alpha: 0.5, kappa: 1.0 };
    let b = filter(&case.problem(), &case.theta, Approximation::Unscented(params), &KalmanOptions::default())
        .unwrap();
    let last = a.filtered.len() - 1;
    assert_relative_eq!(a.filtered[last].mean[1], b.filtered[last].mean[1], epsilon = 1e-12);
    assert_relative_eq!(a.log_likelihood, b.log_likelihood, epsilon = 1e-10);
    let bad = UnscentedParams { alpha: 1.0, kappa: -2.0 };
    assert!(filter(&case.problem(), &case.theta, Approximation::Unscented(bad), &KalmanOptions::default())
        .is_err());
}

#[test]
fn non_gaussian_likelihood_and_prior_are_errors() {
    let mut case = OscillatorRecord::new().unwrap();
    case.observation.noise = Noise::StudentT { nu: Param::Fixed(4.0), scale: Param::Fixed(0.1) };
    for method in [KalmanMethod::Ekf, KalmanMethod::Uks] {
        match estimate(&case.problem(), method, &KalmanOptions::default()) {
            Err(Error::InvalidOption { name, reason }) => {
                assert_eq!(name, "likelihood");
                assert!(reason.contains("Gaussian") && reason.contains("student-t"), "{reason}");
            }
            other => panic!("expected an error, got {other:?}"),
        }
    }
    let mut case = OscillatorRecord::new().unwrap();
    case.x0_prior = vec![Prior::flat()];
    assert!(matches!(
        estimate(&case.problem(), KalmanMethod::Eks, &KalmanOptions::default()),
        Err(Error::InvalidOption { name, .. }) if name == "x0-prior"
    ));
}

#[test]
fn estimate_reports_the_path_on_the_grid_with_sd() {
    let case = OscillatorRecord::new().unwrap();
    let est = estimate(&case.problem(), KalmanMethod::Uks, &KalmanOptions::default().with_dt(0.05)).unwrap();
    assert_eq!(est.method, crate::Method::Uks);
    assert_eq!(est.status, Status::Converged);
    // t0 = 0 is the first measurement time; 20 intervals of 0.2 with 4 steps each.
    assert_eq!(est.path.times.len(), 81);
    assert_relative_eq!(est.path.times[80], 4.0, epsilon = 1e-12);
    assert_eq!(est.path.names, vec!["v".to_string(), "q".to_string()]);
    let sd = est.path.sd.as_ref().unwrap();
    assert!(sd.iter().flatten().all(|v| *v > 0.0));
    // Estimating parameters is the PEM's job.
    let mut p = case.problem();
    p.estimate = &[0];
    assert!(estimate(&p, KalmanMethod::Ekf, &KalmanOptions::default()).is_err());
    // The initial time must not follow the first measurement.
    let late = EstimationProblem { t0: 0.5, ..case.problem() };
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
    let case = OscillatorRecord::new().unwrap();
    let priors = [Prior::flat(), Prior::flat(), Prior::flat(), Prior::flat(), Prior::gamma(1.1, 10.0)];
    let mut p = case.problem();
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
    let case = OscillatorRecord::new().unwrap();
    let priors =
        [Prior::gaussian(0.0, 10.0), Prior::flat(), Prior::flat(), Prior::flat(), Prior::gamma(1.1, 10.0)];
    let theta = vec![0.9, 1.5, 0.3, 0.4, 0.2];
    let mut p = case.problem();
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
    let case = OscillatorRecord::new().unwrap();
    let m0 = DVector::from_vec(vec![0.1, -0.3]);
    let p0 = DMatrix::from_diagonal(&DVector::from_vec(vec![0.25, 0.36]));
    let model =
        LinearGaussianModel::from_sde(&LinearOscillator, &case.theta, &case.observation, -0.5, m0, p0)
            .unwrap();
    let reference = kalman_rts(&model, &case.data, &[]).unwrap();
    let opts = KalmanOptions::default().with_dt(0.005);
    let early = EstimationProblem { t0: -0.5, ..case.problem() };
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

#[test]
fn a_step_made_unstable_by_outliers_is_refined_not_failed() {
    // Van der Pol (μ = 2, σ = 0.1, 001 Sec. 9), u measured every 0.1 on [0, 16] with the outlier
    // mixture of `vdp-robust` at p_o = 0.4, σ_o = 10, and filtered with the Gaussian likelihood
    // N(0, 0.5²) as there. The updates at the outliers move the moments far from the limit cycle,
    // where the drift's Jacobian is large enough that the default step (0.01) leaves a
    // covariance that is not positive definite (these seeds ended `numerical-failure` with fixed
    // steps); the halved steps there give the path of a 20× finer fixed step to a small fraction of the
    // posterior sd.
    use crate::model::library::VanDerPol;
    use crate::simulate::{sample_measurements, simulate, SimulateOptions};
    use rand::SeedableRng;
    let theta = VanDerPol::NOMINAL;
    let noise = Noise::Mixture {
        p_outlier: Param::Fixed(0.4),
        sigma: Param::Fixed(0.5),
        sigma_outlier: Param::Fixed(10.0),
    };
    let mixture = StateMeasurement::new(vec![0], vec!["y".into()], noise);
    let obs = crate::test_models::gaussian_measurement(0, 0.5);
    let priors = [Prior::flat(), Prior::flat()];
    let x0 = [Prior::gaussian(1.0, 0.1), Prior::gaussian(0.0, 0.1)];
    for seed in [0, 3, 6] {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let options = SimulateOptions::new(0.0, 16.0, 0.001);
        let truth = simulate(&VanDerPol, &theta, &[1.0, 0.0], &[], &options, &mut rng).unwrap();
        let data = sample_measurements(&mixture, &theta, &truth, 2, 0.1, &mut rng).unwrap();
        let problem = EstimationProblem {
            sde: &VanDerPol,
            observation: &obs,
            theta: &theta,
            theta_prior: &priors,
            estimate: &[],
            x0_prior: &x0,
            z0_prior: &[],
            data: &data,
            t0: 0.0,
            seed: 0,
            max_memory: Default::default(),
        };
        let coarse = estimate(&problem, KalmanMethod::Uks, &KalmanOptions::default().with_dt(0.01)).unwrap();
        let fine = estimate(&problem, KalmanMethod::Uks, &KalmanOptions::default().with_dt(0.0005)).unwrap();
        assert_eq!(coarse.status, Status::Converged, "seed {seed}");
        assert_eq!(fine.status, Status::Converged, "seed {seed}");
        // The difference to the fine step in units of the posterior sd at each time; the fixed
        // step's own error elsewhere on the record (RK4 at 0.01) is of order 1e-3.
        let sd = coarse.path.sd.as_ref().unwrap();
        let mut worst = 0.0_f64;
        for (i, t) in coarse.path.times.iter().enumerate() {
            let j = fine.path.times.iter().position(|s| (s - t).abs() < 1e-9).unwrap();
            for ((c, f), s) in coarse.path.values[i].iter().zip(&fine.path.values[j]).zip(&sd[i]) {
                worst = worst.max((c - f).abs() / s);
            }
        }
        assert!(worst < 0.05, "seed {seed}: difference to the fine step {worst} sd");
    }
}
