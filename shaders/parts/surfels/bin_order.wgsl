// Ray binning, pass 2 (after the prefix sum over the bins' counts): each ray takes the next
// place in its bin, so the trace pass runs the rays of one bin (one grid cell, one quadrant of
// directions) side by side. Within a bin the order depends on thread timing, which changes no
// result: each ray keeps its index (trace.wgsl).
#import gilab::surfels::{params, ray_offsets, counters, RAY_BINS, ray_bin_keys, ray_bin_order}

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if i >= min(ray_offsets[params.max_surfels], params.ray_capacity) {
        return;
    }
    let bin = atomicLoad(&counters[ray_bin_keys() + i]);
    let at = atomicLoad(&counters[bin]) + atomicAdd(&counters[RAY_BINS + 1u + bin], 1u);
    atomicStore(&counters[ray_bin_order() + at], i);
}
