//! G-buffer raster pass: depth, normal+roughness, albedo+metallic, emission, motion vectors and
//! view distance — the shared primary-visibility input of the real-time techniques.

use super::pipelines::{shader_module, uniform_entry};
use crate::gpu::shaders::ShaderLibrary;
use crate::gpu::{timing::PassTimer, Gpu};
use crate::scene::gpu_scene::{GpuScene, RasterVertex};
use anyhow::Result;

pub const TARGETS: [(&str, wgpu::TextureFormat); 5] = [
    ("normal_roughness", wgpu::TextureFormat::Rgba16Float),
    ("albedo_metallic", wgpu::TextureFormat::Rgba8Unorm),
    ("emissive", wgpu::TextureFormat::Rgba16Float),
    ("motion", wgpu::TextureFormat::Rg16Float),
    ("view_distance", wgpu::TextureFormat::R32Float),
];
pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

pub struct GBuffer {
    pub extent: [u32; 2],
    pub targets: Vec<wgpu::Texture>,
    pub views: Vec<wgpu::TextureView>,
    pub depth: wgpu::Texture,
    depth_view: wgpu::TextureView,
    pipeline: wgpu::RenderPipeline,
    frame_bind_group: wgpu::BindGroup,
}

impl GBuffer {
    pub fn new(
        gpu: &Gpu,
        shaders: &ShaderLibrary,
        scene: &GpuScene,
        uniforms: &wgpu::Buffer,
        extent: [u32; 2],
    ) -> Result<GBuffer> {
        let frame_layout = super::pipelines::layout(
            gpu,
            "gbuffer frame",
            &[uniform_entry(
                0,
                wgpu::ShaderStages::VERTEX | wgpu::ShaderStages::FRAGMENT,
            )],
        );
        let frame_bind_group = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("gbuffer frame"),
            layout: &frame_layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: uniforms.as_entire_binding(),
            }],
        });
        let module = shader_module(gpu, shaders, "gbuffer/gbuffer.wgsl")?;
        let size = wgpu::Extent3d {
            width: extent[0],
            height: extent[1],
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
                usage: wgpu::TextureUsages::RENDER_ATTACHMENT
                    | wgpu::TextureUsages::TEXTURE_BINDING
                    | wgpu::TextureUsages::COPY_SRC,
                view_formats: &[],
            })
        };
        let targets: Vec<wgpu::Texture> = TARGETS.iter().map(|(n, f)| make(n, *f)).collect();
        let views = targets
            .iter()
            .map(|t| t.create_view(&Default::default()))
            .collect();
        let depth = make("gbuffer depth", DEPTH_FORMAT);
        let depth_view = depth.create_view(&Default::default());
        let attributes = wgpu::vertex_attr_array![0 => Float32x3];
        let color_targets: Vec<Option<wgpu::ColorTargetState>> = TARGETS
            .iter()
            .map(|(_, f)| {
                Some(wgpu::ColorTargetState {
                    format: *f,
                    blend: None,
                    write_mask: wgpu::ColorWrites::ALL,
                })
            })
            .collect();
        let pipeline = gpu.scoped("gbuffer pipeline", || {
            let layout = gpu
                .device
                .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                    label: Some("gbuffer"),
                    bind_group_layouts: &[Some(&scene.layout), Some(&frame_layout)],
                    immediate_size: 0,
                });
            gpu.device
                .create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                    label: Some("gbuffer"),
                    layout: Some(&layout),
                    vertex: wgpu::VertexState {
                        module: &module,
                        entry_point: Some("vs_main"),
                        compilation_options: Default::default(),
                        buffers: &[Some(wgpu::VertexBufferLayout {
                            array_stride: std::mem::size_of::<RasterVertex>() as u64,
                            step_mode: wgpu::VertexStepMode::Vertex,
                            attributes: &attributes,
                        })],
                    },
                    primitive: wgpu::PrimitiveState {
                        cull_mode: None,
                        front_face: wgpu::FrontFace::Ccw,
                        ..Default::default()
                    },
                    depth_stencil: Some(wgpu::DepthStencilState {
                        format: DEPTH_FORMAT,
                        depth_write_enabled: Some(true),
                        depth_compare: Some(wgpu::CompareFunction::Less),
                        stencil: Default::default(),
                        bias: Default::default(),
                    }),
                    multisample: Default::default(),
                    fragment: Some(wgpu::FragmentState {
                        module: &module,
                        entry_point: Some("fs_main"),
                        compilation_options: Default::default(),
                        targets: &color_targets,
                    }),
                    multiview_mask: None,
                    cache: None,
                })
        })?;
        Ok(GBuffer {
            extent,
            targets,
            views,
            depth,
            depth_view,
            pipeline,
            frame_bind_group,
        })
    }

    pub fn render(&self, scene: &GpuScene, enc: &mut wgpu::CommandEncoder, timer: &mut PassTimer) {
        let attachments: Vec<Option<wgpu::RenderPassColorAttachment>> = self
            .views
            .iter()
            .map(|v| {
                Some(wgpu::RenderPassColorAttachment {
                    view: v,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                        store: wgpu::StoreOp::Store,
                    },
                })
            })
            .collect();
        let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("gbuffer"),
            color_attachments: &attachments,
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &self.depth_view,
                depth_ops: Some(wgpu::Operations {
                    load: wgpu::LoadOp::Clear(1.0),
                    store: wgpu::StoreOp::Store,
                }),
                stencil_ops: None,
            }),
            timestamp_writes: timer.render_pass("gbuffer"),
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &scene.bind_group, &[]);
        pass.set_bind_group(1, &self.frame_bind_group, &[]);
        pass.set_vertex_buffer(0, scene.vertex_buffer.slice(..));
        pass.draw(0..scene.vertex_count, 0..1);
    }

    /// Reads the view-distance target (tests and debug views). Background pixels are 0.
    pub fn read_view_distance(&self, gpu: &Gpu) -> Result<Vec<f32>> {
        let [w, h] = self.extent;
        let row = (w * 4).div_ceil(256) * 256;
        let buf = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("view distance readback"),
            size: (row * h) as u64,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        enc.copy_texture_to_buffer(
            self.targets[4].as_image_copy(),
            wgpu::TexelCopyBufferInfo {
                buffer: &buf,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(row),
                    rows_per_image: Some(h),
                },
            },
            wgpu::Extent3d {
                width: w,
                height: h,
                depth_or_array_layers: 1,
            },
        );
        gpu.submit("G-buffer read", enc.finish());
        let bytes = crate::gpu::readback::read_buffer_bytes(gpu, &buf, (row * h) as u64)?;
        let mut out = Vec::with_capacity((w * h) as usize);
        for y in 0..h {
            let start = (y * row) as usize;
            out.extend_from_slice(bytemuck::cast_slice::<u8, f32>(
                &bytes[start..start + (w * 4) as usize],
            ));
        }
        Ok(out)
    }
}
