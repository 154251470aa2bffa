// ReSTIR pass 2: initial candidates by RIS from the light pool (target: unshadowed f * Le * G),
// an optional visibility test of the chosen candidate (biased mode), then temporal reuse of last frame's
// reservoir at the reprojected pixel (normal/depth similarity, history clamp).
#import gilab::rng::{Rng, rng_init, rand, rand_pair}
#import gilab::frame::frame
#import gilab::counters::{flush_counts, no_counts, RAY_CANDIDATE}
#import gilab::math::luminance
#import gilab::scene::light_pool
#import gilab::lights::select_light
#import gilab::sampling::sample_triangle
#import gilab::restir::{params, surfaces, reservoirs, GSurface, Reservoir, surface_index, reservoir_index, parity, empty_reservoir, reproject, regir_cell, regir_slots, contribution, target_at, visible, update, similar, TEMPORAL_SEGMENT}

fn initial_candidates(s: GSurface, rng: ptr<function, Rng>) -> Reservoir {
    var r = empty_reservoir();
    let cell = regir_cell(s.pos.xyz);
    if params.regir == 1u && cell >= 0 {
        // ReGIR: candidates are the cell's pre-selected lights; each carries the slot's
        // contribution weight, so the RIS weight is target x W_slot.
        let base = u32(cell) * params.regir_slots;
        for (var i = 0u; i < params.candidates; i++) {
            let slot = regir_slots[base + min(u32(rand(rng) * f32(params.regir_slots)), params.regir_slots - 1u)];
            var w = 0.0;
            if slot.big_w > 0.0 {
                w = luminance(contribution(s, slot.light, vec2<f32>(slot.bary_u, slot.bary_v)).value) * slot.big_w;
            }
            update(&r, Reservoir(slot.light, slot.bary_u, slot.bary_v, 0.0, 0.0, 0.0, 0.0, 0.0), w, 1.0, rand(rng));
        }
        r.target_pdf = target_at(s, r);
        if r.target_pdf > 0.0 && r.m > 0.0 {
            r.big_w = r.w_sum / (r.m * r.target_pdf);
        }
        return r;
    }
    for (var i = 0u; i < params.candidates; i++) {
        let li = select_light(rand(rng));
        let b = sample_triangle(rand_pair(rng));
        let c = contribution(s, li, b);
        var w = 0.0;
        if c.light.area_pdf > 0.0 {
            w = luminance(c.value) / c.light.area_pdf;
        }
        update(&r, Reservoir(li, b.x, b.y, 0.0, 0.0, 0.0, 0.0, 0.0), w, 1.0, rand(rng));
    }
    r.target_pdf = target_at(s, r);
    if r.target_pdf > 0.0 && r.m > 0.0 {
        r.big_w = r.w_sum / (r.m * r.target_pdf);
    }
    return r;
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    var counts = no_counts();
    if gid.x < frame.size.x && gid.y < frame.size.y {
        let idx = gid.y * frame.size.x + gid.x;
        var rng = rng_init(gid.xy, frame.sample_offset * 4u + 1u, frame.seed);
        let s = surfaces[surface_index(parity(), idx)];
        var r = empty_reservoir();
        if s.pos.w > 0.5 && light_pool.count > 0u {
            r = initial_candidates(s, &rng);
            // Zeroing occluded candidates narrows what a reservoir can hold below the unshadowed
            // support the 1/Z weights assume, so the unbiased mode does not do it.
            if params.candidate_visibility == 1u && params.unbiased == 0u && r.big_w > 0.0 {
                counts[RAY_CANDIDATE] += 1u;
                let c = contribution(s, r.light, vec2<f32>(r.bary_u, r.bary_v));
                if !visible(s, c.light) {
                    r.big_w = 0.0;
                    r.w_sum = 0.0;
                }
            }
            if params.temporal == 1u && frame.frame_index > 0u {
                // Where this surface point was on screen last frame.
                let prev = reproject(s.pos.xyz);
                if prev >= 0 {
                    let pidx = u32(prev);
                    let ps = surfaces[surface_index(1u - parity(), pidx)];
                    if similar(s, ps) {
                        let pr = reservoirs[reservoir_index(1u - parity(), pidx)];
                        let mc = max(r.m, 1.0);
                        let mp = min(pr.m, params.max_history * mc);
                        var out = empty_reservoir();
                        update(&out, r, r.target_pdf * r.big_w * r.m, r.m, rand(&rng));
                        let tp = target_at(s, pr);
                        update(&out, pr, tp * pr.big_w * mp, mp, rand(&rng));
                        out.target_pdf = target_at(s, out);
                        if out.target_pdf > 0.0 && out.m > 0.0 {
                            var z = out.m;
                            if params.unbiased == 1u {
                                // 1/Z over the unshadowed support: reservoirs carry samples
                                // that reuse brought in, occluded or not.
                                z = r.m;
                                if target_at(ps, out) > 0.0 {
                                    z += mp;
                                }
                            }
                            out.big_w = out.w_sum / (z * out.target_pdf);
                        }
                        r = out;
                    }
                }
            }
        }
        reservoirs[reservoir_index(TEMPORAL_SEGMENT, idx)] = r;
    }
    flush_counts(local_index, counts);
}
