//! Camera controls shared by every pane: orbit (left drag turns around the target, wheel
//! dollies) and fly (right drag looks around, W/A/S/D/Q/E move). Pure functions of the camera
//! and the input, so they are testable without a window.

use crate::scene::Camera;
use glam::{Quat, Vec3};

/// Radians per pixel of drag.
const TURN_PER_PIXEL: f32 = 0.008;

/// Orbits around the target: `dx` turns about the world up axis, `dy` tilts (kept off the poles).
pub fn orbit(cam: &Camera, dx: f32, dy: f32) -> Camera {
    let offset = cam.position - cam.target;
    let radius = offset.length().max(1e-4);
    let up = cam.up.try_normalize().unwrap_or(Vec3::Y);
    let yaw = Quat::from_axis_angle(up, -dx * TURN_PER_PIXEL);
    let mut dir = yaw * (offset / radius);
    let right = up.cross(dir).try_normalize().unwrap_or(Vec3::X);
    let tilted = Quat::from_axis_angle(right, dy * TURN_PER_PIXEL) * dir;
    // Stop short of looking straight up or down, where the basis flips.
    if tilted.dot(up).abs() < 0.995 {
        dir = tilted;
    }
    Camera {
        position: cam.target + dir * radius,
        ..*cam
    }
}

/// Moves towards (positive) or away from the target by a fraction of the distance per wheel step.
pub fn dolly(cam: &Camera, steps: f32) -> Camera {
    let offset = cam.position - cam.target;
    let scale = 0.9f32.powf(steps).clamp(0.01, 100.0);
    Camera {
        position: cam.target + offset * scale,
        ..*cam
    }
}

/// Fly-mode look: turns the view direction in place (the target moves, the position stays).
pub fn look(cam: &Camera, dx: f32, dy: f32) -> Camera {
    let dist = (cam.target - cam.position).length().max(1e-3);
    let (right, _, fwd) = cam.basis();
    let up = cam.up.try_normalize().unwrap_or(Vec3::Y);
    let yaw = Quat::from_axis_angle(up, -dx * TURN_PER_PIXEL);
    let pitch = Quat::from_axis_angle(right, -dy * TURN_PER_PIXEL);
    let mut dir = yaw * fwd;
    let pitched = pitch * dir;
    if pitched.dot(up).abs() < 0.995 {
        dir = pitched;
    }
    Camera {
        target: cam.position + dir * dist,
        ..*cam
    }
}

/// Fly-mode move in camera space (x right, y up, z forward), in scene units.
pub fn fly(cam: &Camera, local: Vec3) -> Camera {
    let (right, up, fwd) = cam.basis();
    let d = right * local.x + up * local.y + fwd * local.z;
    Camera {
        position: cam.position + d,
        target: cam.target + d,
        ..*cam
    }
}
