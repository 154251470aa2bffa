//! A/B screenshot: every visible pane as PNG (what the pane shows) + EXR (linear radiance) +
//! JSON (the same record `gilab shot` writes), one composite PNG of the panes side by side,
//! and `session.toml`: the preset as it is now (camera, parameters, panes), loadable again.

use super::session::Session;
use crate::compare::io;
use crate::jobs;
use anyhow::{Context, Result};
use std::path::{Path, PathBuf};

/// Writes a whole-window screenshot (egui's pixels, sRGB) as PNG.
pub fn save_window(image: &egui::ColorImage, path: &Path) -> Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let [w, h] = image.size;
    let rgba = image::RgbaImage::from_raw(w as u32, h as u32, image.as_raw().to_vec())
        .context("window screenshot: pixel count does not match its size")?;
    // The window is opaque: drop alpha so viewers do not show egui's premultiplied edges.
    image::DynamicImage::ImageRgba8(rgba)
        .to_rgb8()
        .save(path)
        .with_context(|| format!("writing {}", path.display()))
}

/// Writes the files into a new folder under `out_dir` and returns it.
pub fn save_ab(session: &Session, out_dir: &Path) -> Result<PathBuf> {
    let stamp = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_millis())
        .unwrap_or(0);
    let dir = out_dir.join(format!("ab-{stamp}"));
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let preset = session.current_preset();
    let panes = &session.panes[..session.layout.pane_count()];
    let mut tiles: Vec<(u32, u32, Vec<u8>)> = Vec::new();
    for (i, pane) in panes.iter().enumerate() {
        let run = &session.runs[pane.run];
        if run.engine.frame_index == 0 {
            continue;
        }
        let stem = format!(
            "pane{}-{}-{}",
            i + 1,
            sanitize(run.label()),
            format!("{:?}", pane.display).to_lowercase()
        );
        // The CPU path (the same images `gilab shot` writes), read back once for the files.
        let (rgba, radiance, _) = session.pane_pixels(pane).context("pane has no image yet")?;
        let radiance = &radiance;
        io::write_png_rgba(
            &dir.join(format!("{stem}.png")),
            radiance.width,
            radiance.height,
            rgba.clone(),
        )?;
        io::write_exr(&dir.join(format!("{stem}.exr")), radiance)?;
        let by_pass = run
            .last_frame
            .as_ref()
            .map(|f| f.gpu_ms_by_pass.iter().cloned().collect())
            .unwrap_or_default();
        let meta = jobs::metadata(&run.engine, &preset, &run.entry, radiance, by_pass)?;
        std::fs::write(
            dir.join(format!("{stem}.json")),
            serde_json::to_string_pretty(&meta)?,
        )?;
        tiles.push((radiance.width, radiance.height, rgba));
    }
    anyhow::ensure!(!tiles.is_empty(), "no pane has rendered an image yet");
    let (w, h) = composite_size(&tiles);
    let mut canvas = image::RgbaImage::new(w, h);
    let mut x0 = 0;
    for (tw, th, rgba) in tiles {
        if let Some(tile) = image::RgbaImage::from_raw(tw, th, rgba) {
            image::imageops::overlay(&mut canvas, &tile, x0 as i64, 0);
        }
        x0 += tw;
    }
    canvas
        .save(dir.join("composite.png"))
        .context("writing composite.png")?;
    std::fs::write(dir.join("session.toml"), preset.to_toml()?)?;
    Ok(dir)
}

fn composite_size(tiles: &[(u32, u32, Vec<u8>)]) -> (u32, u32) {
    let w = tiles.iter().map(|t| t.0).sum();
    let h = tiles.iter().map(|t| t.1).max().unwrap_or(1);
    (w, h)
}

fn sanitize(s: &str) -> String {
    s.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect()
}
