// Sampling routines: cosine hemisphere, uniform triangle, GGX visible normals (Heitz 2018).
#define_import_path gilab::sampling

#import gilab::math::{PI, TWO_PI}

// Local frame (z = normal).
fn sample_cosine_hemisphere(u: vec2<f32>) -> vec3<f32> {
    let r = sqrt(u.x);
    let phi = TWO_PI * u.y;
    return vec3<f32>(r * cos(phi), r * sin(phi), sqrt(max(0.0, 1.0 - u.x)));
}

// Barycentrics (bary_b, bary_c) uniform over a triangle.
fn sample_triangle(u: vec2<f32>) -> vec2<f32> {
    let su = sqrt(u.x);
    return vec2<f32>(1.0 - su, u.y * su) ;
}

// GGX visible-normal sampling in the local frame; wo.z > 0. Returns the half vector.
fn sample_ggx_vndf(wo: vec3<f32>, alpha: f32, u: vec2<f32>) -> vec3<f32> {
    let vh = normalize(vec3<f32>(alpha * wo.x, alpha * wo.y, wo.z));
    let lensq = vh.x * vh.x + vh.y * vh.y;
    var tangent_a = vec3<f32>(1.0, 0.0, 0.0);
    if lensq > 1e-12 {
        tangent_a = vec3<f32>(-vh.y, vh.x, 0.0) / sqrt(lensq);
    }
    let tangent_b = cross(vh, tangent_a);
    let r = sqrt(u.x);
    let phi = TWO_PI * u.y;
    let disk_x = r * cos(phi);
    var disk_y = r * sin(phi);
    let s = 0.5 * (1.0 + vh.z);
    disk_y = (1.0 - s) * sqrt(max(0.0, 1.0 - disk_x * disk_x)) + s * disk_y;
    let nh = disk_x * tangent_a + disk_y * tangent_b + sqrt(max(0.0, 1.0 - disk_x * disk_x - disk_y * disk_y)) * vh;
    return normalize(vec3<f32>(alpha * nh.x, alpha * nh.y, max(1e-6, nh.z)));
}

fn power_heuristic(a: f32, b: f32) -> f32 {
    let alpha_sq = a * a;
    let bary_c = b * b;
    if alpha_sq + bary_c <= 0.0 {
        return 0.0;
    }
    return alpha_sq / (alpha_sq + bary_c);
}
