// Lumen's world radiance cache (src/parts/world_cache.rs, shared/seeds/000 "Radiance Caching
// for Real-Time Global Illumination"): camera-centred clipmap levels of probes, WORLD_RES^2
// equal-area cells of radiance each, placed in toroidal slots (a scroll reuses the slots it
// leaves). A lookup interpolates the eight probes around a point in a direction and marks them
// read; `select.wgsl` lists the read probes (never traced first, then the stalest) and
// `update.wgsl` traces this frame's share of that list.
//
// Bindings at bind group WORLD_CACHE_GROUP, a shader def: default 3 (Lumen's probe group, which
// holds them beside the screen probes' bindings, and the cache's own passes); a pass of another
// technique sets the group it binds the lookup at (ReSTIR GI's `gi_terminate = "lumen-world"`:
// 3, beside the surface cache's lookup). A reader binds only the uniform and the probes (24, 26:
// Lumen's final gather is at the 32 storage buffers a stage may bind); the update lists (25)
// are the cache's own passes'. Layouts must match `world_cache::lookup_entries` and
// `WorldCache::layout`.
#define_import_path gilab::world_cache

#import gilab::frame::frame
#import gilab::equal_area::octa_cell
#import gilab::toroidal::wrap_grid

const WORLD_RES: u32 = 16u;
const WORLD_CELLS: u32 = 256u;
// A ray reads the cache only past the diagonal of a probe cell of the level around its start
// (the seed's probe TMin): nearer, the eight probes' parallax and visibility dominate (Cornell
// from its camera, whose box falls in the third level: -3.3% of the light at the fixed
// distance alone, -0.9% with this floor).
const PROBE_DIAGONALS: f32 = 1.7320508;

// Words of `world_lists`: how many probes are listed for this frame's update, new (never traced
// at their position) and old (stalest first); from WORLD_LISTS_HEADER the new list, then from
// WORLD_LISTS_HEADER + slots the old one.
const WORLD_STATE_NEW: u32 = 0u;
const WORLD_STATE_OLD: u32 = 1u;
const WORLD_LISTS_HEADER: u32 = 4u;

struct WorldCacheParams {
    // Per level: xyz the centre of its probe (0, 0, 0), w the probe spacing.
    levels: array<vec4<f32>, 4>,
    // Per level: the grid coordinate of probe (0, 0, 0).
    base: array<vec4<i32>, 4>,
    // Probes per axis, levels, slots (levels x probes per axis^3), probes updated per frame.
    shape: vec4<u32>,
    // x: updates in a cell's running mean at most (`world_cache_history`); yzw: 0.
    update: vec4<u32>,
    // x: the distance a ray is traced before it reads the cache (at least PROBE_DIAGONALS probe
    // spacings); yzw: 0.
    misc: vec4<f32>,
}

@group(#{WORLD_CACHE_GROUP}) @binding(24) var<uniform> wc: WorldCacheParams;
@group(#{WORLD_CACHE_GROUP}) @binding(25) var<storage, read_write> world_lists: array<u32>;
// WORLD_CELLS texels per slot (rgb radiance, hit distance); then one header per slot; then per
// slot the frames it was last read (x) and traced (y), + 1 (0: never), as floats (exact below
// 2^24 frames: a marked probe's lookups all store the same value, so a plain store suffices).
@group(#{WORLD_CACHE_GROUP}) @binding(26) var<storage, read_write> world_cache: array<vec4<f32>>;

// Start of the update lists: new probes at [0, slots), old ones at [slots, 2 slots).
fn world_list_offset() -> u32 {
    return WORLD_LISTS_HEADER;
}

fn world_frames_index(slot: u32) -> u32 {
    return world_slots() * (WORLD_CELLS + 1u) + slot;
}

// The frame slot was last read at + 1 (0: never).
fn world_read_frame(slot: u32) -> u32 {
    return u32(world_cache[world_frames_index(slot)].x);
}

// Where a ray starting at p stops and reads the cache instead (the seed's probe TMin).
fn world_tmin_at(p: vec3<f32>) -> f32 {
    return max(wc.misc.x, PROBE_DIAGONALS * world_spacing_at(p));
}

fn world_res() -> u32 {
    return wc.shape.x;
}

fn world_slots() -> u32 {
    return wc.shape.z;
}

fn world_spacing(l: u32) -> f32 {
    return wc.levels[l].w;
}

// Slot of grid coordinate g of level l (toroidal: a scroll reuses the slots it leaves).
fn world_slot(l: u32, g: vec3<i32>) -> u32 {
    let n = i32(world_res());
    let w = wrap_grid(g, vec3<i32>(n));
    return l * u32(n * n * n) + u32((w.z * n + w.y) * n + w.x);
}

// xyz: the grid coordinate the slot was traced at; w: -1 never traced, else 2 x (updates, at
// most `world_cache_history`) + the share of its rays that hit back faces (over a quarter: inside geometry).
fn world_header(slot: u32) -> vec4<f32> {
    return world_cache[world_slots() * WORLD_CELLS + slot];
}

// The frame slot was last traced at + 1 (0: never).
fn world_traced_frame(slot: u32) -> u32 {
    return u32(world_cache[world_frames_index(slot)].y);
}

fn world_updates(h: vec4<f32>) -> f32 {
    return floor(h.w * 0.5);
}

fn world_inside(h: vec4<f32>) -> f32 {
    return h.w - 2.0 * floor(h.w * 0.5);
}

// Grid coordinate of slot `slot` as the level stands now.
fn world_slot_coord(slot: u32) -> vec3<i32> {
    let n = i32(world_res());
    let per = u32(n * n * n);
    let l = slot / per;
    let r = i32(slot % per);
    let w = vec3<i32>(r % n, (r / n) % n, r / (n * n));
    let base = wc.base[l].xyz;
    // The coordinate in [base, base + n) with this remainder.
    return base + wrap_grid(w - base, vec3<i32>(n));
}

fn world_probe_pos(l: u32, g: vec3<i32>) -> vec3<f32> {
    return wc.levels[l].xyz + vec3<f32>(g - wc.base[l].xyz) * world_spacing(l);
}

struct WorldLookup {
    radiance: vec3<f32>,
    // Sum of the trilinear weights of valid probes (0: nothing known here).
    weight: f32,
}

// Probe spacing of the finest world-cache level whose probes surround p (the coarsest level's
// when none does).
fn world_spacing_at(p: vec3<f32>) -> f32 {
    let n = f32(world_res());
    for (var l = 0u; l < wc.shape.y; l++) {
        let f = (p - wc.levels[l].xyz) / world_spacing(l);
        if all(f >= vec3<f32>(0.0)) && all(f <= vec3<f32>(n - 1.0)) {
            return world_spacing(l);
        }
    }
    return world_spacing(wc.shape.y - 1u);
}

// Radiance arriving at p from direction d, interpolated from the finest level's eight probes
// around p that were traced at their current position and are not inside geometry. `mark`: ask
// for those probes to be traced (debug views read without asking).
fn world_lookup(p: vec3<f32>, d: vec3<f32>, mark: bool) -> WorldLookup {
    var out = WorldLookup(vec3<f32>(0.0), 0.0);
    let cell = octa_cell(d, WORLD_RES);
    for (var l = 0u; l < wc.shape.y; l++) {
        let s = world_spacing(l);
        let f = (p - wc.levels[l].xyz) / s;
        let n = f32(world_res());
        if any(f < vec3<f32>(0.0)) || any(f > vec3<f32>(n - 1.0)) {
            continue;
        }
        let i0 = vec3<i32>(floor(f));
        let t = f - floor(f);
        var sum = vec3<f32>(0.0);
        var weight = 0.0;
        for (var k = 0u; k < 8u; k++) {
            let o = vec3<i32>(i32(k & 1u), i32((k >> 1u) & 1u), i32(k >> 2u));
            let g = wc.base[l].xyz + i0 + o;
            let slot = world_slot(l, g);
            if mark {
                world_mark(slot);
            }
            let h = world_header(slot);
            if h.w < 0.0 || world_inside(h) > 0.25 || any(vec3<i32>(h.xyz) != g) {
                continue;
            }
            // Visibility (DDGI's test, hard): a probe whose rays towards p stop short of it sees
            // p behind a surface: the far side of a wall (a leak) or outside a closed room.
            let v = p - world_probe_pos(l, g);
            let r = length(v);
            if r > 1e-4 * s && world_cache[slot * WORLD_CELLS + octa_cell(v / r, WORLD_RES)].w < 0.9 * r {
                continue;
            }
            let texel = world_cache[slot * WORLD_CELLS + cell];
            let b = select(1.0 - t, t, vec3<bool>(o == vec3<i32>(1)));
            let w = b.x * b.y * b.z;
            sum += w * texel.xyz;
            weight += w;
        }
        if weight > 0.05 {
            out.radiance = sum / weight;
            out.weight = weight;
            return out;
        }
    }
    return out;
}

// Marks a world probe slot as read this frame (the update pass traces read slots first).
fn world_mark(slot: u32) {
    world_cache[world_frames_index(slot)].x = f32(frame.frame_index + 1u);
}
