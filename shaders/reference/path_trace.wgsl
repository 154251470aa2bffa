// Reference path tracer: progressive, unbiased; NEE + MIS (power heuristic) over emissive triangles and punctual lights, Russian roulette, Welford per-pixel mean and variance.
#import gilab::rng::{rng_init, rand_pair, STREAM_CAMERA}
#import gilab::frame::{frame, camera_ray_dir, FLAG_NO_PRIMARY_EMISSION}
#import gilab::counters::{flush_counts, no_counts, RAY_CAMERA, RAY_SHADOW, RAY_INDIRECT, COUNT_INVALID_SAMPLES}
#import gilab::path::{trace_path, plain_path}
#import gilab::accumulate::{accumulate_sample, accum_mean, welford_add}
#import gilab::math::is_finite_vec

// Which sample of the frame this dispatch traces (one path per invocation per dispatch).
struct DispatchSample {
    index: u32,
}
@group(2) @binding(0) var<uniform> dispatch_sample: DispatchSample;

struct ReferenceSettings {
    // Maximum bounces; 0 = unbounded (Russian roulette only).
    max_depth: u32,
    // 0: the frame's first sample replaces the pixel's average (nothing kept across frames).
    accumulate: u32,
    // 1: also average what max_depth 1 and 2 would give (`depth_images`) into depth_accum.
    depth_images: u32,
}
@group(2) @binding(1) var<uniform> settings: ReferenceSettings;
// With depth_images, per pixel: mean (w = count) and M2 of the direct-light image (planes 0, 1)
// and of the one-bounce image (planes 2, 3), Welford's update as the main average's.
@group(2) @binding(2) var<storage, read_write> depth_accum: array<vec4<f32>>;

fn accumulate_plane(plane: u32, pixel: u32, l: vec3<f32>, keep: bool) {
    let px = frame.size.x * frame.size.y;
    let at_mean = (2u * plane) * px + pixel;
    let at_m2 = (2u * plane + 1u) * px + pixel;
    if !keep {
        depth_accum[at_mean] = vec4<f32>(l, 1.0);
        depth_accum[at_m2] = vec4<f32>(0.0);
        return;
    }
    let w = welford_add(depth_accum[at_mean], depth_accum[at_m2], l);
    depth_accum[at_mean] = w.mean;
    depth_accum[at_m2] = w.sq_dev;
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    // One path per invocation: the frame's samples are separate dispatches. Tracing several
    // paths in a loop inside one invocation came out biased on lavapipe (Mesa 22.3): paths after
    // the first were cut short (the white furnace at albedo 0.95 lost 8%); see the README.
    var counts = no_counts();
    if gid.x < frame.size.x && gid.y < frame.size.y {
        let idx = gid.y * frame.size.x + gid.x;
        var rng = rng_init(gid.xy, frame.sample_offset + dispatch_sample.index, STREAM_CAMERA, frame.seed);
        let jitter = rand_pair(&rng);
        let dir = camera_ray_dir(vec2<f32>(gid.xy) + jitter);
        let skip = (frame.flags & FLAG_NO_PRIMARY_EMISSION) != 0u;
        let path = trace_path(frame.camera_pos.xyz, dir, &rng, settings.max_depth, skip, plain_path());
        counts[RAY_CAMERA] = path.first_rays;
        counts[RAY_SHADOW] = path.shadow_rays;
        counts[RAY_INDIRECT] = path.indirect_rays;
        let keep = settings.accumulate != 0u || dispatch_sample.index > 0u;
        if !accumulate_sample(idx, path.radiance, keep) {
            counts[COUNT_INVALID_SAMPLES] = 1u;
        } else if settings.depth_images != 0u && is_finite_vec(path.radiance_direct) && is_finite_vec(path.radiance_one_bounce) {
            // Kept in step with the main average: a sample it rejects is left out here too, and
            // they restart with it (its count is 1 after a restart's first sample).
            let keep_depth = keep && accum_mean[idx].w > 1.5;
            accumulate_plane(0u, idx, path.radiance_direct, keep_depth);
            accumulate_plane(1u, idx, path.radiance_one_bounce, keep_depth);
        }
    }
    flush_counts(local_index, counts);
}
