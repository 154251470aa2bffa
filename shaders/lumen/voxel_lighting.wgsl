// Voxel lighting, step 2 (the seed's "Voxel Lighting Update"), every frame after the surface
// cache's lighting: each stored visibility hit of every allocated brick is shaded from its
// object's cards facing that direction (the reflected light a ray arriving from that side
// takes back); directions with no surface or no card answer store EMPTY (weight 0).
#import gilab::tracing::{params, brick_table, brick_coord, brick_pool, fill_list, sdf_state, lit_list_index, STATE_LIT, MAX_GROUPS, level_voxel, lighting_voxel_size, voxel_dir, voxel_word_index, lighting_voxel_centre, seen_point, pack_rgb9e5, VOXEL_DIRS, EMPTY}
#import gilab::surface_cache::{sample_cache, cache_reflected}

// One workgroup per allocated brick (the list sdf_allocate wrote), a thread per lighting voxel.
@compute @workgroup_size(64, 1, 1)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let item = wg.y * MAX_GROUPS + wg.x;
    if item >= atomicLoad(&sdf_state[STATE_LIT]) {
        return;
    }
    let n = params.bricks_per_axis;
    let slot = fill_list[lit_list_index(item)];
    let l = slot / (n * n * n);
    let entry = brick_table[slot];
    let held = brick_coord[slot];
    if l >= params.levels_built || entry == EMPTY || held.w == 0 {
        return;
    }
    let voxel = level_voxel(l);
    let size = lighting_voxel_size(l);
    let centre = lighting_voxel_centre(held.xyz, li, size);
    for (var k = 0u; k < VOXEL_DIRS; k++) {
        let seen = brick_pool[voxel_word_index(0u, entry, li, k)];
        var word = EMPTY;
        if seen != EMPTY {
            // The hit is exact (a BVH ray): half a field voxel of depth tolerance.
            let s = sample_cache(seen_point(centre, size, k, seen), voxel_dir(k), seen & 0xffffu, 0.5 * voxel);
            if s.weight > 1e-4 {
                word = pack_rgb9e5(cache_reflected(s));
            }
        }
        brick_pool[voxel_word_index(1u, entry, li, k)] = word;
    }
}
