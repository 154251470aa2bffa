// Test harness for tests/brdf.rs: histograms of bsdf_sample's directions and bsdf_eval's pdf and
// f·cos integrated over the same (theta, phi) bins, for chi-square tests of sampling against evaluation.
#import gilab::math::PI
#import gilab::brdf::{Shading, make_shaded_surface, bsdf_eval, bsdf_sample}
#import gilab::rng::{rng_init, rand, rand_pair, STREAM_TEST}

struct Params {
    theta_bins: u32,
    phi_bins: u32,
    samples_per_thread: u32,
    threads_per_case: u32,
    // Midpoint-rule points per bin edge in the integration pass.
    subdivisions: u32,
    case_count: u32,
    seed: u32,
    pad: u32,
}

struct Case {
    // rgb: base colour, w: metallic.
    base_metal: vec4<f32>,
    // x: roughness, y: specular factor, z: theta of wo (radians).
    misc: vec4<f32>,
    // The BRDF model and Callisto's parameters.
    shading: Shading,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> cases: array<Case>;
// Per case: theta_bins * phi_bins direction bins, then one bin for invalid samples.
@group(0) @binding(2) var<storage, read_write> counts: array<atomic<u32>>;
// Per case and bin: x = integral of the pdf over the bin (solid angle), yzw = integral of f·cos.
@group(0) @binding(3) var<storage, read_write> integrals: array<vec4<f32>>;
// Per case and thread: rgb = summed sample weights, w = samples whose weight or pdf disagrees
// with bsdf_eval at the sampled direction.
@group(0) @binding(4) var<storage, read_write> thread_sums: array<vec4<f32>>;

const N: vec3<f32> = vec3<f32>(0.0, 0.0, 1.0);

fn wo_of(c: Case) -> vec3<f32> {
    return vec3<f32>(sin(c.misc.z), 0.0, cos(c.misc.z));
}

fn bin_count() -> u32 {
    return params.theta_bins * params.phi_bins + 1u;
}

@compute @workgroup_size(64, 1, 1)
fn sample_directions(@builtin(global_invocation_id) gid: vec3<u32>) {
    let thread = gid.x;
    let ci = gid.y;
    if thread >= params.threads_per_case || ci >= params.case_count {
        return;
    }
    let c = cases[ci];
    let s = make_shaded_surface(c.base_metal.xyz, c.base_metal.w, c.misc.x, c.misc.y, c.shading);
    let wo = wo_of(c);
    var rng = rng_init(vec2<u32>(thread, ci), 0u, STREAM_TEST, params.seed);
    var sum = vec4<f32>(0.0);
    for (var k = 0u; k < params.samples_per_thread; k++) {
        let b = bsdf_sample(s, N, wo, rand(&rng), rand_pair(&rng));
        var bin = params.theta_bins * params.phi_bins;
        if b.valid && b.wi.z > 0.0 {
            let theta = acos(clamp(b.wi.z, -1.0, 1.0));
            var phi = atan2(b.wi.y, b.wi.x);
            if phi < 0.0 {
                phi += 2.0 * PI;
            }
            let ti = min(u32(theta / (0.5 * PI) * f32(params.theta_bins)), params.theta_bins - 1u);
            let pi = min(u32(phi / (2.0 * PI) * f32(params.phi_bins)), params.phi_bins - 1u);
            bin = ti * params.phi_bins + pi;
            sum += vec4<f32>(b.weight, 0.0);
            let e = bsdf_eval(s, N, wo, b.wi);
            let expected_weight = e.f * b.wi.z / max(e.pdf, 1e-30);
            let weight_off = any(abs(b.weight - expected_weight) > 1e-3 * max(expected_weight, vec3<f32>(1e-3)));
            if abs(b.pdf - e.pdf) > 1e-3 * e.pdf || weight_off {
                sum.w += 1.0;
            }
        }
        atomicAdd(&counts[ci * bin_count() + bin], 1u);
    }
    thread_sums[ci * params.threads_per_case + thread] = sum;
}

@compute @workgroup_size(64, 1, 1)
fn integrate_bins(@builtin(global_invocation_id) gid: vec3<u32>) {
    let bin = gid.x;
    let ci = gid.y;
    if bin >= params.theta_bins * params.phi_bins || ci >= params.case_count {
        return;
    }
    let c = cases[ci];
    let s = make_shaded_surface(c.base_metal.xyz, c.base_metal.w, c.misc.x, c.misc.y, c.shading);
    let wo = wo_of(c);
    let ti = bin / params.phi_bins;
    let pi = bin % params.phi_bins;
    let d_theta = 0.5 * PI / f32(params.theta_bins);
    let d_phi = 2.0 * PI / f32(params.phi_bins);
    let sub = params.subdivisions;
    var acc = vec4<f32>(0.0);
    for (var a = 0u; a < sub; a++) {
        let theta = (f32(ti) + (f32(a) + 0.5) / f32(sub)) * d_theta;
        var row = vec4<f32>(0.0);
        for (var b = 0u; b < sub; b++) {
            let phi = (f32(pi) + (f32(b) + 0.5) / f32(sub)) * d_phi;
            let wi = vec3<f32>(sin(theta) * cos(phi), sin(theta) * sin(phi), cos(theta));
            let e = bsdf_eval(s, N, wo, wi);
            row += vec4<f32>(e.pdf, e.f * wi.z);
        }
        acc += row * sin(theta);
    }
    integrals[ci * (bin_count() - 1u) + bin] = acc * (d_theta * d_phi / f32(sub * sub));
}
