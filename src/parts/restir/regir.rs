//! ReGIR ("Making Connections"; Boksansky et al. 2021), a part of [`RestirLighting`]: a
//! camera-centred grid whose cells hold light reservoirs pre-selected for the cell (by strength
//! over squared distance), rebuilt every frame; DI draws its initial candidates from the cell.
//! Each frame a mark pass flags the cells under the pixels, and the build fills only those
//! (a slot's random stream depends on its index alone, so the result equals a full build's).
//! Runs only where the scene has many lights (rule 3). Shaders: shaders/parts/restir/regir_mark.wgsl,
//! shaders/parts/restir/regir_build.wgsl.

use super::lighting::RestirLighting;
use super::RestirSettings;
use crate::gpu::{timing::PassTimer, Gpu};
use crate::render::{pipelines, PassInfo, RenderContext};
use crate::scene::features::SceneFeatures;
use anyhow::Result;

/// Bytes of `RegirSlot` in shaders/parts/restir/shared.wgsl.
pub const REGIR_SLOT_BYTES: u64 = 16;
/// ReGIR grid: REGIR_DIMS^3 cells around the camera.
pub const REGIR_DIMS: u32 = 16;
pub const PASS: &str = "regir_build";
pub const MARK_PASS: &str = "regir_mark";

#[derive(Default)]
pub struct Regir {
    /// (mark, build).
    pipelines: Option<(wgpu::ComputePipeline, wgpu::ComputePipeline)>,
    pub(super) slots: Option<wgpu::Buffer>,
    /// One u32 per cell: read this frame (set by the mark pass).
    pub(super) used: Option<wgpu::Buffer>,
    /// Cell size in use (the setting, or the automatic one for this scene).
    pub(super) cell: f32,
}

impl Regir {
    pub(super) fn pipelines(
        ctx: &RenderContext,
        layout: &wgpu::BindGroupLayout,
    ) -> Result<(wgpu::ComputePipeline, wgpu::ComputePipeline)> {
        Ok((
            ctx.pipeline("parts/restir/regir_mark.wgsl", layout)?,
            ctx.pipeline("parts/restir/regir_build.wgsl", layout)?,
        ))
    }

    pub(super) fn set_pipelines(&mut self, p: (wgpu::ComputePipeline, wgpu::ComputePipeline)) {
        self.pipelines = Some(p);
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
        if self.used.is_none() {
            self.used = Some(pipelines::storage_buffer(
                gpu,
                "restir regir used",
                cells * 4,
            ));
        }
    }

    /// The mark pass (one invocation per pixel), then the build: one invocation per
    /// (cell, slot), 64 per workgroup, of which unmarked cells return at once.
    pub(super) fn record(
        &self,
        ctx: &RenderContext,
        enc: &mut wgpu::CommandEncoder,
        timer: &mut PassTimer,
        bind_group: &wgpu::BindGroup,
        lights_per_cell: u32,
    ) {
        let (Some((mark, build)), Some(used)) = (&self.pipelines, &self.used) else {
            return;
        };
        enc.clear_buffer(used, 0, None);
        pipelines::image_pass(ctx, enc, timer, MARK_PASS, mark, bind_group);
        let slots = REGIR_DIMS.pow(3) * lights_per_cell;
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some(PASS),
            timestamp_writes: timer.compute_pass(PASS),
        });
        pass.set_pipeline(build);
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

    /// The mark and build passes.
    pub fn regir_passes(&self, f: &SceneFeatures) -> [PassInfo; 2] {
        let s = &self.settings;
        let runs = s.regir && f.many_lights;
        let build = PassInfo {
            name: PASS,
            runs,
            why: if !s.regir {
                "regir = false: candidates from the global light pool".into()
            } else if f.many_lights {
                format!(
                    "{} lights: the marked cells of {}^3 around the camera, {} lights each, 32 candidates a slot {}",
                    f.light_count(),
                    REGIR_DIMS,
                    s.regir_lights_per_cell,
                    if s.regir_tree && s.light_classes {
                        "by the light tree's importance for the cell"
                    } else {
                        "by power"
                    }
                )
            } else {
                format!(
                    "only {} lights: the global pool is enough, no grid",
                    f.light_count()
                )
            },
        };
        let mark = PassInfo {
            name: MARK_PASS,
            runs,
            why: if runs {
                "flags the ReGIR cells under the pixels: only those are built".into()
            } else {
                "no ReGIR grid".into()
            },
        };
        [mark, build]
    }
}
