//! What one read costs a compute shader on this machine's adapter, by where the data lives:
//! a storage buffer (vec4, at indices that differ across lanes, the same for all lanes, or
//! consecutive; one word), a texel fetch (rgba32float), a uniform buffer, a storage write, and
//! the loop's arithmetic alone. Each kernel runs 65,536 invocations of 256 dependent reads.
//!
//!     cargo run --release --example load_costs
//!
//! On lavapipe (Mesa 22.3, CI's renderer) a storage-buffer vec4 costs about 6x a texel fetch:
//! Mesa loads storage buffers in a scalar loop over the SIMD lanes. That is why the scene's BVH
//! and records are read from texel copies (src/scene/gpu_scene.rs `SceneTexels`); the numbers
//! of 2026-12-01 are in docs/performance.md.
use gilab::gpu::{BackendChoice, Gpu};
use std::time::Instant;
use wgpu::util::DeviceExt;

const INVOCATIONS: u32 = 65_536;
const READS: f64 = 256.0;

const KERNELS: &str = r#"
@group(0) @binding(0) var<storage, read> buf: array<vec4<f32>>;
@group(0) @binding(1) var tex: texture_2d<f32>;
@group(0) @binding(2) var<storage, read_write> out: array<f32>;
@group(0) @binding(3) var<uniform> ubo: array<vec4<f32>, 1024>;

// The next index from this one and the value read (a dependent chain, so no read is skipped).
fn next(i: u32, v: f32) -> u32 { return (i * 1664525u + 1013904223u + bitcast<u32>(v)) & 1023u; }

@compute @workgroup_size(64)
fn arithmetic(@builtin(global_invocation_id) g: vec3<u32>) {
    var i = g.x & 1023u; var acc = 0.0;
    for (var k = 0u; k < 256u; k++) { let v = vec4<f32>(f32(i), 1.0, 2.0, 3.0); acc += v.y + v.z + v.w; i = next(i, v.x); }
    out[g.x] = acc;
}
@compute @workgroup_size(64)
fn storage_divergent(@builtin(global_invocation_id) g: vec3<u32>) {
    var i = g.x & 1023u; var acc = 0.0;
    for (var k = 0u; k < 256u; k++) { let v = buf[i]; acc += v.y + v.z + v.w; i = next(i, v.x); }
    out[g.x] = acc;
}
@compute @workgroup_size(64)
fn storage_uniform(@builtin(global_invocation_id) g: vec3<u32>) {
    var i = 0u; var acc = 0.0;
    for (var k = 0u; k < 256u; k++) { let v = buf[i]; acc += v.y + v.z + v.w; i = next(i, 0.0); }
    out[g.x] = acc;
}
@compute @workgroup_size(64)
fn storage_consecutive(@builtin(global_invocation_id) g: vec3<u32>) {
    var acc = 0.0;
    for (var k = 0u; k < 256u; k++) { let v = buf[(g.x + k * 64u) & 1023u]; acc += v.y + v.z + v.w; }
    out[g.x] = acc;
}
@compute @workgroup_size(64)
fn storage_one_word(@builtin(global_invocation_id) g: vec3<u32>) {
    var i = g.x & 1023u; var acc = 0.0;
    for (var k = 0u; k < 256u; k++) { let v = buf[i].x; acc += v; i = next(i, v); }
    out[g.x] = acc;
}
@compute @workgroup_size(64)
fn texel(@builtin(global_invocation_id) g: vec3<u32>) {
    var i = g.x & 1023u; var acc = 0.0;
    for (var k = 0u; k < 256u; k++) { let v = textureLoad(tex, vec2<u32>(i & 31u, i >> 5u), 0); acc += v.y + v.z + v.w; i = next(i, v.x); }
    out[g.x] = acc;
}
@compute @workgroup_size(64)
fn uniform_divergent(@builtin(global_invocation_id) g: vec3<u32>) {
    var i = g.x & 1023u; var acc = 0.0;
    for (var k = 0u; k < 256u; k++) { let v = ubo[i]; acc += v.y + v.z + v.w; i = next(i, v.x); }
    out[g.x] = acc;
}
@compute @workgroup_size(64)
fn storage_write(@builtin(global_invocation_id) g: vec3<u32>) {
    for (var k = 0u; k < 256u; k++) { out[(g.x + k * 64u) & 65535u] = f32(k); }
}
"#;

fn main() -> anyhow::Result<()> {
    let gpu = Gpu::new(BackendChoice::Auto)?;
    println!("{}", gpu.summary);
    let d = &gpu.device;
    let data: Vec<f32> = (0..4096)
        .map(|i| ((i * 7919) % 1000) as f32 * 0.001)
        .collect();
    let buf = d.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("data"),
        contents: bytemuck::cast_slice(&data),
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::UNIFORM,
    });
    let out = d.create_buffer(&wgpu::BufferDescriptor {
        label: Some("out"),
        size: INVOCATIONS as u64 * 4,
        usage: wgpu::BufferUsages::STORAGE,
        mapped_at_creation: false,
    });
    let tex = d.create_texture_with_data(
        &gpu.queue,
        &wgpu::TextureDescriptor {
            label: Some("data"),
            size: wgpu::Extent3d {
                width: 32,
                height: 32,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Rgba32Float,
            usage: wgpu::TextureUsages::TEXTURE_BINDING,
            view_formats: &[],
        },
        wgpu::util::TextureDataOrder::LayerMajor,
        bytemuck::cast_slice(&data),
    );
    let view = tex.create_view(&Default::default());
    let module = d.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("load costs"),
        source: wgpu::ShaderSource::Wgsl(KERNELS.into()),
    });
    println!("{INVOCATIONS} invocations x {READS} reads; ns per read per invocation (the best of 3 runs, after one to compile)");
    for entry in [
        "arithmetic",
        "storage_divergent",
        "storage_uniform",
        "storage_consecutive",
        "storage_one_word",
        "texel",
        "uniform_divergent",
        "storage_write",
    ] {
        let pipeline = d.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(entry),
            layout: None,
            module: &module,
            entry_point: Some(entry),
            compilation_options: Default::default(),
            cache: None,
        });
        // Auto layouts hold only what the entry point reads.
        let input = match entry {
            "texel" => Some((1, wgpu::BindingResource::TextureView(&view))),
            "uniform_divergent" => Some((3, buf.as_entire_binding())),
            "arithmetic" | "storage_write" => None,
            _ => Some((0, buf.as_entire_binding())),
        };
        let mut entries = vec![wgpu::BindGroupEntry {
            binding: 2,
            resource: out.as_entire_binding(),
        }];
        if let Some((binding, resource)) = input {
            entries.push(wgpu::BindGroupEntry { binding, resource });
        }
        let bind = d.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(entry),
            layout: &pipeline.get_bind_group_layout(0),
            entries: &entries,
        });
        let mut best = f64::MAX;
        for run in 0..4 {
            let mut enc = d.create_command_encoder(&Default::default());
            {
                let mut pass = enc.begin_compute_pass(&Default::default());
                pass.set_pipeline(&pipeline);
                pass.set_bind_group(0, &bind, &[]);
                pass.dispatch_workgroups(INVOCATIONS / 64, 1, 1);
            }
            let start = Instant::now();
            gpu.queue.submit([enc.finish()]);
            d.poll(wgpu::PollType::wait_indefinitely())?;
            if run > 0 {
                best = best.min(start.elapsed().as_secs_f64());
            }
        }
        println!(
            "  {entry:<20} {:7.2} ns   ({:.1} ms a run)",
            best * 1e9 / (INVOCATIONS as f64 * READS),
            best * 1e3
        );
    }
    Ok(())
}
