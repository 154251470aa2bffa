// What happens at a vertex of a path, shared by the path tracer (gilab::path), ReSTIR PT and
// the caches a path ends in (their end modules, gilab::path_end): next-event estimation of one
// light, and what a cache hands back when a path ends in it.
#define_import_path gilab::path_vertex

#import gilab::ray::{INFINITE_DISTANCE, unoccluded}
#import gilab::rng::{Rng, rand, rand_pair}
#import gilab::scene::light_pool
#import gilab::lights::{LightSample, no_light_sample, sample_light_at, light_shadow_ray}
#import gilab::sky::{sky_radiance, sample_sky, sky_nee}
#import gilab::brdf::bsdf_eval
#import gilab::sampling::power_heuristic
#import gilab::math::luminance
#import gilab::surface_point::HitSurface

// Probability that NEE samples the environment map rather than the light pool when both exist.
const SKY_NEE_SHARE: f32 = 0.5;

struct NextEvent {
    radiance: vec3<f32>,
    shadow_rays: u32,
}

// A path's end in a cache at a hit (gilab::path_end): `ended` when the cache covers the hit
// (the path stops there with `direct` and `indirect` added, in that order, each already
// multiplied by the path's throughput); otherwise the path is traced on to its end. `outcome`:
// the lookup's outcome for gilab::counters::count_cache_lookup (0: none).
struct PathEnd {
    ended: bool,
    direct: vec3<f32>,
    indirect: vec3<f32>,
    shadow_rays: u32,
    indirect_rays: u32,
    outcome: u32,
}

fn path_not_ended(outcome: u32) -> PathEnd {
    return PathEnd(false, vec3<f32>(0.0), vec3<f32>(0.0), 0u, 0u, outcome);
}

// Probability that NEE samples the sky rather than the light pool (0: the pool only, as
// without an environment map; 1: the map alone when the pool is empty).
fn nee_sky_share() -> f32 {
    if !sky_nee() {
        return 0.0;
    }
    return select(1.0, SKY_NEE_SHARE, light_pool.count > 0u);
}

// One NEE light sample at p (geometric normal n, facing the side light is gathered on) from
// three random numbers: the sky with probability p_sky (importance sampled), else one light of
// the pool by its power; pdf and area_pdf include that choice. By power, the light point depends
// on the numbers only, never on p (ReSTIR PT's random replay relies on it); a pipeline with the
// light tree (LIGHT_TREE) picks by p and n.
fn pick_nee_light(p: vec3<f32>, n: vec3<f32>, u_sel: f32, u_light: vec2<f32>, p_sky: f32) -> LightSample {
    if u_sel < p_sky {
        let ss = sample_sky(u_light);
        let le_sky = sky_radiance(ss.dir);
        return LightSample(ss.dir, INFINITE_DISTANCE, le_sky, p_sky * ss.pdf, p_sky * ss.pdf, 1.0, false, ss.pdf > 0.0 && any(le_sky > vec3<f32>(0.0)), vec3<f32>(0.0));
    }
    if light_pool.count == 0u {
        return no_light_sample();
    }
    var ls = sample_light_at(p, n, (u_sel - p_sky) / (1.0 - p_sky), u_light);
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
        ls = pick_nee_light(surf.position, surf.geo_normal, u_sel, u_light, p_sky);
        big_w = 1.0 / max(ls.pdf, 1e-30);
    } else if light_pool.count > 0u {
        var w_sum = 0.0;
        var chosen_target = 0.0;
        for (var i = 0u; i < candidates; i++) {
            var c = sample_light_at(surf.position, surf.geo_normal, rand(rng), rand_pair(rng));
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
