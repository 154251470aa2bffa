//! Rendering jobs shared by the CLI (`shot`, `reference`), the viewer and `converge`, below all
//! three: an engine for a preset's technique entry (with its ray budget mapped the one way),
//! references and their cache keys, JSON metadata, and PNG + EXR + JSON outputs.

use crate::compare::{io, Image};
use crate::gpu::{shaders::ShaderLibrary, Gpu};
use crate::preset::{LoadedPreset, TechniqueEntry};
use crate::render::{engine::Engine, engine::EngineSettings, PassInfo, RayCounts};
use crate::scene::{features::SceneFeatures, gpu_scene::GpuScene, Scene};
use crate::techniques::create_technique;
use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Everything a shot records next to its images.
#[derive(Serialize)]
pub struct ShotMetadata {
    pub technique: String,
    /// File stem and viewer name (the preset entry's label, else the technique id).
    pub label: String,
    pub params: toml::Table,
    pub preset: serde_json::Value,
    pub preset_file: Option<String>,
    pub adapter: crate::gpu::AdapterSummary,
    pub scene: String,
    pub scene_features: SceneFeatures,
    /// Scene set-up wall times: load, BVH build, preparation, GPU upload.
    pub scene_timings: crate::scene::gpu_scene::SceneTimings,
    pub passes: Vec<PassInfo>,
    pub camera: crate::scene::Camera,
    pub size: [u32; 2],
    pub seed: u32,
    pub spp: u32,
    pub frames: u32,
    pub rays: RayCounts,
    pub rays_by_kind: std::collections::BTreeMap<String, u64>,
    pub rays_per_pixel: f64,
    pub gpu_ms_total: f64,
    pub gpu_ms_per_frame: f64,
    pub gpu_ms_by_pass: std::collections::BTreeMap<String, f64>,
    pub wall_ms_total: f64,
    pub timestamps: bool,
    pub mean_radiance: [f64; 3],
    pub non_finite_pixels: usize,
}

impl Engine {
    /// An engine for a preset's technique entry on an uploaded scene (shared by the viewer's
    /// panes and an experiment's runs): the entry's technique, parameters and ray budget, the
    /// preset's size and seed.
    pub fn for_entry(
        gpu: Arc<Gpu>,
        shaders: ShaderLibrary,
        scene: Arc<Scene>,
        gpu_scene: Arc<GpuScene>,
        entry: &TechniqueEntry,
        settings: EngineSettings,
    ) -> Result<Engine> {
        let mut technique = create_technique(&entry.name)?;
        technique
            .set_params_from_table(&entry.params)
            .with_context(|| format!("technique '{}'", entry.display_name()))?;
        let mut engine =
            Engine::with_shared_scene(gpu, shaders, scene, gpu_scene, technique, settings)?;
        // The shared denoiser, before the budget: the budget's calibration counts its
        // primary-surface rays like every other pass's.
        if entry.denoise {
            engine.set_denoise(true)?;
        }
        // The entry's ray budget, mapped as the viewer's slider and `converge` map it.
        if let Some(budget) = entry.budget {
            engine.apply_ray_budget(budget, None)?;
        }
        Ok(engine)
    }
}

/// A preset's scene loaded and uploaded once, with the preset's camera: every engine made on it
/// shares it (`shot` makes one per technique; a Python session keeps one for all its renders).
#[derive(Clone)]
pub struct SceneOnGpu {
    pub scene: Arc<Scene>,
    pub gpu_scene: Arc<GpuScene>,
    pub camera: crate::scene::Camera,
}

impl SceneOnGpu {
    pub fn load(gpu: &Gpu, p: &LoadedPreset) -> Result<SceneOnGpu> {
        let start = std::time::Instant::now();
        let scene = p.load_scene()?;
        let load_ms = start.elapsed().as_secs_f64() * 1e3;
        let camera = p.camera(&scene);
        let mut gpu_scene = GpuScene::upload(gpu, &scene);
        gpu_scene.data.timings.load_ms = load_ms;
        Ok(SceneOnGpu {
            scene: Arc::new(scene),
            gpu_scene: Arc::new(gpu_scene),
            camera,
        })
    }

    /// An engine for `entry` on this scene: the preset's size and seed, this camera.
    pub fn engine(
        &self,
        gpu: Arc<Gpu>,
        p: &LoadedPreset,
        entry: &TechniqueEntry,
    ) -> Result<Engine> {
        let settings = EngineSettings {
            extent: p.preset.render.size,
            seed: p.preset.render.seed,
            camera: self.camera,
        };
        Engine::for_entry(
            gpu,
            ShaderLibrary::discover(),
            self.scene.clone(),
            self.gpu_scene.clone(),
            entry,
            settings,
        )
    }
}

/// An engine for the preset's technique entry `index`: its scene (loaded and uploaded here),
/// camera, size, seed and ray budget.
pub fn engine_for_entry(gpu: Arc<Gpu>, p: &LoadedPreset, index: usize) -> Result<Engine> {
    SceneOnGpu::load(&gpu, p)?.engine(gpu, p, &p.preset.techniques[index])
}

/// Frames `shot` renders for `spp` samples per pixel on an engine.
pub fn frames_for_spp(engine: &Engine, spp: u32) -> u32 {
    let spf = engine.technique.samples_per_frame().max(1);
    spp.div_ceil(spf).max(1)
}

/// Renders `frames` frames with a progress bar; returns the mean GPU ms per frame of each pass.
pub fn render_frames(
    engine: &mut Engine,
    frames: u32,
    label: &str,
    quiet: bool,
) -> Result<std::collections::BTreeMap<String, f64>> {
    let bar = progress_bar(frames as u64, label, quiet);
    let mut by_pass = std::collections::BTreeMap::new();
    for _ in 0..frames {
        let report = engine.render_frame()?;
        for (name, ms) in report.gpu_ms_by_pass {
            *by_pass.entry(name).or_insert(0.0) += ms / frames as f64;
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    Ok(by_pass)
}

/// Renders one technique of a preset for `spp` samples; returns the image and its metadata.
pub fn render_technique(
    gpu: Arc<Gpu>,
    p: &LoadedPreset,
    index: usize,
    quiet: bool,
) -> Result<(Image, ShotMetadata)> {
    let preset = &p.preset;
    let entry = &preset.techniques[index];
    let mut engine = engine_for_entry(gpu, p, index)?;
    let frames = frames_for_spp(&engine, preset.render.spp);
    let by_pass = render_frames(&mut engine, frames, &entry.name, quiet)?;
    let image = engine.read_output()?;
    let meta = metadata(&engine, p, entry, &image, by_pass)?;
    Ok((image, meta))
}

/// The JSON record of an engine's state: what `shot` and the viewer's A/B save write.
pub fn metadata(
    engine: &Engine,
    p: &LoadedPreset,
    entry: &TechniqueEntry,
    image: &Image,
    gpu_ms_by_pass: std::collections::BTreeMap<String, f64>,
) -> Result<ShotMetadata> {
    let rays = engine.ray_counts()?;
    let [w, h] = engine.extent;
    let pixels = (w * h) as f64;
    let frames = engine.frame_index.max(1);
    Ok(ShotMetadata {
        technique: entry.name.clone(),
        label: entry.display_name().to_string(),
        params: engine.technique.params(),
        preset: serde_json::to_value(&p.preset)?,
        preset_file: p.path.as_ref().map(|p| p.display().to_string()),
        adapter: engine.gpu.summary.clone(),
        scene: engine.scene.name.clone(),
        scene_features: engine.gpu_scene.data.features.clone(),
        scene_timings: engine.gpu_scene.data.timings,
        passes: engine.passes(),
        camera: engine.camera,
        size: engine.extent,
        seed: engine.seed,
        spp: engine.samples,
        frames: engine.frame_index,
        rays,
        rays_by_kind: rays
            .named()
            .into_iter()
            .map(|(k, v)| (k.to_string(), v))
            .collect(),
        rays_per_pixel: rays.total() as f64 / pixels,
        gpu_ms_total: engine.total_gpu_ms,
        gpu_ms_per_frame: engine.total_gpu_ms / frames as f64,
        gpu_ms_by_pass,
        wall_ms_total: engine.total_wall_ms,
        timestamps: engine.gpu.timestamp_period.is_some(),
        mean_radiance: image.mean(),
        non_finite_pixels: image.non_finite_count(),
    })
}

fn preset_stem(p: &LoadedPreset) -> String {
    p.path.as_ref().and_then(|p| p.file_stem()).map_or_else(
        || "default".to_string(),
        |s| s.to_string_lossy().to_string(),
    )
}

pub fn write_outputs(
    dir: &Path,
    stem: &str,
    image: &Image,
    meta: &ShotMetadata,
    p: &LoadedPreset,
) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    io::write_png(&dir.join(format!("{stem}.png")), image, &p.preset.tonemap)?;
    io::write_exr(&dir.join(format!("{stem}.exr")), image)?;
    std::fs::write(
        dir.join(format!("{stem}.json")),
        serde_json::to_string_pretty(meta)?,
    )?;
    Ok(())
}

pub fn shot(gpu: Arc<Gpu>, p: &LoadedPreset, out: &Path, verbose: bool) -> Result<()> {
    let dir = out.join(preset_stem(p));
    for i in 0..p.preset.techniques.len() {
        let (image, meta) = render_technique(gpu.clone(), p, i, false)?;
        if verbose && i == 0 {
            println!("scene '{}': {}", meta.scene, meta.scene_features.summary());
            println!(
                "shading: {} (every technique; [shading] brdf)",
                p.preset.shading.brdf.name()
            );
            let t = &meta.scene_timings;
            println!(
                "scene set-up: load {:.1} ms, BVH build {:.1} ms ({} triangles, depth {}, {} threads), preparation {:.1} ms in all, GPU upload {:.1} ms",
                t.load_ms,
                t.bvh_build_ms,
                meta.scene_features.triangle_count,
                meta.scene_features.bvh_depth,
                t.threads,
                t.prepare_ms,
                t.upload_ms
            );
        }
        if verbose && meta.rays.cache_lookups.total() > 0 {
            println!(
                "  {:<10} {}",
                meta.technique,
                meta.rays.cache_lookups.summary()
            );
        }
        if verbose {
            for pass in &meta.passes {
                println!(
                    "  {:<10} {:<26} {:<4} {}",
                    meta.technique,
                    pass.name,
                    if pass.runs { "runs" } else { "skip" },
                    pass.why
                );
            }
        }
        write_outputs(&dir, &meta.label, &image, &meta, p)?;
        let per_pass: Vec<String> = meta
            .gpu_ms_by_pass
            .iter()
            .map(|(k, v)| format!("{k} {v:.2} ms"))
            .collect();
        println!(
            "{}: {}x{} {} spp, {:.2} rays/pixel, {:.1} ms GPU/frame ({}), mean radiance [{:.4}, {:.4}, {:.4}], non-finite pixels {} -> {}",
            meta.label,
            meta.size[0],
            meta.size[1],
            meta.spp,
            meta.rays_per_pixel,
            meta.gpu_ms_per_frame,
            if per_pass.is_empty() { "wall time".to_string() } else { per_pass.join(", ") },
            meta.mean_radiance[0],
            meta.mean_radiance[1],
            meta.mean_radiance[2],
            meta.non_finite_pixels,
            dir.join(format!("{}.png", meta.label)).display()
        );
    }
    Ok(())
}

/// How a preset's reference is rendered: the reference path tracer with the preset's
/// `max_depth`, `render.reference_spp` samples and a seed derived from the preset's, so the
/// reference's noise is independent of a technique run with the preset seed.
pub struct ReferenceSetup {
    pub params: toml::Table,
    pub spp: u32,
    pub seed: u32,
}

pub fn reference_setup(p: &LoadedPreset) -> ReferenceSetup {
    let mut params = toml::Table::new();
    let entry = p.preset.techniques.iter().find(|t| t.name == "reference");
    if let Some(d) = entry.and_then(|t| t.params.get("max_depth")) {
        params.insert("max_depth".into(), d.clone());
    }
    ReferenceSetup {
        params,
        spp: p.preset.render.reference_spp.max(1),
        seed: p.preset.render.seed.wrapping_mul(0x9E37_79B9) ^ 0x5BD1_E995,
    }
}

/// Cache key of a reference render: scene, camera, size, reference spp, seed and max_depth.
/// Samples per frame are left out: results do not depend on how samples are split in frames.
pub fn reference_key(p: &LoadedPreset) -> Result<String> {
    let scene = p.load_scene()?;
    Ok(reference_key_for_camera(p, &p.camera(&scene)))
}

/// `reference_key` at another camera (the viewer's, after the user moved it).
pub fn reference_key_for_camera(p: &LoadedPreset, camera: &crate::scene::Camera) -> String {
    use std::hash::Hasher;
    let setup = reference_setup(p);
    let mut canonical = serde_json::json!({
        "scene": p.preset.scene.source,
        "scene_params": p.preset.scene.params,
        "camera": camera,
        "size": p.preset.render.size,
        "spp": setup.spp,
        "seed": setup.seed,
        "reference": setup.params,
    });
    // Only with an environment map, so that the keys of every other preset stay as they were.
    if let Some(env) = &p.preset.scene.environment {
        canonical["environment"] = serde_json::json!([
            env,
            p.preset.scene.environment_rotation,
            p.preset.scene.environment_intensity,
            p.environment_path().as_deref().and_then(file_stamp)
        ]);
    }
    // A scene file edited in place (same name) must not hit the old render.
    if let Some(stamp) = p.scene_path().as_deref().and_then(file_stamp) {
        canonical["scene_file"] = serde_json::json!(stamp);
    }
    if !p.preset.scene.instancing {
        canonical["instancing"] = false.into();
    }
    // The pose (a reference is of one frame's pose; still scenes keep their keys).
    let s = &p.preset.scene;
    if s.time.is_some() || s.animation.is_some() {
        canonical["pose"] = serde_json::json!([s.time, s.animation]);
    }
    if !s.animate.is_empty() {
        canonical["animate"] = serde_json::json!(s.animate);
    }
    let mut h = fnv::FnvHasher::default();
    h.write(canonical.to_string().as_bytes());
    format!("{:016x}", h.finish())
}

/// A file's length and modification time (ns since the epoch): cache keys of file inputs.
fn file_stamp(path: &Path) -> Option<(u64, u128)> {
    let meta = std::fs::metadata(path).ok()?;
    let modified = meta
        .modified()
        .ok()?
        .duration_since(std::time::UNIX_EPOCH)
        .ok()?;
    Some((meta.len(), modified.as_nanos()))
}

pub fn reference(gpu: Arc<Gpu>, p: &LoadedPreset, cache: &Path, force: bool) -> Result<PathBuf> {
    let scene = p.load_scene()?;
    let camera = p.camera(&scene);
    let key = reference_key(p)?;
    let (_, path) = reference_image(gpu, p, scene, camera, &key, cache, force, false)?;
    Ok(path)
}

/// The cached reference of `scene` seen from `camera` under key `key` (renders and caches
/// it when missing or `force`): the image and its EXR path.
#[allow(clippy::too_many_arguments)]
pub fn reference_image(
    gpu: Arc<Gpu>,
    p: &LoadedPreset,
    scene: crate::scene::Scene,
    camera: crate::scene::Camera,
    key: &str,
    cache: &Path,
    force: bool,
    quiet: bool,
) -> Result<(Image, PathBuf)> {
    let seed = reference_setup(p).seed;
    reference_image_seeded(gpu, p, scene, camera, key, cache, seed, force, quiet)
}

/// `reference_image` with another seed than the preset's reference seed (real-time
/// experiments render each frame's reference with its own seed, so consecutive references
/// are independent renders); `key` must include the seed.
#[allow(clippy::too_many_arguments)]
pub fn reference_image_seeded(
    gpu: Arc<Gpu>,
    p: &LoadedPreset,
    scene: crate::scene::Scene,
    camera: crate::scene::Camera,
    key: &str,
    cache: &Path,
    seed: u32,
    force: bool,
    quiet: bool,
) -> Result<(Image, PathBuf)> {
    let path = cache.join(format!("{key}.exr"));
    if path.exists() && !force {
        if !quiet {
            println!("reference: cached {}", path.display());
        }
        let image = io::read_exr(&path)?;
        anyhow::ensure!(
            [image.width, image.height] == p.preset.render.size,
            "{}: cached reference has the wrong size (delete it)",
            path.display()
        );
        return Ok((image, path));
    }
    let setup = reference_setup(p);
    // Only the reference technique renders a reference, whatever the preset lists; frames
    // of up to 16 samples keep the progress bar moving.
    let mut params = setup.params;
    params.insert(
        "samples_per_frame".into(),
        (setup.spp.min(16) as i64).into(),
    );
    let entry = TechniqueEntry {
        params,
        ..TechniqueEntry::new("reference")
    };
    let mut technique = create_technique("reference")?;
    technique.set_params_from_table(&entry.params)?;
    let settings = EngineSettings {
        extent: p.preset.render.size,
        seed,
        camera,
    };
    let mut engine = Engine::new(gpu, ShaderLibrary::discover(), scene, technique, settings)?;
    let spf = engine.technique.samples_per_frame().max(1);
    let frames = setup.spp.div_ceil(spf).max(1);
    let by_pass = render_frames(&mut engine, frames, "reference", quiet)?;
    let image = engine.read_output()?;
    let mut p = p.clone();
    p.preset.techniques = vec![entry.clone()];
    p.preset.render.spp = setup.spp;
    p.preset.render.seed = seed;
    let meta = metadata(&engine, &p, &entry, &image, by_pass)?;
    write_outputs(cache, key, &image, &meta, &p)?;
    if !quiet {
        println!(
            "reference: {} spp, {:.1} s GPU, {:.2} rays/pixel, non-finite pixels {}",
            meta.spp,
            meta.gpu_ms_total / 1e3,
            meta.rays_per_pixel,
            meta.non_finite_pixels
        );
    }
    Ok((image, path))
}

/// Where progress goes instead of the terminal bar (the Python module's tqdm): called with
/// the bar's label, position, length and whether it finished.
pub type ProgressSink = Arc<dyn Fn(&str, u64, u64, bool) + Send + Sync>;

static PROGRESS_SINK: std::sync::RwLock<Option<ProgressSink>> = std::sync::RwLock::new(None);

/// Sends every visible progress bar to `sink` (None: back to the terminal).
pub fn set_progress_sink(sink: Option<ProgressSink>) {
    *PROGRESS_SINK.write().unwrap_or_else(|e| e.into_inner()) = sink;
}

/// A progress bar: indicatif's on the terminal, or the installed sink's.
pub struct Progress {
    bar: ProgressBar,
    sink: Option<ProgressSink>,
    label: String,
}

impl Progress {
    pub fn inc(&self, n: u64) {
        self.bar.inc(n);
        if let Some(sink) = &self.sink {
            sink(&self.label, self.bar.position(), self.len(), false);
        }
    }
    pub fn position(&self) -> u64 {
        self.bar.position()
    }
    fn len(&self) -> u64 {
        self.bar.length().unwrap_or(0)
    }
    pub fn set_message(&self, message: String) {
        self.bar.set_message(message);
    }
    /// Runs `f` (which prints) without the bar drawn over it.
    pub fn suspend<R>(&self, f: impl FnOnce() -> R) -> R {
        self.bar.suspend(f)
    }
    pub fn finish_and_clear(&self) {
        self.bar.finish_and_clear();
        if let Some(sink) = &self.sink {
            sink(&self.label, self.bar.position(), self.len(), true);
        }
    }
}

/// A progress bar in gilab's style (hidden when `quiet`; through the sink when one is set).
pub fn progress_bar(len: u64, prefix: &str, quiet: bool) -> Progress {
    let sink = if quiet {
        None
    } else {
        PROGRESS_SINK
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    };
    let bar = if quiet || sink.is_some() {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(len)
    };
    // A hidden bar keeps its length and position: the sink reads them.
    bar.set_length(len);
    bar.set_style(
        ProgressStyle::with_template(
            "{prefix:>10} [{bar:30}] {pos}/{len} frames {elapsed_precise} eta {eta} {msg}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    bar.set_prefix(prefix.to_string());
    if let Some(sink) = &sink {
        sink(prefix, 0, len, false);
    }
    Progress {
        bar,
        sink,
        label: prefix.to_string(),
    }
}
