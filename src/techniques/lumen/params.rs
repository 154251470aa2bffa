//! The Lumen technique's parameters (one table: docs, ranges, defaults) and their GPU form.

use crate::render::params::{ParamKind, ParamSpec, Params};

use crate::parts::world_cache::DEFAULTS as WORLD_CACHE_DEFAULTS;

/// Lumen's own parameters; [`PARAMS`] adds the reflections part's.
const OWN_PARAMS: &[ParamSpec] = &[
    ParamSpec {
        name: "tracing",
        what: "what rays trace: the global distance field (the seed's software ray tracing) or the scene's triangles through the BVH (its hardware ray tracing); both read the same surface cache",
        higher: "bvh: exact hits and shadows, no leaks through thin walls, cost grows with triangles",
        lower: "sdf: cost independent of triangle count, hits within about a voxel, over-occlusion from the expand",
        kind: ParamKind::Choice(&["sdf", "bvh"]),
        default: 0.0,
    },
    ParamSpec {
        name: "clipmap_levels",
        what: "global SDF clipmaps centred on the camera, each twice the size of the last (levels past the first that holds the whole scene are not built)",
        higher: "reach farther from the camera",
        lower: "less memory and build time; rays that leave the last level miss",
        kind: ParamKind::Int { min: 1, max: 6 },
        default: 4.0,
    },
    ParamSpec {
        name: "clipmap_resolution",
        what: "voxels along each side of every clipmap (a multiple of 8: bricks are 8^3)",
        higher: "finer distance field: hits and thin walls resolved closer, more bricks to build",
        lower: "coarser: faster builds, more over-occlusion and error",
        kind: ParamKind::Int { min: 32, max: 256 },
        default: 128.0,
    },
    ParamSpec {
        name: "atlas_size",
        what: "side of the surface cache atlas in texels (a multiple of its 128x128 pages); card resolution follows from it",
        higher: "sharper cache, more memory, each update budget covers a smaller share",
        lower: "blurrier cache, cheaper updates",
        kind: ParamKind::Int { min: 128, max: 4096 },
        default: 2048.0,
    },
    ParamSpec {
        name: "direct_texels_per_frame",
        what: "surface cache texels whose direct light is updated per frame, quoted for a 4096^2 atlas and scaled to the atlas's area (the seed's 1024^2)",
        higher: "the cache follows light changes sooner and converges faster",
        lower: "cheaper frames, more lag",
        kind: ParamKind::Int { min: 0, max: 16_777_216 },
        default: 1_048_576.0,
    },
    ParamSpec {
        name: "indirect_texels_per_frame",
        what: "surface cache texels whose indirect light (probes on 4x4 tiles, 16 rays each) is updated per frame, quoted for a 4096^2 atlas and scaled (the seed's 512^2)",
        higher: "bounces propagate sooner (each update adds one), more cache rays",
        lower: "cheaper frames, multi-bounce converges more slowly",
        kind: ParamKind::Int { min: 0, max: 16_777_216 },
        default: 262_144.0,
    },
    ParamSpec {
        name: "final_gather",
        what: "how pixels gather indirect light: screen probes (the seed's Screen Space Radiance Cache, backed by the world radiance cache) or part 1's per-pixel rays",
        higher: "pixels: one ray set per pixel (or per gather_downsample block), no probe interpolation",
        lower: "screen_probes: 64 rays per probe every probe_spacing pixels, importance sampled, filtered in probe space",
        kind: ParamKind::Choice(&["screen_probes", "pixels"]),
        default: 0.0,
    },
    ParamSpec {
        name: "probe_spacing",
        what: "pixels between uniform screen probes (a power of two); each probe traces 64 rays into 8x8 octahedral cells, adaptive probes go at half this spacing",
        higher: "fewer probes and rays (64 / spacing^2 per pixel), blurrier indirect light",
        lower: "more probes: sharper indirect shadows, more rays",
        kind: ParamKind::Int { min: 4, max: 64 },
        default: 16.0,
    },
    ParamSpec {
        name: "probe_sampling",
        what: "screen probe ray directions: the product of the served pixels' BRDF and last frame's reprojected probe radiance (world cache where reprojection fails), with a quarter uniform; or uniform over the directions the pixels see",
        higher: "uniform: no dependence on last frame, more noise where light comes from few directions",
        lower: "product: rays go where the light and the BRDF are",
        kind: ParamKind::Choice(&["product", "uniform"]),
        default: 0.0,
    },
    ParamSpec {
        name: "probe_ray_reassignment",
        what: "with product sampling, the seed's ray reassignment instead of a CDF draw: one ray per seen cell, cells below half the uniform pdf keep theirs with probability 2 C p (Russian roulette, unbiased), the freed rays supersample the highest-pdf cells 2x2",
        higher: "on: bright cells are traced 4 times, dim cells sometimes not at all",
        lower: "off: each cell gets about 64 p rays from a stratified CDF draw",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "adaptive_probes",
        what: "place extra probes at half the spacing where the uniform ones cannot interpolate (depth and normal discontinuities)",
        higher: "on: corners and edges get probes of their own",
        lower: "off: those pixels take the nearest probe on another plane",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "screen_traces",
        what: "trace probe rays through last frame's hierarchical Z first; only rays it cannot resolve go on to the world trace",
        higher: "on: fewer world rays, on-screen detail and multi-bounce from last frame's image",
        lower: "off: every probe ray is a world ray",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "screen_trace_steps",
        what: "iteration cap of a screen trace's hierarchical-Z walk",
        higher: "more rays resolved on screen",
        lower: "cheaper walks, more rays continue in the world",
        kind: ParamKind::Int { min: 1, max: 256 },
        default: 64.0,
    },
    ParamSpec {
        name: "world_cache",
        what: "the world radiance cache: clipmaps of 16x16-cell probes around the camera; probe rays stop at world_cache_distance and a miss reads it",
        higher: "on: distant and small bright sources seen by 256 directions per probe, cheaper probe rays",
        lower: "off: probe rays go the whole way",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "world_cache_distance",
        what: "length of screen probe rays before they read the world cache, in scene units (the seed's 2 m; level 0's probes are a quarter of it apart); at least the probe diagonal of the level around the screen probe, as the seed's probe TMin",
        higher: "more exact nearby light, longer rays",
        lower: "more light from the coarser world cache",
        kind: ParamKind::Float { min: 0.05, max: 1000.0 },
        default: WORLD_CACHE_DEFAULTS.distance as f64,
    },
    ParamSpec {
        name: "world_cache_levels",
        what: "world cache clipmaps, each with twice the last one's probe spacing",
        higher: "reach farther from the camera",
        lower: "less memory",
        kind: ParamKind::Int { min: 1, max: 4 },
        default: WORLD_CACHE_DEFAULTS.levels as f64,
    },
    ParamSpec {
        name: "world_cache_probes",
        what: "world cache probes along each side of a clipmap",
        higher: "wider coverage at the same spacing, more memory",
        lower: "less memory, lookups fall to coarser levels sooner",
        kind: ParamKind::Int { min: 4, max: 32 },
        default: WORLD_CACHE_DEFAULTS.probes as f64,
    },
    ParamSpec {
        name: "world_probes_per_frame",
        what: "world probes traced per frame (256 rays each): probes read but never traced first, then the others, stalest first (fixed cost, variable latency)",
        higher: "the world cache fills and follows light changes sooner",
        lower: "fewer cache rays per frame",
        kind: ParamKind::Int { min: 0, max: 4096 },
        default: WORLD_CACHE_DEFAULTS.probes_per_frame as f64,
    },
    ParamSpec {
        name: "world_cache_history",
        what: "updates a world probe's running mean spans (each update is 256 fresh rays; 1: the latest update alone): a short history follows the surface cache's light with less lag",
        higher: "less noise in the world cache",
        lower: "less lag behind the surface cache (a cold start or a light change)",
        kind: ParamKind::Int { min: 1, max: 16 },
        default: WORLD_CACHE_DEFAULTS.history as f64,
    },
    ParamSpec {
        name: "spatial_filter",
        what: "filter each probe with its 3x3 neighbours in probe space (plane distance and hit angle-error weights)",
        higher: "on: less noise for the cost of 9 loads per cell",
        lower: "off: each probe alone",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "temporal_filter",
        what: "temporal accumulation of probes (reprojected, about 4 frames) and of per-pixel irradiance (depth and normal rejection, about 10 frames)",
        higher: "on: less noise per frame, some lag after a change",
        lower: "off: each frame's probes alone",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "contact_ao",
        what: "short-range screen-space occlusion (4 rays over half a probe spacing) applied after the temporal filter, for the contact shadows the probes are too sparse to see",
        higher: "on: darker creases and contacts",
        lower: "off: no extra occlusion (the probes' own)",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "gather_downsample",
        what: "final_gather = pixels: gather at one pixel per NxN block, upsampled with normal and depth weights",
        higher: "fewer gather rays per pixel, blurrier indirect light",
        lower: "1: every pixel gathers",
        kind: ParamKind::Int { min: 1, max: 4 },
        default: 1.0,
    },
    ParamSpec {
        name: "rays_per_pixel",
        what: "final_gather = pixels: rays per gathering pixel per frame (the viewer's ray-budget slider sets it; with screen probes it sets probe_spacing)",
        higher: "less noise per frame, more rays",
        lower: "cheaper frames, noisier",
        kind: ParamKind::Int { min: 1, max: 64 },
        default: 2.0,
    },
    ParamSpec {
        name: "voxel_lighting",
        what: "tracing = sdf: the seed's voxel lighting, the cards merged into clipmaps at half the distance field's resolution (radiance per voxel along 6 axis directions, shaded every frame), lights the hits whose own cards give no answer",
        higher: "on: hits beside a card's coverage or on the wrong object still bring light back",
        lower: "off: those hits are black (energy lost)",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "sign_rays",
        what: "rays per narrow-band voxel that decide the distance field's sign by counting back faces (the seed casts 64)",
        higher: "a more reliable sign near open or messy geometry, slower SDF builds",
        lower: "faster builds, more voxels with the wrong sign",
        kind: ParamKind::Int { min: 4, max: 64 },
        default: 16.0,
    },
    crate::parts::restir_direct::param(
        &["nee", "restir"],
        "direct light per pixel: next-event estimation of one light by power, or ReSTIR DI (the restir technique's passes with GI off, the shared direct-light part); the surface cache's own direct light is unchanged",
        "restir: far less noise with many lights (ReGIR where the scene has them), more passes",
        "nee: one shadow ray in apply, no extra passes",
    ),
    ParamSpec {
        name: "accumulate",
        what: "average frames into the output (off: each frame alone, the real-time view)",
        higher: "on: a static view converges",
        lower: "off: what a game would show each frame",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "debug_views",
        what: "compute the debug views each frame (cache channels, cards, SDF slice, steps and error: one more SDF trace per pixel, inside the apply pass's time)",
        higher: "on: the viewer's debug views show data",
        lower: "off: timings without the debug work (benchmarks)",
        kind: ParamKind::Bool,
        default: 1.0,
    },
];

/// Lumen's parameters and its parts' (reflections, the cache's light sampling).
pub const PARAMS: &[ParamSpec] = crate::param_table![
    OWN_PARAMS,
    crate::parts::reflections::PARAMS,
    crate::parts::world_regir::PARAMS,
];

/// The parameters, typed.
#[derive(Clone, Debug, PartialEq)]
pub struct LumenSettings {
    pub bvh: bool,
    pub clipmap_levels: u32,
    pub clipmap_resolution: u32,
    pub atlas_size: u32,
    pub direct_texels_per_frame: u32,
    pub indirect_texels_per_frame: u32,
    pub gather_downsample: u32,
    pub rays_per_pixel: u32,
    pub sign_rays: u32,
    pub voxel_lighting: bool,
    pub accumulate: bool,
    /// `direct = "restir"`: pixels take direct light from the ReSTIR DI part.
    pub direct_restir: bool,
    pub debug_views: bool,
    pub screen_probes: bool,
    pub probe_spacing: u32,
    pub product_sampling: bool,
    /// `probe_ray_reassignment` (with product sampling).
    pub ray_reassignment: bool,
    pub adaptive_probes: bool,
    pub screen_traces: bool,
    pub screen_trace_steps: u32,
    pub world_cache: bool,
    pub world_cache_distance: f32,
    pub world_cache_levels: u32,
    pub world_cache_probes: u32,
    pub world_probes_per_frame: u32,
    pub world_cache_history: u32,
    pub spatial_filter: bool,
    pub temporal_filter: bool,
    pub contact_ao: bool,
    /// `reflections = "traced"`.
    pub reflections: bool,
    /// The reflections part's settings.
    pub reflection: crate::parts::reflections::ReflectionSettings,
    /// How the surface cache picks the lights of its texels (`cache_direct`).
    pub cache_light: crate::parts::world_regir::WorldRegirSettings,
}

impl LumenSettings {
    /// The surface cache part's settings (`crate::parts::surface_cache`).
    pub fn surface_cache_settings(&self) -> crate::parts::surface_cache::SurfaceCacheSettings {
        crate::parts::surface_cache::SurfaceCacheSettings {
            atlas_size: self.atlas_size,
            direct_texels_per_frame: self.direct_texels_per_frame,
            indirect_texels_per_frame: self.indirect_texels_per_frame,
            cache_light: self.cache_light,
        }
    }

    /// The world radiance cache part's settings (`crate::parts::world_cache`).
    pub fn world_cache_settings(&self) -> crate::parts::world_cache::WorldCacheSettings {
        crate::parts::world_cache::WorldCacheSettings {
            levels: self.world_cache_levels,
            probes: self.world_cache_probes,
            probes_per_frame: self.world_probes_per_frame,
            history: self.world_cache_history,
            distance: self.world_cache_distance,
        }
    }

    pub fn from_params(p: &Params) -> Self {
        LumenSettings {
            bvh: p.u32("tracing") == 1,
            clipmap_levels: p.u32("clipmap_levels"),
            clipmap_resolution: p.u32("clipmap_resolution"),
            atlas_size: p.u32("atlas_size"),
            direct_texels_per_frame: p.u32("direct_texels_per_frame"),
            indirect_texels_per_frame: p.u32("indirect_texels_per_frame"),
            gather_downsample: p.u32("gather_downsample"),
            rays_per_pixel: p.u32("rays_per_pixel"),
            sign_rays: p.u32("sign_rays"),
            voxel_lighting: p.bool("voxel_lighting"),
            accumulate: p.bool("accumulate"),
            direct_restir: crate::parts::restir_direct::chosen(p),
            debug_views: p.bool("debug_views"),
            screen_probes: p.u32("final_gather") == 0,
            probe_spacing: p.u32("probe_spacing"),
            product_sampling: p.u32("probe_sampling") == 0,
            ray_reassignment: p.bool("probe_ray_reassignment"),
            adaptive_probes: p.bool("adaptive_probes"),
            screen_traces: p.bool("screen_traces"),
            screen_trace_steps: p.u32("screen_trace_steps"),
            world_cache: p.bool("world_cache"),
            world_cache_distance: p.f32("world_cache_distance"),
            world_cache_levels: p.u32("world_cache_levels"),
            world_cache_probes: p.u32("world_cache_probes"),
            world_probes_per_frame: p.u32("world_probes_per_frame"),
            world_cache_history: p.u32("world_cache_history"),
            spatial_filter: p.bool("spatial_filter"),
            temporal_filter: p.bool("temporal_filter"),
            contact_ao: p.bool("contact_ao"),
            reflections: crate::parts::reflections::ReflectionSettings::from_params(p).0,
            reflection: crate::parts::reflections::ReflectionSettings::from_params(p).1,
            cache_light: crate::parts::world_regir::WorldRegirSettings::from_params(p),
        }
    }

    /// What the table's ranges cannot say.
    pub fn check(&self) -> anyhow::Result<()> {
        anyhow::ensure!(
            self.clipmap_resolution.is_multiple_of(8),
            "lumen: clipmap_resolution = {} is not a multiple of 8 (bricks are 8^3 voxels)",
            self.clipmap_resolution
        );
        anyhow::ensure!(
            self.atlas_size
                .is_multiple_of(crate::parts::surface_cache::cards::PAGE),
            "lumen: atlas_size = {} is not a multiple of the {}-texel page",
            self.atlas_size,
            crate::parts::surface_cache::cards::PAGE
        );
        anyhow::ensure!(
            self.probe_spacing.is_power_of_two(),
            "lumen: probe_spacing = {} is not a power of two",
            self.probe_spacing
        );
        Ok(())
    }
}

pub use crate::parts::tracing::{
    LevelGpu, TracingParamsGpu, FLAG_BVH, FLAG_LIGHTS, FLAG_SKY, FLAG_VOXEL_LIGHTING,
};

// Lumen's own bits of the tracing uniform's flags (shaders/lumen/shared.wgsl); the tracing
// part's are 1, 2, 16 and 128.
pub const FLAG_ACCUMULATE: u32 = 4;
pub const FLAG_DEBUG: u32 = 8;
pub const FLAG_DIRECT_RESTIR: u32 = 32;
/// Pixels add the reflections part's specular light.
pub const FLAG_REFLECTIONS: u32 = 64;
