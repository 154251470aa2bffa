//! Display transforms: exposure in EV stops, a tone curve, then the sRGB transfer function;
//! plus the zone views (a strip of 17 zones one stop apart, per-pixel zones, the tone curve's
//! toe / linear / shoulder regions). `shaders/compare/display.wgsl` computes the same on the
//! GPU for the viewer; tests/tonemap.rs checks that both agree.

use super::Image;
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Operator {
    /// Narkowicz's fit of the ACES filmic curve.
    #[default]
    Aces,
    /// x / (1 + x) per channel.
    Reinhard,
    /// Clamp to [0, 1]: shows linear values as they are.
    Linear,
    /// Uchimura's Gran Turismo curve (toe, linear section, shoulder; `GtParams`).
    Gt,
}

impl Operator {
    pub const ALL: [Operator; 4] = [
        Operator::Aces,
        Operator::Reinhard,
        Operator::Linear,
        Operator::Gt,
    ];
    pub fn label(self) -> &'static str {
        match self {
            Operator::Aces => "ACES",
            Operator::Reinhard => "Reinhard",
            Operator::Linear => "Linear",
            Operator::Gt => "GT (Uchimura)",
        }
    }
}

/// Parameters of Uchimura's GT tonemapper ("HDR theory and practice", CEDEC 2017), with his
/// defaults (the ones The Callisto Protocol used).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "GtFields")]
pub struct GtParams {
    /// P: maximum brightness (the shoulder's asymptote).
    pub max_brightness: f32,
    /// a: contrast (the linear section's slope).
    pub contrast: f32,
    /// m: where the linear section starts.
    pub linear_start: f32,
    /// l: the linear section's length, as a fraction of what is left up to P.
    pub linear_length: f32,
    /// c: black tightness (the toe's exponent).
    pub black_tightness: f32,
    /// b: pedestal (the curve's value at black).
    pub pedestal: f32,
}

impl Default for GtParams {
    fn default() -> Self {
        GtParams {
            max_brightness: 1.0,
            contrast: 1.0,
            linear_start: 0.22,
            linear_length: 0.4,
            black_tightness: 1.33,
            pedestal: 0.0,
        }
    }
}

/// What a preset's `[tonemap.gt]` table may hold: any key left out takes Uchimura's default.
#[derive(Deserialize)]
#[serde(deny_unknown_fields, default)]
struct GtFields {
    max_brightness: f32,
    contrast: f32,
    linear_start: f32,
    linear_length: f32,
    black_tightness: f32,
    pedestal: f32,
}

impl Default for GtFields {
    fn default() -> Self {
        let d = GtParams::default();
        GtFields {
            max_brightness: d.max_brightness,
            contrast: d.contrast,
            linear_start: d.linear_start,
            linear_length: d.linear_length,
            black_tightness: d.black_tightness,
            pedestal: d.pedestal,
        }
    }
}

impl TryFrom<GtFields> for GtParams {
    type Error = String;
    fn try_from(f: GtFields) -> Result<GtParams, String> {
        let p = GtParams {
            max_brightness: f.max_brightness,
            contrast: f.contrast,
            linear_start: f.linear_start,
            linear_length: f.linear_length,
            black_tightness: f.black_tightness,
            pedestal: f.pedestal,
        };
        p.check()?;
        Ok(p)
    }
}

impl GtParams {
    pub fn is_default(&self) -> bool {
        *self == GtParams::default()
    }

    /// The ranges the formula needs: P > 0, a > 0, 0 < m < P, 0 <= l < 1 (l = 1 would put the
    /// shoulder's start at P), c > 0, 0 <= b < P.
    pub fn check(&self) -> Result<(), String> {
        let GtParams {
            max_brightness: p,
            contrast: a,
            linear_start: m,
            linear_length: l,
            black_tightness: c,
            pedestal: b,
        } = *self;
        let ok = [p, a, m, l, c, b].iter().all(|v| v.is_finite())
            && p > 0.0
            && a > 0.0
            && m > 0.0
            && m < p
            && (0.0..1.0).contains(&l)
            && c > 0.0
            && b >= 0.0
            && b < p;
        if ok {
            Ok(())
        } else {
            Err(format!(
                "GT tonemapper parameters out of range: need max_brightness > 0, contrast > 0, \
                 0 < linear_start < max_brightness, 0 <= linear_length < 1, black_tightness > 0, \
                 0 <= pedestal < max_brightness (got {self:?})"
            ))
        }
    }

    /// Where the linear section ends and the shoulder starts: S0 = m + l0, l0 = (P - m) l / a.
    pub fn shoulder_start(&self) -> f64 {
        let (p, a, m, l) = (
            self.max_brightness as f64,
            self.contrast as f64,
            self.linear_start as f64,
            self.linear_length as f64,
        );
        m + (p - m) * l / a
    }
}

fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Uchimura's GT curve as published: toe T(x) = m (x/m)^c + b, linear L(x) = m + a (x - m),
/// shoulder S(x) = P - (P - S1) e^(-C2 (x - S0) / P), blended by w0 = 1 - smoothstep(0, m, x),
/// w2 = step(S0, x), w1 = 1 - w0 - w2 (so [m, S0) is exactly L). In f64; `curve` rounds to f32.
pub fn gt(p: &GtParams, x: f64) -> f64 {
    let (pp, a, m, l, c, b) = (
        p.max_brightness as f64,
        p.contrast as f64,
        p.linear_start as f64,
        p.linear_length as f64,
        p.black_tightness as f64,
        p.pedestal as f64,
    );
    let x = x.max(0.0);
    let l0 = (pp - m) * l / a;
    let s0 = m + l0;
    let s1 = m + a * l0;
    let c2 = a * pp / (pp - s1);
    let cp = -c2 / pp;
    let w0 = 1.0 - smoothstep(0.0, m, x);
    let w2 = if x >= s0 { 1.0 } else { 0.0 };
    let w1 = 1.0 - w0 - w2;
    // Each part only where its weight is non-zero (0 * inf would be NaN for huge x).
    let mut y = 0.0;
    if w0 > 0.0 {
        y += (m * (x / m).powf(c) + b) * w0;
    }
    if w1 > 0.0 {
        y += (m + a * (x - m)) * w1;
    }
    if w2 > 0.0 {
        y += (pp - (pp - s1) * (cp * (x - s0)).exp()) * w2;
    }
    y
}

pub fn curve(op: Operator, gt_params: &GtParams, x: f32) -> f32 {
    let x = x.max(0.0);
    match op {
        Operator::Aces => {
            ((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14)).clamp(0.0, 1.0)
        }
        Operator::Reinhard => x / (1.0 + x),
        Operator::Linear => x.min(1.0),
        Operator::Gt => gt(gt_params, x as f64) as f32,
    }
}

/// The sRGB transfer function's inverse (8-bit colour textures and the talk's base colours).
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.040_45 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

pub fn linear_to_srgb(c: f32) -> f32 {
    if c <= 0.003_130_8 {
        c * 12.92
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    }
}

fn to_u8(x: f32) -> u8 {
    (x * 255.0 + 0.5).clamp(0.0, 255.0) as u8
}

/// What the display shows besides (or instead of) the tonemapped image.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum View {
    /// The tonemapped image.
    #[default]
    Normal,
    /// The tonemapped image with the strip of 17 zones (one stop apart) along the bottom.
    Strip,
    /// Each pixel in the grey of its zone (by luminance), with the strip.
    Zones,
    /// Each pixel coloured by the part of the tone curve its luminance falls in (toe blue,
    /// linear grey, shoulder red), with the strip coloured the same way.
    Regions,
}

impl View {
    pub const ALL: [View; 4] = [View::Normal, View::Strip, View::Zones, View::Regions];
    pub fn label(self) -> &'static str {
        match self {
            View::Normal => "Normal",
            View::Strip => "Zone strip",
            View::Zones => "Zones per pixel",
            View::Regions => "Curve regions",
        }
    }
    pub fn is_normal(&self) -> bool {
        *self == View::Normal
    }
    /// The value the display shader's `params.view` takes.
    pub fn index(self) -> u32 {
        self as u32
    }
}

/// The display transform a preset's `[tonemap]` table describes.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Settings {
    #[serde(default)]
    pub operator: Operator,
    /// Exposure in EV stops (+1 doubles the brightness).
    #[serde(default)]
    pub exposure: f32,
    /// The GT curve's parameters (used when `operator = "gt"`); keys left out take Uchimura's
    /// defaults.
    #[serde(default, skip_serializing_if = "GtParams::is_default")]
    pub gt: GtParams,
    /// Zone views: "normal", "strip", "zones", "regions".
    #[serde(default, skip_serializing_if = "View::is_normal")]
    pub view: View,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            operator: Operator::Aces,
            exposure: 0.0,
            gt: GtParams::default(),
            view: View::Normal,
        }
    }
}

impl Settings {
    pub fn curve(&self, x: f32) -> f32 {
        curve(self.operator, &self.gt, x)
    }
    /// The same curve and exposure without a zone view (what metrics score).
    pub fn normal(&self) -> Settings {
        Settings {
            view: View::Normal,
            ..*self
        }
    }
}

/// Zones of the zone view: 17 (the Zone System's 11, widened for HDR), one stop apart.
pub const ZONES: u32 = 17;
/// The middle zone, whose centre is 18% grey (scene-linear luminance after exposure).
pub const MIDDLE_ZONE: u32 = 8;
pub const MIDDLE_GREY: f32 = 0.18;

/// The luminance at the centre of zone `k`: 0.18 * 2^(k - 8).
pub fn zone_centre(k: u32) -> f32 {
    MIDDLE_GREY * 2f32.powi(k as i32 - MIDDLE_ZONE as i32)
}

/// Zone `k` holds luminances in [0.18 * 2^(k - 8.5), 0.18 * 2^(k - 7.5)); zone 0 also holds
/// everything darker, zone 16 everything brighter.
pub fn zone_bounds(k: u32) -> (f32, f32) {
    let e = k as f32 - MIDDLE_ZONE as f32;
    (
        MIDDLE_GREY * (e - 0.5).exp2(),
        MIDDLE_GREY * (e + 0.5).exp2(),
    )
}

/// The zone of a luminance (after exposure).
pub fn zone_of(y: f32) -> u32 {
    // NaN and non-positive values: zone 0.
    if y.is_nan() || y <= 0.0 {
        return 0;
    }
    let z = ((y / MIDDLE_GREY).log2() + MIDDLE_ZONE as f32 + 0.5).floor();
    z.clamp(0.0, (ZONES - 1) as f32) as u32
}

/// Rec. 709 luminance of linear RGB.
pub fn luminance(c: [f32; 3]) -> f32 {
    0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
}

/// The part of the tone curve a value falls in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Region {
    Toe = 0,
    Linear = 1,
    Shoulder = 2,
}

/// Log-log slope thresholds for curves without explicit sections: above TOE_SLOPE the curve
/// expands contrast (a toe), below SHOULDER_SLOPE it compresses it (a shoulder).
pub const TOE_SLOPE: f32 = 1.1;
pub const SHOULDER_SLOPE: f32 = 0.9;
/// Half width of the log-log slope's difference quotient: a factor 2^(1/8) either side.
pub const SLOPE_STEP: f32 = 1.090_507_7;

/// GT: its own sections (toe below m, where the toe weight w0 is non-zero; linear on
/// [m, S0); shoulder from S0). Other curves: by the log-log slope d ln T / d ln x over a
/// factor 2^(1/8) either side (toe above 1.1, shoulder below 0.9, linear between; black is toe).
pub fn region(op: Operator, gt_params: &GtParams, x: f32) -> Region {
    let x = x.max(0.0);
    if op == Operator::Gt {
        if x < gt_params.linear_start {
            return Region::Toe;
        }
        if (x as f64) < gt_params.shoulder_start() {
            return Region::Linear;
        }
        return Region::Shoulder;
    }
    let lo = curve(op, gt_params, x / SLOPE_STEP);
    let hi = curve(op, gt_params, x * SLOPE_STEP);
    if lo.is_nan() || lo <= 0.0 {
        return Region::Toe;
    }
    let slope = (hi / lo).ln() / (2.0 * SLOPE_STEP.ln());
    if slope > TOE_SLOPE {
        Region::Toe
    } else if slope < SHOULDER_SLOPE {
        Region::Shoulder
    } else {
        Region::Linear
    }
}

/// The colour (sRGB-encoded) a region tints with: toe blue, linear grey, shoulder red.
pub fn region_tint(r: Region) -> [f32; 3] {
    match r {
        Region::Toe => [0.3, 0.55, 1.0],
        Region::Linear => [1.0, 1.0, 1.0],
        Region::Shoulder => [1.0, 0.35, 0.25],
    }
}

/// A region-coded pixel: the tint scaled by the displayed (sRGB) grey `g` of its luminance,
/// never below 20% so the tint shows in black too.
fn region_colour(r: Region, g: f32) -> [u8; 4] {
    let t = region_tint(r);
    let k = 0.2 + 0.8 * g;
    [to_u8(t[0] * k), to_u8(t[1] * k), to_u8(t[2] * k), 255]
}

/// 3x5 glyphs for the strip's labels: 0-9, '+', '-' (rows top to bottom, 3 bits each, the
/// leftmost pixel the highest bit).
pub const GLYPHS: [u32; 12] = [
    0b111_101_101_101_111,
    0b010_110_010_010_111,
    0b111_001_111_100_111,
    0b111_001_111_001_111,
    0b101_101_111_001_001,
    0b111_100_111_001_111,
    0b111_100_111_101_111,
    0b111_001_001_001_001,
    0b111_101_111_101_111,
    0b111_101_111_001_111,
    0b000_010_111_010_000,
    0b000_000_111_000_000,
];

/// The zone strip's place: its first row and height (h / 10, at least 8 and at most 64 rows,
/// never more than the image) and the labels' pixel scale (0: no room for labels).
pub fn strip_layout(width: u32, height: u32) -> (u32, u32, u32) {
    let sh = (height / 10).clamp(8, 64).min(height);
    let patch = width / ZONES;
    let scale = (patch / 8).min(sh.saturating_sub(2) / 5).min(4);
    (height - sh, sh, scale)
}

/// The strip's pixel at (x, y) if it lies in the strip: the zone's patch (its centre through
/// the tone curve, or region-coded in the regions view) with its EV offset from 18% grey
/// (-8 .. +8) written in black or white.
pub fn strip_pixel(tm: &Settings, width: u32, height: u32, x: u32, y: u32) -> Option<[u8; 4]> {
    let (y0, sh, scale) = strip_layout(width, height);
    if tm.view == View::Normal || y < y0 {
        return None;
    }
    let k = x * ZONES / width;
    let centre = zone_centre(k);
    let g = linear_to_srgb(tm.curve(centre));
    let mut rgba = if tm.view == View::Regions {
        region_colour(region(tm.operator, &tm.gt, centre), g)
    } else {
        let v = to_u8(g);
        [v, v, v, 255]
    };
    if scale > 0 {
        let x0 = (k * width).div_ceil(ZONES);
        let x1 = ((k + 1) * width).div_ceil(ZONES);
        let ev = k as i32 - MIDDLE_ZONE as i32;
        let n = if ev == 0 { 1 } else { 2 };
        let tw = (4 * n - 1) * scale;
        let lx0 = x0 + (x1 - x0).saturating_sub(tw) / 2;
        let ly0 = y0 + (sh - 5 * scale) / 2;
        if x >= lx0 && x < lx0 + tw && y >= ly0 && y < ly0 + 5 * scale {
            let (lx, ly) = (x - lx0, y - ly0);
            let (gi, gx, gy) = (lx / (4 * scale), (lx % (4 * scale)) / scale, ly / scale);
            let glyph = if n == 1 {
                GLYPHS[0]
            } else if gi == 0 {
                GLYPHS[if ev > 0 { 10 } else { 11 }]
            } else {
                GLYPHS[ev.unsigned_abs() as usize]
            };
            if gx < 3 && (glyph >> ((4 - gy) * 3 + (2 - gx))) & 1 == 1 {
                let ink = if g > 0.5 { 0 } else { 255 };
                rgba = [ink, ink, ink, 255];
            }
        }
    }
    Some(rgba)
}

/// One displayed pixel (8-bit sRGB RGBA) of linear `rgb` at (x, y) of a width x height image.
pub fn display_pixel(
    tm: &Settings,
    rgb: [f32; 3],
    (x, y): (u32, u32),
    (width, height): (u32, u32),
) -> [u8; 4] {
    if let Some(p) = strip_pixel(tm, width, height, x, y) {
        return p;
    }
    // Non-finite values show as magenta so they cannot hide.
    if rgb.iter().any(|v| !v.is_finite()) {
        return [255, 0, 255, 255];
    }
    let scale = 2f32.powf(tm.exposure);
    let s = rgb.map(|v| v * scale);
    match tm.view {
        View::Normal | View::Strip => {
            let c = s.map(|v| to_u8(linear_to_srgb(tm.curve(v))));
            [c[0], c[1], c[2], 255]
        }
        View::Zones => {
            let v = to_u8(linear_to_srgb(tm.curve(zone_centre(zone_of(luminance(s))))));
            [v, v, v, 255]
        }
        View::Regions => {
            let l = luminance(s);
            region_colour(region(tm.operator, &tm.gt, l), linear_to_srgb(tm.curve(l)))
        }
    }
}

/// 8-bit sRGB RGBA of the display transform `tm` (curve, exposure and zone view); non-finite
/// values show as magenta so they cannot hide.
pub fn to_srgb8(img: &Image, tm: &Settings) -> Vec<u8> {
    let mut out = Vec::with_capacity(img.rgb.len() / 3 * 4);
    for (i, p) in img.rgb.chunks_exact(3).enumerate() {
        let i = i as u32;
        let xy = (i % img.width, i / img.width);
        out.extend_from_slice(&display_pixel(
            tm,
            [p[0], p[1], p[2]],
            xy,
            (img.width, img.height),
        ));
    }
    out
}
