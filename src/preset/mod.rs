//! Presets (`presets/*.toml`): scene, camera, resolution, seed, sample budget, techniques with
//! parameters and tonemapping. Unknown keys are errors (typos fail loudly, with line and column).
//! CLI overrides (`--scene`, `--technique`, `--size`, `--spp`, `--seed`, `--set key=value`) are
//! applied to the parsed document before it is checked again.

pub mod animate;
pub mod experiment;

use crate::scene::animation::PoseRequest;
use crate::scene::environment::Environment;
use crate::scene::shading::ShadingSettings;
use crate::scene::{builtin, gltf_load, Camera, Scene};
use anyhow::{anyhow, bail, Context, Result};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Preset {
    pub scene: SceneRef,
    /// Overrides the scene's own camera.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<Camera>,
    #[serde(default)]
    pub render: RenderSettings,
    #[serde(default)]
    pub tonemap: TonemapSettings,
    /// The BRDF every technique shades with, and Callisto parameter overrides.
    #[serde(default, skip_serializing_if = "ShadingSettings::is_default")]
    pub shading: ShadingSettings,
    #[serde(default = "default_techniques")]
    pub techniques: Vec<TechniqueEntry>,
    /// How the viewer shows the techniques (ignored by headless commands).
    #[serde(default)]
    pub view: ViewSettings,
    /// A convergence experiment over this preset's techniques (`gilab converge`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub experiment: Option<experiment::ExperimentSettings>,
}

/// The viewer's arrangement of panes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Layout {
    Single,
    #[default]
    SideBySide,
    Grid,
    /// One image split by a draggable line between two techniques.
    Wipe,
}

impl Layout {
    pub const ALL: [Layout; 4] = [
        Layout::Single,
        Layout::SideBySide,
        Layout::Grid,
        Layout::Wipe,
    ];
    /// Panes the layout shows.
    pub fn pane_count(self) -> usize {
        match self {
            Layout::Single => 1,
            Layout::SideBySide | Layout::Wipe => 2,
            Layout::Grid => 4,
        }
    }
    pub fn label(self) -> &'static str {
        match self {
            Layout::Single => "Single",
            Layout::SideBySide => "Side by side",
            Layout::Grid => "2x2 grid",
            Layout::Wipe => "Wipe",
        }
    }
}

/// What a pane shows of its technique.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum DisplayMode {
    /// Tonemapped linear radiance.
    #[default]
    Radiance,
    /// Per-pixel sample variance (mean of r, g, b), log scale.
    Variance,
    /// Per-pixel relMSE against the reference, log scale.
    Error,
    /// Samples accumulated per pixel (debug).
    Samples,
    /// One of the technique's own debug views (pane's `debug` index).
    Debug,
}

impl DisplayMode {
    pub const ALL: [DisplayMode; 5] = [
        DisplayMode::Radiance,
        DisplayMode::Variance,
        DisplayMode::Error,
        DisplayMode::Samples,
        DisplayMode::Debug,
    ];
    pub fn label(self) -> &'static str {
        match self {
            DisplayMode::Radiance => "Radiance",
            DisplayMode::Variance => "Variance heatmap",
            DisplayMode::Error => "Error heatmap",
            DisplayMode::Samples => "Samples per pixel",
            DisplayMode::Debug => "Technique debug view",
        }
    }
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ViewSettings {
    #[serde(default)]
    pub layout: Layout,
    /// Panes in reading order; each shows one entry of `techniques` (by index).
    #[serde(default = "default_panes")]
    pub panes: Vec<PaneSettings>,
}

#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PaneSettings {
    /// Index into the preset's `techniques` list.
    pub technique: usize,
    #[serde(default)]
    pub display: DisplayMode,
    /// With `display = "debug"`: which of the technique's debug views.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub debug: usize,
}

fn is_zero(v: &usize) -> bool {
    *v == 0
}

fn default_panes() -> Vec<PaneSettings> {
    [
        (0, DisplayMode::Radiance),
        (1, DisplayMode::Radiance),
        (0, DisplayMode::Variance),
        (0, DisplayMode::Error),
    ]
    .map(|(technique, display)| PaneSettings {
        technique,
        display,
        debug: 0,
    })
    .to_vec()
}

impl Default for ViewSettings {
    fn default() -> Self {
        ViewSettings {
            layout: Layout::default(),
            panes: default_panes(),
        }
    }
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SceneRef {
    /// A built-in scene name (`cornell`, `furnace`, ...) or a path to a .gltf/.glb file
    /// (relative paths are relative to the preset file).
    pub source: String,
    /// Built-in scene parameters (e.g. furnace `albedo`).
    #[serde(default, skip_serializing_if = "toml::Table::is_empty")]
    pub params: toml::Table,
    /// An equirectangular HDR environment map (.exr or .hdr) as the sky, replacing the
    /// scene's constant sky (relative paths are relative to the preset file).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub environment: Option<String>,
    /// Turn of the environment map about +Y in degrees (right-handed: +X towards -Z).
    #[serde(
        default,
        skip_serializing_if = "is_zero_f32",
        deserialize_with = "rotation_f32"
    )]
    pub environment_rotation: f32,
    /// Radiance scale of the environment map.
    #[serde(
        default = "one_f32",
        skip_serializing_if = "is_one_f32",
        deserialize_with = "intensity_f32"
    )]
    pub environment_intensity: f32,
    /// `false` traces instanced meshes as ordinary triangles (a flat BVH) instead of a
    /// two-level BVH: to compare the two on the same scene.
    #[serde(default = "yes", skip_serializing_if = "is_true")]
    pub instancing: bool,
    /// Seconds into the scene's animations to pose it at (glTF files); unset: the rest pose.
    /// `--set scene.time=T` renders one pose, so a reference exists for any frame.
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "time_f32"
    )]
    pub time: Option<f32>,
    /// The one animation (glTF clip name) that plays; unset: every one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub animation: Option<String>,
    /// Playback speed of the animations: scene seconds per second of frames, at 60 frames a
    /// second of scene time (`render::engine::PLAYBACK_FPS`); 0 (default): the scene holds its
    /// pose. Playback starts at `time`.
    #[serde(
        default,
        skip_serializing_if = "is_zero_f32",
        deserialize_with = "time_scale_f32"
    )]
    pub time_scale: f32,
    /// Playback stops at this scene time and holds the pose there (with a positive
    /// `time_scale`): a real-time experiment then measures how long each technique takes to
    /// settle after the motion stops. Unset: playback loops on.
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "time_f32"
    )]
    pub play_until: Option<f32>,
    /// `[[scene.animate]]`: keyframes that move named objects of a built-in scene (the clip
    /// "animate"; docs/scenes.md).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub animate: Vec<animate::AnimateEntry>,
}

fn time_scale_f32<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<f32, D::Error> {
    let v = f64::deserialize(d)?;
    if !v.is_finite() {
        return Err(serde::de::Error::custom(format!(
            "time_scale {v}: expected a finite number (scene seconds per second)"
        )));
    }
    Ok(v as f32)
}

fn yes() -> bool {
    true
}
fn is_true(v: &bool) -> bool {
    *v
}

fn is_zero_f32(v: &f32) -> bool {
    *v == 0.0
}
fn is_one_f32(v: &f32) -> bool {
    *v == 1.0
}
fn one_f32() -> f32 {
    1.0
}
fn rotation_f32<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<f32, D::Error> {
    let v = f64::deserialize(d)?;
    if !v.is_finite() {
        return Err(serde::de::Error::custom(format!(
            "environment_rotation {v}: expected a finite number of degrees"
        )));
    }
    Ok(v as f32)
}
fn time_f32<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Option<f32>, D::Error> {
    let v = f64::deserialize(d)?;
    if !v.is_finite() {
        return Err(serde::de::Error::custom(format!(
            "time {v}: expected a finite number of seconds"
        )));
    }
    Ok(Some(v as f32))
}
fn intensity_f32<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<f32, D::Error> {
    let v = f64::deserialize(d)?;
    if !(v.is_finite() && v >= 0.0) {
        return Err(serde::de::Error::custom(format!(
            "environment_intensity {v}: expected a finite number >= 0"
        )));
    }
    Ok(v as f32)
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RenderSettings {
    /// Width and height in pixels.
    #[serde(default = "default_size")]
    pub size: [u32; 2],
    #[serde(default = "default_seed")]
    pub seed: u32,
    /// Samples per pixel a `shot` accumulates (frames = spp / samples_per_frame).
    #[serde(default = "default_spp")]
    pub spp: u32,
    /// Samples per pixel of the reference that errors are measured against (`gilab
    /// reference`, the viewer's background reference).
    #[serde(default = "default_reference_spp")]
    pub reference_spp: u32,
}

/// `[tonemap]`: operator, exposure, the GT curve's parameters and the zone view (defined
/// beside the display transform in compare/tonemap.rs).
pub use crate::compare::tonemap::Settings as TonemapSettings;

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TechniqueEntry {
    pub name: String,
    /// Name shown in the viewer and used for output files (default: `name`); needed when a
    /// preset lists one technique twice with different parameters.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub label: Option<String>,
    #[serde(default)]
    pub params: toml::Table,
    /// Ray budget in rays per pixel per frame the viewer's slider last asked for.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub budget: Option<f64>,
    /// Run the shared SVGF-style denoiser (src/render/denoise.rs) on the technique's output
    /// after every frame; its GPU time counts in the technique's frame time.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub denoise: bool,
}

impl TechniqueEntry {
    pub fn new(name: &str) -> TechniqueEntry {
        TechniqueEntry {
            name: name.to_string(),
            label: None,
            params: toml::Table::new(),
            budget: None,
            denoise: false,
        }
    }
    pub fn display_name(&self) -> &str {
        self.label.as_deref().unwrap_or(&self.name)
    }
}

fn default_size() -> [u32; 2] {
    [256, 256]
}
fn default_reference_spp() -> u32 {
    1024
}
fn default_seed() -> u32 {
    1
}
fn default_spp() -> u32 {
    64
}
fn default_techniques() -> Vec<TechniqueEntry> {
    vec![TechniqueEntry::new("reference")]
}

impl Default for RenderSettings {
    fn default() -> Self {
        RenderSettings {
            size: default_size(),
            seed: default_seed(),
            spp: default_spp(),
            reference_spp: default_reference_spp(),
        }
    }
}

/// Command-line overrides of a preset.
#[derive(Clone, Debug, Default, clap::Args)]
pub struct Overrides {
    /// Scene: a built-in name (cornell, furnace, many-lights, thin-wall, glossy, courtyard, material-balls, atrium, hard-cases, mirror-hall) or a .gltf/.glb path.
    #[arg(long)]
    pub scene: Option<String>,
    /// Technique to render (replaces the preset's list).
    #[arg(long)]
    pub technique: Option<String>,
    /// Image size: N (square) or WxH.
    #[arg(long)]
    pub size: Option<String>,
    /// Samples per pixel.
    #[arg(long)]
    pub spp: Option<u32>,
    #[arg(long)]
    pub seed: Option<u32>,
    /// Set any preset key: `render.seed=3`, `scene.params.albedo=0.5`, `tonemap.exposure=1`,
    /// `shading.brdf="callisto"`;
    /// a key without a section (`max_depth=4`) sets that parameter on every technique.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
}

/// A loaded preset with where it came from (for relative paths and metadata).
#[derive(Clone, Debug)]
pub struct LoadedPreset {
    pub preset: Preset,
    pub path: Option<PathBuf>,
    /// The preset file's text (empty for the built-in default).
    pub text: String,
}

/// The default preset, used when no file is given: the Cornell box.
pub const DEFAULT_PRESET: &str = include_str!("../../presets/cornell.toml");

/// Formats a TOML error as `file:line:column: message` on one line.
pub(crate) fn toml_error(path: &str, text: &str, e: &toml::de::Error) -> anyhow::Error {
    let msg = e.message().replace('\n', " ");
    match e.span() {
        Some(span) => {
            let before = &text[..span.start.min(text.len())];
            let line = before.matches('\n').count() + 1;
            let col = before
                .rfind('\n')
                .map_or(before.chars().count(), |i| before[i + 1..].chars().count())
                + 1;
            anyhow!("{path}:{line}:{col}: {msg}")
        }
        None => anyhow!("{path}: {msg}"),
    }
}

impl LoadedPreset {
    pub fn from_text(text: &str, path: Option<&Path>) -> Result<LoadedPreset> {
        let label = path.map_or("<built-in default preset>".to_string(), |p| {
            p.display().to_string()
        });
        let preset: Preset = toml::from_str(text).map_err(|e| toml_error(&label, text, &e))?;
        Ok(LoadedPreset {
            preset,
            path: path.map(Path::to_path_buf),
            text: text.to_string(),
        })
    }

    pub fn load(path: &Path) -> Result<LoadedPreset> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read preset {}", path.display()))?;
        Self::from_text(&text, Some(path))
    }

    /// `None` gives the built-in default preset.
    pub fn load_or_default(path: Option<&Path>) -> Result<LoadedPreset> {
        match path {
            Some(p) => Self::load(p),
            None => Self::from_text(DEFAULT_PRESET, None),
        }
    }

    pub fn apply(&mut self, o: &Overrides) -> Result<()> {
        let mut doc = toml::Table::try_from(&self.preset).context("serialising preset")?;
        if let Some(s) = &o.scene {
            set_path(&mut doc, "scene.source", toml::Value::String(s.clone()))?;
            // Parameters of the preset's scene do not carry over to another scene.
            if let Some(toml::Value::Table(scene)) = doc.get_mut("scene") {
                scene.remove("params");
                scene.remove("animate");
            }
            // Relative to where the user typed it, not to the preset.
            let p = Path::new(s);
            if !builtin::is_builtin(s)
                && p.is_relative()
                && (p.extension().is_some() || p.components().count() > 1)
            {
                let abs = std::env::current_dir()?.join(p);
                set_path(
                    &mut doc,
                    "scene.source",
                    toml::Value::String(abs.display().to_string()),
                )?;
            }
        }
        if let Some(t) = &o.technique {
            let mut entry = toml::Table::new();
            entry.insert("name".into(), toml::Value::String(t.clone()));
            doc.insert(
                "techniques".into(),
                toml::Value::Array(vec![toml::Value::Table(entry)]),
            );
        }
        if let Some(size) = &o.size {
            let [w, h] = parse_size(size)?;
            set_path(
                &mut doc,
                "render.size",
                toml::Value::Array(vec![(w as i64).into(), (h as i64).into()]),
            )?;
        }
        if let Some(spp) = o.spp {
            set_path(&mut doc, "render.spp", (spp as i64).into())?;
        }
        if let Some(seed) = o.seed {
            set_path(&mut doc, "render.seed", (seed as i64).into())?;
        }
        for kv in &o.set {
            let (k, v) = kv
                .split_once('=')
                .ok_or_else(|| anyhow!("--set {kv}: expected KEY=VALUE"))?;
            let mut value = parse_value(v.trim());
            let k = k.trim();
            // A relative environment map path typed on the command line is relative to where
            // the user typed it, as `--scene` is.
            if let ("scene.environment", toml::Value::String(path)) = (k, &value) {
                if Path::new(path).is_relative() {
                    value = toml::Value::String(
                        std::env::current_dir()?.join(path).display().to_string(),
                    );
                }
            }
            let top = k.split('.').next().unwrap_or("");
            if [
                "scene",
                "camera",
                "render",
                "tonemap",
                "shading",
                "techniques",
                "view",
                "experiment",
            ]
            .contains(&top)
            {
                set_path(&mut doc, k, value).with_context(|| format!("--set {kv}"))?;
            } else if let Some(toml::Value::Array(list)) = doc.get_mut("techniques") {
                for t in list.iter_mut() {
                    if let toml::Value::Table(t) = t {
                        let params = t
                            .entry("params")
                            .or_insert_with(|| toml::Value::Table(Default::default()));
                        if let toml::Value::Table(p) = params {
                            p.insert(k.to_string(), value.clone());
                        }
                    }
                }
            }
        }
        self.preset = doc.try_into().map_err(|e: toml::de::Error| {
            anyhow!(
                "preset after command-line overrides: {}",
                e.message().replace('\n', " ")
            )
        })?;
        Ok(())
    }

    /// The scene file the preset names (None for built-in scenes); relative paths are
    /// relative to the preset file.
    pub fn scene_path(&self) -> Option<PathBuf> {
        let src = &self.preset.scene.source;
        if builtin::is_builtin(src) {
            return None;
        }
        let p = Path::new(src);
        Some(match (&self.path, p.is_relative()) {
            (Some(preset_path), true) => preset_path.parent().unwrap_or(Path::new(".")).join(p),
            _ => p.to_path_buf(),
        })
    }

    /// Builds the scene the preset names, with the preset's shading model and environment
    /// map applied.
    pub fn load_scene(&self) -> Result<Scene> {
        let mut scene = self.load_scene_as_authored()?;
        if !self.preset.scene.instancing {
            scene.instances.clear();
        }
        self.preset.shading.apply(&mut scene)?;
        scene.environment = self.load_environment()?;
        Ok(scene)
    }

    /// The file `scene.environment` names (relative paths are relative to the preset file).
    pub fn environment_path(&self) -> Option<PathBuf> {
        let p = Path::new(self.preset.scene.environment.as_ref()?);
        Some(match (&self.path, p.is_relative()) {
            (Some(preset_path), true) => preset_path.parent().unwrap_or(Path::new(".")).join(p),
            _ => p.to_path_buf(),
        })
    }

    /// The environment map `scene.environment` names, with its rotation and intensity.
    pub fn load_environment(&self) -> Result<Option<Environment>> {
        let s = &self.preset.scene;
        let Some(path) = self.environment_path() else {
            if s.environment_rotation != 0.0 || s.environment_intensity != 1.0 {
                bail!(
                    "{}: scene.environment_rotation and scene.environment_intensity need scene.environment (an .exr or .hdr file)",
                    self.path
                        .as_ref()
                        .map_or("the preset".to_string(), |p| p.display().to_string())
                );
            }
            return Ok(None);
        };
        let env = Environment::load(&path, s.environment_rotation, s.environment_intensity)
            .with_context(|| {
                format!(
                    "scene.environment of {}",
                    self.path
                        .as_ref()
                        .map_or("the preset".to_string(), |p| p.display().to_string())
                )
            })?;
        Ok(Some(env))
    }

    fn load_scene_as_authored(&self) -> Result<Scene> {
        let src = &self.preset.scene.source;
        let Some(path) = self.scene_path() else {
            let mut scene = builtin::build(src, &self.preset.scene.params)?;
            self.animate_builtin(&mut scene)?;
            self.pose_builtin(&mut scene)?;
            return Ok(scene);
        };
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or("")
            .to_ascii_lowercase();
        if ext != "gltf" && ext != "glb" {
            if !path.exists() {
                // Most likely a misspelt built-in name (its error lists the built-ins).
                let mut scene = builtin::build(src, &self.preset.scene.params)?;
                self.animate_builtin(&mut scene)?;
                self.pose_builtin(&mut scene)?;
                return Ok(scene);
            }
            bail!(
                "{}: unsupported scene format (expected .gltf or .glb)",
                path.display()
            );
        }
        if !self.preset.scene.params.is_empty() {
            bail!(
                "scene.params is only for built-in scenes, not {}",
                path.display()
            );
        }
        let s = &self.preset.scene;
        if !s.animate.is_empty() {
            bail!(
                "{}scene.animate moves objects of built-in scenes; the animations of {} come from the file (scene.time poses them, scene.time_scale plays them)",
                self.animate_at(0),
                path.display()
            );
        }
        let pose = (s.time.is_some() || s.animation.is_some()).then(|| PoseRequest {
            time: s.time.unwrap_or(0.0),
            clip: s.animation.clone(),
        });
        let mut scene = gltf_load::load_posed(&path, s.environment.is_some(), pose.as_ref())?;
        if s.time_scale != 0.0 {
            match scene.motion.as_mut().map(std::sync::Arc::make_mut) {
                Some(m) => {
                    m.time_scale = s.time_scale;
                    m.play_until = s.play_until;
                }
                None => bail!(
                    "scene.time_scale = {} plays animations, but nothing in {} moves (no animated mesh or light)",
                    s.time_scale,
                    path.display()
                ),
            }
        }
        Ok(scene)
    }

    /// `[[scene.animate]]` on a built-in scene: its objects move, posed at 0 unless
    /// `scene.time` poses them elsewhere (`pose_builtin`).
    fn animate_builtin(&self, scene: &mut Scene) -> Result<()> {
        let s = &self.preset.scene;
        if s.animate.is_empty() {
            return Ok(());
        }
        animate::animate_objects(scene, &s.animate, |i| self.animate_at(i))?;
        if s.time.is_none() {
            if let Some(motion) = scene.motion.clone() {
                motion.apply(scene, 0.0)?;
            }
        }
        Ok(())
    }

    /// `file:line: ` of the preset's `[[scene.animate]]` table number `i`, where the text
    /// has it (empty otherwise: an inline table, or a preset made in code).
    fn animate_at(&self, i: usize) -> String {
        let Some(line) = self
            .text
            .lines()
            .enumerate()
            .filter(|(_, l)| l.trim_start().starts_with("[[scene.animate]]"))
            .nth(i)
            .map(|(n, _)| n + 1)
        else {
            return String::new();
        };
        let path = self
            .path
            .as_ref()
            .map_or("<preset>".to_string(), |p| p.display().to_string());
        format!("{path}:{line}: ")
    }

    /// `scene.time`, `scene.animation` and `scene.time_scale` for a built-in scene: posed and
    /// played where it moves (`moving`); refused where it has nothing to move, rather than
    /// silently changing nothing.
    fn pose_builtin(&self, scene: &mut Scene) -> Result<()> {
        let s = &self.preset.scene;
        if s.time.is_none()
            && s.animation.is_none()
            && s.time_scale == 0.0
            && s.play_until.is_none()
        {
            return Ok(());
        }
        let Some(motion) = scene.motion.as_mut().map(std::sync::Arc::make_mut) else {
            bail!(
                "scene.time, scene.animation and scene.time_scale pose and play animations; the built-in scene '{}' has none (the built-in 'moving' has, and [[scene.animate]] tables add keyframes to a built-in scene)",
                s.source
            );
        };
        if let Some(name) = &s.animation {
            if !motion.clips.iter().any(|c| &c.name == name) {
                let names: Vec<&str> = motion.clips.iter().map(|c| c.name.as_str()).collect();
                bail!(
                    "scene.animation = \"{name}\": the scene has no such animation (it has: {})",
                    names.join(", ")
                );
            }
            motion.clip = Some(name.clone());
        }
        motion.time_scale = s.time_scale;
        motion.play_until = s.play_until;
        let motion = motion.clone();
        if let Some(t) = s.time {
            motion.apply(scene, t)?;
        }
        Ok(())
    }

    pub fn camera(&self, scene: &Scene) -> Camera {
        self.preset.camera.unwrap_or_else(|| scene.default_camera())
    }

    pub fn to_toml(&self) -> Result<String> {
        Ok(toml::to_string_pretty(&self.preset)?)
    }
}

pub fn parse_size(s: &str) -> Result<[u32; 2]> {
    let parse = |v: &str| {
        v.trim()
            .parse::<u32>()
            .ok()
            .filter(|n| (1..=16384).contains(n))
    };
    let size = match s.split_once(['x', 'X']) {
        Some((w, h)) => parse(w).zip(parse(h)).map(|(w, h)| [w, h]),
        None => parse(s).map(|n| [n, n]),
    };
    size.ok_or_else(|| anyhow!("invalid size '{s}': expected N or WxH with values 1..16384"))
}

fn parse_value(v: &str) -> toml::Value {
    toml::from_str::<toml::Table>(&format!("v = {v}"))
        .ok()
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| toml::Value::String(v.to_string()))
}

fn set_path(doc: &mut toml::Table, key: &str, value: toml::Value) -> Result<()> {
    let parts: Vec<&str> = key.split('.').collect();
    let mut cur = doc;
    for (i, part) in parts.iter().enumerate() {
        let last = i == parts.len() - 1;
        if last {
            cur.insert(part.to_string(), value);
            return Ok(());
        }
        let next = cur
            .entry(part.to_string())
            .or_insert_with(|| toml::Value::Table(Default::default()));
        cur = match next {
            toml::Value::Table(t) => t,
            toml::Value::Array(a) => {
                // `techniques.0.params.x`: index into the array.
                let idx: usize = parts[i + 1]
                    .parse()
                    .map_err(|_| anyhow!("'{part}' is a list: use {part}.N"))?;
                let rest = parts[i + 2..].join(".");
                let item = a
                    .get_mut(idx)
                    .ok_or_else(|| anyhow!("{part}.{idx} does not exist"))?;
                return match item {
                    toml::Value::Table(t) if !rest.is_empty() => set_path(t, &rest, value),
                    _ => {
                        *item = value;
                        Ok(())
                    }
                };
            }
            _ => bail!("'{part}' is not a table"),
        };
    }
    Ok(())
}
