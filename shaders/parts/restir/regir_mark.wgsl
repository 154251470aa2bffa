// ReGIR mark pass: flags the grid cell under each pixel's primary surface, so that
// regir_build.wgsl fills only cells that DI's initial candidates read this frame. On a small
// image most of the 16^3 cells hold no visible surface; building them was most of the frame.
#import gilab::frame::frame
#import gilab::primary::current_surface
#import gilab::restir::{params, regir_cell, regir_used}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= frame.size.x || gid.y >= frame.size.y || params.regir == 0u {
        return;
    }
    let s = current_surface(gid.y * frame.size.x + gid.x);
    if s.pos.w < 0.5 {
        return;
    }
    let cell = regir_cell(s.pos.xyz);
    if cell >= 0 {
        atomicStore(&regir_used[u32(cell)], 1u);
    }
}
