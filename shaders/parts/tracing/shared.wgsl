// Scene tracing, the part every family that traces Lumen's scene representation binds (Lumen
// itself, the surface cache's card texels and probes, the world radiance cache): the global
// signed distance field of Lumen's seed (shared/seeds/000: camera-centred clipmaps of sparse
// 8^3 bricks plus a quarter-resolution coarse volume, its voxel lighting), tracing through it or
// through the BVH (`trace_scene`, mode by FLAG_BVH), and the lighting at a hit (the surface
// cache's cards, src/parts/surface_cache/). Bind group 2, bindings 0 (the uniform) and 4-11
// (the distance field); layout in src/parts/tracing.rs. Lumen builds and fills the distance
// field (its sdf_* and voxel_* passes); a holder without one binds BVH mode only.
#define_import_path gilab::tracing

#import gilab::math::{PI, INV_PI}
#import gilab::scene::{materials, tri_geom, tri_material, scene_triangle, material_at}
#import gilab::bvh::{trace_closest, NO_HIT, INSTANCE_LEAF, instance_at, to_object_vector}
#import gilab::scene::{bvh_nodes, bvh_node, tri_geom_at}
#import gilab::ray::{offset_point, unoccluded, INFINITE_DISTANCE}
#import gilab::lights::{LightSample, light_shadow_ray}
#import gilab::surface_cache::{cards, object_cards, tri_object, atlas_direct, atlas_indirect, atlas_albedo, atlas_normal, atlas_emissive, atlas_depth, CacheSample, sample_cache, cache_radiance, cache_reflected}
#import gilab::toroidal::wrap_grid
#import gilab::texels::wide_texel

const MAX_LEVELS: u32 = 6u;
const BRICK: u32 = 8u;
// BRICK = 1 << BRICK_SHIFT: a voxel's brick by an arithmetic shift (floor division for negatives).
const BRICK_SHIFT: u32 = 3u;
const BRICK_VOXELS: u32 = 512u;
// Narrow band: bricks hold distances within +-BAND voxels of their level (the seed's [-4, 4]).
const BAND: f32 = 4.0;
const EMPTY: u32 = 0xffffffffu;
const NO_OBJECT: u32 = 0xffffu;
// Half a voxel's diagonal: the seed's expand against leaks through thin surfaces.
const EXPAND_VOXELS: f32 = 0.8660254;
// Expand grows with the distance travelled (so a ray can leave its own surface), at this slope.
const EXPAND_SLOPE: f32 = 0.5;
// Rays start this many voxels (of the finest level holding the origin) off their surface.
const SURFACE_BIAS_VOXELS: f32 = 1.0;
const HIT_VOXELS: f32 = 0.05;
const MIN_STEP_VOXELS: f32 = 0.125;
const MAX_STEPS: u32 = 256u;

// Flags of `params.flags` this module reads (src/parts/tracing.rs); the holder's own flags
// take the other bits (Lumen's: shaders/lumen/shared.wgsl).
const FLAG_BVH: u32 = 1u;
const FLAG_SKY: u32 = 2u;
const FLAG_LIGHTS: u32 = 16u;
const FLAG_VOXEL_LIGHTING: u32 = 128u;

struct Level {
    // xyz: world position of the level's minimum corner, w: voxel size.
    origin: vec4<f32>,
    // xyz: brick coordinate of the minimum corner (origin / (8 voxels)), w: 1 if built.
    brick_origin: vec4<i32>,
    // x: 1 if this frame updates the level (scrolled, edited or first build), y: 1 if every brick
    // of it is rebuilt.
    update: vec4<u32>,
}

// The tracing uniform; its holder's fields follow the distance field's (Lumen's gather).
struct TracingParams {
    levels: array<Level, 6>,
    resolution: u32,
    levels_built: u32,
    bricks_per_axis: u32,
    pool_bricks: u32,
    flags: u32,
    rays_per_pixel: u32,
    gather_downsample: u32,
    gather_width: u32,
    gather_height: u32,
    dirty_box_count: u32,
    sign_rays: u32,
    query_count: u32,
    slice_depth: f32,
    query_mode: u32,
    pad_a: u32,
    pad_b: u32,
}

@group(2) @binding(0) var<uniform> params: TracingParams;
// Bindings 1-3 (cards, object_cards, tri_object), 12-15 (atlas lighting, cache probes, tiles),
// 19-22 (atlas textures) and 23 (its uniform) are the surface cache part's (src/parts/
// surface_cache/): its lookup in shaders/parts/surface_cache/shared.wgsl, at group 2 here
// (SURFACE_CACHE_GROUP's default), its passes' in shaders/parts/surface_cache/lighting.wgsl.
// Per level and brick slot (toroidal): pool index or EMPTY.
@group(2) @binding(4) var<storage, read_write> brick_table: array<u32>;
// Per level and brick slot: the brick coordinate it holds (w: 1 once built).
@group(2) @binding(5) var<storage, read_write> brick_coord: array<vec4<i32>>;
// Brick pool: 512 voxels per brick; low 16 bits signed distance / band, high 16 bits object.
// Behind the distances, the voxel lighting's two regions of VOXEL_WORDS per brick (visibility,
// then radiance: `voxel_word_index`), in this buffer because the final gather's passes are at
// the 32 storage buffers a stage may bind.
@group(2) @binding(6) var<storage, read_write> brick_pool: array<u32>;
// Per level, quarter resolution: unsigned distance at coarse voxel centres.
@group(2) @binding(7) var<storage, read_write> coarse: array<f32>;
// Free pool bricks; sdf_state[0] counts them.
@group(2) @binding(8) var<storage, read_write> free_stack: array<u32>;
// [0] free count, [2] failed allocations (this update), [3] pops (this update), [4 + l] bricks
// of level l to fill, [STATE_LIT] bricks held (the voxel lighting's list).
@group(2) @binding(9) var<storage, read_write> sdf_state: array<atomic<u32>, 16>;
// Per level its bricks to fill, then the slots holding a brick (`lit_list_index`).
@group(2) @binding(10) var<storage, read_write> fill_list: array<u32>;
const STATE_LIT: u32 = 10u;
// Workgroups per row of a long indirect dispatch.
const MAX_GROUPS: u32 = 65535u;

fn lit_list_index(k: u32) -> u32 {
    return arrayLength(&fill_list) / 2u + k;
}
// Scene edits: world boxes (min, max) whose bricks are rebuilt.
@group(2) @binding(11) var<storage, read> dirty_boxes: array<vec4<f32>>;
// The same words as bindings 4, 5, 6 (its distances) and 7, as texels (src/parts/tracing.rs
// DistanceFieldTexels), copied at the end of each update: every SDF step reads up to ten of
// them, and lavapipe reads a texel in half the time of a storage-buffer word (a vec4 in a
// seventh). The update's own passes read the buffers (`written`), which the copy follows.
@group(2) @binding(27) var brick_table_texels: texture_2d<u32>;
@group(2) @binding(28) var brick_coord_texels: texture_2d<i32>;
@group(2) @binding(29) var brick_pool_texels: texture_2d<u32>;
@group(2) @binding(30) var coarse_texels: texture_2d<f32>;

fn has_flag(f: u32) -> bool {
    return (params.flags & f) != 0u;
}

// ---------------------------------------------------------------------------------------------
// Global distance field.

fn level_voxel(l: u32) -> f32 {
    return params.levels[l].origin.w;
}

fn level_min(l: u32) -> vec3<f32> {
    return params.levels[l].origin.xyz;
}

fn level_max(l: u32) -> vec3<f32> {
    return params.levels[l].origin.xyz + f32(params.resolution) * level_voxel(l);
}

fn inside_level(l: u32, p: vec3<f32>, margin: f32) -> bool {
    return all(p > level_min(l) + margin) && all(p < level_max(l) - margin);
}

// The finest built level that holds p (levels_built when none does).
fn finest_level(p: vec3<f32>) -> u32 {
    for (var l = 0u; l < params.levels_built; l++) {
        if inside_level(l, p, level_voxel(l)) {
            return l;
        }
    }
    return params.levels_built;
}

fn floor_div(v: vec3<i32>, d: i32) -> vec3<i32> {
    return vec3<i32>(floor(vec3<f32>(v) / f32(d)));
}

// Index into brick_table / brick_coord of brick `b` (world brick coordinates) of level l.
fn brick_slot(l: u32, b: vec3<i32>) -> u32 {
    let n = i32(params.bricks_per_axis);
    let s = wrap_grid(b, vec3<i32>(n));
    return l * params.bricks_per_axis * params.bricks_per_axis * params.bricks_per_axis + u32(s.x + n * (s.y + n * s.z));
}

// Where brick `b` (world brick coordinates) of level l starts in brick_pool, or EMPTY where no
// brick is stored for it; from the texels, or with `written` from the buffers.
fn brick_base(l: u32, b: vec3<i32>, written: bool) -> u32 {
    let slot = brick_slot(l, b);
    var held: vec4<i32>;
    var entry: u32;
    if written {
        held = brick_coord[slot];
        entry = brick_table[slot];
    } else {
        held = textureLoad(brick_coord_texels, wide_texel(slot), 0);
        entry = textureLoad(brick_table_texels, wide_texel(slot), 0).x;
    }
    if entry == EMPTY || held.w == 0 || any(held.xyz != b) {
        return EMPTY;
    }
    return entry * BRICK_VOXELS;
}

// The word of world voxel v in the brick `b` that holds it, whose pool start is `base`.
fn brick_word(base: u32, b: vec3<i32>, v: vec3<i32>, written: bool) -> u32 {
    if base == EMPTY {
        return EMPTY;
    }
    let local = vec3<u32>(v - b * i32(BRICK));
    let i = base + local.x + BRICK * (local.y + BRICK * local.z);
    if written {
        return brick_pool[i];
    }
    return textureLoad(brick_pool_texels, wide_texel(i), 0).x;
}

// The stored voxel word of world voxel v of level l, or EMPTY where no brick holds it.
fn voxel_word(l: u32, v: vec3<i32>) -> u32 {
    let b = floor_div(v, i32(BRICK));
    return brick_word(brick_base(l, b, false), b, v, false);
}

fn encode_voxel(dist_in_band: f32, object: u32) -> u32 {
    let q = u32(round(clamp(dist_in_band, -1.0, 1.0) * 32767.0 + 32768.0));
    return q | (min(object, NO_OBJECT) << 16u);
}

fn decode_distance(word: u32) -> f32 {
    return (f32(word & 0xffffu) - 32768.0) / 32767.0;
}

fn decode_object(word: u32) -> u32 {
    return word >> 16u;
}

fn coarse_cells() -> u32 {
    return params.resolution / 4u;
}

// Lower bound on the distance to the nearest surface from the coarse volume (its value at the
// nearest coarse centre minus the distance to that centre), or -1 outside the level.
fn coarse_bound(l: u32, p: vec3<f32>, written: bool) -> f32 {
    let n = coarse_cells();
    let cell = 4.0 * level_voxel(l);
    let c = vec3<i32>(floor((p - level_min(l)) / cell));
    if any(c < vec3<i32>(0)) || any(c >= vec3<i32>(i32(n))) {
        return -1.0;
    }
    let idx = l * n * n * n + u32(c.x) + n * (u32(c.y) + n * u32(c.z));
    let centre = level_min(l) + (vec3<f32>(c) + 0.5) * cell;
    var d: f32;
    if written {
        d = coarse[idx];
    } else {
        d = textureLoad(coarse_texels, wide_texel(idx), 0).x;
    }
    return d - length(p - centre);
}

// Trilinear distance from the bricks of level l. The eight taps mostly lie in one brick, so a
// brick's table entry is looked up when a tap enters it, not once per tap: this is the inner
// loop of every distance-field ray. A tap's distance (world units) is its voxel centre's,
// `BAND` voxels where no brick is stored.
fn brick_distance(l: u32, p: vec3<f32>, written: bool) -> f32 {
    let f = p / level_voxel(l) - 0.5;
    let i0 = vec3<i32>(floor(f));
    let t = f - floor(f);
    let band = BAND * level_voxel(l);
    var d = 0.0;
    // No brick is this far out: the first tap looks its brick up.
    var brick = vec3<i32>(-0x7fffffff);
    var base = EMPTY;
    for (var k = 0u; k < 8u; k++) {
        let o = vec3<i32>(i32(k & 1u), i32((k >> 1u) & 1u), i32((k >> 2u) & 1u));
        let w = select(1.0 - t, t, vec3<bool>(o == vec3<i32>(1)));
        let v = i0 + o;
        let b = v >> vec3<u32>(BRICK_SHIFT);
        if any(b != brick) {
            brick = b;
            base = brick_base(l, b, written);
        }
        let word = brick_word(base, b, v, written);
        d += w.x * w.y * w.z * select(decode_distance(word) * band, band, word == EMPTY);
    }
    return d;
}

// Signed distance at p from level l: the coarse volume far from surfaces (empty-space
// skipping), the narrow-band bricks near them.
fn sdf_distance(l: u32, p: vec3<f32>) -> f32 {
    return sdf_distance_from(l, p, false);
}

// The same from the buffers, for a pass of the update itself (before the texels are copied).
fn sdf_distance_written(l: u32, p: vec3<f32>) -> f32 {
    return sdf_distance_from(l, p, true);
}

fn sdf_distance_from(l: u32, p: vec3<f32>, written: bool) -> f32 {
    let bound = coarse_bound(l, p, written);
    let band = BAND * level_voxel(l);
    if bound > band {
        return bound;
    }
    return brick_distance(l, p, written);
}

// Object id stored at the voxel nearest p.
fn sdf_object(l: u32, p: vec3<f32>) -> u32 {
    let w = voxel_word(l, vec3<i32>(floor(p / level_voxel(l))));
    return select(decode_object(w), NO_OBJECT, w == EMPTY);
}

// Gradient by central differences, 6 taps at +-half a voxel (the seed's hit normal).
fn sdf_normal(l: u32, p: vec3<f32>) -> vec3<f32> {
    let h = 0.5 * level_voxel(l);
    let g = vec3<f32>(
        sdf_distance(l, p + vec3<f32>(h, 0.0, 0.0)) - sdf_distance(l, p - vec3<f32>(h, 0.0, 0.0)),
        sdf_distance(l, p + vec3<f32>(0.0, h, 0.0)) - sdf_distance(l, p - vec3<f32>(0.0, h, 0.0)),
        sdf_distance(l, p + vec3<f32>(0.0, 0.0, h)) - sdf_distance(l, p - vec3<f32>(0.0, 0.0, h)),
    );
    let len = length(g);
    return select(vec3<f32>(0.0, 1.0, 0.0), g / len, len > 1e-12);
}

// Distance at p from the finest level holding it (queries, debug slice); 1e30 outside all.
fn sdf_sample(p: vec3<f32>) -> f32 {
    let l = finest_level(p);
    if l >= params.levels_built {
        return 1e30;
    }
    return sdf_distance(l, p);
}

fn ray_box_exit(o: vec3<f32>, d: vec3<f32>, lo: vec3<f32>, hi: vec3<f32>) -> f32 {
    let inv = 1.0 / select(d, vec3<f32>(1e-20), abs(d) < vec3<f32>(1e-20));
    let t0 = (lo - o) * inv;
    let t1 = (hi - o) * inv;
    let tmax = max(t0, t1);
    return min(tmax.x, min(tmax.y, tmax.z));
}

struct SdfHit {
    hit: bool,
    t: f32,
    level: u32,
    steps: u32,
}

// Sphere tracing through the clipmaps from the finest to the coarsest: each level is marched
// while the ray is inside it, then the next level continues from where it left. The surface is
// expanded by up to half a voxel diagonal (thin walls between voxel centres still stop rays),
// growing from 0 at the origin; `shadow` rays fade the expand out again before t_max so the
// surface a light sits on does not occlude it. Hitting the iteration cap counts as a hit.
// `expand_on` false traces the bare field (queries that measure its accuracy). `travelled` is
// how far the ray came before o (a continued ray keeps its full expand: restarting it from 0 let
// continued probe rays pass thin walls, 3% of Cornell's light).
fn sdf_trace(o: vec3<f32>, d: vec3<f32>, t_max: f32, shadow: bool, expand_on: bool, travelled: f32) -> SdfHit {
    var t = 0.0;
    var steps = 0u;
    for (var l = 0u; l < params.levels_built; l++) {
        let voxel = level_voxel(l);
        if !inside_level(l, o + d * t, 0.5 * voxel) {
            continue;
        }
        let t_exit = min(ray_box_exit(o, d, level_min(l) + 0.5 * voxel, level_max(l) - 0.5 * voxel), t_max);
        while t < t_exit {
            if steps >= MAX_STEPS {
                return SdfHit(true, t, l, steps);
            }
            steps++;
            let p = o + d * t;
            let dist = sdf_distance(l, p);
            var expand = select(0.0, min(EXPAND_VOXELS * voxel, EXPAND_SLOPE * (t + travelled)), expand_on);
            if shadow {
                expand = min(expand, EXPAND_SLOPE * max(t_max - t, 0.0));
            }
            if dist - expand < HIT_VOXELS * voxel {
                return SdfHit(true, t, l, steps);
            }
            t += max(dist - expand, MIN_STEP_VOXELS * voxel);
        }
        if t >= t_max {
            break;
        }
    }
    return SdfHit(false, t_max, params.levels_built, steps);
}

// ---------------------------------------------------------------------------------------------
// One query for both `tracing` modes: the SDF (software) or the BVH's triangles (hardware).

struct TraceHit {
    hit: bool,
    t: f32,
    position: vec3<f32>,
    // Facing the ray.
    normal: vec3<f32>,
    object: u32,
    // The ray met the back of a single-sided surface (it started inside geometry): no light.
    back_face: bool,
    steps: u32,
    // Voxel size of the level that found the hit (SDF mode), 0 for BVH hits: how far the
    // position may be off the surface.
    voxel: f32,
    // That level (SDF mode): where the voxel lighting is read.
    level: u32,
    // The ray's direction.
    dir: vec3<f32>,
}

// The world size of the surface bias at p: SURFACE_BIAS_VOXELS of the finest level holding it.
fn sdf_bias(p: vec3<f32>) -> f32 {
    let l = finest_level(p);
    return SURFACE_BIAS_VOXELS * level_voxel(min(l, max(params.levels_built, 1u) - 1u));
}

fn trace_sdf_mode(p: vec3<f32>, n_geo: vec3<f32>, d: vec3<f32>, t_max: f32, shadow: bool, travelled: f32) -> TraceHit {
    let side = select(-n_geo, n_geo, dot(n_geo, d) >= 0.0);
    let bias = sdf_bias(p);
    var o = p + side * bias;
    // In a concave corner the offset origin is still within a voxel of the second surface, and
    // the march would stop there at once: push it out along the field's gradient until it is a
    // bias away from everything (two steps).
    for (var k = 0u; k < 2u; k++) {
        let l = finest_level(o);
        if l >= params.levels_built {
            break;
        }
        let dist = sdf_distance(l, o);
        if dist >= 0.9 * bias {
            break;
        }
        o += sdf_normal(l, o) * (bias - dist);
    }
    let h = sdf_trace(o, d, t_max, shadow, true, travelled);
    if !h.hit {
        return TraceHit(false, t_max, vec3<f32>(0.0), vec3<f32>(0.0), NO_OBJECT, false, h.steps, 0.0, 0u, d);
    }
    // The march stops up to an expand (under a voxel) short of the surface; the cache lookup's
    // depth tolerance covers that. Stepping on to the surface was tried: it moves thin-wall hits
    // onto the sunlit side's object and multiplies the leak by four (README, Known gaps).
    let pos = o + d * h.t;
    let l = surface_level(pos, h.level);
    let g = sdf_normal(l, pos);
    let back = dot(g, d) > 0.0;
    return TraceHit(true, h.t, pos, select(g, -g, back), sdf_object(l, pos), back, h.steps, level_voxel(l), l, d);
}

// The level to read a hit's surface from: `first` or the next coarser one that holds p with room
// for the gradient's taps (a march may stop at a level's edge, where the neighbours are not stored).
fn surface_level(p: vec3<f32>, first: u32) -> u32 {
    for (var l = first; l + 1u < params.levels_built; l++) {
        if inside_level(l, p, 2.0 * level_voxel(l)) {
            return l;
        }
    }
    return max(params.levels_built, 1u) - 1u;
}

fn trace_bvh_mode(p: vec3<f32>, n_geo: vec3<f32>, d: vec3<f32>, t_max: f32) -> TraceHit {
    let o = offset_point(p, n_geo, d);
    let h = trace_closest(o, d, 0.0, t_max);
    if h.tri == NO_HIT {
        return TraceHit(false, t_max, vec3<f32>(0.0), vec3<f32>(0.0), NO_OBJECT, false, 0u, 0.0, 0u, d);
    }
    let g = hit_geometric_normal(h.tri);
    let front = dot(g, d) < 0.0;
    let double_sided = material_at(tri_material(h.tri)).emissive.w > 0.5;
    let object = tri_object[scene_triangle(h.tri)];
    return TraceHit(true, h.t, o + d * h.t, select(-g, g, front), object, !front && !double_sided, 0u, 0.0, 0u, d);
}

fn hit_geometric_normal(tri: u32) -> vec3<f32> {
    let g = tri_geom[tri];
    return normalize(cross(g.edge_b.xyz, g.edge_c.xyz));
}

// Closest hit with the technique's `tracing` mode, from surface point p (geometric normal n_geo).
fn trace_scene(p: vec3<f32>, n_geo: vec3<f32>, d: vec3<f32>, t_max: f32) -> TraceHit {
    return trace_scene_on(p, n_geo, d, t_max, 0.0);
}

// A ray continued from p after `travelled` in free space (screen traces, cache steps).
fn trace_scene_on(p: vec3<f32>, n_geo: vec3<f32>, d: vec3<f32>, t_max: f32, travelled: f32) -> TraceHit {
    if has_flag(FLAG_BVH) {
        return trace_bvh_mode(p, n_geo, d, t_max);
    }
    return trace_sdf_mode(p, n_geo, d, t_max, false, travelled);
}

// ---------------------------------------------------------------------------------------------
// The surface cache at traced hits (its sampling, the seed's "Card Sampling", is the part's:
// shaders/parts/surface_cache/shared.wgsl).

// Radiance a traced ray brings back: the cache's reflected light at a hit (nothing from the back
// of a surface or where neither a card nor the voxel lighting covers it), the sky on a miss.
fn hit_radiance(h: TraceHit, sky: vec3<f32>) -> vec3<f32> {
    if !h.hit {
        return select(vec3<f32>(0.0), sky, has_flag(FLAG_SKY));
    }
    return hit_light(h).xyz;
}

// Reflected light only (emitters are in the light pool, so light leaving them directly is
// already counted by next-event estimation where the ray started) at a hit: w 1 where the
// hit's cards answered, 2 where the voxel lighting did, 0 where neither (that energy is lost).
fn hit_light(h: TraceHit) -> vec4<f32> {
    let voxels = !has_flag(FLAG_BVH) && has_flag(FLAG_VOXEL_LIGHTING);
    if h.back_face && !voxels {
        return vec4<f32>(0.0);
    }
    if !h.back_face {
        let s = hit_cache_sample(h);
        if s.weight > 1e-4 {
            return vec4<f32>(cache_reflected(s), 1.0);
        }
    }
    // The seed's answer for global-SDF hits: the cards merged per voxel. A march that stopped
    // with the field's gradient along the ray (grazing an edge within the expand, or starting
    // in a concave corner) has no surface normal to trust; the seed shades it too, here with
    // the surfaces that face the ray.
    if voxels {
        let n = select(h.normal, -h.dir, h.back_face);
        let v = voxel_lighting(h.position, n, h.level, h.object);
        if v.w > 0.0 {
            return vec4<f32>(v.xyz, 2.0);
        }
    }
    return vec4<f32>(0.0);
}

// The surface cache at a traced hit, with the depth tolerance of the mode that traced it (a BVH
// hit has no voxel: it is exact).
fn hit_cache_sample(h: TraceHit) -> CacheSample {
    let tol = select(2.5 * h.voxel, 1e-3 * max(h.t, 1.0), h.voxel == 0.0);
    return sample_cache(h.position, h.normal, h.object, tol);
}

// ---------------------------------------------------------------------------------------------
// Voxel lighting (the seed's "Voxel Lighting"): the cards merged into the distance field's
// clipmaps at half its resolution (4^3 lighting voxels per 8^3 brick, so they live in the
// brick's pool slot), per voxel the radiance leaving its surfaces along each of the 6 axis
// directions. `voxel_visibility` traces, when a brick is (re)built, BVH rays per voxel and
// direction across the voxel (the seed's visibility buffer: the surface seen and its distance);
// `voxel_lighting` shades those hits from the cards facing that direction every frame.

const LIGHT_BRICK: u32 = 4u;
const VOXEL_DIRS: u32 = 6u;
// Words per brick in each of the two regions: 64 voxels x 6 directions.
const VOXEL_WORDS: u32 = 384u;

// Side of level l's lighting voxels.
fn lighting_voxel_size(l: u32) -> f32 {
    return f32(BRICK / LIGHT_BRICK) * level_voxel(l);
}

// Centre of lighting voxel `local` (0..64) of brick b, voxels of side `size`.
fn lighting_voxel_centre(b: vec3<i32>, local: u32, size: f32) -> vec3<f32> {
    let v = vec3<u32>(local % LIGHT_BRICK, (local / LIGHT_BRICK) % LIGHT_BRICK, local / (LIGHT_BRICK * LIGHT_BRICK));
    return (vec3<f32>(b * i32(LIGHT_BRICK) + vec3<i32>(v)) + 0.5) * size;
}

// Index in brick_pool of direction k of lighting voxel `local` (0..64) of pool brick `entry`,
// in region 0 (visibility: object | distance across the voxel << 16) or 1 (radiance, RGB9E5);
// EMPTY where no surface faces that way.
fn voxel_word_index(region: u32, entry: u32, local: u32, k: u32) -> u32 {
    return params.pool_bricks * (BRICK_VOXELS + region * VOXEL_WORDS) + entry * VOXEL_WORDS + local * VOXEL_DIRS + k;
}

// Unit vector of direction k, numbered as card sides: 0 +x, 1 -x, 2 +y, 3 -y, 4 +z, 5 -z.
fn voxel_dir(k: u32) -> vec3<f32> {
    var d = vec3<f32>(0.0);
    d[k / 2u] = select(1.0, -1.0, (k & 1u) == 1u);
    return d;
}

// Visibility rays run on this share of a voxel past its far face: a wall on a voxel boundary
// (the Cornell box's, at whole clipmap coordinates) ends the rays exactly, where they missed it.
// They start on the near face: starting outside, the back of a single-sided wall there stopped
// them before the voxel.
const VOXEL_RAY_MARGIN: f32 = 0.05;

// Start and length of the visibility rays of direction k of the voxel at `centre` (side
// `size`): from the face k points out of, travelling -voxel_dir(k).
fn voxel_ray_start(centre: vec3<f32>, size: f32, k: u32) -> vec3<f32> {
    return centre + 0.5 * size * voxel_dir(k);
}

fn voxel_ray_length(size: f32) -> f32 {
    return (1.0 + VOXEL_RAY_MARGIN) * size;
}

// A visibility word: the object met (16 bits) and the distance along the ray (16 bits).
fn encode_seen(object: u32, t: f32, size: f32) -> u32 {
    let q = u32(round(clamp(t / voxel_ray_length(size), 0.0, 1.0) * 65535.0));
    return min(object, 0xffffu) | (q << 16u);
}

// The surface point a visibility word of direction k saw.
fn seen_point(centre: vec3<f32>, size: f32, k: u32, word: u32) -> vec3<f32> {
    let t = f32(word >> 16u) / 65535.0 * voxel_ray_length(size);
    return voxel_ray_start(centre, size, k) - t * voxel_dir(k);
}

// Shared-exponent RGB (9-bit mantissas, 5-bit exponent): one word per voxel and direction;
// never all ones, so EMPTY stays free.
fn pack_rgb9e5(c: vec3<f32>) -> u32 {
    let m = clamp(c, vec3<f32>(0.0), vec3<f32>(65000.0));
    let top = max(m.x, max(m.y, m.z));
    var e = clamp(i32(floor(log2(max(top, 1e-30)))) + 1, -15, 16);
    var q = vec3<u32>(round(m * exp2(f32(9 - e))));
    if any(q > vec3<u32>(511u)) {
        e = min(e + 1, 16);
        q = min(vec3<u32>(round(m * exp2(f32(9 - e)))), vec3<u32>(511u));
    }
    return q.x | (q.y << 9u) | (q.z << 18u) | (u32(e + 15) << 27u);
}

fn unpack_rgb9e5(w: u32) -> vec3<f32> {
    let e = i32(w >> 27u) - 15;
    let q = vec3<u32>(w & 511u, (w >> 9u) & 511u, (w >> 18u) & 511u);
    return vec3<f32>(q) * exp2(f32(e - 9));
}

// Radiance leaving the surfaces near p towards normal n, from the lighting voxels of level
// `first` (or the next coarser, where it holds none): the 8 nearest voxels, trilinear, each
// mixing the 3 directions n faces by n^2; directions with no surface drop out and the rest are
// renormalised (the seed's alpha weights). Surfaces of `object` (the field's object at the
// hit) are preferred where any is found: a voxel straddling a thin wall also holds the other
// side's surfaces, and mixing them in leaked the sunlit ground into thin-wall's closed room
// (interior 0.030 without voxel lighting, 0.044 mixing all objects, 0.034 preferring the hit's;
// 64^3, screen probes). w: the weight found (0: nothing there).
fn voxel_lighting(p: vec3<f32>, n: vec3<f32>, first: u32, object: u32) -> vec4<f32> {
    for (var l = first; l < min(first + 2u, params.levels_built); l++) {
        let size = lighting_voxel_size(l);
        let f = p / size - 0.5;
        let i0 = vec3<i32>(floor(f));
        let t = f - floor(f);
        // Any surface, then those of `object`.
        var sum = array<vec3<f32>, 2>(vec3<f32>(0.0), vec3<f32>(0.0));
        var weight = vec2<f32>(0.0);
        for (var c = 0u; c < 8u; c++) {
            let o = vec3<i32>(i32(c & 1u), i32((c >> 1u) & 1u), i32((c >> 2u) & 1u));
            let v = i0 + o;
            let b = floor_div(v, i32(LIGHT_BRICK));
            let slot = brick_slot(l, b);
            let held = brick_coord[slot];
            let entry = brick_table[slot];
            if entry == EMPTY || held.w == 0 || any(held.xyz != b) {
                continue;
            }
            let lv = vec3<u32>(v - b * i32(LIGHT_BRICK));
            let local = lv.x + LIGHT_BRICK * (lv.y + LIGHT_BRICK * lv.z);
            let tw = select(1.0 - t, t, vec3<bool>(o == vec3<i32>(1)));
            let trilinear = tw.x * tw.y * tw.z;
            for (var a = 0u; a < 3u; a++) {
                let na = n[a] * n[a];
                if na < 1e-4 {
                    continue;
                }
                let k = 2u * a + select(0u, 1u, n[a] < 0.0);
                let word = brick_pool[voxel_word_index(1u, entry, local, k)];
                if word == EMPTY {
                    continue;
                }
                let own = (brick_pool[voxel_word_index(0u, entry, local, k)] & 0xffffu) == object;
                let radiance = unpack_rgb9e5(word);
                let w = trilinear * na;
                sum[0] += w * radiance;
                weight[0] += w;
                if own {
                    sum[1] += w * radiance;
                    weight[1] += w;
                }
            }
        }
        let pick = select(0u, 1u, weight[1] > 1e-4);
        if weight[pick] > 1e-4 {
            return vec4<f32>(sum[pick] / weight[pick], weight[pick]);
        }
    }
    return vec4<f32>(0.0);
}

// ---------------------------------------------------------------------------------------------
// Building the distance field: closest triangle through the BVH (a point query).

// Closest point to p on triangle tri (Ericson, Real-Time Collision Detection 5.1.5).
fn closest_point_on_triangle(p: vec3<f32>, tri: u32) -> vec3<f32> {
    let g = tri_geom_at(tri);
    let a = g.vertex_a.xyz;
    let ab = g.edge_b.xyz;
    let ac = g.edge_c.xyz;
    let ap = p - a;
    let d1 = dot(ab, ap);
    let d2 = dot(ac, ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = ap - ab;
    let d3 = dot(ab, bp);
    let d4 = dot(ac, bp);
    if d3 >= 0.0 && d4 <= d3 {
        return a + ab;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = ap - ac;
    let d5 = dot(ab, cp);
    let d6 = dot(ac, cp);
    if d6 >= 0.0 && d5 <= d6 {
        return a + ac;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let bc = ac - ab;
        return a + ab + bc * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    return a + ab * (vb * denom) + ac * (vc * denom);
}

struct Closest {
    dist: f32,
    // BVH-order triangle, NO_HIT when nothing lies within the search radius.
    tri: u32,
}

// The nearest triangle within `radius` of p: the stackless BVH walk with nodes farther than the
// best distance so far skipped. With INSTANCES (a two-level BVH) an instance's tree is walked
// with p in its object space, its boxes' distances scaled to a lower bound of the world
// distance (`distance_scale`); triangle distances are world distances to the flattened
// world-space triangles, as with a flat tree.
fn closest_triangle(p: vec3<f32>, radius: f32) -> Closest {
    var best = Closest(radius, NO_HIT);
    let node_count = arrayLength(&bvh_nodes);
#ifdef INSTANCES
    var top_end = 0u;
    if node_count > 0u {
        top_end = bvh_node(0u).skip;
    }
    var q_p = p;
    var scale = 1.0;
    var end = top_end;
    var resume = 0u;
    var tri_base = 0u;
    var inside = false;
#else
    let q_p = p;
    let scale = 1.0;
    let end = node_count;
    let tri_base = 0u;
#endif
    var i = 0u;
    loop {
        if i >= end {
#ifdef INSTANCES
            if inside {
                i = resume;
                end = top_end;
                q_p = p;
                scale = 1.0;
                tri_base = 0u;
                inside = false;
                continue;
            }
#endif
            break;
        }
        let node = bvh_node(i);
        let q = clamp(q_p, node.bounds_min, node.bounds_max);
        if length(q - q_p) * scale >= best.dist {
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
            let inst = instance_at(node.tris >> 8u);
            q_p = to_object_vector(inst, p) + inst.translation;
            scale = inst.distance_scale;
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
            let d = length(closest_point_on_triangle(p, first + k) - p);
            if d < best.dist {
                best = Closest(d, first + k);
            }
        }
        i = node.skip;
    }
    return best;
}

// The brick coordinate slot s of level l should hold for the level's current origin.
fn wanted_brick(l: u32, slot: u32) -> vec3<i32> {
    let n = params.bricks_per_axis;
    let local = slot - l * n * n * n;
    let s = vec3<i32>(vec3<u32>(local % n, (local / n) % n, local / (n * n)));
    let bo = params.levels[l].brick_origin.xyz;
    return bo + wrap_grid(s - bo, vec3<i32>(i32(n)));
}

// Does a scene edit touch brick b of level l (its box grown by the band)?
fn brick_edited(l: u32, b: vec3<i32>) -> bool {
    let size = f32(BRICK) * level_voxel(l);
    let grow = BAND * level_voxel(l);
    let lo = vec3<f32>(b) * size - grow;
    let hi = vec3<f32>(b + 1) * size + grow;
    for (var k = 0u; k < params.dirty_box_count; k++) {
        let bmin = dirty_boxes[2u * k].xyz;
        let bmax = dirty_boxes[2u * k + 1u].xyz;
        if all(lo <= bmax) && all(hi >= bmin) {
            return true;
        }
    }
    return false;
}

// Visibility of a light sample from point p (geometric normal n) in the `tracing` mode.
fn light_visible(p: vec3<f32>, n: vec3<f32>, ls: LightSample) -> bool {
    if has_flag(FLAG_BVH) {
        return unoccluded(light_shadow_ray(p, n, ls));
    }
    // The light is geometry in the field too: stop a surface bias (at the light's end) short.
    let end = p + ls.wi * ls.dist;
    let t_max = select(max(ls.dist - 2.0 * sdf_bias(end), 0.0), 1e30, ls.dist >= INFINITE_DISTANCE);
    return !trace_sdf_mode(p, n, ls.wi, t_max, true, 0.0).hit;
}
