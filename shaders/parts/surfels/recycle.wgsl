// Recycling (per slot), after moving surfels on moving objects with them: the seed's heuristic decides which live surfels go back to the free
// stack, from the pool's fill level, frames since the surfel last lit a visible pixel, its
// distance, and whether the pixels it lit were over-covered; compared with a random number.
// Writes 1 per recycled slot for the prefix sum that gives each its stack position (push.wgsl).
#import gilab::frame::frame
#import gilab::math::max_component
#import gilab::rng::{rng_init, rand, STREAM_SURFEL_RECYCLE}
#import gilab::surfels::{params, surfels, pool, seen, slot_scan, is_live, surfel_id}
#import gilab::scene::{next_position, next_normal}


@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let slot = gid.x;
    if slot == 0u {
        atomicStore(&pool.request_total, 0u);
    }
    if slot >= params.max_surfels {
        return;
    }
    var recycle = 0u;
    if is_live(slot) {
        // Transform ids: a surfel on a moving object goes with it (its triangle's instance
        // record, identity for static geometry), before this frame's grid is built.
        let tri = surfel_id(surfels[slot]);
        if tri > 0u {
            let s = surfels[slot];
            surfels[slot].pos_radius = vec4<f32>(next_position(tri - 1u, s.pos_radius.xyz), s.pos_radius.w);
            surfels[slot].normal_id = vec4<f32>(next_normal(tri - 1u, s.normal_id.xyz), s.normal_id.w);
        }
        let last_seen = atomicLoad(&seen[3u * slot]);
        let lit = atomicLoad(&seen[3u * slot + 1u]);
        let crowded = atomicLoad(&seen[3u * slot + 2u]);
        atomicStore(&seen[3u * slot + 1u], 0u);
        atomicStore(&seen[3u * slot + 2u], 0u);
        let unseen = f32(frame.frame_index - min(last_seen, frame.frame_index));
        let fullness = f32(atomicLoad(&pool.live_count)) / f32(params.max_surfels);
        let dist = length(surfels[slot].pos_radius.xyz - frame.camera_pos.xyz);
        let far = clamp(dist / (16.0 * params.grid_half_extent), 0.0, 1.0);
        var p = 0.0;
        if unseen > 2.0 {
            // Out of view: likelier the longer, the fuller the pool and the farther away.
            p = clamp((unseen - 2.0) / 120.0, 0.0, 1.0) * (0.02 + fullness * fullness) * (0.5 + far);
            if fullness > 0.95 {
                p = max(p, 0.5);
            }
        }
        if lit > 0u && 2u * crowded > lit {
            // Over-covered (the camera backed away and surfels grew): thin them out.
            p = max(p, 0.1 * f32(crowded) / f32(lit));
        }
        var rng = rng_init(vec2<u32>(slot, 0u), frame.frame_index, STREAM_SURFEL_RECYCLE, frame.seed);
        if rand(&rng) < p {
            recycle = 1u;
        }
    }
    slot_scan[slot] = recycle;
}
