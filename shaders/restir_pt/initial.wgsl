// ReSTIR PT pass 1: one path per pixel from its primary surface, traced as the reference
// traces it (NEE of one light with the power heuristic against BSDF sampling at x_1 .. x_D,
// emitters and the sky hit up to x_{D+1}; no Russian roulette). Each of its contributions is a
// candidate path (one per length and end); resampling by luminance keeps one, with
// W = sum of the candidates' luminances / the kept one's (M = 1). Its reconnection vertex and
// suffix are recorded as the path is traced (gilab::restir_pt describes them).
//
// With SUFFIX_TERMINATE (`suffix_terminate` names a cache; the pass is composed with the
// cache's lookup at group 3 and its module overriding gilab::path_end::end_path), the suffix
// ends at its first hit past the reconnection vertex that the cache covers: that hit's cache
// light is the candidate of that length (END_CACHE) and the path stops. The decision and the
// light depend on the suffix alone (the hit, the segment that reached it), which every shift
// reuses as traced, so a shifted path ends in the same cell and the Jacobians are unchanged.
// A path without a reconnection vertex never ends early: its shifts replay it.
#import gilab::rng::{rng_init, rand, rand_uint, STREAM_PT_INITIAL}
#import gilab::frame::frame
#import gilab::counters::{flush_counts, no_counts, count_cache_lookup, RAY_SHADOW, RAY_INDIRECT}
#import gilab::math::luminance
#import gilab::primary::current_surface
#import gilab::brdf::{bsdf_eval, bsdf_sample}
#import gilab::bvh::{trace_closest, NO_HIT}
#import gilab::lights::{light_shadow_ray, triangle_emission, triangle_light_pdf}
#import gilab::sky::{sky_radiance, sky_pdf}
#import gilab::ray::{spawn_ray_origin, unoccluded}
#import gilab::sampling::power_heuristic
#import gilab::path_vertex::{nee_sky_share, pick_nee_light}
#import gilab::path_end::end_path
#import gilab::restir_pt::{params, reservoirs, reservoir_index, TEMPORAL_SEGMENT, PathReservoir, empty_path_reservoir, Vertex, primary_vertex, hit_vertex, path_surface, vertex_numbers, rough, reconnectable, pack_info, Stream, empty_stream, stream_add, stream_result, END_EMISSION, END_NEE, END_SKY, END_CACHE}

// Light candidates of the NEE a cache end takes at its hit (ReSTIR's path_light_candidates
// default, as ReSTIR GI's paths end).
const END_LIGHT_CANDIDATES: u32 = 8u;

// The reconnection vertex found so far along the base path (r = 0: none yet).
struct Reconnection {
    r: u32,
    tri: u32,
    bary: vec2<f32>,
    front: bool,
    area_pdf: f32,
    // x_r's step: its direction and BSDF pdf (0 when only NEE left x_r so far).
    dir: vec3<f32>,
    pdf: f32,
    // Throughput of the steps after x_r's own.
    suffix: vec3<f32>,
}

// The candidate of length k with end `end`, contribution c. `rc_step_light` (k = r + 1 with
// NEE at x_r, or x_r's BSDF step ending at x_{r+1}): the suffix radiance is the light's raw
// radiance `le`, its MIS weight redone by each shift with pdf `p_light`; k = r: x_r is the
// emitter, `p_light` its area pdf; later ends: `le` already carries the steps after x_r and
// the light's weight.
fn candidate(seed: u32, c: vec3<f32>, k: u32, end: u32, delta: bool, rc: Reconnection, le: vec3<f32>, p_light: f32, nee_dir: vec3<f32>) -> PathReservoir {
    var o = empty_path_reservoir();
    o.seed = seed;
    o.contrib = vec4<f32>(c, luminance(c));
    o.info = pack_info(0u, k, end, false, delta);
    if rc.r > 0u && rc.r <= k {
        o.rc_tri = rc.tri;
        o.rc_bary_u = rc.bary.x;
        o.rc_bary_v = rc.bary.y;
        o.info = pack_info(rc.r, k, end, rc.front, delta);
        o.rc_area_pdf = rc.area_pdf;
        o.suffix = vec4<f32>(le, p_light);
        if end == END_NEE && k == rc.r + 1u {
            o.rc_dir = vec4<f32>(nee_dir, 0.0);
        } else {
            o.rc_dir = vec4<f32>(rc.dir, rc.pdf);
        }
    }
    return o;
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    var counts = no_counts();
    if gid.x < frame.size.x && gid.y < frame.size.y {
        let idx = gid.y * frame.size.x + gid.x;
        var rng = rng_init(gid.xy, frame.sample_offset, STREAM_PT_INITIAL, frame.seed);
        let seed = rand_uint(&rng);
        let s = current_surface(idx);
        var st = empty_stream();
        if s.pos.w > 0.5 {
            let p_sky = nee_sky_share();
            var v = primary_vertex(s);
            var t = vec3<f32>(1.0);
            var rc = Reconnection(0u, NO_HIT, vec2<f32>(0.0), false, 0.0, vec3<f32>(0.0), 0.0, vec3<f32>(1.0));
            var looked_up = false;
            for (var j = 1u; j <= params.max_bounces; j++) {
                let u = vertex_numbers(seed, j);
                // Paths of length 2 to a light of the pool are direct light: ReSTIR DI's with
                // `direct = "restir"` (the sky stays here: the part leaves it to the family).
                let counted = j > 1u || params.direct_restir == 0u;
                // NEE at x_j: the candidate of length j + 1 ending at the light point.
                let ls = pick_nee_light(v.pos, v.geo, u.u_select, u.u_light, p_sky);
                if ls.valid && ls.pdf > 0.0 && dot(ls.wi, v.geo) > 0.0 {
                    let e = bsdf_eval(v.material, v.normal, v.wo, ls.wi);
                    if any(e.f > vec3<f32>(0.0)) {
                        counts[RAY_SHADOW] += 1u;
                        if unoccluded(light_shadow_ray(v.pos, v.geo, ls)) {
                            let w = select(power_heuristic(ls.pdf, e.pdf), 1.0, ls.is_delta);
                            let step = e.f * dot(v.normal, ls.wi) * (w / ls.pdf);
                            let c = t * step * ls.radiance;
                            var le = ls.radiance;
                            if rc.r > 0u && rc.r < j {
                                le = rc.suffix * step * ls.radiance;
                            }
                            if counted || u.u_select < p_sky {
                                stream_add(&st, candidate(seed, c, j + 1u, END_NEE, ls.is_delta, rc, le, ls.pdf, ls.wi), luminance(c), 1.0, rand(&rng));
                            }
                        }
                    }
                }
                // BSDF sampling to x_{j+1}.
                let bs = bsdf_sample(v.material, v.normal, v.wo, u.u_lobe, u.u_dir);
                if !bs.valid || dot(bs.wi, v.geo) <= 0.0 {
                    break;
                }
                let hit = trace_closest(spawn_ray_origin(v.pos, v.geo, bs.wi), bs.wi, 0.0, 1e30);
                counts[RAY_INDIRECT] += 1u;
                t *= bs.weight;
                if rc.r == j {
                    rc.dir = bs.wi;
                    rc.pdf = bs.pdf;
                } else if rc.r > 0u {
                    rc.suffix *= bs.weight;
                }
                if hit.tri == NO_HIT {
                    var w = 1.0;
                    var p_light = 0.0;
                    if !bs.is_delta && p_sky > 0.0 {
                        p_light = p_sky * sky_pdf(bs.wi);
                        w = power_heuristic(bs.pdf, p_light);
                    }
                    let le = sky_radiance(bs.wi);
                    let c = t * le * w;
                    var suffix = le;
                    if rc.r > 0u && rc.r < j {
                        suffix = rc.suffix * le * w;
                    }
                    stream_add(&st, candidate(seed, c, j + 1u, END_SKY, false, rc, suffix, p_light, vec3<f32>(0.0)), luminance(c), 1.0, rand(&rng));
                    break;
                }
                let h = path_surface(hit.tri, hit.bary, bs.wi);
                if rc.r == 0u && rough(h.material) && reconnectable(v, h.position) {
                    let cos_r = dot(h.geo_normal, -bs.wi);
                    rc = Reconnection(j + 1u, hit.tri, hit.bary, h.front_face, bs.pdf * cos_r / (hit.t * hit.t), vec3<f32>(0.0), 0.0, vec3<f32>(1.0));
                }
                // The emitter at x_{j+1}: the candidate of length j + 1 ending there.
                let le = triangle_emission(hit.tri, hit.bary, -bs.wi);
                if any(le > vec3<f32>(0.0)) && counted {
                    let p_solid = (1.0 - p_sky) * triangle_light_pdf(hit.tri, bs.wi, hit.t, v.pos, v.geo);
                    let w = select(power_heuristic(bs.pdf, p_solid), 1.0, bs.is_delta);
                    let c = t * le * w;
                    var suffix = le;
                    var p_light = p_solid;
                    if rc.r == j + 1u {
                        // x_r is the emitter: its pdf in area measure, for the shifts' weights.
                        p_light = p_solid * dot(h.geo_normal, -bs.wi) / (hit.t * hit.t);
                    } else if rc.r > 0u && rc.r < j {
                        suffix = rc.suffix * le * w;
                    }
                    stream_add(&st, candidate(seed, c, j + 1u, END_EMISSION, false, rc, suffix, p_light, vec3<f32>(0.0)), luminance(c), 1.0, rand(&rng));
                }
#ifdef SUFFIX_TERMINATE
                // x_{j+1} is a suffix hit (past x_r) where the path would take NEE (j < D): the
                // cache's light there (reflected, with its own NEE for caches that take one)
                // ends the path where the cache covers the hit. The first lookup is counted.
                if rc.r > 0u && rc.r <= j && j < params.max_bounces {
                    let e = end_path(h, -bs.wi, hit.tri, hit.t, vec3<f32>(1.0), p_sky, END_LIGHT_CANDIDATES, &rng);
                    counts[RAY_SHADOW] += e.shadow_rays;
                    counts[RAY_INDIRECT] += e.indirect_rays;
                    if !looked_up && e.outcome != 0u {
                        looked_up = true;
                        count_cache_lookup(&counts, e.outcome);
                    }
                    if e.ended {
                        let l_end = e.direct + e.indirect;
                        let c = t * l_end;
                        var suffix = l_end;
                        if rc.r < j {
                            suffix = rc.suffix * l_end;
                        }
                        stream_add(&st, candidate(seed, c, j + 1u, END_CACHE, false, rc, suffix, 0.0, vec3<f32>(0.0)), luminance(c), 1.0, rand(&rng));
                        break;
                    }
                }
#endif
                v = hit_vertex(h, bs.wi);
            }
        }
        reservoirs[reservoir_index(TEMPORAL_SEGMENT, idx)] = stream_result(st, 1.0);
    }
    flush_counts(local_index, counts);
}
