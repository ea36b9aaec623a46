//! The exact effective-action and KSP estimators on a grid (issue 6).

use approx::assert_relative_eq;
use nalgebra::{DMatrix, DVector};
use rand::rngs::StdRng;
use rand::SeedableRng;

use onsager::action::dispersion::{dispersion_by_multipliers, dispersion_from_hessian, posterior_variance};
use onsager::action::exact::{gaussian_dual_data, ExactAction};
use onsager::action::{
    ksp_smoother, maximize_dual, mean_optimal, DualOptions, EffectiveAction, ExactOptions, GridSpec,
    KspSmoothing, TimeScheme,
};
use onsager::data::{Dataset, StatePath};
use onsager::estimate::{EstimationProblem, Status};
use onsager::kalman::linear::{kalman_rts, KalmanSmoothing, LinearGaussianModel};
use onsager::model::library::{DoubleWell, Lorenz96, VanDerPol};
use onsager::model::observation::{Noise, StateMeasurement};
use onsager::model::prior::Prior;
use onsager::model::{Param, Sde};
use onsager::simulate::{sample_measurements, simulate, SimulateOptions};
use onsager::test_models::{gaussian_measurement, DoubleWellRecord, LagRecord, OuRecord, Start};
use onsager::Error;

#[test]
fn ou_ksp_mean_optimal_and_kalman_agree_and_converge_under_refinement() {
    // Linear dynamics: the KSP mean, the mean-optimal z(t) and the RTS mean coincide
    // (003_d2fc48a470e528fc.txt Sec. I.3, (I.80)–(I.84) vs (I.61)–(I.62)); on the grid they differ
    // by the discretisation error, which falls as the square of the steps: each refinement (cells
    // doubled, dt halved) divides it by about 4 (observed order ≥ 1.8: ratio ≥ 2^1.8 ≈ 3.5).
    let ou = OuRecord::new().unwrap();
    let problem = ou.problem();
    let max_errors = |options: &ExactOptions| {
        let ksp = ksp_smoother(&problem, options).unwrap();
        let mo = mean_optimal(&problem, options).unwrap();
        assert_eq!(mo.dual.status, Status::Converged);
        assert!(mo.dual.residual <= 1e-9);
        let kf = ou.rts(&ksp.times).unwrap();
        let (mut e_ksp, mut e_mo, mut e_sd) = (0.0f64, 0.0f64, 0.0f64);
        for (i, &t) in ksp.times.iter().enumerate() {
            let j = kf.index_of(t).unwrap();
            let m = kf.smoothed_mean[j][0];
            e_ksp = e_ksp.max((ksp.smoothed_mean[i][0] - m).abs());
            e_mo = e_mo.max((mo.history.mean[i][0] - m).abs());
            e_sd = e_sd.max((mo.sd[i][0] - kf.smoothed_cov[j][(0, 0)].sqrt()).abs());
        }
        (ksp.times, (e_ksp, e_mo, e_sd, (ksp.log_likelihood - kf.log_likelihood).abs()))
    };
    let mut errors = Vec::new();
    for (cells, dt) in [(40, 0.05), (80, 0.025), (160, 0.0125)] {
        let options = ExactOptions::new(GridSpec::new_1d(-3.0, 3.0, cells))
            .with_dt(dt)
            .with_output_step(0.05)
            .with_extra_times(&[5.3]);
        let (times, e) = max_errors(&options);
        // The output grid runs to the extra time 5.3, past the last datum (prediction).
        assert_eq!(times.len(), 107);
        assert!((times[106] - 5.3).abs() < 1e-12);
        errors.push(e);
    }
    for w in errors.windows(2) {
        let (a, b) = (w[0], w[1]);
        assert!(a.0 > 3.5 * b.0, "KSP errors {errors:?}");
        assert!(a.1 > 3.5 * b.1, "mean-optimal errors {errors:?}");
        assert!(a.2 > 3.5 * b.2, "dispersion errors {errors:?}");
        assert!(a.3 > 3.5 * b.3, "log-likelihood errors {errors:?}");
    }
    let finest = errors[errors.len() - 1];
    assert!(finest.0 < 4e-4 && finest.1 < 4e-4 && finest.2 < 4e-4, "{errors:?}");
    // The default settings (grid, output step, dt) are within 1e-4 of the RTS mean.
    let (_, e) = max_errors(&ExactOptions::default());
    assert!(e.0 <= 1e-4 && e.1 <= 1e-4, "default settings: {e:?}");
}

#[test]
fn double_well_second_order_scheme_beats_implicit_euler_at_the_same_step() {
    // The record of the closure benchmarks: the mean-optimal estimate with TR-BDF2 at its
    // default step (output step / 2) is at least 10× closer to a fine TR-BDF2 reference than
    // implicit Euler at the same step, and implicit Euler's error falls to first order in dt.
    let record = DoubleWellRecord::new(0, 40.0).unwrap();
    let problem = record.problem();
    let options = |dt: Option<f64>, scheme| {
        let o =
            ExactOptions::new(GridSpec::new_1d(-2.5, 2.5, 1000)).with_output_step(0.1).with_scheme(scheme);
        match dt {
            Some(dt) => o.with_dt(dt),
            None => o,
        }
    };
    let run = |o: ExactOptions| {
        let mo = mean_optimal(&problem, o).unwrap();
        assert_eq!(mo.status, Status::Converged);
        (mo.history.mean.iter().map(|m| m[0]).collect::<Vec<f64>>(), mo.details.tridiagonal_solves.unwrap())
    };
    let (reference, _) = run(options(Some(0.0125), TimeScheme::TrBdf2));
    let distance = |o| {
        let (m, solves) = run(o);
        (m.iter().zip(&reference).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max), solves)
    };
    let (tr, tr_solves) = distance(options(None, TimeScheme::TrBdf2));
    let (ie, _) = distance(options(Some(0.05), TimeScheme::ImplicitEuler));
    let (ie_default, ie_solves) = distance(options(None, TimeScheme::ImplicitEuler));
    let (ie_half, _) = distance(options(Some(0.0125), TimeScheme::ImplicitEuler));
    assert!(ie >= 10.0 * tr, "TR-BDF2 {tr:.3e}, implicit Euler {ie:.3e} at dt = 0.05");
    // Implicit Euler's default step is output step / 4; halving it halves the error.
    assert!(ie_default > 3.0 * tr && ie_solves < tr_solves, "{ie_default:.3e} {ie_solves} {tr_solves}");
    let ratio = ie_default / ie_half;
    assert!((1.6..2.4).contains(&ratio), "implicit Euler order: ratio {ratio}");
}

#[test]
fn discrete_identities_hold() {
    // Double well, 150 cells, measurements every 1 with R = 0.04 (the data need not be real).
    let obs = gaussian_measurement(0, 0.2);
    let times: Vec<f64> = (0..6).map(|k| k as f64).collect();
    let values = vec![vec![-1.0], vec![-0.9], vec![-0.2], vec![0.8], vec![1.1], vec![0.9]];
    let data = Dataset::try_new(vec!["y".into()], times, values).unwrap();
    let priors = [Prior::flat().with_bounds(0.0, f64::INFINITY)];
    let x0 = [Prior::gaussian(-1.0, 0.2)];
    let problem = EstimationProblem {
        sde: &DoubleWell,
        observation: &obs,
        theta: &[0.5],
        theta_prior: &priors,
        estimate: &[],
        x0_prior: &x0,
        z0_prior: &[],
        data: &data,
        t0: 0.0,
        seed: 0,
        max_memory: Default::default(),
    };
    let options = ExactOptions::new(GridSpec::new_1d(-2.5, 2.5, 150)).with_dt(0.02).with_output_step(0.1);
    let mut action = ExactAction::try_new(&problem, &options).unwrap();
    let lambda = [1.5, -2.0, 0.7, 3.0, -0.4, 2.2];

    // Mass and ⟨A, P⟩ = 1 at every step, and on both sides of every jump.
    let diag = action.diagnostics(&lambda).unwrap();
    assert_eq!(diag.mass.len(), action.exact_grid().n_steps());
    assert!(diag.mass.iter().all(|m| (m - 1.0).abs() <= 1e-12), "mass");
    assert_eq!(diag.pairing.len(), action.exact_grid().n_steps());
    assert!(diag.pairing.iter().all(|m| (m - 1.0).abs() <= 1e-12), "pairing");
    for &(minus, plus) in &diag.pairing_at_jumps {
        assert!((minus - 1.0).abs() <= 1e-12 && (plus - 1.0).abs() <= 1e-12);
    }
    // z(t) continuous across the jumps while P and A jump (I.76, I.77).
    for (&(zm, zp), &(dp, da)) in diag.z_at_jumps.iter().zip(&diag.jumps) {
        assert_relative_eq!(zm, zp, epsilon = 1e-12);
        assert!(dp > 1e-3 && da > 1e-3, "P and A jump: {dp}, {da}");
    }

    // ∂F/∂λ_k from the adjoint sweep = central differences of F (step 1e-4: truncation
    // ~1e-8 · F''', rounding ~1e-12).
    let value = action.evaluate(&lambda).unwrap();
    for k in 0..lambda.len() {
        let h = 1e-4;
        let mut l = lambda;
        l[k] += h;
        let fp = action.evaluate(&l).unwrap().value;
        l[k] -= 2.0 * h;
        let fm = action.evaluate(&l).unwrap().value;
        assert_relative_eq!(value.z[k], (fp - fm) / (2.0 * h), max_relative = 1e-7);
    }
    // The exact Hessian by tangent sweeps = central differences of the adjoint gradient.
    let h_exact = action.hessian(&lambda).unwrap().unwrap();
    let mut fd = action.clone_hessian_fd(&lambda);
    fd = (&fd + fd.transpose()) * 0.5;
    for i in 0..lambda.len() {
        for j in 0..lambda.len() {
            assert_relative_eq!(h_exact[(i, j)], fd[(i, j)], epsilon = 1e-8, max_relative = 1e-6);
        }
    }

    // The dual optimum: residual ≤ 1e-9, and λ_k = R⁻¹(r_k − z_k) (I.60).
    let dd = gaussian_dual_data(&problem).unwrap();
    let sol = maximize_dual(&mut action, &dd, &DualOptions::default(), None).unwrap();
    assert_eq!(sol.status, Status::Converged);
    assert!(sol.residual <= 1e-9, "residual {}", sol.residual);
    for k in 0..6 {
        assert_relative_eq!(sol.lambda[k], (dd.r[k] - sol.z[k]) / 0.04, epsilon = 1e-9);
    }
}

/// Central differences of the adjoint gradient (the trait's default Hessian).
trait FdHessian {
    fn clone_hessian_fd(&mut self, lambda: &[f64]) -> DMatrix<f64>;
}

impl<S: Sde> FdHessian for ExactAction<'_, S> {
    fn clone_hessian_fd(&mut self, lambda: &[f64]) -> DMatrix<f64> {
        let m = lambda.len();
        let mut h = DMatrix::zeros(m, m);
        for j in 0..m {
            let step = 1e-5;
            let mut l = lambda.to_vec();
            l[j] += step;
            let plus = self.evaluate(&l).unwrap().z;
            l[j] -= 2.0 * step;
            let minus = self.evaluate(&l).unwrap().z;
            for i in 0..m {
                h[(i, j)] = (plus[i] - minus[i]) / (2.0 * step);
            }
        }
        h
    }
}

#[test]
fn dispersion_by_hessian_and_by_lagrange_multipliers_agree() {
    // Both routes compute the same C_*(t_k) (003 (I.90) vs (I.104)–(I.106)); on OU both also
    // approximate the RTS smoothed variance.
    let ou = OuRecord::new().unwrap();
    let (problem, data) = (ou.problem(), &ou.data);
    let options = ExactOptions::new(GridSpec::new_1d(-3.0, 3.0, 120)).with_dt(0.02).with_output_step(0.1);
    let mut action = ExactAction::try_new(&problem, &options).unwrap();
    let dd = gaussian_dual_data(&problem).unwrap();
    let opts = DualOptions::default().with_tolerance(1e-11);
    let sol = maximize_dual(&mut action, &dd, &opts, None).unwrap();
    assert!(sol.status.is_success());
    let hess = action.hessian(&sol.lambda).unwrap().unwrap();
    let by_h = dispersion_from_hessian(&hess, &dd).unwrap().unwrap();
    let by_l = dispersion_by_multipliers(&mut action, &dd, &sol, &opts, None).unwrap().unwrap();
    let hist = action.history(&sol.lambda, true).unwrap().unwrap();
    let post = posterior_variance(&hist, &hess, &dd).unwrap().unwrap();
    let kf = ou.rts(&hist.times).unwrap();
    for (k, &t) in data.times.iter().enumerate() {
        assert_relative_eq!(by_h[k][(0, 0)], by_l[k][(0, 0)], max_relative = 1e-5);
        let i = hist.times.iter().position(|&s| (s - t).abs() < 1e-9).unwrap();
        // The same formula evaluated through the cross-covariances (identity, rounding only).
        assert_relative_eq!(post[i][0], by_h[k][(0, 0)], max_relative = 1e-9);
        let j = kf.index_of(t).unwrap();
        assert_relative_eq!(by_h[k][(0, 0)], kf.smoothed_cov[j][(0, 0)], max_relative = 0.05);
    }
}

/// The double-well record (D = 0.5, x0 ~ N(−1, 0.2²), y ~ N(x(k), 0.2²) at k = 0, …, 40) of the
/// first seed whose path changes wells on [0, 40] and ends away from the barrier.
fn double_well_record() -> DoubleWellRecord {
    let times: Vec<f64> = (0..=40).map(|k| k as f64).collect();
    (0..100u64)
        .map(|seed| DoubleWellRecord::simulate(seed, Start::Drawn, 40.0, &times).unwrap())
        .find(|r| r.changes_wells() && r.truth.values.last().is_some_and(|x| x[0].abs() > 0.5))
        .expect("a well change within 100 seeds (Kramers rate ≈ 0.12 per unit time)")
}

#[test]
fn double_well_estimates_follow_the_true_well() {
    let record = double_well_record();
    let (problem, path) = (record.problem(), &record.truth);
    let options = ExactOptions::new(GridSpec::new_1d(-2.5, 2.5, 300)).with_dt(0.025);
    let ksp = ksp_smoother(&problem, &options).unwrap();
    let mo = mean_optimal(&problem, &options).unwrap();
    assert_eq!(mo.dual.status, Status::Converged);
    let truth = path.column("x").unwrap();
    let x_at = |t: f64| truth[(t / 0.005).round() as usize];
    let crossings: Vec<f64> = path
        .times
        .windows(2)
        .zip(truth.windows(2))
        .filter(|(_, x)| x[0] * x[1] <= 0.0)
        .map(|(t, _)| t[1])
        .collect();
    assert!(!crossings.is_empty());
    // Excluded: from each crossing of 0 by the true path to the first measurement after it.
    let excluded = |t: f64| crossings.iter().any(|&c| t >= c && t < c.floor() + 1.0);
    let (mut n, mut ok_ksp, mut ok_mo) = (0, 0, 0);
    for (i, &t) in ksp.times.iter().enumerate() {
        if excluded(t) {
            continue;
        }
        n += 1;
        let side = x_at(t).signum();
        ok_ksp += usize::from(ksp.smoothed_mean[i][0].signum() == side);
        ok_mo += usize::from(mo.history.mean[i][0].signum() == side);
    }
    let (f_ksp, f_mo) = (ok_ksp as f64 / n as f64, ok_mo as f64 / n as f64);
    assert!(f_ksp >= 0.9 && f_mo >= 0.9, "fractions on the true side: KSP {f_ksp}, mean-optimal {f_mo}");
}

#[test]
fn van_der_pol_runs_on_a_200_by_200_grid() {
    // Small noise (σ = 0.1, 001 Sec. 9), u measured with N(0, 0.2²) errors every 0.1 on [0, 0.4].
    let obs = gaussian_measurement(0, 0.2);
    let times: Vec<f64> = (0..5).map(|k| 0.1 * k as f64).collect();
    let values = vec![vec![0.05], vec![0.1], vec![0.12], vec![0.2], vec![0.3]];
    let data = Dataset::try_new(vec!["y".into()], times, values).unwrap();
    let priors = [Prior::flat(), Prior::flat()];
    let x0 = [Prior::gaussian(0.0, 0.1), Prior::gaussian(0.0, 0.1)];
    let theta = VanDerPol::NOMINAL;
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
    let options = ExactOptions::new(GridSpec::new_2d([-1.0, -1.0], [1.0, 1.0], [200, 200]))
        .with_dt(0.025)
        .with_output_step(0.05);
    let ksp = ksp_smoother(&problem, &options).unwrap();
    let mo = mean_optimal(&problem, &options).unwrap();
    assert_eq!(mo.dual.status, Status::Converged);
    for (i, _) in ksp.times.iter().enumerate() {
        assert_relative_eq!(ksp.smoothed[i].iter().sum::<f64>(), 1.0, epsilon = 1e-12);
        // Nearly linear regime near the origin: KSP and mean-optimal agree to a fraction of the sd.
        for a in 0..2 {
            assert!((ksp.smoothed_mean[i][a] - mo.history.mean[i][a]).abs() < 0.25 * ksp.smoothed_sd[i][a]);
        }
    }
}

#[test]
fn bad_inputs_are_clear_errors() {
    // The OU problem of the record (flat θ priors) on data of its own.
    let ou = OuRecord::new().unwrap().with_theta_prior([Prior::flat(); 2]);
    let data = Dataset::try_new(vec!["y".into()], vec![0.0, 1.0], vec![vec![0.1], vec![3.5]]).unwrap();
    let options = ExactOptions::new(GridSpec::new_1d(-3.0, 3.0, 50));
    // A grid that does not cover the datum 3.5.
    let err = mean_optimal(&EstimationProblem { data: &data, ..ou.problem() }, &options).unwrap_err();
    assert!(
        matches!(err, Error::InvalidOption { .. }) && err.to_string().contains("does not cover"),
        "{err}"
    );
    // A non-Gaussian likelihood for the mean-optimal estimator.
    let laplace =
        StateMeasurement::new(vec![0], vec!["y".into()], Noise::Laplace { scale: Param::Fixed(0.2) });
    let data2 = Dataset::try_new(vec!["y".into()], vec![0.0, 1.0], vec![vec![0.1], vec![0.5]]).unwrap();
    let on_laplace = EstimationProblem { observation: &laplace, data: &data2, ..ou.problem() };
    let err = mean_optimal(&on_laplace, &options).unwrap_err();
    assert!(err.to_string().contains("Gaussian measurement errors"), "{err}");
    // …which the KSP smoother accepts.
    assert!(ksp_smoother(&on_laplace, &options).is_ok());
    // More than three noisy states.
    let lorenz_obs = gaussian_measurement(0, 1.0);
    let lp = [Prior::flat(); 2];
    let lx = [Prior::gaussian(1.0, 1.0); 4];
    let lorenz96 = Lorenz96::new(4).unwrap();
    let problem = EstimationProblem {
        sde: &lorenz96,
        observation: &lorenz_obs,
        theta: &Lorenz96::NOMINAL,
        theta_prior: &lp,
        estimate: &[],
        x0_prior: &lx,
        z0_prior: &[],
        data: &data2,
        t0: 0.0,
        seed: 0,
        max_memory: Default::default(),
    };
    let err = ksp_smoother(&problem, &ExactOptions::new(GridSpec::new_1d(-3.0, 3.0, 50))).unwrap_err();
    assert!(err.to_string().contains("1 to 3 noisy states"), "{err}");
    // A grid with the wrong number of axes.
    let err = ksp_smoother(
        &EstimationProblem { data: &data2, ..ou.problem() },
        &ExactOptions::new(GridSpec::new_2d([-1.0, -1.0], [1.0, 1.0], [5, 5])),
    )
    .unwrap_err();
    assert!(err.to_string().contains("axes"), "{err}");
}

#[test]
fn cli_writes_the_path_and_the_report_and_rejects_bad_input() {
    use std::process::Command;
    let dir = std::env::temp_dir().join(format!("onsager-action-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let data = OuRecord::new().unwrap().data;
    let data_path = dir.join("ou.csv");
    data.write_csv(&data_path).unwrap();
    let run = |method: &str, extra: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_onsager"))
            .args(["estimate", "--model", "ou", "--method", method])
            .args(["--x0-prior", "x=normal:0,0.5", "--data"])
            .arg(&data_path)
            .args(extra)
            .arg("--out")
            .arg(dir.join(format!("{method}.csv")))
            .arg("--report")
            .arg(dir.join(format!("{method}.json")))
            .output()
            .unwrap()
    };
    for method in ["ksp", "mean-optimal"] {
        let out = run(
            method,
            &["--grid", "lo=-3,hi=3,cells=120", "--dt", "0.0125", "--likelihood", "gaussian:sigma=0.2"],
        );
        assert!(out.status.success(), "{method}: {}", String::from_utf8_lossy(&out.stderr));
        let path = StatePath::read_csv(dir.join(format!("{method}.csv"))).unwrap();
        assert_eq!(path.names, vec!["x"]);
        assert!(path.sd.is_some());
        // Output step = spacing / 10 = 0.05 on [0, 5].
        assert_eq!(path.len(), 101);
        let report: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join(format!("{method}.json"))).unwrap())
                .unwrap();
        assert_eq!(report["method"], method);
        assert!(report["solve_seconds"].as_f64().unwrap() >= 0.0);
        if method == "mean-optimal" {
            assert_eq!(report["details"]["lambda"].as_array().unwrap().len(), data.len());
            assert!(report["details"]["optimality_residual"].as_f64().unwrap() <= 1e-9);
            assert!(report["iterations"].as_u64().unwrap() >= 1);
        } else {
            assert!(report["details"]["log_likelihood"].as_f64().unwrap().is_finite());
        }
    }
    let fails = |method: &str, extra: &[&str], needle: &str| {
        let out = run(method, extra);
        let err = String::from_utf8_lossy(&out.stderr).to_string();
        assert!(!out.status.success() && err.contains(needle), "{method} {extra:?}: {err}");
    };
    fails("ksp", &["--grid", "lo=-0.5,hi=0.5,cells=50"], "does not cover");
    // Without --grid the default grid (data range with margins) is used and reported.
    let out = run("ksp", &[]);
    assert!(out.status.success());
    assert!(String::from_utf8_lossy(&out.stdout)
        .contains("(the default: data range with margins and the initial prior)"));
    fails("ksp", &["--step", "0.1"], "`--step`");
    fails(
        "mean-optimal",
        &["--grid", "lo=-3,hi=3,cells=50", "--likelihood", "laplace:scale=0.2"],
        "Gaussian",
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn linear_two_state_model_matches_kalman_on_a_2d_grid() {
    // Duffing with a = γ = 0 is linear: dX = (−bZ − dX) dt + σ_D dW, dZ = X dt (one noisy, one clean
    // state: upwind flux along z). b = 1, d = 0.5, σ_D = 0.5; z measured with sd 0.2 every 0.5.
    // KSP mean, mean-optimal z(t) and the RTS mean coincide in the limit (003 Sec. I.3); here
    // within the grid's error, which halves under refinement and is below a quarter of the
    // smallest smoothed sd on 120 × 120 cells.
    use onsager::model::library::Duffing;
    let theta = [0.0, 1.0, 0.5, 0.0, 0.5, 0.2];
    let obs = StateMeasurement::new(vec![1], vec!["y".into()], Noise::Gaussian { sigma: Param::Theta(5) });
    let mut rng = StdRng::seed_from_u64(3);
    let path =
        simulate(&Duffing, &theta, &[0.2], &[-0.3], &SimulateOptions::new(0.0, 4.0, 0.01), &mut rng).unwrap();
    let data = sample_measurements(&obs, &theta, &path, 1, 0.5, &mut rng).unwrap();
    let priors = [Prior::flat(); 6];
    let x0 = [Prior::gaussian(0.0, 0.4)];
    let z0 = [Prior::gaussian(0.0, 0.4)];
    let problem = EstimationProblem {
        sde: &Duffing,
        observation: &obs,
        theta: &theta,
        theta_prior: &priors,
        estimate: &[],
        x0_prior: &x0,
        z0_prior: &z0,
        data: &data,
        t0: 0.0,
        seed: 0,
        max_memory: Default::default(),
    };
    let model = LinearGaussianModel::from_sde(
        &Duffing,
        &theta,
        &obs,
        0.0,
        DVector::zeros(2),
        DMatrix::from_diagonal_element(2, 2, 0.16),
    )
    .unwrap();
    let mut errors = Vec::new();
    for (cells, dt) in [(60, 0.02), (120, 0.01)] {
        let options = ExactOptions::new(GridSpec::new_2d([-2.0, -2.0], [2.0, 2.0], [cells, cells]))
            .with_dt(dt)
            .with_output_step(0.1);
        let ksp = ksp_smoother(&problem, &options).unwrap();
        let mo = mean_optimal(&problem, &options).unwrap();
        assert_eq!(mo.dual.status, Status::Converged);
        let kf = kalman_rts(&model, &data, &ksp.times).unwrap();
        errors.push(largest_distances_to_rts(&ksp, &mo.history.mean, &kf));
    }
    eprintln!("2-D linear (max |KSP − RTS|, max |mean-optimal − RTS|, min RTS sd): {errors:?}");
    let (coarse, fine) = (errors[0], errors[1]);
    // First order (upwind along the clean state, implicit Euler): the error about halves.
    assert!(fine.0 < 0.7 * coarse.0 && fine.1 < 0.7 * coarse.1, "{errors:?}");
    let (e_ksp, e_mo, min_sd) = fine;
    assert!(e_ksp < 0.25 * min_sd && e_mo < 0.25 * min_sd, "{e_ksp} {e_mo} {min_sd}");
}

/// The largest distances of the KSP mean and of the mean-optimal history `mo_mean` (at the KSP's
/// output times) from the RTS mean over the times and states, with the smallest RTS sd.
fn largest_distances_to_rts(
    ksp: &KspSmoothing,
    mo_mean: &[Vec<f64>],
    kf: &KalmanSmoothing,
) -> (f64, f64, f64) {
    let (mut e_ksp, mut e_mo, mut min_sd) = (0.0f64, 0.0f64, f64::INFINITY);
    for (i, &t) in ksp.times.iter().enumerate() {
        let j = kf.index_of(t).unwrap();
        for (a, &m) in kf.smoothed_mean[j].iter().enumerate() {
            e_ksp = e_ksp.max((ksp.smoothed_mean[i][a] - m).abs());
            e_mo = e_mo.max((mo_mean[i][a] - m).abs());
            min_sd = min_sd.min(kf.smoothed_cov[j][(a, a)].sqrt());
        }
    }
    (e_ksp, e_mo, min_sd)
}

#[test]
fn linear_three_state_model_matches_kalman_on_a_3d_grid() {
    // The damped rotation with a lagging third state (three noisy states, G = 0.5 I), x₁ and x₃
    // measured with sd 0.2 every 0.5 on [0, 2] (`LagRecord`): the KSP mean, the mean-optimal history and the
    // RTS mean coincide (003 Sec. I.3); on the grid within its error, which falls under
    // refinement (second order: Chang–Cooper fluxes, TR-BDF2 steps, Strang splitting of the three
    // axes) and is far below the smallest smoothed sd on 36³ cells. Measured: 0.040 on 18³ cells,
    // 0.013 on 36³ (a ratio of 0.31), against a smallest sd of 0.158.
    let record = LagRecord::new(4).unwrap();
    let problem = record.problem();
    let mut errors = Vec::new();
    for (cells, dt) in [(18, 0.02), (36, 0.01)] {
        let spec = GridSpec { lo: vec![-1.6; 3], hi: vec![1.6; 3], cells: vec![cells; 3] };
        let options = ExactOptions::new(spec).with_dt(dt).with_output_step(0.25);
        let ksp = ksp_smoother(&problem, &options).unwrap();
        let mo = mean_optimal(&problem, &options).unwrap();
        assert_eq!(mo.dual.status, Status::Converged);
        let kf = record.rts(&ksp.times).unwrap();
        errors.push(largest_distances_to_rts(&ksp, &mo.history.mean, &kf));
    }
    eprintln!("3-D linear (max |KSP − RTS|, max |mean-optimal − RTS|, min RTS sd): {errors:?}");
    let (coarse, fine) = (errors[0], errors[1]);
    assert!(fine.0 < 0.5 * coarse.0 && fine.1 < 0.5 * coarse.1, "{errors:?}");
    let (e_ksp, e_mo, min_sd) = fine;
    assert!(e_ksp < 0.15 * min_sd && e_mo < 0.15 * min_sd, "{e_ksp} {e_mo} {min_sd}");
}

#[test]
fn ksp_takes_any_likelihood() {
    // One Laplace measurement at t = 0 (no dynamics before it): the KSP jump is Bayes' rule
    // (003 (A.2)), so the smoothed mean at 0 and log p(y) are ∫x ψ(y|x) π(x) dx / p(y) and
    // ln ∫ψ(y|x) π(x) dx with π = N(0, 0.5²), here by a fine midpoint rule (independent of the grid;
    // the grid's midpoint error at h = 0.02 is ~1e-4 relative, the asserted tolerance 1e-3).
    let laplace =
        StateMeasurement::new(vec![0], vec!["y".into()], Noise::Laplace { scale: Param::Fixed(0.3) });
    let data = Dataset::try_new(vec!["y".into()], vec![0.0, 1.0], vec![vec![0.8], vec![f64::NAN]]).unwrap();
    // The OU problem of the record (flat θ priors) with this likelihood and data.
    let ou = OuRecord::new().unwrap().with_theta_prior([Prior::flat(); 2]);
    let problem = EstimationProblem { observation: &laplace, data: &data, ..ou.problem() };
    let options = ExactOptions::new(GridSpec::new_1d(-3.0, 3.0, 300)).with_dt(0.01);
    let ksp = ksp_smoother(&problem, &options).unwrap();
    let (mut z, mut zx) = (0.0, 0.0);
    let n = 200_000;
    for i in 0..n {
        let x = -4.0 + (i as f64 + 0.5) * 8.0 / n as f64;
        let w = (-(x * x) / (2.0 * 0.25)).exp() / (0.5 * (2.0 * std::f64::consts::PI).sqrt())
            * (-(0.8f64 - x).abs() / 0.3).exp()
            / 0.6
            * 8.0
            / n as f64;
        z += w;
        zx += w * x;
    }
    assert_relative_eq!(ksp.log_likelihood, z.ln(), max_relative = 1e-3);
    assert_relative_eq!(ksp.smoothed_mean[0][0], zx / z, max_relative = 1e-3);
    // The missing datum at t = 1 does not jump: the filter there is the prediction.
    assert!(ksp.filtered_mean.last().unwrap()[0].is_finite());
}
