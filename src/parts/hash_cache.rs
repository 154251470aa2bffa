//! A spatially hashed world-space radiance cache, as a part (issue 61): NVIDIA's SHaRC (RTXGI
//! 2.x, its public integration guide), Bevy Solari's world cache, id Tech 8's "compact
//! spatial-hash radiance cache". Written from the published descriptions, no SDK code.
//!
//! - **Cells** are keyed by the quantised position, the axis the surface faces (6 sides) and a
//!   level that grows by one each time the distance to the camera doubles (a cell is about
//!   1 / `cells_per_distance` of its distance, at least `cell_size`). A 32-bit hash picks the
//!   slot, linear probing over 8 slots, a 32-bit checksum of the hash is the stored key.
//! - **Update** (`hash update`): one full path a frame from a random pixel of each
//!   `block` × `block` block (SHaRC's 5 × 5), from its primary surface; each of its first six
//!   vertices adds a sample of the light it reflects, over its albedo, to its cell (fixed-point
//!   32-bit atomics, stochastic rounding: lavapipe and every backend run it).
//! - **Resolve** (`hash resolve`): each cell's samples of the frame join its average, whose
//!   history is capped at `history` samples; a cell without samples for `stale_frames` frames is
//!   evicted. Lookups probe a key's whole run, so eviction needs no compaction (see the
//!   shader).
//! - **Lookup** (`gilab::hash_cache::hash_lookup`, at the bind group a pass names with
//!   `HASH_CACHE_GROUP`): the cell's light over albedo; a reader multiplies by its own albedo.
//!
//! Readers: the `hash-cache` technique (a path tracer whose paths end in the cache, as RTXGI 2
//! ships it) and ReSTIR GI (`gi_terminate = "hash-cache"`). Rays are counted as `cache`
//! (update path segments) and `shadow` (their NEE). Docs: docs/hash-cache.md.

use crate::gpu::{timing::PassTimer, Gpu};
use crate::render::{pipelines, PassInfo, RenderContext};
use crate::scene::features::SceneFeatures;
use anyhow::Result;

/// The cache's sizes and rates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HashCacheSettings {
    /// log2 of the slots in the table.
    pub capacity_log2: u32,
    /// A cell's size as a fraction of its distance to the camera (inverse).
    pub cells_per_distance: f32,
    /// Samples a cell's average keeps at most.
    pub history: u32,
    /// Frames without a sample before a cell is evicted.
    pub stale_frames: u32,
    /// One update path per `block` × `block` pixels a frame.
    pub block: u32,
    /// The update paths pick NEE lights by the light tree (`LIGHT_TREE`, parts::light_tree)
    /// rather than by power.
    pub light_tree: bool,
}

impl Default for HashCacheSettings {
    fn default() -> Self {
        HashCacheSettings {
            capacity_log2: 20,
            cells_per_distance: 32.0,
            history: 256,
            stale_frames: 32,
            block: 5,
            light_tree: false,
        }
    }
}

impl HashCacheSettings {
    pub fn capacity(&self) -> u32 {
        1 << self.capacity_log2
    }

    /// Bytes of its buffers: six words a slot (key, four sums, age) and a vec4 cell.
    pub fn memory_bytes(&self) -> u64 {
        self.capacity() as u64 * (6 * 4 + 16)
    }
}

/// Matches `HashCacheParams` in shaders/parts/hash_cache/shared.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct HashCacheParamsGpu {
    pub capacity: u32,
    pub stale_frames: u32,
    pub max_samples: f32,
    pub cell_size: f32,
    pub cells_per_distance: f32,
    pub block: u32,
    pub pad: [u32; 2],
}

/// The shader def naming the lookup's bind group.
pub const GROUP_DEF: &str = "HASH_CACHE_GROUP";
/// Finest cell edge as a fraction of the scene's bounding-box diagonal.
const FINEST_CELL_OF_DIAGONAL: f32 = 1.0 / 2048.0;

/// Shader defs of a pipeline that reads the cache at bind group `group`.
pub fn lookup_defs(group: u32) -> [(&'static str, u32); 1] {
    [(GROUP_DEF, group)]
}

/// Layout of the cache's bind group: its uniform, its words and its cells (a reader binds the
/// same group its passes do).
pub fn lookup_layout(gpu: &Gpu) -> wgpu::BindGroupLayout {
    pipelines::layout(
        gpu,
        "hash cache",
        &[
            pipelines::uniform_entry(0, wgpu::ShaderStages::COMPUTE),
            pipelines::storage_entry(1, false),
            pipelines::storage_entry(2, false),
        ],
    )
}

struct Built {
    capacity: u32,
    light_tree: bool,
    update: wgpu::ComputePipeline,
    resolve: wgpu::ComputePipeline,
    params: wgpu::Buffer,
    words: wgpu::Buffer,
    cells: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
}

pub struct HashCache {
    pub settings: HashCacheSettings,
    built: Option<Built>,
    /// Finest cell edge of the scene it was built for.
    cell_size: f32,
    /// The holder's `cache_direct`, kept for its cache key only: the update paths pick lights
    /// as the reference does.
    holder_light: Option<crate::parts::world_regir::WorldRegirSettings>,
}

/// Slot statistics read back (tests, `shot --verbose`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct HashCacheStats {
    /// Slots holding a key.
    pub occupied: u32,
    /// Of those, cells with samples.
    pub with_samples: u32,
    pub capacity: u32,
    /// Mean over cells with samples of their light over albedo (mean of r, g, b), each cell
    /// weighted by its samples.
    pub mean_light: f64,
}

impl HashCache {
    pub fn new(settings: HashCacheSettings) -> HashCache {
        HashCache {
            settings,
            built: None,
            cell_size: 0.0,
            holder_light: None,
        }
    }

    /// Builds its pipelines and buffers, empty (on error the previous ones stay).
    pub fn build(&mut self, ctx: &RenderContext) -> Result<()> {
        let gpu = ctx.gpu;
        let layout = lookup_layout(gpu);
        let shaders = ctx.shaders.with_defs(&lookup_defs(2));
        let shaders = if self.settings.light_tree {
            shaders.with_defs(&[("LIGHT_TREE", 1)])
        } else {
            shaders
        };
        let layouts = [&ctx.scene.layout, ctx.frame_layout, &layout];
        let update =
            pipelines::compute_pipeline(gpu, &shaders, "parts/hash_cache/update.wgsl", &layouts)?;
        let resolve =
            pipelines::compute_pipeline(gpu, &shaders, "parts/hash_cache/resolve.wgsl", &layouts)?;
        let capacity = self.settings.capacity() as u64;
        let largest = gpu.device.limits().max_storage_buffer_binding_size;
        if capacity * 6 * 4 > largest {
            anyhow::bail!(
                "hash cache: 2^{} slots need a {} MiB buffer, above this GPU's largest storage binding ({} MiB): lower capacity_log2",
                self.settings.capacity_log2,
                (capacity * 24) >> 20,
                largest >> 20
            );
        }
        // A table of the same size keeps its cells across a rebuild (a scripted scene edit
        // rebuilds every technique): as in a game, they catch up with the change (the lag the
        // experiments measure). Bind groups of structurally equal layouts are interchangeable.
        let kept = self
            .built
            .take()
            .filter(|b| b.capacity as u64 == capacity)
            .map(|b| (b.params, b.words, b.cells, b.bind_group));
        let fresh = kept.is_none();
        let (params, words, cells, bind_group) = match kept {
            Some(k) => k,
            None => {
                let params = gpu.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("hash cache params"),
                    size: std::mem::size_of::<HashCacheParamsGpu>() as u64,
                    usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                });
                let words = pipelines::storage_buffer(gpu, "hash cache words", capacity * 6 * 4);
                let cells = pipelines::storage_buffer(gpu, "hash cache cells", capacity * 16);
                let bind_group = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("hash cache"),
                    layout: &layout,
                    entries: &[
                        wgpu::BindGroupEntry {
                            binding: 0,
                            resource: params.as_entire_binding(),
                        },
                        wgpu::BindGroupEntry {
                            binding: 1,
                            resource: words.as_entire_binding(),
                        },
                        wgpu::BindGroupEntry {
                            binding: 2,
                            resource: cells.as_entire_binding(),
                        },
                    ],
                });
                (params, words, cells, bind_group)
            }
        };
        let (lo, hi) = ctx.scene.data.bounds();
        self.cell_size = ((hi - lo).length() * FINEST_CELL_OF_DIAGONAL).max(1e-4);
        self.built = Some(Built {
            capacity: capacity as u32,
            light_tree: self.settings.light_tree,
            update,
            resolve,
            params,
            words,
            cells,
            bind_group,
        });
        self.write_params(gpu);
        if fresh {
            self.reset(gpu);
        }
        Ok(())
    }

    pub fn is_built(&self) -> bool {
        self.built.is_some()
    }

    /// Slots of the table as built (0 before `build`).
    pub fn built_capacity(&self) -> u32 {
        self.built.as_ref().map_or(0, |b| b.capacity)
    }

    /// Whether the built update pipeline picks lights by the light tree.
    pub fn built_light_tree(&self) -> bool {
        self.built.as_ref().is_some_and(|b| b.light_tree)
    }

    fn write_params(&self, gpu: &Gpu) {
        let Some(b) = &self.built else { return };
        let s = &self.settings;
        let p = HashCacheParamsGpu {
            capacity: b.capacity,
            stale_frames: s.stale_frames,
            max_samples: s.history as f32,
            cell_size: self.cell_size,
            cells_per_distance: s.cells_per_distance,
            block: s.block.max(1),
            pad: [0; 2],
        };
        gpu.queue.write_buffer(&b.params, 0, bytemuck::bytes_of(&p));
    }

    /// New rates (history, eviction, update density, cell size) without emptying it; a new
    /// capacity takes effect at the next `build`.
    pub fn set_settings(&mut self, gpu: &Gpu, settings: HashCacheSettings) {
        self.settings = settings;
        self.write_params(gpu);
    }

    /// Empties every slot.
    pub fn reset(&self, gpu: &Gpu) {
        let Some(b) = &self.built else { return };
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        enc.clear_buffer(&b.words, 0, None);
        enc.clear_buffer(&b.cells, 0, None);
        gpu.submit("hash cache: reset", enc.finish());
    }

    /// This frame's update paths and the resolve (before the passes that read it).
    pub fn record(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
    ) {
        let Some(b) = &self.built else { return };
        let block = self.settings.block.max(1);
        let blocks = [ctx.extent[0].div_ceil(block), ctx.extent[1].div_ceil(block)];
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("hash update"),
                timestamp_writes: timer.compute_pass("hash update"),
            });
            pass.set_pipeline(&b.update);
            pass.set_bind_group(0, &ctx.scene.bind_group, &[]);
            pass.set_bind_group(1, ctx.frame_bind_group, &[]);
            pass.set_bind_group(2, &b.bind_group, &[]);
            pass.dispatch_workgroups(blocks[0].div_ceil(8), blocks[1].div_ceil(8), 1);
        }
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("hash resolve"),
            timestamp_writes: timer.compute_pass("hash resolve"),
        });
        pass.set_pipeline(&b.resolve);
        pass.set_bind_group(0, &ctx.scene.bind_group, &[]);
        pass.set_bind_group(1, ctx.frame_bind_group, &[]);
        pass.set_bind_group(2, &b.bind_group, &[]);
        // Rows of at most 1,024 workgroups: 2^24 slots would pass the 65,535 workgroups one
        // dimension may hold (resolve.wgsl's slot is row-major over them).
        let groups = b.capacity.div_ceil(64);
        let row = groups.min(1024);
        pass.dispatch_workgroups(row, groups.div_ceil(row), 1);
    }

    /// The lookup's bind group: valid until the next `build`.
    pub fn lookup(&self) -> Option<&wgpu::BindGroup> {
        self.built.as_ref().map(|b| &b.bind_group)
    }

    /// Its passes, for the holder's pass list.
    pub fn passes(&self, _f: &SceneFeatures) -> Vec<PassInfo> {
        let s = &self.settings;
        vec![
            PassInfo {
                name: "hash update",
                runs: true,
                why: format!(
                    "one path per {b}x{b} pixels from a random pixel's primary surface (NEE by {}); its first six vertices add samples to their cells",
                    if s.light_tree { "the light tree" } else { "power" },
                    b = s.block
                ),
            },
            PassInfo {
                name: "hash resolve",
                runs: true,
                why: format!(
                    "{} slots ({:.1} MiB): the frame's samples join each cell's average (history {} samples), cells unseen for {} frames evicted",
                    s.capacity(),
                    s.memory_bytes() as f64 / (1024.0 * 1024.0),
                    s.history,
                    s.stale_frames
                ),
            },
        ]
    }

    /// Slots in use and cells with samples (reads the whole table back).
    pub fn stats(&self, gpu: &Gpu) -> Result<HashCacheStats> {
        let Some(b) = &self.built else {
            return Ok(HashCacheStats::default());
        };
        let capacity = b.capacity;
        let keys: Vec<u32> = crate::gpu::readback::read_buffer(gpu, &b.words, capacity as usize)?;
        let cells: Vec<[f32; 4]> =
            crate::gpu::readback::read_buffer(gpu, &b.cells, capacity as usize)?;
        let (sum, weight) = cells
            .iter()
            .filter(|c| c[3] > 0.0)
            .fold((0.0, 0.0), |(s, w), c| {
                let l = (c[0] + c[1] + c[2]) as f64 / 3.0;
                (s + l * c[3] as f64, w + c[3] as f64)
            });
        Ok(HashCacheStats {
            occupied: keys.iter().filter(|k| **k != 0).count() as u32,
            with_samples: cells.iter().filter(|c| c[3] > 0.0).count() as u32,
            capacity,
            mean_light: if weight > 0.0 { sum / weight } else { 0.0 },
        })
    }
}

/// `gi_terminate = "hash-cache"`: the cache at its defaults.
pub const KIND: crate::parts::gi_cache::CacheKind = crate::parts::gi_cache::CacheKind {
    name: "hash-cache",
    key: |s| crate::parts::gi_cache::CacheKey {
        name: "hash-cache",
        size: 0,
        budget: 0,
        light: s.light,
    },
    new: |s| {
        let mut cache = HashCache::new(HashCacheSettings {
            light_tree: s.light.uses_tree(),
            ..HashCacheSettings::default()
        });
        cache.holder_light = Some(s.light);
        Ok(Box::new(cache))
    },
    describe: |s, hit| {
        format!(
            "in the hash radiance cache at hit {hit} where the segment is longer than the hit's cell and the cell has samples (its reflected light times the hit's albedo, no ray); traced on otherwise; update paths pick lights by {}",
            if s.light.uses_tree() { "the light tree" } else { "power" }
        )
    },
};

impl crate::parts::gi_cache::GiCache for HashCache {
    fn key(&self) -> crate::parts::gi_cache::CacheKey {
        crate::parts::gi_cache::CacheKey {
            name: "hash-cache",
            size: 0,
            budget: 0,
            light: self.holder_light.expect("made by KIND"),
        }
    }

    fn build(&mut self, ctx: &RenderContext) -> Result<()> {
        HashCache::build(self, ctx)
    }

    fn record(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
    ) {
        HashCache::record(self, ctx, enc, timer)
    }

    fn lookup(&self) -> Option<&wgpu::BindGroup> {
        HashCache::lookup(self)
    }

    fn passes(&self, f: &SceneFeatures) -> Vec<PassInfo> {
        HashCache::passes(self, f)
    }

    fn reader(&self, gpu: &Gpu, group: u32) -> (Vec<(&'static str, u32)>, wgpu::BindGroupLayout) {
        (vec![lookup_defs(group)[0]], lookup_layout(gpu))
    }

    fn path_end(&self) -> &'static str {
        "gilab::hash_cache_path_end"
    }

    fn cache_regir_coverage(&self, _gpu: &Gpu) -> Result<crate::parts::world_regir::Coverage> {
        anyhow::bail!("the hash cache picks no lights through world ReGIR")
    }
}
