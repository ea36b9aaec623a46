//! Distances between paths, one rule for `onsager compare` and the experiments: the normalised
//! integrated square error of `000_74b95e149527c64e.txt (4.1)`, the root-mean-square error, and
//! the fraction of time an estimate is on the same side of a threshold (the well) as the truth,
//! and for estimates with standard deviations the mean posterior sd and the coverage of the
//! truth by the ±2 sd band.
//!
//! **The rule.** Every metric compares an estimate with a reference path (the truth, or the
//! estimate of another estimator) at the *reference's* times inside the estimate's time span,
//! the estimate linearly interpolated there. An estimate and its reference usually live on
//! different time grids (a KSP output grid, a transcription's nodes, the measurement times of a
//! filter); the truth's grid is the simulation's, so against the truth the metrics are averages
//! over time. [`measure`] applies the rule to a [`Metric`]; `compare` and the experiment runner
//! both call it.

use crate::data::StatePath;
use crate::{Error, Result};

/// A metric of an estimate (a column of `results.csv`, of `onsager compare`'s table).
#[derive(Debug, Clone, PartialEq)]
pub enum Metric {
    /// Normalised integrated square error to the truth over all states,
    /// `000_74b95e149527c64e.txt (4.1)` (column `ise`).
    Ise,
    /// Root-mean-square error to the truth over the truth's times, all states (`rmse`).
    Rmse,
    /// Root-mean-square error to the estimate of another estimator (by its label), over that
    /// estimate's times (`rmse_to_LABEL`).
    RmseTo(String),
    /// Fraction of the truth's times at which the estimate of `state` (default: the first) is on
    /// the true side of `barrier`: the true well of a double well (`well_side`,
    /// `well_side_STATE`).
    WellSide {
        /// The state (default: the first).
        state: Option<String>,
        /// The threshold between the wells.
        barrier: f64,
    },
    /// Mean of the estimate's standard deviations over the truth's times and all states
    /// (`mean_sd`).
    MeanSd,
    /// Fraction of the truth's (time, state) points inside the estimate's ±2 sd band
    /// (`coverage`); about 0.95 for a calibrated Gaussian posterior.
    Coverage,
}

impl Metric {
    /// Parses `ise`, `rmse`, `rmse-to:LABEL`, `well-side[:STATE]` (barrier 0, the symmetric
    /// double well, or the lobes of Lorenz-63 for the state `x`), `mean-sd` or `coverage`.
    pub fn parse(s: &str) -> Result<Metric> {
        let s = s.trim();
        let side = |state: Option<String>| Metric::WellSide { state, barrier: 0.0 };
        match s.split_once(':') {
            None if s == "ise" => Ok(Metric::Ise),
            None if s == "rmse" => Ok(Metric::Rmse),
            None if s == "well-side" => Ok(side(None)),
            None if s == "mean-sd" => Ok(Metric::MeanSd),
            None if s == "coverage" => Ok(Metric::Coverage),
            Some(("rmse-to", label)) if !label.trim().is_empty() => Ok(Metric::RmseTo(label.trim().into())),
            Some(("well-side", state)) if !state.trim().is_empty() => Ok(side(Some(state.trim().into()))),
            _ => Err(Error::InvalidOption {
                name: "metrics".into(),
                reason: format!(
                    "unknown metric `{s}` (known: ise, rmse, rmse-to:LABEL, well-side, well-side:STATE, \
                     mean-sd, coverage)"
                ),
            }),
        }
    }

    /// The metric's column.
    pub fn column(&self) -> String {
        match self {
            Metric::Ise => "ise".into(),
            Metric::Rmse => "rmse".into(),
            Metric::RmseTo(label) => format!("rmse_to_{label}"),
            Metric::WellSide { state: None, .. } => "well_side".into(),
            Metric::WellSide { state: Some(s), .. } => format!("well_side_{s}"),
            Metric::MeanSd => "mean_sd".into(),
            Metric::Coverage => "coverage".into(),
        }
    }
}

/// The value of `metric` for `estimate`, by the rule of the [module documentation](self):
/// against `truth` (for `ise`, `rmse`, `well-side`) or against the estimate labelled so in
/// `others` (for `rmse-to`).
///
/// Errors: the reference is not given (no truth, no estimate with that label); those of
/// [`ise`], [`rmse`] and [`same_side_fraction`].
pub fn measure(
    metric: &Metric,
    estimate: &StatePath,
    truth: Option<&StatePath>,
    others: &[(&str, &StatePath)],
) -> Result<f64> {
    let missing = |what: String| Error::InvalidOption {
        name: metric.column(),
        reason: format!("{what} is not available"),
    };
    let truth = || truth.ok_or_else(|| missing("the true path".into()));
    match metric {
        Metric::Ise => ise(estimate, truth()?, None),
        Metric::Rmse => rmse(estimate, truth()?, None),
        Metric::RmseTo(label) => match others.iter().find(|(l, _)| l == label) {
            Some((_, reference)) => rmse(estimate, reference, None),
            None => Err(missing(format!("the estimate of `{label}`"))),
        },
        Metric::WellSide { state, barrier } => {
            let truth = truth()?;
            let state = state.clone().unwrap_or_else(|| truth.names[0].clone());
            same_side_fraction(estimate, truth, &state, *barrier)
        }
        Metric::MeanSd => band(estimate, truth()?, 2.0).map(|b| b.mean_sd),
        Metric::Coverage => band(estimate, truth()?, 2.0).map(|b| b.coverage),
    }
}

/// The estimate's standard deviations against a reference path: their mean and the coverage of
/// the reference by the band mean ± k sd ([`band`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Band {
    /// Mean sd over the reference's (time, state) points inside the estimate's span.
    pub mean_sd: f64,
    /// Fraction of those points with |reference − mean| ≤ k sd.
    pub coverage: f64,
}

/// The mean sd of `estimate` and the fraction of the reference's (time, state) points inside
/// the estimate's span that lie in the band mean ± `k` sd, mean and sd linearly interpolated
/// at the reference's times (every state of the reference).
///
/// Errors: the estimate has no standard deviations ([`Error::InvalidOption`], name `sd`);
/// those of [`ise`].
pub fn band(estimate: &StatePath, reference: &StatePath, k: f64) -> Result<Band> {
    let Some(sd) = &estimate.sd else {
        return Err(Error::InvalidOption {
            name: "sd".into(),
            reason: "the estimate has no standard deviations".into(),
        });
    };
    let cols = columns(estimate, reference, None)?;
    let (mut inside, mut sum_sd, mut n) = (0usize, 0.0, 0usize);
    for &(e, r) in &cols {
        let mean: Vec<f64> = estimate.values.iter().map(|row| row[e]).collect();
        let sds: Vec<f64> = sd.iter().map(|row| row[e]).collect();
        for (i, &t) in reference.times.iter().enumerate() {
            let (Some(m), Some(s)) =
                (interpolate(&estimate.times, &mean, t), interpolate(&estimate.times, &sds, t))
            else {
                continue;
            };
            n += 1;
            sum_sd += s;
            if (reference.values[i][r] - m).abs() <= k * s {
                inside += 1;
            }
        }
    }
    if n == 0 {
        return Err(Error::InvalidOption {
            name: "reference".into(),
            reason: "no reference time lies inside the estimate's time span".into(),
        });
    }
    Ok(Band { mean_sd: sum_sd / n as f64, coverage: inside as f64 / n as f64 })
}

/// Linear interpolation of `values` (one value per time of the increasing `times`) at `t`;
/// `None` outside [times₀, times_last] or on an empty path.
pub fn interpolate(times: &[f64], values: &[f64], t: f64) -> Option<f64> {
    let (&first, &last) = (times.first()?, times.last()?);
    if !(t >= first && t <= last) {
        return None;
    }
    let j = times.partition_point(|&s| s <= t);
    if j == 0 {
        return Some(values[0]);
    }
    if j == times.len() {
        return Some(values[j - 1]);
    }
    let (t0, t1) = (times[j - 1], times[j]);
    let w = if t1 > t0 { (t - t0) / (t1 - t0) } else { 0.0 };
    Some(values[j - 1] + w * (values[j] - values[j - 1]))
}

/// The state columns compared: the reference's state names, each found in `estimate`.
fn columns(
    estimate: &StatePath,
    reference: &StatePath,
    states: Option<&[String]>,
) -> Result<Vec<(usize, usize)>> {
    let names: Vec<String> = match states {
        Some(s) => s.to_vec(),
        None => reference.names.clone(),
    };
    names
        .iter()
        .map(|n| {
            let e = estimate.names.iter().position(|m| m == n);
            let r = reference.names.iter().position(|m| m == n);
            match (e, r) {
                (Some(e), Some(r)) => Ok((e, r)),
                _ => Err(Error::UnknownName {
                    kind: "state".into(),
                    name: n.clone(),
                    known: estimate.names.iter().filter(|m| reference.names.contains(m)).cloned().collect(),
                }),
            }
        })
        .collect()
}

/// Squared differences Σ_states (estimate − reference)² at each reference time inside the
/// estimate's span, as (time, value) pairs.
fn squared_differences(
    estimate: &StatePath,
    reference: &StatePath,
    states: Option<&[String]>,
) -> Result<Vec<(f64, f64)>> {
    let cols = columns(estimate, reference, states)?;
    let est_columns: Vec<Vec<f64>> =
        cols.iter().map(|&(e, _)| estimate.values.iter().map(|row| row[e]).collect()).collect();
    let mut out = Vec::with_capacity(reference.times.len());
    'times: for (i, &t) in reference.times.iter().enumerate() {
        let mut s = 0.0;
        for (c, &(_, r)) in cols.iter().enumerate() {
            match interpolate(&estimate.times, &est_columns[c], t) {
                Some(v) => s += (v - reference.values[i][r]).powi(2),
                None => continue 'times,
            }
        }
        out.push((t, s));
    }
    if out.is_empty() {
        return Err(Error::InvalidOption {
            name: "reference".into(),
            reason: "no reference time lies inside the estimate's time span".into(),
        });
    }
    Ok(out)
}

/// The normalised integrated square error (`000_74b95e149527c64e.txt (4.1)`),
/// (1/T)∫ Σ_states |estimate − reference|² dt, by the trapezoidal rule over the reference's
/// times inside the estimate's span (T = that span). `states` restricts the sum (default: every
/// state of the reference). A single common time gives the squared difference there.
///
/// Errors: a state missing from either path; no common time.
pub fn ise(estimate: &StatePath, reference: &StatePath, states: Option<&[String]>) -> Result<f64> {
    let d = squared_differences(estimate, reference, states)?;
    if d.len() == 1 {
        return Ok(d[0].1);
    }
    let span = d[d.len() - 1].0 - d[0].0;
    let integral: f64 = d.windows(2).map(|w| 0.5 * (w[1].0 - w[0].0) * (w[0].1 + w[1].1)).sum();
    Ok(integral / span)
}

/// The root-mean-square error over the reference's times inside the estimate's span,
/// sqrt(mean over times of Σ_states (estimate − reference)²).
///
/// Errors: as [`ise`].
pub fn rmse(estimate: &StatePath, reference: &StatePath, states: Option<&[String]>) -> Result<f64> {
    let d = squared_differences(estimate, reference, states)?;
    Ok((d.iter().map(|p| p.1).sum::<f64>() / d.len() as f64).sqrt())
}

/// The fraction of the reference's times (inside the estimate's span) at which `state` of the
/// estimate is on the same side of `threshold` as the reference (the same well of a double well
/// when the threshold is the barrier).
///
/// Errors: as [`ise`].
pub fn same_side_fraction(
    estimate: &StatePath,
    reference: &StatePath,
    state: &str,
    threshold: f64,
) -> Result<f64> {
    let cols = columns(estimate, reference, Some(&[state.to_string()]))?;
    let (e, r) = cols[0];
    let est: Vec<f64> = estimate.values.iter().map(|row| row[e]).collect();
    let (mut same, mut n) = (0usize, 0usize);
    for (i, &t) in reference.times.iter().enumerate() {
        if let Some(v) = interpolate(&estimate.times, &est, t) {
            n += 1;
            if (v > threshold) == (reference.values[i][r] > threshold) {
                same += 1;
            }
        }
    }
    if n == 0 {
        return Err(Error::InvalidOption {
            name: "reference".into(),
            reason: "no reference time lies inside the estimate's time span".into(),
        });
    }
    Ok(same as f64 / n as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn path(times: Vec<f64>, f: impl Fn(f64) -> f64) -> StatePath {
        let values = times.iter().map(|&t| vec![f(t)]).collect();
        StatePath { names: vec!["x".into()], times, values, sd: None }
    }

    #[test]
    fn interpolation_is_linear_and_bounded() {
        let t = [0.0, 1.0, 3.0];
        let v = [0.0, 2.0, 6.0];
        assert_eq!(interpolate(&t, &v, 0.5), Some(1.0));
        assert_eq!(interpolate(&t, &v, 2.0), Some(4.0));
        assert_eq!(interpolate(&t, &v, 3.0), Some(6.0));
        assert_eq!(interpolate(&t, &v, 0.0), Some(0.0));
        assert_eq!(interpolate(&t, &v, 3.1), None);
        assert_eq!(interpolate(&t, &v, f64::NAN), None);
        assert_eq!(interpolate(&[], &[], 0.0), None);
    }

    #[test]
    fn ise_and_rmse_closed_forms() {
        // Estimate t, reference 0 on [0, 1]: ISE = ∫ t² dt = 1/3, and the trapezoidal rule on
        // a step h gives exactly 1/3 + h²/6; RMSE² is the mean of t_i².
        let n = 1000;
        let times: Vec<f64> = (0..=n).map(|i| i as f64 / n as f64).collect();
        let est = path(vec![0.0, 1.0], |t| t);
        let reference = path(times.clone(), |_| 0.0);
        let h = 1.0 / n as f64;
        assert!((ise(&est, &reference, None).unwrap() - (1.0 / 3.0 + h * h / 6.0)).abs() < 1e-12);
        let mean_sq: f64 = times.iter().map(|t| t * t).sum::<f64>() / times.len() as f64;
        assert!((rmse(&est, &reference, None).unwrap() - mean_sq.sqrt()).abs() < 1e-12);
        // Identical paths.
        assert_eq!(ise(&reference, &reference, None).unwrap(), 0.0);
        // Only the estimate's span counts: estimate on [0, 0.5] vs reference on [0, 1].
        let half = path(vec![0.0, 0.5], |t| t);
        let ise_half = ise(&half, &reference, None).unwrap();
        assert!((ise_half - (1.0 / 12.0 + h * h / 6.0)).abs() < 1e-12, "{ise_half}");
    }

    #[test]
    fn same_side_and_errors() {
        let times: Vec<f64> = (0..=100).map(|i| i as f64 / 100.0).collect();
        let truth = path(times.clone(), |t| if t < 0.5 { -1.0 } else { 1.0 });
        let est = path(times.clone(), |t| if t < 0.25 { -1.0 } else { 1.0 });
        let f = same_side_fraction(&est, &truth, "x", 0.0).unwrap();
        assert!((f - 76.0 / 101.0).abs() < 1e-12, "{f}");
        let other = StatePath { names: vec!["y".into()], ..est.clone() };
        assert!(matches!(rmse(&other, &truth, None), Err(Error::UnknownName { .. })));
        let late = path(vec![2.0, 3.0], |t| t);
        assert!(rmse(&late, &truth, None).is_err());
    }

    #[test]
    fn band_closed_forms() {
        // Truth t on [0, 1] (101 points), estimate 0 with sd 0.25: |t| ≤ 2 · 0.25 for t ≤ 0.5,
        // 51 of 101 points; the mean sd is 0.25. Without sds the band is an error.
        let times: Vec<f64> = (0..=100).map(|i| i as f64 / 100.0).collect();
        let truth = path(times.clone(), |t| t);
        let mut est = path(vec![0.0, 1.0], |_| 0.0);
        assert!(matches!(band(&est, &truth, 2.0), Err(Error::InvalidOption { .. })));
        est.sd = Some(vec![vec![0.25], vec![0.25]]);
        let b = band(&est, &truth, 2.0).unwrap();
        assert!((b.coverage - 51.0 / 101.0).abs() < 1e-12, "{b:?}");
        assert!((b.mean_sd - 0.25).abs() < 1e-12);
        assert_eq!(measure(&Metric::Coverage, &est, Some(&truth), &[]).unwrap(), b.coverage);
        assert_eq!(Metric::parse("coverage").unwrap().column(), "coverage");
        assert_eq!(Metric::parse("mean-sd").unwrap().column(), "mean_sd");
    }
}
