// The shared output of every technique: per pixel a running mean and Welford M2 (sum of squared
// deviations), numerically stable in float32 over many samples. The engine owns the buffers
// (bind group 1), clears them when accumulation restarts and reads them back; a technique only
// writes its pixel's sample here.
#define_import_path gilab::accumulate

#import gilab::math::is_finite_vec

// Per pixel: xyz = running mean radiance, w = sample count.
@group(1) @binding(3) var<storage, read_write> accum_mean: array<vec4<f32>>;
// Per pixel: xyz = M2 per channel.
@group(1) @binding(4) var<storage, read_write> accum_m2: array<vec4<f32>>;

// Adds a sample to the pixel's average (`keep_history`), or replaces it (a real-time technique
// showing one frame). Returns false, writing nothing, for a NaN or infinite sample: the caller
// counts it (COUNT_INVALID_SAMPLES).
fn accumulate_sample(pixel: u32, l: vec3<f32>, keep_history: bool) -> bool {
    if !is_finite_vec(l) {
        return false;
    }
    if !keep_history {
        accum_mean[pixel] = vec4<f32>(l, 1.0);
        accum_m2[pixel] = vec4<f32>(0.0);
        return true;
    }
    let w = welford_add(accum_mean[pixel], accum_m2[pixel], l);
    accum_mean[pixel] = w.mean;
    accum_m2[pixel] = w.sq_dev;
    return true;
}

struct Welford {
    // xyz = running mean, w = sample count.
    mean: vec4<f32>,
    // xyz = M2 per channel (the sum of squared deviations).
    sq_dev: vec4<f32>,
}

// One sample into a running mean and M2 (Welford's update); also for averages a technique keeps
// in its own buffers (the reference's depth images).
fn welford_add(mean: vec4<f32>, sq_dev: vec4<f32>, l: vec3<f32>) -> Welford {
    let n = mean.w + 1.0;
    let delta = l - mean.xyz;
    let new_mean = mean.xyz + delta / n;
    return Welford(vec4<f32>(new_mean, n), vec4<f32>(sq_dev.xyz + delta * (l - new_mean), 0.0));
}
