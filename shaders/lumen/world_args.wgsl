// Workgroups of the world trace: one thread per ray the screen traces left unresolved.
#import gilab::lumen_probes::{probe_state, STATE_WORLD_RAYS, STATE_WORLD_ARGS}

@compute @workgroup_size(1, 1, 1)
fn main() {
    let n = atomicLoad(&probe_state[STATE_WORLD_RAYS]);
    atomicStore(&probe_state[STATE_WORLD_ARGS], (n + 63u) / 64u);
    atomicStore(&probe_state[STATE_WORLD_ARGS + 1u], 1u);
    atomicStore(&probe_state[STATE_WORLD_ARGS + 2u], 1u);
}
