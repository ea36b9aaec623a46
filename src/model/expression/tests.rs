//! Tests of expression models: parsing and evaluation against the same formulas written in Rust,
//! automatic and symbolic derivatives against central finite differences over random points
//! and parameters, and the errors of malformed model files (file, line, column, what was
//! expected). The derivative tests of every built-in model also run on their twins from model
//! files (`src/model/library/tests.rs`).

use approx::assert_relative_eq;
use num_dual::{Dual64, HyperDual64};
use proptest::prelude::*;

use super::*;
use crate::model::library::Preset;
use crate::model::Sde;

/// A model exercising every function and operator: two noisy states, one clean state, three
/// parameters, time-dependent.
fn every_function() -> ExpressionModel {
    ExpressionModel::new(
        &["x", "y"],
        &["z"],
        &["a", "b", "c"],
        &[
            "a*exp(-x^2/2) + sin(b*t)*cos(y) - tan(0.3*x) + tanh(y)*z + atan(x*y) + atan2(y, 2 + x^2)",
            "sqrt(1 + x^2 + c^2)*log(2 + y^2) + sinh(0.2*x)*cosh(0.1*y) + (1 + z^2)^c + pow(2, x/4) \
             + log1p(y^2) + expm1(x/3) + erf(x - y) + Phi(z) - x/(1 + b^2) + 2^-1*x^3",
        ],
        &["x*y - c*z"],
        Diffusion::Full(vec![vec!["c", "0.1*a"], vec!["0", "exp(b)"]]),
    )
    .unwrap()
}

/// The same drift written in Rust, in f64.
fn every_function_drift(t: f64, x: &[f64], z: &[f64], th: &[f64]) -> [f64; 3] {
    let (u, v, w) = (x[0], x[1], z[0]);
    let (a, b, c) = (th[0], th[1], th[2]);
    let f0 = a * (-u * u / 2.0).exp() + (b * t).sin() * v.cos() - (0.3 * u).tan()
        + v.tanh() * w
        + (u * v).atan()
        + v.atan2(2.0 + u * u);
    let f1 = (1.0 + u * u + c * c).sqrt() * (2.0 + v * v).ln()
        + (0.2 * u).sinh() * (0.1 * v).cosh()
        + (1.0 + w * w).powf(c)
        + 2f64.powf(u / 4.0)
        + (v * v).ln_1p()
        + (u / 3.0).exp_m1()
        + crate::model::special::erf(u - v)
        + crate::model::special::ndtr(w)
        - u / (1.0 + b * b)
        + 0.5 * u.powi(3);
    [f0, f1, u * v - c * w]
}

#[test]
fn evaluation_matches_the_formulas() {
    let m = every_function();
    let (t, x, z, th) = (0.7, [0.4, -0.9], [1.3], [0.8, 1.7, 0.6]);
    let mut f = [0.0; 2];
    let mut h = [0.0];
    m.drift(t, &x, &z, &th, &mut f);
    m.clean_drift(t, &x, &z, &th, &mut h);
    let want = every_function_drift(t, &x, &z, &th);
    for (got, want) in f.iter().chain(&h).zip(&want) {
        assert_relative_eq!(*got, *want, epsilon = 1e-15, max_relative = 1e-14);
    }
    let g = m.diffusion_matrix(&th).unwrap();
    // rows [c, 0.1 a], [0, e^b]
    assert_eq!((g[(0, 0)], g[(0, 1)], g[(1, 0)], g[(1, 1)]), (0.6, 0.1 * 0.8, 0.0, 1.7f64.exp()));
    // the clean state, t and θ as dual numbers: the same code path
    let xd = [Dual64::from(0.4).derivative(), Dual64::from(-0.9)];
    let mut fd = [Dual64::from(0.0); 2];
    let lift = |v: &[f64]| v.iter().map(|&a| Dual64::from(a)).collect::<Vec<_>>();
    m.drift(Dual64::from(t), &xd, &lift(&z), &lift(&th), &mut fd);
    assert_relative_eq!(fd[0].re, want[0], epsilon = 1e-15, max_relative = 1e-14);
}

#[test]
fn operator_precedence_and_folding() {
    let one = |e: &str| {
        let m = ExpressionModel::new(&["x"], &[], &["p"], &[e], &[], Diffusion::Scalar("p")).unwrap();
        let mut f = [0.0];
        m.drift(0.0, &[3.0], &[], &[2.0], &mut f);
        (f[0], m.tape_lengths()[0])
    };
    // −x² is −(x²); ^ is right-associative; unary minus in an exponent
    assert_eq!(one("-x^2").0, -9.0);
    assert_eq!(one("2^3^2").0, 512.0);
    assert_eq!(one("x^-1").0, 1.0 / 3.0);
    assert_eq!(one("x - p - 1").0, 0.0);
    assert_eq!(one("x / p / 3").0, 0.5);
    assert_eq!(one("1e-1*x + .5 + 2.5E+1").0, 0.30000000000000004 + 0.5 + 25.0);
    assert_eq!(one("pi*x").0, 3.0 * std::f64::consts::PI);
    // constants fold: (2·3 + 1)·x is one multiplication by 7 (and the reads of 7 and x)
    assert_eq!(one("(2*3 + 1)*x"), (21.0, 3));
    // equal subexpressions are computed once: x, p, x·p, sin(x·p), the sum
    assert_eq!(one("sin(x*p) + sin(x*p)").1, 5);
}

/// Central-difference derivative of `f` in w_i.
fn central(f: &dyn Fn(&[f64]) -> f64, w: &[f64], i: usize) -> f64 {
    let h = 1e-6 * w[i].abs().max(1.0);
    let (mut p, mut m) = (w.to_vec(), w.to_vec());
    p[i] += h;
    m[i] -= h;
    (f(&p) - f(&m)) / (p[i] - m[i])
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// Every first derivative of f, h and div_x f by dual numbers, and by the symbolic
    /// `drift_derivatives`, agrees with central differences at random points and parameters;
    /// the symbolic second derivatives agree with hyper-dual numbers.
    #[test]
    fn derivatives_match_finite_differences(
        t in 0.0..5.0f64,
        s in proptest::collection::vec(-1.5..1.5f64, 3),
        th in proptest::collection::vec(0.3..2.0f64, 3),
    ) {
        let m = every_function();
        let w: Vec<f64> = s.iter().chain(&th).copied().collect();
        let output = |o: usize| {
            let m = &m;
            move |w: &[f64]| -> f64 {
                if o == 3 {
                    return m.divergence(t, &w[..2], &w[2..3], &w[3..]);
                }
                every_function_drift(t, &w[..2], &w[2..3], &w[3..])[o]
            }
        };
        let n = w.len();
        let cols: Vec<usize> = (0..n).collect();
        let (mut jac, mut hess) = (vec![0.0; 4 * n], vec![0.0; 4 * n * (n + 1) / 2]);
        let mut out = DriftDerivatives::new(&cols, n, 4, &mut jac, &mut hess);
        prop_assert!(m.drift_derivatives(t, &w[..2], &w[2..3], &w[3..], &mut out));
        for o in 0..4 {
            let f = output(o);
            for i in 0..n {
                let fd = central(&f, &w, i);
                let sym = jac[o + i * 4];
                prop_assert!(approx::relative_eq!(sym, fd, epsilon = 1e-6, max_relative = 1e-6),
                    "d output {o} / dw_{i}: symbolic {sym}, FD {fd}");
                // the generic evaluation with dual numbers (the automatic derivative)
                let mut wd: Vec<Dual64> = w.iter().map(|&v| Dual64::from(v)).collect();
                wd[i] = wd[i].derivative();
                let ad = if o == 3 {
                    m.divergence(Dual64::from(t), &wd[..2], &wd[2..3], &wd[3..]).eps
                } else {
                    let (mut fo, mut ho) = ([Dual64::from(0.0); 2], [Dual64::from(0.0)]);
                    m.drift(Dual64::from(t), &wd[..2], &wd[2..3], &wd[3..], &mut fo);
                    m.clean_drift(Dual64::from(t), &wd[..2], &wd[2..3], &wd[3..], &mut ho);
                    [fo[0], fo[1], ho[0]][o].eps
                };
                prop_assert!(approx::relative_eq!(ad, fd, epsilon = 1e-6, max_relative = 1e-6),
                    "d output {o} / dw_{i}: AD {ad}, FD {fd}");
                for j in 0..=i {
                    let mut wh: Vec<HyperDual64> = w.iter().map(|&v| HyperDual64::from(v)).collect();
                    wh[i].eps1 = 1.0;
                    wh[j].eps2 = 1.0;
                    let th_ = HyperDual64::from(t);
                    let hd = if o == 3 {
                        m.divergence(th_, &wh[..2], &wh[2..3], &wh[3..]).eps1eps2
                    } else {
                        let (mut fo, mut ho) = ([HyperDual64::from(0.0); 2], [HyperDual64::from(0.0)]);
                        m.drift(th_, &wh[..2], &wh[2..3], &wh[3..], &mut fo);
                        m.clean_drift(th_, &wh[..2], &wh[2..3], &wh[3..], &mut ho);
                        [fo[0], fo[1], ho[0]][o].eps1eps2
                    };
                    let tri = n * (n + 1) / 2;
                    let sym2 = hess[o * tri + crate::model::packed_index(n, i, j)];
                    prop_assert!(approx::relative_eq!(sym2, hd, epsilon = 1e-10, max_relative = 1e-10),
                        "d² output {o} / dw_{i} dw_{j}: symbolic {sym2}, hyper-dual {hd}");
                }
            }
        }
    }
}

#[test]
fn parameters_in_g_only_polynomial_degrees_and_time() {
    let m = every_function();
    assert_eq!(m.drift_polynomial_degree(), None);
    assert!((0..3).all(|i| m.drift_uses_param(i)));
    let poly = ExpressionModel::new(
        &["x"],
        &["z"],
        &["a", "s"],
        &["a*x*z^2/3 - cos(a)*x"],
        &["x + t"],
        Diffusion::Scalar("s"),
    )
    .unwrap();
    assert_eq!(poly.drift_polynomial_degree(), Some(3));
    assert!(poly.drift_uses_param(0) && !poly.drift_uses_param(1));
    let rational =
        ExpressionModel::new(&["x"], &[], &["s"], &["1/(1 + x^2)"], &[], Diffusion::Scalar("s")).unwrap();
    assert_eq!(rational.drift_polynomial_degree(), None);
    // t in h alone makes the model non-autonomous.
    assert!(!poly.drift_is_autonomous() && rational.drift_is_autonomous());
}

/// The error of a model file, as `file:line:column: reason`.
fn file_error(text: &str) -> String {
    match Preset::from_toml_str(text, "bad.toml") {
        Ok(_) => panic!("accepted:\n{text}"),
        Err(e @ crate::Error::ModelFile { .. }) => e.to_string(),
        Err(other) => panic!("not a model-file error: {other}"),
    }
}

/// A valid file: the Van der Pol twin with one edit.
fn vdp_with(from: &str, to: &str) -> String {
    let text = crate::test_models::MODEL_FILES[2].1;
    assert!(text.contains(from), "{from}");
    text.replacen(from, to, 1)
}

#[test]
fn the_example_files_load() {
    for (name, _) in crate::test_models::MODEL_FILES {
        let p = crate::test_models::model_file(name).unwrap();
        assert_eq!(p.name, *name);
        p.validate().unwrap();
    }
}

#[test]
fn models_md_shows_the_example_file() {
    let doc = include_str!("../../../docs/models.md");
    let example = include_str!("../../../examples/models/pendulum.toml");
    assert!(
        doc.contains(example.trim_end()),
        "docs/models.md is out of date with examples/models/pendulum.toml"
    );
    let p = crate::test_models::model_file("pendulum").unwrap();
    assert_eq!(p.estimate, [true, true, false, true]);
    assert_eq!(p.observation.names, ["angle"]);
    // the forcing with a zero amplitude is folded away: −g/l·sin φ − c·ω is g/l, φ, sin φ,
    // the product, c, ω, the product, the difference and its negated first term
    let crate::model::library::Model::Expression(m) = &p.model else { panic!("an expression model") };
    assert!(m.tape_lengths()[0] <= 9, "{:?}", m.tape_lengths());
}

#[test]
fn malformed_files_name_line_column_and_what_was_expected() {
    let cases: Vec<(String, &str)> = vec![
        // an empty file
        (String::new(), "bad.toml:1:1: empty model file"),
        // a TOML syntax error
        (vdp_with("mu = { value = 2.0 }", "mu = { value = 2.0"), "bad.toml:13:1: TOML syntax: missing comma"),
        // a syntax error inside an expression: the column of the second `*`
        (vdp_with("\"-u + mu * (1 - u*u) * v\"", "\"-u + mu * * v\""), "bad.toml:18:16: drift component 2: unexpected `*`"),
        // an unclosed parenthesis, pointed at
        (vdp_with("\"-u + mu * (1 - u*u) * v\"", "\"-u + mu * (1 - u*u * v\""), "bad.toml:18:16: drift component 2: this `(` is not closed"),
        // an unknown symbol
        (vdp_with("\"-u + mu * (1 - u*u) * v\"", "\"-u + nu * (1 - u*u) * v\""), "bad.toml:18:11: drift component 2: unknown symbol `nu` (known: t, u, v, mu, sigma, pi)"),
        // an unknown function
        (vdp_with("\"-u + mu * (1 - u*u) * v\"", "\"-u + mu * sec(u) * v\""), "bad.toml:18:16: drift component 2: unknown function `sec`"),
        // a function with the wrong number of arguments
        (vdp_with("\"-u + mu * (1 - u*u) * v\"", "\"-u + mu * atan2(u) * v\""), "bad.toml:18:16: drift component 2: `atan2` takes 2 arguments, got 1"),
        (vdp_with("\"-u + mu * (1 - u*u) * v\"", "\"-u + mu * exp(u, v)\""), "bad.toml:18:16: drift component 2: `exp` takes 1 argument, got 2"),
        // a drift with the wrong number of components
        (vdp_with("    \"v\",\n", ""), "bad.toml:16:9: `drift` has 1 components, expected 2: one expression per noisy state (u, v)"),
        // a diffusion that is not square
        (vdp_with("diffusion = \"sigma\"", "diffusion = [[\"sigma\", \"0\"]]"), "bad.toml:20:13: G must be square, 2 × 2"),
        (vdp_with("diffusion = \"sigma\"", "diffusion = [[\"sigma\", \"0\"], [\"0\"]]"), "bad.toml:20:30: G must be square, 2 × 2 (one row and column per noisy state u, v): row 2 has 1 entries"),
        // a diffusion that is not invertible at the nominal parameters
        (vdp_with("diffusion = \"sigma\"", "diffusion = [[\"sigma\", \"sigma\"], [\"sigma\", \"sigma\"]]"), "bad.toml:20:13: G must be invertible at the nominal parameters: singular"),
        // a diffusion that depends on the state
        (vdp_with("diffusion = \"sigma\"", "diffusion = \"sigma*u\""), "bad.toml:20:20: diffusion entry (1, 1): G(theta) may depend on the parameters only, not on the noisy state `u`"),
        // a likelihood with the wrong number of outputs
        (vdp_with("states = [\"u\"]", "states = [\"u\"]\nnames = [\"y1\", \"y2\"]"), "bad.toml:28:9: the likelihood has 1 outputs (`states`) but `names` has 2"),
        // a likelihood naming an unknown parameter
        (vdp_with("p=0.25", "p=p_o"), "bad.toml:28:14: likelihood: unknown parameter `p_o`"),
        // a parameter both fixed and estimated
        (vdp_with("[dynamics]", "[constants]\nmu = 2.0\n\n[dynamics]").replace("mu = { value = 2.0 }", "mu = { value = 2.0, estimate = true }"),
         "bad.toml:12:1: `mu` is both fixed (a constant, line 16) and estimated"),
        // an unknown key, a missing section, a measured state that does not exist
        (vdp_with("dt = 5e-4", "dt = 5e-4\nsteps = 10"), "bad.toml:34:1: unknown key `steps` in [simulation] (expected one of: t_end, dt)"),
        (vdp_with("[initial]\nu = \"normal:0,0.1\"\nv = \"normal:0,0.1\"\n", ""), "bad.toml:1:1: missing table [initial]"),
        (vdp_with("states = [\"u\"]", "states = [\"w\"]"), "bad.toml:27:11: unknown state `w` (known: u, v)"),
        // a reserved name
        (vdp_with("noisy = [\"u\", \"v\"]", "noisy = [\"u\", \"t\"]"), "bad.toml:9:15: `t` is reserved"),
    ];
    assert!(cases.len() >= 10);
    for (text, want) in &cases {
        let got = file_error(text);
        assert!(got.starts_with(want), "expected `{want}…`, got `{got}`");
    }
}

#[test]
fn programmatic_errors_name_the_expression_and_character() {
    let e = ExpressionModel::new(&["x"], &[], &["s"], &["x +* 2"], &[], Diffusion::Scalar("s")).unwrap_err();
    assert_eq!(e.to_string(), "invalid option `drift component 1`: at character 4 of `x +* 2`: unexpected `*`; expected a number, a name or `(`");
    let e = ExpressionModel::new(&["x"], &[], &["s"], &["x", "x"], &[], Diffusion::Scalar("s")).unwrap_err();
    assert!(matches!(e, crate::Error::DimensionMismatch { .. }));
    let e = ExpressionModel::new(&["x"], &[], &["x"], &["x"], &[], Diffusion::Scalar("1")).unwrap_err();
    assert!(e.to_string().contains("`x` is declared twice"), "{e}");
}
