//! Lumen's surface cache as a part: cards captured into an atlas, lit every frame (direct light
//! by one light per texel, indirect light from 16-ray probes on the texels that read the cache
//! itself, so bounces accumulate frame after frame), and read by a lookup that another
//! technique's pass imports (`shaders/parts/surface_cache/shared.wgsl`, `gilab::surface_cache`).
//!
//! The part owns the cards (`cards.rs`), the atlas textures and lighting buffers, the capture
//! raster passes (`capture.rs`), the `cache direct`, `cache probes` and `cache indirect` passes,
//! the world ReGIR clipmap its texels may take their lights from (`cache_direct = "regir"`) and
//! the cards' scene-change handling. Its passes trace rays through the scene-tracing part
//! ([`crate::parts::tracing`]: `gilab::tracing`'s `trace_scene` and `light_visible`, the distance
//! field or the BVH by the holder's uniform), at bind group 2. So the cache's resources sit in its holder's
//! group 2 beside that representation, at fixed binding numbers ([`SurfaceCache::layout_entries`],
//! [`SurfaceCache::entries`]):
//!
//! - Lumen holds one like any reader, binds these entries into its own group 2 (its final
//!   gather reads the lookup there) and records the cache's passes with that group.
//! - On its own ([`SurfaceCache::new`]) it builds a group 2 of its own: Lumen's tracing uniform
//!   in BVH mode and no distance field, and, for `gi_terminate = "lumen-world"`, a world
//!   radiance cache ([`crate::parts::WorldCache`], Lumen's default sizes). The seed (shared/seeds/
//!   003, "connecting at the surface cache") ends ReSTIR GI's sample paths in it (`gi_terminate =
//!   "lumen-cards"`): the cache runs inside the frame that reads it, its passes timed under
//!   their names and its rays counted as `cache`, so a connection's frame time includes what
//!   keeping the cache lit costs. Each engine entry holds its own cache: two panes never share
//!   one, so each pane's timings include its own cache work (fair for A/B timing).

mod capture;
pub mod cards;

use crate::gpu::{timing::PassTimer, Gpu};
use crate::parts::texels::BufferTexels;
use crate::parts::tracing::{self, BvhOnly};
use crate::parts::world_cache::{WorldCache, WorldCachePipelines, WorldCacheSettings};
use crate::parts::world_regir::{WorldRegir, WorldRegirSettings};
use crate::render::pipelines::init_buffer;
use crate::render::{pipelines, PassInfo, RenderContext};
use crate::scene::features::SceneFeatures;
use anyhow::Result;
use cards::CardSet;
use glam::Vec3;

/// The lookup's bindings (`gilab::surface_cache`): cards, objects' card ranges, triangle
/// objects, direct and indirect irradiance per texel, the atlas textures. Binding numbers are
/// those of the holder's group 2, so the same module serves Lumen at group 2 and another
/// technique at the group it names with `SURFACE_CACHE_GROUP`.
pub const LOOKUP_BINDINGS: [u32; 5] = [1, 2, 3, 12, 13];
pub const LOOKUP_TEXTURES: [u32; 4] = [19, 20, 21, 22];
/// The cards again as texels (`card_texels`), beside the atlas textures.
pub const CARD_TEXELS: u32 = 23;
/// The passes' own bindings in the holder's group 2 (`gilab::surface_cache_lighting`): the
/// probes on 4x4 tiles, the tile list (its header holds this frame's share: a uniform more in
/// Lumen's group 2 crashed lavapipe's screen-probe passes).
const PROBES: u32 = 14;
const TILES: u32 = 15;

/// The lighting passes (timer name, file).
const PASSES: [(&str, &str); 3] = [
    ("cache direct", "parts/surface_cache/direct.wgsl"),
    ("cache probes", "parts/surface_cache/probe.wgsl"),
    ("cache indirect", "parts/surface_cache/indirect.wgsl"),
];

/// Budgets are quoted for the seed's 4096^2 atlas.
const BUDGET_ATLAS: f64 = 4096.0;

/// Shader defs of a pipeline that reads the cache at bind group `group`.
pub fn lookup_defs(group: u32) -> [(&'static str, u32); 1] {
    [("SURFACE_CACHE_GROUP", group)]
}

/// A non-filtered 2D float texture read by compute passes (the atlas textures).
pub fn texture_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable: false },
            view_dimension: wgpu::TextureViewDimension::D2,
            multisampled: false,
        },
        count: None,
    }
}

/// The card texels' entry: a 2D rgba32uint texture read by compute passes.
fn card_texels_entry() -> wgpu::BindGroupLayoutEntry {
    crate::parts::texels::texture_entry(CARD_TEXELS, wgpu::TextureSampleType::Uint)
}

/// Texels per row of the card texels (4095 and 12 in `card_texel`).
const CARD_TEXELS_PER_ROW: u32 = 4096;

/// The cards as an rgba32uint texture, four texels a card (the lookup's `card_at`,
/// shaders/parts/surface_cache/shared.wgsl): the same words as the cards' storage buffer, which
/// the capture's raster pass and the card count keep reading. Every cache lookup walks its
/// object's cards, and lavapipe reads a texel several times faster than a storage-buffer vec4
/// (crate::parts::texels).
fn card_texels(gpu: &Gpu, cards: &[cards::GpuCard]) -> Result<BufferTexels> {
    let t = BufferTexels::new(
        gpu,
        "lumen card texels",
        wgpu::TextureFormat::Rgba32Uint,
        4 * cards.len() as u32,
        CARD_TEXELS_PER_ROW,
    )?;
    t.write(gpu, bytemuck::cast_slice(cards));
    Ok(t)
}

/// `CacheParams` of shaders/parts/surface_cache/lighting.wgsl, the tile list's header.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct CacheParamsGpu {
    pub atlas_size: u32,
    pub card_count: u32,
    pub direct_tile_first: u32,
    pub direct_tile_count: u32,
    pub direct_tiles_total: u32,
    pub probe_tile_first: u32,
    pub probe_tile_count: u32,
    pub probe_tiles_total: u32,
}

/// What sizes and drives the cache (Lumen's `atlas_size`, `*_texels_per_frame`, `cache_direct`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfaceCacheSettings {
    /// Side of the atlas in texels.
    pub atlas_size: u32,
    /// Texels relit per frame (direct light), quoted for a 4096² atlas.
    pub direct_texels_per_frame: u32,
    /// Texels relit per frame (indirect light), quoted for a 4096² atlas.
    pub indirect_texels_per_frame: u32,
    /// How texels pick their lights.
    pub cache_light: WorldRegirSettings,
}

struct Pipelines {
    capture: wgpu::RenderPipeline,
    capture_clear: wgpu::RenderPipeline,
    lighting: [wgpu::ComputePipeline; 3],
}

struct Resources {
    gpu_params: CacheParamsGpu,
    /// Group 2's buffers by binding: cards, object cards, triangle objects, direct and
    /// indirect irradiance, probes, tiles.
    buffers: Vec<(u32, wgpu::Buffer)>,
    atlas_views: Vec<wgpu::TextureView>,
    card_texels: BufferTexels,
    capture_depth_view: wgpu::TextureView,
    index_buffer: wgpu::Buffer,
    capture_bind_group: wgpu::BindGroup,
    /// This frame's tile-list headers (moved cards' runs, then the round robin), each copied
    /// into the tile list's header before its passes.
    headers: wgpu::Buffer,
}

impl Resources {
    fn buffer(&self, binding: u32) -> &wgpu::Buffer {
        &self
            .buffers
            .iter()
            .find(|(b, _)| *b == binding)
            .expect("a cache binding")
            .1
    }

    /// The lookup's textures: the atlas (LOOKUP_TEXTURES) and the card texels.
    fn texture_entries(&self) -> Vec<wgpu::BindGroupEntry<'_>> {
        let views = self.atlas_views.iter().chain([&self.card_texels.view]);
        LOOKUP_TEXTURES
            .iter()
            .chain([&CARD_TEXELS])
            .zip(views)
            .map(|(&binding, view)| wgpu::BindGroupEntry {
                binding,
                resource: wgpu::BindingResource::TextureView(view),
            })
            .collect()
    }
}

/// What a scene change did to the cache (`SurfaceCache::refresh_for_scene`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refresh {
    /// No resources yet: build them.
    Build,
    /// Kept (a material edit queued every card for a recapture).
    Kept,
    /// Triangles moved: new cards and card buffers (the holder's group 2 must be made anew),
    /// the lighting starts over.
    NewCards,
    /// Objects moved rigidly: their cards were re-placed in the same buffers and are captured
    /// and relit first; every other texel keeps its lighting.
    Moved,
}

/// Runs of re-placed cards relit ahead of the round robin per frame (one tile-list header each).
const PRIORITY_RUNS: usize = 15;

/// The cache on its own: the group 2 its passes trace through and the world cache.
struct Standalone {
    world: Option<WorldCacheSettings>,
    layout: Option<wgpu::BindGroupLayout>,
    /// The scene-tracing bindings without a distance field (BVH mode).
    trace: Option<BvhOnly>,
    bind_group: Option<wgpu::BindGroup>,
    world_cache: Option<(WorldCache, WorldCachePipelines)>,
    lookup: Option<wgpu::BindGroup>,
    flags: u32,
}

pub struct SurfaceCache {
    pub settings: SurfaceCacheSettings,
    capture_layout: Option<wgpu::BindGroupLayout>,
    pipelines: Option<Pipelines>,
    res: Option<Resources>,
    cards: Option<CardSet>,
    /// Cards still to capture, nearest first when taken.
    capture_queue: Vec<u32>,
    /// Re-placed cards: captured next frame whatever the budget, then relit ahead of the
    /// round robin.
    moved_captures: Vec<u32>,
    moved_relight: Vec<u32>,
    direct_tiles: u32,
    probe_tiles: u32,
    direct_cursor: u32,
    probe_cursor: u32,
    /// The scene the cards were built for: its triangles (a change rebuilds them) and
    /// materials (a change recaptures them).
    scene_tris: Vec<[Vec3; 3]>,
    scene_materials: Vec<u8>,
    features: SceneFeatures,
    /// The world ReGIR clipmap the texels take their lights from (`cache_direct = "regir"`;
    /// built the first time it is asked for).
    world_regir: WorldRegir,
    /// The `cache_direct` the "cache direct" pipeline was composed for.
    direct_light: &'static str,
    standalone: Option<Standalone>,
}

impl SurfaceCache {
    /// A cache its holder binds into its own group 2 (Lumen).
    pub fn held(settings: SurfaceCacheSettings) -> SurfaceCache {
        SurfaceCache {
            settings,
            capture_layout: None,
            pipelines: None,
            res: None,
            cards: None,
            capture_queue: Vec::new(),
            moved_captures: Vec::new(),
            moved_relight: Vec::new(),
            direct_tiles: 0,
            probe_tiles: 0,
            direct_cursor: 0,
            probe_cursor: 0,
            scene_tris: Vec::new(),
            scene_materials: Vec::new(),
            features: SceneFeatures::default(),
            world_regir: WorldRegir::default(),
            direct_light: "power",
            standalone: None,
        }
    }

    /// A cache on its own with `atlas_size`² texels that relights `update` of them (a
    /// fraction) per frame, direct and indirect light each, its texels picking their lights as
    /// `light` says; traced through the BVH (the connection then measures the cache, not the
    /// distance field's approximation). With `world`, it also keeps a world radiance cache
    /// (Lumen's default sizes and update budget), whose probes its reader marks and whose
    /// lookup it binds beside its own.
    pub fn new(
        atlas_size: u32,
        update: f32,
        light: WorldRegirSettings,
        world: bool,
    ) -> Result<SurfaceCache> {
        let texels = Self::budget(update);
        let mut cache = SurfaceCache::held(SurfaceCacheSettings {
            atlas_size,
            direct_texels_per_frame: texels,
            indirect_texels_per_frame: texels,
            cache_light: light,
        });
        cache.standalone = Some(Standalone {
            world: world.then_some(crate::parts::world_cache::DEFAULTS),
            layout: None,
            trace: None,
            bind_group: None,
            world_cache: None,
            lookup: None,
            flags: 0,
        });
        Ok(cache)
    }

    /// The texel budget (quoted for a 4096² atlas) that relights `update` (a fraction) of the
    /// atlas per frame: budgets scale with the atlas's area.
    pub fn budget(update: f32) -> u32 {
        ((update.clamp(0.0, 1.0) as f64 * 4096.0 * 4096.0).round() as u32).max(1)
    }

    /// Texels per frame of a budget quoted for the seed's 4096^2 atlas.
    fn scaled_budget(&self, texels: u32) -> f64 {
        let a = self.settings.atlas_size as f64 / BUDGET_ATLAS;
        texels as f64 * a * a
    }

    /// The world ReGIR clipmap's lookup counts (`cache_direct = "regir"`; tests).
    pub fn cache_regir_coverage(&self, gpu: &Gpu) -> Result<crate::parts::world_regir::Coverage> {
        self.world_regir.coverage(gpu)
    }

    /// How its texels pick their lights (`cache_direct`).
    pub fn cache_light(&self) -> WorldRegirSettings {
        self.settings.cache_light
    }

    /// Whether it keeps the world radiance cache too (on its own only).
    pub fn has_world(&self) -> bool {
        self.standalone.as_ref().is_some_and(|s| s.world.is_some())
    }

    /// (atlas size, texel budget) it was made with.
    pub fn sized(&self) -> (u32, u32) {
        (
            self.settings.atlas_size,
            self.settings.direct_texels_per_frame,
        )
    }

    /// The cards and objects of the current scene.
    pub fn card_set(&self) -> Option<&CardSet> {
        self.cards.as_ref()
    }

    /// The cache's entries in its holder's group 2 layout: card data (1-3), lighting (12-13),
    /// probes (14), tiles (15), atlas textures (19-22), card texels (23).
    pub fn layout_entries() -> Vec<wgpu::BindGroupLayoutEntry> {
        let mut entries: Vec<wgpu::BindGroupLayoutEntry> = [1, 2, 3, 12, 13, PROBES, TILES]
            .iter()
            .map(|&b| pipelines::storage_entry(b, b <= 3 || b == TILES))
            .collect();
        entries.extend(LOOKUP_TEXTURES.iter().map(|&b| texture_entry(b)));
        entries.push(card_texels_entry());
        entries
    }

    /// The cache's entries of its holder's group 2 over the current resources (`None` before
    /// `build_resources`); a holder makes its group anew after `Refresh::NewCards`.
    pub fn entries(&self) -> Option<Vec<wgpu::BindGroupEntry<'_>>> {
        let r = self.res.as_ref()?;
        let mut entries: Vec<wgpu::BindGroupEntry> = r
            .buffers
            .iter()
            .map(|(b, buffer)| wgpu::BindGroupEntry {
                binding: *b,
                resource: buffer.as_entire_binding(),
            })
            .collect();
        entries.extend(r.texture_entries());
        Some(entries)
    }

    /// Layout of the lookup's bind group (the group a reading pass sets `SURFACE_CACHE_GROUP`
    /// to), with the world cache's lookup bindings when `world` (`WORLD_CACHE_GROUP`, the same).
    pub fn lookup_layout(gpu: &Gpu, world: bool) -> wgpu::BindGroupLayout {
        let mut entries: Vec<wgpu::BindGroupLayoutEntry> = LOOKUP_BINDINGS
            .iter()
            .map(|&b| pipelines::storage_entry(b, b <= 3))
            .collect();
        entries.extend(LOOKUP_TEXTURES.iter().map(|&b| texture_entry(b)));
        entries.push(card_texels_entry());
        if world {
            entries.extend(crate::parts::world_cache::lookup_entries());
        }
        pipelines::layout(gpu, "surface cache lookup", &entries)
    }

    /// A bind group of the lookup's bindings under `layout` (`lookup_layout(gpu, world)`), with
    /// `world`'s lookup bindings when given; `None` before `build_resources`.
    pub fn lookup_bind_group(
        &self,
        gpu: &Gpu,
        layout: &wgpu::BindGroupLayout,
        world: Option<&WorldCache>,
    ) -> Option<wgpu::BindGroup> {
        let r = self.res.as_ref()?;
        let mut entries: Vec<wgpu::BindGroupEntry> = LOOKUP_BINDINGS
            .iter()
            .map(|&b| wgpu::BindGroupEntry {
                binding: b,
                resource: r.buffer(b).as_entire_binding(),
            })
            .collect();
        entries.extend(r.texture_entries());
        if let Some(w) = world {
            entries.extend(w.entries());
        }
        Some(gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("surface cache lookup"),
            layout,
            entries: &entries,
        }))
    }

    /// The cache's pipelines over the scene, the frame and `group2` (the holder's group 2, with
    /// [`Self::layout_entries`]); nothing is replaced on error. Also prepares the world ReGIR
    /// clipmap when the texels take their lights from it.
    pub fn build_pipelines(
        &mut self,
        ctx: &RenderContext,
        group2: &wgpu::BindGroupLayout,
    ) -> Result<()> {
        let capture_layout = self
            .capture_layout
            .get_or_insert_with(|| capture::layout(ctx.gpu))
            .clone();
        let direct =
            WorldRegir::lighting_pipeline(ctx, PASSES[0].1, group2, &self.settings.cache_light)?;
        let probes = ctx.pipeline(PASSES[1].1, group2)?;
        let indirect = ctx.pipeline(PASSES[2].1, group2)?;
        let (capture, capture_clear) = capture::pipelines(ctx, &capture_layout)?;
        self.world_regir
            .prepare_for(ctx, &self.settings.cache_light, true)?;
        self.direct_light = self.settings.cache_light.name();
        self.pipelines = Some(Pipelines {
            capture,
            capture_clear,
            lighting: [direct, probes, indirect],
        });
        Ok(())
    }

    /// New settings (`cache_direct` may change; sizes that change need `build_resources`):
    /// prepares the ReGIR clipmap and recomposes `cache direct` when the light choice changed.
    pub fn apply_settings(
        &mut self,
        ctx: &RenderContext,
        group2: &wgpu::BindGroupLayout,
    ) -> Result<()> {
        self.world_regir
            .prepare_for(ctx, &self.settings.cache_light, false)?;
        let light = self.settings.cache_light.name();
        if self.direct_light != light {
            let pipeline = WorldRegir::lighting_pipeline(
                ctx,
                PASSES[0].1,
                group2,
                &self.settings.cache_light,
            )?;
            if let Some(p) = self.pipelines.as_mut() {
                p.lighting[0] = pipeline;
            }
            self.direct_light = light;
        }
        Ok(())
    }

    /// (Re)builds the cards, the atlas and the lighting buffers; the cache starts unlit and
    /// every card is queued for capture.
    pub fn build_resources(&mut self, ctx: &RenderContext) -> Result<()> {
        let gpu = ctx.gpu;
        let data = &ctx.scene.data;
        self.features = data.features.clone();
        let s = self.settings;
        let card_set = cards::build(data, s.atlas_size)?;
        let max_binding = gpu.device.limits().max_storage_buffer_binding_size;
        let atlas_texels = s.atlas_size as u64 * s.atlas_size as u64;
        anyhow::ensure!(
            atlas_texels * 16 <= max_binding,
            "lumen: atlas_size = {} needs {} MiB per lighting buffer, over this device's {} MiB binding limit",
            s.atlas_size,
            (atlas_texels * 16) >> 20,
            max_binding >> 20
        );
        let capture_layout = self
            .capture_layout
            .get_or_insert_with(|| capture::layout(gpu))
            .clone();
        let ([cards_buffer, object_cards, tri_object, tiles], index_buffer, nd, np) =
            card_buffers(gpu, &card_set);
        let buf = |label: &str, size: u64| pipelines::storage_buffer(gpu, label, size.max(16));
        let gpu_params = CacheParamsGpu {
            atlas_size: s.atlas_size,
            card_count: card_set.cards.len() as u32,
            direct_tiles_total: nd,
            probe_tiles_total: np,
            ..Default::default()
        };
        let capture_bind_group = capture::bind_group(gpu, &capture_layout, &cards_buffer);
        let buffers = vec![
            (1, cards_buffer),
            (2, object_cards),
            (3, tri_object),
            (12, buf("lumen atlas direct", atlas_texels * 16)),
            (13, buf("lumen atlas indirect", atlas_texels * 16)),
            (PROBES, buf("lumen probes", atlas_texels / 16 * 48)),
            (TILES, tiles),
        ];
        let (atlas_views, capture_depth_view) = capture::atlas(gpu, s.atlas_size);
        let card_texels = card_texels(gpu, &card_set.cards)?;
        let headers = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("lumen tile headers"),
            size: ((PRIORITY_RUNS + 1) * std::mem::size_of::<CacheParamsGpu>()) as u64,
            usage: wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        self.res = Some(Resources {
            gpu_params,
            buffers,
            atlas_views,
            card_texels,
            capture_depth_view,
            index_buffer,
            capture_bind_group,
            headers,
        });
        self.moved_captures.clear();
        self.moved_relight.clear();
        self.direct_tiles = nd;
        self.probe_tiles = np;
        self.direct_cursor = 0;
        self.probe_cursor = 0;
        self.capture_queue = (0..card_set.cards.len() as u32).collect();
        self.cards = Some(card_set);
        self.scene_tris = data.tris.clone();
        self.scene_materials = bytemuck::cast_slice(&data.materials).to_vec();
        self.world_regir
            .prepare_for(ctx, &self.settings.cache_light, false)?;
        Ok(())
    }

    /// A scene change keeps what still holds: unchanged triangles keep everything; a material
    /// edit recaptures the cards; objects of instances that moved get their cards re-placed
    /// (`Refresh::Moved`); other moved, added or removed triangles rebuild the cards (the
    /// lighting starts over).
    pub fn refresh_for_scene(&mut self, ctx: &RenderContext) -> Result<Refresh> {
        let gpu = ctx.gpu;
        let data = &ctx.scene.data;
        if self.res.is_none() {
            return Ok(Refresh::Build);
        }
        self.features = data.features.clone();
        let materials: Vec<u8> = bytemuck::cast_slice(&data.materials).to_vec();
        if data.tris != self.scene_tris && materials == self.scene_materials && self.replace(ctx) {
            return Ok(Refresh::Moved);
        }
        if data.tris != self.scene_tris {
            let card_set = cards::build(data, self.settings.atlas_size)?;
            let capture_layout = self
                .capture_layout
                .get_or_insert_with(|| capture::layout(gpu))
                .clone();
            let (new, index_buffer, nd, np) = card_buffers(gpu, &card_set);
            let Some(r) = self.res.as_mut() else {
                return Ok(Refresh::Build);
            };
            for (b, buffer) in [1, 2, 3, TILES].into_iter().zip(new) {
                if let Some(slot) = r.buffers.iter_mut().find(|(k, _)| *k == b) {
                    slot.1 = buffer;
                }
            }
            r.index_buffer = index_buffer;
            r.capture_bind_group = capture::bind_group(gpu, &capture_layout, r.buffer(1));
            r.gpu_params.card_count = card_set.cards.len() as u32;
            r.gpu_params.direct_tiles_total = nd;
            r.gpu_params.probe_tiles_total = np;
            self.direct_tiles = nd;
            self.probe_tiles = np;
            self.capture_queue = (0..card_set.cards.len() as u32).collect();
            self.moved_captures.clear();
            self.moved_relight.clear();
            self.cards = Some(card_set);
            self.scene_tris = data.tris.clone();
            self.scene_materials = materials;
            self.reset(gpu);
            return Ok(Refresh::NewCards);
        }
        if materials != self.scene_materials {
            self.scene_materials = materials;
            self.capture_queue =
                (0..self.cards.as_ref().map_or(0, |c| c.cards.len() as u32)).collect();
        }
        Ok(Refresh::Kept)
    }

    /// The objects whose triangles changed (same triangle count) get their cards re-placed and
    /// written alone to the card buffer; false, with nothing changed, where that cannot be done.
    fn replace(&mut self, ctx: &RenderContext) -> bool {
        let data = &ctx.scene.data;
        let (Some(c), Some(r)) = (self.cards.as_mut(), self.res.as_ref()) else {
            return false;
        };
        if data.tris.len() != self.scene_tris.len() || c.tri_object.len() != data.tris.len() {
            return false;
        }
        let mut moved: Vec<u32> = data
            .tris
            .iter()
            .zip(&self.scene_tris)
            .zip(&c.tri_object)
            .filter(|((a, b), _)| a != b)
            .map(|(_, &o)| o)
            .collect();
        moved.sort_unstable();
        moved.dedup();
        // Only instances move rigidly; an edit of the rest rebuilds the cards.
        if moved.iter().any(|&o| {
            c.object_instance
                .get(o as usize)
                .is_none_or(|&i| i == cards::NO_INSTANCE)
        }) {
            return false;
        }
        let changed = c.replace_objects(data, &self.scene_tris, &moved);
        let size = std::mem::size_of::<cards::GpuCard>() as u64;
        for &k in &changed {
            ctx.gpu.queue.write_buffer(
                r.buffer(1),
                k as u64 * size,
                bytemuck::bytes_of(&c.cards[k as usize]),
            );
        }
        if !changed.is_empty() {
            r.card_texels.write(ctx.gpu, bytemuck::cast_slice(&c.cards));
        }
        self.capture_queue.retain(|k| !changed.contains(k));
        for k in changed {
            if !self.moved_captures.contains(&k) {
                self.moved_captures.push(k);
            }
            if !self.moved_relight.contains(&k) {
                self.moved_relight.push(k);
            }
        }
        self.scene_tris = data.tris.clone();
        true
    }

    /// Direct irradiance per atlas texel (rgb, w: valid), read back (tests).
    pub fn read_direct(&self, gpu: &Gpu) -> Result<Option<Vec<[f32; 4]>>> {
        let Some(r) = &self.res else {
            return Ok(None);
        };
        let texels = (self.settings.atlas_size * self.settings.atlas_size) as usize;
        crate::gpu::readback::read_buffer(gpu, r.buffer(12), texels).map(Some)
    }

    /// Cards re-placed since the last frame was recorded (tests, debug).
    pub fn moved_cards(&self) -> &[u32] {
        &self.moved_relight
    }

    /// Forgets the cache's lighting (it relights over the next frames).
    pub fn reset(&self, gpu: &Gpu) {
        if let Some(r) = &self.res {
            let mut enc = gpu.device.create_command_encoder(&Default::default());
            for b in [12, 13, PROBES] {
                enc.clear_buffer(r.buffer(b), 0, None);
            }
            gpu.submit("surface cache: history reset", enc.finish());
        }
        if let Some((w, _)) = self
            .standalone
            .as_ref()
            .and_then(|s| s.world_cache.as_ref())
        {
            w.reset(gpu);
        }
    }

    /// This frame's cache work through `group2` (the holder's group 2): card captures (nearest
    /// the camera first), then direct and indirect texel updates, round robin over the tiles.
    pub fn record_passes(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
        group2: &wgpu::BindGroup,
    ) {
        if self.pipelines.is_none() || self.res.is_none() {
            return;
        }
        let mut captures = std::mem::take(&mut self.moved_captures);
        captures.extend(self.next_captures(ctx.camera.position));
        let runs = self.moved_runs();
        let direct =
            (self.scaled_budget(self.settings.direct_texels_per_frame) / 64.0).ceil() as u32;
        let probes =
            (self.scaled_budget(self.settings.indirect_texels_per_frame) / 16.0).ceil() as u32;
        let direct = direct.clamp(1, self.direct_tiles.max(1));
        let probes = probes.clamp(1, self.probe_tiles.max(1));
        let (direct_first, probe_first) = (self.direct_cursor, self.probe_cursor);
        self.direct_cursor = (self.direct_cursor + direct) % self.direct_tiles.max(1);
        self.probe_cursor = (self.probe_cursor + probes) % self.probe_tiles.max(1);
        let (Some(p), Some(r)) = (&self.pipelines, self.res.as_mut()) else {
            return;
        };
        let gp = &mut r.gpu_params;
        gp.direct_tile_first = direct_first;
        gp.direct_tile_count = direct;
        gp.probe_tile_first = probe_first;
        gp.probe_tile_count = probes;
        // Moved cards' runs first, then the round robin: one header each.
        let mut headers: Vec<CacheParamsGpu> = runs
            .iter()
            .map(|&[df, dc, pf, pc]| CacheParamsGpu {
                direct_tile_first: df,
                direct_tile_count: dc,
                probe_tile_first: pf,
                probe_tile_count: pc,
                ..*gp
            })
            .collect();
        headers.push(*gp);
        ctx.gpu
            .queue
            .write_buffer(&r.headers, 0, bytemuck::cast_slice(&headers));
        if !captures.is_empty() {
            if let Some(c) = &self.cards {
                capture::record(ctx, enc, timer, p, r, c, &captures);
            }
        }
        let lights = self.features.light_count() > 0 && self.direct_tiles > 0;
        let regir = if lights {
            self.world_regir.record_for_pass(
                ctx,
                enc,
                timer,
                self.direct_light == "regir",
                self.features.many_lights,
            )
        } else {
            None
        };
        let groups: Vec<&wgpu::BindGroup> = [Some(group2), regir].into_iter().flatten().collect();
        let header = std::mem::size_of::<CacheParamsGpu>() as u64;
        for (k, h) in headers.iter().enumerate() {
            enc.copy_buffer_to_buffer(&r.headers, k as u64 * header, r.buffer(TILES), 0, header);
            let (direct, probes) = (h.direct_tile_count, h.probe_tile_count);
            if lights && direct > 0 {
                pipelines::technique_pass(
                    ctx,
                    enc,
                    timer,
                    PASSES[0].0,
                    &p.lighting[0],
                    &groups,
                    [direct, 1, 1],
                );
            }
            if self.probe_tiles > 0 && probes > 0 {
                pipelines::technique_pass(
                    ctx,
                    enc,
                    timer,
                    PASSES[1].0,
                    &p.lighting[1],
                    &[group2],
                    // Four probes of 16 rays a workgroup (probe.wgsl).
                    [probes.div_ceil(4), 1, 1],
                );
                pipelines::technique_pass(
                    ctx,
                    enc,
                    timer,
                    PASSES[2].0,
                    &p.lighting[2],
                    &[group2],
                    [probes.div_ceil(4), 1, 1],
                );
            }
        }
    }

    /// Takes the re-placed cards off the relight list as runs of consecutive cards: (first
    /// direct tile, count, first probe tile, count) each, at most `PRIORITY_RUNS` (the rest
    /// wait for the next frame).
    fn moved_runs(&mut self) -> Vec<[u32; 4]> {
        let Some(c) = &self.cards else {
            self.moved_relight.clear();
            return Vec::new();
        };
        let mut cards = std::mem::take(&mut self.moved_relight);
        cards.sort_unstable();
        let (ds, ps) = (c.tile_starts(8), c.tile_starts(4));
        let end = |starts: &[u32], k: usize, total: u32| starts.get(k).copied().unwrap_or(total);
        let mut runs: Vec<[u32; 2]> = Vec::new();
        for k in cards {
            match runs.last_mut() {
                Some(r) if r[1] == k => r[1] = k + 1,
                _ => runs.push([k, k + 1]),
            }
        }
        if runs.len() > PRIORITY_RUNS {
            for r in runs.split_off(PRIORITY_RUNS) {
                self.moved_relight.extend(r[0]..r[1]);
            }
        }
        const MAX_GROUPS: u32 = 65_535;
        runs.iter()
            .map(|&[a, b]| {
                let (a, b) = (a as usize, b as usize);
                let d = end(&ds, a, self.direct_tiles);
                let q = end(&ps, a, self.probe_tiles);
                [
                    d,
                    (end(&ds, b, self.direct_tiles) - d).min(MAX_GROUPS),
                    q,
                    (end(&ps, b, self.probe_tiles) - q).min(MAX_GROUPS * 4),
                ]
            })
            .collect()
    }

    /// Takes this frame's captures off the queue: nearest the camera first, up to the budget.
    fn next_captures(&mut self, camera: Vec3) -> Vec<u32> {
        let Some(c) = &self.cards else {
            return Vec::new();
        };
        let cards = &c.cards;
        self.capture_queue.sort_by(|a, b| {
            let da = cards[*a as usize].centre().distance_squared(camera);
            let db = cards[*b as usize].centre().distance_squared(camera);
            db.total_cmp(&da)
        });
        let mut out = Vec::new();
        let mut texels = 0;
        while let Some(&next) = self.capture_queue.last() {
            let t = cards[next as usize].texels();
            if !out.is_empty() && texels + t > capture::TEXELS_PER_FRAME {
                break;
            }
            texels += t;
            out.push(next);
            self.capture_queue.pop();
        }
        out
    }

    /// The cache's passes, traced through the BVH or the distance field (`bvh`).
    pub fn cache_passes(&self, f: &SceneFeatures, bvh: bool) -> Vec<PassInfo> {
        let s = &self.settings;
        let pass = |name, runs, why: String| PassInfo { name, runs, why };
        let lights = f.light_count() > 0;
        let cards = self.cards.as_ref();
        let regir = s.cache_light.regir && f.many_lights;
        vec![
            pass(
                "capture",
                true,
                format!(
                    "{} cards of {} objects in {} pages; up to {} texels per frame, nearest first",
                    cards.map_or(0, |c| c.cards.len()),
                    cards.map_or(0, |c| c.object_count()),
                    cards.map_or(0, |c| c.pages_used),
                    capture::TEXELS_PER_FRAME
                ),
            ),
            WorldRegir::pass_info(&s.cache_light, f),
            pass(
                "cache direct",
                lights,
                if lights {
                    format!(
                        "{:.0} texels per frame, one light {} and one {} shadow ray each",
                        self.scaled_budget(s.direct_texels_per_frame),
                        if regir {
                            "from the world ReGIR clipmap"
                        } else if s.cache_light.uses_tree() {
                            "by the light tree"
                        } else {
                            "by power"
                        },
                        if bvh { "BVH" } else { "SDF" }
                    )
                } else {
                    "no lights in the pool".into()
                },
            ),
            pass("cache indirect", true, format!("{:.0} texels per frame: 16-ray probes on 4x4 tiles reading the cache (one more bounce per update), 4-frame blend", self.scaled_budget(s.indirect_texels_per_frame))),
        ]
    }
}

/// The cache on its own (ReSTIR GI's `lumen-cards` and `lumen-world`).
impl SurfaceCache {
    /// Its group 2: Lumen's tracing uniform and distance-field bindings (placeholders: it
    /// traces the BVH) and the cache's entries.
    fn standalone_layout(gpu: &Gpu) -> wgpu::BindGroupLayout {
        let mut entries = tracing::layout_entries();
        entries.extend(Self::layout_entries());
        pipelines::layout(gpu, "surface cache", &entries)
    }

    /// Builds the cache's pipelines and resources (on error the previous pipelines stay).
    pub fn build(&mut self, ctx: &RenderContext) -> Result<()> {
        let gpu = ctx.gpu;
        let Some(st) = self.standalone.as_mut() else {
            anyhow::bail!("surface cache: a held cache is built by its holder");
        };
        let layout = st
            .layout
            .get_or_insert_with(|| Self::standalone_layout(gpu))
            .clone();
        let world_pipelines = match st.world {
            Some(_) => Some(WorldCachePipelines::build(ctx, &layout)?),
            None => None,
        };
        self.build_pipelines(ctx, &layout)?;
        let refresh = self.refresh_for_scene(ctx)?;
        if refresh == Refresh::Build {
            self.build_resources(ctx)?;
        }
        let st = self.standalone.as_mut().expect("standalone");
        if let (Some(w), Some(pipes)) = (st.world, world_pipelines) {
            let cache = match st.world_cache.take() {
                Some((c, _)) if refresh != Refresh::Build => c,
                _ => WorldCache::new(gpu, w)?,
            };
            st.world_cache = Some((cache, pipes));
        }
        let data = &ctx.scene.data;
        let sky = ctx.scene.sky.max_element() > 0.0 && data.features.sky_visible;
        st.flags = BvhOnly::flags(sky, data.features.light_count() > 0);
        if st.trace.is_none() {
            st.trace = Some(BvhOnly::new(gpu, "surface cache tracing")?);
        }
        if refresh == Refresh::Build {
            self.reset(gpu);
        }
        self.standalone_groups(gpu);
        Ok(())
    }

    /// Its group 2 and lookup over the current resources.
    fn standalone_groups(&mut self, gpu: &Gpu) {
        let Some(entries) = self.entries() else {
            return;
        };
        let Some(st) = self.standalone.as_ref() else {
            return;
        };
        let (Some(layout), Some(trace)) = (&st.layout, &st.trace) else {
            return;
        };
        let mut all = trace.entries();
        all.extend(entries);
        let bind_group = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("surface cache"),
            layout,
            entries: &all,
        });
        let world = st.world_cache.as_ref().map(|(w, _)| w);
        let lookup = self.lookup_bind_group(gpu, &Self::lookup_layout(gpu, world.is_some()), world);
        let st = self.standalone.as_mut().expect("standalone");
        st.bind_group = Some(bind_group);
        st.lookup = lookup;
    }

    pub fn is_built(&self) -> bool {
        self.standalone.as_ref().is_some_and(|s| s.lookup.is_some())
    }

    /// The lookup's bind group: valid until the next `build`.
    pub fn lookup(&self) -> Option<&wgpu::BindGroup> {
        self.standalone.as_ref()?.lookup.as_ref()
    }

    /// This frame's cache work: card captures, direct and indirect texel updates, and the
    /// world cache's probes read by the reader when it keeps one.
    pub fn record(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
    ) {
        let Some(st) = self.standalone.as_ref() else {
            return;
        };
        let (Some(group), Some(trace)) = (st.bind_group.clone(), &st.trace) else {
            return;
        };
        trace.write(ctx.gpu, st.flags);
        self.record_passes(ctx, enc, timer, &group);
        let st = self.standalone.as_mut().expect("standalone");
        if let (Some(s), Some((w, pipes))) = (st.world, st.world_cache.as_mut()) {
            w.record(ctx, enc, timer, &group, pipes, &s, true);
        }
    }

    /// The cache's passes, for the technique that holds it.
    pub fn passes(&self, f: &SceneFeatures) -> Vec<PassInfo> {
        let mut v = self.cache_passes(f, true);
        if let Some(w) = self.standalone.as_ref().and_then(|s| s.world) {
            v.extend(WorldCache::pass_info(&w, true, "BVH", "ReSTIR GI's paths"));
        }
        v
    }
}

/// The card buffers (cards, object cards, triangle objects, tiles after a `CacheParamsGpu`
/// header), the capture index buffer, and the tile counts.
fn card_buffers(gpu: &Gpu, c: &CardSet) -> ([wgpu::Buffer; 4], wgpu::Buffer, u32, u32) {
    let storage = wgpu::BufferUsages::STORAGE;
    let direct = c.tiles(8);
    let probes = c.tiles(4);
    let (nd, np) = (direct.len() as u32, probes.len() as u32);
    let mut tiles = direct;
    tiles.extend(probes);
    (
        [
            // COPY_DST: moved cards are written in place (`replace`).
            init_buffer(
                gpu,
                "lumen cards",
                bytemuck::cast_slice(&c.cards),
                storage | wgpu::BufferUsages::COPY_DST,
            ),
            init_buffer(
                gpu,
                "lumen object cards",
                bytemuck::cast_slice(&c.object_cards),
                storage,
            ),
            init_buffer(
                gpu,
                "lumen triangle objects",
                bytemuck::cast_slice(&c.tri_object),
                storage,
            ),
            init_buffer(
                gpu,
                "lumen tiles",
                &[
                    bytemuck::bytes_of(&CacheParamsGpu::default()),
                    bytemuck::cast_slice(&tiles),
                ]
                .concat(),
                storage | wgpu::BufferUsages::COPY_DST,
            ),
        ],
        init_buffer(
            gpu,
            "lumen capture indices",
            bytemuck::cast_slice(&c.indices),
            wgpu::BufferUsages::INDEX,
        ),
        nd,
        np,
    )
}

/// `gi_terminate = "lumen-cards"`: the surface cache on its own (`SurfaceCache::new`).
pub const CARDS: crate::parts::gi_cache::CacheKind = crate::parts::gi_cache::CacheKind {
    name: "lumen-cards",
    key: |s| standalone_key("lumen-cards", s),
    new: |s| {
        Ok(Box::new(SurfaceCache::new(
            s.atlas_size,
            s.update,
            s.light,
            false,
        )?))
    },
    describe: |s, hit| describe(s, hit, "the surface cache"),
};

/// `gi_terminate = "lumen-world"`: the surface cache with a world radiance cache.
pub const WORLD: crate::parts::gi_cache::CacheKind = crate::parts::gi_cache::CacheKind {
    name: "lumen-world",
    key: |s| standalone_key("lumen-world", s),
    new: |s| {
        Ok(Box::new(SurfaceCache::new(
            s.atlas_size,
            s.update,
            s.light,
            true,
        )?))
    },
    describe: |s, hit| {
        describe(
            s,
            hit,
            "the world radiance cache (the surface cache for short rays)",
        )
    },
};

fn standalone_key(
    name: &'static str,
    s: &crate::parts::gi_cache::CacheSettings,
) -> crate::parts::gi_cache::CacheKey {
    crate::parts::gi_cache::CacheKey {
        name,
        size: s.atlas_size,
        budget: SurfaceCache::budget(s.update),
        light: s.light,
    }
}

fn describe(s: &crate::parts::gi_cache::CacheSettings, hit: u32, what: &str) -> String {
    format!(
        "in {what} at hit {hit} (NEE there, further bounces from the cache: {}² atlas, {:.0}% relit per frame)",
        s.atlas_size,
        s.update * 100.0
    )
}

/// `lumen-cards`, and `lumen-world` when it keeps a world radiance cache.
impl crate::parts::gi_cache::GiCache for SurfaceCache {
    fn key(&self) -> crate::parts::gi_cache::CacheKey {
        let (size, budget) = self.sized();
        crate::parts::gi_cache::CacheKey {
            name: if self.has_world() {
                "lumen-world"
            } else {
                "lumen-cards"
            },
            size,
            budget,
            light: self.cache_light(),
        }
    }

    fn build(&mut self, ctx: &RenderContext) -> Result<()> {
        SurfaceCache::build(self, ctx)
    }

    fn record(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
    ) {
        SurfaceCache::record(self, ctx, enc, timer)
    }

    fn lookup(&self) -> Option<&wgpu::BindGroup> {
        SurfaceCache::lookup(self)
    }

    fn passes(&self, f: &SceneFeatures) -> Vec<PassInfo> {
        SurfaceCache::passes(self, f)
    }

    fn reader(&self, gpu: &Gpu, group: u32) -> (Vec<(&'static str, u32)>, wgpu::BindGroupLayout) {
        let world = self.has_world();
        let mut defs = vec![lookup_defs(group)[0]];
        if world {
            defs.push(crate::parts::world_cache::lookup_defs(group)[0]);
        }
        (defs, SurfaceCache::lookup_layout(gpu, world))
    }

    fn path_end(&self) -> &'static str {
        if self.has_world() {
            "gilab::world_cache_path_end"
        } else {
            "gilab::surface_cache_path_end"
        }
    }

    fn cache_regir_coverage(&self, gpu: &Gpu) -> Result<crate::parts::world_regir::Coverage> {
        SurfaceCache::cache_regir_coverage(self, gpu)
    }

    fn surface_cache(&self) -> Option<&SurfaceCache> {
        Some(self)
    }
}
