//! The DDGI probe volume: where the probes of each cascade sit this frame, the uniforms the
//! shaders read (`DdgiParams` in shaders/ddgi/shared.wgsl), the per-frame random rotation of
//! the rays, and the buffers' sizes.
//!
//! Cascade c has spacing `s·2^c`, s = volume × the scene's longest side / probes_per_axis; on
//! each axis its grid holds the probes that fit at that spacing, centred in the scene's extent,
//! so that a volume that spans the scene puts its outer probes about half a spacing from the
//! walls, never on them. An axis
//! the scene is short on gets only the probes it holds (at least 2). The volume is centred on
//! the camera, snapped to the grid, and kept inside the scene's bounds (centred on the scene on
//! an axis it is longer than); probes live in slots by grid index modulo the counts, so a move
//! keeps every probe still inside (shaders/ddgi/shared.wgsl).

use glam::{IVec3, Quat, Vec3};

pub const FLAG_VISIBILITY: u32 = 1;
pub const FLAG_RELOCATION: u32 = 2;
pub const FLAG_CLASSIFICATION: u32 = 4;
pub const FLAG_MULTI_BOUNCE: u32 = 8;
pub const FLAG_ACCUMULATE: u32 = 16;
pub const FLAG_DEBUG: u32 = 32;
pub const FLAG_DIRECT_RESTIR: u32 = 64;
/// The debug buffer holds the gather's corner planes too (`DEBUG_PLANES`).
pub const FLAG_DEBUG_CORNERS: u32 = 128;
/// Planes of one vec4 per pixel in the debug buffer with the corner views (channels 0-23).
pub const DEBUG_PLANES: u64 = 6;

/// Rays per probe with fixed directions (`FIXED_RAYS` in shared.wgsl).
pub const FIXED_RAYS: u32 = 32;
/// Texels per probe of the bordered maps (8 × 8 irradiance, 16 × 16 distance: the paper's 6 × 6
/// and 14 × 14 with their borders).
pub const IRRADIANCE_TEXELS: u64 = 8 * 8;
pub const DISTANCE_TEXELS: u64 = 16 * 16;
/// Cascades the uniforms hold.
pub const MAX_CASCADES: usize = 4;
/// Longest distance a distance texel holds, in spacings: beyond the farthest point a probe
/// serves (the cell's diagonal, 1.73, plus a relocation of up to 0.45·√3 = 0.78 and the view
/// bias), so that no visible surface reads as occluded.
const MAX_DISTANCE: f32 = 3.0;
/// Relocation keeps a probe this far from the nearest front face, in spacings.
const MIN_FRONTFACE: f32 = 0.25;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VolumeSettings {
    pub probes_per_axis: u32,
    pub cascades: u32,
    pub volume: f32,
    pub rays_per_probe: u32,
    pub hysteresis: f32,
    pub visibility: bool,
    pub relocation: bool,
    pub classification: bool,
    pub multi_bounce: bool,
    pub bias: f32,
}

impl Default for VolumeSettings {
    fn default() -> Self {
        VolumeSettings {
            probes_per_axis: 8,
            cascades: 1,
            volume: 1.0,
            rays_per_probe: 256,
            hysteresis: 0.97,
            visibility: true,
            relocation: true,
            classification: true,
            multi_bounce: true,
            bias: 0.3,
        }
    }
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct CascadeGpu {
    pub origin_spacing: [f32; 4],
    pub base: [i32; 4],
}

/// Matches `DdgiParams` in shaders/ddgi/shared.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct DdgiParamsGpu {
    pub cascades: [CascadeGpu; MAX_CASCADES],
    pub counts: [u32; 4],
    pub rot_x: [f32; 4],
    pub rot_y: [f32; 4],
    pub rot_z: [f32; 4],
    pub rays: u32,
    pub flags: u32,
    pub hysteresis: f32,
    pub bias: f32,
    pub max_distance: f32,
    pub min_frontface: f32,
    pub pad: [u32; 2],
}

/// Bytes of each buffer for `probes` probes of `rays` rays (fixed ones included).
pub struct BufferBytes {
    pub probes: u64,
    pub rays: u64,
    pub irradiance: u64,
    pub distance: u64,
}

pub fn buffer_bytes(probes: u32, rays: u32) -> BufferBytes {
    let p = probes as u64;
    BufferBytes {
        probes: p * 32,
        rays: p * rays as u64 * 16,
        irradiance: p * IRRADIANCE_TEXELS * 16,
        distance: p * DISTANCE_TEXELS * 8,
    }
}

#[derive(Clone, Debug, Default)]
pub struct ProbeVolume {
    settings: VolumeSettings,
    /// The scene's bounds.
    lo: Vec3,
    hi: Vec3,
    /// Probes per axis (every cascade).
    counts: [u32; 3],
}

impl ProbeVolume {
    /// Sizes the volume for the settings and the scene's bounds.
    pub fn configure(&mut self, settings: &VolumeSettings, lo: Vec3, hi: Vec3) {
        self.settings = *settings;
        self.settings.cascades = settings.cascades.clamp(1, MAX_CASCADES as u32);
        self.lo = lo;
        self.hi = hi;
        let s = self.spacing(0);
        let n = settings.probes_per_axis.max(2);
        self.counts = [0, 1, 2].map(|a| n.min(self.fit(a, s).max(2)));
    }

    /// Probes the scene holds along axis `a` at spacing `s` (half a spacing from each side).
    fn fit(&self, a: usize, s: f32) -> u32 {
        ((self.hi[a] - self.lo[a]) / s + 1e-3).floor().max(1.0) as u32
    }

    pub fn spacing(&self, cascade: u32) -> f32 {
        let side = (self.hi - self.lo).max_element().max(1e-4);
        let n = self.settings.probes_per_axis.max(2) as f32;
        self.settings.volume * side / n * (1 << cascade) as f32
    }

    pub fn counts(&self) -> [u32; 3] {
        self.counts
    }

    pub fn probe_count(&self) -> u32 {
        self.counts.iter().product::<u32>() * self.settings.cascades.max(1)
    }

    /// Rays per probe, the fixed ones included.
    pub fn rays_per_probe(&self) -> u32 {
        self.settings.rays_per_probe + FIXED_RAYS
    }

    /// Cascade c's grid origin (world position of index 0) and its lowest probe's index for a
    /// camera at `camera`.
    pub fn cascade(&self, c: u32, camera: Vec3) -> (Vec3, IVec3) {
        let s = self.spacing(c);
        // The probes that fit along an axis, centred in the scene's extent on it.
        let origin = Vec3::from_array([0, 1, 2].map(|a| {
            let fit = self.fit(a, s) as f32;
            self.lo[a] + 0.5 * ((self.hi[a] - self.lo[a]) - (fit - 1.0) * s)
        }));
        let base = IVec3::from_array([0, 1, 2].map(|a| {
            let n = self.counts[a] as i32;
            let fit = self.fit(a, s) as i32;
            if n >= fit {
                // The volume is longer than the scene on this axis: centred on it.
                (fit - n).div_euclid(2)
            } else {
                let at = ((camera[a] - origin[a]) / s - (n - 1) as f32 / 2.0).round() as i32;
                at.clamp(0, fit - n)
            }
        }));
        (origin, base)
    }

    /// This frame's uniforms: the cascades around `camera`, and the rays' random rotation
    /// (drawn from the frame number: the same run renders the same frames).
    pub fn frame_params(&self, camera: Vec3, frame: u32, flags: u32) -> DdgiParamsGpu {
        let s = &self.settings;
        let mut p = DdgiParamsGpu {
            counts: [
                self.counts[0],
                self.counts[1],
                self.counts[2],
                s.cascades.max(1),
            ],
            rays: s.rays_per_probe,
            flags,
            hysteresis: s.hysteresis,
            bias: s.bias,
            max_distance: MAX_DISTANCE,
            min_frontface: MIN_FRONTFACE,
            ..Default::default()
        };
        for c in 0..s.cascades.max(1) {
            let (origin, base) = self.cascade(c, camera);
            p.cascades[c as usize] = CascadeGpu {
                origin_spacing: origin.extend(self.spacing(c)).to_array(),
                base: base.extend(0).to_array(),
            };
        }
        let m = glam::Mat3::from_quat(random_rotation(frame));
        // Rows: the shader computes dot(row, d).
        let t = m.transpose();
        p.rot_x = t.x_axis.extend(0.0).to_array();
        p.rot_y = t.y_axis.extend(0.0).to_array();
        p.rot_z = t.z_axis.extend(0.0).to_array();
        p
    }
}

/// A uniformly distributed rotation (Shoemake's quaternion from three uniform numbers), drawn
/// from the frame number by a splitmix64 hash.
pub fn random_rotation(frame: u32) -> Quat {
    let mut state = 0x9E37_79B9_7F4A_7C15u64 ^ frame as u64;
    let mut next = || {
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
    };
    let (u1, u2, u3) = (next(), next(), next());
    let tau = std::f32::consts::TAU;
    let (a, b) = ((1.0 - u1).sqrt(), u1.sqrt());
    Quat::from_xyzw(
        a * (tau * u2).sin(),
        a * (tau * u2).cos(),
        b * (tau * u3).sin(),
        b * (tau * u3).cos(),
    )
    .normalize()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_volume_spanning_the_scene_sits_inside_it() {
        let mut v = ProbeVolume::default();
        let s = VolumeSettings::default();
        v.configure(&s, Vec3::splat(-1.0), Vec3::new(1.0, 0.5, 1.0));
        // Longest side 2: spacing 0.25, 8 probes on x and z, 6 on y (1.5 / 0.25), centred:
        // y from -1 + (1.5 - 5 x 0.25) / 2.
        assert_eq!(v.counts(), [8, 6, 8]);
        let (origin, base) = v.cascade(0, Vec3::ZERO);
        assert_eq!(base, IVec3::ZERO);
        assert!(
            (origin - Vec3::new(-0.875, -0.875, -0.875)).length() < 1e-5,
            "{origin}"
        );
    }

    #[test]
    fn a_small_volume_follows_the_camera_and_stays_in_the_scene() {
        let mut v = ProbeVolume::default();
        let s = VolumeSettings {
            volume: 0.25,
            ..Default::default()
        };
        v.configure(&s, Vec3::ZERO, Vec3::splat(64.0));
        // Spacing 2: 32 probes fit per axis, the volume holds 8.
        let (_, at_corner) = v.cascade(0, Vec3::ZERO);
        assert_eq!(at_corner, IVec3::ZERO);
        let (_, middle) = v.cascade(0, Vec3::splat(32.0));
        assert_eq!(middle, IVec3::splat(12));
        let (_, far) = v.cascade(0, Vec3::splat(1000.0));
        assert_eq!(far, IVec3::splat(24));
    }

    #[test]
    fn rotations_are_rotations_and_differ_per_frame() {
        let a = random_rotation(1);
        let b = random_rotation(2);
        // A rotation keeps lengths and angles: the matrix is orthonormal.
        let m = glam::Mat3::from_quat(a);
        assert!((m * m.transpose()).abs_diff_eq(glam::Mat3::IDENTITY, 1e-5));
        assert!((m.determinant() - 1.0).abs() < 1e-5);
        assert!(a.angle_between(b) > 1e-3);
        assert_eq!(a, random_rotation(1));
    }
}
