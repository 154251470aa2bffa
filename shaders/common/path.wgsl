// Path tracing shared by the reference and by ReSTIR GI's sample paths: NEE of one light
// (power heuristic against BSDF sampling; gilab::path_vertex), GGX/Lambert BSDF sampling,
// Russian roulette, and (composed with GI_TERMINATE) the end of a path in a cache
// (gilab::path_end).
// With an environment map as the sky, NEE picks the map (luminance importance sampling) with
// probability SKY_NEE_SHARE, the light pool otherwise (the map alone when the pool is empty);
// both sides of the power heuristic use that combined NEE pdf. A constant sky is reached by
// BSDF sampling only, as before.
#define_import_path gilab::path

#import gilab::math::max_component
#import gilab::ray::spawn_ray_origin
#import gilab::rng::{Rng, rand, rand_pair}
#import gilab::bvh::{trace_closest, NO_HIT}
#import gilab::surface::hit_surface
#import gilab::brdf::{Surface, bsdf_sample}
#import gilab::lights::{triangle_emission, triangle_light_pdf}
#import gilab::sky::{sky_radiance, sky_pdf}
#import gilab::sampling::power_heuristic
#import gilab::path_vertex::{next_event, nee_sky_share}
#ifdef GI_TERMINATE
#import gilab::path_end::end_path
#endif

// Hard safety cap on path length. With Russian roulette survival <= 0.95 the chance of
// reaching it is below 0.95^1021 ~ 1e-23, so "unbounded" stays unbiased in practice.
const SAFETY_MAX_BOUNCES: u32 = 1024u;
const RR_START_DEPTH: u32 = 3u;

struct PathResult {
    // Radiance arriving at the origin along the first direction.
    radiance: vec3<f32>,
    // The part of it that max_depth 1 (direct light) and 2 (one bounce) would return: the same
    // path's contributions up to that depth (Russian roulette starts later), so one unbounded
    // path gives all three estimates (the reference's `depth_images`).
    radiance_direct: vec3<f32>,
    radiance_one_bounce: vec3<f32>,
    first_rays: u32,
    shadow_rays: u32,
    indirect_rays: u32,
    // The first hit (w = 1) or a miss (w = 0), and its geometric normal facing the ray.
    first_hit: vec4<f32>,
    first_normal: vec3<f32>,
    // The first hit's triangle (BVH order), NO_HIT on a miss: reuse follows it when it moves.
    first_tri: u32,
    // Where the path looked its cache up (a cache that reports it: the surfels): the outcome for
    // gilab::counters::count_cache_lookup, 0 without a lookup.
    cache_outcome: u32,
}


// How a path samples light and where it may go past its end. The reference and the surfels'
// rays use `plain_path()`; ReSTIR GI's sample paths take theirs from its parameters.
struct PathOptions {
    // Light-pool candidates per NEE (RIS, the seed's initial sampling loop at every hit); 1 is
    // one light by the pool's own pdf.
    light_candidates: u32,
    // Hits on specular surfaces (roughness below `specular_max_roughness`) a path may go
    // through past the hit it would end at (`max_depth`, or a cache): the seed's multi-bounce
    // specular paths (funhouse mirrors).
    specular_bounces: u32,
    specular_max_roughness: f32,
}

fn plain_path() -> PathOptions {
    return PathOptions(1u, 0u, 0.0);
}

// Whether a hit continues a specular chain: GGX alpha = roughness^2.
fn specular_vertex(m: Surface, o: PathOptions) -> bool {
    return m.alpha < o.specular_max_roughness * o.specular_max_roughness;
}




// Adds a contribution that a path limited to `depth` bounces (max_depth = depth, depth >= 1)
// would include, to the full radiance and to the depth-limited sums it belongs to.
fn add_contribution(out: ptr<function, PathResult>, c: vec3<f32>, depth: u32) {
    (*out).radiance += c;
    if depth <= 1u {
        (*out).radiance_direct += c;
    }
    if depth <= 2u {
        (*out).radiance_one_bounce += c;
    }
}

// Traces a path from `origin` along `dir`. `max_bounces` 0 = unbounded. With the shader def
// GI_TERMINATE (ReSTIR GI's `gi_terminate` naming a cache) the path ends at hit `max_depth` in
// the cache the caller composed it with (gilab::path_end, the cache's lookup bound by the
// caller), where the cache covers the hit, and is traced on to the end where it does not. With
// `skip_first_emission` the emission of the first hit is left out (ReSTIR GI: direct light
// from emitters is ReSTIR DI's job).
fn trace_path(origin_in: vec3<f32>, dir_in: vec3<f32>, rng: ptr<function, Rng>, max_depth: u32, skip_first_emission: bool, options: PathOptions) -> PathResult {
    var out = PathResult(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0), 0u, 0u, 0u, vec4<f32>(0.0), vec3<f32>(0.0), NO_HIT, 0u);
    var origin = origin_in;
    var dir = dir_in;
    var throughput = vec3<f32>(1.0);
    var prev_pdf = 0.0;
    var prev_delta = true;
    // The last vertex's point and geometric normal, where its NEE picked a light: the light
    // tree's pdf of an emitter hit depends on them.
    var prev_position = origin_in;
    var prev_normal = vec3<f32>(0.0);
    var max_bounces = select(SAFETY_MAX_BOUNCES, max_depth, max_depth > 0u);
    var specular_left = options.specular_bounces;
    // The hit a path ends at: the one that reads a cache, or (traced paths) the last one,
    // which only adds its emission.
    var end_offset = 0u;
#ifdef GI_TERMINATE
    end_offset = 1u;
#endif
    // Probability that NEE samples the sky (0: light pool only, as without an environment map).
    let p_sky = nee_sky_share();
    for (var depth = 0u; depth <= max_bounces; depth++) {
        let hit = trace_closest(origin, dir, 0.0, 1e30);
        if depth == 0u {
            out.first_rays += 1u;
        } else {
            out.indirect_rays += 1u;
        }
        if hit.tri == NO_HIT {
            var w = 1.0;
            if !prev_delta && p_sky > 0.0 {
                w = power_heuristic(prev_pdf, p_sky * sky_pdf(dir));
            }
            add_contribution(&out, throughput * sky_radiance(dir) * w, depth);
            break;
        }
        let surf = hit_surface(origin, dir, hit);
        if depth == 0u {
            out.first_hit = vec4<f32>(surf.position, 1.0);
            out.first_normal = surf.geo_normal;
            out.first_tri = hit.tri;
        }
        let le = triangle_emission(hit.tri, hit.bary, -dir);
        if any(le > vec3<f32>(0.0)) && !(depth == 0u && skip_first_emission) {
            var w = 1.0;
            if !prev_delta {
                w = power_heuristic(prev_pdf, (1.0 - p_sky) * triangle_light_pdf(hit.tri, dir, hit.t, prev_position, prev_normal));
            }
            add_contribution(&out, throughput * le * w, depth);
        }
        let wo = -dir;
        let m = surf.material;
        // A specular hit where the path would end goes on one more hit (the reflection of a
        // reflection is not in any diffuse cache), `specular_bounces` times at most.
        if specular_left > 0u && depth + end_offset >= max_bounces && max_bounces < SAFETY_MAX_BOUNCES && specular_vertex(m, options) {
            specular_left -= 1u;
            max_bounces += 1u;
        }
        if depth == max_bounces {
            break;
        }
#ifdef GI_TERMINATE
        // The path ends in the cache its reader composed it with (gilab::path_end: each
        // cache's own module says what a path does at its last hit). Where the cache does not
        // cover the hit, the path is traced on to its end, unbiased there.
        if depth + 1u >= max_bounces {
            let e = end_path(surf, wo, hit.tri, hit.t, throughput, p_sky, options.light_candidates, rng);
            out.cache_outcome = e.outcome;
            out.shadow_rays += e.shadow_rays;
            out.indirect_rays += e.indirect_rays;
            if e.ended {
                out.radiance += e.direct;
                out.radiance += e.indirect;
                break;
            }
            max_bounces = SAFETY_MAX_BOUNCES;
        }
#endif
        let direct = next_event(surf, wo, rng, p_sky, true, options.light_candidates);
        out.shadow_rays += direct.shadow_rays;
        // NEE at this vertex belongs to paths one vertex longer: max_depth > depth.
        add_contribution(&out, throughput * direct.radiance, depth + 1u);
        // Continue the path by sampling the BRDF.
        let bs = bsdf_sample(m, surf.normal, wo, rand(rng), rand_pair(rng));
        // Directions below the geometric surface would leak through thin walls.
        if !bs.valid || dot(bs.wi, surf.geo_normal) <= 0.0 {
            break;
        }
        throughput *= bs.weight;
        prev_pdf = bs.pdf;
        prev_delta = bs.is_delta;
        prev_position = surf.position;
        prev_normal = surf.geo_normal;
        origin = spawn_ray_origin(surf.position, surf.geo_normal, bs.wi);
        dir = bs.wi;
        if depth + 1u >= RR_START_DEPTH {
            let q = min(max_component(throughput), 0.95);
            if q <= 0.0 || rand(rng) >= q {
                break;
            }
            throughput /= q;
        }
    }
    return out;
}
