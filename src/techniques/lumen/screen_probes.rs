//! Lumen's final gather, part 2 (shared/seeds/000, "Screen Space Radiance Caching"): screen
//! probes with product importance sampling, screen traces through last frame's hierarchical Z,
//! rays past a probe's TMin read the world radiance cache (`crate::parts::world_cache`, whose
//! bindings share this group), probe-space filtering and full-resolution integration. Bind group
//! 3 of shaders/lumen/probes.wgsl; the passes are recorded by `ScreenProbes::record`.

use super::params::LumenSettings;
use crate::gpu::{readback, timing::PassTimer, Gpu};
use crate::parts::world_cache::{self, WorldCache};
use crate::render::{pipelines, RenderContext};
use anyhow::Result;

/// The passes of the final gather, in the order they run (timer name, file); the world cache's
/// own passes run before them.
pub const PASSES: [(&str, &str); 10] = [
    ("hzb", "lumen/hzb_build.wgsl"),
    ("hzb top", "lumen/hzb_top.wgsl"),
    ("probe place", "lumen/probe_place.wgsl"),
    ("probe adaptive", "lumen/probe_adaptive.wgsl"),
    ("probe sample", "lumen/probe_sample.wgsl"),
    ("screen trace", "lumen/screen_trace.wgsl"),
    ("world args", "lumen/world_args.wgsl"),
    ("world trace", "lumen/world_trace.wgsl"),
    ("probe resolve", "lumen/probe_resolve.wgsl"),
    ("probe filter", "lumen/probe_filter.wgsl"),
];
pub const INTEGRATE: (&str, &str) = ("integrate", "lumen/integrate.wgsl");

const PROBE_CELLS: u64 = 64;
const HEADER_WORDS: u32 = 16;
const MAX_WORKGROUPS: u32 = 65_535;
/// Floors of the temporal blends: probes keep about 4 frames (the seed's), pixels about 10.
const PROBE_TEMPORAL_WEIGHT: f32 = 0.25;
const PIXEL_TEMPORAL_WEIGHT: f32 = 0.1;
/// How far behind last frame's depth a screen-trace ray may enter a pixel and still hit it (2%):
/// a pixel's depth is flat, so a surface coming towards the ray stair-steps in front of it and
/// the ray "enters behind" a pixel it is really hitting. At 0 the traces resolved 8% of Cornell's
/// probe rays.
const SCREEN_THICKNESS: f32 = 0.02;

pub const PROBES_PRODUCT: u32 = 1;
pub const PROBES_SCREEN_TRACES: u32 = 2;
pub const PROBES_WORLD_CACHE: u32 = 4;
pub const PROBES_ADAPTIVE: u32 = 8;
pub const PROBES_SPATIAL: u32 = 16;
pub const PROBES_TEMPORAL: u32 = 32;
pub const PROBES_CONTACT_AO: u32 = 64;
pub const PROBES_ACTIVE: u32 = 128;
pub const PROBES_REASSIGN: u32 = 256;

/// `ProbeParams` of shaders/lumen/probes.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ProbeParamsGpu {
    pub hzb_mips: [[u32; 4]; 16],
    pub grid: [u32; 4],
    pub adaptive: [u32; 4],
    pub jitter: [u32; 4],
    pub counts: [u32; 4],
    pub offsets: [u32; 4],
    pub offsets_b: [u32; 4],
    pub misc: [f32; 4],
    pub flags: [u32; 4],
}

/// Screen-probe statistics since the last history reset (tests, README).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ProbeStats {
    pub uniform_probes: u32,
    pub probes_this_frame: u32,
    pub screen_hits: u64,
    pub world_rays: u64,
    pub adaptive_probes: u64,
    pub world_cache_reads: u64,
}

/// Sizes that follow from the image and the settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Sizes {
    tiles: [u32; 2],
    cells: [u32; 2],
    max_probes: u32,
    hzb_levels: u32,
}

/// The final gather's pipelines (groups: scene, frame, lumen, probes), in `PASSES` order.
pub struct ProbePipelines {
    passes: Vec<wgpu::ComputePipeline>,
    integrate: wgpu::ComputePipeline,
}

impl ProbePipelines {
    /// Every pipeline or an error (nothing half-built).
    pub fn build(
        ctx: &RenderContext,
        lumen: &wgpu::BindGroupLayout,
        probes: &wgpu::BindGroupLayout,
    ) -> Result<ProbePipelines> {
        let layouts = [&ctx.scene.layout, ctx.frame_layout, lumen, probes];
        let mut passes = Vec::new();
        for (_, file) in PASSES {
            passes.push(pipelines::compute_pipeline(
                ctx.gpu,
                ctx.shaders,
                file,
                &layouts,
            )?);
        }
        let integrate = pipelines::compute_pipeline(ctx.gpu, ctx.shaders, INTEGRATE.1, &layouts)?;
        Ok(ProbePipelines { passes, integrate })
    }
}

pub struct ScreenProbes {
    params_buffer: wgpu::Buffer,
    state: wgpu::Buffer,
    args: wgpu::Buffer,
    buffers: Vec<wgpu::Buffer>,
    pub bind_group: wgpu::BindGroup,
    gpu_params: ProbeParamsGpu,
    sizes: Sizes,
    frame: u32,
    history: bool,
}

fn r2_jitter(frame: u32, spacing: u32) -> [u32; 2] {
    // The R2 sequence (plastic-number Kronecker): even coverage of the tile over frames.
    let f = frame as f64;
    let x = (0.5 + f * 0.754_877_666_246_692_8).fract();
    let y = (0.5 + f * 0.569_840_290_998_053_3).fract();
    [
        ((x * spacing as f64) as u32).min(spacing - 1),
        ((y * spacing as f64) as u32).min(spacing - 1),
    ]
}

impl ScreenProbes {
    /// Bindings 0..=3 and the world cache's lookup (24, 26).
    pub fn layout(gpu: &Gpu) -> wgpu::BindGroupLayout {
        let mut entries = vec![pipelines::uniform_entry(0, wgpu::ShaderStages::COMPUTE)];
        for b in 1..=3 {
            entries.push(pipelines::storage_entry(b, false));
        }
        entries.extend(world_cache::lookup_entries());
        pipelines::layout(gpu, "lumen probes", &entries)
    }

    /// GPU resources for an image of `extent` with `s`, bound beside `world`'s; errors where a
    /// buffer would exceed the device's binding limit or a dispatch its workgroup limit.
    pub fn new(
        ctx: &RenderContext,
        layout: &wgpu::BindGroupLayout,
        s: &LumenSettings,
        world: &WorldCache,
    ) -> Result<ScreenProbes> {
        let gpu = ctx.gpu;
        let [w, h] = ctx.extent;
        let spacing = s.probe_spacing;
        let tiles = [w.div_ceil(spacing), h.div_ceil(spacing)];
        let uniform = tiles[0] * tiles[1];
        anyhow::ensure!(
            uniform <= MAX_WORKGROUPS,
            "lumen: {uniform} screen probes at probe_spacing = {spacing} exceed one dispatch's {MAX_WORKGROUPS} workgroups; use a larger spacing"
        );
        let max_probes = (2 * uniform).min(MAX_WORKGROUPS);
        let cell = (spacing / 2).max(1);
        let cells = [w.div_ceil(cell), h.div_ceil(cell)];
        let mut hzb_mips = [[0u32; 4]; 16];
        let mut offset = HEADER_WORDS;
        let mut hzb_levels = 0;
        let (mut mw, mut mh) = (w, h);
        loop {
            hzb_mips[hzb_levels as usize] = [offset, mw, mh, 0];
            offset += mw * mh;
            hzb_levels += 1;
            if (mw == 1 && mh == 1) || hzb_levels == 16 {
                break;
            }
            mw = mw.div_ceil(2);
            mh = mh.div_ceil(2);
        }
        let adaptive_offset = offset;
        let list_offset = adaptive_offset + cells[0] * cells[1];
        let state_words = list_offset as u64 + max_probes as u64 * PROBE_CELLS;
        let mp = max_probes as u64;
        let rays_offset = 8 * mp;
        let cache_offset = rays_offset + 2 * mp * PROBE_CELLS;
        let filtered_offset = cache_offset + 2 * mp * PROBE_CELLS;
        let probe_vec4s = filtered_offset + mp * PROBE_CELLS;
        let pixels = w as u64 * h as u64;
        let limit = gpu.device.limits().max_storage_buffer_binding_size;
        for (what, bytes) in [
            ("screen probe data", probe_vec4s * 16),
            ("pixel history", 4 * pixels * 16),
            ("probe state", state_words * 4),
        ] {
            anyhow::ensure!(
                bytes <= limit,
                "lumen: the {what} needs {} MiB, over this device's {} MiB binding limit (a larger probe_spacing)",
                bytes >> 20,
                limit >> 20
            );
        }
        let storage = wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_DST
            | wgpu::BufferUsages::COPY_SRC;
        let state = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("lumen probe state"),
            size: state_words * 4,
            usage: storage,
            mapped_at_creation: false,
        });
        // The world trace's dispatch, copied out of the state (a buffer cannot be storage and
        // indirect arguments in one dispatch).
        let args = pipelines::indirect_args_buffer(gpu, "lumen world trace args", 1);
        let params_buffer = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("lumen probe params"),
            size: std::mem::size_of::<ProbeParamsGpu>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let buffers = vec![
            pipelines::storage_buffer(gpu, "lumen probe data", probe_vec4s * 16),
            pipelines::storage_buffer(gpu, "lumen pixel history", 4 * pixels * 16),
        ];
        let mut entries: Vec<wgpu::BindGroupEntry> =
            [&params_buffer, &state, &buffers[0], &buffers[1]]
                .into_iter()
                .enumerate()
                .map(|(i, b)| wgpu::BindGroupEntry {
                    binding: i as u32,
                    resource: b.as_entire_binding(),
                })
                .collect();
        entries.extend(world.entries());
        let bind_group = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("lumen probes"),
            layout,
            entries: &entries,
        });
        let gpu_params = ProbeParamsGpu {
            hzb_mips,
            grid: [tiles[0], tiles[1], spacing, max_probes],
            adaptive: [cells[0], cells[1], cell, uniform],
            counts: [hzb_levels, s.screen_trace_steps, 0, 0],
            offsets: [
                adaptive_offset,
                list_offset,
                rays_offset as u32,
                cache_offset as u32,
            ],
            offsets_b: [filtered_offset as u32, 2 * pixels as u32, 0, 0],
            misc: [
                s.world_cache_distance,
                SCREEN_THICKNESS,
                PROBE_TEMPORAL_WEIGHT,
                PIXEL_TEMPORAL_WEIGHT,
            ],
            ..Default::default()
        };
        let mut probes = ScreenProbes {
            params_buffer,
            state,
            args,
            buffers,
            bind_group,
            gpu_params,
            sizes: Sizes {
                tiles,
                cells,
                max_probes,
                hzb_levels,
            },
            frame: 0,
            history: false,
        };
        probes.reset(gpu);
        Ok(probes)
    }

    /// Forgets every probe and the pixel history.
    pub fn reset(&mut self, gpu: &Gpu) {
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        enc.clear_buffer(&self.state, 0, None);
        enc.clear_buffer(&self.buffers[0], 0, None);
        enc.clear_buffer(&self.buffers[1], 0, None);
        gpu.submit("lumen: screen probe reset", enc.finish());
        self.history = false;
    }

    pub fn uniform_probes(&self) -> u32 {
        self.sizes.tiles[0] * self.sizes.tiles[1]
    }

    /// Probe rays per pixel per frame of the uniform probes alone.
    pub fn rays_per_pixel(spacing: u32) -> f64 {
        PROBE_CELLS as f64 / (spacing as f64 * spacing as f64)
    }

    fn flags(s: &LumenSettings) -> u32 {
        let mut flags = PROBES_ACTIVE;
        for (on, flag) in [
            (s.product_sampling, PROBES_PRODUCT),
            (s.ray_reassignment, PROBES_REASSIGN),
            (s.screen_traces, PROBES_SCREEN_TRACES),
            (s.world_cache, PROBES_WORLD_CACHE),
            (s.adaptive_probes, PROBES_ADAPTIVE),
            (s.spatial_filter, PROBES_SPATIAL),
            (s.temporal_filter, PROBES_TEMPORAL),
            (s.contact_ao, PROBES_CONTACT_AO),
        ] {
            if on {
                flags |= flag;
            }
        }
        flags
    }

    /// Per-frame uniforms: jitter, parity.
    fn prepare(&mut self, ctx: &RenderContext, s: &LumenSettings) {
        let spacing = s.probe_spacing;
        let jitter = r2_jitter(self.frame, spacing);
        let prev = r2_jitter(self.frame.wrapping_sub(1), spacing);
        let p = &mut self.gpu_params;
        p.jitter = [jitter[0], jitter[1], prev[0], prev[1]];
        p.flags = [Self::flags(s), self.history as u32, self.frame & 1, 0];
        p.counts[1] = s.screen_trace_steps;
        p.misc[0] = s.world_cache_distance;
        ctx.gpu
            .queue
            .write_buffer(&self.params_buffer, 0, bytemuck::bytes_of(&self.gpu_params));
    }

    /// Records the final gather; `integrate` leaves per-pixel irradiance for `apply`.
    pub fn record(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
        lumen: &wgpu::BindGroup,
        s: &LumenSettings,
        pipes: &ProbePipelines,
    ) {
        self.prepare(ctx, s);
        let groups = [lumen, &self.bind_group];
        let z = self.sizes;
        let [w, h] = ctx.extent;
        let probes = [z.max_probes, 1, 1];
        for (i, (name, _)) in PASSES.iter().enumerate() {
            let workgroups = match *name {
                "hzb" | "hzb top" if !(s.screen_traces && self.history) => continue,
                "hzb top" if z.hzb_levels <= 5 => continue,
                "world args" | "hzb top" => [1, 1, 1],
                "hzb" => [w.div_ceil(16), h.div_ceil(16), 1],
                "probe place" => [z.tiles[0].div_ceil(8), z.tiles[1].div_ceil(8), 1],
                "probe adaptive" => [z.cells[0].div_ceil(8), z.cells[1].div_ceil(8), 1],
                "world trace" => {
                    enc.copy_buffer_to_buffer(&self.state, 16, &self.args, 0, 12);
                    pipelines::list_pass(
                        enc,
                        timer,
                        name,
                        &pipes.passes[i],
                        &[
                            &ctx.scene.bind_group,
                            ctx.frame_bind_group,
                            lumen,
                            &self.bind_group,
                        ],
                        &self.args,
                        0,
                    );
                    continue;
                }
                _ => probes,
            };
            pipelines::technique_pass(ctx, enc, timer, name, &pipes.passes[i], &groups, workgroups);
        }
        pipelines::technique_pass(
            ctx,
            enc,
            timer,
            INTEGRATE.0,
            &pipes.integrate,
            &groups,
            [w.div_ceil(8), h.div_ceil(8), 1],
        );
        self.frame = self.frame.wrapping_add(1);
        self.history = true;
    }

    /// Counters since the last reset (waits for the GPU).
    pub fn stats(&self, gpu: &Gpu) -> Result<ProbeStats> {
        let words: Vec<u32> = readback::read_buffer(gpu, &self.state, HEADER_WORDS as usize)?;
        Ok(ProbeStats {
            uniform_probes: self.uniform_probes(),
            probes_this_frame: words[0].min(self.sizes.max_probes),
            screen_hits: words[8] as u64,
            world_rays: words[9] as u64,
            adaptive_probes: words[10] as u64,
            world_cache_reads: words[11] as u64,
        })
    }
}
