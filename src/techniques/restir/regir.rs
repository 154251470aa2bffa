//! ReGIR ("Making Connections"; Boksansky et al. 2021), a part of [`RestirLighting`]: a
//! camera-centred grid whose cells hold light reservoirs pre-selected for the cell (by strength
//! over squared distance), rebuilt every frame; DI draws its initial candidates from the cell.
//! Runs only where the scene has many lights (rule 3). Shader: shaders/restir/regir_build.wgsl.

use super::lighting::RestirLighting;
use super::RestirSettings;
use crate::gpu::{timing::PassTimer, Gpu};
use crate::render::{pipelines, PassInfo, RenderContext};
use crate::scene::features::SceneFeatures;
use anyhow::Result;

/// Bytes of `RegirSlot` in shaders/restir/shared.wgsl.
pub const REGIR_SLOT_BYTES: u64 = 16;
/// ReGIR grid: REGIR_DIMS^3 cells around the camera.
pub const REGIR_DIMS: u32 = 16;
pub const PASS: &str = "regir_build";

#[derive(Default)]
pub struct Regir {
    pipeline: Option<wgpu::ComputePipeline>,
    pub(super) slots: Option<wgpu::Buffer>,
    /// Cell size in use (the setting, or the automatic one for this scene).
    pub(super) cell: f32,
}

impl Regir {
    pub(super) fn pipeline(
        ctx: &RenderContext,
        layout: &wgpu::BindGroupLayout,
    ) -> Result<wgpu::ComputePipeline> {
        ctx.pipeline("restir/regir_build.wgsl", layout)
    }

    pub(super) fn set_pipeline(&mut self, p: wgpu::ComputePipeline) {
        self.pipeline = Some(p);
    }

    /// The cell size and the slots buffer (kept while its size holds).
    pub(super) fn build_resources(&mut self, gpu: &Gpu, s: &RestirSettings, f: &SceneFeatures) {
        self.cell = if s.regir_cell_size > 0.0 {
            s.regir_cell_size
        } else {
            let lo = glam::Vec3::from(f.bounds_min);
            let hi = glam::Vec3::from(f.bounds_max);
            ((hi - lo).length() / 24.0).max(1e-3)
        };
        let cells = (REGIR_DIMS as u64).pow(3);
        let bytes = cells * s.regir_lights_per_cell as u64 * REGIR_SLOT_BYTES;
        self.slots = match self.slots.take() {
            Some(b) if b.size() == bytes.max(16) => Some(b),
            _ => Some(pipelines::storage_buffer(gpu, "restir regir slots", bytes)),
        };
    }

    /// One invocation per (cell, slot), 64 per workgroup.
    pub(super) fn record(
        &self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
        bind_group: &wgpu::BindGroup,
        lights_per_cell: u32,
    ) {
        let Some(p) = &self.pipeline else {
            return;
        };
        let slots = REGIR_DIMS.pow(3) * lights_per_cell;
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some(PASS),
            timestamp_writes: timer.compute_pass(PASS),
        });
        pass.set_pipeline(p);
        pass.set_bind_group(0, &ctx.scene.bind_group, &[]);
        pass.set_bind_group(1, ctx.frame_bind_group, &[]);
        pass.set_bind_group(2, bind_group, &[]);
        pass.dispatch_workgroups(slots.div_ceil(64), 1, 1);
    }
}

impl RestirLighting {
    /// ReGIR runs only where the scene calls for it: many lights (rule 3).
    pub fn regir_active(&self) -> bool {
        self.settings.regir && self.many_lights && self.class_candidates()[0] > 0
    }

    pub fn regir_pass(&self, f: &SceneFeatures) -> PassInfo {
        let s = &self.settings;
        PassInfo {
            name: PASS,
            runs: s.regir && f.many_lights,
            why: if !s.regir {
                "regir = false: candidates from the global light pool".into()
            } else if f.many_lights {
                format!(
                    "{} lights: {}^3 cells around the camera, {} lights each",
                    f.light_count(),
                    REGIR_DIMS,
                    s.regir_lights_per_cell
                )
            } else {
                format!(
                    "only {} lights: the global pool is enough, no grid",
                    f.light_count()
                )
            },
        }
    }
}
