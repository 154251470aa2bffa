// ReSTIR DI shared state: per-pixel primary surfaces and weighted reservoirs (Bitterli et al.
// 2020; "Making Connections", GDC), the unshadowed target function and the reservoir updates.
// Layouts must match src/techniques/restir/mod.rs.
#define_import_path gilab::restir

#import gilab::frame::frame
#import gilab::math::{luminance, offset_ray_origin}
#import gilab::brdf::{Surface, bsdf_eval}
#import gilab::lights::{LightSample, eval_light_point}
#import gilab::bvh::trace_any

struct RestirParams {
    // RIS candidates per pixel per frame drawn from the light pool by power.
    candidates: u32,
    // 1: trace one visibility ray for the chosen candidate (talk: conservative visibility).
    candidate_visibility: u32,
    // 1: reuse last frame's reservoir at the reprojected pixel.
    temporal: u32,
    // Previous reservoir's M is clamped to max_history x the current M.
    max_history: f32,
    spatial_count: u32,
    spatial_radius: f32,
    // 1: 1/Z weights (unbiased); 0: M-weighted combination (biased, cheaper).
    unbiased: u32,
    // 1: reuse a neighbour's light only if it is visible from this pixel (talk: bidirectional occlusion test).
    bidirectional: u32,
    // Pixels per segment (width x height), for indexing the double-buffered arrays.
    pixels: u32,
    // 1: average frames progressively (converges on a static view); 0: show this frame only.
    accumulate: u32,
    pad_b: u32,
    pad_c: u32,
}

// A primary hit (or a miss, valid = 0) as the passes need it.
struct GSurface {
    // xyz: position, w: 1 valid / 0 miss.
    pos: vec4<f32>,
    // xyz: shading normal, w: GGX alpha.
    normal_alpha: vec4<f32>,
    // xyz: geometric normal, w: specular factor.
    geo_specular: vec4<f32>,
    // rgb: base colour, w: metallic.
    base_metal: vec4<f32>,
    // xyz: direction to the viewer, w: distance to the camera.
    wo_dist: vec4<f32>,
    // rgb: emitted radiance towards the camera (or sky radiance for a miss).
    emission: vec4<f32>,
}

struct Reservoir {
    light: u32,
    // Barycentrics of the point on a triangle light.
    bary_u: f32,
    bary_v: f32,
    w_sum: f32,
    m: f32,
    // Unbiased contribution weight W (0 = empty).
    big_w: f32,
    // Target function of the sample at the reservoir's own surface.
    target_pdf: f32,
    pad: f32,
}

@group(1) @binding(2) var<uniform> params: RestirParams;
// Two segments of `pixels` surfaces: this frame's and last frame's (by frame parity).
@group(1) @binding(3) var<storage, read_write> surfaces: array<GSurface>;
// Three segments of `pixels` reservoirs: final of even frames, final of odd frames, temporal output.
@group(1) @binding(4) var<storage, read_write> reservoirs: array<Reservoir>;

const TEMPORAL_SEGMENT: u32 = 2u;

fn parity() -> u32 {
    return frame.frame_index & 1u;
}

fn surface_index(segment: u32, pixel: u32) -> u32 {
    return segment * params.pixels + pixel;
}

fn reservoir_index(segment: u32, pixel: u32) -> u32 {
    return segment * params.pixels + pixel;
}

fn empty_reservoir() -> Reservoir {
    return Reservoir(0u, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
}

fn surface_material(s: GSurface) -> Surface {
    return Surface(s.base_metal.xyz, s.base_metal.w, s.normal_alpha.w, s.geo_specular.w);
}

// Unshadowed contribution of a stored light sample at a surface, per unit of the light's
// measure (area for triangles): f * cos * Le * G. Zero below the geometric surface.
struct Contribution {
    value: vec3<f32>,
    light: LightSample,
}

fn contribution(s: GSurface, light: u32, bary: vec2<f32>) -> Contribution {
    var c = Contribution(vec3<f32>(0.0), eval_light_point(light, bary, s.pos.xyz));
    if s.pos.w < 0.5 || !c.light.valid || dot(c.light.wi, s.geo_specular.xyz) <= 0.0 {
        return c;
    }
    let n = s.normal_alpha.xyz;
    let e = bsdf_eval(surface_material(s), n, s.wo_dist.xyz, c.light.wi);
    c.value = e.f * max(dot(n, c.light.wi), 0.0) * c.light.radiance * c.light.geom;
    return c;
}

// The target function p-hat: luminance of the unshadowed contribution.
fn target_at(s: GSurface, r: Reservoir) -> f32 {
    return luminance(contribution(s, r.light, vec2<f32>(r.bary_u, r.bary_v)).value);
}

// Shadow test from a surface to a light sample (true = visible).
fn visible(s: GSurface, l: LightSample) -> bool {
    let p = offset_ray_origin(s.pos.xyz, s.geo_specular.xyz);
    let t_max = select(l.dist * (1.0 - 1e-4), 1e30, l.is_delta && l.dist >= 1e30);
    return !trace_any(p, l.wi, 0.0, t_max);
}

// Weighted reservoir sampling: take `candidate` with weight w with probability w / w_sum.
fn update(r: ptr<function, Reservoir>, candidate: Reservoir, w: f32, m: f32, u: f32) -> bool {
    (*r).w_sum += w;
    (*r).m += m;
    if w > 0.0 && u * (*r).w_sum < w {
        (*r).light = candidate.light;
        (*r).bary_u = candidate.bary_u;
        (*r).bary_v = candidate.bary_v;
        return true;
    }
    return false;
}

// Similar enough surfaces to share samples: normals within ~25 degrees, depths within 10%.
fn similar(a: GSurface, b: GSurface) -> bool {
    if a.pos.w < 0.5 || b.pos.w < 0.5 {
        return false;
    }
    if dot(a.normal_alpha.xyz, b.normal_alpha.xyz) < 0.9 {
        return false;
    }
    let plane = abs(dot(b.pos.xyz - a.pos.xyz, a.geo_specular.xyz));
    return plane < 0.1 * a.wo_dist.w && abs(a.wo_dist.w - b.wo_dist.w) < 0.1 * a.wo_dist.w;
}
