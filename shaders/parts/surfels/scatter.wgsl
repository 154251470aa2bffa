// Grid scatter (per slot): each live surfel writes its slot into the lists of the cells it
// overlaps (offsets from the prefix sum of prepare.wgsl's counts). Order within a cell depends
// on scheduling until sort_cells.wgsl sorts it.
#import gilab::frame::frame
#import gilab::surfels::{params, surfels, cell_offsets, counters, CELL_CURSORS, cell_surfels, is_live, overlapped_cells, grid_center_for, NONE}

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let slot = gid.x;
    if slot >= params.max_surfels || !is_live(slot) {
        return;
    }
    let s = surfels[slot];
    let cells = overlapped_cells(s.pos_radius.xyz, s.pos_radius.w, grid_center_for(frame.camera_pos.xyz));
    for (var k = 0u; k < 8u; k++) {
        let c = cells[k];
        if c != NONE {
            cell_surfels[atomicLoad(&cell_offsets[c]) + atomicAdd(&counters[CELL_CURSORS + c], 1u)] = slot;
        }
    }
}
