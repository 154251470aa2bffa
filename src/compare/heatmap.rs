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

/// Log10 histogram bins behind heatmap ranges; `shaders/compare/shared.wgsl` has the same
/// constants (the viewer builds the histogram on the GPU).
pub const HIST_LO: f32 = -16.0;
pub const HIST_PER_DECADE: f32 = 64.0;
pub const HIST_BINS: u32 = 1536;

fn hist_bin(v: f32) -> usize {
    ((v.log10() - HIST_LO) * HIST_PER_DECADE)
        .floor()
        .clamp(0.0, (HIST_BINS - 1) as f32) as usize
}

/// Counts of the positive finite values per log10 bin.
pub fn histogram(values: &[f32]) -> Vec<u32> {
    let mut h = vec![0u32; HIST_BINS as usize];
    for &v in values {
        if v.is_finite() && v > 0.0 {
            h[hist_bin(v)] += 1;
        }
    }
    h
}

/// A log10 display range from a histogram: from the bin holding the 1st percentile of the
/// positive finite values to the end of the bin holding the 99th (1/64 decade resolution), so a
/// few fireflies or black pixels do not flatten the rest. `None` when no value is positive.
pub fn range_from_histogram(counts: &[u32]) -> Option<(f32, f32)> {
    let total: u64 = counts.iter().map(|&c| c as u64).sum();
    if total == 0 {
        return None;
    }
    let rank = |q: f64| ((total - 1) as f64 * q).round() as u64;
    let bin_of = |r: u64| {
        let mut seen = 0u64;
        for (i, &c) in counts.iter().enumerate() {
            seen += c as u64;
            if seen > r {
                return i;
            }
        }
        counts.len() - 1
    };
    let edge = |b: usize| HIST_LO + b as f32 / HIST_PER_DECADE;
    let (lo, hi) = (edge(bin_of(rank(0.01))), edge(bin_of(rank(0.99)) + 1));
    Some(if hi - lo < 0.25 {
        (lo - 0.5, hi + 0.5)
    } else {
        (lo, hi)
    })
}

/// The log10 display range of a scalar map (`range_from_histogram` of its `histogram`).
pub fn log_range(values: &[f32]) -> Option<(f32, f32)> {
    range_from_histogram(&histogram(values))
}

/// Colour map resolution: positions are rounded to one of this many samples of viridis, on
/// the CPU and on the GPU alike (neighbouring samples differ by at most 1 per channel).
pub const COLOUR_MAP_SIZE: usize = 1024;

/// Colour of a position in [0, 1] on the map.
pub fn colour(t: f32) -> [u8; 3] {
    let i = (t.clamp(0.0, 1.0) * (COLOUR_MAP_SIZE - 1) as f32 + 0.5) as usize;
    let c = colorous::VIRIDIS.eval_continuous(i as f64 / (COLOUR_MAP_SIZE - 1) as f64);
    [c.r, c.g, c.b]
}

/// The colour map as packed RGBA8 words (r in the low byte), for the GPU display pass.
pub fn colour_map_rgba8() -> Vec<u32> {
    (0..COLOUR_MAP_SIZE)
        .map(|i| {
            let c = colorous::VIRIDIS.eval_continuous(i as f64 / (COLOUR_MAP_SIZE - 1) as f64);
            u32::from_le_bytes([c.r, c.g, c.b, 255])
        })
        .collect()
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
        let h = id_hash(id as u32);
        out.extend_from_slice(&[
            64 + (h & 0xBF) as u8,
            64 + ((h >> 8) & 0xBF) as u8,
            64 + ((h >> 16) & 0xBF) as u8,
            255,
        ]);
    }
    out
}

/// Integer hash (lowbias32, as `shaders/compare/display.wgsl`): neighbouring ids get unrelated
/// colours.
pub fn id_hash(mut x: u32) -> u32 {
    x ^= x >> 16;
    x = x.wrapping_mul(0x7feb_352d);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846c_a68b);
    x ^= x >> 16;
    x
}
