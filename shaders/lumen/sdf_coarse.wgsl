// Global SDF update, step 5: the quarter-resolution coarse volume of each updated level,
// rebuilt whole as the seed does: the unsigned distance to the closest triangle at each coarse
// cell centre (searched out to the level's size). Tracing uses it to skip empty space. After
// scene edits alone (levels' update.z), a cell keeps its distance when every edited box lies
// farther than it: neither its closest triangle nor any new one can be in them.
#import gilab::tracing::{params, coarse, dirty_boxes, level_min, level_voxel, coarse_cells, closest_triangle}

fn near_an_edit(p: vec3<f32>, d: f32) -> bool {
    for (var k = 0u; k < params.dirty_box_count; k++) {
        let lo = dirty_boxes[2u * k].xyz;
        let hi = dirty_boxes[2u * k + 1u].xyz;
        if length(max(max(lo - p, p - hi), vec3<f32>(0.0))) <= d * 1.0001 + 1e-6 {
            return true;
        }
    }
    return false;
}

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
    if params.levels[l].update.z == 1u && !near_an_edit(centre, coarse[i]) {
        return;
    }
    let reach = f32(params.resolution) * level_voxel(l);
    coarse[i] = closest_triangle(centre, reach).dist;
}
