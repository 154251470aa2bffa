// The surface cache (src/parts/surface_cache/): Lumen's cards and atlas, and their lookup at a
// point, as a part that any pass may import. Its bindings sit at bind group SURFACE_CACHE_GROUP,
// a shader def: Lumen's own passes use the default, 2 (their group, with these binding numbers);
// a pass of another technique sets the group it binds the part's lookup bind group at (ReSTIR
// GI's cache-terminated paths: 3). Layout must match `SurfaceCache::lookup_layout`.
#define_import_path gilab::surface_cache

#import gilab::math::INV_PI
#import gilab::scene::scene_triangle
#import gilab::card::{Card, card_dir, card_uv, card_depth, card_depth_range, card_texel_size, card_point}

const NO_CARD: u32 = 0xffffffffu;

@group(#{SURFACE_CACHE_GROUP}) @binding(1) var<storage, read> cards: array<Card>;
// Per object: (first card, card count).
@group(#{SURFACE_CACHE_GROUP}) @binding(2) var<storage, read> object_cards: array<vec2<u32>>;
// Per scene triangle: its object (connected component).
@group(#{SURFACE_CACHE_GROUP}) @binding(3) var<storage, read> tri_object: array<u32>;
// Atlas lighting, one vec4 per texel: direct irradiance (w: samples), indirect irradiance (w: frames).
@group(#{SURFACE_CACHE_GROUP}) @binding(12) var<storage, read_write> atlas_direct: array<vec4<f32>>;
@group(#{SURFACE_CACHE_GROUP}) @binding(13) var<storage, read_write> atlas_indirect: array<vec4<f32>>;
@group(#{SURFACE_CACHE_GROUP}) @binding(19) var atlas_albedo: texture_2d<f32>;
@group(#{SURFACE_CACHE_GROUP}) @binding(20) var atlas_normal: texture_2d<f32>;
@group(#{SURFACE_CACHE_GROUP}) @binding(21) var atlas_emissive: texture_2d<f32>;
@group(#{SURFACE_CACHE_GROUP}) @binding(22) var atlas_depth: texture_2d<f32>;
// The cards again as texels (rgba32uint, four a card, 4,096 a row): what the lookups read. On
// lavapipe a storage-buffer vec4 costs about six texel fetches (src/parts/surface_cache/mod.rs
// `CardTexels`).
@group(#{SURFACE_CACHE_GROUP}) @binding(23) var card_texels: texture_2d<u32>;

fn card_texel(k: u32) -> vec4<u32> {
    return textureLoad(card_texels, vec2<u32>(k & 4095u, k >> 12u), 0);
}

// cards[ci], read from its four texels.
fn card_at(ci: u32) -> Card {
    let k = 4u * ci;
    return Card(bitcast<vec4<f32>>(card_texel(k)), bitcast<vec4<f32>>(card_texel(k + 1u)), card_texel(k + 2u), card_texel(k + 3u));
}

struct CacheSample {
    albedo: vec3<f32>,
    direct: vec3<f32>,
    indirect: vec3<f32>,
    emissive: vec3<f32>,
    // Sum of the weights (0: no card covers the point; the caller loses that energy).
    weight: f32,
    // Card with the largest weight, or NO_CARD.
    best_card: u32,
}

fn atlas_index(t: vec2<u32>) -> u32 {
    return t.y * textureDimensions(atlas_depth).x + t.x;
}

// The cache at point p (normal n) of `object`: project onto the object's cards facing n, four
// texels each (manual bilinear), weighted by card-normal agreement and by how far the texel's
// depth is from the point's (occluded texels drop out); invalid texels are skipped.
fn sample_cache(p: vec3<f32>, n: vec3<f32>, object: u32, tolerance_in: f32) -> CacheSample {
    var out = CacheSample(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0), 0.0, NO_CARD);
    if object >= arrayLength(&object_cards) {
        return out;
    }
    let range = object_cards[object];
    var best = 0.0;
    for (var k = 0u; k < range.y; k++) {
        let ci = range.x + k;
        let c = card_at(ci);
        let facing = dot(n, card_dir(c));
        if facing <= 0.1 {
            continue;
        }
        let tolerance = max(tolerance_in, 2.0 * card_texel_size(c));
        if any(p < c.box_min.xyz - tolerance) || any(p > c.box_max.xyz + tolerance) {
            continue;
        }
        let uv = clamp(card_uv(c, p), vec2<f32>(0.0), vec2<f32>(1.0));
        let depth = card_depth(c, p);
        let range_w = card_depth_range(c);
        let f = uv * vec2<f32>(c.rect.zw) - 0.5;
        let i0 = vec2<i32>(floor(f));
        let t = f - floor(f);
        var card_weight = 0.0;
        for (var j = 0u; j < 4u; j++) {
            let o = vec2<i32>(i32(j & 1u), i32(j >> 1u));
            let local = clamp(i0 + o, vec2<i32>(0), vec2<i32>(c.rect.zw) - 1);
            let texel = vec2<u32>(local) + c.rect.xy;
            let td = textureLoad(atlas_depth, texel, 0).x;
            if td > 1.5 {
                continue;
            }
            let bw = select(1.0 - t, t, vec2<bool>(o == vec2<i32>(1)));
            let dw = clamp(1.0 - abs(td - depth) * range_w / tolerance, 0.0, 1.0);
            let w = bw.x * bw.y * dw * facing;
            if w <= 0.0 {
                continue;
            }
            let ai = atlas_index(texel);
            out.albedo += w * textureLoad(atlas_albedo, texel, 0).xyz;
            out.emissive += w * textureLoad(atlas_emissive, texel, 0).xyz;
            out.direct += w * atlas_direct[ai].xyz;
            out.indirect += w * atlas_indirect[ai].xyz;
            card_weight += w;
        }
        out.weight += card_weight;
        if card_weight > best {
            best = card_weight;
            out.best_card = ci;
        }
    }
    if out.weight > 1e-4 {
        let inv = 1.0 / out.weight;
        out.albedo *= inv;
        out.emissive *= inv;
        out.direct *= inv;
        out.indirect *= inv;
    }
    return out;
}

// Diffuse radiance leaving a cached surface: albedo x (direct + indirect irradiance) / pi + emission.
fn cache_radiance(s: CacheSample) -> vec3<f32> {
    return cache_reflected(s) + s.emissive;
}

// Its reflected part alone (what a traced ray takes back where emitters are the light pool's).
fn cache_reflected(s: CacheSample) -> vec3<f32> {
    return s.albedo * (s.direct + s.indirect) * INV_PI;
}

struct CacheTexel {
    valid: bool,
    position: vec3<f32>,
    normal: vec3<f32>,
}

// The surface a texel of card `ci` holds (invalid where the capture saw nothing).
fn cache_texel(ci: u32, texel: vec2<u32>) -> CacheTexel {
    let c = card_at(ci);
    let td = textureLoad(atlas_depth, texel, 0).x;
    if td > 1.5 {
        return CacheTexel(false, vec3<f32>(0.0), vec3<f32>(0.0));
    }
    let uv = (vec2<f32>(texel - c.rect.xy) + 0.5) / vec2<f32>(c.rect.zw);
    let n = textureLoad(atlas_normal, texel, 0).xyz;
    return CacheTexel(true, card_point(c, uv, td), normalize(n));
}


// The cache where a ray (BVH-order triangle `tri`, distance t) hit point p with normal n (facing
// the ray): a depth tolerance that grows with the distance, as Lumen's BVH tracing uses.
fn cache_at_hit(tri: u32, p: vec3<f32>, n: vec3<f32>, t: f32) -> CacheSample {
    return sample_cache(p, n, tri_object[scene_triangle(tri)], 1e-3 * max(t, 1.0));
}
