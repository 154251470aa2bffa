// Mean error of an image against the reference on the GPU (MSE, relMSE, SMAPE sums): `partials` reduces 256 pixels per workgroup, `total` the partials in one workgroup; the viewer reads the 16-byte result back asynchronously.
#import gilab::compare::error_terms

struct MetricParams {
    pixels: u32,
    partial_count: u32,
    pad0: u32,
    pad1: u32,
}

@group(0) @binding(0) var<uniform> params: MetricParams;
@group(0) @binding(1) var<storage, read> image: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> reference: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> partials: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> result: array<vec4<f32>>;

var<workgroup> sums: array<vec3<f32>, 256>;

// Pairwise sum of the workgroup's 256 values into sums[0].
fn reduce_workgroup(li: u32) {
    for (var stride = 128u; stride > 0u; stride >>= 1u) {
        workgroupBarrier();
        if li < stride {
            sums[li] += sums[li + stride];
        }
    }
    workgroupBarrier();
}

@compute @workgroup_size(256, 1, 1)
fn partials_main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let group = wid.y * 65535u + wid.x;
    let i = group * 256u + li;
    var v = vec3<f32>(0.0);
    if i < params.pixels {
        v = error_terms(image[i].xyz, reference[i].xyz);
    }
    sums[li] = v;
    reduce_workgroup(li);
    if li == 0u && group < params.partial_count {
        partials[group] = vec4<f32>(sums[0], 0.0);
    }
}

@compute @workgroup_size(256, 1, 1)
fn total_main(@builtin(local_invocation_index) li: u32) {
    var v = vec3<f32>(0.0);
    for (var k = li; k < params.partial_count; k += 256u) {
        v += partials[k].xyz;
    }
    sums[li] = v;
    reduce_workgroup(li);
    if li == 0u {
        result[0] = vec4<f32>(sums[0], f32(params.pixels));
    }
}
