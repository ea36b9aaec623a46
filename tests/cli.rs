//! The command-line tool, run as a user would run it.

use std::path::PathBuf;

use onsager::data::{Dataset, StatePath};

use crate::support::onsager;

fn scratch(name: &str) -> PathBuf {
    crate::support::scratch("cli", name)
}

#[test]
fn simulate_output_is_read_back_by_the_library() {
    let dir = scratch("duffing");
    let (data, truth) = (dir.join("data.csv"), dir.join("truth.csv"));
    let out = onsager()
        .args(["simulate", "--model", "duffing", "--param", "d=0.3", "--t-end", "5", "--dt", "0.01"])
        .args(["--sample-every", "0.1", "--seed", "7", "--out"])
        .arg(&data)
        .arg("--truth")
        .arg(&truth)
        .output()
        .unwrap();
    assert!(out.status.success(), "stderr: {}", String::from_utf8_lossy(&out.stderr));
    let outputs = vec!["y".to_string()];
    let d = Dataset::read_csv_for(&data, &outputs).unwrap();
    assert_eq!(d.names, outputs);
    assert_eq!(d.len(), 51, "measurements at 0, 0.1, …, 5");
    for (k, &t) in d.times.iter().enumerate() {
        assert!((t - 0.1 * k as f64).abs() < 1e-9, "t[{k}] = {t}");
    }
    assert!(d.values.iter().flatten().all(|v| v.is_finite()));
    let p = StatePath::read_csv(&truth).unwrap();
    assert_eq!(p.names, vec!["x", "z"]);
    assert_eq!(p.len(), 501);
    // The measurements are z plus noise of sd 0.1 (000 Table 4.1): within 6 sd of the truth.
    let z = p.column("z").unwrap();
    for (k, y) in d.values.iter().enumerate() {
        assert!((y[0] - z[10 * k]).abs() < 0.6, "y[{k}] = {} vs z = {}", y[0], z[10 * k]);
    }
    // Same seed, same file.
    let again = dir.join("again.csv");
    let out2 = onsager()
        .args(["simulate", "--model", "duffing", "--param", "d=0.3", "--t-end", "5", "--dt", "0.01"])
        .args(["--sample-every", "0.1", "--seed", "7", "--out"])
        .arg(&again)
        .output()
        .unwrap();
    assert!(out2.status.success());
    assert_eq!(std::fs::read(&data).unwrap(), std::fs::read(&again).unwrap());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn models_lists_every_builtin_model() {
    let out = onsager().arg("models").output().unwrap();
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    for name in onsager::model::library::NAMES {
        assert!(text.contains(name), "`onsager models` should list {name}");
    }
    assert!(text.contains("sigma_y"), "Duffing's measurement parameter is listed");
}

#[test]
fn bad_arguments_are_clear_errors_not_panics() {
    let dir = scratch("bad");
    let cases: &[(&[&str], &str)] = &[
        (&["simulate", "--model", "nope"], "unknown model `nope`"),
        (&["simulate", "--model", "duffing", "--param", "q=1"], "unknown parameter `q`"),
        (&["simulate", "--model", "duffing", "--param", "a"], "expected NAME=VALUE"),
        (&["simulate", "--model", "duffing", "--dt", "-1"], "dt"),
        (&["simulate", "--model", "ou", "--likelihood", "cauchy:scale=1"], "cauchy"),
        // A usage error (clap's) exits with 1 too.
        (&["estimate", "--data", "x.csv", "--method", "kalman"], "unknown method `kalman`"),
    ];
    for (args, needle) in cases {
        let out = onsager().args(*args).arg("--out").arg(dir.join("x.csv")).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {err}");
        assert!(err.contains(needle), "{args:?}: `{err}` should contain `{needle}`");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn measurements_closer_than_the_time_tolerance_do_not_panic_the_grid_methods() {
    // Regression: two measurement times 1e-10 apart were merged into one grid event and the
    // backward sweep indexed past the end.
    let dir = scratch("close");
    let data = dir.join("close.csv");
    std::fs::write(&data, "t,y\n0.5,-1\n1,-0.9\n1.0000000001,-0.95\n2,-1\n").unwrap();
    for method in ["ksp", "mean-optimal"] {
        let out = onsager()
            .args(["estimate", "--model", "double-well", "--method", method])
            .args(["--grid", "lo=-2.5,hi=2.5,cells=100", "--data"])
            .arg(&data)
            .arg("--out")
            .arg(dir.join(format!("{method}.csv")))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{method}: {err}");
        let path = StatePath::read_csv(dir.join(format!("{method}.csv"))).unwrap();
        assert!(path.values.iter().flatten().all(|v| v.is_finite()), "{method}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `onsager compare` on the built-in double-well data (issue 7): the table with every default
/// method and the four files.
#[test]
fn compare_prints_the_table_and_writes_the_four_files() {
    let dir = scratch("compare");
    let (data, truth, out_dir) = (dir.join("dw.csv"), dir.join("dw-truth.csv"), dir.join("cmp"));
    let sim = onsager().args(["simulate", "--out"]).arg(&data).arg("--truth").arg(&truth).output().unwrap();
    assert!(sim.status.success(), "stderr: {}", String::from_utf8_lossy(&sim.stderr));
    let out = onsager()
        .args(["compare", "--data"])
        .arg(&data)
        .arg("--truth")
        .arg(&truth)
        .arg("--out-dir")
        .arg(&out_dir)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.code() != Some(1), "stderr: {}", String::from_utf8_lossy(&out.stderr));
    assert!(
        stdout.contains("rmse_truth") && stdout.contains("rmse_ksp") && stdout.contains("same_well"),
        "{stdout}"
    );
    for method in ["ksp", "mean-optimal", "gaussian-ksp-closure", "jme", "mee", "uks"] {
        assert!(stdout.lines().any(|l| l.starts_with(method)), "no row for {method}:\n{stdout}");
    }
    for file in ["paths.csv", "summary.json", "compare.svg", "compare.png"] {
        let len = std::fs::metadata(out_dir.join(file)).map(|m| m.len()).unwrap_or(0);
        assert!(len > 100, "{file}: {len} bytes");
    }
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("summary.json")).unwrap()).unwrap();
    let rows = summary["methods"].as_array().unwrap();
    let ksp = rows.iter().find(|r| r["method"] == "ksp").unwrap();
    assert!(ksp["rmse_truth"].as_f64().unwrap() < 0.5 && ksp["same_well_fraction"].as_f64().unwrap() > 0.9);
    // An unknown method is a clear error.
    let bad = onsager().args(["compare", "--methods", "ksp,kalman", "--data"]).arg(&data).output().unwrap();
    assert_eq!(bad.status.code(), Some(1), "a usage error exits with 1 (2 means not converged)");
    assert!(String::from_utf8_lossy(&bad.stderr).contains("kalman"));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Runs the binary; (exit code, stdout, stderr).
fn run(args: &[&str], dir: &std::path::Path) -> (i32, String, String) {
    let out = onsager().args(args).current_dir(dir).output().unwrap();
    let text = |b: Vec<u8>| String::from_utf8_lossy(&b).into_owned();
    (out.status.code().unwrap_or(-1), text(out.stdout), text(out.stderr))
}

#[test]
fn the_cli_keeps_its_promises() {
    let dir = scratch("promises");
    let sim = ["simulate", "--t-end", "3", "--seed", "3"];
    let (code, _, err) = run(&[&sim[..], &["--model", "duffing", "--out", "d.csv"]].concat(), &dir);
    assert_eq!(code, 0, "{err}");
    let (code, _, err) = run(&[&sim[..], &["--out", "w.csv", "--truth", "wt.csv"]].concat(), &dir);
    assert_eq!(code, 0, "{err}");
    // compare: ksp on two states without a grid does not apply (skipped by default, see
    // `compare_skips`), ...
    let (code, out, err) = run(
        &["compare", "--model", "duffing", "--data", "d.csv", "--methods", "ksp,uks", "--out-dir", "c"],
        &dir,
    );
    // ... and refused (exit 1, not 2) when asked for, with a two-state grid as the way out.
    assert_eq!(code, 1, "{out}{err}");
    assert!(err.contains("--methods") && err.contains("lo=L1;L2"), "{err}");
    // A non-Gaussian likelihood: the methods that need Gaussian errors are listed as skipped.
    let (code, out, err) = run(
        &["compare", "--data", "w.csv", "--likelihood", "student-t:nu=4,scale=0.2", "--methods", "uks"],
        &dir,
    );
    assert_eq!(code, 1, "{out}{err}");
    assert!(err.contains("Gaussian measurement errors"), "{err}");
    // pem runs in compare with --estimate.
    let (code, out, err) = run(
        &["compare", "--model", "duffing", "--data", "d.csv", "--methods", "pem", "--estimate", "d"],
        &dir,
    );
    assert!(code == 0 || code == 2, "{out}{err}");
    assert!(out.contains("pem ") && !out.contains("error"), "{out}");
    // Negative numbers as flag values: the domain error, naming the flag.
    let (code, _, err) = run(&["estimate", "--data", "w.csv", "--method", "jme", "--step", "-0.1"], &dir);
    assert_eq!(code, 1);
    assert!(err.contains("step") && err.contains("-0.1"), "{err}");
    let (code, _, err) = run(&["simulate", "--t-end", "-1"], &dir);
    assert_eq!(code, 1);
    assert!(err.contains("`--t-end`"), "{err}");
    // --param D=-1 says what D must be.
    let (code, _, err) = run(&["simulate", "--param", "D=-1"], &dir);
    assert_eq!(code, 1);
    assert!(err.contains("--param") && err.contains("`D=-1`") && err.contains("positive"), "{err}");
    // --x0-prior names the flag, not `prior.sd`.
    let (code, _, err) = run(&["simulate", "--x0-prior", "x=normal:0,0"], &dir);
    assert_eq!(code, 1);
    assert!(err.contains("`--x0-prior`") && !err.contains("prior.sd"), "{err}");
    // All-NaN data is refused, naming the file.
    std::fs::write(dir.join("nan.csv"), "t,y\n0,\n1,NaN\n").unwrap();
    let (code, _, err) = run(&["estimate", "--data", "nan.csv", "--method", "uks"], &dir);
    assert_eq!(code, 1);
    assert!(err.contains("--data") && err.contains("nan.csv"), "{err}");
    // A truth that does not cover the data: a warning on stderr.
    let truth = std::fs::read_to_string(dir.join("wt.csv")).unwrap();
    let short: Vec<&str> = truth.lines().take(50).collect();
    std::fs::write(dir.join("short.csv"), short.join("\n") + "\n").unwrap();
    let (_, _, err) = run(
        &["compare", "--data", "w.csv", "--truth", "short.csv", "--methods", "uks", "--out-dir", "c"],
        &dir,
    );
    assert!(err.contains("warning: --truth short.csv covers"), "{err}");
    // Statuses and exit codes are defined under --help, from one source.
    let (code, out, _) = run(&["compare", "--help"], &dir);
    assert_eq!(code, 0);
    for s in onsager::Status::ALL {
        assert!(out.contains(s.name()) && out.contains(s.description()), "{s} in --help");
    }
    assert!(out.contains("Exit codes"));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn max_iterations_and_tolerance_and_no_progress_text_on_a_pipe() {
    let dir = scratch("limits");
    let (code, _, err) = run(&["simulate", "--t-end", "5", "--seed", "3", "--out", "w.csv"], &dir);
    assert_eq!(code, 0, "{err}");
    let jme = ["estimate", "--data", "w.csv", "--method", "jme"];
    let report = |name: &str| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(dir.join(name)).unwrap()).unwrap()
    };
    // At the iteration limit: the status max-iterations and exit code 2.
    let (code, out, err) = run(&[&jme[..], &["--max-iterations", "1", "--report", "r1.json"]].concat(), &dir);
    assert_eq!(code, 2, "{out}{err}");
    assert_eq!(report("r1.json")["status"], "max-iterations");
    // A looser tolerance: fewer iterations in the report. Stderr is a pipe here: no progress text.
    let (code, out, err) = run(&[&jme[..], &["--report", "r0.json"]].concat(), &dir);
    assert_eq!(code, 0, "{out}{err}");
    assert!(!err.contains('\r') && !err.contains("iteration"), "{err}");
    let (code, out, err) = run(&[&jme[..], &["--tolerance", "1e-2", "--report", "r2.json"]].concat(), &dir);
    assert_eq!(code, 0, "{out}{err}");
    let (strict, loose) =
        (report("r0.json")["iterations"].as_u64(), report("r2.json")["iterations"].as_u64());
    assert!(loose < strict, "{loose:?} < {strict:?}");
    // A method that does not iterate says so.
    let (code, out, err) =
        run(&["estimate", "--data", "w.csv", "--method", "uks", "--max-iterations", "5"], &dir);
    assert_eq!(code, 0, "{out}{err}");
    assert!(out.contains("`uks` does not iterate"), "{out}");
    // Bad values name the flag, exit code 1.
    for (flag, value) in [("--max-iterations", "0"), ("--tolerance", "-1"), ("--tolerance", "nan")] {
        let (code, _, err) = run(&[&jme[..], &[flag, value]].concat(), &dir);
        assert_eq!(code, 1, "{flag} {value}: {err}");
        assert!(err.contains(flag), "{err}");
    }
    // compare passes the limits to every estimator.
    let (code, out, err) = run(
        &["compare", "--data", "w.csv", "--methods", "jme,uks", "--max-iterations", "1", "--out-dir", "c"],
        &dir,
    );
    assert_eq!(code, 2, "{out}{err}");
    assert!(out.lines().any(|l| l.starts_with("jme") && l.contains("max-iterations")), "{out}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn messages_name_what_the_user_typed() {
    let dir = scratch("messages");
    let (code, _, err) = run(&["simulate", "--t-end", "5", "--seed", "3", "--out", "w.csv"], &dir);
    assert_eq!(code, 0, "{err}");
    // An exponential closure on a box says which box and whether the quadrature check kept it.
    let (code, out, err) =
        run(&["estimate", "--data", "w.csv", "--method", "exp-closure", "--out", "e.csv"], &dir);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("  box (domain): x [-4.2863, 2.8589]"), "{out}");
    assert!(out.contains("  quadrature: 12 panels (checked on 18 panels: shift "), "{out}");
    // A tiny sampling interval is refused before the times are allocated (it was a panic).
    for every in ["1e-300", "1e-8"] {
        let (code, _, err) = run(&["simulate", "--sample-every", every, "--out", "tiny.csv"], &dir);
        assert_eq!(code, 1, "{err}");
        assert!(err.contains("--sample-every") && err.contains("at most"), "{err}");
    }
    // A datum of 1e300: the file, line and column, not an option of the estimator.
    std::fs::write(dir.join("big.csv"), "t,y\n0,1\n0.5,1e300\n1,2\n").unwrap();
    for method in ["exp-closure", "jme", "uks"] {
        let (code, _, err) = run(&["estimate", "--data", "big.csv", "--method", method], &dir);
        assert_eq!(code, 1, "{method}: {err}");
        assert!(err.contains("big.csv:3") && !err.contains("moments"), "{err}");
    }
    // Large data within range: the exponential closure names its domain, not `moments`.
    std::fs::write(dir.join("wide.csv"), "t,y\n0,1\n0.5,1e140\n1,2\n").unwrap();
    let (code, _, err) = run(&["estimate", "--data", "wide.csv", "--method", "exp-closure"], &dir);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("`domain`") && !err.contains("`moments`"), "{err}");
    // The Gauss–Hermite points as typed: the flag when the flag set them.
    for (method, value) in [("gaussian-closure", "0"), ("ksp-closure", "0"), ("gaussian-closure", "1000000")]
    {
        let (code, _, err) =
            run(&["estimate", "--data", "w.csv", "--method", method, "--gaussian-points", value], &dir);
        assert_eq!(code, 1, "{method} {value}: {err}");
        assert!(err.contains("`--gaussian-points`") && !err.contains("gaussian points"), "{err}");
    }
    // simulate: a step that does not divide the horizon names the flag.
    let (code, _, err) = run(&["simulate", "--dt", "10", "--t-end", "5"], &dir);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("`--dt`"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_example_grid_of_an_unmeasured_state_has_one_axis_per_state() {
    // Van der Pol measures u only: the grid methods have no default grid, and the error gives an
    // example with two axes, which the CLI then accepts.
    let dir = scratch("example-grid");
    let data = dir.join("vdp.csv");
    let sim = onsager()
        .args(["simulate", "--model", "van-der-pol", "--likelihood", "gaussian:sigma=0.1"])
        .args(["--t-end", "0.5", "--seed", "1", "--out"])
        .arg(&data)
        .output()
        .unwrap();
    assert!(sim.status.success(), "{}", String::from_utf8_lossy(&sim.stderr));
    let estimate = |grid: Option<&str>| {
        let mut cmd = onsager();
        cmd.args(["estimate", "--model", "van-der-pol", "--likelihood", "gaussian:sigma=0.1"]);
        cmd.args(["--method", "ksp", "--data"]).arg(&data);
        cmd.arg("--out").arg(dir.join("ksp.csv"));
        if let Some(g) = grid {
            cmd.args(["--grid", g]);
        }
        cmd.output().unwrap()
    };
    let out = estimate(None);
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(out.status.code(), Some(1), "{err}");
    let example =
        err.split('`').find(|s| s.starts_with("lo=")).unwrap_or_else(|| panic!("no example: {err}"));
    assert_eq!(example, "lo=-2.5;-2.5,hi=2.5;2.5,cells=120;120");
    let out = estimate(Some(example));
    assert_ne!(out.status.code(), Some(1), "{}", String::from_utf8_lossy(&out.stderr));
    std::fs::remove_dir_all(&dir).unwrap();
}
