// Push (per slot): recycled surfels go onto the free stack above its current top, in slot
// order (positions from the prefix sum of recycle.wgsl's flags); the slot is marked free. The
// coverage pass then moves the stack counter by the total.
#import gilab::surfels::{params, surfels, pool, free_stack, slot_scan}

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let slot = gid.x;
    if slot >= params.max_surfels {
        return;
    }
    let rank = slot_scan[slot];
    if slot_scan[slot + 1u] > rank {
        free_stack[atomicLoad(&pool.free_count) + rank] = slot;
        surfels[slot].pos_radius.w = 0.0;
    }
}
