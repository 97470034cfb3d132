//! Sharded evaluation through the binary: `cac eval --shard K/N` for every K, then `--merge`,
//! gives the report of a single process (records.csv, results.json apart from timing, the CSV
//! tables, report.html, plots), for N = 1, 2 and 3; the merge reads the shards' records and
//! renders nothing; bad input (shard out of range, shard missing, duplicated, split in two ways,
//! written with other settings) is a clear error naming the file, and nothing is overwritten.

mod support;

use std::path::{Path, PathBuf};

/// A tiny evaluation: the barrel at 96², FV and RV, 2 views per level (8 views), two textures.
fn args(dir: &Path, out: &Path, views: usize) -> Vec<String> {
    let cfg = dir.join("barrel.toml");
    std::fs::write(
        &cfg,
        "[object]\nmesh = \"barrel\"\n[render]\nwidth = 96\nheight = 96\nsamples = 1\n\
         atlas_res = 32\n[environment]\ndistance_ratio = [1.5, 3.0]\n",
    )
    .unwrap();
    [
        "eval",
        "--config",
        cfg.to_str().unwrap(),
        "--views",
        &views.to_string(),
        "--sets",
        "fv,rv",
        "--texture",
        "original,random",
        "--models",
        "nanodet",
        "--true-classes",
        "car,truck",
        "--target",
        "person",
        "--out",
        out.to_str().unwrap(),
    ]
    .map(String::from)
    .to_vec()
}

fn run(args: &[String], extra: &[&str]) -> std::process::Output {
    let mut a: Vec<&str> = args.iter().map(String::as_str).collect();
    a.extend(extra);
    support::cac(&a)
}

fn ok(args: &[String], extra: &[&str]) -> String {
    support::ok_text(&format!("{args:?} {extra:?}"), &run(args, extra))
}

fn fails(args: &[String], extra: &[&str]) -> String {
    let o = run(args, extra);
    assert!(!o.status.success(), "cac {extra:?} should fail");
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// results.json without its timing field.
fn results(out: &Path) -> serde_json::Value {
    let mut v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("results.json")).unwrap()).unwrap();
    v["info"].as_object_mut().unwrap().remove("seconds");
    v
}

fn read(p: PathBuf) -> Vec<u8> {
    std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

#[test]
fn merged_shards_equal_the_single_process_report_for_1_2_and_3_shards() {
    let dir = tempfile::tempdir().unwrap();
    let single = dir.path().join("single");
    ok(&args(dir.path(), &single, 2), &[]);
    let want = results(&single);
    assert_eq!(
        want["records"].as_array().unwrap().len(),
        16,
        "8 views x 2 textures"
    );
    for n in 1..=3usize {
        let out = dir.path().join(format!("n{n}"));
        let a = args(dir.path(), &out, 2);
        for k in 0..n {
            let text = ok(&a, &["--shard", &format!("{k}/{n}")]);
            assert!(text.contains(&format!("shard {k}/{n} finished")), "{text}");
            assert!(
                !out.join("results.json").exists(),
                "a shard writes no report"
            );
        }
        let text = ok(&a, &["--merge"]);
        assert!(
            text.contains(&format!("Original: assembled from {n} shard(s)")),
            "{text}"
        );
        assert_eq!(
            read(single.join("records.csv")),
            read(out.join("records.csv")),
            "records.csv, N = {n}"
        );
        assert_eq!(results(&out), want, "results.json, N = {n}");
        for f in [
            "summary.csv",
            "breakdown.csv",
            "p05_fv.csv",
            "p05_rv_fv.csv",
            "targeted_rv.csv",
            "report.html",
            "plot_distance_ratio_nanodet.png",
        ] {
            assert_eq!(read(single.join(f)), read(out.join(f)), "{f}, N = {n}");
        }
    }

    // The merge reads the shards' records: a record changed in a shard file shows up in the
    // report (nothing is rendered again).
    let out = dir.path().join("tampered");
    let a = args(dir.path(), &out, 2);
    for k in 0..2 {
        ok(&a, &["--shard", &format!("{k}/2")]);
    }
    let f = out.join("cache/Random.shard-1-of-2.json");
    let mut v: serde_json::Value = serde_json::from_slice(&read(f.clone())).unwrap();
    let conf = v["records"][0]["best_true_conf"].as_f64().unwrap();
    v["records"][0]["best_true_conf"] = serde_json::json!(0.123456);
    std::fs::write(&f, serde_json::to_vec(&v).unwrap()).unwrap();
    ok(&a, &["--merge"]);
    let got = results(&out);
    let changed: Vec<&serde_json::Value> = got["records"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|r| (r["best_true_conf"].as_f64().unwrap() - 0.123456).abs() < 1e-6)
        .collect();
    assert_eq!(
        changed.len(),
        1,
        "the edited record (was {conf}) is in the report"
    );
    assert_eq!(changed[0]["texture"], "Random");
}

#[test]
fn bad_shard_input_is_refused_naming_the_file_and_nothing_is_overwritten() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let a = args(dir.path(), &out, 2);

    let e = fails(&a, &["--shard", "3/3"]);
    assert!(
        e.contains("shard 3/3 is out of range") && e.contains("0 to 2"),
        "{e}"
    );
    let e = fails(&a, &["--shard", "1/0"]);
    assert!(e.contains("at least 1"), "{e}");
    assert!(!out.exists(), "a refused shard writes nothing");
    let e = fails(&a, &["--merge"]);
    assert!(e.contains("no shard of texture \"Original\""), "{e}");
    assert!(!out.join("results.json").exists());

    // A finished report from other settings is in the folder; failed merges leave it as it was.
    ok(&args(dir.path(), &out, 1), &[]);
    let before: Vec<(PathBuf, Vec<u8>)> = ["records.csv", "results.json", "report.html"]
        .iter()
        .map(|f| (out.join(f), read(out.join(f))))
        .collect();
    let unchanged = || {
        for (p, b) in &before {
            assert_eq!(&read(p.clone()), b, "{} was overwritten", p.display());
        }
    };

    // Shard 1 of 3 missing.
    ok(&a, &["--shard", "0/3"]);
    ok(&a, &["--shard", "2/3"]);
    let e = fails(&a, &["--merge"]);
    assert!(
        e.contains("shard 1/3")
            && e.contains("Original.shard-1-of-3.json")
            && e.contains("missing"),
        "{e}"
    );
    assert!(e.contains("nothing was written"), "{e}");
    unchanged();

    // Shard 0 of 3 twice (a copy under another name).
    ok(&a, &["--shard", "1/3"]);
    let cache = out.join("cache");
    std::fs::copy(
        cache.join("Original.shard-0-of-3.json"),
        cache.join("Original.shard-0-of-3.copy.json"),
    )
    .unwrap();
    let e = fails(&a, &["--merge"]);
    assert!(
        e.contains("shard 0/3 of texture \"Original\" is present twice")
            && e.contains("Original.shard-0-of-3.copy.json"),
        "{e}"
    );
    unchanged();
    std::fs::remove_file(cache.join("Original.shard-0-of-3.copy.json")).unwrap();

    // A shard of another split (0 of 2) next to the split in 3.
    ok(&a, &["--shard", "0/2"]);
    let e = fails(&a, &["--merge"]);
    assert!(e.contains("split in different ways"), "{e}");
    assert!(e.contains("of 2") && e.contains("of 3"), "{e}");
    unchanged();
    for t in ["Original", "Random"] {
        std::fs::remove_file(cache.join(format!("{t}.shard-0-of-2.json"))).unwrap();
    }

    // Shard 1 rerun with other settings (3 views per level): its cache key differs.
    ok(&args(dir.path(), &out, 3), &["--shard", "1/3"]);
    let e = fails(&a, &["--merge"]);
    assert!(
        e.contains("Original.shard-1-of-3.json") && e.contains("other settings"),
        "{e}"
    );
    unchanged();

    // Shard 1 redone with the right settings replaces its stale files, the merge succeeds, and
    // a rerun of a finished shard does nothing.
    let text = ok(&a, &["--shard", "1/3"]);
    assert!(text.contains("shard 1/3: Random ->"), "{text}");
    let text = ok(&a, &["--shard", "1/3"]);
    assert!(text.contains("already done: Original, Random"), "{text}");
    ok(&a, &["--merge"]);
    assert_eq!(results(&out)["records"].as_array().unwrap().len(), 16);
}
