//! The exact Kalman filter and Rauch–Tung–Striebel smoother for linear time-invariant SDEs:
//! the reference every estimator must reproduce on linear-Gaussian models.
//!
//! The model is
//!
//! $$ dS = (A S + b)\,dt + B\,dW, \qquad y_k = H S(t_k) + v_k, \quad v_k \sim N(0, R), \qquad S(t_0) \sim N(m_0, P_0), $$
//!
//! discretised *exactly* between consecutive times (no time-stepping error): with Δ the
//! spacing, $S(t+\Delta) = F S(t) + c + \xi$, $F = e^{A\Delta}$, $c = \int_0^\Delta e^{As} b\,ds$,
//! $\xi \sim N(0, Q)$, $Q = \int_0^\Delta e^{As} B B^\top e^{A^\top s}\,ds$, computed by Van Loan's
//! block-matrix exponential (C. F. Van Loan, "Computing integrals involving the matrix
//! exponential", IEEE TAC 23(3), 1978, Thm 1). The filter and smoother are the textbook ones
//! (Särkkä, *Bayesian Filtering and Smoothing*, 2013, Thms 4.2 and 8.2).

use nalgebra::{DMatrix, DVector};

use crate::data::{Dataset, EventTimes};
use crate::model::observation::StateMeasurement;
use crate::model::{check_len, Sde};
use crate::{Error, Result};

/// A linear time-invariant SDE dS = (A S + b) dt + B dW.
#[derive(Debug, Clone, PartialEq)]
pub struct LinearSde {
    /// Drift matrix A (n × n).
    pub a: DMatrix<f64>,
    /// Drift offset b (n).
    pub b: DVector<f64>,
    /// Noise matrix B (n × m); may have zero rows (clean states).
    pub noise: DMatrix<f64>,
}

impl LinearSde {
    /// The exact transition over a step Δ ≥ 0: (F, c, Q) with S(t+Δ) = F S(t) + c + N(0, Q)
    /// (Van Loan 1978, Thm 1, with the offset b carried as an extra constant state).
    pub fn transition(&self, delta: f64) -> (DMatrix<f64>, DVector<f64>, DMatrix<f64>) {
        let n = self.a.nrows();
        // Augmented drift [[A, b], [0, 0]] gives F and c at once.
        let mut aug = DMatrix::zeros(n + 1, n + 1);
        aug.view_mut((0, 0), (n, n)).copy_from(&self.a);
        aug.view_mut((0, n), (n, 1)).copy_from(&self.b);
        let e = (aug * delta).exp();
        let f = e.view((0, 0), (n, n)).into_owned();
        let c = e.view((0, n), (n, 1)).column(0).into_owned();
        // Van Loan: exp([[−A, BBᵀ], [0, Aᵀ]] Δ) = [[·, E12], [0, E22]], F = E22ᵀ, Q = F E12.
        let bbt = &self.noise * self.noise.transpose();
        let mut m = DMatrix::zeros(2 * n, 2 * n);
        m.view_mut((0, 0), (n, n)).copy_from(&(-&self.a));
        m.view_mut((0, n), (n, n)).copy_from(&bbt);
        m.view_mut((n, n), (n, n)).copy_from(&self.a.transpose());
        let e = (m * delta).exp();
        let q = &f * e.view((0, n), (n, n));
        let q = (&q + q.transpose()) * 0.5;
        (f, c, q)
    }
}

/// A linear-Gaussian state-space model: [`LinearSde`], a linear measurement y = H S + N(0, R),
/// and a Gaussian initial law at `t0`.
#[derive(Debug, Clone, PartialEq)]
pub struct LinearGaussianModel {
    /// The dynamics.
    pub sde: LinearSde,
    /// Measurement matrix H (outputs × n).
    pub h: DMatrix<f64>,
    /// Measurement covariance R (outputs × outputs).
    pub r: DMatrix<f64>,
    /// Initial time.
    pub t0: f64,
    /// Initial mean.
    pub m0: DVector<f64>,
    /// Initial covariance.
    pub p0: DMatrix<f64>,
}

impl LinearGaussianModel {
    /// The linear-Gaussian model of an [`Sde`] whose drifts are affine and time-invariant in
    /// the state s = [x; z] (checked at two points), measured through a [`StateMeasurement`]
    /// with Gaussian errors, with initial law N(m0, P0) at t0.
    pub fn from_sde<S: Sde + ?Sized>(
        sde: &S,
        theta: &[f64],
        observation: &StateMeasurement,
        t0: f64,
        m0: DVector<f64>,
        p0: DMatrix<f64>,
    ) -> Result<LinearGaussianModel> {
        let d = sde.dims();
        let n = d.states();
        check_len("theta", d.params, theta.len())?;
        check_len("initial mean", n, m0.len())?;
        check_len("initial covariance", n, p0.nrows())?;
        check_len("initial covariance", n, p0.ncols())?;
        let full = |t: f64, s: &[f64]| {
            let (x, z) = s.split_at(d.noisy);
            let f = sde.drift_jacobians(t, x, z, theta);
            let h = sde.clean_drift_jacobians(t, x, z, theta);
            let mut a = DMatrix::zeros(n, n);
            a.view_mut((0, 0), (d.noisy, d.noisy)).copy_from(&f.dx);
            a.view_mut((0, d.noisy), (d.noisy, d.clean)).copy_from(&f.dz);
            a.view_mut((d.noisy, 0), (d.clean, d.noisy)).copy_from(&h.dx);
            a.view_mut((d.noisy, d.noisy), (d.clean, d.clean)).copy_from(&h.dz);
            let mut v = f.value;
            v.extend(h.value);
            let mut dt = f.dt;
            dt.extend(h.dt);
            (a, DVector::from_vec(v), dt)
        };
        let zero = vec![0.0; n];
        let (a, b, dt0) = full(t0, &zero);
        let probe: Vec<f64> = (0..n).map(|i| 0.7 - 0.3 * i as f64).collect();
        let (a2, v2, dt2) = full(t0 + 1.3, &probe);
        let predicted = &a * DVector::from_vec(probe.clone()) + &b;
        let tol = 1e-10 * (1.0 + a.amax() + b.amax());
        if (&a2 - &a).amax() > tol
            || (v2 - predicted).amax() > tol
            || dt0.iter().chain(&dt2).any(|v| v.abs() > tol)
        {
            return Err(Error::InvalidOption {
                name: "model".into(),
                reason: "the exact Kalman reference needs drifts affine and time-invariant in the state"
                    .into(),
            });
        }
        let g = sde.diffusion_matrix(theta)?;
        let mut noise = DMatrix::zeros(n, d.noisy);
        noise.view_mut((0, 0), (d.noisy, d.noisy)).copy_from(&g);
        let sigma = observation.noise.gaussian_sigma(
            &sde.param_names(),
            "the Kalman reference",
            "it is exact for linear-Gaussian models only",
        )?;
        let sd = sigma.value(theta).ok_or_else(|| {
            Error::invalid("likelihood", "the measurement sd refers to a parameter out of range")
        })?;
        let k = observation.states.len();
        let mut h = DMatrix::zeros(k, n);
        for (row, &s) in observation.states.iter().enumerate() {
            if s >= n {
                return Err(Error::InvalidOption {
                    name: "observation".into(),
                    reason: format!("state index {s} is out of range ({n} states)"),
                });
            }
            h[(row, s)] = 1.0;
        }
        let r = DMatrix::identity(k, k) * (sd * sd);
        Ok(LinearGaussianModel { sde: LinearSde { a, b, noise }, h, r, t0, m0, p0 })
    }
}

/// Filtered and smoothed moments on a time grid.
#[derive(Debug, Clone, PartialEq)]
pub struct KalmanSmoothing {
    /// The grid: t0, the measurement times and the requested output times, sorted and merged.
    pub times: Vec<f64>,
    /// Filtered means E[S(t) | y_k, t_k ≤ t].
    pub filtered_mean: Vec<DVector<f64>>,
    /// Filtered covariances.
    pub filtered_cov: Vec<DMatrix<f64>>,
    /// Smoothed means E[S(t) | all y].
    pub smoothed_mean: Vec<DVector<f64>>,
    /// Smoothed covariances.
    pub smoothed_cov: Vec<DMatrix<f64>>,
    /// log p(y_0, …, y_N), the marginal likelihood of the data.
    pub log_likelihood: f64,
}

impl KalmanSmoothing {
    /// Index of time `t` in the grid (within 1e-9 relative), if present.
    pub fn index_of(&self, t: f64) -> Option<usize> {
        self.times.iter().position(|&s| (s - t).abs() <= 1e-9 * (1.0 + t.abs()))
    }
}

/// The exact Kalman filter and RTS smoother of `model` given `data` (NaN = missing), with the
/// moments reported at t0, every measurement time and every time of `output_times`
/// (Särkkä 2013, Thms 4.2 and 8.2, on the exact discretisation of [`LinearSde::transition`]).
pub fn kalman_rts(
    model: &LinearGaussianModel,
    data: &Dataset,
    output_times: &[f64],
) -> Result<KalmanSmoothing> {
    let n = model.sde.a.nrows();
    check_len("measurement matrix rows", data.names.len(), model.h.nrows())?;
    check_len("measurement matrix columns", n, model.h.ncols())?;
    let extra: Vec<f64> = std::iter::once(model.t0).chain(output_times.iter().copied()).collect();
    let EventTimes { times, measurement, .. } = EventTimes::merge(&data.times, &extra);
    if times[0] < model.t0 || times.iter().any(|t| !t.is_finite()) {
        return Err(Error::InvalidOption {
            name: "times".into(),
            reason: format!("all times must be finite and ≥ t0 = {}", model.t0),
        });
    }
    let singular = || Error::InvalidOption {
        name: "model".into(),
        reason: "a covariance of the Kalman recursion is singular".into(),
    };
    let nt = times.len();
    let (mut fm, mut fc) = (Vec::with_capacity(nt), Vec::with_capacity(nt));
    let (mut pm, mut pc, mut trans) =
        (Vec::with_capacity(nt), Vec::with_capacity(nt), Vec::with_capacity(nt));
    let mut log_lik = 0.0;
    let (mut m, mut p) = (model.m0.clone(), model.p0.clone());
    for (i, &t) in times.iter().enumerate() {
        if i > 0 {
            let (f, c, q) = model.sde.transition(t - times[i - 1]);
            m = &f * &m + c;
            p = &f * &p * f.transpose() + q;
            trans.push(f);
        }
        pm.push(m.clone());
        pc.push(p.clone());
        if let Some(k) = measurement[i] {
            let y = &data.values[k];
            let obs: Vec<usize> = (0..y.len()).filter(|&j| !y[j].is_nan()).collect();
            if !obs.is_empty() {
                let h = model.h.select_rows(&obs);
                let r = model.r.select_rows(&obs).select_columns(&obs);
                let innov = DVector::from_iterator(obs.len(), obs.iter().map(|&j| y[j])) - &h * &m;
                let s = &h * &p * h.transpose() + r;
                let chol = s.clone().cholesky().ok_or_else(singular)?;
                let s_inv_innov = chol.solve(&innov);
                let log_det: f64 = chol.l().diagonal().iter().map(|d| 2.0 * d.ln()).sum();
                log_lik += -0.5
                    * (innov.dot(&s_inv_innov)
                        + log_det
                        + obs.len() as f64 * (2.0 * std::f64::consts::PI).ln());
                let gain = chol.solve(&(&h * &p)).transpose();
                m = &m + &gain * innov;
                p = &p - &gain * &s * gain.transpose();
                p = (&p + p.transpose()) * 0.5;
            }
        }
        fm.push(m.clone());
        fc.push(p.clone());
    }
    let (mut sm, mut sc) = (fm.clone(), fc.clone());
    for i in (0..nt - 1).rev() {
        let f = &trans[i];
        // G = P_f Fᵀ P_pred⁻¹, with P_pred = pc[i + 1].
        let lu = pc[i + 1].clone().lu();
        let g = lu.solve(&(f * &fc[i])).ok_or_else(singular)?.transpose();
        sm[i] = &fm[i] + &g * (&sm[i + 1] - &pm[i + 1]);
        let cov = &fc[i] + &g * (&sc[i + 1] - &pc[i + 1]) * g.transpose();
        sc[i] = (&cov + cov.transpose()) * 0.5;
    }
    Ok(KalmanSmoothing {
        times,
        filtered_mean: fm,
        filtered_cov: fc,
        smoothed_mean: sm,
        smoothed_cov: sc,
        log_likelihood: log_lik,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    fn ou(theta: f64, sigma: f64) -> LinearSde {
        LinearSde {
            a: DMatrix::from_element(1, 1, -theta),
            b: DVector::zeros(1),
            noise: DMatrix::from_element(1, 1, sigma),
        }
    }

    #[test]
    fn transition_matches_ou_closed_form() {
        // OU: F = e^{−θΔ}, Q = σ²/(2θ)(1 − e^{−2θΔ}) (closed form).
        let (th, s, d) = (1.3, 0.7, 0.37);
        let (f, c, q) = ou(th, s).transition(d);
        assert_relative_eq!(f[(0, 0)], (-th * d).exp(), max_relative = 1e-13);
        assert_eq!(c[0], 0.0);
        assert_relative_eq!(
            q[(0, 0)],
            s * s / (2.0 * th) * (1.0 - (-2.0 * th * d).exp()),
            max_relative = 1e-12
        );
    }

    #[test]
    fn transition_of_integrated_brownian_motion_matches_closed_form() {
        // dX = b dt + σ dW, dZ = X dt: F = [[1, 0], [Δ, 1]], c = (bΔ, bΔ²/2),
        // Q = σ² [[Δ, Δ²/2], [Δ²/2, Δ³/3]] (closed form).
        let (b, s, d) = (0.4, 0.9, 0.6);
        let sde = LinearSde {
            a: DMatrix::from_row_slice(2, 2, &[0.0, 0.0, 1.0, 0.0]),
            b: DVector::from_vec(vec![b, 0.0]),
            noise: DMatrix::from_row_slice(2, 1, &[s, 0.0]),
        };
        let (f, c, q) = sde.transition(d);
        assert_relative_eq!(f, DMatrix::from_row_slice(2, 2, &[1.0, 0.0, d, 1.0]), epsilon = 1e-14);
        assert_relative_eq!(c, DVector::from_vec(vec![b * d, b * d * d / 2.0]), epsilon = 1e-14);
        let expect = DMatrix::from_row_slice(2, 2, &[d, d * d / 2.0, d * d / 2.0, d * d * d / 3.0]) * (s * s);
        assert_relative_eq!(q, expect, epsilon = 1e-13);
    }

    #[test]
    fn one_measurement_posterior_is_the_gaussian_conjugate_update() {
        // Prior N(0, 1) at 0, OU to t = 1, one measurement y = 0.8 with R = 0.04. The smoothed
        // law at t = 1 is the conjugate update of the predicted law N(0, P1), P1 = e^{−2θ} +
        // σ²/(2θ)(1 − e^{−2θ}); at t = 0 it is the regression of S(0) on S(1).
        let (th, s, r, y) = (1.0, 0.5, 0.04, 0.8);
        let model = LinearGaussianModel {
            sde: ou(th, s),
            h: DMatrix::identity(1, 1),
            r: DMatrix::from_element(1, 1, r),
            t0: 0.0,
            m0: DVector::zeros(1),
            p0: DMatrix::identity(1, 1),
        };
        let data = Dataset::try_new(vec!["y".into()], vec![1.0], vec![vec![y]]).unwrap();
        let out = kalman_rts(&model, &data, &[0.5]).unwrap();
        assert_eq!(out.times, vec![0.0, 0.5, 1.0]);
        let e = (-th).exp();
        let p1 = e * e + s * s / (2.0 * th) * (1.0 - e * e);
        let k = p1 / (p1 + r);
        assert_relative_eq!(out.smoothed_mean[2][0], k * y, max_relative = 1e-12);
        assert_relative_eq!(out.smoothed_cov[2][(0, 0)], (1.0 - k) * p1, max_relative = 1e-12);
        // Cov(S0, S1) = e^{−θ} P0 = e; E[S0 | y] = e/(P1 + R) y.
        assert_relative_eq!(out.smoothed_mean[0][0], e / (p1 + r) * y, max_relative = 1e-12);
        assert_relative_eq!(out.smoothed_cov[0][(0, 0)], 1.0 - e * e / (p1 + r), max_relative = 1e-12);
        let var = p1 + r;
        let ll = -0.5 * (y * y / var + var.ln() + (2.0 * std::f64::consts::PI).ln());
        assert_relative_eq!(out.log_likelihood, ll, max_relative = 1e-12);
    }

    #[test]
    fn measurements_closer_than_the_merge_tolerance_are_all_used() {
        // Two measurements 1e-10 apart, then two more: the result must be continuous in the
        // second time (compare with the pair 1e-6 apart) and must use the later data.
        let model = LinearGaussianModel {
            sde: ou(1.0, 0.5),
            h: DMatrix::identity(1, 1),
            r: DMatrix::from_element(1, 1, 0.04),
            t0: 0.0,
            m0: DVector::zeros(1),
            p0: DMatrix::identity(1, 1),
        };
        let data = |gap: f64, tail: bool| {
            let (mut t, mut v) = (vec![1.0, 1.0 + gap], vec![vec![0.8], vec![0.9]]);
            if tail {
                t.extend([2.0, 3.0]);
                v.extend([vec![-0.5], vec![0.3]]);
            }
            Dataset::try_new(vec!["y".into()], t, v).unwrap()
        };
        let close = kalman_rts(&model, &data(1e-10, true), &[]).unwrap();
        let apart = kalman_rts(&model, &data(1e-6, true), &[]).unwrap();
        let head = kalman_rts(&model, &data(1e-10, false), &[3.0]).unwrap();
        assert_eq!(close.times.len(), 5);
        assert_relative_eq!(close.log_likelihood, apart.log_likelihood, epsilon = 1e-5);
        let last = close.times.len() - 1;
        assert_relative_eq!(close.filtered_mean[last][0], apart.filtered_mean[last][0], epsilon = 1e-5);
        assert!((close.log_likelihood - head.log_likelihood).abs() > 0.1, "the data at 2 and 3 count");
    }

    #[test]
    fn missing_values_are_skipped() {
        let model = LinearGaussianModel {
            sde: ou(1.0, 0.5),
            h: DMatrix::identity(1, 1),
            r: DMatrix::from_element(1, 1, 0.04),
            t0: 0.0,
            m0: DVector::zeros(1),
            p0: DMatrix::identity(1, 1),
        };
        let with_nan =
            Dataset::try_new(vec!["y".into()], vec![0.5, 1.0], vec![vec![f64::NAN], vec![0.8]]).unwrap();
        let without = Dataset::try_new(vec!["y".into()], vec![1.0], vec![vec![0.8]]).unwrap();
        let a = kalman_rts(&model, &with_nan, &[]).unwrap();
        let b = kalman_rts(&model, &without, &[0.5]).unwrap();
        assert_eq!(a.times, b.times);
        for i in 0..a.times.len() {
            assert_relative_eq!(a.smoothed_mean[i], b.smoothed_mean[i], epsilon = 1e-15);
        }
        assert_relative_eq!(a.log_likelihood, b.log_likelihood, epsilon = 1e-15);
    }
}
