//! Card capture (the seed's "Card Capture"): each card's object rasterised with the card's
//! orthographic camera into its rectangle of the atlas (albedo, normal, emission, depth),
//! `vs_clear` first marking the rectangle invalid. Nearest cards first, up to a fixed budget
//! of texels per frame.

use super::cards::{CardSet, GpuCard};
use super::{Pipelines, Resources};
use crate::gpu::{timing::PassTimer, Gpu};
use crate::render::{pipelines, RenderContext};
use anyhow::Result;

pub const FILE: &str = "parts/surface_cache/capture.wgsl";
/// Texels captured per frame (the seed's fixed 512^2 budget).
pub const TEXELS_PER_FRAME: u32 = 512 * 512;
const ALBEDO_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
const NORMAL_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba16Float;
const EMISSIVE_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba16Float;
const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Float;
const CAPTURE_DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
const ATLAS_FORMATS: [wgpu::TextureFormat; 4] =
    [ALBEDO_FORMAT, NORMAL_FORMAT, EMISSIVE_FORMAT, DEPTH_FORMAT];

/// Group 1 of the capture raster pipelines: the cards.
pub fn layout(gpu: &Gpu) -> wgpu::BindGroupLayout {
    let mut capture = pipelines::storage_entry(0, true);
    capture.visibility = wgpu::ShaderStages::VERTEX_FRAGMENT;
    pipelines::layout(gpu, "lumen capture", &[capture])
}

pub fn bind_group(
    gpu: &Gpu,
    layout: &wgpu::BindGroupLayout,
    cards: &wgpu::Buffer,
) -> wgpu::BindGroup {
    pipelines::buffers_bind_group(gpu, "lumen capture", layout, &[cards])
}

/// The atlas textures (albedo, normal, emission, depth) and the capture's depth buffer.
pub fn atlas(gpu: &Gpu, atlas_size: u32) -> (Vec<wgpu::TextureView>, wgpu::TextureView) {
    let size = wgpu::Extent3d {
        width: atlas_size,
        height: atlas_size,
        depth_or_array_layers: 1,
    };
    let make = |label: &str, format| {
        gpu.device.create_texture(&wgpu::TextureDescriptor {
            label: Some(label),
            size,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
            view_formats: &[],
        })
    };
    let atlas_views: Vec<wgpu::TextureView> = [
        "lumen albedo",
        "lumen normal",
        "lumen emissive",
        "lumen depth",
    ]
    .iter()
    .zip(ATLAS_FORMATS)
    .map(|(l, f)| make(l, f).create_view(&Default::default()))
    .collect();
    let depth = make("lumen capture depth", CAPTURE_DEPTH_FORMAT).create_view(&Default::default());
    (atlas_views, depth)
}

/// The capture and clear pipelines (one module).
pub fn pipelines(
    ctx: &RenderContext,
    capture_layout: &wgpu::BindGroupLayout,
) -> Result<(wgpu::RenderPipeline, wgpu::RenderPipeline)> {
    let gpu = ctx.gpu;
    let module = pipelines::shader_module(gpu, ctx.shaders, FILE)?;
    let raster_layout = gpu
        .device
        .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("lumen capture"),
            bind_group_layouts: &[Some(&ctx.scene.layout), Some(capture_layout)],
            immediate_size: 0,
        });
    Ok((
        pipeline(gpu, &module, &raster_layout, false)?,
        pipeline(gpu, &module, &raster_layout, true)?,
    ))
}

fn pipeline(
    gpu: &Gpu,
    module: &wgpu::ShaderModule,
    layout: &wgpu::PipelineLayout,
    clear: bool,
) -> Result<wgpu::RenderPipeline> {
    let attributes = wgpu::vertex_attr_array![0 => Float32x3];
    let targets: Vec<Option<wgpu::ColorTargetState>> = ATLAS_FORMATS
        .iter()
        .map(|f| {
            Some(wgpu::ColorTargetState {
                format: *f,
                blend: None,
                write_mask: wgpu::ColorWrites::ALL,
            })
        })
        .collect();
    let buffers = [Some(wgpu::VertexBufferLayout {
        array_stride: std::mem::size_of::<crate::scene::gpu_scene::RasterVertex>() as u64,
        step_mode: wgpu::VertexStepMode::Vertex,
        attributes: &attributes,
    })];
    gpu.scoped("lumen capture pipeline", || {
        gpu.device
            .create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(if clear {
                    "lumen capture clear"
                } else {
                    "lumen capture"
                }),
                layout: Some(layout),
                vertex: wgpu::VertexState {
                    module,
                    entry_point: Some(if clear { "vs_clear" } else { "vs_main" }),
                    compilation_options: Default::default(),
                    buffers: if clear { &[] } else { &buffers },
                },
                primitive: wgpu::PrimitiveState {
                    cull_mode: None,
                    front_face: wgpu::FrontFace::Ccw,
                    ..Default::default()
                },
                depth_stencil: Some(wgpu::DepthStencilState {
                    format: CAPTURE_DEPTH_FORMAT,
                    depth_write_enabled: Some(true),
                    depth_compare: Some(if clear {
                        wgpu::CompareFunction::Always
                    } else {
                        wgpu::CompareFunction::Less
                    }),
                    stencil: Default::default(),
                    bias: Default::default(),
                }),
                multisample: Default::default(),
                fragment: Some(wgpu::FragmentState {
                    module,
                    entry_point: Some(if clear { "fs_clear" } else { "fs_main" }),
                    compilation_options: Default::default(),
                    targets: &targets,
                }),
                multiview_mask: None,
                cache: None,
            })
    })
}

/// Records the `capture` pass: each listed card cleared, then its object drawn.
pub(super) fn record(
    ctx: &RenderContext,
    enc: &mut wgpu::CommandEncoder,
    timer: &mut PassTimer,
    p: &Pipelines,
    r: &Resources,
    c: &CardSet,
    list: &[u32],
) {
    let attachments: Vec<Option<wgpu::RenderPassColorAttachment>> = r
        .atlas_views
        .iter()
        .map(|v| {
            Some(wgpu::RenderPassColorAttachment {
                view: v,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Load,
                    store: wgpu::StoreOp::Store,
                },
            })
        })
        .collect();
    let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
        label: Some("lumen capture"),
        color_attachments: &attachments,
        depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
            view: &r.capture_depth_view,
            depth_ops: Some(wgpu::Operations {
                load: wgpu::LoadOp::Load,
                store: wgpu::StoreOp::Store,
            }),
            stencil_ops: None,
        }),
        timestamp_writes: timer.render_pass("capture"),
        occlusion_query_set: None,
        multiview_mask: None,
    });
    pass.set_bind_group(0, &ctx.scene.bind_group, &[]);
    pass.set_bind_group(1, &r.capture_bind_group, &[]);
    pass.set_vertex_buffer(0, ctx.scene.vertex_buffer.slice(..));
    pass.set_index_buffer(r.index_buffer.slice(..), wgpu::IndexFormat::Uint32);
    for &ci in list {
        let card: &GpuCard = &c.cards[ci as usize];
        let [x, y, w, h] = card.rect;
        pass.set_viewport(x as f32, y as f32, w as f32, h as f32, 0.0, 1.0);
        pass.set_scissor_rect(x, y, w, h);
        pass.set_pipeline(&p.capture_clear);
        pass.draw(0..3, ci..ci + 1);
        pass.set_pipeline(&p.capture);
        let [first, count, _, _] = card.draw;
        pass.draw_indexed(first..first + count, 0, ci..ci + 1);
    }
}
