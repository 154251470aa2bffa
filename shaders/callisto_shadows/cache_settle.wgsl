// Callisto shadows, after the `shadows` pass when `static_shadow_cache` is on: one invocation per
// slot of the static-visibility hash grid (static_cache.wgsl) settles what next frame's rays
// read, so that no read depends on the order this frame's rays ran in:
// - an empty slot goes to the largest key that bid for it this frame, and starts filling;
// - a slot whose cell has had `cache_samples` rays is filled: FILLED = VALUE.
#import gilab::callisto::{params, shadow_cache}
#import gilab::callisto_cache::{slot_word, SLOT_CLAIM, SLOT_OWNER, SLOT_VALUE, SLOT_FILLED}

@compute @workgroup_size(256, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let slot = gid.x;
    if slot >= params.cache_slots {
        return;
    }
    let owner = atomicLoad(&shadow_cache[slot_word(slot, SLOT_OWNER)]);
    if owner == 0u {
        let claim = atomicLoad(&shadow_cache[slot_word(slot, SLOT_CLAIM)]);
        if claim != 0u {
            atomicStore(&shadow_cache[slot_word(slot, SLOT_OWNER)], claim);
            atomicStore(&shadow_cache[slot_word(slot, SLOT_CLAIM)], 0u);
        }
        return;
    }
    let value = atomicLoad(&shadow_cache[slot_word(slot, SLOT_VALUE)]);
    if atomicLoad(&shadow_cache[slot_word(slot, SLOT_FILLED)]) == 0u && (value >> 16u) >= params.cache_samples {
        atomicStore(&shadow_cache[slot_word(slot, SLOT_FILLED)], value);
    }
}
