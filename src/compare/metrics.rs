//! Error metrics in linear HDR, over all pixels and channels (definitions from shared/ANCHORS.md):
//! MSE = mean((x-y)^2); relMSE = mean((x-y)^2 / (y^2 + 0.01)); SMAPE = mean(|x-y| / (|x|+|y|+0.01)).
//! `y` is the reference.

use super::Image;
use anyhow::{ensure, Result};
use serde::Serialize;

#[derive(Clone, Copy, Debug, Default, Serialize, PartialEq)]
pub struct Metrics {
    pub mse: f64,
    pub rel_mse: f64,
    pub smape: f64,
}

pub fn compare(image: &Image, reference: &Image) -> Result<Metrics> {
    ensure!(
        image.width == reference.width && image.height == reference.height,
        "image sizes differ: {}x{} vs reference {}x{}",
        image.width,
        image.height,
        reference.width,
        reference.height
    );
    let (mut mse, mut rel, mut smape) = (0.0f64, 0.0f64, 0.0f64);
    for (&x, &y) in image.rgb.iter().zip(&reference.rgb) {
        let (x, y) = (x as f64, y as f64);
        let d = x - y;
        mse += d * d;
        rel += d * d / (y * y + 0.01);
        smape += d.abs() / (x.abs() + y.abs() + 0.01);
    }
    let n = image.rgb.len().max(1) as f64;
    Ok(Metrics {
        mse: mse / n,
        rel_mse: rel / n,
        smape: smape / n,
    })
}

/// Per-pixel relMSE (mean over channels): the error heatmap whose mean is `compare().rel_mse`.
pub fn rel_mse_map(image: &Image, reference: &Image) -> Vec<f32> {
    image
        .rgb
        .chunks_exact(3)
        .zip(reference.rgb.chunks_exact(3))
        .map(|(x, y)| {
            (0..3)
                .map(|c| {
                    let d = (x[c] - y[c]) as f64;
                    d * d / ((y[c] as f64).powi(2) + 0.01)
                })
                .sum::<f64>() as f32
                / 3.0
        })
        .collect()
}
