// How a GI sample path ends in the ambient cache (`gi_terminate = "ambient"`,
// src/parts/ambient_cache.rs): at its last hit, NEE of the lights at full weight (the sky is
// the ambient term's, so NEE leaves it out) plus the constant irradiance E0 reflected by the
// diffuse albedo and the specular layer's average albedo. Every hit is covered.
#define_import_path gilab::ambient_cache_path_end

#import gilab::path_end
#import gilab::math::INV_PI
#import gilab::rng::Rng
#import gilab::surface_point::HitSurface
#import gilab::brdf::{diffuse_color, specular_albedo_average}
#import gilab::path_vertex::{PathEnd, next_event}

// E0 in rgb (w unused), written by the cache every frame.
@group(#{AMBIENT_CACHE_GROUP}) @binding(0) var<uniform> ambient_irradiance: vec4<f32>;

override fn gilab::path_end::end_path(surf: HitSurface, wo: vec3<f32>, tri: u32, t: f32, throughput: vec3<f32>, p_sky: f32, candidates: u32, rng: ptr<function, Rng>) -> PathEnd {
    let direct = next_event(surf, wo, rng, 0.0, false, candidates);
    let m = surf.material;
    let albedo = diffuse_color(m, max(dot(surf.normal, wo), 0.0)) + specular_albedo_average(m);
    return PathEnd(true, throughput * direct.radiance, throughput * albedo * ambient_irradiance.xyz * INV_PI, direct.shadow_rays, 0u, 0u);
}
