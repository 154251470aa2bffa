//! Direct light as a part: ReSTIR DI at the primary surfaces, for families whose own direct
//! light is one NEE sample (`direct = "restir"` in `surfels` and `lumen`).
//!
//! It runs the `restir` technique's DI passes (`initial_temporal`, `spatial`, and `regir_build`
//! on many-light scenes) with ReSTIR's default parameters and GI off, once per frame, then the
//! timed `direct` pass (`shaders/parts/restir_direct.wgsl`): each pixel's reservoir shaded with
//! one visibility ray into a `vec4` per pixel that the family's own pass reads (no emission).
//! The DI random streams depend only on pixel, frame and seed, and the primary surfaces are the
//! engine's, so the image equals the `restir` technique's direct light with GI off (tested).

use crate::gpu::{timing::PassTimer, Gpu};
use crate::parts::restir::{self, RestirLighting, RestirSettings};
use crate::render::params::Params;
use crate::render::{pipelines, PassInfo, RenderContext};
use crate::scene::features::SceneFeatures;
use anyhow::Result;

/// The shading pass's entry file.
pub const SHADE: &str = "parts/restir_direct.wgsl";

/// Every entry file the part compiles (its shading and ReSTIR's DI and ReGIR passes): a family
/// that uses the part lists them in its `shader_files`, so editing one rebuilds it.
pub const SHADER_FILES: [&str; 5] = [
    SHADE,
    "parts/restir/regir_mark.wgsl",
    "parts/restir/regir_build.wgsl",
    "parts/restir/initial_temporal.wgsl",
    "parts/restir/spatial.wgsl",
];

pub struct RestirDirect {
    lighting: RestirLighting,
    shade: Option<wgpu::ComputePipeline>,
    /// Group 3 of the shading pass: the per-pixel output (one storage buffer, 16 bytes a pixel).
    output_layout: Option<wgpu::BindGroupLayout>,
}

impl Default for RestirDirect {
    fn default() -> Self {
        RestirDirect {
            lighting: RestirLighting::new(Self::settings()),
            shade: None,
            output_layout: None,
        }
    }
}

impl RestirDirect {
    /// ReSTIR's defaults with GI off: the part supplies direct light only (the sky, when the
    /// scene has one, stays with the family's own rays, as `sky_candidates` defaults to 0).
    pub fn settings() -> RestirSettings {
        let mut s = RestirSettings::from_params(&Params::new("restir", restir::PARAMS));
        s.gi = false;
        s.sky_candidates = 0;
        s
    }

    /// The layout of the output bind group the family makes over its own buffer
    /// (`pixels × 16` bytes, read as `array<vec4<f32>>`).
    pub fn output_layout(&mut self, gpu: &Gpu) -> &wgpu::BindGroupLayout {
        self.output_layout.get_or_insert_with(|| {
            pipelines::layout(
                gpu,
                "direct light output",
                &[pipelines::storage_entry(0, false)],
            )
        })
    }

    pub fn is_built(&self) -> bool {
        self.shade.is_some()
    }

    /// Builds the shading pass and ReSTIR's pipelines (on an error nothing is replaced), then
    /// the resources.
    pub fn build(&mut self, ctx: &RenderContext) -> Result<()> {
        let output = self.output_layout(ctx.gpu).clone();
        let restir_layout = self.lighting.layout(ctx.gpu).clone();
        let shade = pipelines::compute_pipeline(
            ctx.gpu,
            ctx.shaders,
            SHADE,
            &[&ctx.scene.layout, ctx.frame_layout, &restir_layout, &output],
        )?;
        self.lighting.build(ctx)?;
        self.shade = Some(shade);
        Ok(())
    }

    /// Buffers sized by the image and the scene's lights (never a pipeline).
    pub fn build_resources(&mut self, ctx: &RenderContext) {
        self.lighting.settings = Self::settings();
        self.lighting.build_resources(ctx);
    }

    /// This frame's ReSTIR DI passes, then the `direct` pass into `output` (a bind group of
    /// [`Self::output_layout`]).
    pub fn record(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
        output: &wgpu::BindGroup,
    ) {
        let (Some(shade), Some(restir_bg)) =
            (self.shade.clone(), self.lighting.bind_group().cloned())
        else {
            return;
        };
        self.lighting.record(ctx, enc, timer);
        pipelines::technique_pass(
            ctx,
            enc,
            timer,
            "direct",
            &shade,
            &[&restir_bg, output],
            [ctx.extent[0].div_ceil(8), ctx.extent[1].div_ceil(8), 1],
        );
    }

    /// Forgets the reservoirs (camera cut, parameter change).
    pub fn reset(&self, gpu: &Gpu) {
        if self.is_built() {
            self.lighting.reset(gpu);
        }
    }

    /// ReSTIR's DI and ReGIR passes as the family's pass list shows them (before its `direct`).
    pub fn passes(&self, f: &SceneFeatures) -> Vec<PassInfo> {
        let mut v: Vec<PassInfo> = self.lighting.di_passes(f).into();
        v.extend(self.lighting.regir_passes(f));
        v
    }

    /// What the `direct` pass entry says it does.
    pub fn describe() -> String {
        "ReSTIR DI (the restir technique's passes, GI off): the pixel's reservoir, one visibility ray".into()
    }

    /// Rays per pixel per frame of ReSTIR DI, the final visibility ray included.
    pub fn rays_per_pixel(&self) -> f64 {
        // direct_rays_per_pixel counts the camera ray too, which the family counts itself.
        self.lighting.direct_rays_per_pixel() - 1.0
    }
}
