//! The built-in `interior` scene (issue 58): what Callisto's shadows were built for (seed 002,
//! a console game's dark interiors): a closed, unlit hall of pillars and crates lit only by
//! `lights` (default 24) small ranged point lights on the walls and pillars, plus four lanterns
//! (small emissive octahedra, 8 triangle lights each) carried round the hall and one crate that
//! slides, in one looped 8-second clip (`[scene] time_scale` plays it). Most of the hall is in
//! the shadow of the pillars for most lights: the static/dynamic split, the tile rejection and
//! the per-tile light lists have something to save. No sky, no sun: the light is local.

use super::animation::{Interpolation, Property, Trs};
use super::motion::MotionBuilder;
use super::{Camera, Material, PunctualKind, PunctualLight, Scene};
use anyhow::Result;
use glam::{Quat, Vec3};

/// Length of the clip (seconds).
pub const DURATION: f32 = 8.0;
/// The carried lanterns.
pub const LANTERNS: usize = 4;

pub fn interior(lights: u32) -> Result<Scene> {
    let mut s = Scene::new("interior");
    let v = Vec3::new;
    let plaster = s.add_material(Material::lambert("plaster", v(0.55, 0.52, 0.48)));
    let stone = s.add_material(Material::lambert("stone", v(0.35, 0.34, 0.32)));
    let wood = s.add_material(Material::lambert("crate", v(0.42, 0.28, 0.15)));
    let lantern = s.add_material(Material::emitter("lantern", v(30.0, 18.0, 6.0)));
    let (w, h, l) = (16.0f32, 4.0f32, 12.0f32);
    // A closed box (normals inward): floor, ceiling, four walls.
    s.add_quad(
        v(0.0, 0.0, 0.0),
        v(0.0, 0.0, l),
        v(w, 0.0, l),
        v(w, 0.0, 0.0),
        stone,
    );
    s.add_quad(
        v(0.0, h, 0.0),
        v(w, h, 0.0),
        v(w, h, l),
        v(0.0, h, l),
        plaster,
    );
    s.add_quad(
        v(0.0, 0.0, l),
        v(0.0, h, l),
        v(w, h, l),
        v(w, 0.0, l),
        plaster,
    );
    s.add_quad(
        v(0.0, 0.0, 0.0),
        v(w, 0.0, 0.0),
        v(w, h, 0.0),
        v(0.0, h, 0.0),
        plaster,
    );
    s.add_quad(
        v(0.0, 0.0, 0.0),
        v(0.0, h, 0.0),
        v(0.0, h, l),
        v(0.0, 0.0, l),
        plaster,
    );
    s.add_quad(
        v(w, 0.0, 0.0),
        v(w, 0.0, l),
        v(w, h, l),
        v(w, h, 0.0),
        plaster,
    );
    // Two rows of four pillars, 0.6 m square.
    let mut pillars = Vec::new();
    for row in [4.0f32, 8.0] {
        for col in [3.2f32, 6.4, 9.6, 12.8] {
            s.add_aabb(
                v(col - 0.3, 0.0, row - 0.3),
                v(col + 0.3, h, row + 0.3),
                stone,
            );
            pillars.push(v(col, 0.0, row));
        }
    }
    // Static crates between them.
    for (x, z, size) in [
        (1.5f32, 2.0f32, 0.9f32),
        (5.0, 6.0, 0.7),
        (11.0, 10.5, 1.0),
        (14.5, 6.5, 0.8),
    ] {
        s.add_aabb(
            v(x - size * 0.5, 0.0, z - size * 0.5),
            v(x + size * 0.5, size, z + size * 0.5),
            wood,
        );
    }
    // Static point lights: on the walls at 2.6 m and on the pillars' faces at 2.2 m, in warm
    // and cold colours (a fixed sequence, so the scene is the same on every machine).
    let colours = [
        v(1.0, 0.72, 0.42),
        v(0.55, 0.7, 1.0),
        v(1.0, 0.9, 0.75),
        v(0.9, 0.5, 0.3),
    ];
    let mut spots = Vec::new();
    for k in 0..8 {
        let x = 1.0 + k as f32 * 2.0;
        spots.push(v(x, 2.6, 0.15));
        spots.push(v(x, 2.6, l - 0.15));
    }
    for p in &pillars {
        spots.push(*p + v(0.0, 2.2, -0.4));
        spots.push(*p + v(0.0, 2.2, 0.4));
    }
    for k in 0..lights as usize {
        // Beyond the listed places, lights go round again half a metre lower.
        let p = spots[k % spots.len()] - v(0.0, 0.5 * (k / spots.len()) as f32, 0.0);
        s.lights.push(PunctualLight {
            kind: PunctualKind::Point,
            position: p,
            direction: Vec3::NEG_Y,
            intensity: colours[k % colours.len()] * 3.0,
            inner_cone: 0.0,
            outer_cone: 0.0,
        });
    }

    // The moving things: four lanterns carried round the hall at different heights and speeds
    // (each once or twice round in the clip), and a crate sliding along the middle aisle.
    let mut motion = MotionBuilder::new("interior");
    let at = |p: Vec3| Trs {
        translation: p,
        rotation: Quat::IDENTITY,
        scale: Vec3::ONE,
    };
    let steps = 32usize;
    let times: Vec<f32> = (0..=steps)
        .map(|k| k as f32 * DURATION / steps as f32)
        .collect();
    for i in 0..LANTERNS {
        let turns = if i % 2 == 0 { 1.0 } else { -2.0 };
        let (cx, cz, r, y) = (
            4.8 + 6.4 * (i / 2) as f32,
            6.0,
            1.6 + 0.3 * i as f32,
            1.4 + 0.3 * i as f32,
        );
        let phase = i as f32 * 1.3;
        let place = move |t: f32| {
            let a = phase + std::f32::consts::TAU * turns * t / DURATION;
            v(cx + r * a.cos(), y, cz + r * a.sin())
        };
        let node = motion.object(&mut s, at(place(0.0)), |s| add_octahedron(s, 0.1, lantern))?;
        motion.track(
            node,
            Property::Translation,
            times.clone(),
            times.iter().map(|&t| place(t).extend(0.0)).collect(),
            Interpolation::Linear,
        )?;
    }
    let crate_at = |t: f32| {
        let u = 0.5 * (1.0 - (std::f32::consts::TAU * t / DURATION).cos());
        v(2.0 + 12.0 * u, 0.0, 6.0)
    };
    let sliding = motion.object(&mut s, at(crate_at(0.0)), |s| {
        s.add_aabb(v(-0.45, 0.0, -0.45), v(0.45, 0.9, 0.45), wood)
    })?;
    motion.track(
        sliding,
        Property::Translation,
        times.clone(),
        times.iter().map(|&t| crate_at(t).extend(0.0)).collect(),
        Interpolation::Linear,
    )?;
    motion.finish(&mut s);

    s.camera = Some(Camera {
        position: v(0.8, 1.7, 0.8),
        target: v(9.0, 1.2, 8.0),
        up: Vec3::Y,
        fov_y: 60.0,
    });
    Ok(s)
}

/// A regular octahedron of radius `r` at the origin (8 triangles, normals outward).
fn add_octahedron(s: &mut Scene, r: f32, material: u32) {
    let [px, nx, py, ny, pz, nz] = [
        Vec3::X * r,
        -Vec3::X * r,
        Vec3::Y * r,
        -Vec3::Y * r,
        Vec3::Z * r,
        -Vec3::Z * r,
    ];
    for (a, b) in [(px, pz), (pz, nx), (nx, nz), (nz, px)] {
        s.add_triangle([a, py, b], material);
        s.add_triangle([b, ny, a], material);
    }
}
