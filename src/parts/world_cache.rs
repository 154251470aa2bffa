//! Lumen's world radiance cache as a part (shared/seeds/000, "Radiance Caching for Real-Time
//! Global Illumination"): camera-centred clipmap levels of probes, 16×16 equal-area cells of
//! radiance each. A lookup (`gilab::world_cache::world_lookup`, at the bind group a pass names
//! with `WORLD_CACHE_GROUP`) interpolates the eight probes around a point in a direction and
//! marks them read; each frame `world select` lists the probes read in the last 8 frames
//! (never traced first, then the stalest) and `world update` traces a fixed budget of them,
//! 256 rays each, lit at their hits from the surface cache.
//!
//! Its rays run through the scene-tracing part (`gilab::tracing::trace_scene`,
//! [`crate::parts::tracing`], bind group 2), so it lives beside a surface cache: Lumen's final gather reads it past a screen
//! probe's TMin, and ReSTIR GI's sample paths end in it (`gi_terminate = "lumen-world"`,
//! through [`crate::parts::SurfaceCache`] built with the world cache).

use crate::gpu::{timing::PassTimer, Gpu};
use crate::render::{pipelines, PassInfo, RenderContext};
use anyhow::Result;
use glam::Vec3;

/// The cache's bindings: uniform, update lists, probes. A reader binds 24 and 26 in one of its
/// groups (its lookups mark probes read in the probes' buffer); the lists are the cache's own.
pub const BINDINGS: [u32; 3] = [24, 25, 26];
/// The cache's own passes (timer name, file).
pub const PASSES: [(&str, &str); 2] = [
    ("world select", "parts/world_cache/select.wgsl"),
    ("world update", "parts/world_cache/update.wgsl"),
];

const WORLD_CELLS: u64 = 256;
/// Words before the lists (`WORLD_LISTS_HEADER`).
const LISTS_HEADER_WORDS: u64 = 4;
const MAX_WORKGROUPS: u32 = 65_535;
/// Probes sit off the round coordinates walls are modelled at: a probe exactly on a
/// zero-thickness wall sees both rooms and leaked the sunlit side into thin-wall's dark room.
const GRID_OFFSET: Vec3 = Vec3::new(0.382, 0.618, 0.271);

/// Shader defs of a pipeline that reads the cache at bind group `group`.
pub fn lookup_defs(group: u32) -> [(&'static str, u32); 1] {
    [("WORLD_CACHE_GROUP", group)]
}

/// Layout entries of a reader's bindings (it adds them to one of its groups' layouts).
pub fn lookup_entries() -> Vec<wgpu::BindGroupLayoutEntry> {
    vec![
        pipelines::uniform_entry(BINDINGS[0], wgpu::ShaderStages::COMPUTE),
        pipelines::storage_entry(BINDINGS[2], false),
    ]
}

/// What sizes and drives the cache (Lumen's `world_cache_*` parameters).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WorldCacheSettings {
    /// Clipmap levels (1..=4), each twice the last's probe spacing.
    pub levels: u32,
    /// Probes per axis of a level.
    pub probes: u32,
    /// Probes traced per frame (the fixed update cost).
    pub probes_per_frame: u32,
    /// Updates in a cell's running mean at most (1: the latest).
    pub history: u32,
    /// Distance a ray travels before it reads the cache; level 0's spacing is a quarter of it.
    pub distance: f32,
}

/// The defaults (Lumen's `world_cache_*` parameters take theirs from here): the seed's 2 m
/// probe TMin, three 16^3 clipmaps, 128 probes traced a frame, the latest update alone.
pub const DEFAULTS: WorldCacheSettings = WorldCacheSettings {
    levels: 3,
    probes: 16,
    probes_per_frame: 128,
    history: 1,
    distance: 2.0,
};

impl WorldCacheSettings {
    pub fn slots(&self) -> u32 {
        self.levels * self.probes * self.probes * self.probes
    }

    /// Probe spacing of level 0 (scene units).
    pub fn spacing(&self) -> f32 {
        self.distance / 4.0
    }

    /// The camera-centred extent of the coarsest level.
    pub fn extent(&self) -> Vec3 {
        Vec3::splat(self.spacing() * (1u32 << (self.levels - 1)) as f32 * self.probes as f32)
    }
}

/// `WorldCacheParams` of shaders/parts/world_cache/shared.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct WorldCacheParamsGpu {
    pub levels: [[f32; 4]; 4],
    pub base: [[i32; 4]; 4],
    pub shape: [u32; 4],
    pub update: [u32; 4],
    pub misc: [f32; 4],
}

/// The select and update pipelines (groups: scene, frame, Lumen's group 2, the cache's own).
pub struct WorldCachePipelines {
    select: wgpu::ComputePipeline,
    update: wgpu::ComputePipeline,
}

impl WorldCachePipelines {
    /// Both pipelines or an error. `lumen` is the layout of Lumen's group 2 (its tracing and
    /// the surface cache the probes' hits read).
    pub fn build(ctx: &RenderContext, lumen: &wgpu::BindGroupLayout) -> Result<Self> {
        let own = WorldCache::layout(ctx.gpu);
        let layouts = [&ctx.scene.layout, ctx.frame_layout, lumen, &own];
        let shaders = ctx.shaders.with_defs(&lookup_defs(3));
        let build = |file| pipelines::compute_pipeline(ctx.gpu, &shaders, file, &layouts);
        Ok(WorldCachePipelines {
            select: build(PASSES[0].1)?,
            update: build(PASSES[1].1)?,
        })
    }
}

pub struct WorldCache {
    settings: WorldCacheSettings,
    params: wgpu::Buffer,
    lists: wgpu::Buffer,
    probes: wgpu::Buffer,
    gpu_params: WorldCacheParamsGpu,
    /// The cache's bindings alone, for its own passes (group 3).
    bind_group: wgpu::BindGroup,
}

impl WorldCache {
    /// Layout of the cache's own passes' group (every binding).
    pub fn layout(gpu: &Gpu) -> wgpu::BindGroupLayout {
        let mut entries = lookup_entries();
        entries.push(pipelines::storage_entry(BINDINGS[1], false));
        pipelines::layout(gpu, "world radiance cache", &entries)
    }

    /// The cache's buffers for `s`; errors where one would exceed the device's binding limit.
    pub fn new(gpu: &Gpu, s: WorldCacheSettings) -> Result<WorldCache> {
        anyhow::ensure!(
            (1..=4).contains(&s.levels),
            "world cache: 1 to 4 levels, not {}",
            s.levels
        );
        let slots = s.slots() as u64;
        // Per slot: its cells, a header, the frames it was read and traced.
        let probe_bytes = slots * (WORLD_CELLS + 2) * 16;
        let list_bytes = (LISTS_HEADER_WORDS + 2 * slots) * 4;
        let limit = gpu.device.limits().max_storage_buffer_binding_size;
        anyhow::ensure!(
            probe_bytes <= limit,
            "world cache: {} MiB of probes, over this device's {} MiB binding limit (fewer world_cache_probes or levels)",
            probe_bytes >> 20,
            limit >> 20
        );
        let params = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("world cache params"),
            size: std::mem::size_of::<WorldCacheParamsGpu>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let lists = pipelines::storage_buffer(gpu, "world cache lists", list_bytes);
        let probes = pipelines::storage_buffer(gpu, "world cache probes", probe_bytes);
        let entries: Vec<wgpu::BindGroupEntry> = BINDINGS
            .iter()
            .zip([&params, &lists, &probes])
            .map(|(&binding, b)| wgpu::BindGroupEntry {
                binding,
                resource: b.as_entire_binding(),
            })
            .collect();
        let bind_group = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("world radiance cache"),
            layout: &Self::layout(gpu),
            entries: &entries,
        });
        let cache = WorldCache {
            settings: s,
            params,
            lists,
            probes,
            gpu_params: WorldCacheParamsGpu::default(),
            bind_group,
        };
        cache.reset(gpu);
        Ok(cache)
    }

    pub fn settings(&self) -> WorldCacheSettings {
        self.settings
    }

    /// Forgets every probe: no cell traced, every header "never traced" (w = -1), no marks.
    pub fn reset(&self, gpu: &Gpu) {
        let slots = self.settings.slots() as u64;
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        enc.clear_buffer(&self.lists, 0, None);
        enc.clear_buffer(&self.probes, 0, None);
        gpu.submit("world cache: reset", enc.finish());
        let headers = vec![[0.0f32, 0.0, 0.0, -1.0]; slots as usize];
        gpu.queue.write_buffer(
            &self.probes,
            slots * WORLD_CELLS * 16,
            bytemuck::cast_slice(&headers),
        );
    }

    /// Forgets the probes within one probe spacing of `boxes` (world boxes: where objects
    /// were and now are), on every level as last placed: their headers read "never traced", so
    /// lookups skip them (a coarser level or the ray answers) and `world select` lists them
    /// first once read. Returns how many slots it wrote.
    pub fn invalidate(&self, gpu: &Gpu, boxes: &[(Vec3, Vec3)]) -> usize {
        let p = &self.gpu_params;
        let n = self.settings.probes as i32;
        if p.shape[0] == 0 || boxes.is_empty() {
            return 0;
        }
        let never = [0.0f32, 0.0, 0.0, -1.0];
        let header_at = self.settings.slots() as u64 * WORLD_CELLS * 16;
        let mut written = 0;
        for l in 0..self.settings.levels as usize {
            let [ox, oy, oz, spacing] = p.levels[l];
            let origin = Vec3::new(ox, oy, oz);
            let base = glam::IVec3::from_slice(&p.base[l][..3]);
            let per = (n * n * n) as u64;
            for &(lo, hi) in boxes {
                let g0 = ((lo - origin) / spacing - Vec3::ONE).floor().as_ivec3() + base;
                let g1 = ((hi - origin) / spacing + Vec3::ONE).ceil().as_ivec3() + base;
                let g0 = g0.max(base);
                let g1 = g1.min(base + glam::IVec3::splat(n - 1));
                for z in g0.z..=g1.z {
                    for y in g0.y..=g1.y {
                        // Runs of consecutive slots (a row wraps round the torus at most once).
                        let mut x = g0.x;
                        while x <= g1.x {
                            let w = glam::IVec3::new(x, y, z).rem_euclid(glam::IVec3::splat(n));
                            let run = (g1.x - x + 1).min(n - w.x);
                            let slot = l as u64 * per + ((w.z * n + w.y) * n + w.x) as u64;
                            gpu.queue.write_buffer(
                                &self.probes,
                                header_at + slot * 16,
                                bytemuck::cast_slice(&vec![never; run as usize]),
                            );
                            written += run as usize;
                            x += run;
                        }
                    }
                }
            }
        }
        written
    }

    /// A reader's bindings (`lookup_entries`) as entries of its bind group.
    pub fn entries(&self) -> [wgpu::BindGroupEntry<'_>; 2] {
        [
            wgpu::BindGroupEntry {
                binding: BINDINGS[0],
                resource: self.params.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: BINDINGS[2],
                resource: self.probes.as_entire_binding(),
            },
        ]
    }

    /// This frame's uniforms: the levels centred on the camera, the update budget. Budget,
    /// history and distance may change without new buffers (`settings` keeps the sizes).
    fn prepare(&mut self, ctx: &RenderContext, s: &WorldCacheSettings) {
        let p = &mut self.gpu_params;
        let n = self.settings.probes;
        p.shape = [
            n,
            self.settings.levels,
            self.settings.slots(),
            s.probes_per_frame,
        ];
        p.update = [s.history.max(1), 0, 0, 0];
        p.misc = [s.distance, 0.0, 0.0, 0.0];
        let half = glam::IVec3::splat(n as i32 / 2);
        for l in 0..self.settings.levels as usize {
            let spacing = s.distance / 4.0 * (1u32 << l) as f32;
            let base = (ctx.camera.position / spacing).floor().as_ivec3() - half;
            let origin = (base.as_vec3() + GRID_OFFSET) * spacing;
            p.levels[l] = [origin.x, origin.y, origin.z, spacing];
            p.base[l] = [base.x, base.y, base.z, 0];
        }
        ctx.gpu
            .queue
            .write_buffer(&self.params, 0, bytemuck::bytes_of(&self.gpu_params));
    }

    /// The cache's passes (they run when `on` and `reader` reads the cache), its rays traced
    /// through `tracing` ("BVH" or "SDF").
    pub fn pass_info(
        s: &WorldCacheSettings,
        on: bool,
        tracing: &str,
        reader: &str,
    ) -> Vec<PassInfo> {
        let why = |why: String| {
            if on {
                why
            } else {
                "world_cache = false".into()
            }
        };
        let levels = s.levels;
        let per_axis = s.probes;
        vec![
            PassInfo {
                name: PASSES[0].0,
                runs: on,
                why: why(format!("{levels} clipmap levels of {per_axis}^3 probes around the camera; lists the ones {reader} read, never-traced first, then the stalest")),
            },
            PassInfo {
                name: PASSES[1].0,
                runs: on && s.probes_per_frame > 0,
                why: why(format!("{} listed probes per frame, 256 {tracing} rays each (16x16 cells), lit from the surface cache, mean of the last {} updates", s.probes_per_frame, s.history)),
            },
        ]
    }

    /// Writes this frame's uniforms, then records `world select` and `world update` (when
    /// `update`) through `lumen`, the holder's group 2. Readers later in the frame see the
    /// same uniforms.
    #[allow(clippy::too_many_arguments)]
    pub fn record(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
        lumen: &wgpu::BindGroup,
        pipes: &WorldCachePipelines,
        s: &WorldCacheSettings,
        update: bool,
    ) {
        self.prepare(ctx, s);
        if !update {
            return;
        }
        let groups = [lumen, &self.bind_group];
        pipelines::technique_pass(
            ctx,
            enc,
            timer,
            PASSES[0].0,
            &pipes.select,
            &groups,
            [1, 1, 1],
        );
        if s.probes_per_frame > 0 {
            pipelines::technique_pass(
                ctx,
                enc,
                timer,
                PASSES[1].0,
                &pipes.update,
                &groups,
                [s.probes_per_frame.min(MAX_WORKGROUPS), 1, 1],
            );
        }
    }
}
