//! # Hash radiance cache (`hash-cache`)
//!
//! A path tracer whose paths end in a spatially hashed world-space radiance cache, as RTXGI 2
//! ships NVIDIA's SHaRC (issue 61; the cache is the part [`crate::parts::hash_cache`], which
//! ReSTIR GI's paths can end in too). Each frame: the cache's update (one full path per 5 × 5
//! pixels, each vertex a sample of its cell) and resolve, then one path per pixel from its
//! primary surface, traced as the reference traces it until its footprint at a hit is wider
//! than the hit's cell and the cell has samples: there the cell's reflected light (times the
//! hit's albedo) stands for the rest of the path. `use_cache = false` traces the same paths to
//! the end (the unbiased baseline). Shader: shaders/hash_cache/shade.wgsl. Docs:
//! docs/hash-cache.md.

use crate::gpu::{timing::PassTimer, Gpu};
use crate::parts::hash_cache::{self, HashCache, HashCacheSettings};
use crate::render::params::{ParamChanges, ParamKind, ParamSpec, Params};
use crate::render::primary::FrameInputs;
use crate::render::{pipelines, DebugView, PassInfo, RenderContext, Technique};
use crate::scene::features::SceneFeatures;
use anyhow::Result;

pub const PARAMS: &[ParamSpec] = &[
    ParamSpec {
        name: "accumulate",
        what: "average every frame since the last reset (off: each frame shows only its own paths)",
        higher: "on: converges (to the cache's answer, not the reference's)",
        lower: "off: one frame's noise, for real-time comparisons",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "use_cache",
        what: "paths end in the cache where their footprint is wider than the hit's cell and the cell has samples; off: the same paths traced to the end (unbiased, the baseline)",
        higher: "on: about one bounce's rays per pixel, biased by the cells' blur and history",
        lower: "off: every bounce traced",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "light_sampling",
        what: "how the pixels' and the update paths' NEE pick a light: `power` (one CDF over the pool) or `tree` (one descent of the light tree at the point and its normal, parts::light_tree); both unbiased",
        higher: "tree: fewer wasted shadow rays, less noise in the cells where many lights are far or facing away (many-lights)",
        lower: "power: no tree walk; as good where one or two lights dominate",
        kind: ParamKind::Choice(&["power", "tree"]),
        default: 0.0,
    },
    ParamSpec {
        name: "update_block",
        what: "one update path per update_block x update_block pixels a frame (SHaRC's 5 x 5)",
        higher: "fewer update paths: cheaper, cells converge and follow changes more slowly",
        lower: "more update paths: more rays, less noise and lag in the cells",
        kind: ParamKind::Int { min: 1, max: 32 },
        default: 5.0,
    },
    ParamSpec {
        name: "cells_per_distance",
        what: "a cell's edge is about 1 / cells_per_distance of its distance to the camera (its level grows by one each time the distance doubles), at least 1/2048 of the scene's diagonal",
        higher: "finer cells: sharper light, more cells to fill (noise, lag)",
        lower: "coarser cells: light blurred over larger areas (leaks across corners)",
        kind: ParamKind::Float {
            min: 2.0,
            max: 512.0,
        },
        default: 32.0,
    },
    ParamSpec {
        name: "history",
        what: "samples a cell's average keeps at most (older samples fade as an exponential average beyond it)",
        higher: "less noise in the cells, slower to follow a change",
        lower: "faster to follow moving lights and objects, noisier cells",
        kind: ParamKind::Int { min: 1, max: 65536 },
        default: 256.0,
    },
    ParamSpec {
        name: "stale_frames",
        what: "frames a cell is kept without a new sample before it is evicted",
        higher: "cells out of view survive longer (ready when the camera turns back)",
        lower: "the table frees slots sooner",
        kind: ParamKind::Int { min: 1, max: 4096 },
        default: 32.0,
    },
    ParamSpec {
        name: crate::techniques::DEBUG_VIEWS,
        what: "write the debug views (each pixel's cell, its samples, its level, the cache's light there)",
        higher: "on: the viewer's debug views work",
        lower: "off: no debug writes (timed runs switch it off)",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "capacity_log2",
        what: "log2 of the table's slots (2^20: 40 MiB)",
        higher: "room for more cells (large scenes, fine cells)",
        lower: "less memory; a full table drops new cells (their paths are traced on)",
        kind: ParamKind::Int { min: 10, max: 24 },
        default: 20.0,
    },
];

/// Matches `ShadeSettings` in shaders/hash_cache/shade.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ShadeSettingsGpu {
    pub accumulate: u32,
    pub use_cache: u32,
    pub debug: u32,
    pub pad: u32,
}

pub struct HashCacheTechnique {
    params: Params,
    pub cache: HashCache,
    accumulate: bool,
    use_cache: bool,
    debug: bool,
    shade: Option<wgpu::ComputePipeline>,
    /// One vec4 per pixel: the debug views' channels 0-3.
    debug_buffer: Option<wgpu::Buffer>,
    settings_buffer: Option<wgpu::Buffer>,
    settings_bind_group: Option<wgpu::BindGroup>,
}

impl Default for HashCacheTechnique {
    fn default() -> Self {
        let mut t = HashCacheTechnique {
            params: Params::new("hash-cache", PARAMS),
            cache: HashCache::new(HashCacheSettings::default()),
            accumulate: true,
            use_cache: true,
            debug: true,
            shade: None,
            debug_buffer: None,
            settings_buffer: None,
            settings_bind_group: None,
        };
        t.read_params();
        t
    }
}

impl HashCacheTechnique {
    fn read_params(&mut self) {
        let p = &self.params;
        self.accumulate = p.bool("accumulate");
        self.use_cache = p.bool("use_cache");
        self.debug = p.bool(crate::techniques::DEBUG_VIEWS);
        self.cache.settings = HashCacheSettings {
            capacity_log2: p.u32("capacity_log2"),
            cells_per_distance: p.f32("cells_per_distance"),
            history: p.u32("history"),
            stale_frames: p.u32("stale_frames"),
            block: p.u32("update_block"),
            light_tree: p.choice("light_sampling") == "tree",
        };
    }

    fn write_settings(&self, gpu: &Gpu) {
        if let Some(b) = &self.settings_buffer {
            let s = ShadeSettingsGpu {
                accumulate: self.accumulate as u32,
                use_cache: self.use_cache as u32,
                debug: self.debug as u32,
                pad: 0,
            };
            gpu.queue.write_buffer(b, 0, bytemuck::bytes_of(&s));
        }
    }
}

impl Technique for HashCacheTechnique {
    fn id(&self) -> &'static str {
        "hash-cache"
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
        let mut v = Vec::new();
        for mut p in self.cache.passes(f) {
            if !self.use_cache {
                p.runs = false;
                p.why = "use_cache = false: paths are traced to the end".into();
            }
            v.push(p);
        }
        v.push(PassInfo {
            name: "shade",
            runs: true,
            why: if self.use_cache {
                "one path per pixel (NEE, BSDF sampling), ending in the cache where its footprint is wider than the hit's cell".into()
            } else {
                "one path per pixel traced to the end (use_cache = false)".into()
            },
        });
        v
    }

    fn build(&mut self, ctx: &RenderContext) -> Result<()> {
        let gpu = ctx.gpu;
        let settings_layout = pipelines::layout(
            gpu,
            "hash-cache settings",
            &[
                pipelines::uniform_entry(0, wgpu::ShaderStages::COMPUTE),
                pipelines::storage_entry(1, false),
            ],
        );
        let cache_layout = hash_cache::lookup_layout(gpu);
        let mut defs = hash_cache::lookup_defs(2).to_vec();
        if self.cache.settings.light_tree {
            defs.push(("LIGHT_TREE", 1));
        }
        let shade = pipelines::compute_pipeline(
            gpu,
            &ctx.shaders.with_defs(&defs),
            "hash_cache/shade.wgsl",
            &[
                &ctx.scene.layout,
                ctx.frame_layout,
                &cache_layout,
                &settings_layout,
            ],
        )?;
        self.cache.build(ctx)?;
        let buffer = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("hash-cache settings"),
            size: std::mem::size_of::<ShadeSettingsGpu>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let pixels = ctx.extent[0] as u64 * ctx.extent[1] as u64;
        let debug = pipelines::storage_buffer(gpu, "hash-cache debug", pixels * 16);
        self.settings_bind_group = Some(gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("hash-cache settings"),
            layout: &settings_layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: buffer.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: debug.as_entire_binding(),
                },
            ],
        }));
        self.debug_buffer = Some(debug);
        self.settings_buffer = Some(buffer);
        self.shade = Some(shade);
        self.write_settings(gpu);
        Ok(())
    }

    /// A new capacity rebuilds the cache (empty), a new light sampling the pipelines too;
    /// other settings keep its cells.
    fn apply_params(&mut self, ctx: &RenderContext) -> Result<()> {
        let settings = self.cache.settings;
        if self.cache.is_built() && self.cache.built_light_tree() != settings.light_tree {
            return self.build(ctx);
        }
        if self.cache.is_built() {
            if self.cache_capacity_built() != settings.capacity() {
                self.cache.build(ctx)?;
            } else {
                self.cache.set_settings(ctx.gpu, settings);
            }
        }
        self.write_settings(ctx.gpu);
        Ok(())
    }

    fn reset_history(&mut self, gpu: &Gpu) {
        self.cache.reset(gpu);
    }

    /// The cells carry over a scripted change or a move, as in a game: their history has to
    /// catch up (the lag the experiments measure); stale cells are evicted.
    fn on_scene_change(&mut self, _gpu: &Gpu) {}

    fn render(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
    ) {
        if self.use_cache {
            self.cache.record(ctx, enc, timer);
        }
        let (Some(shade), Some(settings), Some(cache)) =
            (&self.shade, &self.settings_bind_group, self.cache.lookup())
        else {
            return;
        };
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("hash-cache shade"),
            timestamp_writes: timer.compute_pass("shade"),
        });
        pass.set_pipeline(shade);
        pass.set_bind_group(0, &ctx.scene.bind_group, &[]);
        pass.set_bind_group(1, ctx.frame_bind_group, &[]);
        pass.set_bind_group(2, cache, &[]);
        pass.set_bind_group(3, settings, &[]);
        pass.dispatch_workgroups(ctx.extent[0].div_ceil(8), ctx.extent[1].div_ceil(8), 1);
    }

    fn debug_views(&self) -> Vec<DebugView> {
        let view = |name, channel, is_id| DebugView {
            name,
            channel,
            is_id,
        };
        vec![
            view("cell (colour per cell)", 0, true),
            view("cell samples", 1, false),
            view("cell level (edge = cell_size x 2^level)", 2, true),
            view("cache light at the pixel (albedo x cell)", 3, false),
        ]
    }

    fn debug_buffer(&self) -> Option<&wgpu::Buffer> {
        self.debug_buffer.as_ref()
    }

    fn param_set(&self) -> &Params {
        &self.params
    }

    fn set_params(&mut self, changes: &ParamChanges) -> Result<()> {
        self.params.apply(changes)?;
        self.read_params();
        Ok(())
    }
}

impl HashCacheTechnique {
    fn cache_capacity_built(&self) -> u32 {
        self.cache.built_capacity()
    }
}
