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
use crate::parts::Part;
use crate::render::params::{ParamKind, ParamSpec, Params};
use crate::render::{pipelines, PassInfo, RenderContext};
use crate::scene::features::SceneFeatures;
use anyhow::Result;

/// The shading pass's entry file.
pub const SHADE: &str = "parts/restir_direct.wgsl";

/// The parameter that picks this part in a family.
pub const PARAM: &str = "direct";

/// The `direct` parameter of a family that can use the part: `choices` is the family's own
/// direct light, then `"restir"` (this part), the own one the default. The part owns the name
/// and the reading (`chosen`); the family says what its own choice is.
pub const fn param(
    choices: &'static [&'static str],
    what: &'static str,
    higher: &'static str,
    lower: &'static str,
) -> ParamSpec {
    assert!(
        choices.len() == 2 && str_eq(choices[1], "restir"),
        "direct's choices: the family's own, then \"restir\""
    );
    ParamSpec {
        name: PARAM,
        what,
        higher,
        lower,
        kind: ParamKind::Choice(choices),
        default: 0.0,
    }
}

/// Whether a family's parameters pick the part (`direct = "restir"`).
pub fn chosen(p: &Params) -> bool {
    p.u32(PARAM) == 1
}

const fn str_eq(a: &str, b: &str) -> bool {
    let (a, b) = (a.as_bytes(), b.as_bytes());
    if a.len() != b.len() {
        return false;
    }
    let mut i = 0;
    while i < a.len() {
        if a[i] != b[i] {
            return false;
        }
        i += 1;
    }
    true
}

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
}

impl Part for RestirDirect {
    type Input<'a> = ();

    fn is_built(&self) -> bool {
        self.shade.is_some()
    }

    /// Builds the shading pass and ReSTIR's pipelines (on an error nothing is replaced).
    fn build(&mut self, ctx: &RenderContext, _: ()) -> Result<()> {
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
    fn build_resources(&mut self, ctx: &RenderContext) {
        self.lighting.settings = RestirDirect::settings();
        self.lighting.build_resources(ctx);
    }

    /// Forgets the reservoirs (camera cut, parameter change).
    fn reset(&self, gpu: &Gpu) {
        if self.is_built() {
            self.lighting.reset(gpu);
        }
    }
}

impl RestirDirect {
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
