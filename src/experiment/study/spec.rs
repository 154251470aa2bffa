//! A study file (`gilab study FILE`, e.g. `presets/studies/headline.toml`): scenes, the
//! families compared on them with their settings, and frame-time budgets. Each scene becomes
//! one real-time `converge` experiment (written beside the report as `experiment.toml`, so it
//! can be run alone).

use crate::preset::{LoadedPreset, Overrides, TechniqueEntry};
use crate::techniques::create_technique;
use anyhow::{anyhow, bail, ensure, Context, Result};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

use crate::experiment::{CameraKey, ExperimentSettings, Metric, Mode};

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct StudyFile {
    pub study: StudySettings,
    /// `[[family]]`: a technique and its settings (cheaper to richer).
    #[serde(rename = "family")]
    pub families: Vec<Family>,
    /// `[[scene]]`: where the families are compared.
    #[serde(rename = "scene")]
    pub scenes: Vec<StudyScene>,
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct StudySettings {
    /// Name of the study (default: the file stem).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    /// Image size of every scene (`--size` overrides it).
    #[serde(default = "default_size")]
    pub size: [u32; 2],
    /// Frames per run. Must be a multiple of `reference_every`, so that the last frame (the
    /// one the equal-time images show) is scored.
    #[serde(default = "default_frames")]
    pub frames: u32,
    /// Score every N-th frame against a reference rendered for it (real-time mode).
    #[serde(default = "default_reference_every")]
    pub reference_every: u32,
    /// Samples per pixel of the per-frame references.
    #[serde(default = "default_reference_spp")]
    pub reference_spp: u32,
    /// Frame-time budgets in GPU ms per frame.
    pub budgets_ms: Vec<f64>,
    /// The error the budgets are decided by (`rel_mse`, `flip`, `smape`, `mse`).
    #[serde(default)]
    pub metric: Metric,
    /// Each family without and with the shared denoiser (a family may override it).
    #[serde(default = "default_denoise")]
    pub denoise: Vec<bool>,
    #[serde(default = "default_seed")]
    pub seed: u32,
    /// The bias table marks a family's energy as lost or gained beyond this fraction (issue
    /// 35's 5%).
    #[serde(default = "default_bias_tolerance")]
    pub bias_tolerance: f64,
}

fn default_size() -> [u32; 2] {
    [1920, 1080]
}
fn default_frames() -> u32 {
    24
}
fn default_reference_every() -> u32 {
    8
}
fn default_reference_spp() -> u32 {
    256
}
fn default_denoise() -> Vec<bool> {
    vec![false, true]
}
fn default_seed() -> u32 {
    1
}
fn default_bias_tolerance() -> f64 {
    0.05
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Family {
    /// Names the family's curves and runs: letters, digits, `-` and `_`.
    pub label: String,
    pub technique: String,
    /// Overrides `study.denoise` for this family.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub denoise: Option<Vec<bool>>,
    /// `[[family.variant]]`: one point of the family's curve each.
    #[serde(rename = "variant")]
    pub variants: Vec<Variant>,
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Variant {
    /// `default` marks the shipped defaults: the bias table reads that one.
    pub name: String,
    #[serde(default, skip_serializing_if = "toml::Table::is_empty")]
    pub params: toml::Table,
    /// Rays per pixel per frame, mapped to parameters by the technique (the viewer's slider).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub budget: Option<f64>,
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct StudyScene {
    /// Names the scene's folder: letters, digits, `-` and `_`.
    pub name: String,
    /// A preset (relative to the study file) giving the scene, camera, tone mapping and shading;
    /// its techniques and experiment are replaced by the study's.
    pub preset: String,
    /// The effect this scene tests, a column of the bias table (e.g. "diffuse", "mirror").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub effect: Option<String>,
    /// Families compared here (default: all).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub families: Vec<String>,
    /// Settings run here (variant names; default: every family's all). An effect scene of the
    /// bias table needs only `["default"]`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub variants: Vec<String>,
    /// Overrides the study's and the families' `denoise` here.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub denoise: Option<Vec<bool>>,
    /// Preset keys set on top of the preset, as `--set` takes them (`scene.params.lamp=4`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub set: Vec<String>,
    /// A camera path (`[[scene.camera]]`), as an experiment's; default: the preset's camera.
    #[serde(default, rename = "camera", skip_serializing_if = "Vec::is_empty")]
    pub camera_path: Vec<CameraKey>,
}

/// One run of a scene's experiment, as the study names it.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct RunName {
    pub label: String,
    pub family: String,
    pub variant: String,
    pub denoise: bool,
}

/// A loaded study: the file, where it came from, and the settings after the command line.
#[derive(Clone, Debug)]
pub struct Study {
    pub file: StudyFile,
    pub path: PathBuf,
    pub name: String,
}

fn plain_name(what: &str, s: &str) -> Result<()> {
    ensure!(
        !s.is_empty()
            && s.chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_'),
        "{what} '{s}': use letters, digits, '-' and '_' only (it names files)"
    );
    Ok(())
}

fn absolute(p: &Path) -> Result<String> {
    Ok(std::path::absolute(p)
        .with_context(|| format!("{}", p.display()))?
        .display()
        .to_string())
}

impl Study {
    /// Reads and checks a study file: every family's technique and parameters, every scene's
    /// preset and overrides, before any GPU work.
    /// `size` and `budget_scale` come from the command line.
    pub fn load(path: &Path, size: Option<[u32; 2]>, budget_scale: f64) -> Result<Study> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read study {}", path.display()))?;
        let mut file: StudyFile = toml::from_str(&text)
            .map_err(|e| crate::preset::toml_error(&path.display().to_string(), &text, &e))?;
        if let Some(size) = size {
            file.study.size = size;
        }
        ensure!(
            budget_scale.is_finite() && budget_scale > 0.0,
            "--budget-scale {budget_scale}: a positive factor"
        );
        for b in &mut file.study.budgets_ms {
            *b *= budget_scale;
        }
        let name = file.study.name.clone().unwrap_or_else(|| {
            path.file_stem()
                .map_or("study".into(), |s| s.to_string_lossy().into_owned())
        });
        let study = Study {
            file,
            path: path.to_path_buf(),
            name,
        };
        study.check()?;
        Ok(study)
    }

    fn check(&self) -> Result<()> {
        let s = &self.file.study;
        ensure!(
            s.size[0] >= 8 && s.size[1] >= 8,
            "study.size {:?}: at least 8x8",
            s.size
        );
        ensure!(s.reference_every >= 1, "study.reference_every: at least 1");
        ensure!(
            s.frames >= s.reference_every && s.frames.is_multiple_of(s.reference_every),
            "study.frames = {} must be a multiple of reference_every = {} (the last frame is the one the images show, and it needs its reference)",
            s.frames,
            s.reference_every
        );
        ensure!(
            !s.budgets_ms.is_empty(),
            "study.budgets_ms: give at least one budget"
        );
        ensure!(
            s.budgets_ms.iter().all(|b| b.is_finite() && *b > 0.0),
            "study.budgets_ms: budgets must be positive milliseconds"
        );
        ensure!(
            !s.denoise.is_empty(),
            "study.denoise: give [false], [true] or both"
        );
        ensure!(
            !self.file.families.is_empty(),
            "the study has no [[family]]"
        );
        ensure!(!self.file.scenes.is_empty(), "the study has no [[scene]]");
        let mut seen = std::collections::HashSet::new();
        for f in &self.file.families {
            plain_name("family", &f.label)?;
            ensure!(
                seen.insert(&f.label),
                "two families are labelled '{}'",
                f.label
            );
            ensure!(
                !f.variants.is_empty(),
                "family '{}' has no [[family.variant]]",
                f.label
            );
            let mut names = std::collections::HashSet::new();
            for v in &f.variants {
                plain_name(&format!("family '{}': variant", f.label), &v.name)?;
                ensure!(
                    names.insert(&v.name),
                    "family '{}': two variants are named '{}'",
                    f.label,
                    v.name
                );
                create_technique(&f.technique)
                    .with_context(|| format!("family '{}'", f.label))?
                    .set_params_from_table(&v.params)
                    .with_context(|| format!("family '{}', variant '{}'", f.label, v.name))?;
            }
        }
        let mut scenes = std::collections::HashSet::new();
        for sc in &self.file.scenes {
            plain_name("scene", &sc.name)?;
            ensure!(
                scenes.insert(&sc.name),
                "two scenes are named '{}'",
                sc.name
            );
            for v in &sc.variants {
                ensure!(
                    self.file
                        .families
                        .iter()
                        .any(|f| f.variants.iter().any(|x| &x.name == v)),
                    "scene '{}': no family has a variant named '{v}'",
                    sc.name
                );
            }
            if let Some(d) = &sc.denoise {
                ensure!(
                    !d.is_empty(),
                    "scene '{}': denoise = [] runs nothing",
                    sc.name
                );
            }
            for f in &sc.families {
                ensure!(
                    self.file.families.iter().any(|x| &x.label == f),
                    "scene '{}': no family is labelled '{f}'",
                    sc.name
                );
            }
            self.scene_preset(sc)
                .and_then(|p| p.load_scene())
                .with_context(|| format!("scene '{}'", sc.name))?;
        }
        Ok(())
    }

    pub fn families_of<'a>(&'a self, scene: &'a StudyScene) -> impl Iterator<Item = &'a Family> {
        self.file
            .families
            .iter()
            .filter(move |f| scene.families.is_empty() || scene.families.contains(&f.label))
    }

    /// The runs of a scene, in the order its experiment lists them.
    pub fn run_names(&self, scene: &StudyScene) -> Vec<RunName> {
        let mut v = Vec::new();
        for f in self.families_of(scene) {
            let variants = f
                .variants
                .iter()
                .filter(|v| scene.variants.is_empty() || scene.variants.contains(&v.name));
            for var in variants {
                let denoise = scene
                    .denoise
                    .as_ref()
                    .or(f.denoise.as_ref())
                    .unwrap_or(&self.file.study.denoise);
                for &d in denoise {
                    v.push(RunName {
                        label: format!(
                            "{}-{}{}",
                            f.label,
                            var.name,
                            if d { "-denoised" } else { "" }
                        ),
                        family: f.label.clone(),
                        variant: var.name.clone(),
                        denoise: d,
                    });
                }
            }
        }
        v
    }

    /// The scene's real-time experiment: its preset with the study's size, seed, references,
    /// techniques (families × variants × denoiser) and `[experiment]`.
    pub fn scene_preset(&self, sc: &StudyScene) -> Result<LoadedPreset> {
        let s = &self.file.study;
        let dir = self.path.parent().unwrap_or(Path::new("."));
        let path = dir.join(&sc.preset);
        let mut p = LoadedPreset::load(&path)?;
        let overrides = Overrides {
            size: Some(format!("{}x{}", s.size[0], s.size[1])),
            seed: Some(s.seed),
            set: sc.set.clone(),
            ..Overrides::default()
        };
        p.apply(&overrides)?;
        p.preset.render.reference_spp = s.reference_spp;
        // Files the preset names, absolute: the experiment file is written elsewhere.
        if let Some(f) = p.scene_path() {
            p.preset.scene.source = absolute(&f)?;
        }
        if let Some(f) = p.environment_path() {
            p.preset.scene.environment = Some(absolute(&f)?);
        }
        let mut entries = Vec::new();
        for (f, run) in self.families_of(sc).flat_map(|f| {
            self.run_names(sc)
                .into_iter()
                .filter(move |r| r.family == f.label)
                .map(move |r| (f, r))
        }) {
            let v = f
                .variants
                .iter()
                .find(|v| v.name == run.variant)
                .ok_or_else(|| anyhow!("variant '{}'", run.variant))?;
            entries.push(TechniqueEntry {
                label: Some(run.label.clone()),
                params: v.params.clone(),
                budget: v.budget,
                denoise: run.denoise,
                ..TechniqueEntry::new(&f.technique)
            });
        }
        if entries.is_empty() {
            bail!("no families to run");
        }
        p.preset.techniques = entries;
        p.preset.view = Default::default();
        p.preset.experiment = Some(ExperimentSettings {
            name: Some(sc.name.clone()),
            frames: s.frames,
            metric: s.metric,
            mode: Mode::RealTime,
            reference_every: s.reference_every,
            frame_ms: s.budgets_ms.clone(),
            camera_path: sc.camera_path.clone(),
            ..toml::from_str::<ExperimentSettings>("").expect("the defaults parse")
        });
        // The text a user can run alone (`gilab converge scenes/NAME/experiment.toml`).
        p.text = p.to_toml()?;
        Ok(p)
    }
}
