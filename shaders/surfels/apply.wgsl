// Light apply (per pixel): the surfels of the pixel's cell, weighted by distance within their
// radius, normal agreement and (radial_depth) their depth maps; where their weight is below 1
// the cell's average tops it up (the seed's gap filling). Pixel = emission + direct light +
// diffuse albedo x irradiance / pi + specular indirect light from the reflections part (scenes
// with a specular layer; rough lobes: their albedo x the surfels' irradiance / pi).
// Marks the surfels that lit the pixel as seen, writes the debug planes, accumulates. In
// cache-only mode (FLAG_CACHE_ONLY: another technique reads the surfels) it only marks: the
// pixels are that technique's.
#import gilab::frame::{frame, FLAG_NO_PRIMARY_EMISSION}
#import gilab::math::{INV_PI, luminance}
#import gilab::counters::{flush_counts, no_counts, COUNT_INVALID_SAMPLES}
#import gilab::accumulate::accumulate_sample
#import gilab::primary::{current_surface, surface_material}
#import gilab::brdf::diffuse_color
#import gilab::surfels::{params, surfels, states, seen, pixel_direct, pixel_specular, FLAG_REFLECTIONS, has_flag, gather, gathered_irradiance, grid_center_for, spawn_frame, write_debug, FLAG_ACCUMULATE, FLAG_CACHE_ONLY, NONE}

// Coverage above this multiple of the target counts a pixel as crowded (recycling thins it).
const CROWDED: f32 = 4.0;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    var counts = no_counts();
    if gid.x < frame.size.x && gid.y < frame.size.y {
        let idx = gid.y * frame.size.x + gid.x;
        let s = current_surface(idx);
        var l = s.emission.xyz;
        if (frame.flags & FLAG_NO_PRIMARY_EMISSION) != 0u {
            l = vec3<f32>(0.0);
        }
        var first_plane = vec4<f32>(0.0);
        var second_plane = vec4<f32>(0.0);
        if s.pos.w > 0.5 {
            let n = s.normal_alpha.xyz;
            let g = gather(s.pos.xyz, n, grid_center_for(frame.camera_pos.xyz), true);
            let albedo = diffuse_color(surface_material(s), max(dot(n, s.wo_dist.xyz), 0.0));
            let irradiance = gathered_irradiance(g);
            l += pixel_direct[idx].xyz + albedo * irradiance * INV_PI;
            if has_flag(FLAG_REFLECTIONS) {
                // Traced specular, or a rough lobe's albedo times the surfels' irradiance.
                let px = frame.size.x * frame.size.y;
                l += pixel_specular[idx].xyz + pixel_specular[px + idx].xyz * irradiance * INV_PI;
            }
            first_plane.y = g.coverage;
            second_plane.x = f32(g.cell + 1u);
            if g.best != NONE {
                let st = states[g.best];
                let mean = max(luminance(st.mean.xyz), 1e-6);
                first_plane.x = f32(g.best + 1u);
                first_plane.z = f32(st.info.x);
                first_plane.w = luminance(st.variance.xyz) / (mean * mean);
                second_plane.y = f32(frame.frame_index - spawn_frame(surfels[g.best])) + 1.0;
                atomicAdd(&seen[3u * g.best + 1u], 1u);
                if g.coverage > CROWDED * params.coverage_target {
                    atomicAdd(&seen[3u * g.best + 2u], 1u);
                }
            }
        }
        if !has_flag(FLAG_CACHE_ONLY) {
            write_debug(idx, first_plane, second_plane);
            if !accumulate_sample(idx, l, has_flag(FLAG_ACCUMULATE)) {
                counts[COUNT_INVALID_SAMPLES] = 1u;
            }
        }
    }
    flush_counts(local_index, counts);
}
