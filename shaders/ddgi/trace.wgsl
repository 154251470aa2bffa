// DDGI probe rays (src/techniques/ddgi): one invocation per ray of every probe (x: ray, y and z:
// probe). A switched-off probe traces only its fixed rays. At a front-face hit of a blended ray:
// direct light by NEE (one light by power, one shadow ray) plus the hit's albedo x the probes'
// irradiance there (FLAG_MULTI_BOUNCE: last frame's maps, so each frame adds a bounce);
// emission is left out, as the pixels' own direct light counts it. A miss reads the sky; a
// back face (of a single-sided material) returns no light and -0.2 x its distance (the paper's back-face marker, which
// relocation and classification count and which keeps the distance maps short inside walls).
// With `probe_hits = "hash-cache"` (DDGI_HASH_CACHE) a hit whose cell holds samples reads the
// hash radiance cache instead (no shadow ray, no probe gather).
#import gilab::frame::frame
#import gilab::math::INV_PI
#import gilab::counters::{flush_counts, no_counts, RAY_PROBE, RAY_SHADOW}
#import gilab::rng::{rng_init, rand, rand_pair, STREAM_DDGI_PROBE}
#import gilab::bvh::{trace_closest, NO_HIT}
#import gilab::surface::hit_surface
#import gilab::scene::{materials, material_at}
#import gilab::brdf::{diffuse_color, specular_albedo_average}
#import gilab::ray::INFINITE_DISTANCE
#import gilab::nee::direct_light
#import gilab::sky::sky_radiance
#ifdef DDGI_HASH_CACHE
#import gilab::hash_cache::{hash_lookup, cell_size_at, cache_albedo, cacheable}
#import gilab::hash_cache_outcome::lookup_outcome
#import gilab::counters::count_cache_lookup
#endif
#import gilab::ddgi::{params, ray_results, probes_per_cascade, rays_per_probe, probe_position, probe_active, ray_direction, ddgi_gather, has_flag, FIXED_RAYS, MISS_DISTANCE, FLAG_MULTI_BOUNCE}

@compute @workgroup_size(32, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    var counts = no_counts();
    let ray = gid.x;
    let slot = gid.z * 1024u + gid.y;
    if ray < rays_per_probe() && slot < probes_per_cascade() * params.counts.w && (ray < FIXED_RAYS || probe_active(slot)) {
        let dir = ray_direction(ray);
        let origin = probe_position(slot);
        let hit = trace_closest(origin, dir, 0.0, INFINITE_DISTANCE);
        counts[RAY_PROBE] += 1u;
        var l = vec3<f32>(0.0);
        var t = MISS_DISTANCE;
        if hit.tri == NO_HIT {
            l = sky_radiance(dir);
        } else {
            let h = hit_surface(origin, dir, hit);
            // A double-sided material has no back face (glTF planes, leaves).
            if !h.front_face && material_at(h.material_index).emissive.w < 0.5 {
                t = -0.2 * hit.t;
            } else {
                t = hit.t;
                let wo = -dir;
                var cached = false;
#ifdef DDGI_HASH_CACHE
                // `probe_hits = "hash-cache"`: a segment longer than the hit's cell ends in the
                // cache, whose cell holds the light the surface reflects (direct and indirect)
                // over its albedo (SHaRC's query rule); elsewhere the probes' own hit lighting.
                if ray >= FIXED_RAYS && hit.t > cell_size_at(h.position) && cacheable(h.material) {
                    let c = hash_lookup(h.position, h.geo_normal);
                    count_cache_lookup(&counts, lookup_outcome(h.position, c.w > 0.0));
                    if c.w > 0.0 {
                        l = cache_albedo(h.material, max(dot(h.normal, wo), 0.0)) * c.xyz;
                        cached = true;
                    }
                }
#endif
                if ray >= FIXED_RAYS && !cached {
                    var rng = rng_init(vec2<u32>(slot, ray), frame.frame_index, STREAM_DDGI_PROBE, frame.seed);
                    let d = direct_light(h.position, h.geo_normal, h.normal, h.material, wo, rand(&rng), rand_pair(&rng));
                    counts[RAY_SHADOW] += d.shadow_rays;
                    l = d.radiance;
                    if has_flag(FLAG_MULTI_BOUNCE) {
                        let g = ddgi_gather(h.position, h.normal, wo);
                        // The specular layer's energy reflected diffusely, as the other caches do.
                        let albedo = diffuse_color(h.material, max(dot(h.normal, wo), 0.0)) + specular_albedo_average(h.material);
                        l += albedo * g.irradiance * INV_PI;
                    }
                }
            }
        }
        ray_results[slot * rays_per_probe() + ray] = vec4<f32>(l, t);
    }
    flush_counts(local_index, counts);
}
