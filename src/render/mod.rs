//! Shared per-frame inputs (FrameUniforms, G-buffer), the Technique interface and registry,
//! ray accounting, and the headless engine that drives them.

pub mod denoise;
pub mod engine;
pub mod params;
pub mod pipelines;
pub mod primary;

use crate::gpu::{shaders::ShaderLibrary, timing::PassTimer, Gpu};
use crate::scene::{features::SceneFeatures, gpu_scene::GpuScene};
use anyhow::Result;
use serde::Serialize;

/// Matches `FrameUniforms` in shaders/common/frame.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct FrameUniforms {
    pub clip_from_world: [[f32; 4]; 4],
    pub prev_clip_from_world: [[f32; 4]; 4],
    pub camera_pos: [f32; 4],
    pub camera_right: [f32; 4],
    pub camera_up: [f32; 4],
    pub camera_forward: [f32; 4],
    pub sky: [f32; 4],
    pub size: [u32; 2],
    pub frame_index: u32,
    pub seed: u32,
    pub sample_offset: u32,
    pub flags: u32,
    pub pad: [u32; 2],
}

/// FrameUniforms flag: leave out emission seen directly by the camera, so an image holds
/// only the light arriving at the first surface (tests of direct-light estimators use it).
pub const FLAG_NO_PRIMARY_EMISSION: u32 = 1;

/// FrameUniforms flag: the path tracer (`gilab::path`) leaves the environment map out of
/// next-event estimation, so the sky is reached by BSDF sampling alone (A/B tests).
pub const FLAG_NO_SKY_NEE: u32 = 2;

/// Ray kinds, indices into the GPU counters (shaders/common/counters.wgsl).
/// `candidate`: visibility of a resampling candidate before reuse; `reuse`: occlusion tests made
/// by reuse itself (unbiased weights, bidirectional test); `reflection`: rays along a specular
/// lobe (the reflections part).
pub const RAY_KINDS: [&str; 9] = [
    "camera",
    "shadow",
    "indirect",
    "probe",
    "surfel",
    "cache",
    "candidate",
    "reuse",
    "reflection",
];
pub const COUNTER_INVALID_SAMPLES: usize = 15;
pub const COUNTER_SLOTS: usize = 16;
/// First of the six cache-lookup counters (not rays; counters.wgsl's COUNT_CACHE_*).
pub const COUNTER_CACHE_LOOKUPS: usize = 9;

/// Cumulative counters since the last history reset.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct RayCounts {
    pub by_kind: [u64; RAY_KINDS.len()],
    pub invalid_samples: u64,
    pub cache_lookups: CacheLookups,
}

/// Not rays: what a ray's hit found in the radiance cache it may end in (the surfels' own rays
/// today), by outcome and by whether the camera sees the hit this frame (it projects into the
/// image at the primary surface's depth, within 5%): covered by the cache's entries (a surfel
/// footprint of weight >= 0.25), by a coarser average only (the surfels' cell average), or not
/// at all (the ray goes on as a path).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct CacheLookups {
    pub entry_seen: u64,
    pub coarse_seen: u64,
    pub miss_seen: u64,
    pub entry_unseen: u64,
    pub coarse_unseen: u64,
    pub miss_unseen: u64,
}

impl CacheLookups {
    /// The lookups counted since `then` (an earlier read of the same counters).
    pub fn since(&self, then: &CacheLookups) -> CacheLookups {
        CacheLookups {
            entry_seen: self.entry_seen - then.entry_seen,
            coarse_seen: self.coarse_seen - then.coarse_seen,
            miss_seen: self.miss_seen - then.miss_seen,
            entry_unseen: self.entry_unseen - then.entry_unseen,
            coarse_unseen: self.coarse_unseen - then.coarse_unseen,
            miss_unseen: self.miss_unseen - then.miss_unseen,
        }
    }

    /// Lookups the cache covered (entries or coarse), seen or not.
    pub fn covered(&self) -> u64 {
        self.entry_seen + self.coarse_seen + self.entry_unseen + self.coarse_unseen
    }

    pub fn total(&self) -> u64 {
        self.seen() + self.unseen()
    }

    pub fn seen(&self) -> u64 {
        self.entry_seen + self.coarse_seen + self.miss_seen
    }

    pub fn unseen(&self) -> u64 {
        self.entry_unseen + self.coarse_unseen + self.miss_unseen
    }

    /// Share of the hits on surfaces the camera sees that the cache covers (entry or coarse).
    pub fn covered_seen(&self) -> Option<f64> {
        (self.seen() > 0).then(|| (self.entry_seen + self.coarse_seen) as f64 / self.seen() as f64)
    }

    /// Share of the hits the camera does not see that the cache covers.
    pub fn covered_unseen(&self) -> Option<f64> {
        (self.unseen() > 0)
            .then(|| (self.entry_unseen + self.coarse_unseen) as f64 / self.unseen() as f64)
    }

    /// One line for `shot --verbose` and the tests.
    pub fn summary(&self) -> String {
        let pct = |a: u64, b: u64| 100.0 * a as f64 / b.max(1) as f64;
        format!(
            "cache lookups at ray hits: {} seen by the camera ({:.1}% of all): {:.1}% covered ({:.1}% by entries, {:.1}% by the coarse average only), {:.1}% not; {} unseen: {:.1}% covered ({:.1}% by entries, {:.1}% coarse), {:.1}% not",
            self.seen(),
            pct(self.seen(), self.total()),
            pct(self.entry_seen + self.coarse_seen, self.seen()),
            pct(self.entry_seen, self.seen()),
            pct(self.coarse_seen, self.seen()),
            pct(self.miss_seen, self.seen()),
            self.unseen(),
            pct(self.entry_unseen + self.coarse_unseen, self.unseen()),
            pct(self.entry_unseen, self.unseen()),
            pct(self.coarse_unseen, self.unseen()),
            pct(self.miss_unseen, self.unseen()),
        )
    }
}

impl RayCounts {
    pub fn total(&self) -> u64 {
        self.by_kind.iter().sum()
    }
    pub fn from_words(words: &[u32]) -> RayCounts {
        let get = |k: usize| words[2 * k] as u64 | ((words[2 * k + 1] as u64) << 32);
        let mut by_kind = [0; RAY_KINDS.len()];
        for (k, v) in by_kind.iter_mut().enumerate() {
            *v = get(k);
        }
        let c = COUNTER_CACHE_LOOKUPS;
        RayCounts {
            by_kind,
            invalid_samples: get(COUNTER_INVALID_SAMPLES),
            cache_lookups: CacheLookups {
                entry_seen: get(c),
                coarse_seen: get(c + 1),
                miss_seen: get(c + 2),
                entry_unseen: get(c + 3),
                coarse_unseen: get(c + 4),
                miss_unseen: get(c + 5),
            },
        }
    }
    /// Rays of one kind of [`RAY_KINDS`] (0 for an unknown name).
    pub fn kind(&self, name: &str) -> u64 {
        RAY_KINDS
            .iter()
            .position(|k| *k == name)
            .map_or(0, |i| self.by_kind[i])
    }
    pub fn named(&self) -> Vec<(&'static str, u64)> {
        RAY_KINDS
            .iter()
            .copied()
            .zip(self.by_kind)
            .filter(|(_, v)| *v > 0)
            .collect()
    }
}

/// A pass a technique runs or skips for the current scene, with the reason (rule 3).
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct PassInfo {
    pub name: &'static str,
    pub runs: bool,
    pub why: String,
}

/// Everything a technique needs to build and record its work. Bind groups: 0 the scene,
/// 1 the frame (uniforms, ray counters, primary surfaces, accumulated output; owned by the
/// engine), 2 the technique's.
pub struct RenderContext<'a> {
    pub gpu: &'a Gpu,
    pub shaders: &'a ShaderLibrary,
    pub scene: &'a GpuScene,
    pub frame_layout: &'a wgpu::BindGroupLayout,
    pub frame_bind_group: &'a wgpu::BindGroup,
    pub extent: [u32; 2],
    /// The camera this frame renders from (techniques with camera-centred structures).
    pub camera: &'a crate::scene::Camera,
}

impl RenderContext<'_> {
    /// A compute pipeline of `entry` with the scene, frame and `technique` bind group layouts.
    pub fn pipeline(
        &self,
        entry: &str,
        technique: &wgpu::BindGroupLayout,
    ) -> Result<wgpu::ComputePipeline> {
        pipelines::compute_pipeline(
            self.gpu,
            self.shaders,
            entry,
            &[&self.scene.layout, self.frame_layout, technique],
        )
    }
}

/// One GI technique: long-lived pipelines, per-frame recording, linear HDR out.
pub trait Technique: std::any::Any {
    /// Preset key, CSV column and file-name stem.
    fn id(&self) -> &'static str;
    /// The concrete technique, for tests and tools that read its own state (surfel pool).
    fn as_any(&self) -> &dyn std::any::Any;
    /// Which passes run for this scene and why the others do not.
    fn passes(&self, features: &SceneFeatures) -> Vec<PassInfo>;
    /// What the engine must provide besides the scene and the frame uniforms.
    fn inputs(&self) -> primary::FrameInputs {
        primary::FrameInputs::default()
    }
    /// (Re)creates pipelines and buffers; on error the previous pipelines stay usable.
    fn build(&mut self, ctx: &RenderContext) -> Result<()>;
    /// Forget the technique's own history: reservoirs, caches (camera cut, scene edit, parameter
    /// change). The engine clears the accumulated output itself.
    fn reset_history(&mut self, gpu: &Gpu);
    /// A scripted change while running (light switched, material edited, camera moved; the
    /// lag experiments): the engine restarts the accumulated output, but history a real-time
    /// technique would keep across such a change (reservoirs, caches) stays, so its lag shows.
    /// Default: forget everything.
    fn on_scene_change(&mut self, gpu: &Gpu) {
        self.reset_history(gpu);
    }
    /// Geometry moved (animation playback, `[scene] time_scale`): the scene's buffers already
    /// hold the new pose, in place (bind groups stay valid); the engine restarts the
    /// accumulated output. Default: as a scripted change (`on_scene_change`). A technique whose
    /// own structures depend on where triangles are (Lumen's cards and distance field)
    /// updates them here.
    fn on_geometry_moved(&mut self, ctx: &RenderContext) -> Result<()> {
        self.on_scene_change(ctx.gpu);
        Ok(())
    }
    /// Samples per pixel one frame adds (the frame uniforms' `sample_offset` counts them).
    fn samples_per_frame(&self) -> u32 {
        1
    }
    fn render(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
    );
    // Output: a technique writes each pixel's linear HDR sample with
    // `gilab::accumulate::accumulate_sample` into the engine's buffers (bind group 1), averaged
    // over frames (Welford mean and M2) or replaced each frame; `Engine::read_output` and
    // `read_variance` read them.
    /// The technique's parameters, declared in one table (`render::params`).
    fn param_set(&self) -> &params::Params;
    /// The parameters as a preset table.
    fn params(&self) -> toml::Table {
        self.param_set().table()
    }
    /// Checks and applies typed parameter values (all or none); `apply_params` makes them take
    /// effect.
    fn set_params(&mut self, changes: &params::ParamChanges) -> Result<()>;
    /// A preset's TOML table parsed against the technique's table (the edge: presets, `--set`,
    /// the Python API), then applied as `set_params` does.
    fn set_params_from_table(&mut self, table: &toml::Table) -> Result<()> {
        let changes = self.param_set().parse(table)?;
        self.set_params(&changes)
    }
    /// Makes the current parameters take effect on the GPU: uniforms, and resources whose size
    /// depends on a parameter. Never rebuilds pipelines (a slider move costs no shader compile);
    /// the default does nothing, for techniques whose parameters travel in the frame uniforms.
    fn apply_params(&mut self, _ctx: &RenderContext) -> Result<()> {
        Ok(())
    }
    /// The technique's own debug views: each shows one channel of `debug_buffer`.
    fn debug_views(&self) -> Vec<DebugView> {
        Vec::new()
    }
    /// The data behind `debug_views` (written every frame): planes of one vec4<f32> per pixel,
    /// channel c in plane c / 4, component c % 4.
    fn debug_buffer(&self) -> Option<&wgpu::Buffer> {
        None
    }
    /// Frames `Engine::apply_ray_budget` renders to measure rays per frame when no measurement
    /// is given: more where the cost per frame settles only after a warm-up (surfels spawning).
    fn calibration_frames(&self) -> u32 {
        1
    }
    /// Maps a ray budget (rays per pixel per frame) to the technique's own knobs, given the
    /// rays per pixel per frame measured at the current settings (None before any frame).
    /// Returns the parameters to apply, or None when they would not change. The default: no
    /// budget knob.
    fn params_for_ray_budget(
        &self,
        _rays_per_pixel: f64,
        _measured: Option<f64>,
    ) -> Option<params::ParamChanges> {
        None
    }
}

/// Channel `channel` of every pixel from debug data read back as planes of `pixels` vec4s.
pub fn debug_channel(data: &[[f32; 4]], pixels: usize, channel: usize) -> Vec<f32> {
    let plane = channel / 4;
    data.iter()
        .skip(plane * pixels)
        .take(pixels)
        .map(|v| v[channel % 4])
        .collect()
}

/// A technique's debug view: which channel of its debug buffer, and how to show it.
#[derive(Clone, Debug, Serialize)]
pub struct DebugView {
    pub name: &'static str,
    pub channel: usize,
    /// Ids (light index, cell index) get a random colour each; values a log heatmap.
    pub is_id: bool,
}
