//! Side panel (preset load/save, layout and panes, tonemapping, technique parameters and ray
//! budgets, scene features and passes) and bottom panel (convergence plots, per-pass GPU
//! timings, rays/s).

use super::session::Session;
use super::{ViewerApp, ViewerOptions};
use crate::compare::tonemap::{GtParams, Operator, View};
use crate::preset::{DisplayMode, Layout};
use crate::render::{engine::TimingSource, params::ParamKind};
use crate::techniques::REGISTRY;
use egui_plot::{Legend, Line, Plot, PlotPoints};
use std::path::PathBuf;

/// Which error the plots show.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum PlotMetric {
    RelMse,
    Mse,
}

pub struct PanelState {
    pub load_path: String,
    pub save_path: String,
    pub add_technique: String,
    pub metric: PlotMetric,
    /// Pixel under the pointer, for the inspector line in the bottom panel.
    pub inspected: Option<(u32, u32)>,
}

impl PanelState {
    pub fn new(options: &ViewerOptions) -> PanelState {
        let save = options
            .presets_dir
            .join("my-session.toml")
            .display()
            .to_string();
        PanelState {
            load_path: options
                .preset
                .path
                .as_ref()
                .map(|p| p.display().to_string())
                .unwrap_or_default(),
            save_path: save,
            add_technique: REGISTRY[0].id.to_string(),
            metric: PlotMetric::RelMse,
            inspected: None,
        }
    }
}

fn preset_files(dir: &std::path::Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|rd| {
            rd.filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|e| e == "toml"))
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

pub fn side_panel(app: &mut ViewerApp, ui: &mut egui::Ui) {
    egui::Panel::left("side")
        .resizable(true)
        .default_size(340.0)
        .show(ui, |ui| {
            egui::ScrollArea::vertical().show(ui, |ui| side_contents(app, ui));
        });
}

fn side_contents(app: &mut ViewerApp, ui: &mut egui::Ui) {
    let presets = preset_files(&app.presets_dir);
    let Some(s) = app.session.as_mut() else {
        return;
    };
    let st = &mut app.panels;

    preset_section(s, st, &presets, ui);
    animation_section(s, ui);
    view_section(s, ui);
    display_section(s, ui);

    ui.separator();
    ui.heading("Techniques");
    let features = s.runs[0].engine.gpu_scene.data.features.clone();
    let mut action: Option<(usize, Action)> = None;
    for (i, run) in s.runs.iter().enumerate() {
        egui::CollapsingHeader::new(run.label())
            .id_salt(("run", i))
            .default_open(i < 2)
            .show(ui, |ui| {
                let mut name = run.entry.name.clone();
                egui::ComboBox::from_label(format!("Technique of {}", run.label()))
                    .selected_text(&name)
                    .show_ui(ui, |ui| {
                        for t in REGISTRY {
                            let (id, what) = (t.id, t.what);
                            ui.selectable_value(&mut name, id.to_string(), id)
                                .on_hover_text(what);
                        }
                    });
                if name != run.entry.name {
                    action = Some((i, Action::Technique(name)));
                }
                let params = run.engine.technique.params();
                for doc in run.engine.technique.param_set().specs() {
                    let Some(v) = params.get(doc.name) else {
                        continue;
                    };
                    let hover =
                        format!("{}\nhigher: {}\nlower: {}", doc.what, doc.higher, doc.lower);
                    if let Some(mut on) = v.as_bool() {
                        // Switches: "higher" is on, "lower" is off.
                        if ui
                            .checkbox(&mut on, doc.name)
                            .on_hover_text(hover)
                            .changed()
                        {
                            let mut t = toml::Table::new();
                            t.insert(doc.name.to_string(), toml::Value::Boolean(on));
                            action = Some((i, Action::Params(t)));
                        }
                        ui.small(doc.what);
                        continue;
                    }
                    if let ParamKind::Choice(choices) = doc.kind {
                        let current = v.as_integer().unwrap_or(0).max(0) as usize;
                        let mut picked = current;
                        egui::ComboBox::from_label(doc.name)
                            .selected_text(choices.get(current).copied().unwrap_or("?"))
                            .show_ui(ui, |ui| {
                                for (k, c) in choices.iter().enumerate() {
                                    ui.selectable_value(&mut picked, k, *c);
                                }
                            })
                            .response
                            .on_hover_text(hover);
                        ui.small(doc.what);
                        if picked != current {
                            let mut t = toml::Table::new();
                            t.insert(doc.name.to_string(), toml::Value::Integer(picked as i64));
                            action = Some((i, Action::Params(t)));
                        }
                        continue;
                    }
                    let mut x = v
                        .as_float()
                        .or(v.as_integer().map(|n| n as f64))
                        .unwrap_or(0.0);
                    let (min, max) = doc.range();
                    let mut slider = egui::Slider::new(&mut x, min..=max).text(doc.name);
                    if doc.is_integer() {
                        slider = slider.integer();
                    }
                    let r = ui.add(slider).on_hover_text(hover);
                    ui.small(doc.what);
                    if r.changed() && !r.dragged() || r.drag_stopped() {
                        let mut t = toml::Table::new();
                        let value = if doc.is_integer() {
                            toml::Value::Integer(x.round() as i64)
                        } else {
                            toml::Value::Float(x)
                        };
                        t.insert(doc.name.to_string(), value);
                        action = Some((i, Action::Params(t)));
                    }
                }
                let measured = run.measured_rays_per_pixel();
                let mut budget = run.entry.budget.or(measured).unwrap_or(4.0);
                let r = ui.add(
                    egui::Slider::new(&mut budget, 1.0..=256.0)
                        .logarithmic(true)
                        .text(format!("Ray budget {} (rays/px/frame)", run.label())),
                );
                if r.changed() && !r.dragged() || r.drag_stopped() {
                    action = Some((i, Action::Budget(budget)));
                }
                ui.label(format!(
                    "measured: {} rays/px/frame",
                    measured.map_or("-".into(), |m| format!("{m:.2}"))
                ));
                let mut denoise = run.engine.denoise();
                if ui
                    .checkbox(&mut denoise, format!("Denoise {} (SVGF)", run.label()))
                    .on_hover_text(
                        "the shared SVGF-style denoiser after every frame (src/render/denoise.rs); \
                         its GPU time counts in the frame time",
                    )
                    .changed()
                {
                    action = Some((i, Action::Denoise(denoise)));
                }
                ui.label("passes:");
                for p in run.engine.passes() {
                    ui.small(format!(
                        "{} {}: {}",
                        if p.runs { "runs" } else { "skips" },
                        p.name,
                        p.why
                    ));
                }
                if ui.button(format!("Reset {}", run.label())).clicked() {
                    action = Some((i, Action::Reset));
                }
            });
    }
    if let Some((i, a)) = action {
        let result = match a {
            Action::Technique(name) => s.set_run_technique(i, &name),
            Action::Params(t) => s.set_run_params(i, &t),
            Action::Budget(b) => s.set_ray_budget(i, b),
            Action::Denoise(on) => s.set_run_denoise(i, on),
            Action::Reset => {
                s.reset_run(i);
                Ok(())
            }
        };
        match result {
            Ok(()) => {
                s.errors.remove("parameters");
            }
            Err(e) => {
                s.errors.insert("parameters".into(), format!("{e:#}"));
            }
        }
    }
    ui.horizontal(|ui| {
        egui::ComboBox::from_id_salt("add-technique")
            .selected_text(&st.add_technique)
            .show_ui(ui, |ui| {
                for id in REGISTRY.iter().map(|t| t.id) {
                    ui.selectable_value(&mut st.add_technique, id.to_string(), id);
                }
            });
        if ui.button("Add technique").clicked() {
            if let Err(e) = s.add_run(&st.add_technique) {
                s.errors.insert("parameters".into(), format!("{e:#}"));
            }
        }
    });

    ui.separator();
    ui.heading("Scene");
    ui.label(format!("{}: {}", s.scene.name, features.summary()));
    ui.label(format!(
        "shading: {} (preset [shading] brdf)",
        s.preset.preset.shading.brdf.name()
    ));
    ui.checkbox(&mut app.brdf_window.open, "BRDF slice under the cursor")
        .on_hover_text("the material's (theta_h, theta_d) slice under lambert-ggx, callisto and callisto-proxima");

    ui.separator();
    ui.heading("Render");
    ui.checkbox(&mut s.paused, "Pause");
    ui.add(
        egui::Slider::new(&mut app.frame_budget_ms, 5.0..=500.0)
            .logarithmic(true)
            .text("render ms per UI frame"),
    );
    ui.add(
        egui::Slider::new(&mut app.max_ui_share, 0.05..=1.0).text("max UI painting share when idle"),
    )
    .on_hover_text(
        "when the viewer's own painting is slow (CPU rasteriser), render more technique frames per \
         UI frame while you are not interacting; 1 = always one budget per UI frame",
    );
    ui.label(format!("adapter: {}", s.gpu.summary));
    if ui.button("Save A/B screenshot (F12)").clicked() {
        app.save_screenshot();
    }
    if ui.button("Save window screenshot (F11)").clicked() {
        app.request_window_shot(ui.ctx(), None);
    }
    if let Some(d) = &app.last_screenshot {
        ui.small(format!("last: {}", d.display()));
    }
    let Some(s) = app.session.as_ref() else {
        return;
    };
    ui.separator();
    ui.heading("Log");
    for line in s.log.iter().rev().take(8) {
        ui.small(line);
    }
}

/// The preset: the current file, one button per preset of the folder, load and save by path.
fn preset_section(s: &mut Session, st: &mut PanelState, presets: &[PathBuf], ui: &mut egui::Ui) {
    ui.heading("Preset");
    ui.label(format!(
        "current: {}",
        s.preset
            .path
            .as_ref()
            .map_or("built-in default".into(), |p| p.display().to_string())
    ));
    ui.horizontal_wrapped(|ui| {
        for p in presets {
            let name = p
                .file_name()
                .map(|n| n.to_string_lossy().to_string())
                .unwrap_or_default();
            if ui
                .button(&name)
                .on_hover_text(p.display().to_string())
                .clicked()
            {
                st.load_path = p.display().to_string();
                let _ = s.load_preset_file(p);
            }
        }
    });
    ui.horizontal(|ui| {
        ui.add(
            egui::TextEdit::singleline(&mut st.load_path)
                .desired_width(200.0)
                .hint_text("preset path"),
        );
        if ui.button("Load").clicked() {
            let _ = s.load_preset_file(&PathBuf::from(st.load_path.trim()));
        }
    });
    ui.horizontal(|ui| {
        ui.add(egui::TextEdit::singleline(&mut st.save_path).desired_width(200.0));
        if ui.button("Save preset").clicked() {
            if let Err(e) = s.save_preset(&PathBuf::from(st.save_path.trim())) {
                s.errors.insert("save".into(), format!("{e:#}"));
            }
        }
    });
}

/// Playback of a moving scene: play/pause (Space) and the scene-time slider, one clock for every pane.
fn animation_section(s: &mut Session, ui: &mut egui::Ui) {
    if let Some((scale, duration)) = s.playback() {
        // The scene moves (issue 36): one clock for every pane.
        ui.separator();
        ui.heading("Animation");
        let space =
            !ui.ctx().egui_wants_keyboard_input() && ui.input(|i| i.key_pressed(egui::Key::Space));
        ui.horizontal(|ui| {
            let label = if s.playing {
                "Pause (Space)"
            } else {
                "Play (Space)"
            };
            if ui.button(label).clicked() || space {
                s.playing = !s.playing;
            }
            ui.label(format!("x{scale} (scene.time_scale)"));
        });
        let mut t = if duration > 0.0 {
            s.scene_time.rem_euclid(duration)
        } else {
            s.scene_time
        };
        let slider =
            ui.add(egui::Slider::new(&mut t, 0.0..=duration.max(1e-3)).text("scene time (s)"));
        // Only the user's scrub (a slider also reports a change when it clamps the value).
        if slider.changed() && (slider.dragged() || slider.has_focus()) {
            s.playing = false;
            s.set_scene_time(t);
        }
        if scale == 0.0 {
            ui.label("time_scale is 0: the slider poses the scene; Play plays it at x0 (set scene.time_scale)");
        }
    }
}

/// The layout and, per pane, its technique, display and debug view.
fn view_section(s: &mut Session, ui: &mut egui::Ui) {
    ui.separator();
    ui.heading("View");
    ui.horizontal_wrapped(|ui| {
        for l in Layout::ALL {
            ui.radio_value(&mut s.layout, l, l.label());
        }
    });
    let labels: Vec<String> = s.runs.iter().map(|r| r.label().to_string()).collect();
    for i in 0..s.layout.pane_count() {
        let pane = &mut s.panes[i];
        ui.horizontal(|ui| {
            egui::ComboBox::from_label(format!("Pane {} technique", i + 1))
                .selected_text(labels.get(pane.run).cloned().unwrap_or_default())
                .show_ui(ui, |ui| {
                    for (k, l) in labels.iter().enumerate() {
                        ui.selectable_value(&mut pane.run, k, l);
                    }
                });
        });
        egui::ComboBox::from_label(format!("Pane {} display", i + 1))
            .selected_text(pane.display.label())
            .show_ui(ui, |ui| {
                for m in DisplayMode::ALL {
                    ui.selectable_value(&mut pane.display, m, m.label());
                }
            });
        if pane.display == DisplayMode::Debug {
            let views = s.runs[pane.run].engine.technique.debug_views();
            if views.is_empty() {
                ui.small("this technique has no debug views");
            } else {
                egui::ComboBox::from_label(format!("Pane {} debug view", i + 1))
                    .selected_text(views.get(pane.debug).map_or("?", |v| v.name))
                    .show_ui(ui, |ui| {
                        for (k, v) in views.iter().enumerate() {
                            ui.selectable_value(&mut pane.debug, k, v.name);
                        }
                    });
            }
        }
    }
}

/// Tonemapping: operator, exposure, the GT curve's sliders and the zone view.
fn display_section(s: &mut Session, ui: &mut egui::Ui) {
    ui.separator();
    ui.heading("Display");
    let tm = &mut s.preset.preset.tonemap;
    egui::ComboBox::from_label("Tonemapper")
        .selected_text(tm.operator.label())
        .show_ui(ui, |ui| {
            for op in Operator::ALL {
                ui.selectable_value(&mut tm.operator, op, op.label());
            }
        });
    ui.add(egui::Slider::new(&mut tm.exposure, -10.0..=10.0).text("Exposure (EV)"));
    if tm.operator == Operator::Gt {
        gt_sliders(ui, &mut tm.gt);
    }
    egui::ComboBox::from_label("Zone view")
        .selected_text(tm.view.label())
        .show_ui(ui, |ui| {
            for v in View::ALL {
                ui.selectable_value(&mut tm.view, v, v.label());
            }
        })
        .response
        .on_hover_text(
            "17 zones one stop apart, labelled by EV from zone 8, which is 18% grey after exposure. \
             Regions: toe blue, linear grey, shoulder red.",
        );
}

enum Action {
    Technique(String),
    Params(toml::Table),
    Budget(f64),
    Denoise(bool),
    Reset,
}

/// A plot's x coordinate from a convergence point.
type XAxis = fn(&super::session::ConvergencePoint) -> f64;

/// log10 with non-positive values dropped (log-log plots).
fn log_points(points: impl Iterator<Item = (f64, f64)>) -> PlotPoints<'static> {
    points
        .filter(|(x, y)| *x > 0.0 && *y > 0.0 && x.is_finite() && y.is_finite())
        .map(|(x, y)| [x.log10(), y.log10()])
        .collect::<Vec<_>>()
        .into()
}

fn pow10_label(mark: egui_plot::GridMark, _: &std::ops::RangeInclusive<f64>) -> String {
    let v = mark.value;
    if (v - v.round()).abs() < 1e-6 {
        format!("1e{}", v.round() as i64)
    } else {
        format!("{:.2e}", 10f64.powf(v))
    }
}

pub fn bottom_panel(app: &mut ViewerApp, ui: &mut egui::Ui) {
    egui::Panel::bottom("bottom")
        .resizable(true)
        .default_size(270.0)
        .show(ui, |ui| bottom_contents(app, ui));
}

fn bottom_contents(app: &mut ViewerApp, ui: &mut egui::Ui) {
    let Some(s) = app.session.as_ref() else {
        return;
    };
    let st = &mut app.panels;
    ui.horizontal(|ui| {
        ui.label("error:");
        ui.radio_value(&mut st.metric, PlotMetric::RelMse, "relMSE");
        ui.radio_value(&mut st.metric, PlotMetric::Mse, "MSE");
        ui.label("(log-log; against the reference at its current spp)");
        if let Some((x, y)) = st.inspected {
            ui.separator();
            ui.label(format!(
                "inspecting pixel ({x}, {y}); hover shows all panes"
            ));
        }
    });
    let metric = st.metric;
    let visible = s.visible_runs();
    let err = move |p: &super::session::ConvergencePoint| match metric {
        PlotMetric::RelMse => p.rel_mse,
        PlotMetric::Mse => p.mse,
    };
    let plot_h = (ui.available_height() - 10.0).max(80.0);
    ui.columns(4, |cols| {
        let axes: [(&str, XAxis); 3] = [
            ("GPU ms", |p| p.gpu_ms),
            ("rays/px", |p| p.rays_per_pixel),
            ("frames", |p| p.frame as f64),
        ];
        for (c, (xname, xf)) in axes.iter().enumerate() {
            let ui = &mut cols[c];
            ui.label(format!("error vs {xname}"));
            Plot::new(format!("plot-{xname}"))
                .height(plot_h - 20.0)
                .legend(Legend::default())
                .x_axis_label(*xname)
                .x_axis_formatter(pow10_label)
                .y_axis_formatter(pow10_label)
                .show(ui, |plot| {
                    for &i in &visible {
                        let run = &s.runs[i];
                        let pts = log_points(run.curve.iter().map(|p| (xf(p), err(p))));
                        plot.line(Line::new(run.label().to_string(), pts));
                    }
                });
        }
        let ui = &mut cols[3];
        ui.label("GPU time per pass (last frame)");
        egui::ScrollArea::vertical()
            .id_salt("timings")
            .show(ui, |ui| {
                egui::Grid::new("timings").striped(true).show(ui, |ui| {
                    for &i in &visible {
                        let run = &s.runs[i];
                        let Some(f) = &run.last_frame else { continue };
                        ui.strong(run.label());
                        ui.label(format!("{:.2} ms GPU", f.gpu_ms));
                        ui.end_row();
                        if f.timing != TimingSource::Timestamps {
                            ui.label("  timing");
                            ui.label(format!("{:?}", f.timing)).on_hover_text(
                                "no per-pass split: timestamps unavailable or implausible on \
                                 this driver; GPU time is the frame's waited wall time",
                            );
                            ui.end_row();
                        }
                        for (pass, ms) in &f.gpu_ms_by_pass {
                            ui.label(format!("  {pass}"));
                            ui.label(format!("{ms:.2} ms"));
                            ui.end_row();
                        }
                        let pixels = (run.engine.extent[0] * run.engine.extent[1]) as f64;
                        let rays_per_frame = run.measured_rays_per_pixel().unwrap_or(0.0) * pixels;
                        ui.label("  frame (wall)");
                        ui.label(format!("{:.1} ms", f.wall_ms));
                        ui.end_row();
                        ui.label("  rays/s");
                        ui.label(format!(
                            "{:.2} M",
                            rays_per_frame / (f.gpu_ms.max(1e-6) * 1e-3) / 1e6
                        ));
                        ui.end_row();
                        ui.label("  error");
                        ui.label(
                            run.error
                                .map_or("-".into(), |m| format!("relMSE {:.2e}", m.rel_mse)),
                        );
                        ui.end_row();
                    }
                });
            });
    });
}

/// Sliders for the GT curve's parameters. Values a preset set outside the sliders' ranges stay
/// as they are until edited; an edit that breaks `GtParams::check` (P below m) pulls m and b
/// back inside.
fn gt_sliders(ui: &mut egui::Ui, g: &mut GtParams) {
    gt_slider(ui, &mut g.max_brightness, 0.25..=4.0, "GT P max brightness");
    gt_slider(ui, &mut g.contrast, 0.1..=3.0, "GT a contrast");
    let m_max = 0.95 * g.max_brightness;
    gt_slider(ui, &mut g.linear_start, 0.01..=m_max, "GT m linear start");
    gt_slider(ui, &mut g.linear_length, 0.0..=0.95, "GT l linear length");
    gt_slider(
        ui,
        &mut g.black_tightness,
        0.1..=3.0,
        "GT c black tightness",
    );
    let b_max = 0.5 * g.linear_start;
    gt_slider(ui, &mut g.pedestal, 0.0..=b_max, "GT b pedestal");
    if g.check().is_err() {
        g.linear_start = g.linear_start.clamp(0.01, m_max);
        g.pedestal = g.pedestal.clamp(0.0, 0.5 * g.linear_start);
    }
    if ui.button("GT defaults (Uchimura)").clicked() {
        *g = GtParams::default();
    }
}

fn gt_slider(ui: &mut egui::Ui, v: &mut f32, range: std::ops::RangeInclusive<f32>, text: &str) {
    let slider = egui::Slider::new(v, range).clamping(egui::SliderClamping::Edits);
    ui.add(slider.text(text));
}
