//! The viewer's model, without any UI: one scene and camera, one engine per technique entry
//! ("run"), a progressive reference for error, convergence curves, and the reactions to
//! preset loads, parameter edits, camera moves and file changes. Everything that can fail
//! is built aside first and swapped in only on success, so bad input never loses state.

use crate::compare::display::{
    DisplayKind, DisplaySettings, DisplaySource, DisplayTarget, GpuCompare, MetricsReduction,
    PixelProbe,
};
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

/// One technique entry of the preset with its engine and what it last produced. Images stay
/// on the GPU: the panes are drawn from the engine's buffers (`compare::display`), errors come
/// from a GPU reduction read back a frame or more late; `cpu_images` reads them on demand.
pub struct Run {
    pub entry: TechniqueEntry,
    pub engine: Engine,
    pub rays: RayCounts,
    pub last_frame: Option<FrameReport>,
    /// The latest mean errors against the reference (from the asynchronous reduction).
    pub error: Option<Metrics>,
    pub curve: Vec<ConvergencePoint>,
    /// Bumped whenever a frame is submitted (the panes display again then).
    pub version: u64,
    metrics: MetricsReduction,
    /// Per completed frame: cumulative GPU ms and rays per pixel, until its error arrives.
    costs: BTreeMap<u32, (f64, f64)>,
    errors_by_frame: BTreeMap<u32, Metrics>,
    gpu_ms_cum: f64,
    /// The engine frame the curve starts at: the last reset, or the last pose the scene's
    /// motion gave it (the accumulation restarts there, and so does the curve).
    curve_from: u32,
    pub probe: PixelProbe,
    /// The inspected pixel's debug channels: one probe per plane of the technique's debug
    /// buffer (made when first asked for; the buffer's planes are one vec4 per pixel each).
    debug_probes: Vec<PixelProbe>,
}

/// A run's images read back to the CPU (screenshots, tests): what the CLI's files use.
pub struct CpuImages {
    pub radiance: Image,
    pub variance: Option<Image>,
    pub debug: Option<Vec<[f32; 4]>>,
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
            metrics: MetricsReduction::new(gpu, engine.extent),
            probe: PixelProbe::new(gpu, 3),
            debug_probes: Vec::new(),
            engine,
            rays: RayCounts::default(),
            last_frame: None,
            error: None,
            curve: Vec::new(),
            version: 0,
            costs: BTreeMap::new(),
            errors_by_frame: BTreeMap::new(),
            gpu_ms_cum: 0.0,
            curve_from: 0,
        })
    }

    pub fn label(&self) -> &str {
        self.entry.display_name()
    }

    /// Rays per pixel per frame measured since the last reset.
    pub fn measured_rays_per_pixel(&self) -> Option<f64> {
        // The counts are the last completed frame's (cumulative since the reset), which can
        // trail the frames submitted by one or two: divide by the frames they cover, not by
        // the engine's frame count (that read 2/3 of a new budget's rays under load).
        let frames = self.last_frame.as_ref()?.frame_index + 1;
        let [w, h] = self.engine.extent;
        Some(self.rays.total() as f64 / (w as f64 * h as f64) / frames as f64)
    }

    fn reset(&mut self) {
        self.engine.reset();
        self.rays = RayCounts::default();
        self.last_frame = None;
        self.curve.clear();
        self.error = None;
        self.costs.clear();
        self.errors_by_frame.clear();
        self.gpu_ms_cum = 0.0;
        self.curve_from = 0;
        self.version += 1;
    }

    /// The scene moved to a new pose: the accumulated image starts over, so does the curve
    /// (frames and GPU time counted from here; errors of earlier frames still in flight are
    /// dropped).
    fn restart_curve(&mut self) {
        self.curve.clear();
        self.costs.clear();
        self.errors_by_frame.clear();
        self.error = None;
        self.gpu_ms_cum = 0.0;
        self.curve_from = self.engine.frame_index;
        self.version += 1;
    }

    /// Submits one frame (not waited for) and, when a reference is on the GPU and a readback
    /// slot is free, the reduction of its error; then collects what has arrived.
    fn render_frame(
        &mut self,
        compare: &GpuCompare,
        reference: Option<&wgpu::Buffer>,
    ) -> Result<()> {
        self.engine.submit_frame(None)?;
        let key = self.engine.frame_index - 1;
        if let Some(r) = reference {
            let gpu = self.engine.gpu.clone();
            let mut enc = gpu.device.create_command_encoder(&Default::default());
            let (mean, _) = self.engine.output_buffers();
            if compare.record_metrics(&gpu, &mut enc, mean, r, &mut self.metrics, key) {
                let submission =
                    gpu.submit("viewer: error metrics against the reference", enc.finish());
                GpuCompare::start_metrics_read(&mut self.metrics, &submission);
            }
        }
        self.version += 1;
        self.collect()
    }

    /// Takes in completed frames and errors (never waits) and extends the convergence curve.
    pub fn collect(&mut self) -> Result<()> {
        self.engine.poll_frames(false)?;
        let pixels = (self.engine.extent[0] * self.engine.extent[1]) as f64;
        for f in self.engine.take_completed() {
            if f.report.frame_index < self.curve_from {
                continue;
            }
            self.gpu_ms_cum += f.report.gpu_ms;
            self.costs.insert(
                f.report.frame_index,
                (self.gpu_ms_cum, f.rays.total() as f64 / pixels),
            );
            self.rays = f.rays;
            self.last_frame = Some(f.report);
        }
        self.probe.poll(&self.engine.gpu)?;
        for p in &mut self.debug_probes {
            p.poll(&self.engine.gpu)?;
        }
        for (frame, m) in self.metrics.poll(&self.engine.gpu)? {
            if frame < self.curve_from {
                continue;
            }
            self.errors_by_frame.insert(frame, m);
            self.error = Some(m);
        }
        let ready: Vec<u32> = self
            .errors_by_frame
            .keys()
            .copied()
            .filter(|k| self.costs.contains_key(k))
            .collect();
        for k in ready {
            let m = self.errors_by_frame.remove(&k).expect("listed");
            let (gpu_ms, rays_per_pixel) = self.costs[&k];
            self.curve.push(ConvergencePoint {
                frame: k + 1 - self.curve_from,
                gpu_ms,
                rays_per_pixel,
                mse: m.mse,
                rel_mse: m.rel_mse,
            });
            // Costs of frames before a scored one are no longer needed.
            self.costs.retain(|f, _| *f > k);
        }
        Ok(())
    }

    /// Reads the run's images back (blocking): the CPU path for screenshots and tests.
    pub fn cpu_images(&self, want_debug: bool) -> Result<CpuImages> {
        let (radiance, variance) = self.engine.read_output_and_variance()?;
        let debug = if want_debug {
            self.engine.read_debug()?
        } else {
            None
        };
        Ok(CpuImages {
            radiance,
            variance,
            debug,
        })
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

/// The reference path tracer at the viewer's camera, rendered progressively (or loaded). The
/// image lives on the GPU (`gpu_image`, copied from the engine after each of its frames); the
/// CPU copy exists once loaded from the cache or done (written to the cache then).
pub struct ReferenceRun {
    pub engine: Engine,
    pub image: Option<Image>,
    /// One vec4 per pixel; valid when `on_gpu`.
    pub gpu_image: wgpu::Buffer,
    pub on_gpu: bool,
    pub target_spp: u32,
    pub source: ReferenceSource,
    cache_file: PathBuf,
    /// The scene time the preset poses (its cached reference is of that pose only).
    preset_time: f32,
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

    /// The reference on the GPU, when there is one.
    pub fn buffer(&self) -> Option<&wgpu::Buffer> {
        self.on_gpu.then_some(&self.gpu_image)
    }

    /// Whether the scene stands at the preset's pose, which cached references are of.
    fn at_presets_pose(&self) -> bool {
        self.engine.scene.motion.is_none() || self.engine.scene_time == self.preset_time
    }

    fn restart(&mut self, cache_dir: &Path, preset: &LoadedPreset) {
        let key = reference_key_for_camera(preset, &self.engine.camera);
        self.cache_file = cache_dir.join(format!("{key}.exr"));
        self.engine.reset();
        self.image = None;
        self.on_gpu = false;
        self.source = ReferenceSource::Rendering;
        if !self.at_presets_pose() {
            return;
        }
        if let Ok(img) = io::read_exr(&self.cache_file) {
            if [img.width, img.height] == self.engine.extent {
                let px: Vec<[f32; 4]> = img
                    .rgb
                    .chunks_exact(3)
                    .map(|p| [p[0], p[1], p[2], 0.0])
                    .collect();
                self.engine
                    .gpu
                    .queue
                    .write_buffer(&self.gpu_image, 0, bytemuck::cast_slice(&px));
                self.on_gpu = true;
                self.image = Some(img);
                self.source = ReferenceSource::Cached(self.cache_file.clone());
            }
        }
    }

    /// Drops the current image (its shader changed): renders anew.
    fn invalidate(&mut self) {
        self.engine.reset();
        self.image = None;
        self.on_gpu = false;
        self.source = ReferenceSource::Rendering;
    }

    fn render_frame(&mut self) -> Result<()> {
        self.engine.render_frame()?;
        let gpu = self.engine.gpu.clone();
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        let (mean, _) = self.engine.output_buffers();
        enc.copy_buffer_to_buffer(mean, 0, &self.gpu_image, 0, mean.size());
        gpu.submit("viewer: reference image copy", enc.finish());
        self.on_gpu = true;
        if self.engine.samples >= self.target_spp {
            self.source = ReferenceSource::Done;
            let img = self.engine.read_output()?;
            if let (Some(dir), true) = (self.cache_file.parent(), self.at_presets_pose()) {
                // A cache that cannot be written only costs a re-render next time.
                let _ = std::fs::create_dir_all(dir);
                if let Err(e) = io::write_exr(&self.cache_file, &img) {
                    log::warn!("reference cache not written: {e:#}");
                }
            }
            self.image = Some(img);
        }
        Ok(())
    }

    /// The reference on the CPU: the cached or finished image, else the partial one read back.
    pub fn cpu_image(&self) -> Result<Option<Image>> {
        if let Some(img) = &self.image {
            return Ok(Some(img.clone()));
        }
        if !self.on_gpu {
            return Ok(None);
        }
        let [w, h] = self.engine.extent;
        let px: Vec<[f32; 4]> =
            crate::gpu::readback::read_buffer(&self.engine.gpu, &self.gpu_image, (w * h) as usize)?;
        Ok(Some(Image::from_rgba(w, h, &px)))
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
    /// The display and error passes on the GPU (shared by every pane and run).
    pub compare: GpuCompare,
    next_run: usize,
    /// The scene clock every pane shares when the scene moves: scene seconds, advanced by
    /// wall time × `time_scale` while `playing` (paused with Space, set by the time slider).
    pub scene_time: f32,
    pub playing: bool,
    last_tick: Option<Instant>,
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
        let compare = GpuCompare::new(&gpu, &shaders)?;
        let mut s = Session {
            compare,
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
            scene_time: 0.0,
            playing: false,
            last_tick: None,
        };
        s.runs = loaded.runs;
        s.apply_view_settings();
        s.start_clock();
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
        let [w, h] = ref_run.engine.extent;
        let mut reference = ReferenceRun {
            gpu_image: crate::render::pipelines::storage_buffer(
                gpu,
                "viewer reference",
                w as u64 * h as u64 * 16,
            ),
            on_gpu: false,
            engine: ref_run.engine,
            image: None,
            target_spp: setup.spp,
            source: ReferenceSource::Rendering,
            cache_file: PathBuf::new(),
            preset_time: staged.scene.posed_at.unwrap_or(0.0),
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
        self.start_clock();
    }

    /// The scene's playback speed (`[scene] time_scale`; 0 without motion) and clip length.
    pub fn playback(&self) -> Option<(f32, f32)> {
        let m = self.scene.motion.as_ref()?;
        Some((m.time_scale, m.duration()))
    }

    /// The shared clock at the preset's pose; every engine follows it rather than its frames.
    fn start_clock(&mut self) {
        self.scene_time = self.scene.posed_at.unwrap_or(0.0);
        self.playing = self.playback().is_some_and(|(scale, _)| scale != 0.0);
        self.last_tick = None;
        let has_motion = self.scene.motion.is_some();
        for r in &mut self.runs {
            r.engine.external_clock = has_motion;
        }
        self.reference.engine.external_clock = has_motion;
    }

    /// Poses every pane and the reference at scene time `t` (the reference starts again).
    pub fn set_scene_time(&mut self, t: f32) {
        self.scene_time = t;
        let mut failed = Vec::new();
        for r in &mut self.runs {
            if r.engine.scene_time == t {
                continue;
            }
            match r.engine.set_scene_time(t) {
                Ok(()) => r.restart_curve(),
                Err(e) => failed.push(format!("{}: {e:#}", r.label())),
            }
        }
        if self.reference.engine.scene_time != t {
            match self.reference.engine.set_scene_time(t) {
                Ok(()) => self.reference.invalidate(),
                Err(e) => failed.push(format!("reference: {e:#}")),
            }
        }
        for msg in failed {
            self.note(msg);
        }
    }

    /// Advances the shared clock by the wall time since the last call while playing.
    fn tick(&mut self) {
        let now = Instant::now();
        let last = self.last_tick.replace(now);
        let Some((scale, _)) = self.playback() else {
            return;
        };
        if !self.playing || scale == 0.0 {
            return;
        }
        // At most a tenth of a second a step, so a slow frame does not jump the scene.
        let dt = last.map_or(0.0, |l| (now - l).as_secs_f32().min(0.1));
        if dt > 0.0 {
            let mut t = self.scene_time + dt * scale;
            // `[scene] play_until`: the clock stops there (the slider still scrubs past it).
            if let Some(u) = self.scene.motion.as_ref().and_then(|m| m.play_until) {
                if scale > 0.0 && self.scene_time <= u {
                    t = t.min(u);
                }
            }
            if t != self.scene_time {
                self.set_scene_time(t);
            }
        }
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
        // The scene as the reference holds it: at the shared clock's pose.
        let staged = StagedScene {
            scene: self.reference.engine.scene.clone(),
            gpu_scene: self.reference.engine.gpu_scene.clone(),
        };
        let mut run = Run::new(
            &self.gpu,
            &self.shaders,
            &staged,
            entry,
            self.camera,
            &self.preset,
        )?;
        run.engine.external_clock = self.scene.motion.is_some();
        Ok(run)
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
        let before = r.engine.technique.param_set().changes();
        if let Err(e) = r.engine.set_params_from_table(params) {
            // Restore what worked (set_params may have applied some keys).
            let _ = r.engine.set_params(&before);
            return Err(e);
        }
        r.entry.params = r.engine.technique.params();
        r.reset();
        Ok(())
    }

    /// The denoise checkbox: the shared denoiser on or off for a run (its entry's `denoise`).
    /// Errors leave the run as it was.
    pub fn set_run_denoise(&mut self, run: usize, on: bool) -> Result<()> {
        let r = &mut self.runs[run];
        r.engine.set_denoise(on)?;
        r.entry.denoise = on;
        r.reset();
        Ok(())
    }

    /// The ray-budget slider: rays per pixel per frame, mapped by the technique to its knobs.
    /// Errors leave the run as it was.
    pub fn set_ray_budget(&mut self, run: usize, rays_per_pixel: f64) -> Result<()> {
        let r = &mut self.runs[run];
        let measured = r.measured_rays_per_pixel();
        let before = r.engine.technique.param_set().changes();
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
            self.last_tick = None;
            return 0;
        }
        self.tick();
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
                    let reference = self.reference.buffer();
                    self.runs[i].render_frame(&self.compare, reference)
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
        self.collect();
        frames
    }

    /// Takes in every run's completed frames and errors without waiting.
    pub fn collect(&mut self) {
        for i in 0..self.runs.len() {
            if let Err(e) = self.runs[i].collect() {
                let key = self.runs[i].label().to_string();
                self.errors.insert(key, format!("{e:#}"));
            }
        }
    }

    /// Waits for every run's frames in flight and their errors (tests, screenshots).
    pub fn finish(&mut self) -> Result<()> {
        for r in &mut self.runs {
            r.engine.finish_frames()?;
        }
        self.gpu.wait()?;
        for r in &mut self.runs {
            r.collect()?;
        }
        Ok(())
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
                    self.reference.invalidate();
                    rebuilt += 1;
                }
                Err(e) => failures.push(format!("{e:#}")),
            }
        }
        if entries.iter().any(|e| e.starts_with("compare/")) {
            match GpuCompare::new(&self.gpu, &self.shaders) {
                Ok(c) => {
                    self.compare = c;
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

    /// The per-pixel scalars behind a heatmap pane (None for radiance), read back to the CPU:
    /// variance, relMSE, samples per pixel or a channel of the technique's debug buffer.
    pub fn pane_values(&self, pane: &Pane) -> Option<Vec<f32>> {
        let run = self.runs.get(pane.run)?;
        let images = run.cpu_images(pane.display == DisplayMode::Debug).ok()?;
        self.values_of(pane, &images)
    }

    fn values_of(&self, pane: &Pane, images: &CpuImages) -> Option<Vec<f32>> {
        let run = self.runs.get(pane.run)?;
        let img = &images.radiance;
        match pane.display {
            DisplayMode::Radiance => None,
            DisplayMode::Variance => images.variance.as_ref().map(heatmap::variance_scalar),
            DisplayMode::Error => {
                let r = self.reference.cpu_image().ok()??;
                Some(metrics::rel_mse_map(img, &r))
            }
            DisplayMode::Samples => Some(vec![
                run.engine.samples as f32;
                (img.width * img.height) as usize
            ]),
            DisplayMode::Debug => {
                let view = self.debug_view(pane)?;
                let data = images.debug.as_ref()?;
                let pixels = (run.engine.extent[0] * run.engine.extent[1]) as usize;
                Some(crate::render::debug_channel(data, pixels, view.channel))
            }
        }
    }

    /// The display image of a pane computed on the CPU (the path the CLI's files use; the
    /// viewer draws the GPU one): RGBA8 pixels, the radiance and, for heatmaps, the range.
    pub fn pane_pixels(&self, pane: &Pane) -> Option<(Vec<u8>, Image, Option<LogRange>)> {
        let run = self.runs.get(pane.run)?;
        let images = run.cpu_images(pane.display == DisplayMode::Debug).ok()?;
        if pane.display == DisplayMode::Radiance {
            let tonemap = &self.preset.preset.tonemap;
            let rgba = compare::tonemap::to_srgb8(&images.radiance, tonemap);
            return Some((rgba, images.radiance, None));
        }
        let values = self.values_of(pane, &images)?;
        let is_id = pane.display == DisplayMode::Debug
            && run
                .engine
                .technique
                .debug_views()
                .get(pane.debug)
                .is_some_and(|v| v.is_id);
        if is_id {
            return Some((heatmap::id_colours(&values), images.radiance, None));
        }
        let range = match pane.display {
            DisplayMode::Samples => (0.0, (run.engine.samples.max(1) as f32).log10().max(1.0)),
            _ => heatmap::log_range(&values).unwrap_or((-6.0, 0.0)),
        };
        Some((
            heatmap::to_rgba(&values, range.0, range.1),
            images.radiance,
            Some(range),
        ))
    }

    /// The technique debug view a pane shows.
    fn debug_view(&self, pane: &Pane) -> Option<crate::render::DebugView> {
        let run = self.runs.get(pane.run)?;
        run.engine
            .technique
            .debug_views()
            .into_iter()
            .nth(pane.debug)
    }

    /// The GPU display settings of a pane (`range`: None for the histogram's).
    pub fn display_settings(&self, pane: &Pane) -> Option<DisplaySettings> {
        self.runs.get(pane.run)?;
        let tonemap = &self.preset.preset.tonemap;
        let (kind, channel) = match pane.display {
            DisplayMode::Radiance => (DisplayKind::Radiance, 0),
            DisplayMode::Variance => (DisplayKind::Variance, 0),
            DisplayMode::Error => (DisplayKind::Error, 0),
            DisplayMode::Samples => (DisplayKind::Samples, 0),
            DisplayMode::Debug => {
                let view = self.debug_view(pane)?;
                let kind = if view.is_id {
                    DisplayKind::DebugId
                } else {
                    DisplayKind::DebugValue
                };
                (kind, view.channel)
            }
        };
        Some(DisplaySettings {
            kind,
            tonemap: *tonemap,
            channel,
            range: None,
        })
    }

    /// Records a pane's display pass on the GPU into `target`; false when it cannot show yet.
    pub fn record_pane_display(
        &self,
        enc: &mut wgpu::CommandEncoder,
        pane: &Pane,
        settings: &DisplaySettings,
        target: &mut DisplayTarget,
    ) -> bool {
        let Some(run) = self.runs.get(pane.run) else {
            return false;
        };
        if run.engine.frame_index == 0 {
            return false;
        }
        let (mean, m2) = run.engine.output_buffers();
        let src = DisplaySource {
            mean,
            m2,
            reference: self.reference.buffer(),
            debug: run.engine.technique.debug_buffer(),
            extent: run.engine.extent,
            samples: run.engine.samples,
        };
        self.compare
            .record_display(&self.gpu, enc, &src, settings, target)
    }

    /// Asks for one pixel of every visible run (and the reference) without waiting; the values
    /// arrive a frame or more later in each run's `probe`.
    pub fn request_pixel(&mut self, x: u32, y: u32) {
        let mut enc = self.gpu.device.create_command_encoder(&Default::default());
        let mut asked = Vec::new();
        let mut debug_asked = false;
        let reference = &self.reference.gpu_image;
        for i in self.visible_runs() {
            let r = &mut self.runs[i];
            let [w, h] = r.engine.extent;
            if x >= w || y >= h {
                continue;
            }
            let (mean, m2) = r.engine.output_buffers();
            let (mean, m2) = (mean.clone(), m2.clone());
            let index = (y * w + x) as u64;
            if r.probe
                .record(&mut enc, (x, y), index, &[&mean, &m2, reference])
            {
                asked.push(i);
            }
            // The debug planes too: plane k holds pixel `index` at k × pixels.
            if let Some(debug) = r.engine.technique.debug_buffer() {
                let pixels = w as u64 * h as u64;
                let planes = (debug.size() / (16 * pixels)).max(1) as usize;
                if r.debug_probes.len() != planes {
                    r.debug_probes = (0..planes).map(|_| PixelProbe::new(&self.gpu, 1)).collect();
                }
                for (k, p) in r.debug_probes.iter_mut().enumerate() {
                    debug_asked |= p.record(&mut enc, (x, y), k as u64 * pixels + index, &[debug]);
                }
            }
        }
        if asked.is_empty() && !debug_asked {
            return;
        }
        let submission = self
            .gpu
            .submit("viewer: pixel inspector probes", enc.finish());
        for i in asked {
            self.runs[i].probe.start(submission.clone());
        }
        for r in &mut self.runs {
            for p in &mut r.debug_probes {
                p.start(submission.clone());
            }
        }
    }

    /// The debug channels of a pixel of a run (channel c is plane c / 4, component c % 4), from
    /// its last probe; None until every plane has arrived for this pixel.
    pub fn inspect_debug(&self, run: usize, x: u32, y: u32) -> Option<Vec<f32>> {
        let r = self.runs.get(run)?;
        if r.debug_probes.is_empty() {
            return None;
        }
        let mut channels = Vec::with_capacity(4 * r.debug_probes.len());
        for p in &r.debug_probes {
            let ((px, py), v) = p.last.as_ref()?;
            if (*px, *py) != (x, y) {
                return None;
            }
            channels.extend_from_slice(v.first()?);
        }
        Some(channels)
    }

    /// HDR value, variance and error of a pixel of a run, from its last probe (the pixel
    /// inspector; `request_pixel` asks for it, the values come a frame or more later).
    pub fn inspect(&self, run: usize, x: u32, y: u32) -> Option<PixelInfo> {
        let on_gpu = self.reference.on_gpu;
        let r = self.runs.get(run)?;
        let ((px, py), v) = r.probe.last.as_ref()?;
        if (*px, *py) != (x, y) {
            return None;
        }
        let (mean, m2, reference) = (v[0], v[1], v[2]);
        let n = mean[3];
        let d = if n > 1.0 { 1.0 / (n - 1.0) } else { 0.0 };
        let rel_mse = on_gpu.then(|| {
            (0..3)
                .map(|c| {
                    let e = (mean[c] - reference[c]) as f64;
                    e * e / ((reference[c] as f64).powi(2) + 0.01)
                })
                .sum::<f64>() as f32
                / 3.0
        });
        Some(PixelInfo {
            radiance: [mean[0], mean[1], mean[2]],
            variance: Some((m2[0] * d + m2[1] * d + m2[2] * d) / 3.0),
            rel_mse,
            reference: on_gpu.then_some([reference[0], reference[1], reference[2]]),
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
