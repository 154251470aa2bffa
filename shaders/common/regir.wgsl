// ReGIR ("Making Connections"; Boksansky et al. 2021): what a grid cell's light reservoirs are
// and how one is filled. Shared by ReSTIR DI's camera-centred grid (restir/regir_build.wgsl)
// and the world-space clipmap that lights the caches (parts/world_regir; src/parts/world_regir.rs).
#define_import_path gilab::regir

#import gilab::rng::{Rng, rand, rand_pair}
#import gilab::math::luminance
#import gilab::scene::{light_pool, light_at}
#import gilab::lights::{select_light, select_light_in_class, class_pdf_scale, light_emitter}
#import gilab::sampling::sample_triangle
#import gilab::light_tree::tree_sample_region

struct RegirSlot {
    light: u32,
    bary_u: f32,
    bary_v: f32,
    // Unbiased contribution weight of the slot's light sample (area measure); 0 = empty.
    big_w: f32,
}

// Light candidates resampled into each slot.
const REGIR_CANDIDATES_PER_SLOT: u32 = 32u;

// The cell's target: emitted strength over squared distance to the cell centre, clamped at the
// cell's half-diagonal, no cosine. No light that may reach the cell gets zero weight, so a
// point in the cell can use the slots' weights unbiasedly.
fn regir_cell_target(light: u32, b: vec2<f32>, centre: vec3<f32>, min_dist_sq: f32) -> f32 {
    let e = light_emitter(light, b);
    if e.directional {
        return luminance(e.strength);
    }
    let d = e.position - centre;
    return luminance(e.strength) / max(dot(d, d), min_dist_sq);
}

// One slot of the cell at `centre` (edge `cell_size`) by RIS over REGIR_CANDIDATES_PER_SLOT
// lights: by power over every light (`all_lights`), or within the local class (triangles,
// point and spot lights) as ReSTIR DI's classes use it, by power or (`by_tree`) by the light
// tree's importance for the cell's bounding ball (`regir_fill = "tree"`), whose pmf is zero
// only for lights that light no point of the cell.
fn regir_fill_slot(centre: vec3<f32>, cell_size: f32, all_lights: bool, by_tree: bool, rng: ptr<function, Rng>) -> RegirSlot {
    let half_diag = 0.87 * cell_size;
    let min_dist_sq = half_diag * half_diag;
    var w_sum = 0.0;
    var chosen = RegirSlot(0u, 0.0, 0.0, 0.0);
    var chosen_target = 0.0;
    for (var i = 0u; i < REGIR_CANDIDATES_PER_SLOT; i++) {
        var li = 0u;
        var scale = 1.0;
        if all_lights {
            li = select_light(rand(rng));
        } else if by_tree {
            // The area pdf below is the pool's power pmf times the point's: swap the pmf.
            let t = tree_sample_region(centre, half_diag, rand(rng));
            let power_pmf = light_at(t.light).pmf;
            if t.pmf <= 0.0 || power_pmf <= 0.0 {
                continue;
            }
            li = t.light;
            scale = t.pmf / power_pmf;
        } else {
            li = select_light_in_class(rand(rng), 0u, light_pool.local_count);
            scale = class_pdf_scale(li);
        }
        let b = sample_triangle(rand_pair(rng));
        let e = light_emitter(li, b);
        let pdf = e.area_pdf * scale;
        if pdf <= 0.0 {
            continue;
        }
        let t = regir_cell_target(li, b, centre, min_dist_sq);
        let w = t / pdf;
        w_sum += w;
        if w > 0.0 && rand(rng) * w_sum < w {
            chosen = RegirSlot(li, b.x, b.y, 0.0);
            chosen_target = t;
        }
    }
    if chosen_target > 0.0 {
        chosen.big_w = w_sum / (f32(REGIR_CANDIDATES_PER_SLOT) * chosen_target);
    }
    return chosen;
}
