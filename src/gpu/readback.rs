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
    gpu.queue.submit([enc.finish()]);
    let (tx, rx) = std::sync::mpsc::channel();
    staging.slice(..).map_async(wgpu::MapMode::Read, move |r| {
        let _ = tx.send(r);
    });
    gpu.wait()?;
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
