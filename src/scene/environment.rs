//! Environment maps: an equirectangular HDR image (.exr through `exr`, .hdr through `image`) as
//! the sky, turned about +Y by `rotation_deg` and scaled by `intensity`, importance-sampled by
//! luminance. The shaders' side is `shaders/common/sky.wgsl` (binding 6 of the scene group,
//! laid out by [`gpu_bytes`]); the functions here are its CPU twins, used by tests.
//!
//! **Mapping** (map space, +Y up). A direction d = (x, y, z) has
//! θ = acos(y) ∈ [0, π] (0 straight up) and φ = atan2(x, −z) ∈ (−π, π] (0 towards −Z,
//! +π/2 towards +X), and reads the image at u = ½ + φ / 2π (columns, left to right) and
//! v = θ / π (rows, top to bottom). So the image's centre is seen looking along −Z, +X is a
//! quarter turn to its right (the image is not mirrored when seen from inside), the top row is
//! the zenith. Back: d = (sin θ sin φ, cos θ, −sin θ cos φ).
//!
//! **Rotation**: a world direction is the map direction turned by `rotation_deg` about +Y,
//! right-handed (positive angles turn +X towards −Z): world = R_y(r) map, so lookups use
//! map = R_y(−r) world.
//!
//! **Radiance**: bilinear between texel centres ((i + ½)/W, (j + ½)/H), wrapping in u and
//! clamped in v, times `intensity`.
//!
//! **Sampling**: texel (i, j) is picked with probability ∝ L̄_ij sin θ_j, where L̄ is the texel
//! luminance smoothed by the separable filter (⅛, ¾, ⅛) (exactly the mean of the bilinear
//! radiance over the texel, so the pdf is non-zero wherever the radiance can be) and θ_j the
//! row centre's polar angle: first a row from the marginal CDF, then a column from that row's
//! conditional CDF (both inclusive, f32, as uploaded), then a uniform point in the texel. The
//! density over (u, v) is p = pmf_row · pmf_column · W · H, in solid angle
//! p / (2π² sin θ). Both the CPU and the GPU take pmfs as differences of the stored CDFs, so
//! `pdf(sample(u).dir)` equals the sample's pdf.

use super::Scene;
use anyhow::{bail, ensure, Context, Result};
use glam::{DVec3, Vec2, Vec3};
use std::f64::consts::PI;
use std::path::Path;
use std::sync::Arc;

/// Largest share of the scene data buffer (128 MiB in all, wgpu's default
/// `max_storage_buffer_binding_size` and lavapipe's, shared with the textures: see
/// gpu_scene::SCENE_DATA_WORDS) the map may take: larger maps are halved (2x2 box filter)
/// until they fit, with a warning. 4096x2048 is halved once, to 2048x1024 (24 MiB).
pub const MAX_GPU_BYTES: usize = 64 * 1024 * 1024;

/// Words of the buffer header (see [`gpu_bytes`]).
pub const HEADER_WORDS: usize = 16;

/// FrameUniforms flag (render::FLAG_*): the path tracer leaves the environment map out of
/// next-event estimation (misses then count with weight 1: BSDF sampling alone). For A/B tests.
pub const FLAG_NO_SKY_NEE: u32 = crate::render::FLAG_NO_SKY_NEE;

/// An equirectangular environment map used as the sky.
#[derive(Clone)]
pub struct Environment {
    /// Turn about +Y in degrees (right-handed: +X towards −Z).
    pub rotation_deg: f32,
    /// Radiance scale.
    pub intensity: f32,
    data: Arc<EnvData>,
}

struct EnvData {
    width: u32,
    height: u32,
    /// Linear RGB, row-major, row 0 = the zenith.
    texels: Vec<[f32; 3]>,
    /// Inclusive CDF over rows (last = 1).
    marginal: Vec<f32>,
    /// Inclusive CDF over columns of each row (last of each row = 1).
    conditional: Vec<f32>,
    /// Solid-angle mean of the radiance (intensity 1).
    mean: Vec3,
    /// Sum of the sampling weights is positive (a black map cannot be sampled).
    sampleable: bool,
    source: String,
    invalid_texels: usize,
    halvings: u32,
}

impl std::fmt::Debug for Environment {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Environment")
            .field("source", &self.data.source)
            .field("width", &self.data.width)
            .field("height", &self.data.height)
            .field("rotation_deg", &self.rotation_deg)
            .field("intensity", &self.intensity)
            .field("mean", &self.data.mean)
            .finish()
    }
}

impl Environment {
    /// A map from linear RGB texels (row-major, row 0 the zenith), rotation 0, intensity 1.
    /// NaN, infinite and negative values are set to 0 (counted, with a warning).
    pub fn new(width: u32, height: u32, texels: Vec<[f32; 3]>) -> Result<Environment> {
        Self::build("procedural", width, height, texels)
    }

    /// A map whose texel (i, j) is `f` of the direction through its centre (rotation 0).
    pub fn from_fn(width: u32, height: u32, f: impl Fn(Vec3) -> Vec3) -> Result<Environment> {
        let mut texels = Vec::with_capacity((width * height) as usize);
        for j in 0..height {
            for i in 0..width {
                let uv = Vec2::new(
                    (i as f32 + 0.5) / width as f32,
                    (j as f32 + 0.5) / height as f32,
                );
                texels.push(f(map_direction(uv)).to_array());
            }
        }
        Self::new(width, height, texels)
    }

    /// Reads an equirectangular .exr (its first layer with R, G, B channels; A ignored) or
    /// .hdr (Radiance RGBE) file.
    pub fn load(path: &Path, rotation_deg: f32, intensity: f32) -> Result<Environment> {
        let what = || format!("environment map {}", path.display());
        ensure!(
            rotation_deg.is_finite(),
            "{}: rotation {rotation_deg} is not a finite number of degrees",
            what()
        );
        ensure!(
            intensity.is_finite() && intensity >= 0.0,
            "{}: intensity {intensity} must be finite and >= 0",
            what()
        );
        if !path.is_file() {
            bail!("{}: file not found", what());
        }
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or("")
            .to_ascii_lowercase();
        let (w, h, texels) = match ext.as_str() {
            "exr" => read_exr(path).with_context(what)?,
            "hdr" => read_hdr(path).with_context(what)?,
            _ => bail!(
                "{}: unsupported format '{}' (expected an equirectangular .exr or .hdr)",
                what(),
                if ext.is_empty() { "(none)" } else { &ext }
            ),
        };
        let name = path.display().to_string();
        let mut env = Self::build(&name, w, h, texels).with_context(what)?;
        env.rotation_deg = rotation_deg;
        env.intensity = intensity;
        Ok(env)
    }

    fn build(
        source: &str,
        width: u32,
        height: u32,
        mut texels: Vec<[f32; 3]>,
    ) -> Result<Environment> {
        ensure!(width >= 1 && height >= 1, "empty image ({width}x{height})");
        ensure!(
            texels.len() == (width as usize) * (height as usize),
            "{} texels for a {width}x{height} image",
            texels.len()
        );
        let mut invalid = 0usize;
        for t in &mut texels {
            let mut bad = false;
            for c in t.iter_mut() {
                if !(c.is_finite() && *c >= 0.0) {
                    *c = 0.0;
                    bad = true;
                }
            }
            invalid += bad as usize;
        }
        if invalid > 0 {
            log::warn!(
                "environment map {source}: {invalid} texels had NaN, infinite or negative values, set to 0"
            );
        }
        let (mut w, mut h) = (width, height);
        let mut halvings = 0;
        while gpu_size(w, h) > MAX_GPU_BYTES && (w > 1 || h > 1) {
            (w, h, texels) = halve(w, h, &texels);
            halvings += 1;
        }
        if halvings > 0 {
            log::warn!(
                "environment map {source}: {width}x{height} exceeds the {} MiB GPU buffer limit, halved to {w}x{h}",
                MAX_GPU_BYTES >> 20
            );
        }
        let (marginal, conditional, sampleable) = sampling_tables(w, h, &texels);
        let mean = mean_radiance(w, h, &texels);
        Ok(Environment {
            rotation_deg: 0.0,
            intensity: 1.0,
            data: Arc::new(EnvData {
                width: w,
                height: h,
                texels,
                marginal,
                conditional,
                mean,
                sampleable,
                source: source.to_string(),
                invalid_texels: invalid,
                halvings,
            }),
        })
    }

    pub fn width(&self) -> u32 {
        self.data.width
    }
    pub fn height(&self) -> u32 {
        self.data.height
    }
    /// Linear RGB, row-major, row 0 the zenith (after any halving to fit the GPU limit).
    pub fn texels(&self) -> &[[f32; 3]] {
        &self.data.texels
    }
    /// Texels that were NaN, infinite or negative in the file (set to 0).
    pub fn invalid_texels(&self) -> usize {
        self.data.invalid_texels
    }
    /// How many times the map was halved to fit the GPU buffer limit.
    pub fn halvings(&self) -> u32 {
        self.data.halvings
    }
    /// The file it came from ("procedural" otherwise).
    pub fn source(&self) -> &str {
        &self.data.source
    }
    /// Solid-angle mean of the radiance, intensity included.
    pub fn mean_radiance(&self) -> Vec3 {
        self.data.mean * self.intensity
    }
    /// Whether importance sampling has anything to sample (the map is not black).
    pub fn sampleable(&self) -> bool {
        self.data.sampleable && self.intensity > 0.0
    }
    /// "environment map WxH", as logs and the UI name the sky.
    pub fn label(&self) -> String {
        format!("environment map {}x{}", self.data.width, self.data.height)
    }

    fn rotation(&self) -> (f64, f64) {
        (self.rotation_deg as f64).to_radians().sin_cos()
    }

    /// Map (u, v) of a world direction (rotation applied).
    pub fn direction_to_uv(&self, dir: Vec3) -> Vec2 {
        let (u, v) = self.uv64(dir.as_dvec3());
        Vec2::new(u as f32, v as f32)
    }

    /// World direction of map coordinates (u, v) (rotation applied).
    pub fn uv_to_direction(&self, uv: Vec2) -> Vec3 {
        self.world_dir(uv.x as f64, uv.y as f64).as_vec3()
    }

    fn uv64(&self, d: DVec3) -> (f64, f64) {
        let d = d.normalize_or(DVec3::Y);
        let (s, c) = self.rotation();
        // map = R_y(-r) world.
        let x = d.x * c - d.z * s;
        let z = d.x * s + d.z * c;
        let phi = x.atan2(-z);
        let u = 0.5 + phi / (2.0 * PI);
        (u - u.floor(), d.y.clamp(-1.0, 1.0).acos() / PI)
    }

    fn world_dir(&self, u: f64, v: f64) -> DVec3 {
        let m = map_direction64(u, v);
        let (s, c) = self.rotation();
        // world = R_y(r) map.
        DVec3::new(m.x * c + m.z * s, m.y, -m.x * s + m.z * c)
    }

    fn texel(&self, i: i64, j: i64) -> DVec3 {
        let (w, h) = (self.data.width as i64, self.data.height as i64);
        let i = i.rem_euclid(w);
        let j = j.clamp(0, h - 1);
        let t = self.data.texels[(j * w + i) as usize];
        DVec3::new(t[0] as f64, t[1] as f64, t[2] as f64)
    }

    /// Radiance arriving from world direction `dir` (towards the scene from the sky):
    /// bilinear, intensity included.
    pub fn radiance(&self, dir: Vec3) -> Vec3 {
        let (u, v) = self.uv64(dir.as_dvec3());
        let x = u * self.data.width as f64 - 0.5;
        let y = v * self.data.height as f64 - 0.5;
        let (fx, fy) = (x.floor(), y.floor());
        let (tx, ty) = (x - fx, y - fy);
        let (i, j) = (fx as i64, fy as i64);
        let top = self.texel(i, j) * (1.0 - tx) + self.texel(i + 1, j) * tx;
        let bottom = self.texel(i, j + 1) * (1.0 - tx) + self.texel(i + 1, j + 1) * tx;
        ((top * (1.0 - ty) + bottom * ty) * self.intensity as f64).as_vec3()
    }

    fn pmf(cdf: &[f32], k: usize) -> f64 {
        cdf[k] as f64 - if k > 0 { cdf[k - 1] as f64 } else { 0.0 }
    }

    /// Solid-angle pdf of texel (i, j) at polar sine `sin_theta`.
    fn texel_pdf(&self, i: usize, j: usize, sin_theta: f64) -> f64 {
        let (w, h) = (self.data.width as usize, self.data.height as usize);
        if !self.data.sampleable || sin_theta <= 0.0 {
            return 0.0;
        }
        let p = Self::pmf(&self.data.marginal, j)
            * Self::pmf(&self.data.conditional[j * w..(j + 1) * w], i)
            * (w * h) as f64;
        p / (2.0 * PI * PI * sin_theta)
    }

    /// A direction by luminance importance sampling and its solid-angle pdf (0 for a black
    /// map). `u` in [0, 1)^2: u.x picks the row, u.y the column.
    pub fn sample(&self, u: Vec2) -> (Vec3, f32) {
        let (w, h) = (self.data.width as usize, self.data.height as usize);
        if !self.data.sampleable {
            return (Vec3::Y, 0.0);
        }
        let pick = |cdf: &[f32], u: f64| -> (usize, f64) {
            let u = u.clamp(0.0, 1.0 - f64::EPSILON);
            let k = cdf.partition_point(|&c| (c as f64) <= u).min(cdf.len() - 1);
            let p = Self::pmf(cdf, k);
            let before = cdf[k] as f64 - p;
            let t = if p > 0.0 { (u - before) / p } else { 0.5 };
            (k, t.clamp(0.0, 1.0 - 1e-9))
        };
        let (j, dv) = pick(&self.data.marginal, u.x as f64);
        let (i, du) = pick(&self.data.conditional[j * w..(j + 1) * w], u.y as f64);
        let (uu, vv) = ((i as f64 + du) / w as f64, (j as f64 + dv) / h as f64);
        let dir = self.world_dir(uu, vv);
        let sin_theta = (1.0 - dir.y * dir.y).max(0.0).sqrt();
        (dir.as_vec3(), self.texel_pdf(i, j, sin_theta) as f32)
    }

    /// Solid-angle pdf with which [`Environment::sample`] produces world direction `dir`.
    pub fn pdf(&self, dir: Vec3) -> f32 {
        let d = dir.as_dvec3().normalize_or(DVec3::Y);
        let (u, v) = self.uv64(d);
        let (w, h) = (self.data.width as usize, self.data.height as usize);
        let i = ((u * w as f64) as usize).min(w - 1);
        let j = ((v * h as f64) as usize).min(h - 1);
        let sin_theta = (1.0 - d.y * d.y).max(0.0).sqrt();
        self.texel_pdf(i, j, sin_theta) as f32
    }
}

impl Scene {
    /// Mean sky radiance: the environment map's solid-angle mean (intensity included) when
    /// there is one, the constant `sky` otherwise. Non-zero means the scene has a sky.
    pub fn sky_mean(&self) -> Vec3 {
        match &self.environment {
            Some(e) => e.mean_radiance(),
            None => self.sky,
        }
    }
    /// What lights the scene from outside: "environment map WxH" or "sky".
    pub fn sky_label(&self) -> String {
        match &self.environment {
            Some(e) => e.label(),
            None => "sky".into(),
        }
    }
}

/// Map-space direction of (u, v) (no rotation).
pub fn map_direction(uv: Vec2) -> Vec3 {
    map_direction64(uv.x as f64, uv.y as f64).as_vec3()
}

fn map_direction64(u: f64, v: f64) -> DVec3 {
    let phi = 2.0 * PI * (u - 0.5);
    let theta = PI * v;
    let (st, ct) = theta.sin_cos();
    DVec3::new(st * phi.sin(), ct, -st * phi.cos())
}

fn luminance(t: [f32; 3]) -> f64 {
    0.2126 * t[0] as f64 + 0.7152 * t[1] as f64 + 0.0722 * t[2] as f64
}

/// Bytes of the GPU buffer of a w x h map.
fn gpu_size(w: u32, h: u32) -> usize {
    let (w, h) = (w as usize, h as usize);
    4 * (HEADER_WORDS + 2 * w * h + h + w * h)
}

/// 2x2 box filter (an odd last row or column folds into its neighbour).
fn halve(w: u32, h: u32, texels: &[[f32; 3]]) -> (u32, u32, Vec<[f32; 3]>) {
    let (nw, nh) = ((w / 2).max(1), (h / 2).max(1));
    let mut out = Vec::with_capacity((nw * nh) as usize);
    for y in 0..nh {
        for x in 0..nw {
            let (x0, x1) = (x * w / nw, ((x + 1) * w / nw).max(x * w / nw + 1));
            let (y0, y1) = (y * h / nh, ((y + 1) * h / nh).max(y * h / nh + 1));
            let mut sum = [0.0f64; 3];
            for sy in y0..y1 {
                for sx in x0..x1 {
                    let t = texels[(sy * w + sx) as usize];
                    for c in 0..3 {
                        sum[c] += t[c] as f64;
                    }
                }
            }
            let n = ((x1 - x0) * (y1 - y0)) as f64;
            out.push(sum.map(|s| (s / n) as f32));
        }
    }
    (nw, nh, out)
}

/// Inclusive f32 CDF of non-negative weights (last entry exactly 1; uniform when all are 0).
fn inclusive_cdf(weights: &[f64]) -> Vec<f32> {
    let total: f64 = weights.iter().sum();
    let n = weights.len();
    let mut acc = 0.0;
    let mut cdf: Vec<f32> = weights
        .iter()
        .enumerate()
        .map(|(k, &w)| {
            if total > 0.0 {
                acc += w;
                (acc / total) as f32
            } else {
                ((k + 1) as f64 / n as f64) as f32
            }
        })
        .collect();
    if let Some(last) = cdf.last_mut() {
        *last = 1.0;
    }
    cdf
}

/// Marginal (rows) and conditional (columns per row) CDFs of the sampling weights
/// L̄_ij sin θ_j (L̄: luminance smoothed by (⅛, ¾, ⅛), wrapping in u, clamped in v).
fn sampling_tables(w: u32, h: u32, texels: &[[f32; 3]]) -> (Vec<f32>, Vec<f32>, bool) {
    let (w, h) = (w as usize, h as usize);
    let lum: Vec<f64> = texels.iter().map(|&t| luminance(t)).collect();
    const K: [f64; 3] = [0.125, 0.75, 0.125];
    // Horizontal pass (wrapping), then vertical (clamped).
    let mut horiz = vec![0.0f64; w * h];
    for j in 0..h {
        for i in 0..w {
            let l = |di: usize| lum[j * w + (i + w + di - 1) % w];
            horiz[j * w + i] = K[0] * l(0) + K[1] * l(1) + K[2] * l(2);
        }
    }
    let mut weights = vec![0.0f64; w * h];
    let mut row_sums = vec![0.0f64; h];
    for j in 0..h {
        let sin_theta = (PI * (j as f64 + 0.5) / h as f64).sin();
        let up = j.saturating_sub(1);
        let down = (j + 1).min(h - 1);
        for i in 0..w {
            let f = K[0] * horiz[up * w + i] + K[1] * horiz[j * w + i] + K[2] * horiz[down * w + i];
            weights[j * w + i] = f * sin_theta;
            row_sums[j] += f * sin_theta;
        }
    }
    let sampleable = row_sums.iter().sum::<f64>() > 0.0;
    let marginal = inclusive_cdf(&row_sums);
    let mut conditional = Vec::with_capacity(w * h);
    for j in 0..h {
        conditional.extend(inclusive_cdf(&weights[j * w..(j + 1) * w]));
    }
    (marginal, conditional, sampleable)
}

/// Solid-angle mean of the texels taken as constant over each texel.
fn mean_radiance(w: u32, h: u32, texels: &[[f32; 3]]) -> Vec3 {
    let (w, h) = (w as usize, h as usize);
    let mut sum = DVec3::ZERO;
    for j in 0..h {
        let c0 = (PI * j as f64 / h as f64).cos();
        let c1 = (PI * (j + 1) as f64 / h as f64).cos();
        let solid_angle = 2.0 * PI / w as f64 * (c0 - c1);
        for i in 0..w {
            let t = texels[j * w + i];
            sum += DVec3::new(t[0] as f64, t[1] as f64, t[2] as f64) * solid_angle;
        }
    }
    (sum / (4.0 * PI)).as_vec3()
}

fn f16_bits(x: f32) -> u32 {
    half::f16::from_f32(x).to_bits() as u32
}

/// The bytes of binding 6 of the scene group (`environment` in shaders/common/sky.wgsl), one
/// array of 32-bit words:
///
/// | words | content |
/// | --- | --- |
/// | 0, 1 | width W, height H |
/// | 2 | 1 if a map is bound (0: the constant `frame.sky` is the sky) |
/// | 3 | 1 if the map can be sampled (not black, intensity > 0) |
/// | 4, 5 | word offsets of the marginal and the conditional CDFs |
/// | 6, 7 | sin and cos of the rotation (f32) |
/// | 8 | radiance scale: intensity x texel scale (f32) |
/// | 9..12 | mean radiance, intensity included (f32 RGB) |
/// | 12 | texel scale (f32): texels are stored divided by it so half floats do not overflow |
/// | 13..16 | 0 |
/// | 16.. | texels, two words each: half (R, G), half (B, 0) |
/// | then | marginal CDF, H f32 (inclusive, last 1) |
/// | then | conditional CDFs, W f32 per row |
///
/// Without a map: the 16 header words, word 2 = 0.
pub fn gpu_bytes(env: Option<&Environment>) -> Vec<u8> {
    let mut words = vec![0u32; HEADER_WORDS];
    let Some(e) = env else {
        return bytemuck::cast_slice(&words).to_vec();
    };
    let d = &e.data;
    let (w, h) = (d.width as usize, d.height as usize);
    let max = d
        .texels
        .iter()
        .flat_map(|t| t.iter().copied())
        .fold(0.0f32, f32::max);
    // Half floats end at 65504: keep the brightest texel at or below 32768.
    let scale = if max > 32768.0 { max / 32768.0 } else { 1.0 };
    let (s, c) = (e.rotation_deg as f64).to_radians().sin_cos();
    let mean = e.mean_radiance();
    let marginal_at = HEADER_WORDS + 2 * w * h;
    let conditional_at = marginal_at + h;
    words[0] = d.width;
    words[1] = d.height;
    words[2] = 1;
    words[3] = e.sampleable() as u32;
    words[4] = marginal_at as u32;
    words[5] = conditional_at as u32;
    words[6] = (s as f32).to_bits();
    words[7] = (c as f32).to_bits();
    words[8] = (e.intensity * scale).to_bits();
    words[9] = mean.x.to_bits();
    words[10] = mean.y.to_bits();
    words[11] = mean.z.to_bits();
    words[12] = scale.to_bits();
    words.reserve(gpu_size(d.width, d.height) / 4 - HEADER_WORDS);
    for t in &d.texels {
        words.push(f16_bits(t[0] / scale) | (f16_bits(t[1] / scale) << 16));
        words.push(f16_bits(t[2] / scale));
    }
    words.extend(d.marginal.iter().map(|x| x.to_bits()));
    words.extend(d.conditional.iter().map(|x| x.to_bits()));
    debug_assert_eq!(words.len() * 4, gpu_size(d.width, d.height));
    bytemuck::cast_slice(&words).to_vec()
}

fn read_exr(path: &Path) -> Result<(u32, u32, Vec<[f32; 3]>)> {
    use exr::prelude::*;
    struct Pixels {
        width: usize,
        texels: Vec<[f32; 3]>,
    }
    let image = read_first_rgba_layer_from_file(
        path,
        |res, _| Pixels {
            width: res.width(),
            texels: vec![[0.0; 3]; res.width() * res.height()],
        },
        |px: &mut Pixels, pos, (r, g, b, _a): (f32, f32, f32, f32)| {
            px.texels[pos.y() * px.width + pos.x()] = [r, g, b];
        },
    )
    .map_err(|e| anyhow::anyhow!("not a readable RGB(A) EXR: {e}"))?;
    let size = image.layer_data.size;
    let px = image.layer_data.channel_data.pixels;
    Ok((size.width() as u32, size.height() as u32, px.texels))
}

fn read_hdr(path: &Path) -> Result<(u32, u32, Vec<[f32; 3]>)> {
    let img = image::ImageReader::open(path)
        .context("cannot open")?
        .with_guessed_format()
        .context("cannot read")?
        .decode()
        .map_err(|e| anyhow::anyhow!("not a readable Radiance HDR image: {e}"))?
        .into_rgb32f();
    let (w, h) = img.dimensions();
    let texels = img.pixels().map(|p| p.0).collect();
    Ok((w, h, texels))
}
