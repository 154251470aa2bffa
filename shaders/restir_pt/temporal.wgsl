// ReSTIR PT pass 2: temporal reuse. This pixel's new path (canonical, M = 1) and last frame's
// final reservoir at the reprojected pixel (its confidence clamped to max_history x the
// current one) are resampled with pairwise MIS: the old path is shifted to this pixel, and the
// new one to last frame's primary surface there to weigh it (rays traced in this frame's scene:
// where objects moved, last frame's targets are approximated by this frame's geometry).
#import gilab::rng::{rng_init, rand, STREAM_PT_TEMPORAL}
#import gilab::frame::frame
#import gilab::counters::{flush_counts, no_counts, RAY_REUSE}
#import gilab::math::luminance
#import gilab::primary::{current_surface, previous_surface, reproject, at_last_frame, similar}
#import gilab::restir_pt::{params, reservoirs, reservoir_index, parity, TEMPORAL_SEGMENT, shift_path, failed_shift, adopt, empty_stream, stream_add, stream_result, pair_share, pair_balance}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    var counts = no_counts();
    if gid.x < frame.size.x && gid.y < frame.size.y && params.temporal == 1u {
        let idx = gid.y * frame.size.x + gid.x;
        var rng = rng_init(gid.xy, frame.sample_offset, STREAM_PT_TEMPORAL, frame.seed);
        let s = current_surface(idx);
        let at = reservoir_index(TEMPORAL_SEGMENT, idx);
        let c = reservoirs[at];
        var prev = -1;
        if s.pos.w > 0.5 && frame.frame_index > 0u {
            prev = reproject(s.prev_pos.xyz);
        }
        if prev >= 0 {
            let ps = previous_surface(u32(prev));
            let q = reservoirs[reservoir_index(parity() ^ 1u, u32(prev))];
            // An empty reservoir still counts (its domain could have made the sample): M must
            // not depend on what the samples were, or the MIS weights stop summing to one.
            if similar(at_last_frame(s), ps) && q.m > 0.0 {
                let m_q = min(q.m, params.max_history * c.m);
                let m_total = c.m + m_q;
                let share = pair_share(c.m, m_q, 1.0, m_total);
                var st = empty_stream();
                // The old path shifted here (k = 0; shift_path gives nothing for an empty q),
                // and the new path to last frame's pixel (k = 1): one call site, since drivers
                // inline every call and shift_path is the largest function in gilab.
                var sq = failed_shift(0u);
                var sc = failed_shift(0u);
                for (var k = 0u; k < 2u; k++) {
                    var path = q;
                    var to = s;
                    if k == 1u {
                        path = c;
                        to = ps;
                    }
                    let shifted = shift_path(path, to);
                    if k == 0u {
                        sq = shifted;
                    } else {
                        sc = shifted;
                    }
                }
                counts[RAY_REUSE] += sq.rays;
                let target_q = luminance(sq.contrib);
                if sq.jacobian > 0.0 {
                    let mis_q = share * pair_balance(m_q, q.contrib.w / sq.jacobian, c.m, target_q);
                    stream_add(&st, adopt(q, sq), mis_q * target_q * q.big_w * sq.jacobian, sq.jacobian, rand(&rng));
                }
                // The new path, weighed against last frame's pixel.
                counts[RAY_REUSE] += sc.rays;
                let mis_c = share * pair_balance(c.m, c.contrib.w, m_q, luminance(sc.contrib) * sc.jacobian);
                stream_add(&st, c, mis_c * c.contrib.w * c.big_w, 1.0, rand(&rng));
                reservoirs[at] = stream_result(st, m_total);
            }
        }
    }
    flush_counts(local_index, counts);
}
