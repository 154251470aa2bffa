//! The shared SVGF-style denoiser (src/render/denoise.rs) on lavapipe, small images: one 1-spp
//! reference frame of the Cornell box denoised against the same frame undenoised (relMSE
//! against a converged reference, energy), the temporal part over a few frames of a still
//! camera, no NaN/Inf on the hard cases (also after a camera move), and its passes in the
//! frame's GPU time.

mod common;

use common::{gpu, luminance};
use gilab::compare::{metrics, Image};
use gilab::gpu::shaders::ShaderLibrary;
use gilab::preset::{LoadedPreset, TechniqueEntry};
use gilab::render::{
    denoise, engine::Engine, engine::EngineSettings, engine::TimingSource, FLAG_NO_PRIMARY_EMISSION,
};
use gilab::scene::gpu_scene::GpuScene;
use std::path::Path;
use std::sync::Arc;

/// An engine for a technique entry on a preset's scene and camera at `size`, made the way every
/// preset entry's engine is (`Engine::for_entry`: `denoise = true` turns the denoiser on).
fn preset_engine(
    preset: &str,
    size: [u32; 2],
    seed: u32,
    technique: &str,
    params: toml::Table,
    denoise: bool,
) -> Engine {
    let p = LoadedPreset::load(Path::new(preset)).unwrap();
    let scene = p.load_scene().unwrap();
    let camera = p.camera(&scene);
    let gpu = gpu();
    let gpu_scene = Arc::new(GpuScene::upload(&gpu, &scene));
    let mut entry = TechniqueEntry::new(technique);
    entry.params = params;
    entry.denoise = denoise;
    let engine = Engine::for_entry(
        gpu,
        ShaderLibrary::discover(),
        Arc::new(scene),
        gpu_scene,
        &entry,
        EngineSettings {
            extent: size,
            seed,
            camera,
        },
    )
    .unwrap();
    assert_eq!(engine.denoise(), denoise);
    engine
}

fn reference_params(spf: u32) -> toml::Table {
    let mut t = toml::Table::new();
    t.insert("samples_per_frame".into(), (spf as i64).into());
    t
}

/// The converged Cornell box: `spp` samples per pixel of the reference path tracer (with
/// FrameUniforms `flags`), rendered once for this file's tests (the preset's camera is the
/// scene's own). Seed 1001: the frame-by-frame checks were measured against this truth.
/// The Cornell box's truth; the full image at 64² is the one other binaries share (halved from
/// 128²), so it is not rendered again.
fn cornell_truth(size: [u32; 2], spp: u32, flags: u32) -> Image {
    if size == [64, 64] && flags == 0 {
        return common::cornell_truth_64();
    }
    common::shared_reference(gilab::scene::builtin::cornell(), size, spp, 1001, 0, flags)
}

fn energy(img: &Image) -> f64 {
    luminance(img.mean())
}

fn rel_mse(img: &Image, truth: &Image) -> f64 {
    metrics::compare(img, truth).unwrap().rel_mse
}

/// One 1-spp reference frame from a reset (no history: only the spatial part can help),
/// denoised and not, against 512 spp from the same camera; the noisy image is the same
/// frame's own output before the filter (`read_noisy_output`), so both see the same samples.
/// Energy: each denoised frame within 2% of its own noisy frame (the filter's doing, held by
/// `targets::check`; the à-trous luminance weights take 1.3-1.45% off since they are symmetric,
/// 2.0-2.1% before, when they shrank bright samples more than they spread them), and the mean over four seeds within 2% of the converged reference (one 1-spp
/// frame's own mean is up to 4% off the reference's at 96x96, so a single frame against the
/// reference would test the frame's luck, not the filter).
#[test]
fn one_denoised_frame_beats_the_noisy_frame_on_cornell() {
    // 128² against the shared 512-spp truth: its own relMSE (about 1/512 of a 1-spp frame's) is
    // far under both errors compared here. (96² from 2026-11-26 because at 128² one seed's
    // filter energy change measured 2.07%, over the 2% bound: back at 128² for issue 55, where
    // it was an unmet target until the symmetric luminance weight of 2026-11-29.)
    let size = [128, 128];
    let truth = common::cornell_truth_128();
    let e_truth = energy(&truth);
    let mut e = preset_engine(
        "presets/cornell.toml",
        size,
        1,
        "reference",
        reference_params(1),
        true,
    );
    let seeds = 1..5u32;
    let (mut noisy_err, mut denoised_err) = (0.0, 0.0);
    let (mut noisy_energy, mut denoised_energy) = (0.0, 0.0);
    let mut worst_change: f64 = 0.0;
    for seed in seeds.clone() {
        e.seed = seed;
        e.reset();
        e.render_frame().unwrap();
        let denoised = e.read_output().unwrap();
        let noisy = e.read_noisy_output().unwrap().expect("denoiser on");
        assert_eq!(denoised.non_finite_count(), 0);
        let (rn, rd) = (rel_mse(&noisy, &truth), rel_mse(&denoised, &truth));
        let (en, ed) = (energy(&noisy), energy(&denoised));
        eprintln!(
            "cornell {}x{} 1 spp, seed {seed}: relMSE noisy {rn:.4}, denoised {rd:.4} ({:.1}x); \
             energy noisy/truth {:.4}, denoised/truth {:.4}, denoised/noisy {:.4}",
            size[0],
            size[1],
            rn / rd,
            en / e_truth,
            ed / e_truth,
            ed / en
        );
        assert!(rd < rn, "seed {seed}: denoised relMSE {rd} >= noisy {rn}");
        // What the filter itself does to the energy of the frame it filters.
        worst_change = worst_change.max((ed / en - 1.0).abs());
        noisy_err += rn;
        denoised_err += rd;
        noisy_energy += en;
        denoised_energy += ed;
    }
    let n = seeds.len() as f64;
    let (noisy_energy, denoised_energy) = (noisy_energy / n, denoised_energy / n);
    eprintln!(
        "cornell 1 spp over {n} seeds: relMSE noisy {:.4}, denoised {:.4}; energy noisy/truth \
         {:.4}, denoised/truth {:.4}, denoised/noisy {:.4}",
        noisy_err / n,
        denoised_err / n,
        noisy_energy / e_truth,
        denoised_energy / e_truth,
        denoised_energy / noisy_energy
    );
    assert!(
        denoised_err < 0.5 * noisy_err,
        "denoised relMSE {denoised_err} not half the noisy {noisy_err}"
    );
    let ratio = denoised_energy / e_truth;
    assert!(
        (ratio - 1.0).abs() < 0.02,
        "denoised energy {ratio:.4} of the converged reference's"
    );
    common::targets::check(
        "denoiser-one-frame-energy-change",
        common::targets::Better::Lower,
        0.02,
        worst_change,
        "worst |denoised / noisy energy - 1| of one 1-spp Cornell frame at 128², seeds 1-4",
    );
}

/// Eight frames of a still camera: the denoised image's error keeps falling. Twice: the
/// reference averaging its frames (the denoiser's history follows the technique's average)
/// and the reference showing one frame at a time (the paper's moving average, real time).
/// The real-time run leaves out the emission seen directly (in the reference too): the
/// denoiser adds each frame's own back unfiltered, as SVGF does, so the light's jittered
/// edge pixels (17 against a converged 0.7) would dominate the error frame by frame.
#[test]
fn temporal_accumulation_lowers_the_error_frame_by_frame() {
    let size = [64, 64];
    for accumulate in [true, false] {
        let flags = if accumulate {
            0
        } else {
            FLAG_NO_PRIMARY_EMISSION
        };
        // 512 spp without the emission seen directly (1,024 before 2026-11-26, for CI time): its
        // own relMSE, about 1/512 of a 1-spp frame's, is under 5% of the filter's bias.
        let truth = cornell_truth(size, 512, flags);
        let mut params = reference_params(1);
        params.insert("accumulate".into(), accumulate.into());
        let mut e = preset_engine("presets/cornell.toml", size, 3, "reference", params, true);
        e.flags = flags;
        let mut errors = Vec::new();
        let mut noisy_errors = Vec::new();
        for _ in 0..8 {
            e.render_frame().unwrap();
            errors.push(rel_mse(&e.read_output().unwrap(), &truth));
            noisy_errors.push(rel_mse(&e.read_noisy_output().unwrap().unwrap(), &truth));
        }
        let fmt = |v: &[f64]| {
            v.iter()
                .map(|x| format!("{x:.4}"))
                .collect::<Vec<_>>()
                .join(" ")
        };
        eprintln!(
            "cornell {}x{} reference accumulate={accumulate}, frames 1-8 relMSE: denoised [{}], \
             undenoised [{}]",
            size[0],
            size[1],
            fmt(&errors),
            fmt(&noisy_errors)
        );
        for (d, n) in errors.iter().zip(&noisy_errors) {
            assert!(d < n, "denoised {d} >= undenoised {n}");
        }
        if accumulate {
            // Falling frame by frame (within a little noise), as the technique's own average.
            for (i, pair) in errors.windows(2).enumerate() {
                assert!(
                    pair[1] < pair[0] * 1.05,
                    "frame {} relMSE {} after {}",
                    i + 2,
                    pair[1],
                    pair[0]
                );
            }
            assert!(
                errors[7] < 0.5 * errors[0],
                "frame 8 relMSE {} vs frame 1 {}",
                errors[7],
                errors[0]
            );
        } else {
            // The moving average holds about 9 frames and the filter keeps the strength the
            // per-sample variance asks for (the paper's design): the error falls over the
            // first frames, then stays at the filter's bias (about 0.014 at 64x64, against
            // 0.0185 for frame 1 and 0.2-0.28 undenoised).
            let late = errors[4..].iter().sum::<f64>() / 4.0;
            assert!(
                errors[1..].iter().all(|e| *e < errors[0]),
                "a later frame is worse than frame 1: {errors:?}"
            );
            assert!(
                late < 0.9 * errors[0],
                "frames 5-8 relMSE {late} vs frame 1 {}",
                errors[0]
            );
        }
    }
}

/// A technique that keeps accumulating converges denoised too: the denoiser's history follows
/// its average and the output is clamped to within a standard error of it from 16 samples
/// on, so the filter's blur does not stay as the noise falls (without the clamp the
/// denoised reference stopped at relMSE 0.016 while the undenoised one went on to 0.00035).
/// Four samples per frame: the surfaces share only the first sample's jitter.
#[test]
fn denoised_accumulation_converges_with_the_technique() {
    let size = [64, 64];
    let truth = cornell_truth(size, 1024, 0);
    let mut e = preset_engine(
        "presets/cornell.toml",
        size,
        5,
        "reference",
        reference_params(4),
        true,
    );
    let mut lines = Vec::new();
    for frame in 1..=64u32 {
        e.render_frame().unwrap();
        if ![1, 4, 16, 64].contains(&frame) {
            continue;
        }
        let d = rel_mse(&e.read_output().unwrap(), &truth);
        let n = rel_mse(&e.read_noisy_output().unwrap().unwrap(), &truth);
        lines.push(format!("{} spp: {d:.5} ({n:.5})", 4 * frame));
        if frame <= 16 {
            assert!(d < n, "{} spp: denoised {d} >= undenoised {n}", 4 * frame);
        } else {
            assert!(
                d < 1.5 * n,
                "{} spp: denoised {d} vs undenoised {n}",
                4 * frame
            );
        }
    }
    eprintln!(
        "cornell {}x{} reference 4 spp/frame, relMSE denoised (undenoised): {}",
        size[0],
        size[1],
        lines.join(", ")
    );
}

/// No NaN or Inf from the denoiser on the hard cases (degenerate triangles, zero normals,
/// emission 1e6), for the reference and ReSTIR in real-time mode, before and after a camera
/// move (reprojected history).
#[test]
fn denoiser_stays_finite_on_hard_cases() {
    let size = [48, 48];
    let restir: toml::Table = toml::toml! { accumulate = false };
    for (technique, params) in [("reference", reference_params(4)), ("restir", restir)] {
        let mut e = preset_engine("presets/hard-cases.toml", size, 1, technique, params, true);
        let mut camera = e.camera;
        let check = |e: &Engine, what: &str| {
            let img = e.read_output().unwrap();
            assert_eq!(
                img.non_finite_count(),
                0,
                "{technique} {what}: non-finite pixels"
            );
            let noisy = e.read_noisy_output().unwrap().unwrap();
            // The filter is a weighted average: nothing brighter than the brightest input
            // (plus the emission it adds back, which the input holds too).
            assert!(
                img.max_value() <= noisy.max_value() * 1.001 + 1e-3,
                "{technique} {what}: max {} > input max {}",
                img.max_value(),
                noisy.max_value()
            );
        };
        for i in 0..3 {
            e.render_frame().unwrap();
            check(&e, &format!("frame {i}"));
        }
        let step = (camera.target - camera.position).length() * 0.05;
        camera.position.x += step;
        camera.target.x += step;
        e.move_camera(camera);
        for i in 0..3 {
            e.render_frame().unwrap();
            check(&e, &format!("frame {i} after the move"));
        }
        eprintln!(
            "hard-cases {technique}: finite over 6 frames, mean {:.4e}",
            energy(&e.read_output().unwrap())
        );
    }
}

/// The denoiser's passes are timed inside the frame (so its time counts in the technique's
/// frame time), listed in `passes()`, and turning it off leaves the engine as it was.
#[test]
fn denoiser_passes_count_in_frame_time() {
    let size = [128, 128];
    let mut e = preset_engine(
        "presets/cornell.toml",
        size,
        1,
        "reference",
        reference_params(1),
        true,
    );
    let names = denoise::pass_names();
    let listed: Vec<&str> = e.passes().iter().map(|p| p.name).collect();
    for n in &names {
        assert!(listed.contains(n), "{n} missing from passes(): {listed:?}");
    }
    assert!(listed.contains(&"primary"), "{listed:?}");
    // Two frames first: lavapipe compiles a pipeline's code on its first dispatch.
    for _ in 0..2 {
        e.render_frame().unwrap();
    }
    let frames = 4;
    let mut by_pass = std::collections::BTreeMap::<String, f64>::new();
    let mut total = 0.0;
    // Without believable timestamps (lavapipe beside other work), the frames' wall times: the
    // denoised frames must take longer than the same frames without the denoiser (below).
    let mut timestamps = true;
    let mut wall_with = Vec::new();
    for _ in 0..frames {
        let r = e.render_frame().unwrap();
        wall_with.push(r.wall_ms);
        if r.timing != TimingSource::Timestamps {
            timestamps = false;
            continue;
        }
        for n in &names {
            assert!(
                r.gpu_ms_by_pass.iter().any(|(p, _)| p == n),
                "{n} not timed: {:?}",
                r.gpu_ms_by_pass
            );
        }
        let sum: f64 = r.gpu_ms_by_pass.iter().map(|p| p.1).sum();
        assert!(
            (sum - r.gpu_ms).abs() <= 1e-9 * sum.max(1.0),
            "{sum} vs {}",
            r.gpu_ms
        );
        for (p, ms) in &r.gpu_ms_by_pass {
            *by_pass.entry(p.clone()).or_default() += ms / frames as f64;
        }
        total += r.gpu_ms / frames as f64;
    }
    if timestamps {
        let denoise_ms: f64 = names.iter().map(|n| by_pass[*n]).sum();
        assert!(denoise_ms > 0.0);
        let list = by_pass
            .iter()
            .map(|(n, ms)| format!("{n} {ms:.2}"))
            .collect::<Vec<_>>()
            .join(", ");
        eprintln!(
            "cornell {}x{} reference 1 spp + denoiser, ms per frame: {total:.2} total, denoiser \
             {denoise_ms:.2}; by pass: {list}",
            size[0], size[1]
        );
    }
    // Rays: the denoiser's primary surfaces add one camera ray per pixel and frame.
    let with = e.ray_counts().unwrap().by_kind[0];
    let frames = frames + 2;
    e.set_denoise(false).unwrap();
    assert!(!e.denoise());
    let listed: Vec<&str> = e.passes().iter().map(|p| p.name).collect();
    assert!(!listed.contains(&"primary") && !listed.contains(&names[0]));
    let mut wall_without = Vec::new();
    for _ in 0..frames {
        wall_without.push(e.render_frame().unwrap().wall_ms);
    }
    if !timestamps {
        let median = |v: &mut Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        let (with_ms, without_ms) = (median(&mut wall_with), median(&mut wall_without));
        eprintln!(
            "no timestamps: cornell {}x{} reference 1 spp, median wall ms a frame with the denoiser {with_ms:.2}, without {without_ms:.2}",
            size[0], size[1]
        );
        assert!(
            with_ms > without_ms,
            "the denoiser's passes add no frame time: {with_ms} vs {without_ms} ms"
        );
    }
    let without = e.ray_counts().unwrap().by_kind[0];
    let pixels = (size[0] * size[1]) as u64;
    assert_eq!(with, without + frames as u64 * pixels);
    assert!(e.read_noisy_output().unwrap().is_none());
}
