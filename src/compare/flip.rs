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
    let r = nv_flip::FlipImageRgb8::with_data(width, height, reference);
    let t = nv_flip::FlipImageRgb8::with_data(width, height, test);
    Ok(nv_flip::flip(r, t, default_pixels_per_degree()).to_vec())
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
