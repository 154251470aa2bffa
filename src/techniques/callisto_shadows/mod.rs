//! # Callisto shadows (`callisto-shadows`)
//!
//! Direct light with one shadow ray per light per pixel, the pure ray-traced shadows of "The
//! Rendering of The Callisto Protocol" (SIGGRAPH 2023, shared/seeds/002: RAYTRACED SHADOWS,
//! variable rate, culling, denoising), on the engine's primary surfaces. Per frame:
//!
//! 1. `cull` (one workgroup per 16×16 tile): the tile's depth bounds, point box and normal
//!    cone; every light of the pool is tested (its range sphere against the tile frustum cut to
//!    the depth bounds and against the box, then cone culling) and the survivors written as the
//!    tile's compacted list, sorted by light index; a list that would overflow keeps the
//!    lights with the highest bound on their irradiance at the tile. Lights are the scene's light pool: point,
//!    spot and directional lights and emissive triangles (one area sample per light per pixel).
//!    Ranges come from `range_cutoff`: range = sqrt(intensity / cutoff).
//! 2. `shadows` (one workgroup per tile): per light of the list, the rate of each 2×2 quad
//!    chosen last frame (quarter / half / full), the traced pixels' shadow rays, the bilateral
//!    reconstruction of the skipped ones, the unshadowed contribution times visibility, and the
//!    rates for next frame from the shadow variance weighted by perceptual importance; then
//!    `tail_samples` power-sampled shadow rays for the lights outside the list (list + tail is
//!    unbiased whatever the ranges).
//!    With `static_shadow_cache`, a light that has not moved takes static geometry's
//!    visibility from a world-space hash grid (filled by rays that skip the moving instances) and
//!    traces only the moving instances each frame (`split.rs`, static_cache.wgsl).
//! 3. `luminance_mean`: the mean scene luminance the next frame's weighting uses.
//! 4. `resolve` (per pixel): the punctual lights' shadow mask, the ratio of their shadowed and
//!    unshadowed direct light each averaged over frames, with a disocclusion blur that shrinks
//!    with the frames since, times this frame's (exact) unshadowed light, plus the sampled
//!    lights (emissive triangles, tail) as traced; with `gi`, ReSTIR GI's sample adds indirect light; the engine's
//!    progressive average.
//!
//! Shaders: shaders/callisto_shadows/*.wgsl, shared state in shared.wgsl (group 3; group 2 is
//! ReSTIR's for `resolve`, empty for the others).

mod params;
mod split;

pub use params::{CallistoParamsGpu, CallistoSettings, MAX_LIGHTS_PER_TILE, PARAMS, RATES};

use crate::gpu::{timing::PassTimer, Gpu};
use crate::parts::reflections::HitCache;
use crate::parts::Part;
use crate::parts::{Reflections, RestirDirect, RestirGi};
use crate::render::params::{ParamChanges, Params};
use crate::render::primary::FrameInputs;
use crate::render::{pipelines, DebugView, PassInfo, RenderContext, Technique};
use crate::scene::features::SceneFeatures;
use anyhow::Result;

/// Screen tile edge in pixels (`TILE` in shared.wgsl).
pub const TILE: u32 = 16;
const CULL: &str = "callisto_shadows/cull.wgsl";
const SHADOWS: &str = "callisto_shadows/shadows.wgsl";
const MEAN: &str = "callisto_shadows/luminance_mean.wgsl";
const RESOLVE: &str = "callisto_shadows/resolve.wgsl";
const SETTLE: &str = "callisto_shadows/cache_settle.wgsl";

struct Pipelines {
    cull: wgpu::ComputePipeline,
    shadows: wgpu::ComputePipeline,
    mean: wgpu::ComputePipeline,
    resolve: wgpu::ComputePipeline,
    /// The static cache's end of frame (`static_shadow_cache`).
    settle: wgpu::ComputePipeline,
}

struct Resources {
    bind_group: wgpu::BindGroup,
    /// `pixel_direct` (binding 7) for the direct-light part's pass to write.
    direct_bind_group: wgpu::BindGroup,
    /// `pixel_specular` (binding 8) for the reflections part's filter to write.
    specular_bind_group: wgpu::BindGroup,
    /// Cleared on a history reset: tile lists, rates, stats, shadow-mask history.
    clear_on_reset: Vec<wgpu::Buffer>,
    debug: wgpu::Buffer,
    tiles: [u32; 2],
    uniform: wgpu::Buffer,
    /// The static/dynamic split's buffer (binding 9): masks, dynamic entries, the hash grid.
    cache: wgpu::Buffer,
    cache_layout: split::CacheLayout,
}

pub struct CallistoShadows {
    params: Params,
    pub settings: CallistoSettings,
    /// The ReSTIR GI part for `gi` (pipelines built the first time it is on; its resources
    /// always, for `resolve`'s group 2).
    restir: RestirGi,
    /// The direct-light part for `direct = "restir"` (built the first time it is needed).
    restir_direct: RestirDirect,
    /// The reflections part (built the first time a scene with a specular layer needs it): its
    /// rays' hits are lit by one NEE sample (Callisto has no cache of its own).
    reflections: Reflections,
    /// Whether the scene has a surface with a specular layer (the reflections part runs).
    specular: bool,
    /// What the reflections part was built to light its hits with besides NEE: None (nothing),
    /// Some(world): the surface cache ReSTIR GI's paths end in (`gi_terminate = "lumen-cards"`
    /// or `"lumen-world"`), whose lookup layout holds the world cache's bindings when `world`.
    reflection_cache: Option<bool>,
    layout: Option<wgpu::BindGroupLayout>,
    empty: Option<(wgpu::BindGroupLayout, wgpu::BindGroup)>,
    pipelines: Option<Pipelines>,
    res: Option<Resources>,
    /// Lights in the scene's pool, for the pass list.
    lights: usize,
    /// Which entries and lights have moved (`static_shadow_cache`).
    split: split::Split,
}

impl Default for CallistoShadows {
    fn default() -> Self {
        let params = Params::new("callisto-shadows", PARAMS);
        let settings = CallistoSettings::from_params(&params);
        CallistoShadows {
            restir: {
                let mut gi = RestirGi::default();
                gi.configure(settings.gi, settings.gi_terminate, settings.cache_light);
                gi
            },
            restir_direct: RestirDirect::default(),
            reflections: Reflections::default(),
            specular: false,
            reflection_cache: None,
            settings,
            params,
            layout: None,
            empty: None,
            pipelines: None,
            res: None,
            lights: 0,
            split: split::Split::default(),
        }
    }
}

impl CallistoShadows {
    fn layout(&mut self, gpu: &Gpu) -> wgpu::BindGroupLayout {
        self.layout
            .get_or_insert_with(|| {
                let mut entries = vec![pipelines::uniform_entry(0, wgpu::ShaderStages::COMPUTE)];
                for b in 1..=9 {
                    entries.push(pipelines::storage_entry(b, false));
                }
                pipelines::layout(gpu, "callisto", &entries)
            })
            .clone()
    }

    fn empty(&mut self, gpu: &Gpu) -> (wgpu::BindGroupLayout, wgpu::BindGroup) {
        self.empty
            .get_or_insert_with(|| {
                let layout = pipelines::layout(gpu, "callisto empty", &[]);
                let bg = pipelines::buffers_bind_group(gpu, "callisto empty", &layout, &[]);
                (layout, bg)
            })
            .clone()
    }

    /// Builds ReSTIR GI's pipelines when `gi` is on and they are not built yet; its resources
    /// (the bind group `resolve` needs) in any case.
    fn ensure_restir(&mut self, ctx: &RenderContext, rebuild_gi: bool) -> Result<()> {
        self.restir.configure(
            self.settings.gi,
            self.settings.gi_terminate,
            self.settings.cache_light,
        );
        self.restir.prepare(ctx, rebuild_gi)?;
        self.restir_direct
            .prepare(ctx, self.settings.direct_restir, false, ())
    }

    /// The reflections part runs: `reflections = "traced"` on a scene with a specular layer.
    fn reflections_active(&self) -> bool {
        self.settings.reflections && self.specular
    }

    /// Builds the reflections part when it is needed and not built, or built for another hit
    /// cache (`rebuild`: a shader change rebuilds it if built), and passes it the settings. Its
    /// hits get one NEE sample, plus the surface cache's indirect light where ReSTIR GI's paths
    /// end in one (call after `ensure_restir`, which builds that cache).
    fn prepare_reflections(&mut self, ctx: &RenderContext, rebuild: bool) -> Result<()> {
        self.reflections.settings = self.settings.reflection.clone();
        self.specular = ctx.scene.data.features.min_specular_roughness.is_some();
        let needed = self.reflections_active();
        let cache = self.restir.surface_cache().map(|(_, world)| world);
        // Built for another hit cache: built again for this one.
        let stale = self.reflections.is_built() && cache != self.reflection_cache;
        let layout = cache.map(|world| crate::parts::SurfaceCache::lookup_layout(ctx.gpu, world));
        self.reflections.prepare(
            ctx,
            needed,
            rebuild || stale,
            layout.as_ref().map(HitCache::SurfaceCache),
        )?;
        if self.reflections.is_built() {
            self.reflection_cache = cache;
        }
        Ok(())
    }

    /// The tile shadows run (lights, and not replaced by the direct-light part).
    fn tile_shadows(&self) -> bool {
        self.lights > 0 && !self.settings.direct_restir
    }

    /// Light slots per tile: the setting, or fewer where the rate buffer (2 x tiles x slots x
    /// 16 B) would pass a 128 MiB binding (above 1080p with 512 slots).
    fn slots(&self, tiles: [u32; 2]) -> u32 {
        let tile_count = (tiles[0] as u64 * tiles[1] as u64).max(1);
        let fit = (128u64 << 20) / (2 * tile_count * 16);
        (self.settings.max_lights_per_tile as u64).min(fit).max(1) as u32
    }

    fn gpu_params(
        &self,
        tiles: [u32; 2],
        pixels: u32,
        data: &crate::scene::gpu_scene::SceneData,
        cache: &split::CacheLayout,
    ) -> CallistoParamsGpu {
        let s = &self.settings;
        let top = data.bvh.top.as_ref();
        CallistoParamsGpu {
            shadow_cache: s.static_shadow_cache as u32,
            cache_samples: s.shadow_cache_samples,
            cache_cell: s.shadow_cache_cell,
            cache_slots: cache.slots,
            motion_base: data.bvh.nodes.len() as u32,
            records_at: top.map_or(0, |t| t.records_at as u32),
            dynamic_count: self.split.dynamic_count(),
            light_mask_base: cache.light_mask_base,
            dynamic_base: cache.dynamic_base,
            hash_base: cache.hash_base,
            pad: [0; 2],
            tiles_x: tiles[0],
            tiles_y: tiles[1],
            max_lights: self.slots(tiles),
            rate_mode: s.rate,
            range_cutoff: s.range_cutoff,
            cone_culling: s.cone_culling as u32,
            half_threshold: s.half_threshold,
            full_threshold: s.full_threshold,
            perceptual: s.perceptual,
            border_depth: s.border_depth,
            denoise: s.denoise as u32,
            max_history: s.max_history,
            blur_radius: s.blur_radius,
            accumulate: s.accumulate as u32,
            gi: s.gi as u32,
            pixels,
            tail_samples: s.tail_samples,
            direct_restir: (s.direct_restir && self.lights > 0) as u32,
            reflections: self.reflections_active() as u32,
            reflection_max_roughness: s.reflection.max_roughness,
        }
    }

    fn build_resources(&mut self, ctx: &RenderContext) {
        let gpu = ctx.gpu;
        self.lights = ctx.scene.data.features.light_count();
        let [w, h] = ctx.extent;
        let tiles = [w.div_ceil(TILE), h.div_ceil(TILE)];
        let tile_count = tiles[0] as u64 * tiles[1] as u64;
        let px = w as u64 * h as u64;
        let slots = self.slots(tiles) as u64;
        let buf = |label, size| pipelines::storage_buffer(gpu, label, size);
        let lists = buf("callisto tile lists", 2 * tile_count * (slots + 1) * 4);
        let rates = buf("callisto rates", 2 * tile_count * slots * 16);
        let stats = buf("callisto stats", (1 + tile_count) * 4);
        let current = buf("callisto current", 3 * px * 16);
        let history = buf("callisto history", 2 * px * 32);
        // Two planes of Callisto's views, a third for the reflections part's.
        let debug = buf("callisto debug", 3 * px * 16);
        let pixel_direct = buf("callisto pixel direct", px * 16);
        let pixel_specular = buf("callisto pixel specular", 2 * px * 16);
        self.split.observe(&ctx.scene.data);
        let cache_layout =
            split::CacheLayout::new(&ctx.scene.data, px, self.settings.static_shadow_cache);
        // Zeroed: an empty hash grid.
        let cache = buf("callisto shadow cache", cache_layout.words() * 4);
        gpu.queue.write_buffer(
            &cache,
            0,
            bytemuck::cast_slice(&self.split.head(&ctx.scene.data, &cache_layout)),
        );
        let uniform = wgpu::util::DeviceExt::create_buffer_init(
            &gpu.device,
            &wgpu::util::BufferInitDescriptor {
                label: Some("callisto params"),
                contents: bytemuck::bytes_of(&self.gpu_params(
                    tiles,
                    px as u32,
                    &ctx.scene.data,
                    &cache_layout,
                )),
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            },
        );
        let layout = self.layout(gpu);
        let bind_group = pipelines::buffers_bind_group(
            gpu,
            "callisto",
            &layout,
            &[
                &uniform,
                &lists,
                &rates,
                &stats,
                &current,
                &history,
                &debug,
                &pixel_direct,
                &pixel_specular,
                &cache,
            ],
        );
        let output = self.restir_direct.output_layout(gpu).clone();
        let direct_bind_group =
            pipelines::buffers_bind_group(gpu, "callisto pixel direct", &output, &[&pixel_direct]);
        let specular_layout = self.reflections.output_layout(gpu).clone();
        let specular_bind_group = pipelines::buffers_bind_group(
            gpu,
            "callisto pixel specular",
            &specular_layout,
            &[&pixel_specular],
        );
        self.res = Some(Resources {
            bind_group,
            direct_bind_group,
            specular_bind_group,
            clear_on_reset: vec![lists, rates, stats, history],
            debug,
            tiles,
            uniform,
            cache,
            cache_layout,
        });
    }

    /// Clears the hash grid of the static/dynamic split (every light's cached visibility).
    fn clear_cache(&self, enc: &mut wgpu::CommandEncoder) {
        if let Some(r) = &self.res {
            enc.clear_buffer(&r.cache, r.cache_layout.hash_base as u64 * 4, None);
        }
    }

    /// Whether next frame's rates use the mean scene luminance (the `luminance_mean` pass).
    fn weighting(&self) -> bool {
        self.settings.rate == 0 && self.settings.perceptual > 0.0
    }
}

impl Technique for CallistoShadows {
    fn id(&self) -> &'static str {
        "callisto-shadows"
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn inputs(&self) -> FrameInputs {
        FrameInputs {
            primary_surfaces: true,
        }
    }

    fn passes(&self, f: &SceneFeatures) -> Vec<PassInfo> {
        let s = &self.settings;
        let lights = f.light_count();
        let no_lights = || "no lights in the scene's pool".to_string();
        let mut v = vec![
            PassInfo {
                name: "cull",
                runs: self.tile_shadows(),
                why: if s.direct_restir {
                    "direct = \"restir\": the direct-light part replaces the tile shadows".into()
                } else if lights > 0 {
                    format!(
                        "{lights} lights ({} emissive triangles, {} point, {} spot, {} directional) against 16x16 tiles: {}, depth bounds{}, at most {} per tile",
                        f.emissive_triangle_count,
                        f.point_lights,
                        f.spot_lights,
                        f.directional_lights,
                        if s.range_cutoff > 0.0 {
                            format!("ranges at {} W/m^2", s.range_cutoff)
                        } else {
                            "infinite ranges".into()
                        },
                        if s.cone_culling { ", normal cones" } else { "" },
                        s.max_lights_per_tile
                    )
                } else {
                    no_lights()
                },
            },
            PassInfo {
                name: "shadows",
                runs: self.tile_shadows(),
                why: if s.direct_restir {
                    "direct = \"restir\": the direct-light part replaces the tile shadows".into()
                } else if lights > 0 {
                    format!(
                        "one shadow ray per light per traced pixel, rate {} per 2x2 quad, bilateral reconstruction{}",
                        RATES[s.rate as usize],
                        if s.static_shadow_cache {
                            "; static lights over static receivers: cached static visibility x the moving instances traced"
                        } else {
                            ""
                        }
                    )
                } else {
                    no_lights()
                },
            },
            PassInfo {
                name: "shadow_cache_settle",
                runs: self.tile_shadows() && s.static_shadow_cache,
                why: if s.static_shadow_cache {
                    "per slot of the static-visibility hash grid: owners and filled cells for next frame (so no read depends on the order rays run in)".into()
                } else {
                    "static_shadow_cache off".into()
                },
            },
            PassInfo {
                name: "luminance_mean",
                runs: self.tile_shadows() && self.weighting(),
                why: if self.weighting() {
                    "mean scene luminance for next frame's perceptual weighting".into()
                } else {
                    "rates forced or perceptual = 0: no weighting".into()
                },
            },
            PassInfo {
                name: "resolve",
                runs: true,
                why: format!(
                    "{}, emission{}, accumulation",
                    if s.direct_restir {
                        "the direct-light part's result"
                    } else if s.denoise {
                        "shadow mask accumulated over frames (disocclusion blur)"
                    } else {
                        "shadow mask as traced (denoise = false)"
                    },
                    if s.gi { ", ReSTIR GI sample" } else { "" }
                ),
            },
        ];
        if s.direct_restir {
            let mut direct = self.restir_direct.passes(f);
            direct.push(PassInfo {
                name: "direct",
                runs: lights > 0,
                why: if lights > 0 {
                    RestirDirect::describe()
                } else {
                    no_lights()
                },
            });
            v.splice(0..0, direct);
        }
        v.extend(self.restir.passes(f));
        v.extend(self.reflections.family_passes(s.reflections, f));
        v
    }

    fn build(&mut self, ctx: &RenderContext) -> Result<()> {
        let mine = self.layout(ctx.gpu);
        let (empty, _) = self.empty(ctx.gpu);
        let restir_layout = self.restir.layout(ctx.gpu).clone();
        let make = |entry: &str, group2: &wgpu::BindGroupLayout| {
            pipelines::compute_pipeline(
                ctx.gpu,
                ctx.shaders,
                entry,
                &[&ctx.scene.layout, ctx.frame_layout, group2, &mine],
            )
        };
        let built = Pipelines {
            cull: make(CULL, &empty)?,
            shadows: make(SHADOWS, &empty)?,
            mean: make(MEAN, &empty)?,
            resolve: make(RESOLVE, &restir_layout)?,
            settle: make(SETTLE, &empty)?,
        };
        // And the direct-light part's (on an error its old pipelines stay).
        self.restir_direct
            .prepare(ctx, self.settings.direct_restir, true, ())?;
        // Rebuild ReSTIR GI's pipelines too when it runs (hot reload of its shaders).
        self.ensure_restir(ctx, self.settings.gi)?;
        self.prepare_reflections(ctx, true)?;
        self.pipelines = Some(built);
        self.build_resources(ctx);
        Ok(())
    }

    fn apply_params(&mut self, ctx: &RenderContext) -> Result<()> {
        self.ensure_restir(ctx, false)?;
        self.prepare_reflections(ctx, false)?;
        self.build_resources(ctx);
        Ok(())
    }

    fn reset_history(&mut self, gpu: &Gpu) {
        self.restir.reset(gpu);
        self.restir_direct.reset(gpu);
        self.reflections.reset(gpu);
        let Some(r) = &self.res else {
            return;
        };
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        for b in &r.clear_on_reset {
            enc.clear_buffer(b, 0, None);
        }
        self.clear_cache(&mut enc);
        gpu.submit("callisto-shadows: history reset", enc.finish());
    }

    /// Tile lists, rates and the shadow mask carry over, as they would in a game. (A scene
    /// edit has just rebuilt the resources, so the shadow cache starts empty.)
    fn on_scene_change(&mut self, _gpu: &Gpu) {}

    /// The static/dynamic split: entries and lights that moved become dynamic (clearing the
    /// cache when one does); the dynamic entries' boxes and the uniform follow the new pose.
    fn on_geometry_moved(&mut self, ctx: &RenderContext) -> Result<()> {
        let Some(r) = &self.res else {
            return Ok(());
        };
        let newly_dynamic = self.split.observe(&ctx.scene.data);
        let px = ctx.extent[0] * ctx.extent[1];
        let layout = r.cache_layout;
        let q = &ctx.gpu.queue;
        q.write_buffer(
            &r.cache,
            0,
            bytemuck::cast_slice(&self.split.head(&ctx.scene.data, &layout)),
        );
        let params = self.gpu_params(r.tiles, px, &ctx.scene.data, &layout);
        q.write_buffer(&r.uniform, 0, bytemuck::bytes_of(&params));
        if newly_dynamic {
            let mut enc = ctx.gpu.device.create_command_encoder(&Default::default());
            self.clear_cache(&mut enc);
            ctx.gpu
                .submit("callisto-shadows: shadow cache cleared", enc.finish());
        }
        Ok(())
    }

    fn render(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
    ) {
        let (Some(p), Some(r), Some((_, empty)), Some(restir_bg)) = (
            &self.pipelines,
            &self.res,
            &self.empty,
            self.restir.bind_group().cloned(),
        ) else {
            return;
        };
        self.restir.record(ctx, enc, timer);
        let tiles = [r.tiles[0], r.tiles[1], 1];
        let groups = &[empty, &r.bind_group];
        if self.settings.direct_restir && self.lights > 0 {
            self.restir_direct
                .record(ctx, enc, timer, &r.direct_bind_group);
        }
        if self.tile_shadows() {
            pipelines::technique_pass(ctx, enc, timer, "cull", &p.cull, groups, tiles);
            pipelines::technique_pass(ctx, enc, timer, "shadows", &p.shadows, groups, tiles);
            if self.settings.static_shadow_cache {
                let slots = r.cache_layout.slots.div_ceil(256);
                pipelines::technique_pass(
                    ctx,
                    enc,
                    timer,
                    "shadow_cache_settle",
                    &p.settle,
                    groups,
                    [slots, 1, 1],
                );
            }
            if self.weighting() {
                pipelines::technique_pass(
                    ctx,
                    enc,
                    timer,
                    "luminance_mean",
                    &p.mean,
                    groups,
                    [1, 1, 1],
                );
            }
        }
        if self.reflections_active() {
            let cache = self.restir.surface_cache().map(|(bg, _)| bg);
            self.reflections
                .record(ctx, enc, timer, cache, (&r.specular_bind_group, 0), true);
            self.reflections.copy_debug(enc, ctx.extent, &r.debug, 2);
        }
        let image = [ctx.extent[0].div_ceil(8), ctx.extent[1].div_ceil(8), 1];
        pipelines::technique_pass(
            ctx,
            enc,
            timer,
            "resolve",
            &p.resolve,
            &[&restir_bg, &r.bind_group],
            image,
        );
    }

    fn debug_views(&self) -> Vec<DebugView> {
        let view = |name, channel| DebugView {
            name,
            channel,
            is_id: false,
        };
        let mut v = vec![
            view("rate per quad (1 quarter, 2 half, 3 full)", 0),
            view("shadow rays per pixel", 1),
            view("lights per tile", 2),
            view("shadow-mask frames since disocclusion", 3),
            view("lights left out of the tile's full list", 4),
        ];
        v.extend(crate::parts::reflections::debug_views(2));
        v
    }

    fn debug_buffer(&self) -> Option<&wgpu::Buffer> {
        self.res.as_ref().map(|r| &r.debug)
    }

    fn param_set(&self) -> &Params {
        &self.params
    }

    fn set_params(&mut self, changes: &ParamChanges) -> Result<()> {
        self.params.apply(changes)?;
        self.settings = CallistoSettings::from_params(&self.params);
        // The pass list reads ReSTIR's settings before `apply_params` runs.
        self.restir.configure(
            self.settings.gi,
            self.settings.gi_terminate,
            self.settings.cache_light,
        );
        Ok(())
    }

    /// Variable rate settles after the first (full-rate) frame.
    fn calibration_frames(&self) -> u32 {
        4
    }

    /// The knob is the lights' range: lights per tile (so shadow rays) scale about inversely
    /// with `range_cutoff` for lights spread over a plane (count within range ~ range^2 ~
    /// 1 / cutoff). The camera ray, the tail samples and the GI path (when on) are fixed costs.
    fn params_for_ray_budget(
        &self,
        rays_per_pixel: f64,
        measured: Option<f64>,
    ) -> Option<ParamChanges> {
        let measured = measured?;
        // Camera ray, tail samples (at most one ray each), GI path (when on): not range-bound.
        let fixed =
            1.0 + self.settings.tail_samples as f64 + if self.settings.gi { 5.0 } else { 0.0 };
        let shadow_now = (measured - fixed).max(0.05);
        let shadow_want = (rays_per_pixel - fixed).max(0.05);
        let cutoff = if self.settings.range_cutoff > 0.0 {
            self.settings.range_cutoff as f64
        } else {
            0.01
        };
        let next = (cutoff * shadow_now / shadow_want).clamp(1e-6, 1e6);
        ((next / self.settings.range_cutoff as f64 - 1.0).abs() > 0.01)
            .then(|| ParamChanges::new().float("range_cutoff", next))
    }
}
