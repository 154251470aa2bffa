//! glTF 2.0 (.gltf and .glb) through the `gltf` crate, flattened to a world-space [`Scene`].
//!
//! Read:
//! - the node hierarchy and transforms, triangle primitives (positions, normals, TEXCOORD_0,
//!   TEXCOORD_1, TANGENT, indices; flat normals generated when missing);
//! - materials: base colour factor and texture (with alpha), metallic-roughness factors and
//!   texture, normal texture and its `scale`, emissive factor and texture,
//!   occlusion texture and its `strength` (loaded; the renderers do not apply it, see
//!   [`Material::occlusion_texture`]), `alphaMode` and `alphaCutoff` (BLEND is traced as MASK),
//!   doubleSided; every texture's `texCoord` (sets 0 and 1) and KHR_texture_transform (offset,
//!   rotation, scale and its `texCoord` override); KHR_materials_emissive_strength,
//!   KHR_materials_specular's `specularFactor`, KHR_materials_ior; the `gilab_callisto` extras;
//! - KHR_lights_punctual and the first perspective camera;
//! - EXT_mesh_gpu_instancing (TRANSLATION, ROTATION, SCALE) and meshes used by several nodes:
//!   each placement is a [`MeshInstance`] of one bottom-level tree (`super::instancing`); the
//!   shading records stay one copy per instance (144 bytes a triangle), so heavily instanced
//!   files still cost triangle memory per instance.
//!
//! Tangents: a primitive whose material has a normal texture keeps its TANGENT attribute
//! (transformed by the node's matrix; the bitangent sign flips where the matrix mirrors), or,
//! without one, gets MikkTSpace tangents ([`super::tangents`]) computed in object space from
//! the normal texture's UV set, then transformed the same way. Other primitives get none.
//!
//! Samplers: wrap modes (repeat, clamp to edge, mirrored repeat) per axis and magFilter
//! (nearest or bilinear); minFilter is not read (ray cones pick the mip level).
//!
//! Not read (left out on purpose, listed in docs/scenes.md): UV sets past 1 (a texture using one is dropped with a warning), KHR_materials_specular's
//! colour and textures, the other material extensions (transmission, clearcoat, sheen, ...),
//! skins, morph targets, animations, cameras after the first, orthographic cameras.
//! Lenient where a part is optional: an unreadable image, an invalid texture transform or
//! instancing extension, or an unknown extension that is not required is skipped with a
//! warning naming it; an extension the file requires but this loader does not read is refused.
//! A file with no light at all gets a default sky.

use super::gltf_validate::{self, Usage};
use super::{
    tangents, AlphaMode, Camera, Material, MeshInstance, PunctualKind, PunctualLight, Sampler,
    Scene, Texture, TextureRef, UvTransform, Wrap,
};
use crate::scene::animation::{
    posed_locals, Clip, ClipInfo, Interpolation, Keyframes, PoseRequest, Property, Track, Trs,
};
use crate::scene::motion::{Motion, MovingLight, MovingMesh};
use anyhow::{anyhow, bail, Context, Result};
use glam::{Mat3, Mat4, Quat, Vec2, Vec3, Vec4};
use std::collections::HashMap;
use std::path::Path;

pub fn load(path: &Path) -> Result<Scene> {
    load_lit(path, false)
}

/// `load`, told whether an environment map will light the scene (a preset's
/// `scene.environment`): then a file without lights gets no default sky and no warning.
pub fn load_lit(path: &Path, environment: bool) -> Result<Scene> {
    load_posed(path, environment, None)
}

/// `load_lit` with the file's animations posed at a time (`[scene] time` and `animation`):
/// every animated node takes the local transform its channels hold then, and the scene is
/// built from those transforms exactly as from a file that stored them. None: the nodes'
/// own (rest) transforms.
pub fn load_posed(path: &Path, environment: bool, pose: Option<&PoseRequest>) -> Result<Scene> {
    load_inner(path, environment, pose)
        .with_context(|| format!("cannot load glTF scene {}", path.display()))
}

/// Extensions read (others in `extensionsUsed` are ignored with a warning; a file that
/// *requires* one not listed here is refused).
pub const SUPPORTED_EXTENSIONS: [&str; 6] = [
    "KHR_lights_punctual",
    "KHR_materials_emissive_strength",
    "KHR_materials_specular",
    "KHR_materials_ior",
    "KHR_texture_transform",
    "EXT_mesh_gpu_instancing",
];

/// Parses and validates the file. The gltf crate refuses every required extension it does not
/// know itself (EXT_mesh_gpu_instancing and KHR_materials_specular among them), so required
/// extensions are checked here against [`SUPPORTED_EXTENSIONS`] before its validation, which
/// refuses only invalid objects the scene uses ([`gltf_validate`]).
fn open(path: &Path) -> Result<(gltf::Document, Option<Vec<u8>>, Usage)> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let gltf::Gltf { document, blob } =
        gltf::Gltf::from_slice_without_validation(&bytes).map_err(|e| anyhow!("{e}"))?;
    let mut root = document.into_json();
    for ext in &root.extensions_required {
        if !SUPPORTED_EXTENSIONS.contains(&ext.as_str()) {
            bail!("extension {ext} is required by the file but not supported");
        }
    }
    for ext in &root.extensions_used {
        if !SUPPORTED_EXTENSIONS.contains(&ext.as_str()) {
            log::warn!(
                "{}: extension {ext} is not supported: ignored",
                path.display()
            );
        }
    }
    root.extensions_required.clear();
    let (doc, usage) = gltf_validate::validate(root, &path.display().to_string())?;
    Ok((doc, blob, usage))
}

fn load_inner(path: &Path, environment: bool, pose: Option<&PoseRequest>) -> Result<Scene> {
    let (doc, blob, usage) = open(path)?;
    let base = path.parent();
    let buffers = gltf::import_buffers(&doc, base, blob).map_err(|e| anyhow!("{e}"))?;
    let mut scene = Scene::new(
        &path
            .file_stem()
            .map(|s| s.to_string_lossy().to_string())
            .unwrap_or_default(),
    );
    let file = path.display().to_string();

    let texture_of_image = read_images(&doc, &usage, base, &buffers, &mut scene, &file);
    let default_material = read_materials(&doc, &usage, &texture_of_image, &mut scene, &file)?;

    let gltf_scene = doc
        .default_scene()
        .or_else(|| doc.scenes().next())
        .ok_or_else(|| anyhow!("file has no scene"))?;
    // Meshes drawn more than once (several nodes, or instancing) are read once and kept.
    let mut uses = vec![0usize; doc.meshes().len()];
    for node in doc.nodes().filter(|n| !usage.dropped("nodes", n.index())) {
        if let Some(mesh) = node.mesh() {
            uses[mesh.index()] += 1 + node.extension_value(INSTANCING).is_some() as usize;
        }
    }
    if doc.skins().next().is_some() {
        log::warn!(
            "{file}: skinned meshes are drawn in their bind pose (skinning is not supported)"
        );
    }
    let clips = read_animations(&doc, &buffers, &file);
    scene.animations = clips.iter().map(ClipInfo::of).collect();
    let posed = match pose {
        Some(p) => {
            scene.posed_at = Some(p.time);
            posed_locals(&clips, p, |n| rest_trs(&doc, n))?
        }
        None => HashMap::new(),
    };
    if pose.is_none() && !clips.is_empty() {
        log::info!(
            "{file}: {} animation(s) ({}), shown at the rest pose: [scene] time = T poses them",
            clips.len(),
            scene
                .animations
                .iter()
                .map(|c| format!("'{}' {:.2} s", c.name, c.duration))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    // What the animations move (src/scene/motion.rs): the nodes a playing clip drives, and
    // everything under them.
    let driven: std::collections::HashSet<usize> = clips
        .iter()
        .filter(|c| {
            pose.and_then(|p| p.clip.as_ref())
                .is_none_or(|n| &c.name == n)
        })
        .flat_map(|c| c.tracks.iter().map(|t| t.node))
        .collect();
    let mut motion = Motion {
        clips: clips.clone(),
        clip: pose.and_then(|p| p.clip.clone()),
        parents: vec![None; doc.nodes().len()],
        rest_local: doc.nodes().map(|n| local_matrix(&n)).collect(),
        rest_trs: (0..doc.nodes().len()).map(|n| rest_trs(&doc, n)).collect(),
        meshes: Vec::new(),
        lights: Vec::new(),
        time_scale: 0.0,
        play_until: None,
    };
    for node in doc.nodes() {
        for child in node.children() {
            motion.parents[child.index()] = Some(node.index());
        }
    }
    let mut cache: HashMap<usize, Vec<Primitive>> = HashMap::new();
    let mut stack: Vec<(gltf::Node, Mat4, bool)> = gltf_scene
        .nodes()
        .map(|n| (n, Mat4::IDENTITY, false))
        .collect();
    let mut visited = 0usize;
    while let Some((node, parent, parent_moves)) = stack.pop() {
        visited += 1;
        if visited > 1_000_000 {
            bail!("node hierarchy too deep or cyclic");
        }
        let moves = parent_moves || driven.contains(&node.index());
        let local = match posed.get(&node.index()) {
            Some(m) => *m,
            None => local_matrix(&node),
        };
        let world = parent * local;
        if let Some(mesh) = node.mesh() {
            // (world transform, EXT_mesh_gpu_instancing's matrix relative to the node)
            let transforms: Vec<(Mat4, Option<Mat4>)> = match read_instances(&node, &doc, &buffers)
            {
                Ok(Some(instances)) => instances
                    .into_iter()
                    .map(|m| (world * m, Some(m)))
                    .collect(),
                Ok(None) => vec![(world, None)],
                Err(e) => {
                    log::warn!(
                            "{file}: node {} ('{}'): {INSTANCING} skipped ({e:#}): the mesh is drawn once at the node",
                            node.index(),
                            node.name().unwrap_or("unnamed")
                        );
                    vec![(world, None)]
                }
            };
            // A mesh drawn more than once is traced as instances of one tree; one that moves
            // is an instance of its own, so that only the BVH's top level moves with it.
            let instanced = uses[mesh.index()] > 1 || moves;
            let fresh;
            let prims = match cache.get(&mesh.index()) {
                Some(p) => p,
                None => {
                    fresh = read_mesh(&scene, &mesh, &buffers, default_material, &file)?;
                    if uses[mesh.index()] > 1 {
                        cache.insert(mesh.index(), fresh);
                        &cache[&mesh.index()]
                    } else {
                        &fresh
                    }
                }
            };
            for (m, ext) in &transforms {
                if !m.is_finite() {
                    log::warn!(
                        "{file}: node {} ('{}'): an instance with a non-finite transform skipped",
                        node.index(),
                        node.name().unwrap_or("unnamed")
                    );
                    continue;
                }
                let first = scene.triangles.len() as u32;
                let first_vertex = scene.positions.len();
                for p in prims {
                    emit(&mut scene, p, *m);
                }
                if instanced {
                    if moves {
                        motion.meshes.push(MovingMesh {
                            instance: scene.instances.len(),
                            node: node.index(),
                            local: *ext,
                            primitives: prims.clone(),
                            first_vertex,
                        });
                    }
                    scene.instances.push(MeshInstance {
                        mesh: mesh.index() as u32,
                        transform: *m,
                        first_triangle: first,
                        triangle_count: scene.triangles.len() as u32 - first,
                    });
                }
            }
        }
        if let Some(light) = node.light() {
            if moves {
                motion.lights.push(MovingLight {
                    light: scene.lights.len(),
                    node: node.index(),
                });
            }
            scene.lights.push(read_light(&light, world));
        }
        if let (Some(cam), None) = (node.camera(), scene.camera) {
            if let gltf::camera::Projection::Perspective(p) = cam.projection() {
                let pos = world.transform_point3(Vec3::ZERO);
                let fwd = world.transform_vector3(Vec3::NEG_Z).normalize_or_zero();
                let up = world.transform_vector3(Vec3::Y).normalize_or_zero();
                if fwd != Vec3::ZERO {
                    scene.camera = Some(Camera {
                        position: pos,
                        target: pos + fwd,
                        up,
                        fov_y: p.yfov().to_degrees(),
                    });
                }
            }
        }
        for child in node.children() {
            stack.push((child, world, moves));
        }
    }
    if scene.triangles.is_empty() {
        bail!("file has no triangle geometry");
    }
    // Public samples made for viewers with image-based lighting often have no light at all: a
    // black image would say nothing, so they get a uniform default sky, and the user is told.
    let emits = scene
        .triangle_material
        .iter()
        .any(|&m| scene.materials[m as usize].emissive.max_element() > 0.0);
    if !emits && scene.lights.is_empty() && scene.sky.max_element() <= 0.0 && !environment {
        scene.sky = Vec3::splat(DEFAULT_SKY);
        log::warn!(
            "{file}: no light source (no emissive material, no KHR_lights_punctual): lit by a default uniform sky of radiance {DEFAULT_SKY}"
        );
    }
    if !motion.meshes.is_empty() || !motion.lights.is_empty() {
        scene.motion = Some(std::sync::Arc::new(motion));
    }
    scene.validate()?;
    Ok(scene)
}

/// The images the used materials read, decoded into `scene.textures`: per glTF image, its
/// texture index, or None (unused, or unreadable: skipped with a warning naming it, so its
/// textures fall back to their factors instead of refusing the scene).
fn read_images(
    doc: &gltf::Document,
    usage: &Usage,
    base: Option<&Path>,
    buffers: &[gltf::buffer::Data],
    scene: &mut Scene,
    file: &str,
) -> Vec<Option<usize>> {
    // Lenient: an image that cannot be read is skipped (its textures fall back to the factors)
    // with a warning naming it, instead of refusing the whole scene.
    // Images no used material reads are not decoded.
    let mut texture_of_image = Vec::new();
    for image in doc.images() {
        if !usage.uses("images", image.index()) {
            texture_of_image.push(None);
            continue;
        }
        let loaded = gltf::image::Data::from_source(image.source(), base, buffers)
            .map_err(|e| anyhow!("{e}"))
            .and_then(|img| to_rgba8(&img));
        match loaded {
            Ok(t) => {
                texture_of_image.push(Some(scene.textures.len()));
                scene.textures.push(t);
            }
            Err(e) => {
                let from = match image.source() {
                    gltf::image::Source::Uri { uri, .. } if !uri.starts_with("data:") => {
                        format!(" from '{uri}'")
                    }
                    _ => String::new(),
                };
                log::warn!(
                    "{file}: image {} ('{}'){from} skipped: {e:#}; textures using it fall back to their factors",
                    image.index(),
                    image.name().unwrap_or("unnamed")
                );
                texture_of_image.push(None);
            }
        }
    }
    texture_of_image
}

/// The materials into `scene.materials` (an unused, invalid one as plain white, so indices hold),
/// then glTF's default material, whose index is returned.
fn read_materials(
    doc: &gltf::Document,
    usage: &Usage,
    texture_of_image: &[Option<usize>],
    scene: &mut Scene,
    file: &str,
) -> Result<u32> {
    for m in doc.materials() {
        let i = m.index().expect("a material of the document has an index");
        // Only a valid material's texture indices may be followed.
        let reads_dropped = || {
            let pbr = m.pbr_metallic_roughness();
            [
                pbr.base_color_texture().map(|t| t.texture().index()),
                pbr.metallic_roughness_texture()
                    .map(|t| t.texture().index()),
                m.normal_texture().map(|t| t.texture().index()),
                m.occlusion_texture().map(|t| t.texture().index()),
                m.emissive_texture().map(|t| t.texture().index()),
            ]
            .into_iter()
            .flatten()
            .any(|t| usage.dropped("textures", t))
        };
        if usage.dropped("materials", i) || reads_dropped() {
            // Unused (validation refused the file otherwise): a placeholder keeps the indices.
            let name = m.name().unwrap_or("unnamed");
            log::warn!(
                "{file}: material {i} ('{name}') is unused and invalid or reads an invalid texture: read as plain white"
            );
            scene.materials.push(Material::lambert(name, Vec3::ONE));
            continue;
        }
        scene
            .materials
            .push(read_material(&m, texture_of_image, file)?);
    }
    // Primitives without a material get glTF's default material (appended last).
    let default_material = scene.materials.len() as u32;
    scene.materials.push(Material {
        base_color: Vec4::ONE,
        metallic: 1.0,
        roughness: 1.0,
        specular: 1.0,
        ..Material::lambert("gltf default", Vec3::ONE)
    });
    Ok(default_material)
}

/// A node's own transform. TRS nodes go through [`Trs::matrix`], as animated ones do, so a pose
/// equals a file with the sampled TRS written into its nodes, bit for bit.
fn local_matrix(node: &gltf::Node) -> Mat4 {
    match node.transform() {
        gltf::scene::Transform::Matrix { matrix } => Mat4::from_cols_array_2d(&matrix),
        gltf::scene::Transform::Decomposed {
            translation,
            rotation,
            scale,
        } => Trs {
            translation: Vec3::from_array(translation),
            rotation: Quat::from_array(rotation),
            scale: Vec3::from_array(scale),
        }
        .matrix(),
    }
}

/// A node's own translation, rotation and scale (a node given by a matrix is decomposed: glTF
/// allows only TRS on animated nodes).
fn rest_trs(doc: &gltf::Document, node: usize) -> Trs {
    let (t, r, s) = doc
        .nodes()
        .nth(node)
        .map(|n| n.transform().decomposed())
        .unwrap_or(([0.0; 3], [0.0, 0.0, 0.0, 1.0], [1.0; 3]));
    Trs {
        translation: Vec3::from_array(t),
        rotation: Quat::from_array(r),
        scale: Vec3::from_array(s),
    }
}

/// The file's animations as clips of node tracks. Lenient: a channel that cannot be read (bad
/// accessor, keys out of order, morph-target weights, which are not built) is skipped with a
/// warning naming it; the rest of the animation plays.
fn read_animations(doc: &gltf::Document, buffers: &[gltf::buffer::Data], file: &str) -> Vec<Clip> {
    use gltf::animation::util::ReadOutputs;
    let mut clips = Vec::new();
    for anim in doc.animations() {
        let name = anim
            .name()
            .map(str::to_string)
            .unwrap_or_else(|| format!("animation {}", anim.index()));
        let mut tracks = Vec::new();
        for (c, ch) in anim.channels().enumerate() {
            let reader = ch.reader(|b| buffers.get(b.index()).map(|d| &d[..]));
            let interpolation = match ch.sampler().interpolation() {
                gltf::animation::Interpolation::Step => Interpolation::Step,
                gltf::animation::Interpolation::Linear => Interpolation::Linear,
                gltf::animation::Interpolation::CubicSpline => Interpolation::CubicSpline,
            };
            let read = || -> Result<Option<Track>> {
                let times: Vec<f32> = reader
                    .read_inputs()
                    .ok_or_else(|| anyhow!("its input accessor cannot be read"))?
                    .collect();
                let (property, values): (Property, Vec<Vec4>) = match reader
                    .read_outputs()
                    .ok_or_else(|| anyhow!("its output accessor cannot be read"))?
                {
                    ReadOutputs::Translations(it) => (
                        Property::Translation,
                        it.map(|v| Vec3::from_array(v).extend(0.0)).collect(),
                    ),
                    ReadOutputs::Scales(it) => (
                        Property::Scale,
                        it.map(|v| Vec3::from_array(v).extend(0.0)).collect(),
                    ),
                    ReadOutputs::Rotations(r) => (
                        Property::Rotation,
                        r.into_f32().map(Vec4::from_array).collect(),
                    ),
                    ReadOutputs::MorphTargetWeights(_) => return Ok(None),
                };
                Ok(Some(Track {
                    node: ch.target().node().index(),
                    property,
                    keys: Keyframes::new(times, values, interpolation)?,
                }))
            };
            match read() {
                Ok(Some(t)) => tracks.push(t),
                Ok(None) => log::warn!(
                    "{file}: animation '{name}', channel {c}: morph-target weights are not supported: skipped"
                ),
                Err(e) => log::warn!("{file}: animation '{name}', channel {c} skipped: {e:#}"),
            }
        }
        if !tracks.is_empty() {
            clips.push(Clip { name, tracks });
        }
    }
    clips
}

/// Radiance of the sky a glTF without any light source gets.
pub const DEFAULT_SKY: f32 = 1.0;

const INSTANCING: &str = "EXT_mesh_gpu_instancing";

fn info<'a>(slot: &'static str, i: Option<gltf::texture::Info<'a>>) -> Option<SlotIn<'a>> {
    i.map(|i| SlotIn {
        slot,
        texture: i.texture(),
        tex_coord: i.tex_coord(),
        transform: typed_transform(i.texture_transform()),
    })
}

/// A texture slot as the file gives it, before it becomes a [`TextureRef`].
struct SlotIn<'a> {
    slot: &'static str,
    texture: gltf::texture::Texture<'a>,
    tex_coord: u32,
    /// KHR_texture_transform as parsed (None: absent), or why it is invalid.
    transform: Option<std::result::Result<(UvTransform, Option<u32>), String>>,
}

fn typed_transform(
    t: Option<gltf::texture::TextureTransform>,
) -> Option<std::result::Result<(UvTransform, Option<u32>), String>> {
    t.map(|t| {
        Ok((
            UvTransform {
                offset: Vec2::from_array(t.offset()),
                rotation: t.rotation(),
                scale: Vec2::from_array(t.scale()),
            },
            t.tex_coord(),
        ))
    })
}

/// KHR_texture_transform from raw JSON (normal and occlusion textures, whose typed structs in
/// the gltf crate do not carry it).
fn raw_transform(
    v: Option<&serde_json::Value>,
) -> Option<std::result::Result<(UvTransform, Option<u32>), String>> {
    let v = v?;
    let pair = |key: &str, default: Vec2| -> std::result::Result<Vec2, String> {
        match v.get(key) {
            None => Ok(default),
            Some(a) => {
                let a = a
                    .as_array()
                    .filter(|a| a.len() == 2)
                    .ok_or_else(|| format!("{key} is not an array of 2 numbers"))?;
                let x = a[0]
                    .as_f64()
                    .ok_or_else(|| format!("{key}[0] is not a number"))?;
                let y = a[1]
                    .as_f64()
                    .ok_or_else(|| format!("{key}[1] is not a number"))?;
                Ok(Vec2::new(x as f32, y as f32))
            }
        }
    };
    Some((|| {
        let offset = pair("offset", Vec2::ZERO)?;
        let scale = pair("scale", Vec2::ONE)?;
        let rotation = match v.get("rotation") {
            None => 0.0,
            Some(r) => r.as_f64().ok_or("rotation is not a number")? as f32,
        };
        let tex_coord = match v.get("texCoord") {
            None => None,
            Some(t) => Some(
                t.as_u64()
                    .filter(|&t| t <= u32::MAX as u64)
                    .ok_or("texCoord is not a non-negative integer")? as u32,
            ),
        };
        Ok((
            UvTransform {
                offset,
                rotation,
                scale,
            },
            tex_coord,
        ))
    })())
}

/// The [`TextureRef`] of a slot, or None (with a warning) when its image could not be read,
/// its UV set is past 1; an invalid transform is dropped (identity) with a warning.
fn texture_ref(
    s: SlotIn,
    material: &str,
    texture_of_image: &[Option<usize>],
    file: &str,
) -> Result<Option<TextureRef>> {
    let idx = s.texture.source().index();
    let texture = match texture_of_image.get(idx) {
        Some(Some(t)) => *t,
        Some(None) => return Ok(None), // unreadable image: warned about above
        None => bail!(
            "material '{material}': {} references missing image {idx}",
            s.slot
        ),
    };
    let mut tex_coord = s.tex_coord;
    let mut transform = UvTransform::default();
    match s.transform {
        None => {}
        Some(Ok((t, set))) => {
            let finite = t.offset.is_finite() && t.rotation.is_finite() && t.scale.is_finite();
            if finite {
                transform = t;
                if let Some(set) = set {
                    tex_coord = set;
                }
            } else {
                log::warn!(
                    "{file}: material '{material}': {}: KHR_texture_transform has non-finite values: ignored",
                    s.slot
                );
            }
        }
        Some(Err(e)) => log::warn!(
            "{file}: material '{material}': {}: KHR_texture_transform is invalid ({e}): ignored",
            s.slot
        ),
    }
    if tex_coord > 1 {
        log::warn!(
            "{file}: material '{material}': {} uses TEXCOORD_{tex_coord} (only sets 0 and 1 are read): texture dropped",
            s.slot
        );
        return Ok(None);
    }
    let wrap = |w: gltf::texture::WrappingMode| match w {
        gltf::texture::WrappingMode::Repeat => Wrap::Repeat,
        gltf::texture::WrappingMode::ClampToEdge => Wrap::ClampToEdge,
        gltf::texture::WrappingMode::MirroredRepeat => Wrap::MirroredRepeat,
    };
    let sampler = s.texture.sampler();
    Ok(Some(TextureRef {
        texture,
        tex_coord,
        transform,
        sampler: Sampler {
            wrap_u: wrap(sampler.wrap_s()),
            wrap_v: wrap(sampler.wrap_t()),
            nearest: sampler.mag_filter() == Some(gltf::texture::MagFilter::Nearest),
        },
    }))
}

fn read_material(
    m: &gltf::Material,
    texture_of_image: &[Option<usize>],
    file: &str,
) -> Result<Material> {
    let name = m.name().unwrap_or("unnamed").to_string();
    let pbr = m.pbr_metallic_roughness();
    let tex = |s: Option<SlotIn>| -> Result<Option<TextureRef>> {
        match s {
            Some(s) => texture_ref(s, &name, texture_of_image, file),
            None => Ok(None),
        }
    };
    let base_color_texture = tex(info("baseColorTexture", pbr.base_color_texture()))?;
    let metallic_roughness_texture = tex(info(
        "metallicRoughnessTexture",
        pbr.metallic_roughness_texture(),
    ))?;
    let emissive_texture = tex(info("emissiveTexture", m.emissive_texture()))?;
    let normal = m.normal_texture();
    let normal_scale = normal.as_ref().map_or(1.0, |n| n.scale());
    let normal_texture = tex(normal.map(|n| SlotIn {
        slot: "normalTexture",
        texture: n.texture(),
        tex_coord: n.tex_coord(),
        transform: raw_transform(n.extension_value("KHR_texture_transform")),
    }))?;
    let occlusion = m.occlusion_texture();
    let occlusion_strength = occlusion.as_ref().map_or(1.0, |o| o.strength());
    let occlusion_texture = tex(occlusion.map(|o| SlotIn {
        slot: "occlusionTexture",
        texture: o.texture(),
        tex_coord: o.tex_coord(),
        transform: raw_transform(o.extension_value("KHR_texture_transform")),
    }))?;

    let strength = m.emissive_strength().unwrap_or(1.0);
    let specular = m.specular().map(|s| s.specular_factor()).unwrap_or(1.0);
    let emissive = Vec3::from_array(m.emissive_factor()) * strength;
    if !emissive.is_finite() {
        bail!("material '{name}' has a non-finite emission");
    }
    let checked = |what: &str, v: f32, ok: bool, default: f32| {
        if ok {
            v
        } else {
            log::warn!("{file}: material '{name}': {what} {v} is invalid: {default} used");
            default
        }
    };
    let normal_scale = checked(
        "normalTexture.scale",
        normal_scale,
        normal_scale.is_finite(),
        1.0,
    );
    let occlusion_strength = checked(
        "occlusionTexture.strength",
        occlusion_strength,
        occlusion_strength.is_finite(),
        1.0,
    );
    let cutoff = m.alpha_cutoff().unwrap_or(0.5);
    let alpha_cutoff = checked(
        "alphaCutoff",
        cutoff,
        cutoff.is_finite() && cutoff >= 0.0,
        0.5,
    );
    let ior = m.ior().unwrap_or(1.5);
    let ior = checked(
        "KHR_materials_ior.ior",
        ior,
        ior.is_finite() && ior >= 1.0,
        1.5,
    );
    let alpha_mode = match m.alpha_mode() {
        gltf::material::AlphaMode::Opaque => AlphaMode::Opaque,
        gltf::material::AlphaMode::Mask => AlphaMode::Mask,
        gltf::material::AlphaMode::Blend => AlphaMode::Blend,
    };
    let callisto = read_callisto_extras(m)?;
    Ok(Material {
        name: name.clone(),
        base_color: Vec4::from_array(pbr.base_color_factor()),
        base_color_texture,
        metallic: pbr.metallic_factor(),
        roughness: pbr.roughness_factor(),
        metallic_roughness_texture,
        normal_texture,
        normal_scale,
        emissive,
        emissive_texture,
        occlusion_texture,
        occlusion_strength,
        alpha_mode,
        alpha_cutoff,
        specular,
        ior,
        double_sided: m.double_sided(),
        brdf: Default::default(),
        callisto,
    })
}

/// Callisto parameters from the material's extras: `"extras": {"gilab_callisto": {...}}` with the
/// preset's key names (`retroreflection`, `diffuse_fresnel_tint`, ...); other extras are ignored.
fn read_callisto_extras(m: &gltf::Material) -> Result<crate::scene::shading::CallistoParams> {
    let mut p = crate::scene::shading::CallistoParams::default();
    let Some(raw) = m.extras() else {
        return Ok(p);
    };
    let name = m.name().unwrap_or("?");
    let extras: serde_json::Value = serde_json::from_str(raw.get())
        .map_err(|e| anyhow::anyhow!("material '{name}': extras are not JSON: {e}"))?;
    if let Some(c) = extras.get("gilab_callisto") {
        let o: crate::scene::shading::CallistoOverrides = serde_json::from_value(c.clone())
            .map_err(|e| anyhow::anyhow!("material '{name}': extras.gilab_callisto: {e}"))?;
        o.apply(&mut p);
        p.check()
            .map_err(|e| anyhow::anyhow!("material '{name}': extras.gilab_callisto: {e}"))?;
    }
    Ok(p)
}

/// One triangle primitive in object space, its vertices unshared (three per triangle, in the
/// file's winding), ready to be placed once per node or instance.
#[derive(Clone)]
pub(crate) struct Primitive {
    pub(crate) material: u32,
    pub(crate) positions: Vec<Vec3>,
    pub(crate) normals: Vec<Vec3>,
    pub(crate) uvs: Vec<Vec2>,
    pub(crate) uvs1: Option<Vec<Vec2>>,
    /// Only for normal-mapped materials: the file's TANGENT or MikkTSpace's.
    pub(crate) tangents: Option<Vec<Vec4>>,
}

fn read_mesh(
    scene: &Scene,
    mesh: &gltf::Mesh,
    buffers: &[gltf::buffer::Data],
    default_material: u32,
    file: &str,
) -> Result<Vec<Primitive>> {
    let mesh_name = mesh.name().unwrap_or("?");
    let mut out = Vec::new();
    for prim in mesh.primitives() {
        if prim.mode() != gltf::mesh::Mode::Triangles {
            log::warn!(
                "mesh '{mesh_name}': skipping a {:?} primitive (only triangles are rendered)",
                prim.mode()
            );
            continue;
        }
        let reader = prim.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
        let positions: Vec<Vec3> = reader
            .read_positions()
            .ok_or_else(|| anyhow!("mesh '{mesh_name}' has a primitive without positions"))?
            .map(Vec3::from_array)
            .collect();
        let n = positions.len();
        let normals: Option<Vec<Vec3>> = reader.read_normals().map(|it| {
            it.map(|v| Vec3::from_array(v).normalize_or_zero())
                .collect()
        });
        let uvs: Vec<Vec2> = match reader.read_tex_coords(0) {
            Some(it) => it.into_f32().map(Vec2::from_array).collect(),
            None => vec![Vec2::ZERO; n],
        };
        let uvs1: Option<Vec<Vec2>> = reader
            .read_tex_coords(1)
            .map(|it| it.into_f32().map(Vec2::from_array).collect());
        if normals.as_ref().is_some_and(|v| v.len() != n)
            || uvs.len() != n
            || uvs1.as_ref().is_some_and(|v| v.len() != n)
        {
            bail!("mesh '{mesh_name}': attribute counts differ from the position count");
        }
        let indices: Vec<u32> = match reader.read_indices() {
            Some(it) => it.into_u32().collect(),
            None => (0..n as u32).collect(),
        };
        if let Some(bad) = indices.iter().find(|&&i| i as usize >= n) {
            bail!("mesh '{mesh_name}': index {bad} is out of range ({n} vertices)");
        }
        let material = prim
            .material()
            .index()
            .map_or(default_material, |i| i as u32);
        let normal_map = scene.materials[material as usize].normal_texture;

        // Unshare: three vertices per triangle; generated flat normals stay per triangle.
        let corners = indices.len() / 3 * 3;
        let idx = &indices[..corners];
        let mut p = Primitive {
            material,
            positions: idx.iter().map(|&i| positions[i as usize]).collect(),
            normals: Vec::with_capacity(corners),
            uvs: idx.iter().map(|&i| uvs[i as usize]).collect(),
            uvs1: uvs1
                .as_ref()
                .map(|u| idx.iter().map(|&i| u[i as usize]).collect()),
            tangents: None,
        };
        match &normals {
            Some(nv) => p.normals.extend(idx.iter().map(|&i| nv[i as usize])),
            None => {
                for t in p.positions.chunks_exact(3) {
                    let f = (t[1] - t[0]).cross(t[2] - t[0]).normalize_or_zero();
                    p.normals.extend([f; 3]);
                }
            }
        }
        if let Some(nt) = normal_map {
            let file_tangents: Option<Vec<Vec4>> = reader
                .read_tangents()
                .map(|it| it.map(Vec4::from_array).collect());
            match file_tangents {
                Some(t) if t.len() == n && t.iter().all(|t| t.is_finite()) => {
                    p.tangents = Some(
                        idx.iter()
                            .map(|&i| {
                                let t = t[i as usize];
                                let xyz = t.truncate().normalize_or_zero();
                                if xyz == Vec3::ZERO {
                                    Vec4::ZERO
                                } else {
                                    xyz.extend(if t.w < 0.0 { -1.0 } else { 1.0 })
                                }
                            })
                            .collect(),
                    );
                }
                other => {
                    if other.is_some() {
                        log::warn!(
                            "{file}: mesh '{mesh_name}': TANGENT is invalid (count or non-finite values): MikkTSpace tangents used"
                        );
                    }
                    let set = if nt.tex_coord == 0 {
                        Some(&p.uvs)
                    } else {
                        p.uvs1.as_ref()
                    };
                    match set {
                        Some(uv) if nt.tex_coord == 1 || reader.read_tex_coords(0).is_some() => {
                            let tris: Vec<[u32; 3]> = (0..corners as u32 / 3)
                                .map(|k| [3 * k, 3 * k + 1, 3 * k + 2])
                                .collect();
                            p.tangents =
                                Some(tangents::generate(&p.positions, &p.normals, uv, &tris));
                        }
                        _ => log::warn!(
                            "{file}: mesh '{mesh_name}': the normal map reads TEXCOORD_{}, which the primitive lacks: no normal mapping on it",
                            nt.tex_coord
                        ),
                    }
                }
            }
        }
        out.push(p);
    }
    Ok(out)
}

/// Appends a primitive placed by `m` (winding kept front-facing where `m` mirrors).
/// Writes primitive `p` under transform `m` over the vertices from `first_vertex` on, as `emit`
/// wrote them (the same arithmetic, so the result equals a load at that pose), and returns the
/// vertex after them. For a re-posed instance (src/scene/motion.rs): positions, normals, UVs
/// and tangents; the triangles' indices and materials stay.
pub(crate) fn emit_at(scene: &mut Scene, p: &Primitive, m: Mat4, first_vertex: usize) -> usize {
    let m3 = Mat3::from_mat4(m);
    let normal_matrix = m3.inverse().transpose();
    let flip = m3.determinant() < 0.0;
    let sign = if flip { -1.0 } else { 1.0 };
    let order: [usize; 3] = if flip { [0, 2, 1] } else { [0, 1, 2] };
    let tri_count = p.positions.len() / 3;
    let end = first_vertex + 3 * tri_count;
    if end > scene.positions.len() {
        return first_vertex;
    }
    for k in 0..tri_count {
        for (slot, &c) in order.iter().enumerate() {
            let i = 3 * k + c;
            let v = first_vertex + 3 * k + slot;
            scene.positions[v] = m.transform_point3(p.positions[i]);
            scene.normals[v] = (normal_matrix * p.normals[i]).normalize_or_zero();
            scene.uvs[v] = p.uvs[i];
            if let (Some(uv), Some(dst)) = (&p.uvs1, scene.uvs1.get_mut(v)) {
                *dst = uv[i];
            }
            if let (Some(t), Some(dst)) = (&p.tangents, scene.tangents.get_mut(v)) {
                let t = t[i];
                let xyz = (m3 * t.truncate()).normalize_or_zero();
                *dst = if xyz == Vec3::ZERO {
                    Vec4::ZERO
                } else {
                    xyz.extend(t.w * sign)
                };
            }
        }
    }
    end
}

pub(crate) fn emit(scene: &mut Scene, p: &Primitive, m: Mat4) {
    let m3 = Mat3::from_mat4(m);
    let normal_matrix = m3.inverse().transpose();
    let flip = m3.determinant() < 0.0;
    let sign = if flip { -1.0 } else { 1.0 };
    let order: [usize; 3] = if flip { [0, 2, 1] } else { [0, 1, 2] };
    let start = scene.positions.len();
    let tri_count = p.positions.len() / 3;
    scene.positions.reserve(tri_count * 3);
    for k in 0..tri_count {
        let base = scene.positions.len() as u32;
        for &c in &order {
            let i = 3 * k + c;
            scene.positions.push(m.transform_point3(p.positions[i]));
            scene
                .normals
                .push((normal_matrix * p.normals[i]).normalize_or_zero());
            scene.uvs.push(p.uvs[i]);
        }
        scene.triangles.push([base, base + 1, base + 2]);
        scene.triangle_material.push(p.material);
    }
    let end = scene.positions.len();
    // Optional arrays: empty until some primitive has them, then one entry per vertex.
    match &p.uvs1 {
        Some(uv) => {
            scene.uvs1.resize(start, Vec2::ZERO);
            for k in 0..tri_count {
                scene.uvs1.extend(order.map(|c| uv[3 * k + c]));
            }
        }
        None if !scene.uvs1.is_empty() => scene.uvs1.resize(end, Vec2::ZERO),
        None => {}
    }
    match &p.tangents {
        Some(t) => {
            scene.tangents.resize(start, Vec4::ZERO);
            for k in 0..tri_count {
                scene.tangents.extend(order.map(|c| {
                    let t = t[3 * k + c];
                    let xyz = (m3 * t.truncate()).normalize_or_zero();
                    if xyz == Vec3::ZERO {
                        Vec4::ZERO
                    } else {
                        xyz.extend(t.w * sign)
                    }
                }));
            }
        }
        None if !scene.tangents.is_empty() => scene.tangents.resize(end, Vec4::ZERO),
        None => {}
    }
}

/// EXT_mesh_gpu_instancing: the node's instance matrices (relative to the node), None without
/// the extension, an error when it is malformed.
fn read_instances(
    node: &gltf::Node,
    doc: &gltf::Document,
    buffers: &[gltf::buffer::Data],
) -> Result<Option<Vec<Mat4>>> {
    use gltf::accessor::{DataType, Dimensions, Iter};
    let Some(ext) = node.extension_value(INSTANCING) else {
        return Ok(None);
    };
    let attributes = ext
        .get("attributes")
        .and_then(|a| a.as_object())
        .ok_or_else(|| anyhow!("no attributes object"))?;
    let accessor = |name: &str, dims: Dimensions| -> Result<Option<gltf::Accessor>> {
        let Some(v) = attributes.get(name) else {
            return Ok(None);
        };
        let i = v
            .as_u64()
            .ok_or_else(|| anyhow!("{name} is not an accessor index"))?;
        let a = doc
            .accessors()
            .nth(i as usize)
            .ok_or_else(|| anyhow!("{name}: accessor {i} does not exist"))?;
        if a.dimensions() != dims {
            bail!(
                "{name}: accessor {i} is {:?}, {dims:?} expected",
                a.dimensions()
            );
        }
        Ok(Some(a))
    };
    let get = |b: gltf::Buffer| buffers.get(b.index()).map(|d| &d.0[..]);
    let unreadable = |name: &str| anyhow!("{name}: accessor data cannot be read");
    let translation: Option<Vec<Vec3>> = match accessor("TRANSLATION", Dimensions::Vec3)? {
        Some(a) if a.data_type() == DataType::F32 => Some(
            Iter::<[f32; 3]>::new(a, get)
                .ok_or_else(|| unreadable("TRANSLATION"))?
                .map(Vec3::from_array)
                .collect(),
        ),
        Some(a) => bail!(
            "TRANSLATION: {:?} components (float expected)",
            a.data_type()
        ),
        None => None,
    };
    let scale: Option<Vec<Vec3>> = match accessor("SCALE", Dimensions::Vec3)? {
        Some(a) if a.data_type() == DataType::F32 => Some(
            Iter::<[f32; 3]>::new(a, get)
                .ok_or_else(|| unreadable("SCALE"))?
                .map(Vec3::from_array)
                .collect(),
        ),
        Some(a) => bail!("SCALE: {:?} components (float expected)", a.data_type()),
        None => None,
    };
    let rotation: Option<Vec<Vec4>> = match accessor("ROTATION", Dimensions::Vec4)? {
        Some(a) => {
            let normalized = a.normalized();
            Some(match a.data_type() {
                DataType::F32 => Iter::<[f32; 4]>::new(a, get)
                    .ok_or_else(|| unreadable("ROTATION"))?
                    .map(Vec4::from_array)
                    .collect(),
                DataType::I8 if normalized => Iter::<[i8; 4]>::new(a, get)
                    .ok_or_else(|| unreadable("ROTATION"))?
                    .map(|q| Vec4::from_array(q.map(|c| (c as f32 / 127.0).max(-1.0))))
                    .collect(),
                DataType::I16 if normalized => Iter::<[i16; 4]>::new(a, get)
                    .ok_or_else(|| unreadable("ROTATION"))?
                    .map(|q| Vec4::from_array(q.map(|c| (c as f32 / 32767.0).max(-1.0))))
                    .collect(),
                other => bail!(
                    "ROTATION: {other:?} components{} (float, or normalized byte or short expected)",
                    if normalized { "" } else { ", not normalized" }
                ),
            })
        }
        None => None,
    };
    let counts: Vec<usize> = [
        translation.as_ref().map(|v| v.len()),
        rotation.as_ref().map(|v| v.len()),
        scale.as_ref().map(|v| v.len()),
    ]
    .into_iter()
    .flatten()
    .collect();
    let Some(&count) = counts.first() else {
        bail!("none of TRANSLATION, ROTATION, SCALE is given");
    };
    if counts.iter().any(|&c| c != count) {
        bail!("TRANSLATION, ROTATION and SCALE differ in count ({counts:?})");
    }
    Ok(Some(
        (0..count)
            .map(|i| {
                let t = translation.as_ref().map_or(Vec3::ZERO, |v| v[i]);
                let s = scale.as_ref().map_or(Vec3::ONE, |v| v[i]);
                let r = rotation.as_ref().map_or(Quat::IDENTITY, |v| {
                    v[i].try_normalize().map_or(Quat::IDENTITY, Quat::from_vec4)
                });
                Mat4::from_scale_rotation_translation(s, r, t)
            })
            .collect(),
    ))
}

fn read_light(light: &gltf::khr_lights_punctual::Light, world: Mat4) -> PunctualLight {
    use gltf::khr_lights_punctual::Kind;
    let intensity = Vec3::from_array(light.color()) * light.intensity();
    let position = world.transform_point3(Vec3::ZERO);
    let direction = world
        .transform_vector3(Vec3::NEG_Z)
        .try_normalize()
        .unwrap_or(Vec3::NEG_Z);
    let (kind, inner, outer) = match light.kind() {
        Kind::Directional => (PunctualKind::Directional, 0.0, 0.0),
        Kind::Point => (PunctualKind::Point, 0.0, 0.0),
        Kind::Spot {
            inner_cone_angle,
            outer_cone_angle,
        } => (PunctualKind::Spot, inner_cone_angle, outer_cone_angle),
    };
    PunctualLight {
        kind,
        position,
        direction,
        intensity,
        inner_cone: inner,
        outer_cone: outer,
    }
}

/// Decoded image to RGBA8. The gltf crate decodes PNG and JPEG with the `image` crate, whose
/// grey-alpha images arrive as two channels (grey, alpha); 16-bit and float images are
/// rounded to 8 bits (floats clamped to [0, 1]).
fn to_rgba8(img: &gltf::image::Data) -> Result<Texture> {
    use gltf::image::Format;
    let px = img.width as usize * img.height as usize;
    let src = &img.pixels;
    let u16s = || {
        src.chunks_exact(2)
            .map(|c| ((u16::from_ne_bytes([c[0], c[1]]) as u32 * 255 + 32767) / 65535) as u8)
            .collect::<Vec<u8>>()
    };
    let f32s = || {
        src.chunks_exact(4)
            .map(|c| {
                let v = f32::from_ne_bytes([c[0], c[1], c[2], c[3]]);
                (if v.is_finite() {
                    v.clamp(0.0, 1.0)
                } else {
                    0.0
                } * 255.0)
                    .round() as u8
            })
            .collect::<Vec<u8>>()
    };
    let expand = |v: &[u8], channels: usize| -> Vec<u8> {
        v.chunks_exact(channels)
            .flat_map(|c| match channels {
                1 => [c[0], c[0], c[0], 255],
                2 => [c[0], c[0], c[0], c[1]],
                3 => [c[0], c[1], c[2], 255],
                _ => [c[0], c[1], c[2], c[3]],
            })
            .collect()
    };
    let rgba8: Vec<u8> = match img.format {
        Format::R8 => expand(src, 1),
        Format::R8G8 => expand(src, 2),
        Format::R8G8B8 => expand(src, 3),
        Format::R8G8B8A8 => src.clone(),
        Format::R16 => expand(&u16s(), 1),
        Format::R16G16 => expand(&u16s(), 2),
        Format::R16G16B16 => expand(&u16s(), 3),
        Format::R16G16B16A16 => u16s(),
        Format::R32G32B32FLOAT => expand(&f32s(), 3),
        Format::R32G32B32A32FLOAT => f32s(),
    };
    if rgba8.len() != px * 4 {
        bail!(
            "texture data size does not match {}x{}",
            img.width,
            img.height
        );
    }
    Ok(Texture {
        width: img.width,
        height: img.height,
        rgba8,
    })
}
