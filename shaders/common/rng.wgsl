// Counter-based random numbers: PCG hash seeded per pixel, sample and frame so any frame can be re-rendered bit-identically.
#define_import_path gilab::rng

struct Rng {
    state: u32,
}

fn pcg_hash(v: u32) -> u32 {
    let state = v * 747796405u + 2891336453u;
    let word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

// Named random streams. Every pass that draws random numbers owns one, so no two passes of a
// technique share numbers, in the same frame or across frames (streams derived from
// `sample_index * 4 + k` collided: frame 5's first pass read frame 1's second pass's numbers).
// tests/cpu.rs checks that each rng_init call names one of these and that no two entry files
// of a technique use the same one.
// Camera jitter, and the rest of the reference's path. ReSTIR's primary pass uses it too, on
// purpose: its surfaces then sit at the reference's jitter positions.
const STREAM_CAMERA: u32 = 1u;
const STREAM_REGIR_BUILD: u32 = 2u;
const STREAM_DI_INITIAL: u32 = 3u;
const STREAM_DI_SPATIAL: u32 = 4u;
const STREAM_GI_SAMPLE: u32 = 5u;
const STREAM_GI_SPATIAL: u32 = 6u;
const STREAM_BENCH: u32 = 7u;
const STREAM_TEST: u32 = 8u;
const STREAM_SURFEL_RECYCLE: u32 = 9u;
const STREAM_SURFEL_SPAWN: u32 = 10u;
const STREAM_SURFEL_ALLOCATE: u32 = 11u;
const STREAM_SURFEL_RAYS: u32 = 12u;
const STREAM_SURFEL_DIRECT: u32 = 13u;
const STREAM_LUMEN_DIRECT: u32 = 14u;
const STREAM_LUMEN_PROBE: u32 = 15u;
const STREAM_LUMEN_GATHER: u32 = 16u;
const STREAM_LUMEN_PIXEL: u32 = 17u;
const STREAM_LUMEN_QUERY: u32 = 18u;
const STREAM_LUMEN_PLACE: u32 = 19u;
const STREAM_LUMEN_PROBE_RAYS: u32 = 20u;
const STREAM_LUMEN_WORLD: u32 = 21u;
const STREAM_LUMEN_AO: u32 = 22u;
// Callisto shadows: the per-pixel light sample of each light in the tile's list.
const STREAM_CALLISTO_LIGHT: u32 = 37u;
// The reflections part: its rays, and the choice of neighbours to reuse.
const STREAM_REFLECTION: u32 = 38u;
const STREAM_REFLECTION_REUSE: u32 = 39u;
// The world-space ReGIR clipmap that lights the caches: its slots.
const STREAM_WORLD_REGIR: u32 = 40u;

// The sequence for one pixel (or work item), sample index (frame or sample number) and stream.
fn rng_init(pixel: vec2<u32>, sample_index: u32, stream: u32, seed: u32) -> Rng {
    let h = pcg_hash(pixel.x ^ pcg_hash(pixel.y ^ pcg_hash(sample_index ^ pcg_hash(stream ^ pcg_hash(seed)))));
    return Rng(h);
}

fn rand_uint(rng: ptr<function, Rng>) -> u32 {
    (*rng).state = (*rng).state * 747796405u + 2891336453u;
    let s = (*rng).state;
    let word = ((s >> ((s >> 28u) + 4u)) ^ s) * 277803737u;
    return (word >> 22u) ^ word;
}

// Uniform in [0, 1): 24 random mantissa bits so 1.0 is never returned.
fn rand(rng: ptr<function, Rng>) -> f32 {
    return f32(rand_uint(rng) >> 8u) * (1.0 / 16777216.0);
}

fn rand_pair(rng: ptr<function, Rng>) -> vec2<f32> {
    let a = rand(rng);
    let b = rand(rng);
    return vec2<f32>(a, b);
}
// ReSTIR PT: each pixel's path seed and the choice among its path lengths; the temporal and the
// spatial pass's resampling choices. The path's own numbers come from its seed (per vertex).
const STREAM_PT_INITIAL: u32 = 41u;
const STREAM_PT_TEMPORAL: u32 = 42u;
const STREAM_PT_SPATIAL: u32 = 43u;
// The hash radiance cache: its update paths, and the hash-cache technique's pixel paths.
const STREAM_HASH_UPDATE: u32 = 44u;
const STREAM_HASH_PIXEL: u32 = 45u;
// DDGI: the probes' rays (their hits' NEE), and the pixels' NEE.
const STREAM_DDGI_PROBE: u32 = 46u;
const STREAM_DDGI_PIXEL: u32 = 47u;
