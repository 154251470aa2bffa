//! ReSTIR GI (Ouyang et al. 2021), a part of [`RestirLighting`]: one sample path per pixel
//! whose first hit becomes a reservoir sample (`gi_temporal`, with temporal reuse), then spatial
//! reuse in the area measure (`gi_spatial`). Its reservoirs (`gilab::restir::gi_reservoirs`) and
//! the sky each sample ray reached (`gi_sky`) are what a shading pass turns into indirect light
//! (`gi_contribution`, `gi_visible`). Shaders: shaders/restir/{gi_temporal,gi_spatial}.wgsl.

use super::lighting::{PassFiles, PassPair, RestirLighting};
use crate::gpu::Gpu;
use crate::render::{pipelines, PassInfo};

/// Bytes of `GiReservoir` in shaders/restir/shared.wgsl.
pub const GI_RESERVOIR_BYTES: u64 = 64;
const TEMPORAL: &str = "gi_temporal";
const SPATIAL: &str = "gi_spatial";

/// `gi_temporal`, then `gi_spatial`.
pub(super) const PASSES: PassFiles = [
    (TEMPORAL, "restir/gi_temporal.wgsl"),
    (SPATIAL, "restir/gi_spatial.wgsl"),
];

#[derive(Default)]
pub struct Gi {
    pub(super) passes: PassPair,
    /// Three segments like the DI reservoirs.
    pub(super) reservoirs: Option<wgpu::Buffer>,
    /// Per pixel: sky radiance reached by this frame's sample ray (not reused: it has no point).
    pub(super) sky: Option<wgpu::Buffer>,
}

impl Gi {
    pub(super) fn build_resources(&mut self, gpu: &Gpu, pixels: u64, keep: bool) {
        if !keep || self.reservoirs.is_none() {
            self.reservoirs = Some(pipelines::storage_buffer(
                gpu,
                "restir gi reservoirs",
                3 * pixels * GI_RESERVOIR_BYTES,
            ));
        }
        if !keep || self.sky.is_none() {
            self.sky = Some(pipelines::storage_buffer(gpu, "restir gi sky", pixels * 16));
        }
    }
}

impl RestirLighting {
    pub fn gi_passes(&self) -> [PassInfo; 2] {
        let s = &self.settings;
        [
            PassInfo {
                name: TEMPORAL,
                runs: s.gi,
                why: if s.gi {
                    format!(
                        "one sample path per pixel ({}), temporal reuse",
                        if s.gi_bounces == 0 {
                            "unbounded, Russian roulette".to_string()
                        } else {
                            format!("{} bounces", s.gi_bounces)
                        }
                    )
                } else {
                    "gi = false: direct light only".into()
                },
            },
            PassInfo {
                name: SPATIAL,
                runs: s.gi,
                why: if s.gi {
                    "spatial reuse of GI samples (area-measure weights)".into()
                } else {
                    "gi = false".into()
                },
            },
        ]
    }
}
