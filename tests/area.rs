//! The scalar area-rule closure (`003_d2fc48a470e528fc.txt (II.17)–(II.35)`).

use nalgebra::{DMatrix, DVector};

use onsager::action::closure::area::{area_action, AreaAction, AreaClosure, JumpRule, ScalarArea};
use onsager::action::EffectiveAction;
use onsager::estimate::Status;
use onsager::kalman::linear::{kalman_rts, LinearGaussianModel};
use onsager::model::library::{DoubleWell, Ou};
use onsager::model::prior::Prior;
use onsager::test_models::DoubleWellRecord;
use onsager::test_models::OuRecord;
use onsager::{Estimator, Method};

/// The measured function of the Z ≠ M tests: increasing, so Cov(Z, x) > 0.
fn z_cubic(x: f64) -> f64 {
    x + 0.3 * x * x * x
}

fn double_well_family(jumps: JumpRule, z: impl Fn(f64) -> f64) -> ScalarArea<'static, DoubleWell> {
    ScalarArea::try_new(&DoubleWell, &DoubleWell::NOMINAL, 0.0, (-3.5, 3.5), 12, z)
        .unwrap()
        .with_jumps(jumps, 64)
}

fn central(f: impl Fn(f64) -> f64, x: f64, h: f64) -> f64 {
    (f(x + h) - f(x - h)) / (2.0 * h)
}

#[test]
fn the_area_rules_satisfy_their_differential_identities() {
    // (II.27) ∂μ⁺/∂λ = C^Z(μ⁺), (II.29) ∂ΔF/∂λ = ζ(μ⁺), (II.30) ∂μ⁺/∂μ⁻ = C^{Z+}/C^{Z−} and
    // ∂ΔF/∂μ⁻ = (ζ⁺ − ζ⁻)/C^{Z−}, each by central differences of the integrated area rules, for
    // Z = x + 0.3x³ ≠ M = x, at several (θ⁻, λ).
    let fam = double_well_family(JumpRule::Area, z_cubic);
    for &(theta_minus, lambda) in &[(-1.5, 0.7), (0.3, -1.2), (2.0, 0.05), (-0.2, 2.5)] {
        let (theta_plus, _) = fam.jump(theta_minus, lambda).unwrap();
        let (plus, minus) = (fam.moments(theta_plus).unwrap(), fam.moments(theta_minus).unwrap());
        let mu_plus = |l: f64| fam.moments(fam.jump(theta_minus, l).unwrap().0).unwrap().mu;
        let df = |l: f64| fam.jump(theta_minus, l).unwrap().1;
        let h = 1e-4;
        let d27 = central(mu_plus, lambda, h);
        let d29 = central(df, lambda, h);
        assert!((d27 - plus.cz).abs() <= 1e-7 * plus.cz.abs().max(1e-3), "(II.27) {d27} vs {}", plus.cz);
        assert!((d29 - plus.zeta).abs() <= 1e-7 * (1.0 + plus.zeta.abs()), "(II.29) {d29} vs {}", plus.zeta);
        // (II.30): vary μ⁻ through θ⁻.
        let mu_minus = |th: f64| fam.moments(th).unwrap().mu;
        let dmu_minus = central(mu_minus, theta_minus, h);
        let dmu_plus = central(|th| fam.moments(fam.jump(th, lambda).unwrap().0).unwrap().mu, theta_minus, h);
        let ddf = central(|th| fam.jump(th, lambda).unwrap().1, theta_minus, h);
        let ratio = dmu_plus / dmu_minus;
        assert!(
            (ratio - plus.cz / minus.cz).abs() <= 1e-6 * ratio.abs(),
            "(II.30a) {ratio} vs {}",
            plus.cz / minus.cz
        );
        let want = (plus.zeta - minus.zeta) / minus.cz;
        let got = ddf / dmu_minus;
        assert!((got - want).abs() <= 1e-6 * (1.0 + want.abs()), "(II.30b) {got} vs {want}");
    }
}

#[test]
fn the_z_equals_m_jumps_are_the_differences_of_the_explicit_functions() {
    // Z = M = x: the area rules integrated in λ (II.19), (II.23) and the differences of
    // λ(μ) = θ and F = log N (II.34)–(II.35) agree to the Runge–Kutta error in λ.
    let area = double_well_family(JumpRule::Area, |x| x);
    let explicit = double_well_family(JumpRule::Explicit, |x| x);
    for &(theta_minus, lambda) in &[(-1.5, 0.7), (0.3, -1.2), (2.0, 0.05), (-0.2, 2.5)] {
        let (ta, fa) = area.jump(theta_minus, lambda).unwrap();
        let (te, fe) = explicit.jump(theta_minus, lambda).unwrap();
        assert!((te - (theta_minus + lambda)).abs() <= 1e-15 * (1.0 + te.abs()));
        assert!((ta - te).abs() <= 1e-9 * (1.0 + te.abs()), "θ⁺ {ta} vs {te}");
        assert!((fa - fe).abs() <= 1e-9 * (1.0 + fe.abs()), "ΔF {fa} vs {fe}");
        // (II.33): F′ = μ, F″ = C.
        let f = |th: f64| explicit.moments(th).unwrap().log_partition;
        let m = explicit.moments(te).unwrap();
        assert!((central(f, te, 1e-4) - m.mu).abs() <= 1e-7 * (1.0 + m.mu.abs()));
        assert!(((f(te + 1e-3) - 2.0 * f(te) + f(te - 1e-3)) / 1e-6 - m.c).abs() <= 1e-5 * m.c);
    }
}

/// z = ∂F/∂λ of the adjoint against central differences of F, on `action` at `lambda`.
fn check_gradient<S: onsager::model::Sde>(action: &mut AreaAction<'_, S>, lambda: &[f64], tol: f64) {
    let v = action.evaluate(lambda).unwrap();
    assert!(v.value.is_finite());
    for k in 0..lambda.len() {
        let mut l = lambda.to_vec();
        let h = 1e-5;
        l[k] += h;
        let fp = action.evaluate(&l).unwrap().value;
        l[k] -= 2.0 * h;
        let fm = action.evaluate(&l).unwrap().value;
        let fd = (fp - fm) / (2.0 * h);
        assert!(
            (v.z[k] - fd).abs() <= tol * (1.0 + fd.abs()),
            "z_{k}: adjoint {} vs difference {fd}",
            v.z[k]
        );
    }
}

#[test]
fn the_adjoint_gives_the_gradient_of_f_on_a_double_well_record() {
    // ∂F_Z/∂λ_k by the backward sweep ((II.21) and the adjoint flow) equals the central
    // difference of F_Z = Σ(ΔF)_k (II.22), for Z = M (explicit jumps) and for Z = x + 0.3x³
    // (area rules), on a double-well record with 8 measurements that changes wells.
    let rec = DoubleWellRecord::new(3, 8.0).unwrap();
    let lambda: Vec<f64> = (0..8).map(|k| 1.5 * (0.9 * k as f64).sin()).collect();
    let options = AreaClosure::default().with_output_step(0.1);
    let mut explicit = area_action(&rec.problem(), &options).unwrap();
    check_gradient(&mut explicit, &lambda, 1e-8);
    // The estimate is continuous across the jumps (II.20): at t_k the history is z_k.
    let z = explicit.evaluate(&lambda).unwrap().z;
    let hist = explicit.history(&lambda, false).unwrap().unwrap();
    for (k, &t) in rec.data.times.iter().enumerate() {
        let i = hist.times.iter().position(|&s| (s - t).abs() < 1e-9).unwrap();
        assert!((hist.mean[i][0] - z[k]).abs() <= 1e-10, "x̂(t_{k}) = {} vs z = {}", hist.mean[i][0], z[k]);
    }
    let mut area = area_action(&rec.problem(), &options.clone().with_jumps(JumpRule::Area)).unwrap();
    let za = area.evaluate(&lambda).unwrap();
    let ze = explicit.evaluate(&lambda).unwrap();
    assert!((za.value - ze.value).abs() <= 1e-8 * (1.0 + ze.value.abs()), "F {} vs {}", za.value, ze.value);
    for (a, e) in za.z.iter().zip(&ze.z) {
        assert!((a - e).abs() <= 1e-8, "z {a} vs {e}");
    }
    let fam = double_well_family(JumpRule::Area, z_cubic);
    let theta0 = fam.theta_of_mean(-1.0).unwrap();
    let mut cubic = AreaAction::try_new(fam, 0.0, theta0, &rec.data.times, &[], 0.01).unwrap();
    let small: Vec<f64> = lambda.iter().map(|l| 0.3 * l).collect();
    check_gradient(&mut cubic, &small, 1e-7);
}

#[test]
fn a_failed_area_sweep_says_where_and_why() {
    // A multiplier of 10⁸ at the third measurement tilts the density onto the domain's edge:
    // the sweep has no value, and the action keeps the time and the reason for the report.
    let rec = DoubleWellRecord::new(3, 8.0).unwrap();
    let mut action = area_action(&rec.problem(), &AreaClosure::default()).unwrap();
    assert_eq!(action.last_failure(), None);
    let mut lambda = vec![0.0; 8];
    lambda[2] = 1e8;
    let value = action.evaluate(&lambda).unwrap();
    assert!(value.value.is_nan());
    let why = action.last_failure().expect("a reason");
    let at = format!("at t = {:.4}:", rec.data.times[2]);
    assert!(why.starts_with(&at) && why.contains("measurement 2"), "{why}");
}

#[test]
fn area_closure_of_ou_with_the_stationary_prior_is_the_rts_smoother() {
    // Linear drift, Z = M = x, reference the stationary N(0, σ²/(2θ)): the jumps are
    // μ⁺ = μ⁻ + λ_k v_s, ΔF = λ_kμ⁻ + ½λ_k²v_s and μ − m relaxes as e^{−θt}, so F_Z is the
    // cumulant generating function of the Gaussian process with covariance e^{−θ|t−s|}v_s: the
    // OU started from its stationary variance. With that x0 prior the estimate and its
    // dispersion are the RTS smoother's.
    let mut ou = OuRecord::new().unwrap();
    let vs = 0.5f64.powi(2) / 2.0;
    ou.x0_prior = [Prior::gaussian(0.2, vs.sqrt())];
    let options = AreaClosure::default()
        .with_output_step(0.1)
        .with_dual(onsager::action::DualOptions::default().with_tolerance(1e-10));
    let run = Estimator::AreaClosure(options).run(&ou.problem()).unwrap();
    let est = run.estimate;
    assert_eq!(est.status, Status::Converged);
    assert_eq!(est.method, Method::AreaClosure);
    let model = LinearGaussianModel::from_sde(
        &Ou,
        &ou.theta,
        &ou.observation,
        0.0,
        DVector::from_element(1, 0.2),
        DMatrix::from_element(1, 1, vs),
    )
    .unwrap();
    let kf = kalman_rts(&model, &ou.data, &est.path.times).unwrap();
    let sd = est.path.sd.as_ref().unwrap();
    let (mut e_mean, mut e_sd) = (0.0f64, 0.0f64);
    for (i, &t) in est.path.times.iter().enumerate() {
        let j = kf.index_of(t).unwrap();
        e_mean = e_mean.max((est.path.values[i][0] - kf.smoothed_mean[j][0]).abs());
        e_sd = e_sd.max((sd[i][0] - kf.smoothed_cov[j][(0, 0)].sqrt()).abs());
    }
    assert!(e_mean < 1e-7, "max |area closure − RTS| = {e_mean}");
    assert!(e_sd < 1e-5, "max |sd − RTS sd| = {e_sd}");
}

#[test]
fn area_closure_estimates_the_double_well_and_refuses_what_it_cannot_take() {
    let rec = DoubleWellRecord::new(3, 8.0).unwrap();
    let run = Estimator::new(Method::AreaClosure).run(&rec.problem()).unwrap();
    assert!(run.estimate.status.is_success(), "{:?}", run.estimate.status);
    assert!(run.estimate.path.values.iter().all(|v| v[0].is_finite()));
    // The default box is reported: the data and the prior mean ± 5 sd, widened.
    let domain = &run.estimate.details["domain"][0];
    let (a, b) = (domain[0].as_f64().unwrap(), domain[1].as_f64().unwrap());
    assert!(rec.data.values.iter().all(|y| (a + 1.0..=b - 1.0).contains(&y[0])), "[{a}, {b}]");
    // A box that does not cover the data: an error naming the datum, not a truncated estimate.
    let narrow = AreaClosure::default().with_domain(-0.5, 0.5);
    let err = Estimator::AreaClosure(narrow).run(&rec.problem()).unwrap_err();
    assert!(
        matches!(err, onsager::Error::InvalidOption { .. })
            && err.to_string().contains("the box [-0.5, 0.5] of state `x` does not cover the datum y = "),
        "{err}"
    );
    // Two states: not applicable, with the reason.
    let p = onsager::model::library::preset("lorenz63").unwrap();
    let data = onsager::data::Dataset { names: vec![], times: vec![], values: vec![] };
    let why = Estimator::new(Method::AreaClosure).applies_to(&p.problem(&data, &[])).unwrap_err();
    assert!(why.reason.contains("one-state"), "{why}");
}
