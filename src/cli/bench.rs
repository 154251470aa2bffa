//! `gilab bench`: BVH traversal throughput (Mrays/s, rays counted on the GPU like every
//! technique's) and reference path tracer ms/frame, per scene. Prints numbers; asserts nothing.

use crate::app::{headless::HeadlessViewer, session::ReferenceSource, ViewerOptions};
use crate::gpu::{shaders::ShaderLibrary, timing::PassTimer, Gpu};
use crate::preset::LoadedPreset;
use crate::render::params::Params;
use crate::render::{
    engine::Engine, engine::EngineSettings, pipelines, PassInfo, RenderContext, Technique,
};
use crate::scene::{builtin, features::SceneFeatures};
use crate::techniques::create_technique;
use anyhow::Result;
use std::sync::Arc;

/// Camera ray plus three diffuse bounces per pixel, closest hit: traversal cost alone.
struct TraceBench {
    /// No parameters.
    params: Params,
    pipeline: Option<wgpu::ComputePipeline>,
    bind_group: Option<wgpu::BindGroup>,
    checksum: Option<wgpu::Buffer>,
}

impl Technique for TraceBench {
    fn id(&self) -> &'static str {
        "bench-trace"
    }
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
    fn passes(&self, _: &SceneFeatures) -> Vec<PassInfo> {
        vec![PassInfo {
            name: "trace_rays",
            runs: true,
            why: "benchmark".into(),
        }]
    }
    fn build(&mut self, ctx: &RenderContext) -> Result<()> {
        let layout = pipelines::layout(ctx.gpu, "bench", &[pipelines::storage_entry(0, false)]);
        let pipeline = ctx.pipeline("bench/trace_rays.wgsl", &layout)?;
        let checksum = pipelines::storage_buffer(
            ctx.gpu,
            "bench checksum",
            (ctx.extent[0] * ctx.extent[1]) as u64 * 16,
        );
        self.bind_group = Some(pipelines::buffers_bind_group(
            ctx.gpu,
            "bench",
            &layout,
            &[&checksum],
        ));
        self.pipeline = Some(pipeline);
        self.checksum = Some(checksum);
        Ok(())
    }
    fn shader_files(&self) -> &'static [&'static str] {
        &["bench/trace_rays.wgsl"]
    }
    fn reset_history(&mut self, _: &Gpu) {}
    fn render(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
    ) {
        let (Some(p), Some(bg)) = (&self.pipeline, &self.bind_group) else {
            return;
        };
        pipelines::image_pass(ctx, enc, timer, "trace_rays", p, bg);
    }
    fn param_set(&self) -> &Params {
        &self.params
    }
    fn set_params(&mut self, p: &toml::Table) -> Result<()> {
        self.params.set("bench-trace", p)
    }
}

/// The built-in scene with the most triangles.
pub fn largest_builtin() -> Result<String> {
    let mut best = ("cornell".to_string(), 0usize);
    for (name, _) in builtin::NAMES {
        let s = builtin::build(name, &toml::Table::new())?;
        if s.triangles.len() > best.1 {
            best = (name.to_string(), s.triangles.len());
        }
    }
    Ok(best.0)
}

/// One warm-up frame (pipeline compilation happens lazily on some drivers), then `frames` timed ones.
fn timed_frames(mut e: Engine, frames: u32) -> Result<Engine> {
    e.render_frame()?;
    e.reset();
    for _ in 0..frames {
        e.render_frame()?;
    }
    Ok(e)
}

pub fn run(gpu: Arc<Gpu>, extent: [u32; 2], frames: u32, scenes: &[String]) -> Result<()> {
    let scenes: Vec<String> = if scenes.is_empty() {
        vec!["cornell".into(), largest_builtin()?]
    } else {
        scenes.to_vec()
    };
    println!(
        "{:<12} {:>9} {:>12} {:>14} {:>16} {:>14}",
        "scene", "triangles", "size", "trace Mrays/s", "reference ms/fr", "ref rays/px/fr"
    );
    for name in scenes {
        let scene = builtin::build(&name, &toml::Table::new())?;
        let camera = scene.default_camera();
        let tris = scene.triangles.len();
        let settings = || EngineSettings {
            extent,
            seed: 1,
            camera,
        };
        let bench = Box::new(TraceBench {
            params: Params::new("bench-trace", &[]),
            pipeline: None,
            bind_group: None,
            checksum: None,
        });
        let e = timed_frames(
            Engine::new(
                gpu.clone(),
                ShaderLibrary::discover(),
                scene.clone(),
                bench,
                settings(),
            )?,
            frames,
        )?;
        let rays = e.ray_counts()?.total() as f64;
        let mrays = rays / (e.total_gpu_ms * 1e-3) / 1e6;

        let mut reference = create_technique("reference")?;
        reference.set_params(&toml::toml! { samples_per_frame = 1 })?;
        let e = timed_frames(
            Engine::new(
                gpu.clone(),
                ShaderLibrary::discover(),
                scene,
                reference,
                settings(),
            )?,
            frames,
        )?;
        let ms = e.total_gpu_ms / frames as f64;
        let rpp = e.ray_counts()?.total() as f64 / (extent[0] * extent[1]) as f64 / frames as f64;
        println!(
            "{:<12} {:>9} {:>12} {:>14.2} {:>16.2} {:>14.2}",
            name,
            tris,
            format!("{}x{}", extent[0], extent[1]),
            mrays,
            ms,
            rpp
        );
    }
    println!(
        "(GPU time from timestamp queries: {})",
        if gpu.timestamp_period.is_some() {
            "yes"
        } else {
            "no, wall time"
        }
    );
    viewer_overhead(gpu, extent, frames)
}

/// The reference path tracer's frame inside the viewer (one technique frame per UI frame,
/// plus readback, heatmaps, panels, plots and egui's painting at 1400x900) against the same
/// frame headless. Wall time per frame, both waited for.
fn viewer_overhead(gpu: Arc<Gpu>, extent: [u32; 2], frames: u32) -> Result<()> {
    let text = format!(
        "[scene]\nsource = \"cornell\"\n[render]\nsize = [{}, {}]\n[view]\nlayout = \"single\"\n\
         [[techniques]]\nname = \"reference\"\nparams = {{ samples_per_frame = 1 }}\n",
        extent[0], extent[1]
    );
    let preset = LoadedPreset::from_text(&text, None)?;
    let mut e = crate::jobs::engine_for_entry(gpu.clone(), &preset, 0)?;
    e.render_frame()?;
    let mut headless = 0.0;
    for _ in 0..frames {
        headless += e.render_frame()?.wall_ms;
    }
    headless /= frames as f64;

    let mut options = ViewerOptions::new(preset);
    options.watch = false;
    options.cache_dir = std::env::temp_dir().join("gilab-bench-cache");
    let mut v = HeadlessViewer::new(gpu, options, [1400, 900])?;
    if let Some(s) = &mut v.app.session {
        // The same work as headless: no background reference in the measured frames.
        s.reference.source = ReferenceSource::Done;
    }
    // Default pacing (batches technique frames so painting stays under 20% of the time),
    // then interactive pacing (what the viewer does while the user drags or types).
    for (share, pacing) in [(v.app.max_ui_share, "default, idle"), (1.0, "interactive")] {
        v.app.max_ui_share = share;
        v.app.render_in_ui = true;
        for _ in 0..3 {
            v.frame()?;
        }
        let (mut ms, mut technique_frames) = (0.0, 0u32);
        for _ in 0..frames {
            let before = v
                .app
                .session
                .as_ref()
                .map_or(0, |s| s.runs[0].engine.frame_index);
            ms += v.frame()?;
            let after = v
                .app
                .session
                .as_ref()
                .map_or(0, |s| s.runs[0].engine.frame_index);
            technique_frames += after.saturating_sub(before).max(1);
        }
        let per_frame = ms / technique_frames as f64;
        println!(
            "viewer overhead, cornell {}x{} reference 1 spp/frame, {} pacing: \
             headless {:.1} ms/frame, in viewer {:.1} ms/frame ({:.2}x, {:.1} technique frames per UI frame)",
            extent[0],
            extent[1],
            pacing,
            headless,
            per_frame,
            per_frame / headless,
            technique_frames as f64 / frames as f64
        );
    }
    v.app.render_in_ui = false;
    let mut ui_only = 0.0;
    for _ in 0..frames {
        ui_only += v.frame()?;
    }
    println!(
        "viewer UI and egui painting at 1400x900 alone (no technique frame): {:.1} ms",
        ui_only / frames as f64
    );
    Ok(())
}

/// Per-pass statistics of one technique over the timed frames.
#[derive(Clone, Debug, serde::Serialize)]
pub struct PassStats {
    pub pass: String,
    pub min_ms: f64,
    pub median_ms: f64,
    pub max_ms: f64,
}

/// `gilab bench --preset`: one technique entry of a preset.
#[derive(Clone, Debug, serde::Serialize)]
pub struct TechniqueBench {
    pub label: String,
    pub technique: String,
    pub frames: u32,
    pub passes: Vec<PassStats>,
    pub frame_min_ms: f64,
    pub frame_median_ms: f64,
    pub frame_max_ms: f64,
    /// Rays per pixel per frame and rays per second of GPU time (whole frame), by kind too.
    pub rays_per_pixel: f64,
    pub mrays_per_s: f64,
    pub rays_by_kind: Vec<(String, u64)>,
    pub timing: String,
    pub clock_check: crate::gpu::calibrate::ClockCheck,
}

fn stats(mut v: Vec<f64>) -> (f64, f64, f64) {
    v.sort_by(f64::total_cmp);
    if v.is_empty() {
        return (0.0, 0.0, 0.0);
    }
    (v[0], v[v.len() / 2], v[v.len() - 1])
}

/// Every technique of a preset at its size: warm-up (calibration kernel stable, then
/// `warmup` frames), `frames` frames back to back, per-pass min/median/max GPU ms, rays/s,
/// and the clock check. Prints a table; returns the records (the CLI writes them as JSON).
pub fn preset(
    gpu: Arc<Gpu>,
    p: &LoadedPreset,
    frames: u32,
    warmup: u32,
) -> Result<Vec<TechniqueBench>> {
    let mut calibration =
        crate::gpu::calibrate::Calibration::new(&gpu, &ShaderLibrary::discover())?;
    let mut out = Vec::new();
    let [w, h] = p.preset.render.size;
    for (i, entry) in p.preset.techniques.iter().enumerate() {
        let mut e = crate::jobs::engine_for_entry(gpu.clone(), p, i)?;
        let (before, warm_ms) = calibration.warm_up(&gpu)?;
        let clock_before = calibration.clock();
        for _ in 0..warmup {
            e.submit_frame(None)?;
        }
        e.finish_frames()?;
        e.take_completed();
        let rays_before = e.ray_counts()?;
        let mut results = Vec::new();
        for _ in 0..frames {
            e.submit_frame(None)?;
            results.extend(e.take_completed());
        }
        let after = calibration.measure(&gpu)?;
        e.finish_frames()?;
        results.extend(e.take_completed());
        let check = crate::gpu::calibrate::Calibration::check(
            before,
            after,
            warm_ms,
            (clock_before, calibration.clock()),
        );
        let rays_after = results.last().map(|r| r.rays).unwrap_or_default();
        let mut names: Vec<String> = Vec::new();
        for r in &results {
            for (n, _) in &r.report.gpu_ms_by_pass {
                if !names.contains(n) {
                    names.push(n.clone());
                }
            }
        }
        let passes = names
            .iter()
            .map(|n| {
                let v = results
                    .iter()
                    .map(|r| {
                        r.report
                            .gpu_ms_by_pass
                            .iter()
                            .filter(|(m, _)| m == n)
                            .map(|(_, ms)| ms)
                            .sum::<f64>()
                    })
                    .collect();
                let (min_ms, median_ms, max_ms) = stats(v);
                PassStats {
                    pass: n.clone(),
                    min_ms,
                    median_ms,
                    max_ms,
                }
            })
            .collect();
        let frame_ms: Vec<f64> = results.iter().map(|r| r.report.gpu_ms).collect();
        let total_ms: f64 = frame_ms.iter().sum();
        let (frame_min_ms, frame_median_ms, frame_max_ms) = stats(frame_ms);
        let rays = rays_after.total().saturating_sub(rays_before.total());
        let by_kind = rays_after
            .named()
            .into_iter()
            .map(|(k, v)| {
                let before = rays_before
                    .named()
                    .into_iter()
                    .find(|(b, _)| *b == k)
                    .map_or(0, |b| b.1);
                (k.to_string(), v - before)
            })
            .collect();
        out.push(TechniqueBench {
            label: entry.display_name().to_string(),
            technique: entry.name.clone(),
            frames,
            passes,
            frame_min_ms,
            frame_median_ms,
            frame_max_ms,
            rays_per_pixel: rays as f64 / (w as f64 * h as f64) / frames as f64,
            mrays_per_s: rays as f64 / (total_ms * 1e-3).max(1e-12) / 1e6,
            rays_by_kind: by_kind,
            timing: results
                .first()
                .map_or("none".into(), |r| format!("{:?}", r.report.timing)),
            clock_check: check,
        });
    }
    println!(
        "{w}x{h}, {frames} frames back to back after warm-up; GPU ms per pass min / median / max"
    );
    for t in &out {
        println!(
            "\n{} ({}): frame {:.3} / {:.3} / {:.3} ms, {:.2} rays/px/frame, {:.1} Mrays/s [{}] {}",
            t.label,
            t.technique,
            t.frame_min_ms,
            t.frame_median_ms,
            t.frame_max_ms,
            t.rays_per_pixel,
            t.mrays_per_s,
            t.timing,
            t.clock_check.summary()
        );
        println!("  {:<24} {:>9} {:>9} {:>9}", "pass", "min", "median", "max");
        for p in &t.passes {
            println!(
                "  {:<24} {:>9.3} {:>9.3} {:>9.3}",
                p.pass, p.min_ms, p.median_ms, p.max_ms
            );
        }
        let kinds: Vec<String> = t
            .rays_by_kind
            .iter()
            .map(|(k, v)| {
                format!(
                    "{k} {:.2}/px",
                    *v as f64 / (w as f64 * h as f64) / frames as f64
                )
            })
            .collect();
        println!("  rays by kind: {}", kinds.join(", "));
    }
    Ok(out)
}
