//! # The surfel core (GIBS)
//!
//! One core, two thin holders: the `surfels` technique (`crate::techniques::surfels`) and the
//! surfel cache other families' rays end in ([`crate::parts::SurfelCache`]).
//!
//! "Global Illumination based on Surfels" (GIBS; EA SEED / Frostbite, SIGGRAPH 2021,
//! shared/seeds/001): the scene is discretised on the fly into surfels spawned from the G-buffer
//! (here the engine's primary surfaces); each surfel integrates the irradiance arriving at it
//! with rays, and pixels gather the surfels around them. Everything runs on the GPU from fixed
//! buffers; nothing is read back inside a frame. Per frame:
//!
//! 1. `recycle` + `push`: the seed's recycling heuristic (pool fill, frames since the surfel
//!    lit a visible pixel, distance, over-coverage) against a random number; recycled slots go
//!    back onto the free stack.
//! 2. `coverage` + `spawn`: per spawn tile (16x16 pixels at 1080p) the least-covered pixel spawns a surfel when its
//!    coverage is below `coverage_target` times a random number; its slot is popped from the
//!    free stack. Surfel = position, normal, radius, albedo, object id (the triangle).
//! 3. `prepare` + `scatter` + `sort_cells`: radii for this frame (a constant fraction of the
//!    image height, at most half the cell side), then the non-linear grid is rebuilt: count,
//!    prefix sum, scatter into every cell a surfel's bounding box overlaps, and a per-cell sort
//!    so gathers are deterministic. Each surfel also requests rays (age, variance, visibility).
//! 4. `allocate` + `ray_owner`: the global `ray_budget` is split in proportion to requests.
//! 5. `trace`: guided (or cosine) rays; at the hit NEE plus the surfel irradiance there
//!    (multi-bounce), a path where no surfel covers the hit, the sky on a miss.
//! 6. `integrate`: multiscale mean estimator (or running mean), guiding map, radial depth.
//! 7. `direct`: per-pixel direct light (NEE, or ReSTIR DI with `direct = "restir"`).
//! 8. `apply`: gather, emission + direct + albedo x irradiance / pi, debug views, accumulation.
//!
//! Positions and orders come from prefix sums (`scan.rs`), not per-thread atomics, so a fixed
//! seed gives bit-identical images. Shaders: shaders/parts/surfels/*.wgsl (shared state in
//! shaders/parts/surfels/shared.wgsl). Files: `params.rs` (the table), `scan.rs`, this file.

pub mod params;
mod scan;

pub use params::{SurfelParamsGpu, SurfelSettings, MAX_RAYS_PER_SURFEL, PARAMS};

use crate::gpu::{readback, timing::PassTimer, Gpu};
use crate::parts::hash_cache::{self, HashCache, HashCacheSettings};
use crate::parts::reflections::HitCache;
use crate::parts::Part;
use crate::parts::{Reflections, RestirDirect, WorldRegir};
use crate::render::params::{ParamChanges, Params};
use crate::render::primary::FrameInputs;
use crate::render::{pipelines, DebugView, PassInfo, RenderContext};
use crate::scene::features::SceneFeatures;
use anyhow::{Context, Result};
use params::*;
use scan::{ScanJob, ScanPipelines};

/// Cells of the grid: the 32^3 centre grid and six 32x32x64 trapezoids (shared.wgsl).
pub const GRID_CELLS: u32 = 32 * 32 * 32 + 6 * 32 * 32 * 64;
/// The coverage pass's blocks are 16x16 pixels (one workgroup each), holding spawn tiles of 1-16
/// pixels (`SurfelSettings::spawn_tile`; one spawn candidate each).
pub const TILE: u32 = 16;
/// Bytes per surfel of each per-slot buffer (shared.wgsl's structs).
pub const SURFEL_BYTES: u64 = 48;
pub const STATE_BYTES: u64 = 64;
pub const POOL_BYTES: u64 = 48;
const GUIDE_WORDS: u64 = 9;
const DEPTH_TEXELS: u64 = 16;
/// Bytes per ray of the results buffer (two vec4).
const RAY_RESULT_BYTES: u64 = 32;
/// The centre grid spans this fraction of the scene's diagonal.
const GRID_FRACTION: f32 = 0.1;

crate::compute_passes! {
    /// The surfels' passes that share the surfel layout (group 2), in pipeline order.
    enum Pass {
        Recycle => ("recycle", "parts/surfels/recycle.wgsl"),
        Push => ("push", "parts/surfels/push.wgsl"),
        Coverage => ("coverage", "parts/surfels/coverage.wgsl"),
        Spawn => ("spawn", "parts/surfels/spawn.wgsl"),
        Prepare => ("prepare", "parts/surfels/prepare.wgsl"),
        Scatter => ("scatter", "parts/surfels/scatter.wgsl"),
        SortCells => ("sort_cells", "parts/surfels/sort_cells.wgsl"),
        Allocate => ("allocate", "parts/surfels/allocate.wgsl"),
        Bin => ("bin", "parts/surfels/bin.wgsl"),
        BinOrder => ("bin order", "parts/surfels/bin_order.wgsl"),
        Trace => ("trace", "parts/surfels/trace.wgsl"),
        Estimate => ("estimate", "parts/surfels/estimate.wgsl"),
        Integrate => ("integrate", "parts/surfels/integrate.wgsl"),
        Direct => ("direct", "parts/surfels/direct_nee.wgsl"),
        ApplyGather => ("apply gather", "parts/surfels/apply_gather.wgsl"),
        Apply => ("apply", "parts/surfels/apply.wgsl"),
    }
}
const RAY_OWNER: &str = "parts/surfels/ray_owner.wgsl";
/// Ray bins (16-bit keys) and where the cells' cursors start in the counters buffer (`RAY_BINS`
/// and `CELL_CURSORS` in shared.wgsl).
const RAY_BINS: u64 = 65536;
const CELL_CURSORS: u64 = 2 * RAY_BINS + 1;

/// Pipelines in `Pass::ALL` order, plus the ones with other layouts.
struct Pipelines {
    passes: Vec<wgpu::ComputePipeline>,
    ray_owner: wgpu::ComputePipeline,
    scan: ScanPipelines,
}

impl Pipelines {
    fn get(&self, pass: Pass) -> &wgpu::ComputePipeline {
        &self.passes[pass as usize]
    }
}

/// The bindings of group 2 that the irradiance lookup (`gilab::surfels::gather`) reads: the
/// reflections part's trace pass binds only these (with all 20, a stage would bind more than
/// the 32 storage buffers it may).
const LOOKUP_BINDINGS: [u32; 7] = [0, 1, 2, 5, 7, 10, 14];

/// Shader defs of a pipeline that reads the surfels' irradiance (`gilab::surfels::gather`) at
/// bind group `group`, bound with [`lookup_layout`] and [`SurfelCore::lookup_bind_group`].
pub fn lookup_defs(group: u32) -> [(&'static str, u32); 1] {
    [("SURFELS_GROUP", group)]
}

/// Layout of the irradiance lookup's bind group (the LOOKUP_BINDINGS of group 2).
pub fn lookup_layout(gpu: &Gpu) -> wgpu::BindGroupLayout {
    let entries: Vec<wgpu::BindGroupLayoutEntry> = LOOKUP_BINDINGS
        .iter()
        .map(|&b| match b {
            0 => pipelines::uniform_entry(0, wgpu::ShaderStages::COMPUTE),
            _ => pipelines::storage_entry(b, false),
        })
        .collect();
    pipelines::layout(gpu, "surfel lookup", &entries)
}

/// Layouts, created once so pipelines built against them stay valid across resource rebuilds.
struct Layouts {
    surfels: wgpu::BindGroupLayout,
    /// Group 3 of `ray_owner`: the trace pass's indirect arguments (writable only there).
    args: wgpu::BindGroupLayout,
    /// Group 3 of the direct-light part's pass: the per-pixel direct light it writes.
    direct: wgpu::BindGroupLayout,
    /// Group 3 of the reflections part's filter: the per-pixel specular light it writes.
    specular: wgpu::BindGroupLayout,
    scan: wgpu::BindGroupLayout,
}

/// Buffers and bind groups sized by the parameters and the image.
struct Resources {
    params_buffer: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    args_bind_group: wgpu::BindGroup,
    direct_bind_group: wgpu::BindGroup,
    specular_bind_group: wgpu::BindGroup,
    /// The irradiance lookup's bindings for the reflections part's trace pass.
    lookup_bind_group: wgpu::BindGroup,
    args: wgpu::Buffer,
    /// Every per-slot, per-cell and per-ray buffer, cleared on reset.
    clear_on_reset: Vec<wgpu::Buffer>,
    surfels: wgpu::Buffer,
    pool: wgpu::Buffer,
    free_stack: wgpu::Buffer,
    cell_offsets: wgpu::Buffer,
    counters: wgpu::Buffer,
    cell_surfels: wgpu::Buffer,
    states: wgpu::Buffer,
    debug: wgpu::Buffer,
    /// Direct light per pixel (this frame's; the NEE pass or the direct-light part writes it).
    pixel_direct: wgpu::Buffer,
    scans: [ScanJob; 5],
    gpu_params: SurfelParamsGpu,
    /// 16x16-pixel blocks: the coverage pass's workgroups.
    blocks: [u32; 2],
}

/// The GPU pool's counters, read back for tests and the viewer (never inside a frame).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PoolCounts {
    pub capacity: u32,
    pub free: u32,
    pub live: u32,
    /// Slots whose radius marks them live (counted over the surfel buffer).
    pub live_slots: u32,
    pub spawned_last_frame: u32,
    pub recycled_last_frame: u32,
}

/// Per-surfel integrator state read back for tests (irradiance, variance).
#[derive(Clone, Copy, Debug)]
pub struct SurfelSnapshot {
    pub irradiance: [f32; 3],
    pub variance: [f32; 3],
    pub rays_total: f32,
}

pub struct SurfelCore {
    params: Params,
    pub settings: SurfelSettings,
    layouts: Option<Layouts>,
    pipelines: Option<Pipelines>,
    res: Option<Resources>,
    /// The direct-light part for `direct = "restir"` (built the first time it is needed).
    restir_direct: RestirDirect,
    /// The reflections part (built the first time a scene with a specular layer needs it).
    reflections: Reflections,
    features: SceneFeatures,
    /// Largest component of the sky radiance.
    sky_radiance: f32,
    extent: [u32; 2],
    /// Cache-only mode (`SurfelCore::surfel_cache`): surfels spawned, traced and integrated, no
    /// direct light, reflections or apply (another technique reads their irradiance).
    cache_only: bool,
    /// The world ReGIR clipmap ray hits take their lights from (`cache_direct = "regir"`;
    /// built the first time it is asked for).
    world_regir: WorldRegir,
    /// The `cache_direct` the trace pipeline was composed for, and whether it reads the hash
    /// radiance cache (`uncovered_hits`).
    trace_key: ((&'static str, u32), bool),
    /// The hash radiance cache uncovered ray hits read (`uncovered_hits = "hash-cache"`; built
    /// the first time it is asked for).
    hash_cache: HashCache,
}

impl Default for SurfelCore {
    fn default() -> Self {
        let params = Params::new("surfels", PARAMS);
        SurfelCore {
            settings: SurfelSettings::from_params(&params),
            params,
            layouts: None,
            pipelines: None,
            res: None,
            restir_direct: RestirDirect::default(),
            reflections: Reflections::default(),
            features: SceneFeatures::default(),
            sky_radiance: 0.0,
            extent: [0, 0],
            cache_only: false,
            world_regir: WorldRegir::default(),
            trace_key: (("power", 1), false),
            hash_cache: HashCache::new(HashCacheSettings::default()),
        }
    }
}

impl SurfelCore {
    /// The surfels as a cache for another technique (`crate::parts::SurfelCache`): the pool,
    /// grid, rays and integration of every frame, none of the pixels' shading. Reflections off.
    pub fn surfel_cache() -> SurfelCore {
        let mut s = SurfelCore {
            cache_only: true,
            ..SurfelCore::default()
        };
        s.set_params(&ParamChanges::new().choice("reflections", "none"))
            .expect("valid surfel cache parameters");
        s
    }

    /// The irradiance lookup's bind group (valid until the next resource rebuild).
    pub fn lookup_bind_group(&self) -> Option<&wgpu::BindGroup> {
        self.res.as_ref().map(|r| &r.lookup_bind_group)
    }
}

impl SurfelCore {
    fn layouts(&mut self, gpu: &Gpu) -> &Layouts {
        self.layouts.get_or_insert_with(|| {
            let mut entries = vec![pipelines::uniform_entry(0, wgpu::ShaderStages::COMPUTE)];
            for b in 1..=20 {
                entries.push(pipelines::storage_entry(b, false));
            }
            Layouts {
                surfels: pipelines::layout(gpu, "surfels", &entries),
                args: pipelines::layout(
                    gpu,
                    "surfel ray args",
                    &[pipelines::storage_entry(0, false)],
                ),
                direct: self.restir_direct.output_layout(gpu).clone(),
                specular: self.reflections.output_layout(gpu).clone(),
                scan: scan::layout(gpu),
            }
        })
    }

    /// Misses see the sky wherever its radiance is non-zero: surfels persist across camera
    /// moves, so "reachable from the default camera" (SceneFeatures::sky_visible) is not enough.
    fn sky_term(&self) -> bool {
        self.sky_radiance > 0.0
    }

    /// The shader's switches for these settings and this scene.
    fn flags(&self, ctx: &RenderContext) -> u32 {
        let s = &self.settings;
        let mut flags = 0;
        for (on, flag) in [
            (s.guiding, FLAG_GUIDING),
            (s.radial_depth, FLAG_RADIAL_DEPTH),
            (s.msme, FLAG_MSME),
            (ctx.scene.sky.max_element() > 0.0, FLAG_SKY),
            (s.accumulate, FLAG_ACCUMULATE),
            (self.reflections_active(), FLAG_REFLECTIONS),
            (self.cache_only, FLAG_CACHE_ONLY),
            (s.sharing, FLAG_SHARING),
            (s.quarter_apply && !self.cache_only, FLAG_QUARTER_APPLY),
            (s.ray_binning, FLAG_BINNING),
            (s.hard_depth_test, FLAG_HARD_DEPTH),
        ] {
            if on {
                flags |= flag;
            }
        }
        flags
    }

    /// Rays per pixel per frame the technique spends besides surfel rays: the shared camera
    /// ray and (with lights) the direct light's: one shadow ray with NEE, ReSTIR DI's with the
    /// part.
    fn fixed_rays_per_pixel(&self) -> f64 {
        let reflections = if self.reflections_active() {
            self.reflections.rays_per_pixel()
        } else {
            0.0
        };
        1.0 + reflections
            + if self.features.light_count() == 0 {
                0.0
            } else if self.settings.direct_restir {
                self.restir_direct.rays_per_pixel()
            } else {
                1.0
            }
    }

    /// The reflections part runs: `reflections = "traced"` on a scene with a specular layer.
    fn reflections_active(&self) -> bool {
        self.settings.reflections && self.features.min_specular_roughness.is_some()
    }

    /// Builds the reflections part when it is needed and not built (its hits get direct light
    /// and the surfels' irradiance, read from this technique's group 2 at the part's cache
    /// group; `rebuild`: a shader change rebuilds it if built), and passes it the settings.
    fn prepare_reflections(&mut self, ctx: &RenderContext, rebuild: bool) -> Result<()> {
        self.reflections.settings = self.settings.reflection.clone();
        let needed =
            self.settings.reflections && ctx.scene.data.features.min_specular_roughness.is_some();
        let layout = lookup_layout(ctx.gpu);
        self.reflections
            .prepare(ctx, needed, rebuild, Some(HitCache::Surfels(&layout)))
    }

    /// Builds the direct-light part for `direct = "restir"` if not built yet (its resources
    /// follow the image and the scene when it is).
    /// Lookups the world ReGIR clipmap served, for tests and reports.
    pub fn cache_regir_coverage(&self, gpu: &Gpu) -> Result<crate::parts::world_regir::Coverage> {
        self.world_regir.coverage(gpu)
    }

    fn ensure_restir(&mut self, ctx: &RenderContext) -> Result<()> {
        self.restir_direct
            .prepare(ctx, self.settings.direct_restir, false, ())
    }

    fn build_resources(&mut self, ctx: &RenderContext) -> Result<()> {
        let gpu = ctx.gpu;
        self.features = ctx.scene.data.features.clone();
        self.sky_radiance = ctx.scene.sky.max_element();
        self.extent = ctx.extent;
        let (surfel_layout, args_layout, direct_layout, specular_layout) = {
            let l = self.layouts(gpu);
            (
                l.surfels.clone(),
                l.args.clone(),
                l.direct.clone(),
                l.specular.clone(),
            )
        };
        let s = &self.settings;
        let max = s.max_surfels as u64;
        let pixels = ctx.extent[0] as u64 * ctx.extent[1] as u64;
        // Spawn tiles of `spawn_tile` pixels; the coverage pass runs one workgroup per 16x16
        // block of them.
        let spawn_tile = s.spawn_tile(ctx.extent[1]);
        let tiles = [
            ctx.extent[0].div_ceil(spawn_tile),
            ctx.extent[1].div_ceil(spawn_tile),
        ];
        let tile_count = tiles[0] * tiles[1];
        let coverage_groups = [ctx.extent[0].div_ceil(TILE), ctx.extent[1].div_ceil(TILE)];
        let max_binding = gpu.device.limits().max_storage_buffer_binding_size;
        let ray_capacity =
            ((s.ray_budget as u64 * 5 / 4 + 1024).min(max_binding / RAY_RESULT_BYTES)) as u32;
        let f = &self.features;
        let diagonal = glam::Vec3::from(f.bounds_max) - glam::Vec3::from(f.bounds_min);
        let flags = self.flags(ctx);
        let gpu_params = SurfelParamsGpu {
            max_surfels: s.max_surfels,
            ray_budget: s.ray_budget,
            ray_capacity,
            flags,
            coverage_target: s.coverage_target,
            surfel_size: s.surfel_size,
            grid_half_extent: (diagonal.length() * GRID_FRACTION).max(1e-3),
            tiles_x: tiles[0],
            tiles: tile_count,
            cells: GRID_CELLS,
            max_rays_per_surfel: MAX_RAYS_PER_SURFEL,
            spawn_tile,
        };
        let buf = |label: &str, size: u64| pipelines::storage_buffer(gpu, label, size);
        let params_buffer = wgpu::util::DeviceExt::create_buffer_init(
            &gpu.device,
            &wgpu::util::BufferInitDescriptor {
                label: Some("surfel params"),
                contents: bytemuck::bytes_of(&gpu_params),
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            },
        );
        let surfels = buf("surfels", max * SURFEL_BYTES);
        let states = buf("surfel states", max * STATE_BYTES);
        let pool = buf("surfel pool", POOL_BYTES);
        let free_stack = buf("surfel free stack", max * 4);
        let seen = buf("surfel seen", max * 12);
        let guide = buf("surfel guiding maps", max * GUIDE_WORDS * 4);
        let depth = buf("surfel depth maps", max * DEPTH_TEXELS * 8);
        let slot_scan = buf("surfel slot scan", (max + 1) * 4);
        let tile_scan = buf("surfel tile scan", (tile_count as u64 + 1) * 4);
        let cell_offsets = buf("surfel cell offsets", (GRID_CELLS as u64 + 1) * 4);
        let ray_offsets = buf("surfel ray offsets", (max + 1) * 4);
        let tile_pixel = buf("surfel tile pixel", tile_count as u64 * 4);
        // Ray binning's counts and cursors, the cells' cursors, then per ray its bin and the
        // order (`counters` in shared.wgsl).
        let counters = buf(
            "surfel counters",
            (CELL_CURSORS + GRID_CELLS as u64 + 2 * ray_capacity as u64) * 4,
        );
        let cell_surfels = buf("surfel cell lists", max * 8 * 4);
        let ray_owner = buf("surfel ray owner", ray_capacity as u64 * 4);
        let ray_results = buf("surfel ray results", ray_capacity as u64 * RAY_RESULT_BYTES);
        // Per pixel, then (quarter-area apply) per 2x2 block: the gathered irradiance.
        let blocks = ctx.extent[0].div_ceil(2) as u64 * ctx.extent[1].div_ceil(2) as u64;
        let pixel_direct = buf("surfel pixel direct", (pixels + blocks) * 16);
        // Two planes of the surfels' views, a third for the reflections part's.
        let debug = buf("surfel debug", 3 * pixels * 16);
        let pixel_specular = buf("surfel pixel specular", 2 * pixels * 16);
        let frame_estimates = buf("surfel frame estimates", max * 16);
        let args = pipelines::indirect_args_buffer(gpu, "surfel trace args", 1);
        let bind_group = pipelines::buffers_bind_group(
            gpu,
            "surfels",
            &surfel_layout,
            &[
                &params_buffer,
                &surfels,
                &states,
                &pool,
                &free_stack,
                &seen,
                &guide,
                &depth,
                &slot_scan,
                &tile_scan,
                &cell_offsets,
                &ray_offsets,
                &tile_pixel,
                &counters,
                &cell_surfels,
                &ray_owner,
                &ray_results,
                &pixel_direct,
                &debug,
                &pixel_specular,
                &frame_estimates,
            ],
        );
        let args_bind_group =
            pipelines::buffers_bind_group(gpu, "surfel ray args", &args_layout, &[&args]);
        let direct_bind_group =
            pipelines::buffers_bind_group(gpu, "surfel direct", &direct_layout, &[&pixel_direct]);
        let specular_bind_group = pipelines::buffers_bind_group(
            gpu,
            "surfel specular",
            &specular_layout,
            &[&pixel_specular],
        );
        let lookup_buffers = [
            &params_buffer,
            &surfels,
            &states,
            &seen,
            &depth,
            &cell_offsets,
            &cell_surfels,
        ];
        let lookup_entries: Vec<wgpu::BindGroupEntry> = LOOKUP_BINDINGS
            .iter()
            .zip(lookup_buffers)
            .map(|(&binding, b)| wgpu::BindGroupEntry {
                binding,
                resource: b.as_entire_binding(),
            })
            .collect();
        let lookup_bind_group = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("surfel lookup"),
            layout: &lookup_layout(gpu),
            entries: &lookup_entries,
        });
        let Some(p) = &self.pipelines else {
            anyhow::bail!("surfel pipelines are built before their resources");
        };
        let blocks = buf(
            "surfel scan blocks",
            4 * scan::block_buffer_len(
                GRID_CELLS
                    .max(s.max_surfels)
                    .max(tile_count)
                    .max(RAY_BINS as u32),
            ),
        );
        let scans = [
            p.scan
                .job(gpu, "scan: recycled", s.max_surfels, &slot_scan, &blocks)?,
            p.scan
                .job(gpu, "scan: spawns", tile_count, &tile_scan, &blocks)?,
            p.scan
                .job(gpu, "scan: cells", GRID_CELLS, &cell_offsets, &blocks)?,
            p.scan
                .job(gpu, "scan: rays", s.max_surfels, &ray_offsets, &blocks)?,
            p.scan
                .job(gpu, "scan: ray bins", RAY_BINS as u32, &counters, &blocks)?,
        ];
        self.res = Some(Resources {
            params_buffer,
            bind_group,
            args_bind_group,
            direct_bind_group,
            specular_bind_group,
            lookup_bind_group,
            args,
            clear_on_reset: vec![
                surfels.clone(),
                states.clone(),
                seen,
                guide,
                depth,
                slot_scan,
                tile_scan,
                cell_offsets.clone(),
                ray_offsets,
                tile_pixel,
                counters.clone(),
                cell_surfels.clone(),
                pool.clone(),
                pixel_direct.clone(),
                debug.clone(),
            ],
            pixel_direct,
            surfels,
            pool,
            free_stack,
            cell_offsets,
            cell_surfels,
            counters,
            states,
            debug,
            scans,
            gpu_params,
            blocks: coverage_groups,
        });
        Ok(())
    }

    /// The pool's counters and the number of slots that hold a surfel (tests: live + free =
    /// capacity, and the live count matches the slots).
    pub fn pool_counts(&self, gpu: &Gpu) -> Result<Option<PoolCounts>> {
        let Some(r) = &self.res else {
            return Ok(None);
        };
        let words: Vec<u32> = readback::read_buffer(gpu, &r.pool, 12)?;
        let surfels: Vec<[f32; 12]> =
            readback::read_buffer(gpu, &r.surfels, r.gpu_params.max_surfels as usize)?;
        Ok(Some(PoolCounts {
            capacity: r.gpu_params.max_surfels,
            free: words[0],
            live: words[1],
            live_slots: surfels.iter().filter(|s| s[3] > 0.0).count() as u32,
            spawned_last_frame: words[3],
            recycled_last_frame: words[4],
        }))
    }

    /// The grid's cell lists as `sort_cells` left them: each cell's slots (tests: sorted).
    pub fn cell_lists(&self, gpu: &Gpu) -> Result<Vec<Vec<u32>>> {
        let Some(r) = &self.res else {
            return Ok(Vec::new());
        };
        let offsets: Vec<u32> =
            readback::read_buffer(gpu, &r.cell_offsets, GRID_CELLS as usize + 1)?;
        let total = offsets[GRID_CELLS as usize] as usize;
        let lists: Vec<u32> = readback::read_buffer(gpu, &r.cell_surfels, total.max(1))?;
        Ok(offsets
            .windows(2)
            .filter(|w| w[1] > w[0])
            .map(|w| lists[w[0] as usize..w[1] as usize].to_vec())
            .collect())
    }

    /// This frame's direct light per pixel (no emission), as `apply` adds it.
    pub fn pixel_direct(&self, gpu: &Gpu) -> Result<Option<Vec<[f32; 4]>>> {
        let Some(r) = &self.res else {
            return Ok(None);
        };
        let pixels = (self.extent[0] * self.extent[1]) as usize;
        readback::read_buffer(gpu, &r.pixel_direct, pixels).map(Some)
    }

    /// Every live surfel's position and normal, and the triangle it sits on (BVH order + 1,
    /// 0: none): tests check that surfels on moving objects move with them.
    pub fn surfel_positions(&self, gpu: &Gpu) -> Result<Vec<(glam::Vec3, glam::Vec3, u32)>> {
        let Some(r) = &self.res else {
            return Ok(Vec::new());
        };
        let surfels: Vec<[f32; 12]> =
            readback::read_buffer(gpu, &r.surfels, r.gpu_params.max_surfels as usize)?;
        Ok(surfels
            .iter()
            .filter(|s| s[3] > 0.0)
            .map(|s| {
                (
                    glam::Vec3::new(s[0], s[1], s[2]),
                    glam::Vec3::new(s[4], s[5], s[6]),
                    s[7].to_bits(),
                )
            })
            .collect())
    }

    /// Every live surfel's integrator state.
    pub fn surfel_states(&self, gpu: &Gpu) -> Result<Vec<SurfelSnapshot>> {
        let Some(r) = &self.res else {
            return Ok(Vec::new());
        };
        let n = r.gpu_params.max_surfels as usize;
        let surfels: Vec<[f32; 12]> = readback::read_buffer(gpu, &r.surfels, n)?;
        let states: Vec<[f32; 16]> = readback::read_buffer(gpu, &r.states, n)?;
        Ok(surfels
            .iter()
            .zip(&states)
            .filter(|(s, st)| s[3] > 0.0 && st[3] > 0.0)
            .map(|(_, st)| SurfelSnapshot {
                irradiance: [st[0], st[1], st[2]],
                variance: [st[8], st[9], st[10]],
                rays_total: st[3],
            })
            .collect())
    }
}

/// What the holders call: the technique's trait methods, and the cache's frame.
impl SurfelCore {
    pub fn inputs(&self) -> FrameInputs {
        FrameInputs {
            primary_surfaces: true,
        }
    }

    pub fn passes(&self, f: &SceneFeatures) -> Vec<PassInfo> {
        let s = &self.settings;
        let pass = |name, runs, why: String| PassInfo { name, runs, why };
        let lights = f.light_count() > 0;
        let hit_light = match (
            s.cache_light.reservoir,
            s.cache_light.tree,
            s.cache_light.lightcut,
            s.cache_light.rays,
        ) {
            (_, _, true, n) => format!(
                " (light by a stochastic lightcut of at most {n} tree nodes, a shadow ray each, one more for the directional lights)"
            ),
            (true, _, _, n) => format!(
                " (light by a reservoir of 8 candidates{})",
                if n > 1 {
                    format!(", {n} reservoirs averaged")
                } else {
                    String::new()
                }
            ),
            (_, true, _, n) => format!(
                " (light by the light tree{})",
                if n > 1 {
                    format!(", {n} descents averaged")
                } else {
                    String::new()
                }
            ),
            (_, _, _, n) => format!(
                " (light by power{})",
                if n > 1 {
                    format!(", {n} picks averaged")
                } else {
                    String::new()
                }
            ),
        };
        let mut v = vec![
            pass("recycle", true, "recycling heuristic (pool fill, frames unseen, distance, over-coverage); free stack push".into()),
            pass("coverage", true, format!("per {t}x{t}-pixel spawn tile: least-covered pixel, randomised spawn threshold", t = s.spawn_tile(self.extent[1]))),
            pass("spawn", true, format!("pop from the free stack of {} slots", s.max_surfels)),
            pass("grid", true, "radius update, ray requests, non-linear grid rebuilt: count, prefix sum, scatter, per-cell sort".into()),
            WorldRegir::pass_info(&s.cache_light, f),
            pass("allocate", true, format!("{} rays per frame split by request (at most {MAX_RAYS_PER_SURFEL} per surfel)", s.ray_budget)),
        ];
        if s.uncovered_in_hash_cache {
            v.extend(self.hash_cache.passes(f));
        }
        v.extend([
            pass("bin", s.ray_binning, if s.ray_binning { "ray binning: each ray's bin (grid cell, direction quadrant) counted, prefix sum over 65,536 bins".into() } else { "ray_binning off".into() }),
            pass("bin order", s.ray_binning, if s.ray_binning { "rays placed in bin order for the trace pass".into() } else { "ray_binning off".into() }),
            pass(
                "trace",
                true,
                format!(
                    "{} directions; NEE at hits{}; surfel irradiance at hits (multi-bounce), {} where none covers the hit",
                    if s.guiding { "guided (6x6 map, mixed with cosine)" } else { "cosine" },
                    if !lights { " skipped: no lights" } else if s.cache_light.regir && f.many_lights { if s.cache_light.rays > 1 { " (light from the world ReGIR clipmap, picks averaged)" } else { " (light from the world ReGIR clipmap)" } } else { &hit_light },
                    if s.uncovered_in_hash_cache { "the hash radiance cache (no shadow ray) or else a path" } else { "a path" }
                ),
            ),
            pass("estimate", true, format!("each surfel's frame estimate (mean of its rays){}; radial depth {}", if s.sharing { " for irradiance sharing" } else { "" }, if !s.radial_depth { "off" } else if s.hard_depth_test { "on, hard test" } else { "on, Chebyshev test" })),
            pass("integrate", true, format!("{}{}; guiding map", if s.sharing { "irradiance sharing with the cell's surfels (gather weights, by uncertainty), then " } else { "" }, if s.msme { "multiscale mean estimator" } else { "plain running mean (msme off)" })),
        ]);
        v.push(pass(
            "sky",
            self.sky_term(),
            if self.sky_term() {
                format!(
                    "surfel rays that escape see the sky (reachable from the default camera: {})",
                    f.sky_visible
                )
            } else {
                "sky black: misses add nothing".into()
            },
        ));
        if self.cache_only {
            v.push(pass(
                "apply",
                true,
                "cache-only: marks the surfels the pixels see (recycling keeps them), shades no pixel".into(),
            ));
            return v;
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
                "NEE: one light by power, one shadow ray".into()
            },
        ));
        if s.quarter_apply {
            v.push(pass("apply gather", true, "once per 2x2 block: gather the cell's surfels (distance, normal, depth), cell average where weight < 1".into()));
            v.push(pass("apply", true, "irradiance upsampled from the 4 nearest block samples (bilinear x depth x normal; a pixel none matches gathers itself); accumulate".into()));
        } else {
            v.push(pass("apply", true, "gather the cell's surfels (distance, normal, depth), cell average where weight < 1; accumulate".into()));
        }
        v.extend(self.reflections.family_passes(s.reflections, f));
        v
    }

    pub fn build(&mut self, ctx: &RenderContext) -> Result<()> {
        let gpu = ctx.gpu;
        let (surfel_layout, args_layout, scan_layout) = {
            let l = self.layouts(gpu);
            (l.surfels.clone(), l.args.clone(), l.scan.clone())
        };
        // Every pipeline first: on an error nothing is replaced.
        let mut passes = Vec::new();
        for &pass in Pass::ALL {
            if pass == Pass::Trace {
                passes.push(self.trace_pipeline(ctx, &surfel_layout)?);
                continue;
            }
            passes.push(ctx.pipeline(pass.file(), &surfel_layout)?);
        }
        let ray_owner = pipelines::compute_pipeline(
            gpu,
            ctx.shaders,
            RAY_OWNER,
            &[
                &ctx.scene.layout,
                ctx.frame_layout,
                &surfel_layout,
                &args_layout,
            ],
        )?;
        let scan = ScanPipelines::build(gpu, ctx.shaders, &scan_layout)?;
        // The direct-light part is rebuilt too (shader change); if that fails, its old
        // pipelines and the old surfel pipelines stay.
        self.restir_direct
            .prepare(ctx, self.settings.direct_restir, true, ())?;
        self.prepare_reflections(ctx, true)?;
        self.world_regir
            .prepare_for(ctx, &self.settings.cache_light, true)?;
        if self.settings.uncovered_in_hash_cache {
            self.hash_cache.build(ctx)?;
        }
        self.trace_key = self.trace_key();
        self.pipelines = Some(Pipelines {
            passes,
            ray_owner,
            scan,
        });
        // A rebuild after a scene edit or a shader change keeps the surfels and their history
        // (the scene's flags, such as which lights exist, are refreshed); a new size starts over.
        match &self.res {
            Some(r) if self.extent == ctx.extent => {
                let mut p = r.gpu_params;
                p.flags = self.flags(ctx);
                gpu.queue
                    .write_buffer(&r.params_buffer, 0, bytemuck::bytes_of(&p));
                self.features = ctx.scene.data.features.clone();
                self.sky_radiance = ctx.scene.sky.max_element();
            }
            _ => {
                self.build_resources(ctx)?;
                self.reset_history(gpu);
            }
        }
        Ok(())
    }

    pub fn apply_params(&mut self, ctx: &RenderContext) -> Result<()> {
        self.ensure_restir(ctx)?;
        self.prepare_reflections(ctx, false)?;
        self.world_regir
            .prepare_for(ctx, &self.settings.cache_light, false)?;
        if self.settings.uncovered_in_hash_cache && !self.hash_cache.is_built() {
            self.hash_cache.build(ctx)?;
        }
        if self.trace_key != self.trace_key() {
            let layout = self.layouts(ctx.gpu).surfels.clone();
            let pipeline = self.trace_pipeline(ctx, &layout)?;
            if let Some(p) = self.pipelines.as_mut() {
                p.passes[Pass::Trace as usize] = pipeline;
            }
            self.trace_key = self.trace_key();
        }
        self.build_resources(ctx)?;
        self.reset_history(ctx.gpu);
        Ok(())
    }

    /// What the trace pipeline is composed for: the hits' light sampling, the hash cache.
    fn trace_key(&self) -> ((&'static str, u32), bool) {
        (
            self.settings.cache_light.shader_key(),
            self.settings.uncovered_in_hash_cache,
        )
    }

    /// The trace pass: the hits' light sampling (`cache_direct`, with the world ReGIR
    /// clipmap's group) and, with `uncovered_hits = "hash-cache"`, the hash cache's lookup
    /// group after it.
    fn trace_pipeline(
        &self,
        ctx: &RenderContext,
        layout: &wgpu::BindGroupLayout,
    ) -> Result<wgpu::ComputePipeline> {
        let light = &self.settings.cache_light;
        if !self.settings.uncovered_in_hash_cache {
            return WorldRegir::lighting_pipeline(ctx, Pass::Trace.file(), layout, light);
        }
        let cache_layout = hash_cache::lookup_layout(ctx.gpu);
        let defs = |group: u32| {
            let mut d = hash_cache::lookup_defs(group).to_vec();
            d.push(("SURFELS_HASH_CACHE", 1));
            d
        };
        let pipeline = WorldRegir::lighting_pipeline_with(
            ctx,
            Pass::Trace.file(),
            layout,
            light,
            Some((&cache_layout, &defs)),
        );
        if light.regir {
            // With the clipmap's group too, the trace pass binds 34 storage buffers: over the
            // 32 that lavapipe (and many GPUs) allow in one stage.
            return pipeline.context(
                "uncovered_hits = \"hash-cache\" with cache_direct = \"regir\": the trace pass binds both the hash cache and the world ReGIR clipmap, more storage buffers than this GPU allows in one stage; choose one",
            );
        }
        pipeline
    }

    pub fn reset_history(&mut self, gpu: &Gpu) {
        self.hash_cache.reset(gpu);
        let Some(r) = &self.res else {
            return;
        };
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        for b in &r.clear_on_reset {
            enc.clear_buffer(b, 0, None);
        }
        gpu.submit("surfels: history reset", enc.finish());
        // Every slot free, popped from the top: slot 0 first.
        let max = r.gpu_params.max_surfels;
        let stack: Vec<u32> = (0..max).rev().collect();
        gpu.queue
            .write_buffer(&r.free_stack, 0, bytemuck::cast_slice(&stack));
        gpu.queue
            .write_buffer(&r.pool, 0, bytemuck::cast_slice(&[max, 0u32]));
        self.restir_direct.reset(gpu);
        self.reflections.reset(gpu);
    }

    pub fn render(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
    ) {
        let (Some(p), Some(r)) = (&self.pipelines, &self.res) else {
            return;
        };
        let bg = &r.bind_group;
        let max = r.gpu_params.max_surfels;
        let per_slot = [max.div_ceil(64), 1, 1];
        let pass = |enc: &mut wgpu::CommandEncoder,
                    timer: &mut PassTimer,
                    pass: Pass,
                    groups: [u32; 3]| {
            let name = pass.name();
            pipelines::technique_pass(ctx, enc, timer, name, p.get(pass), &[bg], groups);
        };
        pass(enc, timer, Pass::Recycle, per_slot);
        p.scan.record(enc, timer, &r.scans[0]);
        pass(enc, timer, Pass::Push, per_slot);
        pass(enc, timer, Pass::Coverage, [r.blocks[0], r.blocks[1], 1]);
        p.scan.record(enc, timer, &r.scans[1]);
        pass(
            enc,
            timer,
            Pass::Spawn,
            [r.gpu_params.tiles.div_ceil(64), 1, 1],
        );
        // The coverage pass above read last frame's grid; this frame's is built from here.
        enc.clear_buffer(&r.cell_offsets, 0, None);
        enc.clear_buffer(&r.counters, 0, None);
        pass(enc, timer, Pass::Prepare, per_slot);
        p.scan.record(enc, timer, &r.scans[2]);
        pass(enc, timer, Pass::Scatter, per_slot);
        pass(enc, timer, Pass::SortCells, [GRID_CELLS.div_ceil(64), 1, 1]);
        pass(enc, timer, Pass::Allocate, per_slot);
        p.scan.record(enc, timer, &r.scans[3]);
        pipelines::technique_pass(
            ctx,
            enc,
            timer,
            "ray_owner",
            &p.ray_owner,
            &[bg, &r.args_bind_group],
            per_slot,
        );
        let regir = self.world_regir.record_for_pass(
            ctx,
            enc,
            timer,
            self.trace_key.0 .0 == "regir",
            self.features.many_lights,
        );
        // The hash cache's update paths and resolve, before the trace pass reads it.
        let cache = if self.trace_key.1 {
            self.hash_cache.record(ctx, enc, timer);
            self.hash_cache.lookup()
        } else {
            None
        };
        let groups: Vec<&wgpu::BindGroup> = [
            Some(&ctx.scene.bind_group),
            Some(ctx.frame_bind_group),
            Some(bg),
            regir,
            cache,
        ]
        .into_iter()
        .flatten()
        .collect();
        if self.settings.ray_binning {
            // The seed's ray binning: bins counted, summed, the rays ordered by bin.
            let bin = Pass::Bin;
            pipelines::list_pass(enc, timer, bin.name(), p.get(bin), &groups[..3], &r.args, 0);
            p.scan.record(enc, timer, &r.scans[4]);
            let order = Pass::BinOrder;
            pipelines::list_pass(
                enc,
                timer,
                order.name(),
                p.get(order),
                &groups[..3],
                &r.args,
                0,
            );
        }
        let trace = Pass::Trace;
        pipelines::list_pass(enc, timer, trace.name(), p.get(trace), &groups, &r.args, 0);
        pass(enc, timer, Pass::Estimate, per_slot);
        pass(enc, timer, Pass::Integrate, per_slot);
        let image = [ctx.extent[0].div_ceil(8), ctx.extent[1].div_ceil(8), 1];
        if self.cache_only {
            // Marks the surfels the pixels see: recycling frees the ones no pixel saw.
            pass(enc, timer, Pass::Apply, image);
            return;
        }
        if self.restir_direct.active(self.settings.direct_restir) {
            self.restir_direct
                .record(ctx, enc, timer, &r.direct_bind_group);
        } else {
            pass(enc, timer, Pass::Direct, image);
        }
        if self.reflections.active(self.reflections_active()) {
            self.reflections.record(
                ctx,
                enc,
                timer,
                Some(&r.lookup_bind_group),
                (&r.specular_bind_group, 0),
                true,
            );
            self.reflections.copy_debug(enc, ctx.extent, &r.debug, 2);
        }
        if self.settings.quarter_apply {
            let blocks = [ctx.extent[0].div_ceil(2), ctx.extent[1].div_ceil(2)];
            pass(
                enc,
                timer,
                Pass::ApplyGather,
                [blocks[0].div_ceil(8), blocks[1].div_ceil(8), 1],
            );
        }
        pass(enc, timer, Pass::Apply, image);
    }

    pub fn debug_views(&self) -> Vec<DebugView> {
        let view = |name, channel, is_id| DebugView {
            name,
            channel,
            is_id,
        };
        let mut v = vec![
            view("surfel (colour per id)", 0, true),
            view("coverage", 1, false),
            view("rays per surfel", 2, false),
            view("MSME relative variance", 3, false),
            view("grid cell / cascade", 4, true),
            view("surfel age (frames)", 5, false),
            // What a surfel ray (or a GI path ending in the surfels) hitting this pixel's
            // surface finds: the gather the rays make, at the pixel (issue 57).
            view(
                "ray-hit coverage (1 surfels, 2 cell average, 3 none)",
                6,
                true,
            ),
        ];
        v.extend(crate::parts::reflections::debug_views(2));
        v
    }

    pub fn debug_buffer(&self) -> Option<&wgpu::Buffer> {
        self.res.as_ref().map(|r| &r.debug)
    }

    pub fn param_set(&self) -> &Params {
        &self.params
    }

    pub fn set_params(&mut self, changes: &ParamChanges) -> Result<()> {
        self.params.apply(changes)?;
        self.settings = SurfelSettings::from_params(&self.params);
        Ok(())
    }

    /// Surfels spawn over the first frames (and hits outside their cover trace paths then):
    /// the cost per surfel ray settles after a few dozen frames.
    pub fn calibration_frames(&self) -> u32 {
        16
    }

    pub fn params_for_ray_budget(
        &self,
        rays_per_pixel: f64,
        measured: Option<f64>,
    ) -> Option<ParamChanges> {
        // Each surfel ray costs itself plus what its hit traces (a shadow ray, a path where the
        // cache does not cover): measured at the current budget (which the allocation always
        // spends in full), else 2.
        let pixels = (self.extent[0] as f64 * self.extent[1] as f64).max(1.0);
        let fixed = self.fixed_rays_per_pixel();
        let current = self.settings.ray_budget as f64 / pixels;
        let per_ray = measured
            .filter(|m| *m > fixed && current > 0.0)
            .map(|m| ((m - fixed) / current).clamp(1.0, 16.0))
            .unwrap_or(2.0);
        let budget = (((rays_per_pixel - fixed).max(0.0) / per_ray) * pixels).round();
        let budget = budget.clamp(0.0, 16_000_000.0) as i64;
        (budget != self.settings.ray_budget as i64)
            .then(|| ParamChanges::new().int("ray_budget", budget))
    }
}
