// Where a cache picks the light that lights one of its points (a Lumen card texel, a surfel
// ray's hit): the one place `cache_direct` is plugged in. By power from the shared light pool
// (`cache_direct = "power"`), from the world-space ReGIR clipmap when the pipeline sets
// CACHE_REGIR, its bindings at WORLD_REGIR_GROUP (`cache_direct = "regir"`;
// src/parts/world_regir.rs), or by a reservoir over RESERVOIR_CANDIDATES power-sampled lights,
// one winner resampled by its unshadowed contribution at the point (CACHE_RESERVOIR,
// `cache_direct = "reservoir"`: GIBS's light sampling at a surfel ray's hit, seed 001), or by
// the light tree at the point and its normal when the pipeline sets LIGHT_TREE
// (`cache_direct = "tree"`; a point's light reaches it only above its normal's plane, so the
// tree's importance may use either normal).
#define_import_path gilab::cache_light

#import gilab::rng::{Rng, rand, rand_pair}
#import gilab::brdf::{Surface, bsdf_eval}
#import gilab::math::luminance
#import gilab::lights::{LightSample, sample_light_at, no_light_sample}
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
    return sample_light_at(p, n, rand(rng), rand_pair(rng));
}

// Candidates of `cache_direct = "reservoir"` (the seed's 4-8; src/parts/world_regir.rs).
const RESERVOIR_CANDIDATES: u32 = 8u;

// Resampled importance sampling over RESERVOIR_CANDIDATES lights drawn by power: the winner by
// its unshadowed contribution f * Le * cos, returned with the pdf whose reciprocal is RIS's
// contribution weight (w_sum / (M * target)), so one shadow ray shades it unbiasedly.
fn reservoir_light_sample(p: vec3<f32>, n: vec3<f32>, m: Surface, wo: vec3<f32>, rng: ptr<function, Rng>) -> LightSample {
    var chosen = no_light_sample();
    var w_sum = 0.0;
    var chosen_target = 0.0;
    for (var i = 0u; i < RESERVOIR_CANDIDATES; i++) {
        let c = sample_light_at(p, n, rand(rng), rand_pair(rng));
        if !c.valid || c.pdf <= 0.0 {
            continue;
        }
        let t = luminance(bsdf_eval(m, n, wo, c.wi).f * c.radiance) * max(dot(n, c.wi), 0.0);
        if t <= 0.0 {
            continue;
        }
        w_sum += t / c.pdf;
        if rand(rng) * w_sum < t / c.pdf {
            chosen = c;
            chosen_target = t;
        }
    }
    if chosen_target <= 0.0 {
        return no_light_sample();
    }
    chosen.pdf = chosen_target * f32(RESERVOIR_CANDIDATES) / w_sum;
    return chosen;
}

// Next-event estimation at a cache point with the cache's light sampler and one shadow ray.
fn cache_direct_light(p: vec3<f32>, n_geo: vec3<f32>, n: vec3<f32>, m: Surface, wo: vec3<f32>, rng: ptr<function, Rng>) -> Direct {
#ifdef CACHE_RESERVOIR
    return shade_light_sample(p, n_geo, n, m, wo, reservoir_light_sample(p, n, m, wo, rng));
#else
    return shade_light_sample(p, n_geo, n, m, wo, cache_light_sample(p, n, rng));
#endif
}
