//! GPU context: adapter choice (Vulkan preferred, GL fallback), device creation with the
//! adapter's own limits, an error log instead of panics, timestamp queries and readback.

pub mod calibrate;
pub mod pipeline_cache;
pub mod readback;
pub mod shaders;
pub mod timing;

use anyhow::{anyhow, bail, Context, Result};
use std::sync::{Arc, Mutex};

/// Which wgpu backend to use. `Auto` prefers Vulkan and falls back to GL.
#[derive(
    Clone,
    Copy,
    Debug,
    PartialEq,
    Eq,
    Default,
    clap::ValueEnum,
    serde::Serialize,
    serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum BackendChoice {
    #[default]
    Auto,
    Vulkan,
    Gl,
}

impl std::str::FromStr for BackendChoice {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> Result<Self> {
        match s.to_ascii_lowercase().as_str() {
            "auto" | "" => Ok(Self::Auto),
            "vulkan" | "vk" => Ok(Self::Vulkan),
            "gl" | "gles" | "opengl" => Ok(Self::Gl),
            other => bail!("unknown backend '{other}' (expected auto, vulkan or gl)"),
        }
    }
}

impl BackendChoice {
    /// `GILAB_BACKEND` overrides `Auto`.
    pub fn resolve_env(self) -> Result<Self> {
        match (self, std::env::var("GILAB_BACKEND")) {
            (Self::Auto, Ok(v)) => v.parse().context("GILAB_BACKEND"),
            (s, _) => Ok(s),
        }
    }
}

/// Errors wgpu reported outside any error scope; drained and shown instead of panicking.
#[derive(Clone, Default)]
pub struct ErrorLog(Arc<Mutex<Vec<String>>>);

impl ErrorLog {
    pub fn push(&self, msg: String) {
        log::error!("wgpu: {msg}");
        if let Ok(mut v) = self.0.lock() {
            v.push(msg);
        }
    }
    pub fn take(&self) -> Vec<String> {
        self.0
            .lock()
            .map(|mut v| std::mem::take(&mut *v))
            .unwrap_or_default()
    }
}

#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct AdapterSummary {
    pub name: String,
    pub backend: String,
    pub device_type: String,
    pub driver: String,
    pub driver_info: String,
    pub timestamps: bool,
}

impl std::fmt::Display for AdapterSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} ({}, {}, {} {})",
            self.name, self.backend, self.device_type, self.driver, self.driver_info
        )
    }
}

pub struct Gpu {
    pub instance: wgpu::Instance,
    pub adapter: wgpu::Adapter,
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub summary: AdapterSummary,
    pub errors: ErrorLog,
    /// Nanoseconds per timestamp tick; `None` when timestamp queries are unavailable.
    pub timestamp_period: Option<f32>,
    /// What the last submission through [`Gpu::submit`] ran (named when a wait times out).
    last_submitted: Mutex<String>,
    /// How long a wait for the GPU may take before it is an error ([`Gpu::wait`]).
    wait_timeout: Mutex<std::time::Duration>,
    /// Layouts and compute pipelines shared by every engine on this device.
    pub pipelines: pipeline_cache::PipelineCache,
}

/// Default bound of one wait for the GPU. Generous on purpose: lavapipe on 2 cores takes
/// seconds for a large frame; a GPU dispatch that runs this long is stuck (or would trip a
/// driver watchdog on a real GPU). `GILAB_GPU_TIMEOUT_S` changes it.
pub const DEFAULT_WAIT_TIMEOUT_S: f64 = 300.0;

/// Storage buffers one compute stage binds at most: the scene's 6, the ray counters and up to 8
/// of a technique's own (ReSTIR). lavapipe offers 32, GL llvmpipe 16.
pub const MIN_STORAGE_BUFFERS: u32 = 15;

/// Features used when the adapter has them; nothing is strictly required beyond compute.
fn optional_features() -> wgpu::Features {
    wgpu::Features::TIMESTAMP_QUERY | wgpu::Features::TIMESTAMP_QUERY_INSIDE_ENCODERS
}

/// The device gilab asks for: the adapter's own limits (storage buffer counts, sizes) and
/// timestamp queries when present. Shared by the headless path and eframe's device.
pub fn device_descriptor(adapter: &wgpu::Adapter) -> wgpu::DeviceDescriptor<'static> {
    wgpu::DeviceDescriptor {
        label: Some("gilab"),
        required_features: adapter.features() & optional_features(),
        required_limits: adapter.limits(),
        experimental_features: wgpu::ExperimentalFeatures::disabled(),
        memory_hints: wgpu::MemoryHints::Performance,
        trace: wgpu::Trace::Off,
    }
}

/// `GILAB_GPU_TIMEOUT_S` (seconds, > 0) or [`DEFAULT_WAIT_TIMEOUT_S`].
fn wait_timeout_from_env() -> std::time::Duration {
    let s = std::env::var("GILAB_GPU_TIMEOUT_S")
        .ok()
        .and_then(|v| match v.trim().parse::<f64>() {
            Ok(s) if s.is_finite() && s > 0.0 => Some(s),
            _ => {
                log::warn!(
                    "GILAB_GPU_TIMEOUT_S='{v}' is not a positive number of seconds: ignored"
                );
                None
            }
        })
        .unwrap_or(DEFAULT_WAIT_TIMEOUT_S);
    std::time::Duration::from_secs_f64(s)
}

/// Sets `XDG_RUNTIME_DIR` when missing (lavapipe prints an error line without it).
pub fn ensure_runtime_dir() {
    if std::env::var_os("XDG_RUNTIME_DIR").is_none() {
        let dir = std::env::temp_dir().join(format!("gilab-xdg-{}", std::process::id()));
        let _ = std::fs::create_dir_all(&dir);
        // SAFETY: called at start-up, before we start threads that read the environment.
        unsafe { std::env::set_var("XDG_RUNTIME_DIR", &dir) };
    }
}

/// Adapter preference: real GPUs first, then CPU rasterisers (lavapipe/llvmpipe).
pub fn adapter_rank(adapter: &wgpu::Adapter) -> u32 {
    match adapter.get_info().device_type {
        wgpu::DeviceType::DiscreteGpu => 4,
        wgpu::DeviceType::IntegratedGpu => 3,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Cpu => 1,
        wgpu::DeviceType::Other => 0,
    }
}

impl BackendChoice {
    /// Backends to try, in order.
    pub fn order(self) -> &'static [wgpu::Backends] {
        match self {
            BackendChoice::Auto => &[wgpu::Backends::VULKAN, wgpu::Backends::GL],
            BackendChoice::Vulkan => &[wgpu::Backends::VULKAN],
            BackendChoice::Gl => &[wgpu::Backends::GL],
        }
    }
}

impl Gpu {
    /// Creates a headless device. Errors (not panics) if no adapter fits.
    pub fn new(choice: BackendChoice) -> Result<Gpu> {
        let choice = choice.resolve_env()?;
        ensure_runtime_dir();
        let mut tried = Vec::new();
        for &backends in choice.order() {
            let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
            desc.backends = backends;
            let instance = wgpu::Instance::new(desc);
            let adapters = pollster::block_on(instance.enumerate_adapters(backends));
            let best = adapters.into_iter().max_by_key(adapter_rank);
            match best {
                Some(adapter) => return Self::from_adapter(instance, adapter),
                None => tried.push(format!("{backends:?}")),
            }
        }
        Err(anyhow!(
            "no GPU adapter found (tried {}). Install Mesa's software Vulkan driver with \
             `apt-get install mesa-vulkan-drivers`, or force GL with --backend gl",
            tried.join(", ")
        ))
    }

    /// Checks that an adapter can run gilab at all (compute shaders, enough storage buffers).
    pub fn check_adapter(adapter: &wgpu::Adapter) -> Result<()> {
        let info = adapter.get_info();
        if !adapter
            .get_downlevel_capabilities()
            .flags
            .contains(wgpu::DownlevelFlags::COMPUTE_SHADERS)
        {
            bail!(
                "adapter {} has no compute shaders, which gilab requires",
                info.name
            );
        }
        let limits = adapter.limits();
        if limits.max_storage_buffers_per_shader_stage < MIN_STORAGE_BUFFERS {
            bail!(
                "adapter {} allows {} storage buffers per stage; gilab needs {MIN_STORAGE_BUFFERS}",
                info.name,
                limits.max_storage_buffers_per_shader_stage
            );
        }
        Ok(())
    }

    fn from_adapter(instance: wgpu::Instance, adapter: wgpu::Adapter) -> Result<Gpu> {
        Self::check_adapter(&adapter)?;
        let (device, queue) =
            pollster::block_on(adapter.request_device(&device_descriptor(&adapter)))
                .with_context(|| format!("requesting a device from {}", adapter.get_info().name))?;
        Ok(Self::from_device(instance, adapter, device, queue))
    }

    /// Wraps a device someone else created (the viewer shares eframe's device). The device
    /// should come from [`device_descriptor`] so that gilab's limits and features are there.
    pub fn from_device(
        instance: wgpu::Instance,
        adapter: wgpu::Adapter,
        device: wgpu::Device,
        queue: wgpu::Queue,
    ) -> Gpu {
        let info = adapter.get_info();
        let errors = ErrorLog::default();
        let sink = errors.clone();
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| sink.push(e.to_string())));
        let timestamps = device.features().contains(wgpu::Features::TIMESTAMP_QUERY);
        let timestamp_period = timestamps.then(|| queue.get_timestamp_period());
        let summary = AdapterSummary {
            name: info.name.clone(),
            backend: format!("{:?}", info.backend),
            device_type: format!("{:?}", info.device_type),
            driver: info.driver.clone(),
            driver_info: info.driver_info.clone(),
            timestamps,
        };
        Gpu {
            instance,
            adapter,
            device,
            queue,
            summary,
            errors,
            timestamp_period,
            last_submitted: Mutex::new("nothing yet".into()),
            wait_timeout: Mutex::new(wait_timeout_from_env()),
            pipelines: Default::default(),
        }
    }

    /// Submits one command buffer and remembers `what` it runs (a frame and its passes, a
    /// kernel), so that a wait that times out can name it.
    pub fn submit(&self, what: &str, commands: wgpu::CommandBuffer) -> wgpu::SubmissionIndex {
        self.submit_all(what, [commands])
    }

    /// [`Gpu::submit`] of several command buffers in one submission.
    pub fn submit_all(
        &self,
        what: &str,
        commands: impl IntoIterator<Item = wgpu::CommandBuffer>,
    ) -> wgpu::SubmissionIndex {
        *self.last_submitted.lock().expect("gpu label") = what.to_string();
        self.queue.submit(commands)
    }

    /// What the last [`Gpu::submit`] ran.
    pub fn last_submitted(&self) -> String {
        self.last_submitted.lock().expect("gpu label").clone()
    }

    /// The bound on one wait for the GPU.
    pub fn wait_timeout(&self) -> std::time::Duration {
        *self.wait_timeout.lock().expect("gpu timeout")
    }

    pub fn set_wait_timeout(&self, timeout: std::time::Duration) {
        *self.wait_timeout.lock().expect("gpu timeout") = timeout;
    }

    /// Waits for all submitted work, at most [`Gpu::wait_timeout`]: a stuck dispatch becomes an
    /// error naming what was in flight, not a hang.
    pub fn wait(&self) -> Result<()> {
        self.wait_for(None, None)
    }

    /// Waits for one submission (all of them with None), at most the wait timeout; `what`
    /// names it in the error (default: the last submission's label).
    pub fn wait_for(
        &self,
        submission: Option<wgpu::SubmissionIndex>,
        what: Option<&str>,
    ) -> Result<()> {
        let timeout = self.wait_timeout();
        match self.device.poll(wgpu::PollType::Wait {
            submission_index: submission,
            timeout: Some(timeout),
        }) {
            Ok(_) => Ok(()),
            Err(wgpu::PollError::Timeout) => Err(anyhow!(
                "the GPU did not finish within {:.1} s: in flight: {} ({}; set \
                 GILAB_GPU_TIMEOUT_S to wait longer)",
                timeout.as_secs_f64(),
                what.map_or_else(|| self.last_submitted(), str::to_string),
                self.summary.name
            )),
            Err(e) => Err(self.poll_error(e)),
        }
    }

    /// A failed device poll, with what wgpu reported since the last check: a submission that
    /// failed validation (a shader edited under `GILAB_SHADERS` that no longer fits the engine's
    /// buffers, say) is dropped, and the poll alone only says its index was never returned.
    pub fn poll_error(&self, e: impl std::fmt::Display) -> anyhow::Error {
        let errs = self.errors.take();
        if errs.is_empty() {
            anyhow!("device poll failed: {e}")
        } else {
            anyhow!(
                "GPU error: {} (the submission was dropped; device poll: {e})",
                errs.join("; ")
            )
        }
    }

    /// Runs `f` inside a validation error scope and turns a captured error into `Err`.
    pub fn scoped<T>(&self, what: &str, f: impl FnOnce() -> T) -> Result<T> {
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let value = f();
        match pollster::block_on(scope.pop()) {
            None => Ok(value),
            Some(e) => Err(anyhow!("{what}: {e}")),
        }
    }

    /// Fails if wgpu reported any error outside a scope since the last check.
    pub fn check_errors(&self) -> Result<()> {
        let errs = self.errors.take();
        if errs.is_empty() {
            Ok(())
        } else {
            Err(anyhow!("GPU error: {}", errs.join("; ")))
        }
    }
}
