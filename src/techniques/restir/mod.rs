//! # ReSTIR DI (`restir`)
//!
//! Direct lighting by reservoir-based spatiotemporal importance resampling, as in "Making
//! Connections" (GDC; shared/seeds/003) and Bitterli et al. 2020. Per pixel and frame:
//!
//! 1. `primary` (the engine's shared pass, `render::primary`): a jittered camera ray per pixel
//!    (the reference's jitter sequence) stores the surface; ReSTIR reads this frame's and last
//!    frame's through `gilab::primary`.
//! 2. `initial_temporal`: initial candidates per light class, as in the talk, each class
//!    resampled by the unshadowed target f · Le · G into its own reservoir:
//!    - local lights (emissive triangles, point and spot lights): `candidates` drawn by power
//!      within the class, or from the pixel's ReGIR cell;
//!    - directional lights: `directional_candidates` drawn by power within the class;
//!    - the sky: `sky_candidates` directions from an equal mix of BSDF and cosine sampling
//!      (0 by default: the GI sample ray then estimates direct sky light, which measured better).
//!
//!    A class the scene lacks gets no candidates (rule 3). The class reservoirs are merged
//!    before visibility (disjoint domains: each class is its own RIS estimator); in biased mode
//!    each class's pick can be visibility-tested first (the talk's fix for a strong, shadowed
//!    sun), or only the merged pick. Then last frame's reservoir at the reprojected pixel is
//!    merged if the surfaces are similar, its M clamped to `max_history` × the current M.
//!    `light_classes = false` gives the single power-proportional pool over every light, with
//!    the sky left to GI rays, for A/B comparisons.
//! 3. `spatial`: `spatial_count` neighbours within `spatial_radius` pixels are merged.
//!    Unbiased mode weights by 1/Z (only reservoirs that could have produced the sample count,
//!    with a visibility ray each when candidate visibility is on); biased mode weights by M and
//!    drops occluded samples from reuse. The bidirectional occlusion test only reuses a
//!    neighbour's light that is visible from this pixel.
//! 4. `shade`: one visibility ray for the final sample; emission + f · Le · G · V · W is
//!    accumulated over frames (Welford), like the reference, so a static view converges.
//!
//! Samples live in the light's own measure (area for triangles, solid angle for sky directions),
//! so reuse across pixels needs no Jacobian. With a sky class, GI sample rays that escape add
//! nothing: direct sky light is ReSTIR DI's.
//! Shaders: shaders/restir/*.wgsl, shared state in shaders/restir/shared.wgsl.

use crate::gpu::{timing::PassTimer, Gpu};
use crate::render::params::{ParamKind, ParamSpec, Params};
use crate::render::primary::FrameInputs;
use crate::render::{pipelines, DebugView, PassInfo, RenderContext, Technique};
use crate::scene::features::SceneFeatures;
use anyhow::Result;
use wgpu::util::DeviceExt;

/// Matches `RestirParams` in shaders/restir/shared.wgsl.
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
    pub directional_candidates: u32,
    pub sky_candidates: u32,
    pub single_pool: u32,
    pub pad: u32,
}

/// ReSTIR's parameters: docs, ranges and defaults in one place (the talk's defaults: 8 initial
/// candidates, max history 8, a few spatial neighbours).
pub const PARAMS: &[ParamSpec] = &[
    ParamSpec {
        name: "candidates",
        what: "initial RIS candidates per pixel per frame from the local lights (emissive triangles, point, spot), by power or from the ReGIR cell",
        higher: "better initial samples (many lights), more shading work, no extra rays",
        lower: "cheaper, noisier before reuse; 0 leaves local lights out of direct light",
        kind: ParamKind::Int { min: 0, max: 256 },
        default: 8.0,
    },
    ParamSpec {
        name: "directional_candidates",
        what: "initial RIS candidates per pixel per frame from the directional lights, by power (unused without directional lights)",
        higher: "better choice among several suns, more shading work, no extra rays",
        lower: "cheaper; 0 leaves directional lights out of direct light (biased dark)",
        kind: ParamKind::Int { min: 0, max: 64 },
        default: 1.0,
    },
    ParamSpec {
        name: "sky_candidates",
        what: "initial RIS candidates per pixel per frame from the sky: directions from an equal mix of BSDF and cosine sampling, merged with the other classes (unused when the sky is black or out of reach)",
        higher: "sky light resampled and reused like the other lights; one DI sample then carries sun, lamps and sky (colour noise)",
        lower: "0 (default): direct sky light comes from the GI sample ray instead (measured lower error on courtyard)",
        kind: ParamKind::Int { min: 0, max: 64 },
        default: 0.0,
    },
    ParamSpec {
        name: "light_classes",
        what: "on: candidates per light class (local, directional, sky), merged before visibility, as in the talk; off: one power-proportional pool over every light, sky through GI rays only",
        higher: "every class gets its candidates: a strong sun cannot starve local lights",
        lower: "the single-pool baseline, for A/B comparisons",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "candidate_visibility",
        what: "biased mode: visibility rays before reuse: off, each light class's pick before the merge (the talk's fix), or only the merged pick",
        higher: "per_class: occluded lights are not spread to neighbours and a shadowed sun cannot crowd out visible local lights (+1 ray per class)",
        lower: "off: fewer rays, shadows spread through reuse until the final test; merged: one ray, the talk's artifact under a shadowed sun",
        kind: ParamKind::Choice(&["off", "per_class", "merged"]),
        default: 1.0,
    },
    ParamSpec {
        name: "temporal",
        what: "merge last frame's reservoir at the reprojected pixel",
        higher: "on: more effective samples per pixel, some temporal lag",
        lower: "off: no history, no lag, noisier",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "max_history",
        what: "last frame's reservoir counts at most this many times the current candidates",
        higher: "more stable, slower to follow changes (lag)",
        lower: "reacts faster to changes, noisier (the talk's default is 8)",
        kind: ParamKind::Float { min: 0.0, max: 64.0 },
        default: 8.0,
    },
    ParamSpec {
        name: "spatial_count",
        what: "neighbour reservoirs merged per pixel",
        higher: "less noise; in unbiased mode +1 ray per neighbour",
        lower: "cheaper; 0 turns spatial reuse off",
        kind: ParamKind::Int { min: 0, max: MAX_SPATIAL as i64 },
        default: 3.0,
    },
    ParamSpec {
        name: "spatial_radius",
        what: "radius in pixels in which neighbours are picked",
        higher: "more independent neighbours, more blur across geometry edges",
        lower: "neighbours more similar, more correlated noise",
        kind: ParamKind::Float { min: 1.0, max: 128.0 },
        default: 16.0,
    },
    ParamSpec {
        name: "unbiased",
        what: "1/Z contribution weights over the unshadowed support (no candidate visibility tests)",
        higher: "on: converges to the reference",
        lower: "off: M weights and visibility reuse, cheaper, darkens contact shadows (biased)",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "bidirectional",
        what: "reuse a neighbour's light only if it is visible from this pixel (the talk's bidirectional occlusion test)",
        higher: "on: no runaway reuse under overlapping shadows, +1 ray per neighbour",
        lower: "off: cheaper",
        kind: ParamKind::Bool,
        default: 0.0,
    },
    ParamSpec {
        name: "accumulate",
        what: "average frames progressively; off shows each frame as a real-time renderer would",
        higher: "on: a static view converges (what the error plots measure)",
        lower: "off: the noise of one frame, with temporal reuse only",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "gi",
        what: "ReSTIR GI adds indirect light (one resampled sample path per pixel)",
        higher: "on: full global illumination, +1 path per pixel",
        lower: "off: direct light only",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "gi_bounces",
        what: "bounces of a GI sample path after its first hit; 0 = unbounded (Russian roulette)",
        higher: "more indirect light kept",
        lower: "cheaper paths that lose multi-bounce light (biased dark); 0 is unbiased",
        kind: ParamKind::Int { min: 0, max: 64 },
        default: 0.0,
    },
    ParamSpec {
        name: "regir",
        what: "draw initial candidates from a camera-centred grid of per-cell pre-selected lights (only when the scene has many lights)",
        higher: "on: candidates near the shading point, far less noise with many small lights",
        lower: "off: candidates from the global pool by power only",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "regir_cell_size",
        what: "ReGIR cell edge in world units (0 = scene diagonal / 24)",
        higher: "fewer, coarser cells: pre-selection less local",
        lower: "more local pre-selection; the 16^3 grid covers less of the scene",
        kind: ParamKind::Float { min: 0.0, max: 1e6 },
        default: 0.0,
    },
    ParamSpec {
        name: "regir_lights_per_cell",
        what: "light reservoirs kept per ReGIR cell, rebuilt each frame",
        higher: "more diverse candidates per cell, more build work",
        lower: "cheaper build, pixels in a cell share fewer lights (correlated noise)",
        kind: ParamKind::Int { min: 1, max: 256 },
        default: 16.0,
    },
];

/// Which initial candidates are visibility-tested before reuse (biased mode only).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CandidateVisibility {
    Off = 0,
    /// Each light class's pick, before the classes are merged (one ray per class present).
    PerClass = 1,
    /// Only the merged pick (one ray): a strong shadowed light can crowd out visible ones.
    Merged = 2,
}

impl CandidateVisibility {
    fn from_index(i: u32) -> Self {
        match i {
            0 => Self::Off,
            2 => Self::Merged,
            _ => Self::PerClass,
        }
    }
}

/// Bytes of `Reservoir`, `GiReservoir` and `RegirSlot` in shaders/restir/shared.wgsl.
pub const RESERVOIR_BYTES: u64 = 32;
pub const GI_RESERVOIR_BYTES: u64 = 64;
pub const REGIR_SLOT_BYTES: u64 = 16;
/// ReGIR grid: REGIR_DIMS^3 cells around the camera.
pub const REGIR_DIMS: u32 = 16;
const MAX_SPATIAL: u32 = 8;

#[derive(Clone, Debug, PartialEq)]
pub struct RestirSettings {
    /// Candidates from the local lights (all lights when `light_classes` is off).
    pub candidates: u32,
    pub directional_candidates: u32,
    pub sky_candidates: u32,
    /// Candidates per light class; false: one pool over every light, sky through GI only.
    pub light_classes: bool,
    pub candidate_visibility: CandidateVisibility,
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

impl RestirSettings {
    /// The settings the parameter table holds.
    fn from_params(p: &Params) -> Self {
        RestirSettings {
            candidates: p.u32("candidates"),
            directional_candidates: p.u32("directional_candidates"),
            sky_candidates: p.u32("sky_candidates"),
            light_classes: p.bool("light_classes"),
            candidate_visibility: CandidateVisibility::from_index(p.u32("candidate_visibility")),
            temporal: p.bool("temporal"),
            max_history: p.f32("max_history"),
            spatial_count: p.u32("spatial_count"),
            spatial_radius: p.f32("spatial_radius"),
            unbiased: p.bool("unbiased"),
            bidirectional: p.bool("bidirectional"),
            accumulate: p.bool("accumulate"),
            gi: p.bool("gi"),
            gi_bounces: p.u32("gi_bounces"),
            regir: p.bool("regir"),
            regir_cell_size: p.f32("regir_cell_size"),
            regir_lights_per_cell: p.u32("regir_lights_per_cell"),
        }
    }
}

impl Default for RestirSettings {
    fn default() -> Self {
        RestirSettings::from_params(&Params::new("restir", PARAMS))
    }
}

struct Pipelines {
    regir_build: wgpu::ComputePipeline,
    initial_temporal: wgpu::ComputePipeline,
    spatial: wgpu::ComputePipeline,
    gi_temporal: wgpu::ComputePipeline,
    gi_spatial: wgpu::ComputePipeline,
    shade: wgpu::ComputePipeline,
}

pub struct Restir {
    params: Params,
    /// The parameters as typed settings (refreshed whenever they change).
    pub settings: RestirSettings,
    pipelines: Option<Pipelines>,
    layout: Option<wgpu::BindGroupLayout>,
    bind_group: Option<wgpu::BindGroup>,
    params_buffer: Option<wgpu::Buffer>,
    reservoirs: Option<wgpu::Buffer>,
    gi_reservoirs: Option<wgpu::Buffer>,
    gi_sky: Option<wgpu::Buffer>,
    regir_slots: Option<wgpu::Buffer>,
    debug: Option<wgpu::Buffer>,
    extent: [u32; 2],
    classes: LightClasses,
    many_lights: bool,
    /// Cell size in use (the setting, or the automatic one for this scene).
    regir_cell: f32,
}

impl Default for Restir {
    fn default() -> Self {
        let params = Params::new("restir", PARAMS);
        Restir {
            settings: RestirSettings::from_params(&params),
            params,
            pipelines: None,
            layout: None,
            bind_group: None,
            params_buffer: None,
            reservoirs: None,
            gi_reservoirs: None,
            gi_sky: None,
            regir_slots: None,
            debug: None,
            extent: [0, 0],
            classes: LightClasses::default(),
            many_lights: false,
            regir_cell: 0.0,
        }
    }
}

/// Which light classes the scene has (rule 3: a class it lacks gets no candidates).
#[derive(Clone, Copy, Debug, Default)]
struct LightClasses {
    local: usize,
    directional: usize,
    sky: bool,
}

impl LightClasses {
    fn of(f: &SceneFeatures) -> Self {
        LightClasses {
            local: f.emissive_triangle_count + f.point_lights + f.spot_lights,
            directional: f.directional_lights,
            sky: f.sky_visible,
        }
    }
}

const PASSES: [&str; 6] = [
    "regir_build",
    "initial_temporal",
    "spatial",
    "gi_temporal",
    "gi_spatial",
    "shade",
];

impl Restir {
    /// ReGIR runs only where the scene calls for it: many lights (rule 3).
    pub fn regir_active(&self) -> bool {
        self.settings.regir && self.many_lights && self.class_candidates()[0] > 0
    }

    /// Candidates per frame of each class (local, directional, sky) as dispatched: 0 for a
    /// class the scene lacks; in single-pool mode all lights are "local" and the sky has none.
    fn class_candidates(&self) -> [u32; 3] {
        self.candidates_for(&self.classes)
    }

    fn candidates_for(&self, c: &LightClasses) -> [u32; 3] {
        let s = &self.settings;
        if !s.light_classes {
            let any = c.local + c.directional > 0;
            return [if any { s.candidates } else { 0 }, 0, 0];
        }
        [
            if c.local > 0 { s.candidates } else { 0 },
            if c.directional > 0 {
                s.directional_candidates
            } else {
                0
            },
            if c.sky { s.sky_candidates } else { 0 },
        ]
    }

    fn has_direct_sources(&self) -> bool {
        self.class_candidates().iter().any(|&n| n > 0)
    }

    fn gpu_params(&self, pixels: u32) -> RestirParamsGpu {
        let s = &self.settings;
        let [local, directional, sky] = self.class_candidates();
        RestirParamsGpu {
            candidates: local,
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
            directional_candidates: directional,
            sky_candidates: sky,
            single_pool: !s.light_classes as u32,
            pad: 0,
        }
    }

    /// What the initial candidates are drawn from, class by class, and what is skipped and why.
    fn candidate_summary(&self, f: &SceneFeatures) -> String {
        let c = LightClasses::of(f);
        let [local, directional, sky] = self.candidates_for(&c);
        let s = &self.settings;
        let source = if s.regir && f.many_lights {
            "ReGIR cell"
        } else {
            "by power"
        };
        if !s.light_classes {
            return format!(
                "one pool (light_classes = false): {local} candidates from {} lights {source}, sky only through GI rays",
                c.local + c.directional
            );
        }
        let mut parts = Vec::new();
        parts.push(if local > 0 {
            format!("local: {local} candidates over {} lights {source}", c.local)
        } else {
            "local: none in the scene".into()
        });
        parts.push(if directional > 0 {
            format!(
                "directional: {directional} candidates over {} lights",
                c.directional
            )
        } else {
            "directional: none in the scene".into()
        });
        parts.push(if sky > 0 {
            format!("sky: {sky} candidate directions")
        } else if f.sky_visible {
            "sky: sky_candidates = 0, through GI rays".into()
        } else {
            "sky: black or out of reach".into()
        });
        let test = match (s.unbiased, s.candidate_visibility) {
            (true, _) => "no candidate test (unbiased)",
            (false, CandidateVisibility::Off) => "no candidate test",
            (false, CandidateVisibility::PerClass) => "each class's pick tested",
            (false, CandidateVisibility::Merged) => "merged pick tested",
        };
        format!(
            "RIS per light class ({}), merged before visibility, {test}",
            parts.join("; ")
        )
    }

    /// Buffers, the parameter uniform and the bind group: on build, on a parameter change
    /// (buffers whose size did not change are kept) and never with a pipeline.
    fn build_resources(&mut self, ctx: &RenderContext) {
        let gpu = ctx.gpu;
        let [w, h] = ctx.extent;
        let pixels = w * h;
        let features = &ctx.scene.data.features;
        self.classes = LightClasses::of(features);
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
        let reuse = self.extent == ctx.extent && self.reservoirs.is_some();
        let buffer = |slot: &mut Option<wgpu::Buffer>, label: &str, bytes: u64| match slot
            .take()
            .filter(|_| reuse)
        {
            Some(b) => b,
            None => pipelines::storage_buffer(gpu, label, bytes),
        };
        let px = pixels as u64;
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
        let bind_group = pipelines::buffers_bind_group(
            gpu,
            "restir",
            self.layout.as_ref().expect("built"),
            &[
                &params,
                &reservoirs,
                &gi_reservoirs,
                &gi_sky,
                &regir_slots,
                &debug,
            ],
        );
        self.bind_group = Some(bind_group);
        self.params_buffer = Some(params);
        self.reservoirs = Some(reservoirs);
        self.gi_reservoirs = Some(gi_reservoirs);
        self.gi_sky = Some(gi_sky);
        self.regir_slots = Some(regir_slots);
        self.debug = Some(debug);
        self.extent = ctx.extent;
    }

    /// Rays per pixel per frame of everything but GI: camera, final DI visibility, the
    /// candidate tests (biased mode), the bidirectional test per neighbour.
    pub fn direct_rays_per_pixel(&self) -> f64 {
        let s = &self.settings;
        let mut rays = 2.0;
        if !s.unbiased {
            rays += match s.candidate_visibility {
                CandidateVisibility::Off => 0.0,
                CandidateVisibility::Merged => 1.0,
                CandidateVisibility::PerClass => {
                    self.class_candidates().iter().filter(|&&n| n > 0).count() as f64
                }
            };
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

    fn inputs(&self) -> FrameInputs {
        FrameInputs {
            primary_surfaces: true,
        }
    }

    fn passes(&self, f: &SceneFeatures) -> Vec<PassInfo> {
        let lights = self
            .candidates_for(&LightClasses::of(f))
            .iter()
            .any(|&n| n > 0);
        let no_lights = || "no emissive triangles, punctual lights or reachable sky".to_string();
        vec![
            PassInfo {
                name: "initial_temporal",
                runs: lights,
                why: if lights {
                    format!(
                        "{}; temporal reuse {}",
                        self.candidate_summary(f),
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
        let mut entries = vec![pipelines::uniform_entry(0, wgpu::ShaderStages::COMPUTE)];
        for b in 1..=5 {
            entries.push(pipelines::storage_entry(b, false));
        }
        let layout = pipelines::layout(gpu, "restir", &entries);
        // Everything is built before anything is replaced: a failure keeps the old pipelines.
        let make = |entry: &str| ctx.pipeline(entry, &layout);
        let built = Pipelines {
            regir_build: make("restir/regir_build.wgsl")?,
            initial_temporal: make("restir/initial_temporal.wgsl")?,
            spatial: make("restir/spatial.wgsl")?,
            gi_temporal: make("restir/gi_temporal.wgsl")?,
            gi_spatial: make("restir/gi_spatial.wgsl")?,
            shade: make("restir/shade.wgsl")?,
        };
        self.pipelines = Some(built);
        self.layout = Some(layout);
        self.build_resources(ctx);
        Ok(())
    }

    fn apply_params(&mut self, ctx: &RenderContext) -> Result<()> {
        self.build_resources(ctx);
        Ok(())
    }

    fn reset_history(&mut self, gpu: &Gpu) {
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        if let Some(r) = &self.reservoirs {
            enc.clear_buffer(r, 0, None);
        }
        gpu.queue.submit([enc.finish()]);
    }

    /// The reservoirs carry over, as they would in a game (the engine restarts the average).
    fn on_scene_change(&mut self, _gpu: &Gpu) {}

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
            pass.set_bind_group(1, ctx.frame_bind_group, &[]);
            pass.set_bind_group(2, bg, &[]);
            pass.dispatch_workgroups(slots.div_ceil(64), 1, 1);
        }
        let steps = [
            (PASSES[1], &p.initial_temporal, self.has_direct_sources()),
            // With spatial_count = 0 this pass only copies the temporal result through.
            (PASSES[2], &p.spatial, self.has_direct_sources()),
            (PASSES[3], &p.gi_temporal, self.settings.gi),
            (PASSES[4], &p.gi_spatial, self.settings.gi),
            (PASSES[5], &p.shade, true),
        ];
        for (name, pipeline, runs) in steps {
            if runs {
                pipelines::image_pass(ctx, enc, timer, name, pipeline, bg);
            }
        }
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

    fn param_set(&self) -> &Params {
        &self.params
    }

    fn set_params(&mut self, params: &toml::Table) -> Result<()> {
        self.params.set("restir", params)?;
        self.settings = RestirSettings::from_params(&self.params);
        Ok(())
    }

    fn shader_files(&self) -> &'static [&'static str] {
        &[
            "restir/regir_build.wgsl",
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
