// Callisto shadows pass 3, one workgroup: the mean scene luminance of this frame's direct light
// (the sum of the tiles' sums over the pixels), which next frame's rate decisions weigh each
// light's tile luminance against (the seed's perceptual weighting, one frame late as there).
#import gilab::frame::frame
#import gilab::callisto::{params, stats, tile_count}

var<workgroup> wg_sum: array<f32, 256>;

@compute @workgroup_size(256, 1, 1)
fn main(@builtin(local_invocation_index) li: u32) {
    var sum = 0.0;
    for (var t = li; t < tile_count(); t += 256u) {
        sum += stats[1u + t];
    }
    wg_sum[li] = sum;
    workgroupBarrier();
    for (var s = 128u; s > 0u; s >>= 1u) {
        if li < s {
            wg_sum[li] += wg_sum[li + s];
        }
        workgroupBarrier();
    }
    if li == 0u {
        stats[0] = wg_sum[0] / f32(max(frame.size.x * frame.size.y, 1u));
    }
}
