//! Per-pass GPU timings from timestamp queries (one begin/end pair per pass).

use super::Gpu;
use anyhow::Result;

/// Where a measured time comes from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum TimingSource {
    /// Timestamp queries around each pass.
    #[default]
    Timestamps,
    /// No timestamp queries on this adapter: wall time of submit-to-idle.
    Wall,
    /// Timestamps came out implausibly short against the waited wall time (lavapipe: beside
    /// egui's graphics work, and end stamps that are not after their begin, which read as 0):
    /// wall time, no per-pass split.
    WallTimestampsImplausible,
}

/// Timestamps that add up to less than this share of the wall time are not believed.
pub const IMPLAUSIBLE_SHARE: f64 = 0.1;
/// ... once the wall time is at least this long: below it, submission and polling latency
/// (a viewer polls once per displayed frame) can dwarf short GPU work honestly.
pub const IMPLAUSIBLE_MIN_WALL_MS: f64 = 20.0;

impl TimingSource {
    /// The one plausibility check for every timed piece of GPU work (engine frames, the clock
    /// calibration kernel): `stamped_ms` is the sum of the timestamped passes (None without
    /// timestamp queries), `wall_ms` the wall time from when the GPU could start the work to
    /// when its completion was seen. The wall clock cannot be ten times the GPU work it waited
    /// for, so timestamps that say so are wrong.
    pub fn judge(stamped_ms: Option<f64>, wall_ms: f64) -> TimingSource {
        match stamped_ms {
            None => TimingSource::Wall,
            Some(s) if wall_ms >= IMPLAUSIBLE_MIN_WALL_MS && s < IMPLAUSIBLE_SHARE * wall_ms => {
                TimingSource::WallTimestampsImplausible
            }
            Some(_) => TimingSource::Timestamps,
        }
    }

    /// Words for reports, e.g. in the clock check.
    pub fn describe(self) -> &'static str {
        match self {
            TimingSource::Timestamps => "timestamps",
            TimingSource::Wall => "no timestamps: using wall time",
            TimingSource::WallTimestampsImplausible => "timestamps implausible: using wall time",
        }
    }
}

/// Timed passes per frame (the surfel technique records about 20).
pub const MAX_PASSES: u32 = 64;

pub struct PassTimer {
    query_set: Option<wgpu::QuerySet>,
    resolve: Option<wgpu::Buffer>,
    names: Vec<&'static str>,
}

impl PassTimer {
    pub fn new(gpu: &Gpu) -> PassTimer {
        let (query_set, resolve) = if gpu.timestamp_period.is_some() {
            let qs = gpu.device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("pass timestamps"),
                ty: wgpu::QueryType::Timestamp,
                count: MAX_PASSES * 2,
            });
            let buf = gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("timestamp resolve"),
                size: (MAX_PASSES * 2 * 8) as u64,
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            });
            (Some(qs), Some(buf))
        } else {
            (None, None)
        };
        PassTimer {
            query_set,
            resolve,
            names: Vec::new(),
        }
    }

    /// Starts a new frame's set of passes.
    pub fn begin_frame(&mut self) {
        self.names.clear();
    }

    /// Timestamp writes for a compute pass named `name` (None when unsupported or full).
    pub fn compute_pass(
        &mut self,
        name: &'static str,
    ) -> Option<wgpu::ComputePassTimestampWrites<'_>> {
        let i = self.next_index(name)?;
        Some(wgpu::ComputePassTimestampWrites {
            query_set: self.query_set.as_ref()?,
            beginning_of_pass_write_index: Some(2 * i),
            end_of_pass_write_index: Some(2 * i + 1),
        })
    }

    pub fn render_pass(
        &mut self,
        name: &'static str,
    ) -> Option<wgpu::RenderPassTimestampWrites<'_>> {
        let i = self.next_index(name)?;
        Some(wgpu::RenderPassTimestampWrites {
            query_set: self.query_set.as_ref()?,
            beginning_of_pass_write_index: Some(2 * i),
            end_of_pass_write_index: Some(2 * i + 1),
        })
    }

    fn next_index(&mut self, name: &'static str) -> Option<u32> {
        self.query_set.as_ref()?;
        if self.names.len() as u32 >= MAX_PASSES {
            return None;
        }
        self.names.push(name);
        Some(self.names.len() as u32 - 1)
    }

    /// Records the resolve of this frame's queries into the encoder.
    pub fn resolve(&self, enc: &mut wgpu::CommandEncoder) {
        if let (Some(qs), Some(buf)) = (&self.query_set, &self.resolve) {
            if !self.names.is_empty() {
                enc.resolve_query_set(qs, 0..self.names.len() as u32 * 2, buf, 0);
            }
        }
    }

    /// This frame's pass names, in the order of their queries.
    pub fn names(&self) -> &[&'static str] {
        &self.names
    }

    /// Resolves this frame's queries and copies the ticks to `dst` at `offset` (a staging
    /// buffer read later: frames can be in flight while earlier ones are read).
    pub fn resolve_to(&self, enc: &mut wgpu::CommandEncoder, dst: &wgpu::Buffer, offset: u64) {
        if let Some(buf) = &self.resolve {
            if !self.names.is_empty() {
                self.resolve(enc);
                enc.copy_buffer_to_buffer(buf, 0, dst, offset, self.names.len() as u64 * 16);
            }
        }
    }

    /// (name, milliseconds) per pass from ticks copied by `resolve_to`.
    pub fn ms_from_ticks(
        gpu: &Gpu,
        names: &[&'static str],
        ticks: &[u64],
    ) -> Vec<(&'static str, f64)> {
        let Some(period) = gpu.timestamp_period else {
            return Vec::new();
        };
        names
            .iter()
            .enumerate()
            .map(|(i, n)| {
                let dt = ticks[2 * i + 1].saturating_sub(ticks[2 * i]);
                (*n, dt as f64 * period as f64 * 1e-6)
            })
            .collect()
    }

    /// Reads back (name, milliseconds) per pass; call after the frame's submission.
    pub fn read(&self, gpu: &Gpu) -> Result<Vec<(&'static str, f64)>> {
        let (Some(buf), Some(period)) = (&self.resolve, gpu.timestamp_period) else {
            return Ok(Vec::new());
        };
        if self.names.is_empty() {
            return Ok(Vec::new());
        }
        let ticks: Vec<u64> = super::readback::read_buffer(gpu, buf, self.names.len() * 2)?;
        Ok(self
            .names
            .iter()
            .enumerate()
            .map(|(i, n)| {
                let dt = ticks[2 * i + 1].saturating_sub(ticks[2 * i]);
                (*n, dt as f64 * period as f64 * 1e-6)
            })
            .collect())
    }
}
