// Queries for tests and tools (never part of a frame), `query_mode`:
// 0: SDF at points: in queries[2i].xyz (queries[2i + 1] = (level, 1) to read that level rather
//    than the finest holding the point), out queries[2i + 1] = (distance, object, level, 0);
// 1: SDF sphere trace of rays (origin queries[2i].xyz, direction queries[2i + 1].xyz), from the
//    origin itself with no surface bias and no expand (the bare field): out queries[2i] = (t, hit, steps, level);
// 4: the same with the expand the technique traces with (no surface bias: the caller places the origin);
// 2: the same rays through the BVH: out queries[2i] = (t, hit, 0, 0), queries[2i + 1] = the hit
//    triangle's normal;
// 3: a ray as the cache probes and the gather trace it, in the `tracing` mode, from surface
//    point queries[2i].xyz with normal queries[2i + 1].xyz, cosine direction hashed from i:
//    out queries[2i] = (t, hit, back face, card weight), queries[2i + 1] = (luminance of the
//    reflected radiance the hit brings back, best card or -1, object, answered by: 0 nothing,
//    1 cards, 2 voxel lighting);
// 5: the same rays, both answers apart: out queries[2i] = (t, hit, back face, voxel lighting
//    weight), queries[2i + 1] = (luminance of the voxel lighting, of the cards, card weight, 0);
// 6: mode 3's rays through the BVH whatever the `tracing` mode, shaded from the cards with the
//    BVH's depth tolerance (the same cache, traced exactly): out as mode 3.
#import gilab::bvh::{trace_closest, NO_HIT}
#import gilab::scene::tri_geom
#import gilab::math::{to_world, luminance}
#import gilab::sampling::sample_cosine_hemisphere
#import gilab::rng::{rng_init, rand_pair, STREAM_LUMEN_QUERY}
#import gilab::surface_cache::cache_reflected
#import gilab::tracing::{params, sdf_distance, sdf_object, sdf_trace, finest_level, trace_scene, trace_bvh_mode, hit_cache_sample, hit_light, TraceHit, voxel_lighting, EMPTY}

// Group 1 of the query pipeline only (it has no frame group): inputs in, answers out.
@group(1) @binding(0) var<storage, read_write> queries: array<vec4<f32>>;

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if i >= params.query_count {
        return;
    }
    let a = queries[2u * i].xyz;
    let b = queries[2u * i + 1u].xyz;
    switch params.query_mode {
        case 0u: {
            // b.y > 0.5: read level b.x instead of the finest one holding the point.
            let l = select(finest_level(a), u32(b.x), b.y > 0.5);
            var object = 0xffffu;
            var dist = 1e30;
            if l < params.levels_built {
                object = sdf_object(l, a);
                dist = sdf_distance(l, a);
            }
            queries[2u * i + 1u] = vec4<f32>(dist, f32(object), f32(l), 0.0);
        }
        case 1u, 4u: {
            let h = sdf_trace(a, b, 1e30, false, params.query_mode == 4u, 0.0);
            queries[2u * i] = vec4<f32>(h.t, select(0.0, 1.0, h.hit), f32(h.steps), f32(h.level));
        }
        case 3u, 5u, 6u: {
            var rng = rng_init(vec2<u32>(i, 0u), 0u, STREAM_LUMEN_QUERY, 1u);
            let dir = to_world(sample_cosine_hemisphere(rand_pair(&rng)), b);
            var h: TraceHit;
            if params.query_mode == 6u {
                h = trace_bvh_mode(a, b, dir, 1e30);
            } else {
                h = trace_scene(a, b, dir, 1e30);
            }
            var weight = 0.0;
            var card = -1.0;
            var light = vec4<f32>(0.0);
            var voxel = vec4<f32>(0.0);
            var cards = 0.0;
            if h.hit && !h.back_face {
                let s = hit_cache_sample(h);
                weight = s.weight;
                card = select(f32(s.best_card), -1.0, s.best_card == EMPTY);
                cards = luminance(cache_reflected(s));
                voxel = voxel_lighting(h.position, h.normal, h.level, h.object);
            }
            if params.query_mode == 6u {
                light = vec4<f32>(vec3<f32>(cards), select(0.0, 1.0, weight > 1e-4));
            } else if h.hit {
                light = hit_light(h);
            }
            let flags = vec3<f32>(h.t, select(0.0, 1.0, h.hit), select(0.0, 1.0, h.back_face));
            if params.query_mode != 5u {
                queries[2u * i] = vec4<f32>(flags, weight);
                queries[2u * i + 1u] = vec4<f32>(luminance(light.xyz), card, f32(h.object), light.w);
            } else {
                queries[2u * i] = vec4<f32>(flags, voxel.w);
                queries[2u * i + 1u] = vec4<f32>(luminance(voxel.xyz), cards, weight, 0.0);
            }
        }
        default: {
            let h = trace_closest(a, b, 0.0, 1e30);
            queries[2u * i] = vec4<f32>(h.t, select(0.0, 1.0, h.tri != NO_HIT), 0.0, 0.0);
            if h.tri != NO_HIT {
                let g = tri_geom[h.tri];
                queries[2u * i + 1u] = vec4<f32>(normalize(cross(g.edge_b.xyz, g.edge_c.xyz)), 0.0);
            }
        }
    }
}
