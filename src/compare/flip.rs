//! LDR FLIP (Andersson et al. 2020, "FLIP: A Difference Evaluator for Alternating Images")
//! through `nv-flip`, the gfx-rs bindings of NVIDIA's own C++ implementation, rather than a
//! re-implementation whose constants could drift from the published metric.
//!
//! HDR handling: both images go through the preset's display transform first (exposure, tone
//! curve, sRGB, 8 bits: exactly what the PNGs show) and LDR-FLIP compares those, so FLIP
//! measures the error a viewer of the tonemapped image sees. HDR-FLIP's exposure bracketing
//! is not used: it would fold several exposures into one number, which is not what a fixed
//! tonemap shows.

use super::{tonemap, Image};
use anyhow::{ensure, Result};

/// Pixels per degree FLIP's reference tools default to: a 0.7 m wide 3840-pixel monitor
/// seen from 0.7 m.
pub fn default_pixels_per_degree() -> f32 {
    let (distance, width_px, width_m) = (0.7f32, 3840.0f32, 0.7f32);
    distance * (width_px / width_m) * std::f32::consts::PI / 180.0
}

/// Per-pixel LDR-FLIP between two 8-bit sRGB RGB images (row-major, 3 bytes per pixel).
pub fn ldr_flip_map_srgb8(
    test: &[u8],
    reference: &[u8],
    width: u32,
    height: u32,
) -> Result<Vec<f32>> {
    let n = (width * height * 3) as usize;
    ensure!(
        test.len() == n && reference.len() == n,
        "FLIP: image data does not match {width}x{height} RGB"
    );
    ensure!(width > 0 && height > 0, "FLIP: empty image");
    let strips = strips(height, rayon::current_num_threads());
    if strips.len() <= 1 {
        return Ok(flip_whole(test, reference, width, height));
    }
    // LDR-FLIP is local: a pixel's value depends only on pixels within its filters' support
    // (about 10 pixels at the default pixels per degree), so horizontal strips with a halo
    // wider than that give the whole image's values; nv-flip itself runs on one thread.
    use rayon::prelude::*;
    let row = (width * 3) as usize;
    let parts: Vec<Vec<f32>> = strips
        .par_iter()
        .map(|&(y0, y1)| {
            let (h0, h1) = (y0.saturating_sub(HALO), (y1 + HALO).min(height));
            let rows = |img: &[u8]| img[h0 as usize * row..h1 as usize * row].to_vec();
            let map = flip_whole(&rows(test), &rows(reference), width, h1 - h0);
            let start = ((y0 - h0) * width) as usize;
            map[start..start + ((y1 - y0) * width) as usize].to_vec()
        })
        .collect();
    Ok(parts.concat())
}

/// Rows of halo around each strip: over twice FLIP's widest filter radius at the default
/// pixels per degree (the spatial filter's 3σ, 10 pixels; the feature filters', 9).
const HALO: u32 = 24;

/// Horizontal strips `[y0, y1)` for `threads` workers: one strip (no split) for small images,
/// where a halo would cost more than it saves.
fn strips(height: u32, threads: usize) -> Vec<(u32, u32)> {
    let min_rows = 4 * HALO;
    let n = (height / min_rows).clamp(1, threads.max(1) as u32);
    (0..n)
        .map(|i| (height * i / n, height * (i + 1) / n))
        .collect()
}

/// nv-flip on the whole of two images, one thread.
fn flip_whole(test: &[u8], reference: &[u8], width: u32, height: u32) -> Vec<f32> {
    let r = nv_flip::FlipImageRgb8::with_data(width, height, reference);
    let t = nv_flip::FlipImageRgb8::with_data(width, height, test);
    nv_flip::flip(r, t, default_pixels_per_degree()).to_vec()
}

/// Mean LDR-FLIP between two 8-bit sRGB RGB images (row-major, 3 bytes per pixel).
pub fn ldr_flip_srgb8(test: &[u8], reference: &[u8], width: u32, height: u32) -> Result<f64> {
    let values = ldr_flip_map_srgb8(test, reference, width, height)?;
    Ok(values.iter().map(|&v| v as f64).sum::<f64>() / values.len() as f64)
}

/// Per-pixel LDR-FLIP of `image` against `reference` after the display transform.
pub fn ldr_flip_map(image: &Image, reference: &Image, tm: &tonemap::Settings) -> Result<Vec<f32>> {
    ensure!(
        image.width == reference.width && image.height == reference.height,
        "image sizes differ"
    );
    let rgb = |img: &Image| -> Vec<u8> {
        // The curve and exposure only: a zone view is for looking, not for scoring.
        tonemap::to_srgb8(img, &tm.normal())
            .chunks_exact(4)
            .flat_map(|p| [p[0], p[1], p[2]])
            .collect()
    };
    ldr_flip_map_srgb8(&rgb(image), &rgb(reference), image.width, image.height)
}

/// Mean LDR-FLIP of `image` against `reference` after the display transform.
pub fn ldr_flip(image: &Image, reference: &Image, tm: &tonemap::Settings) -> Result<f64> {
    let values = ldr_flip_map(image, reference, tm)?;
    Ok(values.iter().map(|&v| v as f64).sum::<f64>() / values.len().max(1) as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Strips give the whole image's FLIP map value for value, on an image with edges, points
    /// and noise everywhere (so every filter sees structure across the strip seams).
    #[test]
    fn flip_in_strips_is_flip_of_the_whole_image() {
        let (w, h) = (301u32, 517u32);
        let mut state = 12345u32;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            state
        };
        let mut reference = Vec::new();
        let mut test = Vec::new();
        for y in 0..h {
            for x in 0..w {
                for c in 0..3 {
                    let base = if (x / 17 + y / 23 + c) % 2 == 0 {
                        40
                    } else {
                        200
                    };
                    reference.push(base as u8);
                    let noise = (next() % 61) as i32 - 30;
                    test.push((base + noise).clamp(0, 255) as u8);
                }
            }
        }
        let whole = flip_whole(&test, &reference, w, h);
        for threads in [2, 3, 5] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let split = pool
                .install(|| ldr_flip_map_srgb8(&test, &reference, w, h))
                .unwrap();
            assert!(strips(h, threads).len() > 1, "the image is split");
            assert_eq!(split.len(), whole.len());
            let worst = whole
                .iter()
                .zip(&split)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0f32, f32::max);
            assert_eq!(worst, 0.0, "{threads} strips: worst difference {worst}");
        }
        assert!(whole.iter().sum::<f32>() > 0.0, "the images differ");
    }
}
