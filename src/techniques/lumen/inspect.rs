//! What tests and the viewer read back from Lumen: cards, probe and distance-field counters,
//! per-pixel planes, and distance-field queries. Never inside a frame.

use super::*;

impl Lumen {
    /// The cards and objects of the current scene.
    pub fn card_set(&self) -> Option<&crate::parts::surface_cache::cards::CardSet> {
        self.cache.card_set()
    }

    /// Screen-probe counters since the last reset (probes, screen-trace hits, world-traced
    /// rays, world cache reads); None before the first build.
    pub fn probe_stats(&self, gpu: &Gpu) -> Result<Option<ProbeStats>> {
        self.res.as_ref().map(|r| r.probes.stats(gpu)).transpose()
    }

    /// This frame's direct light per pixel from the direct-light part (`direct = "restir"`; with
    /// NEE apply computes it inline and this holds zeros).
    pub fn pixel_direct(&self, gpu: &Gpu) -> Result<Option<Vec<[f32; 4]>>> {
        let Some(r) = &self.res else {
            return Ok(None);
        };
        let pixels = (self.extent[0] * self.extent[1]) as usize;
        readback::read_buffer(gpu, r.buffer(18), pixels).map(Some)
    }

    /// What the last scene change or re-posing did to the surface cache.
    pub fn last_refresh(&self) -> Option<Refresh> {
        self.last_refresh
    }

    /// World-cache slots the last re-posing marked never traced (around moved objects).
    pub fn world_invalidated(&self) -> usize {
        self.world_invalidated
    }

    /// The surface cache's direct irradiance per atlas texel (tests).
    pub fn cache_direct(&self, gpu: &Gpu) -> Result<Option<Vec<[f32; 4]>>> {
        self.cache.read_direct(gpu)
    }

    /// The clipmaps' placement as of the last frame.
    pub fn clipmaps(&self) -> Option<&Clipmaps> {
        self.clipmaps.as_ref()
    }

    /// Pool use and failed allocations of the distance field.
    pub fn sdf_stats(&self, gpu: &Gpu) -> Result<Option<SdfStats>> {
        let Some(r) = &self.res else {
            return Ok(None);
        };
        let state: Vec<u32> = readback::read_buffer(gpu, r.buffer(9), 16)?;
        Ok(Some(SdfStats {
            pool_bricks: r.gpu_params.pool_bricks,
            allocated_bricks: r.gpu_params.pool_bricks - state[0].min(r.gpu_params.pool_bricks),
            failed_allocations: state[2],
            levels_built: self.clipmaps.as_ref().map_or(0, |c| c.built),
        }))
    }

    /// Answers `mode` for each input pair (points: (p, unused); rays: (origin, direction)) on
    /// the GPU against the distance field as of the last frame, two vec4 per input as
    /// shaders/lumen/query.wgsl writes them. At most QUERY_CAPACITY / 2.
    pub fn query(
        &self,
        ctx: &RenderContext,
        mode: QueryMode,
        inputs: &[([f32; 3], [f32; 3])],
    ) -> Result<Vec<[[f32; 4]; 2]>> {
        let (Some(p), Some(r)) = (&self.pipelines, &self.res) else {
            anyhow::bail!("lumen: query before the technique was built");
        };
        anyhow::ensure!(
            inputs.len() <= QUERY_CAPACITY / 2,
            "lumen: too many queries"
        );
        let gpu = ctx.gpu;
        let mut data = Vec::with_capacity(inputs.len() * 2);
        for (a, b) in inputs {
            data.push([a[0], a[1], a[2], 0.0]);
            data.push([b[0], b[1], b[2], 0.0]);
        }
        let queries = &r.queries;
        gpu.queue
            .write_buffer(queries, 0, bytemuck::cast_slice(&data));
        let mut params = r.gpu_params;
        params.query_count = inputs.len() as u32;
        params.query_mode = mode as u32;
        gpu.queue
            .write_buffer(&r.params_buffer, 0, bytemuck::bytes_of(&params));
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            pass.set_pipeline(&p.query);
            pass.set_bind_group(0, &ctx.scene.bind_group, &[]);
            pass.set_bind_group(1, &r.query_bind_group, &[]);
            pass.set_bind_group(2, &r.bind_group, &[]);
            pass.dispatch_workgroups((inputs.len() as u32).div_ceil(64), 1, 1);
        }
        gpu.submit("lumen: distance-field point queries", enc.finish());
        gpu.queue
            .write_buffer(&r.params_buffer, 0, bytemuck::bytes_of(&r.gpu_params));
        let out: Vec<[f32; 4]> = readback::read_buffer(gpu, queries, inputs.len() * 2)?;
        Ok(out.chunks(2).map(|c| [c[0], c[1]]).collect())
    }
}
