// DDGI's pixels (src/techniques/ddgi): emission + direct light (NEE, one light by power and one
// shadow ray, or the ReSTIR DI part's result with `direct = "restir"`) + (diffuse albedo + the
// specular layer's average albedo) x the irradiance gathered from the 8 probes around the
// pixel's surface / pi. DDGI keeps diffuse light only: a glossy lobe reads the same irradiance
// (no traced reflections).
//
// Debug views (FLAG_DEBUG), per pixel: the camera ray's nearest probe sphere of the finest
// cascade in front of the surface (its state: 1 on, 2 off; 0 none); on a sphere, that probe's
// irradiance and mean distance (in spacings) towards the sphere's normal, elsewhere the
// gathered irradiance and 0; the probe the pixel's gather weights most (slot + 1).
#import gilab::frame::frame
#import gilab::math::{INV_PI, luminance}
#import gilab::counters::{flush_counts, no_counts, RAY_SHADOW, COUNT_INVALID_SAMPLES}
#import gilab::rng::{rng_init, rand, rand_pair, STREAM_DDGI_PIXEL}
#import gilab::accumulate::accumulate_sample
#import gilab::primary::{current_surface, surface_material, primary_emission}
#import gilab::brdf::{diffuse_color, specular_albedo_average}
#import gilab::nee::direct_light
#import gilab::ddgi::{params, debug_out, pixel_direct, ddgi_gather, probes_per_cascade, probe_position, probe_active, probe_irradiance, probe_distance, spacing, has_flag, FLAG_ACCUMULATE, FLAG_DEBUG, FLAG_DIRECT_RESTIR}

// Radius of a probe's sphere in the debug view, in spacings.
const PROBE_SPHERE: f32 = 0.1;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    var counts = no_counts();
    if gid.x < frame.size.x && gid.y < frame.size.y {
        let idx = gid.y * frame.size.x + gid.x;
        let s = current_surface(idx);
        var l = primary_emission(s);
        var gathered = vec3<f32>(0.0);
        var strongest = 0u;
        if s.pos.w > 0.5 {
            let n = s.normal_alpha.xyz;
            let wo = s.wo_dist.xyz;
            let m = surface_material(s);
            if has_flag(FLAG_DIRECT_RESTIR) {
                // The direct-light part's pass wrote it this frame (its rays counted there).
                l += pixel_direct[idx].xyz;
            } else {
                var rng = rng_init(gid.xy, frame.frame_index, STREAM_DDGI_PIXEL, frame.seed);
                let d = direct_light(s.pos.xyz, s.geo_specular.xyz, n, m, wo, rand(&rng), rand_pair(&rng));
                l += d.radiance;
                counts[RAY_SHADOW] += d.shadow_rays;
            }
            let g = ddgi_gather(s.pos.xyz, n, wo);
            gathered = g.irradiance;
            strongest = g.strongest;
            let albedo = diffuse_color(m, max(dot(n, wo), 0.0)) + specular_albedo_average(m);
            l += albedo * g.irradiance * INV_PI;
        }
        if has_flag(FLAG_DEBUG) {
            debug_out[idx] = debug_planes(s.pos.w > 0.5, s.wo_dist, gathered, strongest);
        }
        if !accumulate_sample(idx, l, has_flag(FLAG_ACCUMULATE)) {
            counts[COUNT_INVALID_SAMPLES] = 1u;
        }
    }
    flush_counts(local_index, counts);
}

fn debug_planes(hit: bool, wo_dist: vec4<f32>, gathered: vec3<f32>, strongest: u32) -> vec4<f32> {
    let origin = frame.camera_pos.xyz;
    let dir = -wo_dist.xyz;
    let r = PROBE_SPHERE * spacing(0u);
    var t_best = select(1e30, wo_dist.w, hit);
    var sphere = -1;
    for (var slot = 0u; slot < probes_per_cascade(); slot++) {
        let oc = origin - probe_position(slot);
        let b = dot(oc, dir);
        let disc = b * b - (dot(oc, oc) - r * r);
        if disc >= 0.0 {
            let t = -b - sqrt(disc);
            if t > 0.0 && t < t_best {
                t_best = t;
                sphere = i32(slot);
            }
        }
    }
    if sphere >= 0 {
        let slot = u32(sphere);
        let normal = normalize(origin + dir * t_best - probe_position(slot));
        return vec4<f32>(
            select(2.0, 1.0, probe_active(slot)),
            luminance(probe_irradiance(slot, normal)),
            probe_distance(slot, normal).x / spacing(0u),
            f32(strongest),
        );
    }
    return vec4<f32>(0.0, luminance(gathered), 0.0, f32(strongest));
}
