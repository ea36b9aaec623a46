//! The embedded font: a subset of DejaVu Sans (ASCII, Latin-1, Greek, common math symbols),
//! used to measure text for the layout and to draw glyph outlines into PNGs.
//!
//! The file `font/DejaVuSans-subset.ttf` was made from DejaVu Sans 2.37 with fontTools:
//! `pyftsubset DejaVuSans.ttf --unicodes="U+0020-007E,U+00A0-00FF,U+0302,U+0370-03FF,U+2009,`
//! `U+2013-2014,U+2018-2019,U+201C-201D,U+2022,U+2026,U+2070-208E,U+2202,U+2207,U+2211,U+2212,`
//! `U+221A,U+221E,U+2248,U+2264-2265,U+FFFD" --no-hinting --layout-features=''`.
//! Its licence (Bitstream Vera, DejaVu changes in the public domain) is `font/LICENSE-DejaVu.txt`.

use std::sync::OnceLock;
use ttf_parser::{Face, GlyphId, OutlineBuilder};

static FONT_BYTES: &[u8] = include_bytes!("font/DejaVuSans-subset.ttf");

fn face() -> Option<&'static Face<'static>> {
    static FACE: OnceLock<Option<Face<'static>>> = OnceLock::new();
    FACE.get_or_init(|| Face::parse(FONT_BYTES, 0).ok()).as_ref()
}

/// The glyph drawn for `c`: its own, or '?' when the font lacks it.
fn glyph(face: &Face<'_>, c: char) -> Option<GlyphId> {
    face.glyph_index(c).or_else(|| face.glyph_index('?'))
}

/// Width of `text` at font size `size` (pixels per em), from the font's advance widths.
pub(crate) fn text_width(text: &str, size: f64) -> f64 {
    let Some(face) = face() else {
        return 0.6 * size * text.chars().count() as f64;
    };
    let upem = f64::from(face.units_per_em());
    let units: f64 = text
        .chars()
        .map(|c| glyph(face, c).and_then(|g| face.glyph_hor_advance(g)).map_or(0.0, f64::from))
        .sum();
    units * size / upem
}

/// Height of capital letters above the baseline, as a fraction of the font size.
pub(crate) const CAP_HEIGHT: f64 = 0.73;

/// One glyph outline command in em units (y up), relative to the glyph's pen position.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Segment {
    MoveTo(f32, f32),
    LineTo(f32, f32),
    QuadTo(f32, f32, f32, f32),
    CubicTo(f32, f32, f32, f32, f32, f32),
    Close,
}

struct Collect {
    scale: f32,
    out: Vec<Segment>,
}

impl OutlineBuilder for Collect {
    fn move_to(&mut self, x: f32, y: f32) {
        self.out.push(Segment::MoveTo(x * self.scale, y * self.scale));
    }
    fn line_to(&mut self, x: f32, y: f32) {
        self.out.push(Segment::LineTo(x * self.scale, y * self.scale));
    }
    fn quad_to(&mut self, x1: f32, y1: f32, x: f32, y: f32) {
        let s = self.scale;
        self.out.push(Segment::QuadTo(x1 * s, y1 * s, x * s, y * s));
    }
    fn curve_to(&mut self, x1: f32, y1: f32, x2: f32, y2: f32, x: f32, y: f32) {
        let s = self.scale;
        self.out.push(Segment::CubicTo(x1 * s, y1 * s, x2 * s, y2 * s, x * s, y * s));
    }
    fn close(&mut self) {
        self.out.push(Segment::Close);
    }
}

/// The outlines of `text` laid out on one line, in em units (y up), pen starting at x = 0.
pub(crate) fn text_outline(text: &str) -> Vec<Segment> {
    let Some(face) = face() else {
        return vec![];
    };
    let scale = 1.0 / f32::from(face.units_per_em());
    let mut out = Vec::new();
    let mut pen = 0.0f32;
    for c in text.chars() {
        let Some(g) = glyph(face, c) else { continue };
        let mut b = Collect { scale, out: Vec::new() };
        face.outline_glyph(g, &mut b);
        out.extend(b.out.into_iter().map(|s| match s {
            Segment::MoveTo(x, y) => Segment::MoveTo(x + pen, y),
            Segment::LineTo(x, y) => Segment::LineTo(x + pen, y),
            Segment::QuadTo(a, b, x, y) => Segment::QuadTo(a + pen, b, x + pen, y),
            Segment::CubicTo(a, b, c, d, x, y) => Segment::CubicTo(a + pen, b, c + pen, d, x + pen, y),
            Segment::Close => Segment::Close,
        }));
        pen += face.glyph_hor_advance(g).map_or(0.0, f32::from) * scale;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn font_parses_and_measures() {
        assert!(face().is_some());
        // DejaVu Sans: every digit advances 1303/2048 em.
        let w = text_width("0123456789", 20.0);
        assert!((w - 10.0 * 20.0 * 1303.0 / 2048.0).abs() < 1e-9, "{w}");
        // Missing glyphs degrade to '?' (CJK is not in the subset).
        assert_eq!(text_width("水", 10.0), text_width("?", 10.0));
        assert!(text_width("θ̂ ± σ", 12.0) > 0.0);
        assert!(!text_outline("Ag").is_empty());
        assert!(text_outline(" ").is_empty());
    }
}
