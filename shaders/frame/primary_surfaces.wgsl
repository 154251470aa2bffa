// Engine pass: one jittered camera ray per pixel (the reference's jitter sequence, so pixel
// footprints match) and the primary surface it hits, for every technique that needs them.
#import gilab::rng::{rng_init, rand_pair, STREAM_CAMERA}
#import gilab::frame::{frame, camera_ray_dir}
#import gilab::counters::{flush_counts, no_counts, RAY_CAMERA}
#import gilab::bvh::{trace_closest, NO_HIT}
#import gilab::surface::hit_surface
#import gilab::scene::{scene_triangle, previous_position}
#import gilab::lights::triangle_emission
#import gilab::primary::{GSurface, surfaces, surface_slot, previous_pixel_position, NO_SURFACE}
#import gilab::sky::sky_radiance

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    var counts = no_counts();
    if gid.x < frame.size.x && gid.y < frame.size.y {
        let idx = gid.y * frame.size.x + gid.x;
        var rng = rng_init(gid.xy, frame.sample_offset, STREAM_CAMERA, frame.seed);
        let pixel_pos = vec2<f32>(gid.xy) + rand_pair(&rng);
        let origin = frame.camera_pos.xyz;
        let dir = camera_ray_dir(pixel_pos);
        let hit = trace_closest(origin, dir, 0.0, 1e30);
        counts[RAY_CAMERA] = 1u;
        var g = GSurface(vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(-dir, 1e30), vec4<f32>(sky_radiance(dir), 0.0), vec2<f32>(0.0), NO_SURFACE, NO_SURFACE, vec4<f32>(0.0));
        if hit.tri != NO_HIT {
            let s = hit_surface(origin, dir, hit);
            let m = s.material;
            g.pos = vec4<f32>(s.position, 1.0);
            g.normal_alpha = vec4<f32>(s.normal, m.alpha);
            g.geo_specular = vec4<f32>(s.geo_normal, m.specular);
            g.base_metal = vec4<f32>(m.base_color, m.metallic);
            g.wo_dist = vec4<f32>(-dir, hit.t);
            g.emission = vec4<f32>(triangle_emission(hit.tri, hit.bary, -dir), 0.0);
            g.triangle = scene_triangle(hit.tri);
            g.material = s.material_index;
            // Camera and object motion: where the point was last frame, seen by last frame's
            // camera.
            let was = previous_position(hit.tri, s.position);
            // w: the hit triangle (BVH order) + 1, so caches can follow the object it is on.
            g.prev_pos = vec4<f32>(was, f32(hit.tri + 1u));
            let prev = previous_pixel_position(was);
            if prev.x >= 0.0 {
                g.motion = pixel_pos - prev;
            }
        }
        surfaces[surface_slot(frame.frame_index, idx)] = g;
    }
    flush_counts(local_index, counts);
}
