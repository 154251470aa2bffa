//! The study's `report.md`: header, one-page summary, bias table, then per scene its plots,
//! budget table, every run and the equal-time images. Readable on any code host.

use super::analysis::{SceneResult, StudyRun};
use super::{budget_text, Study, StudyReport};
use std::fmt::Write as _;

fn num(v: Option<f64>) -> String {
    match v {
        Some(v) if v.is_finite() => {
            if v != 0.0 && (v.abs() < 1e-3 || v.abs() >= 1e4) {
                format!("{v:.3e}")
            } else {
                format!("{v:.4}")
            }
        }
        Some(v) => format!("{v}"),
        None => "—".into(),
    }
}

fn ms(v: f64) -> String {
    if v < 10.0 {
        format!("{v:.2}")
    } else {
        format!("{v:.1}")
    }
}

fn scene_title(s: &SceneResult) -> String {
    if s.effect == s.name {
        s.name.clone()
    } else {
        format!("{} ({})", s.name, s.effect)
    }
}

fn run_of<'a>(s: &'a SceneResult, label: &str) -> Option<&'a StudyRun> {
    s.runs.iter().find(|r| r.label == label)
}

/// A commit's first 12 hex digits, keeping a `-dirty` mark (a tree with uncommitted changes).
fn short_commit(c: &str) -> String {
    let dirty = if c.ends_with("-dirty") { "-dirty" } else { "" };
    format!("{}{dirty}", &c[..c.len().min(12)])
}

/// The five passes that take the longest, as `name ms`.
fn top_passes(r: &StudyRun) -> String {
    let mut p: Vec<(&String, &f64)> = r.passes.iter().collect();
    p.sort_by(|a, b| b.1.total_cmp(a.1));
    p.iter()
        .take(5)
        .map(|(n, v)| format!("{n} {}", ms(**v)))
        .collect::<Vec<_>>()
        .join(", ")
}

pub fn report(study: &Study, r: &StudyReport) -> String {
    let h = &r.header;
    let mut md = String::new();
    let _ = writeln!(md, "# Study `{}`: what accuracy costs in time\n", h.study);
    let in_report = |scene: &str| r.scenes.iter().any(|x| x.name == scene);
    for (scene, why) in &r.failed {
        if in_report(scene) {
            // Its numbers are in the report; a figure could not be drawn.
            let _ = writeln!(md, "> **Scene `{scene}`, figures missing:** {why}\n");
        } else {
            let _ = writeln!(md, "> **Scene `{scene}` failed:** {why}\n");
        }
    }
    let finished = r.scenes.len() + r.failed.iter().filter(|f| !in_report(&f.0)).count();
    if finished < h.scenes_planned {
        let _ = writeln!(
            md,
            "> **Partial:** {} of the study's {} scenes are in this report (the study is running, was cut short, or ran a subset with --scenes).\n",
            r.scenes.len(),
            h.scenes_planned
        );
    }
    if h.adapter.device_type.to_lowercase().contains("cpu") {
        let _ = writeln!(
            md,
            "> **CPU rasteriser ({}):** these times come from a software Vulkan driver. Fixed costs are not amortised at this size and the passes' relative costs are not a GPU's. The ranking says nothing about a GPU.\n",
            h.adapter.name
        );
    }
    let _ = writeln!(
        md,
        "Every family runs as a real-time renderer: each frame is shown on its own. One frame in {} is scored against a reference rendered for that frame (the reference path tracer, {} paths per pixel). Errors are medians over the scored frames. Times are the median GPU time per frame, every pass included. Budgets are the red vertical lines of the plots.\n",
        h.reference_every, h.reference_spp
    );
    let _ = writeln!(md, "| | |\n| --- | --- |");
    let _ = writeln!(md, "| adapter | {} |", h.adapter);
    let runs: Vec<&StudyRun> = r.scenes.iter().flat_map(|s| &s.runs).collect();
    let wall = runs.iter().filter(|x| x.timing != "timestamps").count();
    let _ = writeln!(
        md,
        "| timing | {} |",
        if wall == 0 {
            "GPU timestamps, per pass".to_string()
        } else {
            format!(
                "wall clock for {wall} of {} runs (the adapter's timestamps missing or implausible): their per-pass times are not measured",
                runs.len()
            )
        }
    );
    let _ = writeln!(
        md,
        "| clocks | graphics clock {}; clock check: {} of {} runs flagged (calibration kernel drift over 10%), largest drift {:.1}% |",
        h.clocks.join(", "),
        h.clock_flagged,
        h.runs,
        h.max_clock_drift * 100.0
    );
    let _ = writeln!(md, "| commit | `{}` |", h.git_commit);
    let _ = writeln!(md, "| date | {} |", h.date_utc);
    let _ = writeln!(md, "| command | `{}` |", h.command);
    let _ = writeln!(
        md,
        "| study file | `{}` (SHA-256 `{}`) |",
        h.file,
        &h.file_sha256[..h.file_sha256.len().min(16)]
    );
    let _ = writeln!(
        md,
        "| size, frames | {}×{}, {} frames a run, frames {}, {}, … scored |",
        h.size[0],
        h.size[1],
        h.frames,
        h.reference_every - 1,
        2 * h.reference_every - 1
    );
    let _ = writeln!(md, "| metric | {} (budgets decided by it) |", h.metric);
    let _ = writeln!(
        md,
        "| wall time | {:.0} s, references included (time an invocation spent on a scene it did not finish is not counted) |",
        h.wall_seconds
    );
    if h.parts.len() > 1 {
        // A study cut short and resumed: which invocation ran which scenes.
        for (i, p) in h.parts.iter().enumerate() {
            let _ = writeln!(
                md,
                "| part {} | {}: {}{} in {:.0} s, commit `{}`, `{}` |",
                i + 1,
                p.date_utc,
                p.scenes.join(", "),
                if p.reused.is_empty() {
                    String::new()
                } else {
                    let each: Vec<String> = p
                        .reused
                        .iter()
                        .enumerate()
                        .map(|(k, n)| match p.reused_commits.get(k) {
                            Some(c) => format!("{n} at `{}`", short_commit(c)),
                            None => n.clone(),
                        })
                        .collect();
                    format!(
                        " (read back, rendered by an earlier invocation that was cut short: {})",
                        each.join(", ")
                    )
                },
                p.wall_seconds,
                short_commit(&p.git_commit),
                p.command
            );
        }
    }
    let _ = writeln!(md);

    // One-page summary.
    let _ = writeln!(
        md,
        "## Summary: the lowest {} at each frame budget\n",
        h.metric
    );
    let _ = write!(md, "| scene |");
    for b in &h.budgets_ms {
        let _ = write!(md, " {} ms |", budget_text(*b));
    }
    let _ = write!(md, "\n| --- |");
    for _ in &h.budgets_ms {
        let _ = write!(md, " --- |");
    }
    let _ = writeln!(md);
    for s in &r.scenes {
        let _ = write!(md, "| {} |", scene_title(s));
        for w in &s.winners {
            match (&w.run, w.error) {
                (Some(run), Some(e)) => {
                    let next = match (&w.runner_up, w.runner_up_ratio) {
                        (Some(n), Some(x)) => format!("; next {n} ×{x:.2}"),
                        _ => String::new(),
                    };
                    let _ = write!(md, " **{run}** {}{next} |", num(Some(e)));
                }
                _ => {
                    let _ = write!(md, " nothing fits |");
                }
            }
        }
        let _ = writeln!(md);
    }
    let _ = writeln!(
        md,
        "\n\"next\": the best run of another family, and how many times higher its error is.\n"
    );

    // Bias table.
    let tol = study.file.study.bias_tolerance;
    let _ = writeln!(md, "## Bias: energy against the reference\n");
    let _ = writeln!(
        md,
        "Mean over the scored frames of each frame's mean luminance over its reference's. Each family runs at its `default` setting without the denoiser. These are real-time frames, not accumulated ones: noise averages out over the frames but bias does not. ✓ means within ±{:.0}%, ✗ means outside.\n",
        tol * 100.0
    );
    let mut families: Vec<String> = Vec::new();
    for s in &r.scenes {
        for b in &s.bias {
            if !families.contains(&b.family) {
                families.push(b.family.clone());
            }
        }
    }
    let _ = write!(md, "| family |");
    for s in &r.scenes {
        let _ = write!(md, " {} |", scene_title(s));
    }
    let _ = write!(md, "\n| --- |");
    for _ in &r.scenes {
        let _ = write!(md, " ---: |");
    }
    let _ = writeln!(md);
    for f in &families {
        let _ = write!(md, "| {f} |");
        for s in &r.scenes {
            match s.bias.iter().find(|b| &b.family == f) {
                Some(b) => {
                    let mark = match b.within {
                        Some(true) => " ✓",
                        Some(false) => " ✗",
                        None => "",
                    };
                    let _ = write!(md, " {}{mark} |", num(b.energy));
                }
                None => {
                    let _ = write!(md, " not run |");
                }
            }
        }
        let _ = writeln!(md);
    }
    let _ = writeln!(md);

    for s in &r.scenes {
        scene_section(&mut md, s, r, h.metric.as_str());
    }
    let _ = writeln!(
        md,
        "## Files\n\n- `study.json`: this report's numbers (header, runs, budget picks, winners, bias, images).\n- `runs.csv`: one row per scene and run, with each pass's mean GPU ms.\n- `budgets.csv`: per scene, budget and curve, the run chosen.\n- `scenes/NAME/`: each scene's `converge` output: `experiment.toml` (run it alone with `gilab converge`), `report.md`, `convergence.csv` (every scored frame), `summary.json`, the last frame of every run in `runs/`."
    );
    md
}

fn scene_section(md: &mut String, s: &SceneResult, r: &StudyReport, metric: &str) {
    let dir = format!("scenes/{}", s.name);
    let _ = writeln!(md, "## Scene: {}\n", scene_title(s));
    let _ = writeln!(
        md,
        "{} runs, {} references at {} spp, {} runs with a flagged clock. The `converge` report is [{dir}/report.md]({dir}/report.md).\n",
        s.runs.len(),
        s.references,
        s.reference_spp,
        s.clock_flagged
    );
    let _ = writeln!(
        md,
        "![relMSE against GPU ms]({dir}/study-pareto-rel_mse.png)\n![FLIP against GPU ms]({dir}/study-pareto-flip.png)\n"
    );
    let _ = writeln!(
        md,
        "Each family's best setting within each budget (lowest median {metric} among its settings whose median ms fits):\n"
    );
    let _ = writeln!(
        md,
        "| budget | family | denoiser | setting | ms | rays/px | energy | relMSE | FLIP | flicker |\n| ---: | --- | :---: | --- | ---: | ---: | ---: | ---: | ---: | ---: |"
    );
    for p in &s.picks {
        let run = p.run.as_deref().and_then(|l| run_of(s, l));
        match run {
            Some(x) => {
                let _ = writeln!(
                    md,
                    "| {} ms | {} | {} | {} | {}{} | {:.2} | {} | {} | {} | {} |",
                    budget_text(p.budget_ms),
                    p.family,
                    if p.denoise { "yes" } else { "no" },
                    x.variant,
                    ms(x.ms_median),
                    if x.clock_flagged { " (clock)" } else { "" },
                    x.rays_per_pixel_per_frame,
                    num(x.energy),
                    num(x.rel_mse),
                    num(x.flip),
                    num(x.flicker_ratio)
                );
            }
            None => {
                let _ = writeln!(
                    md,
                    "| {} ms | {} | {} | none fits (cheapest {} ms) | | | | | | |",
                    budget_text(p.budget_ms),
                    p.family,
                    if p.denoise { "yes" } else { "no" },
                    ms(p.cheapest_ms)
                );
            }
        }
    }
    let _ = writeln!(md, "\nEvery run:\n");
    let _ = writeln!(
        md,
        "| run | ms (median) | ms (mean) | rays/px | energy | relMSE | FLIP | flicker | longest passes (ms) |\n| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |"
    );
    for x in &s.runs {
        let _ = writeln!(
            md,
            "| {}{} | {} | {} | {:.2} | {} | {} | {} | {} | {} |",
            x.label,
            if x.non_finite_pixels > 0 {
                format!(" ({} non-finite pixels)", x.non_finite_pixels)
            } else {
                String::new()
            },
            ms(x.ms_median),
            ms(x.ms_mean),
            x.rays_per_pixel_per_frame,
            num(x.energy),
            num(x.rel_mse),
            num(x.flip),
            num(x.flicker_ratio),
            top_passes(x)
        );
    }
    let _ = writeln!(
        md,
        "\nFlicker: the run's mean frame-to-frame change of displayed luminance over the references' (1: as stable as the truth).\n"
    );
    for img in r.images.iter().filter(|i| i.scene == s.name) {
        let _ = writeln!(
            md,
            "### Equal time: {} ms\n\nLast frame of each family's best run within {} ms. The top row is the image, the bottom row its per-pixel relMSE on one log scale. The magenta box on the reference is the crop below, where the families differ most.\n\n![equal time {} ms]({})\n\n![crops]({})\n",
            budget_text(img.budget_ms),
            budget_text(img.budget_ms),
            budget_text(img.budget_ms),
            img.image,
            img.crops
        );
    }
}
