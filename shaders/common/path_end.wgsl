// Where a GI sample path ends in a cache (ReSTIR GI's `gi_terminate`): the shader side of the
// cache registry (`parts::gi_cache::CACHES`), one block per cache, chosen by the def its reader
// is composed with (`GiCache::reader`, which also sets GI_TERMINATE). What a path does at its
// last hit is each cache's own module, in the cache's folder; gilab::path calls `end_path`
// and knows no cache.
#define_import_path gilab::path_end

#import gilab::rng::Rng
#import gilab::surface_point::HitSurface
#import gilab::path_vertex::PathEnd
#ifdef GI_TERMINATE_CACHE
#import gilab::surface_cache_path_end::{end_path as end_in_surface_cache}
#endif
#ifdef GI_TERMINATE_WORLD
#import gilab::world_cache_path_end::{end_path as end_in_world_cache}
#endif
#ifdef GI_TERMINATE_SURFELS
#import gilab::surfels_path_end::{end_path as end_in_surfels}
#endif
#ifdef GI_TERMINATE_HASH
#import gilab::hash_cache_path_end::{end_path as end_in_hash_cache}
#endif

// The path's end at hit (`tri`, distance `t`) of surface `surf` seen from `wo`, with the
// path's `throughput`; `p_sky` and `candidates` as the path's own NEE takes them.
fn end_path(surf: HitSurface, wo: vec3<f32>, tri: u32, t: f32, throughput: vec3<f32>, p_sky: f32, candidates: u32, rng: ptr<function, Rng>) -> PathEnd {
#ifdef GI_TERMINATE_CACHE
    return end_in_surface_cache(surf, wo, tri, t, throughput, p_sky, candidates, rng);
#endif
#ifdef GI_TERMINATE_WORLD
    return end_in_world_cache(surf, wo, tri, t, throughput, p_sky, candidates, rng);
#endif
#ifdef GI_TERMINATE_SURFELS
    return end_in_surfels(surf, wo, tri, t, throughput, p_sky, candidates, rng);
#endif
#ifdef GI_TERMINATE_HASH
    return end_in_hash_cache(surf, wo, tri, t, throughput, p_sky, candidates, rng);
#endif
}
