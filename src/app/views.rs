//! The central panel: panes in the chosen layout (single, side by side, 2x2, wipe), each
//! with its texture, a title and a colour bar for heatmaps; camera input; pixel inspector;
//! the error overlay.

use super::{camera, session::Session, ViewerApp};
use crate::compare::display::{DisplayTarget, GpuCompare};
use crate::compare::heatmap;
use crate::preset::{DisplayMode, Layout};
use egui::{Color32, Pos2, Rect, Sense, Stroke, TextureHandle, Vec2};

/// The egui renderer the panes' GPU textures are registered with (eframe's, or the headless
/// viewer's); without one the panes fall back to the CPU path and upload images.
pub type EguiRenderer = std::sync::Arc<egui::mutex::RwLock<egui_wgpu::Renderer>>;

/// One texture per pane, displayed again only when its content key changes.
#[derive(Default)]
pub struct PaneTextures {
    slots: Vec<Option<Slot>>,
}

enum PaneTexture {
    /// Written on the GPU by `compare::display` and drawn by egui as it is.
    Gpu {
        target: Box<DisplayTarget>,
        id: egui::TextureId,
    },
    /// Computed on the CPU and uploaded (no egui renderer to register a GPU texture with).
    Cpu(TextureHandle),
}

struct Slot {
    key: Option<TextureKey>,
    texture: PaneTexture,
    range: Option<(f32, f32)>,
    size: [u32; 2],
    run: usize,
}

#[derive(Clone, Copy, PartialEq)]
struct TextureKey {
    run: usize,
    display: DisplayMode,
    debug: usize,
    version: u64,
    tonemap: crate::compare::tonemap::Settings,
    /// The histogram range the GPU display uses (a new one displays again).
    range: Option<(u32, u32)>,
    reference: bool,
}

/// What a pane draws this frame.
#[derive(Clone)]
struct PaneImage {
    texture: egui::TextureId,
    range: Option<(f32, f32)>,
    size: [u32; 2],
}

impl PaneTextures {
    fn update(
        &mut self,
        ctx: &egui::Context,
        renderer: Option<&EguiRenderer>,
        s: &Session,
        pane: usize,
    ) -> Option<PaneImage> {
        if self.slots.len() <= pane {
            self.slots.resize_with(pane + 1, || None);
        }
        let p = s.panes[pane];
        let run = s.runs.get(p.run)?;
        let tm = &s.preset.preset.tonemap;
        let size = run.engine.extent;
        let slot = &mut self.slots[pane];
        match renderer {
            Some(renderer) => {
                let fresh = !matches!(slot, Some(Slot { texture: PaneTexture::Gpu { target, .. }, .. }) if target.extent == size);
                if fresh {
                    let target = Box::new(DisplayTarget::new(&s.gpu, size));
                    let id = renderer.write().register_native_texture(
                        &s.gpu.device,
                        &target.view,
                        wgpu::FilterMode::Nearest,
                    );
                    if let Some(Slot {
                        texture: PaneTexture::Gpu { id: old, .. },
                        ..
                    }) = slot.take()
                    {
                        renderer.write().free_texture(&old);
                    }
                    *slot = Some(Slot {
                        key: None,
                        texture: PaneTexture::Gpu { target, id },
                        range: None,
                        size,
                        run: p.run,
                    });
                }
                let sl = slot.as_mut().expect("set above");
                let PaneTexture::Gpu { target, .. } = &mut sl.texture else {
                    unreachable!("a GPU slot")
                };
                if let Err(e) = target.poll_range(&s.gpu) {
                    log::warn!("heatmap range readback: {e:#}");
                }
                let key = TextureKey {
                    run: p.run,
                    display: p.display,
                    debug: p.debug,
                    version: run.version,
                    tonemap: *tm,
                    range: target.range.map(|(a, b)| (a.to_bits(), b.to_bits())),
                    reference: s.reference.on_gpu,
                };
                if sl.key != Some(key) {
                    if let Some(settings) = s.display_settings(&p) {
                        let mut enc = s.gpu.device.create_command_encoder(&Default::default());
                        if s.record_pane_display(&mut enc, &p, &settings, target) {
                            let histogram = s.compare.record_histogram_copy(&mut enc, target);
                            let submission = s.gpu.submit("viewer: pane display", enc.finish());
                            if histogram {
                                GpuCompare::start_histogram_read(target, submission);
                            }
                            sl.key = Some(key);
                            sl.range = target.shown_range;
                            sl.run = p.run;
                        }
                    }
                }
            }
            None => {
                let key = TextureKey {
                    run: p.run,
                    display: p.display,
                    debug: p.debug,
                    version: run.version,
                    tonemap: *tm,
                    range: None,
                    reference: s.reference.on_gpu,
                };
                if slot.as_ref().is_none_or(|sl| sl.key != Some(key)) {
                    if let Some((rgba, img, range)) = s.pane_pixels(&p) {
                        let size = [img.width, img.height];
                        let image = egui::ColorImage::from_rgba_unmultiplied(
                            [size[0] as usize, size[1] as usize],
                            &rgba,
                        );
                        let options = egui::TextureOptions::NEAREST;
                        match slot {
                            Some(Slot {
                                texture: PaneTexture::Cpu(t),
                                ..
                            }) => t.set(image, options),
                            _ => {
                                *slot = Some(Slot {
                                    key: None,
                                    texture: PaneTexture::Cpu(ctx.load_texture(
                                        format!("pane{pane}"),
                                        image,
                                        options,
                                    )),
                                    range: None,
                                    size,
                                    run: p.run,
                                })
                            }
                        }
                        let sl = slot.as_mut().expect("set above");
                        sl.key = Some(key);
                        sl.range = range;
                        sl.size = size;
                        sl.run = p.run;
                    }
                }
            }
        }
        slot.as_ref()
            .filter(|sl| sl.key.is_some() && sl.run == p.run)
            .map(|sl| PaneImage {
                texture: match &sl.texture {
                    PaneTexture::Gpu { id, .. } => *id,
                    PaneTexture::Cpu(t) => t.id(),
                },
                range: sl.range,
                size: sl.size,
            })
    }
}

/// Largest rect of the image's aspect inside `area`, centred.
fn fit(area: Rect, size: [u32; 2]) -> Rect {
    let aspect = size[0] as f32 / size[1].max(1) as f32;
    let w = area.width().min(area.height() * aspect);
    let h = w / aspect;
    Rect::from_center_size(area.center(), Vec2::new(w, h))
}

/// Splits the area into the layout's pane rects.
fn pane_rects(area: Rect, layout: Layout) -> Vec<Rect> {
    let gap = 6.0;
    let (w, h) = (area.width(), area.height());
    match layout {
        Layout::Single | Layout::Wipe => vec![area],
        Layout::SideBySide => {
            let half = (w - gap) / 2.0;
            vec![
                Rect::from_min_size(area.min, Vec2::new(half, h)),
                Rect::from_min_size(area.min + Vec2::new(half + gap, 0.0), Vec2::new(half, h)),
            ]
        }
        Layout::Grid => {
            let (hw, hh) = ((w - gap) / 2.0, (h - gap) / 2.0);
            (0..4)
                .map(|i| {
                    let off = Vec2::new((i % 2) as f32 * (hw + gap), (i / 2) as f32 * (hh + gap));
                    Rect::from_min_size(area.min + off, Vec2::new(hw, hh))
                })
                .collect()
        }
    }
}

const TITLE_H: f32 = 18.0;
const BAR_H: f32 = 30.0;

pub fn central_panel(app: &mut ViewerApp, ui: &mut egui::Ui) {
    egui::CentralPanel::default().show(ui, |ui| {
        let Some(s) = app.session.as_mut() else {
            return;
        };
        error_overlay(ui, s);
        status_line(ui, s, app.ui_frame_ms);
        let area = ui.available_rect_before_wrap();
        let count = s.layout.pane_count();
        let renderer = app.egui_renderer.as_ref();
        let images: Vec<Option<PaneImage>> = (0..count)
            .map(|i| app.views.update(ui.ctx(), renderer, s, i))
            .collect();
        let mut new_camera = None;
        let mut hovered: Option<(u32, u32)> = None;
        if s.layout == Layout::Wipe {
            let (cam, hover) = wipe_view(ui, s, area, &images);
            new_camera = cam;
            hovered = hover;
        } else {
            for (i, rect) in pane_rects(area, s.layout).into_iter().enumerate() {
                let (cam, hover) = pane_view(ui, s, i, rect, images[i].as_ref());
                new_camera = new_camera.or(cam);
                hovered = hovered.or(hover);
            }
        }
        app.panels.inspected = hovered;
        if let Some((x, y)) = hovered {
            // Only the hovered pixel travels back, a frame or more later.
            s.request_pixel(x, y);
        }
        if let Some(c) = new_camera {
            s.set_camera(c);
        }
    });
}

fn error_overlay(ui: &mut egui::Ui, s: &Session) {
    if s.errors.is_empty() {
        return;
    }
    egui::Frame::new()
        .fill(Color32::from_rgb(70, 10, 10))
        .stroke(Stroke::new(1.0, Color32::RED))
        .inner_margin(6.0)
        .show(ui, |ui| {
            for (source, msg) in &s.errors {
                ui.colored_label(Color32::WHITE, format!("{source}: {msg}"));
            }
            if s.errors.contains_key("shaders") {
                ui.colored_label(
                    Color32::LIGHT_GRAY,
                    "the last good pipelines keep running; fix the file to reload",
                );
            }
        });
}

fn status_line(ui: &mut egui::Ui, s: &Session, ui_ms: f64) {
    let r = &s.reference;
    let reference = match &r.source {
        super::session::ReferenceSource::Cached(p) => format!("reference: cached {}", p.display()),
        super::session::ReferenceSource::Done => format!("reference: {} spp (done)", r.samples()),
        super::session::ReferenceSource::Rendering => {
            format!("reference: converging {}/{} spp", r.samples(), r.target_spp)
        }
    };
    ui.horizontal(|ui| {
        ui.label(format!(
            "{} | {} | UI frame {:.0} ms",
            s.scene.name, reference, ui_ms
        ));
        if !r.done() {
            ui.add(egui::ProgressBar::new(r.progress()).desired_width(120.0));
        }
    });
}

/// Camera input on an image area; returns the moved camera, if any.
fn camera_input(
    ui: &egui::Ui,
    response: &egui::Response,
    cam: &crate::scene::Camera,
) -> Option<crate::scene::Camera> {
    let mut c = *cam;
    let d = response.drag_delta();
    if response.dragged_by(egui::PointerButton::Primary) && d != Vec2::ZERO {
        c = camera::orbit(&c, d.x, d.y);
    }
    if response.dragged_by(egui::PointerButton::Secondary) && d != Vec2::ZERO {
        c = camera::look(&c, d.x, d.y);
    }
    if response.hovered() {
        let scroll = ui.input(|i| i.smooth_scroll_delta.y);
        if scroll != 0.0 {
            c = camera::dolly(&c, scroll / 50.0);
        }
        let step = (c.target - c.position).length().max(0.1) * 0.02;
        let keys = ui.input(|i| {
            let k = |key| if i.key_down(key) { 1.0 } else { 0.0 };
            glam::Vec3::new(
                k(egui::Key::D) - k(egui::Key::A),
                k(egui::Key::E) - k(egui::Key::Q),
                k(egui::Key::W) - k(egui::Key::S),
            )
        });
        if keys != glam::Vec3::ZERO {
            c = camera::fly(&c, keys * step);
        }
    }
    (c != *cam).then_some(c)
}

/// Pixel under the pointer for an image drawn in `img_rect`.
fn pixel_at(pos: Pos2, img_rect: Rect, size: [u32; 2]) -> Option<(u32, u32)> {
    if !img_rect.contains(pos) {
        return None;
    }
    let u = (pos.x - img_rect.min.x) / img_rect.width();
    let v = (pos.y - img_rect.min.y) / img_rect.height();
    let x = ((u * size[0] as f32) as u32).min(size[0] - 1);
    let y = ((v * size[1] as f32) as u32).min(size[1] - 1);
    Some((x, y))
}

fn pane_view(
    ui: &mut egui::Ui,
    s: &Session,
    pane: usize,
    rect: Rect,
    image: Option<&PaneImage>,
) -> (Option<crate::scene::Camera>, Option<(u32, u32)>) {
    let p = s.panes[pane];
    let title = s.runs.get(p.run).map_or("?".to_string(), |r| {
        format!(
            "{}: {} · {} · frame {}",
            pane + 1,
            r.label(),
            p.display.label().to_lowercase(),
            r.engine.frame_index
        )
    });
    let painter = ui.painter_at(rect);
    painter.text(
        rect.min,
        egui::Align2::LEFT_TOP,
        title,
        egui::FontId::proportional(13.0),
        ui.visuals().text_color(),
    );
    let mut body = rect;
    body.min.y += TITLE_H;
    if image.is_some_and(|i| i.range.is_some()) {
        body.max.y -= BAR_H;
    }
    let response = ui.interact(
        body,
        ui.scope_id().with(("pane", pane)),
        Sense::click_and_drag(),
    );
    let cam = camera_input(ui, &response, &s.camera);
    let Some(image) = image else {
        painter.text(
            body.center(),
            egui::Align2::CENTER_CENTER,
            "rendering…",
            egui::FontId::proportional(14.0),
            ui.visuals().weak_text_color(),
        );
        return (cam, None);
    };
    let img_rect = fit(body, image.size);
    painter.image(
        image.texture,
        img_rect,
        Rect::from_min_max(Pos2::ZERO, Pos2::new(1.0, 1.0)),
        Color32::WHITE,
    );
    if let Some((lo, hi)) = image.range {
        let bar = Rect::from_min_max(
            Pos2::new(img_rect.min.x, body.max.y + 4.0),
            Pos2::new(img_rect.max.x, body.max.y + 14.0),
        );
        colour_bar(&painter, ui, bar, lo, hi, p.display);
    }
    let hover = response
        .hover_pos()
        .and_then(|pos| pixel_at(pos, img_rect, image.size));
    if let Some((x, y)) = hover {
        response.on_hover_ui_at_pointer(|ui| inspector(ui, s, x, y));
    }
    (cam, hover)
}

fn colour_bar(
    painter: &egui::Painter,
    ui: &egui::Ui,
    bar: Rect,
    lo: f32,
    hi: f32,
    mode: DisplayMode,
) {
    let n = 64;
    for i in 0..n {
        let t = i as f32 / (n - 1) as f32;
        let [r, g, b] = heatmap::colour(t);
        let x0 = bar.min.x + bar.width() * i as f32 / n as f32;
        let x1 = bar.min.x + bar.width() * (i + 1) as f32 / n as f32;
        painter.rect_filled(
            Rect::from_min_max(Pos2::new(x0, bar.min.y), Pos2::new(x1 + 0.5, bar.max.y)),
            0.0,
            Color32::from_rgb(r, g, b),
        );
    }
    let what = match mode {
        DisplayMode::Variance => "variance (log)",
        DisplayMode::Error => "relMSE (log)",
        DisplayMode::Debug => "debug value (log)",
        _ => "samples (log)",
    };
    let font = egui::FontId::proportional(11.0);
    let col = ui.visuals().text_color();
    let y = bar.max.y + 1.0;
    painter.text(
        Pos2::new(bar.min.x, y),
        egui::Align2::LEFT_TOP,
        format!("{:.1e}", 10f32.powf(lo)),
        font.clone(),
        col,
    );
    painter.text(
        Pos2::new(bar.center().x, y),
        egui::Align2::CENTER_TOP,
        format!("{what} {:.1e}", 10f32.powf((lo + hi) / 2.0)),
        font.clone(),
        col,
    );
    painter.text(
        Pos2::new(bar.max.x, y),
        egui::Align2::RIGHT_TOP,
        format!("{:.1e}", 10f32.powf(hi)),
        font,
        col,
    );
}

/// The pixel inspector: HDR value, variance and error of this pixel in every visible pane.
pub fn inspector(ui: &mut egui::Ui, s: &Session, x: u32, y: u32) {
    ui.label(format!("pixel ({x}, {y})"));
    egui::Grid::new("inspector").striped(true).show(ui, |ui| {
        ui.label("pane");
        ui.label("radiance (linear rgb)");
        ui.label("variance");
        ui.label("relMSE");
        ui.end_row();
        for (i, p) in s.panes[..s.layout.pane_count()].iter().enumerate() {
            let Some(info) = s.inspect(p.run, x, y) else {
                continue;
            };
            let [r, g, b] = info.radiance;
            ui.label(format!("{} {}", i + 1, s.runs[p.run].label()));
            ui.label(format!("{r:.4} {g:.4} {b:.4}"));
            ui.label(info.variance.map_or("-".into(), |v| format!("{v:.3e}")));
            ui.label(info.rel_mse.map_or("-".into(), |v| format!("{v:.3e}")));
            ui.end_row();
        }
        let reference = s.panes[..s.layout.pane_count()]
            .iter()
            .find_map(|p| s.inspect(p.run, x, y))
            .and_then(|info| info.reference);
        if let Some([r, g, b]) = reference {
            ui.label("reference");
            ui.label(format!("{r:.4} {g:.4} {b:.4}"));
            ui.end_row();
        }
    });
    // A pane showing a debug view: every debug view of its technique at this pixel (DDGI's
    // list the 8 probes the pixel reads and their shares, for example).
    for (i, p) in s.panes[..s.layout.pane_count()].iter().enumerate() {
        if p.display != DisplayMode::Debug {
            continue;
        }
        let Some(values) = s.inspect_debug(p.run, x, y) else {
            continue;
        };
        let run = &s.runs[p.run];
        ui.label(format!("{} {}: debug views here", i + 1, run.label()));
        egui::Grid::new(("inspector-debug", i))
            .striped(true)
            .show(ui, |ui| {
                for view in run.engine.technique.debug_views() {
                    let Some(v) = values.get(view.channel) else {
                        continue;
                    };
                    ui.label(view.name);
                    ui.label(if view.is_id {
                        format!("{v}")
                    } else {
                        format!("{v:.4e}")
                    });
                    ui.end_row();
                }
            });
    }
}

fn wipe_view(
    ui: &mut egui::Ui,
    s: &mut Session,
    area: Rect,
    images: &[Option<PaneImage>],
) -> (Option<crate::scene::Camera>, Option<(u32, u32)>) {
    let painter = ui.painter_at(area);
    let label = |i: usize| {
        let p = s.panes[i];
        format!(
            "{} · {}",
            s.runs[p.run].label(),
            p.display.label().to_lowercase()
        )
    };
    painter.text(
        area.min,
        egui::Align2::LEFT_TOP,
        format!("wipe: left {} | right {}", label(0), label(1)),
        egui::FontId::proportional(13.0),
        ui.visuals().text_color(),
    );
    let mut body = area;
    body.min.y += TITLE_H;
    let (Some(a), Some(b)) = (&images[0], &images[1]) else {
        return (None, None);
    };
    let img_rect = fit(body, a.size);
    let split = img_rect.min.x + img_rect.width() * s.wipe;
    let left = Rect::from_min_max(img_rect.min, Pos2::new(split, img_rect.max.y));
    let right = Rect::from_min_max(Pos2::new(split, img_rect.min.y), img_rect.max);
    painter.image(
        a.texture,
        left,
        Rect::from_min_max(Pos2::ZERO, Pos2::new(s.wipe, 1.0)),
        Color32::WHITE,
    );
    painter.image(
        b.texture,
        right,
        Rect::from_min_max(Pos2::new(s.wipe, 0.0), Pos2::new(1.0, 1.0)),
        Color32::WHITE,
    );
    // Camera input everywhere but on the handle, which is added after so it wins.
    let response = ui.interact(
        img_rect,
        ui.scope_id().with("wipe-image"),
        Sense::click_and_drag(),
    );
    let cam = camera_input(ui, &response, &s.camera);
    let handle = Rect::from_min_max(
        Pos2::new(split - 6.0, img_rect.min.y),
        Pos2::new(split + 6.0, img_rect.max.y),
    );
    let h = ui.interact(handle, ui.scope_id().with("wipe-handle"), Sense::drag());
    if h.dragged() {
        s.wipe = ((split + h.drag_delta().x - img_rect.min.x) / img_rect.width()).clamp(0.0, 1.0);
    }
    painter.line_segment(
        [
            Pos2::new(split, img_rect.min.y),
            Pos2::new(split, img_rect.max.y),
        ],
        Stroke::new(2.0, Color32::WHITE),
    );
    let hover = response
        .hover_pos()
        .and_then(|pos| pixel_at(pos, img_rect, a.size));
    if let Some((x, y)) = hover {
        response.on_hover_ui_at_pointer(|ui| inspector(ui, s, x, y));
    }
    (if h.dragged() { None } else { cam }, hover)
}
