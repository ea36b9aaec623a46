//! Noise levels of a flight-test record from its own samples: the sensors' noise sds and the
//! jerks' diffusions σ_a, σ_m of [`FlightPath`](super::FlightPath), for a record whose levels
//! are not known (the thesis chose them "empirically", 000 Sec. 4.2).
//!
//! Both come from finite differences of equally spaced samples. A channel y_k = s(t_k) + e_k
//! with e white of sd σ_e has, for its n-th difference at lag ℓ samples,
//! var Δⁿ_ℓ y = var Δⁿ_ℓ s + C(2n, n) σ_e² (C(2n, n) = 20 for n = 3).
//!
//! - At lag 1 a smooth signal's third differences are negligible, so
//!   σ̂_e = rms(Δ³y)/√20 ([`noise_sd`]; an upper bound where the signal is rough at the
//!   sample scale).
//! - A signal that is an m-fold integral of white noise of intensity σ (the specific forces
//!   are m = 1 integrals of the jerks, the rates m = 2) has
//!   var Δ^{m+1}_h s = c_m σ² h^{2m+1} at lag h, with c_m = ∫ B_m² the squared norm of the
//!   cardinal B-spline of degree m: c₁ = 2/3, c₂ = 11/20 ([`integrated_noise_intensity`]).

use super::{FlightPath, FlightPathObservation, FlightPathSetup, SensorSd};
use crate::data::Dataset;
use crate::{Error, Result};

/// n-th differences at lag `lag` of `y` over the windows whose samples are all finite.
fn differences(y: &[f64], order: usize, lag: usize) -> Vec<f64> {
    let coef: Vec<f64> = (0..=order)
        .map(|j| {
            let binom = (0..j).fold(1.0, |b, i| b * (order - i) as f64 / (i + 1) as f64);
            if (order - j).is_multiple_of(2) {
                binom
            } else {
                -binom
            }
        })
        .collect();
    let span = order * lag;
    (0..y.len().saturating_sub(span))
        .filter_map(|k| {
            let d: f64 = coef.iter().enumerate().map(|(j, c)| c * y[k + j * lag]).sum();
            d.is_finite().then_some(d)
        })
        .collect()
}

fn mean_square(v: &[f64]) -> Option<f64> {
    (v.len() >= 10).then(|| v.iter().map(|d| d * d).sum::<f64>() / v.len() as f64)
}

/// The noise sd of a channel sampled at equal steps: rms(Δ³y)/√20 over the windows of four
/// finite samples (module docs); `None` with fewer than 10 windows.
pub fn noise_sd(y: &[f64]) -> Option<f64> {
    mean_square(&differences(y, 3, 1)).map(|m| (m / 20.0).sqrt())
}

/// The intensity σ of the white noise of which the channel `y` (step `dt`) is an `order`-fold
/// integral (1 or 2), from its (order + 1)-th differences at lag `lag` samples with the noise
/// of sd `noise` removed: σ² = (mean (Δ^{m+1}_h y)² − C(2m+2, m+1) noise²) / (c_m h^{2m+1}),
/// h = lag·dt (module docs). `None` for another order, fewer than 10 windows, or a signal part
/// within three times the sampling error of the noise part (about C(2m+2, m+1) noise² √(2/n)
/// for n windows) of zero.
pub fn integrated_noise_intensity(y: &[f64], dt: f64, order: usize, lag: usize, noise: f64) -> Option<f64> {
    let (c, binom) = match order {
        1 => (2.0 / 3.0, 6.0),
        2 => (11.0 / 20.0, 20.0),
        _ => return None,
    };
    let h = lag as f64 * dt;
    let d = differences(y, order + 1, lag);
    let noise_part = binom * noise * noise;
    let signal = mean_square(&d)? - noise_part;
    // The mean square of the noise part has relative sampling error about √(2/windows): a
    // signal within three of those of zero is not measured.
    let resolved = signal > 3.0 * noise_part * (2.0 / d.len() as f64).sqrt();
    resolved.then(|| (signal / (c * h.powi(2 * order as i32 + 1))).sqrt())
}

/// The lag, in seconds, at which [`FlightPathSetup::for_record`] measures the roughness of the
/// rates and specific forces: long against the sample step (so the sensor noise is small in
/// the differences), short against the manoeuvre.
pub const ROUGHNESS_LAG: f64 = 0.2;

impl FlightPathSetup {
    /// The setup for estimating on a flight-test record `data` (outputs of
    /// [`FlightPathObservation`], equal steps): the default setup with the estimators' step
    /// equal to the record's, each sensor's sd its [`noise_sd`], and σ_a and σ_m the largest
    /// [`integrated_noise_intensity`] at lag [`ROUGHNESS_LAG`] of the three specific forces
    /// (order 1) and of the three rates (order 2), over the channels whose roughness shows
    /// above their noise: the jerks are then free enough to follow the roughest channel of
    /// each kind.
    ///
    /// # Errors
    /// [`Error::InvalidOption`] naming the output whose noise cannot be measured (fewer than
    /// 10 windows of finite samples), or the group (specific forces, rates) none of whose
    /// roughness shows above its noise, or when the record has fewer than two times.
    pub fn for_record(data: &Dataset) -> Result<FlightPathSetup> {
        let n = data.times.len();
        if n < 2 {
            return Err(invalid("the record has fewer than two times".into()));
        }
        let dt = (data.times[n - 1] - data.times[0]) / (n - 1) as f64;
        let column = |j: usize| -> Vec<f64> { data.values.iter().map(|row| row[j]).collect() };
        let mut sd = [0.0; 13];
        for (j, s) in sd.iter_mut().enumerate() {
            *s = noise_sd(&column(j)).ok_or_else(|| {
                invalid(format!(
                    "output `{}`: fewer than 10 windows of four finite samples, so its noise cannot be measured",
                    FlightPathObservation::OUTPUTS[j]
                ))
            })?;
        }
        let lag = ((ROUGHNESS_LAG / dt).round() as usize).max(1);
        // The largest intensity over the channels whose roughness shows above their noise.
        let roughest = |channels: std::ops::Range<usize>, order: usize| {
            let names = FlightPathObservation::OUTPUTS[channels.clone()].join("`, `");
            channels
                .filter_map(|j| integrated_noise_intensity(&column(j), dt, order, lag, sd[j]))
                .reduce(f64::max)
                .ok_or_else(|| {
                    invalid(format!(
                        "outputs `{names}`: no roughness shows above the noise at lag {ROUGHNESS_LAG} s, so the jerks' \
                         diffusion cannot be measured from the record; set it instead"
                    ))
                })
        };
        let sigma_a = roughest(10..13, 1)?;
        let sigma_m = roughest(7..10, 2)?;
        let base = FlightPathSetup::new();
        Ok(FlightPathSetup {
            model: FlightPath { sigma_a, sigma_m, ..base.model },
            observation: FlightPathObservation { sd: SensorSd(sd), ..base.observation },
            sample_every: dt,
            ..base
        })
    }
}

fn invalid(reason: String) -> Error {
    Error::InvalidOption { name: "flight record".into(), reason }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};

    fn white(n: usize, seed: u64) -> Vec<f64> {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        (0..n).map(|_| StandardNormal.sample(&mut rng)).collect()
    }

    /// A cubic plus white noise of sd 0.3: the third differences of the cubic are a constant
    /// 6a dt³, negligible here, so the estimate is the noise sd to sampling error
    /// (relative sd about 1/√n·√(C(6,3)²/20² … ) ≈ 4 % at n = 2000).
    #[test]
    fn noise_sd_recovers_white_noise_on_a_smooth_signal() {
        let e = white(2000, 1);
        let y: Vec<f64> = (0..2000).map(|k| 1e-9 * (k as f64).powi(3) + 0.3 * e[k]).collect();
        let s = noise_sd(&y).unwrap();
        assert!((s / 0.3 - 1.0).abs() < 0.08, "{s}");
        let mut gaps = y.clone();
        gaps[500] = f64::NAN;
        assert!((noise_sd(&gaps).unwrap() / s - 1.0).abs() < 0.01);
        assert_eq!(noise_sd(&y[..12]), None);
    }

    /// Integrated Brownian motion (order 1) and twice integrated (order 2), built exactly on a
    /// fine grid by cumulative sums and sampled every 10th step, plus white noise: the
    /// intensity comes back within sampling error.
    #[test]
    fn integrated_noise_intensity_recovers_the_driving_noise() {
        let (n, fine, sigma, noise) = (20_000, 10, 2.0, 0.01);
        let dt_fine: f64 = 0.004;
        let w = white(n * fine, 2);
        let mut level1 = vec![0.0; n * fine];
        let mut level2 = vec![0.0; n * fine];
        let (mut b, mut i1, mut i2) = (0.0, 0.0, 0.0);
        for k in 0..n * fine {
            b += sigma * dt_fine.sqrt() * w[k];
            i1 += b * dt_fine;
            i2 += i1 * dt_fine;
            level1[k] = i1;
            level2[k] = i2;
        }
        let e = white(n, 3);
        let sample = |level: &[f64]| (0..n).map(|k| level[k * fine] + noise * e[k]).collect::<Vec<f64>>();
        let dt = dt_fine * fine as f64;
        for (order, level) in [(1, &level1), (2, &level2)] {
            let s = integrated_noise_intensity(&sample(level), dt, order, 5, noise).unwrap();
            assert!((s / sigma - 1.0).abs() < 0.1, "order {order}: {s}");
        }
        assert_eq!(integrated_noise_intensity(&level1, dt, 3, 5, 0.0), None);
    }
}
