//! DDGI irradiance probes (issue 61): the furnace's closed form, the Cornell box against the
//! reference, the thin-wall leak with and without the paper's two fixes (Chebyshev visibility,
//! relocation), hard cases and determinism. Docs: docs/ddgi.md.

mod common;

use common::{engine, luminance};
use gilab::compare::{metrics, Image};
use gilab::render::engine::Engine;
use gilab::scene::builtin;
use gilab::techniques::ddgi::Ddgi;

fn energy(img: &Image) -> f64 {
    luminance(img.mean())
}

fn frames(e: &mut Engine, n: u32) {
    for _ in 0..n {
        e.render_frame().unwrap();
    }
}

/// `warmup` frames that only fill the probes (the engine's `reset` would empty them, so the
/// accumulation restarts as after a scripted camera move), then `frames` accumulated: the
/// image and the rays per pixel per frame of those frames, by kind ("all", "probe", "shadow").
fn render_warm(
    params: toml::Table,
    scene: gilab::scene::Scene,
    size: [u32; 2],
    warmup: u32,
    n: u32,
) -> (Image, [f64; 3], Engine) {
    let camera = scene.default_camera();
    let mut e = engine("ddgi", params, scene, size, 1);
    frames(&mut e, warmup);
    let before = e.ray_counts().unwrap();
    e.move_camera(camera);
    frames(&mut e, n);
    let after = e.ray_counts().unwrap();
    assert_eq!(after.invalid_samples, 0, "NaN/Inf samples");
    let per_px = |k: &str| {
        let d = |c: &gilab::render::RayCounts| {
            if k == "all" {
                c.total()
            } else {
                c.kind(k)
            }
        };
        (d(&after) - d(&before)) as f64 / (size[0] as f64 * size[1] as f64 * n as f64)
    };
    let rays = [per_px("all"), per_px("probe"), per_px("shadow")];
    (e.read_output().unwrap(), rays, e)
}

fn table(pairs: &[(&str, toml::Value)]) -> toml::Table {
    pairs
        .iter()
        .map(|(k, v)| (k.to_string(), v.clone()))
        .collect()
}

/// White furnace (albedo 0.8, emission 1: radiance 5 everywhere). Every probe sees the same
/// light, so what is left is the method's own loss and its approach to the fixed point: each
/// frame adds a bounce through the probes, and a frame replaces only 1 - h of a probe's maps,
/// so from a cold start the error shrinks by (1 - h)(1 - albedo) a frame (0.6% at the default
/// h = 0.97: hundreds of frames, docs/ddgi.md). The fixed point does not depend on h, so it is
/// checked at h = 0 (within 3%, issue 61); the default's run is checked to approach it from
/// below and printed.
#[test]
fn furnace_within_three_percent_once_converged() {
    let (albedo, emission) = (0.8f32, 1.0f32);
    let expected = emission as f64 / (1.0 - albedo as f64);
    let scene = || builtin::furnace(albedo, emission, 1);
    let p = table(&[("hysteresis", 0.0.into())]);
    let (img, rays, e) = render_warm(p, scene(), [32, 32], 40, 16);
    let v = energy(&img);
    let rpp = rays[0];
    let memory = e
        .technique
        .as_any()
        .downcast_ref::<Ddgi>()
        .unwrap()
        .memory_bytes();
    eprintln!(
        "ddgi furnace, hysteresis 0, after 40 + 16 frames: {v:.4} vs {expected:.4} ({:+.2}%), {rpp:.1} rays/px/frame, probe memory {:.2} MiB",
        (v / expected - 1.0) * 100.0,
        memory as f64 / (1 << 20) as f64
    );
    assert!((v / expected - 1.0).abs() < 0.03, "{v} vs {expected}");
    assert_eq!(img.non_finite_count(), 0);

    let p = table(&[("accumulate", false.into())]);
    let mut e = engine("ddgi", p, scene(), [32, 32], 1);
    let mut curve = Vec::new();
    for f in 1..=48 {
        e.render_frame().unwrap();
        if f % 16 == 0 {
            curve.push(energy(&e.read_output().unwrap()));
        }
    }
    eprintln!("ddgi furnace at the defaults, frames 16, 32, 48 (each alone): {curve:.4?}");
    assert!(
        curve.windows(2).all(|w| w[1] > w[0]) && curve[2] < expected,
        "the default approaches {expected} from below: {curve:?}"
    );
}

/// Cornell box, 64², the defaults after 32 frames' warm-up, 32 accumulated: energy within 5%
/// of the reference (issue 61) and relMSE printed, with and without multi-bounce.
#[test]
fn cornell_against_the_reference() {
    let truth = common::cornell_truth_64();
    let e_truth = energy(&truth);
    let mut ratios = Vec::new();
    for multi_bounce in [true, false] {
        let p = table(&[("multi_bounce", multi_bounce.into())]);
        let (img, rays, e) = render_warm(p, builtin::cornell(), [64, 64], 32, 32);
        if multi_bounce {
            check_corner_views(&e, 64 * 64);
        }
        let ratio = energy(&img) / e_truth;
        let m = metrics::compare(&img, &truth).unwrap();
        eprintln!(
            "ddgi cornell 64², multi_bounce = {multi_bounce}: energy {ratio:.4} of the reference, relMSE {:.3e}, rays/px/frame {:.1} (probe {:.1}, shadow {:.1})",
            m.rel_mse, rays[0], rays[1], rays[2],
        );
        assert_eq!(img.non_finite_count(), 0);
        ratios.push(ratio);
    }
    assert!((ratios[0] - 1.0).abs() < 0.05, "energy {}", ratios[0]);
    assert!(
        ratios[1] < ratios[0],
        "one bounce must lose light: {ratios:?}"
    );
}

/// The debug views of the 8 probes each pixel reads (channels 4-23, `shade.wgsl`) agree with
/// the gather that lit the image: a corner weighs in where its probe is named, the shares sum
/// to 1, the strongest corner is the probe of channel 3 ("the probe the pixel reads most"),
/// and every surface pixel of the box reads probes (channel 7, the cascade, marks a surface).
fn check_corner_views(e: &Engine, pixels: usize) {
    let views = e.technique.debug_views();
    assert_eq!(views.len(), 24, "the corner views are offered at 64²");
    let data = e.read_debug().unwrap().expect("ddgi has a debug buffer");
    assert_eq!(data.len(), 6 * pixels, "six planes");
    let ch = |c: usize| gilab::render::debug_channel(&data, pixels, c);
    let (strongest, count, total, cascade) = (ch(3), ch(4), ch(5), ch(7));
    let slots: Vec<Vec<f32>> = (8..16).map(ch).collect();
    let shares: Vec<Vec<f32>> = (16..24).map(ch).collect();
    let mut reading = 0usize;
    let mut weighing = 0.0;
    // Pixels on a surface (the camera ray hit): they name the cascade they read.
    let surfaces = cascade.iter().filter(|&&c| c > 0.0).count();
    for px in 0..pixels {
        let named = (0..8).filter(|&k| slots[k][px] > 0.0).count();
        assert_eq!(
            count[px] as usize, named,
            "pixel {px}: count against named corners"
        );
        if named == 0 {
            assert_eq!(total[px], 0.0, "pixel {px}: weight without a probe");
            assert_eq!(
                strongest[px], 0.0,
                "pixel {px}: a strongest probe without a corner"
            );
            continue;
        }
        reading += 1;
        weighing += named as f64;
        let sum: f32 = (0..8).map(|k| shares[k][px]).sum();
        assert!((sum - 1.0).abs() < 1e-4, "pixel {px}: shares sum to {sum}");
        for k in 0..8 {
            assert_eq!(
                slots[k][px] > 0.0,
                shares[k][px] > 0.0,
                "pixel {px}, corner {k}: named without a share, or the other way"
            );
        }
        let best = (0..8)
            .max_by(|&a, &b| shares[a][px].total_cmp(&shares[b][px]))
            .unwrap();
        let best_share = shares[best][px];
        assert!(
            (0..8).any(|k| shares[k][px] == best_share && slots[k][px] == strongest[px]),
            "pixel {px}: the strongest probe {} is not the corner of the largest share",
            strongest[px]
        );
    }
    eprintln!(
        "ddgi corner views, cornell 64²: {reading} of the {surfaces} surface pixels ({pixels} in all) read probes, {:.2} of the 8 weigh in on average",
        weighing / reading.max(1) as f64
    );
    assert!(
        reading == surfaces && surfaces as f64 > 0.9 * pixels as f64,
        "{reading} of {surfaces} surface pixels read probes"
    );
}

/// Probe rays that end in the hash radiance cache (`probe_hits = "hash-cache"`, issue 61's
/// reader): Cornell 64² as `cornell_against_the_reference`, energy within 5% of the reference,
/// relMSE printed; at least 90% of the lookups on surfaces the camera sees find samples, and
/// the cache's light stands for the hit's NEE there, so fewer shadow rays are traced than with
/// the probes' own hit lighting.
#[test]
#[ignore = "slow tier, not run by CI (docs/testing.md#slow-tier): DDGI probe rays ending in the hash cache (not a default), 125 s in CI"]
fn probe_rays_ending_in_the_hash_cache() {
    let truth = common::cornell_truth_64();
    let p = table(&[("probe_hits", "hash-cache".into())]);
    let (img, rays, e) = render_warm(p, builtin::cornell(), [64, 64], 32, 32);
    let ratio = energy(&img) / energy(&truth);
    let m = metrics::compare(&img, &truth).unwrap();
    let lookups = e.ray_counts().unwrap().cache_lookups;
    eprintln!(
        "ddgi cornell 64², probe_hits = hash-cache: energy {ratio:.4} of the reference, relMSE {:.3e}, rays/px/frame {:.1} (probe {:.1}, shadow {:.1}); lookups: {}",
        m.rel_mse,
        rays[0],
        rays[1],
        rays[2],
        lookups.summary()
    );
    assert_eq!(img.non_finite_count(), 0);
    assert!((ratio - 1.0).abs() < 0.05, "energy {ratio}");
    let covered = lookups.covered_seen().unwrap();
    assert!(covered >= 0.9, "covered lookups on seen surfaces {covered}");
    let (_, own, _) = render_warm(table(&[]), builtin::cornell(), [64, 64], 0, 1);
    assert!(
        rays[2] < own[2],
        "the cache replaces NEE at hits: {} against {} shadow rays/px",
        rays[2],
        own[2]
    );
}

/// The thin-wall room (its reference inside is exactly 0: tests/gpu.rs): 48 frames outside
/// facing the sunlit wall, then moved inside with the probes kept, 8 frames accumulated (the
/// surfels' and the hash cache's sequence). DDGI's classic failure, measured: light reaches
/// inside through probes whose cell straddles the wall. At the defaults the one volume spans
/// the scene's 100-unit ground (spacing 12.5, the 4-unit room inside one cell), so every probe
/// the room reads is outside; at `volume = 0.08` (spacing 1, the volume following the camera)
/// probes stand inside the room, and the paper's fixes can work: measured with both, without
/// the Chebyshev visibility and without relocation. Visibility must cut the leak there.
#[test]
fn thin_wall_leak_with_and_without_the_fixes() {
    let dense = |extra: &[(&str, toml::Value)]| {
        let mut t = table(&[("volume", 0.08.into())]);
        t.extend(table(extra));
        t
    };
    let mut leaks = Vec::new();
    for (label, p) in [
        ("defaults", table(&[])),
        ("volume 0.08", dense(&[])),
        (
            "volume 0.08, no visibility",
            dense(&[("visibility", false.into())]),
        ),
        (
            "volume 0.08, no relocation",
            dense(&[("relocation", false.into())]),
        ),
    ] {
        let (outside, leak) = common::thin_wall_leak("ddgi", p);
        eprintln!(
            "ddgi thin-wall, {label}: outside view luminance {outside:.4}; inside after moving in, 8 frames: {leak:.5} (reference 0, the surfels' target 0.02)"
        );
        assert!(outside > 1.0, "the outside view is sunlit: {outside}");
        leaks.push(leak);
    }
    assert!(
        leaks[1] < leaks[2],
        "visibility must cut the leak: {leaks:?}"
    );
}

/// Hard cases (emission 1e6, degenerate triangles, grazing angles) stay finite, and the same
/// seed gives the same image twice.
#[test]
fn hard_cases_are_finite_and_deterministic() {
    let (a, b) = common::hard_cases_twice("ddgi");
    assert_eq!(a.non_finite_count(), 0, "hard-cases: NaN/Inf");
    assert!(a.rgb == b.rgb, "same seed, different image");
}
