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

// Shading attributes, same order as TriGeom (96 bytes: see GpuTriAttr).
struct TriAttr {
    // Oct-encoded vertex normals (oct_decode_packed); valid when flags has TRI_HAS_NORMALS.
    normals: vec3<u32>,
    // Probability of picking this triangle as a light (0 if not emissive).
    light_pmf: f32,
    // Oct-encoded vertex tangents; valid when flags has TRI_HAS_TANGENTS.
    tangents: vec3<u32>,
    material: u32,
    uv0_ab: vec4<f32>,
    // xy: UV set 0 of vertex c, zw: UV set 1 of vertex a.
    uv0_c_uv1_a: vec4<f32>,
    uv1_bc: vec4<f32>,
    // The triangle's index in the scene (the arrays here are in BVH order), the object id
    // primary surfaces report.
    scene_tri: u32,
    flags: u32,
    // x: the triangle's motion record + 1 (a node index in bvh_nodes; 0: it does not move);
    // y: its light's index in the light pool + 1 (0: it does not emit).
    pad: vec2<u32>,
}

const TRI_HAS_NORMALS: u32 = 1u;
const TRI_HAS_TANGENTS: u32 = 2u;
// Bit 2 + k: vertex k's bitangent sign is negative.
const TRI_BITANGENT_NEG_SHIFT: u32 = 2u;

// A material's use of a texture: rows of the KHR_texture_transform matrix,
// uv' = (dot(transform_u.xy, uv) + transform_u.z, dot(transform_v.xy, uv) + transform_v.z); transform_u.w: texture index
// (bitcast, NO_TEXTURE when unused), transform_v.w: UV set (bit 0) and sampler (bits 1-5,
// Sampler::gpu_bits), bitcast.
struct TexSlot {
    transform_u: vec4<f32>,
    transform_v: vec4<f32>,
}

const NO_TEXTURE: u32 = 0xffffffffu;
const SLOT_BASE_COLOR: u32 = 0u;
const SLOT_METALLIC_ROUGHNESS: u32 = 1u;
const SLOT_NORMAL: u32 = 2u;
const SLOT_EMISSIVE: u32 = 3u;
const SLOT_OCCLUSION: u32 = 4u;

struct Material {
    base_color: vec4<f32>,
    // rgb: emitted radiance (factor x strength), w: 1 if double-sided.
    emissive: vec4<f32>,
    // x: metallic, y: roughness, z: specular factor (0 = pure Lambert), w: unused. The
    // dielectric F0 from the IOR travels in shading.dual.w.
    params: vec4<f32>,
    // x: normal scale, y: occlusion strength, z: alpha cutoff, w: 1 if alpha-tested (mask; blend traced as mask).
    extra: vec4<f32>,
    // Base colour, metallic-roughness, normal, emissive, occlusion.
    tex: array<TexSlot, 5>,
    // The BRDF model and Callisto's parameters.
    shading: Shading,
}

// Where a texture's mip chain lies in `texels`: `first` holds `levels` words, the offset of
// each level's texels; level k is (width >> k) x (height >> k), at least 1 x 1.
struct TextureInfo {
    first: u32,
    width: u32,
    height: u32,
    levels: u32,
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
    // Local lights: the bit trail to the light's leaf in the light tree (low, high word;
    // gilab::light_tree).
    trail: vec2<u32>,
    position: vec4<f32>,
    // rgb: intensity (point/spot, W/sr) or irradiance (directional, W/m^2).
    intensity: vec4<f32>,
    // Direction the light points to (spot, directional).
    direction: vec4<f32>,
    // x: cos(outer cone), y: angle scale, z: angle offset (glTF spot falloff).
    spot: vec4<f32>,
}

// Local lights come first ([0, local_count)), directional lights after them; the light tree's
// nodes follow the lights in records of the same size (gilab::light_tree::tree_node).
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
// The scene's data words: [0] the texture table's start; [1..] the environment map
// (gilab::sky, ENV_OFFSET); then the texture table (4 words per texture, see texture_info);
// then every texture's level-offset header and RGBA8 texels. One binding for all of it keeps
// the techniques under lavapipe's 32 storage buffers per stage.
@group(0) @binding(4) var<storage, read> texels: array<u32>;
@group(0) @binding(5) var<storage, read> light_pool: LightPool;
// The BVH nodes, triangle geometry and attributes, materials and light pool again, as texels
// (rgba32uint, the same words' bits): what the shaders read through bvh_node, tri_geom_at,
// tri_attr_at, material_at and light_at. On lavapipe a storage-buffer load at an index that
// differs across lanes runs a scalar loop over the lanes, about 6x slower than a texel fetch,
// and a BVH walk or a hit's shading is mostly such loads (src/scene/gpu_scene.rs
// `SceneTexels`). The buffers stay for their lengths and the few uniform reads.
@group(0) @binding(6) var bvh_texels: texture_2d<u32>;
@group(0) @binding(7) var geom_texels: texture_2d<u32>;
@group(0) @binding(8) var attr_texels: texture_2d<u32>;
@group(0) @binding(9) var material_texels: texture_2d<u32>;
@group(0) @binding(10) var light_texels: texture_2d<u32>;

// Texels per row of bvh_texels and geom_texels (must match SCENE_TEXELS_PER_ROW in
// src/scene/gpu_scene.rs): a power of two, so a texel index splits by mask and shift.
const SCENE_TEXEL_ROW_SHIFT: u32 = 12u;
const SCENE_TEXEL_ROW_MASK: u32 = 4095u;

fn scene_texel(t: texture_2d<u32>, k: u32) -> vec4<u32> {
    return textureLoad(t, vec2<u32>(k & SCENE_TEXEL_ROW_MASK, k >> SCENE_TEXEL_ROW_SHIFT), 0);
}

// bvh_nodes[i], read from its two texels.
fn bvh_node(i: u32) -> BvhNode {
    let a = scene_texel(bvh_texels, 2u * i);
    let b = scene_texel(bvh_texels, 2u * i + 1u);
    return BvhNode(bitcast<vec3<f32>>(a.xyz), a.w, bitcast<vec3<f32>>(b.xyz), b.w);
}

// tri_geom[tri], read from its three texels.
fn tri_geom_at(tri: u32) -> TriGeom {
    let k = 3u * tri;
    return TriGeom(
        bitcast<vec4<f32>>(scene_texel(geom_texels, k)),
        bitcast<vec4<f32>>(scene_texel(geom_texels, k + 1u)),
        bitcast<vec4<f32>>(scene_texel(geom_texels, k + 2u)),
    );
}

// tri_attr[tri], read from its six texels.
fn tri_attr_at(tri: u32) -> TriAttr {
    let k = 6u * tri;
    let a = scene_texel(attr_texels, k);
    let b = scene_texel(attr_texels, k + 1u);
    let f = scene_texel(attr_texels, k + 5u);
    return TriAttr(
        a.xyz, bitcast<f32>(a.w), b.xyz, b.w,
        bitcast<vec4<f32>>(scene_texel(attr_texels, k + 2u)),
        bitcast<vec4<f32>>(scene_texel(attr_texels, k + 3u)),
        bitcast<vec4<f32>>(scene_texel(attr_texels, k + 4u)),
        f.x, f.y, f.zw,
    );
}

fn material_word(k: u32) -> vec4<f32> {
    return bitcast<vec4<f32>>(scene_texel(material_texels, k));
}

fn tex_slot_at(k: u32) -> TexSlot {
    return TexSlot(material_word(k), material_word(k + 1u));
}

// materials[m], read from its 19 texels.
fn material_at(m: u32) -> Material {
    let k = 19u * m;
    return Material(
        material_word(k), material_word(k + 1u), material_word(k + 2u), material_word(k + 3u),
        array<TexSlot, 5>(tex_slot_at(k + 4u), tex_slot_at(k + 6u), tex_slot_at(k + 8u), tex_slot_at(k + 10u), tex_slot_at(k + 12u)),
        Shading(material_word(k + 14u), material_word(k + 15u), material_word(k + 16u), material_word(k + 17u), material_word(k + 18u)),
    );
}

// light_pool.lights[i] (a light, or a light tree node's record), read from its six texels
// after the pool's one-texel header.
fn light_at(i: u32) -> Light {
    let k = 1u + 6u * i;
    let a = scene_texel(light_texels, k);
    let b = scene_texel(light_texels, k + 1u);
    return Light(
        a.x, a.y, bitcast<f32>(a.z), bitcast<f32>(a.w),
        bitcast<f32>(b.x), bitcast<f32>(b.y), b.zw,
        bitcast<vec4<f32>>(scene_texel(light_texels, k + 2u)),
        bitcast<vec4<f32>>(scene_texel(light_texels, k + 3u)),
        bitcast<vec4<f32>>(scene_texel(light_texels, k + 4u)),
        bitcast<vec4<f32>>(scene_texel(light_texels, k + 5u)),
    );
}

fn texture_info(index: u32) -> TextureInfo {
    let k = texels[0] + 4u * index;
    return TextureInfo(texels[k], texels[k + 1u], texels[k + 2u], texels[k + 3u]);
}

// The triangle's index in the scene (before BVH ordering).
// Where point `p` of triangle `tri` (BVH order) was last frame: its instance's motion record
// (two BVH nodes past the tree, "this frame's world to last frame's", src/scene/gpu_scene.rs)
// when the triangle belongs to a moving instance (TriAttr.pad.x = record + 1), else p.
fn previous_position(tri: u32, p: vec3<f32>) -> vec3<f32> {
    let record = tri_attr_at(tri).pad.x;
    if record == 0u {
        return p;
    }
    let a = bvh_nodes[record - 1u];
    let b = bvh_nodes[record];
    return a.bounds_min * p.x + a.bounds_max * p.y + b.bounds_min * p.z + b.bounds_max;
}

// The inverse of `previous_position`: where a point of triangle `tri` recorded last frame is
// now (a reservoir's reconnection point on a moving object follows the object).
fn next_position(tri: u32, p: vec3<f32>) -> vec3<f32> {
    let record = tri_attr_at(tri).pad.x;
    if record == 0u {
        return p;
    }
    let a = bvh_nodes[record - 1u];
    let b = bvh_nodes[record];
    let c0 = a.bounds_min;
    let c1 = a.bounds_max;
    let c2 = b.bounds_min;
    let det = dot(c0, cross(c1, c2));
    if abs(det) < 1e-20 {
        return p;
    }
    // Rows of the inverse are the columns' cross products over the determinant.
    let inv = transpose(mat3x3<f32>(cross(c1, c2), cross(c2, c0), cross(c0, c1))) * (1.0 / det);
    return inv * (p - b.bounds_max);
}

// A normal of triangle `tri` recorded last frame, as it faces now: normals go with the inverse
// transpose of the point map, and the inverse of "now to last frame" transposed back is its
// own transpose.
fn next_normal(tri: u32, n: vec3<f32>) -> vec3<f32> {
    let record = tri_attr_at(tri).pad.x;
    if record == 0u {
        return n;
    }
    let a = bvh_nodes[record - 1u];
    let b = bvh_nodes[record];
    let m = mat3x3<f32>(a.bounds_min, a.bounds_max, b.bounds_min);
    let t = transpose(m) * n;
    let len = length(t);
    return select(n, t / len, len > 0.0);
}

fn scene_triangle(tri: u32) -> u32 {
    return tri_attr_at(tri).scene_tri;
}

fn tri_material(tri: u32) -> u32 {
    return tri_attr_at(tri).material;
}

// Probability that light sampling picks triangle `tri` (0 if it does not emit).
fn tri_light_pmf(tri: u32) -> f32 {
    return tri_attr_at(tri).light_pmf;
}

// Material index + 1 of a triangle rays may pass through (alpha-tested), else 0.
fn tri_alpha_tag(tri: u32) -> u32 {
    return bitcast<u32>(tri_geom[tri].vertex_a.w);
}

// Unit vector from two snorm16 octahedral coordinates (src/scene/gpu_scene.rs oct_encode_packed).
fn oct_decode_packed(packed: u32) -> vec3<f32> {
    let e = unpack2x16snorm(packed);
    var v = vec3<f32>(e.x, e.y, 1.0 - abs(e.x) - abs(e.y));
    if v.z < 0.0 {
        let s = select(vec2<f32>(-1.0), vec2<f32>(1.0), v.xy >= vec2<f32>(0.0));
        v = vec3<f32>((1.0 - abs(v.yx)) * s, v.z);
    }
    return normalize(v);
}

// UV sets 0 and 1 at barycentrics (b, c) of triangle `tri`: xy set 0, zw set 1.
fn tri_uvs(tri: u32, bary: vec2<f32>) -> vec4<f32> {
    let a = tri_attr_at(tri);
    let w = 1.0 - bary.x - bary.y;
    let uv0 = w * a.uv0_ab.xy + bary.x * a.uv0_ab.zw + bary.y * a.uv0_c_uv1_a.xy;
    let uv1 = w * a.uv0_c_uv1_a.zw + bary.x * a.uv1_bc.xy + bary.y * a.uv1_bc.zw;
    return vec4<f32>(uv0, uv1);
}

fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        return c / 12.92;
    }
    return pow((c + 0.055) / 1.055, 2.4);
}

fn slot_used(slot: TexSlot) -> bool {
    return bitcast<u32>(slot.transform_u.w) != NO_TEXTURE;
}

// The slot's texture coordinates: its UV set through its transform.
fn slot_uv(slot: TexSlot, uvs: vec4<f32>) -> vec2<f32> {
    let uv = select(uvs.xy, uvs.zw, (bitcast<u32>(slot.transform_v.w) & 1u) == 1u);
    return vec2<f32>(dot(slot.transform_u.xy, uv) + slot.transform_u.z, dot(slot.transform_v.xy, uv) + slot.transform_v.z);
}

// Wraps texel coordinate `x` into [0, n): mode 0 repeat, 1 clamp to edge, 2 mirrored repeat
// (glTF samplers). Selects rather than branches: this runs inside BVH traversal (the alpha
// test), where lavapipe has miscompiled nested control flow before.
fn wrap_texel(x: i32, n: i32, mode: u32) -> i32 {
    let repeat = ((x % n) + n) % n;
    let clamped = clamp(x, 0, n - 1);
    let p = ((x % (2 * n)) + 2 * n) % (2 * n);
    let mirrored = select(p, 2 * n - 1 - p, p >= n);
    return select(select(repeat, clamped, mode == 1u), mirrored, mode == 2u);
}

// One texel of mip level `level`, wrapped by `sampler` (Sampler::gpu_bits: wrap u in bits
// 0-1, wrap v in 2-3), decoded (sRGB colour channels when `srgb`).
fn fetch_texel(t: TextureInfo, level: u32, x: i32, y: i32, srgb: bool, sampler: u32) -> vec4<f32> {
    // No loop here: a loop nested in BVH traversal (the any-hit alpha test) was seen to
    // change lavapipe's results even where it never ran (a furnace lost 4% of its energy).
    let first = texels[t.first + level];
    let wi = i32(max(t.width >> level, 1u));
    let hi = i32(max(t.height >> level, 1u));
    let xx = wrap_texel(x, wi, sampler & 3u);
    let yy = wrap_texel(y, hi, (sampler >> 2u) & 3u);
    let c = unpack4x8unorm(texels[first + u32(yy * wi + xx)]);
    if srgb {
        return vec4<f32>(srgb_to_linear(c.x), srgb_to_linear(c.y), srgb_to_linear(c.z), c.w);
    }
    return c;
}

// Bilinear (or nearest: `sampler` bit 4) lookup in mip level `level`, wrapped as `sampler`
// says. No branch: the alpha test calls it from inside BVH traversal.
fn sample_level(t: TextureInfo, level: u32, uv: vec2<f32>, srgb: bool, sampler: u32) -> vec4<f32> {
    let size = vec2<f32>(f32(max(t.width >> level, 1u)), f32(max(t.height >> level, 1u)));
    let p = uv * size - 0.5;
    let f = floor(p);
    // Nearest: weights 0 or 1 pick the texel containing `uv` out of the same four.
    let s = select(p - f, step(vec2<f32>(0.5), p - f), (sampler & 16u) != 0u);
    let x = i32(f.x);
    let y = i32(f.y);
    let a = mix(fetch_texel(t, level, x, y, srgb, sampler), fetch_texel(t, level, x + 1, y, srgb, sampler), s.x);
    let b = mix(fetch_texel(t, level, x, y + 1, srgb, sampler), fetch_texel(t, level, x + 1, y + 1, srgb, sampler), s.x);
    return mix(a, b, s.y);
}

// Trilinear lookup at `lod` (log2 of texels per footprint at level 0; <= 0 reads level 0): the
// two levels around it, blended.
fn sample_texture(index: u32, uv: vec2<f32>, lod: f32, srgb: bool, sampler: u32) -> vec4<f32> {
    let t = texture_info(index);
    let last = max(t.levels, 1u) - 1u;
    let l = clamp(lod, 0.0, f32(last));
    let level = u32(floor(l));
    let blend = l - floor(l);
    let c = sample_level(t, level, uv, srgb, sampler);
    if blend <= 0.0 {
        return c;
    }
    return mix(c, sample_level(t, min(level + 1u, last), uv, srgb, sampler), blend);
}

// The sampler bits of a slot (Sampler::gpu_bits, above its UV set bit).
fn slot_sampler(slot: TexSlot) -> u32 {
    return bitcast<u32>(slot.transform_v.w) >> 1u;
}

// Texture of a material slot at a triangle point. `lod_base` is the ray-cone term
// log2(footprint / |cos|) + 0.5 log2(uv area / world area) of the slot's UV set (see
// gilab::surface); the texture's own size and the transform's scale are added here.
fn slot_sample(slot: TexSlot, uvs: vec4<f32>, lod_base: vec2<f32>, srgb: bool) -> vec4<f32> {
    let index = bitcast<u32>(slot.transform_u.w);
    let t = texture_info(index);
    let set1 = (bitcast<u32>(slot.transform_v.w) & 1u) == 1u;
    let det = abs(slot.transform_u.x * slot.transform_v.y - slot.transform_u.y * slot.transform_v.x);
    let lod = select(lod_base.x, lod_base.y, set1) + 0.5 * log2(max(f32(t.width * t.height) * det, 1e-20));
    return sample_texture(index, slot_uv(slot, uvs), lod, srgb, slot_sampler(slot));
}

// Emitted radiance of a material at a triangle point (both sides; the caller decides which side
// emits): the factor x the sRGB emissive texture at its finest level.
fn material_emission(m: Material, uvs: vec4<f32>) -> vec3<f32> {
    var le = m.emissive.xyz;
    if slot_used(m.tex[SLOT_EMISSIVE]) && any(le > vec3<f32>(0.0)) {
        le *= slot_sample(m.tex[SLOT_EMISSIVE], uvs, vec2<f32>(-100.0), true).xyz;
    }
    return le;
}

// Alpha of a material at a triangle point (base colour factor x texture, finest level):
// what the any-hit test and the G-buffer cutout compare with the cutoff.
fn material_alpha(m: Material, uvs: vec4<f32>) -> f32 {
    var a = m.base_color.w;
    let slot = m.tex[SLOT_BASE_COLOR];
    if slot_used(slot) {
        let t = texture_info(bitcast<u32>(slot.transform_u.w));
        a *= sample_level(t, 0u, slot_uv(slot, uvs), false, slot_sampler(slot)).w;
    }
    return a;
}

// True where an alpha-tested triangle has a hole at barycentrics `bary`.
fn alpha_hole(tri: u32, bary: vec2<f32>) -> bool {
    let tag = tri_alpha_tag(tri);
    if tag == 0u {
        return false;
    }
    let m = material_at(tag - 1u);
    return material_alpha(m, tri_uvs(tri, bary)) < m.extra.z;
}
