//! Callisto shadows' parameters: the declared table, the typed settings made from it, and the
//! uniform the passes read.

use crate::render::params::{ParamKind, ParamSpec, Params};

/// Light slots per tile list at most (the rate buffer stays under a 128 MiB binding at 1080p).
pub const MAX_LIGHTS_PER_TILE: u32 = 512;

/// Matches `CallistoParams` in shaders/callisto_shadows/shared.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct CallistoParamsGpu {
    pub tiles_x: u32,
    pub tiles_y: u32,
    pub max_lights: u32,
    pub rate_mode: u32,
    pub range_cutoff: f32,
    pub cone_culling: u32,
    pub half_threshold: f32,
    pub full_threshold: f32,
    pub perceptual: f32,
    pub border_depth: f32,
    pub denoise: u32,
    pub max_history: f32,
    pub blur_radius: u32,
    pub accumulate: u32,
    pub gi: u32,
    pub pixels: u32,
    pub tail_samples: u32,
    pub direct_restir: u32,
    pub reflections: u32,
    pub reflection_max_roughness: f32,
    /// The static/dynamic split (`static_shadow_cache`); layout of the cache buffer in words.
    pub shadow_cache: u32,
    pub cache_samples: u32,
    pub cache_cell: f32,
    pub cache_slots: u32,
    /// First motion record in the BVH nodes buffer (`bvh.nodes.len()`).
    pub motion_base: u32,
    /// First instance record (`TopLevel::records_at`).
    pub records_at: u32,
    pub dynamic_count: u32,
    pub light_mask_base: u32,
    pub dynamic_base: u32,
    pub hash_base: u32,
    pub pad: [u32; 2],
}

/// Rate choices, in the order of `rate_mode` on the GPU.
pub const RATES: &[&str] = &["variable", "full", "half", "quarter"];

/// Callisto's own parameters; [`PARAMS`] adds the reflections part's and the caches' light
/// sampling (`cache_direct`, for the cache ReSTIR GI's paths end in).
const OWN_PARAMS: &[ParamSpec] = &[
    ParamSpec {
        name: "rate",
        what: "shadow-ray rate per light and 2x2 quad: variable (chosen from last frame's shadow variance, perceptually weighted) or forced everywhere",
        higher: "full: one ray per light per pixel (the ground truth of the reconstruction)",
        lower: "half / quarter: 2 or 1 rays per quad everywhere, reconstructed bilaterally (blurred shadow edges)",
        kind: ParamKind::Choice(RATES),
        default: 0.0,
    },
    ParamSpec {
        name: "range_cutoff",
        what: "irradiance (luminance, W/m^2) at which a local light's influence ends: range = sqrt(intensity / cutoff), intensity = a point or spot light's, or an emissive triangle's radiance x area; 0 = infinite range",
        higher: "shorter ranges: fewer lights per tile, fewer rays; the light beyond them is left to the tail samples (noisier), or lost without them",
        lower: "longer ranges: more lights per tile and rays; 0 keeps every light in the lists",
        kind: ParamKind::Float { min: 0.0, max: 1e6 },
        default: 0.01,
    },
    ParamSpec {
        name: "tail_samples",
        what: "shadow-ray samples per pixel of the lights outside the tile's list (beyond their range or left out of a full list), picked by power from the whole pool; a pick in the list adds nothing, so list + tail is unbiased",
        higher: "less noise from the lights beyond range, +1 ray per pixel each",
        lower: "0: the seed's behaviour, light beyond the ranges is lost (biased dark)",
        kind: ParamKind::Int { min: 0, max: 16 },
        default: 1.0,
    },
    ParamSpec {
        name: "max_lights_per_tile",
        what: "light slots of a 16x16 tile's list; when more lights reach the tile, those with the lowest bound on their irradiance there (in factors of 2) are left out (debug view 4 counts them)",
        higher: "no light dropped in dense tiles, more memory (tiles x slots x 16 B of rates)",
        lower: "less memory, dense tiles lose lights (biased dark)",
        kind: ParamKind::Int { min: 1, max: MAX_LIGHTS_PER_TILE as i64 },
        default: 256.0,
    },
    ParamSpec {
        name: "cone_culling",
        what: "reject a light for a tile when the tile's normal cone and the cone towards the light admit no N.L > 0 (and one-sided emitters facing away)",
        higher: "on: fewer lights per tile on surfaces facing away from lights",
        lower: "off: range and depth-bounds culling only",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "half_threshold",
        what: "weighted shadow variance of a quad's neighbourhood above which the quad gets half rate next frame",
        higher: "more quads at quarter rate: fewer rays, blurrier soft shadows",
        lower: "more quads at half rate or above",
        kind: ParamKind::Float { min: 0.0, max: 0.25 },
        default: 0.02,
    },
    ParamSpec {
        name: "full_threshold",
        what: "weighted shadow variance above which the quad gets full rate next frame",
        higher: "fewer quads at full rate: fewer rays, edges reconstructed from half rate",
        lower: "more quads at full rate (0: every quad with any variance)",
        kind: ParamKind::Float { min: 0.0, max: 0.25 },
        default: 0.08,
    },
    ParamSpec {
        name: "perceptual",
        what: "perceptual weighting: the variance is scaled by min(1, (the light's mean luminance over the tile / mean scene luminance) / perceptual); 0 = off",
        higher: "a light must be brighter against the scene mean to keep its rate: dim lights drop to quarter",
        lower: "weaker weighting; 0 uses the variance alone",
        kind: ParamKind::Float { min: 0.0, max: 100.0 },
        default: 0.25,
    },
    ParamSpec {
        name: "border_depth",
        what: "relative depth spread inside a quad that makes it a border quad (half rate then traces its min/max-depth pair); also the depth scale of the reconstruction's bilateral weights",
        higher: "fewer border quads, reconstruction mixes across larger depth steps",
        lower: "more border quads, stricter depth weights",
        kind: ParamKind::Float { min: 0.001, max: 1.0 },
        default: 0.05,
    },
    ParamSpec {
        name: "denoise",
        what: "temporal accumulation of the punctual lights' shadow mask (ratio of their shadowed to unshadowed direct light, both averaged over frames), with the disocclusion blur; sampled lights (emissive triangles, the tail) are added as traced",
        higher: "on: smooth shadows from few rays, some lag under motion",
        lower: "off: each frame's visibility as traced and reconstructed (unbiased with rate = full)",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "max_history",
        what: "frames the shadow mask's moving average spans at most (alpha = 1 - 1/(t+1), t frames since disocclusion)",
        higher: "smoother, slower to follow moving shadows",
        lower: "faster, noisier",
        kind: ParamKind::Float { min: 1.0, max: 256.0 },
        default: 16.0,
    },
    ParamSpec {
        name: "blur_radius",
        what: "bilateral blur radius (pixels) of the punctual lights' shadowed and unshadowed light right after a disocclusion; it halves with every frame since (the blurred frames stay in the moving average for a while, so large radii soften shadow edges for tens of frames)",
        higher: "smoother disoccluded regions, blurrier for a few frames",
        lower: "sharper, noisier disocclusions; 0 = no blur",
        kind: ParamKind::Int { min: 0, max: 32 },
        default: 2.0,
    },
    ParamSpec {
        name: "accumulate",
        what: "average frames progressively; off shows each frame as a real-time renderer would",
        higher: "on: a static view converges (what the error plots measure)",
        lower: "off: one frame (with the shadow mask's own temporal accumulation)",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "gi",
        what: "add indirect light from ReSTIR GI's resampled sample (one sample path per pixel, temporal and spatial reuse), as the `restir` technique shades it",
        higher: "on: global illumination (the sky arrives through it too), +1 path and 1 ray per pixel",
        lower: "off: direct light from the light pool only (no sky)",
        kind: ParamKind::Bool,
        default: 0.0,
    },
    ParamSpec {
        name: "gi_terminate",
        what: "where ReSTIR GI's sample paths end when gi is on, as in the restir technique: traced to the end, or at their first hit in one of the caches restir's gi_terminate lists (the cache parts, with restir's default atlas, update share and surfel ray budget)",
        higher: "a cache: multi-bounce light at about one bounce's price, biased by the cache",
        lower: "path: unbiased, every bounce traced",
        kind: ParamKind::Choice(&crate::parts::restir::GiTerminate::NAMES),
        default: 0.0,
    },
    crate::parts::restir_direct::param(
        &["tiles", "restir"],
        "direct light per pixel: this technique's tile-culled, variable-rate shadow rays, or ReSTIR DI (the restir technique's passes with GI off, the shared direct-light part), for A/B at equal everything else",
        "restir: reservoir resampling over every light, one visibility ray per pixel; cull, shadows and the shadow mask do not run",
        "tiles: the seed's ray-traced shadows (one ray per light per traced pixel)",
    ),
    ParamSpec {
        name: "static_shadow_cache",
        what: "the seed's static/dynamic split: a light that has not moved keeps the visibility of static geometry from static receivers in a world-space hash grid (cells of shadow_cache_cell pixel footprints, per light), filled by rays against static geometry only; each frame traces only the moving instances (those whose transform has changed) and multiplies. Lights that moved and receivers on moving instances trace the whole scene",
        higher: "on: a cell stops tracing static geometry after shadow_cache_samples rays; shadow edges of static casters are averaged over a cell",
        lower: "off: every shadow ray traverses the whole scene every frame",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "shadow_cache_samples",
        what: "static-only shadow rays a cache cell (per light) takes before its visibility is final",
        higher: "smoother cached soft shadows, more rays before a cell is filled",
        lower: "fewer rays, noisier cached visibility (1: a point light's cell keeps its first ray)",
        kind: ParamKind::Int { min: 1, max: 1024 },
        default: 16.0,
    },
    ParamSpec {
        name: "shadow_cache_cell",
        what: "edge of a cache cell in pixel footprints at the cell's distance (rounded to a power of two metres, so cells survive camera motion); the normal's dominant axis is part of the key",
        higher: "fewer cells, faster filling, blurrier and blockier static shadow edges",
        lower: "sharper cached edges, more cells to fill (more rays after camera motion)",
        kind: ParamKind::Float { min: 0.25, max: 64.0 },
        default: 2.0,
    },
];

/// Callisto's parameters and its parts' (reflections, the caches' light sampling).
pub const PARAMS: &[ParamSpec] = crate::param_table![
    OWN_PARAMS,
    // Off by default: Callisto alone is direct light (`gi = false`), which its tests compare
    // with the reference's direct light.
    crate::parts::reflections::params_off_by_default(),
    crate::parts::world_regir::PARAMS,
];

#[derive(Clone, Debug, PartialEq)]
pub struct CallistoSettings {
    pub rate: u32,
    pub range_cutoff: f32,
    pub tail_samples: u32,
    pub max_lights_per_tile: u32,
    pub cone_culling: bool,
    pub half_threshold: f32,
    pub full_threshold: f32,
    pub perceptual: f32,
    pub border_depth: f32,
    pub denoise: bool,
    pub max_history: f32,
    pub blur_radius: u32,
    pub accumulate: bool,
    pub gi: bool,
    /// Where ReSTIR GI's sample paths end (`gi_terminate`).
    pub gi_terminate: crate::parts::restir_gi::GiTerminate,
    /// `direct = "restir"`: the direct-light part replaces the tile shadows.
    pub direct_restir: bool,
    /// How the cache ReSTIR GI's paths end in lights its points (`cache_direct`).
    pub cache_light: crate::parts::world_regir::WorldRegirSettings,
    /// `reflections = "traced"`.
    pub reflections: bool,
    /// The reflections part's settings.
    pub reflection: crate::parts::reflections::ReflectionSettings,
    pub static_shadow_cache: bool,
    pub shadow_cache_samples: u32,
    pub shadow_cache_cell: f32,
}

impl CallistoSettings {
    pub fn from_params(p: &Params) -> Self {
        CallistoSettings {
            rate: p.u32("rate"),
            range_cutoff: p.f32("range_cutoff"),
            tail_samples: p.u32("tail_samples"),
            max_lights_per_tile: p.u32("max_lights_per_tile"),
            cone_culling: p.bool("cone_culling"),
            half_threshold: p.f32("half_threshold"),
            full_threshold: p.f32("full_threshold"),
            perceptual: p.f32("perceptual"),
            border_depth: p.f32("border_depth"),
            denoise: p.bool("denoise"),
            max_history: p.f32("max_history"),
            blur_radius: p.u32("blur_radius"),
            accumulate: p.bool("accumulate"),
            gi: p.bool("gi"),
            gi_terminate: crate::parts::restir_gi::GiTerminate::from_index(p.u32("gi_terminate")),
            direct_restir: crate::parts::restir_direct::chosen(p),
            cache_light: crate::parts::world_regir::WorldRegirSettings::from_params(p),
            reflections: crate::parts::reflections::ReflectionSettings::from_params(p).0,
            reflection: crate::parts::reflections::ReflectionSettings::from_params(p).1,
            static_shadow_cache: p.bool("static_shadow_cache"),
            shadow_cache_samples: p.u32("shadow_cache_samples"),
            shadow_cache_cell: p.f32("shadow_cache_cell"),
        }
    }
}
