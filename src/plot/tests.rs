use super::font::text_width;
use super::*;

/// Balanced tags (an XML well-formedness check sufficient for our writer: text is escaped, so
/// '<' and '>' only delimit tags), a single `svg` root, no non-finite numbers.
fn assert_well_formed(svg: &str) {
    let mut stack: Vec<String> = vec![];
    let mut roots = 0;
    let mut rest = svg;
    while let Some(start) = rest.find('<') {
        let end = rest[start..].find('>').expect("unterminated tag") + start;
        let tag = &rest[start + 1..end];
        rest = &rest[end + 1..];
        if tag.starts_with('?') || tag.starts_with('!') {
            continue;
        }
        if let Some(name) = tag.strip_prefix('/') {
            assert_eq!(stack.pop().as_deref(), Some(name.trim()), "unbalanced </{name}>");
        } else if !tag.ends_with('/') {
            let name = tag.split_whitespace().next().unwrap().to_string();
            if stack.is_empty() {
                roots += 1;
            }
            stack.push(name);
        } else if stack.is_empty() {
            panic!("element outside the root: <{tag}>");
        }
    }
    assert!(stack.is_empty(), "unclosed: {stack:?}");
    assert_eq!(roots, 1);
    assert!(svg.contains("<svg "));
    for bad in ["NaN", "nan", "inf"] {
        assert!(!svg.contains(bad), "{bad} in SVG");
    }
}

fn example_plot() -> LinePlot {
    let t: Vec<f64> = (0..=100).map(|i| i as f64 * 0.1).collect();
    let x: Vec<f64> = t.iter().map(|t| (0.7 * t).sin()).collect();
    let mut y = x.clone();
    y[40] = f64::NAN; // a gap in the line
    let obs_t: Vec<f64> = (0..=10).map(f64::from).collect();
    let obs: Vec<f64> = obs_t.iter().map(|t| (0.7 * t).sin() + 0.1).collect();
    LinePlot {
        title: "Double well: estimates".into(),
        x_label: "time t".into(),
        y_label: "state x".into(),
        series: vec![
            Series::line("truth", t.clone(), x).with_style(SeriesStyle::Line),
            Series::line("estimate", t.clone(), y).with_sd_band(&vec![0.25; t.len()], 2.0),
            Series::points("data", obs_t, obs),
        ],
        ..LinePlot::default()
    }
}

#[test]
fn line_plot_svg_is_well_formed_and_labelled() {
    let svg = render_svg(&example_plot().scene().unwrap());
    assert_well_formed(&svg);
    for label in ["Double well: estimates", "time t", "state x", "truth", "estimate", "data"] {
        assert!(svg.contains(&format!(">{label}</text>")), "missing label {label}");
    }
    // Tick labels of the x axis: 0 .. 10 with step 1 or 2.
    assert!(svg.contains(">0</text>") && svg.contains(">10</text>"));
    // The line is broken at the NaN: the estimate is drawn as two polylines.
    assert!(svg.matches("<polygon").count() >= 2);
    // Escaping.
    let p = LinePlot { title: "a < b & \"c\"".into(), ..example_plot() };
    let svg = render_svg(&p.scene().unwrap());
    assert_well_formed(&svg);
    assert!(svg.contains("a &lt; b &amp; &quot;c&quot;"));
}

#[test]
fn degenerate_line_plots_render_without_nan() {
    let cases = vec![
        vec![],
        vec![Series::line("empty", vec![], vec![])],
        vec![Series::line("one point", vec![1.0], vec![2.0])],
        vec![Series::points("constant", vec![0.0, 1.0, 2.0], vec![3.0; 3])],
        vec![Series::line("same x", vec![5.0; 3], vec![1.0, 2.0, 3.0])],
        vec![Series::line("all missing", vec![0.0, 1.0], vec![f64::NAN, f64::INFINITY])],
        vec![Series::line("huge", vec![0.0, 1.0, 2.0], vec![-1e300, 1e300, f64::MAX])],
        vec![Series::line("tiny", vec![0.0, 1e-12], vec![1e-9, 2e-9])],
    ];
    for series in cases {
        let name = series.first().map_or("none".to_string(), |s| s.label.clone());
        let p = LinePlot { series, title: name.clone(), ..LinePlot::default() };
        let scene = p.scene().unwrap();
        let svg = render_svg(&scene);
        assert_well_formed(&svg);
        let png = render_png(&scene, 1.0).unwrap();
        assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n", "{name}");
        if name == "huge" {
            // A range wider than f64 can span still gets scientific tick labels.
            let sci = scene
                .prims
                .iter()
                .filter(|p| matches!(p, Prim::Text { text, .. } if text.contains("e30")))
                .count();
            assert!(sci >= 2, "{sci}");
        }
        if name == "all missing" || name == "none" || name == "empty" {
            assert!(svg.contains("no finite data"), "{name}");
        }
    }
}

#[test]
fn misuse_is_an_error() {
    let bad = LinePlot { series: vec![Series::line("a", vec![0.0, 1.0], vec![0.0])], ..LinePlot::default() };
    assert!(matches!(bad.scene(), Err(Error::DimensionMismatch { expected: 2, got: 1, .. })));
    let bad_band = LinePlot {
        series: vec![Series::line("a", vec![0.0, 1.0], vec![0.0, 1.0]).with_band(vec![0.0], vec![1.0, 2.0])],
        ..LinePlot::default()
    };
    assert!(matches!(bad_band.scene(), Err(Error::DimensionMismatch { .. })));
    let tiny = LinePlot { width: 10, ..LinePlot::default() };
    assert!(matches!(tiny.scene(), Err(Error::InvalidOption { .. })));
    let nan_ref = BoxPlot { reference_lines: vec![("x".into(), f64::NAN)], ..BoxPlot::default() };
    assert!(nan_ref.scene().is_err());
    let neg_log = BoxPlot { reference_lines: vec![("x".into(), -1.0)], log_y: true, ..BoxPlot::default() };
    assert!(neg_log.scene().is_err());
    let no_cols: Panels<LinePlot> = Panels { columns: 0, ..Panels::default() };
    assert!(no_cols.scene().is_err());
    assert!(render_png(&Scene::new(100.0, 100.0), 0.0).is_err());
    assert!(render_png(&Scene::new(0.0, 100.0), 1.0).is_err());
}

fn pixel(pm: &tiny_skia::Pixmap, x: f64, y: f64) -> (u8, u8, u8) {
    let p = pm.pixel(x.round() as u32, y.round() as u32).unwrap().demultiply();
    (p.red(), p.green(), p.blue())
}

#[test]
fn png_decodes_with_ink_in_the_plot_area_and_translucent_bands() {
    let p = LinePlot {
        series: vec![
            Series::line("mean", vec![0.0, 10.0], vec![0.0, 0.0]).with_band(vec![-1.0; 2], vec![1.0; 2])
        ],
        ..LinePlot::default()
    };
    let scene = p.scene().unwrap();
    let png = render_png(&scene, PNG_SCALE).unwrap();
    // Signature and IHDR size: 2× the logical canvas.
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    assert_eq!(&png[12..16], b"IHDR");
    let w = u32::from_be_bytes(png[16..20].try_into().unwrap());
    let h = u32::from_be_bytes(png[20..24].try_into().unwrap());
    assert_eq!((w, h), (1800, 1000));
    let pm = tiny_skia::Pixmap::decode_png(&png).unwrap();
    assert_eq!((pm.width(), pm.height()), (1800, 1000));

    let plot = scene.clips[0];
    let s = PNG_SCALE;
    let mut ink = 0usize;
    let mut total = 0usize;
    for yy in (plot.y * s) as u32..(plot.bottom() * s) as u32 {
        for xx in (plot.x * s) as u32..(plot.right() * s) as u32 {
            total += 1;
            let c = pm.pixel(xx, yy).unwrap();
            ink += usize::from((c.red(), c.green(), c.blue()) != (255, 255, 255));
        }
    }
    // The band covers 2/2.16 of the height: most of the plot area is tinted.
    assert!(ink as f64 > 0.8 * total as f64, "{ink} of {total}");

    // Between the line (y = 0) and the band's upper edge (y = 1), away from grid lines: the series
    // colour, the first of the palette (204, 102, 119), at the band opacity 0.2 over white gives
    // (245, 224, 228).
    let Some(Prim::Polygon { points, .. }) = scene.prims.iter().find(|p| matches!(p, Prim::Polygon { .. }))
    else {
        panic!("no band polygon")
    };
    let (top, mid) = (points[0].1, plot.y + plot.h / 2.0);
    let x = plot.x + plot.w * 0.07;
    let y = top + 0.3 * (mid - top);
    let (r, g, b) = pixel(&pm, x * s, y * s);
    assert!(
        (r as i32 - 245).abs() <= 4 && (g as i32 - 224).abs() <= 4 && (b as i32 - 228).abs() <= 4,
        "{r} {g} {b}"
    );
    // Outside the canvas' plot area (the margin) the background is white.
    assert_eq!(pixel(&pm, 2.0, 2.0), (255, 255, 255));
}

#[test]
fn box_plot_stats_labels_and_degenerate_groups() {
    let spread: Vec<f64> = (1..=9).map(f64::from).chain([30.0, f64::NAN]).collect();
    let p = BoxPlot {
        title: "ISE by estimator".into(),
        y_label: "θ̂".into(),
        groups: vec![
            BoxGroup { label: "JME".into(), values: spread, ..BoxGroup::default() },
            BoxGroup { label: "MEE".into(), values: vec![4.0; 5], ..BoxGroup::default() },
            BoxGroup { label: "UKS".into(), values: vec![f64::NAN], ..BoxGroup::default() },
            BoxGroup { label: "PEM".into(), values: vec![], ..BoxGroup::default() },
        ],
        reference_lines: vec![("nominal θ = 5".into(), 5.0)],
        ..BoxPlot::default()
    };
    let scene = p.scene().unwrap();
    let svg = render_svg(&scene);
    assert_well_formed(&svg);
    // Each box states its count of rows drawn and what it lost.
    for label in [
        "ISE by estimator",
        "θ̂",
        "JME",
        "n = 10/11",
        "1 skipped",
        "MEE",
        "n = 5/5",
        "UKS",
        "n = 0/1",
        "n = 0/0",
        "nominal θ = 5",
        "no data",
    ] {
        assert!(svg.contains(&format!(">{label}</text>")), "missing {label}");
    }
    // One outlier (30) drawn as a hollow circle.
    assert_eq!(svg.matches("<circle").count(), 1);
    assert!(render_png(&scene, 1.0).is_ok());

    // Log axis: non-positive values are skipped, decades labelled.
    let log = BoxPlot {
        groups: vec![BoxGroup {
            label: "a".into(),
            values: vec![-1.0, 0.0, 1e-3, 1e-2, 0.1, 1.0],
            ..BoxGroup::default()
        }],
        log_y: true,
        ..BoxPlot::default()
    };
    let svg = render_svg(&log.scene().unwrap());
    assert_well_formed(&svg);
    assert!(
        svg.contains(">n = 4/6</text>")
            && svg.contains(">2 skipped</text>")
            && svg.contains(">0.01</text>")
            && svg.contains(">1</text>")
    );

    // No groups at all, and long labels (rotated).
    let empty = BoxPlot::default();
    assert!(render_svg(&empty.scene().unwrap()).contains("no groups"));
    let long = BoxPlot {
        groups: (0..12)
            .map(|i| BoxGroup {
                label: format!("a rather long estimator name {i}"),
                values: vec![i as f64, 1.0],
                ..BoxGroup::default()
            })
            .collect(),
        ..BoxPlot::default()
    };
    let svg = render_svg(&long.scene().unwrap());
    assert_well_formed(&svg);
    assert!(svg.contains("rotate(-30"));
    let crowded = BoxPlot {
        groups: (0..60)
            .map(|i| BoxGroup {
                label: format!("scenario {i}"),
                values: vec![i as f64],
                ..BoxGroup::default()
            })
            .collect(),
        ..BoxPlot::default()
    };
    let scene = crowded.scene().unwrap();
    let svg = render_svg(&scene);
    assert_well_formed(&svg);
    assert!(svg.contains("rotate(-90"));
    // The vertical labels fit under the plot, inside the canvas.
    assert!(scene.clips[0].bottom() + text_width("scenario 59", 12.0) < scene.height);
}

#[test]
fn panels_grid_and_files() {
    let panel = |i: usize| LinePlot {
        title: format!("state {i}"),
        width: 400,
        height: 250,
        series: vec![Series::line("x", vec![0.0, 1.0], vec![0.0, i as f64])],
        ..LinePlot::default()
    };
    let grid = Panels {
        title: "paths".into(),
        panels: (0..3).map(panel).collect(),
        columns: 2,
        ..Panels::default()
    };
    let scene = grid.scene().unwrap();
    assert_eq!(scene.width, 800.0);
    assert!(scene.height > 500.0 && scene.height < 560.0);
    let svg = render_svg(&scene);
    assert_well_formed(&svg);
    assert!(svg.contains(">state 2</text>") && svg.contains(">paths</text>"));

    let dir = std::env::temp_dir().join(format!("onsager-plot-test-{}", std::process::id()));
    let stem = dir.join("sub").join("grid.v1");
    grid.write(&stem).unwrap();
    let png = std::fs::read(dir.join("sub/grid.v1.png")).unwrap();
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    assert!(std::fs::read_to_string(dir.join("sub/grid.v1.svg")).unwrap().contains("</svg>"));
    let boxes = Panels {
        title: String::new(),
        panels: vec![BoxPlot {
            groups: vec![BoxGroup { label: "g".into(), values: vec![1.0, 2.0], ..BoxGroup::default() }],
            ..BoxPlot::default()
        }],
        columns: 3,
        ..Panels::default()
    };
    boxes.write(&dir.join("boxes")).unwrap();
    assert!(dir.join("boxes.png").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn non_ascii_text_renders_in_png() {
    let p = LinePlot {
        title: "θ̂ ± 2σ — 估计 ✓".into(),
        series: vec![Series::line("λ₁", vec![0.0, 1.0], vec![0.0, 1.0])],
        ..LinePlot::default()
    };
    let scene = p.scene().unwrap();
    assert!(render_png(&scene, 1.0).is_ok());
    assert!(render_svg(&scene).contains("估计"));
}
