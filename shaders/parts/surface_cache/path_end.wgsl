// How a GI sample path ends in the surface cache (`gi_terminate = "lumen-cards"`,
// src/parts/surface_cache/): direct light by NEE at full weight (no BSDF-sampled continuation
// to share it with), every further bounce from the cache's indirect irradiance at the hit,
// reflected by its albedo. The cache's direct light is not used: NEE at the hit is per pixel
// and unbiased, the cache's one power-sampled light per texel is coarse.
#define_import_path gilab::surface_cache_path_end

#import gilab::path_end
#import gilab::math::INV_PI
#import gilab::rng::Rng
#import gilab::surface_point::HitSurface
#import gilab::surface_cache::cache_at_hit
#import gilab::path_vertex::{PathEnd, next_event}

override fn gilab::path_end::end_path(surf: HitSurface, wo: vec3<f32>, tri: u32, t: f32, throughput: vec3<f32>, p_sky: f32, candidates: u32, rng: ptr<function, Rng>) -> PathEnd {
    let direct = next_event(surf, wo, rng, p_sky, false, candidates);
    var e = PathEnd(true, throughput * direct.radiance, vec3<f32>(0.0), direct.shadow_rays, 0u, 0u);
    let c = cache_at_hit(tri, surf.position, surf.geo_normal, t);
    if c.weight > 1e-4 {
        e.indirect = throughput * c.albedo * c.indirect * INV_PI;
    }
    return e;
}
