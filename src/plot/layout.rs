//! Layout: line plots, box plots and panel grids turned into a [`Scene`].

use super::font::{text_width, CAP_HEIGHT};
use super::scene::{Anchor, Color, Dash, Prim, Rect, Scene, PALETTE};
use super::stats::BoxStats;
use super::ticks::{format_log_ticks, format_ticks, linear_ticks, log_ticks, widen};
use super::{BoxGroup, BoxPlot, LinePlot, Panels, Series, SeriesStyle};
use crate::{Error, Result};

const TICK_FONT: f64 = 12.0;
const LABEL_FONT: f64 = 13.0;
const TITLE_FONT: f64 = 16.0;
const LEGEND_FONT: f64 = 12.0;
const NOTE_FONT: f64 = 12.0;
const TICK_LEN: f64 = 5.0;
const LINE_WIDTH: f64 = 1.6;
const MARKER_R: f64 = 2.6;
const BAND_ALPHA: f32 = 0.2;
/// Coordinates are clamped to this many pixels so that extreme values (outside the clip
/// rectangle anyway) never produce infinite or NaN coordinates.
const COORD_LIMIT: f64 = 1e6;

/// The colour and dash pattern of the `i`-th of a plot's series or groups without a colour of
/// their own: the palette, then the palette with each further dash pattern.
fn palette_look(i: usize) -> (Color, Dash) {
    (PALETTE[i % PALETTE.len()], Dash::ALL[(i / PALETTE.len()) % Dash::ALL.len()])
}

/// The colour and dash pattern series `s`, the `i`-th of its plot, is drawn with.
fn series_look(s: &Series, i: usize) -> (Color, Vec<f64>) {
    let (color, dash) = s.color.map_or_else(|| palette_look(i), |c| (c, s.dash));
    (color, dash.pattern())
}

/// The colour of box group `g`, the `i`-th of its plot.
fn group_color(g: &BoxGroup, i: usize) -> Color {
    g.color.unwrap_or_else(|| palette_look(i).0)
}

/// A numeric axis: its range, whether logarithmic, ticks (as values) and their labels.
struct Axis {
    lo: f64,
    hi: f64,
    log: bool,
    ticks: Vec<f64>,
    labels: Vec<String>,
}

impl Axis {
    /// `lo`..`hi` are data values (> 0 when `log`); `pad` is the fraction added on each side.
    fn new(lo: f64, hi: f64, log: bool, pad: f64, target: usize) -> Axis {
        if log {
            let (a, b) = widen(lo.log10(), hi.log10());
            let p = (b - a) * pad;
            let (a, b) = (a - p, b + p);
            let ticks = log_ticks(10f64.powf(a), 10f64.powf(b), target);
            let labels = format_log_ticks(&ticks);
            Axis { lo: a, hi: b, log, ticks, labels }
        } else {
            let (a, b) = widen(lo, hi);
            let p = (b - a) * pad;
            let (a, b) = (a - p, b + p);
            let (ticks, step) = linear_ticks(a, b, target);
            let labels = format_ticks(&ticks, step);
            Axis { lo: a, hi: b, log, ticks, labels }
        }
    }

    /// Position of value `v` as a fraction of the axis length (not clamped).
    fn frac(&self, v: f64) -> f64 {
        let v = if self.log { v.log10() } else { v };
        (v - self.lo) / (self.hi - self.lo)
    }

    fn max_label_width(&self) -> f64 {
        self.labels.iter().map(|l| text_width(l, TICK_FONT)).fold(0.0, f64::max)
    }
}

fn clamp_coord(v: f64) -> f64 {
    if v.is_nan() {
        0.0
    } else {
        v.clamp(-COORD_LIMIT, COORD_LIMIT)
    }
}

fn px(r: &Rect, ax: &Axis, v: f64) -> f64 {
    clamp_coord(r.x + ax.frac(v) * r.w)
}

fn py(r: &Rect, ax: &Axis, v: f64) -> f64 {
    clamp_coord(r.bottom() - ax.frac(v) * r.h)
}

/// `size`, or smaller (down to 60 %) so that `text` fits in `width`.
fn fit_size(text: &str, size: f64, width: f64) -> f64 {
    let w = text_width(text, size);
    if w <= width || w <= 0.0 {
        size
    } else {
        (size * width / w).max(0.6 * size)
    }
}

/// Size of the lines of a title after its first.
const SUBTITLE_FONT: f64 = 12.0;

/// Title at the top of `area`: its first line at the title size, further lines (after `\n`)
/// smaller in the note colour; returns the y where the content may start.
fn draw_title(scene: &mut Scene, area: &Rect, title: &str) -> f64 {
    if title.trim().is_empty() {
        return area.y + 12.0;
    }
    let mut y = area.y + 10.0;
    for (i, line) in title.lines().enumerate() {
        let (font, color) = if i == 0 { (TITLE_FONT, Color::TEXT) } else { (SUBTITLE_FONT, Color::NOTE) };
        // A long line is set smaller rather than cut at the canvas edges.
        let size = fit_size(line, font, area.w - 20.0);
        y += CAP_HEIGHT * font;
        scene.text(area.x + area.w / 2.0, y, line, size, Anchor::Middle, color);
        y += if i == 0 { 8.0 } else { 6.0 } + (1.0 - CAP_HEIGHT) * font;
    }
    y + 8.0
}

fn left_margin(y_axis: &Axis, y_label: &str) -> f64 {
    let label = if y_label.trim().is_empty() { 0.0 } else { LABEL_FONT + 10.0 };
    10.0 + label + y_axis.max_label_width() + TICK_LEN + 5.0
}

/// Grid lines and the y axis (ticks, labels, axis label) for plot rectangle `plot`.
fn draw_y_axis(scene: &mut Scene, area: &Rect, plot: &Rect, y: &Axis, y_label: &str) {
    for (t, label) in y.ticks.iter().zip(&y.labels) {
        let yy = py(plot, y, *t);
        scene.line(vec![(plot.x, yy), (plot.right(), yy)], Color::GRID, 1.0, None);
        scene.line(vec![(plot.x - TICK_LEN, yy), (plot.x, yy)], Color::AXIS, 1.0, None);
        scene.text(
            plot.x - TICK_LEN - 4.0,
            yy + CAP_HEIGHT * TICK_FONT / 2.0,
            label,
            TICK_FONT,
            Anchor::End,
            Color::TEXT,
        );
    }
    if !y_label.trim().is_empty() {
        scene.prims.push(Prim::Text {
            x: area.x + 10.0 + CAP_HEIGHT * LABEL_FONT,
            y: plot.y + plot.h / 2.0,
            text: y_label.to_string(),
            size: LABEL_FONT,
            anchor: Anchor::Middle,
            angle: -90.0,
            color: Color::TEXT,
        });
    }
}

fn draw_frame(scene: &mut Scene, plot: &Rect) {
    scene.prims.push(Prim::Rect { rect: *plot, fill: None, stroke: Some((Color::AXIS, 1.0)), clip: None });
}

fn note(scene: &mut Scene, plot: &Rect, text: &str) {
    scene.text(plot.x + plot.w / 2.0, plot.y + plot.h / 2.0, text, NOTE_FONT, Anchor::Middle, Color::NOTE);
}

fn check_size(what: &str, width: u32, height: u32) -> Result<()> {
    if !(120..=20_000).contains(&width) || !(80..=20_000).contains(&height) {
        return Err(Error::InvalidOption {
            name: format!("{what}.width/height"),
            reason: format!("{width}×{height} is outside 120×80 … 20000×20000"),
        });
    }
    Ok(())
}

/// Maximal runs of consecutive indices for which `ok` holds (lines break at missing values).
fn runs(n: usize, ok: impl Fn(usize) -> bool) -> Vec<std::ops::Range<usize>> {
    let mut out = vec![];
    let mut start = None;
    for i in 0..=n {
        let good = i < n && ok(i);
        match (good, start) {
            (true, None) => start = Some(i),
            (false, Some(s)) => {
                out.push(s..i);
                start = None;
            }
            _ => {}
        }
    }
    out
}

pub(crate) fn validate_line_plot(p: &LinePlot) -> Result<()> {
    check_size("LinePlot", p.width, p.height)?;
    for (name, range) in [("x_range", p.x_range), ("y_range", p.y_range)] {
        if let Some((lo, hi)) = range {
            if !(lo.is_finite() && hi.is_finite() && lo < hi) {
                return Err(Error::InvalidOption {
                    name: format!("LinePlot.{name}"),
                    reason: format!("({lo}, {hi}) is not a finite increasing range"),
                });
            }
        }
    }
    for s in &p.series {
        let n = s.x.len();
        let mismatch = |what: &str, got: usize| Error::DimensionMismatch {
            what: format!("series `{}`: {what}", s.label),
            expected: n,
            got,
        };
        if s.y.len() != n {
            return Err(mismatch("y versus x", s.y.len()));
        }
        if let Some((lo, hi)) = &s.band {
            if lo.len() != n {
                return Err(mismatch("band lower versus x", lo.len()));
            }
            if hi.len() != n {
                return Err(mismatch("band upper versus x", hi.len()));
            }
        }
    }
    Ok(())
}

/// The ranges (x0, x1, y0, y1) of the finite points of a line plot, bands included; `None` when
/// it has none.
fn data_range(p: &LinePlot) -> Option<(f64, f64, f64, f64)> {
    let (mut x0, mut x1, mut y0, mut y1) =
        (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
    for s in &p.series {
        for i in 0..s.x.len() {
            let x = s.x[i];
            if !x.is_finite() {
                continue;
            }
            let mut ys = vec![s.y[i]];
            if let Some((lo, hi)) = &s.band {
                ys.push(lo[i]);
                ys.push(hi[i]);
            }
            for y in ys.into_iter().filter(|y| y.is_finite()) {
                x0 = x0.min(x);
                x1 = x1.max(x);
                y0 = y0.min(y);
                y1 = y1.max(y);
            }
        }
    }
    (x0.is_finite() && y0.is_finite()).then_some((x0, x1, y0, y1))
}

/// The screen positions of a line plot's finite points, of the midpoints of its line segments
/// and of its band ends: what a legend inside the plot would hide.
fn screen_points(p: &LinePlot, plot: &Rect, x_axis: &Axis, y_axis: &Axis) -> Vec<(f64, f64)> {
    let mut pts = vec![];
    for s in &p.series {
        let mut push = |x: f64, y: f64| {
            if x.is_finite() && y.is_finite() {
                pts.push((px(plot, x_axis, x), py(plot, y_axis, y)));
            }
        };
        for i in 0..s.x.len() {
            push(s.x[i], s.y[i]);
            if i + 1 < s.x.len() && !matches!(s.style, SeriesStyle::Points) {
                push((s.x[i] + s.x[i + 1]) / 2.0, (s.y[i] + s.y[i + 1]) / 2.0);
            }
            if let Some((lo, hi)) = &s.band {
                push(s.x[i], lo[i]);
                push(s.x[i], hi[i]);
            }
        }
    }
    pts
}

/// Grid lines and the x axis (ticks, labels, axis label) for plot rectangle `plot`.
fn draw_x_axis(scene: &mut Scene, area: &Rect, plot: &Rect, x: &Axis, x_label: &str) {
    for (t, label) in x.ticks.iter().zip(&x.labels) {
        let xx = px(plot, x, *t);
        scene.line(vec![(xx, plot.y), (xx, plot.bottom())], Color::GRID, 1.0, None);
        scene.line(vec![(xx, plot.bottom()), (xx, plot.bottom() + TICK_LEN)], Color::AXIS, 1.0, None);
        scene.text(
            xx,
            plot.bottom() + TICK_LEN + 4.0 + CAP_HEIGHT * TICK_FONT,
            label,
            TICK_FONT,
            Anchor::Middle,
            Color::TEXT,
        );
    }
    if !x_label.trim().is_empty() {
        scene.text(
            plot.x + plot.w / 2.0,
            area.bottom() - 10.0,
            x_label,
            LABEL_FONT,
            Anchor::Middle,
            Color::TEXT,
        );
    }
}

/// The bands of a line plot, then its lines and markers (so that every line is drawn over every
/// band), in `plot` with clip rectangle `clip`.
fn draw_series(
    scene: &mut Scene,
    p: &LinePlot,
    plot: &Rect,
    x_axis: &Axis,
    y_axis: &Axis,
    clip: Option<usize>,
) {
    for (k, s) in p.series.iter().enumerate() {
        let Some((lo, hi)) = &s.band else { continue };
        let (color, _) = series_look(s, k);
        for r in runs(s.x.len(), |i| s.x[i].is_finite() && lo[i].is_finite() && hi[i].is_finite()) {
            let mut pts: Vec<(f64, f64)> =
                r.clone().map(|i| (px(plot, x_axis, s.x[i]), py(plot, y_axis, hi[i]))).collect();
            pts.extend(r.rev().map(|i| (px(plot, x_axis, s.x[i]), py(plot, y_axis, lo[i]))));
            if pts.len() >= 4 {
                scene.prims.push(Prim::Polygon { points: pts, fill: color.with_alpha(BAND_ALPHA), clip });
            }
        }
    }
    for (k, s) in p.series.iter().enumerate() {
        let (color, dash) = series_look(s, k);
        let ok = |i: usize| s.x[i].is_finite() && s.y[i].is_finite();
        if matches!(s.style, SeriesStyle::Line | SeriesStyle::LineAndPoints) {
            for r in runs(s.x.len(), ok) {
                let pts: Vec<(f64, f64)> =
                    r.map(|i| (px(plot, x_axis, s.x[i]), py(plot, y_axis, s.y[i]))).collect();
                if pts.len() >= 2 {
                    scene.prims.push(Prim::Polyline {
                        points: pts,
                        color,
                        width: s.width.unwrap_or(LINE_WIDTH),
                        dash: dash.clone(),
                        clip,
                    });
                } else if matches!(s.style, SeriesStyle::Line) {
                    // An isolated point of a line would be invisible: mark it.
                    let (cx, cy) = pts[0];
                    scene.prims.push(Prim::Circle {
                        cx,
                        cy,
                        r: LINE_WIDTH,
                        fill: Some(color),
                        stroke: None,
                        clip,
                    });
                }
            }
        }
        if matches!(s.style, SeriesStyle::Points | SeriesStyle::LineAndPoints) {
            for i in (0..s.x.len()).filter(|i| ok(*i)) {
                scene.prims.push(Prim::Circle {
                    cx: px(plot, x_axis, s.x[i]),
                    cy: py(plot, y_axis, s.y[i]),
                    r: MARKER_R,
                    fill: Some(color.with_alpha(0.85)),
                    stroke: Some((Color::WHITE, 0.6)),
                    clip,
                });
            }
        }
    }
}

/// The legend of a line plot: its rows (the series with a label, in order), the height of a row
/// and the size of its box.
struct Legend {
    entries: Vec<usize>,
    row_h: f64,
    w: f64,
    h: f64,
}

impl Legend {
    fn new(p: &LinePlot) -> Legend {
        let entries: Vec<usize> = if p.legend {
            (0..p.series.len()).filter(|i| !p.series[*i].label.trim().is_empty()).collect()
        } else {
            Vec::new()
        };
        let row_h = LEGEND_FONT + 7.0;
        let label_w =
            entries.iter().map(|i| text_width(&p.series[*i].label, LEGEND_FONT)).fold(0.0, f64::max);
        let (w, h) = (10.0 + 26.0 + 6.0 + label_w + 10.0, 8.0 + row_h * entries.len() as f64);
        Legend { entries, row_h, w, h }
    }

    /// Draws the legend of `p` with its box's top left corner at (lx, ly).
    fn draw(&self, scene: &mut Scene, p: &LinePlot, (lx, ly): (f64, f64)) {
        let row_h = self.row_h;
        scene.prims.push(Prim::Rect {
            rect: Rect { x: lx, y: ly, w: self.w, h: self.h },
            fill: Some(Color::WHITE.with_alpha(0.88)),
            stroke: Some((Color::rgb(200, 200, 200), 1.0)),
            clip: None,
        });
        for (row, &k) in self.entries.iter().enumerate() {
            let s = &p.series[k];
            let (color, dash) = series_look(s, k);
            let cy = ly + 4.0 + row_h * (row as f64 + 0.5);
            let (sx0, sx1) = (lx + 10.0, lx + 36.0);
            if s.band.is_some() {
                scene.prims.push(Prim::Rect {
                    rect: Rect { x: sx0, y: cy - 5.0, w: sx1 - sx0, h: 10.0 },
                    fill: Some(color.with_alpha(BAND_ALPHA)),
                    stroke: None,
                    clip: None,
                });
            }
            if matches!(s.style, SeriesStyle::Line | SeriesStyle::LineAndPoints) {
                scene.prims.push(Prim::Polyline {
                    points: vec![(sx0, cy), (sx1, cy)],
                    color,
                    width: s.width.unwrap_or(LINE_WIDTH),
                    dash,
                    clip: None,
                });
            }
            if matches!(s.style, SeriesStyle::Points | SeriesStyle::LineAndPoints) {
                scene.prims.push(Prim::Circle {
                    cx: (sx0 + sx1) / 2.0,
                    cy,
                    r: MARKER_R,
                    fill: Some(color.with_alpha(0.85)),
                    stroke: Some((Color::WHITE, 0.6)),
                    clip: None,
                });
            }
            scene.text(
                sx1 + 6.0,
                cy + CAP_HEIGHT * LEGEND_FONT / 2.0,
                &s.label,
                LEGEND_FONT,
                Anchor::Start,
                Color::TEXT,
            );
        }
    }
}

/// Lay out a line plot in `area` of `scene`.
pub(crate) fn layout_line_plot(scene: &mut Scene, area: Rect, p: &LinePlot) -> Result<()> {
    validate_line_plot(p)?;
    let top = draw_title(scene, &area, &p.title);

    // Data ranges over finite points, bands included, unless the plot fixes them.
    let range = data_range(p);
    let empty = range.is_none();
    let (mut x0, mut x1, mut y0, mut y1) = range.unwrap_or((0.0, 1.0, 0.0, 1.0));
    if let Some((lo, hi)) = p.x_range {
        (x0, x1) = (lo, hi);
    }
    let y_pad = if let Some((lo, hi)) = p.y_range {
        (y0, y1) = (lo, hi);
        0.0
    } else {
        0.04
    };

    let has_x_label = !p.x_label.trim().is_empty();
    let bottom = area.bottom()
        - (TICK_LEN + 6.0 + TICK_FONT + 8.0 + if has_x_label { LABEL_FONT + 10.0 } else { 0.0 });
    let plot_h = (bottom - top).max(10.0);
    let y_axis = Axis::new(y0, y1, false, y_pad, (plot_h / 45.0).round().max(2.0) as usize);
    let left = area.x + left_margin(&y_axis, &p.y_label);
    let mut right = area.right() - 18.0;

    // Legend: inside the corner that hides the fewest data points, or outside on the right.
    let legend = Legend::new(p);
    let (leg_w, leg_h) = (legend.w, legend.h);
    let mut plot = Rect { x: left, y: top, w: (right - left).max(10.0), h: plot_h };
    // Time axes end at the data, except that markers at the ends get room.
    let x_pad = if p.x_range.is_none() && p.series.iter().any(|s| !matches!(s.style, SeriesStyle::Line)) {
        0.015
    } else {
        0.0
    };
    let mut x_axis = Axis::new(x0, x1, false, x_pad, (plot.w / 90.0).round().max(2.0) as usize);
    let mut legend_at = None;
    if !legend.entries.is_empty() && !empty {
        let inset = 8.0;
        let candidates = |plot: &Rect| {
            [
                (plot.right() - inset - leg_w, plot.y + inset),
                (plot.x + inset, plot.y + inset),
                (plot.right() - inset - leg_w, plot.bottom() - inset - leg_h),
                (plot.x + inset, plot.bottom() - inset - leg_h),
            ]
        };
        let pts = screen_points(p, &plot, &x_axis, &y_axis);
        let best = candidates(&plot)
            .into_iter()
            .map(|(lx, ly)| {
                let r = Rect { x: lx - 4.0, y: ly - 4.0, w: leg_w + 8.0, h: leg_h + 8.0 };
                (pts.iter().filter(|(x, y)| r.contains(*x, *y)).count(), (lx, ly))
            })
            .min_by_key(|(count, _)| *count);
        if let Some((count, at)) = best {
            let fits_outside = plot.w - leg_w - 12.0 > 0.55 * area.w;
            if count == 0 || !fits_outside {
                legend_at = Some(at);
            } else {
                right -= leg_w + 12.0;
                plot.w = (right - left).max(10.0);
                x_axis = Axis::new(x0, x1, false, x_pad, (plot.w / 90.0).round().max(2.0) as usize);
                legend_at = Some((plot.right() + 12.0, plot.y));
            }
        }
    }

    // Grid and axes.
    draw_y_axis(scene, &area, &plot, &y_axis, &p.y_label);
    draw_x_axis(scene, &area, &plot, &x_axis, &p.x_label);

    let clip = Some(scene.clip(plot));
    draw_series(scene, p, &plot, &x_axis, &y_axis, clip);
    draw_frame(scene, &plot);
    if empty {
        note(scene, &plot, "no finite data");
    }

    if let Some(at) = legend_at {
        legend.draw(scene, p, at);
    }
    Ok(())
}

pub(crate) fn validate_box_plot(p: &BoxPlot) -> Result<()> {
    check_size("BoxPlot", p.width, p.height)?;
    for (name, v) in &p.reference_lines {
        if !v.is_finite() || (p.log_y && *v <= 0.0) {
            return Err(Error::InvalidOption {
                name: format!("reference line `{name}`"),
                reason: format!("value {v} cannot be drawn{}", if p.log_y { " on a log axis" } else { "" }),
            });
        }
    }
    Ok(())
}

/// Distance between the baselines of the stacked lines of a box label.
const LABEL_LINE: f64 = TICK_FONT + 3.0;

/// The lines under a box: its label; `n = drawn/rows`; the failed rows and the skipped values,
/// if any.
fn box_label(g: &BoxGroup, s: Option<&BoxStats>) -> Vec<String> {
    let (drawn, skipped) = s.map_or((0, g.values.len()), |s| (s.n, s.skipped));
    let mut lines = vec![g.label.clone(), format!("n = {drawn}/{}", g.values.len() + g.failed)];
    let mut lost = vec![];
    if g.failed > 0 {
        lost.push(format!("{} failed", g.failed));
    }
    if skipped > 0 {
        lost.push(format!("{skipped} skipped"));
    }
    if !lost.is_empty() {
        lines.push(lost.join(", "));
    }
    lines
}

/// The label of the box centred at `cx` under the plot's bottom edge `bottom`: stacked lines
/// when `angle` is 0, else the lines joined and rotated.
fn draw_box_label(scene: &mut Scene, cx: f64, bottom: f64, lines: &[String], angle: f64) {
    let ty = bottom + TICK_LEN + 4.0 + CAP_HEIGHT * TICK_FONT;
    let text = lines.join("; ");
    let (x, y) = if angle == -90.0 {
        (cx + CAP_HEIGHT * TICK_FONT / 2.0, bottom + TICK_LEN + 4.0)
    } else {
        (cx + 4.0, ty)
    };
    if angle == 0.0 {
        for (i, line) in lines.iter().enumerate() {
            let color = if i == 0 { Color::TEXT } else { Color::NOTE };
            scene.text(cx, ty + LABEL_LINE * i as f64, line, TICK_FONT, Anchor::Middle, color);
        }
    } else {
        scene.prims.push(Prim::Text {
            x,
            y,
            text,
            size: TICK_FONT,
            anchor: Anchor::End,
            angle,
            color: Color::TEXT,
        });
    }
}

/// A Tukey box (`BoxStats`) centred at `center.0` with half-width `center.1`, in `color`; `y`
/// maps values to the canvas.
fn draw_box(
    scene: &mut Scene,
    b: &BoxStats,
    (cx, half): (f64, f64),
    color: Color,
    y: impl Fn(f64) -> f64,
    clip: Option<usize>,
) {
    // Whiskers with caps.
    for (from, to) in [(b.q1, b.whisker_low), (b.q3, b.whisker_high)] {
        scene.line(vec![(cx, y(from)), (cx, y(to))], Color::AXIS, 1.2, clip);
        scene.line(vec![(cx - half * 0.5, y(to)), (cx + half * 0.5, y(to))], Color::AXIS, 1.2, clip);
    }
    let (top_y, bot_y) = (y(b.q3), y(b.q1));
    scene.prims.push(Prim::Rect {
        rect: Rect { x: cx - half, y: top_y, w: 2.0 * half, h: (bot_y - top_y).max(0.0) },
        fill: Some(color.with_alpha(0.35)),
        stroke: Some((color, 1.4)),
        clip,
    });
    scene.line(vec![(cx - half, y(b.median)), (cx + half, y(b.median))], Color::TEXT, 2.2, clip);
    for o in &b.outliers {
        scene.prims.push(Prim::Circle {
            cx,
            cy: y(*o),
            r: MARKER_R,
            fill: None,
            stroke: Some((color, 1.1)),
            clip,
        });
    }
}

/// Lay out a box plot in `area` of `scene`.
pub(crate) fn layout_box_plot(scene: &mut Scene, area: Rect, p: &BoxPlot) -> Result<()> {
    validate_box_plot(p)?;
    let top = draw_title(scene, &area, &p.title);
    let log = p.log_y;
    let stats: Vec<Option<BoxStats>> =
        p.groups.iter().map(|g| BoxStats::from_values_where(&g.values, |v| !log || v > 0.0)).collect();
    let (mut y0, mut y1) = (f64::INFINITY, f64::NEG_INFINITY);
    for b in stats.iter().flatten() {
        for v in [b.whisker_low, b.whisker_high].iter().chain(&b.outliers) {
            y0 = y0.min(*v);
            y1 = y1.max(*v);
        }
    }
    for (_, v) in &p.reference_lines {
        y0 = y0.min(*v);
        y1 = y1.max(*v);
    }
    let empty = stats.iter().all(Option::is_none);
    if !(y0.is_finite() && y1.is_finite()) {
        (y0, y1) = if log { (1.0, 10.0) } else { (0.0, 1.0) };
    }

    let labels: Vec<Vec<String>> =
        p.groups.iter().zip(&stats).map(|(g, s)| box_label(g, s.as_ref())).collect();
    // Horizontal labels are stacked lines; slanted and vertical ones are the lines joined.
    let joined: Vec<String> = labels.iter().map(|l| l.join("; ")).collect();
    let max_line = labels.iter().flatten().map(|l| text_width(l, TICK_FONT)).fold(0.0, f64::max);
    let max_joined = joined.iter().map(|l| text_width(l, TICK_FONT)).fold(0.0, f64::max);
    let lines = labels.iter().map(Vec::len).max().unwrap_or(1) as f64;
    let n = p.groups.len().max(1);
    let right = area.right() - 18.0;
    // Label angle: horizontal when the labels fit their slots, −30° when the slanted labels
    // (TICK_FONT / sin 30° apart horizontally) do not overlap, else vertical.
    let bottom_for = |angle: f64| {
        let labels_h = if angle == 0.0 {
            lines * LABEL_LINE - (LABEL_LINE - TICK_FONT)
        } else {
            let a = angle.abs().to_radians();
            max_joined * a.sin() + TICK_FONT * a.cos()
        };
        area.bottom() - (TICK_LEN + 6.0 + labels_h + 10.0)
    };
    // Decide the label rotation with the unrotated layout, then lay out for good.
    let provisional = Axis::new(y0, y1, log, 0.05, ((bottom_for(0.0) - top) / 45.0).max(2.0) as usize);
    let slot = (right - area.x - left_margin(&provisional, &p.y_label)) / n as f64;
    let angle = if max_line <= 0.92 * slot {
        0.0
    } else if slot >= 2.0 * TICK_FONT + 2.0 {
        -30.0
    } else {
        -90.0
    };
    let bottom = bottom_for(angle);
    let plot_h = (bottom - top).max(10.0);
    let y_axis = Axis::new(y0, y1, log, 0.05, (plot_h / 45.0).round().max(2.0) as usize);
    // A slanted first label reaches left of its box by its width × cos 30°: keep it on the canvas.
    let first_reach = if angle == -30.0 {
        joined.first().map_or(0.0, |l| text_width(l, TICK_FONT) * 30f64.to_radians().cos() + 6.0)
    } else {
        0.0
    };
    let left = area.x + left_margin(&y_axis, &p.y_label).max(first_reach - slot / 2.0);
    let plot = Rect { x: left, y: top, w: (right - left).max(10.0), h: plot_h };
    let slot = plot.w / n as f64;

    draw_y_axis(scene, &area, &plot, &y_axis, &p.y_label);
    let clip = Some(scene.clip(plot));
    for (k, ((g, s), lines)) in p.groups.iter().zip(&stats).zip(&labels).enumerate() {
        let cx = plot.x + slot * (k as f64 + 0.5);
        scene.line(vec![(cx, plot.bottom()), (cx, plot.bottom() + TICK_LEN)], Color::AXIS, 1.0, None);
        draw_box_label(scene, cx, plot.bottom(), lines, angle);
        match s {
            Some(b) => {
                let half = (slot * 0.3).min(40.0);
                draw_box(scene, b, (cx, half), group_color(g, k), |v| py(&plot, &y_axis, v), clip);
            }
            None => scene.text(cx, plot.y + plot.h / 2.0, "no data", NOTE_FONT, Anchor::Middle, Color::NOTE),
        }
    }
    for (name, v) in &p.reference_lines {
        let yy = py(&plot, &y_axis, *v);
        scene.prims.push(Prim::Polyline {
            points: vec![(plot.x, yy), (plot.right(), yy)],
            color: Color::BLACK.with_alpha(0.75),
            width: 1.3,
            dash: vec![6.0, 4.0],
            clip,
        });
        if !name.trim().is_empty() {
            // On a light backdrop so that a box under the label does not hide it.
            let w = text_width(name, TICK_FONT);
            scene.prims.push(Prim::Rect {
                rect: Rect {
                    x: plot.right() - 7.0 - w,
                    y: yy - 5.0 - TICK_FONT,
                    w: w + 6.0,
                    h: TICK_FONT + 2.0,
                },
                fill: Some(Color::WHITE.with_alpha(0.8)),
                stroke: None,
                clip,
            });
            scene.text(plot.right() - 4.0, yy - 6.0, name, TICK_FONT, Anchor::End, Color::TEXT);
        }
    }
    draw_frame(scene, &plot);
    if empty {
        note(scene, &plot, if p.groups.is_empty() { "no groups" } else { "no finite data" });
    }
    Ok(())
}

/// Anything that lays itself out in a rectangle: what a panel grid holds.
pub trait Figure {
    /// Preferred size in logical pixels.
    fn size(&self) -> (u32, u32);
    /// Check the figure before drawing.
    ///
    /// # Errors
    /// As the figure's `write`.
    fn validate(&self) -> Result<()>;
    /// Add the figure to `scene` inside `area`.
    ///
    /// # Errors
    /// As the figure's `write`.
    fn layout(&self, scene: &mut Scene, area: Rect) -> Result<()>;
}

impl Figure for LinePlot {
    fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }
    fn validate(&self) -> Result<()> {
        validate_line_plot(self)
    }
    fn layout(&self, scene: &mut Scene, area: Rect) -> Result<()> {
        layout_line_plot(scene, area, self)
    }
}

impl Figure for BoxPlot {
    fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }
    fn validate(&self) -> Result<()> {
        validate_box_plot(self)
    }
    fn layout(&self, scene: &mut Scene, area: Rect) -> Result<()> {
        layout_box_plot(scene, area, self)
    }
}

/// A figure alone on its canvas.
pub(crate) fn single<F: Figure>(f: &F) -> Result<Scene> {
    f.validate()?;
    let (w, h) = f.size();
    let mut scene = Scene::new(f64::from(w), f64::from(h));
    f.layout(&mut scene, Rect { x: 0.0, y: 0.0, w: f64::from(w), h: f64::from(h) })?;
    Ok(scene)
}

/// Panels on a grid of `columns` columns, each cell as large as the largest panel, under a
/// title and the header row (whose panels share the width equally).
pub(crate) fn grid<F: Figure>(p: &Panels<F>) -> Result<Scene> {
    let (title, panels, header) = (&p.title, &p.panels, &p.header);
    if p.columns == 0 {
        return Err(Error::InvalidOption { name: "columns".into(), reason: "must be at least 1".into() });
    }
    for f in header.iter().chain(panels) {
        f.validate()?;
    }
    let cols = p.columns.min(panels.len().max(1));
    let rows = panels.len().div_ceil(cols);
    let cw = panels.iter().map(|f| f.size().0).max().unwrap_or(400);
    let ch = panels.iter().map(|f| f.size().1).max().unwrap_or(300);
    let header_h = f64::from(header.iter().map(|f| f.size().1).max().unwrap_or(0));
    let title_h = if title.trim().is_empty() { 0.0 } else { TITLE_FONT + 22.0 };
    let body_h =
        if panels.is_empty() && !header.is_empty() { 0.0 } else { f64::from(ch) * rows.max(1) as f64 };
    let (w, h) = (f64::from(cw) * cols as f64, title_h + header_h + body_h);
    if w * h > 1e8 {
        return Err(Error::InvalidOption {
            name: "panels".into(),
            reason: format!("{w}×{h} canvas is too large"),
        });
    }
    let mut scene = Scene::new(w, h);
    if title_h > 0.0 {
        let size = fit_size(title, TITLE_FONT, w - 20.0);
        scene.text(w / 2.0, 12.0 + CAP_HEIGHT * TITLE_FONT, title, size, Anchor::Middle, Color::TEXT);
    }
    if panels.is_empty() && header.is_empty() {
        let r = Rect { x: 0.0, y: title_h, w, h: h - title_h };
        note(&mut scene, &r, "no panels");
    }
    let header_w = w / header.len().max(1) as f64;
    for (i, f) in header.iter().enumerate() {
        f.layout(&mut scene, Rect { x: header_w * i as f64, y: title_h, w: header_w, h: header_h })?;
    }
    for (i, f) in panels.iter().enumerate() {
        let (r, c) = (i / cols, i % cols);
        let area = Rect {
            x: f64::from(cw) * c as f64,
            y: title_h + header_h + f64::from(ch) * r as f64,
            w: f64::from(cw),
            h: f64::from(ch),
        };
        f.layout(&mut scene, area)?;
    }
    Ok(scene)
}
