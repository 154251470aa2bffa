//! Runs an experiment: references per scene state (cached), then every run of the shard frame
//! by frame, recording time, rays and error after each frame.

use super::realtime::{self, FrameUse, RealTimePlan};
use super::report::{self, Analysis};
pub use super::rows::{read_output_dir, ReferenceInfo, Row, RunSummary, Summary};
use super::spec::{expand_runs, Event, Mode, RunSpec, Shard};
use crate::compare::{flip, io, metrics, Image};
use crate::gpu::{shaders::ShaderLibrary, Gpu};
use crate::jobs;
use crate::preset::{LoadedPreset, TechniqueEntry};
use crate::render::{engine::Engine, engine::EngineSettings, RAY_KINDS};
use crate::scene::{gpu_scene::GpuScene, Camera, Scene};
use crate::techniques::create_technique;
use anyhow::{ensure, Context, Result};

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

pub struct ConvergeOptions {
    pub out: PathBuf,
    pub cache: PathBuf,
    pub shard: Option<Shard>,
    pub quiet: bool,
}

/// A scene state: the preset's scene with the first `k` events applied.
struct SceneState {
    scene: Arc<Scene>,
    gpu_scene: Arc<GpuScene>,
    camera: Camera,
    /// The state's reference (accumulate mode; real-time mode renders one per frame).
    reference: Option<Image>,
    /// Image size of the experiment.
    extent: [u32; 2],
    info: ReferenceInfo,
}

pub fn git_commit() -> String {
    let out = std::process::Command::new("git")
        .args(["rev-parse", "HEAD"])
        .output();
    let dirty = std::process::Command::new("git")
        .args(["status", "--porcelain", "--untracked-files=no"])
        .output()
        .map(|o| !o.stdout.is_empty())
        .unwrap_or(false);
    match out {
        Ok(o) if o.status.success() => {
            let c = String::from_utf8_lossy(&o.stdout).trim().to_string();
            if dirty {
                format!("{c}-dirty")
            } else {
                c
            }
        }
        _ => "unknown".into(),
    }
}

pub fn sha256_hex(text: &str) -> String {
    use sha2::Digest;
    sha2::Sha256::digest(text.as_bytes())
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// The experiment name: `[experiment] name`, else the file stem.
pub fn experiment_name(p: &LoadedPreset) -> String {
    p.preset
        .experiment
        .as_ref()
        .and_then(|e| e.name.clone())
        .or_else(|| {
            p.path
                .as_ref()
                .and_then(|p| p.file_stem())
                .map(|s| s.to_string_lossy().to_string())
        })
        .unwrap_or_else(|| "experiment".into())
}

fn sorted_events(p: &LoadedPreset) -> Result<Vec<Event>> {
    let exp = p
        .preset
        .experiment
        .as_ref()
        .context("no [experiment] table")?;
    let mut events = exp.events.clone();
    events.sort_by_key(|e| e.frame);
    for e in &events {
        ensure!(
            e.frame >= 1 && e.frame < exp.frames,
            "event at frame {}: events must fall within frames 1..{} (frame 0 is the preset itself)",
            e.frame,
            exp.frames
        );
    }
    Ok(events)
}

/// The reference cache key of a scene state: the preset's key (`jobs::reference_key_for_camera`)
/// with the events applied so far hashed in (the Python module keys its edited scenes so too).
pub fn edited_reference_key(base_key: &str, events: &[Event]) -> Result<String> {
    use std::hash::Hasher;
    let mut h = fnv::FnvHasher::default();
    h.write(base_key.as_bytes());
    h.write(serde_json::to_string(events)?.as_bytes());
    Ok(format!("{:016x}", h.finish()))
}

fn build_states(
    gpu: &Arc<Gpu>,
    p: &LoadedPreset,
    events: &[Event],
    cache: &Path,
    quiet: bool,
    render_references: bool,
) -> Result<Vec<SceneState>> {
    let mut scene = p.load_scene()?;
    let mut camera = p.camera(&scene);
    let base_key = jobs::reference_key_for_camera(p, &camera);
    let setup = jobs::reference_setup(p);
    let mut states = Vec::new();
    for k in 0..=events.len() {
        if k > 0 {
            events[k - 1].apply(&mut scene, &mut camera)?;
            scene.validate()?;
        }
        // The key of an edited state adds the events applied so far.
        let key = if k == 0 {
            base_key.clone()
        } else {
            edited_reference_key(&base_key, &events[..k])?
        };
        let (reference, path) = if render_references {
            let (image, path) = jobs::reference_image(
                gpu.clone(),
                p,
                scene.clone(),
                camera,
                &key,
                cache,
                false,
                quiet,
            )?;
            (Some(image), path)
        } else {
            (None, cache.join(format!("{key}.exr")))
        };
        let gpu_scene = Arc::new(GpuScene::upload(gpu, &scene));
        states.push(SceneState {
            scene: Arc::new(scene.clone()),
            gpu_scene,
            camera,
            reference,
            extent: p.preset.render.size,
            info: ReferenceInfo {
                state: k,
                frame: None,
                from_frame: if k == 0 { 0 } else { events[k - 1].frame },
                key,
                cache_file: path.display().to_string(),
                spp: setup.spp,
                seed: setup.seed,
            },
        });
    }
    Ok(states)
}

/// Runs the experiment (or its shard), writes every output into `opts.out` and returns the
/// summary.
pub fn converge(gpu: Arc<Gpu>, p: &LoadedPreset, opts: &ConvergeOptions) -> Result<Summary> {
    let exp = p
        .preset
        .experiment
        .clone()
        .context("the preset has no [experiment] table: nothing to converge")?;
    ensure!(exp.frames >= 1, "experiment.frames must be at least 1");
    let runs = expand_runs(p)?;
    let events = sorted_events(p)?;
    // Events are checked on the CPU scene before any reference is rendered.
    {
        let mut scene = p.load_scene()?;
        let mut camera = p.camera(&scene);
        for e in &events {
            e.apply(&mut scene, &mut camera)?;
        }
        ensure!(
            exp.mode == Mode::RealTime || scene.motion.as_ref().is_none_or(|m| m.time_scale == 0.0),
            "scene.time_scale plays the scene, so every frame has its own pose: it needs mode = \"real-time\" (a reference per scored frame, at that frame's pose)"
        );
    }
    // Every run's technique and parameters are checked before any GPU work.
    for r in &runs {
        create_technique(&r.technique)?
            .set_params_from_table(&r.params)
            .with_context(|| format!("run '{}'", r.label))?;
    }
    let real_time = exp.mode == Mode::RealTime;
    let runs = if real_time {
        real_time_runs(runs, &exp, &events)?
    } else {
        ensure!(
            exp.camera_path.is_empty() && exp.frame_ms.is_empty() && exp.reference_every == 1,
            "[[experiment.camera]], frame_ms and reference_every belong to mode = \"real-time\""
        );
        runs
    };
    std::fs::create_dir_all(opts.out.join("runs"))
        .with_context(|| format!("creating {}", opts.out.display()))?;
    let states = build_states(&gpu, p, &events, &opts.cache, opts.quiet, !real_time)?;
    let plan = if real_time {
        Some(real_time_plan(&gpu, p, &states, &events, &exp, opts)?)
    } else {
        None
    };
    for (s, reference) in states
        .iter()
        .filter_map(|s| s.reference.as_ref().map(|r| (s, r)))
    {
        let name = format!("reference-state{}", s.info.state);
        io::write_exr(
            &opts.out.join("runs").join(format!("{name}.exr")),
            reference,
        )?;
        io::write_png(
            &opts.out.join("runs").join(format!("{name}.png")),
            reference,
            &p.preset.tonemap,
        )?;
    }
    let mine: Vec<&RunSpec> = runs
        .iter()
        .filter(|r| opts.shard.is_none_or(|s| s.takes(r.index)))
        .collect();
    let bar = jobs::progress_bar(
        mine.len() as u64 * exp.frames as u64,
        "converge",
        opts.quiet,
    );
    let shaders = ShaderLibrary::discover();
    let mut rows = Vec::new();
    let mut summaries = Vec::new();
    let mut calibration = crate::gpu::calibrate::Calibration::new(&gpu, &shaders)?;
    for (i, spec) in mine.iter().enumerate() {
        bar.set_message(format!("run {}/{}: {}", i + 1, mine.len(), spec.label));
        let (run_rows, summary) = run_one(
            &gpu,
            p,
            &shaders,
            &states,
            plan.as_ref(),
            &events,
            spec,
            &exp,
            opts,
            &bar,
            &mut calibration,
        )
        .with_context(|| format!("run '{}'", spec.label))?;
        rows.extend(run_rows);
        summaries.push(summary);
    }
    bar.finish_and_clear();
    let summary = Summary {
        experiment: experiment_name(p),
        file: p.path.as_ref().map(|p| p.display().to_string()),
        preset_sha256: sha256_hex(&p.to_toml()?),
        git_commit: git_commit(),
        adapter: gpu.summary.clone(),
        size: p.preset.render.size,
        seeds: runs
            .iter()
            .map(|r| r.seed)
            .collect::<std::collections::BTreeSet<_>>()
            .into_iter()
            .collect(),
        tonemap: p.preset.tonemap,
        settings: exp.clone(),
        total_runs: runs.len(),
        shards: opts.shard.into_iter().collect(),
        references: match &plan {
            Some(plan) => plan.infos.clone(),
            None => states.iter().map(|s| s.info.clone()).collect(),
        },
        motion_stop_frame: plan.as_ref().and_then(|p| p.motion_stop_frame),
        runs: summaries,
        analysis: Analysis::default(),
    };
    report::finish(summary, rows, &opts.out)
}

/// Real-time mode's checks and parameters: every technique shows single frames
/// (`accumulate = false`; an entry asking for accumulation is an error), camera keys are
/// ordered and do not clash with camera events.
fn real_time_runs(
    mut runs: Vec<RunSpec>,
    exp: &super::ExperimentSettings,
    events: &[Event],
) -> Result<Vec<RunSpec>> {
    ensure!(
        exp.reference_every >= 1,
        "reference_every must be at least 1"
    );
    ensure!(
        exp.error_every == 1,
        "mode = \"real-time\" scores frames with reference_every, not error_every"
    );
    ensure!(
        exp.frame_ms.iter().all(|m| m.is_finite() && *m > 0.0),
        "frame_ms: budgets must be positive milliseconds"
    );
    let mut frames: Vec<u32> = exp.camera_path.iter().map(|k| k.frame).collect();
    frames.sort_unstable();
    frames.dedup();
    ensure!(
        frames.len() == exp.camera_path.len(),
        "[[experiment.camera]]: two keys at the same frame"
    );
    ensure!(
        exp.camera_path.windows(2).all(|w| w[0].frame < w[1].frame),
        "[[experiment.camera]]: keys must be listed in frame order"
    );
    ensure!(
        exp.camera_path.is_empty() || events.iter().all(|e| e.camera.is_none()),
        "a camera path and camera events both move the camera: use one"
    );
    for r in &mut runs {
        let has = create_technique(&r.technique)?
            .params()
            .contains_key("accumulate");
        if !has {
            continue;
        }
        ensure!(
            r.params.get("accumulate").and_then(|v| v.as_bool()) != Some(true),
            "run '{}': accumulate = true contradicts mode = \"real-time\" (each frame is scored on its own)",
            r.label
        );
        r.params.insert("accumulate".into(), false.into());
    }
    Ok(runs)
}

/// Cameras, per-frame references (cached by content, cost estimated before rendering),
/// reprojection maps and the references' own flicker.
fn real_time_plan(
    gpu: &Arc<Gpu>,
    p: &LoadedPreset,
    states: &[SceneState],
    events: &[Event],
    exp: &super::ExperimentSettings,
    opts: &ConvergeOptions,
) -> Result<RealTimePlan> {
    let every = exp.reference_every.max(1);
    let cameras = realtime::frame_cameras(exp.frames, &exp.camera_path, &states[0].camera, events);
    let setup = jobs::reference_setup(p);
    let state_of = |f: u32| events.iter().filter(|e| e.frame <= f).count();
    // A scene that plays (`scene.time_scale`): frame f is at the pose the engines give it,
    // t0 + f × time_scale / PLAYBACK_FPS (held at `play_until`), and its reference is of that
    // pose.
    let poses = realtime::FramePoses::new(&states[0].scene);
    let frame_time = |f: u32| poses.time(f);
    let wanted: Vec<(u32, usize, u32, String)> = realtime::reference_frames(exp.frames, every)
        .into_iter()
        .map(|f| {
            let state = state_of(f);
            let seed = realtime::frame_seed(setup.seed, f);
            let state_key = match frame_time(f) {
                Some(t) => format!("{}@t={t}", states[state].info.key),
                None => states[state].info.key.clone(),
            };
            let key = realtime::frame_reference_key(&state_key, &cameras[f as usize], seed);
            (f, state, seed, key)
        })
        .collect();
    let missing: Vec<&(u32, usize, u32, String)> = wanted
        .iter()
        .filter(|w| !opts.cache.join(format!("{}.exr", w.3)).exists())
        .collect();
    let [w, h] = p.preset.render.size;
    if !opts.quiet {
        println!(
            "references: {} frames need one ({} cached, {} to render at {} spp, {w}x{h})",
            wanted.len(),
            wanted.len() - missing.len(),
            missing.len(),
            setup.spp
        );
    }
    let bar = jobs::progress_bar(missing.len() as u64, "references", opts.quiet);
    let mut references = BTreeMap::new();
    let mut infos = Vec::new();
    for (f, state, seed, key) in &wanted {
        let started = std::time::Instant::now();
        let fresh = missing.iter().any(|m| m.0 == *f);
        // The pose of frame f, held still while its reference accumulates.
        let scene = match frame_time(*f) {
            Some(_) => realtime::FramePoses::new(&states[*state].scene).scene(*f)?,
            None => (*states[*state].scene).clone(),
        };
        let (image, path) = jobs::reference_image_seeded(
            gpu.clone(),
            p,
            scene,
            cameras[*f as usize],
            key,
            &opts.cache,
            *seed,
            false,
            true,
        )?;
        if fresh {
            bar.inc(1);
            if bar.position() == 1 && !opts.quiet {
                let each = started.elapsed().as_secs_f64();
                bar.suspend(|| {
                    println!(
                        "references: the first took {each:.1} s: about {:.0} s for all {}",
                        each * missing.len() as f64,
                        missing.len()
                    )
                });
            }
        }
        references.insert(*f, image);
        infos.push(ReferenceInfo {
            state: *state,
            frame: Some(*f),
            from_frame: *f,
            key: key.clone(),
            cache_file: path.display().to_string(),
            spp: setup.spp,
            seed: *seed,
        });
    }
    bar.finish_and_clear();
    let cpu = realtime::cpu_frames(
        &poses,
        &cameras,
        every,
        exp.ghost_frames,
        p.preset.render.size,
    )?;
    let reprojection = cpu.reprojection;
    let tm = p.preset.tonemap;
    let mut reference_flicker = BTreeMap::new();
    for (f, map) in &reprojection {
        let (Some(cur), Some(prev)) = (references.get(f), references.get(&(f - 1))) else {
            continue;
        };
        let cur = realtime::display_luminance(cur, &tm);
        let prev = realtime::display_luminance(prev, &tm);
        if let Some(v) = realtime::flicker(&cur, &prev, map.as_deref()) {
            reference_flicker.insert(*f, v);
        }
    }
    Ok(RealTimePlan {
        every,
        cameras,
        references,
        infos,
        reprojection,
        reference_flicker,
        ghost_masks: cpu.ghost_masks,
        motion_stop_frame: poses.stop_frame(exp.frames),
        scene_times: (0..exp.frames)
            .filter(|f| realtime::frame_use(*f, every) == FrameUse::Scored)
            .filter_map(|f| Some((f, poses.time(f)?)))
            .collect(),
    })
}

#[allow(clippy::too_many_arguments)]
fn run_one(
    gpu: &Arc<Gpu>,
    p: &LoadedPreset,
    shaders: &ShaderLibrary,
    states: &[SceneState],
    plan: Option<&RealTimePlan>,
    events: &[Event],
    spec: &RunSpec,
    exp: &super::ExperimentSettings,
    opts: &ConvergeOptions,
    bar: &jobs::Progress,
    calibration: &mut crate::gpu::calibrate::Calibration,
) -> Result<(Vec<Row>, RunSummary)> {
    let entry = crate::techniques::entry_for_timing(&TechniqueEntry {
        name: spec.technique.clone(),
        label: Some(spec.label.clone()),
        params: spec.params.clone(),
        budget: spec.budget,
        denoise: spec.denoise,
    });
    let settings = EngineSettings {
        extent: p.preset.render.size,
        seed: spec.seed,
        camera: plan.map_or(states[0].camera, |p| p.cameras[0]),
    };
    let clock = std::time::Instant::now();
    let mut wall = super::rows::RunWallTime::default();
    let lap = |since: &mut std::time::Instant| {
        let s = since.elapsed().as_secs_f64();
        *since = std::time::Instant::now();
        s
    };
    let mut since = clock;
    let mut engine = Engine::for_entry(
        gpu.clone(),
        shaders.clone(),
        states[0].scene.clone(),
        states[0].gpu_scene.clone(),
        &entry,
        settings,
    )?;
    wall.setup = lap(&mut since);
    let pixels = (engine.extent[0] * engine.extent[1]) as f64;
    let tonemap = p.preset.tonemap;
    let image_bytes = engine.output_buffers().0.size();
    let every = exp.error_every.max(1);
    // Frames whose image is copied for scoring (real-time mode: also the frame before each
    // scored one, for flicker).
    let scored = |f: u32| match plan {
        Some(plan) => plan.frame_use(f) != FrameUse::Unused,
        None => (f + 1).is_multiple_of(every) || f + 1 == exp.frames,
    };
    // Timing protocol: warm up until the calibration kernel is stable, then frames back to
    // back (`submit_frame`; nothing waits on the CPU between them), copies of the scored
    // frames kept on the GPU and evaluated afterwards (or per chunk when they would take too
    // much memory; a new warm-up follows each chunk and each scene edit).
    let (before, warm_up_ms) = calibration.warm_up(gpu)?;
    wall.warm_up += lap(&mut since);
    let clock_before = calibration.clock();
    let mut rows = Vec::new();
    let mut by_pass: std::collections::BTreeMap<String, f64> = Default::default();
    let mut state = 0usize;
    let mut last_image: Option<Image> = None;
    // Real-time mode: the last evaluated frame's displayed luminance, for flicker.
    let mut previous: Option<(u32, Vec<f32>)> = None;
    let mut copies: Vec<(u32, usize, wgpu::Buffer)> = Vec::new();
    let mut recent: Vec<(Option<(u32, usize)>, wgpu::Buffer)> = Vec::new();
    let mut states_of_frames: Vec<usize> = Vec::new();
    let mut costs: Vec<(crate::render::engine::FrameResult, f64, f64)> = Vec::new();
    let (mut gpu_cum, mut wall_cum) = (0.0, 0.0);
    let mut stop_at: Option<u32> = None;
    let copy_buffer = |label: &str| {
        gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: image_bytes,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        })
    };
    let mut f = 0u32;
    while f < exp.frames && stop_at.is_none() {
        let mut edited = false;
        for _ in events.iter().filter(|e| e.frame == f) {
            state += 1;
            let s = &states[state];
            if !Arc::ptr_eq(&s.scene, &engine.scene) {
                engine.change_scene(s.scene.clone(), s.gpu_scene.clone())?;
                edited = true;
            }
            if plan.is_none() && s.camera != engine.camera {
                engine.move_camera(s.camera);
            }
        }
        // Real-time mode: the camera of this frame (on the path, or the state's).
        if let Some(plan) = plan {
            let camera = plan.cameras[f as usize];
            if camera != engine.camera {
                engine.move_camera(camera);
            }
        }
        if edited {
            wall.frames += lap(&mut since);
            calibration.warm_up(gpu)?;
            wall.warm_up += lap(&mut since);
        }
        states_of_frames.push(state);
        let dst = if scored(f) {
            copies.push((f, state, copy_buffer("scored frame")));
            Some(copies.last().expect("pushed").2.clone())
        } else if exp.seconds > 0.0 {
            // A time budget may end the run on any frame: keep the last few frames too.
            let slot = f as usize % (crate::render::engine::FRAMES_IN_FLIGHT + 1);
            // Scored frames skip slots (error_every > 1): fill every slot up to this one.
            while recent.len() <= slot {
                recent.push((None, copy_buffer("recent frame")));
            }
            recent[slot].0 = Some((f, state));
            Some(recent[slot].1.clone())
        } else {
            None
        };
        engine.submit_frame(dst.as_ref())?;
        f += 1;
        bar.inc(1);
        let chunk_full = copies.len() as u64 * image_bytes >= CHUNK_BYTES;
        if chunk_full || f == exp.frames {
            engine.finish_frames()?;
        }
        for done in engine.take_completed() {
            gpu_cum += done.report.gpu_ms;
            wall_cum += done.report.wall_ms;
            for (name, ms) in &done.report.gpu_ms_by_pass {
                *by_pass.entry(name.clone()).or_insert(0.0) += ms;
            }
            let frame = done.report.frame_index;
            costs.push((done, gpu_cum, wall_cum));
            if stop_at.is_none() && exp.seconds > 0.0 && gpu_cum >= exp.seconds * 1e3 {
                stop_at = Some(frame);
            }
        }
        if chunk_full && stop_at.is_none() && f < exp.frames {
            wall.frames += lap(&mut since);
            evaluate(
                gpu,
                tonemap,
                &mut copies,
                &costs,
                (states, plan),
                &mut rows,
                &mut last_image,
                &mut previous,
            )?;
            wall.score += lap(&mut since);
            calibration.warm_up(gpu)?;
            wall.warm_up += lap(&mut since);
        }
    }
    // Queued right behind the last frame: the clock state the run ended in.
    let after = calibration.measure(gpu)?;
    let clock_check = calibration.check(
        before,
        after,
        warm_up_ms,
        (clock_before, calibration.clock()),
    );
    engine.finish_frames()?;
    for done in engine.take_completed() {
        gpu_cum += done.report.gpu_ms;
        wall_cum += done.report.wall_ms;
        for (name, ms) in &done.report.gpu_ms_by_pass {
            *by_pass.entry(name.clone()).or_insert(0.0) += ms;
        }
        costs.push((done, gpu_cum, wall_cum));
    }
    // A time budget ends the run on the frame that reached it: later frames do not count.
    if let Some(last) = stop_at {
        costs.retain(|c| c.0.report.frame_index <= last);
        copies.retain(|c| c.0 <= last);
        // Real-time mode scores only frames with a reference of their own.
        if plan.is_none() && !copies.iter().any(|c| c.0 == last) {
            let (_, buffer) = recent
                .iter()
                .find(|r| r.0.is_some_and(|(fr, _)| fr == last))
                .context("the last frame's copy")?;
            copies.push((last, states_of_frames[last as usize], buffer.clone()));
        }
        by_pass.clear();
        for c in &costs {
            for (name, ms) in &c.0.report.gpu_ms_by_pass {
                *by_pass.entry(name.clone()).or_insert(0.0) += ms;
            }
        }
    }
    wall.frames += lap(&mut since);
    evaluate(
        gpu,
        tonemap,
        &mut copies,
        &costs,
        (states, plan),
        &mut rows,
        &mut last_image,
        &mut previous,
    )?;
    wall.score += lap(&mut since);
    let mut frame_ms: Vec<f64> = costs.iter().map(|c| c.0.report.gpu_ms).collect();
    frame_ms.sort_by(f64::total_cmp);
    let gpu_ms_median = frame_ms.get(frame_ms.len() / 2).copied().unwrap_or(0.0);
    for r in &mut rows {
        r.clock_flagged = clock_check.flagged;
        r.run = spec.index;
        r.label = spec.label.clone();
        r.technique = spec.technique.clone();
        r.seed = spec.seed;
        r.budget = spec.budget;
    }
    bar.inc((exp.frames - f) as u64);
    let _ = pixels;
    let image = last_image.context("no frame rendered")?;
    let last = rows.last().cloned().context("no frame rendered")?;
    let frames = last.frame;
    let stem = format!("{:03}-{}", spec.index, spec.label);
    let dir = opts.out.join("runs");
    let entry = TechniqueEntry {
        label: Some(spec.label.clone()),
        params: engine.technique.params(),
        denoise: spec.denoise,
        ..TechniqueEntry::new(&spec.technique)
    };
    let mut meta_by_pass = by_pass.clone();
    meta_by_pass.values_mut().for_each(|v| *v /= frames as f64);
    let meta = jobs::metadata(&engine, p, &entry, &image, meta_by_pass.clone())?;
    jobs::write_outputs(&dir, &stem, &image, &meta, p)?;
    wall.write = lap(&mut since);
    if std::env::var_os("GILAB_RUN_WALL").is_some() {
        eprintln!(
            "run {}: {:.2} s (setup {:.2}, warm-up {:.2}, frames {:.2}, score {:.2}, write {:.2})",
            spec.label,
            clock.elapsed().as_secs_f64(),
            wall.setup,
            wall.warm_up,
            wall.frames,
            wall.score,
            wall.write
        );
    }
    let passes = engine.passes();
    let median_error = median(rows.iter().map(|r| r.error(exp.metric)).collect());
    let flicker_ratio = flicker_ratio(&rows);
    Ok((
        rows,
        RunSummary {
            spec: spec.clone(),
            params: engine.technique.params(),
            rays_per_pixel_per_frame: last.rays_per_pixel / frames as f64,
            frames,
            gpu_ms_total: last.gpu_ms_cum,
            gpu_ms_per_frame: last.gpu_ms_cum / frames as f64,
            gpu_ms_median,
            gpu_ms_by_pass: meta_by_pass,
            passes_run: passes
                .iter()
                .filter(|p| p.runs)
                .map(|p| p.name.to_string())
                .collect(),
            passes_skipped: passes
                .iter()
                .filter(|p| !p.runs)
                .map(|p| format!("{}: {}", p.name, p.why))
                .collect(),
            final_mse: last.mse,
            final_rel_mse: last.rel_mse,
            final_smape: last.smape,
            final_flip: last.flip,
            non_finite_pixels: image.non_finite_count(),
            image: format!("runs/{stem}.exr"),
            clock_check,
            median_error,
            flicker_ratio,
            wall_s: wall,
        },
    ))
}

/// Median of finite values (None when there are none).
pub fn median(mut v: Vec<f64>) -> Option<f64> {
    v.retain(|x| x.is_finite());
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied()
}

/// Mean flicker of a run over the references' mean flicker on the same frames.
pub fn flicker_ratio(rows: &[Row]) -> Option<f64> {
    let (mut run, mut reference) = (0.0, 0.0);
    for r in rows {
        if let (Some(a), Some(b)) = (r.flicker, r.flicker_reference) {
            run += a;
            reference += b;
        }
    }
    (reference > 0.0).then(|| run / reference)
}

/// Copies of scored frames kept on the GPU before they are read back (per chunk).
const CHUNK_BYTES: u64 = 512 << 20;

/// Reads back the scored frames' copies, scores them against their reference (the state's,
/// or in real-time mode the frame's own) and appends their rows (times and rays from `costs`,
/// the frames' collected results). Real-time mode also measures flicker against the previous
/// frame, which `previous` carries from one call to the next.
#[allow(clippy::too_many_arguments)]
fn evaluate(
    gpu: &Gpu,
    tonemap: crate::compare::tonemap::Settings,
    copies: &mut Vec<(u32, usize, wgpu::Buffer)>,
    costs: &[(crate::render::engine::FrameResult, f64, f64)],
    (states, plan): (&[SceneState], Option<&RealTimePlan>),
    rows: &mut Vec<Row>,
    last_image: &mut Option<Image>,
    previous: &mut Option<(u32, Vec<f32>)>,
) -> Result<()> {
    let Some(first) = states.first() else {
        return Ok(());
    };
    let (w, h) = (first.extent[0], first.extent[1]);
    copies.sort_by_key(|c| c.0);
    // Read back in frame order, score the frames in parallel (errors, FLIP and the displayed
    // luminance are per frame: on a many-core host this is most of a run's time after its
    // frames), then join the order-dependent part (flicker against the previous frame).
    let mut images = Vec::with_capacity(copies.len());
    for (frame, state, buffer) in copies.drain(..) {
        let px: Vec<[f32; 4]> = crate::gpu::readback::read_buffer(gpu, &buffer, (w * h) as usize)?;
        images.push((frame, state, Image::from_rgba(w, h, &px)));
    }
    use rayon::prelude::*;
    let scored: Vec<Result<ScoredFrame>> = images
        .into_par_iter()
        .map(|(frame, state, image)| {
            let cost = costs
                .iter()
                .find(|c| c.0.report.frame_index == frame)
                .context("a scored frame without its timing")?;
            let Some(plan) = plan else {
                let reference = states[state]
                    .reference
                    .as_ref()
                    .context("a scene state without its reference")?;
                let (row, _) = score_row(&image, reference, tonemap, state, frame, cost)?;
                return Ok((frame, image, Some(row), None));
            };
            let luminance = realtime::display_luminance(&image, &tonemap);
            if plan.frame_use(frame) != FrameUse::Scored {
                return Ok((frame, image, None, Some(luminance)));
            }
            let reference = plan
                .references
                .get(&frame)
                .context("a scored frame without its reference")?;
            let (mut row, flip_map) = score_row(&image, reference, tonemap, state, frame, cost)?;
            if let Some(mask) = plan.ghost_masks.get(&frame) {
                let (ghost, rest) = masked_mean(&flip_map, mask);
                row.ghost_pixels = mask.iter().filter(|m| **m).count() as u32;
                row.ghost_flip = ghost;
                row.rest_flip = rest;
            }
            row.scene_time = plan.scene_times.get(&frame).map(|t| *t as f64);
            Ok((frame, image, Some(row), Some(luminance)))
        })
        .collect();
    for done in scored {
        let (frame, image, row, luminance) = done?;
        let Some(luminance) = luminance else {
            rows.extend(row);
            *last_image = Some(image);
            continue;
        };
        if let Some(mut row) = row {
            let plan = plan.context("a real-time frame without its plan")?;
            if let Some((_, prev)) = previous.as_ref().filter(|p| p.0 + 1 == frame) {
                let map = plan.reprojection.get(&frame).and_then(|m| m.as_deref());
                row.flicker = realtime::flicker(&luminance, prev, map);
                row.flicker_reference = plan.reference_flicker.get(&frame).copied();
            }
            rows.push(row);
            *last_image = Some(image);
        }
        *previous = Some((frame, luminance));
    }
    Ok(())
}

/// A frame after scoring: its image, its row (frames scored against a reference) and its
/// displayed luminance (real-time mode, for flicker).
type ScoredFrame = (u32, Image, Option<Row>, Option<Vec<f32>>);

/// Mean FLIP over the pixels of `mask` and over the others (None where a side has no pixel).
/// FLIP rather than relMSE: bounded per pixel, so one firefly does not decide a ghost.
fn masked_mean(flip_map: &[f32], mask: &[bool]) -> (Option<f64>, Option<f64>) {
    let (mut sums, mut counts) = ([0.0f64; 2], [0usize; 2]);
    for (e, m) in flip_map.iter().zip(mask) {
        let side = usize::from(*m);
        sums[side] += *e as f64;
        counts[side] += 1;
    }
    let mean = |k: usize| (counts[k] > 0).then(|| sums[k] / counts[k] as f64);
    (mean(1), mean(0))
}

/// Mean luminance of `image` over the reference's: the energy a frame gains or loses (None
/// where the reference is black or either sum is not finite).
pub fn energy_ratio(image: &Image, reference: &Image) -> Option<f64> {
    let mean = |img: &Image| {
        img.rgb
            .chunks_exact(3)
            .map(|c| crate::compare::tonemap::luminance([c[0], c[1], c[2]]) as f64)
            .sum::<f64>()
    };
    let (a, b) = (mean(image), mean(reference));
    (b > 0.0 && a.is_finite() && b.is_finite()).then(|| a / b)
}

/// One CSV row for a scored frame (the run's identity is filled in by `label_rows`), and the
/// frame's FLIP map (its mean is the row's `flip`).
fn score_row(
    image: &Image,
    reference: &Image,
    tonemap: crate::compare::tonemap::Settings,
    state: usize,
    frame: u32,
    cost: &(crate::render::engine::FrameResult, f64, f64),
) -> Result<(Row, Vec<f32>)> {
    let m = metrics::compare(image, reference)?;
    // flip::ldr_flip's mean, from the map kept for the ghost masks.
    let flip_map = flip::ldr_flip_map(image, reference, &tonemap)?;
    let flip = flip_map.iter().map(|&v| v as f64).sum::<f64>() / flip_map.len().max(1) as f64;
    let (done, gpu_cum, wall_cum) = cost;
    let rays = &done.rays;
    let pixels = (image.width * image.height) as f64;
    let k = |name: &str| {
        RAY_KINDS
            .iter()
            .position(|n| *n == name)
            .map_or(0, |i| rays.by_kind[i])
    };
    let report = &done.report;
    let row = Row {
        run: 0,
        label: String::new(),
        technique: String::new(),
        seed: 0,
        budget: None,
        frame: frame + 1,
        state,
        gpu_ms: report.gpu_ms,
        gpu_ms_cum: *gpu_cum,
        wall_ms: report.wall_ms,
        wall_ms_cum: *wall_cum,
        timing: match report.timing {
            crate::render::engine::TimingSource::Timestamps => "timestamps",
            _ => "wall",
        }
        .into(),
        clock_flagged: false,
        rays: rays.total(),
        rays_per_pixel: rays.total() as f64 / pixels,
        rays_camera: k("camera"),
        rays_shadow: k("shadow"),
        rays_indirect: k("indirect"),
        rays_probe: k("probe"),
        rays_surfel: k("surfel"),
        rays_cache: k("cache"),
        rays_candidate: k("candidate"),
        rays_reuse: k("reuse"),
        mse: m.mse,
        rel_mse: m.rel_mse,
        smape: m.smape,
        flip,
        energy: energy_ratio(image, reference),
        flicker: None,
        flicker_reference: None,
        scene_time: None,
        ghost_pixels: 0,
        ghost_flip: None,
        rest_flip: None,
        passes: report
            .gpu_ms_by_pass
            .iter()
            .map(|(n, ms)| format!("{n}={ms:.4}"))
            .collect::<Vec<_>>()
            .join(";"),
    };
    Ok((row, flip_map))
}

/// Merges shard folders into one output: checks they come from the same experiment, joins
/// runs and rows in run order, copies the last-frame images, and writes the report again.
pub fn merge(dirs: &[PathBuf], out: &Path) -> Result<Summary> {
    ensure!(!dirs.is_empty(), "--merge needs at least one folder");
    let mut merged: Option<Summary> = None;
    let mut rows = Vec::new();
    std::fs::create_dir_all(out.join("runs"))?;
    for dir in dirs {
        let (s, r) = read_output_dir(dir)?;
        if let Some(m) = &mut merged {
            ensure!(
                m.preset_sha256 == s.preset_sha256,
                "{}: a different experiment (preset hash {} against {})",
                dir.display(),
                s.preset_sha256,
                m.preset_sha256
            );
            for run in &s.runs {
                ensure!(
                    !m.runs.iter().any(|x| x.spec.index == run.spec.index),
                    "{}: run '{}' is in two shards",
                    dir.display(),
                    run.spec.label
                );
            }
            m.runs.extend(s.runs.clone());
            m.shards.extend(s.shards.clone());
        } else {
            merged = Some(s);
        }
        rows.extend(r);
        for e in std::fs::read_dir(dir.join("runs"))? {
            let e = e?;
            if e.file_type()?.is_file() {
                let to = out.join("runs").join(e.file_name());
                if e.path() != to {
                    std::fs::copy(e.path(), &to)?;
                }
            }
        }
    }
    let mut summary = merged.expect("one folder at least");
    summary.runs.sort_by_key(|r| r.spec.index);
    summary.shards.sort_by_key(|s| s.index);
    let missing = summary.total_runs - summary.runs.len();
    if missing > 0 {
        eprintln!(
            "warning: {missing} of {} runs are in none of the merged folders",
            summary.total_runs
        );
    }
    rows.sort_by_key(|r| (r.run, r.frame));
    report::finish(summary, rows, out)
}
