//! Shared primary surfaces: the engine's own pass, run before a technique that declares it needs
//! them (`Technique::inputs`). One jittered camera ray per pixel, **traced** (not rasterised) with
//! the reference's jitter sequence, so a technique's pixel footprints match the reference's; per
//! pixel it stores position, shading and geometric normals, material, direction to the viewer and
//! depth, emission, screen motion (camera and object motion) and object id (triangle and
//! material), and where the point was last frame, this frame's and last frame's (for
//! reprojection). Shaders read them through `gilab::primary`
//! (shaders/common/primary.wgsl) at bind group 1, binding 2.

use super::pipelines;
use crate::gpu::{shaders::ShaderLibrary, timing::PassTimer, Gpu};
use crate::scene::gpu_scene::GpuScene;
use anyhow::Result;

/// Matches `GSurface` in shaders/common/primary.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct PrimarySurface {
    /// xyz: position, w: 1 valid / 0 miss.
    pub pos: [f32; 4],
    /// xyz: shading normal, w: GGX alpha.
    pub normal_alpha: [f32; 4],
    /// xyz: geometric normal, w: specular factor.
    pub geo_specular: [f32; 4],
    /// rgb: base colour, w: metallic.
    pub base_metal: [f32; 4],
    /// xyz: direction to the viewer, w: distance to the camera.
    pub wo_dist: [f32; 4],
    /// rgb: emitted radiance towards the camera (sky radiance on a miss).
    pub emission: [f32; 4],
    /// This frame's pixel position minus last frame's, in pixels.
    pub motion: [f32; 2],
    /// The hit triangle's index in the scene (`Scene::triangles`), `NO_SURFACE` on a miss.
    pub triangle: u32,
    pub material: u32,
    /// xyz: where this surface point was last frame (it equals `pos` unless its object moved:
    /// playback), for temporal reprojection; w: unused.
    pub prev_pos: [f32; 4],
}

/// `PrimarySurface::triangle` of a miss.
pub const NO_SURFACE: u32 = u32::MAX;
pub const SURFACE_BYTES: u64 = std::mem::size_of::<PrimarySurface>() as u64;
/// The pass's entry file.
pub const ENTRY: &str = "frame/primary_surfaces.wgsl";
/// Its name in pass lists and timings.
pub const PASS: &str = "primary";

/// What a technique needs from the engine besides the scene and the frame uniforms.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FrameInputs {
    /// This frame's and last frame's primary surfaces (`gilab::primary`).
    pub primary_surfaces: bool,
}

/// The surfaces buffer: two segments of width × height surfaces (by frame parity).
pub fn surfaces_buffer(gpu: &Gpu, extent: [u32; 2]) -> wgpu::Buffer {
    let pixels = extent[0] as u64 * extent[1] as u64;
    pipelines::storage_buffer(gpu, "primary surfaces", 2 * pixels * SURFACE_BYTES)
}

pub fn pipeline(
    gpu: &Gpu,
    shaders: &ShaderLibrary,
    scene: &GpuScene,
    frame_layout: &wgpu::BindGroupLayout,
) -> Result<wgpu::ComputePipeline> {
    pipelines::compute_pipeline(gpu, shaders, ENTRY, &[&scene.layout, frame_layout])
}

/// Records the pass: one 8×8 workgroup per tile.
pub fn record(
    enc: &mut wgpu::CommandEncoder,
    timer: &mut PassTimer,
    pipeline: &wgpu::ComputePipeline,
    scene: &GpuScene,
    frame_bind_group: &wgpu::BindGroup,
    extent: [u32; 2],
) {
    let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
        label: Some(PASS),
        timestamp_writes: timer.compute_pass(PASS),
    });
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, &scene.bind_group, &[]);
    pass.set_bind_group(1, frame_bind_group, &[]);
    pass.dispatch_workgroups(extent[0].div_ceil(8), extent[1].div_ceil(8), 1);
}
