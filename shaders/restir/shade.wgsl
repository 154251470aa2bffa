// ReSTIR final pass: visibility rays for each pixel's DI and GI reservoirs, shading (emission + f * Le * G * V * W + GI),
// and progressive accumulation (Welford mean and M2, as the reference path tracer does).
#import gilab::frame::frame
#import gilab::counters::{flush_counts, no_counts, RAY_SHADOW, COUNT_INVALID_SAMPLES}
#import gilab::accumulate::accumulate_sample
#import gilab::primary::{current_surface, primary_emission}
#import gilab::restir::{params, reservoirs, gi_reservoirs, gi_sky, reservoir_index, parity, shade_reservoir, gi_contribution, gi_visible, regir_cell, debug_out, SKY_SAMPLE}
#import gilab::scene::light_pool

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    var counts = no_counts();
    if gid.x < frame.size.x && gid.y < frame.size.y {
        let idx = gid.y * frame.size.x + gid.x;
        let s = current_surface(idx);
        let ri = reservoir_index(parity(), idx);
        var l = primary_emission(s);
        let direct = shade_reservoir(s, ri);
        l += direct.radiance;
        counts[RAY_SHADOW] += direct.shadow_rays;
        // After shading: biased mode may have emptied it.
        let r = reservoirs[ri];
        var light_id = 0.0;
        if r.big_w > 0.0 && r.light == SKY_SAMPLE {
            light_id = f32(light_pool.count + 1u);
        } else if r.big_w > 0.0 {
            light_id = f32(r.light + 1u);
        }
        var cell_id = 0.0;
        if params.regir == 1u && s.pos.w > 0.5 {
            cell_id = f32(regir_cell(s.pos.xyz) + 1);
        }
        debug_out[idx] = vec4<f32>(r.m, r.big_w, light_id, cell_id);
        if params.gi == 1u && s.pos.w > 0.5 {
            // Indirect light: this frame's sky sample plus the resampled GI sample, visibility re-checked.
            l += gi_sky[idx].xyz;
            let g = gi_reservoirs[ri];
            if g.big_w > 0.0 {
                let e = gi_contribution(s, g);
                if any(e.value > vec3<f32>(0.0)) {
                    counts[RAY_SHADOW] += 1u;
                    if gi_visible(s, g) {
                        l += e.value * g.big_w;
                    }
                }
            }
        }
        if !accumulate_sample(idx, l, params.accumulate == 1u) {
            counts[COUNT_INVALID_SAMPLES] = 1u;
        }
    }
    flush_counts(local_index, counts);
}
