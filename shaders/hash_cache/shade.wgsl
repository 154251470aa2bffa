// The `hash-cache` technique's pixels (src/techniques/hash_cache): a path from each pixel's
// primary surface, as the reference traces it (NEE with MIS, BSDF sampling, Russian roulette),
// that ends in the hash radiance cache (gilab::hash_cache) at the first hit whose cell is
// narrower than the path's footprint there and holds samples: the hit's emission (MIS-weighted)
// plus the cell's reflected light times the hit's albedo (never at a smooth hit, whose light
// depends on the view: the path goes on there). That is RTXGI 2's SHaRC query rule: a
// diffuse bounce's segment longer than about a cell ends, a glossy path goes on until its cone
// is wider than the cell. The footprint grows by t / sqrt(pdf) a segment (the width of the
// solid angle 1 / pdf a sample stands for), not at all past a mirror.
#import gilab::rng::{rng_init, rand, rand_pair, STREAM_HASH_PIXEL}
#import gilab::frame::frame
#import gilab::counters::{flush_counts, no_counts, count_cache_lookup, RAY_INDIRECT, RAY_SHADOW, COUNT_INVALID_SAMPLES}
#import gilab::math::max_component
#import gilab::surface::pixel_spread
#import gilab::hash_cache_path_step::path_step
#import gilab::path_vertex::{next_event, nee_sky_share}
#import gilab::primary::{current_surface, primary_hit_surface, primary_emission, surface_material}
#import gilab::accumulate::accumulate_sample
#import gilab::hash_cache::{hash_lookup, cell_size_at, cache_albedo, cell_key, cell_level, cacheable}
#import gilab::math::luminance
#import gilab::hash_cache_outcome::lookup_outcome

struct ShadeSettings {
    // 1: average frames (converging); 0: each frame alone.
    accumulate: u32,
    // 0: paths never end in the cache (the same paths traced to the end: the A/B baseline).
    use_cache: u32,
    // 1: write the debug views.
    debug: u32,
    pad: u32,
}
@group(3) @binding(0) var<uniform> settings: ShadeSettings;
// Per pixel, the debug views (src/techniques/hash_cache): the primary surface's cell (its
// checksum's low 24 bits, an id), that cell's samples, its level, and the cache's light there
// (luminance of albedo x cell).
@group(3) @binding(1) var<storage, read_write> debug_out: array<vec4<f32>>;

const SAFETY_MAX_BOUNCES: u32 = 1024u;
const RR_START_DEPTH: u32 = 3u;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    var counts = no_counts();
    if gid.x < frame.size.x && gid.y < frame.size.y {
        let idx = gid.y * frame.size.x + gid.x;
        var rng = rng_init(gid.xy, frame.sample_offset, STREAM_HASH_PIXEL, frame.seed);
        let s = current_surface(idx);
        var l = primary_emission(s);
        if s.pos.w > 0.5 {
            var surf = primary_hit_surface(s);
            var wo = s.wo_dist.xyz;
            let p_sky = nee_sky_share();
            var throughput = vec3<f32>(1.0);
            var footprint = s.wo_dist.w * pixel_spread();
            var looked_up = false;
            for (var depth = 0u; depth < SAFETY_MAX_BOUNCES; depth++) {
                let direct = next_event(surf, wo, &rng, p_sky, true, 1u);
                counts[RAY_SHADOW] += direct.shadow_rays;
                l += throughput * direct.radiance;
                let st = path_step(surf, wo, p_sky, &rng);
                if st.rays == 0u {
                    break;
                }
                counts[RAY_INDIRECT] += st.rays;
                throughput *= st.weight;
                l += throughput * st.light;
                if !st.hit {
                    break;
                }
                let next = st.next;
                if !st.is_delta {
                    footprint += st.t / sqrt(max(st.pdf, 1e-6));
                }
                if settings.use_cache == 1u && footprint > cell_size_at(next.position) && cacheable(next.material) {
                    let c = hash_lookup(next.position, next.geo_normal);
                    if !looked_up {
                        looked_up = true;
                        count_cache_lookup(&counts, lookup_outcome(next.position, c.w > 0.0));
                    }
                    if c.w > 0.0 {
                        l += throughput * cache_albedo(next.material, max(dot(next.normal, -st.dir), 0.0)) * c.xyz;
                        break;
                    }
                }
                if depth + 1u >= RR_START_DEPTH {
                    let q = min(max_component(throughput), 0.95);
                    if q <= 0.0 || rand(&rng) >= q {
                        break;
                    }
                    throughput /= q;
                }
                surf = next;
                wo = -st.dir;
            }
        }
        if settings.debug == 1u {
            var d = vec4<f32>(0.0);
            if s.pos.w > 0.5 {
                let c = hash_lookup(s.pos.xyz, s.geo_specular.xyz);
                let a = cache_albedo(surface_material(s), max(dot(s.normal_alpha.xyz, s.wo_dist.xyz), 0.0));
                d = vec4<f32>(f32(cell_key(s.pos.xyz, s.geo_specular.xyz).y & 0xffffffu), c.w, f32(cell_level(s.pos.xyz)), luminance(a * c.xyz));
            }
            debug_out[idx] = d;
        }
        if !accumulate_sample(idx, l, settings.accumulate == 1u) {
            counts[COUNT_INVALID_SAMPLES] = 1u;
        }
    }
    flush_counts(local_index, counts);
}
