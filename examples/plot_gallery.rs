//! A gallery of the `onsager::plot` figures, written under `out/gallery/` as SVG and PNG:
//! a line plot of a double-well path with estimates, ±2 sd bands and measurements, a box plot
//! of an error metric per estimator with a reference line, a log-scale box plot, and a grid
//! of panels.
//!
//! Run with `cargo run --release --example plot_gallery`.

use onsager::plot::{BoxGroup, BoxPlot, Dash, LinePlot, Panels, Series, SeriesStyle, DATA, TRUTH};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use std::path::Path;

fn main() -> onsager::Result<()> {
    let out = Path::new("out/gallery");
    let mut rng = rand::rngs::StdRng::seed_from_u64(7);
    let noise = Normal::new(0.0, 1.0).expect("unit normal");

    // A double-well-like path: Euler–Maruyama for dx = 4x(1 - x²) dt + 0.7 dW.
    let dt = 0.01;
    let n = 1001;
    let t: Vec<f64> = (0..n).map(|i| i as f64 * dt).collect();
    let mut x = vec![-1.0; n];
    for i in 1..n {
        let xi = x[i - 1];
        x[i] = xi + 4.0 * xi * (1.0 - xi * xi) * dt + 0.7 * dt.sqrt() * noise.sample(&mut rng);
    }
    let obs_t: Vec<f64> = t.iter().copied().step_by(50).collect();
    let obs: Vec<f64> = x.iter().step_by(50).map(|v| v + 0.2 * noise.sample(&mut rng)).collect();
    // Two smoothed "estimates" with their sd.
    let smooth = |w: usize| -> Vec<f64> {
        (0..n)
            .map(|i| {
                let (a, b) = (i.saturating_sub(w), (i + w + 1).min(n));
                x[a..b].iter().sum::<f64>() / (b - a) as f64
            })
            .collect()
    };
    let (est_a, est_b) = (smooth(15), smooth(60));
    let sd_a: Vec<f64> = t.iter().map(|t| 0.12 + 0.05 * (3.0 * t).sin().abs()).collect();
    let sd_b: Vec<f64> = vec![0.22; n];
    let paths = LinePlot {
        title: "Double well: state path estimates (±2 sd)".into(),
        x_label: "time t".into(),
        y_label: "state x".into(),
        series: vec![
            Series::line("truth", t.clone(), x.clone()).with_look(TRUTH, Dash::Solid),
            Series::line("mean-optimal", t.clone(), est_a.clone()).with_sd_band(&sd_a, 2.0),
            Series::line("Gaussian closure", t.clone(), est_b.clone()).with_sd_band(&sd_b, 2.0),
            Series::points("measurements", obs_t, obs).with_look(DATA, Dash::Solid),
        ],
        ..LinePlot::default()
    };
    paths.write(&out.join("paths"))?;

    // Box plot of a metric per estimator, with outliers, a NaN and three failed replicates.
    let names = ["JME", "MEE", "Euler MAP", "trapezoidal MAP", "UKS", "PEM"];
    let groups: Vec<BoxGroup> = names
        .iter()
        .enumerate()
        .map(|(k, name)| {
            let mut values: Vec<f64> =
                (0..50).map(|_| 0.5 + 0.1 * k as f64 + 0.15 * noise.sample(&mut rng).abs()).collect();
            values.push(1.6 + 0.2 * k as f64);
            if k == 4 {
                values.push(f64::NAN);
            }
            BoxGroup {
                label: name.to_string(),
                values,
                failed: usize::from(k == 4) * 3,
                ..BoxGroup::default()
            }
        })
        .collect();
    let boxes = BoxPlot {
        title: "Van der Pol, p_o = 0.25: integrated squared error".into(),
        y_label: "ISE".into(),
        groups: groups.clone(),
        reference_lines: vec![("target".into(), 0.75)],
        ..BoxPlot::default()
    };
    boxes.write(&out.join("boxes"))?;

    // θ̂ box plots with the nominal value, log axis, as a grid of panels.
    let theta = |scale: f64, rng: &mut rand::rngs::StdRng| -> Vec<f64> {
        (0..40).map(|_| scale * (0.4 * noise.sample(rng)).exp()).collect()
    };
    let panel = |title: &str, nominal: f64, rng: &mut rand::rngs::StdRng| BoxPlot {
        title: title.into(),
        y_label: "θ̂ (log scale)".into(),
        groups: ["JME", "MEE", "PEM"]
            .iter()
            .map(|name| BoxGroup {
                label: name.to_string(),
                values: theta(nominal, rng),
                ..BoxGroup::default()
            })
            .collect(),
        reference_lines: vec![(format!("nominal {nominal}"), nominal)],
        log_y: true,
        width: 450,
        height: 340,
    };
    let grid = Panels {
        title: "Duffing: parameter estimates, t_f = 100".into(),
        panels: vec![panel("damping d", 0.1, &mut rng), panel("stiffness a", 2.0, &mut rng)],
        columns: 2,
        ..Panels::default()
    };
    grid.write(&out.join("theta"))?;

    // A line plot with markers only and lines with markers, 12 series (palette then dashes).
    let many = LinePlot {
        title: "Twelve series".into(),
        x_label: "replicate".into(),
        y_label: "value".into(),
        series: (0..12)
            .map(|k| {
                let xs: Vec<f64> = (0..20).map(f64::from).collect();
                let ys: Vec<f64> =
                    xs.iter().map(|v| (v * 0.3 + k as f64 * 0.5).sin() + k as f64 * 0.3).collect();
                Series::line(format!("series {k}"), xs, ys).with_style(if k % 3 == 0 {
                    SeriesStyle::LineAndPoints
                } else {
                    SeriesStyle::Line
                })
            })
            .collect(),
        ..LinePlot::default()
    };
    many.write(&out.join("many"))?;
    // Many groups: estimator × scenario, labels set vertically.
    let crowded = BoxPlot {
        title: "Duffing with outliers: ISE per estimator and outlier probability p_o".into(),
        y_label: "ISE".into(),
        groups: ["0.05", "0.1", "0.2", "0.3", "0.4"]
            .iter()
            .flat_map(|po| ["JME", "MEE", "UKS", "PEM"].map(|e| format!("{e}, p_o={po}")))
            .enumerate()
            .map(|(k, label)| BoxGroup {
                label,
                values: (0..30)
                    .map(|_| (1.0 + 0.05 * k as f64) * (0.3 * noise.sample(&mut rng)).exp())
                    .collect(),
                ..BoxGroup::default()
            })
            .collect(),
        reference_lines: vec![],
        log_y: false,
        width: 700,
        height: 450,
    };
    crowded.write(&out.join("crowded"))?;
    println!("wrote {}/{{paths,boxes,theta,many,crowded}}.{{svg,png}}", out.display());
    Ok(())
}
