// Global SDF update, step 1 (levels flagged for update only): every brick slot whose level
// scrolled past it, or that a scene edit touched, or all of them when the level is rebuilt whole, gives its
// pool brick back to the free stack and is marked pending (brick_coord.w = 0). Slots that still
// hold the right brick keep it: scrolling rebuilds only the new slabs.
#import gilab::tracing::{params, brick_table, brick_coord, free_stack, sdf_state, wanted_brick, brick_edited, EMPTY}

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let n = params.bricks_per_axis;
    let slot = gid.x;
    if slot >= params.levels_built * n * n * n {
        return;
    }
    let l = slot / (n * n * n);
    if params.levels[l].update.x == 0u {
        return;
    }
    let b = wanted_brick(l, slot);
    let held = brick_coord[slot];
    let stale = held.w == 0 || any(held.xyz != b);
    if !(stale || params.levels[l].update.y != 0u || brick_edited(l, b)) {
        return;
    }
    let entry = brick_table[slot];
    if entry != EMPTY {
        free_stack[atomicAdd(&sdf_state[0], 1u)] = entry;
    }
    brick_table[slot] = EMPTY;
    brick_coord[slot] = vec4<i32>(b, 0);
}
