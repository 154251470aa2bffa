//! glTF 2.0 (.gltf and .glb) through the `gltf` crate, flattened to a world-space [`Scene`].
//!
//! Read: node hierarchy and transforms, triangle primitives (positions, normals, UV0, indices;
//! flat normals generated when missing), metallic-roughness factors, base-colour textures,
//! emissive factor x KHR_materials_emissive_strength, KHR_materials_specular's factor,
//! doubleSided, KHR_lights_punctual and the first perspective camera.
//! Not read (left out on purpose, listed in the README): metallic-roughness/normal/occlusion/
//! emissive textures, texture transforms, UV sets other than 0, alpha modes, skins, morph targets.
//! Lenient where a part is optional: an unreadable image or an unknown extension that is not
//! required is skipped with a warning; a file with no light at all gets a default sky.

use super::{Camera, Material, PunctualKind, PunctualLight, Scene, Texture};
use anyhow::{anyhow, bail, Context, Result};
use glam::{Mat3, Mat4, Vec2, Vec3, Vec4};
use std::path::Path;

pub fn load(path: &Path) -> Result<Scene> {
    load_inner(path).with_context(|| format!("cannot load glTF scene {}", path.display()))
}

/// Extensions read (others in `extensionsUsed` are ignored with a warning; the gltf crate
/// refuses a file that *requires* one it does not know).
const SUPPORTED_EXTENSIONS: [&str; 3] = [
    "KHR_lights_punctual",
    "KHR_materials_emissive_strength",
    "KHR_materials_specular",
];

fn load_inner(path: &Path) -> Result<Scene> {
    let gltf::Gltf {
        document: doc,
        blob,
    } = gltf::Gltf::open(path).map_err(|e| anyhow!("{e}"))?;
    for ext in doc.extensions_used() {
        if !SUPPORTED_EXTENSIONS.contains(&ext) {
            let required = doc.extensions_required().any(|r| r == ext);
            if required {
                bail!("extension {ext} is required by the file but not supported");
            }
            log::warn!(
                "{}: extension {ext} is not supported: ignored",
                path.display()
            );
        }
    }
    let base = path.parent();
    let buffers = gltf::import_buffers(&doc, base, blob).map_err(|e| anyhow!("{e}"))?;
    let mut scene = Scene::new(
        &path
            .file_stem()
            .map(|s| s.to_string_lossy().to_string())
            .unwrap_or_default(),
    );

    // Lenient: an image that cannot be read is skipped (its textures fall back to the factors)
    // with a warning naming it, instead of refusing the whole scene.
    let mut texture_of_image = Vec::new();
    for image in doc.images() {
        let loaded = gltf::image::Data::from_source(image.source(), base, &buffers)
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
                    "{}: image {} ('{}'){from} skipped: {e:#}; textures using it fall back to their factors",
                    path.display(),
                    image.index(),
                    image.name().unwrap_or("unnamed")
                );
                texture_of_image.push(None);
            }
        }
    }
    for m in doc.materials() {
        scene.materials.push(read_material(&m, &texture_of_image)?);
    }
    // Primitives without a material get glTF's default material (appended last).
    let default_material = scene.materials.len() as u32;
    scene.materials.push(Material {
        name: "gltf default".into(),
        base_color: Vec4::ONE,
        base_color_texture: None,
        metallic: 1.0,
        roughness: 1.0,
        emissive: Vec3::ZERO,
        specular: 1.0,
        double_sided: false,
        brdf: Default::default(),
        callisto: Default::default(),
    });

    let gltf_scene = doc
        .default_scene()
        .or_else(|| doc.scenes().next())
        .ok_or_else(|| anyhow!("file has no scene"))?;
    let mut stack: Vec<(gltf::Node, Mat4)> =
        gltf_scene.nodes().map(|n| (n, Mat4::IDENTITY)).collect();
    let mut visited = 0usize;
    while let Some((node, parent)) = stack.pop() {
        visited += 1;
        if visited > 1_000_000 {
            bail!("node hierarchy too deep or cyclic");
        }
        let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        if let Some(mesh) = node.mesh() {
            add_mesh(&mut scene, &mesh, world, &buffers, default_material)?;
        }
        if let Some(light) = node.light() {
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
            stack.push((child, world));
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
    if !emits && scene.lights.is_empty() && scene.sky.max_element() <= 0.0 {
        scene.sky = Vec3::splat(DEFAULT_SKY);
        log::warn!(
            "{}: no light source (no emissive material, no KHR_lights_punctual): lit by a default uniform sky of radiance {DEFAULT_SKY}",
            path.display()
        );
    }
    scene.validate()?;
    Ok(scene)
}

/// Radiance of the sky a glTF without any light source gets.
pub const DEFAULT_SKY: f32 = 1.0;

fn read_material(m: &gltf::Material, texture_of_image: &[Option<usize>]) -> Result<Material> {
    let pbr = m.pbr_metallic_roughness();
    let tex = match pbr.base_color_texture() {
        Some(info) => {
            let idx = info.texture().source().index();
            match texture_of_image.get(idx) {
                Some(Some(t)) => Some(*t),
                Some(None) => None, // unreadable image: warned about above
                None => bail!(
                    "material '{}' references missing image {idx}",
                    m.name().unwrap_or("?")
                ),
            }
        }
        None => None,
    };
    let strength = m.emissive_strength().unwrap_or(1.0);
    let specular = m.specular().map(|s| s.specular_factor()).unwrap_or(1.0);
    let emissive = Vec3::from_array(m.emissive_factor()) * strength;
    if !emissive.is_finite() {
        bail!(
            "material '{}' has a non-finite emission",
            m.name().unwrap_or("?")
        );
    }
    let callisto = read_callisto_extras(m)?;
    Ok(Material {
        name: m.name().unwrap_or("unnamed").to_string(),
        base_color: Vec4::from_array(pbr.base_color_factor()),
        base_color_texture: tex,
        metallic: pbr.metallic_factor(),
        roughness: pbr.roughness_factor(),
        emissive,
        specular,
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

fn add_mesh(
    scene: &mut Scene,
    mesh: &gltf::Mesh,
    world: Mat4,
    buffers: &[gltf::buffer::Data],
    default_material: u32,
) -> Result<()> {
    let normal_matrix = Mat3::from_mat4(world).inverse().transpose();
    let flip = Mat3::from_mat4(world).determinant() < 0.0;
    for prim in mesh.primitives() {
        if prim.mode() != gltf::mesh::Mode::Triangles {
            log::warn!(
                "mesh '{}': skipping a {:?} primitive (only triangles are rendered)",
                mesh.name().unwrap_or("?"),
                prim.mode()
            );
            continue;
        }
        let reader = prim.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
        let positions: Vec<Vec3> = reader
            .read_positions()
            .ok_or_else(|| {
                anyhow!(
                    "mesh '{}' has a primitive without positions",
                    mesh.name().unwrap_or("?")
                )
            })?
            .map(|p| world.transform_point3(Vec3::from_array(p)))
            .collect();
        let n = positions.len();
        let normals: Vec<Vec3> = match reader.read_normals() {
            Some(it) => it
                .map(|v| (normal_matrix * Vec3::from_array(v)).normalize_or_zero())
                .collect(),
            None => vec![Vec3::ZERO; n],
        };
        let uvs: Vec<Vec2> = match reader.read_tex_coords(0) {
            Some(it) => it.into_f32().map(Vec2::from_array).collect(),
            None => vec![Vec2::ZERO; n],
        };
        if normals.len() != n || uvs.len() != n {
            bail!(
                "mesh '{}': attribute counts differ from the position count",
                mesh.name().unwrap_or("?")
            );
        }
        let indices: Vec<u32> = match reader.read_indices() {
            Some(it) => it.into_u32().collect(),
            None => (0..n as u32).collect(),
        };
        if let Some(bad) = indices.iter().find(|&&i| i as usize >= n) {
            bail!(
                "mesh '{}': index {bad} is out of range ({n} vertices)",
                mesh.name().unwrap_or("?")
            );
        }
        let material = prim
            .material()
            .index()
            .map_or(default_material, |i| i as u32);
        let missing_normals = reader.read_normals().is_none();
        for tri in indices.chunks_exact(3) {
            let t = if flip {
                [tri[0], tri[2], tri[1]]
            } else {
                [tri[0], tri[1], tri[2]]
            };
            let base = scene.positions.len() as u32;
            let p = t.map(|i| positions[i as usize]);
            // Unshared vertices: generated flat normals stay per triangle.
            let flat = (p[1] - p[0]).cross(p[2] - p[0]).normalize_or_zero();
            for (k, &i) in t.iter().enumerate() {
                scene.positions.push(p[k]);
                scene.normals.push(if missing_normals {
                    flat
                } else {
                    normals[i as usize]
                });
                scene.uvs.push(uvs[i as usize]);
            }
            scene.triangles.push([base, base + 1, base + 2]);
            scene.triangle_material.push(material);
        }
    }
    Ok(())
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

fn to_rgba8(img: &gltf::image::Data) -> Result<Texture> {
    use gltf::image::Format;
    let px = img.width as usize * img.height as usize;
    let src = &img.pixels;
    let rgba8: Vec<u8> = match img.format {
        Format::R8 => src.iter().flat_map(|&r| [r, r, r, 255]).collect(),
        Format::R8G8 => src
            .chunks_exact(2)
            .flat_map(|c| [c[0], c[1], 0, 255])
            .collect(),
        Format::R8G8B8 => src
            .chunks_exact(3)
            .flat_map(|c| [c[0], c[1], c[2], 255])
            .collect(),
        Format::R8G8B8A8 => src.clone(),
        other => bail!("unsupported texture format {other:?} (8-bit textures only)"),
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
