//! # Surfel GI (`surfels`)
//!
//! "Global Illumination based on Surfels" (GIBS; EA SEED / Frostbite, SIGGRAPH 2021,
//! shared/seeds/001). The technique is a thin holder of the surfel core
//! ([`crate::parts::surfels`]: spawning, the grid, rays, integration and the pixels' gather and
//! shading), which the surfel cache ([`crate::parts::SurfelCache`]) holds too, in cache-only
//! mode, for other families' rays. Its methods (pool counts, surfel read-backs) are the core's,
//! reached through `Deref`. Docs: docs/surfels.md.

pub use crate::parts::surfels::{
    PoolCounts, SurfelCore, SurfelParamsGpu, SurfelSettings, SurfelSnapshot, GRID_CELLS,
    MAX_RAYS_PER_SURFEL, PARAMS, POOL_BYTES, STATE_BYTES, SURFEL_BYTES, TILE,
};

use crate::gpu::{timing::PassTimer, Gpu};
use crate::render::params::{ParamChanges, Params};
use crate::render::primary::FrameInputs;
use crate::render::{DebugView, PassInfo, RenderContext, Technique};
use crate::scene::features::SceneFeatures;
use anyhow::Result;

#[derive(Default)]
pub struct Surfels {
    core: SurfelCore,
}

impl std::ops::Deref for Surfels {
    type Target = SurfelCore;
    fn deref(&self) -> &SurfelCore {
        &self.core
    }
}

impl std::ops::DerefMut for Surfels {
    fn deref_mut(&mut self) -> &mut SurfelCore {
        &mut self.core
    }
}

impl Technique for Surfels {
    fn id(&self) -> &'static str {
        "surfels"
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn inputs(&self) -> FrameInputs {
        self.core.inputs()
    }

    fn passes(&self, f: &SceneFeatures) -> Vec<PassInfo> {
        self.core.passes(f)
    }

    fn build(&mut self, ctx: &RenderContext) -> Result<()> {
        self.core.build(ctx)
    }

    fn apply_params(&mut self, ctx: &RenderContext) -> Result<()> {
        self.core.apply_params(ctx)
    }

    fn reset_history(&mut self, gpu: &Gpu) {
        self.core.reset_history(gpu)
    }

    /// Surfels and their irradiance carry over, as in a game: the estimator has to catch up.
    fn on_scene_change(&mut self, _gpu: &Gpu) {}

    fn render(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
    ) {
        self.core.render(ctx, enc, timer)
    }

    fn debug_views(&self) -> Vec<DebugView> {
        self.core.debug_views()
    }

    fn debug_buffer(&self) -> Option<&wgpu::Buffer> {
        self.core.debug_buffer()
    }

    fn param_set(&self) -> &Params {
        self.core.param_set()
    }

    fn set_params(&mut self, changes: &ParamChanges) -> Result<()> {
        self.core.set_params(changes)
    }

    fn calibration_frames(&self) -> u32 {
        self.core.calibration_frames()
    }

    fn params_for_ray_budget(
        &self,
        rays_per_pixel: f64,
        measured: Option<f64>,
    ) -> Option<ParamChanges> {
        self.core.params_for_ray_budget(rays_per_pixel, measured)
    }
}
