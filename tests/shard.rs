//! Sharded experiments: the shards' rows merged equal an unsharded run's (rows, summary, plots);
//! a shard killed midway and run again loses and duplicates no row; a merge with a shard
//! missing lists the missing replicates and fails; shards of different runs, duplicated or
//! misplaced rows and running shards are refused.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use onsager::experiment::builtin::builtin_text;
use onsager::experiment::report::parse_results;
use onsager::experiment::{builtin, merge, run, Experiment, MergeOptions, MergeStatus, RunOptions, Shard};
use onsager::Error;

use crate::experiment::row_set;

fn scratch(name: &str) -> PathBuf {
    crate::support::fresh_scratch("shard", name)
}

fn options(out: &Path, replicates: Option<usize>, shard: Option<Shard>) -> RunOptions {
    let mut o = RunOptions::new(out);
    o.quick = true;
    o.jobs = 1;
    o.replicates = replicates;
    o.shard = shard;
    o
}

fn shard(i: usize, n: usize) -> Option<Shard> {
    Some(Shard::try_new(i, n).unwrap())
}

/// `summary.json` without the `solve_seconds` statistics (timings differ between two runs;
/// everything else is computed from the rows).
fn summary_without_timing(dir: &Path) -> serde_json::Value {
    fn strip(v: &mut serde_json::Value) {
        match v {
            serde_json::Value::Object(m) => {
                m.remove("solve_seconds");
                m.values_mut().for_each(strip);
            }
            serde_json::Value::Array(a) => a.iter_mut().for_each(strip),
            _ => {}
        }
    }
    let mut v = serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap();
    strip(&mut v);
    v
}

fn file_names(dir: &Path) -> BTreeSet<String> {
    std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect()
}

/// The (scenario, replicate, estimator) of every row of `dir/results.csv`, with repeats.
fn row_keys(dir: &Path) -> Vec<(String, usize, String)> {
    let path = dir.join("results.csv");
    let rows = parse_results(&std::fs::read_to_string(&path).unwrap(), &path).unwrap().rows;
    rows.into_iter().map(|r| (r.scenario, r.replicate, r.estimator)).collect()
}

/// Runs shards `which` of `n` of `experiment` into `out`, concurrently (as the tasks of a job
/// array would).
fn run_shards(experiment: &Experiment, out: &Path, replicates: Option<usize>, n: usize, which: &[usize]) {
    std::thread::scope(|s| {
        for &i in which {
            s.spawn(move || {
                let report = run(experiment, &options(out, replicates, shard(i, n)), &|_| {}).unwrap();
                assert!(report.complete && report.summary.is_none(), "shard {i}/{n}");
            });
        }
    });
}

fn merge_error(dir: &Path) -> String {
    match merge(&MergeOptions::new(dir)) {
        Err(e @ Error::Merge { .. }) => e.to_string(),
        other => panic!("expected a refused merge, got {other:?}"),
    }
}

#[test]
fn three_shards_merged_equal_the_unsharded_run() {
    // tanh-limits quick: 2 scenarios × 2 replicates (units to shards 0, 1, 2, 0);
    // double-well-jumps quick with 3 replicates: 1 scenario, one replicate per shard.
    for (name, replicates) in [("tanh-limits", None), ("double-well-jumps", Some(3))] {
        let experiment = builtin(name).unwrap();
        let (whole, sharded) = (scratch(&format!("whole-{name}")), scratch(&format!("sharded-{name}")));
        let mut unsharded = options(&whole, replicates, None);
        unsharded.jobs = 2;
        let report = run(&experiment, &unsharded, &|_| {}).unwrap();
        run_shards(&experiment, &sharded, replicates, 3, &[0, 1, 2]);
        let merged = merge(&MergeOptions::new(&sharded)).unwrap();
        let MergeStatus::Complete { plots, .. } = &merged.status else {
            panic!("{name}: {:?}", merged.status)
        };
        assert_eq!((merged.rows, merged.total, merged.count), (report.total, report.total, 3), "{name}");
        assert!(merged.shards.iter().all(|s| s.rows > 0), "{name}: every shard has rows");
        assert_eq!(row_keys(&sharded).len(), report.total, "{name}: each row once");
        assert_eq!(row_set(&whole), row_set(&sharded), "{name}: the rows (timing aside)");
        assert_eq!(summary_without_timing(&whole), summary_without_timing(&sharded), "{name}: summary.json");
        // The same plots: the summary plots of the merge, the path plots of the shards.
        assert_eq!(file_names(&whole.join("plots")), file_names(&sharded.join("plots")), "{name}");
        assert_eq!(plots.len(), report.plots.len(), "{name}");
        // The merged folder resumes as an unsharded run: nothing left to compute.
        let mut again = options(&sharded, replicates, None);
        again.resume = true;
        again.plots = false;
        let resumed = run(&experiment, &again, &|_| {}).unwrap();
        assert_eq!((resumed.written, resumed.resumed), (0, report.total), "{name}");
        for d in [whole, sharded] {
            let _ = std::fs::remove_dir_all(d);
        }
    }
}

/// The data lines of a results.csv (0 while it does not exist).
fn data_lines(path: &Path) -> usize {
    std::fs::read_to_string(path).map(|t| t.lines().count().saturating_sub(1)).unwrap_or(0)
}

#[test]
fn a_shard_killed_midway_and_run_again_loses_and_duplicates_no_row() {
    // tanh-limits (full) with 60 replicates: 3 scenarios × 60 = 180 units, 60 per shard of 3,
    // 4 rows each; shard 0 is killed (SIGKILL) after 20 of its 240 rows.
    let bin = env!("CARGO_BIN_EXE_onsager");
    let out = scratch("killed");
    let shard_run = |i: usize| {
        let mut c = Command::new(bin);
        c.args(["experiment", "run", "tanh-limits", "--replicates", "60", "--jobs", "1", "--resume"])
            .args(["--shard", &format!("{i}/3"), "--out"])
            .arg(&out)
            .stdout(Stdio::null())
            .stderr(Stdio::null());
        c
    };
    let results = out.join("shards/0-of-3/results.csv");
    let mut child = shard_run(0).spawn().unwrap();
    let start = Instant::now();
    while data_lines(&results) < 20 {
        assert!(child.try_wait().unwrap().is_none(), "shard 0 ended before it could be killed");
        assert!(start.elapsed() < Duration::from_secs(120), "shard 0 wrote no rows in 120 s");
        std::thread::sleep(Duration::from_millis(2));
    }
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    let before = data_lines(&results);
    assert!((20..240).contains(&before), "killed midway: {before} of 240 rows");
    // A kill can cut the last line; so does this (resuming drops it).
    let mut text = std::fs::read_to_string(&results).unwrap();
    text.push_str("h=0.5,59,eul");
    std::fs::write(&results, text).unwrap();
    // The other shards, then shard 0 resubmitted.
    for i in [1, 2, 0] {
        assert!(shard_run(i).status().unwrap().success(), "shard {i}");
    }
    assert_eq!(data_lines(&results), 240);
    let merged = Command::new(bin).args(["experiment", "merge"]).arg(&out).output().unwrap();
    assert!(merged.status.success(), "{}", String::from_utf8_lossy(&merged.stderr));
    assert!(String::from_utf8_lossy(&merged.stdout).contains("720 of 720 rows"));
    let keys = row_keys(&out);
    assert_eq!(keys.len(), 720);
    assert_eq!(keys.iter().collect::<BTreeSet<_>>().len(), 720, "no row twice");
    // The same rows as an unsharded run.
    let whole = scratch("killed-whole");
    let mut unsharded = RunOptions::new(&whole);
    unsharded.replicates = Some(60);
    unsharded.plots = false;
    run(&builtin("tanh-limits").unwrap(), &unsharded, &|_| {}).unwrap();
    assert_eq!(row_set(&whole), row_set(&out));
    for d in [out, whole] {
        let _ = std::fs::remove_dir_all(d);
    }
}

#[test]
fn a_merge_with_a_shard_missing_lists_its_replicates_and_fails() {
    let experiment = builtin("tanh-limits").unwrap();
    let out = scratch("missing");
    // tanh-limits quick: unit k = 2·replicate + scenario (h = 0.5, 0.05); shard 1 of 3 has
    // k = 1 only: h=0.05, replicate 0.
    run_shards(&experiment, &out, None, 3, &[0, 2]);
    let report = merge(&MergeOptions::new(&out)).unwrap();
    let MergeStatus::Incomplete { missing } = &report.status else { panic!("{:?}", report.status) };
    assert_eq!(missing.len(), 1);
    assert_eq!(
        (missing[0].shard, missing[0].scenario.as_str(), missing[0].replicate),
        (shard(1, 3).unwrap(), "h=0.05", 0)
    );
    assert_eq!(missing[0].estimators, ["om", "energy", "euler", "trapezoidal"]);
    assert!(!out.join("results.csv").exists() && !out.join("summary.json").exists(), "nothing written");
    let cli =
        Command::new(env!("CARGO_BIN_EXE_onsager")).args(["experiment", "merge"]).arg(&out).output().unwrap();
    assert_eq!(cli.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&cli.stderr);
    assert!(stderr.contains("4 of 16 rows are missing"), "{stderr}");
    assert!(
        stderr.contains("shard 1/3: 4 rows missing") && stderr.contains("scenario h=0.05: replicates 0"),
        "{stderr}"
    );
    // The command that reruns it, with the run's replicates, seed and --quick.
    assert!(
        stderr.contains(
            "onsager experiment run tanh-limits --replicates 2 --seed 1 --quick --shard 1/3 --resume"
        ),
        "{stderr}"
    );
    assert!(stderr.contains("--array=1"), "{stderr}");
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn shards_of_different_runs_are_refused() {
    let tanh = builtin("tanh-limits").unwrap();
    /// Shard 1 of `count` of `other` (2 replicates), beside shard 0 of 3 of tanh-limits
    /// (quick, seed 1): the merge's message.
    struct Case {
        case: &'static str,
        seed: Option<u64>,
        other: &'static str,
        quick: bool,
        count: usize,
        message: &'static str,
    }
    let cases = [
        Case {
            case: "seed",
            seed: Some(5),
            other: "tanh-limits",
            quick: true,
            count: 3,
            message: "seed 1 in",
        },
        Case {
            case: "spec",
            seed: None,
            other: "double-well-jumps",
            quick: true,
            count: 3,
            message: "different specs (`tanh-limits`",
        },
        Case {
            case: "quick",
            seed: None,
            other: "tanh-limits",
            quick: false,
            count: 3,
            message: "the quick version",
        },
        Case {
            case: "count",
            seed: None,
            other: "tanh-limits",
            quick: true,
            count: 2,
            message: "of 3 shards",
        },
    ];
    for Case { case, seed, other, quick, count, message } in cases {
        let out = scratch(&format!("differ-{case}"));
        run(&tanh, &options(&out, None, shard(0, 3)), &|_| {}).unwrap();
        let mut o = options(&out, Some(2), shard(1, count));
        o.seed = seed;
        o.quick = quick;
        run(&builtin(other).unwrap(), &o, &|_| {}).unwrap();
        let err = merge_error(&out);
        assert!(err.contains(message) && err.contains("not parts of one run"), "{case}: {err}");
        let _ = std::fs::remove_dir_all(&out);
    }
    // The same name, another spec (a spec file edited between two shards).
    let out = scratch("differ-edited");
    run(&tanh, &options(&out, None, shard(0, 3)), &|_| {}).unwrap();
    let text = builtin_text("tanh-limits").unwrap().replace("dt = 0.005", "dt = 0.01");
    run(&Experiment::from_toml(&text).unwrap(), &options(&out, None, shard(1, 3)), &|_| {}).unwrap();
    let err = merge_error(&out);
    assert!(err.contains("different specs named `tanh-limits`"), "{err}");
    let _ = std::fs::remove_dir_all(&out);
    // Another number of replicates (a shard rerun with another --replicates).
    let out = scratch("differ-replicates");
    run_shards(&tanh, &out, None, 2, &[0]);
    run(&tanh, &options(&out, Some(4), shard(1, 2)), &|_| {}).unwrap();
    assert!(merge_error(&out).contains("ran 2 replicates per scenario"), "{}", merge_error(&out));
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn duplicated_misplaced_or_running_shards_are_refused() {
    let tanh = builtin("tanh-limits").unwrap();
    let out = scratch("refused");
    run_shards(&tanh, &out, None, 3, &[0, 1, 2]);
    let file = |i: usize| out.join(format!("shards/{i}-of-3/results.csv"));
    let original = std::fs::read_to_string(file(0)).unwrap();
    let last = original.lines().last().unwrap().to_string();
    // A row twice in its shard.
    std::fs::write(file(0), format!("{original}{last}\n")).unwrap();
    assert!(merge_error(&out).contains("appears twice in"), "{}", merge_error(&out));
    // A row of shard 0 in shard 2's file.
    std::fs::write(file(0), &original).unwrap();
    let two = std::fs::read_to_string(file(2)).unwrap();
    std::fs::write(file(2), format!("{two}{last}\n")).unwrap();
    assert!(merge_error(&out).contains("belongs to shard 0/3, not 2/3"), "{}", merge_error(&out));
    std::fs::write(file(2), &two).unwrap();
    // A shard still writing (its lock held): the merge waits for it, and the same shard
    // started a second time fails instead of writing its rows twice.
    let held = std::fs::OpenOptions::new().append(true).open(file(1)).unwrap();
    held.lock().unwrap();
    assert!(merge_error(&out).contains("shard 1/3 is still running"), "{}", merge_error(&out));
    let mut twice = options(&out, None, shard(1, 3));
    twice.resume = true;
    match run(&tanh, &twice, &|_| {}) {
        Err(Error::InvalidOption { name, reason }) => {
            assert!(name == "--out" && reason.contains("being written by another run"), "{reason}")
        }
        other => panic!("{other:?}"),
    }
    drop(held);
    // Merged once; merged again (e.g. after a resubmission) it is rewritten.
    assert!(matches!(merge(&MergeOptions::new(&out)).unwrap().status, MergeStatus::Complete { .. }));
    assert!(matches!(merge(&MergeOptions::new(&out)).unwrap().status, MergeStatus::Complete { .. }));
    // An unsharded run's results.csv is not replaced.
    let whole = scratch("refused-whole");
    run(&tanh, &options(&whole, None, None), &|_| {}).unwrap();
    std::fs::rename(out.join("shards"), whole.join("shards")).unwrap();
    assert!(merge_error(&whole).contains("not written by a merge"), "{}", merge_error(&whole));
    for d in [out, whole] {
        let _ = std::fs::remove_dir_all(d);
    }
}

#[test]
fn cli_shard_flag_and_slurm_scripts() {
    let bin = env!("CARGO_BIN_EXE_onsager");
    let out = scratch("cli");
    for bad in ["3/3", "1", "a/2", "0/0"] {
        let o = Command::new(bin)
            .args(["experiment", "run", "tanh-limits", "--quick", "--shard", bad])
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(1), "{bad}");
        assert!(String::from_utf8_lossy(&o.stderr).contains("--shard"), "{bad}");
    }
    let o = Command::new(bin)
        .args(["experiment", "slurm", "tanh-limits", "--quick", "--shards", "3", "--time", "10:00", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("sbatch --dependency=afterok:JOB"), "{stdout}");
    let array = std::fs::read_to_string(out.join("slurm/array.sbatch")).unwrap();
    assert!(
        array.contains("#SBATCH --array=0-2")
            && array.contains("--quick --shard \"${SLURM_ARRAY_TASK_ID}/3\" --resume")
    );
    assert!(array.contains(&format!("--out {}", out.display())), "{array}");
    assert!(out.join("slurm/merge.sbatch").exists() && out.join("slurm/submit.sh").exists());
    let bad =
        Command::new(bin).args(["experiment", "slurm", "tanh-limits", "--time", "2h"]).output().unwrap();
    assert_eq!(bad.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("--time"));
    let _ = std::fs::remove_dir_all(&out);
}
