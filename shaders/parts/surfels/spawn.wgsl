// Spawning (per tile): a tile that asked for a surfel pops the slot at its rank below the top of
// the free stack (rank from the prefix sum over tiles) and fills it from the primary surface:
// position, normal, radius, diffuse albedo, the id of the object (triangle) it sits on. A fresh
// surfel has no irradiance yet (it weighs nothing in gathers until its first rays), a uniform
// guiding map and a depth map at its diameter (no occluder seen).
#import gilab::frame::frame
#import gilab::primary::current_surface
#import gilab::surfels::{params, surfels, states, pool, free_stack, seen, guide, depth, tile_scan, tile_pixel, surfel_radius, Surfel, SurfelState, NONE, GUIDE_WORDS, DEPTH_TEXELS}

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let tile = gid.x;
    if tile >= params.tiles || tile_pixel[tile] == NONE {
        return;
    }
    let rank = tile_scan[tile];
    let free = atomicLoad(&pool.free_count);
    if rank >= free {
        return;
    }
    let slot = free_stack[free - 1u - rank];
    let s = current_surface(tile_pixel[tile]);
    let p = s.pos.xyz;
    let r = surfel_radius(p);
    let albedo = s.base_metal.xyz * (1.0 - s.base_metal.w);
    surfels[slot] = Surfel(vec4<f32>(p, r), vec4<f32>(s.geo_specular.xyz, bitcast<f32>(u32(s.prev_pos.w))), vec4<f32>(albedo, bitcast<f32>(frame.frame_index)));
    states[slot] = SurfelState(vec4<f32>(0.0), vec4<f32>(0.0, 0.0, 0.0, 1.0), vec4<f32>(0.0), vec4<u32>(0u));
    for (var w = 0u; w < GUIDE_WORDS; w++) {
        guide[slot * GUIDE_WORDS + w] = 0xffffffffu;
    }
    for (var t = 0u; t < DEPTH_TEXELS; t++) {
        depth[slot * DEPTH_TEXELS + t] = vec2<f32>(2.0 * r, 4.0 * r * r);
    }
    atomicStore(&seen[3u * slot], frame.frame_index);
    atomicStore(&seen[3u * slot + 1u], 0u);
    atomicStore(&seen[3u * slot + 2u], 0u);
}
