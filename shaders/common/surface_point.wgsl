// The surface at a point of a triangle: position, normals facing the viewer, material
// (textures at a ray-cone level, normal map). No bindings beyond the scene's (group 0), so
// raster passes with their own group 1 (Lumen's card capture) use it too.
#define_import_path gilab::surface_point

#import gilab::scene::{tri_geom, tri_attr, materials, tri_uvs, oct_decode_packed, slot_used, slot_sample, TRI_HAS_NORMALS, TRI_HAS_TANGENTS, TRI_BITANGENT_NEG_SHIFT, SLOT_BASE_COLOR, SLOT_METALLIC_ROUGHNESS, SLOT_NORMAL, material_at, tri_attr_at}
#import gilab::brdf::{Surface, make_shaded_surface}

struct HitSurface {
    position: vec3<f32>,
    // Geometric normal, flipped to face the incoming ray.
    geo_normal: vec3<f32>,
    // Shading normal (interpolated, normal-mapped), on the viewer's side; the geometric normal
    // where it is unusable.
    normal: vec3<f32>,
    // True if the ray hit the side the triangle's winding faces (where single-sided emission goes).
    front_face: bool,
    material: Surface,
    material_index: u32,
}

// Area (x2) of a UV triangle.
fn uv_area2(a: vec2<f32>, b: vec2<f32>, c: vec2<f32>) -> f32 {
    let e1 = b - a;
    let e2 = c - a;
    return abs(e1.x * e2.y - e1.y * e2.x);
}

// The surface at barycentrics `bary` of triangle `tri`, seen along `dir`, with a ray-cone
// footprint `cone_width` there (0: finest texture level).
fn surface_at(tri: u32, bary: vec2<f32>, dir: vec3<f32>, cone_width: f32) -> HitSurface {
    let g = tri_geom[tri];
    let a = tri_attr_at(tri);
    let bary_a = 1.0 - bary.x - bary.y;
    let position = g.vertex_a.xyz + bary.x * g.edge_b.xyz + bary.y * g.edge_c.xyz;
    let cross_e = cross(g.edge_b.xyz, g.edge_c.xyz);
    let world_area2 = length(cross_e);
    let winding_n = cross_e / max(world_area2, 1e-30);
    let front = dot(winding_n, dir) < 0.0;
    let ng = select(-winding_n, winding_n, front);

    // Ray-cone level terms of both UV sets (the texture's size is added per slot).
    let cos_v = max(abs(dot(winding_n, dir)), 1e-4);
    let cone = log2(max(cone_width, 1e-20) / cos_v);
    let area0 = uv_area2(a.uv0_ab.xy, a.uv0_ab.zw, a.uv0_c_uv1_a.xy);
    let area1 = uv_area2(a.uv0_c_uv1_a.zw, a.uv1_bc.xy, a.uv1_bc.zw);
    let inv_world = 1.0 / max(world_area2, 1e-30);
    var lod = vec2<f32>(cone) + 0.5 * log2(max(vec2<f32>(area0, area1) * inv_world, vec2<f32>(1e-30)));
    if cone_width <= 0.0 {
        lod = vec2<f32>(-100.0);
    }
    let uvs = tri_uvs(tri, bary);

    let mi = a.material;
    let m = material_at(mi);
    var base = m.base_color;
    if slot_used(m.tex[SLOT_BASE_COLOR]) {
        base *= slot_sample(m.tex[SLOT_BASE_COLOR], uvs, lod, true);
    }
    var metallic = m.params.x;
    var roughness = m.params.y;
    if slot_used(m.tex[SLOT_METALLIC_ROUGHNESS]) {
        let mr = slot_sample(m.tex[SLOT_METALLIC_ROUGHNESS], uvs, lod, false);
        roughness *= mr.y;
        metallic *= mr.z;
    }

    // The mesh's normal (winding side), normal-mapped, then turned to the viewer's side.
    var ns = winding_n;
    if (a.flags & TRI_HAS_NORMALS) != 0u {
        let n = bary_a * oct_decode_packed(a.normals.x) + bary.x * oct_decode_packed(a.normals.y) + bary.y * oct_decode_packed(a.normals.z);
        let len = length(n);
        if len > 1e-6 {
            ns = n / len;
        }
    }
    if (a.flags & TRI_HAS_TANGENTS) != 0u && slot_used(m.tex[SLOT_NORMAL]) {
        let t_raw = bary_a * oct_decode_packed(a.tangents.x) + bary.x * oct_decode_packed(a.tangents.y) + bary.y * oct_decode_packed(a.tangents.z);
        let t = t_raw - ns * dot(ns, t_raw);
        let t_len = length(t);
        if t_len > 1e-6 {
            let signs = vec3<f32>(
                select(1.0, -1.0, ((a.flags >> TRI_BITANGENT_NEG_SHIFT) & 1u) != 0u),
                select(1.0, -1.0, ((a.flags >> (TRI_BITANGENT_NEG_SHIFT + 1u)) & 1u) != 0u),
                select(1.0, -1.0, ((a.flags >> (TRI_BITANGENT_NEG_SHIFT + 2u)) & 1u) != 0u),
            );
            let sign = select(-1.0, 1.0, dot(vec3<f32>(bary_a, bary.x, bary.y), signs) >= 0.0);
            let tangent = t / t_len;
            let bitangent = sign * cross(ns, tangent);
            // The map's own axes when its texture transform rotates or scales it: with
            // uv' = M uv, dP/du' = dP/duv M^-1 (dP/du ~ T, dP/dv ~ -B: image +Y is -v).
            let slot = m.tex[SLOT_NORMAL];
            let det = slot.transform_u.x * slot.transform_v.y - slot.transform_u.y * slot.transform_v.x;
            var map_t = tangent;
            var map_b = bitangent;
            if abs(det) > 1e-12 {
                let inv = mat2x2<f32>(slot.transform_v.y, -slot.transform_v.x, -slot.transform_u.y, slot.transform_u.x) * (1.0 / det);
                // inv[c][r]: column c, row r of M^-1.
                let du = inv[0][0] * tangent - inv[0][1] * bitangent;
                let dv = inv[1][0] * tangent - inv[1][1] * bitangent;
                map_t = normalize(du);
                map_b = -normalize(dv);
            }
            var tn = slot_sample(slot, uvs, lod, false).xyz * 2.0 - 1.0;
            tn = vec3<f32>(tn.xy * m.extra.x, tn.z);
            let mapped = tn.x * map_t + tn.y * map_b + tn.z * ns;
            let len = length(mapped);
            if len > 1e-6 {
                ns = mapped / len;
            }
        }
    }
    // Back faces see the mirrored frame (glTF: double-sided back faces flip the normal).
    if !front {
        ns = -ns;
    }
    if dot(ns, ng) < 0.0 {
        ns = -ns;
    }
    // Shading normals facing away from the viewer make the BRDF meaningless: fall back.
    if dot(ns, -dir) <= 1e-4 {
        ns = ng;
    }
    let surf = make_shaded_surface(base.xyz, metallic, roughness, m.params.z, m.shading);
    return HitSurface(position, ng, ns, front, surf, mi);
}
