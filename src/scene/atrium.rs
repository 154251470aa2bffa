//! `atrium`: a large procedural scene in the layout of the classic Sponza atrium, for scale
//! (load, BVH build and tracing of a million triangles): a long open courtyard between two
//! storeys of arcades (finely tessellated columns, round arches, gallery slabs, back walls),
//! a tiled floor, cloth panels hanging between the upper columns, a repeated vase on every
//! pier of the gallery, 64 small lamps along the arcades, a sun and a sky. `detail` scales the
//! tessellation (1.0: about 1.1 million triangles).
//!
//! Not yet (issue 19): textures, alpha-masked cloth and GPU instancing; the vases are repeated
//! meshes, not instances.

use super::builtin::add_uv_sphere;
use super::{Camera, Material, PunctualKind, PunctualLight, Scene};
use glam::{Vec2, Vec3};
use std::f32::consts::{PI, TAU};

/// A smooth parametric patch: `f(u, v)` gives (position, normal) for u, v in [0, 1]; `nu` x `nv`
/// quads. Triangles are wound so their geometric normal agrees with the given normals.
fn add_patch(s: &mut Scene, nu: u32, nv: u32, material: u32, f: impl Fn(f32, f32) -> (Vec3, Vec3)) {
    let base = s.positions.len() as u32;
    for j in 0..=nv {
        for i in 0..=nu {
            let (u, v) = (i as f32 / nu as f32, j as f32 / nv as f32);
            let (p, n) = f(u, v);
            s.positions.push(p);
            s.normals.push(n.normalize_or_zero());
            s.uvs.push(Vec2::new(u, v));
        }
    }
    let idx = |i: u32, j: u32| base + j * (nu + 1) + i;
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

/// A column: shaft with a slight entasis and flutes, base and capital as wider drums.
fn add_column(s: &mut Scene, at: Vec3, height: f32, radius: f32, segs: u32, rings: u32, m: u32) {
    let shaft = |u: f32, v: f32| {
        let a = u * TAU;
        let flute = 1.0 + 0.03 * (a * 16.0).cos();
        let r = radius * flute * (1.0 - 0.12 * v * v);
        let dir = Vec3::new(a.cos(), 0.0, a.sin());
        (
            at + dir * r + Vec3::Y * (0.1 * height + 0.8 * height * v),
            dir,
        )
    };
    add_patch(s, segs, rings, m, shaft);
    for (y0, y1, r) in [(0.0, 0.1, 1.35), (0.9, 1.0, 1.45)] {
        let drum = move |u: f32, v: f32| {
            let a = u * TAU;
            let dir = Vec3::new(a.cos(), 0.0, a.sin());
            (
                at + dir * radius * r + Vec3::Y * height * (y0 + (y1 - y0) * v),
                dir,
            )
        };
        add_patch(s, segs, (rings / 8).max(1), m, drum);
    }
}

/// A round arch between two column tops: the intrados (inner half-cylinder surface) and the
/// two faces of the wall above it, from `a` to `b` (same height), `depth` thick along `across`.
#[allow(clippy::too_many_arguments)]
fn add_arch(
    s: &mut Scene,
    a: Vec3,
    b: Vec3,
    across: Vec3,
    depth: f32,
    top: f32,
    segs: u32,
    m: u32,
) {
    let mid = (a + b) * 0.5;
    let half = (b - a) * 0.5;
    let r = half.length();
    let along = half / r;
    let point = move |t: f32| mid - along * r * (t * PI).cos() + Vec3::Y * r * (t * PI).sin();
    let intrados = move |u: f32, v: f32| {
        let p = point(u);
        let n = (mid - p).normalize_or_zero(); // towards the arch's centre (down into the opening)
        (p + across * depth * (v - 0.5), n)
    };
    add_patch(s, segs, 4, m, intrados);
    for side in [-0.5f32, 0.5] {
        let face = move |u: f32, v: f32| {
            let p = point(u);
            let wall = Vec3::new(p.x, mid.y + top, p.z);
            (
                p.lerp(wall, v) + across * depth * side,
                across * side.signum(),
            )
        };
        add_patch(s, segs, 4, m, face);
    }
}

pub fn atrium(detail: f32) -> Scene {
    let d = detail.clamp(0.02, 4.0);
    let q = |n: f32| ((n * d.sqrt()).round() as u32).max(2);
    let mut s = Scene::new("atrium");
    let v = Vec3::new;
    let stone = s.add_material(Material::lambert("stone", v(0.62, 0.58, 0.5)));
    let floor = s.add_material(Material::glossy(
        "floor tiles",
        v(0.45, 0.4, 0.35),
        0.0,
        0.55,
    ));
    let plaster = s.add_material(Material::lambert("plaster", v(0.7, 0.64, 0.55)));
    let cloths = [
        s.add_material(Material::lambert("cloth red", v(0.55, 0.08, 0.06))),
        s.add_material(Material::lambert("cloth green", v(0.1, 0.4, 0.15))),
        s.add_material(Material::lambert("cloth blue", v(0.08, 0.15, 0.5))),
    ];
    let bronze = s.add_material(Material::glossy(
        "vase bronze",
        v(0.7, 0.45, 0.25),
        1.0,
        0.35,
    ));
    let lamp = s.add_material(Material::emitter("lamp", v(40.0, 30.0, 18.0)));

    // Courtyard 32 m long (x), 12 m wide (z); arcades along both long sides.
    let (len, width, storey) = (32.0f32, 12.0f32, 5.0f32);
    let columns = 13;
    let spacing = len / (columns - 1) as f32;
    add_patch(&mut s, q(420.0), q(160.0), floor, |u, w| {
        (
            v(
                -len * 0.5 - 2.0 + (len + 4.0) * u,
                0.0,
                -width * 0.5 - 4.0 + (width + 8.0) * w,
            ),
            Vec3::Y,
        )
    });
    for side in [-1.0f32, 1.0] {
        let z = side * width * 0.5;
        let across = v(0.0, 0.0, 1.0);
        for level in 0..2 {
            let y = level as f32 * storey;
            let h = if level == 0 {
                storey - 1.2
            } else {
                storey - 1.6
            };
            for c in 0..columns {
                let x = -len * 0.5 + c as f32 * spacing;
                add_column(&mut s, v(x, y, z), h, 0.32, q(96.0), q(48.0), stone);
                if c + 1 < columns {
                    let (a, b) = (v(x, y + h, z), v(x + spacing, y + h, z));
                    add_arch(
                        &mut s,
                        a,
                        b,
                        across,
                        0.7,
                        1.2 + spacing * 0.5,
                        q(48.0),
                        stone,
                    );
                }
            }
            // Gallery slab over this storey and the back wall behind the arcade.
            let top = y + storey;
            let zb = z + side * 3.0;
            add_patch(&mut s, q(64.0), q(8.0), plaster, |u, w| {
                (v(-len * 0.5 + len * u, top, z + (zb - z) * w), Vec3::NEG_Y)
            });
            add_patch(&mut s, q(64.0), q(16.0), plaster, |u, w| {
                (
                    v(-len * 0.5 + len * u, y + storey * w, zb),
                    v(0.0, 0.0, -side),
                )
            });
        }
        // Cloth between the upper columns: a hanging, gently waving sheet.
        for c in 0..columns - 1 {
            let x0 = -len * 0.5 + c as f32 * spacing + 0.45;
            let x1 = x0 + spacing - 0.9;
            let m = cloths[c % 3];
            let n = q(80.0);
            add_patch(&mut s, n, n, m, move |u, w| {
                let sag = 0.35 * (u * PI).sin() * (1.0 - w);
                let wave = 0.12 * (u * 9.0 + w * 5.0).sin() * w;
                let p = v(
                    x0 + (x1 - x0) * u,
                    storey * 2.0 - 1.7 - 2.6 * w - sag,
                    side * (width * 0.5 - 0.5) + wave,
                );
                (p, v(0.0, 0.0, -side))
            });
        }
        // A vase on every pier of the gallery (the same mesh repeated: issue 19's instances).
        for c in 0..columns {
            let x = -len * 0.5 + c as f32 * spacing;
            for dz in [-0.9f32, 0.9] {
                let at = v(x, storey, side * width * 0.5 + dz * side + side * 1.2);
                let n = q(48.0);
                add_patch(&mut s, n, n / 2, bronze, move |u, w| {
                    let a = u * TAU;
                    let r = 0.18 + 0.12 * (w * PI).sin() + 0.04 * (w * 3.0 * PI).sin();
                    let dir = v(a.cos(), 0.0, a.sin());
                    (at + dir * r + Vec3::Y * 0.8 * w, dir)
                });
            }
        }
    }
    // End walls.
    for x in [-len * 0.5 - 2.0, len * 0.5 + 2.0] {
        add_patch(&mut s, q(24.0), q(20.0), plaster, move |u, w| {
            (
                v(x, 2.0 * storey * w, -width * 0.5 - 4.0 + (width + 8.0) * u),
                v(-x.signum(), 0.0, 0.0),
            )
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
                    add_uv_sphere(&mut s, p, 0.08, lamp, 6, 12);
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
    s
}
