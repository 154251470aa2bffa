//! # The viewer (`gilab` with no subcommand)
//!
//! An eframe app on wgpu that shares eframe's device with the engines. The model lives in
//! [`session::Session`] (runs, reference, camera, hot reload) and knows nothing of egui; this
//! module owns the egui side: panes and their textures ([`views`]), the side and bottom panels
//! ([`panels`]), camera input ([`camera`]), file watching ([`watch`]) and A/B screenshots
//! ([`screenshot`]).
//!
//! Frame pacing: each UI frame renders technique frames round-robin until a wall-time budget
//! is spent (at least one), so the UI stays interactive on slow adapters while every visible
//! technique and the background reference make progress.

pub mod brdf_window;
pub mod camera;
pub mod headless;
pub mod panels;
pub mod screenshot;
pub mod session;
pub mod views;
pub mod watch;

use crate::gpu::{self, shaders::ShaderLibrary, BackendChoice, Gpu};
use crate::preset::LoadedPreset;
use anyhow::{bail, Result};
use session::Session;
use std::path::PathBuf;
use std::sync::Arc;

/// What the viewer starts with.
pub struct ViewerOptions {
    pub preset: LoadedPreset,
    pub shaders: ShaderLibrary,
    /// Folder listed in the preset picker and watched for changes.
    pub presets_dir: PathBuf,
    /// Where A/B screenshots go.
    pub out_dir: PathBuf,
    /// Reference cache (the same folder `gilab reference` uses by default).
    pub cache_dir: PathBuf,
    /// Watch shaders, presets and the scene file for changes.
    pub watch: bool,
    /// Take a screenshot of the whole window this many seconds after start, write it to the
    /// path and close (`gilab view --window-shot-after S --window-shot PATH`).
    pub window_shot: Option<(f64, PathBuf)>,
    /// Used only when eframe gives no wgpu device (never with the wgpu renderer).
    pub backend: BackendChoice,
}

impl ViewerOptions {
    pub fn new(preset: LoadedPreset) -> ViewerOptions {
        ViewerOptions {
            preset,
            shaders: ShaderLibrary::discover(),
            presets_dir: PathBuf::from("presets"),
            out_dir: PathBuf::from("out/viewer"),
            cache_dir: PathBuf::from("cache/reference"),
            watch: true,
            window_shot: None,
            backend: BackendChoice::Auto,
        }
    }
}

pub struct ViewerApp {
    /// None when start-up failed; the window then shows why.
    pub session: Option<Session>,
    pub startup_error: Option<String>,
    pub views: views::PaneTextures,
    pub panels: panels::PanelState,
    pub watcher: Option<watch::FileWatcher>,
    pub presets_dir: PathBuf,
    pub out_dir: PathBuf,
    /// Wall milliseconds of rendering per UI frame before the UI takes the thread back
    /// (the least; see `max_ui_share`).
    pub frame_budget_ms: f64,
    /// Largest share of time the UI's own painting may take while the user is not
    /// interacting: when painting is slow (a CPU rasteriser), more technique frames are
    /// rendered per UI frame. 1.0 turns this off.
    pub max_ui_share: f64,
    last_show_start: Option<std::time::Instant>,
    /// Smoothed time between UI frames spent outside `show` (egui painting, presenting).
    outside_ms: f64,
    /// Set by tests that step rendering themselves.
    pub render_in_ui: bool,
    pub last_screenshot: Option<PathBuf>,
    /// A whole-window screenshot asked for (F11, the button or `window_shot`): its pixels
    /// arrive through this channel a frame later, and go to this path.
    window_shot_pending: Option<(std::sync::mpsc::Receiver<Arc<egui::ColorImage>>, PathBuf)>,
    /// `ViewerOptions::window_shot`, and when the viewer started.
    auto_window_shot: Option<(f64, PathBuf)>,
    started: std::time::Instant,
    /// UI frame times (ms) of the last frames, for the status line.
    pub ui_frame_ms: f64,
    /// egui's wgpu renderer, to draw the panes' GPU textures (None: CPU upload path).
    pub egui_renderer: Option<views::EguiRenderer>,
    /// The BRDF slice of the material under the cursor (opened from the side panel).
    pub brdf_window: brdf_window::BrdfWindow,
}

impl ViewerApp {
    /// Creates the viewer on eframe's wgpu device (or a headless one when eframe has none).
    pub fn new(cc: &eframe::CreationContext<'_>, options: ViewerOptions) -> ViewerApp {
        let gpu = match &cc.wgpu_render_state {
            Some(rs) => Gpu::check_adapter(&rs.adapter).map(|()| {
                Gpu::from_device(
                    rs.instance.clone(),
                    rs.adapter.clone(),
                    rs.device.clone(),
                    rs.queue.clone(),
                )
            }),
            None => Gpu::new(options.backend),
        };
        let mut app = Self::with_gpu(gpu.map(Arc::new), options);
        app.egui_renderer = cc.wgpu_render_state.as_ref().map(|rs| rs.renderer.clone());
        app
    }

    pub fn with_gpu(gpu: Result<Arc<Gpu>>, options: ViewerOptions) -> ViewerApp {
        let session = gpu.and_then(|gpu| {
            log::info!("viewer adapter: {}", gpu.summary);
            Session::new(
                gpu,
                options.shaders.clone(),
                options.preset.clone(),
                options.cache_dir.clone(),
            )
        });
        let (session, startup_error) = match session {
            Ok(s) => (Some(s), None),
            Err(e) => (None, Some(format!("{e:#}"))),
        };
        let watcher = if options.watch {
            let mut paths = vec![options.presets_dir.clone()];
            paths.extend(options.shaders.root().map(|p| p.to_path_buf()));
            match watch::FileWatcher::new(&paths) {
                Ok(mut w) => {
                    if let Some(p) = options.preset.scene_path() {
                        w.add(&p);
                    }
                    if let Some(p) = &options.preset.path {
                        w.add(p);
                    }
                    Some(w)
                }
                Err(e) => {
                    log::warn!("hot reload off: cannot watch files: {e}");
                    None
                }
            }
        } else {
            None
        };
        let panels = panels::PanelState::new(&options);
        ViewerApp {
            session,
            startup_error,
            views: views::PaneTextures::default(),
            panels,
            watcher,
            presets_dir: options.presets_dir,
            out_dir: options.out_dir,
            frame_budget_ms: 50.0,
            max_ui_share: 0.2,
            last_show_start: None,
            outside_ms: 0.0,
            render_in_ui: true,
            last_screenshot: None,
            window_shot_pending: None,
            auto_window_shot: options.window_shot,
            started: std::time::Instant::now(),
            ui_frame_ms: 0.0,
            egui_renderer: None,
            brdf_window: Default::default(),
        }
    }

    /// Drains file events and applies them (called every UI frame; tests call it too).
    pub fn poll_file_changes(&mut self) {
        let (Some(w), Some(s)) = (&mut self.watcher, &mut self.session) else {
            return;
        };
        // The scene file of whatever preset is loaded now (adding is idempotent).
        if let Some(p) = s.preset.scene_path() {
            w.add(&p);
        }
        let changed = w.drain();
        if !changed.is_empty() {
            s.handle_changed_files(&changed);
        }
    }

    /// This UI frame's rendering budget: the set minimum while the user interacts (so the UI
    /// answers), otherwise enough that painting stays under `max_ui_share` of the time.
    pub fn render_budget_ms(&self, ui: &egui::Ui) -> f64 {
        let interacting = ui.input(|i| {
            i.pointer.any_down()
                || !i.keys_down.is_empty()
                || i.smooth_scroll_delta != egui::Vec2::ZERO
        });
        let share = self.max_ui_share.clamp(0.01, 1.0);
        if interacting || share >= 1.0 {
            self.frame_budget_ms
        } else {
            self.frame_budget_ms
                .max(self.outside_ms * (1.0 / share - 1.0))
        }
    }

    /// Saves the visible panes (button and F12).
    pub fn save_screenshot(&mut self) {
        let Some(s) = &mut self.session else { return };
        match screenshot::save_ab(s, &self.out_dir) {
            Ok(dir) => {
                s.note(format!("A/B screenshot saved to {}", dir.display()));
                s.errors.remove("screenshot");
                self.last_screenshot = Some(dir);
            }
            Err(e) => {
                s.errors.insert("screenshot".into(), format!("{e:#}"));
            }
        }
    }
}

impl ViewerApp {
    /// Asks egui for a screenshot of the whole window (panels, panes, plots), written to `path`
    /// (default: `out/viewer/window-<time>.png`) when its pixels arrive.
    pub fn request_window_shot(&mut self, ctx: &egui::Context, path: Option<PathBuf>) {
        let path = path.unwrap_or_else(|| {
            let stamp = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map(|d| d.as_millis())
                .unwrap_or(0);
            self.out_dir.join(format!("window-{stamp}.png"))
        });
        let (tx, rx) = std::sync::mpsc::channel();
        ctx.request_screenshot(move |image| {
            let _ = tx.send(image);
        });
        self.window_shot_pending = Some((rx, path));
    }

    /// Writes a window screenshot whose pixels have arrived; closes the window after an
    /// automatic one.
    fn poll_window_shot(&mut self, ctx: &egui::Context) {
        let auto_due = self
            .auto_window_shot
            .as_ref()
            .is_some_and(|(after, _)| self.started.elapsed().as_secs_f64() >= *after);
        if auto_due && self.window_shot_pending.is_none() {
            let path = self.auto_window_shot.as_ref().map(|a| a.1.clone());
            self.request_window_shot(ctx, path);
        }
        let Some((rx, path)) = &self.window_shot_pending else {
            return;
        };
        ctx.request_repaint();
        let Ok(image) = rx.try_recv() else {
            return;
        };
        let result = screenshot::save_window(&image, path);
        let path = path.clone();
        self.window_shot_pending = None;
        let s = self.session.as_mut();
        match result {
            Ok(()) => {
                if let Some(s) = s {
                    s.note(format!("window screenshot saved to {}", path.display()));
                    s.errors.remove("screenshot");
                }
                self.last_screenshot = Some(path);
            }
            Err(e) => {
                log::error!("{e:#}");
                if let Some(s) = s {
                    s.errors.insert("screenshot".into(), format!("{e:#}"));
                }
            }
        }
        if auto_due {
            ctx.send_viewport_cmd(egui::ViewportCommand::Close);
        }
    }
}

impl eframe::App for ViewerApp {
    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        self.show(ui);
    }
}

impl ViewerApp {
    /// One UI frame: file events, rendering work, panels and panes.
    pub fn show(&mut self, ui: &mut egui::Ui) {
        let start = std::time::Instant::now();
        if let Some(err) = &self.startup_error {
            egui::CentralPanel::default().show(ui, |ui| {
                ui.heading("gilab could not start the viewer");
                ui.label(err.as_str());
                ui.label("The headless commands (gilab shot, bench, compare) may still work.");
            });
            return;
        }
        self.poll_file_changes();
        if let Some(prev) = self.last_show_start.replace(start) {
            let outside = (start - prev).as_secs_f64() * 1e3 - self.ui_frame_ms;
            self.outside_ms = 0.7 * self.outside_ms + 0.3 * outside.max(0.0);
        }
        if self.render_in_ui {
            let budget = self.render_budget_ms(ui);
            if let Some(s) = &mut self.session {
                s.step(budget);
            }
        }
        if ui.input(|i| i.key_pressed(egui::Key::F12)) {
            self.save_screenshot();
        }
        if ui.input(|i| i.key_pressed(egui::Key::F11)) {
            self.request_window_shot(ui.ctx(), None);
        }
        self.poll_window_shot(ui.ctx());
        panels::side_panel(self, ui);
        panels::bottom_panel(self, ui);
        views::central_panel(self, ui);
        if let Some(s) = &self.session {
            self.brdf_window.show(ui.ctx(), s, self.panels.inspected);
        }
        self.ui_frame_ms = start.elapsed().as_secs_f64() * 1e3;
        if self.session.as_ref().is_some_and(|s| !s.paused) {
            ui.ctx().request_repaint();
        }
    }
}

/// eframe's wgpu setup with gilab's device requirements (adapter limits, timestamp queries)
/// and adapter choice (Vulkan preferred, GL fallback, `GILAB_BACKEND`).
pub fn wgpu_setup(backend: BackendChoice) -> egui_wgpu::WgpuSetup {
    let backend = backend.resolve_env().unwrap_or_default();
    let mut setup = egui_wgpu::WgpuSetupCreateNew::without_display_handle();
    setup.instance_descriptor.backends = backend
        .order()
        .iter()
        .fold(wgpu::Backends::empty(), |a, b| a | *b);
    let order: Vec<wgpu::Backends> = backend.order().to_vec();
    setup.native_adapter_selector = Some(Arc::new(move |adapters, surface| {
        let usable = |a: &&wgpu::Adapter| {
            Gpu::check_adapter(a).is_ok() && surface.is_none_or(|s| a.is_surface_supported(s))
        };
        for backends in &order {
            let best = adapters
                .iter()
                .filter(|a| backends.contains(wgpu::Backends::from(a.get_info().backend)))
                .filter(usable)
                .max_by_key(|a| gpu::adapter_rank(a));
            if let Some(a) = best {
                return Ok(a.clone());
            }
        }
        Err(
            "no adapter with compute shaders and 9 storage buffers per stage; install \
             mesa-vulkan-drivers or try GILAB_BACKEND=gl"
                .to_string(),
        )
    }));
    setup.device_descriptor = Arc::new(gpu::device_descriptor);
    egui_wgpu::WgpuSetup::CreateNew(setup)
}

/// Opens the viewer window; returns when it is closed.
pub fn run(options: ViewerOptions) -> Result<()> {
    if std::env::var_os("DISPLAY").is_none() && std::env::var_os("WAYLAND_DISPLAY").is_none() {
        bail!(
            "no display: the viewer needs X11 or Wayland (DISPLAY / WAYLAND_DISPLAY unset). \
             Run it under Xvfb (`Xvfb :99 & DISPLAY=:99 gilab`), or use the headless \
             commands: gilab shot, reference, compare, bench"
        );
    }
    gpu::ensure_runtime_dir();
    let native = eframe::NativeOptions {
        renderer: eframe::Renderer::Wgpu,
        viewport: egui::ViewportBuilder::default()
            .with_title("gilab")
            .with_inner_size([1400.0, 900.0]),
        wgpu_options: egui_wgpu::WgpuConfiguration {
            wgpu_setup: wgpu_setup(options.backend),
            ..Default::default()
        },
        ..Default::default()
    };
    eframe::run_native(
        "gilab",
        native,
        Box::new(move |cc| Ok(Box::new(ViewerApp::new(cc, options)))),
    )
    .map_err(|e| anyhow::anyhow!("viewer: {e}"))
}
