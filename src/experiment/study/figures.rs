//! The study's pictures: per scene the Pareto plots (error against GPU ms per frame, one curve
//! per family with and without the denoiser, the budgets marked, the 1-spp reference as the
//! baseline) and, per budget, the equal-time images: every family's best run that fits, side by
//! side with the reference and each one's error heatmap, and crops where they differ most.

use super::analysis::{curves, SceneResult, StudyRun};
use crate::compare::{heatmap, io, metrics, tonemap, Image};
use crate::experiment::plot::{self, colour, err, log_range, png, register_font};
use anyhow::{anyhow, Context, Result};
use plotters::prelude::*;
use std::path::Path;

/// Error against median GPU ms per frame: `value` picks the error (relMSE or FLIP).
pub fn pareto(
    path: &Path,
    s: &SceneResult,
    budgets: &[f64],
    what: &str,
    value: impl Fn(&StudyRun) -> Option<f64>,
) -> Result<()> {
    register_font();
    let points: Vec<(&StudyRun, f64)> = s
        .runs
        .iter()
        .filter_map(|r| {
            value(r)
                .filter(|v| *v > 0.0 && v.is_finite())
                .map(|v| (r, v))
        })
        .filter(|(r, _)| r.ms_median > 0.0)
        .collect();
    png(path, |root| {
        let xs = points
            .iter()
            .map(|p| p.0.ms_median)
            .chain(budgets.iter().copied());
        let (Some(xr), Some(yr)) = (log_range(xs), log_range(points.iter().map(|p| p.1))) else {
            return Ok(());
        };
        let mut chart = ChartBuilder::on(root)
            .caption(
                format!(
                    "{}: median per-frame {what} against median GPU ms/frame",
                    s.name
                ),
                ("sans-serif", 22),
            )
            .margin(12)
            .x_label_area_size(44)
            .y_label_area_size(72)
            .build_cartesian_2d(xr.clone().log_scale(), yr.clone().log_scale())
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc("GPU ms per frame (median)")
            .y_desc(what)
            .x_label_formatter(&|v| format!("{v:.2}"))
            .y_label_formatter(&|v| format!("{v:.0e}"))
            .draw()
            .map_err(err)?;
        // The budgets, as vertical grey lines.
        for &b in budgets {
            chart
                .draw_series(std::iter::once(PathElement::new(
                    vec![(b, yr.start), (b, yr.end)],
                    RGBColor(230, 150, 150).stroke_width(2),
                )))
                .map_err(err)?;
        }
        if let Some(base) = s
            .baseline
            .as_ref()
            .and_then(|b| points.iter().find(|p| &p.0.label == b).map(|p| p.1))
        {
            chart
                .draw_series(std::iter::once(PathElement::new(
                    vec![(xr.start, base), (xr.end, base)],
                    BLACK.stroke_width(1),
                )))
                .map_err(err)?
                .label("reference, 1 path/px/frame")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK));
        }
        let families: Vec<String> =
            curves(&s.runs)
                .into_iter()
                .map(|c| c.0)
                .fold(Vec::new(), |mut v, f| {
                    if !v.contains(&f) {
                        v.push(f);
                    }
                    v
                });
        for (family, denoise) in curves(&s.runs) {
            let c = colour(families.iter().position(|f| *f == family).unwrap_or(0));
            let mut line: Vec<(f64, f64)> = points
                .iter()
                .filter(|p| p.0.family == family && p.0.denoise == denoise)
                .map(|p| (p.0.ms_median, p.1))
                .collect();
            line.sort_by(|a, b| a.0.total_cmp(&b.0));
            let width = if denoise { 1 } else { 2 };
            let label = if denoise {
                format!("{family} + denoiser")
            } else {
                family.clone()
            };
            chart
                .draw_series(LineSeries::new(line.clone(), c.stroke_width(width)))
                .map_err(err)?
                .label(label)
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(width))
                });
            if denoise {
                chart
                    .draw_series(line.iter().map(|p| TriangleMarker::new(*p, 7, c.filled())))
                    .map_err(err)?;
            } else {
                chart
                    .draw_series(line.iter().map(|p| Circle::new(*p, 5, c.filled())))
                    .map_err(err)?;
            }
        }
        plot::legend(&mut chart)?;
        Ok(())
    })
}

/// Tiles at most this wide in the side-by-side images (larger images are box-filtered down).
const TILE: u32 = 480;
/// Tiles and crops at least this wide (smaller ones are enlarged, nearest pixel: pixels stay
/// visible as squares).
const MIN_TILE: u32 = 192;
/// Space above each tile for its label.
const LABEL: u32 = 22;

/// An RGB canvas the tiles are copied into.
struct Canvas {
    w: u32,
    h: u32,
    rgb: Vec<u8>,
}

impl Canvas {
    fn new(w: u32, h: u32) -> Canvas {
        Canvas {
            w,
            h,
            rgb: vec![255; (w * h * 3) as usize],
        }
    }
    fn put(&mut self, x0: u32, y0: u32, w: u32, h: u32, rgba: &[u8]) {
        for y in 0..h.min(self.h.saturating_sub(y0)) {
            for x in 0..w.min(self.w.saturating_sub(x0)) {
                let s = ((y * w + x) * 4) as usize;
                let d = (((y0 + y) * self.w + x0 + x) * 3) as usize;
                self.rgb[d..d + 3].copy_from_slice(&rgba[s..s + 3]);
            }
        }
    }
    /// Writes the PNG with `labels` (x, y, text) drawn on it.
    fn save(mut self, path: &Path, labels: &[(u32, u32, String)]) -> Result<()> {
        register_font();
        {
            let root =
                BitMapBackend::with_buffer(&mut self.rgb, (self.w, self.h)).into_drawing_area();
            for (x, y, t) in labels {
                root.draw(&Text::new(
                    t.as_str(),
                    (*x as i32 + 4, *y as i32 + 3),
                    ("sans-serif", 16).into_font().color(&BLACK),
                ))
                .map_err(err)?;
            }
            root.present().map_err(err)?;
        }
        image::RgbImage::from_raw(self.w, self.h, self.rgb)
            .ok_or_else(|| anyhow!("image buffer"))?
            .save(path)
            .map_err(|e| anyhow!("writing {}: {e}", path.display()))
    }
}

/// Box-filtered by an integer factor: RGBA8 of the display transform, and a scalar map.
fn shrink_rgba(rgba: &[u8], w: u32, h: u32, k: u32) -> (u32, u32, Vec<u8>) {
    let (tw, th) = (w / k, h / k);
    let mut out = vec![0u8; (tw * th * 4) as usize];
    for ty in 0..th {
        for tx in 0..tw {
            let mut acc = [0u32; 4];
            for y in ty * k..ty * k + k {
                for x in tx * k..tx * k + k {
                    let s = ((y * w + x) * 4) as usize;
                    for c in 0..4 {
                        acc[c] += rgba[s + c] as u32;
                    }
                }
            }
            let d = ((ty * tw + tx) * 4) as usize;
            for c in 0..4 {
                out[d + c] = (acc[c] / (k * k)) as u8;
            }
        }
    }
    (tw, th, out)
}

/// Nearest-pixel enlargement by an integer factor.
fn enlarge_rgba(rgba: &[u8], w: u32, h: u32, u: u32) -> Vec<u8> {
    let mut out = Vec::with_capacity((w * h * u * u * 4) as usize);
    for y in 0..h * u {
        for x in 0..w * u {
            let s = (((y / u) * w + x / u) * 4) as usize;
            out.extend_from_slice(&rgba[s..s + 4]);
        }
    }
    out
}

/// A tile of a full image: box-filtered down by `k` and then enlarged by `u` (one of them 1).
fn tile(rgba: &[u8], w: u32, h: u32, k: u32, u: u32) -> Vec<u8> {
    let (sw, sh, small) = shrink_rgba(rgba, w, h, k);
    if u > 1 {
        enlarge_rgba(&small, sw, sh, u)
    } else {
        small
    }
}

fn shrink_scalar(v: &[f32], w: u32, h: u32, k: u32) -> Vec<f32> {
    let (tw, th) = (w / k, h / k);
    let mut out = vec![0f32; (tw * th) as usize];
    for ty in 0..th {
        for tx in 0..tw {
            let mut acc = 0f64;
            for y in ty * k..ty * k + k {
                for x in tx * k..tx * k + k {
                    acc += v[(y * w + x) as usize] as f64;
                }
            }
            out[(ty * tw + tx) as usize] = (acc / (k * k) as f64) as f32;
        }
    }
    out
}

/// A square window of the full image: x, y, side.
type Crop = (u32, u32, u32);

/// The window where the families' errors differ most: on a grid of half-overlapping windows,
/// the largest spread (max − min) of the families' mean per-pixel relMSE (clamped at 10 per
/// pixel, so that one firefly does not choose it).
fn crop_where_they_differ(maps: &[Vec<f32>], w: u32, h: u32) -> Crop {
    let side = (h / 5).clamp(8.min(h), 256).min(w);
    let step = (side / 2).max(1);
    let mut best = (0, 0, f64::MIN);
    let mut y = 0;
    while y + side <= h {
        let mut x = 0;
        while x + side <= w {
            let means: Vec<f64> = maps
                .iter()
                .map(|m| {
                    let mut s = 0.0;
                    for yy in y..y + side {
                        for xx in x..x + side {
                            s += (m[(yy * w + xx) as usize] as f64).min(10.0);
                        }
                    }
                    s / (side * side) as f64
                })
                .collect();
            let spread = means.iter().copied().fold(f64::MIN, f64::max)
                - means.iter().copied().fold(f64::MAX, f64::min);
            if spread > best.2 {
                best = (x, y, spread);
            }
            x += step;
        }
        y += step;
    }
    (best.0, best.1, side)
}

fn crop_rgba(rgba: &[u8], w: u32, c: Crop) -> Vec<u8> {
    let mut out = Vec::with_capacity((c.2 * c.2 * 4) as usize);
    for y in c.1..c.1 + c.2 {
        let s = ((y * w + c.0) * 4) as usize;
        out.extend_from_slice(&rgba[s..s + (c.2 * 4) as usize]);
    }
    out
}

/// One equal-time comparison: `runs` (label, image) beside the reference. Writes `path` (the
/// images in the top row, their relMSE heatmaps below on one shared log scale) and
/// `crops_path` (the window where they differ most, at full resolution). Returns the heatmap's
/// log10 range and the crop.
pub fn equal_time(
    path: &Path,
    crops_path: &Path,
    reference: &Image,
    runs: &[(String, Image)],
    tm: &tonemap::Settings,
) -> Result<((f32, f32), Crop)> {
    let (w, h) = (reference.width, reference.height);
    let k = w.div_ceil(TILE).max(1);
    let u = if k == 1 {
        MIN_TILE.div_ceil(w).max(1)
    } else {
        1
    };
    let (tw, th) = (w / k * u, h / k * u);
    let columns = runs.len() as u32 + 1;
    let maps: Vec<Vec<f32>> = runs
        .iter()
        .map(|(_, img)| metrics::rel_mse_map(img, reference))
        .collect();
    let all: Vec<f32> = maps.iter().flatten().copied().collect();
    let range = heatmap::log_range(&all).unwrap_or((-4.0, 0.0));
    let crop = crop_where_they_differ(&maps, w, h);
    let mut canvas = Canvas::new(columns * tw, 2 * (th + LABEL));
    let mut labels = Vec::new();
    let reference_rgba = tonemap::to_srgb8(reference, tm);
    // The crop's window, outlined on the reference.
    let mut outline = tile(&reference_rgba, w, h, k, u);
    let (cx, cy, cs) = (crop.0 / k * u, crop.1 / k * u, (crop.2 / k * u).max(2));
    for i in 0..cs {
        for (x, y) in [
            (cx + i, cy),
            (cx + i, cy + cs - 1),
            (cx, cy + i),
            (cx + cs - 1, cy + i),
        ] {
            if x < tw && y < th {
                let d = ((y * tw + x) * 4) as usize;
                outline[d..d + 3].copy_from_slice(&[255, 0, 255]);
            }
        }
    }
    canvas.put(0, LABEL, tw, th, &outline);
    labels.push((0, 0, "reference".to_string()));
    labels.push((
        0,
        th + LABEL,
        format!("relMSE 1e{:.1}..1e{:.1}", range.0, range.1),
    ));
    for (i, ((label, img), map)) in runs.iter().zip(&maps).enumerate() {
        let x0 = (i as u32 + 1) * tw;
        canvas.put(
            x0,
            LABEL,
            tw,
            th,
            &tile(&tonemap::to_srgb8(img, tm), w, h, k, u),
        );
        let heat = heatmap::to_rgba(&shrink_scalar(map, w, h, k), range.0, range.1);
        canvas.put(x0, th + 2 * LABEL, tw, th, &tile(&heat, w / k, h / k, 1, u));
        labels.push((x0, 0, label.clone()));
        labels.push((
            x0,
            th + LABEL,
            format!("mean relMSE {:.3e}", heatmap::mean(map)),
        ));
    }
    // The colour bar under the reference.
    let bar: Vec<u8> = (0..th)
        .flat_map(|_| {
            (0..tw).flat_map(|x| {
                let c = heatmap::colour(x as f32 / (tw - 1).max(1) as f32);
                [c[0], c[1], c[2], 255]
            })
        })
        .collect();
    canvas.put(0, th + 2 * LABEL, tw, (th / 6).max(4), &bar);
    canvas.save(path, &labels)?;

    // Crops at full resolution, enlarged when small.
    let cu = MIN_TILE.div_ceil(crop.2).max(1);
    let cw = crop.2 * cu;
    let mut crops = Canvas::new(columns * cw, cw + LABEL);
    let cropped = |rgba: &[u8]| enlarge_rgba(&crop_rgba(rgba, w, crop), crop.2, crop.2, cu);
    crops.put(0, LABEL, cw, cw, &cropped(&reference_rgba));
    let mut labels = vec![(0, 0, "reference".to_string())];
    for (i, (label, img)) in runs.iter().enumerate() {
        let x0 = (i as u32 + 1) * cw;
        crops.put(x0, LABEL, cw, cw, &cropped(&tonemap::to_srgb8(img, tm)));
        labels.push((x0, 0, label.clone()));
    }
    crops.save(crops_path, &labels)?;
    Ok((range, crop))
}

/// Reads a run's last-frame image (relative to the report folder).
pub fn read_image(out: &Path, rel: &str) -> Result<Image> {
    io::read_exr(&out.join(rel)).with_context(|| format!("image of {rel}"))
}
