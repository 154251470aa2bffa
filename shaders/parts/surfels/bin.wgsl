// Ray binning, pass 1 (the seed's "bin rays by position and orientation", `ray_binning`; one
// invocation per ray, indirect dispatch like the trace pass): the ray's bin is the 1D index of
// its surfel's grid cell (low 12 bits) and its direction's octahedral quadrant (4 bits: a 4x4
// grid over the octahedral map), drawn exactly as the trace pass will draw it. Writes the bin
// and counts it; a prefix sum over the bins follows, then bin_order.wgsl.
#import gilab::frame::frame
#import gilab::math::to_world
#import gilab::rng::{rng_init, STREAM_SURFEL_RAYS}
#import gilab::surfels::{params, surfels, ray_offsets, ray_owner, counters, cell_of, grid_center_for, ray_bin_keys}
#import gilab::surfel_rays::surfel_ray_direction

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if i >= min(ray_offsets[params.max_surfels], params.ray_capacity) {
        return;
    }
    let slot = ray_owner[i];
    let k = i - ray_offsets[slot];
    let s = surfels[slot];
    var rng = rng_init(vec2<u32>(slot, k), frame.frame_index, STREAM_SURFEL_RAYS, frame.seed);
    let d = to_world(surfel_ray_direction(slot, &rng).v, s.normal_id.xyz);
    // Octahedral map of the direction, quantised to 4x4.
    let a = d / max(abs(d.x) + abs(d.y) + abs(d.z), 1e-20);
    var e = a.xy;
    if a.z < 0.0 {
        e = (1.0 - abs(a.yx)) * select(vec2<f32>(-1.0), vec2<f32>(1.0), a.xy >= vec2<f32>(0.0));
    }
    let q = min(vec2<u32>((e * 0.5 + 0.5) * 4.0), vec2<u32>(3u));
    let cell = cell_of(s.pos_radius.xyz, grid_center_for(frame.camera_pos.xyz));
    let bin = ((cell & 0xfffu) << 4u) | (q.y * 4u + q.x);
    atomicStore(&counters[ray_bin_keys() + i], bin);
    atomicAdd(&counters[bin], 1u);
}
