//! Sharded runs: one experiment split over independent processes (the tasks of a Slurm job
//! array, or shells on one machine), and the merge of their rows.
//!
//! The work of an experiment is its (scenario, replicate) units. With `S` scenarios (in the
//! order of the grid), unit (s, r) is the `k = r·S + s`-th, counting replicate by replicate,
//! and belongs to shard `(k + ⌊k/L⌋) mod N` of `N`, where `L = lcm(S, N)`
//! ([`Shard::assigned`]): the units are dealt round-robin, and the deal shifts by one shard
//! after every `L` units, so that a scenario does not stay on the same shards when `S` and `N`
//! have a common factor (with `S = N = 3`, plain `k mod N` would give each shard one
//! scenario). So the shards differ by at most one unit in all and by at most one replicate of
//! each scenario, and growing the number of replicates later does not move a unit to another
//! shard.
//!
//! Shard `I` of `N` writes `OUT/shards/I-of-N/` ([`Shard::folder`]): its `results.csv` (the
//! rows of its units, exactly those an unsharded run with the same seed writes for them, since
//! a replicate's seed depends only on (seed, scenario, replicate)), `run.json` (the resume key:
//! spec, seed and `--quick`) and `shard.json` (the shard, the number of shards and the
//! replicates per scenario). The path plots of replicate 0 go to `OUT/plots/` as in an
//! unsharded run. A shard resumes like a run ([`RunOptions::resume`](super::RunOptions)), and
//! holds an exclusive lock on its `results.csv` while it runs, so that the same shard started
//! twice fails instead of writing its rows twice.
//!
//! [`merge`] gathers the shards' rows into `OUT/results.csv`, `summary.json` and the plots,
//! exactly as an unsharded run writes them.

use std::collections::{BTreeMap, HashMap};
use std::fmt;
use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use super::report::{self, Results};
use super::runner::{self, Row};
use super::spec::{Experiment, Scenario};
use crate::{Error, Result};

/// Shard `index` of `count` (`0 ≤ index < count`); written `I/N` on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Shard {
    index: usize,
    count: usize,
}

impl Shard {
    /// Shard `index` of `count`. Errors: [`Error::InvalidOption`] (`--shard`) unless
    /// `count ≥ 1` and `index < count`.
    pub fn try_new(index: usize, count: usize) -> Result<Shard> {
        if count == 0 {
            return Err(Error::invalid("--shard", "the number of shards N in I/N must be at least 1"));
        }
        if index >= count {
            return Err(Error::invalid(
                "--shard",
                format!("shard {index}/{count}: I in I/N counts from 0 to N-1 = {}", count - 1),
            ));
        }
        Ok(Shard { index, count })
    }

    /// The shard's index `I` (from 0).
    pub fn index(&self) -> usize {
        self.index
    }

    /// The number of shards `N`.
    pub fn count(&self) -> usize {
        self.count
    }

    /// The shard (of `count`) that runs replicate `replicate` of scenario `scenario` (its index
    /// in the grid) when the experiment has `scenarios` scenarios: `(k + ⌊k/L⌋) mod count`
    /// with `k = replicate·scenarios + scenario` and `L = lcm(scenarios, count)` (see the
    /// [module](self)).
    pub fn assigned(scenario: usize, replicate: usize, scenarios: usize, count: usize) -> usize {
        let (s, n) = (scenarios.max(1) as u128, count.max(1) as u128);
        let k = replicate as u128 * s + scenario as u128;
        let lcm = s / gcd(s, n) * n;
        ((k + k / lcm) % n) as usize
    }

    /// Whether this shard runs replicate `replicate` of scenario `scenario` (see
    /// [`Shard::assigned`]).
    pub fn owns(&self, scenario: usize, replicate: usize, scenarios: usize) -> bool {
        Shard::assigned(scenario, replicate, scenarios, self.count) == self.index
    }

    /// The shard's folder in the output folder `out`: `out/shards/I-of-N`.
    pub fn folder(&self, out: &Path) -> PathBuf {
        out.join("shards").join(format!("{}-of-{}", self.index, self.count))
    }

    /// The shard of a folder name `I-of-N`, if it is one.
    fn from_folder_name(name: &str) -> Option<Shard> {
        let (i, n) = name.split_once("-of-")?;
        Shard::try_new(i.parse().ok()?, n.parse().ok()?).ok()
    }
}

fn gcd(a: u128, b: u128) -> u128 {
    if b == 0 {
        a
    } else {
        gcd(b, a % b)
    }
}

impl fmt::Display for Shard {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl FromStr for Shard {
    type Err = Error;

    /// `I/N`, e.g. `0/3` (the first of three shards).
    fn from_str(s: &str) -> Result<Shard> {
        let bad = || Error::invalid("--shard", format!("expected I/N with 0 ≤ I < N (e.g. 0/3), got `{s}`"));
        let (i, n) = s.split_once('/').ok_or_else(bad)?;
        let i = i.trim().parse::<usize>().map_err(|_| bad())?;
        let n = n.trim().parse::<usize>().map_err(|_| bad())?;
        Shard::try_new(i, n)
    }
}

/// `shard.json` of a shard's folder.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct ShardRecord {
    shard: usize,
    shards: usize,
    replicates: usize,
}

/// Writes `shard.json` (the shard and the replicates per scenario) in the shard's `folder`.
pub(crate) fn write_record(folder: &Path, shard: Shard, replicates: usize) -> Result<()> {
    let path = folder.join("shard.json");
    let record = ShardRecord { shard: shard.index, shards: shard.count, replicates };
    let text = serde_json::to_string(&record).expect("a record serialises");
    std::fs::write(&path, text + "\n").map_err(|source| Error::Io { path, source })
}

/// The resume key of `run.json`, parsed (see `Experiment::resume_key`).
#[derive(Debug, Clone, PartialEq, Deserialize)]
struct RunKey {
    spec: String,
    seed: u64,
    quick: bool,
}

/// How to merge the shards of a folder.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct MergeOptions {
    /// The output folder the shards wrote to (`DIR/shards/I-of-N`); the merge writes
    /// `DIR/results.csv`, `DIR/summary.json` and `DIR/plots/`.
    pub dir: PathBuf,
    /// Write the summary plots (default true).
    pub plots: bool,
}

impl MergeOptions {
    /// Merging the shards of `dir`, with plots.
    pub fn new(dir: impl Into<PathBuf>) -> MergeOptions {
        MergeOptions { dir: dir.into(), plots: true }
    }
}

/// One shard folder found by [`merge`].
#[derive(Debug, Clone, PartialEq)]
pub struct ShardFolder {
    /// The shard.
    pub shard: Shard,
    /// Its folder.
    pub folder: PathBuf,
    /// Its complete rows.
    pub rows: usize,
}

/// The rows of one (scenario, replicate) that no shard has.
#[derive(Debug, Clone, PartialEq)]
pub struct Missing {
    /// The shard that runs them.
    pub shard: Shard,
    /// The scenario.
    pub scenario: String,
    /// The replicate.
    pub replicate: usize,
    /// The estimators whose rows are missing.
    pub estimators: Vec<String>,
}

/// Whether the shards held every row.
#[derive(Debug, Clone, PartialEq)]
pub enum MergeStatus {
    /// Every row is there: `results.csv`, `summary.json` and the plots are written.
    Complete {
        /// `DIR/results.csv`.
        results: PathBuf,
        /// `DIR/summary.json`.
        summary: PathBuf,
        /// The plots in `DIR/plots/` (stems; each has `.svg` and `.png`): the summary plots
        /// written now and the path plots the shards wrote.
        plots: Vec<PathBuf>,
    },
    /// Rows are missing (a shard not run, failed or still running): nothing is written.
    Incomplete {
        /// The missing rows, by shard, scenario and replicate.
        missing: Vec<Missing>,
    },
}

/// The outcome of [`merge`].
#[derive(Debug, Clone, PartialEq)]
pub struct MergeReport {
    /// The experiment's name.
    pub experiment: String,
    /// Whether the shards ran the quick version.
    pub quick: bool,
    /// The seed the shards ran with.
    pub seed: u64,
    /// The number of shards N.
    pub count: usize,
    /// Replicates per scenario.
    pub replicates: usize,
    /// The shard folders found, by index.
    pub shards: Vec<ShardFolder>,
    /// Rows gathered.
    pub rows: usize,
    /// Rows of the whole experiment.
    pub total: usize,
    /// Complete or not.
    pub status: MergeStatus,
}

fn refuse(dir: &Path, reason: impl Into<String>) -> Error {
    Error::Merge { path: dir.to_path_buf(), reason: reason.into() }
}

/// One shard folder as read: its key, record and rows.
struct ShardData {
    shard: Shard,
    folder: PathBuf,
    key: String,
    record: ShardRecord,
    results: Results,
}

/// The shard folders `dir/shards/I-of-N`, by index.
fn shard_folders(dir: &Path) -> Result<Vec<(Shard, PathBuf)>> {
    let shards = dir.join("shards");
    let entries = match std::fs::read_dir(&shards) {
        Ok(entries) => entries,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Err(refuse(
            dir,
            "no shards here (no folder shards/); run `onsager experiment run NAME --shard I/N --out DIR` \
                 for each shard first",
        )),
        Err(source) => return Err(Error::Io { path: shards, source }),
    };
    let mut found = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|source| Error::Io { path: shards.clone(), source })?;
        if let Some(shard) = entry.file_name().to_str().and_then(Shard::from_folder_name) {
            found.push((shard, entry.path()));
        }
    }
    if found.is_empty() {
        return Err(refuse(dir, format!("no shard folders (I-of-N) in {}", shards.display())));
    }
    found.sort();
    Ok(found)
}

/// Reads one shard folder: `run.json`, `shard.json` and the complete lines of `results.csv`
/// (a last line cut by a killed shard is left out; the file is not changed).
fn read_shard(dir: &Path, shard: Shard, folder: PathBuf) -> Result<ShardData> {
    let io = |path: PathBuf| move |source| Error::Io { path, source };
    let run_json = folder.join("run.json");
    let key = std::fs::read_to_string(&run_json).map_err(io(run_json.clone()))?.trim().to_string();
    let record_path = folder.join("shard.json");
    let text = std::fs::read_to_string(&record_path).map_err(io(record_path.clone()))?;
    let record: ShardRecord = serde_json::from_str(&text)
        .map_err(|e| refuse(dir, format!("{}: not a shard record: {e}", record_path.display())))?;
    if (record.shard, record.shards) != (shard.index, shard.count) {
        return Err(refuse(
            dir,
            format!(
                "{} says shard {}/{}, its folder is shard {shard}",
                record_path.display(),
                record.shard,
                record.shards
            ),
        ));
    }
    let path = folder.join("results.csv");
    let file = File::open(&path).map_err(io(path.clone()))?;
    if let Err(std::fs::TryLockError::WouldBlock) = file.try_lock_shared() {
        return Err(refuse(
            dir,
            format!(
                "shard {shard} is still running ({} is being written); merge when it ends",
                path.display()
            ),
        ));
    }
    let text = std::io::read_to_string(&file).map_err(io(path.clone()))?;
    let complete = text.rfind('\n').map_or(0, |i| i + 1);
    let results = report::parse_results(&text[..complete], &path)?;
    Ok(ShardData { shard, folder, key, record, results })
}

/// Refuses shards that are not parts of one run: another number of shards, replicates, spec,
/// seed, `--quick` setting or header.
fn check_same_run(dir: &Path, first: &ShardData, other: &ShardData) -> Result<()> {
    let (a, b) = (first.folder.display(), other.folder.display());
    let differ = |what: String| {
        refuse(
            dir,
            format!(
                "shards {} and {} are not parts of one run: {what}; merge only the shards of one run \
                 (move the others to another folder)",
                first.shard, other.shard
            ),
        )
    };
    if first.shard.count != other.shard.count {
        return Err(differ(format!("{} of {} shards, {} of {}", a, first.shard.count, b, other.shard.count)));
    }
    if first.key != other.key {
        let parse = |d: &ShardData| {
            serde_json::from_str::<RunKey>(&d.key).map_err(|e| {
                refuse(dir, format!("{}: not a run key: {e}", d.folder.join("run.json").display()))
            })
        };
        let (ka, kb) = (parse(first)?, parse(other)?);
        let name = |k: &RunKey| {
            toml::from_str::<toml::Table>(&k.spec)
                .ok()
                .and_then(|t| t.get("name").and_then(|n| n.as_str().map(String::from)))
                .unwrap_or_default()
        };
        let reason = if ka.spec != kb.spec && name(&ka) == name(&kb) {
            format!("different specs named `{}` in {a} and {b} (a spec file edited between them?)", name(&ka))
        } else if ka.spec != kb.spec {
            format!("different specs (`{}` in {a}, `{}` in {b})", name(&ka), name(&kb))
        } else if ka.seed != kb.seed {
            format!("seed {} in {a}, seed {} in {b}", ka.seed, kb.seed)
        } else {
            let q = |quick: bool| if quick { "the quick version" } else { "the full version" };
            format!("{a} ran {}, {b} {}", q(ka.quick), q(kb.quick))
        };
        return Err(differ(reason));
    }
    if first.record.replicates != other.record.replicates {
        return Err(differ(format!(
            "{a} ran {} replicates per scenario, {b} {} (rerun the shards with the same --replicates)",
            first.record.replicates, other.record.replicates
        )));
    }
    if first.results.header != other.results.header {
        return Err(differ(format!("{a} and {b} have different columns in results.csv")));
    }
    Ok(())
}

/// The experiment the shards ran, from their resume key and replicates.
fn experiment_of(dir: &Path, data: &ShardData) -> Result<(Experiment, RunKey)> {
    let key: RunKey = serde_json::from_str(&data.key).map_err(|e| {
        refuse(dir, format!("{}: not a run key: {e}", data.folder.join("run.json").display()))
    })?;
    let experiment =
        Experiment::from_toml(&key.spec)?.with_seed(key.seed).with_replicates(data.record.replicates);
    Ok((experiment, key))
}

/// Every row once, each in the shard that runs it; the rows sorted by scenario (grid order),
/// replicate and estimator (the spec's order). Errors: a duplicate row, a row in the wrong
/// shard or of an unknown scenario or estimator.
fn gather(dir: &Path, scenarios: &[Scenario], data: Vec<ShardData>) -> Result<Vec<Row>> {
    let index: HashMap<&str, usize> =
        scenarios.iter().enumerate().map(|(i, s)| (s.name.as_str(), i)).collect();
    let mut seen: HashMap<(usize, usize, usize), PathBuf> = HashMap::new();
    let mut rows = Vec::new();
    for d in data {
        let file = d.folder.join("results.csv");
        for row in d.results.rows {
            let what = || format!("row ({}, replicate {}, {})", row.scenario, row.replicate, row.estimator);
            let Some(&si) = index.get(row.scenario.as_str()) else {
                return Err(refuse(dir, format!("{}: {} of an unknown scenario", file.display(), what())));
            };
            let Some(ei) = scenarios[si].estimators.iter().position(|e| e.label == row.estimator) else {
                return Err(refuse(dir, format!("{}: {} of an unknown estimator", file.display(), what())));
            };
            if !d.shard.owns(si, row.replicate, scenarios.len()) {
                let owner = Shard::assigned(si, row.replicate, scenarios.len(), d.shard.count);
                return Err(refuse(
                    dir,
                    format!(
                        "{}: {} belongs to shard {owner}/{}, not {}",
                        file.display(),
                        what(),
                        d.shard.count,
                        d.shard
                    ),
                ));
            }
            if let Some(earlier) = seen.insert((si, row.replicate, ei), file.clone()) {
                let place = if earlier == file {
                    format!("twice in {}", file.display())
                } else {
                    format!("in {} and in {}", earlier.display(), file.display())
                };
                return Err(refuse(dir, format!("{} appears {place}", what())));
            }
            rows.push(((si, row.replicate, ei), row));
        }
    }
    rows.sort_by_key(|(k, _)| *k);
    Ok(rows.into_iter().map(|(_, r)| r).collect())
}

/// The rows of replicates `0..replicates` that `rows` lack, by unit.
fn missing(scenarios: &[Scenario], replicates: usize, count: usize, rows: &[Row]) -> Vec<Missing> {
    let mut present: BTreeMap<(&str, usize), Vec<&str>> = BTreeMap::new();
    for r in rows {
        present.entry((r.scenario.as_str(), r.replicate)).or_default().push(r.estimator.as_str());
    }
    let mut out = Vec::new();
    for r in 0..replicates {
        for (si, s) in scenarios.iter().enumerate() {
            let have = present.get(&(s.name.as_str(), r));
            let lacking: Vec<String> = s
                .estimators
                .iter()
                .filter(|e| !have.is_some_and(|h| h.contains(&e.label.as_str())))
                .map(|e| e.label.clone())
                .collect();
            if !lacking.is_empty() {
                let shard = Shard { index: Shard::assigned(si, r, scenarios.len(), count), count };
                out.push(Missing { shard, scenario: s.name.clone(), replicate: r, estimators: lacking });
            }
        }
    }
    out.sort_by_key(|m| (m.shard, m.replicate));
    out
}

/// Writes `text` to `path` through a temporary file renamed over it.
fn write_atomic(path: &Path, text: &str) -> Result<()> {
    let tmp = path.with_extension("tmp");
    let io = |p: &Path| {
        let p = p.to_path_buf();
        move |source| Error::Io { path: p, source }
    };
    let mut f = File::create(&tmp).map_err(io(&tmp))?;
    f.write_all(text.as_bytes()).map_err(io(&tmp))?;
    f.sync_all().map_err(io(&tmp))?;
    std::fs::rename(&tmp, path).map_err(io(path))
}

/// Merges the shards of `options.dir` (`DIR/shards/I-of-N`, written by
/// [`run`](super::run) with [`RunOptions::shard`](super::RunOptions)): checks that they are
/// parts of one run (number of shards, replicates, spec, seed, `--quick`), gathers their rows
/// and, when every row of the experiment is there, writes `DIR/results.csv` (sorted by
/// scenario, replicate and estimator), `DIR/run.json` (so that an unsharded `--resume` can
/// extend the merged run), `DIR/summary.json` and the summary plots, as an unsharded run
/// does. When rows are missing nothing is written and the status lists them.
///
/// Errors ([`Error::Merge`] naming the folder and the files): no shard folders; shards of
/// different runs; a row twice, in the wrong shard or of an unknown scenario or estimator; a
/// shard still running; a `DIR/results.csv` not written by a merge (an unsharded run's, which
/// the merge would replace).
pub fn merge(options: &MergeOptions) -> Result<MergeReport> {
    let dir = options.dir.as_path();
    let mut data = Vec::new();
    for (shard, folder) in shard_folders(dir)? {
        data.push(read_shard(dir, shard, folder)?);
    }
    for d in &data[1..] {
        check_same_run(dir, &data[0], d)?;
    }
    let (experiment, RunKey { quick, seed, .. }) = experiment_of(dir, &data[0])?;
    let scenarios = experiment.scenarios(quick)?;
    let spec = scenarios[0].spec.clone();
    let (count, replicates, key) = (data[0].shard.count, data[0].record.replicates, data[0].key.clone());
    let header = data[0].results.header.clone();
    let (metric_columns, theta_columns) =
        (data[0].results.metric_columns.clone(), data[0].results.theta_columns.clone());
    let shards: Vec<ShardFolder> = data
        .iter()
        .map(|d| ShardFolder { shard: d.shard, folder: d.folder.clone(), rows: d.results.rows.len() })
        .collect();
    let rows = gather(dir, &scenarios, data)?;
    let total = scenarios.iter().map(|s| s.estimators.len()).sum::<usize>() * replicates;
    let lacking = missing(&scenarios, replicates, count, &rows);
    let n_rows = rows.len();
    let report = |status| MergeReport {
        experiment: spec.name.clone(),
        quick,
        seed,
        count,
        replicates,
        shards: shards.clone(),
        rows: n_rows,
        total,
        status,
    };
    if !lacking.is_empty() {
        return Ok(report(MergeStatus::Incomplete { missing: lacking }));
    }
    let results = dir.join("results.csv");
    let marker = dir.join("merged.json");
    if results.exists() && !marker.exists() {
        return Err(refuse(
            dir,
            format!(
                "{} exists and was not written by a merge (an unsharded run's rows); move it away first",
                results.display()
            ),
        ));
    }
    let mut text = runner::csv_line(&header);
    for r in &rows {
        text.push_str(&runner::csv_line(&r.fields()));
    }
    write_atomic(&results, &text)?;
    write_atomic(&dir.join("run.json"), &format!("{key}\n"))?;
    let merged = serde_json::json!({ "shards": count, "replicates": replicates, "rows": rows.len() });
    write_atomic(&marker, &format!("{merged}\n"))?;
    let mut table = Results { header, metric_columns, theta_columns, rows };
    table.rows.retain(|r| r.replicate < replicates);
    let (summary, mut plots) = runner::finish(dir, &spec, &scenarios, &table, quick, options.plots)?;
    if options.plots {
        for s in &scenarios {
            let stem = dir.join("plots").join(format!("paths_{}", report::file_name(&s.name)));
            if PathBuf::from(format!("{}.svg", stem.display())).exists() {
                plots.push(stem);
            }
        }
    }
    plots.sort();
    let status = MergeStatus::Complete { results, summary, plots };
    Ok(report(status))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_unit_falls_to_one_shard_and_the_shards_share_every_scenario_evenly() {
        let cases = [(1, 1, 1), (2, 2, 3), (9, 50, 7), (3, 20, 40), (1, 2000, 16), (3, 60, 3), (9, 2000, 40)];
        let more = [(4, 37, 2), (6, 25, 4), (9, 31, 6), (9, 100, 9), (2, 5, 5), (12, 13, 8)];
        for (scenarios, replicates, count) in cases.into_iter().chain(more) {
            let shards: Vec<Shard> = (0..count).map(|i| Shard::try_new(i, count).unwrap()).collect();
            let mut sizes = vec![vec![0usize; count]; scenarios];
            for (s, per_shard) in sizes.iter_mut().enumerate() {
                for r in 0..replicates {
                    let owners: Vec<usize> =
                        shards.iter().filter(|sh| sh.owns(s, r, scenarios)).map(|sh| sh.index()).collect();
                    assert_eq!(owners, [Shard::assigned(s, r, scenarios, count)]);
                    per_shard[owners[0]] += 1;
                }
            }
            let spread = |v: &[usize]| v.iter().max().unwrap() - v.iter().min().unwrap();
            let all: Vec<usize> = (0..count).map(|i| sizes.iter().map(|s| s[i]).sum()).collect();
            assert!(spread(&all) <= 1, "{scenarios}×{replicates} over {count}: {all:?}");
            for (s, per_shard) in sizes.iter().enumerate() {
                assert!(
                    spread(per_shard) <= 1,
                    "{scenarios}×{replicates} over {count}, scenario {s}: {per_shard:?}"
                );
            }
        }
        // Unit k = replicate·S + scenario goes to (k + ⌊k/L⌋) mod N, L = lcm(S, N):
        // (scenario 1, replicate 2) of 3 scenarios is unit 7, L = 12, shard 3 of 4;
        // (scenario 0, replicate 1) of 3 is unit 3, L = 3, shard (3 + 1) mod 3 = 1 of 3.
        assert_eq!(Shard::assigned(1, 2, 3, 4), 3);
        assert_eq!(Shard::assigned(0, 1, 3, 3), 1);
        // Growing the replicates moves no unit: the rule does not involve their number.
    }

    #[test]
    fn shards_parse_from_i_of_n_and_name_their_folder() {
        let s: Shard = "2/5".parse().unwrap();
        assert_eq!((s.index(), s.count(), s.to_string()), (2, 5, "2/5".to_string()));
        assert_eq!(s.folder(Path::new("out")), Path::new("out/shards/2-of-5"));
        assert_eq!(Shard::from_folder_name("2-of-5"), Some(s));
        assert_eq!(Shard::from_folder_name("5-of-5"), None);
        for bad in ["5/5", "0/0", "1", "-1/3", "a/b", "1/3/4"] {
            match bad.parse::<Shard>() {
                Err(Error::InvalidOption { name, .. }) => assert_eq!(name, "--shard", "{bad}"),
                other => panic!("{bad}: {other:?}"),
            }
        }
    }
}
