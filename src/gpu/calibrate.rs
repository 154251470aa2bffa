//! The timing protocol's clock check: a fixed arithmetic kernel (`shaders/bench/calibrate.wgsl`)
//! run until its time is stable (warm-up: GPUs drop their clocks when idle, an H100 from about
//! 1,980 to 345 MHz), then timed again right after a timed run, queued behind its last frame.
//! A run whose two times differ by more than `DRIFT_LIMIT` was measured in another clock state
//! than it started in, and is flagged. Clocks are read through NVML where it loads (NVIDIA).

use super::{shaders::ShaderLibrary, timing::PassTimer, Gpu};
use crate::render::pipelines;
use anyhow::Result;
use serde::{Deserialize, Serialize};

/// Largest relative difference between the kernel's time before and after a run.
pub const DRIFT_LIMIT: f64 = 0.10;
const WORKGROUPS: u32 = 1024;
const BATCH: usize = 8;

pub struct Calibration {
    pipeline: wgpu::ComputePipeline,
    bind_group: wgpu::BindGroup,
    timer: PassTimer,
    pub iterations: u32,
    clocks: Option<Clocks>,
}

/// The check of one timed run, written to the summary, the CSV and the report.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct ClockCheck {
    /// The calibration kernel's median ms after warm-up, before the run.
    pub kernel_ms_before: f64,
    /// ... and right after the run's last frame.
    pub kernel_ms_after: f64,
    /// after / before - 1.
    pub drift: f64,
    /// The drift exceeds `DRIFT_LIMIT`: this run's times are not comparable.
    pub flagged: bool,
    /// Warm-up time before the run (ms of kernels).
    pub warm_up_ms: f64,
    /// Graphics clock before / after (MHz) or "unknown" where the platform does not say.
    pub clock_before: String,
    pub clock_after: String,
}

impl ClockCheck {
    pub fn summary(&self) -> String {
        format!(
            "calibration {:.3} -> {:.3} ms ({:+.1}%){}; clock {} -> {}",
            self.kernel_ms_before,
            self.kernel_ms_after,
            self.drift * 100.0,
            if self.flagged { " FLAGGED" } else { "" },
            self.clock_before,
            self.clock_after
        )
    }
}

/// GPU clocks through NVML, loaded at run time (no build requirement; absent elsewhere).
struct Clocks {
    nvml: nvml_wrapper::Nvml,
}

impl Clocks {
    fn open(gpu: &Gpu) -> Option<Clocks> {
        // Only on NVIDIA adapters (PCI vendor 0x10de); NVML's device 0 is assumed to be it.
        if gpu.adapter.get_info().vendor != 0x10de {
            return None;
        }
        nvml_wrapper::Nvml::init().ok().map(|nvml| Clocks { nvml })
    }

    fn graphics_mhz(&self) -> Option<u32> {
        let d = self.nvml.device_by_index(0).ok()?;
        d.clock_info(nvml_wrapper::enum_wrappers::device::Clock::Graphics)
            .ok()
    }
}

impl Calibration {
    /// Builds the kernel and sizes it once (doubling its loop until it takes at least 0.5 ms);
    /// the size then stays fixed for every run it checks.
    pub fn new(gpu: &Gpu, shaders: &ShaderLibrary) -> Result<Calibration> {
        let layout = pipelines::layout(
            gpu,
            "calibration",
            &[
                pipelines::uniform_entry(0, wgpu::ShaderStages::COMPUTE),
                pipelines::storage_entry(1, false),
            ],
        );
        let pipeline =
            pipelines::compute_pipeline(gpu, shaders, "bench/calibrate.wgsl", &[&layout])?;
        let data = pipelines::storage_buffer(gpu, "calibration data", WORKGROUPS as u64 * 256 * 16);
        let params = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("calibration params"),
            size: 16,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let bind_group =
            pipelines::buffers_bind_group(gpu, "calibration", &layout, &[&params, &data]);
        let mut c = Calibration {
            pipeline,
            bind_group,
            timer: PassTimer::new(gpu),
            iterations: 4,
            clocks: Clocks::open(gpu),
        };
        loop {
            gpu.queue
                .write_buffer(&params, 0, bytemuck::cast_slice(&[c.iterations, 0, 0, 0]));
            let ms = c.time_batch(gpu, 2)?;
            if ms >= 0.5 || c.iterations >= 1 << 20 {
                break;
            }
            c.iterations *= 2;
        }
        Ok(c)
    }

    /// Median ms of `n` kernels submitted back to back.
    fn time_batch(&mut self, gpu: &Gpu, n: usize) -> Result<f64> {
        let start = std::time::Instant::now();
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        self.timer.begin_frame();
        for _ in 0..n {
            let writes = self.timer.compute_pass("calibration");
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("calibration"),
                timestamp_writes: writes,
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &self.bind_group, &[]);
            pass.dispatch_workgroups(WORKGROUPS, 1, 1);
        }
        self.timer.resolve(&mut enc);
        gpu.queue.submit([enc.finish()]);
        gpu.wait()?;
        let wall = start.elapsed().as_secs_f64() * 1e3 / n as f64;
        let mut times: Vec<f64> = self.timer.read(gpu)?.into_iter().map(|p| p.1).collect();
        if times.is_empty() {
            return Ok(wall);
        }
        times.sort_by(f64::total_cmp);
        Ok(times[times.len() / 2])
    }

    /// Runs the kernel until its median time is stable (two batches within 3%, and within 5%
    /// of the fastest batch seen, so a transient slow phase is not taken for the steady state)
    /// or 3 s have passed; returns (median ms, warm-up ms spent).
    pub fn warm_up(&mut self, gpu: &Gpu) -> Result<(f64, f64)> {
        let start = std::time::Instant::now();
        let mut last: Option<f64> = None;
        let mut best = f64::INFINITY;
        loop {
            let ms = self.time_batch(gpu, BATCH)?;
            best = best.min(ms);
            let stable =
                last.is_some_and(|prev| (ms / prev - 1.0).abs() <= 0.03) && ms <= best * 1.05;
            if stable || start.elapsed().as_secs_f64() > 3.0 {
                return Ok((ms, start.elapsed().as_secs_f64() * 1e3));
            }
            last = Some(ms);
        }
    }

    /// The kernel's median time now (queued behind whatever was submitted last).
    pub fn measure(&mut self, gpu: &Gpu) -> Result<f64> {
        self.time_batch(gpu, BATCH)
    }

    /// The graphics clock in MHz, or "unknown".
    pub fn clock(&self) -> String {
        self.clocks
            .as_ref()
            .and_then(|c| c.graphics_mhz())
            .map_or("unknown".into(), |m| format!("{m} MHz"))
    }

    /// The check from the times before and after a run.
    pub fn check(before: f64, after: f64, warm_up_ms: f64, clocks: (String, String)) -> ClockCheck {
        let drift = after / before.max(1e-9) - 1.0;
        ClockCheck {
            kernel_ms_before: before,
            kernel_ms_after: after,
            drift,
            flagged: drift.abs() > DRIFT_LIMIT,
            warm_up_ms,
            clock_before: clocks.0,
            clock_after: clocks.1,
        }
    }
}
