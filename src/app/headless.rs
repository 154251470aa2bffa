//! The viewer without a window: the real `ViewerApp` UI frame (rendering step, readback,
//! heatmaps, panels, plots) plus egui's own wgpu painting into an offscreen texture. `gilab
//! bench` uses it to measure what the viewer adds to a technique's frame time.

use super::{ViewerApp, ViewerOptions};
use crate::gpu::Gpu;
use anyhow::Result;
use std::sync::Arc;

pub struct HeadlessViewer {
    pub app: ViewerApp,
    ctx: egui::Context,
    renderer: super::views::EguiRenderer,
    target: wgpu::TextureView,
    size: [u32; 2],
    gpu: Arc<Gpu>,
}

const FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;

impl HeadlessViewer {
    pub fn new(gpu: Arc<Gpu>, options: ViewerOptions, size: [u32; 2]) -> Result<HeadlessViewer> {
        let mut app = ViewerApp::with_gpu(Ok(gpu.clone()), options);
        if let Some(e) = &app.startup_error {
            anyhow::bail!("viewer: {e}");
        }
        let renderer = Arc::new(egui::mutex::RwLock::new(egui_wgpu::Renderer::new(
            &gpu.device,
            FORMAT,
            Default::default(),
        )));
        app.egui_renderer = Some(renderer.clone());
        let texture = gpu.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("headless viewer"),
            size: wgpu::Extent3d {
                width: size[0],
                height: size[1],
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
            view_formats: &[],
        });
        Ok(HeadlessViewer {
            app,
            ctx: egui::Context::default(),
            renderer,
            target: texture.create_view(&Default::default()),
            size,
            gpu,
        })
    }

    /// One UI frame, painted and waited for; returns its wall milliseconds.
    pub fn frame(&mut self) -> Result<f64> {
        let start = std::time::Instant::now();
        let input = egui::RawInput {
            screen_rect: Some(egui::Rect::from_min_size(
                egui::Pos2::ZERO,
                egui::vec2(self.size[0] as f32, self.size[1] as f32),
            )),
            ..Default::default()
        };
        let app = &mut self.app;
        let output = self.ctx.run_ui(input, |ui| app.show(ui));
        let jobs = self.ctx.tessellate(output.shapes, output.pixels_per_point);
        let screen = egui_wgpu::ScreenDescriptor {
            size_in_pixels: self.size,
            pixels_per_point: output.pixels_per_point,
        };
        let (device, queue) = (&self.gpu.device, &self.gpu.queue);
        let mut renderer = self.renderer.write();
        for (id, deltas) in &output.textures_delta.set {
            for delta in deltas {
                renderer.update_texture(device, queue, *id, delta);
            }
        }
        let mut enc = device.create_command_encoder(&Default::default());
        let extra = renderer.update_buffers(device, queue, &mut enc, &jobs, &screen);
        {
            let pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("headless viewer"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &self.target,
                    resolve_target: None,
                    depth_slice: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                ..Default::default()
            });
            renderer.render(&mut pass.forget_lifetime(), &jobs, &screen);
        }
        self.gpu.submit_all(
            "viewer: egui frame",
            extra.into_iter().chain([enc.finish()]),
        );
        for id in &output.textures_delta.free {
            renderer.free_texture(id);
        }
        drop(renderer);
        self.gpu.wait()?;
        Ok(start.elapsed().as_secs_f64() * 1e3)
    }
}
