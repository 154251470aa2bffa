//! ReSTIR against the reference path tracer on lavapipe, small images: DI alone against the
//! reference's direct light (max_depth = 1: emission plus one bounce of next-event estimation
//! with MIS), DI + GI against the full reference, the furnace, many lights, hard cases.

mod common;

use common::{engine, render_technique as render};
use gilab::compare::{metrics, Image};
use gilab::render::{RayCounts, FLAG_NO_PRIMARY_EMISSION};
use gilab::scene::{builtin, Scene};

fn restir(
    scene: Scene,
    size: [u32; 2],
    frames: u32,
    seed: u32,
    params: toml::Table,
) -> (Image, RayCounts) {
    render("restir", params, scene, size, frames, seed, 0)
}

/// The reference path tracer's direct light: emission plus one bounce (NEE + MIS).
fn direct_reference(
    scene: Scene,
    size: [u32; 2],
    spp: u32,
    seed: u32,
    flags: u32,
) -> (Image, RayCounts) {
    common::reference_render(scene, size, spp, seed, 1, flags)
}

/// The same direct light as a converged truth, shared across tests and binaries.
fn direct_truth(scene: Scene, size: [u32; 2], spp: u32, seed: u32, flags: u32) -> Image {
    common::shared_reference(scene, size, spp, seed, 1, flags)
}

fn energy(img: &Image) -> f64 {
    common::luminance(img.mean())
}

#[test]
fn restir_di_converges_to_reference_direct_light() {
    let size = [64, 64];
    let truth = direct_truth(builtin::cornell(), size, 1024, 7, 0);
    let (unbiased, _) = restir(builtin::cornell(), size, 128, 1, toml::toml! { gi = false });
    let ratio = energy(&unbiased) / energy(&truth);
    let m = metrics::compare(&unbiased, &truth).unwrap();
    eprintln!(
        "unbiased ReSTIR DI, 128 frames: energy ratio {ratio:.4}, relMSE {:.2e}",
        m.rel_mse
    );
    assert!((ratio - 1.0).abs() < 0.02, "energy ratio {ratio}");
    assert!(m.rel_mse < 0.01, "relMSE {}", m.rel_mse);

    let biased_params: toml::Table = toml::toml! { unbiased = false
    gi = false };
    let (biased, _) = restir(builtin::cornell(), size, 128, 1, biased_params);
    let b_ratio = energy(&biased) / energy(&truth);
    let bm = metrics::compare(&biased, &truth).unwrap();
    // Reported, not hidden: the biased mode loses energy in contact shadows.
    eprintln!(
        "biased ReSTIR DI, 128 frames: energy ratio {b_ratio:.4}, relMSE {:.2e}",
        bm.rel_mse
    );
    assert!(
        b_ratio < 1.02 && b_ratio > 0.8,
        "biased energy ratio {b_ratio}"
    );
}

/// Many lights at equal rays: ReSTIR's reuse against the reference's one NEE sample per bounce.
/// Emission seen directly by the camera is left out of both (it is the same for both and its
/// pixel-coverage noise would swamp the comparison of light sampling).
#[test]
fn restir_beats_nee_on_many_lights_at_equal_rays() {
    let size = [64, 64];
    let flags = FLAG_NO_PRIMARY_EMISSION;
    let scene = || builtin::many_lights(1024, 1);
    // 1,024 spp (2,048 before 2026-11-26, for CI time): the truth's own relMSE (about 1/1,024 of
    // NEE's at 1 spp) adds the same small amount to both errors of the ratio.
    let truth = direct_truth(scene(), size, 1024, 9, flags);
    let per_spp = direct_reference(scene(), size, 1, 3, flags).1.total() as f64;
    // One real-time frame each: ReSTIR's frame after `frames` frames of reuse (no averaging)
    // against NEE with at least the rays that frame traced.
    let params: toml::Table = toml::toml! { candidates = 32
    accumulate = false
    gi = false };
    for frames in [1u32, 16] {
        let (before, before_rays) = render(
            "restir",
            params.clone(),
            scene(),
            size,
            frames - 1,
            1,
            flags,
        );
        let _ = before;
        let (r, r_rays) = render("restir", params.clone(), scene(), size, frames, 1, flags);
        let frame_rays = r_rays.total() - before_rays.total();
        let spp = ((frame_rays as f64 / per_spp).ceil() as u32).max(1);
        // NEE's relMSE at 1 spp follows a handful of bright pixels: one image measured 6.8 to
        // 15.9 by seed alone, and the mean of 8 seeds moved with the seeds (8.8 over seeds 3-10,
        // 12.6 over 11-18), so it is averaged over all 16, none the truth's (9).
        let nee_seeds = 3..19u32;
        let mut e_nee = 0.0;
        let mut nee_rays = 0;
        for seed in nee_seeds.clone() {
            let (nee, rays) = direct_reference(scene(), size, spp, seed, flags);
            e_nee += metrics::compare(&nee, &truth).unwrap().rel_mse / nee_seeds.len() as f64;
            nee_rays = rays.total();
        }
        assert!(nee_rays >= frame_rays);
        let e_restir = metrics::compare(&r, &truth).unwrap().rel_mse;
        let gain = e_nee / e_restir;
        eprintln!(
            "many-lights, frame {frames}: ReSTIR relMSE {e_restir:.3e} ({frame_rays} rays) vs NEE {e_nee:.3e} (mean of {} seeds, {nee_rays} rays, {spp} spp): {gain:.1}x (target 10x)",
            nee_seeds.len()
        );
        common::targets::check(
            if frames == 1 {
                "restir-vs-nee-gain-frame-1"
            } else {
                "restir-vs-nee-gain-frame-16"
            },
            common::targets::Better::Higher,
            10.0,
            gain,
            "NEE relMSE / ReSTIR relMSE at equal rays, many-lights",
        );
    }
}

#[test]
fn restir_stays_finite_on_hard_cases() {
    for (name, scene) in [
        ("hard-cases", builtin::hard_cases(1e6)),
        ("glossy", builtin::glossy()),
    ] {
        let max_emitted = scene
            .materials
            .iter()
            .map(|m| m.emissive.max_element())
            .fold(0.0f32, f32::max);
        let (img, _) = restir(scene, [48, 48], 8, 1, toml::Table::new());
        assert_eq!(img.non_finite_count(), 0, "{name}");
        // Direct light at a pixel cannot exceed what the brightest emitter sends times a
        // generous factor for W on a handful of samples.
        let bound = max_emitted.max(1.0) * 1e3;
        assert!(
            img.max_value() <= bound,
            "{name}: max pixel {} > {bound}",
            img.max_value()
        );
    }
}

/// Temporal and spatial reuse each lower the error of a single frame (real-time view, no
/// averaging) of direct light on many-lights (emission seen by the camera left out). The gains
/// are modest: with the unshadowed target the remaining noise is mostly visibility.
#[test]
fn reuse_lowers_single_frame_error() {
    let size = [64, 64];
    let flags = FLAG_NO_PRIMARY_EMISSION;
    let scene = || builtin::many_lights(1024, 1);
    let truth = direct_truth(scene(), size, 1024, 5, flags);
    let err = |mut params: toml::Table| {
        params.insert("gi".into(), false.into());
        // Candidates from the global pool: this test is about reuse, not ReGIR.
        params.insert("regir".into(), false.into());
        let (img, _) = render("restir", params, scene(), size, 16, 1, flags);
        metrics::compare(&img, &truth).unwrap().rel_mse
    };
    let none = err(toml::toml! { accumulate = false
    temporal = false
    spatial_count = 0 });
    let temporal = err(toml::toml! { accumulate = false
    spatial_count = 0 });
    let spatial = err(toml::toml! { accumulate = false
    temporal = false
    spatial_radius = 4.0 });
    let both = err(toml::toml! { accumulate = false
    spatial_radius = 4.0 });
    let biased = err(toml::toml! { accumulate = false
    spatial_radius = 4.0
    unbiased = false });
    eprintln!(
        "many-lights direct, frame 16 relMSE: no reuse {none:.3e}, temporal {temporal:.3e}, \
         spatial {spatial:.3e}, temporal+spatial {both:.3e}, biased with visibility reuse {biased:.3e}"
    );
    assert!(
        temporal < 0.85 * none,
        "temporal reuse: {temporal} vs {none}"
    );
    common::targets::check(
        "restir-spatial-reuse-single-frame",
        common::targets::Better::Lower,
        0.85,
        spatial / none,
        "relMSE of frame 16 with spatial reuse alone over none, many-lights 64², seed 1",
    );
    // On top of temporal reuse the spatial gain is within this test's noise (2.12 against 2.16
    // in one RNG stream, 2.19 against 2.11 in another), so only a bound is checked.
    assert!(both < 0.85 * none, "temporal + spatial: {both} vs {none}");
}

/// DI + GI accumulated over 128 frames at 128² converges to the full reference (256 frames
/// before 2026-11-26: energy 0.9935, relMSE 2.3e-3 against 2% and 1e-2).
#[test]
fn restir_di_gi_converges_to_reference() {
    let size = [128, 128];
    // The Cornell truth Lumen's and the surfels' tests share (512 spp).
    let truth = common::shared_reference(builtin::cornell(), size, 512, 11, 0, 0);
    let (img, rays) = restir(builtin::cornell(), size, 128, 1, toml::Table::new());
    let ratio = energy(&img) / energy(&truth);
    let m = metrics::compare(&img, &truth).unwrap();
    eprintln!(
        "ReSTIR DI+GI unbiased, 128 frames at 128²: energy ratio {ratio:.4}, relMSE {:.2e}, {:.2} rays/px/frame",
        m.rel_mse,
        rays.total() as f64 / (128.0 * 128.0 * 128.0)
    );
    assert!((ratio - 1.0).abs() < 0.02, "energy ratio {ratio}");
    assert!(m.rel_mse < 0.01, "relMSE {}", m.rel_mse);
    common::assert_energy_and_error_controls_fail(&img, &truth, 0.02, 0.01);
}

/// White furnace: closed sphere, albedo a, emission E: radiance E / (1 - a) everywhere.
#[test]
fn restir_furnace_matches_closed_form() {
    let (albedo, emission) = (0.8f32, 1.0f32);
    let (img, _) = restir(
        builtin::furnace(albedo, emission, 2),
        [48, 48],
        64,
        1,
        toml::Table::new(),
    );
    let expected = emission as f64 / (1.0 - albedo as f64);
    let mean = img.mean();
    for (c, v) in mean.iter().enumerate() {
        let rel = v / expected - 1.0;
        eprintln!(
            "furnace channel {c}: {v:.4} vs {expected:.4} ({:+.2}%)",
            rel * 100.0
        );
        assert!(rel.abs() < 0.02, "furnace channel {c}: {v} vs {expected}");
    }
}

/// Issue 60: ReGIR's cells filled by the light tree (`regir_fill = "tree"`: each slot's 32
/// candidates drawn by the tree's importance for the cell's bounding ball instead of by power).
/// On many-lights (1,024 lights) at 64², the initial candidates alone (no reuse): one frame's
/// relMSE against the reference's direct light beside power's fill (printed: 2.960 against
/// 2.957, no gain on this scene), and after 64 frames the two fills' energies agree within 2%
/// (measured 1.0210 and 1.0169 of the reference: ReGIR on this seed, either fill). Not
/// discriminated here: a fill whose boxes are not grown by the cell (an edited shader, not
/// kept) passes too, the hall's lights all facing down on every cell.
#[test]
fn regir_cells_filled_by_the_light_tree_stay_unbiased() {
    let size = [64, 64];
    let flags = FLAG_NO_PRIMARY_EMISSION;
    let scene = || builtin::many_lights(1024, 1);
    let truth = direct_truth(scene(), size, 1024, 9, flags);
    let run = |fill: &str, frames: u32| {
        let mut params: toml::Table = toml::toml! { gi = false
        temporal = false
        spatial_count = 0
        regir = true };
        params.insert("regir_fill".into(), fill.into());
        params.insert("accumulate".into(), (frames > 1).into());
        let (img, rays) = render("restir", params, scene(), size, frames, 1, flags);
        (img, rays.total())
    };
    let one_frame = |fill: &str| {
        let (img, rays) = run(fill, 1);
        (metrics::compare(&img, &truth).unwrap().rel_mse, rays)
    };
    let (power, power_rays) = one_frame("power");
    let (tree, tree_rays) = one_frame("tree");
    eprintln!("many-lights, 1 frame, ReGIR filled by power: relMSE {power:.3e} ({power_rays} rays); by the light tree: {tree:.3e} ({tree_rays} rays)");
    let mut energies = Vec::new();
    for fill in ["power", "tree"] {
        let (img, _) = run(fill, 64);
        let ratio = energy(&img) / energy(&truth);
        eprintln!(
            "many-lights, ReGIR filled by {fill}, no reuse, 64 frames: energy {ratio:.4}, relMSE {:.3e}",
            metrics::compare(&img, &truth).unwrap().rel_mse
        );
        energies.push(ratio);
    }
    let drift = energies[1] / energies[0] - 1.0;
    assert!(
        drift.abs() < 0.02,
        "the tree's fill against power's: {drift:+.4} of the energy"
    );
}

/// ReGIR on many-lights: the initial candidates it draws (no temporal or spatial reuse, so the
/// comparison is of the candidate source alone) leave less error than candidates from the
/// global pool, at equal rays (ReGIR traces none); on the Cornell box no grid is built.
#[test]
fn regir_and_the_light_tree_help_many_lights_and_regir_is_skipped_for_cornell() {
    let size = [64, 64];
    let flags = FLAG_NO_PRIMARY_EMISSION;
    let scene = || builtin::many_lights(1024, 1);
    let truth = direct_truth(scene(), size, 1024, 9, flags);
    let err = |regir: bool, light_tree: bool| {
        let params: toml::Table = toml::toml! { accumulate = false
        gi = false
        temporal = false
        spatial_count = 0
        regir = regir
        light_tree = light_tree };
        let (img, rays) = render("restir", params, scene(), size, 1, 1, flags);
        (
            metrics::compare(&img, &truth).unwrap().rel_mse,
            rays.total(),
        )
    };
    let (global, global_rays) = err(false, false);
    let (regir, regir_rays) = err(true, false);
    // Issue 60: the same candidates by the light tree (no build pass).
    let (tree, tree_rays) = err(false, true);
    eprintln!("many-lights, 1 frame: global pool relMSE {global:.3e} ({global_rays} rays), ReGIR {regir:.3e} ({regir_rays} rays), light tree {tree:.3e} ({tree_rays} rays)");
    // Shadow rays are traced for every pixel whose reservoir holds a sample: equal up to noise.
    assert!((regir_rays as f64) <= 1.01 * global_rays as f64);
    // The tree leaves fewer reservoirs empty (fewer candidates of zero target), so a few more
    // pixels trace their shadow ray: 1.2% more rays on this frame.
    assert!((tree_rays as f64) <= 1.02 * global_rays as f64);
    assert!(
        regir < 0.9 * global,
        "ReGIR {regir} vs global pool {global}"
    );
    assert!(
        tree < 0.9 * global,
        "light tree {tree} vs global pool {global}"
    );
    // Issue 60: asserted where the tree should win. Its candidates see each light's distance,
    // orientation and the receiving normal; ReGIR's cell reservoirs see the distance to the cell
    // only (measured 2026-11-29: 0.946 against 2.96).
    assert!(tree < 0.9 * regir, "light tree {tree} vs ReGIR {regir}");
    // And unbiased: the tree's candidates alone (no reuse), 64 frames, converge to the
    // reference's direct light within 1%; with the default reuse (temporal and spatial, 1/Z
    // weights) within 4%: reuse carries a firefly over frames, and power's candidates with
    // reuse read 1.018 and 0.985 on seeds 1 and 2 (the tree's 1.024 and 1.000).
    for (reuse, bound) in [(false, 0.01), (true, 0.04)] {
        let mut params: toml::Table = toml::toml! { gi = false
        regir = false
        light_tree = true };
        if !reuse {
            params.insert("temporal".into(), false.into());
            params.insert("spatial_count".into(), 0.into());
        }
        let (img, _) = render("restir", params, scene(), size, 64, 1, flags);
        let ratio = energy(&img) / energy(&truth);
        let m = metrics::compare(&img, &truth).unwrap();
        eprintln!(
            "many-lights, light tree, unbiased DI, reuse {reuse}, 64 frames: energy {ratio:.4}, relMSE {:.3e}",
            m.rel_mse
        );
        assert!(
            (ratio - 1.0).abs() < bound,
            "reuse {reuse}: energy ratio {ratio}"
        );
    }

    // Cornell: the pass is listed as skipped and never dispatched.
    let mut e = engine(
        "restir",
        toml::Table::new(),
        builtin::cornell(),
        [16, 16],
        1,
    );
    let regir_pass = e
        .passes()
        .into_iter()
        .find(|p| p.name == "regir_build")
        .unwrap();
    assert!(!regir_pass.runs, "{regir_pass:?}");
    let report = e.render_frame().unwrap();
    if report.timing == gilab::render::engine::TimingSource::Timestamps {
        assert!(report
            .gpu_ms_by_pass
            .iter()
            .all(|(n, _)| n != "regir_build"));
        assert!(report.gpu_ms_by_pass.iter().any(|(n, _)| n == "shade"));
    }
}

/// The debug views hold what they say: reservoir M at least the candidate count, light ids
/// within the light pool, ReGIR cells on many-lights and none on the Cornell box.
#[test]
fn debug_views_hold_reservoir_data() {
    for (scene, regir) in [
        (builtin::many_lights(1024, 1), true),
        (builtin::cornell(), false),
    ] {
        let mut e = engine("restir", toml::Table::new(), scene, [32, 32], 1);
        let names: Vec<&str> = e.technique.debug_views().iter().map(|v| v.name).collect();
        assert_eq!(
            names,
            [
                "reservoir M",
                "reservoir weight W",
                "selected light",
                "ReGIR cell"
            ]
        );
        let lights = e.gpu_scene.data.features.light_count() as f32;
        e.render_frame().unwrap();
        e.render_frame().unwrap();
        let debug = e.read_debug().unwrap().expect("restir has a debug buffer");
        let with_sample: Vec<&[f32; 4]> = debug.iter().filter(|d| d[2] > 0.0).collect();
        assert!(
            with_sample.len() > debug.len() / 4,
            "few pixels hold a light sample"
        );
        for d in &with_sample {
            assert!(d[0] >= 8.0, "M {} below the candidate count", d[0]);
            assert!(d[1] > 0.0 && d[1].is_finite(), "W {}", d[1]);
            assert!(
                d[2] >= 1.0 && d[2] <= lights,
                "light id {} of {lights}",
                d[2]
            );
        }
        let cells = debug.iter().filter(|d| d[3] > 0.0).count();
        assert_eq!(cells > 0, regir, "ReGIR cells present: {cells}");
    }
}

/// Per light class candidates (local, directional, sky) on `courtyard`, where all three exist:
/// unbiased DI with sky candidates converges to the reference's direct light (sky included:
/// the reference reaches it by BSDF sampling), and DI + GI with sky candidates converges to the
/// full reference, so direct sky light is not counted twice (GI rays that escape add nothing).
#[test]
fn light_classes_with_sky_converge_to_reference() {
    let size = [48, 48];
    let scene = || builtin::courtyard(15.0, 1.0, 1.0);
    let truth = direct_truth(scene(), size, 1024, 7, 0);
    let params: toml::Table = toml::toml! { gi = false
    sky_candidates = 2 };
    let (di, _) = restir(scene(), size, 128, 1, params);
    let ratio = energy(&di) / energy(&truth);
    let m = metrics::compare(&di, &truth).unwrap();
    eprintln!(
        "courtyard DI, local + directional + sky classes, 128 frames: energy ratio {ratio:.4}, relMSE {:.2e}",
        m.rel_mse
    );
    assert!((ratio - 1.0).abs() < 0.02, "energy ratio {ratio}");
    // Under the porch roof the merge by unshadowed target mostly picks the occluded sun, so
    // relMSE falls slowly there (0.078 measured); the bound catches outliers, not convergence.
    assert!(m.rel_mse < 0.15, "relMSE {}", m.rel_mse);
    // The sky's share arrives through the sky class: without it DI misses it.
    let no_sky: toml::Table = toml::toml! { gi = false
    sky_candidates = 0 };
    let (without, _) = restir(scene(), size, 32, 1, no_sky);
    let without_ratio = energy(&without) / energy(&truth);
    eprintln!("courtyard DI without sky candidates: energy ratio {without_ratio:.4}");
    assert!(
        without_ratio < 0.93,
        "sky missing yet ratio {without_ratio}"
    );

    let full = common::shared_reference(scene(), size, 1024, 11, 0, 0);
    let mut energies = Vec::new();
    for sky in [0, 2] {
        let mut params = toml::Table::new();
        params.insert("sky_candidates".into(), sky.into());
        let (img, _) = restir(scene(), size, 128, 1, params);
        let ratio = energy(&img) / energy(&full);
        let m = metrics::compare(&img, &full).unwrap();
        eprintln!(
            "courtyard DI+GI, sky_candidates {sky}, 128 frames: energy ratio {ratio:.4}, relMSE {:.2e}",
            m.rel_mse
        );
        // 1.5-2% low at 128 frames with or without the sky class (measured 0.985 and 0.980):
        // the metal sphere's glossy sky reflections come from cosine-sampled GI rays, whose
        // rare high-weight samples leave the mean low at finite frame counts.
        assert!(
            (ratio - 1.0).abs() < 0.03,
            "sky {sky}: energy ratio {ratio}"
        );
        energies.push(energy(&img));
    }
    // Sky light counted once: the sky is ~15% of this image, so counting it in both DI and GI
    // would move this ratio far outside the bound.
    let sky_ratio = energies[1] / energies[0];
    assert!(
        (sky_ratio - 1.0).abs() < 0.02,
        "sky class / GI sky {sky_ratio}"
    );
}

/// The talk's reason for classes: a strong sun holds almost all of the light power, so one
/// power-proportional pool spends nearly every candidate on it and the porch lamps are rarely
/// drawn. With classes the local lights get their own candidates. Initial candidates only (no
/// reuse), sky off so both see the same lights, equal rays.
#[test]
fn light_classes_beat_one_pool_under_a_strong_sun() {
    let size = [48, 48];
    let scene = || builtin::courtyard(15.0, 1.0, 0.0);
    let truth = direct_truth(scene(), size, 2048, 7, 0);
    let mut errors = Vec::new();
    for classes in [true, false] {
        let mut params: toml::Table = toml::toml! { gi = false
        temporal = false
        spatial_count = 0 };
        params.insert("light_classes".into(), classes.into());
        // Equal candidates: 8 local + 1 directional against 9 from the pool.
        params.insert("candidates".into(), (if classes { 8 } else { 9 }).into());
        let (img, rays) = restir(scene(), size, 16, 1, params);
        let m = metrics::compare(&img, &truth).unwrap();
        eprintln!(
            "courtyard DI initial candidates, light_classes {classes}: relMSE {:.3e}, {} rays",
            m.rel_mse,
            rays.total()
        );
        errors.push((m.rel_mse, rays.total()));
    }
    // Rays: one camera ray and at most one final visibility ray per pixel for both (the latter
    // only where the pick contributes), so within a few percent.
    let ray_ratio = errors[0].1 as f64 / errors[1].1 as f64;
    assert!((0.95..1.05).contains(&ray_ratio), "rays {ray_ratio}");
    assert!(
        errors[0].0 * 4.0 < errors[1].0,
        "classes {} vs one pool {}",
        errors[0].0,
        errors[1].0
    );
}

/// Biased mode: testing each class's pick before the merge (the talk's fix) against testing
/// only the merged pick, where the shadowed sun wins the merge under the porch roof.
#[test]
fn per_class_visibility_beats_merged_visibility() {
    let size = [48, 48];
    let scene = || builtin::courtyard(15.0, 1.0, 0.0);
    let truth = direct_truth(scene(), size, 2048, 7, 0);
    let mut errors = Vec::new();
    for mode in [1, 2] {
        let mut params: toml::Table = toml::toml! { gi = false
        unbiased = false
        temporal = false
        spatial_count = 0 };
        params.insert("candidate_visibility".into(), mode.into());
        let (img, rays) = restir(scene(), size, 16, 1, params);
        let m = metrics::compare(&img, &truth).unwrap();
        let rays_px = rays.total() as f64 / (size[0] * size[1] * 16) as f64;
        eprintln!(
            "courtyard biased DI, candidate_visibility {mode}: relMSE {:.3e}, {rays_px:.2} rays/px/frame",
            m.rel_mse
        );
        errors.push(m.rel_mse);
    }
    assert!(
        errors[0] < 0.75 * errors[1],
        "per class {} vs merged {}",
        errors[0],
        errors[1]
    );
}

/// The direct-light part (src/parts/restir_direct.rs, issue 34): `direct = "restir"` in Lumen, in
/// surfels and in callisto-shadows runs the restir technique's own DI passes (not a copy), so
/// each frame's direct light per pixel equals the restir technique's image with GI off and the
/// emission seen by the camera left out: same scene (many lights, ReGIR on), seed, camera and
/// frames, with temporal and spatial reuse from the second frame on. Callisto's whole image
/// (accumulation off) is compared: with the part its tile shadows do not run.
#[test]
fn direct_part_equals_the_restir_technique_in_every_family() {
    use gilab::techniques::{lumen::Lumen, surfels::Surfels};
    let size = [48, 48];
    let scene = || builtin::many_lights(256, 1);
    let frames = 3;
    let mut reference_engine = engine(
        "restir",
        toml::toml! { gi = false
        accumulate = false },
        scene(),
        size,
        1,
    );
    reference_engine.flags = FLAG_NO_PRIMARY_EMISSION;
    reference_engine.reset();
    for _ in 0..frames {
        reference_engine.render_frame().unwrap();
    }
    let expected = reference_engine.read_output().unwrap();
    let families: [(&str, toml::Table); 3] = [
        (
            "lumen",
            toml::toml! { direct = "restir"
            clipmap_resolution = 64
            atlas_size = 256 },
        ),
        (
            "surfels",
            toml::toml! { direct = "restir"
            ray_budget = 2048 },
        ),
        (
            "callisto-shadows",
            toml::toml! { direct = "restir"
            accumulate = false },
        ),
    ];
    for (family, params) in families {
        let mut e = engine(family, params, scene(), size, 1);
        let passes = e.passes();
        for name in ["regir_build", "initial_temporal", "spatial", "direct"] {
            assert!(
                passes.iter().any(|p| p.name == name && p.runs),
                "{family}: {name} should run: {passes:?}"
            );
        }
        if family == "callisto-shadows" {
            for name in ["cull", "shadows"] {
                assert!(
                    passes.iter().any(|p| p.name == name && !p.runs),
                    "{family}: {name} should not run: {passes:?}"
                );
            }
        }
        e.flags = FLAG_NO_PRIMARY_EMISSION;
        e.reset();
        for _ in 0..frames {
            e.render_frame().unwrap();
        }
        let any: &dyn std::any::Any = e.technique.as_any();
        let direct: Vec<[f32; 4]> = if let Some(l) = any.downcast_ref::<Lumen>() {
            l.pixel_direct(&e.gpu).unwrap().unwrap()
        } else if let Some(s) = any.downcast_ref::<Surfels>() {
            s.pixel_direct(&e.gpu).unwrap().unwrap()
        } else {
            let img = e.read_output().unwrap();
            img.rgb.chunks(3).map(|c| [c[0], c[1], c[2], 0.0]).collect()
        };
        let (mut worst, mut differing) = (0.0f64, 0);
        for (i, d) in direct.iter().enumerate() {
            for (c, a) in d[..3].iter().enumerate() {
                let (a, b) = (*a as f64, expected.rgb[3 * i + c] as f64);
                let rel = (a - b).abs() / b.abs().max(1e-3);
                if a != b {
                    differing += 1;
                }
                worst = worst.max(rel);
            }
        }
        let mean: f64 = direct.iter().map(|d| d[1] as f64).sum::<f64>() / direct.len() as f64;
        eprintln!(
            "{family} direct = \"restir\" against restir (GI off), frame {frames}: {differing} of {} values differ, worst relative difference {worst:.2e}; mean green {mean:.4}",
            3 * direct.len()
        );
        assert!(mean > 0.0, "{family}: no direct light");
        assert!(
            worst < 1e-5,
            "{family}: direct light differs from the restir technique's by up to {worst:.2e}"
        );
    }
}

/// ReGIR fills only the cells a pixel reads (the mark pass): the image equals a full build's
/// bit for bit, checked against a copy of the shaders whose build ignores the marks.
#[test]
fn regir_marked_build_equals_the_full_build() {
    use gilab::gpu::shaders::ShaderLibrary;
    use gilab::render::engine::{Engine, EngineSettings};
    let render = |shaders: ShaderLibrary| {
        let scene = builtin::many_lights(256, 1);
        let mut t = gilab::techniques::create_technique("restir").unwrap();
        t.set_params_from_table(&toml::toml! { gi = false })
            .unwrap();
        let settings = EngineSettings {
            extent: [32, 32],
            seed: 5,
            camera: scene.default_camera(),
        };
        let mut e = Engine::new(common::gpu(), shaders, scene, t, settings).unwrap();
        assert!(e.passes().iter().any(|p| p.name == "regir_mark" && p.runs));
        for _ in 0..2 {
            e.render_frame().unwrap();
        }
        e.read_output().unwrap()
    };
    let marked = render(ShaderLibrary::discover());
    let dir = common::tmp_dir("restir", "regir-full-build");
    common::copy_dir(std::path::Path::new("shaders"), &dir);
    let build = dir.join("parts/restir/regir_build.wgsl");
    let text = std::fs::read_to_string(&build).unwrap();
    let check = "if atomicLoad(&regir_used[cell]) == 0u {";
    assert!(
        text.contains(check),
        "regir_build.wgsl no longer skips unmarked cells this way"
    );
    std::fs::write(&build, text.replace(check, "if false {")).unwrap();
    let full = render(ShaderLibrary::at(dir));
    assert_eq!(
        marked.rgb, full.rgb,
        "building only the marked cells changed the image"
    );
    assert!(energy(&marked) > 0.0);
}

/// RIS at every hit of a GI sample path (`path_light_candidates`, the seed's light loop along
/// its paths): on many-lights, 8 candidates against 1 (one light by power, as the reference
/// samples) at about equal rays (one shadow ray per hit either way). GI alone (no DI
/// candidates, no primary emission) against the reference's full image minus its direct light:
/// one frame with no GI reuse has lower relMSE; averaged over 16 frames the energies agree (the
/// resampled estimate is unbiased).
#[test]
fn path_light_candidates_lower_gi_noise_at_equal_rays() {
    let size = [64, 64];
    let flags = FLAG_NO_PRIMARY_EMISSION;
    let scene = || builtin::many_lights(1024, 1);
    let full = common::shared_reference(scene(), size, 512, 9, 0, flags);
    let direct = direct_truth(scene(), size, 1024, 9, flags);
    let mut truth = full.clone();
    for (t, d) in truth.rgb.iter_mut().zip(&direct.rgb) {
        *t -= d;
    }
    let run_by = |candidates: i64, frames: u32, accumulate: bool, light_tree: bool| {
        let p: toml::Table = toml::toml! {
            path_light_candidates = candidates
            candidates = 0
            directional_candidates = 0
            accumulate = accumulate
            temporal = false
            spatial_count = 0
            light_tree = light_tree
        };
        render("restir", p, scene(), size, frames, 1, flags)
    };
    let run = |candidates: i64, frames: u32, accumulate: bool| {
        run_by(candidates, frames, accumulate, false)
    };
    let (one, one_rays) = run(1, 1, false);
    let (eight, eight_rays) = run(8, 1, false);
    let e_one = metrics::compare(&one, &truth).unwrap().rel_mse;
    let e_eight = metrics::compare(&eight, &truth).unwrap().rel_mse;
    let (acc_one, _) = run(1, 16, true);
    let (acc_eight, _) = run(8, 16, true);
    let ratio = energy(&acc_eight) / energy(&acc_one);
    // Issue 60 (and 58's cheaper way to the same noise): one light a hit, by the light tree.
    let (tree, tree_rays) = run_by(1, 1, false, true);
    let e_tree = metrics::compare(&tree, &truth).unwrap().rel_mse;
    let (acc_tree, _) = run_by(1, 16, true, true);
    let tree_ratio = energy(&acc_tree) / energy(&acc_one);
    eprintln!(
        "many-lights GI, one frame, no reuse, 1 light a hit by the light tree: relMSE {e_tree:.3e} ({} rays); 16 frames: energy tree/power {tree_ratio:.4}, against the reference {:.4}",
        tree_rays.total(),
        energy(&acc_tree) / energy(&truth),
    );
    assert!(
        e_tree < 0.9 * e_one,
        "tree relMSE {e_tree} vs power's {e_one}"
    );
    assert!(
        (tree_ratio - 1.0).abs() < 0.03,
        "tree energy ratio {tree_ratio}"
    );
    eprintln!(
        "many-lights GI, one frame, no reuse: relMSE {e_one:.3e} with 1 light candidate per hit, {e_eight:.3e} with 8 ({} against {} rays); 16 frames: energy 8/1 {ratio:.4}, against the reference {:.4} / {:.4}",
        one_rays.total(),
        eight_rays.total(),
        energy(&acc_eight) / energy(&truth),
        energy(&acc_one) / energy(&truth),
    );
    assert!(e_eight < 0.9 * e_one, "relMSE {e_eight} vs {e_one}");
    assert!((ratio - 1.0).abs() < 0.03, "energy ratio {ratio}");
    let rays = eight_rays.total() as f64 / one_rays.total() as f64;
    assert!((rays - 1.0).abs() < 0.1, "rays {rays}");
}

/// ReSTIR GI on a moving object (issue 36): a reservoir's reconnection point on an object that
/// moved goes with it (its triangle's motion record), so temporal reuse never reconnects to
/// where the object was. Through `moving` at `time_scale = 6` (0.1 s a frame), every sample
/// point the temporal pass keeps lies on a surface of the current pose.
#[test]
fn gi_reconnections_follow_moving_objects() {
    let mut scene = gilab::scene::builtin::build("moving", &toml::Table::new()).unwrap();
    std::sync::Arc::make_mut(scene.motion.as_mut().unwrap()).time_scale = 6.0;
    let mut e = common::engine("restir", toml::Table::new(), scene, [48, 48], 3);
    for _ in 0..12 {
        e.render_frame().unwrap();
    }
    let any: &dyn std::any::Any = e.technique.as_any();
    let restir = any
        .downcast_ref::<gilab::techniques::restir::Restir>()
        .unwrap();
    let points = restir.lighting.gi_temporal_points(&e.gpu).unwrap();
    let tris = e.scene.triangle_positions();
    let held: Vec<glam::Vec3> = points
        .iter()
        .filter(|p| p[3] > 0.5)
        .map(|p| glam::Vec3::new(p[0], p[1], p[2]))
        .collect();
    let off = common::off_surface(&held, &tris);
    println!(
        "{} GI samples at t = {:.2} s; {} more than 1 cm off every surface (worst {:.3} m)",
        held.len(),
        e.scene_time,
        off.len(),
        off.iter().copied().fold(0.0, f32::max)
    );
    assert!(held.len() > 1000, "{}", held.len());
    assert!(
        off.is_empty(),
        "{} reconnection points float in the air",
        off.len()
    );
}

/// Switching `light_tree` on in a running engine composes ReSTIR's GI passes again with the
/// tree (their NEE): the frames after the switch equal those of an engine built with it.
#[test]
fn switching_the_light_tree_on_equals_starting_with_it() {
    let size = [32, 32];
    let frames = |e: &mut gilab::render::engine::Engine| {
        e.reset();
        for _ in 0..2 {
            e.render_frame().unwrap();
        }
        e.read_output().unwrap()
    };
    let on = toml::toml! { light_tree = true };
    let mut switched = engine(
        "restir",
        toml::Table::new(),
        builtin::many_lights(64, 3),
        size,
        5,
    );
    let before = frames(&mut switched);
    switched.set_params_from_table(&on).unwrap();
    let after = frames(&mut switched);
    let mut started = engine("restir", on, builtin::many_lights(64, 3), size, 5);
    let fresh = frames(&mut started);
    assert_eq!(
        after.rgb, fresh.rgb,
        "the switch composes what a fresh build does"
    );
    assert_ne!(after.rgb, before.rgb, "the tree changes the image");
}

/// A metal floor of roughness `roughness` under an n × n grid of small lights facing down (36
/// in all the power of 36), a grey back wall, and with `pillars` three boxes that hide lights
/// from parts of the floor; no mirror (a delta lobe is out of DI's reach, so the reference's
/// direct light would show what ReSTIR DI cannot). Issue 60's "glossy floor under many small
/// lights".
fn glossy_floor_under_small_lights(roughness: f32, n: u32, pillars: bool) -> Scene {
    use gilab::scene::{Camera, Material};
    use glam::Vec3;
    let v = Vec3::new;
    let mut s = Scene::new("glossy floor under small lights");
    let floor = s.add_material(Material::glossy(
        "metal floor",
        v(0.8, 0.8, 0.8),
        1.0,
        roughness,
    ));
    let wall = s.add_material(Material::lambert("wall", v(0.6, 0.6, 0.6)));
    let light = s.add_material(Material::emitter("light", v(50.0, 45.0, 40.0)));
    let floor_quad = [
        v(-6.0, 0.0, -6.0),
        v(-6.0, 0.0, 6.0),
        v(6.0, 0.0, 6.0),
        v(6.0, 0.0, -6.0),
    ];
    s.add_quad(
        floor_quad[0],
        floor_quad[1],
        floor_quad[2],
        floor_quad[3],
        floor,
    );
    s.add_quad(
        v(-6.0, 0.0, -6.0),
        v(6.0, 0.0, -6.0),
        v(6.0, 4.0, -6.0),
        v(-6.0, 4.0, -6.0),
        wall,
    );
    let step = 12.0 / n as f32;
    // Each light's area shrinks with the count: the total power stays that of 36.
    let r = 0.08 * 6.0 / n as f32;
    for i in 0..n {
        for j in 0..n {
            let (x, z) = (
                -6.0 + step * (i as f32 + 0.5),
                -6.0 + step * (j as f32 + 0.5),
            );
            s.add_quad(
                v(x - r, 3.0, z - r),
                v(x + r, 3.0, z - r),
                v(x + r, 3.0, z + r),
                v(x - r, 3.0, z + r),
                light,
            );
        }
    }
    if pillars {
        for x in [-2.5f32, 0.0, 2.5] {
            s.add_aabb(v(x - 0.3, 0.0, -1.8), v(x + 0.3, 2.2, -1.2), wall);
        }
    }
    s.camera = Some(Camera {
        position: v(0.0, 1.5, 7.0),
        target: v(0.0, 0.0, -2.0),
        up: Vec3::Y,
        fov_y: 55.0,
    });
    s
}

/// Issue 60, item 3: BSDF-sampled initial candidates (`bsdf_candidates`, seed 003's light BVH
/// for specular), MIS-combined with the light-sampled ones, on a metal floor of roughness 0.1
/// under 1,024 small lights, 64², initial candidates only (no reuse), 16 frames accumulated,
/// against the reference's direct light: with 2 BSDF candidates beside the 8 light candidates
/// the relMSE is at most 0.75 of the 8 alone, by power and by the light tree (whose importance
/// ignores the glossy lobe). Printed beside: 16 light candidates (no rays). Unbiased: on the
/// 36-light floor, 256 frames with them accumulate to the reference's energy within 2% (its own
/// 1,024 spp hold about 1%); and with pillars that hide lights from parts of the floor, with
/// the tree and the default reuse (temporal and spatial, 1/Z weights, which assume a reservoir
/// covers every light point its surface could see, visible or not: the BSDF candidates' rays
/// ignore occluders for that), 128 frames within 4% (the bound of the tree's candidates with
/// reuse in `regir_and_the_light_tree_help_many_lights_and_regir_is_skipped_for_cornell`).
#[test]
fn bsdf_candidates_find_glossy_highlights_without_bias() {
    let size = [64, 64];
    let flags = FLAG_NO_PRIMARY_EMISSION;
    // (relMSE, energy ratio, rays a frame); initial candidates alone unless `reuse`.
    let run = |scene: &Scene,
               truth: &Image,
               bsdf: i64,
               candidates: i64,
               tree: bool,
               frames: u32,
               reuse: bool| {
        let mut params: toml::Table = toml::toml! { accumulate = true
        gi = false
        regir = false
        candidates = candidates
        bsdf_candidates = bsdf
        light_tree = tree };
        if !reuse {
            params.insert("temporal".into(), false.into());
            params.insert("spatial_count".into(), 0.into());
        }
        let (img, rays) = render("restir", params, scene.clone(), size, frames, 1, flags);
        assert_eq!(img.non_finite_count(), 0);
        let m = metrics::compare(&img, truth).unwrap();
        (
            m.rel_mse,
            energy(&img) / energy(truth),
            rays.total() / frames as u64,
        )
    };
    let scene = glossy_floor_under_small_lights(0.1, 32, false);
    let truth = direct_truth(scene.clone(), size, 1024, 9, flags);
    for tree in [false, true] {
        let (light, _, light_rays) = run(&scene, &truth, 0, 8, tree, 16, false);
        let (mixed, _, mixed_rays) = run(&scene, &truth, 2, 8, tree, 16, false);
        let (more, _, more_rays) = run(&scene, &truth, 0, 16, tree, 16, false);
        eprintln!(
            "glossy floor, 1,024 lights, 16 frames, light candidates {}: 8 light relMSE {light:.4} ({light_rays} rays a frame), 8 light + 2 BSDF {mixed:.4} ({mixed_rays}), 16 light {more:.4} ({more_rays})",
            if tree { "by the tree" } else { "by power" }
        );
        assert!(
            mixed <= 0.75 * light,
            "BSDF candidates: relMSE {mixed} against {light} without (tree: {tree})"
        );
    }
    let scene = glossy_floor_under_small_lights(0.1, 6, false);
    let truth = direct_truth(scene.clone(), size, 1024, 9, flags);
    let (m, ratio, _) = run(&scene, &truth, 2, 8, false, 256, false);
    eprintln!("36 lights, 8 light + 2 BSDF candidates, 256 frames: energy {ratio:.4} of the reference, relMSE {m:.3e}");
    assert!((ratio - 1.0).abs() < 0.02, "energy ratio {ratio}");
    let scene = glossy_floor_under_small_lights(0.1, 6, true);
    let truth = direct_truth(scene.clone(), size, 1024, 9, flags);
    let (m, ratio, _) = run(&scene, &truth, 2, 8, true, 128, true);
    eprintln!("36 lights and pillars, 8 tree + 2 BSDF candidates with the default reuse, 128 frames: energy {ratio:.4} of the reference, relMSE {m:.3e}");
    assert!(
        (ratio - 1.0).abs() < 0.04,
        "energy ratio with reuse {ratio}"
    );
}

/// Issue 55 (honest accuracy), found while testing issue 60's BSDF candidates: ReSTIR DI at its
/// defaults (temporal and spatial reuse, unbiased weights; ReGIR, as the 72 emissive triangles
/// count as many lights) on a metal floor of roughness 0.1 with pillars under 36 small lights,
/// 64², 128 frames accumulated, against the reference's direct light. With 1/Z weights the
/// reuse turned glossy highlights into fireflies: energy 2.228 of the reference, relMSE 0.700
/// against 0.0247 without reuse (by power, no ReGIR: 0.849 and 0.109 against 0.0114). The
/// balance heuristic (spatial.wgsl) keeps the energy within 4% (the tree test's bound for
/// reuse) and the error within twice that of the initial candidates alone.
#[test]
fn restir_di_reuse_stays_unbiased_on_a_glossy_floor() {
    let size = [64, 64];
    let flags = FLAG_NO_PRIMARY_EMISSION;
    let scene = glossy_floor_under_small_lights(0.1, 6, true);
    let truth = direct_truth(scene.clone(), size, 1024, 9, flags);
    let run = |reuse: bool| {
        let mut params: toml::Table = toml::toml! { gi = false };
        if !reuse {
            params.insert("temporal".into(), false.into());
            params.insert("spatial_count".into(), 0.into());
        }
        let (img, _) = render("restir", params, scene.clone(), size, 128, 1, flags);
        assert_eq!(img.non_finite_count(), 0);
        let m = metrics::compare(&img, &truth).unwrap();
        (m.rel_mse, energy(&img) / energy(&truth))
    };
    let (alone, alone_energy) = run(false);
    let (reuse, reuse_energy) = run(true);
    eprintln!(
        "glossy floor with pillars, 128 frames: default reuse energy {reuse_energy:.4}, relMSE {reuse:.3e}; initial candidates alone energy {alone_energy:.4}, relMSE {alone:.3e}"
    );
    assert!(
        (reuse_energy - 1.0).abs() < 0.04,
        "energy with reuse {reuse_energy}"
    );
    assert!(
        reuse <= 2.0 * alone,
        "reuse relMSE {reuse} against {alone} without"
    );
}
