//! Validation that refuses only what the scene needs.
//!
//! The `gltf` crate validates a whole file, so a texture whose `source` points past the end of
//! `images` refuses the file even when no material uses that texture (such files are in public
//! sample repositories). Here the file is validated as usual; when that fails, each error is
//! traced to its top-level object (`textures[3]`, `meshes[0]`, ...) and the objects the loader
//! reads for the scene are walked from the scene's nodes. An invalid object the scene uses
//! refuses the file, naming it; an invalid unused one is dropped with a one-line warning, and
//! the loader never touches it (the crate's accessors would panic on its broken indices).

use anyhow::{bail, Result};
use gltf::json;
use std::collections::{BTreeMap, BTreeSet, HashSet};

/// A top-level glTF object: its array (`"textures"`) and index.
pub type ObjectId = (String, usize);

/// What the loader may read: the objects the scene uses and the invalid ones dropped.
#[derive(Debug, Default)]
pub struct Usage {
    pub used: HashSet<ObjectId>,
    /// Invalid objects nothing in the scene uses, with what was wrong.
    pub dropped: BTreeMap<ObjectId, Vec<String>>,
}

impl Usage {
    pub fn uses(&self, kind: &str, index: usize) -> bool {
        self.used.contains(&(kind.to_string(), index))
    }

    pub fn dropped(&self, kind: &str, index: usize) -> bool {
        self.dropped.contains_key(&(kind.to_string(), index))
    }
}

/// Validates `root` and returns the document, refusing only invalid objects the scene uses
/// (or errors outside any top-level object, e.g. in `asset`).
pub fn validate(root: json::Root, file: &str) -> Result<(gltf::Document, Usage)> {
    let mut usage = Usage {
        used: used_objects(&root),
        ..Default::default()
    };
    let errors = match gltf::Document::from_json(root.clone()) {
        Ok(doc) => return Ok((doc, usage)),
        Err(gltf::Error::Validation(errors)) => errors,
        Err(e) => bail!("{e}"),
    };
    let mut refused = Vec::new();
    let mut invalid: BTreeMap<ObjectId, Vec<String>> = BTreeMap::new();
    for (path, error) in &errors {
        let what = format!("{path}: {error}");
        match top_object(path.as_str()) {
            Some(id) => invalid.entry(id).or_default().push(what),
            None => refused.push(what),
        }
    }
    for (id, whats) in invalid {
        let name = object_name(&root, &id);
        if usage.used.contains(&id) {
            refused.push(format!(
                "{}[{}]{name} is used by the scene and invalid ({})",
                id.0,
                id.1,
                whats.join("; ")
            ));
        } else {
            log::warn!(
                "{file}: {}[{}]{name} is invalid ({}) and nothing in the scene uses it: dropped",
                id.0,
                id.1,
                whats.join("; ")
            );
            usage.dropped.insert(id, whats);
        }
    }
    if !refused.is_empty() {
        bail!("invalid glTF: {}", refused.join("; "));
    }
    Ok((gltf::Document::from_json_without_validation(root), usage))
}

/// `textures[3].source` -> ("textures", 3); the innermost array before the first index
/// (`extensions.KHR_lights_punctual.lights[2].spot` -> ("lights", 2)).
fn top_object(path: &str) -> Option<ObjectId> {
    let open = path.find('[')?;
    let close = open + path[open..].find(']')?;
    let index = path[open + 1..close].parse().ok()?;
    let kind = path[..open].rsplit('.').next()?;
    (!kind.is_empty()).then(|| (kind.to_string(), index))
}

/// " ('name')" of an object that has one.
fn object_name(root: &json::Root, (kind, i): &ObjectId) -> String {
    let name = match kind.as_str() {
        "textures" => root.textures.get(*i).and_then(|t| t.name.clone()),
        "images" => root.images.get(*i).and_then(|t| t.name.clone()),
        "materials" => root.materials.get(*i).and_then(|t| t.name.clone()),
        "meshes" => root.meshes.get(*i).and_then(|t| t.name.clone()),
        "nodes" => root.nodes.get(*i).and_then(|t| t.name.clone()),
        "accessors" => root.accessors.get(*i).and_then(|t| t.name.clone()),
        _ => None,
    };
    name.map(|n| format!(" ('{n}')")).unwrap_or_default()
}

/// The objects the loader reads for the scene, walked from the default scene (or the first)
/// through nodes, meshes, primitives' accessors and materials, textures, images, samplers,
/// buffer views and buffers, cameras, lights and instancing accessors. Broken indices are
/// recorded as used (and so refused by validation) but not followed.
pub fn used_objects(root: &json::Root) -> HashSet<ObjectId> {
    let mut used: HashSet<ObjectId> = HashSet::new();
    let mark = |used: &mut HashSet<ObjectId>, kind: &str, i: usize| -> bool {
        used.insert((kind.to_string(), i))
    };
    let scene = root.scene.map(|s| s.value()).unwrap_or(0);
    let Some(s) = root.scenes.get(scene) else {
        return used;
    };
    mark(&mut used, "scenes", scene);
    let mut nodes: Vec<usize> = s.nodes.iter().map(|n| n.value()).collect();
    let mut meshes = BTreeSet::new();
    let mut accessors = BTreeSet::new();
    while let Some(n) = nodes.pop() {
        if !mark(&mut used, "nodes", n) {
            continue;
        }
        let Some(node) = root.nodes.get(n) else {
            continue;
        };
        nodes.extend(node.children.iter().flatten().map(|c| c.value()));
        if let Some(m) = node.mesh {
            meshes.insert(m.value());
        }
        if let Some(c) = node.camera {
            mark(&mut used, "cameras", c.value());
        }
        if let Some(ext) = &node.extensions {
            if let Some(l) = &ext.khr_lights_punctual {
                mark(&mut used, "lights", l.light.value());
            }
            let instancing = ext.others.get("EXT_mesh_gpu_instancing");
            let attributes = instancing.and_then(|v| v.get("attributes"));
            for a in attributes.and_then(|a| a.as_object()).into_iter().flatten() {
                if let Some(i) = a.1.as_u64() {
                    accessors.insert(i as usize);
                }
            }
        }
    }
    let mut materials = BTreeSet::new();
    for m in meshes {
        mark(&mut used, "meshes", m);
        for p in root.meshes.get(m).iter().flat_map(|m| &m.primitives) {
            accessors.extend(p.attributes.values().map(|a| a.value()));
            accessors.extend(p.indices.map(|a| a.value()));
            materials.extend(p.material.map(|m| m.value()));
        }
    }
    let mut textures = BTreeSet::new();
    for m in materials {
        mark(&mut used, "materials", m);
        let Some(m) = root.materials.get(m) else {
            continue;
        };
        let pbr = &m.pbr_metallic_roughness;
        textures.extend(pbr.base_color_texture.as_ref().map(|t| t.index.value()));
        textures.extend(
            pbr.metallic_roughness_texture
                .as_ref()
                .map(|t| t.index.value()),
        );
        textures.extend(m.normal_texture.as_ref().map(|t| t.index.value()));
        textures.extend(m.occlusion_texture.as_ref().map(|t| t.index.value()));
        textures.extend(m.emissive_texture.as_ref().map(|t| t.index.value()));
    }
    let mut views = BTreeSet::new();
    for t in textures {
        mark(&mut used, "textures", t);
        let Some(t) = root.textures.get(t) else {
            continue;
        };
        if let Some(s) = t.sampler {
            mark(&mut used, "samplers", s.value());
        }
        let image = t.source.value();
        mark(&mut used, "images", image);
        views.extend(
            root.images
                .get(image)
                .and_then(|i| i.buffer_view)
                .map(|v| v.value()),
        );
    }
    for a in accessors {
        mark(&mut used, "accessors", a);
        let Some(a) = root.accessors.get(a) else {
            continue;
        };
        views.extend(a.buffer_view.map(|v| v.value()));
        if let Some(s) = &a.sparse {
            views.insert(s.indices.buffer_view.value());
            views.insert(s.values.buffer_view.value());
        }
    }
    for v in views {
        mark(&mut used, "bufferViews", v);
        if let Some(v) = root.buffer_views.get(v) {
            mark(&mut used, "buffers", v.buffer.value());
        }
    }
    used
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paths_name_their_top_object() {
        let t = |p: &str| top_object(p).map(|(k, i)| format!("{k}[{i}]"));
        assert_eq!(t("textures[3].source").as_deref(), Some("textures[3]"));
        assert_eq!(
            t("meshes[0].primitives[1].attributes[\"POSITION\"]").as_deref(),
            Some("meshes[0]")
        );
        assert_eq!(
            t("extensions.KHR_lights_punctual.lights[2].spot").as_deref(),
            Some("lights[2]")
        );
        assert_eq!(t("asset.version"), None);
        assert_eq!(t("scene"), None);
    }
}
