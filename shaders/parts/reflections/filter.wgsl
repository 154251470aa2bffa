// Reflections, pass 4: the bilateral filter, the seed's "last ditch effort". It runs where the
// accumulated luminance still varies (relative deviation above 0.5) and at double radius where
// history is new (disocclusion); weights follow normal, depth and lobe width, and the seed's
// tonemapped weighting (1 / (1 + luminance)) keeps fireflies from spreading. Mirror pixels are
// never blurred. Writes the family's output: (specular radiance, 0) and (rough albedo, kind).
#import gilab::frame::frame
#import gilab::math::luminance
#import gilab::primary::{current_surface, surface_material}
#import gilab::reflections::{rparams, ray_samples, resolved, history, history_slot, debug_out, has_flag, FLAG_FILTER, FLAG_DEBUG, KIND_WORLD, KIND_MIRROR}

@group(3) @binding(0) var<storage, read_write> reflection_out: array<vec4<f32>>;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= frame.size.x || gid.y >= frame.size.y {
        return;
    }
    let idx = gid.y * frame.size.x + gid.x;
    let px = frame.size.x * frame.size.y;
    let s = current_surface(idx);
    let centre = history[history_slot(frame.frame_index, 0u, idx)];
    let m = history[history_slot(frame.frame_index, 1u, idx)].xy;
    var out = centre.xyz;
    if s.pos.w > 0.5 && has_flag(FLAG_FILTER) {
        let roughness = sqrt(surface_material(s).alpha);
        let deviation = sqrt(max(m.y - m.x * m.x, 0.0)) / max(m.x, 1e-4);
        var radius = 0;
        if centre.w < 4.0 {
            radius = 2;
        } else if deviation > 0.5 {
            radius = 1;
        }
        if roughness < 0.05 {
            radius = 0;
        }
        if radius > 0 {
            var sum = vec3<f32>(0.0);
            var weight = 0.0;
            let hi = vec2<i32>(frame.size.xy) - 1;
            for (var dy = -radius; dy <= radius; dy++) {
                for (var dx = -radius; dx <= radius; dx++) {
                    let q = clamp(vec2<i32>(gid.xy) + vec2<i32>(dx, dy), vec2<i32>(0), hi);
                    let qi = u32(q.y) * frame.size.x + u32(q.x);
                    let o = current_surface(qi);
                    if o.pos.w < 0.5 {
                        continue;
                    }
                    let c = history[history_slot(frame.frame_index, 0u, qi)].xyz;
                    let nw = pow(max(dot(o.normal_alpha.xyz, s.normal_alpha.xyz), 0.0), 32.0);
                    let dw = exp(-abs(o.wo_dist.w - s.wo_dist.w) / max(0.02 * s.wo_dist.w, 1e-6));
                    let rw = exp(-abs(sqrt(o.normal_alpha.w) - roughness) * 10.0);
                    let w = nw * dw * rw / (1.0 + luminance(c));
                    sum += w * c;
                    weight += w;
                }
            }
            if weight > 0.0 {
                out = sum / weight;
            }
        }
    }
    let rough = resolved[px + idx];
    let first = rparams.output_plane * px;
    reflection_out[first + idx] = vec4<f32>(out, 0.0);
    reflection_out[first + px + idx] = rough;
    if has_flag(FLAG_DEBUG) {
        // Whether this pixel was its block's ray source this frame.
        let ds = rparams.downsample;
        let t = min(gid.xy / ds, vec2<u32>(rparams.trace_width, rparams.trace_height) - 1u);
        let info = ray_samples[3u * (t.y * rparams.trace_width + t.x) + 2u];
        let traced = u32(info.x) == idx && info.y >= KIND_WORLD && info.y <= KIND_MIRROR;
        debug_out[idx] = vec4<f32>(select(0.0, 1.0, traced), rough.w, luminance(out), centre.w);
    }
}
