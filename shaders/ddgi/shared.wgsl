// DDGI (Majercik et al., JCGT 2019 and 2021; src/techniques/ddgi): the probe volume's data and
// its lookup. Probes sit on a uniform grid per cascade (cascade c's spacing is 2^c times the
// first's), in a volume that follows the camera inside the scene's bounds; each probe keeps an
// octahedral irradiance map (6 x 6 texels) and a map of the mean and mean square of the
// distance to the nearest surface (14 x 14), each with a one-texel border (8 x 8 and 16 x 16
// in all, the paper's sizes) that copies the
// octahedral wrap so that bilinear filtering needs no wrap logic. Probes are stored
// toroidally: the probe of world grid index g lives in slot g mod counts, so a volume that
// moves keeps every probe still inside it; a slot whose record names another g is new.
#define_import_path gilab::ddgi

#import gilab::math::{PI, TWO_PI, oct_encode, oct_decode}
#import gilab::toroidal::wrap_grid
#import gilab::texels::wide_texel

struct Cascade {
    // World position of grid index (0, 0, 0) (xyz), the probe spacing (w).
    origin_spacing: vec4<f32>,
    // World grid index of the volume's lowest probe.
    base: vec4<i32>,
}

struct DdgiParams {
    cascades: array<Cascade, 4>,
    // Probes per axis (xyz, the same for every cascade), cascades in use (w).
    counts: vec4<u32>,
    // This frame's random rotation of the probes' ray directions (rows).
    rot_x: vec4<f32>,
    rot_y: vec4<f32>,
    rot_z: vec4<f32>,
    // Rays per probe that update its maps (after FIXED_RAYS fixed ones).
    rays: u32,
    flags: u32,
    // Weight of the old maps (the paper's hysteresis, 0.97).
    hysteresis: f32,
    // Self-shadow bias of the lookup, in spacings (the paper's (0.2 n + 0.8 v) 0.75 spacing x bias).
    bias: f32,
    // Longest distance a distance texel holds, in spacings.
    max_distance: f32,
    // Relocation pushes a probe at least this far (in spacings) from the nearest front face.
    min_frontface: f32,
    pad_a: u32,
    pad_b: u32,
}

struct Probe {
    // World offset from its grid position (relocation; xyz) and its state (w: STATE_*).
    offset_state: vec4<f32>,
    // The world grid index the record belongs to (xyz) and the frames it has been blended (w).
    coord_frames: vec4<i32>,
}

@group(2) @binding(0) var<uniform> params: DdgiParams;
@group(2) @binding(1) var<storage, read_write> probes: array<Probe>;
// Per probe, FIXED_RAYS + params.rays results: radiance (xyz) and the hit distance (w; negative:
// a back face, at -0.2 x distance as the paper stores it; MISS_DISTANCE: no hit).
@group(2) @binding(2) var<storage, read_write> ray_results: array<vec4<f32>>;
// Per probe IRR_SIDE² texels of irradiance (xyz) and DIST_SIDE² of distance (mean, mean²).
@group(2) @binding(3) var<storage, read_write> irradiance_texels: array<vec4<f32>>;
@group(2) @binding(4) var<storage, read_write> distance_texels: array<vec2<f32>>;
// Per pixel, the debug views (src/techniques/ddgi).
@group(2) @binding(5) var<storage, read_write> debug_out: array<vec4<f32>>;
// Per pixel, the direct-light part's radiance (direct = "restir").
@group(2) @binding(6) var<storage, read_write> pixel_direct: array<vec4<f32>>;
// The probe records (two texels a probe: offset_state, then coord_frames, as words) and the
// irradiance and distance maps again as texels, copied after each blend (src/techniques/ddgi:
// Resources::texels): every gather reads 8 probes' records and bilinear footprints, and
// lavapipe reads a texel several times faster than a storage buffer. The blend reads and
// writes the buffers above; everything after it reads these.
@group(2) @binding(7) var probe_texels: texture_2d<u32>;
@group(2) @binding(8) var irradiance_map: texture_2d<f32>;
@group(2) @binding(9) var distance_map: texture_2d<f32>;

// A probe's record as the last blend left it.
fn probe_record(slot: u32) -> Probe {
    let a = textureLoad(probe_texels, wide_texel(2u * slot), 0);
    let b = textureLoad(probe_texels, wide_texel(2u * slot + 1u), 0);
    return Probe(bitcast<vec4<f32>>(a), bitcast<vec4<i32>>(b));
}

// Rays per probe with fixed directions (not rotated, never blended): relocation and
// classification read them; a switched-off probe traces only these (RTXGI's fixed rays).
const FIXED_RAYS: u32 = 32u;
const IRR_TEXELS: u32 = 6u;
const IRR_SIDE: u32 = 8u;
const DIST_TEXELS: u32 = 14u;
const DIST_SIDE: u32 = 16u;
const MISS_DISTANCE: f32 = 1e27;

const STATE_ACTIVE: f32 = 0.0;
const STATE_OFF: f32 = 1.0;

const FLAG_VISIBILITY: u32 = 1u;
const FLAG_RELOCATION: u32 = 2u;
const FLAG_CLASSIFICATION: u32 = 4u;
const FLAG_MULTI_BOUNCE: u32 = 8u;
const FLAG_ACCUMULATE: u32 = 16u;
const FLAG_DEBUG: u32 = 32u;
const FLAG_DIRECT_RESTIR: u32 = 64u;
// The debug buffer holds the gather's corner planes too (channels 4-23; shade.wgsl).
const FLAG_DEBUG_CORNERS: u32 = 128u;

fn has_flag(f: u32) -> bool {
    return (params.flags & f) != 0u;
}

fn probes_per_cascade() -> u32 {
    return params.counts.x * params.counts.y * params.counts.z;
}

fn rays_per_probe() -> u32 {
    return FIXED_RAYS + params.rays;
}

// The slot of the probe `local` steps above cascade c's lowest probe.
fn probe_slot(c: u32, local: vec3<i32>) -> u32 {
    let n = vec3<i32>(params.counts.xyz);
    let m = wrap_grid(params.cascades[c].base.xyz + local, n);
    return c * probes_per_cascade() + u32(m.x + n.x * (m.y + n.y * m.z));
}

// The world grid index (xyz) and cascade (w) a slot holds this frame.
fn slot_grid(slot: u32) -> vec4<i32> {
    let c = slot / probes_per_cascade();
    let r = slot % probes_per_cascade();
    let n = vec3<i32>(params.counts.xyz);
    let m = vec3<i32>(i32(r % params.counts.x), i32((r / params.counts.x) % params.counts.y), i32(r / (params.counts.x * params.counts.y)));
    let base = params.cascades[c].base.xyz;
    return vec4<i32>(base + wrap_grid(m - base, n), i32(c));
}

fn spacing(c: u32) -> f32 {
    return params.cascades[c].origin_spacing.w;
}

fn grid_position(c: u32, g: vec3<i32>) -> vec3<f32> {
    return params.cascades[c].origin_spacing.xyz + vec3<f32>(g) * spacing(c);
}

// Whether the record in `slot` belongs to the probe the slot holds now (not yet: the volume
// moved, and the slot's probe is new).
fn record_current(slot: u32, g: vec3<i32>) -> bool {
    return all(probe_record(slot).coord_frames.xyz == g);
}

// A probe's world position: its grid position plus its relocation offset.
fn probe_position(slot: u32) -> vec3<f32> {
    let g = slot_grid(slot);
    var p = grid_position(u32(g.w), g.xyz);
    if record_current(slot, g.xyz) {
        p += probe_record(slot).offset_state.xyz;
    }
    return p;
}

// Traces all its rays: on, or new (off: classified as inside a wall or away from every
// surface; it traces its fixed rays only).
fn probe_active(slot: u32) -> bool {
    let g = slot_grid(slot);
    return !record_current(slot, g.xyz) || probe_record(slot).offset_state.w == STATE_ACTIVE;
}

// Its maps may be read: on, and blended at least once since it was switched on (a new probe,
// or one switched on again, holds no data of its own yet).
fn probe_readable(slot: u32) -> bool {
    let g = slot_grid(slot);
    let r = probe_record(slot);
    return all(r.coord_frames.xyz == g.xyz) && r.offset_state.w == STATE_ACTIVE && r.coord_frames.w > 0;
}

// Direction i of n spread evenly over the sphere (spherical Fibonacci).
fn spherical_fibonacci(i: u32, n: u32) -> vec3<f32> {
    let phi = TWO_PI * fract(f32(i) * 0.618033988749895);
    let z = 1.0 - (2.0 * f32(i) + 1.0) / f32(n);
    let r = sqrt(max(1.0 - z * z, 0.0));
    return vec3<f32>(r * cos(phi), r * sin(phi), z);
}

// A probe ray's direction: the fixed set, then this frame's rotation of the blended set.
fn ray_direction(ray: u32) -> vec3<f32> {
    if ray < FIXED_RAYS {
        return spherical_fibonacci(ray, FIXED_RAYS);
    }
    let d = spherical_fibonacci(ray - FIXED_RAYS, params.rays);
    return vec3<f32>(dot(params.rot_x.xyz, d), dot(params.rot_y.xyz, d), dot(params.rot_z.xyz, d));
}

// The direction at the centre of interior texel t of a res x res octahedral map.
fn texel_direction(t: vec2<u32>, res: u32) -> vec3<f32> {
    return oct_decode((vec2<f32>(t) + 0.5) / f32(res) * 2.0 - 1.0);
}

// Bilinear footprint in a bordered map of `res` interior texels: the lower texel and weights.
struct Bilinear {
    texel: vec2<u32>,
    t: vec2<f32>,
}

fn bilinear(dir: vec3<f32>, res: u32) -> Bilinear {
    let x = 1.0 + (oct_encode(dir) * 0.5 + 0.5) * f32(res) - 0.5;
    let lo = clamp(floor(x), vec2<f32>(0.0), vec2<f32>(f32(res)));
    return Bilinear(vec2<u32>(lo), clamp(x - lo, vec2<f32>(0.0), vec2<f32>(1.0)));
}

fn irradiance_index(slot: u32, t: vec2<u32>) -> u32 {
    return slot * IRR_SIDE * IRR_SIDE + t.y * IRR_SIDE + t.x;
}

fn distance_index(slot: u32, t: vec2<u32>) -> u32 {
    return slot * DIST_SIDE * DIST_SIDE + t.y * DIST_SIDE + t.x;
}

// A probe's irradiance arriving from around `dir` (a surface facing dir receives it).
fn probe_irradiance(slot: u32, dir: vec3<f32>) -> vec3<f32> {
    let b = bilinear(dir, IRR_TEXELS);
    let a = textureLoad(irradiance_map, wide_texel(irradiance_index(slot, b.texel)), 0).xyz;
    let c = textureLoad(irradiance_map, wide_texel(irradiance_index(slot, b.texel + vec2<u32>(1u, 0u))), 0).xyz;
    let d = textureLoad(irradiance_map, wide_texel(irradiance_index(slot, b.texel + vec2<u32>(0u, 1u))), 0).xyz;
    let e = textureLoad(irradiance_map, wide_texel(irradiance_index(slot, b.texel + vec2<u32>(1u, 1u))), 0).xyz;
    return mix(mix(a, c, b.t.x), mix(d, e, b.t.x), b.t.y);
}

// Mean and mean square of the distance from a probe to the nearest surface around `dir`.
fn probe_distance(slot: u32, dir: vec3<f32>) -> vec2<f32> {
    let b = bilinear(dir, DIST_TEXELS);
    let a = textureLoad(distance_map, wide_texel(distance_index(slot, b.texel)), 0).xy;
    let c = textureLoad(distance_map, wide_texel(distance_index(slot, b.texel + vec2<u32>(1u, 0u))), 0).xy;
    let d = textureLoad(distance_map, wide_texel(distance_index(slot, b.texel + vec2<u32>(0u, 1u))), 0).xy;
    let e = textureLoad(distance_map, wide_texel(distance_index(slot, b.texel + vec2<u32>(1u, 1u))), 0).xy;
    return mix(mix(a, c, b.t.x), mix(d, e, b.t.x), b.t.y);
}

// The finest cascade whose probes enclose p (the coarsest when none does).
fn cascade_at(p: vec3<f32>) -> u32 {
    let top = vec3<f32>(params.counts.xyz - vec3<u32>(1u));
    for (var c = 0u; c + 1u < params.counts.w; c++) {
        let local = (p - grid_position(c, params.cascades[c].base.xyz)) / spacing(c);
        if all(local >= vec3<f32>(0.0)) && all(local <= top) {
            return c;
        }
    }
    return max(params.counts.w, 1u) - 1u;
}

struct ProbeGather {
    // Irradiance at the point (cosine-weighted incoming radiance over its hemisphere).
    irradiance: vec3<f32>,
    // Sum of the probes' weights (0: no probe reached the point).
    weight: f32,
    // The slot of the probe with the largest weight, plus one (0: none).
    strongest: u32,
    // Probes with a weight above zero.
    probes: u32,
}

// The cell of 8 probes a gather at p (normal n, towards the eye wo) reads.
struct GatherCell {
    cascade: u32,
    // The cell's lowest corner, in grid coordinates of the cascade.
    lo: vec3<i32>,
    // Trilinear position within the cell.
    alpha: vec3<f32>,
    // The biased point the visibility test uses.
    q: vec3<f32>,
}

fn gather_cell(p: vec3<f32>, n: vec3<f32>, wo: vec3<f32>) -> GatherCell {
    let c = cascade_at(p);
    let sp = spacing(c);
    let q = p + (0.2 * n + 0.8 * wo) * (0.75 * sp * params.bias);
    let top = vec3<f32>(params.counts.xyz - vec3<u32>(1u));
    let base_pos = grid_position(c, params.cascades[c].base.xyz);
    let local = clamp((q - base_pos) / sp, vec3<f32>(0.0), top);
    let lo = min(floor(local), top - 1.0);
    return GatherCell(c, vec3<i32>(lo), local - lo, q);
}

// Corner i (bits x, y, z) of a gather's cell: its probe's slot and weight (0 where the probe
// cannot be read: off, or without data of its own).
struct GatherCorner {
    slot: u32,
    weight: f32,
}

fn gather_corner(cell: GatherCell, p: vec3<f32>, n: vec3<f32>, i: u32) -> GatherCorner {
    let o = vec3<u32>(i & 1u, (i >> 1u) & 1u, (i >> 2u) & 1u);
    let slot = probe_slot(cell.cascade, cell.lo + vec3<i32>(o));
    let tri = select(1.0 - cell.alpha, cell.alpha, o == vec3<u32>(1u));
    let trilinear = tri.x * tri.y * tri.z;
    let pp = probe_position(slot);
    let to_probe = normalize(pp - p);
    let facing = (dot(to_probe, n) + 1.0) * 0.5;
    var w = facing * facing + 0.2;
    if has_flag(FLAG_VISIBILITY) {
        let d = cell.q - pp;
        let r = length(d);
        let m = probe_distance(slot, d / max(r, 1e-8));
        if r > m.x {
            let variance = abs(m.x * m.x - m.y);
            let v = variance / (variance + (r - m.x) * (r - m.x));
            w *= max(v * v * v, 0.05);
        }
    }
    w = max(w, 1e-6);
    // Crush weights below 0.2 (the paper's light-leak tweak).
    if w < 0.2 {
        w *= w * w / (0.2 * 0.2);
    }
    w *= trilinear;
    return GatherCorner(slot, select(0.0, w, probe_readable(slot)));
}

// The paper's gather (JCGT 2019, section 5): the 8 probes of the cell around p, each weighted
// by its trilinear weight, a smooth backface term, and (FLAG_VISIBILITY) the Chebyshev bound
// that the surface is visible from it given the probe's distance moments; the point is first
// moved off the surface by the self-shadow bias along the normal and the view direction wo.
// Probes that are off or hold no data of their own yet (new after the volume moved, or just
// switched on) are skipped; a point no other probe reaches gets no indirect light.
fn ddgi_gather(p: vec3<f32>, n: vec3<f32>, wo: vec3<f32>) -> ProbeGather {
    let cell = gather_cell(p, n, wo);
    var sum = vec3<f32>(0.0);
    var weight = 0.0;
    var best = 0.0;
    var strongest = 0u;
    var count = 0u;
    for (var i = 0u; i < 8u; i++) {
        let k = gather_corner(cell, p, n, i);
        let w = k.weight;
        // A readable probe whose trilinear weight is 0 adds nothing: skipped with the rest.
        if w > 0.0 {
            let e = probe_irradiance(k.slot, n);
            sum += w * e;
            weight += w;
            if w > best {
                best = w;
                strongest = k.slot + 1u;
            }
            count += 1u;
        }
    }
    if weight > 0.0 {
        return ProbeGather(sum / weight, weight, strongest, count);
    }
    return ProbeGather(vec3<f32>(0.0), 0.0, 0u, 0u);
}
