//! Noise levels of a flight-test record from its own samples: the sensors' noise sds and the
//! jerks' diffusions σ_a, σ_m of [`FlightPath`](super::FlightPath), for a record whose levels
//! are not known (the thesis chose them "empirically", 000 Sec. 4.2).
//!
//! Both come from finite differences of equally spaced samples. A channel y_k = s(t_k) + e_k
//! with e white of sd σ_e has, for its n-th difference at lag ℓ samples,
//! var Δⁿ_ℓ y = var Δⁿ_ℓ s + Σ_j c_j² σ_e² with c_j the difference's coefficients
//! (Σ c_j² = C(2n, n): 6 for n = 2, 20 for n = 3).
//!
//! - At lag 1 a smooth signal's third differences are negligible, so
//!   σ̂_e = rms(Δ³y)/√20 ([`noise_sd`]). For white noise it errs upward where the signal is
//!   rough at the sample scale; noise that is not white (filtered before sampling) has smaller
//!   third differences and is underestimated.
//! - A signal that is an m-fold integral of a Brownian motion σW has
//!   var Δ^{m+1}_h s = c_m σ² h^{2m+1} at lag h, with c_m = ∫ B_m² the squared norm of the
//!   cardinal B-spline of degree m: c₁ = 2/3, c₂ = 11/20 ([`integrated_noise_intensity`]). In
//!   the model the jerks are Ornstein–Uhlenbeck processes of diffusion σ and damping k, which
//!   are σW on lags with k h ≪ 1: the specific forces are m = 1 and the rates m = 2 integrals
//!   of them. At larger k h the damping lowers the differences and the estimate of σ is low
//!   (by 7–8 % at k h = 0.2, by a factor 0.5–0.6 at k h = 1.5–2).

use super::{FlightPath, FlightPathObservation, FlightPathSetup, SensorSd};
use crate::data::Dataset;
use crate::{Error, Result};

/// The coefficients (−1)^{n−j} C(n, j), j = 0..=n, of the n-th difference.
fn coefficients(order: usize) -> Vec<f64> {
    (0..=order)
        .map(|j| {
            let binom = (0..j).fold(1.0, |b, i| b * (order - i) as f64 / (i + 1) as f64);
            if (order - j).is_multiple_of(2) {
                binom
            } else {
                -binom
            }
        })
        .collect()
}

/// n-th differences at lag `lag` of `y` over the windows whose samples are all finite.
fn differences(y: &[f64], order: usize, lag: usize) -> Vec<f64> {
    let coef = coefficients(order);
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

/// For white noise through the n-th difference at lag ℓ: Σ c_j² (the noise variance's factor)
/// and 1 + 2 Σ_s ρ_s², where ρ_s is the correlation of two windows s lags apart (they share
/// samples), the factor by which overlapping windows inflate the variance of a mean square.
fn noise_factors(order: usize) -> (f64, f64) {
    let c = coefficients(order);
    let norm: f64 = c.iter().map(|x| x * x).sum();
    let overlap: f64 = (1..=order)
        .map(|s| {
            let rho = c.iter().zip(&c[s..]).map(|(a, b)| a * b).sum::<f64>() / norm;
            rho * rho
        })
        .sum();
    (norm, 1.0 + 2.0 * overlap)
}

/// The noise sd of a channel sampled at equal steps: rms(Δ³y)/√20 over the windows of four
/// finite samples (module docs); `None` with fewer than 10 windows.
pub fn noise_sd(y: &[f64]) -> Option<f64> {
    let (norm, _) = noise_factors(3);
    mean_square(&differences(y, 3, 1)).map(|m| (m / norm).sqrt())
}

/// The intensity σ of the Brownian motion of which the channel `y` (step `dt`) is an
/// `order`-fold integral (1 or 2), from its (order + 1)-th differences at lag `lag` samples
/// with the noise of sd `noise` removed: σ² = (mean (Δ^{m+1}_h y)² − C(2m+2, m+1) noise²) /
/// (c_m h^{2m+1}), h = lag·dt (module docs). `None` for another order, a `dt` that is not
/// positive and finite, fewer than 10 windows, or a signal part within three sampling sds of
/// the noise part of zero (that sd is C(2m+2, m+1) noise² √(2 (1 + 2 Σ ρ²)/n) for n windows
/// whose overlaps have correlations ρ; the error of `noise` itself is not included).
pub fn integrated_noise_intensity(y: &[f64], dt: f64, order: usize, lag: usize, noise: f64) -> Option<f64> {
    let c = match order {
        1 => 2.0 / 3.0,
        2 => 11.0 / 20.0,
        _ => return None,
    };
    if !(dt > 0.0 && dt.is_finite()) || lag == 0 {
        return None;
    }
    let (norm, overlap) = noise_factors(order + 1);
    let h = lag as f64 * dt;
    let d = differences(y, order + 1, lag);
    let noise_part = norm * noise * noise;
    let signal = mean_square(&d)? - noise_part;
    let resolved = signal > 3.0 * noise_part * (2.0 * overlap / d.len() as f64).sqrt();
    resolved.then(|| (signal / (c * h.powi(2 * order as i32 + 1))).sqrt())
}

/// The lag, in seconds, at which [`RecordLevels::measure`] measures the roughness of the rates
/// and specific forces: long against the sample step (so the sensor noise is small in the
/// differences), short against the manoeuvre.
pub const ROUGHNESS_LAG: f64 = 0.2;

/// The noise levels of a flight record measured from its samples ([`RecordLevels::measure`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RecordLevels {
    /// The record's step (s).
    pub step: f64,
    /// Each sensor's sd ([`noise_sd`]).
    pub sensor_sd: SensorSd,
    /// σ_a: the largest [`integrated_noise_intensity`] (order 1, lag [`ROUGHNESS_LAG`]) of
    /// the three specific forces whose roughness shows above their noise; `None` if none does.
    pub sigma_a: Option<f64>,
    /// σ_m: the same over the three rates (order 2).
    pub sigma_m: Option<f64>,
}

impl RecordLevels {
    /// Measures the levels of `data`, a record with the outputs of [`FlightPathObservation`]
    /// in their order at equal steps (within 10⁻⁶ of the mean step).
    ///
    /// # Errors
    /// [`Error::InvalidOption`] (option `flight record`) when the record has fewer than two
    /// times, other columns than [`FlightPathObservation::OUTPUTS`], rows of another length,
    /// times that are not equally spaced and increasing, or an output whose noise cannot be
    /// measured (fewer than 10 windows of four finite samples) or measures zero.
    pub fn measure(data: &Dataset) -> Result<RecordLevels> {
        let n = data.times.len();
        if n < 2 {
            return Err(invalid("the record has fewer than two times".into()));
        }
        if data.names != FlightPathObservation::OUTPUTS {
            return Err(invalid(format!(
                "the columns are {:?}, not the flight-path outputs {:?}",
                data.names,
                FlightPathObservation::OUTPUTS
            )));
        }
        if let Some(k) = data.values.iter().position(|row| row.len() != 13) {
            return Err(invalid(format!("row {k} has {} values, not 13", data.values[k].len())));
        }
        let step = (data.times[n - 1] - data.times[0]) / (n - 1) as f64;
        // NaN times fail `even` too.
        let even = |w: &[f64]| (w[1] - w[0] - step).abs() <= 1e-6 * step;
        let uneven = data.times.windows(2).position(|w| !even(w));
        if !(step > 0.0 && step.is_finite()) || data.values.len() != n || uneven.is_some() {
            return Err(invalid(format!(
                "the times are not equally spaced and increasing (first departure after time index {})",
                uneven.unwrap_or(0)
            )));
        }
        let column = |j: usize| -> Vec<f64> { data.values.iter().map(|row| row[j]).collect() };
        let mut sd = [0.0; 13];
        for (j, s) in sd.iter_mut().enumerate() {
            *s = noise_sd(&column(j)).filter(|&v| v > 0.0).ok_or_else(|| {
                invalid(format!(
                    "output `{}`: fewer than 10 windows of four finite samples, or no noise at all, so its \
                     noise cannot be measured",
                    FlightPathObservation::OUTPUTS[j]
                ))
            })?;
        }
        let lag = ((ROUGHNESS_LAG / step).round() as usize).max(1);
        let roughest = |channels: std::ops::Range<usize>, order: usize| {
            channels
                .filter_map(|j| integrated_noise_intensity(&column(j), step, order, lag, sd[j]))
                .reduce(f64::max)
        };
        Ok(RecordLevels {
            step,
            sensor_sd: SensorSd(sd),
            sigma_a: roughest(10..13, 1),
            sigma_m: roughest(7..10, 2),
        })
    }

    /// The setup for estimating on the record: the default setup with the estimators' step
    /// the record's, the measured sensor sds, and σ_a, σ_m as measured.
    ///
    /// # Errors
    /// [`Error::InvalidOption`] naming the outputs of σ_a or σ_m when it was not measured (no
    /// roughness shows above the noise at lag [`ROUGHNESS_LAG`]): set it instead.
    pub fn setup(&self) -> Result<FlightPathSetup> {
        let missing = |outputs: &[&str]| {
            invalid(format!(
                "outputs `{}`: no roughness shows above the noise at lag {ROUGHNESS_LAG} s, so the jerks' \
                 diffusion cannot be measured from the record; set it instead",
                outputs.join("`, `")
            ))
        };
        let sigma_a = self.sigma_a.ok_or_else(|| missing(&FlightPathObservation::OUTPUTS[10..13]))?;
        let sigma_m = self.sigma_m.ok_or_else(|| missing(&FlightPathObservation::OUTPUTS[7..10]))?;
        let base = FlightPathSetup::new();
        Ok(FlightPathSetup {
            model: FlightPath { sigma_a, sigma_m, ..base.model },
            observation: FlightPathObservation { sd: self.sensor_sd, ..base.observation },
            sample_every: self.step,
            ..base
        })
    }
}

impl FlightPathSetup {
    /// The setup for estimating on a flight-test record `data`: [`RecordLevels::measure`] then
    /// [`RecordLevels::setup`]. The jerks are then free enough to follow the roughest channel
    /// of each kind.
    ///
    /// # Errors
    /// As those two.
    pub fn for_record(data: &Dataset) -> Result<FlightPathSetup> {
        RecordLevels::measure(data)?.setup()
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
    /// 6a dt³, negligible here, so the estimate is the noise sd to sampling error (relative sd
    /// ½ √(2 (1 + 2 Σ ρ²)/n) = 2.4 % at n = 2000).
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

    /// The constants: the (m+1)-th difference at unit lag of the m-fold integral of a
    /// Brownian motion is ∫ K(u) dW(u) with K(u) = Σ_j c_j (j − u)₊^m / m!, the cardinal
    /// B-spline of degree m; its variance ∫ K² by the midpoint rule is 2/3 (m = 1) and 11/20
    /// (m = 2). And the noise factors of second and third differences: Σ c² = 6, 20;
    /// 1 + 2 Σ ρ² = 1 + 2 (16 + 1)/36 and 1 + 2 (225 + 36 + 1)/400.
    #[test]
    fn difference_constants_match_their_closed_forms() {
        for (m, expected) in [(1usize, 2.0 / 3.0), (2, 11.0 / 20.0)] {
            let c = coefficients(m + 1);
            let fact: f64 = (1..=m).map(|i| i as f64).product();
            let cells = 200_000;
            let du = (m + 1) as f64 / cells as f64;
            let integral: f64 = (0..cells)
                .map(|i| {
                    let u = (i as f64 + 0.5) * du;
                    let k: f64 =
                        c.iter().enumerate().map(|(j, cj)| cj * (j as f64 - u).max(0.0).powi(m as i32)).sum();
                    (k / fact).powi(2) * du
                })
                .sum();
            assert!((integral - expected).abs() < 1e-8, "m = {m}: {integral}");
        }
        let (n2, o2) = noise_factors(2);
        let (n3, o3) = noise_factors(3);
        assert_eq!((n2, n3), (6.0, 20.0));
        assert!(
            (o2 - (1.0 + 2.0 * 17.0 / 36.0)).abs() < 1e-14
                && (o3 - (1.0 + 2.0 * 262.0 / 400.0)).abs() < 1e-14
        );
    }

    /// A record that is not a flight-path record at equal steps is an error that says why,
    /// not a panic or a NaN level: other columns, short rows, uneven or repeated times, a
    /// channel without noise.
    #[test]
    fn bad_records_are_errors() {
        let names: Vec<String> = FlightPathObservation::OUTPUTS.iter().map(|s| s.to_string()).collect();
        let e = white(13 * 40, 4);
        let good = Dataset {
            names: names.clone(),
            times: (0..40).map(|k| k as f64 * 0.04).collect(),
            values: (0..40).map(|k| e[13 * k..13 * k + 13].to_vec()).collect(),
        };
        assert!(RecordLevels::measure(&good).is_ok());
        let message = |d: &Dataset| RecordLevels::measure(d).unwrap_err().to_string();
        let mut d = good.clone();
        d.names.swap(0, 1);
        assert!(message(&d).contains("not the flight-path outputs"));
        let mut d = good.clone();
        d.values[3].pop();
        assert!(message(&d).contains("row 3 has 12 values"));
        let mut d = good.clone();
        d.times[5] += 0.01;
        assert!(message(&d).contains("not equally spaced"));
        let mut d = good.clone();
        d.times.iter_mut().for_each(|t| *t = 1.0);
        assert!(message(&d).contains("not equally spaced"));
        let mut d = good.clone();
        d.values.iter_mut().for_each(|row| row[4] = 0.1);
        assert!(message(&d).contains("`theta_m`"));
        assert!(message(&Dataset { times: vec![0.0], values: vec![good.values[0].clone()], ..good })
            .contains("fewer than two"));
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
