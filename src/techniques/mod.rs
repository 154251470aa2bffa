//! GI techniques, one folder each (with a matching folder under `shaders/`). They meet only at
//! the shared inputs (scene, frame uniforms and counters, primary surfaces) and at their linear
//! HDR output. The registry below is the one table a new technique is added to.

pub mod callisto_shadows;
pub mod ddgi;
pub mod hash_cache;
pub mod lumen;
pub mod reference;
pub mod restir;
pub mod restir_pt;
pub mod surfels;

use crate::render::{params, Technique};
use anyhow::Result;

/// A registered technique: its preset id, a one-line description, and how to make one.
pub struct TechniqueInfo {
    pub id: &'static str,
    pub what: &'static str,
    pub create: fn() -> Box<dyn Technique>,
}

pub const REGISTRY: &[TechniqueInfo] = &[
    TechniqueInfo {
        id: "reference",
        what: "progressive unbiased path tracer (ground truth)",
        create: || Box::new(reference::ReferencePathTracer::default()),
    },
    TechniqueInfo {
        id: "restir",
        what: "ReSTIR DI + GI: resampled direct light (light classes, ReGIR) and indirect light, with temporal and spatial reuse",
        create: || Box::new(restir::Restir::default()),
    },
    TechniqueInfo {
        id: "restir-pt",
        what: "ReSTIR PT (GRIS): whole paths resampled per pixel with the hybrid shift (random replay, then reconnection at the first rough, distant vertex pair), temporal and spatial reuse with pairwise MIS",
        create: || Box::new(restir_pt::RestirPt::default()),
    },
    TechniqueInfo {
        id: "surfels",
        what: "surfel GI (GIBS): G-buffer-spawned surfels in a non-linear grid integrate irradiance with guided, budgeted rays (multiscale mean estimator, radial Gaussian depth)",
        create: || Box::new(surfels::Surfels::default()),
    },
    TechniqueInfo {
        id: "lumen",
        what: "Lumen-style GI: global distance field clipmaps and surface cache cards (direct + multi-bounce indirect through feedback), rays traced through the SDF or the BVH; final gather by screen probes (screen traces first, world radiance cache optional) or per pixel",
        create: || Box::new(lumen::Lumen::default()),
    },
    TechniqueInfo {
        id: "callisto-shadows",
        what: "Callisto Protocol ray-traced shadows: one shadow ray per light per pixel from 16x16 tile light lists (depth-bounds and cone culling), variable rate per light and 2x2 quad with bilateral reconstruction, power-sampled tail rays for the lights outside the list, temporally accumulated shadow mask of the punctual lights; optional ReSTIR GI for indirect light",
        create: || Box::new(callisto_shadows::CallistoShadows::default()),
    },
    TechniqueInfo {
        id: "hash-cache",
        what: "spatially hashed radiance cache (SHaRC-style): one path per pixel from its primary surface, ending in a world-space hash grid of cells (position, facing, a level by camera distance) where its footprint is wider than the cell; the cells are averaged from full update paths of one pixel in 25",
        create: || Box::new(hash_cache::HashCacheTechnique::default()),
    },
    TechniqueInfo {
        id: "ddgi",
        what: "DDGI irradiance probes (Majercik et al. 2019/2021): a camera-following probe grid (cascades) traces rotated ray sets each frame into octahedral irradiance and distance maps with hysteresis; probes relocate out of walls and switch off where useless; pixels gather from 8 probes with Chebyshev visibility; multi-bounce through the probes",
        create: || Box::new(ddgi::Ddgi::default()),
    },
];

pub fn create_technique(name: &str) -> Result<Box<dyn Technique>> {
    match REGISTRY.iter().find(|t| t.id == name) {
        Some(t) => Ok((t.create)()),
        None => {
            let names: Vec<&str> = REGISTRY.iter().map(|t| t.id).collect();
            anyhow::bail!(
                "unknown technique '{name}' (available: {})",
                names.join(", ")
            )
        }
    }
}

/// The entry as timed runs (`bench --preset`, `converge`) render it: work done only for the
/// viewer's debug views (`debug_views`, where a technique has it) is switched off unless the
/// preset sets it, so that no technique's frame time carries work the others do not do.
pub fn entry_for_timing(entry: &crate::preset::TechniqueEntry) -> crate::preset::TechniqueEntry {
    let mut timed = entry.clone();
    let has_debug_work = REGISTRY
        .iter()
        .find(|t| t.id == entry.name)
        .is_some_and(|t| {
            (t.create)()
                .param_set()
                .specs()
                .iter()
                .any(|s| s.name == DEBUG_VIEWS)
        });
    if has_debug_work && !timed.params.contains_key(DEBUG_VIEWS) {
        timed
            .params
            .insert(DEBUG_VIEWS.into(), toml::Value::Boolean(false));
    }
    timed
}

/// The parameter that switches debug-only work on (on by default, for the viewer).
pub const DEBUG_VIEWS: &str = "debug_views";

/// Every technique's parameter table in Markdown (`gilab params`; docs/parameters.md).
pub fn params_markdown() -> String {
    let mut out = String::new();
    for t in REGISTRY {
        out += &format!(
            "### `{}`: {}\n\n{}\n",
            t.id,
            t.what,
            params::markdown_table((t.create)().param_set().specs())
        );
    }
    out
}
