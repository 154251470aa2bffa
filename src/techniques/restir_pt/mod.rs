//! # ReSTIR PT (`restir-pt`)
//!
//! Resampled whole paths with the hybrid shift of Lin et al. 2022 ("Generalized Resampled
//! Importance Sampling: Foundations of ReSTIR", SIGGRAPH; the shift RTXDI 3.0 ships). Per pixel
//! and frame, on the engine's primary surfaces:
//!
//! Pass names carry `path_` so they never collide with the direct-light part's (`spatial`).
//!
//! 1. `path_initial`: one path traced as the reference traces it (NEE with MIS at every vertex,
//!    bounded by `max_bounces`, no Russian roulette); its contributions (one per length and
//!    end) are candidates resampled by luminance into the pixel's path reservoir. The reservoir
//!    keeps the reconnection vertex (triangle + barycentrics, so it follows moving objects),
//!    the suffix radiance there, the path's seed, length and end. With `suffix_terminate`
//!    naming a cache (the caches of ReSTIR GI's `gi_terminate`, through
//!    [`crate::parts::gi_cache`]), the suffix ends at its first hit the cache covers: the
//!    cache's passes run first and this pass reads its lookup.
//! 2. `path_temporal`: last frame's reservoir at the reprojected pixel, pairwise MIS (two shifts).
//! 3. `path_spatial`: `spatial_count` neighbours, pairwise MIS with the canonical sample (two
//!    shifts per neighbour: GRIS's generalised balance heuristic in its pairwise form). With
//!    `spatial_pairs` the neighbours are p ± d for per-frame offsets d, and `path_pairs` traces
//!    each pair's two shifts once for both of its pixels (ReSTIR PT Enhanced's reciprocal
//!    neighbours: half the shifts).
//! 4. `shade`: F × W of the kept path, emission, accumulation.
//!
//! The shift (hybrid, or reconnection / replay only) and its Jacobians are described in
//! shaders/restir_pt/shared.wgsl; tests/restir_pt.rs checks the Jacobians against finite
//! differences on the CPU ([`shift_math`]). Direct light is either in the same reservoirs
//! (`direct = "unified"`) or ReSTIR DI's through the direct-light part (`"restir"`).

mod params;
pub mod shift_math;

pub use params::{PtParamsGpu, PtSettings, MAX_SPATIAL, PARAMS};

use crate::gpu::{timing::PassTimer, Gpu};
use crate::parts::gi_cache::{CacheReader, CacheSettings, ReaderPass};
use crate::parts::restir::{RestirSettings, PARAMS as RESTIR_PARAMS};
use crate::parts::Part;
use crate::parts::RestirDirect;
use crate::render::params::{ParamChanges, Params};
use crate::render::primary::FrameInputs;
use crate::render::{pipelines, DebugView, PassInfo, RenderContext, Technique};
use crate::scene::features::SceneFeatures;
use anyhow::Result;

/// Bytes of `PathReservoir` in shaders/restir_pt/shared.wgsl.
pub const PATH_RESERVOIR_BYTES: u64 = 80;
/// Reservoir segments: final of even frames, final of odd frames, this frame's working copy.
const SEGMENTS: u64 = 3;
/// Bytes of `PairShift` in shaders/restir_pt/shared.wgsl, and of a pixel's pairs (`MAX_PAIRS`
/// offsets, two shifts each).
const PAIR_SHIFT_BYTES: u64 = 32;
const PAIR_BYTES_PER_PIXEL: u64 = 2 * (MAX_SPATIAL as u64).div_ceil(2) * PAIR_SHIFT_BYTES;

const OWN_SHADER_FILES: [&str; 5] = [
    "restir_pt/initial.wgsl",
    "restir_pt/temporal.wgsl",
    "restir_pt/spatial.wgsl",
    "restir_pt/shade.wgsl",
    "restir_pt/pairs.wgsl",
];

#[derive(Default)]
struct Pipelines {
    initial: Option<wgpu::ComputePipeline>,
    temporal: Option<wgpu::ComputePipeline>,
    spatial: Option<wgpu::ComputePipeline>,
    shade: Option<wgpu::ComputePipeline>,
    pairs: Option<wgpu::ComputePipeline>,
}

/// Buffers sized by the image, and the bind groups over them.
struct Resources {
    extent: [u32; 2],
    params: wgpu::Buffer,
    reservoirs: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    /// The direct-light part's output, over the `direct_light` buffer the shading pass reads.
    direct_bind_group: wgpu::BindGroup,
    debug: wgpu::Buffer,
}

pub struct RestirPt {
    params: Params,
    pub settings: PtSettings,
    layout: Option<wgpu::BindGroupLayout>,
    pipelines: Pipelines,
    resources: Option<Resources>,
    restir_direct: RestirDirect,
    /// `suffix_terminate` names a cache: the cache and `path_initial` composed to read it.
    cache: Option<CacheReader>,
    scene_diagonal: f32,
}

impl Default for RestirPt {
    fn default() -> Self {
        let params = Params::new("restir-pt", PARAMS);
        RestirPt {
            settings: PtSettings::from_params(&params),
            params,
            layout: None,
            pipelines: Pipelines::default(),
            resources: None,
            restir_direct: RestirDirect::default(),
            cache: None,
            scene_diagonal: 1.0,
        }
    }
}

impl RestirPt {
    fn layout(&mut self, gpu: &Gpu) -> wgpu::BindGroupLayout {
        self.layout
            .get_or_insert_with(|| {
                pipelines::layout(
                    gpu,
                    "restir-pt",
                    &[
                        pipelines::uniform_entry(0, wgpu::ShaderStages::COMPUTE),
                        pipelines::storage_entry(1, false),
                        pipelines::storage_entry(2, false),
                        pipelines::storage_entry(3, false),
                        pipelines::storage_entry(4, false),
                    ],
                )
            })
            .clone()
    }

    /// Reservoir memory per pixel (bytes): three segments of one path reservoir.
    pub fn reservoir_bytes_per_pixel() -> u64 {
        SEGMENTS * PATH_RESERVOIR_BYTES
    }

    /// Memory of paired spatial reuse's shifts per pixel (bytes; allocated whether or not
    /// `spatial_pairs` is on, so that switching it rebuilds nothing).
    pub fn pair_bytes_per_pixel() -> u64 {
        PAIR_BYTES_PER_PIXEL
    }

    fn write_params(&self, gpu: &Gpu) {
        if let Some(r) = &self.resources {
            let pixels = r.extent[0] * r.extent[1];
            let p = self.settings.gpu(pixels, self.scene_diagonal);
            gpu.queue.write_buffer(&r.params, 0, bytemuck::bytes_of(&p));
        }
    }

    fn build_resources(&mut self, ctx: &RenderContext) {
        let gpu = ctx.gpu;
        let f = &ctx.scene.data.features;
        let lo = glam::Vec3::from(f.bounds_min);
        let hi = glam::Vec3::from(f.bounds_max);
        self.scene_diagonal = (hi - lo).length().max(1e-6);
        if self.resources.as_ref().map(|r| r.extent) != Some(ctx.extent) {
            let pixels = ctx.extent[0] as u64 * ctx.extent[1] as u64;
            let layout = self.layout(gpu);
            let params = gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("restir-pt params"),
                size: std::mem::size_of::<PtParamsGpu>() as u64,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let reservoirs = pipelines::storage_buffer(
                gpu,
                "restir-pt reservoirs",
                SEGMENTS * pixels * PATH_RESERVOIR_BYTES,
            );
            let debug = pipelines::storage_buffer(gpu, "restir-pt debug", 2 * pixels * 16);
            let direct = pipelines::storage_buffer(gpu, "restir-pt direct light", pixels * 16);
            let pair_shifts = pipelines::storage_buffer(
                gpu,
                "restir-pt pair shifts",
                pixels * PAIR_BYTES_PER_PIXEL,
            );
            let bind_group = pipelines::buffers_bind_group(
                gpu,
                "restir-pt",
                &layout,
                &[&params, &reservoirs, &debug, &direct, &pair_shifts],
            );
            let direct_layout = self.restir_direct.output_layout(gpu).clone();
            let direct_bind_group = pipelines::buffers_bind_group(
                gpu,
                "restir-pt direct output",
                &direct_layout,
                &[&direct],
            );
            self.resources = Some(Resources {
                extent: ctx.extent,
                params,
                reservoirs,
                bind_group,
                direct_bind_group,
                debug,
            });
        }
        self.write_params(gpu);
    }

    fn prepare_direct(&mut self, ctx: &RenderContext, rebuild: bool) -> Result<()> {
        self.restir_direct
            .prepare(ctx, self.settings.direct_restir, rebuild, ())
    }

    /// The cache a suffix ends in: at ReSTIR's cache defaults (`cache_atlas_size`,
    /// `cache_update`, `cache_ray_budget`, `cache_direct`).
    fn cache_settings() -> CacheSettings {
        RestirSettings::from_params(&Params::new("restir", RESTIR_PARAMS)).cache_settings()
    }

    /// Builds the cache `suffix_terminate` names and `path_initial` composed to read it, when
    /// they are not built for it yet, or again on `rebuild` (a shader changed). A cache
    /// switched off stays built (switching back costs no compile) and is not recorded.
    fn prepare_cache(&mut self, ctx: &RenderContext, rebuild: bool) -> Result<()> {
        let Some(kind) = self.settings.suffix_terminate.kind() else {
            // Switched off: kept for switching back, unless its shaders changed.
            if rebuild {
                self.cache = None;
            }
            return Ok(());
        };
        let settings = Self::cache_settings();
        let current = self.cache.as_ref().map(|c| c.cache.key());
        if !rebuild && current == Some((kind.key)(&settings)) {
            return Ok(());
        }
        let layout = self.layout(ctx.gpu);
        let pass = ReaderPass {
            entry: OWN_SHADER_FILES[0],
            layout: &layout,
            defs: &[("SUFFIX_TERMINATE", 1)],
        };
        let (reader, built) = CacheReader::build(ctx, self.cache.take(), kind, &settings, pass);
        self.cache = reader;
        built
    }
}

impl Technique for RestirPt {
    fn id(&self) -> &'static str {
        "restir-pt"
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn inputs(&self) -> FrameInputs {
        FrameInputs {
            primary_surfaces: true,
        }
    }

    fn passes(&self, f: &SceneFeatures) -> Vec<PassInfo> {
        let s = &self.settings;
        let mut v = Vec::new();
        if s.direct_restir {
            v.extend(self.restir_direct.passes(f));
            v.push(PassInfo {
                name: "direct",
                runs: true,
                why: RestirDirect::describe(),
            });
        }
        let suffix_end = match s.suffix_terminate.kind() {
            Some(kind) => {
                if let Some(c) = &self.cache {
                    v.extend(c.cache.passes(f));
                }
                format!(
                    "; its suffix ends in {} at its first hit past the reconnection vertex that the cache covers",
                    kind.name
                )
            }
            None => String::new(),
        };
        v.push(PassInfo {
            name: "path_initial",
            runs: true,
            why: format!(
                "one path per pixel (NEE + MIS, up to {} bounces), its contributions resampled into a path reservoir{}{}",
                s.max_bounces,
                if s.direct_restir {
                    " (length 2 left to ReSTIR DI)"
                } else {
                    ""
                },
                suffix_end
            ),
        });
        v.push(PassInfo {
            name: "path_temporal",
            runs: s.temporal,
            why: if s.temporal {
                format!(
                    "last frame's path shifted here ({} shift), pairwise MIS",
                    params::SHIFTS[s.shift]
                )
            } else {
                "temporal = false".into()
            },
        });
        v.push(PassInfo {
            name: "path_pairs",
            runs: s.pairs() > 0,
            why: if s.pairs() > 0 {
                format!(
                    "{} offsets within {} px: each pair of pixels' two shifts, traced once for both",
                    s.pairs(),
                    s.spatial_radius
                )
            } else {
                "spatial_pairs = false".into()
            },
        });
        v.push(PassInfo {
            name: "path_spatial",
            runs: true,
            why: if s.pairs() > 0 {
                format!(
                    "{} neighbours (p +- each offset), pairwise MIS from the pairs' shifts",
                    2 * s.pairs()
                )
            } else if s.spatial_count > 0 {
                format!(
                    "{} neighbours within {} px, two shifts each (pairwise MIS)",
                    s.spatial_count, s.spatial_radius
                )
            } else {
                "spatial_count = 0: copies the reservoir".into()
            },
        });
        v.push(PassInfo {
            name: "shade",
            runs: true,
            why:
                "F x W of the kept path (its shifts traced the visibility), emission, accumulation"
                    .into(),
        });
        v
    }

    fn build(&mut self, ctx: &RenderContext) -> Result<()> {
        let layout = self.layout(ctx.gpu);
        // Everything first: a failure leaves the previous pipelines in place.
        let initial = ctx.pipeline(OWN_SHADER_FILES[0], &layout)?;
        let temporal = ctx.pipeline(OWN_SHADER_FILES[1], &layout)?;
        let spatial = ctx.pipeline(OWN_SHADER_FILES[2], &layout)?;
        let shade = ctx.pipeline(OWN_SHADER_FILES[3], &layout)?;
        let pairs = ctx.pipeline(OWN_SHADER_FILES[4], &layout)?;
        self.prepare_direct(ctx, true)?;
        self.prepare_cache(ctx, true)?;
        self.pipelines = Pipelines {
            initial: Some(initial),
            temporal: Some(temporal),
            spatial: Some(spatial),
            shade: Some(shade),
            pairs: Some(pairs),
        };
        self.build_resources(ctx);
        Ok(())
    }

    fn apply_params(&mut self, ctx: &RenderContext) -> Result<()> {
        self.prepare_direct(ctx, false)?;
        self.prepare_cache(ctx, false)?;
        self.build_resources(ctx);
        Ok(())
    }

    fn reset_history(&mut self, gpu: &Gpu) {
        if let Some(r) = &self.resources {
            let mut enc = gpu.device.create_command_encoder(&Default::default());
            enc.clear_buffer(&r.reservoirs, 0, None);
            gpu.submit("restir-pt: reservoir reset", enc.finish());
        }
        self.restir_direct.reset(gpu);
    }

    /// The reservoirs carry over, as they would in a game (the engine restarts the average).
    fn on_scene_change(&mut self, _gpu: &Gpu) {}

    /// Reconnection vertices are triangle points: they follow their objects, and every shift
    /// traces this frame's geometry, so nothing needs forgetting.
    fn on_geometry_moved(&mut self, _ctx: &RenderContext) -> Result<()> {
        Ok(())
    }

    fn render(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
    ) {
        let (Some(initial), Some(temporal), Some(spatial), Some(shade), Some(pairs)) = (
            &self.pipelines.initial,
            &self.pipelines.temporal,
            &self.pipelines.spatial,
            &self.pipelines.shade,
            &self.pipelines.pairs,
        ) else {
            return;
        };
        let Some(r) = &self.resources else {
            return;
        };
        if self.restir_direct.active(self.settings.direct_restir) {
            self.restir_direct
                .record(ctx, enc, timer, &r.direct_bind_group);
        }
        let bg = &r.bind_group;
        let suffix_cache = self
            .settings
            .suffix_terminate
            .cache()
            .then_some(self.cache.as_mut())
            .flatten();
        // With a cache: its passes, then the initial pass that reads its lookup (the plain
        // pass while the lookup is not there yet).
        let mut read_cache = false;
        if let Some(c) = suffix_cache {
            c.cache.record(ctx, enc, timer);
            if let Some(lookup) = c.cache.lookup() {
                let groups = [ctx.extent[0].div_ceil(8), ctx.extent[1].div_ceil(8), 1];
                let bind_groups = [bg, lookup];
                pipelines::technique_pass(
                    ctx,
                    enc,
                    timer,
                    "path_initial",
                    &c.pipeline,
                    &bind_groups,
                    groups,
                );
                read_cache = true;
            }
        }
        if !read_cache {
            pipelines::image_pass(ctx, enc, timer, "path_initial", initial, bg);
        }
        if self.settings.temporal {
            pipelines::image_pass(ctx, enc, timer, "path_temporal", temporal, bg);
        }
        if self.settings.pairs() > 0 {
            pipelines::image_pass(ctx, enc, timer, "path_pairs", pairs, bg);
        }
        pipelines::image_pass(ctx, enc, timer, "path_spatial", spatial, bg);
        pipelines::image_pass(ctx, enc, timer, "shade", shade, bg);
    }

    fn debug_views(&self) -> Vec<DebugView> {
        let view = |name, channel, is_id| DebugView {
            name,
            channel,
            is_id,
        };
        vec![
            view("reconnection vertex r (0 = replay)", 0, true),
            view("shift kind (0 replay, 1 reconnection, 2 hybrid)", 1, true),
            view("shift failure rate", 2, false),
            view("|log10 Jacobian| of the kept shift", 3, false),
            view("path length k", 4, true),
            view("reservoir M", 5, false),
            view("reservoir weight W", 6, false),
            view("target luminance(F)", 7, false),
        ]
    }

    fn debug_buffer(&self) -> Option<&wgpu::Buffer> {
        self.resources.as_ref().map(|r| &r.debug)
    }

    fn param_set(&self) -> &Params {
        &self.params
    }

    fn set_params(&mut self, changes: &ParamChanges) -> Result<()> {
        self.params.apply(changes)?;
        self.settings = PtSettings::from_params(&self.params);
        Ok(())
    }

    /// The budget knob is `spatial_count`: each neighbour costs two shifts (one with
    /// `spatial_pairs`), about one ray each
    /// where paths reconnect at their first bounce (more where they replay), measured when a
    /// measurement is given; the path and the temporal shifts are the fixed part.
    fn params_for_ray_budget(
        &self,
        rays_per_pixel: f64,
        measured: Option<f64>,
    ) -> Option<ParamChanges> {
        let s = &self.settings;
        // Spatial shifts per neighbour: two, or one with `spatial_pairs` (a pair's two shifts
        // serve both of its pixels).
        let per_neighbour = if s.spatial_pairs { 1.0 } else { 2.0 };
        let neighbours = |n: u32| {
            if s.spatial_pairs {
                2 * n.min(MAX_SPATIAL).div_ceil(2)
            } else {
                n
            }
        };
        let shifts =
            |n: u32| per_neighbour * neighbours(n) as f64 + if s.temporal { 2.0 } else { 0.0 };
        let assumed_path = 2.0 * s.max_bounces.min(3) as f64 + 1.0;
        let (fixed, per_shift) = match measured {
            Some(m) if m > 0.0 => {
                let path = assumed_path.min(m);
                let reuse = (m - path).max(0.0);
                let n = shifts(s.spatial_count);
                (path, if n > 0.0 { reuse / n } else { 1.0 }.max(0.25))
            }
            _ => (assumed_path, 1.0),
        };
        let temporal = shifts(0) * per_shift;
        let left = rays_per_pixel - fixed - temporal;
        let count = ((left / (per_neighbour * per_shift)).floor().max(0.0) as u32).min(MAX_SPATIAL);
        (count != s.spatial_count).then(|| ParamChanges::new().int("spatial_count", count as i64))
    }
}
