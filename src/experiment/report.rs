//! What an experiment's rows say: equal-time error, time-to-error, the Pareto front of error
//! against ms/frame, and lag after scripted events; written as CSV, JSON, plots and Markdown.
//! Everything here is computed from the rows alone, so merged shards give the same report.

use super::plot;
use super::rows::{Row, Summary};
use super::Metric;
use anyhow::{Context, Result};
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::path::Path;

#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct Analysis {
    pub metric: String,
    /// Label of the run ratios are taken against.
    pub baseline: Option<String>,
    pub equal_time_ms: Option<f64>,
    pub equal_time: Vec<EqualTime>,
    pub target_error: Option<f64>,
    pub time_to_error: Vec<TimeToError>,
    /// Frame at which the Pareto points take their error (the fewest frames any run has).
    pub pareto_frame: u32,
    pub pareto: Vec<ParetoPoint>,
    pub lag: Vec<Lag>,
    /// Real-time mode: per run, the median frame time and per-frame error and the flicker ratio.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub real_time: Vec<RealTimeRun>,
    /// Real-time mode: per frame-time budget and technique entry, the best run that fits.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub frame_budgets: Vec<FrameBudget>,
    /// Real-time mode on a playing scene: per run, error while moving, settling after the
    /// motion stops, and ghosting.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub motion: Vec<MotionRun>,
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct MotionRun {
    pub label: String,
    /// Median per-frame error over the scored frames before the motion stops (all of them
    /// when it never stops).
    pub moving_error: Option<f64>,
    /// The first scored frame at or after the stop: its error, the steady level after it
    /// (median of the last frames, as for events), the threshold (`settle_factor` × steady),
    /// and the frames from the stop until the error is under it.
    pub error_at_stop: Option<f64>,
    pub steady_error: Option<f64>,
    pub threshold: Option<f64>,
    pub settle_frames: Option<u32>,
    pub settle_ms: Option<f64>,
    /// Scored frames with uncovered pixels, and the median over them of the mean FLIP there and
    /// elsewhere.
    pub ghost_frames: u32,
    pub ghost_flip: Option<f64>,
    pub rest_flip: Option<f64>,
    /// ghost / rest (1: uncovered pixels no worse than the rest of the image).
    pub ghost_ratio: Option<f64>,
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct RealTimeRun {
    pub label: String,
    /// The `[[techniques]]` entry it comes from.
    pub entry: String,
    pub denoise: bool,
    /// Median GPU ms over all the run's frames.
    pub ms_per_frame: f64,
    /// Median over the scored frames of each frame's own error.
    pub median_error: Option<f64>,
    pub flicker: Option<f64>,
    pub flicker_reference: Option<f64>,
    /// flicker / flicker_reference (1: as stable as the ground truth).
    pub flicker_ratio: Option<f64>,
    pub clock_flagged: bool,
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct FrameBudget {
    pub budget_ms: f64,
    pub entry: String,
    /// The run (sweep value) with the lowest median per-frame error among those whose median
    /// ms/frame fits the budget; None when none fits.
    pub run: Option<String>,
    pub ms_per_frame: Option<f64>,
    pub median_error: Option<f64>,
    pub flicker_ratio: Option<f64>,
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct EqualTime {
    pub label: String,
    /// Error of the last frame finished within the budget (None: not even one frame fits).
    pub error: Option<f64>,
    pub frames: Option<u32>,
    /// error / baseline's error at the same budget.
    pub ratio: Option<f64>,
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct TimeToError {
    pub label: String,
    /// GPU ms until the error first reaches the target (None: it never does in this run).
    pub ms: Option<f64>,
    pub frames: Option<u32>,
    /// ms / baseline's ms.
    pub ratio: Option<f64>,
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct ParetoPoint {
    pub label: String,
    pub ms_per_frame: f64,
    pub error: f64,
    pub on_front: bool,
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Lag {
    pub event: String,
    pub frame: u32,
    pub label: String,
    /// Error on the frame before the event (against the old state's reference).
    pub error_before: f64,
    /// Error on the first frame after it (against the new state's reference).
    pub error_after: f64,
    /// Median error over the state's last frames (up to 8, at most half of them): the level
    /// the run settles at in the new scene.
    pub steady_error: f64,
    pub threshold: f64,
    /// Frames rendered after the event until the error is under the threshold.
    pub settle_frames: Option<u32>,
    pub settle_ms: Option<f64>,
}

/// The rows of one run before the first event (state 0), in frame order.
fn segment(rows: &[Row], run: usize) -> Vec<&Row> {
    let mut v: Vec<&Row> = rows
        .iter()
        .filter(|r| r.run == run && r.state == 0)
        .collect();
    v.sort_by_key(|r| r.frame);
    v
}

/// Median error of the last frames of a state (up to 8, at most half of the state's frames).
pub fn steady_error(rows: &[&Row], metric: Metric) -> f64 {
    let n = (rows.len() / 2).clamp(1, 8).min(rows.len());
    let mut tail: Vec<f64> = rows[rows.len() - n..]
        .iter()
        .map(|r| r.error(metric))
        .collect();
    tail.sort_by(f64::total_cmp);
    tail.get(tail.len() / 2).copied().unwrap_or(f64::NAN)
}

/// Error of the last frame finished by GPU time `t` (what a viewer would show at `t`).
pub fn error_at_time(rows: &[&Row], metric: Metric, t: f64) -> Option<(f64, u32)> {
    rows.iter()
        .take_while(|r| r.gpu_ms_cum <= t * (1.0 + 1e-9))
        .last()
        .map(|r| (r.error(metric), r.frame))
}

/// First frame whose error is at or under `target`: (GPU ms, frames).
pub fn time_to_error(rows: &[&Row], metric: Metric, target: f64) -> Option<(f64, u32)> {
    rows.iter()
        .find(|r| r.error(metric) <= target)
        .map(|r| (r.gpu_ms_cum, r.frame))
}

fn ratio(a: Option<f64>, b: Option<f64>) -> Option<f64> {
    match (a, b) {
        (Some(a), Some(b)) if b > 0.0 => Some(a / b),
        _ => None,
    }
}

pub fn analyse(summary: &Summary, rows: &[Row]) -> Analysis {
    let s = &summary.settings;
    let metric = s.metric;
    let runs: Vec<(usize, String)> = summary
        .runs
        .iter()
        .map(|r| (r.spec.index, r.spec.label.clone()))
        .collect();
    let segs: Vec<(String, Vec<&Row>)> = runs
        .iter()
        .map(|(i, l)| (l.clone(), segment(rows, *i)))
        .filter(|(_, v)| !v.is_empty())
        .collect();
    let baseline = match &s.baseline {
        Some(b) => summary
            .runs
            .iter()
            .find(|r| &r.spec.label == b || &r.spec.entry == b),
        None => summary
            .runs
            .iter()
            .find(|r| r.spec.technique == "reference")
            .or(summary.runs.first()),
    };
    let base_seg = baseline
        .and_then(|b| segs.iter().find(|(l, _)| *l == b.spec.label))
        .map(|(_, v)| v.clone());

    let equal_time_ms = s.equal_time_ms.or_else(|| {
        segs.iter()
            .filter_map(|(_, v)| v.last().map(|r| r.gpu_ms_cum))
            .min_by(f64::total_cmp)
    });
    let equal_time = match equal_time_ms {
        Some(t) => {
            let base = base_seg.as_ref().and_then(|b| error_at_time(b, metric, t));
            segs.iter()
                .map(|(label, v)| {
                    let e = error_at_time(v, metric, t);
                    EqualTime {
                        label: label.clone(),
                        error: e.map(|e| e.0),
                        frames: e.map(|e| e.1),
                        ratio: ratio(e.map(|e| e.0), base.map(|b| b.0)),
                    }
                })
                .collect()
        }
        None => Vec::new(),
    };

    let target_error = s.target_error.or_else(|| {
        segs.iter()
            .filter_map(|(_, v)| v.iter().map(|r| r.error(metric)).min_by(f64::total_cmp))
            .max_by(f64::total_cmp)
    });
    let time_to_error = match target_error {
        Some(target) => {
            let base = base_seg
                .as_ref()
                .and_then(|b| time_to_error(b, metric, target));
            segs.iter()
                .map(|(label, v)| {
                    let t = time_to_error(v, metric, target);
                    TimeToError {
                        label: label.clone(),
                        ms: t.map(|t| t.0),
                        frames: t.map(|t| t.1),
                        ratio: ratio(t.map(|t| t.0), base.map(|b| b.0)),
                    }
                })
                .collect()
        }
        None => Vec::new(),
    };

    let real_time_mode = s.mode == super::Mode::RealTime;
    let real_time: Vec<RealTimeRun> = if real_time_mode {
        summary
            .runs
            .iter()
            .map(|r| {
                let mine: Vec<&Row> = rows.iter().filter(|x| x.run == r.spec.index).collect();
                let mean = |f: &dyn Fn(&Row) -> Option<f64>| {
                    let v: Vec<f64> = mine
                        .iter()
                        .filter(|x| x.flicker.is_some() && x.flicker_reference.is_some())
                        .filter_map(|x| f(x))
                        .collect();
                    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
                };
                let flicker = mean(&|x| x.flicker);
                let flicker_reference = mean(&|x| x.flicker_reference);
                RealTimeRun {
                    label: r.spec.label.clone(),
                    entry: r.spec.entry.clone(),
                    denoise: r.spec.denoise,
                    ms_per_frame: r.gpu_ms_median,
                    median_error: super::run::median(
                        mine.iter().map(|x| x.error(metric)).collect(),
                    ),
                    flicker,
                    flicker_reference,
                    flicker_ratio: ratio(flicker, flicker_reference),
                    clock_flagged: r.clock_check.flagged,
                }
            })
            .collect()
    } else {
        Vec::new()
    };
    let mut frame_budgets = Vec::new();
    for &budget in s.frame_ms.iter().filter(|_| real_time_mode) {
        let mut entries: Vec<&str> = Vec::new();
        for r in &real_time {
            if !entries.contains(&r.entry.as_str()) {
                entries.push(&r.entry);
            }
        }
        for entry in entries {
            let best = real_time
                .iter()
                .filter(|r| r.entry == entry && r.ms_per_frame <= budget)
                .filter(|r| r.median_error.is_some())
                .min_by(|a, b| {
                    a.median_error
                        .unwrap_or(f64::INFINITY)
                        .total_cmp(&b.median_error.unwrap_or(f64::INFINITY))
                });
            frame_budgets.push(FrameBudget {
                budget_ms: budget,
                entry: entry.to_string(),
                run: best.map(|b| b.label.clone()),
                ms_per_frame: best.map(|b| b.ms_per_frame),
                median_error: best.and_then(|b| b.median_error),
                flicker_ratio: best.and_then(|b| b.flicker_ratio),
            });
        }
    }
    let pareto_frame = if real_time_mode {
        0
    } else {
        segs.iter().map(|(_, v)| v.len() as u32).min().unwrap_or(0)
    };
    let mut pareto: Vec<ParetoPoint> = real_time
        .iter()
        .filter_map(|r| {
            Some(ParetoPoint {
                label: r.label.clone(),
                ms_per_frame: r.ms_per_frame,
                error: r.median_error?,
                on_front: false,
            })
        })
        .collect();
    pareto.extend(segs.iter().filter(|_| pareto_frame > 0).map(|(label, v)| {
        let last = v[pareto_frame as usize - 1];
        ParetoPoint {
            label: label.clone(),
            ms_per_frame: last.gpu_ms_cum / last.frame as f64,
            error: last.error(metric),
            on_front: false,
        }
    }));
    let points: Vec<(f64, f64)> = pareto.iter().map(|p| (p.ms_per_frame, p.error)).collect();
    for p in pareto.iter_mut() {
        p.on_front = !points.iter().any(|&(ms, e)| {
            ms <= p.ms_per_frame && e <= p.error && (ms < p.ms_per_frame || e < p.error)
        });
    }

    let mut events = s.events.clone();
    events.sort_by_key(|e| e.frame);
    let mut lag = Vec::new();
    for (k, e) in events.iter().enumerate() {
        for (i, label) in &runs {
            let mut v: Vec<&Row> = rows.iter().filter(|r| r.run == *i).collect();
            v.sort_by_key(|r| r.frame);
            let Some(before) = v.iter().find(|r| r.frame == e.frame) else {
                continue;
            };
            // The frames this event's state lasted (up to the next event or the end).
            let after: Vec<&Row> = v
                .iter()
                .copied()
                .filter(|r| r.frame > e.frame && r.state == k + 1)
                .collect();
            let Some(first) = after.first() else {
                continue;
            };
            let threshold = s.settle_error.unwrap_or_else(|| {
                s.settle_factor * before.error(metric).max(steady_error(&after, metric))
            });
            let settled = after.iter().find(|r| r.error(metric) <= threshold);
            lag.push(Lag {
                event: e.describe(),
                frame: e.frame,
                label: label.clone(),
                error_before: before.error(metric),
                error_after: first.error(metric),
                steady_error: steady_error(&after, metric),
                threshold,
                settle_frames: settled.map(|r| r.frame - e.frame),
                settle_ms: settled.map(|r| r.gpu_ms_cum - before.gpu_ms_cum),
            });
        }
    }

    let plays = rows.iter().any(|r| r.scene_time.is_some());
    let motion: Vec<MotionRun> = if real_time_mode && plays {
        runs.iter()
            .map(|(i, label)| {
                let mut v: Vec<&Row> = rows.iter().filter(|r| r.run == *i).collect();
                v.sort_by_key(|r| r.frame);
                // Row frames count from 1: frame index = frame - 1.
                let stop = summary.motion_stop_frame;
                let still = |r: &&Row| stop.is_some_and(|s| r.frame > s);
                let moving: Vec<f64> = v
                    .iter()
                    .filter(|r| !still(r))
                    .map(|r| r.error(metric))
                    .collect();
                let after: Vec<&Row> = v.iter().copied().filter(still).collect();
                let steady = (!after.is_empty()).then(|| steady_error(&after, metric));
                let threshold = steady.map(|e| s.settle_factor * e);
                let settled =
                    threshold.and_then(|th| after.iter().find(|r| r.error(metric) <= th).copied());
                let before_stop = v.iter().rev().find(|r| !still(r));
                let ghosts: Vec<&&Row> = v.iter().filter(|r| r.ghost_flip.is_some()).collect();
                // Medians over the frames: one firefly frame does not decide the ratio.
                let ghost =
                    super::run::median(ghosts.iter().filter_map(|r| r.ghost_flip).collect());
                let rest = super::run::median(ghosts.iter().filter_map(|r| r.rest_flip).collect());
                MotionRun {
                    label: label.clone(),
                    moving_error: super::run::median(moving),
                    error_at_stop: after.first().map(|r| r.error(metric)),
                    steady_error: steady,
                    threshold,
                    settle_frames: settled
                        .zip(stop)
                        .map(|(r, s)| (r.frame - 1).saturating_sub(s)),
                    settle_ms: settled
                        .map(|r| r.gpu_ms_cum - before_stop.map_or(0.0, |b| b.gpu_ms_cum)),
                    ghost_frames: ghosts.len() as u32,
                    ghost_flip: ghost,
                    rest_flip: rest,
                    ghost_ratio: ratio(ghost, rest),
                }
            })
            .collect()
    } else {
        Vec::new()
    };

    // Accumulated-image tables say nothing about single real-time frames.
    let (equal_time_ms, equal_time, target_error, time_to_error) = if real_time_mode {
        (None, Vec::new(), None, Vec::new())
    } else {
        (equal_time_ms, equal_time, target_error, time_to_error)
    };
    Analysis {
        metric: metric.name().into(),
        baseline: baseline.map(|b| b.spec.label.clone()),
        equal_time_ms,
        equal_time,
        target_error,
        time_to_error,
        pareto_frame,
        pareto,
        lag,
        real_time,
        frame_budgets,
        motion,
    }
}

/// Analyses, writes every output into `out`, prints the headline tables, returns the summary.
pub fn finish(mut summary: Summary, rows: Vec<Row>, out: &Path) -> Result<Summary> {
    summary.analysis = analyse(&summary, &rows);
    std::fs::create_dir_all(out)?;
    let mut w = csv::Writer::from_path(out.join("convergence.csv"))
        .with_context(|| format!("writing {}", out.join("convergence.csv").display()))?;
    for r in &rows {
        w.serialize(r)?;
    }
    w.flush()?;
    std::fs::write(
        out.join("summary.json"),
        serde_json::to_string_pretty(&summary)?,
    )?;
    plot::write_all(&summary, &rows, out)?;
    std::fs::write(out.join("report.md"), markdown(&summary))?;
    print!("{}", headline(&summary));
    Ok(summary)
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or("—".into(), |v| {
        if v != 0.0 && (v.abs() < 1e-3 || v.abs() >= 1e5) {
            format!("{v:.digits$e}")
        } else {
            format!("{v:.digits$}")
        }
    })
}

fn ratio_text(v: Option<f64>) -> String {
    v.map_or("—".into(), |r| format!("{r:.2}×"))
}

/// The equal-time and time-to-error tables, for the terminal.
pub fn headline(s: &Summary) -> String {
    let a = &s.analysis;
    let mut t = String::new();
    for r in s.runs.iter().filter(|r| r.clock_check.flagged) {
        let _ = writeln!(
            t,
            "FLAGGED {}: the GPU's clock state changed during the run ({}); its times are not comparable",
            r.spec.label,
            r.clock_check.summary()
        );
    }
    let base = a.baseline.as_deref().unwrap_or("—");
    if let Some(ms) = a.equal_time_ms {
        let _ = writeln!(t, "equal time ({ms:.1} GPU ms), {} vs {base}:", a.metric);
        for e in &a.equal_time {
            let _ = writeln!(
                t,
                "  {:<40} {:>12} after {:>4} frames  ratio {}",
                e.label,
                opt(e.error, 4),
                e.frames.map_or("—".into(), |f| f.to_string()),
                ratio_text(e.ratio)
            );
        }
    }
    if let Some(target) = a.target_error {
        let _ = writeln!(t, "time to {} {}:", a.metric, opt(Some(target), 4));
        for e in &a.time_to_error {
            let _ = writeln!(
                t,
                "  {:<40} {:>10} ms {:>5} frames  ratio {}",
                e.label,
                opt(e.ms, 1),
                e.frames.map_or("—".into(), |f| f.to_string()),
                ratio_text(e.ratio)
            );
        }
    }
    if !a.frame_budgets.is_empty() {
        let _ = writeln!(
            t,
            "error at a frame-time budget (median per-frame {}):",
            a.metric
        );
        for b in &a.frame_budgets {
            let _ = writeln!(
                t,
                "  {:>6.1} ms  {:<24} {:>12}  {:<40} {:>8} ms/frame  flicker {}",
                b.budget_ms,
                b.entry,
                opt(b.median_error, 4),
                b.run.as_deref().unwrap_or("(nothing fits)"),
                opt(b.ms_per_frame, 2),
                ratio_text(b.flicker_ratio)
            );
        }
    }
    for r in &a.real_time {
        let _ = writeln!(
            t,
            "  {:<40} {:>9.2} ms/frame  median {} {:>12}  flicker ratio {}",
            r.label,
            r.ms_per_frame,
            a.metric,
            opt(r.median_error, 4),
            ratio_text(r.flicker_ratio)
        );
    }
    if !a.motion.is_empty() {
        let _ = writeln!(
            t,
            "motion (median {} while moving; settle frames after it stops; ghost FLIP in uncovered pixels / elsewhere, medians over frames):",
            a.metric
        );
        for r in &a.motion {
            let _ = writeln!(
                t,
                "  {:<40} moving {:>10}  settles in {:>5}  ghost {:>10} / {:>10} = {}",
                r.label,
                opt(r.moving_error, 4),
                r.settle_frames.map_or(
                    if r.steady_error.is_some() {
                        "never"
                    } else {
                        "—"
                    }
                    .into(),
                    |f| f.to_string()
                ),
                opt(r.ghost_flip, 4),
                opt(r.rest_flip, 4),
                ratio_text(r.ghost_ratio)
            );
        }
    }
    for l in &a.lag {
        let _ = writeln!(
            t,
            "lag after '{}': {:<30} settles in {} frames, {} ms",
            l.event,
            l.label,
            l.settle_frames.map_or("never".into(), |f| f.to_string()),
            opt(l.settle_ms, 1)
        );
    }
    t
}

/// A `| run | frames | value | ratio |` table row.
fn ratio_row(m: &mut String, label: &str, frames: Option<u32>, value: String, r: Option<f64>) {
    let frames = frames.map_or("—".into(), |f| f.to_string());
    let _ = writeln!(m, "| {label} | {frames} | {value} | {} |", ratio_text(r));
}

pub fn markdown(s: &Summary) -> String {
    let a = &s.analysis;
    let mut m = String::new();
    let _ = writeln!(m, "# Convergence experiment: {}\n", s.experiment);
    let _ = writeln!(m, "| | |\n| --- | --- |");
    let _ = writeln!(m, "| file | `{}` |", s.file.as_deref().unwrap_or("—"));
    let _ = writeln!(
        m,
        "| adapter | {} ({}, {}) |",
        s.adapter.name, s.adapter.backend, s.adapter.device_type
    );
    let _ = writeln!(
        m,
        "| driver | {} {} |",
        s.adapter.driver, s.adapter.driver_info
    );
    let _ = writeln!(m, "| git commit | `{}` |", s.git_commit);
    let _ = writeln!(m, "| preset SHA-256 | `{}` |", s.preset_sha256);
    let _ = writeln!(m, "| image | {}×{} |", s.size[0], s.size[1]);
    let _ = writeln!(m, "| seeds | {:?} |", s.seeds);
    let _ = writeln!(
        m,
        "| frames per run | {}{} |",
        s.settings.frames,
        if s.settings.seconds > 0.0 {
            format!(" (or {} s of GPU time)", s.settings.seconds)
        } else {
            String::new()
        }
    );
    let _ = writeln!(
        m,
        "| runs | {} of {}{} |",
        s.runs.len(),
        s.total_runs,
        if s.shards.is_empty() {
            String::new()
        } else {
            format!(
                " (shards {:?})",
                s.shards
                    .iter()
                    .map(|x| format!("{}/{}", x.index, x.count))
                    .collect::<Vec<_>>()
            )
        }
    );
    let real_time = s.settings.mode == super::Mode::RealTime;
    if real_time {
        let _ = writeln!(
            m,
            "| mode | real-time: every {} frame(s) scored on its own against a reference rendered for that frame |",
            s.settings.reference_every.max(1)
        );
        let _ = writeln!(
            m,
            "| camera | {} |",
            if s.settings.camera_path.is_empty() {
                "still (or moved by events)".to_string()
            } else {
                format!("path of {} keys", s.settings.camera_path.len())
            }
        );
        let _ = writeln!(
            m,
            "| references | {} per-frame references, {} spp, each with its own seed (cached by content in `{}`) |",
            s.references.len(),
            s.references.first().map_or(0, |r| r.spp),
            s.references
                .first()
                .and_then(|r| Path::new(&r.cache_file).parent())
                .map_or("—".into(), |d| d.display().to_string())
        );
    } else {
        for r in &s.references {
            let _ = writeln!(
                m,
                "| reference, state {} (from frame {}) | {} spp, seed {}, `{}` |",
                r.state, r.from_frame, r.spp, r.seed, r.cache_file
            );
        }
    }
    let _ = writeln!(m);
    let _ = writeln!(
        m,
        "Errors are measured after every frame against the reference of the scene state that frame saw, \
         in linear HDR (MSE, relMSE = (x−y)²/(y²+0.01), SMAPE) and as LDR-FLIP (NVIDIA's implementation \
         through `nv-flip`, 67 pixels per degree) on both images after the preset's display transform \
         ({:?}, exposure {:+} EV, sRGB, 8 bits): FLIP scores what the tonemapped image shows; HDR values \
         above the curve's shoulder count only as far as they change the displayed pixel. Time is GPU time \
         from timestamp queries (the `timing` column says `wall` where the adapter gave none). Tables use **{}**.\n",
        s.tonemap.operator, s.tonemap.exposure, a.metric
    );
    let _ = writeln!(m, "## Runs\n");
    let _ = writeln!(m, "| run | technique | rays/px/frame | GPU ms/frame | passes run | final relMSE | final FLIP |\n| --- | --- | ---: | ---: | --- | ---: | ---: |");
    for r in &s.runs {
        let _ = writeln!(
            m,
            "| {} | {}{} | {:.2} | {:.2} | {} | {} | {:.4} |",
            r.spec.label,
            r.spec.technique,
            r.spec
                .budget
                .map_or(String::new(), |b| format!(" (budget {b})")),
            r.rays_per_pixel_per_frame,
            r.gpu_ms_per_frame,
            r.passes_run.join(", "),
            opt(Some(r.final_rel_mse), 4),
            r.final_flip
        );
    }
    let _ = writeln!(
        m,
        "\n## Timing protocol\n\nFrames of a run go back to back (up to {} in flight; errors are computed afterwards \
         from copies of the scored frames, every {} frame(s)). Before each run a fixed calibration kernel runs until \
         its time is stable; it is timed again right behind the run's last frame. A run whose two times differ by \
         more than {:.0}% ran in another clock state than it started in and is **flagged** (its times are not \
         comparable).\n\n| run | calibration before → after (ms) | drift | clock before → after | flag |\n| --- | ---: | ---: | --- | --- |",
        crate::render::engine::FRAMES_IN_FLIGHT,
        s.settings.error_every.max(1),
        crate::gpu::calibrate::DRIFT_LIMIT * 100.0
    );
    for r in &s.runs {
        let c = &r.clock_check;
        let _ = writeln!(
            m,
            "| {} | {:.3} → {:.3} | {:+.1}% | {} → {} | {} |",
            r.spec.label,
            c.kernel_ms_before,
            c.kernel_ms_after,
            c.drift * 100.0,
            c.clock_before,
            c.clock_after,
            if c.flagged { "**FLAGGED**" } else { "ok" }
        );
    }
    let skipped: Vec<String> = s
        .runs
        .iter()
        .flat_map(|r| {
            r.passes_skipped
                .iter()
                .map(move |p| format!("{}: {p}", r.spec.label))
        })
        .collect();
    if !skipped.is_empty() {
        let _ = writeln!(m, "\nPasses not dispatched (scene analysis):\n");
        for p in skipped {
            let _ = writeln!(m, "- {p}");
        }
    }
    if !a.frame_budgets.is_empty() {
        let _ = writeln!(
            m,
            "\n## Error at a frame-time budget\n\nPer budget and technique entry: the run (sweep value) whose median GPU ms per frame \
             fits the budget and whose median per-frame {} is lowest. Flicker ratio: the run's mean change of the displayed \
             luminance between consecutive frames (camera motion undone by reprojection) over the same for the references \
             (1: as stable as the ground truth).\n",
            a.metric
        );
        let _ = writeln!(
            m,
            "| budget ms | technique | run | median ms/frame | median {} | flicker ratio |\n| ---: | --- | --- | ---: | ---: | ---: |",
            a.metric
        );
        for b in &a.frame_budgets {
            let _ = writeln!(
                m,
                "| {} | {} | {} | {} | {} | {} |",
                b.budget_ms,
                b.entry,
                b.run.as_deref().unwrap_or("nothing fits"),
                opt(b.ms_per_frame, 2),
                opt(b.median_error, 4),
                ratio_text(b.flicker_ratio)
            );
        }
    }
    if !a.real_time.is_empty() {
        let _ = writeln!(
            m,
            "\n## Real-time runs\n\n| run | denoised | median ms/frame | median {} | flicker | reference flicker | flicker ratio |\n| --- | :---: | ---: | ---: | ---: | ---: | ---: |",
            a.metric
        );
        for r in &a.real_time {
            let _ = writeln!(
                m,
                "| {}{} | {} | {:.2} | {} | {} | {} | {} |",
                r.label,
                if r.clock_flagged {
                    " (**FLAGGED**)"
                } else {
                    ""
                },
                if r.denoise { "yes" } else { "" },
                r.ms_per_frame,
                opt(r.median_error, 4),
                opt(r.flicker, 4),
                opt(r.flicker_reference, 4),
                ratio_text(r.flicker_ratio)
            );
        }
    }
    let base = a.baseline.as_deref().unwrap_or("—");
    if let Some(ms) = a.equal_time_ms {
        let _ = writeln!(m, "\n## Equal time: {} at {ms:.1} GPU ms\n\nThe image each run had finished by the budget; ratio to `{base}` (below 1: better).\n", a.metric);
        let _ = writeln!(
            m,
            "| run | frames | {} | ratio |\n| --- | ---: | ---: | ---: |",
            a.metric
        );
        for e in &a.equal_time {
            ratio_row(&mut m, &e.label, e.frames, opt(e.error, 4), e.ratio);
        }
    }
    if let Some(t) = a.target_error {
        let _ = writeln!(
            m,
            "\n## Time to {} ≤ {}\n\nRatio to `{base}` (below 1: faster).\n",
            a.metric,
            opt(Some(t), 4)
        );
        let _ = writeln!(
            m,
            "| run | frames | GPU ms | ratio |\n| --- | ---: | ---: | ---: |"
        );
        for e in &a.time_to_error {
            ratio_row(&mut m, &e.label, e.frames, opt(e.ms, 1), e.ratio);
        }
    }
    if !a.pareto.is_empty() {
        if real_time {
            let _ = writeln!(
                m,
                "\n## Pareto front: median per-frame {} against median GPU ms per frame\n",
                a.metric
            );
        } else {
            let _ = writeln!(
                m,
                "\n## Pareto front: {} after {} frames against GPU ms per frame\n",
                a.metric, a.pareto_frame
            );
        }
        let _ = writeln!(
            m,
            "| run | ms/frame | {} | on the front |\n| --- | ---: | ---: | :---: |",
            a.metric
        );
        let mut pts = a.pareto.clone();
        pts.sort_by(|x, y| x.ms_per_frame.total_cmp(&y.ms_per_frame));
        for p in pts {
            let _ = writeln!(
                m,
                "| {} | {:.2} | {} | {} |",
                p.label,
                p.ms_per_frame,
                opt(Some(p.error), 4),
                if p.on_front { "●" } else { "" }
            );
        }
    }
    if !a.lag.is_empty() {
        let rule = match s.settings.settle_error {
            Some(e) => format!("{} back under {e}", a.metric),
            None => format!(
                "{} back under {}× the larger of its value on the frame before the event and its steady level in the new state \
                 (median of the state's last frames, up to 8): a harder scene after the event is not counted as lag",
                a.metric, s.settings.settle_factor
            ),
        };
        let _ = writeln!(m, "\n## Lag after events\n\nSettled: {rule} (each frame against the reference of the state it saw).\n");
        let _ = writeln!(m, "| event | run | before | first frame after | steady after | threshold | settle frames | settle GPU ms |\n| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |");
        for l in &a.lag {
            let _ = writeln!(
                m,
                "| {} | {} | {} | {} | {} | {} | {} | {} |",
                l.event,
                l.label,
                opt(Some(l.error_before), 4),
                opt(Some(l.error_after), 4),
                opt(Some(l.steady_error), 4),
                opt(Some(l.threshold), 4),
                l.settle_frames
                    .map_or("not settled".into(), |f| f.to_string()),
                opt(l.settle_ms, 1)
            );
        }
    }
    if !a.motion.is_empty() {
        let stop = match s.motion_stop_frame {
            Some(f) => format!("The motion stops at frame {f} (`[scene] play_until`); settled: {} under {}× its steady level after the stop (median of the last scored frames, up to 8).", a.metric, s.settings.settle_factor),
            None => "The motion does not stop in this run (set `[scene] play_until` to measure settling).".into(),
        };
        let _ = writeln!(
            m,
            "\n## Motion\n\n{stop} Ghosting: FLIP in the pixels a moving object uncovered in the {} frames before a scored frame, against the rest of that frame (medians over the frames that have such pixels).\n",
            s.settings.ghost_frames
        );
        let _ = writeln!(m, "| run | median {} while moving | at the stop | steady | settle frames | settle GPU ms | frames with ghosts | ghost FLIP | elsewhere | ratio |\n| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |", a.metric);
        for r in &a.motion {
            let _ = writeln!(
                m,
                "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
                r.label,
                opt(r.moving_error, 4),
                opt(r.error_at_stop, 4),
                opt(r.steady_error, 4),
                r.settle_frames.map_or(
                    if r.steady_error.is_some() {
                        "not settled"
                    } else {
                        "—"
                    }
                    .into(),
                    |f| f.to_string()
                ),
                opt(r.settle_ms, 1),
                r.ghost_frames,
                opt(r.ghost_flip, 4),
                opt(r.rest_flip, 4),
                ratio_text(r.ghost_ratio)
            );
        }
    }
    let _ = writeln!(m, "\n## Plots\n");
    for (file, what) in plot::FILES {
        let _ = writeln!(m, "**{what}**\n\n![{what}]({file})\n");
    }
    let _ = writeln!(m, "Data: `convergence.csv` (one row per run × frame), `summary.json`; last frames in `runs/`.");
    m
}
