// Each surfel's irradiance estimate of this frame, the mean of its rays' results, with its ray
// count (0 where it traced none): integrate's irradiance sharing reads its neighbours' (the
// seed's spatial filter between the ray trace and the multiscale mean estimator). The rays also
// update the surfel's radial Gaussian depth (moving averages of hit distance and its square,
// distances clamped to the surfel's diameter) here, before integrate reads the neighbours' maps.
#import gilab::surfels::{params, surfels, states, depth, ray_offsets, ray_results, frame_estimates, is_live, DEPTH_TEXELS}

const DEPTH_BLEND: f32 = 0.1;

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let slot = gid.x;
    if slot >= params.max_surfels {
        return;
    }
    var estimate = vec4<f32>(0.0);
    let count = states[slot].info.x;
    if is_live(slot) && count > 0u {
        let first = ray_offsets[slot];
        let diameter = 2.0 * surfels[slot].pos_radius.w;
        var sum = vec3<f32>(0.0);
        for (var k = 0u; k < count; k++) {
            let a = ray_results[2u * (first + k)];
            let b = ray_results[2u * (first + k) + 1u];
            sum += a.xyz;
            let di = slot * DEPTH_TEXELS + min(u32(b.z), DEPTH_TEXELS - 1u);
            let z = min(a.w, diameter);
            depth[di] = mix(depth[di], vec2<f32>(z, z * z), DEPTH_BLEND);
        }
        estimate = vec4<f32>(sum / f32(count), f32(count));
    }
    frame_estimates[slot] = estimate;
}
