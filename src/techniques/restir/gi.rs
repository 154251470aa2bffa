//! ReSTIR GI (Ouyang et al. 2021), a part of [`RestirLighting`]: one sample path per pixel
//! whose first hit becomes a reservoir sample (`gi_temporal`, with temporal reuse), then spatial
//! reuse in the area measure (`gi_spatial`). Its reservoirs (`gilab::restir::gi_reservoirs`) and
//! the sky each sample ray reached (`gi_sky`) are what a shading pass turns into indirect light
//! (`gi_contribution`, `gi_visible`). Shaders: shaders/restir/{gi_temporal,gi_spatial}.wgsl.

use super::lighting::{PassFiles, PassPair, RestirLighting};
use super::params::GiTerminate;
use crate::gpu::{timing::PassTimer, Gpu};
use crate::parts::world_regir::WorldRegirSettings;
use crate::parts::{SurfaceCache, SurfelCache};
use crate::render::{pipelines, PassInfo, RenderContext};
use anyhow::Result;

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
    /// `gi_terminate = "lumen-cards" | "surfels"`: the cache the sample paths end in, and the
    /// temporal pass composed to read it (group 3).
    pub(super) cache: Option<CacheTermination>,
}

/// Sample paths that end in a cache (the part and the pass that reads it).
pub(super) struct CacheTermination {
    pub(super) cache: GiCache,
    pub(super) temporal: wgpu::ComputePipeline,
}

/// The caches a GI sample path can end in: parts, each with a lookup at bind group CACHE_GROUP.
/// `Cards` serves `lumen-cards` and, built with its world radiance cache, `lumen-world`.
pub(super) enum GiCache {
    Cards(Box<SurfaceCache>),
    Surfels(Box<SurfelCache>),
}

/// What a cache is made with: the termination, its sizes (atlas and texel budget, or surfel
/// rays) and how it picks lights (`cache_direct`); a different key builds a new cache.
type CacheKey = (GiTerminate, u32, u32, WorldRegirSettings);

impl GiCache {
    fn new(key: CacheKey, cache_update: f32) -> Result<GiCache> {
        Ok(match key.0 {
            GiTerminate::Surfels => GiCache::Surfels(Box::new(SurfelCache::new(key.1, key.3)?)),
            t => GiCache::Cards(Box::new(SurfaceCache::new(
                key.1,
                cache_update,
                key.3,
                t == GiTerminate::LumenWorld,
            )?)),
        })
    }

    fn key(&self) -> CacheKey {
        match self {
            GiCache::Cards(c) => (
                if c.has_world() {
                    GiTerminate::LumenWorld
                } else {
                    GiTerminate::LumenCards
                },
                c.sized().0,
                c.sized().1,
                c.cache_light(),
            ),
            GiCache::Surfels(c) => (GiTerminate::Surfels, c.sized(), 0, c.cache_light()),
        }
    }

    fn build(&mut self, ctx: &RenderContext) -> Result<()> {
        match self {
            GiCache::Cards(c) => c.build(ctx),
            GiCache::Surfels(c) => c.build(ctx),
        }
    }

    fn record(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
    ) {
        match self {
            GiCache::Cards(c) => c.record(ctx, enc, timer),
            GiCache::Surfels(c) => c.record(ctx, enc, timer),
        }
    }

    fn cache_regir_coverage(&self, gpu: &Gpu) -> Result<crate::parts::world_regir::Coverage> {
        match self {
            GiCache::Cards(c) => c.cache_regir_coverage(gpu),
            GiCache::Surfels(c) => c.cache_regir_coverage(gpu),
        }
    }

    fn lookup(&self) -> Option<&wgpu::BindGroup> {
        match self {
            GiCache::Cards(c) => c.lookup(),
            GiCache::Surfels(c) => c.lookup(),
        }
    }

    fn passes(&self, f: &crate::scene::features::SceneFeatures) -> Vec<PassInfo> {
        match self {
            GiCache::Cards(c) => c.passes(f),
            GiCache::Surfels(c) => c.passes(f),
        }
    }

    /// The temporal pass's shader defs (path.wgsl's termination and the lookup's group) and
    /// the lookup's layout.
    fn reader(&self, gpu: &Gpu) -> (Vec<(&'static str, u32)>, wgpu::BindGroupLayout) {
        use crate::parts::{surface_cache, surfel_cache, world_cache};
        match self {
            GiCache::Cards(c) if c.has_world() => (
                vec![
                    ("GI_TERMINATE_WORLD", 1),
                    surface_cache::lookup_defs(CACHE_GROUP)[0],
                    world_cache::lookup_defs(CACHE_GROUP)[0],
                ],
                SurfaceCache::lookup_layout(gpu, true),
            ),
            GiCache::Cards(_) => (
                vec![
                    ("GI_TERMINATE_CACHE", 1),
                    surface_cache::lookup_defs(CACHE_GROUP)[0],
                ],
                SurfaceCache::lookup_layout(gpu, false),
            ),
            GiCache::Surfels(_) => (
                vec![
                    ("GI_TERMINATE_SURFELS", 1),
                    surfel_cache::lookup_defs(CACHE_GROUP)[0],
                ],
                SurfelCache::lookup_layout(gpu),
            ),
        }
    }
}

/// The bind group the temporal pass reads the cache through.
const CACHE_GROUP: u32 = 3;

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

impl Gi {
    /// The temporal pass and, with a cache, the cache's own passes before it; then spatial reuse.
    pub(super) fn record(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
        bind_group: &wgpu::BindGroup,
        cache: bool,
    ) {
        let Some(c) = self.cache.as_mut().filter(|_| cache) else {
            self.passes.record(ctx, enc, timer, bind_group);
            return;
        };
        c.cache.record(ctx, enc, timer);
        let Some(lookup) = c.cache.lookup() else {
            return;
        };
        pipelines::technique_pass(
            ctx,
            enc,
            timer,
            TEMPORAL,
            &c.temporal,
            &[bind_group, lookup],
            [ctx.extent[0].div_ceil(8), ctx.extent[1].div_ceil(8), 1],
        );
        self.passes.record_second(ctx, enc, timer, bind_group);
    }
}

impl RestirLighting {
    /// The surface cache and the temporal pass that ends paths in it, when `gi_terminate`
    /// names the cache and they are not built yet (or the atlas size changed). Nothing is
    /// replaced on error.
    pub fn build_gi_cache(&mut self, ctx: &RenderContext) -> Result<()> {
        let s = &self.settings;
        if !(s.gi && s.gi_terminate.cache()) {
            return Ok(());
        }
        if let Some(c) = &self.gi.cache {
            if c.cache.key() == self.cache_key() {
                return Ok(());
            }
        }
        self.rebuild_gi_cache(ctx)
    }

    /// Builds the cache and its reading pass from the current sources (also on hot reload).
    pub(super) fn rebuild_gi_cache(&mut self, ctx: &RenderContext) -> Result<()> {
        let key = self.cache_key();
        let old = self.gi.cache.take();
        let (mut cache, old_temporal) = match old {
            Some(c) if c.cache.key() == key => (c.cache, Some(c.temporal)),
            _ => (GiCache::new(key, self.settings.cache_update)?, None),
        };
        let built = cache.build(ctx).and_then(|()| {
            let (defs, lookup_layout) = cache.reader(ctx.gpu);
            let shaders = ctx.shaders.with_defs(&defs);
            let layout = self.layout(ctx.gpu).clone();
            pipelines::compute_pipeline(
                ctx.gpu,
                &shaders,
                PASSES[0].1,
                &[&ctx.scene.layout, ctx.frame_layout, &layout, &lookup_layout],
            )
        });
        match (built, old_temporal) {
            (Ok(temporal), _) => {
                self.gi.cache = Some(CacheTermination { cache, temporal });
                Ok(())
            }
            // A failed hot reload keeps the cache and its pass running.
            (Err(e), Some(temporal)) => {
                self.gi.cache = Some(CacheTermination { cache, temporal });
                Err(e)
            }
            (Err(e), None) => Err(e),
        }
    }

    /// The surface cache the GI paths end in (`lumen-cards`, `lumen-world`), when it runs: its
    /// lookup bind group and whether that holds the world cache's bindings too (a layout of
    /// `SurfaceCache::lookup_layout(gpu, world)` reads it). Another part may read it (the
    /// reflections part's hits in a family whose GI ends there).
    pub fn gi_surface_cache(&self) -> Option<(&wgpu::BindGroup, bool)> {
        if !(self.settings.gi && self.settings.gi_terminate.cache()) {
            return None;
        }
        match &self.gi.cache.as_ref()?.cache {
            GiCache::Cards(c) => Some((c.lookup()?, c.has_world())),
            GiCache::Surfels(_) => None,
        }
    }

    /// The lookup counts of the world ReGIR clipmap that lights the cache the GI paths end in
    /// (None without such a cache; tests).
    pub fn gi_cache_regir_coverage(
        &self,
        gpu: &Gpu,
    ) -> Result<Option<crate::parts::world_regir::Coverage>> {
        self.gi
            .cache
            .as_ref()
            .map(|c| c.cache.cache_regir_coverage(gpu))
            .transpose()
    }

    /// The cache the parameters ask for.
    fn cache_key(&self) -> CacheKey {
        let s = &self.settings;
        match s.gi_terminate {
            GiTerminate::Surfels => (GiTerminate::Surfels, s.cache_ray_budget, 0, s.cache_light),
            t => (
                t,
                s.cache_atlas_size,
                SurfaceCache::budget(s.cache_update),
                s.cache_light,
            ),
        }
    }

    pub fn gi_passes(&self, f: &crate::scene::features::SceneFeatures) -> Vec<PassInfo> {
        let s = &self.settings;
        let cache = s.gi && s.gi_terminate.cache();
        let mut v = Vec::new();
        if cache {
            if let Some(c) = &self.gi.cache {
                v.extend(c.cache.passes(f));
            }
        }
        v.extend([
            PassInfo {
                name: TEMPORAL,
                runs: s.gi,
                why: if !s.gi {
                    "gi = false: direct light only".into()
                } else if cache && s.gi_terminate == GiTerminate::Surfels {
                    format!(
                        "one sample path per pixel ending in the surfels at hit {} where they cover it (NEE there, further bounces from the surfels' irradiance: {} surfel rays per frame; traced on where none cover it), temporal reuse",
                        s.gi_bounces.max(1),
                        s.cache_ray_budget
                    )
                } else if cache {
                    format!(
                        "one sample path per pixel ending in the surface cache at hit {} (NEE there, further bounces from the cache: {}² atlas, {:.0}% relit per frame), temporal reuse",
                        s.gi_bounces.max(1),
                        s.cache_atlas_size,
                        s.cache_update * 100.0
                    )
                } else {
                    format!(
                        "one sample path per pixel ({}), temporal reuse",
                        if s.gi_bounces == 0 {
                            "unbounded, Russian roulette".to_string()
                        } else {
                            format!("{} bounces", s.gi_bounces)
                        }
                    )
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
        ]);
        v
    }
}
