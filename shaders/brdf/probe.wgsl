// BRDF probe: evaluates the shared BRDF (gilab::brdf, the code every technique shades with) at
// given (wo, wi) pairs around the normal +Z, for `gilab brdf-slice`, the viewer's slice window
// and the BRDF tests. Layout must match src/compare/brdf_probe.rs.
#import gilab::brdf::{Shading, make_shaded_surface, bsdf_eval}

struct ProbeMaterial {
    // rgb: base colour, w: metallic.
    base_metal: vec4<f32>,
    // x: roughness, y: specular factor.
    misc: vec4<f32>,
    shading: Shading,
}

struct Query {
    // xyz: wo, w: material index.
    wo: vec4<f32>,
    // xyz: wi.
    wi: vec4<f32>,
}

@group(0) @binding(0) var<storage, read> probe_materials: array<ProbeMaterial>;
@group(0) @binding(1) var<storage, read> queries: array<Query>;
// rgb: f (not multiplied by the cosine), w: the sampling pdf of wi.
@group(0) @binding(2) var<storage, read_write> results: array<vec4<f32>>;

const N: vec3<f32> = vec3<f32>(0.0, 0.0, 1.0);

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x + gid.y * 65535u * 64u;
    if i >= arrayLength(&queries) {
        return;
    }
    let q = queries[i];
    let m = probe_materials[u32(q.wo.w)];
    let s = make_shaded_surface(m.base_metal.xyz, m.base_metal.w, m.misc.x, m.misc.y, m.shading);
    let e = bsdf_eval(s, N, q.wo.xyz, q.wi.xyz);
    results[i] = vec4<f32>(e.f, e.pdf);
}
