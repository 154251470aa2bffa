//! The hash radiance cache (issue 61): the `hash-cache` technique (a path tracer whose paths end
//! in the cache) against the furnace's closed form and the reference; the cache's eviction,
//! stability and determinism; its leak through a thin wall, measured. ReSTIR GI's paths ending
//! in it (`gi_terminate = "hash-cache"`) are tested with the other caches in
//! `tests/connections.rs`. Docs: docs/hash-cache.md.

mod common;

use common::{engine, luminance};
use gilab::compare::{metrics, Image};
use gilab::parts::hash_cache::HashCacheStats;
use gilab::render::engine::Engine;
use gilab::scene::{builtin, Camera};
use gilab::techniques::hash_cache::HashCacheTechnique;
use glam::Vec3;

fn energy(img: &Image) -> f64 {
    luminance(img.mean())
}

fn frames(e: &mut Engine, n: u32) {
    for _ in 0..n {
        e.render_frame().unwrap();
    }
}

fn stats(e: &Engine) -> HashCacheStats {
    e.technique
        .as_any()
        .downcast_ref::<HashCacheTechnique>()
        .unwrap()
        .cache
        .stats(&e.gpu)
        .unwrap()
}

/// White furnace (albedo 0.8, emission 1: radiance 5 everywhere) at the defaults: every cell
/// holds the same light, so the cache adds no spatial bias, and what is left is its own loss
/// (fixed-point rounding, the update paths' albedo division) and the noise of its samples. That
/// noise is shared by every pixel that reads a cell, so the image's mean carries it whole: one
/// update path per 25 pixels is few on a small image (at 32² after 32 frames, seeds 1-4 read
/// 5.168, 4.987, 4.927, 5.003; at 128² after 16 + 240 frames, seeds 1-3 read 4.989, 4.996,
/// 5.018). Hence 128² and 256 frames: within 1% (issue 61).
#[test]
fn furnace_within_one_percent() {
    let (albedo, emission) = (0.8f32, 1.0f32);
    let expected = emission as f64 / (1.0 - albedo as f64);
    let (img, rays, _) = common::render_after_warmup(
        "hash-cache",
        toml::Table::new(),
        builtin::furnace(albedo, emission, 1),
        [128, 128],
        16,
        240,
        1,
    );
    let v = energy(&img);
    let rpp = rays.total() as f64 / (128.0 * 128.0 * 240.0);
    eprintln!(
        "hash-cache furnace after 16 + 240 frames: {v:.4} vs {expected:.4} ({:+.2}%), {rpp:.2} rays/px/frame",
        (v / expected - 1.0) * 100.0
    );
    assert!((v / expected - 1.0).abs() < 0.01, "{v} vs {expected}");
    assert_eq!(img.non_finite_count(), 0);
}

/// Cornell box, 64², the defaults after 16 frames' warm-up, 32 accumulated: energy within 3%
/// of the reference (issue 61), relMSE printed; the same paths traced to the end
/// (`use_cache = false`) are the unbiased baseline (within 2%) and trace more rays; at least
/// 90% of the lookups on surfaces the camera sees find samples.
#[test]
fn cornell_against_the_reference() {
    let size = [64, 64];
    let truth = common::cornell_truth_64();
    let e_truth = energy(&truth);
    let mut results = Vec::new();
    for use_cache in [true, false] {
        let mut p = toml::Table::new();
        p.insert("use_cache".into(), use_cache.into());
        let (img, rays, _) =
            common::render_after_warmup("hash-cache", p, builtin::cornell(), size, 16, 32, 1);
        let ratio = energy(&img) / e_truth;
        let m = metrics::compare(&img, &truth).unwrap();
        let per_px = |n: u64| n as f64 / (64.0 * 64.0 * 32.0);
        eprintln!(
            "hash-cache cornell 64², use_cache = {use_cache}: energy {ratio:.4} of the reference, relMSE {:.3e}, rays/px/frame {:.2} (pixel paths' indirect {:.2}, shadow {:.2}, cache updates {:.2}); lookups: {}",
            m.rel_mse,
            per_px(rays.total()),
            per_px(rays.kind("indirect")),
            per_px(rays.kind("shadow")),
            per_px(rays.kind("cache")),
            rays.cache_lookups.summary()
        );
        assert_eq!(img.non_finite_count(), 0);
        results.push((ratio, rays));
    }
    let (cached, traced) = (&results[0], &results[1]);
    assert!(
        (cached.0 - 1.0).abs() < 0.03,
        "energy with the cache {}",
        cached.0
    );
    assert!(
        (traced.0 - 1.0).abs() < 0.02,
        "energy traced to the end {}",
        traced.0
    );
    assert!(
        (cached.1.kind("indirect") as f64) < 0.8 * traced.1.kind("indirect") as f64,
        "the cache should end paths: {} against {} indirect rays",
        cached.1.kind("indirect"),
        traced.1.kind("indirect")
    );
    assert_eq!(
        traced.1.kind("cache"),
        0,
        "no update paths without the cache"
    );
    let covered = cached.1.cache_lookups.covered_seen().unwrap();
    assert!(covered >= 0.9, "covered lookups on seen surfaces {covered}");
}

/// Hard cases (emission 1e6, degenerate triangles, grazing angles) stay finite, and the same
/// seed gives the same image twice: samples are summed in fixed point, so the order in which
/// the update paths add them changes nothing.
#[test]
fn hard_cases_are_finite_and_deterministic() {
    let (a, b) = common::hard_cases_twice("hash-cache");
    assert_eq!(a.non_finite_count(), 0, "hard-cases: NaN/Inf");
    assert!(a.rgb == b.rgb, "same seed, different image");
}

/// Eviction: cells of a view the camera left are freed after `stale_frames` frames without a
/// sample. Cornell seen whole, then only its floor from close by (finer cells, so more of
/// them): after the stale frames the table holds about what a cache that only ever saw the
/// floor holds (within 15%), not the whole box's cells besides.
#[test]
fn cells_out_of_view_are_evicted() {
    // Inside the box (about 5.5 units a side), looking down at the floor.
    let floor = Camera {
        position: Vec3::new(2.78, 1.5, 1.5),
        target: Vec3::new(2.78, 0.0, 3.5),
        up: Vec3::Y,
        fov_y: 40.0,
    };
    let p = toml::toml! { stale_frames = 4 };
    let mut moved = engine("hash-cache", p.clone(), builtin::cornell(), [32, 32], 3);
    frames(&mut moved, 8);
    let whole = stats(&moved);
    moved.move_camera(floor);
    frames(&mut moved, 10);
    let after = stats(&moved);
    let mut only = engine("hash-cache", p, builtin::cornell(), [32, 32], 3);
    only.move_camera(floor);
    frames(&mut only, 10);
    let fresh = stats(&only);
    eprintln!(
        "hash-cache occupied slots: whole box {} ({} with samples), then the floor for 10 frames {}, the floor alone {}",
        whole.occupied, whole.with_samples, after.occupied, fresh.occupied
    );
    assert!(whole.occupied > 0 && whole.with_samples > 0);
    let ratio = after.occupied as f64 / fresh.occupied as f64;
    assert!(
        (ratio - 1.0).abs() < 0.15,
        "after eviction {} slots against {} for the floor alone",
        after.occupied,
        fresh.occupied
    );
}

/// A scripted change keeps the cells (as a game would; the engine rebuilds the technique for
/// it): the lamp on Cornell's back wall is switched on after 24 frames, and the cache still
/// holds the same cells, with the dark light they had, so its light at the pixels (albedo ×
/// cell) lags behind the lamp. The first frame after the switch reads the old cells; after
/// more frames the cells take the new light in, and the frame's light rises.
#[test]
fn a_scripted_change_keeps_the_cells() {
    let mut p = toml::Table::new();
    p.insert("accumulate".into(), false.into());
    let mut e = engine(
        "hash-cache",
        p,
        builtin::cornell_with_lamp(Some(0.0)),
        [32, 32],
        1,
    );
    frames(&mut e, 24);
    let before = stats(&e);
    let on = builtin::cornell_with_lamp(Some(40.0));
    let gpu_scene = std::sync::Arc::new(gilab::scene::gpu_scene::GpuScene::upload(&e.gpu, &on));
    e.change_scene(std::sync::Arc::new(on), gpu_scene).unwrap();
    let kept = stats(&e);
    frames(&mut e, 1);
    let first = stats(&e);
    frames(&mut e, 31);
    let later = stats(&e);
    eprintln!(
        "hash-cache, lamp switched on: cells {} (mean light over albedo {:.4}); after the switch {} ({:.4}); frame 1 after {:.4}, frame 32 after {:.4}",
        before.occupied,
        before.mean_light,
        kept.occupied,
        kept.mean_light,
        first.mean_light,
        later.mean_light
    );
    assert_eq!(
        kept.occupied, before.occupied,
        "the switch emptied the table"
    );
    assert_eq!(kept.mean_light, before.mean_light);
    assert!(
        later.mean_light > 1.2 * first.mean_light,
        "the cells should take the lamp's light in: {} then {}",
        first.mean_light,
        later.mean_light
    );
}

/// `light_sampling = "tree"` (NEE of the pixels' and the update paths by the light tree) keeps
/// the Cornell box's energy within 3% of the reference, as power sampling does.
#[test]
fn light_tree_sampling_keeps_the_energy() {
    let truth = common::cornell_truth_64();
    let (img, _, _) = common::render_after_warmup(
        "hash-cache",
        toml::toml! { light_sampling = "tree" },
        builtin::cornell(),
        [64, 64],
        16,
        32,
        1,
    );
    let ratio = energy(&img) / energy(&truth);
    eprintln!("hash-cache cornell 64², light tree: energy {ratio:.4} of the reference");
    assert!((ratio - 1.0).abs() < 0.03, "energy {ratio}");
    assert_eq!(img.non_finite_count(), 0);
}

/// The thin-wall room (its reference inside is exactly 0: tests/gpu.rs), the surfels' leak
/// test's sequence: 48 frames outside facing the sunlit wall, then moved inside with the cache
/// kept, 8 frames accumulated. Cells are keyed by the side a surface faces, so the wall's two
/// faces never share a cell; what can leak is a cell that straddles the wall's foot (the
/// ground outside and the floor inside face the same way within one cell). Measured and
/// printed beside the surfels' target (0.02 of luminance, 0.4% of the sunlit exterior), which
/// it must meet.
#[test]
fn thin_wall_leak() {
    let (outside, leak) = common::thin_wall_leak("hash-cache", toml::Table::new());
    eprintln!(
        "hash-cache thin-wall: outside view luminance {outside:.4}; inside after moving in, 8 frames: {leak:.5} (reference 0, the surfels' target 0.02)"
    );
    assert!(outside > 1.0, "the outside view is sunlit: {outside}");
    assert!(leak < 0.02, "leak {leak}");
}

/// Surfel rays whose hit no surfel covers end in the hash cache (`uncovered_hits =
/// "hash-cache"`, issue 61's reader for surfel rays): Cornell 64² from a cold start, 32 frames,
/// beside the surfels' default (`"path"`) with the same surfels (spawning reads no irradiance).
/// At 64² the surfels cover the box slowly (docs/surfels.md), so both read about 0.89 of the
/// reference here: the check is that the cache adds no error of its own against the reference
/// (energy no further from it than the path's + 1%, relMSE within 10% of the path's) while
/// the uncovered hits trace far fewer indirect and shadow rays, the cache's update paths instead.
#[test]
fn surfel_rays_ending_in_the_hash_cache() {
    let truth = common::cornell_truth_64();
    let e_truth = energy(&truth);
    let mut runs = Vec::new();
    for uncovered in ["path", "hash-cache"] {
        let p = toml::toml! { uncovered_hits = uncovered };
        let mut e = engine("surfels", p, builtin::cornell(), [64, 64], 1);
        frames(&mut e, 32);
        let img = e.read_output().unwrap();
        let rays = e.ray_counts().unwrap();
        let m = metrics::compare(&img, &truth).unwrap();
        let per_px = |k: &str| rays.kind(k) as f64 / (64.0 * 64.0 * 32.0);
        let ratio = energy(&img) / e_truth;
        eprintln!(
            "surfels, uncovered_hits = {uncovered}, cornell 64², 32 frames: energy {ratio:.4} of the reference, relMSE {:.3e}; rays/px/frame surfel {:.2}, shadow {:.2}, indirect {:.2}, cache {:.3}",
            m.rel_mse,
            per_px("surfel"),
            per_px("shadow"),
            per_px("indirect"),
            per_px("cache")
        );
        assert_eq!(img.non_finite_count(), 0, "{uncovered}: NaN/Inf");
        assert_eq!(rays.invalid_samples, 0, "{uncovered}: invalid samples");
        runs.push((
            ratio,
            per_px("indirect"),
            per_px("shadow"),
            per_px("cache"),
            m.rel_mse,
        ));
    }
    let (path, cached) = (runs[0], runs[1]);
    assert!(
        (cached.0 - 1.0).abs() < (path.0 - 1.0).abs() + 0.01,
        "energy with the cache {} against the path's {}",
        cached.0,
        path.0
    );
    assert!(
        cached.4 < 1.1 * path.4,
        "relMSE with the cache {} against the path's {}",
        cached.4,
        path.4
    );
    assert!(
        cached.1 < 0.3 * path.1 && cached.2 < path.2,
        "uncovered hits should read the cache: indirect {} against {}, shadow {} against {}",
        cached.1,
        path.1,
        cached.2,
        path.2
    );
    assert!(
        path.3 == 0.0 && cached.3 > 0.0,
        "update paths only with the cache"
    );
}
