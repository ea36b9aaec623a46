//! Property-based fuzzing of the readers: the measurement and path CSV reader, the experiment
//! spec reader and the model-file reader. Inputs are arbitrary bytes and text, and structured
//! mutations of valid files (cells replaced by garbage, lines dropped, duplicated or swapped,
//! huge, NaN and infinite numbers, unicode, long lines, random TOML keys and values, deeply
//! nested expressions). The property: the reader returns `Ok` or a typed error, never panics;
//! input sizes are bounded so that a case cannot run long.
//!
//! The suite runs a modest number of cases per reader; `ONSAGER_FUZZ_CASES` raises it, e.g.
//! `ONSAGER_FUZZ_CASES=100000 cargo test --release --test main fuzz` (docs/extending.md,
//! "Fuzzing the readers").

use std::path::Path;
use std::time::{Duration, Instant};

use onsager::data::{Dataset, StatePath};
use onsager::experiment::Experiment;
use onsager::model::library::{Model, Preset};
use onsager::model::Sde;
use proptest::prelude::*;
use proptest::test_runner::{Config, TestRunner};

/// Cases per reader: `ONSAGER_FUZZ_CASES`, else a number that keeps the suite quick.
fn cases() -> u32 {
    std::env::var("ONSAGER_FUZZ_CASES").ok().and_then(|s| s.parse().ok()).unwrap_or(300)
}

/// Runs `check` on `cases()` inputs of `strategy`; a panic in `check` fails the test with the
/// shrunk input. When the number of cases was raised, prints the count, the total time and the
/// slowest case (the long runs' record).
fn fuzz<S: Strategy>(name: &str, strategy: S, check: impl Fn(S::Value))
where
    S::Value: std::fmt::Debug,
{
    let n = cases();
    let config = Config { cases: n, failure_persistence: None, ..Config::default() };
    let mut runner = TestRunner::new(config);
    let start = Instant::now();
    let slowest = std::cell::Cell::new(Duration::ZERO);
    let result = runner.run(&strategy, |input| {
        let t = Instant::now();
        check(input);
        slowest.set(slowest.get().max(t.elapsed()));
        Ok(())
    });
    if let Err(e) = result {
        panic!("fuzz {name}: {e}");
    }
    if std::env::var_os("ONSAGER_FUZZ_CASES").is_some() {
        eprintln!(
            "fuzz {name}: {n} cases in {:.1} s, slowest case {:.3} s",
            start.elapsed().as_secs_f64(),
            slowest.get().as_secs_f64()
        );
    }
}

// ---------------------------------------------------------------------------------------------
// Building blocks

/// Text that readers find hard: numbers at and beyond the limits of f64, non-numbers, unicode,
/// separators and quotes, long runs of digits, random short text.
fn garbage() -> impl Strategy<Value = String> {
    prop_oneof![
        prop::sample::select(vec![
            "", " ", "nan", "NaN", "-nan", "inf", "-inf", "+inf", "infinity", "1e300", "-1e300", "1e308",
            "1e309", "-1e309", "1e-320", "4.9e-324", "0", "-0", "+", "-", ".", "e5", "1e", "0x10", "1_000",
            "1,5", "\"", "\"\"", "\"1\"", ",", ",,", "\n", "\r\n", "\t", "\u{feff}", "x", "ü", "😀", "٣",
            "１", "−1", "true", "[]", "{}", "=", "#", "[", "]", "'", "\\", "\0",
        ])
        .prop_map(str::to_string),
        any::<f64>().prop_map(|v| v.to_string()),
        any::<f64>().prop_map(|v| format!("{v:e}")),
        any::<i64>().prop_map(|v| v.to_string()),
        "[0-9eE+.-]{0,30}",
        "\\PC{0,12}",
        (1usize..3000).prop_map(|n| "9".repeat(n)),
    ]
}

/// Edits of a text seen as lines: each picks its lines modulo their number.
#[derive(Debug, Clone)]
enum LineEdit {
    Drop(usize),
    Duplicate(usize),
    Swap(usize, usize),
    Replace(usize, String),
    Insert(usize, String),
    /// Replaces the text after the first `=` or `,` at or after byte `at` of the line.
    Value(usize, usize, String),
    /// Inserts `text` at byte `at` (rounded down to a char boundary) of the line.
    Splice(usize, usize, String),
    LongLine(usize, usize),
    Truncate(usize),
    CrLf,
    Bom,
}

fn line_edit(extra: BoxedStrategy<String>) -> impl Strategy<Value = LineEdit> {
    let i = any::<usize>();
    prop_oneof![
        i.prop_map(LineEdit::Drop),
        i.prop_map(LineEdit::Duplicate),
        (i, i).prop_map(|(a, b)| LineEdit::Swap(a, b)),
        (i, extra.clone()).prop_map(|(a, s)| LineEdit::Replace(a, s)),
        (i, extra.clone()).prop_map(|(a, s)| LineEdit::Insert(a, s)),
        (i, i, extra.clone()).prop_map(|(a, b, s)| LineEdit::Value(a, b, s)),
        (i, i, extra).prop_map(|(a, b, s)| LineEdit::Splice(a, b, s)),
        (i, 1usize..20_000).prop_map(|(a, n)| LineEdit::LongLine(a, n)),
        i.prop_map(LineEdit::Truncate),
        Just(LineEdit::CrLf),
        Just(LineEdit::Bom),
    ]
}

fn floor_boundary(s: &str, at: usize) -> usize {
    let mut at = at.min(s.len());
    while !s.is_char_boundary(at) {
        at -= 1;
    }
    at
}

/// Applies `edits` to `text` line by line.
fn apply(text: &str, edits: &[LineEdit]) -> String {
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    let mut crlf = false;
    let mut bom = false;
    for edit in edits {
        let n = lines.len().max(1);
        if lines.is_empty() {
            lines.push(String::new());
        }
        match edit {
            LineEdit::Drop(a) => {
                lines.remove(a % n);
            }
            LineEdit::Duplicate(a) => {
                let l = lines[a % n].clone();
                lines.insert(a % n, l);
            }
            LineEdit::Swap(a, b) => lines.swap(a % n, b % n),
            LineEdit::Replace(a, s) => lines[a % n] = s.clone(),
            LineEdit::Insert(a, s) => lines.insert(a % (n + 1), s.clone()),
            LineEdit::Value(a, b, s) => {
                let l = &mut lines[a % n];
                let from = floor_boundary(l, b % (l.len() + 1));
                if let Some(k) = l[from..].find(['=', ',']) {
                    l.truncate(from + k + 1);
                    l.push_str(s);
                }
            }
            LineEdit::Splice(a, b, s) => {
                let l = &mut lines[a % n];
                let at = floor_boundary(l, b % (l.len() + 1));
                l.insert_str(at, s);
            }
            LineEdit::LongLine(a, len) => {
                let l = &mut lines[a % n];
                let fill = l.clone();
                while l.len() < *len && !fill.is_empty() {
                    l.push_str(&fill);
                }
                if fill.is_empty() {
                    l.push_str(&"1".repeat(*len));
                }
            }
            LineEdit::Truncate(a) => lines.truncate(a % (n + 1)),
            LineEdit::CrLf => crlf = true,
            LineEdit::Bom => bom = true,
        }
    }
    let mut out = if bom { "\u{feff}".to_string() } else { String::new() };
    out.push_str(&lines.join(if crlf { "\r\n" } else { "\n" }));
    out
}

// ---------------------------------------------------------------------------------------------
// The CSV reader

/// A valid measurement or path file: `t` and 1 to 3 columns (`sd_` columns for a path), rows at
/// increasing times, some cells empty.
fn valid_csv() -> impl Strategy<Value = String> {
    (1usize..4, prop::bool::ANY, 0usize..40, 0.001f64..10.0, -5.0f64..5.0, any::<u64>()).prop_map(
        |(cols, with_sd, rows, dt, t0, bits)| {
            let names: Vec<String> = (0..cols).map(|j| format!("y{j}")).collect();
            let mut header = vec!["t".to_string()];
            header.extend(names.iter().cloned());
            if with_sd {
                header.extend(names.iter().map(|n| format!("sd_{n}")));
            }
            let mut out = header.join(",");
            for i in 0..rows {
                out.push('\n');
                let t = t0 + i as f64 * dt;
                let mut row = vec![t.to_string()];
                for j in 1..header.len() {
                    let empty = (bits >> ((i * 7 + j) % 64)) & 1 == 1 && i % 3 == 0;
                    row.push(if empty { String::new() } else { format!("{:.4}", (t * j as f64).sin()) });
                }
                out.push_str(&row.join(","));
            }
            out
        },
    )
}

fn csv_input() -> impl Strategy<Value = Vec<u8>> {
    let edits = prop::collection::vec(line_edit(garbage().boxed()), 0..6);
    prop_oneof![
        prop::collection::vec(any::<u8>(), 0..2048),
        "\\PC{0,400}".prop_map(String::into_bytes),
        (valid_csv(), edits).prop_map(|(text, edits)| apply(&text, &edits).into_bytes()),
    ]
}

fn read_csv_all_ways(bytes: &[u8]) {
    let path = Path::new("fuzz.csv");
    let _ = Dataset::from_reader(bytes, path, None);
    let outputs = vec!["y0".to_string(), "y1".to_string()];
    let _ = Dataset::from_reader(bytes, path, Some(&outputs));
    let _ = StatePath::from_reader(bytes, path);
}

#[test]
fn fuzz_csv_reader() {
    fuzz("csv", csv_input(), |bytes| read_csv_all_ways(&bytes));
}

// ---------------------------------------------------------------------------------------------
// TOML documents: the experiment spec and the model file

/// A random TOML value: scalars of every kind (including non-finite and huge numbers), arrays and
/// inline tables, nested a few levels.
fn toml_value() -> impl Strategy<Value = toml::Value> {
    let leaf = prop_oneof![
        any::<i64>().prop_map(toml::Value::Integer),
        prop_oneof![
            any::<f64>(),
            Just(f64::NAN),
            Just(f64::INFINITY),
            Just(f64::NEG_INFINITY),
            Just(1e300),
            Just(0.0),
            Just(-1.0),
            Just(1e-300),
        ]
        .prop_map(toml::Value::Float),
        any::<bool>().prop_map(toml::Value::Boolean),
        garbage().prop_map(toml::Value::String),
        "[a-z_]{1,12}".prop_map(toml::Value::String),
        "[a-z]{1,6}:[a-z_]{1,6}=[0-9.]{1,4}".prop_map(toml::Value::String),
    ];
    leaf.prop_recursive(3, 24, 6, |inner| {
        prop_oneof![
            prop::collection::vec(inner.clone(), 0..6).prop_map(toml::Value::Array),
            prop::collection::btree_map(key(), inner, 0..4)
                .prop_map(|m| toml::Value::Table(m.into_iter().collect())),
        ]
    })
}

/// A key: one a reader knows (taken from the valid files) or a random one.
fn key() -> impl Strategy<Value = String> {
    prop_oneof![
        prop::sample::select(vec![
            "name",
            "method",
            "estimate",
            "options",
            "params",
            "replicates",
            "seed",
            "metrics",
            "every",
            "first",
            "generate",
            "t_end",
            "dt",
            "scheme",
            "file",
            "grid",
            "quick",
            "model",
            "simulation",
            "measurements",
            "estimators",
            "states",
            "noisy",
            "clean",
            "parameters",
            "value",
            "prior",
            "bounds",
            "dynamics",
            "drift",
            "clean_drift",
            "diffusion",
            "initial",
            "likelihood",
            "x",
            "z",
            "D",
            "sigma_y",
            "step",
            "transcription",
            "grid.t_f",
            "estimators.jme.options.step",
        ])
        .prop_map(str::to_string),
        "[a-zA-Z_.]{1,16}",
        "\\PC{1,8}",
    ]
}

/// Structured edits of a parsed TOML document: set a value at a (possibly new) key path,
/// remove a key, or replace a leaf value by a random one.
#[derive(Debug, Clone)]
enum TomlEdit {
    Set(Vec<usize>, String, toml::Value),
    Remove(Vec<usize>),
}

fn toml_edit() -> impl Strategy<Value = TomlEdit> {
    let path = prop::collection::vec(any::<usize>(), 0..4);
    prop_oneof![
        (path.clone(), key(), toml_value()).prop_map(|(p, k, v)| TomlEdit::Set(p, k, v)),
        path.prop_map(TomlEdit::Remove),
    ]
}

/// Follows `path` (indices modulo the number of entries) down through tables and arrays.
fn descend<'a>(value: &'a mut toml::Value, path: &[usize]) -> &'a mut toml::Value {
    let Some((&i, rest)) = path.split_first() else { return value };
    let has_children = match &*value {
        toml::Value::Table(t) => !t.is_empty(),
        toml::Value::Array(a) => !a.is_empty(),
        _ => false,
    };
    if !has_children {
        return value;
    }
    let next = match value {
        toml::Value::Table(t) => {
            let k = t.keys().nth(i % t.len()).expect("in range").clone();
            t.get_mut(&k).expect("present")
        }
        toml::Value::Array(a) => {
            let n = a.len();
            &mut a[i % n]
        }
        _ => unreachable!("checked above"),
    };
    descend(next, rest)
}

fn edit_toml(text: &str, edits: &[TomlEdit]) -> String {
    let Ok(table) = text.parse::<toml::Table>() else { return text.to_string() };
    let mut doc = toml::Value::Table(table);
    for edit in edits {
        match edit {
            TomlEdit::Set(path, key, value) => match descend(&mut doc, path) {
                toml::Value::Table(t) => {
                    t.insert(key.clone(), value.clone());
                }
                toml::Value::Array(a) => a.push(value.clone()),
                leaf => *leaf = value.clone(),
            },
            TomlEdit::Remove(path) => {
                if let Some((last, parent)) = path.split_last() {
                    match descend(&mut doc, parent) {
                        toml::Value::Table(t) if !t.is_empty() => {
                            let k = t.keys().nth(last % t.len()).expect("in range").clone();
                            t.remove(&k);
                        }
                        toml::Value::Array(a) if !a.is_empty() => {
                            let n = a.len();
                            a.remove(last % n);
                        }
                        _ => {}
                    }
                }
            }
        }
    }
    toml::to_string(&doc).unwrap_or_default()
}

/// A TOML line that may or may not make sense where it lands.
fn toml_line() -> BoxedStrategy<String> {
    prop_oneof![
        (key(), toml_value()).prop_map(|(k, v)| format!("{k} = {v}")),
        key().prop_map(|k| format!("[{k}]")),
        key().prop_map(|k| format!("[[{k}]]")),
        garbage(),
    ]
    .boxed()
}

/// Inputs built from the valid documents `bases`: arbitrary text, structured edits of the parsed
/// document, and line edits of its text.
fn toml_input(bases: Vec<&'static str>, values: BoxedStrategy<String>) -> impl Strategy<Value = String> {
    let base = prop::sample::select(bases);
    let line = prop_oneof![toml_line(), values].boxed();
    prop_oneof![
        1 => "\\PC{0,400}",
        1 => prop::collection::vec(any::<u8>(), 0..1024).prop_map(|b| String::from_utf8_lossy(&b).into_owned()),
        3 => (base.clone(), prop::collection::vec(toml_edit(), 1..4)).prop_map(|(t, e)| edit_toml(t, &e)),
        3 => (base, prop::collection::vec(line_edit(line), 1..5)).prop_map(|(t, e)| apply(t, &e)),
    ]
}

// ---------------------------------------------------------------------------------------------
// The experiment spec reader

const SPECS: [&str; 7] = [
    include_str!("../experiments/double-well-jumps.toml"),
    include_str!("../experiments/duffing-gaussian.toml"),
    include_str!("../experiments/duffing-outliers.toml"),
    include_str!("../experiments/holmes-rand-quantized.toml"),
    include_str!("../experiments/lorenz63-smoothing.toml"),
    include_str!("../experiments/tanh-limits.toml"),
    include_str!("../experiments/vdp-robust.toml"),
];

#[test]
fn fuzz_spec_reader() {
    for spec in SPECS {
        Experiment::from_toml(spec).expect("the committed specs are valid");
    }
    fuzz("spec", toml_input(SPECS.to_vec(), garbage().boxed()), |text| {
        let _ = Experiment::from_toml(&text);
    });
}

// ---------------------------------------------------------------------------------------------
// The model-file reader

const MODELS: [&str; 9] = [
    include_str!("../examples/models/double-well.toml"),
    include_str!("../examples/models/duffing.toml"),
    include_str!("../examples/models/holmes-rand.toml"),
    include_str!("../examples/models/lorenz63.toml"),
    include_str!("../examples/models/lorenz96.toml"),
    include_str!("../examples/models/ou.toml"),
    include_str!("../examples/models/pendulum.toml"),
    include_str!("../examples/models/tanh.toml"),
    include_str!("../examples/models/van-der-pol.toml"),
];

/// A random expression over the names the example files declare: numbers at the limits,
/// functions with right and wrong arities, unknown names, operators in a row, deep nesting.
fn expression() -> impl Strategy<Value = String> {
    let leaf = prop_oneof![
        prop::sample::select(vec![
            "x", "z", "y", "D", "t", "a", "b", "sigma", "theta", "pi", "e", "1", "0", "1e300", "1e309",
            "nan", "inf", "-0", "2.5", "q", "sin", "",
        ])
        .prop_map(str::to_string),
        any::<f64>().prop_map(|v| format!("{v:e}")),
    ];
    let expr = leaf.prop_recursive(5, 40, 3, |inner| {
        prop_oneof![
            (inner.clone(), prop::sample::select(vec!["+", "-", "*", "/", "^", "", " ", ","]), inner.clone())
                .prop_map(|(a, op, b)| format!("{a}{op}{b}")),
            inner.clone().prop_map(|a| format!("({a})")),
            inner.clone().prop_map(|a| format!("-{a}")),
            (
                prop::sample::select(vec![
                    "sin", "cos", "exp", "log", "sqrt", "tanh", "abs", "atan2", "pow", "foo", "max",
                ]),
                prop::collection::vec(inner, 0..4)
            )
                .prop_map(|(f, args)| format!("{f}({})", args.join(","))),
        ]
    });
    prop_oneof![
        4 => expr,
        1 => (1usize..3000).prop_map(|n| format!("{}x{}", "(".repeat(n), ")".repeat(n))),
        1 => (1usize..3000).prop_map(|n| format!("{}x", "-".repeat(n))),
        1 => (1usize..3000).prop_map(|n| format!("x{}", "^x".repeat(n))),
        1 => (1usize..3000).prop_map(|n| format!("{}x{}", "sin(".repeat(n), ")".repeat(n))),
        1 => (1usize..3000).prop_map(|n| vec!["x"; n].join("*")),
    ]
}

/// A TOML value holding an expression: a string, or a list of strings (a drift).
fn expression_value() -> BoxedStrategy<String> {
    prop_oneof![
        expression().prop_map(|e| toml::Value::String(e).to_string()),
        prop::collection::vec(expression(), 0..4).prop_map(|es| {
            toml::Value::Array(es.into_iter().map(toml::Value::String).collect()).to_string()
        }),
    ]
    .boxed()
}

fn read_model(text: &str) {
    if let Ok(p) = Preset::from_toml_str(text, "fuzz.toml") {
        // What `onsager models --check` derives from the expressions.
        if let Model::Expression(m) = &p.model {
            let _ = m.drift_polynomial_degree();
            let _ = m.tape_lengths();
        }
    }
}

#[test]
fn fuzz_model_file_reader() {
    for model in MODELS {
        Preset::from_toml_str(model, "example.toml").expect("the example model files are valid");
    }
    fuzz("model file", toml_input(MODELS.to_vec(), expression_value()), |text| read_model(&text));
}

// ---------------------------------------------------------------------------------------------
// Regressions found by the fuzz targets

/// A tiny `measurements.every` asked for more measurement times than a `Vec` can hold (a panic,
/// "capacity overflow") or than memory holds (an abort); it is an error naming the key.
#[test]
fn a_tiny_measurement_interval_is_refused_before_allocating() {
    let spec = SPECS[1];
    assert!(spec.contains("every = 0.1"));
    for every in ["1e-300", "1e-9"] {
        let text = spec.replacen("every = 0.1", &format!("every = {every}"), 1);
        let e = Experiment::from_toml(&text).unwrap_err().to_string();
        assert!(e.contains("measurements.every") && e.contains("measurement times"), "{e}");
    }
}

/// Expressions nested deeper than the parser's limit are an error with the line, not a stack
/// overflow (the recursive descent takes a few frames per level).
#[test]
fn a_deeply_nested_expression_is_an_error_not_a_stack_overflow() {
    let model = MODELS[0];
    let drift = "drift = [\"x*4 - x^3*4\"]";
    assert!(model.contains(drift));
    for nested in [
        format!("{}x{}", "(".repeat(100_000), ")".repeat(100_000)),
        format!("{}x", "-".repeat(100_000)),
        format!("x{}", "^-x".repeat(100_000)),
        format!("{}x{}", "sin(".repeat(100_000), ")".repeat(100_000)),
    ] {
        let text = model.replacen(drift, &format!("drift = [\"{nested}\"]"), 1);
        let e = Preset::from_toml_str(&text, "deep.toml").unwrap_err().to_string();
        assert!(e.contains("nested more than") && e.contains("deep.toml"), "{}", &e[..e.len().min(300)]);
    }
    // Nesting within the limit is fine.
    let text = model.replacen(drift, &format!("drift = [\"{}x{}\"]", "(".repeat(400), ")".repeat(400)), 1);
    Preset::from_toml_str(&text, "deep.toml").unwrap();
}
