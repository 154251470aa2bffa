//! Shading models (`[shading]` in presets): which BRDF every technique evaluates, and the Callisto
//! parameters per material. The BRDF itself lives once in `shaders/common/brdf.wgsl`; this file
//! holds the parameters, their defaults and ranges (The Rendering of The Callisto Protocol,
//! SIGGRAPH 2023), and how presets and glTF extras override them.

use super::Scene;
use anyhow::{bail, Result};
use glam::Vec3;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// The BRDF model; the GPU reads it per material (`Material.callisto_dual.z`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum BrdfModel {
    /// Lambert diffuse + GGX specular (glTF metallic-roughness).
    #[default]
    LambertGgx,
    /// Callisto: Lambert with diffuse Fresnel and retroreflection, dual GGX with a Fresnel
    /// falloff, smooth terminator on both.
    Callisto,
    /// Callisto with Proxima (the functional fit of the GGX-microfacet diffuse) replacing Lambert.
    CallistoProxima,
}

impl BrdfModel {
    pub const ALL: [BrdfModel; 3] = [
        BrdfModel::LambertGgx,
        BrdfModel::Callisto,
        BrdfModel::CallistoProxima,
    ];
    pub fn id(self) -> u32 {
        self as u32
    }
    pub fn name(self) -> &'static str {
        match self {
            BrdfModel::LambertGgx => "lambert-ggx",
            BrdfModel::Callisto => "callisto",
            BrdfModel::CallistoProxima => "callisto-proxima",
        }
    }
    pub fn parse(s: &str) -> Result<BrdfModel> {
        match BrdfModel::ALL.iter().find(|m| m.name() == s) {
            Some(m) => Ok(*m),
            None => {
                bail!("unknown BRDF '{s}' (available: lambert-ggx, callisto, callisto-proxima)")
            }
        }
    }
}

/// Callisto's parameters with the seed's names, ranges and defaults (the defaults reproduce
/// Lambert + GGX exactly). Intensities marked * in the seed are "intensity multiplied by a tint".
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CallistoParams {
    /// ρ_f, [0, 256], 1: diffuse brightening (> 1) or darkening (< 1) at grazing θd.
    pub diffuse_fresnel: f32,
    pub diffuse_fresnel_tint: [f32; 3],
    /// n_f, [0, 1], 0.75: how fast the diffuse Fresnel rises with θd.
    pub diffuse_fresnel_falloff: f32,
    /// m_f, [0, 1], 0.75: how fast it fades as θh grows.
    pub diffuse_fresnel_tangent_falloff: f32,
    /// ρ_r, [0, 256], 1: diffuse retroreflection (θd near 0, θh large).
    pub retroreflection: f32,
    pub retroreflection_tint: [f32; 3],
    /// n_r, [0, 1], 0.75.
    pub retroreflection_falloff: f32,
    /// m_r, [0, 1], 0.75.
    pub retroreflection_tangent_falloff: f32,
    /// o, [-1, 1], 0: how much the terminator is smoothed (0 = Lambert's).
    pub smooth_terminator: f32,
    pub smooth_terminator_tint: [f32; 3],
    /// p, [0, 1], 0.5: the cos θi over which the terminator is smoothed.
    pub smooth_terminator_length: f32,
    /// n_s, [0, 1], 0.5 = Schlick; 0 removes the specular Fresnel, 1 makes it total.
    pub specular_fresnel_falloff: f32,
    /// Second GGX lobe's roughness over the first's (perceptual roughness, clamped to 1).
    pub dual_specular_roughness_scale: f32,
    /// Weight of the second lobe, [0, 1], 0 = single lobe.
    pub dual_specular_opacity: f32,
}

impl Default for CallistoParams {
    fn default() -> Self {
        CallistoParams {
            diffuse_fresnel: 1.0,
            diffuse_fresnel_tint: [1.0; 3],
            diffuse_fresnel_falloff: 0.75,
            diffuse_fresnel_tangent_falloff: 0.75,
            retroreflection: 1.0,
            retroreflection_tint: [1.0; 3],
            retroreflection_falloff: 0.75,
            retroreflection_tangent_falloff: 0.75,
            smooth_terminator: 0.0,
            smooth_terminator_tint: [1.0; 3],
            smooth_terminator_length: 0.5,
            specular_fresnel_falloff: 0.5,
            dual_specular_roughness_scale: 1.0,
            dual_specular_opacity: 0.0,
        }
    }
}

/// Partial overrides (preset tables and glTF extras set only some keys).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CallistoOverrides {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub diffuse_fresnel: Option<f32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub diffuse_fresnel_tint: Option<[f32; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub diffuse_fresnel_falloff: Option<f32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub diffuse_fresnel_tangent_falloff: Option<f32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub retroreflection: Option<f32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub retroreflection_tint: Option<[f32; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub retroreflection_falloff: Option<f32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub retroreflection_tangent_falloff: Option<f32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub smooth_terminator: Option<f32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub smooth_terminator_tint: Option<[f32; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub smooth_terminator_length: Option<f32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub specular_fresnel_falloff: Option<f32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dual_specular_roughness_scale: Option<f32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dual_specular_opacity: Option<f32>,
}

impl CallistoOverrides {
    pub fn apply(&self, p: &mut CallistoParams) {
        macro_rules! set {
            ($($f:ident),*) => { $( if let Some(v) = self.$f { p.$f = v; } )* };
        }
        set!(
            diffuse_fresnel,
            diffuse_fresnel_tint,
            diffuse_fresnel_falloff,
            diffuse_fresnel_tangent_falloff,
            retroreflection,
            retroreflection_tint,
            retroreflection_falloff,
            retroreflection_tangent_falloff,
            smooth_terminator,
            smooth_terminator_tint,
            smooth_terminator_length,
            specular_fresnel_falloff,
            dual_specular_roughness_scale,
            dual_specular_opacity
        );
    }
}

impl CallistoParams {
    /// Errors name the parameter and its range: out-of-range values are refused, not clamped.
    pub fn check(&self) -> Result<()> {
        let ranges: [(&str, f32, f32, f32); 11] = [
            ("diffuse_fresnel", self.diffuse_fresnel, 0.0, 256.0),
            (
                "diffuse_fresnel_falloff",
                self.diffuse_fresnel_falloff,
                0.0,
                1.0,
            ),
            (
                "diffuse_fresnel_tangent_falloff",
                self.diffuse_fresnel_tangent_falloff,
                0.0,
                1.0,
            ),
            ("retroreflection", self.retroreflection, 0.0, 256.0),
            (
                "retroreflection_falloff",
                self.retroreflection_falloff,
                0.0,
                1.0,
            ),
            (
                "retroreflection_tangent_falloff",
                self.retroreflection_tangent_falloff,
                0.0,
                1.0,
            ),
            ("smooth_terminator", self.smooth_terminator, -1.0, 1.0),
            (
                "smooth_terminator_length",
                self.smooth_terminator_length,
                0.0,
                1.0,
            ),
            (
                "specular_fresnel_falloff",
                self.specular_fresnel_falloff,
                0.0,
                1.0,
            ),
            (
                "dual_specular_roughness_scale",
                self.dual_specular_roughness_scale,
                0.0,
                16.0,
            ),
            (
                "dual_specular_opacity",
                self.dual_specular_opacity,
                0.0,
                1.0,
            ),
        ];
        for (name, v, lo, hi) in ranges {
            if !(lo..=hi).contains(&v) {
                bail!("callisto parameter {name} = {v} is outside [{lo}, {hi}]");
            }
        }
        for (name, t) in [
            ("diffuse_fresnel_tint", self.diffuse_fresnel_tint),
            ("retroreflection_tint", self.retroreflection_tint),
            ("smooth_terminator_tint", self.smooth_terminator_tint),
        ] {
            if t.iter().any(|c| !(0.0..=1.0).contains(c)) {
                bail!("callisto parameter {name} = {t:?} must be an RGB colour in [0, 1]");
            }
        }
        Ok(())
    }

    /// The five vec4s of the GPU material (layout in shaders/common/brdf.wgsl `Shading`).
    pub fn gpu_words(&self, model: BrdfModel) -> [[f32; 4]; 5] {
        let scaled = |i: f32, t: [f32; 3]| [i * t[0], i * t[1], i * t[2]];
        let f = scaled(self.diffuse_fresnel, self.diffuse_fresnel_tint);
        let r = scaled(self.retroreflection, self.retroreflection_tint);
        let t = self.smooth_terminator_tint;
        [
            [f[0], f[1], f[2], self.diffuse_fresnel_falloff],
            [r[0], r[1], r[2], self.diffuse_fresnel_tangent_falloff],
            [t[0], t[1], t[2], self.smooth_terminator],
            [
                self.retroreflection_falloff,
                self.retroreflection_tangent_falloff,
                self.smooth_terminator_length,
                self.specular_fresnel_falloff,
            ],
            [
                self.dual_specular_roughness_scale,
                self.dual_specular_opacity,
                model.id() as f32,
                0.0,
            ],
        ]
    }
}

/// `[shading]` in a preset: the model for every material, overrides for every material, and
/// overrides per material name (applied last).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShadingSettings {
    #[serde(default)]
    pub brdf: BrdfModel,
    #[serde(default, skip_serializing_if = "is_default")]
    pub callisto: CallistoOverrides,
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub materials: BTreeMap<String, CallistoOverrides>,
}

fn is_default(o: &CallistoOverrides) -> bool {
    *o == CallistoOverrides::default()
}

impl ShadingSettings {
    pub fn is_default(&self) -> bool {
        *self == ShadingSettings::default()
    }

    /// Sets every material's model and applies the overrides (a material name that matches
    /// nothing is an error: a typo must not silently do nothing).
    pub fn apply(&self, scene: &mut Scene) -> Result<()> {
        for name in self.materials.keys() {
            if !scene.materials.iter().any(|m| &m.name == name) {
                let names: Vec<&str> = scene.materials.iter().map(|m| m.name.as_str()).collect();
                bail!(
                    "shading.materials.{name}: no material of that name (the scene has: {})",
                    names.join(", ")
                );
            }
        }
        for m in &mut scene.materials {
            m.brdf = self.brdf;
            self.callisto.apply(&mut m.callisto);
            if let Some(o) = self.materials.get(&m.name) {
                o.apply(&mut m.callisto);
            }
            m.callisto
                .check()
                .map_err(|e| anyhow::anyhow!("material '{}': {e}", m.name))?;
        }
        Ok(())
    }
}

/// A material fitted with Callisto in the talk.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CallistoFit {
    pub base: Vec3,
    pub metallic: f32,
    pub roughness: f32,
    pub specular: f32,
    pub callisto: CallistoParams,
}

/// The Callisto fits of MERL materials the talk shows (SIGGRAPH 2023, "Callisto BRDF slice
/// selection"), by name: base colours in 8-bit sRGB as printed there.
pub fn callisto_fit(name: &str) -> Option<CallistoFit> {
    struct Fit {
        name: &'static str,
        base: [u8; 3],
        fresnel: (f32, [u8; 3], f32, f32),
        retro: (f32, [u8; 3], f32, f32),
        terminator: f32,
        metallic: f32,
        specular: f32,
        specular_falloff: f32,
        roughness: f32,
        dual: (f32, f32),
    }
    const WHITE: [u8; 3] = [255, 255, 255];
    let fits = [
        Fit {
            name: "black-soft-plastic",
            base: [20, 20, 20],
            fresnel: (0.75, WHITE, 0.7, 0.75),
            retro: (3.0, WHITE, 0.7, 0.75),
            terminator: 0.0,
            metallic: 0.0,
            specular: 0.2,
            specular_falloff: 0.0,
            roughness: 0.6,
            dual: (2.0, 0.0),
        },
        Fit {
            name: "blue-fabric",
            base: [40, 42, 66],
            fresnel: (4.0, [255, 218, 185], 0.6, 0.95),
            retro: (3.0, WHITE, 0.5, 0.75),
            terminator: 0.0,
            metallic: 0.0,
            specular: 0.2,
            specular_falloff: 0.0,
            roughness: 0.77,
            dual: (2.0, 0.0),
        },
        Fit {
            name: "yellow-phenolic",
            base: [152, 130, 93],
            fresnel: (0.8, WHITE, 0.85, 1.0),
            retro: (0.3, WHITE, 0.85, 1.0),
            terminator: 0.25,
            metallic: 0.0,
            specular: 0.5,
            specular_falloff: 0.5,
            roughness: 0.055,
            dual: (4.25, 0.15),
        },
        Fit {
            name: "yellow-plastic",
            base: [128, 124, 55],
            fresnel: (5.0, [255, 200, 255], 0.6, 0.85),
            retro: (3.5, [225, 191, 255], 0.25, 1.0),
            terminator: 0.0,
            metallic: 0.0,
            specular: 0.1,
            specular_falloff: 0.375,
            roughness: 0.5,
            dual: (2.0, 0.0),
        },
        Fit {
            name: "gold-metallic-paint",
            base: [105, 86, 88],
            fresnel: (1.0, WHITE, 0.5, 1.0),
            retro: (1.0, WHITE, 0.5, 0.75),
            terminator: 0.0,
            metallic: 0.85,
            specular: 1.0,
            specular_falloff: 0.0,
            roughness: 0.21,
            dual: (2.0, 0.9),
        },
        Fit {
            name: "light-red-paint",
            base: [173, 58, 23],
            fresnel: (1.0, WHITE, 0.5, 1.0),
            retro: (3.5, [200, 240, 255], 0.5, 0.65),
            terminator: 0.2,
            metallic: 0.0,
            specular: 0.25,
            specular_falloff: 0.4,
            roughness: 0.8,
            dual: (2.0, 0.0),
        },
    ];
    // The talk prints base colours as 8-bit sRGB.
    let srgb = |c: [u8; 3]| {
        Vec3::from_array(c.map(|v| crate::compare::tonemap::srgb_to_linear(v as f32 / 255.0)))
    };
    let unit = |c: [u8; 3]| c.map(|v| v as f32 / 255.0);
    let f = fits.iter().find(|f| f.name == name)?;
    Some(CallistoFit {
        base: srgb(f.base),
        metallic: f.metallic,
        roughness: f.roughness,
        specular: f.specular,
        callisto: CallistoParams {
            diffuse_fresnel: f.fresnel.0,
            diffuse_fresnel_tint: unit(f.fresnel.1),
            diffuse_fresnel_falloff: f.fresnel.2,
            diffuse_fresnel_tangent_falloff: f.fresnel.3,
            retroreflection: f.retro.0,
            retroreflection_tint: unit(f.retro.1),
            retroreflection_falloff: f.retro.2,
            retroreflection_tangent_falloff: f.retro.3,
            smooth_terminator: f.terminator,
            specular_fresnel_falloff: f.specular_falloff,
            dual_specular_roughness_scale: f.dual.0,
            dual_specular_opacity: f.dual.1,
            ..CallistoParams::default()
        },
    })
}

pub const CALLISTO_FITS: [&str; 6] = [
    "black-soft-plastic",
    "blue-fabric",
    "yellow-phenolic",
    "yellow-plastic",
    "gold-metallic-paint",
    "light-red-paint",
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn overrides_set_only_named_keys_and_ranges_are_checked() {
        let o: CallistoOverrides =
            toml::from_str("retroreflection = 3.0\nsmooth_terminator = 0.25").unwrap();
        let mut p = CallistoParams::default();
        o.apply(&mut p);
        assert_eq!(p.retroreflection, 3.0);
        assert_eq!(p.smooth_terminator, 0.25);
        assert_eq!(p.diffuse_fresnel, 1.0);
        assert!(p.check().is_ok());
        p.smooth_terminator = 2.0;
        assert!(p
            .check()
            .unwrap_err()
            .to_string()
            .contains("smooth_terminator"));
        assert!(toml::from_str::<CallistoOverrides>("retro = 1").is_err());
        assert_eq!(
            BrdfModel::parse("callisto-proxima").unwrap(),
            BrdfModel::CallistoProxima
        );
        assert!(BrdfModel::parse("disney").is_err());
    }
}
