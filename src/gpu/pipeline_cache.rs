//! Reuse of what compiling costs, per device: bind group layouts with equal entries are one
//! object, and a compute pipeline is built once per (composed shader, entry point, layouts).
//!
//! Why: every engine (a viewer pane, a preset's A and B, each test) builds its technique's
//! pipelines, and on lavapipe one pipeline takes 20–260 ms to compile: engine setup was most of
//! the test suite's time. Sharing is safe because a pipeline depends only on its key: the
//! composed module (named by a hash of every source file it reads and its shader defs), the
//! entry point and the layouts. Hot reload changes the source, so its key, and replaces the
//! entry that had the old source (the cache never holds two versions of one pipeline).
//!
//! Layouts are shared for the same reason wgpu-core deduplicates them: a pipeline built with
//! one engine's layouts must accept the next engine's bind groups, and wgpu checks that by the
//! layout's identity (`wgpu::BindGroupLayout` compares by id).

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

/// A compute pipeline's identity apart from its source version.
#[derive(Clone, PartialEq, Eq, Hash)]
pub struct ComputeKey {
    /// Entry file (e.g. "lumen/world_trace.wgsl") and its shader defs, as composed.
    pub entry: String,
    pub defs: Vec<String>,
    pub entry_point: String,
    pub layouts: Vec<wgpu::BindGroupLayout>,
}

#[derive(Default)]
pub struct PipelineCache {
    layouts: Mutex<HashMap<Vec<wgpu::BindGroupLayoutEntry>, wgpu::BindGroupLayout>>,
    /// Key → (hash of the composed source, pipeline).
    compute: Mutex<HashMap<ComputeKey, (u64, wgpu::ComputePipeline)>>,
    built: AtomicU64,
}

impl PipelineCache {
    /// The layout of `entries`, created on first use. `label` names it in that first creation
    /// only (equal layouts are one object, as in wgpu-core).
    pub fn layout(
        &self,
        device: &wgpu::Device,
        label: &str,
        entries: &[wgpu::BindGroupLayoutEntry],
    ) -> wgpu::BindGroupLayout {
        let mut layouts = self.layouts.lock().expect("layout cache");
        layouts
            .entry(entries.to_vec())
            .or_insert_with(|| {
                device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                    label: Some(label),
                    entries,
                })
            })
            .clone()
    }

    /// The pipeline of `key` built from source `version`, if there is one.
    pub fn compute(&self, key: &ComputeKey, version: u64) -> Option<wgpu::ComputePipeline> {
        let compute = self.compute.lock().expect("pipeline cache");
        compute
            .get(key)
            .filter(|(v, _)| *v == version)
            .map(|(_, p)| p.clone())
    }

    /// Remembers a freshly built pipeline (replacing an older source version of it).
    pub fn insert_compute(&self, key: ComputeKey, version: u64, pipeline: wgpu::ComputePipeline) {
        self.built.fetch_add(1, Ordering::Relaxed);
        self.compute
            .lock()
            .expect("pipeline cache")
            .insert(key, (version, pipeline));
    }

    /// Compute pipelines this device has compiled (cache misses).
    pub fn built(&self) -> u64 {
        self.built.load(Ordering::Relaxed)
    }
}
