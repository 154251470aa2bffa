// Ray accounting, counted the same way for every technique: one count per traversal query, by kind.
// Threads count locally, a workgroup sums in shared memory, and one thread adds the sum to a
// 64-bit (lo, hi) global counter, so atomics stay cheap and totals never wrap.
#define_import_path gilab::counters

const RAY_CAMERA: u32 = 0u;
const RAY_SHADOW: u32 = 1u;
const RAY_INDIRECT: u32 = 2u;
const RAY_PROBE: u32 = 3u;
const RAY_SURFEL: u32 = 4u;
const RAY_CACHE: u32 = 5u;
// Visibility of a resampling candidate before reuse (ReSTIR's conservative candidate test).
const RAY_CANDIDATE: u32 = 6u;
// Occlusion tests made by reuse itself (unbiased reuse weights, bidirectional test).
const RAY_REUSE: u32 = 7u;
// Rays along a specular lobe for reflections (the reflections part).
const RAY_REFLECTION: u32 = 8u;
// Not rays: what a ray's hit found in the radiance cache it may end in (render::CacheLookups):
// covered by the cache's entries, by its coarse average only, or not at all, each split by
// whether the camera sees the hit this frame (gilab::primary::camera_sees).
const COUNT_CACHE_ENTRY_SEEN: u32 = 9u;
const COUNT_CACHE_COARSE_SEEN: u32 = 10u;
const COUNT_CACHE_MISS_SEEN: u32 = 11u;
const COUNT_CACHE_ENTRY_UNSEEN: u32 = 12u;
const COUNT_CACHE_COARSE_UNSEEN: u32 = 13u;
const COUNT_CACHE_MISS_UNSEEN: u32 = 14u;
// Outcomes of a cache lookup for count_cache_lookup (0: no lookup); + CACHE_UNSEEN when the
// camera does not see the hit.
const CACHE_ENTRY: u32 = 1u;
const CACHE_COARSE: u32 = 2u;
const CACHE_MISS: u32 = 3u;
const CACHE_UNSEEN: u32 = 3u;
// Not a ray: samples whose radiance was NaN/Inf and was dropped. Tests require it to stay 0.
const COUNT_INVALID_SAMPLES: u32 = 15u;
const COUNTER_KINDS: u32 = 16u;

// Per-invocation counts by kind, summed by flush_counts. Index it with the constants above only
// (see flush_counts).
fn no_counts() -> array<u32, 16> {
    return array<u32, 16>(0u, 0u, 0u, 0u, 0u, 0u, 0u, 0u, 0u, 0u, 0u, 0u, 0u, 0u, 0u, 0u);
}

@group(1) @binding(1) var<storage, read_write> counters: array<atomic<u32>, 32>;

var<workgroup> wg_counts: array<atomic<u32>, 16>;

fn add_to_workgroup(kind: u32, v: u32) {
    if v > 0u {
        atomicAdd(&wg_counts[kind], v);
    }
}

// Counts one cache lookup by its outcome (CACHE_* above, + CACHE_UNSEEN; 0 counts nothing),
// with constant indices (see flush_counts).
fn count_cache_lookup(counts: ptr<function, array<u32, 16>>, outcome: u32) {
    switch outcome {
        case 1u: { (*counts)[COUNT_CACHE_ENTRY_SEEN] += 1u; }
        case 2u: { (*counts)[COUNT_CACHE_COARSE_SEEN] += 1u; }
        case 3u: { (*counts)[COUNT_CACHE_MISS_SEEN] += 1u; }
        case 4u: { (*counts)[COUNT_CACHE_ENTRY_UNSEEN] += 1u; }
        case 5u: { (*counts)[COUNT_CACHE_COARSE_UNSEEN] += 1u; }
        case 6u: { (*counts)[COUNT_CACHE_MISS_UNSEEN] += 1u; }
        default: {}
    }
}

// Must be called by every invocation of the workgroup (it contains a barrier).
// The kinds are read with constant indices, one line each, on purpose: a loop indexing the
// private array by a variable puts the array in local memory on NVIDIA GPUs, which cost every
// 1920x1080 pass about 0.57 ms on an H100 (measured, docs/performance.md).
fn flush_counts(local_index: u32, counts: array<u32, 16>) {
    add_to_workgroup(0u, counts[0]);
    add_to_workgroup(1u, counts[1]);
    add_to_workgroup(2u, counts[2]);
    add_to_workgroup(3u, counts[3]);
    add_to_workgroup(4u, counts[4]);
    add_to_workgroup(5u, counts[5]);
    add_to_workgroup(6u, counts[6]);
    add_to_workgroup(7u, counts[7]);
    add_to_workgroup(8u, counts[8]);
    add_to_workgroup(9u, counts[9]);
    add_to_workgroup(10u, counts[10]);
    add_to_workgroup(11u, counts[11]);
    add_to_workgroup(12u, counts[12]);
    add_to_workgroup(13u, counts[13]);
    add_to_workgroup(14u, counts[14]);
    add_to_workgroup(15u, counts[15]);
    workgroupBarrier();
    if local_index == 0u {
        for (var k = 0u; k < COUNTER_KINDS; k++) {
            let v = atomicLoad(&wg_counts[k]);
            if v > 0u {
                let old = atomicAdd(&counters[2u * k], v);
                if old > 0xffffffffu - v {
                    atomicAdd(&counters[2u * k + 1u], 1u);
                }
            }
        }
    }
}
