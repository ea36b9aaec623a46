use super::*;
use crate::compare::{compare, CompareOptions, Comparison};
use crate::estimator::parse_list;
use crate::model::library::preset;
use crate::model::{Noise, Param, Sde};
use crate::plot::{Prim, Scene};
use crate::test_models::PresetRecord;

/// Every label of every series of every panel (overviews first) with its colour and dash.
fn drawn_looks(figure: &Panels<LinePlot>) -> Vec<(String, Look)> {
    figure
        .header
        .iter()
        .chain(&figure.panels)
        .flat_map(|p| &p.series)
        .filter_map(|s| s.color.map(|color| (s.label.clone(), Look { color, dash: s.dash })))
        .collect()
}

/// Checks the looks of `figure` against `looks`: the truth black and solid, the data grey, every
/// other series in the look of its estimator, and no estimator in the truth's or the data's
/// colour. Returns the estimators' labels as drawn.
fn assert_one_look_per_estimator(figure: &Panels<LinePlot>, looks: &EstimatorLooks) -> Vec<String> {
    let mut estimators = Vec::new();
    for (label, look) in drawn_looks(figure) {
        if label == "truth" {
            assert_eq!(look, Look { color: TRUTH, dash: Dash::Solid });
        } else if label.starts_with("data") {
            assert_eq!(look.color, DATA);
        } else {
            assert_eq!(look, looks.look(&label), "{label}");
            assert!(look.color != TRUTH && look.color != DATA, "{label} in a reserved colour");
            estimators.push(label);
        }
    }
    // Every series has an explicit colour (none takes a palette colour by its position).
    let series = figure.header.iter().chain(&figure.panels).flat_map(|p| &p.series);
    assert!(series.clone().all(|s| s.color.is_some()));
    estimators
}

/// The double-well preset on [0, 5] from x(0) = 1 (step 0.01), measured every 0.5, compared
/// with `methods` (the text of `onsager compare --methods`).
fn double_well(methods: &str) -> (PresetRecord, Comparison) {
    let mut p = preset("double-well").unwrap();
    (p.t_end, p.dt, p.sample_every) = (5.0, 0.01, 0.5);
    let record = PresetRecord::simulate_from(p, 2, &[1.0], &[]).unwrap();
    let problem = record.problem(&[]);
    let estimators = parse_list(methods).unwrap();
    let c = compare(&problem, &estimators, Some(&record.truth), &CompareOptions::default()).unwrap();
    (record, c)
}

fn figure(record: &PresetRecord, c: &Comparison) -> Panels<LinePlot> {
    let p = &record.preset;
    c.figure(&p.model.state_names(), &record.data, &p.observation, Some(&record.truth), "double well")
}

/// The texts of a scene.
fn texts(scene: &Scene) -> Vec<&str> {
    scene
        .prims
        .iter()
        .filter_map(|p| if let Prim::Text { text, .. } = p { Some(text.as_str()) } else { None })
        .collect()
}

/// A run of two estimators, one of them failing, the Laplace sd of another skipped: every
/// panel draws an estimator in one look, the one of the run's [`EstimatorLooks`].
const METHODS: &str =
    "ksp,uks,jme:laplace_max_states=5,label=jme,mee,jme:transcription=euler,label=euler,pem";

#[test]
fn an_estimator_has_one_look_in_every_panel_and_none_has_the_truths_or_the_datas() {
    let (record, c) = double_well(METHODS);
    assert_eq!(c.rows[5].status, crate::estimate::RowStatus::Error, "pem without parameters to estimate");
    let fig = figure(&record, &c);
    let looks = c.looks();
    let drawn = assert_one_look_per_estimator(&fig, &looks);
    // Each estimator with an estimate is drawn twice: in the overview and in its panel.
    for label in ["ksp", "uks", "jme", "mee", "euler"] {
        assert_eq!(drawn.iter().filter(|l| *l == label).count(), 2, "{label}");
    }
    assert!(!drawn.iter().any(|l| l == "pem"));
    // The looks are the methods' fixed ones; `euler`, a second jme, has one no other has.
    for (label, method) in
        [("ksp", Method::Ksp), ("uks", Method::Uks), ("jme", Method::Jme), ("mee", Method::Mee)]
    {
        assert_eq!(looks.look(label), method_look(method));
    }
    let taken: Vec<Look> = looks.iter().filter(|(l, _)| *l != "euler").map(|(_, look)| look).collect();
    assert!(!taken.iter().any(|l| l.color == looks.look("euler").color));
}

#[test]
fn the_looks_are_fixed_distinct_and_never_the_reserved_ones() {
    // Every method has its own look.
    let all: Vec<Look> = Method::ALL.iter().map(|&m| method_look(m)).collect();
    for (i, a) in all.iter().enumerate() {
        assert!(a.color != TRUTH && a.color != DATA);
        assert!(PALETTE.contains(&a.color));
        assert!(!all[..i].contains(a), "{:?} shares its look", Method::ALL[i]);
    }
    // The default comparison: nine estimators in nine colours, solid, and the Gaussian KSP
    // closure dashed (the palette has nine colours); no two share a look.
    let defaults = crate::compare::DEFAULT_METHODS;
    let solid: Vec<Method> = defaults.iter().copied().filter(|&m| m != Method::GaussianKspClosure).collect();
    assert_eq!(solid.len(), PALETTE.len());
    let colors: Vec<Color> = solid.iter().map(|&m| method_look(m).color).collect();
    for (i, c) in colors.iter().enumerate() {
        assert!(!colors[..i].contains(c));
        assert_eq!(method_look(solid[i]).dash, Dash::Solid);
    }
    let looks: Vec<Look> = defaults.iter().map(|&m| method_look(m)).collect();
    for (i, l) in looks.iter().enumerate() {
        assert!(!looks[..i].contains(l), "{:?} shares its look", defaults[i]);
    }
    // Forty estimators of one method: looks distinct as far as the palette and the dashes go
    // (36), then repeated, never the truth's or the data's; the same list gives the same looks.
    let labels: Vec<String> = (0..40).map(|i| format!("jme {i}")).collect();
    let list = || labels.iter().map(|l| (l.as_str(), Method::Jme));
    let looks = EstimatorLooks::new(list());
    assert_eq!(looks, EstimatorLooks::new(list()));
    let drawn: Vec<Look> = looks.iter().map(|(_, l)| l).collect();
    assert_eq!(drawn[0], method_look(Method::Jme), "the first of the method has its look");
    for (i, l) in drawn.iter().enumerate() {
        assert!(l.color != TRUTH && l.color != DATA);
        if i < PALETTE.len() * Dash::ALL.len() {
            assert!(!drawn[..i].contains(l), "look {i} repeats");
        }
    }
    // The estimator named after its method has the method's look wherever it comes in the list.
    let looks = EstimatorLooks::new([("euler", Method::Jme), ("uks", Method::Uks), ("jme", Method::Jme)]);
    assert_eq!(looks.look("jme"), method_look(Method::Jme));
    assert_eq!(looks.look("uks"), method_look(Method::Uks));
    assert_ne!(looks.look("euler").color, method_look(Method::Jme).color);
}

#[test]
fn titles_claim_bands_only_where_bands_are_drawn_and_say_why_there_are_none() {
    let (record, c) = double_well(METHODS);
    let fig = figure(&record, &c);
    let scene = fig.scene().unwrap();
    let texts = texts(&scene);
    // The top title says nothing of bands.
    assert!(!fig.title.contains("sd") && !fig.title.contains("band"));
    for p in fig.header.iter().chain(&fig.panels) {
        let banded = p.series.iter().any(|s| s.band.is_some());
        assert_eq!(p.title.contains("± 2 sd"), banded, "{}", p.title);
        // What the title says is what the figure shows.
        for line in p.title.lines() {
            assert!(texts.contains(&line), "{line}");
        }
    }
    for p in &fig.header {
        assert!(p.title.contains("no bands"));
    }
    // An estimator's title, its lines joined by spaces.
    let title = |label: &str| -> String {
        let prefix = format!("{label}\n");
        let t = fig.panels.iter().map(|p| p.title.as_str()).find(|t| t.starts_with(&prefix)).unwrap();
        t.lines().collect::<Vec<_>>().join(" ")
    };
    // ksp and uks have their bands, mee its Laplace band.
    assert_eq!(title("ksp"), "ksp path ± 2 sd");
    assert_eq!(title("uks"), "uks path ± 2 sd");
    assert_eq!(title("mee"), "mee path ± 2 sd (Laplace)");
    // jme skipped its Laplace sd (more than 5 node states) and says so, with the remedy.
    assert_eq!(
        title("jme"),
        "jme path, no sd (Laplace skipped above 5 node states; raise laplace_max_states)"
    );
    // pem did not run and says why.
    let pem = title("pem");
    assert!(pem.starts_with("pem no estimate: ") && pem.contains("--estimate"), "{pem}");
    let pem = fig.panels.iter().find(|p| p.title.starts_with("pem\n")).unwrap();
    assert!(pem.series.iter().all(|s| s.label == "truth" || s.label == "data"));
}

#[test]
fn long_lines_under_a_title_wrap_in_two_lines_at_most() {
    assert_eq!(wrap("path ± 2 sd", 20), "path ± 2 sd");
    assert_eq!(wrap("path, no sd (Laplace sd off)", 16), "path, no sd\n(Laplace sd off)");
    assert_eq!(wrap("one two three four five", 9), "one two\nthree…");
    assert_eq!(wrap("abcdefghijklmnopqrstuvwxyz", 10), "abcdefghi…");
    assert_eq!(wrap("", 10), "");
}

#[test]
fn small_multiples_share_their_axes_for_two_to_twelve_estimators() {
    let (record, c) = double_well("ksp,uks,mee");
    let p = &record.preset;
    let names = p.model.state_names();
    let estimates: Vec<&PathEstimate> = c.estimates.iter().flatten().collect();
    for n in 2..=12 {
        let labels: Vec<String> = (0..n).map(|i| format!("estimator {i}")).collect();
        let looks = EstimatorLooks::new(labels.iter().map(|l| (l.as_str(), Method::Jme)));
        let fig = PathFigure {
            title: format!("{n} estimators"),
            states: &names,
            truth: Some(&record.truth),
            data: &record.data,
            measured: &p.observation.states,
            estimates: labels
                .iter()
                .enumerate()
                .map(|(i, l)| (l.as_str(), Outcome::Estimate(estimates[i % 3])))
                .collect(),
            looks: &looks,
        }
        .panels();
        assert_eq!((fig.header.len(), fig.panels.len()), (1, n));
        assert_eq!(fig.columns, if n <= 2 || n == 4 { 2 } else { 3 });
        // One frame for all; one legend, in the overview, listing the truth, every estimator and
        // the data; every estimator in a look of its own.
        let frame = (fig.header[0].x_range, fig.header[0].y_range);
        assert!(frame.0.is_some() && frame.1.is_some());
        assert!(fig.panels.iter().all(|q| (q.x_range, q.y_range) == frame));
        assert!(fig.header[0].legend && fig.panels.iter().all(|q| !q.legend));
        assert_eq!(fig.header[0].series.len(), n + 2);
        let drawn = assert_one_look_per_estimator(&fig, &looks);
        assert_eq!(drawn.len(), 2 * n);
        let distinct: Vec<Look> = labels.iter().map(|l| looks.look(l)).collect();
        assert!((1..n).all(|i| !distinct[..i].contains(&distinct[i])));
        assert!(fig.scene().is_ok());
    }
}

#[test]
fn a_multi_state_figure_has_an_overview_and_a_column_per_state() {
    let mut p = preset("van-der-pol").unwrap();
    (p.t_end, p.dt, p.sample_every) = (2.0, 0.005, 0.1);
    // Measured with Gaussian errors (the preset's outliers are beside the point here).
    p.observation.noise = Noise::Gaussian { sigma: Param::Fixed(0.5) };
    let record = PresetRecord::simulate_from(p, 3, &[0.0, 0.0], &[]).unwrap();
    let problem = record.problem(&[]);
    let estimators = parse_list("uks,jme:step=0.02,laplace_max_states=0").unwrap();
    let c = compare(&problem, &estimators, Some(&record.truth), &CompareOptions::default()).unwrap();
    let fig = figure(&record, &c);
    let looks = c.looks();
    assert_one_look_per_estimator(&fig, &looks);
    assert_eq!((fig.header.len(), fig.panels.len(), fig.columns), (2, 4, 2));
    let titles: Vec<&str> = fig.panels.iter().map(|q| q.title.as_str()).collect();
    assert_eq!(
        titles,
        [
            "uks (u)\npath ± 2 sd",
            "uks (v)\npath ± 2 sd",
            "jme (u)\npath, no sd (Laplace sd off: laplace_max_states = 0)",
            "jme (v)\npath, no sd (Laplace sd off: laplace_max_states = 0)",
        ]
    );
    // The panels of a state share its overview's axes; only u is measured.
    for (i, q) in fig.panels.iter().enumerate() {
        let overview = &fig.header[i % 2];
        assert_eq!(
            (q.x_range, q.y_range, &q.y_label),
            (overview.x_range, overview.y_range, &overview.y_label)
        );
        assert_eq!(q.series.iter().any(|s| s.label == "data"), i % 2 == 0);
    }
    // An estimator is drawn in one look in both states' panels.
    let jme: Vec<Look> =
        drawn_looks(&fig).into_iter().filter(|(l, _)| l == "jme").map(|(_, look)| look).collect();
    assert_eq!(jme.len(), 4);
    assert!(jme.iter().all(|l| *l == method_look(Method::Jme)));
}
