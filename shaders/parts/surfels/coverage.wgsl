// Gap detection (one 16x16 workgroup per block of spawn tiles; a tile is `params.spawn_tile`
// pixels on a side, 1-16): each pixel's surfel coverage from last frame's grid; each tile's
// least-covered pixel spawns a surfel when its coverage is below the target times a random
// number (the seed's randomised threshold). The seed's tile is 16x16 at 1080p; `spawn_tiles =
// "scaled"` keeps that tile's size against the surfels' (src/parts/surfels/params.rs). Ties
// (every pixel of an empty tile, every pixel of a hole) go to a random pixel of the tie each
// frame: with ties to the lowest index, surfels lined the top rows of a tile first, half of each
// footprint over the tile above, and a cold start filled the lower rows last (issue 57,
// docs/surfels.md).
// Thread 0 first commits last pass's pushes to the stack counter.
#import gilab::frame::frame
#import gilab::rng::{rng_init, rand, STREAM_SURFEL_SPAWN}
#import gilab::primary::current_surface
#import gilab::surfels::{params, pool, slot_scan, tile_scan, tile_pixel, gather, NONE}

const BLOCK: u32 = 16u;

// Per tile of the block (up to 16x16 tiles of one pixel): coverage << 8 | local pixel index.
var<workgroup> least: array<atomic<u32>, 256>;

@compute @workgroup_size(16, 16, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    atomicStore(&least[local_index], NONE);
    if gid.x == 0u && gid.y == 0u {
        let recycled = slot_scan[params.max_surfels];
        atomicAdd(&pool.free_count, recycled);
        atomicSub(&pool.live_count, recycled);
        pool.recycled = recycled;
    }
    let t = params.spawn_tile;
    let per_row = BLOCK / t;
    // This frame's tie-break: pixel indices XOR a random byte, the same for the whole block.
    var tie_rng = rng_init(wg.xy, frame.frame_index, STREAM_SURFEL_SPAWN, frame.seed ^ 0x9e3779b9u);
    let tie = u32(rand(&tie_rng) * 256.0) & 255u;
    workgroupBarrier();
    if gid.x < frame.size.x && gid.y < frame.size.y {
        let s = current_surface(gid.y * frame.size.x + gid.x);
        if s.pos.w > 0.5 {
            var coverage = 0.0;
            if pool.grid_center.w > 0.0 {
                coverage = gather(s.pos.xyz, s.normal_alpha.xyz, pool.grid_center.xyz, false).coverage;
            }
            let q = u32(clamp(coverage, 0.0, 15.0) * 4096.0);
            let sub = (lid.y / t) * per_row + lid.x / t;
            atomicMin(&least[sub], (q << 8u) | (local_index ^ tie));
        }
    }
    workgroupBarrier();
    // One thread per tile of the block writes its spawn request.
    if local_index < per_row * per_row {
        let tile_xy = wg.xy * per_row + vec2<u32>(local_index % per_row, local_index / per_row);
        let tiles_y = (frame.size.y + t - 1u) / t;
        if tile_xy.x < params.tiles_x && tile_xy.y < tiles_y {
            let tile = tile_xy.y * params.tiles_x + tile_xy.x;
            let key = atomicLoad(&least[local_index]);
            var pixel = NONE;
            if key != NONE {
                let coverage = f32(key >> 8u) / 4096.0;
                var rng = rng_init(tile_xy, frame.frame_index, STREAM_SURFEL_SPAWN, frame.seed);
                if coverage < params.coverage_target * rand(&rng) {
                    let l = (key & 255u) ^ tie;
                    pixel = (wg.y * BLOCK + l / BLOCK) * frame.size.x + wg.x * BLOCK + l % BLOCK;
                }
            }
            tile_pixel[tile] = pixel;
            tile_scan[tile] = select(0u, 1u, pixel != NONE);
        }
    }
}
