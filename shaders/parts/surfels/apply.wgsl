// Light apply (per pixel): the surfels of the pixel's cell, weighted by distance within their
// radius, normal agreement and (radial_depth) their depth maps; where their weight is below 1
// the cell's average tops it up (the seed's gap filling). Pixel = emission + direct light +
// diffuse albedo x irradiance / pi + specular indirect light from the reflections part (scenes
// with a specular layer; rough lobes: their albedo x the surfels' irradiance / pi).
// Marks the surfels that lit the pixel as seen, writes the debug planes, accumulates. With
// quarter-area apply (FLAG_QUARTER_APPLY) the irradiance comes from the 2x2 blocks' samples
// (apply_gather.wgsl), weighted by bilinear position, depth (distance to the pixel's plane)
// and normal; a pixel none of them matches (an edge, a thin object) gathers itself. In
// cache-only mode (FLAG_CACHE_ONLY: another technique reads the surfels) it only marks: the
// pixels are that technique's.
#import gilab::frame::frame
#import gilab::math::INV_PI
#import gilab::counters::{flush_counts, no_counts, COUNT_INVALID_SAMPLES}
#import gilab::accumulate::accumulate_sample
#import gilab::primary::{current_surface, surface_material, GSurface, primary_emission}
#import gilab::brdf::diffuse_color
#import gilab::surfels::{pixel_direct, pixel_specular, FLAG_REFLECTIONS, has_flag, gather, Gather, gathered_irradiance, grid_center_for, write_debug, block_sample_pixel, note_gather, FLAG_ACCUMULATE, FLAG_CACHE_ONLY, FLAG_QUARTER_APPLY, NONE}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    var counts = no_counts();
    if gid.x < frame.size.x && gid.y < frame.size.y {
        let idx = gid.y * frame.size.x + gid.x;
        let s = current_surface(idx);
        var l = primary_emission(s);
        var first_plane = vec4<f32>(0.0);
        var second_plane = vec4<f32>(0.0);
        var debug_done = false;
        if s.pos.w > 0.5 {
            let n = s.normal_alpha.xyz;
            let albedo = diffuse_color(surface_material(s), max(dot(n, s.wo_dist.xyz), 0.0));
            var irradiance = vec3<f32>(0.0);
            var g = Gather(vec3<f32>(0.0), 0.0, 0.0, 0.0, vec3<f32>(0.0), 0.0, NONE, 0u);
            var gathered = true;
            if has_flag(FLAG_QUARTER_APPLY) {
                let up = upsample(gid.xy, s);
                gathered = up.w <= 0.0;
                irradiance = up.xyz;
                // The block pass wrote this pixel's debug planes.
                debug_done = !gathered;
            }
            if gathered {
                g = gather(s.pos.xyz, n, grid_center_for(frame.camera_pos.xyz), true);
                irradiance = gathered_irradiance(g);
            }
            l += pixel_direct[idx].xyz + albedo * irradiance * INV_PI;
            if has_flag(FLAG_REFLECTIONS) {
                // Traced specular, or a rough lobe's albedo times the surfels' irradiance.
                let px = frame.size.x * frame.size.y;
                l += pixel_specular[idx].xyz + pixel_specular[px + idx].xyz * irradiance * INV_PI;
            }
            if gathered {
                let d = note_gather(g, 1u);
                first_plane = d.first;
                second_plane = d.second;
            }
        }
        if !has_flag(FLAG_CACHE_ONLY) {
            if !debug_done {
                write_debug(idx, first_plane, second_plane);
            }
            if !accumulate_sample(idx, l, has_flag(FLAG_ACCUMULATE)) {
                counts[COUNT_INVALID_SAMPLES] = 1u;
            }
        }
    }
    flush_counts(local_index, counts);
}

// Quarter-area apply: irradiance from the four block samples around the pixel (w = 1), or
// w = 0 when none lies on the pixel's surface.
fn upsample(pixel: vec2<u32>, s: GSurface) -> vec4<f32> {
    let px = frame.size.x * frame.size.y;
    let blocks = (frame.size + 1u) / 2u;
    // Block samples sit on even pixels: pixel p lies between samples floor(p / 2) and + 1.
    let f = vec2<f32>(pixel) * 0.5;
    let base = vec2<u32>(floor(f));
    let t = f - vec2<f32>(base);
    let n = s.normal_alpha.xyz;
    // Plane distance allowed: a few percent of the distance to the camera.
    let tolerance = 0.02 * max(s.wo_dist.w, 1e-3);
    var sum = vec3<f32>(0.0);
    var weight = 0.0;
    for (var k = 0u; k < 4u; k++) {
        let o = vec2<u32>(k & 1u, k >> 1u);
        let b = min(base + o, blocks - 1u);
        let block = b.y * blocks.x + b.x;
        let at_block = pixel_direct[px + block];
        if at_block.w <= 0.0 {
            continue;
        }
        let q = current_surface(block_sample_pixel(block));
        let bilinear = select(1.0 - t.x, t.x, o.x == 1u) * select(1.0 - t.y, t.y, o.y == 1u);
        let plane = abs(dot(n, q.pos.xyz - s.pos.xyz)) / tolerance;
        let normal = max(dot(n, q.normal_alpha.xyz), 0.0);
        let w = max(bilinear, 1e-3) * max(1.0 - plane, 0.0) * pow(normal, 8.0);
        sum += at_block.xyz * w;
        weight += w;
    }
    if weight < 1e-4 {
        return vec4<f32>(0.0);
    }
    return vec4<f32>(sum / weight, 1.0);
}
