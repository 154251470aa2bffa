//! The shared BRDF evaluated on the GPU at chosen direction pairs (shaders/brdf/probe.wgsl runs
//! `bsdf_eval` from shaders/common/brdf.wgsl, the code every technique shades with), and the
//! BRDF slice built on it: the (θh, θd) image of Burley's BRDF explorer, used by the Callisto
//! talk to compare models (`gilab brdf-slice`, the viewer's slice window, the BRDF tests).

use super::Image;
use crate::gpu::readback::read_buffer;
use crate::gpu::shaders::ShaderLibrary;
use crate::gpu::Gpu;
use crate::render::pipelines::{self, storage_entry};
use crate::scene::shading::{BrdfModel, CallistoParams};
use anyhow::Result;
use glam::Vec3;
use wgpu::util::DeviceExt;

/// A material as the BRDF sees it (textures resolved to a base colour).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ProbeMaterial {
    pub base: Vec3,
    pub metallic: f32,
    pub roughness: f32,
    pub specular: f32,
    pub brdf: BrdfModel,
    pub callisto: CallistoParams,
}

impl ProbeMaterial {
    pub fn new(brdf: BrdfModel, base: Vec3, roughness: f32) -> ProbeMaterial {
        ProbeMaterial {
            base,
            metallic: 0.0,
            roughness,
            specular: 1.0,
            brdf,
            callisto: CallistoParams::default(),
        }
    }

    /// A scene material without its texture (the base colour factor only).
    pub fn from_material(m: &crate::scene::Material) -> ProbeMaterial {
        ProbeMaterial {
            base: m.base_color.truncate(),
            metallic: m.metallic,
            roughness: m.roughness,
            specular: m.specular,
            brdf: m.brdf,
            callisto: m.callisto,
        }
    }

    fn gpu(&self) -> GpuProbeMaterial {
        GpuProbeMaterial {
            base_metal: self.base.extend(self.metallic).to_array(),
            misc: [self.roughness, self.specular, 0.0, 0.0],
            shading: self.callisto.gpu_words(self.brdf),
        }
    }
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuProbeMaterial {
    pub base_metal: [f32; 4],
    pub misc: [f32; 4],
    pub shading: [[f32; 4]; 5],
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuQuery {
    pub wo: [f32; 4],
    pub wi: [f32; 4],
}

/// One evaluation: material index, direction to the viewer, direction to the light (normal +Z).
#[derive(Clone, Copy, Debug)]
pub struct Query {
    pub material: u32,
    pub wo: Vec3,
    pub wi: Vec3,
}

/// What `bsdf_eval` returned: f (not multiplied by the cosine) and the sampling pdf of wi.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Evaluation {
    pub f: Vec3,
    pub pdf: f32,
}

pub struct BrdfProbe {
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
}

const WORKGROUP: u32 = 64;
const MAX_GROUPS_X: u32 = 65535;

impl BrdfProbe {
    pub fn new(gpu: &Gpu, shaders: &ShaderLibrary) -> Result<BrdfProbe> {
        let layout = pipelines::layout(
            gpu,
            "brdf probe",
            &[
                storage_entry(0, true),
                storage_entry(1, true),
                storage_entry(2, false),
            ],
        );
        let pipeline = pipelines::compute_pipeline(gpu, shaders, "brdf/probe.wgsl", &[&layout])?;
        Ok(BrdfProbe { layout, pipeline })
    }

    pub fn eval(
        &self,
        gpu: &Gpu,
        materials: &[ProbeMaterial],
        queries: &[Query],
    ) -> Result<Vec<Evaluation>> {
        if queries.is_empty() {
            return Ok(Vec::new());
        }
        anyhow::ensure!(!materials.is_empty(), "BRDF probe: no materials");
        if let Some(q) = queries
            .iter()
            .find(|q| q.material as usize >= materials.len())
        {
            anyhow::bail!("BRDF probe: query names material {}", q.material);
        }
        let mats: Vec<GpuProbeMaterial> = materials.iter().map(|m| m.gpu()).collect();
        let qs: Vec<GpuQuery> = queries
            .iter()
            .map(|q| GpuQuery {
                wo: q.wo.extend(q.material as f32).to_array(),
                wi: q.wi.extend(0.0).to_array(),
            })
            .collect();
        let init = |label, contents: &[u8]| {
            gpu.device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some(label),
                    contents,
                    usage: wgpu::BufferUsages::STORAGE,
                })
        };
        let mat_buf = init("probe materials", bytemuck::cast_slice(&mats));
        let query_buf = init("probe queries", bytemuck::cast_slice(&qs));
        let out = crate::render::pipelines::storage_buffer(
            gpu,
            "probe results",
            (queries.len() * 16) as u64,
        );
        let bind = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("brdf probe"),
            layout: &self.layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: mat_buf.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: query_buf.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: out.as_entire_binding(),
                },
            ],
        });
        let groups = (queries.len() as u32).div_ceil(WORKGROUP);
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &bind, &[]);
            pass.dispatch_workgroups(groups.min(MAX_GROUPS_X), groups.div_ceil(MAX_GROUPS_X), 1);
        }
        gpu.submit("BRDF slice probe", enc.finish());
        let raw: Vec<[f32; 4]> = read_buffer(gpu, &out, queries.len())?;
        Ok(raw
            .into_iter()
            .map(|r| Evaluation {
                f: Vec3::new(r[0], r[1], r[2]),
                pdf: r[3],
            })
            .collect())
    }

    /// The BRDF slice of one material: θh (half vector from the normal) from 0 to 90° left to
    /// right, θd (light from the half vector) from 0 to 90° top to bottom, at azimuth φd; pixels
    /// store f·π (1 for a white Lambertian), 0 where wi or wo is below the horizon.
    pub fn slice(
        &self,
        gpu: &Gpu,
        material: &ProbeMaterial,
        size: u32,
        phi_d: f32,
    ) -> Result<Image> {
        let mut queries = Vec::with_capacity((size * size) as usize);
        let mut index = Vec::with_capacity((size * size) as usize);
        for y in 0..size {
            for x in 0..size {
                let theta_h = (x as f32 + 0.5) / size as f32 * std::f32::consts::FRAC_PI_2;
                let theta_d = (y as f32 + 0.5) / size as f32 * std::f32::consts::FRAC_PI_2;
                let (wo, wi) = slice_directions(theta_h, theta_d, phi_d);
                if wo.z > 0.0 && wi.z > 0.0 {
                    index.push(Some(queries.len()));
                    queries.push(Query {
                        material: 0,
                        wo,
                        wi,
                    });
                } else {
                    index.push(None);
                }
            }
        }
        let evals = self.eval(gpu, std::slice::from_ref(material), &queries)?;
        let mut img = Image::new(size, size);
        for (p, i) in index.iter().enumerate() {
            if let Some(i) = i {
                let f = evals[*i].f * std::f32::consts::PI;
                img.rgb[p * 3..p * 3 + 3].copy_from_slice(&f.to_array());
            }
        }
        Ok(img)
    }
}

/// Rusinkiewicz's half/difference angles to (wo, wi) around +Z: the half vector at θh in the
/// xz-plane, wi at (θd, φd) around it, wo its mirror through it.
pub fn slice_directions(theta_h: f32, theta_d: f32, phi_d: f32) -> (Vec3, Vec3) {
    let h = Vec3::new(theta_h.sin(), 0.0, theta_h.cos());
    // Frame around h: t in the xz-plane, b = y.
    let t = Vec3::new(theta_h.cos(), 0.0, -theta_h.sin());
    let b = Vec3::Y;
    let d = |phi: f32| {
        (t * (theta_d.sin() * phi.cos()) + b * (theta_d.sin() * phi.sin()) + h * theta_d.cos())
            .normalize()
    };
    let wi = d(phi_d);
    let wo = (2.0 * wi.dot(h) * h - wi).normalize();
    (wo, wi)
}

/// One of the talk's Callisto fits as a probe material (see `shading::callisto_fit`).
pub fn seed_material(name: &str) -> Option<ProbeMaterial> {
    let f = crate::scene::shading::callisto_fit(name)?;
    Some(ProbeMaterial {
        base: f.base,
        metallic: f.metallic,
        roughness: f.roughness,
        specular: f.specular,
        brdf: BrdfModel::Callisto,
        callisto: f.callisto,
    })
}

pub use crate::scene::shading::CALLISTO_FITS as SEED_MATERIALS;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slice_directions_have_the_requested_half_and_difference_angles() {
        for (th, td, pd) in [(0.3f32, 0.7f32, 1.2f32), (1.0, 0.2, 2.0), (0.0, 1.4, 0.5)] {
            let (wo, wi) = slice_directions(th, td, pd);
            let h = (wo + wi).normalize();
            assert!((h.z.acos() - th).abs() < 1e-4, "θh {th}");
            assert!(
                (wi.dot(h).clamp(-1.0, 1.0).acos() - td).abs() < 1e-4,
                "θd {td}"
            );
        }
    }
}
