//! A tiny glTF writer for tests: meshes (positions, normals, TEXCOORD_0/1, TANGENT, indices),
//! materials with the fields and extensions the loader reads, PNG textures (8 or 16 bits),
//! KHR_lights_punctual lights, a perspective camera and EXT_mesh_gpu_instancing. Writes
//! `<name>.gltf` with its buffer in `<name>.bin` and images in `<name>-<i>.png` beside it.
#![allow(dead_code)]

use glam::{Mat3, Quat, Vec2, Vec3, Vec4};
use serde_json::{json, Map, Value};
use std::path::{Path, PathBuf};

/// Vertex data of one triangle primitive.
#[derive(Clone, Debug, Default)]
pub struct MeshData {
    pub positions: Vec<Vec3>,
    pub normals: Option<Vec<Vec3>>,
    pub uv0: Option<Vec<Vec2>>,
    pub uv1: Option<Vec<Vec2>>,
    pub tangents: Option<Vec<Vec4>>,
    pub indices: Option<Vec<u32>>,
}

impl MeshData {
    /// A square in the XZ plane at height `y`, normal +Y, corners (±half, y, ±half), two
    /// triangles counter-clockwise seen from above; UV0 from `uv(x, z)`.
    pub fn quad_xz(half: f32, y: f32, uv: impl Fn(f32, f32) -> Vec2) -> MeshData {
        let p = vec![
            Vec3::new(-half, y, -half),
            Vec3::new(-half, y, half),
            Vec3::new(half, y, half),
            Vec3::new(half, y, -half),
        ];
        MeshData {
            uv0: Some(p.iter().map(|p| uv(p.x, p.z)).collect()),
            normals: Some(vec![Vec3::Y; 4]),
            positions: p,
            indices: Some(vec![0, 1, 2, 0, 2, 3]),
            ..Default::default()
        }
    }
}

/// KHR_texture_transform of a texture reference.
#[derive(Clone, Copy, Debug, Default)]
pub struct TexTransform {
    pub offset: Option<[f32; 2]>,
    pub rotation: Option<f32>,
    pub scale: Option<[f32; 2]>,
    pub tex_coord: Option<u32>,
}

/// A textureInfo: texture index, texCoord, optional KHR_texture_transform.
#[derive(Clone, Copy, Debug)]
pub struct TexRef {
    pub texture: usize,
    pub tex_coord: u32,
    pub transform: Option<TexTransform>,
}

pub fn tex(texture: usize) -> TexRef {
    TexRef {
        texture,
        tex_coord: 0,
        transform: None,
    }
}

/// A glTF material; `None` fields are left out of the file (glTF defaults apply).
#[derive(Clone, Debug, Default)]
pub struct MaterialDesc {
    pub name: String,
    pub base_color: Option<[f32; 4]>,
    pub base_color_texture: Option<TexRef>,
    pub metallic: Option<f32>,
    pub roughness: Option<f32>,
    pub metallic_roughness_texture: Option<TexRef>,
    pub normal_texture: Option<TexRef>,
    pub normal_scale: Option<f32>,
    pub occlusion_texture: Option<TexRef>,
    pub occlusion_strength: Option<f32>,
    pub emissive: Option<[f32; 3]>,
    pub emissive_texture: Option<TexRef>,
    /// KHR_materials_emissive_strength.
    pub emissive_strength: Option<f32>,
    /// "OPAQUE", "MASK", "BLEND".
    pub alpha_mode: Option<&'static str>,
    pub alpha_cutoff: Option<f32>,
    pub double_sided: bool,
    /// KHR_materials_ior.
    pub ior: Option<f32>,
    /// KHR_materials_specular specularFactor.
    pub specular: Option<f32>,
}

impl MaterialDesc {
    /// Pure Lambert (metallic 0, roughness 1, specularFactor 0) of linear albedo `a`.
    pub fn lambert(name: &str, a: [f32; 3]) -> MaterialDesc {
        MaterialDesc {
            name: name.into(),
            base_color: Some([a[0], a[1], a[2], 1.0]),
            metallic: Some(0.0),
            roughness: Some(1.0),
            specular: Some(0.0),
            ..Default::default()
        }
    }
}

/// Node placement: translation, rotation, scale (glTF's TRS) or a column-major matrix.
#[derive(Clone, Copy, Debug)]
pub enum Place {
    Trs(Vec3, Quat, Vec3),
    Matrix(glam::Mat4),
}

impl Place {
    pub const IDENTITY: Place = Place::Trs(Vec3::ZERO, Quat::IDENTITY, Vec3::ONE);
    pub fn at(t: Vec3) -> Place {
        Place::Trs(t, Quat::IDENTITY, Vec3::ONE)
    }
}

enum ImageData {
    Png(Vec<u8>),
    /// A URI that does not exist (tests of the lenient loader).
    Missing(String),
}

#[derive(Default)]
pub struct GltfBuilder {
    bin: Vec<u8>,
    buffer_views: Vec<Value>,
    accessors: Vec<Value>,
    meshes: Vec<Value>,
    materials: Vec<Value>,
    textures: Vec<Value>,
    samplers: Vec<Value>,
    images: Vec<ImageData>,
    nodes: Vec<Value>,
    cameras: Vec<Value>,
    lights: Vec<Value>,
    extensions_used: Vec<String>,
    extensions_required: Vec<String>,
}

impl GltfBuilder {
    pub fn new() -> GltfBuilder {
        GltfBuilder::default()
    }

    pub fn use_extension(&mut self, name: &str, required: bool) {
        if !self.extensions_used.iter().any(|e| e == name) {
            self.extensions_used.push(name.into());
        }
        if required && !self.extensions_required.iter().any(|e| e == name) {
            self.extensions_required.push(name.into());
        }
    }

    fn view(&mut self, bytes: &[u8], target: Option<u32>) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let mut v = json!({"buffer": 0, "byteOffset": self.bin.len(), "byteLength": bytes.len()});
        if let Some(t) = target {
            v["target"] = t.into();
        }
        self.bin.extend_from_slice(bytes);
        self.buffer_views.push(v);
        self.buffer_views.len() - 1
    }

    /// A float accessor of `n`-component elements (`kind`: "SCALAR", "VEC2", ...).
    pub fn float_accessor(&mut self, data: &[f32], kind: &str, n: usize, minmax: bool) -> usize {
        let bytes: Vec<u8> = data.iter().flat_map(|f| f.to_le_bytes()).collect();
        let view = self.view(&bytes, Some(34962));
        let mut a = json!({
            "bufferView": view, "componentType": 5126, "count": data.len() / n, "type": kind
        });
        if minmax {
            let mut lo = vec![f32::MAX; n];
            let mut hi = vec![f32::MIN; n];
            for e in data.chunks_exact(n) {
                for k in 0..n {
                    lo[k] = lo[k].min(e[k]);
                    hi[k] = hi[k].max(e[k]);
                }
            }
            a["min"] = json!(lo);
            a["max"] = json!(hi);
        }
        self.accessors.push(a);
        self.accessors.len() - 1
    }

    /// A normalized signed-short VEC4 accessor (instancing rotations as quantised files have them).
    pub fn snorm16_vec4_accessor(&mut self, data: &[Vec4]) -> usize {
        let bytes: Vec<u8> = data
            .iter()
            .flat_map(|v| v.to_array())
            .flat_map(|f| ((f.clamp(-1.0, 1.0) * 32767.0).round() as i16).to_le_bytes())
            .collect();
        let view = self.view(&bytes, None);
        self.accessors.push(json!({
            "bufferView": view, "componentType": 5122, "normalized": true,
            "count": data.len(), "type": "VEC4"
        }));
        self.accessors.len() - 1
    }

    fn index_accessor(&mut self, idx: &[u32]) -> usize {
        let bytes: Vec<u8> = idx.iter().flat_map(|i| i.to_le_bytes()).collect();
        let view = self.view(&bytes, Some(34963));
        self.accessors.push(json!({
            "bufferView": view, "componentType": 5125, "count": idx.len(), "type": "SCALAR"
        }));
        self.accessors.len() - 1
    }

    /// A mesh of one primitive; returns the mesh index.
    pub fn mesh(&mut self, m: &MeshData, material: Option<usize>) -> usize {
        let flat3 = |v: &[Vec3]| v.iter().flat_map(|p| p.to_array()).collect::<Vec<f32>>();
        let flat2 = |v: &[Vec2]| v.iter().flat_map(|p| p.to_array()).collect::<Vec<f32>>();
        let mut attributes = Map::new();
        let pos = self.float_accessor(&flat3(&m.positions), "VEC3", 3, true);
        attributes.insert("POSITION".into(), pos.into());
        if let Some(n) = &m.normals {
            let a = self.float_accessor(&flat3(n), "VEC3", 3, false);
            attributes.insert("NORMAL".into(), a.into());
        }
        if let Some(uv) = &m.uv0 {
            let a = self.float_accessor(&flat2(uv), "VEC2", 2, false);
            attributes.insert("TEXCOORD_0".into(), a.into());
        }
        if let Some(uv) = &m.uv1 {
            let a = self.float_accessor(&flat2(uv), "VEC2", 2, false);
            attributes.insert("TEXCOORD_1".into(), a.into());
        }
        if let Some(t) = &m.tangents {
            let data: Vec<f32> = t.iter().flat_map(|t| t.to_array()).collect();
            let a = self.float_accessor(&data, "VEC4", 4, false);
            attributes.insert("TANGENT".into(), a.into());
        }
        let mut prim = json!({"attributes": attributes, "mode": 4});
        if let Some(idx) = &m.indices {
            prim["indices"] = self.index_accessor(idx).into();
        }
        if let Some(mat) = material {
            prim["material"] = mat.into();
        }
        self.meshes.push(json!({"primitives": [prim]}));
        self.meshes.len() - 1
    }

    fn push_image(&mut self, image: ImageData) -> usize {
        self.images.push(image);
        let i = self.images.len() - 1;
        self.textures.push(json!({"source": i}));
        self.textures.len() - 1
    }

    /// An RGBA8 PNG texture (row 0 is the top of the image, v = 0); returns the texture index.
    pub fn texture_rgba8(&mut self, w: u32, h: u32, rgba: &[u8]) -> usize {
        let img = image::RgbaImage::from_raw(w, h, rgba.to_vec()).expect("w * h * 4 bytes");
        let mut png = Vec::new();
        img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .unwrap();
        self.push_image(ImageData::Png(png))
    }

    /// An RGBA16 PNG texture.
    pub fn texture_rgba16(&mut self, w: u32, h: u32, rgba: &[u16]) -> usize {
        let img: image::ImageBuffer<image::Rgba<u16>, Vec<u16>> =
            image::ImageBuffer::from_raw(w, h, rgba.to_vec()).expect("w * h * 4 values");
        let mut png = Vec::new();
        image::DynamicImage::ImageRgba16(img)
            .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .unwrap();
        self.push_image(ImageData::Png(png))
    }

    /// Gives `texture` a sampler: glTF wrap codes (10497 repeat, 33071 clamp to edge, 33648
    /// mirrored repeat) and magFilter (9728 nearest, 9729 linear).
    pub fn sampler(&mut self, texture: usize, wrap_s: u32, wrap_t: u32, mag_filter: Option<u32>) {
        let mut v = json!({"wrapS": wrap_s, "wrapT": wrap_t});
        if let Some(m) = mag_filter {
            v["magFilter"] = m.into();
        }
        self.samplers.push(v);
        self.textures[texture]["sampler"] = (self.samplers.len() - 1).into();
    }

    /// A texture whose image file does not exist.
    pub fn texture_missing(&mut self, uri: &str) -> usize {
        self.push_image(ImageData::Missing(uri.into()))
    }

    fn tex_json(&mut self, t: &TexRef) -> Value {
        let mut v = json!({"index": t.texture});
        if t.tex_coord != 0 {
            v["texCoord"] = t.tex_coord.into();
        }
        if let Some(tr) = t.transform {
            self.use_extension("KHR_texture_transform", false);
            let mut e = Map::new();
            if let Some(o) = tr.offset {
                e.insert("offset".into(), json!(o));
            }
            if let Some(r) = tr.rotation {
                e.insert("rotation".into(), json!(r));
            }
            if let Some(s) = tr.scale {
                e.insert("scale".into(), json!(s));
            }
            if let Some(c) = tr.tex_coord {
                e.insert("texCoord".into(), json!(c));
            }
            v["extensions"] = json!({"KHR_texture_transform": e});
        }
        v
    }

    pub fn material(&mut self, m: &MaterialDesc) -> usize {
        let mut pbr = Map::new();
        if let Some(c) = m.base_color {
            pbr.insert("baseColorFactor".into(), json!(c));
        }
        if let Some(t) = &m.base_color_texture {
            pbr.insert("baseColorTexture".into(), self.tex_json(t));
        }
        if let Some(v) = m.metallic {
            pbr.insert("metallicFactor".into(), json!(v));
        }
        if let Some(v) = m.roughness {
            pbr.insert("roughnessFactor".into(), json!(v));
        }
        if let Some(t) = &m.metallic_roughness_texture {
            pbr.insert("metallicRoughnessTexture".into(), self.tex_json(t));
        }
        let mut v = json!({"name": m.name, "pbrMetallicRoughness": pbr});
        if let Some(t) = &m.normal_texture {
            let mut n = self.tex_json(t);
            if let Some(s) = m.normal_scale {
                n["scale"] = json!(s);
            }
            v["normalTexture"] = n;
        }
        if let Some(t) = &m.occlusion_texture {
            let mut o = self.tex_json(t);
            if let Some(s) = m.occlusion_strength {
                o["strength"] = json!(s);
            }
            v["occlusionTexture"] = o;
        }
        if let Some(e) = m.emissive {
            v["emissiveFactor"] = json!(e);
        }
        if let Some(t) = &m.emissive_texture {
            v["emissiveTexture"] = self.tex_json(t);
        }
        if let Some(a) = m.alpha_mode {
            v["alphaMode"] = json!(a);
        }
        if let Some(c) = m.alpha_cutoff {
            v["alphaCutoff"] = json!(c);
        }
        if m.double_sided {
            v["doubleSided"] = json!(true);
        }
        let mut ext = Map::new();
        if let Some(s) = m.emissive_strength {
            self.use_extension("KHR_materials_emissive_strength", false);
            ext.insert(
                "KHR_materials_emissive_strength".into(),
                json!({"emissiveStrength": s}),
            );
        }
        if let Some(i) = m.ior {
            self.use_extension("KHR_materials_ior", false);
            ext.insert("KHR_materials_ior".into(), json!({"ior": i}));
        }
        if let Some(s) = m.specular {
            self.use_extension("KHR_materials_specular", false);
            ext.insert(
                "KHR_materials_specular".into(),
                json!({"specularFactor": s}),
            );
        }
        if !ext.is_empty() {
            v["extensions"] = Value::Object(ext);
        }
        self.materials.push(v);
        self.materials.len() - 1
    }

    fn place(v: &mut Value, p: Place) {
        match p {
            Place::Trs(t, r, s) => {
                v["translation"] = json!(t.to_array());
                v["rotation"] = json!(r.to_array());
                v["scale"] = json!(s.to_array());
            }
            Place::Matrix(m) => v["matrix"] = json!(m.to_cols_array()),
        }
    }

    /// A root node with a mesh.
    pub fn node(&mut self, mesh: usize, place: Place) -> usize {
        let mut v = json!({"mesh": mesh});
        Self::place(&mut v, place);
        self.nodes.push(v);
        self.nodes.len() - 1
    }

    /// A root node with a mesh drawn once per instance (EXT_mesh_gpu_instancing); `rotation`
    /// is written as normalized shorts when `snorm_rotation`.
    pub fn instanced_node(
        &mut self,
        mesh: usize,
        place: Place,
        translation: Option<&[Vec3]>,
        rotation: Option<&[Quat]>,
        scale: Option<&[Vec3]>,
        snorm_rotation: bool,
    ) -> usize {
        self.use_extension("EXT_mesh_gpu_instancing", true);
        let mut attrs = Map::new();
        if let Some(t) = translation {
            let d: Vec<f32> = t.iter().flat_map(|v| v.to_array()).collect();
            attrs.insert(
                "TRANSLATION".into(),
                self.float_accessor(&d, "VEC3", 3, false).into(),
            );
        }
        if let Some(r) = rotation {
            let a = if snorm_rotation {
                let q: Vec<Vec4> = r.iter().map(|q| Vec4::from(q.to_array())).collect();
                self.snorm16_vec4_accessor(&q)
            } else {
                let d: Vec<f32> = r.iter().flat_map(|q| q.to_array()).collect();
                self.float_accessor(&d, "VEC4", 4, false)
            };
            attrs.insert("ROTATION".into(), a.into());
        }
        if let Some(s) = scale {
            let d: Vec<f32> = s.iter().flat_map(|v| v.to_array()).collect();
            attrs.insert(
                "SCALE".into(),
                self.float_accessor(&d, "VEC3", 3, false).into(),
            );
        }
        let mut v = json!({
            "mesh": mesh,
            "extensions": {"EXT_mesh_gpu_instancing": {"attributes": attrs}}
        });
        Self::place(&mut v, place);
        self.nodes.push(v);
        self.nodes.len() - 1
    }

    /// Rotation taking the node's -Z (where lights and cameras point) to `dir`, its +Y toward `up`.
    fn look_rotation(dir: Vec3, up: Vec3) -> Quat {
        let f = dir.normalize();
        let mut r = f.cross(up);
        if r.length_squared() < 1e-10 {
            r = f.cross(if f.y.abs() < 0.9 { Vec3::Y } else { Vec3::X });
        }
        let r = r.normalize();
        let u = r.cross(f);
        Quat::from_mat3(&Mat3::from_cols(r, u, -f)).normalize()
    }

    /// A KHR_lights_punctual directional light shining along `dir` (W/m^2 as the loader reads it).
    pub fn directional_light(&mut self, dir: Vec3, color: [f32; 3], intensity: f32) -> usize {
        self.use_extension("KHR_lights_punctual", false);
        self.lights
            .push(json!({"type": "directional", "color": color, "intensity": intensity}));
        let mut v =
            json!({"extensions": {"KHR_lights_punctual": {"light": self.lights.len() - 1}}});
        Self::place(
            &mut v,
            Place::Trs(Vec3::ZERO, Self::look_rotation(dir, Vec3::Y), Vec3::ONE),
        );
        self.nodes.push(v);
        self.nodes.len() - 1
    }

    pub fn point_light(&mut self, at: Vec3, color: [f32; 3], intensity: f32) -> usize {
        self.use_extension("KHR_lights_punctual", false);
        self.lights
            .push(json!({"type": "point", "color": color, "intensity": intensity}));
        let mut v =
            json!({"extensions": {"KHR_lights_punctual": {"light": self.lights.len() - 1}}});
        Self::place(&mut v, Place::at(at));
        self.nodes.push(v);
        self.nodes.len() - 1
    }

    /// A perspective camera at `pos` looking at `target`; `yfov` in degrees.
    pub fn camera(&mut self, pos: Vec3, target: Vec3, up: Vec3, yfov_deg: f32) -> usize {
        self.cameras.push(json!({
            "type": "perspective",
            "perspective": {"yfov": yfov_deg.to_radians(), "znear": 0.01, "aspectRatio": 1.0}
        }));
        let mut v = json!({"camera": self.cameras.len() - 1});
        Self::place(
            &mut v,
            Place::Trs(pos, Self::look_rotation(target - pos, up), Vec3::ONE),
        );
        self.nodes.push(v);
        self.nodes.len() - 1
    }

    /// The glTF JSON (the buffer and images referenced as files named after `name`).
    pub fn json(&self, name: &str) -> Value {
        let images: Vec<Value> = self
            .images
            .iter()
            .enumerate()
            .map(|(i, im)| match im {
                ImageData::Png(_) => json!({"uri": format!("{name}-{i}.png")}),
                ImageData::Missing(uri) => json!({"uri": uri}),
            })
            .collect();
        let mut root = json!({
            "asset": {"version": "2.0", "generator": "gilab tests/common/gltf_writer.rs"},
            "scene": 0,
            "scenes": [{"nodes": (0..self.nodes.len()).collect::<Vec<_>>()}],
            "nodes": self.nodes,
            "meshes": self.meshes,
            "accessors": self.accessors,
            "bufferViews": self.buffer_views,
            "buffers": [{"uri": format!("{name}.bin"), "byteLength": self.bin.len()}],
        });
        let mut put = |key: &str, v: &Vec<Value>| {
            if !v.is_empty() {
                root[key] = json!(v);
            }
        };
        put("materials", &self.materials);
        put("textures", &self.textures);
        put("samplers", &self.samplers);
        put("images", &images);
        put("cameras", &self.cameras);
        if !self.lights.is_empty() {
            root["extensions"] = json!({"KHR_lights_punctual": {"lights": self.lights}});
        }
        if !self.extensions_used.is_empty() {
            root["extensionsUsed"] = json!(self.extensions_used);
        }
        if !self.extensions_required.is_empty() {
            root["extensionsRequired"] = json!(self.extensions_required);
        }
        root
    }

    /// Writes `<dir>/<name>.gltf` (JSON as given by `edit` applied to [`Self::json`]), its
    /// buffer and PNG images; returns the .gltf path.
    pub fn write_with(&self, dir: &Path, name: &str, edit: impl FnOnce(&mut Value)) -> PathBuf {
        std::fs::create_dir_all(dir).unwrap();
        let mut root = self.json(name);
        edit(&mut root);
        std::fs::write(dir.join(format!("{name}.bin")), &self.bin).unwrap();
        for (i, im) in self.images.iter().enumerate() {
            if let ImageData::Png(png) = im {
                std::fs::write(dir.join(format!("{name}-{i}.png")), png).unwrap();
            }
        }
        let path = dir.join(format!("{name}.gltf"));
        std::fs::write(&path, serde_json::to_string_pretty(&root).unwrap()).unwrap();
        path
    }

    pub fn write(&self, dir: &Path, name: &str) -> PathBuf {
        self.write_with(dir, name, |_| {})
    }
}

/// A constant RGBA8 image.
pub fn solid_rgba8(w: u32, h: u32, c: [u8; 4]) -> Vec<u8> {
    (0..w * h).flat_map(|_| c).collect()
}
