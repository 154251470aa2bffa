// The sky: an equirectangular HDR environment map (rotation about +Y, intensity), or without
// one the constant frame.sky. Radiance on a miss, importance sampling by luminance and its pdf.
// The mapping, the sampling and the buffer layout are documented in src/scene/environment.rs
// (its CPU functions are this module's twins): map direction (x, y, z) reads
// u = 1/2 + atan2(x, -z) / 2pi, v = acos(y) / pi (row 0 the zenith, the image centre towards -Z,
// +X a quarter turn to its right); world = R_y(rotation) map.
#define_import_path gilab::sky

#import gilab::math::{PI, TWO_PI}
#import gilab::frame::frame
#import gilab::scene::texels

// Header words (then texels: two words each, half (r, g) and half (b, 0); the marginal CDF over
// rows; the conditional CDFs of every row; CDFs inclusive f32, last entry 1).
const ENV_WIDTH: u32 = 0u;
const ENV_HEIGHT: u32 = 1u;
const ENV_PRESENT: u32 = 2u;
const ENV_SAMPLEABLE: u32 = 3u;
const ENV_MARGINAL: u32 = 4u;
const ENV_CONDITIONAL: u32 = 5u;
const ENV_ROT_SIN: u32 = 6u;
const ENV_ROT_COS: u32 = 7u;
const ENV_SCALE: u32 = 8u;
const ENV_TEXELS: u32 = 16u;

// FrameUniforms flag (render::FLAG_NO_SKY_NEE): leave the map out of the path tracer's NEE.
const FLAG_NO_SKY_NEE: u32 = 2u;

// The map's words sit in the scene's data buffer (`texels`, binding 4) from ENV_OFFSET on: one
// binding for textures and the map keeps the techniques under 32 storage buffers per stage.
const ENV_OFFSET: u32 = 1u;

fn env_word(i: u32) -> u32 {
    return texels[ENV_OFFSET + i];
}

struct SkySample {
    dir: vec3<f32>,
    // Solid-angle pdf (0: no sample).
    pdf: f32,
}

fn env_word_f32(i: u32) -> f32 {
    return bitcast<f32>(env_word(i));
}

// True when an environment map is bound (otherwise the sky is the constant frame.sky).
fn has_environment() -> bool {
    return env_word(ENV_PRESENT) != 0u;
}

// The path tracer samples the sky in next-event estimation: only an environment map that is not
// black (a constant sky is reached by BSDF sampling, which cosine-weighted sampling would not
// improve on), unless FLAG_NO_SKY_NEE is set.
fn sky_nee() -> bool {
    return has_environment() && env_word(ENV_SAMPLEABLE) != 0u && (frame.flags & FLAG_NO_SKY_NEE) == 0u;
}

// Environment map sampling is available (ReSTIR's sky class mixes it in).
fn sky_importance() -> bool {
    return has_environment() && env_word(ENV_SAMPLEABLE) != 0u;
}

// Map (u, v) of a world direction.
fn env_uv(dir: vec3<f32>) -> vec2<f32> {
    let s = env_word_f32(ENV_ROT_SIN);
    let c = env_word_f32(ENV_ROT_COS);
    // map = R_y(-rotation) world.
    let x = dir.x * c - dir.z * s;
    let z = dir.x * s + dir.z * c;
    let u = 0.5 + atan2(x, -z) / TWO_PI;
    let v = acos(clamp(dir.y, -1.0, 1.0)) / PI;
    return vec2<f32>(u - floor(u), v);
}

// World direction of map coordinates (u, v).
fn env_dir(uv: vec2<f32>) -> vec3<f32> {
    let phi = TWO_PI * (uv.x - 0.5);
    let theta = PI * uv.y;
    let st = sin(theta);
    let m = vec3<f32>(st * sin(phi), cos(theta), -st * cos(phi));
    let s = env_word_f32(ENV_ROT_SIN);
    let c = env_word_f32(ENV_ROT_COS);
    // world = R_y(rotation) map.
    return vec3<f32>(m.x * c + m.z * s, m.y, -m.x * s + m.z * c);
}

// A non-negative IEEE half float (the low 16 bits of h) as f32. Decoded by hand:
// unpack2x16float needs a float16 capability that naga's default validation does not grant.
fn half_to_f32(h: u32) -> f32 {
    let e = (h >> 10u) & 0x1fu;
    let m = h & 0x3ffu;
    if e == 0u {
        // Subnormal: m x 2^-24.
        return f32(m) * 5.9604645e-8;
    }
    return bitcast<f32>(((e + 112u) << 23u) | (m << 13u));
}

fn env_texel(i: i32, j: i32) -> vec3<f32> {
    let w = i32(env_word(ENV_WIDTH));
    let h = i32(env_word(ENV_HEIGHT));
    let ii = ((i % w) + w) % w;
    let jj = clamp(j, 0, h - 1);
    let k = ENV_TEXELS + 2u * u32(jj * w + ii);
    let rg = env_word(k);
    return vec3<f32>(half_to_f32(rg & 0xffffu), half_to_f32(rg >> 16u), half_to_f32(env_word(k + 1u)));
}

// Bilinear between texel centres, wrapping in u, clamped in v; intensity included.
fn env_radiance(dir: vec3<f32>) -> vec3<f32> {
    let uv = env_uv(dir);
    let p = uv * vec2<f32>(f32(env_word(ENV_WIDTH)), f32(env_word(ENV_HEIGHT))) - 0.5;
    let f = floor(p);
    let t = p - f;
    let i = i32(f.x);
    let j = i32(f.y);
    let top = mix(env_texel(i, j), env_texel(i + 1, j), t.x);
    let bottom = mix(env_texel(i, j + 1), env_texel(i + 1, j + 1), t.x);
    return mix(top, bottom, t.y) * env_word_f32(ENV_SCALE);
}

// Radiance arriving from the sky along world direction `dir` (a ray that left the scene).
fn sky_radiance(dir: vec3<f32>) -> vec3<f32> {
    if has_environment() {
        return env_radiance(dir);
    }
    return frame.sky.xyz;
}

// First k in [0, n) with cdf[first + k] > u (an inclusive CDF whose last entry is 1).
fn env_search(first: u32, n: u32, u: f32) -> u32 {
    var lo = 0u;
    var hi = n - 1u;
    while lo < hi {
        let mid = (lo + hi) / 2u;
        if env_word_f32(first + mid) > u {
            hi = mid;
        } else {
            lo = mid + 1u;
        }
    }
    return lo;
}

fn env_pmf(first: u32, k: u32) -> f32 {
    let before = select(0.0, env_word_f32(first + k - 1u), k > 0u);
    return env_word_f32(first + k) - before;
}

// Solid-angle pdf of texel (i, j) at polar sine sin_theta: pmf_row pmf_column W H / (2 pi^2 sin).
fn env_texel_pdf(i: u32, j: u32, sin_theta: f32) -> f32 {
    let w = env_word(ENV_WIDTH);
    let h = env_word(ENV_HEIGHT);
    if sin_theta <= 0.0 {
        return 0.0;
    }
    let p = env_pmf(env_word(ENV_MARGINAL), j) * env_pmf(env_word(ENV_CONDITIONAL) + j * w, i) * f32(w) * f32(h);
    return max(p, 0.0) / (2.0 * PI * PI * sin_theta);
}

// A direction to the sky and its solid-angle pdf. Environment map: luminance importance
// sampling (row by the marginal CDF from u.x, column by the row's conditional CDF from u.y,
// uniform within the texel). Constant sky: uniform over the sphere, pdf 1 / 4pi.
fn sample_sky(u_in: vec2<f32>) -> SkySample {
    let u = min(u_in, vec2<f32>(0.99999994));
    if !has_environment() {
        let y = 1.0 - 2.0 * u.x;
        let r = sqrt(max(0.0, 1.0 - y * y));
        let phi = TWO_PI * u.y;
        return SkySample(vec3<f32>(r * cos(phi), y, r * sin(phi)), 0.25 / PI);
    }
    if env_word(ENV_SAMPLEABLE) == 0u {
        return SkySample(vec3<f32>(0.0, 1.0, 0.0), 0.0);
    }
    let w = env_word(ENV_WIDTH);
    let h = env_word(ENV_HEIGHT);
    let marginal = env_word(ENV_MARGINAL);
    let j = env_search(marginal, h, u.x);
    let pj = env_pmf(marginal, j);
    let row = env_word(ENV_CONDITIONAL) + j * w;
    let i = env_search(row, w, u.y);
    let p_col = env_pmf(row, i);
    if pj <= 0.0 || p_col <= 0.0 {
        return SkySample(vec3<f32>(0.0, 1.0, 0.0), 0.0);
    }
    let dv = clamp((u.x - (env_word_f32(marginal + j) - pj)) / pj, 0.0, 0.99999);
    let du = clamp((u.y - (env_word_f32(row + i) - p_col)) / p_col, 0.0, 0.99999);
    let uv = vec2<f32>((f32(i) + du) / f32(w), (f32(j) + dv) / f32(h));
    let dir = env_dir(uv);
    let sin_theta = sqrt(max(0.0, 1.0 - dir.y * dir.y));
    return SkySample(dir, env_texel_pdf(i, j, sin_theta));
}

// Solid-angle pdf with which sample_sky produces `dir`.
fn sky_pdf(dir: vec3<f32>) -> f32 {
    if !has_environment() {
        return 0.25 / PI;
    }
    if env_word(ENV_SAMPLEABLE) == 0u {
        return 0.0;
    }
    let w = env_word(ENV_WIDTH);
    let h = env_word(ENV_HEIGHT);
    let uv = env_uv(dir);
    let i = min(u32(uv.x * f32(w)), w - 1u);
    let j = min(u32(uv.y * f32(h)), h - 1u);
    let sin_theta = sqrt(max(0.0, 1.0 - dir.y * dir.y));
    return env_texel_pdf(i, j, sin_theta);
}
