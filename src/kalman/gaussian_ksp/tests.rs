//! Tests of the Gaussian KSP closure against the exact RTS smoother, the polynomial exactness of
//! its rules, and the particle smoother on a Lorenz-63 record.

use rand::rngs::StdRng;
use rand::SeedableRng;

use super::*;
use crate::data::{Dataset, StatePath};
use crate::estimate::Status;
use crate::model::library::preset;
use crate::model::observation::{Noise, Param};
use crate::model::prior::Prior;
use crate::particle::ParticleOptions;
use crate::simulate::{sample_measurements_at, simulate, SimulateOptions};
use crate::test_models::RotationRecord;

/// The largest |closure − RTS| of the smoothed means and sds at the measurement times on the
/// three-state linear model with a clean state (`RotationWithPosition`: x2 and z measured every
/// 0.25 on [0, 4] with sd 0.2, one datum missing) with the Runge–Kutta step `dt`.
fn rts_error(dt: f64, rule: ExpectationRule) -> f64 {
    let record = RotationRecord::new().unwrap();
    let problem = record.problem();
    let times = &record.times;
    let options = GaussianKspOptions::default().with_dt(dt).with_rule(rule, None);
    let est = gaussian_ksp(&problem, &options).unwrap();
    assert_eq!(est.status, Status::Converged);
    assert_eq!(est.method, Method::GaussianKspClosure);
    let kf = record.rts(times).unwrap();
    let sd = est.path.sd.as_ref().unwrap();
    let mut max_err: f64 = 0.0;
    for &t in times {
        let i = est.path.times.iter().position(|&s| (s - t).abs() < 1e-9).unwrap();
        let j = kf.index_of(t).unwrap();
        for (s, (value, sd)) in est.path.values[i].iter().zip(&sd[i]).enumerate() {
            max_err = max_err.max((value - kf.smoothed_mean[j][s]).abs());
            max_err = max_err.max((sd - kf.smoothed_cov[j][(s, s)].sqrt()).abs());
        }
    }
    max_err
}

#[test]
fn gaussian_ksp_closure_of_a_three_state_model_with_a_clean_state_is_the_rts_smoother() {
    // Identity: on a linear SDE the closed moment equations are exact (any rule of degree ≥ 1
    // computes E[a] and E[(S − m) aᵀ] exactly), the Bayes jump is the Kalman update and the
    // backward pass is the RTS smoother: the only error is the Runge–Kutta error O(dt⁴).
    for rule in [ExpectationRule::Auto, ExpectationRule::GaussHermite, ExpectationRule::Cubature5] {
        let coarse = rts_error(0.125, rule);
        let fine = rts_error(0.0125, rule);
        assert!(fine < 1e-6, "{rule:?}: max |closure − RTS| at dt 0.0125: {fine}");
        assert!(fine < 1e-2 * coarse, "{rule:?}: the error shrinks with the step: {coarse} → {fine}");
    }
}

/// A record of `model` simulated with `theta` from `x0`, all states measured with sd
/// `sigma_y` every `every` on (0, `t_end`].
fn record(
    name: &str,
    theta: &[f64],
    x0: &[f64],
    t_end: f64,
    every: f64,
    sigma_y: f64,
) -> (StatePath, Dataset) {
    let p = preset(name).unwrap();
    let n = x0.len();
    let obs = StateMeasurement::new(
        (0..n).collect(),
        (0..n).map(|i| format!("y{i}")).collect(),
        Noise::Gaussian { sigma: Param::Fixed(sigma_y) },
    );
    let mut rng = StdRng::seed_from_u64(11);
    let truth =
        simulate(&p.model, theta, x0, &[], &SimulateOptions::new(0.0, t_end, 0.001), &mut rng).unwrap();
    let k = (t_end / every).round() as usize;
    let times: Vec<f64> = (1..=k).map(|i| i as f64 * every).collect();
    let data = sample_measurements_at(&obs, theta, &truth, n, &times, &mut rng).unwrap();
    (truth, data)
}

/// The smoothed path of `options` on the preset `name` at `theta` with all states measured
/// with sd `sigma_y`, the initial state N(`x0`, `prior_sd`²).
fn smooth_preset(
    name: &str,
    theta: &[f64],
    data: &Dataset,
    x0: &[f64],
    prior_sd: f64,
    sigma_y: f64,
    estimator: &crate::estimator::Estimator,
) -> PathEstimate {
    let mut p = preset(name).unwrap();
    let n = x0.len();
    p.theta = theta.to_vec();
    p.observation = StateMeasurement::new(
        (0..n).collect(),
        (0..n).map(|i| format!("y{i}")).collect(),
        Noise::Gaussian { sigma: Param::Fixed(sigma_y) },
    );
    p.x0_prior = x0.iter().map(|&m| Prior::gaussian(m, prior_sd)).collect();
    let mut problem = p.problem(data, &[]);
    problem.t0 = 0.0;
    estimator.run(&problem).unwrap().estimate
}

fn max_difference(a: &StatePath, b: &StatePath) -> f64 {
    a.values.iter().flatten().zip(b.values.iter().flatten()).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max)
}

#[test]
fn the_rules_are_exact_for_polynomial_drifts_of_their_degree() {
    // Identity: a Gauss–Hermite rule of p points per axis integrates ξ^a exactly for a ≤ 2p − 1,
    // so the closed moment equations of a drift of degree d (integrands of degree d + 1) are
    // exact once 2p − 1 ≥ d + 1; a rule of degree 3 is exact for a quadratic drift. Exact rules
    // give the same smoother to rounding; a rule below the degree does not.
    use crate::estimator::Estimator;
    let gh = |p: usize| {
        Estimator::GaussianKspClosure(
            GaussianKspOptions::default().with_rule(ExpectationRule::GaussHermite, Some(p)),
        )
    };
    let cub = |rule| Estimator::GaussianKspClosure(GaussianKspOptions::default().with_rule(rule, None));
    // Lorenz-63: quadratic drift (d = 2): 2 points per axis, cubature 3 and 5 and 6 points agree.
    let theta = [10.0, 28.0, 8.0 / 3.0, 10f64.sqrt()];
    let x0 = [-5.9, -5.5, 24.6];
    let (_, data) = record("lorenz63", &theta, &x0, 4.0, 0.2, 2f64.sqrt());
    let run = |e: &Estimator| smooth_preset("lorenz63", &theta, &data, &x0, 1.0, 2f64.sqrt(), e);
    let reference = run(&gh(6));
    for e in [gh(2), cub(ExpectationRule::Cubature3), cub(ExpectationRule::Cubature5)] {
        let d = max_difference(&run(&e).path, &reference.path);
        assert!(d < 1e-8, "{e:?} differs from 6 points per axis by {d}");
    }
    let d1 = max_difference(&run(&gh(1)).path, &reference.path);
    assert!(d1 > 1e-3, "one point per axis (degree 1) is not exact for Lorenz-63: {d1}");
    // The UKS's default sigma points are the degree-3 cubature rule: the same moment equations.
    let uks = run(&Estimator::new(Method::Uks));
    assert!(max_difference(&uks.path, &reference.path) < 1e-8);
    // Duffing: cubic drift (d = 3): 3 points per axis agree with 8, 2 points do not.
    let p = preset("duffing").unwrap();
    let (dx0, dtheta) = (vec![0.5, 0.0], p.theta.clone());
    let (_, ddata) = {
        let mut rng = StdRng::seed_from_u64(3);
        let truth = simulate(
            &p.model,
            &dtheta,
            &dx0[..p.model.dims().noisy],
            &dx0[p.model.dims().noisy..],
            &SimulateOptions::new(0.0, 4.0, 0.001),
            &mut rng,
        )
        .unwrap();
        let times: Vec<f64> = (1..=20).map(|i| 0.2 * i as f64).collect();
        let data =
            sample_measurements_at(&p.observation, &dtheta, &truth, p.model.dims().noisy, &times, &mut rng)
                .unwrap();
        (truth, data)
    };
    let drun = |e: &Estimator| {
        let mut problem = p.problem(&ddata, &[]);
        problem.t0 = 0.0;
        e.run(&problem).unwrap().estimate
    };
    let dref = drun(&gh(8));
    assert_eq!(dref.status, Status::Converged);
    assert!(max_difference(&drun(&gh(3)).path, &dref.path) < 1e-8);
    assert!(max_difference(&drun(&gh(2)).path, &dref.path) > 1e-8);
}

#[test]
fn on_a_lorenz63_record_it_converges_near_the_particle_smoother() {
    // The dense setting of the `lorenz63-smoothing` experiment (G = √10 I, all states measured
    // every 0.2 with variance 2) on a window of 4: the posterior is nearly Gaussian, and the
    // closure's RMSE to the truth is within 10 % of the particle smoother's (the experiment
    // states the 5 % of its 20 replicates on T = 20).
    use crate::estimator::Estimator;
    let theta = [10.0, 28.0, 8.0 / 3.0, 10f64.sqrt()];
    let x0 = [-5.9, -5.5, 24.6];
    let (truth, data) = record("lorenz63", &theta, &x0, 4.0, 0.2, 2f64.sqrt());
    let run = |e: &Estimator| smooth_preset("lorenz63", &theta, &data, &x0, 1.0, 2f64.sqrt(), e);
    let closure = run(&Estimator::new(Method::GaussianKspClosure));
    assert_eq!(closure.status, Status::Converged);
    let particle_options = ParticleOptions { particles: 2000, ..ParticleOptions::default() };
    let particle = run(&Estimator::Particle(particle_options));
    let rmse = |e: &PathEstimate| crate::metrics::rmse(&e.path, &truth, None).unwrap();
    let (rc, rp) = (rmse(&closure), rmse(&particle));
    assert!(rc < 1.1 * rp, "closure RMSE {rc}, particle smoother {rp}");
    assert!(rc < 2.0, "closure RMSE {rc} (all three states; the measurement sd is 1.41)");
}
