//! `cac slurm eval|study topn [OPTIONS] -- ARGS`: runs a `cac eval` (or `cac study topn`) with
//! ARGS on a Slurm cluster: writes job-array scripts into OUT/slurm/ and submits them with
//! sbatch, each stage depending on the previous one (`--dependency=afterok`): the study's
//! trainings (one task per setting), the evaluation shards (one task per shard), the merge that
//! writes the report. `--dry-run` prints the scripts and the sbatch commands instead. Rerunning
//! the same command after a task was killed resubmits the sweep; finished parts are skipped
//! (finished runs, shard files), a killed task resumes from what it had written.

use super::{eval, study};
use anyhow::{bail, Context, Result};
use cac::eval::slurm::{self, Batch, Stage};
use clap::Parser;
use std::path::{Path, PathBuf};
use std::process::Command;

#[derive(clap::Subcommand, Debug)]
pub enum Cmd {
    /// A sharded `cac eval`: N shard tasks, then the merge.
    Eval(Args),
    /// A study as a sweep: one training task per setting, the evaluation's shards, the merge.
    #[command(subcommand)]
    Study(StudyCmd),
}

#[derive(clap::Subcommand, Debug)]
pub enum StudyCmd {
    /// `cac study topn`: one task per value of n.
    Topn(Args),
}

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Evaluation shards (array tasks).
    #[arg(long, default_value_t = 4)]
    pub shards: usize,
    /// Slurm partition (default: the cluster's default).
    #[arg(long)]
    pub partition: Option<String>,
    /// Wall-time limit per task (sbatch --time, e.g. 2:00:00).
    #[arg(long)]
    pub time: Option<String>,
    /// CPUs per task (sbatch --cpus-per-task; also the task's thread count).
    #[arg(long, default_value_t = 1)]
    pub cpus_per_task: usize,
    /// Memory per task (sbatch --mem, e.g. 4G).
    #[arg(long)]
    pub mem: Option<String>,
    /// Further #SBATCH option, verbatim (repeatable), e.g. --sbatch-arg=--account=lab.
    #[arg(long = "sbatch-arg", allow_hyphen_values = true)]
    pub sbatch_args: Vec<String>,
    /// Print the scripts and the sbatch commands; write and submit nothing.
    #[arg(long)]
    pub dry_run: bool,
    /// The arguments of `cac eval` / `cac study topn` (after `--`).
    #[arg(last = true)]
    pub args: Vec<String>,
}

#[derive(Parser)]
#[command(name = "cac eval")]
struct EvalLine {
    #[command(flatten)]
    a: eval::Args,
}

#[derive(Parser)]
#[command(name = "cac study topn")]
struct TopnLine {
    #[command(flatten)]
    a: study::TopnArgs,
}

pub fn run(c: Cmd) -> Result<()> {
    let exe = std::env::current_exe().context("cannot find the cac binary")?;
    let exe = exe.display().to_string();
    match c {
        Cmd::Eval(a) => {
            let line = EvalLine::try_parse_from(
                std::iter::once("cac eval".to_string()).chain(a.args.iter().cloned()),
            )
            .map_err(|e| anyhow::anyhow!("the cac eval arguments after --: {e}"))?;
            if line.a.shard.is_some() || line.a.merge {
                bail!("leave --shard and --merge to cac slurm: pass the plain cac eval arguments after --");
            }
            let shards = shards(a.shards)?;
            let base: Vec<String> = [exe, "eval".into()]
                .into_iter()
                .chain(a.args.iter().cloned())
                .collect();
            submit(&a, &line.a.out, &shards_then_merge(&base, shards))
        }
        Cmd::Study(StudyCmd::Topn(a)) => {
            let line = TopnLine::try_parse_from(
                std::iter::once("cac study topn".to_string()).chain(a.args.iter().cloned()),
            )
            .map_err(|e| anyhow::anyhow!("the cac study topn arguments after --: {e}"))?;
            if line.a.task.is_some() || line.a.shard.is_some() || line.a.merge {
                bail!("leave --task, --shard and --merge to cac slurm: pass the plain cac study topn arguments after --");
            }
            let shards = shards(a.shards)?;
            let base: Vec<String> = [exe, "study".into(), "topn".into()]
                .into_iter()
                .chain(a.args.iter().cloned())
                .collect();
            let mut stages = vec![Stage {
                name: "train".into(),
                tasks: Some(line.a.n.len()),
                argv: with(&base, &["--task", "{task}"]),
            }];
            stages.extend(shards_then_merge(&base, shards));
            submit(&a, &line.a.out, &stages)
        }
    }
}

/// The evaluation as an array of `shards` tasks, then the merge that waits for them.
fn shards_then_merge(base: &[String], shards: usize) -> Vec<Stage> {
    vec![
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
    ]
}

fn shards(n: usize) -> Result<usize> {
    if n == 0 {
        bail!("--shards must be at least 1");
    }
    Ok(n)
}

fn with(base: &[String], extra: &[&str]) -> Vec<String> {
    base.iter()
        .cloned()
        .chain(extra.iter().map(|s| s.to_string()))
        .collect()
}

/// The name shared by every job of the sweep writing into `out`.
fn job_name(out: &Path) -> String {
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

fn submit(a: &Args, out: &Path, stages: &[Stage]) -> Result<()> {
    let cwd = std::env::current_dir().context("no current folder")?;
    let out_abs: PathBuf = if out.is_absolute() {
        out.to_path_buf()
    } else {
        cwd.join(out)
    };
    let dir = out_abs.join("slurm");
    let name = job_name(&out_abs);
    let batch = Batch {
        partition: a.partition.clone(),
        time: a.time.clone(),
        cpus_per_task: a.cpus_per_task,
        mem: a.mem.clone(),
        extra: a.sbatch_args.clone(),
    };
    let scripts: Vec<(PathBuf, String)> = stages
        .iter()
        .map(|s| {
            (
                dir.join(format!("{}.sbatch", s.name)),
                slurm::script(s, &name, &batch, &cwd, &dir),
            )
        })
        .collect();
    let command = |s: &Stage, path: &Path, prev: Option<&str>| -> Vec<String> {
        let mut c = vec!["--parsable".to_string()];
        if let Some(n) = s.tasks {
            c.push(format!("--array={}", slurm::array(n)));
        }
        if let Some(p) = prev {
            c.push(format!("--dependency=afterok:{p}"));
        }
        c.push(path.display().to_string());
        c
    };
    if a.dry_run {
        let mut prev: Option<String> = None;
        for (s, (path, text)) in stages.iter().zip(&scripts) {
            println!("# {}\n{text}", path.display());
            let c = command(s, path, prev.as_deref());
            println!("# submit: sbatch {}\n", c.join(" "));
            prev = Some(format!("${}_JOB", s.name.to_uppercase()));
        }
        println!("(dry run: nothing written, nothing submitted)");
        return Ok(());
    }
    // A sweep still queued or running for this folder would race with a second submission.
    if let Ok(o) = Command::new("squeue")
        .args(["-h", "-n", &name, "-o", "%i %T"])
        .output()
    {
        let active = String::from_utf8_lossy(&o.stdout).trim().to_string();
        if o.status.success() && !active.is_empty() {
            bail!(
                "jobs of a sweep into {} are still queued or running ({}): wait for them or scancel them, then rerun",
                out_abs.display(),
                active.replace('\n', ", ")
            );
        }
    }
    for (path, text) in &scripts {
        cac::io::write_atomic(path, text.as_bytes())?;
    }
    let mut prev: Option<String> = None;
    for (s, (path, _)) in stages.iter().zip(&scripts) {
        let id = sbatch(&command(s, path, prev.as_deref()))?;
        match s.tasks {
            Some(n) => println!("{}: job {id}, array of {n} task(s)", s.name),
            None => println!("{}: job {id}", s.name),
        }
        prev = Some(id);
    }
    println!(
        "submitted; logs in {}; the report is written into {} by the last job",
        dir.display(),
        out_abs.display()
    );
    Ok(())
}
