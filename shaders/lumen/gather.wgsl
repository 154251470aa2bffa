// First final gather (part 2 replaces it with screen probes): per `gather_downsample` block, the
// block's centre pixel traces `rays_per_pixel` cosine-distributed rays in the `tracing` mode,
// lit from the surface cache (the sky on a miss); plane 0 keeps its irradiance, plane 1 its
// normal and depth for the upsampling in `apply`.
#import gilab::frame::frame
#import gilab::math::{PI, to_world}
#import gilab::sampling::sample_cosine_hemisphere
#import gilab::counters::{flush_counts, no_counts, RAY_INDIRECT}
#import gilab::rng::{rng_init, rand_pair, STREAM_LUMEN_GATHER}
#import gilab::primary::current_surface
#import gilab::tracing::{params, trace_scene, hit_radiance}
#import gilab::lumen::{gather_out}
#import gilab::sky::sky_radiance

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    var counts = no_counts();
    if gid.x < params.gather_width && gid.y < params.gather_height {
        let g = gid.y * params.gather_width + gid.x;
        let plane = params.gather_width * params.gather_height;
        let ds = params.gather_downsample;
        let pixel = min(gid.xy * ds + ds / 2u, frame.size - 1u);
        let s = current_surface(pixel.y * frame.size.x + pixel.x);
        if s.pos.w < 0.5 {
            gather_out[g] = vec4<f32>(0.0);
            gather_out[plane + g] = vec4<f32>(0.0);
        } else {
            var rng = rng_init(pixel, frame.frame_index, STREAM_LUMEN_GATHER, frame.seed);
            let n = s.normal_alpha.xyz;
            var sum = vec3<f32>(0.0);
            for (var r = 0u; r < params.rays_per_pixel; r++) {
                let dir = to_world(sample_cosine_hemisphere(rand_pair(&rng)), n);
                if dot(dir, s.geo_specular.xyz) <= 0.0 {
                    continue;
                }
                sum += hit_radiance(trace_scene(s.pos.xyz, s.geo_specular.xyz, dir, 1e30), sky_radiance(dir));
            }
            counts[RAY_INDIRECT] += params.rays_per_pixel;
            gather_out[g] = vec4<f32>(PI * sum / f32(max(params.rays_per_pixel, 1u)), 1.0);
            gather_out[plane + g] = vec4<f32>(n, s.wo_dist.w);
        }
    }
    flush_counts(li, counts);
}
