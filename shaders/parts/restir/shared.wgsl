// ReSTIR's shared state (module gilab::restir): weighted reservoirs (Bitterli et al. 2020;
// "Making Connections", GDC), the unshadowed target function and the reservoir updates, GI
// reservoirs and ReGIR cells.
// Layouts must match src/techniques/restir/mod.rs.
#define_import_path gilab::restir

#import gilab::frame::frame
#import gilab::primary::{GSurface, current_surface, surface_material, disk_neighbour, similar}
#import gilab::math::luminance
#import gilab::brdf::{Surface, bsdf_eval}
#import gilab::lights::{LightSample, eval_light_point, light_shadow_ray}
#import gilab::ray::{spawn_ray_to, unoccluded, INFINITE_DISTANCE}
#import gilab::math::{PI, oct_decode}
#import gilab::sky::sky_radiance
#import gilab::regir::RegirSlot

struct RestirParams {
    // RIS candidates per pixel per frame from the local lights (triangles, point, spot) by
    // power, or from the pixel's ReGIR cell; 0 when the scene has none.
    candidates: u32,
    // Visibility test before reuse (talk: conservative visibility), biased mode only:
    // 0 off, 1 each light class's chosen candidate before the classes are merged, 2 the merged one.
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
    // 1: ReSTIR GI (indirect light by resampled sample paths).
    gi: u32,
    // Bounces of a GI sample path after its first hit; 0 = unbounded (Russian roulette).
    gi_bounces: u32,
    // 1: initial DI candidates come from the ReGIR grid cell of the shading point.
    regir: u32,
    // ReGIR cell edge length (world units); the grid has regir_dims^3 cells around the camera.
    regir_cell_size: f32,
    regir_dims: u32,
    // Light reservoirs per cell.
    regir_slots: u32,
    // RIS candidates per pixel per frame from the directional lights; 0 when there are none.
    directional_candidates: u32,
    // RIS candidates per pixel per frame from the sky (directions); 0 when the sky is black or
    // out of reach. When non-zero the sky is direct light: GI sample rays that escape add nothing.
    sky_candidates: u32,
    // 1: one power-proportional pool over all lights instead of classes; no sky candidates.
    single_pool: u32,
    // 1: GI sample directions cosine-sampled; 0: by the BSDF (`gi_sampling`).
    gi_cosine: u32,
    // Light candidates resampled at each hit of a GI sample path (RIS; 1 = by the pool's pdf).
    path_light_candidates: u32,
    // Specular hits a GI sample path goes through past the hit it would end at.
    specular_bounces: u32,
    // Roughness below which a hit counts as specular for `specular_bounces`.
    specular_max_roughness: f32,
    // 1: the local class's initial candidates by the light tree (gilab::light_tree).
    light_tree: u32,
    // BSDF-sampled candidates of the local class at pixels whose roughness is below
    // bsdf_max_roughness (0: none; parts/restir/initial_temporal.wgsl).
    bsdf_candidates: u32,
    bsdf_max_roughness: f32,
    // 1: ReGIR's cell slots draw their candidates by the light tree (`regir_fill = "tree"`).
    regir_tree: u32,
    pad_b: u32,
}

const VISIBILITY_PER_CLASS: u32 = 1u;
const VISIBILITY_MERGED: u32 = 2u;

struct Reservoir {
    // Light pool index, or SKY_SAMPLE for a direction to the sky.
    light: u32,
    // Barycentrics of the point on a triangle light; the octahedral-encoded direction of a sky sample.
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

@group(2) @binding(0) var<uniform> params: RestirParams;
// Three segments of `pixels` reservoirs: final of even frames, final of odd frames, temporal output.
@group(2) @binding(1) var<storage, read_write> reservoirs: array<Reservoir>;

const TEMPORAL_SEGMENT: u32 = 2u;

fn parity() -> u32 {
    return frame.frame_index & 1u;
}

fn reservoir_index(segment: u32, pixel: u32) -> u32 {
    return segment * params.pixels + pixel;
}

fn empty_reservoir() -> Reservoir {
    return Reservoir(0u, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
}

// The sky as a light class: a sample is a direction (solid-angle measure, the same at every
// pixel, so reuse needs no Jacobian), stored octahedral-encoded in the barycentric slots.
const SKY_SAMPLE: u32 = 0xffffffffu;

// A stored sample seen from p: a light pool sample, or the sky in a direction (infinitely far).
fn eval_sample(light: u32, bary: vec2<f32>, p: vec3<f32>) -> LightSample {
    if light == SKY_SAMPLE {
        let dir = oct_decode(bary);
        let sky = sky_radiance(dir);
        return LightSample(dir, INFINITE_DISTANCE, sky, 0.0, 0.0, 1.0, false, any(sky > vec3<f32>(0.0)), vec3<f32>(0.0));
    }
    return eval_light_point(light, bary, p);
}

// Unshadowed contribution of a stored light sample at a surface, per unit of the sample's
// measure (area for triangles, solid angle for the sky): f * cos * Le * G. Zero below the
// geometric surface.
struct Contribution {
    value: vec3<f32>,
    light: LightSample,
}

fn contribution(s: GSurface, light: u32, bary: vec2<f32>) -> Contribution {
    var c = Contribution(vec3<f32>(0.0), eval_sample(light, bary, s.pos.xyz));
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
    return unoccluded(light_shadow_ray(s.pos.xyz, s.geo_specular.xyz, l));
}

// A pixel's final DI reservoir (index ri) shaded with one visibility ray: f * Le * G * V * W.
// In biased mode an occluded sample is not passed on to the next frame (the reservoir is
// emptied). Used by restir/shade.wgsl and by techniques that take ReSTIR's direct light.
struct ShadedReservoir {
    radiance: vec3<f32>,
    shadow_rays: u32,
}

fn shade_reservoir(s: GSurface, ri: u32) -> ShadedReservoir {
    var out = ShadedReservoir(vec3<f32>(0.0), 0u);
    var r = reservoirs[ri];
    if s.pos.w < 0.5 || r.big_w <= 0.0 {
        return out;
    }
    let c = contribution(s, r.light, vec2<f32>(r.bary_u, r.bary_v));
    if !any(c.value > vec3<f32>(0.0)) {
        return out;
    }
    out.shadow_rays = 1u;
    if visible(s, c.light) {
        out.radiance = c.value * r.big_w;
    } else if params.unbiased == 0u {
        r.big_w = 0.0;
        r.w_sum = 0.0;
        reservoirs[ri] = r;
    }
    return out;
}

// Weighted reservoir sampling: take `candidate` with weight w with probability w / w_sum.
// A reservoir that starts from `r` (its sample with its target, weighted as a merged reservoir,
// and its M): the first candidate of spatial reuse.
fn reservoir_from(r: Reservoir, u: f32) -> Reservoir {
    var out = empty_reservoir();
    if update(&out, r, r.target_pdf * r.big_w * r.m, r.m, u) {
        out.target_pdf = r.target_pdf;
    }
    return out;
}

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

// A random pixel in the spatial-reuse disk around `pixel` (uniform in area), or -1 off screen.
fn spatial_neighbour(pixel: vec2<u32>, u: vec2<f32>) -> i32 {
    return disk_neighbour(pixel, params.spatial_radius, u);
}

// Spatial neighbours per pixel at most (MAX_SPATIAL in src/techniques/restir/params.rs).
const MAX_NEIGHBOURS: u32 = 8u;

// The neighbours a spatial pass merged, kept for the 1/Z pass over the same set.
struct Neighbours {
    ids: array<u32, 8>,
    count: u32,
}

fn no_neighbours() -> Neighbours {
    return Neighbours(array<u32, 8>(0u, 0u, 0u, 0u, 0u, 0u, 0u, 0u), 0u);
}

// How many neighbours a spatial pass draws this frame.
fn neighbour_budget() -> u32 {
    return min(params.spatial_count, MAX_NEIGHBOURS);
}

// A random neighbour in the spatial-reuse disk around pixel `idx` whose surface is similar to
// `s`, or -1 (off screen, the pixel itself, or a dissimilar surface): what spatial reuse of DI
// and GI reservoirs draws from.
fn similar_neighbour(pixel: vec2<u32>, idx: u32, s: GSurface, u: vec2<f32>) -> i32 {
    let n = spatial_neighbour(pixel, u);
    if n < 0 || u32(n) == idx || !similar(s, current_surface(u32(n))) {
        return -1;
    }
    return n;
}

// ReSTIR GI (Ouyang et al. 2021): a reservoir holds a sample point x_s found by a sample path,
// with the radiance leaving it towards the pixel that traced it. Weights are kept in the area
// measure at x_s, so reusing a sample at another pixel multiplies by that pixel's geometry term
// |cos| / d^2: the reconnection Jacobian is the ratio of the two geometry terms.
struct GiReservoir {
    // xyz: x_s, w: 1 when the reservoir holds a sample.
    point: vec4<f32>,
    // xyz: geometric normal at x_s, on the side the sample ray arrived from.
    normal: vec4<f32>,
    // rgb: radiance leaving x_s (its own emission excluded: direct light is ReSTIR DI's).
    radiance: vec4<f32>,
    w_sum: f32,
    m: f32,
    big_w: f32,
    target_pdf: f32,
}

// Three segments like `reservoirs`.
@group(2) @binding(2) var<storage, read_write> gi_reservoirs: array<GiReservoir>;
// Per pixel: sky radiance reached by this frame's GI sample ray (not reused: it has no point),
// or a mirror's whole sample; w: the specular layer's share of it (1 for a mirror's).
@group(2) @binding(3) var<storage, read_write> gi_sky: array<vec4<f32>>;

fn empty_gi_reservoir() -> GiReservoir {
    return GiReservoir(vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0), 0.0, 0.0, 0.0, 0.0);
}

struct GiEval {
    // f * cos * L * G (area measure at x_s).
    value: vec3<f32>,
    // Geometry term |cos at x_s| / d^2.
    geom: f32,
    wi: vec3<f32>,
    dist: f32,
}

fn gi_contribution(s: GSurface, r: GiReservoir) -> GiEval {
    var e = GiEval(vec3<f32>(0.0), 0.0, vec3<f32>(0.0), 0.0);
    if s.pos.w < 0.5 || r.point.w < 0.5 {
        return e;
    }
    let d = r.point.xyz - s.pos.xyz;
    let dist_sq = dot(d, d);
    if dist_sq <= 1e-12 {
        return e;
    }
    e.dist = sqrt(dist_sq);
    e.wi = d / e.dist;
    let cos_s = dot(r.normal.xyz, -e.wi);
    if dot(e.wi, s.geo_specular.xyz) <= 0.0 || cos_s <= 0.0 {
        return e;
    }
    let n = s.normal_alpha.xyz;
    let f = bsdf_eval(surface_material(s), n, s.wo_dist.xyz, e.wi).f;
    e.geom = cos_s / dist_sq;
    e.value = f * max(dot(n, e.wi), 0.0) * r.radiance.xyz * e.geom;
    return e;
}

// Reuse of a GI sample from surface `origin` at surface `receiver` is allowed only while the
// reconnection Jacobian G_receiver / G_origin stays within [1/10, 10] (Ouyang et al.): beyond it, a
// sample found far away lands next to the receiver and its weight has no bound (fireflies that
// spread through reuse). Z uses the same test, so the 1/Z weights stay consistent.
const GI_MAX_JACOBIAN: f32 = 10.0;

fn gi_jacobian_ok(receiver: GSurface, origin: GSurface, r: GiReservoir) -> bool {
    let g_to = gi_contribution(receiver, r).geom;
    let g_from = gi_contribution(origin, r).geom;
    if g_to <= 0.0 || g_from <= 0.0 {
        return false;
    }
    let j = g_to / g_from;
    return j <= GI_MAX_JACOBIAN && j >= 1.0 / GI_MAX_JACOBIAN;
}

fn gi_target(s: GSurface, r: GiReservoir) -> f32 {
    return luminance(gi_contribution(s, r).value);
}

// The GI counterpart of `reservoir_from`.
fn gi_reservoir_from(r: GiReservoir, u: f32) -> GiReservoir {
    var out = empty_gi_reservoir();
    gi_update(&out, r, r.target_pdf * r.big_w * r.m, r.m, u);
    return out;
}

fn gi_update(r: ptr<function, GiReservoir>, candidate: GiReservoir, w: f32, m: f32, u: f32) -> bool {
    (*r).w_sum += w;
    (*r).m += m;
    if w > 0.0 && u * (*r).w_sum < w {
        (*r).point = candidate.point;
        (*r).normal = candidate.normal;
        (*r).radiance = candidate.radiance;
        return true;
    }
    return false;
}

// Shadow test between a surface and a GI sample point (true = visible).
fn gi_visible(s: GSurface, r: GiReservoir) -> bool {
    return unoccluded(spawn_ray_to(s.pos.xyz, s.geo_specular.xyz, r.point.xyz, r.normal.xyz));
}

// ReGIR ("Making Connections"; Boksansky et al. 2021): a camera-centred grid whose cells hold
// reservoirs of lights pre-selected for the cell (gilab::regir), rebuilt every frame. Pixels
// draw their initial candidates from their cell.
@group(2) @binding(4) var<storage, read_write> regir_slots: array<RegirSlot>;
// Per pixel, for the debug views: x = DI reservoir M, y = its contribution weight W,
// z = selected light index + 1 (0 = none), w = ReGIR cell index + 1 (0 = none).
@group(2) @binding(5) var<storage, read_write> debug_out: array<vec4<f32>>;
// Per ReGIR cell: non-zero when a pixel reads it this frame (`regir_mark`), so the build
// fills only those cells. Cleared every frame before the mark pass.
@group(2) @binding(6) var<storage, read_write> regir_used: array<atomic<u32>>;

// Lower corner of the grid: centred on the camera, snapped to whole cells so cells stay put.
fn regir_origin() -> vec3<f32> {
    let c = params.regir_cell_size;
    let half = f32(params.regir_dims / 2u);
    return (floor(frame.camera_pos.xyz / c) - vec3<f32>(half)) * c;
}

// Cell index of a world point, or -1 outside the grid.
fn regir_cell(p: vec3<f32>) -> i32 {
    let g = (p - regir_origin()) / params.regir_cell_size;
    let d = f32(params.regir_dims);
    if any(g < vec3<f32>(0.0)) || any(g >= vec3<f32>(d)) {
        return -1;
    }
    let i = vec3<u32>(g);
    return i32((i.z * params.regir_dims + i.y) * params.regir_dims + i.x);
}

fn regir_cell_centre(cell: u32) -> vec3<f32> {
    let d = params.regir_dims;
    let i = vec3<u32>(cell % d, (cell / d) % d, cell / (d * d));
    return regir_origin() + (vec3<f32>(i) + 0.5) * params.regir_cell_size;
}
