// Per pixel: emission + direct light (NEE through the BVH, one light by power, or the ReSTIR DI
// part's result with `direct = "restir"`) + diffuse albedo
// x gathered irradiance / pi + specular indirect light from the reflections part (glossy scenes). With `gather_downsample` > 1 the four nearest gather samples are
// blended by bilinear, normal and depth weights (the nearest valid one where all fail). Writes
// the debug planes (with `debug_views`) and accumulates. With screen probes the irradiance comes
// from `integrate` at full resolution, and the reflected radiance (no emission) is kept for next
// frame's screen traces.
#import gilab::frame::frame
#import gilab::math::{INV_PI, luminance}
#import gilab::counters::{flush_counts, no_counts, RAY_SHADOW, COUNT_INVALID_SAMPLES}
#import gilab::accumulate::accumulate_sample
#import gilab::rng::{rng_init, rand, rand_pair, STREAM_LUMEN_PIXEL}
#import gilab::primary::{current_surface, surface_material, GSurface, primary_emission}
#import gilab::brdf::diffuse_color
#import gilab::nee::direct_light
#import gilab::lumen_probes::{pixel_data, lit_index, parity, probes_flag, PROBES_ACTIVE}
#import gilab::tracing::{params, has_flag, sdf_trace, sdf_sample, sdf_bias, level_voxel, FLAG_LIGHTS, EMPTY}
#import gilab::lumen::{gather_out, debug_out, pixel_direct, FLAG_ACCUMULATE, FLAG_DEBUG, FLAG_DIRECT_RESTIR, FLAG_REFLECTIONS}
#import gilab::surface_cache::{tri_object, sample_cache, cache_radiance}

fn gathered_irradiance(pixel: vec2<u32>, s: GSurface) -> vec3<f32> {
    let ds = params.gather_downsample;
    let plane = params.gather_width * params.gather_height;
    if ds == 1u {
        return gather_out[pixel.y * params.gather_width + pixel.x].xyz;
    }
    let f = (vec2<f32>(pixel) + 0.5) / f32(ds) - 0.5;
    let i0 = vec2<i32>(floor(f));
    let t = f - floor(f);
    var sum = vec3<f32>(0.0);
    var weight = 0.0;
    let hi = vec2<i32>(i32(params.gather_width), i32(params.gather_height)) - 1;
    for (var j = 0u; j < 4u; j++) {
        let o = vec2<i32>(i32(j & 1u), i32(j >> 1u));
        let g = clamp(i0 + o, vec2<i32>(0), hi);
        let gi = u32(g.y) * params.gather_width + u32(g.x);
        let e = gather_out[gi];
        let geo = gather_out[plane + gi];
        if e.w < 0.5 {
            continue;
        }
        let bw = select(1.0 - t, t, vec2<bool>(o == vec2<i32>(1)));
        let nw = pow(max(dot(geo.xyz, s.normal_alpha.xyz), 0.0), 8.0);
        let dw = exp(-abs(geo.w - s.wo_dist.w) / max(0.02 * s.wo_dist.w, 1e-6));
        let w = (bw.x * bw.y + 1e-4) * nw * dw;
        sum += w * e.xyz;
        weight += w;
    }
    if weight > 1e-8 {
        return sum / weight;
    }
    let own = clamp(vec2<i32>(pixel / ds), vec2<i32>(0), hi);
    return gather_out[u32(own.y) * params.gather_width + u32(own.x)].xyz;
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    var counts = no_counts();
    if gid.x < frame.size.x && gid.y < frame.size.y {
        let idx = gid.y * frame.size.x + gid.x;
        let s = current_surface(idx);
        var l = primary_emission(s);
        let emitted = l;
        var first_plane = vec4<f32>(0.0);
        var second_plane = vec4<f32>(0.0);
        if s.pos.w > 0.5 {
            let n = s.normal_alpha.xyz;
            let m = surface_material(s);
            if has_flag(FLAG_DIRECT_RESTIR) {
                // The direct-light part's pass wrote it this frame (its rays counted there).
                l += pixel_direct[idx].xyz;
            } else if has_flag(FLAG_LIGHTS) {
                var rng = rng_init(gid.xy, frame.frame_index, STREAM_LUMEN_PIXEL, frame.seed);
                let d = direct_light(s.pos.xyz, s.geo_specular.xyz, n, m, s.wo_dist.xyz, rand(&rng), rand_pair(&rng));
                l += d.radiance;
                counts[RAY_SHADOW] += d.shadow_rays;
            }
            let albedo = diffuse_color(m, max(dot(n, s.wo_dist.xyz), 0.0));
            let irradiance = gathered_irradiance(gid.xy, s);
            l += albedo * irradiance * INV_PI;
            if has_flag(FLAG_REFLECTIONS) {
                // Traced specular, or a rough lobe's albedo times the gathered irradiance.
                let px = frame.size.x * frame.size.y;
                l += pixel_direct[px + idx].xyz + pixel_direct[2u * px + idx].xyz * irradiance * INV_PI;
            }
            if has_flag(FLAG_DEBUG) {
                let cs = sample_cache(s.pos.xyz, n, tri_object[s.triangle], 1.5 * sdf_bias(s.pos.xyz));
                first_plane = vec4<f32>(
                    luminance(cs.albedo),
                    luminance(cs.albedo * cs.direct) * INV_PI,
                    luminance(cs.albedo * cs.indirect) * INV_PI,
                    luminance(cache_radiance(cs)),
                );
                second_plane.x = select(f32(cs.best_card + 1u), 0.0, cs.best_card == EMPTY);
            }
        }
        if has_flag(FLAG_DEBUG) {
            // SDF views: the distance on a plane facing the camera (slice), the sphere-tracing
            // steps of the camera ray, and its hit distance against the BVH's, in voxels.
            let dir = -s.wo_dist.xyz;
            let slice = frame.camera_pos.xyz + dir * params.slice_depth / max(dot(dir, frame.camera_forward.xyz), 1e-3);
            second_plane.y = abs(sdf_sample(slice));
            let h = sdf_trace(frame.camera_pos.xyz, dir, 1e30, false, false, 0.0);
            second_plane.z = f32(h.steps);
            if h.hit && s.pos.w > 0.5 {
                second_plane.w = abs(h.t - s.wo_dist.w) / level_voxel(min(h.level, params.levels_built - 1u));
            }
            let px = frame.size.x * frame.size.y;
            debug_out[idx] = first_plane;
            debug_out[px + idx] = second_plane;
        }
        if probes_flag(PROBES_ACTIVE) {
            pixel_data[lit_index(parity(), idx)] = vec4<f32>(l - emitted, s.pos.w);
        }
        if !accumulate_sample(idx, l, has_flag(FLAG_ACCUMULATE)) {
            counts[COUNT_INVALID_SAMPLES] = 1u;
        }
    }
    flush_counts(local_index, counts);
}
