//! Tests of the ensemble Kalman filter and smoother: the linear-Gaussian identity with the exact
//! Kalman filter and RTS smoother ([`crate::kalman::linear`]) within Monte Carlo error, the
//! options through the estimator interface, determinism, and the checked assumptions. The
//! models and records are the shared fixtures of [`crate::test_models`].

use nalgebra::{DMatrix, DVector};
use rand::rngs::StdRng;
use rand::SeedableRng;

use super::*;
use crate::data::Dataset;
use crate::estimator::Estimator;
use crate::kalman::linear::{kalman_rts, KalmanSmoothing, LinearGaussianModel};
use crate::model::library::preset;
use crate::model::observation::Noise;
use crate::model::prior::Prior;
use crate::model::{Dims, Param, Scalar};
use crate::test_models::{OscillatorRecord, OuRecord, PresetRecord};

/// The exact Kalman filter and RTS smoother of a linear `problem` whose initial-state priors
/// are the Gaussians N(`m0`, diag(`sd0`²)).
fn reference<S: Sde + ?Sized>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    m0: &[f64],
    sd0: &[f64],
) -> KalmanSmoothing {
    let p0 = DMatrix::from_diagonal(&DVector::from_iterator(sd0.len(), sd0.iter().map(|s| s * s)));
    let m0 = DVector::from_column_slice(m0);
    let model =
        LinearGaussianModel::from_sde(problem.sde, problem.theta, problem.observation, problem.t0, m0, p0)
            .unwrap();
    kalman_rts(&model, problem.data, &[]).unwrap()
}

/// Statistics computed by R independent runs: `runs[r][k][i]` at time k and state i.
type Runs<'a> = [&'a [Vec<f64>]];

/// The largest deviation over the times and states of the average of R independent runs from
/// `exact`, beyond a known bias bound `allowance`, in units of the standard error of the
/// average: max(|average − exact| − allowance, 0) / (SE/√R), SE (the standard error of one run)
/// estimated by the spread of the runs. Also returns the largest SE / `scale(k, i)`.
fn z_score(
    runs: &Runs<'_>,
    exact: impl Fn(usize, usize) -> f64,
    allowance: impl Fn(usize, usize) -> f64,
    scale: impl Fn(usize, usize) -> f64,
) -> (f64, f64) {
    let r = runs.len() as f64;
    let (mut z, mut se_scaled) = (0.0f64, 0.0f64);
    for k in 0..runs[0].len() {
        for i in 0..runs[0][k].len() {
            let avg = runs.iter().map(|run| run[k][i]).sum::<f64>() / r;
            let se = (runs.iter().map(|run| (run[k][i] - avg).powi(2)).sum::<f64>() / (r - 1.0)).sqrt();
            let beyond = ((avg - exact(k, i)).abs() - allowance(k, i)).max(0.0);
            z = z.max(beyond / (se / r.sqrt()));
            se_scaled = se_scaled.max(se / scale(k, i));
        }
    }
    (z, se_scaled)
}

/// No known bias.
fn unbiased(_: usize, _: usize) -> f64 {
    0.0
}

/// The agreement of R independent EnKS runs with the exact Kalman filter and RTS smoother:
/// the largest deviations of the averages of the runs in standard errors of the average
/// ([`z_score`]; for the smoothed sd beyond its shrinkage bound), and the largest standard
/// error of one run's smoothed mean relative to the exact smoothed sd.
#[derive(Debug)]
struct Agreement {
    smoothed_mean: f64,
    smoothed_sd: f64,
    filtered_mean: f64,
    filtered_sd: f64,
    log_likelihood: f64,
    one_run_se_over_sd: f64,
}

impl Agreement {
    /// Monte Carlo acceptance (STYLE.md): every average within 4 standard errors of the exact
    /// value (the smoothed sd beyond its shrinkage bound), and one run's error small compared
    /// with the posterior sd (a sanity bound, not the acceptance: SE ≤ sd/√10, as for the
    /// particle smoother in tests/baselines.rs).
    fn check(&self, what: &str) {
        let worst =
            [self.smoothed_mean, self.smoothed_sd, self.filtered_mean, self.filtered_sd, self.log_likelihood];
        assert!(worst.iter().all(|&z| z < 4.0), "{what}: {self:?} (tolerance 4 SE)");
        assert!(self.one_run_se_over_sd < 10f64.sqrt().recip(), "{what}: {self:?}");
    }
}

/// Independent runs of each comparison with the exact Kalman/RTS solution. With 31 degrees of
/// freedom in the estimated SE, a deviation of 4 SE has probability 4·10⁻⁴ by chance.
const RUNS: u64 = 32;

/// Runs the EnKS with `options` from [`RUNS`] seeds on a linear `problem` (t0 the first
/// measurement time) and compares its smoother, its filter and its log-likelihood with the
/// exact ones, `rts`.
///
/// The smoothed sd at t_j has a known bias, which is allowed for: each later analysis shrinks
/// the ensemble variance at t_j by the sampling variance of its cross-covariance with the
/// measurement, Var(s_j) Var(H s_k) / N, relative to S = Var(H s_k) + R, i.e. by κ_k / N with
/// κ_k = HPHᵀ/S < 1, and about as much again through the sampled correlation of s_j with the
/// perturbations (Evensen & van Leeuwen 2000 discuss this spurious-correlation loss): the
/// relative sd bias is at most (number of later analyses) / N. Measured on OU with 20 later
/// analyses: −1.25 % at N = 1000, −2.4 % at N = 250 (bounds 2 % and 8 %).
fn compare_with_rts<S: Sde + ?Sized>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    rts: &KalmanSmoothing,
    options: &EnksOptions,
) -> Agreement {
    let runs: Vec<EnksSmoothing> = (0..RUNS)
        .map(|seed| {
            let out = ensemble_smoother(problem, options, &mut StdRng::seed_from_u64(100 + seed)).unwrap();
            assert_eq!(out.status, Status::Converged);
            assert_eq!(out.times, problem.data.times, "t0 is the first measurement time");
            out
        })
        .collect();
    let analysed: Vec<bool> = problem.data.values.iter().map(|y| y.iter().any(|v| !v.is_nan())).collect();
    assert_eq!(runs[0].analyses, analysed.iter().filter(|&&a| a).count());
    let smoothed: Vec<_> = runs.iter().map(EnksSmoothing::mean_and_sd).collect();
    for (run, (mean, sd)) in runs.iter().zip(&smoothed) {
        // After the last analysis nothing updates the last ensemble: the smoother's last time
        // is the filter's, exactly.
        assert_eq!((mean.last(), sd.last()), (run.filtered_mean.last(), run.filtered_sd.last()));
    }
    let at = |k: usize| rts.index_of(problem.data.times[k]).unwrap();
    let smoothed_sd = |k: usize, i: usize| rts.smoothed_cov[at(k)][(i, i)].sqrt();
    let filtered_sd = |k: usize, i: usize| rts.filtered_cov[at(k)][(i, i)].sqrt();
    let later = |k: usize| analysed[k + 1..].iter().filter(|&&a| a).count() as f64;
    let shrinkage = |k: usize, i: usize| smoothed_sd(k, i) * later(k) / options.members as f64;
    let smoothed_means: Vec<&[Vec<f64>]> = smoothed.iter().map(|(m, _)| m.as_slice()).collect();
    let smoothed_sds: Vec<&[Vec<f64>]> = smoothed.iter().map(|(_, s)| s.as_slice()).collect();
    let filtered_means: Vec<&[Vec<f64>]> = runs.iter().map(|r| r.filtered_mean.as_slice()).collect();
    let filtered_sds: Vec<&[Vec<f64>]> = runs.iter().map(|r| r.filtered_sd.as_slice()).collect();
    let log_likelihoods: Vec<Vec<Vec<f64>>> = runs.iter().map(|r| vec![vec![r.log_likelihood]]).collect();
    let log_likelihoods: Vec<&[Vec<f64>]> = log_likelihoods.iter().map(Vec::as_slice).collect();
    let (smoothed_mean, one_run_se_over_sd) =
        z_score(&smoothed_means, |k, i| rts.smoothed_mean[at(k)][i], unbiased, smoothed_sd);
    Agreement {
        smoothed_mean,
        smoothed_sd: z_score(&smoothed_sds, smoothed_sd, shrinkage, smoothed_sd).0,
        filtered_mean: z_score(&filtered_means, |k, i| rts.filtered_mean[at(k)][i], unbiased, filtered_sd).0,
        filtered_sd: z_score(&filtered_sds, filtered_sd, unbiased, filtered_sd).0,
        log_likelihood: z_score(&log_likelihoods, |_, _| rts.log_likelihood, unbiased, |_, _| 1.0).0,
        one_run_se_over_sd,
    }
}

#[test]
fn ou_smoother_and_filter_match_the_exact_rts_smoother_and_kalman_filter() {
    // Identity (DESIGN.md, linear-Gaussian) on `OuRecord` (θ = 1, σ = 0.5, σ_y = 0.2,
    // x0 ~ N(0, 0.5²); 11 measurements on [0, 5]): the EnKS mean and sd tend, as N → ∞, to those
    // of the RTS smoother of the Euler-discretised model, the filter's to the Kalman filter's and
    // the log-likelihood to the exact one (Le Gland, Monbet & Tran 2011).
    //
    // The members of one run are not independent (they share the sampled gain), so σ/√N is
    // not the Monte Carlo error of one run's mean (measured: up to 4 σ/√N at the early times):
    // that error is estimated from R = 32 independent runs, whose average must lie within
    // 4 standard errors of the exact value (fixed seeds); SE/√R ≈ 1.5/√(2N)/√32 = 0.4 % of
    // the sd for N = 2500. The smoothed sd is allowed its known shrinkage (at most the number
    // of later analyses / N relative, see `compare_with_rts`); the Euler bias of the variances,
    // relative θ dt / 2 = 0.1 % with dt = 0.002, is below the tolerance.
    let record = OuRecord::new().unwrap();
    let options = EnksOptions::default().with_members(2500).with_dt(0.002);
    let agreement = compare_with_rts(&record.problem(), &record.rts(&[]).unwrap(), &options);
    eprintln!("EnKS vs exact Kalman/RTS on OuRecord, 32 runs of N = 2500: {agreement:?}");
    agreement.check("OU");
}

#[test]
fn clean_state_measured_alone_updates_the_noisy_state_as_the_rts_smoother() {
    // Identity (linear-Gaussian) with a clean state, on `OscillatorRecord` (LinearOscillator,
    // θ = (0.7, 1.5, 0.3, 0.4, 0.15), v0 ~ N(0.1, 0.5²), q0 ~ N(−0.3, 0.6²); q measured every
    // 0.2 on [0, 4], one value missing): only q is measured, so the velocity v is corrected
    // through the ensemble cross-covariances alone (E4, E5), and the missing value exercises the
    // skipped analysis. The acceptance as in the OU test (32 runs of N = 2500; substep 0.001:
    // Euler bias O(|A| dt) ≈ 0.15 %).
    let record = OscillatorRecord::new().unwrap();
    let problem = record.problem();
    let rts = reference(&problem, &[0.1, -0.3], &[0.5, 0.6]);
    let options = EnksOptions::default().with_members(2500).with_dt(0.001);
    let agreement = compare_with_rts(&problem, &rts, &options);
    eprintln!("EnKS vs exact Kalman/RTS on OscillatorRecord, 32 runs of N = 2500: {agreement:?}");
    agreement.check("linear oscillator");
}

/// The `double-well` preset simulated with its own settings (41 measurements on [0, 20]).
fn double_well() -> PresetRecord {
    PresetRecord::simulate(preset("double-well").unwrap(), 1).unwrap()
}

#[test]
fn bad_options_are_errors_naming_the_option() {
    for (text, option) in [
        ("enks:members=1", "members"),
        ("enks:members=0", "members"),
        ("enks:inflation=0.99", "inflation"),
        ("enks:dt=0", "dt"),
        ("enks:dt=-0.1", "dt"),
        ("enks:particles=10", "particles"),
    ] {
        match Estimator::parse(text) {
            Err(Error::EstimatorOption { method, option: o, .. }) => {
                assert_eq!((method.as_str(), o.as_str()), ("enks", option), "{text}");
            }
            other => panic!("{text}: {other:?}"),
        }
    }
    for (options, option) in [
        (EnksOptions::default().with_members(1), "members"),
        (EnksOptions::default().with_inflation(0.5), "inflation"),
        (EnksOptions::default().with_inflation(f64::INFINITY), "inflation"),
        (EnksOptions::default().with_dt(0.0), "dt"),
    ] {
        match Estimator::Enks(options).validate() {
            Err(Error::EstimatorOption { method, option: o, .. }) => {
                assert_eq!((method.as_str(), o.as_str()), ("enks", option));
            }
            other => panic!("{options:?}: {other:?}"),
        }
    }
    assert_eq!(Estimator::new(Method::Enks), Estimator::Enks(EnksOptions::default()));
    assert_eq!(Estimator::option_names(Method::Enks), ["dt", "inflation", "members"]);
}

#[test]
fn parsed_options_run_on_the_double_well() {
    let record = double_well();
    let data = &record.data;
    let estimator = Estimator::parse("enks:members=50,inflation=1.02").unwrap();
    assert_eq!(estimator, Estimator::Enks(EnksOptions::default().with_members(50).with_inflation(1.02)));
    let est = estimator.run(&record.problem(&[])).unwrap().estimate;
    assert_eq!((est.method, est.status), (Method::Enks, Status::Converged));
    assert_eq!(est.path.times, data.times);
    let sd = est.path.sd.as_ref().unwrap();
    assert!(est.path.values.iter().flatten().chain(sd.iter().flatten()).all(|v| v.is_finite()));
    assert!(sd.iter().flatten().all(|&s| s > 0.0));
    let details = est.details.get::<EnksDetails>().unwrap();
    assert_eq!((details.members, details.inflation, details.analyses), (50, 1.02, data.times.len()));
    assert!(details.log_likelihood.is_finite() && details.failed_at.is_none());
    assert_eq!(est.details["members"], 50);
}

#[test]
fn the_same_seed_gives_the_same_estimate() {
    let record = double_well();
    let run = |seed: u64| {
        let problem = EstimationProblem { seed, ..record.problem(&[]) };
        Estimator::new(Method::Enks).run(&problem).unwrap().estimate
    };
    let (a, b, c) = (run(5), run(5), run(6));
    assert_eq!(a.status, Status::Converged);
    assert_eq!((&a.path, &a.details), (&b.path, &b.details));
    assert_ne!(a.path.values, c.path.values);
}

#[test]
fn non_gaussian_likelihoods_and_improper_priors_are_rejected_and_proper_priors_accepted() {
    let mut record = double_well();
    let mut rng = StdRng::seed_from_u64(0);
    let options = EnksOptions::default().with_members(20);
    // A proper but non-Gaussian, bounded prior: the Kalman methods reject it, the EnKS draws it.
    record.preset.x0_prior = vec![Prior::flat().with_bounds(-1.5, -0.5)];
    assert!(enks(&record.problem(&[]), &options, &mut rng).is_ok());
    record.preset.x0_prior = vec![Prior::flat()];
    match enks(&record.problem(&[]), &options, &mut rng) {
        Err(Error::InvalidOption { name, .. }) => assert_eq!(name, "x0-prior"),
        other => panic!("{other:?}"),
    }
    record.preset.x0_prior = vec![Prior::gaussian(-1.0, 0.2)];
    record.preset.observation.noise = Noise::Laplace { scale: Param::Fixed(0.4) };
    match enks(&record.problem(&[]), &options, &mut rng) {
        Err(Error::InvalidOption { name, reason }) => {
            assert_eq!(name, "likelihood");
            assert!(reason.contains("enks"), "{reason}");
        }
        other => panic!("{other:?}"),
    }
}

/// dX = X² dt + dW: the solution from X0 = 1 blows up at t = 1. It stays beside its one test
/// (not in `test_models`): its only known answer is that it blows up.
struct Explosive;

impl Sde for Explosive {
    fn dims(&self) -> Dims {
        Dims { noisy: 1, clean: 0, params: 1 }
    }
    fn noisy_names(&self) -> Vec<String> {
        vec!["x".into()]
    }
    fn param_names(&self) -> Vec<String> {
        vec!["sigma_y".into()]
    }
    fn drift<D: Scalar>(&self, _t: D, x: &[D], _z: &[D], _th: &[D], out: &mut [D]) {
        out[0] = x[0] * x[0];
    }
    fn diffusion<D: Scalar>(&self, _th: &[D], out: &mut [D]) {
        out[0] = D::from(1.0);
    }
}

#[test]
fn a_non_finite_ensemble_is_a_numerical_failure_with_the_path_up_to_it() {
    let obs = StateMeasurement::new(vec![0], vec!["y".into()], Noise::Gaussian { sigma: Param::Fixed(0.1) });
    let data = Dataset::try_new(vec!["y".into()], vec![0.5, 3.0], vec![vec![2.0], vec![1.0]]).unwrap();
    let (x0, theta, theta_prior) = (vec![Prior::gaussian(1.0, 0.1)], vec![0.1], vec![Prior::flat()]);
    let problem = EstimationProblem {
        sde: &Explosive,
        observation: &obs,
        theta: &theta,
        theta_prior: &theta_prior,
        estimate: &[],
        x0_prior: &x0,
        z0_prior: &[],
        data: &data,
        t0: 0.0,
        seed: 0,
        max_memory: Default::default(),
    };
    let est =
        enks(&problem, &EnksOptions::default().with_members(10), &mut StdRng::seed_from_u64(1)).unwrap();
    assert_eq!(est.status, Status::NumericalFailure);
    assert_eq!(est.path.times, [0.0, 0.5]);
    assert!(est.path.values.iter().flatten().all(|v| v.is_finite()));
    let details = est.details.get::<EnksDetails>().unwrap();
    assert_eq!(details.failed_at, Some(3.0));
    assert!(details.log_likelihood.is_nan());
}

/// `enkf` is the filtered part of `enks`: the same random numbers give, bit for bit, the
/// smoother's filtered moments (whose identity with the Kalman filter the tests above check),
/// without the smoother's updates of the stored ensembles.
#[test]
fn the_ensemble_kalman_filter_is_the_filtered_part_of_the_smoother() {
    let record = double_well();
    let problem = EstimationProblem { seed: 9, ..record.problem(&[]) };
    let options = EnksOptions::default().with_members(60);
    let filter = Estimator::Enkf(options).run(&problem).unwrap().estimate;
    let smoothing = ensemble_smoother(&problem, &options, &mut StdRng::seed_from_u64(9)).unwrap();
    assert_eq!((filter.method, filter.status), (Method::Enkf, Status::Converged));
    assert_eq!(filter.path.times, smoothing.times);
    assert_eq!(filter.path.values, smoothing.filtered_mean);
    assert_eq!(filter.path.sd.as_ref().unwrap(), &smoothing.filtered_sd);
    let details = filter.details.get::<EnksDetails>().unwrap();
    assert_eq!((details.analyses, details.log_likelihood), (smoothing.analyses, smoothing.log_likelihood));
    // At the last time the filter is the smoother.
    let smoothed = Estimator::Enks(options).run(&problem).unwrap().estimate;
    assert_eq!(smoothed.path.values.last(), filter.path.values.last());
    assert_ne!(smoothed.path.values[0], filter.path.values[0]);
    assert!(matches!(Estimator::parse("enkf:members=1"), Err(Error::EstimatorOption { .. })));
}
