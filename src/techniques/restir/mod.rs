//! # ReSTIR DI (`restir`)
//!
//! Direct lighting by reservoir-based spatiotemporal importance resampling, as in "Making
//! Connections" (GDC; shared/seeds/003) and Bitterli et al. 2020. Per pixel and frame:
//!
//! 1. `primary` (the engine's shared pass, `render::primary`): a jittered camera ray per pixel
//!    (the reference's jitter sequence) stores the surface; ReSTIR reads this frame's and last
//!    frame's through `gilab::primary`.
//! 2. `initial_temporal`: initial candidates per light class, as in the talk, each class
//!    resampled by the unshadowed target f · Le · G into its own reservoir:
//!    - local lights (emissive triangles, point and spot lights): `candidates` drawn by power
//!      within the class, or from the pixel's ReGIR cell;
//!    - directional lights: `directional_candidates` drawn by power within the class;
//!    - the sky: `sky_candidates` directions from an equal mix of BSDF and cosine sampling
//!      (0 by default: the GI sample ray then estimates direct sky light, which measured better).
//!
//!    A class the scene lacks gets no candidates (rule 3). The class reservoirs are merged
//!    before visibility (disjoint domains: each class is its own RIS estimator); in biased mode
//!    each class's pick can be visibility-tested first (the talk's fix for a strong, shadowed
//!    sun), or only the merged pick. Then last frame's reservoir at the reprojected pixel is
//!    merged if the surfaces are similar, its M clamped to `max_history` × the current M.
//!    `light_classes = false` gives the single power-proportional pool over every light, with
//!    the sky left to GI rays, for A/B comparisons.
//! 3. `spatial`: `spatial_count` neighbours within `spatial_radius` pixels are merged.
//!    Unbiased mode weights by 1/Z (only reservoirs that could have produced the sample count,
//!    with a visibility ray each when candidate visibility is on); biased mode weights by M and
//!    drops occluded samples from reuse. The bidirectional occlusion test only reuses a
//!    neighbour's light that is visible from this pixel.
//! 4. `shade`: one visibility ray for the final sample; emission + f · Le · G · V · W is
//!    accumulated over frames (Welford), like the reference, so a static view converges.
//!
//! Samples live in the light's own measure (area for triangles, solid angle for sky directions),
//! so reuse across pixels needs no Jacobian. With a sky class, GI sample rays that escape add
//! nothing: direct sky light is ReSTIR DI's.
//! The lighting core (DI, GI, ReGIR, their parameters, buffers and bind group) is the part
//! [`crate::parts::restir`] (shaders/parts/restir/), which other families hold too; this
//! technique is that core plus its shading pass (shaders/restir/shade.wgsl).

pub use crate::parts::restir::{
    CandidateVisibility, GiTerminate, RestirLighting, RestirParamsGpu, RestirSettings,
    GI_RESERVOIR_BYTES, MAX_SPATIAL, PARAMS, REGIR_DIMS, REGIR_SLOT_BYTES, RESERVOIR_BYTES,
};

use crate::gpu::{timing::PassTimer, Gpu};
use crate::render::params::{ParamChanges, Params};
use crate::render::primary::FrameInputs;
use crate::render::{pipelines, DebugView, PassInfo, RenderContext, Technique};
use crate::scene::features::SceneFeatures;
use anyhow::Result;

/// The `restir` technique: [`RestirLighting`] (DI, GI, ReGIR) and a shading pass that turns its
/// reservoirs into the pixel's radiance.
pub struct Restir {
    params: Params,
    pub lighting: RestirLighting,
    shade: Option<wgpu::ComputePipeline>,
}

impl Default for Restir {
    fn default() -> Self {
        let params = Params::new("restir", PARAMS);
        Restir {
            lighting: RestirLighting::new(RestirSettings::from_params(&params)),
            params,
            shade: None,
        }
    }
}

impl Restir {
    pub fn settings(&self) -> &RestirSettings {
        &self.lighting.settings
    }

    pub fn regir_active(&self) -> bool {
        self.lighting.regir_active()
    }

    pub fn direct_rays_per_pixel(&self) -> f64 {
        self.lighting.direct_rays_per_pixel()
    }
}

impl Technique for Restir {
    fn id(&self) -> &'static str {
        "restir"
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
        let l = &self.lighting;
        let mut v: Vec<PassInfo> = l.di_passes(f).into_iter().chain(l.gi_passes(f)).collect();
        v.push(PassInfo {
            name: "shade",
            runs: true,
            why: "final visibility (DI and GI), emission and accumulation".into(),
        });
        v.extend(l.regir_passes(f));
        v
    }

    fn build(&mut self, ctx: &RenderContext) -> Result<()> {
        // The shading pass first: if it fails, nothing is replaced.
        let layout = self.lighting.layout(ctx.gpu).clone();
        let shade = ctx.pipeline("restir/shade.wgsl", &layout)?;
        self.lighting.build(ctx)?;
        self.shade = Some(shade);
        Ok(())
    }

    /// Buffers and uniforms; the surface cache and its GI pipeline the first time
    /// `gi_terminate` names the cache (built on demand, never a black pane).
    fn apply_params(&mut self, ctx: &RenderContext) -> Result<()> {
        self.lighting.build_gi_cache(ctx)?;
        self.lighting.build_resources(ctx);
        Ok(())
    }

    fn reset_history(&mut self, gpu: &Gpu) {
        self.lighting.reset(gpu);
    }

    /// The reservoirs carry over, as they would in a game (the engine restarts the average).
    fn on_scene_change(&mut self, _gpu: &Gpu) {}

    fn render(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
    ) {
        let (Some(shade), Some(bg)) = (self.shade.clone(), self.lighting.bind_group().cloned())
        else {
            return;
        };
        self.lighting.record(ctx, enc, timer);
        pipelines::image_pass(ctx, enc, timer, "shade", &shade, &bg);
    }

    fn debug_views(&self) -> Vec<DebugView> {
        let view = |name, channel, is_id| DebugView {
            name,
            channel,
            is_id,
        };
        vec![
            view("reservoir M", 0, false),
            view("reservoir weight W", 1, false),
            view("selected light", 2, true),
            view("ReGIR cell", 3, true),
        ]
    }

    fn debug_buffer(&self) -> Option<&wgpu::Buffer> {
        self.lighting.debug_buffer()
    }

    fn param_set(&self) -> &Params {
        &self.params
    }

    fn set_params(&mut self, changes: &ParamChanges) -> Result<()> {
        let before = self.params.clone();
        self.params.apply(changes)?;
        let settings = RestirSettings::from_params(&self.params);
        if let Err(e) = settings.check() {
            self.params = before;
            return Err(e);
        }
        self.lighting.settings = settings;
        Ok(())
    }

    fn params_for_ray_budget(
        &self,
        rays_per_pixel: f64,
        measured: Option<f64>,
    ) -> Option<ParamChanges> {
        // What costs rays: GI sample paths (their length is scene-dependent, so measured when
        // possible), the bidirectional test per neighbour; the rest is fixed. The budget first
        // decides whether GI fits, then spends what is left on bidirectional neighbours (when
        // on) and scales the candidate count, which costs shading but no rays.
        let direct = self.lighting.direct_rays_per_pixel();
        let gi_cost = measured
            .filter(|_| self.lighting.settings.gi)
            .map(|m| (m - direct).max(1.0))
            .unwrap_or(5.0);
        let mut next = self.lighting.settings.clone();
        next.gi = rays_per_pixel >= direct + gi_cost;
        let base = direct
            - if next.bidirectional {
                next.spatial_count as f64
            } else {
                0.0
            };
        let left = (rays_per_pixel - base - if next.gi { gi_cost } else { 0.0 }).max(0.0);
        if next.bidirectional {
            next.spatial_count = (left.floor() as u32).min(MAX_SPATIAL);
        }
        next.candidates = ((4.0 + 4.0 * left).round() as u32).clamp(1, 64);
        (next != self.lighting.settings).then(|| {
            ParamChanges::new()
                .bool("gi", next.gi)
                .int("spatial_count", next.spatial_count as i64)
                .int("candidates", next.candidates as i64)
        })
    }
}
