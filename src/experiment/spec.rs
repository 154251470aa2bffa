//! The `[experiment]` table of a preset: frames or seconds per run, seeds, sweeps over a
//! technique entry's parameters or ray budget (crossed), scripted events, and how the report
//! summarises. The runs are the preset's `[[techniques]]` entries expanded by the sweeps and
//! seeds, in a fixed order, so `--shard i/n` picks the same runs on every machine.

use crate::preset::LoadedPreset;
use crate::scene::{Camera, Scene};
use anyhow::{bail, ensure, Result};
use glam::Vec3;
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ExperimentSettings {
    /// Name of the experiment (default: the file stem); names the output folder.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    /// Frames per run (an upper bound when `seconds` is given).
    #[serde(default = "default_frames")]
    pub frames: u32,
    /// Stop a run once its summed GPU time reaches this many seconds (0 = frames only).
    #[serde(default)]
    pub seconds: f64,
    /// Seeds each run is repeated with (default: the preset's `render.seed`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub seeds: Vec<u32>,
    /// Error metric the report's tables use: `mse`, `rel_mse`, `smape` or `flip`.
    #[serde(default)]
    pub metric: Metric,
    /// Label of the run ratios are taken against (default: the first `reference` run).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub baseline: Option<String>,
    /// Common time budget in GPU ms for the equal-time table (default: the shortest run's
    /// total GPU time, so every run reaches it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub equal_time_ms: Option<f64>,
    /// Target error for the time-to-error table (default: the largest of the runs' lowest
    /// errors, so every run reaches it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target_error: Option<f64>,
    /// After an event a run has settled when its error is back under this factor times the
    /// larger of its error on the frame before the event and its steady level in the new
    /// state (median of the state's last frames): a scene made harder by the event (a light
    /// switched on adds noise) is not counted as lag.
    #[serde(default = "default_settle_factor")]
    pub settle_factor: f64,
    /// An absolute error a run must get back under after an event (replaces
    /// `settle_factor`): right when the event changes how hard the image is, e.g. a light
    /// switched on, where the error before the event is not a fair target.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub settle_error: Option<f64>,
    #[serde(default, rename = "sweep", skip_serializing_if = "Vec::is_empty")]
    pub sweeps: Vec<Sweep>,
    #[serde(default, rename = "event", skip_serializing_if = "Vec::is_empty")]
    pub events: Vec<Event>,
}

fn default_frames() -> u32 {
    64
}
fn default_settle_factor() -> f64 {
    1.1
}

#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum Metric {
    Mse,
    #[default]
    RelMse,
    Smape,
    Flip,
}

impl Metric {
    pub fn name(self) -> &'static str {
        match self {
            Metric::Mse => "mse",
            Metric::RelMse => "rel_mse",
            Metric::Smape => "smape",
            Metric::Flip => "flip",
        }
    }
}

/// Runs one technique entry once per value; several sweeps of one entry are crossed.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Sweep {
    /// Label (or name) of the `[[techniques]]` entry.
    pub technique: String,
    /// A parameter of that technique, or `budget`: rays per pixel per frame, mapped to
    /// parameters by the technique (the viewer's ray-budget slider).
    pub param: String,
    pub values: Vec<toml::Value>,
}

/// A scripted change at the start of `frame` (before it renders), to measure temporal lag.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Event {
    pub frame: u32,
    /// Shown in the report and plots (default: a description of the change).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub label: Option<String>,
    /// Move the camera here.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<Camera>,
    /// Edit the material of this name: `emissive` (switching a light on or off),
    /// `base_color`, `roughness`, `metallic`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub material: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub emissive: Option<[f32; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub base_color: Option<[f32; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub roughness: Option<f32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub metallic: Option<f32>,
    /// Edit the punctual light of this index: `position`, `intensity` (0 switches it off).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub light: Option<usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub position: Option<[f32; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub intensity: Option<[f32; 3]>,
}

impl Event {
    pub fn describe(&self) -> String {
        if let Some(l) = &self.label {
            return l.clone();
        }
        let mut parts = Vec::new();
        if self.camera.is_some() {
            parts.push("camera moved".to_string());
        }
        if let Some(m) = &self.material {
            parts.push(format!("material '{m}' edited"));
        }
        if let Some(l) = self.light {
            parts.push(format!("light {l} edited"));
        }
        format!("frame {}: {}", self.frame, parts.join(", "))
    }

    /// Applies the change to a scene and camera; errors name what is wrong.
    pub fn apply(&self, scene: &mut Scene, camera: &mut Camera) -> Result<()> {
        let material_fields = self.emissive.is_some()
            || self.base_color.is_some()
            || self.roughness.is_some()
            || self.metallic.is_some();
        let light_fields = self.position.is_some() || self.intensity.is_some();
        ensure!(
            self.camera.is_some() || self.material.is_some() || self.light.is_some(),
            "event at frame {}: nothing to change (give camera, material or light)",
            self.frame
        );
        ensure!(
            !material_fields || self.material.is_some(),
            "event at frame {}: emissive/base_color/roughness/metallic need `material`",
            self.frame
        );
        ensure!(
            !light_fields || self.light.is_some(),
            "event at frame {}: position/intensity need `light`",
            self.frame
        );
        if let Some(c) = self.camera {
            *camera = c;
        }
        if let Some(name) = &self.material {
            let Some(m) = scene.materials.iter_mut().find(|m| &m.name == name) else {
                let names: Vec<&str> = scene.materials.iter().map(|m| m.name.as_str()).collect();
                bail!(
                    "event at frame {}: the scene has no material '{name}' (it has: {})",
                    self.frame,
                    names.join(", ")
                );
            };
            let finite = |v: [f32; 3]| v.iter().all(|x| x.is_finite() && *x >= 0.0);
            if let Some(e) = self.emissive {
                ensure!(finite(e), "event at frame {}: bad emissive", self.frame);
                m.emissive = Vec3::from(e);
            }
            if let Some(b) = self.base_color {
                ensure!(finite(b), "event at frame {}: bad base_color", self.frame);
                m.base_color = Vec3::from(b).extend(m.base_color.w);
            }
            if let Some(r) = self.roughness {
                m.roughness = r.clamp(0.0, 1.0);
            }
            if let Some(v) = self.metallic {
                m.metallic = v.clamp(0.0, 1.0);
            }
        }
        if let Some(i) = self.light {
            let count = scene.lights.len();
            let Some(l) = scene.lights.get_mut(i) else {
                bail!(
                    "event at frame {}: light {i} does not exist (the scene has {count} punctual lights)",
                    self.frame
                );
            };
            if let Some(p) = self.position {
                l.position = Vec3::from(p);
            }
            if let Some(v) = self.intensity {
                l.intensity = Vec3::from(v);
            }
        }
        Ok(())
    }
}

/// One run of an experiment: a technique entry with swept values applied and a seed.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct RunSpec {
    /// Position in the full (unsharded) run list.
    pub index: usize,
    /// Unique, file-name safe: entry label, swept values, seed.
    pub label: String,
    /// The `[[techniques]]` entry's label it comes from.
    pub entry: String,
    pub technique: String,
    pub params: toml::Table,
    /// Rays per pixel per frame asked for (mapped to parameters by the technique).
    pub budget: Option<f64>,
    pub seed: u32,
}

fn value_text(v: &toml::Value) -> String {
    match v {
        toml::Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

/// Characters safe in file names and CSV cells.
fn safe(s: &str) -> String {
    s.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || "-_.=".contains(c) {
                c
            } else {
                '-'
            }
        })
        .collect()
}

/// Expands the preset's techniques by sweeps and seeds, in a fixed order.
pub fn expand_runs(p: &LoadedPreset) -> Result<Vec<RunSpec>> {
    let Some(exp) = &p.preset.experiment else {
        bail!("the preset has no [experiment] table");
    };
    let entries = &p.preset.techniques;
    ensure!(!entries.is_empty(), "the experiment has no techniques");
    for s in &exp.sweeps {
        ensure!(
            entries.iter().any(|e| e.display_name() == s.technique),
            "sweep over '{}': no [[techniques]] entry has that label (labels: {})",
            s.technique,
            entries
                .iter()
                .map(|e| e.display_name())
                .collect::<Vec<_>>()
                .join(", ")
        );
        ensure!(
            !s.values.is_empty(),
            "sweep over '{}.{}' has no values",
            s.technique,
            s.param
        );
        if s.param == "budget" {
            for v in &s.values {
                ensure!(
                    v.as_float()
                        .or(v.as_integer().map(|i| i as f64))
                        .is_some_and(|b| b > 0.0),
                    "sweep '{}.budget': {v} is not a positive number of rays per pixel",
                    s.technique
                );
            }
        }
    }
    let mut labels = std::collections::HashSet::new();
    for e in entries {
        ensure!(
            labels.insert(e.display_name().to_string()),
            "two [[techniques]] entries share the label '{}': give one a `label`",
            e.display_name()
        );
    }
    let seeds = if exp.seeds.is_empty() {
        vec![p.preset.render.seed]
    } else {
        exp.seeds.clone()
    };
    let mut runs = Vec::new();
    for entry in entries {
        // Cross product of this entry's sweeps: one Vec<(param, value)> per combination.
        let mut combos: Vec<Vec<(String, toml::Value)>> = vec![Vec::new()];
        for s in exp
            .sweeps
            .iter()
            .filter(|s| s.technique == entry.display_name())
        {
            combos = combos
                .into_iter()
                .flat_map(|c| {
                    s.values.iter().map(move |v| {
                        let mut c = c.clone();
                        c.push((s.param.clone(), v.clone()));
                        c
                    })
                })
                .collect();
        }
        for combo in &combos {
            for &seed in &seeds {
                let mut params = entry.params.clone();
                let mut budget = entry.budget;
                let mut label = entry.display_name().to_string();
                for (k, v) in combo {
                    if k == "budget" {
                        budget = v.as_float().or(v.as_integer().map(|i| i as f64));
                    } else {
                        params.insert(k.clone(), v.clone());
                    }
                    label.push_str(&format!(" {k}={}", value_text(v)));
                }
                if seeds.len() > 1 {
                    label.push_str(&format!(" seed={seed}"));
                }
                runs.push(RunSpec {
                    index: runs.len(),
                    label: safe(&label),
                    entry: entry.display_name().to_string(),
                    technique: entry.name.clone(),
                    params,
                    budget,
                    seed,
                });
            }
        }
    }
    Ok(runs)
}

/// `i/n`: this process runs every n-th run starting at i.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Shard {
    pub index: usize,
    pub count: usize,
}

impl std::str::FromStr for Shard {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> Result<Shard> {
        let (i, n) = s
            .split_once('/')
            .ok_or_else(|| anyhow::anyhow!("--shard {s}: expected I/N, e.g. 0/4"))?;
        let index: usize = i
            .trim()
            .parse()
            .map_err(|_| anyhow::anyhow!("--shard {s}: bad I"))?;
        let count: usize = n
            .trim()
            .parse()
            .map_err(|_| anyhow::anyhow!("--shard {s}: bad N"))?;
        ensure!(count > 0 && index < count, "--shard {s}: need 0 <= I < N");
        Ok(Shard { index, count })
    }
}

impl Shard {
    pub fn takes(&self, run_index: usize) -> bool {
        run_index % self.count == self.index
    }
}
