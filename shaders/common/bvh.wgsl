// BVH traversal: closest hit and any hit over the binned-SAH BVH built in src/scene/bvh.rs,
// with the alpha test of alpha-masked materials (finest texture level) on every candidate.
// Stackless: nodes are in depth-first order with skip pointers (a hit on an interior node goes
// to the next node, a miss or a finished leaf to `skip`), so no per-lane stack is needed; on
// CPU rasterisers such as lavapipe private-array stacks are gather/scatter and far slower.
#define_import_path gilab::bvh

#import gilab::scene::{bvh_nodes, bvh_node, tri_geom_at, alpha_hole}

const NO_HIT: u32 = 0xffffffffu;

struct Hit {
    t: f32,
    tri: u32,
    // Barycentrics of the second and third vertex.
    bary: vec2<f32>,
}

fn hits_aabb(origin: vec3<f32>, inv_dir: vec3<f32>, bmin: vec3<f32>, bmax: vec3<f32>, t_max: f32) -> bool {
    let t_lo = (bmin - origin) * inv_dir;
    let t_hi = (bmax - origin) * inv_dir;
    let tmin = min(t_lo, t_hi);
    let tmax = max(t_lo, t_hi);
    let enter = max(max(tmin.x, tmin.y), max(tmin.z, 0.0));
    let exit = min(min(tmax.x, tmax.y), min(tmax.z, t_max));
    return enter <= exit;
}

// Returns (t, bary_b, bary_c); t < 0 when missed. Zero-area triangles never hit (det == 0).
fn intersect_tri(origin: vec3<f32>, dir: vec3<f32>, tri: u32) -> vec3<f32> {
    let g = tri_geom_at(tri);
    let edge_b = g.edge_b.xyz;
    let edge_c = g.edge_c.xyz;
    let p = cross(dir, edge_c);
    let det = dot(edge_b, p);
    if abs(det) < 1e-20 {
        return vec3<f32>(-1.0, 0.0, 0.0);
    }
    let inv_det = 1.0 / det;
    let s = origin - g.vertex_a.xyz;
    let bary_b = dot(s, p) * inv_det;
    let q = cross(s, edge_b);
    let bary_c = dot(dir, q) * inv_det;
    if bary_b < 0.0 || bary_b > 1.0 || bary_c < 0.0 || bary_b + bary_c > 1.0 {
        return vec3<f32>(-1.0, 0.0, 0.0);
    }
    let t = dot(edge_c, q) * inv_det;
    return vec3<f32>(t, bary_b, bary_c);
}

fn safe_inv_dir(dir: vec3<f32>) -> vec3<f32> {
    let eps = 1e-20;
    let d = select(dir, vec3<f32>(eps), abs(dir) < vec3<f32>(eps));
    return 1.0 / d;
}

// Top-level leaf: `tris >> 8` is the node index of an instance record (src/scene/bvh.rs).
const INSTANCE_LEAF: u32 = 0xffu;

// An instance (src/scene/bvh.rs InstanceRecord), stored as the two nodes from `at` on: the
// world-to-object columns and translation in their float slots, the tree's node range, the
// first triangle and the distance scale in their integer slots.
struct Instance {
    to_object_x: vec3<f32>,
    to_object_y: vec3<f32>,
    to_object_z: vec3<f32>,
    translation: vec3<f32>,
    root: u32,
    end: u32,
    tri_offset: u32,
    // Lower bound of world length per object length (point queries).
    distance_scale: f32,
}

fn instance_at(at: u32) -> Instance {
    let a = bvh_node(at);
    let b = bvh_node(at + 1u);
    return Instance(a.bounds_min, a.bounds_max, b.bounds_min, b.bounds_max, a.skip, a.tris, b.skip, bitcast<f32>(b.tris));
}

fn to_object_vector(inst: Instance, v: vec3<f32>) -> vec3<f32> {
    return inst.to_object_x * v.x + inst.to_object_y * v.y + inst.to_object_z * v.z;
}

// Instance filters of `traverse`: which instances of a two-level BVH a ray sees. All; only
// those that do not move (`instance_moves` false), with the flat rest of the scene; only those
// that move. (`instance_moves` follows the last const with its comment inside it: naga_oil
// turns `virtual fn` and the whitespace before it into spaces, joining it to the line above,
// where a line comment would swallow the declaration.)
const INSTANCES_ALL: u32 = 0u;
const INSTANCES_STATIC: u32 = 1u;
const INSTANCES_DYNAMIC: u32 = 2u;
virtual fn instance_moves(at: u32) -> bool {
    // Whether the instance whose record is at node `at` moves, for INSTANCES_STATIC and
    // INSTANCES_DYNAMIC. The BVH does not know what moves: a pass that filters overrides this
    // in its entry shader (naga_oil `override fn gilab::bvh::instance_moves`) with its own
    // record, e.g. Callisto's static/dynamic split (shaders/callisto_shadows/static_cache.wgsl).
    // Without an override nothing moves.
    return false;
}

// Walks the BVH for hits in (t_min, t_max): the closest one, or with `any_hit` the first one
// found (shadow rays need no more). hit.tri == NO_HIT on a miss.
// With INSTANCES (a two-level BVH, src/scene/instancing.rs) a top-level leaf moves the ray into
// its instance's object space for the node tests of the mesh's tree, then traversal returns to
// the top level; triangles are always the flattened world-space ones, so `t` and the hit are
// those of a flat tree. `instances` (INSTANCES_*) skips the top-level leaves of the instances it
// leaves out; a flat BVH has no instances, so nothing in it moves.
fn traverse(origin: vec3<f32>, dir: vec3<f32>, t_min: f32, t_max: f32, any_hit: bool, instances: u32) -> Hit {
    var hit = Hit(t_max, NO_HIT, vec2<f32>(0.0));
#ifndef INSTANCES
    if instances == INSTANCES_DYNAMIC {
        return hit;
    }
#endif
    let inv_dir = safe_inv_dir(dir);
    let node_count = arrayLength(&bvh_nodes);
#ifdef INSTANCES
    var top_end = 0u;
    if node_count > 0u {
        top_end = bvh_node(0u).skip;
    }
    var o = origin;
    var inv = inv_dir;
    var end = top_end;
    var resume = 0u;
    var tri_base = 0u;
    var inside = false;
#else
    let o = origin;
    let inv = inv_dir;
    let end = node_count;
    let tri_base = 0u;
#endif
    var i = 0u;
    loop {
        if i >= end {
#ifdef INSTANCES
            if inside {
                // The instance's tree is done: back to the top level.
                i = resume;
                end = top_end;
                o = origin;
                inv = inv_dir;
                tri_base = 0u;
                inside = false;
                continue;
            }
#endif
            break;
        }
        let node = bvh_node(i);
        if !hits_aabb(o, inv, node.bounds_min, node.bounds_max, hit.t) {
            i = node.skip;
            continue;
        }
        let count = node.tris & 0xffu;
        if count == 0u {
            i++;
            continue;
        }
#ifdef INSTANCES
        if count == INSTANCE_LEAF {
            let at = node.tris >> 8u;
            if instances != INSTANCES_ALL && instance_moves(at) == (instances == INSTANCES_STATIC) {
                i = node.skip;
                continue;
            }
            let inst = instance_at(at);
            o = to_object_vector(inst, origin) + inst.translation;
            inv = safe_inv_dir(to_object_vector(inst, dir));
            resume = node.skip;
            i = inst.root;
            end = inst.end;
            tri_base = inst.tri_offset;
            inside = true;
            continue;
        }
#endif
        let first = tri_base + (node.tris >> 8u);
        for (var k = 0u; k < count; k++) {
            let r = intersect_tri(origin, dir, first + k);
#ifdef ALPHA_TEST
            // Any-hit: holes of alpha-tested triangles let the ray through (compiled in only
            // for scenes with alpha-tested materials: ShaderVariant in src/gpu/shaders.rs).
            if r.x > t_min && r.x < hit.t && !alpha_hole(first + k, r.yz) {
#else
            if r.x > t_min && r.x < hit.t {
#endif
                hit = Hit(r.x, first + k, r.yz);
                if any_hit {
                    return hit;
                }
            }
        }
        i = node.skip;
    }
    return hit;
}

// Closest hit in (t_min, t_max). hit.tri == NO_HIT (and hit.t == t_max) on a miss.
fn trace_closest(origin: vec3<f32>, dir: vec3<f32>, t_min: f32, t_max: f32) -> Hit {
    return traverse(origin, dir, t_min, t_max, false, INSTANCES_ALL);
}

// True if anything among the instances `instances` (INSTANCES_*) selects blocks the open segment
// (t_min, t_max).
fn trace_any_filtered(origin: vec3<f32>, dir: vec3<f32>, t_min: f32, t_max: f32, instances: u32) -> bool {
    return traverse(origin, dir, t_min, t_max, true, instances).tri != NO_HIT;
}

// True if anything blocks the open segment (t_min, t_max): shadow and visibility rays.
fn trace_any(origin: vec3<f32>, dir: vec3<f32>, t_min: f32, t_max: f32) -> bool {
    return trace_any_filtered(origin, dir, t_min, t_max, INSTANCES_ALL);
}
