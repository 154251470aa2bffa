//! ReSTIR lighting as a reusable piece: the DI, GI and ReGIR parts with their shared parameter
//! uniform, buffers and bind group (`gilab::restir`, bind group 2). The `restir` technique is this
//! plus a shading pass; another technique can hold a `RestirLighting` for its direct (or
//! indirect) light: `build` it, `record` it each frame, then shade from its reservoirs in a pass
//! whose layouts are [scene, frame, `layout()`, its own] (bind group 3 for its own resources).

use super::di::{Di, LightClasses};
use super::gi::{gi_defs, Gi};
use super::regir::{Regir, REGIR_DIMS};
use super::{RestirParamsGpu, RestirSettings};
use crate::gpu::{timing::PassTimer, Gpu};
use crate::render::{pipelines, RenderContext};
use anyhow::Result;

/// A part's two image passes over the pixels (temporal reuse, then spatial reuse), recorded in
/// that order with the lighting's bind group.
#[derive(Default)]
pub(super) struct PassPair {
    passes: Option<[(&'static str, wgpu::ComputePipeline); 2]>,
}

/// Names and entry files of a pair's passes.
pub(super) type PassFiles = [(&'static str, &'static str); 2];

impl PassPair {
    /// Builds both pipelines; nothing is replaced until `set`.
    pub(super) fn build(
        ctx: &RenderContext,
        layout: &wgpu::BindGroupLayout,
        files: PassFiles,
        defs: &[(&str, u32)],
    ) -> Result<[(&'static str, wgpu::ComputePipeline); 2]> {
        let [(a, fa), (b, fb)] = files;
        let shaders = ctx.shaders.with_defs(defs);
        let pipeline = |f| {
            pipelines::compute_pipeline(
                ctx.gpu,
                &shaders,
                f,
                &[&ctx.scene.layout, ctx.frame_layout, layout],
            )
        };
        Ok([(a, pipeline(fa)?), (b, pipeline(fb)?)])
    }

    pub(super) fn set(&mut self, built: [(&'static str, wgpu::ComputePipeline); 2]) {
        self.passes = Some(built);
    }

    pub(super) fn is_built(&self) -> bool {
        self.passes.is_some()
    }

    pub(super) fn record(
        &self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
        bind_group: &wgpu::BindGroup,
    ) {
        for (name, pipeline) in self.passes.iter().flatten() {
            pipelines::image_pass(ctx, enc, timer, name, pipeline, bind_group);
        }
    }

    /// The second pass alone (after a first pass recorded elsewhere with other bind groups).
    pub(super) fn record_second(
        &self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
        bind_group: &wgpu::BindGroup,
    ) {
        if let Some([_, (name, pipeline)]) = &self.passes {
            pipelines::image_pass(ctx, enc, timer, name, pipeline, bind_group);
        }
    }
}

pub struct RestirLighting {
    pub settings: RestirSettings,
    pub(super) di: Di,
    pub(super) gi: Gi,
    pub(super) regir: Regir,
    /// Created once, so pipelines built against it stay valid across rebuilds.
    layout: Option<wgpu::BindGroupLayout>,
    bind_group: Option<wgpu::BindGroup>,
    params_buffer: Option<wgpu::Buffer>,
    /// Per pixel, for the debug views: DI reservoir M, W, selected light + 1, ReGIR cell + 1.
    debug: Option<wgpu::Buffer>,
    extent: [u32; 2],
    pub(super) classes: LightClasses,
    pub(super) many_lights: bool,
}

impl RestirLighting {
    pub fn new(settings: RestirSettings) -> Self {
        RestirLighting {
            settings,
            di: Di::default(),
            gi: Gi::default(),
            regir: Regir::default(),
            layout: None,
            bind_group: None,
            params_buffer: None,
            debug: None,
            extent: [0, 0],
            classes: LightClasses::default(),
            many_lights: false,
        }
    }

    /// Bind group 2 of every ReSTIR pass (`gilab::restir`).
    pub fn layout(&mut self, gpu: &Gpu) -> &wgpu::BindGroupLayout {
        self.layout.get_or_insert_with(|| {
            let mut entries = vec![pipelines::uniform_entry(0, wgpu::ShaderStages::COMPUTE)];
            for b in 1..=6 {
                entries.push(pipelines::storage_entry(b, false));
            }
            pipelines::layout(gpu, "restir", &entries)
        })
    }

    pub fn bind_group(&self) -> Option<&wgpu::BindGroup> {
        self.bind_group.as_ref()
    }

    pub fn debug_buffer(&self) -> Option<&wgpu::Buffer> {
        self.debug.as_ref()
    }

    /// Builds every part's pipelines (all before any is replaced: a failure keeps the old ones),
    /// then the resources.
    pub fn build(&mut self, ctx: &RenderContext) -> Result<()> {
        let layout = self.layout(ctx.gpu).clone();
        let regir = Regir::pipelines(ctx, &layout)?;
        let di = PassPair::build(ctx, &layout, super::di::PASSES, &[])?;
        let gi_tree = self.settings.light_tree;
        let gi = PassPair::build(ctx, &layout, super::gi::PASSES, gi_defs(gi_tree))?;
        self.regir.set_pipelines(regir);
        self.di.passes.set(di);
        self.gi.passes.set(gi);
        self.gi.light_tree = gi_tree;
        // The cache a GI path may end in is rebuilt with the rest (hot reload), or built now.
        if self.gi.cache.is_some() {
            self.rebuild_gi_cache(ctx)?;
        } else {
            self.build_gi_cache(ctx)?;
        }
        self.build_resources(ctx);
        Ok(())
    }

    /// Buffers, the parameter uniform and the bind group: on build and on a parameter change
    /// (buffers whose size did not change are kept); never a pipeline.
    pub fn build_resources(&mut self, ctx: &RenderContext) {
        let gpu = ctx.gpu;
        let features = &ctx.scene.data.features;
        self.classes = LightClasses::of(features);
        self.many_lights = features.many_lights;
        let px = ctx.extent[0] as u64 * ctx.extent[1] as u64;
        let keep = self.extent == ctx.extent;
        self.di.build_resources(gpu, px, keep);
        self.gi.build_resources(gpu, px, keep);
        self.regir.build_resources(gpu, &self.settings, features);
        if !keep || self.debug.is_none() {
            self.debug = Some(pipelines::storage_buffer(gpu, "restir debug", px * 16));
        }
        let params = wgpu::util::DeviceExt::create_buffer_init(
            &gpu.device,
            &wgpu::util::BufferInitDescriptor {
                label: Some("restir params"),
                contents: bytemuck::bytes_of(&self.gpu_params(px as u32)),
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            },
        );
        let layout = self.layout(gpu).clone();
        let (
            Some(reservoirs),
            Some(gi_reservoirs),
            Some(gi_sky),
            Some(slots),
            Some(used),
            Some(debug),
        ) = (
            &self.di.reservoirs,
            &self.gi.reservoirs,
            &self.gi.sky,
            &self.regir.slots,
            &self.regir.used,
            &self.debug,
        )
        else {
            unreachable!("every buffer was just made");
        };
        self.bind_group = Some(pipelines::buffers_bind_group(
            gpu,
            "restir",
            &layout,
            &[
                &params,
                reservoirs,
                gi_reservoirs,
                gi_sky,
                slots,
                debug,
                used,
            ],
        ));
        self.params_buffer = Some(params);
        self.extent = ctx.extent;
    }

    /// This frame's ReGIR build (many lights), DI (when the scene has light to sample) and GI
    /// (`gi` on) passes.
    pub fn record(
        &mut self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
    ) {
        let Some(bg) = &self.bind_group else {
            return;
        };
        if self.regir_active() {
            self.regir
                .record(ctx, enc, timer, bg, self.settings.regir_lights_per_cell);
        }
        // With spatial_count = 0 DI's spatial pass only copies the temporal result through.
        if self.has_direct_sources() {
            self.di.passes.record(ctx, enc, timer, bg);
        }
        if self.settings.gi {
            let cache = self.settings.gi_terminate.cache();
            self.gi.record(ctx, enc, timer, bg, cache);
        }
    }

    /// The GI reservoirs' sample points (xyz, w = 1 when the reservoir holds one) this frame's
    /// temporal pass wrote (tests: a reused point on a moving object moved with it).
    pub fn gi_temporal_points(&self, gpu: &Gpu) -> anyhow::Result<Vec<[f32; 4]>> {
        let Some(buffer) = &self.gi.reservoirs else {
            return Ok(Vec::new());
        };
        let px = (self.extent[0] * self.extent[1]) as usize;
        // 16 floats a reservoir, three segments of px: the temporal pass's is the third.
        let all: Vec<[f32; 16]> = crate::gpu::readback::read_buffer(gpu, buffer, 3 * px)?;
        Ok(all[2 * px..]
            .iter()
            .map(|r| [r[0], r[1], r[2], r[3]])
            .collect())
    }

    /// Forgets the DI reservoirs (camera cut, parameter change).
    pub fn reset(&self, gpu: &Gpu) {
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        self.di.reset(&mut enc);
        gpu.submit("restir: reservoir reset", enc.finish());
    }

    fn gpu_params(&self, pixels: u32) -> RestirParamsGpu {
        let s = &self.settings;
        let [local, directional, sky] = self.class_candidates();
        RestirParamsGpu {
            candidates: local,
            candidate_visibility: s.candidate_visibility as u32,
            temporal: s.temporal as u32,
            max_history: s.max_history,
            spatial_count: s.spatial_count,
            spatial_radius: s.spatial_radius,
            unbiased: s.unbiased as u32,
            bidirectional: s.bidirectional as u32,
            pixels,
            accumulate: s.accumulate as u32,
            gi: s.gi as u32,
            // A path that ends in a cache ends at a hit: at the first one when unbounded.
            gi_bounces: if s.gi_terminate.cache() {
                s.gi_bounces.max(1)
            } else {
                s.gi_bounces
            },
            regir: self.regir_active() as u32,
            regir_cell_size: self.regir.cell,
            regir_dims: REGIR_DIMS,
            regir_slots: s.regir_lights_per_cell,
            directional_candidates: directional,
            sky_candidates: sky,
            single_pool: !s.light_classes as u32,
            gi_cosine: s.gi_cosine as u32,
            path_light_candidates: s.path_light_candidates.max(1),
            specular_bounces: s.specular_bounces,
            specular_max_roughness: s.specular_max_roughness,
            light_tree: (s.light_tree && s.light_classes) as u32,
            bsdf_candidates: if local > 0 {
                super::di::bsdf_candidates_for(s, &self.classes)
            } else {
                0
            },
            bsdf_max_roughness: s.bsdf_max_roughness,
            // Local lights only: the tree holds no directional light.
            regir_tree: (s.regir_tree && s.light_classes) as u32,
            pad_b: 0,
        }
    }
}
