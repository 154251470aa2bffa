//! Pipeline creation with composed shaders, inside wgpu error scopes: failures come back as
//! `Err` with the shader's file:line, never as a panic.

use crate::gpu::{pipeline_cache::ComputeKey, shaders::ShaderLibrary, timing::PassTimer, Gpu};
use anyhow::{anyhow, Result};
use std::borrow::Cow;
use std::cell::{Cell, RefCell};
use std::collections::BTreeSet;

thread_local! {
    static PIPELINES_REQUESTED: Cell<u64> = const { Cell::new(0) };
    /// Entry files composed on this thread while `recording_entries` runs.
    static ENTRIES_RECORDED: RefCell<Option<BTreeSet<String>>> = const { RefCell::new(None) };
}

/// Runs `f` and returns, beside its result, every entry file under `shaders/` whose module or
/// pipeline it asked for (built or taken from the cache). The engine records what its
/// technique, parts, primary surfaces and denoiser compile, so hot reload rebuilds an engine
/// exactly when one of those files (or a module they import) changes: no hand-kept file lists.
/// Nested calls are recorded by the outer call too.
pub fn recording_entries<T>(f: impl FnOnce() -> T) -> (T, BTreeSet<String>) {
    let outer = ENTRIES_RECORDED.with(|r| r.borrow_mut().replace(BTreeSet::new()));
    let out = f();
    let inner = ENTRIES_RECORDED
        .with(|r| std::mem::replace(&mut *r.borrow_mut(), outer))
        .unwrap_or_default();
    ENTRIES_RECORDED.with(|r| {
        if let Some(outer) = r.borrow_mut().as_mut() {
            outer.extend(inner.iter().cloned());
        }
    });
    (out, inner)
}

/// Records `entry` and the modules `shaders` adds to it (`with_imports`): the files hot reload
/// watches for this pipeline.
fn note_pipeline_files(shaders: &ShaderLibrary, entry: &str) {
    note_entry(entry);
    for file in shaders.import_files() {
        note_entry(&file);
    }
}

fn note_entry(entry: &str) {
    ENTRIES_RECORDED.with(|r| {
        if let Some(set) = r.borrow_mut().as_mut() {
            set.insert(entry.to_string());
        }
    });
}

/// Compute pipelines this thread has asked for, built or taken from the device's cache
/// (`Gpu::pipelines`): a test checks that parameter changes ask for none.
pub fn pipelines_requested() -> u64 {
    PIPELINES_REQUESTED.with(|c| c.get())
}

pub fn shader_module(
    gpu: &Gpu,
    shaders: &ShaderLibrary,
    entry: &str,
) -> Result<wgpu::ShaderModule> {
    note_pipeline_files(shaders, entry);
    let module = shaders.compose(entry).map_err(|e| anyhow!("{e}"))?;
    module_from(gpu, entry, module)
}

fn module_from(gpu: &Gpu, entry: &str, module: naga::Module) -> Result<wgpu::ShaderModule> {
    gpu.scoped(&format!("shader module shaders/{entry}"), || {
        gpu.device
            .create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(entry),
                source: wgpu::ShaderSource::Naga(Cow::Owned(module)),
            })
    })
}

/// The compute pipeline of `entry`'s `main`, with these bind group layouts (0, 1, …).
pub fn compute_pipeline(
    gpu: &Gpu,
    shaders: &ShaderLibrary,
    entry: &str,
    layouts: &[&wgpu::BindGroupLayout],
) -> Result<wgpu::ComputePipeline> {
    compute_pipeline_at(gpu, shaders, entry, "main", layouts)
}

/// The compute pipeline of one entry point of `entry` (files with several, such as the
/// surfel scan), with these bind group layouts (0, 1, …). Built once per device and source
/// version: later engines take it from `Gpu::pipelines`.
pub fn compute_pipeline_at(
    gpu: &Gpu,
    shaders: &ShaderLibrary,
    entry: &str,
    entry_point: &str,
    layouts: &[&wgpu::BindGroupLayout],
) -> Result<wgpu::ComputePipeline> {
    PIPELINES_REQUESTED.with(|c| c.set(c.get() + 1));
    note_pipeline_files(shaders, entry);
    let started = std::time::Instant::now();
    let composed = shaders
        .compose_versioned(entry)
        .map_err(|e| anyhow!("{e}"))?;
    let key = ComputeKey {
        entry: entry.to_string(),
        defs: shaders.def_names(),
        entry_point: entry_point.to_string(),
        layouts: layouts.iter().map(|l| (*l).clone()).collect(),
    };
    if let Some(pipeline) = gpu.pipelines.compute(&key, composed.version) {
        return Ok(pipeline);
    }
    let composed_at = started.elapsed();
    let module = module_from(gpu, entry, composed.module)?;
    let pipeline = gpu.scoped(&format!("compute pipeline shaders/{entry}"), || {
        build_pipeline(gpu, &module, entry_point, layouts)
    })?;
    if std::env::var_os("GILAB_PIPELINE_TIMES").is_some() {
        eprintln!(
            "pipeline {entry}:{entry_point} compose {:.3} s, build {:.3} s",
            composed_at.as_secs_f64(),
            (started.elapsed() - composed_at).as_secs_f64()
        );
    }
    gpu.pipelines
        .insert_compute(key, composed.version, pipeline.clone());
    Ok(pipeline)
}

/// The compute pipeline of one entry point of a module built elsewhere (the test harnesses),
/// with these bind group layouts (0, 1, …); not cached. Counted by `pipelines_requested`.
pub fn entry_point_pipeline(
    gpu: &Gpu,
    module: &wgpu::ShaderModule,
    entry_point: &str,
    layouts: &[&wgpu::BindGroupLayout],
) -> wgpu::ComputePipeline {
    PIPELINES_REQUESTED.with(|c| c.set(c.get() + 1));
    build_pipeline(gpu, module, entry_point, layouts)
}

fn build_pipeline(
    gpu: &Gpu,
    module: &wgpu::ShaderModule,
    entry_point: &str,
    layouts: &[&wgpu::BindGroupLayout],
) -> wgpu::ComputePipeline {
    let bind_group_layouts: Vec<Option<&wgpu::BindGroupLayout>> =
        layouts.iter().map(|l| Some(*l)).collect();
    let layout = gpu
        .device
        .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some(entry_point),
            bind_group_layouts: &bind_group_layouts,
            immediate_size: 0,
        });
    gpu.device
        .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(entry_point),
            layout: Some(&layout),
            module,
            entry_point: Some(entry_point),
            compilation_options: Default::default(),
            cache: None,
        })
}

/// A bind group of buffers bound whole, at bindings 0, 1, 2, … in order.
pub fn buffers_bind_group(
    gpu: &Gpu,
    label: &str,
    layout: &wgpu::BindGroupLayout,
    buffers: &[&wgpu::Buffer],
) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry> = buffers
        .iter()
        .enumerate()
        .map(|(i, b)| wgpu::BindGroupEntry {
            binding: i as u32,
            resource: b.as_entire_binding(),
        })
        .collect();
    gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some(label),
        layout,
        entries: &entries,
    })
}

/// A bind group layout of `entries`: one object per device for equal entries, so that cached
/// pipelines accept every engine's bind groups (`Gpu::pipelines`).
pub fn layout(
    gpu: &Gpu,
    label: &str,
    entries: &[wgpu::BindGroupLayoutEntry],
) -> wgpu::BindGroupLayout {
    gpu.pipelines.layout(&gpu.device, label, entries)
}

pub fn storage_entry(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

pub fn uniform_entry(binding: u32, visibility: wgpu::ShaderStages) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// A buffer made from `contents` (padded to the 16 bytes a binding needs at least).
pub fn init_buffer(
    gpu: &Gpu,
    label: &str,
    contents: &[u8],
    usage: wgpu::BufferUsages,
) -> wgpu::Buffer {
    use wgpu::util::DeviceExt;
    let mut bytes = contents.to_vec();
    bytes.resize(bytes.len().max(16), 0);
    gpu.device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents: &bytes,
            usage,
        })
}

pub fn storage_buffer(gpu: &Gpu, label: &str, size: u64) -> wgpu::Buffer {
    gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: size.max(16),
        usage: wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_SRC
            | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

/// Arguments for `count` indirect dispatches (`gilab::dispatch::DispatchArgs`, 12 bytes each),
/// written by shaders and read by `list_pass`.
pub fn indirect_args_buffer(gpu: &Gpu, label: &str, count: u64) -> wgpu::Buffer {
    gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: (count * 12).max(16),
        usage: wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::INDIRECT
            | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

/// Records one timed compute pass over a list whose length the GPU decided (surfels, probes,
/// tiles): its workgroup counts come from `args` at byte `offset` (`gilab::dispatch`), its bind
/// groups are bound at 0, 1, … in order. `args` must not be writable storage in this pass (wgpu
/// forbids both uses in one dispatch): the pass that decides the length writes it.
pub fn list_pass(
    enc: &mut wgpu::CommandEncoder,
    timer: &mut PassTimer,
    name: &'static str,
    pipeline: &wgpu::ComputePipeline,
    bind_groups: &[&wgpu::BindGroup],
    args: &wgpu::Buffer,
    offset: u64,
) {
    let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
        label: Some(name),
        timestamp_writes: timer.compute_pass(name),
    });
    pass.set_pipeline(pipeline);
    for (i, bg) in bind_groups.iter().enumerate() {
        pass.set_bind_group(i as u32, *bg, &[]);
    }
    pass.dispatch_workgroups_indirect(args, offset);
}

/// Records one timed compute pass over the image: the scene at group 0, the frame at group 1,
/// the technique's bind group at group 2, one 8x8 workgroup per tile.
pub fn image_pass(
    ctx: &super::RenderContext,
    enc: &mut wgpu::CommandEncoder,
    timer: &mut crate::gpu::timing::PassTimer,
    name: &'static str,
    pipeline: &wgpu::ComputePipeline,
    bind_group: &wgpu::BindGroup,
) {
    let groups = [ctx.extent[0].div_ceil(8), ctx.extent[1].div_ceil(8), 1];
    technique_pass(ctx, enc, timer, name, pipeline, &[bind_group], groups);
}

/// Records one timed compute pass of `workgroups`: the scene at group 0, the frame at group 1,
/// then `bind_groups` at 2, 3, ….
pub fn technique_pass(
    ctx: &super::RenderContext,
    enc: &mut wgpu::CommandEncoder,
    timer: &mut crate::gpu::timing::PassTimer,
    name: &'static str,
    pipeline: &wgpu::ComputePipeline,
    bind_groups: &[&wgpu::BindGroup],
    workgroups: [u32; 3],
) {
    let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
        label: Some(name),
        timestamp_writes: timer.compute_pass(name),
    });
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, &ctx.scene.bind_group, &[]);
    pass.set_bind_group(1, ctx.frame_bind_group, &[]);
    for (i, bg) in bind_groups.iter().enumerate() {
        pass.set_bind_group(2 + i as u32, *bg, &[]);
    }
    let [x, y, z] = workgroups;
    pass.dispatch_workgroups(x, y, z);
}

/// The compute passes of a technique or part that share one bind group layout, as an enum:
/// each variant carries its timing name and entry file, and indexes the pipelines built in
/// `ALL` order. A pass is looked up by variant, so a misspelt pass is a compile error rather
/// than a panic at run time.
///
/// ```ignore
/// compute_passes! { enum Pass { Trace => ("trace", "parts/surfels/trace.wgsl") } }
/// let pipeline = &pipelines[Pass::Trace as usize];
/// ```
#[macro_export]
macro_rules! compute_passes {
    ($(#[$meta:meta])* $vis:vis enum $E:ident { $($V:ident => ($name:literal, $file:literal)),+ $(,)? }) => {
        $(#[$meta])*
        #[derive(Clone, Copy, Debug, PartialEq, Eq)]
        $vis enum $E { $($V),+ }
        impl $E {
            /// Every pass, in pipeline order.
            $vis const ALL: &'static [$E] = &[$($E::$V),+];
            /// Its name in timings and pass lists.
            $vis const fn name(self) -> &'static str {
                match self { $($E::$V => $name),+ }
            }
            /// Its entry file under `shaders/`.
            $vis const fn file(self) -> &'static str {
                match self { $($E::$V => $file),+ }
            }
        }
    };
}
