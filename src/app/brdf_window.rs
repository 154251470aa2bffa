//! The BRDF slice window: the (θh, θd) slices of the material under the cursor under the three
//! shading models (lambert-ggx, callisto, callisto-proxima, left to right), from the same GPU
//! probe as `gilab brdf-slice`. The material is found by a CPU ray through the pixel.

use super::session::Session;
use crate::compare::brdf_probe::{BrdfProbe, ProbeMaterial};
use crate::experiment::realtime::CpuScene;
use crate::scene::shading::BrdfModel;
use std::sync::Arc;

const SLICE: u32 = 96;
const GAP: u32 = 4;

#[derive(Default)]
pub struct BrdfWindow {
    pub open: bool,
    /// Picking structure and probe, built when the window first needs them (per scene).
    picker: Option<(usize, CpuScene)>,
    probe: Option<BrdfProbe>,
    /// Material shown (by index) and its parameters when drawn: redrawn when either changes.
    shown: Option<(usize, ProbeMaterial)>,
    texture: Option<egui::TextureHandle>,
    error: Option<String>,
}

impl BrdfWindow {
    /// Index of the material whose slices are shown.
    pub fn shown_material(&self) -> Option<usize> {
        self.shown.as_ref().map(|(i, _)| *i)
    }

    pub fn show(&mut self, ctx: &egui::Context, s: &Session, hovered: Option<(u32, u32)>) {
        if !self.open {
            return;
        }
        let mut open = self.open;
        if let Some((x, y)) = hovered {
            self.update(ctx, s, x, y);
        }
        egui::Window::new("BRDF slice under the cursor")
            .open(&mut open)
            .default_width((3 * SLICE + 2 * GAP) as f32 + 20.0)
            .show(ctx, |ui| {
                if let Some(e) = &self.error {
                    ui.colored_label(egui::Color32::RED, e);
                }
                match (&self.shown, &self.texture) {
                    (Some((i, m)), Some(tex)) => {
                        let name = s.scene.materials.get(*i).map(|m| m.name.as_str());
                        ui.label(format!(
                            "material '{}' (renders with {}), roughness {:.2}, metallic {:.2}",
                            name.unwrap_or("?"),
                            m.brdf.name(),
                            m.roughness,
                            m.metallic
                        ));
                        ui.image((tex.id(), tex.size_vec2() * 1.5));
                        ui.label(
                            "lambert-ggx | callisto | callisto-proxima; theta_h to the right, \
                             theta_d down (0-90 deg, phi_d 90 deg), f*pi linear (white = 1); base \
                             colour factor, no texture",
                        );
                    }
                    _ => {
                        ui.label("hover a pane to pick a material");
                    }
                }
            });
        self.open = open;
    }

    fn update(&mut self, ctx: &egui::Context, s: &Session, x: u32, y: u32) {
        let scene_id = Arc::as_ptr(&s.scene) as usize;
        if self.picker.as_ref().is_none_or(|(id, _)| *id != scene_id) {
            self.picker = Some((scene_id, CpuScene::new(&s.scene)));
            self.shown = None;
        }
        let extent = s.reference.engine.extent;
        let (_, picker) = self.picker.as_ref().unwrap();
        let Some(tri) = picker.pick(&s.camera, extent, x as f32 + 0.5, y as f32 + 0.5) else {
            return;
        };
        let Some(&mi) = s.scene.triangle_material.get(tri as usize) else {
            return;
        };
        let mi = mi as usize;
        let material = ProbeMaterial::from_material(&s.scene.materials[mi]);
        if self.shown == Some((mi, material)) {
            return;
        }
        if self.probe.is_none() {
            match BrdfProbe::new(&s.gpu, &s.shaders) {
                Ok(p) => self.probe = Some(p),
                Err(e) => {
                    self.error = Some(format!("BRDF probe: {e}"));
                    return;
                }
            }
        }
        let probe = self.probe.as_ref().unwrap();
        let width = 3 * SLICE + 2 * GAP;
        let mut rgba = vec![40u8; (width * SLICE * 4) as usize];
        for (k, model) in BrdfModel::ALL.iter().enumerate() {
            let m = ProbeMaterial {
                brdf: *model,
                ..material
            };
            let img = match probe.slice(&s.gpu, &m, SLICE, std::f32::consts::FRAC_PI_2) {
                Ok(img) => img,
                Err(e) => {
                    self.error = Some(format!("BRDF slice: {e}"));
                    return;
                }
            };
            for (p, c) in img.rgb.chunks_exact(3).enumerate() {
                let (px, py) = (p as u32 % SLICE, p as u32 / SLICE);
                let o = ((py * width + k as u32 * (SLICE + GAP) + px) * 4) as usize;
                for ch in 0..3 {
                    let v = crate::compare::tonemap::linear_to_srgb(c[ch].clamp(0.0, 1.0));
                    rgba[o + ch] = (v * 255.0 + 0.5) as u8;
                }
                rgba[o + 3] = 255;
            }
        }
        let image =
            egui::ColorImage::from_rgba_unmultiplied([width as usize, SLICE as usize], &rgba);
        match &mut self.texture {
            Some(t) => t.set(image, egui::TextureOptions::NEAREST),
            None => {
                self.texture =
                    Some(ctx.load_texture("brdf slice", image, egui::TextureOptions::NEAREST))
            }
        }
        self.error = None;
        self.shown = Some((mi, material));
    }
}
