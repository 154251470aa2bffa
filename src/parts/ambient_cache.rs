//! The ambient cache (`gi_terminate = "ambient"`): the simplest cache a GI path can end in, and
//! the worked example of adding one (docs/parts.md). It holds one irradiance for every point,
//! `E0 = π × the sky's mean radiance`: the classic ambient term, the light an unoccluded point
//! would get from the scene's sky, with no bounce and no occlusion: zero where the sky is black,
//! and inside a closed room under a sky it lights the room as an ambient term does (a leak, by
//! design: it is the baseline, not a method to trust). A
//! path that ends in it takes next-event estimation of the lights at its last hit plus
//! `albedo × E0 / π`. As a baseline it says what the bounces the other caches carry are worth.
//! Its end of a path: `shaders/parts/ambient_cache/path_end.wgsl`.

use crate::gpu::{timing::PassTimer, Gpu};
use crate::parts::gi_cache::{CacheKey, CacheKind, GiCache};
use crate::parts::world_regir::{Coverage, WorldRegirSettings};
use crate::render::{pipelines, PassInfo, RenderContext};
use crate::scene::features::SceneFeatures;
use anyhow::Result;

/// `gi_terminate = "ambient"`.
pub const KIND: CacheKind = CacheKind {
    name: "ambient",
    key: |s| key(s.light),
    new: |s| {
        Ok(Box::new(AmbientCache {
            light: s.light,
            built: None,
        }))
    },
    describe: |_, hit| {
        format!("in a constant ambient irradiance at hit {hit} (pi x the sky's mean radiance, unoccluded), with NEE of the lights there")
    },
};

fn key(light: WorldRegirSettings) -> CacheKey {
    CacheKey {
        name: "ambient",
        size: 0,
        budget: 0,
        light,
    }
}

/// The shader def that names the bind group of its lookup (its one uniform) in a reader.
const GROUP_DEF: &str = "AMBIENT_CACHE_GROUP";

pub struct AmbientCache {
    /// The holder's light picking: part of the key (the holder rebuilds on a change), unused.
    light: WorldRegirSettings,
    /// The uniform holding `E0` (rgb) and its bind group.
    built: Option<(wgpu::Buffer, wgpu::BindGroup)>,
}

fn lookup_layout(gpu: &Gpu) -> wgpu::BindGroupLayout {
    pipelines::layout(
        gpu,
        "ambient cache",
        &[pipelines::uniform_entry(0, wgpu::ShaderStages::COMPUTE)],
    )
}

impl GiCache for AmbientCache {
    fn key(&self) -> CacheKey {
        key(self.light)
    }

    fn build(&mut self, ctx: &RenderContext) -> Result<()> {
        let buffer = pipelines::init_buffer(
            ctx.gpu,
            "ambient cache",
            &[0u8; 16],
            wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        );
        let group = pipelines::buffers_bind_group(
            ctx.gpu,
            "ambient cache",
            &lookup_layout(ctx.gpu),
            &[&buffer],
        );
        self.built = Some((buffer, group));
        Ok(())
    }

    /// Writes `E0` from the scene's sky (an edited sky is read the next frame); no pass.
    fn record(&mut self, ctx: &RenderContext, _: &mut wgpu::CommandEncoder, _: &mut PassTimer) {
        if let Some((buffer, _)) = &self.built {
            let e0 = ctx.scene.sky * std::f32::consts::PI;
            let words = [e0.x, e0.y, e0.z, 0.0];
            ctx.gpu
                .queue
                .write_buffer(buffer, 0, bytemuck::cast_slice(&words));
        }
    }

    fn lookup(&self) -> Option<&wgpu::BindGroup> {
        self.built.as_ref().map(|(_, group)| group)
    }

    fn passes(&self, _: &SceneFeatures) -> Vec<PassInfo> {
        Vec::new()
    }

    fn reader(&self, gpu: &Gpu, group: u32) -> (Vec<(&'static str, u32)>, wgpu::BindGroupLayout) {
        (vec![(GROUP_DEF, group)], lookup_layout(gpu))
    }

    fn path_end(&self) -> &'static str {
        "gilab::ambient_cache_path_end"
    }

    fn cache_regir_coverage(&self, _: &Gpu) -> Result<Coverage> {
        anyhow::bail!("the ambient cache picks no lights through world ReGIR")
    }
}
