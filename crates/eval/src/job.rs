//! One whole evaluation: resolve the textures, draw the views, score every texture with every
//! model (reusing finished textures from the cache folder), and write the report into the output
//! folder (`report.md`, `report.html`, tables as CSV, `results.json`, plots).
//!
//! The same job can be split: [`run_shard`] evaluates one shard's views and only writes its cache
//! files, [`merge`] writes the report from those files without rendering (see [`super::shard`]).

use super::report::{self, EvalInfo};
use super::run::{all_views, evaluate_texture_in, view_groups, TextureResult, ViewGroup, ViewPlan};
use super::shard::{self, Shard};
use super::{cache, textures, Protocol};
use anyhow::Result;
use burn::tensor::Device;
use cac_detect::Detector;
use cac_render::config::SceneConfig;
use cac_render::environment::Environment;
use cac_render::Renderer;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Everything an evaluation needs besides the detectors.
#[derive(Clone, Debug)]
pub struct EvalJob {
    pub scene: SceneConfig,
    /// Texture specs (see [`textures::resolve`]); the first is the drop reference unless one is
    /// named Original.
    pub textures: Vec<String>,
    pub plan: ViewPlan,
    pub protocol: Protocol,
    /// Example views kept per group for the HTML report.
    pub examples_per_group: usize,
    /// Extra figures for the HTML report, `(caption, PNG path)`: e.g. the top-n study's plot.
    pub figures: Vec<(String, PathBuf)>,
    /// Judge every texture as this printer makes it (a printer profile; `cac eval --printer`).
    pub printer: Option<PathBuf>,
    pub out: PathBuf,
}

/// Parses an extra figure `CAPTION=PNG` (clap's value parser for `--figure`). The PNG must exist
/// now: it is read only when the report is written, after every view has been scored.
pub fn parse_figure(s: &str) -> Result<(String, PathBuf), String> {
    let (caption, png) = s
        .split_once('=')
        .filter(|(c, p)| !c.is_empty() && !p.is_empty())
        .ok_or_else(|| format!("{s:?}: expected CAPTION=PNG"))?;
    if !Path::new(png).is_file() {
        return Err(format!("{png}: no such file (the figure {caption:?})"));
    }
    Ok((caption.to_string(), PathBuf::from(png)))
}

/// What a finished evaluation wrote and measured.
pub struct Outcome {
    pub info: EvalInfo,
    /// Every image's record, all textures.
    pub records: Vec<super::run::ImageRecord>,
    pub files: Vec<String>,
    /// Images rendered and scored in this call (cached textures excluded).
    pub images_scored: usize,
    pub reused: Vec<String>,
    /// Textures assembled from shard files in this call, with their shard count N.
    pub merged: Vec<(String, usize)>,
    /// The output folder and the text of its report.md.
    pub out: PathBuf,
    pub report_md: String,
}

/// What `cac eval` prints: the report, then what was reused, merged, skipped and written.
impl std::fmt::Display for Outcome {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let out = self.out.display();
        writeln!(f, "{}", self.report_md)?;
        if !self.reused.is_empty() {
            writeln!(f, "reused from {out}/cache: {}", self.reused.join(", "))?;
        }
        for (t, n) in &self.merged {
            writeln!(f, "{t}: assembled from {n} shard(s) in {out}/cache")?;
        }
        if self.info.skipped.iter().any(|&s| s > 0) {
            let s = &self.info.skipped;
            writeln!(
                f,
                "views without a visible object (excluded), per texture: {s:?}"
            )?;
        }
        writeln!(
            f,
            "wrote {out} ({} files: report.md, report.html, CSV tables, results.json, plots) in \
             {:.0} s",
            self.files.len(),
            self.info.seconds
        )
    }
}

/// What a shard wrote.
pub struct ShardOutcome {
    pub shard: Shard,
    /// Textures this shard evaluated now, with the file each went to.
    pub written: Vec<(String, PathBuf)>,
    /// Textures whose part was already there (a finished shard file, or the whole texture in the
    /// cache): a rerun of a killed shard resumes after them.
    pub reused: Vec<String>,
    /// Images rendered and scored in this call.
    pub images_scored: usize,
    pub seconds: f64,
}

/// What a shard did, one line per texture.
impl std::fmt::Display for ShardOutcome {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let k = self.shard;
        for (t, file) in &self.written {
            writeln!(f, "shard {k}: {t} -> {}", file.display())?;
        }
        if !self.reused.is_empty() {
            writeln!(f, "shard {k}: already done: {}", self.reused.join(", "))?;
        }
        writeln!(
            f,
            "shard {k} finished: {} images scored in {:.1} s; run the same command with --merge \
             instead of --shard once every shard is done",
            self.images_scored, self.seconds
        )
    }
}

/// Which part of the job a call does.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Part {
    /// Everything missing from the cache; complete shard sets are merged, not re-rendered.
    All,
    /// The report from the cache and the shard files only; nothing is rendered.
    Merge,
}

/// The resolved job: textures, views, keys.
struct Prepared {
    scene: cac_scene::Scene,
    texs: Vec<textures::NamedTexture>,
    env: Environment,
    groups: Vec<ViewGroup>,
    views: Vec<(usize, usize)>,
    models: Vec<String>,
    keys: Vec<String>,
    cache_dir: PathBuf,
}

impl Prepared {
    /// Renders and scores texture `t` in `views` (building the renderer on first use, so a run
    /// that only reuses the cache never ray-casts).
    #[allow(clippy::too_many_arguments)]
    fn score(
        &self,
        job: &EvalJob,
        renderer: &mut Option<Renderer>,
        views: &[(usize, usize)],
        t: &textures::NamedTexture,
        dets: &[&dyn Detector],
        device: &Device,
        progress: &mut dyn FnMut(),
    ) -> Result<TextureResult> {
        if renderer.is_none() {
            *renderer = Some(Renderer::new(self.scene.clone(), job.scene.render.clone())?);
        }
        evaluate_texture_in(
            renderer.as_ref().expect("built above"),
            &self.env,
            &self.groups,
            views,
            &t.name,
            &t.atlas,
            dets,
            &job.protocol,
            job.examples_per_group,
            device,
            progress,
        )
    }
}

fn prepare(job: &EvalJob, dets: &[&dyn Detector]) -> Result<Prepared> {
    // The protocol's classes against every model, before anything is rendered or written.
    super::Scorer::new(dets, &job.protocol)?;
    let scene = job.scene.object.load()?;
    let res = job.scene.render.atlas_res;
    let mut texs = textures::resolve_all(&job.textures, &scene, res, job.plan.seed)?;
    if let Some(path) = &job.printer {
        textures::print_all(&mut texs, path)?;
    }
    let env = Environment::new(job.scene.environment.clone())?;
    let groups = view_groups(&env, &job.plan);
    let views = all_views(&groups);
    let models: Vec<String> = dets.iter().map(|d| d.name().to_string()).collect();
    let settings = serde_json::json!({
        "scene": job.scene, "plan": job.plan, "protocol": job.protocol,
        "models": models, "examples": job.examples_per_group,
    });
    let keys = texs
        .iter()
        .map(|t| cache::key(&settings, &t.atlas.texels))
        .collect();
    Ok(Prepared {
        scene,
        texs,
        env,
        groups,
        views,
        models,
        keys,
        cache_dir: job.out.join("cache"),
    })
}

/// Runs the job: every texture not in the cache is rendered and scored (a texture whose shards
/// are all in the cache, from the same settings, is assembled from them instead), and the report
/// is written. `progress(done, total)` is called once per image.
pub fn run(
    job: &EvalJob,
    dets: &[&dyn Detector],
    device: &Device,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<Outcome> {
    report_part(job, Part::All, dets, device, progress)
}

/// Assembles the report from the cache and the shards' files only (nothing is rendered): each
/// texture is either whole in the cache or has all N shard files of one split, written with the
/// same settings. Anything else is an error naming the file, and then nothing is written.
pub fn merge(job: &EvalJob, dets: &[&dyn Detector], device: &Device) -> Result<Outcome> {
    report_part(job, Part::Merge, dets, device, &mut |_, _| {})
}

/// Evaluates shard `shard` of the job's views for every texture and writes each texture's part
/// into its own file in the cache (`OUT/cache/NAME.shard-K-of-N.json`); writes no report. A
/// texture whose part (or whole result) is already there with the same settings is skipped, so
/// a killed shard resumes. `progress(done, total)` is called once per image.
pub fn run_shard(
    job: &EvalJob,
    shard: Shard,
    dets: &[&dyn Detector],
    device: &Device,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<ShardOutcome> {
    let start = Instant::now();
    let p = prepare(job, dets)?;
    let mine = shard.part(&p.views);
    let total = mine.len() * p.texs.len();
    let mut renderer = None;
    let mut out = ShardOutcome {
        shard,
        written: vec![],
        reused: vec![],
        images_scored: 0,
        seconds: 0.0,
    };
    let mut done = 0;
    for (t, key) in p.texs.iter().zip(&p.keys) {
        let have = cache::load_shard(&p.cache_dir, &t.name, key, (shard.k, shard.n))?.is_some()
            || cache::load(&p.cache_dir, &t.name, key)?.is_some();
        if have {
            out.reused.push(t.name.clone());
            done += mine.len();
            progress(done, total);
            continue;
        }
        let r = p.score(job, &mut renderer, &mine, t, dets, device, &mut || {
            done += 1;
            progress(done, total);
        })?;
        out.images_scored += mine.len();
        let file = cache::store_shard(&p.cache_dir, &t.name, key, (shard.k, shard.n), &mine, &r)?;
        out.written.push((t.name.clone(), file));
    }
    out.seconds = start.elapsed().as_secs_f64();
    Ok(out)
}

fn report_part(
    job: &EvalJob,
    part: Part,
    dets: &[&dyn Detector],
    device: &Device,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<Outcome> {
    let start = Instant::now();
    let p = prepare(job, dets)?;
    let got = texture_results(job, part, &p, dets, device, progress)?;
    // Every texture is there: keep the merged ones whole in the cache (a later run reads one
    // file), then write the report.
    store_merged(&p, &got.results)?;
    let (mut records, mut examples, mut skipped) = (vec![], vec![], vec![]);
    for (r, _) in got.results {
        records.extend(r.records);
        examples.push(r.examples);
        skipped.push(r.skipped);
    }
    let info = eval_info(job, &p.texs, p.models, skipped, got.reused.clone(), start)?;
    let (files, report_md) = write_report(job, &info, &records, &examples)?;
    Ok(Outcome {
        info,
        records,
        files,
        images_scored: got.scored,
        reused: got.reused,
        merged: got.merged,
        out: job.out.clone(),
        report_md,
    })
}

/// Every texture's result, in the job's order, and where each came from.
struct TextureResults {
    /// Each texture's result, and whether it was assembled from shard files.
    results: Vec<(TextureResult, bool)>,
    /// Textures read whole from the cache.
    reused: Vec<String>,
    /// Textures assembled from shard files, with their shard count N.
    merged: Vec<(String, usize)>,
    /// Images rendered and scored.
    scored: usize,
}

/// Each texture from the cache, else from its shard files, else (unless merging only)
/// rendered, scored and stored in the cache.
fn texture_results(
    job: &EvalJob,
    part: Part,
    p: &Prepared,
    dets: &[&dyn Detector],
    device: &Device,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<TextureResults> {
    let per_texture = p.views.len();
    let total = per_texture * p.texs.len();
    let mut renderer = None;
    let mut got = TextureResults {
        results: vec![],
        reused: vec![],
        merged: vec![],
        scored: 0,
    };
    let mut done = 0;
    for (t, key) in p.texs.iter().zip(&p.keys) {
        if let Some(r) = cache::load(&p.cache_dir, &t.name, key)? {
            got.reused.push(t.name.clone());
            done += per_texture;
            progress(done, total);
            got.results.push((r, false));
            continue;
        }
        let from_shards = shard::merge(&p.cache_dir, &t.name, key, &p.groups, &p.views, &p.models);
        match (part, from_shards) {
            (_, Ok((r, n))) => {
                got.merged.push((t.name.clone(), n));
                done += per_texture;
                progress(done, total);
                got.results.push((r, true));
            }
            (Part::Merge, Err(e)) => {
                return Err(e.context(format!(
                    "cannot merge the evaluation in {} (nothing was written)",
                    job.out.display()
                )))
            }
            (_, Err(_)) => {
                let r = p.score(job, &mut renderer, &p.views, t, dets, device, &mut || {
                    done += 1;
                    progress(done, total);
                })?;
                got.scored += per_texture;
                cache::store(&p.cache_dir, &t.name, key, &r)?;
                got.results.push((r, false));
            }
        }
    }
    Ok(got)
}

/// Stores the textures assembled from shard files whole in the cache.
fn store_merged(p: &Prepared, results: &[(TextureResult, bool)]) -> Result<()> {
    for ((r, from_shards), (t, key)) in results.iter().zip(p.texs.iter().zip(&p.keys)) {
        if *from_shards {
            cache::store(&p.cache_dir, &t.name, key, r)?;
        }
    }
    Ok(())
}

/// What was evaluated and how, for the report; the drop reference is the texture named
/// Original, else the first.
fn eval_info(
    job: &EvalJob,
    texs: &[textures::NamedTexture],
    models: Vec<String>,
    skipped: Vec<usize>,
    reused: Vec<String>,
    start: Instant,
) -> Result<EvalInfo> {
    let names: Vec<String> = texs.iter().map(|t| t.name.clone()).collect();
    let reference = names
        .iter()
        .find(|n| n.eq_ignore_ascii_case("original"))
        .unwrap_or(&names[0])
        .clone();
    Ok(EvalInfo {
        object: job.scene.object.mesh.clone(),
        protocol: job.protocol.clone(),
        plan: job.plan.clone(),
        render: job.scene.render.clone(),
        light: hdri_text(&job.scene.environment),
        printed: printed_text(job)?,
        textures: names,
        reference,
        models,
        skipped,
        reused,
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// Writes the report's files into the output folder (with the job's extra figures); their
/// names, and the text of report.md.
fn write_report(
    job: &EvalJob,
    info: &EvalInfo,
    records: &[super::run::ImageRecord],
    examples: &[Vec<super::run::Example>],
) -> Result<(Vec<String>, String)> {
    let (mut files, mut report_md) = (vec![], String::new());
    let extra = job
        .figures
        .iter()
        .map(|(c, p)| Ok((c.clone(), cac_core::io::load_rgb(p)?)))
        .collect::<Result<Vec<_>>>()?;
    for (name, bytes) in report::files(info, records, examples, &extra)? {
        cac_core::io::write_atomic(&job.out.join(&name), &bytes)?;
        if name == "report.md" {
            report_md = String::from_utf8_lossy(&bytes).into_owned();
        }
        files.push(name);
    }
    Ok((files, report_md))
}

/// The protocol statement's words for photographed light: empty under the sun and ambient.
fn hdri_text(e: &cac_render::environment::EnvConfig) -> String {
    if e.hdri.is_empty() {
        return String::new();
    }
    format!(
        "; lit by the HDR environments {} (a share {} of the views, one drawn per view, turned {:?} deg, exposure {:?} stops; the brightness level then changes nothing: L_b and L_d are two draws of views under them)",
        e.hdri.join(", "),
        e.hdri_share,
        e.hdri_rotation_deg,
        e.hdri_exposure_stops
    )
}

/// The report's note of the printer the textures were judged through, or empty.
fn printed_text(job: &EvalJob) -> Result<String> {
    let Some(path) = &job.printer else {
        return Ok(String::new());
    };
    let p = cac_core::printer::Profile::load(path)?;
    Ok(format!(
        ", each as printed by {:?} ({} profile {})",
        p.name,
        p.kind(),
        path.display()
    ))
}
