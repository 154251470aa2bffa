// The hash radiance cache's update (SHaRC's update pass): one path a frame from a random pixel
// of each block x block pixel block, from its primary surface. The path is the reference's (NEE
// with MIS against BSDF sampling, Russian roulette, unbounded); each of its first MAX_VERTICES
// vertices becomes a sample of its cell: the light the rest of the path brings to it and the
// vertex reflects towards the previous one, over the vertex's albedo. Each sample is unbiased
// for its vertex whatever the cache holds: the paths never read it, so a cell's average only
// blurs light over the cell and over its history.
#import gilab::rng::{Rng, rng_init, rand, rand_pair, STREAM_HASH_UPDATE}
#import gilab::frame::frame
#import gilab::counters::{flush_counts, no_counts, RAY_CACHE, RAY_SHADOW}
#import gilab::math::max_component
#import gilab::path_vertex::{next_event, nee_sky_share}
#import gilab::hash_cache_path_step::path_step
#import gilab::primary::{current_surface, primary_hit_surface}
#import gilab::hash_cache::{hash_params, cell_key, insert_slot, add_sample, cache_albedo, cacheable}

// Vertices of a path that write a sample (later ones still light these).
const MAX_VERTICES: u32 = 6u;
const SAFETY_MAX_BOUNCES: u32 = 1024u;
const RR_START_DEPTH: u32 = 3u;
// Surfaces darker than this in any channel write no sample (their light over albedo is noise,
// or 0 / 0).
const MIN_ALBEDO: f32 = 0.01;

// What a recorded vertex keeps: the light it reflects is what the path gathers after it,
// divided by the throughput that reached it: (light at the end - light before it) / throughput.
// No loop over the vertices runs inside the path's loop (only after it): on lavapipe such an
// inner loop made the samples 5% too bright in the furnace (issue 61; the lavapipe faults of
// docs/known-issues.md).
struct Vertex {
    // The cell's slot (-1: none).
    slot: i32,
    albedo: vec3<f32>,
    // The path's throughput arriving at the vertex, and the light it had gathered before it.
    throughput: vec3<f32>,
    light_before: vec3<f32>,
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    var counts = no_counts();
    let block = hash_params.block;
    let blocks = (frame.size + vec2<u32>(block - 1u)) / block;
    if gid.x < blocks.x && gid.y < blocks.y {
        var rng = rng_init(gid.xy, frame.sample_offset, STREAM_HASH_UPDATE, frame.seed);
        let u = rand_pair(&rng);
        let px = min(gid.xy * block + vec2<u32>(u * f32(block)), frame.size - vec2<u32>(1u));
        let s = current_surface(px.y * frame.size.x + px.x);
        if s.pos.w > 0.5 {
            var v: array<Vertex, 6>;
            for (var k = 0u; k < MAX_VERTICES; k++) {
                v[k] = Vertex(-1, vec3<f32>(1.0), vec3<f32>(0.0), vec3<f32>(0.0));
            }
            var surf = primary_hit_surface(s);
            var wo = s.wo_dist.xyz;
            let p_sky = nee_sky_share();
            var throughput = vec3<f32>(1.0);
            var light = vec3<f32>(0.0);
            var recorded = 0u;
            for (var depth = 0u; depth < SAFETY_MAX_BOUNCES; depth++) {
                if depth < MAX_VERTICES {
                    let albedo = cache_albedo(surf.material, max(dot(surf.normal, wo), 0.0));
                    var slot = -1;
                    // A channel the path or the albedo carries nothing in cannot be divided back
                    // out; a smooth surface's light depends on the view (not cached).
                    if min(albedo.x, min(albedo.y, albedo.z)) >= MIN_ALBEDO && min(throughput.x, min(throughput.y, throughput.z)) > 0.0 && cacheable(surf.material) {
                        slot = insert_slot(cell_key(surf.position, surf.geo_normal));
                    }
                    v[depth] = Vertex(slot, albedo, throughput, light);
                    recorded = depth + 1u;
                }
                let direct = next_event(surf, wo, &rng, p_sky, true, 1u);
                counts[RAY_SHADOW] += direct.shadow_rays;
                light += throughput * direct.radiance;
                let st = path_step(surf, wo, p_sky, &rng);
                if st.rays == 0u {
                    break;
                }
                counts[RAY_CACHE] += st.rays;
                throughput *= st.weight;
                light += throughput * st.light;
                if !st.hit {
                    break;
                }
                if depth + 1u >= RR_START_DEPTH {
                    let q = min(max_component(throughput), 0.95);
                    if q <= 0.0 || rand(&rng) >= q {
                        break;
                    }
                    throughput /= q;
                }
                surf = st.next;
                wo = -st.dir;
            }
            for (var k = 0u; k < recorded; k++) {
                let x = v[k];
                if x.slot >= 0 {
                    add_sample(u32(x.slot), (light - x.light_before) / (x.throughput * x.albedo), rand(&rng));
                }
            }
        }
    }
    flush_counts(local_index, counts);
}
