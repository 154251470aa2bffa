// Global SDF update, step 2: each pending slot whose brick lies within the narrow band of a
// triangle (distance from the brick centre below its half diagonal plus the band) takes a brick
// from the free stack and joins the fill list; the rest stay empty (the coarse volume answers
// there). When the pool runs out the brick stays empty and the failure is counted. Every slot
// holding a brick afterwards joins the voxel lighting's list.
#import gilab::tracing::{params, brick_table, brick_coord, free_stack, sdf_state, fill_list, lit_list_index, level_voxel, closest_triangle, BRICK, BAND, EMPTY, STATE_LIT}

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let n = params.bricks_per_axis;
    let slot = gid.x;
    if slot >= params.levels_built * n * n * n {
        return;
    }
    let l = slot / (n * n * n);
    let held = brick_coord[slot];
    if params.levels[l].update.x != 0u && held.w == 0 {
        allocate(slot, l, held.xyz);
    }
    // Every brick held after this update, for the voxel lighting's dispatch.
    if brick_table[slot] != EMPTY {
        fill_list[lit_list_index(atomicAdd(&sdf_state[STATE_LIT], 1u))] = slot;
    }
}

fn allocate(slot: u32, l: u32, b: vec3<i32>) {
    let n = params.bricks_per_axis;
    let voxel = level_voxel(l);
    let half_diag = 0.5 * sqrt(3.0) * f32(BRICK) * voxel;
    let centre = (vec3<f32>(b) + 0.5) * f32(BRICK) * voxel;
    let reach = half_diag + (BAND + 1.0) * voxel;
    let c = closest_triangle(centre, reach);
    if c.dist < reach {
        let free = atomicLoad(&sdf_state[0]);
        let pop = atomicAdd(&sdf_state[3], 1u);
        if pop < free {
            brick_table[slot] = free_stack[free - 1u - pop];
            fill_list[l * n * n * n + atomicAdd(&sdf_state[4u + l], 1u)] = slot;
        } else {
            atomicAdd(&sdf_state[2], 1u);
        }
    }
    brick_coord[slot] = vec4<i32>(b, 1);
}
