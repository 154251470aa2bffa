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
// With FLAG_DEBUG_CORNERS, five more planes say which probes the pixel reads (the viewer's
// inspector lists them under the cursor): channel 4 the probes that weigh in (of the 8), 5 the
// gather's total weight, 6 the probe sphere the camera ray meets (slot + 1), 7 the cascade read
// (+ 1); 8-15 corner k's probe (slot + 1; 0 where it does not weigh in; k's bits are x, y, z);
// 16-23 corner k's share of the gather.
#import gilab::frame::frame
#import gilab::math::{INV_PI, luminance}
#import gilab::counters::{flush_counts, no_counts, RAY_SHADOW, COUNT_INVALID_SAMPLES}
#import gilab::rng::{rng_init, rand, rand_pair, STREAM_DDGI_PIXEL}
#import gilab::accumulate::accumulate_sample
#import gilab::primary::{current_surface, surface_material, primary_emission}
#import gilab::brdf::{diffuse_color, specular_albedo_average}
#import gilab::nee::direct_light
#import gilab::ddgi::{params, debug_out, pixel_direct, ddgi_gather, gather_cell, gather_corner, probes_per_cascade, probe_position, probe_active, probe_irradiance, probe_distance, spacing, has_flag, FLAG_ACCUMULATE, FLAG_DEBUG, FLAG_DEBUG_CORNERS, FLAG_DIRECT_RESTIR}

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
            let sphere = probe_sphere(s.pos.w > 0.5, s.wo_dist);
            debug_out[idx] = debug_planes(sphere, s.wo_dist, gathered, strongest);
            if has_flag(FLAG_DEBUG_CORNERS) {
                debug_corners(idx, s.pos.w > 0.5, s.pos.xyz, s.normal_alpha.xyz, s.wo_dist.xyz, sphere.x);
            }
        }
        if !accumulate_sample(idx, l, has_flag(FLAG_ACCUMULATE)) {
            counts[COUNT_INVALID_SAMPLES] = 1u;
        }
    }
    flush_counts(local_index, counts);
}

// The nearest probe sphere of the finest cascade the camera ray meets in front of the surface:
// (slot, t), slot -1 where none.
fn probe_sphere(hit: bool, wo_dist: vec4<f32>) -> vec2<f32> {
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
    return vec2<f32>(f32(sphere), t_best);
}

fn debug_planes(sphere: vec2<f32>, wo_dist: vec4<f32>, gathered: vec3<f32>, strongest: u32) -> vec4<f32> {
    if sphere.x >= 0.0 {
        let slot = u32(sphere.x);
        let origin = frame.camera_pos.xyz;
        let normal = normalize(origin - wo_dist.xyz * sphere.y - probe_position(slot));
        return vec4<f32>(
            select(2.0, 1.0, probe_active(slot)),
            luminance(probe_irradiance(slot, normal)),
            probe_distance(slot, normal).x / spacing(0u),
            f32(strongest),
        );
    }
    return vec4<f32>(0.0, luminance(gathered), 0.0, f32(strongest));
}

// Planes 1-5 of the debug buffer (FLAG_DEBUG_CORNERS): the 8 probes the pixel's gather reads.
fn debug_corners(idx: u32, hit: bool, p: vec3<f32>, n: vec3<f32>, wo: vec3<f32>, sphere: f32) {
    let pixels = frame.size.x * frame.size.y;
    var slots = array<f32, 8>();
    var weights = array<f32, 8>();
    var total = 0.0;
    var count = 0.0;
    var cascade = 0.0;
    if hit {
        let cell = gather_cell(p, n, wo);
        cascade = f32(cell.cascade + 1u);
        for (var i = 0u; i < 8u; i++) {
            let k = gather_corner(cell, p, n, i);
            if k.weight > 0.0 {
                slots[i] = f32(k.slot + 1u);
                weights[i] = k.weight;
                total += k.weight;
                count += 1.0;
            }
        }
    }
    debug_out[idx + pixels] = vec4<f32>(count, total, sphere + 1.0, cascade);
    let share = 1.0 / max(total, 1e-30);
    for (var plane = 0u; plane < 2u; plane++) {
        let k = 4u * plane;
        debug_out[idx + (2u + plane) * pixels] = vec4<f32>(slots[k], slots[k + 1u], slots[k + 2u], slots[k + 3u]);
        debug_out[idx + (4u + plane) * pixels] = vec4<f32>(weights[k], weights[k + 1u], weights[k + 2u], weights[k + 3u]) * share;
    }
}
