//! The `[experiment]` table of a preset, as the preset file holds it: frames or seconds per run,
//! seeds, sweeps over a technique entry's parameters or ray budget, scripted events, and how the
//! report summarises. `crate::experiment` expands it into runs and runs them.

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
    /// Score every N-th frame (and the last): errors are computed afterwards from copies of
    /// those frames, so scoring never holds up the timed frames; 1 scores every frame.
    #[serde(default = "default_error_every")]
    pub error_every: u32,
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
    /// Real-time mode on a playing scene: a scored frame's ghost mask holds the pixels a
    /// moving object covered in one of this many frames before it and no longer covers.
    #[serde(default = "default_ghost_frames")]
    pub ghost_frames: u32,
    /// `accumulate` (default): runs average frames as the viewer shows them and are scored as
    /// they converge. `real-time`: every displayed frame is scored on its own against the
    /// reference of that frame; every technique runs with `accumulate = false` (the reference
    /// traces `samples_per_frame` fresh paths per pixel per frame and keeps nothing).
    #[serde(default)]
    pub mode: Mode,
    /// Real-time mode: score every N-th frame (frames N-1, 2N-1, ...) against a reference
    /// rendered for that frame; the frame before each scored one gets a reference too, for the
    /// flicker measure. 1 scores every frame.
    #[serde(default = "default_error_every")]
    pub reference_every: u32,
    /// Real-time mode: frame-time budgets in GPU ms for the report's main table: per budget
    /// and technique entry, the sweep value whose median ms/frame fits and whose median
    /// per-frame error is lowest.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub frame_ms: Vec<f64>,
    /// Camera path keyframes (`[[experiment.camera]]`), interpolated per frame (Catmull-Rom
    /// through the keys' positions and targets, linear field of view).
    #[serde(default, rename = "camera", skip_serializing_if = "Vec::is_empty")]
    pub camera_path: Vec<CameraKey>,
    #[serde(default, rename = "sweep", skip_serializing_if = "Vec::is_empty")]
    pub sweeps: Vec<Sweep>,
    #[serde(default, rename = "event", skip_serializing_if = "Vec::is_empty")]
    pub events: Vec<Event>,
}

fn default_frames() -> u32 {
    64
}
fn default_error_every() -> u32 {
    1
}
fn default_ghost_frames() -> u32 {
    10
}
fn default_settle_factor() -> f64 {
    1.1
}

#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum Mode {
    #[default]
    Accumulate,
    RealTime,
}

/// A camera path keyframe: where the camera is at the start of `frame`.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CameraKey {
    pub frame: u32,
    pub position: [f32; 3],
    pub target: [f32; 3],
    /// Vertical field of view in degrees (default: the preset camera's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fov: Option<f32>,
}

/// The camera of `frame` on a path of keys sorted by frame: Catmull-Rom through positions and
/// targets (end keys repeated), so an orbit given by a ring of keys stays round; the field of
/// view is interpolated linearly. Before the first key and after the last the camera stands.
pub fn camera_on_path(keys: &[CameraKey], frame: u32, base: &Camera) -> Camera {
    let cam = |k: &CameraKey| Camera {
        position: Vec3::from(k.position),
        target: Vec3::from(k.target),
        up: base.up,
        fov_y: k.fov.unwrap_or(base.fov_y),
    };
    let Some(first) = keys.first() else {
        return *base;
    };
    let last = keys.last().expect("not empty");
    if frame <= first.frame {
        return cam(first);
    }
    if frame >= last.frame {
        return cam(last);
    }
    let i = keys
        .windows(2)
        .position(|w| frame >= w[0].frame && frame < w[1].frame)
        .expect("frame within the keys");
    let at = |j: isize| &keys[j.clamp(0, keys.len() as isize - 1) as usize];
    let (k0, k1, k2, k3) = (
        at(i as isize - 1),
        at(i as isize),
        at(i as isize + 1),
        at(i as isize + 2),
    );
    let t = (frame - k1.frame) as f32 / (k2.frame - k1.frame) as f32;
    let spline = |a: [f32; 3], b: [f32; 3], c: [f32; 3], d: [f32; 3]| {
        let (a, b, c, d) = (Vec3::from(a), Vec3::from(b), Vec3::from(c), Vec3::from(d));
        let (t2, t3) = (t * t, t * t * t);
        0.5 * ((2.0 * b)
            + (c - a) * t
            + (2.0 * a - 5.0 * b + 4.0 * c - d) * t2
            + (3.0 * b - a - 3.0 * c + d) * t3)
    };
    let fov = |k: &CameraKey| k.fov.unwrap_or(base.fov_y);
    Camera {
        position: spline(k0.position, k1.position, k2.position, k3.position),
        target: spline(k0.target, k1.target, k2.target, k3.target),
        up: base.up,
        fov_y: fov(k1) + (fov(k2) - fov(k1)) * t,
    }
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
