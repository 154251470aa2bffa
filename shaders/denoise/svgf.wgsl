// The shared SVGF-style denoiser (src/render/denoise.rs; Schied et al. 2017, "Spatiotemporal
// Variance-Guided Filtering"): its buffers at bind group 0 and the helpers its three passes
// share. Bind group 1 is the engine's frame (uniforms, primary surfaces, accumulated output).
// The primary surfaces are its G-buffer: one jittered camera ray per pixel, the reference's
// jitter, so for a 1-spp technique the surface is the one its sample saw.
#define_import_path gilab::denoise

#import gilab::frame::{frame, FLAG_NO_PRIMARY_EMISSION}
#import gilab::primary::{GSurface, NO_SURFACE}
#import gilab::math::is_finite_vec

// One à-trous iteration (a 256-byte slot each, bound with a dynamic offset).
struct AtrousStep {
    // Distance between taps in pixels: 1, 2, 4, 8, 16.
    step_px: u32,
    iteration: u32,
    // 1 on the last iteration: it remodulates into the engine's output.
    last: u32,
    pad: u32,
}

// The remodulation of a pixel: albedo and the emission seen directly (rgb; w unused).
struct Remod {
    albedo: vec4<f32>,
    emission: vec4<f32>,
}

// The technique's output (mean rgb, w: samples) as it stood after its own render last frame.
// The engine copies it back into the output before the technique renders, so a technique
// that accumulates goes on averaging its own samples, never the denoised image.
@group(0) @binding(0) var<storage, read_write> noisy: array<vec4<f32>>;
// Two segments by frame parity: integrated demodulated illumination (rgb) and its history
// length w, counted in effective samples (see temporal.wgsl); 0 = no history.
@group(0) @binding(1) var<storage, read_write> hist_colour: array<vec4<f32>>;
// Two segments by frame parity: luminance moments m1, m2 of the demodulated illumination;
// z = 1 where the technique accumulated this frame (its average continued).
@group(0) @binding(2) var<storage, read_write> hist_moments: array<vec4<f32>>;
// Per pixel: what the output is remodulated with.
@group(0) @binding(3) var<storage, read_write> remod: array<Remod>;
// Per pixel: octahedral shading normal (xy; 2 = none), distance to the camera z (0 = no
// surface), and the screen-space depth gradient |grad z| per pixel.
@group(0) @binding(4) var<storage, read_write> guide: array<vec4<f32>>;
// Two segments, ping-pong between à-trous iterations: illumination rgb, variance w.
@group(0) @binding(5) var<storage, read_write> illum_var: array<vec4<f32>>;
@group(0) @binding(6) var<uniform> atrous: AtrousStep;

// Exponential moving average weight of new samples (colour and moments), as in the paper.
const ALPHA: f32 = 0.2;
// Effective samples of that average at steady state: (2 - ALPHA) / ALPHA.
const SVGF_SAMPLES: f32 = 9.0;
// Edge-stopping parameters of the paper.
const SIGMA_Z: f32 = 1.0;
const SIGMA_N: f32 = 128.0;
const SIGMA_L: f32 = 4.0;
const F32_BIG: f32 = 3.0e38;

fn pixel_count() -> u32 {
    return frame.size.x * frame.size.y;
}

// Index into a two-segment buffer: this frame's half.
fn current_slot(pixel: u32) -> u32 {
    return (frame.frame_index & 1u) * pixel_count() + pixel;
}

// Last frame's half.
fn previous_slot(pixel: u32) -> u32 {
    return ((frame.frame_index + 1u) & 1u) * pixel_count() + pixel;
}

fn finite3(v: vec3<f32>) -> vec3<f32> {
    return select(vec3<f32>(0.0), v, is_finite_vec(v));
}

fn finite1(x: f32) -> f32 {
    return select(0.0, x, abs(x) <= F32_BIG);
}

// A usable hit: valid, finite position and distance.
fn surface_ok(s: GSurface) -> bool {
    return s.triangle != NO_SURFACE && s.pos.w > 0.5 && is_finite_vec(s.pos.xyz) && s.wo_dist.w > 0.0 && s.wo_dist.w <= F32_BIG;
}

// Unit shading normal, or 0 when it is degenerate (zero or non-finite normals in hard-cases):
// a zero normal matches nothing (w_n = 0), so such a pixel is filtered with itself only.
fn surface_normal(s: GSurface) -> vec3<f32> {
    let n = s.normal_alpha.xyz;
    if !is_finite_vec(n) || dot(n, n) < 1e-12 {
        return vec3<f32>(0.0);
    }
    return normalize(n);
}

// The albedo the illumination is demodulated by: the diffuse albedo base * (1 - metallic)
// plus the specular reflectance at normal incidence (F0: 0.04 * specular factor for
// dielectrics, the base colour for metals), clamped away from 0. Misses (sky): 1.
fn demod_albedo(s: GSurface) -> vec3<f32> {
    if !surface_ok(s) {
        return vec3<f32>(1.0);
    }
    let base = clamp(finite3(s.base_metal.xyz), vec3<f32>(0.0), vec3<f32>(1.0));
    let metal = clamp(finite1(s.base_metal.w), 0.0, 1.0);
    let spec = clamp(finite1(s.geo_specular.w), 0.0, 1.0);
    let f_zero = mix(vec3<f32>(0.04 * spec), base, metal);
    return max(base * (1.0 - metal) + f_zero, vec3<f32>(0.01));
}

// Emission the camera sees at this pixel (sky radiance on a miss), which is taken out before
// demodulating and added back after filtering; none from surfaces when the frame leaves out
// primary emission (FLAG_NO_PRIMARY_EMISSION: the technique's output lacks it too).
fn seen_emission(s: GSurface) -> vec3<f32> {
    if surface_ok(s) && (frame.flags & FLAG_NO_PRIMARY_EMISSION) != 0u {
        return vec3<f32>(0.0);
    }
    return max(finite3(s.emission.xyz), vec3<f32>(0.0));
}

fn oct_wrap(v: vec2<f32>) -> vec2<f32> {
    return (vec2<f32>(1.0) - abs(v.yx)) * select(vec2<f32>(-1.0), vec2<f32>(1.0), v >= vec2<f32>(0.0));
}

// Octahedral encoding of a unit normal; (2, 2) for none.
fn encode_normal(n: vec3<f32>) -> vec2<f32> {
    let l1 = abs(n.x) + abs(n.y) + abs(n.z);
    if l1 < 1e-6 {
        return vec2<f32>(2.0);
    }
    let p = n.xy / l1;
    return select(oct_wrap(p), p, n.z >= 0.0);
}

fn decode_normal(e: vec2<f32>) -> vec3<f32> {
    if e.x > 1.5 {
        return vec3<f32>(0.0);
    }
    var n = vec3<f32>(e, 1.0 - abs(e.x) - abs(e.y));
    if n.z < 0.0 {
        let xy = oct_wrap(n.xy);
        n = vec3<f32>(xy, n.z);
    }
    return normalize(n);
}

// Edge-stopping weight of depth and normal between pixel p (depth z_p, gradient grad_p,
// normal n_p) and q at `dist_px` pixels (the paper's w_z * w_n):
//   w_z = exp(-|z_p - z_q| / (sigma_z * |grad z| * |p - q| + eps)),  w_n = max(0, n_p . n_q)^128.
// z is the distance to the camera along the pixel's ray (the G-buffer's), not the projected
// depth; eps scales with z (1e-3 z) instead of the paper's constant, so the test means the
// same near and far.
fn geometry_weight(z_p: f32, grad_p: f32, n_p: vec3<f32>, z_q: f32, n_q: vec3<f32>, dist_px: f32) -> f32 {
    let w_z = exp(-abs(z_p - z_q) / (SIGMA_Z * grad_p * dist_px + 1e-3 * z_p));
    let w_n = pow(max(0.0, dot(n_p, n_q)), SIGMA_N);
    return w_z * w_n;
}

fn pixel_in_image(q: vec2<i32>) -> bool {
    return q.x >= 0 && q.y >= 0 && q.x < i32(frame.size.x) && q.y < i32(frame.size.y);
}

fn pixel_index(q: vec2<i32>) -> u32 {
    return u32(q.y) * frame.size.x + u32(q.x);
}
