// Global SDF update, step 5: the quarter-resolution coarse volume of each updated level,
// rebuilt whole as the seed does: the unsigned distance to the closest triangle at each coarse
// cell centre (searched out to the level's size). Tracing uses it to skip empty space.
#import gilab::lumen::{params, coarse, level_min, level_voxel, coarse_cells, closest_triangle}

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let n = coarse_cells();
    let i = gid.x;
    if i >= params.levels_built * n * n * n {
        return;
    }
    let l = i / (n * n * n);
    if params.levels[l].update.x == 0u {
        return;
    }
    let local = i - l * n * n * n;
    let c = vec3<u32>(local % n, (local / n) % n, local / (n * n));
    let cell = 4.0 * level_voxel(l);
    let centre = level_min(l) + (vec3<f32>(c) + 0.5) * cell;
    let reach = f32(params.resolution) * level_voxel(l);
    coarse[i] = closest_triangle(centre, reach).dist;
}
