// One bounce of the hash cache's two path loops (the update paths, update.wgsl, and the
// hash-cache technique's pixel paths, shaders/hash_cache/shade.wgsl), as the reference's
// gilab::path takes it: a BSDF sample, its ray, and the light the ray finds (the sky, or the
// emission of its hit), weighted by the power heuristic against the NEE that could have picked
// it.
#define_import_path gilab::hash_cache_path_step

#import gilab::rng::{Rng, rand, rand_pair}
#import gilab::ray::spawn_ray_origin
#import gilab::bvh::{trace_closest, NO_HIT}
#import gilab::surface::hit_surface
#import gilab::surface_point::HitSurface
#import gilab::brdf::bsdf_sample
#import gilab::lights::{triangle_emission, triangle_light_pdf}
#import gilab::sky::{sky_radiance, sky_pdf}
#import gilab::sampling::power_heuristic

struct PathStep {
    // Rays traced (0: no valid BSDF sample; the path ends before this bounce).
    rays: u32,
    // The ray hit a surface (`next`, at distance `t`); false: it left the scene.
    hit: bool,
    // The BSDF sample: f cos / pdf, its pdf, whether its lobe was a delta.
    weight: vec3<f32>,
    pdf: f32,
    is_delta: bool,
    dir: vec3<f32>,
    t: f32,
    // Light arriving along the ray, MIS-weighted, before the sample's weight.
    light: vec3<f32>,
    next: HitSurface,
}

fn path_step(surf: HitSurface, wo: vec3<f32>, p_sky: f32, rng: ptr<function, Rng>) -> PathStep {
    var out = PathStep(0u, false, vec3<f32>(0.0), 0.0, false, vec3<f32>(0.0), 0.0, vec3<f32>(0.0), surf);
    let bs = bsdf_sample(surf.material, surf.normal, wo, rand(rng), rand_pair(rng));
    // Directions below the geometric surface would leak through thin walls.
    if !bs.valid || dot(bs.wi, surf.geo_normal) <= 0.0 {
        return out;
    }
    out.rays = 1u;
    out.weight = bs.weight;
    out.pdf = bs.pdf;
    out.is_delta = bs.is_delta;
    out.dir = bs.wi;
    let origin = spawn_ray_origin(surf.position, surf.geo_normal, bs.wi);
    let hit = trace_closest(origin, bs.wi, 0.0, 1e30);
    if hit.tri == NO_HIT {
        var w = 1.0;
        if !bs.is_delta && p_sky > 0.0 {
            w = power_heuristic(bs.pdf, p_sky * sky_pdf(bs.wi));
        }
        out.light = sky_radiance(bs.wi) * w;
        return out;
    }
    out.hit = true;
    out.t = hit.t;
    out.next = hit_surface(origin, bs.wi, hit);
    let le = triangle_emission(hit.tri, hit.bary, -bs.wi);
    if any(le > vec3<f32>(0.0)) {
        var w = 1.0;
        if !bs.is_delta {
            w = power_heuristic(bs.pdf, (1.0 - p_sky) * triangle_light_pdf(hit.tri, bs.wi, hit.t, surf.position, surf.geo_normal));
        }
        out.light = le * w;
    }
    return out;
}
