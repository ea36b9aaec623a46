//! Slurm job scripts for a sharded experiment: a job array whose task `I` runs shard `I` of
//! `N` ([`super::shard`]) with `--resume`, and a merge job that runs after every task ended
//! well (`--dependency=afterok`).
//!
//! [`write`] puts three files in `OUT/slurm/`:
//!
//! - `array.sbatch`: `#SBATCH --array=0-(N-1)`; each task runs
//!   `onsager experiment run NAME --shard $SLURM_ARRAY_TASK_ID/N --resume --jobs
//!   $SLURM_CPUS_PER_TASK --out OUT` (logs `OUT/slurm/shard-I.log`, appended to). It asks for
//!   `--requeue`, so a pre-empted task is requeued and continues its shard.
//! - `merge.sbatch`: `onsager experiment merge OUT` (log `OUT/slurm/merge.log`).
//! - `submit.sh`: submits the array, then the merge with `--dependency=afterok:ARRAY_ID
//!   --kill-on-invalid-dep=yes`, and prints both job ids.
//!
//! A task that failed or was killed is resubmitted alone (`sbatch --array=I array.sbatch`) or
//! with the others (`sh submit.sh` again: complete shards find all their rows and end at
//! once); either way only the missing rows are computed.

use std::path::{Path, PathBuf};

use crate::{Error, Result};

/// What the Slurm scripts run, and the resources they ask for.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct SlurmOptions {
    /// The experiment as `onsager experiment run` takes it: a built-in name, or a spec file's
    /// path (absolute, so that the compute nodes find it).
    pub experiment: String,
    /// The `onsager` program the tasks run (absolute; on a file system the nodes see).
    pub program: PathBuf,
    /// The output folder (absolute; shared with the nodes): the shards, the merged results and
    /// `slurm/` with the scripts and the logs.
    pub out: PathBuf,
    /// Number of shards N, one array task each (≥ 1). Default 10.
    pub shards: usize,
    /// CPUs per task (≥ 1), the worker threads of each shard (`--jobs`). Default 1.
    pub cpus_per_task: usize,
    /// Wall-time limit per task in a Slurm time format (`MM`, `MM:SS`, `HH:MM:SS`, `D-HH`,
    /// `D-HH:MM`, `D-HH:MM:SS`). Default: none (the partition's).
    pub time: Option<String>,
    /// The partition. Default: none (the cluster's default partition).
    pub partition: Option<String>,
    /// Run the spec's quick version. Default false.
    pub quick: bool,
    /// Replicates per scenario. Default: the spec's.
    pub replicates: Option<usize>,
    /// Seed. Default: the spec's.
    pub seed: Option<u64>,
}

impl SlurmOptions {
    /// Scripts running `experiment` with `program` into `out`; every other option at its
    /// default (10 shards, 1 CPU per task, no time limit or partition, full version, the
    /// spec's replicates and seed).
    pub fn new(
        experiment: impl Into<String>,
        program: impl Into<PathBuf>,
        out: impl Into<PathBuf>,
    ) -> SlurmOptions {
        SlurmOptions {
            experiment: experiment.into(),
            program: program.into(),
            out: out.into(),
            shards: 10,
            cpus_per_task: 1,
            time: None,
            partition: None,
            quick: false,
            replicates: None,
            seed: None,
        }
    }

    /// Checks the options. Errors: [`Error::InvalidOption`] naming the flag: `--shards` or
    /// `--cpus-per-task` of 0, a `--time` not in a Slurm format, a `--partition` with other
    /// characters than letters, digits, `_`, `-`, `.` and `,`, a `--out` or program path that
    /// is not absolute or holds whitespace, quotes or `%` (Slurm's file-name patterns).
    pub fn validate(&self) -> Result<()> {
        if self.shards == 0 {
            return Err(Error::invalid("--shards", "must be at least 1"));
        }
        if self.cpus_per_task == 0 {
            return Err(Error::invalid("--cpus-per-task", "must be at least 1"));
        }
        if let Some(t) = &self.time {
            check_time(t)?;
        }
        if let Some(p) = &self.partition {
            let ok = |c: char| c.is_ascii_alphanumeric() || "_-.,".contains(c);
            if p.is_empty() || !p.chars().all(ok) {
                return Err(Error::invalid(
                    "--partition",
                    format!("`{p}` is not a partition name (letters, digits, `_`, `-`, `.`; several joined by `,`)"),
                ));
            }
        }
        check_path("--out", &self.out)?;
        check_path("the onsager program", &self.program)?;
        if self.experiment.is_empty()
            || self.experiment.chars().any(|c| c.is_whitespace() || "'\"%".contains(c))
        {
            return Err(Error::invalid(
                "EXPERIMENT",
                format!(
                    "`{}`: the Slurm scripts need a name or path without whitespace, quotes or `%`",
                    self.experiment
                ),
            ));
        }
        Ok(())
    }
}

/// A path the scripts can name: absolute, without whitespace, quotes or `%`.
fn check_path(name: &str, path: &Path) -> Result<()> {
    let text = path.to_string_lossy();
    if !path.is_absolute() {
        return Err(Error::invalid(name, format!("`{text}` must be an absolute path for the Slurm scripts")));
    }
    if text.chars().any(|c| c.is_whitespace() || "'\"%".contains(c)) {
        return Err(Error::invalid(
            name,
            format!("`{text}`: the Slurm scripts need a path without whitespace, quotes or `%`"),
        ));
    }
    Ok(())
}

/// Checks a Slurm time limit: `MM`, `MM:SS`, `HH:MM:SS`, `D-HH`, `D-HH:MM` or `D-HH:MM:SS`
/// (digits only), or `UNLIMITED`/`INFINITE`.
fn check_time(t: &str) -> Result<()> {
    let digits = |s: &str| !s.is_empty() && s.chars().all(|c| c.is_ascii_digit());
    let ok = if t.eq_ignore_ascii_case("unlimited") || t.eq_ignore_ascii_case("infinite") {
        true
    } else if let Some((days, rest)) = t.split_once('-') {
        let parts: Vec<&str> = rest.split(':').collect();
        digits(days) && parts.len() <= 3 && parts.iter().all(|p| digits(p))
    } else {
        let parts: Vec<&str> = t.split(':').collect();
        parts.len() <= 3 && parts.iter().all(|p| digits(p))
    };
    if ok {
        Ok(())
    } else {
        Err(Error::invalid(
            "--time",
            format!("`{t}` is not a Slurm time (MM, MM:SS, HH:MM:SS, D-HH, D-HH:MM or D-HH:MM:SS)"),
        ))
    }
}

/// The three scripts, as text.
#[derive(Debug, Clone, PartialEq)]
pub struct SlurmScripts {
    /// `array.sbatch`: the job array, one task per shard.
    pub array: String,
    /// `merge.sbatch`: the merge job.
    pub merge: String,
    /// `submit.sh`: submits both, the merge depending on the array.
    pub submit: String,
}

/// The files [`write`] wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct SlurmFiles {
    /// `OUT/slurm/array.sbatch`.
    pub array: PathBuf,
    /// `OUT/slurm/merge.sbatch`.
    pub merge: PathBuf,
    /// `OUT/slurm/submit.sh`.
    pub submit: PathBuf,
}

/// The folder of the scripts and logs: `out/slurm`.
pub fn folder(out: &Path) -> PathBuf {
    out.join("slurm")
}

/// The `#SBATCH` lines every job shares: name, one task, CPUs, time, partition, log.
fn header(o: &SlurmOptions, name: &str, cpus: usize, log: &str) -> String {
    let mut h = format!(
        "#!/bin/bash\n#SBATCH --job-name={name}\n#SBATCH --ntasks=1\n#SBATCH --cpus-per-task={cpus}\n"
    );
    if let Some(t) = &o.time {
        h.push_str(&format!("#SBATCH --time={t}\n"));
    }
    if let Some(p) = &o.partition {
        h.push_str(&format!("#SBATCH --partition={p}\n"));
    }
    h.push_str(&format!("#SBATCH --output={}/{log}\n#SBATCH --open-mode=append\n", folder(&o.out).display()));
    h
}

/// The scripts for `options` (checked first; see [`SlurmOptions::validate`]).
pub fn scripts(options: &SlurmOptions) -> Result<SlurmScripts> {
    options.validate()?;
    let o = options;
    let n = o.shards;
    let name = format!("onsager-{}", super::report::file_name(o.experiment.rsplit('/').next().unwrap_or("")));
    let mut flags = String::new();
    if o.quick {
        flags.push_str(" --quick");
    }
    if let Some(r) = o.replicates {
        flags.push_str(&format!(" --replicates {r}"));
    }
    if let Some(s) = o.seed {
        flags.push_str(&format!(" --seed {s}"));
    }
    let (program, out) = (o.program.display(), o.out.display());
    let mut array = header(o, &name, o.cpus_per_task, "shard-%a.log");
    array.push_str(&format!(
        "#SBATCH --array=0-{last}\n#SBATCH --requeue\n\
         # Task I runs shard I of {n} into {out}/shards/I-of-{n}; a resubmitted or requeued task\n\
         # computes only the rows its shard lacks (--resume).\n\
         set -eu\n\
         echo \"shard ${{SLURM_ARRAY_TASK_ID}}/{n} on $(hostname) (job ${{SLURM_JOB_ID}})\"\n\
         exec {program} experiment run {experiment}{flags} --shard \"${{SLURM_ARRAY_TASK_ID}}/{n}\" \
         --resume --jobs \"${{SLURM_CPUS_PER_TASK:-1}}\" --out {out}\n",
        last = n - 1,
        experiment = o.experiment,
    ));
    let mut merge = header(o, &format!("{name}-merge"), 1, "merge.log");
    merge.push_str(&format!(
        "# Merges the {n} shards of {out} into results.csv, summary.json and plots/.\n\
         set -eu\n\
         exec {program} experiment merge {out}\n"
    ));
    let dir = folder(&o.out);
    let dir = dir.display();
    let submit = format!(
        "#!/bin/sh\n\
         # Submits the {n} shards as a job array and the merge to run once every task ended well.\n\
         set -eu\n\
         array=$(sbatch --parsable {dir}/array.sbatch)\n\
         array=${{array%%;*}}\n\
         merge=$(sbatch --parsable --dependency=afterok:${{array}} --kill-on-invalid-dep=yes {dir}/merge.sbatch)\n\
         merge=${{merge%%;*}}\n\
         echo \"array job ${{array}} ({n} shards), merge job ${{merge}}\"\n"
    );
    Ok(SlurmScripts { array, merge, submit })
}

/// Writes the scripts of `options` to `out/slurm/` (creating it: Slurm writes the logs there).
/// Errors: those of [`scripts`], I/O.
pub fn write(options: &SlurmOptions) -> Result<SlurmFiles> {
    let s = scripts(options)?;
    let dir = folder(&options.out);
    std::fs::create_dir_all(&dir).map_err(|source| Error::Io { path: dir.clone(), source })?;
    let files = SlurmFiles {
        array: dir.join("array.sbatch"),
        merge: dir.join("merge.sbatch"),
        submit: dir.join("submit.sh"),
    };
    for (path, text) in [(&files.array, &s.array), (&files.merge, &s.merge), (&files.submit, &s.submit)] {
        std::fs::write(path, text).map_err(|source| Error::Io { path: path.clone(), source })?;
        make_executable(path)?;
    }
    Ok(files)
}

#[cfg(unix)]
fn make_executable(path: &Path) -> Result<()> {
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o755))
        .map_err(|source| Error::Io { path: path.to_path_buf(), source })
}

#[cfg(not(unix))]
fn make_executable(_: &Path) -> Result<()> {
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn options() -> SlurmOptions {
        let mut o = SlurmOptions::new("vdp-robust", "/opt/bin/onsager", "/scratch/vdp");
        o.shards = 40;
        o.cpus_per_task = 4;
        o.time = Some("02:00:00".into());
        o.partition = Some("short".into());
        o.replicates = Some(2000);
        o
    }

    #[test]
    fn the_array_runs_one_shard_per_task_and_the_merge_waits_for_it() {
        let s = scripts(&options()).unwrap();
        for line in [
            "#SBATCH --array=0-39",
            "#SBATCH --cpus-per-task=4",
            "#SBATCH --time=02:00:00",
            "#SBATCH --partition=short",
            "#SBATCH --output=/scratch/vdp/slurm/shard-%a.log",
            "#SBATCH --requeue",
            "exec /opt/bin/onsager experiment run vdp-robust --replicates 2000 --shard \"${SLURM_ARRAY_TASK_ID}/40\" \
             --resume --jobs \"${SLURM_CPUS_PER_TASK:-1}\" --out /scratch/vdp",
        ] {
            assert!(s.array.lines().any(|l| l == line), "{line}\n{}", s.array);
        }
        assert!(
            s.merge.lines().any(|l| l == "exec /opt/bin/onsager experiment merge /scratch/vdp"),
            "{}",
            s.merge
        );
        assert!(s.merge.lines().any(|l| l == "#SBATCH --cpus-per-task=1"));
        assert!(!s.merge.contains("--array"));
        assert!(s.submit.contains("--dependency=afterok:${array}"), "{}", s.submit);
        assert!(s.submit.contains("sbatch --parsable /scratch/vdp/slurm/array.sbatch"));
    }

    #[test]
    fn bad_options_name_their_flag() {
        type Change = fn(&mut SlurmOptions);
        let cases: Vec<(Change, &str)> = vec![
            (|o| o.shards = 0, "--shards"),
            (|o| o.cpus_per_task = 0, "--cpus-per-task"),
            (|o| o.time = Some("2h".into()), "--time"),
            (|o| o.time = Some("1-2:3:4:5".into()), "--time"),
            (|o| o.partition = Some("a b".into()), "--partition"),
            (|o| o.out = PathBuf::from("relative/out"), "--out"),
            (|o| o.out = PathBuf::from("/scratch/my run"), "--out"),
        ];
        for (change, flag) in cases {
            let mut o = options();
            change(&mut o);
            match scripts(&o) {
                Err(Error::InvalidOption { name, .. }) => assert_eq!(name, flag),
                other => panic!("{flag}: {other:?}"),
            }
        }
        for t in ["30", "30:00", "2:00:00", "1-0", "1-12:00", "1-12:00:00", "UNLIMITED"] {
            check_time(t).unwrap();
        }
    }
}
