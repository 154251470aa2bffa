//! # DDGI irradiance probes (`ddgi`)
//!
//! Dynamic Diffuse Global Illumination (Majercik et al., "Dynamic Diffuse Global Illumination
//! with Ray-Traced Irradiance Fields", JCGT 2019; "Scaling Probe-Based Real-Time Dynamic Global
//! Illumination for Production", JCGT 2021), issue 61. A grid of probes per cascade, in a
//! volume that follows the camera inside the scene's bounds ([`volume`]); each frame every
//! probe traces `rays_per_probe` rays in a randomly rotated spherical-Fibonacci set plus 32
//! fixed rays (`trace`), shades their hits with direct light and the probes' own irradiance
//! (multi-bounce), and blends them into its octahedral irradiance (6 × 6) and distance moment
//! (14 × 14) maps with hysteresis, borders included (`blend`); the fixed rays relocate probes
//! out of walls and switch off probes in walls or away from every surface. The pixels gather
//! from the 8 probes around their surface with the Chebyshev visibility test (`shade`).
//! Shaders: shaders/ddgi/. Docs: docs/ddgi.md.

pub mod volume;

use crate::gpu::{timing::PassTimer, Gpu};
use crate::parts::hash_cache::{self, HashCache, HashCacheSettings};
use crate::parts::texels::{texture_entry, BufferTexels, WIDE_ROW};
use crate::parts::{Part, RestirDirect};
use crate::render::params::{ParamChanges, ParamKind, ParamSpec, Params};
use crate::render::primary::FrameInputs;
use crate::render::{pipelines, DebugView, PassInfo, RenderContext, Technique};
use crate::scene::features::SceneFeatures;
use anyhow::Result;
use volume::{DdgiParamsGpu, ProbeVolume, VolumeSettings};

pub const PARAMS: &[ParamSpec] = &[
    ParamSpec {
        name: "accumulate",
        what: "average every frame since the last reset (off: each frame alone)",
        higher: "on: a static view converges (to the probes' answer)",
        lower: "off: what a game shows each frame",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "probes_per_axis",
        what: "probes along each axis of a cascade (fewer on an axis the scene is shorter on)",
        higher: "finer probes: sharper indirect light, more rays and memory",
        lower: "coarser probes: blurrier light, more leaking past thin walls",
        kind: ParamKind::Int { min: 2, max: 32 },
        default: 8.0,
    },
    ParamSpec {
        name: "cascades",
        what: "nested probe volumes around the camera, each with twice the previous one's spacing",
        higher: "covers larger scenes around the camera",
        lower: "one volume (default: it spans the scene at `volume` = 1)",
        kind: ParamKind::Int { min: 1, max: 4 },
        default: 1.0,
    },
    ParamSpec {
        name: "volume",
        what: "the first cascade's extent as a share of the scene's longest side (spacing = volume x side / probes_per_axis); a volume smaller than the scene follows the camera",
        higher: "one volume covers more of the scene, coarser probes",
        lower: "finer probes around the camera only",
        kind: ParamKind::Float { min: 0.05, max: 4.0 },
        default: 1.0,
    },
    ParamSpec {
        name: "rays_per_probe",
        what: "rays each probe traces a frame into its maps (plus 32 fixed rays for relocation and classification); the ray budget's knob",
        higher: "less noise per frame, more rays",
        lower: "cheaper, noisier maps (hysteresis averages them)",
        kind: ParamKind::Int { min: 16, max: 1024 },
        default: 256.0,
    },
    ParamSpec {
        name: "hysteresis",
        what: "share of the old maps a frame keeps (the paper's 0.97; a new probe averages its frames until its history is this long)",
        higher: "less noise, slower to follow a change (lag)",
        lower: "follows changes sooner, noisier",
        kind: ParamKind::Float { min: 0.0, max: 0.999 },
        default: 0.97,
    },
    ParamSpec {
        name: "visibility",
        what: "weight each probe by the Chebyshev bound that it sees the surface (its distance moments), the paper's leak fix",
        higher: "on: probes behind a wall are not read",
        lower: "off: plain trilinear irradiance probes (leak through walls)",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "relocation",
        what: "move probes out of walls and away from nearby surfaces (at most 0.45 of a spacing)",
        higher: "on: fewer probes lost inside geometry",
        lower: "off: probes stay on the grid",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "classification",
        what: "switch off probes inside walls or with no surface within their cell: they trace only their fixed rays and are not read",
        higher: "on: fewer rays, no dark probes read",
        lower: "off: every probe traces every ray",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "multi_bounce",
        what: "probe rays' hits add the probes' own irradiance (last frame's), so every frame adds a bounce",
        higher: "on: all bounces",
        lower: "off: one bounce of indirect light",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "bias",
        what: "self-shadow bias of the lookup: the point moves (0.2 normal + 0.8 view) x 0.75 spacing x bias before the probes are weighted",
        higher: "fewer dark self-shadowing artefacts, more leaking at thin walls",
        lower: "tighter contact, more self-shadowing",
        kind: ParamKind::Float { min: 0.0, max: 2.0 },
        default: 0.3,
    },
    ParamSpec {
        name: "probe_hits",
        what: "what lights a probe ray's hit: `probes` (NEE plus the probes' own irradiance, the paper's) or `hash-cache` (where the segment is longer than the hit's cell and the cell has samples, the hash radiance cache's reflected light, parts::hash_cache at its defaults; elsewhere the probes')",
        higher: "hash-cache: no shadow ray or probe gather at most hits, all bounces from the cache's full paths (its update paths' rays added)",
        lower: "probes: self-contained, one bounce a frame through the probes",
        kind: ParamKind::Choice(&["probes", "hash-cache"]),
        default: 0.0,
    },
    crate::parts::restir_direct::param(
        &["nee", "restir"],
        "direct light per pixel: next-event estimation of one light by power, or ReSTIR DI (the shared direct-light part); the probe rays' hits use NEE either way",
        "restir: far less noise with many lights, more passes",
        "nee: one shadow ray a pixel, no extra passes",
    ),
    ParamSpec {
        name: crate::techniques::DEBUG_VIEWS,
        what: "write the debug views (probe spheres and states, their irradiance and distance, the probe a pixel reads most; the 8 probes each pixel reads and their shares where the five extra planes fit in one storage binding)",
        higher: "on: the viewer's debug views work",
        lower: "off: no debug writes (timed runs switch it off)",
        kind: ParamKind::Bool,
        default: 1.0,
    },
];

struct Pipelines {
    trace: wgpu::ComputePipeline,
    blend: wgpu::ComputePipeline,
    shade: wgpu::ComputePipeline,
}

struct Resources {
    params: wgpu::Buffer,
    probes: wgpu::Buffer,
    rays: wgpu::Buffer,
    irradiance: wgpu::Buffer,
    distance: wgpu::Buffer,
    /// The probe records, irradiance and distance maps again as texels (bindings 7-9), copied
    /// after each blend: every gather reads 8 probes' records and 8 bilinear footprints, and
    /// lavapipe reads a texel several times faster than a storage buffer (crate::parts::texels).
    /// The blend reads and writes the buffers.
    texels: [BufferTexels; 3],
    bind_group: wgpu::BindGroup,
    direct_bind_group: wgpu::BindGroup,
    /// (probes, rays per probe, pixels, debug planes) they were sized for.
    sized: (u32, u32, u64, u64),
}

impl Resources {
    /// Records the copy of the probe records and maps into their texels.
    fn copy_texels(&self, enc: &mut wgpu::CommandEncoder) {
        for (t, b) in self
            .texels
            .iter()
            .zip([&self.probes, &self.irradiance, &self.distance])
        {
            t.copy_from(enc, b, 0);
        }
    }
}

/// The debug views of the 8 probes a pixel's gather reads: corner k of its cell (k's bits are
/// the +x, +y, +z steps from its lowest corner), its probe and its share of the weight.
const CORNER_NAMES: [[&str; 2]; 8] = [
    [
        "probe read at corner 0 (slot + 1; 0: weighs nothing)",
        "share of corner 0 in the gather",
    ],
    ["probe read at corner 1 (+x)", "share of corner 1 (+x)"],
    ["probe read at corner 2 (+y)", "share of corner 2 (+y)"],
    ["probe read at corner 3 (+x+y)", "share of corner 3 (+x+y)"],
    ["probe read at corner 4 (+z)", "share of corner 4 (+z)"],
    ["probe read at corner 5 (+x+z)", "share of corner 5 (+x+z)"],
    ["probe read at corner 6 (+y+z)", "share of corner 6 (+y+z)"],
    [
        "probe read at corner 7 (+x+y+z)",
        "share of corner 7 (+x+y+z)",
    ],
];

pub struct Ddgi {
    params: Params,
    settings: VolumeSettings,
    accumulate: bool,
    debug: bool,
    direct_restir: bool,
    /// Probe rays' hits read the hash radiance cache (`probe_hits = "hash-cache"`).
    hits_in_cache: bool,
    pub volume: ProbeVolume,
    /// The hash radiance cache the probe rays read (built only when they do).
    pub cache: HashCache,
    /// Whether the built trace pipeline reads the cache.
    built_with_cache: bool,
    restir_direct: RestirDirect,
    layout: Option<wgpu::BindGroupLayout>,
    pipelines: Option<Pipelines>,
    res: Option<Resources>,
    /// One vec4 per pixel: the debug views' channels 0-3.
    debug_buffer: Option<wgpu::Buffer>,
    /// Pixels of the image built for (the ray budget's conversion).
    pixels: u64,
    /// Frames since the last reset (the rays' rotation is drawn from it).
    frame: u32,
}

impl Default for Ddgi {
    fn default() -> Self {
        let mut t = Ddgi {
            params: Params::new("ddgi", PARAMS),
            settings: VolumeSettings::default(),
            accumulate: true,
            debug: true,
            direct_restir: false,
            hits_in_cache: false,
            volume: ProbeVolume::default(),
            cache: HashCache::new(HashCacheSettings::default()),
            built_with_cache: false,
            restir_direct: RestirDirect::default(),
            layout: None,
            pipelines: None,
            res: None,
            debug_buffer: None,
            pixels: 1,
            frame: 0,
        };
        t.read_params();
        t
    }
}

impl Ddgi {
    fn read_params(&mut self) {
        let p = &self.params;
        self.accumulate = p.bool("accumulate");
        self.debug = p.bool(crate::techniques::DEBUG_VIEWS);
        self.direct_restir = crate::parts::restir_direct::chosen(p);
        self.hits_in_cache = p.choice("probe_hits") == "hash-cache";
        self.settings = VolumeSettings {
            probes_per_axis: p.u32("probes_per_axis"),
            cascades: p.u32("cascades"),
            volume: p.f32("volume"),
            rays_per_probe: p.u32("rays_per_probe"),
            hysteresis: p.f32("hysteresis"),
            visibility: p.bool("visibility"),
            relocation: p.bool("relocation"),
            classification: p.bool("classification"),
            multi_bounce: p.bool("multi_bounce"),
            bias: p.f32("bias"),
        };
    }

    fn layout(&mut self, gpu: &Gpu) -> wgpu::BindGroupLayout {
        self.layout
            .get_or_insert_with(|| {
                let mut entries = vec![pipelines::uniform_entry(0, wgpu::ShaderStages::COMPUTE)];
                entries.extend((1..=6).map(|b| pipelines::storage_entry(b, false)));
                let float = wgpu::TextureSampleType::Float { filterable: false };
                entries.push(texture_entry(7, wgpu::TextureSampleType::Uint));
                entries.push(texture_entry(8, float));
                entries.push(texture_entry(9, float));
                pipelines::layout(gpu, "ddgi", &entries)
            })
            .clone()
    }

    /// Buffers sized by the probe count, rays per probe and image (kept when those stay); a
    /// size above the GPU's largest storage binding is refused, naming the parameters.
    fn build_resources(&mut self, ctx: &RenderContext) -> Result<()> {
        let gpu = ctx.gpu;
        let (lo, hi) = ctx.scene.data.bounds();
        self.volume.configure(&self.settings, lo, hi);
        let probes = self.volume.probe_count();
        let rays = self.volume.rays_per_probe();
        let pixels = ctx.extent[0] as u64 * ctx.extent[1] as u64;
        self.pixels = pixels.max(1);
        let largest = gpu.device.limits().max_storage_buffer_binding_size;
        // The corner views' planes where the debug views are on and they fit in one binding
        // (at 1920x1080 they take 190 MiB); otherwise the first plane alone.
        let planes = if self.debug && pixels * 16 * volume::DEBUG_PLANES <= largest {
            volume::DEBUG_PLANES
        } else {
            1
        };
        if self
            .res
            .as_ref()
            .is_some_and(|r| r.sized == (probes, rays, pixels, planes))
        {
            return Ok(());
        }
        let ray_bytes = volume::buffer_bytes(probes, rays).rays;
        if ray_bytes > largest {
            anyhow::bail!(
                "ddgi: {probes} probes x {rays} rays need a {} MiB ray buffer, above this GPU's largest storage binding ({} MiB): lower probes_per_axis, cascades or rays_per_probe",
                ray_bytes >> 20,
                largest >> 20
            );
        }
        let layout = self.layout(gpu);
        let params = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("ddgi params"),
            size: std::mem::size_of::<DdgiParamsGpu>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let bytes = volume::buffer_bytes(probes, rays);
        let probe_buf = pipelines::storage_buffer(gpu, "ddgi probes", bytes.probes);
        let ray_buf = pipelines::storage_buffer(gpu, "ddgi rays", bytes.rays);
        let irradiance = pipelines::storage_buffer(gpu, "ddgi irradiance", bytes.irradiance);
        let distance = pipelines::storage_buffer(gpu, "ddgi distance", bytes.distance);
        let debug = pipelines::storage_buffer(gpu, "ddgi debug", pixels * 16 * planes);
        let direct = pipelines::storage_buffer(gpu, "ddgi pixel direct", pixels * 16);
        let texels = |label, format, count: u64| {
            BufferTexels::new(gpu, label, format, count as u32, WIDE_ROW)
        };
        let texels = [
            texels(
                "ddgi probe texels",
                wgpu::TextureFormat::Rgba32Uint,
                2 * probes as u64,
            )?,
            texels(
                "ddgi irradiance texels",
                wgpu::TextureFormat::Rgba32Float,
                bytes.irradiance / 16,
            )?,
            texels(
                "ddgi distance texels",
                wgpu::TextureFormat::Rg32Float,
                bytes.distance / 8,
            )?,
        ];
        let mut entries: Vec<wgpu::BindGroupEntry> = [
            &params,
            &probe_buf,
            &ray_buf,
            &irradiance,
            &distance,
            &debug,
            &direct,
        ]
        .into_iter()
        .enumerate()
        .map(|(b, buffer)| wgpu::BindGroupEntry {
            binding: b as u32,
            resource: buffer.as_entire_binding(),
        })
        .collect();
        entries.extend(texels.iter().zip(7..).map(|(t, b)| wgpu::BindGroupEntry {
            binding: b,
            resource: wgpu::BindingResource::TextureView(&t.view),
        }));
        let bind_group = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("ddgi"),
            layout: &layout,
            entries: &entries,
        });
        let direct_layout = self.restir_direct.output_layout(gpu).clone();
        let direct_bind_group =
            pipelines::buffers_bind_group(gpu, "ddgi pixel direct", &direct_layout, &[&direct]);
        self.res = Some(Resources {
            params,
            probes: probe_buf,
            rays: ray_buf,
            irradiance,
            distance,
            texels,
            bind_group,
            direct_bind_group,
            sized: (probes, rays, pixels, planes),
        });
        self.debug_buffer = Some(debug);
        self.reset_history(gpu);
        Ok(())
    }

    /// Planes of the debug buffer as built (`DEBUG_PLANES` with the corner views, else 1).
    fn debug_planes(&self) -> u64 {
        self.res.as_ref().map_or(1, |r| r.sized.3)
    }

    fn flags(&self) -> u32 {
        let s = &self.settings;
        let mut f = 0;
        for (on, bit) in [
            (s.visibility, volume::FLAG_VISIBILITY),
            (s.relocation, volume::FLAG_RELOCATION),
            (s.classification, volume::FLAG_CLASSIFICATION),
            (s.multi_bounce, volume::FLAG_MULTI_BOUNCE),
            (self.accumulate, volume::FLAG_ACCUMULATE),
            (self.debug, volume::FLAG_DEBUG),
            (self.direct_restir, volume::FLAG_DIRECT_RESTIR),
            (self.debug_planes() > 1, volume::FLAG_DEBUG_CORNERS),
        ] {
            if on {
                f |= bit;
            }
        }
        f
    }

    /// GPU memory of the probe maps, records and ray results (not the per-pixel planes).
    pub fn memory_bytes(&self) -> u64 {
        let b = volume::buffer_bytes(self.volume.probe_count(), self.volume.rays_per_probe());
        b.probes + b.rays + b.irradiance + b.distance
    }
}

impl Technique for Ddgi {
    fn id(&self) -> &'static str {
        "ddgi"
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
        let s = &self.settings;
        if self.hits_in_cache {
            v.extend(self.cache.passes(f));
        }
        v.push(PassInfo {
            name: "probe trace",
            runs: true,
            why: format!(
                "{} probes x ({} + 32 fixed) rays: {}NEE{} at each hit",
                self.volume.probe_count(),
                s.rays_per_probe,
                if self.hits_in_cache {
                    "the hash cache where it covers the hit, else "
                } else {
                    ""
                },
                if s.multi_bounce {
                    " + the probes' irradiance"
                } else {
                    ""
                }
            ),
        });
        v.push(PassInfo {
            name: "probe blend",
            runs: true,
            why: format!(
                "octahedral irradiance 6x6 and distance 14x14 per probe, hysteresis {}{}{}",
                s.hysteresis,
                if s.relocation { ", relocation" } else { "" },
                if s.classification {
                    ", classification"
                } else {
                    ""
                }
            ),
        });
        if self.direct_restir {
            v.extend(self.restir_direct.passes(f));
        }
        v.push(PassInfo {
            name: "shade",
            runs: true,
            why: format!(
                "direct light ({}) + irradiance from the 8 probes around each pixel{}",
                if self.direct_restir {
                    RestirDirect::describe()
                } else {
                    "NEE, one shadow ray".into()
                },
                if s.visibility {
                    ", Chebyshev visibility"
                } else {
                    ", no visibility test"
                }
            ),
        });
        v
    }

    fn build(&mut self, ctx: &RenderContext) -> Result<()> {
        let layout = self.layout(ctx.gpu);
        let make = |file| {
            pipelines::compute_pipeline(
                ctx.gpu,
                ctx.shaders,
                file,
                &[&ctx.scene.layout, ctx.frame_layout, &layout],
            )
        };
        let trace = if self.hits_in_cache {
            let mut defs = hash_cache::lookup_defs(3).to_vec();
            defs.push(("DDGI_HASH_CACHE", 1));
            pipelines::compute_pipeline(
                ctx.gpu,
                &ctx.shaders.with_defs(&defs),
                "ddgi/trace.wgsl",
                &[
                    &ctx.scene.layout,
                    ctx.frame_layout,
                    &layout,
                    &hash_cache::lookup_layout(ctx.gpu),
                ],
            )?
        } else {
            make("ddgi/trace.wgsl")?
        };
        let blend = make("ddgi/blend.wgsl")?;
        let shade = make("ddgi/shade.wgsl")?;
        self.restir_direct
            .prepare(ctx, self.direct_restir, true, ())?;
        if self.hits_in_cache {
            self.cache.build(ctx)?;
        }
        self.built_with_cache = self.hits_in_cache;
        self.pipelines = Some(Pipelines {
            trace,
            blend,
            shade,
        });
        self.build_resources(ctx)
    }

    /// New sizes (probes, rays) rebuild the buffers (empty probes); other settings travel in
    /// the uniforms and keep the probes' maps.
    fn apply_params(&mut self, ctx: &RenderContext) -> Result<()> {
        if self.pipelines.is_some() && self.built_with_cache != self.hits_in_cache {
            // The trace pipeline reads the cache or not (a shader def): rebuilt.
            return self.build(ctx);
        }
        self.restir_direct
            .prepare(ctx, self.direct_restir, false, ())?;
        if self.pipelines.is_some() {
            self.build_resources(ctx)?;
        }
        Ok(())
    }

    fn reset_history(&mut self, gpu: &Gpu) {
        self.frame = 0;
        self.restir_direct.reset(gpu);
        self.cache.reset(gpu);
        let Some(r) = &self.res else { return };
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        for b in [&r.probes, &r.rays, &r.irradiance, &r.distance] {
            enc.clear_buffer(b, 0, None);
        }
        r.copy_texels(&mut enc);
        gpu.submit("ddgi: reset", enc.finish());
    }

    /// The probes carry over a scripted change or a move, as in a game: their hysteresis has
    /// to catch up (the lag the experiments measure).
    fn on_scene_change(&mut self, _gpu: &Gpu) {}

    fn render(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
    ) {
        let flags = self.flags();
        let gpu_params = self
            .volume
            .frame_params(ctx.camera.position, self.frame, flags);
        self.frame = self.frame.wrapping_add(1);
        let direct_restir = self.restir_direct.active(self.direct_restir);
        let (Some(p), Some(r)) = (&self.pipelines, &self.res) else {
            return;
        };
        ctx.gpu
            .queue
            .write_buffer(&r.params, 0, bytemuck::bytes_of(&gpu_params));
        let probes = self.volume.probe_count();
        let rows = [probes.min(1024), probes.div_ceil(1024)];
        let trace_groups = [self.volume.rays_per_probe().div_ceil(32), rows[0], rows[1]];
        if self.built_with_cache {
            self.cache.record(ctx, enc, timer);
            if let Some(cache) = self.cache.lookup() {
                pipelines::technique_pass(
                    ctx,
                    enc,
                    timer,
                    "probe trace",
                    &p.trace,
                    &[&r.bind_group, cache],
                    trace_groups,
                );
            }
        } else {
            pipelines::technique_pass(
                ctx,
                enc,
                timer,
                "probe trace",
                &p.trace,
                &[&r.bind_group],
                trace_groups,
            );
        }
        pipelines::technique_pass(
            ctx,
            enc,
            timer,
            "probe blend",
            &p.blend,
            &[&r.bind_group],
            [rows[0], rows[1], 1],
        );
        // Every reader after the blend (this frame's shade, next frame's probe rays) takes
        // the texels.
        r.copy_texels(enc);
        if direct_restir {
            self.restir_direct
                .record(ctx, enc, timer, &r.direct_bind_group);
        }
        pipelines::technique_pass(
            ctx,
            enc,
            timer,
            "shade",
            &p.shade,
            &[&r.bind_group],
            [ctx.extent[0].div_ceil(8), ctx.extent[1].div_ceil(8), 1],
        );
    }

    fn debug_views(&self) -> Vec<DebugView> {
        let view = |name, channel, is_id| DebugView {
            name,
            channel,
            is_id,
        };
        let mut views = vec![
            view("probes (spheres: 1 on, 2 switched off)", 0, true),
            view(
                "probe irradiance (on a sphere), else the gathered irradiance",
                1,
                false,
            ),
            view("probe mean distance on a sphere (spacings)", 2, false),
            view("probe the pixel reads most (slot + 1)", 3, true),
        ];
        if self.debug_planes() > 1 {
            views.extend([
                view(
                    "probes the pixel reads: how many of the 8 weigh in",
                    4,
                    false,
                ),
                view("gather weight (sum over the 8 probes)", 5, false),
                view("probe sphere under the pixel (slot + 1)", 6, true),
                view("cascade the pixel reads (+ 1)", 7, true),
            ]);
            views.extend(
                CORNER_NAMES
                    .iter()
                    .enumerate()
                    .map(|(k, n)| view(n[0], 8 + k, true)),
            );
            views.extend(
                CORNER_NAMES
                    .iter()
                    .enumerate()
                    .map(|(k, n)| view(n[1], 16 + k, false)),
            );
        }
        views
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

    /// Probe rays (and their shadow rays) are the budget's share; the camera ray, the pixels'
    /// direct light and the fixed rays are what is left, measured when a measurement exists.
    fn params_for_ray_budget(
        &self,
        rays_per_pixel: f64,
        measured: Option<f64>,
    ) -> Option<ParamChanges> {
        let probes = self.volume.probe_count().max(1) as f64;
        let per_ray = 2.0 * probes / self.pixels as f64;
        let now = self.settings.rays_per_probe as f64 * per_ray;
        let other = measured.map(|m| (m - now).max(2.0)).unwrap_or(2.0);
        let want = ((rays_per_pixel - other) / per_ray).round();
        let rays = ((want / 16.0).round() * 16.0).clamp(16.0, 1024.0) as u32;
        (rays != self.settings.rays_per_probe)
            .then(|| ParamChanges::new().int("rays_per_probe", rays as i64))
    }
}
