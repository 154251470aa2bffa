//! GpuScene: the scene's buffers on the GPU (bind group 0 of every technique) and the light pool.

use super::{bvh::Bvh, features::luminance, features::SceneFeatures, PunctualKind, Scene};
use crate::gpu::Gpu;
use glam::Vec3;
use wgpu::util::DeviceExt;

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuTriGeom {
    pub v0: [f32; 4],
    pub e1: [f32; 4],
    pub e2: [f32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuTriAttr {
    pub n0: [f32; 4],
    pub n1: [f32; 4],
    pub n2: [f32; 4],
    pub uv01: [f32; 4],
    pub uv2: [f32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuMaterial {
    pub base_color: [f32; 4],
    pub emissive: [f32; 4],
    pub params: [f32; 4],
    pub base_tex: [u32; 4],
    /// Callisto parameters and the BRDF model (layout: shaders/common/brdf.wgsl `Shading`).
    pub shading: [[f32; 4]; 5],
}

pub const LIGHT_TRIANGLE: u32 = 0;
pub const LIGHT_POINT: u32 = 1;
pub const LIGHT_SPOT: u32 = 2;
pub const LIGHT_DIRECTIONAL: u32 = 3;

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuLight {
    pub kind: u32,
    pub tri: u32,
    /// Selection over the whole pool (next-event estimation of the path tracers).
    pub cdf: f32,
    pub pmf: f32,
    /// Selection within the light's class (local: triangles, points, spots; directional),
    /// for ReSTIR's per-class candidates.
    pub class_cdf: f32,
    pub class_pmf: f32,
    pub pad: [u32; 2],
    pub position: [f32; 4],
    pub intensity: [f32; 4],
    pub direction: [f32; 4],
    pub spot: [f32; 4],
}

/// One vertex of the G-buffer raster pass (triangles expanded, BVH order).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct RasterVertex {
    pub position: [f32; 3],
    pub normal: [f32; 3],
    pub uv: [f32; 2],
    pub material: u32,
}

/// CPU copies of everything uploaded, kept for tests, the CPU BVH and light statistics.
pub struct SceneData {
    pub tris: Vec<[Vec3; 3]>,
    pub bvh: Bvh,
    pub tri_geom: Vec<GpuTriGeom>,
    pub tri_attr: Vec<GpuTriAttr>,
    pub materials: Vec<GpuMaterial>,
    pub texels: Vec<u32>,
    pub lights: Vec<GpuLight>,
    pub vertices: Vec<RasterVertex>,
    pub features: SceneFeatures,
    pub timings: SceneTimings,
}

/// Where a scene's set-up time goes (wall ms on the CPU), printed by `shot --verbose` and
/// recorded in the shot JSON.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct SceneTimings {
    /// Reading the file or building the built-in scene (set by the caller that loaded it).
    pub load_ms: f64,
    /// BVH build alone (parallel, rayon's thread pool).
    pub bvh_build_ms: f64,
    /// Everything SceneData does: BVH, scene features, triangle and material arrays, lights.
    pub prepare_ms: f64,
    /// Creating and filling the GPU buffers (CPU side of the upload).
    pub upload_ms: f64,
    pub threads: usize,
}

impl SceneData {
    pub fn new(scene: &Scene) -> SceneData {
        let start = std::time::Instant::now();
        let tris = scene.triangle_positions();
        let bvh = Bvh::build(&tris);
        let bvh_build_ms = start.elapsed().as_secs_f64() * 1e3;
        let features = SceneFeatures::compute(scene, &bvh, &tris);

        // Textures packed into one texel array (sRGB RGBA8 words).
        let mut texels = Vec::new();
        let mut tex_offset = Vec::new();
        for t in &scene.textures {
            tex_offset.push(texels.len() as u32);
            texels.extend(
                t.rgba8
                    .chunks_exact(4)
                    .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]])),
            );
        }
        if texels.is_empty() {
            texels.push(0);
        }
        let materials: Vec<GpuMaterial> = scene
            .materials
            .iter()
            .map(|m| {
                let base_tex = match m.base_color_texture {
                    Some(i) => [
                        tex_offset[i],
                        scene.textures[i].width,
                        scene.textures[i].height,
                        1,
                    ],
                    None => [0; 4],
                };
                GpuMaterial {
                    base_color: m.base_color.to_array(),
                    emissive: m
                        .emissive
                        .extend(if m.double_sided { 1.0 } else { 0.0 })
                        .to_array(),
                    params: [
                        m.metallic.clamp(0.0, 1.0),
                        m.roughness.clamp(0.0, 1.0),
                        m.specular.clamp(0.0, 1.0),
                        0.0,
                    ],
                    base_tex,
                    shading: m.callisto.gpu_words(m.brdf),
                }
            })
            .collect();

        // Light pool: power-proportional selection over emissive triangles and punctual lights.
        let (lo, hi) = scene.bounds();
        let scene_radius = ((hi - lo).length() * 0.5).max(1e-3);
        let mut lights = Vec::new();
        let mut powers = Vec::new();
        let mut tri_light_power = vec![0.0f32; tris.len()];
        for (bvh_index, &orig) in bvh.order.iter().enumerate() {
            let m = &scene.materials[scene.triangle_material[orig as usize] as usize];
            let t = &tris[orig as usize];
            let area = 0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length();
            let power = std::f32::consts::PI
                * area
                * luminance(m.emissive)
                * if m.double_sided { 2.0 } else { 1.0 };
            if power > 0.0 && power.is_finite() {
                tri_light_power[bvh_index] = power;
                lights.push(GpuLight {
                    kind: LIGHT_TRIANGLE,
                    tri: bvh_index as u32,
                    ..Default::default()
                });
                powers.push(power);
            }
        }
        // Local lights first, directional ones last: each class is one contiguous range.
        let mut punctual: Vec<&super::PunctualLight> = scene.lights.iter().collect();
        punctual.sort_by_key(|l| matches!(l.kind, PunctualKind::Directional));
        for l in punctual {
            let lum = luminance(l.intensity);
            if !(lum > 0.0 && lum.is_finite()) {
                continue;
            }
            let (kind, power) = match l.kind {
                PunctualKind::Point => (LIGHT_POINT, 4.0 * std::f32::consts::PI * lum),
                PunctualKind::Spot => (LIGHT_SPOT, 4.0 * std::f32::consts::PI * lum),
                // Power through a disc the size of the scene.
                PunctualKind::Directional => (
                    LIGHT_DIRECTIONAL,
                    std::f32::consts::PI * scene_radius * scene_radius * lum,
                ),
            };
            // glTF spot falloff: smooth between cos(outer) and cos(inner).
            let (co, ci) = (l.outer_cone.cos(), l.inner_cone.cos());
            let scale = 1.0 / (ci - co).max(1e-4);
            lights.push(GpuLight {
                kind,
                position: l.position.extend(1.0).to_array(),
                intensity: l.intensity.extend(0.0).to_array(),
                direction: l.direction.normalize_or(Vec3::NEG_Y).extend(0.0).to_array(),
                spot: [co, scale, -co * scale, 0.0],
                ..Default::default()
            });
            powers.push(power);
        }
        let total: f64 = powers.iter().map(|&p| p as f64).sum();
        let mut acc = 0.0f64;
        for (l, p) in lights.iter_mut().zip(&powers) {
            acc += *p as f64;
            l.pmf = (*p as f64 / total) as f32;
            l.cdf = (acc / total) as f32;
        }
        if let Some(last) = lights.last_mut() {
            last.cdf = 1.0;
        }
        let local = lights
            .iter()
            .filter(|l| l.kind != LIGHT_DIRECTIONAL)
            .count();
        set_class_cdf(&mut lights[..local], &powers[..local]);
        set_class_cdf(&mut lights[local..], &powers[local..]);

        let mut tri_geom = Vec::with_capacity(tris.len());
        let mut tri_attr = Vec::with_capacity(tris.len());
        let mut vertices = Vec::with_capacity(tris.len() * 3);
        for (bvh_index, &orig) in bvh.order.iter().enumerate() {
            let idx = scene.triangles[orig as usize];
            let p = tris[orig as usize];
            let n = idx.map(|i| scene.normals[i as usize]);
            let uv = idx.map(|i| scene.uvs[i as usize]);
            let material = scene.triangle_material[orig as usize];
            let pmf = if total > 0.0 {
                (tri_light_power[bvh_index] as f64 / total) as f32
            } else {
                0.0
            };
            tri_geom.push(GpuTriGeom {
                v0: p[0].extend(0.0).to_array(),
                e1: (p[1] - p[0]).extend(0.0).to_array(),
                e2: (p[2] - p[0]).extend(0.0).to_array(),
            });
            tri_attr.push(GpuTriAttr {
                n0: n[0].extend(pmf).to_array(),
                n1: n[1].extend(f32::from_bits(material)).to_array(),
                n2: n[2].extend(f32::from_bits(orig)).to_array(),
                uv01: [uv[0].x, uv[0].y, uv[1].x, uv[1].y],
                uv2: [uv[2].x, uv[2].y, 0.0, 0.0],
            });
            for k in 0..3 {
                vertices.push(RasterVertex {
                    position: p[k].to_array(),
                    normal: n[k].to_array(),
                    uv: uv[k].to_array(),
                    material,
                });
            }
        }
        SceneData {
            timings: SceneTimings {
                bvh_build_ms,
                prepare_ms: start.elapsed().as_secs_f64() * 1e3,
                ..SceneTimings::default()
            },
            tris,
            bvh,
            tri_geom,
            tri_attr,
            materials,
            texels,
            lights,
            vertices,
            features,
        }
    }
}

/// Power-proportional selection within one class of lights (inclusive CDF, last = 1).
fn set_class_cdf(lights: &mut [GpuLight], powers: &[f32]) {
    let total: f64 = powers.iter().map(|&p| p as f64).sum();
    let mut acc = 0.0f64;
    for (l, p) in lights.iter_mut().zip(powers) {
        acc += *p as f64;
        l.class_pmf = (*p as f64 / total) as f32;
        l.class_cdf = (acc / total) as f32;
    }
    if let Some(last) = lights.last_mut() {
        last.class_cdf = 1.0;
    }
}

pub struct GpuScene {
    pub data: SceneData,
    pub sky: Vec3,
    pub layout: wgpu::BindGroupLayout,
    pub bind_group: wgpu::BindGroup,
    pub vertex_buffer: wgpu::Buffer,
    pub vertex_count: u32,
}

impl GpuScene {
    pub fn bind_group_layout(gpu: &Gpu) -> wgpu::BindGroupLayout {
        let entries: Vec<wgpu::BindGroupLayoutEntry> = (0..6)
            .map(|i| wgpu::BindGroupLayoutEntry {
                binding: i,
                visibility: wgpu::ShaderStages::COMPUTE | wgpu::ShaderStages::FRAGMENT,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Storage { read_only: true },
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            })
            .collect();
        gpu.device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("scene"),
                entries: &entries,
            })
    }

    pub fn upload(gpu: &Gpu, scene: &Scene) -> GpuScene {
        let mut data = SceneData::new(scene);
        let upload_start = std::time::Instant::now();
        let storage = |label: &str, bytes: &[u8]| {
            // Bindings may not be empty: pad to at least 16 bytes.
            let mut v = bytes.to_vec();
            if v.len() < 16 {
                v.resize(16, 0);
            }
            gpu.device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some(label),
                    contents: &v,
                    usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                })
        };
        let nodes = storage("bvh nodes", bytemuck::cast_slice(&data.bvh.nodes));
        let geom = storage("tri geom", bytemuck::cast_slice(&data.tri_geom));
        let attr = storage("tri attr", bytemuck::cast_slice(&data.tri_attr));
        let mats = storage("materials", bytemuck::cast_slice(&data.materials));
        let texels = storage("texels", bytemuck::cast_slice(&data.texels));
        let mut light_bytes: Vec<u8> = Vec::new();
        let emissive = data
            .lights
            .iter()
            .filter(|l| l.kind == LIGHT_TRIANGLE)
            .count() as u32;
        let local = data
            .lights
            .iter()
            .filter(|l| l.kind != LIGHT_DIRECTIONAL)
            .count() as u32;
        let header = [
            data.lights.len() as u32,
            emissive,
            data.lights.len() as u32 - emissive,
            local,
        ];
        light_bytes.extend_from_slice(bytemuck::cast_slice(&header));
        light_bytes.extend_from_slice(bytemuck::cast_slice(&data.lights));
        if data.lights.is_empty() {
            light_bytes.extend_from_slice(bytemuck::bytes_of(&GpuLight::default()));
        }
        let lights = storage("light pool", &light_bytes);
        let layout = Self::bind_group_layout(gpu);
        let bind_group = crate::render::pipelines::buffers_bind_group(
            gpu,
            "scene",
            &layout,
            &[&nodes, &geom, &attr, &mats, &texels, &lights],
        );
        let mut vbytes = bytemuck::cast_slice::<RasterVertex, u8>(&data.vertices).to_vec();
        if vbytes.is_empty() {
            vbytes.resize(std::mem::size_of::<RasterVertex>(), 0);
        }
        let vertex_buffer = gpu
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("raster vertices"),
                contents: &vbytes,
                usage: wgpu::BufferUsages::VERTEX,
            });
        let vertex_count = data.vertices.len() as u32;
        data.timings.upload_ms = upload_start.elapsed().as_secs_f64() * 1e3;
        data.timings.threads = rayon::current_num_threads();
        GpuScene {
            data,
            sky: scene.sky,
            layout,
            bind_group,
            vertex_buffer,
            vertex_count,
        }
    }
}
