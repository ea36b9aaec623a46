//! Figures for `onsager compare` and the experiments: line plots of paths with data points and
//! ±2 sd bands, box plots of metrics and parameter estimates, and grids of panels, written
//! as SVG and PNG.
//!
//! ```no_run
//! use onsager::plot::{LinePlot, Series};
//! # fn main() -> onsager::Result<()> {
//! let t: Vec<f64> = (0..50).map(|i| i as f64 * 0.1).collect();
//! let x: Vec<f64> = t.iter().map(|t| t.sin()).collect();
//! let plot = LinePlot {
//!     title: "estimate".into(),
//!     x_label: "t".into(),
//!     y_label: "x".into(),
//!     series: vec![Series::line("sin", t.clone(), x.clone())
//!         .with_band(x.iter().map(|v| v - 0.2).collect(), x.iter().map(|v| v + 0.2).collect())],
//!     ..LinePlot::default()
//! };
//! plot.write(std::path::Path::new("out/sine"))?; // out/sine.svg and out/sine.png
//! # Ok(()) }
//! ```
//!
//! ## Design
//!
//! The layout code (nice 1-2-5 ticks, margins measured from the text, legend placed in the
//! corner that hides the fewest data points, or outside on the right) builds one [`Scene`]: a
//! list of primitives (polyline, filled polygon, rectangle, circle, text with an anchor and a
//! rotation, clip rectangles) in logical pixels. Two renderers draw it:
//!
//! - [`render_svg`] writes SVG elements as strings (no dependency);
//! - [`render_png`] rasterises with `tiny-skia` (pure Rust, anti-aliased, writes PNG), at twice
//!   the logical size by default ([`PNG_SCALE`]).
//!
//! Text is measured and, in PNGs, drawn from a subset of DejaVu Sans embedded in the library
//! (30 kB; ASCII, Latin-1, Greek and common math symbols; glyph outlines read with
//! `ttf-parser`), so figures are identical on every machine: no system fonts, no fontconfig,
//! no C library. Characters outside the subset are drawn as '?' in PNGs. SVG text names the
//! same family first, so browsers with DejaVu or the metrically similar Verdana show the
//! layout as measured.
//!
//! A series or box group has a colour (and a series a dash pattern and width) of its own, or
//! takes the next [`PALETTE`] colour by its position, dashed after the ninth. The palette is
//! Paul Tol's colour-blind-safe "muted" scheme; black ([`TRUTH`]) and grey ([`DATA`]) are not
//! in it, so that a true path and measurements drawn in them never share an estimate's colour.
//! [`crate::figures`] gives every estimator a fixed look. A title's lines after the first
//! (`\n`) are set smaller, in grey, e.g. what a panel draws.
//!
//! Degenerate input is drawn, not refused: lines break at NaN, a single point or constant
//! data gets a widened range, all-NaN data gives empty axes with a note, a box group with no
//! finite value says "no data". Size mismatches and undrawable options are errors.
//! Coordinates in the output are always finite.

mod font;
mod layout;
mod raster;
mod scene;
mod stats;
mod svg;
mod ticks;

pub use layout::Figure;
pub use raster::{render_pixmap, render_png};
pub use scene::{Anchor, Color, Dash, Prim, Rect, Scene, DATA, PALETTE, TRUTH};
pub use stats::{quantile, BoxStats};
pub use svg::render_svg;

use crate::{Error, Result};
use std::path::{Path, PathBuf};

/// Device pixels per logical pixel in the PNGs written by `write` (a 900×500 plot is a
/// 1800×1000 PNG, crisp on screens and in documents).
pub const PNG_SCALE: f64 = 2.0;

/// How a series is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SeriesStyle {
    /// A line through the points, broken at non-finite values.
    #[default]
    Line,
    /// Markers only (e.g. measurements).
    Points,
    /// A line with markers.
    LineAndPoints,
}

/// One curve of a [`LinePlot`], with an optional band (drawn translucent in the series colour).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Series {
    /// Its colour; `None` takes the plot's next [`PALETTE`] colour by position (dashed after
    /// the ninth).
    pub color: Option<Color>,
    /// Its dash pattern (with an explicit `color`).
    pub dash: Dash,
    /// Its line width in logical pixels (`None`: 1.6).
    pub width: Option<f64>,
    /// Legend text; series with an empty label are not in the legend.
    pub label: String,
    /// Abscissae.
    pub x: Vec<f64>,
    /// Ordinates, as many as `x`.
    pub y: Vec<f64>,
    /// Lower and upper band edges (e.g. ±2 sd), as many as `x`.
    pub band: Option<(Vec<f64>, Vec<f64>)>,
    /// Line, points or both.
    pub style: SeriesStyle,
}

impl Series {
    /// A line series.
    pub fn line(label: impl Into<String>, x: Vec<f64>, y: Vec<f64>) -> Series {
        Series { label: label.into(), x, y, style: SeriesStyle::Line, ..Series::default() }
    }
    /// A series of markers.
    pub fn points(label: impl Into<String>, x: Vec<f64>, y: Vec<f64>) -> Series {
        Series { label: label.into(), x, y, style: SeriesStyle::Points, ..Series::default() }
    }
    /// With a band between `lower` and `upper`.
    pub fn with_band(mut self, lower: Vec<f64>, upper: Vec<f64>) -> Series {
        self.band = Some((lower, upper));
        self
    }
    /// With a ±`k`·sd band around `y` (non-finite sd leaves a gap in the band).
    pub fn with_sd_band(self, sd: &[f64], k: f64) -> Series {
        let edge = |sign: f64| -> Vec<f64> {
            let sd_at = |i: usize| sd.get(i).copied().unwrap_or(f64::NAN);
            self.y.iter().enumerate().map(|(i, y)| y + sign * k * sd_at(i)).collect()
        };
        let (lower, upper) = (edge(-1.0), edge(1.0));
        self.with_band(lower, upper)
    }
    /// With style `style`.
    pub fn with_style(mut self, style: SeriesStyle) -> Series {
        self.style = style;
        self
    }
    /// With line width `width`.
    pub fn with_width(mut self, width: f64) -> Series {
        self.width = Some(width);
        self
    }
    /// In colour `color` with dash pattern `dash`.
    pub fn with_look(mut self, color: Color, dash: Dash) -> Series {
        self.color = Some(color);
        self.dash = dash;
        self
    }
}

/// Curves against a common x axis, with a legend.
#[derive(Debug, Clone, PartialEq)]
pub struct LinePlot {
    /// Title above the axes (empty for none); lines after the first are set smaller.
    pub title: String,
    /// x-axis label.
    pub x_label: String,
    /// y-axis label.
    pub y_label: String,
    /// The curves: each in its own colour, or in order from [`PALETTE`].
    pub series: Vec<Series>,
    /// A fixed x range (lower, upper) instead of the data's, e.g. shared by small multiples;
    /// what lies outside is clipped.
    pub x_range: Option<(f64, f64)>,
    /// A fixed y range, as `x_range`.
    pub y_range: Option<(f64, f64)>,
    /// Whether the labelled series are listed in a legend (default true); small multiples
    /// whose titles name what they draw leave it to one panel.
    pub legend: bool,
    /// Width in logical pixels (default 900).
    pub width: u32,
    /// Height in logical pixels (default 500).
    pub height: u32,
}

impl Default for LinePlot {
    fn default() -> Self {
        LinePlot {
            title: String::new(),
            x_label: String::new(),
            y_label: String::new(),
            series: vec![],
            x_range: None,
            y_range: None,
            legend: true,
            width: 900,
            height: 500,
        }
    }
}

/// One box of a [`BoxPlot`]. Under its label the box states its count, `n = drawn/rows`, where
/// the rows are the values and the `failed` rows that have none; a third line gives the failed
/// rows and the values skipped (NaN and infinite values, and non-positive ones on a log axis).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct BoxGroup {
    /// Label under the box.
    pub label: String,
    /// The sample.
    pub values: Vec<f64>,
    /// Rows of the group without a value (e.g. failed runs), counted in `n = drawn/rows`.
    pub failed: usize,
    /// Its colour; `None` takes the next [`PALETTE`] colour by position.
    pub color: Option<Color>,
}

/// Tukey box plots ([`BoxStats`]) side by side, with optional horizontal reference lines.
#[derive(Debug, Clone, PartialEq)]
pub struct BoxPlot {
    /// Title above the axes (empty for none); lines after the first are set smaller.
    pub title: String,
    /// y-axis label.
    pub y_label: String,
    /// One box per group: each in its own colour, or in order from [`PALETTE`].
    pub groups: Vec<BoxGroup>,
    /// Dashed horizontal lines with their labels (e.g. a parameter's nominal value).
    pub reference_lines: Vec<(String, f64)>,
    /// Logarithmic y axis (default false).
    pub log_y: bool,
    /// Width in logical pixels (default 900).
    pub width: u32,
    /// Height in logical pixels (default 500).
    pub height: u32,
}

impl Default for BoxPlot {
    fn default() -> Self {
        BoxPlot {
            title: String::new(),
            y_label: String::new(),
            groups: vec![],
            reference_lines: vec![],
            log_y: false,
            width: 900,
            height: 500,
        }
    }
}

/// A grid of figures (e.g. one per state), `columns` wide, under a common title, with an
/// optional header row above it (e.g. an overview of the panels below). Each grid cell is as
/// large as the largest panel's `width`×`height`; the header panels share the grid's width
/// equally, as tall as the tallest of them.
#[derive(Debug, Clone, PartialEq)]
pub struct Panels<T> {
    /// Title above the grid (empty for none).
    pub title: String,
    /// The header row (empty for none).
    pub header: Vec<T>,
    /// The panels, row by row.
    pub panels: Vec<T>,
    /// Number of columns (≥ 1).
    pub columns: usize,
}

impl<T> Default for Panels<T> {
    fn default() -> Self {
        Panels { title: String::new(), header: vec![], panels: vec![], columns: 1 }
    }
}

/// `stem` with `.ext` appended (not replacing an extension: `out/run.1` gives `out/run.1.svg`).
fn with_ext(stem: &Path, ext: &str) -> PathBuf {
    let mut s = stem.as_os_str().to_owned();
    s.push(".");
    s.push(ext);
    PathBuf::from(s)
}

/// Write `scene` as `stem.svg` and `stem.png`, creating the parent directory.
///
/// # Errors
/// [`Error::Io`] naming the file that could not be written; rendering errors as
/// [`render_png`].
pub fn write_scene(scene: &Scene, stem: &Path) -> Result<()> {
    let png = render_png(scene, PNG_SCALE)?;
    if let Some(dir) = stem.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|source| Error::Io { path: dir.to_path_buf(), source })?;
    }
    let svg_path = with_ext(stem, "svg");
    std::fs::write(&svg_path, render_svg(scene)).map_err(|source| Error::Io { path: svg_path, source })?;
    let png_path = with_ext(stem, "png");
    std::fs::write(&png_path, png).map_err(|source| Error::Io { path: png_path, source })
}

impl LinePlot {
    /// The plot as a scene (to render in memory with [`render_svg`] / [`render_png`]).
    ///
    /// # Errors
    /// [`Error::DimensionMismatch`] when a series' y or band lengths differ from its x length;
    /// [`Error::InvalidOption`] for a size outside 120×80 … 20000×20000 or a fixed range that
    /// is not finite and increasing.
    pub fn scene(&self) -> Result<Scene> {
        layout::single(self)
    }
    /// Write `stem.svg` and `stem.png`.
    ///
    /// # Errors
    /// As [`LinePlot::scene`] and [`write_scene`].
    pub fn write(&self, stem: &Path) -> Result<()> {
        write_scene(&self.scene()?, stem)
    }
}

impl BoxPlot {
    /// The plot as a scene.
    ///
    /// # Errors
    /// [`Error::InvalidOption`] for a non-finite reference line (or a non-positive one on a log
    /// axis) or a size outside 120×80 … 20000×20000.
    pub fn scene(&self) -> Result<Scene> {
        layout::single(self)
    }
    /// Write `stem.svg` and `stem.png`.
    ///
    /// # Errors
    /// As [`BoxPlot::scene`] and [`write_scene`].
    pub fn write(&self, stem: &Path) -> Result<()> {
        write_scene(&self.scene()?, stem)
    }
}

impl<T: Figure> Panels<T> {
    /// The grid as a scene.
    ///
    /// # Errors
    /// [`Error::InvalidOption`] when `columns` is 0; any panel's error.
    pub fn scene(&self) -> Result<Scene> {
        layout::grid(self)
    }
    /// Write `stem.svg` and `stem.png`.
    ///
    /// # Errors
    /// As [`Panels::scene`] and [`write_scene`].
    pub fn write(&self, stem: &Path) -> Result<()> {
        write_scene(&self.scene()?, stem)
    }
}

#[cfg(test)]
mod tests;
