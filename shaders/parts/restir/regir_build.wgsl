// ReGIR pass: fills every (cell, slot) that a pixel reads in the camera-centred grid with one
// light sample chosen by RIS (gilab::regir::regir_fill_slot) from the local lights (from every
// light in single-pool mode).
#import gilab::rng::{rng_init, STREAM_REGIR_BUILD}
#import gilab::frame::frame
#import gilab::regir::regir_fill_slot
#import gilab::restir::{params, regir_slots, regir_cell_centre, regir_used}

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let dims = params.regir_dims;
    let total = dims * dims * dims * params.regir_slots;
    if gid.x >= total || params.candidates == 0u {
        return;
    }
    let cell = gid.x / params.regir_slots;
    // Only cells some pixel reads (marked by regir_mark.wgsl this frame). A slot's random
    // stream depends only on its index, so the filled cells are the same as a full build's.
    if atomicLoad(&regir_used[cell]) == 0u {
        return;
    }
    var rng = rng_init(vec2<u32>(gid.x, 0u), frame.sample_offset, STREAM_REGIR_BUILD, frame.seed);
    regir_slots[gid.x] = regir_fill_slot(regir_cell_centre(cell), params.regir_cell_size, params.single_pool == 1u, params.regir_tree == 1u, &rng);
}
