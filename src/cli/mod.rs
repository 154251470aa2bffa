//! Command-line interface: the viewer (no subcommand, or `view`), `shot`, `reference`,
//! `compare`, `bench`. Every rendering subcommand
//! takes a preset (optional: the built-in default is the Cornell box) and overrides for it.

pub mod bench;
pub mod brdf_slice;

use crate::compare::{io, metrics};
use crate::gpu::{BackendChoice, Gpu};
use crate::jobs;
use crate::preset::{LoadedPreset, Overrides};
use anyhow::Result;
use clap::{Parser, Subcommand};
use std::path::PathBuf;

#[derive(Parser, Debug)]
#[command(
    name = "gilab",
    version,
    about = "Real-time global illumination research sandbox"
)]
pub struct Cli {
    /// GPU backend: auto (Vulkan, else GL), vulkan or gl. Also GILAB_BACKEND.
    #[arg(long, global = true, default_value = "auto")]
    pub backend: BackendChoice,
    #[command(subcommand)]
    pub command: Option<Command>,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Open the interactive viewer (the default when no subcommand is given).
    View {
        /// Preset file (default: the built-in Cornell box preset).
        preset: Option<PathBuf>,
        /// Do not watch shaders/ and presets/ for changes.
        #[arg(long)]
        no_watch: bool,
        /// Save a screenshot of the whole window this many seconds after start, then close.
        #[arg(long, value_name = "SECONDS")]
        window_shot_after: Option<f64>,
        /// Where that screenshot goes (default: out/viewer/window.png).
        #[arg(long, value_name = "PNG", requires = "window_shot_after")]
        window_shot: Option<PathBuf>,
        #[command(flatten)]
        overrides: Overrides,
    },
    /// Render a preset: tonemapped PNG, linear EXR and JSON metadata per technique.
    Shot {
        /// Preset file (default: the built-in Cornell box preset).
        preset: Option<PathBuf>,
        /// Output folder; files go to OUT/<preset name>/<technique>.{png,exr,json}.
        #[arg(long, default_value = "out")]
        out: PathBuf,
        /// Print scene features and the passes each technique runs or skips.
        #[arg(long)]
        verbose: bool,
        #[command(flatten)]
        overrides: Overrides,
    },
    /// Render and cache a converged reference EXR for a preset's scene, camera and size.
    Reference {
        preset: Option<PathBuf>,
        /// Cache folder.
        #[arg(long, default_value = "cache/reference")]
        cache: PathBuf,
        /// Render again even if the cache has this reference.
        #[arg(long)]
        force: bool,
        #[command(flatten)]
        overrides: Overrides,
    },
    /// Runs a convergence experiment (a preset with an [experiment] table): per run and frame
    /// GPU time, rays and error against the reference; writes CSV, JSON, plots, images and a
    /// Markdown report.
    Converge {
        /// Experiment file, e.g. presets/experiments/cornell-budgets.toml.
        #[arg(required_unless_present = "merge")]
        file: Option<PathBuf>,
        /// Output folder (default: out/converge/<experiment name>[-shard-I-of-N]).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Run only every N-th run starting at I (e.g. a Slurm array task: --shard $SLURM_ARRAY_TASK_ID/N).
        #[arg(long, value_name = "I/N")]
        shard: Option<crate::experiment::Shard>,
        /// Merge the outputs of shard runs (folders) into one report in --out.
        #[arg(long, num_args = 1.., value_name = "DIR", conflicts_with_all = ["file", "shard"])]
        merge: Vec<PathBuf>,
        /// Reference cache folder.
        #[arg(long, default_value = "cache/reference")]
        cache: PathBuf,
        #[command(flatten)]
        overrides: Overrides,
    },
    /// Runs a study (e.g. presets/studies/headline.toml): every scene's families at their
    /// settings as real-time renderers, scored per frame against references; writes one report
    /// folder (summary, Pareto plots, tables per budget, equal-time images, bias table, CSV,
    /// JSON).
    Study {
        /// Study file.
        file: PathBuf,
        /// Output folder (default: out/study/<study name>).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Image size of every scene: N or WxH (default: the study's).
        #[arg(long)]
        size: Option<String>,
        /// Multiplies every frame-time budget: a CPU device (lavapipe) at a small size needs
        /// budgets about 50× a GPU's at 1080p.
        #[arg(long, default_value_t = 1.0)]
        budget_scale: f64,
        /// Reference cache folder.
        #[arg(long, default_value = "cache/reference")]
        cache: PathBuf,
        /// No progress bars or per-scene lines (each scene's converge tables still print).
        #[arg(long)]
        quiet: bool,
        /// Continue the report in the output folder (a study cut short, e.g. by a device
        /// call's time limit): its finished scenes stay, the others run.
        #[arg(long)]
        resume: bool,
        /// Run only these scenes now (comma-separated names from the study file).
        #[arg(long, value_delimiter = ',')]
        scenes: Vec<String>,
    },
    /// Error of image A against reference B (linear HDR): MSE, relMSE, SMAPE, and LDR-FLIP
    /// after the default display transform (ACES, 0 EV).
    Compare { image: PathBuf, reference: PathBuf },
    /// BRDF slice images (θh across, θd down) of the shading models: PNG and EXR (f·π) per
    /// model and a side-by-side PNG, from the WGSL every technique shades with.
    BrdfSlice(brdf_slice::SliceArgs),
    /// Print every technique's parameters (name, what it does, higher/lower, range, default) as
    /// the Markdown tables of docs/parameters.md.
    Params,
    /// Benchmarks: BVH traversal Mrays/s and reference path tracer ms/frame.
    Bench {
        /// Image size: N or WxH.
        #[arg(long, default_value = "256")]
        size: String,
        /// Timed frames per measurement (after one warm-up frame).
        #[arg(long, default_value_t = 8)]
        frames: u32,
        /// Scenes to measure (default: cornell and the largest built-in scene).
        #[arg(long)]
        scene: Vec<String>,
        /// Per-pass GPU ms (min, median, max) of every technique of this preset instead, at
        /// the preset's size (or `--size` when given explicitly).
        #[arg(long)]
        preset: Option<PathBuf>,
        /// Frames rendered before the timed ones (after the calibration warm-up), with --preset.
        #[arg(long, default_value_t = 8)]
        warmup: u32,
        /// Write the --preset results as JSON here.
        #[arg(long)]
        json: Option<PathBuf>,
    },
}

/// Loads the preset with its overrides first (bad input fails before any GPU work), then the device.
fn preset_and_gpu(
    preset: Option<PathBuf>,
    overrides: &Overrides,
    backend: BackendChoice,
) -> Result<(LoadedPreset, std::sync::Arc<Gpu>)> {
    let mut p = LoadedPreset::load_or_default(preset.as_deref())?;
    p.apply(overrides)?;
    let gpu = std::sync::Arc::new(Gpu::new(backend)?);
    println!("adapter: {}", gpu.summary);
    Ok((p, gpu))
}

fn view(
    preset: Option<PathBuf>,
    no_watch: bool,
    window_shot: Option<(f64, PathBuf)>,
    overrides: &Overrides,
    backend: BackendChoice,
) -> Result<()> {
    // The default preset from its file when run in the repository, so edits hot-reload.
    let default_file = PathBuf::from("presets/cornell.toml");
    let preset = preset.or_else(|| default_file.exists().then_some(default_file));
    let mut p = LoadedPreset::load_or_default(preset.as_deref())?;
    p.apply(overrides)?;
    let mut options = crate::app::ViewerOptions::new(p);
    options.watch = !no_watch;
    options.window_shot = window_shot;
    options.backend = backend;
    crate::app::run(options)
}

pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        None => view(None, false, None, &Overrides::default(), cli.backend),
        Some(Command::View {
            preset,
            no_watch,
            window_shot_after,
            window_shot,
            overrides,
        }) => {
            let shot = window_shot_after.map(|s| {
                let path = window_shot.unwrap_or_else(|| PathBuf::from("out/viewer/window.png"));
                (s, path)
            });
            view(preset, no_watch, shot, &overrides, cli.backend)
        }
        Some(Command::Shot {
            preset,
            out,
            verbose,
            overrides,
        }) => {
            let (p, gpu) = preset_and_gpu(preset, &overrides, cli.backend)?;
            jobs::shot(gpu, &p, &out, verbose)
        }
        Some(Command::Reference {
            preset,
            cache,
            force,
            overrides,
        }) => {
            let (p, gpu) = preset_and_gpu(preset, &overrides, cli.backend)?;
            let path = jobs::reference(gpu, &p, &cache, force)?;
            println!("reference: {}", path.display());
            Ok(())
        }
        Some(Command::Compare { image, reference }) => {
            let a = io::read_exr(&image)?;
            let b = io::read_exr(&reference)?;
            let m = metrics::compare(&a, &b)?;
            let flip = crate::compare::flip::ldr_flip(
                &a,
                &b,
                &crate::compare::tonemap::Settings::default(),
            )?;
            println!(
                "MSE {:.6e}  relMSE {:.6e}  SMAPE {:.6e}  FLIP {:.6e}",
                m.mse, m.rel_mse, m.smape, flip
            );
            Ok(())
        }
        Some(Command::Converge {
            file,
            out,
            shard,
            merge,
            cache,
            overrides,
        }) => {
            use crate::experiment::run;
            if !merge.is_empty() {
                let out = out.unwrap_or_else(|| PathBuf::from("out/converge/merged"));
                run::merge(&merge, &out)?;
                println!("report: {}", out.join("report.md").display());
                return Ok(());
            }
            let (p, gpu) = preset_and_gpu(file, &overrides, cli.backend)?;
            let name = run::experiment_name(&p);
            let out = out.unwrap_or_else(|| {
                let mut dir = PathBuf::from("out/converge").join(&name);
                if let Some(s) = shard {
                    dir = PathBuf::from("out/converge")
                        .join(format!("{name}-shard-{}-of-{}", s.index, s.count));
                }
                dir
            });
            let opts = run::ConvergeOptions {
                out: out.clone(),
                cache,
                shard,
                quiet: false,
            };
            run::converge(gpu, &p, &opts)?;
            println!("report: {}", out.join("report.md").display());
            Ok(())
        }
        Some(Command::Study {
            file,
            out,
            size,
            budget_scale,
            cache,
            quiet,
            resume,
            scenes,
        }) => {
            use crate::experiment::study;
            let size = size.as_deref().map(crate::preset::parse_size).transpose()?;
            let s = study::Study::load(&file, size, budget_scale)?;
            let gpu = std::sync::Arc::new(Gpu::new(cli.backend)?);
            if !quiet {
                println!("adapter: {}", gpu.summary);
            }
            let out = out.unwrap_or_else(|| PathBuf::from("out/study").join(&s.name));
            let opts = study::StudyOptions {
                out: out.clone(),
                cache,
                quiet,
                resume,
                scenes,
            };
            let report = study::run_study(gpu, &s, &opts)?;
            if !quiet {
                println!("study took {:.0} s", report.header.wall_seconds);
            }
            println!("report: {}", out.join("report.md").display());
            Ok(())
        }
        Some(Command::BrdfSlice(args)) => brdf_slice::run(&args, cli.backend),
        Some(Command::Params) => {
            print!("{}", crate::techniques::params_markdown());
            Ok(())
        }
        Some(Command::Bench {
            size,
            frames,
            scene,
            preset: Some(path),
            warmup,
            json,
        }) => {
            let mut p = LoadedPreset::load(&path)?;
            if std::env::args().any(|a| a == "--size" || a.starts_with("--size=")) {
                p.preset.render.size = crate::preset::parse_size(&size)?;
            }
            let _ = scene;
            let gpu = std::sync::Arc::new(Gpu::new(cli.backend)?);
            println!("adapter: {}", gpu.summary);
            let results = bench::preset(gpu.clone(), &p, frames.max(1), warmup)?;
            if let Some(json) = json {
                let record = serde_json::json!({
                    "preset": path.display().to_string(),
                    "adapter": gpu.summary,
                    "size": p.preset.render.size,
                    "git_commit": crate::experiment::run::git_commit(),
                    "techniques": results,
                });
                std::fs::write(&json, serde_json::to_string_pretty(&record)?)
                    .map_err(|e| anyhow::anyhow!("writing {}: {e}", json.display()))?;
                println!("\nJSON: {}", json.display());
            }
            Ok(())
        }
        Some(Command::Bench {
            size,
            frames,
            scene,
            preset: None,
            ..
        }) => {
            let gpu = std::sync::Arc::new(Gpu::new(cli.backend)?);
            println!("adapter: {}", gpu.summary);
            bench::run(
                gpu,
                crate::preset::parse_size(&size)?,
                frames.max(1),
                &scene,
            )
        }
    }
}
