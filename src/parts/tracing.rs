//! Scene tracing as a part: the rays of Lumen's scene representation (`gilab::tracing`,
//! shaders/parts/tracing/shared.wgsl), through the global distance field or the BVH
//! (`trace_scene`, mode by [`FLAG_BVH`]), and the light at a hit from the surface cache. Its
//! bindings sit in bind group 2 of the pass that traces: the uniform at 0 ([`TracingParamsGpu`])
//! and the distance field at 4-11 ([`DISTANCE_FIELD_BINDINGS`]), with its texel copies at
//! 27-30 ([`DistanceFieldTexels`]). Lumen builds and fills the distance field and binds it; a
//! holder without one (the standalone surface cache and its world cache, for ReSTIR GI's paths)
//! binds [`BvhOnly`]: BVH mode, the distance-field slots filled with 16-byte buffers and
//! one-texel textures no pass reads.

use crate::gpu::Gpu;
use crate::parts::texels::{texture_entry, BufferTexels, WIDE_ROW};
use crate::render::pipelines;
use anyhow::Result;

/// One clipmap level of the distance field in [`TracingParamsGpu`].
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct LevelGpu {
    pub origin: [f32; 4],
    pub brick_origin: [i32; 4],
    pub update: [u32; 4],
}

/// `TracingParams` of shaders/parts/tracing/shared.wgsl (binding 0): the distance field's
/// clipmaps and the flags, then the holder's fields (Lumen's gather and queries; zero for a
/// holder without them).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct TracingParamsGpu {
    pub levels: [LevelGpu; 6],
    pub resolution: u32,
    pub levels_built: u32,
    pub bricks_per_axis: u32,
    pub pool_bricks: u32,
    pub flags: u32,
    pub rays_per_pixel: u32,
    pub gather_downsample: u32,
    pub gather_width: u32,
    pub gather_height: u32,
    pub dirty_box_count: u32,
    pub sign_rays: u32,
    pub query_count: u32,
    pub slice_depth: f32,
    pub query_mode: u32,
    pub pad: [u32; 2],
}

/// Rays trace the BVH (exact hits), not the distance field.
pub const FLAG_BVH: u32 = 1;
/// Misses see the sky.
pub const FLAG_SKY: u32 = 2;
/// The scene has lights (hit lighting samples them).
pub const FLAG_LIGHTS: u32 = 16;
/// SDF hits without a card answer read the voxel lighting.
pub const FLAG_VOXEL_LIGHTING: u32 = 128;

/// Bindings of group 2 that hold the distance field (11: the edit boxes, read-only).
pub const DISTANCE_FIELD_BINDINGS: [u32; 8] = [4, 5, 6, 7, 8, 9, 10, 11];

/// Bindings of group 2 that hold the distance field's texel copies: brick table, brick
/// coordinates, the brick pool's distances, the coarse volume.
pub const DISTANCE_FIELD_TEXEL_BINDINGS: [u32; 4] = [27, 28, 29, 30];

/// Layout entries of the tracing bindings (uniform and distance field).
pub fn layout_entries() -> Vec<wgpu::BindGroupLayoutEntry> {
    let mut entries = vec![pipelines::uniform_entry(0, wgpu::ShaderStages::COMPUTE)];
    entries.extend(DISTANCE_FIELD_BINDINGS.map(|b| pipelines::storage_entry(b, b == 11)));
    entries.extend(DistanceFieldTexels::layout_entries());
    entries
}

/// The distance field's words again as textures, which every SDF step reads (up to ten words:
/// the coarse bound, a brick's table entry and coordinates, eight voxels). Copied from the
/// buffers at the end of each update (`copy`); the update's own passes read the buffers. On
/// lavapipe this is most of a distance-field ray's cost (crate::parts::texels).
pub struct DistanceFieldTexels {
    table: BufferTexels,
    coords: BufferTexels,
    pool: BufferTexels,
    coarse: BufferTexels,
}

impl DistanceFieldTexels {
    /// Copies for `slots` brick slots, `pool_bricks` bricks of 512 voxels and `coarse_cells`
    /// coarse cells.
    pub fn new(
        gpu: &Gpu,
        slots: u32,
        pool_bricks: u32,
        coarse_cells: u32,
    ) -> Result<DistanceFieldTexels> {
        use wgpu::TextureFormat as F;
        let texels = |label, format, count| BufferTexels::new(gpu, label, format, count, WIDE_ROW);
        Ok(DistanceFieldTexels {
            table: texels("sdf brick table texels", F::R32Uint, slots)?,
            coords: texels("sdf brick coord texels", F::Rgba32Sint, slots)?,
            pool: texels("sdf brick pool texels", F::R32Uint, pool_bricks * 512)?,
            coarse: texels("sdf coarse texels", F::R32Float, coarse_cells)?,
        })
    }

    /// Layout entries of the copies.
    pub fn layout_entries() -> [wgpu::BindGroupLayoutEntry; 4] {
        use wgpu::TextureSampleType as T;
        let [a, b, c, d] = DISTANCE_FIELD_TEXEL_BINDINGS;
        [
            texture_entry(a, T::Uint),
            texture_entry(b, T::Sint),
            texture_entry(c, T::Uint),
            texture_entry(d, T::Float { filterable: false }),
        ]
    }

    /// Records the copy of the buffers at bindings 4 (table), 5 (coordinates), 6 (the pool,
    /// whose distances come first) and 7 (coarse).
    pub fn copy(
        &self,
        enc: &mut wgpu::CommandEncoder,
        table: &wgpu::Buffer,
        coords: &wgpu::Buffer,
        pool: &wgpu::Buffer,
        coarse: &wgpu::Buffer,
    ) {
        self.table.copy_from(enc, table, 0);
        self.coords.copy_from(enc, coords, 0);
        self.pool.copy_from(enc, pool, 0);
        self.coarse.copy_from(enc, coarse, 0);
    }

    /// Bind group entries of the copies.
    pub fn entries(&self) -> Vec<wgpu::BindGroupEntry<'_>> {
        let views = [
            &self.table.view,
            &self.coords.view,
            &self.pool.view,
            &self.coarse.view,
        ];
        DISTANCE_FIELD_TEXEL_BINDINGS
            .iter()
            .zip(views)
            .map(|(&binding, view)| wgpu::BindGroupEntry {
                binding,
                resource: wgpu::BindingResource::TextureView(view),
            })
            .collect()
    }
}

/// The tracing bindings of a holder without a distance field: its uniform (BVH mode) and
/// unread placeholders for the distance field's slots.
pub struct BvhOnly {
    pub uniform: wgpu::Buffer,
    unused: Vec<wgpu::Buffer>,
    unused_texels: DistanceFieldTexels,
}

impl BvhOnly {
    pub fn new(gpu: &Gpu, label: &str) -> Result<BvhOnly> {
        let uniform = pipelines::init_buffer(
            gpu,
            label,
            &[0u8; std::mem::size_of::<TracingParamsGpu>()],
            wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        );
        let unused = DISTANCE_FIELD_BINDINGS
            .iter()
            .map(|_| pipelines::storage_buffer(gpu, "tracing: no distance field", 16))
            .collect();
        Ok(BvhOnly {
            uniform,
            unused,
            unused_texels: DistanceFieldTexels::new(gpu, 1, 0, 1)?,
        })
    }

    /// BVH tracing with the sky and the lights as the scene has them.
    pub fn flags(sky: bool, lights: bool) -> u32 {
        FLAG_BVH | if sky { FLAG_SKY } else { 0 } | if lights { FLAG_LIGHTS } else { 0 }
    }

    /// Writes this frame's uniform.
    pub fn write(&self, gpu: &Gpu, flags: u32) {
        let params = TracingParamsGpu {
            flags,
            ..Default::default()
        };
        gpu.queue
            .write_buffer(&self.uniform, 0, bytemuck::bytes_of(&params));
    }

    /// Bind group entries of the tracing bindings.
    pub fn entries(&self) -> Vec<wgpu::BindGroupEntry<'_>> {
        let mut all = vec![wgpu::BindGroupEntry {
            binding: 0,
            resource: self.uniform.as_entire_binding(),
        }];
        all.extend(
            DISTANCE_FIELD_BINDINGS
                .iter()
                .zip(&self.unused)
                .map(|(&binding, b)| wgpu::BindGroupEntry {
                    binding,
                    resource: b.as_entire_binding(),
                }),
        );
        all.extend(self.unused_texels.entries());
        all
    }
}
