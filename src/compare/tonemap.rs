//! Display transforms: exposure in EV stops, a tone curve, then the sRGB transfer function.

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
}

pub fn curve(op: Operator, x: f32) -> f32 {
    let x = x.max(0.0);
    match op {
        Operator::Aces => {
            ((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14)).clamp(0.0, 1.0)
        }
        Operator::Reinhard => x / (1.0 + x),
        Operator::Linear => x.min(1.0),
    }
}

pub fn linear_to_srgb(c: f32) -> f32 {
    if c <= 0.003_130_8 {
        c * 12.92
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    }
}

/// 8-bit sRGB RGBA; non-finite values show as magenta so they cannot hide.
pub fn to_srgb8(img: &Image, op: Operator, exposure_ev: f32) -> Vec<u8> {
    let scale = 2f32.powf(exposure_ev);
    let mut out = Vec::with_capacity(img.rgb.len() / 3 * 4);
    for p in img.rgb.chunks_exact(3) {
        if p.iter().any(|v| !v.is_finite()) {
            out.extend_from_slice(&[255, 0, 255, 255]);
            continue;
        }
        for &v in p {
            out.push((linear_to_srgb(curve(op, v * scale)) * 255.0 + 0.5).clamp(0.0, 255.0) as u8);
        }
        out.push(255);
    }
    out
}
