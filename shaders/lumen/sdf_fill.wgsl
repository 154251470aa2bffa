// Global SDF update, step 4: one workgroup per allocated brick fills its 8^3 voxels with the
// distance to the closest triangle (BVH point query, within the band) and that triangle's
// object. The sign comes from rays, as in the seed: a voxel is inside when most of the
// single-sided surfaces its `sign_rays` rays hit are back faces (and most rays hit something).
#import gilab::scene::{tri_geom, tri_material, materials, scene_triangle, material_at}
#import gilab::bvh::{trace_closest, NO_HIT}
#import gilab::math::TWO_PI
#import gilab::tracing::{params, brick_table, brick_coord, brick_pool, fill_list, level_voxel, closest_triangle, encode_voxel, BRICK, BRICK_VOXELS, BAND, NO_OBJECT}
#import gilab::surface_cache::{tri_object}

// Direction k of n spread over the sphere (spherical Fibonacci).
fn fibonacci_dir(k: u32, n: u32) -> vec3<f32> {
    let z = 1.0 - (2.0 * f32(k) + 1.0) / f32(n);
    let r = sqrt(max(0.0, 1.0 - z * z));
    let phi = TWO_PI * fract(f32(k) * 0.618033988749895);
    return vec3<f32>(r * cos(phi), r * sin(phi), z);
}

fn inside(p: vec3<f32>) -> bool {
    var hits = 0u;
    var back = 0u;
    for (var k = 0u; k < params.sign_rays; k++) {
        let d = fibonacci_dir(k, params.sign_rays);
        let h = trace_closest(p, d, 0.0, 1e30);
        if h.tri == NO_HIT {
            continue;
        }
        let g = tri_geom[h.tri];
        let n = cross(g.edge_b.xyz, g.edge_c.xyz);
        let double_sided = material_at(tri_material(h.tri)).emissive.w > 0.5;
        if double_sided {
            continue;
        }
        hits++;
        if dot(n, d) > 0.0 {
            back++;
        }
    }
    // Inside: most hits are back faces (the seed's vote) and the point is enclosed (at least
    // three quarters of the rays hit something). Behind an open scene's single-sided walls most
    // rays escape: those points count as outside, so the wall is a thin two-sided surface there
    // (the expand stops rays at it) instead of a sign flip that reaches into empty space.
    return 2u * back > hits && 4u * hits >= 3u * params.sign_rays;
}

// The level this dispatch fills (one dispatch per level, so each level's build is timed).
@group(3) @binding(0) var<uniform> fill_level: vec4<u32>;

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let n = params.bricks_per_axis;
    let l = fill_level.x;
    let slot = fill_list[l * n * n * n + wg.x];
    let entry = brick_table[slot];
    let b = brick_coord[slot].xyz;
    let voxel = level_voxel(l);
    let band = BAND * voxel;
    for (var k = li; k < BRICK_VOXELS; k += 64u) {
        let local = vec3<i32>(i32(k % BRICK), i32((k / BRICK) % BRICK), i32(k / (BRICK * BRICK)));
        let p = (vec3<f32>(b * i32(BRICK) + local) + 0.5) * voxel;
        let c = closest_triangle(p, band);
        var d = c.dist;
        var object = NO_OBJECT;
        if c.tri != NO_HIT {
            object = tri_object[scene_triangle(c.tri)];
            if inside(p) {
                d = -d;
            }
        }
        brick_pool[entry * BRICK_VOXELS + k] = encode_voxel(d / band, object);
    }
}
