// glTF metallic-roughness BRDF: Lambert diffuse + GGX specular (height-correlated Smith G2),
// with KHR_materials_specular's factor scaling the dielectric lobe (0 = pure Lambert).
// Roughness so low that alpha < DELTA_ALPHA is treated as a perfect mirror (delta lobe).
#define_import_path gilab::brdf

#import gilab::math::{PI, INV_PI, luminance, to_local, to_world}
#import gilab::sampling::{sample_cosine_hemisphere, sample_ggx_vndf}

const DELTA_ALPHA: f32 = 1e-3;

struct Surface {
    base_color: vec3<f32>,
    metallic: f32,
    alpha: f32,
    specular: f32,
}

struct BsdfEval {
    // BRDF value (not multiplied by cosine).
    f: vec3<f32>,
    // Solid-angle pdf of bsdf_sample producing wi (0 for delta lobes).
    pdf: f32,
}

struct BsdfSample {
    wi: vec3<f32>,
    // f * cos / pdf (or F / p for the delta lobe).
    weight: vec3<f32>,
    pdf: f32,
    is_delta: bool,
    valid: bool,
}

fn make_surface(base: vec3<f32>, metallic: f32, roughness: f32, specular: f32) -> Surface {
    let r = clamp(roughness, 0.0, 1.0);
    return Surface(clamp(base, vec3<f32>(0.0), vec3<f32>(1.0)), clamp(metallic, 0.0, 1.0), r * r, clamp(specular, 0.0, 1.0));
}

fn schlick(f_zero: vec3<f32>, c: f32) -> vec3<f32> {
    let m = clamp(1.0 - c, 0.0, 1.0);
    let m_sq = m * m;
    return f_zero + (vec3<f32>(1.0) - f_zero) * (m_sq * m_sq * m);
}

// Fresnel of the whole specular layer: the dielectric part is scaled by the specular factor.
fn spec_fresnel(s: Surface, c: f32) -> vec3<f32> {
    let dielectric = s.specular * schlick(vec3<f32>(0.04), c);
    let metal = schlick(s.base_color, c);
    return mix(dielectric, metal, s.metallic);
}

fn diffuse_color(s: Surface, n_dot_v: f32) -> vec3<f32> {
    let f = s.specular * schlick(vec3<f32>(0.04), n_dot_v).x;
    return (1.0 - s.metallic) * (1.0 - f) * s.base_color;
}

fn ggx_d(n_dot_h: f32, alpha_sq: f32) -> f32 {
    let d = n_dot_h * n_dot_h * (alpha_sq - 1.0) + 1.0;
    return alpha_sq / max(PI * d * d, 1e-30);
}

fn smith_lambda(n_dot_x: f32, alpha_sq: f32) -> f32 {
    let cos_sq = max(n_dot_x * n_dot_x, 1e-12);
    let tan_sq = max(0.0, 1.0 - cos_sq) / cos_sq;
    return 0.5 * (-1.0 + sqrt(1.0 + alpha_sq * tan_sq));
}

// Probability of choosing the specular lobe when sampling.
fn spec_probability(s: Surface, n_dot_v: f32) -> f32 {
    let ws = luminance(spec_fresnel(s, n_dot_v));
    let wd = luminance(diffuse_color(s, n_dot_v));
    if ws <= 0.0 {
        return 0.0;
    }
    if wd <= 0.0 {
        return 1.0;
    }
    return clamp(ws / (ws + wd), 0.1, 0.9);
}

// n must face wo (dot(n, wo) > 0).
fn bsdf_eval(s: Surface, n: vec3<f32>, wo: vec3<f32>, wi: vec3<f32>) -> BsdfEval {
    let n_dot_v = dot(n, wo);
    let n_dot_l = dot(n, wi);
    if n_dot_v <= 0.0 || n_dot_l <= 0.0 {
        return BsdfEval(vec3<f32>(0.0), 0.0);
    }
    let p_spec = spec_probability(s, n_dot_v);
    var f = diffuse_color(s, n_dot_v) * INV_PI;
    var pdf = (1.0 - p_spec) * n_dot_l * INV_PI;
    if p_spec > 0.0 && s.alpha >= DELTA_ALPHA {
        let h = normalize(wo + wi);
        let n_dot_h = max(dot(n, h), 0.0);
        let v_dot_h = max(dot(wo, h), 0.0);
        let alpha_sq = s.alpha * s.alpha;
        let d = ggx_d(n_dot_h, alpha_sq);
        let lv = smith_lambda(n_dot_v, alpha_sq);
        let ll = smith_lambda(n_dot_l, alpha_sq);
        let smith_g = 1.0 / (1.0 + lv + ll);
        let smith_g_view = 1.0 / (1.0 + lv);
        f += spec_fresnel(s, v_dot_h) * d * smith_g / (4.0 * n_dot_v * n_dot_l);
        pdf += p_spec * smith_g_view * d / (4.0 * n_dot_v);
    }
    return BsdfEval(f, pdf);
}

fn bsdf_sample(s: Surface, n: vec3<f32>, wo: vec3<f32>, u_lobe: f32, u: vec2<f32>) -> BsdfSample {
    var out = BsdfSample(vec3<f32>(0.0), vec3<f32>(0.0), 0.0, false, false);
    let n_dot_v = dot(n, wo);
    if n_dot_v <= 0.0 {
        return out;
    }
    let p_spec = spec_probability(s, n_dot_v);
    if u_lobe < p_spec {
        if s.alpha < DELTA_ALPHA {
            out.wi = reflect(-wo, n);
            out.weight = spec_fresnel(s, n_dot_v) / p_spec;
            out.pdf = 0.0;
            out.is_delta = true;
            out.valid = true;
            return out;
        }
        let h = to_world(sample_ggx_vndf(to_local(wo, n), s.alpha, u), n);
        out.wi = reflect(-wo, h);
    } else {
        out.wi = to_world(sample_cosine_hemisphere(u), n);
    }
    let e = bsdf_eval(s, n, wo, out.wi);
    if e.pdf <= 0.0 {
        return out;
    }
    out.weight = e.f * dot(n, out.wi) / e.pdf;
    out.pdf = e.pdf;
    out.valid = true;
    return out;
}
