//! The viewer driven through egui_kittest with real wgpu rendering (lavapipe in CI): layouts,
//! pane pickers, the ray-budget slider, preset loading, and bad input while it runs (broken
//! shader, preset and glTF). Plus the heatmaps' numbers against CPU computations.

mod common;

use egui_kittest::{kittest::Queryable, Harness};
use gilab::app::{session::ReferenceSource, wgpu_setup, ViewerApp, ViewerOptions};
use gilab::gpu::{shaders::ShaderLibrary, BackendChoice};
use gilab::preset::{DisplayMode, Layout, LoadedPreset};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// A fresh folder per test (tests run in parallel threads).
fn tempdir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("gilab-viewer-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Small presets: two techniques on the Cornell box, and a furnace.
const CORNELL: &str = r#"
[scene]
source = "cornell"
[render]
size = [32, 32]
seed = 3
reference_spp = 8
[[techniques]]
name = "reference"
params = { samples_per_frame = 1 }
[[techniques]]
name = "reference"
label = "two-bounce"
params = { samples_per_frame = 1, max_depth = 2 }
"#;

const DDGI: &str = r#"
[scene]
source = "cornell"
[render]
size = [32, 32]
seed = 3
reference_spp = 4
# Few probes and rays: the test reads the inspector, not DDGI's light (a frame in 0.1 s).
[[techniques]]
name = "ddgi"
params = { probes_per_axis = 4, rays_per_probe = 32 }
"#;

const FURNACE: &str = r#"
[scene]
source = "furnace"
params = { subdivisions = 1 }
[render]
size = [32, 32]
reference_spp = 4
"#;

struct Fixture {
    dir: PathBuf,
    presets: PathBuf,
    shaders: PathBuf,
}

fn fixture(name: &str) -> Fixture {
    gilab::gpu::ensure_runtime_dir();
    let dir = tempdir(name);
    let presets = dir.join("presets");
    std::fs::create_dir_all(&presets).unwrap();
    std::fs::write(presets.join("cornell.toml"), CORNELL).unwrap();
    std::fs::write(presets.join("furnace.toml"), FURNACE).unwrap();
    std::fs::write(presets.join("ddgi.toml"), DDGI).unwrap();
    let shaders = dir.join("shaders");
    common::copy_dir(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("shaders")
            .as_path(),
        &shaders,
    );
    Fixture {
        dir,
        presets,
        shaders,
    }
}

fn viewer(f: &Fixture, watch: bool) -> Harness<'static, ViewerApp> {
    viewer_on(f, "cornell.toml", watch)
}

/// The viewer on one of the fixture's presets.
fn viewer_on(f: &Fixture, preset: &str, watch: bool) -> Harness<'static, ViewerApp> {
    let preset = LoadedPreset::load(&f.presets.join(preset)).unwrap();
    let mut options = ViewerOptions::new(preset);
    options.shaders = ShaderLibrary::at(f.shaders.clone());
    options.presets_dir = f.presets.clone();
    options.out_dir = f.dir.join("out");
    options.cache_dir = f.dir.join("cache");
    options.watch = watch;
    let mut harness = Harness::builder()
        .with_size(egui::Vec2::new(1400.0, 1000.0))
        .wgpu_setup(wgpu_setup(BackendChoice::Auto))
        .build_eframe(move |cc| ViewerApp::new(cc, options));
    let app = harness.state();
    assert!(app.startup_error.is_none(), "{:?}", app.startup_error);
    harness.run_steps(3);
    harness
}

fn session<'a>(h: &'a Harness<'static, ViewerApp>) -> &'a gilab::app::session::Session {
    h.state().session.as_ref().expect("session")
}

/// Steps until `cond` holds or `timeout` passes; returns whether it held.
fn step_until(
    h: &mut Harness<'static, ViewerApp>,
    timeout: Duration,
    mut cond: impl FnMut(&Harness<'static, ViewerApp>) -> bool,
) -> bool {
    let start = Instant::now();
    while start.elapsed() < timeout {
        h.step();
        if cond(h) {
            return true;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    false
}

#[test]
fn layouts_panes_and_budget_slider() {
    let f = fixture("layouts");
    let mut h = viewer(&f, false);
    // Both panes of the default side-by-side layout render.
    assert_eq!(session(&h).layout, Layout::SideBySide);
    assert!(step_until(&mut h, Duration::from_secs(30), |h| {
        session(h).runs.iter().all(|r| r.engine.frame_index >= 2)
    }));
    // The real wgpu renderer draws the window: the panes are not blank.
    let image = h.render().expect("wgpu render of the window");
    let lit = image.pixels().filter(|p| p[0] > 120 && p[1] < 80).count();
    assert!(
        lit > 50,
        "no red wall visible in the rendered window ({lit} px)"
    );

    for (label, layout) in [
        ("2x2 grid", Layout::Grid),
        ("Wipe", Layout::Wipe),
        ("Single", Layout::Single),
        ("Side by side", Layout::SideBySide),
    ] {
        h.get_by_label(label).click();
        h.run_steps(2);
        assert_eq!(session(&h).layout, layout, "after clicking {label}");
    }

    // Pane 1: pick the second technique, then the variance heatmap.
    h.get_by_label("Pane 1 technique").click();
    h.run_steps(2);
    // The open popup's entry is the only button with that label (the label also names a
    // panel section and the plot legends).
    h.get_by_role_and_label(egui::accesskit::Role::Button, "two-bounce")
        .click();
    h.run_steps(2);
    assert_eq!(session(&h).panes[0].run, 1);
    h.get_by_label("Pane 1 display").click();
    h.run_steps(2);
    h.get_by_label("Variance heatmap").click();
    h.run_steps(2);
    assert_eq!(session(&h).panes[0].display, DisplayMode::Variance);
    assert!(session(&h).pane_pixels(&session(&h).panes[0]).is_some());

    // The ray-budget slider raises the measured rays per pixel per frame (of the run the
    // panes now show: only visible runs render).
    let before = session(&h).runs[1].measured_rays_per_pixel().unwrap();
    h.get_by_role_and_label(
        egui::accesskit::Role::Slider,
        "Ray budget two-bounce (rays/px/frame)",
    )
    .set_value_accesskit(before * 4.0);
    h.run_steps(2);
    let spf = session(&h).runs[1].engine.technique.samples_per_frame();
    assert!(spf >= 3, "budget x4 gave {spf} samples per frame");
    assert!(step_until(&mut h, Duration::from_secs(30), |h| {
        session(h).runs[1].engine.frame_index >= 2
    }));
    let after = session(&h).runs[1].measured_rays_per_pixel().unwrap();
    assert!(
        after > 2.5 * before,
        "measured rays/px/frame {before:.2} -> {after:.2}"
    );
    // The A/B screenshot button writes every visible pane and the composite.
    // Below the fold of the side panel: an accessibility click, as a screen reader would.
    h.get_by_label("Save A/B screenshot (F12)")
        .click_accesskit();
    h.run_steps(2);
    let dir = h
        .state()
        .last_screenshot
        .clone()
        .unwrap_or_else(|| panic!("no screenshot: {:?}", session(&h).errors));
    let names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
        .collect();
    for want in ["composite.png", "session.toml"] {
        assert!(names.iter().any(|n| n == want), "{want} missing: {names:?}");
    }
    for ext in ["png", "exr", "json"] {
        let n = names
            .iter()
            .filter(|n| n.starts_with("pane") && n.ends_with(ext))
            .count();
        assert_eq!(n, 2, "two panes' .{ext} expected: {names:?}");
    }
    let composite = image::open(dir.join("composite.png")).unwrap();
    assert_eq!((composite.width(), composite.height()), (64, 32));
    LoadedPreset::load(&dir.join("session.toml")).expect("session.toml loads as a preset");

    // The run that left the panes stops rendering.
    let idle = session(&h).runs[0].engine.frame_index;
    h.run_steps(4);
    assert_eq!(session(&h).runs[0].engine.frame_index, idle);
}

#[test]
fn preset_loading_and_bad_input_keep_the_viewer_up() {
    let f = fixture("presets");
    let mut h = viewer(&f, false);
    h.get_by_label("furnace.toml").click();
    h.run_steps(2);
    assert_eq!(session(&h).scene.name, "furnace");

    // A preset with a typo: error with line and column, nothing changes.
    let bad = f.presets.join("typo.toml");
    std::fs::write(
        &bad,
        "[scene]\nsource = \"cornell\"\n[render]\nsizee = [8, 8]\n",
    )
    .unwrap();
    h.state_mut()
        .session
        .as_mut()
        .unwrap()
        .load_preset_file(&bad)
        .unwrap_err();
    h.run_steps(2);
    let msg = session(&h)
        .errors
        .get("preset")
        .cloned()
        .unwrap_or_default();
    assert!(msg.contains("typo.toml:4:1"), "{msg}");
    assert!(h
        .query_all_by_label_contains("typo.toml:4:1")
        .next()
        .is_some());
    assert_eq!(session(&h).scene.name, "furnace");

    // A preset naming a missing glTF file, then a malformed one.
    let missing = f.presets.join("missing.toml");
    std::fs::write(&missing, "[scene]\nsource = \"nowhere.gltf\"\n").unwrap();
    let garbage = f.presets.join("garbage.gltf");
    std::fs::write(&garbage, "{ this is not gltf").unwrap();
    let malformed = f.presets.join("malformed.toml");
    std::fs::write(&malformed, "[scene]\nsource = \"garbage.gltf\"\n").unwrap();
    for p in [&missing, &malformed] {
        let s = h.state_mut().session.as_mut().unwrap();
        assert!(s.load_preset_file(p).is_err());
        h.run_steps(2);
        assert_eq!(session(&h).scene.name, "furnace");
    }
    let msg = session(&h)
        .errors
        .get("preset")
        .cloned()
        .unwrap_or_default();
    assert!(msg.contains("garbage.gltf"), "{msg}");
    // Still rendering.
    let frame = session(&h).runs[0].engine.frame_index;
    assert!(step_until(&mut h, Duration::from_secs(30), |h| {
        session(h).runs[0].engine.frame_index > frame
    }));
    // Save and load round trip through a preset file.
    let saved = f.presets.join("saved.toml");
    h.state_mut()
        .session
        .as_mut()
        .unwrap()
        .save_preset(&saved)
        .unwrap();
    let reloaded = LoadedPreset::load(&saved).unwrap();
    assert_eq!(reloaded.preset.scene.source, "furnace");
    assert_eq!(
        reloaded.preset.camera,
        Some(session(&h).camera),
        "saved preset keeps the camera"
    );
}

#[test]
fn broken_shader_keeps_last_pipeline_and_fix_reloads() {
    let f = fixture("hotreload");
    let mut h = viewer(&f, true);
    assert!(step_until(&mut h, Duration::from_secs(30), |h| {
        session(h).runs[0].engine.frame_index >= 1
    }));
    let file = f.shaders.join("reference/path_trace.wgsl");
    let good = std::fs::read_to_string(&file).unwrap();
    std::fs::write(&file, format!("{good}\nfn broken( {{\n")).unwrap();
    assert!(
        step_until(&mut h, Duration::from_secs(30), |h| session(h)
            .errors
            .contains_key("shaders")),
        "no shader error shown"
    );
    let msg = session(&h).errors["shaders"].clone();
    assert!(msg.contains("reference/path_trace.wgsl:"), "{msg}");
    assert!(h
        .query_all_by_label_contains("path_trace.wgsl:")
        .next()
        .is_some());
    // The last good pipeline keeps rendering.
    let frame = session(&h).runs[0].engine.frame_index;
    assert!(step_until(&mut h, Duration::from_secs(30), |h| {
        session(h).runs[0].engine.frame_index >= frame + 2
    }));
    // A broken shared module is reported against its own file.
    let math = f.shaders.join("common/math.wgsl");
    let math_good = std::fs::read_to_string(&math).unwrap();
    std::fs::write(&file, &good).unwrap();
    std::fs::write(&math, format!("{math_good}\nconst oops: f32 = ;\n")).unwrap();
    assert!(step_until(&mut h, Duration::from_secs(30), |h| {
        session(h)
            .errors
            .get("shaders")
            .is_some_and(|m| m.contains("common/math.wgsl:"))
    }));
    // Fixing it reloads without a restart and clears the error.
    std::fs::write(&math, &math_good).unwrap();
    assert!(
        step_until(&mut h, Duration::from_secs(30), |h| !session(h)
            .errors
            .contains_key("shaders")),
        "error not cleared after the fix"
    );
    assert!(session(&h).log.iter().any(|l| l.starts_with("reloaded")));
    assert!(step_until(&mut h, Duration::from_secs(30), |h| {
        session(h).runs[0].engine.frame_index >= 1
    }));
}

#[test]
fn broken_gltf_on_disk_while_running_keeps_the_scene() {
    let f = fixture("gltf");
    let scene_dir = f.dir.join("scene");
    common::copy_dir(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("scenes/box-room")
            .as_path(),
        &scene_dir,
    );
    let preset = f.presets.join("room.toml");
    std::fs::write(
        &preset,
        "[scene]\nsource = \"../scene/box-room.gltf\"\n[render]\nsize = [32, 32]\nreference_spp = 4\n",
    )
    .unwrap();
    let mut h = viewer(&f, true);
    h.state_mut()
        .session
        .as_mut()
        .unwrap()
        .load_preset_file(&preset)
        .unwrap();
    h.state_mut().poll_file_changes();
    let name = session(&h).scene.name.clone();
    // Someone overwrites the scene file with garbage while the viewer runs.
    std::fs::write(scene_dir.join("box-room.gltf"), "{ broken").unwrap();
    assert!(
        step_until(&mut h, Duration::from_secs(30), |h| session(h)
            .errors
            .contains_key("preset")),
        "no error after the scene file broke"
    );
    assert_eq!(session(&h).scene.name, name);
    let frame = session(&h).runs[0].engine.frame_index;
    assert!(step_until(&mut h, Duration::from_secs(30), |h| {
        session(h).runs[0].engine.frame_index > frame
    }));
}

/// The variance heatmap's values equal a CPU computation of per-pixel sample variance from
/// the individual frames (recovered from the running means), and the error heatmap's mean
/// equals the relMSE `gilab compare` prints for the same two EXRs.
#[test]
fn heatmaps_agree_with_cpu_and_compare() {
    let f = fixture("heatmaps");
    let preset = LoadedPreset::load(&f.presets.join("cornell.toml")).unwrap();
    let mut s = gilab::app::session::Session::new(
        common::gpu(),
        ShaderLibrary::discover(),
        preset,
        f.dir.join("cache"),
    )
    .unwrap();
    s.layout = Layout::Single;
    // Converge the reference first (8 spp at 32²), then render only the technique.
    while !s.reference.done() {
        s.step(0.0);
    }
    assert_eq!(s.reference.source, ReferenceSource::Done);
    let n = 12;
    let mut means: Vec<Vec<f32>> = Vec::new();
    s.runs[0].engine.reset();
    for _ in 0..n {
        assert_eq!(s.step(0.0), 1);
        means.push(s.runs[0].cpu_images(false).unwrap().radiance.rgb.clone());
    }
    let frames = s.runs[0].engine.frame_index as usize;
    assert_eq!(frames, n);
    // Individual samples: x_k = k m_k - (k-1) m_{k-1}; unbiased sample variance per channel.
    let px = means[0].len() / 3;
    let mut cpu = vec![0f64; px];
    for (i, cpu_var) in cpu.iter_mut().enumerate() {
        for c in 0..3 {
            let j = 3 * i + c;
            let xs: Vec<f64> = (0..n)
                .map(|k| {
                    let prev = if k == 0 { 0.0 } else { means[k - 1][j] as f64 };
                    (k + 1) as f64 * means[k][j] as f64 - k as f64 * prev
                })
                .collect();
            let mean = xs.iter().sum::<f64>() / n as f64;
            let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
            *cpu_var += var / 3.0;
        }
    }
    let mut pane = s.panes[0];
    pane.display = DisplayMode::Variance;
    let gpu_values = s.pane_values(&pane).unwrap();
    let mut worst = 0f64;
    for (g, c) in gpu_values.iter().zip(&cpu) {
        let err = (*g as f64 - c).abs() / (c.abs() + 1e-4);
        worst = worst.max(err);
    }
    assert!(
        worst < 2e-3,
        "variance heatmap vs CPU: worst relative error {worst}"
    );
    assert!(cpu.iter().any(|v| *v > 1e-3), "variance suspiciously zero");

    // Error heatmap mean vs `gilab compare` on the EXRs of the same images.
    pane.display = DisplayMode::Error;
    let map = s.pane_values(&pane).unwrap();
    let heat_mean = gilab::compare::heatmap::mean(&map);
    let a = f.dir.join("a.exr");
    let b = f.dir.join("b.exr");
    let radiance = s.runs[0].cpu_images(false).unwrap().radiance;
    gilab::compare::io::write_exr(&a, &radiance).unwrap();
    gilab::compare::io::write_exr(&b, s.reference.image.as_ref().unwrap()).unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_gilab"))
        .args(["compare"])
        .arg(&a)
        .arg(&b)
        .output()
        .unwrap();
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    let rel: f64 = text
        .split_whitespace()
        .skip_while(|w| *w != "relMSE")
        .nth(1)
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no relMSE in: {text}"));
    assert!(
        (heat_mean - rel).abs() <= 1e-5 * rel,
        "heatmap mean {heat_mean} vs gilab compare {rel}"
    );
    assert!(rel > 0.0);

    // The viewer's GPU reduction of the same frame, read back asynchronously, equals it too.
    s.finish().unwrap();
    let gpu = s.runs[0].error.expect("GPU error reduction arrived");
    let last = s.runs[0].curve.last().expect("curve point");
    assert_eq!(last.frame, n as u32, "the last frame was scored");
    println!(
        "relMSE: GPU reduction {:.9e}, gilab compare {rel:.9e} (rel. diff {:.2e}); MSE {:.9e}",
        gpu.rel_mse,
        (gpu.rel_mse - rel).abs() / rel,
        gpu.mse
    );
    assert!(
        (gpu.rel_mse - rel).abs() <= 1e-5 * rel,
        "GPU reduction {} vs gilab compare {rel}",
        gpu.rel_mse
    );
    let cpu =
        gilab::compare::metrics::compare(&radiance, s.reference.image.as_ref().unwrap()).unwrap();
    for (g, c, what) in [(gpu.mse, cpu.mse, "MSE"), (gpu.smape, cpu.smape, "SMAPE")] {
        assert!((g - c).abs() <= 1e-5 * c, "{what}: GPU {g} vs CPU {c}");
    }
}

/// The viewer's images come from the GPU display pass; the CLI's files from the CPU path.
/// Both must show the same pixels (within 1/255 per channel) in every display mode, and the
/// GPU histogram must give the heatmap range the CPU computes.
#[test]
fn gpu_display_equals_cpu_path_in_every_mode() {
    use gilab::compare::display::{DisplayTarget, GpuCompare};
    let f = fixture("display");
    let text = CORNELL.replace(
        "[[techniques]]\nname = \"reference\"\nlabel = \"two-bounce\"\nparams = { samples_per_frame = 1, max_depth = 2 }",
        "[[techniques]]\nname = \"restir\"",
    );
    let preset = LoadedPreset::from_text(&text, None).unwrap();
    assert_eq!(preset.preset.techniques[1].name, "restir");
    let mut s = gilab::app::session::Session::new(
        common::gpu(),
        ShaderLibrary::discover(),
        preset,
        f.dir.join("cache"),
    )
    .unwrap();
    s.layout = Layout::SideBySide;
    s.panes[0].run = 0;
    s.panes[1].run = 1;
    for _ in 0..40 {
        s.step(0.0);
    }
    s.finish().unwrap();
    assert!(s.reference.on_gpu);
    let mut cases = vec![
        (0, DisplayMode::Radiance, 0),
        (0, DisplayMode::Variance, 0),
        (0, DisplayMode::Error, 0),
        (0, DisplayMode::Samples, 0),
        (1, DisplayMode::Radiance, 0),
        (1, DisplayMode::Error, 0),
    ];
    let views = s.runs[1].engine.technique.debug_views();
    for (k, _) in views.iter().enumerate() {
        cases.push((1, DisplayMode::Debug, k));
    }
    assert!(views.iter().any(|v| v.is_id) && views.iter().any(|v| !v.is_id));
    let mut modes_seen = 0;
    for (run, display, debug) in cases {
        let pane = gilab::app::session::Pane {
            run,
            display,
            debug,
        };
        let (cpu, img, cpu_range) = s.pane_pixels(&pane).expect("CPU image");
        let mut settings = s.display_settings(&pane).unwrap();
        let mut target = DisplayTarget::new(&s.gpu, [img.width, img.height]);
        // First pass: the GPU histogram's range; second: the CPU's range, to compare pixels.
        for pass in 0..2 {
            let mut enc = s.gpu.device.create_command_encoder(&Default::default());
            assert!(s.record_pane_display(&mut enc, &pane, &settings, &mut target));
            let hist = s.compare.record_histogram_copy(&mut enc, &target);
            let sub = s.gpu.queue.submit([enc.finish()]);
            if hist {
                GpuCompare::start_histogram_read(&mut target, sub);
            }
            s.gpu.wait().unwrap();
            target.poll_range(&s.gpu).unwrap();
            if pass == 0 {
                if settings.kind.has_histogram() {
                    let (g, c) = (target.range.unwrap(), cpu_range.unwrap());
                    let bin = 1.0 / gilab::compare::heatmap::HIST_PER_DECADE;
                    assert!(
                        (g.0 - c.0).abs() <= bin + 1e-6 && (g.1 - c.1).abs() <= bin + 1e-6,
                        "{display:?} {debug}: GPU range {g:?} vs CPU {c:?}"
                    );
                }
                settings.range = cpu_range;
            }
        }
        let gpu = target.read_rgba(&s.gpu).unwrap();
        assert_eq!(gpu.len(), cpu.len());
        let worst = gpu
            .iter()
            .zip(&cpu)
            .map(|(a, b)| (*a as i32 - *b as i32).abs())
            .max()
            .unwrap();
        let differing = gpu.iter().zip(&cpu).filter(|(a, b)| a != b).count();
        println!(
            "run {run} {display:?} {debug}: worst channel difference {worst}/255, \
             {differing} of {} channels differ",
            cpu.len()
        );
        assert!(
            worst <= 1,
            "{display:?} {debug}: GPU and CPU differ by {worst}/255"
        );
        if matches!(
            display,
            DisplayMode::Radiance | DisplayMode::Variance | DisplayMode::Error
        ) {
            assert!(
                cpu.chunks(4).any(|p| p[..3] != cpu[..3]),
                "a flat image tests nothing"
            );
        }
        modes_seen += 1;
    }
    assert_eq!(modes_seen, 6 + views.len());
}

/// Frame times the viewer reports are never silently wrong: with egui painting on the same
/// device between frames (where lavapipe's timestamps come out far too short), every frame's
/// GPU time is either from plausible timestamps or marked as wall time.
#[test]
fn viewer_frame_timings_are_plausible_or_marked() {
    use gilab::render::engine::TimingSource;
    let f = fixture("timing");
    let text = CORNELL
        .replace("size = [32, 32]", "size = [128, 128]")
        .replace("reference_spp = 8", "reference_spp = 2");
    let preset = LoadedPreset::from_text(&text, None).unwrap();
    let mut options = ViewerOptions::new(preset);
    options.watch = false;
    options.cache_dir = f.dir.join("cache");
    let mut v =
        gilab::app::headless::HeadlessViewer::new(common::gpu(), options, [800, 600]).unwrap();
    v.app.frame_budget_ms = 0.0;
    let mut seen = 0;
    for _ in 0..8 {
        v.frame().unwrap();
        let s = v.app.session.as_ref().unwrap();
        for r in &s.runs {
            if let Some(fr) = &r.last_frame {
                seen += 1;
                match fr.timing {
                    TimingSource::Timestamps => {
                        let passes: f64 = fr.gpu_ms_by_pass.iter().map(|p| p.1).sum();
                        assert!((passes - fr.gpu_ms).abs() < 1e-6);
                        assert!(
                            fr.wall_ms < 20.0 || fr.gpu_ms >= 0.1 * fr.wall_ms,
                            "implausible timestamps passed as GPU time: {fr:?}"
                        );
                    }
                    _ => {
                        assert_eq!(fr.gpu_ms, fr.wall_ms);
                        assert!(fr.gpu_ms_by_pass.is_empty());
                    }
                }
            }
        }
    }
    assert!(seen > 0);
}

/// The BRDF slice window picks the material under the pointer (a CPU ray through the hovered
/// pixel) and draws its slices under the three models.
#[test]
fn brdf_slice_window_shows_the_material_under_the_cursor() {
    let f = fixture("brdf-slice");
    let mut h = viewer(&f, false);
    // Below the fold of the side panel: an accessibility click.
    h.get_by_label("BRDF slice under the cursor")
        .click_accesskit();
    h.run_steps(2);
    assert!(h.state().brdf_window.open);
    // Sweep the pointer over the central area until it is over a pane.
    let mut picked = None;
    'sweep: for y in [200.0f32, 300.0, 400.0, 500.0] {
        for x in [500.0f32, 700.0, 900.0, 1100.0] {
            h.event(egui::Event::PointerMoved(egui::pos2(x, y)));
            h.run_steps(2);
            if let Some(m) = h.state().brdf_window.shown_material() {
                picked = Some((m, x, y));
                break 'sweep;
            }
        }
    }
    let (m, x, y) = picked.expect("no material picked anywhere over the panes");
    let (px, py) = h.state().panels.inspected.expect("a hovered pixel");
    let name = session(&h).scene.materials[m].name.clone();
    eprintln!("pointer ({x}, {y}) -> pixel ({px}, {py}) -> material '{name}'");
    // The window names it.
    h.get_by_label_contains(&format!("material '{name}'"));
    // For looking at it: GILAB_TEST_SCREENSHOTS=DIR saves the rendered window.
    if let Some(dir) = std::env::var_os("GILAB_TEST_SCREENSHOTS") {
        h.run_steps(2);
        let image = h.render().expect("wgpu render of the window");
        image
            .save(Path::new(&dir).join("brdf-slice-window.png"))
            .unwrap();
    }
}

/// The pixel inspector lists, for a pane showing a debug view, every debug view of its
/// technique at the hovered pixel: DDGI's 8 probes a pixel reads and their shares (issue 61).
/// The values come from the debug buffer's planes, read back without waiting.
#[test]
fn inspector_lists_the_debug_views_under_the_pointer() {
    let f = fixture("inspector-debug");
    let mut h = viewer_on(&f, "ddgi.toml", false);
    let run = {
        let s = h.state_mut().session.as_mut().expect("session");
        let run = s.panes[0].run;
        let views = s.runs[run].engine.technique.debug_views();
        let corner = views
            .iter()
            .position(|v| v.name.starts_with("probe read at corner 0"))
            .expect("DDGI offers the corner views at 32²");
        s.panes[0].display = DisplayMode::Debug;
        s.panes[0].debug = corner;
        run
    };
    h.run_steps(4);
    // Sweep the pointer until a hovered surface pixel's debug channels have arrived.
    let mut found = None;
    'sweep: for y in [300.0f32, 400.0, 500.0, 600.0] {
        for x in [500.0f32, 700.0, 900.0, 1100.0] {
            h.event(egui::Event::PointerMoved(egui::pos2(x, y)));
            for _ in 0..6 {
                h.run_steps(1);
                let Some((px, py)) = h.state().panels.inspected else {
                    continue;
                };
                if let Some(v) = session(&h).inspect_debug(run, px, py) {
                    if v[7] > 0.0 {
                        found = Some((px, py, v));
                        break 'sweep;
                    }
                }
            }
        }
    }
    let (px, py, v) = found.expect("no surface pixel's debug channels arrived under the pointer");
    assert_eq!(v.len(), 24, "six planes of four channels");
    let named = (8..16).filter(|&c| v[c] > 0.0).count();
    let shares: f32 = (16..24).map(|c| v[c]).sum();
    eprintln!(
        "pixel ({px}, {py}): {} probes weigh in, corners {:?}, shares {:?}",
        v[4],
        &v[8..16],
        &v[16..24]
    );
    assert_eq!(v[4] as usize, named, "count against the named corners");
    assert!(
        named > 0 && (shares - 1.0).abs() < 1e-4,
        "shares sum to {shares}"
    );
    // The hover shows them, by name.
    h.run_steps(2);
    h.get_by_label_contains("debug views here");
    h.get_by_label_contains("share of corner 7 (+x+y+z)");
    if let Some(dir) = std::env::var_os("GILAB_TEST_SCREENSHOTS") {
        let image = h.render().expect("wgpu render of the window");
        image
            .save(Path::new(&dir).join("inspector-debug-views.png"))
            .unwrap();
    }
}
