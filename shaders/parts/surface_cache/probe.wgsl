// Surface cache indirect lighting, step 1 (the seed's "Indirect Lighting Probes"): one
// hemispherical probe per 4x4 texel tile in this frame's share (`indirect_texels_per_frame`),
// placed on a texel jittered per frame, 16 stratified cosine rays (jittered per frame) traced in
// the `tracing` mode, one invocation per ray. Hits read the cache itself (this frame's direct, last update's indirect),
// so each update adds a bounce: multi-bounce through feedback.
#import gilab::frame::frame
#import gilab::math::{PI, to_world}
#import gilab::sampling::sample_cosine_hemisphere
#import gilab::counters::{flush_counts, no_counts, RAY_CACHE}
#import gilab::rng::{rng_init, rand, rand_pair, STREAM_LUMEN_PROBE}
#import gilab::tracing::{trace_scene, hit_radiance}
#import gilab::surface_cache_lighting::{cache_tiles, probes, Probe}
#import gilab::surface_cache::{cache_texel}
#import gilab::sky::sky_radiance

const PROBE_RAYS: u32 = 16u;
// Probes per workgroup: one invocation per ray (a probe's 16 rays in one loop of one
// invocation left a GPU with a sixteenth of the parallelism: issue 58).
const GROUP_PROBES: u32 = 4u;

var<workgroup> wg_found: array<bool, 4>;
var<workgroup> wg_texel: array<vec2<u32>, 4>;
var<workgroup> wg_position: array<vec3<f32>, 4>;
var<workgroup> wg_normal: array<vec3<f32>, 4>;
var<workgroup> wg_jitter: array<vec2<f32>, 4>;
var<workgroup> wg_radiance: array<vec3<f32>, 64>;
var<workgroup> wg_dist: array<f32, 64>;

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    var counts = no_counts();
    let local_probe = li / PROBE_RAYS;
    let ray = li % PROBE_RAYS;
    let index = wid.x * GROUP_PROBES + local_probe;
    let live = index < cache_tiles.params.probe_tile_count && cache_tiles.params.probe_tiles_total > 0u;
    var entry = vec2<u32>(0u);
    var tile = vec2<u32>(0u);
    if live {
        entry = cache_tiles.tiles[cache_tiles.params.direct_tiles_total + (cache_tiles.params.probe_tile_first + index) % cache_tiles.params.probe_tiles_total].xy;
        tile = vec2<u32>(entry.x & 0xffffu, entry.x >> 16u);
    }
    // The probe's first invocation places it (a valid texel of the tile from a random start)
    // and draws its jitter; the random numbers are the ones one invocation per probe drew.
    if ray == 0u {
        wg_found[local_probe] = false;
        if live {
            var rng = rng_init(tile, frame.frame_index, STREAM_LUMEN_PROBE, frame.seed);
            let start = u32(rand(&rng) * 16.0);
            var found = false;
            var texel = vec2<u32>(0u);
            for (var k = 0u; k < 16u && !found; k++) {
                let i = (start + k) % 16u;
                texel = tile * 4u + vec2<u32>(i % 4u, i / 4u);
                found = cache_texel(entry.y, texel).valid;
            }
            wg_found[local_probe] = found;
            wg_texel[local_probe] = texel;
            if found {
                let t = cache_texel(entry.y, texel);
                wg_position[local_probe] = t.position;
                wg_normal[local_probe] = t.normal;
                wg_jitter[local_probe] = rand_pair(&rng);
            }
        }
    }
    workgroupBarrier();
    let found = wg_found[local_probe];
    if found {
        let position = wg_position[local_probe];
        let normal = wg_normal[local_probe];
        let u = (vec2<f32>(f32(ray % 4u), f32(ray / 4u)) + wg_jitter[local_probe]) / 4.0;
        let dir = to_world(sample_cosine_hemisphere(u), normal);
        let h = trace_scene(position, normal, dir, 1e30);
        wg_radiance[li] = hit_radiance(h, sky_radiance(dir));
        wg_dist[li] = select(1e4, h.t, h.hit);
    }
    workgroupBarrier();
    // The probe's first invocation sums its rays in order (the same sums as one loop).
    if live && ray == 0u {
        let probe_index = tile.y * (cache_tiles.params.atlas_size / 4u) + tile.x;
        if !found {
            probes[probe_index].pos = vec4<f32>(0.0);
        } else {
            var sum = vec3<f32>(0.0);
            var dist = 0.0;
            for (var r = 0u; r < PROBE_RAYS; r++) {
                sum += wg_radiance[li + r];
                dist += wg_dist[li + r];
            }
            counts[RAY_CACHE] += PROBE_RAYS;
            // Cosine-distributed rays: irradiance = pi x mean radiance.
            probes[probe_index] = Probe(vec4<f32>(wg_position[local_probe], 1.0), vec4<f32>(wg_normal[local_probe], dist / f32(PROBE_RAYS)), vec4<f32>(PI * sum / f32(PROBE_RAYS), f32(frame.frame_index)));
        }
    }
    flush_counts(li, counts);
}
