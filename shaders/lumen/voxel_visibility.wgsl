// Voxel lighting, step 1 (the seed's "Voxel Lighting Visibility Buffer"): for each brick the
// distance field (re)built this frame (scrolled, edited, moved objects, first build), one thread
// per lighting voxel (4^3 per brick, twice the field's voxel) traces BVH rays per axis
// direction across the voxel, from the face that direction points out of, and stores the
// nearest front face they meet: its object and the distance. Geometry is cached, lighting is
// not: the radiance is shaded every frame (voxel_lighting.wgsl), and reads as none until then.
#import gilab::scene::{tri_geom, tri_material, materials, scene_triangle, material_at}
#import gilab::bvh::{trace_closest, NO_HIT}
#import gilab::tracing::{params, brick_table, brick_coord, brick_pool, fill_list, lighting_voxel_size, sdf_distance_written, voxel_dir, voxel_word_index, lighting_voxel_centre, voxel_ray_start, voxel_ray_length, encode_seen, VOXEL_DIRS, EMPTY}
#import gilab::surface_cache::{tri_object}

// The level this dispatch fills (one dispatch per level, as the fill).
@group(3) @binding(0) var<uniform> fill_level: vec4<u32>;

const VISIBILITY_RAYS: u32 = 5u;

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let n = params.bricks_per_axis;
    let l = fill_level.x;
    let slot = fill_list[l * n * n * n + wg.x];
    let entry = brick_table[slot];
    let b = brick_coord[slot].xyz;
    let size = lighting_voxel_size(l);
    let centre = lighting_voxel_centre(b, li, size);
    for (var k = 0u; k < VOXEL_DIRS; k++) {
        let d = voxel_dir(k);
        // Rays through the centre and the four quarter points of the face: a surface covering
        // part of the voxel (a block's edge in a coarse level) is still found.
        let a = k / 2u;
        let u = voxel_dir(2u * ((a + 1u) % 3u));
        let v = voxel_dir(2u * ((a + 2u) % 3u));
        let start = voxel_ray_start(centre, size, k);
        var best = voxel_ray_length(size);
        var word = EMPTY;
        for (var r = 0u; r < VISIBILITY_RAYS; r++) {
            // The centre first; a quarter ray replaces its surface only when clearly nearer
            // (a floor seen by all five keeps the centre's point, not one under a block).
            let o = select(vec2<f32>(select(-0.25, 0.25, (r & 1u) == 1u), select(-0.25, 0.25, (r & 2u) == 2u)), vec2<f32>(0.0), r == 0u);
            let origin = start + (o.x * u + o.y * v) * size;
            // A ray starting inside geometry (the field, filled just before) sees nothing real.
            if sdf_distance_written(l, origin) < 0.0 {
                continue;
            }
            let h = trace_closest(origin, -d, 0.0, select(best - 0.02 * size, best, word == EMPTY));
            if h.tri == NO_HIT {
                continue;
            }
            let g = tri_geom[h.tri];
            let facing = dot(cross(g.edge_b.xyz, g.edge_c.xyz), d) > 0.0;
            let double_sided = material_at(tri_material(h.tri)).emissive.w > 0.5;
            if facing || double_sided {
                best = h.t;
                word = encode_seen(tri_object[scene_triangle(h.tri)], h.t, size);
            }
        }
        brick_pool[voxel_word_index(0u, entry, li, k)] = word;
        // No radiance until this frame's voxel lighting pass: the surface cache's lighting
        // traces between the two, and the pool entry still held the radiance of whichever brick
        // had it last (entries come off the free stack in atomic order, so that read made
        // SDF-traced Lumen in a playing scene differ from run to run).
        brick_pool[voxel_word_index(1u, entry, li, k)] = EMPTY;
    }
}
