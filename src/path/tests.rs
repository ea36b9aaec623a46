use approx::assert_relative_eq;

use super::*;
use crate::model::library::{preset, Preset};
use crate::model::observation::StateMeasurement;
use crate::nlp::{NlpOptions, NlpProblem};

/// A few deterministic measurements 0.8 cos(1.3 t) of the preset's one output (no randomness
/// needed: the derivative and quadrature identities hold for any data).
fn data_for(p: &Preset, times: &[f64]) -> Dataset {
    crate::test_models::cosine_data(&p.observation.names[0], times, 0.8, 0.0).unwrap()
}

/// Dense central finite differences of the NLP's gradient, constraint Jacobian and Hessian of
/// the Lagrangian, compared with the assembled exact values at a non-trivial point.
fn check_derivatives<P: NlpProblem>(nlp: &mut P) {
    let (n, m) = (nlp.num_variables(), nlp.num_constraints());
    let mut w = vec![0.0; n];
    nlp.initial_point(&mut w);
    // Perturb deterministically away from the guess so that no term is at a special point.
    for (i, wi) in w.iter_mut().enumerate() {
        *wi += 0.1 * ((i as f64) * 0.7).sin();
    }
    let lambda: Vec<f64> = (0..m).map(|r| ((r as f64) * 1.3).cos()).collect();
    let sigma = 0.7;
    let eps = 1e-5;
    // gradient
    let mut grad = vec![0.0; n];
    nlp.gradient(&w, &mut grad);
    // Jacobian (dense)
    let js = nlp.jacobian_structure();
    let mut jv = vec![0.0; js.len()];
    nlp.jacobian_values(&w, &mut jv);
    let mut jac = nalgebra::DMatrix::<f64>::zeros(m, n);
    for (&(r, c), v) in js.iter().zip(&jv) {
        jac[(r as usize, c as usize)] += v;
    }
    // Hessian (dense, symmetric)
    let hs = nlp.hessian_structure();
    let mut hv = vec![0.0; hs.len()];
    nlp.hessian_values(&w, sigma, &lambda, &mut hv);
    let mut hess = nalgebra::DMatrix::<f64>::zeros(n, n);
    for (&(r, c), v) in hs.iter().zip(&hv) {
        let (r, c) = (r as usize, c as usize);
        hess[(r, c)] += v;
        if r != c {
            hess[(c, r)] += v;
        }
    }
    let lag_grad = |nlp: &mut P, w: &[f64]| {
        let mut g = vec![0.0; n];
        nlp.gradient(w, &mut g);
        let mut jv = vec![0.0; js.len()];
        nlp.jacobian_values(w, &mut jv);
        let mut out: Vec<f64> = g.iter().map(|v| v * sigma).collect();
        for (&(r, c), v) in js.iter().zip(&jv) {
            out[c as usize] += lambda[r as usize] * v;
        }
        out
    };
    for i in 0..n {
        let (mut wp, mut wm) = (w.clone(), w.clone());
        wp[i] += eps;
        wm[i] -= eps;
        let fd = (nlp.objective(&wp) - nlp.objective(&wm)) / (2.0 * eps);
        assert_relative_eq!(grad[i], fd, epsilon = 1e-5, max_relative = 1e-6);
        let (mut cp, mut cm) = (vec![0.0; m], vec![0.0; m]);
        nlp.constraints(&wp, &mut cp);
        nlp.constraints(&wm, &mut cm);
        for r in 0..m {
            assert_relative_eq!(
                jac[(r, i)],
                (cp[r] - cm[r]) / (2.0 * eps),
                epsilon = 1e-6,
                max_relative = 1e-6
            );
        }
        let (gp, gm) = (lag_grad(nlp, &wp), lag_grad(nlp, &wm));
        for j in 0..n {
            assert_relative_eq!(
                hess[(j, i)],
                (gp[j] - gm[j]) / (2.0 * eps),
                epsilon = 1e-5,
                max_relative = 1e-5
            );
        }
    }
}

/// Every sign and index of the objective, constraints and their derivatives, on Duffing (a
/// noisy and a clean state, a time-dependent forcing) with four estimated parameters.
#[test]
fn derivatives_match_finite_differences() {
    let p = preset("duffing").unwrap();
    let data = data_for(&p, &[0.0, 0.3, 0.6]);
    for (transcription, estimate) in [
        (Transcription::HermiteSimpson, vec![0, 1, 2, 5]),
        (Transcription::Trapezoidal, vec![0, 2, 4, 5]),
        (Transcription::Euler, vec![1, 2, 4, 5]),
    ] {
        for merit in [Merit::OnsagerMachlup, Merit::Energy] {
            let prob = p.problem(&data, &estimate);
            let options = PathOptions::new(merit, transcription).with_step(0.15);
            let mut nlp = build_nlp(&prob, &options).unwrap();
            assert_eq!(nlp.grid().intervals, 4);
            check_derivatives(&mut nlp);
        }
    }
}

/// The Hermite–Simpson Jacobian and Hessian evaluated on their own (each Lobatto point
/// differentiated again) equal those that reuse the per-point derivatives stored by `gradient`
/// at the same point (the path of `derivatives_match_finite_differences`), for both merits; a
/// gradient at another point is not reused.
#[test]
fn jacobian_and_hessian_without_and_with_the_gradients_cache_agree() {
    let p = preset("duffing").unwrap();
    let data = data_for(&p, &[0.0, 0.3, 0.6]);
    for merit in [Merit::OnsagerMachlup, Merit::Energy] {
        let prob = p.problem(&data, &[0, 1, 2, 5]);
        let options = PathOptions::new(merit, Transcription::HermiteSimpson).with_step(0.15);
        let mut nlp = build_nlp(&prob, &options).unwrap();
        let (n, m) = (nlp.num_variables(), nlp.num_constraints());
        let mut w = vec![0.0; n];
        nlp.initial_point(&mut w);
        for (i, wi) in w.iter_mut().enumerate() {
            *wi += 0.1 * ((i as f64) * 0.7).sin();
        }
        let lambda: Vec<f64> = (0..m).map(|r| ((r as f64) * 1.3).cos()).collect();
        let (nj, nh) = (nlp.jacobian_structure().len(), nlp.hessian_structure().len());
        let eval = |nlp: &mut PathNlp<_, _>| {
            let (mut jv, mut hv) = (vec![0.0; nj], vec![0.0; nh]);
            nlp.jacobian_values(&w, &mut jv);
            nlp.hessian_values(&w, 0.7, &lambda, &mut hv);
            (jv, hv)
        };
        let fresh = eval(&mut nlp);
        let mut g = vec![0.0; n];
        nlp.gradient(&w, &mut g);
        let cached = eval(&mut nlp);
        let mut w2 = w.clone();
        w2[n / 2] += 0.01;
        nlp.gradient(&w2, &mut g);
        let after_other = eval(&mut nlp);
        for (a, b, c) in [(&fresh.0, &cached.0, &after_other.0), (&fresh.1, &cached.1, &after_other.1)] {
            for ((x, y), z) in a.iter().zip(b).zip(c) {
                assert_relative_eq!(x, y, epsilon = 1e-13, max_relative = 1e-12);
                assert_eq!(x, z);
            }
        }
    }
}

/// The Hermite–Simpson Hessian holds each (θ_i, θ_j) pair of the estimated θ that enter the
/// dynamics once for all pieces (their summed block), not once per Lobatto point: on Duffing
/// with θ = (a, b, d, σ_y) estimated and 4 pieces, the pairs of (a, b, d) appear in that block,
/// the prior block and one block per measurement, whatever the number of pieces.
/// (`derivatives_match_finite_differences` checks the summed values.)
#[test]
fn hermite_simpson_theta_pairs_are_one_block_for_all_pieces() {
    let p = preset("duffing").unwrap();
    let data = data_for(&p, &[0.0, 0.3, 0.6]);
    let prob = p.problem(&data, &[0, 1, 2, 5]);
    for step in [0.15, 0.075] {
        let nlp = build_nlp(&prob, &PathOptions::default().with_step(step)).unwrap();
        let theta0 = nlp.num_variables() - 4;
        let pattern = nlp.hessian_structure();
        let at = |i: usize| (theta0 + i) as u32;
        let count = |i: usize, j: usize| pattern.iter().filter(|&&e| e == (at(i), at(j))).count();
        // a, b, d enter the drift; the prior block and the 3 measurement blocks are dense in θ
        assert_eq!(count(0, 0), 1 + 1 + 3);
        assert_eq!(count(2, 1), 1 + 1 + 3);
        // σ_y enters only the likelihood and the prior
        assert_eq!(count(3, 3), 1 + 3);
    }
}

/// With noise w(t) = sin 2t + ½ on [0, 2] (piece coefficients a_k = w at the midpoint,
/// b_k = the change of w across the piece), the Hermite–Simpson energy part converges to
/// −∫½w² dt = −½[1 − sin(8)/8 + (1 − cos 4)/2 + ½] (closed form), at second order in h.
#[test]
fn hermite_simpson_energy_converges_to_the_continuous_energy() {
    let p = preset("ou").unwrap();
    let data = data_for(&p, &[0.0, 2.0]);
    let exact = -0.5 * (1.0 - (8.0f64).sin() / 8.0 + (1.0 - (4.0f64).cos()) / 2.0 + 0.5);
    let noise = |t: f64| (2.0 * t).sin() + 0.5;
    let mut errors = Vec::new();
    for pieces in [10usize, 20, 40] {
        let h = 2.0 / pieces as f64;
        let prob = p.problem(&data, &[]);
        let nlp = build_nlp(&prob, &PathOptions::default().with_step(h)).unwrap();
        let mut w = vec![0.0; nlp.num_variables()];
        for k in 0..pieces {
            let t = k as f64 * h;
            nlp.set_piece_noise(&mut w, k, &[noise(t + 0.5 * h)], &[noise(t + h) - noise(t)]);
        }
        errors.push((nlp.merit_parts(&w).energy - exact).abs());
    }
    // Second order: the error falls by ~4 per halving (midpoint-rule error h²/24 ∫(w²)''/2).
    for pair in errors.windows(2) {
        assert!(pair[1] < pair[0] / 3.5, "errors {errors:?}");
    }
    assert!(errors[2] < 1e-3, "errors {errors:?}");
}

#[test]
fn measurement_off_the_grid_is_an_error() {
    let p = preset("ou").unwrap();
    let data = data_for(&p, &[0.0, 0.5, 1.0]);
    let prob = p.problem(&data, &[]);
    let err = build_nlp(&prob, &PathOptions::default().with_step(0.3)).err().unwrap();
    assert!(err.to_string().contains("not on the grid"), "{err}");
}

/// A grid with more unknowns than the NLP's `u32` pattern indices can number is an error before
/// anything is allocated per node.
#[test]
fn a_grid_too_fine_for_u32_indices_is_an_error() {
    let p = preset("ou").unwrap();
    let data = data_for(&p, &[0.0, 1.0]);
    // The memory guard refuses it first at any realistic limit.
    let prob = p.problem(&data, &[]);
    let err = build_nlp(&prob, &PathOptions::default().with_step(1e-10)).err().unwrap();
    assert!(err.to_string().contains("--max-memory"), "{err}");
    let prob =
        EstimationProblem { max_memory: crate::estimate::MemoryLimit::UNLIMITED, ..p.problem(&data, &[]) };
    let err = build_nlp(&prob, &PathOptions::default().with_step(1e-10)).err().unwrap();
    assert!(err.to_string().contains("2^32 - 1 unknowns"), "{err}");
}

#[test]
fn initial_theta_outside_its_bounds_is_an_error() {
    let mut p = preset("ou").unwrap();
    p.theta_prior[0] = p.theta_prior[0].with_bounds(2.0, 3.0);
    let data = data_for(&p, &[0.0, 0.5]);
    let prob = p.problem(&data, &[0]);
    let err = build_nlp(&prob, &PathOptions::default()).err().unwrap();
    assert!(err.to_string().contains("violates its bounds"), "{err}");
}

#[test]
fn estimating_a_noise_parameter_with_hermite_simpson_is_an_error() {
    let p = preset("ou").unwrap();
    let data = data_for(&p, &[0.0, 0.5]);
    let prob = p.problem(&data, &[1]);
    assert!(build_nlp(&prob, &PathOptions::default()).is_err());
    assert!(build_nlp(&prob, &PathOptions::new(Merit::Energy, Transcription::Euler)).is_ok());
}

/// The multipliers returned with the solution follow the convention the Laplace step relies
/// on, ∇f + Jᵀλ = 0 at the optimum, on a problem with nonlinear constraints (Duffing, cubic
/// stiffness, estimated a, b, d).
#[test]
fn multipliers_satisfy_stationarity_at_the_optimum() {
    let p = preset("duffing").unwrap();
    let data = data_for(&p, &[0.0, 0.3, 0.6, 0.9]);
    let estimate = [0, 1, 2];
    let prob = p.problem(&data, &estimate);
    let options = PathOptions::new(Merit::OnsagerMachlup, Transcription::HermiteSimpson).with_step(0.1);
    let mut nlp = build_nlp(&prob, &options).unwrap();
    let sol = crate::nlp::solve(&mut nlp, NlpOptions::default()).unwrap();
    assert_eq!(sol.report.status, crate::Status::Converged);
    let n = nlp.num_variables();
    let mut g = vec![0.0; n];
    nlp.gradient(&sol.w, &mut g);
    let js = nlp.jacobian_structure();
    let mut jv = vec![0.0; js.len()];
    nlp.jacobian_values(&sol.w, &mut jv);
    for (&(r, c), v) in js.iter().zip(&jv) {
        g[c as usize] += sol.lambda[r as usize] * v;
    }
    let norm = g.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    assert!(norm < 1e-6, "‖∇f + Jᵀλ‖∞ = {norm}");
}

/// `Laplace::Parameters` gives the same θ sds as `Laplace::PathAndParameters` (the same
/// diagonal entries of the same inverse) and no path sd, with the reason in the details.
#[test]
fn parameter_only_laplace_sd_equals_the_full_one() {
    let p = preset("duffing").unwrap();
    let data = data_for(&p, &[0.0, 0.3, 0.6, 0.9]);
    let estimate = [0, 1, 2];
    let prob = p.problem(&data, &estimate);
    let options = |laplace| {
        PathOptions::new(Merit::OnsagerMachlup, Transcription::HermiteSimpson)
            .with_step(0.1)
            .with_laplace(laplace)
    };
    let full = estimate_path(&prob, options(Laplace::PathAndParameters)).unwrap().estimate;
    let only = estimate_path(&prob, options(Laplace::Parameters)).unwrap().estimate;
    let (a, b) = (full.theta_sd.unwrap(), only.theta_sd.unwrap());
    assert_eq!(a.len(), 3);
    for (x, y) in a.iter().zip(&b) {
        assert_relative_eq!(x, y, max_relative = 1e-10);
    }
    assert!(full.path.sd.is_some() && only.path.sd.is_none());
    assert_eq!(only.details.get::<PathDetails>().unwrap().sd, LaplaceSd::ParametersOnly);
    let off = estimate_path(&prob, options(Laplace::Off)).unwrap().estimate;
    assert!(off.theta_sd.is_none() && off.path.sd.is_none());
}

/// Non-convergence is a status, not an error: two iterations are not enough for Duffing.
#[test]
fn iteration_limit_is_a_status() {
    let p = preset("duffing").unwrap();
    let data = data_for(&p, &[0.0, 0.3, 0.6, 0.9]);
    let estimate = [0, 1, 2];
    let prob = p.problem(&data, &estimate);
    let options = PathOptions::new(Merit::OnsagerMachlup, Transcription::HermiteSimpson)
        .with_step(0.1)
        .with_nlp(NlpOptions::default().with_max_iterations(2));
    let sol = estimate_path(&prob, options).unwrap();
    assert_eq!(sol.estimate.status, crate::Status::MaxIterations);
    assert!(sol.estimate.path.sd.is_none(), "no Laplace sd at a non-converged point");
}

/// The interpolation guess: linear between measurements (here 0.8 cos(1.3 t) at 0.5 and 1.0),
/// constant before the first, zeros for the unmeasured state.
#[test]
fn interpolation_guess_interpolates_measured_states() {
    let p = preset("duffing").unwrap();
    let data = data_for(&p, &[0.5, 1.0]);
    let g = interpolation_guess(vec!["x".into(), "z".into()], 2, &p.observation.states, &data, 0.0);
    assert_eq!(g.times, vec![0.0, 0.5, 1.0]);
    let y = |t: f64| 0.8 * (1.3 * t).cos();
    for (row, expected) in g.values.iter().zip([y(0.5), y(0.5), y(1.0)]) {
        assert_eq!(row[0], 0.0);
        assert_relative_eq!(row[1], expected, epsilon = 1e-15);
    }
    let grid = Grid::try_new(0.0, 0.25, &data.times).unwrap();
    let on_grid = guess_on_grid(Some(&g), &grid, 2).unwrap();
    assert_relative_eq!(on_grid[3][1], 0.5 * (y(0.5) + y(1.0)), epsilon = 1e-15);
}

/// Van der Pol: u̇ = v; Duffing: ż = x (000 Sec. 4.1.1); Ornstein–Uhlenbeck: none.
#[test]
fn derivative_states_are_detected_from_the_drift() {
    for (name, expected) in
        [("van-der-pol", vec![Some(1), None]), ("duffing", vec![None, Some(0)]), ("ou", vec![None])]
    {
        let p = preset(name).unwrap();
        assert_eq!(derivative_states(&p.model, &p.theta), expected, "{name}");
    }
}

/// A measurement model whose outputs are not the data's columns is an error, not a NaN.
#[test]
fn likelihood_with_the_wrong_output_count_is_an_error() {
    let mut p = preset("ou").unwrap();
    let data = data_for(&p, &[0.0, 0.5]);
    p.observation = StateMeasurement::new(vec![0, 0], vec!["y".into(), "y2".into()], p.observation.noise);
    let prob = p.problem(&data, &[]);
    let err = build_nlp(&prob, &PathOptions::default()).err().unwrap();
    assert!(err.to_string().contains("outputs"), "{err}");
}

/// The band KKT solver (chosen automatically for these time-ordered programs) and faer's
/// general sparse LDLᵀ give the same joint Duffing estimate, for every transcription and
/// merit.
#[test]
fn band_and_faer_kkt_solvers_give_the_same_estimate() {
    use crate::nlp::LinearSolver;
    let p = preset("duffing").unwrap();
    let times: Vec<f64> = (0..=20).map(|k| 0.1 * k as f64).collect();
    let data = data_for(&p, &times);
    for transcription in [Transcription::HermiteSimpson, Transcription::Trapezoidal, Transcription::Euler] {
        for merit in [Merit::OnsagerMachlup, Merit::Energy] {
            let prob = p.problem(&data, &[0, 1, 2]);
            let run = |solver| {
                let options = PathOptions::new(merit, transcription)
                    .with_step(0.025)
                    .with_laplace(Laplace::Off)
                    .with_nlp(NlpOptions::default().with_linear_solver(solver));
                estimate_path(&prob, options).unwrap()
            };
            let (faer, auto) = (run(LinearSolver::Faer), run(LinearSolver::Auto));
            assert_eq!(faer.report.linear_solver, "faer");
            assert_eq!(auto.report.linear_solver, "band");
            eprintln!(
                "{transcription:?} {merit:?}: faer {} / {} iterations, band {} / {}",
                faer.report.status, faer.report.iterations, auto.report.status, auto.report.iterations
            );
            assert_eq!(faer.report.status, crate::Status::Converged);
            assert_eq!(auto.report.status, faer.report.status);
            // the orders of elimination differ, so do rounding and which pivots need
            // regularisation: on these nonconvex programs the iterates may part ways, but both
            // must reach the same optimum, the band solver in no more iterations (+2)
            assert!(auto.report.iterations <= faer.report.iterations + 2, "{transcription:?} {merit:?}");
            for (ra, rf) in auto.estimate.path.values.iter().zip(&faer.estimate.path.values) {
                for (a, f) in ra.iter().zip(rf) {
                    assert_relative_eq!(a, f, epsilon = 1e-6, max_relative = 1e-6);
                }
            }
            for (a, f) in auto.estimate.theta.iter().zip(&faer.estimate.theta) {
                assert_relative_eq!(a, f, epsilon = 1e-6, max_relative = 1e-6);
            }
        }
    }
}

/// The band and faer KKT solvers solve the KKT system of a JME transcription (Van der Pol,
/// Hermite–Simpson, Onsager–Machlup, at the initial point with random multipliers) to the same
/// solution within 1e-10 (relative to its largest component), and both to a relative residual
/// of 1e-10: here the second state enters the drift linearly, so its pivots are numerically
/// zero and are regularised (see `nlp::kkt::REGULARIZATION_DELTA`), which iterative refinement
/// must repair.
#[test]
fn band_and_faer_solve_a_jme_kkt_system_alike() {
    use crate::nlp::{BandLdlt, FaerLdlt, KktSolver, KktStructure, KktValues};
    use rand::{RngExt, SeedableRng};
    let p = preset("van-der-pol").unwrap();
    let times: Vec<f64> = (0..=20).map(|k| 0.1 * k as f64).collect();
    let data = data_for(&p, &times);
    let prob = p.problem(&data, &[]);
    let options = PathOptions::new(Merit::OnsagerMachlup, Transcription::HermiteSimpson).with_step(0.005);
    let mut nlp = build_nlp(&prob, &options).unwrap();
    let (n, m) = (nlp.num_variables(), nlp.num_constraints());
    let mut w = vec![0.0; n];
    nlp.initial_point(&mut w);
    let (hs, js) = (nlp.hessian_structure(), nlp.jacobian_structure());
    let mut rng = rand::rngs::StdRng::seed_from_u64(3);
    let lambda: Vec<f64> = (0..m).map(|_| rng.random_range(-1.0..1.0)).collect();
    let (mut hv, mut jv) = (vec![0.0; hs.len()], vec![0.0; js.len()]);
    nlp.hessian_values(&w, 1.0, &lambda, &mut hv);
    nlp.jacobian_values(&w, &mut jv);
    let structure = KktStructure::new(n, m, &hs, &js);
    let sigma = vec![0.0; n];
    let values =
        KktValues { hessian: &hv, jacobian: &jv, primal_diagonal: &sigma, delta_w: 0.0, delta_c: 0.0 };
    let (mut band, mut faer) = (BandLdlt::new(), FaerLdlt::new());
    band.analyse(&structure).unwrap();
    faer.analyse(&structure).unwrap();
    let bi = band.factorize(&values).unwrap();
    let fi = faer.factorize(&values).unwrap();
    assert!(bi.regularized_pivots > 0 && fi.regularized_pivots > 0, "{bi:?} {fi:?}");
    for _ in 0..3 {
        let rhs: Vec<f64> = (0..n + m).map(|_| rng.random_range(-1.0..1.0)).collect();
        let (mut xb, mut xf) = (rhs.clone(), rhs.clone());
        let rb = band.solve_in_place(&mut xb);
        let rf = faer.solve_in_place(&mut xf);
        assert!(rb <= 1e-10 && rf <= 1e-10, "residuals {rb:.1e} {rf:.1e}");
        let scale = xf.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        for (b, f) in xb.iter().zip(&xf) {
            assert!((b - f).abs() <= 1e-10 * scale, "{b} vs {f} (scale {scale:.2e})");
        }
    }
}

/// The transcriptions' ordering hint ([`NlpProblem::kkt_order`]) against the band solver's own
/// order (reverse Cuthill–McKee, each constraint after its last variable, θ last), on five
/// models (with estimated θ for Duffing): for Euler and trapezoidal it is that order; for
/// Hermite–Simpson its envelope is narrower, and a JME KKT matrix (at the initial point, with
/// random multipliers) factorises without a regularised pivot, where RCM's order regularises
/// at least two per piece on Van der Pol and Duffing (their velocities have no curvature). On
/// the grid of the Van der Pol benchmark (3200 pieces) the envelope is 204,811 entries against
/// 243,187, and 6,400 regularised pivots become none.
#[test]
fn kkt_order_avoids_zero_pivots_and_narrows_the_band() {
    use crate::nlp::{BandLdlt, KktSolver, KktStructure, KktValues};
    use rand::{RngExt, SeedableRng};
    // the band solvers without and with the hint, and their regularised pivots
    let analyses = |name: &str, estimate: &[usize], times: &[f64], options: &PathOptions| {
        let p = preset(name).unwrap();
        let data = data_for(&p, times);
        let prob = p.problem(&data, estimate);
        let mut nlp = build_nlp(&prob, options).unwrap();
        let (n, m) = (nlp.num_variables(), nlp.num_constraints());
        let (hs, js) = (nlp.hessian_structure(), nlp.jacobian_structure());
        let order = nlp.kkt_order().unwrap();
        let mut w = vec![0.0; n];
        nlp.initial_point(&mut w);
        let mut rng = rand::rngs::StdRng::seed_from_u64(3);
        let lambda: Vec<f64> = (0..m).map(|_| rng.random_range(-1.0..1.0)).collect();
        let (mut hv, mut jv) = (vec![0.0; hs.len()], vec![0.0; js.len()]);
        nlp.hessian_values(&w, 1.0, &lambda, &mut hv);
        nlp.jacobian_values(&w, &mut jv);
        let sigma = vec![0.0; n];
        let values =
            KktValues { hessian: &hv, jacobian: &jv, primal_diagonal: &sigma, delta_w: 0.0, delta_c: 0.0 };
        let (mut rcm, mut hinted) = (BandLdlt::new(), BandLdlt::new());
        rcm.analyse(&KktStructure::new(n, m, &hs, &js)).unwrap();
        hinted.analyse(&KktStructure::new(n, m, &hs, &js).with_order(Some(&order))).unwrap();
        let regularized = [&mut rcm, &mut hinted].map(|s| s.factorize(&values).unwrap().regularized_pivots);
        (rcm, hinted, regularized)
    };
    let times: Vec<f64> = (0..=20).map(|k| 0.1 * k as f64).collect();
    let cases: &[(&str, &[usize])] = &[
        ("ou", &[]),
        ("van-der-pol", &[]),
        ("duffing", &[0, 1, 2]),
        ("holmes-rand", &[]),
        ("double-well", &[]),
    ];
    for &(name, estimate) in cases {
        for transcription in [Transcription::HermiteSimpson, Transcription::Trapezoidal, Transcription::Euler]
        {
            let options = PathOptions::new(Merit::OnsagerMachlup, transcription).with_step(0.025);
            let (rcm, hinted, [reg_rcm, reg_hinted]) = analyses(name, estimate, &times, &options);
            let what = format!("{name} {}", transcription.name());
            if transcription == Transcription::HermiteSimpson {
                assert!(hinted.envelope_size() < rcm.envelope_size(), "{what}");
                assert_eq!(reg_hinted, 0, "{what}");
                if matches!(name, "van-der-pol" | "duffing") {
                    assert!(reg_rcm >= 2 * 80, "{what}: {reg_rcm}");
                }
            } else {
                assert_eq!(hinted.permutation(), rcm.permutation(), "{what}");
            }
        }
    }
    // the grid of the Van der Pol benchmark: 3200 Hermite–Simpson pieces on [0, 16]
    let times: Vec<f64> = (0..=160).map(|k| 0.1 * k as f64).collect();
    let options = PathOptions::new(Merit::OnsagerMachlup, Transcription::HermiteSimpson).with_step(0.005);
    let (rcm, hinted, regularized) = analyses("van-der-pol", &[], &times, &options);
    assert_eq!([rcm.envelope_size(), hinted.envelope_size()], [243_187, 204_811]);
    assert_eq!(regularized, [6400, 0]);
}

/// A KKT solver kept across estimates reuses its analysis (for the Laplace sd after the solve
/// and for the next estimate on the same grid) and gives bit-for-bit the estimate of a fresh
/// solver; a different grid gets a fresh analysis.
#[test]
fn kept_kkt_solver_reuses_its_analysis() {
    use crate::nlp::AutoLdlt;
    let p = preset("duffing").unwrap();
    let times: Vec<f64> = (0..=20).map(|k| 0.1 * k as f64).collect();
    let data = data_for(&p, &times);
    let prob = p.problem(&data, &[0, 1, 2]);
    let options =
        |step: f64| PathOptions::new(Merit::OnsagerMachlup, Transcription::HermiteSimpson).with_step(step);
    let fresh = estimate_path(&prob, options(0.025)).unwrap();
    let mut kkt = AutoLdlt::new();
    let reused = |k: &AutoLdlt| match k {
        AutoLdlt::Band(b) => b.reused_analyses(),
        AutoLdlt::Faer(_) => panic!("expected the band solver"),
    };
    for round in 1..=2 {
        let kept = estimate_path_with(&prob, options(0.025), &mut kkt).unwrap();
        // the NLP solve and the Laplace sd of the first estimate analyse once; later ones reuse
        assert_eq!(reused(&kkt), 2 * round - 1);
        assert_eq!(kept.report.iterations, fresh.report.iterations);
        assert_eq!(kept.estimate.path.values, fresh.estimate.path.values);
        assert_eq!(kept.estimate.path.sd, fresh.estimate.path.sd);
        assert_eq!(kept.estimate.theta, fresh.estimate.theta);
    }
    let other = estimate_path_with(&prob, options(0.05), &mut kkt).unwrap();
    assert_eq!(other.report.status, crate::Status::Converged);
    let sd = other.estimate.path.sd.as_ref().expect("Laplace sd");
    assert!(sd.iter().flatten().all(|v| v.is_finite() && *v > 0.0));
}

/// A built-in model without its closed-form `drift_derivatives`: the transcription then
/// differentiates the drifts automatically. (A wrapper for the one comparison below, not a
/// model, so not in `test_models`.)
struct WithoutClosedForm<'a>(&'a crate::model::library::Model);

impl crate::model::Sde for WithoutClosedForm<'_> {
    fn dims(&self) -> crate::model::Dims {
        self.0.dims()
    }
    fn noisy_names(&self) -> Vec<String> {
        self.0.noisy_names()
    }
    fn clean_names(&self) -> Vec<String> {
        self.0.clean_names()
    }
    fn param_names(&self) -> Vec<String> {
        self.0.param_names()
    }
    fn drift<D: crate::model::Scalar>(&self, t: D, x: &[D], z: &[D], theta: &[D], out: &mut [D]) {
        self.0.drift(t, x, z, theta, out)
    }
    fn clean_drift<D: crate::model::Scalar>(&self, t: D, x: &[D], z: &[D], theta: &[D], out: &mut [D]) {
        self.0.clean_drift(t, x, z, theta, out)
    }
    fn diffusion<D: crate::model::Scalar>(&self, theta: &[D], out: &mut [D]) {
        self.0.diffusion(theta, out)
    }
    fn drift_uses_param(&self, i: usize) -> bool {
        self.0.drift_uses_param(i)
    }
    fn divergence<D: crate::model::Scalar>(&self, t: D, x: &[D], z: &[D], theta: &[D]) -> D {
        self.0.divergence(t, x, z, theta)
    }
}

/// The gradient, the constraint Jacobian values and the Hessian values (σ_f = 0.7) at `w`.
fn all_derivatives<P: NlpProblem>(nlp: &mut P, w: &[f64], lambda: &[f64]) -> [Vec<f64>; 3] {
    let (nj, nh) = (nlp.jacobian_structure().len(), nlp.hessian_structure().len());
    let (mut g, mut jv, mut hv) = (vec![0.0; w.len()], vec![0.0; nj], vec![0.0; nh]);
    nlp.gradient(w, &mut g);
    nlp.jacobian_values(w, &mut jv);
    nlp.hessian_values(w, 0.7, lambda, &mut hv);
    [g, jv, hv]
}

/// The Hermite–Simpson gradient, Jacobian and Hessian from the models' closed-form
/// `drift_derivatives` equal those from automatic differentiation of the drifts (Duffing with
/// three estimated parameters in the dynamics and one outside, Van der Pol with μ estimated),
/// both merits, at two successive points (the second reuses the first's stored outputs).
#[test]
fn closed_form_point_derivatives_equal_automatic_ones() {
    for (name, estimate) in [("duffing", vec![0, 1, 2, 5]), ("van-der-pol", vec![0])] {
        let p = preset(name).unwrap();
        let data = data_for(&p, &[0.0, 0.3, 0.6]);
        let plain = WithoutClosedForm(&p.model);
        for merit in [Merit::OnsagerMachlup, Merit::Energy] {
            let closed = p.problem(&data, &estimate);
            let automatic = EstimationProblem {
                sde: &plain,
                observation: closed.observation,
                theta: closed.theta,
                theta_prior: closed.theta_prior,
                estimate: &estimate,
                x0_prior: closed.x0_prior,
                z0_prior: closed.z0_prior,
                data: &data,
                t0: 0.0,
                seed: 0,
                max_memory: Default::default(),
            };
            let options = PathOptions::new(merit, Transcription::HermiteSimpson).with_step(0.15);
            let mut a = build_nlp(&closed, &options).unwrap();
            let mut b = build_nlp(&automatic, &options).unwrap();
            let (n, m) = (a.num_variables(), a.num_constraints());
            assert_eq!(a.hessian_structure(), b.hessian_structure());
            let mut w = vec![0.0; n];
            a.initial_point(&mut w);
            let lambda: Vec<f64> = (0..m).map(|r| ((r as f64) * 1.3).cos()).collect();
            for step in 0..2 {
                for (i, wi) in w.iter_mut().enumerate() {
                    *wi += 0.1 * ((i as f64) * 0.7 + step as f64).sin();
                }
                let (x, y) = (all_derivatives(&mut a, &w, &lambda), all_derivatives(&mut b, &w, &lambda));
                for (u, v) in x.iter().zip(&y) {
                    for (s, t) in u.iter().zip(v) {
                        assert_relative_eq!(s, t, epsilon = 1e-12, max_relative = 1e-12);
                    }
                }
            }
        }
    }
}
