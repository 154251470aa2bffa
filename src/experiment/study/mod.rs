//! `gilab study FILE`: what accuracy costs in time, for every family, in one command. Each
//! scene of the study file is one real-time `converge` experiment (families × settings × with
//! and without the denoiser, per-frame references); the study reads their outputs back and
//! writes one report folder: a summary page, per scene the Pareto plots, a table per budget,
//! the equal-time images with heatmaps and crops, a bias table across the effect scenes, and
//! every number as CSV and JSON.

pub mod analysis;
pub mod figures;
pub mod markdown;
pub mod spec;

pub use spec::{Study, StudyFile};

use crate::experiment::run::{self, ConvergeOptions};
use crate::gpu::Gpu;
use analysis::SceneResult;
use anyhow::{Context, Result};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::Arc;

pub struct StudyOptions {
    pub out: PathBuf,
    pub cache: PathBuf,
    pub quiet: bool,
    /// Continue the report already in `out` (a study cut short by a time limit): its finished
    /// scenes are kept, the others run.
    pub resume: bool,
    /// Run only these scenes now (empty: all). With `resume`, the report keeps the others it
    /// already has.
    pub scenes: Vec<String>,
}

/// One invocation that added scenes to a report: a study cut short and resumed has several.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct StudyPart {
    pub command: String,
    pub git_commit: String,
    pub date_utc: String,
    pub wall_seconds: f64,
    pub scenes: Vec<String>,
    /// Scenes of `scenes` whose runs an earlier invocation finished (cut short while drawing
    /// their figures): this one read them back and rendered nothing for them.
    #[serde(default)]
    pub reused: Vec<String>,
    /// The commit each of `reused` was rendered at (its `converge` summary's).
    #[serde(default)]
    pub reused_commits: Vec<String>,
}

/// Where and when the study ran: the report's header.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct Header {
    pub study: String,
    pub file: String,
    pub file_sha256: String,
    pub command: String,
    pub date_utc: String,
    pub git_commit: String,
    pub adapter: crate::gpu::AdapterSummary,
    /// Graphics clocks seen before and after the runs (MHz, or "unknown").
    pub clocks: Vec<String>,
    /// Runs whose clock check failed, of all runs.
    pub clock_flagged: usize,
    pub runs: usize,
    /// Largest |drift| of the calibration kernel over a run.
    pub max_clock_drift: f64,
    pub size: [u32; 2],
    pub frames: u32,
    pub reference_every: u32,
    pub reference_spp: u32,
    pub budgets_ms: Vec<f64>,
    pub metric: String,
    pub wall_seconds: f64,
    /// Scenes in the study file: more than `scenes` holds while the study runs, or when it was
    /// cut short.
    pub scenes_planned: usize,
    /// The invocations that made the report, in order (one unless it was resumed). The fields
    /// above are the last one's, `wall_seconds` and the run counts the sum of all.
    #[serde(default)]
    pub parts: Vec<StudyPart>,
}

/// `study.json`: the header and every scene's result.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct StudyReport {
    pub header: Header,
    pub scenes: Vec<SceneResult>,
    /// Per scene and budget: the equal-time picture and its crops, relative to the report.
    pub images: Vec<EqualTimeImage>,
    /// Scenes that failed, with why.
    #[serde(default)]
    pub failed: Vec<(String, String)>,
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct EqualTimeImage {
    pub scene: String,
    pub budget_ms: f64,
    pub image: String,
    pub crops: String,
    /// Per family, the run shown (its best within the budget).
    pub runs: Vec<String>,
    pub heatmap_log10_range: (f32, f32),
    /// x, y, side of the crop in pixels.
    pub crop: (u32, u32, u32),
}

/// Days since 1970-01-01 to a civil date (Howard Hinnant's algorithm): no date crate needed
/// for one header line.
fn date_utc() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs()) as i64;
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1_460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02} {:02}:{:02} UTC",
        rem / 3600,
        (rem % 3600) / 60
    )
}

/// Runs every scene of the study and writes the report into `opts.out`.
pub fn run_study(gpu: Arc<Gpu>, study: &Study, opts: &StudyOptions) -> Result<StudyReport> {
    let started = std::time::Instant::now();
    let s = &study.file.study;
    std::fs::create_dir_all(&opts.out)
        .with_context(|| format!("creating {}", opts.out.display()))?;
    for name in &opts.scenes {
        anyhow::ensure!(
            study.file.scenes.iter().any(|sc| &sc.name == name),
            "--scenes: the study has no scene '{name}' (it has {})",
            study
                .file
                .scenes
                .iter()
                .map(|sc| sc.name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    anyhow::ensure!(
        opts.resume || opts.scenes.is_empty() || !opts.out.join("study.json").exists(),
        "--scenes without --resume would replace the report in {} by these scenes alone: add --resume to add them to it, or choose another --out",
        opts.out.display()
    );
    let chosen = |name: &str| opts.scenes.is_empty() || opts.scenes.iter().any(|n| n == name);
    let file_sha256 = run::sha256_hex(&std::fs::read_to_string(&study.path).unwrap_or_default());
    // The report so far: an earlier invocation's (--resume) or an empty one.
    let mut report = if opts.resume {
        previous_report(study, s, &file_sha256, &opts.out)?
    } else {
        StudyReport::default()
    };
    // A note on a scene in the report (its figures) stays; a failed scene that runs again
    // loses its old failure.
    let kept: Vec<String> = report.scenes.iter().map(|x| x.name.clone()).collect();
    report
        .failed
        .retain(|(n, _)| kept.contains(n) || !chosen(n.as_str()));
    // Times from two devices do not belong in one report.
    let timed_on = (!report.scenes.is_empty()).then(|| report.header.adapter.clone());
    let earlier_wall = report.header.wall_seconds;
    let parts = report.header.parts.clone();
    let mut part = StudyPart {
        command: std::env::args().collect::<Vec<_>>().join(" "),
        git_commit: run::git_commit(),
        date_utc: date_utc(),
        ..Default::default()
    };
    let mut changed = false;
    // Stamps this invocation into the header and writes the report.
    let save = |report: &mut StudyReport, part: &StudyPart| -> Result<()> {
        stamp_header(
            report,
            study,
            &file_sha256,
            part,
            &parts,
            earlier_wall,
            started,
        );
        write_report(study, report, &opts.out)
    };
    for (i, sc) in study.file.scenes.iter().enumerate() {
        let done_before = report.scenes.iter().any(|x| x.name == sc.name);
        if done_before || !chosen(sc.name.as_str()) {
            if !opts.quiet {
                let why = if done_before {
                    "in the report already"
                } else {
                    "not in --scenes"
                };
                println!("study {}: scene '{}' skipped: {why}", study.name, sc.name);
            }
            continue;
        }
        if !opts.quiet {
            println!(
                "study {}: scene {}/{} '{}'",
                study.name,
                i + 1,
                study.file.scenes.len(),
                sc.name
            );
        }
        let p = study.scene_preset(sc)?;
        let dir = opts.out.join("scenes").join(&sc.name);
        std::fs::create_dir_all(&dir)?;
        let options = ConvergeOptions {
            out: dir.clone(),
            cache: opts.cache.clone(),
            shard: None,
            quiet: opts.quiet,
        };
        // Resuming: a scene whose runs all finished before the cut (the study stopped while it
        // drew the scene's figures) is read back, not rendered again.
        let finished = if opts.resume {
            finished_scene(&dir, &p)?
        } else {
            None
        };
        if let Some((summary, _)) = &finished {
            part.reused.push(sc.name.clone());
            part.reused_commits.push(summary.git_commit.clone());
            if !opts.quiet {
                println!(
                    "study {}: scene '{}': its runs are in {} already (an earlier invocation's): read back",
                    study.name,
                    sc.name,
                    dir.display()
                );
            }
        } else {
            if let Some(a) = timed_on.as_ref().filter(|a| a.name != gpu.summary.name) {
                anyhow::bail!(
                    "--resume: the report's runs were timed on {} and this adapter is {}: times from two devices do not belong in one report (choose another --out)",
                    a.name,
                    gpu.summary.name
                );
            }
            std::fs::write(dir.join("experiment.toml"), &p.text)?;
        }
        // A scene that fails (a technique refusing the scene, a GPU fault) is reported and the
        // study goes on: a long device run keeps the other scenes.
        let done = match finished {
            Some(x) => Ok(x),
            None => {
                run::converge(gpu.clone(), &p, &options).and_then(|_| run::read_output_dir(&dir))
            }
        };
        changed = true;
        let (summary, rows) = match done {
            Ok(x) => x,
            Err(e) => {
                let why = format!("{e:#}");
                eprintln!("study {}: scene '{}' failed: {why}", study.name, sc.name);
                report.failed.push((sc.name.clone(), why));
                continue;
            }
        };
        let h = &mut report.header;
        for r in &summary.runs {
            h.runs += 1;
            h.clock_flagged += usize::from(r.clock_check.flagged);
            h.max_clock_drift = h.max_clock_drift.max(r.clock_check.drift.abs());
            for c in [&r.clock_check.clock_before, &r.clock_check.clock_after] {
                if !h.clocks.contains(c) {
                    h.clocks.push(c.clone());
                }
            }
        }
        h.clocks.sort();
        h.adapter = summary.adapter.clone();
        let names = study.run_names(sc);
        let result = analysis::scene_result(study, sc, &names, &summary, &rows);
        match scene_figures(study, &result, &summary, &opts.out) {
            Ok(v) => report.images.extend(v),
            Err(e) => report.failed.push((
                sc.name.clone(),
                if part.reused.contains(&sc.name) {
                    format!("its equal-time images: {e:#} (its runs were read back from an invocation cut short; their images and references stayed where it ran)")
                } else {
                    format!("its figures: {e:#}")
                },
            )),
        }
        report.scenes.push(result);
        // The study file's order, whichever invocation ran a scene.
        let order = |n: &str| study.file.scenes.iter().position(|x| x.name == n);
        report.scenes.sort_by_key(|x| order(&x.name));
        report.images.sort_by_key(|x| order(&x.scene));
        part.scenes.push(sc.name.clone());
        // The report so far: a study cut short (a device call's time limit) keeps its scenes.
        save(&mut report, &part)?;
        if !opts.quiet {
            println!(
                "study {}: scene '{}' done, {:.0} s so far",
                study.name, sc.name, report.header.wall_seconds
            );
        }
    }
    anyhow::ensure!(
        !report.scenes.is_empty(),
        "every scene failed: {}",
        report
            .failed
            .iter()
            .map(|(s, e)| format!("{s}: {e}"))
            .collect::<Vec<_>>()
            .join("; ")
    );
    if changed {
        // The last word: failures after the last finished scene, and this invocation's time.
        save(&mut report, &part)?;
    } else if !opts.quiet {
        println!(
            "study {}: nothing to run: every chosen scene is in the report already",
            study.name
        );
    }
    Ok(report)
}

/// The header's fields of this invocation: the study, the last part's command, commit and date,
/// and the wall time of every part (this one's up to now).
fn stamp_header(
    report: &mut StudyReport,
    study: &Study,
    file_sha256: &str,
    part: &StudyPart,
    earlier_parts: &[StudyPart],
    earlier_wall: f64,
    started: std::time::Instant,
) {
    let s = &study.file.study;
    let mut part = part.clone();
    part.wall_seconds = started.elapsed().as_secs_f64();
    let h = &mut report.header;
    h.study = study.name.clone();
    h.file = study.path.display().to_string();
    h.file_sha256 = file_sha256.to_string();
    h.command = part.command.clone();
    h.date_utc = part.date_utc.clone();
    h.git_commit = part.git_commit.clone();
    h.size = s.size;
    h.frames = s.frames;
    h.reference_every = s.reference_every;
    h.reference_spp = s.reference_spp;
    h.budgets_ms = s.budgets_ms.clone();
    h.metric = s.metric.name().to_string();
    h.wall_seconds = earlier_wall + part.wall_seconds;
    h.scenes_planned = study.file.scenes.len();
    h.parts = earlier_parts.to_vec();
    h.parts.push(part);
}

/// A scene's `converge` output that an earlier invocation finished: every planned run is in it
/// and it was made from this scene's preset (by content). None when it is absent or partial.
fn finished_scene(
    dir: &Path,
    p: &crate::preset::LoadedPreset,
) -> Result<Option<(run::Summary, Vec<crate::experiment::rows::Row>)>> {
    if !dir.join("summary.json").exists() {
        return Ok(None);
    }
    let (summary, rows) = match run::read_output_dir(dir) {
        Ok(x) => x,
        Err(e) => {
            // Cut while it was written, or from another version of gilab: render it again.
            log::warn!(
                "{}: not read back ({e:#}): the scene runs again",
                dir.display()
            );
            return Ok(None);
        }
    };
    let same_preset = summary.preset_sha256 == run::sha256_hex(&p.to_toml()?);
    let complete = summary.total_runs > 0 && summary.runs.len() == summary.total_runs;
    Ok((same_preset && complete).then_some((summary, rows)))
}

/// The report a resumed study continues: the same study file (by content) at the same size
/// and budgets, else the scenes would not belong in one report.
fn previous_report(
    study: &Study,
    s: &spec::StudySettings,
    file_sha256: &str,
    out: &Path,
) -> Result<StudyReport> {
    let path = out.join("study.json");
    let text = std::fs::read_to_string(&path).with_context(|| {
        format!(
            "--resume: reading {} (run the study without --resume first)",
            path.display()
        )
    })?;
    let mut prev: StudyReport = serde_json::from_str(&text)
        .with_context(|| format!("--resume: {} is not a study report", path.display()))?;
    let h = &prev.header;
    anyhow::ensure!(
        h.file_sha256 == file_sha256,
        "--resume: {} was made from another version of {} (SHA-256 {} against {})",
        path.display(),
        study.path.display(),
        &h.file_sha256[..h.file_sha256.len().min(16)],
        &file_sha256[..file_sha256.len().min(16)]
    );
    anyhow::ensure!(
        h.size == s.size && h.frames == s.frames && h.budgets_ms == s.budgets_ms,
        "--resume: {} ran at {}x{}, {} frames, budgets {:?}; this run would be {}x{}, {} frames, budgets {:?}",
        path.display(),
        h.size[0],
        h.size[1],
        h.frames,
        h.budgets_ms,
        s.size[0],
        s.size[1],
        s.frames,
        s.budgets_ms
    );
    if prev.header.parts.is_empty() {
        // A report from before parts were recorded: its header is its one part.
        prev.header.parts.push(StudyPart {
            command: h.command.clone(),
            git_commit: h.git_commit.clone(),
            date_utc: h.date_utc.clone(),
            wall_seconds: h.wall_seconds,
            scenes: prev.scenes.iter().map(|x| x.name.clone()).collect(),
            ..Default::default()
        });
    }
    Ok(prev)
}

/// Per scene: the two Pareto plots and, per budget, the equal-time images.
fn scene_figures(
    study: &Study,
    s: &SceneResult,
    summary: &run::Summary,
    out: &Path,
) -> Result<Vec<EqualTimeImage>> {
    let budgets = &study.file.study.budgets_ms;
    let dir = out.join("scenes").join(&s.name);
    figures::pareto(
        &dir.join("study-pareto-rel_mse.png"),
        s,
        budgets,
        "relMSE",
        |r| r.rel_mse,
    )?;
    figures::pareto(
        &dir.join("study-pareto-flip.png"),
        s,
        budgets,
        "FLIP",
        |r| r.flip,
    )?;
    // The reference of the last frame, which every run's last image is compared with.
    let last = study.file.study.frames - 1;
    let reference = summary
        .references
        .iter()
        .find(|r| r.frame == Some(last))
        .with_context(|| format!("scene '{}': no reference for frame {last}", s.name))?;
    let reference = crate::compare::io::read_exr(Path::new(&reference.cache_file))
        .with_context(|| format!("reading the reference {}", reference.cache_file))?;
    let mut images = Vec::new();
    for &b in budgets {
        // Per family, its best run within the budget (with or without the denoiser).
        let mut shown: Vec<(String, crate::compare::Image)> = Vec::new();
        let mut labels = Vec::new();
        for family in s
            .bias
            .iter()
            .map(|x| x.family.clone())
            .chain(s.runs.iter().map(|r| r.family.clone()))
        {
            if labels.iter().any(|(f, _): &(String, String)| *f == family) {
                continue;
            }
            let best = s
                .runs
                .iter()
                .filter(|r| r.family == family && r.ms_median <= b && r.error.is_some())
                .min_by(|x, y| x.error.unwrap().total_cmp(&y.error.unwrap()));
            if let Some(r) = best {
                labels.push((family, r.label.clone()));
                shown.push((
                    format!("{} ({:.2} ms)", r.label, r.ms_median),
                    figures::read_image(out, &r.image)?,
                ));
            }
        }
        if shown.is_empty() {
            continue;
        }
        let stem = format!("equal-time-{}ms", budget_text(b));
        let image = dir.join(format!("{stem}.png"));
        let crops = dir.join(format!("{stem}-crops.png"));
        let (range, crop) =
            figures::equal_time(&image, &crops, &reference, &shown, &summary.tonemap)?;
        images.push(EqualTimeImage {
            scene: s.name.clone(),
            budget_ms: b,
            image: format!("scenes/{}/{stem}.png", s.name),
            crops: format!("scenes/{}/{stem}-crops.png", s.name),
            runs: labels.into_iter().map(|l| l.1).collect(),
            heatmap_log10_range: range,
            crop,
        });
    }
    Ok(images)
}

/// A budget as file-name text: 4 → "4", 0.5 → "0.5".
pub fn budget_text(b: f64) -> String {
    let t = format!("{b}");
    t.trim_end_matches(".0").to_string()
}

/// `report.md`, `study.json`, `runs.csv` and `budgets.csv`.
fn write_report(study: &Study, report: &StudyReport, out: &Path) -> Result<()> {
    std::fs::write(
        out.join("study.json"),
        serde_json::to_string_pretty(report)?,
    )?;
    let mut w = csv::Writer::from_path(out.join("runs.csv"))?;
    for s in &report.scenes {
        for r in &s.runs {
            w.serialize(analysis::RunCsv::from(r))?;
        }
    }
    w.flush()?;
    let mut w = csv::Writer::from_path(out.join("budgets.csv"))?;
    for s in &report.scenes {
        for p in &s.picks {
            w.serialize(p)?;
        }
    }
    w.flush()?;
    std::fs::write(out.join("report.md"), markdown::report(study, report))?;
    Ok(())
}
