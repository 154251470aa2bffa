// World probes to trace this frame (one workgroup, slot order, so the choice is deterministic):
// slots read in the last 8 frames that were never traced at their current grid position go to
// the "new" list, those traced before to the "old" list; world_update takes new ones first and
// refreshes old ones round-robin with what is left of its fixed budget (the seed's fixed update
// cost, variable lighting latency).
#import gilab::frame::frame
#import gilab::lumen_probes::{pp, probe_state, world_header, world_slot_coord, world_slots, STATE_WORLD_NEW, STATE_WORLD_OLD}

const RECENT_FRAMES: u32 = 8u;

var<workgroup> scan_new: array<u32, 256>;
var<workgroup> scan_old: array<u32, 256>;

@compute @workgroup_size(256, 1, 1)
fn main(@builtin(local_invocation_index) li: u32) {
    var base_new = 0u;
    var base_old = 0u;
    let total = world_slots();
    for (var first = 0u; first < total; first += 256u) {
        let slot = first + li;
        var is_new = 0u;
        var is_old = 0u;
        if slot < total {
            let mark = atomicLoad(&probe_state[pp.counts_b.x + slot]);
            if mark > 0u && mark + RECENT_FRAMES > frame.frame_index {
                let h = world_header(slot);
                let traced = h.w >= 0.0 && all(vec3<i32>(h.xyz) == world_slot_coord(slot));
                is_old = select(0u, 1u, traced);
                is_new = 1u - is_old;
            }
        }
        scan_new[li] = is_new;
        scan_old[li] = is_old;
        workgroupBarrier();
        // Inclusive prefix sums (Hillis-Steele).
        for (var step = 1u; step < 256u; step *= 2u) {
            var a = scan_new[li];
            var b = scan_old[li];
            if li >= step {
                a += scan_new[li - step];
                b += scan_old[li - step];
            }
            workgroupBarrier();
            scan_new[li] = a;
            scan_old[li] = b;
            workgroupBarrier();
        }
        if is_new == 1u {
            atomicStore(&probe_state[pp.counts_b.y + base_new + scan_new[li] - 1u], slot);
        }
        if is_old == 1u {
            atomicStore(&probe_state[pp.counts_b.y + total + base_old + scan_old[li] - 1u], slot);
        }
        base_new += scan_new[255];
        base_old += scan_old[255];
        workgroupBarrier();
    }
    if li == 0u {
        atomicStore(&probe_state[STATE_WORLD_NEW], base_new);
        atomicStore(&probe_state[STATE_WORLD_OLD], base_old);
    }
}
