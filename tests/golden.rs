//! Every estimator gives the numbers it gave before the typed-estimator interface: each line of
//! `tests/golden/cases.txt` is run through `onsager estimate` again and its path CSV, status,
//! iterations and θ̂ are compared with the goldens written at commit 32300c1 (regenerated only
//! by `tests/golden/regenerate.sh`, when a change of numbers is meant; `cases.txt` names the
//! cases written again since).

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;

fn golden_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests").join("golden")
}

/// Relative agreement to round-off: the same arithmetic in another order may differ in the last
/// bits of an iterative solver's output, not more.
fn close(a: f64, b: f64) -> bool {
    a == b || (a - b).abs() <= 1e-9 * (1.0 + a.abs().max(b.abs()))
}

fn read_table(path: &Path) -> (String, Vec<Vec<f64>>) {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut lines = text.lines();
    let header = lines.next().unwrap_or_default().to_string();
    let rows = lines.map(|l| l.split(',').map(|v| v.parse::<f64>().unwrap_or(f64::NAN)).collect()).collect();
    (header, rows)
}

fn compare_paths(name: &str, got: &Path, want: &Path) {
    let (h1, r1) = read_table(got);
    let (h2, r2) = read_table(want);
    assert_eq!(h1, h2, "{name}: header");
    assert_eq!(r1.len(), r2.len(), "{name}: rows");
    for (i, (a, b)) in r1.iter().zip(&r2).enumerate() {
        assert_eq!(a.len(), b.len(), "{name}: row {i}");
        for (j, (&x, &y)) in a.iter().zip(b).enumerate() {
            assert!(close(x, y) || (x.is_nan() && y.is_nan()), "{name}: row {i} column {j}: {x} vs {y}");
        }
    }
}

fn compare_reports(name: &str, got: &Path, want: &Path) {
    let read = |p: &Path| -> Value { serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap() };
    let (a, b) = (read(got), read(want));
    assert_eq!(a["status"], b["status"], "{name}: status");
    assert_eq!(a["iterations"], b["iterations"], "{name}: iterations");
    let (ta, tb) = (a["theta"].as_object().unwrap(), b["theta"].as_object().unwrap());
    assert_eq!(ta.keys().collect::<Vec<_>>(), tb.keys().collect::<Vec<_>>(), "{name}: θ names");
    for (k, vb) in tb {
        let va = &ta[k];
        assert_eq!(va["estimated"], vb["estimated"], "{name}: {k} estimated");
        for field in ["value", "sd"] {
            match (va[field].as_f64(), vb[field].as_f64()) {
                (Some(x), Some(y)) => assert!(close(x, y), "{name}: {k}.{field}: {x} vs {y}"),
                (x, y) => assert_eq!(x, y, "{name}: {k}.{field}"),
            }
        }
    }
}

#[test]
fn every_estimator_gives_its_golden_numbers() {
    let dir = golden_dir();
    let out = std::env::temp_dir().join(format!("onsager-golden-{}", std::process::id()));
    std::fs::create_dir_all(&out).unwrap();
    let cases = std::fs::read_to_string(dir.join("cases.txt")).unwrap();
    let mut ran = 0;
    for line in cases.lines().filter(|l| !l.trim().is_empty() && !l.starts_with('#')) {
        let mut words = line.split_whitespace();
        let (name, data) = (words.next().unwrap(), words.next().unwrap());
        let (csv, json) = (out.join(format!("{name}.csv")), out.join(format!("{name}.json")));
        let run = Command::new(env!("CARGO_BIN_EXE_onsager"))
            .arg("estimate")
            .arg("--data")
            .arg(dir.join(data))
            .args(words)
            .arg("--out")
            .arg(&csv)
            .arg("--report")
            .arg(&json)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&run.stderr);
        assert!(matches!(run.status.code(), Some(0 | 2)), "{name}: {err}");
        compare_paths(name, &csv, &dir.join(format!("{name}.csv")));
        compare_reports(name, &json, &dir.join(format!("{name}.json")));
        ran += 1;
    }
    assert!(ran >= 19, "{ran} cases");
    std::fs::remove_dir_all(&out).unwrap();
}
