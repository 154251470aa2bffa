// Surface cache direct lighting (the seed's "Direct Lighting"): this frame's share of 8x8 texel
// tiles (round robin through every valid tile, `direct_texels_per_frame`), one light sample
// per texel (by power from the shared light pool, or from the world ReGIR clipmap: `cache_direct`,
// gilab::cache_light) with a shadow ray in the `tracing`
// mode, averaged into the texel's direct irradiance (running mean over up to 32 updates).
#import gilab::frame::frame
#import gilab::counters::{flush_counts, no_counts, RAY_CACHE}
#import gilab::rng::{rng_init, STREAM_LUMEN_DIRECT}
#import gilab::cache_light::cache_light_sample
#import gilab::tracing::{light_visible, has_flag, FLAG_LIGHTS}
#import gilab::surface_cache_lighting::{cache_tiles}
#import gilab::surface_cache::{atlas_direct, atlas_index, cache_texel}

const DIRECT_HISTORY: f32 = 32.0;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    var counts = no_counts();
    if wg.x < cache_tiles.params.direct_tile_count && cache_tiles.params.direct_tiles_total > 0u {
        let entry = cache_tiles.tiles[(cache_tiles.params.direct_tile_first + wg.x) % cache_tiles.params.direct_tiles_total];
        let texel = vec2<u32>(entry.x & 0xffffu, entry.x >> 16u) * 8u + lid.xy;
        let t = cache_texel(entry.y, texel);
        if t.valid {
            var e = vec3<f32>(0.0);
            if has_flag(FLAG_LIGHTS) {
                var rng = rng_init(texel, frame.frame_index, STREAM_LUMEN_DIRECT, frame.seed);
                let ls = cache_light_sample(t.position, t.normal, &rng);
                let cos_n = dot(ls.wi, t.normal);
                if ls.valid && ls.pdf > 0.0 && cos_n > 0.0 {
                    counts[RAY_CACHE] += 1u;
                    if light_visible(t.position, t.normal, ls) {
                        e = ls.radiance * cos_n / ls.pdf;
                    }
                }
            }
            let ai = atlas_index(texel);
            let old = atlas_direct[ai];
            let n = min(old.w + 1.0, DIRECT_HISTORY);
            atlas_direct[ai] = vec4<f32>(old.xyz + (e - old.xyz) / n, n);
        }
    }
    flush_counts(li, counts);
}
