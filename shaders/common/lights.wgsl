// Light sampling for next-event estimation: one light picked from the power-proportional CDF
// over emissive triangles and punctual lights (or, in a pipeline with the LIGHT_TREE def, by the
// light tree for local lights and by power among directional ones: gilab::light_tree), then a
// point on it (area) or its position (delta).
#define_import_path gilab::lights

#import gilab::scene::{light_pool, Light, tri_attr, tri_geom, tri_light_pmf, tri_uvs, material_emission, materials, tri_material, LIGHT_TRIANGLE, LIGHT_POINT, LIGHT_SPOT, LIGHT_DIRECTIONAL, light_at, material_at, tri_attr_at}
#import gilab::sampling::sample_triangle
#import gilab::ray::{RaySegment, spawn_ray_to, spawn_ray_to_infinity, INFINITE_DISTANCE}
#import gilab::light_tree::{tree_sample, tree_pmf, tree_node, TREE_ONE_MINUS_EPSILON, TREE_MAX_DEPTH}
#import gilab::bvh::{intersect_tri, hits_aabb, safe_inv_dir}

struct LightSample {
    wi: vec3<f32>,
    dist: f32,
    // Radiance arriving along wi (before the shadow test), not divided by pdf.
    radiance: vec3<f32>,
    // Solid-angle pdf including the selection probability; for delta lights the selection probability.
    pdf: f32,
    // The same pdf in the light's own measure: selection probability / area for triangles
    // (area measure), the selection probability for punctual lights. Reservoirs reuse samples
    // across pixels in this measure, so no Jacobian is needed.
    area_pdf: f32,
    // Geometry factor to the point: |cos_l| / d^2 for triangles, 1 for punctual lights (whose
    // radiance already includes the 1/d^2 falloff).
    geom: f32,
    is_delta: bool,
    valid: bool,
    // Normal of the light's surface at the sampled point (triangles); 0 for punctual lights and
    // directions. Shadow rays offset their far end along it.
    normal: vec3<f32>,
}

fn no_light_sample() -> LightSample {
    return LightSample(vec3<f32>(0.0), 0.0, vec3<f32>(0.0), 0.0, 0.0, 0.0, false, false, vec3<f32>(0.0));
}

// The shadow ray from surface point p (geometric normal n) to a light sample taken at p.
fn light_shadow_ray(p: vec3<f32>, n: vec3<f32>, l: LightSample) -> RaySegment {
    if l.dist >= INFINITE_DISTANCE {
        return spawn_ray_to_infinity(p, n, l.wi);
    }
    return spawn_ray_to(p, n, p + l.wi * l.dist, l.normal);
}

// Inclusive CDF of light i: over the whole pool, or within its class (see LightPool).
fn light_cdf(i: u32, in_class: bool) -> f32 {
    let l = light_at(i);
    return select(l.cdf, l.class_cdf, in_class);
}

// Index of the light in [first, end) whose inclusive CDF first exceeds u (binary search).
fn search_cdf(u: f32, first: u32, end: u32, in_class: bool) -> u32 {
    var lo = first;
    var hi = end - 1u;
    while lo < hi {
        let mid = (lo + hi) / 2u;
        if light_cdf(mid, in_class) > u {
            hi = mid;
        } else {
            lo = mid + 1u;
        }
    }
    return lo;
}

// A light picked by power over the whole pool (path tracer NEE).
fn select_light(u: f32) -> u32 {
    return search_cdf(u, 0u, light_pool.count, false);
}

// A light picked by power within one class: local lights [0, local_count) or directional
// lights [local_count, count) (ReSTIR's per-class candidates).
fn select_light_in_class(u: f32, first: u32, end: u32) -> u32 {
    return search_cdf(u, first, end, true);
}

// Factor that turns a sample's pool pdf (LightSample.pdf / area_pdf) into its pdf within its class.
fn class_pdf_scale(light_index: u32) -> f32 {
    let l = light_at(light_index);
    return l.class_pmf / l.pmf;
}

// Emitted radiance of a triangle at barycentrics `bary` towards direction `to_viewer`
// (single-sided unless the material says so): the emissive factor x its texture, read at the
// finest level so that light sampling and hits see the same emission.
fn triangle_emission(tri: u32, bary: vec2<f32>, to_viewer: vec3<f32>) -> vec3<f32> {
    let m = material_at(tri_material(tri));
    let g = tri_geom[tri];
    let ng = cross(g.edge_b.xyz, g.edge_c.xyz);
    if m.emissive.w < 0.5 && dot(ng, to_viewer) <= 0.0 {
        return vec3<f32>(0.0);
    }
    return material_emission(m, tri_uvs(tri, bary));
}

// Probability of picking directional lights rather than local ones under the light tree: their
// share of the pool's power (0 without them, 1 without local lights).
fn directional_share() -> f32 {
    let local = light_pool.local_count;
    if local == light_pool.count {
        return 0.0;
    }
    if local == 0u {
        return 1.0;
    }
    return 1.0 - light_at(local - 1u).cdf;
}

struct LightChoice {
    light: u32,
    // Selection probability; 0: no light (light = count).
    pmf: f32,
}

// One light of the pool for point p (geometric normal n facing the side light is gathered on,
// or 0) from u in [0, 1): by power, or with LIGHT_TREE by the light tree (local lights) and by
// power (directional ones, with their share of the power).
fn choose_light(p: vec3<f32>, n: vec3<f32>, u: f32) -> LightChoice {
    if light_pool.count == 0u {
        return LightChoice(0u, 0.0);
    }
#ifdef LIGHT_TREE
    let p_dir = directional_share();
    if u < p_dir {
        let i = select_light_in_class(min(u / p_dir, TREE_ONE_MINUS_EPSILON), light_pool.local_count, light_pool.count);
        return LightChoice(i, p_dir * light_at(i).class_pmf);
    }
    let t = tree_sample(p, n, min((u - p_dir) / (1.0 - p_dir), TREE_ONE_MINUS_EPSILON));
    if t.pmf <= 0.0 {
        return LightChoice(light_pool.count, 0.0);
    }
    return LightChoice(t.light, (1.0 - p_dir) * t.pmf);
#else
    let i = select_light(u);
    return LightChoice(i, light_at(i).pmf);
#endif
}

// The probability that choose_light(p, n, .) picks light i.
fn light_choice_pmf(i: u32, p: vec3<f32>, n: vec3<f32>) -> f32 {
    if i >= light_pool.count {
        return 0.0;
    }
#ifdef LIGHT_TREE
    if i >= light_pool.local_count {
        return directional_share() * light_at(i).class_pmf;
    }
    return (1.0 - directional_share()) * tree_pmf(i, p, n);
#else
    return light_at(i).pmf;
#endif
}

// Solid-angle pdf with which sample_light_at(from_p, from_n, ...) would have produced a hit on
// emissive triangle `tri` at distance `dist` along direction `wi`: used for MIS when a
// BSDF-sampled ray hits a light.
fn triangle_light_pdf(tri: u32, wi: vec3<f32>, dist: f32, from_p: vec3<f32>, from_n: vec3<f32>) -> f32 {
#ifdef LIGHT_TREE
    let light = tri_attr_at(tri).pad.y;
    if light == 0u {
        return 0.0;
    }
    let pmf = light_choice_pmf(light - 1u, from_p, from_n);
#else
    let pmf = tri_light_pmf(tri);
#endif
    if pmf <= 0.0 {
        return 0.0;
    }
    let g = tri_geom[tri];
    let c = cross(g.edge_b.xyz, g.edge_c.xyz);
    let len = length(c);
    let area = 0.5 * len;
    let cos_l = abs(dot(c / len, wi));
    if area <= 0.0 || cos_l <= 0.0 {
        return 0.0;
    }
    return pmf * dist * dist / (cos_l * area);
}

// A light sample for point p: one light by choose_light, then a point on it.
fn sample_light_at(p: vec3<f32>, n: vec3<f32>, u_select: f32, u: vec2<f32>) -> LightSample {
    let c = choose_light(p, n, u_select);
    return eval_light_chosen(c.light, sample_triangle(u), p, c.pmf);
}

// sample_light_at without a normal (the light tree then leaves the receiving cosine out).
fn sample_light(p: vec3<f32>, u_select: f32, u: vec2<f32>) -> LightSample {
    return sample_light_at(p, vec3<f32>(0.0), u_select, u);
}

// A light sample fixed by (light index, barycentrics on a triangle light; unused otherwise),
// seen from the point p, with the pool's power pdf: what reservoirs store and re-evaluate at
// other pixels.
fn eval_light_point(light_index: u32, b: vec2<f32>, p: vec3<f32>) -> LightSample {
    if light_index >= light_pool.count {
        return no_light_sample();
    }
    return eval_light_chosen(light_index, b, p, light_at(light_index).pmf);
}

// eval_light_point for a light chosen with probability `pmf`.
fn eval_light_chosen(light_index: u32, b: vec2<f32>, p: vec3<f32>, pmf: f32) -> LightSample {
    var s = no_light_sample();
    if light_index >= light_pool.count || pmf <= 0.0 {
        return s;
    }
    let light = light_at(light_index);
    switch light.kind {
        case LIGHT_TRIANGLE: {
            let g = tri_geom[light.tri];
            let x = g.vertex_a.xyz + b.x * g.edge_b.xyz + b.y * g.edge_c.xyz;
            let c = cross(g.edge_b.xyz, g.edge_c.xyz);
            let len = length(c);
            let d = x - p;
            let dist_sq = dot(d, d);
            if len <= 0.0 || dist_sq <= 1e-12 {
                return s;
            }
            let dist = sqrt(dist_sq);
            s.wi = d / dist;
            s.dist = dist;
            s.radiance = triangle_emission(light.tri, b, -s.wi);
            let cos_l = abs(dot(c / len, s.wi));
            if cos_l <= 1e-8 {
                return s;
            }
            s.pdf = pmf * dist_sq / (cos_l * 0.5 * len);
            s.area_pdf = pmf / (0.5 * len);
            s.geom = cos_l / dist_sq;
            s.normal = c / len;
            s.valid = any(s.radiance > vec3<f32>(0.0));
        }
        case LIGHT_POINT, LIGHT_SPOT: {
            let d = light.position.xyz - p;
            let dist_sq = dot(d, d);
            if dist_sq <= 1e-12 {
                return s;
            }
            s.dist = sqrt(dist_sq);
            s.wi = d / s.dist;
            var falloff = 1.0;
            if light.kind == LIGHT_SPOT {
                let cd = dot(light.direction.xyz, -s.wi);
                let a = clamp(cd * light.spot.y + light.spot.z, 0.0, 1.0);
                falloff = a * a;
            }
            s.radiance = light.intensity.xyz * falloff / dist_sq;
            s.pdf = pmf;
            s.area_pdf = pmf;
            s.geom = 1.0;
            s.is_delta = true;
            s.valid = falloff > 0.0;
        }
        case LIGHT_DIRECTIONAL: {
            s.wi = -light.direction.xyz;
            s.dist = INFINITE_DISTANCE;
            s.radiance = light.intensity.xyz;
            s.pdf = pmf;
            s.area_pdf = pmf;
            s.geom = 1.0;
            s.is_delta = true;
            s.valid = true;
        }
        default: {}
    }
    return s;
}

// A light sample point independent of any shading point: where it is, how strongly it emits
// (radiance for triangles, intensity for point and spot lights, irradiance for directional
// ones) and its pdf in the light's own measure. ReGIR weighs lights for a whole grid cell by it.
struct LightEmitter {
    position: vec3<f32>,
    strength: vec3<f32>,
    area_pdf: f32,
    directional: bool,
}

fn light_emitter(light_index: u32, b: vec2<f32>) -> LightEmitter {
    var e = LightEmitter(vec3<f32>(0.0), vec3<f32>(0.0), 0.0, false);
    if light_index >= light_pool.count {
        return e;
    }
    let light = light_at(light_index);
    switch light.kind {
        case LIGHT_TRIANGLE: {
            let g = tri_geom[light.tri];
            e.position = g.vertex_a.xyz + b.x * g.edge_b.xyz + b.y * g.edge_c.xyz;
            let area = 0.5 * length(cross(g.edge_b.xyz, g.edge_c.xyz));
            e.strength = material_at(tri_material(light.tri)).emissive.xyz;
            if area > 0.0 {
                e.area_pdf = light.pmf / area;
            }
        }
        case LIGHT_POINT, LIGHT_SPOT: {
            e.position = light.position.xyz;
            e.strength = light.intensity.xyz;
            e.area_pdf = light.pmf;
        }
        case LIGHT_DIRECTIONAL: {
            e.strength = light.intensity.xyz;
            e.area_pdf = light.pmf;
            e.directional = true;
        }
        default: {}
    }
    return e;
}

// The nearest point along a ray where an emissive triangle of the light pool sends light back
// (light = the pool's count: none).
struct EmitterHit {
    light: u32,
    t: f32,
    bary: vec2<f32>,
}

// Entries of trace_emitter's stack: a descent pushes at most one node per level.
const EMITTER_STACK: u32 = TREE_MAX_DEPTH + 2u;

// The nearest emitting point of a triangle light along the ray, every other surface ignored: a
// traversal of the light tree's boxes, each widened by a thousandth of its size against
// rounding on flat boxes (seed 003's "light BVH for specular"). A hit on a face that sends no
// light towards the origin (the back of a one-sided emitter, a dark texel) is passed through.
// What it finds does not depend on occluders, so the pdf of finding a light point is the
// unshadowed one (ReSTIR's BSDF-sampled candidates rely on that); an emitting face in front of
// another emitter hides it.
fn trace_emitter(origin: vec3<f32>, dir: vec3<f32>) -> EmitterHit {
    var out = EmitterHit(light_pool.count, 1e30, vec2<f32>(0.0));
    if light_pool.local_count == 0u {
        return out;
    }
    let inv_dir = safe_inv_dir(dir);
    var stack: array<u32, EMITTER_STACK>;
    stack[0] = 0u;
    var top = 1u;
    while top > 0u {
        top -= 1u;
        let at = stack[top];
        let node = tree_node(at);
        let margin = vec3<f32>(1e-3 * max(max(node.hi.x - node.lo.x, node.hi.y - node.lo.y), max(node.hi.z - node.lo.z, 1e-3)));
        if !hits_aabb(origin, inv_dir, node.lo - margin, node.hi + margin, out.t) {
            continue;
        }
        if node.leaf {
            let light = light_at(node.index);
            if light.kind == LIGHT_TRIANGLE {
                let h = intersect_tri(origin, dir, light.tri);
                if h.x > 0.0 && h.x < out.t && any(triangle_emission(light.tri, h.yz, -dir) > vec3<f32>(0.0)) {
                    out = EmitterHit(node.index, h.x, h.yz);
                }
            }
            continue;
        }
        if top + 2u <= EMITTER_STACK {
            stack[top] = node.index;
            stack[top + 1u] = at + 1u;
            top += 2u;
        }
    }
    return out;
}
