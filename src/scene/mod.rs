//! Scenes: the CPU-side triangle soup every technique renders (world space, one material per
//! triangle), loaded from glTF or built procedurally, plus its BVH, features and GPU upload.

pub mod animation;
pub mod atrium;
pub mod builtin;
pub mod bvh;
pub mod environment;
pub mod features;
pub mod gltf_load;
pub mod gltf_validate;
pub mod gpu_scene;
pub mod instancing;
pub mod interior;
pub mod motion;
pub mod moving;
pub mod shading;
pub mod tangents;

use anyhow::Result;
use glam::{Vec2, Vec3, Vec4};
use serde::{Deserialize, Serialize};

/// glTF alpha modes. `Blend` is traced as `Mask` with the material's cutoff (0.5 unless the
/// file says otherwise): a path tracer has no draw order to blend in, and stochastic
/// transparency would add noise to every technique alike (stated in docs/scenes.md).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum AlphaMode {
    #[default]
    Opaque,
    Mask,
    Blend,
}

/// KHR_texture_transform: uv' = T(offset) R(rotation) S(scale) uv, as the extension specifies
/// (rotation in radians, counter-clockwise in UV space, i.e. the matrix [[c, s], [-s, c]]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UvTransform {
    pub offset: Vec2,
    pub rotation: f32,
    pub scale: Vec2,
}

impl Default for UvTransform {
    fn default() -> Self {
        UvTransform {
            offset: Vec2::ZERO,
            rotation: 0.0,
            scale: Vec2::ONE,
        }
    }
}

impl UvTransform {
    /// Rows of the 2x3 matrix: uv' = (r0.xy . uv + r0.z, r1.xy . uv + r1.z).
    pub fn rows(&self) -> [[f32; 3]; 2] {
        let (s, c) = self.rotation.sin_cos();
        // T * R * S with R = [[c, s], [-s, c]] (the extension's column-major mat3 written out).
        [
            [c * self.scale.x, s * self.scale.y, self.offset.x],
            [-s * self.scale.x, c * self.scale.y, self.offset.y],
        ]
    }
    pub fn apply(&self, uv: Vec2) -> Vec2 {
        let r = self.rows();
        Vec2::new(
            r[0][0] * uv.x + r[0][1] * uv.y + r[0][2],
            r[1][0] * uv.x + r[1][1] * uv.y + r[1][2],
        )
    }
}

/// A material's use of a texture: which one, which UV set, its transform and its sampler.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TextureRef {
    /// Index into `Scene::textures`.
    pub texture: usize,
    /// UV set: 0 (`uvs`) or 1 (`uvs1`).
    pub tex_coord: u32,
    pub transform: UvTransform,
    pub sampler: Sampler,
}

impl TextureRef {
    pub fn new(texture: usize) -> TextureRef {
        TextureRef {
            texture,
            tex_coord: 0,
            transform: UvTransform::default(),
            sampler: Sampler::default(),
        }
    }
}

/// glTF sampler wrap mode of one texture axis (codes as in shaders/common/scene.wgsl).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Wrap {
    #[default]
    Repeat = 0,
    ClampToEdge = 1,
    MirroredRepeat = 2,
}

/// How a texture is read (glTF sampler): wrap per axis, and `nearest` texel instead of
/// bilinear (magFilter NEAREST; mip levels are picked by ray cones whatever minFilter says).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Sampler {
    pub wrap_u: Wrap,
    pub wrap_v: Wrap,
    pub nearest: bool,
}

impl Sampler {
    /// The bits above the UV set in `GpuTexSlot::transform_v.w`: wrap u (2 bits), wrap v
    /// (2 bits), nearest (1 bit).
    pub fn gpu_bits(self) -> u32 {
        self.wrap_u as u32 | (self.wrap_v as u32) << 2 | (self.nearest as u32) << 4
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    pub name: String,
    /// Linear RGBA factor (multiplied with the texture).
    pub base_color: Vec4,
    /// sRGB base colour and alpha.
    pub base_color_texture: Option<TextureRef>,
    pub metallic: f32,
    pub roughness: f32,
    /// Linear; G = roughness, B = metallic (glTF), multiplying the factors.
    pub metallic_roughness_texture: Option<TextureRef>,
    /// Tangent-space normal map (linear, glTF's +Y-up convention).
    pub normal_texture: Option<TextureRef>,
    /// glTF normalTexture.scale: scales the map's X and Y.
    pub normal_scale: f32,
    /// Emitted radiance: emissiveFactor x KHR_materials_emissive_strength.
    pub emissive: Vec3,
    /// sRGB, multiplying `emissive`.
    pub emissive_texture: Option<TextureRef>,
    /// Baked ambient occlusion (R channel). Loaded and uploaded but not applied: every technique
    /// here computes occlusion itself, and applying both would count it twice (as Cycles and
    /// Mitsuba also ignore it).
    pub occlusion_texture: Option<TextureRef>,
    pub occlusion_strength: f32,
    pub alpha_mode: AlphaMode,
    /// Mask: alpha below this is a hole (glTF default 0.5).
    pub alpha_cutoff: f32,
    /// KHR_materials_specular specularFactor: 0 turns the dielectric specular lobe off (pure Lambert).
    pub specular: f32,
    /// KHR_materials_ior: dielectric F0 = ((ior - 1) / (ior + 1))^2 (1.5: F0 = 0.04).
    pub ior: f32,
    /// Emission goes both ways only when the material is double-sided.
    pub double_sided: bool,
    /// The BRDF model (set for all materials by the preset's `[shading] brdf`).
    pub brdf: shading::BrdfModel,
    /// Callisto parameters (glTF extras `gilab_callisto`, preset `[shading]` overrides).
    pub callisto: shading::CallistoParams,
}

impl Material {
    pub fn lambert(name: &str, albedo: Vec3) -> Material {
        Material {
            name: name.into(),
            base_color: albedo.extend(1.0),
            base_color_texture: None,
            metallic: 0.0,
            roughness: 1.0,
            metallic_roughness_texture: None,
            normal_texture: None,
            normal_scale: 1.0,
            emissive: Vec3::ZERO,
            emissive_texture: None,
            occlusion_texture: None,
            occlusion_strength: 1.0,
            alpha_mode: AlphaMode::Opaque,
            alpha_cutoff: 0.5,
            specular: 0.0,
            ior: 1.5,
            double_sided: false,
            brdf: shading::BrdfModel::default(),
            callisto: shading::CallistoParams::default(),
        }
    }
    pub fn emitter(name: &str, radiance: Vec3) -> Material {
        Material {
            emissive: radiance,
            ..Material::lambert(name, Vec3::ZERO)
        }
    }
    pub fn glossy(name: &str, base: Vec3, metallic: f32, roughness: f32) -> Material {
        Material {
            metallic,
            roughness,
            specular: 1.0,
            ..Material::lambert(name, base)
        }
    }
    /// Every texture the material uses, with the slot name (for validation and messages).
    pub fn texture_refs(&self) -> [(&'static str, Option<TextureRef>); 5] {
        [
            ("baseColorTexture", self.base_color_texture),
            ("metallicRoughnessTexture", self.metallic_roughness_texture),
            ("normalTexture", self.normal_texture),
            ("emissiveTexture", self.emissive_texture),
            ("occlusionTexture", self.occlusion_texture),
        ]
    }
    /// True when rays may pass through parts of it (alpha mask, or blend traced as a mask).
    pub fn alpha_tested(&self) -> bool {
        self.alpha_mode != AlphaMode::Opaque
    }
}

/// An RGBA8 texture as stored in the file (sRGB or linear is decided by the material slot
/// that reads it: base colour and emission are sRGB, the others linear).
#[derive(Clone, Debug)]
pub struct Texture {
    pub width: u32,
    pub height: u32,
    pub rgba8: Vec<u8>,
}

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PunctualKind {
    Point,
    Spot,
    Directional,
}

#[derive(Clone, Debug, PartialEq)]
pub struct PunctualLight {
    pub kind: PunctualKind,
    pub position: Vec3,
    /// Direction the light points to (spot, directional).
    pub direction: Vec3,
    /// Colour x intensity: W/sr for point/spot, W/m^2 for directional (glTF's photometric units taken as radiometric).
    pub intensity: Vec3,
    pub inner_cone: f32,
    pub outer_cone: f32,
}

/// A pinhole camera; `fov_y` in degrees.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Camera {
    pub position: Vec3,
    pub target: Vec3,
    #[serde(default = "default_up")]
    pub up: Vec3,
    pub fov_y: f32,
}

fn default_up() -> Vec3 {
    Vec3::Y
}

impl Camera {
    pub fn forward(&self) -> Vec3 {
        (self.target - self.position)
            .try_normalize()
            .unwrap_or(Vec3::NEG_Z)
    }
    /// Right and up vectors, robust to `up` parallel to the view direction.
    pub fn basis(&self) -> (Vec3, Vec3, Vec3) {
        let f = self.forward();
        let mut r = f.cross(self.up);
        if r.length_squared() < 1e-10 {
            r = f.cross(if f.y.abs() < 0.9 { Vec3::Y } else { Vec3::X });
        }
        let r = r.normalize();
        (r, r.cross(f), f)
    }
    pub fn view_from_world(&self) -> glam::Mat4 {
        let (_, up, f) = self.basis();
        glam::camera::rh::view::look_to_mat4(self.position, f, up)
    }
    pub fn clip_from_world(&self, aspect: f32, near: f32) -> glam::Mat4 {
        let fov = self.fov_y.clamp(0.01, 179.0).to_radians();
        // wgpu's NDC: y up, depth in [0, 1] (the "directx" convention).
        glam::camera::rh::proj::directx::perspective_infinite(fov, aspect, near)
            * self.view_from_world()
    }
}

/// World-space triangle soup. Triangles index into the vertex arrays.
#[derive(Clone, Debug, Default)]
pub struct Scene {
    pub name: String,
    pub positions: Vec<Vec3>,
    /// Per vertex; zero-length normals mean "use the geometric normal".
    pub normals: Vec<Vec3>,
    pub uvs: Vec<Vec2>,
    /// Second UV set (glTF TEXCOORD_1): empty when no vertex has one, else one per vertex.
    pub uvs1: Vec<Vec2>,
    /// Per-vertex tangent (xyz) and bitangent sign (w), MikkTSpace when generated: empty when no
    /// material needs them, else one per vertex (zero where unknown).
    pub tangents: Vec<Vec4>,
    pub triangles: Vec<[u32; 3]>,
    pub triangle_material: Vec<u32>,
    pub materials: Vec<Material>,
    pub textures: Vec<Texture>,
    pub lights: Vec<PunctualLight>,
    pub camera: Option<Camera>,
    /// Constant sky radiance seen by rays that leave the scene.
    pub sky: Vec3,
    /// An equirectangular HDR map as the sky; when set it replaces `sky` (see `sky_mean`).
    pub environment: Option<environment::Environment>,
    /// Repeats of one mesh (glTF meshes drawn by several nodes, EXT_mesh_gpu_instancing, the
    /// atrium's columns and vases): the BVH builds one bottom-level tree per mesh and a top
    /// level over the instances (`bvh::Bvh::build_instanced`). Their triangles are also in
    /// `triangles` (shading reads the flattened world-space records).
    pub instances: Vec<MeshInstance>,
    /// The file's animations (glTF clips), and the pose the scene is at (`[scene] time`, or
    /// playback's last `Motion::apply`; None: the rest pose).
    pub animations: Vec<animation::ClipInfo>,
    pub posed_at: Option<f32>,
    /// What the animations move and how to re-pose it (`[scene] time_scale` plays it); None
    /// when nothing moves.
    pub motion: Option<std::sync::Arc<motion::Motion>>,
    /// Named triangle ranges of a built-in scene ("tall box", "light"): what a preset's
    /// `[[scene.animate]]` can move. Naming changes no triangle.
    pub objects: Vec<NamedObject>,
}

/// Scene triangles `first_triangle..first_triangle + triangle_count`, under a name.
#[derive(Clone, Debug, PartialEq)]
pub struct NamedObject {
    pub name: String,
    pub first_triangle: u32,
    pub triangle_count: u32,
}

/// One placement of a mesh: scene triangles `first_triangle..first_triangle + triangle_count`
/// are mesh `mesh`'s triangles, in the same order for every instance of that mesh, moved by
/// `transform` (object to world, affine). The mesh's own object-space shape is that of its
/// first instance taken back through its transform; an instance whose triangles do not match
/// it (an edited scene, a mirrored winding) is traced as ordinary geometry instead.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MeshInstance {
    pub mesh: u32,
    pub transform: glam::Mat4,
    pub first_triangle: u32,
    pub triangle_count: u32,
}

impl Scene {
    pub fn new(name: &str) -> Scene {
        Scene {
            name: name.into(),
            ..Default::default()
        }
    }

    pub fn add_material(&mut self, m: Material) -> u32 {
        self.materials.push(m);
        self.materials.len() as u32 - 1
    }

    /// Names the triangles `add` puts into the scene (`Scene::objects`).
    pub fn named(&mut self, name: &str, add: impl FnOnce(&mut Scene)) {
        let first = self.triangles.len();
        add(self);
        self.objects.push(NamedObject {
            name: name.to_string(),
            first_triangle: first as u32,
            triangle_count: (self.triangles.len() - first) as u32,
        });
    }

    /// Adds a triangle with flat normals (computed from the winding) and planar UVs.
    pub fn add_triangle(&mut self, v: [Vec3; 3], material: u32) {
        let n = (v[1] - v[0]).cross(v[2] - v[0]).normalize_or_zero();
        let base = self.positions.len() as u32;
        for (i, p) in v.iter().enumerate() {
            self.positions.push(*p);
            self.normals.push(n);
            self.uvs.push([Vec2::ZERO, Vec2::X, Vec2::Y][i]);
        }
        self.triangles.push([base, base + 1, base + 2]);
        self.triangle_material.push(material);
    }

    /// Quad a-b-c-d (counter-clockwise seen from the side the normal faces).
    pub fn add_quad(&mut self, a: Vec3, b: Vec3, c: Vec3, d: Vec3, material: u32) {
        self.add_triangle([a, b, c], material);
        self.add_triangle([a, c, d], material);
    }

    /// The axis-aligned box from corner `lo` to corner `hi`; faces wound outward.
    pub fn add_aabb(&mut self, lo: Vec3, hi: Vec3, material: u32) {
        let v = Vec3::new;
        self.add_box(
            [
                v(lo.x, lo.y, lo.z),
                v(lo.x, lo.y, hi.z),
                v(hi.x, lo.y, hi.z),
                v(hi.x, lo.y, lo.z),
                v(lo.x, hi.y, lo.z),
                v(lo.x, hi.y, hi.z),
                v(hi.x, hi.y, hi.z),
                v(hi.x, hi.y, lo.z),
            ],
            material,
        );
    }

    /// Axis-aligned-then-transformed box given by 8 corners; faces wound outward.
    pub fn add_box(&mut self, corners: [Vec3; 8], material: u32) {
        // corners: bottom 0..4 (ccw seen from above), top 4..8 above them.
        let [b0, b1, b2, b3, t0, t1, t2, t3] = corners;
        self.add_quad(t0, t1, t2, t3, material); // top, faces +y when bottom ring is ccw from above
        self.add_quad(b0, b3, b2, b1, material); // bottom
        self.add_quad(b0, b1, t1, t0, material);
        self.add_quad(b1, b2, t2, t1, material);
        self.add_quad(b2, b3, t3, t2, material);
        self.add_quad(b3, b0, t0, t3, material);
    }

    /// Every triangle's three positions (the soup the BVH is built over).
    pub fn triangle_positions(&self) -> Vec<[Vec3; 3]> {
        self.triangles
            .iter()
            .map(|t| t.map(|i| self.positions[i as usize]))
            .collect()
    }
    pub fn bounds(&self) -> (Vec3, Vec3) {
        let mut lo = Vec3::splat(f32::MAX);
        let mut hi = Vec3::splat(f32::MIN);
        for t in &self.triangles {
            for &i in t {
                lo = lo.min(self.positions[i as usize]);
                hi = hi.max(self.positions[i as usize]);
            }
        }
        if lo.x > hi.x {
            (Vec3::ZERO, Vec3::ZERO)
        } else {
            (lo, hi)
        }
    }

    /// A camera that frames the whole scene when neither the file nor the preset gives one.
    pub fn default_camera(&self) -> Camera {
        if let Some(c) = self.camera {
            return c;
        }
        let (lo, hi) = self.bounds();
        let center = (lo + hi) * 0.5;
        let radius = ((hi - lo).length() * 0.5).max(1e-3);
        Camera {
            position: center + Vec3::new(0.0, 0.3, 1.0).normalize() * radius * 2.2,
            target: center,
            up: Vec3::Y,
            fov_y: 45.0,
        }
    }

    /// Checks internal consistency; loaders call it so bad data never reaches the GPU.
    pub fn validate(&self) -> Result<()> {
        let nv = self.positions.len();
        anyhow::ensure!(
            self.triangles.len() < bvh::MAX_TRIANGLES,
            "{} triangles exceed the limit of {}",
            self.triangles.len(),
            bvh::MAX_TRIANGLES
        );
        anyhow::ensure!(
            self.normals.len() == nv && self.uvs.len() == nv,
            "vertex attribute arrays differ in length"
        );
        anyhow::ensure!(
            (self.uvs1.is_empty() || self.uvs1.len() == nv)
                && (self.tangents.is_empty() || self.tangents.len() == nv),
            "second UV set or tangents given for some vertices only"
        );
        anyhow::ensure!(
            self.triangle_material.len() == self.triangles.len(),
            "one material per triangle expected"
        );
        for (i, t) in self.triangles.iter().enumerate() {
            anyhow::ensure!(
                t.iter().all(|&v| (v as usize) < nv),
                "triangle {i} indexes a vertex out of range"
            );
            anyhow::ensure!(
                (self.triangle_material[i] as usize) < self.materials.len(),
                "triangle {i} has no material"
            );
        }
        for p in &self.positions {
            anyhow::ensure!(p.is_finite(), "vertex position is not finite");
        }
        for m in &self.materials {
            for (slot, t) in m.texture_refs() {
                if let Some(t) = t {
                    anyhow::ensure!(
                        t.texture < self.textures.len(),
                        "material '{}': {slot} references a missing texture",
                        m.name
                    );
                    anyhow::ensure!(
                        t.tex_coord <= 1,
                        "material '{}': {slot} uses TEXCOORD_{} (sets 0 and 1 are read)",
                        m.name,
                        t.tex_coord
                    );
                }
            }
        }
        Ok(())
    }
}
