// Ray geometry in one place: every ray that leaves a surface, and every shadow ray between two
// points, is built here, so no pass chooses its own offsets or t_max. Shadow rays offset both
// ends (pbrt-v4's SpawnRayTo): aiming from an offset origin with a direction and length measured
// from the un-offset surface point makes the ray meet the light's own plane before t_max when the
// surface is near the light, and the light then shadows itself (the reference's lost indirect
// light, see README "Known issues").
#define_import_path gilab::ray

#import gilab::math::max_component
#import gilab::bvh::{trace_any_filtered, INSTANCES_ALL}

// Shadow rays stop this fraction short of their (offset) end point.
const SHADOW_EPSILON: f32 = 1e-4;
// t_max of a ray to an infinitely distant source (directional light, sky).
const INFINITE_DISTANCE: f32 = 1e30;

struct RaySegment {
    origin: vec3<f32>,
    dir: vec3<f32>,
    t_max: f32,
}

// A point moved off its surface (geometric normal n) to the side `towards` points to, by an
// amount that grows with the position's magnitude so large scenes do not self-intersect
// (Wächter & Binder, RTG1 ch. 6).
fn offset_point(p: vec3<f32>, n: vec3<f32>, towards: vec3<f32>) -> vec3<f32> {
    let side = select(-n, n, dot(n, towards) >= 0.0);
    return p + side * (1e-4 + 2e-6 * max_component(abs(p)));
}

// Origin of a ray that leaves the surface at p (geometric normal n) in direction dir.
fn spawn_ray_origin(p: vec3<f32>, n: vec3<f32>, dir: vec3<f32>) -> vec3<f32> {
    return offset_point(p, n, dir);
}

// The open segment from surface point p (normal n) to point q on a surface with normal n_q, both
// ends offset towards each other. n_q = 0 for a point on no surface (a point or spot light).
fn spawn_ray_to(p: vec3<f32>, n: vec3<f32>, q: vec3<f32>, n_q: vec3<f32>) -> RaySegment {
    let to_q = q - p;
    let start = offset_point(p, n, to_q);
    var end = q;
    if dot(n_q, n_q) > 0.0 {
        end = offset_point(q, n_q, -to_q);
    }
    let d = end - start;
    let len = length(d);
    if len <= 0.0 {
        return RaySegment(start, vec3<f32>(0.0, 0.0, 1.0), 0.0);
    }
    return RaySegment(start, d / len, len * (1.0 - SHADOW_EPSILON));
}

// A shadow ray from surface point p (normal n) to a source infinitely far along dir.
fn spawn_ray_to_infinity(p: vec3<f32>, n: vec3<f32>, dir: vec3<f32>) -> RaySegment {
    return RaySegment(offset_point(p, n, dir), dir, INFINITE_DISTANCE);
}

// True if anything among the instances `instances` selects (gilab::bvh::INSTANCES_*: all, only
// the static or only the moving ones) blocks the segment.
fn occluded_filtered(s: RaySegment, instances: u32) -> bool {
    return trace_any_filtered(s.origin, s.dir, 0.0, s.t_max, instances);
}

// True if nothing blocks the segment.
fn unoccluded(s: RaySegment) -> bool {
    return !occluded_filtered(s, INSTANCES_ALL);
}
