//! The `[experiment]` table of a preset: frames or seconds per run, seeds, sweeps over a
//! technique entry's parameters or ray budget (crossed), scripted events, and how the report
//! summarises. The runs are the preset's `[[techniques]]` entries expanded by the sweeps and
//! seeds, in a fixed order, so `--shard i/n` picks the same runs on every machine.

pub use crate::preset::experiment::{
    camera_on_path, CameraKey, Event, ExperimentSettings, Metric, Mode, Sweep,
};
use crate::preset::LoadedPreset;
use anyhow::{bail, ensure, Result};
use serde::{Deserialize, Serialize};

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
    /// The entry's `denoise`: the shared denoiser runs after every frame.
    #[serde(default)]
    pub denoise: bool,
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
                    denoise: entry.denoise,
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
