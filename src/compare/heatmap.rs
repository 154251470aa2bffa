//! Heatmaps of per-pixel scalars (sample variance, relMSE) on a log10 scale through the
//! viridis colour map (from `colorous`: perceptually uniform, readable in greyscale and by
//! most colour-blind viewers). The range used is returned so the viewer can draw a colour bar.

use super::Image;

/// Per-pixel scalar for the variance heatmap: the mean of the r, g, b sample variances.
pub fn variance_scalar(variance: &Image) -> Vec<f32> {
    variance
        .rgb
        .chunks_exact(3)
        .map(|v| (v[0] + v[1] + v[2]) / 3.0)
        .collect()
}

/// A log10 display range: the 1st to 99th percentile of the positive finite values, so a
/// few fireflies or black pixels do not flatten the rest. `None` when no value is positive.
pub fn log_range(values: &[f32]) -> Option<(f32, f32)> {
    let mut logs: Vec<f32> = values
        .iter()
        .filter(|v| v.is_finite() && **v > 0.0)
        .map(|v| v.log10())
        .collect();
    if logs.is_empty() {
        return None;
    }
    logs.sort_by(f32::total_cmp);
    let at = |q: f32| logs[((logs.len() - 1) as f32 * q).round() as usize];
    let (lo, hi) = (at(0.01), at(0.99));
    Some(if hi - lo < 1e-3 {
        (lo - 0.5, hi + 0.5)
    } else {
        (lo, hi)
    })
}

/// Colour of a position in [0, 1] on the map.
pub fn colour(t: f32) -> [u8; 3] {
    let c = colorous::VIRIDIS.eval_continuous(t.clamp(0.0, 1.0) as f64);
    [c.r, c.g, c.b]
}

/// RGBA8 heatmap of `values` with log10 range `[lo, hi]`; zero maps to the bottom colour,
/// non-finite values to magenta (so they cannot hide).
pub fn to_rgba(values: &[f32], lo: f32, hi: f32) -> Vec<u8> {
    let span = (hi - lo).max(1e-6);
    let mut out = Vec::with_capacity(values.len() * 4);
    for &v in values {
        let rgb = if !v.is_finite() {
            [255, 0, 255]
        } else if v <= 0.0 {
            colour(0.0)
        } else {
            colour((v.log10() - lo) / span)
        };
        out.extend_from_slice(&[rgb[0], rgb[1], rgb[2], 255]);
    }
    out
}

/// Mean of a scalar map (f64 accumulation), e.g. the mean of the relMSE heatmap.
pub fn mean(values: &[f32]) -> f64 {
    values.iter().map(|&v| v as f64).sum::<f64>() / values.len().max(1) as f64
}

/// RGBA8 with one random colour per integer id (0 = none, black): light or cell ids.
pub fn id_colours(ids: &[f32]) -> Vec<u8> {
    let mut out = Vec::with_capacity(ids.len() * 4);
    for &id in ids {
        if id.is_nan() || id < 1.0 {
            out.extend_from_slice(&[0, 0, 0, 255]);
            continue;
        }
        // An integer hash (splitmix-style) spreads neighbouring ids over the colour space.
        let mut h = (id as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        h ^= h >> 31;
        h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
        h ^= h >> 29;
        out.extend_from_slice(&[
            64 + (h & 0xBF) as u8,
            64 + ((h >> 8) & 0xBF) as u8,
            64 + ((h >> 16) & 0xBF) as u8,
            255,
        ]);
    }
    out
}
