// ReSTIR GI pass 2: spatial reuse of GI samples from k neighbours in a disk (similar surfaces
// only); the sample's weight at this pixel uses this pixel's geometry term to the sample point
// (the reconnection Jacobian); 1/Z (unbiased) or M weights (biased).
#import gilab::rng::{rng_init, rand, rand_pair, STREAM_GI_SPATIAL}
#import gilab::frame::frame
#import gilab::counters::{flush_counts, no_counts}
#import gilab::primary::{current_surface}
#import gilab::restir::{params, gi_reservoirs, reservoir_index, parity, gi_reservoir_from, similar_neighbour, no_neighbours, neighbour_budget, gi_target, gi_update, gi_jacobian_ok, TEMPORAL_SEGMENT}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    var counts = no_counts();
    if gid.x < frame.size.x && gid.y < frame.size.y {
        let idx = gid.y * frame.size.x + gid.x;
        var rng = rng_init(gid.xy, frame.sample_offset, STREAM_GI_SPATIAL, frame.seed);
        let s = current_surface(idx);
        let r0 = gi_reservoirs[reservoir_index(TEMPORAL_SEGMENT, idx)];
        var out = gi_reservoir_from(r0, rand(&rng));
        var used = no_neighbours();
        let k = neighbour_budget();
        if s.pos.w > 0.5 && params.gi == 1u {
            for (var j = 0u; j < k; j++) {
                let n = similar_neighbour(gid.xy, idx, s, rand_pair(&rng));
                if n < 0 {
                    continue;
                }
                let nidx = u32(n);
                let ns = current_surface(nidx);
                let nr = gi_reservoirs[reservoir_index(TEMPORAL_SEGMENT, nidx)];
                // Out-of-bounds Jacobian: weight 0, but the neighbour still takes part in Z.
                var w = 0.0;
                if gi_jacobian_ok(s, ns, nr) {
                    w = gi_target(s, nr) * nr.big_w * nr.m;
                }
                gi_update(&out, nr, w, nr.m, rand(&rng));
                used.ids[used.count] = nidx;
                used.count += 1u;
            }
        }
        out.target_pdf = gi_target(s, out);
        if out.target_pdf > 0.0 && out.m > 0.0 {
            var z = out.m;
            if params.unbiased == 1u {
                z = r0.m;
                for (var j = 0u; j < used.count; j++) {
                    let nidx = used.ids[j];
                    let ns = current_surface(nidx);
                    if gi_target(ns, out) > 0.0 && gi_jacobian_ok(s, ns, out) {
                        z += gi_reservoirs[reservoir_index(TEMPORAL_SEGMENT, nidx)].m;
                    }
                }
            }
            out.big_w = out.w_sum / (z * out.target_pdf);
        }
        gi_reservoirs[reservoir_index(parity(), idx)] = out;
    }
    flush_counts(local_index, counts);
}
