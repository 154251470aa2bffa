// Traversal benchmark: per pixel a camera ray and up to `settings.bounces` cosine-sampled diffuse bounce rays
// (closest hit), counted like every technique's rays (camera / indirect). `gilab bench` runs it with 0 bounces
// (camera rays alone) and with 3, and takes the bounce rays' cost as the difference of the two times.
#import gilab::math::to_world
#import gilab::ray::spawn_ray_origin
#import gilab::rng::{rng_init, rand_pair, STREAM_BENCH}
#import gilab::frame::{frame, camera_ray_dir}
#import gilab::counters::{flush_counts, no_counts, RAY_CAMERA, RAY_INDIRECT}
#import gilab::bvh::{trace_closest, NO_HIT}
#import gilab::scene::tri_geom
#import gilab::sampling::sample_cosine_hemisphere

// Keeps the traversal from being optimised away: summed hit distances per pixel.
@group(2) @binding(0) var<storage, read_write> checksum: array<vec4<f32>>;

struct BenchSettings {
    // Diffuse bounce rays after the camera ray (a path ends earlier where a ray misses).
    bounces: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}
@group(2) @binding(1) var<uniform> settings: BenchSettings;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    var counts = no_counts();
    if gid.x < frame.size.x && gid.y < frame.size.y {
        var rng = rng_init(gid.xy, frame.frame_index, STREAM_BENCH, frame.seed);
        var origin = frame.camera_pos.xyz;
        var dir = camera_ray_dir(vec2<f32>(gid.xy) + 0.5);
        var sum = 0.0;
        let bounces = settings.bounces;
        for (var bounce = 0u; bounce <= bounces; bounce++) {
            let hit = trace_closest(origin, dir, 0.0, 1e30);
            if bounce == 0u {
                counts[RAY_CAMERA] += 1u;
            } else {
                counts[RAY_INDIRECT] += 1u;
            }
            if hit.tri == NO_HIT {
                break;
            }
            sum += hit.t;
            if bounce == bounces {
                break;
            }
            let g = tri_geom[hit.tri];
            var n = normalize(cross(g.edge_b.xyz, g.edge_c.xyz));
            n = select(n, -n, dot(n, dir) > 0.0);
            let hit_point = origin + dir * hit.t;
            dir = to_world(sample_cosine_hemisphere(rand_pair(&rng)), n);
            origin = spawn_ray_origin(hit_point, n, dir);
        }
        checksum[gid.y * frame.size.x + gid.x] += vec4<f32>(sum, 0.0, 0.0, 1.0);
    }
    flush_counts(local_index, counts);
}
