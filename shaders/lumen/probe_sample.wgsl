// Ray directions of a screen probe (one workgroup per probe, one thread per octahedral cell and
// per ray): the seed's product importance sampling. Each cell's weight is the BRDF of the pixels
// the probe serves (mean clamped cosine over 16 of their normals) times the light arriving from
// it, estimated by last frame's probe on the same plane (reprojected) or else the world radiance
// cache; a quarter of the rays stay uniform over the cells any of those pixels sees (defensive).
// 64 stratified numbers pick cells through the CDF, a ray is uniform within its cell (cells have
// equal solid angle), and its weight 1 / (64 p_cell) makes the cell's radiance estimate unbiased
// (probe_resolve). `probe_sampling = uniform` uses the defensive part alone.
// `probe_ray_reassignment` (product only) replaces the CDF draw by the seed's reassignment: each
// seen cell starts with one ray; a cell whose pdf p is below half the uniform level 1/C (C seen
// cells) keeps it with probability 2 C p (Russian roulette, weight 1 / (2 C p): unbiased, and
// >= 1/2 through the defensive part, so a dark estimate cannot lock a cell out); the freed rays
// and those of unseen cells go 3 at a time to the kept cells in decreasing pdf, which then take
// 4 stratified sub-rays (2x2 in the cell) weighted 1/4 each: their radiance is the mean of their
// sub-rays. The threshold was measured (docs/lumen.md): 1/C culled too much on both scenes.
#import gilab::frame::frame
#import gilab::math::luminance
#import gilab::primary::current_surface
#import gilab::rng::{Rng, rng_init, rand, rand_pair, STREAM_LUMEN_PROBE_RAYS}
#import gilab::equal_area::cell_dir
#import gilab::world_cache::world_lookup
#import gilab::lumen_probes::{pp, probe_data, load_probe, parity, probe_count, probes_flag, previous_match, cache_index, ray_index, spacing, PROBE_CELLS, PROBE_RES, NO_PROBE, DEFENSIVE, PROBES_PRODUCT, PROBES_WORLD_CACHE, PROBES_REASSIGN}

var<workgroup> normals: array<vec3<f32>, 16>;
var<workgroup> pdf: array<f32, 64>;
var<workgroup> cdf: array<f32, 64>;
var<workgroup> support: array<f32, 64>;
// Reassignment: rays per cell, first ray of each cell, cells by decreasing pdf.
var<workgroup> rays: array<u32, 64>;
var<workgroup> first: array<u32, 64>;
var<workgroup> order: array<u32, 64>;
// Cells below this share of the uniform pdf play roulette.
const REASSIGN_THRESHOLD: f32 = 0.5;

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) j: u32) {
    let probe = wid.x;
    let q = load_probe(parity(), probe);
    let live = probe < probe_count() && q.valid;
    // The pixels the probe serves: its tile (uniform) or its cell (adaptive), on its plane.
    if j < 16u {
        var n = vec3<f32>(0.0);
        if live {
            let extent = select(spacing(), spacing() / 2u, q.adaptive);
            let corner = q.pixel - min(q.pixel % extent, q.pixel);
            let pixel = min(corner + (vec2<u32>(j % 4u, j / 4u) * extent + extent / 2u) / 4u, frame.size - 1u);
            let s = current_surface(pixel.y * frame.size.x + pixel.x);
            if s.pos.w > 0.5 && abs(dot(q.normal, s.pos.xyz - q.pos)) < 0.05 * q.dist {
                n = s.normal_alpha.xyz;
            }
        }
        normals[j] = n;
    }
    workgroupBarrier();
    let d = cell_dir(j, PROBE_RES, vec2<f32>(0.5));
    var brdf = max(dot(q.normal, d), 0.0);
    for (var k = 0u; k < 16u; k++) {
        brdf += max(dot(normals[k], d), 0.0);
    }
    // Cells straddling the horizon of some served pixel count as seen.
    let seen = brdf > 0.0 || dot(q.normal, d) > -0.35;
    var light = 1.0;
    if live && probes_flag(PROBES_PRODUCT) {
        let prev = previous_match(q);
        if prev != NO_PROBE {
            light = luminance(probe_data[cache_index(1u - parity(), prev, j)].xyz);
        } else if probes_flag(PROBES_WORLD_CACHE) {
            let w = world_lookup(q.pos + q.normal * 0.01 * q.dist, d, true);
            light = select(1.0, luminance(w.radiance), w.weight > 0.0);
        }
    }
    support[j] = select(0.0, 1.0, seen);
    pdf[j] = select(0.0, (brdf + 0.05) * max(light, 0.0), seen);
    workgroupBarrier();
    if j == 0u {
        var total = 0.0;
        var count = 0.0;
        for (var k = 0u; k < PROBE_CELLS; k++) {
            total += pdf[k];
            count += support[k];
        }
        let product = select(0.0, 1.0 - DEFENSIVE, probes_flag(PROBES_PRODUCT) && total > 0.0);
        var sum = 0.0;
        for (var k = 0u; k < PROBE_CELLS; k++) {
            let p = product * pdf[k] / max(total, 1e-30) + (1.0 - product) * support[k] / max(count, 1.0);
            pdf[k] = p;
            sum += p;
            cdf[k] = sum;
        }
        cdf[PROBE_CELLS - 1u] = 2.0;
    }
    workgroupBarrier();
    // Seeded by the probe's pixel: adaptive probes' indices depend on the order of atomics.
    var rng = rng_init(q.pixel, frame.frame_index * PROBE_CELLS + j, STREAM_LUMEN_PROBE_RAYS, frame.seed);
    let r = ray_index(probe, j);
    if probes_flag(PROBES_PRODUCT) && probes_flag(PROBES_REASSIGN) {
        reassign(live, j, r, &rng);
        return;
    }
    let u = (f32(j) + rand(&rng)) / f32(PROBE_CELLS);
    var cell = 0u;
    while cell < PROBE_CELLS - 1u && (cdf[cell] <= u || pdf[cell] <= 0.0) {
        cell++;
    }
    let offset = rand_pair(&rng);
    let uv = (vec2<f32>(f32(cell % PROBE_RES), f32(cell / PROBE_RES)) + offset) / f32(PROBE_RES);
    var weight = 0.0;
    if live && pdf[cell] > 0.0 {
        weight = 1.0 / (f32(PROBE_CELLS) * pdf[cell]);
    }
    probe_data[r] = vec4<f32>(uv, weight, bitcast<f32>(cell));
    probe_data[r + 1u] = vec4<f32>(0.0, 0.0, 0.0, 0.0);
}

// The seed's ray reassignment (see the top); pdf holds the mixture, support the seen cells.
fn reassign(live: bool, j: u32, r: u32, rng: ptr<function, Rng>) {
    // Rank by decreasing pdf (ties by index): every thread counts the cells above its own.
    var rank = 0u;
    for (var k = 0u; k < PROBE_CELLS; k++) {
        if pdf[k] > pdf[j] || (pdf[k] == pdf[j] && k < j) {
            rank++;
        }
    }
    order[rank] = j;
    var count = 0.0;
    for (var k = 0u; k < PROBE_CELLS; k++) {
        count += support[k];
    }
    // Roulette: keep probability min(1, C p / threshold); the survivors' weight divides by it.
    let keep = min(count * pdf[j] / REASSIGN_THRESHOLD, 1.0);
    let kept = live && pdf[j] > 0.0 && rand(rng) < keep;
    rays[j] = select(0u, 1u, kept);
    workgroupBarrier();
    if j == 0u {
        var used = 0u;
        for (var k = 0u; k < PROBE_CELLS; k++) {
            used += rays[k];
        }
        // Freed rays, 3 at a time, to the kept cells by decreasing pdf (again while any remain).
        var left = select(0u, PROBE_CELLS - used, used > 0u);
        while left > 0u {
            for (var i = 0u; i < PROBE_CELLS && left > 0u; i++) {
                let c = order[i];
                if rays[c] > 0u {
                    let extra = min(left, 3u);
                    rays[c] += extra;
                    left -= extra;
                }
            }
        }
        var start = 0u;
        for (var k = 0u; k < PROBE_CELLS; k++) {
            first[k] = start;
            start += rays[k];
        }
    }
    workgroupBarrier();
    var cell = 0u;
    while cell < PROBE_CELLS - 1u && (rays[cell] == 0u || j >= first[cell] + rays[cell]) {
        cell++;
    }
    let n = rays[cell];
    let sub = j - min(first[cell], j);
    var weight = 0.0;
    var offset = rand_pair(rng);
    if n > 0u && j >= first[cell] {
        // 4 sub-rays: a 2x2 stratification; other counts: strata along x.
        if n == 4u {
            offset = (vec2<f32>(f32(sub % 2u), f32(sub / 2u)) + offset) / 2.0;
        } else {
            offset.x = (f32(sub) + offset.x) / f32(n);
        }
        weight = 1.0 / (f32(n) * min(count * pdf[cell] / REASSIGN_THRESHOLD, 1.0));
    }
    let uv = (vec2<f32>(f32(cell % PROBE_RES), f32(cell / PROBE_RES)) + offset) / f32(PROBE_RES);
    probe_data[r] = vec4<f32>(uv, weight, bitcast<f32>(cell));
    probe_data[r + 1u] = vec4<f32>(0.0, 0.0, 0.0, 0.0);
}
