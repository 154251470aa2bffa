//! Runs an experiment: references per scene state (cached), then every run of the shard frame
//! by frame, recording time, rays and error after each frame.

use super::report::{self, Analysis};
pub use super::rows::{read_output_dir, ReferenceInfo, Row, RunSummary, Summary};
use super::spec::{expand_runs, Event, RunSpec, Shard};
use crate::compare::{flip, io, metrics, Image};
use crate::gpu::{shaders::ShaderLibrary, Gpu};
use crate::jobs;
use crate::preset::{LoadedPreset, TechniqueEntry};
use crate::render::{engine::Engine, engine::EngineSettings, RAY_KINDS};
use crate::scene::{gpu_scene::GpuScene, Camera, Scene};
use crate::techniques::create_technique;
use anyhow::{ensure, Context, Result};

use std::path::{Path, PathBuf};
use std::sync::Arc;

pub struct ConvergeOptions {
    pub out: PathBuf,
    pub cache: PathBuf,
    pub shard: Option<Shard>,
    pub quiet: bool,
}

/// A scene state: the preset's scene with the first `k` events applied.
struct SceneState {
    scene: Arc<Scene>,
    gpu_scene: Arc<GpuScene>,
    camera: Camera,
    reference: Image,
    info: ReferenceInfo,
}

pub fn git_commit() -> String {
    let out = std::process::Command::new("git")
        .args(["rev-parse", "HEAD"])
        .output();
    let dirty = std::process::Command::new("git")
        .args(["status", "--porcelain", "--untracked-files=no"])
        .output()
        .map(|o| !o.stdout.is_empty())
        .unwrap_or(false);
    match out {
        Ok(o) if o.status.success() => {
            let c = String::from_utf8_lossy(&o.stdout).trim().to_string();
            if dirty {
                format!("{c}-dirty")
            } else {
                c
            }
        }
        _ => "unknown".into(),
    }
}

pub fn sha256_hex(text: &str) -> String {
    use sha2::Digest;
    sha2::Sha256::digest(text.as_bytes())
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// The experiment name: `[experiment] name`, else the file stem.
pub fn experiment_name(p: &LoadedPreset) -> String {
    p.preset
        .experiment
        .as_ref()
        .and_then(|e| e.name.clone())
        .or_else(|| {
            p.path
                .as_ref()
                .and_then(|p| p.file_stem())
                .map(|s| s.to_string_lossy().to_string())
        })
        .unwrap_or_else(|| "experiment".into())
}

fn sorted_events(p: &LoadedPreset) -> Result<Vec<Event>> {
    let exp = p
        .preset
        .experiment
        .as_ref()
        .context("no [experiment] table")?;
    let mut events = exp.events.clone();
    events.sort_by_key(|e| e.frame);
    for e in &events {
        ensure!(
            e.frame >= 1 && e.frame < exp.frames,
            "event at frame {}: events must fall within frames 1..{} (frame 0 is the preset itself)",
            e.frame,
            exp.frames
        );
    }
    Ok(events)
}

fn build_states(
    gpu: &Arc<Gpu>,
    p: &LoadedPreset,
    events: &[Event],
    cache: &Path,
    quiet: bool,
) -> Result<Vec<SceneState>> {
    let mut scene = p.load_scene()?;
    let mut camera = p.camera(&scene);
    let base_key = jobs::reference_key_for_camera(p, &camera);
    let setup = jobs::reference_setup(p);
    let mut states = Vec::new();
    for k in 0..=events.len() {
        if k > 0 {
            events[k - 1].apply(&mut scene, &mut camera)?;
            scene.validate()?;
        }
        // The key of an edited state adds the events applied so far.
        let key = if k == 0 {
            base_key.clone()
        } else {
            use std::hash::Hasher;
            let mut h = fnv::FnvHasher::default();
            h.write(base_key.as_bytes());
            h.write(serde_json::to_string(&events[..k])?.as_bytes());
            format!("{:016x}", h.finish())
        };
        let (reference, path) = jobs::reference_image(
            gpu.clone(),
            p,
            scene.clone(),
            camera,
            &key,
            cache,
            false,
            quiet,
        )?;
        let gpu_scene = Arc::new(GpuScene::upload(gpu, &scene));
        states.push(SceneState {
            scene: Arc::new(scene.clone()),
            gpu_scene,
            camera,
            reference,
            info: ReferenceInfo {
                state: k,
                from_frame: if k == 0 { 0 } else { events[k - 1].frame },
                key,
                cache_file: path.display().to_string(),
                spp: setup.spp,
                seed: setup.seed,
            },
        });
    }
    Ok(states)
}

/// Runs the experiment (or its shard), writes every output into `opts.out` and returns the
/// summary.
pub fn converge(gpu: Arc<Gpu>, p: &LoadedPreset, opts: &ConvergeOptions) -> Result<Summary> {
    let exp = p
        .preset
        .experiment
        .clone()
        .context("the preset has no [experiment] table: nothing to converge")?;
    ensure!(exp.frames >= 1, "experiment.frames must be at least 1");
    let runs = expand_runs(p)?;
    let events = sorted_events(p)?;
    // Events are checked on the CPU scene before any reference is rendered.
    {
        let mut scene = p.load_scene()?;
        let mut camera = p.camera(&scene);
        for e in &events {
            e.apply(&mut scene, &mut camera)?;
        }
    }
    // Every run's technique and parameters are checked before any GPU work.
    for r in &runs {
        create_technique(&r.technique)?
            .set_params(&r.params)
            .with_context(|| format!("run '{}'", r.label))?;
    }
    std::fs::create_dir_all(opts.out.join("runs"))
        .with_context(|| format!("creating {}", opts.out.display()))?;
    let states = build_states(&gpu, p, &events, &opts.cache, opts.quiet)?;
    for s in &states {
        let name = format!("reference-state{}", s.info.state);
        io::write_exr(
            &opts.out.join("runs").join(format!("{name}.exr")),
            &s.reference,
        )?;
        io::write_png(
            &opts.out.join("runs").join(format!("{name}.png")),
            &s.reference,
            p.preset.tonemap.operator,
            p.preset.tonemap.exposure,
        )?;
    }
    let mine: Vec<&RunSpec> = runs
        .iter()
        .filter(|r| opts.shard.is_none_or(|s| s.takes(r.index)))
        .collect();
    let bar = jobs::progress_bar(
        mine.len() as u64 * exp.frames as u64,
        "converge",
        opts.quiet,
    );
    let shaders = ShaderLibrary::discover();
    let mut rows = Vec::new();
    let mut summaries = Vec::new();
    for (i, spec) in mine.iter().enumerate() {
        bar.set_message(format!("run {}/{}: {}", i + 1, mine.len(), spec.label));
        let (run_rows, summary) =
            run_one(&gpu, p, &shaders, &states, &events, spec, &exp, opts, &bar)
                .with_context(|| format!("run '{}'", spec.label))?;
        rows.extend(run_rows);
        summaries.push(summary);
    }
    bar.finish_and_clear();
    let summary = Summary {
        experiment: experiment_name(p),
        file: p.path.as_ref().map(|p| p.display().to_string()),
        preset_sha256: sha256_hex(&p.to_toml()?),
        git_commit: git_commit(),
        adapter: gpu.summary.clone(),
        size: p.preset.render.size,
        seeds: runs
            .iter()
            .map(|r| r.seed)
            .collect::<std::collections::BTreeSet<_>>()
            .into_iter()
            .collect(),
        tonemap: p.preset.tonemap.clone(),
        settings: exp.clone(),
        total_runs: runs.len(),
        shards: opts.shard.into_iter().collect(),
        references: states.iter().map(|s| s.info.clone()).collect(),
        runs: summaries,
        analysis: Analysis::default(),
    };
    report::finish(summary, rows, &opts.out)
}

#[allow(clippy::too_many_arguments)]
fn run_one(
    gpu: &Arc<Gpu>,
    p: &LoadedPreset,
    shaders: &ShaderLibrary,
    states: &[SceneState],
    events: &[Event],
    spec: &RunSpec,
    exp: &super::ExperimentSettings,
    opts: &ConvergeOptions,
    bar: &indicatif::ProgressBar,
) -> Result<(Vec<Row>, RunSummary)> {
    let entry = TechniqueEntry {
        name: spec.technique.clone(),
        label: Some(spec.label.clone()),
        params: spec.params.clone(),
        budget: spec.budget,
    };
    let settings = EngineSettings {
        extent: p.preset.render.size,
        seed: spec.seed,
        camera: states[0].camera,
    };
    let mut engine = Engine::for_entry(
        gpu.clone(),
        shaders.clone(),
        states[0].scene.clone(),
        states[0].gpu_scene.clone(),
        &entry,
        settings,
    )?;
    let pixels = (engine.extent[0] * engine.extent[1]) as f64;
    let (op, ev) = (p.preset.tonemap.operator, p.preset.tonemap.exposure);
    let mut rows = Vec::new();
    let mut by_pass: std::collections::BTreeMap<String, f64> = Default::default();
    let mut state = 0usize;
    let mut last_image = None;
    for f in 0..exp.frames {
        for _ in events.iter().filter(|e| e.frame == f) {
            state += 1;
            let s = &states[state];
            if !Arc::ptr_eq(&s.scene, &engine.scene) {
                engine.change_scene(s.scene.clone(), s.gpu_scene.clone())?;
            }
            if s.camera != engine.camera {
                engine.move_camera(s.camera);
            }
        }
        let report = engine.render_frame()?;
        for (name, ms) in &report.gpu_ms_by_pass {
            *by_pass.entry(name.clone()).or_insert(0.0) += ms;
        }
        let image = engine.read_output()?;
        let reference = &states[state].reference;
        let m = metrics::compare(&image, reference)?;
        let flip = flip::ldr_flip(&image, reference, op, ev)?;
        let rays = engine.ray_counts()?;
        let prev = rows
            .last()
            .map_or((0.0, 0.0), |r: &Row| (r.gpu_ms_cum, r.wall_ms_cum));
        let k = |name: &str| {
            RAY_KINDS
                .iter()
                .position(|n| *n == name)
                .map_or(0, |i| rays.by_kind[i])
        };
        rows.push(Row {
            run: spec.index,
            label: spec.label.clone(),
            technique: spec.technique.clone(),
            seed: spec.seed,
            budget: spec.budget,
            frame: f + 1,
            state,
            gpu_ms: report.gpu_ms,
            gpu_ms_cum: prev.0 + report.gpu_ms,
            wall_ms: report.wall_ms,
            wall_ms_cum: prev.1 + report.wall_ms,
            timing: match report.timing {
                crate::render::engine::TimingSource::Timestamps => "timestamps",
                _ => "wall",
            }
            .into(),
            rays: rays.total(),
            rays_per_pixel: rays.total() as f64 / pixels,
            rays_camera: k("camera"),
            rays_shadow: k("shadow"),
            rays_indirect: k("indirect"),
            rays_probe: k("probe"),
            rays_surfel: k("surfel"),
            rays_cache: k("cache"),
            rays_candidate: k("candidate"),
            rays_reuse: k("reuse"),
            mse: m.mse,
            rel_mse: m.rel_mse,
            smape: m.smape,
            flip,
            passes: report
                .gpu_ms_by_pass
                .iter()
                .map(|(n, ms)| format!("{n}={ms:.4}"))
                .collect::<Vec<_>>()
                .join(";"),
        });
        last_image = Some(image);
        bar.inc(1);
        if exp.seconds > 0.0 && prev.0 + report.gpu_ms >= exp.seconds * 1e3 {
            bar.inc((exp.frames - f - 1) as u64);
            break;
        }
    }
    let image = last_image.context("no frame rendered")?;
    let last = rows.last().cloned().context("no frame rendered")?;
    let frames = last.frame;
    let stem = format!("{:03}-{}", spec.index, spec.label);
    let dir = opts.out.join("runs");
    let entry = TechniqueEntry {
        label: Some(spec.label.clone()),
        params: engine.technique.params(),
        ..TechniqueEntry::new(&spec.technique)
    };
    let mut meta_by_pass = by_pass.clone();
    meta_by_pass.values_mut().for_each(|v| *v /= frames as f64);
    let meta = jobs::metadata(&engine, p, &entry, &image, meta_by_pass.clone())?;
    jobs::write_outputs(&dir, &stem, &image, &meta, p)?;
    let passes = engine.passes();
    Ok((
        rows,
        RunSummary {
            spec: spec.clone(),
            params: engine.technique.params(),
            rays_per_pixel_per_frame: last.rays_per_pixel / frames as f64,
            frames,
            gpu_ms_total: last.gpu_ms_cum,
            gpu_ms_per_frame: last.gpu_ms_cum / frames as f64,
            gpu_ms_by_pass: meta_by_pass,
            passes_run: passes
                .iter()
                .filter(|p| p.runs)
                .map(|p| p.name.to_string())
                .collect(),
            passes_skipped: passes
                .iter()
                .filter(|p| !p.runs)
                .map(|p| format!("{}: {}", p.name, p.why))
                .collect(),
            final_mse: last.mse,
            final_rel_mse: last.rel_mse,
            final_smape: last.smape,
            final_flip: last.flip,
            non_finite_pixels: image.non_finite_count(),
            image: format!("runs/{stem}.exr"),
        },
    ))
}

/// Merges shard folders into one output: checks they come from the same experiment, joins
/// runs and rows in run order, copies the last-frame images, and writes the report again.
pub fn merge(dirs: &[PathBuf], out: &Path) -> Result<Summary> {
    ensure!(!dirs.is_empty(), "--merge needs at least one folder");
    let mut merged: Option<Summary> = None;
    let mut rows = Vec::new();
    std::fs::create_dir_all(out.join("runs"))?;
    for dir in dirs {
        let (s, r) = read_output_dir(dir)?;
        if let Some(m) = &mut merged {
            ensure!(
                m.preset_sha256 == s.preset_sha256,
                "{}: a different experiment (preset hash {} against {})",
                dir.display(),
                s.preset_sha256,
                m.preset_sha256
            );
            for run in &s.runs {
                ensure!(
                    !m.runs.iter().any(|x| x.spec.index == run.spec.index),
                    "{}: run '{}' is in two shards",
                    dir.display(),
                    run.spec.label
                );
            }
            m.runs.extend(s.runs.clone());
            m.shards.extend(s.shards.clone());
        } else {
            merged = Some(s);
        }
        rows.extend(r);
        for e in std::fs::read_dir(dir.join("runs"))? {
            let e = e?;
            if e.file_type()?.is_file() {
                let to = out.join("runs").join(e.file_name());
                if e.path() != to {
                    std::fs::copy(e.path(), &to)?;
                }
            }
        }
    }
    let mut summary = merged.expect("one folder at least");
    summary.runs.sort_by_key(|r| r.spec.index);
    summary.shards.sort_by_key(|s| s.index);
    let missing = summary.total_runs - summary.runs.len();
    if missing > 0 {
        eprintln!(
            "warning: {missing} of {} runs are in none of the merged folders",
            summary.total_runs
        );
    }
    rows.sort_by_key(|r| (r.run, r.frame));
    report::finish(summary, rows, out)
}
