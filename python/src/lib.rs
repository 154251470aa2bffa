//! `gilab._gilab`: the Python extension over the gilab library. A thin layer: every call goes
//! to the functions the CLI uses (`jobs`, `compare`, `experiment::run`); structured values
//! cross as JSON (parsed by the pure-Python package `gilab`), images as numpy arrays. The GIL is
//! released while the GPU works.

use anyhow::Context;
use gilab::compare::{flip, io, metrics, tonemap, Image};
use gilab::experiment::{rows, run};
use gilab::gpu::{BackendChoice, Gpu};
use gilab::jobs::{self, SceneOnGpu};
use gilab::preset::experiment::Event;
use gilab::preset::{LoadedPreset, Overrides, TechniqueEntry};
use gilab::scene::Camera;
use numpy::ndarray::{Array2, Array3};
use numpy::{IntoPyArray, PyArray2, PyArray3, PyReadonlyArrayDyn};
use pyo3::create_exception;
use pyo3::exceptions::{PyFileNotFoundError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;
use std::sync::Arc;

create_exception!(
    _gilab,
    GilabError,
    PyRuntimeError,
    "An error from the gilab library (its message is the CLI's)."
);

fn file_missing(e: &anyhow::Error) -> bool {
    e.chain().any(|c| {
        c.downcast_ref::<std::io::Error>()
            .is_some_and(|io| io.kind() == std::io::ErrorKind::NotFound)
    })
}

/// The library's error as a Python exception with the CLI's message: FileNotFoundError where
/// a file is missing, GilabError otherwise (no adapter, a GPU fault).
fn py_err(e: anyhow::Error) -> PyErr {
    if file_missing(&e) {
        PyFileNotFoundError::new_err(format!("{e:#}"))
    } else {
        GilabError::new_err(format!("{e:#}"))
    }
}

/// Bad input the library rejected (unknown technique or scene, parameter out of range, bad
/// preset): ValueError, or FileNotFoundError where a file is missing.
fn value_err(e: anyhow::Error) -> PyErr {
    if file_missing(&e) {
        PyFileNotFoundError::new_err(format!("{e:#}"))
    } else {
        PyValueError::new_err(format!("{e:#}"))
    }
}

/// `value_err` for a file input whose reader does not keep the io::Error (EXR).
fn file_err(path: &std::path::Path, e: anyhow::Error) -> PyErr {
    if path.exists() {
        value_err(e)
    } else {
        PyFileNotFoundError::new_err(format!("{e:#}"))
    }
}

fn json_err(e: serde_json::Error) -> PyErr {
    PyValueError::new_err(format!("bad JSON from the Python layer: {e}"))
}

/// A JSON object (from Python) as a TOML table: parameters, events, whole presets.
fn toml_table(json: &str) -> PyResult<toml::Table> {
    let value: serde_json::Value = serde_json::from_str(json).map_err(json_err)?;
    toml::Table::try_from(value)
        .map_err(|e| PyValueError::new_err(format!("not representable in a preset: {e}")))
}

fn image_from_array(a: &PyReadonlyArrayDyn<'_, f32>, what: &str) -> PyResult<Image> {
    let view = a.as_array();
    let shape = view.shape();
    if shape.len() != 3 || shape[2] != 3 {
        return Err(PyValueError::new_err(format!(
            "{what}: expected a float32 array of shape (height, width, 3), got {shape:?}"
        )));
    }
    Ok(Image {
        width: shape[1] as u32,
        height: shape[0] as u32,
        rgb: view.iter().copied().collect(),
    })
}

fn image_to_array<'py>(py: Python<'py>, image: Image) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let (w, h) = (image.width as usize, image.height as usize);
    let array = Array3::from_shape_vec((h, w, 3), image.rgb)
        .map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
    Ok(array.into_pyarray(py))
}

/// Progress of long calls goes to this Python callable: (label, position, total, done).
#[pyfunction]
#[pyo3(signature = (callback=None))]
fn set_progress(callback: Option<Py<PyAny>>) {
    let sink = callback.map(|cb| -> jobs::ProgressSink {
        Arc::new(move |label: &str, pos: u64, total: u64, done: bool| {
            Python::attach(|py| {
                // A failing progress display must not fail the render.
                if let Err(e) = cb.call1(py, (label, pos, total, done)) {
                    e.print(py);
                }
            })
        })
    });
    jobs::set_progress_sink(sink);
}

/// The registered techniques as JSON: [{id, what}].
#[pyfunction]
fn techniques_json() -> String {
    let list: Vec<serde_json::Value> = gilab::techniques::REGISTRY
        .iter()
        .map(|t| serde_json::json!({"id": t.id, "what": t.what}))
        .collect();
    serde_json::Value::from(list).to_string()
}

/// A technique's parameter specs as JSON (the table behind `gilab params`).
#[pyfunction]
fn params_json(technique: &str) -> PyResult<String> {
    let t = gilab::techniques::create_technique(technique).map_err(value_err)?;
    let defaults = t.params();
    let specs: Vec<serde_json::Value> = t
        .param_set()
        .specs()
        .iter()
        .map(|s| {
            let (min, max) = s.range();
            let choices = match s.kind {
                gilab::render::params::ParamKind::Choice(c) => Some(c.to_vec()),
                _ => None,
            };
            // The default in the parameter's own type: a number, a switch, a choice's name.
            let default = match (&choices, defaults.get(s.name)) {
                (Some(c), _) => serde_json::json!(c.get(s.default as usize)),
                (None, Some(v)) => serde_json::to_value(v).unwrap_or(serde_json::Value::Null),
                (None, None) => serde_json::json!(s.default),
            };
            serde_json::json!({
                "name": s.name,
                "doc": s.what,
                "higher": s.higher,
                "lower": s.lower,
                "kind": match s.kind {
                    gilab::render::params::ParamKind::Int { .. } => "int",
                    gilab::render::params::ParamKind::Float { .. } => "float",
                    gilab::render::params::ParamKind::Bool => "bool",
                    gilab::render::params::ParamKind::Choice(_) => "choice",
                },
                "min": min,
                "max": max,
                "choices": choices,
                "default": default,
            })
        })
        .collect();
    Ok(serde_json::Value::from(specs).to_string())
}

/// MSE, relMSE and SMAPE of `image` against `reference` (`gilab compare`'s code).
#[pyfunction]
fn error_metrics(
    image: PyReadonlyArrayDyn<'_, f32>,
    reference: PyReadonlyArrayDyn<'_, f32>,
) -> PyResult<(f64, f64, f64)> {
    let a = image_from_array(&image, "image")?;
    let b = image_from_array(&reference, "reference")?;
    let m = metrics::compare(&a, &b).map_err(value_err)?;
    Ok((m.mse, m.rel_mse, m.smape))
}

fn tonemap_settings(json: Option<&str>) -> PyResult<tonemap::Settings> {
    match json {
        None => Ok(tonemap::Settings::default()),
        Some(j) => {
            let table = toml_table(j)?;
            table
                .try_into()
                .map_err(|e| PyValueError::new_err(format!("tonemap settings: {e}")))
        }
    }
}

/// Mean LDR-FLIP after the display transform (default: `gilab compare`'s ACES at 0 EV).
#[pyfunction]
#[pyo3(signature = (image, reference, tonemap_json=None))]
fn ldr_flip(
    py: Python<'_>,
    image: PyReadonlyArrayDyn<'_, f32>,
    reference: PyReadonlyArrayDyn<'_, f32>,
    tonemap_json: Option<&str>,
) -> PyResult<f64> {
    let a = image_from_array(&image, "image")?;
    let b = image_from_array(&reference, "reference")?;
    let tm = tonemap_settings(tonemap_json)?;
    py.detach(|| flip::ldr_flip(&a, &b, &tm)).map_err(value_err)
}

/// 8-bit sRGB (H×W×3) of the display transform.
#[pyfunction]
#[pyo3(signature = (image, tonemap_json=None))]
fn tonemap_srgb8<'py>(
    py: Python<'py>,
    image: PyReadonlyArrayDyn<'py, f32>,
    tonemap_json: Option<&str>,
) -> PyResult<Bound<'py, PyArray3<u8>>> {
    let img = image_from_array(&image, "image")?;
    let tm = tonemap_settings(tonemap_json)?;
    let rgba = tonemap::to_srgb8(&img, &tm);
    let rgb: Vec<u8> = rgba
        .chunks_exact(4)
        .flat_map(|p| [p[0], p[1], p[2]])
        .collect();
    let array = Array3::from_shape_vec((img.height as usize, img.width as usize, 3), rgb)
        .map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
    Ok(array.into_pyarray(py))
}

#[pyfunction]
fn read_exr<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let image = io::read_exr(&path).map_err(|e| file_err(&path, e))?;
    image_to_array(py, image)
}

/// Writes a linear EXR exactly as `gilab shot` does.
#[pyfunction]
fn write_exr(path: PathBuf, image: PyReadonlyArrayDyn<'_, f32>) -> PyResult<()> {
    let img = image_from_array(&image, "image")?;
    io::write_exr(&path, &img).map_err(py_err)
}

/// Writes a tonemapped PNG exactly as `gilab shot` does.
#[pyfunction]
#[pyo3(signature = (path, image, tonemap_json=None))]
fn write_png(
    path: PathBuf,
    image: PyReadonlyArrayDyn<'_, f32>,
    tonemap_json: Option<&str>,
) -> PyResult<()> {
    let img = image_from_array(&image, "image")?;
    let tm = tonemap_settings(tonemap_json)?;
    io::write_png(&path, &img, &tm).map_err(py_err)
}

fn load_preset(
    path: Option<PathBuf>,
    text_json: Option<&str>,
    overrides: &Overrides,
) -> PyResult<LoadedPreset> {
    let mut p = match text_json {
        Some(json) => {
            let table = toml_table(json)?;
            let text = toml::to_string(&table)
                .map_err(|e| PyValueError::new_err(format!("preset: {e}")))?;
            LoadedPreset::from_text(&text, None).map_err(value_err)?
        }
        None => LoadedPreset::load_or_default(path.as_deref()).map_err(value_err)?,
    };
    p.apply(overrides).map_err(value_err)?;
    Ok(p)
}

/// Runs a convergence experiment as `gilab converge` does; returns (out dir, rows JSON) read
/// back from what it wrote (the Python side reads summary.json itself: Python's JSON parser
/// keeps every digit, serde_json's default one may round the last).
#[pyfunction]
#[pyo3(signature = (path=None, preset_json=None, out=None, cache=PathBuf::from("cache/reference"), set=Vec::new(), backend=None, quiet=false))]
#[allow(clippy::too_many_arguments)]
fn converge(
    py: Python<'_>,
    path: Option<PathBuf>,
    preset_json: Option<&str>,
    out: Option<PathBuf>,
    cache: PathBuf,
    set: Vec<String>,
    backend: Option<&str>,
    quiet: bool,
) -> PyResult<(String, String)> {
    let overrides = Overrides {
        set,
        ..Overrides::default()
    };
    let p = load_preset(path, preset_json, &overrides)?;
    let backend = parse_backend(backend)?;
    let out = out.unwrap_or_else(|| PathBuf::from("out/converge").join(run::experiment_name(&p)));
    let result = py.detach(|| -> anyhow::Result<Vec<rows::Row>> {
        let gpu = Arc::new(Gpu::new(backend)?);
        let opts = run::ConvergeOptions {
            out: out.clone(),
            cache,
            shard: None,
            quiet,
        };
        run::converge(gpu, &p, &opts)?;
        Ok(rows::read_output_dir(&out)?.1)
    });
    let rows = serde_json::to_string(&result.map_err(py_err)?).map_err(json_err)?;
    Ok((out.display().to_string(), rows))
}

fn parse_backend(backend: Option<&str>) -> PyResult<BackendChoice> {
    backend
        .unwrap_or("auto")
        .parse::<BackendChoice>()
        .map_err(value_err)
}

/// One GPU device and a loaded, uploaded scene; renders any technique on it.
#[pyclass(module = "gilab._gilab")]
struct Session {
    gpu: Option<Arc<Gpu>>,
    preset: LoadedPreset,
    /// None once closed: the scene's GPU buffers go with the device.
    scene: Option<SceneOnGpu>,
    /// Scene edits applied since loading (a camera among them moves the preset's camera instead);
    /// reference cache keys include them, as `converge` keys edited states.
    events: Vec<Event>,
}

impl Session {
    fn gpu(&self) -> PyResult<Arc<Gpu>> {
        self.gpu
            .clone()
            .ok_or_else(|| GilabError::new_err("the session is closed"))
    }

    fn scene(&self) -> PyResult<&SceneOnGpu> {
        self.scene
            .as_ref()
            .ok_or_else(|| GilabError::new_err("the session is closed"))
    }

    fn scene_mut(&mut self) -> PyResult<&mut SceneOnGpu> {
        self.scene
            .as_mut()
            .ok_or_else(|| GilabError::new_err("the session is closed"))
    }

    /// The preset's scene loaded again with the session's edits and camera.
    fn reload_scene(&mut self, py: Python<'_>) -> PyResult<()> {
        let gpu = self.gpu()?;
        let p = self.preset.clone();
        let events = self.events.clone();
        let camera = self.scene()?.camera;
        let scene = py
            .detach(|| -> anyhow::Result<SceneOnGpu> {
                let mut scene = p.load_scene()?;
                let mut cam = camera;
                for e in &events {
                    e.apply(&mut scene, &mut cam)?;
                }
                scene.validate()?;
                let gpu_scene = gilab::scene::gpu_scene::GpuScene::upload(&gpu, &scene);
                Ok(SceneOnGpu {
                    scene: Arc::new(scene),
                    gpu_scene: Arc::new(gpu_scene),
                    camera,
                })
            })
            .map_err(value_err)?;
        self.scene = Some(scene);
        Ok(())
    }

    /// The reference's cache key: the CLI's for this preset and camera, with the session's
    /// edits hashed in as `converge` does for an edited state.
    fn reference_key(&self, p: &LoadedPreset) -> PyResult<String> {
        let base = jobs::reference_key_for_camera(p, &self.scene()?.camera);
        if self.events.is_empty() {
            return Ok(base);
        }
        run::edited_reference_key(&base, &self.events).map_err(py_err)
    }

    /// The session's preset with one technique entry, checked by the library before any GPU
    /// work (unknown technique, bad parameters), and the entry.
    fn entry_preset(
        &self,
        technique: &str,
        seed: Option<u32>,
        params_json: &str,
        denoise: bool,
        budget: Option<f64>,
    ) -> PyResult<(LoadedPreset, TechniqueEntry)> {
        if budget.is_some_and(|b| !(b.is_finite() && b > 0.0)) {
            return Err(PyValueError::new_err(
                "budget must be a positive number of rays per pixel per frame",
            ));
        }
        let entry = TechniqueEntry {
            params: toml_table(params_json)?,
            budget,
            denoise,
            ..TechniqueEntry::new(technique)
        };
        gilab::techniques::create_technique(&entry.name)
            .and_then(|mut t| {
                t.set_params_from_table(&entry.params)
                    .with_context(|| format!("technique '{}'", entry.name))
            })
            .map_err(value_err)?;
        let mut p = self.preset.clone();
        if let Some(seed) = seed {
            p.preset.render.seed = seed;
        }
        p.preset.techniques = vec![entry.clone()];
        Ok((p, entry))
    }

    fn reference_preset(&self, spp: Option<u32>) -> LoadedPreset {
        let mut p = self.preset.clone();
        if let Some(spp) = spp {
            p.preset.render.reference_spp = spp;
        }
        p
    }
}

#[pymethods]
impl Session {
    #[new]
    #[pyo3(signature = (preset=None, preset_json=None, scene=None, size=None, set=Vec::new(), backend=None))]
    fn new(
        py: Python<'_>,
        preset: Option<PathBuf>,
        preset_json: Option<&str>,
        scene: Option<String>,
        size: Option<String>,
        set: Vec<String>,
        backend: Option<&str>,
    ) -> PyResult<Session> {
        let overrides = Overrides {
            scene,
            size,
            set,
            ..Overrides::default()
        };
        let mut p = load_preset(preset, preset_json, &overrides)?;
        let backend = parse_backend(backend)?;
        let gpu = py
            .detach(|| Gpu::new(backend).map(Arc::new))
            .map_err(py_err)?;
        // A bad scene (unknown name, missing or broken file) is the caller's input.
        let scene = py
            .detach(|| SceneOnGpu::load(&gpu, &p))
            .map_err(value_err)?;
        // The camera is part of the preset from now on: references key on it as the CLI's do.
        p.preset.camera = Some(scene.camera);
        Ok(Session {
            gpu: Some(gpu),
            preset: p,
            scene: Some(scene),
            events: Vec::new(),
        })
    }

    /// Releases the GPU device (renders after this raise).
    fn close(&mut self) {
        self.scene = None;
        self.gpu = None;
    }

    #[getter]
    fn closed(&self) -> bool {
        self.gpu.is_none()
    }

    #[getter]
    fn size(&self) -> (u32, u32) {
        let [w, h] = self.preset.preset.render.size;
        (w, h)
    }

    #[getter]
    fn seed(&self) -> u32 {
        self.preset.preset.render.seed
    }

    #[getter]
    fn scene_name(&self) -> String {
        self.scene
            .as_ref()
            .map_or_else(String::new, |s| s.scene.name.clone())
    }

    fn adapter_json(&self) -> PyResult<String> {
        serde_json::to_string(&self.gpu()?.summary).map_err(json_err)
    }

    fn preset_json(&self) -> PyResult<String> {
        serde_json::to_string(&self.preset.preset).map_err(json_err)
    }

    fn scene_features_json(&self) -> PyResult<String> {
        serde_json::to_string(&self.scene()?.gpu_scene.data.features).map_err(json_err)
    }

    fn camera_json(&self) -> PyResult<String> {
        serde_json::to_string(&self.scene()?.camera).map_err(json_err)
    }

    fn set_camera_json(&mut self, json: &str) -> PyResult<()> {
        let camera = camera_from_json(json)?;
        self.scene_mut()?.camera = camera;
        self.preset.preset.camera = Some(camera);
        Ok(())
    }

    /// Sets a preset key (`scene.params.albedo`, `render.seed`, ...) as `--set KEY=VALUE` does
    /// (VALUE a TOML literal); the scene is loaded again when the key is under `scene.`.
    fn set_preset_value(&mut self, py: Python<'_>, key: &str, value: &str) -> PyResult<()> {
        let mut p = self.preset.clone();
        p.apply(&Overrides {
            set: vec![format!("{key}={value}")],
            ..Overrides::default()
        })
        .map_err(value_err)?;
        let old = std::mem::replace(&mut self.preset, p);
        if key.starts_with("scene.") {
            if let Err(e) = self.reload_scene(py) {
                self.preset = old;
                return Err(e);
            }
        }
        Ok(())
    }

    /// A scripted scene edit (`[[experiment.event]]`'s fields: material + emissive /
    /// base_color / roughness / metallic, light + position / intensity, camera), applied to the
    /// session's scene for the renders that follow.
    fn apply_event_json(&mut self, py: Python<'_>, json: &str) -> PyResult<()> {
        let mut event = event_from_json(json)?;
        // Check it against the scene first (names, light indices), leaving the session as it was.
        let mut probe = (*self.scene()?.scene).clone();
        let mut camera = self.scene()?.camera;
        event.apply(&mut probe, &mut camera).map_err(value_err)?;
        if let Some(c) = event.camera.take() {
            self.scene_mut()?.camera = c;
            self.preset.preset.camera = Some(c);
        }
        if event.material.is_some() || event.light.is_some() {
            self.events.push(event);
            self.reload_scene(py)?;
        }
        Ok(())
    }

    fn events_json(&self) -> PyResult<String> {
        serde_json::to_string(&self.events).map_err(json_err)
    }

    /// Renders `frames` frames of `technique` as `gilab shot` does (one fresh engine on the
    /// session's scene); returns a dict of arrays and JSON.
    #[pyo3(signature = (technique, frames=1, seed=None, params_json="{}", denoise=false, budget=None, clock_check=false, progress=false))]
    #[allow(clippy::too_many_arguments)]
    fn render<'py>(
        &self,
        py: Python<'py>,
        technique: &str,
        frames: u32,
        seed: Option<u32>,
        params_json: &str,
        denoise: bool,
        budget: Option<f64>,
        clock_check: bool,
        progress: bool,
    ) -> PyResult<Bound<'py, PyDict>> {
        if frames == 0 {
            return Err(PyValueError::new_err("frames must be at least 1"));
        }
        let gpu = self.gpu()?;
        let (p, entry) = self.entry_preset(technique, seed, params_json, denoise, budget)?;
        let scene = self.scene()?.clone();
        let rendered = py
            .detach(|| render_entry(gpu, &p, &scene, &entry, frames, clock_check, !progress))
            .map_err(py_err)?;
        rendered.into_dict(py, p.preset.render.size)
    }

    /// An engine for `technique` kept for `Run.step` calls (the parameters checked first).
    #[pyo3(signature = (technique, seed=None, params_json="{}", denoise=false, budget=None))]
    fn start(
        &self,
        py: Python<'_>,
        technique: &str,
        seed: Option<u32>,
        params_json: &str,
        denoise: bool,
        budget: Option<f64>,
    ) -> PyResult<Run> {
        let gpu = self.gpu()?;
        let (p, entry) = self.entry_preset(technique, seed, params_json, denoise, budget)?;
        let scene = self.scene()?.clone();
        let engine = py
            .detach(|| scene.engine(gpu, &p, &entry).map(EngineCell))
            .map_err(py_err)?;
        Ok(Run {
            engine,
            preset: p,
            entry,
        })
    }

    /// The preset's reference (cached in `cache` under the CLI's key): (image, EXR path).
    #[pyo3(signature = (spp=None, cache=PathBuf::from("cache/reference"), force=false, progress=true))]
    fn reference<'py>(
        &self,
        py: Python<'py>,
        spp: Option<u32>,
        cache: PathBuf,
        force: bool,
        progress: bool,
    ) -> PyResult<(Bound<'py, PyArray3<f32>>, String)> {
        if spp == Some(0) {
            return Err(PyValueError::new_err("spp must be at least 1"));
        }
        let gpu = self.gpu()?;
        let p = self.reference_preset(spp);
        let key = self.reference_key(&p)?;
        let scene = (*self.scene()?.scene).clone();
        let camera = self.scene()?.camera;
        let (image, path) = py
            .detach(|| {
                jobs::reference_image(gpu, &p, scene, camera, &key, &cache, force, !progress)
            })
            .map_err(py_err)?;
        Ok((image_to_array(py, image)?, path.display().to_string()))
    }

    /// Where `reference(spp)` is cached (whether or not it exists yet).
    #[pyo3(signature = (spp=None, cache=PathBuf::from("cache/reference")))]
    fn reference_path(&self, spp: Option<u32>, cache: PathBuf) -> PyResult<String> {
        let key = self.reference_key(&self.reference_preset(spp))?;
        Ok(cache.join(format!("{key}.exr")).display().to_string())
    }
}

struct Rendered {
    image: Image,
    variance: Image,
    meta_json: String,
    clock_check_json: Option<String>,
    /// Each debug view: name, whether it shows ids, values (row-major).
    debug: Vec<(String, bool, Vec<f32>)>,
}

/// `shot`'s render of one entry on a fresh engine (`SceneOnGpu::engine`, then `render_on`).
fn render_entry(
    gpu: Arc<Gpu>,
    p: &LoadedPreset,
    scene: &SceneOnGpu,
    entry: &TechniqueEntry,
    frames: u32,
    clock_check: bool,
    quiet: bool,
) -> anyhow::Result<Rendered> {
    let mut engine = scene.engine(gpu, p, entry)?;
    render_on(&mut engine, p, entry, frames, clock_check, quiet)
}

/// `frames` more frames on `engine` (`jobs::render_frames`) and what `shot` reads after them
/// (`jobs::metadata`), plus the variance, the debug views and optionally the clock check
/// `converge` runs around each run.
fn render_on(
    engine: &mut gilab::render::engine::Engine,
    p: &LoadedPreset,
    entry: &TechniqueEntry,
    frames: u32,
    clock_check: bool,
    quiet: bool,
) -> anyhow::Result<Rendered> {
    let gpu = engine.gpu.clone();
    let mut calibration = None;
    if clock_check {
        let mut c = gilab::gpu::calibrate::Calibration::new(&gpu, &engine.shaders)?;
        let (before, warm_up_ms) = c.warm_up(&gpu)?;
        let clock_before = c.clock();
        calibration = Some((c, before, warm_up_ms, clock_before));
    }
    let by_pass = jobs::render_frames(engine, frames, &entry.name, quiet)?;
    let clock_check_json = match calibration {
        Some((mut c, before, warm_up_ms, clock_before)) => {
            let after = c.measure(&gpu)?;
            let check = c.check(before, after, warm_up_ms, (clock_before, c.clock()));
            Some(serde_json::to_string(&check)?)
        }
        None => None,
    };
    let (image, variance) = engine.read_output_and_variance()?;
    let variance = variance.unwrap_or_else(|| Image::new(image.width, image.height));
    let meta = jobs::metadata(engine, p, entry, &image, by_pass)?;
    let mut debug = Vec::new();
    if let Some(data) = engine.read_debug()? {
        let pixels = (image.width * image.height) as usize;
        for view in engine.technique.debug_views() {
            let values = gilab::render::debug_channel(&data, pixels, view.channel);
            debug.push((view.name.to_string(), view.is_id, values));
        }
    }
    Ok(Rendered {
        image,
        variance,
        meta_json: serde_json::to_string(&meta)?,
        clock_check_json,
        debug,
    })
}

impl Rendered {
    fn into_dict<'py>(self, py: Python<'py>, size: [u32; 2]) -> PyResult<Bound<'py, PyDict>> {
        let out = PyDict::new(py);
        out.set_item("image", image_to_array(py, self.image)?)?;
        out.set_item("variance", image_to_array(py, self.variance)?)?;
        out.set_item("meta_json", self.meta_json)?;
        out.set_item("clock_check_json", self.clock_check_json)?;
        let debug = PyDict::new(py);
        let [w, h] = size;
        for (name, is_id, values) in self.debug {
            let array: Bound<'py, PyArray2<f32>> =
                Array2::from_shape_vec((h as usize, w as usize), values)
                    .map_err(|e| PyRuntimeError::new_err(e.to_string()))?
                    .into_pyarray(py);
            debug.set_item(name, (array, is_id))?;
        }
        out.set_item("debug", debug)?;
        Ok(out)
    }
}

/// An engine kept between calls (`Run`).
struct EngineCell(gilab::render::engine::Engine);

impl EngineCell {
    /// The engine, borrowed through the cell (so closures capture the cell, which is `Send`).
    fn get(&mut self) -> &mut gilab::render::engine::Engine {
        &mut self.0
    }
}

// SAFETY: the engine (its technique is not `Send`) lives in a `Run`, an `unsendable` pyclass:
// pyo3 hands a `Run` only to the thread that made it, and `Python::detach` runs its closure on
// the calling thread, so the engine never crosses threads; `Send` is only what `detach` asks of
// the closure that borrows it.
unsafe impl Send for EngineCell {}

/// One technique's engine kept across calls: frames accumulate (or a real-time technique's
/// history carries on) from one `step` to the next, and scripted edits land mid-run, as in
/// `converge`'s runs.
#[pyclass(unsendable, module = "gilab._gilab")]
struct Run {
    engine: EngineCell,
    preset: LoadedPreset,
    entry: TechniqueEntry,
}

#[pymethods]
impl Run {
    /// `frames` more frames; the frame returned holds everything since the start (or reset).
    #[pyo3(signature = (frames=1, clock_check=false, progress=false))]
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        frames: u32,
        clock_check: bool,
        progress: bool,
    ) -> PyResult<Bound<'py, PyDict>> {
        if frames == 0 {
            return Err(PyValueError::new_err("frames must be at least 1"));
        }
        let (p, entry) = (&self.preset, &self.entry);
        let engine = &mut self.engine;
        let rendered = py
            .detach(|| render_on(engine.get(), p, entry, frames, clock_check, !progress))
            .map_err(py_err)?;
        rendered.into_dict(py, self.preset.preset.render.size)
    }

    /// Frames since the start or the last reset.
    #[getter]
    fn frames(&self) -> u32 {
        self.engine.0.frame_index
    }

    /// Forgets everything: history, accumulation, counters (a camera cut).
    fn reset(&mut self, py: Python<'_>) {
        let engine = &mut self.engine;
        py.detach(|| engine.get().reset());
    }

    fn camera_json(&self) -> PyResult<String> {
        serde_json::to_string(&self.engine.0.camera).map_err(json_err)
    }

    /// A scripted camera move (`Engine::move_camera`): accumulation restarts, reuse history
    /// and counters carry on, as a camera event in `converge`.
    fn move_camera_json(&mut self, json: &str) -> PyResult<()> {
        let camera = camera_from_json(json)?;
        self.engine.0.move_camera(camera);
        Ok(())
    }

    /// A scripted scene edit mid-run, as `converge` applies `[[experiment.event]]`: the edited
    /// scene is uploaded and swapped in (`Engine::change_scene`), then the camera moved.
    fn apply_event_json(&mut self, py: Python<'_>, json: &str) -> PyResult<()> {
        let event = event_from_json(json)?;
        let engine = &mut self.engine;
        let mut scene = (*engine.0.scene).clone();
        let mut camera = engine.0.camera;
        event.apply(&mut scene, &mut camera).map_err(value_err)?;
        scene.validate().map_err(value_err)?;
        let edits_scene = event.material.is_some() || event.light.is_some();
        py.detach(|| -> anyhow::Result<()> {
            let engine = engine.get();
            if edits_scene {
                let gpu_scene = gilab::scene::gpu_scene::GpuScene::upload(&engine.gpu, &scene);
                engine.change_scene(Arc::new(scene), Arc::new(gpu_scene))?;
            }
            if camera != engine.camera {
                engine.move_camera(camera);
            }
            Ok(())
        })
        .map_err(py_err)
    }
}

fn camera_from_json(json: &str) -> PyResult<Camera> {
    let camera: Camera =
        serde_json::from_str(json).map_err(|e| PyValueError::new_err(format!("camera: {e}")))?;
    let finite = camera.position.is_finite() && camera.target.is_finite() && camera.up.is_finite();
    if !(finite && camera.fov_y > 0.0 && camera.fov_y < 180.0) {
        return Err(PyValueError::new_err(
            "camera: position, target and up must be finite and fov in (0, 180) degrees",
        ));
    }
    if (camera.target - camera.position).length() == 0.0 {
        return Err(PyValueError::new_err(
            "camera: target must differ from position",
        ));
    }
    Ok(camera)
}

/// An `[[experiment.event]]` table from JSON; `frame` may be left out (the edit is now).
fn event_from_json(json: &str) -> PyResult<Event> {
    let mut table = toml_table(json)?;
    table.entry("frame").or_insert(toml::Value::Integer(0));
    table
        .try_into()
        .map_err(|e| PyValueError::new_err(format!("event: {e}")))
}

#[pymodule]
fn _gilab(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("GilabError", m.py().get_type::<GilabError>())?;
    m.add_class::<Session>()?;
    m.add_class::<Run>()?;
    m.add_function(wrap_pyfunction!(set_progress, m)?)?;
    m.add_function(wrap_pyfunction!(techniques_json, m)?)?;
    m.add_function(wrap_pyfunction!(params_json, m)?)?;
    m.add_function(wrap_pyfunction!(error_metrics, m)?)?;
    m.add_function(wrap_pyfunction!(ldr_flip, m)?)?;
    m.add_function(wrap_pyfunction!(tonemap_srgb8, m)?)?;
    m.add_function(wrap_pyfunction!(read_exr, m)?)?;
    m.add_function(wrap_pyfunction!(write_exr, m)?)?;
    m.add_function(wrap_pyfunction!(write_png, m)?)?;
    m.add_function(wrap_pyfunction!(converge, m)?)?;
    Ok(())
}
