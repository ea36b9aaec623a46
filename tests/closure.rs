//! The Rayleigh–Ritz closure estimators (issue 7).

use approx::assert_relative_eq;
use nalgebra::DMatrix;
use rand::rngs::StdRng;
use rand::SeedableRng;

use onsager::action::closure::om::MomentPathOptions;
use onsager::action::closure::{closure_action, Closure, ExponentialFamily, GaussianFamily, NodeRule};
use onsager::action::exact::gaussian_dual_data;
use onsager::action::{
    maximize_dual, mean_optimal, ClosureOptions, DualOptions, EffectiveAction, ExactOptions, GridSpec,
};
use onsager::data::Dataset;
use onsager::estimate::PathEstimate;
use onsager::estimate::{EstimationProblem, Status};
use onsager::model::library::DoubleWell;
use onsager::model::observation::StateMeasurement;
use onsager::model::prior::Prior;
use onsager::model::Sde;
use onsager::simulate::{sample_measurements_at, simulate, SimulateOptions};
use onsager::test_models::{
    gaussian_measurement, DampedRotation, DoubleWellRecord, LagRecord, OuRecord, Start,
};
use onsager::{Error, Estimator};

/// The closures of these tests, each with the options of the dual closures (the moment-path
/// closures take the output step as their grid step).
#[derive(Debug, Clone, Copy, PartialEq)]
enum ClosureKind {
    Gaussian,
    Exponential { degree: usize },
    Ksp,
    DoubleExponential,
}

impl ClosureKind {
    fn estimator(self, options: &ClosureOptions) -> Estimator {
        let mut path = MomentPathOptions::new();
        path.step = options.output_step;
        match self {
            ClosureKind::Gaussian => Estimator::GaussianClosure(Closure::gaussian(options.clone())),
            ClosureKind::Exponential { degree } => {
                Estimator::ExpClosure(Closure::exponential(degree, options.clone()))
            }
            ClosureKind::Ksp => Estimator::KspClosure(path),
            ClosureKind::DoubleExponential => Estimator::DoubleExpClosure(path),
        }
    }

    fn method_name(self) -> &'static str {
        self.estimator(&ClosureOptions::new()).name()
    }
}

/// The estimate of closure `kind` on `problem`.
fn closure_estimate(
    problem: &EstimationProblem<'_, impl Sde, StateMeasurement>,
    kind: &ClosureKind,
    options: &ClosureOptions,
) -> onsager::Result<PathEstimate> {
    kind.estimator(options).run(problem).map(|r| r.estimate)
}

fn gaussian_closure_action<'a, S: Sde>(
    problem: &EstimationProblem<'a, S, StateMeasurement>,
    options: &ClosureOptions,
) -> onsager::Result<onsager::action::ClosureAction<onsager::action::closure::GaussianDrift<'a, S>>> {
    closure_action(problem, &Closure::gaussian(options.clone()))
}

fn exponential_closure_action<'a, S: Sde>(
    problem: &EstimationProblem<'a, S, StateMeasurement>,
    degree: usize,
    options: &ClosureOptions,
) -> onsager::Result<onsager::action::ClosureAction<onsager::action::closure::ExponentialDrift<'a, S>>> {
    closure_action(problem, &Closure::exponential(degree, options.clone()))
}

#[test]
fn gaussian_closure_of_ou_is_the_rts_smoother() {
    // The Gaussian closure is exact for linear dynamics: its mean-optimal estimate is the RTS
    // smoothed mean (the Kalman reference, Särkkä 2013 Thm 8.2, on the exact discretisation) and
    // its dispersion the smoothed sd, to the ODE tolerance.
    let ou = OuRecord::new().unwrap().with_theta_prior([Prior::flat(); 2]);
    let (problem, data) = (ou.problem(), &ou.data);
    let options = ClosureOptions::new().with_tolerances(1e-10, 1e-12).with_output_step(0.1);
    let est = closure_estimate(&problem, &ClosureKind::Gaussian, &options).unwrap();
    assert_eq!(est.status, Status::Converged);
    assert_eq!(est.method, onsager::Method::GaussianClosure);
    // The cost counters: every counted sweep takes at least one Runge–Kutta step per interval
    // between measurements, and far fewer are rejected; a converged dual has no stop reason.
    let count = |key: &str| est.details[key].as_u64().unwrap();
    assert!(count("sweeps") >= 1 && count("rk_steps") >= count("sweeps") * (data.len() as u64 - 1));
    assert!(count("rk_rejected") < count("rk_steps") / 4, "{:?}", est.details);
    assert!(!est.details.contains_key("dual_reason"));
    let kf = ou.rts(&est.path.times).unwrap();
    let sd = est.path.sd.as_ref().unwrap();
    let mut max_err: f64 = 0.0;
    for (i, &t) in est.path.times.iter().enumerate() {
        let j = kf.index_of(t).unwrap();
        max_err = max_err.max((est.path.values[i][0] - kf.smoothed_mean[j][0]).abs());
        assert_relative_eq!(sd[i][0], kf.smoothed_cov[j][(0, 0)].sqrt(), epsilon = 1e-5);
    }
    assert!(max_err < 1e-7, "max |closure − RTS| = {max_err}");
}

#[test]
fn the_continuation_rule_gives_the_rts_smoother_on_ou() {
    // Linear dynamics: the curve of stationary points from the prior is λ(s) = s(R + sC)⁻¹(r − μ),
    // without folds, and its end is the RTS smoothed mean, as from the filter start.
    let ou = OuRecord::new().unwrap().with_theta_prior([Prior::flat(); 2]);
    let problem = ou.problem();
    let options = ClosureOptions::new()
        .with_tolerances(1e-10, 1e-12)
        .with_output_step(0.1)
        .with_branch(onsager::action::BranchRule::Continuation);
    let est = closure_estimate(&problem, &ClosureKind::Gaussian, &options).unwrap();
    assert_eq!(est.status, Status::Converged);
    assert_eq!(est.details["dual_start"], "continuation");
    let kf = ou.rts(&est.path.times).unwrap();
    let max_err = est
        .path
        .times
        .iter()
        .enumerate()
        .map(|(i, &t)| (est.path.values[i][0] - kf.smoothed_mean[kf.index_of(t).unwrap()][0]).abs())
        .fold(0.0, f64::max);
    assert!(max_err < 1e-7, "max |closure − RTS| = {max_err}");
}

#[test]
fn filter_start_satisfies_the_filter_condition() {
    // Each multiplier of the closure's assumed-density filter solves μ_x(t_k+) = r_k − Rλ_k with
    // the earlier multipliers fixed.
    let case = double_well_case(3, 6.0);
    let (problem, data) = (case.problem(), &case.data);
    let dd = gaussian_dual_data(&problem).unwrap();
    let options = ClosureOptions::new();
    let mut gaussian = gaussian_closure_action(&problem, &options).unwrap();
    let mut quartic = exponential_closure_action(&problem, 4, &options).unwrap();
    let starts = [gaussian.filter_start(&dd).unwrap(), quartic.filter_start(&dd).unwrap()];
    let paths = [
        gaussian.moment_paths(&starts[0]).unwrap().unwrap(),
        quartic.moment_paths(&starts[1]).unwrap().unwrap(),
    ];
    for (lambda, onsager::action::closure::sweep::MomentPaths { times, mu, .. }) in starts.iter().zip(&paths)
    {
        for (k, &t) in data.times.iter().enumerate() {
            let e = times.iter().position(|&s| s == t).unwrap();
            // To the ODE tolerance (moment_paths integrates with the output times as events too).
            assert_relative_eq!(mu[e][0], dd.r[k] - dd.variance[k] * lambda[k], epsilon = 1e-6);
        }
    }
}

#[test]
fn the_filter_start_leaves_the_evaluation_at_its_multipliers() {
    // The filter's forward sweep is the forward sweep of F at the chosen multipliers, so the
    // evaluation it caches equals a fresh one, bit for bit.
    let case = double_well_case(3, 6.0);
    let problem = case.problem();
    let dd = gaussian_dual_data(&problem).unwrap();
    let options = ClosureOptions::new();
    let mut cached = exponential_closure_action(&problem, 4, &options).unwrap();
    let start = cached.filter_start(&dd).unwrap();
    let sweeps = cached.sweeps();
    let from_cache = cached.evaluate(&start).unwrap();
    assert_eq!(cached.sweeps(), sweeps, "the evaluation at the filter start ran a sweep");
    let mut fresh = exponential_closure_action(&problem, 4, &options).unwrap();
    assert_eq!(from_cache, fresh.evaluate(&start).unwrap());
    let mut gaussian = gaussian_closure_action(&problem, &options).unwrap();
    let start = gaussian.filter_start(&dd).unwrap();
    let sweeps = gaussian.sweeps();
    let from_cache = gaussian.evaluate(&start).unwrap();
    assert_eq!(gaussian.sweeps(), sweeps, "the Gaussian evaluation at the filter start ran a sweep");
    let mut fresh = gaussian_closure_action(&problem, &options).unwrap();
    assert_eq!(from_cache, fresh.evaluate(&start).unwrap());
    // The same tolerances again keep it.
    let (rtol, atol) = gaussian.tolerances();
    gaussian.set_tolerances(rtol, atol).unwrap();
    assert_eq!(gaussian.evaluate(&start).unwrap(), from_cache);
    assert_eq!(gaussian.sweeps(), sweeps);
    // New tolerances forget the cached evaluation: F is that of the new sweeps.
    gaussian.set_tolerances(1e-9, 1e-12).unwrap();
    let tight = gaussian.evaluate(&start).unwrap();
    assert_eq!(gaussian.sweeps(), sweeps + 1);
    assert_ne!(tight, from_cache);
    assert_relative_eq!(tight.value, from_cache.value, max_relative = 1e-4);
    assert!(gaussian.set_tolerances(0.0, 1e-9).is_err());
}

#[test]
fn the_two_stage_dual_reaches_the_one_stage_maximiser() {
    // closure_estimate runs the dual first with coarse sweeps, then chord steps at the requested
    // tolerance; the one-stage iteration (the filter start, then `maximize_dual` with every sweep
    // at the requested tolerance) reaches the same λ* (both to the optimality residual 10⁻⁹).
    let case = double_well_case(5, 20.0);
    let problem = case.problem();
    let dd = gaussian_dual_data(&problem).unwrap();
    let options = ClosureOptions::new().with_dispersion(false).with_dual_matched_to_sweeps(false);
    for (kind, degree) in [(ClosureKind::Gaussian, None), (ClosureKind::Exponential { degree: 4 }, Some(4))] {
        let est = closure_estimate(&problem, &kind, &options).unwrap();
        assert_eq!(est.status, Status::Converged, "{kind:?}");
        let coarse = &est.details["coarse_stage"];
        assert_relative_eq!(coarse["rtol"].as_f64().unwrap(), 1e-4, max_relative = 1e-12);
        assert!(coarse["iterations"].as_u64().unwrap() >= 1);
        let staged: Vec<f64> =
            est.details["lambda"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
        let one_stage = match degree {
            None => {
                let mut a = gaussian_closure_action(&problem, &options).unwrap();
                let start = a.filter_start(&dd).unwrap();
                maximize_dual(&mut a, &dd, &DualOptions::default(), Some(&start)).unwrap()
            }
            Some(d) => {
                let mut a = exponential_closure_action(&problem, d, &options).unwrap();
                let start = a.filter_start(&dd).unwrap();
                maximize_dual(&mut a, &dd, &DualOptions::default(), Some(&start)).unwrap()
            }
        };
        assert_eq!(one_stage.status, Status::Converged, "{kind:?}");
        let diff = staged.iter().zip(&one_stage.lambda).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        assert!(diff < 1e-7, "{kind:?}: max |λ staged − λ one stage| = {diff}");
        // No coarser tolerance to run at: one stage.
        let loose = ClosureOptions::new().with_dispersion(false).with_tolerances(1e-4, 1e-7);
        let est = closure_estimate(&problem, &kind, &loose).unwrap();
        assert_eq!(est.status, Status::Converged, "{kind:?}");
        assert!(!est.details.contains_key("coarse_stage"));
    }
}

#[test]
fn the_dual_matched_to_the_sweeps_stops_where_the_estimate_no_longer_moves() {
    // By default the dual may stop at the residual 0.1 · (rtol · max|y| + atol) / max R: the
    // estimate then differs from the one at the dual tolerance 10⁻⁹ by about R times the
    // residual, far below the sweeps' own accuracy (rtol 10⁻⁶ here).
    let case = double_well_case(5, 20.0);
    let problem = case.problem();
    let y_max = case.data.values.iter().flatten().fold(0.0f64, |a, v| a.max(v.abs()));
    let matched = 0.1 * (1e-6 * y_max + 1e-9) / 0.04;
    let strict = ClosureOptions::new().with_dispersion(false).with_dual_matched_to_sweeps(false);
    let options = ClosureOptions::new().with_dispersion(false);
    for kind in [ClosureKind::Gaussian, ClosureKind::Exponential { degree: 4 }] {
        let a = closure_estimate(&problem, &kind, &options).unwrap();
        let b = closure_estimate(&problem, &kind, &strict).unwrap();
        assert_eq!((a.status, b.status), (Status::Converged, Status::Converged), "{kind:?}");
        let tol = a.details["dual_tolerance"].as_f64().unwrap();
        assert_relative_eq!(tol, matched, max_relative = 1e-12);
        assert_eq!(b.details["dual_tolerance"].as_f64().unwrap(), 1e-9);
        let residual = a.details["optimality_residual"].as_f64().unwrap();
        assert!(residual <= tol, "{kind:?}: residual {residual} above {tol}");
        // It stopped earlier: a sweep fewer than at 10⁻⁹.
        let sweeps = |e: &onsager::estimate::PathEstimate| e.details["sweeps"].as_u64().unwrap();
        assert!(sweeps(&a) < sweeps(&b), "{kind:?}: {} sweeps against {}", sweeps(&a), sweeps(&b));
        let diff = sup_diff(&a.path.values, &b.path.values);
        assert!(diff <= 0.04 * tol, "{kind:?}: the estimates differ by {diff}");
    }
    // A dual tolerance above the matched one stands.
    let loose = options.clone().with_dual(DualOptions::default().with_tolerance(1e-4));
    let est = closure_estimate(&problem, &ClosureKind::Gaussian, &loose).unwrap();
    assert_eq!(est.details["dual_tolerance"].as_f64().unwrap(), 1e-4);
}

/// max_k |a_k − b_k| of the first columns of two paths (rows of values at the same times).
fn sup_diff(a: &[Vec<f64>], b: &[Vec<f64>]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x[0] - y[0]).abs()).fold(0.0, f64::max)
}

/// A double-well record (D = 0.5, x(0) = −1, y ~ N(x(k), 0.2²) at k = 1, …, t_end) and the
/// closures' problem on it (a flat prior on D, x0 ~ N(−1, 0.3²)).
fn double_well_case(seed: u64, t_end: f64) -> DoubleWellRecord {
    let record = DoubleWellRecord::new(seed, t_end).unwrap();
    record.with_theta_prior(Prior::flat()).with_x0_prior(Prior::gaussian(-1.0, 0.3))
}

/// The `exp-closure` estimate of `family` with `options` on `problem`.
fn exp_closure(
    problem: &EstimationProblem<'_, impl Sde, StateMeasurement>,
    family: ExponentialFamily,
    options: &ClosureOptions,
) -> PathEstimate {
    Estimator::ExpClosure(Closure::new(family, options.clone())).run(problem).unwrap().estimate
}

/// ∇²F of the tangent sweeps against central differences of the adjoint gradient z(λ).
fn check_hessian<A: EffectiveAction>(action: &mut A, lambda: &[f64]) {
    let h = action.hessian(lambda).unwrap().unwrap();
    let m = lambda.len();
    for j in 0..m {
        let step = 1e-4;
        let mut l = lambda.to_vec();
        l[j] += step;
        let zp = action.evaluate(&l).unwrap().z;
        l[j] -= 2.0 * step;
        let zm = action.evaluate(&l).unwrap().z;
        for i in 0..m {
            let fd = (zp[i] - zm[i]) / (2.0 * step);
            assert_relative_eq!(h[(i, j)], fd, max_relative = 1e-6, epsilon = 1e-8);
        }
    }
}

/// The cross-covariances of the history, ∂m_x(τ)/∂λ_j by the tangent sweeps chained over the
/// intervals between events (output times between the measurements too), against central
/// differences of m_x(τ); at the measurement times they form ∇²F, symmetric to round-off before
/// any symmetrisation and equal to [`EffectiveAction::hessian`]'s. Gaussian and quartic closures.
#[test]
fn cross_covariances_are_the_derivatives_of_the_history() {
    let case = double_well_case(3, 4.0);
    let problem = case.problem();
    let options = ClosureOptions::new().with_output_step(0.25).with_tolerances(1e-12, 1e-13);
    fn check<A: EffectiveAction>(mut action: A, lambda: &[f64]) {
        let h = action.history(lambda, true).unwrap().unwrap();
        let cross = h.cross.as_ref().unwrap();
        let step = 1e-4;
        for j in 0..lambda.len() {
            let mut l = lambda.to_vec();
            l[j] += step;
            let plus = action.history(&l, false).unwrap().unwrap().mean;
            l[j] -= 2.0 * step;
            let minus = action.history(&l, false).unwrap().unwrap().mean;
            for e in 0..h.times.len() {
                let fd = (plus[e][0] - minus[e][0]) / (2.0 * step);
                assert_relative_eq!(cross[e][(0, j)], fd, max_relative = 1e-6, epsilon = 1e-8);
            }
        }
        let meas: Vec<usize> =
            action.measurement_times().iter().map(|t| h.times.iter().position(|s| s == t).unwrap()).collect();
        let hess = DMatrix::from_fn(lambda.len(), lambda.len(), |i, j| cross[meas[i]][(0, j)]);
        let asym = (&hess - hess.transpose()).amax();
        assert!(asym <= 1e-10 * hess.amax(), "∇²F asymmetric by {asym}: {hess}");
        // The same ∇²F as `hessian`, whose sweep has the measurement times only as events
        // (another step sequence: equal to the ODE tolerance).
        let fit = action.hessian(lambda).unwrap().unwrap();
        for (a, b) in fit.iter().zip(((&hess + hess.transpose()) * 0.5).iter()) {
            assert_relative_eq!(*a, *b, max_relative = 1e-7, epsilon = 1e-9);
        }
    }
    let lambda = [1.5, -2.0, 0.7, 3.0];
    check(gaussian_closure_action(&problem, &options).unwrap(), &lambda);
    check(exponential_closure_action(&problem, 4, &options).unwrap(), &lambda);
}

#[test]
fn quartic_closure_gradient_is_the_adjoint_and_the_history_is_continuous() {
    let case = double_well_case(3, 4.0);
    let (problem, data) = (case.problem(), &case.data);
    // Output times t_k ± ε, 2ε on both sides of every jump for the one-sided limits of m(t).
    let eps = 1e-5;
    let mut extra = Vec::new();
    for &t in &data.times[..data.times.len() - 1] {
        extra.extend([t - 2.0 * eps, t - eps, t + eps, t + 2.0 * eps]);
    }
    let options = ClosureOptions::new().with_tolerances(1e-12, 1e-13).with_extra_times(&extra);
    let mut action = exponential_closure_action(&problem, 4, &options).unwrap();
    let lambda = [1.5, -2.0, 0.7, 3.0];
    let v = action.evaluate(&lambda).unwrap();
    // ∂F/∂λ_k by the adjoint (A.30) = central differences of F (step 1e-4: truncation ~1e-8·F''').
    for k in 0..4 {
        let h = 1e-4;
        let mut l = lambda;
        l[k] += h;
        let fp = action.evaluate(&l).unwrap().value;
        l[k] -= 2.0 * h;
        let fm = action.evaluate(&l).unwrap().value;
        let fd = (fp - fm) / (2.0 * h);
        assert_relative_eq!(v.z[k], fd, max_relative = 1e-7, epsilon = 1e-9);
    }
    // ∇²F by the tangent sweeps (second-order adjoint) = differences of the gradient.
    check_hessian(&mut action, &lambda);
    // (II.44): m(t) is continuous across the jumps while μ(t) jumps; one-sided limits by linear
    // extrapolation from t_k ± ε, t_k ± 2ε (error O(ε² m'') ≈ 1e-10), to the 1e-8.
    let onsager::action::closure::sweep::MomentPaths { times, m, mu } =
        action.moment_paths(&lambda).unwrap().unwrap();
    let at = |t: f64| times.iter().position(|&s| (s - t).abs() < 1e-12).unwrap();
    for &tk in &data.times[..data.times.len() - 1] {
        for a in 0..4 {
            let left = 2.0 * m[at(tk - eps)][a] - m[at(tk - 2.0 * eps)][a];
            let right = 2.0 * m[at(tk + eps)][a] - m[at(tk + 2.0 * eps)][a];
            let scale = 1.0 + m[at(tk)][a].abs();
            assert!((left - right).abs() < 1e-8 * scale, "m_{a} jumps at {tk}: {left} vs {right}");
            let jump_mu = (mu[at(tk + eps)][a] - mu[at(tk - eps)][a]).abs();
            assert!(jump_mu > 1e-3, "μ_{a} should jump at {tk} (got {jump_mu})");
        }
    }
}

#[test]
fn gaussian_closure_gradient_is_the_adjoint() {
    let case = double_well_case(5, 3.0);
    let problem = case.problem();
    let options = ClosureOptions::new().with_tolerances(1e-12, 1e-13);
    let mut action = gaussian_closure_action(&problem, &options).unwrap();
    let lambda = [2.0, -1.0, 4.0];
    let v = action.evaluate(&lambda).unwrap();
    for k in 0..3 {
        let h = 1e-4;
        let mut l = lambda;
        l[k] += h;
        let fp = action.evaluate(&l).unwrap().value;
        l[k] -= 2.0 * h;
        let fm = action.evaluate(&l).unwrap().value;
        assert_relative_eq!(v.z[k], (fp - fm) / (2.0 * h), max_relative = 1e-7, epsilon = 1e-9);
    }
    check_hessian(&mut action, &lambda);
    // The dual solution satisfies (I.60) with this action.
    let dd = gaussian_dual_data(&problem).unwrap();
    let sol = maximize_dual(&mut action, &dd, &DualOptions::default(), None).unwrap();
    assert_eq!(sol.status, Status::Converged);
}

#[test]
fn unsupported_combinations_are_clear_errors() {
    assert_eq!(Estimator::parse("exp-closure").unwrap(), Estimator::ExpClosure(Closure::default()));
    assert_eq!(Estimator::parse("gaussian-closure").unwrap().name(), "gaussian-closure");
    assert!(matches!(Estimator::parse("exp-closure:moments=1"), Err(Error::EstimatorOption { .. })));
    assert!(matches!(Estimator::parse("gaussian-closure:moments=3"), Err(Error::EstimatorOption { .. })));
    assert!(matches!(Estimator::parse("nope"), Err(Error::UnknownName { .. })));
    let case = double_well_case(1, 2.0);
    let problem = case.problem();
    // The moment-path closures (tested in `action::closure::om`) are reached through
    // `closure_estimate`.
    for kind in [ClosureKind::Ksp, ClosureKind::DoubleExponential] {
        let est = closure_estimate(&problem, &kind, &ClosureOptions::new()).unwrap();
        assert_eq!(est.method.name(), kind.method_name());
        assert_eq!(est.status, Status::Converged);
    }
    let flat = [Prior::flat()];
    let p2 = EstimationProblem { x0_prior: &flat, ..problem };
    let err = closure_estimate(&p2, &ClosureKind::Gaussian, &ClosureOptions::new()).unwrap_err();
    assert!(err.to_string().contains("Gaussian initial prior"), "{err}");
    // A 2-state model with the exponential closure.
    let vdp = onsager::model::library::VanDerPol;
    let obs2 = gaussian_measurement(0, 0.2);
    let d2 = Dataset::try_new(vec!["y".into()], vec![0.5], vec![vec![0.1]]).unwrap();
    let th = vec![2.0, 0.1];
    let tp = vec![Prior::flat(); vdp.dims().params];
    let x2 = [Prior::gaussian(0.0, 0.1), Prior::gaussian(0.0, 0.1)];
    let p3 = EstimationProblem {
        sde: &vdp,
        observation: &obs2,
        theta: &th,
        theta_prior: &tp,
        estimate: &[],
        x0_prior: &x2,
        z0_prior: &[],
        data: &d2,
        t0: 0.0,
        seed: 0,
        max_memory: Default::default(),
    };
    // Measurement times must increase (direct construction of the action).
    let (drift, lambda0) = (
        onsager::action::closure::GaussianDrift::try_new(&DoubleWell, &[0.5]).unwrap(),
        vec![-1.0 / 0.09, -0.5 / 0.09],
    );
    let tolerances = onsager::action::closure::SweepTolerances { rtol: 1e-6, atol: 1e-9 };
    let err =
        onsager::action::ClosureAction::try_new(drift, 0.0, lambda0, &[2.0, 1.0], vec![0], &[], tolerances)
            .unwrap_err();
    assert!(err.to_string().contains("strictly increasing"), "{err}");
    // Two states but one domain interval.
    let one_interval =
        Closure::new(ExponentialFamily::of_degree(4).with_domain(&[(-3.0, 3.0)]), ClosureOptions::new());
    let err = Estimator::ExpClosure(one_interval).run(&p3).unwrap_err();
    assert!(err.to_string().contains("one interval per state"), "{err}");
    // A box that does not cover a datum of the measured state (y = 0.1 at t = 0.5).
    let narrow = Closure::new(
        ExponentialFamily::of_degree(4).with_domain(&[(-3.0, 0.05), (-3.0, 3.0)]),
        ClosureOptions::new(),
    );
    let err = Estimator::ExpClosure(narrow).run(&p3).unwrap_err();
    assert!(
        matches!(err, Error::InvalidOption { .. })
            && err
                .to_string()
                .contains("the box [-3, 0.05] of state `u` does not cover the datum y = 0.1 at t = 0.5"),
        "{err}"
    );
    // The moment-path closures handle one-state models only.
    let err = closure_estimate(&p3, &ClosureKind::Ksp, &ClosureOptions::new()).unwrap_err();
    assert!(matches!(err, Error::InvalidOption { .. }), "{err}");
    // Degree too high in 2-D.
    let err =
        closure_estimate(&p3, &ClosureKind::Exponential { degree: 7 }, &ClosureOptions::new()).unwrap_err();
    assert!(err.to_string().contains("degree 2 to 6"), "{err}");
}

/// The problem of a model without parameters, `sde`, with measurements `obs` of `data` and
/// initial prior `x0`.
fn parameterless_problem<'a, S: Sde>(
    sde: &'a S,
    obs: &'a StateMeasurement,
    x0: &'a [Prior],
    data: &'a Dataset,
) -> EstimationProblem<'a, S, StateMeasurement> {
    EstimationProblem {
        sde,
        observation: obs,
        theta: &[],
        theta_prior: &[],
        estimate: &[],
        x0_prior: x0,
        z0_prior: &[],
        data,
        t0: 0.0,
        seed: 0,
        max_memory: Default::default(),
    }
}

#[test]
fn quadratic_exponential_closure_in_2d_is_the_gaussian_closure_on_a_linear_model() {
    // The degree-2 polynomial family in 2-D is the Gaussian family (restricted to a wide grid),
    // so on a linear model its estimate is the Gaussian closure's = the RTS smoother mean
    // (tested above in 1-D), up to the grid's quadrature and truncation error. The model:
    // dX = AX dt + G dW, A = [[−1, 0.5], [−0.5, −1]], G = 0.5 I (`test_models::DampedRotation`).
    let obs = gaussian_measurement(0, 0.2);
    let mut rng = StdRng::seed_from_u64(11);
    let path =
        simulate(&DampedRotation, &[], &[0.5, -0.3], &[], &SimulateOptions::new(0.0, 3.0, 0.01), &mut rng)
            .unwrap();
    let times = [0.5, 1.0, 1.5, 2.0, 2.5, 3.0];
    let data = sample_measurements_at(&obs, &[], &path, 1, &times, &mut rng).unwrap();
    let x0 = [Prior::gaussian(0.5, 0.3), Prior::gaussian(-0.3, 0.3)];
    let problem = parameterless_problem(&DampedRotation, &obs, &x0, &data);
    let options = ClosureOptions::new().with_tolerances(1e-9, 1e-11).with_dispersion(false);
    let g = closure_estimate(&problem, &ClosureKind::Gaussian, &options).unwrap();
    let on_box = ExponentialFamily::of_degree(2).with_domain(&[(-3.5, 3.5), (-3.5, 3.5)]);
    // The same family on nodes that follow the density (exact for a Gaussian up to the node
    // rule's tolerance).
    let following =
        ExponentialFamily::of_degree(2).with_nodes(NodeRule::Density).with_density_tolerance(1e-8);
    for family in [on_box, following] {
        let e = exp_closure(&problem, family, &options);
        assert_eq!(e.status, Status::Converged);
        assert_eq!(g.path.times, e.path.times);
        for (a, b) in g.path.values.iter().zip(&e.path.values) {
            for i in 0..2 {
                assert_relative_eq!(a[i], b[i], epsilon = 1e-5);
            }
        }
    }
}

/// In three states the quartic exponential closure (34 moments) on a linear model is exact: its
/// estimate is the RTS smoothed mean, on nodes that follow the density (the frame's tensor plan in
/// 3-D) and on a fixed box, up to the Runge–Kutta and node tolerances (the defaults). The
/// model: the damped rotation with a third state relaxing to x₁ (`test_models::RotationWithLag`),
/// x₁ and x₃ measured with sd 0.2 at t = 0.5, 1, …, 3. Measured: within 8·10⁻⁶ of the RTS mean
/// on the frame, 7·10⁻⁷ on the box (48³ nodes).
#[test]
fn quartic_exponential_closure_in_3d_is_the_rts_smoother_on_a_linear_model() {
    let record = LagRecord::new(6).unwrap();
    let problem = record.problem();
    let options = ClosureOptions::new().with_dispersion(false);
    let following = ExponentialFamily::of_degree(4).with_nodes(NodeRule::Density);
    let on_box = ExponentialFamily::of_degree(4);
    for (what, family) in [("frame", following), ("box", on_box)] {
        let e = exp_closure(&problem, family, &options);
        assert_eq!(e.status, Status::Converged, "{what}");
        let kf = record.rts(&e.path.times).unwrap();
        let mut worst: f64 = 0.0;
        for (t, values) in e.path.times.iter().zip(&e.path.values) {
            let j = kf.index_of(*t).unwrap();
            for (s, v) in values.iter().enumerate() {
                worst = worst.max((v - kf.smoothed_mean[j][s]).abs());
            }
        }
        assert!(worst < 2e-5, "{what}: max |closure − RTS| = {worst:e}");
    }
}

#[test]
fn the_dual_tolerance_on_nodes_that_follow_the_density_allows_for_their_moves() {
    // The quadratic family in 2-D on a damped rotation, y = x₀ + N(0, 0.2²) at t = 0.5, 1.0
    // (|y| ≤ 0.4): on the box the matched tolerance is 0.1·(rtol·0.4 + atol)/0.04; on nodes
    // that follow the density (q = 10⁻³) it is 0.1·(rtol·0.4 + atol + q·0.2)/0.04, and the
    // estimate converges to it.
    let obs = gaussian_measurement(0, 0.2);
    let data = Dataset::try_new(vec!["y".into()], vec![0.5, 1.0], vec![vec![0.4], vec![0.2]]).unwrap();
    let x0 = [Prior::gaussian(0.5, 0.3), Prior::gaussian(-0.3, 0.3)];
    let problem = parameterless_problem(&DampedRotation, &obs, &x0, &data);
    let options = ClosureOptions::new().with_dispersion(false);
    let (rtol, atol) = (options.rtol, options.atol);
    let tolerance =
        |e: &PathEstimate| e.details.json().get("dual_tolerance").and_then(|v| v.as_f64()).unwrap();
    let on_box = exp_closure(
        &problem,
        ExponentialFamily::of_degree(2).with_domain(&[(-3.5, 3.5), (-3.5, 3.5)]),
        &options,
    );
    assert_eq!(on_box.status, Status::Converged);
    assert_relative_eq!(tolerance(&on_box), 0.1 * (rtol * 0.4 + atol) / 0.04, max_relative = 1e-12);
    let following = exp_closure(
        &problem,
        ExponentialFamily::of_degree(2).with_nodes(NodeRule::Density).with_density_tolerance(1e-3),
        &options,
    );
    assert_eq!(following.status, Status::Converged);
    assert_relative_eq!(
        tolerance(&following),
        0.1 * (rtol * 0.4 + atol + 1e-3 * 0.2) / 0.04,
        max_relative = 1e-12
    );
    // Converged to it, and on the box's path within the node rule's tolerance q·sd ≈ 3·10⁻⁴
    // (4·10⁻⁷ seen: the frame's nodes are nearly exact for this Gaussian family).
    let residual = following.details.json().get("optimality_residual").and_then(|v| v.as_f64()).unwrap();
    assert!(residual <= tolerance(&following), "{residual}");
    assert_eq!(on_box.path.times, following.path.times);
    let gap = (on_box.path.values.iter().zip(&following.path.values))
        .flat_map(|(a, b)| a.iter().zip(b).map(|(x, y)| (x - y).abs()))
        .fold(0.0, f64::max);
    assert!(gap <= 1e-4, "{gap}");
}

#[test]
fn a_failed_sweep_is_reported_with_where_and_why() {
    // The quartic family on a box whose nodes are 7.5 apart cannot hold a density of sd 0.3:
    // the estimate is a numerical failure whose report says where the sweep failed and why.
    let obs = gaussian_measurement(0, 0.2);
    let data = Dataset::try_new(vec!["y".into()], vec![0.5, 1.0], vec![vec![0.4], vec![0.2]]).unwrap();
    let x0 = [Prior::gaussian(0.5, 0.3), Prior::gaussian(-0.3, 0.3)];
    let problem = parameterless_problem(&DampedRotation, &obs, &x0, &data);
    let coarse = ExponentialFamily::of_degree(4).with_domain(&[(-30.0, 30.0), (-30.0, 30.0)]).with_panels(2);
    let e =
        Estimator::ExpClosure(Closure::new(coarse, ClosureOptions::new())).run(&problem).unwrap().estimate;
    assert_eq!(e.status, Status::NumericalFailure);
    let why =
        e.details.json().get("sweep_failure").and_then(|v| v.as_str()).expect("a sweep failure").to_string();
    assert!(why.starts_with("at t = 0"), "{why}");
    assert!(why.contains("nodes") && why.contains("panels"), "{why}");
    // A converged estimate has none.
    let fine = ExponentialFamily::of_degree(4).with_domain(&[(-2.5, 3.5), (-3.0, 3.0)]);
    let e = Estimator::ExpClosure(Closure::new(fine, ClosureOptions::new())).run(&problem).unwrap().estimate;
    assert_eq!(e.status, Status::Converged);
    assert!(e.details.json().get("sweep_failure").is_none());
}

/// RMSE over the output grid.
fn rmse(a: &[Vec<f64>], b: &[Vec<f64>]) -> f64 {
    (a.iter().zip(b).map(|(x, y)| (x[0] - y[0]).powi(2)).sum::<f64>() / a.len() as f64).sqrt()
}

#[test]
fn quartic_closure_is_closer_to_the_exact_estimate_than_the_gaussian_closure() {
    // Double well, measurements every 1.0 on [1, 10] with R = 0.04, seed 3 of the example
    // `closure_double_well` (a path that changes wells; the example runs 10 seeds and prints the
    // table); reference: the exact grid mean-optimal estimate. Example output for this seed:
    // RMSE Gaussian 0.497, quartic 0.0044.
    let times: Vec<f64> = (1..=10).map(|k| k as f64).collect();
    let record = DoubleWellRecord::simulate(3, Start::Drawn, 10.0, &times).unwrap();
    let x = record.truth.column("x").unwrap();
    assert!(x.iter().any(|&v| v > 0.8) && x.iter().any(|&v| v < -0.8), "the path changes wells");
    let record = record.with_theta_prior(Prior::flat());
    let problem = record.problem();
    let exact = mean_optimal(
        &problem,
        ExactOptions::new(GridSpec::new_1d(-3.0, 3.0, 600)).with_dt(0.005).with_output_step(0.1),
    )
    .unwrap();
    let options = ClosureOptions::new().with_output_step(0.1).with_dispersion(false);
    let g = closure_estimate(&problem, &ClosureKind::Gaussian, &options).unwrap();
    let q = closure_estimate(&problem, &ClosureKind::Exponential { degree: 4 }, &options).unwrap();
    assert_eq!(q.status, Status::Converged);
    assert_eq!(g.path.times.len(), exact.history.times.len());
    let (eg, eq) = (rmse(&g.path.values, &exact.history.mean), rmse(&q.path.values, &exact.history.mean));
    assert!(eq < 0.02 && eq < 0.2 * eg, "RMSE quartic {eq} vs Gaussian {eg}");
}

/// The double well's drift 4x − 4x³ is declared cubic, so the Gaussian closures average it with
/// the exact 3-point Gauss–Hermite rule (`Sde::drift_polynomial_degree`); their estimates equal
/// those with the general 16-point rule (`gaussian_points = 16`) to round-off carried through
/// the Runge–Kutta sweeps and the dual Newton iteration: path and F to 1e-8, same status. The
/// moment-path (double-exponential) closure likewise.
#[test]
fn reduced_gauss_hermite_rule_gives_the_16_point_estimate_on_the_double_well() {
    let case = double_well_case(0, 12.0);
    let problem = case.problem();
    for kind in [ClosureKind::Gaussian, ClosureKind::DoubleExponential] {
        let reduced = closure_estimate(&problem, &kind, &ClosureOptions::new()).unwrap();
        let full = with_points(kind, 16).run(&problem).unwrap().estimate;
        assert_eq!(reduced.status, full.status, "{kind:?}");
        assert_eq!(reduced.status, Status::Converged, "{kind:?}");
        assert_eq!(reduced.path.times, full.path.times);
        let mut max_err: f64 = 0.0;
        for (a, b) in reduced.path.values.iter().zip(&full.path.values) {
            max_err = max_err.max((a[0] - b[0]).abs());
        }
        assert!(max_err <= 1e-8, "{kind:?}: max |path(3 points) − path(16 points)| = {max_err}");
        if kind == ClosureKind::Gaussian {
            let f = |e: &onsager::estimate::PathEstimate| e.details["f_value"].as_f64().unwrap();
            assert!((f(&reduced) - f(&full)).abs() <= 1e-8, "F: {} vs {}", f(&reduced), f(&full));
        }
    }
}

/// `gaussian_points`: 0, or more points than the Gauss–Hermite rules have, is an invalid option
/// (for the dual and for the moment-path closures), not a panic.
#[test]
fn gaussian_points_option_is_validated() {
    let case = double_well_case(1, 2.0);
    let problem = case.problem();
    for kind in [ClosureKind::Gaussian, ClosureKind::Ksp] {
        for bad in [0, 100_000] {
            let err = with_points(kind, bad).run(&problem).unwrap_err();
            let named = match &err {
                Error::InvalidOption { name, .. } => name == "gaussian_points",
                Error::EstimatorOption { option, .. } => option == "gaussian_points",
                _ => false,
            };
            assert!(named, "{kind:?}, {bad} points: {err}");
        }
    }
}

/// The Gaussian closure or a moment-path closure with `points` Gauss–Hermite points.
fn with_points(kind: ClosureKind, points: usize) -> Estimator {
    match kind.estimator(&ClosureOptions::new()) {
        Estimator::GaussianClosure(mut c) => {
            c.family = GaussianFamily::default().with_gaussian_points(points);
            Estimator::GaussianClosure(c)
        }
        Estimator::KspClosure(mut o) => {
            o.gaussian_points = Some(points);
            Estimator::KspClosure(o)
        }
        Estimator::DoubleExpClosure(mut o) => {
            o.gaussian_points = Some(points);
            Estimator::DoubleExpClosure(o)
        }
        other => other,
    }
}

/// The history just before a measurement at the default tolerance, against the same estimate
/// at rtol 10⁻¹⁰: the adjoint relaxes backward from each measurement's jump at the rate of
/// ∂W/∂λ, faster than λ does there, so the history's steps resolve it (`ClosureAction::integrate`).
/// Before they did, the differences on this record were: Gaussian path 1.1·10⁻², sd 1.3·10⁻³;
/// quartic path 5.1·10⁻⁴, sd 1.1·10⁻² (at the last output times before some measurements). Now
/// 5.8·10⁻⁶ / 1.6·10⁻⁵ and 1.6·10⁻⁶ / 9·10⁻⁷.
#[test]
fn the_history_just_before_a_measurement_is_resolved() {
    // x(0) = −1, y at t = 1, …, 12, x0 ~ N(−1, 0.2²), a flat prior on D.
    let record = DoubleWellRecord::new(0, 12.0).unwrap().with_theta_prior(Prior::flat());
    let problem = record.problem();
    for kind in [ClosureKind::Gaussian, ClosureKind::Exponential { degree: 4 }] {
        let options = ClosureOptions::new().with_output_step(0.1);
        let default = closure_estimate(&problem, &kind, &options).unwrap();
        let tight = closure_estimate(&problem, &kind, &options.with_tolerances(1e-10, 1e-13)).unwrap();
        assert_eq!(default.status, Status::Converged);
        assert_eq!(tight.status, Status::Converged);
        let dp = sup_diff(&default.path.values, &tight.path.values);
        let ds = sup_diff(default.path.sd.as_ref().unwrap(), tight.path.sd.as_ref().unwrap());
        assert!(dp < 1e-4 && ds < 1e-4, "{kind:?}: path {dp:e}, sd {ds:e}");
    }
}

#[test]
fn a_coarse_stage_cut_short_is_continued_at_the_requested_tolerance() {
    // With the iteration limit below what the coarse first stage needs, it stops at the limit;
    // the second stage goes on from where it got to (not from the filter start again, which at
    // the fine tolerance would need more than the limit) and reaches the same maximiser.
    let case = double_well_case(5, 20.0);
    let problem = case.problem();
    let options = ClosureOptions::new().with_dispersion(false);
    for (kind, limit) in [(ClosureKind::Gaussian, 2), (ClosureKind::Exponential { degree: 4 }, 4)] {
        let full = closure_estimate(&problem, &kind, &options).unwrap();
        let limited = options.clone().with_dual(DualOptions::default().with_max_iterations(limit));
        let cut = closure_estimate(&problem, &kind, &limited).unwrap();
        assert_eq!((full.status, cut.status), (Status::Converged, Status::Converged), "{kind:?}");
        let coarse = &cut.details["coarse_stage"];
        assert_eq!(coarse["status"], "max-iterations", "{kind:?}");
        assert_eq!(coarse["iterations"].as_u64().unwrap(), limit as u64, "{kind:?}");
        assert_eq!(cut.details["dual_start"], "filter", "{kind:?}");
        assert!(cut.iterations <= limit + 2, "{kind:?}: {} iterations", cut.iterations);
        let phi = |e: &onsager::estimate::PathEstimate| e.details["phi"].as_f64().unwrap();
        assert_relative_eq!(phi(&cut), phi(&full), max_relative = 1e-9);
        let diff = sup_diff(&cut.path.values, &full.path.values);
        assert!(diff < 1e-6, "{kind:?}: the estimates differ by {diff}");
    }
}

/// The largest |closure − RTS| over the output grid and all states of the Gaussian closure on a
/// three-state linear model with a clean state (`test_models::RotationWithPosition`: x2 and z
/// measured every 0.25 on [0, 4] with sd 0.2, one datum missing) at Runge–Kutta tolerances
/// (rtol, rtol/100).
fn three_state_closure_error(rtol: f64) -> f64 {
    let record = onsager::test_models::RotationRecord::new().unwrap();
    let problem = record.problem();
    let options = ClosureOptions::new().with_tolerances(rtol, rtol * 1e-2).with_output_step(0.125);
    let est = closure_estimate(&problem, &ClosureKind::Gaussian, &options).unwrap();
    assert_eq!(est.status, Status::Converged);
    let kf = record.rts(&est.path.times).unwrap();
    let sd = est.path.sd.as_ref().unwrap();
    let mut max_err: f64 = 0.0;
    for (i, &t) in est.path.times.iter().enumerate() {
        let j = kf.index_of(t).unwrap();
        for (s, (value, sd)) in est.path.values[i].iter().zip(&sd[i]).enumerate() {
            max_err = max_err.max((value - kf.smoothed_mean[j][s]).abs());
            max_err = max_err.max((sd - kf.smoothed_cov[j][(s, s)].sqrt()).abs());
        }
    }
    max_err
}

#[test]
fn gaussian_closure_of_a_three_state_model_with_a_clean_state_is_the_rts_smoother() {
    // The Gaussian closure is exact for linear dynamics, also with a clean state (a singular
    // diffusion on the full state): its estimate is the RTS smoothed mean and its dispersion the
    // smoothed sd, up to the Runge–Kutta error, which shrinks with the tolerance.
    let coarse = three_state_closure_error(1e-6);
    let fine = three_state_closure_error(1e-10);
    assert!(fine < 1e-6, "max |closure − RTS| at rtol 1e-10: {fine}");
    assert!(fine < 0.1 * coarse, "the error shrinks with the tolerance: {coarse} → {fine}");
}

/// The default rule for a non-concave dual (`branch = filter`, docs/closures.md "Which
/// stationary point") makes the Gaussian closure's estimate a function of the data on a
/// double-well record that changes wells: a second call gives the same path to the last bit,
/// and moving one measurement by ε = 10⁻⁴ and 2ε moves the path by O(ε), in ratio 2 to first
/// order (the estimate is differentiable in that datum there, not only continuous).
#[test]
fn gaussian_closure_estimate_is_repeatable_and_smooth_in_one_datum() {
    let record = double_well_case(4, 20.0);
    assert!(record.changes_wells());
    let options = ClosureOptions::new().with_tolerances(1e-10, 1e-12).with_output_step(0.1);
    let path = |record: &DoubleWellRecord| {
        let est = closure_estimate(&record.problem(), &ClosureKind::Gaussian, &options).unwrap();
        assert_eq!(est.status, Status::Converged);
        est.path.values
    };
    let base = path(&record);
    assert_eq!(path(&record), base, "a second call gives another path");
    let k = record.data.len() / 2;
    let moved = |eps: f64| {
        let mut r = record.clone();
        r.data.values[k][0] += eps;
        sup_diff(&path(&r), &base)
    };
    let (d1, d2) = (moved(1e-4), moved(2e-4));
    eprintln!("moving datum {k} by 1e-4, 2e-4 moved the path by {d1:.3e}, {d2:.3e}");
    assert!(d1 > 0.0 && d1 < 1e-2, "moving datum {k} by 1e-4 moved the path by {d1}");
    assert!((d2 / d1 - 2.0).abs() < 0.05, "not first order in the datum: {d1} then {d2}");
}

#[test]
fn a_box_that_cuts_the_density_off_is_widened_or_reported() {
    // The quartic closure on a double-well record, on a box just wider than the data's range:
    // the density has more than 10⁻³ of its mass within 2 % of the box's width from an end. The
    // box is widened (a quarter of its width at each end) and the estimate solved again, until
    // a wider box no longer moves the means; with `widen = 0` the estimate is `grid-edge`.
    let case = double_well_case(5, 20.0);
    let problem = case.problem();
    let options = ClosureOptions::new().with_dispersion(false);
    let run = |family: ExponentialFamily| exp_closure(&problem, family, &options);
    let (lo, hi) = problem
        .data
        .values
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), y| (a.min(y[0]), b.max(y[0])));
    let tight = || ExponentialFamily::of_degree(4).with_domain(&[(lo - 0.05, hi + 0.05)]);
    let default = run(ExponentialFamily::of_degree(4));
    let kept = run(tight().with_widen(0));
    let widened = run(tight());
    let detail = |e: &PathEstimate, key: &str| e.details[key].clone();
    eprintln!(
        "tight box: {}, {} from the default box; widened: {}, {}",
        detail(&kept, "edge"),
        sup_diff(&kept.path.values, &default.path.values),
        detail(&widened, "widenings"),
        sup_diff(&widened.path.values, &default.path.values)
    );
    assert_eq!(kept.status, Status::GridEdge);
    assert!(detail(&kept, "edge")["mass"].as_f64().unwrap() > 1e-3);
    // 3.6·10⁻³ from the default box's estimate; widened once, 4·10⁻⁶.
    assert!(sup_diff(&kept.path.values, &default.path.values) > 1e-3);
    assert!(widened.status.is_success(), "{}", widened.status);
    assert!(detail(&widened, "widenings").as_u64().unwrap() >= 1);
    assert!(sup_diff(&widened.path.values, &default.path.values) < 1e-4);
    // The default box is wide enough: no edge, or one that a wider box shows not to matter.
    assert_eq!(default.status, Status::Converged);
    assert!(!default.details.contains_key("widenings"));
}

#[test]
fn a_sweep_that_fails_against_the_box_edge_is_solved_on_a_wider_box() {
    // The quartic closure with the prior x0 ~ N(lo − 0.7, 0.1²) on a box that starts at lo − 0.1
    // (lo the lowest datum): the prior's density, truncated to the box, piles against its lower
    // end and the sweep fails there (the moment covariance is not positive definite). With
    // `widen` left the estimate is solved again on the box widened at that axis, a quarter of
    // its width at each end, and equals the estimate on that box; with `widen = 0` it ends
    // `grid-edge` with the edge and the sweep's failure in its details, not `numerical-failure`
    // (as before widening after a failure).
    let case = double_well_case(5, 20.0);
    let (lo, hi) = (case.data.values.iter())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), y| (a.min(y[0]), b.max(y[0])));
    let case = case.with_x0_prior(Prior::gaussian(lo - 0.7, 0.1));
    let problem = case.problem();
    let options = ClosureOptions::new().with_dispersion(false);
    let run = |family: ExponentialFamily| exp_closure(&problem, family, &options);
    let (a, b) = (lo - 0.1, hi + 0.1);
    let narrow = || ExponentialFamily::of_degree(4).with_domain(&[(a, b)]);
    let widened = run(narrow());
    let stopped = run(narrow().with_widen(0));
    let wide = run(ExponentialFamily::of_degree(4).with_domain(&[(a - 0.25 * (b - a), b + 0.25 * (b - a))]));
    assert_eq!(stopped.status, Status::GridEdge);
    let edge = &stopped.details["edge"];
    assert!(stopped.details["sweep_failure"].as_str().is_some_and(|w| w.starts_with("at t = 0:")));
    assert_eq!(edge["axis"], 0);
    assert!(edge["mass"].as_f64().unwrap() > 1e-3);
    assert!(widened.status.is_success(), "{}", widened.status);
    assert_eq!(wide.status, Status::Converged);
    // One widening more than the estimate on the wider box (which widens once more itself: the
    // prior sits 4 sd inside it), and the same path.
    let widenings = |e: &PathEstimate| e.details["widenings"].as_u64().unwrap_or(0);
    assert_eq!(widenings(&widened), widenings(&wide) + 1);
    assert!(sup_diff(&widened.path.values, &wide.path.values) < 1e-12);
}

#[test]
fn the_quadrature_check_refines_a_box_that_does_not_resolve_the_density() {
    // The quartic closure on a double-well record, on boxes of P panels, against 24 panels. After
    // the dual converges on P, the history at its multipliers is recomputed on ⌈1.5 P⌉ panels;
    // where a mean moves by more than 0.01 of the state's sd, or the sweeps failed on P, the
    // estimate is solved again on the finer box (at most `refine` = 2 times).
    let case = double_well_case(5, 20.0);
    let problem = case.problem();
    let options = ClosureOptions::new().with_dispersion(false);
    let run = |family: ExponentialFamily| exp_closure(&problem, family, &options);
    let quartic = || ExponentialFamily::of_degree(4);
    let reference = run(quartic().with_panels(24).with_refine(0));
    let off = |e: &PathEstimate| sup_diff(&e.path.values, &reference.path.values);
    let check = |e: &PathEstimate, key: &str| e.details["quadrature"][key].clone();
    // 5 panels (40 nodes): converged, 0.013 from the reference; checked: moved by more than the
    // tolerance on 8 panels, solved there from the 5-panel solution, 6·10⁻⁴ from it.
    let unchecked = run(quartic().with_panels(5).with_refine(0));
    let checked = run(quartic().with_panels(5));
    assert_eq!((unchecked.status, checked.status), (Status::Converged, Status::Converged));
    assert!(!unchecked.details.contains_key("quadrature"));
    assert_eq!(check(&checked, "nodes"), "8 panels");
    assert_eq!(check(&checked, "checked_on"), "12 panels");
    assert_eq!(check(&checked, "refinements"), 1);
    assert_eq!(check(&checked, "accepted"), true);
    assert!(check(&checked, "shift").as_f64().unwrap() <= 0.01);
    // The box (the default `domain`) is reported, one interval per state; it covers the data.
    let domain = &checked.details["domain"];
    let (a, b) = (domain[0][0].as_f64().unwrap(), domain[0][1].as_f64().unwrap());
    assert_eq!(domain.as_array().map(Vec::len), Some(1));
    assert!(problem.data.values.iter().all(|y| (a..=b).contains(&y[0])), "[{a}, {b}]");
    assert!(
        off(&unchecked) > 0.01 && off(&checked) < 0.1 * off(&unchecked),
        "{} {}",
        off(&unchecked),
        off(&checked)
    );
    // 3 panels: the sweeps fail; checked, the estimate is solved afresh once, on 5 panels,
    // which converge, move by more than the tolerance on 8 and are refined to 8. 4 panels fail,
    // and so do 6: a failure is retried once only.
    assert_eq!(run(quartic().with_panels(3).with_refine(0)).status, Status::NumericalFailure);
    let rescued = run(quartic().with_panels(3));
    assert_eq!(check(&rescued, "nodes"), "8 panels");
    assert_eq!(check(&rescued, "refinements"), 2);
    // The refinements ran out: the estimate on 8 panels is not checked, and the report and the
    // status say so; one more refinement checks it and lets it stand.
    assert_eq!(check(&rescued, "accepted"), false);
    assert_eq!(rescued.status, Status::Unresolved);
    let verified = run(quartic().with_panels(3).with_refine(3));
    assert_eq!((verified.status, check(&verified, "accepted")), (Status::Converged, true.into()));
    assert_eq!(verified.path.values, rescued.path.values);
    let failed = run(quartic().with_panels(4));
    assert_eq!(failed.status, Status::NumericalFailure);
    assert_eq!(check(&failed, "nodes"), "6 panels");
    assert_eq!(check(&failed, "refinements"), 1);
    assert_eq!(check(&failed, "accepted"), false);
    // The default 12 panels resolve this density: checked on 18, kept, the same path. (The
    // check's sweeps run at rtol 10⁻⁴: their error, not the nodes', is most of this shift.)
    let default = run(quartic());
    assert_eq!(check(&default, "refinements"), 0);
    assert_eq!(check(&default, "accepted"), true);
    assert!(check(&default, "shift").as_f64().unwrap() < 1e-3, "{}", check(&default, "shift"));
    assert_eq!(default.path.values, run(quartic().with_refine(0)).path.values);
    // The tolerance must be positive.
    let mut bad = quartic();
    bad.refine_tolerance = 0.0;
    let err = Estimator::ExpClosure(Closure::new(bad, options.clone())).run(&problem).unwrap_err();
    assert!(err.to_string().contains("refine_tolerance"), "{err}");
}
