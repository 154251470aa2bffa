//! `[[scene.animate]]`: keyframes written in a preset that move a named object of a built-in
//! scene (docs/scenes.md, "Keyframes in presets"). Each entry is checked as it is read (so a
//! malformed one is reported with its line and column); the object names are checked against
//! the scene when it is built, and the object becomes an instance of its own that the clip
//! "animate" moves (`MotionBuilder::named_object`).

use crate::scene::animation::{Interpolation, Property};
use crate::scene::motion::MotionBuilder;
use crate::scene::Scene;
use anyhow::{anyhow, bail, Result};
use glam::{Quat, Vec3, Vec4};
use serde::{Deserialize, Serialize};

/// Name of the clip the preset's keyframes make (`[scene] animation` can name it).
pub const CLIP: &str = "animate";

/// How values between two keys are found.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum AnimateInterpolation {
    /// The earlier key's value until the next key.
    Step,
    /// Linear; rotations by slerp on the shorter arc.
    #[default]
    Linear,
    /// A Hermite spline through the keys with Catmull-Rom tangents (one-sided at the ends).
    Cubicspline,
}

/// One `[[scene.animate]]` table: one object, its key times and TRS values.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(try_from = "AnimateFields")]
pub struct AnimateEntry {
    /// A named object of the built-in scene (an unknown name's error lists them).
    pub object: String,
    /// Key times in seconds, from 0, strictly increasing.
    pub times: Vec<f64>,
    /// Per key: [x, y, z] offset from the object's rest position.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub translation: Option<Vec<Vec<f64>>>,
    /// Per key: a unit quaternion [x, y, z, w] about the object's centre.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rotation: Option<Vec<Vec<f64>>>,
    /// Per key: [x, y, z] degrees about the object's centre, turned about X, then Y, then Z
    /// (world axes).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rotation_deg: Option<Vec<Vec<f64>>>,
    /// Per key: [x, y, z] scale factors about the object's centre.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scale: Option<Vec<Vec<f64>>>,
    #[serde(default)]
    pub interpolation: AnimateInterpolation,
}

/// `AnimateEntry` as written, before its checks.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct AnimateFields {
    object: String,
    times: Vec<f64>,
    #[serde(default)]
    translation: Option<Vec<Vec<f64>>>,
    #[serde(default)]
    rotation: Option<Vec<Vec<f64>>>,
    #[serde(default)]
    rotation_deg: Option<Vec<Vec<f64>>>,
    #[serde(default)]
    scale: Option<Vec<Vec<f64>>>,
    #[serde(default)]
    interpolation: AnimateInterpolation,
}

impl TryFrom<AnimateFields> for AnimateEntry {
    type Error = String;
    fn try_from(f: AnimateFields) -> std::result::Result<AnimateEntry, String> {
        let e = AnimateEntry {
            object: f.object,
            times: f.times,
            translation: f.translation,
            rotation: f.rotation,
            rotation_deg: f.rotation_deg,
            scale: f.scale,
            interpolation: f.interpolation,
        };
        e.check()
            .map_err(|m| format!("scene.animate (object \"{}\"): {m}", e.object))?;
        Ok(e)
    }
}

impl AnimateEntry {
    /// What can be checked without the scene.
    fn check(&self) -> std::result::Result<(), String> {
        if self.times.is_empty() {
            return Err("`times` is empty: give at least one key time".into());
        }
        if let Some(t) = self.times.iter().find(|t| !t.is_finite() || **t < 0.0) {
            return Err(format!(
                "key time {t}: expected a finite number of seconds >= 0"
            ));
        }
        if let Some(k) = self.times.windows(2).position(|w| w[1] <= w[0]) {
            return Err(format!(
                "`times` must increase strictly: key {} ({}) is not after key {} ({})",
                k + 1,
                self.times[k + 1],
                k,
                self.times[k]
            ));
        }
        if self.rotation.is_some() && self.rotation_deg.is_some() {
            return Err("give `rotation` (quaternions) or `rotation_deg`, not both".into());
        }
        let lists = self.lists();
        if lists.is_empty() {
            return Err(
                "nothing to animate: give `translation`, `rotation`, `rotation_deg` or `scale`"
                    .into(),
            );
        }
        for (name, values, len) in lists {
            if values.len() != self.times.len() {
                return Err(format!(
                    "`{name}` has {} values for {} key times (one per key)",
                    values.len(),
                    self.times.len()
                ));
            }
            for (k, v) in values.iter().enumerate() {
                if v.len() != len {
                    let what = if len == 4 {
                        "[x, y, z, w]"
                    } else {
                        "[x, y, z]"
                    };
                    return Err(format!(
                        "`{name}` value {k} has {} numbers, expected {len} ({what})",
                        v.len()
                    ));
                }
                if v.iter().any(|x| !x.is_finite()) {
                    return Err(format!("`{name}` value {k} is not finite"));
                }
                if name == "rotation" && v.iter().map(|x| x * x).sum::<f64>() < 1e-12 {
                    return Err(format!(
                        "`rotation` value {k} is a zero quaternion (expected a unit [x, y, z, w])"
                    ));
                }
            }
        }
        Ok(())
    }

    /// The value lists given: (key name, values, numbers per value).
    fn lists(&self) -> Vec<(&'static str, &Vec<Vec<f64>>, usize)> {
        [
            ("translation", &self.translation, 3),
            ("rotation", &self.rotation, 4),
            ("rotation_deg", &self.rotation_deg, 3),
            ("scale", &self.scale, 3),
        ]
        .into_iter()
        .filter_map(|(n, v, l)| v.as_ref().map(|v| (n, v, l)))
        .collect()
    }

    /// The entry's tracks for an object at `pivot`: (property, key values, one per key).
    fn tracks(&self, pivot: Vec3) -> Vec<(Property, Vec<Vec4>)> {
        let v3 = |v: &Vec<f64>| Vec3::new(v[0] as f32, v[1] as f32, v[2] as f32);
        let mut out = Vec::new();
        if let Some(t) = &self.translation {
            let values = t.iter().map(|v| (pivot + v3(v)).extend(0.0)).collect();
            out.push((Property::Translation, values));
        }
        let rotations: Option<Vec<Quat>> = match (&self.rotation, &self.rotation_deg) {
            (Some(q), _) => Some(
                q.iter()
                    .map(|v| {
                        Quat::from_xyzw(v[0] as f32, v[1] as f32, v[2] as f32, v[3] as f32)
                            .normalize()
                    })
                    .collect(),
            ),
            (None, Some(d)) => Some(
                d.iter()
                    .map(|v| {
                        let r = v3(v) * (std::f32::consts::PI / 180.0);
                        Quat::from_rotation_z(r.z)
                            * Quat::from_rotation_y(r.y)
                            * Quat::from_rotation_x(r.x)
                    })
                    .collect(),
            ),
            _ => None,
        };
        if let Some(mut q) = rotations {
            // Each key on the previous one's side, so that a spline through them takes the
            // short way (slerp does this by itself).
            for k in 1..q.len() {
                if q[k].dot(q[k - 1]) < 0.0 {
                    q[k] = -q[k];
                }
            }
            out.push((Property::Rotation, q.into_iter().map(Vec4::from).collect()));
        }
        if let Some(s) = &self.scale {
            out.push((
                Property::Scale,
                s.iter().map(|v| v3(v).extend(0.0)).collect(),
            ));
        }
        out
    }

    /// Keys as the sampler takes them: one value a key, or (in-tangent, value, out-tangent)
    /// with Catmull-Rom tangents (per second) for `cubicspline`.
    fn keys(&self, values: Vec<Vec4>) -> (Vec<Vec4>, Interpolation) {
        match self.interpolation {
            AnimateInterpolation::Step => (values, Interpolation::Step),
            AnimateInterpolation::Linear => (values, Interpolation::Linear),
            AnimateInterpolation::Cubicspline => {
                let t: Vec<f32> = self.times.iter().map(|&t| t as f32).collect();
                let n = values.len();
                let slope = |a: usize, b: usize| (values[b] - values[a]) / (t[b] - t[a]);
                let mut keys = Vec::with_capacity(3 * n);
                for (k, &value) in values.iter().enumerate() {
                    let m = if n == 1 {
                        Vec4::ZERO
                    } else if k == 0 {
                        slope(0, 1)
                    } else if k == n - 1 {
                        slope(n - 2, n - 1)
                    } else {
                        slope(k - 1, k + 1)
                    };
                    keys.extend([m, value, m]);
                }
                (keys, Interpolation::CubicSpline)
            }
        }
    }
}

/// Moves the named objects of a built-in scene as `entries` say: each becomes an instance of
/// its own, animated by the clip `CLIP` (added to any motion the scene has). `at(i)` says
/// where entry i is written, for errors.
pub fn animate_objects(
    scene: &mut Scene,
    entries: &[AnimateEntry],
    at: impl Fn(usize) -> String,
) -> Result<()> {
    if scene.objects.is_empty() {
        bail!(
            "{}scene.animate moves named objects of a built-in scene; '{}' names none (cornell, glossy and material-balls do)",
            at(0),
            scene.name
        );
    }
    let mut builder = MotionBuilder::continuing(scene, CLIP);
    // Per object: its node and pivot, and the properties already animated.
    let mut nodes: Vec<(String, usize, Vec3, Vec<Property>)> = Vec::new();
    for (i, e) in entries.iter().enumerate() {
        let context = || format!("{}scene.animate (object \"{}\")", at(i), e.object);
        let slot = match nodes.iter().position(|n| n.0 == e.object) {
            Some(k) => k,
            None => {
                let Some(o) = scene.objects.iter().find(|o| o.name == e.object).cloned() else {
                    let names: Vec<&str> = scene.objects.iter().map(|o| o.name.as_str()).collect();
                    bail!(
                        "{}: the scene '{}' has no such object (it has: {})",
                        context(),
                        scene.name,
                        names.join(", ")
                    );
                };
                let (node, pivot) = builder
                    .named_object(scene, o.first_triangle as usize, o.triangle_count as usize)
                    .map_err(|err| anyhow!("{}: {err}", context()))?;
                nodes.push((e.object.clone(), node, pivot, Vec::new()));
                nodes.len() - 1
            }
        };
        let (_, node, pivot, done) = &mut nodes[slot];
        for (property, values) in e.tracks(*pivot) {
            if done.contains(&property) {
                bail!(
                    "{}: its {} is animated twice (by two scene.animate tables)",
                    context(),
                    format!("{property:?}").to_lowercase()
                );
            }
            done.push(property);
            let (keys, interpolation) = e.keys(values);
            let times = e.times.iter().map(|&t| t as f32).collect();
            builder
                .track(*node, property, times, keys, interpolation)
                .map_err(|err| anyhow!("{}: {err}", context()))?;
        }
    }
    builder.finish(scene);
    Ok(())
}
