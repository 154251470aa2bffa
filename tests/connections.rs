//! Parts connected across families (issue 34, shared/seeds/003 "Making Connections"): ReSTIR GI
//! sample paths that end in Lumen's surface cache (`gi_terminate = "lumen-cards"`), in Lumen's
//! world radiance cache (`"lumen-world"`), in the surfels (`"surfels"`) or in the hash radiance
//! cache (`"hash-cache"`) against paths traced
//! to the end, the reference and the furnace's closed form; stability, determinism and the
//! refusal of unknown terminations; and the
//! caches lit by the world ReGIR clipmap (`cache_direct = "regir"`) against power sampling.

mod common;

use common::engine;
use gilab::compare::{metrics, Image};
use gilab::render::engine::Engine;
use gilab::scene::{builtin, Scene};

fn energy(img: &Image) -> f64 {
    common::luminance(img.mean())
}

fn params(terminate: &str, bounces: i64) -> toml::Table {
    params_atlas(terminate, bounces, 256)
}

fn params_atlas(terminate: &str, bounces: i64, atlas: i64) -> toml::Table {
    let mut t = toml::Table::new();
    t.insert("gi_terminate".into(), terminate.into());
    t.insert("gi_bounces".into(), bounces.into());
    // A small atlas: the Cornell box's cards fit, and lavapipe lights it in a few frames.
    t.insert("cache_atlas_size".into(), atlas.into());
    // Every texel relit every frame: the cache's feedback gathers a bounce per frame.
    t.insert("cache_update".into(), 1.0.into());
    // Surfel rays as the surfels' default budget spends them on a 128² image (4 per pixel),
    // for these 64² ones: each ray also traces a shadow ray, and a path where no surfel
    // covers its hit.
    t.insert("cache_ray_budget".into(), 16384.into());
    t
}

/// `warmup` frames (the cache captures its cards and lights them, bounce after bounce), then
/// an accumulated run of `frames`; returns the image and rays per pixel per frame of that run.
fn run(
    params: toml::Table,
    scene: Scene,
    size: [u32; 2],
    warmup: u32,
    frames: u32,
    seed: u32,
) -> (Image, f64, Engine) {
    run_technique("restir", params, scene, size, warmup, frames, seed)
}

fn run_technique(
    technique: &str,
    params: toml::Table,
    scene: Scene,
    size: [u32; 2],
    warmup: u32,
    frames: u32,
    seed: u32,
) -> (Image, f64, Engine) {
    let (img, rays, e) =
        common::render_after_warmup(technique, params, scene, size, warmup, frames, seed);
    let rpp = rays.total() as f64 / (size[0] as f64 * size[1] as f64 * frames as f64);
    (img, rpp, e)
}

/// The seed's claim on the Cornell box: a one-bounce path that ends in a cache keeps the
/// multi-bounce light (energy within 5% of the reference), while the same path traced one
/// bounce and stopped loses it; for Lumen's cards and for the surfels. Rays per pixel printed
/// for each (a cache's own rays depend on its size against the image: here every texel of a
/// 256² atlas is relit every frame, and the surfels trace 16,384 rays a frame, for a 64² image,
/// so a cache costs more rays per pixel than it would at a real resolution).
#[test]
#[ignore = "slow tier, not run by CI (docs/testing.md#slow-tier): ReSTIR GI ending in each cache (not a default), 179 s in CI"]
fn cache_terminations_keep_multi_bounce_light() {
    let size = [64, 64];
    let truth = common::cornell_truth_64();
    let e_truth = energy(&truth);
    let frames = 24;
    let (path1, rays_path1, _) = run(params("path", 1), builtin::cornell(), size, 0, frames, 1);
    let r_path1 = energy(&path1) / e_truth;
    eprintln!(
        "cornell 64², {frames} frames: path (gi_bounces 1) energy {r_path1:.4} of the reference at {rays_path1:.2} rays/px/frame"
    );
    for (terminate, cache_kind) in [
        ("lumen-cards", "cache"),
        ("lumen-world", "cache"),
        ("surfels", "surfel"),
        ("hash-cache", "cache"),
    ] {
        let (img, rpp, e) = run(
            params(terminate, 1),
            builtin::cornell(),
            size,
            16,
            frames,
            1,
        );
        let ratio = energy(&img) / e_truth;
        let m = metrics::compare(&img, &truth).unwrap();
        let cache_rays = e.ray_counts().unwrap().kind(cache_kind);
        eprintln!(
            "  {terminate}: energy {ratio:.4} at {rpp:.2} rays/px/frame ({:.2} of them the cache's own {cache_kind} rays), relMSE {:.2e}",
            cache_rays as f64 / (64.0 * 64.0 * frames as f64),
            m.rel_mse
        );
        assert!(
            (ratio - 1.0).abs() < 0.05,
            "{terminate}: energy ratio {ratio}"
        );
        assert!(
            r_path1 < ratio - 0.04,
            "one traced bounce ({r_path1}) should lose the multi-bounce share that {terminate} keeps ({ratio})"
        );
        assert!(cache_rays > 0, "{terminate}: the cache traced no rays");
        assert_eq!(img.non_finite_count(), 0);
        if terminate == "hash-cache" {
            // Where the cache misses, paths are traced on: the energy alone would not show a
            // cache that never ends a path.
            let lookups = e.ray_counts().unwrap().cache_lookups;
            let covered = lookups.covered_seen().unwrap_or(0.0);
            eprintln!("  hash-cache: {}", lookups.summary());
            assert!(covered >= 0.9, "hash-cache: covered lookups {covered}");
        }
    }
}

/// Callisto's `gi = true` takes the same terminations: its ReSTIR GI paths end in the surface
/// cache (restir's default 512² atlas, a quarter relit per frame, so a longer warm-up) or in the
/// surfels, and the Cornell box keeps its energy.
#[test]
#[ignore = "slow tier, not run by CI (docs/testing.md#slow-tier): Callisto's GI ending in a cache (not a default), 119 s in CI"]
fn callisto_gi_ends_in_a_cache() {
    let size = [64, 64];
    let truth = common::cornell_truth_64();
    for (terminate, cache_pass, warmup, frames) in [
        ("lumen-cards", "cache indirect", 48, 24),
        ("surfels", "integrate", 8, 12),
    ] {
        let mut p = toml::Table::new();
        p.insert("gi".into(), true.into());
        p.insert("gi_terminate".into(), terminate.into());
        let (img, rpp, e) = run_technique(
            "callisto-shadows",
            p,
            builtin::cornell(),
            size,
            warmup,
            frames,
            1,
        );
        let ratio = energy(&img) / energy(&truth);
        let passes: Vec<&str> = e
            .technique
            .passes(&e.gpu_scene.data.features)
            .into_iter()
            .filter(|p| p.runs)
            .map(|p| p.name)
            .collect();
        eprintln!("callisto gi -> {terminate}, cornell 64²: energy {ratio:.4}, {rpp:.2} rays/px/frame, passes {passes:?}");
        assert!(passes.contains(&cache_pass), "{terminate}: {passes:?}");
        assert!(
            (ratio - 1.0).abs() < 0.05,
            "{terminate}: energy ratio {ratio}"
        );
        assert_eq!(img.non_finite_count(), 0);
    }
}

/// White furnace (albedo 0.8, emission 1: radiance 5 everywhere). Traced paths are unbiased.
/// A path ending in the cache carries the cache's bias: its indirect light is a 4-frame blend
/// fed back frame after frame, so the bounces it holds converge as about 0.95^frames (measured
/// -9.2% after 24 + 16 frames, -7.0% after 24 + 32); after 64 frames of warm-up what is left
/// is the cache's own loss (measured -1.0%; Lumen's furnace test measures -3% for its
/// per-pixel gather), bounded at 4%.
#[test]
fn furnace_with_each_termination() {
    let (albedo, emission) = (0.8f32, 1.0f32);
    let expected = emission as f64 / (1.0 - albedo as f64);
    for (terminate, bounces, warmup, bound) in [
        ("path", 0, 0, 0.03),
        ("lumen-cards", 1, 64, 0.04),
        ("lumen-world", 1, 64, 0.04),
        ("surfels", 1, 64, 0.04),
        ("hash-cache", 1, 64, 0.04),
    ] {
        // A 128² atlas: the furnace is uniform, texel resolution changes nothing here. No
        // ReGIR: the sphere's triangles make it a many-light scene, and the 16³ grid's build
        // (2 M candidates a frame) costs 0.35 s of a 0.42 s frame on lavapipe while what is
        // measured here is where GI paths end (ReSTIR's own furnace test keeps ReGIR).
        let mut p = params_atlas(terminate, bounces, 128);
        p.insert("regir".into(), false.into());
        // 4,096 surfel rays a frame (as the surfels' own furnace test): in the furnace every
        // surfel ray whose hit no surfel covers yet continues as a long path.
        p.insert("cache_ray_budget".into(), 4096.into());
        let (img, rpp, _) = run(
            p,
            builtin::furnace(albedo, emission, 1),
            [32, 32],
            warmup,
            16,
            1,
        );
        let v = common::luminance(img.mean());
        let rel = v / expected - 1.0;
        eprintln!(
            "furnace, gi_terminate = {terminate}, after {warmup} + 16 frames: {v:.4} vs {expected:.4} ({:+.2}%), {rpp:.2} rays/px/frame",
            rel * 100.0
        );
        assert!(rel.abs() < bound, "{terminate}: {v} vs {expected}");
    }
}

/// The ambient cache (`gi_terminate = "ambient"`, the worked example of adding a cache,
/// docs/parts.md) has a closed form in the white furnace (albedo a, emission Le): the pixel's
/// emission, its direct light a Le, and a GI path that ends at its first hit with the lights'
/// NEE there (a Le) plus the ambient term a S (S the sky's mean radiance, which the closed
/// sphere never sees): Le (1 + a + a²) + a² S. With S = 0 it is the path cut after two
/// bounces; with S = 2 the ambient term is added once. Regardless of frames: nothing warms up.
#[test]
fn ambient_cache_ends_the_furnace_at_its_closed_form() {
    let (albedo, emission) = (0.8f64, 1.0f64);
    for sky in [0.0f64, 2.0] {
        let mut scene = builtin::furnace(albedo as f32, emission as f32, 1);
        scene.sky = glam::Vec3::splat(sky as f32);
        let mut p = params("ambient", 1);
        p.insert("regir".into(), false.into());
        let (img, rpp, _) = run(p, scene, [32, 32], 0, 16, 1);
        let v = energy(&img);
        let expected = emission * (1.0 + albedo + albedo * albedo) + albedo * albedo * sky;
        eprintln!(
            "furnace, gi_terminate = ambient, sky {sky}: {v:.4} vs {expected:.4} ({:+.2}%), {rpp:.2} rays/px/frame",
            (v / expected - 1.0) * 100.0
        );
        assert!(
            (v / expected - 1.0).abs() < 0.01,
            "sky {sky}: {v} vs {expected}"
        );
        assert_eq!(img.non_finite_count(), 0);
    }
}

/// Hard cases stay finite with each cache; the same seed gives the same image twice. Hot
/// reload watches the cache's end-of-path module (added to ReSTIR GI's pass as an additional
/// import, which no entry file imports): an edit to it rebuilds the engine, an edit to another
/// cache's does not.
#[test]
fn cache_terminations_are_finite_and_deterministic() {
    let ends = [
        ("lumen-cards", "parts/surface_cache/path_end.wgsl"),
        ("lumen-world", "parts/world_cache/path_end.wgsl"),
        ("surfels", "parts/surfels/path_end.wgsl"),
        ("hash-cache", "parts/hash_cache/path_end.wgsl"),
        ("ambient", "parts/ambient_cache/path_end.wgsl"),
    ];
    let shaders = gilab::gpu::shaders::ShaderLibrary::discover();
    for (terminate, end_file) in ends {
        let run_once = || {
            run(
                params(terminate, 1),
                builtin::hard_cases(1e6),
                [48, 48],
                4,
                4,
                7,
            )
        };
        let (a, _, engine) = run_once();
        assert_eq!(a.non_finite_count(), 0, "{terminate}, hard-cases: NaN/Inf");
        let (b, _, _) = run_once();
        assert_eq!(a.rgb, b.rgb, "{terminate}: same seed, different image");
        for (_, other) in ends {
            let watched = engine.uses_any_shader(&shaders.dependents(other).unwrap());
            assert_eq!(
                watched,
                other == end_file,
                "{terminate}: hot reload of {other} (entries {:?})",
                engine.shader_entries()
            );
        }
    }
}

/// A termination that does not exist is refused with one clear line that lists the ones that
/// do; the technique keeps its previous parameters.
#[test]
fn unknown_terminations_are_refused() {
    let mut t = gilab::techniques::create_technique("restir").unwrap();
    let mut p = toml::Table::new();
    p.insert("gi_terminate".into(), "lumen-voxels".into());
    let err = t.set_params_from_table(&p).unwrap_err().to_string();
    assert!(
        err.contains("lumen-voxels") && err.contains("lumen-world") && !err.contains('\n'),
        "{err}"
    );
    assert_eq!(
        t.params()["gi_terminate"].as_integer(),
        Some(0),
        "not path any more"
    );
}

/// `cache_direct = "regir"` against `"power"` on `many-lights` (1,024 lights, 2,048 emissive
/// triangles): Lumen's card texels take their light from the world ReGIR clipmap
/// (shared/seeds/003, ReGIR lighting the cache). After two warm-up frames (the clipmap's cells
/// are marked, then built) and a history reset, every texel is relit `UPDATES` times with one
/// light sample each; the cache's direct light, seen through the pixels (debug channel 1:
/// albedo x irradiance / pi), is compared with the reference's direct light. Same texel budget
/// and shadow rays in both: the ReGIR cache must have the lower error and the same energy
/// within noise, and the clipmap must serve nearly every lookup.
#[test]
#[ignore = "slow tier, not run by CI (docs/testing.md#slow-tier): cache_direct = regir (not a default), 91 s in CI"]
fn regir_lights_the_cache_with_less_noise() {
    const UPDATES: u32 = 16;
    let size = [64, 64];
    let px = (size[0] * size[1]) as usize;
    let mut truth = engine(
        "reference",
        toml::toml! { samples_per_frame = 16
        max_depth = 1 },
        builtin::many_lights(1024, 7),
        size,
        3,
    );
    truth.flags = gilab::render::FLAG_NO_PRIMARY_EMISSION;
    truth.reset();
    for _ in 0..8 {
        truth.render_frame().unwrap();
    }
    let reference = truth.read_output().unwrap();
    let mut results = Vec::new();
    for mode in ["power", "regir"] {
        let mut t = toml::toml! { tracing = "bvh"
        clipmap_resolution = 64
        atlas_size = 512
        direct_texels_per_frame = 16_777_216
        indirect_texels_per_frame = 0
        final_gather = "pixels"
        debug_views = true };
        t.insert("cache_direct".into(), mode.into());
        let mut e = engine("lumen", t, builtin::many_lights(1024, 7), size, 3);
        let coverage = |e: &Engine| {
            e.inspect(|ctx, t| {
                let any: &dyn std::any::Any = t.as_any();
                any.downcast_ref::<gilab::techniques::lumen::Lumen>()
                    .unwrap()
                    .cache_regir_coverage(ctx.gpu)
                    .unwrap()
            })
        };
        e.render_frame().unwrap();
        e.render_frame().unwrap();
        let before = coverage(&e);
        e.reset();
        for _ in 0..UPDATES {
            e.render_frame().unwrap();
        }
        let debug = e.read_debug().unwrap().unwrap();
        let cache = gilab::render::debug_channel(&debug, px, 1);
        // Relative L2 error (squared error over squared signal, summed over pixels) and the
        // median relative error: a per-pixel relMSE is ruled by a few dark pixels whose texel
        // lies on a lit neighbour (card resolution), the same in both modes.
        let (mut sum_c, mut sum_r, mut err, mut signal) = (0.0, 0.0, 0.0, 0.0);
        let mut rel_errors = Vec::new();
        for (i, c) in cache.iter().enumerate() {
            let p = reference.pixel(i as u32 % size[0], i as u32 / size[0]);
            let r = common::luminance([p[0] as f64, p[1] as f64, p[2] as f64]);
            if r <= 1e-4 || !c.is_finite() {
                continue;
            }
            sum_c += *c as f64;
            sum_r += r;
            err += (*c as f64 - r).powi(2);
            signal += r * r;
            rel_errors.push(((*c as f64 - r) / r).abs());
        }
        let n = rel_errors.len();
        rel_errors.sort_by(f64::total_cmp);
        let median = rel_errors[n / 2];
        let after = coverage(&e);
        let coverage = gilab::parts::world_regir::Coverage {
            lookups: after.lookups - before.lookups,
            served: after.served - before.served,
        };
        let rel = sum_c / sum_r - 1.0;
        let rel_l2 = err / signal;
        eprintln!(
            "many-lights 64², cache direct after {UPDATES} updates, {mode}: mean {:+.2}% against the reference's direct light, relative L2 error {rel_l2:.4}, median relative error {median:.4} over {n} pixels; clipmap served {} of {} lookups",
            rel * 100.0,
            coverage.served,
            coverage.lookups
        );
        results.push((rel, rel_l2, n, coverage, median));
    }
    let (power, regir) = (results[0], results[1]);
    assert!(power.2 as f64 > 0.5 * px as f64 && regir.2 == power.2);
    assert!(
        regir.1 < 0.7 * power.1 && regir.4 < power.4,
        "ReGIR error {} (median {}) not below power's {} ({})",
        regir.1,
        regir.4,
        power.1,
        power.4
    );
    // Both sit above the reference by the cards' own error (a texel lit by a brighter neighbour);
    // measured +7.2% (power) and +10.0% (ReGIR), power's mean still rising with its heavy tail.
    assert!(
        (regir.0 - power.0).abs() < 0.05,
        "energy moved: {} vs {}",
        regir.0,
        power.0
    );
    assert_eq!(power.3.lookups, 0, "power sampling never reads the clipmap");
    assert!(regir.3.served_share() > 0.9, "{:?}", regir.3);
}

/// The surfels' ray hits lit from the world ReGIR clipmap (`cache_direct = "regir"`) on
/// `many-lights`: the same energy as by power within noise, no NaN/Inf, the clipmap serving
/// nearly every hit, and the same image for the same seed.
#[test]
fn surfel_hits_lit_by_regir() {
    let size = [32, 32];
    let render = |mode: &str| {
        let mut t = toml::toml! { ray_budget = 8192 };
        t.insert("cache_direct".into(), mode.into());
        let (img, _, e) = run_technique("surfels", t, builtin::many_lights(1024, 7), size, 2, 8, 5);
        let coverage = e.inspect(|ctx, t| {
            let any: &dyn std::any::Any = t.as_any();
            any.downcast_ref::<gilab::techniques::surfels::Surfels>()
                .unwrap()
                .cache_regir_coverage(ctx.gpu)
                .unwrap()
        });
        (img, coverage)
    };
    let (power, _) = render("power");
    let (regir, coverage) = render("regir");
    let (again, _) = render("regir");
    // The seed's reservoir at the hit (8 power-sampled candidates, one winner): unbiased, so
    // the same energy as power within noise, no clipmap read (issue 57).
    let (reservoir, reservoir_coverage) = render("reservoir");
    let (ep, er) = (energy(&power), energy(&regir));
    let es = energy(&reservoir);
    eprintln!(
        "surfels on many-lights 32², 8 frames: energy {es:.4} (reservoir, {:+.2}% against power)",
        (es / ep - 1.0) * 100.0
    );
    assert_eq!(reservoir.non_finite_count(), 0);
    assert!((es / ep - 1.0).abs() < 0.05, "{es} vs {ep}");
    assert_eq!(
        reservoir_coverage.lookups, 0,
        "the reservoir reads no clipmap"
    );
    eprintln!(
        "surfels on many-lights 32², 8 frames: energy {ep:.4} (power) vs {er:.4} (ReGIR, {:+.2}%); clipmap served {} of {} hit lookups",
        (er / ep - 1.0) * 100.0,
        coverage.served,
        coverage.lookups
    );
    assert_eq!(regir.non_finite_count(), 0);
    assert!((er / ep - 1.0).abs() < 0.05, "{er} vs {ep}");
    // The counts include the first frame, when no cell is built yet (measured 0.80 in all).
    assert!(coverage.served_share() > 0.7, "{coverage:?}");
    assert_eq!(regir.rgb, again.rgb, "same seed, different image");
}

/// ReSTIR GI's paths that end in a cache can have that cache lit by the world ReGIR clipmap
/// (`cache_direct = "regir"`, the part Lumen and the surfels use themselves), for both caches:
/// on many-lights the clipmap serves the cache's light lookups, the image stays finite, and
/// its energy agrees with the power-sampled cache's.
#[test]
fn restir_gi_caches_lit_by_regir() {
    for terminate in ["lumen-cards", "surfels"] {
        let render = |mode: &str| {
            // many-lights' 1,050 objects need a 512² atlas; a quarter of it relit per frame
            // (the share of lookups served does not depend on how many texels are relit).
            let mut t = params_atlas(terminate, 1, 512);
            t.insert("cache_update".into(), 0.25.into());
            t.insert("cache_direct".into(), mode.into());
            let (img, _, e) = run(t, builtin::many_lights(1024, 7), [32, 32], 6, 2, 5);
            let coverage = e.inspect(|ctx, t| {
                let any: &dyn std::any::Any = t.as_any();
                any.downcast_ref::<gilab::techniques::restir::Restir>()
                    .unwrap()
                    .lighting
                    .gi_cache_regir_coverage(ctx.gpu)
                    .unwrap()
                    .expect("the paths end in a cache")
            });
            (img, coverage)
        };
        let (power, unused) = render("power");
        let (regir, coverage) = render("regir");
        let (ep, er) = (energy(&power), energy(&regir));
        eprintln!(
            "restir, gi_terminate = {terminate}, many-lights 32², 6 + 2 frames: energy {ep:.4} (cache lit by power) vs {er:.4} (by ReGIR, {:+.2}%); clipmap served {} of {} lookups",
            (er / ep - 1.0) * 100.0,
            coverage.served,
            coverage.lookups
        );
        assert_eq!(regir.non_finite_count(), 0, "{terminate}");
        assert_eq!(
            unused.lookups, 0,
            "{terminate}: power sampling read the clipmap"
        );
        assert!(coverage.served_share() > 0.5, "{terminate}: {coverage:?}");
        assert!((er / ep - 1.0).abs() < 0.1, "{terminate}: {er} vs {ep}");
    }
}

/// Issue 57: ReSTIR GI's sample paths end in the surfels (`gi_terminate = "surfels"`) wherever
/// the surfels cover the hit. On the Cornell box at 128² (restir's defaults otherwise), after
/// 64 frames: at least 80% of the paths that hit a surface end in the cache (the open front
/// lets about a third of the sample rays escape: they hit nothing and end in no cache). The
/// engine counts its GI paths' lookups (the surfel cache's own rays are not counted).
#[test]
#[ignore = "slow tier, not run by CI (docs/testing.md#slow-tier): ReSTIR GI ending in the surfel cache (not a default), 255 s in CI"]
fn gi_paths_end_in_the_surfels() {
    let size = [128, 128];
    let mut p = toml::Table::new();
    p.insert("gi_terminate".into(), "surfels".into());
    let mut e = engine("restir", p, builtin::cornell(), size, 1);
    for _ in 0..64 {
        e.render_frame().unwrap();
    }
    let a = e.ray_counts().unwrap().cache_lookups;
    for _ in 0..8 {
        e.render_frame().unwrap();
    }
    let w = e.ray_counts().unwrap().cache_lookups.since(&a);
    let paths = 8.0 * (size[0] * size[1]) as f64;
    let ended = w.covered() as f64 / w.total() as f64;
    eprintln!(
        "restir, gi_terminate = surfels, cornell 128², frames 64-72: {:.1}% of the GI paths hit a surface; {:.1}% of those end in the surfels ({:.1}% of all paths); {}",
        100.0 * w.total() as f64 / paths,
        100.0 * ended,
        100.0 * w.covered() as f64 / paths,
        w.summary()
    );
    common::targets::check(
        "restir-gi-paths-end-in-surfels",
        common::targets::Better::Higher,
        0.80,
        ended,
        "share of ReSTIR GI paths hitting a surface that end in the surfels, cornell 128², frames 64-72",
    );
}
