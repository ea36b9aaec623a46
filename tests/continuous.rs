//! Continuous-time records (`003_d2fc48a470e528fc.txt` Sec. I.4): on a linear Ornstein–Uhlenbeck
//! model with a continuous record, the estimators on the record's cell averages converge to the
//! Kalman–Bucy smoother as the cells shrink.

use rand::rngs::StdRng;
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};

use onsager::action::closure::Closure;
use onsager::action::{ksp_smoother, mean_optimal, ClosureOptions, ExactOptions, GridSpec};
use onsager::data::continuous::ContinuousRecord;
use onsager::data::Dataset;
use onsager::estimate::{EstimationProblem, Status};
use onsager::model::library::Ou;
use onsager::model::observation::StateMeasurement;
use onsager::model::prior::Prior;
use onsager::simulate::{simulate, SimulateOptions};
use onsager::Estimator;

/// OU dX = −θX dt + σ dW with θ = 1, σ = 0.5, x(0) ~ N(0, 0.5²), on [0, T].
const THETA: [f64; 2] = [1.0, 0.5];
const T: f64 = 2.0;
/// The record's intensity R and the fine step on which it is drawn.
const R: f64 = 0.01;
const FINE: f64 = 0.0005;

/// A continuous record dY = x dt + √R dW of a simulated path, as its increments over the fine
/// steps (the path's trapezoidal integral plus √(R·FINE) ε per step).
fn record() -> Vec<f64> {
    let mut rng = StdRng::seed_from_u64(34);
    let path = simulate(&Ou, &THETA, &[0.3], &[], &SimulateOptions::new(0.0, T, FINE), &mut rng).unwrap();
    path.values
        .windows(2)
        .map(|w| {
            let e: f64 = StandardNormal.sample(&mut rng);
            0.5 * (w[0][0] + w[1][0]) * FINE + (R * FINE).sqrt() * e
        })
        .collect()
}

/// The record seen on cells of `m` fine steps: cell averages at the cell midpoints.
fn cell_averages(dy: &[f64], m: usize) -> ContinuousRecord {
    let cell = m as f64 * FINE;
    let (times, values): (Vec<f64>, Vec<Vec<f64>>) = dy
        .chunks_exact(m)
        .enumerate()
        .map(|(k, c)| ((k as f64 + 0.5) * cell, vec![c.iter().sum::<f64>() / cell]))
        .unzip();
    ContinuousRecord::try_new(R, Dataset::try_new(vec!["y".into()], times, values).unwrap()).unwrap()
}

/// The Kalman–Bucy filter and the continuous-time RTS smoother of the record on the fine grid
/// (Särkkä & Solin 2019, *Applied Stochastic Differential Equations*, Sec. 10.6 (filter, eqs.
/// (10.71)–(10.72)) and Thm 10.17 (smoother); Jazwinski 1970, Sec. 7.3 and 7.6), for the scalar
/// model f = −θ, Q = σ², H = 1:
///
/// dm/dt = −θm + (P/R)(r − m), dP/dt = −2θP + Q − P²/R, m(0) = 0, P(0) = 0.25;
/// dmₛ/dt = −θmₛ + (Q/P)(mₛ − m), backward from mₛ(T) = m(T),
///
/// with the signal r = dY/dt constant on each fine step, RK4 on each fine step forward (P,
/// m) and backward (mₛ, with m and P linear between fine points). Returns mₛ on the fine grid.
fn kalman_bucy_smoother(dy: &[f64]) -> Vec<f64> {
    let (theta, q) = (THETA[0], THETA[1] * THETA[1]);
    let n = dy.len();
    let (mut m, mut p) = (vec![0.0; n + 1], vec![0.25; n + 1]);
    let rk4 = |y: [f64; 2], f: &dyn Fn([f64; 2], f64) -> [f64; 2], h: f64| {
        let k1 = f(y, 0.0);
        let k2 = f([y[0] + 0.5 * h * k1[0], y[1] + 0.5 * h * k1[1]], 0.5);
        let k3 = f([y[0] + 0.5 * h * k2[0], y[1] + 0.5 * h * k2[1]], 0.5);
        let k4 = f([y[0] + h * k3[0], y[1] + h * k3[1]], 1.0);
        [0, 1].map(|i| y[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]))
    };
    for j in 0..n {
        let r = dy[j] / FINE;
        let f = |y: [f64; 2], _: f64| {
            [-theta * y[0] + y[1] / R * (r - y[0]), -2.0 * theta * y[1] + q - y[1] * y[1] / R]
        };
        let next = rk4([m[j], p[j]], &f, FINE);
        (m[j + 1], p[j + 1]) = (next[0], next[1]);
    }
    let mut ms = vec![0.0; n + 1];
    ms[n] = m[n];
    for j in (0..n).rev() {
        // Backward in time: s = 0 at t_{j+1}, s = 1 at t_j.
        let at = |s: f64| (m[j + 1] + s * (m[j] - m[j + 1]), p[j + 1] + s * (p[j] - p[j + 1]));
        let f = |y: [f64; 2], s: f64| {
            let (mf, pf) = at(s);
            [-(-theta * y[0] + q / pf * (y[0] - mf)), 0.0]
        };
        ms[j] = rk4([ms[j + 1], 0.0], &f, FINE)[0];
    }
    ms
}

/// max |estimate − reference| over the estimate's times in [0, T] (the reference on the fine
/// grid, linear between its points).
fn distance(times: &[f64], mean: &[f64], reference: &[f64]) -> f64 {
    times
        .iter()
        .zip(mean)
        .filter(|(&t, _)| t <= T + 1e-9)
        .map(|(&t, &v)| {
            let x = t / FINE;
            let j = (x.floor() as usize).min(reference.len() - 2);
            let s = x - j as f64;
            (v - ((1.0 - s) * reference[j] + s * reference[j + 1])).abs()
        })
        .fold(0.0, f64::max)
}

#[test]
fn ou_with_a_continuous_record_converges_to_the_kalman_bucy_smoother() {
    let dy = record();
    let reference = kalman_bucy_smoother(&dy);
    let theta_prior = [Prior::flat(); 2];
    let x0_prior = [Prior::gaussian(0.0, 0.5)];
    let mut rows = Vec::new();
    for m in [40, 20] {
        let rec = cell_averages(&dy, m);
        let observation = StateMeasurement::new(vec![0], vec!["y".into()], rec.noise());
        let problem = EstimationProblem {
            sde: &Ou,
            observation: &observation,
            theta: &THETA,
            theta_prior: &theta_prior,
            estimate: &[],
            x0_prior: &x0_prior,
            z0_prior: &[],
            data: &rec.data,
            t0: 0.0,
            seed: 0,
            max_memory: Default::default(),
        };
        let exact =
            ExactOptions::new(GridSpec::new_1d(-6.0, 6.0, 1200)).with_dt(0.001).with_output_step(0.05);
        let ksp = ksp_smoother(&problem, &exact).unwrap();
        let ksp_mean: Vec<f64> = ksp.smoothed_mean.iter().map(|v| v[0]).collect();
        let mo = mean_optimal(&problem, &exact).unwrap();
        assert_eq!(mo.status, Status::Converged, "mean-optimal on cells of {}", rec.cell());
        let mo_mean: Vec<f64> = mo.history.mean.iter().map(|v| v[0]).collect();
        let options = ClosureOptions::new().with_tolerances(1e-10, 1e-12).with_output_step(0.05);
        let gc = Estimator::GaussianClosure(Closure::gaussian(options)).run(&problem).unwrap().estimate;
        assert_eq!(gc.status, Status::Converged, "Gaussian closure on cells of {}", rec.cell());
        let gc_mean: Vec<f64> = gc.path.values.iter().map(|v| v[0]).collect();
        rows.push((
            rec.cell(),
            distance(&ksp.times, &ksp_mean, &reference),
            distance(&mo.history.times, &mo_mean, &reference),
            distance(&gc.path.times, &gc_mean, &reference),
        ));
    }
    let report = rows
        .iter()
        .map(|(cell, k, mo, g)| {
            format!("Δ = {cell}: ksp {k:.3e}, mean-optimal {mo:.3e}, gaussian-closure {g:.3e}")
        })
        .collect::<Vec<_>>()
        .join("; ");
    let (coarse, fine) = (rows[0], rows[1]);
    for (name, a, b) in [
        ("ksp", coarse.1, fine.1),
        ("mean-optimal", coarse.2, fine.2),
        ("gaussian-closure", coarse.3, fine.3),
    ] {
        assert!(b < 0.8 * a, "{name}: the distance to the Kalman–Bucy smoother must shrink: {report}");
        assert!(b < 0.02, "{name}: too far from the Kalman–Bucy smoother: {report}");
    }
    println!("{report}");
}
