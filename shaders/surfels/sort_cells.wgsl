// Per cell: insertion sort of the cell's surfel list by slot, so gathers visit surfels in the
// same order every run (float sums, and the first MAX_GATHER of a crowded cell, stay the same).
#import gilab::surfels::{params, cell_offsets, cell_surfels}

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let cell = gid.x;
    if cell >= params.cells {
        return;
    }
    let first = atomicLoad(&cell_offsets[cell]);
    let end = atomicLoad(&cell_offsets[cell + 1u]);
    for (var i = first + 1u; i < end; i++) {
        let v = cell_surfels[i];
        var j = i;
        while j > first && cell_surfels[j - 1u] > v {
            cell_surfels[j] = cell_surfels[j - 1u];
            j -= 1u;
        }
        cell_surfels[j] = v;
    }
}
