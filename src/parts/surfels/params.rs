//! The surfel technique's parameters (one table: docs, ranges, defaults) and their GPU form.

use crate::render::params::{ParamKind, ParamSpec, Params};

/// Most rays one surfel takes in a frame: high enough that the first frames, with few surfels,
/// still spend the whole budget (the allocation scales requests both ways, as in the seed).
pub const MAX_RAYS_PER_SURFEL: u32 = 4096;

/// The surfels' own parameters; [`PARAMS`] adds the reflections part's.
const OWN_PARAMS: &[ParamSpec] = &[
    ParamSpec {
        name: "max_surfels",
        what: "size of the surfel pool, allocated up front (the seed's fixed budget)",
        higher: "room for more surfels (larger views, more distant detail), more memory",
        lower: "less memory; a full pool recycles out-of-view surfels sooner and leaves gaps",
        kind: ParamKind::Int {
            min: 1024,
            max: 1_000_000,
        },
        default: 131072.0,
    },
    ParamSpec {
        name: "ray_budget",
        what: "surfel rays per frame, shared among surfels in proportion to their requests (the viewer's ray-budget slider sets it)",
        higher: "faster convergence and reaction, more rays (each also traces a shadow ray at its hit)",
        lower: "cheaper frames, slower convergence, more lag",
        kind: ParamKind::Int {
            min: 0,
            max: 16_000_000,
        },
        default: 65536.0,
    },
    ParamSpec {
        name: "guiding",
        what: "ray guiding: once a surfel's 6x6 radiance map is populated, half its rays follow the map (mixed pdf, unbiased)",
        higher: "on: fewer rays wasted where little light comes from (one bright wall)",
        lower: "off: cosine sampling only",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "radial_depth",
        what: "radial Gaussian depth: per-surfel 4x4 map of mean and mean-square hit distance; gathers weight surfels by the Chebyshev bound",
        higher: "on: no light through thin walls from surfels on the other side",
        lower: "off: surfels light everything within their radius (leaks)",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "depth_test",
        what: "with radial_depth, how a surfel's depth texel weighs a point beyond the texel's mean hit distance: hidden (the mean as a shadow map's depth), or by the seed's Chebyshev bound (as DDGI), which lets a point just behind a thin wall through when the texel also holds open directions",
        higher: "chebyshev: the seed's soft test, light reaches a little past occluders (thin-wall leak 0.047 over 8 frames at the test's set-up)",
        lower: "hard: a point past the mean is hidden (leak 0.016 there); points past a partial occluder in the same texel lose that surfel",
        kind: ParamKind::Choice(&["hard", "chebyshev"]),
        default: 0.0,
    },
    ParamSpec {
        name: "msme",
        what: "multiscale mean estimator: short-term mean and variance steer the long-term mean's blend",
        higher: "on: reacts within a few frames to a light change, still converges when nothing changes",
        lower: "off: plain running mean over every ray (converges, but lags behind any change)",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "irradiance_sharing",
        what: "the seed's irradiance sharing: a surfel's frame estimate is blended with its grid neighbours' (gather weights: footprint, normal, radial depth; by ray count) as much as its own estimate is uncertain, before the estimator",
        higher: "on: less blotchy noise while surfels are young, a little blur between neighbours",
        lower: "off: each surfel integrates its own rays only",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    crate::parts::restir_direct::param(
        &["nee", "restir"],
        "direct light per pixel: next-event estimation of one light by power, or ReSTIR DI (its passes with GI off)",
        "restir: far less noise with many lights (ReGIR where the scene has them), more passes",
        "nee: one shadow ray, no extra passes",
    ),
    ParamSpec {
        name: "apply_resolution",
        what: "where pixels gather the surfels: once per 2x2 block, upsampled per pixel by depth and normal (the seed's quarter-area apply; a pixel no block sample matches gathers itself), or at every pixel",
        higher: "full: every pixel gathers (sharper at edges, about 4x the gather work)",
        lower: "quarter: a quarter of the gathers, irradiance upsampled across smooth surfaces",
        kind: ParamKind::Choice(&["quarter", "full"]),
        default: 0.0,
    },
    ParamSpec {
        name: "coverage_target",
        what: "surfel weight a tile's least-covered pixel must reach before spawning stops there",
        higher: "denser surfels: smoother, sharper irradiance, more surfels to feed",
        lower: "sparser surfels: fewer rays per area covered, blotchier",
        kind: ParamKind::Float {
            min: 0.1,
            max: 8.0,
        },
        default: 1.0,
    },
    ParamSpec {
        name: "surfel_size",
        what: "surfel radius as a fraction of the image height (constant on screen: surfels shrink as the camera approaches)",
        higher: "fewer, larger surfels: blurrier irradiance, fewer surfels per pixel to gather",
        lower: "more, smaller surfels: finer detail, more surfels and gathers",
        kind: ParamKind::Float {
            min: 0.002,
            max: 0.2,
        },
        default: 0.02,
    },
    ParamSpec {
        name: "ray_binning",
        what: "the seed's ray binning: rays sorted by their surfel's grid cell (12 bits) and direction (4 bits) before they are traced; the results do not change, only the order rays run in",
        higher: "on: coherent rays (a win on hardware ray tracing in the seed), two more passes and a prefix sum over 65,536 bins",
        lower: "off: rays run in surfel order",
        kind: ParamKind::Bool,
        default: 0.0,
    },
    ParamSpec {
        name: "spawn_tiles",
        what: "the screen tiles that each spawn at most one surfel a frame (at the tile's least-covered pixel): `16` is 16x16 pixels at any image size, as the seed; `scaled` (a departure from the seed) keeps the seed's tile for its surfel size at 1080p (16 pixels against the default surfel's 21.6-pixel radius) at any image and surfel size, a power of two from 1 to 16 pixels",
        higher: "scaled: a small image covers in a few frames (at 128², 64 times the spawns a frame), with many more surfels and fewer rays each (docs/surfels.md)",
        lower: "16: the seed's spawn; an image smaller than 1080p covers slowly (a 64x64 image spawns 16 surfels a frame)",
        kind: ParamKind::Choice(&["16", "scaled"]),
        default: 0.0,
    },
    ParamSpec {
        name: "uncovered_hits",
        what: "what a surfel ray's hit that no surfel covers (off screen, or not yet spawned) reads: `path` traces on (NEE, BSDF sampling, Russian roulette; unbiased there), `hash-cache` reads the hash radiance cache where the segment is longer than the hit's cell and the cell has samples (parts::hash_cache at its defaults, updated by its own paths each frame), else the path",
        higher: "hash-cache: no shadow ray or path at most uncovered hits; the cache's update paths are traced instead, and its cells' blur and lag are added",
        lower: "path: every uncovered hit traces a path (most of the surfels' indirect rays)",
        kind: ParamKind::Choice(&["path", "hash-cache"]),
        default: 0.0,
    },
    ParamSpec {
        name: "accumulate",
        what: "average frames into the output (off: each frame alone, the real-time view)",
        higher: "on: a static view converges (the per-pixel direct light averages out)",
        lower: "off: what a game would show each frame",
        kind: ParamKind::Bool,
        default: 1.0,
    },
];

/// The surfels' parameters and their parts' (reflections, the ray hits' light sampling).
pub const PARAMS: &[ParamSpec] = crate::param_table![
    OWN_PARAMS,
    crate::parts::reflections::PARAMS,
    crate::parts::world_regir::PARAMS,
];

/// The parameters, typed.
#[derive(Clone, Debug, PartialEq)]
pub struct SurfelSettings {
    pub max_surfels: u32,
    pub ray_budget: u32,
    pub guiding: bool,
    pub radial_depth: bool,
    /// `depth_test = "hard"`: a point beyond its depth texel's mean distance is hidden.
    pub hard_depth_test: bool,
    pub msme: bool,
    pub sharing: bool,
    /// `apply_resolution = "quarter"`.
    pub quarter_apply: bool,
    pub direct_restir: bool,
    pub coverage_target: f32,
    pub surfel_size: f32,
    /// Rays sorted into bins before tracing (`ray_binning`).
    pub ray_binning: bool,
    /// `spawn_tiles = "scaled"`: spawn tiles in proportion to the surfels' size on screen.
    pub scaled_spawn_tiles: bool,
    /// `uncovered_hits = "hash-cache"`: uncovered ray hits read the hash radiance cache.
    pub uncovered_in_hash_cache: bool,
    pub accumulate: bool,
    /// `reflections = "traced"`.
    pub reflections: bool,
    /// The reflections part's settings.
    pub reflection: crate::parts::reflections::ReflectionSettings,
    /// How surfel ray hits pick their lights (`cache_direct`).
    pub cache_light: crate::parts::world_regir::WorldRegirSettings,
}

/// The seed's spawn tile (16 pixels) over its surfels' radius in pixels at 1080p (the default
/// `surfel_size` 0.02 of 1,080 rows): the ratio `spawn_tiles = "scaled"` keeps.
const SEED_TILE_PER_RADIUS: f64 = 16.0 / (0.02 * 1080.0);

impl SurfelSettings {
    /// Side in pixels of the screen tiles that each spawn at most one surfel a frame, for an
    /// image `height` pixels high: 16 (`spawn_tiles = "16"`, the seed's), or the power of two
    /// nearest to the seed's tile for this surfel size and height (`"scaled"`: 16 at 1080p with
    /// the default size; 2 at 128², 1 at 64²).
    pub fn spawn_tile(&self, height: u32) -> u32 {
        if !self.scaled_spawn_tiles {
            return 16;
        }
        let px = SEED_TILE_PER_RADIUS * self.surfel_size as f64 * height as f64;
        let log2 = px.max(1.0).log2().round().clamp(0.0, 4.0);
        1 << log2 as u32
    }

    pub fn from_params(p: &Params) -> Self {
        SurfelSettings {
            max_surfels: p.u32("max_surfels"),
            ray_budget: p.u32("ray_budget"),
            guiding: p.bool("guiding"),
            radial_depth: p.bool("radial_depth"),
            hard_depth_test: p.u32("depth_test") == 0,
            msme: p.bool("msme"),
            sharing: p.bool("irradiance_sharing"),
            quarter_apply: p.u32("apply_resolution") == 0,
            direct_restir: crate::parts::restir_direct::chosen(p),
            coverage_target: p.f32("coverage_target"),
            surfel_size: p.f32("surfel_size"),
            ray_binning: p.bool("ray_binning"),
            scaled_spawn_tiles: p.u32("spawn_tiles") == 1,
            uncovered_in_hash_cache: p.u32("uncovered_hits") == 1,
            accumulate: p.bool("accumulate"),
            reflections: crate::parts::reflections::ReflectionSettings::from_params(p).0,
            reflection: crate::parts::reflections::ReflectionSettings::from_params(p).1,
            cache_light: crate::parts::world_regir::WorldRegirSettings::from_params(p),
        }
    }
}

/// `SurfelParams` of shaders/parts/surfels/shared.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct SurfelParamsGpu {
    pub max_surfels: u32,
    pub ray_budget: u32,
    pub ray_capacity: u32,
    pub flags: u32,
    pub coverage_target: f32,
    pub surfel_size: f32,
    pub grid_half_extent: f32,
    pub tiles_x: u32,
    pub tiles: u32,
    pub cells: u32,
    pub max_rays_per_surfel: u32,
    /// Side of a spawn tile in pixels (1, 2, 4, 8 or 16; `SurfelSettings::spawn_tile`).
    pub spawn_tile: u32,
}

pub const FLAG_GUIDING: u32 = 1;
pub const FLAG_RADIAL_DEPTH: u32 = 2;
pub const FLAG_MSME: u32 = 4;
pub const FLAG_SKY: u32 = 8;
pub const FLAG_ACCUMULATE: u32 = 16;
/// Pixels add the reflections part's specular light.
pub const FLAG_REFLECTIONS: u32 = 32;
/// Cache-only mode (`SurfelCore::surfel_cache`): apply marks the surfels the pixels see (what
/// recycling keeps) and writes no pixel.
pub const FLAG_CACHE_ONLY: u32 = 64;
/// Irradiance sharing between neighbouring surfels before the estimator.
pub const FLAG_SHARING: u32 = 128;
/// Quarter-area apply: `apply gather` gathers once per 2x2 block, apply upsamples.
pub const FLAG_QUARTER_APPLY: u32 = 256;
/// The trace pass runs its rays in bin order (`ray_binning`).
pub const FLAG_BINNING: u32 = 512;
/// With radial depth: a point past its depth texel's mean is hidden (`depth_test = "hard"`).
pub const FLAG_HARD_DEPTH: u32 = 1024;
