// How a GI sample path ends in Lumen's world radiance cache (`gi_terminate = "lumen-world"`,
// src/parts/world_cache.rs), read as a Lumen screen-probe ray reads it: NEE of the lights at
// full weight (the cache holds the sky its probes saw, so NEE leaves the sky out); one
// BSDF-sampled direction traced to the cache's TMin, where a hit reads the surface cache's
// reflected light; past it the world probes around the ray's end, in its direction, marked
// read so that they are traced; where none is traced yet the ray goes on to its end (surface
// cache, or sky). Emitters the ray meets add nothing: NEE counted them.
#define_import_path gilab::world_cache_path_end

#import gilab::path_end
#import gilab::math::INV_PI
#import gilab::rng::{Rng, rand, rand_pair}
#import gilab::surface_point::HitSurface
#import gilab::brdf::bsdf_sample
#import gilab::ray::spawn_ray_origin
#import gilab::bvh::{trace_closest, NO_HIT}
#import gilab::surface::hit_surface
#import gilab::sky::sky_radiance
#import gilab::scene::{materials, tri_material, material_at}
#import gilab::surface_cache::cache_at_hit
#import gilab::world_cache::{world_lookup, world_tmin_at}
#import gilab::path_vertex::{PathEnd, next_event}

override fn gilab::path_end::end_path(surf: HitSurface, wo: vec3<f32>, tri: u32, t: f32, throughput: vec3<f32>, p_sky: f32, candidates: u32, rng: ptr<function, Rng>) -> PathEnd {
    let direct = next_event(surf, wo, rng, 0.0, false, candidates);
    var e = PathEnd(true, throughput * direct.radiance, vec3<f32>(0.0), direct.shadow_rays, 0u, 0u);
    let m = surf.material;
    let bs = bsdf_sample(m, surf.normal, wo, rand(rng), rand_pair(rng));
    if bs.valid && dot(bs.wi, surf.geo_normal) > 0.0 {
        let o = spawn_ray_origin(surf.position, surf.geo_normal, bs.wi);
        let reach = world_tmin_at(surf.position);
        var h = trace_closest(o, bs.wi, 0.0, reach);
        e.indirect_rays += 1u;
        var l = vec3<f32>(0.0);
        if h.tri == NO_HIT {
            let w = world_lookup(o + bs.wi * reach, bs.wi, true);
            if w.weight > 0.0 {
                l = w.radiance;
            } else {
                h = trace_closest(o, bs.wi, reach, 1e30);
                e.indirect_rays += 1u;
                if h.tri == NO_HIT {
                    l = sky_radiance(bs.wi);
                }
            }
        }
        if h.tri != NO_HIT {
            let s = hit_surface(o, bs.wi, h);
            // The back of a single-sided surface (a ray that started inside geometry) gives no
            // light, as in Lumen's own traces.
            let double_sided = material_at(tri_material(h.tri)).emissive.w > 0.5;
            if s.front_face || double_sided {
                let c = cache_at_hit(h.tri, s.position, s.geo_normal, h.t);
                l = c.albedo * (c.direct + c.indirect) * INV_PI;
            }
        }
        e.indirect = throughput * bs.weight * l;
    }
    return e;
}
