//! Slurm batch scripts for sweeps: a pipeline of stages (a job array of training tasks, a job
//! array of evaluation shards, one merge), each stage a plain `cac` command line in which
//! `{task}` stands for the array index ([`script`]). A [`Sweep`] writes the scripts into
//! `OUT/slurm/` and submits them with `sbatch --array=... --dependency=afterok:...` (refusing while
//! a sweep into the same folder is queued or running); `cac slurm` builds the stages and prints.
//! Not a scheduler: the same commands run under any scheduler or by hand (docs/sweeps.md).

use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use std::process::Command;

/// `#SBATCH` settings shared by every stage; `cac slurm`'s flags.
#[derive(Clone, Debug)]
pub struct Batch {
    /// Slurm partition (default: the cluster's default).
    pub partition: Option<String>,
    /// Wall-time limit per task (sbatch --time, e.g. 2:00:00).
    pub time: Option<String>,
    /// CPUs per task (sbatch --cpus-per-task; also the task's thread count).
    pub cpus_per_task: usize,
    /// Memory per task (sbatch --mem, e.g. 4G).
    pub mem: Option<String>,
    /// Further #SBATCH option, verbatim (repeatable), e.g. --sbatch-arg=--account=lab.
    pub extra: Vec<String>,
}

impl Default for Batch {
    /// The cluster's default partition, time limit and memory; one CPU per task; no extra
    /// `#SBATCH` lines.
    fn default() -> Self {
        Batch {
            partition: None,
            time: None,
            cpus_per_task: 1,
            mem: None,
            extra: vec![],
        }
    }
}

/// One stage: a job array over `tasks` (or a single job when `None`) running `argv`, with
/// `{task}` in an argument replaced by the task's index.
#[derive(Clone, Debug)]
pub struct Stage {
    /// `train`, `eval`, `merge`: the script is `<name>.sbatch`, logs `<name>-<job>_<task>.log`.
    pub name: String,
    pub tasks: Option<usize>,
    pub argv: Vec<String>,
}

/// Quotes `s` for a POSIX shell (single quotes; a single quote inside becomes `'\''`), leaving
/// plain words as they are.
pub fn quote(s: &str) -> String {
    let plain = !s.is_empty()
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_./=:,+@%".contains(c));
    if plain {
        s.to_string()
    } else {
        format!("'{}'", s.replace('\'', r"'\''"))
    }
}

/// The `--array` value for `n` tasks: `0-(n-1)`.
pub fn array(n: usize) -> String {
    format!("0-{}", n.saturating_sub(1))
}

/// The batch script of `stage`. `job_name` names every job of one sweep (so a rerun can see
/// whether some are still queued), `workdir` is where the commands run, `log_dir` receives the
/// logs (appended to, so a requeued task's log keeps the killed run's lines).
pub fn script(
    stage: &Stage,
    job_name: &str,
    batch: &Batch,
    workdir: &std::path::Path,
    log_dir: &std::path::Path,
) -> String {
    let mut s = String::from("#!/bin/bash\n");
    let mut opt = |o: String| s.push_str(&format!("#SBATCH {o}\n"));
    opt(format!("--job-name={job_name}"));
    let log = match stage.tasks {
        Some(_) => format!("{}-%A_%a.log", stage.name),
        None => format!("{}-%j.log", stage.name),
    };
    opt(format!("--output={}", log_dir.join(log).display()));
    opt("--open-mode=append".into());
    // A task killed by a node failure or preemption is put back in the queue; it resumes from
    // what it had written (finished runs, checkpoints, shard files).
    opt("--requeue".into());
    opt(format!("--chdir={}", workdir.display()));
    opt(format!("--cpus-per-task={}", batch.cpus_per_task.max(1)));
    if let Some(p) = &batch.partition {
        opt(format!("--partition={p}"));
    }
    if let Some(t) = &batch.time {
        opt(format!("--time={t}"));
    }
    if let Some(m) = &batch.mem {
        opt(format!("--mem={m}"));
    }
    if stage.tasks.is_none() {
        // The merge waits for every task (afterok); when one of them fails or is cancelled the
        // merge can never run: Slurm removes it rather than leaving it pending forever.
        opt("--kill-on-invalid-dep=yes".into());
    }
    for e in &batch.extra {
        opt(e.clone());
    }
    s.push_str("set -euo pipefail\n");
    s.push_str("export RAYON_NUM_THREADS=\"${SLURM_CPUS_PER_TASK:-1}\"\n");
    s.push_str("echo \"cac ${SLURM_JOB_ID:-} task ${SLURM_ARRAY_TASK_ID:-} on $(hostname) (restart ${SLURM_RESTART_COUNT:-0})\"\n");
    let words: Vec<String> = stage
        .argv
        .iter()
        .map(|a| {
            if a.contains("{task}") {
                // Double quotes so that the variable expands; the rest is checked to be plain.
                format!("\"{}\"", a.replace("{task}", "${SLURM_ARRAY_TASK_ID}"))
            } else {
                quote(a)
            }
        })
        .collect();
    s.push_str(&format!("exec {}\n", words.join(" ")));
    s
}

/// `base` followed by `extra`.
pub fn with(base: &[String], extra: &[&str]) -> Vec<String> {
    base.iter()
        .cloned()
        .chain(extra.iter().map(|s| s.to_string()))
        .collect()
}

/// The evaluation `base` as an array of `shards` tasks, then the merge that waits for them.
pub fn shards_then_merge(base: &[String], shards: usize) -> Result<Vec<Stage>> {
    if shards == 0 {
        bail!("--shards must be at least 1");
    }
    Ok(vec![
        Stage {
            name: "eval".into(),
            tasks: Some(shards),
            argv: with(base, &["--shard", &format!("{{task}}/{shards}")]),
        },
        Stage {
            name: "merge".into(),
            tasks: None,
            argv: with(base, &["--merge"]),
        },
    ])
}

/// The name shared by every job of the sweep writing into `out`.
pub(crate) fn job_name(out: &Path) -> String {
    use sha2::{Digest, Sha256};
    let h = Sha256::digest(out.display().to_string().as_bytes());
    let tag: String = h.iter().take(4).map(|b| format!("{b:02x}")).collect();
    let base = out
        .file_name()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let base: String = base
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '-' })
        .take(24)
        .collect();
    format!("cac-{base}-{tag}")
}

/// The stages of a sweep into one output folder, with their scripts.
pub struct Sweep {
    /// The output folder (absolute) and its `slurm/` folder of scripts and logs.
    pub out: PathBuf,
    pub dir: PathBuf,
    pub stages: Vec<Stage>,
    /// Per stage: the script's path and text.
    pub scripts: Vec<(PathBuf, String)>,
    name: String,
}

impl Sweep {
    /// The scripts of `stages` for a sweep into `out` (relative to the current folder).
    pub fn new(out: &Path, stages: Vec<Stage>, batch: &Batch) -> Result<Sweep> {
        let cwd = std::env::current_dir().context("no current folder")?;
        let out = if out.is_absolute() {
            out.to_path_buf()
        } else {
            cwd.join(out)
        };
        let dir = out.join("slurm");
        let name = job_name(&out);
        let scripts = stages
            .iter()
            .map(|s| {
                (
                    dir.join(format!("{}.sbatch", s.name)),
                    script(s, &name, batch, &cwd, &dir),
                )
            })
            .collect();
        Ok(Sweep {
            out,
            dir,
            stages,
            scripts,
            name,
        })
    }

    /// The sbatch arguments of stage `k`, after the job `prev`.
    pub fn command(&self, k: usize, prev: Option<&str>) -> Vec<String> {
        let s = &self.stages[k];
        let mut c = vec!["--parsable".to_string()];
        if let Some(n) = s.tasks {
            c.push(format!("--array={}", array(n)));
        }
        if let Some(p) = prev {
            c.push(format!("--dependency=afterok:{p}"));
        }
        c.push(self.scripts[k].0.display().to_string());
        c
    }

    /// What `--dry-run` prints: each script, then the sbatch command that would submit it (the
    /// previous stage's job id as a shell variable).
    pub fn dry_run(&self) -> String {
        let mut text = String::new();
        let mut prev: Option<String> = None;
        for (k, s) in self.stages.iter().enumerate() {
            let (path, script) = &self.scripts[k];
            let c = self.command(k, prev.as_deref()).join(" ");
            text += &format!("# {}\n{script}\n# submit: sbatch {c}\n\n", path.display());
            prev = Some(format!("${}_JOB", s.name.to_uppercase()));
        }
        text + "(dry run: nothing written, nothing submitted)\n"
    }

    /// Writes the scripts and submits the stages in order, each after the previous; returns the
    /// job ids. Refuses while jobs of a sweep into the same folder are queued or running.
    pub fn submit(&self) -> Result<Vec<String>> {
        if let Ok(o) = Command::new("squeue")
            .args(["-h", "-n", &self.name, "-o", "%i %T"])
            .output()
        {
            let active = String::from_utf8_lossy(&o.stdout).trim().to_string();
            if o.status.success() && !active.is_empty() {
                bail!(
                    "jobs of a sweep into {} are still queued or running ({}): wait for them or scancel them, then rerun",
                    self.out.display(),
                    active.replace('\n', ", ")
                );
            }
        }
        for (path, text) in &self.scripts {
            cac_core::io::write_atomic(path, text.as_bytes())?;
        }
        let mut ids: Vec<String> = vec![];
        for k in 0..self.stages.len() {
            let id = sbatch(&self.command(k, ids.last().map(String::as_str)))?;
            ids.push(id);
        }
        Ok(ids)
    }
}

fn sbatch(args: &[String]) -> Result<String> {
    let o = Command::new("sbatch")
        .args(args)
        .output()
        .context("cannot run sbatch (is Slurm installed and on PATH?)")?;
    if !o.status.success() {
        bail!(
            "sbatch {} failed: {}",
            args.join(" "),
            String::from_utf8_lossy(&o.stderr).trim()
        );
    }
    let id = String::from_utf8_lossy(&o.stdout).trim().to_string();
    // --parsable prints "ID" or "ID;CLUSTER".
    Ok(id.split(';').next().unwrap_or_default().to_string())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    #[test]
    fn scripts_quote_arguments_and_index_the_array() {
        assert_eq!(quote("fv,rv"), "fv,rv");
        assert_eq!(quote("stop sign"), "'stop sign'");
        assert_eq!(quote("it's"), r"'it'\''s'");
        assert_eq!(quote(""), "''");
        assert_eq!(array(1), "0-0");
        assert_eq!(array(4), "0-3");
        let st = Stage {
            name: "eval".into(),
            tasks: Some(3),
            argv: vec![
                "/bin/cac".into(),
                "eval".into(),
                "--target".into(),
                "stop sign".into(),
                "--shard".into(),
                "{task}/3".into(),
            ],
        };
        let b = Batch {
            partition: Some("gpu".into()),
            cpus_per_task: 2,
            time: None,
            mem: None,
            extra: vec!["--account=lab".into()],
        };
        let s = script(&st, "cac-x", &b, Path::new("/w"), Path::new("/w/out/slurm"));
        for want in [
            "#SBATCH --job-name=cac-x\n",
            "#SBATCH --output=/w/out/slurm/eval-%A_%a.log\n",
            "#SBATCH --requeue\n",
            "#SBATCH --partition=gpu\n",
            "#SBATCH --cpus-per-task=2\n",
            "#SBATCH --account=lab\n",
            "exec /bin/cac eval --target 'stop sign' --shard \"${SLURM_ARRAY_TASK_ID}/3\"\n",
        ] {
            assert!(s.contains(want), "{want:?} not in\n{s}");
        }
        assert!(!s.contains("kill-on-invalid-dep"), "only the merge");
        let m = Stage {
            name: "merge".into(),
            tasks: None,
            argv: vec!["cac".into(), "eval".into(), "--merge".into()],
        };
        let s = script(&m, "cac-x", &b, Path::new("/w"), Path::new("/l"));
        assert!(s.contains("--output=/l/merge-%j.log") && s.contains("--kill-on-invalid-dep=yes"));
    }

    #[test]
    fn a_dry_run_chains_each_stage_after_the_previous() {
        let base: Vec<String> = ["cac", "eval"].map(String::from).to_vec();
        let stages = shards_then_merge(&base, 2).unwrap();
        let b = Batch {
            partition: None,
            time: None,
            cpus_per_task: 1,
            mem: None,
            extra: vec![],
        };
        let sweep = Sweep::new(Path::new("/w/out"), stages, &b).unwrap();
        let text = sweep.dry_run();
        let shard = text.find("# submit: sbatch --parsable --array=0-1 /w/out/slurm/");
        let merge = text.find("--dependency=afterok:$");
        assert!(
            shard.is_some() && merge.is_some() && shard < merge,
            "{text}"
        );
        assert!(text.contains("#SBATCH --kill-on-invalid-dep=yes"), "{text}");
        assert!(text.ends_with("(dry run: nothing written, nothing submitted)\n"));
    }
}
