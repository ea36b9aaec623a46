//! Acceptance tests of `onsager-closures` (issue: trial-density families).
//!
//! Every expected value states its source: a closed form, an identity of the exponential-family
//! algebra of `003_d2fc48a470e528fc.txt (II.36)`–(II.43), or central finite differences.

use approx::assert_relative_eq;
use num_dual::{Dual64, DualNum};
use onsager_closures::{
    frame_grid, panel_grid, Error, Exponential, Gaussian, GaussianRule, LegendreOptions, Reference,
    TrialFamily,
};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use std::f64::consts::{E, PI};

// ---------------------------------------------------------------------------------------------
// helpers

/// Central difference of a vector function along coordinate `c` of `x` with step `h`.
fn central_diff(f: &dyn Fn(&[f64]) -> Vec<f64>, x: &[f64], c: usize, h: f64) -> Vec<f64> {
    let mut xp = x.to_vec();
    let mut xm = x.to_vec();
    xp[c] += h;
    xm[c] -= h;
    f(&xp).iter().zip(f(&xm)).map(|(a, b)| (a - b) / (2.0 * h)).collect()
}

/// Inverse and determinant of a 3×3 matrix by cofactors (independent of the crate's Cholesky).
fn inverse3(a: &[f64; 9]) -> ([f64; 9], f64) {
    let c = |i: usize, j: usize| a[i * 3 + j];
    let cof = |i: usize, j: usize| {
        let r: Vec<usize> = (0..3).filter(|&k| k != i).collect();
        let s: Vec<usize> = (0..3).filter(|&k| k != j).collect();
        let m = c(r[0], s[0]) * c(r[1], s[1]) - c(r[0], s[1]) * c(r[1], s[0]);
        if (i + j).is_multiple_of(2) {
            m
        } else {
            -m
        }
    };
    let det = c(0, 0) * cof(0, 0) + c(0, 1) * cof(0, 1) + c(0, 2) * cof(0, 2);
    let mut inv = [0.0; 9];
    for i in 0..3 {
        for j in 0..3 {
            inv[i * 3 + j] = cof(j, i) / det;
        }
    }
    (inv, det)
}

// ---------------------------------------------------------------------------------------------
// Gaussian: closed forms in 1-D and 3-D

#[test]
fn gaussian_1d_matches_closed_forms() {
    let g = Gaussian::try_new(1).unwrap();
    let (m, s2) = (0.7, 1.5);
    let lambda = g.natural_from_mean_cov(&[m], &[s2]).unwrap();
    // Natural parameters of N(m, s²): a = m/s², b = -1/(2s²).
    assert_relative_eq!(lambda[0], m / s2, max_relative = 1e-15);
    assert_relative_eq!(lambda[1], -0.5 / s2, max_relative = 1e-15);

    // F = m²/(2s²) + ½ log(2π s²) (Gaussian integral, II.38).
    let f = g.log_partition(&lambda).unwrap();
    assert_relative_eq!(f, m * m / (2.0 * s2) + 0.5 * (2.0 * PI * s2).ln(), max_relative = 1e-14);

    let c = g.cumulants(&lambda).unwrap();
    // μ = (m, s² + m²).
    assert_relative_eq!(c.mean[0], m, max_relative = 1e-14);
    assert_relative_eq!(c.mean[1], s2 + m * m, max_relative = 1e-14);
    // C: Var x = s², Cov(x, x²) = 2ms², Var x² = 4m²s² + 2s⁴ (moments of N(m, s²)).
    let expected_c = [s2, 2.0 * m * s2, 2.0 * m * s2, 4.0 * m * m * s2 + 2.0 * s2 * s2];
    for (a, b) in c.covariance.iter().zip(expected_c) {
        assert_relative_eq!(*a, b, max_relative = 1e-14);
    }
    // Third cumulant: κ(x,x,x) = 0 (Gaussian), κ(x,x,x²) = 2s⁴, κ(x,x²,x²) = 8ms⁴, and
    // κ3(x²) = 8s⁶ + 24m²s⁴ (non-central χ²₁ scaled by s²: 8(k + 3δ)s⁶, δ = m²/s²).
    let k3 = g.third_cumulant(&lambda).unwrap();
    let idx = |a: usize, b: usize, c: usize| (a * 2 + b) * 2 + c;
    assert_eq!(k3[idx(0, 0, 0)], 0.0);
    assert_relative_eq!(k3[idx(0, 0, 1)], 2.0 * s2 * s2, max_relative = 1e-14);
    assert_relative_eq!(k3[idx(1, 0, 0)], 2.0 * s2 * s2, max_relative = 1e-14);
    assert_relative_eq!(k3[idx(0, 1, 1)], 8.0 * m * s2 * s2, max_relative = 1e-14);
    assert_relative_eq!(k3[idx(1, 1, 1)], 8.0 * s2.powi(3) + 24.0 * m * m * s2 * s2, max_relative = 1e-14);
    // H = -½ log(2πe s²) (negative differential entropy, II.39 with Lebesgue reference).
    let h = g.relative_entropy(&c.mean).unwrap();
    assert_relative_eq!(h, -0.5 * (2.0 * PI * E * s2).ln(), max_relative = 1e-14);
    // Identity H = μᵀλ − F at λ(μ) (II.39).
    let sol = g.legendre(&c.mean, &LegendreOptions::default()).unwrap();
    assert_relative_eq!(
        sol.relative_entropy,
        c.mean[0] * lambda[0] + c.mean[1] * lambda[1] - f,
        max_relative = 1e-13
    );
    for (a, b) in sol.lambda.iter().zip(&lambda) {
        assert_relative_eq!(*a, *b, max_relative = 1e-13);
    }
}

#[test]
fn gaussian_3d_matches_closed_forms() {
    let g = Gaussian::try_new(3).unwrap();
    let m = [0.5, -1.0, 2.0];
    let sigma = [2.0, 0.5, 0.0, 0.5, 1.0, 0.3, 0.0, 0.3, 1.5];
    let (prec, det) = inverse3(&sigma);
    // det Σ = 2(1.5 − 0.09) − 0.5(0.75) = 2.445 (cofactor expansion by hand).
    assert_relative_eq!(det, 2.445, max_relative = 1e-15);
    let lambda = g.natural_from_mean_cov(&m, &sigma).unwrap();
    assert_eq!(lambda.len(), 9);
    // a = Σ⁻¹m; b_ii = −P_ii/2, b_ij = −P_ij.
    for i in 0..3 {
        let a: f64 = (0..3).map(|j| prec[i * 3 + j] * m[j]).sum();
        assert_relative_eq!(lambda[i], a, epsilon = 1e-14, max_relative = 1e-13);
        for j in i..3 {
            let expected = if i == j { -0.5 * prec[i * 4] } else { -prec[i * 3 + j] };
            assert_relative_eq!(
                lambda[g.quadratic_index(i, j).unwrap()],
                expected,
                epsilon = 1e-14,
                max_relative = 1e-13
            );
        }
    }
    // F = ½ mᵀΣ⁻¹m + ½ log((2π)³ det Σ).
    let mpm: f64 = (0..3).map(|i| (0..3).map(|j| m[i] * prec[i * 3 + j] * m[j]).sum::<f64>()).sum();
    let f_expected = 0.5 * mpm + 0.5 * ((2.0 * PI).powi(3) * det).ln();
    assert_relative_eq!(g.log_partition(&lambda).unwrap(), f_expected, max_relative = 1e-13);

    let c = g.cumulants(&lambda).unwrap();
    let r = 9;
    // Moment index → (Some(i), None) for x_i, (Some(i), Some(j)) for x_i x_j.
    let mut kinds = vec![];
    for i in 0..3 {
        kinds.push((i, None));
    }
    for i in 0..3 {
        for j in i..3 {
            kinds.push((i, Some(j)));
        }
    }
    let s = |i: usize, j: usize| sigma[i * 3 + j];
    // μ = (m_i, Σ_ij + m_i m_j).
    for (a, &(i, j)) in kinds.iter().enumerate() {
        let expected = match j {
            None => m[i],
            Some(j) => s(i, j) + m[i] * m[j],
        };
        assert_relative_eq!(c.mean[a], expected, epsilon = 1e-14, max_relative = 1e-13);
    }
    // C by Isserlis: Cov(x_i, x_k) = Σ_ik; Cov(x_i, x_k x_l) = m_k Σ_il + m_l Σ_ik;
    // Cov(x_i x_j, x_k x_l) = Σ_ik Σ_jl + Σ_il Σ_jk + m_i m_k Σ_jl + m_i m_l Σ_jk + m_j m_k Σ_il
    // + m_j m_l Σ_ik.
    let cov_closed = |p: (usize, Option<usize>), q: (usize, Option<usize>)| -> f64 {
        match (p, q) {
            ((i, None), (k, None)) => s(i, k),
            ((i, None), (k, Some(l))) | ((k, Some(l)), (i, None)) => m[k] * s(i, l) + m[l] * s(i, k),
            ((i, Some(j)), (k, Some(l))) => {
                s(i, k) * s(j, l)
                    + s(i, l) * s(j, k)
                    + m[i] * m[k] * s(j, l)
                    + m[i] * m[l] * s(j, k)
                    + m[j] * m[k] * s(i, l)
                    + m[j] * m[l] * s(i, k)
            }
        }
    };
    for a in 0..r {
        for b in 0..r {
            assert_relative_eq!(
                c.covariance[a * r + b],
                cov_closed(kinds[a], kinds[b]),
                epsilon = 1e-13,
                max_relative = 1e-13
            );
        }
    }
    // Third cumulant: the block of x is zero (Gaussian); κ(x_i, x_k, x_p x_q) = Σ_ip Σ_kq +
    // Σ_iq Σ_kp (Isserlis); the whole tensor equals ∂C/∂λ (II.43), checked by central
    // differences with h = 1e-6 (truncation O(h²) ~ 1e-12, round-off ~ 1e-10 · |C|).
    let k3 = g.third_cumulant(&lambda).unwrap();
    for a in 0..3 {
        for b in 0..3 {
            for cc in 0..3 {
                assert_eq!(k3[(a * r + b) * r + cc], 0.0);
            }
            for (p, &(i, j)) in kinds.iter().enumerate().skip(3) {
                let j = j.unwrap();
                assert_relative_eq!(
                    k3[(a * r + b) * r + p],
                    s(a, i) * s(b, j) + s(a, j) * s(b, i),
                    epsilon = 1e-13,
                    max_relative = 1e-13
                );
            }
        }
    }
    let cov_of = |l: &[f64]| g.covariance(l).unwrap();
    for cc in 0..r {
        let d = central_diff(&cov_of, &lambda, cc, 1e-6);
        for ab in 0..r * r {
            assert_relative_eq!(k3[ab * r + cc], d[ab], epsilon = 1e-6, max_relative = 1e-6);
        }
    }
    // H = −½ log((2πe)³ det Σ).
    assert_relative_eq!(
        g.relative_entropy(&c.mean).unwrap(),
        -0.5 * ((2.0 * PI * E).powi(3) * det).ln(),
        max_relative = 1e-13
    );
    // Closed-form round trip (m, Σ) → λ → (m, Σ).
    let (m2, s2) = g.mean_cov_from_natural(&lambda).unwrap();
    for (a, b) in m2.iter().zip(&m).chain(s2.iter().zip(&sigma)) {
        assert_relative_eq!(*a, *b, epsilon = 1e-14, max_relative = 1e-13);
    }
    // The variant that also returns the precision: the same (m, Σ) and PΣ = I.
    let (m3, s3, p3) = g.mean_cov_precision_from_natural(&lambda).unwrap();
    assert_eq!((m3, s3.clone()), (m2, s2));
    let n = m.len();
    for i in 0..n {
        for j in 0..n {
            let ps: f64 = (0..n).map(|k| p3[i * n + k] * s3[k * n + j]).sum();
            assert_relative_eq!(ps, if i == j { 1.0 } else { 0.0 }, epsilon = 1e-12);
        }
    }
}

#[test]
fn gaussian_quadrature_expectations_match_moments() {
    // Identity: ⟨M⟩ through the nodes equals μ = ∇F, for every rule exact to degree ≥ 2.
    let m = [0.5, -1.0, 2.0, 0.1];
    let mut sigma = vec![0.0; 16];
    for i in 0..4 {
        for j in 0..4 {
            sigma[i * 4 + j] = if i == j { 1.0 + i as f64 * 0.2 } else { 0.1 };
        }
    }
    for rule in [
        GaussianRule::Auto,
        GaussianRule::Cubature3,
        GaussianRule::Cubature5,
        GaussianRule::GaussHermite { points_per_dim: 2 },
    ] {
        let g = Gaussian::try_new(4).unwrap().with_rule(rule).unwrap();
        let lambda = g.natural_from_mean_cov(&m, &sigma).unwrap();
        let r = g.n_moments();
        let e = g
            .expectation(&lambda, r, &mut |x, out| {
                g.moment_functions(x, out).unwrap();
            })
            .unwrap();
        let mu = g.mean(&lambda).unwrap();
        for (a, b) in e.iter().zip(&mu) {
            assert_relative_eq!(*a, *b, epsilon = 1e-13, max_relative = 1e-13);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Exponential with M = (x, x²) reproduces the Gaussian

#[test]
fn exponential_quadratic_reproduces_gaussian() {
    // Flat (Lebesgue) reference on [-20, 20]: the neglected tails beyond 9 standard deviations
    // are < 1e-18 relative, and 80 panels × 8 points resolve widths ≥ 0.5 to < 1e-13.
    let grid = panel_grid(&[(-20.0, 20.0)], 80, 8).unwrap();
    let e = Exponential::polynomial(grid, Reference::Lebesgue, 2).unwrap();
    let g = Gaussian::try_new(1).unwrap();
    for (m, s2) in [(0.0, 1.0), (1.5, 0.5), (-2.0, 4.0), (3.0, 0.3)] {
        let lambda = g.natural_from_mean_cov(&[m], &[s2]).unwrap();
        let ce = e.cumulants(&lambda).unwrap();
        let cg = g.cumulants(&lambda).unwrap();
        assert_relative_eq!(ce.log_partition, cg.log_partition, epsilon = 1e-8, max_relative = 1e-8);
        for (a, b) in ce.mean.iter().zip(&cg.mean).chain(ce.covariance.iter().zip(&cg.covariance)) {
            assert_relative_eq!(*a, *b, epsilon = 1e-8, max_relative = 1e-8);
        }
        let ke = e.third_cumulant(&lambda).unwrap();
        let kg = g.third_cumulant(&lambda).unwrap();
        for (a, b) in ke.iter().zip(&kg) {
            assert_relative_eq!(*a, *b, epsilon = 1e-8, max_relative = 1e-8);
        }
        // Legendre inverse by damped Newton vs the Gaussian closed form, and H (II.39).
        let se = e.legendre(&cg.mean, &LegendreOptions::default()).unwrap();
        let sg = g.legendre(&cg.mean, &LegendreOptions::default()).unwrap();
        for (a, b) in se.lambda.iter().zip(&sg.lambda) {
            assert_relative_eq!(*a, *b, epsilon = 1e-8, max_relative = 1e-8);
        }
        assert_relative_eq!(se.relative_entropy, sg.relative_entropy, epsilon = 1e-8, max_relative = 1e-8);
    }
}

// ---------------------------------------------------------------------------------------------
// Quartic family

fn random_quartic_lambda(rng: &mut StdRng) -> Vec<f64> {
    // Negative leading coefficient; ranges keep the mode well inside [-6, 6].
    vec![
        rng.random_range(-1.0..1.0),
        rng.random_range(-2.0..2.0),
        rng.random_range(-0.5..0.5),
        rng.random_range(-1.5..-0.3),
    ]
}

#[test]
fn quartic_derivatives_match_finite_differences() {
    let q = Exponential::quartic(-6.0, 6.0).unwrap();
    let mut rng = StdRng::seed_from_u64(11);
    let h = 1e-5;
    for _ in 0..5 {
        let lambda = random_quartic_lambda(&mut rng);
        let c = q.cumulants(&lambda).unwrap();
        let f_of = |l: &[f64]| vec![q.log_partition(l).unwrap()];
        let mu_of = |l: &[f64]| q.mean(l).unwrap();
        let c_of = |l: &[f64]| q.covariance(l).unwrap();
        let k3 = q.third_cumulant(&lambda).unwrap();
        // Central differences, h = 1e-5: truncation h²·|∂³F| ~ 1e-10·|M|³, round-off
        // 1e-16·|F|/h ~ 1e-11, so 1e-6 relative is a safe margin.
        for a in 0..4 {
            // μ = ∇F (II.38).
            let d = central_diff(&f_of, &lambda, a, h);
            assert_relative_eq!(c.mean[a], d[0], epsilon = 1e-7, max_relative = 1e-6);
            // C = ∂μ/∂λ.
            let d = central_diff(&mu_of, &lambda, a, h);
            for (b, db) in d.iter().enumerate() {
                assert_relative_eq!(c.covariance[b * 4 + a], *db, epsilon = 1e-6, max_relative = 1e-6);
            }
            // Third cumulant = ∂C/∂λ (II.43).
            let d = central_diff(&c_of, &lambda, a, h);
            for (bc, dbc) in d.iter().enumerate() {
                assert_relative_eq!(k3[bc * 4 + a], *dbc, epsilon = 1e-5, max_relative = 1e-6);
            }
        }
    }
}

#[test]
fn quartic_legendre_round_trips_100_random_lambdas() {
    let q = Exponential::quartic(-6.0, 6.0).unwrap();
    let mut rng = StdRng::seed_from_u64(2024);
    let mut worst = 0.0f64;
    let mut max_iter = 0;
    for _ in 0..100 {
        let lambda = random_quartic_lambda(&mut rng);
        let mu = q.mean(&lambda).unwrap();
        let sol = q.legendre(&mu, &LegendreOptions::default()).unwrap();
        max_iter = max_iter.max(sol.iterations);
        for (a, b) in sol.lambda.iter().zip(&lambda) {
            worst = worst.max((a - b).abs() / b.abs().max(1.0));
            // Identity λ(μ(λ)) = λ: Newton converges to round-off, cond(C) ≲ 1e4 here.
            assert_relative_eq!(*a, *b, epsilon = 1e-10, max_relative = 1e-10);
        }
        // Identity H(μ) = μᵀλ − F(λ) (II.39).
        let f = q.log_partition(&lambda).unwrap();
        let h: f64 = mu.iter().zip(&lambda).map(|(m, l)| m * l).sum::<f64>() - f;
        assert_relative_eq!(sol.relative_entropy, h, epsilon = 1e-10, max_relative = 1e-10);
    }
    assert!(worst < 1e-10 && max_iter < 100, "worst {worst:e}, iterations {max_iter}");
}

#[test]
fn relative_entropy_gradient_is_lambda_and_ii43_holds() {
    // λ = ∂H/∂μ (after II.39) and ∂C_aj/∂μ_i = C_ajk Γ_ki (II.43), by central differences in μ.
    let q = Exponential::quartic(-6.0, 6.0).unwrap();
    let lambda = [0.3, 1.0, -0.2, -0.8];
    let c = q.cumulants(&lambda).unwrap();
    let mu = c.mean.clone();
    let opts = LegendreOptions::default();
    let h_of = |m: &[f64]| vec![q.relative_entropy(m).unwrap()];
    let cov_of_mu = |m: &[f64]| {
        let l = q.legendre(m, &opts).unwrap().lambda;
        q.covariance(&l).unwrap()
    };
    let k3 = q.third_cumulant(&lambda).unwrap();
    // Γ = C⁻¹ through the crate's Cholesky.
    let l = onsager_closures::cholesky(&c.covariance, 4).unwrap();
    let gamma = onsager_closures::cholesky_inverse(&l, 4).unwrap();
    for i in 0..4 {
        let step = 1e-5 * mu[i].abs().max(1.0);
        let d = central_diff(&h_of, &mu, i, step);
        assert_relative_eq!(d[0], lambda[i], epsilon = 1e-6, max_relative = 1e-6);
        let d = central_diff(&cov_of_mu, &mu, i, step);
        for aj in 0..16 {
            let expected: f64 = (0..4).map(|k| k3[aj * 4 + k] * gamma[k * 4 + i]).sum();
            assert_relative_eq!(d[aj], expected, epsilon = 1e-6, max_relative = 1e-5);
        }
    }
}

#[test]
fn unrealizable_moments_are_errors() {
    let q = Exponential::quartic(-6.0, 6.0).unwrap();
    let opts = LegendreOptions::default();
    fn unrealizable<T>(r: Result<T, Error>) -> bool {
        matches!(r, Err(Error::Unrealizable { .. }))
    }
    // Variance ≤ 0: μ₂ − μ₁² = 0.5 − 1 < 0, and exactly 0.
    assert!(unrealizable(q.legendre(&[1.0, 0.5, 1.5, 3.0], &opts)));
    assert!(unrealizable(q.legendre(&[1.0, 1.0, 1.0, 1.0], &opts)));
    // A mean outside the grid [-6, 6].
    assert!(unrealizable(q.legendre(&[7.0, 50.0, 350.0, 2500.0], &opts)));
    // Outside the moment space yet componentwise in range with a positive definite Hankel
    // matrix: on [-L, L], E[x⁴] ≤ L² E[x²] = 36·4 = 144 < 200. Caught by Newton divergence.
    let mu = [0.0, 4.0, 0.0, 200.0];
    assert!(q.check_realizable(&mu).is_ok());
    assert!(unrealizable(q.legendre(&mu, &opts)));
    // Gaussian: a non-positive-definite covariance.
    let g = Gaussian::try_new(2).unwrap();
    // μ = (0, 0, Σ00 = 1, Σ01 = 2, Σ11 = 1): det Σ = −3.
    assert!(unrealizable(g.legendre(&[0.0, 0.0, 1.0, 2.0, 1.0], &opts)));
    assert!(unrealizable(g.relative_entropy(&[0.0, 0.0, -1.0, 0.0, 1.0])));
    // Overflowing multipliers are errors, not infinities or NaN.
    assert!(matches!(g.log_partition(&[1e300, 0.0, -1e-300, 0.0, -1.0]), Err(Error::NotNormalizable { .. })));
    assert!(matches!(q.log_partition(&[0.0, 0.0, 0.0, 1e306]), Err(Error::NotNormalizable { .. })));
    // λ₂x² = +inf and λ₄x⁴ = −inf at the outer nodes: λᵀM is NaN there.
    assert!(matches!(q.mean(&[0.0, 1e307, 0.0, -1e307]), Err(Error::NotNormalizable { .. })));
    // And the multipliers of a non-normalizable Gaussian.
    assert!(matches!(g.log_partition(&[0.0, 0.0, 1.0, 0.0, -1.0]), Err(Error::NotNormalizable { .. })));
}

#[test]
fn bad_inputs_are_errors_not_panics() {
    let q = Exponential::quartic(-6.0, 6.0).unwrap();
    assert!(matches!(q.log_partition(&[0.0; 3]), Err(Error::DimensionMismatch { .. })));
    assert!(matches!(q.mean(&[0.0, f64::NAN, 0.0, 0.0]), Err(Error::NonFinite { .. })));
    assert!(matches!(
        q.legendre(&[0.0, 1.0, 0.0, f64::INFINITY], &LegendreOptions::default()),
        Err(Error::NonFinite { .. })
    ));
    let bad = LegendreOptions::default().with_max_iterations(0);
    assert!(matches!(q.legendre(&[0.0, 1.0, 0.0, 2.0], &bad), Err(Error::InvalidOption { .. })));
    assert!(matches!(Exponential::quartic(1.0, -1.0), Err(Error::InvalidOption { .. })));
    assert!(matches!(Gaussian::try_new(0), Err(Error::InvalidOption { .. })));
    let g = Gaussian::try_new(2).unwrap();
    assert!(matches!(g.nodes(&[0.0], &[1.0]), Err(Error::DimensionMismatch { .. })));
    assert!(matches!(g.nodes(&[0.0, 0.0], &[1.0, 2.0, 2.0, 1.0]), Err(Error::NotPositiveDefinite { .. })));
    // An iteration limit that is too small is a NoConvergence error carrying the residual.
    let tight = LegendreOptions::default().with_max_iterations(1);
    let mu = q.mean(&[0.5, 1.0, -0.3, -1.0]).unwrap();
    assert!(matches!(q.legendre(&mu, &tight), Err(Error::NoConvergence { iterations: 1, .. })));
}

// ---------------------------------------------------------------------------------------------
// Dual numbers through the Gaussian nodes

/// E[f(x)] for x ~ N(m, Σ) through the family's nodes, generic over the scalar.
fn expect_f<D: DualNum<Primitive = f64> + Copy>(g: &Gaussian, p: &[D]) -> D {
    let n = g.standard_rule().dim();
    let mean = &p[..n];
    let mut cov = vec![p[n]; n * n];
    // Parameters: mean (n), then the lower triangle of Σ row by row.
    let mut k = n;
    for i in 0..n {
        for j in 0..=i {
            cov[i * n + j] = p[k];
            cov[j * n + i] = p[k];
            k += 1;
        }
    }
    g.nodes(mean, &cov)
        .unwrap()
        .into_iter()
        .map(|(x, w)| {
            let f = x[0].sin() * x[1] + x[0] * x[0] * (x[1] * 0.3).exp() + x[n - 1].cos();
            f * w
        })
        .sum()
}

#[test]
fn dual_derivatives_through_gaussian_nodes_match_finite_differences() {
    for (dim, rule) in [(2, GaussianRule::Auto), (4, GaussianRule::Cubature5)] {
        let g = Gaussian::try_new(dim).unwrap().with_rule(rule).unwrap();
        let mut p: Vec<f64> = (0..dim).map(|i| 0.3 - 0.2 * i as f64).collect();
        for i in 0..dim {
            for j in 0..=i {
                p.push(if i == j { 0.8 + 0.1 * i as f64 } else { 0.15 });
            }
        }
        let f64_fn = |q: &[f64]| vec![expect_f(&g, q)];
        for c in 0..p.len() {
            let dual: Vec<Dual64> = p
                .iter()
                .enumerate()
                .map(|(k, &v)| if k == c { Dual64::from(v).derivative() } else { Dual64::from(v) })
                .collect();
            let ad = expect_f(&g, &dual).eps;
            // Central differences, h = 1e-5: truncation ~ h² ~ 1e-10.
            let fd = central_diff(&f64_fn, &p, c, 1e-5)[0];
            assert_relative_eq!(ad, fd, epsilon = 1e-8, max_relative = 1e-7);
        }
    }
    // Closed form: E[x₀²] = m₀² + Σ₀₀, so ∂/∂m₀ = 2m₀ and ∂/∂Σ₀₀ = 1, exactly through any rule
    // of degree ≥ 2.
    let g = Gaussian::try_new(2).unwrap();
    let m0 = Dual64::from(0.4).derivative();
    let nodes = g.nodes(&[m0, Dual64::from(0.1)], &[1.2, 0.3, 0.3, 0.7].map(Dual64::from)).unwrap();
    let e: Dual64 = nodes.iter().map(|(x, w)| x[0] * x[0] * *w).sum();
    assert_relative_eq!(e.eps, 0.8, max_relative = 1e-13);
    let s00 = Dual64::from(1.2).derivative();
    let cov = [s00, Dual64::from(0.3), Dual64::from(0.3), Dual64::from(0.7)];
    let nodes = g.nodes(&[Dual64::from(0.4), Dual64::from(0.1)], &cov).unwrap();
    let e: Dual64 = nodes.iter().map(|(x, w)| x[0] * x[0] * *w).sum();
    assert_relative_eq!(e.eps, 1.0, max_relative = 1e-13);
}

// ---------------------------------------------------------------------------------------------
// Large multipliers

#[test]
fn large_lambda_gives_finite_f_and_moments() {
    let q = Exponential::quartic(-6.0, 6.0).unwrap();
    for lambda in [
        [1e3, -1e3, 1e3, -1e3],
        [-1e3, 1e3, -1e3, 1e3], // positive leading coefficient: e^{1.3e6} at x = ±6
        [0.0, 0.0, 1e3, -1e3],
    ] {
        let c = q.cumulants(&lambda).unwrap();
        // Log-sum-exp bounds (identity): max_k s_k ≤ F ≤ max_k s_k + log(#nodes), with
        // s_k = log w_k + λᵀM(x_k).
        let s: Vec<f64> = q
            .grid()
            .iter()
            .map(|(x, w)| {
                let x = x[0];
                w.ln() + lambda[0] * x + lambda[1] * x * x + lambda[2] * x.powi(3) + lambda[3] * x.powi(4)
            })
            .collect();
        let smax = s.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        assert!(c.log_partition >= smax && c.log_partition <= smax + (s.len() as f64).ln());
        // The mean of x lies in the grid's range and μ₂ ≥ μ₁² (Jensen); C is finite.
        assert!(c.mean[0].abs() <= 6.0 && c.mean[1] >= c.mean[0] * c.mean[0] - 1e-12);
        assert!(c.covariance.iter().all(|v| v.is_finite()));
        assert!(q.third_cumulant(&lambda).unwrap().iter().all(|v| v.is_finite()));
    }
    // Gaussian with entries of magnitude 1e3: λ = (1e3, −1e3) is N(0.5, 5e-4):
    // F = a²/(4|b|) + ½ log(π/|b|) = 250 + ½ log(π·1e-3) (closed form).
    let g = Gaussian::try_new(1).unwrap();
    let c = g.cumulants(&[1e3, -1e3]).unwrap();
    assert_relative_eq!(c.log_partition, 250.0 + 0.5 * (PI * 1e-3).ln(), max_relative = 1e-14);
    assert_relative_eq!(c.mean[0], 0.5, max_relative = 1e-14);
    assert_relative_eq!(c.mean[1], 0.25 + 5e-4, max_relative = 1e-14);
}

#[test]
fn exponential_2d_polynomial_family() {
    // 2-D quadratic family with flat reference reproduces a 2-D Gaussian (closed forms of the
    // Gaussian family, checked above); the grid covers ±10 standard deviations.
    let grid = panel_grid(&[(-8.0, 8.0), (-8.0, 8.0)], 24, 8).unwrap();
    let e = Exponential::polynomial(grid, Reference::Lebesgue, 2).unwrap();
    assert_eq!(e.exponents().unwrap(), &[vec![1, 0], vec![0, 1], vec![2, 0], vec![1, 1], vec![0, 2]]);
    let g = Gaussian::try_new(2).unwrap();
    // The Gaussian orders (x, y, x², xy, y²): the same as the polynomial family.
    let lambda = g.natural_from_mean_cov(&[0.3, -0.5], &[0.6, 0.2, 0.2, 0.4]).unwrap();
    let ce = e.cumulants(&lambda).unwrap();
    let cg = g.cumulants(&lambda).unwrap();
    assert_relative_eq!(ce.log_partition, cg.log_partition, epsilon = 1e-10, max_relative = 1e-10);
    for (a, b) in ce.mean.iter().zip(&cg.mean).chain(ce.covariance.iter().zip(&cg.covariance)) {
        assert_relative_eq!(*a, *b, epsilon = 1e-10, max_relative = 1e-10);
    }
    let sol = e.legendre(&cg.mean, &LegendreOptions::default()).unwrap();
    for (a, b) in sol.lambda.iter().zip(&lambda) {
        assert_relative_eq!(*a, *b, epsilon = 1e-8, max_relative = 1e-8);
    }
    // Moment matrix of (1, x, y) not PD: Var x = μ_x² − μ_x² = 0.
    assert!(matches!(
        e.legendre(&[1.0, 0.0, 1.0, 0.0, 1.0], &LegendreOptions::default()),
        Err(Error::Unrealizable { .. })
    ));
}

// ---------------------------------------------------------------------------------------------
// Moment-function derivatives (for the closure's generator average ⟨f·∇M + D:∇∇M⟩)

/// M(x, y) = (sin x · y, x² + e^{y/2}): written once, differentiated by hyper-dual numbers.
struct Custom;

impl onsager_closures::MomentFunctions for Custom {
    fn dim(&self) -> usize {
        2
    }
    fn n_moments(&self) -> usize {
        2
    }
    fn eval<D: onsager_closures::Scalar>(&self, x: &[D], out: &mut [D]) {
        out[0] = x[0].sin() * x[1];
        out[1] = x[0] * x[0] + (x[1] * 0.5).exp();
    }
}

#[test]
fn moment_derivatives_match_closed_forms() {
    // Quartic: ∂M/∂x = (1, 2x, 3x², 4x³), ∂²M/∂x² = (0, 2, 6x, 12x²).
    let q = Exponential::quartic(-6.0, 6.0).unwrap();
    let x = 1.3;
    let (mut jac, mut hess) = (vec![0.0; 4], vec![0.0; 4]);
    q.moment_derivatives(&[x], &mut jac, &mut hess).unwrap();
    let jac_expected = [1.0, 2.0 * x, 3.0 * x * x, 4.0 * x.powi(3)];
    let hess_expected = [0.0, 2.0, 6.0 * x, 12.0 * x * x];
    for (a, b) in jac.iter().zip(jac_expected).chain(hess.iter().zip(hess_expected)) {
        assert_relative_eq!(*a, b, epsilon = 1e-14, max_relative = 1e-14);
    }

    // Gaussian in 2-D: M = (x, y, x², xy, y²).
    let g = Gaussian::try_new(2).unwrap();
    let p = [0.7, -0.4];
    let (mut jac, mut hess) = (vec![0.0; 10], vec![0.0; 20]);
    g.moment_derivatives(&p, &mut jac, &mut hess).unwrap();
    let (x, y) = (p[0], p[1]);
    assert_eq!(jac, vec![1.0, 0.0, 0.0, 1.0, 2.0 * x, 0.0, y, x, 0.0, 2.0 * y]);
    let mut h = vec![0.0; 20];
    h[2 * 4] = 2.0; // ∂²x²/∂x²
    h[3 * 4 + 1] = 1.0; // ∂²xy/∂x∂y
    h[3 * 4 + 2] = 1.0;
    h[4 * 4 + 3] = 2.0; // ∂²y²/∂y²
    assert_eq!(hess, h);

    // User moment functions generic over the scalar, 2-D grid.
    let grid = panel_grid(&[(-3.0, 3.0), (-3.0, 3.0)], 4, 4).unwrap();
    let e = Exponential::from_moments(grid.clone(), Reference::Uniform, Custom).unwrap();
    let (mut jac, mut hess) = (vec![0.0; 4], vec![0.0; 8]);
    e.moment_derivatives(&p, &mut jac, &mut hess).unwrap();
    // Closed forms: ∇(sin x · y) = (y cos x, sin x), ∇(x² + e^{y/2}) = (2x, e^{y/2}/2); Hessians
    // [[−y sin x, cos x], [cos x, 0]] and [[2, 0], [0, e^{y/2}/4]].
    let jac_expected = [y * x.cos(), x.sin(), 2.0 * x, 0.5 * (0.5 * y).exp()];
    let hess_expected = [-y * x.sin(), x.cos(), x.cos(), 0.0, 2.0, 0.0, 0.0, 0.25 * (0.5 * y).exp()];
    for (a, b) in jac.iter().zip(jac_expected).chain(hess.iter().zip(hess_expected)) {
        assert_relative_eq!(*a, b, epsilon = 1e-14, max_relative = 1e-14);
    }
    // Uniform reference on the box [-3, 3]²: F(0) = log ∫ p_* = 0 (normalisation).
    assert_relative_eq!(e.log_partition(&[0.0, 0.0]).unwrap(), 0.0, epsilon = 1e-14);

    // A family from a plain f64 closure has no derivatives: an error, not a panic.
    let plain = Exponential::try_new(grid, Reference::Lebesgue, 1, |x, out| out[0] = x[0] * x[1]).unwrap();
    assert!(matches!(
        plain.moment_derivatives(&p, &mut [0.0; 2], &mut [0.0; 4]),
        Err(Error::Unsupported { .. })
    ));
    assert!(matches!(
        Exponential::from_moments(panel_grid(&[(-1.0, 1.0)], 2, 2).unwrap(), Reference::Lebesgue, Custom),
        Err(Error::DimensionMismatch { .. })
    ));
}

#[test]
fn exponential_expectations_through_nodes_match_moments() {
    // Identity: ⟨M⟩ computed through the exposed nodes and probabilities equals μ = ∇F, and the
    // probabilities sum to one.
    let q = Exponential::quartic(-6.0, 6.0).unwrap();
    let lambda = [0.4, 1.5, -0.2, -0.7];
    let rule = q.quadrature(&lambda).unwrap();
    assert_relative_eq!(rule.weights().iter().sum::<f64>(), 1.0, epsilon = 1e-14);
    let e = q.expectation(&lambda, 4, &mut |x, out| q.moment_functions(x, out).unwrap()).unwrap();
    for (a, b) in e.iter().zip(q.mean(&lambda).unwrap()) {
        assert_relative_eq!(*a, b, epsilon = 1e-13, max_relative = 1e-13);
    }
}

#[test]
fn reference_log_density_is_used() {
    // M = (x) with the standard normal reference: F(λ) = log E[e^{λx}] = λ²/2 (normal mgf),
    // μ = λ, C = 1, third cumulant 0. The grid [-14, 14] truncates tails below 1e-40.
    let grid = panel_grid(&[(-14.0, 14.0)], 56, 8).unwrap();
    let log_phi = std::sync::Arc::new(|x: &[f64]| -0.5 * x[0] * x[0] - 0.5 * (2.0 * PI).ln());
    let e = Exponential::polynomial(grid, Reference::LogDensity(log_phi), 1).unwrap();
    for l in [-3.0, 0.0, 0.5, 2.0] {
        let c = e.cumulants(&[l]).unwrap();
        assert_relative_eq!(c.log_partition, 0.5 * l * l, epsilon = 1e-12, max_relative = 1e-12);
        assert_relative_eq!(c.mean[0], l, epsilon = 1e-12, max_relative = 1e-12);
        assert_relative_eq!(c.covariance[0], 1.0, max_relative = 1e-12);
        assert_relative_eq!(e.third_cumulant(&[l]).unwrap()[0], 0.0, epsilon = 1e-11);
        // H(μ) = μ²/2: the Kullback–Leibler divergence of N(μ, 1) from N(0, 1) (closed form).
        assert_relative_eq!(
            e.relative_entropy(&[l]).unwrap(),
            0.5 * l * l,
            epsilon = 1e-12,
            max_relative = 1e-10
        );
    }
}

#[test]
fn trial_family_is_object_safe() {
    // The same generic Newton solver serves every family behind `dyn TrialFamily`; for the
    // Gaussian it must agree with the closed-form inverse (identity).
    let families: Vec<Box<dyn TrialFamily>> =
        vec![Box::new(Gaussian::try_new(1).unwrap()), Box::new(Exponential::quartic(-6.0, 6.0).unwrap())];
    for (f, lambda) in families.iter().zip([vec![0.6, -0.8], vec![0.2, 1.0, -0.1, -0.6]]) {
        let mu = f.mean(&lambda).unwrap();
        let newton = onsager_closures::legendre_newton(
            f.as_ref(),
            &mu,
            &LegendreOptions::default().with_initial(vec![0.0, -0.5, 0.0, -0.5][..lambda.len()].to_vec()),
        )
        .unwrap();
        for (a, b) in newton.lambda.iter().zip(&lambda) {
            assert_relative_eq!(*a, *b, epsilon = 1e-10, max_relative = 1e-10);
        }
    }
}

/// The frame grid m + Lξ integrates the moments of a correlated 2-D Gaussian N(m, LLᵀ) to
/// their closed forms (mean, covariance, fourth moment E[(x − m_x)⁴] = 3Σ_xx²) with the
/// Gaussian as a polynomial exponential family of degree 2 on it; and the moments of a
/// 3-D Gaussian (the frame grid in any dimension).
#[test]
fn frame_grid_moments_of_gaussians_match_closed_forms() {
    let (m, l) = ([0.7, -1.2], [0.5, 0.0, -0.3, 0.2]);
    let s = [l[0] * l[0], l[0] * l[2], l[0] * l[2], l[2] * l[2] + l[3] * l[3]];
    let grid = frame_grid(&m, &l, 7.0, 6, 8).unwrap();
    let density = |x: &[f64]| {
        let det = s[0] * s[3] - s[1] * s[2];
        let (dx, dy) = (x[0] - m[0], x[1] - m[1]);
        let q = (s[3] * dx * dx - 2.0 * s[1] * dx * dy + s[0] * dy * dy) / det;
        (-0.5 * q).exp() / (2.0 * PI * det.sqrt())
    };
    let mass = grid.integrate(density);
    assert!((mass - 1.0).abs() < 1e-10, "mass {mass}");
    let mean_x = grid.integrate(|x| x[0] * density(x));
    let cov_xy = grid.integrate(|x| (x[0] - m[0]) * (x[1] - m[1]) * density(x));
    let fourth = grid.integrate(|x| (x[0] - m[0]).powi(4) * density(x));
    assert!((mean_x - m[0]).abs() < 1e-10, "{mean_x}");
    assert!((cov_xy - s[1]).abs() < 1e-10, "{cov_xy} vs {}", s[1]);
    assert!((fourth - 3.0 * s[0] * s[0]).abs() < 1e-8, "{fourth}");
    // The same Gaussian as the exponential family of degree 2 (x, y, x², xy, y²) on the grid.
    let p = [s[3], -s[1], s[0]].map(|v| v / (s[0] * s[3] - s[1] * s[2]));
    let lambda = [p[0] * m[0] + p[1] * m[1], p[1] * m[0] + p[2] * m[1], -0.5 * p[0], -p[1], -0.5 * p[2]];
    let family = Exponential::polynomial(grid, Reference::Lebesgue, 2).unwrap();
    let mu = family.mean(&lambda).unwrap();
    let expected = [m[0], m[1], s[0] + m[0] * m[0], s[1] + m[0] * m[1], s[3] + m[1] * m[1]];
    for (a, b) in mu.iter().zip(expected) {
        assert!((a - b).abs() < 1e-10, "{a} vs {b}");
    }
    // 3-D: the unit Gaussian's second moments on a shifted, sheared frame.
    let l3 = [1.0, 0.0, 0.0, 0.2, 0.9, 0.0, -0.1, 0.3, 1.1];
    let grid3 = frame_grid(&[0.1, 0.2, -0.1], &l3, 8.0, 5, 8).unwrap();
    let phi = |x: &[f64]| (-0.5 * x.iter().map(|v| v * v).sum::<f64>()).exp() / (2.0 * PI).powf(1.5);
    assert!((grid3.integrate(phi) - 1.0).abs() < 1e-7);
    assert!((grid3.integrate(|x| x[2] * x[2] * phi(x)) - 1.0).abs() < 1e-7);
    assert!(frame_grid(&[0.0], &[-1.0], 6.0, 2, 8).is_err());
}
