// Where a GI sample path ends in a cache (ReSTIR GI's `gi_terminate`). gilab::path calls
// `end_path` at the hit where its path may end and knows no cache. The cache the reader is
// composed with (`GiCache::path_end`, a module in the cache's own folder) overrides it
// (naga_oil `override fn gilab::path_end::end_path`, added to the pipeline as an additional
// import by `ShaderLibrary::with_imports`), so this file lists no cache: a new one adds its
// module, and nothing here changes.
#define_import_path gilab::path_end

#import gilab::rng::Rng
#import gilab::surface_point::HitSurface
#import gilab::path_vertex::{PathEnd, path_not_ended}

// (naga_oil joins `virtual fn` to the line above it: that line must not be a comment.)
const NO_CACHE: u32 = 0u;
virtual fn end_path(surf: HitSurface, wo: vec3<f32>, tri: u32, t: f32, throughput: vec3<f32>, p_sky: f32, candidates: u32, rng: ptr<function, Rng>) -> PathEnd {
    // The path's end at hit (`tri`, distance `t`) of surface `surf` seen from `wo`, with the
    // path's `throughput`; `p_sky` and `candidates` as the path's own NEE takes them. Without
    // a cache's override the path goes on (it is traced to its end, unbiased).
    return path_not_ended(NO_CACHE);
}
