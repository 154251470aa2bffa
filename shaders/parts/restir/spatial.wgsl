// ReSTIR pass 3: spatial reuse from k neighbours in a disk (similar surfaces only), with 1/Z
// (unbiased) or M-weighted (biased) contribution weights and the optional bidirectional
// occlusion test; writes this frame's final reservoirs.
#import gilab::rng::{rng_init, rand, rand_pair, STREAM_DI_SPATIAL}
#import gilab::frame::frame
#import gilab::counters::{flush_counts, no_counts, RAY_REUSE}
#import gilab::primary::{GSurface, current_surface}
#import gilab::restir::{params, reservoirs, Reservoir, reservoir_index, parity, reservoir_from, similar_neighbour, no_neighbours, neighbour_budget, contribution, target_at, visible, update, TEMPORAL_SEGMENT}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    var counts = no_counts();
    if gid.x < frame.size.x && gid.y < frame.size.y {
        let idx = gid.y * frame.size.x + gid.x;
        var rng = rng_init(gid.xy, frame.sample_offset, STREAM_DI_SPATIAL, frame.seed);
        let s = current_surface(idx);
        let r0 = reservoirs[reservoir_index(TEMPORAL_SEGMENT, idx)];
        var out = reservoir_from(r0, rand(&rng));
        var used = no_neighbours();
        let k = neighbour_budget();
        if s.pos.w > 0.5 {
            for (var j = 0u; j < k; j++) {
                let n = similar_neighbour(gid.xy, idx, s, rand_pair(&rng));
                if n < 0 {
                    continue;
                }
                let nidx = u32(n);
                let nr = reservoirs[reservoir_index(TEMPORAL_SEGMENT, nidx)];
                var t = target_at(s, nr);
                if params.bidirectional == 1u && t > 0.0 && nr.big_w > 0.0 {
                    counts[RAY_REUSE] += 1u;
                    let c = contribution(s, nr.light, vec2<f32>(nr.bary_u, nr.bary_v));
                    if !visible(s, c.light) {
                        t = 0.0;
                    }
                }
                update(&out, nr, t * nr.big_w * nr.m, nr.m, rand(&rng));
                used.ids[used.count] = nidx;
                used.count += 1u;
            }
        }
        out.target_pdf = target_at(s, out);
        if out.target_pdf > 0.0 && out.m > 0.0 {
            var z = out.m;
            if params.unbiased == 1u {
                // 1/Z: the M of every reservoir whose own surface could have produced the sample
                // (unshadowed support, as in the temporal pass).
                z = r0.m;
                for (var j = 0u; j < used.count; j++) {
                    let nidx = used.ids[j];
                    let ns = current_surface(nidx);
                    if target_at(ns, out) > 0.0 {
                        z += reservoirs[reservoir_index(TEMPORAL_SEGMENT, nidx)].m;
                    }
                }
            }
            if z > 0.0 {
                out.big_w = out.w_sum / (z * out.target_pdf);
            }
        }
        reservoirs[reservoir_index(parity(), idx)] = out;
    }
    flush_counts(local_index, counts);
}
