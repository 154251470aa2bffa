//! `gilab converge`: the error columns are right (FLIP against NVIDIA's published tool,
//! MSE/relMSE against `gilab compare`), runs are deterministic, shards merge to the unsharded
//! result, the reference's error falls as 1/N, and events give finite lag.

mod common;

use gilab::experiment::run::{self, ConvergeOptions, Row, Summary};
use gilab::experiment::Shard;
use gilab::preset::LoadedPreset;
use std::path::{Path, PathBuf};

fn tmp(name: &str) -> PathBuf {
    common::tmp_dir("converge", name)
}

fn cache() -> PathBuf {
    common::reference_cache("converge")
}

fn converge(p: &LoadedPreset, out: &Path, shard: Option<Shard>) -> (Summary, Vec<Row>) {
    common::converge_into("converge", p, out, shard).unwrap()
}

/// The error columns (and rays) of every row: what must not change between identical runs.
fn error_columns(rows: &[Row]) -> Vec<(usize, u32, u64, [u64; 4])> {
    rows.iter()
        .map(|r| {
            (
                r.run,
                r.frame,
                r.rays,
                [r.mse, r.rel_mse, r.smape, r.flip].map(f64::to_bits),
            )
        })
        .collect()
}

/// The image pair of tests/data (generated here) and its mean LDR-FLIP from NVIDIA's own
/// Python package `flip-evaluator` 1.7 (`flip_evaluator.evaluate(ref/255, test/255, "LDR")`,
/// default 67.02 pixels per degree): 0.09945804625749588.
fn flip_pair() -> (Vec<u8>, Vec<u8>) {
    let (w, h) = (64usize, 64usize);
    let (mut reference, mut test) = (Vec::new(), Vec::new());
    let mut s: u64 = 12345;
    for y in 0..h {
        for x in 0..w {
            let mut v = [(x * 4) % 256, (y * 4) % 256, ((x + y) * 2) % 256];
            if (16..40).contains(&x) && (20..44).contains(&y) {
                v = [230, 40, 40];
            }
            for c in v {
                s = (s * 1_103_515_245 + 12345) % (1 << 31);
                let n = ((s >> 16) % 41) as i64 - 20;
                reference.push(c as u8);
                test.push((c as i64 + n).clamp(0, 255) as u8);
            }
        }
    }
    (reference, test)
}

#[test]
fn flip_matches_nvidias_published_tool() {
    let _serial = common::serial();
    let (reference, test) = flip_pair();
    let flip = gilab::compare::flip::ldr_flip_srgb8(&test, &reference, 64, 64).unwrap();
    eprintln!("FLIP {flip:.6} against flip-evaluator 1.7's 0.099458");
    assert!((flip - 0.099_458).abs() < 1e-3, "FLIP {flip}");
    let same = gilab::compare::flip::ldr_flip_srgb8(&reference, &reference, 64, 64).unwrap();
    assert_eq!(same, 0.0);
}

const SMALL: &str = r#"
[scene]
source = "cornell"
params = { lamp = 0.0 }
[render]
size = [32, 32]
seed = 3
reference_spp = 64
[[techniques]]
name = "reference"
[[techniques]]
name = "restir"
params = { accumulate = true }
[experiment]
frames = 6
[[experiment.sweep]]
technique = "restir"
param = "budget"
values = [3, 12]
[[experiment.event]]
frame = 4
material = "lamp"
emissive = [30.0, 30.0, 30.0]
"#;

fn gilab_compare(image: &Path, reference: &Path) -> (f64, f64) {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_gilab"))
        .arg("compare")
        .arg(image)
        .arg(reference)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(out.status.success(), "{text}");
    let field = |name: &str| -> f64 {
        let mut it = text.split_whitespace();
        while let Some(w) = it.next() {
            if w == name {
                return it.next().unwrap().parse().unwrap();
            }
        }
        panic!("no {name} in {text}")
    };
    (field("MSE"), field("relMSE"))
}

#[test]
fn converge_columns_match_compare_are_deterministic_and_shards_merge() {
    let _serial = common::serial();
    let p = LoadedPreset::from_text(SMALL, None).unwrap();
    let a_dir = tmp("a");
    let (a, a_rows) = converge(&p, &a_dir, None);
    assert_eq!(a.runs.len(), 3, "reference + restir × 2 budgets");
    assert_eq!(a_rows.len(), 3 * 6);
    for f in [
        "convergence.csv",
        "summary.json",
        "report.md",
        "error_vs_time.png",
        "error_vs_rays.png",
        "error_vs_frame.png",
        "pareto.png",
    ] {
        assert!(a_dir.join(f).exists(), "{f} missing");
    }
    // Budgets map to different settings, hence different rays per pixel.
    let rpp: Vec<f64> = a.runs.iter().map(|r| r.rays_per_pixel_per_frame).collect();
    assert!(
        rpp[2] > rpp[1],
        "budget 12 turns GI on, budget 3 cannot afford it: {rpp:?}"
    );

    // The last frame's EXR, compared with `gilab compare`, gives the CSV's numbers.
    for run in &a.runs {
        let last = a_rows
            .iter()
            .filter(|r| r.run == run.spec.index)
            .max_by_key(|r| r.frame)
            .unwrap();
        let reference = a_dir.join(format!("runs/reference-state{}.exr", last.state));
        let (mse, rel) = gilab_compare(&a_dir.join(&run.image), &reference);
        for (cli, csv) in [(mse, last.mse), (rel, last.rel_mse)] {
            assert!(
                (cli - csv).abs() <= 1e-5 * csv.abs() + 1e-12,
                "{}: compare {cli} vs CSV {csv}",
                run.spec.label
            );
        }
    }

    // Same seed, same adapter: identical error columns.
    let (_, b_rows) = converge(&p, &tmp("b"), None);
    assert_eq!(error_columns(&a_rows), error_columns(&b_rows));

    // Two shards merged give the unsharded error columns and analysis errors.
    let s0 = tmp("s0");
    let s1 = tmp("s1");
    converge(&p, &s0, Some(Shard { index: 0, count: 2 }));
    converge(&p, &s1, Some(Shard { index: 1, count: 2 }));
    let merged_dir = tmp("merged");
    run::merge(&[s0, s1], &merged_dir).unwrap();
    let (m, m_rows) = run::read_output_dir(&merged_dir).unwrap();
    assert_eq!(error_columns(&a_rows), error_columns(&m_rows));
    // Per-run results too (the analysis's equal-time columns depend on timings, which differ
    // from run to run, so they are not compared).
    let finals = |s: &Summary| -> Vec<(String, [u64; 4], f64)> {
        s.runs
            .iter()
            .map(|r| {
                (
                    r.spec.label.clone(),
                    [r.final_mse, r.final_rel_mse, r.final_smape, r.final_flip].map(f64::to_bits),
                    r.rays_per_pixel_per_frame,
                )
            })
            .collect()
    };
    assert_eq!(finals(&a), finals(&m));
    assert!(merged_dir.join("report.md").exists());

    // The lamp switched on at frame 4: every run reports a lag entry with its errors.
    assert_eq!(a.analysis.lag.len(), 3);
}

/// An unbiased estimator's expected error falls as 1/N. One run's log-log slope is too noisy to
/// show it (over seeds it ranged from -0.80 to -1.11 at 32², 64 frames: relMSE follows a few
/// bright pixels), so the slope is fitted to the relMSE averaged over 8 seeds against one
/// reference: its expected value is 1/N up to the reference's own noise (4,096 spp here). (16
/// seeds before 2026-11-26, for CI time: the mean's noise grows by √2, to about a third of the
/// ±0.1 bound.)
#[test]
fn reference_error_falls_as_one_over_n() {
    let _serial = common::serial();
    let text = r#"
[scene]
source = "cornell"
[render]
size = [32, 32]
seed = 5
reference_spp = 4096
[[techniques]]
name = "reference"
params = { samples_per_frame = 1 }
[experiment]
frames = 64
seeds = [1, 2, 3, 4, 5, 6, 7, 8]
"#;
    let p = LoadedPreset::from_text(text, None).unwrap();
    let (summary, rows) = converge(&p, &tmp("slope"), None);
    assert_eq!(summary.runs.len(), 8);
    let mut by_frame = std::collections::BTreeMap::<u32, (f64, usize)>::new();
    for r in &rows {
        let e = by_frame.entry(r.frame).or_default();
        e.0 += r.rel_mse;
        e.1 += 1;
    }
    // Least-squares slope of log mean relMSE against log frames.
    let pts: Vec<(f64, f64)> = by_frame
        .iter()
        .map(|(f, (sum, n))| ((*f as f64).ln(), (sum / *n as f64).ln()))
        .collect();
    let n = pts.len() as f64;
    let (mx, my) = (
        pts.iter().map(|p| p.0).sum::<f64>() / n,
        pts.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let slope = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum::<f64>()
        / pts.iter().map(|p| (p.0 - mx).powi(2)).sum::<f64>();
    eprintln!("slope of log mean relMSE (8 seeds) vs log frames: {slope:.3}");
    assert!((-1.1..=-0.9).contains(&slope), "slope {slope}");
}

#[test]
#[ignore = "slow tier, not run by CI (docs/testing.md#slow-tier): the lag experiment on every technique, 116 s in CI"]
fn lag_experiment_settles_for_every_technique() {
    let _serial = common::serial();
    let mut p = LoadedPreset::load(Path::new("presets/experiments/lag-light-on.toml")).unwrap();
    // The shipped experiment, smaller: 32², event at frame 12 of 40.
    p.preset.render.size = [32, 32];
    p.preset.render.reference_spp = 256;
    let exp = p.preset.experiment.as_mut().unwrap();
    exp.frames = 40;
    exp.events[0].frame = 12;
    // Caches sized to the image, as the shipped 96² runs are (for CI time, 2026-11-26): the
    // surfels' rays per frame scaled by the pixel count (65,536 at 96² is 7 per pixel, so about
    // as many per surfel), Lumen's atlas to 512² and no debug views.
    for t in &mut p.preset.techniques {
        match t.name.as_str() {
            "surfels" => {
                t.params.insert("ray_budget".into(), 8192.into());
            }
            "lumen" => {
                t.params.insert("atlas_size".into(), 512.into());
                t.params.insert("debug_views".into(), false.into());
            }
            _ => {}
        }
    }
    let (s, _) = converge(&p, &tmp("lag"), None);
    assert_eq!(s.analysis.lag.len(), s.runs.len());
    for l in &s.analysis.lag {
        eprintln!(
            "{}: {} -> {}, settles in {:?} frames",
            l.label, l.error_before, l.error_after, l.settle_frames
        );
        assert!(
            l.error_after > l.error_before,
            "{}: the switch must show as error",
            l.label
        );
        assert!(l.settle_frames.is_some(), "{} never settled", l.label);
    }
}

#[test]
fn bad_experiments_fail_with_clear_errors() {
    let _serial = common::serial();
    let bad_material = SMALL.replace("material = \"lamp\"", "material = \"lmap\"");
    let p = LoadedPreset::from_text(&bad_material, None).unwrap();
    let opts = ConvergeOptions {
        out: tmp("bad"),
        cache: cache(),
        shard: None,
        quiet: true,
    };
    let e = run::converge(common::gpu(), &p, &opts)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("no material 'lmap'") && e.contains("lamp"),
        "{e}"
    );

    let bad_sweep = SMALL.replace(
        "technique = \"restir\"\nparam",
        "technique = \"restr\"\nparam",
    );
    let p = LoadedPreset::from_text(&bad_sweep, None).unwrap();
    let e = run::converge(common::gpu(), &p, &opts)
        .unwrap_err()
        .to_string();
    assert!(e.contains("'restr'"), "{e}");

    let typo = SMALL.replace("frames = 6", "frame = 6");
    let e = LoadedPreset::from_text(&typo, None)
        .unwrap_err()
        .to_string();
    assert!(e.contains(":") && e.contains("frame"), "{e}");
}

/// Scoring must not change what is scored or how long frames take: errors every frame and
/// every 8th frame are bit-identical at the shared frames, the median GPU ms per frame agrees
/// within 10% on a GPU (at least one pair compared; on a CPU adapter the times are printed:
/// lavapipe's vary by tens of percent between runs), and every run carries its clock check
/// (calibration kernel before and after).
#[test]
fn scoring_every_frame_or_every_eighth_gives_the_same_errors_and_times() {
    let _serial = common::serial();
    let text = r#"
[scene]
source = "cornell"
[render]
size = [64, 64]
seed = 5
reference_spp = 32
[[techniques]]
name = "reference"
params = { samples_per_frame = 2 }
[[techniques]]
name = "restir"
params = { accumulate = true }
[experiment]
frames = 32
"#;
    let every = |n: u32| {
        let p = LoadedPreset::from_text(
            &text.replace("frames = 32", &format!("frames = 32\nerror_every = {n}")),
            None,
        )
        .unwrap();
        converge(&p, &tmp(&format!("every{n}")), None)
    };
    let (s1, rows1) = every(1);
    let (s8, rows8) = every(8);
    assert_eq!(rows1.len(), 2 * 32);
    assert_eq!(rows8.len(), 2 * 4, "frames 8, 16, 24, 32 of each run");
    for r8 in &rows8 {
        let r1 = rows1
            .iter()
            .find(|r| r.run == r8.run && r.frame == r8.frame)
            .expect("shared frame");
        assert_eq!(
            [r1.mse, r1.rel_mse, r1.smape, r1.flip].map(f64::to_bits),
            [r8.mse, r8.rel_mse, r8.smape, r8.flip].map(f64::to_bits),
            "{} frame {}",
            r8.label,
            r8.frame
        );
        assert_eq!(r1.rays, r8.rays);
    }
    // Times: each configuration runs twice more, interleaved (every frame, every 8th, every
    // frame, every 8th), and the fastest comparable median of each side is compared, so that
    // the shared host slowing down under one run (seen on CI's 2-core lavapipe machine: +14%
    // between two back-to-back runs whose clock checks both passed) does not decide. Runs
    // whose calibration kernel drifted are flagged by the protocol as not comparable; runs
    // with frames the engine timed by the wall clock (`TimingSource::judge`: timestamps it did
    // not believe) measure the host more than the scoring. Neither is compared.
    let (s1b, rows1b) = every(1);
    let (s8b, rows8b) = every(8);
    let comparable = |run: &run::RunSummary, rows: &[Row]| {
        let walled = rows
            .iter()
            .filter(|r| r.run == run.spec.index && r.timing != "timestamps")
            .count();
        println!(
            "  {} (error_every {}): median GPU ms/frame {:.3} (mean {:.3}); {}{}",
            run.spec.label,
            if rows.len() > 8 { 1 } else { 8 },
            run.gpu_ms_median,
            run.gpu_ms_per_frame,
            run.clock_check.summary(),
            if walled > 0 {
                format!("; {walled} frames timed by the wall clock")
            } else {
                String::new()
            }
        );
        assert!(run.clock_check.kernel_ms_before > 0.0 && run.clock_check.kernel_ms_after > 0.0);
        assert_eq!(run.clock_check.flagged, run.clock_check.drift.abs() > 0.10);
        (!run.clock_check.flagged && walled == 0).then_some(run.gpu_ms_median)
    };
    // On a CPU adapter (lavapipe) no pair can be held to 10%: the same configuration's median
    // frame time moved from 29 to 42 ms between back-to-back runs on CI's 2-core machine
    // (2026-11-28), and the calibration kernel by -53% to +11%. There the times are printed,
    // not compared (docs/known-issues.md); on a GPU at least one pair must be compared.
    let cpu = common::gpu().adapter.get_info().device_type == wgpu::DeviceType::Cpu;
    // Pairs whose times were compared: a run that compared none has checked no time at all.
    let mut compared = 0;
    for k in 0..s1.runs.len() {
        let fastest = |sides: [(&Summary, &[Row]); 2]| {
            sides
                .iter()
                .filter_map(|(s, rows)| comparable(&s.runs[k], rows))
                .min_by(f64::total_cmp)
        };
        let m1 = fastest([(&s1, &rows1), (&s1b, &rows1b)]);
        let m8 = fastest([(&s8, &rows8), (&s8b, &rows8b)]);
        let label = &s1.runs[k].spec.label;
        match (m1, m8) {
            (Some(m1), Some(m8)) => {
                println!(
                    "{label}: fastest comparable median every frame {m1:.3}, every 8th {m8:.3} ms"
                );
                if cpu {
                    continue;
                }
                compared += 1;
                assert!(
                    (m8 / m1 - 1.0).abs() <= 0.10,
                    "{label}: {m1} vs {m8} ms/frame"
                );
            }
            _ => println!("{label}: no comparable run on one side, times not compared"),
        }
    }
    if cpu {
        println!("CPU adapter: times printed, not compared (they vary by tens of percent between runs here)");
    } else {
        assert!(
            compared > 0,
            "no run's times were compared (every pair flagged or timed by the wall clock)"
        );
    }
}

/// A time budget with sparse scoring (error_every > 1 and seconds) keeps the last frames in a
/// ring whose slots are reached out of order; this combination used to index past the ring.
#[test]
fn time_budget_with_sparse_scoring_runs() {
    let _serial = common::serial();
    let text = r#"
[scene]
source = "cornell"
[render]
size = [32, 32]
seed = 2
reference_spp = 16
[[techniques]]
name = "reference"
params = { samples_per_frame = 1 }
[experiment]
frames = 40
seconds = 0.2
error_every = 3
"#;
    let p = LoadedPreset::from_text(text, None).unwrap();
    let (summary, rows) = converge(&p, &tmp("sparse-seconds"), None);
    assert_eq!(summary.runs.len(), 1);
    assert!(!rows.is_empty());
    assert!(rows
        .iter()
        .all(|r| r.frame % 3 == 0 || r.frame == rows.last().unwrap().frame));
}
