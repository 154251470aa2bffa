// GPU display of one pane: tonemapped radiance or a log10 heatmap (variance, relMSE, samples, a debug channel) as sRGB RGBA8 rows for the egui texture, plus a histogram of the heatmap's log10 values from which the next frame's range comes.
#import gilab::compare::{HIST_BINS, hist_bin, log_ten}

struct DisplayParams {
    size: vec2<u32>,
    // 0 radiance, 1 variance, 2 relMSE, 3 samples, 4 debug value, 5 debug id
    mode: u32,
    // 0 ACES (Narkowicz), 1 Reinhard, 2 linear clamp
    tone_operator: u32,
    exposure_scale: f32,
    range_lo: f32,
    range_hi: f32,
    channel: u32,
    samples: f32,
    row_words: u32,
    pad0: u32,
    pad1: u32,
}

@group(0) @binding(0) var<uniform> params: DisplayParams;
@group(0) @binding(1) var<storage, read> mean: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> m2: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> reference: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> debug_data: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> out_rgba: array<u32>;
@group(0) @binding(6) var<storage, read_write> histogram: array<atomic<u32>>;
// The viridis map sampled at 1024 points (compare/heatmap.rs builds it), packed RGBA8.
@group(0) @binding(7) var<storage, read> colour_map: array<u32>;

const MAGENTA: u32 = 0xffff00ffu;
const COLOUR_MAP_LAST: f32 = 1023.0;

var<workgroup> local_hist: array<atomic<u32>, HIST_BINS>;

fn curve(x_in: f32) -> f32 {
    let x = max(x_in, 0.0);
    switch params.tone_operator {
        case 1u: { return x / (1.0 + x); }
        case 2u: { return min(x, 1.0); }
        default: { return clamp((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0); }
    }
}

fn linear_to_srgb(c: f32) -> f32 {
    if c <= 0.0031308 {
        return c * 12.92;
    }
    return 1.055 * pow(c, 1.0 / 2.4) - 0.055;
}

fn to_u8(x: f32) -> u32 {
    return u32(clamp(x * 255.0 + 0.5, 0.0, 255.0));
}

fn finite(v: f32) -> bool {
    return v == v && abs(v) <= 3.4028235e38;
}

fn tonemap(l: vec3<f32>) -> u32 {
    if !(finite(l.x) && finite(l.y) && finite(l.z)) {
        return MAGENTA;
    }
    let s = l * params.exposure_scale;
    let r = to_u8(linear_to_srgb(curve(s.x)));
    let g = to_u8(linear_to_srgb(curve(s.y)));
    let b = to_u8(linear_to_srgb(curve(s.z)));
    return r | (g << 8u) | (b << 16u) | (255u << 24u);
}

fn heat(v: f32) -> u32 {
    if !finite(v) {
        return MAGENTA;
    }
    var t = 0.0;
    if v > 0.0 {
        t = (log_ten(v) - params.range_lo) / max(params.range_hi - params.range_lo, 1e-6);
    }
    let i = u32(clamp(t, 0.0, 1.0) * COLOUR_MAP_LAST + 0.5);
    return colour_map[i];
}

// Integer hash (lowbias32): neighbouring ids get unrelated colours.
fn hash_id(x_in: u32) -> u32 {
    var x = x_in;
    x ^= x >> 16u;
    x *= 0x7feb352du;
    x ^= x >> 15u;
    x *= 0x846ca68bu;
    x ^= x >> 16u;
    return x;
}

fn id_colour(id: f32) -> u32 {
    if !(id >= 1.0) {
        return 0xff000000u;
    }
    let h = hash_id(u32(id));
    let r = 64u + (h & 0xbfu);
    let g = 64u + ((h >> 8u) & 0xbfu);
    let b = 64u + ((h >> 16u) & 0xbfu);
    return r | (g << 8u) | (b << 16u) | (255u << 24u);
}

// The scalar a heatmap mode shows (as compare/heatmap.rs and metrics.rs compute it).
fn heat_value(i: u32, pixels: u32) -> f32 {
    switch params.mode {
        case 1u: {
            let n = mean[i].w;
            var d = 0.0;
            if n > 1.0 {
                d = 1.0 / (n - 1.0);
            }
            let v = m2[i];
            return (v.x * d + v.y * d + v.z * d) / 3.0;
        }
        case 2u: {
            let x = mean[i].xyz;
            let y = reference[i].xyz;
            let d = x - y;
            let r = d * d / (y * y + vec3<f32>(0.01));
            return (r.x + r.y + r.z) / 3.0;
        }
        case 3u: {
            return params.samples;
        }
        default: {
            let v = debug_data[(params.channel / 4u) * pixels + i];
            return v[params.channel % 4u];
        }
    }
}

@compute @workgroup_size(16, 16, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let histogram_on = params.mode == 1u || params.mode == 2u || params.mode == 4u;
    if histogram_on {
        for (var b = li; b < HIST_BINS; b += 256u) {
            atomicStore(&local_hist[b], 0u);
        }
    }
    workgroupBarrier();
    let inside = gid.x < params.size.x && gid.y < params.size.y;
    if inside {
        let pixels = params.size.x * params.size.y;
        let i = gid.y * params.size.x + gid.x;
        var rgba = 0u;
        if params.mode == 0u {
            rgba = tonemap(mean[i].xyz);
        } else {
            let v = heat_value(i, pixels);
            if params.mode == 5u {
                rgba = id_colour(v);
            } else {
                rgba = heat(v);
                if histogram_on && finite(v) && v > 0.0 {
                    atomicAdd(&local_hist[hist_bin(v)], 1u);
                }
            }
        }
        out_rgba[gid.y * params.row_words + gid.x] = rgba;
    }
    workgroupBarrier();
    if histogram_on {
        for (var b = li; b < HIST_BINS; b += 256u) {
            let c = atomicLoad(&local_hist[b]);
            if c > 0u {
                atomicAdd(&histogram[b], c);
            }
        }
    }
}
