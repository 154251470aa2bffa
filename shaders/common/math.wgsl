// Small shared math helpers: constants, orthonormal bases, luminance, finiteness checks.
#define_import_path gilab::math

const PI: f32 = 3.14159265358979;
const INV_PI: f32 = 0.318309886183791;
const TWO_PI: f32 = 6.28318530717959;
const F32_MAX: f32 = 3.4e38;

fn luminance(c: vec3<f32>) -> f32 {
    return dot(c, vec3<f32>(0.2126, 0.7152, 0.0722));
}

fn max_component(v: vec3<f32>) -> f32 {
    return max(v.x, max(v.y, v.z));
}

// Frisvad-style basis without the singularity (Duff et al. 2017).
fn onb_tangent(n: vec3<f32>) -> vec3<f32> {
    let s = select(-1.0, 1.0, n.z >= 0.0);
    let a = -1.0 / (s + n.z);
    let b = n.x * n.y * a;
    return vec3<f32>(1.0 + s * n.x * n.x * a, s * b, -s * n.x);
}

fn onb_bitangent(n: vec3<f32>) -> vec3<f32> {
    let s = select(-1.0, 1.0, n.z >= 0.0);
    let a = -1.0 / (s + n.z);
    let b = n.x * n.y * a;
    return vec3<f32>(b, s + n.y * n.y * a, -n.y);
}

fn to_world(v: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    return v.x * onb_tangent(n) + v.y * onb_bitangent(n) + v.z * n;
}

fn to_local(v: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(dot(v, onb_tangent(n)), dot(v, onb_bitangent(n)), dot(v, n));
}

// NaN fails every comparison, so this is false for NaN and for +-Inf.
fn is_finite_vec(v: vec3<f32>) -> bool {
    let a = abs(v);
    return a.x <= F32_MAX && a.y <= F32_MAX && a.z <= F32_MAX;
}

// Octahedral map of the unit sphere onto [-1, 1]² (Cigolle et al. 2014): ReSTIR's stored sky
// directions, DDGI's probe texels.
fn oct_encode(d: vec3<f32>) -> vec2<f32> {
    let p = d.xy / (abs(d.x) + abs(d.y) + abs(d.z));
    if d.z >= 0.0 {
        return p;
    }
    return (1.0 - abs(p.yx)) * select(vec2<f32>(-1.0), vec2<f32>(1.0), p >= vec2<f32>(0.0));
}

fn oct_decode(e: vec2<f32>) -> vec3<f32> {
    var d = vec3<f32>(e, 1.0 - abs(e.x) - abs(e.y));
    if d.z < 0.0 {
        d = vec3<f32>((1.0 - abs(d.yx)) * select(vec2<f32>(-1.0), vec2<f32>(1.0), d.xy >= vec2<f32>(0.0)), d.z);
    }
    return normalize(d);
}
