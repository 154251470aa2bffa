// Reflections, pass 3: temporal accumulation. A reflection moves with the reflected point, not
// with the surface: last frame's pixel is found by reprojecting the virtual point behind the
// surface at the reflected hit's distance (exact for a planar mirror), checked to lie on the
// same surface; failing that, by the surface point itself (rough lobes, where the reflection
// barely moves). An exponential average with at most max_history frames; luminance moments
// for the filter's variance test. A new history starts where both fail (disocclusion).
#import gilab::frame::frame
#import gilab::math::luminance
#import gilab::primary::{current_surface, previous_surface, reproject, GSurface}
#import gilab::reflections::{rparams, resolved, history, history_slot, has_flag, FLAG_TEMPORAL}

fn same_surface(s: GSurface, prev: i32) -> bool {
    if prev < 0 {
        return false;
    }
    let o = previous_surface(u32(prev));
    if o.pos.w < 0.5 {
        return false;
    }
    let plane = abs(dot(o.pos.xyz - s.prev_pos.xyz, s.normal_alpha.xyz));
    return plane < 0.02 * s.wo_dist.w && dot(o.normal_alpha.xyz, s.normal_alpha.xyz) > 0.9;
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= frame.size.x || gid.y >= frame.size.y {
        return;
    }
    let idx = gid.y * frame.size.x + gid.x;
    let s = current_surface(idx);
    let cur = resolved[idx];
    var acc = cur.xyz;
    var h = 1.0;
    let l = luminance(cur.xyz);
    var moments = vec2<f32>(l, l * l);
    if s.pos.w > 0.5 && has_flag(FLAG_TEMPORAL) && frame.frame_index > 0u {
        // The reflected point moves with the reflecting surface (its object's motion).
        var prev = reproject(s.prev_pos.xyz - s.wo_dist.xyz * cur.w);
        if !same_surface(s, prev) {
            prev = reproject(s.prev_pos.xyz);
        }
        if same_surface(s, prev) {
            let old = history[history_slot(frame.frame_index + 1u, 0u, u32(prev))];
            let old_m = history[history_slot(frame.frame_index + 1u, 1u, u32(prev))];
            h = min(old.w + 1.0, rparams.max_history);
            let a = 1.0 / h;
            acc = mix(old.xyz, cur.xyz, a);
            moments = mix(old_m.xy, moments, a);
        }
    }
    history[history_slot(frame.frame_index, 0u, idx)] = vec4<f32>(acc, h);
    history[history_slot(frame.frame_index, 1u, idx)] = vec4<f32>(moments, 0.0, 0.0);
}
