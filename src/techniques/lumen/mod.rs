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

pub mod params;
pub mod screen_probes;
pub mod sdf;

use crate::render::pipelines::init_buffer;
pub use params::{LumenSettings, TracingParamsGpu, FLAG_BVH, FLAG_LIGHTS, FLAG_SKY, PARAMS};
pub use screen_probes::ProbeStats;
use screen_probes::{ProbePipelines, ScreenProbes};

use crate::gpu::{readback, timing::PassTimer, Gpu};
use crate::parts::reflections::HitCache;
use crate::parts::surface_cache::{Refresh, SurfaceCache};
use crate::parts::world_cache::{WorldCache, WorldCachePipelines};
use crate::parts::{Reflections, RestirDirect};
use crate::render::params::Params;
use crate::render::primary::FrameInputs;
use crate::render::{pipelines, DebugView, PassInfo, RenderContext, Technique};
use crate::scene::features::SceneFeatures;
use anyhow::Result;
use glam::Vec3;
use params::*;
use sdf::{Clipmaps, MAX_LEVELS};

const COMPUTE: [(&str, &str); 7] = [
    ("sdf release", "lumen/sdf_release.wgsl"),
    ("sdf allocate", "lumen/sdf_allocate.wgsl"),
    ("sdf coarse", "lumen/sdf_coarse.wgsl"),
    ("gather", "lumen/gather.wgsl"),
    ("apply", "lumen/apply.wgsl"),
    ("query", "lumen/query.wgsl"),
    ("voxel lighting", "lumen/voxel_lighting.wgsl"),
];
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
    fn get(&self, name: &str) -> &wgpu::ComputePipeline {
        let i = COMPUTE
            .iter()
            .position(|(n, _)| *n == name)
            .expect("a known pass");
        &self.compute[i]
    }
}

struct Resources {
    params_buffer: wgpu::Buffer,
    /// Lumen's own buffers of group 2 by binding (0, 4..=11, 16..=18); the surface cache's
    /// fill the others.
    buffers: Vec<(u32, wgpu::Buffer)>,
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
}

/// Group 2 over Lumen's `buffers` and the surface cache's entries.
fn lumen_bind_group(
    gpu: &Gpu,
    layout: &wgpu::BindGroupLayout,
    buffers: &[(u32, wgpu::Buffer)],
    cache: &SurfaceCache,
) -> wgpu::BindGroup {
    let mut entries: Vec<wgpu::BindGroupEntry> = buffers
        .iter()
        .map(|(b, buffer)| wgpu::BindGroupEntry {
            binding: *b,
            resource: buffer.as_entire_binding(),
        })
        .collect();
    entries.extend(cache.entries().expect("the surface cache's resources"));
    gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("lumen"),
        layout,
        entries: &entries,
    })
}

/// Lumen's own entry files.
const OWN_SHADER_FILES: [&str; 23] = [
    "lumen/sdf_release.wgsl",
    "lumen/sdf_allocate.wgsl",
    "lumen/sdf_args.wgsl",
    "lumen/sdf_fill.wgsl",
    "lumen/sdf_coarse.wgsl",
    "lumen/gather.wgsl",
    "lumen/apply.wgsl",
    "lumen/query.wgsl",
    "parts/world_cache/select.wgsl",
    "parts/world_cache/update.wgsl",
    "lumen/hzb_build.wgsl",
    "lumen/hzb_top.wgsl",
    "lumen/probe_place.wgsl",
    "lumen/probe_adaptive.wgsl",
    "lumen/probe_sample.wgsl",
    "lumen/screen_trace.wgsl",
    "lumen/world_args.wgsl",
    "lumen/world_trace.wgsl",
    "lumen/probe_resolve.wgsl",
    "lumen/probe_filter.wgsl",
    "lumen/integrate.wgsl",
    "lumen/voxel_visibility.wgsl",
    "lumen/voxel_lighting.wgsl",
];

/// Lumen's entry files and its parts' (surface cache, direct light, reflections, world ReGIR).
const SHADER_FILES: [&str; 37] = crate::render::concat_files(
    crate::render::concat_files::<32, 4, 36>(
        crate::render::concat_files::<27, 5, 32>(
            crate::render::concat_files::<23, 4, 27>(
                OWN_SHADER_FILES,
                crate::parts::surface_cache::SHADER_FILES,
            ),
            crate::parts::restir_direct::SHADER_FILES,
        ),
        crate::parts::reflections::SHADER_FILES,
    ),
    crate::parts::world_regir::SHADER_FILES,
);

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

/// Per object whose triangles changed (same triangle list length, `object` per triangle): the
/// box of its changed triangles where they were and the box where they are (the distance field
/// rebuilds the bricks of both).
fn changed_objects(old: &[[Vec3; 3]], new: &[[Vec3; 3]], object: &[u32]) -> Vec<(Vec3, Vec3)> {
    use std::collections::BTreeMap;
    let empty = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    let mut boxes: BTreeMap<u32, [(Vec3, Vec3); 2]> = BTreeMap::new();
    for ((a, b), &o) in old.iter().zip(new).zip(object) {
        if a == b {
            continue;
        }
        let e = boxes.entry(o).or_insert([empty; 2]);
        for (bx, t) in e.iter_mut().zip([a, b]) {
            bx.0 = bx.0.min(t[0].min(t[1]).min(t[2]));
            bx.1 = bx.1.max(t[0].max(t[1]).max(t[2]));
        }
    }
    boxes.into_values().flatten().collect()
}

/// Scene triangles that are in one list and not the other (a multiset difference by exact
/// vertex bits), as boxes.
fn changed_triangles(old: &[[Vec3; 3]], new: &[[Vec3; 3]]) -> Vec<(Vec3, Vec3)> {
    use std::collections::HashMap;
    let key = |t: &[Vec3; 3]| t.map(|p| p.to_array().map(f32::to_bits));
    let mut count: HashMap<[[u32; 3]; 3], i64> = HashMap::new();
    for t in old {
        *count.entry(key(t)).or_default() += 1;
    }
    for t in new {
        *count.entry(key(t)).or_default() -= 1;
    }
    let mut out = Vec::new();
    for t in old.iter().chain(new) {
        if count.get(&key(t)).copied().unwrap_or(0) != 0 {
            out.push((t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2])));
        }
    }
    out
}

impl Lumen {
    fn layouts(&mut self, gpu: &Gpu) -> &Layouts {
        self.layouts.get_or_insert_with(|| {
            // Lumen's own bindings: its uniform, the distance field (4-11), the gather, debug
            // and per-pixel direct light (16-18); the surface cache's fill the others.
            let mut entries = vec![pipelines::uniform_entry(0, wgpu::ShaderStages::COMPUTE)];
            for b in (4..=11).chain(16..=18) {
                entries.push(pipelines::storage_entry(b, b == 11));
            }
            entries.extend(SurfaceCache::layout_entries());
            Layouts {
                lumen: pipelines::layout(gpu, "lumen", &entries),
                args: pipelines::layout(
                    gpu,
                    "lumen sdf args",
                    &[pipelines::storage_entry(0, false)],
                ),
                fill_level: pipelines::layout(
                    gpu,
                    "lumen fill level",
                    &[pipelines::uniform_entry(0, wgpu::ShaderStages::COMPUTE)],
                ),
                queries: pipelines::layout(
                    gpu,
                    "lumen queries",
                    &[pipelines::storage_entry(0, false)],
                ),
                direct: self.restir_direct.output_layout(gpu).clone(),
                specular: self.reflections.output_layout(gpu).clone(),
                probes: ScreenProbes::layout(gpu),
            }
        })
    }

    fn flags(&self) -> u32 {
        let s = &self.settings;
        let mut flags = 0;
        for (on, flag) in [
            (s.bvh, FLAG_BVH),
            (self.sky, FLAG_SKY),
            (s.accumulate, FLAG_ACCUMULATE),
            (s.debug_views, FLAG_DEBUG),
            (self.features.light_count() > 0, FLAG_LIGHTS),
            (self.direct_restir(), FLAG_DIRECT_RESTIR),
            (self.reflections_active(), FLAG_REFLECTIONS),
            (self.voxel_lighting_active(), FLAG_VOXEL_LIGHTING),
        ] {
            if on {
                flags |= flag;
            }
        }
        flags
    }

    /// (Re)builds the surface cache, the distance field's buffers and everything sized by the
    /// parameters or the image; the cache and the distance field start empty.
    fn build_resources(&mut self, ctx: &RenderContext) -> Result<()> {
        self.settings.check()?;
        let gpu = ctx.gpu;
        let data = &ctx.scene.data;
        self.features = data.features.clone();
        self.sky = ctx.scene.sky.max_element() > 0.0 && self.features.sky_visible;
        self.extent = ctx.extent;
        let s = self.settings.clone();
        let bounds = (
            Vec3::from(self.features.bounds_min),
            Vec3::from(self.features.bounds_max),
        );
        self.cache.settings = s.surface_cache_settings();
        self.cache.build_resources(ctx)?;
        let layouts = {
            let l = self.layouts(gpu);
            [
                l.lumen.clone(),
                l.args.clone(),
                l.fill_level.clone(),
                l.queries.clone(),
                l.probes.clone(),
                l.direct.clone(),
                l.specular.clone(),
            ]
        };
        let max_binding = gpu.device.limits().max_storage_buffer_binding_size;
        let clip = Clipmaps::new(s.clipmap_resolution, s.clipmap_levels, bounds);
        let nb = clip.bricks_per_axis() as u64;
        let slots = s.clipmap_levels as u64 * nb * nb * nb;
        let pool_bricks = slots.min(max_binding / (BRICK_BYTES + VOXEL_LIGHTING_BYTES)) as u32;
        let coarse_cells = s.clipmap_levels as u64 * (s.clipmap_resolution as u64 / 4).pow(3);
        let pixels = ctx.extent[0] as u64 * ctx.extent[1] as u64;
        // Screen probes integrate at full resolution into the gather buffer.
        let ds = if s.screen_probes {
            1
        } else {
            s.gather_downsample
        };
        let gather = [ctx.extent[0].div_ceil(ds), ctx.extent[1].div_ceil(ds)];
        let buf = |label: &str, size: u64| pipelines::storage_buffer(gpu, label, size.max(16));
        let gpu_params = TracingParamsGpu {
            resolution: s.clipmap_resolution,
            bricks_per_axis: clip.bricks_per_axis(),
            pool_bricks,
            rays_per_pixel: s.rays_per_pixel,
            gather_downsample: ds,
            gather_width: gather[0],
            gather_height: gather[1],
            sign_rays: s.sign_rays,
            ..Default::default()
        };
        let params_buffer = init_buffer(
            gpu,
            "lumen params",
            bytemuck::bytes_of(&gpu_params),
            wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        );
        let buffers = vec![
            (0, params_buffer.clone()),
            (4, buf("lumen brick table", slots * 4)),
            (5, buf("lumen brick coords", slots * 16)),
            (
                6,
                buf(
                    "lumen brick pool",
                    pool_bricks as u64 * (BRICK_BYTES + VOXEL_LIGHTING_BYTES),
                ),
            ),
            (7, buf("lumen coarse sdf", coarse_cells * 4)),
            (8, buf("lumen free bricks", pool_bricks as u64 * 4)),
            (9, buf("lumen sdf state", 64)),
            // Per level the bricks to fill, then every allocated brick (the voxel lighting's list).
            (10, buf("lumen fill list", 2 * slots * 4)),
            (
                11,
                buf("lumen dirty boxes", (2 * sdf::MAX_DIRTY_BOXES as u64) * 16),
            ),
            (
                16,
                buf("lumen gather", 2 * gather[0] as u64 * gather[1] as u64 * 16),
            ),
            (17, buf("lumen debug", 4 * pixels * 16)),
            // Direct light, then the reflections part's two planes.
            (18, buf("lumen pixel direct", 3 * pixels * 16)),
        ];
        let queries = buf("lumen queries", QUERY_CAPACITY as u64 * 32);
        let bind_group = lumen_bind_group(gpu, &layouts[0], &buffers, &self.cache);
        // One fill dispatch per level, then the voxel lighting's.
        let args = pipelines::indirect_args_buffer(gpu, "lumen fill args", MAX_LEVELS as u64 + 1);
        let args_bind_group =
            pipelines::buffers_bind_group(gpu, "lumen sdf args", &layouts[1], &[&args]);
        let fill_bind_groups = (0..MAX_LEVELS as u32)
            .map(|l| {
                let b = init_buffer(
                    gpu,
                    "lumen fill level",
                    bytemuck::cast_slice(&[l, 0, 0, 0]),
                    wgpu::BufferUsages::UNIFORM,
                );
                pipelines::buffers_bind_group(gpu, "lumen fill level", &layouts[2], &[&b])
            })
            .collect();
        let pixel_direct = &buffers.last().expect("pixel direct").1;
        let query_bind_group =
            pipelines::buffers_bind_group(gpu, "lumen queries", &layouts[3], &[&queries]);
        let direct_bind_group =
            pipelines::buffers_bind_group(gpu, "lumen pixel direct", &layouts[5], &[pixel_direct]);
        let specular_bind_group = pipelines::buffers_bind_group(
            gpu,
            "lumen pixel specular",
            &layouts[6],
            &[pixel_direct],
        );
        let world = WorldCache::new(gpu, s.world_cache_settings())?;
        let res = Resources {
            params_buffer,
            buffers,
            bind_group,
            args_bind_group,
            fill_bind_groups,
            query_bind_group,
            queries,
            direct_bind_group,
            specular_bind_group,
            args,
            gpu_params,
            probes: ScreenProbes::new(ctx, &layouts[4], &s, &world)?,
            world,
        };
        // Every brick free, every slot unbuilt.
        let stack: Vec<u32> = (0..pool_bricks).rev().collect();
        gpu.queue
            .write_buffer(res.buffer(8), 0, bytemuck::cast_slice(&stack));
        let mut state = [0u32; 16];
        state[0] = pool_bricks;
        gpu.queue
            .write_buffer(res.buffer(9), 0, bytemuck::cast_slice(&state));
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        enc.clear_buffer(res.buffer(5), 0, None);
        let empty_table = vec![u32::MAX; (res.buffer(4).size() / 4) as usize];
        gpu.queue
            .write_buffer(res.buffer(4), 0, bytemuck::cast_slice(&empty_table));
        gpu.submit("lumen: distance field brick pool reset", enc.finish());
        self.clipmaps = Some(clip);
        self.scene_tris = data.tris.clone();
        self.res = Some(res);
        self.built_with = Some(s);
        Ok(())
    }

    /// A rebuild for the same image size keeps what still holds: unchanged triangles keep
    /// everything; a material edit recaptures the cards (the surface cache's part); moved, added
    /// or removed triangles rebuild the cards (and the cache lighting) and only the
    /// distance-field bricks they touch. Returns false when the resources must be built anew.
    fn refresh_for_scene(&mut self, ctx: &RenderContext) -> Result<bool> {
        let gpu = ctx.gpu;
        let data = &ctx.scene.data;
        if self.res.is_none() || self.extent != ctx.extent {
            return Ok(false);
        }
        self.features = data.features.clone();
        self.sky = ctx.scene.sky.max_element() > 0.0 && self.features.sky_visible;
        self.cache.settings = self.settings.surface_cache_settings();
        let refresh = self.cache.refresh_for_scene(ctx)?;
        self.last_refresh = Some(refresh);
        match refresh {
            Refresh::Build => return Ok(false),
            Refresh::Kept | Refresh::Moved => {}
            Refresh::NewCards => {
                let layout = self.layouts(gpu).lumen.clone();
                let Some(r) = self.res.as_mut() else {
                    return Ok(false);
                };
                r.bind_group = lumen_bind_group(gpu, &layout, &r.buffers, &self.cache);
            }
        }
        if data.tris != self.scene_tris {
            let objects = self.cache.card_set().map(|c| c.tri_object.as_slice());
            let changed = match objects {
                Some(o) if o.len() == data.tris.len() => {
                    changed_objects(&self.scene_tris, &data.tris, o)
                }
                _ => changed_triangles(&self.scene_tris, &data.tris),
            };
            if refresh == Refresh::Moved {
                // The seed's reaction: bricks and world probes around the moved objects' old
                // and new places start again; the rest of the history stays (temporal passes
                // reproject with the motion vectors).
                if let Some(r) = self.res.as_ref() {
                    self.world_invalidated = r.world.invalidate(gpu, &changed);
                }
            }
            if let Some(c) = self.clipmaps.as_mut() {
                c.dirty.extend(changed);
            }
            self.scene_tris = data.tris.clone();
            if refresh != Refresh::Moved {
                self.reset_history(gpu);
            }
        }
        Ok(true)
    }
}

impl Lumen {
    /// The cards and objects of the current scene.
    pub fn card_set(&self) -> Option<&crate::parts::surface_cache::cards::CardSet> {
        self.cache.card_set()
    }

    /// Screen-probe counters since the last reset (probes, screen-trace hits, world-traced
    /// rays, world cache reads); None before the first build.
    pub fn probe_stats(&self, gpu: &Gpu) -> Result<Option<ProbeStats>> {
        self.res.as_ref().map(|r| r.probes.stats(gpu)).transpose()
    }

    /// This frame's direct light per pixel from the direct-light part (`direct = "restir"`; with
    /// NEE apply computes it inline and this holds zeros).
    pub fn pixel_direct(&self, gpu: &Gpu) -> Result<Option<Vec<[f32; 4]>>> {
        let Some(r) = &self.res else {
            return Ok(None);
        };
        let pixels = (self.extent[0] * self.extent[1]) as usize;
        readback::read_buffer(gpu, r.buffer(18), pixels).map(Some)
    }

    /// What the last scene change or re-posing did to the surface cache.
    pub fn last_refresh(&self) -> Option<Refresh> {
        self.last_refresh
    }

    /// World-cache slots the last re-posing marked never traced (around moved objects).
    pub fn world_invalidated(&self) -> usize {
        self.world_invalidated
    }

    /// The surface cache's direct irradiance per atlas texel (tests).
    pub fn cache_direct(&self, gpu: &Gpu) -> Result<Option<Vec<[f32; 4]>>> {
        self.cache.read_direct(gpu)
    }

    /// The clipmaps' placement as of the last frame.
    pub fn clipmaps(&self) -> Option<&Clipmaps> {
        self.clipmaps.as_ref()
    }

    /// Pool use and failed allocations of the distance field.
    pub fn sdf_stats(&self, gpu: &Gpu) -> Result<Option<SdfStats>> {
        let Some(r) = &self.res else {
            return Ok(None);
        };
        let state: Vec<u32> = readback::read_buffer(gpu, r.buffer(9), 16)?;
        Ok(Some(SdfStats {
            pool_bricks: r.gpu_params.pool_bricks,
            allocated_bricks: r.gpu_params.pool_bricks - state[0].min(r.gpu_params.pool_bricks),
            failed_allocations: state[2],
            levels_built: self.clipmaps.as_ref().map_or(0, |c| c.built),
        }))
    }

    /// Answers `mode` for each input pair (points: (p, unused); rays: (origin, direction)) on
    /// the GPU against the distance field as of the last frame, two vec4 per input as
    /// shaders/lumen/query.wgsl writes them. At most QUERY_CAPACITY / 2.
    pub fn query(
        &self,
        ctx: &RenderContext,
        mode: QueryMode,
        inputs: &[([f32; 3], [f32; 3])],
    ) -> Result<Vec<[[f32; 4]; 2]>> {
        let (Some(p), Some(r)) = (&self.pipelines, &self.res) else {
            anyhow::bail!("lumen: query before the technique was built");
        };
        anyhow::ensure!(
            inputs.len() <= QUERY_CAPACITY / 2,
            "lumen: too many queries"
        );
        let gpu = ctx.gpu;
        let mut data = Vec::with_capacity(inputs.len() * 2);
        for (a, b) in inputs {
            data.push([a[0], a[1], a[2], 0.0]);
            data.push([b[0], b[1], b[2], 0.0]);
        }
        let queries = &r.queries;
        gpu.queue
            .write_buffer(queries, 0, bytemuck::cast_slice(&data));
        let mut params = r.gpu_params;
        params.query_count = inputs.len() as u32;
        params.query_mode = mode as u32;
        gpu.queue
            .write_buffer(&r.params_buffer, 0, bytemuck::bytes_of(&params));
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            pass.set_pipeline(&p.query);
            pass.set_bind_group(0, &ctx.scene.bind_group, &[]);
            pass.set_bind_group(1, &r.query_bind_group, &[]);
            pass.set_bind_group(2, &r.bind_group, &[]);
            pass.dispatch_workgroups((inputs.len() as u32).div_ceil(64), 1, 1);
        }
        gpu.submit("lumen: distance-field point queries", enc.finish());
        gpu.queue
            .write_buffer(&r.params_buffer, 0, bytemuck::bytes_of(&r.gpu_params));
        let out: Vec<[f32; 4]> = readback::read_buffer(gpu, queries, inputs.len() * 2)?;
        Ok(out.chunks(2).map(|c| [c[0], c[1]]).collect())
    }

    /// Rays per pixel per frame besides the gather: the shared camera ray and the direct
    /// light's (NEE's shadow ray, or ReSTIR DI's with the part).
    fn fixed_rays_per_pixel(&self) -> f64 {
        let reflections = if self.reflections_active() {
            self.reflections.rays_per_pixel()
        } else {
            0.0
        };
        1.0 + reflections
            + if self.features.light_count() == 0 {
                0.0
            } else if self.direct_restir() {
                self.restir_direct.rays_per_pixel()
            } else {
                1.0
            }
    }

    /// The reflections part runs: `reflections = "traced"` on a scene with a specular layer
    /// (metal, or a dielectric specular factor above 0), glossy or not: rough lobes need the
    /// albedo plane even where no ray is traced.
    fn reflections_active(&self) -> bool {
        self.settings.reflections && self.features.min_specular_roughness.is_some()
    }

    /// Builds the reflections part when it is needed and not built (its trace pass reads this
    /// cache: Lumen's group 2 at the part's cache group), and passes it the settings.
    fn prepare_reflections(&mut self, ctx: &RenderContext, rebuild: bool) -> Result<()> {
        self.reflections.settings = self.settings.reflection.clone();
        let needed =
            self.settings.reflections && ctx.scene.data.features.min_specular_roughness.is_some();
        if (needed && !self.reflections.is_built()) || (rebuild && self.reflections.is_built()) {
            // The cache's lookup bindings alone: with all of Lumen's group the trace pass would
            // bind more storage buffers than a stage may.
            let layout = crate::parts::SurfaceCache::lookup_layout(ctx.gpu, false);
            self.reflections
                .build(ctx, Some(HitCache::SurfaceCache(&layout)))?;
        }
        if self.reflections.is_built() {
            self.reflections.build_resources(ctx);
        }
        Ok(())
    }

    /// Lookups the world ReGIR clipmap served, for tests and reports.
    pub fn cache_regir_coverage(&self, gpu: &Gpu) -> Result<crate::parts::world_regir::Coverage> {
        self.cache.cache_regir_coverage(gpu)
    }

    /// SDF hits fall back on the voxel lighting (`voxel_lighting`, `tracing = "sdf"`).
    fn voxel_lighting_active(&self) -> bool {
        self.settings.voxel_lighting && !self.settings.bvh
    }

    /// Whether anything reads the distance field this frame: SDF tracing, or the debug views
    /// (slice, steps, hit error). With BVH tracing and no debug views nothing does, and the field
    /// is left to be built whole when something reads it again: in a playing scene its refill
    /// of moved bricks cost 7.5 ms a 1080p frame on an H200 (docs/performance.md).
    fn distance_field_read(&self) -> bool {
        !self.settings.bvh || self.settings.debug_views
    }

    /// Pixels take their direct light from the ReSTIR DI part (`direct = "restir"`, lights).
    fn direct_restir(&self) -> bool {
        self.settings.direct_restir && self.features.light_count() > 0
    }

    /// Records the distance-field update of this frame's plan, if anything changed.
    fn record_sdf(
        &self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
        plan: &sdf::SdfPlan,
    ) {
        let (Some(p), Some(r)) = (&self.pipelines, &self.res) else {
            return;
        };
        let params = &r.gpu_params;
        let nb = params.bricks_per_axis;
        let slots = plan.built * nb * nb * nb;
        // Per-update counters (fill counts, pops, failures) start at zero; the free count stays.
        enc.clear_buffer(r.buffer(9), 4, Some(60));
        let bg = &r.bind_group;
        let groups = [slots.div_ceil(64), 1, 1];
        pipelines::technique_pass(
            ctx,
            enc,
            timer,
            "sdf release",
            p.get("sdf release"),
            &[bg],
            groups,
        );
        pipelines::technique_pass(
            ctx,
            enc,
            timer,
            "sdf allocate",
            p.get("sdf allocate"),
            &[bg],
            groups,
        );
        pipelines::technique_pass(
            ctx,
            enc,
            timer,
            "sdf args",
            &p.sdf_args,
            &[bg, &r.args_bind_group],
            [1, 1, 1],
        );
        for (l, name) in FILL_PASS_NAMES.iter().enumerate().take(plan.built as usize) {
            if plan.levels[l].update[0] == 0 {
                continue;
            }
            pipelines::list_pass(
                enc,
                timer,
                name,
                &p.sdf_fill,
                &[
                    &ctx.scene.bind_group,
                    ctx.frame_bind_group,
                    bg,
                    &r.fill_bind_groups[l],
                ],
                &r.args,
                12 * l as u64,
            );
            // Every mode: a later switch to SDF tracing or voxel lighting finds it built.
            pipelines::list_pass(
                enc,
                timer,
                "voxel visibility",
                &p.voxel_visibility,
                &[
                    &ctx.scene.bind_group,
                    ctx.frame_bind_group,
                    bg,
                    &r.fill_bind_groups[l],
                ],
                &r.args,
                12 * l as u64,
            );
        }
        let cells = plan.built * (params.resolution / 4).pow(3);
        pipelines::technique_pass(
            ctx,
            enc,
            timer,
            "sdf coarse",
            p.get("sdf coarse"),
            &[bg],
            [cells.div_ceil(64), 1, 1],
        );
    }
}

impl Lumen {
    /// The world radiance cache's passes (they run with `world_cache` when `reader` reads it).
    fn world_passes(&self, reader: &str) -> Vec<PassInfo> {
        let s = &self.settings;
        let tracing = if s.bvh { "BVH" } else { "SDF" };
        WorldCache::pass_info(&s.world_cache_settings(), s.world_cache, tracing, reader)
    }

    /// What the screen-probe final gather runs this frame, and why (the UI's pass list).
    fn probe_passes(&self, f: &SceneFeatures) -> Vec<PassInfo> {
        let s = &self.settings;
        let pass = |name, runs, why: String| PassInfo { name, runs, why };
        let tracing = if s.bvh { "BVH" } else { "SDF" };
        let mut v = self.world_passes("screen probes");
        v.extend([
            pass(
                "hzb",
                s.screen_traces,
                if s.screen_traces { "closest-depth mips of last frame for the screen traces".into() } else { "screen_traces = false".into() },
            ),
            pass(
                "probe place",
                true,
                format!("one probe per {0}x{0} tile on the G-buffer, jittered each frame", s.probe_spacing),
            ),
            pass(
                "probe adaptive",
                s.adaptive_probes,
                if s.adaptive_probes {
                    "extra probes where the uniform ones fail to interpolate (depth and normal edges)".into()
                } else {
                    "adaptive_probes = false".into()
                },
            ),
            pass(
                "probe sample",
                true,
                if s.product_sampling && s.ray_reassignment {
                    "64 rays per probe: one per cell, dim cells (BRDF x last frame's radiance) culled by roulette, their rays supersample the brightest 2x2".into()
                } else if s.product_sampling {
                    "64 directions per probe from BRDF x last frame's radiance (world cache where reprojection fails)".into()
                } else {
                    "64 stratified uniform directions per probe".into()
                },
            ),
            pass(
                "screen trace",
                s.screen_traces,
                if s.screen_traces {
                    format!("hierarchical-Z walk in last frame's image, at most {} steps; misses go to the world trace", s.screen_trace_steps)
                } else {
                    "screen_traces = false: every probe ray is traced in the world".into()
                },
            ),
            pass(
                "world trace",
                true,
                if s.world_cache {
                    format!("{tracing} rays to {} scene units (at least a world probe diagonal), then the world cache (or on to the end where it is empty)", s.world_cache_distance)
                } else {
                    format!("{tracing} rays to the first hit, lit from the surface cache")
                },
            ),
            pass("probe resolve", true, if s.temporal_filter { "per-cell radiance and hit distance, blended with the probe's last frames".into() } else { "per-cell radiance and hit distance (temporal_filter = false)".into() }),
            pass(
                "probe filter",
                s.spatial_filter,
                if s.spatial_filter { "3x3 neighbouring probes, plane and 10-degree angle-error weights".into() } else { "spatial_filter = false".into() },
            ),
            pass(
                "integrate",
                true,
                format!(
                    "per pixel: irradiance from the probes of its plane{}{}",
                    if s.temporal_filter { ", full-resolution temporal filter" } else { "" },
                    if s.contact_ao { ", contact AO" } else { "" }
                ),
            ),
        ]);
        if !f.has_glossy && !f.has_mirror {
            return v;
        }
        v.push(pass(
            "probe reflections",
            false,
            "not built (issue 16 item 6): glossy surfaces get direct specular only".into(),
        ));
        v
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
        for (name, entry) in COMPUTE {
            if name == "query" {
                continue;
            }
            if name == "apply" {
                // Apply also writes the screen traces' image (group 3).
                compute.push(pipelines::compute_pipeline(
                    gpu,
                    ctx.shaders,
                    entry,
                    &[&ctx.scene.layout, ctx.frame_layout, &lumen, &probe_layout],
                )?);
                continue;
            }
            compute.push(ctx.pipeline(entry, &lumen)?);
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
        let query = pipelines::compute_pipeline(
            gpu,
            ctx.shaders,
            COMPUTE
                .iter()
                .find(|(n, _)| *n == "query")
                .expect("query")
                .1,
            &[&ctx.scene.layout, &query_layout, &lumen],
        )?;
        let query_at = COMPUTE
            .iter()
            .position(|(n, _)| *n == "query")
            .expect("query");
        compute.insert(query_at, query.clone());
        let apply = compute[COMPUTE
            .iter()
            .position(|(n, _)| *n == "apply")
            .expect("apply")]
        .clone();
        // The parts are rebuilt too (shader change); if one fails, its old pipelines and
        // Lumen's stay.
        self.cache.settings = self.settings.surface_cache_settings();
        self.cache.build_pipelines(ctx, &lumen)?;
        if self.restir_direct.is_built() || self.settings.direct_restir {
            self.restir_direct.build(ctx)?;
            self.restir_direct.build_resources(ctx);
        }
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
        if self.settings.direct_restir && !self.restir_direct.is_built() {
            self.restir_direct.build(ctx)?;
        }
        if self.restir_direct.is_built() {
            self.restir_direct.build_resources(ctx);
        }
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
        let direct_restir = self.direct_restir() && self.restir_direct.is_built();
        let reflections = self.reflections_active() && self.reflections.is_built();
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
                "voxel lighting",
                p.get("voxel lighting"),
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
                "gather",
                p.get("gather"),
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

    fn set_params(&mut self, params: &toml::Table) -> Result<()> {
        let before = self.params.clone();
        self.params.set("lumen", params)?;
        let settings = LumenSettings::from_params(&self.params);
        if let Err(e) = settings.check() {
            self.params = before;
            return Err(e);
        }
        self.settings = settings;
        Ok(())
    }

    fn shader_files(&self) -> &'static [&'static str] {
        &SHADER_FILES
    }

    /// The first frames build the distance field and capture cards.
    fn calibration_frames(&self) -> u32 {
        4
    }

    fn params_for_ray_budget(
        &self,
        rays_per_pixel: f64,
        measured: Option<f64>,
    ) -> Option<toml::Table> {
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
            return (spacing != s).then(|| {
                let mut t = toml::Table::new();
                t.insert("probe_spacing".into(), (spacing as i64).into());
                t
            });
        }
        let ds2 = (self.settings.gather_downsample as f64).powi(2);
        let gather_now = self.settings.rays_per_pixel as f64 / ds2;
        let other = measured
            .map(|m| (m - gather_now).max(self.fixed_rays_per_pixel()))
            .unwrap_or(self.fixed_rays_per_pixel());
        let rpp = (((rays_per_pixel - other) * ds2).round() as i64).clamp(1, 64);
        (rpp != self.settings.rays_per_pixel as i64).then(|| {
            let mut t = toml::Table::new();
            t.insert("rays_per_pixel".into(), rpp.into());
            t
        })
    }
}
