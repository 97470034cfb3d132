//! One whole evaluation: resolve the textures, draw the views, score every texture with every
//! model (reusing finished textures from the cache folder), and write the report into the output
//! folder (`report.md`, `report.html`, tables as CSV, `results.json`, plots).

use super::report::{self, EvalInfo};
use super::run::{evaluate_texture, view_groups, ViewPlan};
use super::{cache, textures, Protocol};
use crate::config::SceneConfig;
use crate::detect::Detector;
use crate::environment::Environment;
use crate::render::Renderer;
use anyhow::Result;
use burn::tensor::Device;
use std::path::PathBuf;
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
    pub out: PathBuf,
}

/// What a finished evaluation wrote and measured.
pub struct Outcome {
    pub info: EvalInfo,
    pub files: Vec<String>,
    /// Images rendered and scored in this call (cached textures excluded).
    pub images_scored: usize,
    pub reused: Vec<String>,
}

/// Runs the job. `progress(done, total)` is called once per image.
pub fn run(
    job: &EvalJob,
    dets: &[&dyn Detector],
    device: &Device,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<Outcome> {
    let start = Instant::now();
    let scene = job.scene.object.load()?;
    let res = job.scene.render.atlas_res;
    let texs = textures::resolve_all(&job.textures, &scene, res, job.plan.seed)?;
    let renderer = Renderer::new(scene, job.scene.render.clone())?;
    let env = Environment::new(job.scene.environment.clone())?;
    let groups = view_groups(&env, &job.plan);
    let models: Vec<String> = dets.iter().map(|d| d.name().to_string()).collect();
    let per_texture: usize = groups.iter().map(|g| g.conditions.len()).sum();
    let total = per_texture * texs.len();
    let cache_dir = job.out.join("cache");
    let settings = serde_json::json!({
        "scene": job.scene, "plan": job.plan, "protocol": job.protocol,
        "models": models, "examples": job.examples_per_group,
    });
    let (mut records, mut examples, mut skipped, mut reused) = (vec![], vec![], vec![], vec![]);
    let mut done = 0;
    let mut scored = 0;
    for t in &texs {
        let key = cache::key(&settings, &t.atlas.texels);
        let r = match cache::load(&cache_dir, &t.name, &key)? {
            Some(r) => {
                reused.push(t.name.clone());
                done += per_texture;
                progress(done, total);
                r
            }
            None => {
                let r = evaluate_texture(
                    &renderer,
                    &env,
                    &groups,
                    &t.name,
                    &t.atlas,
                    dets,
                    &job.protocol,
                    job.examples_per_group,
                    device,
                    &mut || {
                        done += 1;
                        progress(done, total);
                    },
                )?;
                scored += per_texture;
                cache::store(&cache_dir, &t.name, &key, &r)?;
                r
            }
        };
        records.extend(r.records);
        examples.push(r.examples);
        skipped.push(r.skipped);
    }
    let names: Vec<String> = texs.iter().map(|t| t.name.clone()).collect();
    let reference = names
        .iter()
        .find(|n| n.eq_ignore_ascii_case("original"))
        .unwrap_or(&names[0])
        .clone();
    let info = EvalInfo {
        object: job.scene.object.mesh.clone(),
        protocol: job.protocol.clone(),
        plan: job.plan.clone(),
        render: job.scene.render.clone(),
        textures: names,
        reference,
        models,
        skipped,
        reused: reused.clone(),
        seconds: start.elapsed().as_secs_f64(),
    };
    let mut files = vec![];
    let extra = job
        .figures
        .iter()
        .map(|(c, p)| Ok((c.clone(), crate::io::load_rgb(p)?)))
        .collect::<Result<Vec<_>>>()?;
    for (name, bytes) in report::files(&info, &records, &examples, &extra)? {
        crate::io::write_atomic(&job.out.join(&name), &bytes)?;
        files.push(name);
    }
    Ok(Outcome {
        info,
        files,
        images_scored: scored,
        reused,
    })
}
