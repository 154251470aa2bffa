// Per cell: sort of the cell's surfel list by slot, so gathers visit surfels in the same order
// every run (float sums, and the first MAX_GATHER of a crowded cell, stay the same). Slots are
// unique within a cell, so any correct sort gives the same list. A heap sort, in place: its
// n log n keeps a crowded cell from stalling the pass (the insertion sort used before took
// 6-43 ms per frame at 1920x1080 on an H100 with ReSTIR GI ending in the surfels).
#import gilab::surfels::{params, cell_offsets, cell_surfels}

// Moves the entry at heap index `start` down until the max-heap over the first `n` entries
// from `first` holds again.
fn sift_down(first: u32, start: u32, n: u32) {
    var root = start;
    loop {
        let child = 2u * root + 1u;
        if child >= n {
            break;
        }
        var larger = child;
        if child + 1u < n && cell_surfels[first + child + 1u] > cell_surfels[first + child] {
            larger = child + 1u;
        }
        let root_value = cell_surfels[first + root];
        let larger_value = cell_surfels[first + larger];
        if root_value >= larger_value {
            break;
        }
        cell_surfels[first + root] = larger_value;
        cell_surfels[first + larger] = root_value;
        root = larger;
    }
}

fn heap_sort(first: u32, end: u32) {
    let n = end - first;
    for (var i = n / 2u; i > 0u; i--) {
        sift_down(first, i - 1u, n);
    }
    for (var last = n - 1u; last > 0u; last--) {
        let top = cell_surfels[first];
        cell_surfels[first] = cell_surfels[first + last];
        cell_surfels[first + last] = top;
        sift_down(first, 0u, last);
    }
}

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let cell = gid.x;
    if cell >= params.cells {
        return;
    }
    let first = atomicLoad(&cell_offsets[cell]);
    let end = atomicLoad(&cell_offsets[cell + 1u]);
    if end > first + 1u {
        heap_sort(first, end);
    }
}
