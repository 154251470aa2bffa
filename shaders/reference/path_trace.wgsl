// Reference path tracer: progressive, unbiased; NEE + MIS (power heuristic) over emissive triangles and punctual lights, Russian roulette, Welford per-pixel mean and variance.
#import gilab::math::{max_component, is_finite_vec, offset_ray_origin}
#import gilab::rng::{Rng, rng_init, rand, rand_pair}
#import gilab::frame::{frame, camera_ray_dir, FLAG_NO_PRIMARY_EMISSION}
#import gilab::counters::{flush_counts, no_counts, RAY_CAMERA, RAY_SHADOW, RAY_INDIRECT, COUNT_INVALID_SAMPLES}
#import gilab::scene::light_pool
#import gilab::bvh::{trace_closest, trace_any, NO_HIT}
#import gilab::surface::hit_surface
#import gilab::brdf::{bsdf_eval, bsdf_sample}
#import gilab::lights::{sample_light, triangle_emission, triangle_light_pdf}
#import gilab::sampling::power_heuristic
#import gilab::accumulate::welford_add

// Which sample of the frame this dispatch traces (one path per invocation per dispatch).
struct DispatchSample {
    index: u32,
}
@group(1) @binding(4) var<uniform> dispatch_sample: DispatchSample;

// Per pixel: xyz = running mean radiance, w = sample count.
@group(1) @binding(2) var<storage, read_write> accum_mean: array<vec4<f32>>;
// Per pixel: xyz = Welford M2 (sum of squared deviations) per channel.
@group(1) @binding(3) var<storage, read_write> accum_m2: array<vec4<f32>>;

// Hard safety cap on path length. With Russian roulette survival <= 0.95 the chance of
// reaching it is below 0.95^1021 ~ 1e-23, so "unbounded" stays unbiased in practice.
const SAFETY_MAX_BOUNCES: u32 = 1024u;
const RR_START_DEPTH: u32 = 3u;

struct PathResult {
    radiance: vec3<f32>,
    camera_rays: u32,
    shadow_rays: u32,
    indirect_rays: u32,
}

fn trace_path(pixel: vec2<u32>, sample_index: u32) -> PathResult {
    var camera_rays = 0u;
    var shadow_rays = 0u;
    var indirect_rays = 0u;
    var rng = rng_init(pixel, sample_index, frame.seed);
    let jitter = rand_pair(&rng);
    var origin = frame.camera_pos.xyz;
    var dir = camera_ray_dir(vec2<f32>(pixel) + jitter);
    var throughput = vec3<f32>(1.0);
    var radiance = vec3<f32>(0.0);
    var prev_pdf = 0.0;
    var prev_delta = true;
    let max_bounces = select(SAFETY_MAX_BOUNCES, frame.max_depth, frame.max_depth > 0u);
    for (var depth = 0u; depth <= max_bounces; depth++) {
        let hit = trace_closest(origin, dir, 0.0, 1e30);
        if depth == 0u {
            camera_rays += 1u;
        } else {
            indirect_rays += 1u;
        }
        if hit.tri == NO_HIT {
            radiance += throughput * frame.sky.xyz;
            break;
        }
        let surf = hit_surface(origin, dir, hit);
        let le = triangle_emission(hit.tri, -dir);
        let skip_emission = depth == 0u && (frame.flags & FLAG_NO_PRIMARY_EMISSION) != 0u;
        if any(le > vec3<f32>(0.0)) && !skip_emission {
            var w = 1.0;
            if !prev_delta {
                w = power_heuristic(prev_pdf, triangle_light_pdf(hit.tri, dir, hit.t));
            }
            radiance += throughput * le * w;
        }
        if depth == max_bounces {
            break;
        }
        let wo = -dir;
        let m = surf.material;
        // Next-event estimation (a pure mirror evaluates to 0 and traces no shadow ray).
        let u_sel = rand(&rng);
        let u_light = rand_pair(&rng);
        if light_pool.count > 0u {
            let ls = sample_light(surf.position, u_sel, u_light);
            if ls.valid && ls.pdf > 0.0 && dot(ls.wi, surf.geo_normal) > 0.0 {
                let e = bsdf_eval(m, surf.normal, wo, ls.wi);
                if any(e.f > vec3<f32>(0.0)) {
                    let p = offset_ray_origin(surf.position, surf.geo_normal);
                    let t_max = select(ls.dist * (1.0 - 1e-4), 1e30, ls.is_delta && ls.dist >= 1e30);
                    shadow_rays += 1u;
                    if !trace_any(p, ls.wi, 0.0, t_max) {
                        let w = select(power_heuristic(ls.pdf, e.pdf), 1.0, ls.is_delta);
                        radiance += throughput * e.f * dot(surf.normal, ls.wi) * ls.radiance * (w / ls.pdf);
                    }
                }
            }
        }
        // Continue the path by sampling the BRDF.
        let bs = bsdf_sample(m, surf.normal, wo, rand(&rng), rand_pair(&rng));
        // Directions below the geometric surface would leak through thin walls.
        if !bs.valid || dot(bs.wi, surf.geo_normal) <= 0.0 {
            break;
        }
        throughput *= bs.weight;
        prev_pdf = bs.pdf;
        prev_delta = bs.is_delta;
        origin = offset_ray_origin(surf.position, surf.geo_normal);
        dir = bs.wi;
        if depth + 1u >= RR_START_DEPTH {
            let q = min(max_component(throughput), 0.95);
            if q <= 0.0 || rand(&rng) >= q {
                break;
            }
            throughput /= q;
        }
    }
    return PathResult(radiance, camera_rays, shadow_rays, indirect_rays);
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    // One path per invocation: the frame's samples are separate dispatches. Tracing several
    // paths in a loop inside one invocation came out biased on lavapipe (Mesa 22.3): paths after
    // the first were cut short (the white furnace at albedo 0.95 lost 8%); see the README.
    var counts = no_counts();
    if gid.x < frame.size.x && gid.y < frame.size.y {
        let idx = gid.y * frame.size.x + gid.x;
        let path = trace_path(gid.xy, frame.sample_offset + dispatch_sample.index);
        counts[RAY_CAMERA] = path.camera_rays;
        counts[RAY_SHADOW] = path.shadow_rays;
        counts[RAY_INDIRECT] = path.indirect_rays;
        let l = path.radiance;
        if is_finite_vec(l) {
            let a = welford_add(accum_mean[idx], accum_m2[idx], l);
            accum_mean[idx] = a.mean;
            accum_m2[idx] = a.sq_dev;
        } else {
            counts[COUNT_INVALID_SAMPLES] = 1u;
        }
    }
    flush_counts(local_index, counts);
}
