//! The one interface of a radiance cache that GI sample paths end in (ReSTIR GI's
//! `gi_terminate`, in `restir` and `callisto-shadows`; ReSTIR PT's `suffix_terminate`): the
//! holder builds it ([`CacheReader`] with the one pass that reads it), records its passes
//! inside the frame that reads it, and composes its reading pass with the cache's shader defs
//! (`common/path.wgsl`'s termination and the lookup's bind group) and its end-of-path module
//! (which overrides `gilab::path_end::end_path`), binding the cache's lookup.
//! Implemented by the surface cache (`lumen-cards`, `lumen-world`) and the surfel cache
//! (`surfels`). A new cache implements this trait, declares its [`CacheKind`] in its own folder
//! and adds one line to [`CACHES`]: its `gi_terminate` name, the parameter's choices and the
//! holders' construction all come from there (docs/parts.md).

use crate::gpu::{timing::PassTimer, Gpu};
use crate::parts::world_regir::{Coverage, WorldRegirSettings};
use crate::render::{pipelines, PassInfo, RenderContext};
use crate::scene::features::SceneFeatures;
use anyhow::Result;

/// What a cache is made with: its `gi_terminate` name, its sizes (atlas and texel budget, or
/// surfel rays) and how it picks lights (`cache_direct`); a different key builds a new cache.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CacheKey {
    pub name: &'static str,
    pub size: u32,
    pub budget: u32,
    pub light: WorldRegirSettings,
}

/// The holder's cache parameters (ReSTIR's `cache_atlas_size`, `cache_update`,
/// `cache_ray_budget`, `cache_direct`): each cache takes what it is sized by.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CacheSettings {
    pub atlas_size: u32,
    /// Share of the cache relit per frame.
    pub update: f32,
    pub ray_budget: u32,
    pub light: WorldRegirSettings,
}

/// A cache GI sample paths can end in, as the registry lists it.
pub struct CacheKind {
    /// Its `gi_terminate` name.
    pub name: &'static str,
    /// The key of the cache these settings make: a built cache is kept while its key
    /// (`GiCache::key`) equals this.
    pub key: fn(&CacheSettings) -> CacheKey,
    /// Makes one (its pipelines come with `GiCache::build`).
    pub new: fn(&CacheSettings) -> Result<Box<dyn GiCache>>,
    /// What a path ending in it at hit `hit` does, for the reading pass's line in the pass
    /// list.
    pub describe: fn(&CacheSettings, u32) -> String,
}

/// Every cache GI sample paths can end in, in `gi_terminate`'s order after `"path"`. A new cache
/// is one line here.
pub const CACHES: &[CacheKind] = &[
    crate::parts::surface_cache::CARDS,
    crate::parts::surface_cache::WORLD,
    crate::parts::surfel_cache::KIND,
    crate::parts::hash_cache::KIND,
    crate::parts::ambient_cache::KIND,
];

pub trait GiCache {
    fn key(&self) -> CacheKey;

    /// Builds its pipelines and resources (on error the previous ones stay).
    fn build(&mut self, ctx: &RenderContext) -> Result<()>;

    /// This frame's cache work, before the passes that read it.
    fn record(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
    );

    /// The lookup's bind group: valid until the next `build`.
    fn lookup(&self) -> Option<&wgpu::BindGroup>;

    /// Its passes, for the holder's pass list.
    fn passes(&self, f: &SceneFeatures) -> Vec<PassInfo>;

    /// Shader defs of a pass that reads the cache with its lookup at bind group `group`, and
    /// the lookup's layout.
    fn reader(&self, gpu: &Gpu, group: u32) -> (Vec<(&'static str, u32)>, wgpu::BindGroupLayout);

    /// The module (in the cache's own shader folder) whose `override fn
    /// gilab::path_end::end_path` ends a reader's paths in this cache; the reader's pipeline
    /// adds it as an additional import (`ShaderLibrary::with_imports`).
    fn path_end(&self) -> &'static str;

    /// The world ReGIR clipmap's lookup counts (`cache_direct = "regir"`; tests).
    fn cache_regir_coverage(&self, gpu: &Gpu) -> Result<Coverage>;

    /// The surface cache, when this is one: another part reads its cards (the reflections'
    /// hits in a family whose GI ends there).
    fn surface_cache(&self) -> Option<&crate::parts::SurfaceCache> {
        None
    }
}

/// The bind group a cache's reading pass binds the lookup at: after the scene (0), the frame (1)
/// and the holder's own group (2).
pub const READER_GROUP: u32 = 3;

/// A cache and the one pass of its holder that reads it (the lookup at [`READER_GROUP`]),
/// composed with the cache's reader defs and its end-of-path module: ReSTIR GI's temporal pass,
/// ReSTIR PT's initial pass.
pub struct CacheReader {
    pub cache: Box<dyn GiCache>,
    pub pipeline: wgpu::ComputePipeline,
}

/// The holder's reading pass: its entry file, its own layout (group 2) and its own defs (added
/// after the cache's).
pub struct ReaderPass<'a> {
    pub entry: &'a str,
    pub layout: &'a wgpu::BindGroupLayout,
    pub defs: &'a [(&'static str, u32)],
}

impl CacheReader {
    /// Builds the cache `kind` makes from `settings` and the reading pass, from the current
    /// sources (also on hot reload). `old`'s cache is kept, with its history, while its key
    /// equals the new one. On error the old reader comes back beside the error (a failed hot
    /// reload keeps the cache and its pass running).
    pub fn build(
        ctx: &RenderContext,
        old: Option<CacheReader>,
        kind: &CacheKind,
        settings: &CacheSettings,
        pass: ReaderPass<'_>,
    ) -> (Option<CacheReader>, Result<()>) {
        let key = (kind.key)(settings);
        let (mut cache, old_pipeline) = match old {
            Some(c) if c.cache.key() == key => (c.cache, Some(c.pipeline)),
            _ => match (kind.new)(settings) {
                Ok(cache) => (cache, None),
                Err(e) => return (None, Err(e)),
            },
        };
        let built = cache.build(ctx).and_then(|()| {
            let (mut defs, lookup_layout) = cache.reader(ctx.gpu, READER_GROUP);
            defs.extend_from_slice(pass.defs);
            let shaders = ctx
                .shaders
                .with_defs(&defs)
                .with_imports(&[cache.path_end()]);
            pipelines::compute_pipeline(
                ctx.gpu,
                &shaders,
                pass.entry,
                &[
                    &ctx.scene.layout,
                    ctx.frame_layout,
                    pass.layout,
                    &lookup_layout,
                ],
            )
        });
        match (built, old_pipeline) {
            (Ok(pipeline), _) => (Some(CacheReader { cache, pipeline }), Ok(())),
            (Err(e), Some(pipeline)) => (Some(CacheReader { cache, pipeline }), Err(e)),
            (Err(e), None) => (None, Err(e)),
        }
    }
}
