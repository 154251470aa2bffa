//! A Lumen frame's helpers: rays per pixel, the parts it holds (reflections, direct light), the
//! distance field's update passes, and the pass lists (world cache, screen probes).

use super::*;

impl Lumen {
    /// Rays per pixel per frame besides the gather: the shared camera ray and the direct
    /// light's (NEE's shadow ray, or ReSTIR DI's with the part).
    pub(super) fn fixed_rays_per_pixel(&self) -> f64 {
        let reflections = if self.reflections_active() {
            self.reflections.rays_per_pixel()
        } else {
            0.0
        };
        1.0 + reflections
            + if self.features.light_count() == 0 {
                0.0
            } else if self.direct_restir() {
                self.restir_direct.rays_per_pixel()
            } else {
                1.0
            }
    }

    /// The reflections part runs: `reflections = "traced"` on a scene with a specular layer
    /// (metal, or a dielectric specular factor above 0), glossy or not: rough lobes need the
    /// albedo plane even where no ray is traced.
    pub(super) fn reflections_active(&self) -> bool {
        self.settings.reflections && self.features.min_specular_roughness.is_some()
    }

    /// Builds the reflections part when it is needed and not built (its trace pass reads this
    /// cache: Lumen's group 2 at the part's cache group), and passes it the settings.
    pub(super) fn prepare_reflections(&mut self, ctx: &RenderContext, rebuild: bool) -> Result<()> {
        self.reflections.settings = self.settings.reflection.clone();
        let needed =
            self.settings.reflections && ctx.scene.data.features.min_specular_roughness.is_some();
        // The cache's lookup bindings alone: with all of Lumen's group the trace pass would bind
        // more storage buffers than a stage may.
        let layout = crate::parts::SurfaceCache::lookup_layout(ctx.gpu, false);
        self.reflections
            .prepare(ctx, needed, rebuild, Some(HitCache::SurfaceCache(&layout)))
    }

    /// Lookups the world ReGIR clipmap served, for tests and reports.
    pub fn cache_regir_coverage(&self, gpu: &Gpu) -> Result<crate::parts::world_regir::Coverage> {
        self.cache.cache_regir_coverage(gpu)
    }

    /// SDF hits fall back on the voxel lighting (`voxel_lighting`, `tracing = "sdf"`).
    pub(super) fn voxel_lighting_active(&self) -> bool {
        self.settings.voxel_lighting && !self.settings.bvh
    }

    /// Whether anything reads the distance field this frame: SDF tracing, or the debug views
    /// (slice, steps, hit error). With BVH tracing and no debug views nothing does, and the field
    /// is left to be built whole when something reads it again: in a playing scene its refill
    /// of moved bricks cost 7.5 ms a 1080p frame on an H200 (docs/performance.md).
    pub(super) fn distance_field_read(&self) -> bool {
        !self.settings.bvh || self.settings.debug_views
    }

    /// Pixels take their direct light from the ReSTIR DI part (`direct = "restir"`, lights).
    pub(super) fn direct_restir(&self) -> bool {
        self.settings.direct_restir && self.features.light_count() > 0
    }

    /// Records the distance-field update of this frame's plan, if anything changed.
    pub(super) fn record_sdf(
        &self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
        plan: &sdf::SdfPlan,
    ) {
        let (Some(p), Some(r)) = (&self.pipelines, &self.res) else {
            return;
        };
        let params = &r.gpu_params;
        let nb = params.bricks_per_axis;
        let slots = plan.built * nb * nb * nb;
        // Per-update counters (fill counts, pops, failures) start at zero; the free count stays.
        enc.clear_buffer(r.buffer(9), 4, Some(60));
        let bg = &r.bind_group;
        let groups = [slots.div_ceil(64), 1, 1];
        pipelines::technique_pass(
            ctx,
            enc,
            timer,
            Pass::SdfRelease.name(),
            p.get(Pass::SdfRelease),
            &[bg],
            groups,
        );
        pipelines::technique_pass(
            ctx,
            enc,
            timer,
            Pass::SdfAllocate.name(),
            p.get(Pass::SdfAllocate),
            &[bg],
            groups,
        );
        pipelines::technique_pass(
            ctx,
            enc,
            timer,
            "sdf args",
            &p.sdf_args,
            &[bg, &r.args_bind_group],
            [1, 1, 1],
        );
        for (l, name) in FILL_PASS_NAMES.iter().enumerate().take(plan.built as usize) {
            if plan.levels[l].update[0] == 0 {
                continue;
            }
            pipelines::list_pass(
                enc,
                timer,
                name,
                &p.sdf_fill,
                &[
                    &ctx.scene.bind_group,
                    ctx.frame_bind_group,
                    bg,
                    &r.fill_bind_groups[l],
                ],
                &r.args,
                12 * l as u64,
            );
            // Every mode: a later switch to SDF tracing or voxel lighting finds it built.
            pipelines::list_pass(
                enc,
                timer,
                "voxel visibility",
                &p.voxel_visibility,
                &[
                    &ctx.scene.bind_group,
                    ctx.frame_bind_group,
                    bg,
                    &r.fill_bind_groups[l],
                ],
                &r.args,
                12 * l as u64,
            );
        }
        let cells = plan.built * (params.resolution / 4).pow(3);
        pipelines::technique_pass(
            ctx,
            enc,
            timer,
            Pass::SdfCoarse.name(),
            p.get(Pass::SdfCoarse),
            &[bg],
            [cells.div_ceil(64), 1, 1],
        );
        // Readers take the texels from here on (the update's passes above read the buffers).
        r.copy_sdf_texels(enc);
    }
}

impl Lumen {
    /// The world radiance cache's passes (they run with `world_cache` when `reader` reads it).
    pub(super) fn world_passes(&self, reader: &str) -> Vec<PassInfo> {
        let s = &self.settings;
        let tracing = if s.bvh { "BVH" } else { "SDF" };
        WorldCache::pass_info(&s.world_cache_settings(), s.world_cache, tracing, reader)
    }

    /// What the screen-probe final gather runs this frame, and why (the UI's pass list).
    pub(super) fn probe_passes(&self, f: &SceneFeatures) -> Vec<PassInfo> {
        let s = &self.settings;
        let pass = |name, runs, why: String| PassInfo { name, runs, why };
        let tracing = if s.bvh { "BVH" } else { "SDF" };
        let mut v = self.world_passes("screen probes");
        v.extend([
            pass(
                "hzb",
                s.screen_traces,
                if s.screen_traces { "closest-depth mips of last frame for the screen traces".into() } else { "screen_traces = false".into() },
            ),
            pass(
                "probe place",
                true,
                format!("one probe per {0}x{0} tile on the G-buffer, jittered each frame", s.probe_spacing),
            ),
            pass(
                "probe adaptive",
                s.adaptive_probes,
                if s.adaptive_probes {
                    "extra probes where the uniform ones fail to interpolate (depth and normal edges)".into()
                } else {
                    "adaptive_probes = false".into()
                },
            ),
            pass(
                "probe sample",
                true,
                if s.product_sampling && s.ray_reassignment {
                    "64 rays per probe: one per cell, dim cells (BRDF x last frame's radiance) culled by roulette, their rays supersample the brightest 2x2".into()
                } else if s.product_sampling {
                    "64 directions per probe from BRDF x last frame's radiance (world cache where reprojection fails)".into()
                } else {
                    "64 stratified uniform directions per probe".into()
                },
            ),
            pass(
                "screen trace",
                s.screen_traces,
                if s.screen_traces {
                    format!("hierarchical-Z walk in last frame's image, at most {} steps; misses go to the world trace", s.screen_trace_steps)
                } else {
                    "screen_traces = false: every probe ray is traced in the world".into()
                },
            ),
            pass(
                "world trace",
                true,
                if s.world_cache {
                    format!("{tracing} rays to {} scene units (at least a world probe diagonal), then the world cache (or on to the end where it is empty)", s.world_cache_distance)
                } else {
                    format!("{tracing} rays to the first hit, lit from the surface cache")
                },
            ),
            pass("probe resolve", true, if s.temporal_filter { "per-cell radiance and hit distance, blended with the probe's last frames".into() } else { "per-cell radiance and hit distance (temporal_filter = false)".into() }),
            pass(
                "probe filter",
                s.spatial_filter,
                if s.spatial_filter { "3x3 neighbouring probes, plane and 10-degree angle-error weights".into() } else { "spatial_filter = false".into() },
            ),
            pass(
                "integrate",
                true,
                format!(
                    "per pixel: irradiance from the probes of its plane{}{}",
                    if s.temporal_filter { ", full-resolution temporal filter" } else { "" },
                    if s.contact_ao { ", contact AO" } else { "" }
                ),
            ),
        ]);
        if !f.has_glossy && !f.has_mirror {
            return v;
        }
        v.push(pass(
            "probe reflections",
            false,
            "not built (issue 16 item 6): glossy surfaces get direct specular only".into(),
        ));
        v
    }
}
