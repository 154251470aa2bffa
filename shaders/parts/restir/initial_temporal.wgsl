// ReSTIR pass 2: initial candidates by RIS per light class ("Making Connections": local,
// directional, sky; each class sampled the way its lights call for, into its own reservoir),
// the class reservoirs merged before visibility (optionally each class's pick visibility-tested
// first, biased mode), then temporal reuse of last frame's reservoir at the reprojected pixel
// (normal/depth similarity, history clamp). Target everywhere: unshadowed f * Le * G.
#import gilab::rng::{Rng, rng_init, rand, rand_pair, STREAM_DI_INITIAL}
#import gilab::frame::frame
#import gilab::counters::{flush_counts, no_counts, RAY_CANDIDATE}
#import gilab::math::{PI, luminance, to_world, oct_encode}
#import gilab::scene::{light_pool, light_at}
#import gilab::lights::{LightSample, select_light, select_light_in_class, class_pdf_scale, trace_emitter}
#import gilab::light_tree::{tree_sample, tree_pmf}
#import gilab::ray::spawn_ray_origin
#import gilab::sampling::{sample_triangle, sample_cosine_hemisphere}
#import gilab::brdf::{Surface, bsdf_eval, bsdf_sample}
#import gilab::sky::{sample_sky, sky_pdf, sky_importance}
#import gilab::primary::{GSurface, reproject, current_surface, previous_surface, surface_material, at_last_frame, similar}
#import gilab::restir::{params, reservoirs, Reservoir, reservoir_index, parity, empty_reservoir, regir_cell, regir_slots, contribution, target_at, visible, update, SKY_SAMPLE, VISIBILITY_PER_CLASS, VISIBILITY_MERGED, TEMPORAL_SEGMENT}

// W = w_sum / (M p-hat(y)) of a reservoir filled by RIS.
fn finish_ris(s: GSurface, r_in: Reservoir) -> Reservoir {
    var r = r_in;
    r.target_pdf = target_at(s, r);
    if r.target_pdf > 0.0 && r.m > 0.0 {
        r.big_w = r.w_sum / (r.m * r.target_pdf);
    }
    return r;
}

// The area pdf with which light sampling (below) draws point `l` of local light `li`: by power
// in the pool (single-pool mode) or within the class, or by the light tree.
fn local_light_pdf(s: GSurface, li: u32, l: LightSample) -> f32 {
    if params.single_pool == 1u {
        return l.area_pdf;
    }
    if params.light_tree == 1u {
        return l.area_pdf * tree_pmf(li, s.pos.xyz, s.geo_specular.xyz) / light_at(li).pmf;
    }
    return l.area_pdf * class_pdf_scale(li);
}

// The area pdf with which a BSDF-sampled candidate reaches point `l` of a light: the BSDF's
// solid-angle pdf times |cos_l| / d^2; 0 for punctual lights (no ray hits them) and below the
// geometric surface (no BSDF candidate is traced there).
fn bsdf_area_pdf(s: GSurface, m: Surface, l: LightSample) -> f32 {
    if l.is_delta || dot(l.wi, s.geo_specular.xyz) <= 0.0 {
        return 0.0;
    }
    return bsdf_eval(m, s.normal_alpha.xyz, s.wo_dist.xyz, l.wi).pdf * l.geom;
}

// Local lights (emissive triangles, point and spot lights): by power within the class, by the
// light tree (`light_tree`, one descent per candidate at the pixel's point and geometric
// normal), or the pixel's ReGIR cell. In single-pool mode: by power over every light.
// At glossy pixels (roughness below `bsdf_max_roughness`) outside ReGIR, `bsdf_candidates`
// more come from the BSDF: a direction sampled from the lobe and a ray through the light tree
// to the first emitter along it, occluders ignored (seed 003's "light BVH for specular": the
// small lights whose highlight a glossy lobe shows, which light sampling rarely picks). The
// two strategies are combined by the balance heuristic (multiple importance RIS): each
// candidate's weight is its target over the candidate-count-weighted mix of both pdfs, so
// W = w_sum / (M target) stays unbiased. Both pdfs are unshadowed, as the 1/Z weights of reuse
// assume: a reservoir covers every light point its surface could see, visible or not.
fn local_candidates(s: GSurface, rng: ptr<function, Rng>, counts: ptr<function, array<u32, 16>>) -> Reservoir {
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
        return r;
    }
    let m = surface_material(s);
    let m_light = f32(params.candidates);
    var m_bsdf = 0.0;
    if params.bsdf_candidates > 0u && m.alpha < params.bsdf_max_roughness * params.bsdf_max_roughness {
        m_bsdf = f32(params.bsdf_candidates);
    }
    let m_total = m_light + m_bsdf;
    for (var i = 0u; i < params.candidates; i++) {
        var li = 0u;
        var scale = 1.0;
        if params.single_pool == 1u {
            li = select_light(rand(rng));
        } else if params.light_tree == 1u {
            // A failed descent (no light reaches the point) is a candidate of weight 0.
            let t = tree_sample(s.pos.xyz, s.geo_specular.xyz, rand(rng));
            li = select(light_pool.count, t.light, t.pmf > 0.0);
            // The sample's area pdf below holds the pool's power pmf: swap it for the tree's.
            scale = select(0.0, t.pmf / light_at(t.light).pmf, t.pmf > 0.0);
        } else {
            li = select_light_in_class(rand(rng), 0u, light_pool.local_count);
            scale = class_pdf_scale(li);
        }
        let b = sample_triangle(rand_pair(rng));
        let c = contribution(s, li, b);
        let pdf = c.light.area_pdf * scale;
        var w = 0.0;
        if pdf > 0.0 {
            var mix_pdf = pdf;
            if m_bsdf > 0.0 {
                mix_pdf = (m_light * pdf + m_bsdf * bsdf_area_pdf(s, m, c.light)) / m_total;
            }
            w = luminance(c.value) / mix_pdf;
        }
        update(&r, Reservoir(li, b.x, b.y, 0.0, 0.0, 0.0, 0.0, 0.0), w, 1.0, rand(rng));
    }
    let geo = s.geo_specular.xyz;
    for (var i = 0u; i < u32(m_bsdf); i++) {
        let bs = bsdf_sample(m, s.normal_alpha.xyz, s.wo_dist.xyz, rand(rng), rand_pair(rng));
        // A candidate that finds no local light has weight 0; it still counts in M.
        var candidate = Reservoir(light_pool.count, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        var w = 0.0;
        if bs.valid && !bs.is_delta && dot(bs.wi, geo) > 0.0 {
            (*counts)[RAY_CANDIDATE] += 1u;
            let hit = trace_emitter(spawn_ray_origin(s.pos.xyz, geo, bs.wi), bs.wi);
            if hit.light < light_pool.local_count {
                {
                    let li = hit.light;
                    let c = contribution(s, li, hit.bary);
                    let p_b = bsdf_area_pdf(s, m, c.light);
                    if p_b > 0.0 {
                        w = luminance(c.value) / ((m_light * local_light_pdf(s, li, c.light) + m_bsdf * p_b) / m_total);
                        candidate = Reservoir(li, hit.bary.x, hit.bary.y, 0.0, 0.0, 0.0, 0.0, 0.0);
                    }
                }
            }
        }
        update(&r, candidate, w, 1.0, rand(rng));
    }
    return r;
}

// Directional lights: by power within the class.
fn directional_candidates(s: GSurface, rng: ptr<function, Rng>) -> Reservoir {
    var r = empty_reservoir();
    for (var i = 0u; i < params.directional_candidates; i++) {
        let li = select_light_in_class(rand(rng), light_pool.local_count, light_pool.count);
        let c = contribution(s, li, vec2<f32>(0.0));
        let pdf = light_at(li).class_pmf;
        var w = 0.0;
        if pdf > 0.0 {
            w = luminance(c.value) / pdf;
        }
        update(&r, Reservoir(li, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), w, 1.0, rand(rng));
    }
    return r;
}

// The sky: directions from a mixture of the BSDF's own sampling and the cosine lobe (the two
// keep the pdf non-zero wherever f * cos is, also on mirrors) and, with an environment map,
// the map's luminance importance sampling: one-sample MIS with the mixture pdf. Without a map
// BSDF and cosine 1/2 each; with one BSDF 1/4, cosine 1/4, map 1/2.
fn sky_candidates(s: GSurface, rng: ptr<function, Rng>) -> Reservoir {
    var r = empty_reservoir();
    let n = s.normal_alpha.xyz;
    let wo = s.wo_dist.xyz;
    let m = surface_material(s);
    var p_bsdf = 0.5;
    var p_cos = 0.5;
    var p_env = 0.0;
    if sky_importance() {
        p_bsdf = 0.25;
        p_cos = 0.25;
        p_env = 0.5;
    }
    for (var i = 0u; i < params.sky_candidates; i++) {
        let u_mix = rand(rng);
        let u_lobe = rand(rng);
        let u = rand_pair(rng);
        var wi = to_world(sample_cosine_hemisphere(u), n);
        var valid = true;
        if u_mix < p_bsdf {
            // A failed BSDF sample is a candidate of weight 0 (the pdf below is the density
            // of the valid ones).
            let bs = bsdf_sample(m, n, wo, u_lobe, u);
            wi = bs.wi;
            valid = bs.valid;
        } else if u_mix >= p_bsdf + p_cos {
            let ss = sample_sky(u);
            wi = ss.dir;
            valid = ss.pdf > 0.0;
        }
        var pdf = p_cos * max(dot(n, wi), 0.0) / PI + p_bsdf * bsdf_eval(m, n, wo, wi).pdf;
        if p_env > 0.0 {
            pdf += p_env * sky_pdf(wi);
        }
        let e = oct_encode(wi);
        var w = 0.0;
        if valid && pdf > 0.0 {
            w = luminance(contribution(s, SKY_SAMPLE, e).value) / pdf;
        }
        update(&r, Reservoir(SKY_SAMPLE, e.x, e.y, 0.0, 0.0, 0.0, 0.0, 0.0), w, 1.0, rand(rng));
    }
    return r;
}

// A conservative visibility test of one reservoir's pick (biased mode): an occluded pick is
// kept out of reuse; its candidate count still counts.
fn drop_if_occluded(s: GSurface, r: ptr<function, Reservoir>, counts: ptr<function, array<u32, 16>>) {
    if (*r).big_w <= 0.0 {
        return;
    }
    (*counts)[RAY_CANDIDATE] += 1u;
    let c = contribution(s, (*r).light, vec2<f32>((*r).bary_u, (*r).bary_v));
    if !visible(s, c.light) {
        (*r).big_w = 0.0;
        (*r).w_sum = 0.0;
    }
}

// One reservoir from the three class reservoirs. Their samples come from disjoint domains, so
// each class is its own RIS estimator: the merge picks class c's sample with weight
// p-hat(y_c) W_c, and W = sum of the weights / p-hat(y). M is the total candidate count.
// The classes are three variables, not a private array: an array indexed by a variable lives in
// local memory on NVIDIA GPUs (slow; see gilab::counters). They are merged in a loop all the
// same, so that the target, the visibility test and the BSDF they inline are compiled once:
// drivers inline every call, and one call site per class made this the slowest pipeline to
// compile (about 40 s on lavapipe).
fn initial_candidates(s: GSurface, rng: ptr<function, Rng>, counts: ptr<function, array<u32, 16>>) -> Reservoir {
    var local_class = empty_reservoir();
    var directional_class = empty_reservoir();
    var sky_class = empty_reservoir();
    if params.candidates > 0u {
        local_class = local_candidates(s, rng, counts);
    }
    if params.directional_candidates > 0u {
        directional_class = directional_candidates(s, rng);
    }
    if params.sky_candidates > 0u {
        sky_class = sky_candidates(s, rng);
    }
    let test_each = params.candidate_visibility == VISIBILITY_PER_CLASS && params.unbiased == 0u;
    var r = empty_reservoir();
    for (var c = 0u; c < 3u; c++) {
        var rc = local_class;
        if c == 1u {
            rc = directional_class;
        } else if c == 2u {
            rc = sky_class;
        }
        if rc.m <= 0.0 {
            continue;
        }
        // The class's own RIS weight W, then (per-class testing) its pick's visibility.
        rc = finish_ris(s, rc);
        if test_each {
            drop_if_occluded(s, &rc, counts);
        }
        // The target of the pick is known: no second evaluation. A reservoir that picked
        // nothing keeps target 0 (its W is 0, so no reader weighs it by that target).
        if update(&r, rc, rc.target_pdf * rc.big_w, rc.m, rand(rng)) {
            r.target_pdf = rc.target_pdf;
        }
    }
    if r.target_pdf > 0.0 {
        r.big_w = r.w_sum / r.target_pdf;
    }
    if params.candidate_visibility == VISIBILITY_MERGED && params.unbiased == 0u {
        drop_if_occluded(s, &r, counts);
    }
    return r;
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    var counts = no_counts();
    if gid.x < frame.size.x && gid.y < frame.size.y {
        let idx = gid.y * frame.size.x + gid.x;
        var rng = rng_init(gid.xy, frame.sample_offset, STREAM_DI_INITIAL, frame.seed);
        let s = current_surface(idx);
        var r = empty_reservoir();
        if s.pos.w > 0.5 {
            // Zeroing occluded candidates narrows what a reservoir can hold below the unshadowed
            // support the 1/Z weights assume, so the unbiased mode never tests candidates.
            r = initial_candidates(s, &rng, &counts);
            if params.temporal == 1u && frame.frame_index > 0u {
                // Where this surface point was on screen last frame.
                let prev = reproject(s.prev_pos.xyz);
                if prev >= 0 {
                    let pidx = u32(prev);
                    let ps = previous_surface(pidx);
                    if similar(at_last_frame(s), ps) {
                        let pr = reservoirs[reservoir_index(1u - parity(), pidx)];
                        let mc = max(r.m, 1.0);
                        let mp = min(pr.m, params.max_history * mc);
                        let tp = target_at(s, pr);
                        // Biased: M-weighted (1/M).
                        var w_r = r.target_pdf * r.big_w * r.m;
                        var w_p = tp * pr.big_w * mp;
                        if params.unbiased == 1u {
                            // The generalized balance heuristic over the two inputs' own
                            // surfaces (this frame's and last frame's; parts/restir/spatial.wgsl
                            // says why not 1/Z). Targets are unshadowed: reservoirs carry samples
                            // that reuse brought in, occluded or not. Both targets at last
                            // frame's surface come from one call site (see initial_candidates).
                            var at_prev = vec2<f32>(0.0);
                            for (var k = 0u; k < 2u; k++) {
                                var x = r;
                                if k == 1u {
                                    x = pr;
                                }
                                at_prev[k] = target_at(ps, x);
                            }
                            let r_prev = mp * at_prev.x;
                            let r_here = r.m * r.target_pdf;
                            let p_prev = mp * at_prev.y;
                            let p_here = r.m * tp;
                            w_r = 0.0;
                            if r_here > 0.0 {
                                w_r = r_here / (r_here + r_prev) * r.target_pdf * r.big_w;
                            }
                            w_p = 0.0;
                            if p_prev > 0.0 {
                                w_p = p_prev / (p_here + p_prev) * tp * pr.big_w;
                            }
                        }
                        var out = empty_reservoir();
                        if update(&out, r, w_r, r.m, rand(&rng)) {
                            out.target_pdf = r.target_pdf;
                        }
                        if update(&out, pr, w_p, mp, rand(&rng)) {
                            out.target_pdf = tp;
                        }
                        if params.unbiased == 1u {
                            if out.target_pdf > 0.0 {
                                out.big_w = out.w_sum / out.target_pdf;
                            }
                        } else if out.target_pdf > 0.0 && out.m > 0.0 {
                            out.big_w = out.w_sum / (out.m * out.target_pdf);
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
