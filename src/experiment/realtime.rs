//! Real-time experiments (`mode = "real-time"`): which frames are scored, the camera of every
//! frame, one reference per scored frame (and per frame before one, for flicker), rendered once
//! and cached by content, and the temporal-stability measure: the mean change of the displayed
//! image between consecutive frames after reprojection, against the same for the references.
//!
//! A scene that plays (`[scene] time_scale`) is posed on the CPU at every frame the plan looks
//! at: reprojection then follows moving objects as well as the camera, and each scored frame
//! gets a ghost mask, the pixels a moving object uncovered in the frames just before it, where
//! caches that lag behind the motion leave their ghosts.

use super::rows::ReferenceInfo;
use super::spec::{camera_on_path, CameraKey, Event};
use crate::compare::{tonemap, Image};
use crate::scene::motion::Motion;
use crate::scene::{bvh::Bvh, Camera, Scene};
use glam::{Mat4, Vec3};
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
    /// Per scored frame of a playing scene, the pixels a moving object covered in one of the
    /// `ghost_frames` frames before it and no longer covers (absent: none).
    pub ghost_masks: BTreeMap<u32, Vec<bool>>,
    /// The first frame of the pose playback stops at (`[scene] play_until`).
    pub motion_stop_frame: Option<u32>,
    /// Scene time of each scored frame of a playing scene.
    pub scene_times: BTreeMap<u32, f32>,
}

impl RealTimePlan {
    pub fn frame_use(&self, frame: u32) -> FrameUse {
        frame_use(frame, self.every)
    }
}

pub const INVALID: u32 = u32::MAX;

/// The scene's triangles and BVH on the CPU, for reprojection; with the instances' transforms
/// and which of them the scene's motion moves.
pub struct CpuScene {
    tris: Vec<[Vec3; 3]>,
    bvh: Bvh,
    /// Per triangle, its instance (`NO_INSTANCE`: not in one).
    instance_of: Vec<u32>,
    transforms: Vec<Mat4>,
    moving: Vec<bool>,
}

const NO_INSTANCE: u32 = u32::MAX;

impl CpuScene {
    pub fn new(scene: &Scene) -> CpuScene {
        let tris = scene.triangle_positions();
        let bvh = Bvh::build(&tris);
        let mut instance_of = vec![NO_INSTANCE; tris.len()];
        for (i, inst) in scene.instances.iter().enumerate() {
            let range =
                inst.first_triangle as usize..(inst.first_triangle + inst.triangle_count) as usize;
            for t in range {
                if let Some(slot) = instance_of.get_mut(t) {
                    *slot = i as u32;
                }
            }
        }
        let mut moving = vec![false; scene.instances.len()];
        for m in scene.motion.iter().flat_map(|m| m.meshes.iter()) {
            if let Some(slot) = moving.get_mut(m.instance) {
                *slot = true;
            }
        }
        CpuScene {
            tris,
            bvh,
            instance_of,
            transforms: scene.instances.iter().map(|i| i.transform).collect(),
            moving,
        }
    }

    /// The moving instance a triangle belongs to, if any.
    fn moving_instance(&self, tri: u32) -> Option<usize> {
        let i = *self.instance_of.get(tri as usize)?;
        (i != NO_INSTANCE && self.moving.get(i as usize) == Some(&true)).then_some(i as usize)
    }

    /// Per pixel (through its centre): whether it shows a moving object.
    pub fn moving_coverage(&self, camera: &Camera, extent: [u32; 2]) -> Vec<bool> {
        let (w, h) = (extent[0], extent[1]);
        (0..w * h)
            .map(|i| {
                let d = ray_dir(camera, extent, (i % w) as f32 + 0.5, (i / w) as f32 + 0.5);
                self.bvh
                    .closest_hit(&self.tris, camera.position, d, f32::MAX)
                    .is_some_and(|(_, tri)| self.moving_instance(tri).is_some())
            })
            .collect()
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

/// The motion vectors of a camera move and of moving objects, from the geometry: per pixel of
/// the current frame (through its centre), the previous frame's pixel showing the same point,
/// or `INVALID` where that point was hidden from the previous camera (disocclusion) or off
/// screen. A point on a moving instance goes back with the instance (last frame's transform
/// times the inverse of this frame's). The sky is reprojected as a point far away.
pub fn reprojection_map(
    prev_scene: &CpuScene,
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
            let hit = scene.bvh.closest_hit(&scene.tris, cur.position, d, far);
            let mut p = cur.position + d * hit.map_or(far, |h| h.0);
            if let Some(i) = hit.and_then(|h| scene.moving_instance(h.1)) {
                if let (Some(now), Some(then)) =
                    (scene.transforms.get(i), prev_scene.transforms.get(i))
                {
                    p = (*then * now.inverse()).transform_point3(p);
                }
            }
            let Some((qx, qy)) = project(prev, extent, p) else {
                continue;
            };
            // Visible from the previous camera: nothing between it and the point.
            let to = p - prev.position;
            let dist = to.length();
            if dist <= 0.0 {
                continue;
            }
            let hidden = prev_scene
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

/// The scene of every frame: one pose for a still scene, else the pose playback gives frame f,
/// `Motion::time_after(t0, f)` (held still: the scene as the frame's reference renders it).
pub struct FramePoses<'a> {
    scene: &'a Scene,
    motion: Option<Motion>,
    t0: f32,
}

impl<'a> FramePoses<'a> {
    pub fn new(scene: &'a Scene) -> FramePoses<'a> {
        let motion = scene
            .motion
            .as_deref()
            .filter(|m| m.time_scale != 0.0)
            .cloned();
        FramePoses {
            scene,
            motion,
            t0: scene.posed_at.unwrap_or(0.0),
        }
    }

    /// Scene time of frame f (None: the scene does not play).
    pub fn time(&self, f: u32) -> Option<f32> {
        self.motion
            .as_ref()
            .map(|m| m.time_after(self.t0, f, crate::render::engine::PLAYBACK_FPS))
    }

    /// The scene posed for frame f, holding still.
    pub fn scene(&self, f: u32) -> anyhow::Result<Scene> {
        let mut scene = self.scene.clone();
        if let (Some(m), Some(t)) = (&self.motion, self.time(f)) {
            let mut held = m.clone();
            held.time_scale = 0.0;
            held.apply(&mut scene, t)?;
            scene.motion = Some(std::sync::Arc::new(held));
        }
        Ok(scene)
    }

    /// The first frame of the pose playback stops at (`play_until`), when it stops.
    pub fn stop_frame(&self, frames: u32) -> Option<u32> {
        let m = self.motion.as_ref()?;
        m.play_until?;
        let last = self.time(frames.checked_sub(1)?)?;
        (0..frames).find(|f| self.time(*f) == Some(last) && self.time(f + 1) == Some(last))
    }
}

/// What the plan computes from the CPU scene of each frame: reprojection maps for every scored
/// frame after the first, and ghost masks for a playing scene.
pub struct CpuFrames {
    pub reprojection: BTreeMap<u32, Option<Vec<u32>>>,
    pub ghost_masks: BTreeMap<u32, Vec<bool>>,
}

/// Reprojection maps (shared by all runs) and, for a playing scene, each scored frame's ghost
/// mask over the `ghost_frames` frames before it.
pub fn cpu_frames(
    poses: &FramePoses,
    cameras: &[Camera],
    every: u32,
    ghost_frames: u32,
    extent: [u32; 2],
) -> anyhow::Result<CpuFrames> {
    let plays = poses.motion.is_some();
    let frames = cameras.len() as u32;
    let scored: Vec<u32> = (0..frames)
        .filter(|f| frame_use(*f, every) == FrameUse::Scored)
        .collect();
    let mut needed = BTreeSet::new();
    for &f in &scored {
        needed.insert(f);
        if f > 0 {
            needed.insert(f - 1);
        }
        if plays {
            needed.extend(f.saturating_sub(ghost_frames)..f);
        }
    }
    let mut out = CpuFrames {
        reprojection: BTreeMap::new(),
        ghost_masks: BTreeMap::new(),
    };
    // The last frame's scene (with its time), reused while the pose holds.
    let mut last: Option<(u32, Option<f32>, std::rc::Rc<CpuScene>)> = None;
    let mut coverage: BTreeMap<u32, Vec<bool>> = BTreeMap::new();
    for f in needed {
        let time = poses.time(f);
        let scene = match &last {
            Some((_, t, s)) if *t == time => s.clone(),
            _ => std::rc::Rc::new(CpuScene::new(&poses.scene(f)?)),
        };
        if plays {
            coverage.insert(f, scene.moving_coverage(&cameras[f as usize], extent));
            coverage.retain(|k, _| k + ghost_frames + 1 > f);
        }
        if f > 0 && frame_use(f, every) == FrameUse::Scored {
            let (prev_cam, cam) = (&cameras[f as usize - 1], &cameras[f as usize]);
            let map = match &last {
                Some((k, t, prev)) if *k + 1 == f => (prev_cam != cam || *t != time)
                    .then(|| reprojection_map(prev, &scene, prev_cam, cam, extent)),
                _ => None,
            };
            out.reprojection.insert(f, map);
            if let Some(now) = coverage.get(&f) {
                let mut mask = vec![false; now.len()];
                for (k, before) in coverage.range(f.saturating_sub(ghost_frames)..f) {
                    let _ = k;
                    for (m, (b, n)) in mask.iter_mut().zip(before.iter().zip(now)) {
                        *m |= *b && !*n;
                    }
                }
                if mask.iter().any(|m| *m) {
                    out.ghost_masks.insert(f, mask);
                }
            }
        }
        last = Some((f, time, scene));
    }
    Ok(out)
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
        let same = reprojection_map(&cpu, &cpu, &cam, &cam, extent);
        assert!(same.iter().enumerate().all(|(i, j)| *j == i as u32));
        // Moving the camera 0.5 sideways along its right vector (about 3 pixels here): points shift left on screen.
        let (right, _, _) = cam.basis();
        let moved = Camera {
            position: cam.position + right * 0.5,
            target: cam.target + right * 0.5,
            ..cam
        };
        let map = reprojection_map(&cpu, &cpu, &cam, &moved, extent);
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

    /// The built-in `moving` scene playing at `time_scale`, optionally stopping.
    fn moving(time_scale: f32, play_until: Option<f32>) -> Scene {
        let mut scene =
            crate::scene::builtin::build("moving", &Default::default()).expect("moving");
        let m = std::sync::Arc::make_mut(scene.motion.as_mut().expect("motion"));
        m.time_scale = time_scale;
        m.play_until = play_until;
        scene
    }

    #[test]
    fn reprojection_follows_a_moving_object_and_ghosts_are_what_it_uncovered() {
        // 0.1 s a frame: the ball rolls a few pixels a frame at 48x48.
        let scene = moving(6.0, None);
        let poses = FramePoses::new(&scene);
        let cam = scene.default_camera();
        let extent = [48, 48];
        let (f, t_then, t_now) = (20u32, poses.time(19).unwrap(), poses.time(20).unwrap());
        assert!(t_now > t_then);
        let (then, now) = (
            CpuScene::new(&poses.scene(f - 1).unwrap()),
            CpuScene::new(&poses.scene(f).unwrap()),
        );
        let map = reprojection_map(&then, &now, &cam, &cam, extent);
        let (mut on_object, mut followed, mut still_same, mut still) = (0, 0, 0, 0);
        for (i, &j) in map.iter().enumerate() {
            let (x, y) = (i as u32 % 48, i as u32 / 48);
            let d = ray_dir(&cam, extent, x as f32 + 0.5, y as f32 + 0.5);
            let Some((t, tri)) = now.bvh.closest_hit(&now.tris, cam.position, d, f32::MAX) else {
                continue;
            };
            let Some(inst) = now.moving_instance(tri) else {
                still += 1;
                still_same += usize::from(j == i as u32);
                continue;
            };
            // Interior pixels only: at a silhouette the pixel centre it maps to may miss.
            let same = |dx: i32, dy: i32| {
                let dn = ray_dir(
                    &cam,
                    extent,
                    x as f32 + 0.5 + dx as f32,
                    y as f32 + 0.5 + dy as f32,
                );
                now.bvh
                    .closest_hit(&now.tris, cam.position, dn, f32::MAX)
                    .is_some_and(|(_, k)| now.moving_instance(k) == Some(inst))
            };
            if j == INVALID || !(same(1, 0) && same(-1, 0) && same(0, 1) && same(0, -1)) {
                continue;
            }
            on_object += 1;
            // The pixel it maps to shows the same object last frame, at the point moved back
            // with it (within a pixel's footprint at that depth).
            let (qx, qy) = (j % 48, j / 48);
            let dq = ray_dir(&cam, extent, qx as f32 + 0.5, qy as f32 + 0.5);
            let Some((tq, tri_q)) = then.bvh.closest_hit(&then.tris, cam.position, dq, f32::MAX)
            else {
                continue;
            };
            let p_now = cam.position + d * t;
            let back =
                (then.transforms[inst] * now.transforms[inst].inverse()).transform_point3(p_now);
            let p_then = cam.position + dq * tq;
            let footprint = 2.5 * t * (cam.fov_y.to_radians() * 0.5).tan() * 2.0 / 48.0;
            if then.moving_instance(tri_q) == Some(inst) && (p_then - back).length() < footprint {
                followed += 1;
            }
        }
        println!("moving objects: {followed} of {on_object} pixels reproject onto their object; {still_same} of {still} still pixels map to themselves");
        assert!(on_object > 10, "{on_object} pixels on moving objects");
        assert!(followed * 10 >= on_object * 9, "{followed} of {on_object}");
        // All but those the object hid last frame (disoccluded: no previous pixel).
        assert!(still_same * 100 >= still * 98, "{still_same} of {still}");
        // Ghost masks: pixels a moving object covered in the frames before and not now.
        let cameras = vec![cam; 24];
        let frames = cpu_frames(&poses, &cameras, 4, 6, extent).unwrap();
        assert!(!frames.ghost_masks.is_empty(), "the ball uncovers nothing");
        for (f, mask) in &frames.ghost_masks {
            let now = CpuScene::new(&poses.scene(*f).unwrap()).moving_coverage(&cam, extent);
            let mut before = vec![false; mask.len()];
            for k in f.saturating_sub(6)..*f {
                let c = CpuScene::new(&poses.scene(k).unwrap()).moving_coverage(&cam, extent);
                before.iter_mut().zip(c).for_each(|(b, c)| *b |= c);
            }
            for i in 0..mask.len() {
                assert_eq!(mask[i], before[i] && !now[i], "frame {f} pixel {i}");
            }
        }
        // A moving scene's scored frames all reproject through object motion.
        assert!(frames.reprojection.values().all(|m| m.is_some()));
    }

    #[test]
    fn playback_stops_at_play_until() {
        let scene = moving(6.0, Some(1.0));
        let poses = FramePoses::new(&scene);
        assert_eq!(poses.time(5), Some(0.5));
        assert_eq!(poses.time(10), Some(1.0));
        assert_eq!(poses.time(30), Some(1.0));
        assert_eq!(poses.stop_frame(30), Some(10));
        assert_eq!(FramePoses::new(&moving(6.0, None)).stop_frame(30), None);
        // The same held pose: the scenes of frames after the stop are the same.
        let (a, b) = (poses.scene(12).unwrap(), poses.scene(29).unwrap());
        assert_eq!(a.positions, b.positions);
    }
}
