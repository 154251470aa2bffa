//! The compare step on the GPU, for the viewer: tonemapped radiance and log heatmaps written as
//! sRGB RGBA8 straight into a texture egui draws (no full-image readback), heatmap ranges from a
//! GPU histogram read back a frame late, mean errors (MSE, relMSE, SMAPE) by a GPU reduction
//! read back asynchronously, and single-pixel probes for the inspector. Formulas and colour
//! maps are the CPU path's (`tonemap`, `heatmap`, `metrics`), which the CLI's files still use;
//! a test renders both and compares them.

use super::heatmap::{self, HIST_BINS};
use super::tonemap;
use super::Metrics;
use crate::gpu::{readback::StagingRead, shaders::ShaderLibrary, Gpu};
use crate::render::pipelines;
use anyhow::Result;
use wgpu::util::DeviceExt;

/// What a display pass shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DisplayKind {
    Radiance = 0,
    Variance = 1,
    Error = 2,
    Samples = 3,
    DebugValue = 4,
    DebugId = 5,
    /// Test probe: the tone curve of the red channel (after exposure) as f32 bits per pixel
    /// instead of RGBA8, so tests can compare the GPU curve with `tonemap::curve` in float.
    ToneCurve = 6,
}

impl DisplayKind {
    /// Whether the pass builds a histogram of log10 values (the heatmap range comes from it).
    pub fn has_histogram(self) -> bool {
        matches!(
            self,
            DisplayKind::Variance | DisplayKind::Error | DisplayKind::DebugValue
        )
    }
}

/// The engine buffers a display pass reads.
pub struct DisplaySource<'a> {
    pub mean: &'a wgpu::Buffer,
    pub m2: &'a wgpu::Buffer,
    pub reference: Option<&'a wgpu::Buffer>,
    pub debug: Option<&'a wgpu::Buffer>,
    pub extent: [u32; 2],
    pub samples: u32,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DisplaySettings {
    pub kind: DisplayKind,
    /// Tone curve, exposure and zone view (Radiance, ToneCurve).
    pub tonemap: tonemap::Settings,
    /// Debug channel (DebugValue, DebugId).
    pub channel: usize,
    /// log10 range of a heatmap; None: the target's last histogram range (or a default).
    pub range: Option<(f32, f32)>,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub struct DisplayParams {
    pub size: [u32; 2],
    pub mode: u32,
    pub operator: u32,
    pub exposure_scale: f32,
    pub range_lo: f32,
    pub range_hi: f32,
    pub channel: u32,
    pub samples: f32,
    pub row_words: u32,
    /// tonemap::View as u32.
    pub view: u32,
    /// GT curve: P, a, m, l, c, b.
    pub gt: [f32; 6],
    pub pad: [u32; 3],
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub struct MetricParams {
    pub pixels: u32,
    pub partial_count: u32,
    pub pad: [u32; 2],
}

/// Pipelines and constant buffers, shared by every pane and run.
pub struct GpuCompare {
    display_layout: wgpu::BindGroupLayout,
    display: wgpu::ComputePipeline,
    metrics_layout: wgpu::BindGroupLayout,
    partials: wgpu::ComputePipeline,
    total: wgpu::ComputePipeline,
    colour_map: wgpu::Buffer,
    placeholder: wgpu::Buffer,
}

/// Bytes per output row: copies into a texture need rows aligned to 256 bytes.
pub fn row_words(width: u32) -> u32 {
    width.div_ceil(64) * 64
}

/// One pane's display output: the RGBA8 rows, the texture egui draws and the histogram.
pub struct DisplayTarget {
    pub extent: [u32; 2],
    pub rgba: wgpu::Buffer,
    pub texture: wgpu::Texture,
    pub view: wgpu::TextureView,
    histogram: wgpu::Buffer,
    histogram_read: StagingRead,
    histogram_kind: Option<DisplayKind>,
    /// The range the last histogram gave (used by the next display of a heatmap).
    pub range: Option<(f32, f32)>,
    /// The range of the last display pass (what the colour bar shows).
    pub shown_range: Option<(f32, f32)>,
}

impl DisplayTarget {
    pub fn new(gpu: &Gpu, extent: [u32; 2]) -> DisplayTarget {
        let texture = gpu.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("pane display"),
            size: wgpu::Extent3d {
                width: extent[0],
                height: extent[1],
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            // egui-wgpu samples gamma-encoded Rgba8Unorm textures.
            format: wgpu::TextureFormat::Rgba8Unorm,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        DisplayTarget {
            extent,
            rgba: pipelines::storage_buffer(
                gpu,
                "pane display rgba",
                row_words(extent[0]) as u64 * extent[1] as u64 * 4,
            ),
            view: texture.create_view(&Default::default()),
            texture,
            histogram: pipelines::storage_buffer(gpu, "pane histogram", HIST_BINS as u64 * 4),
            histogram_read: StagingRead::new(gpu, "pane histogram read", HIST_BINS as u64 * 4),
            histogram_kind: None,
            range: None,
            shown_range: None,
        }
    }

    /// Picks up a histogram read back since the last call (never waits): sets `range`.
    pub fn poll_range(&mut self, gpu: &Gpu) -> Result<()> {
        if let Some(bytes) = self.histogram_read.poll(gpu, false)? {
            let counts: Vec<u32> = bytemuck::pod_collect_to_vec(&bytes);
            self.range = heatmap::range_from_histogram(&counts);
        }
        Ok(())
    }

    /// The RGBA8 pixels of the last display (blocking readback: tests and screenshots).
    pub fn read_rgba(&self, gpu: &Gpu) -> Result<Vec<u8>> {
        let [w, h] = self.extent;
        let words: Vec<u32> =
            crate::gpu::readback::read_buffer(gpu, &self.rgba, (row_words(w) * h) as usize)?;
        let mut out = Vec::with_capacity((w * h * 4) as usize);
        for y in 0..h {
            let row = &words[(y * row_words(w)) as usize..][..w as usize];
            out.extend_from_slice(bytemuck::cast_slice(row));
        }
        Ok(out)
    }
}

/// A run's mean-error reduction, read back asynchronously: results come out a frame or more
/// after the frame they score, tagged with the caller's key (the frame index).
pub struct MetricsReduction {
    partials: wgpu::Buffer,
    result: wgpu::Buffer,
    params: wgpu::Buffer,
    pixels: u32,
    reads: Vec<(StagingRead, Option<u32>)>,
}

impl MetricsReduction {
    pub fn new(gpu: &Gpu, extent: [u32; 2]) -> MetricsReduction {
        let pixels = extent[0] * extent[1];
        let partial_count = pixels.div_ceil(256);
        MetricsReduction {
            partials: pipelines::storage_buffer(gpu, "metric partials", partial_count as u64 * 16),
            result: pipelines::storage_buffer(gpu, "metric result", 16),
            params: gpu
                .device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("metric params"),
                    contents: bytemuck::bytes_of(&MetricParams {
                        pixels,
                        partial_count,
                        pad: [0; 2],
                    }),
                    usage: wgpu::BufferUsages::UNIFORM,
                }),
            pixels,
            reads: (0..4)
                .map(|_| (StagingRead::new(gpu, "metric read", 16), None))
                .collect(),
        }
    }

    /// Whether another reduction can be recorded now (a free readback slot).
    pub fn has_free_slot(&self) -> bool {
        self.reads.iter().any(|(r, k)| k.is_none() && r.is_idle())
    }

    /// Results that have arrived since the last call (never waits), as (key, metrics).
    pub fn poll(&mut self, gpu: &Gpu) -> Result<Vec<(u32, Metrics)>> {
        let mut out = Vec::new();
        let n = self.pixels as f64 * 3.0;
        for (read, key) in &mut self.reads {
            if key.is_none() {
                continue;
            }
            if let Some(bytes) = read.poll(gpu, false)? {
                let v: [f32; 4] = bytemuck::pod_read_unaligned(&bytes[..16]);
                out.push((
                    key.take().expect("checked"),
                    Metrics {
                        mse: v[0] as f64 / n,
                        rel_mse: v[1] as f64 / n,
                        smape: v[2] as f64 / n,
                    },
                ));
            }
        }
        out.sort_by_key(|(k, _)| *k);
        Ok(out)
    }
}

impl GpuCompare {
    pub fn new(gpu: &Gpu, shaders: &ShaderLibrary) -> Result<GpuCompare> {
        let display_layout = pipelines::layout(
            gpu,
            "display",
            &[
                pipelines::uniform_entry(0, wgpu::ShaderStages::COMPUTE),
                pipelines::storage_entry(1, true),
                pipelines::storage_entry(2, true),
                pipelines::storage_entry(3, true),
                pipelines::storage_entry(4, true),
                pipelines::storage_entry(5, false),
                pipelines::storage_entry(6, false),
                pipelines::storage_entry(7, true),
            ],
        );
        let display =
            pipelines::compute_pipeline(gpu, shaders, "compare/display.wgsl", &[&display_layout])?;
        let metrics_layout = pipelines::layout(
            gpu,
            "metrics",
            &[
                pipelines::uniform_entry(0, wgpu::ShaderStages::COMPUTE),
                pipelines::storage_entry(1, true),
                pipelines::storage_entry(2, true),
                pipelines::storage_entry(3, false),
                pipelines::storage_entry(4, false),
            ],
        );
        let metrics = |entry_point| {
            pipelines::compute_pipeline_at(
                gpu,
                shaders,
                "compare/metrics.wgsl",
                entry_point,
                &[&metrics_layout],
            )
        };
        let partials = metrics("partials_main")?;
        let total = metrics("total_main")?;
        let colour_map = gpu
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("viridis"),
                contents: bytemuck::cast_slice(&heatmap::colour_map_rgba8()),
                usage: wgpu::BufferUsages::STORAGE,
            });
        Ok(GpuCompare {
            display_layout,
            display,
            metrics_layout,
            partials,
            total,
            colour_map,
            placeholder: pipelines::storage_buffer(gpu, "display placeholder", 16),
        })
    }

    /// Records a display pass into `target` and the copy into its texture; when the target's
    /// histogram readback is free, also the histogram's copy for `poll_range`.
    /// Returns the log10 range used (heatmaps) and false when the pass cannot run (an error
    /// view without a reference, a debug view without data).
    pub fn record_display(
        &self,
        gpu: &Gpu,
        enc: &mut wgpu::CommandEncoder,
        src: &DisplaySource,
        settings: &DisplaySettings,
        target: &mut DisplayTarget,
    ) -> bool {
        let kind = settings.kind;
        let needs_reference = kind == DisplayKind::Error;
        let needs_debug = matches!(kind, DisplayKind::DebugValue | DisplayKind::DebugId);
        if (needs_reference && src.reference.is_none()) || (needs_debug && src.debug.is_none()) {
            return false;
        }
        if target.histogram_kind != Some(kind) {
            // A range from another view's values would be wrong for this one.
            target.range = None;
            target.histogram_kind = Some(kind);
        }
        let range = match kind {
            DisplayKind::Samples => (0.0, (src.samples.max(1) as f32).log10().max(1.0)),
            _ => settings.range.or(target.range).unwrap_or((-6.0, 0.0)),
        };
        let [w, h] = src.extent;
        let params = DisplayParams {
            size: src.extent,
            mode: kind as u32,
            operator: settings.tonemap.operator as u32,
            exposure_scale: 2f32.powf(settings.tonemap.exposure),
            range_lo: range.0,
            range_hi: range.1,
            channel: settings.channel as u32,
            samples: src.samples as f32,
            row_words: row_words(w),
            view: settings.tonemap.view.index(),
            gt: {
                let g = &settings.tonemap.gt;
                [
                    g.max_brightness,
                    g.contrast,
                    g.linear_start,
                    g.linear_length,
                    g.black_tightness,
                    g.pedestal,
                ]
            },
            pad: [0; 3],
        };
        let uniforms = gpu
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("display params"),
                contents: bytemuck::bytes_of(&params),
                usage: wgpu::BufferUsages::UNIFORM,
            });
        let bind_group = pipelines::buffers_bind_group(
            gpu,
            "display",
            &self.display_layout,
            &[
                &uniforms,
                src.mean,
                src.m2,
                src.reference.unwrap_or(&self.placeholder),
                src.debug.unwrap_or(&self.placeholder),
                &target.rgba,
                &target.histogram,
                &self.colour_map,
            ],
        );
        if kind.has_histogram() {
            enc.clear_buffer(&target.histogram, 0, None);
        }
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("display"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.display);
            pass.set_bind_group(0, &bind_group, &[]);
            pass.dispatch_workgroups(w.div_ceil(16), h.div_ceil(16), 1);
        }
        enc.copy_buffer_to_texture(
            wgpu::TexelCopyBufferInfo {
                buffer: &target.rgba,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(row_words(w) * 4),
                    rows_per_image: Some(h),
                },
            },
            target.texture.as_image_copy(),
            wgpu::Extent3d {
                width: w,
                height: h,
                depth_or_array_layers: 1,
            },
        );
        let has_range = !matches!(
            kind,
            DisplayKind::Radiance | DisplayKind::DebugId | DisplayKind::ToneCurve
        );
        target.shown_range = has_range.then_some(range);
        true
    }

    /// After the submission of a `record_display` with a histogram: starts its readback if
    /// the target's staging buffer is free (records the copy in `enc`; call before submit).
    pub fn record_histogram_copy(
        &self,
        enc: &mut wgpu::CommandEncoder,
        target: &DisplayTarget,
    ) -> bool {
        if !target.histogram_kind.is_some_and(|k| k.has_histogram())
            || !target.histogram_read.is_idle()
        {
            return false;
        }
        enc.copy_buffer_to_buffer(
            &target.histogram,
            0,
            target.histogram_read.buffer(),
            0,
            HIST_BINS as u64 * 4,
        );
        true
    }

    /// Starts the histogram readback recorded by `record_histogram_copy`.
    pub fn start_histogram_read(target: &mut DisplayTarget, submission: wgpu::SubmissionIndex) {
        target.histogram_read.start(submission);
    }

    /// Records the mean-error reduction of `image` against `reference` (both one vec4 per
    /// pixel) into a free readback slot tagged `key`; false when no slot is free (the frame
    /// goes unscored rather than waiting). Call `start_metrics_read` after the submit.
    pub fn record_metrics(
        &self,
        gpu: &Gpu,
        enc: &mut wgpu::CommandEncoder,
        image: &wgpu::Buffer,
        reference: &wgpu::Buffer,
        red: &mut MetricsReduction,
        key: u32,
    ) -> bool {
        let Some(slot) = red
            .reads
            .iter()
            .position(|(r, k)| k.is_none() && r.is_idle())
        else {
            return false;
        };
        let bind_group = pipelines::buffers_bind_group(
            gpu,
            "metrics",
            &self.metrics_layout,
            &[&red.params, image, reference, &red.partials, &red.result],
        );
        let groups = red.pixels.div_ceil(256);
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("metrics"),
                timestamp_writes: None,
            });
            pass.set_bind_group(0, &bind_group, &[]);
            pass.set_pipeline(&self.partials);
            pass.dispatch_workgroups(groups.min(65535), groups.div_ceil(65535), 1);
            pass.set_pipeline(&self.total);
            pass.dispatch_workgroups(1, 1, 1);
        }
        enc.copy_buffer_to_buffer(&red.result, 0, red.reads[slot].0.buffer(), 0, 16);
        red.reads[slot].1 = Some(key);
        true
    }

    /// Starts the readbacks recorded since the last submit.
    pub fn start_metrics_read(red: &mut MetricsReduction, submission: &wgpu::SubmissionIndex) {
        for (read, key) in &mut red.reads {
            if key.is_some() && read.is_idle() {
                read.start(submission.clone());
            }
        }
    }
}

/// A probed pixel and its values, one vec4 per buffer asked for.
pub type ProbedPixel = ((u32, u32), Vec<[f32; 4]>);

/// Reads one pixel of several buffers (one vec4 each) without waiting: the pixel inspector.
pub struct PixelProbe {
    read: StagingRead,
    pending: Option<(u32, u32)>,
    /// The last pixel read and its values, one vec4 per buffer asked for.
    pub last: Option<ProbedPixel>,
    count: usize,
}

impl PixelProbe {
    pub fn new(gpu: &Gpu, buffers: usize) -> PixelProbe {
        PixelProbe {
            read: StagingRead::new(gpu, "pixel probe", buffers as u64 * 16),
            pending: None,
            last: None,
            count: buffers,
        }
    }

    /// Records the copies of pixel `index` (row-major) of each buffer when the probe is free.
    pub fn record(
        &mut self,
        enc: &mut wgpu::CommandEncoder,
        pixel: (u32, u32),
        index: u64,
        buffers: &[&wgpu::Buffer],
    ) -> bool {
        if self.pending.is_some() || !self.read.is_idle() {
            return false;
        }
        for (k, b) in buffers.iter().take(self.count).enumerate() {
            enc.copy_buffer_to_buffer(b, index * 16, self.read.buffer(), k as u64 * 16, 16);
        }
        self.pending = Some(pixel);
        true
    }

    pub fn start(&mut self, submission: wgpu::SubmissionIndex) {
        if self.pending.is_some() && self.read.is_idle() {
            self.read.start(submission);
        }
    }

    /// Picks up the values once they arrive (never waits).
    pub fn poll(&mut self, gpu: &Gpu) -> Result<()> {
        if let Some(bytes) = self.read.poll(gpu, false)? {
            let v: Vec<[f32; 4]> = bytemuck::pod_collect_to_vec(&bytes);
            self.last = self.pending.take().map(|p| (p, v));
        }
        Ok(())
    }
}
