//! ReSTIR DI, a part of [`RestirLighting`]: initial candidates per light class resampled into
//! reservoirs with temporal reuse (`initial_temporal`), then spatial reuse (`spatial`). Its
//! final reservoirs (`gilab::restir::reservoirs`, this frame's segment) hold one light sample per
//! pixel with its contribution weight W; a shading pass turns them into direct light with one
//! visibility ray (`contribution`, `visible`). Shaders: shaders/parts/restir/{initial_temporal,spatial}.wgsl.

use super::lighting::{PassFiles, PassPair, RestirLighting};
use super::{CandidateVisibility, RestirSettings};
use crate::render::{pipelines, PassInfo};
use crate::scene::features::SceneFeatures;

/// Bytes of `Reservoir` in shaders/parts/restir/shared.wgsl.
pub const RESERVOIR_BYTES: u64 = 32;
const INITIAL: &str = "initial_temporal";
const SPATIAL: &str = "spatial";

/// Which light classes the scene has (rule 3: a class it lacks gets no candidates).
#[derive(Clone, Copy, Debug, Default)]
pub struct LightClasses {
    pub local: usize,
    pub directional: usize,
    pub sky: bool,
    /// Emissive triangles: the local lights a ray can hit (BSDF-sampled candidates find
    /// nothing else).
    pub emissive: usize,
    /// The lowest roughness of a specular lobe in the scene (none: no lobe).
    pub min_specular_roughness: Option<f32>,
}

impl LightClasses {
    pub fn of(f: &SceneFeatures) -> Self {
        LightClasses {
            local: f.emissive_triangle_count + f.point_lights + f.spot_lights,
            directional: f.directional_lights,
            sky: f.sky_visible,
            emissive: f.emissive_triangle_count,
            min_specular_roughness: f.min_specular_roughness,
        }
    }
}

/// BSDF-sampled candidates a glossy pixel draws (rule 3): none where no ray can find an
/// emitter (the local lights are all point or spot lights) or no surface is glossy enough
/// (no specular lobe below `bsdf_candidates_max_roughness`).
pub fn bsdf_candidates_for(s: &RestirSettings, c: &LightClasses) -> u32 {
    let glossy = c
        .min_specular_roughness
        .is_some_and(|r| r < s.bsdf_max_roughness);
    if c.emissive > 0 && glossy {
        s.bsdf_candidates
    } else {
        0
    }
}

/// Why a scene draws no BSDF-sampled candidates although `bsdf_candidates` asks for them.
fn bsdf_candidates_skipped(s: &RestirSettings, c: &LightClasses) -> Option<&'static str> {
    if s.bsdf_candidates == 0 || bsdf_candidates_for(s, c) > 0 {
        None
    } else if c.emissive == 0 {
        Some(" (no BSDF-sampled candidates: no emissive triangle for a ray to find)")
    } else {
        Some(" (no BSDF-sampled candidates: no surface below bsdf_candidates_max_roughness)")
    }
}

/// `initial_temporal`, then `spatial`.
pub(super) const PASSES: PassFiles = [
    (INITIAL, "parts/restir/initial_temporal.wgsl"),
    (SPATIAL, "parts/restir/spatial.wgsl"),
];

#[derive(Default)]
pub struct Di {
    pub(super) passes: PassPair,
    /// Three segments of reservoirs: final of even frames, final of odd frames, temporal output.
    pub(super) reservoirs: Option<wgpu::Buffer>,
}

impl Di {
    pub(super) fn build_resources(&mut self, gpu: &crate::gpu::Gpu, pixels: u64, keep: bool) {
        if !keep || self.reservoirs.is_none() {
            self.reservoirs = Some(pipelines::storage_buffer(
                gpu,
                "restir reservoirs",
                3 * pixels * RESERVOIR_BYTES,
            ));
        }
    }

    pub(super) fn reset(&self, enc: &mut wgpu::CommandEncoder) {
        if let Some(r) = &self.reservoirs {
            enc.clear_buffer(r, 0, None);
        }
    }
}

impl RestirLighting {
    /// Candidates per frame of each class (local, directional, sky) as dispatched: 0 for a
    /// class the scene lacks; in single-pool mode all lights are "local" and the sky has none.
    pub(super) fn class_candidates(&self) -> [u32; 3] {
        candidates_for(&self.settings, &self.classes)
    }

    pub(super) fn has_direct_sources(&self) -> bool {
        self.class_candidates().iter().any(|&n| n > 0)
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

    pub fn di_passes(&self, f: &SceneFeatures) -> [PassInfo; 2] {
        let s = &self.settings;
        let lights = candidates_for(s, &LightClasses::of(f))
            .iter()
            .any(|&n| n > 0);
        let no_lights = || "no emissive triangles, punctual lights or reachable sky".to_string();
        [
            PassInfo {
                name: INITIAL,
                runs: lights,
                why: if lights {
                    format!(
                        "{}; temporal reuse {}",
                        candidate_summary(s, f),
                        if s.temporal { "on" } else { "off" }
                    )
                } else {
                    no_lights()
                },
            },
            PassInfo {
                name: SPATIAL,
                runs: lights,
                why: if !lights {
                    no_lights()
                } else if s.spatial_count == 0 {
                    "spatial_count = 0: copies the temporal result only".into()
                } else {
                    format!(
                        "{} neighbours within {} px, {}",
                        s.spatial_count,
                        s.spatial_radius,
                        if s.unbiased {
                            "unbiased (1/Z)"
                        } else {
                            "biased (M weights)"
                        }
                    )
                },
            },
        ]
    }
}

/// Candidates per frame of each class for a scene with these classes.
pub fn candidates_for(s: &RestirSettings, c: &LightClasses) -> [u32; 3] {
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

/// What the initial candidates are drawn from, class by class, and what is skipped and why.
fn candidate_summary(s: &RestirSettings, f: &SceneFeatures) -> String {
    let c = LightClasses::of(f);
    let [local, directional, sky] = candidates_for(s, &c);
    let source = if s.regir && f.many_lights {
        "ReGIR cell"
    } else if s.light_tree && s.light_classes {
        "by the light tree"
    } else {
        "by power"
    };
    // BSDF-sampled candidates join the local class where the pixel's ReGIR cell does not serve.
    let bsdf = if let Some(why) = bsdf_candidates_skipped(s, &c) {
        why.to_string()
    } else if bsdf_candidates_for(s, &c) > 0 {
        format!(
            " + {} BSDF-sampled (a ray each through the light tree) at pixels of roughness below {}{}, balance-heuristic MIS",
            s.bsdf_candidates,
            s.bsdf_max_roughness,
            if s.regir && f.many_lights {
                " outside the ReGIR grid"
            } else {
                ""
            }
        )
    } else {
        String::new()
    };
    if !s.light_classes {
        return format!(
            "one pool (light_classes = false): {local} candidates from {} lights {source}{bsdf}, sky only through GI rays",
            c.local + c.directional
        );
    }
    let mut parts = Vec::new();
    parts.push(if local > 0 {
        format!(
            "local: {local} candidates over {} lights {source}{bsdf}",
            c.local
        )
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
    parts.push(if sky > 0 && f.environment.is_some() {
        format!(
            "sky: {sky} candidate directions from BSDF, cosine and {} sampling",
            f.sky_label()
        )
    } else if sky > 0 {
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Rule 3 for BSDF-sampled candidates: drawn only where a ray can find an emitter and some
    /// surface is glossy enough to draw them; the pass list says why they are not.
    #[test]
    fn bsdf_candidates_run_only_where_a_ray_can_find_an_emitter_on_a_glossy_surface() {
        let mut s = RestirSettings::from_params(&crate::render::params::Params::new(
            "restir",
            super::super::PARAMS,
        ));
        s.bsdf_candidates = 2;
        s.bsdf_max_roughness = 0.5;
        let classes = |emissive: usize, points: usize, rough: Option<f32>| LightClasses {
            local: emissive + points,
            directional: 0,
            sky: false,
            emissive,
            min_specular_roughness: rough,
        };
        assert_eq!(bsdf_candidates_for(&s, &classes(8, 0, Some(0.1))), 2);
        assert_eq!(bsdf_candidates_for(&s, &classes(8, 4, Some(0.49))), 2);
        // Point lights only: a ray finds nothing.
        let points = classes(0, 4, Some(0.1));
        assert_eq!(bsdf_candidates_for(&s, &points), 0);
        assert!(bsdf_candidates_skipped(&s, &points)
            .unwrap()
            .contains("emissive"));
        // No surface below the roughness limit, or no specular lobe at all.
        let rough = classes(8, 0, Some(0.5));
        assert_eq!(bsdf_candidates_for(&s, &rough), 0);
        assert!(bsdf_candidates_skipped(&s, &rough)
            .unwrap()
            .contains("roughness"));
        assert_eq!(bsdf_candidates_for(&s, &classes(8, 0, None)), 0);
        // Not asked for: nothing to explain.
        s.bsdf_candidates = 0;
        assert_eq!(bsdf_candidates_for(&s, &classes(8, 0, Some(0.1))), 0);
        assert!(bsdf_candidates_skipped(&s, &classes(0, 4, Some(0.1))).is_none());
    }
}
