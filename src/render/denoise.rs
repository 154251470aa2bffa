//! The shared denoiser: an SVGF-style post pass (Schied et al. 2017, "Spatiotemporal
//! Variance-Guided Filtering") any technique can enable (`denoise = true` on a preset's
//! technique entry, `Engine::set_denoise`). It runs after the technique inside the same frame,
//! so its GPU time counts in the technique's frame time, and writes the denoised radiance into
//! the engine's output, which every consumer (readback, converge's copies, the viewer) reads.
//!
//! Its G-buffer is the engine's shared primary surfaces (`render::primary`), which the engine
//! runs whenever the denoiser is on. Passes (shaders/denoise/):
//! 1. `temporal.wgsl`: the technique's new samples of this frame, less the emission seen
//!    directly, demodulated by the albedo; blended with last frame's history reprojected with
//!    consistency tests (normal, depth, material): moving average with alpha = 0.2 (1/n while
//!    n is small) of colour and of the luminance moments m1, m2.
//! 2. `variance.wgsl`: var = m2 - m1^2, from a 7x7 bilateral window where the history is
//!    shorter than 4 frames.
//! 3. `atrous.wgsl`, five times (steps 1, 2, 4, 8, 16): 5x5 B3-spline à-trous with the paper's
//!    depth, normal and luminance edge-stopping weights; the first iteration's output is fed
//!    back as colour history; the last remodulates into the output.
//!
//! Where it departs from the paper (details in the shaders' comments):
//! - Where the technique keeps accumulating its own average (a still camera; its sample count
//!   grows) the history is the plain average of all its samples, not a 0.2 moving average,
//!   and the variance that steers the filter shrinks with it; from 16 samples of its own on,
//!   the output is clamped per channel to within one standard error of the technique's
//!   average (its Welford M2). So a converging technique converges denoised too.
//! - The spatial variance estimate of short histories is boosted by 4/n, as the authors'
//!   Falcor implementation does.
//! - The emission taken out before demodulating is at most what the pixel's samples hold
//!   (several samples a frame: only the first shares the G-buffer's jitter).
//! - Depth is the distance along the pixel's ray, the depth consistency test a plane
//!   distance; the object test compares materials.
//!
//! The technique's own output before denoising is kept (`noisy`) and put back before the
//! technique renders the next frame, so a technique that accumulates across frames averages
//! its own samples, never the denoised image. The per-pixel variance the engine reports
//! (`Engine::read_variance`, from the technique's Welford M2) stays the technique's own.

use super::{pipelines, PassInfo};
use crate::gpu::{shaders::ShaderLibrary, timing::PassTimer, Gpu};
use anyhow::Result;

/// Entry files under `shaders/`, in the order the passes run.
pub const TEMPORAL_ENTRY: &str = "denoise/temporal.wgsl";
pub const VARIANCE_ENTRY: &str = "denoise/variance.wgsl";
pub const ATROUS_ENTRY: &str = "denoise/atrous.wgsl";

/// Pass names in timings and pass lists.
pub const PASS_TEMPORAL: &str = "denoise temporal";
pub const PASS_VARIANCE: &str = "denoise variance";
pub const PASS_ATROUS: [&str; 5] = [
    "denoise atrous 1",
    "denoise atrous 2",
    "denoise atrous 4",
    "denoise atrous 8",
    "denoise atrous 16",
];
/// Tap spacing of each à-trous iteration, in pixels.
pub const ATROUS_STEPS: [u32; 5] = [1, 2, 4, 8, 16];

/// Every pass the denoiser records, in order.
pub fn pass_names() -> Vec<&'static str> {
    let mut v = vec![PASS_TEMPORAL, PASS_VARIANCE];
    v.extend(PASS_ATROUS);
    v
}

/// `Remod` of shaders/denoise/svgf.wgsl: albedo and emission, a vec4 each.
pub const REMOD_BYTES: u64 = 32;
const VEC4_BYTES: u64 = 16;

struct Pipelines {
    temporal: wgpu::ComputePipeline,
    variance: wgpu::ComputePipeline,
    atrous: wgpu::ComputePipeline,
}

pub struct Denoiser {
    extent: [u32; 2],
    layout: wgpu::BindGroupLayout,
    bind_group: wgpu::BindGroup,
    /// The technique's output (mean, w: samples) after its own render, before denoising.
    noisy: wgpu::Buffer,
    /// Two segments by frame parity: demodulated illumination and history length.
    hist_colour: wgpu::Buffer,
    /// Two segments by frame parity: luminance moments, accumulation flag.
    hist_moments: wgpu::Buffer,
    /// Per pixel: remodulation albedo and emission.
    remod: wgpu::Buffer,
    /// Per pixel: normal, depth, depth gradient.
    guide: wgpu::Buffer,
    /// Two segments, à-trous ping-pong: illumination and variance.
    illum_var: wgpu::Buffer,
    /// One `AtrousStep` per iteration, `stride` bytes apart (dynamic offsets).
    steps: wgpu::Buffer,
    stride: u32,
    pipelines: Pipelines,
}

impl Denoiser {
    /// Buffers and pipelines for an image of `extent`; `frame_layout` is the engine's group 1.
    pub fn new(
        gpu: &Gpu,
        shaders: &ShaderLibrary,
        frame_layout: &wgpu::BindGroupLayout,
        extent: [u32; 2],
    ) -> Result<Denoiser> {
        let layout = pipelines::layout(
            gpu,
            "denoise",
            &[
                pipelines::storage_entry(0, false),
                pipelines::storage_entry(1, false),
                pipelines::storage_entry(2, false),
                pipelines::storage_entry(3, false),
                pipelines::storage_entry(4, false),
                pipelines::storage_entry(5, false),
                wgpu::BindGroupLayoutEntry {
                    binding: 6,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: true,
                        min_binding_size: wgpu::BufferSize::new(16),
                    },
                    count: None,
                },
            ],
        );
        let pipelines = build_pipelines(gpu, shaders, &layout, frame_layout)?;
        let pixels = extent[0] as u64 * extent[1] as u64;
        let noisy = pipelines::storage_buffer(gpu, "denoise noisy", pixels * VEC4_BYTES);
        let hist_colour =
            pipelines::storage_buffer(gpu, "denoise history colour", 2 * pixels * VEC4_BYTES);
        let hist_moments =
            pipelines::storage_buffer(gpu, "denoise history moments", 2 * pixels * VEC4_BYTES);
        let remod = pipelines::storage_buffer(gpu, "denoise remodulation", pixels * REMOD_BYTES);
        let guide = pipelines::storage_buffer(gpu, "denoise guide", pixels * VEC4_BYTES);
        let illum_var =
            pipelines::storage_buffer(gpu, "denoise illumination", 2 * pixels * VEC4_BYTES);
        let stride = gpu
            .device
            .limits()
            .min_uniform_buffer_offset_alignment
            .max(16);
        let mut bytes = vec![0u8; stride as usize * ATROUS_STEPS.len()];
        for (i, step) in ATROUS_STEPS.iter().enumerate() {
            let last = (i + 1 == ATROUS_STEPS.len()) as u32;
            let words = [*step, i as u32, last, 0];
            let at = i * stride as usize;
            bytes[at..at + 16].copy_from_slice(bytemuck::cast_slice(&words));
        }
        let steps = wgpu::util::DeviceExt::create_buffer_init(
            &gpu.device,
            &wgpu::util::BufferInitDescriptor {
                label: Some("denoise atrous steps"),
                contents: &bytes,
                usage: wgpu::BufferUsages::UNIFORM,
            },
        );
        let mut entries: Vec<wgpu::BindGroupEntry> = [
            &noisy,
            &hist_colour,
            &hist_moments,
            &remod,
            &guide,
            &illum_var,
        ]
        .iter()
        .enumerate()
        .map(|(i, b)| wgpu::BindGroupEntry {
            binding: i as u32,
            resource: b.as_entire_binding(),
        })
        .collect();
        entries.push(wgpu::BindGroupEntry {
            binding: 6,
            resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                buffer: &steps,
                offset: 0,
                size: wgpu::BufferSize::new(16),
            }),
        });
        let bind_group = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("denoise"),
            layout: &layout,
            entries: &entries,
        });
        let d = Denoiser {
            extent,
            layout,
            bind_group,
            noisy,
            hist_colour,
            hist_moments,
            remod,
            guide,
            illum_var,
            steps,
            stride,
            pipelines,
        };
        d.reset(gpu);
        Ok(d)
    }

    /// Compiles the passes again (hot reload); on error the previous pipelines stay.
    pub fn rebuild(
        &mut self,
        gpu: &Gpu,
        shaders: &ShaderLibrary,
        frame_layout: &wgpu::BindGroupLayout,
    ) -> Result<()> {
        self.pipelines = build_pipelines(gpu, shaders, &self.layout, frame_layout)?;
        Ok(())
    }

    /// Forgets all history (the engine's reset): the next frame is filtered from itself.
    pub fn reset(&self, gpu: &Gpu) {
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        for b in [
            &self.noisy,
            &self.hist_colour,
            &self.hist_moments,
            &self.remod,
            &self.guide,
            &self.illum_var,
        ] {
            enc.clear_buffer(b, 0, None);
        }
        gpu.submit("denoiser history clear", enc.finish());
    }

    /// The technique's accumulation restarted (the engine cleared its output): forget the
    /// kept noisy output too, so it is not put back. History stays (reprojected next frame).
    pub fn restart_accumulation(&self, enc: &mut wgpu::CommandEncoder) {
        enc.clear_buffer(&self.noisy, 0, None);
    }

    /// Before the technique renders: its own output of last frame back into `output`.
    pub fn restore_noisy(&self, enc: &mut wgpu::CommandEncoder, output: &wgpu::Buffer) {
        enc.copy_buffer_to_buffer(&self.noisy, 0, output, 0, self.noisy.size());
    }

    /// After the technique rendered into `output` (the engine's accum_mean, also bound in the
    /// frame bind group): keeps it as the noisy output and writes the denoised radiance there.
    pub fn record(
        &self,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
        frame_bind_group: &wgpu::BindGroup,
        output: &wgpu::Buffer,
    ) {
        let groups = [self.extent[0].div_ceil(8), self.extent[1].div_ceil(8)];
        let mut pass = |enc: &mut wgpu::CommandEncoder,
                        name: &'static str,
                        pipeline: &wgpu::ComputePipeline,
                        offset: u32| {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some(name),
                timestamp_writes: timer.compute_pass(name),
            });
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, &self.bind_group, &[offset]);
            pass.set_bind_group(1, frame_bind_group, &[]);
            pass.dispatch_workgroups(groups[0], groups[1], 1);
        };
        // The temporal pass reads the technique's output now and as it was (`noisy`) to
        // recover this frame's samples; then the output becomes the kept noisy output.
        pass(enc, PASS_TEMPORAL, &self.pipelines.temporal, 0);
        enc.copy_buffer_to_buffer(output, 0, &self.noisy, 0, self.noisy.size());
        pass(enc, PASS_VARIANCE, &self.pipelines.variance, 0);
        for (i, name) in PASS_ATROUS.iter().enumerate() {
            pass(enc, name, &self.pipelines.atrous, i as u32 * self.stride);
        }
    }

    /// The passes, for `Engine::passes`.
    pub fn passes(&self) -> Vec<PassInfo> {
        let mut v = vec![
            PassInfo {
                name: PASS_TEMPORAL,
                runs: true,
                why: "denoiser: demodulate, reproject and accumulate colour and moments".into(),
            },
            PassInfo {
                name: PASS_VARIANCE,
                runs: true,
                why: "denoiser: variance from moments (7x7 spatial where history < 4)".into(),
            },
        ];
        for (name, step) in PASS_ATROUS.iter().zip(ATROUS_STEPS) {
            v.push(PassInfo {
                name,
                runs: true,
                why: format!("denoiser: edge-stopping à-trous, step {step}"),
            });
        }
        v
    }

    /// The technique's own output of the last frame, before denoising (mean, w: samples).
    pub fn noisy_buffer(&self) -> &wgpu::Buffer {
        &self.noisy
    }

    /// The image size its buffers are for.
    pub fn extent(&self) -> [u32; 2] {
        self.extent
    }

    /// Bytes of GPU memory the denoiser holds.
    pub fn memory_bytes(&self) -> u64 {
        [
            &self.noisy,
            &self.hist_colour,
            &self.hist_moments,
            &self.remod,
            &self.guide,
            &self.illum_var,
            &self.steps,
        ]
        .iter()
        .map(|b| b.size())
        .sum()
    }
}

fn build_pipelines(
    gpu: &Gpu,
    shaders: &ShaderLibrary,
    layout: &wgpu::BindGroupLayout,
    frame_layout: &wgpu::BindGroupLayout,
) -> Result<Pipelines> {
    let make =
        |entry: &str| pipelines::compute_pipeline(gpu, shaders, entry, &[layout, frame_layout]);
    Ok(Pipelines {
        temporal: make(TEMPORAL_ENTRY)?,
        variance: make(VARIANCE_ENTRY)?,
        atrous: make(ATROUS_ENTRY)?,
    })
}
