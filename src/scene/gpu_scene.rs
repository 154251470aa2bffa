//! GpuScene: the scene's buffers on the GPU (bind group 0 of every technique) and the light pool.

use super::bvh::{Bvh, BvhNode};
use super::{features::luminance, features::SceneFeatures, PunctualKind, Scene};
use crate::compare::tonemap::{linear_to_srgb, srgb_to_linear};
use crate::gpu::Gpu;
use crate::parts::light_tree::{LightBounds, LightTree};
use glam::{Mat4, Vec3};
use wgpu::util::DeviceExt;

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuTriGeom {
    pub v0: [f32; 4],
    pub e1: [f32; 4],
    pub e2: [f32; 4],
}

/// Per-triangle shading attributes, 96 bytes so that a scene of 1.2M triangles stays under
/// 128 MiB per binding: normals and tangents oct-encoded (16 bits per component).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuTriAttr {
    /// Oct-encoded vertex normals (see `TRI_HAS_NORMALS`).
    pub normals: [u32; 3],
    /// Probability of picking this triangle as a light (0 if not emissive).
    pub light_pmf: f32,
    /// Oct-encoded vertex tangents (see `TRI_HAS_TANGENTS`; bitangent signs in `flags`).
    pub tangents: [u32; 3],
    pub material: u32,
    /// UV set 0 of vertices a and b.
    pub uv0_ab: [f32; 4],
    /// xy: UV set 0 of vertex c, zw: UV set 1 of vertex a.
    pub uv0_c_uv1_a: [f32; 4],
    /// UV set 1 of vertices b and c.
    pub uv1_bc: [f32; 4],
    /// The triangle's index in the scene (these arrays are in BVH order).
    pub scene_tri: u32,
    pub flags: u32,
    /// [0]: the triangle's motion record + 1 (0: it does not move); [1]: its light's index in
    /// the light pool + 1 (0: it does not emit).
    pub pad: [u32; 2],
}

impl GpuTriAttr {
    pub fn material(&self) -> u32 {
        self.material
    }
}

/// `GpuTriAttr::flags`: the triangle has usable vertex normals (all three non-zero).
pub const TRI_HAS_NORMALS: u32 = 1;
/// The triangle has tangents (a normal-mapped material and non-zero tangents).
pub const TRI_HAS_TANGENTS: u32 = 2;
/// Bit 2 + k: vertex k's bitangent sign is negative.
pub const TRI_BITANGENT_NEG_SHIFT: u32 = 2;

/// A material's use of a texture on the GPU: the rows of its UV transform, the texture index
/// (`transform_u[3]`, bits; `NO_TEXTURE` when unused), the UV set (bit 0 of `transform_v[3]`'s
/// bits) and the sampler above it (`Sampler::gpu_bits`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuTexSlot {
    pub transform_u: [f32; 4],
    pub transform_v: [f32; 4],
}

pub const NO_TEXTURE: u32 = u32::MAX;

impl GpuTexSlot {
    fn new(r: Option<super::TextureRef>, present: &[bool]) -> GpuTexSlot {
        match r {
            Some(t) if present.get(t.texture).copied().unwrap_or(false) => {
                let m = t.transform.rows();
                GpuTexSlot {
                    transform_u: [m[0][0], m[0][1], m[0][2], f32::from_bits(t.texture as u32)],
                    transform_v: [
                        m[1][0],
                        m[1][1],
                        m[1][2],
                        f32::from_bits(t.tex_coord | t.sampler.gpu_bits() << 1),
                    ],
                }
            }
            _ => GpuTexSlot {
                transform_u: [1.0, 0.0, 0.0, f32::from_bits(NO_TEXTURE)],
                transform_v: [0.0, 1.0, 0.0, 0.0],
            },
        }
    }
}

/// Material texture slots, in `GpuMaterial::tex` order.
pub const SLOT_BASE_COLOR: usize = 0;
pub const SLOT_METALLIC_ROUGHNESS: usize = 1;
pub const SLOT_NORMAL: usize = 2;
pub const SLOT_EMISSIVE: usize = 3;
pub const SLOT_OCCLUSION: usize = 4;

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuMaterial {
    pub base_color: [f32; 4],
    /// rgb: emitted radiance, w: 1 if double-sided.
    pub emissive: [f32; 4],
    /// metallic, roughness, specular factor (0 = pure Lambert), unused. (IOR: `shading[4][3]`.)
    pub params: [f32; 4],
    /// normal scale, occlusion strength, alpha cutoff, 1 if alpha-tested.
    pub extra: [f32; 4],
    /// Base colour, metallic-roughness, normal, emissive, occlusion.
    pub tex: [GpuTexSlot; 5],
    /// Callisto parameters and the BRDF model (layout: shaders/common/brdf.wgsl `Shading`).
    pub shading: [[f32; 4]; 5],
}

/// Where a texture's mip chain lies in the texel array: `first` holds `levels` words, the
/// offsets of each level's texels; level k is (width >> k) x (height >> k), at least 1 x 1.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuTexture {
    pub first: u32,
    pub width: u32,
    pub height: u32,
    pub levels: u32,
}

/// Words of the scene data buffer (binding 4: texture table, environment map, every texture's
/// mip chain) kept under this so that it fits one storage binding (128 MiB is wgpu's default
/// limit and lavapipe's): textures lose their finest levels, largest first, with a warning.
pub const SCENE_DATA_WORDS: usize = 32 * 1024 * 1024 - 1024;

/// Where the environment map's words start in the scene data buffer (shaders/common/sky.wgsl
/// `ENV_OFFSET`); word 0 holds the texture table's start.
pub const ENV_OFFSET: usize = 1;

/// The mip chain of one texture (level 0 first), box-filtered 2x2 (odd sizes: the last row or
/// column folds into its neighbour), colour channels in linear light when `srgb`; alpha linear.
pub fn mip_chain(t: &super::Texture, srgb: bool) -> Vec<(u32, u32, Vec<u8>)> {
    let mut levels = vec![(t.width, t.height, t.rgba8.clone())];
    loop {
        let (w, h, ref px) = *levels.last().unwrap();
        if w == 1 && h == 1 {
            break;
        }
        let (nw, nh) = ((w / 2).max(1), (h / 2).max(1));
        let decode = |v: u8, ch: usize| {
            let f = v as f32 / 255.0;
            if srgb && ch < 3 {
                srgb_to_linear(f)
            } else {
                f
            }
        };
        let mut out = vec![0u8; (nw * nh * 4) as usize];
        for y in 0..nh {
            for x in 0..nw {
                // Source rectangle of this texel: 2x2, or wider at an odd last row/column.
                let (x0, x1) = (x * w / nw, ((x + 1) * w / nw).max(x * w / nw + 1));
                let (y0, y1) = (y * h / nh, ((y + 1) * h / nh).max(y * h / nh + 1));
                for ch in 0..4 {
                    let mut sum = 0.0;
                    for sy in y0..y1 {
                        for sx in x0..x1 {
                            sum += decode(px[((sy * w + sx) * 4) as usize + ch], ch);
                        }
                    }
                    let mut v = sum / ((x1 - x0) * (y1 - y0)) as f32;
                    if srgb && ch < 3 {
                        v = linear_to_srgb(v);
                    }
                    out[((y * nw + x) * 4) as usize + ch] =
                        (v * 255.0 + 0.5).clamp(0.0, 255.0) as u8;
                }
            }
        }
        levels.push((nw, nh, out));
    }
    levels
}

/// Mean of a texture's texels (linear light for sRGB), for light powers of emissive textures.
fn texture_mean(t: &super::Texture, srgb: bool) -> Vec3 {
    let mut sum = glam::DVec3::ZERO;
    for c in t.rgba8.chunks_exact(4) {
        let f = |v: u8| {
            let x = v as f32 / 255.0;
            if srgb {
                srgb_to_linear(x)
            } else {
                x
            }
        };
        sum += glam::DVec3::new(f(c[0]) as f64, f(c[1]) as f64, f(c[2]) as f64);
    }
    (sum / (t.rgba8.len() / 4).max(1) as f64).as_vec3()
}

/// Packs every texture with its mips (RGBA8 words, each chain behind a header of level offsets)
/// to be placed at word `base` of the scene data buffer, in at most `budget` words, and the
/// table of where each lies (absolute offsets). Colour textures are averaged in linear light.
fn pack_textures(scene: &Scene, base: usize, budget: usize) -> (Vec<u32>, Vec<GpuTexture>) {
    let mut srgb = vec![false; scene.textures.len()];
    for m in &scene.materials {
        for r in [m.base_color_texture, m.emissive_texture]
            .into_iter()
            .flatten()
        {
            if let Some(s) = srgb.get_mut(r.texture) {
                *s = true;
            }
        }
    }
    // Drop finest levels (largest first) until everything fits the budget.
    let level_count = |w: u32, h: u32| 32 - w.max(h).leading_zeros();
    let chain_texels = |w: u32, h: u32, skip: u32| -> usize {
        let mut total = 0usize;
        let (mut w, mut h) = (w, h);
        for k in 0..level_count(w, h) {
            if k >= skip {
                // The level's texels and its word in the chain's header.
                total += (w * h) as usize + 1;
            }
            w = (w / 2).max(1);
            h = (h / 2).max(1);
        }
        total
    };
    let mut skip = vec![0u32; scene.textures.len()];
    loop {
        let total: usize = scene
            .textures
            .iter()
            .zip(&skip)
            .map(|(t, &s)| chain_texels(t.width, t.height, s))
            .sum();
        if total <= budget {
            break;
        }
        let largest = (0..scene.textures.len())
            .filter(|&i| {
                skip[i] + 1 < level_count(scene.textures[i].width, scene.textures[i].height)
            })
            .max_by_key(|&i| {
                let t = &scene.textures[i];
                (
                    (t.width >> skip[i]).max(1) * (t.height >> skip[i]).max(1),
                    usize::MAX - i,
                )
            });
        match largest {
            Some(i) => skip[i] += 1,
            None => break,
        }
    }
    if skip.iter().any(|&s| s > 0) {
        let reduced = skip.iter().filter(|&&s| s > 0).count();
        log::warn!(
            "textures exceed the GPU buffer budget ({:.1} M texels left beside the environment map): {reduced} of {} lose their finest mip levels",
            budget as f64 / (1024.0 * 1024.0),
            scene.textures.len()
        );
    }
    let chains: Vec<Vec<(u32, u32, Vec<u8>)>> = {
        use rayon::prelude::*;
        scene
            .textures
            .par_iter()
            .enumerate()
            .map(|(i, t)| mip_chain(t, srgb[i]).split_off(skip[i] as usize))
            .collect()
    };
    let mut texels = Vec::new();
    let mut table = Vec::new();
    for chain in chains {
        // A header of level offsets first: shaders find a level without a loop.
        let header = texels.len();
        table.push(GpuTexture {
            first: (base + header) as u32,
            width: chain[0].0,
            height: chain[0].1,
            levels: chain.len() as u32,
        });
        texels.resize(header + chain.len(), 0);
        for (k, (_, _, px)) in chain.iter().enumerate() {
            texels[header + k] = (base + texels.len()) as u32;
            texels.extend(
                px.chunks_exact(4)
                    .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]])),
            );
        }
    }
    (texels, table)
}

/// Octahedral encoding of a unit vector into two snorm16 (the shaders' `oct_decode_packed`).
pub fn oct_encode_packed(n: Vec3) -> u32 {
    let l1 = n.x.abs() + n.y.abs() + n.z.abs();
    if l1.is_nan() || l1 <= 0.0 || !l1.is_finite() {
        return 0;
    }
    let p = glam::Vec2::new(n.x, n.y) / l1;
    let e = if n.z < 0.0 {
        let sign = |v: f32| if v >= 0.0 { 1.0 } else { -1.0 };
        glam::Vec2::new((1.0 - p.y.abs()) * sign(p.x), (1.0 - p.x.abs()) * sign(p.y))
    } else {
        p
    };
    let q = |v: f32| ((v.clamp(-1.0, 1.0) * 32767.0).round() as i16) as u16 as u32;
    q(e.x) | (q(e.y) << 16)
}

pub const LIGHT_TRIANGLE: u32 = 0;
pub const LIGHT_POINT: u32 = 1;
pub const LIGHT_SPOT: u32 = 2;
pub const LIGHT_DIRECTIONAL: u32 = 3;

// A tree node takes a light record's slot in the light pool.
const _: () = assert!(
    std::mem::size_of::<GpuLight>()
        == std::mem::size_of::<crate::parts::light_tree::GpuLightTreeNode>()
);

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
    /// Local lights: the bit trail to the light's leaf in the light tree (low word, high
    /// word; `parts::light_tree`).
    pub trail: [u32; 2],
    pub position: [f32; 4],
    pub intensity: [f32; 4],
    pub direction: [f32; 4],
    pub spot: [f32; 4],
}

/// One vertex of the raster passes (G-buffer, Lumen's card capture): triangles expanded in BVH
/// order, so vertex_index / 3 is the triangle whose record the fragment shades from
/// (`surface_at`); only the position is a vertex attribute.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct RasterVertex {
    pub position: [f32; 3],
}

/// CPU copies of everything uploaded, kept for tests, the CPU BVH and light statistics.
#[derive(Clone)]
pub struct SceneData {
    pub tris: Vec<[Vec3; 3]>,
    pub bvh: Bvh,
    pub tri_geom: Vec<GpuTriGeom>,
    pub tri_attr: Vec<GpuTriAttr>,
    pub materials: Vec<GpuMaterial>,
    /// The scene data buffer (binding 4): word 0 the texture table's start, the environment
    /// map from ENV_OFFSET, the table (`textures`, 4 words each), then the mip chains.
    pub texels: std::sync::Arc<Vec<u32>>,
    /// Where each texture's mip chain lies in `texels`.
    pub textures: Vec<GpuTexture>,
    /// The environment map's words (`environment::gpu_bytes`; a header only without one), also
    /// inside `texels` from ENV_OFFSET on.
    pub environment: std::sync::Arc<Vec<u8>>,
    pub lights: Vec<GpuLight>,
    /// The light tree over the local lights, uploaded after them in the light pool.
    pub light_tree: LightTree,
    pub vertices: Vec<RasterVertex>,
    pub features: SceneFeatures,
    pub timings: SceneTimings,
}

impl SceneData {
    /// The triangles' bounding box (the unit cube for an empty scene): the world-space caches
    /// size their cells and volumes by it.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        let mut lo = Vec3::splat(f32::MAX);
        let mut hi = Vec3::splat(f32::MIN);
        for v in self.tris.iter().flatten() {
            lo = lo.min(*v);
            hi = hi.max(*v);
        }
        if lo.x > hi.x {
            return (Vec3::ZERO, Vec3::ONE);
        }
        (lo, hi)
    }
}

impl SceneData {
    /// The shader variant this scene needs: features it lacks are compiled out.
    pub fn shader_variant(&self) -> crate::gpu::shaders::ShaderVariant {
        crate::gpu::shaders::ShaderVariant {
            alpha_test: self.features.alpha_tested_materials > 0,
            instances: self.bvh.instances > 0,
        }
    }
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
    /// Building the light tree (part of `prepare_ms`; again at each re-pose).
    pub light_tree_ms: f64,
    pub threads: usize,
}

impl SceneData {
    pub fn new(scene: &Scene) -> SceneData {
        let start = std::time::Instant::now();
        let tris = scene.triangle_positions();
        let bvh = Bvh::build_instanced(&tris, &scene.instances);
        let bvh_build_ms = start.elapsed().as_secs_f64() * 1e3;
        let features = SceneFeatures::compute(scene, &bvh, &tris);

        // The scene data buffer: the texture table's start, the environment map, the table,
        // then every texture's mip chain (one binding: see SCENE_DATA_WORDS).
        let environment = super::environment::gpu_bytes(scene.environment.as_ref());
        let env_words: Vec<u32> = environment
            .chunks(4)
            .map(|c| {
                let mut w = [0u8; 4];
                w[..c.len()].copy_from_slice(c);
                u32::from_le_bytes(w)
            })
            .collect();
        let table_start = ENV_OFFSET + env_words.len();
        let data_start = table_start + 4 * scene.textures.len();
        let (texture_words, textures) = pack_textures(
            scene,
            data_start,
            SCENE_DATA_WORDS.saturating_sub(data_start),
        );
        let mut texels = Vec::with_capacity(data_start + texture_words.len());
        texels.push(table_start as u32);
        texels.extend_from_slice(&env_words);
        for t in &textures {
            texels.extend_from_slice(&[t.first, t.width, t.height, t.levels]);
        }
        texels.extend_from_slice(&texture_words);
        let present: Vec<bool> = (0..scene.textures.len()).map(|_| true).collect();
        let materials: Vec<GpuMaterial> = scene
            .materials
            .iter()
            .map(|m| {
                // KHR_materials_ior: the dielectric F0 (Shading.dual.w; IOR 1.5 gives 0.04).
                let ior = if m.ior.is_finite() && m.ior >= 1.0 {
                    m.ior
                } else {
                    1.5
                };
                let f0 = ((ior - 1.0) / (ior + 1.0)).powi(2);
                let mut shading = m.callisto.gpu_words(m.brdf);
                shading[4][3] = f0;
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
                    extra: [
                        m.normal_scale,
                        m.occlusion_strength,
                        m.alpha_cutoff,
                        if m.alpha_tested() { 1.0 } else { 0.0 },
                    ],
                    tex: [
                        GpuTexSlot::new(m.base_color_texture, &present),
                        GpuTexSlot::new(m.metallic_roughness_texture, &present),
                        GpuTexSlot::new(m.normal_texture, &present),
                        GpuTexSlot::new(m.emissive_texture, &present),
                        GpuTexSlot::new(m.occlusion_texture, &present),
                    ],
                    shading,
                }
            })
            .collect();
        let Geometry {
            lights,
            light_tree,
            light_tree_ms,
            tri_geom,
            tri_attr,
            vertices,
        } = Geometry::new(scene, &tris, &bvh);
        SceneData {
            timings: SceneTimings {
                bvh_build_ms,
                light_tree_ms,
                prepare_ms: start.elapsed().as_secs_f64() * 1e3,
                ..SceneTimings::default()
            },
            tris,
            bvh,
            tri_geom,
            tri_attr,
            materials,
            texels: std::sync::Arc::new(texels),
            textures,
            environment: std::sync::Arc::new(environment),
            lights,
            light_tree,
            vertices,
            features,
        }
    }
}

/// What moves with the geometry: the light pool (emissive triangles by BVH position, punctual
/// lights), the triangle records in BVH order and the raster vertices.
struct Geometry {
    lights: Vec<GpuLight>,
    /// The light tree over the local lights (`light_sampling = "tree"`), uploaded after them.
    light_tree: LightTree,
    light_tree_ms: f64,
    tri_geom: Vec<GpuTriGeom>,
    tri_attr: Vec<GpuTriAttr>,
    vertices: Vec<RasterVertex>,
}

impl Geometry {
    fn new(scene: &Scene, tris: &[[Vec3; 3]], bvh: &Bvh) -> Geometry {
        // Light power of a textured emitter: factor x the texture's mean (every triangle of
        // the material alike; unbiased as long as the mean is non-zero where texels are).
        let emission_scale: Vec<Vec3> = scene
            .materials
            .iter()
            .map(|m| match m.emissive_texture {
                Some(r) if r.texture < scene.textures.len() => {
                    texture_mean(&scene.textures[r.texture], true)
                }
                _ => Vec3::ONE,
            })
            .collect();

        // Light pool: power-proportional selection over emissive triangles and punctual lights.
        let (lo, hi) = scene.bounds();
        let scene_radius = ((hi - lo).length() * 0.5).max(1e-3);
        let mut lights = Vec::new();
        let mut powers = Vec::new();
        let mut tri_light_power = vec![0.0f32; tris.len()];
        let mut tri_light_index = vec![0u32; tris.len()];
        // What each local light can give a point, for the light tree.
        let mut local_bounds = Vec::new();
        for (bvh_index, &orig) in bvh.order.iter().enumerate() {
            let mi = scene.triangle_material[orig as usize] as usize;
            let m = &scene.materials[mi];
            let t = &tris[orig as usize];
            let area = 0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length();
            let power = std::f32::consts::PI
                * area
                * luminance(m.emissive * emission_scale[mi])
                * if m.double_sided { 2.0 } else { 1.0 };
            if power > 0.0 && power.is_finite() {
                tri_light_power[bvh_index] = power;
                tri_light_index[bvh_index] = lights.len() as u32 + 1;
                local_bounds.push(LightBounds::triangle(t, power, m.double_sided));
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
            match l.kind {
                PunctualKind::Point => local_bounds.push(LightBounds::point(l.position, power)),
                PunctualKind::Spot => local_bounds.push(LightBounds::spot(
                    l.position,
                    l.direction,
                    l.outer_cone,
                    power,
                )),
                PunctualKind::Directional => {}
            }
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
        let tree_start = std::time::Instant::now();
        let light_tree = LightTree::build(&local_bounds);
        for (l, trail) in lights.iter_mut().zip(&light_tree.trails) {
            l.trail = *trail;
        }
        let light_tree_ms = tree_start.elapsed().as_secs_f64() * 1e3;

        let records = motion_records(bvh);
        let mut tri_geom = Vec::with_capacity(tris.len());
        let mut tri_attr = Vec::with_capacity(tris.len());
        let mut vertices = Vec::with_capacity(tris.len() * 3);
        for (bvh_index, &orig) in bvh.order.iter().enumerate() {
            let idx = scene.triangles[orig as usize];
            let p = tris[orig as usize];
            let n = idx.map(|i| scene.normals[i as usize]);
            let uv = idx.map(|i| scene.uvs[i as usize]);
            let uv1 = idx.map(|i| scene.uvs1.get(i as usize).copied().unwrap_or_default());
            let tangent = idx.map(|i| scene.tangents.get(i as usize).copied().unwrap_or_default());
            let material = scene.triangle_material[orig as usize];
            let m = &scene.materials[material as usize];
            let pmf = if total > 0.0 {
                (tri_light_power[bvh_index] as f64 / total) as f32
            } else {
                0.0
            };
            let mut flags = 0;
            if n.iter().all(|v| v.length_squared() > 1e-12) {
                flags |= TRI_HAS_NORMALS;
            }
            if m.normal_texture.is_some()
                && tangent
                    .iter()
                    .all(|t| t.truncate().length_squared() > 1e-12)
            {
                flags |= TRI_HAS_TANGENTS;
            }
            for (k, t) in tangent.iter().enumerate() {
                if t.w < 0.0 {
                    flags |= 1 << (TRI_BITANGENT_NEG_SHIFT + k as u32);
                }
            }
            // Triangles rays may pass through carry their material (+1) for the any-hit test.
            let alpha_tag = if m.alpha_tested() { material + 1 } else { 0 };
            tri_geom.push(GpuTriGeom {
                v0: p[0].extend(f32::from_bits(alpha_tag)).to_array(),
                e1: (p[1] - p[0]).extend(0.0).to_array(),
                e2: (p[2] - p[0]).extend(0.0).to_array(),
            });
            tri_attr.push(GpuTriAttr {
                normals: n.map(oct_encode_packed),
                light_pmf: pmf,
                tangents: tangent.map(|t| oct_encode_packed(t.truncate())),
                material,
                uv0_ab: [uv[0].x, uv[0].y, uv[1].x, uv[1].y],
                uv0_c_uv1_a: [uv[2].x, uv[2].y, uv1[0].x, uv1[0].y],
                uv1_bc: [uv1[1].x, uv1[1].y, uv1[2].x, uv1[2].y],
                scene_tri: orig,
                flags,
                pad: [
                    records.get(bvh_index).copied().unwrap_or(0),
                    tri_light_index[bvh_index],
                ],
            });
            vertices.extend(p.map(|v| RasterVertex {
                position: v.to_array(),
            }));
        }
        Geometry {
            lights,
            light_tree,
            light_tree_ms,
            tri_geom,
            tri_attr,
            vertices,
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

#[derive(Clone)]
pub struct GpuScene {
    pub data: SceneData,
    pub sky: Vec3,
    pub layout: wgpu::BindGroupLayout,
    pub bind_group: wgpu::BindGroup,
    pub vertex_buffer: wgpu::Buffer,
    pub vertex_count: u32,
    /// The buffers that move with the geometry: BVH nodes, triangle geometry and attributes,
    /// light pool (bindings 0, 1, 2, 5), rewritten in place by `repose`.
    moving: [wgpu::Buffer; 4],
    /// The BVH nodes, triangle records, materials and light pool again as textures (bindings
    /// 6-10): what the shaders read, rewritten with the buffers.
    texels: SceneTexels,
    /// The instances' transforms as last written (motion records go from them to the next).
    transforms: Vec<glam::Mat4>,
    /// Whether the motion records hold a move (else identity).
    motion_live: bool,
}

/// Per triangle in BVH order: the node index + 1 of its instance's motion record (the records
/// follow the BVH's own nodes in the GPU buffer, two nodes per top-level entry), 0 for triangles
/// of the rest of the scene or of a flat BVH. The primary-surface pass reads it
/// (`previous_position`, shaders/common/scene.wgsl).
fn motion_records(bvh: &Bvh) -> Vec<u32> {
    let mut out = vec![0u32; bvh.order.len()];
    let Some(top) = &bvh.top else {
        return out;
    };
    for (e, entry) in top.entries.iter().enumerate() {
        if entry.instance.is_none() {
            continue;
        }
        let start = entry.tri_offset as usize;
        let end = top
            .entries
            .get(e + 1)
            .map_or(out.len(), |n| n.tri_offset as usize)
            .min(out.len());
        let record = (bvh.nodes.len() + 2 * e) as u32 + 1;
        out[start.min(end)..end]
            .iter_mut()
            .for_each(|r| *r = record);
    }
    out
}

/// A motion record (this frame's world to last frame's, affine), as two BVH nodes: columns x
/// and y in the first node's bounds, z and the translation in the second's.
fn motion_record(m: Mat4) -> [BvhNode; 2] {
    let c = |v: glam::Vec4| v.truncate().to_array();
    [
        BvhNode {
            min: c(m.x_axis),
            skip: 0,
            max: c(m.y_axis),
            tris: 0,
        },
        BvhNode {
            min: c(m.z_axis),
            skip: 0,
            max: c(m.w_axis),
            tris: 0,
        },
    ]
}

/// The BVH nodes buffer's contents: the BVH's nodes, then one motion record per top-level
/// entry (`motions[e]`; identity where None).
fn nodes_with_motion(bvh: &Bvh, motions: &[Mat4]) -> Vec<BvhNode> {
    let mut nodes = bvh.nodes.clone();
    if let Some(top) = &bvh.top {
        for e in 0..top.entries.len() {
            nodes.extend(motion_record(
                motions.get(e).copied().unwrap_or(Mat4::IDENTITY),
            ));
        }
    }
    nodes
}

/// The light pool buffer's contents: a header (lights, emissive triangles, punctual lights,
/// local lights), then the lights (one empty record when there are none), then the light
/// tree's nodes in records of the same size (the tree's root at record `lights.len()`).
fn light_pool_bytes(lights: &[GpuLight], tree: &LightTree) -> Vec<u8> {
    let emissive = lights.iter().filter(|l| l.kind == LIGHT_TRIANGLE).count() as u32;
    let local = lights
        .iter()
        .filter(|l| l.kind != LIGHT_DIRECTIONAL)
        .count() as u32;
    let header = [
        lights.len() as u32,
        emissive,
        lights.len() as u32 - emissive,
        local,
    ];
    let mut bytes: Vec<u8> = Vec::new();
    bytes.extend_from_slice(bytemuck::cast_slice(&header));
    bytes.extend_from_slice(bytemuck::cast_slice(lights));
    if lights.is_empty() {
        bytes.extend_from_slice(bytemuck::bytes_of(&GpuLight::default()));
    }
    bytes.extend_from_slice(bytemuck::cast_slice(&tree.nodes));
    bytes
}

/// Texels per row of the scene's texel copies (`SCENE_TEXEL_ROW_*` in shaders/common/scene.wgsl):
/// a power of two, so the shaders split a texel index by mask and shift.
pub const SCENE_TEXELS_PER_ROW: u32 = 4096;

/// The BVH nodes (two texels each), triangle geometry (three) and attributes (six), materials
/// (19) and the light pool (a header texel, then six a record) as rgba32uint textures holding
/// the same words as their storage buffers. Lavapipe (Mesa 22.3, CI's renderer) loads from a
/// storage buffer in a scalar loop over the SIMD lanes, a branch per lane and word: a vec4
/// costs about 23 ns a lane against 4 ns for a texel fetch (measured 2026-12-01,
/// docs/performance.md). A BVH walk or a hit's shading is mostly such loads, so the shaders
/// read these (shaders/common/scene.wgsl `bvh_node`, `material_at`, …); GPUs read either at
/// about the same speed. Rows are SCENE_TEXELS_PER_ROW wide, so the device's largest 2D
/// texture (16,384 rows on lavapipe) bounds a scene at about 11 M triangles.
#[derive(Clone)]
struct SceneTexels {
    nodes: wgpu::Texture,
    geom: wgpu::Texture,
    attr: wgpu::Texture,
    materials: wgpu::Texture,
    lights: wgpu::Texture,
}

impl SceneTexels {
    fn new(gpu: &Gpu, nodes: &[BvhNode], data: &SceneData, light_pool: &[u8]) -> SceneTexels {
        SceneTexels {
            nodes: Self::texture(gpu, "bvh texels", bytemuck::cast_slice(nodes)),
            geom: Self::texture(gpu, "geometry texels", bytemuck::cast_slice(&data.tri_geom)),
            attr: Self::texture(
                gpu,
                "attribute texels",
                bytemuck::cast_slice(&data.tri_attr),
            ),
            materials: Self::texture(
                gpu,
                "material texels",
                bytemuck::cast_slice(&data.materials),
            ),
            lights: Self::texture(gpu, "light texels", &Self::words(light_pool)),
        }
    }

    /// Bytes as words (the light pool is built as bytes, not aligned for a cast).
    fn words(bytes: &[u8]) -> Vec<u32> {
        bytemuck::pod_collect_to_vec(bytes)
    }

    fn views(&self) -> [wgpu::TextureView; 5] {
        [
            &self.nodes,
            &self.geom,
            &self.attr,
            &self.materials,
            &self.lights,
        ]
        .map(|t| t.create_view(&Default::default()))
    }

    /// Rows of SCENE_TEXELS_PER_ROW texels for `words` (16 bytes a texel; at least one row).
    fn extent(words: &[u32]) -> wgpu::Extent3d {
        let texels = words.len().div_ceil(4) as u32;
        wgpu::Extent3d {
            width: SCENE_TEXELS_PER_ROW,
            height: texels.div_ceil(SCENE_TEXELS_PER_ROW).max(1),
            depth_or_array_layers: 1,
        }
    }

    fn texture(gpu: &Gpu, label: &str, words: &[u32]) -> wgpu::Texture {
        let texture = gpu.device.create_texture(&wgpu::TextureDescriptor {
            label: Some(label),
            size: Self::extent(words),
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Rgba32Uint,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        Self::write(gpu, &texture, words);
        texture
    }

    /// `words` into `texture` from texel 0 on, the last row padded with zeros.
    fn write(gpu: &Gpu, texture: &wgpu::Texture, words: &[u32]) {
        let extent = Self::extent(words);
        let mut padded = words.to_vec();
        padded.resize((extent.width * extent.height * 4) as usize, 0);
        gpu.queue.write_texture(
            texture.as_image_copy(),
            bytemuck::cast_slice(&padded),
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(extent.width * 16),
                rows_per_image: Some(extent.height),
            },
            extent,
        );
    }
}

impl GpuScene {
    pub fn bind_group_layout(gpu: &Gpu) -> wgpu::BindGroupLayout {
        // 0 BVH nodes, 1 triangle geometry, 2 triangle attributes, 3 materials, 4 scene data
        // (texture table, environment map, textures), 5 light pool; 6-10 the BVH nodes,
        // triangle geometry and attributes, materials and light pool as texels (`SceneTexels`).
        let visibility = wgpu::ShaderStages::COMPUTE | wgpu::ShaderStages::FRAGMENT;
        let mut entries: Vec<wgpu::BindGroupLayoutEntry> = (0..6)
            .map(|i| wgpu::BindGroupLayoutEntry {
                binding: i,
                visibility,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Storage { read_only: true },
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            })
            .collect();
        entries.extend((6..11).map(|i| wgpu::BindGroupLayoutEntry {
            binding: i,
            visibility,
            ty: wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Uint,
                view_dimension: wgpu::TextureViewDimension::D2,
                multisampled: false,
            },
            count: None,
        }));
        crate::render::pipelines::layout(gpu, "scene", &entries)
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
        let node_words = nodes_with_motion(&data.bvh, &[]);
        let nodes = storage("bvh nodes", bytemuck::cast_slice(&node_words));
        let geom = storage("tri geom", bytemuck::cast_slice(&data.tri_geom));
        let attr = storage("tri attr", bytemuck::cast_slice(&data.tri_attr));
        let mats = storage("materials", bytemuck::cast_slice(&data.materials));
        let scene_words = storage("texels", bytemuck::cast_slice(&data.texels[..]));
        let light_bytes = light_pool_bytes(&data.lights, &data.light_tree);
        let lights = storage("light pool", &light_bytes);
        let texels = SceneTexels::new(gpu, &node_words, &data, &light_bytes);
        let layout = Self::bind_group_layout(gpu);
        let views = texels.views();
        let buffers = [&nodes, &geom, &attr, &mats, &scene_words, &lights];
        let mut entries: Vec<wgpu::BindGroupEntry> = buffers
            .iter()
            .enumerate()
            .map(|(i, b)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource: b.as_entire_binding(),
            })
            .collect();
        entries.extend(views.iter().enumerate().map(|(i, v)| wgpu::BindGroupEntry {
            binding: 6 + i as u32,
            resource: wgpu::BindingResource::TextureView(v),
        }));
        let bind_group = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("scene"),
            layout: &layout,
            entries: &entries,
        });
        let mut vbytes = bytemuck::cast_slice::<RasterVertex, u8>(&data.vertices).to_vec();
        if vbytes.is_empty() {
            vbytes.resize(std::mem::size_of::<RasterVertex>(), 0);
        }
        let vertex_buffer = gpu
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("raster vertices"),
                contents: &vbytes,
                usage: wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
            });
        let vertex_count = data.vertices.len() as u32;
        data.timings.upload_ms = upload_start.elapsed().as_secs_f64() * 1e3;
        data.timings.threads = rayon::current_num_threads();
        GpuScene {
            data,
            // The environment map's mean radiance when there is one.
            sky: scene.sky_mean(),
            layout,
            bind_group,
            vertex_buffer,
            vertex_count,
            moving: [nodes, geom, attr, lights],
            texels,
            transforms: scene.instances.iter().map(|i| i.transform).collect(),
            motion_live: false,
        }
    }

    /// The scene re-posed (`scene`: the same scene with instances moved and lights moved, as
    /// `Motion::apply` leaves it; `moved`: the instances that moved): the BVH's top level is
    /// rebuilt over the instances' transforms (bottom levels kept), the triangle records, raster
    /// vertices and light pool are made again and written into the same buffers, so every bind
    /// group stays valid. False, with nothing written, where that cannot be done (a moved
    /// instance traced as ordinary geometry, or a light pool that changed size): the caller
    /// uploads the scene again.
    pub fn repose(&mut self, gpu: &crate::gpu::Gpu, scene: &Scene, moved: &[usize]) -> bool {
        let start = std::time::Instant::now();
        let tris = scene.triangle_positions();
        if tris.len() != self.data.tris.len() {
            return false;
        }
        // In place: `rebuild_top` changes nothing when it fails. A failure further on leaves
        // a top level the caller's fresh upload replaces.
        let top_start = std::time::Instant::now();
        if !moved.is_empty() && !self.data.bvh.rebuild_top(&scene.instances, moved) {
            return false;
        }
        let bvh_build_ms = top_start.elapsed().as_secs_f64() * 1e3;
        let bvh = &self.data.bvh;
        let g = Geometry::new(scene, &tris, bvh);
        if g.lights.len() != self.data.lights.len()
            || g.light_tree.nodes.len() != self.data.light_tree.nodes.len()
            || g.tri_geom.len() != self.data.tri_geom.len()
        {
            return false;
        }
        // Motion records: from this pose back to the last one written, per top-level entry.
        let motions: Vec<Mat4> = bvh.top.as_ref().map_or(Vec::new(), |top| {
            top.entries
                .iter()
                .map(|e| match e.instance {
                    Some(j) => match (self.transforms.get(j), scene.instances.get(j)) {
                        (Some(prev), Some(now)) => *prev * now.transform.inverse(),
                        _ => Mat4::IDENTITY,
                    },
                    None => Mat4::IDENTITY,
                })
                .collect()
        });
        self.motion_live = motions.iter().any(|m| *m != Mat4::IDENTITY);
        let [nodes, geom, attr, lights] = &self.moving;
        let q = &gpu.queue;
        let node_words = nodes_with_motion(bvh, &motions);
        q.write_buffer(nodes, 0, bytemuck::cast_slice(&node_words));
        q.write_buffer(geom, 0, bytemuck::cast_slice(&g.tri_geom));
        SceneTexels::write(gpu, &self.texels.nodes, bytemuck::cast_slice(&node_words));
        SceneTexels::write(gpu, &self.texels.geom, bytemuck::cast_slice(&g.tri_geom));
        q.write_buffer(attr, 0, bytemuck::cast_slice(&g.tri_attr));
        let light_bytes = light_pool_bytes(&g.lights, &g.light_tree);
        q.write_buffer(lights, 0, &light_bytes);
        SceneTexels::write(gpu, &self.texels.attr, bytemuck::cast_slice(&g.tri_attr));
        SceneTexels::write(gpu, &self.texels.lights, &SceneTexels::words(&light_bytes));
        q.write_buffer(&self.vertex_buffer, 0, bytemuck::cast_slice(&g.vertices));
        let d = &mut self.data;
        d.tris = tris;
        d.tri_geom = g.tri_geom;
        d.tri_attr = g.tri_attr;
        d.lights = g.lights;
        d.light_tree = g.light_tree;
        d.timings.light_tree_ms = g.light_tree_ms;
        d.vertices = g.vertices;
        d.timings.bvh_build_ms = bvh_build_ms;
        d.timings.prepare_ms = start.elapsed().as_secs_f64() * 1e3;
        self.transforms = scene.instances.iter().map(|i| i.transform).collect();
        true
    }

    /// Whether the motion records hold a move (`hold_still` clears them).
    pub fn motion_live(&self) -> bool {
        self.motion_live
    }

    /// A frame where nothing moved: the motion records go back to identity (once), so motion
    /// vectors show the camera's motion only.
    pub fn hold_still(&mut self, gpu: &crate::gpu::Gpu) {
        if !self.motion_live {
            return;
        }
        self.motion_live = false;
        if let Some(top) = &self.data.bvh.top {
            let at = self.data.bvh.nodes.len() * std::mem::size_of::<BvhNode>();
            let identity: Vec<BvhNode> = (0..top.entries.len())
                .flat_map(|_| motion_record(Mat4::IDENTITY))
                .collect();
            gpu.queue
                .write_buffer(&self.moving[0], at as u64, bytemuck::cast_slice(&identity));
            // The texels: the whole node list again (the records need not start a row).
            let nodes = nodes_with_motion(&self.data.bvh, &[]);
            SceneTexels::write(gpu, &self.texels.nodes, bytemuck::cast_slice(&nodes));
        }
    }
}
