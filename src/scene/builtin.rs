//! Built-in procedural scenes, selectable by name in presets (`[scene] source = "cornell"`),
//! each with a few documented parameters (`[scene.params]`).

use super::{Camera, Material, PunctualKind, PunctualLight, Scene};
use anyhow::{bail, Result};
use glam::{Vec2, Vec3};

pub const NAMES: &[(&str, &str)] = &[
    ("cornell", "the classic Cornell box with a ceiling area light (Lambertian walls); `lamp` adds a small back-wall emitter (material `lamp`) of that radiance, 0 = off; `metal_boxes` makes both blocks GGX metal of base colour 1 at that roughness (the Mitsuba comparison's metal box)"),
    ("furnace", "closed sphere seen from inside, Lambertian albedo `albedo`, emission `emission`: radiance E/(1-a) everywhere"),
    ("many-lights", "a pillared hall lit by `lights` (default 1024) small coloured ceiling emitters: the many-light stress case"),
    ("thin-wall", "a sunlit exterior and a closed room of zero-thickness walls; `interior_light` 0 makes any light inside a leak"),
    ("glossy", "metal spheres of roughness 0, 0.1, 0.3, 0.7 before a mirror wall, under an area light"),
    ("courtyard", "an open porch beside a sunlit yard under a blue sky: the roof shadows the porch from the sun, wall lamps of radiance `lamp` (15) and a lantern light it; every light class (local, directional, sky); `sun` and `sky` scale the sun and the sky (1)"),
    ("material-balls", "the Callisto talk's fitted materials (black soft plastic, blue fabric, yellow phenolic, yellow plastic, gold metallic paint, light red paint) as spheres under a grazing key light and a back light: the BRDF models' differences (diffuse Fresnel, retroreflection, terminator) where they show"),
    ("atrium", "a Sponza-like atrium for scale: two storeys of arcades (fluted columns, round arches, galleries), tiled floor, hanging cloth, a vase on every pier, 64 lamps, sun and sky; `detail` (1.0: 1,234,560 triangles) scales the tessellation; columns, arches, vases and lamps are instances (a two-level BVH)"),
    ("mirror-hall", "reflections: a mirror back wall, a rough metal floor (roughness `floor_roughness`, 0.35), seven glossy spheres from roughness 0 to 0.7 (metal and plastic), a teal wall behind the camera seen only in reflections, 36 ceiling lights"),
    ("moving", "dynamic GI: a Cornell-like room whose sliding door opens onto a sunlit exterior over two seconds, a ball rolling through the light and an orange lamp carried round the room, one looped 8-second clip (`[scene] time_scale` plays it, `time` poses it)"),
    ("interior", "Callisto's case (seed 002): a closed, dark hall of pillars and crates lit only by `lights` (24) small point lights on the walls and pillars, four lanterns carried round it and a sliding crate, one looped 8-second clip (`[scene] time_scale` plays it); no sky, no sun"),
    ("hard-cases", "degenerate triangles, zero normals, roughness 0/1, metallic 1, a light inside a box, emission `emission` (1e6), grazing camera"),
];

/// Reads typed parameters and rejects the ones a scene does not know.
struct Params<'a> {
    scene: &'a str,
    table: &'a toml::Table,
    known: Vec<&'static str>,
}

impl<'a> Params<'a> {
    fn f32(&mut self, key: &'static str, default: f32) -> Result<f32> {
        self.known.push(key);
        match self.table.get(key) {
            None => Ok(default),
            Some(toml::Value::Float(f)) => Ok(*f as f32),
            Some(toml::Value::Integer(i)) => Ok(*i as f32),
            Some(v) => bail!(
                "scene '{}': parameter '{key}' must be a number, got {v}",
                self.scene
            ),
        }
    }
    fn u32(&mut self, key: &'static str, default: u32) -> Result<u32> {
        self.known.push(key);
        match self.table.get(key) {
            None => Ok(default),
            Some(toml::Value::Integer(i)) if *i >= 0 && *i <= u32::MAX as i64 => Ok(*i as u32),
            Some(v) => bail!(
                "scene '{}': parameter '{key}' must be a non-negative integer, got {v}",
                self.scene
            ),
        }
    }
    fn finish(self) -> Result<()> {
        for k in self.table.keys() {
            if !self.known.contains(&k.as_str()) {
                bail!(
                    "scene '{}' has no parameter '{k}' (known: {})",
                    self.scene,
                    self.known.join(", ")
                );
            }
        }
        Ok(())
    }
}

pub fn is_builtin(name: &str) -> bool {
    NAMES.iter().any(|(n, _)| *n == name)
}

pub fn build(name: &str, params: &toml::Table) -> Result<Scene> {
    let mut p = Params {
        scene: name,
        table: params,
        known: Vec::new(),
    };
    let scene = match name {
        "cornell" => {
            // The lamp exists only when asked for (0 = present but off: events switch it on).
            let lamp = if params.contains_key("lamp") {
                Some(p.f32("lamp", 0.0)?)
            } else {
                p.known.push("lamp");
                None
            };
            let mut scene = cornell_with_lamp(lamp);
            if params.contains_key("metal_boxes") {
                let roughness = p.f32("metal_boxes", 0.3)?;
                if !(0.0..=1.0).contains(&roughness) {
                    bail!("scene 'cornell': metal_boxes is a roughness in [0, 1], got {roughness}");
                }
                scene = with_metal_boxes(scene, roughness);
            } else {
                p.known.push("metal_boxes");
            }
            scene
        }
        "furnace" => {
            let albedo = p.f32("albedo", 0.8)?;
            let emission = p.f32("emission", 1.0)?;
            let subdivisions = p.u32("subdivisions", 3)?;
            if !(0.0..1.0).contains(&albedo) {
                bail!("scene 'furnace': albedo must be in [0, 1), got {albedo}");
            }
            furnace(albedo, emission, subdivisions.min(6))
        }
        "many-lights" => {
            let lights = p.u32("lights", 1024)?;
            let seed = p.u32("seed", 7)?;
            many_lights(lights.clamp(1, 16384), seed)
        }
        "thin-wall" => thin_wall(p.f32("interior_light", 0.6)?),
        "glossy" => glossy(),
        "material-balls" => material_balls(),
        "atrium" => super::atrium::atrium(p.f32("detail", 1.0)?),
        "hard-cases" => hard_cases(p.f32("emission", 1e6)?),
        "moving" => super::moving::moving()?,
        "interior" => {
            let lights = p.u32("lights", 24)?;
            anyhow::ensure!(
                lights <= 256,
                "scene 'interior': lights = {lights}, at most 256 (many-lights is the many-light scene)"
            );
            super::interior::interior(lights)?
        }
        "mirror-hall" => mirror_hall(p.f32("floor_roughness", 0.35)?.clamp(0.0, 1.0)),
        "courtyard" => courtyard(p.f32("lamp", 15.0)?, p.f32("sun", 1.0)?, p.f32("sky", 1.0)?),
        other => {
            let names: Vec<&str> = NAMES.iter().map(|(n, _)| *n).collect();
            bail!(
                "unknown built-in scene '{other}' (built-ins: {}; or give a .gltf/.glb path)",
                names.join(", ")
            )
        }
    };
    p.finish()?;
    scene.validate()?;
    Ok(scene)
}

/// The Cornell box's two blocks as GGX metal of base colour 1 (F = 1) at `roughness`: the metal
/// box of the Mitsuba comparison (`tests/data/mitsuba/glossy.gltf`), as a scene parameter so that
/// presets and studies can ask for it.
pub fn with_metal_boxes(mut s: Scene, roughness: f32) -> Scene {
    let metal = s.add_material(Material::glossy("metal", Vec3::ONE, 1.0, roughness));
    for o in s.objects.iter().filter(|o| o.name.ends_with(" box")) {
        let first = o.first_triangle as usize;
        for m in &mut s.triangle_material[first..first + o.triangle_count as usize] {
            *m = metal;
        }
    }
    s
}

/// The Cornell box after the Cornell program's measured data (units: 1 = 100 mm), with the
/// colours and light of Mitsuba's version: pure Lambert walls so external renderers can match.
pub fn cornell() -> Scene {
    cornell_with_lamp(None)
}

/// The Cornell box, optionally with a small back-wall emitter (material `lamp`) of the
/// given radiance; 0 keeps the geometry with the light off, for scripted switch-on events.
#[allow(clippy::approx_constant)] // 3.14 is a measured Cornell box coordinate, not pi.
pub fn cornell_with_lamp(lamp: Option<f32>) -> Scene {
    let mut s = Scene::new("cornell");
    let white = s.add_material(Material::lambert("white", Vec3::new(0.725, 0.71, 0.68)));
    let red = s.add_material(Material::lambert("red", Vec3::new(0.63, 0.065, 0.05)));
    let green = s.add_material(Material::lambert("green", Vec3::new(0.14, 0.45, 0.091)));
    let light = s.add_material(Material::emitter("light", Vec3::new(17.0, 12.0, 4.0)));
    let (w, h, l) = (5.56, 5.488, 5.592);
    let v = Vec3::new;
    s.named("floor", |s| {
        s.add_quad(
            v(0.0, 0.0, 0.0),
            v(0.0, 0.0, l),
            v(w, 0.0, l),
            v(w, 0.0, 0.0),
            white,
        )
    });
    s.named("ceiling", |s| {
        s.add_quad(
            v(0.0, h, 0.0),
            v(w, h, 0.0),
            v(w, h, l),
            v(0.0, h, l),
            white,
        )
    });
    s.named("back wall", |s| {
        s.add_quad(
            v(0.0, 0.0, l),
            v(0.0, h, l),
            v(w, h, l),
            v(w, 0.0, l),
            white,
        )
    });
    // x = 0: right as seen.
    s.named("green wall", |s| {
        s.add_quad(
            v(0.0, 0.0, 0.0),
            v(0.0, h, 0.0),
            v(0.0, h, l),
            v(0.0, 0.0, l),
            green,
        )
    });
    // x = w: left as seen.
    s.named("red wall", |s| {
        s.add_quad(v(w, 0.0, 0.0), v(w, 0.0, l), v(w, h, l), v(w, h, 0.0), red)
    });
    let y = h - 0.001;
    s.named("light", |s| {
        s.add_quad(
            v(2.13, y, 2.27),
            v(3.43, y, 2.27),
            v(3.43, y, 3.32),
            v(2.13, y, 3.32),
            light,
        )
    });
    if let Some(radiance) = lamp {
        // Back wall, left of the tall block as seen, facing the camera; warm white.
        let m = s.add_material(Material::emitter(
            "lamp",
            Vec3::new(1.0, 0.85, 0.6) * radiance.max(0.0),
        ));
        let z = l - 0.001;
        s.named("lamp", |s| {
            s.add_quad(
                v(1.2, 2.0, z),
                v(1.2, 2.6, z),
                v(2.0, 2.6, z),
                v(2.0, 2.0, z),
                m,
            )
        });
    }
    let block = |s: &mut Scene, name: &str, top: [Vec3; 4]| {
        let b = top.map(|t| Vec3::new(t.x, 0.0, t.z));
        s.named(name, |s| {
            s.add_box(
                [b[0], b[1], b[2], b[3], top[0], top[1], top[2], top[3]],
                white,
            )
        });
    };
    // The short box, then the tall one.
    block(
        &mut s,
        "short box",
        [
            v(1.30, 1.65, 0.65),
            v(0.82, 1.65, 2.25),
            v(2.40, 1.65, 2.72),
            v(2.90, 1.65, 1.14),
        ],
    );
    block(
        &mut s,
        "tall box",
        [
            v(4.23, 3.30, 2.47),
            v(2.65, 3.30, 2.96),
            v(3.14, 3.30, 4.56),
            v(4.72, 3.30, 4.06),
        ],
    );
    s.camera = Some(Camera {
        position: v(2.78, 2.73, -8.0),
        target: v(2.78, 2.73, 0.0),
        up: Vec3::Y,
        fov_y: 39.3,
    });
    s
}

/// Icosphere with `subdivisions` levels, radius 1; triangles wound so normals point `inward` or out.
pub fn icosphere(subdivisions: u32) -> Vec<[Vec3; 3]> {
    let t = (1.0 + 5f32.sqrt()) / 2.0;
    let verts: Vec<Vec3> = [
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ]
    .iter()
    .map(|p| Vec3::from_array(*p).normalize())
    .collect();
    let faces = [
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    let mut tris: Vec<[Vec3; 3]> = faces
        .iter()
        .map(|f| [verts[f[0]], verts[f[1]], verts[f[2]]])
        .collect();
    for _ in 0..subdivisions {
        tris = tris
            .iter()
            .flat_map(|[a, b, c]| {
                let ab = ((*a + *b) * 0.5).normalize();
                let bc = ((*b + *c) * 0.5).normalize();
                let ca = ((*c + *a) * 0.5).normalize();
                [[*a, ab, ca], [*b, bc, ab], [*c, ca, bc], [ab, bc, ca]]
            })
            .collect();
    }
    tris
}

/// White furnace: a closed sphere, uniform albedo a and emission E, flat normals facing inward.
pub fn furnace(albedo: f32, emission: f32, subdivisions: u32) -> Scene {
    let mut s = Scene::new("furnace");
    let m = s.add_material(Material {
        emissive: Vec3::splat(emission),
        ..Material::lambert("furnace", Vec3::splat(albedo))
    });
    for [a, b, c] in icosphere(subdivisions) {
        // Outward winding reversed: normals (and single-sided emission) face the centre.
        s.add_triangle([a * 2.0, c * 2.0, b * 2.0], m);
    }
    s.camera = Some(Camera {
        position: Vec3::ZERO,
        target: Vec3::new(0.0, 0.0, -1.0),
        up: Vec3::Y,
        fov_y: 70.0,
    });
    s
}

/// Deterministic hash to [0, 1) for procedural placement.
fn hash01(i: u32, seed: u32) -> f32 {
    let mut x = i.wrapping_mul(0x9E37_79B9) ^ seed.wrapping_mul(0x85EB_CA6B);
    x ^= x >> 16;
    x = x.wrapping_mul(0x7FEB_352D);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846C_A68B);
    x ^= x >> 16;
    (x >> 8) as f32 / 16_777_216.0
}

pub fn many_lights(count: u32, seed: u32) -> Scene {
    let mut s = Scene::new("many-lights");
    let grey = s.add_material(Material::lambert("grey", Vec3::splat(0.6)));
    let floor = s.add_material(Material::glossy("floor", Vec3::splat(0.5), 0.0, 0.4));
    let (half, h) = (12.0f32, 6.0f32);
    let v = Vec3::new;
    s.add_quad(
        v(-half, 0.0, -half),
        v(-half, 0.0, half),
        v(half, 0.0, half),
        v(half, 0.0, -half),
        floor,
    );
    s.add_quad(
        v(-half, h, -half),
        v(half, h, -half),
        v(half, h, half),
        v(-half, h, half),
        grey,
    );
    s.add_quad(
        v(-half, 0.0, -half),
        v(half, 0.0, -half),
        v(half, h, -half),
        v(-half, h, -half),
        grey,
    );
    s.add_quad(
        v(-half, 0.0, half),
        v(-half, h, half),
        v(half, h, half),
        v(half, 0.0, half),
        grey,
    );
    s.add_quad(
        v(-half, 0.0, -half),
        v(-half, h, -half),
        v(-half, h, half),
        v(-half, 0.0, half),
        grey,
    );
    s.add_quad(
        v(half, 0.0, -half),
        v(half, 0.0, half),
        v(half, h, half),
        v(half, h, -half),
        grey,
    );
    // Pillars: occluders that make visibility matter.
    for i in 0..5 {
        for j in 0..5 {
            let c = v(-9.6 + 4.8 * i as f32, 0.0, -9.6 + 4.8 * j as f32);
            let r = 0.35;
            let b = [
                c + v(-r, 0.0, -r),
                c + v(-r, 0.0, r),
                c + v(r, 0.0, r),
                c + v(r, 0.0, -r),
            ];
            let t = b.map(|p| p + v(0.0, h, 0.0));
            s.add_box([b[0], b[1], b[2], b[3], t[0], t[1], t[2], t[3]], grey);
        }
    }
    // Small emitters hanging just under the ceiling, colours and strengths spread widely.
    let size = 0.16;
    for i in 0..count {
        let x = -half + 0.5 + (2.0 * half - 1.0) * hash01(3 * i, seed);
        let z = -half + 0.5 + (2.0 * half - 1.0) * hash01(3 * i + 1, seed);
        let hue = hash01(3 * i + 2, seed);
        let strength = 20.0 + 180.0 * hash01(7 * i + 5, seed).powi(3);
        let colour = v(
            0.5 + 0.5 * (std::f32::consts::TAU * hue).cos(),
            0.5 + 0.5 * (std::f32::consts::TAU * (hue + 0.33)).cos(),
            0.5 + 0.5 * (std::f32::consts::TAU * (hue + 0.67)).cos(),
        ) * strength
            + Vec3::splat(2.0);
        let m = s.add_material(Material::emitter(&format!("light{i}"), colour));
        let y = h - 0.05;
        s.add_quad(
            v(x, y, z),
            v(x + size, y, z),
            v(x + size, y, z + size),
            v(x, y, z + size),
            m,
        );
    }
    s.camera = Some(Camera {
        position: v(-10.5, 1.7, 8.0),
        target: v(3.0, 2.5, -6.0),
        up: Vec3::Y,
        fov_y: 60.0,
    });
    s
}

/// A closed room of zero-thickness walls under a strong sun and sky; the camera is inside.
/// With `interior_light` 0 every pixel must be exactly black: anything else is a leak.
pub fn thin_wall(interior_light: f32) -> Scene {
    let mut s = Scene::new("thin-wall");
    let ground = s.add_material(Material::lambert("ground", Vec3::splat(0.5)));
    let wall = s.add_material(Material::lambert("wall", Vec3::splat(0.75)));
    let v = Vec3::new;
    s.add_quad(
        v(-50.0, -0.01, -50.0),
        v(-50.0, -0.01, 50.0),
        v(50.0, -0.01, 50.0),
        v(50.0, -0.01, -50.0),
        ground,
    );
    let (a, h) = (2.0f32, 3.0f32);
    s.add_quad(
        v(-a, 0.0, -a),
        v(-a, 0.0, a),
        v(a, 0.0, a),
        v(a, 0.0, -a),
        wall,
    ); // floor
    s.add_quad(v(-a, h, -a), v(a, h, -a), v(a, h, a), v(-a, h, a), wall); // roof
    s.add_quad(
        v(-a, 0.0, -a),
        v(a, 0.0, -a),
        v(a, h, -a),
        v(-a, h, -a),
        wall,
    ); // the sunlit wall
    s.add_quad(v(-a, 0.0, a), v(-a, h, a), v(a, h, a), v(a, 0.0, a), wall);
    s.add_quad(
        v(-a, 0.0, -a),
        v(-a, h, -a),
        v(-a, h, a),
        v(-a, 0.0, a),
        wall,
    );
    s.add_quad(v(a, 0.0, -a), v(a, 0.0, a), v(a, h, a), v(a, h, -a), wall);
    s.sky = v(0.5, 0.65, 1.0) * 2.0;
    s.lights.push(PunctualLight {
        kind: PunctualKind::Directional,
        position: Vec3::ZERO,
        direction: v(0.2, -0.5, 1.0).normalize(),
        intensity: v(10.0, 9.5, 9.0),
        inner_cone: 0.0,
        outer_cone: 0.0,
    });
    if interior_light > 0.0 {
        s.lights.push(PunctualLight {
            kind: PunctualKind::Point,
            position: v(0.5, 2.2, 1.0),
            direction: Vec3::NEG_Y,
            intensity: Vec3::splat(interior_light),
            inner_cone: 0.0,
            outer_cone: 0.0,
        });
    }
    s.camera = Some(Camera {
        position: v(0.0, 1.5, 1.8),
        target: v(0.0, 1.3, -2.0),
        up: Vec3::Y,
        fov_y: 75.0,
    });
    s
}

/// UV sphere with smooth normals and UVs.
pub fn add_uv_sphere(
    s: &mut Scene,
    center: Vec3,
    radius: f32,
    material: u32,
    rings: u32,
    segments: u32,
) {
    let point = |i: u32, j: u32| {
        let theta = std::f32::consts::PI * i as f32 / rings as f32;
        let phi = std::f32::consts::TAU * j as f32 / segments as f32;
        Vec3::new(
            theta.sin() * phi.cos(),
            theta.cos(),
            theta.sin() * phi.sin(),
        )
    };
    let base = s.positions.len() as u32;
    for i in 0..=rings {
        for j in 0..=segments {
            let n = point(i, j);
            s.positions.push(center + n * radius);
            s.normals.push(n);
            s.uvs.push(Vec2::new(
                j as f32 / segments as f32,
                i as f32 / rings as f32,
            ));
        }
    }
    let idx = |i: u32, j: u32| base + i * (segments + 1) + j;
    for i in 0..rings {
        for j in 0..segments {
            let (a, b, c, d) = (idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1));
            // Outward winding; the pole rows produce zero-area triangles, which the tracer must tolerate.
            s.triangles.push([a, d, c]);
            s.triangle_material.push(material);
            s.triangles.push([a, c, b]);
            s.triangle_material.push(material);
        }
    }
}

pub fn glossy() -> Scene {
    let mut s = Scene::new("glossy");
    let floor = s.add_material(Material::glossy("floor", Vec3::splat(0.45), 0.0, 0.5));
    let mirror = s.add_material(Material::glossy("mirror", Vec3::splat(0.95), 1.0, 0.0));
    let wall = s.add_material(Material::lambert("wall", Vec3::new(0.6, 0.55, 0.5)));
    let light = s.add_material(Material::emitter("light", Vec3::splat(12.0)));
    let v = Vec3::new;
    s.add_quad(
        v(-6.0, 0.0, -4.0),
        v(-6.0, 0.0, 4.0),
        v(6.0, 0.0, 4.0),
        v(6.0, 0.0, -4.0),
        floor,
    );
    s.add_quad(
        v(-6.0, 0.0, -3.0),
        v(6.0, 0.0, -3.0),
        v(6.0, 4.0, -3.0),
        v(-6.0, 4.0, -3.0),
        mirror,
    );
    s.add_quad(
        v(-6.0, 0.0, -4.0),
        v(-6.0, 4.0, -4.0),
        v(-6.0, 4.0, 4.0),
        v(-6.0, 0.0, 4.0),
        wall,
    );
    s.add_quad(
        v(6.0, 0.0, -4.0),
        v(6.0, 0.0, 4.0),
        v(6.0, 4.0, 4.0),
        v(6.0, 4.0, -4.0),
        wall,
    );
    s.named("light", |s| {
        s.add_quad(
            v(-2.0, 3.99, -1.0),
            v(2.0, 3.99, -1.0),
            v(2.0, 3.99, 1.0),
            v(-2.0, 3.99, 1.0),
            light,
        )
    });
    let colours = [
        v(0.95, 0.95, 0.95),
        v(1.0, 0.78, 0.34),
        v(0.95, 0.64, 0.54),
        v(0.56, 0.57, 0.58),
    ];
    for (i, rough) in [0.0f32, 0.1, 0.3, 0.7].iter().enumerate() {
        let m = s.add_material(Material::glossy(
            &format!("metal r{rough}"),
            colours[i],
            1.0,
            *rough,
        ));
        s.named(&format!("sphere r{rough}"), |s| {
            add_uv_sphere(s, v(-3.3 + 2.2 * i as f32, 0.9, -0.5), 0.9, m, 24, 48)
        });
    }
    s.sky = Vec3::splat(0.15);
    s.camera = Some(Camera {
        position: v(0.0, 2.2, 7.0),
        target: v(0.0, 1.0, -1.0),
        up: Vec3::Y,
        fov_y: 50.0,
    });
    s
}

/// The reflections scene (issue 35): a mirror back wall and a rough metal floor, glossy spheres
/// from roughness 0 to 0.7, a teal wall behind the camera that only reflections show, and a
/// 6×6 grid of small ceiling lights. Enclosed (no sky).
pub fn mirror_hall(floor_roughness: f32) -> Scene {
    let mut s = Scene::new("mirror-hall");
    let v = Vec3::new;
    let (w, h, d) = (6.0f32, 4.0f32, 6.0f32);
    let floor = s.add_material(Material::glossy(
        "rough metal floor",
        v(0.62, 0.6, 0.58),
        1.0,
        floor_roughness,
    ));
    let mirror = s.add_material(Material::glossy("mirror", v(0.96, 0.96, 0.96), 1.0, 0.0));
    let wall = s.add_material(Material::lambert("wall", v(0.7, 0.68, 0.64)));
    let teal = s.add_material(Material::lambert(
        "teal wall (reflections only)",
        v(0.05, 0.55, 0.5),
    ));
    let light = s.add_material(Material::emitter("ceiling light", v(40.0, 36.0, 30.0)));
    // Floor and ceiling.
    s.add_quad(
        v(-w, 0.0, -d),
        v(-w, 0.0, d),
        v(w, 0.0, d),
        v(w, 0.0, -d),
        floor,
    );
    s.add_quad(v(-w, h, -d), v(w, h, -d), v(w, h, d), v(-w, h, d), wall);
    // The mirror at the back, the teal wall at the front (behind the camera), side walls.
    s.add_quad(
        v(-w, 0.0, -d),
        v(w, 0.0, -d),
        v(w, h, -d),
        v(-w, h, -d),
        mirror,
    );
    s.add_quad(v(-w, 0.0, d), v(-w, h, d), v(w, h, d), v(w, 0.0, d), teal);
    s.add_quad(
        v(-w, 0.0, -d),
        v(-w, h, -d),
        v(-w, h, d),
        v(-w, 0.0, d),
        wall,
    );
    s.add_quad(v(w, 0.0, -d), v(w, 0.0, d), v(w, h, d), v(w, h, -d), wall);
    // 36 small lights just under the ceiling, facing down.
    for i in 0..6 {
        for j in 0..6 {
            let (x, z) = (
                -w + (i as f32 + 0.5) * 2.0 * w / 6.0,
                -d + (j as f32 + 0.5) * 2.0 * d / 6.0,
            );
            let r = 0.15;
            s.add_quad(
                v(x - r, h - 0.01, z - r),
                v(x + r, h - 0.01, z - r),
                v(x + r, h - 0.01, z + r),
                v(x - r, h - 0.01, z + r),
                light,
            );
        }
    }
    let spheres = [
        (0.0f32, v(0.95, 0.95, 0.95), 1.0f32),
        (0.1, v(1.0, 0.78, 0.34), 1.0),
        (0.2, v(0.95, 0.64, 0.54), 1.0),
        (0.3, v(0.8, 0.1, 0.1), 0.0),
        (0.4, v(0.56, 0.57, 0.58), 1.0),
        (0.55, v(0.1, 0.2, 0.8), 0.0),
        (0.7, v(0.9, 0.9, 0.9), 1.0),
    ];
    for (i, (rough, colour, metal)) in spheres.iter().enumerate() {
        let m = s.add_material(Material::glossy(
            &format!("sphere r{rough}"),
            *colour,
            *metal,
            *rough,
        ));
        add_uv_sphere(&mut s, v(-4.2 + 1.4 * i as f32, 0.6, -1.5), 0.6, m, 24, 48);
    }
    s.camera = Some(Camera {
        position: v(0.0, 2.0, 5.8),
        target: v(0.0, 1.0, -1.5),
        up: Vec3::Y,
        fov_y: 60.0,
    });
    s
}

/// Numerically hostile content in one place; every technique must render it without NaN/Inf.
pub fn hard_cases(emission: f32) -> Scene {
    let mut s = Scene::new("hard-cases");
    let white = s.add_material(Material::lambert("white", Vec3::splat(0.7)));
    let mirror = s.add_material(Material::glossy(
        "rough0-metal1",
        Vec3::splat(1.0),
        1.0,
        0.0,
    ));
    let rough1 = s.add_material(Material::glossy(
        "rough1",
        Vec3::new(0.8, 0.3, 0.2),
        0.0,
        1.0,
    ));
    let metal_rough1 = s.add_material(Material::glossy(
        "metal-rough1",
        Vec3::new(0.9, 0.8, 0.5),
        1.0,
        1.0,
    ));
    let dark = s.add_material(Material::emitter("emission0", Vec3::ZERO));
    let hot = s.add_material(Material::emitter("emission-hot", Vec3::splat(emission)));
    let v = Vec3::new;
    s.add_quad(
        v(-5.0, 0.0, -5.0),
        v(-5.0, 0.0, 5.0),
        v(5.0, 0.0, 5.0),
        v(5.0, 0.0, -5.0),
        white,
    );
    // The wall the camera grazes.
    s.add_quad(
        v(-5.0, 0.0, -5.0),
        v(5.0, 0.0, -5.0),
        v(5.0, 4.0, -5.0),
        v(-5.0, 4.0, -5.0),
        white,
    );
    s.add_quad(
        v(-4.0, 0.0, -4.9),
        v(-2.0, 0.0, -4.9),
        v(-2.0, 2.0, -4.9),
        v(-4.0, 2.0, -4.9),
        mirror,
    );
    add_uv_sphere(&mut s, v(-1.0, 0.8, -2.0), 0.8, rough1, 12, 24);
    add_uv_sphere(&mut s, v(1.2, 0.8, -2.0), 0.8, metal_rough1, 12, 24);
    // Zero-area triangles: a point and a line.
    s.add_triangle([v(0.0, 1.0, 0.0); 3], white);
    s.add_triangle(
        [v(0.0, 1.0, 0.0), v(1.0, 1.0, 0.0), v(2.0, 1.0, 0.0)],
        white,
    );
    // Triangles with zero (missing) normals.
    let base = s.positions.len() as u32;
    for p in [v(2.0, 0.0, 1.0), v(3.0, 0.0, 1.0), v(2.5, 1.5, 1.0)] {
        s.positions.push(p);
        s.normals.push(Vec3::ZERO);
        s.uvs.push(Vec2::ZERO);
    }
    s.triangles.push([base, base + 1, base + 2]);
    s.triangle_material.push(white);
    // A tiny, extremely bright emitter and a black one.
    s.add_quad(
        v(3.0, 2.0, -3.0),
        v(3.0, 2.1, -3.0),
        v(3.0, 2.1, -2.9),
        v(3.0, 2.0, -2.9),
        hot,
    );
    s.add_quad(
        v(-3.0, 2.0, -3.0),
        v(-3.0, 2.5, -3.0),
        v(-3.0, 2.5, -2.5),
        v(-3.0, 2.0, -2.5),
        dark,
    );
    // A point light sealed inside a box: contributes nothing outside.
    let c = v(3.5, 0.0, 2.5);
    let r = 0.4;
    let b = [
        c + v(-r, 0.0, -r),
        c + v(-r, 0.0, r),
        c + v(r, 0.0, r),
        c + v(r, 0.0, -r),
    ];
    let t = b.map(|p| p + v(0.0, 0.8, 0.0));
    s.add_box([b[0], b[1], b[2], b[3], t[0], t[1], t[2], t[3]], white);
    s.lights.push(PunctualLight {
        kind: PunctualKind::Point,
        position: c + v(0.0, 0.4, 0.0),
        direction: Vec3::NEG_Y,
        intensity: Vec3::splat(100.0),
        inner_cone: 0.0,
        outer_cone: 0.0,
    });
    s.lights.push(PunctualLight {
        kind: PunctualKind::Spot,
        position: v(0.0, 3.5, 0.0),
        direction: Vec3::NEG_Y,
        intensity: Vec3::splat(30.0),
        inner_cone: 0.3,
        outer_cone: 0.6,
    });
    s.sky = Vec3::splat(0.3);
    // Grazing: the camera sits 1 mm in front of the back wall, looking along it.
    s.camera = Some(Camera {
        position: v(4.5, 1.5, -4.999),
        target: v(-5.0, 1.2, -4.99),
        up: Vec3::Y,
        fov_y: 70.0,
    });
    s
}

/// "Making Connections"' bistro case in miniature: an open porch beside a sunlit yard. The roof
/// shadows the porch from a strong sun, two small wall lamps and a lantern light it, and the sky
/// reaches it through the open front, so every light class is present: local (lamps, lantern),
/// directional (the sun, which holds almost all of the scene's light power) and the sky.
pub fn courtyard(lamp: f32, sun: f32, sky: f32) -> Scene {
    let mut s = Scene::new("courtyard");
    let ground = s.add_material(Material::lambert("ground", Vec3::new(0.45, 0.42, 0.38)));
    let plaster = s.add_material(Material::lambert("plaster", Vec3::new(0.75, 0.7, 0.62)));
    let stone = s.add_material(Material::lambert("stone", Vec3::new(0.5, 0.5, 0.52)));
    let metal = s.add_material(Material::glossy(
        "metal",
        Vec3::new(0.95, 0.85, 0.6),
        1.0,
        0.25,
    ));
    let lamp_m = s.add_material(Material::emitter("lamp", Vec3::new(1.0, 0.8, 0.55) * lamp));
    let v = Vec3::new;
    s.add_quad(
        v(-25.0, 0.0, -25.0),
        v(-25.0, 0.0, 25.0),
        v(25.0, 0.0, 25.0),
        v(25.0, 0.0, -25.0),
        ground,
    );
    // The porch: back wall, side walls and roof (zero thickness), open towards +z.
    let (w, h, back, front) = (4.0f32, 3.2f32, -4.0f32, -0.5f32);
    s.add_quad(
        v(-w, 0.0, back),
        v(w, 0.0, back),
        v(w, h, back),
        v(-w, h, back),
        plaster,
    );
    s.add_quad(
        v(-w, 0.0, back),
        v(-w, h, back),
        v(-w, h, front),
        v(-w, 0.0, front),
        plaster,
    );
    s.add_quad(
        v(w, 0.0, back),
        v(w, 0.0, front),
        v(w, h, front),
        v(w, h, back),
        plaster,
    );
    s.add_quad(
        v(-w - 0.3, h, back),
        v(w + 0.3, h, back),
        v(w + 0.3, h, front),
        v(-w - 0.3, h, front),
        stone,
    );
    // Wall lamps facing +z, 1 cm in front of the back wall.
    for x in [-2.0f32, 2.0] {
        let z = back + 0.01;
        s.add_quad(
            v(x - 0.15, 2.05, z),
            v(x + 0.15, 2.05, z),
            v(x + 0.15, 2.35, z),
            v(x - 0.15, 2.35, z),
            lamp_m,
        );
    }
    // A pillar in the yard (sun shadow) and a metal sphere (sky and sun reflections).
    let (px, pz, r) = (2.5f32, 2.0f32, 0.25f32);
    let b = [
        v(px - r, 0.0, pz - r),
        v(px - r, 0.0, pz + r),
        v(px + r, 0.0, pz + r),
        v(px + r, 0.0, pz - r),
    ];
    let t = b.map(|p| p + v(0.0, 2.2, 0.0));
    s.add_box([b[0], b[1], b[2], b[3], t[0], t[1], t[2], t[3]], stone);
    add_uv_sphere(&mut s, v(-2.0, 0.8, 1.5), 0.8, metal, 16, 32);
    s.lights.push(PunctualLight {
        kind: PunctualKind::Directional,
        position: Vec3::ZERO,
        direction: v(0.5, -0.9, -0.3).normalize(),
        intensity: v(5.0, 4.7, 4.2) * sun,
        inner_cone: 0.0,
        outer_cone: 0.0,
    });
    s.lights.push(PunctualLight {
        kind: PunctualKind::Point,
        position: v(0.0, 2.7, -2.2),
        direction: Vec3::NEG_Y,
        intensity: v(3.0, 2.6, 2.0),
        inner_cone: 0.0,
        outer_cone: 0.0,
    });
    s.sky = v(0.3, 0.42, 0.7) * sky;
    s.camera = Some(Camera {
        position: v(1.0, 2.0, 8.0),
        target: v(0.0, 1.4, -2.0),
        up: Vec3::Y,
        fov_y: 55.0,
    });
    s
}

/// Six spheres with the talk's Callisto fits (each material named after its fit, with its
/// parameters: they apply under `[shading] brdf = "callisto"` or "callisto-proxima", and
/// lambert-ggx ignores them), a grey floor and back wall, a key light from the side at a
/// grazing angle (terminators), a back light (Fresnel) and a dim sky.
pub fn material_balls() -> Scene {
    use super::shading::{callisto_fit, CALLISTO_FITS};
    let mut s = Scene::new("material-balls");
    let v = Vec3::new;
    let grey = s.add_material(Material::lambert("floor", Vec3::splat(0.35)));
    s.add_quad(
        v(-8.0, 0.0, -4.0),
        v(-8.0, 0.0, 6.0),
        v(8.0, 0.0, 6.0),
        v(8.0, 0.0, -4.0),
        grey,
    );
    s.add_quad(
        v(-8.0, 0.0, -3.0),
        v(8.0, 0.0, -3.0),
        v(8.0, 5.0, -3.0),
        v(-8.0, 5.0, -3.0),
        grey,
    );
    for (i, name) in CALLISTO_FITS.iter().enumerate() {
        let f = callisto_fit(name).expect("fit table");
        let m = s.add_material(Material {
            metallic: f.metallic,
            roughness: f.roughness,
            specular: f.specular,
            callisto: f.callisto,
            ..Material::lambert(name, f.base)
        });
        s.named(name, |s| {
            add_uv_sphere(s, v(-5.0 + 2.0 * i as f32, 0.8, 0.0), 0.8, m, 32, 64)
        });
    }
    // Key light low on the left: the terminator runs down the middle of each ball.
    s.lights.push(PunctualLight {
        kind: PunctualKind::Directional,
        position: Vec3::ZERO,
        direction: v(1.0, -0.35, -0.25).normalize(),
        intensity: Vec3::splat(3.0),
        inner_cone: 0.0,
        outer_cone: 0.0,
    });
    // Back light above and behind the balls: grazing light towards the camera (Fresnel).
    s.lights.push(PunctualLight {
        kind: PunctualKind::Point,
        position: v(0.0, 3.0, -2.5),
        direction: Vec3::NEG_Y,
        intensity: Vec3::splat(25.0),
        inner_cone: 0.0,
        outer_cone: 0.0,
    });
    s.sky = Vec3::splat(0.1);
    s.camera = Some(Camera {
        position: v(0.0, 1.6, 7.5),
        target: v(0.0, 0.8, 0.0),
        up: Vec3::Y,
        fov_y: 45.0,
    });
    s
}
