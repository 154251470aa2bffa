//! Texel copies of a part's storage buffers: the same words in a 2D texture that shaders read
//! with `textureLoad`. Lavapipe (CI's renderer, Mesa 22.3) loads a storage buffer in a scalar
//! loop over the SIMD lanes: a vec4 costs about 22 ns a lane, one word 6 ns, a texel 3 ns
//! (`cargo run --release --example load_costs`, docs/performance.md). Where a pass reads the
//! same records many times (a distance-field step's ten words, a cache lookup's card walk),
//! the buffer stays for its writers and the readers take the copy. The scene's records have
//! their own copy in the engine (`SceneTexels`, src/scene/gpu_scene.rs).

use crate::gpu::Gpu;
use anyhow::{bail, Result};

/// Texels per row of the distance field's and DDGI's copies (`wide_texel` in
/// shaders/parts/texels.wgsl: 8191, 13).
pub const WIDE_ROW: u32 = 8192;

/// A texture holding `count` texels of `format` in rows of `per_row` (a power of two, so that a
/// shader finds texel i at `(i & (per_row - 1), i >> log2(per_row))`).
pub struct BufferTexels {
    texture: wgpu::Texture,
    pub view: wgpu::TextureView,
    format: wgpu::TextureFormat,
    per_row: u32,
    count: u32,
}

impl BufferTexels {
    /// An empty copy (zeros) for `count` texels; an error when the rows do not fit the device's
    /// largest 2D texture.
    pub fn new(
        gpu: &Gpu,
        label: &str,
        format: wgpu::TextureFormat,
        count: u32,
        per_row: u32,
    ) -> Result<BufferTexels> {
        debug_assert!(per_row.is_power_of_two());
        let rows = count.div_ceil(per_row).max(1);
        let max = gpu.device.limits().max_texture_dimension_2d;
        if rows > max || per_row > max {
            bail!(
                "{label}: {count} texels need a {per_row} x {rows} texture, over this device's \
                 {max} texels a side (lower the resolution or the levels)"
            );
        }
        let texture = gpu.device.create_texture(&wgpu::TextureDescriptor {
            label: Some(label),
            size: wgpu::Extent3d {
                width: per_row,
                height: rows,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format,
            // COPY_SRC: tests read a copy back (tests/gpu.rs).
            usage: wgpu::TextureUsages::TEXTURE_BINDING
                | wgpu::TextureUsages::COPY_DST
                | wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        });
        let view = texture.create_view(&Default::default());
        Ok(BufferTexels {
            texture,
            view,
            format,
            per_row,
            count,
        })
    }

    /// The texture (rows of `per_row` texels).
    pub fn texture(&self) -> &wgpu::Texture {
        &self.texture
    }

    fn texel_bytes(&self) -> u32 {
        self.format.block_copy_size(None).unwrap_or(4)
    }

    /// Records a copy of the first `count` texels of `buffer` from byte `offset` on: whole rows,
    /// then the last row's part.
    pub fn copy_from(&self, enc: &mut wgpu::CommandEncoder, buffer: &wgpu::Buffer, offset: u64) {
        let row_bytes = self.per_row * self.texel_bytes();
        let full_rows = self.count / self.per_row;
        let rest = self.count % self.per_row;
        let mut copy = |first_row: u32, width: u32, height: u32| {
            enc.copy_buffer_to_texture(
                wgpu::TexelCopyBufferInfo {
                    buffer,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset: offset + first_row as u64 * row_bytes as u64,
                        bytes_per_row: Some(row_bytes),
                        rows_per_image: Some(height),
                    },
                },
                wgpu::TexelCopyTextureInfo {
                    texture: &self.texture,
                    mip_level: 0,
                    origin: wgpu::Origin3d {
                        x: 0,
                        y: first_row,
                        z: 0,
                    },
                    aspect: wgpu::TextureAspect::All,
                },
                wgpu::Extent3d {
                    width,
                    height,
                    depth_or_array_layers: 1,
                },
            );
        };
        if full_rows > 0 {
            copy(0, self.per_row, full_rows);
        }
        if rest > 0 {
            copy(full_rows, rest, 1);
        }
    }

    /// Writes `bytes` (at most `count` texels) from the CPU, the rest of the last row zero.
    pub fn write(&self, gpu: &Gpu, bytes: &[u8]) {
        debug_assert!(
            bytes.len() <= (self.count * self.texel_bytes()) as usize,
            "more bytes than texels"
        );
        let row_bytes = (self.per_row * self.texel_bytes()) as usize;
        let rows = self.count.div_ceil(self.per_row).max(1);
        let mut padded = bytes.to_vec();
        padded.resize(row_bytes * rows as usize, 0);
        gpu.queue.write_texture(
            self.texture.as_image_copy(),
            &padded,
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(row_bytes as u32),
                rows_per_image: Some(rows),
            },
            wgpu::Extent3d {
                width: self.per_row,
                height: rows,
                depth_or_array_layers: 1,
            },
        );
    }
}

/// A layout entry for a 2D texture of `sample_type` read by compute passes (`textureLoad`).
pub fn texture_entry(
    binding: u32,
    sample_type: wgpu::TextureSampleType,
) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Texture {
            sample_type,
            view_dimension: wgpu::TextureViewDimension::D2,
            multisampled: false,
        },
        count: None,
    }
}
