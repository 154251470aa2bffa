// Surfel rays (one invocation per ray, indirect dispatch). Direction: cosine-weighted, or once
// the surfel's guiding map is populated, from the map with probability GUIDE_MIX (texel by the
// map's CDF, uniform within the texel); the estimate divides by the true mixed pdf, so it stays
// unbiased per surfel. At the hit: direct light by NEE with a shadow ray (the light by power,
// or from the world ReGIR clipmap: `cache_direct`, gilab::cache_light), plus the irradiance
// the surfels there hold (multi-bounce through the cache); where no surfel covers the hit (off
// screen) the path continues instead (NEE + BSDF sampling + Russian roulette). Sky on a miss.
// Emission of the first hit is left out: the pixel's own direct light counts it.
// The paths of uncovered hits are queued in the workgroup and traced by its first invocations,
// one each (the ray, the random state and the result in workgroup memory): the paths are the
// pass's long work, and a wave of rays whose few uncovered hits continued in place ran at the
// longest one's pace with the other lanes idle. The same numbers whichever invocation traces.
// With `uncovered_hits = "hash-cache"` (SURFELS_HASH_CACHE) an uncovered hit whose segment is
// longer than its hash cell and whose cell holds samples reads the hash radiance cache instead
// (the light the surface reflects, direct and indirect: no shadow ray, no path), as DDGI's
// probe rays can; elsewhere as above.
#import gilab::frame::frame
#import gilab::math::{INV_PI, luminance, to_world}
#import gilab::counters::{flush_counts, no_counts, count_cache_lookup, RAY_SURFEL, RAY_SHADOW, RAY_INDIRECT}
#import gilab::rng::{Rng, rng_init, rand, rand_pair, STREAM_SURFEL_RAYS}
#import gilab::bvh::{trace_closest, NO_HIT}
#import gilab::surface::hit_surface
#import gilab::brdf::{bsdf_sample, diffuse_color, specular_albedo_average}
#import gilab::ray::{spawn_ray_origin, INFINITE_DISTANCE}
#import gilab::path::{trace_path, plain_path}
#import gilab::cache_light::cache_direct_light
#import gilab::surfels::{params, surfels, ray_offsets, ray_owner, ray_results, counters, has_flag, gather, gather_covers, gathered_irradiance, grid_center_for, gather_outcome, hemi_oct_encode, texel_of, FLAG_SKY, FLAG_CACHE_ONLY, FLAG_BINNING, ray_bin_order, DEPTH_RES}
#import gilab::surfel_rays::surfel_ray_direction
#import gilab::sky::sky_radiance
#ifdef SURFELS_HASH_CACHE
#import gilab::hash_cache::{hash_lookup, cell_size_at, cache_albedo, cacheable}
#endif

// The queued paths: by the invocation whose ray hit (its local index), the path's first ray and
// random state, then its radiance; the queue holds those invocations in queue order.
var<workgroup> wg_path_origin: array<vec3<f32>, 64>;
var<workgroup> wg_path_dir: array<vec3<f32>, 64>;
var<workgroup> wg_path_rng: array<u32, 64>;
var<workgroup> wg_path_radiance: array<vec3<f32>, 64>;
var<workgroup> wg_queue: array<u32, 64>;
var<workgroup> wg_queued: atomic<u32>;

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    var counts = no_counts();
    if local_index == 0u {
        atomicStore(&wg_queued, 0u);
    }
    workgroupBarrier();
    // What the ray's invocation keeps across the queue: its ray, the light so far, the queued
    // path's weight.
    let has_ray = gid.x < min(ray_offsets[params.max_surfels], params.ray_capacity);
    var i = 0u;
    var v = vec3<f32>(0.0, 0.0, 1.0);
    var pdf = 0.0;
    var guide_texel = 0u;
    var cos_theta = 0.0;
    var l = vec3<f32>(0.0);
    var t_hit = INFINITE_DISTANCE;
    var path_weight = vec3<f32>(0.0);
    var queued = false;
    if has_ray {
        // With ray binning, invocations run the rays in bin order; each ray keeps its index
        // (its surfel, its random numbers, its result slot), so the image does not change.
        i = select(gid.x, atomicLoad(&counters[ray_bin_order() + gid.x]), has_flag(FLAG_BINNING));
        let slot = ray_owner[i];
        let k = i - ray_offsets[slot];
        let s = surfels[slot];
        let n = s.normal_id.xyz;
        let p = s.pos_radius.xyz;
        var rng = rng_init(vec2<u32>(slot, k), frame.frame_index, STREAM_SURFEL_RAYS, frame.seed);

        // Direction and its pdf (solid angle): gilab::surfel_rays, as the binning pass drew it.
        let rd = surfel_ray_direction(slot, &rng);
        v = rd.v;
        pdf = rd.pdf;
        guide_texel = rd.guide_texel;
        cos_theta = v.z;

        if cos_theta > 1e-6 && pdf > 0.0 {
            let dir = to_world(v, n);
            let origin = spawn_ray_origin(p, n, dir);
            let hit = trace_closest(origin, dir, 0.0, INFINITE_DISTANCE);
            counts[RAY_SURFEL] += 1u;
            if hit.tri == NO_HIT {
                if has_flag(FLAG_SKY) {
                    l = sky_radiance(dir);
                }
            } else {
                t_hit = hit.t;
                let h = hit_surface(origin, dir, hit);
                let wo = -dir;
#ifdef SURFELS_HASH_CACHE
                // Where no surfel covers the hit, the hash cache first: a cached hit needs no
                // shadow ray and no path.
                let g = gather(h.position, h.normal, grid_center_for(frame.camera_pos.xyz), false);
                var cached = false;
                if !gather_covers(g) && hit.t > cell_size_at(h.position) && cacheable(h.material) {
                    let c = hash_lookup(h.position, h.geo_normal);
                    if c.w > 0.0 {
                        l = cache_albedo(h.material, max(dot(h.normal, wo), 0.0)) * c.xyz;
                        cached = true;
                    }
                }
                if !cached {
                    let d = cache_direct_light(h.position, h.geo_normal, h.normal, h.material, wo, &rng);
                    counts[RAY_SHADOW] += d.shadow_rays;
                    l = d.radiance;
                }
#else
                let d = cache_direct_light(h.position, h.geo_normal, h.normal, h.material, wo, &rng);
                counts[RAY_SHADOW] += d.shadow_rays;
                l = d.radiance;
                let g = gather(h.position, h.normal, grid_center_for(frame.camera_pos.xyz), false);
                let cached = false;
#endif
                // Counted for the surfels technique; as a cache (ReSTIR GI's paths end in it) the
                // engine counts its reader's lookups instead.
                if !has_flag(FLAG_CACHE_ONLY) {
                    count_cache_lookup(&counts, gather_outcome(g, h.position));
                }
                if gather_covers(g) {
                    // The specular layer's energy reflected diffusely, as Lumen's cache albedo.
                    let albedo = diffuse_color(h.material, max(dot(h.normal, wo), 0.0)) + specular_albedo_average(h.material);
                    l += albedo * gathered_irradiance(g) * INV_PI;
                } else if !cached {
                    let b = bsdf_sample(h.material, h.normal, wo, rand(&rng), rand_pair(&rng));
                    if b.valid && dot(b.wi, h.geo_normal) > 0.0 {
                        wg_path_origin[local_index] = spawn_ray_origin(h.position, h.geo_normal, b.wi);
                        wg_path_dir[local_index] = b.wi;
                        wg_path_rng[local_index] = rng.state;
                        wg_queue[atomicAdd(&wg_queued, 1u)] = local_index;
                        path_weight = b.weight;
                        queued = true;
                    }
                }
            }
        } else {
            v = vec3<f32>(0.0, 0.0, 1.0);
        }
    }
    workgroupBarrier();
    if local_index < atomicLoad(&wg_queued) {
        let owner = wg_queue[local_index];
        var path_rng = Rng(wg_path_rng[owner]);
        let path = trace_path(wg_path_origin[owner], wg_path_dir[owner], &path_rng, 0u, true, plain_path());
        counts[RAY_INDIRECT] += path.first_rays + path.indirect_rays;
        counts[RAY_SHADOW] += path.shadow_rays;
        wg_path_radiance[owner] = path.radiance;
    }
    workgroupBarrier();
    if has_ray {
        if queued {
            l += path_weight * wg_path_radiance[local_index];
        }
        let estimate = select(vec3<f32>(0.0), l * cos_theta / pdf, pdf > 0.0);
        let depth_texel = texel_of(hemi_oct_encode(v), DEPTH_RES);
        ray_results[2u * i] = vec4<f32>(estimate, t_hit);
        ray_results[2u * i + 1u] = vec4<f32>(luminance(l), f32(guide_texel), f32(depth_texel), 0.0);
    }
    flush_counts(local_index, counts);
}
