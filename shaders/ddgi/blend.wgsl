// DDGI probe update (src/techniques/ddgi): one workgroup per probe, one thread per four texels
// of its irradiance map (6 x 6) and one per seven texels of its distance map (14 x 14); the
// probe's blended rays are loaded into workgroup memory 232 at a time and every texel sums them:
// irradiance weighted by max(0, cos) (back-face rays left out), distance and distance² by
// max(0, cos)^50 (the paper's sharpness). The results replace a share 1 - h of the old maps,
// h = min(hysteresis, frames / (frames + 1)) (an average of every frame until the history
// reaches the paper's hysteresis; a new probe starts from its first frame). Then the borders
// are copied (octahedral wrap), and thread 0 relocates and classifies the probe from its
// fixed rays (JCGT 2021): more than a quarter back faces means it sits inside a wall (pushed
// through the nearest back face, and switched off); a front face nearer than min_frontface is
// moved away from; a probe whose fixed rays hit no surface within a spacing on every axis
// (at any distance outwards on the volume's outer sides, whose points beyond the last layer
// read it) lights nothing and is switched off. Offsets stay within 0.45 of a spacing.
#import gilab::math::PI
#import gilab::ddgi::{params, probes, ray_results, irradiance_texels, distance_texels, Probe, probes_per_cascade, rays_per_probe, slot_grid, spacing, ray_direction, texel_direction, irradiance_index, distance_index, has_flag, FIXED_RAYS, IRR_TEXELS, DIST_TEXELS, MISS_DISTANCE, STATE_ACTIVE, STATE_OFF, FLAG_RELOCATION, FLAG_CLASSIFICATION}

const CHUNK: u32 = 232u;
// Texels per thread: irradiance 6 x 6 = 9 threads x 4, distance 14 x 14 = 28 threads x 7.
const IRR_PER_THREAD: u32 = 4u;
const DIST_PER_THREAD: u32 = 7u;
const DISTANCE_SHARPNESS: f32 = 50.0;
const DISTANCE_MIN_COS: f32 = 0.86;
// More back faces than this share of the fixed rays: the probe is inside geometry.
const BACKFACE_SHARE: f32 = 0.25;
const MAX_OFFSET: f32 = 0.45;
const FRAMES_CAP: i32 = 1000000;

var<workgroup> chunk_dir: array<vec3<f32>, 232>;
var<workgroup> chunk_ray: array<vec4<f32>, 232>;

@compute @workgroup_size(232, 1, 1)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let slot = wid.y * 1024u + wid.x;
    if slot >= probes_per_cascade() * params.counts.w {
        return;
    }
    let g = slot_grid(slot);
    let c = u32(g.w);
    let sp = spacing(c);
    let record = probes[slot];
    let fresh = any(record.coord_frames.xyz != g.xyz);
    let blending = fresh || record.offset_state.w == STATE_ACTIVE;
    let frames = select(max(record.coord_frames.w, 0), 0, fresh);
    let h = min(params.hysteresis, f32(frames) / f32(frames + 1));
    let max_distance = params.max_distance * sp;
    let first = slot * rays_per_probe() + FIXED_RAYS;

    // Threads 0-8 own four irradiance texels each, threads 9-36 seven distance texels each
    // (one read of a ray from workgroup memory serves several texels: on lavapipe those reads,
    // not the dot products, were most of this pass); the others only stage rays.
    let irr_threads = IRR_TEXELS * IRR_TEXELS / IRR_PER_THREAD;
    let irr_thread = lid < irr_threads;
    let irr_first = IRR_PER_THREAD * lid;
    let dist_first = select(DIST_PER_THREAD * (lid - irr_threads), 0u, irr_thread);
    let dist_thread = !irr_thread && dist_first < DIST_TEXELS * DIST_TEXELS;
    var irr_dirs: array<vec3<f32>, 4>;
    var irr_sums: array<vec3<f32>, 4>;
    var irr_weights: array<f32, 4>;
    for (var q = 0u; q < IRR_PER_THREAD; q++) {
        irr_dirs[q] = texel_direction(irr_texel(irr_first + q), IRR_TEXELS);
    }
    var dist_dirs: array<vec3<f32>, 7>;
    var dist_sums: array<vec2<f32>, 7>;
    var dist_weights: array<f32, 7>;
    for (var q = 0u; q < DIST_PER_THREAD; q++) {
        dist_dirs[q] = texel_direction(dist_texel(dist_first + q), DIST_TEXELS);
    }
    // Uniform control flow for the barriers: every probe runs the loop; an off probe's rays
    // are not read and its maps not written.
    for (var base = 0u; base < params.rays; base += CHUNK) {
        let k = base + lid;
        if k < params.rays {
            chunk_dir[lid] = ray_direction(FIXED_RAYS + k);
            chunk_ray[lid] = ray_results[first + k];
        }
        workgroupBarrier();
        let count = min(CHUNK, params.rays - base);
        if blending && irr_thread {
            for (var j = 0u; j < count; j++) {
                let r = chunk_ray[j];
                if r.w >= 0.0 {
                    let d = chunk_dir[j];
                    for (var q = 0u; q < IRR_PER_THREAD; q++) {
                        let w = max(dot(irr_dirs[q], d), 0.0);
                        irr_sums[q] += w * r.xyz;
                        irr_weights[q] += w;
                    }
                }
            }
        } else if blending && dist_thread {
            for (var j = 0u; j < count; j++) {
                let d = chunk_dir[j];
                let t = min(abs(chunk_ray[j].w), max_distance);
                for (var q = 0u; q < DIST_PER_THREAD; q++) {
                    // cos^50 < 5e-4 below cos 0.86: those rays are skipped (no pow).
                    let cd = dot(dist_dirs[q], d);
                    if cd > DISTANCE_MIN_COS {
                        let w = pow(cd, DISTANCE_SHARPNESS);
                        dist_sums[q] += w * vec2<f32>(t, t * t);
                        dist_weights[q] += w;
                    }
                }
            }
        }
        workgroupBarrier();
    }
    // A probe without history (new, or switched on again) takes this frame whole; a texel no
    // ray reached is cleared rather than left with what the slot held before.
    if blending && irr_thread {
        for (var q = 0u; q < IRR_PER_THREAD; q++) {
            let reached = irr_weights[q] > 1e-6;
            if reached || frames == 0 {
                // Sum(L cos) / Sum(cos) over directions spread evenly on the sphere is E / pi.
                let at = irradiance_index(slot, irr_texel(irr_first + q) + vec2<u32>(1u));
                let e = select(vec3<f32>(0.0), PI * irr_sums[q] / max(irr_weights[q], 1e-6), reached);
                irradiance_texels[at] = vec4<f32>(mix(e, irradiance_texels[at].xyz, h), 1.0);
            }
        }
    } else if blending && dist_thread {
        for (var q = 0u; q < DIST_PER_THREAD; q++) {
            let reached = dist_weights[q] > 1e-6;
            if reached || frames == 0 {
                let at = distance_index(slot, dist_texel(dist_first + q) + vec2<u32>(1u));
                let m = select(vec2<f32>(0.0), dist_sums[q] / max(dist_weights[q], 1e-6), reached);
                distance_texels[at] = mix(m, distance_texels[at], h);
            }
        }
    }
    storageBarrier();
    workgroupBarrier();
    if blending {
        let n_irr = 4u * IRR_TEXELS + 4u;
        if lid < n_irr {
            let b = border_texel(lid, IRR_TEXELS);
            irradiance_texels[irradiance_index(slot, b.xy)] = irradiance_texels[irradiance_index(slot, b.zw)];
        } else if lid < n_irr + 4u * DIST_TEXELS + 4u {
            let b = border_texel(lid - n_irr, DIST_TEXELS);
            distance_texels[distance_index(slot, b.xy)] = distance_texels[distance_index(slot, b.zw)];
        }
    }
    if lid == 0u {
        probes[slot] = relocate_and_classify(slot, g.xyz, sp, record, fresh, blending, frames);
    }
}

// Interior texel k of the irradiance map, row by row.
fn irr_texel(k: u32) -> vec2<u32> {
    return vec2<u32>(k % IRR_TEXELS, k / IRR_TEXELS);
}

// Interior texel k of the distance map, row by row.
fn dist_texel(k: u32) -> vec2<u32> {
    return vec2<u32>(k % DIST_TEXELS, k / DIST_TEXELS);
}

// Border texel k of a map of n interior texels: where it is (xy) and the interior texel it
// copies (zw), so that bilinear reads across an edge see the octahedral wrap (an edge folds
// onto itself mirrored; a corner copies the opposite corner).
fn border_texel(k: u32, n: u32) -> vec4<u32> {
    if k < n {
        return vec4<u32>(1u + k, 0u, n - k, 1u);
    }
    if k < 2u * n {
        let i = k - n;
        return vec4<u32>(1u + i, n + 1u, n - i, n);
    }
    if k < 3u * n {
        let i = k - 2u * n;
        return vec4<u32>(0u, 1u + i, 1u, n - i);
    }
    if k < 4u * n {
        let i = k - 3u * n;
        return vec4<u32>(n + 1u, 1u + i, n, n - i);
    }
    switch k - 4u * n {
        case 0u: {
            return vec4<u32>(0u, 0u, n, n);
        }
        case 1u: {
            return vec4<u32>(n + 1u, 0u, 1u, n);
        }
        case 2u: {
            return vec4<u32>(0u, n + 1u, n, 1u);
        }
        default: {
            return vec4<u32>(n + 1u, n + 1u, 1u, 1u);
        }
    }
}

fn relocate_and_classify(slot: u32, g: vec3<i32>, sp: f32, record: Probe, fresh: bool, blending: bool, frames: i32) -> Probe {
    var back = 0u;
    var closest_back = MISS_DISTANCE;
    var back_dir = vec3<f32>(0.0);
    var closest_front = MISS_DISTANCE;
    var front_dir = vec3<f32>(0.0);
    var near_surface = false;
    for (var k = 0u; k < FIXED_RAYS; k++) {
        let t = ray_results[slot * rays_per_probe() + k].w;
        let d = ray_direction(k);
        if t < 0.0 {
            back += 1u;
            let tb = -t / 0.2;
            if tb < closest_back {
                closest_back = tb;
                back_dir = d;
            }
        } else if t < MISS_DISTANCE {
            if t < closest_front {
                closest_front = t;
                front_dir = d;
            }
            // Within a spacing on every axis; on an outer side of the volume, at any distance
            // that way (the points beyond the last layer read it).
            let v = d * t;
            let local = g - params.cascades[u32(slot_grid(slot).w)].base.xyz;
            let outer = (local == vec3<i32>(0) & v < vec3<f32>(0.0)) | (local == vec3<i32>(params.counts.xyz) - 1 & v > vec3<f32>(0.0));
            if all(abs(v) <= vec3<f32>(sp) | outer) {
                near_surface = true;
            }
        }
    }
    let inside = f32(back) > BACKFACE_SHARE * f32(FIXED_RAYS);
    var offset = select(record.offset_state.xyz, vec3<f32>(0.0), fresh);
    if has_flag(FLAG_RELOCATION) {
        let min_front = params.min_frontface * sp;
        if inside {
            offset += back_dir * (closest_back + 0.5 * min_front);
        } else if closest_front < min_front {
            offset -= front_dir * (min_front - closest_front);
        }
        offset = clamp(offset, vec3<f32>(-MAX_OFFSET * sp), vec3<f32>(MAX_OFFSET * sp));
    } else {
        offset = vec3<f32>(0.0);
    }
    var state = STATE_ACTIVE;
    if has_flag(FLAG_CLASSIFICATION) && (inside || !near_surface) {
        state = STATE_OFF;
    }
    // Blended this frame: one frame more of history. Off: none (switched on, it starts over).
    var f = 0;
    if blending && state == STATE_ACTIVE {
        f = min(frames + 1, FRAMES_CAP);
    }
    return Probe(vec4<f32>(offset, state), vec4<i32>(g, f));
}
