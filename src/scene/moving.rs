//! The built-in `moving` scene (issue 36): a Cornell-like room (open towards the camera) with a
//! doorway in its back wall. In one looped 8-second clip, "moving":
//! - a sliding door opens the doorway onto a sunlit exterior from 0.5 s to 2.5 s (two seconds),
//!   stays open, and closes from 5 s to 7 s;
//! - a ball rolls across the floor through the sunlight and back (rotation matching the
//!   distance rolled);
//! - a small orange lamp (an emissive sphere, so a light of the light pool) is carried once
//!   round a circle under the ceiling.
//!
//! A dim ceiling light keeps the room lit while the door is shut. Each moving object is an
//! instance of its own (src/scene/motion.rs); `[scene] time_scale` plays the clip, and
//! `[scene] time` poses it (a reference of any frame).

use super::animation::{Interpolation, Property, Trs};
use super::builtin::add_uv_sphere;
use super::motion::MotionBuilder;
use super::{Camera, Material, PunctualKind, PunctualLight, Scene};
use anyhow::Result;
use glam::{Quat, Vec3, Vec4};

/// Length of the clip (seconds).
pub const DURATION: f32 = 8.0;
/// Keyframe spacing of the ball and the lamp (seconds): a rotation between two keys stays well
/// under half a turn, so slerp follows the roll.
const KEY_STEP: f32 = 0.25;

pub fn moving() -> Result<Scene> {
    let mut s = Scene::new("moving");
    let white = s.add_material(Material::lambert("white", Vec3::new(0.725, 0.71, 0.68)));
    let red = s.add_material(Material::lambert("red", Vec3::new(0.63, 0.065, 0.05)));
    let green = s.add_material(Material::lambert("green", Vec3::new(0.14, 0.45, 0.091)));
    let ground = s.add_material(Material::lambert("ground", Vec3::new(0.45, 0.42, 0.35)));
    let wood = s.add_material(Material::lambert("door", Vec3::new(0.45, 0.3, 0.18)));
    let ball = s.add_material(Material::glossy(
        "ball",
        Vec3::new(0.15, 0.3, 0.75),
        0.0,
        0.35,
    ));
    let lamp = s.add_material(Material::emitter("lamp", Vec3::new(40.0, 16.0, 4.0)));
    let ceiling_light = s.add_material(Material::emitter("ceiling light", Vec3::splat(4.0)));
    let (w, h, l) = (6.0f32, 4.0f32, 6.0f32);
    let v = Vec3::new;
    s.add_quad(
        v(0.0, 0.0, 0.0),
        v(0.0, 0.0, l),
        v(w, 0.0, l),
        v(w, 0.0, 0.0),
        white,
    ); // floor
    s.add_quad(
        v(0.0, h, 0.0),
        v(w, h, 0.0),
        v(w, h, l),
        v(0.0, h, l),
        white,
    ); // ceiling
    s.add_quad(
        v(0.0, 0.0, 0.0),
        v(0.0, h, 0.0),
        v(0.0, h, l),
        v(0.0, 0.0, l),
        green,
    ); // x = 0
    s.add_quad(v(w, 0.0, 0.0), v(w, 0.0, l), v(w, h, l), v(w, h, 0.0), red); // x = w
                                                                             // The back wall around a doorway 2 wide and 3 high, facing the camera.
    let (d0, d1, dh) = (2.0f32, 4.0f32, 3.0f32);
    let back = |s: &mut Scene, x0: f32, x1: f32, y0: f32, y1: f32| {
        s.add_quad(
            v(x0, y0, l),
            v(x0, y1, l),
            v(x1, y1, l),
            v(x1, y0, l),
            white,
        );
    };
    back(&mut s, 0.0, d0, 0.0, h);
    back(&mut s, d1, w, 0.0, h);
    back(&mut s, d0, d1, dh, h);
    // Outside: the ground beyond the doorway, in the sun.
    s.add_quad(
        v(-20.0, -0.001, l),
        v(-20.0, -0.001, 40.0),
        v(26.0, -0.001, 40.0),
        v(26.0, -0.001, l),
        ground,
    );
    let y = h - 0.001;
    s.add_quad(
        v(2.5, y, 2.5),
        v(3.5, y, 2.5),
        v(3.5, y, 3.5),
        v(2.5, y, 3.5),
        ceiling_light,
    );
    s.sky = v(0.5, 0.65, 1.0) * 0.6;
    s.lights.push(PunctualLight {
        kind: PunctualKind::Directional,
        position: Vec3::ZERO,
        direction: v(0.25, -0.45, -1.0).normalize(),
        intensity: v(8.0, 7.6, 7.0),
        inner_cone: 0.0,
        outer_cone: 0.0,
    });

    let mut motion = MotionBuilder::new("moving");
    let at = |p: Vec3| Trs {
        translation: p,
        rotation: Quat::IDENTITY,
        scale: Vec3::ONE,
    };
    // The door: 2 wide, 3.02 high, 8 cm thick, just inside the wall; it slides to the left (as
    // seen) in front of the wall's solid part.
    let (door_closed, door_open) = (v(3.0, 0.0, l - 0.08), v(1.0, 0.0, l - 0.08));
    let door = motion.object(&mut s, at(door_closed), |s| {
        let (a, b, t) = (1.0f32, 3.02f32, 0.04f32);
        s.add_aabb(v(-a, 0.0, -t), v(a, b, t), wood);
    })?;
    let p = |x: Vec3| x.extend(0.0);
    motion.track(
        door,
        Property::Translation,
        vec![0.0, 0.5, 2.5, 5.0, 7.0, DURATION],
        vec![
            p(door_closed),
            p(door_closed),
            p(door_open),
            p(door_open),
            p(door_closed),
            p(door_closed),
        ],
        Interpolation::Linear,
    )?;

    // The ball: radius 0.45, rolling from x = 1.2 to 4.8 and back (smoothly, over the clip).
    let r = 0.45f32;
    let (x0, x1) = (1.2f32, 4.8f32);
    let ball_node = motion.object(&mut s, at(v(x0, r, 3.6)), |s| {
        add_uv_sphere(s, Vec3::ZERO, r, ball, 16, 32);
    })?;
    let keys = (DURATION / KEY_STEP).round() as usize;
    let times: Vec<f32> = (0..=keys).map(|k| k as f32 * KEY_STEP).collect();
    let ball_x =
        |t: f32| x0 + (x1 - x0) * 0.5 * (1.0 - (std::f32::consts::TAU * t / DURATION).cos());
    motion.track(
        ball_node,
        Property::Translation,
        times.clone(),
        times
            .iter()
            .map(|&t| v(ball_x(t), r, 3.6).extend(0.0))
            .collect(),
        Interpolation::Linear,
    )?;
    motion.track(
        ball_node,
        Property::Rotation,
        times.clone(),
        times
            .iter()
            .map(|&t| Vec4::from(Quat::from_rotation_z(-(ball_x(t) - x0) / r)))
            .collect(),
        Interpolation::Linear,
    )?;

    // The lamp: radius 0.12, once round a circle of radius 1.6 at 2.6 m.
    let lamp_at = |t: f32| {
        let a = std::f32::consts::TAU * t / DURATION;
        v(3.0 + 1.6 * a.cos(), 2.6, 3.0 + 1.6 * a.sin())
    };
    let lamp_node = motion.object(&mut s, at(lamp_at(0.0)), |s| {
        add_uv_sphere(s, Vec3::ZERO, 0.12, lamp, 8, 16);
    })?;
    motion.track(
        lamp_node,
        Property::Translation,
        times.clone(),
        times.iter().map(|&t| lamp_at(t).extend(0.0)).collect(),
        Interpolation::Linear,
    )?;
    motion.finish(&mut s);

    s.camera = Some(Camera {
        position: v(3.0, 2.0, -7.5),
        target: v(3.0, 1.8, 0.0),
        up: Vec3::Y,
        fov_y: 42.0,
    });
    Ok(s)
}
