// Screen traces (one thread per probe ray): a stackless walk down and up last frame's
// hierarchical Z (closest 1/w per mip; 1/w is linear along a ray in screen space). A cell the
// ray passes entirely in front of is skipped and the walk goes one mip coarser; otherwise one
// finer; at mip 0 the ray either crosses the surface there (a hit: last frame's reflected
// radiance at that pixel) or passes behind it. Rays that leave the image, pass behind, hit a
// back side or run out of steps are appended to the world list, to continue from the last
// point known to be free (world_trace).
#import gilab::frame::frame
#import gilab::primary::previous_surface
#import gilab::equal_area::equal_area_dir
#import gilab::lumen_probes::{pp, probe_state, probe_data, pixel_data, load_probe, parity, probe_count, probes_flag, history_valid, ray_index, hzb_load, lit_index, PROBES_SCREEN_TRACES, STATE_WORLD_RAYS, STATE_SCREEN_HITS, PROBE_CELLS}

struct ScreenResult {
    hit: bool,
    // World distance of the hit, or the last point known to be free.
    t: f32,
    pixel: u32,
}

fn to_screen(c: vec4<f32>) -> vec2<f32> {
    let ndc = c.xy / c.w;
    return vec2<f32>((ndc.x * 0.5 + 0.5) * f32(frame.size.x), (0.5 - ndc.y * 0.5) * f32(frame.size.y));
}

fn screen_trace(o: vec3<f32>, d: vec3<f32>, t_max_in: f32, dist_scale: f32) -> ScreenResult {
    var out = ScreenResult(false, 0.0, 0u);
    let c0 = frame.prev_clip_from_world * vec4<f32>(o, 1.0);
    if c0.w <= 1e-4 {
        return out;
    }
    // Keep the segment in front of the camera.
    var t_max = t_max_in;
    let dw = (frame.prev_clip_from_world * vec4<f32>(d, 0.0)).w;
    if dw < 0.0 {
        t_max = min(t_max, (1e-3 - c0.w) / dw);
    }
    let c1 = frame.prev_clip_from_world * vec4<f32>(o + d * t_max, 1.0);
    let s0 = to_screen(c0);
    let s1 = to_screen(c1);
    let k0 = 1.0 / c0.w;
    let k1 = 1.0 / c1.w;
    let size = vec2<f32>(frame.size);
    if any(s0 < vec2<f32>(0.0)) || any(s0 >= size) {
        return out;
    }
    let full = s1 - s0;
    // Clip the segment to the image (rays towards the camera reach huge screen coordinates),
    // then walk the clipped segment: u in [0, 1], 1/w linear in u.
    var u_clip = 1.0;
    for (var a = 0u; a < 2u; a++) {
        if full[a] > 0.0 {
            u_clip = min(u_clip, (size[a] - 1e-3 - s0[a]) / full[a]);
        } else if full[a] < 0.0 {
            u_clip = min(u_clip, (1e-3 - s0[a]) / full[a]);
        }
    }
    let k_end = mix(k0, k1, u_clip);
    // The world fraction of the clipped end.
    let q_end = u_clip * k1 / max(k_end, 1e-20);
    t_max = t_max * q_end;
    let k1c = k_end;
    let delta = full * u_clip;
    let len = length(delta);
    if len < 1.0 {
        return out;
    }
    let u_end = 1.0;
    // Start two pixels out (the probe's own surface is under the first ones).
    var u = min(2.0 / len, u_end);
    var level = 0u;
    let top = pp.counts.x - 1u;
    for (var i = 0u; i < pp.counts.y; i++) {
        if u >= u_end {
            break;
        }
        let pos = s0 + delta * u;
        let scale = f32(1u << level);
        let cell = vec2<u32>(pos / scale);
        // The ray's parameter where it leaves this cell.
        var u_exit = u_end;
        for (var a = 0u; a < 2u; a++) {
            if delta[a] > 0.0 {
                u_exit = min(u_exit, ((f32(cell[a]) + 1.0) * scale - s0[a]) / delta[a]);
            } else if delta[a] < 0.0 {
                u_exit = min(u_exit, (f32(cell[a]) * scale - s0[a]) / delta[a]);
            }
        }
        u_exit = max(u_exit, u + 1e-3 / len);
        let surface = hzb_load(level, cell);
        let k_in = mix(k0, k1c, u);
        let k_out = mix(k0, k1c, min(u_exit, u_end));
        if min(k_in, k_out) > surface {
            // In front of everything in the cell: skip it, look coarser.
            u = u_exit;
            level = min(level + 1u, top);
            continue;
        }
        if level > 0u {
            level -= 1u;
            continue;
        }
        // Mip 0: the surface at this pixel is at 1/w = surface; the ray enters at k_in.
        let pixel = cell.y * frame.size.x + cell.x;
        let thickness = pp.misc.y;
        if k_in >= surface * (1.0 - thickness) {
            let s = previous_surface(pixel);
            // A ray leaving a plane cannot meet that plane again: a crossing of the plane the
            // ray started on is the pixel's flat depth misjudging a slanted surface; walk on.
            let own_plane = abs(dot(s.geo_specular.xyz, o - s.pos.xyz)) < 0.01 * dist_scale;
            if own_plane && s.pos.w > 0.5 {
                u = u_exit;
                continue;
            }
            if s.pos.w > 0.5 && dot(s.geo_specular.xyz, d) < 0.0 {
                let t_frac = u * k1c / max(mix(k0, k1c, u), 1e-20);
                out.hit = true;
                out.t = t_frac * t_max;
                out.pixel = pixel;
            }
        }
        break;
    }
    if !out.hit {
        // Two pixels back, measured where the walk stopped (perspective stretches the far end
        // of the segment): the last pixel may have been crossed between depth samples.
        let ub = max(u - 2.0 / len, 0.0);
        let t_frac = ub * k1c / max(mix(k0, k1c, ub), 1e-20);
        out.t = t_frac * t_max;
    }
    return out;
}

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) j: u32) {
    let probe = wid.x;
    if probe >= probe_count() {
        return;
    }
    let q = load_probe(parity(), probe);
    let r = ray_index(probe, j);
    let rec = probe_data[r];
    if !q.valid || rec.z <= 0.0 {
        return;
    }
    let d = equal_area_dir(rec.xy);
    if dot(d, q.geo) <= 0.0 {
        // Below the probe's surface: no light arrives from there.
        probe_data[r + 1u] = vec4<f32>(0.0, 0.0, 0.0, 0.0);
        return;
    }
    var t_free = 0.0;
    if probes_flag(PROBES_SCREEN_TRACES) && history_valid() {
        let o = q.pos + q.geo * 2e-3 * q.dist;
        let h = screen_trace(o, d, 2.0 * q.dist + pp.misc.x, q.dist);
        if h.hit {
            let lit = pixel_data[lit_index(1u - parity(), h.pixel)];
            probe_data[r + 1u] = vec4<f32>(lit.xyz, h.t);
            atomicAdd(&probe_state[STATE_SCREEN_HITS], 1u);
            return;
        }
        t_free = h.t;
    }
    let slot = atomicAdd(&probe_state[STATE_WORLD_RAYS], 1u);
    atomicStore(&probe_state[pp.offsets.y + slot], probe * PROBE_CELLS + j);
    probe_data[r + 1u] = vec4<f32>(0.0, 0.0, 0.0, -1.0 - t_free);
}
