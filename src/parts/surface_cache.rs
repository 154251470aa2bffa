//! Lumen's surface cache as a part: cards captured into an atlas, lit every frame (direct light
//! by one power-sampled light per texel, indirect light from 16-ray probes on the texels that
//! read the cache itself, so bounces accumulate frame after frame), and read by a lookup that
//! another technique's pass imports (`shaders/parts/surface_cache.wgsl`, `gilab::surface_cache`).
//!
//! The seed (shared/seeds/003, "connecting at the surface cache") ends ReSTIR GI's sample paths
//! in this cache: `gi_terminate = "lumen-cards"`. The cache runs inside the frame that reads it
//! (the `lumen` technique's own capture and cache passes, timed under their names, rays counted
//! as `cache`), so a connection's frame time includes what keeping the cache lit costs.
//!
//! It is the `lumen` technique in its cache-only mode (`Lumen::surface_cache`): the same code and
//! shaders, none of the final gather. Each engine entry holds its own cache: two panes never
//! share one, so each pane's timings include its own cache work (fair for A/B timing).

use crate::gpu::{timing::PassTimer, Gpu};
use crate::parts::world_regir::WorldRegirSettings;
use crate::render::{pipelines, PassInfo, RenderContext, Technique};
use crate::scene::features::SceneFeatures;
use crate::techniques::lumen::Lumen;
use anyhow::Result;

/// The lookup's bindings (`gilab::surface_cache`): cards, objects' card ranges, triangle
/// objects, direct and indirect irradiance per texel, the atlas textures. Binding numbers are
/// Lumen's own group 2 numbers, so the same module serves Lumen at group 2 and another
/// technique at the group it names with `SURFACE_CACHE_GROUP`.
pub const LOOKUP_BINDINGS: [u32; 5] = [1, 2, 3, 12, 13];
pub const LOOKUP_TEXTURES: [u32; 4] = [19, 20, 21, 22];

/// Shader defs of a pipeline that reads the cache at bind group `group`.
pub fn lookup_defs(group: u32) -> [(&'static str, u32); 1] {
    [("SURFACE_CACHE_GROUP", group)]
}

pub struct SurfaceCache {
    lumen: Lumen,
    lookup: Option<wgpu::BindGroup>,
    /// Whether it holds Lumen's world radiance cache (`gi_terminate = "lumen-world"`).
    world: bool,
}

impl SurfaceCache {
    /// A cache with `atlas_size`² texels that relights `update` of them (a fraction) per
    /// frame, direct and indirect light each; traced through the BVH (`tracing = "bvh"`: the
    /// connection then measures the cache, not the distance field's approximation). With
    /// `world`, it also keeps Lumen's world radiance cache (Lumen's default sizes and update
    /// budget), whose probes its reader marks and whose lookup it binds beside its own.
    pub fn new(
        atlas_size: u32,
        update: f32,
        light: WorldRegirSettings,
        world: bool,
    ) -> Result<SurfaceCache> {
        let mut lumen = Lumen::surface_cache();
        let texels = Self::budget(update) as i64;
        // Its texels pick their lights as the holder's `cache_direct` says.
        let mut t = light.to_table();
        t.insert("atlas_size".into(), (atlas_size as i64).into());
        t.insert("tracing".into(), "bvh".into());
        t.insert("direct_texels_per_frame".into(), texels.into());
        t.insert("indirect_texels_per_frame".into(), texels.into());
        t.insert("world_cache".into(), world.into());
        lumen.set_params(&t)?;
        Ok(SurfaceCache {
            lumen,
            lookup: None,
            world,
        })
    }

    /// Lumen's texel budget for relighting `update` (a fraction) of the atlas per frame: its
    /// budgets are for a 4096² atlas and scale with the atlas's area.
    pub fn budget(update: f32) -> u32 {
        ((update.clamp(0.0, 1.0) as f64 * 4096.0 * 4096.0).round() as u32).max(1)
    }

    /// The world ReGIR clipmap's lookup counts (`cache_direct = "regir"`; tests).
    pub fn cache_regir_coverage(&self, gpu: &Gpu) -> Result<crate::parts::world_regir::Coverage> {
        self.lumen.cache_regir_coverage(gpu)
    }

    /// How its texels pick their lights (`cache_direct`).
    pub fn cache_light(&self) -> WorldRegirSettings {
        self.lumen.settings.cache_light
    }

    /// Whether it keeps the world radiance cache too.
    pub fn has_world(&self) -> bool {
        self.world
    }

    /// (atlas size, texel budget) it was made with.
    pub fn sized(&self) -> (u32, u32) {
        let s = &self.lumen.settings;
        (s.atlas_size, s.direct_texels_per_frame)
    }

    /// Layout of the lookup's bind group (the group a reading pass sets `SURFACE_CACHE_GROUP`
    /// to), with the world cache's lookup bindings when `world` (`WORLD_CACHE_GROUP`, the same).
    pub fn lookup_layout(gpu: &Gpu, world: bool) -> wgpu::BindGroupLayout {
        let mut entries: Vec<wgpu::BindGroupLayoutEntry> = LOOKUP_BINDINGS
            .iter()
            .map(|&b| pipelines::storage_entry(b, b <= 3))
            .collect();
        entries.extend(
            LOOKUP_TEXTURES
                .iter()
                .map(|&b| crate::techniques::lumen::texture_entry(b)),
        );
        if world {
            entries.extend(crate::parts::world_cache::lookup_entries());
        }
        pipelines::layout(gpu, "surface cache lookup", &entries)
    }

    /// Builds the cache's pipelines and resources (on error the previous ones stay).
    pub fn build(&mut self, ctx: &RenderContext) -> Result<()> {
        self.lumen.build(ctx)?;
        self.lookup = self.lumen.surface_cache_bind_group(
            ctx.gpu,
            &Self::lookup_layout(ctx.gpu, self.world),
            self.world,
        );
        Ok(())
    }

    pub fn is_built(&self) -> bool {
        self.lookup.is_some()
    }

    /// The lookup's bind group: valid until the next `build`.
    pub fn lookup(&self) -> Option<&wgpu::BindGroup> {
        self.lookup.as_ref()
    }

    /// This frame's cache work: distance-field scrolls, card captures, direct and indirect
    /// texel updates.
    pub fn record(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
    ) {
        self.lumen.render(ctx, enc, timer);
        // A scene edit can replace the card buffers: the lookup follows every frame.
        self.lookup = self.lumen.surface_cache_bind_group(
            ctx.gpu,
            &Self::lookup_layout(ctx.gpu, self.world),
            self.world,
        );
    }

    /// Forgets the cache's lighting (it relights over the next frames).
    pub fn reset(&mut self, gpu: &Gpu) {
        self.lumen.reset_history(gpu);
    }

    /// The cache's passes, for the technique that holds it.
    pub fn passes(&self, f: &SceneFeatures) -> Vec<PassInfo> {
        self.lumen.passes(f)
    }
}
