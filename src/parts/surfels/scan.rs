//! GPU exclusive prefix sums (shaders/parts/surfels/scan.wgsl) over the surfel technique's fixed-size
//! arrays: one timed pass of three dispatches per scan, the total written after the last value.

use crate::gpu::{shaders::ShaderLibrary, timing::PassTimer, Gpu};
use crate::render::pipelines;
use anyhow::{anyhow, Result};

/// Values one `scan_local` workgroup covers (SCAN_BLOCK in scan.wgsl).
const BLOCK: u32 = 1024;
/// Most blocks `scan_blocks` handles in its single workgroup (256 threads x 16).
const MAX_BLOCKS: u32 = 4096;

pub const ENTRY: &str = "parts/surfels/scan.wgsl";

pub struct ScanPipelines {
    layout: wgpu::BindGroupLayout,
    local: wgpu::ComputePipeline,
    blocks: wgpu::ComputePipeline,
    add: wgpu::ComputePipeline,
}

/// One array to scan: its length and bind group.
pub struct ScanJob {
    pub name: &'static str,
    n: u32,
    bind_group: wgpu::BindGroup,
}

pub fn layout(gpu: &Gpu) -> wgpu::BindGroupLayout {
    pipelines::layout(
        gpu,
        "scan",
        &[
            pipelines::uniform_entry(0, wgpu::ShaderStages::COMPUTE),
            pipelines::storage_entry(1, false),
            pipelines::storage_entry(2, false),
        ],
    )
}

impl ScanPipelines {
    pub fn build(
        gpu: &Gpu,
        shaders: &ShaderLibrary,
        layout: &wgpu::BindGroupLayout,
    ) -> Result<Self> {
        let make =
            |entry: &str| pipelines::compute_pipeline_at(gpu, shaders, ENTRY, entry, &[layout]);
        Ok(ScanPipelines {
            layout: layout.clone(),
            local: make("scan_local")?,
            blocks: make("scan_blocks")?,
            add: make("scan_add")?,
        })
    }

    /// A job over the first `n` values of `values` (which holds n + 1: the total goes last),
    /// using `blocks` (at least `block_buffer_len(n)` u32) as scratch.
    pub fn job(
        &self,
        gpu: &Gpu,
        name: &'static str,
        n: u32,
        values: &wgpu::Buffer,
        blocks: &wgpu::Buffer,
    ) -> Result<ScanJob> {
        if n.div_ceil(BLOCK) > MAX_BLOCKS {
            return Err(anyhow!(
                "{name}: {n} values exceed the prefix sum's limit of {}",
                BLOCK * MAX_BLOCKS
            ));
        }
        let uniform = wgpu::util::DeviceExt::create_buffer_init(
            &gpu.device,
            &wgpu::util::BufferInitDescriptor {
                label: Some(name),
                contents: bytemuck::cast_slice(&[n, 0, 0, 0]),
                usage: wgpu::BufferUsages::UNIFORM,
            },
        );
        let bind_group = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(name),
            layout: &self.layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: uniform.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: values.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: blocks.as_entire_binding(),
                },
            ],
        });
        Ok(ScanJob {
            name,
            n,
            bind_group,
        })
    }

    /// Records the scan as one timed pass.
    pub fn record(&self, enc: &mut wgpu::CommandEncoder, timer: &mut PassTimer, job: &ScanJob) {
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some(job.name),
            timestamp_writes: timer.compute_pass(job.name),
        });
        let blocks = job.n.div_ceil(BLOCK).max(1);
        pass.set_bind_group(0, &job.bind_group, &[]);
        pass.set_pipeline(&self.local);
        pass.dispatch_workgroups(blocks, 1, 1);
        pass.set_pipeline(&self.blocks);
        pass.dispatch_workgroups(1, 1, 1);
        pass.set_pipeline(&self.add);
        pass.dispatch_workgroups(blocks, 1, 1);
    }
}

/// Scratch u32s a scan of `n` values needs.
pub fn block_buffer_len(n: u32) -> u64 {
    n.div_ceil(BLOCK).max(1) as u64
}
