// ReSTIR GI pass 1: one sample path per pixel from the primary surface, its direction drawn by
// the BSDF (or cosine-weighted, `gi_sampling`), its first hit's own emission left out; the hit
// point and its outgoing radiance become a candidate, merged with last frame's GI reservoir at
// the reprojected pixel. A mirror's (delta) sample lights its own pixel only.
#import gilab::rng::{rng_init, rand, rand_pair, STREAM_GI_SAMPLE}
#import gilab::frame::frame
#import gilab::counters::{flush_counts, no_counts, count_cache_lookup, RAY_SHADOW, RAY_INDIRECT}
#import gilab::math::{PI, to_world, luminance}
#import gilab::ray::spawn_ray_origin
#import gilab::sampling::sample_cosine_hemisphere
#import gilab::brdf::{bsdf_eval, bsdf_sample, specular_eval, BsdfSample}
#import gilab::path::{trace_path, PathOptions}
#import gilab::primary::{reproject, current_surface, previous_surface, surface_material, at_last_frame, similar}
#import gilab::scene::previous_position
#import gilab::restir::{params, gi_reservoirs, gi_sky, GiReservoir, reservoir_index, parity, empty_gi_reservoir, gi_contribution, gi_target, gi_update, gi_jacobian_ok, TEMPORAL_SEGMENT}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    var counts = no_counts();
    if gid.x < frame.size.x && gid.y < frame.size.y {
        let idx = gid.y * frame.size.x + gid.x;
        var rng = rng_init(gid.xy, frame.sample_offset, STREAM_GI_SAMPLE, frame.seed);
        let s = current_surface(idx);
        var r = empty_gi_reservoir();
        var sky = vec3<f32>(0.0);
        var sky_w = 0.0;
        if s.pos.w > 0.5 && params.gi == 1u {
            let n = s.normal_alpha.xyz;
            let m = surface_material(s);
            let wo = s.wo_dist.xyz;
            // The sample's direction: by the BSDF (diffuse and GGX lobes mixed by the specular
            // weight, `bsdf_sample`), or cosine-weighted (`gi_sampling = "cosine"`). weight =
            // f cos / pdf, pdf in solid angle (0 for a mirror's delta lobe).
            var bs = BsdfSample(vec3<f32>(0.0), vec3<f32>(0.0), 0.0, false, false);
            if params.gi_cosine == 1u {
                let local = sample_cosine_hemisphere(rand_pair(&rng));
                bs.wi = to_world(local, n);
                bs.pdf = local.z / PI;
                bs.valid = bs.pdf > 0.0;
                bs.weight = bsdf_eval(m, n, wo, bs.wi).f * local.z / max(bs.pdf, 1e-30);
            } else {
                bs = bsdf_sample(m, n, wo, rand(&rng), rand_pair(&rng));
            }
            r.m = 1.0;
            if bs.valid && dot(bs.wi, s.geo_specular.xyz) > 0.0 {
                let wi = bs.wi;
                // A mirror's path keeps its first hit's emission: NEE at the pixel cannot reach
                // an emitter through a delta lobe.
                let path = trace_path(spawn_ray_origin(s.pos.xyz, s.geo_specular.xyz, wi), wi, &rng, params.gi_bounces, !bs.is_delta, PathOptions(params.path_light_candidates, params.specular_bounces, params.specular_max_roughness));
                counts[RAY_INDIRECT] += path.first_rays + path.indirect_rays;
                counts[RAY_SHADOW] += path.shadow_rays;
                count_cache_lookup(&counts, path.cache_outcome);
                if bs.is_delta {
                    // A delta lobe has no density another pixel's reconnection could use: the
                    // sample lights its own pixel only, through the per-pixel term (w = 1: all
                    // of it is the specular layer's, for a family that traces mirrors itself).
                    sky = bs.weight * path.radiance;
                    sky_w = 1.0;
                } else if path.first_hit.w > 0.5 {
                    // normal.w: the hit's triangle + 1, so reuse can follow it if it moves.
                    let cand = GiReservoir(path.first_hit, vec4<f32>(path.first_normal, f32(path.first_tri + 1u)), vec4<f32>(path.radiance, 0.0), 0.0, 0.0, 0.0, 0.0);
                    let e = gi_contribution(s, cand);
                    if e.geom > 0.0 {
                        // Area-measure source pdf: solid-angle pdf times the geometry term.
                        gi_update(&r, cand, luminance(e.value) / (bs.pdf * e.geom), 0.0, rand(&rng));
                    }
                } else if params.sky_candidates == 0u {
                    // Sky without a DI sky class: direct light from the environment,
                    // estimated by this sample alone (with the class, it is ReSTIR DI's).
                    // w: the specular layer's share of the BSDF in that direction, which a
                    // family that traces its glossy pixels' reflections leaves out.
                    sky = bs.weight * path.radiance;
                    let full = luminance(bsdf_eval(m, n, wo, wi).f);
                    if full > 0.0 {
                        sky_w = clamp(luminance(specular_eval(m, n, wo, wi).f) / full, 0.0, 1.0);
                    }
                }
            }
            r.target_pdf = gi_target(s, r);
            if r.target_pdf > 0.0 {
                r.big_w = r.w_sum / (r.m * r.target_pdf);
            }
            if params.temporal == 1u && frame.frame_index > 0u {
                let prev = reproject(s.prev_pos.xyz);
                if prev >= 0 {
                    let pidx = u32(prev);
                    let ps = previous_surface(pidx);
                    if similar(at_last_frame(s), ps) {
                        let pr = gi_reservoirs[reservoir_index(1u - parity(), pidx)];
                        // A sample whose Jacobian is out of bounds, or whose point is on
                        // geometry that moved, is not passed on (weight 0), but the merge still
                        // happens so that Z depends on the chosen sample only.
                        let mp = min(pr.m, params.max_history * r.m);
                        var wp = 0.0;
                        if !on_moved_geometry(pr) && gi_jacobian_ok(s, ps, pr) {
                            wp = gi_target(s, pr) * pr.big_w * mp;
                        }
                        var out = empty_gi_reservoir();
                        gi_update(&out, r, r.target_pdf * r.big_w * r.m, r.m, rand(&rng));
                        gi_update(&out, pr, wp, mp, rand(&rng));
                        out.target_pdf = gi_target(s, out);
                        if out.target_pdf > 0.0 {
                            var z = out.m;
                            if params.unbiased == 1u {
                                // 1/Z: the previous reservoir counts where it could have
                                // passed this sample here (support and Jacobian bound).
                                z = r.m;
                                if !on_moved_geometry(out) && gi_target(ps, out) > 0.0 && gi_jacobian_ok(s, ps, out) {
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
        gi_reservoirs[reservoir_index(TEMPORAL_SEGMENT, idx)] = r;
        gi_sky[idx] = vec4<f32>(sky, sky_w);
    }
    flush_counts(local_index, counts);
}

// Whether a reconnection point's triangle moved between last frame and this one. Such a sample
// is not reused (the seed's "reject or re-evaluate"): its radiance was found where the object
// was. Moving it with its object instead kept a point of a sliding door as the one sample of a
// wall pixel for six frames while the door carried it from 2 m to 0.25 m away; reuse passed
// each step's Jacobian bound, the steps together did not, and the pixel read six times the
// lamp's emission (`every_technique_plays_the_moving_scene`, seed 5).
fn on_moved_geometry(r: GiReservoir) -> bool {
    let tri = u32(r.normal.w);
    if tri == 0u || r.point.w < 0.5 {
        return false;
    }
    let p = r.point.xyz;
    return distance(previous_position(tri - 1u, p), p) > 1e-5 * max(1.0, length(p));
}
