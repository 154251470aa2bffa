// ReSTIR PT pass 4: each pixel's final path, F x W (its shifts traced every visibility ray F
// needs), plus the primary surface's own emission and, with `direct = "restir"`, ReSTIR DI's
// direct light; accumulated over frames like the reference (Welford mean and M2).
#import gilab::frame::frame
#import gilab::counters::{flush_counts, no_counts, COUNT_INVALID_SAMPLES}
#import gilab::accumulate::accumulate_sample
#import gilab::primary::{current_surface, primary_emission}
#import gilab::restir_pt::{params, reservoirs, reservoir_index, parity, direct_light}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    var counts = no_counts();
    if gid.x < frame.size.x && gid.y < frame.size.y {
        let idx = gid.y * frame.size.x + gid.x;
        let s = current_surface(idx);
        var l = primary_emission(s);
        let r = reservoirs[reservoir_index(parity(), idx)];
        if s.pos.w > 0.5 && r.big_w > 0.0 {
            l += r.contrib.xyz * r.big_w;
        }
        if s.pos.w > 0.5 && params.direct_restir == 1u {
            l += direct_light[idx].xyz;
        }
        if !accumulate_sample(idx, l, params.accumulate == 1u) {
            counts[COUNT_INVALID_SAMPLES] = 1u;
        }
    }
    flush_counts(local_index, counts);
}
