// The hash radiance cache's resolve, once a frame after its update: each slot's sums of this
// frame join its average (history capped at max_samples samples); a slot without a sample for
// stale_frames frames is freed. Lookups probe every slot of a key's run, empty or not, so a freed
// slot breaks no other key's run and no compaction is needed for lookups to stay right.
#import gilab::hash_cache::{hash_params, hash_words, hash_cells, FIXED_SCALE}

// Dispatched as rows of workgroups (src/parts/hash_cache.rs): 2^24 slots are more workgroups
// than one dimension may hold.
@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let slot = gid.y * groups.x * 64u + gid.x;
    let cap = hash_params.capacity;
    if slot >= cap || atomicLoad(&hash_words[slot]) == 0u {
        return;
    }
    let base = cap + 4u * slot;
    let n = atomicExchange(&hash_words[base + 3u], 0u);
    let sum = vec3<f32>(f32(atomicExchange(&hash_words[base], 0u)), f32(atomicExchange(&hash_words[base + 1u], 0u)), f32(atomicExchange(&hash_words[base + 2u], 0u))) / FIXED_SCALE;
    let age_at = 5u * cap + slot;
    var cell = hash_cells[slot];
    if n > 0u {
        let total = cell.w + f32(n);
        cell = vec4<f32>((cell.xyz * cell.w + sum) / total, min(total, hash_params.max_samples));
        atomicStore(&hash_words[age_at], 0u);
    } else {
        let age = atomicLoad(&hash_words[age_at]) + 1u;
        atomicStore(&hash_words[age_at], age);
        if age > hash_params.stale_frames {
            atomicStore(&hash_words[slot], 0u);
            atomicStore(&hash_words[age_at], 0u);
            cell = vec4<f32>(0.0);
        }
    }
    hash_cells[slot] = cell;
}
