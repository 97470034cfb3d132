//! `cac slurm eval|study topn [OPTIONS] -- ARGS`: runs a `cac eval` (or `cac study topn`) with
//! ARGS on a Slurm cluster: writes job-array scripts into OUT/slurm/ and submits them with
//! sbatch, each stage depending on the previous one (`--dependency=afterok`): the study's
//! trainings (one task per setting), the evaluation shards (one task per shard), the merge that
//! writes the report. `--dry-run` prints the scripts and the sbatch commands instead. Rerunning
//! the same command after a task was killed resubmits the sweep; finished parts are skipped
//! (finished runs, shard files), a killed task resumes from what it had written. Parse → stages →
//! `cac::eval::slurm::Sweep` → print.

use super::{eval, study};
use anyhow::{bail, Context, Result};
use cac::eval::slurm::{shards_then_merge, with, Batch, Stage, Sweep};
use clap::Parser;
use std::path::Path;

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
    #[command(flatten)]
    pub batch: super::flags::eval::BatchFlags,
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

/// Parses the command line after `--` as `cac NAME` would.
fn parse<P: Parser>(name: &str, args: &[String]) -> Result<P> {
    P::try_parse_from(std::iter::once(name.to_string()).chain(args.iter().cloned()))
        .map_err(|e| anyhow::anyhow!("the {name} arguments after --: {e}"))
}

pub fn run(c: Cmd) -> Result<()> {
    let exe = std::env::current_exe().context("cannot find the cac binary")?;
    let exe = exe.display().to_string();
    match c {
        Cmd::Eval(a) => {
            let line: EvalLine = parse("cac eval", &a.args)?;
            if line.a.shard.is_some() || line.a.merge {
                bail!("leave --shard and --merge to cac slurm: pass the plain cac eval arguments after --");
            }
            let base: Vec<String> = [exe, "eval".into()]
                .into_iter()
                .chain(a.args.iter().cloned())
                .collect();
            submit(&a, &line.a.out, shards_then_merge(&base, a.shards)?)
        }
        Cmd::Study(StudyCmd::Topn(a)) => {
            let line: TopnLine = parse("cac study topn", &a.args)?;
            if line.a.task.is_some() || line.a.shard.is_some() || line.a.merge {
                bail!("leave --task, --shard and --merge to cac slurm: pass the plain cac study topn arguments after --");
            }
            let base: Vec<String> = [exe, "study".into(), "topn".into()]
                .into_iter()
                .chain(a.args.iter().cloned())
                .collect();
            let mut stages = vec![Stage {
                name: "train".into(),
                tasks: Some(line.a.job.n.len()),
                argv: with(&base, &["--task", "{task}"]),
            }];
            stages.extend(shards_then_merge(&base, a.shards)?);
            submit(&a, &line.a.job.out, stages)
        }
    }
}

fn submit(a: &Args, out: &Path, stages: Vec<Stage>) -> Result<()> {
    let sweep = Sweep::new(out, stages, &Batch::from(a.batch.clone()))?;
    if a.dry_run {
        print!("{}", sweep.dry_run());
        return Ok(());
    }
    for (s, id) in sweep.stages.iter().zip(sweep.submit()?) {
        match s.tasks {
            Some(n) => println!("{}: job {id}, array of {n} task(s)", s.name),
            None => println!("{}: job {id}", s.name),
        }
    }
    println!(
        "submitted; logs in {}; the report is written into {} by the last job",
        sweep.dir.display(),
        sweep.out.display()
    );
    Ok(())
}
