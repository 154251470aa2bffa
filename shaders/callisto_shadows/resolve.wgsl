// Callisto shadows pass 4, per pixel: the shadow mask's temporal accumulation and the final
// radiance. The shadow mask is the ratio of the punctual lights' shadowed to unshadowed direct
// light (per channel); both are reprojected and averaged over frames with the seed's moving
// average, alpha = 1 - 1 / (t + 1) for t frames since the last disocclusion (capped at
// `max_history`), and their ratio (a ratio of averages) multiplies this frame's unshadowed light,
// which is exact for punctual lights: only visibility is filtered, never the lighting, as in the
// seed. The sampled lights (emissive triangles, the tail) are added as traced: their unshadowed
// light is itself a sample, and one mask over several of them would carry one light's sampling
// noise into the pixels where another is visible.
// While t is small the current values are first blurred, bilaterally, over a footprint that
// halves with every frame since the disocclusion (the seed's hierarchical blur: radius
// `blur_radius` >> t, 5x5 taps at stride radius / 2). With `gi`, ReSTIR GI's resampled sample
// (group 2) adds indirect light as in ReSTIR's shading pass. With `direct = "restir"` the
// direct-light part's per-pixel result replaces all of the above. Then the engine's progressive
// average.
#import gilab::frame::frame
#import gilab::counters::{flush_counts, no_counts, RAY_SHADOW, COUNT_INVALID_SAMPLES}
#import gilab::accumulate::accumulate_sample
#import gilab::primary::{current_surface, previous_surface, previous_pixel_position, surface_material, GSurface, at_last_frame, primary_emission}
#import gilab::restir::{gi_reservoirs, gi_sky, reservoir_index, gi_contribution, gi_visible}
#import gilab::callisto::{params, current, history, debug_out, pixel_direct, pixel_specular, parity}
#import gilab::brdf::specular_eval

// Last frame's surface at the reprojected pixel is the same surface: normals within ~25 degrees
// and on this surface's plane (1% of the depth). No depth-difference test: the jittered camera
// rays move grazing hits far along their plane from frame to frame.
fn same_surface(a: GSurface, b: GSurface) -> bool {
    if a.pos.w < 0.5 || b.pos.w < 0.5 || dot(a.normal_alpha.xyz, b.normal_alpha.xyz) < 0.9 {
        return false;
    }
    return abs(dot(b.pos.xyz - a.pos.xyz, a.geo_specular.xyz)) < 0.01 * a.wo_dist.w;
}

struct Pair {
    shadowed: vec3<f32>,
    unshadowed: vec3<f32>,
}

fn blurred(pixel: vec2<i32>, s: GSurface, radius: i32) -> Pair {
    let stride = max(radius / 2, 1);
    var out = Pair(vec3<f32>(0.0), vec3<f32>(0.0));
    var wsum = 0.0;
    let size = vec2<i32>(frame.size);
    for (var dy = -2; dy <= 2; dy++) {
        for (var dx = -2; dx <= 2; dx++) {
            let q = pixel + vec2<i32>(dx, dy) * stride;
            if q.x < 0 || q.y < 0 || q.x >= size.x || q.y >= size.y {
                continue;
            }
            let qi = u32(q.y) * frame.size.x + u32(q.x);
            let o = current_surface(qi);
            if o.pos.w < 0.5 {
                continue;
            }
            // Depth (plane distance) and normal weights.
            let plane = abs(dot(o.pos.xyz - s.pos.xyz, s.geo_specular.xyz)) / max(s.wo_dist.w, 1e-6);
            let w = exp(-plane / 0.02) * pow(max(dot(o.normal_alpha.xyz, s.normal_alpha.xyz), 0.0), 32.0);
            out.shadowed += w * current[qi].xyz;
            out.unshadowed += w * current[params.pixels + qi].xyz;
            wsum += w;
        }
    }
    let i = u32(pixel.y) * frame.size.x + u32(pixel.x);
    if wsum <= 0.0 {
        return Pair(current[i].xyz, current[params.pixels + i].xyz);
    }
    return Pair(out.shadowed / wsum, out.unshadowed / wsum);
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    var counts = no_counts();
    if gid.x < frame.size.x && gid.y < frame.size.y {
        let idx = gid.y * frame.size.x + gid.x;
        let s = current_surface(idx);
        var l = primary_emission(s);
        var frames = 0.0;
        if s.pos.w > 0.5 {
            if params.direct_restir == 1u {
                // `direct = "restir"`: the direct-light part's result (src/parts/), its rays
                // counted there; the tile shadows did not run.
                l += pixel_direct[idx].xyz;
            } else {
                let unshadowed = current[params.pixels + idx].xyz;
                var direct = current[idx].xyz;
                if params.denoise == 1u {
                    var t = 0.0;
                    var past = Pair(vec3<f32>(0.0), vec3<f32>(0.0));
                    // Last frame's history at the pixel the point reprojects to; if that pixel
                    // holds another surface (at edges the jittered camera rays move a pixel's hit
                    // between surfaces), the nearest of its 8 neighbours that holds this one. No
                    // bilinear resampling: repeated every frame it would blur the mask.
                    let f = previous_pixel_position(s.prev_pos.xyz);
                    let centre = vec2<i32>(floor(f));
                    var best = 1e30;
                    for (var k = 0; k < 9 && frame.frame_index > 0u && f.x >= 0.0; k++) {
                        // The centre first (k = 4 is swapped to 0).
                        var kk = k;
                        if k == 0 {
                            kk = 4;
                        } else if k == 4 {
                            kk = 0;
                        }
                        let q = centre + vec2<i32>(kk % 3 - 1, kk / 3 - 1);
                        if q.x < 0 || q.y < 0 || q.x >= i32(frame.size.x) || q.y >= i32(frame.size.y) {
                            continue;
                        }
                        let d = length(vec2<f32>(q) + 0.5 - f);
                        let pidx = u32(q.y) * frame.size.x + u32(q.x);
                        let h = 2u * ((1u - parity()) * params.pixels + pidx);
                        if d < best && history[h].w > 0.0 && same_surface(at_last_frame(s), previous_surface(pidx)) {
                            best = d;
                            t = history[h].w;
                            past = Pair(history[h].xyz, history[h + 1u].xyz);
                            if k == 0 {
                                break;
                            }
                        }
                    }
                    var now = Pair(direct, unshadowed);
                    let radius = i32(params.blur_radius >> min(u32(t), 31u));
                    if radius >= 1 {
                        now = blurred(vec2<i32>(gid.xy), s, radius);
                    }
                    let alpha = 1.0 - 1.0 / (min(t, params.max_history - 1.0) + 1.0);
                    let acc = Pair(mix(now.shadowed, past.shadowed, alpha), mix(now.unshadowed, past.unshadowed, alpha));
                    frames = t + 1.0;
                    let h = 2u * (parity() * params.pixels + idx);
                    history[h] = vec4<f32>(acc.shadowed, frames);
                    history[h + 1u] = vec4<f32>(acc.unshadowed, 0.0);
                    // The mask, per channel: 1 where no light reached the history (nothing to scale).
                    let mask = select(vec3<f32>(1.0), acc.shadowed / max(acc.unshadowed, vec3<f32>(1e-30)), acc.unshadowed > vec3<f32>(0.0));
                    direct = min(mask, vec3<f32>(1.0)) * unshadowed;
                }
                l += direct + current[2u * params.pixels + idx].xyz;
            }
            // Pixels the reflections part traces take their specular indirect light from it;
            // ReSTIR GI's sample (which the full BSDF weighs) then gives its diffuse share only.
            let m = surface_material(s);
            let traced = params.reflections == 1u && sqrt(m.alpha) <= params.reflection_max_roughness;
            if traced {
                l += pixel_specular[idx].xyz;
            }
            if params.gi == 1u {
                // Indirect light: this frame's sky sample plus the resampled GI sample, visibility re-checked.
                // (w: the sample's specular share, 1 for a mirror's, which the reflections part
                // replaces where it traces.)
                let gs = gi_sky[idx];
                l += gs.xyz * select(1.0, 1.0 - gs.w, traced);
                let ri = reservoir_index(parity(), idx);
                let g = gi_reservoirs[ri];
                if g.big_w > 0.0 {
                    let e = gi_contribution(s, g);
                    if any(e.value > vec3<f32>(0.0)) {
                        counts[RAY_SHADOW] += 1u;
                        if gi_visible(s, g) {
                            var value = e.value;
                            if traced {
                                let n = s.normal_alpha.xyz;
                                let spec = specular_eval(m, n, s.wo_dist.xyz, e.wi).f;
                                value = max(value - spec * max(dot(n, e.wi), 0.0) * g.radiance.xyz * e.geom, vec3<f32>(0.0));
                            }
                            l += value * g.big_w;
                        }
                    }
                }
            }
        } else if params.denoise == 1u {
            let h = 2u * (parity() * params.pixels + idx);
            history[h] = vec4<f32>(0.0);
            history[h + 1u] = vec4<f32>(0.0);
        }
        var d = debug_out[idx];
        d.w = frames;
        debug_out[idx] = d;
        if !accumulate_sample(idx, l, params.accumulate == 1u) {
            counts[COUNT_INVALID_SAMPLES] = 1u;
        }
    }
    flush_counts(local_index, counts);
}
