//! ReSTIR PT's parameters: the declared table, the typed settings and the uniform.

use crate::parts::restir::GiTerminate;
use crate::render::params::{ParamKind, ParamSpec, Params};

/// Spatial neighbours per pixel at most (`MAX_NEIGHBOURS` in shaders/restir_pt/spatial.wgsl).
pub const MAX_SPATIAL: u32 = 8;
/// GGX alpha below which a lobe is a mirror (`DELTA_ALPHA` in shaders/common/brdf.wgsl): a
/// reconnection needs a density on both sides, so no criterion goes below it.
const DELTA_ALPHA: f32 = 1e-3;

/// How paths move between pixels.
pub const SHIFTS: &[&str] = &["hybrid", "reconnection", "replay"];
/// Where direct light (paths of length 2) comes from.
pub const DIRECT: &[&str] = &["unified", "restir"];

pub const PARAMS: &[ParamSpec] = &[
    ParamSpec {
        name: "max_bounces",
        what: "path length as the reference's max_depth: NEE at the first max_bounces vertices, emitters hit up to one more (no Russian roulette: a shifted path keeps its length); compare with the reference at the same max_depth",
        higher: "less energy cut off (unbiased against the unbounded reference only in the limit), longer paths and replays",
        lower: "cheaper, darker where light needs many bounces",
        kind: ParamKind::Int { min: 1, max: 16 },
        default: 6.0,
    },
    ParamSpec {
        name: "shift",
        what: "shift mapping: hybrid (the paper's: random replay up to the first rough, distant vertex pair, reconnection there), reconnection (always at the first bounce where both ends are not mirrors: ReSTIR GI's shift inside ReSTIR PT), replay (random replay of the whole path)",
        higher: "hybrid: reuse through glossy chains where a reconnection would fail",
        lower: "reconnection: cheapest shift, fails on glossy first bounces; replay: works everywhere, costs a whole path per shift and decorrelates poorly",
        kind: ParamKind::Choice(SHIFTS),
        default: 0.0,
    },
    ParamSpec {
        name: "reconnection_roughness",
        what: "hybrid shift: roughness from which a vertex counts as rough enough to reconnect at (both x_{r-1} and x_r)",
        higher: "reconnection only on very rough vertices: more replay, more robust on glossy paths",
        lower: "reconnection on glossier vertices: cheaper, higher shift failure and variance there",
        kind: ParamKind::Float { min: 0.0, max: 1.0 },
        default: 0.2,
    },
    ParamSpec {
        name: "reconnection_distance",
        what: "hybrid shift: least distance between x_{r-1} and x_r, as a fraction of the scene's bounding-box diagonal (short segments have Jacobians that blow up: corners)",
        higher: "fewer reconnections near corners, more replay",
        lower: "reconnection at any distance: Jacobian outliers in corners",
        kind: ParamKind::Float { min: 0.0, max: 0.25 },
        default: 0.01,
    },
    ParamSpec {
        name: "temporal",
        what: "temporal reuse of last frame's path at the reprojected pixel (pairwise MIS, two shifts)",
        higher: "on: samples accumulate over frames",
        lower: "off: spatial reuse only",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: "max_history",
        what: "last frame's confidence M is clamped to max_history x the current one",
        higher: "longer memory: less noise on still views, more lag after changes",
        lower: "faster reaction, more noise",
        kind: ParamKind::Float {
            min: 1.0,
            max: 100.0,
        },
        default: 20.0,
    },
    ParamSpec {
        name: "spatial_count",
        what: "spatial neighbours per pixel (two shifts each: pairwise MIS)",
        higher: "more reuse, less noise, more shifts (rays)",
        lower: "cheaper; 0 = no spatial reuse",
        kind: ParamKind::Int {
            min: 0,
            max: MAX_SPATIAL as i64,
        },
        default: 3.0,
    },
    ParamSpec {
        name: "spatial_radius",
        what: "radius of the spatial-reuse disk (pixels)",
        higher: "samples from farther away: less correlated noise, more shift failures",
        lower: "closer neighbours: higher acceptance, blotchier",
        kind: ParamKind::Float {
            min: 1.0,
            max: 64.0,
        },
        default: 16.0,
    },
    ParamSpec {
        name: "spatial_pairs",
        what: "paired spatial reuse (ReSTIR PT Enhanced's reciprocal neighbours): the neighbours are p + d and p - d for spatial_count / 2 offsets d drawn per frame (the same at every pixel, rounded up to pairs), and each pair's two shifts are traced once (pass path_pairs) and read by both pixels",
        higher: "on: about half the spatial shifts (rays) for the same neighbour count; neighbours in the same pattern at every pixel in a frame",
        lower: "off: each pixel draws its own neighbours and traces two shifts per neighbour",
        kind: ParamKind::Bool,
        default: 0.0,
    },
    ParamSpec {
        name: "suffix_terminate",
        what: "where a path's suffix (its vertices past the reconnection vertex) ends: path (traced to max_bounces), or at the first suffix hit the named radiance cache covers (the caches of ReSTIR GI's gi_terminate, built and updated in the same frame at ReSTIR's cache defaults; hash-cache: where the segment is longer than the hit's cell and the cell has samples). Shifts reuse the suffix as traced, so it ends in the same cell in every pixel that reconnects to it; paths without a reconnection vertex (shift = replay) never end early",
        higher: "a cache: bounces past the first suffix hit cost no rays, biased by the cache (and a suffix reused from last frame keeps last frame's cache light)",
        lower: "path: every bounce traced, unbiased against the reference at the same max_depth",
        kind: ParamKind::Choice(&GiTerminate::NAMES),
        default: 0.0,
    },
    crate::parts::restir_direct::param(
        DIRECT,
        "direct light (paths of length 2): unified (in the path reservoirs) or restir (ReSTIR DI through the direct-light part; the path reservoirs then hold indirect light only)",
        "restir: ReSTIR DI's many-light sampling for direct light, one extra set of passes",
        "unified: one reservoir for all light, as RTXDI 3.0 and Solari move to",
    ),
    ParamSpec {
        name: "accumulate",
        what: "average every frame since the last reset (off: each frame alone, for real-time comparisons)",
        higher: "on: converges on a still view",
        lower: "off: one frame's noise",
        kind: ParamKind::Bool,
        default: 1.0,
    },
    ParamSpec {
        name: crate::techniques::DEBUG_VIEWS,
        what: "write the debug views (reconnection vertex, shift kind, failure rate, Jacobian, path length, M, W, target)",
        higher: "on: the viewer's debug views work",
        lower: "off: no debug writes (timed runs switch it off)",
        kind: ParamKind::Bool,
        default: 1.0,
    },
];

/// The parameters, typed.
#[derive(Clone, Debug, PartialEq)]
pub struct PtSettings {
    pub max_bounces: u32,
    pub shift: usize,
    pub reconnection_roughness: f32,
    pub reconnection_distance: f32,
    pub temporal: bool,
    pub max_history: f32,
    pub spatial_count: u32,
    pub spatial_radius: f32,
    pub spatial_pairs: bool,
    pub suffix_terminate: GiTerminate,
    pub direct_restir: bool,
    pub accumulate: bool,
    pub debug: bool,
}

impl PtSettings {
    pub fn from_params(p: &Params) -> PtSettings {
        PtSettings {
            max_bounces: p.u32("max_bounces"),
            shift: p.u32("shift") as usize,
            reconnection_roughness: p.f32("reconnection_roughness"),
            reconnection_distance: p.f32("reconnection_distance"),
            temporal: p.bool("temporal"),
            max_history: p.f32("max_history"),
            spatial_count: p.u32("spatial_count"),
            spatial_radius: p.f32("spatial_radius"),
            spatial_pairs: p.bool("spatial_pairs"),
            suffix_terminate: GiTerminate::from_index(p.u32("suffix_terminate")),
            direct_restir: crate::parts::restir_direct::chosen(p),
            accumulate: p.bool("accumulate"),
            debug: p.bool(crate::techniques::DEBUG_VIEWS),
        }
    }

    /// The reconnection criteria the shaders test: GGX alpha and world distance.
    pub fn criteria(&self, scene_diagonal: f32) -> (f32, f32) {
        match SHIFTS[self.shift] {
            // Nothing is rough enough: every shift replays.
            "replay" => (f32::MAX, 0.0),
            "reconnection" => (DELTA_ALPHA, 0.0),
            _ => (
                (self.reconnection_roughness * self.reconnection_roughness).max(DELTA_ALPHA),
                self.reconnection_distance * scene_diagonal,
            ),
        }
    }

    /// Offsets of paired spatial reuse (`spatial_pairs`; 0: off): half the neighbours,
    /// rounded up.
    pub fn pairs(&self) -> u32 {
        if self.spatial_pairs {
            self.spatial_count.min(MAX_SPATIAL).div_ceil(2)
        } else {
            0
        }
    }

    pub fn gpu(&self, pixels: u32, scene_diagonal: f32) -> PtParamsGpu {
        let (rc_alpha, rc_distance) = self.criteria(scene_diagonal);
        PtParamsGpu {
            max_bounces: self.max_bounces,
            temporal: self.temporal as u32,
            max_history: self.max_history,
            spatial_count: self.spatial_count.min(MAX_SPATIAL),
            spatial_radius: self.spatial_radius,
            rc_alpha,
            rc_distance,
            pixels,
            accumulate: self.accumulate as u32,
            direct_restir: self.direct_restir as u32,
            debug: self.debug as u32,
            pairs: self.pairs(),
        }
    }
}

/// Matches `PtParams` in shaders/restir_pt/shared.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct PtParamsGpu {
    pub max_bounces: u32,
    pub temporal: u32,
    pub max_history: f32,
    pub spatial_count: u32,
    pub spatial_radius: f32,
    pub rc_alpha: f32,
    pub rc_distance: f32,
    pub pixels: u32,
    pub accumulate: u32,
    pub direct_restir: u32,
    pub debug: u32,
    pub pairs: u32,
}
