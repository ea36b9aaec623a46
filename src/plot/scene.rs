//! The scene: what the layout decides and both renderers draw, in pixels of the logical
//! canvas (origin top left, y down).

/// An sRGB colour with opacity.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Color {
    /// Red, 0–255.
    pub r: u8,
    /// Green, 0–255.
    pub g: u8,
    /// Blue, 0–255.
    pub b: u8,
    /// Opacity in [0, 1].
    pub a: f32,
}

impl Color {
    /// An opaque colour.
    pub const fn rgb(r: u8, g: u8, b: u8) -> Color {
        Color { r, g, b, a: 1.0 }
    }
    /// The same colour with opacity `a`.
    pub const fn with_alpha(self, a: f32) -> Color {
        Color { a, ..self }
    }
    /// `#rrggbb`.
    pub fn hex(&self) -> String {
        format!("#{:02x}{:02x}{:02x}", self.r, self.g, self.b)
    }
    pub(crate) const BLACK: Color = Color::rgb(0, 0, 0);
    pub(crate) const WHITE: Color = Color::rgb(255, 255, 255);
    pub(crate) const TEXT: Color = Color::rgb(34, 34, 34);
    pub(crate) const AXIS: Color = Color::rgb(80, 80, 80);
    pub(crate) const GRID: Color = Color::rgb(228, 228, 228);
    pub(crate) const NOTE: Color = Color::rgb(120, 120, 120);
}

/// The series palette: Paul Tol's "muted" qualitative scheme, nine colours distinct for
/// readers with normal vision and with the common colour-vision deficiencies, and distinct from
/// black and from grey (P. Tol, "Colour schemes", SRON/EPS/TN/09-002, issue 3.2, 2021, the
/// qualitative schemes; <https://personal.sron.nl/~pault/>). Black and grey are kept for the
/// truth and the data ([`TRUTH`], [`DATA`]); series beyond nine reuse the colours with dashes
/// ([`Dash`]).
pub const PALETTE: [Color; 9] = [
    Color::rgb(0xCC, 0x66, 0x77), // rose
    Color::rgb(0x33, 0x22, 0x88), // indigo
    Color::rgb(0xDD, 0xCC, 0x77), // sand
    Color::rgb(0x11, 0x77, 0x33), // green
    Color::rgb(0x88, 0xCC, 0xEE), // cyan
    Color::rgb(0x88, 0x22, 0x55), // wine
    Color::rgb(0x44, 0xAA, 0x99), // teal
    Color::rgb(0x99, 0x99, 0x33), // olive
    Color::rgb(0xAA, 0x44, 0x99), // purple
];

/// The colour of the true path (a black line): no palette colour.
pub const TRUTH: Color = Color::rgb(0, 0, 0);

/// The colour of the measurements (grey markers): no palette colour.
pub const DATA: Color = Color::rgb(0x6E, 0x6E, 0x6E);

/// The dash pattern of a line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Dash {
    /// A solid line.
    #[default]
    Solid,
    /// Long dashes.
    Dashed,
    /// Dots.
    Dotted,
    /// Dashes and dots.
    DashDot,
}

impl Dash {
    /// Every pattern, solid first.
    pub const ALL: [Dash; 4] = [Dash::Solid, Dash::Dashed, Dash::Dotted, Dash::DashDot];

    /// The pattern (on, off, …) in pixels; empty for a solid line.
    pub fn pattern(self) -> Vec<f64> {
        match self {
            Dash::Solid => vec![],
            Dash::Dashed => vec![7.0, 3.5],
            Dash::Dotted => vec![1.6, 2.4],
            Dash::DashDot => vec![7.0, 2.5, 1.6, 2.5],
        }
    }
}

/// An axis-aligned rectangle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rect {
    /// Left edge.
    pub x: f64,
    /// Top edge.
    pub y: f64,
    /// Width.
    pub w: f64,
    /// Height.
    pub h: f64,
}

impl Rect {
    /// Right edge.
    pub fn right(&self) -> f64 {
        self.x + self.w
    }
    /// Bottom edge.
    pub fn bottom(&self) -> f64 {
        self.y + self.h
    }
    /// Whether (x, y) is inside (edges included).
    pub fn contains(&self, x: f64, y: f64) -> bool {
        x >= self.x && x <= self.right() && y >= self.y && y <= self.bottom()
    }
}

/// Horizontal text alignment relative to the anchor point.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Anchor {
    /// The text starts at the anchor.
    Start,
    /// The text is centred on the anchor.
    Middle,
    /// The text ends at the anchor.
    End,
}

/// One drawing primitive. `clip` indexes [`Scene::clips`]; coordinates are always finite.
#[derive(Debug, Clone, PartialEq)]
pub enum Prim {
    /// An open polyline.
    Polyline {
        /// Vertices.
        points: Vec<(f64, f64)>,
        /// Stroke colour.
        color: Color,
        /// Stroke width.
        width: f64,
        /// Dash pattern (on, off, ...), empty for solid.
        dash: Vec<f64>,
        /// Clip rectangle.
        clip: Option<usize>,
    },
    /// A filled polygon (non-zero rule), no stroke.
    Polygon {
        /// Vertices.
        points: Vec<(f64, f64)>,
        /// Fill colour (usually translucent).
        fill: Color,
        /// Clip rectangle.
        clip: Option<usize>,
    },
    /// A rectangle, filled and/or stroked.
    Rect {
        /// Geometry.
        rect: Rect,
        /// Fill colour.
        fill: Option<Color>,
        /// Stroke colour and width.
        stroke: Option<(Color, f64)>,
        /// Clip rectangle.
        clip: Option<usize>,
    },
    /// A circular marker.
    Circle {
        /// Centre x.
        cx: f64,
        /// Centre y.
        cy: f64,
        /// Radius.
        r: f64,
        /// Fill colour.
        fill: Option<Color>,
        /// Stroke colour and width.
        stroke: Option<(Color, f64)>,
        /// Clip rectangle.
        clip: Option<usize>,
    },
    /// A line of text; (x, y) is the anchor point on the baseline.
    Text {
        /// Anchor x.
        x: f64,
        /// Baseline y.
        y: f64,
        /// The text (any Unicode; the PNG renderer draws '?' for glyphs the font lacks).
        text: String,
        /// Font size in pixels.
        size: f64,
        /// Horizontal alignment.
        anchor: Anchor,
        /// Rotation in degrees about the anchor, clockwise on screen (−90: reads bottom to top).
        angle: f64,
        /// Colour.
        color: Color,
    },
}

/// A picture: a canvas size, clip rectangles and primitives in drawing order.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    /// Canvas width in logical pixels.
    pub width: f64,
    /// Canvas height in logical pixels.
    pub height: f64,
    /// Clip rectangles referenced by the primitives.
    pub clips: Vec<Rect>,
    /// Primitives, painted in order.
    pub prims: Vec<Prim>,
}

impl Scene {
    /// An empty white canvas.
    pub fn new(width: f64, height: f64) -> Scene {
        Scene { width, height, clips: vec![], prims: vec![] }
    }

    /// Register a clip rectangle, returning its index.
    pub(crate) fn clip(&mut self, r: Rect) -> usize {
        self.clips.push(r);
        self.clips.len() - 1
    }

    pub(crate) fn text(&mut self, x: f64, y: f64, text: &str, size: f64, anchor: Anchor, color: Color) {
        self.prims.push(Prim::Text { x, y, text: text.to_string(), size, anchor, angle: 0.0, color });
    }

    pub(crate) fn line(&mut self, points: Vec<(f64, f64)>, color: Color, width: f64, clip: Option<usize>) {
        self.prims.push(Prim::Polyline { points, color, width, dash: vec![], clip });
    }
}
