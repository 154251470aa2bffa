//! # Lumen-style GI (`lumen`): scene representation, world tracing, screen-probe final gather
//!
//! "Lumen: Real-time Global Illumination in Unreal Engine 5" (SIGGRAPH 2022 Advances,
//! shared/seeds/000). Per frame:
//!
//! 1. Global distance field (only when something changed): camera-centred clipmaps of sparse
//!    8^3 bricks holding a narrow band (+-4 voxels), plus a quarter-resolution coarse volume for
//!    empty-space skipping. `sdf_release` frees the bricks a scroll or a scene edit made stale,
//!    `sdf_allocate` gives a pool brick to each slot near a triangle, `sdf_fill` computes each
//!    voxel's distance (BVH point query) and sign (back-face ray counts), one timed dispatch per
//!    level, and `sdf_coarse` rebuilds the coarse volume of updated levels. `voxel_visibility`
//!    runs with each level's fill: per lighting voxel (4^3 per brick) and axis direction, the
//!    surface BVH rays across the voxel meet (the seed's voxel lighting visibility buffer).
//! 2. The surface cache, a part Lumen holds (`crate::parts::surface_cache`, like the world
//!    cache): `capture`: this frame's cards (closest first, 512^2 texels per frame) are
//!    rasterised with their orthographic cameras into the atlas: albedo, normal, emission, depth.
//! 3. Surface cache lighting (the same part): `cache direct` (one light sample and shadow ray per texel of this
//!    frame's 8x8 tiles), `cache probes` (a 16-ray hemisphere probe per 4x4 tile, hits read the
//!    cache itself: multi-bounce through feedback) and `cache indirect` (texels interpolate
//!    their four probes with plane and hit-distance weights, blended over at most 4 frames).
//!    Then `voxel lighting` (SDF tracing): the visibility hits shaded from their cards, which
//!    SDF hits whose own cards give no answer read instead (the seed's voxel lighting).
//! 4. The final gather, `final_gather = screen_probes` (the seed's Screen Space Radiance Cache,
//!    `screen_probes.rs`): world radiance cache probes selected and traced (`world select`,
//!    `world update`), last frame's closest-depth mips (`hzb`), probes placed on a jittered
//!    16x16 grid plus adaptive ones (`probe place`, `probe adaptive`), 64 ray directions per
//!    probe importance sampled from BRDF x last frame's probe radiance (`probe sample`), screen
//!    traces first, the unresolved rays compacted and traced in the world to
//!    `world_cache_distance`, then the world cache (`screen trace`, `world trace`), per-cell
//!    resolve with temporal blend, spatial filter, and per-pixel `integrate` (irradiance from
//!    the probes of the pixel's plane, full-resolution temporal filter, contact AO).
//!    `final_gather = pixels` is part 1's `gather`: cosine rays per pixel (or per
//!    `gather_downsample` block) lit by the cache.
//! 5. Reflections (`reflections = "traced"`, scenes with glossy surfaces): the shared part
//!    `crate::parts::reflections`, its trace pass reading this cache at hits.
//! 6. `apply`: emission + NEE + albedo x irradiance / pi + specular, debug views, accumulation.
//!
//! Rays trace the SDF or the BVH (`tracing`) through one function, so both read the same cache.
//! Files: `params.rs` (the table), `sdf.rs` (clipmap placement and update plans),
//! `screen_probes.rs` (the final gather's buffers and passes), this file (GPU resources and
//! passes). The caches are parts: the surface cache (`src/parts/surface_cache/`: cards, atlas,
//! captures and cache lighting) and the world radiance cache (`src/parts/world_cache.rs`); Lumen
//! binds the surface cache's resources into its group 2, where its tracing and final gather read
//! them, and its passes trace through Lumen's scene representation (that group).

mod frame;
mod inspect;
pub mod params;
mod resources;
pub mod screen_probes;
pub mod sdf;

use crate::parts::Part;
use crate::render::pipelines::init_buffer;
pub use params::{LumenSettings, TracingParamsGpu, FLAG_BVH, FLAG_LIGHTS, FLAG_SKY, PARAMS};
pub use screen_probes::ProbeStats;
use screen_probes::{ProbePipelines, ScreenProbes};

use crate::gpu::{readback, timing::PassTimer, Gpu};
use crate::parts::reflections::HitCache;
use crate::parts::surface_cache::{Refresh, SurfaceCache};
use crate::parts::tracing::DistanceFieldTexels;
use crate::parts::world_cache::{WorldCache, WorldCachePipelines};
use crate::parts::{Reflections, RestirDirect};
use crate::render::params::{ParamChanges, Params};
use crate::render::primary::FrameInputs;
use crate::render::{pipelines, DebugView, PassInfo, RenderContext, Technique};
use crate::scene::features::SceneFeatures;
use anyhow::Result;
use glam::Vec3;
use params::*;
use sdf::{Clipmaps, MAX_LEVELS};

crate::compute_passes! {
    /// Lumen's passes on its group 2 (query and apply with a group of their own besides), in
    /// pipeline order.
    pub(crate) enum Pass {
        SdfRelease => ("sdf release", "lumen/sdf_release.wgsl"),
        SdfAllocate => ("sdf allocate", "lumen/sdf_allocate.wgsl"),
        SdfCoarse => ("sdf coarse", "lumen/sdf_coarse.wgsl"),
        Gather => ("gather", "lumen/gather.wgsl"),
        Apply => ("apply", "lumen/apply.wgsl"),
        Query => ("query", "lumen/query.wgsl"),
        VoxelLighting => ("voxel lighting", "lumen/voxel_lighting.wgsl"),
    }
}
const SDF_ARGS: &str = "lumen/sdf_args.wgsl";
const SDF_FILL: &str = "lumen/sdf_fill.wgsl";
/// Run with each level's fill, over the same bricks (and the fill's group 3).
const VOXEL_VISIBILITY: &str = "lumen/voxel_visibility.wgsl";
const FILL_PASS_NAMES: [&str; MAX_LEVELS] = [
    "sdf fill L0",
    "sdf fill L1",
    "sdf fill L2",
    "sdf fill L3",
    "sdf fill L4",
    "sdf fill L5",
];
/// Queries one call can answer.
pub const QUERY_CAPACITY: usize = 1 << 16;
const BRICK_BYTES: u64 = 512 * 4;
/// A brick's voxel lighting behind the distances in the pool (shaders/parts/tracing/shared.wgsl,
/// `voxel_word_index`): 4^3 lighting voxels x 6 directions, visibility then radiance.
const VOXEL_LIGHTING_BYTES: u64 = 2 * 64 * 6 * 4;

/// What a query asks (shaders/lumen/query.wgsl).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum QueryMode {
    /// Distance at points: in (x, y, z), out (distance, object, level, 0).
    SdfDistance = 0,
    /// Sphere-traced rays (origin, direction), out (t, hit, steps, level).
    SdfTrace = 1,
    /// The same rays through the BVH, out (t, hit, 0, 0).
    BvhTrace = 2,
    /// Like `SdfTrace`, with the expand the technique traces with (the origin is used as given).
    SdfTraceExpanded = 4,
    /// Rays as the technique traces them in its `tracing` mode from surface points (point,
    /// normal), a cosine direction hashed from the index: out (t, hit, back face, cache weight),
    /// (reflected luminance, best card or -1, object, answered by: 0 nothing, 1 the cards,
    /// 2 the voxel lighting).
    CacheRay = 3,
    /// The same rays, the voxel lighting and the cards apart: out (t, hit, back face, voxel
    /// lighting weight), (voxel lighting luminance, cards' luminance, card weight, 0).
    VoxelRay = 5,
    /// `CacheRay`'s rays through the BVH in either `tracing` mode, shaded from the cards with
    /// the BVH's depth tolerance: the same cache traced exactly, out as `CacheRay`.
    CacheRayBvh = 6,
}

/// Global SDF counters read back for tests and the README.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SdfStats {
    pub pool_bricks: u32,
    pub allocated_bricks: u32,
    pub failed_allocations: u32,
    pub levels_built: u32,
}

struct Layouts {
    lumen: wgpu::BindGroupLayout,
    /// Group 3 of `sdf_args`: the fill dispatches it writes.
    args: wgpu::BindGroupLayout,
    /// Group 3 of `sdf_fill`: the level it fills.
    fill_level: wgpu::BindGroupLayout,
    /// Group 1 of the query pipeline (it needs no frame): the query buffer.
    queries: wgpu::BindGroupLayout,
    /// Group 3 of the direct-light part's pass: `pixel_direct` (binding 18), which apply reads.
    direct: wgpu::BindGroupLayout,
    /// Group 3 of the final gather's passes and `apply`: screen probes, world cache.
    probes: wgpu::BindGroupLayout,
    /// Group 3 of the reflections part's filter: `pixel_direct` (binding 18), whose second and
    /// third planes it writes (apply's pipeline is at the 32 storage buffers a stage may bind).
    specular: wgpu::BindGroupLayout,
}

struct Pipelines {
    compute: Vec<wgpu::ComputePipeline>,
    sdf_args: wgpu::ComputePipeline,
    sdf_fill: wgpu::ComputePipeline,
    voxel_visibility: wgpu::ComputePipeline,
    query: wgpu::ComputePipeline,
    apply: wgpu::ComputePipeline,
    probes: ProbePipelines,
    world: WorldCachePipelines,
}

impl Pipelines {
    fn get(&self, pass: Pass) -> &wgpu::ComputePipeline {
        &self.compute[pass as usize]
    }
}

struct Resources {
    params_buffer: wgpu::Buffer,
    /// Lumen's own buffers of group 2 by binding (0, 4..=11, 16..=18); the surface cache's
    /// fill the others.
    buffers: Vec<(u32, wgpu::Buffer)>,
    /// The distance field's texel copies (27-30), which everything that traces it reads.
    sdf_texels: DistanceFieldTexels,
    bind_group: wgpu::BindGroup,
    args_bind_group: wgpu::BindGroup,
    fill_bind_groups: Vec<wgpu::BindGroup>,
    query_bind_group: wgpu::BindGroup,
    queries: wgpu::Buffer,
    /// `pixel_direct` for the direct-light part's pass to write.
    direct_bind_group: wgpu::BindGroup,
    /// `pixel_direct` for the reflections part's filter to write (planes 1 and 2).
    specular_bind_group: wgpu::BindGroup,
    args: wgpu::Buffer,
    gpu_params: TracingParamsGpu,
    /// The world radiance cache (a part: `crate::parts::world_cache`), read by the screen
    /// probes and, through the surface-cache part, by ReSTIR GI's `lumen-world` paths.
    world: WorldCache,
    probes: ScreenProbes,
}

impl Resources {
    fn buffer(&self, binding: u32) -> &wgpu::Buffer {
        &self
            .buffers
            .iter()
            .find(|(b, _)| *b == binding)
            .expect("one of Lumen's bindings")
            .1
    }

    /// Records the copy of the distance field's buffers into its texels (after an update's
    /// passes, before anything traces).
    fn copy_sdf_texels(&self, enc: &mut wgpu::CommandEncoder) {
        self.sdf_texels.copy(
            enc,
            self.buffer(4),
            self.buffer(5),
            self.buffer(6),
            self.buffer(7),
        );
    }
}

/// Group 2 over Lumen's `buffers` and the surface cache's entries.
fn lumen_bind_group(
    gpu: &Gpu,
    layout: &wgpu::BindGroupLayout,
    buffers: &[(u32, wgpu::Buffer)],
    sdf_texels: &DistanceFieldTexels,
    cache: &SurfaceCache,
) -> wgpu::BindGroup {
    let mut entries: Vec<wgpu::BindGroupEntry> = buffers
        .iter()
        .map(|(b, buffer)| wgpu::BindGroupEntry {
            binding: *b,
            resource: buffer.as_entire_binding(),
        })
        .collect();
    entries.extend(sdf_texels.entries());
    entries.extend(cache.entries().expect("the surface cache's resources"));
    gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("lumen"),
        layout,
        entries: &entries,
    })
}

pub struct Lumen {
    params: Params,
    pub settings: LumenSettings,
    layouts: Option<Layouts>,
    pipelines: Option<Pipelines>,
    res: Option<Resources>,
    /// The surface cache (a part: `crate::parts::surface_cache`): cards, atlas, captures and
    /// cache lighting, its resources bound into Lumen's group 2.
    cache: SurfaceCache,
    clipmaps: Option<Clipmaps>,
    /// The scene the distance field was built for: its triangles (scene edits rebuild only the
    /// bricks they touch).
    scene_tris: Vec<[Vec3; 3]>,
    /// What the last scene change did to the surface cache (tests).
    last_refresh: Option<Refresh>,
    /// World-cache slots the last re-posing marked never traced.
    world_invalidated: usize,
    features: SceneFeatures,
    sky: bool,
    extent: [u32; 2],
    /// The settings the GPU resources were sized for.
    built_with: Option<LumenSettings>,
    /// The direct-light part for `direct = "restir"` (built the first time it is needed).
    restir_direct: RestirDirect,
    /// The reflections part (built the first time a glossy scene needs it).
    reflections: Reflections,
}

impl Default for Lumen {
    fn default() -> Self {
        let params = Params::new("lumen", PARAMS);
        let settings = LumenSettings::from_params(&params);
        Lumen {
            cache: SurfaceCache::held(settings.surface_cache_settings()),
            settings,
            params,
            layouts: None,
            pipelines: None,
            res: None,
            clipmaps: None,
            scene_tris: Vec::new(),
            last_refresh: None,
            world_invalidated: 0,
            built_with: None,
            restir_direct: RestirDirect::default(),
            reflections: Reflections::default(),
            features: SceneFeatures::default(),
            sky: false,
            extent: [0, 0],
        }
    }
}

impl Technique for Lumen {
    fn id(&self) -> &'static str {
        "lumen"
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
        let pass = |name, runs, why: String| PassInfo { name, runs, why };
        let lights = f.light_count() > 0;
        let mut v = Vec::new();
        let clip = self.clipmaps.as_ref();
        let built = clip.map_or(0, |c| c.built);
        for (l, name) in [
            "sdf level 0",
            "sdf level 1",
            "sdf level 2",
            "sdf level 3",
            "sdf level 4",
            "sdf level 5",
        ]
        .into_iter()
        .enumerate()
        .take(s.clipmap_levels as usize)
        {
            let voxel = clip.map_or(0.0, |c| c.voxel(l as u32));
            v.push(if !self.distance_field_read() {
                pass(name, false, "tracing = bvh and no debug views: nothing reads the distance field".into())
            } else if (l as u32) < built {
                pass(name, true, format!("{}^3 voxels of {voxel:.4}, rebuilt only where the camera scrolled or the scene changed", s.clipmap_resolution))
            } else {
                pass(name, false, format!("level {} already holds the whole scene", built.saturating_sub(1)))
            });
        }
        v.extend(self.cache.cache_passes(f, s.bvh));
        v.push(pass(
            "voxel visibility",
            self.distance_field_read(),
            "with each brick the distance field builds: one BVH ray per lighting voxel (4^3 per brick) and axis direction, the surface it meets".into(),
        ));
        v.push(pass(
            "voxel lighting",
            self.voxel_lighting_active(),
            if self.voxel_lighting_active() {
                "every frame: each voxel's surfaces shaded from their cards facing that direction; SDF hits without a card answer read it".into()
            } else if s.bvh {
                "tracing = bvh: every hit knows its object and reads its cards".into()
            } else {
                "voxel_lighting = false".into()
            },
        ));
        v.push(pass(
            "sky",
            self.sky,
            if self.sky {
                "rays that escape see the sky".into()
            } else if f.sky_visible {
                "sky radiance is zero".into()
            } else {
                "enclosed: no ray from the camera's side reaches the sky".into()
            },
        ));
        let tracing = if s.bvh { "BVH" } else { "SDF" };
        if s.screen_probes {
            v.extend(self.probe_passes(f));
        } else {
            v.push(pass(
                "gather",
                true,
                format!(
                    "{} {tracing} rays per {}x{} block, lit from the surface cache",
                    s.rays_per_pixel, s.gather_downsample, s.gather_downsample
                ),
            ));
        }
        if s.direct_restir {
            v.extend(self.restir_direct.passes(f));
        }
        v.push(pass(
            "direct",
            lights,
            if !lights {
                "no lights in the pool".into()
            } else if s.direct_restir {
                RestirDirect::describe()
            } else {
                "NEE per pixel in apply: one light by power, one BVH shadow ray".into()
            },
        ));
        v.extend(self.reflections.family_passes(s.reflections, f));
        v
    }

    fn build(&mut self, ctx: &RenderContext) -> Result<()> {
        let gpu = ctx.gpu;
        let (lumen, args, fill_level, query_layout, probe_layout) = {
            let l = self.layouts(gpu);
            (
                l.lumen.clone(),
                l.args.clone(),
                l.fill_level.clone(),
                l.queries.clone(),
                l.probes.clone(),
            )
        };
        // Every pipeline first: on an error nothing is replaced.
        let mut compute = Vec::new();
        for &pass in Pass::ALL {
            let own_group = match pass {
                // Apply also writes the screen traces' image (group 3).
                Pass::Apply => Some(&probe_layout),
                // The query pass reads its queries at group 1 (no frame).
                Pass::Query => None,
                _ => {
                    compute.push(ctx.pipeline(pass.file(), &lumen)?);
                    continue;
                }
            };
            let layouts = match own_group {
                Some(probes) => vec![&ctx.scene.layout, ctx.frame_layout, &lumen, probes],
                None => vec![&ctx.scene.layout, &query_layout, &lumen],
            };
            compute.push(pipelines::compute_pipeline(
                gpu,
                ctx.shaders,
                pass.file(),
                &layouts,
            )?);
        }
        let probes = ProbePipelines::build(ctx, &lumen, &probe_layout)?;
        let world = WorldCachePipelines::build(ctx, &lumen)?;
        let sdf_args = pipelines::compute_pipeline(
            gpu,
            ctx.shaders,
            SDF_ARGS,
            &[&ctx.scene.layout, ctx.frame_layout, &lumen, &args],
        )?;
        let sdf_fill = pipelines::compute_pipeline(
            gpu,
            ctx.shaders,
            SDF_FILL,
            &[&ctx.scene.layout, ctx.frame_layout, &lumen, &fill_level],
        )?;
        let voxel_visibility = pipelines::compute_pipeline(
            gpu,
            ctx.shaders,
            VOXEL_VISIBILITY,
            &[&ctx.scene.layout, ctx.frame_layout, &lumen, &fill_level],
        )?;
        let query = compute[Pass::Query as usize].clone();
        let apply = compute[Pass::Apply as usize].clone();
        // The parts are rebuilt too (shader change); if one fails, its old pipelines and
        // Lumen's stay.
        self.cache.settings = self.settings.surface_cache_settings();
        self.cache.build_pipelines(ctx, &lumen)?;
        self.restir_direct
            .prepare(ctx, self.settings.direct_restir, true, ())?;
        self.prepare_reflections(ctx, true)?;
        self.pipelines = Some(Pipelines {
            compute,
            sdf_args,
            sdf_fill,
            voxel_visibility,
            query,
            apply,
            probes,
            world,
        });
        if !self.refresh_for_scene(ctx)? {
            self.build_resources(ctx)?;
            self.reset_history(gpu);
        }
        Ok(())
    }

    /// Rebuilds the distance field, cards and atlas only when a parameter that sizes them
    /// changed; the ray budget, texel budgets and flags travel in the uniforms. A new tracing
    /// mode relights the cache from scratch.
    fn apply_params(&mut self, ctx: &RenderContext) -> Result<()> {
        self.settings.check()?;
        self.restir_direct
            .prepare(ctx, self.settings.direct_restir, false, ())?;
        self.prepare_reflections(ctx, false)?;
        self.cache.settings = self.settings.surface_cache_settings();
        let layout = self.layouts(ctx.gpu).lumen.clone();
        self.cache.apply_settings(ctx, &layout)?;
        let sized = |s: &LumenSettings| {
            (
                s.clipmap_levels,
                s.clipmap_resolution,
                s.atlas_size,
                s.gather_downsample,
                s.sign_rays,
                s.screen_probes,
            )
        };
        // The screen probes' buffers resize on their own (the ray-budget slider moves
        // probe_spacing) without touching the distance field or the cache.
        let probes_sized =
            |s: &LumenSettings| (s.probe_spacing, s.world_cache_levels, s.world_cache_probes);
        let old = self.built_with.clone();
        match (&old, self.res.as_mut()) {
            (Some(b), Some(r))
                if sized(b) == sized(&self.settings) && self.extent == ctx.extent =>
            {
                if probes_sized(b) != probes_sized(&self.settings) {
                    let layout = self
                        .layouts
                        .as_ref()
                        .expect("built with layouts")
                        .probes
                        .clone();
                    let w = self.settings.world_cache_settings();
                    let ws =
                        |s: crate::parts::world_cache::WorldCacheSettings| (s.levels, s.probes);
                    if ws(r.world.settings()) != ws(w) {
                        r.world = WorldCache::new(ctx.gpu, w)?;
                    }
                    r.probes = ScreenProbes::new(ctx, &layout, &self.settings, &r.world)?;
                }
                let r = self.res.as_mut().expect("resources");
                r.gpu_params.rays_per_pixel = self.settings.rays_per_pixel;
                self.built_with = Some(self.settings.clone());
                if b.bvh != self.settings.bvh {
                    self.reset_history(ctx.gpu);
                }
            }
            _ => {
                self.build_resources(ctx)?;
                self.reset_history(ctx.gpu);
            }
        }
        Ok(())
    }

    fn reset_history(&mut self, gpu: &Gpu) {
        let Some(r) = self.res.as_mut() else {
            return;
        };
        r.probes.reset(gpu);
        r.world.reset(gpu);
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        for b in [16, 17] {
            enc.clear_buffer(r.buffer(b), 0, None);
        }
        gpu.submit("lumen: history reset", enc.finish());
        self.cache.reset(gpu);
        self.restir_direct.reset(gpu);
        self.reflections.reset(gpu);
    }

    /// The cache and the distance field carry over, as in a game: the cache catches up through
    /// its update budgets (a material edit recaptures the cards, see `build`).
    fn on_scene_change(&mut self, _gpu: &Gpu) {}

    /// Playback moved geometry (`refresh_for_scene`): objects that moved rigidly keep their
    /// cards, re-placed on their new triangles, captured and relit first; the distance field's
    /// bricks and the world cache's probes around their old and new places start again; the
    /// rest of the history stays. Anything else (a deformation) rebuilds the cards and restarts
    /// the history, as a scripted edit does.
    fn on_geometry_moved(&mut self, ctx: &RenderContext) -> Result<()> {
        let start = std::time::Instant::now();
        if !self.refresh_for_scene(ctx)? {
            self.build(ctx)?;
        }
        log::debug!(
            "lumen: re-posing handled in {:.3} ms ({:?}, {} cards re-placed, {} world probes invalidated)",
            start.elapsed().as_secs_f64() * 1e3,
            self.last_refresh,
            self.cache.moved_cards().len(),
            self.world_invalidated
        );
        Ok(())
    }

    fn render(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
    ) {
        if self.pipelines.is_none() || self.res.is_none() {
            return;
        }
        // The texel budgets travel with the parameters.
        self.cache.settings = self.settings.surface_cache_settings();
        let camera = ctx.camera.position;
        let read = self.distance_field_read();
        let plan = match self.clipmaps.as_mut() {
            Some(c) => {
                let mut plan = c.plan(camera);
                if !read && plan.any_update {
                    // The level placement stays (biases and lookups use it); the bricks wait.
                    c.invalidate();
                    plan.any_update = false;
                }
                plan
            }
            None => return,
        };
        let flags = self.flags();
        let f = &self.features;
        let centre = (Vec3::from(f.bounds_min) + Vec3::from(f.bounds_max)) * 0.5;
        let Some(r) = self.res.as_mut() else {
            return;
        };
        let p = &mut r.gpu_params;
        p.levels = plan.levels;
        p.levels_built = plan.built;
        p.flags = flags;
        p.dirty_box_count = (plan.dirty.len() / 2) as u32;
        p.slice_depth = (centre - camera).dot(ctx.camera.forward()).max(1e-3);
        p.query_count = 0;
        ctx.gpu
            .queue
            .write_buffer(&r.params_buffer, 0, bytemuck::bytes_of(&r.gpu_params));
        if !plan.dirty.is_empty() {
            ctx.gpu
                .queue
                .write_buffer(r.buffer(11), 0, bytemuck::cast_slice(&plan.dirty));
        }
        if plan.any_update {
            self.record_sdf(ctx, enc, timer, &plan);
        }
        let direct_restir = self.restir_direct.active(self.direct_restir());
        let reflections = self.reflections.active(self.reflections_active());
        let lookup = if reflections {
            let layout = SurfaceCache::lookup_layout(ctx.gpu, false);
            self.cache.lookup_bind_group(ctx.gpu, &layout, None)
        } else {
            None
        };
        let (Some(p), Some(r)) = (&self.pipelines, self.res.as_mut()) else {
            return;
        };
        let bg = &r.bind_group;
        let gp = &r.gpu_params;
        self.cache.record_passes(ctx, enc, timer, bg);
        if gp.flags & FLAG_VOXEL_LIGHTING != 0 {
            // After the cache's lighting of this frame, before anything traces.
            pipelines::list_pass(
                enc,
                timer,
                Pass::VoxelLighting.name(),
                p.get(Pass::VoxelLighting),
                &[&ctx.scene.bind_group, ctx.frame_bind_group, bg],
                &r.args,
                12 * MAX_LEVELS as u64,
            );
        }
        // The world cache: its uniforms every frame (readers need them), its passes when on and
        // read by the screen probes.
        let world = self.settings.world_cache_settings();
        let update = self.settings.world_cache && self.settings.screen_probes;
        r.world
            .record(ctx, enc, timer, bg, &p.world, &world, update);
        if self.settings.screen_probes {
            r.probes
                .record(ctx, enc, timer, bg, &self.settings, &p.probes);
        } else {
            pipelines::technique_pass(
                ctx,
                enc,
                timer,
                Pass::Gather.name(),
                p.get(Pass::Gather),
                &[bg],
                [gp.gather_width.div_ceil(8), gp.gather_height.div_ceil(8), 1],
            );
        }
        if direct_restir {
            self.restir_direct
                .record(ctx, enc, timer, &r.direct_bind_group);
        }
        if reflections {
            let debug = self.settings.debug_views;
            self.reflections.record(
                ctx,
                enc,
                timer,
                lookup.as_ref(),
                (&r.specular_bind_group, 1),
                debug,
            );
            if debug {
                // The part's debug plane becomes Lumen's fourth (views 12 to 15).
                self.reflections
                    .copy_debug(enc, ctx.extent, r.buffer(17), 3);
            }
        }
        pipelines::technique_pass(
            ctx,
            enc,
            timer,
            "apply",
            &p.apply,
            &[bg, &r.probes.bind_group],
            [ctx.extent[0].div_ceil(8), ctx.extent[1].div_ceil(8), 1],
        );
    }

    fn debug_views(&self) -> Vec<DebugView> {
        let view = |name, channel, is_id| DebugView {
            name,
            channel,
            is_id,
        };
        let mut v = vec![
            view("surface cache albedo", 0, false),
            view("surface cache direct", 1, false),
            view("surface cache indirect", 2, false),
            view("surface cache final lighting", 3, false),
            view("card (colour per card)", 4, true),
            view("SDF distance slice (|d|)", 5, false),
            view("SDF steps (camera ray)", 6, false),
            view("SDF hit error vs BVH (voxels)", 7, false),
            view("screen probes: placement (1 uniform, 2 adaptive)", 8, false),
            view(
                "screen probes: radiance (octahedral map per tile)",
                9,
                false,
            ),
            view(
                "screen probes: share of rays hit by screen traces",
                10,
                false,
            ),
            view(
                "world radiance cache where a probe ray along the normal ends",
                11,
                false,
            ),
        ];
        v.extend(crate::parts::reflections::debug_views(3));
        v
    }

    fn debug_buffer(&self) -> Option<&wgpu::Buffer> {
        self.res.as_ref().map(|r| r.buffer(17))
    }

    fn param_set(&self) -> &Params {
        &self.params
    }

    fn set_params(&mut self, changes: &ParamChanges) -> Result<()> {
        let before = self.params.clone();
        self.params.apply(changes)?;
        let settings = LumenSettings::from_params(&self.params);
        if let Err(e) = settings.check() {
            self.params = before;
            return Err(e);
        }
        self.settings = settings;
        Ok(())
    }

    /// The first frames build the distance field and capture cards.
    fn calibration_frames(&self) -> u32 {
        4
    }

    fn params_for_ray_budget(
        &self,
        rays_per_pixel: f64,
        measured: Option<f64>,
    ) -> Option<ParamChanges> {
        // Everything but the gather (camera, NEE, cache updates amortised over pixels) is taken
        // from the measurement at the current settings when there is one.
        if self.settings.screen_probes {
            // 64 rays per probe: the budget picks the power-of-two spacing whose uniform probes
            // come closest (adaptive probes and world-cache updates ride on top, measured).
            let s = self.settings.probe_spacing;
            let probes_now = ScreenProbes::rays_per_pixel(s);
            let other = measured
                .map(|m| (m - probes_now).max(self.fixed_rays_per_pixel()))
                .unwrap_or(self.fixed_rays_per_pixel());
            let want = (rays_per_pixel - other).max(ScreenProbes::rays_per_pixel(64));
            let spacing = [4u32, 8, 16, 32, 64]
                .into_iter()
                .min_by(|a, b| {
                    let err = |x: u32| (ScreenProbes::rays_per_pixel(x) / want).ln().abs();
                    err(*a).total_cmp(&err(*b))
                })
                .unwrap_or(s);
            return (spacing != s)
                .then(|| ParamChanges::new().int("probe_spacing", spacing as i64));
        }
        let ds2 = (self.settings.gather_downsample as f64).powi(2);
        let gather_now = self.settings.rays_per_pixel as f64 / ds2;
        let other = measured
            .map(|m| (m - gather_now).max(self.fixed_rays_per_pixel()))
            .unwrap_or(self.fixed_rays_per_pixel());
        let rpp = (((rays_per_pixel - other) * ds2).round() as i64).clamp(1, 64);
        (rpp != self.settings.rays_per_pixel as i64)
            .then(|| ParamChanges::new().int("rays_per_pixel", rpp))
    }
}
