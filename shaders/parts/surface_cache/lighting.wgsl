// The surface cache's own passes (src/parts/surface_cache/): the tiles to relight (a header with
// this frame's share, then the tiles), the indirect-light probes on 4x4 texel tiles. They run at bind group 2, the group of the scene
// representation they trace (gilab::tracing: its uniform and distance field), to which the cache
// adds these bindings and its lookup's (shaders/parts/surface_cache/shared.wgsl). Layout must
// match `SurfaceCache::entries`.
#define_import_path gilab::surface_cache_lighting

struct CacheParams {
    atlas_size: u32,
    card_count: u32,
    direct_tile_first: u32,
    direct_tile_count: u32,
    direct_tiles_total: u32,
    probe_tile_first: u32,
    probe_tile_count: u32,
    probe_tiles_total: u32,
}

// A surface-cache probe on a 4x4 tile: a hemisphere of rays from one texel.
struct Probe {
    // xyz: position, w: 1 if valid.
    pos: vec4<f32>,
    // xyz: normal, w: mean hit distance.
    normal_dist: vec4<f32>,
    // rgb: irradiance, w: frame it was traced.
    irradiance: vec4<f32>,
}

struct CacheTiles {
    // This frame's share, written before the passes.
    params: CacheParams,
    // Direct-light 8x8 tiles then probe 4x4 tiles: (tile x | tile y << 16, card).
    tiles: array<vec2<u32>>,
}

@group(2) @binding(14) var<storage, read_write> probes: array<Probe>;
// In the tile list's buffer, not a uniform of its own: Lumen's passes bind group 2 too, and
// one more uniform there crashed lavapipe's screen-probe passes.
@group(2) @binding(15) var<storage, read> cache_tiles: CacheTiles;
