// Where a cache picks the light that lights one of its points (a Lumen card texel, a surfel
// ray's hit): the one place `cache_direct` is plugged in. By power from the shared light pool
// (`cache_direct = "power"`), from the world-space ReGIR clipmap when the pipeline sets
// CACHE_REGIR, its bindings at WORLD_REGIR_GROUP (`cache_direct = "regir"`;
// src/parts/world_regir.rs), or by a reservoir over RESERVOIR_CANDIDATES power-sampled lights,
// one winner resampled by its unshadowed contribution at the point (CACHE_RESERVOIR,
// `cache_direct = "reservoir"`: GIBS's light sampling at a surfel ray's hit, seed 001), or by
// the light tree at the point and its normal when the pipeline sets LIGHT_TREE
// (`cache_direct = "tree"`; a point's light reaches it only above its normal's plane, so the
// tree's importance may use either normal), or by a stochastic lightcut when the pipeline sets
// CACHE_LIGHTCUT to the cut's size (`cache_direct = "lightcut"`, with LIGHT_TREE). With
// CACHE_LIGHT_RAYS = N (`cache_light_rays` > 1, not with the lightcut) a point averages N
// independent samples of its strategy, one shadow ray each.
#define_import_path gilab::cache_light

#import gilab::rng::{Rng, rand, rand_pair}
#import gilab::brdf::{Surface, bsdf_eval}
#import gilab::math::luminance
#import gilab::lights::{LightSample, sample_light_at, no_light_sample}
#import gilab::nee::{Direct, shade_light_sample}
#ifdef CACHE_REGIR
#import gilab::world_regir::world_regir_light
#endif
#ifdef CACHE_LIGHTCUT
#import gilab::scene::{light_pool, light_at}
#import gilab::sampling::sample_triangle
#import gilab::lights::{eval_light_chosen, select_light_in_class}
#import gilab::light_tree::{tree_node, lightcut_error, tree_descend, TREE_ONE_MINUS_EPSILON}
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

#ifdef CACHE_LIGHTCUT
// Nodes in the cut (`cache_light_rays`; the seed uses 2-8): shadow rays per point.
const LIGHTCUT_SIZE: u32 = #{CACHE_LIGHTCUT};
// Splits growing the cut may try (LightTree's LIGHTCUT_STEPS).
const LIGHTCUT_STEPS: u32 = 64u;

// Stochastic lightcuts (Yuksel, HPG 2019; GIBS's "lightcut 4", seed 001): a cut of at most
// LIGHTCUT_SIZE nodes through the light tree, grown from the root by splitting the interior node
// of largest error bound at p (lightcut_error; a child that cannot reach p leaves the cut), then one stochastic
// descent below each cut node, one light sample and one shadow ray each. The cut's nodes hold
// every local light that can reach p exactly once, so the sum of their estimates is unbiased.
// Directional lights, outside the tree, add one sample of their own. Mirrors
// LightTree::lightcut and LightTree::sample_from.
fn lightcut_direct(p: vec3<f32>, n_geo: vec3<f32>, n: vec3<f32>, m: Surface, wo: vec3<f32>, rng: ptr<function, Rng>) -> Direct {
    var out = Direct(vec3<f32>(0.0), 0u);
    var cut_node: array<u32, LIGHTCUT_SIZE>;
    var cut_weight: array<f32, LIGHTCUT_SIZE>;
    var count = 0u;
    if light_pool.local_count > 0u {
        let w = lightcut_error(tree_node(0u), p, n);
        if w > 0.0 {
            cut_node[0] = 0u;
            cut_weight[0] = w;
            count = 1u;
        }
    }
    for (var step = 0u; step < LIGHTCUT_STEPS && count < LIGHTCUT_SIZE; step++) {
        var best = LIGHTCUT_SIZE;
        for (var k = 0u; k < count; k++) {
            if !tree_node(cut_node[k]).leaf && (best == LIGHTCUT_SIZE || cut_weight[k] > cut_weight[best]) {
                best = k;
            }
        }
        if best == LIGHTCUT_SIZE {
            break;
        }
        let at = cut_node[best];
        let c0 = at + 1u;
        let c1 = tree_node(at).index;
        let w0 = lightcut_error(tree_node(c0), p, n);
        let w1 = lightcut_error(tree_node(c1), p, n);
        if w0 > 0.0 && w1 > 0.0 {
            cut_node[best] = c0;
            cut_weight[best] = w0;
            cut_node[count] = c1;
            cut_weight[count] = w1;
            count += 1u;
        } else if w0 > 0.0 {
            cut_node[best] = c0;
            cut_weight[best] = w0;
        } else if w1 > 0.0 {
            cut_node[best] = c1;
            cut_weight[best] = w1;
        } else {
            count -= 1u;
            cut_node[best] = cut_node[count];
            cut_weight[best] = cut_weight[count];
        }
    }
    for (var k = 0u; k < count; k++) {
        let t = tree_descend(cut_node[k], p, n, rand(rng));
        let b = sample_triangle(rand_pair(rng));
        if t.pmf > 0.0 {
            let d = shade_light_sample(p, n_geo, n, m, wo, eval_light_chosen(t.light, b, p, t.pmf));
            out.radiance += d.radiance;
            out.shadow_rays += d.shadow_rays;
        }
    }
    if light_pool.local_count < light_pool.count {
        let i = select_light_in_class(min(rand(rng), TREE_ONE_MINUS_EPSILON), light_pool.local_count, light_pool.count);
        let d = shade_light_sample(p, n_geo, n, m, wo, eval_light_chosen(i, sample_triangle(rand_pair(rng)), p, light_at(i).class_pmf));
        out.radiance += d.radiance;
        out.shadow_rays += d.shadow_rays;
    }
    return out;
}
#endif

// One estimate of the direct light at a cache point by the cache's light sampler.
fn cache_direct_estimate(p: vec3<f32>, n_geo: vec3<f32>, n: vec3<f32>, m: Surface, wo: vec3<f32>, rng: ptr<function, Rng>) -> Direct {
#ifdef CACHE_LIGHTCUT
    return lightcut_direct(p, n_geo, n, m, wo, rng);
#else
#ifdef CACHE_RESERVOIR
    return shade_light_sample(p, n_geo, n, m, wo, reservoir_light_sample(p, n, m, wo, rng));
#else
    return shade_light_sample(p, n_geo, n, m, wo, cache_light_sample(p, n, rng));
#endif
#endif
}

// Next-event estimation at a cache point with the cache's light sampler: one estimate (one
// shadow ray, or a lightcut's), or the mean of CACHE_LIGHT_RAYS of them.
fn cache_direct_light(p: vec3<f32>, n_geo: vec3<f32>, n: vec3<f32>, m: Surface, wo: vec3<f32>, rng: ptr<function, Rng>) -> Direct {
#ifdef CACHE_LIGHT_RAYS
    var out = Direct(vec3<f32>(0.0), 0u);
    let rays: u32 = #{CACHE_LIGHT_RAYS};
    for (var i = 0u; i < rays; i++) {
        let d = cache_direct_estimate(p, n_geo, n, m, wo, rng);
        out.radiance += d.radiance;
        out.shadow_rays += d.shadow_rays;
    }
    out.radiance /= f32(rays);
    return out;
#else
    return cache_direct_estimate(p, n_geo, n, m, wo, rng);
#endif
}
