//! Surfel GI (GIBS) on lavapipe, small images: furnace, the Cornell box against the reference,
//! leaks through thin walls (radial Gaussian depth), ray guiding, the multiscale mean
//! estimator's lag, pool invariants, stability, determinism, the ray budget.

mod common;

use common::{engine, luminance, render_reference, shared_reference};
use gilab::compare::{metrics, Image};
use gilab::render::engine::Engine;
use gilab::scene::{builtin, Camera, PunctualKind, PunctualLight, Scene};
use gilab::techniques::surfels::{PoolCounts, Surfels};
use glam::Vec3;
use std::sync::Arc;

fn surfels(e: &Engine) -> &Surfels {
    let any: &dyn std::any::Any = e.technique.as_any();
    any.downcast_ref::<Surfels>().expect("a surfels engine")
}

fn frames(e: &mut Engine, n: u32) {
    for _ in 0..n {
        e.render_frame().unwrap();
    }
}

fn energy(img: &Image) -> f64 {
    luminance(img.mean())
}

fn pool(e: &Engine) -> PoolCounts {
    surfels(e).pool_counts(&e.gpu).unwrap().unwrap()
}

/// White furnace (closed sphere, albedo 0.8, emission 1): every pixel converges to 1 / 0.2 = 5,
/// which needs the bounces carried through the cache and the paths where surfels do not cover.
#[test]
fn surfels_furnace_matches_closed_form() {
    let mut e = engine(
        "surfels",
        toml::toml! { ray_budget = 4096
        surfel_size = 0.06 },
        builtin::furnace(0.8, 1.0, 2),
        [48, 48],
        1,
    );
    // Surfels cover the visible part of the sphere and multi-bounce settles by ~100 frames.
    // (160 + 32 frames before 2026-11-26, for CI time: -0.06% against the 3% bound. At 32²
    // the seed's one spawn per 16×16 tile a frame covers only the top half of each tile by
    // then, -33%; 600 frames reach -0.05%: docs/known-issues.md.)
    frames(&mut e, 112);
    // Converged: restart the average (surfels kept) and average 16 more frames.
    let camera = e.camera;
    e.move_camera(camera);
    frames(&mut e, 16);
    let img = e.read_output().unwrap();
    for (c, v) in img.mean().iter().enumerate() {
        eprintln!(
            "surfel furnace channel {c}: {v:.4} vs 5 ({:+.2}%)",
            (v / 5.0 - 1.0) * 100.0
        );
        assert!((v / 5.0 - 1.0).abs() < 0.03, "channel {c}: {v}");
    }
    // Issue 57: the furnace converges within 1% (the 3% above is issue 38's bound).
    let worst = img
        .mean()
        .iter()
        .map(|v| (v / 5.0 - 1.0).abs())
        .fold(0.0, f64::max);
    common::targets::check(
        "surfels-furnace-1pct",
        common::targets::Better::Lower,
        0.01,
        worst,
        "|radiance / 5 - 1|, worst channel, surfel furnace 48² after 112 + 16 frames",
    );
    assert_eq!(e.ray_counts().unwrap().invalid_samples, 0);
}

/// Cornell box at 128²: energy within 5% of a 512-spp reference after 96 frames, relMSE bounded.
#[test]
fn surfels_converge_near_reference_on_cornell() {
    let size = [128, 128];
    // The Cornell truth Lumen's and ReSTIR's tests share (512 spp; 2,048 before 2026-11-26:
    // its own relMSE is far under the bound either way).
    let truth = shared_reference(builtin::cornell(), size, 512, 11, 0, 0);
    let mut e = engine("surfels", toml::Table::new(), builtin::cornell(), size, 1);
    // 96 frames (256 before 2026-11-26, then 128, for CI time): measured at 256, energy 0.986
    // and relMSE 9.5e-4, at 128 0.976 and 3.4e-3, against bounds of 5% and 2e-2.
    // The coverage of the surfels' ray hits is read over frames 64-96, after the pool has
    // filled (issue 57's target: 90% of the hits the camera sees, at 128² after 64 frames).
    frames(&mut e, 64);
    let before = e.ray_counts().unwrap().cache_lookups;
    frames(&mut e, 32);
    let img = e.read_output().unwrap();
    let rays = e.ray_counts().unwrap();
    let window = rays.cache_lookups.since(&before);
    eprintln!("surfels, cornell 128², frames 64-96: {}", window.summary());
    common::targets::check(
        "surfels-seen-hits-covered-cornell",
        common::targets::Better::Higher,
        0.90,
        window.covered_seen().unwrap(),
        "share of surfel-ray hits the camera sees that surfels cover, cornell 128², frames 64-96",
    );
    let ratio = energy(&img) / energy(&truth);
    let m = metrics::compare(&img, &truth).unwrap();
    eprintln!(
        "surfels, cornell 128², 96 frames: energy ratio {ratio:.4}, relMSE {:.3e}, {:.2} rays/px/frame ({:?})",
        m.rel_mse,
        rays.total() as f64 / (128.0 * 128.0 * 96.0),
        rays.named()
    );
    assert!((ratio - 1.0).abs() < 0.05, "energy ratio {ratio}");
    // Issue 57: Cornell within 3% of the reference (the 5% above is the older bound).
    common::targets::check(
        "surfels-cornell-energy-3pct",
        common::targets::Better::Lower,
        0.03,
        (ratio - 1.0).abs(),
        "|energy / reference - 1| of the surfels at their defaults, cornell 128², 96 frames",
    );
    assert!(m.rel_mse < 0.02, "relMSE {}", m.rel_mse);
    assert_eq!(rays.invalid_samples, 0);
    common::assert_energy_and_error_controls_fail(&img, &truth, 0.05, 0.02);
}

/// The seed's irradiance sharing, measured where it can show: the bright-wall room (a spot light,
/// so the pixels' direct light has no noise and a frame's error is the surfels' own), 2,048
/// surfel rays a frame (about 2 per surfel: the seed's regime at 1080p; the default budget at
/// 64² gives each surfel about 60 rays a frame and little variance to share). One frame alone
/// after 16, sharing on against off at the same budget: the error against the reference is
/// printed and must not grow, and the energy moves by under 2% (the weights are the gather's,
/// so light is not carried across surfaces).
#[test]
fn irradiance_sharing_against_none() {
    let truth = shared_reference(bright_wall_room(), [64, 64], 256, 3, 0, 0);
    let mut results = Vec::new();
    for sharing in [false, true] {
        let mut p = toml::Table::new();
        p.insert("irradiance_sharing".into(), sharing.into());
        p.insert("accumulate".into(), false.into());
        p.insert("ray_budget".into(), 2048.into());
        let mut e = engine("surfels", p, bright_wall_room(), [64, 64], 3);
        frames(&mut e, 16);
        let img = e.read_output().unwrap();
        let rays = e.ray_counts().unwrap();
        assert_eq!(rays.invalid_samples, 0);
        let m = metrics::compare(&img, &truth).unwrap();
        let flip = gilab::compare::flip::ldr_flip(&img, &truth, &Default::default()).unwrap();
        let ratio = energy(&img) / energy(&truth);
        eprintln!(
            "surfels, bright-wall room 64², frame 16 alone, irradiance sharing {sharing}: relMSE {:.3e}, FLIP {flip:.4}, energy ratio {ratio:.4}, {} surfel rays",
            m.rel_mse,
            rays.kind("surfel")
        );
        results.push((m.rel_mse, ratio));
    }
    let ((off, off_energy), (on, on_energy)) = (results[0], results[1]);
    assert!(
        on <= off * 1.02,
        "sharing relMSE {on:.3e} against {off:.3e}"
    );
    assert!(
        (on_energy / off_energy - 1.0).abs() < 0.02,
        "sharing moved the energy: {on_energy} against {off_energy}"
    );
}

/// The seed's ray binning (`ray_binning`, issue 57): the rays run in bin order (grid cell,
/// direction quadrant) but keep their index, so the image and the ray counts equal those without
/// it, value for value, and every ray is traced once (the same counts).
#[test]
fn ray_binning_changes_only_the_order() {
    let run = |binning: bool| {
        let mut p = toml::toml! { ray_budget = 4096 };
        p.insert("ray_binning".into(), binning.into());
        let mut e = engine("surfels", p, builtin::cornell(), [48, 48], 2);
        frames(&mut e, 6);
        (e.read_output().unwrap(), e.ray_counts().unwrap().by_kind)
    };
    let (plain, plain_rays) = run(false);
    let (binned, binned_rays) = run(true);
    assert_eq!(binned.non_finite_count(), 0);
    assert_eq!(plain_rays, binned_rays, "ray counts differ");
    assert!(plain.rgb == binned.rgb, "binning changed the image");
}

/// `spawn_tiles = "scaled"` (issue 57, a departure from the seed, off by default): spawn tiles
/// keep the seed's size against the surfels' on screen, so a 64² image (tiles of 1 pixel
/// instead of 16) is covered after a few frames: after 8 frames fewer pixels lack surfel
/// coverage than with the seed's 16x16 tiles, and the pool's counters still add up.
#[test]
fn scaled_spawn_tiles_cover_a_small_image_sooner() {
    let size = 64u32;
    let uncovered = |spawn: &str| {
        let mut p = toml::Table::new();
        p.insert("spawn_tiles".into(), spawn.into());
        let mut e = engine("surfels", p, builtin::cornell(), [size, size], 1);
        frames(&mut e, 8);
        let n = (size * size) as usize;
        let debug = e.read_debug().unwrap().unwrap();
        let coverage = gilab::render::debug_channel(&debug, n, 1);
        let counts = surfels(&e).pool_counts(&e.gpu).unwrap().unwrap();
        assert_eq!(counts.live + counts.free, counts.capacity, "{spawn}");
        let bare = coverage.iter().filter(|c| **c < 0.25).count();
        eprintln!(
            "cornell 64², 8 frames, spawn_tiles = {spawn}: {bare} of {n} pixels with coverage under 0.25, {} live surfels",
            counts.live
        );
        bare
    };
    let (seed, scaled) = (uncovered("16"), uncovered("scaled"));
    assert!(scaled < seed, "scaled {scaled} against 16x16 tiles {seed}");
}

/// Luminance inside the thin-wall room (interior light off: the truth is exactly 0) seen from
/// inside after surfels were spawned outside in the sun: the seed's leak through thin walls.
/// Each configuration is rendered once per test binary (two tests read the default's).
fn interior_luminance_after_outside_view(radial_depth: bool, apply: &str) -> f64 {
    type Done = Vec<((bool, String), f64)>;
    static DONE: std::sync::Mutex<Done> = std::sync::Mutex::new(Vec::new());
    let mut done = DONE.lock().unwrap_or_else(|e| e.into_inner());
    let key = (radial_depth, apply.to_string());
    if let Some((_, v)) = done.iter().find(|(k, _)| *k == key) {
        return *v;
    }
    let v = render_interior_luminance_after_outside_view(radial_depth, apply);
    done.push((key, v));
    v
}

/// The thin-wall room (48², `ray_budget = 8192`, `surfel_size = 0.06` and `params`) after 48
/// frames outside, facing the sunlit wall and the ground before it, then moved inside with its
/// surfels and their irradiance kept (as a game would).
fn thin_wall_engine_moved_inside(params: toml::Table) -> Engine {
    let scene = builtin::thin_wall(0.0);
    let inside = scene.default_camera();
    let mut p = toml::toml! { ray_budget = 8192
    surfel_size = 0.06 };
    p.extend(params);
    let mut e = engine("surfels", p, scene, [48, 48], 1);
    e.set_camera(Camera {
        position: Vec3::new(0.0, 1.5, -6.0),
        target: Vec3::new(0.0, 0.5, -2.0),
        up: Vec3::Y,
        fov_y: 60.0,
    });
    frames(&mut e, 48);
    e.move_camera(inside);
    e
}

fn render_interior_luminance_after_outside_view(radial_depth: bool, apply: &str) -> f64 {
    let mut p = toml::Table::new();
    p.insert("radial_depth".into(), radial_depth.into());
    p.insert("apply_resolution".into(), apply.into());
    let mut e = thin_wall_engine_moved_inside(p);
    frames(&mut e, 8);
    let img = e.read_output().unwrap();
    assert_eq!(e.ray_counts().unwrap().invalid_samples, 0);
    energy(&img)
}

#[test]
fn radial_depth_stops_light_leaking_through_thin_walls() {
    // The shipped default, quarter-area apply (full-resolution apply's leak is measured in
    // quarter_area_apply_against_full).
    let with_depth = interior_luminance_after_outside_view(true, "quarter");
    let without = interior_luminance_after_outside_view(false, "quarter");
    // The reference inside is exactly 0 (tests/gpu.rs thin_wall_does_not_leak); the sunlit
    // exterior is ~5 in luminance. Tolerance: 0.2% of that.
    let tolerance = 0.02;
    // What the 8 accumulated frames hold is partly the transient of the interior's fill: each
    // frame alone, frames 9-40 inside, is printed beside it (not asserted).
    let steady = steady_interior_luminance();
    eprintln!(
        "thin-wall interior luminance after the outside view (quarter apply): radial depth on {with_depth:.5}, off {without:.5} (reference 0, tolerance {tolerance}); each frame alone, frames 9-40 inside: {steady:.5}"
    );
    common::targets::check(
        "surfels-default-leak",
        common::targets::Better::Lower,
        tolerance,
        with_depth,
        "thin-wall interior luminance, surfels' defaults",
    );
    assert!(
        with_depth < 0.5 * without,
        "radial depth should remove most of the leak: {with_depth} vs {without}"
    );
}

/// The same sequence as `interior_luminance_after_outside_view` at the defaults, each frame
/// alone (`accumulate = false`): the mean interior luminance of frames 9-40 after moving inside.
fn steady_interior_luminance() -> f64 {
    let mut e = thin_wall_engine_moved_inside(toml::toml! { accumulate = false });
    frames(&mut e, 8);
    let mut sum = 0.0;
    for _ in 0..32 {
        frames(&mut e, 1);
        sum += energy(&e.read_output().unwrap());
    }
    sum / 32.0
}

/// A dark room lit by a spot light on one white wall: the light surfels see comes from that
/// wall. Guided rays (same budget) leave less variance per surfel than cosine sampling.
fn bright_wall_room() -> Scene {
    let mut s = Scene::new("bright-wall");
    let dark = s.add_material(gilab::scene::Material::lambert("dark", Vec3::splat(0.05)));
    let white = s.add_material(gilab::scene::Material::lambert("white", Vec3::splat(0.9)));
    let v = Vec3::new;
    let (a, h) = (3.0f32, 3.0f32);
    s.add_quad(
        v(-a, 0.0, -a),
        v(-a, 0.0, a),
        v(a, 0.0, a),
        v(a, 0.0, -a),
        dark,
    );
    s.add_quad(v(-a, h, -a), v(a, h, -a), v(a, h, a), v(-a, h, a), dark);
    s.add_quad(
        v(-a, 0.0, -a),
        v(a, 0.0, -a),
        v(a, h, -a),
        v(-a, h, -a),
        dark,
    );
    s.add_quad(v(-a, 0.0, a), v(-a, h, a), v(a, h, a), v(a, 0.0, a), dark);
    s.add_quad(
        v(-a, 0.0, -a),
        v(-a, h, -a),
        v(-a, h, a),
        v(-a, 0.0, a),
        white,
    );
    s.add_quad(v(a, 0.0, -a), v(a, 0.0, a), v(a, h, a), v(a, h, -a), dark);
    s.lights.push(PunctualLight {
        kind: PunctualKind::Spot,
        position: v(2.5, 1.5, 0.0),
        direction: v(-1.0, 0.0, 0.0),
        intensity: Vec3::splat(60.0),
        inner_cone: 0.5,
        outer_cone: 0.7,
    });
    s.camera = Some(Camera {
        position: v(2.8, 2.5, 0.0),
        target: v(0.0, 0.0, 0.0),
        up: Vec3::Y,
        fov_y: 70.0,
    });
    s
}

/// Mean relative variance of a frame's irradiance estimate (the estimator's variance over its
/// mean squared) over the surfels with at least `min_rays` rays, and how many there are.
fn surfel_relative_variance(e: &Engine, min_rays: f32) -> (f64, usize) {
    let states = surfels(e).surfel_states(&e.gpu).unwrap();
    let rel: Vec<f64> = states
        .iter()
        .filter(|s| s.rays_total >= min_rays)
        .map(|s| {
            let m = luminance(s.irradiance.map(|v| v as f64));
            luminance(s.variance.map(|v| v as f64)) / (m * m).max(1e-12)
        })
        .collect();
    (rel.iter().sum::<f64>() / rel.len().max(1) as f64, rel.len())
}

fn mean_relative_variance(guiding: bool) -> (f64, usize) {
    let mut p = toml::Table::new();
    p.insert("guiding".into(), guiding.into());
    p.insert("ray_budget".into(), 8192.into());
    let mut e = engine("surfels", p, bright_wall_room(), [64, 64], 3);
    frames(&mut e, 96);
    surfel_relative_variance(&e, 256.0)
}

#[test]
fn guiding_lowers_per_surfel_variance() {
    let (guided, n_guided) = mean_relative_variance(true);
    let (cosine, n_cosine) = mean_relative_variance(false);
    eprintln!(
        "bright-wall room, same ray budget: mean relative variance per surfel guided {guided:.4} ({n_guided} surfels), cosine {cosine:.4} ({n_cosine} surfels): {:.2}x",
        cosine / guided
    );
    assert!(n_guided > 50 && n_cosine > 50);
    assert!(guided < cosine, "guided {guided} vs cosine {cosine}");
}

/// A closed dark room (6 × 3 × 6 m, walls of albedo `wall`) for the guiding curves, with the camera
/// looking down at the floor from one corner.
fn guiding_room(wall: f32) -> Scene {
    let mut s = Scene::new("guiding-room");
    let m = s.add_material(gilab::scene::Material::lambert("wall", Vec3::splat(wall)));
    let v = Vec3::new;
    let (a, h) = (3.0f32, 3.0f32);
    s.add_quad(
        v(-a, 0.0, -a),
        v(-a, 0.0, a),
        v(a, 0.0, a),
        v(a, 0.0, -a),
        m,
    );
    s.add_quad(v(-a, h, -a), v(a, h, -a), v(a, h, a), v(-a, h, a), m);
    s.add_quad(v(-a, 0.0, -a), v(a, 0.0, -a), v(a, h, -a), v(-a, h, -a), m);
    s.add_quad(v(-a, 0.0, a), v(-a, h, a), v(a, h, a), v(a, 0.0, a), m);
    s.add_quad(v(-a, 0.0, -a), v(-a, h, -a), v(-a, h, a), v(-a, 0.0, a), m);
    s.camera = Some(Camera {
        position: v(2.8, 2.5, 0.0),
        target: v(0.0, 0.0, 0.0),
        up: Vec3::Y,
        fov_y: 70.0,
    });
    s
}

/// The seed's test bed for ray guiding (issue 57): per-surfel relative variance of a frame's
/// irradiance estimate against surfel rays per frame, guided and cosine, on three lighting
/// set-ups: a bright wall (`bright_wall_room`, a spot on one white wall), the sky through a
/// window (the room's +x wall left open over a 2 × 1 m window, sky radiance 4, no light), and a
/// small bright lamp (a point light 0.1 m under the ceiling in a corner). 64², 96 frames,
/// surfels with at least 64 rays in all. Prints the table in docs/surfels.md; run with
/// `--ignored --nocapture` (about 3 minutes on lavapipe).
#[test]
#[ignore]
fn guiding_against_cosine_over_ray_budgets() {
    let window = || {
        let mut s = guiding_room(0.7);
        let m = s.add_material(gilab::scene::Material::lambert("wall", Vec3::splat(0.7)));
        let v = Vec3::new;
        let (a, h) = (3.0f32, 3.0f32);
        // The +x wall around a window from z -1..1, y 1..2.
        s.add_quad(v(a, 0.0, -a), v(a, 0.0, a), v(a, 1.0, a), v(a, 1.0, -a), m);
        s.add_quad(v(a, 2.0, -a), v(a, 2.0, a), v(a, h, a), v(a, h, -a), m);
        s.add_quad(
            v(a, 1.0, -a),
            v(a, 1.0, -1.0),
            v(a, 2.0, -1.0),
            v(a, 2.0, -a),
            m,
        );
        s.add_quad(
            v(a, 1.0, 1.0),
            v(a, 1.0, a),
            v(a, 2.0, a),
            v(a, 2.0, 1.0),
            m,
        );
        s.sky = Vec3::splat(4.0);
        s
    };
    let lamp = || {
        let mut s = guiding_room(0.7);
        let v = Vec3::new;
        s.add_quad(
            v(3.0, 0.0, -3.0),
            v(3.0, 0.0, 3.0),
            v(3.0, 3.0, 3.0),
            v(3.0, 3.0, -3.0),
            0,
        );
        s.lights.push(PunctualLight {
            kind: PunctualKind::Point,
            position: v(-2.8, 2.9, -2.8),
            direction: v(0.0, -1.0, 0.0),
            intensity: Vec3::splat(20.0),
            inner_cone: 0.0,
            outer_cone: 0.0,
        });
        s
    };
    let setups: [(&str, Scene); 3] = [
        ("bright wall", bright_wall_room()),
        ("sky through a window", window()),
        ("small bright lamp", lamp()),
    ];
    println!("| set-up | surfel rays a frame | live surfels | rays a surfel a frame | mean relative variance, guided | cosine | cosine / guided |");
    println!("| --- | ---: | ---: | ---: | ---: | ---: | ---: |");
    for (name, scene) in setups {
        for budget in [2048i64, 8192, 32768] {
            let run = |guiding: bool| {
                let mut p = toml::Table::new();
                p.insert("guiding".into(), guiding.into());
                p.insert("ray_budget".into(), budget.into());
                let mut e = engine("surfels", p, scene.clone(), [64, 64], 3);
                frames(&mut e, 96);
                let live = surfels(&e).pool_counts(&e.gpu).unwrap().unwrap().live;
                (surfel_relative_variance(&e, 64.0).0, live)
            };
            let ((guided, live), (cosine, _)) = (run(true), run(false));
            println!(
                "| {name} | {budget} | {live} | {:.1} | {guided:.3} | {cosine:.3} | {:.2}× |",
                budget as f64 / live as f64,
                cosine / guided
            );
            assert!(guided.is_finite() && cosine.is_finite());
        }
    }
}

/// The back-wall lamp switched on after 32 frames: per frame after the switch, the mean
/// irradiance over live surfels (what lags; the pixels' direct light does not), and the error
/// of the image averaged over frames 48..64 after the switch against the lamp-on reference.
fn lag(msme: bool, truth: &Image) -> (Vec<f64>, f64) {
    let mut p = toml::Table::new();
    p.insert("msme".into(), msme.into());
    p.insert("ray_budget".into(), 8192.into());
    p.insert("surfel_size".into(), 0.06.into());
    p.insert("max_surfels".into(), 4096.into());
    let mut e = engine(
        "surfels",
        p,
        builtin::cornell_with_lamp(Some(0.0)),
        [64, 64],
        1,
    );
    frames(&mut e, 32);
    let on = builtin::cornell_with_lamp(Some(40.0));
    let gpu_scene = Arc::new(gilab::scene::gpu_scene::GpuScene::upload(&e.gpu, &on));
    e.change_scene(Arc::new(on), gpu_scene).unwrap();
    let camera = e.camera;
    let mut irradiance = Vec::new();
    // 64 frames after the switch (96 before 2026-11-26, for CI time: MSME settled in 38),
    // the last 16 averaged for the error.
    for frame in 0..64 {
        if frame == 48 {
            e.move_camera(camera);
        }
        e.render_frame().unwrap();
        let st = surfels(&e).surfel_states(&e.gpu).unwrap();
        let sum: f64 = st
            .iter()
            .map(|s| luminance(s.irradiance.map(|v| v as f64)))
            .sum();
        irradiance.push(sum / st.len().max(1) as f64);
    }
    assert_eq!(e.ray_counts().unwrap().invalid_samples, 0);
    let tail = metrics::compare(&e.read_output().unwrap(), truth)
        .unwrap()
        .rel_mse;
    (irradiance, tail)
}

#[test]
fn msme_settles_faster_than_running_mean_after_a_light_change() {
    let truth = render_reference(
        builtin::cornell_with_lamp(Some(40.0)),
        [64, 64],
        256,
        64,
        5,
        0,
    )
    .image;
    let (msme, msme_error) = lag(true, &truth);
    let (running, running_error) = lag(false, &truth);
    // Settled: the MSME run's mean irradiance over its last 16 frames.
    let settled = msme[msme.len() - 16..].iter().sum::<f64>() / 16.0;
    let settle = |series: &[f64]| {
        (0..series.len())
            .find(|&i| {
                series[i..]
                    .iter()
                    .all(|&x| (x / settled - 1.0).abs() < 0.05)
            })
            .map(|i| i + 1)
    };
    let (m, r) = (settle(&msme), settle(&running));
    eprintln!(
        "lamp switched on: frames until the mean surfel irradiance stays within 5% of its settled value: MSME {m:?}, running mean {r:?} (of 64); relMSE of frames 48-64 against the reference: MSME {msme_error:.3e}, running mean {running_error:.3e}"
    );
    let m = m.expect("MSME settles within 64 frames");
    assert!(r.is_none_or(|r| m < r), "MSME {m} vs running mean {r:?}");
    assert!(
        msme_error <= running_error * 1.1,
        "converged error {msme_error} vs {running_error}"
    );
}

/// live + free = capacity after any number of frames, camera moves and resets, with a pool
/// small enough that recycling must run.
#[test]
fn pool_invariants_hold_through_moves_and_resets() {
    let scene = builtin::courtyard(15.0, 1.0, 1.0);
    let start = scene.default_camera();
    let mut e = engine(
        "surfels",
        toml::toml! { max_surfels = 1024 },
        scene,
        [96, 96],
        1,
    );
    let check = |e: &Engine, when: &str| {
        let p = pool(e);
        assert_eq!(p.live + p.free, p.capacity, "{when}: {p:?}");
        assert_eq!(p.live, p.live_slots, "{when}: {p:?}");
        p
    };
    let mut recycled = 0;
    let mut peak = 0;
    for step in 0..6 {
        frames(&mut e, 12);
        let p = check(&e, &format!("step {step}"));
        recycled += p.recycled_last_frame;
        peak = peak.max(p.live);
        let mut c = start;
        let angle = step as f32 * 0.9;
        c.position = start.position + Vec3::new(angle.sin() * 6.0, 0.0, angle.cos() * 3.0 - 3.0);
        e.move_camera(c);
        frames(&mut e, 1);
        recycled += check(&e, "after a move").recycled_last_frame;
    }
    e.reset();
    let p = check(&e, "after reset");
    assert_eq!(p.live, 0);
    frames(&mut e, 4);
    check(&e, "after reset and frames");
    // Gathers read each cell's list in slot order (determinism; shaders/parts/surfels/sort_cells.wgsl).
    let lists = surfels(&e).cell_lists(&e.gpu).unwrap();
    let longest = lists.iter().map(Vec::len).max().unwrap_or(0);
    for l in &lists {
        assert!(
            l.windows(2).all(|w| w[0] < w[1]),
            "cell list not sorted: {l:?}"
        );
    }
    eprintln!(
        "pool of 1024: peak live {peak}, recycled (sampled frames) {recycled}; {} cell lists, longest {longest}",
        lists.len()
    );
    assert!(longest > 2, "lists too short to test the sort: {longest}");
    assert!(peak > 900, "the pool should fill: peak {peak}");
    assert!(recycled > 0, "recycling must run on a full pool");
}

#[test]
fn surfels_stay_finite_on_hard_cases() {
    for (name, scene) in [
        ("hard-cases", builtin::hard_cases(1e6)),
        ("glossy", builtin::glossy()),
    ] {
        let mut e = engine(
            "surfels",
            toml::toml! { ray_budget = 4096 },
            scene,
            [48, 48],
            1,
        );
        frames(&mut e, 16);
        let img = e.read_output().unwrap();
        assert_eq!(img.non_finite_count(), 0, "{name}");
        assert_eq!(e.ray_counts().unwrap().invalid_samples, 0, "{name}");
        let states = surfels(&e).surfel_states(&e.gpu).unwrap();
        assert!(!states.is_empty(), "{name}: surfels spawned");
        assert!(
            states
                .iter()
                .all(|s| s.irradiance.iter().all(|v| v.is_finite() && *v >= 0.0)),
            "{name}: surfel irradiance finite and non-negative"
        );
    }
}

#[test]
fn surfels_are_deterministic_for_a_fixed_seed() {
    let run = |seed| {
        let mut e = engine(
            "surfels",
            toml::toml! { ray_budget = 4096 },
            builtin::cornell(),
            [48, 48],
            seed,
        );
        frames(&mut e, 12);
        let img = e.read_output().unwrap();
        (
            img.rgb.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            e.ray_counts().unwrap(),
        )
    };
    let a = run(5);
    let b = run(5);
    let c = run(6);
    assert_eq!(a.1, b.1, "ray counts");
    assert!(a.0 == b.0, "same seed, different images");
    assert!(a.0 != c.0, "another seed must give another image");
}

/// The viewer's slider: rays per pixel per frame measured within 10% of the value asked for.
#[test]
fn ray_budget_is_honoured() {
    for wanted in [3.0, 6.0] {
        let mut e = engine(
            "surfels",
            toml::Table::new(),
            builtin::cornell(),
            [64, 64],
            1,
        );
        frames(&mut e, 16);
        let measured = e.rays_per_pixel_per_frame(&e.ray_counts().unwrap());
        e.apply_ray_budget(wanted, measured).unwrap();
        frames(&mut e, 16);
        let got = e
            .rays_per_pixel_per_frame(&e.ray_counts().unwrap())
            .unwrap();
        eprintln!(
            "ray budget {wanted} rays/px/frame: ray_budget = {}, measured {got:.3}",
            surfels(&e).settings.ray_budget
        );
        assert!(
            (got / wanted - 1.0).abs() < 0.1,
            "asked {wanted}, got {got}"
        );
    }
}

/// The debug views: ids, coverage, rays, variance, cells, ages and ray-hit coverage present and
/// sane.
#[test]
fn debug_views_show_surfels() {
    let mut e = engine(
        "surfels",
        toml::toml! { surfel_size = 0.06 },
        builtin::cornell(),
        [64, 64],
        1,
    );
    frames(&mut e, 16);
    let names: Vec<&str> = e.technique.debug_views().iter().map(|v| v.name).collect();
    // Seven of the surfels' own, then the reflections part's four (plane 2).
    assert_eq!(names.len(), 11, "{names:?}");
    assert!(
        names[7..].iter().all(|n| n.starts_with("reflections: ")),
        "{names:?}"
    );
    let data = e.read_debug().unwrap().unwrap();
    let px = 64 * 64;
    let ch = |c| gilab::render::debug_channel(&data, px, c);
    let ids = ch(0);
    let covered = ids.iter().filter(|v| **v > 0.0).count();
    assert!(covered > px / 4, "pixels with a surfel: {covered}");
    let distinct: std::collections::BTreeSet<u32> = ids.iter().map(|v| *v as u32).collect();
    assert!(distinct.len() > 8, "distinct surfels: {}", distinct.len());
    assert!(ch(1).iter().any(|v| *v > 0.5), "coverage");
    assert!(
        ch(4).iter().all(|v| *v >= 0.0) && ch(4).iter().any(|v| *v > 0.0),
        "cells"
    );
    assert!(
        ch(5).iter().all(|v| *v <= 17.0),
        "ages within the frames rendered"
    );
    // Ray-hit coverage class: 1 surfels, 2 cell average, 3 none, 0 where no surface or no
    // gather wrote (quarter apply writes its block pixels). After 16 frames at 64² with
    // `surfel_size = 0.06` most of the box is covered by surfels.
    let classes = ch(6);
    assert!(
        classes.iter().all(|v| [0.0, 1.0, 2.0, 3.0].contains(v)),
        "classes"
    );
    let by_surfels = classes.iter().filter(|v| **v == 1.0).count();
    assert!(
        by_surfels > px / 4,
        "pixels covered by surfels: {by_surfels}"
    );
}

/// `direct = "restir"`: ReSTIR DI (with ReGIR on many lights) gives the pixels' direct light;
/// its passes are listed and run, and the image stays finite.
#[test]
fn restir_direct_light_runs_with_surfels() {
    let mut e = engine(
        "surfels",
        toml::toml! { direct = "restir"
        surfel_size = 0.06
        ray_budget = 2048 },
        builtin::many_lights(256, 1),
        [32, 32],
        1,
    );
    let passes = e.passes();
    for name in ["initial_temporal", "regir_build", "direct"] {
        assert!(
            passes.iter().any(|p| p.name == name && p.runs),
            "{name} should run: {passes:?}"
        );
    }
    frames(&mut e, 4);
    let img = e.read_output().unwrap();
    assert_eq!(img.non_finite_count(), 0);
    assert_eq!(e.ray_counts().unwrap().invalid_samples, 0);
    assert!(energy(&img) > 0.0);
}

/// GIBS's transform ids (issue 36): a surfel remembers the triangle it sits on, and every frame
/// its instance's motion moves it. Through `moving` played at `time_scale = 6` (0.1 s a frame:
/// the ball rolls and the lamp flies), every live surfel lies on a surface of the current
/// pose; without the transform, surfels spawned on the ball or the lamp stay in the air.
#[test]
fn surfels_move_with_their_objects() {
    let mut scene = builtin::build("moving", &toml::Table::new()).unwrap();
    Arc::make_mut(scene.motion.as_mut().unwrap()).time_scale = 6.0;
    let mut e = engine("surfels", toml::Table::new(), scene, [64, 64], 3);
    frames(&mut e, 16);
    let tris = e.scene.triangle_positions();
    let live = surfels(&e).surfel_positions(&e.gpu).unwrap();
    let points: Vec<Vec3> = live.iter().map(|s| s.0).collect();
    let off = common::off_surface(&points, &tris);
    println!(
        "{} live surfels at t = {:.2} s; {} more than 1 cm off every surface (worst {:.3} m)",
        live.len(),
        e.scene_time,
        off.len(),
        off.iter().copied().fold(0.0, f32::max)
    );
    assert!(live.len() > 100, "{}", live.len());
    assert!(
        live.iter().all(|s| s.2 > 0),
        "a surfel without its triangle"
    );
    assert!(off.is_empty(), "{} surfels float in the air", off.len());
}

/// Quarter-area apply (the seed's default): a gather per 2x2 block, upsampled by depth and
/// normal, against a gather at every pixel. Cornell 48², 24 frames: the images agree (energy
/// within 1%, relMSE between them under 1e-2; at 64² and 32 frames both measured 5.1e-2 and
/// 5.2e-2 against a 256-spp reference). The thin-wall leak with radial depth stays within 1.5x
/// of full-resolution apply's (measured 0.0229 against 0.0198: the block's other pixels mark
/// their surfels as seen through `mark_reach`; without it recycling took surfels no block
/// sample saw, and their young, empty depth maps leaked 0.0325).
#[test]
fn quarter_area_apply_against_full() {
    let size = [48, 48];
    let run = |apply: &str| {
        let mut p = toml::Table::new();
        p.insert("apply_resolution".into(), apply.into());
        let mut e = engine("surfels", p, builtin::cornell(), size, 1);
        frames(&mut e, 24);
        assert_eq!(e.ray_counts().unwrap().invalid_samples, 0);
        let passes: Vec<&str> = e
            .passes()
            .iter()
            .filter(|p| p.runs)
            .map(|p| p.name)
            .collect();
        assert_eq!(
            passes.contains(&"apply gather"),
            apply == "quarter",
            "{passes:?}"
        );
        e.read_output().unwrap()
    };
    let (quarter, full) = (run("quarter"), run("full"));
    let between = metrics::compare(&quarter, &full).unwrap().rel_mse;
    let ratio = energy(&quarter) / energy(&full);
    let leak_quarter = interior_luminance_after_outside_view(true, "quarter");
    let leak_full = interior_luminance_after_outside_view(true, "full");
    eprintln!(
        "cornell 48², 24 frames: quarter vs full energy {ratio:.4}, relMSE between {between:.3e}; thin-wall leak quarter {leak_quarter:.5}, full {leak_full:.5}"
    );
    assert!((ratio - 1.0).abs() < 0.01, "energy {ratio}");
    assert!(between < 1e-2, "relMSE between {between}");
    assert!(
        leak_quarter < 1.5 * leak_full + 1e-3,
        "leak quarter {leak_quarter} full {leak_full}"
    );
}

/// Issue 57's coverage target on the courtyard (sun, sky, open top) at the defaults, 128²:
/// after 64 frames, at least 90% of the surfel-ray hits the camera sees are covered by surfels
/// (their footprints, or the cell average). Hits the camera does not see are counted apart:
/// the seed spawns surfels only where the camera looks, so those continue as paths (printed).
#[test]
fn surfel_ray_hits_on_seen_surfaces_are_covered_on_the_courtyard() {
    let mut e = engine(
        "surfels",
        toml::Table::new(),
        builtin::courtyard(15.0, 1.0, 1.0),
        [128, 128],
        1,
    );
    frames(&mut e, 64);
    let before = e.ray_counts().unwrap().cache_lookups;
    frames(&mut e, 16);
    let rays = e.ray_counts().unwrap();
    let window = rays.cache_lookups.since(&before);
    eprintln!(
        "surfels, courtyard 128², frames 64-80: {}",
        window.summary()
    );
    assert!(window.seen() > 0 && window.unseen() > 0, "{window:?}");
    common::targets::check(
        "surfels-seen-hits-covered-courtyard",
        common::targets::Better::Higher,
        0.90,
        window.covered_seen().unwrap(),
        "share of surfel-ray hits the camera sees that surfels cover, courtyard 128², frames 64-80",
    );
    assert_eq!(rays.invalid_samples, 0);
}

/// Light sampling at the surfels' ray hits: for each (label, `cache_direct`,
/// `cache_light_rays`), the surfels at their defaults otherwise, 64², 15 frames: the surfels'
/// own noise (mean relative variance of their ray estimates, the MSME's, over surfels with 16
/// rays or more; the surfels are the same in every run, spawning does not read irradiance), the
/// mean surfel irradiance, and the last frame's image (no accumulation) against a 256-spp
/// reference. Returns each run's (mean relative variance, mean irradiance).
fn surfel_hit_light_sampling(
    scene: &gilab::scene::Scene,
    runs: &[(&str, &str, i64)],
) -> Vec<(f64, f64)> {
    let size = [64, 64];
    let truth = shared_reference(scene.clone(), size, 256, 5, 0, 0);
    let mut out = Vec::new();
    for &(label, mode, rays_per_hit) in runs {
        let mut p = toml::Table::new();
        p.insert("cache_direct".into(), mode.into());
        p.insert("cache_light_rays".into(), rays_per_hit.into());
        p.insert("accumulate".into(), false.into());
        let mut e = engine("surfels", p, scene.clone(), size, 1);
        frames(&mut e, 15);
        let img = e.read_output().unwrap();
        let m = metrics::compare(&img, &truth).unwrap();
        let rays = e.ray_counts().unwrap();
        let states = surfels(&e).surfel_states(&e.gpu).unwrap();
        let sampled: Vec<_> = states.iter().filter(|s| s.rays_total >= 16.0).collect();
        let lum = |c: [f32; 3]| luminance(c.map(|v| v as f64));
        let rel_var = sampled
            .iter()
            .map(|s| lum(s.variance) / lum(s.irradiance).powi(2).max(1e-12))
            .sum::<f64>()
            / sampled.len().max(1) as f64;
        let mean_e =
            sampled.iter().map(|s| lum(s.irradiance)).sum::<f64>() / sampled.len().max(1) as f64;
        eprintln!(
            "surfels, 64², {label} (cache_direct = {mode}, cache_light_rays = {rays_per_hit}), 15 frames: {} surfels, mean relative variance {rel_var:.4}, mean irradiance {mean_e:.4}; frame 15 alone: relMSE {:.4e}, energy {:.4} of the reference, {:.2} rays/px/frame ({:.2} shadow), {:.1} ms GPU/frame",
            sampled.len(),
            m.rel_mse,
            energy(&img) / energy(&truth),
            rays.total() as f64 / (64.0 * 64.0 * 15.0),
            rays.by_kind[1] as f64 / (64.0 * 64.0 * 15.0),
            e.total_gpu_ms / 15.0
        );
        assert_eq!(img.non_finite_count(), 0);
        out.push((rel_var, mean_e));
    }
    out
}

/// Issue 57: light sampling at the surfels' ray hits on `many-lights` (1,024 lights), the
/// `cache_direct` choices (issue 60 added the light tree) after 15 frames. A measurement
/// (`--ignored --nocapture`), written up in docs/surfels.md.
#[test]
#[ignore]
fn light_sampling_at_surfel_hits_on_many_lights() {
    surfel_hit_light_sampling(
        &builtin::many_lights(1024, 7),
        &[
            ("power", "power", 1),
            ("regir", "regir", 1),
            ("reservoir", "reservoir", 1),
            ("tree", "tree", 1),
        ],
    );
}

/// Issue 60: GIBS's many-light figure (seed 001: random 2, reservoir 8 and lightcut 4 after 15
/// frames on 1,400 lights), with the tree's single descent and the world ReGIR clipmap beside
/// them. A measurement (`--ignored --nocapture`), written up in docs/light-tree.md; the same
/// runs as an experiment: presets/experiments/gibs-many-lights.toml.
#[test]
#[ignore]
fn gibs_many_light_figure() {
    surfel_hit_light_sampling(
        &builtin::many_lights(1400, 7),
        &[
            ("random 2", "power", 2),
            ("reservoir 8", "reservoir", 1),
            ("lightcut 4", "lightcut", 4),
            ("tree 1", "tree", 1),
            ("regir", "regir", 1),
        ],
    );
}

/// Issue 60: the stochastic lightcut at surfel ray hits (`cache_direct = "lightcut"`, 4 nodes)
/// lights the surfels as power sampling does: on 256 lights at 32² after 8 frames, the mean
/// over surfels of the paired difference of their irradiance is within 4 standard errors of
/// zero (the surfels are the same in both runs: spawning does not read irradiance), and the cut
/// grows past one node (more shadow rays than power's one per hit; printed: how many more). The algorithm's
/// unbiasedness, with a negative control, is checked on the CPU
/// (`light_tree_lightcut_covers_every_light_once_and_is_unbiased`, tests/cpu.rs).
#[test]
#[ignore = "slow tier, not run by CI (docs/testing.md#slow-tier): surfel hits lit by a lightcut (not a default), 70 s in CI"]
fn lightcut_at_surfel_hits_agrees_with_power_sampling() {
    let scene = builtin::many_lights(256, 7);
    let run = |mode: &str, rays: i64| {
        let mut p = toml::Table::new();
        p.insert("cache_direct".into(), mode.into());
        p.insert("cache_light_rays".into(), rays.into());
        let mut e = engine("surfels", p, scene.clone(), [32, 32], 1);
        frames(&mut e, 8);
        let states = surfels(&e).surfel_states(&e.gpu).unwrap();
        let shadow = e.ray_counts().unwrap().by_kind[1];
        assert_eq!(e.ray_counts().unwrap().invalid_samples, 0, "{mode}");
        (states, shadow)
    };
    let (power, power_shadow) = run("power", 1);
    let (cut, cut_shadow) = run("lightcut", 4);
    assert_eq!(power.len(), cut.len(), "the same surfels in both runs");
    let lum = |c: [f32; 3]| luminance(c.map(|v| v as f64));
    let d: Vec<f64> = power
        .iter()
        .zip(&cut)
        .map(|(a, b)| lum(b.irradiance) - lum(a.irradiance))
        .collect();
    let n = d.len() as f64;
    let mean = d.iter().sum::<f64>() / n;
    let se = (d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0) / n).sqrt();
    let mean_power = power.iter().map(|s| lum(s.irradiance)).sum::<f64>() / n;
    println!(
        "{n} surfels: mean irradiance by power {mean_power:.4}, lightcut 4 - power {mean:+.4} ± {se:.4} ({:+.2}%); shadow rays {cut_shadow} against {power_shadow} ({:.2}x)",
        100.0 * mean / mean_power,
        cut_shadow as f64 / power_shadow as f64
    );
    assert!(n >= 20.0, "only {n} surfels");
    assert!(
        mean.abs() <= 4.0 * se,
        "lightcut's surfel irradiance differs from power sampling's by {mean} ({se} standard error)"
    );
    assert!(
        cut_shadow as f64 > 1.2 * power_shadow as f64,
        "a cut of 4 nodes traced {cut_shadow} shadow rays against power's {power_shadow}"
    );
}

/// The lightcut's branch for directional lights and `cache_light_rays`' averaging, which the
/// many-light test above does not reach (issue 60, from the ninth session's review): on the
/// courtyard with only its sun (no lamps, no sky: the sun is the surfels' only direct light,
/// sampled by the cut's directional branch) at 32² after 8 frames, the surfels' irradiance with
/// a cut of 4 nodes and with power sampling averaged over 2 picks is paired, surfel by surfel,
/// with power sampling's one pick; each mean difference is within 4 standard errors of zero.
/// What it catches (edited shaders, not kept): an average divided by N + 1 (−23%, 5.1 standard
/// errors); a lost or doubled sun. Not a 20% error in the sun's weight (−11%, 2.6 standard
/// errors; the branch picks the sun by the pool's class pmf, as power sampling does).
#[test]
#[ignore = "slow tier, not run by CI (docs/testing.md#slow-tier): surfel hits lit by a lightcut (not a default), 82 s in CI"]
fn lightcut_and_light_rays_agree_with_power_sampling_under_the_sun() {
    let scene = builtin::courtyard(0.0, 1.0, 0.0);
    let run = |mode: &str, rays: i64| {
        let mut p = toml::Table::new();
        p.insert("cache_direct".into(), mode.into());
        p.insert("cache_light_rays".into(), rays.into());
        // The plain running mean over every ray: the samplers' difference, not the
        // estimator's short window, is what is compared.
        p.insert("msme".into(), false.into());
        let mut e = engine("surfels", p, scene.clone(), [32, 32], 1);
        frames(&mut e, 8);
        assert_eq!(e.ray_counts().unwrap().invalid_samples, 0, "{mode} {rays}");
        surfels(&e).surfel_states(&e.gpu).unwrap()
    };
    let power = run("power", 1);
    let lum = |c: [f32; 3]| luminance(c.map(|v| v as f64));
    let n = power.len() as f64;
    assert!(n >= 20.0, "only {n} surfels");
    let mean_power = power.iter().map(|s| lum(s.irradiance)).sum::<f64>() / n;
    // The sun reaches the surfels at all (0.517 measured): a sun lost by every sampler would
    // otherwise pass as agreement.
    assert!(mean_power > 0.25, "mean irradiance by power {mean_power}");
    for (mode, rays) in [("lightcut", 4), ("power", 2)] {
        let other = run(mode, rays);
        assert_eq!(power.len(), other.len(), "the same surfels in both runs");
        let d: Vec<f64> = power
            .iter()
            .zip(&other)
            .map(|(a, b)| lum(b.irradiance) - lum(a.irradiance))
            .collect();
        let mean = d.iter().sum::<f64>() / n;
        let se = (d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0) / n).sqrt();
        println!(
            "courtyard, {n} surfels: mean irradiance by power {mean_power:.4}; {mode} {rays} - power 1: {mean:+.4} ± {se:.4} ({:+.2}%)",
            100.0 * mean / mean_power
        );
        assert!(
            mean.abs() <= 4.0 * se,
            "{mode} {rays}: the surfels' irradiance differs from power sampling's by {mean} ({se} standard error)"
        );
    }
}
