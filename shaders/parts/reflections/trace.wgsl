// Reflections, pass 1: one ray per traced pixel (one pixel of each downsample² block, jittered
// per frame) along the visible GGX lobe (brdf::specular_sample), through the BVH (the seed's
// hardware path), lit at the hit. What the ray carries is the light the family's own terms do
// not: emission only along the mirror lobe (next-event estimation at the pixel covers emitters
// through every other lobe), the sky on a miss (the families reach the sky by rays, not NEE),
// and at a hit the surface's reflected light: its direct light by one NEE sample plus its
// indirect light from the surface cache (`reflection_lighting = "hit"`), or the cache's whole
// radiance (`"cache"`, no shadow ray). With surfels (REFLECTION_SURFELS) a hit gets NEE plus the
// surfels' irradiance there; with neither, its direct light only: one bounce. A cached hit
// reflects its indirect light by its diffuse albedo plus its specular layer's average albedo
// (the specular share approximated as diffuse, as Lumen's card capture does).
// With `reflection_lighting = "screen"` (Callisto's lighting reuse, shared/seeds/002: "always
// raytrace, ... reuse lighting from previous frame, if available") a hit that last frame's
// camera saw at a pixel takes that pixel's output instead: whatever light the family computed
// there (its GI included), no shadow ray. Only hits rougher than the tracing bound (their
// light depends little on where it is seen from) and not emissive (the output holds the
// emission, which the pixel's own NEE already counts).
#import gilab::frame::frame
#import gilab::counters::{flush_counts, no_counts, RAY_SHADOW, RAY_REFLECTION}
#import gilab::math::INV_PI
#import gilab::rng::{rng_init, rand, rand_pair, STREAM_REFLECTION}
#import gilab::primary::{current_surface, surface_material, reproject, previous_surface}
#import gilab::accumulate::accum_mean
#import gilab::brdf::{diffuse_color, specular_sample, spec_fresnel, specular_albedo_average}
#import gilab::math::luminance
#import gilab::bvh::{trace_closest, NO_HIT}
#import gilab::surface::hit_surface
#import gilab::ray::spawn_ray_origin
#import gilab::lights::triangle_emission
#import gilab::sky::sky_radiance
#import gilab::nee::direct_light
#import gilab::reflections::{rparams, ray_samples, has_flag, FLAG_HIT_LIGHTING, FLAG_SCREEN_REUSE, KIND_NONE, KIND_WORLD, KIND_SKY, KIND_MIRROR, KIND_ROUGH}
#ifdef REFLECTION_CACHE
#import gilab::surface_cache::{cache_at_hit, cache_radiance}
#endif
#ifdef REFLECTION_SURFELS
#import gilab::surfels::{gather, gathered_irradiance, grid_center_for}
#endif

// Far enough to read as "at infinity" in the temporal pass's reprojection.
const SKY_DISTANCE: f32 = 1e6;

// Last frame's output where its camera saw the point `p` (geometric normal `geo_n`, facing the
// reflection ray): w = 1 when the pixel it reprojects to held the same surface (within 3% of
// its distance, normals agreeing) and had a sample; w = 0 otherwise.
fn screen_lighting(p: vec3<f32>, geo_n: vec3<f32>) -> vec4<f32> {
    let prev = reproject(p);
    if prev < 0 {
        return vec4<f32>(0.0);
    }
    let ps = previous_surface(u32(prev));
    let out = accum_mean[u32(prev)];
    let same = ps.pos.w > 0.5 && distance(ps.pos.xyz, p) < 0.03 * ps.wo_dist.w && dot(ps.geo_specular.xyz, geo_n) > 0.9;
    if !same || out.w <= 0.0 {
        return vec4<f32>(0.0);
    }
    return vec4<f32>(out.xyz, 1.0);
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    var counts = no_counts();
    if gid.x < rparams.trace_width && gid.y < rparams.trace_height {
        let t_idx = gid.y * rparams.trace_width + gid.x;
        var rng = rng_init(gid.xy, frame.sample_offset, STREAM_REFLECTION, frame.seed);
        // The block's traced pixel changes every frame, so every pixel is a ray source in turn.
        let ds = rparams.downsample;
        var jitter = vec2<u32>(0u);
        if ds > 1u {
            jitter = min(vec2<u32>(rand_pair(&rng) * f32(ds)), vec2<u32>(ds - 1u));
        }
        let p = min(gid.xy * ds + jitter, frame.size.xy - 1u);
        let idx = p.y * frame.size.x + p.x;
        var radiance = vec3<f32>(0.0);
        var dist = 0.0;
        var dir = vec3<f32>(0.0);
        var pdf = 0.0;
        var kind = KIND_NONE;
        let s = current_surface(idx);
        if s.pos.w > 0.5 {
            let m = surface_material(s);
            let n = s.normal_alpha.xyz;
            let wo = s.wo_dist.xyz;
            let has_specular = luminance(spec_fresnel(m, 1.0)) > 0.0;
            if sqrt(m.alpha) > rparams.max_roughness {
                kind = KIND_ROUGH;
            } else if has_specular {
                let ss = specular_sample(m, n, wo, rand(&rng), rand_pair(&rng));
                if ss.valid && dot(ss.wi, s.geo_specular.xyz) > 0.0 {
                    dir = ss.wi;
                    pdf = ss.pdf;
                    let origin = spawn_ray_origin(s.pos.xyz, s.geo_specular.xyz, dir);
                    let hit = trace_closest(origin, dir, 0.0, 1e30);
                    counts[RAY_REFLECTION] += 1u;
                    if hit.tri == NO_HIT {
                        radiance = sky_radiance(dir);
                        dist = SKY_DISTANCE;
                        kind = KIND_SKY;
                    } else {
                        dist = hit.t;
                        kind = select(KIND_WORLD, KIND_MIRROR, ss.is_delta);
                        let surf = hit_surface(origin, dir, hit);
                        if ss.is_delta {
                            radiance += triangle_emission(hit.tri, hit.bary, -dir);
                        }
                        var lit_by_cache = false;
                        var lit_by_screen = false;
                        if has_flag(FLAG_SCREEN_REUSE) && sqrt(surf.material.alpha) > rparams.max_roughness && !any(triangle_emission(hit.tri, hit.bary, -dir) > vec3<f32>(0.0)) {
                            let sl = screen_lighting(surf.position, surf.geo_normal);
                            if sl.w > 0.0 {
                                radiance += sl.xyz;
                                lit_by_screen = true;
                            }
                        }
                        if !lit_by_screen {
#ifdef REFLECTION_CACHE
                        let c = cache_at_hit(hit.tri, surf.position, surf.geo_normal, hit.t);
                        if c.weight > 1e-4 {
                            if has_flag(FLAG_HIT_LIGHTING) {
                                let albedo = diffuse_color(surf.material, max(dot(surf.normal, -dir), 0.0)) + specular_albedo_average(surf.material);
                                radiance += albedo * c.indirect * INV_PI;
                            } else {
                                radiance += cache_radiance(c) - c.emissive;
                                lit_by_cache = true;
                            }
                        }
#endif
#ifdef REFLECTION_SURFELS
                        // The surfels' irradiance at the hit, as surfels shade any ray's hit.
                        let g = gather(surf.position, surf.normal, grid_center_for(frame.camera_pos.xyz), false);
                        let albedo = diffuse_color(surf.material, max(dot(surf.normal, -dir), 0.0)) + specular_albedo_average(surf.material);
                        radiance += albedo * gathered_irradiance(g) * INV_PI;
#endif
                        if !lit_by_cache {
                            let d = direct_light(surf.position, surf.geo_normal, surf.normal, surf.material, -dir, rand(&rng), rand_pair(&rng));
                            radiance += d.radiance;
                            counts[RAY_SHADOW] += d.shadow_rays;
                        }
                        }
                    }
                }
            }
        }
        let base = 3u * t_idx;
        ray_samples[base] = vec4<f32>(radiance, dist);
        ray_samples[base + 1u] = vec4<f32>(dir, pdf);
        ray_samples[base + 2u] = vec4<f32>(f32(idx), kind, 0.0, 0.0);
    }
    flush_counts(local_index, counts);
}
