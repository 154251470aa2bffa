//! Scene motion over time (issue 36): what a glTF file's animations move, and where it is at a
//! time `t`, so that a scene can be re-posed every frame without reading the file again.
//!
//! At load (`gltf_load`), every mesh under an animated node (the node itself or an ancestor is
//! a channel's target) becomes an instance of its own (`Scene::instances`), so the BVH keeps a
//! bottom-level tree for it and only the top level moves (`Bvh::rebuild_top`). Its object-space
//! primitives are kept here, and so are the punctual lights under animated nodes.
//! `Motion::apply` writes the pose at `t` into the scene: the instances' world-space vertices
//! (computed as the loader computes them, so a scene posed at `t` this way equals, bit for bit,
//! the file loaded with `[scene] time = t`), their transforms, and the lights' positions and
//! directions.
//!
//! A scene made in code (the built-in `moving`) builds its motion with [`MotionBuilder`]: each
//! moving object is added at the origin and placed by a node of its own, which the clip's
//! tracks animate.
//!
//! A preset's `[[scene.animate]]` moves a named object of a built-in scene
//! (`Scene::objects`): [`MotionBuilder::named_object`] makes its triangles, where they are, an
//! instance of its own placed by a node at the object's centre.
//!
//! Not built yet: skins and morph targets (drawn in their bind pose at load), and cameras that
//! move.

use super::animation::{posed_locals, Clip, PoseRequest, Trs};
use super::animation::{Interpolation, Keyframes, Property, Track};
use super::gltf_load::{emit, emit_at, Primitive};
use super::{MeshInstance, Scene};
use anyhow::{bail, Result};
use glam::{Mat4, Vec3, Vec4};

/// One instance that moves: which node carries it, and its primitives in object space.
#[derive(Clone)]
pub(crate) struct MovingMesh {
    /// Index in `Scene::instances`.
    pub instance: usize,
    pub node: usize,
    /// EXT_mesh_gpu_instancing's matrix relative to the node (None: the node itself).
    pub local: Option<Mat4>,
    pub primitives: Vec<Primitive>,
    /// The instance's first vertex in the scene's vertex arrays.
    pub first_vertex: usize,
}

/// A punctual light carried by an animated node.
#[derive(Clone, Copy)]
pub(crate) struct MovingLight {
    /// Index in `Scene::lights`.
    pub light: usize,
    pub node: usize,
}

/// The animations of a glTF file and what they move (module doc).
#[derive(Clone)]
pub struct Motion {
    pub(crate) clips: Vec<Clip>,
    /// The one clip that plays (`[scene] animation`), or every clip.
    pub(crate) clip: Option<String>,
    /// Per node of the file: its parent, rest local matrix and rest TRS.
    pub(crate) parents: Vec<Option<usize>>,
    pub(crate) rest_local: Vec<Mat4>,
    pub(crate) rest_trs: Vec<Trs>,
    pub(crate) meshes: Vec<MovingMesh>,
    pub(crate) lights: Vec<MovingLight>,
    /// Playback speed (`[scene] time_scale`): scene seconds per second of frames; 0 holds the
    /// pose.
    pub time_scale: f32,
    /// Playback stops at this scene time and holds that pose (`[scene] play_until`): the frames
    /// after it show how each cache settles once the motion stops.
    pub play_until: Option<f32>,
}

impl std::fmt::Debug for Motion {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Motion")
            .field("clips", &self.clips.len())
            .field("moving_instances", &self.meshes.len())
            .field("moving_lights", &self.lights.len())
            .finish()
    }
}

/// What one re-posing changed.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Moved {
    /// Indices in `Scene::instances` whose transform and triangles changed.
    pub instances: Vec<usize>,
    /// Whether any punctual light moved.
    pub lights: bool,
}

impl Motion {
    /// Instances the animations move.
    pub fn moving_instances(&self) -> usize {
        self.meshes.len()
    }

    /// Scene time `frames` frames after `t0` at `fps` frames a second of playback, held at
    /// `play_until` once it is reached (moving forwards).
    pub fn time_after(&self, t0: f32, frames: u32, fps: f32) -> f32 {
        let t = t0 + frames as f32 * self.time_scale / fps;
        match self.play_until {
            Some(u) if self.time_scale > 0.0 && t0 <= u => t.min(u),
            _ => t,
        }
    }

    /// The longest clip that plays (seconds); playback loops over each clip's own length.
    pub fn duration(&self) -> f32 {
        self.clips
            .iter()
            .filter(|c| self.clip.as_ref().is_none_or(|n| &c.name == n))
            .map(Clip::duration)
            .fold(0.0, f32::max)
    }

    /// World matrices of the nodes at time `t`, for the nodes `wanted` (and their ancestors),
    /// multiplied in the loader's order (parent × local, from the identity at the roots).
    fn worlds(&self, t: f32, wanted: impl Iterator<Item = usize>) -> Result<Vec<Option<Mat4>>> {
        let request = PoseRequest {
            time: t,
            clip: self.clip.clone(),
        };
        let posed = posed_locals(&self.clips, &request, |n| {
            self.rest_trs.get(n).copied().unwrap_or(Trs {
                translation: Vec3::ZERO,
                rotation: glam::Quat::IDENTITY,
                scale: Vec3::ONE,
            })
        })?;
        let mut world: Vec<Option<Mat4>> = vec![None; self.parents.len()];
        for n in wanted {
            // The chain from n up to the first node already known (or a root).
            let mut chain = Vec::new();
            let mut at = Some(n);
            while let Some(k) = at {
                if k >= world.len() || world[k].is_some() || chain.len() > world.len() {
                    break;
                }
                chain.push(k);
                at = self.parents[k];
            }
            for &k in chain.iter().rev() {
                let parent = match self.parents[k] {
                    Some(p) => world.get(p).copied().flatten().unwrap_or(Mat4::IDENTITY),
                    None => Mat4::IDENTITY,
                };
                let local = posed.get(&k).copied().unwrap_or(self.rest_local[k]);
                world[k] = Some(parent * local);
            }
        }
        Ok(world)
    }

    /// The scene at time `t` (seconds, looped per clip): the moving instances' vertices and
    /// transforms, and the moving lights, rewritten in place.
    pub fn apply(&self, scene: &mut Scene, t: f32) -> Result<Moved> {
        let nodes = self
            .meshes
            .iter()
            .map(|m| m.node)
            .chain(self.lights.iter().map(|l| l.node));
        let world = self.worlds(t, nodes)?;
        let mut moved = Moved::default();
        for m in &self.meshes {
            let Some(w) = world[m.node] else { continue };
            let transform = match m.local {
                Some(l) => w * l,
                None => w,
            };
            if !transform.is_finite() || transform.determinant() == 0.0 {
                // A degenerate pose (a scale key of 0): the instance keeps its last pose.
                continue;
            }
            let Some(instance) = scene.instances.get_mut(m.instance) else {
                continue;
            };
            if instance.transform == transform {
                continue;
            }
            instance.transform = transform;
            let mut vertex = m.first_vertex;
            for p in &m.primitives {
                vertex = emit_at(scene, p, transform, vertex);
            }
            moved.instances.push(m.instance);
        }
        for l in &self.lights {
            let (Some(w), Some(light)) = (world[l.node], scene.lights.get_mut(l.light)) else {
                continue;
            };
            let position = w.transform_point3(Vec3::ZERO);
            let direction = w
                .transform_vector3(Vec3::NEG_Z)
                .try_normalize()
                .unwrap_or(Vec3::NEG_Z);
            if light.position != position || light.direction != direction {
                light.position = position;
                light.direction = direction;
                moved.lights = true;
            }
        }
        scene.posed_at = Some(t);
        Ok(moved)
    }
}

/// A `Motion` for a scene made in code (module doc).
pub struct MotionBuilder {
    motion: Motion,
    tracks: Vec<Track>,
    clip: String,
}

impl MotionBuilder {
    pub fn new(clip: &str) -> MotionBuilder {
        MotionBuilder {
            motion: Motion {
                clips: Vec::new(),
                clip: None,
                parents: Vec::new(),
                rest_local: Vec::new(),
                rest_trs: Vec::new(),
                meshes: Vec::new(),
                lights: Vec::new(),
                time_scale: 0.0,
                play_until: None,
            },
            tracks: Vec::new(),
            clip: clip.to_string(),
        }
    }

    /// Goes on with the scene's own motion (the built-in `moving`), or starts one.
    pub fn continuing(scene: &mut Scene, clip: &str) -> MotionBuilder {
        let mut b = MotionBuilder::new(clip);
        if let Some(m) = scene.motion.take() {
            b.motion = std::sync::Arc::unwrap_or_clone(m);
        }
        b
    }

    /// Makes the scene's triangles `first..first + count` (already placed) a moving object,
    /// without changing their order or materials: an instance of its own, placed by the node
    /// returned, at rest a translation to the triangles' bounding-box centre (the pivot of its
    /// rotation and scale, also returned). Vertices shared with other triangles are copied.
    pub fn named_object(
        &mut self,
        scene: &mut Scene,
        first: usize,
        count: usize,
    ) -> Result<(usize, Vec3)> {
        let range = first..first + count;
        if count == 0 || range.end > scene.triangles.len() {
            bail!("an object without triangles");
        }
        if scene.instances.iter().any(|i| {
            let (a, n) = (i.first_triangle as usize, i.triangle_count as usize);
            a < range.end && range.start < a + n
        }) {
            bail!("the object is already an instance of a mesh");
        }
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        for t in &scene.triangles[range.clone()] {
            for &v in t {
                lo = lo.min(scene.positions[v as usize]);
                hi = hi.max(scene.positions[v as usize]);
            }
        }
        let pivot = (lo + hi) * 0.5;
        // One vertex per corner, in triangle order: in place when the object already has
        // them (`Scene::add_triangle`), else appended.
        let fv = scene.triangles[first][0] as usize;
        let in_place = scene.triangles[range.clone()]
            .iter()
            .enumerate()
            .all(|(k, t)| (0..3).all(|c| t[c] as usize == fv + 3 * k + c))
            && scene.triangles.iter().enumerate().all(|(k, t)| {
                range.contains(&k)
                    || t.iter()
                        .all(|&v| !(fv..fv + 3 * count).contains(&(v as usize)))
            });
        let first_vertex = if in_place { fv } else { scene.positions.len() };
        // One primitive per run of one material (emit_at writes them one after another).
        let mut primitives: Vec<Primitive> = Vec::new();
        for k in range.clone() {
            let material = scene.triangle_material[k];
            if primitives.last().is_none_or(|p| p.material != material) {
                primitives.push(Primitive {
                    material,
                    positions: Vec::new(),
                    normals: Vec::new(),
                    uvs: Vec::new(),
                    uvs1: (!scene.uvs1.is_empty()).then(Vec::new),
                    tangents: (!scene.tangents.is_empty()).then(Vec::new),
                });
            }
            let p = primitives.last_mut().expect("pushed above");
            for v in scene.triangles[k].map(|v| v as usize) {
                p.positions.push(scene.positions[v] - pivot);
                p.normals.push(scene.normals[v]);
                p.uvs.push(scene.uvs[v]);
                if let Some(u) = &mut p.uvs1 {
                    u.push(scene.uvs1[v]);
                }
                if let Some(t) = &mut p.tangents {
                    t.push(scene.tangents[v]);
                }
            }
        }
        if !in_place {
            let n = first_vertex + 3 * count;
            scene.positions.resize(n, Vec3::ZERO);
            scene.normals.resize(n, Vec3::ZERO);
            scene.uvs.resize(n, glam::Vec2::ZERO);
            if !scene.uvs1.is_empty() {
                scene.uvs1.resize(n, glam::Vec2::ZERO);
            }
            if !scene.tangents.is_empty() {
                scene.tangents.resize(n, Vec4::ZERO);
            }
            for (k, t) in scene.triangles[range.clone()].iter_mut().enumerate() {
                let b = (first_vertex + 3 * k) as u32;
                *t = [b, b + 1, b + 2];
            }
        }
        let rest = Trs {
            translation: pivot,
            rotation: glam::Quat::IDENTITY,
            scale: Vec3::ONE,
        };
        let transform = rest.matrix();
        let mut vertex = first_vertex;
        for p in &primitives {
            vertex = emit_at(scene, p, transform, vertex);
        }
        let node = self.motion.parents.len();
        self.motion.parents.push(None);
        self.motion.rest_local.push(transform);
        self.motion.rest_trs.push(rest);
        self.motion.meshes.push(MovingMesh {
            instance: scene.instances.len(),
            node,
            local: None,
            primitives,
            first_vertex,
        });
        scene.instances.push(MeshInstance {
            mesh: 1_000_000 + node as u32,
            transform,
            first_triangle: first as u32,
            triangle_count: count as u32,
        });
        Ok((node, pivot))
    }

    /// Adds a moving object: `add` puts its triangles (one material) into the scene around
    /// the origin, in object space; the object is placed at `rest` and becomes an instance of
    /// its own, moved by the node returned (for `track`).
    pub fn object(
        &mut self,
        scene: &mut Scene,
        rest: Trs,
        add: impl FnOnce(&mut Scene),
    ) -> Result<usize> {
        let (first_tri, first_vertex) = (scene.triangles.len(), scene.positions.len());
        add(scene);
        let new = &scene.triangles[first_tri..];
        let Some(&material) = scene.triangle_material.get(first_tri) else {
            bail!("a moving object without triangles");
        };
        if scene.triangle_material[first_tri..]
            .iter()
            .any(|&m| m != material)
        {
            bail!("a moving object has one material");
        }
        let corners = |f: &dyn Fn(u32) -> Vec3| -> Vec<Vec3> {
            new.iter().flat_map(|t| t.map(f)).collect::<Vec<_>>()
        };
        let primitive = Primitive {
            material,
            positions: corners(&|i| scene.positions[i as usize]),
            normals: corners(&|i| scene.normals[i as usize]),
            uvs: new
                .iter()
                .flat_map(|t| t.map(|i| scene.uvs[i as usize]))
                .collect(),
            uvs1: None,
            tangents: None,
        };
        // The object again, one vertex per corner, at its rest pose (as a glTF load emits it).
        scene.positions.truncate(first_vertex);
        scene.normals.truncate(first_vertex);
        scene.uvs.truncate(first_vertex);
        scene.uvs1.truncate(first_vertex.min(scene.uvs1.len()));
        scene
            .tangents
            .truncate(first_vertex.min(scene.tangents.len()));
        scene.triangles.truncate(first_tri);
        scene.triangle_material.truncate(first_tri);
        let transform = rest.matrix();
        emit(scene, &primitive, transform);
        let node = self.motion.parents.len();
        self.motion.parents.push(None);
        self.motion.rest_local.push(transform);
        self.motion.rest_trs.push(rest);
        self.motion.meshes.push(MovingMesh {
            instance: scene.instances.len(),
            node,
            local: None,
            primitives: vec![primitive],
            first_vertex,
        });
        scene.instances.push(MeshInstance {
            // Its own mesh id, past any a file could use.
            mesh: 1_000_000 + node as u32,
            transform,
            first_triangle: first_tri as u32,
            triangle_count: (scene.triangles.len() - first_tri) as u32,
        });
        Ok(node)
    }

    /// Keyframes of one property of `node`: times in seconds, values (xyz: translation or
    /// scale; xyzw: a rotation quaternion).
    pub fn track(
        &mut self,
        node: usize,
        property: Property,
        times: Vec<f32>,
        values: Vec<Vec4>,
        interpolation: Interpolation,
    ) -> Result<()> {
        self.tracks.push(Track {
            node,
            property,
            keys: Keyframes::new(times, values, interpolation)?,
        });
        Ok(())
    }

    /// The motion, into the scene (which then lists its clip after any it had).
    pub fn finish(mut self, scene: &mut Scene) {
        let clip = Clip {
            name: self.clip,
            tracks: self.tracks,
        };
        scene.animations.push(super::animation::ClipInfo::of(&clip));
        self.motion.clips.push(clip);
        scene.motion = Some(std::sync::Arc::new(self.motion));
    }
}
