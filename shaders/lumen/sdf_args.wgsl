// Global SDF update, step 3 (one invocation): takes the popped bricks off the free stack and
// writes each level's fill dispatch (one workgroup per brick), then the voxel lighting's (one
// workgroup per allocated brick, rows of MAX_GROUPS).
#import gilab::tracing::{sdf_state, STATE_LIT, MAX_GROUPS}

struct Args {
    x: u32,
    y: u32,
    z: u32,
}

@group(3) @binding(0) var<storage, read_write> fill_args: array<Args, 7>;

@compute @workgroup_size(1, 1, 1)
fn main() {
    let free = atomicLoad(&sdf_state[0]);
    let pops = atomicLoad(&sdf_state[3]);
    atomicStore(&sdf_state[0], free - min(pops, free));
    atomicStore(&sdf_state[3], 0u);
    for (var l = 0u; l < 6u; l++) {
        fill_args[l] = Args(atomicLoad(&sdf_state[4u + l]), 1u, 1u);
    }
    let lit = atomicLoad(&sdf_state[STATE_LIT]);
    fill_args[6] = Args(min(lit, MAX_GROUPS), (lit + MAX_GROUPS - 1u) / MAX_GROUPS, 1u);
}
