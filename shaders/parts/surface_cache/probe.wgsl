// Surface cache indirect lighting, step 1 (the seed's "Indirect Lighting Probes"): one
// hemispherical probe per 4x4 texel tile in this frame's share (`indirect_texels_per_frame`),
// placed on a texel jittered per frame, 16 stratified cosine rays (jittered per frame) traced in
// the `tracing` mode. Hits read the cache itself (this frame's direct, last update's indirect),
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

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    var counts = no_counts();
    if gid.x < cache_tiles.params.probe_tile_count && cache_tiles.params.probe_tiles_total > 0u {
        let entry = cache_tiles.tiles[cache_tiles.params.direct_tiles_total + (cache_tiles.params.probe_tile_first + gid.x) % cache_tiles.params.probe_tiles_total];
        let tile = vec2<u32>(entry.x & 0xffffu, entry.x >> 16u);
        var rng = rng_init(tile, frame.frame_index, STREAM_LUMEN_PROBE, frame.seed);
        let start = u32(rand(&rng) * 16.0);
        var found = false;
        var texel = vec2<u32>(0u);
        for (var k = 0u; k < 16u && !found; k++) {
            let i = (start + k) % 16u;
            texel = tile * 4u + vec2<u32>(i % 4u, i / 4u);
            found = cache_texel(entry.y, texel).valid;
        }
        let probe_index = tile.y * (cache_tiles.params.atlas_size / 4u) + tile.x;
        if !found {
            probes[probe_index].pos = vec4<f32>(0.0);
        } else {
            let t = cache_texel(entry.y, texel);
            var sum = vec3<f32>(0.0);
            var dist = 0.0;
            let jitter = rand_pair(&rng);
            for (var r = 0u; r < PROBE_RAYS; r++) {
                let u = (vec2<f32>(f32(r % 4u), f32(r / 4u)) + jitter) / 4.0;
                let dir = to_world(sample_cosine_hemisphere(u), t.normal);
                let h = trace_scene(t.position, t.normal, dir, 1e30);
                sum += hit_radiance(h, sky_radiance(dir));
                dist += select(1e4, h.t, h.hit);
            }
            counts[RAY_CACHE] += PROBE_RAYS;
            // Cosine-distributed rays: irradiance = pi x mean radiance.
            probes[probe_index] = Probe(vec4<f32>(t.position, 1.0), vec4<f32>(t.normal, dist / f32(PROBE_RAYS)), vec4<f32>(PI * sum / f32(PROBE_RAYS), f32(frame.frame_index)));
        }
    }
    flush_counts(li, counts);
}
