// The seed's static/dynamic shadow split (shared/seeds/002, RAYTRACED SHADOWS: static-on-static
// shadows cached, "Dynamic TLAS for dynamic-on-static shadowing"), in world space: the seed
// keeps static shadows in lightmaps baked offline; gilab has no lightmaps, so a light that has
// not moved keeps the visibility of static geometry in a hash grid of cells (per light, cell
// edge a power of two near `cache_cell` pixel footprints, the normal's dominant axis), filled at
// run time by rays that skip the moving instances. Each frame a static receiver then traces only
// the moving instances (a ray that enters none of their boxes traces nothing), and its
// visibility is the cell's static visibility times that. Lights that moved and receivers on
// moving instances trace the whole scene. The static-only and moving-only rays are the shared
// any-hit traversal (gilab::ray::occluded_filtered, gilab::bvh::traverse) with an instance
// filter; what moves is `record_dynamic` below, which shadows.wgsl plugs into it.
#define_import_path gilab::callisto_cache

#import gilab::frame::frame
#import gilab::scene::{tri_attr, tri_attr_at}
#import gilab::bvh::{hits_aabb, safe_inv_dir, INSTANCES_ALL, INSTANCES_STATIC, INSTANCES_DYNAMIC}
#import gilab::ray::{RaySegment, occluded_filtered}
#import gilab::callisto::{params, shadow_cache}

const CACHE_NONE: u32 = 0xffffffffu;

fn cache_word(i: u32) -> u32 {
    return atomicLoad(&shadow_cache[i]);
}

fn entry_dynamic(e: u32) -> bool {
    return ((cache_word(e / 32u) >> (e % 32u)) & 1u) != 0u;
}

fn light_dynamic(light: u32) -> bool {
    return ((cache_word(params.light_mask_base + light / 32u) >> (light % 32u)) & 1u) != 0u;
}

// Whether a receiver (GSurface.prev_pos.w: BVH-order triangle + 1) lies on a moving instance.
fn receiver_dynamic(tri_plus_one: u32) -> bool {
    if tri_plus_one == 0u {
        return false;
    }
    let record = tri_attr_at(tri_plus_one - 1u).pad.x;
    if record == 0u || record - 1u < params.motion_base {
        return false;
    }
    return entry_dynamic((record - 1u - params.motion_base) / 2u);
}

// Whether the top-level entry whose instance record is at node `at` has moved: what the shared
// traversal's instance filters (gilab::bvh::INSTANCES_STATIC / INSTANCES_DYNAMIC) ask, through
// the override of gilab::bvh::instance_moves in the entry shader (shadows.wgsl).
fn record_dynamic(at: u32) -> bool {
    return entry_dynamic((at - params.records_at) / 2u);
}

// Whether the segment enters a moving instance's world box (the caster-box culling: a ray that
// enters none is not traced against them).
fn enters_dynamic(s: RaySegment) -> bool {
    let inv_dir = safe_inv_dir(s.dir);
    for (var d = 0u; d < params.dynamic_count; d++) {
        let b = params.dynamic_base + d * 8u;
        let bmin = vec3<f32>(bitcast<f32>(cache_word(b)), bitcast<f32>(cache_word(b + 1u)), bitcast<f32>(cache_word(b + 2u)));
        let bmax = vec3<f32>(bitcast<f32>(cache_word(b + 4u)), bitcast<f32>(cache_word(b + 5u)), bitcast<f32>(cache_word(b + 6u)));
        if hits_aabb(s.origin, inv_dir, bmin, bmax, s.t_max) {
            return true;
        }
    }
    return false;
}

fn hash_u(v: u32) -> u32 {
    // PCG (Jarzynski & Olano 2020).
    let state = v * 747796405u + 2891336453u;
    let word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

const CACHE_PROBES: u32 = 8u;

// Words of a hash slot (SLOT_WORDS from hash_base + SLOT_WORDS * slot). Reads within a frame see
// only what `settle` (cache_settle.wgsl) fixed at the end of the frames before, so which keys own
// slots and which cells are filled never depends on the order the shadow rays run in (until
// 2026-11-29 the first ray to a slot claimed it and the first `cache_samples` rays of a cell
// filled it within the frame, and a fixed seed gave different images run to run):
// - CLAIM: this frame's bids for the empty slot, atomicMax of the keys;
// - OWNER: the key that owns it (settled; a slot, once owned, is kept until the cache is
//   cleared, as before);
// - VALUE: rays << 16 | unoccluded, added by the owner's receivers while it fills;
// - FILLED: VALUE as it was once the cell had its rays (0 while filling).
const SLOT_WORDS: u32 = 4u;
const SLOT_CLAIM: u32 = 0u;
const SLOT_OWNER: u32 = 1u;
const SLOT_VALUE: u32 = 2u;
const SLOT_FILLED: u32 = 3u;

fn slot_word(slot: u32, word: u32) -> u32 {
    return params.hash_base + SLOT_WORDS * slot + word;
}

// The cache slot of (light, the cell around p with normal n at distance dist from the camera)
// among the key's CACHE_PROBES probes when its key owns one; else CACHE_NONE, and the key bids
// for the first empty probe (settle gives it to the largest key that bid).
fn cache_slot(light: u32, p: vec3<f32>, n: vec3<f32>, dist: f32) -> u32 {
    // Camera up is scaled by tan(fov/2): a pixel spans 2 |up| / height per unit of distance.
    let footprint = dist * 2.0 * length(frame.camera_up.xyz) / f32(frame.size.y);
    let level = i32(ceil(log2(max(footprint * params.cache_cell, 1e-6))));
    let c = vec3<i32>(floor(p * exp2(f32(-level))));
    let a = abs(n);
    let axis = select(select(2u, 1u, a.y >= a.z), 0u, a.x >= a.y && a.x >= a.z);
    let side = select(0u, 1u, n[axis] < 0.0);
    let tag = (u32(level + 64) << 3u) | (axis << 1u) | side;
    let h = hash_u(hash_u(hash_u(hash_u(hash_u(u32(c.x)) + u32(c.y)) + u32(c.z)) + tag) + light);
    // An independent checksum (nonzero: 0 marks an empty slot).
    let key = max(hash_u(u32(c.x) ^ hash_u(u32(c.y) ^ 0x9e3779b9u ^ hash_u(u32(c.z) ^ hash_u(tag ^ hash_u(light + 0x68bc21ebu))))), 1u);
    var empty = CACHE_NONE;
    for (var probe = 0u; probe < CACHE_PROBES; probe++) {
        let slot = (h + probe) & (params.cache_slots - 1u);
        let owner = cache_word(slot_word(slot, SLOT_OWNER));
        if owner == key {
            return slot;
        }
        if owner == 0u && empty == CACHE_NONE {
            empty = slot;
        }
    }
    if empty != CACHE_NONE {
        atomicMax(&shadow_cache[slot_word(empty, SLOT_CLAIM)], key);
    }
    return CACHE_NONE;
}

// No traversal due: after a cache hit or a finished static ray.
const NO_TRACE: u32 = 0xffffffffu;

// What a shadow ray's visibility needs before any traversal: the receiver's cell and its cached
// static visibility, and the traversal left (`instances`: the whole scene, the static instances
// while the cell fills, the moving ones behind a cached value; NO_TRACE: none, `vis` is final).
// The shadow pass plans at the pixel and queues only the rays that traverse.
struct VisibilityPlan {
    slot: u32,
    vis: f32,
    instances: u32,
}

// The plan of a shadow ray from receiver p (geometric normal ng, distance dist from the camera;
// `receiver_moves`: on a moving instance) towards light `light`. Without the split, one ray
// against the whole scene. With it, the cell's static visibility (cached, or traced against the
// static instances while the cell fills), then a ray against the moving instances where the
// static part lets light through.
fn plan_visibility(light: u32, seg: RaySegment, p: vec3<f32>, ng: vec3<f32>, dist: f32, receiver_moves: bool) -> VisibilityPlan {
    var plan = VisibilityPlan(CACHE_NONE, 0.0, INSTANCES_ALL);
    if params.shadow_cache != 0u && !receiver_moves && !light_dynamic(light) {
        plan.slot = cache_slot(light, p, ng, dist);
    }
    if plan.slot != CACHE_NONE {
        let filled = cache_word(slot_word(plan.slot, SLOT_FILLED));
        if filled != 0u {
            plan.vis = f32(filled & 0xffffu) / f32(filled >> 16u);
            plan.instances = next_traversal(plan.vis, seg);
        } else {
            // Filling: this ray's own static visibility, added to the cell.
            plan.instances = INSTANCES_STATIC;
        }
    }
    return plan;
}

// After the static visibility `vis` (cached or just traced): a ray against the moving instances
// where light got through and moving instances may be in the way, else nothing.
fn next_traversal(vis: f32, seg: RaySegment) -> u32 {
    if vis <= 0.0 || params.dynamic_count == 0u || !enters_dynamic(seg) {
        return NO_TRACE;
    }
    return INSTANCES_DYNAMIC;
}

// The plan's traversals, counted in `rays`, and the visibility. They share one call site, in a
// loop of at most two steps: drivers inline every call, and a call site per case made nine
// copies of the BVH traversal in the shadow pass.
fn finish_visibility(plan: VisibilityPlan, seg: RaySegment, rays: ptr<function, u32>) -> f32 {
    var vis = plan.vis;
    var instances = plan.instances;
    for (var step = 0u; step < 2u; step++) {
        if instances == NO_TRACE {
            break;
        }
        *rays += 1u;
        let open = !occluded_filtered(seg, instances);
        if instances == INSTANCES_ALL {
            return select(0.0, 1.0, open);
        }
        if instances == INSTANCES_DYNAMIC {
            return select(0.0, vis, open);
        }
        atomicAdd(&shadow_cache[slot_word(plan.slot, SLOT_VALUE)], 0x10000u | u32(open));
        vis = f32(open);
        instances = next_traversal(vis, seg);
    }
    return vis;
}

fn split_visibility(light: u32, seg: RaySegment, p: vec3<f32>, ng: vec3<f32>, dist: f32, receiver_moves: bool, rays: ptr<function, u32>) -> f32 {
    return finish_visibility(plan_visibility(light, seg, p, ng, dist, receiver_moves), seg, rays);
}

// A plan in two words for workgroup memory: the slot (a static fill's) or the cached
// visibility (a moving-only ray's), and the traversal.
fn pack_plan(plan: VisibilityPlan) -> vec2<u32> {
    return vec2<u32>(select(plan.slot, bitcast<u32>(plan.vis), plan.instances == INSTANCES_DYNAMIC), plan.instances);
}

fn unpack_plan(v: vec2<u32>) -> VisibilityPlan {
    let dynamic = v.y == INSTANCES_DYNAMIC;
    return VisibilityPlan(select(v.x, CACHE_NONE, dynamic), select(0.0, bitcast<f32>(v.x), dynamic), v.y);
}
