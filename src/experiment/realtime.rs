//! Real-time experiments (`mode = "real-time"`): which frames are scored, the camera of every
//! frame, one reference per scored frame (and per frame before one, for flicker), rendered once
//! and cached by content, and the temporal-stability measure: the mean change of the displayed
//! image between consecutive frames after reprojection, against the same for the references.

use super::rows::ReferenceInfo;
use super::spec::{camera_on_path, CameraKey, Event};
use crate::compare::{tonemap, Image};
use crate::scene::{bvh::Bvh, Camera, Scene};
use glam::Vec3;
use std::collections::{BTreeMap, BTreeSet};

/// What a real-time run does with a frame's image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameUse {
    /// Scored against its reference (and its flicker against the frame before).
    Scored,
    /// Kept only as the previous frame of a scored one (flicker).
    Previous,
    Unused,
}

/// Frames N-1, 2N-1, ... are scored (N = `reference_every`), so `reference_every = 4` scores a
/// subset of the frames `reference_every = 1` scores, against the same references.
pub fn frame_use(frame: u32, every: u32) -> FrameUse {
    let every = every.max(1);
    if (frame + 1).is_multiple_of(every) {
        FrameUse::Scored
    } else if (frame + 2).is_multiple_of(every) {
        FrameUse::Previous
    } else {
        FrameUse::Unused
    }
}

/// Frames that need a reference: the scored ones and the frame before each.
pub fn reference_frames(frames: u32, every: u32) -> BTreeSet<u32> {
    (0..frames)
        .filter(|f| frame_use(*f, every) != FrameUse::Unused)
        .collect()
}

/// Each frame's reference gets its own seed: consecutive references are independent renders,
/// so their flicker includes the reference's own residual noise, as a run's does.
pub fn frame_seed(reference_seed: u32, frame: u32) -> u32 {
    reference_seed ^ (frame.wrapping_add(1)).wrapping_mul(0x9E37_79B9)
}

/// Cache key of a frame's reference: its scene state's key, camera and seed.
pub fn frame_reference_key(state_key: &str, camera: &Camera, seed: u32) -> String {
    use std::hash::Hasher;
    let canonical = serde_json::json!({ "state": state_key, "camera": camera, "seed": seed });
    let mut h = fnv::FnvHasher::default();
    h.write(canonical.to_string().as_bytes());
    format!("{:016x}", h.finish())
}

/// The camera of every frame: on the path when one is given, else the camera of the scene
/// state the frame sees (events may move it).
pub fn frame_cameras(
    frames: u32,
    path: &[CameraKey],
    base: &Camera,
    events: &[Event],
) -> Vec<Camera> {
    let mut camera = *base;
    (0..frames)
        .map(|f| {
            for e in events.iter().filter(|e| e.frame == f) {
                if let Some(c) = e.camera {
                    camera = c;
                }
            }
            if path.is_empty() {
                camera
            } else {
                camera_on_path(path, f, base)
            }
        })
        .collect()
}

/// Everything a real-time experiment prepares before its runs.
pub struct RealTimePlan {
    pub every: u32,
    pub cameras: Vec<Camera>,
    pub references: BTreeMap<u32, Image>,
    pub infos: Vec<ReferenceInfo>,
    /// For each scored frame f > 0: per pixel of f, the pixel of f-1 that shows the same
    /// surface point (`INVALID` where it was hidden or off screen); `None`: the camera did not
    /// move (every pixel maps to itself).
    pub reprojection: BTreeMap<u32, Option<Vec<u32>>>,
    /// The references' flicker per scored frame f > 0.
    pub reference_flicker: BTreeMap<u32, f64>,
}

impl RealTimePlan {
    pub fn frame_use(&self, frame: u32) -> FrameUse {
        frame_use(frame, self.every)
    }
}

pub const INVALID: u32 = u32::MAX;

/// The scene's triangles and BVH on the CPU, for reprojection.
pub struct CpuScene {
    tris: Vec<[Vec3; 3]>,
    bvh: Bvh,
}

impl CpuScene {
    pub fn new(scene: &Scene) -> CpuScene {
        let tris = scene.triangle_positions();
        let bvh = Bvh::build(&tris);
        CpuScene { tris, bvh }
    }

    /// Original index of the triangle seen through a pixel position (in pixels), if any: the
    /// viewer's "material under the cursor".
    pub fn pick(&self, camera: &Camera, extent: [u32; 2], px: f32, py: f32) -> Option<u32> {
        let dir = ray_dir(camera, extent, px, py);
        self.bvh
            .closest_hit(&self.tris, camera.position, dir, f32::MAX)
            .map(|(_, tri)| tri)
    }

    fn closest(&self, origin: Vec3, dir: Vec3, t_max: f32) -> Option<f32> {
        self.bvh
            .closest_hit(&self.tris, origin, dir, t_max)
            .map(|(t, _)| t)
    }
}

/// Camera ray through a pixel position (in pixels), as `camera_ray_dir` in frame.wgsl.
fn ray_dir(camera: &Camera, extent: [u32; 2], px: f32, py: f32) -> Vec3 {
    let (right, up, fwd) = camera.basis();
    let aspect = extent[0] as f32 / extent[1] as f32;
    let tan = (camera.fov_y.clamp(0.01, 179.0).to_radians() * 0.5).tan();
    let nx = 2.0 * px / extent[0] as f32 - 1.0;
    let ny = 1.0 - 2.0 * py / extent[1] as f32;
    (fwd + nx * right * tan * aspect + ny * up * tan).normalize()
}

/// Pixel of `camera` a world point projects to, if in front of it and on screen.
fn project(camera: &Camera, extent: [u32; 2], p: Vec3) -> Option<(u32, u32)> {
    let (right, up, fwd) = camera.basis();
    let aspect = extent[0] as f32 / extent[1] as f32;
    let tan = (camera.fov_y.clamp(0.01, 179.0).to_radians() * 0.5).tan();
    let v = p - camera.position;
    let z = v.dot(fwd);
    if z <= 1e-6 {
        return None;
    }
    let nx = v.dot(right) / (z * tan * aspect);
    let ny = v.dot(up) / (z * tan);
    let px = (nx + 1.0) * 0.5 * extent[0] as f32;
    let py = (1.0 - ny) * 0.5 * extent[1] as f32;
    (px >= 0.0 && py >= 0.0 && px < extent[0] as f32 && py < extent[1] as f32)
        .then_some((px as u32, py as u32))
}

/// The motion vectors of a camera move, from the geometry: per pixel of the current frame
/// (through its centre), the previous frame's pixel showing the same point, or `INVALID`
/// where that point was hidden from the previous camera (disocclusion) or off screen. The sky
/// is reprojected as a point far away.
pub fn reprojection_map(
    scene: &CpuScene,
    prev: &Camera,
    cur: &Camera,
    extent: [u32; 2],
) -> Vec<u32> {
    let (w, h) = (extent[0], extent[1]);
    let far = 1e5f32;
    let mut map = vec![INVALID; (w * h) as usize];
    for y in 0..h {
        for x in 0..w {
            let d = ray_dir(cur, extent, x as f32 + 0.5, y as f32 + 0.5);
            let t = scene.closest(cur.position, d, far).unwrap_or(far);
            let p = cur.position + d * t;
            let Some((qx, qy)) = project(prev, extent, p) else {
                continue;
            };
            // Visible from the previous camera: nothing between it and the point.
            let to = p - prev.position;
            let dist = to.length();
            if dist <= 0.0 {
                continue;
            }
            let hidden = scene
                .closest(prev.position, to / dist, dist * (1.0 - 1e-3))
                .is_some();
            if !hidden {
                map[(y * w + x) as usize] = qy * w + qx;
            }
        }
    }
    map
}

/// Per pixel luminance of the displayed image (the preset's exposure and tone curve, sRGB
/// encoded): flicker is judged on what the screen shows, so a firefly counts as far as it
/// changes the displayed pixel.
pub fn display_luminance(image: &Image, tm: &tonemap::Settings) -> Vec<f32> {
    let scale = 2f32.powf(tm.exposure);
    image
        .rgb
        .chunks_exact(3)
        .map(|p| {
            let c: Vec<f32> = p
                .iter()
                .map(|v| {
                    let v = if v.is_finite() { *v } else { 0.0 };
                    tonemap::linear_to_srgb(tm.curve(v * scale))
                })
                .collect();
            0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
        })
        .collect()
}

/// Mean |current - reprojected previous| over the pixels that reproject (None if none do).
pub fn flicker(current: &[f32], previous: &[f32], map: Option<&[u32]>) -> Option<f64> {
    let (mut sum, mut n) = (0.0f64, 0usize);
    for (i, c) in current.iter().enumerate() {
        let j = match map {
            Some(m) if m[i] == INVALID => continue,
            Some(m) => m[i] as usize,
            None => i,
        };
        sum += (c - previous[j]).abs() as f64;
        n += 1;
    }
    (n > 0).then(|| sum / n as f64)
}

/// Reprojection maps for every scored frame after the first, shared by all runs.
pub fn reprojection_maps(
    scene: &Scene,
    cameras: &[Camera],
    every: u32,
    extent: [u32; 2],
) -> BTreeMap<u32, Option<Vec<u32>>> {
    let mut cpu: Option<CpuScene> = None;
    let mut maps = BTreeMap::new();
    for f in 1..cameras.len() as u32 {
        if frame_use(f, every) != FrameUse::Scored {
            continue;
        }
        let (prev, cur) = (&cameras[f as usize - 1], &cameras[f as usize]);
        let map = (prev != cur).then(|| {
            let cpu = cpu.get_or_insert_with(|| CpuScene::new(scene));
            reprojection_map(cpu, prev, cur, extent)
        });
        maps.insert(f, map);
    }
    maps
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scored_frames_of_every_four_are_a_subset_of_every_one() {
        let all: Vec<u32> = (0..16)
            .filter(|f| frame_use(*f, 1) == FrameUse::Scored)
            .collect();
        let four: Vec<u32> = (0..16)
            .filter(|f| frame_use(*f, 4) == FrameUse::Scored)
            .collect();
        assert_eq!(all.len(), 16);
        assert_eq!(four, vec![3, 7, 11, 15]);
        assert_eq!(
            reference_frames(16, 4).into_iter().collect::<Vec<_>>(),
            vec![2, 3, 6, 7, 10, 11, 14, 15]
        );
    }

    #[test]
    fn reprojection_of_a_still_camera_is_identity_and_a_pan_shifts_pixels() {
        let scene = crate::scene::builtin::build("cornell", &Default::default()).expect("cornell");
        let cpu = CpuScene::new(&scene);
        let cam = scene.default_camera();
        let extent = [32, 32];
        let same = reprojection_map(&cpu, &cam, &cam, extent);
        assert!(same.iter().enumerate().all(|(i, j)| *j == i as u32));
        // Moving the camera 0.5 sideways along its right vector (about 3 pixels here): points shift left on screen.
        let (right, _, _) = cam.basis();
        let moved = Camera {
            position: cam.position + right * 0.5,
            target: cam.target + right * 0.5,
            ..cam
        };
        let map = reprojection_map(&cpu, &cam, &moved, extent);
        let valid = map.iter().filter(|j| **j != INVALID).count();
        assert!(valid > 900, "{valid} of 1024 pixels reproject");
        let shifted = map
            .iter()
            .enumerate()
            .filter(|(i, j)| **j != INVALID && (**j % 32) > (*i as u32 % 32))
            .count();
        assert!(
            shifted > 500,
            "{shifted} pixels map to a pixel further right"
        );
    }
}
