//! Parts: pieces of light transport that more than one technique family uses, built once per
//! engine entry and plugged in by name ("Making Connections", shared/seeds/003; issue 34). A
//! family names a part in its parameters (`direct = "restir"`) and holds it; the part owns its
//! passes, buffers and bind groups, and hands the family one output to read. This folder is a
//! floor below `techniques/`: techniques never import each other, what they share lives here
//! and in `shaders/parts/`, and a part names no technique (one exception left: the surface
//! cache's use of Lumen's tracing uniform, docs/architecture.md#floors). The design note with
//! the diagram of who reads what: docs/parts.md.
//!
//! - [`restir`]: ReSTIR's lighting core (DI, GI, ReGIR, their parameters and bind group), held
//!   by the `restir` technique and by the two parts below.
//! - [`surfels`]: the GIBS surfel core, held by the `surfels` technique and by the surfel cache.
//!
//! - [`restir_direct::RestirDirect`]: direct light at the primary surfaces by ReSTIR DI (the
//!   ReSTIR core's DI and ReGIR passes, GI off), shaded into one radiance value per
//!   pixel. Used by `surfels`, `lumen` and `callisto-shadows` (`direct = "restir"`).
//! - [`restir_gi::RestirGi`]: indirect light by ReSTIR GI (the ReSTIR core's GI passes,
//!   no DI), its sample paths ending where `gi_terminate` says. Used by `callisto-shadows`
//!   (`gi = true`).
//! - [`surface_cache::SurfaceCache`]: Lumen's surface cache (cards, lit every frame with
//!   multi-bounce feedback) and its lookup (`gilab::surface_cache`, at the bind group a pass
//!   names with `SURFACE_CACHE_GROUP`). Held by `lumen` (its resources in Lumen's group 2) and,
//!   on its own, by ReSTIR GI (`gi_terminate = "lumen-cards"`).
//! - [`surfel_cache::SurfelCache`]: the surfel core in cache-only mode (spawned from the primary surfaces, their rays
//!   integrated every frame) and their irradiance lookup (`gilab::surfels::gather`, at the bind
//!   group a pass names with `SURFELS_GROUP`). Used by ReSTIR GI (`gi_terminate = "surfels"`).
//! - [`reflections::Reflections`]: specular indirect light (GGX rays, hit lighting from a surface
//!   cache when the family has one, reuse, temporal and bilateral denoising) into two planes
//!   per pixel that the family adds. Used by `lumen` (`reflections = "traced"`).
//! - [`world_cache::WorldCache`]: Lumen's world radiance cache (clipmaps of probes around the
//!   camera, the read ones traced each frame through Lumen's scene representation) and its
//!   lookup (`gilab::world_cache`, at the bind group a pass names with `WORLD_CACHE_GROUP`).
//!   Used by `lumen`'s screen probes and by ReSTIR GI (`gi_terminate = "lumen-world"`, held by
//!   the surface cache it needs for short rays).
//! - [`world_regir::WorldRegir`]: a world-space ReGIR clipmap from which the caches pick the
//!   lights of their points (`gilab::cache_light`, at the bind group a pass names with
//!   `WORLD_REGIR_GROUP`). Used by `lumen`'s card texels and the surfels' ray hits
//!   (`cache_direct = "regir"`).
//! - [`light_tree::LightTree`]: a light BVH over the light pool's local lights (bounds,
//!   orientation cones, power), built with the pool and uploaded after it; a pipeline that sets
//!   the `LIGHT_TREE` def picks its lights by one stochastic descent (`gilab::light_tree`).
//!   Used by the reference (`light_sampling = "tree"`).
//! - [`hash_cache::HashCache`]: a spatially hashed world-space radiance cache (SHaRC-style:
//!   cells by position, facing and a camera-distance level; updated by full paths from one
//!   pixel in 25; lookup `gilab::hash_cache`, at the bind group a pass names with
//!   `HASH_CACHE_GROUP`). Used by the `hash-cache` technique, by ReSTIR GI
//!   (`gi_terminate = "hash-cache"`), by ReSTIR PT's suffixes (`suffix_terminate`), by DDGI's
//!   probe rays (`probe_hits = "hash-cache"`) and by the surfels' uncovered hits.
//! - [`texels::BufferTexels`]: texel copies of storage buffers that passes read many times
//!   (the surface cache's cards, the distance field): lavapipe reads a texel several times
//!   faster than a storage buffer's words.

use crate::gpu::Gpu;
use crate::render::RenderContext;
use anyhow::Result;

pub mod ambient_cache;
pub mod gi_cache;
pub mod hash_cache;
pub mod light_tree;
pub mod reflections;
pub mod restir;
pub mod restir_direct;
pub mod restir_gi;
pub mod surface_cache;
pub mod surfel_cache;
pub mod surfels;
pub mod texels;
pub mod tracing;
pub mod world_cache;
pub mod world_regir;

/// What every part does, whatever light it computes: the interface its holders (the families)
/// drive it through. The part owns its pipelines, buffers and bind groups; the holder says
/// whether it wants the part (its parameters name it) and when shaders changed, and
/// [`Part::prepare`] does the build bookkeeping each family once repeated by hand.
pub trait Part {
    /// What the part's pipelines need from their holder (a lookup layout, a cache): `()` for
    /// none.
    type Input<'a>;

    /// Builds its pipelines: all or nothing, so that a failed hot reload keeps the old ones.
    fn build(&mut self, ctx: &RenderContext, input: Self::Input<'_>) -> Result<()>;
    /// Buffers sized by the image, the scene and the settings (never a pipeline).
    fn build_resources(&mut self, ctx: &RenderContext);
    fn is_built(&self) -> bool;
    /// Forgets its history (camera cut, parameter change).
    fn reset(&self, gpu: &Gpu);

    /// Builds the part when the holder wants it and it is not built, builds it again when
    /// `rebuild` (a shader change) and it is wanted or built, then sizes its resources if
    /// built. A part switched off stays built (switching it back costs no compile) and is
    /// not recorded: see [`Part::active`].
    fn prepare(
        &mut self,
        ctx: &RenderContext,
        wanted: bool,
        rebuild: bool,
        input: Self::Input<'_>,
    ) -> Result<()> {
        let built = self.is_built();
        if (wanted || built) && (rebuild || !built) {
            self.build(ctx, input)?;
        }
        if self.is_built() {
            self.build_resources(ctx);
        }
        Ok(())
    }

    /// Whether the holder's frame records it: wanted and built.
    fn active(&self, wanted: bool) -> bool {
        wanted && self.is_built()
    }
}

pub use reflections::Reflections;
pub use restir_direct::RestirDirect;
pub use restir_gi::RestirGi;
pub use surface_cache::SurfaceCache;
pub use surfel_cache::SurfelCache;
pub use world_cache::WorldCache;
pub use world_regir::WorldRegir;
