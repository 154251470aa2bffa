// How a GI sample path ends in the hash radiance cache (`gi_terminate = "hash-cache"`,
// src/parts/hash_cache.rs), by SHaRC's rule: where the segment that reached the hit is longer
// than the hit's cell and the cell holds samples, the hit's reflected light is the cell's
// (times the hit's albedo) and the path stops, no ray traced; otherwise it is traced on to its
// end, unbiased there.
#define_import_path gilab::hash_cache_path_end

#import gilab::path_end
#import gilab::rng::Rng
#import gilab::surface_point::HitSurface
#import gilab::hash_cache_outcome::lookup_outcome
#import gilab::path_vertex::{PathEnd, path_not_ended}
#import gilab::hash_cache::{hash_lookup, cell_size_at, cache_albedo, cacheable}

override fn gilab::path_end::end_path(surf: HitSurface, wo: vec3<f32>, tri: u32, t: f32, throughput: vec3<f32>, p_sky: f32, candidates: u32, rng: ptr<function, Rng>) -> PathEnd {
    if t <= cell_size_at(surf.position) || !cacheable(surf.material) {
        return path_not_ended(0u);
    }
    let c = hash_lookup(surf.position, surf.geo_normal);
    if c.w <= 0.0 {
        return path_not_ended(lookup_outcome(surf.position, false));
    }
    let albedo = cache_albedo(surf.material, max(dot(surf.normal, wo), 0.0));
    return PathEnd(true, vec3<f32>(0.0), throughput * albedo * c.xyz, 0u, 0u, lookup_outcome(surf.position, true));
}
