// Quarter-area apply, first half (per 2x2 block, the seed's default): the block's top-left
// pixel gathers the cell's surfels as apply does at full resolution, and leaves the irradiance
// for apply to upsample (`pixel_direct` past the pixels, one vec4 per block: rgb, w = 1 when
// the sample is on a surface). It marks the surfels it used as seen and writes the debug
// planes for the whole block.
#import gilab::frame::frame
#import gilab::primary::current_surface
#import gilab::surfels::{pixel_direct, gather, mark_reach, gathered_irradiance, grid_center_for, write_debug, block_sample_pixel, note_gather}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let blocks = (frame.size + 1u) / 2u;
    if gid.x >= blocks.x || gid.y >= blocks.y {
        return;
    }
    let px = frame.size.x * frame.size.y;
    let block = gid.y * blocks.x + gid.x;
    let idx = block_sample_pixel(block);
    let s = current_surface(idx);
    var out = vec4<f32>(0.0);
    var first_plane = vec4<f32>(0.0);
    var second_plane = vec4<f32>(0.0);
    if s.pos.w > 0.5 {
        // Surfels the block's other pixels see count as seen too (recycling keeps them): within
        // the block's diagonal of the sample, measured on the surface.
        let far = current_surface(min(idx + frame.size.x + 1u, frame.size.x * frame.size.y - 1u));
        mark_reach = select(0.0, length(far.pos.xyz - s.pos.xyz), far.pos.w > 0.5);
        mark_reach = min(mark_reach, 0.1 * s.wo_dist.w);
        let g = gather(s.pos.xyz, s.normal_alpha.xyz, grid_center_for(frame.camera_pos.xyz), true);
        out = vec4<f32>(gathered_irradiance(g), 1.0);
        // The block's four pixels saw its best surfel.
        let d = note_gather(g, 4u);
        first_plane = d.first;
        second_plane = d.second;
    }
    pixel_direct[px + block] = out;
    let corner = 2u * gid.xy;
    for (var k = 0u; k < 4u; k++) {
        let p = corner + vec2<u32>(k & 1u, k >> 1u);
        if p.x < frame.size.x && p.y < frame.size.y {
            write_debug(p.y * frame.size.x + p.x, first_plane, second_plane);
        }
    }
}
