// ReSTIR pass 3: spatial reuse from k neighbours in a disk (similar surfaces only), with
// balance-heuristic MIS (unbiased) or M-weighted (biased) contribution weights and the optional bidirectional
// occlusion test; writes this frame's final reservoirs.
#import gilab::rng::{Rng, rng_init, rand, rand_pair, STREAM_DI_SPATIAL}
#import gilab::frame::frame
#import gilab::counters::{flush_counts, no_counts, RAY_REUSE}
#import gilab::primary::{GSurface, current_surface}
#import gilab::restir::{params, reservoirs, Reservoir, reservoir_index, parity, reservoir_from, empty_reservoir, similar_neighbour, Neighbours, no_neighbours, neighbour_budget, contribution, target_at, visible, update, TEMPORAL_SEGMENT}

// Input k of a spatial reuse: the pixel's own reservoir (k = 0), then each merged neighbour's.
fn input_reservoir(r0: Reservoir, used: Neighbours, k: u32) -> Reservoir {
    if k == 0u {
        return r0;
    }
    return reservoirs[reservoir_index(TEMPORAL_SEGMENT, used.ids[k - 1u])];
}

// The target of reservoir r's sample at input k's own surface (one call site: drivers inline
// every call, and each copy of the target costs seconds of compile time on lavapipe).
fn input_target(s: GSurface, used: Neighbours, k: u32, r: Reservoir) -> f32 {
    var at = s;
    if k > 0u {
        at = current_surface(used.ids[k - 1u]);
    }
    return target_at(at, r);
}

// The unbiased combination by the generalized balance heuristic (Bitterli et al. 2020, eq. 22;
// Lin et al. 2022, GRIS): input i's sample y_i is resampled with weight m_i(y_i) p̂(y_i) W_i,
// where m_i(y) = M_i p̂_i(y) / Σ_k M_k p̂_k(y) over every input's own surface, and then
// W = w_sum / p̂(y). The weights sum to one for every y, so the result is unbiased. Unlike 1/Z's
// uniform weights, a sample that was dim where it was drawn (a large W_i) and is bright here gets
// a small m_i instead of becoming a firefly: on a glossy floor, where the targets of
// neighbouring pixels differ most, 1/Z's fireflies kept the image 15% off the reference after
// 512 accumulated frames (docs/restir.md). `here[j]`: neighbour j's sample's target at this
// pixel (0 where the bidirectional test found it occluded).
fn balance_heuristic_reuse(s: GSurface, r0: Reservoir, used: Neighbours, here: array<f32, 8>, rng: ptr<function, Rng>) -> Reservoir {
    var out = empty_reservoir();
    let inputs = used.count + 1u;
    for (var i = 0u; i < inputs; i++) {
        let ri = input_reservoir(r0, used, i);
        var t = r0.target_pdf;
        if i > 0u {
            t = here[i - 1u];
        }
        var w = 0.0;
        if ri.big_w > 0.0 && t > 0.0 {
            var own = 0.0;
            var all = 0.0;
            for (var k = 0u; k < inputs; k++) {
                let mk = input_reservoir(r0, used, k).m * input_target(s, used, k, ri);
                all += mk;
                if k == i {
                    own = mk;
                }
            }
            if all > 0.0 {
                w = own / all * t * ri.big_w;
            }
        }
        // The target here of the kept sample is t: no second evaluation. Nothing kept: target 0
        // (and W = 0).
        if update(&out, ri, w, ri.m, rand(rng)) {
            out.target_pdf = t;
        }
    }
    if out.target_pdf > 0.0 {
        out.big_w = out.w_sum / out.target_pdf;
    }
    return out;
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    var counts = no_counts();
    if gid.x < frame.size.x && gid.y < frame.size.y {
        let idx = gid.y * frame.size.x + gid.x;
        var rng = rng_init(gid.xy, frame.sample_offset, STREAM_DI_SPATIAL, frame.seed);
        let s = current_surface(idx);
        let r0 = reservoirs[reservoir_index(TEMPORAL_SEGMENT, idx)];
        // Its target comes with the sample (biased mode; see below).
        var out = reservoir_from(r0, rand(&rng));
        var used = no_neighbours();
        var here = array<f32, 8>(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
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
                if update(&out, nr, t * nr.big_w * nr.m, nr.m, rand(&rng)) {
                    out.target_pdf = t;
                }
                here[used.count] = t;
                used.ids[used.count] = nidx;
                used.count += 1u;
            }
        }
        if params.unbiased == 1u {
            if s.pos.w > 0.5 {
                out = balance_heuristic_reuse(s, r0, used, here, &rng);
            }
        } else {
            // Biased: M-weighted (1/M), with the kept sample's target tracked above.
            if out.target_pdf > 0.0 && out.m > 0.0 {
                out.big_w = out.w_sum / (out.m * out.target_pdf);
            }
        }
        reservoirs[reservoir_index(parity(), idx)] = out;
    }
    flush_counts(local_index, counts);
}
