// Scene bindings (group 0) shared by every technique: BVH, triangles in BVH order, materials, textures, lights.
// Layouts must match src/scene/gpu_scene.rs (checked by a size test).
#define_import_path gilab::scene

#import gilab::brdf::Shading

// Depth-first order: a hit on an interior node continues at the next node, a miss or a
// finished leaf at `skip` (the node count at the end).
struct BvhNode {
    bounds_min: vec3<f32>,
    skip: u32,
    bounds_max: vec3<f32>,
    // Leaf: first triangle << 8 | count. Interior: 0.
    tris: u32,
}

// Triangle geometry for intersection: vertex_a and two edges.
struct TriGeom {
    vertex_a: vec4<f32>,
    edge_b: vec4<f32>,
    edge_c: vec4<f32>,
}

// Shading attributes, same order as TriGeom.
struct TriAttr {
    // xyz: vertex normal 0, w: probability of picking this triangle as a light (0 if not emissive).
    normal_a: vec4<f32>,
    // xyz: vertex normal 1, w: material index (bitcast).
    normal_b: vec4<f32>,
    // xyz: vertex normal 2, w: the triangle's index in the scene (bitcast; the arrays here are in
    // BVH order), the object id primary surfaces report.
    normal_c: vec4<f32>,
    uv_ab: vec4<f32>,
    uv_c: vec4<f32>,
}

struct Material {
    base_color: vec4<f32>,
    // rgb: emitted radiance (factor x strength), w: 1 if double-sided.
    emissive: vec4<f32>,
    // x: metallic, y: roughness, z: specular factor (0 = pure Lambert), w: unused.
    params: vec4<f32>,
    // x: first texel, y: width, z: height, w: 1 if a base-colour texture is bound.
    base_tex: vec4<u32>,
    // The BRDF model and Callisto's parameters.
    shading: Shading,
}

const LIGHT_TRIANGLE: u32 = 0u;
const LIGHT_POINT: u32 = 1u;
const LIGHT_SPOT: u32 = 2u;
const LIGHT_DIRECTIONAL: u32 = 3u;

struct Light {
    kind: u32,
    tri: u32,
    // Inclusive cumulative selection probability (power-proportional); the last light has 1.
    cdf: f32,
    pmf: f32,
    // The same within the light's class (local: triangles, point, spot; directional).
    class_cdf: f32,
    class_pmf: f32,
    pad_a: u32,
    pad_b: u32,
    position: vec4<f32>,
    // rgb: intensity (point/spot, W/sr) or irradiance (directional, W/m^2).
    intensity: vec4<f32>,
    // Direction the light points to (spot, directional).
    direction: vec4<f32>,
    // x: cos(outer cone), y: angle scale, z: angle offset (glTF spot falloff).
    spot: vec4<f32>,
}

// Local lights come first ([0, local_count)), directional lights after them.
struct LightPool {
    count: u32,
    emissive_count: u32,
    punctual_count: u32,
    local_count: u32,
    lights: array<Light>,
}

@group(0) @binding(0) var<storage, read> bvh_nodes: array<BvhNode>;
@group(0) @binding(1) var<storage, read> tri_geom: array<TriGeom>;
@group(0) @binding(2) var<storage, read> tri_attr: array<TriAttr>;
@group(0) @binding(3) var<storage, read> materials: array<Material>;
@group(0) @binding(4) var<storage, read> texels: array<u32>;
@group(0) @binding(5) var<storage, read> light_pool: LightPool;

// The triangle's index in the scene (before BVH ordering).
fn scene_triangle(tri: u32) -> u32 {
    return bitcast<u32>(tri_attr[tri].normal_c.w);
}

fn tri_material(tri: u32) -> u32 {
    return bitcast<u32>(tri_attr[tri].normal_b.w);
}

fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        return c / 12.92;
    }
    return pow((c + 0.055) / 1.055, 2.4);
}

fn texel(m: Material, x: i32, y: i32) -> vec4<f32> {
    let w = i32(m.base_tex.y);
    let h = i32(m.base_tex.z);
    let xx = ((x % w) + w) % w;
    let yy = ((y % h) + h) % h;
    let packed = texels[m.base_tex.x + u32(yy * w + xx)];
    let c = unpack4x8unorm(packed);
    return vec4<f32>(srgb_to_linear(c.x), srgb_to_linear(c.y), srgb_to_linear(c.z), c.w);
}

// Bilinear, repeat-wrapped base colour (texture x factor).
fn base_color(m: Material, uv: vec2<f32>) -> vec4<f32> {
    if m.base_tex.w == 0u {
        return m.base_color;
    }
    let p = uv * vec2<f32>(f32(m.base_tex.y), f32(m.base_tex.z)) - 0.5;
    let f = floor(p);
    let t = p - f;
    let x = i32(f.x);
    let y = i32(f.y);
    let a = mix(texel(m, x, y), texel(m, x + 1, y), t.x);
    let b = mix(texel(m, x, y + 1), texel(m, x + 1, y + 1), t.x);
    return m.base_color * mix(a, b, t.y);
}
