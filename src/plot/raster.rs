//! The PNG renderer: the scene rasterised with anti-aliasing by `tiny-skia` (pure Rust), text
//! drawn from the embedded font's outlines, encoded by `tiny-skia`'s PNG writer.

use super::font::{text_outline, text_width, Segment};
use super::scene::{Anchor, Color, Prim, Scene};
use crate::{Error, Result};
use tiny_skia::{
    FillRule, LineCap, LineJoin, Mask, Paint, PathBuilder, Pixmap, Stroke, StrokeDash, Transform,
};

fn paint(c: Color) -> Paint<'static> {
    let mut p = Paint::default();
    p.set_color_rgba8(c.r, c.g, c.b, (c.a.clamp(0.0, 1.0) * 255.0).round() as u8);
    p.anti_alias = true;
    p
}

fn poly_path(points: &[(f64, f64)], close: bool) -> Option<tiny_skia::Path> {
    let mut pb = PathBuilder::new();
    let mut it = points.iter().filter(|(x, y)| x.is_finite() && y.is_finite());
    let (x0, y0) = it.next()?;
    pb.move_to(*x0 as f32, *y0 as f32);
    for (x, y) in it {
        pb.line_to(*x as f32, *y as f32);
    }
    if close {
        pb.close();
    }
    pb.finish()
}

fn rect_path(x: f64, y: f64, w: f64, h: f64) -> Option<tiny_skia::Path> {
    tiny_skia::Rect::from_xywh(x as f32, y as f32, w.max(1e-3) as f32, h.max(1e-3) as f32)
        .map(PathBuilder::from_rect)
}

fn stroke(width: f64, dash: &[f64]) -> Stroke {
    Stroke {
        width: width as f32,
        line_join: LineJoin::Round,
        line_cap: LineCap::Butt,
        dash: if dash.len() >= 2 {
            StrokeDash::new(dash.iter().map(|v| *v as f32).collect(), 0.0)
        } else {
            None
        },
        ..Stroke::default()
    }
}

/// The scene rasterised at `scale` device pixels per logical pixel (2 gives crisp figures on
/// screens and in documents), as an RGBA pixmap on a white background.
///
/// # Errors
/// [`Error::InvalidOption`] when the canvas is empty or too large, or `scale` is not positive.
pub fn render_pixmap(scene: &Scene, scale: f64) -> Result<Pixmap> {
    let bad = |reason: String| Error::InvalidOption { name: "scale".into(), reason };
    if !(scale.is_finite() && scale > 0.0) {
        return Err(bad(format!("PNG scale must be positive, got {scale}")));
    }
    let (w, h) = ((scene.width * scale).round(), (scene.height * scale).round());
    if !(w >= 1.0 && h >= 1.0 && w * h <= 6e7) {
        return Err(bad(format!("canvas {w}×{h} device pixels is empty or too large")));
    }
    let (w, h) = (w as u32, h as u32);
    let mut pm = Pixmap::new(w, h).ok_or_else(|| bad("cannot allocate the canvas".into()))?;
    pm.fill(tiny_skia::Color::WHITE);
    let base = Transform::from_scale(scale as f32, scale as f32);
    // One clip mask at a time (a mask is as large as the canvas; a grid of panels has one clip
    // per panel, and primitives come panel by panel).
    let mut current: Option<(usize, Option<Mask>)> = None;
    for p in &scene.prims {
        let clip = match p {
            Prim::Polyline { clip, .. }
            | Prim::Polygon { clip, .. }
            | Prim::Rect { clip, .. }
            | Prim::Circle { clip, .. } => *clip,
            Prim::Text { .. } => None,
        };
        if let Some(i) = clip {
            if current.as_ref().map(|(j, _)| *j) != Some(i) {
                let m = scene.clips.get(i).and_then(|r| {
                    let mut m = Mask::new(w, h)?;
                    m.fill_path(&rect_path(r.x, r.y, r.w, r.h)?, FillRule::Winding, true, base);
                    Some(m)
                });
                current = Some((i, m));
            }
        }
        let mask = clip.and_then(|_| current.as_ref().and_then(|(_, m)| m.as_ref()));
        match p {
            Prim::Polyline { points, color, width, dash, .. } => {
                if let Some(path) = poly_path(points, false) {
                    pm.stroke_path(&path, &paint(*color), &stroke(*width, dash), base, mask);
                }
            }
            Prim::Polygon { points, fill, .. } => {
                if let Some(path) = poly_path(points, true) {
                    pm.fill_path(&path, &paint(*fill), FillRule::Winding, base, mask);
                }
            }
            Prim::Rect { rect, fill, stroke: st, .. } => {
                if let Some(path) = rect_path(rect.x, rect.y, rect.w, rect.h) {
                    if let Some(f) = fill {
                        pm.fill_path(&path, &paint(*f), FillRule::Winding, base, mask);
                    }
                    if let Some((c, sw)) = st {
                        pm.stroke_path(&path, &paint(*c), &stroke(*sw, &[]), base, mask);
                    }
                }
            }
            Prim::Circle { cx, cy, r, fill, stroke: st, .. } => {
                if let Some(path) = PathBuilder::from_circle(*cx as f32, *cy as f32, *r as f32) {
                    if let Some(f) = fill {
                        pm.fill_path(&path, &paint(*f), FillRule::Winding, base, mask);
                    }
                    if let Some((c, sw)) = st {
                        pm.stroke_path(&path, &paint(*c), &stroke(*sw, &[]), base, mask);
                    }
                }
            }
            Prim::Text { x, y, text, size, anchor, angle, color } => {
                let w = text_width(text, *size);
                let dx = match anchor {
                    Anchor::Start => 0.0,
                    Anchor::Middle => -w / 2.0,
                    Anchor::End => -w,
                };
                // em units (y up) -> size px (y down), shifted by the anchor, rotated, placed.
                let t = Transform::from_scale(*size as f32, -*size as f32)
                    .post_translate(dx as f32, 0.0)
                    .post_rotate(*angle as f32)
                    .post_translate(*x as f32, *y as f32)
                    .post_concat(base);
                let mut pb = PathBuilder::new();
                for s in text_outline(text) {
                    match s {
                        Segment::MoveTo(x, y) => pb.move_to(x, y),
                        Segment::LineTo(x, y) => pb.line_to(x, y),
                        Segment::QuadTo(a, b, x, y) => pb.quad_to(a, b, x, y),
                        Segment::CubicTo(a, b, c, d, x, y) => pb.cubic_to(a, b, c, d, x, y),
                        Segment::Close => pb.close(),
                    }
                }
                if let Some(path) = pb.finish() {
                    pm.fill_path(&path, &paint(*color), FillRule::Winding, t, None);
                }
            }
        }
    }
    Ok(pm)
}

/// The scene as PNG file bytes, at `scale` device pixels per logical pixel.
///
/// # Errors
/// As [`render_pixmap`]; [`Error::InvalidOption`] if encoding fails.
pub fn render_png(scene: &Scene, scale: f64) -> Result<Vec<u8>> {
    render_pixmap(scene, scale)?
        .encode_png()
        .map_err(|e| Error::InvalidOption { name: "png".into(), reason: format!("PNG encoding failed: {e}") })
}
