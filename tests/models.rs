//! Model files against the built-in models they declare again (`examples/models/`): the same
//! seed gives the same simulated path and data, and the same estimates from the MAP paths
//! (jme, mee, with the parameters each preset estimates), the unscented filter and smoother,
//! the Gaussian closure and, for one-state models, the exact KSP smoother and mean-optimal
//! estimator, to round-off (the same status, and the same numbers whether or not the method
//! converged). The command line takes `--model-file` and `models --check`.

use onsager::estimator::Estimator;
use onsager::model::library::{preset, Preset, NAMES};
use onsager::model::observation::{Noise, Param};
use onsager::test_models::{model_file, PresetRecord};

/// Round-off: the two models compute the same formulas in a different order (and the built-in
/// models' derivatives in closed form, the files' symbolically), so estimates agree to a few
/// ulp of the solvers' own precision, far below their tolerances.
fn same(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * (1.0 + a.abs().max(b.abs())) || (a.is_nan() && b.is_nan())
}

/// A short record of each model: a few seconds with at least ten measurements, from t = 0.
fn shorten(mut p: Preset) -> Preset {
    let (t_end, every) = match p.name.as_str() {
        "lorenz63" | "lorenz96" => (1.0, 0.1),
        "double-well" => (5.0, 0.5),
        "tanh" => (3.0, 0.5),
        _ => (2.0, 0.1),
    };
    p.t_end = t_end;
    p.sample_every = every;
    p.first_sample = 0.0;
    p
}

/// Gaussian measurements of the same sd (or its parameter), for the methods that need them.
fn gaussian(mut p: Preset) -> Preset {
    let sigma = match p.observation.noise {
        Noise::Gaussian { sigma } => sigma,
        Noise::Quantized { sigma, .. } | Noise::Mixture { sigma, .. } => sigma,
        _ => Param::Fixed(0.5),
    };
    p.observation.noise = Noise::Gaussian { sigma };
    p
}

fn assert_same_numbers(what: &str, a: &[f64], b: &[f64]) {
    assert_eq!(a.len(), b.len(), "{what}: lengths");
    for (k, (x, y)) in a.iter().zip(b).enumerate() {
        assert!(same(*x, *y), "{what}: entry {k}: built-in {x}, file {y}");
    }
}

fn flat(rows: &[Vec<f64>]) -> Vec<f64> {
    rows.iter().flatten().copied().collect()
}

/// Runs `method` on the built-in record and the file record and compares the estimates.
fn compare_method(name: &str, method: &str, builtin: &PresetRecord, file: &PresetRecord) {
    let estimator = Estimator::parse(method).unwrap();
    let method = method.split(':').next().unwrap_or(method);
    let estimate: Vec<usize> = if matches!(method, "jme" | "mee") {
        (0..builtin.preset.theta.len()).filter(|&i| builtin.preset.estimate[i]).collect()
    } else {
        Vec::new()
    };
    let a = estimator.run(&builtin.problem(&estimate)).unwrap().estimate;
    let b = estimator.run(&file.problem(&estimate)).unwrap().estimate;
    let what = format!("{name} {method}");
    assert_eq!(a.status, b.status, "{what}: status");
    assert_same_numbers(&format!("{what} times"), &a.path.times, &b.path.times);
    assert_same_numbers(&format!("{what} path"), &flat(&a.path.values), &flat(&b.path.values));
    if let (Some(sa), Some(sb)) = (&a.path.sd, &b.path.sd) {
        assert_same_numbers(&format!("{what} sd"), &flat(sa), &flat(sb));
    }
    assert_same_numbers(&format!("{what} theta"), &a.theta, &b.theta);
}

/// The built-in model `name` and its model file give the same data and estimates.
fn twins(name: &str) {
    {
        let seed = 11 + NAMES.iter().position(|n| *n == name).unwrap() as u64;
        let builtin = PresetRecord::simulate(shorten(preset(name).unwrap()), seed).unwrap();
        let file = PresetRecord::simulate(shorten(model_file(name).unwrap()), seed).unwrap();
        assert_same_numbers(
            &format!("{name} truth"),
            &flat(&builtin.truth.values),
            &flat(&file.truth.values),
        );
        assert_same_numbers(&format!("{name} data"), &flat(&builtin.data.values), &flat(&file.data.values));
        for method in ["jme", "mee"] {
            compare_method(name, method, &builtin, &file);
        }
        let g = |r: &PresetRecord| PresetRecord { preset: gaussian(r.preset.clone()), ..r.clone() };
        let (gb, gf) = (g(&builtin), g(&file));
        // the Gaussian closure's dual takes seconds to converge on the models with several
        // states: a few of its iterations are as good a comparison
        let mut methods = vec!["ukf", "uks", "gaussian-closure:dual.max_iterations=2"];
        match builtin.preset.dims().states() {
            1 => {
                methods[2] = "gaussian-closure";
                methods.extend(["ksp", "mean-optimal"]);
            }
            // Beyond three states one closure iteration takes minutes (docs/closures.md, Limits).
            n if n > 3 => {
                methods.pop();
            }
            _ => {}
        }
        for method in methods {
            compare_method(name, method, &gb, &gf);
        }
    }
}

macro_rules! twin_tests {
    ($($test:ident => $name:literal),* $(,)?) => {
        $(
            #[test]
            fn $test() {
                twins($name);
            }
        )*
        #[test]
        fn every_built_in_model_has_a_twin_test() {
            assert_eq!(NAMES, [$($name),*]);
        }
    };
}

twin_tests! {
    ou_file_equals_built_in => "ou",
    tanh_file_equals_built_in => "tanh",
    van_der_pol_file_equals_built_in => "van-der-pol",
    duffing_file_equals_built_in => "duffing",
    holmes_rand_file_equals_built_in => "holmes-rand",
    double_well_file_equals_built_in => "double-well",
    double_well_2d_file_equals_built_in => "double-well-2d",
    lorenz63_file_equals_built_in => "lorenz63",
    lorenz96_file_equals_built_in => "lorenz96",
}

use crate::support::onsager;

fn example(name: &str) -> String {
    format!("{}/examples/models/{name}.toml", env!("CARGO_MANIFEST_DIR"))
}

#[test]
fn the_command_line_takes_model_files() {
    let dir = std::env::temp_dir().join(format!("onsager-models-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let data = dir.join("l96.csv");
    let out = onsager()
        .args(["simulate", "--model-file", &example("lorenz96"), "--t-end", "1", "--seed", "2", "--out"])
        .arg(&data)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let out = onsager()
        .args(["estimate", "--model-file", &example("lorenz96"), "--method", "uks", "--data"])
        .arg(&data)
        .arg("--out")
        .arg(dir.join("est.csv"))
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let out = onsager().args(["models", "--check", &example("duffing")]).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success());
    assert!(
        text.contains("clean states: z") && text.contains("polynomial of degree 3 in the state, reads t"),
        "{text}"
    );
    // a bad file: exit code 1, the file, line and column, no panic
    let bad = dir.join("bad.toml");
    std::fs::write(&bad, "[states]\nnoisy = [\"x\"]\n[parameters]\ns = 1\n[dynamics]\ndrift = [\"-x + q\"]\ndiffusion = \"s\"\n")
        .unwrap();
    let out = onsager().args(["models", "--check"]).arg(&bad).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("bad.toml:6:16: drift component 1: unknown symbol `q`"), "{err}");
}

/// dx = log(x) dt + 0.1 dW with data near −1: the model is NaN wherever the estimators look.
const NOT_REAL: &str = r#"
[states]
noisy = ["x"]
[parameters]
s = 0.1
[dynamics]
drift = ["log(x)"]
diffusion = "s"
[initial]
x = "normal:-1,0.1"
[measurements]
states = ["x"]
likelihood = "gaussian:sigma=0.1"
every = 0.1
[simulation]
t_end = 1
dt = 0.01
"#;

#[test]
fn a_model_that_returns_nan_is_a_status_not_a_converged_nan() {
    let p = Preset::from_toml_str(NOT_REAL, "not-real.toml").unwrap();
    let times: Vec<f64> = (0..=10).map(|k| k as f64 * 0.1).collect();
    let data = onsager::data::Dataset {
        names: vec!["y".into()],
        values: times.iter().map(|_| vec![-1.0]).collect(),
        times,
    };
    for method in ["jme", "mee", "ukf", "uks", "ekf", "gaussian-closure", "particle"] {
        let estimator = Estimator::parse(method).unwrap();
        match estimator.run(&p.problem(&data, &[])) {
            Ok(run) => assert!(!run.estimate.status.is_success(), "{method}: {}", run.estimate.status),
            Err(e) => panic!("{method}: an error instead of a status: {e}"),
        }
    }
}

#[test]
fn experiment_specs_name_model_files() {
    let spec = |model: &str| {
        format!(
            "name = \"from-file\"\n[model]\n{model}\n[simulation]\nt_end = 2.0\n\
             [[estimators]]\nmethod = \"uks\"\n"
        )
    };
    let file = example("double-well");
    let e = onsager::experiment::Experiment::from_toml(&spec(&format!(
        "file = {file:?}\nparams = {{ D = 0.3 }}"
    )))
    .unwrap();
    let s = e.scenarios(false).unwrap();
    assert_eq!(s[0].truth.name, "double-well");
    assert_eq!(s[0].truth.theta, [0.3]);
    // relative to the spec's folder
    let dir = std::env::temp_dir().join(format!("onsager-spec-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::copy(&file, dir.join("dw.toml")).unwrap();
    std::fs::write(dir.join("spec.toml"), spec("file = \"dw.toml\"")).unwrap();
    let e = onsager::experiment::Experiment::from_path(&dir.join("spec.toml")).unwrap();
    assert_eq!(e.scenarios(false).unwrap()[0].truth.name, "double-well");
    let both = onsager::experiment::Experiment::from_toml(&spec(&format!("name = \"ou\"\nfile = {file:?}")));
    assert!(both.unwrap_err().to_string().contains("not both"));
}

/// The flight-path model (`000_74b95e149527c64e.txt` Sec. 4.2) is a Rust-only built-in, not in
/// `NAMES` (its measurements are nonlinear outputs, which a preset's state measurement and a
/// model file cannot express). One synthetic replicate (seed 1, 30 s at 25 Hz, conditioned on
/// the envelope): JME (Hermite–Simpson, step = sample period) converges jointly with the eight
/// parameters and recovers every bias within 3 of its Laplace standard deviations; the
/// 20-replicate table (`examples/flight_path.rs`) checks the sds against the spread.
#[test]
fn flight_path_jme_recovers_the_biases() {
    use onsager::model::library::{FlightPath, FlightPathSetup};
    use onsager::path::Merit;
    use rand::SeedableRng;
    assert!(!NAMES.contains(&"flight-path"));
    let setup = FlightPathSetup::new();
    let (_, data) = setup.simulate_in_envelope(&mut rand::rngs::StdRng::seed_from_u64(1), 100).unwrap();
    assert_eq!(data.times.len(), 751);
    let e = setup.estimate(&data, Merit::OnsagerMachlup).unwrap().estimate;
    assert!(e.status.is_success(), "{}", e.status);
    let why = e.details.get::<onsager::path::PathDetails>().map(|d| d.sd.to_string()).unwrap_or_default();
    let sd = e.theta_sd.unwrap_or_else(|| panic!("no Laplace sd: {why}"));
    for (i, &sdi) in sd.iter().enumerate().take(6) {
        let z = (e.theta[i] - FlightPathSetup::TRUTH[i]) / sdi;
        assert!(
            z.abs() < 3.0,
            "{}: {} vs {} (sd {})",
            FlightPath::PARAMS[i],
            e.theta[i],
            FlightPathSetup::TRUTH[i],
            sdi
        );
    }
}

/// The sensor noise of a synthetic record comes back from its third differences
/// (`noise_sd`) within 15 % for each of the 13 outputs; the synthetic specific forces and rates
/// are so smooth that their roughness does not show above the sensors' noise, and `for_record`
/// says so, naming the outputs.
#[test]
fn flight_record_noise_levels_come_from_the_record() {
    use onsager::model::library::{noise_sd, FlightPathObservation, FlightPathSetup};
    use rand::SeedableRng;
    let setup = FlightPathSetup::new();
    let (_, data) = setup.simulate_in_envelope(&mut rand::rngs::StdRng::seed_from_u64(2), 100).unwrap();
    for (j, truth) in setup.observation.sd.per_output().iter().enumerate() {
        let column: Vec<f64> = data.values.iter().map(|row| row[j]).collect();
        let s = noise_sd(&column).unwrap();
        assert!((s / truth - 1.0).abs() < 0.15, "{}: {s} vs {truth}", FlightPathObservation::OUTPUTS[j]);
    }
    let err = FlightPathSetup::for_record(&data).unwrap_err().to_string();
    assert!(err.contains("`ax_m`, `ay_m`, `az_m`") && err.contains("roughness"), "{err}");
}

/// A flight-test record in the book's ASCII layout (`FlightColumns::ATTAS`: 16 columns used):
/// rows of 17 numbers, time 50.00, 50.04, … Row k has every channel equal to k + 1 except the
/// time, degrees in columns 7–14 and feet in 16.
fn flight_rows(rows: usize) -> Vec<String> {
    (0..rows)
        .map(|k| {
            let mut cells = vec![format!("{:.7e}", 50.0 + 0.04 * k as f64)];
            cells.extend((2..=17).map(|_| format!("{:.7e}", (k + 1) as f64)));
            cells.join("  ")
        })
        .collect()
}

/// Reads `lines` written to a scratch file with the ATTAS layout; the error text on failure.
fn read_flight(name: &str, lines: &[String]) -> Result<onsager::data::Dataset, String> {
    use onsager::model::library::{read_flight_record, FlightColumns};
    let path = crate::support::scratch("models", "flight").join(name);
    std::fs::write(&path, lines.join("\n")).unwrap();
    read_flight_record(&path, &FlightColumns::ATTAS).map_err(|e| e.to_string())
}

/// The book's layout converts to the measurement CSV's outputs in SI units: degrees to
/// radians, feet to metres, the rest as recorded.
#[test]
fn flight_record_converts_units() {
    use onsager::model::library::FlightPathObservation;
    let data = read_flight("good.asc", &flight_rows(3)).unwrap();
    assert_eq!(data.names, FlightPathObservation::OUTPUTS);
    assert_eq!(data.times.len(), 3);
    assert!((data.times[2] - 50.08).abs() < 1e-12);
    let row = &data.values[1];
    let rad = 2f64.to_radians();
    assert_eq!(row[0], 2.0); // airspeed m/s
    for (j, v) in row.iter().enumerate().take(6).skip(1) {
        assert!((v - rad).abs() < 1e-15, "{j}: {v}"); // alpha, beta, phi, theta, psi
    }
    assert!((row[6] - 0.6096).abs() < 1e-12); // altitude 2 ft
    for v in &row[7..=9] {
        assert!((v - rad).abs() < 1e-15); // rates deg/s
    }
    assert_eq!(&row[10..], &[2.0, 2.0, 2.0]); // accelerations m/s^2
}

#[test]
fn flight_record_truncated_names_file_line_and_column() {
    let mut rows = flight_rows(4);
    rows[3] = rows[3].split_whitespace().take(9).collect::<Vec<_>>().join(" ");
    let e = read_flight("truncated.asc", &rows).unwrap_err();
    assert!(e.contains("truncated.asc:4, column 10") && e.contains("truncated"), "{e}");
}

#[test]
fn flight_record_wrong_column_count_names_file_and_line() {
    let mut rows = flight_rows(4);
    rows[1].push_str("  1.0");
    let e = read_flight("wide.asc", &rows).unwrap_err();
    assert!(e.contains("wide.asc:2") && e.contains("18 columns, but the first row has 17"), "{e}");
    let narrow: Vec<String> =
        flight_rows(2).iter().map(|r| r.split_whitespace().take(12).collect::<Vec<_>>().join(" ")).collect();
    let e = read_flight("narrow.asc", &narrow).unwrap_err();
    assert!(e.contains("narrow.asc:1") && e.contains("needs at least 16"), "{e}");
}

#[test]
fn flight_record_non_numeric_cell_names_file_line_and_column() {
    let mut rows = flight_rows(4);
    rows[2] = rows[2].replacen("3.0000000e0", "x3", 1);
    let e = read_flight("text.asc", &rows).unwrap_err();
    assert!(e.contains("text.asc:3, column 2 (AXCG)") && e.contains("`x3`"), "{e}");
}

#[test]
fn flight_record_non_increasing_time_names_file_line_and_column() {
    let mut rows = flight_rows(4);
    rows[3] = rows[2].clone();
    let e = read_flight("time.asc", &rows).unwrap_err();
    assert!(e.contains("time.asc:4, column 1 (T)") && e.contains("strictly increasing"), "{e}");
}
