// Callisto shadows pass 2, one workgroup per 16x16 tile (the tile is the workgroup, as the seed
// found it must be): for each light of the tile's list, in order,
// 1. trace: the light's rate for each 2x2 quad comes from last frame (the light's slot in last
//    frame's list of this tile; a light new to the tile gets full rate). Quarter rate traces the
//    top-left pixel; half rate traces the min/max-depth pair on border quads and the diagonal
//    on flat quads; full rate all four. One light sample per traced pixel (a point on a
//    triangle light, the light itself for punctual ones), one shadow ray. A pixel that traces
//    looks up its shadow-cache cell, and queues its ray only when a traversal is left (an
//    uncached cell, or moving instances behind a cached one); the workgroup's first
//    invocations trace the queue. At quarter rate a quarter of the invocations traverse, each
//    wave with all its lanes busy, instead of every wave with a quarter of its lanes (a GPU's
//    skipped pixels and cached cells then save traversal time, not only rays; issue 58);
// 2. reconstruct the skipped pixels bilaterally, as the seed lists: quarter averages the
//    traced top-left samples of this and the neighbouring quads (bilinear x depth weights),
//    half on borders copies the traced sample nearest in depth, half on flat quads averages the
//    diagonal pair. A pixel left with no usable sample traces its own ray;
// 3. the unshadowed contribution of the light (analytic for punctual lights; one area sample
//    for triangles) times the reconstructed visibility is summed per pixel;
// 4. next frame's rates: the variance of the traced visibility over each quad and its
//    neighbours, weighted by the light's perceptual importance (its mean luminance over the
//    tile against last frame's mean scene luminance), against two thresholds.
// 5. the tail (lights outside the list) by `tail_samples` power-sampled shadow rays per pixel.
// A light new to the tile gets half rate (full after a reset, when the tile had no list).
// Writes the pixel's direct light for `resolve` (punctual lights shadowed and unshadowed,
// sampled lights shadowed), the tile's direct
// luminance for `luminance_mean`, and the debug views.
#import gilab::frame::frame
#import gilab::counters::{flush_counts, no_counts, RAY_SHADOW}
#import gilab::rng::{rng_init, rand, rand_pair, STREAM_CALLISTO_LIGHT}
#import gilab::math::luminance
#import gilab::sampling::sample_triangle
#import gilab::primary::{current_surface, surface_material}
#import gilab::brdf::bsdf_eval
#import gilab::lights::{eval_light_point, light_shadow_ray, select_light}
#import gilab::ray::RaySegment
#import gilab::callisto_cache::{split_visibility, plan_visibility, finish_visibility, pack_plan, unpack_plan, receiver_dynamic, record_dynamic, NO_TRACE}
#import gilab::scene::{light_pool, light_at}
#import gilab::callisto::{params, tile_lists, rates, stats, current, debug_out, list_base, list_count, rate_base, get_rate, find_slot, parity, TILE, RATE_NONE, RATE_QUARTER, RATE_HALF, RATE_FULL, NO_SLOT}

// The shared traversal's instance filters (the static cache's static-only and moving-only rays)
// ask the split what moved. naga_oil applies an override only from the entry shader (or an
// additional import), so it is here rather than in static_cache.wgsl.
override fn gilab::bvh::instance_moves(at: u32) -> bool {
    return record_dynamic(at);
}

var<workgroup> wg_depth: array<f32, 256>;
// Traced visibility per pixel (fractional where the shadow cache averages a cell), NOT_TRACED
// where the pixel traced no ray for the light. Plain floats, not bit masks: lavapipe runs a
// workgroup atomic as a scalar loop over the lanes, and the reconstruction and the rates read
// up to 36 of these per pixel and light (docs/performance.md).
var<workgroup> wg_visf: array<f32, 256>;
const NOT_TRACED: f32 = -1.0;
// Per 2x2 quad: its traced pixels, and (<< 8) those that saw the light: the rates' 3x3 quad
// neighbourhoods read 9 of these instead of 36 pixels.
var<workgroup> wg_quad: array<u32, 64>;
var<workgroup> wg_rates: array<atomic<u32>, 4>;
// This light's shadow rays that traverse, queued by their pixels (step 1): the ray and its
// visibility plan (pack_plan) by pixel, the pixels in queue order, their count. And the rays
// traced for each pixel by whichever invocation traced them (the debug view's count per pixel).
var<workgroup> wg_ray: array<RaySegment, 256>;
var<workgroup> wg_plan: array<vec2<u32>, 256>;
var<workgroup> wg_queue: array<u32, 256>;
// A queue entry's flag: a skipped pixel's own ray (step 2 found no traced sample).
const SKIPPED: u32 = 0x10000u;
var<workgroup> wg_queued: atomic<u32>;
var<workgroup> wg_pixel_rays: array<u32, 256>;
var<workgroup> wg_red: array<f32, 256>;
var<workgroup> wg_count: u32;
var<workgroup> wg_valid: atomic<u32>;

fn traced_bit(li: u32) -> bool {
    return wg_visf[li] >= 0.0;
}

// Traced and seen the light (visibility at least a half).
fn vis_bit(li: u32) -> bool {
    return wg_visf[li] >= 0.5;
}

fn local_index(x: u32, y: u32) -> u32 {
    return y * TILE + x;
}

// Depth weight of a sample at depth zs for a pixel at depth z.
fn depth_weight(z: f32, zs: f32) -> f32 {
    return exp(-abs(z - zs) / (params.border_depth * z + 1e-6));
}

// Step 2: a skipped pixel's visibility from the traced samples around it, as the sum of the
// weighted samples and the sum of the weights. Quarter rate: the traced top-left samples of
// this and the neighbouring quads (bilinear x depth weights); half rate on a flat quad: the
// diagonal pair; else (or nothing usable) the traced sample of the quad nearest in depth. The
// weights depend only on which pixels trace (wg_visf >= 0) and their depths, so before
// tracing the pass knows which skipped pixels find no sample (weight 0) and trace their own.
fn reconstruct(rate: u32, border: bool, qx: u32, qy: u32, lid: vec2<u32>, z: f32) -> vec2<f32> {
    var sum = 0.0;
    var wsum = 0.0;
    if rate == RATE_QUARTER {
        for (var k = 0u; k < 4u; k++) {
            let sx = 2u * qx + 2u * (k & 1u);
            let sy = 2u * qy + 2u * (k / 2u);
            if sx < TILE && sy < TILE {
                let sl = local_index(sx, sy);
                if traced_bit(sl) {
                    let w = (1.0 - abs(f32(sx) - f32(lid.x)) * 0.5) * (1.0 - abs(f32(sy) - f32(lid.y)) * 0.5) * depth_weight(z, wg_depth[sl]);
                    sum += w * wg_visf[sl];
                    wsum += w;
                }
            }
        }
    } else if rate == RATE_HALF && !border {
        for (var k = 0u; k < 2u; k++) {
            let sl = local_index(2u * qx + k, 2u * qy + k);
            if traced_bit(sl) {
                let w = depth_weight(z, wg_depth[sl]);
                sum += w * wg_visf[sl];
                wsum += w;
            }
        }
    }
    if wsum <= 1e-6 {
        var best = 1e30;
        for (var k = 0u; k < 4u; k++) {
            let sl = local_index(2u * qx + (k & 1u), 2u * qy + k / 2u);
            let dz = abs(wg_depth[sl] - z);
            if traced_bit(sl) && dz < best {
                best = dz;
                sum = wg_visf[sl];
                wsum = 1.0;
            }
        }
    }
    return vec2<f32>(sum, wsum);
}

// Reduces wg_red over the workgroup (sum); every invocation must call it.
fn reduce_sum(li: u32, v: f32) -> f32 {
    wg_red[li] = v;
    workgroupBarrier();
    for (var s = 128u; s > 0u; s >>= 1u) {
        if li < s {
            wg_red[li] += wg_red[li + s];
        }
        workgroupBarrier();
    }
    let total = wg_red[0];
    workgroupBarrier();
    return total;
}

@compute @workgroup_size(16, 16, 1)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    var counts = no_counts();
    let tile = wid.y * params.tiles_x + wid.x;
    let px = wid.xy * TILE + lid.xy;
    let inside = px.x < frame.size.x && px.y < frame.size.y;
    let idx = px.y * frame.size.x + px.x;
    var valid = false;
    var s = current_surface(0u);
    if inside {
        s = current_surface(idx);
        valid = s.pos.w > 0.5;
    }
    let base = list_base(parity(), tile);
    if li == 0u {
        wg_count = list_count(base);
        atomicStore(&wg_valid, 0u);
    }
    if li < 4u {
        atomicStore(&wg_rates[li], 0u);
    }
    if li == 0u {
        atomicStore(&wg_queued, 0u);
    }
    wg_pixel_rays[li] = 0u;
    wg_depth[li] = select(-1.0, s.wo_dist.w, valid);
    workgroupBarrier();
    if valid {
        atomicAdd(&wg_valid, 1u);
    }
    // The quad: which corner this pixel is, border or flat, its min- and max-depth corners.
    let qx = lid.x / 2u;
    let qy = lid.y / 2u;
    let quad = qy * 8u + qx;
    let corner = (lid.y & 1u) * 2u + (lid.x & 1u);
    var zmin = 1e30;
    var zmax = -1.0;
    var cmin = 0u;
    var cmax = 0u;
    var quad_valid = 0u;
    for (var c = 0u; c < 4u; c++) {
        let z = wg_depth[local_index(2u * qx + (c & 1u), 2u * qy + c / 2u)];
        if z >= 0.0 {
            quad_valid += 1u;
            if z < zmin {
                zmin = z;
                cmin = c;
            }
            if z > zmax {
                zmax = z;
                cmax = c;
            }
        }
    }
    let border = (quad_valid > 0u && quad_valid < 4u) || (quad_valid == 4u && zmax - zmin > params.border_depth * zmin);
    let z = wg_depth[li];
    let p = s.pos.xyz;
    let ng = s.geo_specular.xyz;
    let n = s.normal_alpha.xyz;
    let wo = s.wo_dist.xyz;
    let material = surface_material(s);
    // Receivers on moving instances trace the whole scene (the static/dynamic split).
    let moves = valid && receiver_dynamic(u32(s.prev_pos.w));
    var rng = rng_init(px, frame.sample_offset, STREAM_CALLISTO_LIGHT, frame.seed);
    let prev_segment = 1u - parity();
    // Punctual lights (exact unshadowed light): shadowed and unshadowed, for the shadow mask.
    var shadowed = vec3<f32>(0.0);
    var unshadowed = vec3<f32>(0.0);
    // Sampled lights (emissive triangles, the tail): shadowed only.
    var sampled = vec3<f32>(0.0);
    var rays = 0u;
    var quad_rate = RATE_NONE;
    let mean_scene = stats[0];
    let count = workgroupUniformLoad(&wg_count);
    let had_list = tile_lists[list_base(prev_segment, tile)] != 0u;
    let valid_pixels = f32(max(atomicLoad(&wg_valid), 1u));
    for (var slot = 0u; slot < count; slot++) {
        let light = tile_lists[base + 1u + slot];
        // 1. This quad's rate for the light, decided last frame.
        var rate = RATE_FULL;
        switch params.rate_mode {
            case 2u: {
                rate = RATE_HALF;
            }
            case 3u: {
                rate = RATE_QUARTER;
            }
            case 0u: {
                let prev = find_slot(prev_segment, tile, light);
                if prev != NO_SLOT {
                    rate = max(get_rate(prev_segment, tile, prev, quad), RATE_QUARTER);
                } else if had_list {
                    // A light new to a tile that had a list last frame (it came into range,
                    // often by the jitter of the depth bounds): half rate until its variance
                    // is known; after a reset (no list) full rate.
                    rate = RATE_HALF;
                }
            }
            default: {}
        }
        var traced = true;
        if rate == RATE_QUARTER {
            traced = corner == 0u;
        } else if rate == RATE_HALF {
            traced = select(corner == 0u || corner == 3u, corner == cmin || corner == cmax, border);
        }
        // The light's unshadowed contribution at this pixel (one sample on an area light).
        var c = vec3<f32>(0.0);
        let ls = eval_light_point(light, sample_triangle(rand_pair(&rng)), p);
        if valid && ls.valid && dot(ls.wi, ng) > 0.0 && (ls.is_delta || ls.area_pdf > 0.0) {
            let e = bsdf_eval(material, n, wo, ls.wi);
            let scale = select(light_at(light).pmf / ls.area_pdf, 1.0, ls.is_delta);
            c = e.f * max(dot(n, ls.wi), 0.0) * ls.radiance * ls.geom * scale;
        }
        let lit = any(c > vec3<f32>(0.0));
        let trace_here = traced && lit;
        // Which pixels trace (their visibility comes after the queue).
        wg_visf[li] = select(NOT_TRACED, 0.0, trace_here);
        if valid {
            quad_rate = max(quad_rate, rate);
        }
        workgroupBarrier();
        // A pixel's own ray: where it traces, and where it is skipped but step 2 will find no
        // traced sample around it.
        var own = trace_here;
        if lit && !trace_here {
            own = !(reconstruct(rate, border, qx, qy, lid.xy, z).y > 0.0);
        }
        var own_vis = 0.0;
        var queued = false;
        if own {
            let seg = light_shadow_ray(p, ng, ls);
            let plan = plan_visibility(light, seg, p, ng, z, moves);
            // NO_TRACE: the cell's cached visibility, and nothing moving in the way.
            own_vis = plan.vis;
            if plan.instances != NO_TRACE {
                wg_ray[li] = seg;
                wg_plan[li] = pack_plan(plan);
                wg_queue[atomicAdd(&wg_queued, 1u)] = li | select(0u, SKIPPED, !trace_here);
                queued = true;
            }
        }
        workgroupBarrier();
        // The queue, one ray per invocation (the same visibility whichever invocation traces
        // it: the plan and the ray are the pixel's). A skipped pixel's visibility goes to
        // wg_red (free until this light's reduction), so that step 2 never reads it as traced.
        if li < atomicLoad(&wg_queued) {
            let entry = wg_queue[li];
            let owner = entry & ~SKIPPED;
            var traced_rays = 0u;
            let v = finish_visibility(unpack_plan(wg_plan[owner]), wg_ray[owner], &traced_rays);
            wg_pixel_rays[owner] += traced_rays;
            if (entry & SKIPPED) != 0u {
                wg_red[owner] = v;
            } else {
                wg_visf[owner] = v;
            }
        }
        if trace_here && !queued {
            wg_visf[li] = own_vis;
        }
        workgroupBarrier();
        if li == 0u {
            // Read by every invocation before the barrier above; the next light queues after
            // this light's reduction barriers.
            atomicStore(&wg_queued, 0u);
        }
        var vis = 0.0;
        if trace_here {
            vis = wg_visf[li];
        } else if own {
            vis = select(own_vis, wg_red[li], queued);
        }
        if li < 64u {
            var q = 0u;
            for (var cc = 0u; cc < 4u; cc++) {
                let sl = local_index(2u * (li % 8u) + (cc & 1u), 2u * (li / 8u) + cc / 2u);
                q += select(0u, 1u, traced_bit(sl)) + select(0u, 256u, vis_bit(sl));
            }
            // Read after the reduction's first barrier (step 4).
            wg_quad[li] = q;
        }
        // 2. Bilateral reconstruction of a skipped pixel (its own ray's visibility, above,
        // where no traced sample is usable).
        if lit && !trace_here {
            let r = reconstruct(rate, border, qx, qy, lid.xy, z);
            if r.y > 0.0 {
                vis = r.x / r.y;
            }
        }
        if ls.is_delta {
            shadowed += c * vis;
            unshadowed += c;
        } else {
            sampled += c * vis;
        }
        // 4. Next frame's rates for this light: variance of the traced visibility over the
        // quad and its 8 neighbours, weighted by the light's perceptual importance.
        let tile_lum = reduce_sum(li, luminance(c)) / valid_pixels;
        if li < 64u {
            let gx = li % 8u;
            let gy = li / 8u;
            var counts = 0u;
            for (var oy = -1; oy <= 1; oy++) {
                for (var ox = -1; ox <= 1; ox++) {
                    let nx = i32(gx) + ox;
                    let ny = i32(gy) + oy;
                    if nx < 0 || ny < 0 || nx >= 8 || ny >= 8 {
                        continue;
                    }
                    counts += wg_quad[u32(ny) * 8u + u32(nx)];
                }
            }
            // Traced samples, and those that saw the light (whole numbers: exact in f32).
            let m = f32(counts & 0xffu);
            let k = f32(counts >> 8u);
            var variance = 0.0;
            if m >= 2.0 {
                let mean = k / m;
                variance = mean * (1.0 - mean);
            }
            var weight = 1.0;
            if params.perceptual > 0.0 && mean_scene > 0.0 {
                weight = min(1.0, tile_lum / (mean_scene * params.perceptual));
            }
            let v = variance * weight;
            var r = RATE_QUARTER;
            if v > params.full_threshold {
                r = RATE_FULL;
            } else if v > params.half_threshold {
                r = RATE_HALF;
            }
            atomicOr(&wg_rates[li / 16u], r << (2u * (li % 16u)));
        }
        workgroupBarrier();
        if li < 4u {
            rates[rate_base(parity(), tile, slot) + li] = atomicExchange(&wg_rates[li], 0u);
        }
        // No barrier here: the next light's first writes (wg_visf, then wg_rates after its
        // reduction's barriers) come after every read of this light's.
    }
    // 5. The tail: lights outside the list (beyond their range, left out of a full list), by
    // `tail_samples` samples picked by power from the whole pool; a pick that is in the list
    // adds nothing (the list has it exactly), so the sum over list and tail is unbiased.
    if valid && light_pool.count > 0u {
        for (var k = 0u; k < params.tail_samples; k++) {
            let light = select_light(rand(&rng));
            let b = rand_pair(&rng);
            if find_slot(parity(), tile, light) != NO_SLOT {
                continue;
            }
            let ls = eval_light_point(light, sample_triangle(b), p);
            if !ls.valid || dot(ls.wi, ng) <= 0.0 || ls.area_pdf <= 0.0 {
                continue;
            }
            let e = bsdf_eval(material, n, wo, ls.wi);
            let c = e.f * max(dot(n, ls.wi), 0.0) * ls.radiance * ls.geom / (ls.area_pdf * f32(params.tail_samples));
            if any(c > vec3<f32>(0.0)) {
                sampled += c * split_visibility(light, light_shadow_ray(p, ng, ls), p, ng, z, moves, &rays);
            }
        }
    }
    // The rays queued for this pixel (each written by one invocation per light, before the
    // reduction's barriers).
    rays += wg_pixel_rays[li];
    counts[RAY_SHADOW] += rays;
    let tile_direct = reduce_sum(li, luminance(shadowed + sampled));
    if li == 0u {
        stats[1u + tile] = tile_direct;
    }
    if inside {
        current[idx] = vec4<f32>(shadowed, 0.0);
        current[params.pixels + idx] = vec4<f32>(unshadowed, 0.0);
        current[2u * params.pixels + idx] = vec4<f32>(sampled, 0.0);
        debug_out[idx] = vec4<f32>(f32(quad_rate), f32(rays), f32(count), 0.0);
        debug_out[params.pixels + idx] = vec4<f32>(f32(tile_lists[base] >> 16u), 0.0, 0.0, 0.0);
    }
    flush_counts(li, counts);
}
