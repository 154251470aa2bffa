// Per pixel (full resolution): irradiance from the screen probes of its plane (the four uniform
// probes around it, bilinear x plane weights, and the adaptive probe of its cell), each probe's
// 64 equal-solid-angle cells integrated against the pixel's clamped cosine; then the seed's
// full-resolution temporal filter (history rejected on depth and normal, no neighbourhood clamp)
// and, after it, short-range contact AO traced in this frame's depth. `apply` shades with it.
#import gilab::frame::frame
#import gilab::math::{PI, luminance}
#import gilab::counters::{flush_counts, no_counts}
#import gilab::primary::{current_surface, previous_surface}
#import gilab::rng::{rng_init, rand_pair, STREAM_LUMEN_AO}
#import gilab::math::to_world
#import gilab::sampling::sample_cosine_hemisphere
#import gilab::tracing::{has_flag}
#import gilab::lumen::{gather_out, debug_out, FLAG_DEBUG}
#import gilab::equal_area::cell_dir
#import gilab::world_cache::world_lookup
#import gilab::lumen_probes::{pp, probe_data, pixel_data, load_probe, parity, probes_flag, history_valid, filtered_index, irradiance_index, uniform_neighbours, adaptive_map, plane_weight, tile_probe, tiles, spacing, NO_PROBE, PROBE_CELLS, PROBE_RES, PROBES_TEMPORAL, PROBES_CONTACT_AO, PROBES_WORLD_CACHE}

const AO_RAYS: u32 = 4u;
const AO_STEPS: u32 = 4u;

// Irradiance at normal n from a probe's cells: their radiance weighted by the clamped cosine at
// their centres, divided by the weights' sum and times pi (the integral of the clamped cosine),
// so that uniform light comes out exact whatever n. The plain quadrature (weights times the
// cells' 4 pi / 64 solid angle) is off by the 64 centres' layout: 6.25% low for normals along the
// octahedron's z axis, 3.2% high along x and y (Cornell's back wall and its other walls).
// Cells below the probe's own surface hold no light (its rays there stop at once) but a pixel
// whose normal leans away from the probe's (a curved surface) sees into them: they are left out
// of both sums rather than read as black (the white furnace, a sphere, lost 0.8% to them).
fn probe_irradiance(probe: u32, n: vec3<f32>) -> vec3<f32> {
    let g = load_probe(parity(), probe).geo;
    var e = vec3<f32>(0.0);
    var weight = 0.0;
    for (var j = 0u; j < PROBE_CELLS; j++) {
        let d = cell_dir(j, PROBE_RES, vec2<f32>(0.5));
        let c = max(dot(n, d), 0.0);
        if c > 0.0 && dot(d, g) > 0.0 {
            e += c * probe_data[filtered_index(probe, j)].xyz;
            weight += c;
        }
    }
    return e * PI / max(weight, 1e-6);
}

fn to_pixel(p: vec3<f32>) -> vec2<f32> {
    let c = frame.clip_from_world * vec4<f32>(p, 1.0);
    if c.w <= 0.0 {
        return vec2<f32>(-1.0);
    }
    let ndc = c.xy / c.w;
    return vec2<f32>((ndc.x * 0.5 + 0.5) * f32(frame.size.x), (0.5 - ndc.y * 0.5) * f32(frame.size.y));
}

// Fraction of AO_RAYS cosine rays not blocked within half a probe spacing on screen, marched in
// this frame's depth: the occlusion closer than the probes resolve.
fn contact_ao(pixel: vec2<u32>, p: vec3<f32>, n: vec3<f32>, dist: f32) -> f32 {
    let footprint = 2.0 * length(frame.camera_up.xyz) * dist / f32(frame.size.y);
    let radius = 0.5 * f32(spacing()) * footprint;
    var rng = rng_init(pixel, frame.frame_index, STREAM_LUMEN_AO, frame.seed);
    var open = 0.0;
    for (var r = 0u; r < AO_RAYS; r++) {
        let d = to_world(sample_cosine_hemisphere(rand_pair(&rng)), n);
        var blocked = false;
        for (var k = 1u; k <= AO_STEPS; k++) {
            let q = p + n * 0.5 * footprint + d * radius * f32(k) / f32(AO_STEPS);
            let f = to_pixel(q);
            if f.x < 0.0 || f.y < 0.0 || f.x >= f32(frame.size.x) || f.y >= f32(frame.size.y) {
                break;
            }
            let s = current_surface(u32(f.y) * frame.size.x + u32(f.x));
            let qd = distance(q, frame.camera_pos.xyz);
            if s.pos.w > 0.5 && s.wo_dist.w < qd - 0.02 * radius && qd - s.wo_dist.w < radius {
                blocked = true;
                break;
            }
        }
        open += select(1.0, 0.0, blocked);
    }
    return open / f32(AO_RAYS);
}

// The directions contact AO finds blocked are not black: they see nearby surfaces that reflect
// light too, and counting them as black darkened Cornell by 1.3% (issue 38). Jimenez et al.
// 2016's multi-bounce fit (GTAO) turns visibility v into ((a v + b) v + c) v per colour
// channel of the albedo, fitted to ray-traced interreflections: v = 1 stays 1, a white crease
// loses far less than v.
fn multi_bounce(v: f32, albedo: vec3<f32>) -> vec3<f32> {
    let a = 2.0404 * albedo - 0.3324;
    let b = -4.7951 * albedo + 0.6417;
    let c = 2.7552 * albedo + 0.6903;
    return max(vec3<f32>(v), ((a * v + b) * v + c) * v);
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    var counts = no_counts();
    if gid.x < frame.size.x && gid.y < frame.size.y {
        let idx = gid.y * frame.size.x + gid.x;
        let px = frame.size.x * frame.size.y;
        let s = current_surface(idx);
        var e = vec3<f32>(0.0);
        var debug = vec4<f32>(0.0);
        if s.pos.w > 0.5 {
            let n = s.normal_alpha.xyz;
            let nb = uniform_neighbours(gid.xy, s.pos.xyz, n, s.wo_dist.w);
            var sum = vec3<f32>(0.0);
            var weight = 0.0;
            for (var k = 0u; k < 4u; k++) {
                if nb.weight[k] > 1e-6 {
                    sum += nb.weight[k] * probe_irradiance(nb.probe[k], n);
                    weight += nb.weight[k];
                }
            }
            let cell = min(gid.xy / pp.adaptive.z, pp.adaptive.xy - 1u);
            let adaptive = adaptive_map(cell);
            if adaptive != NO_PROBE {
                let a = load_probe(parity(), adaptive);
                let w = plane_weight(s.pos.xyz, n, s.wo_dist.w, a.pos, a.normal);
                if w > 1e-6 {
                    sum += w * probe_irradiance(adaptive, n);
                    weight += w;
                }
            }
            if weight > 1e-6 {
                e = sum / weight;
            } else {
                // No probe on this plane (a sliver the adaptive probes missed): the nearest
                // valid uniform probe, whatever its plane.
                let t = min(gid.xy / spacing(), tiles() - 1u);
                let q = load_probe(parity(), tile_probe(t));
                if q.valid {
                    e = probe_irradiance(tile_probe(t), n);
                }
            }
            if probes_flag(PROBES_TEMPORAL) && history_valid() {
                let prev = vec2<i32>(floor(vec2<f32>(gid.xy) + 0.5 - s.motion));
                if all(prev >= vec2<i32>(0)) && all(prev < vec2<i32>(frame.size)) {
                    let pi = u32(prev.y) * frame.size.x + u32(prev.x);
                    let ps = previous_surface(pi);
                    if ps.pos.w > 0.5 && plane_weight(s.pos.xyz, n, s.wo_dist.w, ps.pos.xyz, ps.normal_alpha.xyz) > 0.5 {
                        let h = pixel_data[irradiance_index(1u - parity(), pi)];
                        let frames = min(h.w + 1.0, 255.0);
                        let alpha = max(1.0 / (frames + 1.0), pp.misc.w);
                        e = mix(h.xyz, e, alpha);
                        pixel_data[irradiance_index(parity(), idx)] = vec4<f32>(e, frames);
                    } else {
                        pixel_data[irradiance_index(parity(), idx)] = vec4<f32>(e, 0.0);
                    }
                } else {
                    pixel_data[irradiance_index(parity(), idx)] = vec4<f32>(e, 0.0);
                }
            } else {
                pixel_data[irradiance_index(parity(), idx)] = vec4<f32>(e, 0.0);
            }
            if probes_flag(PROBES_CONTACT_AO) {
                let albedo = s.base_metal.rgb * (1.0 - s.base_metal.w);
                e *= multi_bounce(contact_ao(gid.xy, s.pos.xyz, n, s.wo_dist.w), albedo);
            }
            if has_flag(FLAG_DEBUG) {
                // Placement: 1 on a uniform probe's pixel, 2 on an adaptive one's.
                let tile = min(gid.xy / spacing(), tiles() - 1u);
                let u = load_probe(parity(), tile_probe(tile));
                if u.valid && all(u.pixel == gid.xy) {
                    debug.x = 1.0;
                }
                if adaptive != NO_PROBE && all(load_probe(parity(), adaptive).pixel == gid.xy) {
                    debug.x = 2.0;
                }
                // The tile's probe drawn as its octahedral map over the tile.
                let local = (gid.xy % spacing()) * PROBE_RES / spacing();
                if u.valid {
                    debug.y = luminance(probe_data[filtered_index(tile_probe(tile), local.y * PROBE_RES + local.x)].xyz);
                    debug.z = probe_data[4u * (parity() * pp.grid.w + tile_probe(tile)) + 3u].z;
                }
                if probes_flag(PROBES_WORLD_CACHE) {
                    debug.w = luminance(world_lookup(s.pos.xyz + n * pp.misc.x, n, false).radiance);
                }
            }
        }
        gather_out[idx] = vec4<f32>(e, 1.0);
        if has_flag(FLAG_DEBUG) {
            debug_out[2u * px + idx] = debug;
        }
    }
    flush_counts(li, counts);
}
