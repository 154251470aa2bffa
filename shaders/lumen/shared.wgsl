// Lumen-style GI (shared/seeds/000, SIGGRAPH 2022): Lumen's own bindings of group 2, beside
// the scene-tracing part's (the distance field, `trace_scene`, the tracing uniform `params`:
// gilab::tracing, shaders/parts/tracing/shared.wgsl) and the surface cache's (bindings 1-3,
// 12-15, 19-23: gilab::surface_cache). Layout in src/techniques/lumen/mod.rs.
#define_import_path gilab::lumen

// Lumen's flags in the tracing uniform's `flags` (the tracing part's: FLAG_BVH 1, FLAG_SKY 2,
// FLAG_LIGHTS 16, FLAG_VOXEL_LIGHTING 128).
const FLAG_ACCUMULATE: u32 = 4u;
const FLAG_DEBUG: u32 = 8u;
const FLAG_DIRECT_RESTIR: u32 = 32u;
const FLAG_REFLECTIONS: u32 = 64u;

// Final gather per downsampled pixel: rgb irradiance, w: 1 valid.
@group(2) @binding(16) var<storage, read_write> gather_out: array<vec4<f32>>;
@group(2) @binding(17) var<storage, read_write> debug_out: array<vec4<f32>>;
// Per pixel, three planes: direct light from the direct-light part (`direct = "restir"`;
// src/parts/), then from the reflections part (src/parts/reflections.rs) the specular radiance
// and the directional albedo of a lobe too rough to trace (w: hit kind).
@group(2) @binding(18) var<storage, read_write> pixel_direct: array<vec4<f32>>;
