// ReSTIR PT pass 3: spatial reuse with pairwise MIS (GRIS's generalised balance heuristic in
// its pairwise form, with the canonical sample). Up to `spatial_count` neighbours in a disk of
// `spatial_radius` pixels on similar surfaces; each neighbour's path is shifted to this pixel,
// and this pixel's path to each neighbour to weigh it: two shifts per neighbour. The kept path
// goes to this frame's final reservoir. With `spatial_pairs` (params.pairs > 0) the
// neighbours are p +- d_k for this frame's offsets, and both shifts of each pair come from
// `path_pairs` (pairs.wgsl): no shift is traced here.
#import gilab::rng::{Rng, rng_init, rand, rand_pair, STREAM_PT_SPATIAL}
#import gilab::frame::frame
#import gilab::counters::{flush_counts, no_counts, RAY_REUSE}
#import gilab::math::luminance
#import gilab::primary::{current_surface, disk_neighbour, similar}
#import gilab::restir_pt::{params, reservoirs, reservoir_index, parity, TEMPORAL_SEGMENT, PathReservoir, Shifted, shift_path, adopt, empty_stream, stream_add, stream_result, pair_share, pair_balance, write_debug, MAX_PAIRS, pair_offset, offset_pixel, pair_shift_index, load_pair_shift, pair_holds}

// A neighbour of paired reuse: its pixel, the shift of its path to this pixel and of this
// pixel's path to it (stored by the pair's owner).
struct PairedNeighbour {
    pixel: u32,
    to_here: u32,
    from_here: u32,
}

// Spatial reuse from the pairs' stored shifts (pairwise MIS as below, the same weights).
fn paired_reuse(gid: vec2<u32>, idx: u32, c: PathReservoir, rng: ptr<function, Rng>, stats: ptr<function, vec3<f32>>) -> PathReservoir {
    var nb: array<PairedNeighbour, 8>;
    var n = 0u;
    for (var k = 0u; k < min(params.pairs, MAX_PAIRS); k++) {
        let d = pair_offset(k);
        // p + d_k: this pixel owns the pair.
        let q = offset_pixel(gid, d);
        if q >= 0 && pair_holds(pair_shift_index(idx, k, 0u)) {
            nb[n] = PairedNeighbour(u32(q), pair_shift_index(idx, k, 1u), pair_shift_index(idx, k, 0u));
            n += 1u;
        }
        // p - d_k: that pixel owns it, with this pixel as its p + d_k.
        let o = offset_pixel(gid, -d);
        if o >= 0 && pair_holds(pair_shift_index(u32(o), k, 0u)) {
            nb[n] = PairedNeighbour(u32(o), pair_shift_index(u32(o), k, 0u), pair_shift_index(u32(o), k, 1u));
            n += 1u;
        }
    }
    if n == 0u {
        return c;
    }
    var m_total = c.m;
    for (var j = 0u; j < n; j++) {
        m_total += reservoirs[reservoir_index(TEMPORAL_SEGMENT, nb[j].pixel)].m;
    }
    let nf = f32(n);
    var st = empty_stream();
    var mis_c = 0.0;
    for (var j = 0u; j < n; j++) {
        let q = reservoirs[reservoir_index(TEMPORAL_SEGMENT, nb[j].pixel)];
        let share = pair_share(c.m, q.m, nf, m_total);
        if c.big_w > 0.0 {
            let sc = load_pair_shift(nb[j].from_here);
            (*stats).x += 1.0;
            (*stats).y += f32(sc.failed);
            mis_c += share * pair_balance(c.m / nf, c.contrib.w, q.m, luminance(sc.contrib) * sc.jacobian);
        } else {
            mis_c += share;
        }
        if q.big_w > 0.0 {
            let sh = load_pair_shift(nb[j].to_here);
            (*stats).x += 1.0;
            (*stats).y += f32(sh.failed);
            let target_q = luminance(sh.contrib);
            if sh.jacobian > 0.0 {
                let mis_q = share * pair_balance(q.m, q.contrib.w / sh.jacobian, c.m / nf, target_q);
                stream_add(&st, adopt(q, sh), mis_q * target_q * q.big_w * sh.jacobian, sh.jacobian, rand(rng));
            }
        }
    }
    stream_add(&st, c, mis_c * c.contrib.w * c.big_w, 1.0, rand(rng));
    (*stats).z = st.jacobian;
    return stream_result(st, m_total);
}

// Neighbours per pixel at most (MAX_SPATIAL in src/techniques/restir_pt/params.rs).
const MAX_NEIGHBOURS: u32 = 8u;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    var counts = no_counts();
    if gid.x < frame.size.x && gid.y < frame.size.y {
        let idx = gid.y * frame.size.x + gid.x;
        var rng = rng_init(gid.xy, frame.sample_offset, STREAM_PT_SPATIAL, frame.seed);
        let s = current_surface(idx);
        let c = reservoirs[reservoir_index(TEMPORAL_SEGMENT, idx)];
        var ids = array<u32, 8>(0u, 0u, 0u, 0u, 0u, 0u, 0u, 0u);
        var n = 0u;
        if s.pos.w > 0.5 && params.pairs == 0u {
            for (var j = 0u; j < min(params.spatial_count, MAX_NEIGHBOURS); j++) {
                let q = disk_neighbour(gid.xy, params.spatial_radius, rand_pair(&rng));
                if q >= 0 && u32(q) != idx && similar(s, current_surface(u32(q))) {
                    ids[n] = u32(q);
                    n += 1u;
                }
            }
        }
        var out = c;
        var shifts = 0u;
        var failures = 0u;
        var jacobian = 1.0;
        if params.pairs > 0u {
            // (shifts, failures, the kept sample's Jacobian)
            var stats = vec3<f32>(0.0, 0.0, 1.0);
            if s.pos.w > 0.5 {
                out = paired_reuse(gid.xy, idx, c, &rng, &stats);
            }
            shifts = u32(stats.x);
            failures = u32(stats.y);
            jacobian = stats.z;
        } else if n > 0u {
            var m_total = c.m;
            for (var j = 0u; j < n; j++) {
                m_total += reservoirs[reservoir_index(TEMPORAL_SEGMENT, ids[j])].m;
            }
            let nf = f32(n);
            var st = empty_stream();
            var mis_c = 0.0;
            for (var j = 0u; j < n; j++) {
                let q = reservoirs[reservoir_index(TEMPORAL_SEGMENT, ids[j])];
                let share = pair_share(c.m, q.m, nf, m_total);
                // Neighbour j's path shifted here (k = 0), then this pixel's path at neighbour
                // j for the canonical weight (k = 1): one call site, since drivers inline every
                // call and shift_path is the largest function in gilab.
                for (var k = 0u; k < 2u; k++) {
                    let canonical = k == 1u;
                    var path = q;
                    var to = s;
                    if canonical {
                        path = c;
                        to = current_surface(ids[j]);
                    }
                    if !(path.big_w > 0.0) {
                        if canonical {
                            mis_c += share;
                        }
                        continue;
                    }
                    let sh = shift_path(path, to);
                    counts[RAY_REUSE] += sh.rays;
                    shifts += 1u;
                    failures += u32(sh.failed);
                    if canonical {
                        mis_c += share * pair_balance(c.m / nf, c.contrib.w, q.m, luminance(sh.contrib) * sh.jacobian);
                    } else {
                        let target_q = luminance(sh.contrib);
                        if sh.jacobian > 0.0 {
                            let mis_q = share * pair_balance(q.m, q.contrib.w / sh.jacobian, c.m / nf, target_q);
                            stream_add(&st, adopt(q, sh), mis_q * target_q * q.big_w * sh.jacobian, sh.jacobian, rand(&rng));
                        }
                    }
                }
            }
            stream_add(&st, c, mis_c * c.contrib.w * c.big_w, 1.0, rand(&rng));
            out = stream_result(st, m_total);
            jacobian = st.jacobian;
        }
        reservoirs[reservoir_index(parity(), idx)] = out;
        var rate = 0.0;
        if shifts > 0u {
            rate = f32(failures) / f32(shifts);
        }
        write_debug(idx, out, rate, jacobian);
    }
    flush_counts(local_index, counts);
}
