// Reference path tracer: progressive, unbiased; NEE + MIS (power heuristic) over emissive triangles and punctual lights, Russian roulette, Welford per-pixel mean and variance.
#import gilab::rng::{rng_init, rand_pair, STREAM_CAMERA}
#import gilab::frame::{frame, camera_ray_dir, FLAG_NO_PRIMARY_EMISSION}
#import gilab::counters::{flush_counts, no_counts, RAY_CAMERA, RAY_SHADOW, RAY_INDIRECT, COUNT_INVALID_SAMPLES}
#import gilab::path::trace_path
#import gilab::accumulate::accumulate_sample

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
}
@group(2) @binding(1) var<uniform> settings: ReferenceSettings;

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
        let path = trace_path(frame.camera_pos.xyz, dir, &rng, settings.max_depth, skip);
        counts[RAY_CAMERA] = path.first_rays;
        counts[RAY_SHADOW] = path.shadow_rays;
        counts[RAY_INDIRECT] = path.indirect_rays;
        let keep = settings.accumulate != 0u || dispatch_sample.index > 0u;
        if !accumulate_sample(idx, path.radiance, keep) {
            counts[COUNT_INVALID_SAMPLES] = 1u;
        }
    }
    flush_counts(local_index, counts);
}
