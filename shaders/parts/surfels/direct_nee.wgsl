// Direct light per pixel (`direct = "nee"`): one light picked by power from the shared light
// pool, one shadow ray, the full BRDF (diffuse and specular).
#import gilab::frame::frame
#import gilab::counters::{flush_counts, no_counts, RAY_SHADOW}
#import gilab::rng::{rng_init, rand, rand_pair, STREAM_SURFEL_DIRECT}
#import gilab::primary::{current_surface, surface_material}
#import gilab::surfels::pixel_direct
#import gilab::nee::direct_light

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    var counts = no_counts();
    if gid.x < frame.size.x && gid.y < frame.size.y {
        let idx = gid.y * frame.size.x + gid.x;
        let s = current_surface(idx);
        var l = vec3<f32>(0.0);
        if s.pos.w > 0.5 {
            var rng = rng_init(gid.xy, frame.frame_index, STREAM_SURFEL_DIRECT, frame.seed);
            let d = direct_light(s.pos.xyz, s.geo_specular.xyz, s.normal_alpha.xyz, surface_material(s), s.wo_dist.xyz, rand(&rng), rand_pair(&rng));
            l = d.radiance;
            counts[RAY_SHADOW] += d.shadow_rays;
        }
        pixel_direct[idx] = vec4<f32>(l, 0.0);
    }
    flush_counts(local_index, counts);
}
