//! Two-level BVH: one bottom-level tree per instanced mesh (built once, in object space), the
//! rest of the scene in one more, and a top level over the instances.
//!
//! What is shared and what is not: the trees are per mesh (build time and node memory scale
//! with the distinct geometry), but the triangle records the shaders read stay flattened in
//! world space, one copy per instance (`tri_geom`/`tri_attr`, 144 bytes a triangle), so every
//! reader of a hit (surfaces, light pool, Lumen's card lookups, the raster passes) works
//! unchanged and a hit is the same triangle, same `t`, as with a flat tree. Point queries
//! (Lumen's distance field, `closest_triangle`) walk the same two levels, pruning an object-space
//! box by its distance times the record's `distance_scale`. Traversal moves the
//! ray into an instance's object space for its node tests only and intersects the world-space
//! triangles (`t` is one parameter in both spaces, the transform being affine).
//!
//! Node layout (`Bvh::nodes`): top level (leaves of one instance: `INSTANCE_LEAF`), the rest of
//! the scene's tree, each mesh's tree, then the instance records (two nodes each). Skip
//! pointers of a bottom-level tree are absolute, so its root's skip is its end.

use super::bvh::{
    Aabb, Bvh, BvhNode, InstanceRecord, TopEntry, TopLevel, INSTANCE_LEAF, MAX_TRIANGLES,
};
use super::MeshInstance;
use glam::{Mat4, Vec3};
use rayon::prelude::*;
use std::collections::BTreeMap;

/// How far (relative to the mesh's size plus the instance's distance from its origin) an
/// instance's triangles may lie from its mesh's and still count as that mesh: float rounding
/// of the transforms. Bottom-level boxes are padded by as much, so no hit is lost.
const MATCH_TOLERANCE: f32 = 1e-5;

/// A mesh with at least one usable instance: its object-space triangles and instances.
struct Mesh {
    object: Vec<[Vec3; 3]>,
    /// (instance index in the scene's list, world-to-object transform).
    instances: Vec<(usize, Mat4)>,
    /// Box padding covering every instance's rounding.
    pad: f32,
}

impl Bvh {
    /// The scene's BVH: flat without usable instances (bit for bit `Bvh::build`), else two
    /// levels (module doc). Instances that do not match their mesh, overlap another or fall
    /// outside the scene are traced as ordinary geometry, with a log line.
    pub fn build_instanced(tris: &[[Vec3; 3]], instances: &[MeshInstance]) -> Bvh {
        let meshes = usable_meshes(tris, instances);
        if meshes.is_empty() {
            return Bvh::build(tris);
        }
        let mut covered = vec![false; tris.len()];
        for m in &meshes {
            for &(j, _) in &m.instances {
                let i = &instances[j];
                let range =
                    i.first_triangle as usize..(i.first_triangle + i.triangle_count) as usize;
                covered[range].iter_mut().for_each(|c| *c = true);
            }
        }
        let rest: Vec<u32> = (0..tris.len() as u32)
            .filter(|&t| !covered[t as usize])
            .collect();
        let rest_tris: Vec<[Vec3; 3]> = rest.iter().map(|&t| tris[t as usize]).collect();
        // Bottom levels: the rest (parallel inside) and each mesh (meshes in parallel).
        let (rest_bvh, mesh_bvhs) = rayon::join(
            || Bvh::build(&rest_tris),
            || {
                meshes
                    .par_iter()
                    .map(|m| {
                        let mut b = Bvh::build(&m.object);
                        for n in &mut b.nodes {
                            n.min = (Vec3::from(n.min) - m.pad).to_array();
                            n.max = (Vec3::from(n.max) + m.pad).to_array();
                        }
                        b
                    })
                    .collect::<Vec<_>>()
            },
        );

        // Bottom-level trees: the rest's (when any triangle is left), then one per mesh.
        let mut trees: Vec<&Bvh> = Vec::new();
        if !rest_bvh.nodes.is_empty() {
            trees.push(&rest_bvh);
        }
        trees.extend(&mesh_bvhs);
        // Entries of the top level: the rest (identity), then every instance.
        struct Entry {
            bounds: Aabb,
            tree: usize,
            world_to_object: Mat4,
            /// Original index of the tree's local triangle k: `first + k` (instances) or
            /// `rest[k]` (the rest of the scene).
            first: Option<u32>,
            /// Index in the scene's instance list (None: the rest).
            instance: Option<usize>,
        }
        let mut entries = Vec::new();
        if !rest_bvh.nodes.is_empty() {
            entries.push(Entry {
                bounds: node_box(&rest_bvh.nodes[0]),
                tree: 0,
                world_to_object: Mat4::IDENTITY,
                first: None,
                instance: None,
            });
        }
        let first_mesh_tree = trees.len() - meshes.len();
        for (k, m) in meshes.iter().enumerate() {
            let tree = first_mesh_tree + k;
            let object_box = node_box(&trees[tree].nodes[0]);
            for &(j, world_to_object) in &m.instances {
                entries.push(Entry {
                    bounds: transformed_box(&object_box, instances[j].transform),
                    tree,
                    world_to_object,
                    first: Some(instances[j].first_triangle),
                    instance: Some(j),
                });
            }
        }
        let boxes: Vec<Aabb> = entries.iter().map(|e| e.bounds).collect();
        let top = Bvh::build_boxes(&boxes, false, 1);

        // Bottom-level trees once each (a mesh's instances share it), then the records.
        let mut nodes = top.nodes.clone();
        let mut tree_base = Vec::with_capacity(trees.len());
        for tree in &trees {
            let base = nodes.len() as u32;
            tree_base.push(base);
            nodes.extend(tree.nodes.iter().map(|n| BvhNode {
                skip: n.skip + base,
                ..*n
            }));
        }
        let records_at = nodes.len();
        let mut order = Vec::with_capacity(tris.len());
        let mut record_of_entry = vec![0u32; entries.len()];
        let mut top_entries = Vec::with_capacity(entries.len());
        for (e, entry) in entries.iter().enumerate() {
            let tree = trees[entry.tree];
            let tri_offset = order.len() as u32;
            match entry.first {
                Some(first) => order.extend(tree.order.iter().map(|&k| first + k)),
                None => order.extend(tree.order.iter().map(|&k| rest[k as usize])),
            }
            let base = tree_base[entry.tree];
            let end = base + tree.nodes.len() as u32;
            let object = node_box(&tree.nodes[0]);
            top_entries.push(TopEntry {
                object_min: object.min,
                object_max: object.max,
                root: base,
                end,
                tri_offset,
                instance: entry.instance,
            });
            let record = InstanceRecord::new(entry.world_to_object, base, end, tri_offset);
            record_of_entry[e] = (records_at + 2 * e) as u32;
            nodes.extend_from_slice(bytemuck::cast_slice::<InstanceRecord, BvhNode>(&[record]));
        }
        // Top-level leaves point at their entry's record.
        for n in &mut nodes[..top.nodes.len()] {
            if n.tri_count() > 0 {
                let entry = top.order[n.first_tri() as usize] as usize;
                n.tris = (record_of_entry[entry] << 8) | INSTANCE_LEAF;
            }
        }
        debug_assert_eq!(order.len(), tris.len());
        if nodes.len() >= MAX_TRIANGLES {
            log::warn!(
                "two-level BVH: {} nodes exceed the 2^24 a leaf can address; built flat instead",
                nodes.len()
            );
            return Bvh::build(tris);
        }
        let bottom_depth = mesh_bvhs
            .iter()
            .chain([&rest_bvh])
            .map(|b| b.depth)
            .max()
            .unwrap_or(0);
        Bvh {
            nodes,
            order,
            depth: top.depth + 1 + bottom_depth,
            instances: entries.len() - (!rest_bvh.nodes.is_empty()) as usize,
            instanced_meshes: meshes.len(),
            top: Some(TopLevel {
                entries: top_entries,
                nodes: top.nodes.len(),
                records_at,
                bottom_depth,
            }),
        }
    }

    /// Rebuilds the top level of a two-level BVH over the instances' current transforms
    /// (`instances`: the scene's list, moved in place), leaving every bottom level and the
    /// triangle order as they are: the world-space triangles of a moved instance keep their
    /// place. False when that is not possible: a flat tree, or a moved instance (`moved`) that
    /// is not traced through a tree of its own (it was traced as ordinary geometry); then the
    /// caller builds the whole BVH again.
    ///
    /// Bottom-level boxes were padded at build time by 1e-5 of the mesh's size plus its
    /// instances' distance from the origin (float rounding of the transforms); an instance that
    /// moves 100 times farther from the origin than it started exceeds that padding.
    pub fn rebuild_top(&mut self, instances: &[MeshInstance], moved: &[usize]) -> bool {
        let Some(top) = &self.top else {
            return false;
        };
        let traced = |j: usize| top.entries.iter().any(|e| e.instance == Some(j));
        if !moved.iter().all(|&j| traced(j)) {
            return false;
        }
        let mut boxes = Vec::with_capacity(top.entries.len());
        for e in &top.entries {
            let object = Aabb {
                min: e.object_min,
                max: e.object_max,
            };
            boxes.push(match e.instance {
                Some(j) => match instances.get(j) {
                    Some(i) if i.transform.determinant() != 0.0 => {
                        transformed_box(&object, i.transform)
                    }
                    _ => return false,
                },
                None => object,
            });
        }
        let new_top = Bvh::build_boxes(&boxes, false, 1);
        // One entry a leaf: 2E - 1 nodes whatever the boxes, so the records stay in place.
        if new_top.nodes.len() != top.nodes {
            return false;
        }
        let (records_at, bottom_depth) = (top.records_at, top.bottom_depth);
        for (e, entry) in top.entries.iter().enumerate() {
            if let Some(j) = entry.instance {
                let record = InstanceRecord::new(
                    instances[j].transform.inverse(),
                    entry.root,
                    entry.end,
                    entry.tri_offset,
                );
                let at = records_at + 2 * e;
                self.nodes[at..at + 2]
                    .copy_from_slice(bytemuck::cast_slice::<InstanceRecord, BvhNode>(&[record]));
            }
        }
        let mut nodes = new_top.nodes;
        for n in &mut nodes {
            if n.tri_count() > 0 {
                let entry = new_top.order[n.first_tri() as usize] as usize;
                n.tris = (((records_at + 2 * entry) as u32) << 8) | INSTANCE_LEAF;
            }
        }
        let count = nodes.len();
        self.nodes[..count].copy_from_slice(&nodes);
        self.depth = new_top.depth + 1 + bottom_depth;
        true
    }
}

fn node_box(n: &BvhNode) -> Aabb {
    Aabb {
        min: Vec3::from(n.min),
        max: Vec3::from(n.max),
    }
}

/// The world box of an object-space box under `transform` (its eight corners).
fn transformed_box(b: &Aabb, transform: Mat4) -> Aabb {
    let mut out = Aabb::EMPTY;
    for k in 0..8 {
        let corner = Vec3::new(
            if k & 1 == 0 { b.min.x } else { b.max.x },
            if k & 2 == 0 { b.min.y } else { b.max.y },
            if k & 4 == 0 { b.min.z } else { b.max.z },
        );
        out.grow(transform.transform_point3(corner));
    }
    out
}

/// Meshes and their usable instances (see `build_instanced`), in mesh id order.
fn usable_meshes(tris: &[[Vec3; 3]], instances: &[MeshInstance]) -> Vec<Mesh> {
    let mut by_mesh: BTreeMap<u32, Vec<usize>> = BTreeMap::new();
    let mut claimed = vec![false; tris.len()];
    let mut dropped = 0usize;
    for (j, i) in instances.iter().enumerate() {
        let (first, count) = (i.first_triangle as usize, i.triangle_count as usize);
        let in_range = count > 0 && first.checked_add(count).is_some_and(|e| e <= tris.len());
        let invertible = i.transform.is_finite()
            && i.transform.determinant() != 0.0
            && i.transform.inverse().is_finite();
        if !in_range || !invertible || claimed[first..first + count].iter().any(|&c| c) {
            dropped += 1;
            continue;
        }
        claimed[first..first + count]
            .iter_mut()
            .for_each(|c| *c = true);
        by_mesh.entry(i.mesh).or_default().push(j);
    }
    let meshes: Vec<Mesh> = by_mesh
        .into_values()
        .map(|list| {
            // The mesh's shape: its first instance taken back to object space.
            let i0 = &instances[list[0]];
            let to_object = i0.transform.inverse();
            let range0 =
                i0.first_triangle as usize..(i0.first_triangle + i0.triangle_count) as usize;
            let object: Vec<[Vec3; 3]> = tris[range0]
                .iter()
                .map(|t| t.map(|p| to_object.transform_point3(p)))
                .collect();
            let mut size = Aabb::EMPTY;
            object.iter().flatten().for_each(|p| size.grow(*p));
            let diagonal = (size.max - size.min).length();
            let mut mesh = Mesh {
                object,
                instances: Vec::new(),
                pad: 0.0,
            };
            for &j in &list {
                let i = &instances[j];
                let to_object = i.transform.inverse();
                let world = &tris[i.first_triangle as usize..][..i.triangle_count as usize];
                // Rounding grows with the coordinates' size, seen in object units.
                let reach = to_object.transform_vector3(Vec3::ONE).length()
                    * i.transform.w_axis.truncate().length();
                let tolerance = MATCH_TOLERANCE * (diagonal + reach);
                let matches = world.len() == mesh.object.len()
                    && world.iter().zip(&mesh.object).all(|(w, o)| {
                        // Vertex order may differ (a mirrored node flips the winding).
                        w.iter().all(|&p| {
                            let q = to_object.transform_point3(p);
                            o.iter().any(|v| v.distance(q) <= tolerance)
                        })
                    });
                if matches {
                    mesh.pad = mesh.pad.max(tolerance);
                    mesh.instances.push((j, to_object));
                } else {
                    dropped += 1;
                }
            }
            mesh
        })
        .filter(|m| !m.instances.is_empty())
        .collect();
    if dropped > 0 {
        log::warn!(
            "{dropped} of {} instances do not match their mesh (or overlap, or lie outside the scene): traced as ordinary triangles",
            instances.len()
        );
    }
    meshes
}
