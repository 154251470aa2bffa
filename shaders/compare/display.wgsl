// GPU display of one pane: tonemapped radiance (with the zone views) or a log10 heatmap (variance, relMSE, samples, a debug channel) as sRGB RGBA8 rows for the egui texture, plus a histogram of the heatmap's log10 values from which the next frame's range comes.
#import gilab::compare::{HIST_BINS, hist_bin, log_ten}

struct DisplayParams {
    size: vec2<u32>,
    // 0 radiance, 1 variance, 2 relMSE, 3 samples, 4 debug value, 5 debug id, 6 tone curve probe
    mode: u32,
    // 0 ACES (Narkowicz), 1 Reinhard, 2 linear clamp, 3 GT (Uchimura)
    tone_operator: u32,
    exposure_scale: f32,
    range_lo: f32,
    range_hi: f32,
    channel: u32,
    samples: f32,
    row_words: u32,
    // 0 normal, 1 zone strip, 2 zones per pixel, 3 curve regions (compare/tonemap.rs View)
    view: u32,
    // GT curve: P max brightness, a contrast, m linear start, l linear length, c black
    // tightness, b pedestal
    gt_p: f32,
    gt_a: f32,
    gt_m: f32,
    gt_l: f32,
    gt_c: f32,
    gt_b: f32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
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

// Where the GT curve's shoulder starts: S0 = m + l0, l0 = (P - m) l / a.
fn gt_shoulder_start() -> f32 {
    return params.gt_m + (params.gt_p - params.gt_m) * params.gt_l / params.gt_a;
}

// Uchimura's GT curve as published (compare/tonemap.rs `gt`): toe m (x/m)^c + b, linear
// m + a (x - m), shoulder P - (P - S1) e^(CP (x - S0)), blended by w0 = 1 - smoothstep(0, m, x),
// w2 = step(S0, x), w1 = 1 - w0 - w2.
fn gt_curve(x: f32) -> f32 {
    let p = params.gt_p;
    let a = params.gt_a;
    let m = params.gt_m;
    let l0 = (p - m) * params.gt_l / a;
    let s0 = m + l0;
    let s1 = m + a * l0;
    let c2 = a * p / (p - s1);
    let cp = -c2 / p;
    let t = clamp(x / m, 0.0, 1.0);
    let w0 = 1.0 - t * t * (3.0 - 2.0 * t);
    let w2 = select(0.0, 1.0, x >= s0);
    let w1 = 1.0 - w0 - w2;
    // Each part only where its weight is non-zero (0 * inf would be NaN for huge x).
    var y = 0.0;
    if w0 > 0.0 {
        var toe = params.gt_b;
        if x > 0.0 {
            toe += m * pow(x / m, params.gt_c);
        }
        y += toe * w0;
    }
    if w1 > 0.0 {
        y += (m + a * (x - m)) * w1;
    }
    if w2 > 0.0 {
        y += (p - (p - s1) * exp(cp * (x - s0))) * w2;
    }
    return y;
}

fn curve(x_in: f32) -> f32 {
    let x = max(x_in, 0.0);
    switch params.tone_operator {
        case 1u: { return x / (1.0 + x); }
        case 2u: { return min(x, 1.0); }
        case 3u: { return gt_curve(x); }
        default: { return clamp((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0); }
    }
}

// Zones (compare/tonemap.rs): 17, one stop apart, zone 8 centred on 18% grey.
const ZONES: u32 = 17u;
const MIDDLE_ZONE: u32 = 8u;
const MIDDLE_GREY: f32 = 0.18;

fn zone_centre(k: u32) -> f32 {
    return MIDDLE_GREY * exp2(f32(i32(k) - i32(MIDDLE_ZONE)));
}

fn zone_of(y: f32) -> u32 {
    if !(y > 0.0) {
        return 0u;
    }
    let z = floor(log2(y / MIDDLE_GREY) + f32(MIDDLE_ZONE) + 0.5);
    return u32(clamp(z, 0.0, f32(ZONES - 1u)));
}

fn luminance(c: vec3<f32>) -> f32 {
    return 0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z;
}

// Log-log slope thresholds and step for curves without explicit sections (tonemap.rs).
const TOE_SLOPE: f32 = 1.1;
const SHOULDER_SLOPE: f32 = 0.9;
const SLOPE_STEP: f32 = 1.0905077;

// 0 toe, 1 linear, 2 shoulder.
fn region(x_in: f32) -> u32 {
    let x = max(x_in, 0.0);
    if params.tone_operator == 3u {
        if x < params.gt_m {
            return 0u;
        }
        if x < gt_shoulder_start() {
            return 1u;
        }
        return 2u;
    }
    let lo = curve(x / SLOPE_STEP);
    let hi = curve(x * SLOPE_STEP);
    if !(lo > 0.0) {
        return 0u;
    }
    let slope = log(hi / lo) / (2.0 * log(SLOPE_STEP));
    if slope > TOE_SLOPE {
        return 0u;
    }
    if slope < SHOULDER_SLOPE {
        return 2u;
    }
    return 1u;
}

fn region_tint(r: u32) -> vec3<f32> {
    switch r {
        case 0u: { return vec3<f32>(0.3, 0.55, 1.0); }
        case 2u: { return vec3<f32>(1.0, 0.35, 0.25); }
        default: { return vec3<f32>(1.0, 1.0, 1.0); }
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

fn pack_rgb(c: vec3<f32>) -> u32 {
    return to_u8(c.x) | (to_u8(c.y) << 8u) | (to_u8(c.z) << 16u) | (255u << 24u);
}

fn grey(v: f32) -> u32 {
    let g = to_u8(v);
    return g | (g << 8u) | (g << 16u) | (255u << 24u);
}

// A region-coded pixel: the tint scaled by the displayed grey, never below 20%.
fn region_colour(r: u32, g: f32) -> u32 {
    return pack_rgb(region_tint(r) * (0.2 + 0.8 * g));
}

// 3x5 glyphs 0-9, '+', '-' (tonemap.rs GLYPHS): rows top to bottom, 3 bits each.
fn glyph_bits(i: u32) -> u32 {
    var glyphs = array<u32, 12>(
        0x7b6fu, 0x2c97u, 0x73e7u, 0x73cfu, 0x5bc9u, 0x79cfu, 0x79efu, 0x7249u, 0x7befu, 0x7bcfu,
        0x05d0u, 0x01c0u
    );
    return glyphs[min(i, 11u)];
}

// The zone strip along the bottom (tonemap.rs strip_layout / strip_pixel); 0 outside it.
fn strip_pixel(x: u32, y: u32) -> u32 {
    let width = params.size.x;
    let height = params.size.y;
    let sh = min(clamp(height / 10u, 8u, 64u), height);
    let y0 = height - sh;
    if params.view == 0u || y < y0 {
        return 0u;
    }
    let scale = min(min((width / ZONES) / 8u, (max(sh, 2u) - 2u) / 5u), 4u);
    let k = x * ZONES / width;
    let centre = zone_centre(k);
    let g = linear_to_srgb(curve(centre));
    var rgba = grey(g);
    if params.view == 3u {
        rgba = region_colour(region(centre), g);
    }
    if scale > 0u {
        let x0 = (k * width + ZONES - 1u) / ZONES;
        let x1 = ((k + 1u) * width + ZONES - 1u) / ZONES;
        let ev = i32(k) - i32(MIDDLE_ZONE);
        var n = 2u;
        if ev == 0 {
            n = 1u;
        }
        let tw = (4u * n - 1u) * scale;
        let lx0 = x0 + (max(x1 - x0, tw) - tw) / 2u;
        let ly0 = y0 + (sh - 5u * scale) / 2u;
        if x >= lx0 && x < lx0 + tw && y >= ly0 && y < ly0 + 5u * scale {
            let lx = x - lx0;
            let ly = y - ly0;
            let gi = lx / (4u * scale);
            let gx = (lx % (4u * scale)) / scale;
            let gy = ly / scale;
            var glyph = glyph_bits(0u);
            if n == 2u {
                if gi == 0u {
                    glyph = glyph_bits(select(11u, 10u, ev > 0));
                } else {
                    glyph = glyph_bits(u32(abs(ev)));
                }
            }
            if gx < 3u && ((glyph >> ((4u - gy) * 3u + (2u - gx))) & 1u) == 1u {
                rgba = select(grey(1.0), grey(0.0), g > 0.5);
            }
        }
    }
    return rgba;
}

fn tonemap(l: vec3<f32>) -> u32 {
    if !(finite(l.x) && finite(l.y) && finite(l.z)) {
        return MAGENTA;
    }
    let s = l * params.exposure_scale;
    switch params.view {
        case 2u: {
            return grey(linear_to_srgb(curve(zone_centre(zone_of(luminance(s))))));
        }
        case 3u: {
            let y = luminance(s);
            return region_colour(region(y), linear_to_srgb(curve(y)));
        }
        default: {
            let r = to_u8(linear_to_srgb(curve(s.x)));
            let g = to_u8(linear_to_srgb(curve(s.y)));
            let b = to_u8(linear_to_srgb(curve(s.z)));
            return r | (g << 8u) | (b << 16u) | (255u << 24u);
        }
    }
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
            rgba = strip_pixel(gid.x, gid.y);
            if rgba == 0u {
                rgba = tonemap(mean[i].xyz);
            }
        } else if params.mode == 6u {
            rgba = bitcast<u32>(curve(mean[i].x * params.exposure_scale));
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
