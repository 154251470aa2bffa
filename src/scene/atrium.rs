//! `atrium`: a large procedural scene in the layout of the classic Sponza atrium, for scale
//! (load, BVH build and tracing of a million triangles) and for the material features glTF
//! scenes bring (textures, normal maps, alpha masks): a long open courtyard between two
//! storeys of arcades (finely tessellated columns, round arches, gallery slabs, brick back
//! walls), a tiled floor, cloth panels hanging between the upper columns, a repeated vase on
//! every pier of the gallery, 64 small lamps along the arcades, a sun and a sky. `detail`
//! scales the tessellation (1.0: 1,234,560 triangles) and the texture size.
//!
//! **Textures** are generated here, deterministically (same bytes on every run and machine:
//! integer hashing and periodic value noise, no files read), and [`write_textures`] bakes them
//! to PNG for a look or for use elsewhere. Twelve RGBA8 textures, [`texture_size`] square
//! (512 px at detail >= 1, down to 64 px at the CI detail 0.05), listed in [`TEXTURES`]:
//! floor tiles (base colour with per-tile colour, marble veins and grout; a normal map of
//! the grout grooves and bevelled tile edges; metallic-roughness with per-tile roughness and
//! rough grout), brick (base, normal: recessed mortar joints), plaster for the gallery
//! ceilings (base, normal), column stone (base with strata, normal: course joints and chisel
//! marks), cloth (a woven base colour whose alpha cuts a row of lace holes and a fringe:
//! `AlphaMode::Mask`, double-sided) and vase glaze (base, metallic-roughness: a glossy cobalt
//! glaze, gold bands that are metal, bare clay below a drip edge). UVs are continuous and
//! world-scaled on the tiling surfaces (floor 2 m per repeat, brick 1 m, plaster 2 m, stone
//! 1 m; columns wrap a whole number of repeats around), per panel on the cloth and once
//! around each vase. Normal maps follow glTF (+Y = image up, see `super::tangents`). The
//! tangents come analytically from the parametric patches (they agree with MikkTSpace's to a
//! fraction of a degree, tested; MikkTSpace over the million triangles took about 2 s on 2 cores, the
//! whole build without it well under a second); `super::tangents::ensure_scene_tangents` runs
//! last and would fill them if a patch gave none.
//!
//! **Instances**: the columns (one mesh per storey), arches, vases and lamp spheres are the
//! same mesh repeated at different places; [`build`] records which triangles and vertices
//! belong to which repeat ([`Instance`]: prototype, translation, ranges) and lists them as the
//! scene's [`MeshInstance`]s, so the BVH has one bottom-level tree per prototype and a top
//! level over the 184 repeats (`super::instancing`).

use super::builtin::add_uv_sphere;
use super::{
    AlphaMode, Camera, Material, MeshInstance, PunctualKind, PunctualLight, Scene, Texture,
    TextureRef,
};
use anyhow::{Context, Result};
use glam::{Vec2, Vec3, Vec4};
use rayon::prelude::*;
use std::f32::consts::{PI, TAU};
use std::path::Path;

/// The generated textures in `Scene::textures` order (also the PNG names of
/// [`write_textures`]). `*_base` are sRGB colours (alpha: the cloth's mask), `*_normal` linear
/// tangent-space normal maps, `*_mr` linear metallic-roughness (G roughness, B metallic).
pub const TEXTURES: [&str; 12] = [
    "floor_base",
    "floor_normal",
    "floor_mr",
    "brick_base",
    "brick_normal",
    "plaster_base",
    "plaster_normal",
    "stone_base",
    "stone_normal",
    "cloth_base",
    "vase_base",
    "vase_mr",
];
const FLOOR_BASE: usize = 0;
const FLOOR_NORMAL: usize = 1;
const FLOOR_MR: usize = 2;
const BRICK_BASE: usize = 3;
const BRICK_NORMAL: usize = 4;
const PLASTER_BASE: usize = 5;
const PLASTER_NORMAL: usize = 6;
const STONE_BASE: usize = 7;
const STONE_NORMAL: usize = 8;
const CLOTH_BASE: usize = 9;
const VASE_BASE: usize = 10;
const VASE_MR: usize = 11;

/// World metres per texture repeat (one UV unit) of the tiling textures.
const FLOOR_M: f32 = 2.0;
const BRICK_M: f32 = 1.0;
const PLASTER_M: f32 = 2.0;
const STONE_M: f32 = 1.0;

/// Courtyard 32 m long (x), 12 m wide (z), storeys 5 m; 13 columns a side and storey.
const LEN: f32 = 32.0;
const WIDTH: f32 = 12.0;
const STOREY: f32 = 5.0;
const COLUMNS: usize = 13;
const SPACING: f32 = LEN / (COLUMNS - 1) as f32;
/// A cloth panel's size in metres (before its sag): the texture maps once onto it.
const CLOTH_W: f32 = SPACING - 0.9;
const CLOTH_H: f32 = 2.6;

/// Texture width and height at a detail: 512 at detail >= 1, halving with the square root of
/// the detail (a power of two), at least 64 (detail 0.05).
pub fn texture_size(detail: f32) -> u32 {
    let d = detail.clamp(0.02, 4.0);
    let s = ((512.0 * d.sqrt()) as u32).max(1);
    (1u32 << (31 - s.leading_zeros())).clamp(64, 512)
}

/// One repeat of a mesh that occurs several times in the scene: its triangles
/// `first_triangle..first_triangle + triangle_count` (and vertices likewise) are the
/// prototype's, moved by `translation` (the same vertex order, UVs and normals; positions
/// equal to rounding).
#[derive(Clone, Debug, PartialEq)]
pub struct Instance {
    /// "column lower", "column upper", "arch", "vase" or "lamp".
    pub prototype: &'static str,
    pub translation: Vec3,
    pub first_triangle: u32,
    pub triangle_count: u32,
    pub first_vertex: u32,
    pub vertex_count: u32,
}

/// The atrium and its repeated meshes.
pub struct Atrium {
    pub scene: Scene,
    pub instances: Vec<Instance>,
}

/// The atrium scene (see the module doc).
pub fn atrium(detail: f32) -> Scene {
    build(detail).scene
}

/// Writes the generated textures at full size (detail 1) as `DIR/atrium_NAME.png` (names in
/// [`TEXTURES`]); returns the paths.
pub fn write_textures(dir: &Path) -> Result<Vec<std::path::PathBuf>> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let mut paths = Vec::new();
    for (name, t) in TEXTURES.iter().zip(textures(1.0)) {
        let path = dir.join(format!("atrium_{name}.png"));
        image::save_buffer(
            &path,
            &t.rgba8,
            t.width,
            t.height,
            image::ExtendedColorType::Rgba8,
        )
        .with_context(|| format!("writing {}", path.display()))?;
        paths.push(path);
    }
    Ok(paths)
}

// ---------------------------------------------------------------------------------------------
// Geometry

/// A smooth parametric patch: `f(u, v)` gives (position, normal, texture coordinate) for u, v in
/// [0, 1]; `nu` x `nv` quads. Triangles are wound so their geometric normal agrees with the
/// given normals.
fn add_patch(
    s: &mut Scene,
    nu: u32,
    nv: u32,
    material: u32,
    f: impl Fn(f32, f32) -> (Vec3, Vec3, Vec2),
) {
    let base = s.positions.len() as u32;
    for j in 0..=nv {
        for i in 0..=nu {
            let (u, v) = (i as f32 / nu as f32, j as f32 / nv as f32);
            let (p, n, uv) = f(u, v);
            s.positions.push(p);
            s.normals.push(n.normalize_or_zero());
            s.uvs.push(uv);
        }
    }
    let idx = |i: u32, j: u32| base + j * (nu + 1) + i;
    // Tangents for normal-mapped patches, from the grid: dP/du_tex and dP/dv_tex solved from the
    // neighbours' position and UV differences (central, one-sided at the border), in glTF's
    // convention (see `super::tangents`: xyz along +u, w * N x T towards -v). They agree with
    // MikkTSpace (tested) at a fraction of its cost (about 2 s for the million triangles).
    if s.materials[material as usize].normal_texture.is_some() {
        s.tangents.resize(base as usize, Vec4::ZERO);
        for j in 0..=nv {
            for i in 0..=nu {
                let (i0, i1, j0, j1) = (
                    i.saturating_sub(1),
                    (i + 1).min(nu),
                    j.saturating_sub(1),
                    (j + 1).min(nv),
                );
                let at =
                    |a: u32, b: u32| (s.positions[idx(a, b) as usize], s.uvs[idx(a, b) as usize]);
                let ((pa, ua), (pb, ub)) = (at(i0, j), at(i1, j));
                let ((pc, uc), (pd, ud)) = (at(i, j0), at(i, j1));
                let (dp1, dp2, d1, d2) = (pb - pa, pd - pc, ub - ua, ud - uc);
                let det = d1.x * d2.y - d1.y * d2.x;
                let n = s.normals[idx(i, j) as usize];
                let t = if det.abs() > 1e-12 {
                    let dpdu = (dp1 * d2.y - dp2 * d1.y) / det;
                    let dpdv = (dp2 * d1.x - dp1 * d2.x) / det;
                    let t = (dpdu - n * n.dot(dpdu)).normalize_or_zero();
                    let w = if n.cross(t).dot(dpdv) <= 0.0 {
                        1.0
                    } else {
                        -1.0
                    };
                    if t == Vec3::ZERO {
                        Vec4::ZERO
                    } else {
                        t.extend(w)
                    }
                } else {
                    Vec4::ZERO
                };
                s.tangents.push(t);
            }
        }
    }
    // Winding from the patch's middle quad: flip if its geometric normal opposes the given one.
    let (mi, mj) = (nu / 2, nv / 2);
    let p = |k: u32| s.positions[k as usize];
    let g = (p(idx(mi + 1, mj)) - p(idx(mi, mj))).cross(p(idx(mi, mj + 1)) - p(idx(mi, mj)));
    let flip = g.dot(s.normals[idx(mi, mj) as usize]) < 0.0;
    for j in 0..nv {
        for i in 0..nu {
            let (a, b, c, d) = (idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1));
            let (t0, t1) = if flip {
                ([a, c, b], [a, d, c])
            } else {
                ([a, b, c], [a, c, d])
            };
            s.triangles.push(t0);
            s.triangles.push(t1);
            s.triangle_material.push(material);
            s.triangle_material.push(material);
        }
    }
}

/// Whole texture repeats around a circle of this radius (so the seam at u = 0/1 tiles).
fn repeats_around(radius: f32, metres: f32) -> f32 {
    (TAU * radius / metres).round().max(1.0)
}

/// A column standing at `at`: shaft with a slight entasis and flutes, base and capital as wider
/// drums. UVs: whole stone repeats around, height in metres from the foot (so every column of
/// a height is the same mesh moved).
fn add_column(s: &mut Scene, at: Vec3, height: f32, radius: f32, segs: u32, rings: u32, m: u32) {
    let around = repeats_around(radius, STONE_M);
    let shaft = |u: f32, v: f32| {
        let a = u * TAU;
        let flute = 1.0 + 0.03 * (a * 16.0).cos();
        let r = radius * flute * (1.0 - 0.12 * v * v);
        let dir = Vec3::new(a.cos(), 0.0, a.sin());
        let y = 0.1 * height + 0.8 * height * v;
        (
            at + dir * r + Vec3::Y * y,
            dir,
            Vec2::new(u * around, -y / STONE_M),
        )
    };
    add_patch(s, segs, rings, m, shaft);
    for (y0, y1, r) in [(0.0, 0.1, 1.35), (0.9, 1.0, 1.45)] {
        let around = repeats_around(radius * r, STONE_M);
        let drum = move |u: f32, v: f32| {
            let a = u * TAU;
            let dir = Vec3::new(a.cos(), 0.0, a.sin());
            let y = height * (y0 + (y1 - y0) * v);
            (
                at + dir * radius * r + Vec3::Y * y,
                dir,
                Vec2::new(u * around, -y / STONE_M),
            )
        };
        add_patch(s, segs, (rings / 8).max(1), m, drum);
    }
}

/// A round arch between two column tops: the intrados (inner half-cylinder surface) and the
/// two faces of the wall above it, from `a` to `a + span` (horizontal), `depth` thick along
/// `across`.
/// UVs in metres from `a`: along the intrados the stone's course joints run across it like
/// voussoirs; the faces are mapped flat (x, -y).
#[allow(clippy::too_many_arguments)]
fn add_arch(
    s: &mut Scene,
    a: Vec3,
    span: Vec3,
    across: Vec3,
    depth: f32,
    top: f32,
    segs: u32,
    m: u32,
) {
    let half = span * 0.5;
    let r = half.length();
    let along = half / r;
    // Local offsets from `a` (so every arch of a span is the same mesh moved).
    let local = move |t: f32| half - along * r * (t * PI).cos() + Vec3::Y * r * (t * PI).sin();
    let intrados = move |u: f32, v: f32| {
        let l = local(u);
        let n = (half - l).normalize_or_zero(); // towards the arch's centre (down into the opening)
        (
            a + l + across * depth * (v - 0.5),
            n,
            Vec2::new(depth * (v - 0.5), u * PI * r) / STONE_M,
        )
    };
    add_patch(s, segs, 4, m, intrados);
    for side in [-0.5f32, 0.5] {
        let face = move |u: f32, v: f32| {
            let l = local(u);
            let wall = Vec3::new(l.x, half.y + top, l.z);
            let q = l.lerp(wall, v);
            (
                a + q + across * depth * side,
                across * side.signum(),
                Vec2::new(q.dot(along), -q.y) / STONE_M,
            )
        };
        add_patch(s, segs, 4, m, face);
    }
}

/// Runs `add`, recording the triangles and vertices it appended as one instance.
fn instance(
    s: &mut Scene,
    out: &mut Vec<Instance>,
    prototype: &'static str,
    translation: Vec3,
    add: impl FnOnce(&mut Scene),
) {
    let (t0, v0) = (s.triangles.len() as u32, s.positions.len() as u32);
    add(s);
    out.push(Instance {
        prototype,
        translation,
        first_triangle: t0,
        triangle_count: s.triangles.len() as u32 - t0,
        first_vertex: v0,
        vertex_count: s.positions.len() as u32 - v0,
    });
}

fn tex(i: usize) -> Option<TextureRef> {
    Some(TextureRef::new(i))
}

/// The atrium with its instance records (see the module doc).
pub fn build(detail: f32) -> Atrium {
    let d = detail.clamp(0.02, 4.0);
    // Textures (parallel, deterministic) while the geometry is generated.
    let (textures, (mut s, instances)) = rayon::join(|| textures(d), || geometry(d));
    s.textures = textures;
    // The patches gave their tangents; MikkTSpace fills them if none were given.
    if !s.tangents.is_empty() {
        s.tangents.resize(s.positions.len(), Vec4::ZERO);
    }
    super::tangents::ensure_scene_tangents(&mut s);
    // The repeats as mesh instances: one mesh per prototype (numbered by first appearance).
    let mut prototypes: Vec<&str> = Vec::new();
    s.instances = instances
        .iter()
        .map(|i| {
            let mesh = match prototypes.iter().position(|&p| p == i.prototype) {
                Some(k) => k,
                None => {
                    prototypes.push(i.prototype);
                    prototypes.len() - 1
                }
            };
            MeshInstance {
                mesh: mesh as u32,
                transform: glam::Mat4::from_translation(i.translation),
                first_triangle: i.first_triangle,
                triangle_count: i.triangle_count,
            }
        })
        .collect();
    Atrium {
        scene: s,
        instances,
    }
}

fn geometry(d: f32) -> (Scene, Vec<Instance>) {
    let q = |n: f32| ((n * d.sqrt()).round() as u32).max(2);
    let mut s = Scene::new("atrium");
    let mut inst = Vec::new();
    let v = Vec3::new;
    let stone = s.add_material(Material {
        base_color_texture: tex(STONE_BASE),
        normal_texture: tex(STONE_NORMAL),
        ..Material::glossy("stone", Vec3::ONE, 0.0, 0.75)
    });
    // Factors 1: the metallic-roughness texture holds the values (glTF multiplies).
    let floor = s.add_material(Material {
        base_color_texture: tex(FLOOR_BASE),
        normal_texture: tex(FLOOR_NORMAL),
        metallic_roughness_texture: tex(FLOOR_MR),
        ..Material::glossy("floor tiles", Vec3::ONE, 1.0, 1.0)
    });
    let plaster = s.add_material(Material {
        base_color_texture: tex(PLASTER_BASE),
        normal_texture: tex(PLASTER_NORMAL),
        ..Material::lambert("plaster", Vec3::ONE)
    });
    let brick = s.add_material(Material {
        base_color_texture: tex(BRICK_BASE),
        normal_texture: tex(BRICK_NORMAL),
        ..Material::glossy("brick", Vec3::ONE, 0.0, 0.85)
    });
    let cloth = |name: &str, colour: Vec3| Material {
        base_color_texture: tex(CLOTH_BASE),
        alpha_mode: AlphaMode::Mask,
        alpha_cutoff: 0.5,
        double_sided: true,
        ..Material::lambert(name, colour)
    };
    let cloths = [
        s.add_material(cloth("cloth red", v(0.75, 0.1, 0.08))),
        s.add_material(cloth("cloth green", v(0.14, 0.5, 0.2))),
        s.add_material(cloth("cloth blue", v(0.1, 0.2, 0.65))),
    ];
    let vase = s.add_material(Material {
        base_color_texture: tex(VASE_BASE),
        metallic_roughness_texture: tex(VASE_MR),
        ..Material::glossy("vase glaze", Vec3::ONE, 1.0, 1.0)
    });
    let lamp = s.add_material(Material::emitter("lamp", v(40.0, 30.0, 18.0)));

    let (len, width, storey, spacing) = (LEN, WIDTH, STOREY, SPACING);
    add_patch(&mut s, q(420.0), q(160.0), floor, |u, w| {
        let p = v(
            -len * 0.5 - 2.0 + (len + 4.0) * u,
            0.0,
            -width * 0.5 - 4.0 + (width + 8.0) * w,
        );
        (p, Vec3::Y, Vec2::new(p.x, p.z) / FLOOR_M)
    });
    for side in [-1.0f32, 1.0] {
        let z = side * width * 0.5;
        let across = v(0.0, 0.0, 1.0);
        for level in 0..2 {
            let y = level as f32 * storey;
            let (h, name) = if level == 0 {
                (storey - 1.2, "column lower")
            } else {
                (storey - 1.6, "column upper")
            };
            for c in 0..COLUMNS {
                let x = -len * 0.5 + c as f32 * spacing;
                let at = v(x, y, z);
                instance(&mut s, &mut inst, name, at, |s| {
                    add_column(s, at, h, 0.32, q(96.0), q(48.0), stone)
                });
                if c + 1 < COLUMNS {
                    let a = v(x, y + h, z);
                    instance(&mut s, &mut inst, "arch", a, |s| {
                        let span = v(spacing, 0.0, 0.0);
                        add_arch(s, a, span, across, 0.7, 1.2 + spacing * 0.5, q(48.0), stone)
                    });
                }
            }
            // Gallery slab over this storey (plaster ceiling) and the brick wall behind the arcade.
            let top = y + storey;
            let zb = z + side * 3.0;
            add_patch(&mut s, q(64.0), q(8.0), plaster, |u, w| {
                let p = v(-len * 0.5 + len * u, top, z + (zb - z) * w);
                (p, Vec3::NEG_Y, Vec2::new(p.x, p.z) / PLASTER_M)
            });
            add_patch(&mut s, q(64.0), q(16.0), brick, |u, w| {
                let p = v(-len * 0.5 + len * u, y + storey * w, zb);
                (p, v(0.0, 0.0, -side), Vec2::new(p.x, -p.y) / BRICK_M)
            });
        }
        // Cloth between the upper columns: a hanging, gently waving sheet; the texture maps
        // once onto each panel (top of the image at the top), its alpha cuts holes and fringe.
        for c in 0..COLUMNS - 1 {
            let x0 = -len * 0.5 + c as f32 * spacing + 0.45;
            let x1 = x0 + CLOTH_W;
            let m = cloths[c % 3];
            let n = q(80.0);
            add_patch(&mut s, n, n, m, move |u, w| {
                let sag = 0.35 * (u * PI).sin() * (1.0 - w);
                let wave = 0.12 * (u * 9.0 + w * 5.0).sin() * w;
                let p = v(
                    x0 + (x1 - x0) * u,
                    storey * 2.0 - 1.7 - CLOTH_H * w - sag,
                    side * (width * 0.5 - 0.5) + wave,
                );
                (p, v(0.0, 0.0, -side), Vec2::new(u, w))
            });
        }
        // A vase on every pier of the gallery: one mesh repeated (the texture once around it,
        // the top of the image at the rim).
        for c in 0..COLUMNS {
            let x = -len * 0.5 + c as f32 * spacing;
            // Clear of the column's base (radius 0.43 m) and of the back wall.
            for dz in [0.9f32, 2.4] {
                let at = v(x, storey, side * (width * 0.5 + dz));
                let n = q(48.0);
                instance(&mut s, &mut inst, "vase", at, |s| {
                    add_patch(s, n, n / 2, vase, move |u, w| {
                        let a = u * TAU;
                        let r = 0.18 + 0.12 * (w * PI).sin() + 0.04 * (w * 3.0 * PI).sin();
                        let dir = v(a.cos(), 0.0, a.sin());
                        (at + dir * r + Vec3::Y * 0.8 * w, dir, Vec2::new(u, 1.0 - w))
                    })
                });
            }
        }
    }
    // End walls (brick).
    for x in [-len * 0.5 - 2.0, len * 0.5 + 2.0] {
        add_patch(&mut s, q(24.0), q(20.0), brick, move |u, w| {
            let p = v(x, 2.0 * storey * w, -width * 0.5 - 4.0 + (width + 8.0) * u);
            (p, v(-x.signum(), 0.0, 0.0), Vec2::new(p.z, -p.y) / BRICK_M)
        });
    }
    // 64 lamps: 16 per side and storey, small glowing spheres under the arches (emissive
    // triangles), each with a point light beside it.
    for side in [-1.0f32, 1.0] {
        for level in 0..2 {
            for k in 0..16 {
                let x = -len * 0.5 + spacing * 0.5 + (k as f32 / 15.0) * (len - spacing);
                let p = v(x, level as f32 * storey + 2.6, side * (width * 0.5 + 1.2));
                if k % 2 == 0 {
                    instance(&mut s, &mut inst, "lamp", p, |s| {
                        add_uv_sphere(s, p, 0.08, lamp, 6, 12)
                    });
                } else {
                    s.lights.push(PunctualLight {
                        kind: PunctualKind::Point,
                        position: p,
                        direction: Vec3::NEG_Y,
                        intensity: v(6.0, 4.5, 2.8),
                        inner_cone: 0.0,
                        outer_cone: 0.0,
                    });
                }
            }
        }
    }
    s.lights.push(PunctualLight {
        kind: PunctualKind::Directional,
        position: Vec3::ZERO,
        direction: v(0.3, -1.0, 0.45).normalize(),
        intensity: Vec3::splat(4.0),
        inner_cone: 0.0,
        outer_cone: 0.0,
    });
    s.sky = v(0.35, 0.45, 0.65);
    s.camera = Some(Camera {
        position: v(-15.0, 1.7, 0.0),
        target: v(10.0, 3.5, 0.0),
        up: Vec3::Y,
        fov_y: 60.0,
    });
    (s, inst)
}

// ---------------------------------------------------------------------------------------------
// Procedural textures: functions of (u, v) in [0, 1)^2 and the texel size `fw` (for
// antialiased edges), periodic where the texture tiles. Each material's texels are computed in
// one pass (colour, roughness, metallic and height together); normal maps are the height's
// slopes.

/// A pattern's value at a point: linear base colour and alpha, roughness, metallic, and height
/// in metres (for the normal map).
#[derive(Clone, Copy)]
struct Texel {
    base: Vec4,
    rough: f32,
    metal: f32,
    height: f32,
}

impl Texel {
    fn opaque(colour: Vec3, rough: f32, metal: f32, height: f32) -> Texel {
        Texel {
            base: colour.extend(1.0),
            rough,
            metal,
            height,
        }
    }
}

/// A material's textures: base colour (sRGB), normal map (when asked for), metallic-roughness.
struct Baked {
    base: Texture,
    normal: Option<Texture>,
    mr: Texture,
}

/// The generated textures at a detail, in [`TEXTURES`] order (see the module doc).
pub fn textures(detail: f32) -> Vec<Texture> {
    let n = texture_size(detail);
    let threads = (n / 4) as f32;
    let sets: Vec<Baked> = (0..6)
        .into_par_iter()
        .map(|k| match k {
            0 => bake(n, Some(FLOOR_M), floor_at),
            1 => bake(n, Some(BRICK_M), brick_at),
            2 => bake(n, Some(PLASTER_M), |u, v, _| plaster_at(u, v)),
            3 => bake(n, Some(STONE_M), stone_at),
            4 => bake(n, None, |u, v, fw| cloth_at(u, v, fw, threads)),
            _ => bake(n, None, vase_at),
        })
        .collect();
    let Ok([floor, brick, plaster, stone, cloth, vase]) = <[Baked; 6]>::try_from(sets) else {
        unreachable!()
    };
    vec![
        floor.base,
        floor.normal.unwrap(),
        floor.mr,
        brick.base,
        brick.normal.unwrap(),
        plaster.base,
        plaster.normal.unwrap(),
        stone.base,
        stone.normal.unwrap(),
        cloth.base,
        vase.base,
        vase.mr,
    ]
}

fn unorm(x: f32) -> u8 {
    (x.clamp(0.0, 1.0) * 255.0 + 0.5) as u8
}

/// Linear to 8-bit sRGB through a table (8192 steps: within half a code of the exact curve).
fn srgb(x: f32) -> u8 {
    const STEPS: usize = 8192;
    static TABLE: std::sync::OnceLock<Vec<u8>> = std::sync::OnceLock::new();
    let table = TABLE.get_or_init(|| {
        (0..STEPS)
            .map(|i| {
                let x = i as f32 / (STEPS - 1) as f32;
                unorm(if x <= 0.003_130_8 {
                    12.92 * x
                } else {
                    1.055 * x.powf(1.0 / 2.4) - 0.055
                })
            })
            .collect()
    });
    table[(x.clamp(0.0, 1.0) * (STEPS - 1) as f32 + 0.5) as usize]
}

fn texture(size: u32, rgba8: Vec<u8>) -> Texture {
    Texture {
        width: size,
        height: size,
        rgba8,
    }
}

/// Samples `f(u, v, texel)` at the texel centres of size x size textures: base colour (RGB
/// sRGB-encoded, alpha linear), metallic-roughness (R 1, G roughness, B metallic) and, when
/// `metres` (of surface per repeat) is given, the normal map of the height field.
fn bake(size: u32, metres: Option<f32>, f: impl Fn(f32, f32, f32) -> Texel + Sync) -> Baked {
    let n = size as usize;
    let fw = 1.0 / size as f32;
    let mut base = vec![0u8; n * n * 4];
    let mut mr = vec![0u8; n * n * 4];
    let mut height = vec![0f32; n * n];
    base.par_chunks_mut(n * 4)
        .zip(mr.par_chunks_mut(n * 4))
        .zip(height.par_chunks_mut(n))
        .enumerate()
        .for_each(|(y, ((base, mr), height))| {
            for x in 0..n {
                let t = f((x as f32 + 0.5) * fw, (y as f32 + 0.5) * fw, fw);
                let c = t.base;
                base[x * 4..x * 4 + 4].copy_from_slice(&[
                    srgb(c.x),
                    srgb(c.y),
                    srgb(c.z),
                    unorm(c.w),
                ]);
                mr[x * 4..x * 4 + 4].copy_from_slice(&[255, unorm(t.rough), unorm(t.metal), 255]);
                height[x] = t.height;
            }
        });
    Baked {
        base: texture(size, base),
        normal: metres.map(|m| texture(size, normal_map(&height, n, m))),
        mr: texture(size, mr),
    }
}

/// A tangent-space normal map of a periodic n x n height field (metres) over a texture that
/// spans `metres` of surface per repeat: central differences, wrapping. glTF's convention: +X
/// along +u, +Y towards the image's top (-v), so green is the slope along -v.
fn normal_map(h: &[f32], n: usize, metres: f32) -> Vec<u8> {
    let step = 2.0 * metres / n as f32;
    let mut rgba8 = vec![0u8; n * n * 4];
    rgba8
        .par_chunks_mut(n * 4)
        .enumerate()
        .for_each(|(y, row)| {
            let at = |x: usize, y: usize| h[(y % n) * n + x % n];
            for x in 0..n {
                let dhdx = (at(x + 1, y) - at(x + n - 1, y)) / step;
                let dhdv = (at(x, y + 1) - at(x, y + n - 1)) / step;
                // The surface normal (-dh/dx, -dh/dy, 1) with y = -v.
                let nrm = Vec3::new(-dhdx, dhdv, 1.0).normalize();
                row[x * 4..x * 4 + 4].copy_from_slice(&[
                    unorm(nrm.x * 0.5 + 0.5),
                    unorm(nrm.y * 0.5 + 0.5),
                    unorm(nrm.z * 0.5 + 0.5),
                    255,
                ]);
            }
        });
    rgba8
}

fn hash(x: u32, y: u32, seed: u32) -> u32 {
    let mut h =
        x.wrapping_mul(0x8da6_b343) ^ y.wrapping_mul(0xd816_3841) ^ seed.wrapping_mul(0xcb1a_b31f);
    h ^= h >> 15;
    h = h.wrapping_mul(0x2c1b_3c6d);
    h ^ (h >> 12)
}

/// Uniform in [0, 1) from lattice coordinates and a seed.
fn rnd(x: i32, y: i32, seed: u32) -> f32 {
    (hash(x as u32, y as u32, seed) >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
}

/// Value noise in [0, 1], periodic over [0, 1)^2 with `px` x `py` lattice cells (powers of two).
fn vnoise(u: f32, v: f32, px: u32, py: u32, seed: u32) -> f32 {
    debug_assert!(px.is_power_of_two() && py.is_power_of_two());
    let (x, y) = (u * px as f32, v * py as f32);
    let (xf, yf) = (x.floor(), y.floor());
    let (fx, fy) = (x - xf, y - yf);
    let (x0, y0) = (xf as i32 as u32 & (px - 1), yf as i32 as u32 & (py - 1));
    let (x1, y1) = ((x0 + 1) & (px - 1), (y0 + 1) & (py - 1));
    let r = |i: u32, j: u32| (hash(i, j, seed) >> 8) as f32 * (1.0 / (1u32 << 24) as f32);
    let (sx, sy) = (fx * fx * (3.0 - 2.0 * fx), fy * fy * (3.0 - 2.0 * fy));
    let (a, b) = (r(x0, y0), r(x0, y1));
    let a = a + (r(x1, y0) - a) * sx;
    let b = b + (r(x1, y1) - b) * sx;
    a + (b - a) * sy
}

/// Fractal value noise in [0, 1]: `octaves` octaves from `px` x `py` cells, doubling.
fn fbm(u: f32, v: f32, px: u32, py: u32, octaves: u32, seed: u32) -> f32 {
    let (mut sum, mut amp, mut norm) = (0.0, 1.0, 0.0);
    for o in 0..octaves {
        sum += amp * vnoise(u, v, px << o, py << o, seed.wrapping_add(o * 101));
        norm += amp;
        amp *= 0.5;
    }
    sum / norm
}

fn smoothstep(e0: f32, e1: f32, x: f32) -> f32 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// 0 inside (`d` < 0), 1 outside, over about a texel `w` around the edge.
fn edge(d: f32, w: f32) -> f32 {
    smoothstep(-0.5 * w, 0.5 * w, d)
}

/// Floor: 4 x 4 tiles of 0.5 m per repeat in a checker of cream and brown marble, each tile
/// its own shade, veins and roughness; 1 cm grout, bevelled tile edges 3 mm above it.
fn floor_at(u: f32, v: f32, fw: f32) -> Texel {
    const TILES: f32 = 4.0;
    let tile_m = FLOOR_M / TILES;
    let (x, y) = (u * TILES, v * TILES);
    let (tx, ty) = (x.floor(), y.floor());
    let (fx, fy) = (x - tx, y - ty);
    let (ix, iy) = ((tx as i32).rem_euclid(4), (ty as i32).rem_euclid(4));
    let e = fx.min(1.0 - fx).min(fy).min(1.0 - fy) * tile_m; // metres to the tile's edge
    let texel = fw * FLOOR_M;
    let (grout, bevel) = (0.005, 0.008f32.max(1.5 * texel));
    let cover = edge(e - grout, texel);
    let (r, r2) = (rnd(ix, iy, 1), rnd(ix, iy, 2));
    let base = if (ix + iy) % 2 == 1 {
        Vec3::new(0.34, 0.24, 0.17)
    } else {
        Vec3::new(0.72, 0.65, 0.53)
    };
    let marble = fbm(u, v, 4, 4, 4, 7 + (iy * 4 + ix) as u32);
    let vein = (1.0 - (marble * 16.0 + r * 6.0).sin().abs()).powi(12);
    let speck = fbm(u, v, 64, 64, 2, 3);
    let tile = base
        * (0.85 + 0.3 * r)
        * (1.0 - 0.3 * vein)
        * (0.92 + 0.16 * speck)
        * Vec3::new(1.0, 1.0 - 0.05 * r2, 1.0 - 0.1 * r2);
    let grout_c = Vec3::new(0.3, 0.29, 0.27) * (0.85 + 0.3 * speck);
    // Polished tiles, each its own wear; rough grout.
    let rough = 0.15 + 0.2 * r + 0.2 * fbm(u, v, 8, 8, 2, 11);
    let height = -0.003 * (1.0 - smoothstep(grout, grout + bevel, e)) + 0.0003 * (speck - 0.5);
    Texel::opaque(
        grout_c.lerp(tile, cover),
        0.9 + (rough - 0.9) * cover,
        0.0,
        height,
    )
}

/// Brick: running bond of 4 x 12 bricks (0.25 x 0.083 m) per repeat, 5 mm mortar joints
/// recessed 6 mm, bricks of varied firing.
fn brick_at(u: f32, v: f32, fw: f32) -> Texel {
    const COLS: f32 = 4.0;
    const ROWS: f32 = 12.0;
    let y = v * ROWS;
    let row = y.floor();
    let fy = y - row;
    let irow = (row as i32).rem_euclid(ROWS as i32);
    let x = u * COLS + 0.5 * (irow % 2) as f32;
    let col = x.floor();
    let fx = x - col;
    let icol = (col as i32).rem_euclid(COLS as i32);
    let (bw, bh) = (BRICK_M / COLS, BRICK_M / ROWS);
    let e = (fx.min(1.0 - fx) * bw).min(fy.min(1.0 - fy) * bh);
    let texel = fw * BRICK_M;
    let (mortar, bevel) = (0.005, 0.006f32.max(1.5 * texel));
    let cover = edge(e - mortar, texel);
    let (r, r2) = (rnd(icol, irow, 21), rnd(icol, irow, 22));
    let speck = fbm(u, v, 32, 32, 2, 23);
    let brick = Vec3::new(0.42, 0.15, 0.09).lerp(Vec3::new(0.5, 0.3, 0.16), r2)
        * (0.7 + 0.45 * r)
        * (0.8 + 0.2 * smoothstep(0.0, 0.025, e))
        * (0.8 + 0.4 * speck);
    let mortar_c = Vec3::new(0.56, 0.53, 0.48) * (0.85 + 0.3 * speck);
    let height = -0.006 * (1.0 - smoothstep(mortar, mortar + bevel, e))
        + 0.0015 * (fbm(u, v, 16, 16, 3, 25) - 0.5) * cover;
    Texel::opaque(mortar_c.lerp(brick, cover), 0.85, 0.0, height)
}

/// Plaster: warm off-white with blotches and stains, trowel undulation, grain and pits.
fn plaster_at(u: f32, v: f32) -> Texel {
    let low = fbm(u, v, 4, 4, 4, 31);
    let grain = fbm(u, v, 64, 64, 2, 32);
    let stain = smoothstep(0.58, 0.72, low);
    let pits = smoothstep(0.72, 0.9, vnoise(u, v, 128, 128, 35));
    let colour = Vec3::new(0.8, 0.74, 0.63)
        * (0.85 + 0.2 * low)
        * (0.94 + 0.12 * grain)
        * (Vec3::ONE - stain * Vec3::new(0.12, 0.17, 0.25))
        * (1.0 - 0.15 * pits);
    let height = 0.003 * (fbm(u, v, 8, 8, 3, 34) - 0.5) + 0.0008 * (grain - 0.5) - 0.001 * pits;
    Texel::opaque(colour, 0.9, 0.0, height)
}

/// Stone: sandstone with strata, a tint per course and a few pores; courses 0.5 m high with
/// 3 mm joints, chisel-marked faces.
fn stone_at(u: f32, v: f32, fw: f32) -> Texel {
    const COURSES: f32 = 2.0;
    let y = v * COURSES;
    let course = y.floor();
    let fy = y - course;
    let ic = (course as i32).rem_euclid(COURSES as i32);
    let e = fy.min(1.0 - fy) * STONE_M / COURSES;
    let texel = fw * STONE_M;
    let (joint, bevel) = (0.003, 0.006f32.max(1.5 * texel));
    let cover = edge(e - joint, texel);
    let r = rnd(ic, 0, 41);
    let strata = 0.5 + 0.5 * (v * TAU * 6.0 + 5.0 * fbm(u, v, 4, 4, 3, 42)).sin();
    let pores = smoothstep(0.8, 0.92, vnoise(u, v, 128, 128, 44));
    let stone = Vec3::new(0.7, 0.63, 0.52).lerp(Vec3::new(0.76, 0.64, 0.48), r)
        * (0.86 + 0.18 * strata)
        * (0.92 + 0.16 * fbm(u, v, 32, 32, 2, 43))
        * (1.0 - 0.2 * pores);
    let joint_c = Vec3::new(0.42, 0.39, 0.35);
    let chisel = fbm(u, v, 16, 16, 3, 45);
    let height = -0.004 * (1.0 - smoothstep(joint, joint + bevel, e))
        + (0.0015 * (chisel - 0.5) - 0.0005 * pores) * cover;
    Texel::opaque(joint_c.lerp(stone, cover), 0.75, 0.0, height)
}

/// Cloth (one panel per image, top at v = 0): plain weave of `threads` threads across, pale
/// (the material's factor gives the colour) with dark bands edged in gold; alpha: a row of
/// diamond lace holes with gold rims and small round holes between them, and a fringe of
/// strands of varying length at the bottom.
fn cloth_at(u: f32, v: f32, fw: f32, threads: f32) -> Texel {
    let (x, y) = (u * CLOTH_W, v * CLOTH_H); // metres from the top left
    let texel = fw * CLOTH_W.max(CLOTH_H);
    // Weave: warp (vertical) and weft threads alternate over and under.
    let (tx, ty) = (u * threads, v * threads * CLOTH_H / CLOTH_W);
    let (ix, iy) = (tx.floor() as i32, ty.floor() as i32);
    let (fx, fy) = (tx - tx.floor(), ty - ty.floor());
    let warp = (ix + iy).rem_euclid(2) == 0;
    let profile = if warp {
        (fx * PI).sin()
    } else {
        (fy * PI).sin()
    };
    let weave = (0.62 + 0.3 * profile.sqrt()) * if warp { 1.0 } else { 0.9 };
    let mut colour = Vec3::splat(weave) * (0.92 + 0.16 * fbm(u, v, 8, 8, 3, 51));
    let gold = Vec3::new(1.0, 0.85, 0.5) * (0.8 + 0.2 * profile);
    let band = |y0: f32, y1: f32| edge(y - y0, texel) * edge(y1 - y, texel);
    let dark = band(0.1, 0.2)
        .max(band(1.42, 1.5))
        .max(band(CLOTH_H - 0.44, CLOTH_H - 0.36));
    let trim = band(0.08, 0.095)
        .max(band(0.205, 0.22))
        .max(band(1.4, 1.412))
        .max(band(1.508, 1.52))
        .max(band(CLOTH_H - 0.46, CLOTH_H - 0.448))
        .max(band(CLOTH_H - 0.352, CLOTH_H - 0.34));
    colour = colour.lerp(colour * 0.3, dark).lerp(gold, trim);
    // Lace row: 6 diamond holes across, round holes between them.
    let yc = 1.75f32;
    let cx = ((u * 6.0).floor() + 0.5) / 6.0 * CLOTH_W;
    let diamond = ((x - cx).abs() / 0.1 + (y - yc).abs() / 0.15 - 1.0) * 0.08; // ~metres
    let kx = (u * 6.0).round();
    let round = if (1.0..=5.0).contains(&kx) {
        Vec2::new(x - kx / 6.0 * CLOTH_W, y - yc).length() - 0.035
    } else {
        1.0
    };
    let hole = diamond.min(round);
    colour = colour.lerp(gold, edge(hole, texel) * edge(0.025 - hole, texel));
    let mut alpha = edge(hole, texel);
    // Fringe: a solid hem, then strands 4 cm apart, 8 to 26 cm long.
    let hem = CLOTH_H - 0.26;
    if y > hem {
        let pitch = 0.04;
        let s = (x / pitch).floor();
        let fs = x / pitch - s;
        let end = hem + 0.26 * (0.3 + 0.7 * rnd(s as i32, 0, 52));
        let strand = edge(0.25 * pitch - (fs - 0.5).abs() * pitch, texel) * edge(end - y, texel);
        alpha = alpha.min(strand);
        colour *= 0.8 + 0.2 * (y * 180.0 + fs * 3.0).sin().abs();
    }
    Texel {
        base: colour.extend(alpha),
        rough: 1.0,
        metal: 0.0,
        height: 0.0,
    }
}

/// Vase (once around, rim at v = 0): cobalt glaze with streaks, darker where it pools at the
/// drip edge; gold bands (metal); a cream wave band with 8 waves around; bare terracotta clay
/// below the drip edge.
fn vase_at(u: f32, v: f32, fw: f32) -> Texel {
    let band = |v0: f32, v1: f32| edge(v - v0, fw) * edge(v1 - v, fw);
    let streak = fbm(u, v, 32, 4, 3, 63);
    let drip = 0.84 + 0.06 * fbm(u, 0.5, 16, 1, 3, 61);
    let mut colour = Vec3::new(0.015, 0.06, 0.2).lerp(Vec3::new(0.08, 0.25, 0.45), streak)
        * (1.0 - 0.4 * smoothstep(drip - 0.12, drip, v));
    let (mut rough, mut metal) = (0.08 + 0.08 * fbm(u, v, 16, 8, 2, 64), 0.0);
    // Cream wave band between thin cream lines.
    let yy = (v - 0.41) / 0.1;
    let wave = ((yy - 0.55 * (u * 8.0 * TAU).sin()).abs() - 0.2) * 0.05;
    let cream = (edge(-wave, fw) * band(0.31, 0.51))
        .max(band(0.295, 0.305))
        .max(band(0.515, 0.525));
    colour = colour.lerp(Vec3::new(0.8, 0.72, 0.52), cream);
    rough += (0.15 - rough) * cream;
    // Gold: the lip and two bands.
    let gold = band(-1.0, 0.035).max(band(0.2, 0.225)).max(band(0.6, 0.62));
    colour = colour.lerp(Vec3::new(1.0, 0.71, 0.29), gold);
    rough += (0.3 - rough) * gold;
    metal += (1.0 - metal) * gold;
    // Bare clay below the drip edge.
    let clay = edge(v - drip, fw);
    let clay_c = Vec3::new(0.5, 0.26, 0.15) * (0.85 + 0.3 * fbm(u, v, 32, 32, 2, 62));
    Texel::opaque(
        colour.lerp(clay_c, clay),
        rough + (0.85 - rough) * clay,
        metal * (1.0 - clay),
        0.0,
    )
}
