// Path tracing shared by the reference and by ReSTIR GI's sample paths: NEE of one light
// (power heuristic against BSDF sampling), GGX/Lambert BSDF sampling, Russian roulette.
// With an environment map as the sky, NEE picks the map (luminance importance sampling) with
// probability SKY_NEE_SHARE, the light pool otherwise (the map alone when the pool is empty);
// both sides of the power heuristic use that combined NEE pdf. A constant sky is reached by
// BSDF sampling only, as before.
#define_import_path gilab::path

#import gilab::math::max_component
#import gilab::ray::{spawn_ray_origin, unoccluded}
#import gilab::rng::{Rng, rand, rand_pair}
#import gilab::frame::frame
#import gilab::scene::light_pool
#import gilab::bvh::{trace_closest, NO_HIT}
#import gilab::surface::hit_surface
#import gilab::brdf::{Surface, bsdf_eval, bsdf_sample}
#import gilab::lights::{LightSample, no_light_sample, sample_light, light_shadow_ray, triangle_emission, triangle_light_pdf}
#import gilab::ray::INFINITE_DISTANCE
#import gilab::sky::{sky_radiance, sample_sky, sky_pdf, sky_nee}
#import gilab::sampling::power_heuristic
#import gilab::math::luminance
#import gilab::surface_point::HitSurface
#ifdef GI_TERMINATE_CACHE
#import gilab::math::INV_PI
#import gilab::surface_cache::cache_at_hit
#endif
#ifdef GI_TERMINATE_WORLD
#import gilab::math::INV_PI
#import gilab::scene::{materials, tri_material}
#import gilab::surface_cache::cache_at_hit
#import gilab::world_cache::{world_lookup, world_tmin_at}
#endif
#ifdef GI_TERMINATE_SURFELS
#import gilab::math::INV_PI
#import gilab::brdf::{diffuse_color, specular_albedo_average}
#import gilab::surfels::{gather, gather_covers, gather_outcome, gathered_irradiance, grid_center_for}
#endif

// Hard safety cap on path length. With Russian roulette survival <= 0.95 the chance of
// reaching it is below 0.95^1021 ~ 1e-23, so "unbounded" stays unbiased in practice.
const SAFETY_MAX_BOUNCES: u32 = 1024u;
const RR_START_DEPTH: u32 = 3u;
// Probability that NEE samples the environment map rather than the light pool when both exist.
const SKY_NEE_SHARE: f32 = 0.5;

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
    // Where the path looked its cache up (GI_TERMINATE_SURFELS): the outcome for
    // gilab::counters::count_cache_lookup, 0 without a lookup.
    cache_outcome: u32,
}

struct NextEvent {
    radiance: vec3<f32>,
    shadow_rays: u32,
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

// Probability that NEE samples the sky rather than the light pool (0: the pool only, as
// without an environment map; 1: the map alone when the pool is empty).
fn nee_sky_share() -> f32 {
    if !sky_nee() {
        return 0.0;
    }
    return select(1.0, SKY_NEE_SHARE, light_pool.count > 0u);
}

// One NEE light sample from three random numbers: the sky with probability p_sky (importance
// sampled), else one light of the pool by its power; pdf and area_pdf include that choice. The
// light point depends on the numbers only, never on p: ReSTIR PT's random replay relies on it.
fn pick_nee_light(p: vec3<f32>, u_sel: f32, u_light: vec2<f32>, p_sky: f32) -> LightSample {
    if u_sel < p_sky {
        let ss = sample_sky(u_light);
        let le_sky = sky_radiance(ss.dir);
        return LightSample(ss.dir, INFINITE_DISTANCE, le_sky, p_sky * ss.pdf, p_sky * ss.pdf, 1.0, false, ss.pdf > 0.0 && any(le_sky > vec3<f32>(0.0)), vec3<f32>(0.0));
    }
    if light_pool.count == 0u {
        return no_light_sample();
    }
    var ls = sample_light(p, (u_sel - p_sky) / (1.0 - p_sky), u_light);
    ls.pdf *= 1.0 - p_sky;
    ls.area_pdf *= 1.0 - p_sky;
    return ls;
}

// Next-event estimation at a path vertex (a pure mirror evaluates to 0 and traces no shadow
// ray): the sky with probability p_sky, else the light pool; ls.pdf includes that choice. With
// `mis` the sample is weighted against BSDF sampling (power heuristic), which the path's
// continuation does; without it (a path that ends here) it counts in full.
//
// From the pool, one light by the pool's pdf (`candidates` <= 1), or `candidates` of them
// resampled by their unshadowed contribution (RIS, ReSTIR DI's initial sampling without the
// reuse: the seed's light loop at every hit of a specular path), then one shadow ray either
// way. The MIS weight uses the chosen light's source pdf, as the BSDF side does for an emitter
// it hits: RIS estimates that weighted integrand without bias for any target that covers it,
// so the two weights still sum to one.
fn next_event(surf: HitSurface, wo: vec3<f32>, rng: ptr<function, Rng>, p_sky: f32, mis: bool, candidates: u32) -> NextEvent {
    var out = NextEvent(vec3<f32>(0.0), 0u);
    let u_sel = rand(rng);
    let u_light = rand_pair(rng);
    var ls = no_light_sample();
    // Contribution weight of `ls`: 1 / pdf for one sample, RIS's w_sum / (M target) otherwise.
    var big_w = 0.0;
    if u_sel < p_sky || (light_pool.count > 0u && candidates <= 1u) {
        ls = pick_nee_light(surf.position, u_sel, u_light, p_sky);
        big_w = 1.0 / max(ls.pdf, 1e-30);
    } else if light_pool.count > 0u {
        var w_sum = 0.0;
        var chosen_target = 0.0;
        for (var i = 0u; i < candidates; i++) {
            var c = sample_light(surf.position, rand(rng), rand_pair(rng));
            c.pdf *= 1.0 - p_sky;
            if !c.valid || c.pdf <= 0.0 || dot(c.wi, surf.geo_normal) <= 0.0 {
                continue;
            }
            let e = bsdf_eval(surf.material, surf.normal, wo, c.wi);
            let t = luminance(e.f * c.radiance) * max(dot(surf.normal, c.wi), 0.0);
            if t <= 0.0 {
                continue;
            }
            w_sum += t / c.pdf;
            if rand(rng) * w_sum < t / c.pdf {
                ls = c;
                chosen_target = t;
            }
        }
        if chosen_target > 0.0 {
            big_w = w_sum / (f32(candidates) * chosen_target);
        }
    }
    if ls.valid && ls.pdf > 0.0 && big_w > 0.0 && dot(ls.wi, surf.geo_normal) > 0.0 {
        let e = bsdf_eval(surf.material, surf.normal, wo, ls.wi);
        if any(e.f > vec3<f32>(0.0)) {
            out.shadow_rays = 1u;
            if unoccluded(light_shadow_ray(surf.position, surf.geo_normal, ls)) {
                let w = select(power_heuristic(ls.pdf, e.pdf), 1.0, ls.is_delta || !mis);
                out.radiance = e.f * dot(surf.normal, ls.wi) * ls.radiance * (w * big_w);
            }
        }
    }
    return out;
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
// GI_TERMINATE_CACHE (ReSTIR GI's `gi_terminate = "lumen-cards"`) the path ends in the surface
// cache at hit `max_depth` (bound at group SURFACE_CACHE_GROUP by the caller); with
// GI_TERMINATE_SURFELS (`"surfels"`) in the surfels' irradiance there (group SURFELS_GROUP)
// where surfels cover the hit, and is traced on to the end where none do; with
// GI_TERMINATE_WORLD (`"lumen-world"`) in Lumen's world radiance cache seen from there (group
// WORLD_CACHE_GROUP, beside the surface cache at SURFACE_CACHE_GROUP). With
// `skip_first_emission` the emission of the first hit is left out (ReSTIR GI: direct light
// from emitters is ReSTIR DI's job).
fn trace_path(origin_in: vec3<f32>, dir_in: vec3<f32>, rng: ptr<function, Rng>, max_depth: u32, skip_first_emission: bool, options: PathOptions) -> PathResult {
    var out = PathResult(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0), 0u, 0u, 0u, vec4<f32>(0.0), vec3<f32>(0.0), NO_HIT, 0u);
    var origin = origin_in;
    var dir = dir_in;
    var throughput = vec3<f32>(1.0);
    var prev_pdf = 0.0;
    var prev_delta = true;
    var max_bounces = select(SAFETY_MAX_BOUNCES, max_depth, max_depth > 0u);
    var specular_left = options.specular_bounces;
    // The hit a path ends at: the one that reads a cache, or (traced paths) the last one,
    // which only adds its emission.
    var end_offset = 0u;
#ifdef GI_TERMINATE_CACHE
    end_offset = 1u;
#endif
#ifdef GI_TERMINATE_WORLD
    end_offset = 1u;
#endif
#ifdef GI_TERMINATE_SURFELS
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
                w = power_heuristic(prev_pdf, (1.0 - p_sky) * triangle_light_pdf(hit.tri, dir, hit.t));
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
#ifdef GI_TERMINATE_CACHE
        // The path ends in the surface cache at this hit (src/parts/surface_cache/): direct
        // light by NEE at full weight (no BSDF-sampled continuation to share it with), every
        // further bounce from the cache's indirect irradiance, reflected by its albedo.
        if depth + 1u >= max_bounces {
            let direct = next_event(surf, wo, rng, p_sky, false, options.light_candidates);
            out.shadow_rays += direct.shadow_rays;
            out.radiance += throughput * direct.radiance;
            let c = cache_at_hit(hit.tri, surf.position, surf.geo_normal, hit.t);
            if c.weight > 1e-4 {
                out.radiance += throughput * c.albedo * c.indirect * INV_PI;
            }
            break;
        }
#endif
#ifdef GI_TERMINATE_WORLD
        // The path ends at this hit in Lumen's world radiance cache (src/parts/world_cache.rs),
        // read as a Lumen screen-probe ray reads it: NEE of the lights at full weight (the
        // cache holds the sky its probes saw, so NEE leaves the sky out); one BSDF-sampled
        // direction traced to the cache's TMin, where a hit reads the surface cache's reflected
        // light; past it the world probes around the ray's end, in its direction, marked read so
        // that they are traced; where none is traced yet the ray goes on to its end (surface
        // cache, or sky). Emitters the ray meets add nothing: NEE counted them.
        if depth + 1u >= max_bounces {
            let direct = next_event(surf, wo, rng, 0.0, false, options.light_candidates);
            out.shadow_rays += direct.shadow_rays;
            out.radiance += throughput * direct.radiance;
            let bs = bsdf_sample(m, surf.normal, wo, rand(rng), rand_pair(rng));
            if bs.valid && dot(bs.wi, surf.geo_normal) > 0.0 {
                let o = spawn_ray_origin(surf.position, surf.geo_normal, bs.wi);
                let reach = world_tmin_at(surf.position);
                var h = trace_closest(o, bs.wi, 0.0, reach);
                out.indirect_rays += 1u;
                var l = vec3<f32>(0.0);
                if h.tri == NO_HIT {
                    let w = world_lookup(o + bs.wi * reach, bs.wi, true);
                    if w.weight > 0.0 {
                        l = w.radiance;
                    } else {
                        h = trace_closest(o, bs.wi, reach, 1e30);
                        out.indirect_rays += 1u;
                        if h.tri == NO_HIT {
                            l = sky_radiance(bs.wi);
                        }
                    }
                }
                if h.tri != NO_HIT {
                    let s = hit_surface(o, bs.wi, h);
                    // The back of a single-sided surface (a ray that started inside geometry)
                    // gives no light, as in Lumen's own traces.
                    let double_sided = materials[tri_material(h.tri)].emissive.w > 0.5;
                    if s.front_face || double_sided {
                        let c = cache_at_hit(h.tri, s.position, s.geo_normal, h.t);
                        l = c.albedo * (c.direct + c.indirect) * INV_PI;
                    }
                }
                out.radiance += throughput * bs.weight * l;
            }
            break;
        }
#endif
#ifdef GI_TERMINATE_SURFELS
        // The path ends in the surfels where they cover this hit, as a surfel's own ray does:
        // NEE of the lights at full weight, and every further bounce from the surfels'
        // irradiance (which holds the sky their rays reached, so NEE leaves the sky out),
        // reflected by the diffuse albedo plus the specular layer's average albedo. Off screen
        // no surfel covers a hit: the path is traced on to the end, unbiased there.
        if depth + 1u >= max_bounces {
            let g = gather(surf.position, surf.normal, grid_center_for(frame.camera_pos.xyz), false);
            out.cache_outcome = gather_outcome(g, surf.position);
            if gather_covers(g) {
                let direct = next_event(surf, wo, rng, 0.0, false, options.light_candidates);
                out.shadow_rays += direct.shadow_rays;
                out.radiance += throughput * direct.radiance;
                let albedo = diffuse_color(m, max(dot(surf.normal, wo), 0.0)) + specular_albedo_average(m);
                out.radiance += throughput * albedo * gathered_irradiance(g) * INV_PI;
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
