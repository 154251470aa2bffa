//! The surfels (GIBS, shared/seeds/001) as a cache another technique's rays end in: surfels
//! spawned from the primary surfaces, their rays traced and integrated every frame (multi-bounce
//! through their own hits), and read by the irradiance lookup (`gilab::surfels::gather`) at the
//! bind group a pass names with `SURFELS_GROUP`.
//!
//! ReSTIR GI's sample paths end here with `gi_terminate = "surfels"`, as they end in Lumen's
//! cards with `"lumen-cards"` (seed 003's connection, with the other family's cache). It is the
//! surfel core ([`crate::parts::surfels`], which the `surfels` technique holds too) in its
//! cache-only mode (`SurfelCore::surfel_cache`): the same code and shaders, none of the pixels'
//! shading. Its passes run inside the frame that reads it, timed
//! under their names, its rays counted as `surfel` (and `shadow`, `indirect` where a surfel's
//! ray continues as a path). Each engine entry holds its own cache, as with the surface cache.

use crate::gpu::{timing::PassTimer, Gpu};
use crate::parts::surfels::{self, SurfelCore};
use crate::parts::world_regir::WorldRegirSettings;
use crate::render::{PassInfo, RenderContext};
use crate::scene::features::SceneFeatures;

use anyhow::Result;

/// Shader defs of a pipeline that reads the surfels at bind group `group`.
pub fn lookup_defs(group: u32) -> [(&'static str, u32); 1] {
    surfels::lookup_defs(group)
}

pub struct SurfelCache {
    surfels: SurfelCore,
    ray_budget: u32,
}

impl SurfelCache {
    /// A cache of surfels that trace `ray_budget` rays per frame (the `surfels` technique's
    /// `ray_budget`), whose ray hits pick their lights as `light` says (`cache_direct`), its
    /// other settings the technique's defaults.
    pub fn new(ray_budget: u32, light: WorldRegirSettings) -> Result<SurfelCache> {
        let mut surfels = SurfelCore::surfel_cache();
        surfels.set_params(&light.to_changes().int("ray_budget", ray_budget as i64))?;
        Ok(SurfelCache {
            surfels,
            ray_budget,
        })
    }

    /// The world ReGIR clipmap's lookup counts (`cache_direct = "regir"`; tests).
    pub fn cache_regir_coverage(&self, gpu: &Gpu) -> Result<crate::parts::world_regir::Coverage> {
        self.surfels.cache_regir_coverage(gpu)
    }

    /// How its ray hits pick their lights (`cache_direct`).
    pub fn cache_light(&self) -> WorldRegirSettings {
        self.surfels.settings.cache_light
    }

    /// The ray budget it was made with.
    pub fn sized(&self) -> u32 {
        self.ray_budget
    }

    /// Layout of the lookup's bind group (the group a reading pass sets `SURFELS_GROUP` to).
    pub fn lookup_layout(gpu: &Gpu) -> wgpu::BindGroupLayout {
        surfels::lookup_layout(gpu)
    }

    /// Builds the surfels' pipelines and resources (on error the previous ones stay).
    pub fn build(&mut self, ctx: &RenderContext) -> Result<()> {
        self.surfels.build(ctx)
    }

    pub fn is_built(&self) -> bool {
        self.surfels.lookup_bind_group().is_some()
    }

    /// The lookup's bind group: valid until the next `build`.
    pub fn lookup(&self) -> Option<&wgpu::BindGroup> {
        self.surfels.lookup_bind_group()
    }

    /// This frame's surfel work: recycling, spawning, the grid, rays and integration.
    pub fn record(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
    ) {
        self.surfels.render(ctx, enc, timer);
    }

    /// Forgets every surfel (they respawn over the next frames).
    pub fn reset(&mut self, gpu: &Gpu) {
        self.surfels.reset_history(gpu);
    }

    /// The surfels' passes, for the technique that holds them.
    pub fn passes(&self, f: &SceneFeatures) -> Vec<PassInfo> {
        self.surfels.passes(f)
    }
}

/// `gi_terminate = "surfels"`.
pub const KIND: crate::parts::gi_cache::CacheKind = crate::parts::gi_cache::CacheKind {
    name: "surfels",
    key: |s| crate::parts::gi_cache::CacheKey {
        name: "surfels",
        size: s.ray_budget,
        budget: 0,
        light: s.light,
    },
    new: |s| Ok(Box::new(SurfelCache::new(s.ray_budget, s.light)?)),
    describe: |s, hit| {
        format!(
            "in the surfels at hit {hit} where they cover it (NEE there, further bounces from the surfels' irradiance: {} surfel rays per frame; traced on where none cover it)",
            s.ray_budget
        )
    },
};

/// `surfels`.
impl crate::parts::gi_cache::GiCache for SurfelCache {
    fn key(&self) -> crate::parts::gi_cache::CacheKey {
        crate::parts::gi_cache::CacheKey {
            name: "surfels",
            size: self.sized(),
            budget: 0,
            light: self.cache_light(),
        }
    }

    fn build(&mut self, ctx: &RenderContext) -> Result<()> {
        SurfelCache::build(self, ctx)
    }

    fn record(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
    ) {
        SurfelCache::record(self, ctx, enc, timer)
    }

    fn lookup(&self) -> Option<&wgpu::BindGroup> {
        SurfelCache::lookup(self)
    }

    fn passes(&self, f: &SceneFeatures) -> Vec<PassInfo> {
        SurfelCache::passes(self, f)
    }

    fn reader(&self, gpu: &Gpu, group: u32) -> (Vec<(&'static str, u32)>, wgpu::BindGroupLayout) {
        (vec![lookup_defs(group)[0]], SurfelCache::lookup_layout(gpu))
    }

    fn path_end(&self) -> &'static str {
        "gilab::surfels_path_end"
    }

    fn cache_regir_coverage(&self, gpu: &Gpu) -> Result<crate::parts::world_regir::Coverage> {
        SurfelCache::cache_regir_coverage(self, gpu)
    }
}
