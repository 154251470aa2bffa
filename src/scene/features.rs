//! SceneFeatures: what effects a scene calls for, computed once on load. Techniques turn it into
//! the list of passes they dispatch and skip (rule 3: simulate only what the scene needs).

use super::{bvh::Bvh, PunctualKind, Scene};
use glam::Vec3;
use serde::Serialize;

/// Roughness below which a surface counts as glossy (needs reflection work).
pub const GLOSSY_ROUGHNESS: f32 = 0.5;
/// More light sources than this call for many-light structures (ReGIR, light trees).
pub const MANY_LIGHTS: usize = 64;

#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct SceneFeatures {
    pub triangle_count: usize,
    pub emissive_triangle_count: usize,
    /// Sum over emissive triangles of pi * area * luminance(Le) (x2 if double-sided), in W.
    pub emissive_power: f32,
    pub point_lights: usize,
    pub spot_lights: usize,
    pub directional_lights: usize,
    /// Lowest roughness among materials with a specular lobe (metallic > 0 or specular > 0); None if no lobe.
    pub min_specular_roughness: Option<f32>,
    pub has_glossy: bool,
    pub has_mirror: bool,
    /// Sky radiance is non-zero and probe rays from the camera reach it.
    pub sky_visible: bool,
    /// Size of the environment map that is the sky (None: the constant sky).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub environment: Option<[u32; 2]>,
    pub texture_count: usize,
    pub textured_materials: usize,
    /// Materials rays may pass through (alpha mask, or blend traced as a mask): traversal runs
    /// the any-hit alpha test on their triangles only.
    pub alpha_tested_materials: usize,
    pub normal_mapped_materials: usize,
    pub many_lights: bool,
    pub bounds_min: [f32; 3],
    pub bounds_max: [f32; 3],
    pub bvh_nodes: usize,
    pub bvh_depth: usize,
    /// Instances traced through a two-level BVH (0: flat) and their distinct meshes.
    pub bvh_instances: usize,
    pub bvh_instanced_meshes: usize,
}

impl SceneFeatures {
    pub fn light_count(&self) -> usize {
        self.emissive_triangle_count
            + self.point_lights
            + self.spot_lights
            + self.directional_lights
    }
    pub fn has_emissive(&self) -> bool {
        self.emissive_triangle_count > 0
    }
    /// "environment map WxH" when the sky is an environment map, "sky" otherwise.
    pub fn sky_label(&self) -> String {
        match self.environment {
            Some([w, h]) => format!("environment map {w}x{h}"),
            None => "sky".into(),
        }
    }
    pub fn has_punctual(&self) -> bool {
        self.point_lights + self.spot_lights + self.directional_lights > 0
    }

    pub fn compute(scene: &Scene, bvh: &Bvh, tris: &[[Vec3; 3]]) -> SceneFeatures {
        let mut f = SceneFeatures {
            triangle_count: scene.triangles.len(),
            ..Default::default()
        };
        for (i, t) in tris.iter().enumerate() {
            let m = &scene.materials[scene.triangle_material[i] as usize];
            let lum = luminance(m.emissive);
            let area = 0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length();
            if lum > 0.0 && area > 0.0 {
                f.emissive_triangle_count += 1;
                f.emissive_power +=
                    std::f32::consts::PI * area * lum * if m.double_sided { 2.0 } else { 1.0 };
            }
        }
        for l in &scene.lights {
            match l.kind {
                PunctualKind::Point => f.point_lights += 1,
                PunctualKind::Spot => f.spot_lights += 1,
                PunctualKind::Directional => f.directional_lights += 1,
            }
        }
        let used: std::collections::BTreeSet<u32> =
            scene.triangle_material.iter().copied().collect();
        for &mi in &used {
            let m = &scene.materials[mi as usize];
            // A metallic-roughness texture scales the roughness factor by its G channel.
            let roughness = m.roughness
                * m.metallic_roughness_texture
                    .and_then(|r| scene.textures.get(r.texture))
                    .map_or(1.0, |t| {
                        t.rgba8.chunks_exact(4).map(|c| c[1]).min().unwrap_or(255) as f32 / 255.0
                    });
            let metal_texture = m.metallic_roughness_texture.is_some();
            if m.metallic > 0.0 || m.specular > 0.0 || metal_texture {
                f.min_specular_roughness = Some(
                    f.min_specular_roughness
                        .map_or(roughness, |r: f32| r.min(roughness)),
                );
            }
            if m.texture_refs().iter().any(|(_, t)| t.is_some()) {
                f.textured_materials += 1;
            }
            f.alpha_tested_materials += m.alpha_tested() as usize;
            f.normal_mapped_materials += m.normal_texture.is_some() as usize;
        }
        f.has_glossy = f
            .min_specular_roughness
            .is_some_and(|r| r < GLOSSY_ROUGHNESS);
        f.has_mirror = f.min_specular_roughness.is_some_and(|r| r * r < 1e-3);
        f.texture_count = scene.textures.len();
        f.many_lights = f.light_count() > MANY_LIGHTS;
        let (lo, hi) = scene.bounds();
        f.bounds_min = lo.to_array();
        f.bounds_max = hi.to_array();
        f.bvh_nodes = bvh.nodes.len();
        f.bvh_depth = bvh.depth;
        f.bvh_instances = bvh.instances;
        f.bvh_instanced_meshes = bvh.instanced_meshes;
        // The environment map's mean radiance (intensity included) when there is one.
        f.sky_visible = scene.sky_mean().max_element() > 0.0 && sky_reachable(scene, bvh, tris);
        f.environment = scene.environment.as_ref().map(|e| [e.width(), e.height()]);
        f
    }

    /// One line per fact, for `gilab shot --verbose` and the viewer.
    pub fn summary(&self) -> String {
        format!(
            "triangles {}, emissive triangles {} ({:.3} W), point/spot/directional lights {}/{}/{}, \
             min specular roughness {}, glossy {}, mirror {}, {} visible {}, textures {} ({} materials, {} alpha-tested, {} normal-mapped), many lights {}, BVH {} nodes depth {}{}",
            self.triangle_count,
            self.emissive_triangle_count,
            self.emissive_power,
            self.point_lights,
            self.spot_lights,
            self.directional_lights,
            self.min_specular_roughness.map_or("none".into(), |r| format!("{r:.3}")),
            self.has_glossy,
            self.has_mirror,
            self.sky_label(),
            self.sky_visible,
            self.texture_count,
            self.textured_materials,
            self.alpha_tested_materials,
            self.normal_mapped_materials,
            self.many_lights,
            self.bvh_nodes,
            self.bvh_depth,
            if self.bvh_instances > 0 {
                format!(
                    " (two levels: {} instances of {} meshes)",
                    self.bvh_instances, self.bvh_instanced_meshes
                )
            } else {
                String::new()
            }
        )
    }
}

pub fn luminance(c: Vec3) -> f32 {
    c.dot(Vec3::new(0.2126, 0.7152, 0.0722))
}

/// Casts a fixed set of directions from the camera and from one bounce off what it sees; the
/// sky counts as visible if any escapes the geometry.
fn sky_reachable(scene: &Scene, bvh: &Bvh, tris: &[[Vec3; 3]]) -> bool {
    let cam = scene.default_camera();
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    let n = 512;
    let dirs: Vec<Vec3> = (0..n)
        .map(|i| {
            let y = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
            let r = (1.0 - y * y).max(0.0).sqrt();
            let phi = golden * i as f32;
            Vec3::new(r * phi.cos(), y, r * phi.sin())
        })
        .collect();
    for d in &dirs {
        match bvh.closest_hit(tris, cam.position, *d, f32::MAX) {
            None => return true,
            Some((t, _)) => {
                let p = cam.position + *d * t * 0.999;
                for d2 in dirs.iter().step_by(37) {
                    if bvh.closest_hit(tris, p, *d2, f32::MAX).is_none() {
                        return true;
                    }
                }
            }
        }
    }
    false
}
