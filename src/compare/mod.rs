//! Images, error metrics against a reference, tonemapping and image files.

pub mod brdf_probe;
pub mod display;
pub mod flip;
pub mod heatmap;
pub mod io;
pub mod metrics;
pub mod tonemap;

pub use metrics::Metrics;

/// A linear HDR RGB image, row-major from the top-left.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<f32>,
}

impl Image {
    pub fn new(width: u32, height: u32) -> Image {
        Image {
            width,
            height,
            rgb: vec![0.0; (width * height * 3) as usize],
        }
    }
    pub fn from_rgba(width: u32, height: u32, px: &[[f32; 4]]) -> Image {
        Image {
            width,
            height,
            rgb: px.iter().flat_map(|p| [p[0], p[1], p[2]]).collect(),
        }
    }
    pub fn pixel(&self, x: u32, y: u32) -> [f32; 3] {
        let i = ((y * self.width + x) * 3) as usize;
        [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
    }
    pub fn non_finite_count(&self) -> usize {
        self.rgb.iter().filter(|v| !v.is_finite()).count()
    }
    pub fn mean(&self) -> [f64; 3] {
        let mut s = [0.0f64; 3];
        for p in self.rgb.chunks_exact(3) {
            for c in 0..3 {
                s[c] += p[c] as f64;
            }
        }
        let n = (self.rgb.len() / 3).max(1) as f64;
        s.map(|v| v / n)
    }
    pub fn max_value(&self) -> f32 {
        self.rgb.iter().copied().fold(0.0, f32::max)
    }
}
