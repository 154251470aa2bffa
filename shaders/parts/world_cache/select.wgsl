// World probes to trace this frame (one workgroup, slot order within each group, so the choice is
// deterministic). Slots read in the last 8 frames that were never traced at their current grid
// position go to the "new" list. The others read go to the "old" list ordered by staleness: the
// frames since each was last traced, in AGE_BUCKETS buckets, the stalest first. world_update
// takes new ones first, then old ones in list order, with its fixed budget (the seed's fixed
// update cost, variable lighting latency); the oldest probe is always next.
#import gilab::frame::frame
#import gilab::world_cache::{wc, world_lists, world_header, world_slot_coord, world_slots, world_read_frame, world_traced_frame, world_list_offset, WORLD_STATE_NEW, WORLD_STATE_OLD}

const RECENT_FRAMES: u32 = 8u;
// Ages 1..AGE_BUCKETS - 1 frames have a bucket each; older probes share the last one.
const AGE_BUCKETS: u32 = 64u;

// Each thread classifies PER_THREAD consecutive slots, so a chunk is 1024 slots and the scans
// and barriers run a quarter as often as with one slot a thread (lavapipe runs a barrier as a
// switch through every thread; the lists are the same, in slot order).
const PER_THREAD: u32 = 4u;
const CHUNK: u32 = 1024u;

var<workgroup> scan: array<u32, 256>;
var<workgroup> histogram: array<atomic<u32>, AGE_BUCKETS>;
var<workgroup> cutoff: u32;

// 0: not read recently; 1: new; 2 + bucket: old, with its age bucket.
fn classify(slot: u32) -> u32 {
    let mark = world_read_frame(slot);
    if mark == 0u || mark + RECENT_FRAMES <= frame.frame_index {
        return 0u;
    }
    let h = world_header(slot);
    if h.w < 0.0 || any(vec3<i32>(h.xyz) != world_slot_coord(slot)) {
        return 1u;
    }
    let age = frame.frame_index + 1u - world_traced_frame(slot);
    return 2u + min(age, AGE_BUCKETS - 1u);
}

// Inclusive prefix sum of `scan` (Hillis-Steele).
fn scan_counts(li: u32) {
    for (var step = 1u; step < 256u; step *= 2u) {
        var a = scan[li];
        if li >= step {
            a += scan[li - step];
        }
        workgroupBarrier();
        scan[li] = a;
        workgroupBarrier();
    }
}

// Appends this chunk's flagged slots (bit k of `flags`: slot first + li * PER_THREAD + k) to the
// list at `offset` after the `base` already listed, in slot order; returns how many it added.
fn append_chunk(li: u32, first: u32, flags: u32, base: u32, offset: u32) -> u32 {
    let count = countOneBits(flags);
    scan[li] = count;
    workgroupBarrier();
    scan_counts(li);
    var at = base + scan[li] - count;
    for (var k = 0u; k < PER_THREAD; k++) {
        if (flags & (1u << k)) != 0u {
            world_lists[offset + at] = first + li * PER_THREAD + k;
            at += 1u;
        }
    }
    let added = scan[255];
    workgroupBarrier();
    return added;
}

@compute @workgroup_size(256, 1, 1)
fn main(@builtin(local_invocation_index) li: u32) {
    let total = world_slots();
    if li < AGE_BUCKETS {
        atomicStore(&histogram[li], 0u);
    }
    workgroupBarrier();
    // Pass 1: the new list (slot order) and the histogram of old probes' ages.
    var base_new = 0u;
    for (var first = 0u; first < total; first += CHUNK) {
        var flags = 0u;
        for (var k = 0u; k < PER_THREAD; k++) {
            let slot = first + li * PER_THREAD + k;
            if slot < total {
                let c = classify(slot);
                if c == 1u {
                    flags |= 1u << k;
                }
                if c >= 2u {
                    atomicAdd(&histogram[c - 2u], 1u);
                }
            }
        }
        base_new += append_chunk(li, first, flags, base_new, world_list_offset());
    }
    // The oldest bucket that the old probes' share of the budget reaches: buckets above it are
    // listed first, the cutoff bucket after them (world_update takes what its budget allows).
    if li == 0u {
        let budget = wc.shape.w - min(base_new, wc.shape.w);
        var taken = 0u;
        var c = AGE_BUCKETS - 1u;
        loop {
            taken += atomicLoad(&histogram[c]);
            if taken >= budget || c == 0u {
                break;
            }
            c -= 1u;
        }
        cutoff = c;
    }
    let limit = workgroupUniformLoad(&cutoff);
    // Passes 2 and 3: the old list, stalest buckets first.
    var base_old = 0u;
    for (var pass_index = 0u; pass_index < 2u; pass_index++) {
        for (var first = 0u; first < total; first += CHUNK) {
            var flags = 0u;
            for (var k = 0u; k < PER_THREAD; k++) {
                let slot = first + li * PER_THREAD + k;
                if slot < total {
                    let c = classify(slot);
                    let bucket = c - 2u;
                    let wanted = select(bucket == limit, bucket > limit, pass_index == 0u);
                    if c >= 2u && wanted {
                        flags |= 1u << k;
                    }
                }
            }
            base_old += append_chunk(li, first, flags, base_old, world_list_offset() + total);
        }
    }
    if li == 0u {
        world_lists[WORLD_STATE_NEW] = base_new;
        world_lists[WORLD_STATE_OLD] = base_old;
    }
}
