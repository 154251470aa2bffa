//! The static/dynamic split's CPU side (`static_shadow_cache`): which top-level entries of the
//! BVH and which lights have moved since the scene was built, and the head of the cache buffer
//! the shaders read (shaders/callisto_shadows/static_cache.wgsl).
//!
//! The scene does not say which instances its animations move, so the split finds out: an entry
//! whose instance record (world-to-object transform) changed, or a light whose record or
//! emitting triangle changed, is dynamic from then on. Until the first move everything is static,
//! and the first move clears the cache once (it held the movers' shadows as static).

use crate::scene::bvh::{BvhNode, INSTANCE_LEAF};
use crate::scene::gpu_scene::{GpuLight, GpuTriGeom, SceneData};

/// Words per dynamic entry in the buffer: box min (f32 bits), instance record node, box max, 0.
pub const DYNAMIC_WORDS: u32 = 8;

#[derive(Default)]
pub struct Split {
    records: Vec<[BvhNode; 2]>,
    lights: Vec<GpuLight>,
    light_geom: Vec<GpuTriGeom>,
    /// Per top-level entry (two-level BVH), whether it has moved.
    pub dynamic_entries: Vec<bool>,
    /// Per light of the pool, whether it has moved.
    pub dynamic_lights: Vec<bool>,
}

/// Words per slot of the hash grid (`SLOT_WORDS` in static_cache.wgsl).
pub const SLOT_WORDS: u64 = 4;

/// Where things are in the cache buffer (words).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CacheLayout {
    pub light_mask_base: u32,
    pub dynamic_base: u32,
    pub hash_base: u32,
    pub slots: u32,
}

impl CacheLayout {
    /// `enabled` false: one slot (the split is off; the masks are still read).
    pub fn new(data: &SceneData, pixels: u64, enabled: bool) -> CacheLayout {
        let entries = data.bvh.top.as_ref().map_or(0, |t| t.entries.len()) as u32;
        let light_mask_base = entries.div_ceil(32).max(1);
        let dynamic_base = light_mask_base + (data.lights.len() as u32).div_ceil(32).max(1);
        // About 8 slots a pixel (a few lights per cell), 2^16 to 2^21 (32 MiB).
        let slots = if enabled {
            (pixels * 8).next_power_of_two().clamp(1 << 16, 1 << 21) as u32
        } else {
            1
        };
        CacheLayout {
            light_mask_base,
            dynamic_base,
            hash_base: dynamic_base + entries.max(1) * DYNAMIC_WORDS,
            slots,
        }
    }

    pub fn words(&self) -> u64 {
        self.hash_base as u64 + SLOT_WORDS * self.slots as u64
    }
}

fn light_geom(data: &SceneData, l: &GpuLight) -> GpuTriGeom {
    if l.kind == crate::scene::gpu_scene::LIGHT_TRIANGLE {
        data.tri_geom
            .get(l.tri as usize)
            .copied()
            .unwrap_or_default()
    } else {
        GpuTriGeom::default()
    }
}

impl Split {
    /// Compares the scene with what was seen last; true when an entry or a light became
    /// dynamic, or the scene is another one (the cache must be cleared).
    pub fn observe(&mut self, data: &SceneData) -> bool {
        let records: Vec<[BvhNode; 2]> = data.bvh.top.as_ref().map_or(Vec::new(), |t| {
            (0..t.entries.len())
                .map(|e| {
                    let at = t.records_at + 2 * e;
                    [data.bvh.nodes[at], data.bvh.nodes[at + 1]]
                })
                .collect()
        });
        let geom: Vec<GpuTriGeom> = data.lights.iter().map(|l| light_geom(data, l)).collect();
        let same_scene =
            records.len() == self.records.len() && data.lights.len() == self.lights.len();
        if !same_scene {
            self.dynamic_entries = vec![false; records.len()];
            self.dynamic_lights = vec![false; data.lights.len()];
        }
        let mut changed = !same_scene;
        let bytes = bytemuck::bytes_of::<[BvhNode; 2]>;
        for (e, r) in records.iter().enumerate() {
            if same_scene && !self.dynamic_entries[e] && bytes(r) != bytes(&self.records[e]) {
                self.dynamic_entries[e] = true;
                changed = true;
            }
        }
        // A light's place in the light tree (its bit trail) moves when another light moves: it
        // says nothing about this light.
        let without_trail = |l: &GpuLight| GpuLight {
            trail: [0; 2],
            ..*l
        };
        for (i, l) in data.lights.iter().enumerate() {
            if same_scene
                && !self.dynamic_lights[i]
                && (bytemuck::bytes_of(&without_trail(l))
                    != bytemuck::bytes_of(&without_trail(&self.lights[i]))
                    || bytemuck::bytes_of(&geom[i]) != bytemuck::bytes_of(&self.light_geom[i]))
            {
                self.dynamic_lights[i] = true;
                changed = true;
            }
        }
        self.records = records;
        self.lights = data.lights.clone();
        self.light_geom = geom;
        changed
    }

    /// Dynamic entries now.
    pub fn dynamic_count(&self) -> u32 {
        self.dynamic_entries.iter().filter(|&&d| d).count() as u32
    }

    /// The buffer's head: the entry and light masks, then per dynamic entry its world box (the
    /// top-level leaf's) and instance record.
    pub fn head(&self, data: &SceneData, layout: &CacheLayout) -> Vec<u32> {
        let mut words = vec![0u32; layout.hash_base as usize];
        for (e, _) in self.dynamic_entries.iter().enumerate().filter(|(_, d)| **d) {
            words[e / 32] |= 1 << (e % 32);
        }
        for (i, _) in self.dynamic_lights.iter().enumerate().filter(|(_, d)| **d) {
            words[layout.light_mask_base as usize + i / 32] |= 1 << (i % 32);
        }
        let Some(top) = &data.bvh.top else {
            return words;
        };
        let mut at = layout.dynamic_base as usize;
        for n in &data.bvh.nodes[..top.nodes] {
            if n.tri_count() != INSTANCE_LEAF {
                continue;
            }
            let record = (n.tris >> 8) as usize;
            let e = (record - top.records_at) / 2;
            if !self.dynamic_entries.get(e).copied().unwrap_or(false) {
                continue;
            }
            let f = |v: [f32; 3]| v.map(f32::to_bits);
            words[at..at + 3].copy_from_slice(&f(n.min));
            words[at + 3] = record as u32;
            words[at + 4..at + 7].copy_from_slice(&f(n.max));
            at += DYNAMIC_WORDS as usize;
        }
        words
    }
}
