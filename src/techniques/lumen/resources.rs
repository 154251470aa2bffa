//! Lumen's layouts, flags and sized resources (buffers, bind groups), rebuilt when parameters,
//! the image or the scene change; and which parts of the distance field a scene edit dirties.

use super::*;

impl Lumen {
    pub(super) fn layouts(&mut self, gpu: &Gpu) -> &Layouts {
        self.layouts.get_or_insert_with(|| {
            // Lumen's own bindings: its uniform, the distance field (4-11), the gather, debug
            // and per-pixel direct light (16-18); the surface cache's fill the others.
            let mut entries = vec![pipelines::uniform_entry(0, wgpu::ShaderStages::COMPUTE)];
            for b in (4..=11).chain(16..=18) {
                entries.push(pipelines::storage_entry(b, b == 11));
            }
            entries.extend(DistanceFieldTexels::layout_entries());
            entries.extend(SurfaceCache::layout_entries());
            Layouts {
                lumen: pipelines::layout(gpu, "lumen", &entries),
                args: pipelines::layout(
                    gpu,
                    "lumen sdf args",
                    &[pipelines::storage_entry(0, false)],
                ),
                fill_level: pipelines::layout(
                    gpu,
                    "lumen fill level",
                    &[pipelines::uniform_entry(0, wgpu::ShaderStages::COMPUTE)],
                ),
                queries: pipelines::layout(
                    gpu,
                    "lumen queries",
                    &[pipelines::storage_entry(0, false)],
                ),
                direct: self.restir_direct.output_layout(gpu).clone(),
                specular: self.reflections.output_layout(gpu).clone(),
                probes: ScreenProbes::layout(gpu),
            }
        })
    }

    pub(super) fn flags(&self) -> u32 {
        let s = &self.settings;
        let mut flags = 0;
        for (on, flag) in [
            (s.bvh, FLAG_BVH),
            (self.sky, FLAG_SKY),
            (s.accumulate, FLAG_ACCUMULATE),
            (s.debug_views, FLAG_DEBUG),
            (self.features.light_count() > 0, FLAG_LIGHTS),
            (self.direct_restir(), FLAG_DIRECT_RESTIR),
            (self.reflections_active(), FLAG_REFLECTIONS),
            (self.voxel_lighting_active(), FLAG_VOXEL_LIGHTING),
        ] {
            if on {
                flags |= flag;
            }
        }
        flags
    }

    /// (Re)builds the surface cache, the distance field's buffers and everything sized by the
    /// parameters or the image; the cache and the distance field start empty.
    pub(super) fn build_resources(&mut self, ctx: &RenderContext) -> Result<()> {
        self.settings.check()?;
        let gpu = ctx.gpu;
        let data = &ctx.scene.data;
        self.features = data.features.clone();
        self.sky = ctx.scene.sky.max_element() > 0.0 && self.features.sky_visible;
        self.extent = ctx.extent;
        let s = self.settings.clone();
        let bounds = (
            Vec3::from(self.features.bounds_min),
            Vec3::from(self.features.bounds_max),
        );
        self.cache.settings = s.surface_cache_settings();
        self.cache.build_resources(ctx)?;
        let layouts = {
            let l = self.layouts(gpu);
            [
                l.lumen.clone(),
                l.args.clone(),
                l.fill_level.clone(),
                l.queries.clone(),
                l.probes.clone(),
                l.direct.clone(),
                l.specular.clone(),
            ]
        };
        let max_binding = gpu.device.limits().max_storage_buffer_binding_size;
        let clip = Clipmaps::new(s.clipmap_resolution, s.clipmap_levels, bounds);
        let nb = clip.bricks_per_axis() as u64;
        let slots = s.clipmap_levels as u64 * nb * nb * nb;
        let pool_bricks = slots.min(max_binding / (BRICK_BYTES + VOXEL_LIGHTING_BYTES)) as u32;
        let coarse_cells = s.clipmap_levels as u64 * (s.clipmap_resolution as u64 / 4).pow(3);
        let pixels = ctx.extent[0] as u64 * ctx.extent[1] as u64;
        // Screen probes integrate at full resolution into the gather buffer.
        let ds = if s.screen_probes {
            1
        } else {
            s.gather_downsample
        };
        let gather = [ctx.extent[0].div_ceil(ds), ctx.extent[1].div_ceil(ds)];
        let buf = |label: &str, size: u64| pipelines::storage_buffer(gpu, label, size.max(16));
        let gpu_params = TracingParamsGpu {
            resolution: s.clipmap_resolution,
            bricks_per_axis: clip.bricks_per_axis(),
            pool_bricks,
            rays_per_pixel: s.rays_per_pixel,
            gather_downsample: ds,
            gather_width: gather[0],
            gather_height: gather[1],
            sign_rays: s.sign_rays,
            ..Default::default()
        };
        let params_buffer = init_buffer(
            gpu,
            "lumen params",
            bytemuck::bytes_of(&gpu_params),
            wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        );
        let buffers = vec![
            (0, params_buffer.clone()),
            (4, buf("lumen brick table", slots * 4)),
            (5, buf("lumen brick coords", slots * 16)),
            (
                6,
                buf(
                    "lumen brick pool",
                    pool_bricks as u64 * (BRICK_BYTES + VOXEL_LIGHTING_BYTES),
                ),
            ),
            (7, buf("lumen coarse sdf", coarse_cells * 4)),
            (8, buf("lumen free bricks", pool_bricks as u64 * 4)),
            (9, buf("lumen sdf state", 64)),
            // Per level the bricks to fill, then every allocated brick (the voxel lighting's list).
            (10, buf("lumen fill list", 2 * slots * 4)),
            (
                11,
                buf("lumen dirty boxes", (2 * sdf::MAX_DIRTY_BOXES as u64) * 16),
            ),
            (
                16,
                buf("lumen gather", 2 * gather[0] as u64 * gather[1] as u64 * 16),
            ),
            (17, buf("lumen debug", 4 * pixels * 16)),
            // Direct light, then the reflections part's two planes.
            (18, buf("lumen pixel direct", 3 * pixels * 16)),
        ];
        let queries = buf("lumen queries", QUERY_CAPACITY as u64 * 32);
        let sdf_texels =
            DistanceFieldTexels::new(gpu, slots as u32, pool_bricks, coarse_cells as u32)?;
        let bind_group = lumen_bind_group(gpu, &layouts[0], &buffers, &sdf_texels, &self.cache);
        // One fill dispatch per level, then the voxel lighting's.
        let args = pipelines::indirect_args_buffer(gpu, "lumen fill args", MAX_LEVELS as u64 + 1);
        let args_bind_group =
            pipelines::buffers_bind_group(gpu, "lumen sdf args", &layouts[1], &[&args]);
        let fill_bind_groups = (0..MAX_LEVELS as u32)
            .map(|l| {
                let b = init_buffer(
                    gpu,
                    "lumen fill level",
                    bytemuck::cast_slice(&[l, 0, 0, 0]),
                    wgpu::BufferUsages::UNIFORM,
                );
                pipelines::buffers_bind_group(gpu, "lumen fill level", &layouts[2], &[&b])
            })
            .collect();
        let pixel_direct = &buffers.last().expect("pixel direct").1;
        let query_bind_group =
            pipelines::buffers_bind_group(gpu, "lumen queries", &layouts[3], &[&queries]);
        let direct_bind_group =
            pipelines::buffers_bind_group(gpu, "lumen pixel direct", &layouts[5], &[pixel_direct]);
        let specular_bind_group = pipelines::buffers_bind_group(
            gpu,
            "lumen pixel specular",
            &layouts[6],
            &[pixel_direct],
        );
        let world = WorldCache::new(gpu, s.world_cache_settings())?;
        let res = Resources {
            params_buffer,
            buffers,
            sdf_texels,
            bind_group,
            args_bind_group,
            fill_bind_groups,
            query_bind_group,
            queries,
            direct_bind_group,
            specular_bind_group,
            args,
            gpu_params,
            probes: ScreenProbes::new(ctx, &layouts[4], &s, &world)?,
            world,
        };
        // Every brick free, every slot unbuilt.
        let stack: Vec<u32> = (0..pool_bricks).rev().collect();
        gpu.queue
            .write_buffer(res.buffer(8), 0, bytemuck::cast_slice(&stack));
        let mut state = [0u32; 16];
        state[0] = pool_bricks;
        gpu.queue
            .write_buffer(res.buffer(9), 0, bytemuck::cast_slice(&state));
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        enc.clear_buffer(res.buffer(5), 0, None);
        let empty_table = vec![u32::MAX; (res.buffer(4).size() / 4) as usize];
        gpu.queue
            .write_buffer(res.buffer(4), 0, bytemuck::cast_slice(&empty_table));
        res.copy_sdf_texels(&mut enc);
        gpu.submit("lumen: distance field brick pool reset", enc.finish());
        self.clipmaps = Some(clip);
        self.scene_tris = data.tris.clone();
        self.res = Some(res);
        self.built_with = Some(s);
        Ok(())
    }

    /// A rebuild for the same image size keeps what still holds: unchanged triangles keep
    /// everything; a material edit recaptures the cards (the surface cache's part); moved, added
    /// or removed triangles rebuild the cards (and the cache lighting) and only the
    /// distance-field bricks they touch. Returns false when the resources must be built anew.
    pub(super) fn refresh_for_scene(&mut self, ctx: &RenderContext) -> Result<bool> {
        let gpu = ctx.gpu;
        let data = &ctx.scene.data;
        if self.res.is_none() || self.extent != ctx.extent {
            return Ok(false);
        }
        self.features = data.features.clone();
        self.sky = ctx.scene.sky.max_element() > 0.0 && self.features.sky_visible;
        self.cache.settings = self.settings.surface_cache_settings();
        let refresh = self.cache.refresh_for_scene(ctx)?;
        self.last_refresh = Some(refresh);
        match refresh {
            Refresh::Build => return Ok(false),
            Refresh::Kept | Refresh::Moved => {}
            Refresh::NewCards => {
                let layout = self.layouts(gpu).lumen.clone();
                let Some(r) = self.res.as_mut() else {
                    return Ok(false);
                };
                r.bind_group =
                    lumen_bind_group(gpu, &layout, &r.buffers, &r.sdf_texels, &self.cache);
            }
        }
        if data.tris != self.scene_tris {
            let objects = self.cache.card_set().map(|c| c.tri_object.as_slice());
            let changed = match objects {
                Some(o) if o.len() == data.tris.len() => {
                    changed_objects(&self.scene_tris, &data.tris, o)
                }
                _ => changed_triangles(&self.scene_tris, &data.tris),
            };
            if refresh == Refresh::Moved {
                // The seed's reaction: bricks and world probes around the moved objects' old
                // and new places start again; the rest of the history stays (temporal passes
                // reproject with the motion vectors).
                if let Some(r) = self.res.as_ref() {
                    self.world_invalidated = r.world.invalidate(gpu, &changed);
                }
            }
            if let Some(c) = self.clipmaps.as_mut() {
                c.dirty.extend(changed);
            }
            self.scene_tris = data.tris.clone();
            if refresh != Refresh::Moved {
                self.reset_history(gpu);
            }
        }
        Ok(true)
    }
}

/// Per object whose triangles changed (same triangle list length, `object` per triangle): the
/// box of its changed triangles where they were and the box where they are (the distance field
/// rebuilds the bricks of both).
pub(super) fn changed_objects(
    old: &[[Vec3; 3]],
    new: &[[Vec3; 3]],
    object: &[u32],
) -> Vec<(Vec3, Vec3)> {
    use std::collections::BTreeMap;
    let empty = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    let mut boxes: BTreeMap<u32, [(Vec3, Vec3); 2]> = BTreeMap::new();
    for ((a, b), &o) in old.iter().zip(new).zip(object) {
        if a == b {
            continue;
        }
        let e = boxes.entry(o).or_insert([empty; 2]);
        for (bx, t) in e.iter_mut().zip([a, b]) {
            bx.0 = bx.0.min(t[0].min(t[1]).min(t[2]));
            bx.1 = bx.1.max(t[0].max(t[1]).max(t[2]));
        }
    }
    boxes.into_values().flatten().collect()
}

/// Scene triangles that are in one list and not the other (a multiset difference by exact
/// vertex bits), as boxes.
pub(super) fn changed_triangles(old: &[[Vec3; 3]], new: &[[Vec3; 3]]) -> Vec<(Vec3, Vec3)> {
    use std::collections::HashMap;
    let key = |t: &[Vec3; 3]| t.map(|p| p.to_array().map(f32::to_bits));
    let mut count: HashMap<[[u32; 3]; 3], i64> = HashMap::new();
    for t in old {
        *count.entry(key(t)).or_default() += 1;
    }
    for t in new {
        *count.entry(key(t)).or_default() -= 1;
    }
    let mut out = Vec::new();
    for t in old.iter().chain(new) {
        if count.get(&key(t)).copied().unwrap_or(0) != 0 {
            out.push((t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2])));
        }
    }
    out
}
