// World ReGIR build: fills each slot of every cell a lookup read in the last `keep_frames`
// frames (gilab::regir::regir_fill_slot over every light), and flags the cell built.
#import gilab::rng::{rng_init, STREAM_WORLD_REGIR}
#import gilab::frame::frame
#import gilab::regir::regir_fill_slot
#import gilab::world_regir::{world_regir, world_regir_slots, world_regir_cells, world_regir_cell_count, world_regir_cell_centre}

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let total = world_regir_cell_count();
    let s = world_regir.slots;
    if gid.x >= total * s {
        return;
    }
    let cell = gid.x / s;
    let mark = atomicLoad(&world_regir_cells[cell]);
    // Wrapping difference: a mark from before a frame-counter reset reads as very old.
    if mark == 0u || frame.frame_index + 1u - mark > world_regir.keep_frames {
        return;
    }
    var rng = rng_init(vec2<u32>(gid.x, 0u), frame.frame_index, STREAM_WORLD_REGIR, frame.seed);
    let c = world_regir_cell_centre(cell);
    world_regir_slots[gid.x] = regir_fill_slot(c.xyz, c.w, true, false, &rng);
    if gid.x % s == 0u {
        atomicStore(&world_regir_cells[total + cell], 1u);
    }
}
