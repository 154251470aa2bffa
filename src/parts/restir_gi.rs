//! ReSTIR GI as a part: the `restir` technique's GI passes (sample paths, temporal and spatial
//! reuse) with no DI candidates of any class and no ReGIR, for a family that keeps its own
//! direct light and takes its indirect light from ReSTIR GI's reservoirs. Its sample paths end
//! where `gi_terminate` says, in a cache part built inside the same frame (`lumen-cards`,
//! `surfels`). Used by `callisto-shadows` (`gi = true`); its resolve pass reads the reservoirs
//! through [`RestirGi::layout`] at its group 2 (`gilab::restir`'s bindings).

use crate::gpu::{timing::PassTimer, Gpu};
pub use crate::parts::restir::GiTerminate;
use crate::parts::restir::{self, RestirLighting, RestirSettings};
use crate::parts::world_regir::WorldRegirSettings;
use crate::render::params::Params;
use crate::render::{PassInfo, RenderContext};
use crate::scene::features::SceneFeatures;
use anyhow::Result;

pub struct RestirGi {
    lighting: RestirLighting,
    /// Whether ReSTIR's pipelines are built (they are built the first time `gi` is on).
    built: bool,
}

impl Default for RestirGi {
    fn default() -> Self {
        RestirGi {
            lighting: RestirLighting::new(Self::settings(
                false,
                GiTerminate::PATH,
                WorldRegirSettings::from_params(&Params::new("restir", restir::PARAMS)),
            )),
            built: false,
        }
    }
}

impl RestirGi {
    /// ReSTIR's defaults with GI only: no DI candidates of any class (no DI passes run), no
    /// ReGIR; sample paths end where `terminate` says, in a cache that picks its lights as
    /// `cache_light` says.
    pub fn settings(
        gi: bool,
        terminate: GiTerminate,
        cache_light: WorldRegirSettings,
    ) -> RestirSettings {
        let mut s = RestirSettings::from_params(&Params::new("restir", restir::PARAMS));
        s.candidates = 0;
        s.directional_candidates = 0;
        s.sky_candidates = 0;
        s.regir = false;
        s.gi = gi;
        s.gi_terminate = terminate;
        s.cache_light = cache_light;
        s
    }

    /// Takes the family's `gi`, `gi_terminate` and `cache_direct` (the pass list reads them
    /// before `prepare`).
    pub fn configure(&mut self, gi: bool, terminate: GiTerminate, cache_light: WorldRegirSettings) {
        self.lighting.settings = Self::settings(gi, terminate, cache_light);
    }

    /// Builds ReSTIR's pipelines when `gi` is on and they are not built yet (or `rebuild`: a
    /// shader changed), the cache the paths end in the first time it is named, and the
    /// resources (the bind group the family's resolve reads) in any case.
    pub fn prepare(&mut self, ctx: &RenderContext, rebuild: bool) -> Result<()> {
        let gi = self.lighting.settings.gi;
        if gi && (rebuild || !self.built) {
            self.lighting.build(ctx)?;
            self.built = true;
        } else {
            self.lighting.build_gi_cache(ctx)?;
            self.lighting.build_resources(ctx);
        }
        Ok(())
    }

    /// The layout of the reservoirs' bind group (`gilab::restir`'s group 2).
    pub fn layout(&mut self, gpu: &Gpu) -> &wgpu::BindGroupLayout {
        self.lighting.layout(gpu)
    }

    pub fn bind_group(&self) -> Option<&wgpu::BindGroup> {
        self.lighting.bind_group()
    }

    /// The surface cache its paths end in, when they end in one and it is built: its lookup
    /// bind group and whether the world cache's bindings are in it (`SurfaceCache::lookup_layout`).
    pub fn surface_cache(&self) -> Option<(&wgpu::BindGroup, bool)> {
        self.lighting.gi_surface_cache()
    }

    /// This frame's GI passes (and the cache's), when `gi` is on.
    pub fn record(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
    ) {
        if self.lighting.settings.gi && self.built {
            self.lighting.record(ctx, enc, timer);
        }
    }

    /// Forgets the reservoirs.
    pub fn reset(&self, gpu: &Gpu) {
        self.lighting.reset(gpu);
    }

    /// The GI passes (and the cache's) as the family's pass list shows them.
    pub fn passes(&self, f: &SceneFeatures) -> Vec<PassInfo> {
        self.lighting.gi_passes(f)
    }
}
