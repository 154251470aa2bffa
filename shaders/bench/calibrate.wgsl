// Clock calibration kernel: a fixed amount of dependent arithmetic per invocation, no memory traffic to speak of; its GPU time before and after a timed run tells whether the clocks stayed put.
struct CalibrationParams {
    iterations: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

@group(0) @binding(0) var<uniform> params: CalibrationParams;
@group(0) @binding(1) var<storage, read_write> data: array<vec4<f32>>;

@compute @workgroup_size(256, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    var v = vec4<f32>(f32(gid.x & 255u) * 1e-3, 0.5, 0.25, 0.125);
    for (var i = 0u; i < params.iterations; i++) {
        v = fma(v, vec4<f32>(0.999), vec4<f32>(1e-3));
        v = fma(v, vec4<f32>(1.0001), vec4<f32>(-1e-4));
    }
    data[gid.x] = v;
}
