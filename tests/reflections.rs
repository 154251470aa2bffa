//! Specular indirect light (issue 35): the reflections part (`src/parts/reflections.rs`) in
//! Lumen, the surfels and Callisto against the reference path tracer, which agrees with Mitsuba 3 on this scene
//! (tests/mitsuba.rs), on lavapipe at 64². The scene is the Mitsuba comparison's metal Cornell
//! box (tests/data/mitsuba/glossy.gltf: both boxes GGX metal with base colour 1, so F = 1) at
//! roughness 0.3 (glossy: traced), 0 (mirror) and 0.7 (rough: no rays, the albedo plane times
//! the gathered irradiance). Without reflections the boxes are black but for direct specular.

mod common;

use common::engine;
use gilab::compare::Image;
use gilab::render::RayCounts;
use gilab::scene::{builtin, gltf_load, Scene};

const SIZE: [u32; 2] = [64, 64];
const BLOCK: usize = 8;

fn metal_boxes(roughness: f32) -> Scene {
    let path = std::path::Path::new("tests/data/mitsuba/glossy.gltf");
    let mut s = gltf_load::load(path).unwrap();
    let mut metals = 0;
    for m in s.materials.iter_mut().filter(|m| m.metallic > 0.5) {
        m.roughness = roughness;
        metals += 1;
    }
    assert!(metals > 0, "the glossy scene has metal");
    s
}

fn truth(roughness: f32) -> Image {
    common::shared_reference(metal_boxes(roughness), SIZE, 512, 11, 0, 0)
}

/// How an image compares with the reference.
#[derive(Clone, Copy)]
struct Score {
    /// Image luminance over the reference's.
    energy: f64,
    /// Worst and mean relative luminance error of the 8×8 blocks the reference lights (block
    /// mean at least a tenth of the image mean).
    worst_block: f64,
    mean_block: f64,
}

fn score(img: &Image, truth: &Image) -> Score {
    let energy = common::luminance(img.mean()) / common::luminance(truth.mean());
    let w = img.width as usize;
    let lum = |im: &Image, x: usize, y: usize| {
        let p = im.pixel(x as u32, y as u32);
        common::luminance([p[0] as f64, p[1] as f64, p[2] as f64])
    };
    let mean = common::luminance(truth.mean());
    let mut worst: f64 = 0.0;
    let (mut sum, mut lit) = (0.0, 0);
    for by in 0..img.height as usize / BLOCK {
        for bx in 0..w / BLOCK {
            let (mut a, mut b) = (0.0, 0.0);
            for y in by * BLOCK..(by + 1) * BLOCK {
                for x in bx * BLOCK..(bx + 1) * BLOCK {
                    a += lum(img, x, y);
                    b += lum(truth, x, y);
                }
            }
            let n = (BLOCK * BLOCK) as f64;
            if b / n >= 0.1 * mean {
                worst = worst.max((a / b - 1.0).abs());
                sum += (a / b - 1.0).abs();
                lit += 1;
            }
        }
    }
    Score {
        energy,
        worst_block: worst,
        mean_block: sum / lit.max(1) as f64,
    }
}

/// Lumen at its shipped defaults (SDF tracing at 128³ clipmaps, screen probes, world radiance
/// cache, traced reflections) but for the surface cache's size and budgets: a 256² atlas (the
/// box needs no more texels at 64²) updated whole every frame, so that what is measured is the
/// reflections and not the cache's lag, and no debug views (they change no pixel). The surfels
/// at their defaults.
fn family_params(technique: &str) -> toml::Table {
    if technique == "lumen" {
        toml::toml! { atlas_size = 256
        indirect_texels_per_frame = 4194304
        direct_texels_per_frame = 4194304
        debug_views = false }
    } else {
        toml::Table::new()
    }
}

/// A technique accumulated over `frames` at SIZE from a cold start (fails on NaN/Inf samples).
fn render(technique: &str, scene: Scene, extra: toml::Table, frames: u32) -> (Image, RayCounts) {
    let mut params = family_params(technique);
    params.extend(extra);
    common::render_technique(technique, params, scene, SIZE, frames, 1, 0)
}

/// A cache family at SIZE: WARMUP frames (caches, surfels and temporal histories fill), then
/// the average restarts and `frames` are accumulated: what the converged technique shows.
fn render_converged(
    technique: &str,
    scene: Scene,
    extra: toml::Table,
    frames: u32,
) -> (Image, RayCounts) {
    let mut params = family_params(technique);
    params.extend(extra);
    let (img, rays, _) =
        common::render_after_warmup(technique, params, scene, SIZE, WARMUP, frames, 1);
    (img, rays)
}

const WARMUP: u32 = 12;

fn lumen(scene: Scene, extra: toml::Table, frames: u32) -> (Image, RayCounts) {
    render_converged("lumen", scene, extra, frames)
}

const FRAMES: u32 = 24;

/// The family's own bias: its score on the same box with Lambert boxes
/// (tests/data/mitsuba/cornell.gltf) against that box's reference; rendered once per family and
/// test binary.
fn diffuse_baseline(technique: &str) -> Score {
    static BASELINES: std::sync::Mutex<Vec<(String, Score)>> = std::sync::Mutex::new(Vec::new());
    let mut done = BASELINES.lock().unwrap_or_else(|e| e.into_inner());
    if let Some((_, s)) = done.iter().find(|(t, _)| t == technique) {
        return *s;
    }
    let lambert_path = std::path::Path::new("tests/data/mitsuba/cornell.gltf");
    let lambert = || gltf_load::load(lambert_path).unwrap();
    let lambert_truth = common::shared_reference(lambert(), SIZE, 512, 11, 0, 0);
    let (diffuse, _) = render_converged(technique, lambert(), toml::Table::new(), FRAMES);
    let s = score(&diffuse, &lambert_truth);
    done.push((technique.to_string(), s));
    s
}

/// Roughness 0.3: the boxes reflect the room. Against the reference: energy within 10%
/// (issue 55; issue 35's 5% energy and 25% worst block are printed beside). The family's own
/// bias on the same box with Lambert boxes (tests/data/mitsuba/cornell.gltf, its reference) is
/// printed too, and the metal box may lose at most 3% of the energy beyond it, and at most 0.06
/// of mean block error (without reflections the metal added 0.16 for Lumen, 0.10 for the
/// surfels): light that metal reflects onto the walls goes through the diffuse cache or
/// surfels, which spread it evenly (docs/reflections.md).
fn reflects_the_room_in_glossy_metal(technique: &str) {
    let baseline = diffuse_baseline(technique);

    let truth = truth(0.3);
    let (traced, rays) = render_converged(technique, metal_boxes(0.3), toml::Table::new(), FRAMES);
    let t = score(&traced, &truth);
    let px = (SIZE[0] * SIZE[1] * FRAMES) as f64;
    eprintln!(
        "{technique}, Lambert box (the family's own bias): energy {:.4}, blocks mean {:.3} worst {:.3}",
        baseline.energy, baseline.mean_block, baseline.worst_block
    );
    eprintln!(
        "{technique}, metal box, roughness 0.3, {FRAMES} frames: traced energy {:.4} (issue 35: within 5%), blocks mean {:.3} worst {:.3} (issue 35: 25%), {:.3} reflection rays/px/frame",
        t.energy,
        t.mean_block,
        t.worst_block,
        rays.kind("reflection") as f64 / px,
    );
    common::targets::check(
        match technique {
            "lumen" => "lumen-glossy-metal-energy",
            "surfels" => "surfels-glossy-metal-energy",
            _ => unreachable!("{technique}"),
        },
        common::targets::Better::Lower,
        0.10,
        (t.energy - 1.0).abs(),
        "|energy / reference - 1|, metal box at roughness 0.3",
    );
    assert!(
        t.energy > baseline.energy - 0.03,
        "{technique}: energy {} against the diffuse baseline {}",
        t.energy,
        baseline.energy
    );
    // The block error beyond the family's own. Without reflections it measured +0.163 (Lumen)
    // and +0.098 (surfels) on 2026-11-26, with them +0.027 and +0.028 (docs/reflections.md);
    // the run without them is no longer repeated here, for CI time.
    assert!(
        t.mean_block - baseline.mean_block < 0.06,
        "{technique}: mean block error: traced {} diffuse baseline {}",
        t.mean_block,
        baseline.mean_block
    );
    assert!(rays.kind("reflection") > 0);
}

#[test]
fn lumen_reflects_the_room_in_glossy_metal() {
    reflects_the_room_in_glossy_metal("lumen");
}

/// The same for surfels: reflection hits lit by NEE plus the surfels' irradiance there.
#[test]
fn surfels_reflect_the_room_in_glossy_metal() {
    reflects_the_room_in_glossy_metal("surfels");
}

/// Callisto (`callisto-shadows`, issue 35 item 4) with ReSTIR GI ending in the surface cache
/// (`gi = true`, `gi_terminate = "lumen-cards"`): `reflections = "traced"` lights the glossy
/// pixels by the reflections part (hits: one NEE sample plus the cache GI's paths end in), and
/// ReSTIR GI's sample then gives their diffuse share only. Against `none`, where the cosine-sampled
/// GI sample carries the glossy lobe too: lower relMSE against the reference, the same energy
/// within 3%, and within 5% of the reference.
/// Without GI, traced reflections add the room's direct light on the boxes.
#[test]
fn callisto_reflects_the_room_in_glossy_metal() {
    let truth = truth(0.3);
    let gi = || {
        toml::toml! { gi = true
        gi_terminate = "lumen-cards" }
    };
    // FRAMES of warm-up (the cache captures and relights its cards, a quarter a frame), then
    // FRAMES accumulated.
    let run = |reflections: &str, mut p: toml::Table| {
        p.insert("reflections".into(), reflections.into());
        let (img, rays, _) = common::render_after_warmup(
            "callisto-shadows",
            p,
            metal_boxes(0.3),
            SIZE,
            FRAMES,
            FRAMES,
            1,
        );
        (img, rays)
    };
    let (none, _) = run("none", gi());
    let (traced, rays) = run("traced", gi());
    let (n, t) = (score(&none, &truth), score(&traced, &truth));
    let rel = |img: &Image| {
        gilab::compare::metrics::compare(img, &truth)
            .unwrap()
            .rel_mse
    };
    let (rel_none, rel_traced) = (rel(&none), rel(&traced));
    let (direct_none, _) = run("none", toml::Table::new());
    let (direct_traced, _) = run("traced", toml::Table::new());
    let (dn, dt) = (score(&direct_none, &truth), score(&direct_traced, &truth));
    eprintln!(
        "callisto-shadows, metal box 0.3, {FRAMES} frames, GI into the surface cache: reflections none: energy {:.4}, relMSE {rel_none:.3e}, blocks mean {:.3}; traced: energy {:.4}, relMSE {rel_traced:.3e}, blocks mean {:.3}, {:.3} reflection rays/px/frame. Without GI: energy none {:.4}, traced {:.4}",
        n.energy,
        n.mean_block,
        t.energy,
        t.mean_block,
        rays.kind("reflection") as f64 / (SIZE[0] * SIZE[1] * FRAMES) as f64,
        dn.energy,
        dt.energy
    );
    assert!(rays.kind("reflection") > 0);
    assert!(
        rel_traced < rel_none,
        "relMSE traced {rel_traced} none {rel_none}"
    );
    assert!(
        (t.energy - n.energy).abs() < 0.03,
        "energy traced {} none {}",
        t.energy,
        n.energy
    );
    assert!((t.energy - 1.0).abs() < 0.05, "energy {}", t.energy);
    // Callisto's lighting reuse (`reflection_lighting = "screen"`): hits seen on screen last
    // frame take that pixel's output, so they trace no shadow ray, and carry the GI the family
    // computed there.
    let mut p = gi();
    p.insert("reflection_lighting".into(), "screen".into());
    let (screen, screen_rays) = run("traced", p);
    let sc = score(&screen, &truth);
    let rel_screen = rel(&screen);
    let per_px =
        |r: &RayCounts, kind: &str| r.kind(kind) as f64 / (SIZE[0] * SIZE[1] * FRAMES) as f64;
    eprintln!(
        "callisto-shadows, metal box 0.3, reflection_lighting = screen: energy {:.4}, relMSE {rel_screen:.3e}, blocks mean {:.3}; shadow rays/px/frame {:.4} against hit lighting's {:.4}",
        sc.energy,
        sc.mean_block,
        per_px(&screen_rays, "shadow"),
        per_px(&rays, "shadow"),
    );
    assert!(
        screen_rays.kind("shadow") < rays.kind("shadow"),
        "screen reuse traces fewer shadow rays"
    );
    assert!(
        (sc.energy - t.energy).abs() < 0.03,
        "energy screen {} hit {}",
        sc.energy,
        t.energy
    );
    assert!(
        rel_screen < 1.2 * rel_traced,
        "relMSE screen {rel_screen} hit {rel_traced}"
    );
    assert!(
        dt.energy > dn.energy + 0.01,
        "without GI: traced {} none {}",
        dt.energy,
        dn.energy
    );
    assert_eq!(traced.non_finite_count(), 0);
}

/// ReSTIR GI with BSDF-sampled directions (`gi_sampling = "bsdf"`, the default) against
/// cosine-sampled ones on the metal box at roughness 0.3, at equal rays (one GI path per pixel
/// either way): lower block error and relMSE against the reference, energy within 5%. The
/// mirror (roughness 0: its delta samples light their own pixel, emission along the mirror
/// kept) within 10%.
#[test]
fn restir_samples_the_glossy_lobe() {
    let truth = truth(0.3);
    let run = |sampling: &str, roughness: f32| {
        let p: toml::Table = toml::toml! { gi_sampling = sampling };
        render("restir", metal_boxes(roughness), p, FRAMES)
    };
    let px = (SIZE[0] * SIZE[1] * FRAMES) as f64;
    let mut results = Vec::new();
    for sampling in ["bsdf", "cosine"] {
        let (img, rays) = run(sampling, 0.3);
        let m = gilab::compare::metrics::compare(&img, &truth).unwrap();
        let sc = score(&img, &truth);
        eprintln!(
            "restir, metal box 0.3, {FRAMES} frames, gi_sampling = {sampling}: energy {:.4}, relMSE {:.3e}, blocks mean {:.3} worst {:.3}, {:.2} rays/px/frame",
            sc.energy,
            m.rel_mse,
            sc.mean_block,
            sc.worst_block,
            rays.total() as f64 / px
        );
        assert_eq!(img.non_finite_count(), 0);
        results.push((sc, m.rel_mse, rays.total() as f64 / px));
    }
    let ((bsdf, rel_bsdf, rays_bsdf), (cosine, rel_cosine, rays_cosine)) = (results[0], results[1]);
    // Measured 2026-11-27: blocks mean 0.058 against 0.096 (worst 0.31 against 0.72); relMSE
    // 9.18e-2 against 9.49e-2 (both mostly the darkest pixels' noise, the reference's included).
    assert!(
        bsdf.mean_block < 0.8 * cosine.mean_block,
        "blocks mean bsdf {} cosine {}",
        bsdf.mean_block,
        cosine.mean_block
    );
    assert!(
        rel_bsdf < rel_cosine,
        "relMSE bsdf {rel_bsdf} cosine {rel_cosine}"
    );
    assert!((bsdf.energy - 1.0).abs() < 0.05, "energy {}", bsdf.energy);
    assert!(
        (rays_bsdf / rays_cosine - 1.0).abs() < 0.05,
        "rays {rays_bsdf} {rays_cosine}"
    );
    let mirror_truth = self::truth(0.0);
    let (mirror, _) = run("bsdf", 0.0);
    let sm = score(&mirror, &mirror_truth);
    eprintln!(
        "restir, mirror box, {FRAMES} frames: energy {:.4}, blocks mean {:.3} worst {:.3}",
        sm.energy, sm.mean_block, sm.worst_block
    );
    assert!(
        (sm.energy - 1.0).abs() < 0.10,
        "mirror energy {}",
        sm.energy
    );
}

/// The white furnace (albedo 0.8, emission 1: radiance 5 everywhere inside) with a white metal
/// sphere in front of the camera. A mirror sphere (F = 1, roughness 0) is lossless, so the
/// image stays 5 everywhere: the reference within 1%, ReSTIR (BSDF-sampled GI; the mirror's
/// samples light their own pixels) within 3%. At roughness 0.3 single-scattering GGX loses a
/// little energy and the furnace is no longer flat: ReSTIR against the reference, within 3%.
/// Measured 2026-11-27: mirror reference 4.991, ReSTIR 4.946 (32 frames); roughness 0.3
/// reference 4.915, ReSTIR 4.829 (64 frames; 4.835 after 128; cosine-sampled GI 4.699).
/// (Lumen, the surfels and Callisto are not run here: their furnace biases are measured on the
/// plain furnace, and a mirror sphere in them shows what their reflection hits see.)
#[test]
fn metal_sphere_in_the_furnace() {
    use gilab::scene::Material;
    let furnace = |roughness: f32| {
        let mut s = builtin::furnace(0.8, 1.0, 1);
        let m = s.add_material(Material::glossy(
            "white metal",
            glam::Vec3::ONE,
            1.0,
            roughness,
        ));
        let centre = glam::Vec3::new(0.0, 0.0, -1.2);
        for [a, b, c] in builtin::icosphere(2) {
            s.add_triangle([centre + a * 0.5, centre + b * 0.5, centre + c * 0.5], m);
        }
        s
    };
    let size = [32, 32];
    let mean = |img: &Image| common::luminance(img.mean());
    let mirror_ref = common::shared_reference(furnace(0.0), size, 256, 11, 0, 0);
    let (mirror, _) =
        common::render_technique("restir", toml::Table::new(), furnace(0.0), size, 32, 1, 0);
    let rough_ref = common::shared_reference(furnace(0.3), size, 256, 11, 0, 0);
    let (rough, _) =
        common::render_technique("restir", toml::Table::new(), furnace(0.3), size, 64, 1, 0);
    eprintln!(
        "furnace with a white metal sphere, 32²: mirror: reference {:.4}, restir {:.4} (closed form 5); roughness 0.3: reference {:.4}, restir {:.4}",
        mean(&mirror_ref),
        mean(&mirror),
        mean(&rough_ref),
        mean(&rough)
    );
    assert!(
        (mean(&mirror_ref) / 5.0 - 1.0).abs() < 0.01,
        "reference {}",
        mean(&mirror_ref)
    );
    assert!(
        (mean(&mirror) / 5.0 - 1.0).abs() < 0.03,
        "restir {}",
        mean(&mirror)
    );
    assert!(
        (mean(&rough) / mean(&rough_ref) - 1.0).abs() < 0.03,
        "restir {} reference {}",
        mean(&rough),
        mean(&rough_ref)
    );
    assert_eq!(mirror.non_finite_count() + rough.non_finite_count(), 0);
}

/// The mirror (roughness 0: the delta lobe, emission along it) and rough metal (0.7: above
/// reflection_max_roughness, no rays) against the reference: energy within 10% (issue 55). Also
/// at most 3% below Lumen's own Lambert-box baseline (printed).
#[test]
fn lumen_mirror_and_rough_metal_keep_their_energy() {
    let baseline = diffuse_baseline("lumen");
    for (roughness, id) in [
        (0.0, "lumen-mirror-energy"),
        (0.7, "lumen-rough-metal-energy"),
    ] {
        let truth = truth(roughness);
        let (img, rays) = lumen(metal_boxes(roughness), toml::Table::new(), FRAMES);
        let s = score(&img, &truth);
        eprintln!(
            "metal box, roughness {roughness}: energy {:.4} (Lambert baseline {:.4}), blocks mean {:.3} worst {:.3}, {} reflection rays",
            s.energy,
            baseline.energy,
            s.mean_block,
            s.worst_block,
            rays.kind("reflection")
        );
        common::targets::check(
            id,
            common::targets::Better::Lower,
            0.10,
            (s.energy - 1.0).abs(),
            &format!("|energy / reference - 1|, Lumen, metal box at roughness {roughness}"),
        );
        assert!(
            s.energy > baseline.energy - 0.03,
            "roughness {roughness}: energy {} against the diffuse baseline {}",
            s.energy,
            baseline.energy
        );
        if roughness > 0.4 {
            assert_eq!(rays.kind("reflection"), 0, "rough lobes trace no rays");
        }
    }
}

/// Hard cases (roughness 0 and 1, metal, grazing views) stay finite with reflections on, and
/// a fixed seed gives the same image twice. The Cornell box (no specular layer) lists the
/// passes as skipped and traces no reflection ray.
#[test]
fn reflections_are_stable_deterministic_and_skipped_without_specular() {
    for technique in ["lumen", "surfels", "callisto-shadows"] {
        let run = || {
            // Default tracing (SDF for Lumen); a small atlas and no debug views, for CI time.
            let params = match technique {
                "lumen" => toml::toml! { atlas_size = 256
                debug_views = false },
                // Callisto's reflections are off by default (it is direct light alone).
                "callisto-shadows" => toml::toml! { reflections = "traced" },
                _ => toml::Table::new(),
            };
            common::render_after_warmup(
                technique,
                params,
                builtin::hard_cases(1e6),
                [32, 32],
                0,
                4,
                1,
            )
        };
        let (a, rays, _) = run();
        let (b, _, _) = run();
        assert_eq!(a.non_finite_count(), 0, "{technique}");
        assert_eq!(a.rgb, b.rgb, "{technique}: same seed, same image");
        assert!(
            rays.kind("reflection") > 0,
            "{technique}: hard cases have glossy metal"
        );
    }

    // The part's debug views in the surfels' and Callisto's lists show its rays and light on
    // the metal box (Lumen's, which need `debug_views`, are Lumen's planes 12 to 15).
    for technique in ["surfels", "callisto-shadows"] {
        let (_, _, e) = common::render_after_warmup(
            technique,
            toml::toml! { reflections = "traced" },
            metal_boxes(0.3),
            [32, 32],
            0,
            2,
            1,
        );
        let data = e.read_debug().unwrap().unwrap();
        for name in [
            "reflections: rays traced per pixel",
            "reflections: specular radiance (luminance)",
        ] {
            let view = e
                .technique
                .debug_views()
                .into_iter()
                .find(|v| v.name == name)
                .expect("the part's debug views are listed");
            let values = gilab::render::debug_channel(&data, 32 * 32, view.channel);
            assert!(
                values.iter().any(|&v| v > 0.0),
                "{technique}: view '{name}' is empty"
            );
        }
    }

    let mut e = engine("lumen", toml::Table::new(), builtin::cornell(), [16, 16], 1);
    let passes = e.passes();
    let trace = passes
        .iter()
        .find(|p| p.name == "reflection trace")
        .unwrap();
    assert!(!trace.runs, "{trace:?}");
    e.render_frame().unwrap();
    assert_eq!(e.ray_counts().unwrap().kind("reflection"), 0);
}

/// Multi-bounce specular paths (`specular_bounces`, the seed's funhouse mirrors): on the mirror
/// hall, ReSTIR GI paths that end in Lumen's surface cache at their first hit show the cache's
/// diffuse light where a mirror or glossy sphere is seen in the mirror wall or the metal floor.
/// Going through up to three specular hits first brings the image's energy closer to the
/// reference's, and the mirror-and-floor half of the image (lower rows) most.
#[test]
fn specular_paths_go_through_mirrors() {
    let scene = || builtin::mirror_hall(0.35);
    let truth = common::shared_reference(scene(), SIZE, 512, 11, 0, 0);
    let frames = 24;
    let run = |bounces: i64| {
        let p: toml::Table = toml::toml! {
            gi_terminate = "lumen-cards"
            specular_bounces = bounces
        };
        let (img, rays) = render("restir", scene(), p, frames);
        assert_eq!(img.non_finite_count(), 0);
        let px = (SIZE[0] * SIZE[1] * frames) as f64;
        (img, rays.total() as f64 / px)
    };
    // Mean luminance of the image's lower half (rgb rows top to bottom).
    let lower_half = |img: &Image| {
        let half = img.rgb.len() / 6 * 3;
        let lower = &img.rgb[half..];
        let s: f64 = lower
            .chunks_exact(3)
            .map(|p| common::luminance([p[0] as f64, p[1] as f64, p[2] as f64]))
            .sum();
        s / (lower.len() / 3) as f64
    };
    let e_truth = common::luminance(truth.mean());
    let half_truth = lower_half(&truth);
    let mut results = Vec::new();
    for bounces in [0i64, 3] {
        let (img, rays) = run(bounces);
        let energy = common::luminance(img.mean()) / e_truth;
        let half = lower_half(&img) / half_truth;
        eprintln!(
            "restir into lumen-cards, mirror hall, {frames} frames, specular_bounces = {bounces}: energy {energy:.4}, lower half {half:.4}, {rays:.2} rays/px/frame"
        );
        results.push((energy, half, rays));
    }
    let ((e0, h0, r0), (e3, h3, r3)) = (results[0], results[1]);
    assert!(e3 > e0 + 0.02, "energy {e0} -> {e3}");
    assert!(h3 > h0 + 0.04, "lower half {h0} -> {h3}");
    assert!(e3 < 1.03, "energy {e3} above the reference");
    assert!(r3 > r0, "specular bounces trace rays: {r0} -> {r3}");
}
