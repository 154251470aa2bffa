//! Scene animation: glTF animation channels (node translation, rotation and scale with STEP,
//! LINEAR and CUBICSPLINE samplers, as the glTF 2.0 specification defines them), sampled at a
//! time. The glTF loader poses the scene at `[scene] time` by giving each animated node the
//! local transform its channels hold then (`gltf_load::load_posed`), so a pose is the same
//! scene a file with those node transforms baked in would give, bit for bit.
//!
//! Clips loop: a clip is sampled at `time` modulo its duration. Every clip plays unless
//! `[scene] animation` names one. Morph-target weights are not read (warned).

use anyhow::{bail, Result};
use glam::{Mat4, Quat, Vec3, Vec4};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Interpolation {
    Step,
    Linear,
    CubicSpline,
}

/// The node property a channel drives.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Property {
    Translation,
    /// A unit quaternion (x, y, z, w).
    Rotation,
    Scale,
}

/// Keyframes of one property: `times` ascending; per key one value (STEP, LINEAR) or an
/// in-tangent, a value and an out-tangent (CUBICSPLINE), each a Vec4 (w unused for
/// translation and scale).
#[derive(Clone, Debug, PartialEq)]
pub struct Keyframes {
    pub times: Vec<f32>,
    pub values: Vec<Vec4>,
    pub interpolation: Interpolation,
}

impl Keyframes {
    /// Checks the key counts against the interpolation and that the times ascend.
    pub fn new(
        times: Vec<f32>,
        values: Vec<Vec4>,
        interpolation: Interpolation,
    ) -> Result<Keyframes> {
        let per_key = if interpolation == Interpolation::CubicSpline {
            3
        } else {
            1
        };
        if times.is_empty() {
            bail!("no keyframes");
        }
        if values.len() != per_key * times.len() {
            bail!(
                "{} values for {} keyframes ({} per key expected)",
                values.len(),
                times.len(),
                per_key
            );
        }
        if times.iter().any(|t| !t.is_finite()) || times.windows(2).any(|w| w[1] <= w[0]) {
            bail!("keyframe times must be finite and strictly increasing");
        }
        if values.iter().any(|v| !v.is_finite()) {
            bail!("non-finite keyframe value");
        }
        Ok(Keyframes {
            times,
            values,
            interpolation,
        })
    }

    fn value(&self, key: usize) -> Vec4 {
        match self.interpolation {
            Interpolation::CubicSpline => self.values[3 * key + 1],
            _ => self.values[key],
        }
    }

    /// The property at time `t` (held at the first and last keys outside them); rotations
    /// interpolate by slerp and come back normalised.
    pub fn sample(&self, t: f32, property: Property) -> Vec4 {
        let n = self.times.len();
        if t <= self.times[0] {
            return self.value(0);
        }
        if t >= self.times[n - 1] {
            return self.value(n - 1);
        }
        // The key interval [k, k + 1] holding t.
        let k = self.times.partition_point(|&x| x <= t) - 1;
        let (t0, t1) = (self.times[k], self.times[k + 1]);
        let dt = t1 - t0;
        let u = (t - t0) / dt;
        match self.interpolation {
            Interpolation::Step => self.value(k),
            Interpolation::Linear if property == Property::Rotation => {
                slerp(self.value(k), self.value(k + 1), u)
            }
            Interpolation::Linear => self.value(k).lerp(self.value(k + 1), u),
            Interpolation::CubicSpline => {
                // Hermite spline with the tangents scaled by the interval (glTF 2.0, appendix C).
                let p0 = self.values[3 * k + 1];
                let b0 = self.values[3 * k + 2];
                let a1 = self.values[3 * (k + 1)];
                let p1 = self.values[3 * (k + 1) + 1];
                let (u2, u3) = (u * u, u * u * u);
                let v = p0 * (2.0 * u3 - 3.0 * u2 + 1.0)
                    + b0 * (dt * (u3 - 2.0 * u2 + u))
                    + p1 * (-2.0 * u3 + 3.0 * u2)
                    + a1 * (dt * (u3 - u2));
                if property == Property::Rotation {
                    v.normalize_or_zero()
                } else {
                    v
                }
            }
        }
    }

    pub fn duration(&self) -> f32 {
        self.times[self.times.len() - 1]
    }
}

/// Spherical interpolation along the shorter arc (glTF 2.0, appendix C); nearly parallel
/// quaternions interpolate linearly, then normalise.
pub fn slerp(a: Vec4, b: Vec4, u: f32) -> Vec4 {
    let mut d = a.dot(b);
    let mut b = b;
    if d < 0.0 {
        b = -b;
        d = -d;
    }
    if d > 0.9995 {
        return a.lerp(b, u).normalize_or_zero();
    }
    let theta = d.min(1.0).acos();
    let s = theta.sin();
    (a * (((1.0 - u) * theta).sin() / s) + b * ((u * theta).sin() / s)).normalize_or_zero()
}

/// One channel: a node's property over time.
#[derive(Clone, Debug, PartialEq)]
pub struct Track {
    /// The glTF node index.
    pub node: usize,
    pub property: Property,
    pub keys: Keyframes,
}

/// A named animation (glTF `animations[i]`): its tracks play together.
#[derive(Clone, Debug, PartialEq)]
pub struct Clip {
    pub name: String,
    pub tracks: Vec<Track>,
}

impl Clip {
    /// The last keyframe time of any track (the clip loops after it).
    pub fn duration(&self) -> f32 {
        self.tracks
            .iter()
            .map(|t| t.keys.duration())
            .fold(0.0, f32::max)
    }

    /// The time within the clip at scene time `t` (looped; clips of zero duration hold).
    pub fn local_time(&self, t: f32) -> f32 {
        let d = self.duration();
        if d > 0.0 {
            t.rem_euclid(d)
        } else {
            0.0
        }
    }
}

/// A clip as the scene reports it (viewer, errors, shot JSON).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ClipInfo {
    pub name: String,
    pub duration: f32,
    pub channels: usize,
}

impl ClipInfo {
    pub fn of(c: &Clip) -> ClipInfo {
        ClipInfo {
            name: c.name.clone(),
            duration: c.duration(),
            channels: c.tracks.len(),
        }
    }
}

/// Which clips play and at what time: every clip, or the one named (`[scene] animation`).
#[derive(Clone, Debug, PartialEq, Default)]
pub struct PoseRequest {
    pub time: f32,
    pub clip: Option<String>,
}

/// A node's local translation, rotation and scale.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Trs {
    pub translation: Vec3,
    pub rotation: Quat,
    pub scale: Vec3,
}

impl Trs {
    pub fn matrix(&self) -> Mat4 {
        Mat4::from_scale_rotation_translation(self.scale, self.rotation, self.translation)
    }
}

/// The local transform of every animated node at the requested pose, from its rest TRS with
/// the playing clips' channels applied (later clips win where two drive one property).
/// Fails when the request names a clip the scene does not have.
pub fn posed_locals(
    clips: &[Clip],
    request: &PoseRequest,
    rest: impl Fn(usize) -> Trs,
) -> Result<std::collections::HashMap<usize, Mat4>> {
    let playing: Vec<&Clip> = match &request.clip {
        Some(name) => match clips.iter().find(|c| &c.name == name) {
            Some(c) => vec![c],
            None => {
                let names: Vec<&str> = clips.iter().map(|c| c.name.as_str()).collect();
                bail!(
                    "scene.animation = \"{name}\": the scene has no such animation (it has: {})",
                    if names.is_empty() {
                        "none".to_string()
                    } else {
                        names.join(", ")
                    }
                );
            }
        },
        None => clips.iter().collect(),
    };
    let mut trs: std::collections::HashMap<usize, Trs> = std::collections::HashMap::new();
    for clip in playing {
        let t = clip.local_time(request.time);
        for track in &clip.tracks {
            let node = trs.entry(track.node).or_insert_with(|| rest(track.node));
            let v = track.keys.sample(t, track.property);
            match track.property {
                Property::Translation => node.translation = v.truncate(),
                Property::Rotation => node.rotation = Quat::from_vec4(v),
                Property::Scale => node.scale = v.truncate(),
            }
        }
    }
    Ok(trs.into_iter().map(|(n, t)| (n, t.matrix())).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sampler(times: &[f32], values: &[[f32; 4]], i: Interpolation) -> Keyframes {
        Keyframes::new(
            times.to_vec(),
            values.iter().map(|v| Vec4::from_array(*v)).collect(),
            i,
        )
        .unwrap()
    }

    #[test]
    fn step_and_linear_by_hand() {
        let s = sampler(
            &[1.0, 3.0],
            &[[0.0, 2.0, 4.0, 0.0], [4.0, 6.0, 0.0, 0.0]],
            Interpolation::Step,
        );
        assert_eq!(
            s.sample(0.0, Property::Translation),
            Vec4::new(0.0, 2.0, 4.0, 0.0)
        );
        assert_eq!(
            s.sample(2.9, Property::Translation),
            Vec4::new(0.0, 2.0, 4.0, 0.0)
        );
        assert_eq!(
            s.sample(3.5, Property::Translation),
            Vec4::new(4.0, 6.0, 0.0, 0.0)
        );
        let l = Keyframes {
            interpolation: Interpolation::Linear,
            ..s
        };
        // A quarter of the way: 0 + 0.25 * 4, 2 + 0.25 * 4, 4 - 0.25 * 4.
        assert_eq!(
            l.sample(1.5, Property::Translation),
            Vec4::new(1.0, 3.0, 3.0, 0.0)
        );
    }

    #[test]
    fn cubic_spline_by_hand() {
        // One component: p0 = 1, out-tangent b0 = 2, in-tangent a1 = -1, p1 = 3, over [0, 2].
        let s = sampler(
            &[0.0, 2.0],
            &[
                [9.0, 0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0, 0.0],
                [2.0, 0.0, 0.0, 0.0],
                [-1.0, 0.0, 0.0, 0.0],
                [3.0, 0.0, 0.0, 0.0],
                [9.0, 0.0, 0.0, 0.0],
            ],
            Interpolation::CubicSpline,
        );
        // u = 0.5, dt = 2: 1 * 0.5 + 2 * 2 * 0.125 + 3 * 0.5 + (-1) * 2 * (-0.125) = 2.75.
        assert!((s.sample(1.0, Property::Translation).x - 2.75).abs() < 1e-6);
        assert_eq!(s.sample(0.0, Property::Translation).x, 1.0);
        assert_eq!(s.sample(2.0, Property::Translation).x, 3.0);
    }

    #[test]
    fn slerp_takes_the_short_arc() {
        let a = Quat::from_rotation_y(0.0);
        let b = Quat::from_rotation_y(std::f32::consts::FRAC_PI_2);
        let half = slerp(Vec4::from(a), Vec4::from(b), 0.5);
        let expect = Quat::from_rotation_y(std::f32::consts::FRAC_PI_4);
        assert!(Quat::from_vec4(half).abs_diff_eq(expect, 1e-6), "{half}");
        // The same rotation written with the opposite sign: the short arc, not the long one.
        let far = slerp(Vec4::from(a), -Vec4::from(b), 0.5);
        assert!(
            Quat::from_vec4(far).abs_diff_eq(expect, 1e-6)
                || Quat::from_vec4(-far).abs_diff_eq(expect, 1e-6),
            "{far}"
        );
    }

    #[test]
    fn bad_samplers_are_refused() {
        let v = vec![Vec4::ZERO; 2];
        assert!(Keyframes::new(vec![1.0, 1.0], v.clone(), Interpolation::Linear).is_err());
        assert!(Keyframes::new(vec![0.0, 1.0], v.clone(), Interpolation::CubicSpline).is_err());
        assert!(Keyframes::new(vec![], vec![], Interpolation::Step).is_err());
        assert!(Keyframes::new(vec![0.0, f32::NAN], v, Interpolation::Step).is_err());
    }

    #[test]
    fn clips_loop_and_unknown_names_are_refused() {
        let clip = Clip {
            name: "move".into(),
            tracks: vec![Track {
                node: 3,
                property: Property::Translation,
                keys: sampler(
                    &[0.0, 2.0],
                    &[[0.0; 4], [2.0, 0.0, 0.0, 0.0]],
                    Interpolation::Linear,
                ),
            }],
        };
        let rest = |_| Trs {
            translation: Vec3::ZERO,
            rotation: Quat::IDENTITY,
            scale: Vec3::ONE,
        };
        let at = |t: f32| {
            posed_locals(
                std::slice::from_ref(&clip),
                &PoseRequest {
                    time: t,
                    clip: None,
                },
                rest,
            )
            .unwrap()[&3]
                .w_axis
                .x
        };
        assert_eq!(at(0.5), 0.5);
        assert_eq!(at(2.5), 0.5, "looped");
        let err = posed_locals(
            &[clip],
            &PoseRequest {
                time: 0.0,
                clip: Some("walk".into()),
            },
            rest,
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("walk") && err.contains("move"), "{err}");
    }
}
