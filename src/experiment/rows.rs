//! The records an experiment writes and reads back: one `convergence.csv` row per run and
//! frame, and the `summary.json` reproducibility record with per-run results.

use super::report::{self, Analysis};
use super::spec::{RunSpec, Shard};
use anyhow::{Context, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// One row of `convergence.csv`: a run after one more frame. Times and rays are cumulative
/// since the run started; errors are against the reference of the scene state the frame saw.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Row {
    pub run: usize,
    pub label: String,
    pub technique: String,
    pub seed: u32,
    pub budget: Option<f64>,
    /// Frames rendered so far (1 after the first frame).
    pub frame: u32,
    /// Scene state: 0 before the first event, k after the k-th.
    pub state: usize,
    pub gpu_ms: f64,
    pub gpu_ms_cum: f64,
    pub wall_ms: f64,
    pub wall_ms_cum: f64,
    /// `timestamps`, or `wall` where the adapter gave no usable timestamps.
    pub timing: String,
    /// The run's clock check failed (calibration kernel drifted over 10%): times not comparable.
    #[serde(default)]
    pub clock_flagged: bool,
    pub rays: u64,
    pub rays_per_pixel: f64,
    pub rays_camera: u64,
    pub rays_shadow: u64,
    pub rays_indirect: u64,
    pub rays_probe: u64,
    pub rays_surfel: u64,
    pub rays_cache: u64,
    pub rays_candidate: u64,
    pub rays_reuse: u64,
    pub mse: f64,
    pub rel_mse: f64,
    pub smape: f64,
    pub flip: f64,
    /// Mean luminance of the frame over the reference's (1: no energy gained or lost); empty
    /// where the reference is black.
    #[serde(default)]
    pub energy: Option<f64>,
    /// Real-time mode: mean change of the displayed luminance since the previous frame, over
    /// the pixels that reproject (camera motion undone); empty on the first frame.
    #[serde(default)]
    pub flicker: Option<f64>,
    /// The same between this frame's and the previous frame's references.
    #[serde(default)]
    pub flicker_reference: Option<f64>,
    /// A playing scene: the frame's scene time (seconds).
    #[serde(default)]
    pub scene_time: Option<f64>,
    /// A playing scene: pixels a moving object uncovered in the `ghost_frames` frames before
    /// this one (where a lagging cache leaves a ghost).
    #[serde(default)]
    pub ghost_pixels: u32,
    /// Mean FLIP over those pixels, and over the rest of the image.
    #[serde(default)]
    pub ghost_flip: Option<f64>,
    #[serde(default)]
    pub rest_flip: Option<f64>,
    /// GPU ms of this frame per pass: `name=ms;name=ms`.
    pub passes: String,
}

impl Row {
    pub fn error(&self, m: super::Metric) -> f64 {
        match m {
            super::Metric::Mse => self.mse,
            super::Metric::RelMse => self.rel_mse,
            super::Metric::Smape => self.smape,
            super::Metric::Flip => self.flip,
        }
    }
}

/// What the JSON summary says about one run.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct RunSummary {
    pub spec: RunSpec,
    /// Parameters the run rendered with (after the budget was mapped).
    pub params: toml::Table,
    /// Measured rays per pixel per frame.
    pub rays_per_pixel_per_frame: f64,
    pub frames: u32,
    pub gpu_ms_total: f64,
    pub gpu_ms_per_frame: f64,
    /// Median GPU ms of the run's frames (every frame, scored or not).
    #[serde(default)]
    pub gpu_ms_median: f64,
    /// Mean GPU ms per frame of each pass.
    pub gpu_ms_by_pass: std::collections::BTreeMap<String, f64>,
    pub passes_run: Vec<String>,
    pub passes_skipped: Vec<String>,
    pub final_mse: f64,
    pub final_rel_mse: f64,
    pub final_smape: f64,
    pub final_flip: f64,
    pub non_finite_pixels: usize,
    /// Last frame, relative to the output folder.
    pub image: String,
    /// The timing protocol's clock check (`gpu::calibrate`).
    #[serde(default)]
    pub clock_check: crate::gpu::calibrate::ClockCheck,
    /// Median over the scored frames of each frame's error (the experiment's metric): what a
    /// real-time run shows on a typical frame.
    #[serde(default)]
    pub median_error: Option<f64>,
    /// Real-time mode: mean flicker of the run over mean flicker of the references on the same
    /// frames (1: as stable as the ground truth; above: flickers more).
    #[serde(default)]
    pub flicker_ratio: Option<f64>,
    /// Where the run's wall-clock time went on the host (seconds): what makes a study long.
    #[serde(default)]
    pub wall_s: RunWallTime,
}

/// A run's host wall time by phase, in seconds.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct RunWallTime {
    /// Creating the engine: shader composition, pipelines, the technique's buffers.
    pub setup: f64,
    /// The timing protocol's warm-ups (clock stabilisation), every chunk's.
    pub warm_up: f64,
    /// Submitting and finishing the frames.
    pub frames: f64,
    /// Reading the scored frames back and scoring them (errors, FLIP, flicker).
    pub score: f64,
    /// Writing the last frame (PNG, EXR, JSON).
    pub write: f64,
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct ReferenceInfo {
    pub state: usize,
    /// Real-time mode: the frame this reference was rendered for (its camera and seed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame: Option<u32>,
    pub from_frame: u32,
    pub key: String,
    pub cache_file: String,
    pub spp: u32,
    pub seed: u32,
}

/// Reproducibility record and results: `summary.json`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Summary {
    pub experiment: String,
    pub file: Option<String>,
    /// SHA-256 of the experiment as run (file text after command-line overrides).
    pub preset_sha256: String,
    pub git_commit: String,
    pub adapter: crate::gpu::AdapterSummary,
    pub size: [u32; 2],
    pub seeds: Vec<u32>,
    pub tonemap: crate::preset::TonemapSettings,
    pub settings: super::ExperimentSettings,
    /// Runs in the whole experiment (a shard holds some of them).
    pub total_runs: usize,
    pub shards: Vec<Shard>,
    pub references: Vec<ReferenceInfo>,
    /// A playing scene that stops (`[scene] play_until`): the first frame of the held pose.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub motion_stop_frame: Option<u32>,
    pub runs: Vec<RunSummary>,
    /// Recomputed from the rows whenever outputs are written (merges included), so it is not read back.
    #[serde(skip_deserializing, default)]
    pub analysis: Analysis,
}

/// Reads a shard's (or a whole run's) outputs back: summary and rows.
pub fn read_output_dir(dir: &Path) -> Result<(Summary, Vec<Row>)> {
    let text = std::fs::read_to_string(dir.join("summary.json"))
        .with_context(|| format!("reading {}", dir.join("summary.json").display()))?;
    let mut summary: Summary = serde_json::from_str(&text)
        .with_context(|| format!("parsing {}", dir.join("summary.json").display()))?;
    let mut reader = csv::Reader::from_path(dir.join("convergence.csv"))
        .with_context(|| format!("reading {}", dir.join("convergence.csv").display()))?;
    let rows = reader
        .deserialize()
        .collect::<std::result::Result<Vec<Row>, _>>()
        .with_context(|| format!("parsing {}", dir.join("convergence.csv").display()))?;
    summary.analysis = report::analyse(&summary, &rows);
    Ok((summary, rows))
}
