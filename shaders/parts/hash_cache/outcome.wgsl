// A hash-cache lookup's outcome for the ray counters (found or missed, split by whether the
// camera sees the point), shared by every reader: the end of a GI path, the `hash-cache`
// technique's paths and DDGI's probe rays.
#define_import_path gilab::hash_cache_outcome

#import gilab::primary::camera_sees
#import gilab::counters::{CACHE_ENTRY, CACHE_MISS, CACHE_UNSEEN}

fn lookup_outcome(p: vec3<f32>, found: bool) -> u32 {
    return select(CACHE_MISS, CACHE_ENTRY, found) + select(CACHE_UNSEEN, 0u, camera_sees(p));
}

