//! The headless engine: one scene, one camera, one technique; renders frames, reads results
//! back and accounts rays and GPU time. The CLI, the tests and (later) the viewer all use it.

use super::{
    denoise::Denoiser, pipelines, primary, FrameUniforms, PassInfo, RayCounts, RenderContext,
    Technique, COUNTER_SLOTS,
};
use crate::compare::Image;
/// Re-exported: frames and the clock check share one plausibility check (`TimingSource::judge`).
pub use crate::gpu::timing::TimingSource;
use crate::gpu::{readback, shaders::ShaderLibrary, timing::PassTimer, Gpu};
use crate::render::params::ParamChanges;
use crate::scene::{gpu_scene::GpuScene, Camera, Scene};
use anyhow::{Context, Result};
use std::sync::Arc;
use std::time::Instant;
use wgpu::util::DeviceExt;

/// Builds a RenderContext from the engine's fields (a macro so the borrow checker sees that
/// the technique itself is not borrowed and can be called mutably beside it).
macro_rules! render_context {
    ($e:expr) => {
        RenderContext {
            gpu: &$e.gpu,
            shaders: &$e.shaders,
            scene: &$e.gpu_scene,
            frame_layout: &$e.frame_layout,
            frame_bind_group: &$e.frame_bind_group,
            extent: $e.extent,
            camera: &$e.camera,
        }
    };
}

pub struct EngineSettings {
    pub extent: [u32; 2],
    pub seed: u32,
    pub camera: Camera,
}

/// What one frame cost.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct FrameReport {
    pub frame_index: u32,
    pub gpu_ms_by_pass: Vec<(String, f64)>,
    /// GPU milliseconds from timestamps, or the wall time when `timing` says so.
    pub gpu_ms: f64,
    pub wall_ms: f64,
    pub timing: TimingSource,
}

/// A collected frame: its cost and the ray counters (cumulative since the last reset) as
/// they stood right after it.
#[derive(Clone, Debug, Default)]
pub struct FrameResult {
    pub report: FrameReport,
    pub rays: RayCounts,
}

/// Frames submitted ahead of the one being collected (`Engine::submit_frame`).
pub const FRAMES_IN_FLIGHT: usize = 3;
const TIMESTAMP_BYTES: u64 = crate::gpu::timing::MAX_PASSES as u64 * 16;
const COUNTER_BYTES: u64 = (COUNTER_SLOTS * 2 * 4) as u64;

/// A submitted frame waiting for its staging slot.
struct InFlight {
    slot: usize,
    frame_index: u32,
    submitted: Instant,
    names: Vec<&'static str>,
}

pub struct Engine {
    pub gpu: Arc<Gpu>,
    pub shaders: ShaderLibrary,
    pub scene: Arc<Scene>,
    pub gpu_scene: Arc<GpuScene>,
    pub camera: Camera,
    prev_camera: Camera,
    pub extent: [u32; 2],
    pub seed: u32,
    pub technique: Box<dyn Technique>,
    uniforms: wgpu::Buffer,
    counters: wgpu::Buffer,
    /// Bind group 1 of every pass: frame uniforms, ray counters, primary surfaces.
    frame_layout: wgpu::BindGroupLayout,
    frame_bind_group: wgpu::BindGroup,
    /// The primary-surface pass, when the technique needs it (`Technique::inputs`) or the
    /// denoiser runs (its G-buffer).
    primary: Option<wgpu::ComputePipeline>,
    /// Its output (a 16-byte placeholder when no pass runs).
    surfaces: wgpu::Buffer,
    /// The technique's accumulated output: per pixel mean (w: samples) and Welford M2.
    accum_mean: wgpu::Buffer,
    accum_m2: wgpu::Buffer,
    /// The shared denoiser, when on (`set_denoise`): runs after the technique every frame.
    denoiser: Option<Denoiser>,
    timer: PassTimer,
    /// Staging slots of the frames in flight (timestamps, then ray counters).
    slots: Vec<readback::StagingRead>,
    in_flight: std::collections::VecDeque<InFlight>,
    completed: std::collections::VecDeque<FrameResult>,
    last_completion: Option<Instant>,
    /// Frames since the last history reset.
    pub frame_index: u32,
    /// Samples per pixel accumulated since the last reset.
    pub samples: u32,
    /// Summed GPU (or, without timestamps, wall) milliseconds since the last reset.
    pub total_gpu_ms: f64,
    pub total_wall_ms: f64,
    /// FrameUniforms flags (`render::FLAG_*`).
    pub flags: u32,
    /// Scene time (seconds) of the pose the next frame renders; it advances by
    /// `time_scale / PLAYBACK_FPS` before every frame after the first when the scene's
    /// animations play (`[scene] time_scale`).
    pub scene_time: f32,
    /// Whether a frame has been submitted at `scene_time` already (the first frame renders the
    /// pose the scene was loaded at).
    posed_frame_done: bool,
    /// CPU milliseconds the last re-posing of the scene took (motion, BVH top level, scene
    /// buffers written), and the technique's reaction to it with the accumulation restart
    /// (wall time: it may wait for frames in flight).
    pub last_motion_ms: f64,
    pub last_reaction_ms: f64,
    /// Whether the scene was re-posed since the last frame (its motion records hold that move).
    posed_for_frame: bool,
    /// Scene time is set from outside (`set_scene_time`: the viewer's clock, shared by its
    /// panes) instead of advancing with this engine's frames.
    pub external_clock: bool,
    /// Entry files under `shaders/` this engine has compiled (technique, parts, primary
    /// surfaces, denoiser), recorded as they are built: what hot reload watches.
    shader_entries: std::collections::BTreeSet<String>,
}

/// Frames per second of scene time during playback: frame k renders time t0 + k × time_scale /
/// PLAYBACK_FPS, whatever the wall clock, so that headless runs are repeatable.
pub const PLAYBACK_FPS: f32 = 60.0;

impl Engine {
    pub fn new(
        gpu: Arc<Gpu>,
        shaders: ShaderLibrary,
        scene: Scene,
        technique: Box<dyn Technique>,
        settings: EngineSettings,
    ) -> Result<Engine> {
        let gpu_scene = Arc::new(GpuScene::upload(&gpu, &scene));
        Self::with_shared_scene(
            gpu,
            shaders,
            Arc::new(scene),
            gpu_scene,
            technique,
            settings,
        )
    }

    /// Like `new`, for several engines on one uploaded scene (the viewer's panes).
    pub fn with_shared_scene(
        gpu: Arc<Gpu>,
        shaders: ShaderLibrary,
        scene: Arc<Scene>,
        gpu_scene: Arc<GpuScene>,
        technique: Box<dyn Technique>,
        settings: EngineSettings,
    ) -> Result<Engine> {
        let (engine, entries) = pipelines::recording_entries(|| {
            Self::build_with_shared_scene(gpu, shaders, scene, gpu_scene, technique, settings)
        });
        let mut engine = engine?;
        engine.shader_entries = entries;
        Ok(engine)
    }

    fn build_with_shared_scene(
        gpu: Arc<Gpu>,
        shaders: ShaderLibrary,
        scene: Arc<Scene>,
        gpu_scene: Arc<GpuScene>,
        technique: Box<dyn Technique>,
        settings: EngineSettings,
    ) -> Result<Engine> {
        anyhow::ensure!(
            settings.extent[0] > 0 && settings.extent[1] > 0,
            "image size must be positive"
        );
        // Pipelines compile the variant this scene needs (features it lacks compiled out).
        let shaders = shaders.with_variant(gpu_scene.data.shader_variant());
        let max = gpu.device.limits().max_texture_dimension_2d;
        anyhow::ensure!(
            settings.extent[0] <= max && settings.extent[1] <= max,
            "image size exceeds the adapter's limit of {max}"
        );
        let uniforms = gpu
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("frame uniforms"),
                contents: bytemuck::bytes_of(&FrameUniforms::default()),
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            });
        let counters = gpu
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("ray counters"),
                contents: bytemuck::cast_slice(&[0u32; COUNTER_SLOTS * 2]),
                usage: wgpu::BufferUsages::STORAGE
                    | wgpu::BufferUsages::COPY_SRC
                    | wgpu::BufferUsages::COPY_DST,
            });
        let frame_layout = pipelines::layout(
            &gpu,
            "frame",
            &[
                pipelines::uniform_entry(0, wgpu::ShaderStages::COMPUTE),
                pipelines::storage_entry(1, false),
                pipelines::storage_entry(2, false),
                pipelines::storage_entry(3, false),
                pipelines::storage_entry(4, false),
            ],
        );
        let inputs = technique.inputs();
        // Surfaces only where a technique reads them; a placeholder keeps the layout one shape.
        let surfaces = if inputs.primary_surfaces {
            primary::surfaces_buffer(&gpu, settings.extent)
        } else {
            pipelines::storage_buffer(&gpu, "no primary surfaces", 16)
        };
        // The accumulated output every technique writes (gilab::accumulate): mean and Welford M2.
        let pixels = settings.extent[0] as u64 * settings.extent[1] as u64;
        let accum_mean = pipelines::storage_buffer(&gpu, "output mean", pixels * 16);
        let accum_m2 = pipelines::storage_buffer(&gpu, "output m2", pixels * 16);
        let frame_bind_group = pipelines::buffers_bind_group(
            &gpu,
            "frame",
            &frame_layout,
            &[&uniforms, &counters, &surfaces, &accum_mean, &accum_m2],
        );
        // (`set_denoise` rebuilds this bind group when it adds or drops the surfaces.)
        let primary = if inputs.primary_surfaces {
            Some(primary::pipeline(
                &gpu,
                &shaders,
                &gpu_scene,
                &frame_layout,
            )?)
        } else {
            None
        };
        let timer = PassTimer::new(&gpu);
        let slots = (0..FRAMES_IN_FLIGHT)
            .map(|_| {
                readback::StagingRead::new(&gpu, "frame slot", TIMESTAMP_BYTES + COUNTER_BYTES)
            })
            .collect();
        let scene_time = scene.posed_at.unwrap_or(0.0);
        let mut engine = Engine {
            gpu,
            shaders,
            scene,
            gpu_scene,
            camera: settings.camera,
            prev_camera: settings.camera,
            extent: settings.extent,
            seed: settings.seed,
            technique,
            uniforms,
            counters,
            frame_layout,
            frame_bind_group,
            primary,
            surfaces,
            accum_mean,
            accum_m2,
            denoiser: None,
            timer,
            slots,
            in_flight: Default::default(),
            completed: Default::default(),
            last_completion: None,
            frame_index: 0,
            samples: 0,
            total_gpu_ms: 0.0,
            total_wall_ms: 0.0,
            flags: 0,
            scene_time,
            posed_frame_done: false,
            last_motion_ms: 0.0,
            last_reaction_ms: 0.0,
            external_clock: false,
            posed_for_frame: false,
            shader_entries: Default::default(),
        };
        let id = engine.technique.id();
        engine
            .technique
            .build(&render_context!(engine))
            .with_context(|| format!("building technique '{id}'"))?;
        engine.gpu.check_errors()?;
        engine.reset();
        Ok(engine)
    }

    /// Which passes run for this scene: the engine's primary surfaces when the technique needs
    /// them, then the technique's own.
    pub fn passes(&self) -> Vec<PassInfo> {
        let mut v = Vec::new();
        if self.primary.is_some() {
            let why = if self.technique.inputs().primary_surfaces {
                "shared primary surfaces: jittered camera rays, as the reference"
            } else {
                "shared primary surfaces for the denoiser's G-buffer: jittered camera rays, as \
                 the reference"
            };
            v.push(PassInfo {
                name: primary::PASS,
                runs: true,
                why: why.into(),
            });
        }
        v.extend(self.technique.passes(&self.gpu_scene.data.features));
        if let Some(d) = &self.denoiser {
            v.extend(d.passes());
        }
        v
    }

    /// Whether the shared denoiser runs after the technique.
    pub fn denoise(&self) -> bool {
        self.denoiser.is_some()
    }

    /// Turns the shared SVGF-style denoiser (`render::denoise`) on or off. On: the engine runs
    /// the primary-surface pass (the denoiser's G-buffer; its camera rays are counted like any
    /// pass's) even where the technique does not need it, and after every frame the denoised
    /// radiance replaces the output (`read_output`, output copies, the viewer's display); its
    /// passes are timed in the frame. Off: the engine is as it was without it. History and
    /// accumulation restart. On error nothing changes.
    pub fn set_denoise(&mut self, on: bool) -> Result<()> {
        self.recording(|e| e.set_denoise_inner(on))
    }

    fn set_denoise_inner(&mut self, on: bool) -> Result<()> {
        if on == self.denoise() {
            return Ok(());
        }
        self.finish_frames()?;
        if on {
            // Everything that can fail first, so an error leaves the engine as it was.
            let denoiser = Denoiser::new(&self.gpu, &self.shaders, &self.frame_layout, self.extent)
                .context("building the denoiser")?;
            if self.primary.is_none() {
                let pipeline = primary::pipeline(
                    &self.gpu,
                    &self.shaders,
                    &self.gpu_scene,
                    &self.frame_layout,
                )?;
                self.gpu.check_errors()?;
                self.primary = Some(pipeline);
                self.surfaces = primary::surfaces_buffer(&self.gpu, self.extent);
                self.rebuild_frame_bind_group();
            }
            self.gpu.check_errors()?;
            self.denoiser = Some(denoiser);
        } else {
            self.denoiser = None;
            if !self.technique.inputs().primary_surfaces && self.primary.is_some() {
                self.primary = None;
                self.surfaces = pipelines::storage_buffer(&self.gpu, "no primary surfaces", 16);
                self.rebuild_frame_bind_group();
            }
        }
        // Techniques bind the frame bind group from the RenderContext each frame (none keeps
        // its own copy), so they need no rebuild for the new one.
        self.reset();
        Ok(())
    }

    /// Bind group 1 from the current buffers (after the surfaces buffer changed).
    fn rebuild_frame_bind_group(&mut self) {
        self.frame_bind_group = pipelines::buffers_bind_group(
            &self.gpu,
            "frame",
            &self.frame_layout,
            &[
                &self.uniforms,
                &self.counters,
                &self.surfaces,
                &self.accum_mean,
                &self.accum_m2,
            ],
        );
    }

    /// Builds the primary-surface pass again (new shaders or scene); on error the old one stays.
    fn rebuild_primary(&mut self) -> Result<()> {
        if self.primary.is_some() {
            self.primary = Some(primary::pipeline(
                &self.gpu,
                &self.shaders,
                &self.gpu_scene,
                &self.frame_layout,
            )?);
        }
        Ok(())
    }

    /// Clears history and counters (camera cut, scene edit, parameter change).
    pub fn reset(&mut self) {
        // Frames in flight belong to the history being cleared.
        if let Err(e) = self.finish_frames() {
            log::warn!("frames in flight at reset: {e:#}");
        }
        self.completed.clear();
        self.technique.reset_history(&self.gpu);
        if let Some(d) = &self.denoiser {
            d.reset(&self.gpu);
        }
        self.restart_accumulation();
        self.gpu.queue.write_buffer(
            &self.counters,
            0,
            bytemuck::cast_slice(&[0u32; COUNTER_SLOTS * 2]),
        );
        self.frame_index = 0;
        self.samples = 0;
        self.total_gpu_ms = 0.0;
        self.total_wall_ms = 0.0;
        self.prev_camera = self.camera;
    }

    /// Clears the accumulated output: the next frame starts a new average.
    fn restart_accumulation(&self) {
        let mut enc = self.gpu.device.create_command_encoder(&Default::default());
        enc.clear_buffer(&self.accum_mean, 0, None);
        enc.clear_buffer(&self.accum_m2, 0, None);
        if let Some(d) = &self.denoiser {
            d.restart_accumulation(&mut enc);
        }
        self.gpu.submit("accumulation restart", enc.finish());
    }

    pub fn set_camera(&mut self, camera: Camera) {
        self.prev_camera = self.camera;
        self.camera = camera;
        self.reset();
    }

    /// A scripted scene edit while running: swaps in the edited scene (uploaded by the
    /// caller, shared between runs) without a full reset: counters, frame count and the
    /// technique's reuse history continue; accumulation restarts (`Technique::on_scene_change`).
    pub fn change_scene(&mut self, scene: Arc<Scene>, gpu_scene: Arc<GpuScene>) -> Result<()> {
        self.recording(|e| e.change_scene_inner(scene, gpu_scene))
    }

    fn change_scene_inner(&mut self, scene: Arc<Scene>, gpu_scene: Arc<GpuScene>) -> Result<()> {
        self.finish_frames()?;
        let variant = gpu_scene.data.shader_variant();
        let variant_changed = variant != self.shaders.variant;
        self.shaders = self.shaders.with_variant(variant);
        self.scene = scene;
        self.gpu_scene = gpu_scene;
        self.rebuild_primary()?;
        if variant_changed {
            // The edit added or removed a shader feature: every pipeline compiles again.
            if let Some(d) = &mut self.denoiser {
                d.rebuild(&self.gpu, &self.shaders, &self.frame_layout)?;
            }
        }
        self.technique.build(&render_context!(self))?;
        self.gpu.check_errors()?;
        self.technique.on_scene_change(&self.gpu);
        self.restart_accumulation();
        Ok(())
    }

    /// Animation playback: before every frame after the first, scene time advances by
    /// `time_scale / PLAYBACK_FPS`, the scene is re-posed (`Motion::apply`), its BVH top level,
    /// triangle records and light pool are rewritten in place (`GpuScene::repose`; a full
    /// upload where that cannot be done), the technique is told (`on_geometry_moved`) and the
    /// accumulated output restarts.
    fn advance_motion(&mut self) -> Result<()> {
        if self.external_clock {
            return Ok(());
        }
        let Some(motion) = self.scene.motion.clone() else {
            return Ok(());
        };
        if motion.time_scale == 0.0 {
            return Ok(());
        }
        if !self.posed_frame_done {
            self.posed_frame_done = true;
            return Ok(());
        }
        let next = motion.time_after(self.scene_time, 1, PLAYBACK_FPS);
        if next == self.scene_time {
            // Held at `play_until`: nothing moves, and the output accumulates again.
            return Ok(());
        }
        self.scene_time = next;
        self.pose_scene(&motion)
    }

    /// Poses the scene at `t` now (the viewer's shared clock, its time slider); nothing for a
    /// scene that does not move or is at `t` already.
    pub fn set_scene_time(&mut self, t: f32) -> Result<()> {
        let Some(motion) = self.scene.motion.clone() else {
            return Ok(());
        };
        if t == self.scene_time {
            return Ok(());
        }
        self.scene_time = t;
        self.pose_scene(&motion)
    }

    /// The scene at `scene_time`: re-posed, its buffers rewritten in place (a full upload where
    /// that cannot be done), the technique told, the accumulated output restarted.
    fn pose_scene(&mut self, motion: &crate::scene::motion::Motion) -> Result<()> {
        let start = Instant::now();
        let moved = motion.apply(Arc::make_mut(&mut self.scene), self.scene_time)?;
        if moved.instances.is_empty() && !moved.lights {
            return Ok(());
        }
        let reposed =
            Arc::make_mut(&mut self.gpu_scene).repose(&self.gpu, &self.scene, &moved.instances);
        // The scene's own update (motion, BVH top level, buffers written), before anything
        // that may wait for frames in flight.
        self.last_motion_ms = start.elapsed().as_secs_f64() * 1e3;
        self.posed_for_frame = true;
        let start = Instant::now();
        if reposed {
            self.recording(|e| e.technique.on_geometry_moved(&render_context!(e)))?;
            self.restart_accumulation();
        } else {
            log::debug!("re-posing in place not possible: the scene is uploaded again");
            let gpu_scene = Arc::new(GpuScene::upload(&self.gpu, &self.scene));
            self.change_scene(self.scene.clone(), gpu_scene)?;
        }
        self.last_reaction_ms = start.elapsed().as_secs_f64() * 1e3;
        Ok(())
    }

    /// A scripted camera move while running: the next frame reprojects from the old camera
    /// (motion vectors), accumulation restarts, counters and reuse history continue.
    pub fn move_camera(&mut self, camera: Camera) {
        self.camera = camera;
        self.technique.on_scene_change(&self.gpu);
        self.restart_accumulation();
    }

    /// New parameter values: uniforms and parameter-sized resources are updated; no pipeline is
    /// rebuilt. History restarts.
    pub fn set_params(&mut self, changes: &ParamChanges) -> Result<()> {
        self.technique.set_params(changes)?;
        self.recording(|e| e.technique.apply_params(&render_context!(e)))?;
        self.gpu.check_errors()?;
        self.reset();
        Ok(())
    }

    /// `set_params` from a preset's TOML table (parsed against the technique's table).
    pub fn set_params_from_table(&mut self, table: &toml::Table) -> Result<()> {
        let changes = self.technique.param_set().parse(table)?;
        self.set_params(&changes)
    }

    /// A ray budget (rays per pixel per frame) mapped by the technique to its own knobs: the one
    /// mapping behind the viewer's slider, `shot` and `converge`. `measured` is the rays per pixel
    /// per frame at the current settings; without it calibration frames measure them (as many
    /// as the technique asks for), so the mapping uses this scene's rays per path rather than a
    /// guess. History restarts.
    /// A technique that needs several calibration frames gets a second round: its cost per ray
    /// can depend on the budget itself (surfels: what their hits trace).
    pub fn apply_ray_budget(&mut self, rays_per_pixel: f64, measured: Option<f64>) -> Result<()> {
        let frames = self.technique.calibration_frames().max(1);
        let mut measured = match measured {
            Some(m) => Some(m),
            None => self.calibrate(frames)?,
        };
        let rounds = if frames > 1 { 2 } else { 1 };
        for round in 0..rounds {
            if let Some(t) = self
                .technique
                .params_for_ray_budget(rays_per_pixel, measured)
            {
                self.set_params(&t)?;
            }
            if round + 1 < rounds {
                measured = self.calibrate(frames)?;
            }
        }
        self.reset();
        Ok(())
    }

    /// Rays per pixel per frame over `frames` frames from a reset.
    fn calibrate(&mut self, frames: u32) -> Result<Option<f64>> {
        self.reset();
        for _ in 0..frames {
            self.render_frame()?;
        }
        Ok(self.rays_per_pixel_per_frame(&self.ray_counts()?))
    }

    /// Rebuilds the technique's pipelines from the current shader sources (hot reload).
    /// On error the previous pipelines keep running and history is kept.
    pub fn rebuild(&mut self) -> Result<()> {
        self.recording(Self::rebuild_inner)
    }

    fn rebuild_inner(&mut self) -> Result<()> {
        self.rebuild_primary()?;
        if let Some(d) = &mut self.denoiser {
            d.rebuild(&self.gpu, &self.shaders, &self.frame_layout)?;
        }
        self.technique.build(&render_context!(self))?;
        self.gpu.check_errors()?;
        self.reset();
        Ok(())
    }

    /// Whether a change to these entry files affects this engine: whether it has compiled
    /// any of them (`shader_entries`).
    pub fn uses_any_shader(&self, entries: &[String]) -> bool {
        entries.iter().any(|e| self.shader_entries.contains(e))
    }

    /// Every entry file under `shaders/` this engine has compiled since it was made: its
    /// technique's and parts' pipelines (those its parameters have asked for so far), the
    /// primary surfaces' and the denoiser's. A superset of what runs now (a part switched off
    /// stays listed), which costs at most a needless rebuild on hot reload.
    pub fn shader_entries(&self) -> &std::collections::BTreeSet<String> {
        &self.shader_entries
    }

    /// Runs `f` on the engine, adding the entry files it compiles to `shader_entries`.
    fn recording<T>(&mut self, f: impl FnOnce(&mut Self) -> T) -> T {
        let (out, entries) = pipelines::recording_entries(|| f(self));
        self.shader_entries.extend(entries);
        out
    }

    /// Rays per pixel per frame measured since the last reset.
    pub fn rays_per_pixel_per_frame(&self, rays: &RayCounts) -> Option<f64> {
        let pixels = (self.extent[0] * self.extent[1]) as f64;
        (self.frame_index > 0).then(|| rays.total() as f64 / pixels / self.frame_index as f64)
    }

    fn uniforms_for_frame(&self) -> FrameUniforms {
        let [w, h] = self.extent;
        let aspect = w as f32 / h as f32;
        let (lo, hi) = self.scene.bounds();
        let near = ((hi - lo).length() * 1e-4).max(1e-4);
        let (right, up, fwd) = self.camera.basis();
        let tan = (self.camera.fov_y.clamp(0.01, 179.0).to_radians() * 0.5).tan();
        FrameUniforms {
            clip_from_world: self.camera.clip_from_world(aspect, near).to_cols_array_2d(),
            prev_clip_from_world: self
                .prev_camera
                .clip_from_world(aspect, near)
                .to_cols_array_2d(),
            camera_pos: self.camera.position.extend(1.0).to_array(),
            camera_right: (right * tan * aspect).extend(0.0).to_array(),
            camera_up: (up * tan).extend(0.0).to_array(),
            camera_forward: fwd.extend(0.0).to_array(),
            sky: self.gpu_scene.sky.extend(0.0).to_array(),
            size: self.extent,
            frame_index: self.frame_index,
            seed: self.seed,
            sample_offset: self.samples,
            flags: self.flags,
            pad: [0; 2],
        }
    }

    /// Runs `f` with the render context and the technique: tests and tools that query a
    /// technique's own state on the GPU (never inside a frame).
    pub fn inspect<T>(&self, f: impl FnOnce(&RenderContext, &dyn Technique) -> T) -> T {
        f(&render_context!(self), self.technique.as_ref())
    }

    /// Renders one frame of the technique and waits for it (and for any frame in flight).
    pub fn render_frame(&mut self) -> Result<FrameReport> {
        self.submit_frame(None)?;
        self.finish_frames()?;
        let done = std::mem::take(&mut self.completed);
        done.into_iter()
            .last()
            .map(|f| f.report)
            .context("the submitted frame did not complete")
    }

    /// Records and submits one frame without waiting for it: frames go back to back, up to
    /// `FRAMES_IN_FLIGHT`; the oldest is waited for only when all slots are busy (the GPU
    /// still has the newer ones queued, so it does not idle). Timestamps and ray counters
    /// travel in the frame's staging slot; `poll_frames` turns them into `FrameResult`s.
    /// `output_copy`: a buffer (COPY_DST, `pixels * 16` bytes) that receives this frame's
    /// accumulated output after the frame, for evaluation later (converge).
    pub fn submit_frame(&mut self, output_copy: Option<&wgpu::Buffer>) -> Result<()> {
        self.advance_motion()?;
        // A frame the scene did not move into: object motion vectors go back to zero.
        if !std::mem::take(&mut self.posed_for_frame) && self.gpu_scene.motion_live() {
            Arc::make_mut(&mut self.gpu_scene).hold_still(&self.gpu);
        }
        if self.in_flight.len() >= FRAMES_IN_FLIGHT {
            self.complete_oldest(true)?;
        }
        let slot = (0..FRAMES_IN_FLIGHT)
            .find(|i| self.slots[*i].is_idle())
            .context("no idle frame slot")?;
        let submitted = Instant::now();
        let uniforms = self.uniforms_for_frame();
        self.gpu
            .queue
            .write_buffer(&self.uniforms, 0, bytemuck::bytes_of(&uniforms));
        let mut enc = self
            .gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("frame"),
            });
        self.timer.begin_frame();
        if let Some(p) = &self.primary {
            primary::record(
                &mut enc,
                &mut self.timer,
                p,
                &self.gpu_scene,
                &self.frame_bind_group,
                self.extent,
            );
        }
        // With the denoiser the output holds last frame's denoised image: the technique's own
        // output goes back first, so an accumulating technique averages its own samples.
        if let Some(d) = &self.denoiser {
            d.restore_noisy(&mut enc, &self.accum_mean);
        }
        self.technique
            .render(&render_context!(self), &mut enc, &mut self.timer);
        if let Some(d) = &self.denoiser {
            d.record(
                &mut enc,
                &mut self.timer,
                &self.frame_bind_group,
                &self.accum_mean,
            );
        }
        let staging = self.slots[slot].buffer();
        self.timer.resolve_to(&mut enc, staging, 0);
        enc.copy_buffer_to_buffer(&self.counters, 0, staging, TIMESTAMP_BYTES, COUNTER_BYTES);
        if let Some(dst) = output_copy {
            enc.copy_buffer_to_buffer(&self.accum_mean, 0, dst, 0, self.accum_mean.size());
        }
        let what = format!(
            "frame {} of {} (passes: {})",
            self.frame_index,
            self.technique.id(),
            self.timer.names().join(", ")
        );
        let submission = self.gpu.submit(&what, enc.finish());
        self.slots[slot].start_named(submission, what);
        self.in_flight.push_back(InFlight {
            slot,
            frame_index: self.frame_index,
            submitted,
            names: self.timer.names().to_vec(),
        });
        self.frame_index += 1;
        self.samples += self.technique.samples_per_frame();
        self.prev_camera = self.camera;
        Ok(())
    }

    /// Collects the frames that have finished (all of them with `wait`), oldest first.
    pub fn poll_frames(&mut self, wait: bool) -> Result<()> {
        while !self.in_flight.is_empty() {
            if !self.complete_oldest(wait)? {
                break;
            }
        }
        Ok(())
    }

    /// Waits for every frame in flight.
    pub fn finish_frames(&mut self) -> Result<()> {
        self.poll_frames(true)
    }

    /// Frames completed since the last call, oldest first.
    pub fn take_completed(&mut self) -> Vec<FrameResult> {
        std::mem::take(&mut self.completed).into()
    }

    /// Frames submitted and not yet collected.
    pub fn frames_in_flight(&self) -> usize {
        self.in_flight.len()
    }

    /// Reads the oldest frame's slot if it is done (or waits for it); returns whether it was.
    fn complete_oldest(&mut self, wait: bool) -> Result<bool> {
        let Some(f) = self.in_flight.front() else {
            return Ok(false);
        };
        let Some(bytes) = self.slots[f.slot].poll(&self.gpu, wait)? else {
            return Ok(false);
        };
        let f = self.in_flight.pop_front().expect("front exists");
        let now = Instant::now();
        // Wall time of a frame: from when the GPU could start it (its submission, or the
        // previous frame's completion when frames queue back to back) to its completion.
        let began = self
            .last_completion
            .map_or(f.submitted, |c| c.max(f.submitted));
        self.last_completion = Some(now);
        let wall_ms = (now - began).as_secs_f64() * 1e3;
        self.gpu.check_errors()?;
        let ticks: Vec<u64> = bytemuck::pod_collect_to_vec(&bytes[..f.names.len() * 16]);
        let words: Vec<u32> = bytemuck::pod_collect_to_vec(
            &bytes[TIMESTAMP_BYTES as usize..(TIMESTAMP_BYTES + COUNTER_BYTES) as usize],
        );
        let passes = PassTimer::ms_from_ticks(&self.gpu, &f.names, &ticks);
        let stamped: f64 = passes.iter().map(|p| p.1).sum();
        // Wall time counts from when the GPU could start this frame (see `TimingSource::judge`).
        let timing = TimingSource::judge((!passes.is_empty()).then_some(stamped), wall_ms);
        let (gpu_ms, passes) = match timing {
            TimingSource::Timestamps => (stamped, passes),
            TimingSource::Wall | TimingSource::WallTimestampsImplausible => (wall_ms, Vec::new()),
        };
        self.total_gpu_ms += gpu_ms;
        self.total_wall_ms += wall_ms;
        self.completed.push_back(FrameResult {
            report: FrameReport {
                frame_index: f.frame_index,
                gpu_ms_by_pass: passes
                    .into_iter()
                    .map(|(n, ms)| (n.to_string(), ms))
                    .collect(),
                gpu_ms,
                wall_ms,
                timing,
            },
            rays: RayCounts::from_words(&words),
        });
        Ok(true)
    }

    /// The accumulated output on the GPU: per pixel mean (w: samples) and Welford M2. The
    /// viewer's display and error passes read them where they are.
    pub fn output_buffers(&self) -> (&wgpu::Buffer, &wgpu::Buffer) {
        (&self.accum_mean, &self.accum_m2)
    }

    /// The technique's output before the denoiser filtered it (None with the denoiser off,
    /// where `read_output` is that already).
    pub fn read_noisy_output(&self) -> Result<Option<Image>> {
        let Some(d) = &self.denoiser else {
            return Ok(None);
        };
        let [w, h] = self.extent;
        let px: Vec<[f32; 4]> =
            readback::read_buffer(&self.gpu, d.noisy_buffer(), (w * h) as usize)?;
        Ok(Some(Image::from_rgba(w, h, &px)))
    }

    /// Linear HDR radiance of the technique's output (denoised when the denoiser is on).
    pub fn read_output(&self) -> Result<Image> {
        let [w, h] = self.extent;
        let px: Vec<[f32; 4]> =
            readback::read_buffer(&self.gpu, &self.accum_mean, (w * h) as usize)?;
        Ok(Image::from_rgba(w, h, &px))
    }

    /// Per-pixel sample variance (rgb) from the Welford M2 (0 where one sample stands).
    pub fn read_variance(&self) -> Result<Option<Image>> {
        Ok(self.read_output_and_variance()?.1)
    }

    /// Radiance and per-pixel sample variance with one readback of the mean.
    pub fn read_output_and_variance(&self) -> Result<(Image, Option<Image>)> {
        let [w, h] = self.extent;
        let mean: Vec<[f32; 4]> =
            readback::read_buffer(&self.gpu, &self.accum_mean, (w * h) as usize)?;
        let image = Image::from_rgba(w, h, &mean);
        let m2: Vec<[f32; 4]> = readback::read_buffer(&self.gpu, &self.accum_m2, (w * h) as usize)?;
        let var = sample_variance(&mean, &m2);
        Ok((image, Some(Image::from_rgba(w, h, &var))))
    }

    /// The primary surfaces of the last rendered frame, when the technique (or the denoiser)
    /// uses them.
    pub fn read_primary_surfaces(&self) -> Result<Option<Vec<primary::PrimarySurface>>> {
        if self.primary.is_none() || self.frame_index == 0 {
            return Ok(None);
        }
        let pixels = (self.extent[0] * self.extent[1]) as usize;
        let all: Vec<primary::PrimarySurface> =
            readback::read_buffer(&self.gpu, &self.surfaces, 2 * pixels)?;
        let segment = ((self.frame_index - 1) & 1) as usize;
        Ok(Some(all[segment * pixels..(segment + 1) * pixels].to_vec()))
    }

    /// The technique's debug buffer, if it has one: planes of one vec4 per pixel (channels
    /// 0-3 in the first plane, 4-7 in the second; `render::debug_channel` picks one).
    pub fn read_debug(&self) -> Result<Option<Vec<[f32; 4]>>> {
        let Some(buf) = self.technique.debug_buffer() else {
            return Ok(None);
        };
        let pixels = (self.extent[0] * self.extent[1]) as u64;
        let planes = (buf.size() / (16 * pixels)).max(1);
        Ok(Some(readback::read_buffer(
            &self.gpu,
            buf,
            (planes * pixels) as usize,
        )?))
    }

    /// Rays by kind since the last reset.
    pub fn ray_counts(&self) -> Result<RayCounts> {
        let words: Vec<u32> = readback::read_buffer(&self.gpu, &self.counters, COUNTER_SLOTS * 2)?;
        Ok(RayCounts::from_words(&words))
    }
}

/// Per-pixel sample variance from Welford's running mean (w = count) and M2, with the count in
/// alpha (`accumulate_sample`'s buffers, or any average kept the same way).
pub fn sample_variance(mean: &[[f32; 4]], m2: &[[f32; 4]]) -> Vec<[f32; 4]> {
    mean.iter()
        .zip(m2)
        .map(|(m, v)| {
            let n = m[3];
            let d = if n > 1.0 { 1.0 / (n - 1.0) } else { 0.0 };
            [v[0] * d, v[1] * d, v[2] * d, n]
        })
        .collect()
}
