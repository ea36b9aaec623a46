//! The figures of estimates, shared by `onsager compare` and the experiments: one look per
//! estimator ([`EstimatorLooks`]), the comparison of paths as small multiples
//! ([`PathFigure`]), and box-plot groups that state their row counts ([`box_group`]).
//!
//! ## One look per estimator
//!
//! Every method has a fixed colour and dash pattern ([`method_look`]) from the colour-blind-safe
//! [`PALETTE`] (Paul Tol's "muted" scheme): nine estimators of the default comparison are
//! solid lines in the nine colours, and its Gaussian KSP closure is dashed in the wine of the
//! mean-optimal estimator. The other methods reuse a colour with a dash of their own: the UKF dashed in the UKS's teal, the EKS dashed and the EKF dotted in cyan, the EnKS dashed
//! and the EnKF dotted in purple, the particle smoother dashed in the indigo of the exact KSP
//! smoother it approximates, the PEM dashed in MEE's olive. No look is the truth's ([`TRUTH`], a
//! thin black line) or the data's ([`DATA`], grey markers); estimators are lines without
//! markers.
//!
//! Within a run (a comparison, an experiment) an estimator keeps its look in every panel and
//! every figure: [`EstimatorLooks`] is built once from the run's estimators. The estimator
//! labelled with its method's name (or, if none is, the first of that method) has the method's
//! look; another estimator of the same method (e.g. `euler` and `trapezoidal` beside `jme`) takes
//! the first palette colour no estimator of the run has, solid, and once the nine are taken the
//! first free colour and dash pairing. The looks of a run depend only on its list of estimators.

use crate::data::{Dataset, StatePath};
use crate::estimate::PathEstimate;
use crate::estimator::Method;
use crate::path::{LaplaceSd, PathDetails};
use crate::plot::{BoxGroup, Color, Dash, LinePlot, Panels, Series, DATA, PALETTE, TRUTH};
use crate::Status;

/// How an estimator is drawn: its colour and dash pattern.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Look {
    /// Line, band and box colour.
    pub color: Color,
    /// Dash pattern of its line.
    pub dash: Dash,
}

const ROSE: Color = PALETTE[0];
const INDIGO: Color = PALETTE[1];
const SAND: Color = PALETTE[2];
const GREEN: Color = PALETTE[3];
const CYAN: Color = PALETTE[4];
const WINE: Color = PALETTE[5];
const TEAL: Color = PALETTE[6];
const OLIVE: Color = PALETTE[7];
const PURPLE: Color = PALETTE[8];

/// The fixed look of method `m` (see the module documentation); no two methods share one.
pub fn method_look(m: Method) -> Look {
    let (color, dash) = match m {
        Method::Ksp => (INDIGO, Dash::Solid),
        Method::MeanOptimal => (WINE, Dash::Solid),
        Method::GaussianClosure => (CYAN, Dash::Solid),
        Method::ExpClosure => (ROSE, Dash::Solid),
        Method::AreaClosure => (ROSE, Dash::Dashed),
        Method::DoubleExpClosure => (SAND, Dash::Solid),
        Method::KspClosure => (PURPLE, Dash::Solid),
        Method::GaussianKspClosure => (WINE, Dash::Dashed),
        Method::Jme => (GREEN, Dash::Solid),
        Method::Mee => (OLIVE, Dash::Solid),
        Method::Uks => (TEAL, Dash::Solid),
        Method::Ukf => (TEAL, Dash::Dashed),
        Method::Eks => (CYAN, Dash::Dashed),
        Method::Ekf => (CYAN, Dash::Dotted),
        Method::Enks => (PURPLE, Dash::Dashed),
        Method::Enkf => (PURPLE, Dash::Dotted),
        Method::Particle => (INDIGO, Dash::Dashed),
        Method::Pem => (OLIVE, Dash::Dashed),
    };
    Look { color, dash }
}

/// The looks of a run's estimators, by label (see the module documentation).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct EstimatorLooks {
    looks: Vec<(String, Look)>,
}

impl EstimatorLooks {
    /// The looks of `estimators` (label, method), in the run's order; a repeated label keeps its
    /// first look.
    pub fn new<'a>(estimators: impl IntoIterator<Item = (&'a str, Method)>) -> EstimatorLooks {
        let mut list: Vec<(&str, Method)> = Vec::new();
        for (label, method) in estimators {
            if !list.iter().any(|(l, _)| *l == label) {
                list.push((label, method));
            }
        }
        // Who has the method's own look: the estimator named after it, else the first of it.
        let home = |i: usize| {
            let (label, method) = list[i];
            label == method.name()
                || (!list.iter().any(|(l, m)| *m == method && *l == method.name())
                    && list.iter().position(|(_, m)| *m == method) == Some(i))
        };
        let mut looks: Vec<(String, Option<Look>)> = (0..list.len())
            .map(|i| (list[i].0.to_string(), home(i).then(|| method_look(list[i].1))))
            .collect();
        for i in 0..looks.len() {
            if looks[i].1.is_none() {
                let taken: Vec<Look> = looks.iter().filter_map(|(_, l)| *l).collect();
                looks[i].1 = Some(free_look(&taken));
            }
        }
        EstimatorLooks { looks: looks.into_iter().map(|(l, look)| (l, look.unwrap_or(FALLBACK))).collect() }
    }

    /// The look of the estimator labelled `label`; a label the run does not have is drawn
    /// dash-dotted in rose.
    pub fn look(&self, label: &str) -> Look {
        self.looks.iter().find(|(l, _)| l == label).map_or(FALLBACK, |(_, look)| *look)
    }

    /// Every label with its look, in the run's order.
    pub fn iter(&self) -> impl Iterator<Item = (&str, Look)> {
        self.looks.iter().map(|(l, look)| (l.as_str(), *look))
    }
}

const FALLBACK: Look = Look { color: ROSE, dash: Dash::DashDot };

/// The first palette colour no look in `taken` has, solid; else the first (dash, colour) pair
/// not taken; else (more than 36 looks) the first palette colour dash-dotted.
fn free_look(taken: &[Look]) -> Look {
    if let Some(color) = PALETTE.iter().find(|c| !taken.iter().any(|l| l.color == **c)) {
        return Look { color: *color, dash: Dash::Solid };
    }
    Dash::ALL
        .iter()
        .flat_map(|dash| PALETTE.iter().map(move |color| Look { color: *color, dash: *dash }))
        .find(|l| !taken.contains(l))
        .unwrap_or(FALLBACK)
}

/// What one estimator of a [`PathFigure`] contributed.
#[derive(Debug, Clone, Copy)]
pub enum Outcome<'a> {
    /// Its estimate.
    Estimate(&'a PathEstimate),
    /// No estimate, and why (an error message, "no path in this run", …).
    Missing(&'a str),
}

/// The paths of several estimators on one record, as small multiples: a header row with one
/// overview panel per state (the truth, the data and every path, no bands, with the legend),
/// then one panel per estimator and state (the truth, the data, that estimator's path and its
/// ±2 sd band where it has one). All panels of a state share their axes. Every title says what
/// is drawn: the overview that it has no bands, an estimator's panel what its band is, or why
/// it has no band or no path.
#[derive(Debug, Clone)]
pub struct PathFigure<'a> {
    /// Title above the figure.
    pub title: String,
    /// The state names (as the paths name their columns).
    pub states: &'a [String],
    /// The true path, when known.
    pub truth: Option<&'a StatePath>,
    /// The measurements.
    pub data: &'a Dataset,
    /// The state each data column measures (`StateMeasurement::states`).
    pub measured: &'a [usize],
    /// The estimators by label, in order.
    pub estimates: Vec<(&'a str, Outcome<'a>)>,
    /// The run's looks.
    pub looks: &'a EstimatorLooks,
}

/// Width of the figure's canvas in logical pixels.
const FIGURE_WIDTH: u32 = 1260;
/// Height of an overview panel.
const OVERVIEW_HEIGHT: u32 = 360;
/// Height of an estimator's panel.
const PANEL_HEIGHT: u32 = 250;
/// Line width of the truth: thinner than the paths, which it would otherwise hide.
const TRUTH_WIDTH: f64 = 0.9;
/// Line width of the estimated paths.
const PATH_WIDTH: f64 = 1.8;
/// Logical pixels per character of a title's second line, at most (for line breaks).
const SUBTITLE_CHAR: f64 = 7.0;
/// Most points of the truth drawn (the simulation grid can be much finer than the figure).
const TRUTH_POINTS: usize = 4000;

/// The axes shared by the panels of one state.
#[derive(Debug, Clone, Copy)]
struct Frame {
    x: Option<(f64, f64)>,
    y: Option<(f64, f64)>,
}

impl PathFigure<'_> {
    /// The figure (write it with [`Panels::write`]): the overviews in the header row; the
    /// estimators' panels row by row, one column per state for a multi-state model, else two
    /// or three columns.
    pub fn panels(&self) -> Panels<LinePlot> {
        let columns = self.columns();
        let x = self.x_range();
        let frames: Vec<Frame> = (0..self.states.len()).map(|a| Frame { x, y: self.y_range(a) }).collect();
        let header = (0..self.states.len()).map(|a| self.overview(a, frames[a])).collect();
        let cells = self.estimates.len() * self.states.len();
        // The time axis is named under the last row only.
        let last_row = cells.saturating_sub(1) / columns * columns;
        let mut panels = Vec::with_capacity(cells);
        for (label, outcome) in &self.estimates {
            for (a, frame) in frames.iter().enumerate() {
                let named = panels.len() >= last_row;
                panels.push(self.estimator_panel(label, *outcome, a, *frame, named, columns));
            }
        }
        Panels { title: self.title.clone(), header, panels, columns }
    }

    /// Columns of the estimators' panels: one per state, or for one state 2 (at most two
    /// estimators, or four) or 3.
    fn columns(&self) -> usize {
        let n = self.estimates.len();
        match self.states.len() {
            0 | 1 if n <= 2 || n == 4 => 2,
            0 | 1 => 3,
            states => states,
        }
    }

    /// The overview of state `a`: the truth, every path without its band, the data; the legend
    /// in the first state's overview.
    fn overview(&self, a: usize, frame: Frame) -> LinePlot {
        let paths = self.estimates.iter().filter_map(|(label, o)| match o {
            Outcome::Estimate(e) => self.path_series(label, e, a, false).map(|(s, _)| s),
            Outcome::Missing(_) => None,
        });
        let title = format!(
            "{}: every estimate\npaths only, no bands; one panel per estimator below",
            self.states[a]
        );
        let width = FIGURE_WIDTH / self.states.len().max(1) as u32;
        LinePlot {
            legend: a == 0,
            ..self.plot(
                a,
                title,
                self.with_context(a, paths.collect()),
                frame,
                (width, OVERVIEW_HEIGHT),
                true,
            )
        }
    }

    /// The panel of estimator `label` and state `a`: the truth, its path with its band, the
    /// data; titled with what is drawn.
    fn estimator_panel(
        &self,
        label: &str,
        outcome: Outcome<'_>,
        a: usize,
        frame: Frame,
        x_named: bool,
        columns: usize,
    ) -> LinePlot {
        let mut head = label.to_string();
        if self.states.len() > 1 {
            head.push_str(&format!(" ({})", self.states[a]));
        }
        let (path, what) = match outcome {
            Outcome::Estimate(e) => {
                if e.status != Status::Converged {
                    head.push_str(&format!(" [{}]", e.status.name()));
                }
                match self.path_series(label, e, a, true) {
                    Some((s, what)) => (vec![s], what),
                    None => (vec![], "no path of this state".to_string()),
                }
            }
            Outcome::Missing(why) => (vec![], format!("no estimate: {}", why.lines().next().unwrap_or(""))),
        };
        let size = (FIGURE_WIDTH / columns as u32, PANEL_HEIGHT);
        let what = wrap(&what, (f64::from(size.0) / SUBTITLE_CHAR) as usize);
        let series = self.with_context(a, path);
        LinePlot { legend: false, ..self.plot(a, format!("{head}\n{what}"), series, frame, size, x_named) }
    }

    /// A panel of state `a` in `frame`.
    fn plot(
        &self,
        a: usize,
        title: String,
        series: Vec<Series>,
        frame: Frame,
        size: (u32, u32),
        x_named: bool,
    ) -> LinePlot {
        LinePlot {
            title,
            x_label: if x_named { "t".into() } else { String::new() },
            y_label: self.states[a].clone(),
            series,
            x_range: frame.x,
            y_range: frame.y,
            legend: true,
            width: size.0,
            height: size.1,
        }
    }

    /// `paths` between the truth of state `a` (under them) and its data (over them).
    fn with_context(&self, a: usize, paths: Vec<Series>) -> Vec<Series> {
        let mut series = Vec::new();
        if let Some(t) = self.truth {
            if let Some(j) = t.names.iter().position(|n| *n == self.states[a]) {
                let stride = t.times.len().div_ceil(TRUTH_POINTS).max(1);
                let x = t.times.iter().step_by(stride).copied().collect();
                let y = t.values.iter().step_by(stride).map(|r| r[j]).collect();
                let truth = Series::line("truth", x, y).with_look(TRUTH, Dash::Solid);
                series.push(truth.with_width(TRUTH_WIDTH));
            }
        }
        series.extend(paths);
        for c in (0..self.measured.len()).filter(|&c| self.measured[c] == a) {
            let name = if self.data.names.len() > 1 {
                format!("data {}", self.data.names[c])
            } else {
                "data".into()
            };
            let y = self.data.values.iter().map(|r| r[c]).collect();
            series.push(Series::points(name, self.data.times.clone(), y).with_look(DATA, Dash::Solid));
        }
        series
    }

    /// The path of state `a` of estimate `e`, labelled and in the look of estimator `label`,
    /// with its ±2 sd band when `band` and it has one; and what is drawn ("path ± 2 sd (its
    /// kind)", or "path, no sd (why)"). `None` when the estimate has no such state.
    fn path_series(&self, label: &str, e: &PathEstimate, a: usize, band: bool) -> Option<(Series, String)> {
        let j = e.path.names.iter().position(|n| *n == self.states[a])?;
        let look = self.looks.look(label);
        let y: Vec<f64> = e.path.values.iter().map(|r| r[j]).collect();
        let line = Series::line(label, e.path.times.clone(), y)
            .with_look(look.color, look.dash)
            .with_width(PATH_WIDTH);
        let sd: Option<Vec<f64>> = e.path.sd.as_ref().map(|sd| sd.iter().map(|r| r[j]).collect());
        match sd {
            Some(sd) if sd.iter().any(|v| v.is_finite()) => {
                let what = match e.details["sd"].as_str() {
                    Some(kind) => format!("path ± 2 sd ({kind})"),
                    None => "path ± 2 sd".to_string(),
                };
                let line = if band { line.with_sd_band(&sd, 2.0) } else { line };
                Some((line, what))
            }
            Some(_) => Some((line, "path, no sd (not finite)".to_string())),
            None => Some((line, format!("path, no sd ({})", no_sd_reason(e)))),
        }
    }

    /// The range of the times of the truth, the data and the paths.
    fn x_range(&self) -> Option<(f64, f64)> {
        let mut times: Vec<f64> = self.data.times.clone();
        if let Some(t) = self.truth {
            times.extend(t.times.first().into_iter().chain(t.times.last()));
        }
        for (_, o) in &self.estimates {
            if let Outcome::Estimate(e) = o {
                times.extend(e.path.times.first().into_iter().chain(e.path.times.last()));
            }
        }
        finite_range(times.into_iter(), 0.0)
    }

    /// The y range of state `a` shared by its panels: the truth, the data and the paths, and
    /// the bands as far as a quarter of that range beyond it (a band wider than that is cut at
    /// the panel's edge), with 4 % margins.
    fn y_range(&self, a: usize) -> Option<(f64, f64)> {
        let name = &self.states[a];
        let mut core: Vec<f64> = Vec::new();
        let mut bands: Vec<f64> = Vec::new();
        if let Some(t) = self.truth {
            if let Some(j) = t.names.iter().position(|n| n == name) {
                core.extend(t.values.iter().map(|r| r[j]));
            }
        }
        for (c, _) in self.measured.iter().enumerate().filter(|(_, s)| **s == a) {
            core.extend(self.data.values.iter().map(|r| r[c]));
        }
        for (_, o) in &self.estimates {
            let Outcome::Estimate(e) = o else { continue };
            let Some(j) = e.path.names.iter().position(|n| n == name) else { continue };
            core.extend(e.path.values.iter().map(|r| r[j]));
            if let Some(sd) = &e.path.sd {
                for (r, s) in e.path.values.iter().zip(sd) {
                    bands.extend([r[j] - 2.0 * s[j], r[j] + 2.0 * s[j]]);
                }
            }
        }
        let (lo, hi) = finite_range(core.into_iter(), 0.0)?;
        let reach = 0.25 * (hi - lo).max(f64::EPSILON * hi.abs().max(1.0));
        let (blo, bhi) = finite_range(bands.into_iter(), 0.0).unwrap_or((lo, hi));
        finite_range([lo, hi, blo.max(lo - reach), bhi.min(hi + reach)].into_iter(), 0.04)
    }
}

/// The smallest and largest finite values, widened by `pad` of their span on each side (a
/// single value by ±0.5); `None` without finite values.
fn finite_range(values: impl Iterator<Item = f64>, pad: f64) -> Option<(f64, f64)> {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)));
    if !lo.is_finite() {
        return None;
    }
    if hi - lo <= 1e-12 * lo.abs().max(hi.abs()).max(1e-300) {
        return Some((lo - 0.5, hi + 0.5));
    }
    let p = pad * (hi - lo);
    Some((lo - p, hi + p))
}

/// Why estimate `e` has no sd: the MAP estimators say why ([`LaplaceSd`]), other methods by
/// the `sd` entry of their details where they have one.
fn no_sd_reason(e: &PathEstimate) -> String {
    match e.details.get::<PathDetails>().map(|d| d.sd) {
        Some(LaplaceSd::Skipped { max_states: 0, .. }) => "Laplace sd off: laplace_max_states = 0".into(),
        Some(LaplaceSd::Skipped { max_states, .. }) => {
            format!("Laplace skipped above {max_states} node states; raise laplace_max_states")
        }
        Some(LaplaceSd::NotSolved) => "the solve did not succeed".into(),
        Some(LaplaceSd::NotAMaximum) => "not a strict maximum".into(),
        Some(LaplaceSd::Off) => "Laplace sd not asked for".into(),
        Some(LaplaceSd::ParametersOnly) => "Laplace sd of the parameters only".into(),
        Some(LaplaceSd::Computed) => "none reported".into(),
        None => match e.details["sd"].as_str() {
            Some(what) => what.to_string(),
            None => format!("{} reports none", e.method),
        },
    }
}

/// `text` in at most two lines of at most `width` characters, broken at spaces, with "…" where
/// it is cut.
fn wrap(text: &str, width: usize) -> String {
    let width = width.max(8);
    let mut lines: Vec<String> = Vec::new();
    for word in text.split(' ') {
        match lines.last_mut() {
            Some(line) if line.chars().count() + 1 + word.chars().count() <= width => {
                line.push(' ');
                line.push_str(word);
            }
            _ => lines.push(word.to_string()),
        }
    }
    let more = lines.len() > 2;
    lines.truncate(2);
    let n = lines.len();
    for (i, line) in lines.iter_mut().enumerate() {
        let cut = more && i + 1 == n;
        if line.chars().count() > width || (cut && line.chars().count() == width) {
            *line = line.chars().take(width - 1).collect::<String>() + "…";
        } else if cut {
            line.push('…');
        }
    }
    lines.join("\n")
}

/// A box of a box plot: `values` of the successful rows of an estimator in its look's colour,
/// and the number of its rows that `failed` (stated under the box with `n = drawn/rows`).
pub fn box_group(label: &str, values: Vec<f64>, failed: usize, looks: &EstimatorLooks) -> BoxGroup {
    BoxGroup { label: label.to_string(), values, failed, color: Some(looks.look(label).color) }
}

#[cfg(test)]
mod tests;
