// ReGIR pass: fills every (cell, slot) that a pixel reads in the camera-centred grid with one light sample chosen
// by RIS from the local lights (from every light in single-pool mode); target: emitted strength / squared distance to the cell centre
// (clamped at the cell's half-diagonal, no cosine), so no light that may reach the cell is
// ever given zero weight and pixels can use the slots' weights unbiasedly.
#import gilab::rng::{rng_init, rand, rand_pair, STREAM_REGIR_BUILD}
#import gilab::frame::frame
#import gilab::math::luminance
#import gilab::scene::light_pool
#import gilab::lights::{select_light, select_light_in_class, class_pdf_scale, light_emitter}
#import gilab::sampling::sample_triangle
#import gilab::restir::{params, regir_slots, RegirSlot, regir_cell_centre, regir_used}

const CANDIDATES_PER_SLOT: u32 = 32u;

fn cell_target(light: u32, b: vec2<f32>, centre: vec3<f32>, min_dist_sq: f32) -> f32 {
    let e = light_emitter(light, b);
    if e.directional {
        return luminance(e.strength);
    }
    let d = e.position - centre;
    return luminance(e.strength) / max(dot(d, d), min_dist_sq);
}

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let dims = params.regir_dims;
    let total = dims * dims * dims * params.regir_slots;
    if gid.x >= total || params.candidates == 0u {
        return;
    }
    let cell = gid.x / params.regir_slots;
    // Only cells some pixel reads (marked by regir_mark.wgsl this frame). A slot's random
    // stream depends only on its index, so the filled cells are the same as a full build's.
    if atomicLoad(&regir_used[cell]) == 0u {
        return;
    }
    var rng = rng_init(vec2<u32>(gid.x, 0u), frame.sample_offset, STREAM_REGIR_BUILD, frame.seed);
    let centre = regir_cell_centre(cell);
    let half_diag = 0.87 * params.regir_cell_size;
    let min_dist_sq = half_diag * half_diag;
    var w_sum = 0.0;
    var chosen = RegirSlot(0u, 0.0, 0.0, 0.0);
    var chosen_target = 0.0;
    for (var i = 0u; i < CANDIDATES_PER_SLOT; i++) {
        var li = 0u;
        var scale = 1.0;
        if params.single_pool == 1u {
            li = select_light(rand(&rng));
        } else {
            li = select_light_in_class(rand(&rng), 0u, light_pool.local_count);
            scale = class_pdf_scale(li);
        }
        let b = sample_triangle(rand_pair(&rng));
        let e = light_emitter(li, b);
        let pdf = e.area_pdf * scale;
        if pdf <= 0.0 {
            continue;
        }
        let t = cell_target(li, b, centre, min_dist_sq);
        let w = t / pdf;
        w_sum += w;
        if w > 0.0 && rand(&rng) * w_sum < w {
            chosen = RegirSlot(li, b.x, b.y, 0.0);
            chosen_target = t;
        }
    }
    if chosen_target > 0.0 {
        chosen.big_w = w_sum / (f32(CANDIDATES_PER_SLOT) * chosen_target);
    }
    regir_slots[gid.x] = chosen;
}
