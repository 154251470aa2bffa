//! ReSTIR GI (Ouyang et al. 2021), a part of [`RestirLighting`]: one sample path per pixel
//! whose first hit becomes a reservoir sample (`gi_temporal`, with temporal reuse), then spatial
//! reuse in the area measure (`gi_spatial`). Its reservoirs (`gilab::restir::gi_reservoirs`) and
//! the sky each sample ray reached (`gi_sky`) are what a shading pass turns into indirect light
//! (`gi_contribution`, `gi_visible`). Shaders: shaders/parts/restir/{gi_temporal,gi_spatial}.wgsl.

use super::lighting::{PassFiles, PassPair, RestirLighting};
use crate::gpu::{timing::PassTimer, Gpu};
use crate::parts::gi_cache::{CacheKey, CacheReader, ReaderPass};
use crate::render::{pipelines, PassInfo, RenderContext};
use anyhow::Result;

/// Bytes of `GiReservoir` in shaders/parts/restir/shared.wgsl.
pub const GI_RESERVOIR_BYTES: u64 = 64;
const TEMPORAL: &str = "gi_temporal";
const SPATIAL: &str = "gi_spatial";

/// `gi_temporal`, then `gi_spatial`.
pub(super) const PASSES: PassFiles = [
    (TEMPORAL, "parts/restir/gi_temporal.wgsl"),
    (SPATIAL, "parts/restir/gi_spatial.wgsl"),
];

#[derive(Default)]
pub struct Gi {
    pub(super) passes: PassPair,
    /// Three segments like the DI reservoirs.
    pub(super) reservoirs: Option<wgpu::Buffer>,
    /// Per pixel: sky radiance reached by this frame's sample ray (not reused: it has no point).
    pub(super) sky: Option<wgpu::Buffer>,
    /// `gi_terminate` names a cache: the cache the sample paths end in, and the temporal pass
    /// composed to read it (group 3).
    pub(super) cache: Option<CacheReader>,
    /// The passes' sample paths pick NEE lights by the light tree (`LIGHT_TREE`, with
    /// `light_tree`): the variant `passes` and `cache` were composed as.
    pub(super) light_tree: bool,
}

/// The GI passes' shader defs: NEE at the sample paths' vertices by the light tree with
/// `light_tree` (gilab::lights, gilab::path's emitter MIS).
pub(super) fn gi_defs(light_tree: bool) -> &'static [(&'static str, u32)] {
    if light_tree {
        &[("LIGHT_TREE", 1)]
    } else {
        &[]
    }
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
            &c.pipeline,
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
        // `light_tree` changed since the passes were composed: compose them again.
        let tree_changed = s.light_tree != self.gi.light_tree && self.gi.passes.is_built();
        if s.gi && tree_changed {
            let layout = self.layout(ctx.gpu).clone();
            let tree = self.settings.light_tree;
            let built = PassPair::build(ctx, &layout, PASSES, gi_defs(tree))?;
            self.gi.passes.set(built);
            self.gi.light_tree = tree;
        }
        let s = &self.settings;
        if !(s.gi && s.gi_terminate.cache()) {
            return Ok(());
        }
        if let Some(c) = &self.gi.cache {
            if Some(c.cache.key()) == self.cache_key() && !tree_changed {
                return Ok(());
            }
        }
        self.rebuild_gi_cache(ctx)
    }

    /// Builds the cache and its reading pass from the current sources (also on hot reload).
    pub(super) fn rebuild_gi_cache(&mut self, ctx: &RenderContext) -> Result<()> {
        let Some(kind) = self.settings.gi_terminate.kind() else {
            anyhow::bail!("gi_terminate = \"path\" ends in no cache");
        };
        // GI_TERMINATE: the path ends in a cache (gilab::path_end), the one whose module
        // overrides its `end_path`.
        let mut defs = vec![("GI_TERMINATE", 1)];
        defs.extend_from_slice(gi_defs(self.settings.light_tree));
        let layout = self.layout(ctx.gpu).clone();
        let pass = ReaderPass {
            entry: PASSES[0].1,
            layout: &layout,
            defs: &defs,
        };
        let old = self.gi.cache.take();
        let (reader, built) =
            CacheReader::build(ctx, old, kind, &self.settings.cache_settings(), pass);
        self.gi.cache = reader;
        built
    }

    /// The surface cache the GI paths end in (`lumen-cards`, `lumen-world`), when it runs: its
    /// lookup bind group and whether that holds the world cache's bindings too (a layout of
    /// `SurfaceCache::lookup_layout(gpu, world)` reads it). Another part may read it (the
    /// reflections part's hits in a family whose GI ends there).
    pub fn gi_surface_cache(&self) -> Option<(&wgpu::BindGroup, bool)> {
        if !(self.settings.gi && self.settings.gi_terminate.cache()) {
            return None;
        }
        let c = self.gi.cache.as_ref()?.cache.surface_cache()?;
        Some((c.lookup()?, c.has_world()))
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

    /// The cache the parameters ask for (`gi_terminate` names one).
    fn cache_key(&self) -> Option<CacheKey> {
        let kind = self.settings.gi_terminate.kind()?;
        Some((kind.key)(&self.settings.cache_settings()))
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
                } else if let Some(kind) = s.gi_terminate.kind() {
                    format!(
                        "one sample path per pixel ending {}, temporal reuse",
                        (kind.describe)(&self.settings.cache_settings(), s.gi_bounces.max(1))
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
