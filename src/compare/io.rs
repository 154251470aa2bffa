//! Image files: linear EXR (float32) through `exr`, tonemapped PNG through `image`.

use super::{tonemap, Image as HdrImage};
use anyhow::{anyhow, ensure, Context, Result};
use std::path::Path;

pub fn write_exr(path: &Path, img: &HdrImage) -> Result<()> {
    use exr::prelude::*;
    let w = img.width as usize;
    write_rgb_file(path, w, img.height as usize, |x, y| {
        let i = (y * w + x) * 3;
        (img.rgb[i], img.rgb[i + 1], img.rgb[i + 2])
    })
    .map_err(|e| anyhow!("writing {}: {e}", path.display()))
}

pub fn read_exr(path: &Path) -> Result<HdrImage> {
    use exr::prelude::*;
    let image = read_first_rgba_layer_from_file(
        path,
        |res, _| HdrImage::new(res.width() as u32, res.height() as u32),
        |img: &mut HdrImage, pos, (r, g, b, _a): (f32, f32, f32, f32)| {
            let i = (pos.y() * img.width as usize + pos.x()) * 3;
            img.rgb[i] = r;
            img.rgb[i + 1] = g;
            img.rgb[i + 2] = b;
        },
    )
    .map_err(|e| anyhow!("reading {}: {e}", path.display()))?;
    Ok(image.layer_data.channel_data.pixels)
}

pub fn write_png(path: &Path, img: &HdrImage, tm: &tonemap::Settings) -> Result<()> {
    let rgba = tonemap::to_srgb8(img, tm);
    write_png_rgba(path, img.width, img.height, rgba)
}

pub fn write_png_rgba(path: &Path, width: u32, height: u32, rgba: Vec<u8>) -> Result<()> {
    ensure!(
        rgba.len() == (width * height * 4) as usize,
        "PNG data size mismatch"
    );
    let buf = image::RgbaImage::from_raw(width, height, rgba)
        .ok_or_else(|| anyhow!("PNG buffer size mismatch"))?;
    buf.save(path)
        .with_context(|| format!("writing {}", path.display()))
}
