//! # ReSTIR DI (`restir`)
//!
//! Direct lighting by reservoir-based spatiotemporal importance resampling, as in "Making
//! Connections" (GDC; shared/seeds/003) and Bitterli et al. 2020. Per pixel and frame:
//!
//! 1. `primary`: a jittered camera ray (the reference's jitter sequence) stores the surface.
//! 2. `initial_temporal`: `candidates` lights drawn from the power-proportional light pool
//!    (emissive triangles and punctual lights) are resampled by the unshadowed target
//!    f · Le · G into a weighted reservoir; optionally the chosen one is visibility-tested
//!    (the talk's conservative test); then last frame's reservoir at the reprojected pixel is
//!    merged if the surfaces are similar, its M clamped to `max_history` × the current M.
//! 3. `spatial`: `spatial_count` neighbours within `spatial_radius` pixels are merged.
//!    Unbiased mode weights by 1/Z (only reservoirs that could have produced the sample count,
//!    with a visibility ray each when candidate visibility is on); biased mode weights by M and
//!    drops occluded samples from reuse. The bidirectional occlusion test only reuses a
//!    neighbour's light that is visible from this pixel.
//! 4. `shade`: one visibility ray for the final sample; emission + f · Le · G · V · W is
//!    accumulated over frames (Welford), like the reference, so a static view converges.
//!
//! Samples live in the light's own measure (area for triangles), so reuse across pixels needs
//! no Jacobian.
//! Shaders: shaders/restir/*.wgsl, shared state in shaders/common/restir.wgsl.

use crate::gpu::{timing::PassTimer, Gpu};
use crate::render::{pipelines, DebugView, ParamDoc, PassInfo, RenderContext, Technique};
use crate::scene::features::SceneFeatures;
use anyhow::{bail, Result};
use wgpu::util::DeviceExt;

/// Matches `RestirParams` in shaders/common/restir.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct RestirParamsGpu {
    pub candidates: u32,
    pub candidate_visibility: u32,
    pub temporal: u32,
    pub max_history: f32,
    pub spatial_count: u32,
    pub spatial_radius: f32,
    pub unbiased: u32,
    pub bidirectional: u32,
    pub pixels: u32,
    pub accumulate: u32,
    pub gi: u32,
    pub gi_bounces: u32,
    pub regir: u32,
    pub regir_cell_size: f32,
    pub regir_dims: u32,
    pub regir_slots: u32,
}

/// Bytes of `GSurface`, `Reservoir` and `GiReservoir` in shaders/common/restir.wgsl.
pub const SURFACE_BYTES: u64 = 96;
pub const RESERVOIR_BYTES: u64 = 32;
pub const GI_RESERVOIR_BYTES: u64 = 64;
pub const REGIR_SLOT_BYTES: u64 = 16;
/// ReGIR grid: REGIR_DIMS^3 cells around the camera.
pub const REGIR_DIMS: u32 = 16;
const MAX_SPATIAL: u32 = 8;

#[derive(Clone, Debug, PartialEq)]
pub struct RestirSettings {
    pub candidates: u32,
    pub candidate_visibility: bool,
    pub temporal: bool,
    pub max_history: f32,
    pub spatial_count: u32,
    pub spatial_radius: f32,
    pub unbiased: bool,
    pub bidirectional: bool,
    pub accumulate: bool,
    pub gi: bool,
    pub gi_bounces: u32,
    /// Use ReGIR when the scene has many lights.
    pub regir: bool,
    /// Cell edge in world units; 0 = automatic (scene diagonal / 24).
    pub regir_cell_size: f32,
    pub regir_lights_per_cell: u32,
}

impl Default for RestirSettings {
    fn default() -> Self {
        // The talk's defaults: 8 initial candidates, max history 8, a couple of spatial samples.
        RestirSettings {
            candidates: 8,
            candidate_visibility: true,
            temporal: true,
            max_history: 8.0,
            spatial_count: 3,
            spatial_radius: 16.0,
            unbiased: true,
            bidirectional: false,
            accumulate: true,
            gi: true,
            gi_bounces: 0,
            regir: true,
            regir_cell_size: 0.0,
            regir_lights_per_cell: 16,
        }
    }
}

struct Pipelines {
    regir_build: wgpu::ComputePipeline,
    primary: wgpu::ComputePipeline,
    initial_temporal: wgpu::ComputePipeline,
    spatial: wgpu::ComputePipeline,
    gi_temporal: wgpu::ComputePipeline,
    gi_spatial: wgpu::ComputePipeline,
    shade: wgpu::ComputePipeline,
}

#[derive(Default)]
pub struct Restir {
    pub settings: RestirSettings,
    pipelines: Option<Pipelines>,
    bind_group: Option<wgpu::BindGroup>,
    params: Option<wgpu::Buffer>,
    surfaces: Option<wgpu::Buffer>,
    reservoirs: Option<wgpu::Buffer>,
    gi_reservoirs: Option<wgpu::Buffer>,
    gi_sky: Option<wgpu::Buffer>,
    regir_slots: Option<wgpu::Buffer>,
    debug: Option<wgpu::Buffer>,
    mean: Option<wgpu::Buffer>,
    m2: Option<wgpu::Buffer>,
    extent: [u32; 2],
    has_lights: bool,
    many_lights: bool,
    /// Cell size in use (the setting, or the automatic one for this scene).
    regir_cell: f32,
}

const PASSES: [&str; 7] = [
    "regir_build",
    "primary",
    "initial_temporal",
    "spatial",
    "gi_temporal",
    "gi_spatial",
    "shade",
];

impl Restir {
    /// ReGIR runs only where the scene calls for it: many lights (rule 3).
    pub fn regir_active(&self) -> bool {
        self.settings.regir && self.many_lights
    }

    fn gpu_params(&self, pixels: u32) -> RestirParamsGpu {
        let s = &self.settings;
        RestirParamsGpu {
            candidates: s.candidates,
            candidate_visibility: s.candidate_visibility as u32,
            temporal: s.temporal as u32,
            max_history: s.max_history,
            spatial_count: s.spatial_count,
            spatial_radius: s.spatial_radius,
            unbiased: s.unbiased as u32,
            bidirectional: s.bidirectional as u32,
            pixels,
            accumulate: s.accumulate as u32,
            gi: s.gi as u32,
            gi_bounces: s.gi_bounces,
            regir: self.regir_active() as u32,
            regir_cell_size: self.regir_cell,
            regir_dims: REGIR_DIMS,
            regir_slots: s.regir_lights_per_cell,
        }
    }

    /// Rays per pixel per frame of everything but GI: camera, final DI visibility, the
    /// candidate test (biased mode), the bidirectional test per neighbour.
    pub fn direct_rays_per_pixel(&self) -> f64 {
        let s = &self.settings;
        let mut rays = 2.0;
        if s.candidate_visibility && !s.unbiased {
            rays += 1.0;
        }
        if s.bidirectional {
            rays += s.spatial_count as f64;
        }
        rays
    }
}

impl Technique for Restir {
    fn id(&self) -> &'static str {
        "restir"
    }

    fn passes(&self, f: &SceneFeatures) -> Vec<PassInfo> {
        let lights = f.light_count() > 0;
        let no_lights = || "no emissive triangles or punctual lights".to_string();
        vec![
            PassInfo {
                name: "primary",
                runs: true,
                why: "jittered camera rays, as the reference".into(),
            },
            PassInfo {
                name: "initial_temporal",
                runs: lights,
                why: if lights {
                    format!(
                        "RIS over {} lights ({} emissive triangles), temporal reuse {}",
                        f.light_count(),
                        f.emissive_triangle_count,
                        if self.settings.temporal { "on" } else { "off" }
                    )
                } else {
                    no_lights()
                },
            },
            PassInfo {
                name: "spatial",
                runs: lights,
                why: if !lights {
                    no_lights()
                } else if self.settings.spatial_count == 0 {
                    "spatial_count = 0: copies the temporal result only".into()
                } else {
                    format!(
                        "{} neighbours within {} px, {}",
                        self.settings.spatial_count,
                        self.settings.spatial_radius,
                        if self.settings.unbiased {
                            "unbiased (1/Z)"
                        } else {
                            "biased (M weights)"
                        }
                    )
                },
            },
            PassInfo {
                name: "gi_temporal",
                runs: self.settings.gi,
                why: if self.settings.gi {
                    format!(
                        "one sample path per pixel ({}), temporal reuse",
                        if self.settings.gi_bounces == 0 {
                            "unbounded, Russian roulette".to_string()
                        } else {
                            format!("{} bounces", self.settings.gi_bounces)
                        }
                    )
                } else {
                    "gi = false: direct light only".into()
                },
            },
            PassInfo {
                name: "gi_spatial",
                runs: self.settings.gi,
                why: if self.settings.gi {
                    "spatial reuse of GI samples (area-measure weights)".into()
                } else {
                    "gi = false".into()
                },
            },
            PassInfo {
                name: "shade",
                runs: true,
                why: "final visibility (DI and GI), emission and accumulation".into(),
            },
            PassInfo {
                name: "regir_build",
                runs: self.settings.regir && f.many_lights,
                why: if !self.settings.regir {
                    "regir = false: candidates from the global light pool".into()
                } else if f.many_lights {
                    format!(
                        "{} lights: {}^3 cells around the camera, {} lights each",
                        f.light_count(),
                        REGIR_DIMS,
                        self.settings.regir_lights_per_cell
                    )
                } else {
                    format!(
                        "only {} lights: the global pool is enough, no grid",
                        f.light_count()
                    )
                },
            },
        ]
    }

    fn build(&mut self, ctx: &RenderContext) -> Result<()> {
        let gpu = ctx.gpu;
        let mut entries = ctx.frame_layout_entries.to_vec();
        entries.push(pipelines::uniform_entry(2, wgpu::ShaderStages::COMPUTE));
        for b in 3..=10 {
            entries.push(pipelines::storage_entry(b, false));
        }
        let layout = gpu
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("restir"),
                entries: &entries,
            });
        let layouts = [&ctx.scene.layout, &layout];
        // Everything is built before anything is replaced: a failure keeps the old pipelines.
        let make = |entry: &str| pipelines::compute_pipeline(gpu, ctx.shaders, entry, &layouts);
        let built = Pipelines {
            regir_build: make("restir/regir_build.wgsl")?,
            primary: make("restir/primary.wgsl")?,
            initial_temporal: make("restir/initial_temporal.wgsl")?,
            spatial: make("restir/spatial.wgsl")?,
            gi_temporal: make("restir/gi_temporal.wgsl")?,
            gi_spatial: make("restir/gi_spatial.wgsl")?,
            shade: make("restir/shade.wgsl")?,
        };
        let [w, h] = ctx.extent;
        let pixels = w * h;
        let features = &ctx.scene.data.features;
        self.has_lights = features.light_count() > 0;
        self.many_lights = features.many_lights;
        self.regir_cell = if self.settings.regir_cell_size > 0.0 {
            self.settings.regir_cell_size
        } else {
            let lo = glam::Vec3::from(features.bounds_min);
            let hi = glam::Vec3::from(features.bounds_max);
            ((hi - lo).length() / 24.0).max(1e-3)
        };
        let params = gpu
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("restir params"),
                contents: bytemuck::bytes_of(&self.gpu_params(pixels)),
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            });
        let reuse = self.extent == ctx.extent && self.mean.is_some();
        let buffer = |slot: &mut Option<wgpu::Buffer>, label: &str, bytes: u64| match slot
            .take()
            .filter(|_| reuse)
        {
            Some(b) => b,
            None => pipelines::storage_buffer(gpu, label, bytes),
        };
        let px = pixels as u64;
        let surfaces = buffer(
            &mut self.surfaces,
            "restir surfaces",
            2 * px * SURFACE_BYTES,
        );
        let reservoirs = buffer(
            &mut self.reservoirs,
            "restir reservoirs",
            3 * px * RESERVOIR_BYTES,
        );
        let gi_reservoirs = buffer(
            &mut self.gi_reservoirs,
            "restir gi reservoirs",
            3 * px * GI_RESERVOIR_BYTES,
        );
        let gi_sky = buffer(&mut self.gi_sky, "restir gi sky", px * 16);
        let cells = (REGIR_DIMS as u64).pow(3);
        let regir_bytes = cells * self.settings.regir_lights_per_cell as u64 * REGIR_SLOT_BYTES;
        let regir_slots = match self.regir_slots.take() {
            Some(b) if b.size() == regir_bytes.max(16) => b,
            _ => pipelines::storage_buffer(gpu, "restir regir slots", regir_bytes),
        };
        let debug = buffer(&mut self.debug, "restir debug", px * 16);
        let mean = buffer(&mut self.mean, "restir mean", px * 16);
        let m2 = buffer(&mut self.m2, "restir m2", px * 16);
        let resources = [
            ctx.uniforms.as_entire_binding(),
            ctx.counters.as_entire_binding(),
            params.as_entire_binding(),
            surfaces.as_entire_binding(),
            reservoirs.as_entire_binding(),
            mean.as_entire_binding(),
            m2.as_entire_binding(),
            gi_reservoirs.as_entire_binding(),
            gi_sky.as_entire_binding(),
            regir_slots.as_entire_binding(),
            debug.as_entire_binding(),
        ];
        let bind_entries: Vec<wgpu::BindGroupEntry> = resources
            .into_iter()
            .enumerate()
            .map(|(i, resource)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource,
            })
            .collect();
        let bind_group = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("restir"),
            layout: &layout,
            entries: &bind_entries,
        });
        self.pipelines = Some(built);
        self.bind_group = Some(bind_group);
        self.params = Some(params);
        self.surfaces = Some(surfaces);
        self.reservoirs = Some(reservoirs);
        self.gi_reservoirs = Some(gi_reservoirs);
        self.gi_sky = Some(gi_sky);
        self.regir_slots = Some(regir_slots);
        self.debug = Some(debug);
        self.mean = Some(mean);
        self.m2 = Some(m2);
        self.extent = ctx.extent;
        Ok(())
    }

    fn reset_history(&mut self, gpu: &Gpu) {
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        for b in [&self.mean, &self.m2, &self.reservoirs]
            .into_iter()
            .flatten()
        {
            enc.clear_buffer(b, 0, None);
        }
        gpu.queue.submit([enc.finish()]);
    }

    /// Restarts accumulation only: the reservoirs carry over, as they would in a game.
    fn on_scene_change(&mut self, gpu: &Gpu) {
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        for b in [&self.mean, &self.m2].into_iter().flatten() {
            enc.clear_buffer(b, 0, None);
        }
        gpu.queue.submit([enc.finish()]);
    }

    fn samples_per_frame(&self) -> u32 {
        1
    }

    fn render(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
    ) {
        let (Some(p), Some(bg)) = (&self.pipelines, &self.bind_group) else {
            return;
        };
        if self.regir_active() {
            // One invocation per (cell, slot), 64 per workgroup.
            let slots = REGIR_DIMS.pow(3) * self.settings.regir_lights_per_cell;
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some(PASSES[0]),
                timestamp_writes: timer.compute_pass(PASSES[0]),
            });
            pass.set_pipeline(&p.regir_build);
            pass.set_bind_group(0, &ctx.scene.bind_group, &[]);
            pass.set_bind_group(1, bg, &[]);
            pass.dispatch_workgroups(slots.div_ceil(64), 1, 1);
        }
        let steps = [
            (PASSES[1], &p.primary, true),
            (PASSES[2], &p.initial_temporal, self.has_lights),
            // With spatial_count = 0 this pass only copies the temporal result through.
            (PASSES[3], &p.spatial, self.has_lights),
            (PASSES[4], &p.gi_temporal, self.settings.gi),
            (PASSES[5], &p.gi_spatial, self.settings.gi),
            (PASSES[6], &p.shade, true),
        ];
        for (name, pipeline, runs) in steps {
            if runs {
                pipelines::image_pass(ctx, enc, timer, name, pipeline, bg);
            }
        }
    }

    fn output(&self) -> &wgpu::Buffer {
        self.mean.as_ref().expect("restir used before build()")
    }

    fn variance_m2(&self) -> Option<&wgpu::Buffer> {
        self.m2.as_ref()
    }

    fn debug_views(&self) -> Vec<DebugView> {
        let view = |name, channel, is_id| DebugView {
            name,
            channel,
            is_id,
        };
        vec![
            view("reservoir M", 0, false),
            view("reservoir weight W", 1, false),
            view("selected light", 2, true),
            view("ReGIR cell", 3, true),
        ]
    }

    fn debug_buffer(&self) -> Option<&wgpu::Buffer> {
        self.debug.as_ref()
    }

    fn params(&self) -> toml::Table {
        let s = &self.settings;
        let mut t = toml::Table::new();
        t.insert("candidates".into(), (s.candidates as i64).into());
        t.insert("candidate_visibility".into(), s.candidate_visibility.into());
        t.insert("temporal".into(), s.temporal.into());
        t.insert("max_history".into(), (s.max_history as f64).into());
        t.insert("spatial_count".into(), (s.spatial_count as i64).into());
        t.insert("spatial_radius".into(), (s.spatial_radius as f64).into());
        t.insert("unbiased".into(), s.unbiased.into());
        t.insert("bidirectional".into(), s.bidirectional.into());
        t.insert("accumulate".into(), s.accumulate.into());
        t.insert("gi".into(), s.gi.into());
        t.insert("gi_bounces".into(), (s.gi_bounces as i64).into());
        t.insert("regir".into(), s.regir.into());
        t.insert("regir_cell_size".into(), (s.regir_cell_size as f64).into());
        t.insert(
            "regir_lights_per_cell".into(),
            (s.regir_lights_per_cell as i64).into(),
        );
        t
    }

    fn set_params(&mut self, params: &toml::Table) -> Result<()> {
        let mut s = self.settings.clone();
        for (k, v) in params {
            let num = v.as_float().or(v.as_integer().map(|i| i as f64));
            let flag = v.as_bool().or(v.as_integer().map(|i| i != 0));
            match (k.as_str(), num, flag) {
                ("candidates", Some(n), _) if (1.0..=256.0).contains(&n) => s.candidates = n as u32,
                ("max_history", Some(n), _) if (0.0..=1000.0).contains(&n) => s.max_history = n as f32,
                ("spatial_count", Some(n), _) if (0.0..=MAX_SPATIAL as f64).contains(&n) => {
                    s.spatial_count = n as u32
                }
                ("spatial_radius", Some(n), _) if (1.0..=256.0).contains(&n) => s.spatial_radius = n as f32,
                ("candidate_visibility", _, Some(b)) => s.candidate_visibility = b,
                ("temporal", _, Some(b)) => s.temporal = b,
                ("unbiased", _, Some(b)) => s.unbiased = b,
                ("bidirectional", _, Some(b)) => s.bidirectional = b,
                ("accumulate", _, Some(b)) => s.accumulate = b,
                ("gi", _, Some(b)) => s.gi = b,
                ("regir", _, Some(b)) => s.regir = b,
                ("regir_cell_size", Some(n), _) if (0.0..=1e6).contains(&n) => s.regir_cell_size = n as f32,
                ("regir_lights_per_cell", Some(n), _) if (1.0..=256.0).contains(&n) => {
                    s.regir_lights_per_cell = n as u32
                }
                ("gi_bounces", Some(n), _) if (0.0..=64.0).contains(&n) => s.gi_bounces = n as u32,
                (
                    "candidates" | "max_history" | "spatial_count" | "spatial_radius"
                    | "candidate_visibility" | "temporal" | "unbiased" | "bidirectional" | "accumulate" | "gi" | "gi_bounces" | "regir" | "regir_cell_size"
                    | "regir_lights_per_cell",
                    _,
                    _,
                ) => bail!("restir: parameter '{k}' out of range or of the wrong type: {v} (see the parameter docs)"),
                _ => bail!(
                    "restir has no parameter '{k}' (known: candidates, candidate_visibility, temporal, max_history, spatial_count, spatial_radius, unbiased, bidirectional, accumulate, gi, gi_bounces, regir, regir_cell_size, regir_lights_per_cell)"
                ),
            }
        }
        self.settings = s;
        Ok(())
    }

    fn param_docs(&self) -> Vec<ParamDoc> {
        let flag = |name, what, higher, lower| ParamDoc {
            name,
            what,
            higher,
            lower,
            min: 0.0,
            max: 1.0,
            integer: true,
        };
        vec![
            ParamDoc {
                name: "candidates",
                what: "initial RIS candidates per pixel per frame, drawn from the light pool by power",
                higher: "better initial samples (many lights), more shading work, no extra rays",
                lower: "cheaper, noisier before reuse",
                min: 1.0,
                max: 64.0,
                integer: true,
            },
            flag(
                "candidate_visibility",
                "1: one visibility ray for the chosen candidate before reuse",
                "occluded lights are not spread to neighbours (faster convergence, +1 ray)",
                "0: fewer rays, shadows spread through reuse until the final test",
            ),
            flag(
                "temporal",
                "1: merge last frame's reservoir at the reprojected pixel",
                "more effective samples per pixel, some temporal lag",
                "0: no history, no lag, noisier",
            ),
            ParamDoc {
                name: "max_history",
                what: "last frame's reservoir counts at most this many times the current candidates",
                higher: "more stable, slower to follow changes (lag)",
                lower: "reacts faster to changes, noisier (the talk's default is 8)",
                min: 0.0,
                max: 64.0,
                integer: false,
            },
            ParamDoc {
                name: "spatial_count",
                what: "neighbour reservoirs merged per pixel",
                higher: "less noise; in unbiased mode +1 ray per neighbour",
                lower: "cheaper; 0 turns spatial reuse off",
                min: 0.0,
                max: MAX_SPATIAL as f64,
                integer: true,
            },
            ParamDoc {
                name: "spatial_radius",
                what: "radius in pixels in which neighbours are picked",
                higher: "more independent neighbours, more blur across geometry edges",
                lower: "neighbours more similar, more correlated noise",
                min: 1.0,
                max: 64.0,
                integer: false,
            },
            flag(
                "unbiased",
                "1: 1/Z contribution weights (visibility-tested when candidate_visibility is on)",
                "converges to the reference; extra rays",
                "0: M weights and visibility reuse, cheaper, darkens contact shadows (biased)",
            ),
            flag(
                "regir",
                "1: draw initial candidates from a camera-centred grid of per-cell pre-selected lights (only when the scene has many lights)",
                "candidates near the shading point, far less noise with many small lights",
                "0: candidates from the global pool by power only",
            ),
            ParamDoc {
                name: "regir_cell_size",
                what: "ReGIR cell edge in world units (0 = scene diagonal / 24)",
                higher: "fewer, coarser cells: pre-selection less local",
                lower: "more local pre-selection; the 16^3 grid covers less of the scene",
                min: 0.0,
                max: 100.0,
                integer: false,
            },
            ParamDoc {
                name: "regir_lights_per_cell",
                what: "light reservoirs kept per ReGIR cell, rebuilt each frame",
                higher: "more diverse candidates per cell, more build work",
                lower: "cheaper build, pixels in a cell share fewer lights (correlated noise)",
                min: 1.0,
                max: 256.0,
                integer: true,
            },
            flag(
                "gi",
                "1: ReSTIR GI adds indirect light (one resampled sample path per pixel)",
                "full global illumination, +1 path per pixel",
                "0: direct light only",
            ),
            ParamDoc {
                name: "gi_bounces",
                what: "bounces of a GI sample path after its first hit; 0 = unbounded (Russian roulette)",
                higher: "more indirect light kept",
                lower: "cheaper paths that lose multi-bounce light (biased dark); 0 is unbiased",
                min: 0.0,
                max: 16.0,
                integer: true,
            },
            flag(
                "accumulate",
                "1: average frames progressively; 0: show each frame as a real-time renderer would",
                "a static view converges (what the error plots measure)",
                "the noise of one frame, with temporal reuse only",
            ),
            flag(
                "bidirectional",
                "1: reuse a neighbour's light only if it is visible from this pixel (the talk's bidirectional occlusion test)",
                "no runaway reuse under overlapping shadows, +1 ray per neighbour",
                "0: cheaper",
            ),
        ]
    }

    fn shader_files(&self) -> &'static [&'static str] {
        &[
            "restir/regir_build.wgsl",
            "restir/primary.wgsl",
            "restir/initial_temporal.wgsl",
            "restir/spatial.wgsl",
            "restir/gi_temporal.wgsl",
            "restir/gi_spatial.wgsl",
            "restir/shade.wgsl",
        ]
    }

    fn params_for_ray_budget(
        &self,
        rays_per_pixel: f64,
        measured: Option<f64>,
    ) -> Option<toml::Table> {
        // What costs rays: GI sample paths (their length is scene-dependent, so measured when
        // possible), the bidirectional test per neighbour; the rest is fixed. The budget first
        // decides whether GI fits, then spends what is left on bidirectional neighbours (when
        // on) and scales the candidate count, which costs shading but no rays.
        let direct = self.direct_rays_per_pixel();
        let gi_cost = measured
            .filter(|_| self.settings.gi)
            .map(|m| (m - direct).max(1.0))
            .unwrap_or(5.0);
        let mut next = self.settings.clone();
        next.gi = rays_per_pixel >= direct + gi_cost;
        let base = direct
            - if next.bidirectional {
                next.spatial_count as f64
            } else {
                0.0
            };
        let left = (rays_per_pixel - base - if next.gi { gi_cost } else { 0.0 }).max(0.0);
        if next.bidirectional {
            next.spatial_count = (left.floor() as u32).min(MAX_SPATIAL);
        }
        next.candidates = ((4.0 + 4.0 * left).round() as u32).clamp(1, 64);
        (next != self.settings).then(|| {
            let mut t = toml::Table::new();
            t.insert("gi".into(), next.gi.into());
            t.insert("spatial_count".into(), (next.spatial_count as i64).into());
            t.insert("candidates".into(), (next.candidates as i64).into());
            t
        })
    }
}
