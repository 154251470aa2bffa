// Callisto shadows pass 1, one workgroup per 16x16 screen tile: reduce the tile's depth bounds
// (min/max view depth), the bounding box of its surface points and its normal cone, then test
// every light of the pool against them and write the tile's compacted light list, sorted by
// light index (a workgroup prefix sum keeps the order, so next frame finds a light's slot by
// binary search). Tests, as in the seed: the light's range sphere against the tile frustum cut
// to the depth bounds (and against the points' box), then cone culling: the tile's normal cone
// against the cone from the tile to the light (and the emitter's own side for one-sided
// triangles). Directional lights have no range: only the cone test applies.
#import gilab::frame::frame
#import gilab::primary::current_surface
#import gilab::scene::{light_pool, light_at}
#import gilab::callisto::{params, tile_lists, list_base, parity, light_bounds, LightBounds, float_key, key_float, TILE}

// 0..2: point box min/max xyz; 3: view depth.
var<workgroup> wg_min: array<atomic<u32>, 4>;
var<workgroup> wg_max: array<atomic<u32>, 4>;
var<workgroup> wg_normal: array<atomic<i32>, 3>;
var<workgroup> wg_min_cos: atomic<u32>;
var<workgroup> wg_valid: atomic<u32>;
var<workgroup> wg_scan: array<u32, 256>;
var<workgroup> wg_total: u32;
var<workgroup> wg_hist: array<atomic<u32>, 32>;
var<workgroup> wg_min_bin: u32;

struct TileBounds {
    box_min: vec3<f32>,
    box_max: vec3<f32>,
    z_min: f32,
    z_max: f32,
    axis: vec3<f32>,
    // Sine of the normal cone's half angle (>= 1: the cone spans more than a hemisphere).
    sin_half: f32,
    // ndc bounds of the tile.
    ndc_min: vec2<f32>,
    ndc_max: vec2<f32>,
}

fn sphere_in_frustum(t: TileBounds, c: vec3<f32>, r: f32) -> bool {
    let rel = c - frame.camera_pos.xyz;
    let tx = length(frame.camera_right.xyz);
    let ty = length(frame.camera_up.xyz);
    let a = dot(rel, frame.camera_right.xyz) / tx;
    let b = dot(rel, frame.camera_up.xyz) / ty;
    let z = dot(rel, frame.camera_forward.xyz);
    if z < t.z_min - r || z > t.z_max + r {
        return false;
    }
    // Side planes through the eye: a = k z with k = ndc * tan.
    let kl = t.ndc_min.x * tx;
    let kr = t.ndc_max.x * tx;
    let kb = t.ndc_min.y * ty;
    let kt = t.ndc_max.y * ty;
    if (a - kl * z) / sqrt(1.0 + kl * kl) < -r || (kr * z - a) / sqrt(1.0 + kr * kr) < -r {
        return false;
    }
    if (b - kb * z) / sqrt(1.0 + kb * kb) < -r || (kt * z - b) / sqrt(1.0 + kt * kt) < -r {
        return false;
    }
    return true;
}

// Importance bins: a light's bound on the irradiance it can give the tile, I / (d - extent)^2
// at the tile box's nearest point, in factors of two (bin 16 is 1 W/m^2); directional lights
// get the top bin. A list that would overflow keeps the lights of the highest bins.
const BINS: u32 = 32u;

fn importance_bin(t: TileBounds, l: LightBounds) -> u32 {
    if l.directional {
        return BINS - 1u;
    }
    let q = clamp(l.centre, t.box_min, t.box_max);
    let d = max(length(q - l.centre) - l.extent, 1e-3);
    let score = log2(max(l.intensity, 1e-30) / (d * d));
    return u32(clamp(i32(floor(score)) + 16, 0, i32(BINS) - 1));
}

// Whether light i can light the tile.
fn light_reaches(t: TileBounds, i: u32, l: LightBounds) -> bool {
    if light_at(i).pmf <= 0.0 {
        return false;
    }
    let centre = 0.5 * (t.box_min + t.box_max);
    let tile_radius = 0.5 * length(t.box_max - t.box_min);
    if l.directional {
        return params.cone_culling == 0u || t.sin_half >= 1.0 || dot(t.axis, l.dir) > -t.sin_half;
    }
    if l.radius >= 0.0 {
        let q = clamp(l.centre, t.box_min, t.box_max);
        if dot(q - l.centre, q - l.centre) > l.radius * l.radius {
            return false;
        }
        if !sphere_in_frustum(t, l.centre, l.radius) {
            return false;
        }
    }
    if params.cone_culling == 0u {
        return true;
    }
    // One-sided emitter: the whole tile box behind its plane sees no light.
    if l.one_sided {
        let support = select(t.box_min, t.box_max, l.normal > vec3<f32>(0.0));
        if dot(support - l.centre, l.normal) <= 0.0 {
            return false;
        }
    }
    // Tile normals against the directions to the light: some N.L > 0 is possible only if the
    // angle between the normal axis and the tile-to-light direction is below 90 degrees plus
    // both cones' half angles.
    if t.sin_half >= 1.0 {
        return true;
    }
    let d = l.centre - centre;
    let dist = length(d);
    let spread = tile_radius + l.extent;
    if dist <= spread {
        return true;
    }
    let sin_l = spread / dist;
    let cos_l = sqrt(max(1.0 - sin_l * sin_l, 0.0));
    let cos_n = sqrt(max(1.0 - t.sin_half * t.sin_half, 0.0));
    // sin of the sum of both half angles; >= 1 once the sum passes 90 degrees.
    let sin_sum = t.sin_half * cos_l + cos_n * sin_l;
    let cos_sum = cos_n * cos_l - t.sin_half * sin_l;
    if cos_sum <= 0.0 {
        return true;
    }
    return dot(t.axis, d / dist) > -sin_sum;
}

@compute @workgroup_size(16, 16, 1)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let tile = wid.y * params.tiles_x + wid.x;
    if li < 4u {
        atomicStore(&wg_min[li], 0xffffffffu);
        atomicStore(&wg_max[li], 0u);
    }
    if li < 3u {
        atomicStore(&wg_normal[li], 0);
    }
    if li == 0u {
        atomicStore(&wg_min_cos, 0xffffffffu);
        atomicStore(&wg_valid, 0u);
        wg_total = 0u;
        wg_min_bin = 0u;
    }
    if li < BINS {
        atomicStore(&wg_hist[li], 0u);
    }
    workgroupBarrier();
    let px = wid.xy * TILE + lid.xy;
    var valid = false;
    var n = vec3<f32>(0.0);
    if px.x < frame.size.x && px.y < frame.size.y {
        let s = current_surface(px.y * frame.size.x + px.x);
        if s.pos.w > 0.5 {
            valid = true;
            n = s.normal_alpha.xyz;
            let p = s.pos.xyz;
            let z = dot(p - frame.camera_pos.xyz, frame.camera_forward.xyz);
            let v = vec4<f32>(p, z);
            for (var k = 0u; k < 4u; k++) {
                atomicMin(&wg_min[k], float_key(v[k]));
                atomicMax(&wg_max[k], float_key(v[k]));
            }
            let q = vec3<i32>(round(n * 4096.0));
            atomicAdd(&wg_normal[0], q.x);
            atomicAdd(&wg_normal[1], q.y);
            atomicAdd(&wg_normal[2], q.z);
            atomicAdd(&wg_valid, 1u);
        }
    }
    workgroupBarrier();
    let nsum = vec3<f32>(f32(atomicLoad(&wg_normal[0])), f32(atomicLoad(&wg_normal[1])), f32(atomicLoad(&wg_normal[2])));
    var axis = vec3<f32>(0.0, 0.0, 1.0);
    if dot(nsum, nsum) > 0.0 {
        axis = normalize(nsum);
    }
    if valid {
        atomicMin(&wg_min_cos, float_key(dot(n, axis)));
    }
    workgroupBarrier();
    var t: TileBounds;
    t.box_min = vec3<f32>(key_float(atomicLoad(&wg_min[0])), key_float(atomicLoad(&wg_min[1])), key_float(atomicLoad(&wg_min[2])));
    t.box_max = vec3<f32>(key_float(atomicLoad(&wg_max[0])), key_float(atomicLoad(&wg_max[1])), key_float(atomicLoad(&wg_max[2])));
    t.z_min = key_float(atomicLoad(&wg_min[3]));
    t.z_max = key_float(atomicLoad(&wg_max[3]));
    t.axis = axis;
    let min_cos = key_float(atomicLoad(&wg_min_cos));
    // Half angle slightly widened against the fixed-point normal sum.
    let c = min_cos - 0.01;
    t.sin_half = select(sqrt(max(1.0 - c * c, 0.0)), 1.0, c <= 0.0);
    let size = vec2<f32>(frame.size);
    let lo = vec2<f32>(wid.xy * TILE) / size;
    let hi = min(vec2<f32>((wid.xy + 1u) * TILE) / size, vec2<f32>(1.0));
    t.ndc_min = vec2<f32>(2.0 * lo.x - 1.0, 1.0 - 2.0 * hi.y);
    t.ndc_max = vec2<f32>(2.0 * hi.x - 1.0, 1.0 - 2.0 * lo.y);
    let any_valid = workgroupUniformLoad(&wg_valid) > 0u;
    let base = list_base(parity(), tile);
    let count = select(0u, light_pool.count, any_valid);
    // Round 0 lists every light that reaches the tile and histograms their importance bins; if
    // the list overflowed, round 1 lists again only the lights of the highest bins that fit.
    var found = 0u;
    for (var round = 0u; round < 2u; round++) {
        let min_bin = workgroupUniformLoad(&wg_min_bin);
        if round == 1u && min_bin == 0u {
            break;
        }
        if li == 0u {
            wg_total = 0u;
        }
        workgroupBarrier();
        for (var first = 0u; first < count; first += 256u) {
            let i = first + li;
            var hit = 0u;
            if i < count {
                let l = light_bounds(i);
                if light_reaches(t, i, l) {
                    let b = importance_bin(t, l);
                    if round == 0u {
                        atomicAdd(&wg_hist[b], 1u);
                    }
                    if b >= min_bin {
                        hit = 1u;
                    }
                }
            }
            wg_scan[li] = hit;
            workgroupBarrier();
            // Inclusive Hillis-Steele scan.
            for (var off = 1u; off < 256u; off *= 2u) {
                var v = wg_scan[li];
                if li >= off {
                    v += wg_scan[li - off];
                }
                workgroupBarrier();
                wg_scan[li] = v;
                workgroupBarrier();
            }
            let slot = wg_total + wg_scan[li] - 1u;
            if hit == 1u && slot < params.max_lights {
                tile_lists[base + 1u + slot] = i;
            }
            workgroupBarrier();
            if li == 255u {
                wg_total += wg_scan[255];
            }
            workgroupBarrier();
        }
        if round == 0u && li == 0u {
            found = wg_total;
            if wg_total > params.max_lights {
                // The lowest bin from which the lights above fit the list.
                var kept = 0u;
                var b = BINS;
                while b > 0u && kept + atomicLoad(&wg_hist[b - 1u]) <= params.max_lights {
                    kept += atomicLoad(&wg_hist[b - 1u]);
                    b -= 1u;
                }
                // Keep at least the top bin's lights (truncated if even they overflow).
                wg_min_bin = min(b, BINS - 1u);
            }
        }
        workgroupBarrier();
    }
    if li == 0u {
        // Low 16 bits: the list's length; high 16: lights that reached the tile but were left
        // out of a full list (the least important ones).
        let listed = min(wg_total, params.max_lights);
        tile_lists[base] = listed | (min(found - listed, 0xffffu) << 16u);
    }
}
