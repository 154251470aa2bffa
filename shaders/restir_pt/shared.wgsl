// ReSTIR PT's shared state (module gilab::restir_pt): path reservoirs, the path tracer that
// makes each pixel's candidate, and the hybrid shift that moves a path to another pixel
// (Lin et al. 2022, "Generalized Resampled Importance Sampling: Foundations of ReSTIR").
//
// Domain: a path is x_1 (the pixel's primary surface) ... x_k (a light point, an emitter hit,
// or the sky for k reached by an escaping ray); its integrand F is the path tracer's
// contribution of that one path in primary sample space (throughput f cos / p per step, the
// light's MIS weight at the end), so the target, luminance(F), is the same function at every
// pixel. Each vertex x_j draws its random numbers from its own stream (the path's seed and j:
// NEE's three first, then the BSDF's three), so replaying a vertex never depends on how many
// numbers another vertex used. No Russian roulette: a shifted path must take the same length.
//
// Hybrid shift: the first x_r (r >= 2, reached by BSDF sampling) with x_{r-1} and x_r rough
// (roughness >= reconnection_roughness) and |x_r - x_{r-1}| >= reconnection_distance is the reconnection vertex. The offset path replays
// the base path's random numbers from its own primary surface up to y_{r-1}, connects y_{r-1}
// to x_r (a visibility ray) and keeps the suffix from x_r on. Without such a vertex the whole
// path is replayed. Jacobian in primary sample space: 1 for replayed steps; at the connection
// [p_y(y_{r-1} -> x_r) cos_r' / d'^2] / [p_x(x_{r-1} -> x_r) cos_r / d^2]; and, when x_r's
// next step is BSDF-sampled, p_y(x_r -> x_{r+1}) / p_x(x_r -> x_{r+1}) (its incident direction
// changed). The light of an NEE step is a function of its random numbers alone (never of the
// shading point), so a replayed NEE step keeps the same light point and costs no factor.
//
// The shift fails (F = 0) where the offset path cannot be the image of a base path under the
// inverse shift: a replayed ray escapes or finds a reconnection pair earlier than x_r; y_{r-1}
// or x_r is not rough or too close; x_r is seen from its other side; the connection is
// occluded; a BSDF (a lobe) does not contain the new direction.
#define_import_path gilab::restir_pt

#import gilab::frame::frame
#import gilab::primary::{GSurface, surface_material}
#import gilab::math::luminance
#import gilab::rng::{Rng, rand, rand_pair, pcg_hash, rng_init, STREAM_PT_SPATIAL}
#import gilab::brdf::{Surface, bsdf_eval, bsdf_sample}
#import gilab::bvh::{trace_closest, NO_HIT}
#import gilab::surface_point::{HitSurface, surface_at}
#import gilab::lights::{light_shadow_ray, triangle_emission, triangle_light_pdf}
#import gilab::scene::tri_geom
#import gilab::sky::{sky_radiance, sky_pdf}
#import gilab::ray::{spawn_ray_origin, unoccluded}
#import gilab::sampling::power_heuristic
#import gilab::path_vertex::{nee_sky_share, pick_nee_light}

struct PtParams {
    // The reference's max_depth: NEE at x_1 .. x_D, emitters hit up to x_{D+1}.
    max_bounces: u32,
    // 1: reuse last frame's reservoir at the reprojected pixel.
    temporal: u32,
    // Last frame's confidence is clamped to max_history x the current one.
    max_history: f32,
    spatial_count: u32,
    spatial_radius: f32,
    // Reconnection criteria: GGX alpha (roughness^2) at or above this is rough; world distance.
    rc_alpha: f32,
    rc_distance: f32,
    // Pixels per reservoir segment.
    pixels: u32,
    // 1: average frames progressively; 0: each frame alone (real-time experiments).
    accumulate: u32,
    // 1: paths of length 2 (direct light) are left out: ReSTIR DI (the direct-light part) gives them.
    direct_restir: u32,
    // 1: debug views written.
    debug: u32,
    // Paired spatial reuse: the neighbours come in pairs(p +- offset), `pairs` offsets a frame
    // (0: each pixel draws its own neighbours).
    pairs: u32,
}

// End kinds of a path (info bits 16-17).
const END_EMISSION: u32 = 0u; // x_k: an emitter hit by a BSDF-sampled ray from x_{k-1}
const END_NEE: u32 = 1u; // x_k: a light point (or sky direction) sampled by NEE at x_{k-1}
const END_SKY: u32 = 2u; // a BSDF-sampled ray from x_{k-1} escaped to the sky
// x_k (k > r): a suffix hit where the path ended in a radiance cache (`suffix_terminate`); the
// cache's light there is in the suffix radiance, which every shift reuses as it is.
const END_CACHE: u32 = 3u;

struct PathReservoir {
    // Reconnection vertex x_r: its triangle (NO_HIT: none, the shift replays the whole path)
    // and barycentrics; it follows its object when that moves.
    rc_tri: u32,
    rc_bary_u: f32,
    rc_bary_v: f32,
    // Bits 0-7: r; 8-15: k (the light vertex); 16-17: end kind; 18: x_r hit on its front face;
    // 19: the light is a delta light (NEE's weight is then 1).
    info: u32,
    // rgb: radiance arriving at x_r along rc_dir from the rest of the path (the steps after
    // x_r's own and the light's MIS weight, except where the weight depends on x_r's incident
    // direction: k = r + 1, or x_r is the emitter); w: the light's pdf for that weight (solid
    // angle at x_r for k = r + 1, area measure for k = r).
    suffix: vec4<f32>,
    // xyz: direction from x_r to x_{r+1}; w: its BSDF pdf at x_r given this path's incident
    // direction (0 when x_r's step is NEE's).
    rc_dir: vec4<f32>,
    // rgb: F, this path's contribution at the reservoir's own pixel; w: the target, luminance(F).
    contrib: vec4<f32>,
    // Seed of the per-vertex random numbers.
    seed: u32,
    // Area-measure pdf of x_r from this path's x_{r-1}: p(omega) cos_r / d^2.
    rc_area_pdf: f32,
    // Unbiased contribution weight W (0: empty) and confidence M.
    big_w: f32,
    m: f32,
}

@group(2) @binding(0) var<uniform> params: PtParams;
// Three segments of `pixels` reservoirs: final of even frames, final of odd frames, the
// temporal pass's output. The initial pass writes the temporal segment, which the temporal
// pass then updates in place (each pixel only its own).
@group(2) @binding(1) var<storage, read_write> reservoirs: array<PathReservoir>;
// Debug planes (vec4 per pixel): 0 = (reconnection vertex r, 0 = none; shift kind of the final
// sample: 0 replay, 1 reconnection at x_2, 2 hybrid; shift failure rate of this frame's
// shifts; |log10 J| of the selected shifted sample), 1 = (path length k, M, W, target).
@group(2) @binding(2) var<storage, read_write> debug_out: array<vec4<f32>>;
// Direct light per pixel from ReSTIR DI (`direct = "restir"`), written by the direct-light part.
@group(2) @binding(3) var<storage, read_write> direct_light: array<vec4<f32>>;

const TEMPORAL_SEGMENT: u32 = 2u;

// Paired spatial reuse (`spatial_pairs`, ReSTIR PT Enhanced's reciprocal neighbours): this
// frame's offsets d_k, the same at every pixel, so pixel p's neighbours p + d_k and p - d_k have
// p as theirs. Pass `path_pairs` traces each pair {p, p + d_k} once (at p: both of its shifts)
// and `path_spatial` reads them from both ends, so n neighbours cost n shifts instead of 2n.
const MAX_PAIRS: u32 = 4u;

// One shift of a pair as `path_pairs` stores it: F at the receiving pixel and |dT/dx|
// (0: failed), the offset path's pdfs (Shifted), and w = 1 where the pair holds (both pixels
// valid, similar both ways; 0: not neighbours this frame).
struct PairShift {
    contrib_jacobian: vec4<f32>,
    pdfs: vec4<f32>,
}

// Pair shifts: per pixel p and offset k, p's path shifted to p + d_k (2 (p MAX_PAIRS + k)),
// then that pixel's path shifted to p (+ 1).
@group(2) @binding(4) var<storage, read_write> pair_shifts: array<PairShift>;

// Offset k of this frame (never (0, 0)): a point of the spatial_radius disk, rounded, drawn
// from the frame's seed alone (a stream no pixel's coordinates reach).
fn pair_offset(k: u32) -> vec2<i32> {
    var rng = rng_init(vec2<u32>(0xffffffffu, k), frame.sample_offset, STREAM_PT_SPATIAL, frame.seed);
    let u = rand_pair(&rng);
    let r = params.spatial_radius * sqrt(u.x);
    let angle = 6.28318530717959 * u.y;
    let d = vec2<i32>(i32(round(r * cos(angle))), i32(round(r * sin(angle))));
    return select(d, vec2<i32>(1, 0), all(d == vec2<i32>(0)));
}

// The pixel at p + d, or -1 outside the image.
fn offset_pixel(p: vec2<u32>, d: vec2<i32>) -> i32 {
    let q = vec2<i32>(p) + d;
    if q.x < 0 || q.y < 0 || q.x >= i32(frame.size.x) || q.y >= i32(frame.size.y) {
        return -1;
    }
    return q.y * i32(frame.size.x) + q.x;
}

fn pair_shift_index(owner: u32, k: u32, which: u32) -> u32 {
    return 2u * (owner * MAX_PAIRS + k) + which;
}

fn store_pair_shift(at: u32, sh: Shifted, holds: bool) {
    pair_shifts[at] = PairShift(vec4<f32>(sh.contrib, sh.jacobian), vec4<f32>(sh.rc_area_pdf, sh.rc_pdf, f32(sh.failed), select(0.0, 1.0, holds)));
}

fn load_pair_shift(at: u32) -> Shifted {
    let p = pair_shifts[at];
    return Shifted(p.contrib_jacobian.xyz, p.contrib_jacobian.w, p.pdfs.x, p.pdfs.y, 0u, p.pdfs.z > 0.5);
}

fn pair_holds(at: u32) -> bool {
    return pair_shifts[at].pdfs.w > 0.5;
}

fn reservoir_index(segment: u32, pixel: u32) -> u32 {
    return segment * params.pixels + pixel;
}

fn parity() -> u32 {
    return frame.frame_index & 1u;
}

fn empty_path_reservoir() -> PathReservoir {
    return PathReservoir(NO_HIT, 0.0, 0.0, 0u, vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0), 0u, 0.0, 0.0, 0.0);
}

fn rc_index(r: PathReservoir) -> u32 {
    return select(r.info & 0xffu, 0u, r.rc_tri == NO_HIT);
}

fn path_length(r: PathReservoir) -> u32 {
    return (r.info >> 8u) & 0xffu;
}

fn end_kind(r: PathReservoir) -> u32 {
    return (r.info >> 16u) & 3u;
}

fn pack_info(rc: u32, k: u32, end: u32, front: bool, delta: bool) -> u32 {
    return (rc & 0xffu) | ((k & 0xffu) << 8u) | (end << 16u) | (u32(front) << 18u) | (u32(delta) << 19u);
}

// A path vertex with what shading it needs; wo points back along the path.
struct Vertex {
    pos: vec3<f32>,
    geo: vec3<f32>,
    normal: vec3<f32>,
    wo: vec3<f32>,
    material: Surface,
}

fn primary_vertex(s: GSurface) -> Vertex {
    return Vertex(s.pos.xyz, s.geo_specular.xyz, s.normal_alpha.xyz, s.wo_dist.xyz, surface_material(s));
}

fn hit_vertex(h: HitSurface, dir: vec3<f32>) -> Vertex {
    return Vertex(h.position, h.geo_normal, h.normal, -dir, h.material);
}

// Every vertex is shaded at its finest texture level, so a vertex evaluates the same whether a
// base path or a shift reaches it (ray cones would differ with the ray's length).
fn path_surface(tri: u32, bary: vec2<f32>, dir: vec3<f32>) -> HitSurface {
    return surface_at(tri, bary, dir, 0.0);
}

// Vertex j's six random numbers: NEE's (selection, point) and the BSDF's (lobe, direction).
struct VertexNumbers {
    u_select: f32,
    u_light: vec2<f32>,
    u_lobe: f32,
    u_dir: vec2<f32>,
}

fn vertex_numbers(seed: u32, j: u32) -> VertexNumbers {
    var rng = Rng(pcg_hash(seed ^ pcg_hash(j * 0x9e3779b9u + 0x68bc21ebu)));
    let u_select = rand(&rng);
    let u_light = rand_pair(&rng);
    let u_lobe = rand(&rng);
    let u_dir = rand_pair(&rng);
    return VertexNumbers(u_select, u_light, u_lobe, u_dir);
}

fn rough(m: Surface) -> bool {
    return m.alpha >= params.rc_alpha;
}

// Whether x_b may be the reconnection vertex after x_a (x_b's own roughness is checked by the
// caller, which has its material).
fn reconnectable(a: Vertex, b_pos: vec3<f32>) -> bool {
    return rough(a.material) && distance(a.pos, b_pos) >= params.rc_distance;
}

// The triangle point a reservoir's reconnection vertex sits at (this frame's pose).
fn rc_position(r: PathReservoir) -> vec3<f32> {
    let g = tri_geom[r.rc_tri];
    return g.vertex_a.xyz + r.rc_bary_u * g.edge_b.xyz + r.rc_bary_v * g.edge_c.xyz;
}

// What a shift gives: the offset path's contribution F at the new pixel and |dT/dx| (both 0
// on failure), the offset path's own pdfs to store if it is kept, rays traced.
struct Shifted {
    contrib: vec3<f32>,
    jacobian: f32,
    rc_area_pdf: f32,
    rc_pdf: f32,
    rays: u32,
    failed: bool,
}

fn failed_shift(rays: u32) -> Shifted {
    return Shifted(vec3<f32>(0.0), 0.0, 0.0, 0.0, rays, true);
}

// Moves the path of reservoir `r` to the pixel whose primary surface is `s`.
fn shift_path(r: PathReservoir, s: GSurface) -> Shifted {
    if r.big_w <= 0.0 || s.pos.w < 0.5 {
        return failed_shift(0u);
    }
    let k = path_length(r);
    let rc = rc_index(r);
    let end = end_kind(r);
    let p_sky = nee_sky_share();
    var v = primary_vertex(s);
    var t = vec3<f32>(1.0);
    var rays = 0u;
    // Replay: the whole path (no reconnection vertex), or up to y_{r-1}.
    let replay_to = select(k - 1u, rc - 1u, rc > 0u);
    for (var j = 1u; j <= replay_to; j++) {
        let u = vertex_numbers(r.seed, j);
        if rc == 0u && j + 1u == k && end == END_NEE {
            // The path's last step: NEE at y_{k-1}, to the same light point.
            let ls = pick_nee_light(v.pos, v.geo, u.u_select, u.u_light, p_sky);
            if !ls.valid || ls.pdf <= 0.0 || dot(ls.wi, v.geo) <= 0.0 {
                return failed_shift(rays);
            }
            let e = bsdf_eval(v.material, v.normal, v.wo, ls.wi);
            if all(e.f <= vec3<f32>(0.0)) {
                return failed_shift(rays);
            }
            rays += 1u;
            if !unoccluded(light_shadow_ray(v.pos, v.geo, ls)) {
                return failed_shift(rays);
            }
            let w = select(power_heuristic(ls.pdf, e.pdf), 1.0, ls.is_delta);
            let c = t * e.f * dot(v.normal, ls.wi) * ls.radiance * (w / ls.pdf);
            return Shifted(c, 1.0, 0.0, 0.0, rays, false);
        }
        if j == replay_to && rc > 0u {
            break;
        }
        let bs = bsdf_sample(v.material, v.normal, v.wo, u.u_lobe, u.u_dir);
        if !bs.valid || dot(bs.wi, v.geo) <= 0.0 {
            return failed_shift(rays);
        }
        let hit = trace_closest(spawn_ray_origin(v.pos, v.geo, bs.wi), bs.wi, 0.0, 1e30);
        rays += 1u;
        t *= bs.weight;
        if rc == 0u && j + 1u == k {
            // The path's last step: a BSDF-sampled ray to an emitter or to the sky.
            if end == END_SKY {
                if hit.tri != NO_HIT {
                    return failed_shift(rays);
                }
                var w = 1.0;
                if !bs.is_delta && p_sky > 0.0 {
                    w = power_heuristic(bs.pdf, p_sky * sky_pdf(bs.wi));
                }
                return Shifted(t * sky_radiance(bs.wi) * w, 1.0, 0.0, 0.0, rays, false);
            }
            if hit.tri == NO_HIT {
                return failed_shift(rays);
            }
            let h = path_surface(hit.tri, hit.bary, bs.wi);
            if rough(h.material) && reconnectable(v, h.position) {
                return failed_shift(rays);
            }
            let le = triangle_emission(hit.tri, hit.bary, -bs.wi);
            var w = 1.0;
            if !bs.is_delta {
                w = power_heuristic(bs.pdf, (1.0 - p_sky) * triangle_light_pdf(hit.tri, bs.wi, hit.t, v.pos, v.geo));
            }
            return Shifted(t * le * w, 1.0, 0.0, 0.0, rays, false);
        }
        if hit.tri == NO_HIT {
            return failed_shift(rays);
        }
        let h = path_surface(hit.tri, hit.bary, bs.wi);
        // An offset path that could reconnect earlier than the base path is no base path's image.
        if rough(h.material) && reconnectable(v, h.position) {
            return failed_shift(rays);
        }
        v = hit_vertex(h, bs.wi);
    }
    if rc == 0u {
        return failed_shift(rays);
    }
    // Reconnection: y_{r-1} = v to x_r.
    let xr = rc_position(r);
    let d = xr - v.pos;
    let dist = length(d);
    if !reconnectable(v, xr) || dist <= 0.0 {
        return failed_shift(rays);
    }
    let wi = d / dist;
    if dot(wi, v.geo) <= 0.0 {
        return failed_shift(rays);
    }
    let hr = path_surface(r.rc_tri, vec2<f32>(r.rc_bary_u, r.rc_bary_v), wi);
    let front = ((r.info >> 18u) & 1u) != 0u;
    let emitter_end = end == END_EMISSION && k == rc;
    if hr.front_face != front || !rough(hr.material) {
        return failed_shift(rays);
    }
    let e = bsdf_eval(v.material, v.normal, v.wo, wi);
    let cos_r = dot(hr.geo_normal, -wi);
    if e.pdf <= 0.0 || all(e.f <= vec3<f32>(0.0)) || cos_r <= 0.0 {
        return failed_shift(rays);
    }
    // Visibility as the base path had it: the closest hit from y_{r-1} towards x_r is x_r's
    // triangle, at x_r. (A shadow ray's offsets and shortened end accept some segments the
    // closest-hit trace that found x_r would not, and the reverse: the two shifts between a
    // pair of pixels would then disagree.)
    rays += 1u;
    let seen = trace_closest(spawn_ray_origin(v.pos, v.geo, wi), wi, 0.0, 1e30);
    if seen.tri != r.rc_tri || abs(seen.t - dist) > 1e-3 * dist + 1e-3 {
        return failed_shift(rays);
    }
    t *= e.f * max(dot(v.normal, wi), 0.0) / e.pdf;
    let area_pdf = e.pdf * cos_r / (dist * dist);
    var out = Shifted(vec3<f32>(0.0), area_pdf / r.rc_area_pdf, area_pdf, 0.0, rays, false);
    if emitter_end {
        // x_r is the light: its emission towards y_{r-1}, weighted against NEE from there.
        let le = triangle_emission(r.rc_tri, vec2<f32>(r.rc_bary_u, r.rc_bary_v), -wi);
        let p_light = r.suffix.w * dist * dist / cos_r;
        out.contrib = t * le * power_heuristic(e.pdf, p_light);
        return out;
    }
    let wr = r.rc_dir.xyz;
    if dot(wr, hr.geo_normal) <= 0.0 {
        return failed_shift(rays);
    }
    let er = bsdf_eval(hr.material, hr.normal, -wi, wr);
    let cos_in = max(dot(hr.normal, wr), 0.0);
    if end == END_NEE && k == rc + 1u {
        // x_r's step is NEE: the light point stays, only its weight against BSDF sampling moves.
        let delta = ((r.info >> 19u) & 1u) != 0u;
        let p_light = r.suffix.w;
        let w = select(power_heuristic(p_light, er.pdf), 1.0, delta);
        out.contrib = t * er.f * cos_in * r.suffix.xyz * (w / p_light);
        return out;
    }
    if er.pdf <= 0.0 || r.rc_dir.w <= 0.0 {
        return failed_shift(rays);
    }
    t *= er.f * cos_in / er.pdf;
    out.jacobian *= er.pdf / r.rc_dir.w;
    out.rc_pdf = er.pdf;
    var w = 1.0;
    if k == rc + 1u && r.suffix.w > 0.0 {
        // x_{r+1} ends the path (emitter or sky): its MIS weight uses x_r's new BSDF pdf.
        w = power_heuristic(er.pdf, r.suffix.w);
    }
    out.contrib = t * r.suffix.xyz * w;
    return out;
}

// A shifted sample as the receiving pixel stores it: the same vertices and suffix, the offset
// path's contribution and pdfs.
fn adopt(r: PathReservoir, sh: Shifted) -> PathReservoir {
    var o = r;
    o.contrib = vec4<f32>(sh.contrib, luminance(sh.contrib));
    if rc_index(r) > 0u {
        o.rc_area_pdf = sh.rc_area_pdf;
        o.rc_dir.w = sh.rc_pdf;
    }
    return o;
}

// Streaming RIS: candidate `c` with resampling weight w replaces the selection with
// probability w / w_sum.
struct Stream {
    chosen: PathReservoir,
    w_sum: f32,
    jacobian: f32,
}

fn stream_add(st: ptr<function, Stream>, c: PathReservoir, w: f32, jacobian: f32, u: f32) {
    if !(w > 0.0) {
        return;
    }
    (*st).w_sum += w;
    if u * (*st).w_sum < w {
        (*st).chosen = c;
        (*st).jacobian = jacobian;
    }
}

// The reservoir a stream ends in: W = w_sum / target of the chosen sample at this pixel.
fn stream_result(st: Stream, m: f32) -> PathReservoir {
    var o = st.chosen;
    o.m = m;
    o.big_w = 0.0;
    if o.contrib.w > 0.0 && st.w_sum > 0.0 {
        o.big_w = st.w_sum / o.contrib.w;
    }
    return o;
}

fn empty_stream() -> Stream {
    return Stream(empty_path_reservoir(), 0.0, 1.0);
}

// Pairwise MIS (GRIS section 7.4; Bitterli's thesis), with confidence weights. The canonical
// sample's pixel c (confidence m_c) and n neighbours i (m_i) form n pairs; pair i holds the
// share (m_i + m_c / n) / (m_c + sum m_j) and splits it by the balance heuristic between
// neighbour i's domain (weight m_i) and the canonical one (m_c / n). `own` is the target of the
// sample in the domain being weighted, `other` in the pair's other domain (each times the
// Jacobian into that domain).
fn pair_share(m_c: f32, m_i: f32, n: f32, m_total: f32) -> f32 {
    return (m_i + m_c / n) / m_total;
}

fn pair_balance(weight_own: f32, own: f32, weight_other: f32, other: f32) -> f32 {
    let a = weight_own * own;
    let b = weight_other * other;
    if !(a > 0.0) {
        return 0.0;
    }
    // 1 / (1 + b / a): stays finite when a target over a tiny Jacobian overflows to infinity.
    return 1.0 / (1.0 + b / a);
}

fn write_debug(idx: u32, r: PathReservoir, failure_rate: f32, jacobian: f32) {
    if params.debug == 0u {
        return;
    }
    let rc = rc_index(r);
    var kind = 0.0;
    if rc == 2u {
        kind = 1.0;
    } else if rc > 2u {
        kind = 2.0;
    }
    var log_j = 0.0;
    if jacobian > 0.0 {
        log_j = abs(log2(jacobian)) * 0.30103;
    }
    debug_out[idx] = vec4<f32>(f32(rc), kind, failure_rate, log_j);
    debug_out[params.pixels + idx] = vec4<f32>(f32(path_length(r)), r.m, r.big_w, r.contrib.w);
}
