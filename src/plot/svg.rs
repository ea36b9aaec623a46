//! The SVG renderer: the scene written as SVG 1.1 elements, by string formatting.

use super::scene::{Anchor, Color, Prim, Scene};
use std::fmt::Write;

/// Font stack of SVG text: the embedded font's family first (the layout measured text with
/// its metrics), then metrically close fallbacks.
const FONT_FAMILY: &str = "DejaVu Sans, Verdana, Bitstream Vera Sans, Arial, sans-serif";

/// A coordinate with two decimals; non-finite values (which the layout never produces) become 0
/// so that the document stays valid.
fn num(v: f64) -> String {
    if !v.is_finite() {
        return "0".into();
    }
    let s = format!("{v:.2}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" || s.is_empty() {
        "0".into()
    } else {
        s.to_string()
    }
}

fn escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            // Control characters are not allowed in XML 1.0.
            c if (c as u32) < 0x20 && c != '\t' => out.push(' '),
            c => out.push(c),
        }
    }
    out
}

fn paint(attr: &str, c: Color) -> String {
    if c.a >= 1.0 {
        format!(r#" {attr}="{}""#, c.hex())
    } else {
        format!(r#" {attr}="{}" {attr}-opacity="{}""#, c.hex(), num(f64::from(c.a.max(0.0))))
    }
}

fn clip_attr(clip: Option<usize>) -> String {
    clip.map_or(String::new(), |i| format!(r#" clip-path="url(#clip{i})""#))
}

fn points(p: &[(f64, f64)]) -> String {
    let mut s = String::with_capacity(p.len() * 14);
    for (i, (x, y)) in p.iter().enumerate() {
        if i > 0 {
            s.push(' ');
        }
        let _ = write!(s, "{},{}", num(*x), num(*y));
    }
    s
}

/// The scene as a standalone SVG document.
pub fn render_svg(scene: &Scene) -> String {
    let mut s = String::new();
    let (w, h) = (num(scene.width), num(scene.height));
    let _ = writeln!(s, r#"<?xml version="1.0" encoding="UTF-8"?>"#);
    let _ = writeln!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}" font-family="{FONT_FAMILY}">"#
    );
    let _ = writeln!(s, r##"<rect x="0" y="0" width="{w}" height="{h}" fill="#ffffff"/>"##);
    if !scene.clips.is_empty() {
        s.push_str("<defs>\n");
        for (i, r) in scene.clips.iter().enumerate() {
            let _ = writeln!(
                s,
                r#"<clipPath id="clip{i}"><rect x="{}" y="{}" width="{}" height="{}"/></clipPath>"#,
                num(r.x),
                num(r.y),
                num(r.w.max(0.0)),
                num(r.h.max(0.0))
            );
        }
        s.push_str("</defs>\n");
    }
    for p in &scene.prims {
        match p {
            Prim::Polyline { points: pts, color, width, dash, clip } => {
                if pts.len() < 2 {
                    continue;
                }
                let dash = if dash.is_empty() {
                    String::new()
                } else {
                    let d: Vec<String> = dash.iter().map(|v| num(*v)).collect();
                    format!(r#" stroke-dasharray="{}""#, d.join(","))
                };
                let _ = writeln!(
                    s,
                    r#"<polyline points="{}" fill="none"{} stroke-width="{}" stroke-linejoin="round" stroke-linecap="butt"{dash}{}/>"#,
                    points(pts),
                    paint("stroke", *color),
                    num(*width),
                    clip_attr(*clip)
                );
            }
            Prim::Polygon { points: pts, fill, clip } => {
                if pts.len() < 3 {
                    continue;
                }
                let _ = writeln!(
                    s,
                    r#"<polygon points="{}"{} stroke="none"{}/>"#,
                    points(pts),
                    paint("fill", *fill),
                    clip_attr(*clip)
                );
            }
            Prim::Rect { rect, fill, stroke, clip } => {
                let f = fill.map_or(r#" fill="none""#.to_string(), |c| paint("fill", c));
                let st = stroke.map_or(String::new(), |(c, w)| {
                    format!(r#"{} stroke-width="{}""#, paint("stroke", c), num(w))
                });
                let _ = writeln!(
                    s,
                    r#"<rect x="{}" y="{}" width="{}" height="{}"{f}{st}{}/>"#,
                    num(rect.x),
                    num(rect.y),
                    num(rect.w.max(0.0)),
                    num(rect.h.max(0.0)),
                    clip_attr(*clip)
                );
            }
            Prim::Circle { cx, cy, r, fill, stroke, clip } => {
                let f = fill.map_or(r#" fill="none""#.to_string(), |c| paint("fill", c));
                let st = stroke.map_or(String::new(), |(c, w)| {
                    format!(r#"{} stroke-width="{}""#, paint("stroke", c), num(w))
                });
                let _ = writeln!(
                    s,
                    r#"<circle cx="{}" cy="{}" r="{}"{f}{st}{}/>"#,
                    num(*cx),
                    num(*cy),
                    num(*r),
                    clip_attr(*clip)
                );
            }
            Prim::Text { x, y, text, size, anchor, angle, color } => {
                let a = match anchor {
                    Anchor::Start => "start",
                    Anchor::Middle => "middle",
                    Anchor::End => "end",
                };
                let rot = if *angle != 0.0 {
                    format!(r#" transform="rotate({} {} {})""#, num(*angle), num(*x), num(*y))
                } else {
                    String::new()
                };
                let _ = writeln!(
                    s,
                    r#"<text x="{}" y="{}" font-size="{}" text-anchor="{a}"{}{rot}>{}</text>"#,
                    num(*x),
                    num(*y),
                    num(*size),
                    paint("fill", *color),
                    escape(text)
                );
            }
        }
    }
    s.push_str("</svg>\n");
    s
}
