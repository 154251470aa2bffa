// Per slot, after the ray prefix sum: each surfel writes its slot against its rays (the trace
// pass runs one invocation per ray) and how many it got; thread 0 writes the trace pass's
// indirect dispatch for the frame's ray count (at most the ray buffers' capacity).
#import gilab::dispatch::{DispatchArgs, dispatch_for}
#import gilab::surfels::{params, states, ray_offsets, ray_owner}

@group(3) @binding(0) var<storage, read_write> trace_args: DispatchArgs;

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let slot = gid.x;
    if slot == 0u {
        trace_args = dispatch_for(min(ray_offsets[params.max_surfels], params.ray_capacity));
    }
    if slot >= params.max_surfels {
        return;
    }
    let first = ray_offsets[slot];
    let end = min(ray_offsets[slot + 1u], params.ray_capacity);
    let count = select(0u, end - first, end > first);
    for (var i = first; i < first + count; i++) {
        ray_owner[i] = slot;
    }
    states[slot].info.x = count;
}
