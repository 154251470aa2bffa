//! ReSTIR's parameters: the declared table (docs, ranges, defaults), the typed settings made
//! from it, and the uniform the passes read.

use crate::parts::gi_cache::{CacheKind, CACHES};
use crate::render::params::{ParamKind, ParamSpec, Params};

/// Spatial neighbours per pixel at most (`MAX_NEIGHBOURS` in the spatial passes).
pub const MAX_SPATIAL: u32 = 8;

/// Matches `RestirParams` in shaders/parts/restir/shared.wgsl.
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
    /// 1: GI sample directions cosine-sampled (`gi_sampling = "cosine"`); 0: by the BSDF.
    pub gi_cosine: u32,
    pub path_light_candidates: u32,
    pub specular_bounces: u32,
    pub specular_max_roughness: f32,
    /// 1: the local class's initial candidates by the light tree (`light_tree`).
    pub light_tree: u32,
    /// BSDF-sampled candidates of the local class at glossy pixels (`bsdf_candidates`).
    pub bsdf_candidates: u32,
    /// Roughness below which a pixel draws them (`bsdf_candidates_max_roughness`).
    pub bsdf_max_roughness: f32,
    /// 1: ReGIR's cell slots draw their candidates by the light tree (`regir_fill = "tree"`).
    pub regir_tree: u32,
    pub pad_b: u32,
}

/// ReSTIR's parameters: docs, ranges and defaults in one place (the talk's defaults: 8 initial
/// candidates, max history 8, a few spatial neighbours).
/// ReSTIR's own parameters; [`PARAMS`] adds the caches' light sampling (`cache_direct`, for the
/// cache a GI sample path ends in).
const OWN_PARAMS: &[ParamSpec] = &[
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
        what: "initial RIS candidates per pixel per frame from the sky: directions from an equal mix of BSDF and cosine sampling (with an environment map: BSDF 1/4, cosine 1/4, the map's luminance importance sampling 1/2), merged with the other classes (unused when the sky is black or out of reach)",
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
        what: "unbiased contribution weights: generalized balance-heuristic MIS over the unshadowed targets of the merged reservoirs' surfaces in DI's temporal and spatial reuse and GI's spatial reuse (1/Z in GI's temporal merge); no candidate visibility tests",
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
        name: "gi_sampling",
        what: "how a GI sample path's first direction is drawn at the pixel: by the BSDF (its diffuse and GGX lobes mixed by the specular weight, as the reference samples: glossy surfaces sample what they reflect; a mirror's sample is its own pixel's, never reused) or cosine-weighted over the hemisphere (diffuse only)",
        higher: "cosine: the glossy lobe is found by chance (fireflies and speckle on metal)",
        lower: "bsdf: the glossy lobe is sampled where it reflects",
        kind: ParamKind::Choice(&["bsdf", "cosine"]),
        default: 0.0,
    },
    ParamSpec {
        name: "gi_terminate",
        what: "where a GI sample path ends: path (traced to gi_bounces), or at its first hit (hit gi_bounces with a cache) in a radiance cache that holds the further bounces, built and updated in the same frame: lumen-cards (Lumen's surface cache; the seed's connection), lumen-world (Lumen's world radiance cache seen from the hit: one BSDF ray to the probes' TMin, the surface cache where it hits, the world probes past it) surfels (the surfels' irradiance where surfels cover the hit, the path traced on where none do) hash-cache (the spatially hashed radiance cache's cell where the last segment is longer than the cell and the cell has samples, traced on elsewhere) or ambient (NEE at the hit plus a constant ambient irradiance, pi x the sky's mean radiance, unoccluded: the baseline that says what the other caches' bounces are worth)",
        higher: "a cache: multi-bounce light at the price of one ray per path, biased by the cache (coarse texels or surfels, diffuse only, lag; lumen-cards: no light where no card covers a hit)",
        lower: "path: unbiased with gi_bounces = 0, every bounce traced",
        kind: ParamKind::Choice(&GiTerminate::NAMES),
        default: 0.0,
    },
    ParamSpec {
        name: "path_light_candidates",
        what: "light candidates resampled (RIS by unshadowed contribution, ReSTIR DI's initial sampling without reuse) for the one shadow ray at each hit of a GI sample path, the seed's light loop along specular paths; 1 = one light by the pool's pdf, as the reference samples",
        higher: "lights that matter at a hit are found (many lights, glossy hits), more shading work, no extra rays",
        lower: "1: one light by power, noisier where many lights or a glossy lobe pick few of them",
        kind: ParamKind::Int { min: 1, max: 64 },
        default: 8.0,
    },
    ParamSpec {
        name: "specular_bounces",
        what: "specular hits (roughness below specular_max_roughness) a GI sample path goes through past the hit where it would end (a cache, or gi_bounces): the seed's multi-bounce specular paths (funhouse mirrors: three bounces), each lit by path_light_candidates; unused by paths traced to the end (gi_bounces = 0, path)",
        higher: "reflections of reflections instead of a diffuse cache's guess at a mirror or glossy hit, one more ray and shadow ray per specular hit",
        lower: "0: the path ends at its first hit whatever it hit (a mirror seen in a mirror shows the cache's diffuse light)",
        kind: ParamKind::Int { min: 0, max: 8 },
        default: 3.0,
    },
    ParamSpec {
        name: "specular_max_roughness",
        what: "roughness below which a hit counts as specular for specular_bounces",
        higher: "glossier-than-this surfaces are traced through too (more rays)",
        lower: "only near-mirrors are traced through",
        kind: ParamKind::Float { min: 0.0, max: 1.0 },
        default: 0.3,
    },
    ParamSpec {
        name: "cache_atlas_size",
        what: "texels per side of the surface cache's atlas when gi_terminate = lumen-cards (Lumen's atlas_size)",
        higher: "finer cache lighting, more texels to update per frame",
        lower: "coarser and cheaper cache",
        kind: ParamKind::Int { min: 128, max: 4096 },
        default: 512.0,
    },
    ParamSpec {
        name: "cache_update",
        what: "fraction of the surface cache's texels whose direct and indirect light are relit each frame when gi_terminate = lumen-cards (each bounce of the cache's feedback needs a full update)",
        higher: "the cache follows light changes and gathers bounces sooner, more cache rays per frame",
        lower: "cheaper frames, the cache lags (and holds fewer bounces after a change)",
        kind: ParamKind::Float { min: 0.01, max: 1.0 },
        default: 0.25,
    },
    ParamSpec {
        name: "cache_ray_budget",
        what: "surfel rays per frame of the surfel cache when gi_terminate = surfels (the surfels' ray_budget)",
        higher: "the cache converges and follows changes sooner, more cache rays per frame",
        lower: "cheaper frames, noisier and laggier cache irradiance",
        kind: ParamKind::Int { min: 256, max: 16_000_000 },
        default: 65536.0,
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
        name: "light_tree",
        what: "pick lights by the light tree (parts::light_tree: one descent, importance at the point and its normal) instead of by power: DI's initial candidates of the local class (ReGIR's cells take precedence where ReGIR runs; light_classes must be on) and the NEE at every vertex of GI's sample paths (their passes composed with LIGHT_TREE)",
        higher: "on: candidates near and facing the point without a build pass; a tree walk per candidate",
        lower: "off: candidates by power (or ReGIR's cells)",
        kind: ParamKind::Bool,
        default: 0.0,
    },
    ParamSpec {
        name: "bsdf_candidates",
        what: "BSDF-sampled initial candidates of the local class at glossy pixels (roughness below bsdf_candidates_max_roughness), a ray each to the emitter it finds, combined with the light-sampled candidates by the balance heuristic (seed 003's light BVH for specular: a glossy lobe finds the small lights its highlight shows, which light sampling rarely picks); not where the pixel's ReGIR cell serves the candidates",
        higher: "highlights of small lights found sooner on glossy surfaces, a candidate ray each",
        lower: "0: light-sampled candidates only",
        kind: ParamKind::Int { min: 0, max: 8 },
        default: 0.0,
    },
    ParamSpec {
        name: "bsdf_candidates_max_roughness",
        what: "roughness below which a pixel draws BSDF-sampled candidates (bsdf_candidates)",
        higher: "rougher surfaces draw them too (their lobe is wide: light sampling does well there)",
        lower: "only near-mirror surfaces draw them",
        kind: ParamKind::Float { min: 0.0, max: 1.0 },
        default: 0.5,
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
    ParamSpec {
        name: "regir_fill",
        what: "how ReGIR's cell slots draw their 32 candidates from the local lights: by power, or by the light tree's importance for the cell's bounding ball (boxes grown by its half-diagonal, no normal: a light that can light some point of the cell keeps a non-zero pmf, so the slots stay unbiased)",
        higher: "tree: candidates near the cell, fewer wasted on far lights; a tree walk per candidate",
        lower: "power: one table lookup per candidate, most candidates far from the cell in a large scene",
        kind: ParamKind::Choice(&["power", "tree"]),
        default: 0.0,
    },
];

/// ReSTIR's parameters and the world ReGIR part's (the caches its GI paths may end in).
pub const PARAMS: &[ParamSpec] = crate::param_table![OWN_PARAMS, crate::parts::world_regir::PARAMS];

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
    pub fn from_index(i: u32) -> Self {
        match i {
            0 => Self::Off,
            2 => Self::Merged,
            _ => Self::PerClass,
        }
    }
}

/// Where a ReSTIR GI sample path ends (`gi_terminate`): traced to `gi_bounces` (`"path"`,
/// index 0; unbounded is unbiased), or in one of the registered caches
/// ([`crate::parts::gi_cache::CACHES`], from index 1) at the path's last hit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GiTerminate(usize);

impl GiTerminate {
    pub const PATH: GiTerminate = GiTerminate(0);
    /// `"path"`, then every registered cache's name.
    pub const NAMES: [&'static str; CACHES.len() + 1] = names();

    pub fn from_index(i: u32) -> Self {
        Self(if (i as usize) < Self::NAMES.len() {
            i as usize
        } else {
            0
        })
    }

    pub fn name(self) -> &'static str {
        Self::NAMES[self.0]
    }

    /// The cache the path ends in, if any.
    pub fn kind(self) -> Option<&'static CacheKind> {
        self.0.checked_sub(1).map(|k| &CACHES[k])
    }

    /// Whether the path ends in a cache (one that is built).
    pub fn cache(self) -> bool {
        self.kind().is_some()
    }
}

const fn names() -> [&'static str; CACHES.len() + 1] {
    let mut out = ["path"; CACHES.len() + 1];
    let mut k = 0;
    while k < CACHES.len() {
        out[k + 1] = CACHES[k].name;
        k += 1;
    }
    out
}

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
    /// GI sample directions cosine-sampled instead of by the BSDF (`gi_sampling = "cosine"`).
    pub gi_cosine: bool,
    pub gi_terminate: GiTerminate,
    /// Light candidates resampled at each hit of a GI sample path.
    pub path_light_candidates: u32,
    /// Specular hits a GI sample path goes through past its end, and what counts as specular.
    pub specular_bounces: u32,
    pub specular_max_roughness: f32,
    pub cache_atlas_size: u32,
    pub cache_update: f32,
    pub cache_ray_budget: u32,
    /// How the cache a GI path ends in lights its points (`cache_direct` and the clipmap's sizes).
    pub cache_light: crate::parts::world_regir::WorldRegirSettings,
    /// Use ReGIR when the scene has many lights.
    pub regir: bool,
    /// Local candidates by the light tree (where ReGIR does not run).
    pub light_tree: bool,
    /// `regir_fill = "tree"`: ReGIR's slots draw candidates by the light tree.
    pub regir_tree: bool,
    /// BSDF-sampled local candidates at glossy pixels, and the roughness that counts as glossy.
    pub bsdf_candidates: u32,
    pub bsdf_max_roughness: f32,
    /// Cell edge in world units; 0 = automatic (scene diagonal / 24).
    pub regir_cell_size: f32,
    pub regir_lights_per_cell: u32,
}

impl RestirSettings {
    /// The settings the parameter table holds.
    pub fn from_params(p: &Params) -> Self {
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
            gi_cosine: p.u32("gi_sampling") == 1,
            gi_terminate: GiTerminate::from_index(p.u32("gi_terminate")),
            path_light_candidates: p.u32("path_light_candidates"),
            specular_bounces: p.u32("specular_bounces"),
            specular_max_roughness: p.f32("specular_max_roughness"),
            cache_atlas_size: p.u32("cache_atlas_size"),
            cache_update: p.f32("cache_update"),
            cache_ray_budget: p.u32("cache_ray_budget"),
            cache_light: crate::parts::world_regir::WorldRegirSettings::from_params(p),
            regir: p.bool("regir"),
            light_tree: p.bool("light_tree"),
            regir_tree: p.choice("regir_fill") == "tree",
            bsdf_candidates: p.u32("bsdf_candidates"),
            bsdf_max_roughness: p.f32("bsdf_candidates_max_roughness"),
            regir_cell_size: p.f32("regir_cell_size"),
            regir_lights_per_cell: p.u32("regir_lights_per_cell"),
        }
    }
}

impl RestirSettings {
    /// The cache parameters (`cache_atlas_size`, `cache_update`, `cache_ray_budget`,
    /// `cache_direct`), as a registered cache reads them.
    pub fn cache_settings(&self) -> crate::parts::gi_cache::CacheSettings {
        crate::parts::gi_cache::CacheSettings {
            atlas_size: self.cache_atlas_size,
            update: self.cache_update,
            ray_budget: self.cache_ray_budget,
            light: self.cache_light,
        }
    }

    /// Combinations that cannot run, as one line.
    pub fn check(&self) -> anyhow::Result<()> {
        Ok(())
    }
}

impl Default for RestirSettings {
    fn default() -> Self {
        RestirSettings::from_params(&Params::new("restir", PARAMS))
    }
}
