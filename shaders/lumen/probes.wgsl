// Lumen's final gather (part 2, shared/seeds/000 "Screen Space Radiance Caching"): screen probes
// on the G-buffer, last frame's hierarchical-Z for screen traces; the world radiance cache is a
// part (gilab::world_cache) whose bindings share this group. Bind group 3; layout must match
// src/techniques/lumen/screen_probes.rs.
#define_import_path gilab::lumen_probes

#import gilab::frame::frame
#import gilab::primary::{previous_pixel_position, current_surface}

// Screen probes hold 8x8 equal-area octahedral cells over the whole sphere (gilab::equal_area).
const PROBE_RES: u32 = 8u;
const PROBE_CELLS: u32 = 64u;
const NO_PROBE: u32 = 0xffffffffu;
// Samples a probe's importance sampling mixes in uniformly over the directions its pixels see
// (defensive sampling: a stale or wrong lighting estimate cannot starve a direction).
const DEFENSIVE: f32 = 0.25;

const PROBES_PRODUCT: u32 = 1u;
const PROBES_SCREEN_TRACES: u32 = 2u;
const PROBES_WORLD_CACHE: u32 = 4u;
const PROBES_ADAPTIVE: u32 = 8u;
const PROBES_SPATIAL: u32 = 16u;
const PROBES_TEMPORAL: u32 = 32u;
const PROBES_CONTACT_AO: u32 = 64u;
const PROBES_ACTIVE: u32 = 128u;
const PROBES_REASSIGN: u32 = 256u;

// Words of `probe_state`.
const STATE_PROBE_COUNT: u32 = 0u;
const STATE_WORLD_RAYS: u32 = 1u;
// (Words 2 and 3 are free.)
// Indirect dispatch of the world trace (x, y, z) at words 4..6.
const STATE_WORLD_ARGS: u32 = 4u;
// Statistics since the last history reset: screen-trace hits, rays continued in the world,
// adaptive probes placed, world-cache reads on a miss.
const STATE_SCREEN_HITS: u32 = 8u;
const STATE_WORLD_CONTINUED: u32 = 9u;
const STATE_ADAPTIVE: u32 = 10u;
const STATE_WORLD_READS: u32 = 11u;

struct ProbeParams {
    // Per HZB mip: (word offset in probe_state, width, height, 0).
    hzb_mips: array<vec4<u32>, 16>,
    // Tiles x, tiles y, probe spacing in pixels, probe capacity.
    grid: vec4<u32>,
    // Adaptive cells x, y, cell size in pixels, uniform probes.
    adaptive: vec4<u32>,
    // This frame's placement jitter (x, y) and last frame's.
    jitter: vec4<u32>,
    // HZB mips, screen-trace step cap, 0, 0.
    counts: vec4<u32>,
    // Word offsets in probe_state: adaptive map, world ray list; vec4 offsets in probe_data:
    // ray records, temporal cache.
    offsets: vec4<u32>,
    // vec4 offsets in probe_data: filtered radiance; in pixel_data: irradiance history; 0; 0.
    offsets_b: vec4<u32>,
    // World-cache distance, screen-trace thickness, probe temporal weight, pixel temporal weight.
    misc: vec4<f32>,
    // x: PROBES_* flags, y: 1 when last frame's probes and image exist, z: this frame's parity.
    flags: vec4<u32>,
}

@group(3) @binding(0) var<uniform> pp: ProbeParams;
@group(3) @binding(1) var<storage, read_write> probe_state: array<atomic<u32>>;
// Probe headers (3 vec4 per probe and parity), ray records, the temporal and filtered radiance.
@group(3) @binding(2) var<storage, read_write> probe_data: array<vec4<f32>>;
// Per pixel and parity: last frame's reflected radiance (screen traces read it) and the
// temporally filtered irradiance.
@group(3) @binding(3) var<storage, read_write> pixel_data: array<vec4<f32>>;
// The world radiance cache's lookup bindings (24, 26) sit in this group too: gilab::world_cache.

fn probes_flag(f: u32) -> bool {
    return (pp.flags.x & f) != 0u;
}

fn parity() -> u32 {
    return pp.flags.z;
}

fn history_valid() -> bool {
    return pp.flags.y != 0u;
}

fn max_probes() -> u32 {
    return pp.grid.w;
}

// ---------------------------------------------------------------------------------------------
// Screen probes.

struct ScreenProbe {
    valid: bool,
    pos: vec3<f32>,
    // Distance to the camera.
    dist: f32,
    normal: vec3<f32>,
    // Geometric normal (rays leave on its side).
    geo: vec3<f32>,
    pixel: vec2<u32>,
    // Frames of temporal history this probe's radiance carries.
    history: f32,
    adaptive: bool,
}

fn header_index(par: u32, probe: u32) -> u32 {
    return 4u * (par * max_probes() + probe);
}

fn load_probe(par: u32, probe: u32) -> ScreenProbe {
    let h = header_index(par, probe);
    let a = probe_data[h];
    let b = probe_data[h + 1u];
    let c = probe_data[h + 2u];
    let d = probe_data[h + 3u];
    let pixel = vec2<u32>(bitcast<u32>(d.x), bitcast<u32>(d.y));
    return ScreenProbe(c.w > 0.5, a.xyz, a.w, b.xyz, c.xyz, pixel, b.w, c.w > 1.5);
}

fn store_probe(par: u32, probe: u32, p: ScreenProbe) {
    let h = header_index(par, probe);
    var kind = 0.0;
    if p.valid {
        kind = select(1.0, 2.0, p.adaptive);
    }
    probe_data[h] = vec4<f32>(p.pos, p.dist);
    probe_data[h + 1u] = vec4<f32>(p.normal, p.history);
    probe_data[h + 2u] = vec4<f32>(p.geo, kind);
    probe_data[h + 3u] = vec4<f32>(bitcast<f32>(p.pixel.x), bitcast<f32>(p.pixel.y), 0.0, 0.0);
}

// Ray records: 2 vec4 per ray (uv of the direction, weight, cell), (radiance, hit distance).
fn ray_index(probe: u32, ray: u32) -> u32 {
    return pp.offsets.z + 2u * (probe * PROBE_CELLS + ray);
}

// Temporally accumulated radiance per cell (rgb, hit distance), by parity.
fn cache_index(par: u32, probe: u32, cell: u32) -> u32 {
    return pp.offsets.w + (par * max_probes() + probe) * PROBE_CELLS + cell;
}

// Spatially filtered radiance per cell, this frame's.
fn filtered_index(probe: u32, cell: u32) -> u32 {
    return pp.offsets_b.x + probe * PROBE_CELLS + cell;
}

fn tiles() -> vec2<u32> {
    return pp.grid.xy;
}

fn spacing() -> u32 {
    return pp.grid.z;
}

// The uniform probe of a tile: its index is the tile's.
fn tile_probe(t: vec2<u32>) -> u32 {
    return t.y * pp.grid.x + t.x;
}

fn adaptive_map(cell: vec2<u32>) -> u32 {
    return atomicLoad(&probe_state[pp.offsets.x + cell.y * pp.adaptive.x + cell.x]);
}

// How well a probe at `probe_pos` (normal n_probe) stands for a point p with normal n: both on
// one plane, within `tolerance` (relative to the distance to the camera).
fn plane_weight(p: vec3<f32>, n: vec3<f32>, dist: f32, probe_pos: vec3<f32>, n_probe: vec3<f32>) -> f32 {
    let plane_dist = abs(dot(n, probe_pos - p));
    let normal_w = max(dot(n, n_probe), 0.0);
    let w = exp(-plane_dist / max(0.01 * dist, 1e-6));
    return w * normal_w * normal_w;
}

// ---------------------------------------------------------------------------------------------
// Last frame: hierarchical Z (closest 1/w of last frame's surfaces, per mip) and its image.

fn hzb_word(level: u32, cell: vec2<u32>) -> u32 {
    let m = pp.hzb_mips[level];
    return m.x + cell.y * m.y + cell.x;
}

fn hzb_load(level: u32, cell: vec2<u32>) -> f32 {
    return bitcast<f32>(atomicLoad(&probe_state[hzb_word(level, cell)]));
}

fn hzb_store(level: u32, cell: vec2<u32>, v: f32) {
    atomicStore(&probe_state[hzb_word(level, cell)], bitcast<u32>(v));
}

fn pixels() -> u32 {
    return frame.size.x * frame.size.y;
}

// Reflected radiance (no emission) of pixel i in the image of parity `par`; w: 1 where a surface.
fn lit_index(par: u32, pixel: u32) -> u32 {
    return par * pixels() + pixel;
}

// Temporally filtered irradiance (rgb, history frames) of pixel i, parity `par`.
fn irradiance_index(par: u32, pixel: u32) -> u32 {
    return pp.offsets_b.y + par * pixels() + pixel;
}

// ---------------------------------------------------------------------------------------------
// Interpolation between uniform probes: the four tiles around a pixel, bilinear in the jittered
// grid, each weighted by how well it lies on the pixel's plane.

struct Neighbours {
    probe: array<u32, 4>,
    weight: array<f32, 4>,
}

fn uniform_neighbours(pixel: vec2<u32>, p: vec3<f32>, n: vec3<f32>, dist: f32) -> Neighbours {
    var out = Neighbours(array<u32, 4>(NO_PROBE, NO_PROBE, NO_PROBE, NO_PROBE), array<f32, 4>(0.0, 0.0, 0.0, 0.0));
    let f = (vec2<f32>(pixel) - vec2<f32>(pp.jitter.xy)) / f32(spacing());
    let i0 = vec2<i32>(floor(f));
    let t = f - floor(f);
    let hi = vec2<i32>(tiles()) - 1;
    for (var k = 0u; k < 4u; k++) {
        let o = vec2<i32>(i32(k & 1u), i32(k >> 1u));
        let tile = i0 + o;
        if any(tile < vec2<i32>(0)) || any(tile > hi) {
            continue;
        }
        let probe = tile_probe(vec2<u32>(tile));
        let q = load_probe(parity(), probe);
        if !q.valid {
            continue;
        }
        let b = select(1.0 - t, t, vec2<bool>(o == vec2<i32>(1)));
        out.probe[k] = probe;
        out.weight[k] = (b.x * b.y + 1e-3) * plane_weight(p, n, dist, q.pos, q.normal);
    }
    return out;
}

// Last frame's uniform probe that stands for probe q (its radiance indexed by the same cells):
// q's position in last frame's image (its pixel's surface where it was last frame: the motion
// vectors undo the camera's and its object's motion), the nearest tile of last frame's jittered
// grid, accepted when that probe lies on the plane q had; NO_PROBE otherwise (or without history).
fn previous_match(q: ScreenProbe) -> u32 {
    if !history_valid() || !q.valid {
        return NO_PROBE;
    }
    let s = current_surface(q.pixel.y * frame.size.x + q.pixel.x);
    let was = select(q.pos, s.prev_pos.xyz, s.pos.w > 0.5);
    let f = previous_pixel_position(was);
    if f.x < 0.0 || f.y < 0.0 || f.x >= f32(frame.size.x) || f.y >= f32(frame.size.y) {
        return NO_PROBE;
    }
    let t = clamp(vec2<i32>(round((f - vec2<f32>(pp.jitter.zw)) / f32(spacing()))), vec2<i32>(0), vec2<i32>(tiles()) - 1);
    let probe = tile_probe(vec2<u32>(t));
    let prev = load_probe(1u - parity(), probe);
    if !prev.valid || plane_weight(was, q.normal, q.dist, prev.pos, prev.normal) < 0.3 {
        return NO_PROBE;
    }
    return probe;
}

fn probe_count() -> u32 {
    return min(atomicLoad(&probe_state[STATE_PROBE_COUNT]), max_probes());
}
