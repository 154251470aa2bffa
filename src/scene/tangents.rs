//! Per-vertex tangents for normal mapping: MikkTSpace (through `bevy_mikktspace`, a port of the
//! reference implementation), as glTF asks for when a file gives a normal texture but no TANGENT.
//!
//! Convention (glTF's): tangent xyz follows +U; the bitangent is `w * cross(normal, tangent)`
//! and points along the image's +Y, which is -V in glTF's UV space (V grows downward in the
//! image). MikkTSpace assumes V grows upward, so it is fed (u, 1 - v): the tangent is the same
//! either way and the sign comes out as glTF means it (as Blender's exporter does, whose
//! MikkTSpace runs on V-up UVs before V is flipped for the file). A vertex MikkTSpace leaves
//! without a tangent (degenerate geometry or UVs) gets zero: "unknown", no normal mapping.

use super::Scene;
use glam::{Vec2, Vec3, Vec4};

struct Mesh<'a> {
    positions: &'a [Vec3],
    normals: &'a [Vec3],
    uvs: &'a [Vec2],
    triangles: &'a [[u32; 3]],
    out: Vec<Vec4>,
}

impl Mesh<'_> {
    fn vertex(&self, face: usize, vert: usize) -> usize {
        self.triangles[face][vert] as usize
    }
}

impl bevy_mikktspace::Geometry for Mesh<'_> {
    fn num_faces(&self) -> usize {
        self.triangles.len()
    }
    fn num_vertices_of_face(&self, _face: usize) -> usize {
        3
    }
    fn position(&self, face: usize, vert: usize) -> [f32; 3] {
        self.positions[self.vertex(face, vert)].to_array()
    }
    fn normal(&self, face: usize, vert: usize) -> [f32; 3] {
        self.normals[self.vertex(face, vert)].to_array()
    }
    fn tex_coord(&self, face: usize, vert: usize) -> [f32; 2] {
        let uv = self.uvs[self.vertex(face, vert)];
        [uv.x, 1.0 - uv.y]
    }
    fn set_tangent(
        &mut self,
        tangent_space: Option<bevy_mikktspace::TangentSpace>,
        face: usize,
        vert: usize,
    ) {
        let v = self.vertex(face, vert);
        let t = tangent_space
            .map(|t| Vec4::from_array(t.tangent_encoded()))
            .filter(|t| t.is_finite() && t.truncate().length_squared() > 1e-12)
            .unwrap_or(Vec4::ZERO);
        // A vertex shared by triangles MikkTSpace splits (a UV seam with shared indices) gets
        // the last one written; loaders here unshare vertices per triangle, so this is rare.
        self.out[v] = t;
    }
}

/// MikkTSpace tangents per vertex of an indexed triangle mesh (xyz: unit tangent along +U,
/// w: bitangent sign, see the module doc); zero where none can be derived. Triangles with an
/// index out of range are left out.
pub fn generate(
    positions: &[Vec3],
    normals: &[Vec3],
    uvs: &[Vec2],
    triangles: &[[u32; 3]],
) -> Vec<Vec4> {
    let n = positions.len();
    let valid: Vec<[u32; 3]>;
    let triangles = if triangles
        .iter()
        .flatten()
        .all(|&i| (i as usize) < n.min(normals.len()).min(uvs.len()))
    {
        triangles
    } else {
        let m = n.min(normals.len()).min(uvs.len());
        valid = triangles
            .iter()
            .copied()
            .filter(|t| t.iter().all(|&i| (i as usize) < m))
            .collect();
        &valid
    };
    let mut mesh = Mesh {
        positions,
        normals,
        uvs,
        triangles,
        out: vec![Vec4::ZERO; n],
    };
    if !triangles.is_empty() {
        // The error type has no variants: generation cannot fail.
        let _ = bevy_mikktspace::generate_tangents(&mut mesh);
    }
    mesh.out
}

/// Fills `scene.tangents` when it is empty and some material has a normal texture: MikkTSpace
/// over the triangles of normal-mapped materials (with each one's UV set), zero elsewhere.
/// Scenes without normal maps are left without tangents.
pub fn ensure_scene_tangents(scene: &mut Scene) {
    if !scene.tangents.is_empty() {
        return;
    }
    let uses = |set: u32| {
        let mut tris = Vec::new();
        for (t, &m) in scene.triangles.iter().zip(&scene.triangle_material) {
            let nt = scene
                .materials
                .get(m as usize)
                .and_then(|m| m.normal_texture);
            if nt.is_some_and(|r| r.tex_coord == set) {
                tris.push(*t);
            }
        }
        tris
    };
    let (set0, set1) = (uses(0), uses(1));
    if set0.is_empty() && set1.is_empty() {
        return;
    }
    let n = scene.positions.len();
    let mut tangents = vec![Vec4::ZERO; n];
    for (set, tris) in [(0u32, set0), (1, set1)] {
        if tris.is_empty() {
            continue;
        }
        let uvs = if set == 0 { &scene.uvs } else { &scene.uvs1 };
        if uvs.len() != n {
            log::warn!(
                "{} triangles use a normal map on UV set {set}, which the scene lacks: no tangents for them",
                tris.len()
            );
            continue;
        }
        let t = generate(&scene.positions, &scene.normals, uvs, &tris);
        for tri in &tris {
            for &v in tri {
                tangents[v as usize] = t[v as usize];
            }
        }
    }
    scene.tangents = tangents;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{Material, TextureRef};

    /// Quad in the XZ plane (normal +Y) with u along +X and v along +Z; `mirror_u` runs u along -X.
    fn quad(mirror_u: bool) -> (Vec<Vec3>, Vec<Vec3>, Vec<Vec2>, Vec<[u32; 3]>) {
        let p = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(0.0, 0.0, 1.0),
            Vec3::new(1.0, 0.0, 1.0),
            Vec3::new(1.0, 0.0, 0.0),
        ];
        let uv = p
            .iter()
            .map(|p| Vec2::new(if mirror_u { 1.0 - p.x } else { p.x }, p.z))
            .collect();
        // Counter-clockwise seen from +Y.
        (p, vec![Vec3::Y; 4], uv, vec![[0, 1, 2], [0, 2, 3]])
    }

    #[test]
    fn flat_quad_tangent_follows_u_and_sign_gives_image_up() {
        let (p, n, uv, tris) = quad(false);
        let t = generate(&p, &n, &uv, &tris);
        for (i, t) in t.iter().enumerate() {
            assert!((t.truncate() - Vec3::X).length() < 1e-5, "vertex {i}: {t}");
            assert_eq!(t.w, 1.0, "vertex {i}: {t}");
            // The bitangent points to decreasing v (the image's +Y in glTF): -Z here.
            let b = t.w * Vec3::Y.cross(t.truncate());
            assert!(
                (b - Vec3::NEG_Z).length() < 1e-5,
                "vertex {i}: bitangent {b}"
            );
        }
    }

    #[test]
    fn mirrored_uvs_flip_the_sign() {
        let (p, n, uv, tris) = quad(true);
        let t = generate(&p, &n, &uv, &tris);
        for (i, t) in t.iter().enumerate() {
            assert!(
                (t.truncate() - Vec3::NEG_X).length() < 1e-5,
                "vertex {i}: {t}"
            );
            assert_eq!(t.w, -1.0, "vertex {i}: {t}");
            let b = t.w * Vec3::Y.cross(t.truncate());
            assert!(
                (b - Vec3::NEG_Z).length() < 1e-5,
                "vertex {i}: bitangent {b}"
            );
        }
    }

    #[test]
    fn degenerate_uvs_give_zero_and_bad_indices_are_skipped() {
        let (p, n, _, tris) = quad(false);
        let t = generate(&p, &n, &[Vec2::ZERO; 4], &tris);
        assert!(t.iter().all(|t| *t == Vec4::ZERO), "{t:?}");
        let t = generate(&p, &n, &[Vec2::ZERO; 4], &[[0, 1, 9]]);
        assert_eq!(t.len(), 4);
    }

    #[test]
    fn scene_tangents_only_for_normal_mapped_materials() {
        let mut s = Scene::new("t");
        let plain = s.add_material(Material::lambert("plain", Vec3::ONE));
        let mapped = s.add_material(Material {
            normal_texture: Some(TextureRef::new(0)),
            ..Material::lambert("mapped", Vec3::ONE)
        });
        let v = Vec3::new;
        s.add_quad(
            v(0., 0., 0.),
            v(0., 0., 1.),
            v(1., 0., 1.),
            v(1., 0., 0.),
            plain,
        );
        ensure_scene_tangents(&mut s);
        assert!(s.tangents.is_empty(), "no normal map: no tangents");
        s.add_quad(
            v(0., 0., 0.),
            v(0., 0., 1.),
            v(1., 0., 1.),
            v(1., 0., 0.),
            mapped,
        );
        ensure_scene_tangents(&mut s);
        assert_eq!(s.tangents.len(), s.positions.len());
        assert!(s.tangents[..6].iter().all(|t| *t == Vec4::ZERO));
        assert!(s.tangents[6..]
            .iter()
            .all(|t| t.truncate().length() > 0.99 && t.w.abs() == 1.0));
    }
}
