//! The world-space ReGIR clipmap: light reservoirs for the points a cache lights (Lumen's card
//! texels, surfel ray hits), wherever they are, not only under the pixels as ReSTIR DI's
//! camera grid. "Making Connections" (shared/seeds/003) lights Lumen's surface cache with
//! ReGIR-sampled lights from a clipmap of cells: `cache_direct = "regir"`.
//!
//! - Levels of `DIMS`³ cells centred on the camera, each level's cell edge twice the last's;
//!   a point takes the finest level whose window holds it. The finest edge and the level count
//!   follow from the scene's bounds so that the coarsest window holds the whole scene twice.
//! - Cells are addressed toroidally, so a cell keeps its index (and its marks) as the camera
//!   moves.
//! - A lookup marks its cell; each frame the build fills the cells read in the last
//!   `KEEP_FRAMES` frames (`slots` reservoirs each, 32 light candidates per reservoir, target
//!   strength / distance² to the cell centre: `gilab::regir`, the same code as ReSTIR DI's grid).
//! - A lookup resamples `lookup_candidates` of its cell's reservoirs by the irradiance each
//!   gives the point (unshadowed, L G cos). A cell not built this frame (read for the first
//!   time) takes the light by power: the choice does not depend on the lookup's random numbers,
//!   so the estimate stays unbiased.
//!
//! Shaders: shaders/parts/world_regir/ (the module and the build), shaders/parts/cache_light.wgsl
//! (the caches' one place to pick a light). A consumer composes its lighting pass with
//! [`lookup_defs`] and binds [`WorldRegir::bind_group`] at that group; the build binds it at
//! group 2 (`WORLD_REGIR_GROUP`'s default).

use crate::gpu::{readback, timing::PassTimer, Gpu};
use crate::parts::Part;
use crate::render::params::{ParamChanges, ParamKind, ParamSpec, Params};
use crate::render::{pipelines, PassInfo, RenderContext};
use crate::scene::features::SceneFeatures;
use anyhow::Result;

/// One more bind group for `WorldRegir::lighting_pipeline_with`: its layout, and its shader
/// defs given the group index it is bound at.
pub type ExtraGroup<'a> = (
    &'a wgpu::BindGroupLayout,
    &'a dyn Fn(u32) -> Vec<(&'static str, u32)>,
);

/// Cells along each axis of a level.
pub const DIMS: u32 = 16;
/// A cell is rebuilt while a lookup read it within this many frames.
pub const KEEP_FRAMES: u32 = 8;
/// Light candidates resampled into each reservoir (`REGIR_CANDIDATES_PER_SLOT`).
pub const CANDIDATES_PER_SLOT: u32 = 32;
pub const BUILD_FILE: &str = "parts/world_regir/build.wgsl";
pub const PASS: &str = "cache regir";
const SLOT_BYTES: u64 = crate::parts::restir::REGIR_SLOT_BYTES;
/// Pairs of lookup counters (`STAT_SLOTS` in shaders/parts/world_regir/shared.wgsl).
const STAT_SLOTS: u64 = 64;

/// The caches' light-sampling parameters: every family with a cache adds them to its own.
pub const PARAMS: [ParamSpec; 4] = [
    ParamSpec {
        name: "cache_direct",
        what: "how the cache picks the light for each point it lights (card texels, surfel ray hits): by power from the whole light pool, from the world-space ReGIR clipmap's cell at the point (seed 003, ReGIR lighting the cache; runs only with many lights), by a reservoir of 8 power-sampled candidates resampled by their unshadowed contribution at the point (seed 001's light sampling at a surfel ray's hit), by one descent of the light tree at the point and its normal (parts::light_tree), or by a stochastic lightcut: a cut of `cache_light_rays` tree nodes chosen at the point, one descent and one shadow ray below each (seed 001's \"lightcut 4\"; at surfel ray hits; other caches take one tree descent)",
        higher: "regir: lights near the point are picked far more often: lower noise on many lights, one build pass per frame; reservoir: the candidate that lights the point most wins, 8 light evaluations per point, no build pass; tree: lights near and facing the point, a tree walk per point, no build pass; lightcut: the strongest groups of lights each get a shadow ray: least noise per point, a ray per cut node",
        lower: "power: no build pass; a point far from the bright lights gets mostly useless samples",
        kind: ParamKind::Choice(&["power", "regir", "reservoir", "tree", "lightcut"]),
        default: 0.0,
    },
    ParamSpec {
        name: "cache_light_rays",
        what: "shadow rays per point at surfel ray hits (the caches that shade a hit with `cache_direct`'s sampler): that many independent picks averaged (GIBS's \"random 2\" is power with 2), or the lightcut's size (its \"lightcut 4\"); directional lights add one ray to a lightcut",
        higher: "less noise per hit, a shadow ray more each",
        lower: "1: one light sample per hit (a lightcut of 1 is one tree descent)",
        kind: ParamKind::Int { min: 1, max: 8 },
        default: 1.0,
    },
    ParamSpec {
        name: "cache_regir_slots",
        what: "light reservoirs per world ReGIR cell (each resampled from 32 lights by power over squared distance to the cell)",
        higher: "more distinct lights per cell: less correlation between points of one cell, a costlier build",
        lower: "cheaper build, lookups in a cell share fewer lights",
        kind: ParamKind::Int { min: 1, max: 64 },
        default: 16.0,
    },
    ParamSpec {
        name: "cache_regir_candidates",
        what: "reservoirs of its cell that one lookup resamples by the irradiance each gives the point",
        higher: "better light choice per point (the cosine and the distance within the cell count), more light evaluations",
        lower: "cheaper lookups; 1 takes a reservoir as the cell chose it",
        kind: ParamKind::Int { min: 1, max: 32 },
        default: 4.0,
    },
];

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct WorldRegirSettings {
    /// `cache_direct = "regir"`.
    pub regir: bool,
    /// `cache_direct = "reservoir"` (`CACHE_RESERVOIR` in shaders/parts/cache_light.wgsl).
    pub reservoir: bool,
    /// `cache_direct = "tree"`: one light by the light tree (`LIGHT_TREE`, parts::light_tree).
    pub tree: bool,
    /// `cache_direct = "lightcut"`: a stochastic lightcut of `rays` tree nodes at surfel ray
    /// hits (`CACHE_LIGHTCUT`), one tree descent elsewhere.
    pub lightcut: bool,
    /// `cache_light_rays`: light samples (shadow rays) per surfel ray hit, or the cut's size.
    pub rays: u32,
    pub slots: u32,
    pub lookup_candidates: u32,
}

impl WorldRegirSettings {
    /// These settings as typed parameter changes, for a family that hands them to a cache it
    /// holds (ReSTIR GI's termination caches).
    pub fn to_changes(self) -> ParamChanges {
        ParamChanges::new()
            .choice("cache_direct", self.name())
            .int("cache_light_rays", self.rays as i64)
            .int("cache_regir_slots", self.slots as i64)
            .int("cache_regir_candidates", self.lookup_candidates as i64)
    }

    /// The `cache_direct` choice.
    pub fn name(&self) -> &'static str {
        if self.regir {
            "regir"
        } else if self.reservoir {
            "reservoir"
        } else if self.tree {
            "tree"
        } else if self.lightcut {
            "lightcut"
        } else {
            "power"
        }
    }

    /// Whether a cache point's lights come from the light tree (`tree`, and `lightcut`
    /// wherever no cut is taken).
    pub fn uses_tree(&self) -> bool {
        self.tree || self.lightcut
    }

    /// What a lighting pipeline is composed for: a different key needs a new pipeline.
    pub fn shader_key(&self) -> (&'static str, u32) {
        (self.name(), self.rays)
    }

    pub fn from_params(p: &Params) -> WorldRegirSettings {
        WorldRegirSettings {
            regir: p.u32("cache_direct") == 1,
            reservoir: p.u32("cache_direct") == 2,
            tree: p.u32("cache_direct") == 3,
            lightcut: p.u32("cache_direct") == 4,
            rays: p.u32("cache_light_rays").clamp(1, 8),
            slots: p.u32("cache_regir_slots").max(1),
            lookup_candidates: p.u32("cache_regir_candidates").max(1),
        }
    }
}

/// Shader defs of a pipeline that picks its cache lights from the clipmap (`CACHE_REGIR`),
/// whose bind group it binds at `group`.
pub fn lookup_defs(group: u32) -> [(&'static str, u32); 2] {
    [("CACHE_REGIR", 1), ("WORLD_REGIR_GROUP", group)]
}

/// `WorldRegirParams` in shaders/parts/world_regir/shared.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct WorldRegirParamsGpu {
    pub cell_size: f32,
    pub levels: u32,
    pub dims: u32,
    pub slots: u32,
    pub lookup_candidates: u32,
    pub keep_frames: u32,
    pub pad: [u32; 2],
}

struct Buffers {
    params: wgpu::Buffer,
    slots: wgpu::Buffer,
    /// Marks, built flags, then the lookup counters.
    cells: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    gpu_params: WorldRegirParamsGpu,
}

/// Lookups since the buffers were made, and how many a built cell served.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Coverage {
    pub lookups: u64,
    pub served: u64,
}

impl Coverage {
    pub fn served_share(&self) -> f64 {
        self.served as f64 / self.lookups.max(1) as f64
    }
}

#[derive(Default)]
pub struct WorldRegir {
    pipeline: Option<wgpu::ComputePipeline>,
    buffers: Option<Buffers>,
    /// The holder's settings the buffers are sized for (`prepare_for`).
    settings: WorldRegirSettings,
}

impl WorldRegir {
    /// Layout of the part's bind group (the group a consumer sets `WORLD_REGIR_GROUP` to).
    pub fn layout(gpu: &Gpu) -> wgpu::BindGroupLayout {
        pipelines::layout(
            gpu,
            "world regir",
            &[
                pipelines::uniform_entry(0, wgpu::ShaderStages::COMPUTE),
                pipelines::storage_entry(1, false),
                pipelines::storage_entry(2, false),
            ],
        )
    }

    /// What a consumer calls when it builds (`rebuild`: its shaders changed, so the build
    /// pipeline is composed again for hot reload) or its settings or scene change: the
    /// [`Part`] bookkeeping, wanted when `cache_direct = "regir"`, sized for the scene.
    pub fn prepare_for(
        &mut self,
        ctx: &RenderContext,
        s: &WorldRegirSettings,
        rebuild: bool,
    ) -> Result<()> {
        self.settings = *s;
        self.prepare(ctx, s.regir, rebuild, ())
    }

    /// A consumer's lighting pipeline (`entry` over the scene, the frame and its own group 2):
    /// composed with the clipmap's lookup and its bind group at group 3 with `regir`, with
    /// `CACHE_RESERVOIR` with `reservoir`, `LIGHT_TREE` with `tree`, both `LIGHT_TREE` and
    /// `CACHE_LIGHTCUT` (the cut's size) with `lightcut`, `CACHE_LIGHT_RAYS` when more than one
    /// sample a point is asked for without a cut, as it is otherwise.
    pub fn lighting_pipeline(
        ctx: &RenderContext,
        entry: &str,
        own: &wgpu::BindGroupLayout,
        light: &WorldRegirSettings,
    ) -> Result<wgpu::ComputePipeline> {
        Self::lighting_pipeline_with(ctx, entry, own, light, None)
    }

    /// `lighting_pipeline` with one more bind group after the clipmap's (group 3, or 4 with
    /// `regir`): its layout and its defs for the group index it lands at.
    pub fn lighting_pipeline_with(
        ctx: &RenderContext,
        entry: &str,
        own: &wgpu::BindGroupLayout,
        light: &WorldRegirSettings,
        extra: Option<ExtraGroup>,
    ) -> Result<wgpu::ComputePipeline> {
        let mut defs: Vec<(&str, u32)> = Vec::new();
        if light.rays > 1 && !light.lightcut {
            defs.push(("CACHE_LIGHT_RAYS", light.rays));
        }
        if light.reservoir {
            defs.push(("CACHE_RESERVOIR", 1));
        } else if light.tree {
            defs.push(("LIGHT_TREE", 1));
        } else if light.lightcut {
            defs.extend([("LIGHT_TREE", 1), ("CACHE_LIGHTCUT", light.rays)]);
        }
        let regir_layout;
        let mut layouts: Vec<&wgpu::BindGroupLayout> =
            vec![&ctx.scene.layout, ctx.frame_layout, own];
        if light.regir {
            defs.extend(lookup_defs(3));
            regir_layout = Self::layout(ctx.gpu);
            layouts.push(&regir_layout);
        }
        if let Some((layout, group_defs)) = extra {
            defs.extend(group_defs(layouts.len() as u32));
            layouts.push(layout);
        }
        if defs.is_empty() {
            return ctx.pipeline(entry, own);
        }
        pipelines::compute_pipeline(ctx.gpu, &ctx.shaders.with_defs(&defs), entry, &layouts)
    }

    /// The clipmap's geometry for this scene: finest cell edge and level count.
    pub fn geometry(f: &SceneFeatures) -> (f32, u32) {
        let lo = glam::Vec3::from(f.bounds_min);
        let hi = glam::Vec3::from(f.bounds_max);
        let diag = (hi - lo).length().max(1e-3);
        let cell = diag / 48.0;
        // The coarsest window (DIMS cells of cell * 2^(levels-1)) spans twice the diagonal.
        let mut levels = 1;
        while levels < 8 && DIMS as f32 * cell * ((1u32 << (levels - 1)) as f32) < 2.0 * diag {
            levels += 1;
        }
        (cell, levels)
    }

    /// Buffers for this scene and these settings (kept while their sizes hold; the marks and
    /// counters start from zero when they are made).
    fn size_buffers(&mut self, gpu: &Gpu, f: &SceneFeatures) {
        let s = self.settings;
        let (cell_size, levels) = Self::geometry(f);
        let cells = levels as u64 * (DIMS as u64).pow(3);
        let gpu_params = WorldRegirParamsGpu {
            cell_size,
            levels,
            dims: DIMS,
            slots: s.slots,
            lookup_candidates: s.lookup_candidates,
            keep_frames: KEEP_FRAMES,
            pad: [0; 2],
        };
        let slot_bytes = cells * s.slots as u64 * SLOT_BYTES;
        let cell_bytes = (2 * cells + 2 * STAT_SLOTS) * 4;
        let keep = matches!(&self.buffers, Some(b) if b.slots.size() == slot_bytes.max(16) && b.cells.size() == cell_bytes.max(16));
        if !keep {
            let params = gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("world regir params"),
                size: std::mem::size_of::<WorldRegirParamsGpu>() as u64,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let slots = pipelines::storage_buffer(gpu, "world regir slots", slot_bytes);
            let cells_buf = pipelines::storage_buffer(gpu, "world regir cells", cell_bytes);
            let bind_group = pipelines::buffers_bind_group(
                gpu,
                "world regir",
                &Self::layout(gpu),
                &[&params, &slots, &cells_buf],
            );
            self.buffers = Some(Buffers {
                params,
                slots,
                cells: cells_buf,
                bind_group,
                gpu_params,
            });
        }
        if let Some(b) = self.buffers.as_mut() {
            b.gpu_params = gpu_params;
            gpu.queue
                .write_buffer(&b.params, 0, bytemuck::bytes_of(&b.gpu_params));
        }
    }

    /// The bind group a consumer binds at its `WORLD_REGIR_GROUP`.
    pub fn bind_group(&self) -> Option<&wgpu::BindGroup> {
        self.buffers.as_ref().map(|b| &b.bind_group)
    }

    fn cell_count(&self) -> u64 {
        self.buffers.as_ref().map_or(0, |b| {
            b.gpu_params.levels as u64 * (b.gpu_params.dims as u64).pow(3)
        })
    }

    /// This frame's build, before the consumer's lookups: clears the built flags, then fills the
    /// marked cells. `active` false (few lights: rule 3) only clears, so every lookup falls
    /// back to power sampling.
    fn record(
        &self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
        active: bool,
    ) {
        let (Some(pipeline), Some(b)) = (&self.pipeline, &self.buffers) else {
            return;
        };
        let cells = self.cell_count();
        enc.clear_buffer(&b.cells, cells * 4, Some(cells * 4));
        if !active {
            return;
        }
        let invocations = cells as u32 * b.gpu_params.slots;
        pipelines::technique_pass(
            ctx,
            enc,
            timer,
            PASS,
            pipeline,
            &[&b.bind_group],
            [invocations.div_ceil(64), 1, 1],
        );
    }

    /// A consumer's call before its lighting pass: when that pass's pipeline reads the
    /// clipmap (`composed`), records this frame's build (`many_lights` false: only clears, see
    /// [`Self::record`]) and returns the bind group to set at group 3.
    pub fn record_for_pass(
        &self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
        composed: bool,
        many_lights: bool,
    ) -> Option<&wgpu::BindGroup> {
        let group = self.bind_group().filter(|_| composed)?;
        self.record(ctx, enc, timer, many_lights);
        Some(group)
    }

    /// Lookups and served lookups since the buffers were made (reads the GPU: tests and
    /// reports). Marks and counters survive a history reset: they say where to build, not
    /// what the light is.
    pub fn coverage(&self, gpu: &Gpu) -> Result<Coverage> {
        let Some(b) = &self.buffers else {
            return Ok(Coverage::default());
        };
        let cells = self.cell_count() as usize;
        let words: Vec<u32> =
            readback::read_buffer(gpu, &b.cells, 2 * cells + 2 * STAT_SLOTS as usize)?;
        let stats = &words[2 * cells..];
        Ok(Coverage {
            lookups: stats.iter().step_by(2).map(|&w| w as u64).sum(),
            served: stats.iter().skip(1).step_by(2).map(|&w| w as u64).sum(),
        })
    }

    /// The build pass, for the consumer's pass list.
    pub fn pass_info(s: &WorldRegirSettings, f: &SceneFeatures) -> PassInfo {
        let runs = s.regir && f.many_lights;
        let (cell, levels) = Self::geometry(f);
        PassInfo {
            name: PASS,
            runs,
            why: if !s.regir {
                "cache_direct = power: cache lights picked by power from the whole pool".into()
            } else if runs {
                format!(
                    "{} lights: world ReGIR clipmap, {levels} levels of {DIMS}^3 cells from {cell:.3} units, {} reservoirs of {CANDIDATES_PER_SLOT} candidates per cell read in the last {KEEP_FRAMES} frames, {} per lookup",
                    f.light_count(),
                    s.slots,
                    s.lookup_candidates
                )
            } else {
                format!(
                    "only {} lights: the cache picks lights by power, no clipmap",
                    f.light_count()
                )
            },
        }
    }
}

impl Part for WorldRegir {
    type Input<'a> = ();

    fn is_built(&self) -> bool {
        self.pipeline.is_some()
    }

    /// The build pipeline (on an error the previous one stays).
    fn build(&mut self, ctx: &RenderContext, _: ()) -> Result<()> {
        let layout = Self::layout(ctx.gpu);
        self.pipeline = Some(pipelines::compute_pipeline(
            ctx.gpu,
            ctx.shaders,
            BUILD_FILE,
            &[&ctx.scene.layout, ctx.frame_layout, &layout],
        )?);
        Ok(())
    }

    fn build_resources(&mut self, ctx: &RenderContext) {
        self.size_buffers(ctx.gpu, &ctx.scene.data.features);
    }

    /// Nothing: the slots are built again every frame, and the marks and counters say where to
    /// build (and what `coverage` reports), not what the light is.
    fn reset(&self, _: &Gpu) {}
}
