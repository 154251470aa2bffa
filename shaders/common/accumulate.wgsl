// Progressive accumulation shared by techniques: Welford's update of a per-pixel running mean
// and M2 (sum of squared deviations), numerically stable in float32 over many samples.
#define_import_path gilab::accumulate

struct Accumulated {
    // xyz: mean, w: sample count.
    mean: vec4<f32>,
    // xyz: M2 (sum of squared deviations) per channel; naga_oil forbids names ending in a digit.
    sq_dev: vec4<f32>,
}

fn welford_add(mean: vec4<f32>, sq_dev: vec4<f32>, l: vec3<f32>) -> Accumulated {
    let n = mean.w + 1.0;
    let delta = l - mean.xyz;
    let new_mean = mean.xyz + delta / n;
    return Accumulated(vec4<f32>(new_mean, n), vec4<f32>(sq_dev.xyz + delta * (l - new_mean), 0.0));
}
