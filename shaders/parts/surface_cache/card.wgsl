// Lumen surface cache cards (shared/seeds/000, "Cards"): an axis-aligned box per card; the card
// looks at its box from one of six sides with an orthographic camera. Pure functions, no
// bindings, so the capture raster shader and the compute passes project identically.
// Layout must match `GpuCard` in src/parts/surface_cache/cards.rs (the surface-cache part).
#define_import_path gilab::card

struct Card {
    // xyz: box minimum, w: side (bitcast u32): 0 +x, 1 -x, 2 +y, 3 -y, 4 +z, 5 -z; the card
    // sees surfaces whose normal points that way, from outside the box on that side.
    box_min: vec4<f32>,
    // xyz: box maximum, w: object id (bitcast u32).
    box_max: vec4<f32>,
    // Atlas rectangle: x, y, width, height in texels.
    rect: vec4<u32>,
    // x: first index of the object's triangles in the capture index buffer, y: index count,
    // z: physical page, w: unused.
    draw: vec4<u32>,
}

fn card_side(c: Card) -> u32 {
    return bitcast<u32>(c.box_min.w);
}

fn card_object(c: Card) -> u32 {
    return bitcast<u32>(c.box_max.w);
}

fn card_axis(c: Card) -> u32 {
    return card_side(c) / 2u;
}

// Unit vector of the side the card looks from (surfaces it captures face this way).
fn card_dir(c: Card) -> vec3<f32> {
    let s = card_side(c);
    var d = vec3<f32>(0.0);
    d[s / 2u] = select(1.0, -1.0, (s & 1u) == 1u);
    return d;
}

// (u, v) in [0, 1]^2 across the card: u along axis (a+1)%3, mirrored on negative sides so
// that a surface facing the card keeps its counter-clockwise winding on screen; v is the texture
// row direction (0 at the top row).
fn card_uv(c: Card, p: vec3<f32>) -> vec2<f32> {
    let a = card_axis(c);
    let ua = (a + 1u) % 3u;
    let va = (a + 2u) % 3u;
    let size = c.box_max.xyz - c.box_min.xyz;
    var u = (p[ua] - c.box_min[ua]) / max(size[ua], 1e-12);
    let v = (p[va] - c.box_min[va]) / max(size[va], 1e-12);
    if (card_side(c) & 1u) == 1u {
        u = 1.0 - u;
    }
    return vec2<f32>(u, 1.0 - v);
}

// Depth in [0, 1] from the card's own side of the box (0) to the far side (1).
fn card_depth(c: Card, p: vec3<f32>) -> f32 {
    let a = card_axis(c);
    let lo = c.box_min[a];
    let hi = c.box_max[a];
    let d = select((hi - p[a]) / max(hi - lo, 1e-12), (p[a] - lo) / max(hi - lo, 1e-12), (card_side(c) & 1u) == 1u);
    return d;
}

// Depth range of the card in world units.
fn card_depth_range(c: Card) -> f32 {
    let a = card_axis(c);
    return c.box_max[a] - c.box_min[a];
}

// The world point of card coordinates uv and depth (inverse of card_uv / card_depth).
fn card_point(c: Card, uv: vec2<f32>, depth: f32) -> vec3<f32> {
    let a = card_axis(c);
    let ua = (a + 1u) % 3u;
    let va = (a + 2u) % 3u;
    var u = uv.x;
    if (card_side(c) & 1u) == 1u {
        u = 1.0 - u;
    }
    var p = vec3<f32>(0.0);
    p[ua] = mix(c.box_min[ua], c.box_max[ua], u);
    p[va] = mix(c.box_min[va], c.box_max[va], 1.0 - uv.y);
    p[a] = select(mix(c.box_max[a], c.box_min[a], depth), mix(c.box_min[a], c.box_max[a], depth), (card_side(c) & 1u) == 1u);
    return p;
}

// World size of one texel of the card (the larger of its two directions).
fn card_texel_size(c: Card) -> f32 {
    let a = card_axis(c);
    let size = c.box_max.xyz - c.box_min.xyz;
    return max(size[(a + 1u) % 3u] / f32(c.rect.z), size[(a + 2u) % 3u] / f32(c.rect.w));
}
