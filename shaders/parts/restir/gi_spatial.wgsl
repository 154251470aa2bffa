// ReSTIR GI pass 2: spatial reuse of GI samples from k neighbours in a disk (similar surfaces
// only); the sample's weight at this pixel uses this pixel's geometry term to the sample point
// (the reconnection shift in area measure, whose Jacobian the area-measure targets hold).
// Unbiased (`unbiased`): generalized balance-heuristic MIS weights over every reservoir taking
// part, m_i(y) = M_i p_i(y) / sum_j M_j p_j(y), with p_j the unshadowed target at reservoir j's
// surface (zero where the reconnection Jacobian towards this pixel leaves [1/10, 10]). Unlike
// uniform 1/Z weights it stays bounded when the targets differ much between pixels, as a glossy
// lobe's do under BSDF-sampled directions. Biased: M weights.
#import gilab::rng::{rng_init, rand, rand_pair, STREAM_GI_SPATIAL}
#import gilab::frame::frame
#import gilab::counters::{flush_counts, no_counts}
#import gilab::math::luminance
#import gilab::primary::{current_surface, GSurface}
#import gilab::restir::{params, gi_reservoirs, reservoir_index, parity, gi_reservoir_from, similar_neighbour, no_neighbours, neighbour_budget, gi_contribution, gi_target, gi_update, gi_jacobian_ok, empty_gi_reservoir, GiReservoir, GI_MAX_JACOBIAN, TEMPORAL_SEGMENT}

// The target of sample r at surface `domain`, as a reservoir there counts it when resampling
// at `receiver`: zero where the reconnection Jacobian G_receiver / G_domain is out of bounds.
fn domain_target(receiver_geom: f32, domain: GSurface, r: GiReservoir) -> f32 {
    let e = gi_contribution(domain, r);
    if e.geom <= 0.0 || receiver_geom <= 0.0 {
        return 0.0;
    }
    let j = receiver_geom / e.geom;
    if j > GI_MAX_JACOBIAN || j < 1.0 / GI_MAX_JACOBIAN {
        return 0.0;
    }
    return luminance(e.value);
}

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
                if n >= 0 {
                    used.ids[used.count] = u32(n);
                    used.count += 1u;
                }
            }
            if params.unbiased == 1u {
                // Candidate c = 0 is this pixel's reservoir, c > 0 neighbour c - 1's.
                out = empty_gi_reservoir();
                for (var c = 0u; c <= used.count; c++) {
                    var cand = r0;
                    if c > 0u {
                        cand = gi_reservoirs[reservoir_index(TEMPORAL_SEGMENT, used.ids[c - 1u])];
                    }
                    let here = gi_contribution(s, cand);
                    let target_here = luminance(here.value);
                    var own = 0.0;
                    var total = r0.m * target_here;
                    for (var j = 0u; j < used.count; j++) {
                        let nidx = used.ids[j];
                        let m_j = gi_reservoirs[reservoir_index(TEMPORAL_SEGMENT, nidx)].m;
                        let p = m_j * domain_target(here.geom, current_surface(nidx), cand);
                        total += p;
                        if j + 1u == c {
                            own = p;
                        }
                    }
                    if c == 0u {
                        own = r0.m * target_here;
                    }
                    var w = 0.0;
                    if total > 0.0 && cand.big_w > 0.0 {
                        w = own / total * target_here * cand.big_w;
                    }
                    gi_update(&out, cand, w, cand.m, rand(&rng));
                }
                out.target_pdf = gi_target(s, out);
                if out.target_pdf > 0.0 {
                    out.big_w = out.w_sum / out.target_pdf;
                } else {
                    out.big_w = 0.0;
                }
            } else {
                for (var j = 0u; j < used.count; j++) {
                    let nidx = used.ids[j];
                    let ns = current_surface(nidx);
                    let nr = gi_reservoirs[reservoir_index(TEMPORAL_SEGMENT, nidx)];
                    var w = 0.0;
                    if gi_jacobian_ok(s, ns, nr) {
                        w = gi_target(s, nr) * nr.big_w * nr.m;
                    }
                    gi_update(&out, nr, w, nr.m, rand(&rng));
                }
                out.target_pdf = gi_target(s, out);
                if out.target_pdf > 0.0 && out.m > 0.0 {
                    out.big_w = out.w_sum / (out.m * out.target_pdf);
                }
            }
        }
        gi_reservoirs[reservoir_index(parity(), idx)] = out;
    }
    flush_counts(local_index, counts);
}
