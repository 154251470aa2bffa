// Denoiser pass 1 (src/render/denoise.rs): demodulation and temporal accumulation (SVGF,
// Schied et al. 2017, section 4.1). Per pixel: the technique's new samples of this frame,
// less the emission seen directly, divided by the albedo; blended with last frame's history
// reprojected through the primary surfaces with consistency tests; luminance moments beside.
// Also writes the guide (normal, depth, depth gradient) the later passes filter with, and
// the albedo and emission the last pass remodulates with.
//
// Where it differs from the paper:
// - Input. The engine's output is the technique's running mean (w: samples). Where the
//   technique continued its average this frame (its sample count grew; the engine restarts it
//   on every camera move or scene change) this frame's new samples are recovered from the
//   two means, and the history at the same pixel is trusted without reprojection: the
//   blend weight is then 1/n with no ALPHA floor, so the history is the plain average of
//   every sample the technique took, as long as it keeps accumulating, and the remodulation
//   albedo and emission are averaged over those frames too. A converging technique thus
//   converges denoised as well instead of stopping at the 0.2 moving average's noise. Where
//   the technique shows one frame (real time) or restarted, it is the paper's method.
// - History length is counted in effective samples (1 / sum of squared weights), which equals
//   the paper's frame count while 1/n > ALPHA and tends to (2 - ALPHA) / ALPHA = 9 after.
// - Consistency tests: the G-buffer has no object id beyond triangle and material, so the
//   object test compares materials (triangles of one mesh differ); depth is tested as the
//   distance of the previous surface point to the current point's tangent plane (1% of the
//   distance to the camera), normals by n . n_prev > 0.9.
#import gilab::frame::frame
#import gilab::primary::{GSurface, surfaces, surface_slot, current_surface, previous_pixel_position}
#import gilab::accumulate::accum_mean
#import gilab::math::{luminance, is_finite_vec}
#import gilab::denoise::{noisy, hist_colour, hist_moments, remod, guide, Remod, ALPHA, current_slot, previous_slot, finite3, finite1, surface_ok, surface_normal, demod_albedo, seen_emission, encode_normal, pixel_in_image, pixel_index}

struct History {
    colour: vec3<f32>,
    moments: vec2<f32>,
    // Effective samples; 0: none.
    len: f32,
}

fn previous_frame_surface(pixel: u32) -> GSurface {
    return surfaces[surface_slot(frame.frame_index + 1u, pixel)];
}

// Whether last frame's surface at a pixel is the same surface as this one's.
fn consistent(s: GSurface, n: vec3<f32>, prev: GSurface) -> bool {
    if !surface_ok(prev) || prev.material != s.material {
        return false;
    }
    if dot(n, surface_normal(prev)) < 0.9 {
        return false;
    }
    return abs(dot(prev.pos.xyz - s.prev_pos.xyz, n)) <= 0.01 * s.wo_dist.w;
}

// Last frame's history at the point this pixel sees: bilinear over the 2x2 pixels around its
// previous position, each tap kept only where consistent; else the consistent ones of the
// 3x3 around it (the paper's fallback); else none (disocclusion).
fn reproject_history(s: GSurface, n: vec3<f32>) -> History {
    var h = History(vec3<f32>(0.0), vec2<f32>(0.0), 0.0);
    let prev = previous_pixel_position(s.prev_pos.xyz);
    if prev.x < 0.0 {
        return h;
    }
    let f = prev - vec2<f32>(0.5);
    let base = vec2<i32>(floor(f));
    let t = f - floor(f);
    var sum_w = 0.0;
    for (var i = 0; i < 4; i++) {
        let o = vec2<i32>(i & 1, i >> 1u);
        let q = base + o;
        if !pixel_in_image(q) {
            continue;
        }
        let wx = select(1.0 - t.x, t.x, o.x == 1);
        let wy = select(1.0 - t.y, t.y, o.y == 1);
        let w = wx * wy;
        let qi = pixel_index(q);
        let c = hist_colour[previous_slot(qi)];
        if w <= 0.0 || c.w <= 0.0 || !consistent(s, n, previous_frame_surface(qi)) {
            continue;
        }
        h.colour += w * c.xyz;
        h.moments += w * hist_moments[previous_slot(qi)].xy;
        h.len += w * c.w;
        sum_w += w;
    }
    if sum_w > 0.01 {
        h.colour /= sum_w;
        h.moments /= sum_w;
        h.len /= sum_w;
        return h;
    }
    h = History(vec3<f32>(0.0), vec2<f32>(0.0), 0.0);
    sum_w = 0.0;
    let centre = vec2<i32>(floor(prev));
    for (var dy = -1; dy <= 1; dy++) {
        for (var dx = -1; dx <= 1; dx++) {
            let q = centre + vec2<i32>(dx, dy);
            if !pixel_in_image(q) {
                continue;
            }
            let qi = pixel_index(q);
            let c = hist_colour[previous_slot(qi)];
            if c.w <= 0.0 || !consistent(s, n, previous_frame_surface(qi)) {
                continue;
            }
            h.colour += c.xyz;
            h.moments += hist_moments[previous_slot(qi)].xy;
            h.len += c.w;
            sum_w += 1.0;
        }
    }
    if sum_w > 0.0 {
        h.colour /= sum_w;
        h.moments /= sum_w;
        h.len /= sum_w;
    }
    return h;
}

// Distance to the camera of a neighbour's surface, or -1 where it has none.
fn neighbour_depth(q: vec2<i32>) -> f32 {
    if !pixel_in_image(q) {
        return -1.0;
    }
    let s = current_surface(pixel_index(q));
    return select(-1.0, s.wo_dist.w, surface_ok(s));
}

// Depth change per pixel along one axis: the smaller one-sided difference (a central
// difference would straddle depth edges), 0 without neighbours.
fn axis_gradient(z: f32, a: f32, b: f32) -> f32 {
    var g = F32_LARGE;
    if a > 0.0 {
        g = min(g, abs(z - a));
    }
    if b > 0.0 {
        g = min(g, abs(z - b));
    }
    return select(0.0, g, g < F32_LARGE);
}

const F32_LARGE: f32 = 1e30;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= frame.size.x || gid.y >= frame.size.y {
        return;
    }
    let p = gid.y * frame.size.x + gid.x;
    let ip = vec2<i32>(gid.xy);
    let s = current_surface(p);
    let ok = surface_ok(s);
    let n = surface_normal(s);

    // The guide of the filter passes.
    var g = vec4<f32>(2.0, 2.0, 0.0, 0.0);
    if ok {
        let z = s.wo_dist.w;
        let gx = axis_gradient(z, neighbour_depth(ip + vec2<i32>(1, 0)), neighbour_depth(ip - vec2<i32>(1, 0)));
        let gy = axis_gradient(z, neighbour_depth(ip + vec2<i32>(0, 1)), neighbour_depth(ip - vec2<i32>(0, 1)));
        g = vec4<f32>(encode_normal(n), z, length(vec2<f32>(gx, gy)));
    }
    guide[p] = g;

    // This frame's new samples, from the technique's running mean now and before its render.
    let now = accum_mean[p];
    let before = noisy[p];
    let w_new = finite1(now.w);
    let w_old = finite1(before.w);
    let accumulating = ok && w_old > 0.0 && w_new > w_old;
    var fresh = finite3(now.xyz);
    if accumulating {
        fresh = finite3((now.xyz * w_new - finite3(before.xyz) * w_old) / (w_new - w_old));
    }
    fresh = max(fresh, vec3<f32>(0.0));
    let albedo = demod_albedo(s);
    // The emission taken out is at most what the samples hold: with several samples per frame
    // only the first shares the surface's jitter, and at an emitter's edge the others may miss
    // it; taking out all of it would leave a negative illumination that the filter spreads.
    // (One sample a frame: the path's first emission is exactly this, nothing changes.)
    let emission = min(seen_emission(s), fresh);
    var rm = Remod(vec4<f32>(albedo, 0.0), vec4<f32>(emission, 0.0));
    if accumulating {
        // The remodulation follows the technique's average: albedo and emission averaged over
        // the frames it accumulated, weighted by their samples (jittered pixels at edges see
        // several surfaces).
        let t = (w_new - w_old) / w_new;
        let old = remod[p];
        rm.albedo = vec4<f32>(mix(old.albedo.xyz, albedo, t), 0.0);
        rm.emission = vec4<f32>(mix(old.emission.xyz, emission, t), 0.0);
    }
    remod[p] = rm;
    let x = finite3((fresh - emission) / albedo);
    let lx = luminance(x);

    var h = History(vec3<f32>(0.0), vec2<f32>(0.0), 0.0);
    if accumulating {
        let c = hist_colour[previous_slot(p)];
        h = History(c.xyz, hist_moments[previous_slot(p)].xy, c.w);
    } else if ok && is_finite_vec(s.pos.xyz) {
        h = reproject_history(s, n);
    }
    var alpha = 1.0;
    var len = 1.0;
    if h.len > 0.0 && is_finite_vec(h.colour) && is_finite_vec(vec3<f32>(h.moments, h.len)) {
        alpha = 1.0 / (h.len + 1.0);
        if !accumulating {
            alpha = max(ALPHA, alpha);
        }
        len = 1.0 / ((1.0 - alpha) * (1.0 - alpha) / h.len + alpha * alpha);
    } else {
        h = History(vec3<f32>(0.0), vec2<f32>(0.0), 0.0);
    }
    var colour = mix(h.colour, x, alpha);
    var moments = mix(h.moments, vec2<f32>(lx, lx * lx), alpha);
    if !ok {
        // Misses pass through and are nobody's history.
        len = 0.0;
    }
    if !is_finite_vec(vec3<f32>(colour)) || !is_finite_vec(vec3<f32>(moments, len)) {
        colour = x;
        moments = vec2<f32>(lx, lx * lx);
        len = select(0.0, 1.0, ok);
        if !is_finite_vec(vec3<f32>(moments, 0.0)) {
            colour = vec3<f32>(0.0);
            moments = vec2<f32>(0.0);
        }
    }
    hist_colour[current_slot(p)] = vec4<f32>(colour, len);
    hist_moments[current_slot(p)] = vec4<f32>(moments, select(0.0, 1.0, accumulating), 0.0);
}
