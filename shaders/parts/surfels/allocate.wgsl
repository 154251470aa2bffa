// Ray allocation (per slot): the global budget is split in proportion to the requests (up or
// down, the seed's second step), rounded stochastically so the expected total is the budget,
// capped per surfel. The counts are then prefix-summed into ray offsets.
#import gilab::frame::frame
#import gilab::rng::{rng_init, rand, STREAM_SURFEL_ALLOCATE}
#import gilab::surfels::{params, pool, ray_offsets}

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let slot = gid.x;
    if slot >= params.max_surfels {
        return;
    }
    let request = ray_offsets[slot];
    let total = atomicLoad(&pool.request_total);
    var count = 0u;
    if request > 0u && total > 0u {
        let share = f32(request) / f32(total) * f32(params.ray_budget);
        var rng = rng_init(vec2<u32>(slot, 0u), frame.frame_index, STREAM_SURFEL_ALLOCATE, frame.seed);
        count = u32(floor(share));
        if rand(&rng) < fract(share) {
            count += 1u;
        }
        count = min(count, params.max_rays_per_surfel);
    }
    ray_offsets[slot] = count;
}
