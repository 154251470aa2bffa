//! The viewer's model, without any UI: one scene and camera, one engine per technique entry
//! ("run"), a progressive reference for error, convergence curves, and the reactions to
//! preset loads, parameter edits, camera moves and file changes. Everything that can fail
//! is built aside first and swapped in only on success, so bad input never loses state.

use crate::compare::{self, heatmap, io, metrics, Image, Metrics};
use crate::gpu::{shaders::ShaderLibrary, Gpu};
use crate::jobs::{reference_key_for_camera, reference_setup};
use crate::preset::{DisplayMode, Layout, LoadedPreset, PaneSettings, TechniqueEntry};
use crate::render::{
    engine::{Engine, EngineSettings, FrameReport},
    RayCounts,
};
use crate::scene::{gpu_scene::GpuScene, Camera, Scene};
use anyhow::{Context, Result};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

/// One point of a convergence curve (cumulative since the last reset).
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct ConvergencePoint {
    pub frame: u32,
    pub gpu_ms: f64,
    pub rays_per_pixel: f64,
    pub mse: f64,
    pub rel_mse: f64,
}

/// One technique entry of the preset with its engine and what it last produced.
pub struct Run {
    pub entry: TechniqueEntry,
    pub engine: Engine,
    pub rays: RayCounts,
    pub last_frame: Option<FrameReport>,
    pub radiance: Option<Image>,
    pub variance: Option<Image>,
    /// The technique's debug buffer from the last frame (one vec4 per pixel).
    pub debug: Option<Vec<[f32; 4]>>,
    /// Per-pixel relMSE against the current reference and its mean metrics.
    pub error_map: Option<Vec<f32>>,
    pub error: Option<Metrics>,
    pub curve: Vec<ConvergencePoint>,
    /// Bumped whenever the images change (the UI re-uploads textures then).
    pub version: u64,
}

impl Run {
    fn new(
        gpu: &Arc<Gpu>,
        shaders: &ShaderLibrary,
        staged: &StagedScene,
        entry: TechniqueEntry,
        camera: Camera,
        preset: &LoadedPreset,
    ) -> Result<Run> {
        let engine = Engine::for_entry(
            gpu.clone(),
            shaders.clone(),
            staged.scene.clone(),
            staged.gpu_scene.clone(),
            &entry,
            EngineSettings {
                extent: preset.preset.render.size,
                seed: preset.preset.render.seed,
                camera,
            },
        )?;
        Ok(Run {
            entry,
            engine,
            rays: RayCounts::default(),
            last_frame: None,
            radiance: None,
            variance: None,
            debug: None,
            error_map: None,
            error: None,
            curve: Vec::new(),
            version: 0,
        })
    }

    pub fn label(&self) -> &str {
        self.entry.display_name()
    }

    /// Rays per pixel per frame measured since the last reset.
    pub fn measured_rays_per_pixel(&self) -> Option<f64> {
        self.engine.rays_per_pixel_per_frame(&self.rays)
    }

    fn reset(&mut self) {
        self.engine.reset();
        self.rays = RayCounts::default();
        self.last_frame = None;
        self.curve.clear();
        self.error = None;
        self.error_map = None;
    }

    /// Renders one frame and reads back what the views need.
    /// `want_debug`: a visible pane shows one of the technique's debug views, so its debug
    /// buffer is read back too (otherwise that readback is skipped).
    fn render_frame(&mut self, reference: Option<&Image>, want_debug: bool) -> Result<()> {
        let report = self.engine.render_frame()?;
        let (radiance, variance) = self.engine.read_output_and_variance()?;
        self.variance = variance;
        self.debug = if want_debug {
            self.engine.read_debug()?
        } else {
            None
        };
        self.rays = self.engine.ray_counts()?;
        let pixels = (radiance.width * radiance.height) as f64;
        if let Some(r) = reference {
            let m = metrics::compare(&radiance, r)?;
            self.error_map = Some(metrics::rel_mse_map(&radiance, r));
            self.error = Some(m);
            self.curve.push(ConvergencePoint {
                frame: self.engine.frame_index,
                gpu_ms: self.engine.total_gpu_ms,
                rays_per_pixel: self.rays.total() as f64 / pixels,
                mse: m.mse,
                rel_mse: m.rel_mse,
            });
        }
        self.radiance = Some(radiance);
        self.last_frame = Some(report);
        self.version += 1;
        Ok(())
    }
}

/// Where the reference image for errors comes from.
#[derive(Clone, Debug, PartialEq)]
pub enum ReferenceSource {
    /// Loaded from `gilab reference`'s cache (same key: scene, camera, size, spp, seed, params).
    Cached(PathBuf),
    /// Being rendered progressively here; written to the cache when done.
    Rendering,
    Done,
}

/// The reference path tracer at the viewer's camera, rendered progressively (or loaded).
pub struct ReferenceRun {
    pub engine: Engine,
    pub image: Option<Image>,
    pub target_spp: u32,
    pub source: ReferenceSource,
    cache_file: PathBuf,
}

impl ReferenceRun {
    pub fn done(&self) -> bool {
        !matches!(self.source, ReferenceSource::Rendering)
    }
    pub fn samples(&self) -> u32 {
        match self.source {
            ReferenceSource::Rendering => self.engine.samples,
            _ => self.target_spp,
        }
    }
    /// 0..1 for the progress bar.
    pub fn progress(&self) -> f32 {
        (self.samples() as f32 / self.target_spp.max(1) as f32).min(1.0)
    }

    fn restart(&mut self, cache_dir: &Path, preset: &LoadedPreset) {
        let key = reference_key_for_camera(preset, &self.engine.camera);
        self.cache_file = cache_dir.join(format!("{key}.exr"));
        self.engine.reset();
        self.image = None;
        self.source = ReferenceSource::Rendering;
        if let Ok(img) = io::read_exr(&self.cache_file) {
            if [img.width, img.height] == self.engine.extent {
                self.image = Some(img);
                self.source = ReferenceSource::Cached(self.cache_file.clone());
            }
        }
    }

    fn render_frame(&mut self) -> Result<()> {
        self.engine.render_frame()?;
        self.image = Some(self.engine.read_output()?);
        if self.engine.samples >= self.target_spp {
            self.source = ReferenceSource::Done;
            if let (Some(dir), Some(img)) = (self.cache_file.parent(), &self.image) {
                // A cache that cannot be written only costs a re-render next time.
                let _ = std::fs::create_dir_all(dir);
                if let Err(e) = io::write_exr(&self.cache_file, img) {
                    log::warn!("reference cache not written: {e:#}");
                }
            }
        }
        Ok(())
    }
}

/// Scene and its GPU upload, shared by every run.
struct StagedScene {
    scene: Arc<Scene>,
    gpu_scene: Arc<GpuScene>,
}

/// A pane: which run it shows and how.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pane {
    pub run: usize,
    pub display: DisplayMode,
    /// Which of the technique's debug views, with `DisplayMode::Debug`.
    pub debug: usize,
}

/// Everything that a preset determines, built aside and swapped in whole.
struct Loaded {
    preset: LoadedPreset,
    scene: Arc<Scene>,
    runs: Vec<Run>,
    reference: ReferenceRun,
    camera: Camera,
}

pub struct Session {
    pub gpu: Arc<Gpu>,
    pub shaders: ShaderLibrary,
    pub preset: LoadedPreset,
    pub scene: Arc<Scene>,
    pub runs: Vec<Run>,
    pub reference: ReferenceRun,
    pub camera: Camera,
    pub layout: Layout,
    pub panes: Vec<Pane>,
    /// Wipe position across the image, 0..1.
    pub wipe: f32,
    pub paused: bool,
    /// Where the reference cache lives (the CLI's default, so both share it).
    pub cache_dir: PathBuf,
    /// Problems to show until fixed, by source ("shaders", "preset", "scene", run label).
    pub errors: BTreeMap<String, String>,
    /// Recent events, newest last (reloads, saves, errors).
    pub log: Vec<String>,
    next_run: usize,
}

/// Most runs one frame may render before the UI gets the thread back.
const MAX_FRAMES_PER_STEP: usize = 16;

impl Session {
    pub fn new(
        gpu: Arc<Gpu>,
        shaders: ShaderLibrary,
        preset: LoadedPreset,
        cache_dir: PathBuf,
    ) -> Result<Session> {
        let loaded = Self::build(&gpu, &shaders, preset, None, &cache_dir)?;
        let mut s = Session {
            gpu,
            shaders,
            preset: loaded.preset.clone(),
            scene: loaded.scene.clone(),
            runs: Vec::new(),
            reference: loaded.reference,
            camera: loaded.camera,
            layout: Layout::default(),
            panes: Vec::new(),
            wipe: 0.5,
            paused: false,
            cache_dir,
            errors: BTreeMap::new(),
            log: Vec::new(),
            next_run: 0,
        };
        s.runs = loaded.runs;
        s.apply_view_settings();
        Ok(s)
    }

    /// Builds scene, runs and reference for a preset without touching the current session.
    fn build(
        gpu: &Arc<Gpu>,
        shaders: &ShaderLibrary,
        preset: LoadedPreset,
        camera: Option<Camera>,
        cache_dir: &Path,
    ) -> Result<Loaded> {
        anyhow::ensure!(
            !preset.preset.techniques.is_empty(),
            "the preset lists no techniques"
        );
        let scene = preset.load_scene()?;
        scene.validate()?;
        let camera = camera.unwrap_or_else(|| preset.camera(&scene));
        let staged = StagedScene {
            gpu_scene: Arc::new(GpuScene::upload(gpu, &scene)),
            scene: Arc::new(scene),
        };
        let runs = preset
            .preset
            .techniques
            .iter()
            .map(|e| Run::new(gpu, shaders, &staged, e.clone(), camera, &preset))
            .collect::<Result<Vec<_>>>()?;
        // One sample per frame: the shortest unit of work, so the UI stays responsive.
        let setup = reference_setup(&preset);
        let mut ref_preset = preset.clone();
        ref_preset.preset.render.seed = setup.seed;
        let ref_entry = TechniqueEntry {
            params: setup.params,
            ..TechniqueEntry::new("reference")
        };
        let ref_run = Run::new(gpu, shaders, &staged, ref_entry, camera, &ref_preset)?;
        let mut reference = ReferenceRun {
            engine: ref_run.engine,
            image: None,
            target_spp: setup.spp,
            source: ReferenceSource::Rendering,
            cache_file: PathBuf::new(),
        };
        reference.restart(cache_dir, &preset);
        Ok(Loaded {
            preset,
            scene: staged.scene,
            runs,
            reference,
            camera,
        })
    }

    fn apply_view_settings(&mut self) {
        let view = &self.preset.preset.view;
        self.layout = view.layout;
        let n = self.runs.len();
        self.panes = (0..4)
            .map(|i| {
                let p = view.panes.get(i).copied().unwrap_or(PaneSettings {
                    technique: i % n.max(1),
                    display: DisplayMode::Radiance,
                    debug: 0,
                });
                Pane {
                    run: p.technique.min(n.saturating_sub(1)),
                    display: p.display,
                    debug: p.debug,
                }
            })
            .collect();
    }

    fn swap_in(&mut self, loaded: Loaded) {
        self.preset = loaded.preset;
        self.scene = loaded.scene;
        self.runs = loaded.runs;
        self.reference = loaded.reference;
        self.camera = loaded.camera;
        self.next_run = 0;
        self.apply_view_settings();
    }

    /// Replaces the session with a preset; on any error the session is unchanged and the
    /// error is returned (and shown).
    pub fn apply_preset(&mut self, preset: LoadedPreset) -> Result<()> {
        let label = preset
            .path
            .as_ref()
            .map_or("<default>".into(), |p| p.display().to_string());
        match Self::build(&self.gpu, &self.shaders, preset, None, &self.cache_dir) {
            Ok(loaded) => {
                self.swap_in(loaded);
                self.errors.remove("preset");
                self.note(format!("loaded preset {label}"));
                Ok(())
            }
            Err(e) => {
                let msg = format!("{e:#}");
                self.errors.insert("preset".into(), msg.clone());
                self.note(format!("preset not loaded: {msg}"));
                Err(e)
            }
        }
    }

    pub fn load_preset_file(&mut self, path: &Path) -> Result<()> {
        match LoadedPreset::load(path) {
            Ok(p) => self.apply_preset(p),
            Err(e) => {
                let msg = format!("{e:#}");
                self.errors.insert("preset".into(), msg.clone());
                self.note(format!("preset not loaded: {msg}"));
                Err(e)
            }
        }
    }

    /// The preset as the viewer shows it now (camera, parameters, budgets, layout, panes).
    pub fn current_preset(&self) -> LoadedPreset {
        let mut p = self.preset.clone();
        p.preset.camera = Some(self.camera);
        p.preset.techniques = self
            .runs
            .iter()
            .map(|r| TechniqueEntry {
                params: r.engine.technique.params(),
                ..r.entry.clone()
            })
            .collect();
        p.preset.view.layout = self.layout;
        p.preset.view.panes = self
            .panes
            .iter()
            .map(|p| PaneSettings {
                technique: p.run,
                display: p.display,
                debug: p.debug,
            })
            .collect();
        p
    }

    pub fn save_preset(&mut self, path: &Path) -> Result<()> {
        let text = self.current_preset().to_toml()?;
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir)?;
        }
        std::fs::write(path, &text).with_context(|| format!("writing {}", path.display()))?;
        self.note(format!("saved preset {}", path.display()));
        Ok(())
    }

    pub fn note(&mut self, msg: String) {
        log::info!("{msg}");
        self.log.push(msg);
        let excess = self.log.len().saturating_sub(50);
        self.log.drain(..excess);
    }

    /// Runs shown by the current layout.
    pub fn visible_runs(&self) -> Vec<usize> {
        let mut v: Vec<usize> = self.panes[..self.layout.pane_count()]
            .iter()
            .map(|p| p.run)
            .collect();
        v.sort_unstable();
        v.dedup();
        v
    }

    /// Moves the camera: every run and the reference start over (history is invalid).
    pub fn set_camera(&mut self, camera: Camera) {
        if camera == self.camera {
            return;
        }
        self.camera = camera;
        for r in &mut self.runs {
            r.engine.camera = camera;
            r.reset();
        }
        self.reference.engine.camera = camera;
        self.reference.restart(&self.cache_dir, &self.preset);
    }

    /// A new run on the loaded scene at the current camera.
    fn new_run(&self, entry: TechniqueEntry) -> Result<Run> {
        let staged = StagedScene {
            scene: self.scene.clone(),
            gpu_scene: self.reference.engine.gpu_scene.clone(),
        };
        Run::new(
            &self.gpu,
            &self.shaders,
            &staged,
            entry,
            self.camera,
            &self.preset,
        )
    }

    /// Replaces a run's technique, in the same place, with default parameters.
    pub fn set_run_technique(&mut self, run: usize, name: &str) -> Result<()> {
        self.runs[run] = self.new_run(TechniqueEntry::new(name))?;
        Ok(())
    }

    /// Adds another entry (e.g. the same technique with other parameters) and returns its index.
    pub fn add_run(&mut self, name: &str) -> Result<usize> {
        let mut entry = TechniqueEntry::new(name);
        let same = self.runs.iter().filter(|r| r.entry.name == name).count();
        if same > 0 {
            entry.label = Some(format!("{name} #{}", same + 1));
        }
        let run = self.new_run(entry)?;
        self.runs.push(run);
        Ok(self.runs.len() - 1)
    }

    /// Starts a run's history over (the panel's Reset button).
    pub fn reset_run(&mut self, run: usize) {
        self.runs[run].reset();
    }

    /// Applies parameters to a run; errors leave it as it was.
    pub fn set_run_params(&mut self, run: usize, params: &toml::Table) -> Result<()> {
        let r = &mut self.runs[run];
        let before = r.engine.technique.params();
        if let Err(e) = r.engine.set_params(params) {
            // Restore what worked (set_params may have applied some keys).
            let _ = r.engine.set_params(&before);
            return Err(e);
        }
        r.entry.params = r.engine.technique.params();
        r.reset();
        Ok(())
    }

    /// The ray-budget slider: rays per pixel per frame, mapped by the technique to its knobs.
    /// Errors leave the run as it was.
    pub fn set_ray_budget(&mut self, run: usize, rays_per_pixel: f64) -> Result<()> {
        let r = &mut self.runs[run];
        let measured = r.measured_rays_per_pixel();
        let before = r.engine.technique.params();
        if let Err(e) = r.engine.apply_ray_budget(rays_per_pixel, measured) {
            let _ = r.engine.set_params(&before);
            return Err(e);
        }
        r.entry.budget = Some(rays_per_pixel);
        r.entry.params = r.engine.technique.params();
        r.reset();
        Ok(())
    }

    /// Renders frames of the visible runs (round robin) and of the reference while it
    /// converges, until `budget_ms` of wall time is spent (at least one frame).
    /// Returns the number of frames rendered.
    pub fn step(&mut self, budget_ms: f64) -> usize {
        if self.paused || self.runs.is_empty() {
            return 0;
        }
        let start = Instant::now();
        let mut order: Vec<Option<usize>> = self.visible_runs().into_iter().map(Some).collect();
        if !self.reference.done() {
            order.push(None);
        }
        let mut frames = 0;
        while frames < MAX_FRAMES_PER_STEP {
            let slot = order[self.next_run % order.len()];
            self.next_run = self.next_run.wrapping_add(1);
            let result = match slot {
                Some(i) => {
                    let want_debug = self.panes[..self.layout.pane_count()]
                        .iter()
                        .any(|p| p.run == i && p.display == DisplayMode::Debug);
                    let reference = self.reference.image.as_ref();
                    self.runs[i].render_frame(reference, want_debug)
                }
                None => self.reference.render_frame(),
            };
            let key = slot.map_or("reference".to_string(), |i| {
                self.runs[i].label().to_string()
            });
            match result {
                Ok(()) => {
                    self.errors.remove(&key);
                }
                Err(e) => {
                    let msg = format!("{e:#}");
                    if self.errors.get(&key) != Some(&msg) {
                        self.note(format!("{key}: {msg}"));
                    }
                    self.errors.insert(key, msg);
                }
            }
            frames += 1;
            if start.elapsed().as_secs_f64() * 1e3 >= budget_ms {
                break;
            }
        }
        frames
    }

    /// Reacts to changed files: shaders rebuild the pipelines that import them (keeping the
    /// last good ones on error), the current preset or its glTF scene reloads.
    pub fn handle_changed_files(&mut self, paths: &[PathBuf]) {
        let mut changed_shaders = Vec::new();
        let mut reload_preset = false;
        let preset_file = self
            .preset
            .path
            .as_ref()
            .and_then(|p| p.canonicalize().ok());
        let scene_file = self.preset.scene_path().and_then(|p| p.canonicalize().ok());
        let shader_root = self.shaders.root().and_then(|p| p.canonicalize().ok());
        for p in paths {
            let canon = p.canonicalize().unwrap_or_else(|_| p.clone());
            if let Some(rel) = shader_root
                .as_ref()
                .and_then(|root| canon.strip_prefix(root).ok())
            {
                if rel.extension().is_some_and(|e| e == "wgsl") {
                    let rel = rel.to_string_lossy().replace('\\', "/");
                    if !changed_shaders.contains(&rel) {
                        changed_shaders.push(rel);
                    }
                }
            } else if Some(&canon) == preset_file.as_ref() || Some(&canon) == scene_file.as_ref() {
                reload_preset = true;
            }
        }
        if !changed_shaders.is_empty() {
            self.reload_shaders(&changed_shaders);
        }
        if reload_preset {
            if let Some(path) = self.preset.path.clone() {
                let _ = self.load_preset_file(&path);
            }
        }
    }

    /// Rebuilds the pipelines whose entry files import any of `changed` (paths under shaders/).
    pub fn reload_shaders(&mut self, changed: &[String]) {
        let mut entries = Vec::new();
        for c in changed {
            match self.shaders.dependents(c) {
                Ok(d) => entries.extend(d),
                Err(e) => {
                    self.errors.insert("shaders".into(), e.to_string());
                    return;
                }
            }
        }
        entries.sort();
        entries.dedup();
        let mut failures = Vec::new();
        let mut rebuilt = 0;
        for r in &mut self.runs {
            if r.engine.uses_any_shader(&entries) {
                match r.engine.rebuild() {
                    Ok(()) => {
                        r.reset();
                        rebuilt += 1;
                    }
                    Err(e) => failures.push(format!("{e:#}")),
                }
            }
        }
        if self.reference.engine.uses_any_shader(&entries) {
            match self.reference.engine.rebuild() {
                Ok(()) => {
                    // Cached and partial references came from the old shader: render anew.
                    self.reference.engine.reset();
                    self.reference.image = None;
                    self.reference.source = ReferenceSource::Rendering;
                    rebuilt += 1;
                }
                Err(e) => failures.push(format!("{e:#}")),
            }
        }
        if failures.is_empty() {
            self.errors.remove("shaders");
            self.note(format!(
                "reloaded {} ({} pipelines rebuilt)",
                changed.join(", "),
                rebuilt
            ));
        } else {
            failures.dedup();
            let msg = failures.join("\n");
            self.note(format!(
                "shader error, keeping the last good pipelines: {msg}"
            ));
            self.errors.insert("shaders".into(), msg);
        }
    }

    /// The per-pixel scalars behind a heatmap pane (None for radiance): variance, relMSE,
    /// samples per pixel or a channel of the technique's debug buffer.
    pub fn pane_values(&self, pane: &Pane) -> Option<Vec<f32>> {
        let run = self.runs.get(pane.run)?;
        match pane.display {
            DisplayMode::Radiance => None,
            DisplayMode::Variance => run.variance.as_ref().map(heatmap::variance_scalar),
            DisplayMode::Error => run.error_map.clone(),
            DisplayMode::Samples => {
                let img = run.radiance.as_ref()?;
                Some(vec![
                    run.engine.samples as f32;
                    (img.width * img.height) as usize
                ])
            }
            DisplayMode::Debug => {
                let view = run
                    .engine
                    .technique
                    .debug_views()
                    .into_iter()
                    .nth(pane.debug)?;
                let data = run.debug.as_ref()?;
                let pixels = (run.engine.extent[0] * run.engine.extent[1]) as usize;
                Some(crate::render::debug_channel(data, pixels, view.channel))
            }
        }
    }

    /// The display image of a pane: RGBA8 pixels and, for heatmaps, the log10 range shown.
    pub fn pane_pixels(&self, pane: &Pane) -> Option<(Vec<u8>, Option<LogRange>)> {
        let run = self.runs.get(pane.run)?;
        if pane.display == DisplayMode::Radiance {
            let tonemap = &self.preset.preset.tonemap;
            return run.radiance.as_ref().map(|img| {
                (
                    compare::tonemap::to_srgb8(img, tonemap.operator, tonemap.exposure),
                    None,
                )
            });
        }
        let values = self.pane_values(pane)?;
        let is_id = pane.display == DisplayMode::Debug
            && run
                .engine
                .technique
                .debug_views()
                .get(pane.debug)
                .is_some_and(|v| v.is_id);
        if is_id {
            return Some((heatmap::id_colours(&values), None));
        }
        let range = match pane.display {
            DisplayMode::Samples => (0.0, (run.engine.samples.max(1) as f32).log10().max(1.0)),
            _ => heatmap::log_range(&values).unwrap_or((-6.0, 0.0)),
        };
        Some((heatmap::to_rgba(&values, range.0, range.1), Some(range)))
    }

    /// HDR value, variance and error of one pixel of a run (the pixel inspector).
    pub fn inspect(&self, run: usize, x: u32, y: u32) -> Option<PixelInfo> {
        let r = self.runs.get(run)?;
        let img = r.radiance.as_ref()?;
        if x >= img.width || y >= img.height {
            return None;
        }
        let i = (y * img.width + x) as usize;
        Some(PixelInfo {
            radiance: img.pixel(x, y),
            variance: r.variance.as_ref().map(|v| {
                let p = v.pixel(x, y);
                (p[0] + p[1] + p[2]) / 3.0
            }),
            rel_mse: r.error_map.as_ref().map(|e| e[i]),
            reference: self.reference.image.as_ref().map(|im| im.pixel(x, y)),
        })
    }
}

/// A heatmap's displayed range: (log10 low, log10 high).
pub type LogRange = (f32, f32);

/// What the pixel inspector shows for one pane.
#[derive(Clone, Copy, Debug)]
pub struct PixelInfo {
    pub radiance: [f32; 3],
    pub variance: Option<f32>,
    pub rel_mse: Option<f32>,
    pub reference: Option<[f32; 3]>,
}
