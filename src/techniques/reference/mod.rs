//! # Reference path tracer (`reference`)
//!
//! The ground truth every other technique is measured against. Progressive and unbiased:
//! each frame adds `samples_per_frame` paths per pixel, averaged with Welford's update so the
//! mean and per-pixel variance stay accurate in float32 over many thousands of samples.
//!
//! Per path vertex: emission (MIS-weighted after non-delta bounces), next-event estimation of
//! one light picked power-proportionally from emissive triangles and punctual lights, or by the
//! light tree (`light_sampling = "tree"`, `parts::light_tree`; power heuristic against BSDF
//! sampling either way), a BSDF sample (GGX visible normals or cosine), and
//! Russian roulette from the third bounce. `max_depth` 0 means unbounded (roulette only).
//! Shader: shaders/reference/path_trace.wgsl.

use crate::compare::Image;
use crate::gpu::{readback, timing::PassTimer, Gpu};
use crate::render::params::{ParamChanges, ParamKind, ParamSpec, Params};
use crate::render::{pipelines, PassInfo, RenderContext, Technique};
use crate::scene::features::SceneFeatures;
use anyhow::Result;

pub struct ReferencePathTracer {
    params: Params,
    /// `samples_per_frame` and `max_depth` of the table, typed.
    samples_per_frame: u32,
    max_depth: u32,
    /// false: each frame shows only its own `samples_per_frame` paths (real-time experiments).
    accumulate: bool,
    /// Also average the direct-light and one-bounce images from the same paths.
    depth_images: bool,
    /// `light_sampling = "tree"`: NEE picks lights by the light tree.
    light_tree: bool,
    /// The path tracing pipeline by light sampling (power, tree), each built when first wanted.
    pipelines: [Option<wgpu::ComputePipeline>; 2],
    layout: Option<wgpu::BindGroupLayout>,
    /// With `depth_images`: per pixel the means and M2 of the two depth-limited images (four
    /// planes of vec4); 16 bytes otherwise.
    depth_accum: Option<wgpu::Buffer>,
    bind_group: Option<wgpu::BindGroup>,
    /// One 256-byte slot per sample of a frame, bound with a dynamic offset per dispatch.
    sample_slots: Option<wgpu::Buffer>,
    /// `ReferenceSettings` of path_trace.wgsl: max_depth.
    settings_buffer: Option<wgpu::Buffer>,
    extent: [u32; 2],
}

/// Most samples one frame can take (one dispatch each).
pub const MAX_SAMPLES_PER_FRAME: u32 = 64;

pub const PARAMS: &[ParamSpec] = &[
    ParamSpec {
        name: "samples_per_frame",
        what: "paths traced per pixel each frame (one dispatch each)",
        higher: "faster convergence per frame, longer frames",
        lower: "shorter frames, more frames to the same noise",
        kind: ParamKind::Int {
            min: 1,
            max: MAX_SAMPLES_PER_FRAME as i64,
        },
        default: 1.0,
    },
    ParamSpec {
        name: "max_depth",
        what: "maximum bounces; 0 = unbounded (Russian roulette only, unbiased)",
        higher: "more indirect light kept, longer paths",
        lower: "cheaper paths that lose energy (biased dark) below the scene's needs",
        kind: ParamKind::Int { min: 0, max: 1024 },
        default: 0.0,
    },
    ParamSpec {
        name: "accumulate",
        what: "average every frame since the last reset (off: each frame shows only its own samples_per_frame paths, fresh every frame: the reference at a real-time budget)",
        higher: "on: converges to the ground truth",
        lower: "off: one frame's noise, for per-frame real-time comparisons",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "depth_images",
        what: "also average, from the same paths, what max_depth 1 (direct light) and 2 (one bounce) would give: three references for the price of the unbounded one (read with ReferencePathTracer::read_depth_images; the Mitsuba comparison uses them)",
        higher: "on: two more images per pixel (64 bytes of memory per pixel)",
        lower: "off: the full image only",
        kind: ParamKind::Bool,
        default: 0.0,
    },
    ParamSpec {
        name: "light_sampling",
        what: "how next-event estimation picks a light: `power` in proportion to each light's power (one CDF over the pool); `tree` by one descent of the light tree (parts::light_tree: bounds, orientation cones and power, importance at the shading point and its normal), directional lights by their power share. Both are unbiased",
        higher: "tree: fewer wasted shadow rays where many lights are far, behind or facing away (many-lights)",
        lower: "power: no tree walk per sample; as good where one or two lights dominate",
        kind: ParamKind::Choice(&["power", "tree"]),
        default: 0.0,
    },
];
const SLOT_BYTES: u64 = 256;
/// Rays one path costs before anything is measured (camera + a few bounces with shadow rays).
const ASSUMED_RAYS_PER_PATH: f64 = 4.0;

impl Default for ReferencePathTracer {
    fn default() -> Self {
        ReferencePathTracer {
            params: Params::new("reference", PARAMS),
            samples_per_frame: 1,
            max_depth: 0,
            accumulate: true,
            depth_images: false,
            light_tree: false,
            pipelines: [None, None],
            layout: None,
            depth_accum: None,
            bind_group: None,
            sample_slots: None,
            settings_buffer: None,
            extent: [0, 0],
        }
    }
}

impl ReferencePathTracer {
    /// The path tracing pipeline, with NEE by the light tree (`LIGHT_TREE`) or by power.
    fn path_pipeline(
        ctx: &RenderContext,
        layout: &wgpu::BindGroupLayout,
        light_tree: bool,
    ) -> Result<wgpu::ComputePipeline> {
        if !light_tree {
            return ctx.pipeline("reference/path_trace.wgsl", layout);
        }
        pipelines::compute_pipeline(
            ctx.gpu,
            &ctx.shaders.with_defs(&[("LIGHT_TREE", 1)]),
            "reference/path_trace.wgsl",
            &[&ctx.scene.layout, ctx.frame_layout, layout],
        )
    }

    /// The depth planes' buffer, sized for `depth_images` (a new one starts from zero), and the
    /// bind group that holds it.
    fn bind_depth_images(&mut self, gpu: &Gpu) {
        let (Some(layout), Some(slots), Some(settings)) =
            (&self.layout, &self.sample_slots, &self.settings_buffer)
        else {
            return;
        };
        let pixels = (self.extent[0] * self.extent[1]) as u64;
        let bytes = if self.depth_images {
            4 * pixels * 16
        } else {
            16
        };
        if self.bind_group.is_some() && self.depth_accum.as_ref().map(|b| b.size()) == Some(bytes) {
            return;
        }
        let depth = pipelines::storage_buffer(gpu, "reference depth images", bytes);
        self.bind_group = Some(gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("reference"),
            layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                        buffer: slots,
                        offset: 0,
                        size: wgpu::BufferSize::new(16),
                    }),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: settings.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: depth.as_entire_binding(),
                },
            ],
        }));
        self.depth_accum = Some(depth);
    }

    /// With `depth_images`: (mean, per-pixel sample variance with the count in alpha) of what
    /// max_depth 1 (direct light) and 2 (one bounce) would have rendered, from the same paths
    /// as the full image. None when `depth_images` is off.
    pub fn read_depth_images(&self, gpu: &Gpu) -> Result<Option<[(Image, Image); 2]>> {
        let Some(buffer) = self.depth_accum.as_ref().filter(|_| self.depth_images) else {
            return Ok(None);
        };
        let [w, h] = self.extent;
        let px = (w * h) as usize;
        let all: Vec<[f32; 4]> = readback::read_buffer(gpu, buffer, 4 * px)?;
        let plane = |i: usize| {
            let mean = &all[2 * i * px..(2 * i + 1) * px];
            let m2 = &all[(2 * i + 1) * px..(2 * i + 2) * px];
            let var = crate::render::engine::sample_variance(mean, m2);
            (Image::from_rgba(w, h, mean), Image::from_rgba(w, h, &var))
        };
        Ok(Some([plane(0), plane(1)]))
    }
}

impl Technique for ReferencePathTracer {
    fn id(&self) -> &'static str {
        "reference"
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn passes(&self, f: &SceneFeatures) -> Vec<PassInfo> {
        let mut v = vec![PassInfo {
            name: "path_trace",
            runs: true,
            why: "one kernel traces camera, shadow and bounce rays".into(),
        }];
        v.push(PassInfo {
            name: "nee: emissive triangles",
            runs: f.has_emissive(),
            why: if f.has_emissive() {
                format!(
                    "{} emissive triangles in the light pool, picked {}",
                    f.emissive_triangle_count,
                    if self.light_tree {
                        "by the light tree"
                    } else {
                        "by power"
                    }
                )
            } else {
                "no emissive triangles".into()
            },
        });
        v.push(PassInfo {
            name: "nee: punctual lights",
            runs: f.has_punctual(),
            why: if f.has_punctual() {
                "punctual lights in the light pool".into()
            } else {
                "no punctual lights".into()
            },
        });
        v.push(PassInfo {
            name: "sky",
            runs: f.sky_visible,
            why: match (f.sky_visible, f.environment.is_some()) {
                (true, true) => format!(
                    "{} reachable from the camera: NEE samples it (importance by luminance)",
                    f.sky_label()
                ),
                (true, false) => "sky radiance reachable from the camera".into(),
                (false, _) => format!("{} black or enclosed", f.sky_label()),
            },
        });
        v.push(PassInfo {
            name: "gbuffer",
            runs: false,
            why: "traces its own jittered camera rays for antialiasing".into(),
        });
        v
    }

    fn build(&mut self, ctx: &RenderContext) -> Result<()> {
        let gpu = ctx.gpu;
        let layout = pipelines::layout(
            gpu,
            "reference",
            &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: true,
                        min_binding_size: wgpu::BufferSize::new(16),
                    },
                    count: None,
                },
                pipelines::uniform_entry(1, wgpu::ShaderStages::COMPUTE),
                pipelines::storage_entry(2, false),
            ],
        );
        // Build everything first so a failure leaves the previous pipeline in place.
        let pipeline = Self::path_pipeline(ctx, &layout, self.light_tree)?;
        let slots = self.sample_slots.take().unwrap_or_else(|| {
            let mut bytes = vec![0u8; (SLOT_BYTES * MAX_SAMPLES_PER_FRAME as u64) as usize];
            for i in 0..MAX_SAMPLES_PER_FRAME {
                let at = (i as u64 * SLOT_BYTES) as usize;
                bytes[at..at + 4].copy_from_slice(&i.to_le_bytes());
            }
            wgpu::util::DeviceExt::create_buffer_init(
                &gpu.device,
                &wgpu::util::BufferInitDescriptor {
                    label: Some("reference sample slots"),
                    contents: &bytes,
                    usage: wgpu::BufferUsages::UNIFORM,
                },
            )
        });
        let settings = self.settings_buffer.take().unwrap_or_else(|| {
            gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("reference settings"),
                size: 16,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        });
        // The other light sampling's pipeline is built again when next wanted.
        self.pipelines = [None, None];
        self.pipelines[self.light_tree as usize] = Some(pipeline);
        self.layout = Some(layout);
        self.sample_slots = Some(slots);
        self.settings_buffer = Some(settings);
        self.extent = ctx.extent;
        self.depth_accum = None;
        self.apply_params(ctx)
    }

    /// `max_depth` and `accumulate` travel in the technique's own uniform; `samples_per_frame` is the number of
    /// dispatches, so neither needs more than a uniform write.
    fn apply_params(&mut self, ctx: &RenderContext) -> Result<()> {
        if let (Some(layout), None) = (&self.layout, &self.pipelines[self.light_tree as usize]) {
            self.pipelines[self.light_tree as usize] =
                Some(Self::path_pipeline(ctx, layout, self.light_tree)?);
        }
        if let Some(b) = &self.settings_buffer {
            ctx.gpu.queue.write_buffer(
                b,
                0,
                bytemuck::cast_slice(&[
                    self.max_depth,
                    self.accumulate as u32,
                    self.depth_images as u32,
                    0,
                ]),
            );
        }
        self.bind_depth_images(ctx.gpu);
        Ok(())
    }

    /// No history beyond the average, which the engine keeps and clears.
    fn reset_history(&mut self, _gpu: &Gpu) {}

    fn samples_per_frame(&self) -> u32 {
        self.samples_per_frame
    }

    fn render(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
    ) {
        let (Some(pipeline), Some(bg)) =
            (&self.pipelines[self.light_tree as usize], &self.bind_group)
        else {
            return;
        };
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("reference path_trace"),
            timestamp_writes: timer.compute_pass("path_trace"),
        });
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, &ctx.scene.bind_group, &[]);
        pass.set_bind_group(1, ctx.frame_bind_group, &[]);
        for i in 0..self.samples_per_frame {
            pass.set_bind_group(2, bg, &[(i as u64 * SLOT_BYTES) as u32]);
            pass.dispatch_workgroups(ctx.extent[0].div_ceil(8), ctx.extent[1].div_ceil(8), 1);
        }
    }

    fn param_set(&self) -> &Params {
        &self.params
    }

    fn set_params(&mut self, changes: &ParamChanges) -> Result<()> {
        self.params.apply(changes)?;
        self.samples_per_frame = self.params.u32("samples_per_frame");
        self.max_depth = self.params.u32("max_depth");
        self.accumulate = self.params.bool("accumulate");
        self.depth_images = self.params.bool("depth_images");
        self.light_tree = self.params.choice("light_sampling") == "tree";
        Ok(())
    }

    fn params_for_ray_budget(
        &self,
        rays_per_pixel: f64,
        measured: Option<f64>,
    ) -> Option<ParamChanges> {
        // Rays scale with paths per pixel: rays/path measured at the current setting.
        let per_path = measured
            .map(|m| m / self.samples_per_frame.max(1) as f64)
            .filter(|r| *r > 0.0)
            .unwrap_or(ASSUMED_RAYS_PER_PATH);
        let spf = (rays_per_pixel / per_path)
            .round()
            .clamp(1.0, MAX_SAMPLES_PER_FRAME as f64) as u32;
        (spf != self.samples_per_frame)
            .then(|| ParamChanges::new().int("samples_per_frame", spf as i64))
    }
}
