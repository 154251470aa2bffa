//! `gilab bench`: BVH traversal throughput per scene, split into camera rays and diffuse bounce
//! rays (Mrays/s, rays counted on the GPU like every technique's), and the reference path
//! tracer's ms/frame. Frames run back to back after a clock warm-up. Prints numbers; asserts
//! nothing.

use crate::app::{headless::HeadlessViewer, session::ReferenceSource, ViewerOptions};
use crate::gpu::{calibrate::Calibration, shaders::ShaderLibrary, timing::PassTimer, Gpu};
use crate::preset::LoadedPreset;
use crate::render::params::{ParamChanges, ParamKind, ParamSpec, Params};
use crate::render::{
    engine::Engine, engine::EngineSettings, pipelines, PassInfo, RayCounts, RenderContext,
    Technique,
};
use crate::scene::{builtin, features::SceneFeatures, gpu_scene::GpuScene};
use crate::techniques::create_technique;
use anyhow::Result;
use std::sync::Arc;

/// Diffuse bounces of the bounce-ray measurement (the camera-ray one traces none).
pub const BENCH_BOUNCES: u32 = 3;
/// Frames rendered back to back before each timed series (after the calibration warm-up).
const WARMUP_FRAMES: u32 = 4;

const TRACE_PARAMS: &[ParamSpec] = &[ParamSpec {
    name: "bounces",
    what: "cosine-sampled diffuse bounce rays traced after each camera ray (a path ends at a miss)",
    higher: "more bounce rays per pixel",
    lower: "fewer; 0 traces camera rays alone",
    kind: ParamKind::Int { min: 0, max: 8 },
    default: BENCH_BOUNCES as f64,
}];

/// Camera ray plus `bounces` diffuse bounces per pixel, closest hit: traversal cost alone.
struct TraceBench {
    params: Params,
    pipeline: Option<wgpu::ComputePipeline>,
    bind_group: Option<wgpu::BindGroup>,
    checksum: Option<wgpu::Buffer>,
    /// `BenchSettings` of shaders/bench/trace_rays.wgsl: bounces and padding.
    settings: Option<wgpu::Buffer>,
}

/// The trace benchmark's parameters with `bounces`.
fn bounces(bounces: u32) -> ParamChanges {
    ParamChanges::new().int("bounces", bounces as i64)
}

impl TraceBench {
    fn new(bounces: u32) -> Result<TraceBench> {
        let mut params = Params::new("bench-trace", TRACE_PARAMS);
        params.apply(&self::bounces(bounces))?;
        Ok(TraceBench {
            params,
            pipeline: None,
            bind_group: None,
            checksum: None,
            settings: None,
        })
    }
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
        let layout = pipelines::layout(
            ctx.gpu,
            "bench",
            &[
                pipelines::storage_entry(0, false),
                pipelines::uniform_entry(1, wgpu::ShaderStages::COMPUTE),
            ],
        );
        let pipeline = ctx.pipeline("bench/trace_rays.wgsl", &layout)?;
        let checksum = pipelines::storage_buffer(
            ctx.gpu,
            "bench checksum",
            (ctx.extent[0] * ctx.extent[1]) as u64 * 16,
        );
        let settings = self.settings.take().unwrap_or_else(|| {
            ctx.gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("bench settings"),
                size: 16,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        });
        self.bind_group = Some(pipelines::buffers_bind_group(
            ctx.gpu,
            "bench",
            &layout,
            &[&checksum, &settings],
        ));
        self.pipeline = Some(pipeline);
        self.checksum = Some(checksum);
        self.settings = Some(settings);
        self.apply_params(ctx)
    }
    fn apply_params(&mut self, ctx: &RenderContext) -> Result<()> {
        if let Some(b) = &self.settings {
            ctx.gpu.queue.write_buffer(
                b,
                0,
                bytemuck::cast_slice(&[self.params.u32("bounces"), 0u32, 0, 0]),
            );
        }
        Ok(())
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
    fn set_params(&mut self, p: &ParamChanges) -> Result<()> {
        self.params.apply(p)
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

/// One timed series: per-frame GPU ms and the rays the GPU counted in its frames.
struct Series {
    ms: Vec<f64>,
    rays: RayCounts,
}

impl Series {
    fn min_ms(&self) -> f64 {
        stats(self.ms.clone()).0
    }
    fn median_ms(&self) -> f64 {
        stats(self.ms.clone()).1
    }
    /// Rays of one kind (`render::RAY_KINDS` index) per frame.
    fn per_frame(&self, kind: usize) -> f64 {
        self.rays.by_kind[kind] as f64 / self.ms.len().max(1) as f64
    }
    fn total_per_frame(&self) -> f64 {
        self.rays.total() as f64 / self.ms.len().max(1) as f64
    }
}

/// `warmup` frames, then `frames` frames submitted back to back (up to 3 in flight, so the
/// GPU never waits for the CPU between them).
fn timed_series(e: &mut Engine, warmup: u32, frames: u32) -> Result<Series> {
    for _ in 0..warmup {
        e.submit_frame(None)?;
    }
    e.finish_frames()?;
    e.take_completed();
    let before = e.ray_counts()?;
    for _ in 0..frames {
        e.submit_frame(None)?;
    }
    e.finish_frames()?;
    let results = e.take_completed();
    let after = e.ray_counts()?;
    let mut rays = after;
    for (r, b) in rays.by_kind.iter_mut().zip(before.by_kind) {
        *r = r.saturating_sub(b);
    }
    Ok(Series {
        ms: results.iter().map(|r| r.report.gpu_ms).collect(),
        rays,
    })
}

/// Rays per second in millions from rays per frame and ms per frame.
fn mrays(rays_per_frame: f64, ms: f64) -> Option<f64> {
    (ms > 0.0).then(|| rays_per_frame / ms / 1e3)
}

fn fmt_opt(v: Option<f64>, width: usize) -> String {
    v.map_or(format!("{:>width$}", "n/a"), |v| format!("{v:>width$.1}"))
}

pub fn run(gpu: Arc<Gpu>, extent: [u32; 2], frames: u32, scenes: &[String]) -> Result<()> {
    const CAMERA: usize = 0;
    const INDIRECT: usize = 2;
    debug_assert_eq!(crate::render::RAY_KINDS[CAMERA], "camera");
    debug_assert_eq!(crate::render::RAY_KINDS[INDIRECT], "indirect");
    let scenes: Vec<String> = if scenes.is_empty() {
        vec!["cornell".into(), largest_builtin()?]
    } else {
        scenes.to_vec()
    };
    let shaders = ShaderLibrary::discover();
    let mut calibration = Calibration::new(&gpu, &shaders)?;
    println!(
        "{}x{}, {frames} frames back to back per series after a clock warm-up and {WARMUP_FRAMES} \
         frames; Mrays/s from the per-frame median GPU time",
        extent[0], extent[1]
    );
    println!(
        "{:<12} {:>10} {:>9} {:>9} {:>9} {:>17} {:>17} {:>8} {:>10} {:>9}",
        "",
        "",
        "primary",
        "diffuse",
        "mixed",
        "camera rays ms",
        "+3 bounces ms",
        "bounce",
        "reference",
        "ref rays"
    );
    println!(
        "{:<12} {:>10} {:>9} {:>9} {:>9} {:>17} {:>17} {:>8} {:>10} {:>9}",
        "scene",
        "triangles",
        "Mrays/s",
        "Mrays/s",
        "Mrays/s",
        "min / median",
        "min / median",
        "rays/px",
        "ms/frame",
        "/px/frame"
    );
    let mut notes = Vec::new();
    let mut tree_notes = Vec::new();
    // A scene with instances is measured twice: two-level BVH, then flat (same triangles).
    let mut runs = Vec::new();
    for name in scenes {
        let scene = builtin::build(&name, &toml::Table::new())?;
        if !scene.instances.is_empty() {
            let mut flat = scene.clone();
            flat.instances.clear();
            runs.push((name.clone(), scene));
            runs.push((format!("{name} flat"), flat));
        } else {
            runs.push((name, scene));
        }
    }
    for (name, scene) in runs {
        let camera = scene.default_camera();
        let tris = scene.triangles.len();
        let gpu_scene = Arc::new(GpuScene::upload(&gpu, &scene));
        let b = &gpu_scene.data.bvh;
        tree_notes.push(format!(
            "{name}: {} ({} nodes, {:.1} MiB, depth {}, built in {:.0} ms)",
            if b.instances > 0 {
                format!(
                    "two-level BVH, {} instances of {} meshes",
                    b.instances, b.instanced_meshes
                )
            } else {
                "flat BVH".to_string()
            },
            b.nodes.len(),
            (b.nodes.len() * 32) as f64 / (1u64 << 20) as f64,
            b.depth,
            gpu_scene.data.timings.bvh_build_ms
        ));
        let scene = Arc::new(scene);
        let settings = || EngineSettings {
            extent,
            seed: 1,
            camera,
        };
        let engine = |t: Box<dyn Technique>| {
            Engine::with_shared_scene(
                gpu.clone(),
                shaders.clone(),
                scene.clone(),
                gpu_scene.clone(),
                t,
                settings(),
            )
        };

        // Camera rays alone, then the same camera rays plus BENCH_BOUNCES diffuse bounces:
        // the difference of the two times is what the bounce rays cost.
        let mut e = engine(Box::new(TraceBench::new(0)?))?;
        let (before, warm_ms) = calibration.warm_up(&gpu)?;
        let clock_before = calibration.clock();
        let primary = timed_series(&mut e, WARMUP_FRAMES, frames)?;
        e.set_params(&bounces(BENCH_BOUNCES))?;
        let bounced = timed_series(&mut e, WARMUP_FRAMES, frames)?;
        let after = calibration.measure(&gpu)?;
        let check = calibration.check(before, after, warm_ms, (clock_before, calibration.clock()));
        drop(e);

        let primary_mrays = mrays(primary.per_frame(CAMERA), primary.median_ms());
        let bounce_ms = bounced.median_ms() - primary.median_ms();
        let diffuse_mrays = mrays(bounced.per_frame(INDIRECT), bounce_ms);
        let mixed_mrays = mrays(bounced.total_per_frame(), bounced.median_ms());
        let pixels = (extent[0] * extent[1]) as f64;

        let mut reference = create_technique("reference")?;
        reference.set_params(&ParamChanges::new().int("samples_per_frame", 1))?;
        let mut e = engine(reference)?;
        calibration.warm_up(&gpu)?;
        let reference = timed_series(&mut e, WARMUP_FRAMES, frames)?;
        drop(e);

        println!(
            "{:<12} {:>10} {} {} {} {:>17} {:>17} {:>8.2} {:>10.2} {:>9.2}",
            name,
            tris,
            fmt_opt(primary_mrays, 9),
            fmt_opt(diffuse_mrays, 9),
            fmt_opt(mixed_mrays, 9),
            format!("{:.3} / {:.3}", primary.min_ms(), primary.median_ms()),
            format!("{:.3} / {:.3}", bounced.min_ms(), bounced.median_ms()),
            bounced.per_frame(INDIRECT) / pixels,
            reference.median_ms(),
            reference.total_per_frame() / pixels,
        );
        notes.push(format!("{name}: {}", check.summary()));
    }
    println!(
        "primary: camera rays / camera-rays-only time; diffuse: bounce rays / (time with \
         {BENCH_BOUNCES} bounces - camera-rays-only time);\nmixed: all rays / time with \
         {BENCH_BOUNCES} bounces (the one number earlier versions reported); bounce rays/px: \
         per frame (a path ends at a miss);\nreference: path tracer, 1 spp/frame, median GPU ms."
    );
    for n in tree_notes {
        println!("{n}");
    }
    for n in notes {
        println!("clock check, {n}");
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
    /// A playing scene (`[scene] time_scale`): CPU ms per frame of re-posing it (motion, BVH
    /// top level, scene buffers written), min / median / max; and wall ms of the technique's
    /// reaction (which may wait for frames in flight).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reposing_ms: Option<[f64; 3]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reaction_ms: Option<[f64; 3]>,
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
    // Timed as experiments time them: debug-only work off unless the preset asks for it.
    let mut timed = p.clone();
    for entry in &mut timed.preset.techniques {
        *entry = crate::techniques::entry_for_timing(entry);
    }
    let p = &timed;
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
        let (mut reposing, mut reaction) = (Vec::new(), Vec::new());
        for _ in 0..frames {
            e.submit_frame(None)?;
            reposing.push(e.last_motion_ms);
            reaction.push(e.last_reaction_ms);
            results.extend(e.take_completed());
        }
        let plays = e.scene.motion.as_ref().is_some_and(|m| m.time_scale != 0.0);
        let three = |v: Vec<f64>| {
            let (a, b, c) = stats(v);
            [a, b, c]
        };
        let (reposing_ms, reaction_ms) = if plays {
            (Some(three(reposing)), Some(three(reaction)))
        } else {
            (None, None)
        };
        let after = calibration.measure(&gpu)?;
        e.finish_frames()?;
        results.extend(e.take_completed());
        let check = calibration.check(before, after, warm_ms, (clock_before, calibration.clock()));
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
            reposing_ms,
            reaction_ms,
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
        if let (Some([a, b, c]), Some([d, e, f])) = (t.reposing_ms, t.reaction_ms) {
            println!("  scene re-posing (CPU ms per frame): {a:.3} / {b:.3} / {c:.3}");
            println!("  technique's reaction and restart (wall ms): {d:.3} / {e:.3} / {f:.3}");
        }
    }
    Ok(out)
}
