// Integration (per slot with rays this frame): the frame's irradiance estimate (mean of its
// rays; with `irradiance_sharing`, blended with its neighbours' where it is uncertain, below)
// goes into the multiscale mean estimator (Stachowiak 2018 / Barré-Brisebois 2019, as the
// seed uses it): a short-term mean and variance steer the long-term mean's blend, so a change
// is caught within a few frames while a steady surfel keeps averaging down. With `msme` off, a
// plain running mean over all rays. The rays also update the guiding map (moving average of
// radiance per texel, renormalised to max 1); estimate.wgsl has updated the radial depth.
#import gilab::frame::frame
#import gilab::math::luminance
#import gilab::surfels::{params, surfels, states, guide, ray_offsets, ray_results, frame_estimates, cell_offsets, cell_surfels, has_flag, is_live, cell_of, grid_center_for, depth_visibility, SurfelState, FLAG_MSME, FLAG_SHARING, FLAG_RADIAL_DEPTH, GUIDE_TEXELS, GUIDE_WORDS, MAX_GATHER, footprint_d2}

const LUMA: vec3<f32> = vec3<f32>(0.299, 0.587, 0.114);
// Short-term window at REFERENCE_RAYS rays per frame (the estimator's blend factor).
const SHORT_BLEND: f32 = 0.08;
const REFERENCE_RAYS: f32 = 8.0;
const GUIDE_BLEND: f32 = 0.25;

// One estimator step with the frame estimate y of `rays` rays: the more rays, the more a
// frame's estimate is trusted (larger short-term blend).
fn multiscale_mean(st: ptr<function, SurfelState>, y_in: vec3<f32>, rays: f32) {
    var y = y_in;
    if (*st).info.z == 0u {
        (*st).mean = vec4<f32>(y, rays);
        (*st).short_mean = vec4<f32>(y, 1.0);
        (*st).variance = vec4<f32>(y * y, 0.0);
        return;
    }
    var mean = (*st).mean.xyz;
    var short_mean = (*st).short_mean.xyz;
    var vbbr = (*st).short_mean.w;
    var variance = (*st).variance.xyz;
    var inconsistency = (*st).variance.w;
    let short_blend = clamp(SHORT_BLEND * rays / REFERENCE_RAYS, 0.02, 0.5);
    // Firefly suppression: clamp far outliers of the short-term distribution.
    let deviation = sqrt(max(vec3<f32>(1e-5), variance));
    y -= max(vec3<f32>(0.0), y - (0.1 + short_mean + deviation * 8.0));
    let delta = y - short_mean;
    short_mean = mix(short_mean, y, short_blend);
    let delta2 = y - short_mean;
    // A longer window than the short mean's, so the variance does not shrink with it.
    variance = mix(variance, delta * delta2, short_blend * 0.5);
    let dev = sqrt(max(vec3<f32>(1e-5), variance));
    let short_diff = mean - short_mean;
    let relative_diff = dot(LUMA, abs(short_diff) / max(vec3<f32>(1e-5), dev));
    inconsistency = mix(inconsistency, relative_diff, 0.08);
    let variance_blend_reduction = clamp(dot(LUMA, 0.5 * short_mean / max(vec3<f32>(1e-5), dev)), 1.0 / 32.0, 1.0);
    var catch_up = clamp(smoothstep(0.0, 1.0, relative_diff * max(0.02, inconsistency - 0.2)), 1.0 / 256.0, 1.0);
    catch_up *= vbbr;
    vbbr = mix(vbbr, variance_blend_reduction, 0.1);
    mean = mix(mean, y, clamp(catch_up, 0.0, 1.0));
    (*st).mean = vec4<f32>(mean, (*st).mean.w + rays);
    (*st).short_mean = vec4<f32>(short_mean, vbbr);
    (*st).variance = vec4<f32>(variance, inconsistency);
}

// Irradiance sharing (seed 001, "Irradiance Sharing": the same weights as a gather, Mahalanobis
// footprint and radial depth, between the trace and the estimator). The surfels in this surfel's
// grid cell whose footprint (scaled by SHARE_RADIUS) holds its centre, facing its way and
// seeing it by their depth maps, lend their frame estimates, weighted by footprint, normal,
// visibility and ray count. The blend
// follows the surfel's own uncertainty: the short-term relative variance of a frame's estimate
// over the frames it has integrated (at most SHARE_FRAMES), so young surfels share most and
// converged ones keep their own value (no lasting blur).
const SHARE_VARIANCE: f32 = 0.05;
// Surfels spawn where coverage is low, so a neighbour's own footprint seldom holds a surfel's
// centre: sharing reads neighbours within twice their radius (the same ellipsoid, scaled).
const SHARE_RADIUS: f32 = 2.0;
const SHARE_FRAMES: f32 = 32.0;

fn shared_estimate(slot: u32, y: vec3<f32>, rays: f32, st: SurfelState) -> vec3<f32> {
    let s = surfels[slot];
    let p = s.pos_radius.xyz;
    let n = s.normal_id.xyz;
    var sum = y * rays;
    var weight = rays;
    let cell = cell_of(p, grid_center_for(frame.camera_pos.xyz));
    let first = atomicLoad(&cell_offsets[cell]);
    let end = min(atomicLoad(&cell_offsets[cell + 1u]), first + MAX_GATHER);
    for (var i = first; i < end; i++) {
        let other = cell_surfels[i];
        let e = frame_estimates[other];
        if other == slot || e.w <= 0.0 {
            continue;
        }
        let o = surfels[other];
        let r = o.pos_radius.w;
        let on = o.normal_id.xyz;
        let n_w = dot(n, on);
        if r <= 0.0 || n_w <= 0.0 {
            continue;
        }
        let v = p - o.pos_radius.xyz;
        let d2 = footprint_d2(v, on, SHARE_RADIUS * r);
        if d2 >= 1.0 {
            continue;
        }
        var vis = 1.0;
        let t = length(v);
        if has_flag(FLAG_RADIAL_DEPTH) && t > 1e-6 {
            vis = depth_visibility(other, on, v / t, t);
        }
        let w = (1.0 - d2) * n_w * vis * e.w;
        sum += e.xyz * w;
        weight += w;
    }
    let neighbours = sum / weight;
    // Before its first integration a surfel's variance is unknown: it takes the shared value.
    var share = 1.0;
    if st.info.z > 0u {
        let m = max(dot(LUMA, st.short_mean.xyz), 1e-4);
        let v = dot(LUMA, st.variance.xyz) / (m * m) / min(f32(st.info.z), SHARE_FRAMES);
        share = v / (v + SHARE_VARIANCE);
    }
    return mix(y, neighbours, share);
}

// The plain running mean over every ray so far (the `msme = false` baseline); the short-term
// mean and variance are still tracked, for ray requests and the variance view.
fn running_mean(st: ptr<function, SurfelState>, y: vec3<f32>, rays: f32) {
    let count = (*st).mean.w + rays;
    let mean = (*st).mean.xyz + (y - (*st).mean.xyz) * (rays / count);
    if (*st).info.z == 0u {
        (*st).short_mean = vec4<f32>(y, 1.0);
        (*st).variance = vec4<f32>(y * y, 0.0);
    } else {
        let short_blend = clamp(SHORT_BLEND * rays / REFERENCE_RAYS, 0.02, 0.5);
        let delta = y - (*st).short_mean.xyz;
        let short_mean = mix((*st).short_mean.xyz, y, short_blend);
        (*st).short_mean = vec4<f32>(short_mean, 1.0);
        (*st).variance = vec4<f32>(mix((*st).variance.xyz, delta * (y - short_mean), short_blend * 0.5), 0.0);
    }
    (*st).mean = vec4<f32>(mean, count);
}

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let slot = gid.x;
    if slot >= params.max_surfels || !is_live(slot) {
        return;
    }
    var st = states[slot];
    let count = st.info.x;
    if count == 0u {
        return;
    }
    let first = ray_offsets[slot];
    var texel_sum: array<f32, 36>;
    var texel_count: array<u32, 36>;
    for (var t = 0u; t < GUIDE_TEXELS; t++) {
        texel_sum[t] = 0.0;
        texel_count[t] = 0u;
    }
    for (var k = 0u; k < count; k++) {
        let b = ray_results[2u * (first + k) + 1u];
        let gt = min(u32(b.y), GUIDE_TEXELS - 1u);
        texel_sum[gt] += b.x;
        texel_count[gt] += 1u;
    }
    var y = frame_estimates[slot].xyz;
    if has_flag(FLAG_SHARING) {
        y = shared_estimate(slot, y, f32(count), st);
    }
    if has_flag(FLAG_MSME) {
        multiscale_mean(&st, y, f32(count));
    } else {
        running_mean(&st, y, f32(count));
    }
    // Guiding map: absolute radiance per texel = stored (relative) value * the surfel's scale.
    let scale = select(bitcast<f32>(st.info.w), 0.0, st.info.y == 0u);
    var values: array<f32, 36>;
    var top = 0.0;
    for (var t = 0u; t < GUIDE_TEXELS; t++) {
        var v = unpack4x8unorm(guide[slot * GUIDE_WORDS + t / 4u])[t % 4u] * scale;
        if texel_count[t] > 0u {
            let seen_value = texel_sum[t] / f32(texel_count[t]);
            v = select(mix(v, seen_value, GUIDE_BLEND), seen_value, st.info.y == 0u);
        }
        values[t] = v;
        top = max(top, v);
    }
    for (var w = 0u; w < GUIDE_WORDS; w++) {
        var packed = vec4<f32>(1.0);
        if top > 0.0 {
            packed = vec4<f32>(values[4u * w], values[4u * w + 1u], values[4u * w + 2u], values[4u * w + 3u]) / top;
        }
        guide[slot * GUIDE_WORDS + w] = pack4x8unorm(packed);
    }
    st.info.w = bitcast<u32>(top);
    st.info.y += count;
    st.info.z += 1u;
    states[slot] = st;
}
