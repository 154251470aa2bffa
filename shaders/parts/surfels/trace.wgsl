// Surfel rays (one invocation per ray, indirect dispatch). Direction: cosine-weighted, or once
// the surfel's guiding map is populated, from the map with probability GUIDE_MIX (texel by the
// map's CDF, uniform within the texel); the estimate divides by the true mixed pdf, so it stays
// unbiased per surfel. At the hit: direct light by NEE with a shadow ray (the light by power,
// or from the world ReGIR clipmap: `cache_direct`, gilab::cache_light), plus the irradiance
// the surfels there hold (multi-bounce through the cache); where no surfel covers the hit (off
// screen) the path continues instead (NEE + BSDF sampling + Russian roulette). Sky on a miss.
// Emission of the first hit is left out: the pixel's own direct light counts it.
#import gilab::frame::frame
#import gilab::math::{PI, INV_PI, luminance, to_world}
#import gilab::counters::{flush_counts, no_counts, count_cache_lookup, RAY_SURFEL, RAY_SHADOW, RAY_INDIRECT}
#import gilab::rng::{Rng, rng_init, rand, rand_pair, STREAM_SURFEL_RAYS}
#import gilab::sampling::sample_cosine_hemisphere
#import gilab::bvh::{trace_closest, NO_HIT}
#import gilab::surface::hit_surface
#import gilab::brdf::{bsdf_sample, diffuse_color, specular_albedo_average}
#import gilab::ray::{spawn_ray_origin, INFINITE_DISTANCE}
#import gilab::path::{trace_path, plain_path}
#import gilab::cache_light::cache_direct_light
#import gilab::surfels::{params, surfels, states, ray_offsets, ray_owner, ray_results, has_flag, gather, gather_covers, gathered_irradiance, grid_center_for, gather_outcome, guide_value, hemi_oct_encode, hemi_oct_decode, hemi_oct_jacobian, texel_of, FLAG_GUIDING, FLAG_SKY, FLAG_CACHE_ONLY, GUIDE_RES, GUIDE_TEXELS, GUIDE_POPULATED, GUIDE_MIX, DEPTH_RES}
#import gilab::sky::sky_radiance


@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    var counts = no_counts();
    let i = gid.x;
    if i < min(ray_offsets[params.max_surfels], params.ray_capacity) {
        let slot = ray_owner[i];
        let k = i - ray_offsets[slot];
        let s = surfels[slot];
        let n = s.normal_id.xyz;
        let p = s.pos_radius.xyz;
        var rng = rng_init(vec2<u32>(slot, k), frame.frame_index, STREAM_SURFEL_RAYS, frame.seed);

        // Direction and its pdf (solid angle).
        let guided = has_flag(FLAG_GUIDING) && states[slot].info.y >= GUIDE_POPULATED;
        var guide_sum = 0.0;
        if guided {
            for (var t = 0u; t < GUIDE_TEXELS; t++) {
                guide_sum += guide_value(slot, t);
            }
        }
        var v: vec3<f32>;
        let u_mix = rand(&rng);
        let u_texel = rand(&rng);
        let u_dir = rand_pair(&rng);
        if guided && guide_sum > 0.0 && u_mix < GUIDE_MIX {
            // Walk the map's CDF (the seed's discrete inversion), then a uniform point in the texel.
            let target_sum = u_texel * guide_sum;
            var acc = 0.0;
            var texel = GUIDE_TEXELS - 1u;
            for (var t = 0u; t < GUIDE_TEXELS; t++) {
                acc += guide_value(slot, t);
                if acc > target_sum {
                    texel = t;
                    break;
                }
            }
            let cell = vec2<f32>(f32(texel % GUIDE_RES), f32(texel / GUIDE_RES));
            v = hemi_oct_decode((cell + u_dir) / f32(GUIDE_RES) * 2.0 - 1.0);
        } else {
            v = sample_cosine_hemisphere(u_dir);
        }
        let cos_theta = v.z;
        var pdf = cos_theta * INV_PI;
        let e = hemi_oct_encode(v);
        let guide_texel = texel_of(e, GUIDE_RES);
        if guided && guide_sum > 0.0 {
            let texel_area = 4.0 / f32(GUIDE_TEXELS);
            let guide_pdf = guide_value(slot, guide_texel) / guide_sum / texel_area * hemi_oct_jacobian(e);
            pdf = (1.0 - GUIDE_MIX) * pdf + GUIDE_MIX * guide_pdf;
        }

        var l = vec3<f32>(0.0);
        var t_hit = INFINITE_DISTANCE;
        if cos_theta > 1e-6 && pdf > 0.0 {
            let dir = to_world(v, n);
            let origin = spawn_ray_origin(p, n, dir);
            let hit = trace_closest(origin, dir, 0.0, INFINITE_DISTANCE);
            counts[RAY_SURFEL] += 1u;
            if hit.tri == NO_HIT {
                if has_flag(FLAG_SKY) {
                    l = sky_radiance(dir);
                }
            } else {
                t_hit = hit.t;
                let h = hit_surface(origin, dir, hit);
                let wo = -dir;
                let d = cache_direct_light(h.position, h.geo_normal, h.normal, h.material, wo, &rng);
                counts[RAY_SHADOW] += d.shadow_rays;
                l = d.radiance;
                let g = gather(h.position, h.normal, grid_center_for(frame.camera_pos.xyz), false);
                // Counted for the surfels technique; as a cache (ReSTIR GI's paths end in it) the
                // engine counts its reader's lookups instead.
                if !has_flag(FLAG_CACHE_ONLY) {
                    count_cache_lookup(&counts, gather_outcome(g, h.position));
                }
                if gather_covers(g) {
                    // The specular layer's energy reflected diffusely, as Lumen's cache albedo.
                    let albedo = diffuse_color(h.material, max(dot(h.normal, wo), 0.0)) + specular_albedo_average(h.material);
                    l += albedo * gathered_irradiance(g) * INV_PI;
                } else {
                    let b = bsdf_sample(h.material, h.normal, wo, rand(&rng), rand_pair(&rng));
                    if b.valid && dot(b.wi, h.geo_normal) > 0.0 {
                        let path = trace_path(spawn_ray_origin(h.position, h.geo_normal, b.wi), b.wi, &rng, 0u, true, plain_path());
                        counts[RAY_INDIRECT] += path.first_rays + path.indirect_rays;
                        counts[RAY_SHADOW] += path.shadow_rays;
                        l += b.weight * path.radiance;
                    }
                }
            }
        } else {
            v = vec3<f32>(0.0, 0.0, 1.0);
        }
        let estimate = select(vec3<f32>(0.0), l * cos_theta / pdf, pdf > 0.0);
        let depth_texel = texel_of(hemi_oct_encode(v), DEPTH_RES);
        ray_results[2u * i] = vec4<f32>(estimate, t_hit);
        ray_results[2u * i + 1u] = vec4<f32>(luminance(l), f32(guide_texel), f32(depth_texel), 0.0);
    }
    flush_counts(local_index, counts);
}
