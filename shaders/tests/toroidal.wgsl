// Test harness for tests/gpu.rs: gilab::toroidal's wrap on (v, n) pairs, against Rust's
// rem_euclid on the CPU.
#import gilab::toroidal::wrap_grid

// xyz: v, w: n.
@group(0) @binding(0) var<storage, read> cases: array<vec4<i32>>;
@group(0) @binding(1) var<storage, read_write> wrapped: array<vec4<i32>>;

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x < arrayLength(&cases) {
        let c = cases[gid.x];
        wrapped[gid.x] = vec4<i32>(wrap_grid(c.xyz, vec3<i32>(c.w)), c.w);
    }
}
