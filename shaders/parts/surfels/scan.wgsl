// Exclusive prefix sum of n u32 values in place, the total written after them (values[n]):
// `scan_local` scans blocks of SCAN_BLOCK values and keeps each block's sum, `scan_blocks` scans
// the block sums in one workgroup (up to 256 * 16 blocks, 4M values), `scan_add` adds each
// block's offset. Surfels use it for free-stack positions, cell lists and ray offsets, so slot
// and ray order never depend on thread scheduling. Entry points share one layout (group 0).

struct ScanParams {
    n: u32,
}

@group(0) @binding(0) var<uniform> scan: ScanParams;
@group(0) @binding(1) var<storage, read_write> values: array<u32>;
@group(0) @binding(2) var<storage, read_write> blocks: array<u32>;

const THREADS: u32 = 256u;
const PER_THREAD: u32 = 4u;
const SCAN_BLOCK: u32 = 1024u;

var<workgroup> partial: array<u32, 256>;

// Exclusive scan of one value per thread across the workgroup (Hillis-Steele); returns the
// thread's offset and leaves the workgroup total in partial[THREADS - 1] + its own value.
fn workgroup_exclusive(t: u32, v: u32) -> u32 {
    partial[t] = v;
    workgroupBarrier();
    for (var stride = 1u; stride < THREADS; stride *= 2u) {
        var add = 0u;
        if t >= stride {
            add = partial[t - stride];
        }
        workgroupBarrier();
        partial[t] += add;
        workgroupBarrier();
    }
    return partial[t] - v;
}

@compute @workgroup_size(256, 1, 1)
fn scan_local(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) t: u32) {
    let base = wg.x * SCAN_BLOCK + t * PER_THREAD;
    var v: array<u32, 4>;
    var sum = 0u;
    for (var k = 0u; k < PER_THREAD; k++) {
        let i = base + k;
        v[k] = select(0u, values[i], i < scan.n);
        sum += v[k];
    }
    var running = workgroup_exclusive(t, sum);
    for (var k = 0u; k < PER_THREAD; k++) {
        let i = base + k;
        if i < scan.n {
            values[i] = running;
        }
        running += v[k];
    }
    if t == THREADS - 1u {
        blocks[wg.x] = running;
    }
}

@compute @workgroup_size(256, 1, 1)
fn scan_blocks(@builtin(local_invocation_index) t: u32) {
    let count = (scan.n + SCAN_BLOCK - 1u) / SCAN_BLOCK;
    let chunk = (count + THREADS - 1u) / THREADS;
    let first = t * chunk;
    var sum = 0u;
    for (var k = 0u; k < chunk; k++) {
        if first + k < count {
            sum += blocks[first + k];
        }
    }
    var running = workgroup_exclusive(t, sum);
    for (var k = 0u; k < chunk; k++) {
        if first + k < count {
            let b = blocks[first + k];
            blocks[first + k] = running;
            running += b;
        }
    }
    if t == THREADS - 1u {
        values[scan.n] = running;
    }
}

@compute @workgroup_size(256, 1, 1)
fn scan_add(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) t: u32) {
    let offset = blocks[wg.x];
    for (var k = 0u; k < PER_THREAD; k++) {
        let i = wg.x * SCAN_BLOCK + t * PER_THREAD + k;
        if i < scan.n {
            values[i] += offset;
        }
    }
}
