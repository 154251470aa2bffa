//! `gilab study` (issue 59): a tiny study (two scenes, three families, 32², four frames) writes a
//! report with every table, plot and number, every number finite; its numbers are the ones
//! `gilab converge` and `gilab bench --preset` give when run alone on the same settings; bad
//! study files fail with one line that says where.

use gilab::experiment::study::analysis;
use gilab::experiment::study::StudyReport;
use std::path::{Path, PathBuf};
use std::process::Command;

fn gilab(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_gilab"))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into(),
        String::from_utf8_lossy(&out.stderr).into(),
    )
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("gilab-study-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

const BUDGETS: [f64; 3] = [20.0, 80.0, 2000.0];

/// Two scenes (the diffuse Cornell box and its metal-box variant at roughness 0.3), three
/// families (the reference at 1 and 4 paths a frame, ReSTIR with and without the denoiser, the
/// surfels on the diffuse box only).
fn tiny_study(dir: &Path) -> PathBuf {
    let presets = std::fs::canonicalize("presets").unwrap();
    let text = format!(
        r#"
[study]
size = [32, 32]
frames = 4
reference_every = 2
reference_spp = 16
budgets_ms = [20, 80, 2000]

[[family]]
label = "reference"
technique = "reference"
denoise = [false]
[[family.variant]]
name = "default"
params = {{ samples_per_frame = 1 }}
[[family.variant]]
name = "rich"
params = {{ samples_per_frame = 4 }}

[[family]]
label = "restir"
technique = "restir"
[[family.variant]]
name = "default"

[[family]]
label = "surfels"
technique = "surfels"
denoise = [false]
[[family.variant]]
name = "default"

[[scene]]
name = "cornell"
preset = "{0}/cornell.toml"
effect = "diffuse"

[[scene]]
name = "metal"
preset = "{0}/cornell.toml"
effect = "metal 0.3"
set = ["scene.params.metal_boxes=0.3"]
families = ["reference", "restir"]
"#,
        presets.display()
    );
    let file = dir.join("tiny.toml");
    std::fs::write(&file, text).unwrap();
    file
}

fn png_size(path: &Path) -> (u32, u32) {
    let img = image::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    (img.width(), img.height())
}

#[test]
fn a_tiny_study_reports_every_table_plot_and_number_and_agrees_with_converge_and_bench() {
    let dir = tmp("tiny");
    let file = tiny_study(&dir);
    let out = dir.join("out");
    let cache = dir.join("cache");
    let started = std::time::Instant::now();
    let (ok, stdout, stderr) = gilab(&[
        "study",
        file.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--cache",
        cache.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(ok, "{stdout}\n{stderr}");
    println!(
        "tiny study: {:.1} s of wall time",
        started.elapsed().as_secs_f64()
    );
    let report: StudyReport =
        serde_json::from_str(&std::fs::read_to_string(out.join("study.json")).unwrap()).unwrap();
    assert_eq!(report.header.budgets_ms, BUDGETS);
    assert_eq!(report.header.runs, 5 + 4, "runs counted in the header");
    assert!(!report.header.git_commit.is_empty() && !report.header.adapter.name.is_empty());
    assert_eq!(report.scenes.len(), 2);
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    for heading in [
        "# Study `tiny`",
        "| adapter |",
        "| clocks |",
        "| commit |",
        "| command |",
        "| wall time |",
        "## Summary",
        "## Bias",
        "## Scene: cornell (diffuse)",
        "## Scene: metal (metal 0.3)",
        "## Files",
    ] {
        assert!(md.contains(heading), "report.md lacks '{heading}'");
    }
    // Runs per scene: families × settings × denoiser.
    let expected = [
        (
            "cornell",
            vec![
                "reference-default",
                "reference-rich",
                "restir-default",
                "restir-default-denoised",
                "surfels-default",
            ],
        ),
        (
            "metal",
            vec![
                "reference-default",
                "reference-rich",
                "restir-default",
                "restir-default-denoised",
            ],
        ),
    ];
    for (s, (name, labels)) in report.scenes.iter().zip(&expected) {
        assert_eq!(&s.name, name);
        let got: Vec<&str> = s.runs.iter().map(|r| r.label.as_str()).collect();
        assert_eq!(&got, labels);
        let bad = analysis::non_finite_numbers(s);
        assert!(bad.is_empty(), "non-finite numbers: {bad:?}");
        for r in &s.runs {
            assert!(
                r.ms_median > 0.0 && r.rays_per_pixel_per_frame > 0.0,
                "{r:?}"
            );
            assert!(
                r.energy.is_some() && r.rel_mse.is_some() && r.flip.is_some(),
                "{r:?}"
            );
            assert_eq!(r.scored_frames, 2, "{}: frames 1 and 3 scored", r.label);
            assert!(!r.passes.is_empty(), "{}: per-pass ms", r.label);
            assert!(
                md.contains(&format!("| {} |", r.label)),
                "{} not in the run table",
                r.label
            );
            assert!(out.join(&r.image).exists(), "{}", r.image);
        }
        // Picks: one per budget and curve; winners: one per budget.
        let curves = analysis::curves(&s.runs).len();
        assert_eq!(s.picks.len(), BUDGETS.len() * curves, "{name}");
        assert_eq!(s.winners.len(), BUDGETS.len(), "{name}");
        // The largest budget fits every run: its winner has the lowest error of all.
        let best = s
            .runs
            .iter()
            .filter_map(|r| r.error)
            .fold(f64::INFINITY, f64::min);
        assert_eq!(s.winners[2].error, Some(best), "{name}: 2 s fits every run");
        assert!(s.baseline.as_deref() == Some("reference-default"), "{name}");
        let families = if *name == "cornell" { 3 } else { 2 };
        assert_eq!(s.bias.len(), families, "{name}: one bias cell per family");
        for plot in ["study-pareto-rel_mse.png", "study-pareto-flip.png"] {
            let p = out.join("scenes").join(name).join(plot);
            assert_eq!(png_size(&p), (960, 640), "{}", p.display());
            assert!(
                md.contains(&format!("scenes/{name}/{plot}")),
                "{plot} not linked"
            );
        }
        assert!(out
            .join("scenes")
            .join(name)
            .join("experiment.toml")
            .exists());
    }
    // The equal-time images: one per scene and budget where a run fits, with their crops.
    assert!(report.images.len() >= 4, "{:?}", report.images);
    for img in &report.images {
        let (w, h) = png_size(&out.join(&img.image));
        assert!(
            w >= 192 * (img.runs.len() as u32 + 1) && h >= 2 * 192,
            "{}",
            img.image
        );
        let (cw, _) = png_size(&out.join(&img.crops));
        assert!(cw >= 192 * (img.runs.len() as u32 + 1), "{}", img.crops);
        assert!(md.contains(&img.image) && md.contains(&img.crops));
        assert!(img.heatmap_log10_range.0 < img.heatmap_log10_range.1);
    }
    // Every number of the CSVs parses as a finite number (or is empty: not applicable).
    for csv_file in ["runs.csv", "budgets.csv"] {
        let mut r = csv::Reader::from_path(out.join(csv_file)).unwrap();
        let headers = r.headers().unwrap().clone();
        let mut rows = 0;
        for rec in r.records() {
            let rec = rec.unwrap();
            rows += 1;
            for (h, v) in headers.iter().zip(rec.iter()) {
                if let Ok(x) = v.parse::<f64>() {
                    assert!(x.is_finite(), "{csv_file}: {h} = {v}");
                }
            }
        }
        let want = if csv_file == "runs.csv" {
            9
        } else {
            report.scenes.iter().map(|s| s.picks.len()).sum()
        };
        assert_eq!(rows, want, "{csv_file}");
    }

    // The same numbers from `gilab converge` run alone on the scene's experiment file: errors
    // identical (the runs are deterministic), times within lavapipe's timing noise.
    let alone = dir.join("alone");
    let experiment = out.join("scenes/cornell/experiment.toml");
    let (ok, stdout, stderr) = gilab(&[
        "converge",
        experiment.to_str().unwrap(),
        "--out",
        alone.to_str().unwrap(),
        "--cache",
        cache.to_str().unwrap(),
    ]);
    assert!(ok, "{stdout}\n{stderr}");
    let (summary, rows) = gilab::experiment::run::read_output_dir(&alone).unwrap();
    let study_scene = &report.scenes[0];
    for r in &study_scene.runs {
        let s = summary
            .runs
            .iter()
            .find(|s| s.spec.label == r.label)
            .unwrap();
        let mine: Vec<f64> = rows
            .iter()
            .filter(|x| x.run == s.spec.index)
            .map(|x| x.rel_mse)
            .collect();
        let median = gilab::experiment::run::median(mine).unwrap();
        println!(
            "{}: relMSE study {:.6} alone {median:.6}; ms study {:.2} alone {:.2}",
            r.label,
            r.rel_mse.unwrap(),
            r.ms_median,
            s.gpu_ms_median
        );
        assert_eq!(r.rel_mse, Some(median), "{}: the same error", r.label);
        assert_eq!(
            r.rays_per_pixel_per_frame, s.rays_per_pixel_per_frame,
            "{}: the same rays",
            r.label
        );
        let ratio = r.ms_median / s.gpu_ms_median;
        assert!(
            (1.0 / 3.0..3.0).contains(&ratio),
            "{}: study {:.2} ms against converge alone {:.2} ms",
            r.label,
            r.ms_median,
            s.gpu_ms_median
        );
    }

    // And `gilab bench --preset` on the same file: per-technique frame time.
    let json = dir.join("bench.json");
    let (ok, stdout, stderr) = gilab(&[
        "bench",
        "--preset",
        experiment.to_str().unwrap(),
        "--frames",
        "4",
        "--warmup",
        "1",
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(ok, "{stdout}\n{stderr}");
    let bench: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let bench = bench["techniques"]
        .as_array()
        .expect("a list of techniques");
    assert_eq!(bench.len(), study_scene.runs.len());
    for (b, r) in bench.iter().zip(&study_scene.runs) {
        let ms = b["frame_median_ms"].as_f64().unwrap();
        println!("{}: ms study {:.2} bench {ms:.2}", r.label, r.ms_median);
        assert_eq!(b["label"].as_str(), Some(r.label.as_str()));
        let ratio = r.ms_median / ms;
        assert!(
            (1.0 / 3.0..3.0).contains(&ratio),
            "{}: study {:.2} ms against bench {ms:.2} ms",
            r.label,
            r.ms_median
        );
    }
}

#[test]
fn bad_study_files_fail_with_one_line_that_says_where() {
    let dir = tmp("bad");
    let good = std::fs::read_to_string(tiny_study(&dir)).unwrap();
    let cases: Vec<(&str, String, &str)> = vec![
        (
            "syntax",
            good.replace("frames = 4", "frames = = 4"),
            "tiny.toml:4:",
        ),
        (
            "frames",
            good.replace("frames = 4", "frames = 5"),
            "multiple of reference_every",
        ),
        (
            "family",
            good.replace(
                r#"families = ["reference", "restir"]"#,
                r#"families = ["lumen"]"#,
            ),
            "no family is labelled 'lumen'",
        ),
        (
            "technique",
            good.replace(r#"technique = "surfels""#, r#"technique = "surfel""#),
            "family 'surfels'",
        ),
        (
            "parameter",
            good.replace("samples_per_frame = 4", "samples_per_frames = 4"),
            "variant 'rich'",
        ),
        (
            "scene parameter",
            good.replace("metal_boxes=0.3", "metal_boxes=3"),
            "scene 'metal'",
        ),
        (
            "budget",
            good.replace("[20, 80, 2000]", "[20, -1]"),
            "budgets must be positive",
        ),
    ];
    for (what, text, needle) in cases {
        let f = dir.join("tiny.toml");
        std::fs::write(&f, text).unwrap();
        let (ok, _, stderr) = gilab(&["study", f.to_str().unwrap(), "--out", "/nonexistent/x"]);
        assert!(!ok, "{what}: accepted");
        assert!(!stderr.contains("panicked"), "{what}: {stderr}");
        let errors: Vec<&str> = stderr.lines().filter(|l| l.starts_with("error")).collect();
        assert!(
            stderr.contains(needle),
            "{what}: '{needle}' not in: {stderr}"
        );
        assert!(!errors.is_empty(), "{what}: {stderr}");
    }
}

/// The shipped headline study parses and every family, setting and scene in it checks out
/// (techniques, parameters, presets, scene parameters), at its own size and at a CPU's.
#[test]
fn the_headline_study_file_checks_out() {
    use gilab::experiment::study::Study;
    let path = Path::new("presets/studies/headline.toml");
    let s = Study::load(path, None, 1.0).unwrap_or_else(|e| panic!("{e:#}"));
    assert_eq!(s.file.study.size, [1920, 1080]);
    assert_eq!(s.file.study.budgets_ms, [2.0, 4.0, 8.0, 16.0]);
    let runs: usize = s.file.scenes.iter().map(|sc| s.run_names(sc).len()).sum();
    let effects: Vec<&str> = s
        .file
        .scenes
        .iter()
        .filter_map(|sc| sc.effect.as_deref())
        .collect();
    println!(
        "headline: {} scenes, {runs} runs; effects {effects:?}",
        s.file.scenes.len()
    );
    for want in [
        "cornell",
        "many-lights",
        "courtyard",
        "metal",
        "mirror",
        "glossy",
        "moving",
    ] {
        assert!(s.file.scenes.iter().any(|sc| sc.name == want), "{want}");
    }
    let small = Study::load(path, Some([128, 72]), 50.0).unwrap();
    assert_eq!(small.file.study.budgets_ms, [100.0, 200.0, 400.0, 800.0]);
    assert_eq!(
        small
            .scene_preset(&small.file.scenes[0])
            .unwrap()
            .preset
            .render
            .size,
        [128, 72]
    );
}

/// The head of a small study for tests of the study's own behaviour: 16², 2 frames, the
/// reference alone. Its scenes follow; `{0}` in them is the presets folder.
const SMALL_STUDY: &str = r#"
[study]
size = [16, 16]
frames = 2
reference_every = 2
reference_spp = 4
budgets_ms = [1000]
denoise = [false]

[[family]]
label = "reference"
technique = "reference"
[[family.variant]]
name = "default"
params = { samples_per_frame = 1 }
"#;

/// Writes `SMALL_STUDY` with these scenes (`{presets}` in them is the presets folder) as
/// `dir/NAME.toml`; returns the file and its text.
fn small_study(dir: &Path, name: &str, scenes: &str) -> (PathBuf, String) {
    let presets = std::fs::canonicalize("presets").unwrap();
    let text = format!(
        "{SMALL_STUDY}\n{}",
        scenes.replace("{presets}", &presets.display().to_string())
    );
    let file = dir.join(format!("{name}.toml"));
    std::fs::write(&file, &text).unwrap();
    (file, text)
}

/// The study.json a study wrote into `out`.
fn read_report(out: &Path) -> StudyReport {
    serde_json::from_str(&std::fs::read_to_string(out.join("study.json")).unwrap()).unwrap()
}

/// A scene that fails while it runs (here: camera keys out of order, which only the experiment
/// checks) is reported in the study's report, and the other scenes still run.
#[test]
fn a_failing_scene_is_reported_and_the_study_goes_on() {
    let dir = tmp("failing");
    let (file, _) = small_study(
        &dir,
        "failing",
        r#"[[scene]]
name = "bad"
preset = "{presets}/cornell.toml"
[[scene.camera]]
frame = 1
position = [2.78, 2.73, -8.0]
target = [2.78, 2.73, 2.8]
[[scene.camera]]
frame = 0
position = [2.78, 2.73, -7.0]
target = [2.78, 2.73, 2.8]

[[scene]]
name = "good"
preset = "{presets}/cornell.toml"
"#,
    );
    let out = dir.join("out");
    let (ok, stdout, stderr) = gilab(&[
        "study",
        file.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--cache",
        dir.join("cache").to_str().unwrap(),
        "--quiet",
    ]);
    assert!(ok, "one scene ran: the study succeeds\n{stdout}\n{stderr}");
    assert!(stderr.contains("scene 'bad' failed"), "{stderr}");
    let report = read_report(&out);
    assert_eq!(report.scenes.len(), 1);
    assert_eq!(report.scenes[0].name, "good");
    assert_eq!(report.failed.len(), 1);
    assert_eq!(report.failed[0].0, "bad");
    assert!(
        report.failed[0].1.contains("frame order"),
        "{:?}",
        report.failed
    );
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.contains("Scene `bad` failed"), "{md}");
    assert!(!md.contains("Partial"), "every scene was tried: {md}");
}

/// A study cut short is continued with `--resume`: the scenes already in the report stay (not
/// rendered again), the others run, each invocation is a part of the header; a scene whose runs
/// all finished before the cut is read back, not rendered; a changed study file is refused.
#[test]
fn a_study_cut_short_is_resumed_without_rendering_its_scenes_again() {
    let dir = tmp("resume");
    let (file, text) = small_study(
        &dir,
        "resume",
        r#"[[scene]]
name = "first"
preset = "{presets}/cornell.toml"

[[scene]]
name = "second"
preset = "{presets}/cornell.toml"
set = ["scene.params.metal_boxes=0.3"]
"#,
    );
    let (out, cache) = (dir.join("out"), dir.join("cache"));
    let study = |extra: &[&str]| {
        let mut args = vec![
            "study",
            file.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--cache",
            cache.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        gilab(&args)
    };
    let read = || read_report(&out);
    let (ok, stdout, stderr) = study(&["--scenes", "first"]);
    assert!(ok, "{stdout}\n{stderr}");
    assert!(
        stdout.contains("scene 'second' skipped: not in --scenes"),
        "{stdout}"
    );
    let part1 = read();
    assert_eq!(part1.scenes.len(), 1);
    assert!(std::fs::read_to_string(out.join("report.md"))
        .unwrap()
        .contains("Partial"));
    let first = part1.scenes[0].clone();

    let (ok, stdout, stderr) = study(&["--resume"]);
    assert!(ok, "{stdout}\n{stderr}");
    assert!(
        stdout.contains("scene 'first' skipped: in the report already"),
        "{stdout}"
    );
    let both = read();
    assert_eq!(
        both.scenes
            .iter()
            .map(|s| s.name.as_str())
            .collect::<Vec<_>>(),
        ["first", "second"]
    );
    assert_eq!(
        both.scenes[0], first,
        "the kept scene is the earlier one, unchanged"
    );
    assert_eq!(both.header.parts.len(), 2);
    assert_eq!(both.header.parts[0].scenes, ["first"]);
    assert_eq!(both.header.parts[1].scenes, ["second"]);
    assert_eq!(both.header.runs, 2, "runs of both parts counted");
    assert!(
        both.header.wall_seconds > both.header.parts[1].wall_seconds,
        "wall time of both parts"
    );
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.contains("| part 2 |") && !md.contains("Partial"), "{md}");

    // Nothing left to run: the report stays as it is and the command succeeds.
    let (ok, stdout, stderr) = study(&["--resume"]);
    assert!(ok, "{stdout}\n{stderr}");
    assert!(stdout.contains("nothing to run"), "{stdout}");
    assert_eq!(read(), both, "the report is untouched");

    // A cut during the second scene's figures: its runs are on disk, not in the report. A note
    // on the first scene (its figures missing) must survive the resume.
    let mut cut = both.clone();
    cut.scenes.truncate(1);
    cut.images.retain(|i| i.scene == "first");
    cut.header.parts.truncate(1);
    cut.header.runs = 1;
    cut.header.wall_seconds = cut.header.parts[0].wall_seconds;
    cut.failed = vec![("first".into(), "its figures: a test note".into())];
    std::fs::write(
        out.join("study.json"),
        serde_json::to_string_pretty(&cut).unwrap(),
    )
    .unwrap();
    let (ok, stdout, stderr) = study(&["--resume"]);
    assert!(ok, "{stdout}\n{stderr}");
    assert!(stdout.contains("'second': its runs are in"), "{stdout}");
    let again = read();
    assert_eq!(
        again.scenes[1], both.scenes[1],
        "read back, the same numbers"
    );
    assert_eq!(again.header.parts[1].reused, ["second"]);
    assert_eq!(
        again.header.parts[1].reused_commits.len(),
        1,
        "the commit it was rendered at"
    );
    assert_eq!(
        again.header.runs, 2,
        "the read-back scene's run counted once"
    );
    assert_eq!(again.failed, cut.failed, "the note on the kept scene stays");
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.contains("Scene `first`, figures missing"), "{md}");

    // --scenes without --resume would replace the report by a subset: refused.
    let (ok, _, stderr) = study(&["--scenes", "second"]);
    assert!(!ok && stderr.contains("without --resume"), "{stderr}");

    // Another version of the study file is refused, naming the file.
    std::fs::write(
        &file,
        text.replace("reference_spp = 4", "reference_spp = 8"),
    )
    .unwrap();
    let (ok, _, stderr) = study(&["--resume"]);
    assert!(!ok);
    assert!(
        stderr.contains("another version of") && stderr.contains("resume.toml"),
        "{stderr}"
    );
    let (ok, _, stderr) = study(&["--scenes", "third"]);
    assert!(!ok && stderr.contains("no scene 'third'"), "{stderr}");
}
