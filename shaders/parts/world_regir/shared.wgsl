// The world-space ReGIR clipmap (src/parts/world_regir.rs): light reservoirs for cells wherever
// a cache lights a point (Lumen's card texels, surfel ray hits), not only around the pixels.
// "Making Connections" (shared/seeds/003) lights the surface cache with ReGIR-sampled lights
// from a clipmap of cells. Levels are centred on the camera, each twice the last's cell edge;
// a point takes the finest level whose window holds it. Cells are addressed toroidally (world
// cell coordinate modulo the window), so a cell keeps its index while the camera moves.
//
// Lookups mark the cells they read; the build fills a cell while a lookup read it in the last
// `keep_frames` frames. A lookup in a cell not built this frame takes the power-sampled light
// instead (the choice does not depend on the lookup's random numbers: still unbiased).
// Bindings at group WORLD_REGIR_GROUP (default 2: the build's own group); layout must match
// `WorldRegir::layout`.
#define_import_path gilab::world_regir

#import gilab::frame::frame
#import gilab::rng::{Rng, rand}
#import gilab::math::luminance
#import gilab::lights::{LightSample, eval_light_point}
#import gilab::regir::RegirSlot
#import gilab::toroidal::wrap_grid

struct WorldRegirParams {
    // Edge of a finest-level cell (world units); level l's cells are 2^l times larger.
    cell_size: f32,
    levels: u32,
    // Cells along each axis of a level's window.
    dims: u32,
    // Light reservoirs per cell.
    slots: u32,
    // Slots resampled by one lookup (RIS with the point's unshadowed target).
    lookup_candidates: u32,
    // A cell is built while a lookup read it within this many frames.
    keep_frames: u32,
    pad_a: u32,
    pad_b: u32,
}

@group(#{WORLD_REGIR_GROUP}) @binding(0) var<uniform> world_regir: WorldRegirParams;
@group(#{WORLD_REGIR_GROUP}) @binding(1) var<storage, read_write> world_regir_slots: array<RegirSlot>;
// [0, cells): frame + 1 when a lookup last read the cell; [cells, 2 cells): 1 when built this
// frame (cleared every frame); then STAT_SLOTS pairs of counters (lookups, lookups a built cell
// served), spread over slots so that a frame's lookups do not all hit one address.
@group(#{WORLD_REGIR_GROUP}) @binding(2) var<storage, read_write> world_regir_cells: array<atomic<u32>>;

const STAT_SLOTS: u32 = 64u;

fn world_regir_cell_count() -> u32 {
    let d = world_regir.dims;
    return world_regir.levels * d * d * d;
}

fn world_regir_level_size(level: u32) -> f32 {
    return world_regir.cell_size * f32(1u << level);
}

// Lower corner of level `level`'s window, in that level's integer cell coordinates.
fn world_regir_window(level: u32) -> vec3<i32> {
    let c = world_regir_level_size(level);
    return vec3<i32>(floor(frame.camera_pos.xyz / c)) - vec3<i32>(i32(world_regir.dims / 2u));
}

// Cell index of a world point (finest level holding it), or -1 outside every level.
fn world_regir_cell(p: vec3<f32>) -> i32 {
    let d = i32(world_regir.dims);
    for (var l = 0u; l < world_regir.levels; l++) {
        let g = vec3<i32>(floor(p / world_regir_level_size(l)));
        let rel = g - world_regir_window(l);
        if all(rel >= vec3<i32>(0)) && all(rel < vec3<i32>(d)) {
            let t = wrap_grid(g, vec3<i32>(d));
            return i32(l * u32(d * d * d)) + (t.z * d + t.y) * d + t.x;
        }
    }
    return -1;
}

// Level and centre of a cell index.
fn world_regir_cell_centre(cell: u32) -> vec4<f32> {
    let d = i32(world_regir.dims);
    let per_level = u32(d * d * d);
    let level = cell / per_level;
    let i = i32(cell % per_level);
    let t = vec3<i32>(i % d, (i / d) % d, i / (d * d));
    let lo = world_regir_window(level);
    let g = lo + wrap_grid(t - lo, vec3<i32>(d));
    let c = world_regir_level_size(level);
    return vec4<f32>((vec3<f32>(g) + 0.5) * c, c);
}

struct WorldRegirLight {
    // The chosen light seen from the point. Its pdf is 1 / (G W) (solid angle; 1 / W for
    // punctual lights), so f cos L / pdf is the RIS estimate f cos L G W.
    sample: LightSample,
    // False: no built cell here; the caller samples by power.
    served: bool,
}

// One light for point p (shading normal n) from its cell: `lookup_candidates` slots, resampled
// by the unshadowed irradiance they give (L G cos), no BSDF.
fn world_regir_light(p: vec3<f32>, n: vec3<f32>, rng: ptr<function, Rng>) -> WorldRegirLight {
    var out: WorldRegirLight;
    out.served = false;
    let total = world_regir_cell_count();
    let cell = world_regir_cell(p);
    let stat = 2u * total + 2u * (u32(max(cell, 0)) % STAT_SLOTS);
    atomicAdd(&world_regir_cells[stat], 1u);
    if cell < 0 {
        return out;
    }
    let ci = u32(cell);
    // Most lookups find their cell already marked this frame: a load spares the store.
    if atomicLoad(&world_regir_cells[ci]) != frame.frame_index + 1u {
        atomicStore(&world_regir_cells[ci], frame.frame_index + 1u);
    }
    if atomicLoad(&world_regir_cells[total + ci]) == 0u {
        return out;
    }
    atomicAdd(&world_regir_cells[stat + 1u], 1u);
    out.served = true;
    let m = max(world_regir.lookup_candidates, 1u);
    let s = world_regir.slots;
    var w_sum = 0.0;
    var chosen_target = 0.0;
    for (var i = 0u; i < m; i++) {
        let slot = world_regir_slots[ci * s + min(u32(rand(rng) * f32(s)), s - 1u)];
        if slot.big_w <= 0.0 {
            continue;
        }
        let ls = eval_light_point(slot.light, vec2<f32>(slot.bary_u, slot.bary_v), p);
        if !ls.valid {
            continue;
        }
        let t = luminance(ls.radiance) * ls.geom * max(dot(n, ls.wi), 0.0);
        let w = t * slot.big_w;
        w_sum += w;
        if w > 0.0 && rand(rng) * w_sum < w {
            out.sample = ls;
            chosen_target = t;
        }
    }
    if chosen_target > 0.0 {
        let big_w = w_sum / (f32(m) * chosen_target);
        out.sample.area_pdf = 1.0 / big_w;
        out.sample.pdf = 1.0 / (out.sample.geom * big_w);
    } else {
        out.sample.valid = false;
        out.sample.pdf = 0.0;
    }
    return out;
}
