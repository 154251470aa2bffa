// Turns a BVH hit into everything shading needs: position, normals facing the viewer, material
// (textures, normal map). Texture levels come from ray cones (Akenine-Moller et al., "Texture
// Level of Detail Strategies for Real-Time Ray Tracing", 2019): footprint width w at the hit,
// lambda = log2(w / |cos|) + 0.5 log2(texel area / world area). Every ray is given the width of
// a camera ray cone of the same length (`pixel_spread` x t): exact for camera rays, a sharper
// (never blurrier) level than a widening cone for secondary rays.
#define_import_path gilab::surface

#import gilab::surface_point::{HitSurface, surface_at}
#import gilab::bvh::Hit
#import gilab::frame::frame

// Width per unit distance of a camera ray's cone (one pixel at distance 1).
fn pixel_spread() -> f32 {
    return 2.0 * length(frame.camera_up.xyz) / f32(frame.size.y);
}

fn hit_surface(origin: vec3<f32>, dir: vec3<f32>, hit: Hit) -> HitSurface {
    return surface_at(hit.tri, hit.bary, dir, hit.t * pixel_spread());
}

