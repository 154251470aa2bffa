//! The experiment's PNG plots (plotters, bitmap backend; text in egui's bundled Ubuntu font so
//! no system fonts are needed): error against GPU time and against rays (log-log, one line
//! per run), error against frame with the scripted events marked, and the Pareto front.

use super::rows::{Row, Summary};
use anyhow::{anyhow, Result};
use plotters::prelude::*;
use std::path::Path;

pub const FILES: [(&str, &str); 4] = [
    ("error_vs_time.png", "Error against GPU time (log-log)"),
    (
        "error_vs_rays.png",
        "Error against rays per pixel (log-log)",
    ),
    (
        "error_vs_frame.png",
        "Error against frame, scripted events marked",
    ),
    (
        "pareto.png",
        "Error against GPU ms per frame, Pareto front joined",
    ),
];

pub(crate) const SIZE: (u32, u32) = (960, 640);

pub(crate) fn register_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // A bundled TTF cannot fail to parse; if it did, plots would lose only their text.
        let _ = plotters::style::register_font(
            "sans-serif",
            FontStyle::Normal,
            epaint_default_fonts::UBUNTU_LIGHT,
        );
    });
}

pub(crate) fn err<E: std::fmt::Debug>(e: E) -> anyhow::Error {
    anyhow!("plot: {e:?}")
}

/// Positive finite range padded to whole decades, for a log axis.
pub(crate) fn log_range(values: impl Iterator<Item = f64>) -> Option<std::ops::Range<f64>> {
    let (mut lo, mut hi) = (f64::MAX, f64::MIN);
    for v in values.filter(|v| v.is_finite() && *v > 0.0) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    (lo <= hi).then(|| {
        10f64.powf(lo.log10().floor())..10f64.powf(hi.log10().ceil().max(lo.log10().floor() + 1.0))
    })
}

/// Tableau 10: distinct on white, unlike plotters' default palette's pale yellows.
pub(crate) fn colour(i: usize) -> RGBAColor {
    let c = colorous::TABLEAU10[i % colorous::TABLEAU10.len()];
    RGBAColor(c.r, c.g, c.b, 1.0)
}

pub(crate) type Chart<'a, X, Y> = ChartContext<'a, BitMapBackend<'a>, Cartesian2d<X, Y>>;

/// One line per run, in the run's colour, with its legend entry; `keep` drops points a log
/// axis cannot show.
fn lines<X, Y>(
    chart: &mut Chart<'_, X, Y>,
    data: &Series,
    keep: impl Fn(&(f64, f64)) -> bool,
) -> Result<()>
where
    X: Ranged<ValueType = f64>,
    Y: Ranged<ValueType = f64>,
{
    for (i, (label, p)) in data.iter().enumerate() {
        let colour = colour(i);
        let p: Vec<(f64, f64)> = p.iter().copied().filter(|v| keep(v)).collect();
        chart
            .draw_series(LineSeries::new(p, colour.stroke_width(2)))
            .map_err(err)?
            .label(label.as_str())
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
            });
    }
    Ok(())
}

pub(crate) fn legend<X: Ranged, Y: Ranged>(chart: &mut Chart<'_, X, Y>) -> Result<()> {
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 15))
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(err)
}

type Series = Vec<(String, Vec<(f64, f64)>)>;

fn series(s: &Summary, rows: &[Row], x: impl Fn(&Row) -> f64, all_states: bool) -> Series {
    let metric = s.settings.metric;
    s.runs
        .iter()
        .map(|run| {
            let mut pts: Vec<(u32, (f64, f64))> = rows
                .iter()
                .filter(|r| r.run == run.spec.index && (all_states || r.state == 0))
                .map(|r| (r.frame, (x(r), r.error(metric))))
                .collect();
            pts.sort_by_key(|p| p.0);
            (
                run.spec.label.clone(),
                pts.into_iter().map(|p| p.1).collect(),
            )
        })
        .collect()
}

pub(crate) type Root<'a> = DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>;

/// Draws with `draw` on a white canvas and writes the PNG (an empty chart when no data).
pub(crate) fn png(path: &Path, draw: impl FnOnce(&Root) -> Result<()>) -> Result<()> {
    let mut buf = vec![255u8; (SIZE.0 * SIZE.1 * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(err)?;
        draw(&root)?;
        root.present().map_err(err)?;
    }
    let img =
        image::RgbImage::from_raw(SIZE.0, SIZE.1, buf).ok_or_else(|| anyhow!("plot buffer"))?;
    img.save(path)
        .map_err(|e| anyhow!("writing {}: {e}", path.display()))
}

fn log_log(path: &Path, title: &str, x_desc: &str, y_desc: &str, data: &Series) -> Result<()> {
    png(path, |root| {
        let pts = || data.iter().flat_map(|(_, p)| p.iter());
        let (Some(xr), Some(yr)) = (log_range(pts().map(|p| p.0)), log_range(pts().map(|p| p.1)))
        else {
            return Ok(());
        };
        let mut chart = ChartBuilder::on(root)
            .caption(title, ("sans-serif", 22))
            .margin(12)
            .x_label_area_size(44)
            .y_label_area_size(72)
            .build_cartesian_2d(xr.log_scale(), yr.log_scale())
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc(x_desc)
            .y_desc(y_desc)
            .x_label_formatter(&|v| format!("{v:.0e}"))
            .y_label_formatter(&|v| format!("{v:.0e}"))
            .draw()
            .map_err(err)?;
        lines(&mut chart, data, |(x, y)| *x > 0.0 && *y > 0.0)?;
        legend(&mut chart)?;
        Ok(())
    })
}

fn by_frame(path: &Path, s: &Summary, rows: &[Row]) -> Result<()> {
    let data = series(s, rows, |r| r.frame as f64, true);
    png(path, |root| {
        let max_frame = rows.iter().map(|r| r.frame).max().unwrap_or(1) as f64;
        let Some(yr) = log_range(data.iter().flat_map(|(_, p)| p.iter().map(|p| p.1))) else {
            return Ok(());
        };
        let (y0, y1) = (yr.start, yr.end);
        let mut chart = ChartBuilder::on(root)
            .caption(
                format!("{} against frame", s.analysis.metric),
                ("sans-serif", 22),
            )
            .margin(12)
            .x_label_area_size(44)
            .y_label_area_size(72)
            .build_cartesian_2d(0.0..max_frame + 1.0, yr.log_scale())
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc("frame")
            .y_desc(s.analysis.metric.as_str())
            .y_label_formatter(&|v| format!("{v:.0e}"))
            .draw()
            .map_err(err)?;
        for e in &s.settings.events {
            let x = e.frame as f64 + 0.5;
            chart
                .draw_series(std::iter::once(PathElement::new(
                    vec![(x, y0), (x, y1)],
                    BLACK.stroke_width(1),
                )))
                .map_err(err)?
                .label(e.describe())
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK));
        }
        lines(&mut chart, &data, |(_, y)| *y > 0.0)?;
        legend(&mut chart)?;
        Ok(())
    })
}

fn pareto(path: &Path, s: &Summary) -> Result<()> {
    let a = &s.analysis;
    png(path, |root| {
        let (Some(xr), Some(yr)) = (
            log_range(a.pareto.iter().map(|p| p.ms_per_frame)),
            log_range(a.pareto.iter().map(|p| p.error)),
        ) else {
            return Ok(());
        };
        let mut chart = ChartBuilder::on(root)
            .caption(
                if a.real_time.is_empty() {
                    format!(
                        "{} after {} frames against GPU ms/frame",
                        a.metric, a.pareto_frame
                    )
                } else {
                    format!("median per-frame {} against median GPU ms/frame", a.metric)
                },
                ("sans-serif", 22),
            )
            .margin(12)
            .x_label_area_size(44)
            .y_label_area_size(72)
            .build_cartesian_2d(xr.log_scale(), yr.log_scale())
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc("GPU ms per frame")
            .y_desc(a.metric.as_str())
            .x_label_formatter(&|v| format!("{v:.1e}"))
            .y_label_formatter(&|v| format!("{v:.0e}"))
            .draw()
            .map_err(err)?;
        let mut front: Vec<(f64, f64)> = a
            .pareto
            .iter()
            .filter(|p| p.on_front && p.error > 0.0)
            .map(|p| (p.ms_per_frame, p.error))
            .collect();
        front.sort_by(|x, y| x.0.total_cmp(&y.0));
        chart
            .draw_series(LineSeries::new(front, BLACK.stroke_width(1)))
            .map_err(err)?;
        for (i, p) in a.pareto.iter().enumerate().filter(|(_, p)| p.error > 0.0) {
            let colour = colour(i);
            chart
                .draw_series(std::iter::once(Circle::new(
                    (p.ms_per_frame, p.error),
                    6,
                    colour.filled(),
                )))
                .map_err(err)?
                .label(p.label.as_str())
                .legend(move |(x, y)| Circle::new((x + 10, y), 5, colour.filled()));
        }
        legend(&mut chart)?;
        Ok(())
    })
}

pub fn write_all(s: &Summary, rows: &[Row], out: &Path) -> Result<()> {
    register_font();
    let metric = s.analysis.metric.as_str();
    log_log(
        &out.join(FILES[0].0),
        &format!("{metric} against GPU time (before any event)"),
        "GPU ms (cumulative)",
        metric,
        &series(s, rows, |r| r.gpu_ms_cum, false),
    )?;
    log_log(
        &out.join(FILES[1].0),
        &format!("{metric} against rays (before any event)"),
        "rays per pixel (cumulative)",
        metric,
        &series(s, rows, |r| r.rays_per_pixel, false),
    )?;
    by_frame(&out.join(FILES[2].0), s, rows)?;
    pareto(&out.join(FILES[3].0), s)
}
