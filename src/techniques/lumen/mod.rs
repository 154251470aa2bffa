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
//!    level, and `sdf_coarse` rebuilds the coarse volume of updated levels.
//! 2. `capture`: this frame's cards (closest first, 512^2 texels per frame) are rasterised with
//!    their orthographic cameras into the atlas: albedo, normal, emission, depth.
//! 3. Surface cache lighting: `cache direct` (one light sample and shadow ray per texel of this
//!    frame's 8x8 tiles), `cache probes` (a 16-ray hemisphere probe per 4x4 tile, hits read the
//!    cache itself: multi-bounce through feedback) and `cache indirect` (texels interpolate
//!    their four probes with plane and hit-distance weights, blended over at most 4 frames).
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
//! Files: `params.rs` (the table), `cards.rs` (objects, card placement, atlas pages), `sdf.rs`
//! (clipmap placement and update plans), `screen_probes.rs` (the final gather's buffers and
//! passes), this file (GPU resources and passes).

pub mod cards;
mod params;
pub mod screen_probes;
pub mod sdf;

pub use params::{LumenParamsGpu, LumenSettings, PARAMS};
pub use screen_probes::ProbeStats;
use screen_probes::{ProbePipelines, ScreenProbes};

use crate::gpu::{readback, timing::PassTimer, Gpu};
use crate::parts::reflections::HitCache;
use crate::parts::world_cache::{WorldCache, WorldCachePipelines};
use crate::parts::{Reflections, RestirDirect, WorldRegir};
use crate::render::params::Params;
use crate::render::primary::FrameInputs;
use crate::render::{pipelines, DebugView, PassInfo, RenderContext, Technique};
use crate::scene::features::SceneFeatures;
use anyhow::Result;
use cards::{CardSet, GpuCard};
use glam::Vec3;
use params::*;
use sdf::{Clipmaps, MAX_LEVELS};
use wgpu::util::DeviceExt;

const COMPUTE: [(&str, &str); 9] = [
    ("sdf release", "lumen/sdf_release.wgsl"),
    ("sdf allocate", "lumen/sdf_allocate.wgsl"),
    ("sdf coarse", "lumen/sdf_coarse.wgsl"),
    ("cache direct", "lumen/cache_direct.wgsl"),
    ("cache probes", "lumen/cache_probe.wgsl"),
    ("cache indirect", "lumen/cache_indirect.wgsl"),
    ("gather", "lumen/gather.wgsl"),
    ("apply", "lumen/apply.wgsl"),
    ("query", "lumen/query.wgsl"),
];
const SDF_ARGS: &str = "lumen/sdf_args.wgsl";
const SDF_FILL: &str = "lumen/sdf_fill.wgsl";
const CAPTURE: &str = "lumen/capture.wgsl";
const FILL_PASS_NAMES: [&str; MAX_LEVELS] = [
    "sdf fill L0",
    "sdf fill L1",
    "sdf fill L2",
    "sdf fill L3",
    "sdf fill L4",
    "sdf fill L5",
];
/// Texels captured per frame (the seed's fixed 512^2 budget).
pub const CAPTURE_TEXELS_PER_FRAME: u32 = 512 * 512;
/// Budgets are quoted for the seed's 4096^2 atlas.
const BUDGET_ATLAS: f64 = 4096.0;
/// Queries one call can answer.
pub const QUERY_CAPACITY: usize = 1 << 16;
const BRICK_BYTES: u64 = 512 * 4;
const ALBEDO_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
const NORMAL_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba16Float;
const EMISSIVE_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba16Float;
const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Float;
const CAPTURE_DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
const ATLAS_FORMATS: [wgpu::TextureFormat; 4] =
    [ALBEDO_FORMAT, NORMAL_FORMAT, EMISSIVE_FORMAT, DEPTH_FORMAT];

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
    /// (reflected luminance, best card or -1, object, steps).
    CacheRay = 3,
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
    /// Group 1 of the capture raster pipelines: the cards.
    capture: wgpu::BindGroupLayout,
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
    capture: wgpu::RenderPipeline,
    capture_clear: wgpu::RenderPipeline,
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

/// Bindings of group 2 that hold card data (replaced when the scene's triangles change).
const CARD_BINDINGS: [usize; 4] = [1, 2, 3, 15];

struct Resources {
    params_buffer: wgpu::Buffer,
    /// Group 2's buffers in binding order (0..=18).
    buffers: Vec<wgpu::Buffer>,
    atlas_views: Vec<wgpu::TextureView>,
    bind_group: wgpu::BindGroup,
    args_bind_group: wgpu::BindGroup,
    fill_bind_groups: Vec<wgpu::BindGroup>,
    capture_bind_group: wgpu::BindGroup,
    query_bind_group: wgpu::BindGroup,
    queries: wgpu::Buffer,
    /// `pixel_direct` for the direct-light part's pass to write.
    direct_bind_group: wgpu::BindGroup,
    /// `pixel_direct` for the reflections part's filter to write (planes 1 and 2).
    specular_bind_group: wgpu::BindGroup,
    args: wgpu::Buffer,
    index_buffer: wgpu::Buffer,
    capture_depth_view: wgpu::TextureView,
    gpu_params: LumenParamsGpu,
    /// The world radiance cache (a part: `crate::parts::world_cache`), read by the screen
    /// probes and, through the surface-cache part, by ReSTIR GI's `lumen-world` paths.
    world: WorldCache,
    probes: ScreenProbes,
}

impl Resources {
    fn buffer(&self, binding: usize) -> &wgpu::Buffer {
        &self.buffers[binding]
    }
}

/// Group 2 over `buffers` (bindings 0..=18) and the atlas textures (19..=22).
fn lumen_bind_group(
    gpu: &Gpu,
    layout: &wgpu::BindGroupLayout,
    buffers: &[wgpu::Buffer],
    views: &[wgpu::TextureView],
) -> wgpu::BindGroup {
    let mut entries: Vec<wgpu::BindGroupEntry> = buffers
        .iter()
        .enumerate()
        .map(|(i, b)| wgpu::BindGroupEntry {
            binding: i as u32,
            resource: b.as_entire_binding(),
        })
        .collect();
    for (i, v) in views.iter().enumerate() {
        entries.push(wgpu::BindGroupEntry {
            binding: 19 + i as u32,
            resource: wgpu::BindingResource::TextureView(v),
        });
    }
    gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("lumen"),
        layout,
        entries: &entries,
    })
}

fn init_buffer(gpu: &Gpu, label: &str, contents: &[u8], usage: wgpu::BufferUsages) -> wgpu::Buffer {
    let mut bytes = contents.to_vec();
    bytes.resize(bytes.len().max(16), 0);
    gpu.device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents: &bytes,
            usage,
        })
}

/// The card buffers of bindings CARD_BINDINGS, the capture index buffer, and the tile counts.
fn card_buffers(gpu: &Gpu, c: &CardSet) -> ([wgpu::Buffer; 4], wgpu::Buffer, u32, u32) {
    let storage = wgpu::BufferUsages::STORAGE;
    let direct = c.tiles(8);
    let probes = c.tiles(4);
    let (nd, np) = (direct.len() as u32, probes.len() as u32);
    let mut tiles = direct;
    tiles.extend(probes);
    (
        [
            init_buffer(gpu, "lumen cards", bytemuck::cast_slice(&c.cards), storage),
            init_buffer(
                gpu,
                "lumen object cards",
                bytemuck::cast_slice(&c.object_cards),
                storage,
            ),
            init_buffer(
                gpu,
                "lumen triangle objects",
                bytemuck::cast_slice(&c.tri_object),
                storage,
            ),
            init_buffer(gpu, "lumen tiles", bytemuck::cast_slice(&tiles), storage),
        ],
        init_buffer(
            gpu,
            "lumen capture indices",
            bytemuck::cast_slice(&c.indices),
            wgpu::BufferUsages::INDEX,
        ),
        nd,
        np,
    )
}

/// Every entry file Lumen compiles without its direct-light part: what the surface-cache part
/// (`crate::parts::SurfaceCache`, this technique in cache-only mode) builds.
pub const SURFACE_CACHE_FILES: [&str; 25] = [
    "lumen/sdf_release.wgsl",
    "lumen/sdf_allocate.wgsl",
    "lumen/sdf_args.wgsl",
    "lumen/sdf_fill.wgsl",
    "lumen/sdf_coarse.wgsl",
    "lumen/capture.wgsl",
    "lumen/cache_direct.wgsl",
    "lumen/cache_probe.wgsl",
    "lumen/cache_indirect.wgsl",
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
];

/// Lumen's entry files and its parts' (direct light, reflections).
const SHADER_FILES: [&str; 35] = crate::render::concat_files(
    crate::render::concat_files::<30, 4, 34>(
        crate::render::concat_files::<25, 5, 30>(
            SURFACE_CACHE_FILES,
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
    cards: Option<CardSet>,
    clipmaps: Option<Clipmaps>,
    /// Cards still to capture, nearest first when taken.
    capture_queue: Vec<u32>,
    direct_tiles: u32,
    probe_tiles: u32,
    direct_cursor: u32,
    probe_cursor: u32,
    /// The scene the resources were built for: its triangles (scene edits rebuild only the
    /// bricks they touch) and materials (a change recaptures the cards).
    scene_tris: Vec<[Vec3; 3]>,
    scene_materials: Vec<u8>,
    features: SceneFeatures,
    sky: bool,
    extent: [u32; 2],
    /// The settings the GPU resources were sized for.
    built_with: Option<LumenSettings>,
    /// The direct-light part for `direct = "restir"` (built the first time it is needed).
    restir_direct: RestirDirect,
    /// The reflections part (built the first time a glossy scene needs it).
    reflections: Reflections,
    /// Surface-cache part (`Lumen::surface_cache`): the cache's passes only, no final gather.
    cache_only: bool,
    /// The world ReGIR clipmap the cache texels take their lights from (`cache_direct = "regir"`;
    /// built the first time it is asked for).
    world_regir: WorldRegir,
    /// Whether the "cache direct" pipeline was composed with the clipmap's lookup.
    cache_direct_regir: bool,
}

impl Default for Lumen {
    fn default() -> Self {
        let params = Params::new("lumen", PARAMS);
        Lumen {
            settings: LumenSettings::from_params(&params),
            params,
            layouts: None,
            pipelines: None,
            res: None,
            cards: None,
            clipmaps: None,
            capture_queue: Vec::new(),
            direct_tiles: 0,
            probe_tiles: 0,
            direct_cursor: 0,
            probe_cursor: 0,
            scene_tris: Vec::new(),
            built_with: None,
            restir_direct: RestirDirect::default(),
            reflections: Reflections::default(),
            scene_materials: Vec::new(),
            features: SceneFeatures::default(),
            sky: false,
            extent: [0, 0],
            cache_only: false,
            world_regir: WorldRegir::default(),
            cache_direct_regir: false,
        }
    }
}

/// A non-filtered 2D float texture read by compute passes (the atlas textures).
pub fn texture_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable: false },
            view_dimension: wgpu::TextureViewDimension::D2,
            multisampled: false,
        },
        count: None,
    }
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
            let mut entries = vec![pipelines::uniform_entry(0, wgpu::ShaderStages::COMPUTE)];
            for b in 1..=18 {
                entries.push(pipelines::storage_entry(
                    b,
                    (1..=3).contains(&b) || b == 11 || b == 15,
                ));
            }
            for b in 19..=22 {
                entries.push(texture_entry(b));
            }
            let mut capture = pipelines::storage_entry(0, true);
            capture.visibility = wgpu::ShaderStages::VERTEX_FRAGMENT;
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
                capture: pipelines::layout(gpu, "lumen capture", &[capture]),
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
        ] {
            if on {
                flags |= flag;
            }
        }
        flags
    }

    fn capture_pipeline(
        gpu: &Gpu,
        module: &wgpu::ShaderModule,
        layout: &wgpu::PipelineLayout,
        clear: bool,
    ) -> Result<wgpu::RenderPipeline> {
        let attributes = wgpu::vertex_attr_array![0 => Float32x3];
        let targets: Vec<Option<wgpu::ColorTargetState>> = ATLAS_FORMATS
            .iter()
            .map(|f| {
                Some(wgpu::ColorTargetState {
                    format: *f,
                    blend: None,
                    write_mask: wgpu::ColorWrites::ALL,
                })
            })
            .collect();
        let buffers = [Some(wgpu::VertexBufferLayout {
            array_stride: std::mem::size_of::<crate::scene::gpu_scene::RasterVertex>() as u64,
            step_mode: wgpu::VertexStepMode::Vertex,
            attributes: &attributes,
        })];
        gpu.scoped("lumen capture pipeline", || {
            gpu.device
                .create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                    label: Some(if clear {
                        "lumen capture clear"
                    } else {
                        "lumen capture"
                    }),
                    layout: Some(layout),
                    vertex: wgpu::VertexState {
                        module,
                        entry_point: Some(if clear { "vs_clear" } else { "vs_main" }),
                        compilation_options: Default::default(),
                        buffers: if clear { &[] } else { &buffers },
                    },
                    primitive: wgpu::PrimitiveState {
                        cull_mode: None,
                        front_face: wgpu::FrontFace::Ccw,
                        ..Default::default()
                    },
                    depth_stencil: Some(wgpu::DepthStencilState {
                        format: CAPTURE_DEPTH_FORMAT,
                        depth_write_enabled: Some(true),
                        depth_compare: Some(if clear {
                            wgpu::CompareFunction::Always
                        } else {
                            wgpu::CompareFunction::Less
                        }),
                        stencil: Default::default(),
                        bias: Default::default(),
                    }),
                    multisample: Default::default(),
                    fragment: Some(wgpu::FragmentState {
                        module,
                        entry_point: Some(if clear { "fs_clear" } else { "fs_main" }),
                        compilation_options: Default::default(),
                        targets: &targets,
                    }),
                    multiview_mask: None,
                    cache: None,
                })
        })
    }

    /// (Re)builds cards, the distance field's buffers, the atlas and everything sized by the
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
        let card_set = cards::build(data, s.atlas_size)?;
        let layouts = {
            let l = self.layouts(gpu);
            [
                l.lumen.clone(),
                l.args.clone(),
                l.fill_level.clone(),
                l.capture.clone(),
                l.queries.clone(),
                l.probes.clone(),
                l.direct.clone(),
                l.specular.clone(),
            ]
        };
        let max_binding = gpu.device.limits().max_storage_buffer_binding_size;
        let atlas_texels = s.atlas_size as u64 * s.atlas_size as u64;
        anyhow::ensure!(
            atlas_texels * 16 <= max_binding,
            "lumen: atlas_size = {} needs {} MiB per lighting buffer, over this device's {} MiB binding limit",
            s.atlas_size,
            (atlas_texels * 16) >> 20,
            max_binding >> 20
        );
        let clip = Clipmaps::new(s.clipmap_resolution, s.clipmap_levels, bounds);
        let nb = clip.bricks_per_axis() as u64;
        let slots = s.clipmap_levels as u64 * nb * nb * nb;
        let pool_bricks = slots.min(max_binding / BRICK_BYTES) as u32;
        let coarse_cells = s.clipmap_levels as u64 * (s.clipmap_resolution as u64 / 4).pow(3);
        let pixels = ctx.extent[0] as u64 * ctx.extent[1] as u64;
        // Screen probes integrate at full resolution into the gather buffer.
        let ds = if s.screen_probes {
            1
        } else {
            s.gather_downsample
        };
        let gather = [ctx.extent[0].div_ceil(ds), ctx.extent[1].div_ceil(ds)];
        let ([cards_buffer, object_cards, tri_object, tiles], index_buffer, nd, np) =
            card_buffers(gpu, &card_set);
        let buf = |label: &str, size: u64| pipelines::storage_buffer(gpu, label, size.max(16));
        let gpu_params = LumenParamsGpu {
            resolution: s.clipmap_resolution,
            bricks_per_axis: clip.bricks_per_axis(),
            pool_bricks,
            atlas_size: s.atlas_size,
            card_count: card_set.cards.len() as u32,
            rays_per_pixel: s.rays_per_pixel,
            gather_downsample: ds,
            gather_width: gather[0],
            gather_height: gather[1],
            direct_tiles_total: nd,
            probe_tiles_total: np,
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
            params_buffer.clone(),
            cards_buffer,
            object_cards,
            tri_object,
            buf("lumen brick table", slots * 4),
            buf("lumen brick coords", slots * 16),
            buf("lumen brick pool", pool_bricks as u64 * BRICK_BYTES),
            buf("lumen coarse sdf", coarse_cells * 4),
            buf("lumen free bricks", pool_bricks as u64 * 4),
            buf("lumen sdf state", 64),
            buf("lumen fill list", slots * 4),
            buf("lumen dirty boxes", (2 * sdf::MAX_DIRTY_BOXES as u64) * 16),
            buf("lumen atlas direct", atlas_texels * 16),
            buf("lumen atlas indirect", atlas_texels * 16),
            buf("lumen probes", atlas_texels / 16 * 48),
            tiles,
            buf("lumen gather", 2 * gather[0] as u64 * gather[1] as u64 * 16),
            buf("lumen debug", 4 * pixels * 16),
            // Direct light, then the reflections part's two planes.
            buf("lumen pixel direct", 3 * pixels * 16),
        ];
        let queries = buf("lumen queries", QUERY_CAPACITY as u64 * 32);
        let size = wgpu::Extent3d {
            width: s.atlas_size,
            height: s.atlas_size,
            depth_or_array_layers: 1,
        };
        let make = |label: &str, format| {
            gpu.device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size,
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage: wgpu::TextureUsages::RENDER_ATTACHMENT
                    | wgpu::TextureUsages::TEXTURE_BINDING,
                view_formats: &[],
            })
        };
        let atlas_views: Vec<wgpu::TextureView> = [
            "lumen albedo",
            "lumen normal",
            "lumen emissive",
            "lumen depth",
        ]
        .iter()
        .zip(ATLAS_FORMATS)
        .map(|(l, f)| make(l, f).create_view(&Default::default()))
        .collect();
        let capture_depth_view =
            make("lumen capture depth", CAPTURE_DEPTH_FORMAT).create_view(&Default::default());
        let bind_group = lumen_bind_group(gpu, &layouts[0], &buffers, &atlas_views);
        let args = pipelines::indirect_args_buffer(gpu, "lumen fill args", MAX_LEVELS as u64);
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
        let capture_bind_group =
            pipelines::buffers_bind_group(gpu, "lumen capture", &layouts[3], &[&buffers[1]]);
        let query_bind_group =
            pipelines::buffers_bind_group(gpu, "lumen queries", &layouts[4], &[&queries]);
        let direct_bind_group =
            pipelines::buffers_bind_group(gpu, "lumen pixel direct", &layouts[6], &[&buffers[18]]);
        let specular_bind_group = pipelines::buffers_bind_group(
            gpu,
            "lumen pixel specular",
            &layouts[7],
            &[&buffers[18]],
        );
        let world = WorldCache::new(gpu, s.world_cache_settings())?;
        let res = Resources {
            params_buffer,
            buffers,
            atlas_views,
            bind_group,
            args_bind_group,
            fill_bind_groups,
            capture_bind_group,
            query_bind_group,
            queries,
            direct_bind_group,
            specular_bind_group,
            args,
            index_buffer,
            capture_depth_view,
            gpu_params,
            probes: ScreenProbes::new(ctx, &layouts[5], &s, &world)?,
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
        self.direct_tiles = nd;
        self.probe_tiles = np;
        self.direct_cursor = 0;
        self.probe_cursor = 0;
        self.capture_queue = (0..card_set.cards.len() as u32).collect();
        self.cards = Some(card_set);
        self.clipmaps = Some(clip);
        self.scene_tris = data.tris.clone();
        self.scene_materials = bytemuck::cast_slice(&data.materials).to_vec();
        self.res = Some(res);
        self.built_with = Some(s);
        Ok(())
    }

    /// A rebuild for the same image size keeps what still holds: unchanged triangles keep
    /// everything; a material edit recaptures the cards; moved, added or removed triangles
    /// rebuild the cards (and the cache lighting) and only the distance-field bricks they touch.
    /// Returns false when the resources must be built anew.
    fn refresh_for_scene(&mut self, ctx: &RenderContext) -> Result<bool> {
        let gpu = ctx.gpu;
        let data = &ctx.scene.data;
        if self.res.is_none() || self.extent != ctx.extent {
            return Ok(false);
        }
        self.features = data.features.clone();
        self.sky = ctx.scene.sky.max_element() > 0.0 && self.features.sky_visible;
        let materials: Vec<u8> = bytemuck::cast_slice(&data.materials).to_vec();
        if data.tris != self.scene_tris {
            let changed = changed_triangles(&self.scene_tris, &data.tris);
            let card_set = cards::build(data, self.settings.atlas_size)?;
            let layout = self.layouts(gpu).lumen.clone();
            let capture_layout = self.layouts(gpu).capture.clone();
            let (new, index_buffer, nd, np) = card_buffers(gpu, &card_set);
            let Some(r) = self.res.as_mut() else {
                return Ok(false);
            };
            for (b, buffer) in CARD_BINDINGS.iter().zip(new) {
                r.buffers[*b] = buffer;
            }
            r.index_buffer = index_buffer;
            r.bind_group = lumen_bind_group(gpu, &layout, &r.buffers, &r.atlas_views);
            r.capture_bind_group = pipelines::buffers_bind_group(
                gpu,
                "lumen capture",
                &capture_layout,
                &[&r.buffers[1]],
            );
            r.gpu_params.card_count = card_set.cards.len() as u32;
            r.gpu_params.direct_tiles_total = nd;
            r.gpu_params.probe_tiles_total = np;
            self.direct_tiles = nd;
            self.probe_tiles = np;
            self.capture_queue = (0..card_set.cards.len() as u32).collect();
            self.cards = Some(card_set);
            if let Some(c) = self.clipmaps.as_mut() {
                c.dirty.extend(changed);
            }
            self.scene_tris = data.tris.clone();
            self.scene_materials = materials;
            self.reset_history(gpu);
        } else if materials != self.scene_materials {
            self.scene_materials = materials;
            self.capture_queue =
                (0..self.cards.as_ref().map_or(0, |c| c.cards.len() as u32)).collect();
        }
        Ok(true)
    }
}

impl Lumen {
    /// Lumen in cache-only mode, the surface-cache part (`crate::parts::SurfaceCache`): its
    /// distance field, card captures and cache lighting run each frame; no final gather.
    pub fn surface_cache() -> Lumen {
        Lumen {
            cache_only: true,
            ..Lumen::default()
        }
    }

    /// A bind group of the cache's lookup bindings (`crate::parts::surface_cache`) under
    /// `layout`, over the current buffers, and the world cache's lookup bindings when `world`;
    /// `None` before `build`.
    pub fn surface_cache_bind_group(
        &self,
        gpu: &Gpu,
        layout: &wgpu::BindGroupLayout,
        world: bool,
    ) -> Option<wgpu::BindGroup> {
        use crate::parts::surface_cache::{LOOKUP_BINDINGS, LOOKUP_TEXTURES};
        let r = self.res.as_ref()?;
        let mut entries: Vec<wgpu::BindGroupEntry> = LOOKUP_BINDINGS
            .iter()
            .map(|&b| wgpu::BindGroupEntry {
                binding: b,
                resource: r.buffer(b as usize).as_entire_binding(),
            })
            .collect();
        for (&b, view) in LOOKUP_TEXTURES.iter().zip(&r.atlas_views) {
            entries.push(wgpu::BindGroupEntry {
                binding: b,
                resource: wgpu::BindingResource::TextureView(view),
            });
        }
        if world {
            entries.extend(r.world.entries());
        }
        Some(gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("surface cache lookup"),
            layout,
            entries: &entries,
        }))
    }

    /// The cards and objects of the current scene.
    pub fn card_set(&self) -> Option<&CardSet> {
        self.cards.as_ref()
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

    /// Texels per frame of a budget quoted for the seed's 4096^2 atlas.
    fn scaled_budget(&self, texels: u32) -> f64 {
        let a = self.settings.atlas_size as f64 / BUDGET_ATLAS;
        texels as f64 * a * a
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
        self.settings.reflections
            && !self.cache_only
            && self.features.min_specular_roughness.is_some()
    }

    /// Builds the reflections part when it is needed and not built (its trace pass reads this
    /// cache: Lumen's group 2 at the part's cache group), and passes it the settings.
    fn prepare_reflections(&mut self, ctx: &RenderContext, rebuild: bool) -> Result<()> {
        self.reflections.settings = self.settings.reflection.clone();
        let needed = self.settings.reflections
            && !self.cache_only
            && ctx.scene.data.features.min_specular_roughness.is_some();
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
        self.world_regir.coverage(gpu)
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

    /// Takes this frame's captures off the queue: nearest the camera first, up to the budget.
    fn next_captures(&mut self, camera: Vec3) -> Vec<u32> {
        let Some(c) = &self.cards else {
            return Vec::new();
        };
        let cards = &c.cards;
        self.capture_queue.sort_by(|a, b| {
            let da = cards[*a as usize].centre().distance_squared(camera);
            let db = cards[*b as usize].centre().distance_squared(camera);
            db.total_cmp(&da)
        });
        let mut out = Vec::new();
        let mut texels = 0;
        while let Some(&next) = self.capture_queue.last() {
            let t = cards[next as usize].texels();
            if !out.is_empty() && texels + t > CAPTURE_TEXELS_PER_FRAME {
                break;
            }
            texels += t;
            out.push(next);
            self.capture_queue.pop();
        }
        out
    }

    fn record_capture(
        &self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
        list: &[u32],
    ) {
        let (Some(p), Some(r), Some(c)) = (&self.pipelines, &self.res, &self.cards) else {
            return;
        };
        let attachments: Vec<Option<wgpu::RenderPassColorAttachment>> = r
            .atlas_views
            .iter()
            .map(|v| {
                Some(wgpu::RenderPassColorAttachment {
                    view: v,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Load,
                        store: wgpu::StoreOp::Store,
                    },
                })
            })
            .collect();
        let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("lumen capture"),
            color_attachments: &attachments,
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &r.capture_depth_view,
                depth_ops: Some(wgpu::Operations {
                    load: wgpu::LoadOp::Load,
                    store: wgpu::StoreOp::Store,
                }),
                stencil_ops: None,
            }),
            timestamp_writes: timer.render_pass("capture"),
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_bind_group(0, &ctx.scene.bind_group, &[]);
        pass.set_bind_group(1, &r.capture_bind_group, &[]);
        pass.set_vertex_buffer(0, ctx.scene.vertex_buffer.slice(..));
        pass.set_index_buffer(r.index_buffer.slice(..), wgpu::IndexFormat::Uint32);
        for &ci in list {
            let card: &GpuCard = &c.cards[ci as usize];
            let [x, y, w, h] = card.rect;
            pass.set_viewport(x as f32, y as f32, w as f32, h as f32, 0.0, 1.0);
            pass.set_scissor_rect(x, y, w, h);
            pass.set_pipeline(&p.capture_clear);
            pass.draw(0..3, ci..ci + 1);
            pass.set_pipeline(&p.capture);
            let [first, count, _, _] = card.draw;
            pass.draw_indexed(first..first + count, 0, ci..ci + 1);
        }
    }
}

impl Lumen {
    /// The world radiance cache's passes (they run with `world_cache` when `reader` reads it).
    fn world_passes(&self, reader: &str) -> Vec<PassInfo> {
        let s = &self.settings;
        let tracing = if s.bvh { "BVH" } else { "SDF" };
        let why = |why: String| {
            if s.world_cache {
                why
            } else {
                "world_cache = false".into()
            }
        };
        let levels = s.world_cache_levels;
        let per_axis = s.world_cache_probes;
        vec![
            PassInfo {
                name: "world select",
                runs: s.world_cache,
                why: why(format!("{levels} clipmap levels of {per_axis}^3 probes around the camera; lists the ones {reader} read, never-traced first, then the stalest")),
            },
            PassInfo {
                name: "world update",
                runs: s.world_cache && s.world_probes_per_frame > 0,
                why: why(format!("{} listed probes per frame, 256 {tracing} rays each (16x16 cells), lit from the surface cache, mean of the last {} updates", s.world_probes_per_frame, s.world_cache_history)),
            },
        ]
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
                if s.product_sampling {
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
            v.push(if self.cache_only && s.bvh {
                pass(name, false, "the surface cache traces through the BVH: no distance field".into())
            } else if (l as u32) < built {
                pass(name, true, format!("{}^3 voxels of {voxel:.4}, rebuilt only where the camera scrolled or the scene changed", s.clipmap_resolution))
            } else {
                pass(name, false, format!("level {} already holds the whole scene", built.saturating_sub(1)))
            });
        }
        let cards = self.cards.as_ref();
        v.push(pass(
            "capture",
            true,
            format!(
                "{} cards of {} objects in {} pages; up to {} texels per frame, nearest first",
                cards.map_or(0, |c| c.cards.len()),
                cards.map_or(0, |c| c.object_count()),
                cards.map_or(0, |c| c.pages_used),
                CAPTURE_TEXELS_PER_FRAME
            ),
        ));
        let regir = s.cache_light.regir && f.many_lights;
        v.push(WorldRegir::pass_info(&s.cache_light, f));
        v.push(pass(
            "cache direct",
            lights,
            if lights {
                format!(
                    "{:.0} texels per frame, one light {} and one {} shadow ray each",
                    self.scaled_budget(s.direct_texels_per_frame),
                    if regir {
                        "from the world ReGIR clipmap"
                    } else {
                        "by power"
                    },
                    if s.bvh { "BVH" } else { "SDF" }
                )
            } else {
                "no lights in the pool".into()
            },
        ));
        v.push(pass("cache indirect", true, format!("{:.0} texels per frame: 16-ray probes on 4x4 tiles reading the cache (one more bounce per update), 4-frame blend", self.scaled_budget(s.indirect_texels_per_frame))));
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
        if self.cache_only {
            if s.world_cache {
                v.extend(self.world_passes("ReSTIR GI's paths"));
            }
            return v;
        }
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
        let (lumen, args, fill_level, capture_layout, query_layout, probe_layout) = {
            let l = self.layouts(gpu);
            (
                l.lumen.clone(),
                l.args.clone(),
                l.fill_level.clone(),
                l.capture.clone(),
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
            if name == "cache direct" {
                compute.push(WorldRegir::lighting_pipeline(
                    ctx,
                    entry,
                    &lumen,
                    self.settings.cache_light.regir,
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
        let query = pipelines::compute_pipeline(
            gpu,
            ctx.shaders,
            COMPUTE[8].1,
            &[&ctx.scene.layout, &query_layout, &lumen],
        )?;
        compute.push(query.clone());
        let module = pipelines::shader_module(gpu, ctx.shaders, CAPTURE)?;
        let raster_layout = gpu
            .device
            .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("lumen capture"),
                bind_group_layouts: &[Some(&ctx.scene.layout), Some(&capture_layout)],
                immediate_size: 0,
            });
        let capture = Self::capture_pipeline(gpu, &module, &raster_layout, false)?;
        let capture_clear = Self::capture_pipeline(gpu, &module, &raster_layout, true)?;
        let apply = compute[COMPUTE
            .iter()
            .position(|(n, _)| *n == "apply")
            .expect("apply")]
        .clone();
        // The direct-light part is rebuilt too (shader change); if that fails, its old
        // pipelines and Lumen's stay.
        if self.restir_direct.is_built() || self.settings.direct_restir {
            self.restir_direct.build(ctx)?;
            self.restir_direct.build_resources(ctx);
        }
        self.prepare_reflections(ctx, true)?;
        self.world_regir.prepare(ctx, &self.settings.cache_light)?;
        self.cache_direct_regir = self.settings.cache_light.regir;
        self.pipelines = Some(Pipelines {
            compute,
            sdf_args,
            sdf_fill,
            capture,
            capture_clear,
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
        self.world_regir.prepare(ctx, &self.settings.cache_light)?;
        if self.cache_direct_regir != self.settings.cache_light.regir {
            let layout = self.layouts(ctx.gpu).lumen.clone();
            let pipeline = WorldRegir::lighting_pipeline(
                ctx,
                "lumen/cache_direct.wgsl",
                &layout,
                self.settings.cache_light.regir,
            )?;
            if let Some(p) = self.pipelines.as_mut() {
                let i = COMPUTE
                    .iter()
                    .position(|(n, _)| *n == "cache direct")
                    .expect("cache direct");
                p.compute[i] = pipeline;
            }
            self.cache_direct_regir = self.settings.cache_light.regir;
        }
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
        for b in [12usize, 13, 14, 16, 17] {
            enc.clear_buffer(r.buffer(b), 0, None);
        }
        gpu.submit("lumen: history reset", enc.finish());
        self.restir_direct.reset(gpu);
        self.reflections.reset(gpu);
    }

    /// The cache and the distance field carry over, as in a game: the cache catches up through
    /// its update budgets (a material edit recaptures the cards, see `build`).
    fn on_scene_change(&mut self, _gpu: &Gpu) {}

    fn render(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
    ) {
        if self.pipelines.is_none() || self.res.is_none() {
            return;
        }
        let camera = ctx.camera.position;
        let plan = match self.clipmaps.as_mut() {
            Some(c) => c.plan(camera),
            None => return,
        };
        let captures = self.next_captures(camera);
        let direct =
            (self.scaled_budget(self.settings.direct_texels_per_frame) / 64.0).ceil() as u32;
        let probes =
            (self.scaled_budget(self.settings.indirect_texels_per_frame) / 16.0).ceil() as u32;
        let direct = direct.clamp(1, self.direct_tiles.max(1));
        let probes = probes.clamp(1, self.probe_tiles.max(1));
        let flags = self.flags();
        let f = &self.features;
        let centre = (Vec3::from(f.bounds_min) + Vec3::from(f.bounds_max)) * 0.5;
        let (direct_first, probe_first) = (self.direct_cursor, self.probe_cursor);
        self.direct_cursor = (self.direct_cursor + direct) % self.direct_tiles.max(1);
        self.probe_cursor = (self.probe_cursor + probes) % self.probe_tiles.max(1);
        let Some(r) = self.res.as_mut() else {
            return;
        };
        let p = &mut r.gpu_params;
        p.levels = plan.levels;
        p.levels_built = plan.built;
        p.flags = flags;
        p.dirty_box_count = (plan.dirty.len() / 2) as u32;
        p.direct_tile_first = direct_first;
        p.direct_tile_count = direct;
        p.probe_tile_first = probe_first;
        p.probe_tile_count = probes;
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
        // The surface-cache part traced through the BVH reads no distance field.
        let sdf_unused = self.cache_only && self.settings.bvh;
        if plan.any_update && !sdf_unused {
            self.record_sdf(ctx, enc, timer, &plan);
        }
        if !captures.is_empty() {
            self.record_capture(ctx, enc, timer, &captures);
        }
        let direct_restir = self.direct_restir() && self.restir_direct.is_built();
        let reflections = self.reflections_active() && self.reflections.is_built();
        let lookup = if reflections {
            let layout = crate::parts::SurfaceCache::lookup_layout(ctx.gpu, false);
            self.surface_cache_bind_group(ctx.gpu, &layout, false)
        } else {
            None
        };
        let (Some(p), Some(r)) = (&self.pipelines, self.res.as_mut()) else {
            return;
        };
        let bg = &r.bind_group;
        let gp = &r.gpu_params;
        if self.features.light_count() > 0 && self.direct_tiles > 0 {
            let regir = self.world_regir.record_for_pass(
                ctx,
                enc,
                timer,
                self.cache_direct_regir,
                self.features.many_lights,
            );
            let groups: Vec<&wgpu::BindGroup> = [Some(bg), regir].into_iter().flatten().collect();
            pipelines::technique_pass(
                ctx,
                enc,
                timer,
                "cache direct",
                p.get("cache direct"),
                &groups,
                [direct, 1, 1],
            );
        }
        if self.probe_tiles > 0 {
            pipelines::technique_pass(
                ctx,
                enc,
                timer,
                "cache probes",
                p.get("cache probes"),
                &[bg],
                [probes.div_ceil(64), 1, 1],
            );
            pipelines::technique_pass(
                ctx,
                enc,
                timer,
                "cache indirect",
                p.get("cache indirect"),
                &[bg],
                [probes.div_ceil(4), 1, 1],
            );
        }
        // The world cache: its uniforms every frame (readers need them), its passes when on and
        // read (by the screen probes, or in cache-only mode by the part's reader).
        let world = self.settings.world_cache_settings();
        let world_read = self.cache_only || self.settings.screen_probes;
        let update = self.settings.world_cache && world_read;
        r.world
            .record(ctx, enc, timer, bg, &p.world, &world, update);
        if self.cache_only {
            return;
        }
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
