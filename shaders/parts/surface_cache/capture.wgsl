// Card capture (the seed's "Card Capture"): each card's object is rasterised with the card's
// orthographic camera into the card's rectangle of the atlas (viewport = rectangle, the card's
// box depth range clips), writing albedo, normal, emission and depth. `vs_clear` first marks
// the whole rectangle invalid (depth 2), so a recapture leaves nothing stale behind.
#import gilab::scene::{materials, alpha_hole, material_emission, tri_uvs, tri_material, material_at}
#import gilab::surface_point::surface_at
#import gilab::brdf::{diffuse_color, specular_albedo_average}
#import gilab::card::{Card, card_uv, card_depth, card_dir, card_axis}

@group(1) @binding(0) var<storage, read> capture_cards: array<Card>;

struct VertexIn {
    @location(0) position: vec3<f32>,
}

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) @interpolate(flat) card: u32,
    @location(1) depth: f32,
    // The triangle (capture indices are vertex numbers: 3 x triangle + corner) and barycentrics
    // of its second and third vertex, to shade through gilab::surface_point like a ray hit.
    @location(2) @interpolate(flat) tri: u32,
    @location(3) bary: vec2<f32>,
}

struct CaptureOut {
    // rgb: diffuse albedo (specular's share of the energy taken out) plus the specular layer's
    // average albedo (its energy, reflected diffusely), a: 1.
    @location(0) albedo: vec4<f32>,
    // xyz: shading normal on the card's side, w: 1.
    @location(1) normal: vec4<f32>,
    @location(2) emissive: vec4<f32>,
    // Depth in [0, 1] across the card's box; 2 marks an invalid texel.
    @location(3) depth: f32,
}

@vertex
fn vs_main(v: VertexIn, @builtin(instance_index) card: u32, @builtin(vertex_index) vertex: u32) -> VertexOut {
    let c = capture_cards[card];
    let uv = card_uv(c, v.position);
    let depth = card_depth(c, v.position);
    var o: VertexOut;
    o.clip = vec4<f32>(uv.x * 2.0 - 1.0, 1.0 - uv.y * 2.0, depth, 1.0);
    o.card = card;
    o.depth = depth;
    o.tri = vertex / 3u;
    let k = vertex % 3u;
    o.bary = vec2<f32>(select(0.0, 1.0, k == 1u), select(0.0, 1.0, k == 2u));
    return o;
}

@fragment
fn fs_main(in: VertexOut, @builtin(front_facing) front_facing: bool) -> CaptureOut {
    let m = material_at(tri_material(in.tri));
    let double_sided = m.emissive.w > 0.5;
    // The card's projection keeps a surface facing the card counter-clockwise (card_uv).
    if !front_facing && !double_sided {
        discard;
    }
    if alpha_hole(in.tri, in.bary) {
        discard;
    }
    let c = capture_cards[in.card];
    let dir = card_dir(c);
    // Textures at the level of one card texel (its world size as the footprint).
    let size = c.box_max.xyz - c.box_min.xyz;
    let a = card_axis(c);
    let texel = max(size[(a + 1u) % 3u] / f32(c.rect.z), size[(a + 2u) % 3u] / f32(c.rect.w));
    let s = surface_at(in.tri, in.bary, -dir, texel);
    let n = s.normal;
    // The specular layer's energy joins the albedo (the seed's capture does the same): the cache
    // is diffuse, and a metal surface would otherwise pass no light on to the next bounce.
    let albedo = min(diffuse_color(s.material, 1.0) + specular_albedo_average(s.material), vec3<f32>(1.0));
    var o: CaptureOut;
    o.albedo = vec4<f32>(albedo, 1.0);
    o.normal = vec4<f32>(n, 1.0);
    o.emissive = vec4<f32>(material_emission(m, tri_uvs(in.tri, in.bary)), 1.0);
    o.depth = in.depth;
    return o;
}

@vertex
fn vs_clear(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    let xy = vec2<f32>(f32((i << 1u) & 2u), f32(i & 2u)) * 2.0 - 1.0;
    return vec4<f32>(xy, 1.0, 1.0);
}

@fragment
fn fs_clear() -> CaptureOut {
    var o: CaptureOut;
    o.albedo = vec4<f32>(0.0);
    o.normal = vec4<f32>(0.0);
    o.emissive = vec4<f32>(0.0);
    o.depth = 2.0;
    return o;
}
