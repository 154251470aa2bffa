// Callisto-style ray-traced shadows (module gilab::callisto), after "The Rendering of The
// Callisto Protocol" (SIGGRAPH 2023; shared/seeds/002): tiled light culling, variable-rate
// shadow rays per light and 2x2 quad with bilateral reconstruction, and a temporally accumulated
// shadow mask. Group 3 holds the technique's own state (group 2 is ReSTIR's, for the optional
// GI sample, or an empty group). Layouts must match src/techniques/callisto_shadows/.
#define_import_path gilab::callisto

#import gilab::frame::frame
#import gilab::math::luminance
#import gilab::scene::{light_pool, Light, tri_geom, materials, tri_material, LIGHT_TRIANGLE, LIGHT_POINT, LIGHT_SPOT, LIGHT_DIRECTIONAL, light_at, material_at}

struct CallistoParams {
    tiles_x: u32,
    tiles_y: u32,
    // Light slots per tile list.
    max_lights: u32,
    // 0 variable, 1 full, 2 half, 3 quarter (forced everywhere).
    rate_mode: u32,
    // Irradiance (luminance, W/m^2) below which a local light's influence ends: its range is
    // sqrt(intensity / cutoff). 0 = infinite range.
    range_cutoff: f32,
    cone_culling: u32,
    // Perceptually weighted shadow variance above which a quad gets half / full rate.
    half_threshold: f32,
    full_threshold: f32,
    // Importance weight min(1, (tile luminance of the light / mean scene luminance) / perceptual);
    // 0 = no weighting.
    perceptual: f32,
    // Relative depth difference inside a quad that makes it a border quad.
    border_depth: f32,
    // 1: temporal accumulation of the shadow mask (with the disocclusion blur).
    denoise: u32,
    max_history: f32,
    // Blur radius in pixels right after a disocclusion; halves each frame since.
    blur_radius: u32,
    accumulate: u32,
    gi: u32,
    pixels: u32,
    // Samples per pixel of the lights outside the tile's list, picked by power.
    tail_samples: u32,
    direct_restir: u32,
    // 1: the reflections part traces pixels whose perceptual roughness is at most
    // reflection_max_roughness, and resolve adds its specular light (binding 8).
    reflections: u32,
    reflection_max_roughness: f32,
    // The static/dynamic split (static_cache.wgsl): on, rays a cell takes, cell edge in pixel
    // footprints, hash slots (a power of two).
    shadow_cache: u32,
    cache_samples: u32,
    cache_cell: f32,
    cache_slots: u32,
    // First motion record in bvh_nodes (TriAttr.pad.x - 1 - motion_base = 2 x entry).
    motion_base: u32,
    // First instance record in bvh_nodes (a top-level leaf's record - records_at = 2 x entry).
    records_at: u32,
    dynamic_count: u32,
    // Word offsets in shadow_cache: the light mask, the dynamic entries, the hash grid.
    light_mask_base: u32,
    dynamic_base: u32,
    hash_base: u32,
    pad_a: u32,
    pad_b: u32,
}

const TILE: u32 = 16u;
const TILE_PIXELS: u32 = 256u;
const QUADS_PER_TILE: u32 = 64u;

const RATE_NONE: u32 = 0u;
const RATE_QUARTER: u32 = 1u;
const RATE_HALF: u32 = 2u;
const RATE_FULL: u32 = 3u;

const NO_SLOT: u32 = 0xffffffffu;

@group(3) @binding(0) var<uniform> params: CallistoParams;
// Two segments (frame parity) of tiles x (1 + max_lights): the count, then the light indices,
// sorted ascending.
@group(3) @binding(1) var<storage, read_write> tile_lists: array<u32>;
// Two segments (frame parity) of tiles x max_lights x 4 words: 2 bits per quad (64 quads),
// the rate the next frame traces that light's quad at.
@group(3) @binding(2) var<storage, read_write> rates: array<u32>;
// [0]: mean scene luminance of direct light (last frame); [1 + tile]: that tile's sum.
@group(3) @binding(3) var<storage, read_write> stats: array<f32>;
// This frame's direct light: [pixel] from the punctual lights of the list, shadowed;
// [pixels + pixel] the same unshadowed (exact); [2 pixels + pixel] from the sampled lights
// (emissive triangles of the list, the tail), shadowed.
@group(3) @binding(4) var<storage, read_write> current: array<vec4<f32>>;
// Two segments (frame parity) of two vec4 per pixel: the punctual lights' shadowed (w: frames
// since disocclusion) and unshadowed direct light averaged over frames; their ratio is the
// shadow mask.
@group(3) @binding(5) var<storage, read_write> history: array<vec4<f32>>;
@group(3) @binding(6) var<storage, read_write> debug_out: array<vec4<f32>>;
// Direct light per pixel from the direct-light part (`direct = "restir"`; src/parts/).
@group(3) @binding(7) var<storage, read_write> pixel_direct: array<vec4<f32>>;
// The reflections part's output (`reflections = "traced"`): per pixel the traced specular
// radiance, then a second plane (rough albedo, hit kind).
@group(3) @binding(8) var<storage, read_write> pixel_specular: array<vec4<f32>>;
// The static/dynamic split (src/techniques/callisto_shadows/split.rs): a bit per top-level
// entry that moved, a bit per light that moved, 8 words per moving entry (world box, instance
// record), then the hash grid of static visibility (4 words a slot: static_cache.wgsl).
@group(3) @binding(9) var<storage, read_write> shadow_cache: array<atomic<u32>>;

fn parity() -> u32 {
    return frame.frame_index & 1u;
}

fn tile_count() -> u32 {
    return params.tiles_x * params.tiles_y;
}

// Word index of a tile's list (its count; the lights follow) in segment `segment`.
fn list_base(segment: u32, tile: u32) -> u32 {
    return (segment * tile_count() + tile) * (params.max_lights + 1u);
}

// First of the 4 rate words of a tile's slot.
fn rate_base(segment: u32, tile: u32, slot: u32) -> u32 {
    return ((segment * tile_count() + tile) * params.max_lights + slot) * 4u;
}

fn get_rate(segment: u32, tile: u32, slot: u32, quad: u32) -> u32 {
    let w = rates[rate_base(segment, tile, slot) + quad / 16u];
    return (w >> (2u * (quad % 16u))) & 3u;
}

// Lights in the list at `base` (the low 16 bits; the high 16 count lights a full list lost).
fn list_count(base: u32) -> u32 {
    return min(tile_lists[base] & 0xffffu, params.max_lights);
}

// Slot of `light` in a tile's sorted list of segment `segment`, or NO_SLOT.
fn find_slot(segment: u32, tile: u32, light: u32) -> u32 {
    let base = list_base(segment, tile);
    var lo = 0u;
    var hi = list_count(base);
    while lo < hi {
        let mid = (lo + hi) / 2u;
        let v = tile_lists[base + 1u + mid];
        if v == light {
            return mid;
        }
        if v < light {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return NO_SLOT;
}

// A light's culling shape: a sphere (centre, radius: range plus the emitter's own extent) and
// whether it is one-sided (emissive triangle: normal in `plane`); directional lights reach
// everything (radius < 0).
struct LightBounds {
    centre: vec3<f32>,
    // Luminance of the on-axis intensity (W/sr); 0 for directional lights.
    intensity: f32,
    radius: f32,
    extent: f32,
    one_sided: bool,
    normal: vec3<f32>,
    directional: bool,
    dir: vec3<f32>,
}

// The intensity luminance of a light (W/sr): point and spot lights their intensity, an emissive
// triangle radiance x area (its on-axis intensity). Its range is where the irradiance it can
// give falls to `range_cutoff`.
fn light_bounds(i: u32) -> LightBounds {
    let l = light_at(i);
    var b = LightBounds(vec3<f32>(0.0), 0.0, -1.0, 0.0, false, vec3<f32>(0.0), false, vec3<f32>(0.0));
    var intensity = 0.0;
    switch l.kind {
        case LIGHT_TRIANGLE: {
            let g = tri_geom[l.tri];
            let a = g.vertex_a.xyz;
            let pb = a + g.edge_b.xyz;
            let pc = a + g.edge_c.xyz;
            b.centre = (a + pb + pc) / 3.0;
            b.extent = sqrt(max(max(dot(a - b.centre, a - b.centre), dot(pb - b.centre, pb - b.centre)), dot(pc - b.centre, pc - b.centre)));
            let c = cross(g.edge_b.xyz, g.edge_c.xyz);
            let len = length(c);
            let m = material_at(tri_material(l.tri));
            intensity = luminance(m.emissive.xyz) * 0.5 * len;
            if len > 0.0 {
                b.normal = c / len;
                b.one_sided = m.emissive.w < 0.5;
            }
        }
        case LIGHT_POINT, LIGHT_SPOT: {
            b.centre = l.position.xyz;
            intensity = luminance(l.intensity.xyz);
        }
        case LIGHT_DIRECTIONAL: {
            b.directional = true;
            b.dir = -l.direction.xyz;
            return b;
        }
        default: {}
    }
    b.intensity = intensity;
    if params.range_cutoff > 0.0 {
        b.radius = sqrt(max(intensity, 0.0) / params.range_cutoff) + b.extent;
    }
    return b;
}

// Order-preserving float <-> u32 (atomic min/max of signed floats).
fn float_key(f: f32) -> u32 {
    let u = bitcast<u32>(f);
    return select(u | 0x80000000u, ~u, (u & 0x80000000u) != 0u);
}

fn key_float(k: u32) -> f32 {
    return bitcast<f32>(select(~k, k & 0x7fffffffu, (k & 0x80000000u) != 0u));
}
