// BRDF models shared by every technique (`[shading] brdf`, per material):
// - lambert-ggx: glTF metallic-roughness, Lambert diffuse + GGX specular (height-correlated Smith
//   G2), KHR_materials_specular's factor scaling the dielectric lobe (0 = pure Lambert);
// - callisto: The Rendering of The Callisto Protocol (SIGGRAPH 2023): the diffuse gets diffuse
//   Fresnel and retroreflection (c1), the specular dual GGX and a Fresnel falloff, and both the
//   smooth terminator (c2); its defaults reproduce lambert-ggx;
// - callisto-proxima: the same with Proxima, the seed's fit of the GGX-microfacet diffuse,
//   in place of Lambert.
// Sampling is the same for all: GGX visible normals (one of the two lobes) or cosine, and every
// pdf returned is the mixture pdf that sampling actually uses.
// Roughness so low that alpha < DELTA_ALPHA is treated as a perfect mirror (delta lobe; the dual
// lobe is then ignored).
#define_import_path gilab::brdf

#import gilab::math::{PI, INV_PI, luminance, to_local, to_world}
#import gilab::sampling::{sample_cosine_hemisphere, sample_ggx_vndf}

const DELTA_ALPHA: f32 = 1e-3;

const BRDF_LAMBERT_GGX: u32 = 0u;
const BRDF_CALLISTO: u32 = 1u;
const BRDF_CALLISTO_PROXIMA: u32 = 2u;

// Callisto parameters and the model (layout of src/scene/shading.rs `gpu_words`).
struct Shading {
    // rgb: rho_f, diffuse Fresnel (intensity x tint), w: n_f, its falloff.
    fresnel: vec4<f32>,
    // rgb: rho_r, retroreflection (intensity x tint), w: m_f, diffuse Fresnel tangent falloff.
    retro: vec4<f32>,
    // rgb: smooth terminator tint, w: o, smooth terminator.
    terminator: vec4<f32>,
    // x: n_r, y: m_r (retroreflection falloffs), z: p, terminator length, w: n_s, specular
    // Fresnel falloff.
    falloffs: vec4<f32>,
    // x: dual specular roughness scale, y: dual specular opacity, z: model, w: dielectric F0
    // from KHR_materials_ior (0: 0.04, IOR 1.5).
    dual: vec4<f32>,
}

struct Surface {
    base_color: vec3<f32>,
    metallic: f32,
    alpha: f32,
    specular: f32,
    shading: Shading,
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

// Lambert-GGX with Callisto's defaults (which reproduce it).
fn default_shading() -> Shading {
    return Shading(
        vec4<f32>(1.0, 1.0, 1.0, 0.75),
        vec4<f32>(1.0, 1.0, 1.0, 0.75),
        vec4<f32>(1.0, 1.0, 1.0, 0.0),
        vec4<f32>(0.75, 0.75, 0.5, 0.5),
        vec4<f32>(1.0, 0.0, f32(BRDF_LAMBERT_GGX), 0.0),
    );
}

fn make_surface(base: vec3<f32>, metallic: f32, roughness: f32, specular: f32) -> Surface {
    return make_shaded_surface(base, metallic, roughness, specular, default_shading());
}

fn make_shaded_surface(base: vec3<f32>, metallic: f32, roughness: f32, specular: f32, shading: Shading) -> Surface {
    let r = clamp(roughness, 0.0, 1.0);
    return Surface(clamp(base, vec3<f32>(0.0), vec3<f32>(1.0)), clamp(metallic, 0.0, 1.0), r * r, clamp(specular, 0.0, 1.0), shading);
}

fn brdf_model(s: Surface) -> u32 {
    return u32(s.shading.dual.z + 0.5);
}

fn schlick(f_zero: vec3<f32>, c: f32) -> vec3<f32> {
    let m = clamp(1.0 - c, 0.0, 1.0);
    let m_sq = m * m;
    return f_zero + (vec3<f32>(1.0) - f_zero) * (m_sq * m_sq * m);
}

// The seed's remap r(x) = 2(1 - x): parameters in [0, 1] with 0.5 meaning "as Schlick".
fn falloff_remap(x: f32) -> f32 {
    return 2.0 * (1.0 - x);
}

// x^e for x in [0, 1], with x^0 = 1 (pow(0, 0) is undefined in SPIR-V).
fn unit_pow(x: f32, e: f32) -> f32 {
    if e <= 0.0 {
        return 1.0;
    }
    return pow(clamp(x, 1e-20, 1.0), e);
}

// Callisto's specular Fresnel falloff: f0 + t(2 - r(n_s)) (1 - f0) (1 - c)^(5 r(n_s)); n_s = 0.5
// is Schlick, 0 removes the Fresnel term.
fn schlick_falloff(f_zero: vec3<f32>, c: f32, n_s: f32) -> vec3<f32> {
    let r = falloff_remap(n_s);
    let w = clamp(2.0 - r, 0.0, 1.0);
    return f_zero + w * (vec3<f32>(1.0) - f_zero) * unit_pow(1.0 - c, 5.0 * r);
}

fn dielectric_fresnel(s: Surface, c: f32) -> vec3<f32> {
    let f_zero = vec3<f32>(select(0.04, s.shading.dual.w, s.shading.dual.w > 0.0));
    if brdf_model(s) == BRDF_LAMBERT_GGX {
        return schlick(f_zero, c);
    }
    return schlick_falloff(f_zero, c, s.shading.falloffs.w);
}

// Fresnel of the whole specular layer: the dielectric part is scaled by the specular factor.
fn spec_fresnel(s: Surface, c: f32) -> vec3<f32> {
    let dielectric = s.specular * dielectric_fresnel(s, c);
    var metal = schlick(s.base_color, c);
    if brdf_model(s) != BRDF_LAMBERT_GGX {
        metal = schlick_falloff(s.base_color, c, s.shading.falloffs.w);
    }
    return mix(dielectric, metal, s.metallic);
}

fn diffuse_color(s: Surface, n_dot_v: f32) -> vec3<f32> {
    let f = s.specular * dielectric_fresnel(s, n_dot_v).x;
    return (1.0 - s.metallic) * (1.0 - f) * s.base_color;
}

// Angles as fractions of a right angle (the terminator mask's units).
fn right_angle_fraction(c: f32) -> f32 {
    return acos(clamp(c, -1.0, 1.0)) * (2.0 / PI);
}

// c1(theta_d, theta_h): diffuse Fresnel x retroreflection, lerps from 1 towards rho_f / rho_r
// by the masks alpha_f = (1 - cos theta_d)^(5 r(n_f)) cos(theta_h)^(5 r(m_f)) and
// alpha_r = (1 - cos theta_h)^(5 r(n_r)) cos(theta_d)^(5 r(m_r)). Symmetric in wi and wo.
fn callisto_diffuse_lobes(sh: Shading, cos_d: f32, cos_h: f32) -> vec3<f32> {
    let a_f = unit_pow(1.0 - cos_d, 5.0 * falloff_remap(sh.fresnel.w)) * unit_pow(cos_h, 5.0 * falloff_remap(sh.retro.w));
    let a_r = unit_pow(1.0 - cos_h, 5.0 * falloff_remap(sh.falloffs.x)) * unit_pow(cos_d, 5.0 * falloff_remap(sh.falloffs.y));
    return mix(vec3<f32>(1.0), sh.fresnel.xyz, a_f) * mix(vec3<f32>(1.0), sh.retro.xyz, a_r);
}

// c2(theta_i) = lerp(1, smoothstep(0, alpha_s p, cos theta_i), alpha_s o) with the mask
// alpha_s = (1 - (1 - theta_d)^3)(1 - (1 - theta_h)^3) (angles in right angles), which leaves
// the retroreflection (theta_d = 0) and Fresnel (theta_h = 0) regions untouched. The seed lists a
// terminator tint without its formula: here the smoothed band takes the tint where the
// smoothstep is between 0 and 1 (t(s) = s lerp(tint, 1, s)); a white tint is the seed's formula.
fn callisto_terminator(sh: Shading, n_dot_l: f32, cos_d: f32, cos_h: f32) -> vec3<f32> {
    let td = 1.0 - right_angle_fraction(cos_d);
    let th = 1.0 - right_angle_fraction(cos_h);
    let a_s = (1.0 - td * td * td) * (1.0 - th * th * th);
    let edge = a_s * sh.falloffs.z;
    var s = 1.0;
    if edge > 1e-6 {
        s = smoothstep(0.0, edge, n_dot_l);
    }
    let band = s * mix(sh.terminator.xyz, vec3<f32>(1.0), s);
    return mix(vec3<f32>(1.0), band, a_s * sh.terminator.w);
}

// Proxima / Lambert: alpha (-0.55 + 0.19 / cos theta_i)(1 - sqrt(cos theta_k)) + 1 with
// cos theta_k = -V.L clamped to [0, 1] (V, L both pointing away from the surface), alpha the
// GGX alpha. cos theta_i is kept away from 0: the product with cos theta_i the estimators apply
// stays finite (the seed's advice to pre-multiply).
fn proxima_factor(alpha: f32, n_dot_l: f32, v_dot_l: f32) -> f32 {
    let cos_k = clamp(-v_dot_l, 0.0, 1.0);
    return alpha * (-0.55 + 0.19 / max(n_dot_l, 1e-4)) * (1.0 - sqrt(cos_k)) + 1.0;
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

// GGX microfacet specular (without Fresnel) and its visible-normal sampling pdf for one alpha.
fn ggx_lobe(n_dot_v: f32, n_dot_l: f32, n_dot_h: f32, alpha: f32) -> vec2<f32> {
    let alpha_sq = alpha * alpha;
    let d = ggx_d(n_dot_h, alpha_sq);
    let lv = smith_lambda(n_dot_v, alpha_sq);
    let ll = smith_lambda(n_dot_l, alpha_sq);
    let smith_g = 1.0 / (1.0 + lv + ll);
    let smith_g_view = 1.0 / (1.0 + lv);
    return vec2<f32>(d * smith_g / (4.0 * n_dot_v * n_dot_l), smith_g_view * d / (4.0 * n_dot_v));
}

// Callisto's second specular lobe: perceptual roughness scaled, clamped to 1 (alpha = r^2).
fn dual_alpha(s: Surface) -> f32 {
    let r = min(sqrt(s.alpha) * s.shading.dual.x, 1.0);
    return max(r * r, DELTA_ALPHA);
}

fn dual_opacity(s: Surface) -> f32 {
    if brdf_model(s) == BRDF_LAMBERT_GGX {
        return 0.0;
    }
    return clamp(s.shading.dual.y, 0.0, 1.0);
}

// n must face wo (dot(n, wo) > 0).
fn bsdf_eval(s: Surface, n: vec3<f32>, wo: vec3<f32>, wi: vec3<f32>) -> BsdfEval {
    let n_dot_v = dot(n, wo);
    let n_dot_l = dot(n, wi);
    if n_dot_v <= 0.0 || n_dot_l <= 0.0 {
        return BsdfEval(vec3<f32>(0.0), 0.0);
    }
    let model = brdf_model(s);
    let p_spec = spec_probability(s, n_dot_v);
    let h = normalize(wo + wi);
    let n_dot_h = max(dot(n, h), 0.0);
    let v_dot_h = max(dot(wo, h), 0.0);
    var f = diffuse_color(s, n_dot_v) * INV_PI;
    if model != BRDF_LAMBERT_GGX {
        f *= callisto_diffuse_lobes(s.shading, v_dot_h, n_dot_h);
        if model == BRDF_CALLISTO_PROXIMA {
            f *= proxima_factor(s.alpha, n_dot_l, dot(wo, wi));
        }
    }
    var pdf = (1.0 - p_spec) * n_dot_l * INV_PI;
    if p_spec > 0.0 && s.alpha >= DELTA_ALPHA {
        var lobe = ggx_lobe(n_dot_v, n_dot_l, n_dot_h, s.alpha);
        let opacity = dual_opacity(s);
        if opacity > 0.0 {
            lobe = mix(lobe, ggx_lobe(n_dot_v, n_dot_l, n_dot_h, dual_alpha(s)), opacity);
        }
        f += spec_fresnel(s, v_dot_h) * lobe.x;
        pdf += p_spec * lobe.y;
    }
    if model != BRDF_LAMBERT_GGX {
        f *= callisto_terminator(s.shading, n_dot_l, v_dot_h, n_dot_h);
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
            // (The terminator mask is 0 at theta_h = 0, so c2 = 1 for the mirror.)
            out.weight = spec_fresnel(s, n_dot_v) / p_spec;
            out.pdf = 0.0;
            out.is_delta = true;
            out.valid = true;
            return out;
        }
        // The lobe choice reuses u_lobe rescaled to [0, 1).
        var alpha = s.alpha;
        if u_lobe < p_spec * dual_opacity(s) {
            alpha = dual_alpha(s);
        }
        let h = to_world(sample_ggx_vndf(to_local(wo, n), alpha, u), n);
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

// The specular layer alone (the reflections part): F x GGX (with Callisto's second lobe and
// terminator where the model has them) and the pdf of specular_sample; zero for the mirror lobe.
fn specular_eval(s: Surface, n: vec3<f32>, wo: vec3<f32>, wi: vec3<f32>) -> BsdfEval {
    let n_dot_v = dot(n, wo);
    let n_dot_l = dot(n, wi);
    if n_dot_v <= 0.0 || n_dot_l <= 0.0 || s.alpha < DELTA_ALPHA {
        return BsdfEval(vec3<f32>(0.0), 0.0);
    }
    let h = normalize(wo + wi);
    let n_dot_h = max(dot(n, h), 0.0);
    let v_dot_h = max(dot(wo, h), 0.0);
    var lobe = ggx_lobe(n_dot_v, n_dot_l, n_dot_h, s.alpha);
    let opacity = dual_opacity(s);
    if opacity > 0.0 {
        lobe = mix(lobe, ggx_lobe(n_dot_v, n_dot_l, n_dot_h, dual_alpha(s)), opacity);
    }
    var f = spec_fresnel(s, v_dot_h) * lobe.x;
    if brdf_model(s) != BRDF_LAMBERT_GGX {
        f *= callisto_terminator(s.shading, n_dot_l, v_dot_h, n_dot_h);
    }
    return BsdfEval(f, lobe.y);
}

// A direction from the specular layer alone, by its visible normals (the mirror direction for
// the delta lobe); weight = f_spec cos / pdf (F for the mirror). u_lobe picks Callisto's lobe.
fn specular_sample(s: Surface, n: vec3<f32>, wo: vec3<f32>, u_lobe: f32, u: vec2<f32>) -> BsdfSample {
    var out = BsdfSample(vec3<f32>(0.0), vec3<f32>(0.0), 0.0, false, false);
    let n_dot_v = dot(n, wo);
    if n_dot_v <= 0.0 {
        return out;
    }
    if s.alpha < DELTA_ALPHA {
        out.wi = reflect(-wo, n);
        out.weight = spec_fresnel(s, n_dot_v);
        out.is_delta = true;
        out.valid = true;
        return out;
    }
    var alpha = s.alpha;
    if u_lobe < dual_opacity(s) {
        alpha = dual_alpha(s);
    }
    let h = to_world(sample_ggx_vndf(to_local(wo, n), alpha, u), n);
    out.wi = reflect(-wo, h);
    let e = specular_eval(s, n, wo, out.wi);
    if e.pdf <= 0.0 {
        return out;
    }
    out.weight = e.f * dot(n, out.wi) / e.pdf;
    out.pdf = e.pdf;
    out.valid = true;
    return out;
}

// Cosine-weighted hemispherical average of the specular layer's directional albedo: Fresnel as
// X + Y (1 - v.h)^5 (X at normal incidence), times the GGX lobe's average energy with F = 1
// (A) and its Fresnel moment (B), tabulated by perceptual roughness from the same integral as
// the reflections part's table (src/parts/reflections.rs). For diffuse-only caches that count a
// surface's specular energy in its albedo, as Lumen's card capture does ("approximate specular
// by modifying albedo to account for the lost energy", shared/seeds/000).
fn specular_albedo_average(s: Surface) -> vec3<f32> {
    // The table's six rows (roughness, A, B), read by branches rather than from an array: an
    // array indexed by a variable lives in local memory on NVIDIA GPUs (see gilab::counters).
    let x = clamp(sqrt(s.alpha), 0.0, 1.0);
    var e = vec2<f32>(0.409, 0.0028);
    if x <= 0.2 {
        e = mix(vec2<f32>(1.0, 0.0476), vec2<f32>(0.996, 0.0434), x / 0.2);
    } else if x <= 0.3 {
        e = mix(vec2<f32>(0.996, 0.0434), vec2<f32>(0.976, 0.0355), (x - 0.2) / (0.3 - 0.2));
    } else if x <= 0.5 {
        e = mix(vec2<f32>(0.976, 0.0355), vec2<f32>(0.882, 0.0187), (x - 0.3) / (0.5 - 0.3));
    } else if x <= 0.7 {
        e = mix(vec2<f32>(0.882, 0.0187), vec2<f32>(0.708, 0.0086), (x - 0.5) / (0.7 - 0.5));
    } else if x <= 1.0 {
        e = mix(vec2<f32>(0.708, 0.0086), vec2<f32>(0.409, 0.0028), (x - 0.7) / (1.0 - 0.7));
    }
    let ea = e.x;
    let eb = e.y;
    let f_x = spec_fresnel(s, 1.0);
    let f_y = spec_fresnel(s, 0.0) - f_x;
    return f_x * ea + f_y * eb;
}
