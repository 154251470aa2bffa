//! Specular indirect light as a part (issue 35; shared/seeds/000 "Reflections"): the rays,
//! reuse and denoiser that any family plugs in to light glossy surfaces with what they reflect.
//!
//! Four timed passes (`shaders/parts/reflections/`):
//! 1. `reflection trace`: one ray per `downsample`² block along the visible GGX lobe
//!    (`brdf::specular_sample`), through the BVH, lit at the hit: its direct light by one NEE
//!    sample plus its indirect light from the surface cache (`lighting = hit`), or the cache's
//!    radiance alone (`cache`). Families without a cache get one bounce (direct light at hits).
//! 2. `reflection resolve`: each pixel reuses its block's and `reuse` neighbours' rays, weighted
//!    by its own lobe over their pdf (ratio estimator) times the lobe's directional albedo.
//! 3. `reflection temporal`: reprojection by the reflected hit's depth, exponential history.
//! 4. `reflection filter`: bilateral where variance stays high or history is new; writes the
//!    family's output buffer (group 3): `(specular radiance, 0)` per pixel, then a second plane
//!    `(rough albedo, hit kind)`: pixels rougher than `max_roughness` trace no ray, and the
//!    family adds `rough albedo × its own irradiance / π` (the seed's reuse of diffuse rays).
//!
//! What the rays carry never overlaps what a family computes itself: emission is added only
//! along the mirror lobe (NEE at the pixel covers emitters through every other lobe), and the
//! sky on a miss (the families reach the sky by rays).

use crate::gpu::{timing::PassTimer, Gpu};
use crate::parts::Part;
use crate::render::params::{ParamKind, ParamSpec, Params};
use crate::render::{pipelines, DebugView, PassInfo, RenderContext};
use anyhow::Result;
use glam::Vec3;

pub const TRACE: &str = "parts/reflections/trace.wgsl";
pub const RESOLVE: &str = "parts/reflections/resolve.wgsl";
pub const TEMPORAL: &str = "parts/reflections/temporal.wgsl";
pub const FILTER: &str = "parts/reflections/filter.wgsl";
const PASS_NAMES: [&str; 4] = [
    "reflection trace",
    "reflection resolve",
    "reflection temporal",
    "reflection filter",
];

/// The bind group a hit's cache lookup sits at in the trace pass.
pub const CACHE_GROUP: u32 = 3;

/// What lights a reflection ray's hit besides its direct light: the family's cache, whose
/// bindings the trace pass reads at [`CACHE_GROUP`] (a bind group under this layout).
#[derive(Clone, Copy)]
pub enum HitCache<'a> {
    /// Lumen's surface cache (`gilab::surface_cache`).
    SurfaceCache(&'a wgpu::BindGroupLayout),
    /// The surfels' irradiance (`gilab::surfels`).
    Surfels(&'a wgpu::BindGroupLayout),
}
/// Entries per side of the directional-albedo table (shaders/parts/reflections/shared.wgsl).
pub const LUT_SIZE: usize = 32;

/// The part's parameters, the same in every family that plugs it in (appended to its own).
pub const PARAMS: [ParamSpec; 6] = [
    ParamSpec {
        name: "reflections",
        what: "specular indirect light on surfaces with a specular layer (the shared reflections part, seed 000's reflection pipeline): GGX rays traced through the BVH and lit at the hit, reused across neighbours, accumulated and filtered; runs only where the scene has metal or a specular factor",
        higher: "traced: metal and glossy surfaces reflect the scene, one more ray per traced pixel",
        lower: "none: specular surfaces get direct specular only (metal reflecting the room comes out black)",
        kind: ParamKind::Choice(&["traced", "none"]),
        default: 0.0,
    },
    ParamSpec {
        name: "reflection_lighting",
        what: "how a reflection ray's hit is lit: hit lighting (one NEE sample and shadow ray at the hit plus, where the family has a surface cache, its indirect light: the seed's Hit Lighting), the surface cache alone (Lumen's Surface Cache mode; families without a cache use hit lighting), or screen (Callisto's lighting reuse: a hit seen on screen last frame, rougher than reflection_max_roughness and not emissive, takes that pixel's output, with all the light the family computed there; other hits get hit lighting)",
        higher: "cache: no shadow ray, the cache's resolution and lag show in reflections; screen: no shadow ray where the hit is on screen, the family's full lighting there, one frame late and seen from the camera rather than the reflecting point",
        lower: "hit: exact direct light at the hit, one more ray",
        kind: ParamKind::Choice(&["hit", "cache", "screen"]),
        default: 0.0,
    },
    ParamSpec {
        name: "reflection_max_roughness",
        what: "perceptual roughness above which a pixel traces no reflection ray and takes the lobe's directional albedo times the family's own irradiance instead (the seed reuses the screen radiance cache from 0.4 up)",
        higher: "more pixels trace rays: rough reflections keep their directionality, more rays",
        lower: "fewer rays, rough highlights of the room become a diffuse-like sheen",
        kind: ParamKind::Float { min: 0.0, max: 1.0 },
        default: 0.4,
    },
    ParamSpec {
        name: "reflection_downsample",
        what: "one reflection ray per NxN pixel block (the traced pixel jitters each frame); the resolve pass reuses the rays at full resolution",
        higher: "fewer rays (1/N^2 per pixel), blurrier and lagging reflections",
        lower: "a ray per pixel",
        kind: ParamKind::Int { min: 1, max: 4 },
        default: 1.0,
    },
    ParamSpec {
        name: "reflection_reuse",
        what: "neighbours' reflection rays each pixel reuses, weighted by its own lobe over the pdf that drew them (the seed's spatial reuse); 0: its own ray only",
        higher: "less noise, contact detail blurs over the reuse radius",
        lower: "noisier, sharper",
        kind: ParamKind::Int { min: 0, max: 16 },
        default: 4.0,
    },
    ParamSpec {
        name: "reflection_denoise",
        what: "temporal accumulation (reprojected by the reflected hit's depth) and the bilateral filter after reuse",
        higher: "on: stable reflections, ghosting under fast motion",
        lower: "off: each frame's reuse alone",
        kind: ParamKind::Bool,
        default: 1.0,
    },
];

/// The part's debug views, on plane `plane` of the family's debug buffer (its channels
/// 4·plane to 4·plane + 3), filled by [`Reflections::copy_debug`].
pub fn debug_views(plane: usize) -> [DebugView; 4] {
    let view = |name, k: usize, is_id| DebugView {
        name,
        channel: 4 * plane + k,
        is_id,
    };
    [
        view("reflections: rays traced per pixel", 0, false),
        view(
            "reflections: hit kind (1 world, 2 sky, 3 mirror, 4 rough: reuses irradiance)",
            1,
            true,
        ),
        view("reflections: specular radiance (luminance)", 2, false),
        view("reflections: history length (frames)", 3, false),
    ]
}

/// [`PARAMS`] with `reflections = "none"` as the default: for a family whose default is
/// direct light only (Callisto's shadows), where traced reflections are an opt-in.
pub const fn params_off_by_default() -> [ParamSpec; 6] {
    let mut p = PARAMS;
    p[0].default = 1.0;
    p
}

/// What the family's parameters choose.
#[derive(Clone, Debug, PartialEq)]
pub struct ReflectionSettings {
    /// Perceptual roughness above which a pixel traces no ray.
    pub max_roughness: f32,
    pub downsample: u32,
    /// Light at a hit: NEE plus the cache's indirect light (true), or the cache alone.
    pub hit_lighting: bool,
    /// Hits seen on screen last frame take that pixel's output (`reflection_lighting = "screen"`).
    pub screen_reuse: bool,
    pub reuse: u32,
    pub reuse_radius: f32,
    pub temporal: bool,
    pub filter: bool,
    pub max_history: f32,
}

impl ReflectionSettings {
    /// `reflections = "traced"`, and the settings, from a family's parameters (which include
    /// [`PARAMS`]).
    pub fn from_params(p: &Params) -> (bool, ReflectionSettings) {
        let s = ReflectionSettings {
            max_roughness: p.f32("reflection_max_roughness"),
            downsample: p.u32("reflection_downsample"),
            hit_lighting: p.u32("reflection_lighting") != 1,
            screen_reuse: p.u32("reflection_lighting") == 2,
            reuse: p.u32("reflection_reuse"),
            temporal: p.bool("reflection_denoise"),
            filter: p.bool("reflection_denoise"),
            ..Default::default()
        };
        (p.u32("reflections") == 0, s)
    }
}

impl Default for ReflectionSettings {
    fn default() -> Self {
        ReflectionSettings {
            max_roughness: 0.4,
            downsample: 1,
            hit_lighting: true,
            screen_reuse: false,
            reuse: 4,
            reuse_radius: 3.0,
            temporal: true,
            filter: true,
            max_history: 16.0,
        }
    }
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ReflectionParamsGpu {
    pub max_roughness: f32,
    pub downsample: u32,
    pub flags: u32,
    pub reuse: u32,
    pub reuse_radius: f32,
    pub max_history: f32,
    pub trace_width: u32,
    pub trace_height: u32,
    pub output_plane: u32,
    pub pad: [u32; 3],
}

pub const FLAG_HIT_LIGHTING: u32 = 1;
pub const FLAG_TEMPORAL: u32 = 2;
pub const FLAG_FILTER: u32 = 4;
pub const FLAG_DEBUG: u32 = 8;
pub const FLAG_SCREEN_REUSE: u32 = 16;

struct Buffers {
    params: wgpu::Buffer,
    history: wgpu::Buffer,
    debug: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    extent: [u32; 2],
    trace: [u32; 2],
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum CacheKind {
    SurfaceCache,
    Surfels,
}

#[derive(Default)]
pub struct Reflections {
    pub settings: ReflectionSettings,
    layout: Option<wgpu::BindGroupLayout>,
    output_layout: Option<wgpu::BindGroupLayout>,
    /// trace, resolve, temporal, filter.
    pipelines: Option<[wgpu::ComputePipeline; 4]>,
    /// What the trace pass reads at hits (built with).
    with_cache: Option<CacheKind>,
    buffers: Option<Buffers>,
}

impl Reflections {
    /// Group 2 of every pass.
    fn layout(&mut self, gpu: &Gpu) -> wgpu::BindGroupLayout {
        self.layout
            .get_or_insert_with(|| {
                let mut entries = vec![pipelines::uniform_entry(0, wgpu::ShaderStages::COMPUTE)];
                for b in 1..=5 {
                    entries.push(pipelines::storage_entry(b, b == 2));
                }
                pipelines::layout(gpu, "reflections", &entries)
            })
            .clone()
    }

    /// The layout of the output bind group the family makes over its own buffer: two planes
    /// of `pixels` `vec4<f32>` from the plane `record` names.
    pub fn output_layout(&mut self, gpu: &Gpu) -> &wgpu::BindGroupLayout {
        self.output_layout.get_or_insert_with(|| {
            pipelines::layout(
                gpu,
                "reflection output",
                &[pipelines::storage_entry(0, false)],
            )
        })
    }

    /// This frame's four passes; `cache`: the lookup bind group (when built with a cache
    /// layout); `output`: the family's output (a bind group of [`Self::output_layout`]) and the
    /// plane (of `pixels` vec4s) the part's two planes start at in it.
    pub fn record(
        &self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
        cache: Option<&wgpu::BindGroup>,
        (output, output_plane): (&wgpu::BindGroup, u32),
        debug: bool,
    ) {
        let (Some([trace, resolve, temporal, filter]), Some(b)) = (&self.pipelines, &self.buffers)
        else {
            return;
        };
        let s = &self.settings;
        let mut flags = 0;
        for (on, flag) in [
            (s.hit_lighting, FLAG_HIT_LIGHTING),
            (s.temporal, FLAG_TEMPORAL),
            (s.filter, FLAG_FILTER),
            (debug, FLAG_DEBUG),
            (s.screen_reuse, FLAG_SCREEN_REUSE),
        ] {
            if on {
                flags |= flag;
            }
        }
        let params = ReflectionParamsGpu {
            max_roughness: s.max_roughness,
            downsample: s.downsample.max(1),
            flags,
            reuse: s.reuse,
            reuse_radius: s.reuse_radius,
            max_history: s.max_history.max(1.0),
            trace_width: b.trace[0],
            trace_height: b.trace[1],
            output_plane,
            pad: [0; 3],
        };
        ctx.gpu
            .queue
            .write_buffer(&b.params, 0, bytemuck::bytes_of(&params));
        let image = [ctx.extent[0].div_ceil(8), ctx.extent[1].div_ceil(8), 1];
        let traced = [b.trace[0].div_ceil(8), b.trace[1].div_ceil(8), 1];
        let bg = &b.bind_group;
        match (self.with_cache, cache) {
            (Some(_), Some(c)) => {
                pipelines::technique_pass(ctx, enc, timer, PASS_NAMES[0], trace, &[bg, c], traced)
            }
            (None, _) => {
                pipelines::technique_pass(ctx, enc, timer, PASS_NAMES[0], trace, &[bg], traced)
            }
            // Built for a cache that is not there this frame: no rays rather than a bind error.
            (Some(_), None) => return,
        }
        pipelines::technique_pass(ctx, enc, timer, PASS_NAMES[1], resolve, &[bg], image);
        pipelines::technique_pass(ctx, enc, timer, PASS_NAMES[2], temporal, &[bg], image);
        pipelines::technique_pass(ctx, enc, timer, PASS_NAMES[3], filter, &[bg, output], image);
    }

    /// The debug planes (rays traced, hit kind, specular luminance, history length) a family
    /// copies into its own debug buffer.
    pub fn debug_buffer(&self) -> Option<&wgpu::Buffer> {
        self.buffers.as_ref().map(|b| &b.debug)
    }

    /// Copies the part's debug plane (written when `record` ran with `debug`) into plane
    /// `plane` of a family's debug buffer (vec4 planes of the image's size), where
    /// [`debug_views`] shows it.
    pub fn copy_debug(
        &self,
        enc: &mut wgpu::CommandEncoder,
        extent: [u32; 2],
        family_debug: &wgpu::Buffer,
        plane: u32,
    ) {
        if let Some(d) = self.debug_buffer() {
            let bytes = extent[0] as u64 * extent[1] as u64 * 16;
            enc.copy_buffer_to_buffer(d, 0, family_debug, plane as u64 * bytes, bytes);
        }
    }

    /// The passes as a family's pass list shows them: they run when the family's
    /// `reflections = "traced"` (`on`) and the scene has a surface with a specular layer.
    pub fn family_passes(
        &self,
        on: bool,
        f: &crate::scene::features::SceneFeatures,
    ) -> Vec<PassInfo> {
        let why_not = if !on {
            "reflections = none: specular surfaces get direct specular only"
        } else {
            "no surface with a specular layer (metal or specular factor) in the scene"
        };
        self.passes(on && f.min_specular_roughness.is_some(), why_not)
    }

    /// The passes as a family's pass list shows them; `runs`: the family turned them on and the
    /// scene has glossy surfaces.
    pub fn passes(&self, runs: bool, why_not: &str) -> Vec<PassInfo> {
        let s = &self.settings;
        let whys = [
            format!(
                "GGX rays from pixels up to roughness {}, 1 per {}² block; hits lit by {}",
                s.max_roughness,
                s.downsample.max(1),
                match (self.with_cache, s.hit_lighting) {
                    (None, _) => "NEE (no cache: one bounce)",
                    (Some(CacheKind::Surfels), _) => "NEE + the surfels' irradiance",
                    (Some(CacheKind::SurfaceCache), true) => {
                        "NEE + the surface cache's indirect light"
                    }
                    (Some(CacheKind::SurfaceCache), false) => "the surface cache",
                }
            ),
            format!(
                "reuse of {} neighbours' rays within {} traced pixels, weighted by the pixel's lobe",
                s.reuse, s.reuse_radius
            ),
            format!(
                "reprojection by the reflected hit's depth, up to {} frames{}",
                s.max_history,
                if s.temporal { "" } else { " (off)" }
            ),
            format!(
                "bilateral filter where variance is high or history new{}",
                if s.filter { "" } else { " (off)" }
            ),
        ];
        PASS_NAMES
            .iter()
            .zip(whys)
            .map(|(&name, why)| PassInfo {
                name,
                runs,
                why: if runs { why } else { why_not.to_string() },
            })
            .collect()
    }

    /// Reflection rays per pixel per frame at most (one per traced block).
    pub fn rays_per_pixel(&self) -> f64 {
        let ds = self.settings.downsample.max(1) as f64;
        1.0 / (ds * ds)
    }
}

/// The directional albedo of the GGX specular layer (height-correlated Smith, as
/// `brdf::ggx_lobe`) with Fresnel 1 and its (1 - v·h)^5 moment, per (n·v, perceptual
/// roughness) on a `LUT_SIZE`² grid (entry `y * LUT_SIZE + x`, both axes from 0 to 1).
/// Integrated with visible-normal samples (Heitz 2018): f·cos/pdf = G2/G1 for each.
pub fn albedo_table() -> Vec<[f32; 2]> {
    const SAMPLES: u32 = 1024;
    let mut out = Vec::with_capacity(LUT_SIZE * LUT_SIZE);
    for y in 0..LUT_SIZE {
        let roughness = y as f32 / (LUT_SIZE - 1) as f32;
        let alpha = (roughness * roughness).max(1e-3);
        for x in 0..LUT_SIZE {
            let n_dot_v = (x as f32 / (LUT_SIZE - 1) as f32).max(1e-3);
            let wo = Vec3::new((1.0 - n_dot_v * n_dot_v).max(0.0).sqrt(), 0.0, n_dot_v);
            let (mut a, mut b) = (0.0f64, 0.0f64);
            for i in 0..SAMPLES {
                // Hammersley points.
                let u = [(i as f32 + 0.5) / SAMPLES as f32, radical_inverse(i)];
                let h = sample_vndf(wo, alpha, u);
                let wi = 2.0 * wo.dot(h) * h - wo;
                if wi.z <= 0.0 {
                    continue;
                }
                let lv = smith_lambda(wo.z, alpha);
                let ll = smith_lambda(wi.z, alpha);
                let g2_over_g1 = (1.0 + lv) / (1.0 + lv + ll);
                let k = (1.0 - wo.dot(h).clamp(0.0, 1.0)).powi(5);
                a += g2_over_g1 as f64;
                b += (g2_over_g1 * k) as f64;
            }
            out.push([(a / SAMPLES as f64) as f32, (b / SAMPLES as f64) as f32]);
        }
    }
    out
}

fn radical_inverse(mut i: u32) -> f32 {
    i = i.reverse_bits();
    i as f32 * (1.0 / 4_294_967_296.0)
}

fn smith_lambda(cos: f32, alpha: f32) -> f32 {
    let cos_sq = cos * cos;
    let tan_sq = (1.0 - cos_sq).max(0.0) / cos_sq.max(1e-12);
    0.5 * (-1.0 + (1.0 + alpha * alpha * tan_sq).sqrt())
}

/// Heitz 2018's visible-normal sampling, as `sampling::sample_ggx_vndf`.
fn sample_vndf(wo: Vec3, alpha: f32, u: [f32; 2]) -> Vec3 {
    let vh = Vec3::new(alpha * wo.x, alpha * wo.y, wo.z).normalize();
    let lensq = vh.x * vh.x + vh.y * vh.y;
    let t1 = if lensq > 1e-12 {
        Vec3::new(-vh.y, vh.x, 0.0) / lensq.sqrt()
    } else {
        Vec3::X
    };
    let t2 = vh.cross(t1);
    let r = u[0].sqrt();
    let phi = std::f32::consts::TAU * u[1];
    let p1 = r * phi.cos();
    let s = 0.5 * (1.0 + vh.z);
    let p2 = (1.0 - s) * (1.0 - p1 * p1).max(0.0).sqrt() + s * r * phi.sin();
    let nh = p1 * t1 + p2 * t2 + (1.0 - p1 * p1 - p2 * p2).max(0.0).sqrt() * vh;
    Vec3::new(alpha * nh.x, alpha * nh.y, nh.z.max(1e-6)).normalize()
}

/// `Input`: what the trace pass reads at hits (at group [`CACHE_GROUP`]); none: direct light
/// only.
impl Part for Reflections {
    type Input<'a> = Option<HitCache<'a>>;

    fn is_built(&self) -> bool {
        self.pipelines.is_some()
    }

    /// Builds the four pipelines (on an error nothing is replaced). `cache`: what the trace
    /// pass reads at hits (at group [`CACHE_GROUP`]); none: direct light only.
    fn build(&mut self, ctx: &RenderContext, cache: Option<HitCache<'_>>) -> Result<()> {
        let layout = self.layout(ctx.gpu);
        let output = self.output_layout(ctx.gpu).clone();
        let base = [&ctx.scene.layout, ctx.frame_layout, &layout];
        let trace = match cache {
            Some(hit_cache) => {
                let (defs, cache_layout) = match hit_cache {
                    HitCache::SurfaceCache(l) => (
                        [
                            ("REFLECTION_CACHE", 1),
                            crate::parts::surface_cache::lookup_defs(CACHE_GROUP)[0],
                        ],
                        l,
                    ),
                    HitCache::Surfels(l) => (
                        [("REFLECTION_SURFELS", 1), ("SURFELS_GROUP", CACHE_GROUP)],
                        l,
                    ),
                };
                let shaders = ctx.shaders.with_defs(&defs);
                pipelines::compute_pipeline(
                    ctx.gpu,
                    &shaders,
                    TRACE,
                    &[&ctx.scene.layout, ctx.frame_layout, &layout, cache_layout],
                )?
            }
            None => pipelines::compute_pipeline(ctx.gpu, ctx.shaders, TRACE, &base)?,
        };
        let resolve = pipelines::compute_pipeline(ctx.gpu, ctx.shaders, RESOLVE, &base)?;
        let temporal = pipelines::compute_pipeline(ctx.gpu, ctx.shaders, TEMPORAL, &base)?;
        let filter = pipelines::compute_pipeline(
            ctx.gpu,
            ctx.shaders,
            FILTER,
            &[&ctx.scene.layout, ctx.frame_layout, &layout, &output],
        )?;
        self.pipelines = Some([trace, resolve, temporal, filter]);
        self.with_cache = cache.map(|c| match c {
            HitCache::SurfaceCache(_) => CacheKind::SurfaceCache,
            HitCache::Surfels(_) => CacheKind::Surfels,
        });
        Ok(())
    }

    /// Buffers sized by the image and `downsample` (kept while those hold) and the parameters.
    fn build_resources(&mut self, ctx: &RenderContext) {
        let gpu = ctx.gpu;
        let ds = self.settings.downsample.max(1);
        let trace = [ctx.extent[0].div_ceil(ds), ctx.extent[1].div_ceil(ds)];
        let keep = matches!(&self.buffers, Some(b) if b.extent == ctx.extent && b.trace == trace);
        if !keep {
            let px = ctx.extent[0] as u64 * ctx.extent[1] as u64;
            let samples = trace[0] as u64 * trace[1] as u64 * 3 * 16;
            let params = gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("reflection params"),
                size: std::mem::size_of::<ReflectionParamsGpu>() as u64,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let rays = pipelines::storage_buffer(gpu, "reflection rays", samples);
            let lut = wgpu::util::DeviceExt::create_buffer_init(
                &gpu.device,
                &wgpu::util::BufferInitDescriptor {
                    label: Some("reflection albedo table"),
                    contents: bytemuck::cast_slice(&albedo_table()),
                    usage: wgpu::BufferUsages::STORAGE,
                },
            );
            let resolved = pipelines::storage_buffer(gpu, "reflection resolved", px * 32);
            let history = pipelines::storage_buffer(gpu, "reflection history", px * 64);
            let debug = pipelines::storage_buffer(gpu, "reflection debug", px * 16);
            let layout = self.layout(gpu);
            let bind_group = pipelines::buffers_bind_group(
                gpu,
                "reflections",
                &layout,
                &[&params, &rays, &lut, &resolved, &history, &debug],
            );
            self.buffers = Some(Buffers {
                params,
                history,
                debug,
                bind_group,
                extent: ctx.extent,
                trace,
            });
        }
    }

    /// Forgets the accumulated reflections (camera cut, parameter change).
    fn reset(&self, gpu: &Gpu) {
        if let Some(b) = &self.buffers {
            let mut enc = gpu.device.create_command_encoder(&Default::default());
            enc.clear_buffer(&b.history, 0, None);
            gpu.submit("reflections: history reset", enc.finish());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn albedo_table_is_bounded_and_smooth_lobes_keep_their_energy() {
        let t = albedo_table();
        assert_eq!(t.len(), LUT_SIZE * LUT_SIZE);
        for [a, b] in &t {
            assert!(
                *a >= 0.0 && *a <= 1.0001 && *b >= 0.0 && *b <= *a + 1e-6,
                "{a} {b}"
            );
        }
        // A near-mirror lobe reflects everything at normal incidence, with no Fresnel moment.
        let [a, b] = t[LUT_SIZE - 1];
        assert!((a - 1.0).abs() < 1e-3 && b < 1e-3, "{a} {b}");
        // Rough lobes lose energy to single scattering: 0.307 at roughness 1 and normal
        // incidence (an independent integration in Python, 4,096 samples, gave 0.3069).
        let [a, _] = t[(LUT_SIZE - 1) * LUT_SIZE + LUT_SIZE - 1];
        assert!((a - 0.307).abs() < 0.01, "{a}");
    }
}
