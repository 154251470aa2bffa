//! What a study's runs say, computed from each scene's `convergence.csv` and `summary.json`
//! alone: per run its median frame time and per-frame errors, per family a curve of error
//! against time, per budget the best setting that fits, the energy each family keeps, and the
//! winner of each budget.

use super::spec::{RunName, Study, StudyScene};
use crate::experiment::rows::{Row, Summary};
use crate::experiment::run::median;
use crate::experiment::Metric;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// One run of one scene, summarised over its scored frames.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct StudyRun {
    pub scene: String,
    pub label: String,
    pub family: String,
    pub variant: String,
    pub denoise: bool,
    /// Median GPU ms over all the run's frames; mean too.
    pub ms_median: f64,
    pub ms_mean: f64,
    pub rays_per_pixel_per_frame: f64,
    /// Mean over the scored frames of the frame's mean luminance over its reference's.
    pub energy: Option<f64>,
    /// Medians over the scored frames of each frame's own error.
    pub rel_mse: Option<f64>,
    pub flip: Option<f64>,
    pub smape: Option<f64>,
    /// The study's metric (one of the above).
    pub error: Option<f64>,
    pub flicker_ratio: Option<f64>,
    pub clock_flagged: bool,
    /// `timestamps`, or `wall` where any scored frame was timed by the wall clock (the adapter's
    /// timestamps missing or implausible).
    pub timing: String,
    pub non_finite_pixels: usize,
    pub scored_frames: usize,
    /// Mean GPU ms per frame of each pass.
    pub passes: BTreeMap<String, f64>,
    /// The last frame's image, relative to the report folder.
    pub image: String,
}

/// The best run of one curve (a family, with or without the denoiser) within a budget.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct BudgetPick {
    pub scene: String,
    pub budget_ms: f64,
    pub family: String,
    pub denoise: bool,
    /// None: even the cheapest variant takes longer than the budget.
    pub run: Option<String>,
    pub cheapest_ms: f64,
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Winner {
    pub scene: String,
    pub budget_ms: f64,
    /// Label of the run with the lowest error that fits (None: nothing fits).
    pub run: Option<String>,
    pub error: Option<f64>,
    /// The next-best family's run, and how much higher its error is.
    pub runner_up: Option<String>,
    pub runner_up_ratio: Option<f64>,
}

/// A family's energy on one scene, at its `default` variant (else its first) without the
/// denoiser.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Bias {
    pub scene: String,
    pub effect: String,
    pub family: String,
    pub run: String,
    pub energy: Option<f64>,
    /// |energy − 1| within the study's tolerance.
    pub within: Option<bool>,
}

/// Everything the report says about one scene.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct SceneResult {
    pub name: String,
    pub effect: String,
    pub runs: Vec<StudyRun>,
    pub picks: Vec<BudgetPick>,
    pub winners: Vec<Winner>,
    pub bias: Vec<Bias>,
    /// The reference at one path per pixel per frame without the denoiser, where the study
    /// has it: the baseline line of the plots.
    pub baseline: Option<String>,
    /// The scored frames' references (frame, spp).
    pub references: usize,
    pub reference_spp: u32,
    /// Runs whose clock check failed (times less comparable).
    pub clock_flagged: usize,
}

fn mean(v: impl Iterator<Item = f64>) -> Option<f64> {
    let (mut s, mut n) = (0.0, 0usize);
    for x in v.filter(|x| x.is_finite()) {
        s += x;
        n += 1;
    }
    (n > 0).then(|| s / n as f64)
}

pub fn metric_of(r: &StudyRun, m: Metric) -> Option<f64> {
    match m {
        Metric::RelMse => r.rel_mse,
        Metric::Flip => r.flip,
        Metric::Smape => r.smape,
        // MSE is not kept per run: relMSE is the study's absolute measure.
        Metric::Mse => r.rel_mse,
    }
}

/// Summarises one scene's converge output.
pub fn scene_result(
    study: &Study,
    sc: &StudyScene,
    names: &[RunName],
    summary: &Summary,
    rows: &[Row],
) -> SceneResult {
    let metric = study.file.study.metric;
    let mut runs = Vec::new();
    for r in &summary.runs {
        let Some(name) = names.iter().find(|n| n.label == r.spec.label) else {
            continue;
        };
        let mine: Vec<&Row> = rows.iter().filter(|x| x.run == r.spec.index).collect();
        let rel_mse = median(mine.iter().map(|x| x.rel_mse).collect());
        let flip = median(mine.iter().map(|x| x.flip).collect());
        let smape = median(mine.iter().map(|x| x.smape).collect());
        let mut run = StudyRun {
            scene: sc.name.clone(),
            label: r.spec.label.clone(),
            family: name.family.clone(),
            variant: name.variant.clone(),
            denoise: name.denoise,
            ms_median: r.gpu_ms_median,
            ms_mean: r.gpu_ms_per_frame,
            rays_per_pixel_per_frame: r.rays_per_pixel_per_frame,
            energy: mean(mine.iter().filter_map(|x| x.energy)),
            rel_mse,
            flip,
            smape,
            error: None,
            flicker_ratio: r.flicker_ratio,
            clock_flagged: r.clock_check.flagged,
            timing: if mine.iter().any(|x| x.timing != "timestamps") {
                "wall".into()
            } else {
                "timestamps".into()
            },
            non_finite_pixels: r.non_finite_pixels,
            scored_frames: mine.len(),
            passes: r.gpu_ms_by_pass.clone(),
            image: format!("scenes/{}/{}", sc.name, r.image),
        };
        run.error = metric_of(&run, metric);
        runs.push(run);
    }
    let budgets = &study.file.study.budgets_ms;
    let mut picks = Vec::new();
    for &b in budgets {
        for (family, denoise) in curves(&runs) {
            let curve: Vec<&StudyRun> = runs
                .iter()
                .filter(|r| r.family == family && r.denoise == denoise)
                .collect();
            let best = curve
                .iter()
                .filter(|r| r.ms_median <= b && r.error.is_some())
                .min_by(|x, y| x.error.unwrap().total_cmp(&y.error.unwrap()));
            picks.push(BudgetPick {
                scene: sc.name.clone(),
                budget_ms: b,
                family,
                denoise,
                run: best.map(|r| r.label.clone()),
                cheapest_ms: curve
                    .iter()
                    .map(|r| r.ms_median)
                    .fold(f64::INFINITY, f64::min),
            });
        }
    }
    let winners = budgets.iter().map(|&b| winner(sc, &runs, b)).collect();
    let effect = sc.effect.clone().unwrap_or_else(|| sc.name.clone());
    let tolerance = study.file.study.bias_tolerance;
    let mut bias = Vec::new();
    for f in study.families_of(sc) {
        let pick = |name: &str| {
            runs.iter()
                .find(|r| r.family == f.label && !r.denoise && r.variant == name)
        };
        let run = f
            .variants
            .iter()
            .find(|v| v.name == "default")
            .or(f.variants.first())
            .and_then(|v| pick(&v.name));
        if let Some(run) = run {
            bias.push(Bias {
                scene: sc.name.clone(),
                effect: effect.clone(),
                family: f.label.clone(),
                run: run.label.clone(),
                energy: run.energy,
                within: run.energy.map(|e| (e - 1.0).abs() <= tolerance),
            });
        }
    }
    // The reference technique at one path per pixel a frame, without the denoiser.
    let baseline = summary
        .runs
        .iter()
        .filter(|s| s.spec.technique == "reference" && !s.spec.denoise)
        .find(|s| {
            s.params
                .get("samples_per_frame")
                .and_then(|v| v.as_integer())
                == Some(1)
        })
        .and_then(|s| runs.iter().find(|r| r.label == s.spec.label))
        .map(|r| r.label.clone());
    SceneResult {
        name: sc.name.clone(),
        effect,
        clock_flagged: runs.iter().filter(|r| r.clock_flagged).count(),
        runs,
        picks,
        winners,
        bias,
        baseline,
        references: summary.references.len(),
        reference_spp: summary.references.first().map_or(0, |r| r.spp),
    }
}

/// The curves of a scene: (family, denoiser) in the order the runs come.
pub fn curves(runs: &[StudyRun]) -> Vec<(String, bool)> {
    let mut v: Vec<(String, bool)> = Vec::new();
    for r in runs {
        if !v.iter().any(|(f, d)| *f == r.family && *d == r.denoise) {
            v.push((r.family.clone(), r.denoise));
        }
    }
    v
}

/// The lowest-error run within `budget`, and the best run of another family.
fn winner(sc: &StudyScene, runs: &[StudyRun], budget: f64) -> Winner {
    let mut fits: Vec<&StudyRun> = runs
        .iter()
        .filter(|r| r.ms_median <= budget && r.error.is_some())
        .collect();
    fits.sort_by(|x, y| x.error.unwrap().total_cmp(&y.error.unwrap()));
    let first = fits.first();
    let second = first.and_then(|w| fits.iter().find(|r| r.family != w.family));
    Winner {
        scene: sc.name.clone(),
        budget_ms: budget,
        run: first.map(|r| r.label.clone()),
        error: first.and_then(|r| r.error),
        runner_up: second.map(|r| r.label.clone()),
        runner_up_ratio: match (first, second) {
            (Some(a), Some(b)) if a.error.unwrap() > 0.0 => {
                Some(b.error.unwrap() / a.error.unwrap())
            }
            _ => None,
        },
    }
}

/// Every number of a scene result is finite where present (the CI study checks this).
pub fn non_finite_numbers(s: &SceneResult) -> Vec<String> {
    let mut bad = Vec::new();
    for r in &s.runs {
        let mut check = |what: &str, v: Option<f64>| {
            if v.is_some_and(|v| !v.is_finite()) {
                bad.push(format!("{} {}: {what}", s.name, r.label));
            }
        };
        check("ms_median", Some(r.ms_median));
        check("ms_mean", Some(r.ms_mean));
        check("rays_per_pixel_per_frame", Some(r.rays_per_pixel_per_frame));
        check("energy", r.energy);
        check("rel_mse", r.rel_mse);
        check("flip", r.flip);
        check("smape", r.smape);
        check("flicker_ratio", r.flicker_ratio);
        for (p, ms) in &r.passes {
            check(&format!("pass {p}"), Some(*ms));
        }
    }
    bad
}

/// A row of `runs.csv`: a run with its passes as `name=ms;name=ms`.
#[derive(Clone, Debug, Serialize)]
pub struct RunCsv {
    pub scene: String,
    pub label: String,
    pub family: String,
    pub variant: String,
    pub denoise: bool,
    pub ms_median: f64,
    pub ms_mean: f64,
    pub rays_per_pixel_per_frame: f64,
    pub energy: Option<f64>,
    pub rel_mse: Option<f64>,
    pub flip: Option<f64>,
    pub smape: Option<f64>,
    pub flicker_ratio: Option<f64>,
    pub clock_flagged: bool,
    pub timing: String,
    pub non_finite_pixels: usize,
    pub scored_frames: usize,
    pub passes: String,
    pub image: String,
}

impl From<&StudyRun> for RunCsv {
    fn from(r: &StudyRun) -> RunCsv {
        RunCsv {
            scene: r.scene.clone(),
            label: r.label.clone(),
            family: r.family.clone(),
            variant: r.variant.clone(),
            denoise: r.denoise,
            ms_median: r.ms_median,
            ms_mean: r.ms_mean,
            rays_per_pixel_per_frame: r.rays_per_pixel_per_frame,
            energy: r.energy,
            rel_mse: r.rel_mse,
            flip: r.flip,
            smape: r.smape,
            flicker_ratio: r.flicker_ratio,
            clock_flagged: r.clock_flagged,
            timing: r.timing.clone(),
            non_finite_pixels: r.non_finite_pixels,
            scored_frames: r.scored_frames,
            passes: r
                .passes
                .iter()
                .map(|(n, ms)| format!("{n}={ms:.4}"))
                .collect::<Vec<_>>()
                .join(";"),
            image: r.image.clone(),
        }
    }
}
