//! The timing protocol's clock check: a fixed arithmetic kernel (`shaders/bench/calibrate.wgsl`)
//! run until its time is stable (warm-up: GPUs drop their clocks when idle, an H100 from about
//! 1,980 to 345 MHz), then timed again right after a timed run, queued behind its last frame.
//! A run whose two times differ by more than `DRIFT_LIMIT` was measured in another clock state
//! than it started in, and is flagged. Clocks are read through NVML where it loads (NVIDIA).
//!
//! Sizing cannot run away: the kernel's loop doubles until it takes `TARGET_MS`, judged by
//! the timestamps *and* the wall clock, and never past `KERNEL_WALL_LIMIT_MS` of wall time.
//! Timestamps the wall clock contradicts (`TimingSource::judge`, the check engine frames use)
//! are dropped for the wall clock, and the clock check says so.

use super::{
    shaders::ShaderLibrary,
    timing::{PassTimer, TimingSource, IMPLAUSIBLE_MIN_WALL_MS},
    Gpu,
};
use crate::render::pipelines;
use anyhow::Result;
use serde::{Deserialize, Serialize};

/// Largest relative difference between the kernel's time before and after a run.
pub const DRIFT_LIMIT: f64 = 0.10;
const WORKGROUPS: u32 = 1024;
const BATCH: usize = 8;
/// Batches whose median is the kernel's time before and after a run.
const MEASURE_BATCHES: usize = 5;
/// The kernel is sized to take at least this long (per kernel, by trusted timestamps).
pub const TARGET_MS: f64 = 0.5;
/// ... or this long by the wall clock, which also counts each dispatch's fixed cost (about
/// 1.3 ms per kernel on lavapipe, where timestamps read 0.06 ms for a 4-iteration kernel):
/// sizing never doubles a kernel past it, whatever the timestamps say.
pub const WALL_TARGET_MS: f64 = 4.0 * TARGET_MS;
/// No calibration kernel may run longer than this, by the wall clock: sizing stops short of
/// it. (Sized by broken timestamps alone, the loop once grew to 1M iterations: minutes per
/// kernel on lavapipe, seconds and a watchdog on a GPU.)
pub const KERNEL_WALL_LIMIT_MS: f64 = 25.0;
/// Most kernels in the batch that judges the timestamps (long enough for the wall clock to
/// tell, `IMPLAUSIBLE_MIN_WALL_MS`).
const MAX_JUDGE_BATCH: usize = 256;

pub struct Calibration {
    pipeline: wgpu::ComputePipeline,
    bind_group: wgpu::BindGroup,
    timer: PassTimer,
    params: wgpu::Buffer,
    pub iterations: u32,
    /// Where the kernel's times come from, judged once the kernel is sized.
    pub timing: TimingSource,
    /// Test hook: the timestamps read back as zeros (the fault that made sizing run away).
    zero_timestamps: bool,
    clocks: Option<Clocks>,
    /// The fastest batch median this kernel has shown (any warm-up or measurement).
    fastest_ms: f64,
}

/// One batch of kernels: its timestamps per kernel (None without timestamp queries) and the
/// wall time of the whole batch, from submission to the end of the wait.
#[derive(Clone, Debug)]
pub struct BatchTime {
    pub kernels: usize,
    pub stamped_ms: Option<Vec<f64>>,
    pub wall_ms: f64,
}

impl BatchTime {
    pub fn wall_per_kernel(&self) -> f64 {
        self.wall_ms / self.kernels.max(1) as f64
    }

    /// The timestamps' verdict on this batch.
    pub fn source(&self) -> TimingSource {
        TimingSource::judge(
            self.stamped_ms.as_ref().map(|t| t.iter().sum()),
            self.wall_ms,
        )
    }

    /// The median kernel time from `source` (timestamps when believed, else wall time).
    pub fn median_ms(&self, source: TimingSource) -> f64 {
        match (&self.stamped_ms, source) {
            (Some(t), TimingSource::Timestamps) if !t.is_empty() => {
                let mut t = t.clone();
                t.sort_by(f64::total_cmp);
                t[t.len() / 2]
            }
            _ => self.wall_per_kernel(),
        }
    }
}

/// The kernel's size: `iterations` and where its times come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sizing {
    pub iterations: u32,
    pub timing: TimingSource,
}

/// Sizes the kernel with `run(iterations, kernels)`: doubles the loop from 4 until a kernel
/// takes `TARGET_MS` by the trusted clock or `WALL_TARGET_MS` by the wall clock, never to a size whose wall
/// time would pass `KERNEL_WALL_LIMIT_MS` (halving back if one did); then times one batch long
/// enough for `TimingSource::judge` to tell whether the timestamps can be believed.
pub fn size_kernel(mut run: impl FnMut(u32, usize) -> Result<BatchTime>) -> Result<Sizing> {
    let mut iterations = 4u32;
    // The first dispatch pays for compiling the pipeline (lavapipe JITs it): not timed.
    run(iterations, 1)?;
    let mut wall_per_kernel;
    loop {
        let b = run(iterations, 2)?;
        wall_per_kernel = b.wall_per_kernel();
        if wall_per_kernel > KERNEL_WALL_LIMIT_MS {
            // Already too long (a slow adapter from the first size): back off, and stop.
            while wall_per_kernel > KERNEL_WALL_LIMIT_MS && iterations > 1 {
                iterations /= 2;
                wall_per_kernel /= 2.0;
            }
            break;
        }
        let ms = b.median_ms(b.source());
        let long_enough = ms >= TARGET_MS || wall_per_kernel >= WALL_TARGET_MS;
        if long_enough || 2.0 * wall_per_kernel > KERNEL_WALL_LIMIT_MS || iterations >= 1 << 30 {
            break;
        }
        iterations *= 2;
    }
    // Judge the timestamps on a batch long enough for the wall clock to tell.
    let mut kernels = BATCH;
    let judged = loop {
        let b = run(iterations, kernels)?;
        let enough = 1.5 * IMPLAUSIBLE_MIN_WALL_MS;
        if b.wall_ms >= enough || kernels >= MAX_JUDGE_BATCH {
            break b;
        }
        let more = (enough / b.wall_ms.max(1e-3)).ceil() as usize;
        kernels = (kernels * more.max(2)).min(MAX_JUDGE_BATCH);
    };
    Ok(Sizing {
        iterations,
        timing: judged.source(),
    })
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
    /// Where the kernel's times came from (timestamps, or the wall clock when there are none
    /// or they were implausible).
    #[serde(default)]
    pub timing: TimingSource,
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
        ) + match self.timing {
            TimingSource::Timestamps => "",
            TimingSource::Wall => "; no timestamps: using wall time",
            TimingSource::WallTimestampsImplausible => "; timestamps implausible: using wall time",
        }
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
    /// Builds the kernel and sizes it once (`size_kernel`); the size then stays fixed for every
    /// run it checks.
    pub fn new(gpu: &Gpu, shaders: &ShaderLibrary) -> Result<Calibration> {
        Self::build(gpu, shaders, false)
    }

    /// `new` with a timer whose timestamps read back as zeros, for the test that sizing stops
    /// within its wall-clock bound however wrong the timestamps are.
    #[doc(hidden)]
    pub fn new_with_zero_timestamps(gpu: &Gpu, shaders: &ShaderLibrary) -> Result<Calibration> {
        Self::build(gpu, shaders, true)
    }

    fn build(gpu: &Gpu, shaders: &ShaderLibrary, zero_timestamps: bool) -> Result<Calibration> {
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
            params,
            iterations: 4,
            timing: TimingSource::Timestamps,
            zero_timestamps,
            clocks: Clocks::open(gpu),
            fastest_ms: f64::INFINITY,
        };
        let sizing = size_kernel(|iterations, kernels| {
            c.iterations = iterations;
            c.run_batch(gpu, kernels)
        })?;
        c.iterations = sizing.iterations;
        c.timing = sizing.timing;
        // A CPU adapter's timestamps sometimes pass the judge and read a tenth of the kernel's
        // time, varying ±40% from batch to batch (lavapipe, docs/known-issues.md): the clock
        // check there flagged nearly every run. Its kernels are timed by the wall clock.
        if c.timing == TimingSource::Timestamps
            && gpu.adapter.get_info().device_type == wgpu::DeviceType::Cpu
        {
            c.timing = TimingSource::WallTimestampsImplausible;
        }
        if c.timing == TimingSource::WallTimestampsImplausible {
            log::warn!(
                "clock calibration on {}: timestamps implausible against the wall clock: using wall time",
                gpu.summary.name
            );
        }
        Ok(c)
    }

    /// Runs `n` kernels of the current size back to back and times them.
    fn run_batch(&mut self, gpu: &Gpu, n: usize) -> Result<BatchTime> {
        gpu.queue.write_buffer(
            &self.params,
            0,
            bytemuck::cast_slice(&[self.iterations, 0, 0, 0]),
        );
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
        let what = format!(
            "clock calibration kernel (bench/calibrate.wgsl, {n} x {} iterations)",
            self.iterations
        );
        gpu.submit(&what, enc.finish());
        gpu.wait()?;
        let wall_ms = start.elapsed().as_secs_f64() * 1e3;
        let mut stamped: Vec<f64> = self.timer.read(gpu)?.into_iter().map(|p| p.1).collect();
        if self.zero_timestamps {
            stamped.iter_mut().for_each(|t| *t = 0.0);
        }
        Ok(BatchTime {
            kernels: n,
            stamped_ms: (!stamped.is_empty()).then_some(stamped),
            wall_ms,
        })
    }

    /// Median ms of `n` kernels submitted back to back, from the clock chosen at sizing.
    fn time_batch(&mut self, gpu: &Gpu, n: usize) -> Result<f64> {
        let b = self.run_batch(gpu, n)?;
        let ms = b.median_ms(self.timing);
        self.fastest_ms = self.fastest_ms.min(ms);
        Ok(ms)
    }

    /// Runs the kernel until its median time is stable (two batches within 3%, and within 5%
    /// of the fastest batch seen, so a transient slow phase is not taken for the steady state)
    /// or 3 s have passed; returns (median ms, warm-up ms spent).
    ///
    /// Where the clock can be read (NVIDIA), "fastest seen" includes earlier warm-ups and
    /// measurements: an H100 left idle while the next technique was set up sat at 345 MHz and
    /// gave steady batches 5.7x slower than at 1,980 MHz, which passed the check alone.
    pub fn warm_up(&mut self, gpu: &Gpu) -> Result<(f64, f64)> {
        let start = std::time::Instant::now();
        let mut last: Option<f64> = None;
        let mut best = if self.clocks.is_some() {
            self.fastest_ms
        } else {
            f64::INFINITY
        };
        loop {
            let ms = self.time_batch(gpu, BATCH)?;
            best = best.min(ms);
            let stable =
                last.is_some_and(|prev| (ms / prev - 1.0).abs() <= 0.03) && ms <= best * 1.05;
            if stable || start.elapsed().as_secs_f64() > 3.0 {
                // The time the run's `measure` is compared with, taken the same way.
                let ms = self.median_of_batches(gpu)?;
                return Ok((ms, start.elapsed().as_secs_f64() * 1e3));
            }
            last = Some(ms);
        }
    }

    /// The kernel's time now: the median of `MEASURE_BATCHES` batches, queued behind whatever
    /// was submitted last. Timed by the wall clock, a batch would also count the frames still
    /// in flight before it, so those are waited for first.
    pub fn measure(&mut self, gpu: &Gpu) -> Result<f64> {
        if self.timing != TimingSource::Timestamps {
            gpu.wait()?;
        }
        self.median_of_batches(gpu)
    }

    /// The median of `MEASURE_BATCHES` batches' medians: one batch's time on a CPU adapter
    /// varies by tens of percent with its threads' scheduling.
    fn median_of_batches(&mut self, gpu: &Gpu) -> Result<f64> {
        let mut ms = [0.0; MEASURE_BATCHES];
        for m in &mut ms {
            *m = self.time_batch(gpu, BATCH)?;
        }
        ms.sort_by(f64::total_cmp);
        Ok(ms[MEASURE_BATCHES / 2])
    }

    /// The graphics clock in MHz, or "unknown".
    pub fn clock(&self) -> String {
        self.clocks
            .as_ref()
            .and_then(|c| c.graphics_mhz())
            .map_or("unknown".into(), |m| format!("{m} MHz"))
    }

    /// The check from the times before and after a run.
    pub fn check(
        &self,
        before: f64,
        after: f64,
        warm_up_ms: f64,
        clocks: (String, String),
    ) -> ClockCheck {
        let drift = after / before.max(1e-9) - 1.0;
        ClockCheck {
            timing: self.timing,
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A simulated adapter: a kernel takes `fixed + per_iteration * iterations` ms of wall
    /// time; its timestamps read `stamp_factor` times that (0: the zeros seen on lavapipe).
    /// Returns the sizing and the simulated wall time it spent.
    fn simulate(fixed: f64, per_iteration: f64, stamp_factor: f64) -> (Sizing, f64) {
        let mut spent = 0.0;
        let sizing = size_kernel(|iterations, kernels| {
            let kernel = fixed + per_iteration * iterations as f64;
            spent += kernel * kernels as f64;
            Ok(BatchTime {
                kernels,
                stamped_ms: Some(vec![kernel * stamp_factor; kernels]),
                wall_ms: kernel * kernels as f64 + 0.05,
            })
        })
        .unwrap();
        (sizing, spent)
    }

    #[test]
    fn zero_timestamps_stop_at_the_wall_clock_target() {
        // lavapipe-like: 2 ms per 1024 iterations, timestamps all zero.
        let per_iteration = 2.0 / 1024.0;
        let (s, spent) = simulate(0.01, per_iteration, 0.0);
        let kernel = 0.01 + per_iteration * s.iterations as f64;
        assert!(kernel >= WALL_TARGET_MS, "{s:?}: {kernel} ms per kernel");
        assert!(
            kernel <= KERNEL_WALL_LIMIT_MS,
            "{s:?}: {kernel} ms per kernel"
        );
        // Sized by zeros alone the loop would double to its old cap (1M iterations: 2 s per
        // kernel here, minutes on lavapipe).
        assert!(spent < 4_000.0, "sizing spent {spent} ms");
        assert_eq!(s.timing, TimingSource::WallTimestampsImplausible);
    }

    #[test]
    fn good_timestamps_size_by_timestamps() {
        let (s, _) = simulate(0.002, 1e-4, 1.0);
        let kernel = 0.002 + 1e-4 * s.iterations as f64;
        assert!(
            (TARGET_MS..2.0 * TARGET_MS + 0.01).contains(&kernel),
            "{s:?}"
        );
        assert_eq!(s.timing, TimingSource::Timestamps);
    }

    #[test]
    fn a_slow_adapter_backs_off_under_the_bound() {
        // 100 ms per kernel already at 4 iterations.
        let (s, _) = simulate(0.0, 25.0, 0.0);
        assert!(25.0 * s.iterations as f64 <= KERNEL_WALL_LIMIT_MS, "{s:?}");
        assert!(s.iterations >= 1);
    }

    #[test]
    fn timestamps_are_judged_against_the_wall_clock() {
        use crate::gpu::timing::IMPLAUSIBLE_MIN_WALL_MS as MIN;
        assert_eq!(TimingSource::judge(None, 5.0), TimingSource::Wall);
        assert_eq!(
            TimingSource::judge(Some(0.0), MIN),
            TimingSource::WallTimestampsImplausible
        );
        assert_eq!(
            TimingSource::judge(Some(0.2 * MIN), MIN),
            TimingSource::Timestamps
        );
        // Short work: latency may dwarf it honestly.
        assert_eq!(
            TimingSource::judge(Some(0.0), 0.5 * MIN),
            TimingSource::Timestamps
        );
    }
}
