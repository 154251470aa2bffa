// Where a cache picks the light that lights one of its points (a Lumen card texel, a surfel
// ray's hit): the one place `cache_direct` is plugged in. By power from the shared light pool
// (`cache_direct = "power"`), or from the world-space ReGIR clipmap when the pipeline sets
// CACHE_REGIR, its bindings at WORLD_REGIR_GROUP (`cache_direct = "regir"`;
// src/parts/world_regir.rs).
#define_import_path gilab::cache_light

#import gilab::rng::{Rng, rand, rand_pair}
#import gilab::brdf::Surface
#import gilab::lights::{LightSample, sample_light}
#import gilab::nee::{Direct, shade_light_sample}
#ifdef CACHE_REGIR
#import gilab::world_regir::world_regir_light
#endif

// A light sample for point p with shading normal n (used by the ReGIR lookup's target).
fn cache_light_sample(p: vec3<f32>, n: vec3<f32>, rng: ptr<function, Rng>) -> LightSample {
#ifdef CACHE_REGIR
    let r = world_regir_light(p, n, rng);
    if r.served {
        return r.sample;
    }
#endif
    return sample_light(p, rand(rng), rand_pair(rng));
}

// Next-event estimation at a cache point with the cache's light sampler and one shadow ray.
fn cache_direct_light(p: vec3<f32>, n_geo: vec3<f32>, n: vec3<f32>, m: Surface, wo: vec3<f32>, rng: ptr<function, Rng>) -> Direct {
    return shade_light_sample(p, n_geo, n, m, wo, cache_light_sample(p, n, rng));
}
