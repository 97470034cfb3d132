//! A real single-node Slurm cluster (Debian's slurm-wlm and munge, started by `.ci/slurm-up`):
//! `cac slurm eval` runs a small evaluation as a job array of shards and a dependent merge, with
//! one task killed by `scancel` mid-way and the sweep resubmitted (the killed shard resumes after
//! its finished texture), and writes the report of a single process; `cac slurm study topn`
//! trains a two-setting top-n study as an array, evaluates it in shards and merges it, giving the
//! figures a single process computes from the same runs. Without Slurm the tests skip with a note
//! (and fail under `CI=true`, as when it is installed but does not start).

mod support;

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

fn sh(program: &str, args: &[&str]) -> (bool, String) {
    match Command::new(program).args(args).output() {
        Ok(o) => (
            o.status.success(),
            format!(
                "{}{}",
                String::from_utf8_lossy(&o.stdout),
                String::from_utf8_lossy(&o.stderr)
            ),
        ),
        Err(e) => (false, e.to_string()),
    }
}

fn node_up() -> bool {
    let (ok, text) = sh("sinfo", &["-h", "-o", "%t"]);
    ok && ["idle", "mix", "alloc"].iter().any(|s| text.contains(s))
}

/// Is a Slurm cluster answering? Starts one with `.ci/slurm-up` when Slurm is installed but not
/// running. Missing: a skip note here, a failure under CI.
fn cluster() -> bool {
    if !support::require(
        "sbatch",
        &["--version"],
        "Slurm (Debian's slurm-wlm and munge)",
    ) {
        return false;
    }
    // The tests of this file run in parallel: one of them starts the cluster, the others wait
    // (two concurrent starts race for munged's socket lock).
    static START: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _one = START.lock().unwrap_or_else(|e| e.into_inner());
    if !node_up() {
        let (ok, text) = sh(support::root().join(".ci/slurm-up").to_str().unwrap(), &[]);
        if !ok || !node_up() {
            support::missing(
                "a running Slurm cluster",
                &format!("slurm-wlm is installed but .ci/slurm-up did not start it:\n{text}"),
            );
            return false;
        }
    }
    true
}

/// The job ids `cac slurm` printed, by stage (`eval: job 12, ...`).
fn job_id(text: &str, stage: &str) -> String {
    text.lines()
        .find_map(|l| l.strip_prefix(&format!("{stage}: job ")))
        .map(|r| r.split([',', ' ']).next().unwrap().to_string())
        .unwrap_or_else(|| panic!("no {stage} job in\n{text}"))
}

/// Waits until none of `ids` is queued or running.
fn wait_for(ids: &[String], logs: &Path) {
    let start = Instant::now();
    loop {
        let (_, q) = sh("squeue", &["-h", "-j", &ids.join(","), "-o", "%i %T %r"]);
        if q.trim().is_empty() || q.contains("Invalid job id") {
            return;
        }
        if start.elapsed() > Duration::from_secs(600) {
            let mut logs_text = String::new();
            for e in std::fs::read_dir(logs).into_iter().flatten().flatten() {
                logs_text += &std::fs::read_to_string(e.path()).unwrap_or_default();
            }
            panic!("Slurm jobs still queued after 10 minutes:\n{q}\nlogs:\n{logs_text}");
        }
        std::thread::sleep(Duration::from_millis(500));
    }
}

fn log(dir: &Path, prefix: &str) -> String {
    let mut out = String::new();
    let mut names: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.file_name().unwrap().to_string_lossy().starts_with(prefix))
        .collect();
    names.sort();
    for p in names {
        out += &format!("== {}\n", p.display());
        out += &std::fs::read_to_string(p).unwrap();
    }
    out
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap().flatten() {
        if e.path().is_dir() {
            copy_dir(&e.path(), &to.join(e.file_name()));
        } else {
            std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
        }
    }
}

fn results(out: &Path) -> serde_json::Value {
    let mut v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("results.json")).unwrap()).unwrap();
    v["info"].as_object_mut().unwrap().remove("seconds");
    v
}

fn config(dir: &Path, mesh: &str) -> String {
    let cfg = dir.join(format!("{mesh}.toml"));
    std::fs::write(
        &cfg,
        format!(
            "[object]\nmesh = \"{mesh}\"\n[render]\nwidth = 96\nheight = 96\nsamples = 1\n\
             atlas_res = 32\n[environment]\ndistance_ratio = [1.5, 3.0]\n"
        ),
    )
    .unwrap();
    cfg.to_str().unwrap().to_string()
}

#[test]
fn slurm_eval_with_a_killed_and_resubmitted_shard_equals_one_process() {
    if !cluster() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let cfg = config(dir.path(), "barrel");
    let out = dir.path().join("sharded");
    let single = dir.path().join("single");
    let base = [
        "--config",
        &cfg,
        "--views",
        "8",
        "--sets",
        "fv,rv",
        "--texture",
        "original,random",
        "--models",
        "nanodet",
    ];
    let with_out = |o: &Path| -> Vec<String> {
        base.iter()
            .map(|s| s.to_string())
            .chain(["--out".into(), o.to_str().unwrap().into()])
            .collect()
    };
    let sharded = with_out(&out);
    let submit: Vec<&str> = ["slurm", "eval", "--shards", "2", "--"]
        .into_iter()
        .chain(sharded.iter().map(String::as_str))
        .collect();

    // The dry run prints the array and the dependent merge and writes nothing.
    let mut dry = submit.clone();
    dry.insert(4, "--dry-run");
    let text = support::cac_ok(&dry);
    assert!(
        text.contains("sbatch --parsable --array=0-1 ")
            && text.contains("--dependency=afterok:$EVAL_JOB")
            && text.contains("--shard \"${SLURM_ARRAY_TASK_ID}/2\"")
            && text.contains(" --merge\n"),
        "{text}"
    );
    assert!(!out.exists(), "a dry run writes nothing");

    let text = support::cac_ok(&submit);
    let (array, merge) = (job_id(&text, "eval"), job_id(&text, "merge"));
    // Kill shard 0 once its first texture is written, before its second.
    let first = out.join("cache/Original.shard-0-of-2.json");
    let start = Instant::now();
    while !first.exists() {
        assert!(
            start.elapsed() < Duration::from_secs(300),
            "shard 0 never wrote {}:\n{}",
            first.display(),
            log(&out.join("slurm"), "eval")
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    let (ok, t) = sh("scancel", &[&format!("{array}_0")]);
    assert!(ok, "scancel: {t}");
    let killed_early = !out.join("cache/Random.shard-0-of-2.json").exists();
    // The other shard finishes; the merge, whose dependency can no longer be met, is removed.
    wait_for(&[array.clone(), merge.clone()], &out.join("slurm"));
    let logs = log(&out.join("slurm"), "eval");
    assert!(logs.contains("CANCELLED"), "{logs}");
    assert!(
        !out.join("results.json").exists(),
        "no report without shard 0"
    );

    // The single-process reference meanwhile.
    support::cac_ok(
        &["eval"]
            .into_iter()
            .chain(with_out(&single).iter().map(String::as_str))
            .collect::<Vec<_>>(),
    );

    // Resubmitted: shard 0 resumes after Original, shard 1 has nothing left, the merge writes
    // the report.
    let text = support::cac_ok(&submit);
    let (array2, merge2) = (job_id(&text, "eval"), job_id(&text, "merge"));
    wait_for(&[array2.clone(), merge2.clone()], &out.join("slurm"));
    let logs = log(&out.join("slurm"), &format!("eval-{array2}_"));
    assert!(logs.contains("shard 0/2: already done: Original"), "{logs}");
    if killed_early {
        assert!(logs.contains("shard 0/2: Random ->"), "{logs}");
    }
    assert!(
        logs.contains("shard 1/2: already done: Original, Random"),
        "{logs}"
    );
    let mlog = log(&out.join("slurm"), &format!("merge-{merge2}"));
    assert!(mlog.contains("Random: assembled from 2 shard(s)"), "{mlog}");
    assert_eq!(
        std::fs::read(single.join("records.csv")).unwrap(),
        std::fs::read(out.join("records.csv")).unwrap(),
        "records.csv"
    );
    assert_eq!(results(&single), results(&out), "results.json");
}

#[test]
fn slurm_two_setting_topn_study_trains_as_an_array_and_merges_to_one_process() {
    if !cluster() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let cfg = config(dir.path(), "pickup");
    let out = dir.path().join("study");
    let args = |o: &Path| -> Vec<String> {
        [
            "--config",
            &cfg,
            "--n",
            "5,10",
            "--iterations",
            "2",
            "--batch",
            "1",
            "--views",
            "2",
            "--sets",
            "fv,rv",
            "--models",
            "nanodet",
            "--eval-models",
            "nanodet",
            "--out",
            o.to_str().unwrap(),
        ]
        .map(String::from)
        .to_vec()
    };
    let a = args(&out);
    let submit: Vec<&str> = ["slurm", "study", "topn", "--shards", "3", "--"]
        .into_iter()
        .chain(a.iter().map(String::as_str))
        .collect();
    let text = support::cac_ok(&submit);
    let ids = ["train", "eval", "merge"]
        .map(|s| job_id(&text, s))
        .to_vec();
    wait_for(&ids, &out.join("slurm"));
    let logs = log(&out.join("slurm"), "");
    for n in ["n5", "n10"] {
        assert!(out.join(n).join("atlas.png").exists(), "{n}:\n{logs}");
    }
    for k in 0..3 {
        assert!(logs.contains(&format!("shard {k}/3 finished")), "{logs}");
    }
    assert!(out.join("topn.csv").exists(), "no study written:\n{logs}");

    // One process from the same trained runs (copied; finished runs are reused, not retrained):
    // the same records and the same top-n table.
    let single = dir.path().join("single");
    for n in ["n5", "n10"] {
        copy_dir(&out.join(n), &single.join(n));
    }
    let s = args(&single);
    let text = support::cac_ok(
        &["study", "topn"]
            .into_iter()
            .chain(s.iter().map(String::as_str))
            .collect::<Vec<_>>(),
    );
    assert!(text.contains("n = 10: reusing the finished run"), "{text}");
    assert_eq!(
        std::fs::read(single.join("eval/records.csv")).unwrap(),
        std::fs::read(out.join("eval/records.csv")).unwrap()
    );
    assert_eq!(results(&single.join("eval")), results(&out.join("eval")));
    assert_eq!(
        std::fs::read_to_string(single.join("topn.csv")).unwrap(),
        std::fs::read_to_string(out.join("topn.csv")).unwrap()
    );
    // A task out of range is refused.
    let o = support::cac(&["study", "topn", "--n", "5,10", "--task", "2"]);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && e.contains("--task 2 is out of range"),
        "{e}"
    );
}
