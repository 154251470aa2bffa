// The reflections part (src/parts/reflections.rs; issue 35, shared/seeds/000 "Reflections"):
// specular indirect light for any family. Rays follow the visible GGX lobe from pixels no rougher
// than `max_roughness` (at one pixel per `downsample`² block), are traced through the BVH and
// lit at the hit; a resolve pass reuses neighbours' rays weighted by the pixel's own lobe, then
// temporal accumulation (reprojected by the reflected hit's depth) and a bilateral filter.
// Rougher pixels get no ray: the family multiplies its own irradiance by the lobe's directional
// albedo (the `rough` plane of the output), the seed's reuse of the diffuse rays.
#define_import_path gilab::reflections

#import gilab::brdf::{Surface, spec_fresnel}
#import gilab::frame::frame

struct ReflectionParams {
    // Perceptual roughness (sqrt(alpha)) above which a pixel traces no ray.
    max_roughness: f32,
    downsample: u32,
    // FLAG_* below.
    flags: u32,
    // Neighbour samples the resolve pass reuses besides the pixel's own block.
    reuse: u32,
    // Radius of that reuse, in traced pixels.
    reuse_radius: f32,
    max_history: f32,
    trace_width: u32,
    trace_height: u32,
    // Where the output's two planes start in the family's buffer, in planes of pixels.
    output_plane: u32,
    // To the Rust struct's 48 bytes (src/parts/reflections.rs).
    pad_a: u32,
    pad_b: u32,
    pad_c: u32,
}

const FLAG_HIT_LIGHTING: u32 = 1u;
const FLAG_TEMPORAL: u32 = 2u;
const FLAG_FILTER: u32 = 4u;
const FLAG_DEBUG: u32 = 8u;
// Hits seen on screen last frame take that pixel's output (`reflection_lighting = "screen"`).
const FLAG_SCREEN_REUSE: u32 = 16u;

// Hit kinds (debug view, and which samples may be reused).
const KIND_NONE: f32 = 0.0;
const KIND_WORLD: f32 = 1.0;
const KIND_SKY: f32 = 2.0;
const KIND_MIRROR: f32 = 3.0;
const KIND_ROUGH: f32 = 4.0;

// Entries of the directional-albedo table per side (n.v and perceptual roughness).
const LUT_SIZE: u32 = 32u;

@group(2) @binding(0) var<uniform> rparams: ReflectionParams;
// Per traced pixel, 3 vec4: (radiance arriving along the ray, hit distance), (direction, its
// solid-angle pdf; 0 for the mirror lobe), (source pixel, hit kind, 0, 0).
@group(2) @binding(1) var<storage, read_write> ray_samples: array<vec4<f32>>;
// GGX directional albedo with Fresnel 1 (x) and its (1 - v.h)^5 moment (y), built on the CPU.
@group(2) @binding(2) var<storage, read> albedo_lut: array<vec2<f32>>;
// Per pixel, 2 planes: (resolved specular radiance, hit distance), (rough-pixel albedo, kind).
@group(2) @binding(3) var<storage, read_write> resolved: array<vec4<f32>>;
// Per pixel, 2 ping-pong frames x 2 planes: (accumulated rgb, history length), (luminance
// moments m1, m2, 0, 0).
@group(2) @binding(4) var<storage, read_write> history: array<vec4<f32>>;
// Per pixel: rays traced, hit kind, specular luminance, history length.
@group(2) @binding(5) var<storage, read_write> debug_out: array<vec4<f32>>;

fn has_flag(f: u32) -> bool {
    return (rparams.flags & f) != 0u;
}

// Directional albedo of the specular layer, F·G integrated over the hemisphere: Fresnel is
// linear in (1 - v.h)^5 (F = X + Y k), so the table's two moments give it for any F0.
fn specular_albedo(m: Surface, n_dot_v: f32) -> vec3<f32> {
    let x = clamp(n_dot_v, 0.0, 1.0) * f32(LUT_SIZE - 1u);
    let y = clamp(sqrt(m.alpha), 0.0, 1.0) * f32(LUT_SIZE - 1u);
    let i = vec2<u32>(min(vec2<f32>(x, y), vec2<f32>(f32(LUT_SIZE - 2u))));
    let t = vec2<f32>(x, y) - vec2<f32>(i);
    let a = mix(albedo_lut[i.y * LUT_SIZE + i.x], albedo_lut[i.y * LUT_SIZE + i.x + 1u], t.x);
    let b = mix(albedo_lut[(i.y + 1u) * LUT_SIZE + i.x], albedo_lut[(i.y + 1u) * LUT_SIZE + i.x + 1u], t.x);
    let ab = mix(a, b, t.y);
    let f_x = spec_fresnel(m, 1.0);
    let f_y = spec_fresnel(m, 0.0) - f_x;
    return f_x * ab.x + f_y * ab.y;
}

fn history_slot(frame_index: u32, plane: u32, pixel: u32) -> u32 {
    return ((frame_index & 1u) * 2u + plane) * frame.size.x * frame.size.y + pixel;
}
