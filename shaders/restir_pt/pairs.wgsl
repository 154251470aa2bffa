// ReSTIR PT pass 3a (`spatial_pairs`): the shifts of paired spatial reuse. Pixel p owns its
// pairs {p, p + d_k} for this frame's offsets d_k (gilab::restir_pt::pair_offset); where both
// pixels hold surfaces that are similar both ways, p's path is shifted to p + d_k and that
// pixel's path to p (two shifts, one call site), and both are stored for `path_spatial`, which
// reads each pair from both ends.
#import gilab::frame::frame
#import gilab::counters::{flush_counts, no_counts, RAY_REUSE}
#import gilab::primary::{current_surface, similar}
#import gilab::restir_pt::{params, reservoirs, reservoir_index, TEMPORAL_SEGMENT, MAX_PAIRS, shift_path, failed_shift, pair_offset, offset_pixel, pair_shift_index, store_pair_shift}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    var counts = no_counts();
    if gid.x < frame.size.x && gid.y < frame.size.y {
        let idx = gid.y * frame.size.x + gid.x;
        let s = current_surface(idx);
        let c = reservoirs[reservoir_index(TEMPORAL_SEGMENT, idx)];
        for (var k = 0u; k < min(params.pairs, MAX_PAIRS); k++) {
            let q = offset_pixel(gid.xy, pair_offset(k));
            var holds = false;
            if q >= 0 {
                let sq = current_surface(u32(q));
                holds = similar(s, sq) && similar(sq, s);
            }
            for (var which = 0u; which < 2u; which++) {
                var sh = failed_shift(0u);
                if holds {
                    // This pixel's path to the neighbour (0), the neighbour's here (1).
                    var path = c;
                    var to = current_surface(u32(q));
                    if which == 1u {
                        path = reservoirs[reservoir_index(TEMPORAL_SEGMENT, u32(q))];
                        to = s;
                    }
                    if path.big_w > 0.0 {
                        sh = shift_path(path, to);
                        counts[RAY_REUSE] += sh.rays;
                    }
                }
                store_pair_shift(pair_shift_index(idx, k, which), sh, holds);
            }
        }
    }
    flush_counts(local_index, counts);
}
