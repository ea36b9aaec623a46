//! Unit tests of the particle filter's building blocks and of the ancestral-path smoother.

use rand::rngs::StdRng;
use rand::SeedableRng;

use super::*;

#[test]
fn systematic_resampling_counts_are_floor_or_ceil_of_n_w() {
    // Property of systematic resampling (Kitagawa 1996): particle i is copied either
    // ⌊N wᵢ⌋ or ⌈N wᵢ⌉ times.
    let w = [0.05, 0.4, 0.0, 0.3, 0.25];
    let mut rng = StdRng::seed_from_u64(3);
    for _ in 0..50 {
        let mut out = [0usize; 16];
        systematic(&w, &mut rng, &mut out);
        for (i, &wi) in w.iter().enumerate() {
            let count = out.iter().filter(|&&o| o == i).count() as f64;
            let nw = 16.0 * wi;
            assert!(count >= nw.floor() && count <= nw.ceil(), "particle {i}: {count} copies for N w = {nw}");
        }
        assert!(out.windows(2).all(|p| p[0] <= p[1]));
    }
}

#[test]
fn options_are_validated() {
    let ok = ParticleOptions::default();
    assert!(ok.validate().is_ok());
    assert!(ok.with_particles(1).validate().is_err());
    assert!(ok.with_backward_paths(0).validate().is_err());
    assert!(ok.with_dt(-1.0).validate().is_err());
    let bad = ParticleOptions { ess_threshold: 1.5, ..ok };
    assert!(bad.validate().is_err());
}

#[test]
fn ancestral_smoother_with_a_clean_state_agrees_with_rts_within_monte_carlo_error() {
    // Models with clean states use the ancestral paths. Monte Carlo test: R = 8 runs with
    // N = 1000 on a short record (T = 1, 6 measurements of q); the average of the runs' means
    // of both states lies within 4 SE/√R of the exact RTS mean (kalman::linear), the SE from
    // the spread of the runs. The model: the linear oscillator of `test_models` without forcing,
    // dV = (−kV − cQ) dt + σ dW, dQ = V dt.
    use crate::kalman::linear::{kalman_rts, LinearGaussianModel};
    use crate::model::observation::{Noise, StateMeasurement};
    use crate::model::prior::Prior;
    use crate::model::Param;
    use crate::test_models::LinearOscillator;
    use nalgebra::{DMatrix, DVector};

    // θ = (k, c, u, σ, σ_y).
    let theta = [0.5, 2.0, 0.0, 0.5, 0.1];
    let sigma = Param::Theta(LinearOscillator::SIGMA_Y);
    let obs = StateMeasurement::new(vec![1], vec!["y".into()], Noise::Gaussian { sigma });
    let data = crate::data::Dataset::try_new(
        vec!["y".into()],
        vec![0.0, 0.2, 0.4, 0.6, 0.8, 1.0],
        vec![vec![0.3], vec![0.25], vec![0.05], vec![-0.1], vec![-0.3], vec![-0.35]],
    )
    .unwrap();
    let (x0, z0, flat) = ([Prior::gaussian(0.0, 0.5)], [Prior::gaussian(0.0, 0.5)], [Prior::flat(); 5]);
    let problem = EstimationProblem {
        sde: &LinearOscillator,
        observation: &obs,
        theta: &theta,
        theta_prior: &flat,
        estimate: &[],
        x0_prior: &x0,
        z0_prior: &z0,
        data: &data,
        t0: 0.0,
        seed: 0,
        max_memory: Default::default(),
    };
    let p0 = DMatrix::from_diagonal(&DVector::from_vec(vec![0.25, 0.25]));
    let model =
        LinearGaussianModel::from_sde(&LinearOscillator, &theta, &obs, 0.0, DVector::zeros(2), p0).unwrap();
    let reference = kalman_rts(&model, &data, &[]).unwrap();
    let options = ParticleOptions::default().with_particles(1000).with_backward_paths(500).with_dt(0.005);
    let r = 8;
    let runs: Vec<Vec<Vec<f64>>> = (0..r)
        .map(|rep| {
            let mut rng = StdRng::seed_from_u64(50 + rep);
            let est = estimate(&problem, &options, &mut rng).unwrap();
            assert_eq!(est.details["smoother"], "ancestral-paths");
            est.path.values
        })
        .collect();
    for k in 0..data.len() {
        for i in 0..2 {
            let mean = runs.iter().map(|v| v[k][i]).sum::<f64>() / r as f64;
            let var = runs.iter().map(|v| (v[k][i] - mean).powi(2)).sum::<f64>() / (r - 1) as f64;
            let se = (var / r as f64).sqrt();
            let rts = reference.smoothed_mean[k][i];
            assert!(
                (mean - rts).abs() < 4.0 * se,
                "t = {}, state {i}: {mean} vs RTS {rts}, SE {se}",
                data.times[k]
            );
        }
    }
}
