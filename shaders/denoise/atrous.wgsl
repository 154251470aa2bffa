// Denoiser pass 3, run five times (src/render/denoise.rs): one iteration of the edge-avoiding
// à-trous wavelet filter (SVGF, section 4.3): a 5x5 B3-spline kernel (1/16, 1/4, 3/8, 1/4,
// 1/16) with taps `step_px` apart (1, 2, 4, 8, 16), each tap weighted by
//   w_z = exp(-|z_p - z_q| / (sigma_z |grad z| |p - q| + eps))   (sigma_z = 1)
//   w_n = max(0, n_p . n_q)^128
//   w_l = exp(-|l_p - l_q| / (sigma_l sqrt(min(g3x3(var_p), var_q)) + eps))   (sigma_l = 4)
// where g3x3 is a 3x3 Gaussian of the variance; the variance is filtered with the squared
// weights. The first iteration's output becomes the colour history (where the technique does
// not accumulate itself; see temporal.wgsl). The last remodulates: illumination * albedo plus
// the emission seen directly, into the engine's output (the sample count w stays).
//
// Where it differs from the paper:
// - The luminance weight is symmetric: its scale is the smaller of the two pixels' variances
//   (the paper's is the centre's alone). With the centre's alone, a bright sample with a large
//   variance took in its dark neighbours while they, with small variances, refused it, so its
//   light was lost rather than spread: one denoised 1-spp Cornell frame at 128² lost 2.0-2.1%
//   of its energy, now 1.3-1.45%. The larger of the two (tried) lost 1.1-1.2% but blurred
//   more: relMSE at 64 and 256 accumulated spp 44% and 35% above the paper's weight, worse than
//   no denoiser at 256. The smaller: 4 / 16 / 64 / 256 spp 0.0178 / 0.0109 / 0.0037 / 0.00107
//   against the paper's 0.0203 / 0.0084 / 0.0031 / 0.00114, real time 0.0124 against 0.0148
//   (docs/denoiser.md; tests/denoise.rs, 2026-11-29).
// - Where the technique's own average holds at least 16
// samples, the denoised value is clamped per channel to within one standard error of that
// average (from the technique's Welford M2, gilab::accumulate). The filter's bias (a blur
// of smooth gradients the edge-stopping weights cannot see) would otherwise stay while a
// converging technique's noise falls: on the Cornell box at 64x64 the denoised reference
// stopped at relMSE 0.016 while the undenoised one reached 0.00035 at 1024 spp; clamped it
// follows it (0.0004). A technique that shows one frame (w = 1, real time) is never clamped.
// Below 16 samples the standard error from M2 is itself too noisy (two equal samples give 0).
#import gilab::frame::frame
#import gilab::accumulate::{accum_mean, accum_m2}
#import gilab::math::{luminance, is_finite_vec}
#import gilab::denoise::{hist_colour, hist_moments, remod, guide, illum_var, atrous, SIGMA_L, pixel_count, current_slot, geometry_weight, decode_normal, pixel_in_image, pixel_index, finite3, finite1}

// The clamp to the technique's own average: standard errors, and the samples it needs.
const CLAMP_K: f32 = 1.0;
const CLAMP_MIN_SAMPLES: f32 = 16.0;

fn b3(o: i32) -> f32 {
    switch abs(o) {
        case 0: {
            return 0.375;
        }
        case 1: {
            return 0.25;
        }
        default: {
            return 0.0625;
        }
    }
}

fn in_slot(pixel: u32) -> u32 {
    return (atrous.iteration & 1u) * pixel_count() + pixel;
}

fn out_slot(pixel: u32) -> u32 {
    return ((atrous.iteration + 1u) & 1u) * pixel_count() + pixel;
}

// 3x3 Gaussian (1/4, 1/2, 1/4) of the variance around a pixel, over the taps in the image.
fn blurred_variance(ip: vec2<i32>) -> f32 {
    var sum = 0.0;
    var sum_w = 0.0;
    for (var dy = -1; dy <= 1; dy++) {
        for (var dx = -1; dx <= 1; dx++) {
            let q = ip + vec2<i32>(dx, dy);
            if !pixel_in_image(q) {
                continue;
            }
            let w = select(0.25, 0.5, dx == 0) * select(0.25, 0.5, dy == 0);
            sum += w * illum_var[in_slot(pixel_index(q))].w;
            sum_w += w;
        }
    }
    return sum / sum_w;
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= frame.size.x || gid.y >= frame.size.y {
        return;
    }
    let p = gid.y * frame.size.x + gid.x;
    let ip = vec2<i32>(gid.xy);
    let c = illum_var[in_slot(p)];
    let g = guide[p];
    var out = c;
    if g.z > 0.0 {
        let n_p = decode_normal(g.xy);
        let l_p = luminance(c.xyz);
        let var_p = max(blurred_variance(ip), 0.0);
        let stride = i32(atrous.step_px);
        let w_centre = b3(0) * b3(0);
        var sum_c = w_centre * c.xyz;
        var sum_v = w_centre * w_centre * c.w;
        var sum_w = w_centre;
        for (var dy = -2; dy <= 2; dy++) {
            for (var dx = -2; dx <= 2; dx++) {
                let q = ip + stride * vec2<i32>(dx, dy);
                if (dx == 0 && dy == 0) || !pixel_in_image(q) {
                    continue;
                }
                let qi = pixel_index(q);
                let gq = guide[qi];
                if gq.z <= 0.0 {
                    continue;
                }
                let cq = illum_var[in_slot(qi)];
                let dist = f32(stride) * length(vec2<f32>(f32(dx), f32(dy)));
                let phi_l = SIGMA_L * sqrt(min(var_p, max(cq.w, 0.0))) + 1e-10;
                let w_l = exp(-abs(l_p - luminance(cq.xyz)) / phi_l);
                let w = b3(dx) * b3(dy) * geometry_weight(g.z, g.w, n_p, gq.z, decode_normal(gq.xy), dist) * w_l;
                if w > 0.0 {
                    sum_c += w * cq.xyz;
                    sum_v += w * w * cq.w;
                    sum_w += w;
                }
            }
        }
        out = vec4<f32>(sum_c / sum_w, sum_v / (sum_w * sum_w));
    }
    if !is_finite_vec(out.xyz) || !(abs(out.w) <= 3.0e38) {
        out = vec4<f32>(finite3(c.xyz), finite1(c.w));
    }
    illum_var[out_slot(p)] = out;
    // The paper feeds the first iteration back as the colour history (more spatial smoothing
    // over time); not where the technique accumulates, whose history stays its plain average.
    if atrous.iteration == 0u && g.z > 0.0 && hist_moments[current_slot(p)].z == 0.0 {
        let h = hist_colour[current_slot(p)];
        hist_colour[current_slot(p)] = vec4<f32>(out.xyz, h.w);
    }
    if atrous.last != 0u {
        let rm = remod[p];
        let now = accum_mean[p];
        var radiance = out.xyz * rm.albedo.xyz + rm.emission.xyz;
        if !is_finite_vec(radiance) {
            radiance = finite3(now.xyz);
        }
        if now.w >= CLAMP_MIN_SAMPLES {
            let se = sqrt(max(finite3(accum_m2[p].xyz), vec3<f32>(0.0)) / (now.w * (now.w - 1.0)));
            radiance = clamp(radiance, now.xyz - CLAMP_K * se, now.xyz + CLAMP_K * se);
        }
        accum_mean[p] = vec4<f32>(max(radiance, vec3<f32>(0.0)), now.w);
    }
}
