// Test shader (tests/gpu.rs `scene_texels_hold_the_storage_buffers_words`): every record the
// scene's texel copies give (bvh_node, tri_geom_at, tri_attr_at, material_at, light_at) against
// the same record read from its storage buffer, bit for bit; mismatches counted per copy.
// `shifted`, the negative control, compares each buffer record with the next record's texels.
#import gilab::scene::{bvh_nodes, bvh_node, tri_geom, tri_geom_at, tri_attr, tri_attr_at, materials, material_at, light_pool, light_at}

@group(1) @binding(0) var<storage, read_write> mismatches: array<atomic<u32>, 6>;

fn differ(a: vec4<f32>, b: vec4<f32>) -> bool {
    return any(bitcast<vec4<u32>>(a) != bitcast<vec4<u32>>(b));
}

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    compare(gid.x, 0u);
}

@compute @workgroup_size(64, 1, 1)
fn shifted(@builtin(global_invocation_id) gid: vec3<u32>) {
    compare(gid.x, 1u);
}

// Buffer record i against texel record i + shift (records without a partner are skipped).
fn compare(i: u32, shift: u32) {
    // [5]: records compared, so a test that reads nothing fails.
    if i + shift < arrayLength(&bvh_nodes) {
        let a = bvh_nodes[i];
        let b = bvh_node(i + shift);
        atomicAdd(&mismatches[5], 1u);
        if differ(vec4<f32>(a.bounds_min, bitcast<f32>(a.skip)), vec4<f32>(b.bounds_min, bitcast<f32>(b.skip)))
            || differ(vec4<f32>(a.bounds_max, bitcast<f32>(a.tris)), vec4<f32>(b.bounds_max, bitcast<f32>(b.tris))) {
            atomicAdd(&mismatches[0], 1u);
        }
    }
    if i + shift < arrayLength(&tri_geom) {
        let a = tri_geom[i];
        let b = tri_geom_at(i + shift);
        atomicAdd(&mismatches[5], 1u);
        if differ(a.vertex_a, b.vertex_a) || differ(a.edge_b, b.edge_b) || differ(a.edge_c, b.edge_c) {
            atomicAdd(&mismatches[1], 1u);
        }
    }
    if i + shift < arrayLength(&tri_attr) {
        let a = tri_attr[i];
        let b = tri_attr_at(i + shift);
        atomicAdd(&mismatches[5], 1u);
        if any(a.normals != b.normals) || bitcast<u32>(a.light_pmf) != bitcast<u32>(b.light_pmf)
            || any(a.tangents != b.tangents) || a.material != b.material
            || differ(a.uv0_ab, b.uv0_ab) || differ(a.uv0_c_uv1_a, b.uv0_c_uv1_a) || differ(a.uv1_bc, b.uv1_bc)
            || a.scene_tri != b.scene_tri || a.flags != b.flags || any(a.pad != b.pad) {
            atomicAdd(&mismatches[2], 1u);
        }
    }
    if i + shift < arrayLength(&materials) {
        let a = materials[i];
        let b = material_at(i + shift);
        atomicAdd(&mismatches[5], 1u);
        var bad = differ(a.base_color, b.base_color) || differ(a.emissive, b.emissive) || differ(a.params, b.params) || differ(a.extra, b.extra);
        for (var k = 0u; k < 5u; k++) {
            bad = bad || differ(a.tex[k].transform_u, b.tex[k].transform_u) || differ(a.tex[k].transform_v, b.tex[k].transform_v);
        }
        let s = a.shading;
        let t = b.shading;
        bad = bad || differ(s.fresnel, t.fresnel) || differ(s.retro, t.retro) || differ(s.terminator, t.terminator) || differ(s.falloffs, t.falloffs) || differ(s.dual, t.dual);
        if bad {
            atomicAdd(&mismatches[3], 1u);
        }
    }
    if i + shift < arrayLength(&light_pool.lights) {
        let a = light_pool.lights[i];
        let b = light_at(i + shift);
        atomicAdd(&mismatches[5], 1u);
        if a.kind != b.kind || a.tri != b.tri || bitcast<u32>(a.cdf) != bitcast<u32>(b.cdf) || bitcast<u32>(a.pmf) != bitcast<u32>(b.pmf)
            || bitcast<u32>(a.class_cdf) != bitcast<u32>(b.class_cdf) || bitcast<u32>(a.class_pmf) != bitcast<u32>(b.class_pmf) || any(a.trail != b.trail)
            || differ(a.position, b.position) || differ(a.intensity, b.intensity) || differ(a.direction, b.direction) || differ(a.spot, b.spot) {
            atomicAdd(&mismatches[4], 1u);
        }
    }
}
