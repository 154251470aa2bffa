//! Callisto shadows (`callisto-shadows`) on lavapipe, small images: forced full rate against the
//! reference's direct light, variable rate against full rate (rays counted, relMSE reported), the
//! culling and the debug views.

mod common;

use common::{engine, render_technique as render};
use gilab::compare::{heatmap, io, metrics, Image};
use gilab::render::{debug_channel, RayCounts, FLAG_NO_PRIMARY_EMISSION};
use gilab::scene::{builtin, Scene};

/// The reference path tracer's direct light: emission plus one bounce (NEE + MIS), rendered
/// once for each (scene, size, spp, seed, flags) and shared with the other tests and binaries
/// (the many-lights one costs most of a minute on lavapipe).
fn direct_reference(scene: Scene, size: [u32; 2], spp: u32, seed: u32, flags: u32) -> Image {
    common::shared_reference(scene, size, spp, seed, 1, flags)
}

fn callisto(
    scene: Scene,
    size: [u32; 2],
    frames: u32,
    params: toml::Table,
    flags: u32,
) -> (Image, RayCounts) {
    render("callisto-shadows", params, scene, size, frames, 1, flags)
}

/// A scene of a comparison: name, constructor, range cutoff.
type Case = (&'static str, fn() -> Scene, f64);

fn energy(img: &Image) -> f64 {
    common::luminance(img.mean())
}

/// Courtyard without its sky: every light of the scene is in the light pool (sun, point light,
/// lamp triangles), which is all this technique lights with when `gi` is off.
fn courtyard_no_sky() -> Scene {
    builtin::courtyard(15.0, 1.0, 0.0)
}

/// The shipped defaults first: energy within 3% of the reference's direct light (issue 55).
/// Then, with every rate forced to full, infinite ranges and no temporal filtering, each frame is an
/// unbiased estimate of direct light (exact for punctual lights, one area sample per emissive
/// triangle): 64 frames must match the reference's direct light. Courtyard leaves out the
/// emission the camera sees (in both), so its truth is the one `variable_rate_traces_fewer_rays`
/// uses; Cornell's is the one ReSTIR DI's test uses.
#[test]
fn full_rate_equals_reference_direct_light() {
    let size = [64, 64];
    // Without the shadow cache, whose cells average visibility (its own test is below).
    let params: toml::Table = toml::toml! { rate = "full"
    range_cutoff = 0.0
    denoise = false
    static_shadow_cache = false };
    for (name, scene, flags) in [
        ("cornell", builtin::cornell as fn() -> Scene, 0),
        (
            "courtyard (sky 0)",
            courtyard_no_sky,
            FLAG_NO_PRIMARY_EMISSION,
        ),
    ] {
        let truth = direct_reference(scene(), size, 1024, 7, flags);
        // The shipped defaults first (variable rate, range cutoff, tail rays, denoised shadow
        // mask, static shadow cache): energy within 3% of the reference's direct light.
        let (img, _) = callisto(scene(), size, 64, toml::Table::new(), flags);
        let ratio = energy(&img) / energy(&truth);
        eprintln!(
            "{name}: defaults, 64 frames: energy ratio {ratio:.4}, relMSE {:.2e}",
            metrics::compare(&img, &truth).unwrap().rel_mse
        );
        common::targets::check(
            if name == "cornell" {
                "callisto-default-direct-energy-cornell"
            } else {
                "callisto-default-direct-energy-courtyard"
            },
            common::targets::Better::Lower,
            0.03,
            (ratio - 1.0).abs(),
            "|energy / reference direct light - 1|, callisto-shadows' defaults",
        );
        // 64 frames (256 before 2026-11-26, then 128, for CI time; measured at 256: relMSE
        // 2.5e-4 on Cornell, 2.9e-2 on courtyard, mostly the reference's own noise; at 128:
        // 8.8e-4 and 3.0e-2).
        let (img, rays) = callisto(scene(), size, 64, params.clone(), flags);
        let ratio = energy(&img) / energy(&truth);
        let m = metrics::compare(&img, &truth).unwrap();
        let shadow = rays.by_kind[1] as f64 / (size[0] * size[1] * 64) as f64;
        eprintln!(
            "{name}: full rate, 64 frames: energy ratio {ratio:.4}, relMSE {:.2e}, {shadow:.2} shadow rays/px/frame",
            m.rel_mse
        );
        assert!((ratio - 1.0).abs() < 0.02, "{name}: energy ratio {ratio}");
        // Courtyard's per-pixel error is mostly the reference's own noise: its NEE picks lights
        // by power, so the sun takes nearly every sample and the porch lamps get few.
        let bound = if name == "cornell" { 0.01 } else { 0.05 };
        assert!(m.rel_mse < bound, "{name}: relMSE {}", m.rel_mse);
    }
}

/// Variable rate against full rate with the same settings: fewer shadow rays (counted by the
/// shared counters), and the error the reconstruction adds, against the reference's direct
/// light and against the converged full-rate image.
#[test]
fn variable_rate_traces_fewer_rays() {
    let size = [64, 64];
    let flags = FLAG_NO_PRIMARY_EMISSION;
    let frames = 16;
    let cases: [Case; 2] = [
        ("many-lights (1024)", || builtin::many_lights(1024, 7), 0.01),
        ("courtyard (sky 0)", courtyard_no_sky, 0.01),
    ];
    for (name, scene, cutoff) in cases {
        let truth = direct_reference(scene(), size, 1024, 7, flags);
        // No tail samples: their noise would hide the reconstruction's error (the tail has its
        // own test); full and variable rate then see the same lights.
        let mut full_params: toml::Table = toml::toml! { rate = "full"
        tail_samples = 0 };
        full_params.insert("range_cutoff".into(), cutoff.into());
        let mut var_params = full_params.clone();
        var_params.insert("rate".into(), "variable".into());
        // The converged full-rate image at this cutoff: what reconstruction should reproduce
        // (32 frames; 128 before 2026-11-26, then 64, for CI time: its own noise
        // is half the 16-frame images' and adds to both errors alike; measured ratio 1.05 at 64
        // frames against the 1.5 bound).
        let mut conv = full_params.clone();
        conv.insert("denoise".into(), false.into());
        let (full_truth, _) = callisto(scene(), size, 32, conv, flags);
        let (full, full_rays) = callisto(scene(), size, frames, full_params, flags);
        let (var, var_rays) = callisto(scene(), size, frames, var_params, flags);
        let per = |r: &RayCounts| r.by_kind[1] as f64 / (size[0] * size[1] * frames) as f64;
        let (f_rays, v_rays) = (per(&full_rays), per(&var_rays));
        let e = |img: &Image, t: &Image| metrics::compare(img, t).unwrap().rel_mse;
        eprintln!(
            "{name}, {frames} frames, cutoff {cutoff}: shadow rays/px/frame full {f_rays:.2}, variable {v_rays:.2} ({:.0}% saved); \
             relMSE vs reference direct: full {:.3e}, variable {:.3e}; vs converged full rate: full {:.3e}, variable {:.3e}; \
             energy vs reference: full {:.3}, variable {:.3}, converged full {:.3}",
            100.0 * (1.0 - v_rays / f_rays),
            e(&full, &truth),
            e(&var, &truth),
            e(&full, &full_truth),
            e(&var, &full_truth),
            energy(&full) / energy(&truth),
            energy(&var) / energy(&truth),
            energy(&full_truth) / energy(&truth),
        );
        assert!(
            v_rays < 0.7 * f_rays,
            "{name}: variable rate traced {v_rays:.2} rays/px/frame, full {f_rays:.2}"
        );
        // The reconstruction's error must stay close to the error full rate has after the same
        // frames (area-light sampling noise dominates both on courtyard).
        assert!(
            e(&var, &full_truth) < 1.5 * e(&full, &full_truth) + 1e-3,
            "{name}: variable rate relMSE {} against converged full rate (full rate: {})",
            e(&var, &full_truth),
            e(&full, &full_truth)
        );
        assert!(
            (energy(&var) / energy(&full_truth) - 1.0).abs() < 0.03,
            "{name}: variable rate energy {} of full rate's",
            energy(&var) / energy(&full_truth)
        );
    }
}

/// The debug views hold what they say: per-quad rates of every kind under variable rate, the
/// per-pixel ray counts summing to the counted shadow rays, tile light counts below the pool
/// (range culling) and fewer with cone culling on. Writes the views as PNGs under
/// target/callisto-debug/ for inspection.
#[test]
fn debug_views_and_culling() {
    let size = [128, 128];
    let mut stats = Vec::new();
    for cone in [true, false] {
        let mut params: toml::Table = toml::toml! { rate = "variable" };
        params.insert("cone_culling".into(), cone.into());
        let mut e = engine(
            "callisto-shadows",
            params,
            builtin::many_lights(256, 7),
            size,
            1,
        );
        e.reset();
        for _ in 0..3 {
            e.render_frame().unwrap();
        }
        let before = e.ray_counts().unwrap().by_kind[1];
        e.render_frame().unwrap();
        let frame_rays = e.ray_counts().unwrap().by_kind[1] - before;
        let debug = e.read_debug().unwrap().unwrap();
        let px = (size[0] * size[1]) as usize;
        let rate = debug_channel(&debug, px, 0);
        let rays = debug_channel(&debug, px, 1);
        let lights = debug_channel(&debug, px, 2);
        let ray_sum: f64 = rays.iter().map(|&r| r as f64).sum();
        let mean_lights = lights.iter().map(|&l| l as f64).sum::<f64>() / px as f64;
        let share = |k: f32| rate.iter().filter(|&&r| r == k).count() as f64 / px as f64;
        eprintln!(
            "cone culling {cone}: {frame_rays} shadow rays counted, {ray_sum} in the debug view; mean lights per tile {mean_lights:.1} of 512; \
             pixels by highest quad rate: quarter {:.3}, half {:.3}, full {:.3}",
            share(1.0),
            share(2.0),
            share(3.0)
        );
        assert_eq!(ray_sum as u64, frame_rays, "debug ray counts");
        assert!(mean_lights > 0.0 && mean_lights < 512.0);
        if cone {
            assert!(share(1.0) > 0.0 && share(2.0) > 0.0 && share(3.0) > 0.0);
            let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("callisto-debug");
            std::fs::create_dir_all(&dir).unwrap();
            for (i, v) in [&rate, &rays, &lights].iter().enumerate() {
                let (lo, hi) = (0.0, v.iter().cloned().fold(1.0f32, f32::max).log10());
                io::write_png_rgba(
                    &dir.join(format!("channel{i}.png")),
                    size[0],
                    size[1],
                    heatmap::to_rgba(v, lo, hi),
                )
                .unwrap();
            }
        }
        stats.push(mean_lights);
    }
    assert!(
        stats[0] < stats[1],
        "cone culling kept {} lights per tile, without {}",
        stats[0],
        stats[1]
    );
}

/// Without the tail samples the light beyond the derived ranges is lost, as with the seed's
/// ranged lights: reported on many-lights, where it is most of the light.
#[test]
fn range_cutoff_without_tail_loses_light() {
    let size = [64, 64];
    let flags = FLAG_NO_PRIMARY_EMISSION;
    let scene = || builtin::many_lights(1024, 7);
    let truth = direct_reference(scene(), size, 1024, 7, flags);
    let mut lost = Vec::new();
    // 16 and 4 frames (64 each before 2026-11-26, for CI time: a full-rate frame here traces
    // 77 shadow rays per pixel, 0.74 s on lavapipe). Measured at 64 frames: 0.990 with the
    // tail, 0.331 without; the loss is systematic, so a few frames show it.
    for (tail, frames) in [(1i64, 16), (0, 4)] {
        let mut params: toml::Table = toml::toml! { rate = "full"
        range_cutoff = 0.01
        denoise = false };
        params.insert("tail_samples".into(), tail.into());
        let (img, _) = callisto(scene(), size, frames, params, flags);
        let ratio = energy(&img) / energy(&truth);
        eprintln!(
            "many-lights, cutoff 0.01, tail_samples {tail}, {frames} frames: energy ratio {ratio:.3}"
        );
        lost.push(ratio);
    }
    assert!((lost[0] - 1.0).abs() < 0.03, "with the tail: {}", lost[0]);
    assert!(lost[1] < 0.9, "without the tail: {}", lost[1]);
}

/// `gi = true`: ReSTIR GI's sample adds the indirect light; 128 frames on Cornell match the
/// full reference (256 before 2026-11-26: energy 0.9947, relMSE 4.7e-3 against 3% and 2e-2).
#[test]
fn gi_adds_indirect_light() {
    let size = [64, 64];
    let truth = common::cornell_truth_64();
    let params: toml::Table = toml::toml! { gi = true };
    let (img, rays) = callisto(builtin::cornell(), size, 128, params, 0);
    let ratio = energy(&img) / energy(&truth);
    let m = metrics::compare(&img, &truth).unwrap();
    let (direct, _) = callisto(builtin::cornell(), size, 16, toml::Table::new(), 0);
    eprintln!(
        "callisto + ReSTIR GI, 128 frames at 64²: energy ratio {ratio:.4}, relMSE {:.2e}, {:.2} rays/px/frame; direct only: energy ratio {:.3}",
        m.rel_mse,
        rays.total() as f64 / (64.0 * 64.0 * 128.0),
        energy(&direct) / energy(&truth)
    );
    assert!((ratio - 1.0).abs() < 0.03, "energy ratio {ratio}");
    assert!(m.rel_mse < 0.02, "relMSE {}", m.rel_mse);
    assert!(energy(&direct) / energy(&truth) < 0.9);
}

/// The shadow mask's temporal accumulation: one real-time frame (no progressive average) after
/// 16 frames has a lower error with it than without (against the converged image); after a camera move, pixels the old view
/// did not see restart their history (frames since disocclusion 1) while the rest keep theirs.
#[test]
fn shadow_mask_accumulation_and_disocclusion() {
    let size = [64, 64];
    let flags = FLAG_NO_PRIMARY_EMISSION;
    // Variable rate with accumulation over frames: the converged image the frames estimate
    // (64 frames: its own noise is under 2% of one frame's, against a 25% margin).
    let (truth, _) = callisto(
        courtyard_no_sky(),
        size,
        64,
        toml::toml! { denoise = false },
        flags,
    );
    let mut errors = Vec::new();
    for denoise in [true, false] {
        let mut params: toml::Table = toml::toml! { accumulate = false };
        params.insert("denoise".into(), denoise.into());
        let (img, _) = callisto(courtyard_no_sky(), size, 16, params, flags);
        errors.push(metrics::compare(&img, &truth).unwrap().rel_mse);
    }
    eprintln!(
        "courtyard, one frame after 16: relMSE {:.3e} with the shadow-mask accumulation, {:.3e} without",
        errors[0], errors[1]
    );
    // Only the punctual lights' (sun, point light) visibility is filtered; the lamps' sampling
    // noise is the same in both.
    assert!(errors[0] < 0.75 * errors[1], "{errors:?}");

    let mut e = engine(
        "callisto-shadows",
        toml::toml! { accumulate = false },
        courtyard_no_sky(),
        size,
        1,
    );
    e.reset();
    for _ in 0..8 {
        e.render_frame().unwrap();
    }
    let mut cam = e.camera;
    cam.position += glam::Vec3::new(1.5, 0.0, 0.0);
    cam.target += glam::Vec3::new(1.5, 0.0, 0.0);
    e.move_camera(cam);
    e.render_frame().unwrap();
    let px = (size[0] * size[1]) as usize;
    let frames = debug_channel(&e.read_debug().unwrap().unwrap(), px, 3);
    let surfaces = frames.iter().filter(|&&t| t > 0.0).count() as f64;
    let fresh = frames.iter().filter(|&&t| t == 1.0).count() as f64 / surfaces;
    let kept = frames.iter().filter(|&&t| t >= 9.0).count() as f64 / surfaces;
    eprintln!(
        "after a 1.5 m camera move: {:.1}% of surface pixels restart their shadow mask, {:.1}% keep 9+ frames",
        100.0 * fresh,
        100.0 * kept
    );
    assert!(fresh > 0.005 && fresh < 0.5, "fresh {fresh}");
    assert!(kept > 0.5, "kept {kept}");
}

/// The ray-budget mapping scales the lights' range: fewer rays than measured raise the cutoff.
#[test]
fn ray_budget_maps_to_range_cutoff() {
    let t = gilab::techniques::create_technique("callisto-shadows").unwrap();
    let lower = t.params_for_ray_budget(10.0, Some(40.0)).unwrap();
    let float = |c: &gilab::render::params::ParamChanges| match c.get("range_cutoff") {
        Some(gilab::render::params::ParamValue::Float(x)) => x,
        other => panic!("range_cutoff: {other:?}"),
    };
    let cutoff = float(&lower);
    assert!(cutoff > 0.01 * 3.0, "cutoff {cutoff}");
    let higher = t.params_for_ray_budget(80.0, Some(40.0)).unwrap();
    assert!(float(&higher) < 0.01);
    assert!(t.params_for_ray_budget(40.0, Some(40.0)).is_none());
    assert!(t.params_for_ray_budget(40.0, None).is_none());
}

/// The largest relative difference of mean luminance over 4x4 blocks of `img` against `truth`
/// (blocks whose truth is darker than a tenth of the image mean are left out): a shadow lost or
/// left behind by the static/dynamic split shows here, where relMSE over the image dilutes it.
fn worst_block(img: &Image, truth: &Image) -> f64 {
    let lum = |im: &Image, x: u32, y: u32| common::luminance(im.pixel(x, y).map(|v| v as f64));
    let floor = 0.1 * energy(truth);
    let mut worst: f64 = 0.0;
    for by in 0..truth.height / 4 {
        for bx in 0..truth.width / 4 {
            let (mut a, mut b) = (0.0, 0.0);
            for y in 4 * by..4 * by + 4 {
                for x in 4 * bx..4 * bx + 4 {
                    a += lum(img, x, y) / 16.0;
                    b += lum(truth, x, y) / 16.0;
                }
            }
            if b > floor {
                worst = worst.max((a - b).abs() / b);
            }
        }
    }
    worst
}

/// `static_shadow_cache` on a still scene (Cornell, full rate, no temporal filter): the cached
/// static visibility converges to the image tracing everything (against the reference's direct
/// light) with fewer shadow rays.
#[test]
fn static_shadow_cache_on_a_still_scene() {
    let size = [64, 64];
    let frames = 64;
    let truth = direct_reference(builtin::cornell(), size, 1024, 7, 0);
    let run = |cache: bool| {
        let mut p: toml::Table = toml::toml! { rate = "full"
        range_cutoff = 0.0
        denoise = false };
        p.insert("static_shadow_cache".into(), cache.into());
        callisto(builtin::cornell(), size, frames, p, 0)
    };
    let (on, on_rays) = run(true);
    let (off, off_rays) = run(false);
    let per = |r: &RayCounts| r.by_kind[1] as f64 / (size[0] * size[1] * frames) as f64;
    let e = |img: &Image| metrics::compare(img, &truth).unwrap().rel_mse;
    eprintln!(
        "cornell, {frames} frames at full rate: shadow rays/px/frame cache on {:.3}, off {:.3}; relMSE vs reference direct: on {:.2e}, off {:.2e}; worst 4x4 block on {:.3}, off {:.3}; energy ratio on/off {:.4}",
        per(&on_rays),
        per(&off_rays),
        e(&on),
        e(&off),
        worst_block(&on, &truth),
        worst_block(&off, &truth),
        energy(&on) / energy(&off)
    );
    assert_eq!(on.non_finite_count(), 0);
    assert_eq!(on_rays.invalid_samples, 0);
    assert!(per(&on_rays) < 0.5 * per(&off_rays), "the cache saves rays");
    assert!(e(&on) < 0.01, "relMSE {}", e(&on));
    assert!((energy(&on) / energy(&off) - 1.0).abs() < 0.02);
}

/// `static_shadow_cache` at the defaults on `many-lights` (1,024 lights: many (light, cell) keys
/// meet in the hash grid) gives the same image and ray counts twice for a fixed seed. Until
/// 2026-11-29 it did not: which key claimed a slot, and which rays filled a cell, depended on
/// the order the shadow rays ran in (found by tools/bit-identical.sh); now every read sees only
/// what the settle pass fixed at the end of the frames before.
#[test]
fn static_shadow_cache_is_deterministic() {
    let size = [48, 48];
    let run = || {
        let mut e = engine(
            "callisto-shadows",
            toml::Table::new(),
            builtin::build("many-lights", &toml::Table::new()).unwrap(),
            size,
            1,
        );
        for _ in 0..6 {
            e.render_frame().unwrap();
        }
        (e.read_output().unwrap(), e.ray_counts().unwrap().by_kind[1])
    };
    let (a, a_rays) = run();
    let (b, b_rays) = run();
    assert_eq!(a.non_finite_count(), 0);
    assert_eq!(a_rays, b_rays, "shadow rays differ");
    assert!(a.rgb == b.rgb, "two runs with seed 1 differ");
}

/// `static_shadow_cache` under motion: `moving` (door, ball and lamp move; sun and ceiling light
/// stay: static lights over moving casters) and Cornell with only its ceiling light animated
/// (the boxes are static casters whose shadows move with the light: a light that moves must not
/// keep its cached visibility), played at `time_scale = 12` to 1 s (5 re-posings) and held
/// there: the image with the cache matches the one tracing everything (Cornell's exactly). Full
/// rate, no temporal filter, 32x32.
#[test]
fn static_shadow_cache_follows_moving_casters_and_lights() {
    let size = [32, 32];
    let frames = 24;
    let moving = || {
        let mut s = builtin::build("moving", &toml::Table::new()).unwrap();
        let m = std::sync::Arc::make_mut(s.motion.as_mut().unwrap());
        m.time_scale = 12.0;
        m.play_until = Some(1.0);
        s
    };
    let light_moves = || {
        let path = std::env::temp_dir().join("gilab-callisto-light-moves.toml");
        std::fs::write(
            &path,
            "[scene]\nsource = \"cornell\"\ntime_scale = 12.0\nplay_until = 1.0\n\
             [[scene.animate]]\nobject = \"light\"\ntimes = [0.0, 1.0]\n\
             translation = [[0, 0, 0], [0.6, -0.5, 0.3]]\n",
        )
        .unwrap();
        gilab::preset::LoadedPreset::load(&path)
            .unwrap()
            .load_scene()
            .unwrap()
    };
    for (name, scene) in [
        ("moving", &moving as &dyn Fn() -> Scene),
        ("cornell, light moves", &light_moves),
    ] {
        let run = |cache: bool| {
            let mut p: toml::Table = toml::toml! { rate = "full"
            denoise = false };
            p.insert("static_shadow_cache".into(), cache.into());
            let mut e = common::engine("callisto-shadows", p, scene(), size, 3);
            for _ in 0..frames {
                e.render_frame().unwrap();
            }
            assert!((e.scene_time - 1.0).abs() < 1e-4, "{}", e.scene_time);
            let rays = e.ray_counts().unwrap();
            (e.read_output().unwrap(), rays)
        };
        let (on, on_rays) = run(true);
        let (off, off_rays) = run(false);
        let m = metrics::compare(&on, &off).unwrap();
        let per = |r: &RayCounts| r.by_kind[1] as f64 / (size[0] * size[1] * frames) as f64;
        eprintln!(
            "{name}, {frames} frames (held at 1 s after 5 re-posings): shadow rays/px/frame on {:.3}, off {:.3}; relMSE on vs off {:.2e}; worst 4x4 block {:.3}; energy ratio {:.4}",
            per(&on_rays),
            per(&off_rays),
            m.rel_mse,
            worst_block(&on, &off),
            energy(&on) / energy(&off)
        );
        assert_eq!(on.non_finite_count(), 0, "{name}");
        assert_eq!(on_rays.invalid_samples, 0, "{name}");
        assert!(m.rel_mse < 0.02, "{name}: relMSE {}", m.rel_mse);
        assert!(worst_block(&on, &off) < 0.3, "{name}: a block differs");
        assert!((energy(&on) / energy(&off) - 1.0).abs() < 0.03, "{name}");
        if name != "moving" {
            // Its one light moved, so every ray traces the whole scene as without the cache, with
            // the same samples: a light kept in the cache after moving would differ (measured
            // with the moved light's cache left on: worst block 0.283, relMSE 3.9e-4).
            assert!(
                on.rgb == off.rgb,
                "{name}: the moved light's shadows differ"
            );
        }
    }
}

/// A scene edit (Cornell's back-wall lamp switched on, which also changes the light pool)
/// empties the shadow cache: the first frame after it equals the frame tracing everything bit
/// for bit, every cell refilling from the pixels' own rays. Before the edit the full cells'
/// averages make the two frames differ, so a cache kept across the edit would show.
#[test]
fn scene_edit_empties_the_shadow_cache() {
    let size = [32, 32];
    let run = |cache: bool| {
        let mut p: toml::Table = toml::toml! { rate = "full"
        denoise = false
        accumulate = false };
        p.insert("static_shadow_cache".into(), cache.into());
        let mut e = common::engine(
            "callisto-shadows",
            p,
            builtin::cornell_with_lamp(Some(0.0)),
            size,
            3,
        );
        for _ in 0..24 {
            e.render_frame().unwrap();
        }
        let before = e.read_output().unwrap();
        let on = builtin::cornell_with_lamp(Some(40.0));
        let gpu_scene = std::sync::Arc::new(gilab::scene::gpu_scene::GpuScene::upload(&e.gpu, &on));
        e.change_scene(std::sync::Arc::new(on), gpu_scene).unwrap();
        e.render_frame().unwrap();
        (before, e.read_output().unwrap())
    };
    let (on_before, on_after) = run(true);
    let (off_before, off_after) = run(false);
    let m = metrics::compare(&on_before, &off_before).unwrap();
    eprintln!(
        "cornell, lamp switched on after 24 frames: before, cache on vs off relMSE {:.2e}; first frame after: {}",
        m.rel_mse,
        if on_after.rgb == off_after.rgb { "equal" } else { "different" }
    );
    assert_eq!(on_after.non_finite_count(), 0);
    assert!(on_before.rgb != off_before.rgb, "the cells were full");
    assert!(
        on_after.rgb == off_after.rgb,
        "a stale cache after the edit"
    );
}

/// Issue 58: the scene Callisto's shadows were built for (`interior`: a dark hall lit by 24
/// point lights, four carried lanterns and a sliding crate, playing). Seed 002 reports −85% of
/// the tracing cost against full-rate shadows; here the shipped defaults (variable rate, static
/// shadow cache) against full rate without the cache, at 64² after 16 frames, over the next 16:
/// at most 15% of the shadow rays (measured 2026-11-29: 12.6% with `gilab bench --preset`, 3.68
/// against 29.26 rays per pixel and frame), and the same light (the frames accumulated over the
/// same poses: energy within 3%).
#[test]
fn interior_defaults_trace_a_seventh_of_the_full_rate_shadow_rays() {
    let size = [64, 64];
    let (warmup, frames) = (16u32, 16u32);
    let scene = || {
        let mut s = builtin::build("interior", &toml::Table::new()).unwrap();
        let m = std::sync::Arc::make_mut(s.motion.as_mut().unwrap());
        m.time_scale = 1.0;
        s
    };
    let run = |p: toml::Table| {
        let mut e = common::engine("callisto-shadows", p, scene(), size, 5);
        for _ in 0..warmup {
            e.render_frame().unwrap();
        }
        let before = e.ray_counts().unwrap().kind("shadow");
        for _ in 0..frames {
            e.render_frame().unwrap();
        }
        let rays = e.ray_counts().unwrap();
        assert_eq!(rays.invalid_samples, 0);
        let shadow = (rays.kind("shadow") - before) as f64 / (size[0] * size[1] * frames) as f64;
        (e.read_output().unwrap(), shadow)
    };
    let (defaults, rays) = run(toml::Table::new());
    let (full, full_rays) = run(toml::toml! { rate = "full"
    static_shadow_cache = false });
    let share = rays / full_rays;
    let ratio = energy(&defaults) / energy(&full);
    eprintln!(
        "interior 64², frames {warmup}-{}: shadow rays/px/frame defaults {rays:.3}, full rate without the cache {full_rays:.3} ({:.1}%); energy ratio {ratio:.4}",
        warmup + frames,
        share * 100.0
    );
    assert_eq!(defaults.non_finite_count(), 0);
    assert!(
        full_rays > 10.0,
        "the hall's lights reach the pixels: {full_rays}"
    );
    assert!(
        share < 0.15,
        "defaults trace {:.1}% of the full-rate rays",
        share * 100.0
    );
    assert!((ratio - 1.0).abs() < 0.03, "energy ratio {ratio}");
}

/// Issue 58's "stability first". On `many-lights` with 16 lights at 64² (seed 1, the shipped
/// defaults: variable rate, the static shadow cache, the mask's temporal accumulation) the
/// accumulated direct light read 0.938, 1.051 and 0.993 of a converged reference after 64, 128
/// and 256 frames, as if the variable rate's feedback oscillated. It does not: the reference's
/// own direct light at the same seed moves the same way (frames 65-128 at 1.29 of its converged
/// image, 2026-11-30), with `rate = "full"`, without the cache and without the mask's
/// accumulation alike ([callisto.md](../docs/callisto.md)). Every technique reads its camera
/// jitter from the shared primary surfaces, the reference's sequence at the same seed, and the
/// 16 small bright emitters seen directly cover a pixel only where a jittered ray hits them. So
/// each 128-frame window is compared with the same window of the reference at the same seed
/// (the bound: within 2%); the reference's windows against its own 384-frame mean are
/// printed, the size of the jitter's noise; and the defaults' shadow rays per window.
#[test]
fn direct_light_is_stable_in_every_128_frame_window() {
    let size = [64, 64];
    let (window, windows) = (128u32, 3u32);
    let mut scene_params = toml::Table::new();
    scene_params.insert("lights".into(), 16.into());
    let scene = builtin::build("many-lights", &scene_params).unwrap();
    // Each window's mean image energy, from the accumulated image at the windows' ends, and the
    // shadow rays traced in it.
    let run = |technique: &str, params: toml::Table| {
        let mut e = common::engine(technique, params, scene.clone(), size, 1);
        let (mut means, mut rays) = (Vec::new(), Vec::new());
        let (mut before, mut shadow_before) = (0.0, 0u64);
        for k in 1..=windows {
            for _ in 0..window {
                e.render_frame().unwrap();
            }
            let total = energy(&e.read_output().unwrap()) * (k * window) as f64;
            means.push((total - before) / window as f64);
            before = total;
            let counts = e.ray_counts().unwrap();
            assert_eq!(counts.invalid_samples, 0, "{technique}: NaN/Inf samples");
            let shadow = counts.kind("shadow");
            rays.push((shadow - shadow_before) as f64 / (size[0] * size[1] * window) as f64);
            shadow_before = shadow;
        }
        (means, rays)
    };
    let (callisto, rays) = run("callisto-shadows", toml::Table::new());
    let (reference, _) = run(
        "reference",
        toml::toml! { max_depth = 1
        samples_per_frame = 1 },
    );
    let converged = reference.iter().sum::<f64>() / windows as f64;
    for k in 0..windows as usize {
        let (first, last) = (k as u32 * window + 1, (k as u32 + 1) * window);
        let ratio = callisto[k] / reference[k];
        eprintln!(
            "many-lights (16) 64², frames {first}-{last}: defaults / reference at the same seed {ratio:.4}; \
             the reference's window / its 384-frame mean {:.4}; defaults' shadow rays/px/frame {:.3}",
            reference[k] / converged,
            rays[k]
        );
        assert!(
            (ratio - 1.0).abs() < 0.02,
            "frames {first}-{last}: the defaults' direct light is {ratio:.4} of the reference's at the same seed"
        );
    }
}
