// Turns a BVH hit into everything shading needs: position, normals facing the viewer, material.
#define_import_path gilab::surface

#import gilab::scene::{tri_geom, tri_attr, materials, tri_material, base_color}
#import gilab::brdf::{Surface, make_shaded_surface}
#import gilab::bvh::Hit

struct HitSurface {
    position: vec3<f32>,
    // Geometric normal, flipped to face the incoming ray.
    geo_normal: vec3<f32>,
    // Interpolated shading normal, on the viewer's side; the geometric normal where interpolation is unusable.
    normal: vec3<f32>,
    // True if the ray hit the side the triangle's winding faces (where single-sided emission goes).
    front_face: bool,
    material: Surface,
    material_index: u32,
}

fn hit_surface(origin: vec3<f32>, dir: vec3<f32>, hit: Hit) -> HitSurface {
    let g = tri_geom[hit.tri];
    let a = tri_attr[hit.tri];
    let bary_a = 1.0 - hit.bary.x - hit.bary.y;
    let position = g.vertex_a.xyz + hit.bary.x * g.edge_b.xyz + hit.bary.y * g.edge_c.xyz;
    var ng = normalize(cross(g.edge_b.xyz, g.edge_c.xyz));
    let front = dot(ng, dir) < 0.0;
    if !front {
        ng = -ng;
    }
    var ns = bary_a * a.normal_a.xyz + hit.bary.x * a.normal_b.xyz + hit.bary.y * a.normal_c.xyz;
    let len = length(ns);
    if len > 1e-6 {
        ns = ns / len;
        if dot(ns, ng) < 0.0 {
            ns = -ns;
        }
        // Shading normals facing away from the viewer make the BRDF meaningless: fall back.
        if dot(ns, -dir) <= 1e-4 {
            ns = ng;
        }
    } else {
        ns = ng;
    }
    let uv = bary_a * a.uv_ab.xy + hit.bary.x * a.uv_ab.zw + hit.bary.y * a.uv_c.xy;
    let mi = tri_material(hit.tri);
    let m = materials[mi];
    let base = base_color(m, uv);
    let surf = make_shaded_surface(base.xyz, m.params.x, m.params.y, m.params.z, m.shading);
    return HitSurface(position, ng, ns, front, surf, mi);
}
