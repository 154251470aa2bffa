// How a GI sample path ends in the surfels (`gi_terminate = "surfels"`, src/parts/surfel_cache.rs)
// where they cover the hit, as a surfel's own ray does: NEE of the lights at full weight, and
// every further bounce from the surfels' irradiance (which holds the sky their rays reached, so
// NEE leaves the sky out), reflected by the diffuse albedo plus the specular layer's average
// albedo. Off screen no surfel covers a hit: the path is traced on to the end, unbiased there.
#define_import_path gilab::surfels_path_end

#import gilab::path_end
#import gilab::math::INV_PI
#import gilab::frame::frame
#import gilab::rng::Rng
#import gilab::surface_point::HitSurface
#import gilab::brdf::{diffuse_color, specular_albedo_average}
#import gilab::surfels::{gather, gather_covers, gather_outcome, gathered_irradiance, grid_center_for}
#import gilab::path_vertex::{PathEnd, next_event, path_not_ended}

override fn gilab::path_end::end_path(surf: HitSurface, wo: vec3<f32>, tri: u32, t: f32, throughput: vec3<f32>, p_sky: f32, candidates: u32, rng: ptr<function, Rng>) -> PathEnd {
    let g = gather(surf.position, surf.normal, grid_center_for(frame.camera_pos.xyz), false);
    let outcome = gather_outcome(g, surf.position);
    if !gather_covers(g) {
        return path_not_ended(outcome);
    }
    let direct = next_event(surf, wo, rng, 0.0, false, candidates);
    let m = surf.material;
    let albedo = diffuse_color(m, max(dot(surf.normal, wo), 0.0)) + specular_albedo_average(m);
    return PathEnd(true, throughput * direct.radiance, throughput * albedo * gathered_irradiance(g) * INV_PI, direct.shadow_rays, 0u, outcome);
}
