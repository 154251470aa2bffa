// Next-event estimation shared by techniques that shade a point with one light sample: one light
// picked by power from the shared light pool, one shadow ray through the BVH.
#define_import_path gilab::nee

#import gilab::brdf::{Surface, bsdf_eval}
#import gilab::scene::light_pool
#import gilab::lights::{LightSample, sample_light_at, light_shadow_ray}
#import gilab::ray::unoccluded

// Next-event estimation of one light picked by power (the shared light pool), one shadow ray.
struct Direct {
    radiance: vec3<f32>,
    shadow_rays: u32,
}

fn direct_light(p: vec3<f32>, n_geo: vec3<f32>, n: vec3<f32>, m: Surface, wo: vec3<f32>, u_select: f32, u: vec2<f32>) -> Direct {
    if light_pool.count == 0u {
        return Direct(vec3<f32>(0.0), 0u);
    }
    return shade_light_sample(p, n_geo, n, m, wo, sample_light_at(p, n_geo, u_select, u));
}

// One light sample taken at p (its pdf in solid angle, as `sample_light` gives it), shaded with
// the BSDF and one shadow ray. The caches' light samplers share it (gilab::cache_light).
fn shade_light_sample(p: vec3<f32>, n_geo: vec3<f32>, n: vec3<f32>, m: Surface, wo: vec3<f32>, ls: LightSample) -> Direct {
    var out = Direct(vec3<f32>(0.0), 0u);
    if !ls.valid || ls.pdf <= 0.0 || dot(ls.wi, n_geo) <= 0.0 {
        return out;
    }
    let e = bsdf_eval(m, n, wo, ls.wi);
    if !any(e.f > vec3<f32>(0.0)) {
        return out;
    }
    out.shadow_rays = 1u;
    if unoccluded(light_shadow_ray(p, n_geo, ls)) {
        out.radiance = e.f * max(dot(n, ls.wi), 0.0) * ls.radiance / ls.pdf;
    }
    return out;
}
