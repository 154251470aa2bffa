// Voxel lighting, step 1 (the seed's "Voxel Lighting Visibility Buffer"): for each brick the
// distance field (re)built this frame (scrolled, edited, moved objects, first build), one thread
// per lighting voxel (4^3 per brick, twice the field's voxel) traces one BVH ray per axis
// direction across the voxel, from the face that direction points out of, and stores the
// front face it meets: its object and the distance. Geometry is cached, lighting is not: the
// radiance is shaded every frame (voxel_lighting.wgsl).
#import gilab::scene::{tri_geom, tri_material, materials, scene_triangle}
#import gilab::bvh::{trace_closest, NO_HIT}
#import gilab::lumen::{params, brick_table, brick_coord, brick_pool, fill_list, level_voxel, voxel_dir, voxel_word_index, BRICK, LIGHT_BRICK, VOXEL_DIRS, EMPTY}
#import gilab::surface_cache::{tri_object}

// The level this dispatch fills (one dispatch per level, as the fill).
@group(3) @binding(0) var<uniform> fill_level: vec4<u32>;

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let n = params.bricks_per_axis;
    let l = fill_level.x;
    let slot = fill_list[l * n * n * n + wg.x];
    let entry = brick_table[slot];
    let b = brick_coord[slot].xyz;
    let size = f32(BRICK / LIGHT_BRICK) * level_voxel(l);
    let local = vec3<i32>(i32(li % LIGHT_BRICK), i32((li / LIGHT_BRICK) % LIGHT_BRICK), i32(li / (LIGHT_BRICK * LIGHT_BRICK)));
    let centre = (vec3<f32>(b * i32(LIGHT_BRICK) + local) + 0.5) * size;
    for (var k = 0u; k < VOXEL_DIRS; k++) {
        let d = voxel_dir(k);
        let h = trace_closest(centre + 0.5 * size * d, -d, 0.0, size);
        var word = EMPTY;
        if h.tri != NO_HIT {
            let g = tri_geom[h.tri];
            let facing = dot(cross(g.edge_b.xyz, g.edge_c.xyz), d) > 0.0;
            let double_sided = materials[tri_material(h.tri)].emissive.w > 0.5;
            if facing || double_sided {
                let object = tri_object[scene_triangle(h.tri)];
                let q = u32(round(clamp(h.t / size, 0.0, 1.0) * 65535.0));
                word = min(object, 0xffffu) | (q << 16u);
            }
        }
        brick_pool[voxel_word_index(0u, entry, li, k)] = word;
    }
}
