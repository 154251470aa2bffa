// Denoiser pass 2 (src/render/denoise.rs): the variance that drives the à-trous filter's
// luminance edge-stopping (SVGF, section 4.2). From the temporal luminance moments,
// var = m2 - m1^2; where the history is shorter than 4 samples (after a reset or a
// disocclusion) the moments are first averaged over a 7x7 bilateral window weighted by depth
// and normal, as in the paper.
//
// Where it differs from the paper:
// - The spatial estimate is scaled by 4 / n (n < 4), as the authors' own implementation
//   (Falcor's SVGF) does: a stronger filter while history is short. Without it the luminance
//   weights shrank bright samples more than they spread them, and one denoised 1-spp frame of
//   the Cornell box lost 3% of its energy (1.6-2.1% with it, 1.45% once the à-trous luminance
//   weight was made symmetric; tests/denoise.rs).
// - Where the history holds more than the moving average's 9 effective samples (a technique
//   that keeps accumulating, temporal.wgsl) the variance is scaled by 9 / n, the variance of
//   that longer average relative to the moving average's, so the filter lets go as the
//   technique converges. At or below 9 samples it is the paper's.
#import gilab::frame::frame
#import gilab::denoise::{hist_colour, hist_moments, guide, illum_var, SVGF_SAMPLES, current_slot, geometry_weight, decode_normal, pixel_in_image, pixel_index, finite1}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= frame.size.x || gid.y >= frame.size.y {
        return;
    }
    let p = gid.y * frame.size.x + gid.x;
    let ip = vec2<i32>(gid.xy);
    let c = hist_colour[current_slot(p)];
    var m = hist_moments[current_slot(p)].xy;
    let g = guide[p];
    if g.z > 0.0 && c.w < 4.0 {
        let n_p = decode_normal(g.xy);
        var sum_m = m;
        var sum_w = 1.0;
        for (var dy = -3; dy <= 3; dy++) {
            for (var dx = -3; dx <= 3; dx++) {
                let q = ip + vec2<i32>(dx, dy);
                if (dx == 0 && dy == 0) || !pixel_in_image(q) {
                    continue;
                }
                let qi = pixel_index(q);
                let gq = guide[qi];
                if gq.z <= 0.0 {
                    continue;
                }
                let w = geometry_weight(g.z, g.w, n_p, gq.z, decode_normal(gq.xy), length(vec2<f32>(f32(dx), f32(dy))));
                if w > 0.0 {
                    sum_m += w * hist_moments[current_slot(qi)].xy;
                    sum_w += w;
                }
            }
        }
        m = sum_m / sum_w;
    }
    var variance = max(m.y - m.x * m.x, 0.0);
    if g.z > 0.0 && c.w < 4.0 {
        // The boost of short histories (Falcor's).
        variance *= 4.0 / max(c.w, 1.0);
    }
    if c.w > SVGF_SAMPLES {
        variance *= SVGF_SAMPLES / c.w;
    }
    illum_var[p] = vec4<f32>(c.xyz, finite1(variance));
}
