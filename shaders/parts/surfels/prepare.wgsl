// Per slot, after spawning: thread 0 commits the spawns to the stack counter and records the
// grid centre; each live surfel takes this frame's radius (constant screen size, at most half
// its cell), counts itself into every cell its bounding box overlaps (the grid's count step),
// and requests rays: more when young, when its irradiance varies, while it lights the image.
#import gilab::frame::frame
#import gilab::math::luminance
#import gilab::surfels::{params, surfels, states, pool, seen, tile_scan, cell_offsets, ray_offsets, is_live, surfel_radius, overlapped_cells, grid_center_for, spawn_frame, NONE, REQUEST_SCALE}

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let slot = gid.x;
    let center = grid_center_for(frame.camera_pos.xyz);
    if slot == 0u {
        let free = atomicLoad(&pool.free_count);
        let spawned = min(tile_scan[params.tiles], free);
        atomicSub(&pool.free_count, spawned);
        atomicAdd(&pool.live_count, spawned);
        pool.spawned = spawned;
        pool.grid_center = vec4<f32>(center, 1.0);
    }
    if slot >= params.max_surfels {
        return;
    }
    if !is_live(slot) {
        ray_offsets[slot] = 0u;
        return;
    }
    let s = surfels[slot];
    let p = s.pos_radius.xyz;
    let r = surfel_radius(p);
    surfels[slot].pos_radius.w = r;
    let cells = overlapped_cells(p, r, center);
    for (var k = 0u; k < 8u; k++) {
        if cells[k] != NONE {
            atomicAdd(&cell_offsets[cells[k]], 1u);
        }
    }
    // The seed's request: a dormant base, more for variance and for young surfels, much less
    // for surfels out of view.
    let st = states[slot];
    let age = f32(frame.frame_index - spawn_frame(s));
    let mean = max(luminance(st.mean.xyz), 1e-4);
    let relative_deviation = clamp(sqrt(max(luminance(st.variance.xyz), 0.0)) / mean, 0.0, 4.0);
    var request = 0.5 + 2.0 * relative_deviation + 8.0 * exp(-age / 16.0);
    if st.mean.w <= 0.0 {
        request = 16.0;
    }
    let unseen = frame.frame_index - min(atomicLoad(&seen[3u * slot]), frame.frame_index);
    if unseen > 1u {
        request *= 0.1;
    }
    let fixed = max(u32(request * REQUEST_SCALE), 1u);
    ray_offsets[slot] = fixed;
    atomicAdd(&pool.request_total, fixed);
}
