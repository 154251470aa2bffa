// The spatially hashed radiance cache (src/parts/hash_cache.rs; NVIDIA's SHaRC in RTXGI 2.x,
// Bevy Solari's world cache, id Tech 8's "compact spatial-hash radiance cache"): cells keyed by
// a quantised position, the side the surface faces and a level that grows with the distance to
// the camera (log2). A cell holds the light a surface reflects there, divided by its albedo (so
// a reader multiplies by its own: texture detail finer than a cell stays), averaged over the
// samples of update paths (`update.wgsl`) with a capped history (`resolve.wgsl`).
//
// The table is open addressing: a key's slot is its hash, probed linearly over PROBE_SLOTS
// slots; a slot holds the key's 32-bit checksum (0: empty). Only 32-bit atomics: every wgpu
// backend, lavapipe too. Samples are summed in fixed point (stochastic rounding keeps the sum
// unbiased) and folded into the cell's average once a frame.
//
// Bindings at bind group HASH_CACHE_GROUP (a shader def; default 2, the cache's own passes);
// a reader of another technique sets the group it binds the lookup at. Layout must match
// `hash_cache::lookup_layout`.
#define_import_path gilab::hash_cache

#import gilab::frame::frame
#import gilab::brdf::{Surface, diffuse_color, specular_albedo_average}

// Slots a key may sit in past its hash (linear probing).
const PROBE_SLOTS: u32 = 8u;
// Levels: the finest cells are `cell_size` wide, level l 2^l times that.
const LEVELS: u32 = 16u;
// Fixed-point scale of the per-frame sums: 1/256 of a unit of light over albedo, rounded
// stochastically.
const FIXED_SCALE: f32 = 256.0;
// Largest light over albedo one sample adds (a reflected radiance of 4,096 x the albedo: a
// firefly clamp only far above the scenes' light), and the most samples a cell takes a frame,
// so that its sums stay within 32 bits: 4,096 x 4,096 x 256 = 2^32. Samples past that are
// dropped, whatever their value (no bias: which ones arrive first does not depend on it).
const MAX_SAMPLE: f32 = 4096.0;
const MAX_SAMPLES_PER_FRAME: u32 = 4096u;
// Surfaces smoother than this (GGX alpha below 0.3^2, ReSTIR's `specular_max_roughness`) are
// neither written nor read: their light depends on the view, which a cell does not keep.
const MIN_CACHED_ALPHA: f32 = 0.09;

struct HashCacheParams {
    // Slots in the table (a power of two).
    capacity: u32,
    // Frames a cell is kept without a new sample before it is evicted.
    stale_frames: u32,
    // Samples a cell's average keeps at most (its history).
    max_samples: f32,
    // Edge of the finest cells, world units.
    cell_size: f32,
    // A cell is about 1 / cells_per_distance of its distance to the camera, at least cell_size.
    cells_per_distance: f32,
    // One update path per block x block pixels a frame.
    block: u32,
    // (Padding names without a trailing digit: naga_oil cannot compose a module whose
    // identifiers naga would rename, such as `pad0`.)
    pad_a: u32,
    pad_b: u32,
}

@group(#{HASH_CACHE_GROUP}) @binding(0) var<uniform> hash_params: HashCacheParams;
// [0, capacity): keys (checksums, 0 empty); [capacity, 5 capacity): this frame's sums, four
// words a slot (r, g, b in fixed point, sample count); [5 capacity, 6 capacity): frames since a
// slot's last sample.
@group(#{HASH_CACHE_GROUP}) @binding(1) var<storage, read_write> hash_words: array<atomic<u32>>;
// Per slot: reflected radiance over albedo (xyz), samples its average holds (w).
@group(#{HASH_CACHE_GROUP}) @binding(2) var<storage, read_write> hash_cells: array<vec4<f32>>;

fn hash_u32(v: u32) -> u32 {
    let state = v * 747796405u + 2891336453u;
    let word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

// The level of a cell at p: 0 within cells_per_distance finest cells of the camera, then one
// more each time the distance doubles.
fn cell_level(p: vec3<f32>) -> u32 {
    let ratio = distance(p, frame.camera_pos.xyz) / (hash_params.cells_per_distance * hash_params.cell_size);
    if ratio < 1.0 {
        return 0u;
    }
    return min(u32(floor(log2(ratio))) + 1u, LEVELS - 1u);
}

// Edge of the cell at p, world units.
fn cell_size_at(p: vec3<f32>) -> f32 {
    return hash_params.cell_size * exp2(f32(cell_level(p)));
}

// Which of the six axis directions n is closest to.
fn normal_axis(n: vec3<f32>) -> u32 {
    let a = abs(n);
    if a.x >= a.y && a.x >= a.z {
        return select(1u, 0u, n.x >= 0.0);
    }
    if a.y >= a.z {
        return select(3u, 2u, n.y >= 0.0);
    }
    return select(5u, 4u, n.z >= 0.0);
}

// (hash, checksum) of the cell at p on a surface facing n: the slot is the hash, the key stored
// in it the checksum, a function of the whole hash (never 0).
fn cell_key(p: vec3<f32>, n: vec3<f32>) -> vec2<u32> {
    let level = cell_level(p);
    let q = vec3<i32>(floor(p / (hash_params.cell_size * exp2(f32(level)))));
    var h = hash_u32(bitcast<u32>(q.x));
    h = hash_u32(h ^ bitcast<u32>(q.y));
    h = hash_u32(h ^ bitcast<u32>(q.z));
    h = hash_u32(h ^ (level | (normal_axis(n) << 8u)));
    return vec2<u32>(h, max(hash_u32(h ^ 0x68e31da4u), 1u));
}

fn probe_slot(key: vec2<u32>, i: u32) -> u32 {
    return (key.x + i) & (hash_params.capacity - 1u);
}

// The slot holding `key`, or -1.
fn find_slot(key: vec2<u32>) -> i32 {
    for (var i = 0u; i < PROBE_SLOTS; i++) {
        let slot = probe_slot(key, i);
        if atomicLoad(&hash_words[slot]) == key.y {
            return i32(slot);
        }
    }
    return -1;
}

// The slot holding `key`, claiming an empty one if none does; -1 when its slots are all taken.
fn insert_slot(key: vec2<u32>) -> i32 {
    let found = find_slot(key);
    if found >= 0 {
        return found;
    }
    for (var i = 0u; i < PROBE_SLOTS; i++) {
        let slot = probe_slot(key, i);
        // Again while the slot is still empty: the weak exchange may fail without another
        // writer, and moving on would put the key in a second slot (bounded, as a safeguard).
        for (var attempt = 0u; attempt < 64u; attempt++) {
            let r = atomicCompareExchangeWeak(&hash_words[slot], 0u, key.y);
            if r.exchanged || r.old_value == key.y {
                return i32(slot);
            }
            if r.old_value != 0u {
                break;
            }
        }
    }
    return -1;
}

// Whether a surface's light may be cached: rough enough that its reflected light hardly
// depends on the view.
fn cacheable(m: Surface) -> bool {
    return m.alpha >= MIN_CACHED_ALPHA;
}

// What the cache divides a surface's reflected light by, and a reader multiplies it back with:
// its diffuse albedo plus its specular layer's average albedo (the surfels' too).
fn cache_albedo(m: Surface, n_dot_v: f32) -> vec3<f32> {
    return diffuse_color(m, n_dot_v) + specular_albedo_average(m);
}

// The cell of a surface at p facing n: reflected radiance over albedo (xyz) and the samples
// behind it (w; 0 where the cache has none).
fn hash_lookup(p: vec3<f32>, n: vec3<f32>) -> vec4<f32> {
    let slot = find_slot(cell_key(p, n));
    if slot < 0 {
        return vec4<f32>(0.0);
    }
    return hash_cells[u32(slot)];
}

// Adds one sample of reflected radiance over albedo to a slot's sums this frame; `u` in [0, 1)
// rounds it. The count is claimed first: a sample past MAX_SAMPLES_PER_FRAME gives its claim
// back and adds nothing.
fn add_sample(slot: u32, l: vec3<f32>, u: f32) {
    let base = hash_params.capacity + 4u * slot;
    if atomicAdd(&hash_words[base + 3u], 1u) >= MAX_SAMPLES_PER_FRAME {
        atomicSub(&hash_words[base + 3u], 1u);
        return;
    }
    let v = vec3<u32>(floor(clamp(l, vec3<f32>(0.0), vec3<f32>(MAX_SAMPLE)) * FIXED_SCALE + u));
    atomicAdd(&hash_words[base], v.x);
    atomicAdd(&hash_words[base + 1u], v.y);
    atomicAdd(&hash_words[base + 2u], v.z);
}
