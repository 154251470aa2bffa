//! Copies GPU buffers back to the CPU (for images, counters and tests).

use super::Gpu;
use anyhow::{anyhow, Result};

/// Reads `size` bytes of `buffer` (which must have COPY_SRC usage).
pub fn read_buffer_bytes(gpu: &Gpu, buffer: &wgpu::Buffer, size: u64) -> Result<Vec<u8>> {
    let staging = gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("readback staging"),
        size,
        usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
        mapped_at_creation: false,
    });
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    enc.copy_buffer_to_buffer(buffer, 0, &staging, 0, size);
    // Not relabelled: if the wait times out, what is stuck is the work queued before the copy.
    let submission = gpu.queue.submit([enc.finish()]);
    let (tx, rx) = std::sync::mpsc::channel();
    staging.slice(..).map_async(wgpu::MapMode::Read, move |r| {
        let _ = tx.send(r);
    });
    let what = format!(
        "{} (a readback copy queued behind it)",
        gpu.last_submitted()
    );
    gpu.wait_for(Some(submission), Some(&what))?;
    rx.recv()
        .map_err(|_| anyhow!("readback callback dropped"))?
        .map_err(|e| anyhow!("readback map failed: {e}"))?;
    let bytes = staging
        .slice(..)
        .get_mapped_range()
        .map_err(|e| anyhow!("readback range: {e:?}"))?
        .to_vec();
    staging.unmap();
    Ok(bytes)
}

/// Reads a buffer as plain-old-data values.
pub fn read_buffer<T: bytemuck::Pod>(
    gpu: &Gpu,
    buffer: &wgpu::Buffer,
    count: usize,
) -> Result<Vec<T>> {
    let bytes = read_buffer_bytes(gpu, buffer, (count * std::mem::size_of::<T>()) as u64)?;
    Ok(bytemuck::pod_collect_to_vec(&bytes))
}

/// A MAP_READ staging buffer read back without blocking the frame: copy into `buffer()`,
/// submit, `start` with the submission, then `poll` each frame until the bytes arrive (or
/// `poll(.., true)` waits for that submission only). Reused once read.
pub struct StagingRead {
    buffer: wgpu::Buffer,
    state: std::sync::Arc<std::sync::Mutex<MapState>>,
    submission: Option<wgpu::SubmissionIndex>,
    /// What that submission ran (named when the wait times out).
    what: String,
}

#[derive(Debug)]
enum MapState {
    Idle,
    Pending,
    Done(Result<(), String>),
}

impl StagingRead {
    pub fn new(gpu: &Gpu, label: &str, size: u64) -> StagingRead {
        StagingRead {
            buffer: gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: size.max(4),
                usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
                mapped_at_creation: false,
            }),
            state: std::sync::Arc::new(std::sync::Mutex::new(MapState::Idle)),
            submission: None,
            what: String::new(),
        }
    }

    /// The copy destination (only while idle: a pending buffer is mapped or about to be).
    pub fn buffer(&self) -> &wgpu::Buffer {
        &self.buffer
    }

    pub fn is_idle(&self) -> bool {
        matches!(*self.state.lock().expect("map state"), MapState::Idle)
    }

    /// Asks for the mapping once `submission` (which copied into the buffer) has run.
    pub fn start(&mut self, submission: wgpu::SubmissionIndex) {
        self.start_named(submission, String::new());
    }

    /// `start`, naming what the submission runs for a wait that times out.
    pub fn start_named(&mut self, submission: wgpu::SubmissionIndex, what: String) {
        self.what = what;
        *self.state.lock().expect("map state") = MapState::Pending;
        let state = self.state.clone();
        self.buffer
            .slice(..)
            .map_async(wgpu::MapMode::Read, move |r| {
                *state.lock().expect("map state") = MapState::Done(r.map_err(|e| e.to_string()));
            });
        self.submission = Some(submission);
    }

    /// The bytes once mapped (then the buffer is idle again); None while still pending or idle.
    /// `wait` blocks until this buffer's submission has run (not the whole queue).
    pub fn poll(&mut self, gpu: &Gpu, wait: bool) -> Result<Option<Vec<u8>>> {
        if self.is_idle() {
            return Ok(None);
        }
        if wait {
            let what = (!self.what.is_empty()).then_some(self.what.as_str());
            gpu.wait_for(self.submission.clone(), what)?;
        } else {
            gpu.device
                .poll(wgpu::PollType::Poll)
                .map_err(|e| gpu.poll_error(e))?;
        }
        let take = |state: &std::sync::Mutex<MapState>| {
            let mut s = state.lock().expect("map state");
            match std::mem::replace(&mut *s, MapState::Pending) {
                MapState::Done(r) => Some(r),
                other => {
                    *s = other;
                    None
                }
            }
        };
        let mut done = take(&self.state);
        // Another thread polling the same device may be running our callback right now: the
        // submission is done, so the callback is imminent.
        let start = std::time::Instant::now();
        while wait && done.is_none() && start.elapsed().as_secs() < 60 {
            std::thread::yield_now();
            gpu.device
                .poll(wgpu::PollType::Poll)
                .map_err(|e| gpu.poll_error(e))?;
            done = take(&self.state);
        }
        let Some(result) = done else {
            return Ok(None);
        };
        *self.state.lock().expect("map state") = MapState::Idle;
        self.submission = None;
        result.map_err(|e| anyhow!("readback map failed: {e}"))?;
        let bytes = self
            .buffer
            .slice(..)
            .get_mapped_range()
            .map_err(|e| anyhow!("readback range: {e:?}"))?
            .to_vec();
        self.buffer.unmap();
        Ok(Some(bytes))
    }
}
