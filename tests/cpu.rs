//! GPU-free tests: shaders validate with naga, CPU/GPU layouts agree, the BVH matches brute
//! force, presets parse and round-trip, glTF loading and its errors, metrics.

mod common;

use common::base64 as base64_decode;
use gilab::compare::{metrics, Image};
use gilab::gpu::shaders::{ShaderLibrary, ShaderVariant};
use gilab::preset::{LoadedPreset, Overrides};
use gilab::scene::{builtin, bvh, gltf_load};
use glam::Vec3;
use std::path::Path;

#[test]
fn every_wgsl_entry_file_validates() {
    // Both sources, each in every variant (scene-chosen shader defs).
    let mut libs = Vec::new();
    for alpha_test in [false, true] {
        for instances in [false, true] {
            let variant = ShaderVariant {
                alpha_test,
                instances,
            };
            libs.push(ShaderLibrary::discover().with_variant(variant));
            libs.push(ShaderLibrary::embedded().with_variant(variant));
        }
    }
    // NEE by the light tree (a def any pipeline may set: the reference's `light_sampling`).
    libs.push(ShaderLibrary::discover().with_defs(&[("LIGHT_TREE", 1)]));
    // Two libraries at a time (naga's composition and validation run on one core each).
    common::on_two_threads(&libs, |lib| {
        let entries = lib.entry_files().unwrap();
        assert!(entries.len() >= 3, "entry files: {entries:?}");
        for entry in entries {
            let module = lib
                .compose(&entry)
                .unwrap_or_else(|e| panic!("{e}\n{}", e.report));
            naga::valid::Validator::new(
                naga::valid::ValidationFlags::all(),
                naga::valid::Capabilities::default(),
            )
            .validate(&module)
            .unwrap_or_else(|e| panic!("shaders/{entry}: {e:?}"));
        }
    });
}

/// Each registered cache's end of a GI path (`GiCache::path_end`, an `override fn
/// gilab::path_end::end_path` added as an additional import) composes into ReSTIR GI's reading
/// pass, validates, and changes it: the override is applied (a plain `#import` would not), and
/// each cache's pass differs from the others'. Without a GPU: the GPU tests in
/// tests/connections.rs run them.
#[test]
fn every_cache_end_of_path_overrides_the_path_end() {
    use gilab::parts::gi_cache::{CacheSettings, CACHES};
    let settings = CacheSettings {
        atlas_size: 512,
        update: 0.25,
        ray_budget: 4096,
        light: gilab::parts::world_regir::WorldRegirSettings::from_params(
            &gilab::render::params::Params::new("restir", gilab::parts::restir::PARAMS),
        ),
    };
    let entry = "parts/restir/gi_temporal.wgsl";
    // Every cache's lookup at group 3, as ReSTIR GI's reader binds it (`CACHE_GROUP`; the
    // world cache's bindings sit beside the surface cache's there).
    let base = ShaderLibrary::discover().with_defs(&[
        ("GI_TERMINATE", 1),
        ("SURFACE_CACHE_GROUP", 3),
        ("WORLD_CACHE_GROUP", 3),
        ("SURFELS_GROUP", 3),
        ("HASH_CACHE_GROUP", 3),
        ("AMBIENT_CACHE_GROUP", 3),
    ]);
    let plain = format!("{:?}", base.compose(entry).unwrap());
    let mut seen = vec![plain];
    for kind in CACHES {
        let cache = (kind.new)(&settings).unwrap();
        let lib = base.with_imports(&[cache.path_end()]);
        let module = lib
            .compose(entry)
            .unwrap_or_else(|e| panic!("{}: {e}\n{}", kind.name, e.report));
        naga::valid::Validator::new(
            naga::valid::ValidationFlags::all(),
            naga::valid::Capabilities::default(),
        )
        .validate(&module)
        .unwrap_or_else(|e| panic!("{}: {e:?}", kind.name));
        let text = format!("{module:?}");
        assert!(
            !seen.contains(&text),
            "{}: its end module changed nothing (or equals another cache's)",
            kind.name
        );
        seen.push(text);
    }
}

#[test]
fn shader_errors_name_file_and_line() {
    let dir = std::env::temp_dir().join(format!("gilab-shader-err-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    common::copy_dir(Path::new("shaders"), &dir);
    let path = dir.join("common/math.wgsl");
    let text = std::fs::read_to_string(&path).unwrap();
    std::fs::write(
        &path,
        text.replace(
            "fn luminance(c: vec3<f32>) -> f32 {",
            "fn luminance(c: vec3<f32>) -> f32 {\n    let broken: u32 = 1.5;",
        ),
    )
    .unwrap();
    let lib = ShaderLibrary::at(dir.clone());
    let err = lib.compose("reference/path_trace.wgsl").unwrap_err();
    assert!(
        err.location.contains("common/math.wgsl:"),
        "location: {}",
        err.location
    );
    let line: usize = err.location.split(':').nth(1).unwrap().parse().unwrap();
    let expected = text
        .lines()
        .position(|l| l.starts_with("fn luminance"))
        .unwrap()
        + 2;
    assert_eq!(line, expected, "{err}");
    // Hot reload must know which entry files to rebuild.
    let deps = lib.dependents("common/math.wgsl").unwrap();
    assert!(
        deps.contains(&"reference/path_trace.wgsl".to_string())
            && deps.contains(&"bench/trace_rays.wgsl".to_string()),
        "{deps:?}"
    );
    assert!(!lib
        .dependents("reference/path_trace.wgsl")
        .unwrap()
        .contains(&"bench/trace_rays.wgsl".to_string()));
}

// Layouts shared by Rust and WGSL (issue 56, item 4): every `#[repr(C)]` struct that Rust
// uploads is compared with naga's layout of its WGSL twin in the composed entry files (size,
// each member's name and offset, the scalar kind of each 4-byte word), every byte-size
// constant with its WGSL struct, and every flag or code that Rust mirrors by hand with the WGSL
// constant of the same name. One test reports every mismatch at once.

/// A 4-byte scalar as the GPU reads it: "f32", "u32" or "i32" ("other" for anything else).
type Word = &'static str;

/// The scalars of a Rust type shared with WGSL, one per 4 bytes in memory order (a `Pod`
/// struct has no padding, so they tile it).
trait Words {
    fn words(out: &mut Vec<Word>);
}

impl Words for f32 {
    fn words(out: &mut Vec<Word>) {
        out.push("f32")
    }
}

impl Words for u32 {
    fn words(out: &mut Vec<Word>) {
        out.push("u32")
    }
}

impl Words for i32 {
    fn words(out: &mut Vec<Word>) {
        out.push("i32")
    }
}

impl<T: Words, const N: usize> Words for [T; N] {
    fn words(out: &mut Vec<Word>) {
        for _ in 0..N {
            T::words(out)
        }
    }
}

/// A field of a Rust `#[repr(C)]` struct: name, byte offset, bytes, scalar kinds.
struct RustField {
    name: &'static str,
    offset: usize,
    size: usize,
    words: Vec<Word>,
}

fn rust_field<S, F: Words>(name: &'static str, offset: usize, _: fn(&S) -> &F) -> RustField {
    let mut words = Vec::new();
    F::words(&mut words);
    RustField {
        name,
        offset,
        size: std::mem::size_of::<F>(),
        words,
    }
}

/// Where the WGSL twin of a Rust struct is.
enum Twin {
    /// The struct of that name (uniform or storage memory) in every composed entry file that
    /// has it.
    Memory(&'static str),
    /// A vertex-input struct: its members are the vertex attributes, which the pipelines pack
    /// in location order (`wgpu::vertex_attr_array!`), so offsets are the packed ones, not
    /// naga's memory layout, and the struct's memory size means nothing (the stride is the
    /// Rust size).
    VertexInput(&'static str),
    /// `InstanceRecord` lives in the BVH node buffer as two `BvhNode`s; WGSL has no struct of
    /// its memory but reads it in `instance_at` (common/bvh.wgsl) into `Instance`. Each
    /// `Instance` member is checked at the node member that `instance_at` reads it from.
    InstanceNodes,
}

/// A Rust struct shared with WGSL: its name, size and fields, and where its twin is.
struct Shared {
    rust: &'static str,
    size: usize,
    fields: Vec<RustField>,
    twin: Twin,
}

/// `Twin => path::Type { every field, in order }`. A field left out fails the test (the fields
/// must tile the struct), so the lists cannot fall behind the structs.
macro_rules! shared_structs {
    ($($twin:expr => $ty:ty { $($field:ident),* $(,)? })*) => {
        $(impl Words for $ty {
            fn words(out: &mut Vec<Word>) {
                $(out.extend(rust_field(stringify!($field), 0, |s: &$ty| &s.$field).words);)*
            }
        })*

        fn shared_structs() -> Vec<Shared> {
            vec![$(Shared {
                rust: last_segment(stringify!($ty)),
                size: std::mem::size_of::<$ty>(),
                fields: vec![$(rust_field(
                    stringify!($field),
                    std::mem::offset_of!($ty, $field),
                    |s: &$ty| &s.$field,
                )),*],
                twin: $twin,
            }),*]
        }
    };
}

fn last_segment(path: &'static str) -> &'static str {
    path.rsplit("::").next().unwrap().trim()
}

shared_structs! {
    Twin::Memory("TriGeom") => gilab::scene::gpu_scene::GpuTriGeom { v0, e1, e2 }
    Twin::Memory("TriAttr") => gilab::scene::gpu_scene::GpuTriAttr {
        normals, light_pmf, tangents, material, uv0_ab, uv0_c_uv1_a, uv1_bc, scene_tri, flags, pad,
    }
    Twin::Memory("TexSlot") => gilab::scene::gpu_scene::GpuTexSlot { transform_u, transform_v }
    Twin::Memory("Material") => gilab::scene::gpu_scene::GpuMaterial {
        base_color, emissive, params, extra, tex, shading,
    }
    Twin::Memory("TextureInfo") => gilab::scene::gpu_scene::GpuTexture {
        first, width, height, levels,
    }
    Twin::Memory("Light") => gilab::scene::gpu_scene::GpuLight {
        kind, tri, cdf, pmf, class_cdf, class_pmf, trail, position, intensity, direction, spot,
    }
    Twin::Memory("Light") => gilab::parts::light_tree::GpuLightTreeNode {
        leaf, index, phi, cos_theta_o, cos_theta_e, two_sided, pad, lo, hi, axis, pad_b,
    }
    Twin::VertexInput("VertexIn") => gilab::scene::gpu_scene::RasterVertex { position }
    Twin::Memory("BvhNode") => gilab::scene::bvh::BvhNode { min, skip, max, tris }
    Twin::InstanceNodes => gilab::scene::bvh::InstanceRecord {
        column_x, root, column_y, end, column_z, tri_offset, translation, distance_scale,
    }
    Twin::Memory("GSurface") => gilab::render::primary::PrimarySurface {
        pos, normal_alpha, geo_specular, base_metal, wo_dist, emission, motion, triangle,
        material, prev_pos,
    }
    Twin::Memory("FrameUniforms") => gilab::render::FrameUniforms {
        clip_from_world, prev_clip_from_world, camera_pos, camera_right, camera_up,
        camera_forward, sky, size, frame_index, seed, sample_offset, flags, pad,
    }
    Twin::Memory("DisplayParams") => gilab::compare::display::DisplayParams {
        size, mode, operator, exposure_scale, range_lo, range_hi, channel, samples, row_words,
        view, gt, pad,
    }
    Twin::Memory("MetricParams") => gilab::compare::display::MetricParams {
        pixels, partial_count, pad,
    }
    Twin::Memory("ProbeMaterial") => gilab::compare::brdf_probe::GpuProbeMaterial {
        base_metal, misc, shading,
    }
    Twin::Memory("Query") => gilab::compare::brdf_probe::GpuQuery { wo, wi }
    Twin::Memory("WorldCacheParams") => gilab::parts::world_cache::WorldCacheParamsGpu {
        levels, base, shape, update, misc,
    }
    Twin::Memory("WorldRegirParams") => gilab::parts::world_regir::WorldRegirParamsGpu {
        cell_size, levels, dims, slots, lookup_candidates, keep_frames, pad,
    }
    Twin::Memory("ReflectionParams") => gilab::parts::reflections::ReflectionParamsGpu {
        max_roughness, downsample, flags, reuse, reuse_radius, max_history, trace_width,
        trace_height, output_plane, pad,
    }
    Twin::Memory("SurfelParams") => gilab::parts::surfels::SurfelParamsGpu {
        max_surfels, ray_budget, ray_capacity, flags, coverage_target, surfel_size,
        grid_half_extent, tiles_x, tiles, cells, max_rays_per_surfel, spawn_tile,
    }
    Twin::Memory("RestirParams") => gilab::parts::restir::RestirParamsGpu {
        candidates, candidate_visibility, temporal, max_history, spatial_count, spatial_radius,
        unbiased, bidirectional, pixels, accumulate, gi, gi_bounces, regir, regir_cell_size,
        regir_dims, regir_slots, directional_candidates, sky_candidates, single_pool, gi_cosine,
        path_light_candidates, specular_bounces, specular_max_roughness, light_tree,
        bsdf_candidates, bsdf_max_roughness, regir_tree, pad_b,
    }
    Twin::Memory("Card") => gilab::parts::surface_cache::cards::GpuCard {
        box_min, box_max, rect, draw,
    }
    Twin::Memory("CacheParams") => gilab::parts::surface_cache::CacheParamsGpu {
        atlas_size, card_count, direct_tile_first, direct_tile_count, direct_tiles_total,
        probe_tile_first, probe_tile_count, probe_tiles_total,
    }
    Twin::Memory("ProbeParams") => gilab::techniques::lumen::screen_probes::ProbeParamsGpu {
        hzb_mips, grid, adaptive, jitter, counts, offsets, offsets_b, misc, flags,
    }
    Twin::Memory("Level") => gilab::parts::tracing::LevelGpu { origin, brick_origin, update }
    Twin::Memory("TracingParams") => gilab::parts::tracing::TracingParamsGpu {
        levels, resolution, levels_built, bricks_per_axis, pool_bricks, flags, rays_per_pixel,
        gather_downsample, gather_width, gather_height, dirty_box_count, sign_rays, query_count,
        slice_depth, query_mode, pad,
    }
    Twin::Memory("CallistoParams") => gilab::techniques::callisto_shadows::CallistoParamsGpu {
        tiles_x, tiles_y, max_lights, rate_mode, range_cutoff, cone_culling, half_threshold,
        full_threshold, perceptual, border_depth, denoise, max_history, blur_radius, accumulate,
        gi, pixels, tail_samples, direct_restir, reflections, reflection_max_roughness,
        shadow_cache, cache_samples, cache_cell, cache_slots, motion_base, records_at,
        dynamic_count, light_mask_base, dynamic_base, hash_base, pad,
    }
    Twin::Memory("HashCacheParams") => gilab::parts::hash_cache::HashCacheParamsGpu {
        capacity, stale_frames, max_samples, cell_size, cells_per_distance, block, pad,
    }
    Twin::Memory("ShadeSettings") => gilab::techniques::hash_cache::ShadeSettingsGpu {
        accumulate, use_cache, debug, pad,
    }
    Twin::Memory("DdgiParams") => gilab::techniques::ddgi::volume::DdgiParamsGpu {
        cascades, counts, rot_x, rot_y, rot_z, rays, flags, hysteresis, bias, max_distance,
        min_frontface, pad,
    }
    Twin::Memory("Cascade") => gilab::techniques::ddgi::volume::CascadeGpu { origin_spacing, base }
    Twin::Memory("PtParams") => gilab::techniques::restir_pt::PtParamsGpu {
        max_bounces, temporal, max_history, spatial_count, spatial_radius, rc_alpha, rc_distance,
        pixels, accumulate, direct_restir, debug, pairs,
    }
}

/// (Rust struct, WGSL member, Rust field) where the names differ (naming is left as it is in
/// the code). Several members that name one Rust array take its elements in order.
const RENAMES: &[(&str, &str, &str)] = &[
    ("GpuTriGeom", "vertex_a", "v0"),
    ("GpuTriGeom", "edge_b", "e1"),
    ("GpuTriGeom", "edge_c", "e2"),
    // A light tree node takes a light's record in the light pool (gilab::light_tree::tree_node).
    ("GpuLightTreeNode", "kind", "leaf"),
    ("GpuLightTreeNode", "tri", "index"),
    ("GpuLightTreeNode", "cdf", "phi"),
    ("GpuLightTreeNode", "pmf", "cos_theta_o"),
    ("GpuLightTreeNode", "class_cdf", "cos_theta_e"),
    ("GpuLightTreeNode", "class_pmf", "two_sided"),
    ("GpuLightTreeNode", "trail", "pad"),
    ("GpuLightTreeNode", "position", "lo"),
    ("GpuLightTreeNode", "intensity", "hi"),
    ("GpuLightTreeNode", "direction", "axis"),
    ("GpuLightTreeNode", "spot", "pad_b"),
    ("BvhNode", "bounds_min", "min"),
    ("BvhNode", "bounds_max", "max"),
    ("InstanceRecord", "to_object_x", "column_x"),
    ("InstanceRecord", "to_object_y", "column_y"),
    ("InstanceRecord", "to_object_z", "column_z"),
    // `operator` is reserved in WGSL.
    ("DisplayParams", "tone_operator", "operator"),
    ("DisplayParams", "gt_p", "gt"),
    ("DisplayParams", "gt_a", "gt"),
    ("DisplayParams", "gt_m", "gt"),
    ("DisplayParams", "gt_l", "gt"),
    ("DisplayParams", "gt_c", "gt"),
    ("DisplayParams", "gt_b", "gt"),
    ("DisplayParams", "pad0", "pad"),
    ("DisplayParams", "pad1", "pad"),
    ("DisplayParams", "pad2", "pad"),
    ("MetricParams", "pad0", "pad"),
    ("MetricParams", "pad1", "pad"),
    ("HashCacheParamsGpu", "pad_a", "pad"),
    ("HashCacheParamsGpu", "pad_b", "pad"),
    ("DdgiParamsGpu", "pad_a", "pad"),
    ("DdgiParamsGpu", "pad_b", "pad"),
    ("WorldRegirParamsGpu", "pad_a", "pad"),
    ("WorldRegirParamsGpu", "pad_b", "pad"),
    ("TracingParamsGpu", "pad_a", "pad"),
    ("TracingParamsGpu", "pad_b", "pad"),
    ("CallistoParamsGpu", "pad_a", "pad"),
    ("CallistoParamsGpu", "pad_b", "pad"),
    ("ReflectionParamsGpu", "pad_a", "pad"),
    ("ReflectionParamsGpu", "pad_b", "pad"),
    ("ReflectionParamsGpu", "pad_c", "pad"),
];

/// `#[repr(C)]` structs of src/ with no WGSL twin, each with the reason.
const NOT_SHARED: &[(&str, &str)] = &[];

/// Differences this test found that are not fixed yet, as (Rust struct, the end of its error
/// line). Each must still occur: the fix removes its line here.
const KNOWN_MISMATCHES: &[(&str, &str)] = &[];

/// A WGSL struct member as the check sees it: name, byte offset, bytes, and the scalar of
/// each word as (byte offset in the member, kind) (`None`: read through a bitcast, any kind).
#[derive(Debug, PartialEq)]
struct WgslMember {
    name: String,
    offset: u32,
    size: u32,
    words: Option<Vec<(u32, Word)>>,
}

/// The WGSL side of a comparison: where it comes from, its size (`None`: not checked), its
/// members.
struct WgslLayout {
    at: String,
    size: Option<u32>,
    members: Vec<WgslMember>,
}

/// A composed entry file with naga's layout of its types.
struct Composed {
    entry: String,
    module: naga::Module,
    layouter: naga::proc::Layouter,
}

/// A struct of a composed module by its WGSL name (naga_oil suffixes imported names).
fn find_struct(module: &naga::Module, name: &str) -> Option<naga::Handle<naga::Type>> {
    module.types.iter().find_map(|(h, t)| {
        let base = t.name.as_deref()?.split("X_naga_oil_mod_").next()?;
        (base == name && matches!(t.inner, naga::TypeInner::Struct { .. })).then_some(h)
    })
}

fn struct_members(module: &naga::Module, ty: naga::Handle<naga::Type>) -> &[naga::StructMember] {
    match &module.types[ty].inner {
        naga::TypeInner::Struct { members, .. } => members,
        _ => unreachable!(),
    }
}

/// The scalars of a WGSL type at `base`, as (byte offset, kind), padding left out.
fn wgsl_words(module: &naga::Module, ty: naga::Handle<naga::Type>, base: u32) -> Vec<(u32, Word)> {
    use naga::{ScalarKind as K, TypeInner as T};
    let word = |s: &naga::Scalar| match (s.kind, s.width) {
        (K::Float, 4) => "f32",
        (K::Uint, 4) => "u32",
        (K::Sint, 4) => "i32",
        _ => "other",
    };
    match &module.types[ty].inner {
        T::Scalar(s) | T::Atomic(s) => vec![(base, word(s))],
        T::Vector { size, scalar } => (0..*size as u32)
            .map(|i| (base + 4 * i, word(scalar)))
            .collect(),
        T::Matrix {
            columns,
            rows,
            scalar,
        } => {
            let stride = if *rows == naga::VectorSize::Bi { 8 } else { 16 };
            (0..*columns as u32)
                .flat_map(|c| {
                    (0..*rows as u32).map(move |r| (base + c * stride + 4 * r, word(scalar)))
                })
                .collect()
        }
        T::Array {
            base: element,
            size: naga::ArraySize::Constant(n),
            stride,
        } => (0..n.get())
            .flat_map(|i| wgsl_words(module, *element, base + i * stride))
            .collect(),
        T::Struct { members, .. } => members
            .iter()
            .flat_map(|m| wgsl_words(module, m.ty, base + m.offset))
            .collect(),
        _ => vec![(base, "other")],
    }
}

fn wgsl_member(c: &Composed, m: &naga::StructMember) -> WgslMember {
    WgslMember {
        name: m.name.clone().unwrap_or_default(),
        offset: m.offset,
        size: c.layouter[m.ty].size,
        words: Some(wgsl_words(&c.module, m.ty, 0)),
    }
}

/// Every distinct layout of the WGSL twin in the composed entry files (one unless entry files
/// disagree), or why there is none.
fn wgsl_layouts(
    twin: &Twin,
    composed: &[Composed],
    files: &std::collections::BTreeMap<String, String>,
) -> Result<Vec<WgslLayout>, String> {
    let mut layouts: Vec<WgslLayout> = Vec::new();
    let name = match twin {
        Twin::Memory(name) | Twin::VertexInput(name) => name,
        Twin::InstanceNodes => return instance_nodes_layout(composed, files).map(|l| vec![l]),
    };
    for c in composed {
        let Some(ty) = find_struct(&c.module, name) else {
            continue;
        };
        let mut members: Vec<WgslMember> = struct_members(&c.module, ty)
            .iter()
            .map(|m| wgsl_member(c, m))
            .collect();
        let mut size = Some(c.layouter[ty].size);
        if let Twin::VertexInput(_) = twin {
            let mut packed = 0;
            for (i, (m, naga_m)) in members
                .iter_mut()
                .zip(struct_members(&c.module, ty))
                .enumerate()
            {
                if !matches!(naga_m.binding, Some(naga::Binding::Location { location, .. }) if location as usize == i)
                {
                    return Err(format!(
                        "{name} ({}): member {} is not at @location({i}), the packing order",
                        c.entry, m.name
                    ));
                }
                m.offset = packed;
                packed += m.size;
            }
            size = Some(packed);
        }
        if !layouts
            .iter()
            .any(|l| l.size == size && l.members == members)
        {
            layouts.push(WgslLayout {
                at: format!("{name} in {}", c.entry),
                size,
                members,
            });
        }
    }
    if layouts.is_empty() {
        return Err(format!("no composed entry file has a WGSL struct {name}"));
    }
    Ok(layouts)
}

/// `InstanceRecord` as `instance_at` reads it: each `Instance` member at the `BvhNode` member
/// its constructor takes (`let a = bvh_node(at); let b = bvh_node(at + 1u); return
/// Instance(a.bounds_min, ..., bitcast<f32>(b.tris));`), parsed from the source. `bvh_node`
/// reads the node's texel copy, which `gpu::scene_texels_hold_the_storage_buffers_words` holds
/// to `bvh_nodes[i]` word for word; the buffer's own index form is read too.
fn instance_nodes_layout(
    composed: &[Composed],
    files: &std::collections::BTreeMap<String, String>,
) -> Result<WgslLayout, String> {
    let (c, instance, node) = composed
        .iter()
        .find_map(|c| {
            Some((
                c,
                find_struct(&c.module, "Instance")?,
                find_struct(&c.module, "BvhNode")?,
            ))
        })
        .ok_or("no composed entry file has WGSL structs Instance and BvhNode")?;
    let (path, text) = files
        .iter()
        .find(|(_, t)| t.contains("fn instance_at("))
        .ok_or("no WGSL file has fn instance_at")?;
    let body = &text[text.find("fn instance_at(").unwrap()..];
    let body = &body[..body.find("\n}").unwrap_or(body.len())];
    let mut nodes = std::collections::HashMap::new();
    for line in body.lines() {
        let Some((var, index)) = line.trim().strip_prefix("let ").and_then(|l| {
            l.split_once(" = bvh_nodes[at")
                .or_else(|| l.split_once(" = bvh_node(at"))
        }) else {
            continue;
        };
        let k = index
            .trim_start_matches(" + ")
            .trim_end_matches("];")
            .trim_end_matches(");")
            .trim_end_matches('u');
        let k: u32 = if k.is_empty() {
            0
        } else {
            k.parse()
                .map_err(|_| format!("{path}: node index in `{line}`"))?
        };
        nodes.insert(var, k);
    }
    let args = body
        .split_once("return Instance(")
        .ok_or(format!("{path}: no `return Instance(` in instance_at"))?
        .1;
    let (mut depth, mut start, mut parsed) = (0, 0, Vec::new());
    for (i, ch) in args.char_indices() {
        match ch {
            '(' => depth += 1,
            ')' if depth == 0 => {
                parsed.push(args[start..i].trim());
                break;
            }
            ')' => depth -= 1,
            ',' if depth == 0 => {
                parsed.push(args[start..i].trim());
                start = i + 1;
            }
            _ => {}
        }
    }
    let instance_members = struct_members(&c.module, instance);
    if parsed.len() != instance_members.len() {
        return Err(format!(
            "{path}: instance_at passes {} values to Instance's {} members",
            parsed.len(),
            instance_members.len()
        ));
    }
    let node_size = c.layouter[node].size;
    let mut members = Vec::new();
    let mut end = 0;
    for (arg, im) in parsed.iter().zip(instance_members) {
        let bitcast = arg.starts_with("bitcast<");
        let read = if bitcast {
            arg.split_once('(')
                .and_then(|(_, r)| r.strip_suffix(')'))
                .unwrap_or(arg)
        } else {
            arg
        };
        let (var, field) = read.split_once('.').ok_or(format!(
            "{path}: instance_at reads `{arg}`, not a node member"
        ))?;
        let k = nodes
            .get(var)
            .ok_or(format!("{path}: `{var}` is not a node in instance_at"))?;
        let nm = struct_members(&c.module, node)
            .iter()
            .find(|m| m.name.as_deref() == Some(field))
            .ok_or(format!("{path}: BvhNode has no member {field}"))?;
        let mut m = wgsl_member(c, nm);
        m.name = im.name.clone().unwrap_or_default();
        m.offset += k * node_size;
        if bitcast {
            m.words = None;
        }
        end = end.max((k + 1) * node_size);
        members.push(m);
    }
    members.sort_by_key(|m| m.offset);
    Ok(WgslLayout {
        at: format!(
            "Instance read by instance_at ({path}) from two BvhNodes of {}",
            c.entry
        ),
        size: Some(end),
        members,
    })
}

/// Compares one Rust struct with one WGSL layout; every difference goes to `errors`.
fn compare_layout(s: &Shared, w: &WgslLayout, used: &mut [bool], errors: &mut Vec<String>) {
    let mut err = |e: String| errors.push(format!("{} / {}: {e}", s.rust, w.at));
    // The field list tiles the Rust struct: a field missing from the table shows as a gap.
    let mut end = 0;
    for f in &s.fields {
        if f.offset != end {
            err(format!(
                "Rust field {} at byte {}, not {end}: a field is missing from the table",
                f.name, f.offset
            ));
        }
        end = f.offset + f.size;
    }
    if end != s.size {
        err(format!(
            "Rust fields end at byte {end} of {}: a field is missing from the table",
            s.size
        ));
    }
    if let Some(size) = w.size {
        if size as usize != s.size {
            err(format!("size: WGSL {size} bytes, Rust {}", s.size));
        }
    }
    // Bytes of each Rust field named so far by WGSL members.
    let mut covered = vec![0usize; s.fields.len()];
    for m in &w.members {
        let rename = RENAMES
            .iter()
            .position(|&(rust, wgsl, _)| rust == s.rust && wgsl == m.name);
        if let Some(r) = rename {
            used[r] = true;
        }
        let field = rename.map_or(m.name.as_str(), |r| RENAMES[r].2);
        let Some(i) = s.fields.iter().position(|f| f.name == field) else {
            err(format!(
                "WGSL member {} (byte {}) has no Rust field",
                m.name, m.offset
            ));
            continue;
        };
        let f = &s.fields[i];
        let rust_offset = f.offset + covered[i];
        if m.offset as usize != rust_offset {
            err(format!(
                "{}: WGSL byte {}, Rust byte {rust_offset} ({}{})",
                m.name,
                m.offset,
                f.name,
                if covered[i] > 0 {
                    format!(" + {}", covered[i])
                } else {
                    String::new()
                }
            ));
        }
        if covered[i] + m.size as usize > f.size {
            err(format!(
                "{}: {} bytes in WGSL, past the end of Rust {} ({} bytes)",
                m.name, m.size, f.name, f.size
            ));
        } else if let Some(words) = &m.words {
            if let Some((o, kind)) = words
                .iter()
                .find(|&&(o, kind)| f.words[(covered[i] + o as usize) / 4] != kind)
            {
                err(format!(
                    "{} byte {o}: WGSL {kind}, Rust {}",
                    m.name,
                    f.words[(covered[i] + *o as usize) / 4]
                ));
            }
        }
        covered[i] += m.size as usize;
    }
    for (f, &c) in s.fields.iter().zip(&covered) {
        if c != f.size {
            err(format!(
                "Rust field {} ({} bytes): WGSL members cover {c}",
                f.name, f.size
            ));
        }
    }
}

/// The value of `const NAME: u32 = 2u;` / `const NAME = 0xffu;` in WGSL source, if declared.
fn wgsl_const(text: &str, name: &str) -> Option<Result<u64, String>> {
    text.lines().find_map(|line| {
        let rest = line.trim().strip_prefix("const ")?.strip_prefix(name)?;
        if !rest.starts_with([':', ' ', '=']) {
            return None;
        }
        let value = rest.split_once('=')?.1.split(';').next()?.trim();
        let digits = value.trim_end_matches(['u', 'i']);
        let parsed = match digits.strip_prefix("0x") {
            Some(hex) => u64::from_str_radix(hex, 16),
            None => digits.parse(),
        };
        Some(parsed.map_err(|_| format!("`{value}` is not an integer literal")))
    })
}

/// (WGSL module's import path, Rust name, Rust value) of a constant Rust mirrors by hand.
macro_rules! mirrored {
    ($module:literal, $($path:ident)::+) => {
        ($module, last_segment(stringify!($($path)::+)), $($path)::+ as u64)
    };
}

/// Bit flags by name: `FLAG_*` (a struct's `flags` word) and Lumen's `PROBES_*`.
fn is_flag(name: &str) -> bool {
    name.starts_with("FLAG_") || name.starts_with("PROBES_")
}

/// Rust `FLAG_*` / `PROBES_*` constants with no WGSL twin, each with the reason.
const RUST_ONLY_FLAGS: &[(&str, &str)] = &[];

/// The flags (`is_flag`) declared as constants in src/ and its `#[repr(C)]` structs, by name,
/// from the source text.
fn rust_declarations(dir: &Path, consts: &mut Vec<String>, repr_c: &mut Vec<String>) {
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let path = e.path();
        if path.is_dir() {
            rust_declarations(&path, consts, repr_c);
        } else if path.extension().is_some_and(|x| x == "rs") {
            let text = std::fs::read_to_string(&path).unwrap();
            let mut after_repr = false;
            for line in text.lines().map(str::trim) {
                let decl = line.strip_prefix("pub ").unwrap_or(line);
                if let Some(name) = decl.strip_prefix("const ") {
                    let name = name.split([':', ' ']).next().unwrap();
                    if is_flag(name) {
                        consts.push(name.to_string());
                    }
                }
                if line == "#[repr(C)]" {
                    after_repr = true;
                } else if after_repr && !line.starts_with("#[") {
                    if let Some(name) = decl.strip_prefix("struct ") {
                        repr_c.push(name.split([' ', '{', '<']).next().unwrap().to_string());
                    }
                    after_repr = false;
                }
            }
        }
    }
}

#[test]
fn every_gpu_struct_matches_its_wgsl_layout() {
    let started = std::time::Instant::now();
    // One variant: no struct depends on shader defs; INSTANCES brings in `instance_at`.
    let lib = ShaderLibrary::discover().with_variant(ShaderVariant {
        alpha_test: false,
        instances: true,
    });
    let files = lib.files().unwrap();
    let composed: Vec<Composed> = lib
        .entry_files()
        .unwrap()
        .into_iter()
        .map(|entry| {
            let module = lib
                .compose(&entry)
                .unwrap_or_else(|e| panic!("{e}\n{}", e.report));
            let mut layouter = naga::proc::Layouter::default();
            layouter.update(module.to_ctx()).unwrap();
            Composed {
                entry,
                module,
                layouter,
            }
        })
        .collect();
    let mut errors = Vec::new();

    // Structs.
    let shared = shared_structs();
    let mut used = vec![false; RENAMES.len()];
    let mut layouts = 0;
    for s in &shared {
        match wgsl_layouts(&s.twin, &composed, &files) {
            Ok(ws) => {
                for w in &ws {
                    compare_layout(s, w, &mut used, &mut errors);
                }
                layouts += ws.len();
            }
            Err(e) => errors.push(format!("{}: {e}", s.rust)),
        }
    }
    for (_, (rust, wgsl, field)) in used.iter().zip(RENAMES).filter(|(u, _)| !**u) {
        errors.push(format!(
            "{rust}: rename {wgsl} -> {field} names no WGSL member: remove it"
        ));
    }

    // Byte sizes Rust keeps for WGSL structs it has no struct of.
    let sizes = [
        (
            "GSurface",
            "SURFACE_BYTES",
            gilab::render::primary::SURFACE_BYTES,
        ),
        (
            "Reservoir",
            "RESERVOIR_BYTES",
            gilab::parts::restir::RESERVOIR_BYTES,
        ),
        (
            "RegirSlot",
            "REGIR_SLOT_BYTES",
            gilab::parts::restir::REGIR_SLOT_BYTES,
        ),
        (
            "GiReservoir",
            "GI_RESERVOIR_BYTES",
            gilab::parts::restir::GI_RESERVOIR_BYTES,
        ),
        (
            "Surfel",
            "SURFEL_BYTES",
            gilab::parts::surfels::SURFEL_BYTES,
        ),
        (
            "SurfelState",
            "STATE_BYTES",
            gilab::parts::surfels::STATE_BYTES,
        ),
        ("Pool", "POOL_BYTES", gilab::parts::surfels::POOL_BYTES),
        (
            "PathReservoir",
            "PATH_RESERVOIR_BYTES",
            gilab::techniques::restir_pt::PATH_RESERVOIR_BYTES,
        ),
        ("Remod", "REMOD_BYTES", gilab::render::denoise::REMOD_BYTES),
    ];
    for (wgsl, rust, bytes) in sizes {
        let found: std::collections::BTreeSet<u32> = composed
            .iter()
            .filter_map(|c| find_struct(&c.module, wgsl).map(|h| c.layouter[h].size))
            .collect();
        if found.iter().copied().collect::<Vec<_>>() != [bytes as u32] {
            errors.push(format!(
                "{rust} = {bytes}: WGSL struct {wgsl} has size(s) {found:?}"
            ));
        }
    }

    // Flags and codes mirrored by hand, against the WGSL module that declares them.
    use gilab::parts::reflections as refl;
    use gilab::parts::surfels::params as surfels;
    use gilab::parts::tracing;
    use gilab::scene::gpu_scene as scene;
    use gilab::techniques::lumen::{params as lumen, screen_probes as probes};
    let consts = [
        mirrored!("gilab::frame", gilab::render::FLAG_NO_PRIMARY_EMISSION),
        mirrored!("gilab::sky", gilab::render::FLAG_NO_SKY_NEE),
        mirrored!("gilab::sky", gilab::scene::environment::FLAG_NO_SKY_NEE),
        mirrored!("gilab::reflections", refl::FLAG_HIT_LIGHTING),
        mirrored!("gilab::reflections", refl::FLAG_TEMPORAL),
        mirrored!("gilab::reflections", refl::FLAG_FILTER),
        mirrored!("gilab::reflections", refl::FLAG_DEBUG),
        mirrored!("gilab::reflections", refl::FLAG_SCREEN_REUSE),
        mirrored!("gilab::surfels", surfels::FLAG_GUIDING),
        mirrored!("gilab::surfels", surfels::FLAG_RADIAL_DEPTH),
        mirrored!("gilab::surfels", surfels::FLAG_MSME),
        mirrored!("gilab::surfels", surfels::FLAG_SKY),
        mirrored!("gilab::surfels", surfels::FLAG_ACCUMULATE),
        mirrored!("gilab::surfels", surfels::FLAG_REFLECTIONS),
        mirrored!("gilab::surfels", surfels::FLAG_CACHE_ONLY),
        mirrored!("gilab::surfels", surfels::FLAG_SHARING),
        mirrored!("gilab::surfels", surfels::FLAG_QUARTER_APPLY),
        mirrored!("gilab::surfels", surfels::FLAG_BINNING),
        mirrored!("gilab::surfels", surfels::FLAG_HARD_DEPTH),
        mirrored!("gilab::tracing", tracing::FLAG_BVH),
        mirrored!("gilab::tracing", tracing::FLAG_SKY),
        mirrored!("gilab::tracing", tracing::FLAG_LIGHTS),
        mirrored!("gilab::tracing", tracing::FLAG_VOXEL_LIGHTING),
        mirrored!("gilab::lumen", lumen::FLAG_ACCUMULATE),
        mirrored!("gilab::lumen", lumen::FLAG_DEBUG),
        mirrored!("gilab::lumen", lumen::FLAG_DIRECT_RESTIR),
        mirrored!("gilab::lumen", lumen::FLAG_REFLECTIONS),
        mirrored!(
            "gilab::ddgi",
            gilab::techniques::ddgi::volume::FLAG_VISIBILITY
        ),
        mirrored!(
            "gilab::ddgi",
            gilab::techniques::ddgi::volume::FLAG_RELOCATION
        ),
        mirrored!(
            "gilab::ddgi",
            gilab::techniques::ddgi::volume::FLAG_CLASSIFICATION
        ),
        mirrored!(
            "gilab::ddgi",
            gilab::techniques::ddgi::volume::FLAG_MULTI_BOUNCE
        ),
        mirrored!(
            "gilab::ddgi",
            gilab::techniques::ddgi::volume::FLAG_ACCUMULATE
        ),
        mirrored!("gilab::ddgi", gilab::techniques::ddgi::volume::FLAG_DEBUG),
        mirrored!(
            "gilab::ddgi",
            gilab::techniques::ddgi::volume::FLAG_DIRECT_RESTIR
        ),
        mirrored!(
            "gilab::ddgi",
            gilab::techniques::ddgi::volume::FLAG_DEBUG_CORNERS
        ),
        mirrored!("gilab::ddgi", gilab::techniques::ddgi::volume::FIXED_RAYS),
        mirrored!("gilab::lumen_probes", probes::PROBES_PRODUCT),
        mirrored!("gilab::lumen_probes", probes::PROBES_SCREEN_TRACES),
        mirrored!("gilab::lumen_probes", probes::PROBES_WORLD_CACHE),
        mirrored!("gilab::lumen_probes", probes::PROBES_ADAPTIVE),
        mirrored!("gilab::lumen_probes", probes::PROBES_SPATIAL),
        mirrored!("gilab::lumen_probes", probes::PROBES_TEMPORAL),
        mirrored!("gilab::lumen_probes", probes::PROBES_CONTACT_AO),
        mirrored!("gilab::lumen_probes", probes::PROBES_ACTIVE),
        mirrored!("gilab::lumen_probes", probes::PROBES_REASSIGN),
        // The scene's encodings: triangle flags, texture slots, light kinds, sentinels.
        mirrored!("gilab::scene", scene::TRI_HAS_NORMALS),
        mirrored!("gilab::scene", scene::TRI_HAS_TANGENTS),
        mirrored!("gilab::scene", scene::TRI_BITANGENT_NEG_SHIFT),
        mirrored!("gilab::scene", scene::NO_TEXTURE),
        mirrored!("gilab::scene", scene::SLOT_BASE_COLOR),
        mirrored!("gilab::scene", scene::SLOT_METALLIC_ROUGHNESS),
        mirrored!("gilab::scene", scene::SLOT_NORMAL),
        mirrored!("gilab::scene", scene::SLOT_EMISSIVE),
        mirrored!("gilab::scene", scene::SLOT_OCCLUSION),
        mirrored!("gilab::scene", scene::LIGHT_TRIANGLE),
        mirrored!("gilab::scene", scene::LIGHT_POINT),
        mirrored!("gilab::scene", scene::LIGHT_SPOT),
        mirrored!("gilab::scene", scene::LIGHT_DIRECTIONAL),
        mirrored!("gilab::primary", gilab::render::primary::NO_SURFACE),
        mirrored!("gilab::bvh", gilab::scene::bvh::INSTANCE_LEAF),
    ];
    for (module, name, value) in consts {
        let import = format!("#define_import_path {module}");
        let sources: Vec<_> = files
            .iter()
            .filter(|(_, t)| t.lines().any(|l| l.trim() == import))
            .collect();
        let [(path, text)] = sources[..] else {
            errors.push(format!(
                "{name}: {} WGSL files declare module {module}",
                sources.len()
            ));
            continue;
        };
        match wgsl_const(text, name) {
            None => errors.push(format!(
                "{name} = {value}: not declared in {path} ({module})"
            )),
            Some(Err(e)) => errors.push(format!("{name} in {path}: {e}")),
            Some(Ok(wgsl)) if wgsl != value => {
                errors.push(format!("{name}: Rust {value}, WGSL {wgsl} ({path})"))
            }
            Some(Ok(_)) => {}
        }
    }

    // Flags that share one word are distinct bits (the modules whose flags fill one word).
    for word in [
        &["gilab::frame", "gilab::sky"][..], // FrameUniforms.flags
        &["gilab::tracing", "gilab::lumen"], // TracingParams.flags
        &["gilab::surfels"],
        &["gilab::reflections"],
        &["gilab::lumen_probes"], // ProbeParams.flags.x
    ] {
        let bits: std::collections::BTreeMap<&str, u64> = consts
            .iter()
            .filter(|c| word.contains(&c.0) && is_flag(c.1))
            .map(|c| (c.1, c.2))
            .collect();
        let mut seen = 0;
        for (name, bit) in bits {
            if !bit.is_power_of_two() || seen & bit != 0 {
                errors.push(format!(
                    "{name} = {bit} is not a bit of its own in {word:?}'s word"
                ));
            }
            seen |= bit;
        }
    }

    // Every flag and every #[repr(C)] struct of src/ is in a table above.
    let (mut declared_flags, mut declared_structs) = (Vec::new(), Vec::new());
    rust_declarations(Path::new("src"), &mut declared_flags, &mut declared_structs);
    let listed_flags: Vec<String> = consts
        .iter()
        .map(|c| c.1)
        .chain(RUST_ONLY_FLAGS.iter().map(|f| f.0))
        .filter(|n| is_flag(n))
        .map(String::from)
        .collect();
    let listed_structs: Vec<String> = shared
        .iter()
        .map(|s| s.rust)
        .chain(NOT_SHARED.iter().map(|s| s.0))
        .map(String::from)
        .collect();
    for (what, declared, listed) in [
        ("flag constants", declared_flags, listed_flags),
        ("#[repr(C)] structs", declared_structs, listed_structs),
    ] {
        // Multisets: a name declared twice (FLAG_SKY, FLAG_DEBUG, ...) is listed twice.
        let less = |a: &[String], b: &[String]| {
            let mut rest = b.to_vec();
            a.iter()
                .filter(|n| match rest.iter().position(|r| r == *n) {
                    Some(k) => {
                        rest.swap_remove(k);
                        false
                    }
                    None => true,
                })
                .cloned()
                .collect::<Vec<_>>()
        };
        let (unlisted, undeclared) = (less(&declared, &listed), less(&listed, &declared));
        if !unlisted.is_empty() || !undeclared.is_empty() {
            errors.push(format!(
                "{what}: in src/ but not in this test {unlisted:?}, in this test but not in src/ {undeclared:?}"
            ));
        }
    }

    eprintln!(
        "{} structs against {layouts} WGSL layouts, {} sizes, {} constants, from {} entry files, in {:.2?}",
        shared.len(),
        sizes.len(),
        consts.len(),
        composed.len(),
        started.elapsed()
    );
    for &(rust, tail) in KNOWN_MISMATCHES {
        let before = errors.len();
        errors.retain(|e| !(e.starts_with(&format!("{rust} /")) && e.ends_with(tail)));
        if errors.len() == before {
            errors.push(format!(
                "known mismatch ({rust}: {tail}) no longer occurs: remove it from KNOWN_MISMATCHES"
            ));
        }
    }
    assert!(
        errors.is_empty(),
        "{} layout mismatches between Rust and WGSL:\n{}",
        errors.len(),
        errors.join("\n")
    );
}

fn random_rays(n: usize, lo: Vec3, hi: Vec3, seed: u64) -> Vec<(Vec3, Vec3)> {
    let mut s = seed;
    let mut next = move || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((s >> 40) as f32) / (1u64 << 24) as f32
    };
    (0..n)
        .map(|_| {
            let o = lo + (hi - lo) * Vec3::new(next(), next(), next());
            let d = Vec3::new(next() - 0.5, next() - 0.5, next() - 0.5).normalize_or(Vec3::X);
            (o, d)
        })
        .collect()
}

#[test]
fn bvh_matches_brute_force_on_random_rays() {
    for name in [
        "cornell",
        "glossy",
        "many-lights",
        "hard-cases",
        "courtyard",
    ] {
        let scene = builtin::build(name, &toml::Table::new()).unwrap();
        let tris: Vec<[Vec3; 3]> = scene
            .triangles
            .iter()
            .map(|t| t.map(|i| scene.positions[i as usize]))
            .collect();
        let bvh = bvh::Bvh::build(&tris);
        // Every triangle is in exactly one leaf.
        let mut seen = vec![0; tris.len()];
        for n in &bvh.nodes {
            for k in n.first_tri()..n.first_tri() + n.tri_count() {
                seen[bvh.order[k as usize] as usize] += 1;
            }
            assert!(n.tri_count() as usize <= bvh::MAX_LEAF);
        }
        assert!(
            seen.iter().all(|&c| c == 1),
            "{name}: triangles missing or duplicated in leaves"
        );
        let (lo, hi) = scene.bounds();
        for (o, d) in random_rays(3000, lo, hi, 7) {
            let a = bvh.closest_hit(&tris, o, d, f32::MAX);
            let b = bvh::brute_force_closest(&tris, o, d);
            match (a, b) {
                (None, None) => {}
                (Some(a), Some(b)) => assert!(
                    (a.0 - b.0).abs() <= 1e-5 * b.0.max(1.0),
                    "{name}: t {a:?} vs {b:?}"
                ),
                _ => panic!("{name}: BVH {a:?} vs brute force {b:?}"),
            }
        }
    }
}

#[test]
fn every_shipped_preset_parses_and_round_trips() {
    let mut count = 0;
    for e in std::fs::read_dir("presets").unwrap().flatten() {
        let p = e.path();
        if p.extension().is_some_and(|x| x == "toml") {
            let loaded = LoadedPreset::load(&p).unwrap();
            let text = loaded.to_toml().unwrap();
            let again = LoadedPreset::from_text(&text, Some(&p)).unwrap();
            assert_eq!(loaded.preset, again.preset, "{}", p.display());
            loaded.load_scene().unwrap();
            count += 1;
        }
    }
    assert!(count >= 5, "presets found: {count}");
}

#[test]
fn preset_typo_reports_line_and_column() {
    let text = "[scene]\nsource = \"cornell\"\n\n[render]\nsize = [64, 64]\nsed = 3\n";
    let err = LoadedPreset::from_text(text, Some(Path::new("presets/typo.toml")))
        .unwrap_err()
        .to_string();
    assert!(err.starts_with("presets/typo.toml:6:1:"), "{err}");
    assert!(err.contains("sed") && !err.contains('\n'), "{err}");
    let err = LoadedPreset::from_text("[scene\nsource = 1", Some(Path::new("p.toml")))
        .unwrap_err()
        .to_string();
    assert!(err.starts_with("p.toml:1:"), "{err}");
}

#[test]
fn overrides_apply_to_presets() {
    let mut p = LoadedPreset::load_or_default(None).unwrap();
    p.apply(&Overrides {
        scene: Some("furnace".into()),
        technique: Some("reference".into()),
        size: Some("40x30".into()),
        spp: Some(3),
        seed: Some(9),
        set: vec![
            "scene.params.albedo=0.5".into(),
            "max_depth=2".into(),
            "tonemap.exposure=1.5".into(),
        ],
    })
    .unwrap();
    assert_eq!(p.preset.scene.source, "furnace");
    assert_eq!(p.preset.render.size, [40, 30]);
    assert_eq!((p.preset.render.spp, p.preset.render.seed), (3, 9));
    assert_eq!(
        p.preset.techniques[0].params["max_depth"].as_integer(),
        Some(2)
    );
    assert_eq!(p.preset.tonemap.exposure, 1.5);
    assert_eq!(p.load_scene().unwrap().materials[0].base_color.x, 0.5);
    let mut bad = LoadedPreset::load_or_default(None).unwrap();
    assert!(bad
        .apply(&Overrides {
            set: vec!["render.sizee=3".into()],
            ..Default::default()
        })
        .is_err());
    assert!(bad
        .apply(&Overrides {
            size: Some("0x5".into()),
            ..Default::default()
        })
        .is_err());
    let mut unknown = LoadedPreset::load_or_default(None).unwrap();
    unknown
        .apply(&Overrides {
            scene: Some("cornel".into()),
            ..Default::default()
        })
        .unwrap();
    let err = unknown.load_scene().unwrap_err().to_string();
    assert!(err.contains("unknown built-in scene 'cornel'"), "{err}");
}

#[test]
fn gltf_scene_loads_with_extensions() {
    for file in [
        "scenes/box-room/box-room.gltf",
        "scenes/box-room/box-room.glb",
    ] {
        let s = gltf_load::load(Path::new(file)).unwrap();
        assert_eq!(s.triangles.len(), 16, "{file}");
        let panel = s
            .materials
            .iter()
            .find(|m| m.name == "panel light")
            .unwrap();
        assert!(
            (panel.emissive - Vec3::new(6.0, 5.4, 4.8))
                .abs()
                .max_element()
                < 1e-5,
            "emissive strength: {:?}",
            panel.emissive
        );
        let cube = s
            .materials
            .iter()
            .find(|m| m.name == "lambert cube")
            .unwrap();
        assert_eq!(cube.specular, 0.0);
        assert!(s
            .materials
            .iter()
            .any(|m| m.base_color_texture.map(|t| t.texture) == Some(0)));
        assert_eq!((s.textures[0].width, s.textures[0].height), (8, 8));
        assert_eq!(s.lights.len(), 1);
        assert!((s.lights[0].position - Vec3::new(-1.5, 1.5, 1.0)).length() < 1e-5);
        let cam = s.camera.unwrap();
        assert!((cam.position - Vec3::new(0.0, 1.6, 5.0)).length() < 1e-5);
        // Cube normals were missing: generated ones are unit length and face out of the cube.
        let centre = Vec3::new(0.8, 0.75, -0.5);
        for (t, &m) in s.triangles.iter().zip(&s.triangle_material) {
            if s.materials[m as usize].name == "lambert cube" {
                let p = s.positions[t[0] as usize];
                let n = s.normals[t[0] as usize];
                assert!((n.length() - 1.0).abs() < 1e-4 && n.dot(p - centre) > 0.0);
            }
        }
        // Node transform: the panel sits at y = 3.
        let panel_idx = s
            .materials
            .iter()
            .position(|m| m.name == "panel light")
            .unwrap() as u32;
        let t = s
            .triangles
            .iter()
            .zip(&s.triangle_material)
            .find(|(_, &m)| m == panel_idx)
            .unwrap()
            .0;
        assert!((s.positions[t[0] as usize].y - 3.0).abs() < 1e-6);
    }
}

#[test]
fn malformed_gltf_gives_clear_errors() {
    let dir = std::env::temp_dir().join(format!("gilab-gltf-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let glb = std::fs::read("scenes/box-room/box-room.glb").unwrap();
    let truncated = dir.join("truncated.glb");
    std::fs::write(&truncated, &glb[..glb.len() / 2]).unwrap();
    let err = format!("{:#}", gltf_load::load(&truncated).unwrap_err());
    assert!(err.contains("truncated.glb"), "{err}");

    let text = std::fs::read_to_string("scenes/box-room/box-room.gltf").unwrap();
    let bad_accessor = dir.join("bad-accessor.gltf");
    std::fs::write(
        &bad_accessor,
        text.replacen("\"indices\": 3", "\"indices\": 99", 1),
    )
    .unwrap();
    let err = format!("{:#}", gltf_load::load(&bad_accessor).unwrap_err());
    assert!(err.contains("bad-accessor.gltf"), "{err}");

    // An index value past the vertex count: patch the first u16 index of the floor to 999.
    let mut doc: serde_json::Value = serde_json::from_str(&text).unwrap();
    let uri = doc["buffers"][0]["uri"].as_str().unwrap().to_string();
    use base64_decode::decode;
    let mut bytes = decode(uri.split(',').nth(1).unwrap());
    let view = doc["accessors"][3]["bufferView"].as_u64().unwrap() as usize;
    let off = doc["bufferViews"][view]["byteOffset"].as_u64().unwrap() as usize;
    bytes[off..off + 2].copy_from_slice(&999u16.to_le_bytes());
    doc["buffers"][0]["uri"] = format!(
        "data:application/octet-stream;base64,{}",
        base64_decode::encode(&bytes)
    )
    .into();
    let bad_index = dir.join("bad-index.gltf");
    std::fs::write(&bad_index, doc.to_string()).unwrap();
    let err = format!("{:#}", gltf_load::load(&bad_index).unwrap_err());
    assert!(
        err.contains("bad-index.gltf") && err.contains("out of range"),
        "{err}"
    );

    let missing = format!(
        "{:#}",
        gltf_load::load(&dir.join("missing.gltf")).unwrap_err()
    );
    assert!(missing.contains("missing.gltf"), "{missing}");
}

#[test]
fn metrics_follow_their_definitions() {
    let reference = Image {
        width: 2,
        height: 1,
        rgb: vec![1.0, 0.0, 2.0, 0.5, 0.5, 0.5],
    };
    let image = Image {
        width: 2,
        height: 1,
        rgb: vec![1.5, 0.0, 2.0, 0.5, 0.0, 1.0],
    };
    let m = metrics::compare(&image, &reference).unwrap();
    let d2 = [0.25, 0.0, 0.0, 0.0, 0.25, 0.25];
    let y = [1.0f64, 0.0, 2.0, 0.5, 0.5, 0.5];
    let x = [1.5f64, 0.0, 2.0, 0.5, 0.0, 1.0];
    let mse = d2.iter().sum::<f64>() / 6.0;
    let rel = (0..6).map(|i| d2[i] / (y[i] * y[i] + 0.01)).sum::<f64>() / 6.0;
    let smape = (0..6)
        .map(|i| (x[i] - y[i]).abs() / (x[i].abs() + y[i].abs() + 0.01))
        .sum::<f64>()
        / 6.0;
    assert!(
        (m.mse - mse).abs() < 1e-12
            && (m.rel_mse - rel).abs() < 1e-12
            && (m.smape - smape).abs() < 1e-12
    );
    let map = metrics::rel_mse_map(&image, &reference);
    let mean = map.iter().map(|v| *v as f64).sum::<f64>() / map.len() as f64;
    assert!(
        (mean - m.rel_mse).abs() < 1e-6,
        "heatmap mean {mean} vs relMSE {}",
        m.rel_mse
    );
    assert!(metrics::compare(&image, &Image::new(3, 1)).is_err());
}

#[test]
fn builtin_scene_parameters_are_checked() {
    let mut t = toml::Table::new();
    t.insert("albdo".into(), 0.5.into());
    let err = builtin::build("furnace", &t).unwrap_err().to_string();
    assert!(err.contains("albdo"), "{err}");
    t.clear();
    t.insert("albedo".into(), 1.0.into());
    assert!(
        builtin::build("furnace", &t).is_err(),
        "albedo 1 has no finite furnace solution"
    );
    for (name, _) in builtin::NAMES {
        builtin::build(name, &toml::Table::new()).unwrap();
    }
    // `interior`: its point lights as asked, at most 256 (a clear error beyond).
    t.clear();
    t.insert("lights".into(), 8.into());
    assert_eq!(builtin::build("interior", &t).unwrap().lights.len(), 8);
    t.insert("lights".into(), 300.into());
    let err = builtin::build("interior", &t).unwrap_err().to_string();
    assert!(err.contains("at most 256"), "{err}");
    assert!(
        builtin::many_lights(1024, 7)
            .materials
            .iter()
            .filter(|m| m.emissive.max_element() > 0.0)
            .count()
            >= 1000
    );
}

/// ReSTIR's ray-budget slider: a budget too small for GI sample paths turns GI off; a larger
/// one keeps GI and raises the candidate count (which costs no rays).
#[test]
fn restir_budget_maps_rays_to_settings() {
    use gilab::render::Technique;
    let r = gilab::techniques::restir::Restir::default();
    let small = r.params_for_ray_budget(2.0, Some(8.0)).expect("change");
    use gilab::render::params::ParamValue;
    assert_eq!(small.get("gi"), Some(ParamValue::Bool(false)), "{small:?}");
    let large = r.params_for_ray_budget(16.0, Some(8.0)).expect("change");
    assert_eq!(large.get("gi"), Some(ParamValue::Bool(true)), "{large:?}");
    assert!(
        matches!(large.get("candidates"), Some(ParamValue::Int(n)) if n > 8),
        "{large:?}"
    );
}

/// The light pool keeps each class contiguous (local lights first, directional lights last) and
/// a power-proportional CDF within each class, which ReSTIR's per-class candidates sample; the
/// pool-wide CDF (path tracer NEE) is unchanged.
#[test]
fn light_pool_has_per_class_cdfs() {
    use gilab::scene::gpu_scene::{SceneData, LIGHT_DIRECTIONAL};
    let mut scene = builtin::courtyard(15.0, 1.0, 1.0);
    // A second sun listed before the lantern: the pool must still put it last.
    let mut sun = scene.lights[0].clone();
    sun.intensity *= 0.25;
    scene.lights.insert(0, sun);
    let data = SceneData::new(&scene);
    let lights = &data.lights;
    let local = lights
        .iter()
        .take_while(|l| l.kind != LIGHT_DIRECTIONAL)
        .count();
    assert_eq!(local, 5, "4 lamp triangles and the lantern first");
    assert!(lights[local..].iter().all(|l| l.kind == LIGHT_DIRECTIONAL));
    assert_eq!(lights.len() - local, 2);
    for class in [&lights[..local], &lights[local..]] {
        let sum: f32 = class.iter().map(|l| l.class_pmf).sum();
        assert!((sum - 1.0).abs() < 1e-5, "class pmfs sum to {sum}");
        assert_eq!(class.last().unwrap().class_cdf, 1.0);
        assert!(class.windows(2).all(|w| w[0].class_cdf <= w[1].class_cdf));
    }
    // The two suns keep their 4:1 power ratio within their class.
    let ratio = lights[local].class_pmf / lights[local + 1].class_pmf;
    assert!(
        (ratio - 4.0).abs() < 1e-3 || (1.0 / ratio - 4.0).abs() < 1e-3,
        "{ratio}"
    );
    // The sun holds almost all of the pool's power: the reason for per-class candidates.
    let local_mass: f32 = lights[..local].iter().map(|l| l.pmf).sum();
    assert!(
        local_mass < 0.01,
        "local lights' share of the pool {local_mass}"
    );
    assert_eq!(lights.last().unwrap().cdf, 1.0);
}

/// Every `rng_init` call names a `STREAM_*` constant of shaders/common/rng.wgsl, the constants
/// have distinct values, and no two entry files of one technique (folder) draw from the same
/// stream: passes never share random numbers, in one frame or across frames.
#[test]
fn random_streams_are_distinct_per_pass() {
    let lib = ShaderLibrary::discover();
    let files = lib.files().unwrap();
    let rng = &files["common/rng.wgsl"];
    let mut values = std::collections::BTreeMap::new();
    for line in rng.lines().filter(|l| l.starts_with("const STREAM_")) {
        let (name, value) = line["const ".len()..].split_once(": u32 = ").unwrap();
        let value = value.trim_end_matches(';').to_string();
        assert!(
            !values.values().any(|v| *v == value),
            "{name} reuses value {value}"
        );
        values.insert(name.to_string(), value);
    }
    assert!(values.len() >= 6, "streams: {values:?}");
    let mut owner: std::collections::BTreeMap<(String, String), String> = Default::default();
    let mut calls = 0;
    for entry in lib.entry_files().unwrap() {
        let src = &files[&entry];
        let folder = entry.split('/').next().unwrap().to_string();
        for (at, _) in src.match_indices("rng_init(") {
            let args = &src[at + "rng_init(".len()..];
            // The third argument: skip the pixel (which may hold commas inside vec2<u32>(..)).
            let mut depth = 0;
            let mut commas = Vec::new();
            for (i, c) in args.char_indices() {
                match c {
                    '(' => depth += 1,
                    ')' if depth == 0 => break,
                    ')' => depth -= 1,
                    ',' if depth == 0 => commas.push(i),
                    _ => {}
                }
            }
            assert_eq!(
                commas.len(),
                3,
                "shaders/{entry}: rng_init takes pixel, sample index, stream, seed"
            );
            let stream = args[commas[1] + 1..commas[2]].trim().to_string();
            assert!(
                values.contains_key(&stream),
                "shaders/{entry}: rng_init's stream `{stream}` is not a STREAM_ constant of rng.wgsl"
            );
            calls += 1;
            if let Some(other) = owner.insert((folder.clone(), stream.clone()), entry.clone()) {
                // The surfels' ray binning draws each ray's direction as the trace pass will,
                // from the same stream, on purpose (it sorts rays by it).
                let redraws = [("parts/surfels/bin.wgsl", "parts/surfels/trace.wgsl")];
                let pair = |a: &str, b: &str| {
                    redraws
                        .iter()
                        .any(|(x, y)| (a == *x && b == *y) || (a == *y && b == *x))
                };
                assert!(
                    other == entry || pair(&other, &entry),
                    "{stream} is used by shaders/{other} and shaders/{entry}"
                );
            }
        }
    }
    assert!(calls >= 8, "rng_init calls found: {calls}");
}

/// The shared references' cache key (`common::scene_content_hash`) changes with everything a
/// reference image depends on: one texel of a texture or of the environment map, one normal,
/// UV, tangent, an instance's transform, a material, and for a playing scene its speed and the
/// number of frames (poses) the render takes. Two equal scenes share a key.
#[test]
fn reference_cache_key_covers_the_image_inputs() {
    use gilab::scene::{environment::Environment, Texture};
    use glam::{Vec2, Vec3, Vec4};
    let key = |s: &gilab::scene::Scene| common::scene_content_hash(s, 4);
    let mut base = gilab::scene::builtin::cornell();
    let n = base.positions.len();
    base.normals = vec![Vec3::Y; n];
    base.uvs = vec![Vec2::ZERO; n];
    base.uvs1 = vec![Vec2::ZERO; n];
    base.tangents = vec![Vec4::X; n];
    base.textures.push(Texture {
        width: 2,
        height: 2,
        rgba8: vec![128; 16],
    });
    base.environment = Some(Environment::new(2, 1, vec![[1.0; 3]; 2]).unwrap());
    let k0 = key(&base);
    assert_eq!(k0, key(&base.clone()), "equal scenes share a key");
    type Edit = fn(&mut gilab::scene::Scene);
    let edits: [(&str, Edit); 7] = [
        ("texture texel", |s| s.textures[0].rgba8[5] = 129),
        ("environment texel", |s| {
            s.environment = Some(Environment::new(2, 1, vec![[1.0; 3], [1.0, 1.0, 0.5]]).unwrap())
        }),
        ("normal", |s| s.normals[3] = Vec3::X),
        ("uv", |s| s.uvs[3] = Vec2::new(0.5, 0.0)),
        ("second uv", |s| s.uvs1[3] = Vec2::new(0.5, 0.0)),
        ("tangent", |s| s.tangents[3] = Vec4::Y),
        ("material", |s| s.materials[0].roughness += 0.1),
    ];
    for (what, edit) in edits {
        let mut s = base.clone();
        edit(&mut s);
        assert_ne!(key(&s), k0, "the key ignores a changed {what}");
    }
    // Instances and motion: the animated box room (its panel light, cube and lamp move).
    let dir = common::tmp_dir("cpu", "cache-key");
    let (path, _) = common::animated_box_room(&dir);
    let mut playing = gilab::scene::gltf_load::load(&path).unwrap();
    assert!(!playing.instances.is_empty());
    std::sync::Arc::make_mut(playing.motion.as_mut().unwrap()).time_scale = 30.0;
    let k_play = key(&playing);
    assert_ne!(
        common::scene_content_hash(&playing, 1),
        k_play,
        "a longer render sees more poses"
    );
    let mut faster = playing.clone();
    std::sync::Arc::make_mut(faster.motion.as_mut().unwrap()).time_scale = 60.0;
    assert_ne!(key(&faster), k_play, "the key ignores the playback speed");
    let mut moved = playing.clone();
    moved.instances[0].transform =
        glam::Mat4::from_translation(Vec3::X * 0.01) * moved.instances[0].transform;
    assert_ne!(
        key(&moved),
        k_play,
        "the key ignores an instance's transform"
    );
}

/// docs/known-issues.md lists every unmet accuracy target that a test holds as a ratchet
/// (tests/common/targets.rs): the table between its markers is `targets::markdown_table()`, and
/// every target's id is checked by a test file. `GILAB_BLESS=1` rewrites the table.
#[test]
fn known_issues_lists_every_unmet_target() {
    let path = "docs/known-issues.md";
    let doc = std::fs::read_to_string(path).unwrap();
    let (begin, end) = (
        "<!-- unmet-targets:begin (generated from tests/common/targets.rs) -->\n",
        "<!-- unmet-targets:end -->",
    );
    let (a, b) = (
        doc.find(begin).expect("the begin marker") + begin.len(),
        doc.find(end).expect("the end marker"),
    );
    let table = common::targets::markdown_table();
    if std::env::var("GILAB_BLESS").is_ok_and(|v| v == "1") {
        std::fs::write(path, format!("{}{table}{}", &doc[..a], &doc[b..])).unwrap();
    } else {
        assert_eq!(
            &doc[a..b],
            table,
            "{path}'s table of unmet targets is out of date: run `GILAB_BLESS=1 cargo test --release --test cpu known_issues`"
        );
    }
    // Each id is passed to targets::check by the test that holds it.
    let tests: String = std::fs::read_dir("tests")
        .unwrap()
        .flatten()
        .filter(|e| e.path().extension().is_some_and(|x| x == "rs"))
        .map(|e| std::fs::read_to_string(e.path()).unwrap())
        .collect();
    for u in common::targets::UNMET {
        assert!(
            tests.contains(&format!("\"{}\"", u.id)),
            "unmet target {} is held by no test",
            u.id
        );
        assert!(u.issue > 0 && !u.date.is_empty());
    }
}

/// docs/parameters.md holds the tables the techniques declare (`gilab params` prints them).
#[test]
fn parameter_tables_match_the_declared_ones() {
    let doc = std::fs::read_to_string("docs/parameters.md").unwrap();
    let tables = gilab::techniques::params_markdown();
    assert!(
        doc.contains(&tables),
        "docs/parameters.md's technique parameter tables are out of date: paste the output of `gilab params`"
    );
}

/// Declared parameters: defaults in range, every value round-trips through a preset table, bad
/// values and unknown names are refused with the expected range, and a failed set changes nothing.
#[test]
fn declared_parameters_validate_and_round_trip() {
    for name in gilab::techniques::REGISTRY.iter().map(|t| t.id) {
        let mut t = gilab::techniques::create_technique(name).unwrap();
        let defaults = t.params();
        t.set_params_from_table(&defaults).unwrap();
        assert_eq!(t.params(), defaults, "{name}: defaults do not round-trip");
        for spec in t.param_set().specs() {
            let (_, max) = spec.range();
            let mut bad = toml::Table::new();
            bad.insert(spec.name.into(), (max + 1.0).into());
            let err = t.set_params_from_table(&bad).unwrap_err().to_string();
            assert!(
                err.contains(spec.name) && err.contains("must be"),
                "{name}: {err}"
            );
            assert_eq!(
                t.params(),
                defaults,
                "{name}: a refused value changed the parameters"
            );
        }
        let err = t
            .set_params_from_table(&toml::toml! { no_such_knob = 1 })
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("no_such_knob") && err.contains("known:"),
            "{err}"
        );
    }
    // Choices take their name, their index or (where a switch once stood) a boolean.
    let mut r = gilab::techniques::create_technique("restir").unwrap();
    for (v, want) in [
        (toml::Value::from("merged"), 2),
        (toml::Value::from(0), 0),
        (toml::Value::from(true), 1),
    ] {
        let mut t = toml::Table::new();
        t.insert("candidate_visibility".into(), v);
        r.set_params_from_table(&t).unwrap();
        assert_eq!(r.params()["candidate_visibility"].as_integer(), Some(want));
    }
}

/// Typed parameters (issue 56): the TOML a preset gives is parsed once into typed changes
/// (`Params::parse`), which apply exactly as the table did; every technique's current values
/// come back as changes that restore them; typed changes built in code are checked like parsed
/// ones (wrong type, out of range, unknown choice or name: an error naming the parameter, and
/// nothing applied).
#[test]
fn typed_parameters_apply_as_their_table_did() {
    use gilab::render::params::{ParamChanges, ParamValue};
    for name in gilab::techniques::REGISTRY.iter().map(|t| t.id) {
        let t = gilab::techniques::create_technique(name).unwrap();
        let defaults = t.params();
        let typed = t.param_set().parse(&defaults).unwrap();
        assert_eq!(typed, t.param_set().changes(), "{name}");
        // Each parameter moved to its range's top, through both doors: the same values.
        for spec in t.param_set().specs() {
            let (_, max) = spec.range();
            let mut top = toml::Table::new();
            top.insert(
                spec.name.into(),
                if spec.is_integer() {
                    toml::Value::Integer(max as i64)
                } else {
                    toml::Value::Float(max)
                },
            );
            let mut by_table = gilab::techniques::create_technique(name).unwrap();
            by_table.set_params_from_table(&top).unwrap();
            let changes = t.param_set().parse(&top).unwrap();
            let mut by_changes = gilab::techniques::create_technique(name).unwrap();
            by_changes.set_params(&changes).unwrap();
            assert_eq!(
                by_table.params(),
                by_changes.params(),
                "{name}.{}",
                spec.name
            );
            // And back to the defaults from the typed restore point.
            by_changes.set_params(&t.param_set().changes()).unwrap();
            assert_eq!(by_changes.params(), defaults, "{name}.{}", spec.name);
        }
    }
    let mut r = gilab::techniques::create_technique("restir").unwrap();
    let before = r.params();
    for (bad, says) in [
        (ParamChanges::new().int("candidates", 100_000), "candidates"),
        (ParamChanges::new().bool("candidates", true), "candidates"),
        (
            ParamChanges::new().choice("gi_terminate", "nowhere"),
            "gi_terminate",
        ),
        (
            ParamChanges::new().float("no_such_knob", 1.0),
            "no_such_knob",
        ),
        (
            ParamChanges::new()
                .int("candidates", 8)
                .int("spatial_count", -1),
            "spatial_count",
        ),
    ] {
        let err = r.set_params(&bad).unwrap_err().to_string();
        assert!(err.contains(says), "{err}");
        assert_eq!(r.params(), before, "{bad:?} changed the parameters");
    }
    r.set_params(&ParamChanges::new().choice("gi_terminate", "lumen-cards"))
        .unwrap();
    assert_eq!(
        r.param_set().changes().get("gi_terminate"),
        Some(ParamValue::Choice("lumen-cards"))
    );
}

/// The surfels' spawn tiles: 16 pixels whatever the image (`spawn_tiles = "16"`, the default,
/// the seed's), or with `"scaled"` the power of two nearest the seed's tile for the surfels' size
/// on screen: 16 at 1080p with the default `surfel_size`, fewer pixels on smaller images and
/// smaller surfels, never under 1 or over 16.
#[test]
fn surfel_spawn_tiles_keep_the_seeds_ratio_when_scaled() {
    use gilab::parts::surfels::{SurfelSettings, PARAMS};
    use gilab::render::params::{ParamChanges, Params};
    let settings = |changes: ParamChanges| {
        let mut p = Params::new("surfels", PARAMS);
        p.apply(&changes).unwrap();
        SurfelSettings::from_params(&p)
    };
    let seed = settings(ParamChanges::new());
    let scaled = settings(ParamChanges::new().choice("spawn_tiles", "scaled"));
    for h in [32, 64, 128, 1080, 4320] {
        assert_eq!(seed.spawn_tile(h), 16, "{h}");
    }
    let tiles: Vec<u32> = [32, 64, 128, 256, 512, 720, 1080, 2160]
        .iter()
        .map(|h| scaled.spawn_tile(*h))
        .collect();
    assert_eq!(tiles, [1, 1, 2, 4, 8, 8, 16, 16]);
    let small = settings(
        ParamChanges::new()
            .choice("spawn_tiles", "scaled")
            .float("surfel_size", 0.005),
    );
    assert_eq!(small.spawn_tile(1080), 4);
    assert_eq!(small.spawn_tile(32), 1);
}

/// `#define_import_path` marks a module wherever it lives; every other file is an entry file.
#[test]
fn entry_files_are_the_files_without_an_import_path() {
    let entries = ShaderLibrary::discover().entry_files().unwrap();
    assert!(entries.contains(&"frame/primary_surfaces.wgsl".to_string()));
    assert!(entries.contains(&"restir/shade.wgsl".to_string()));
    assert!(
        !entries
            .iter()
            .any(|e| e == "parts/restir/shared.wgsl" || e.starts_with("common/")),
        "modules listed as entry files: {entries:?}"
    );
}

/// Callisto parameters come from a glTF material's extras (`gilab_callisto`); a bad key or an
/// out-of-range value is refused naming the material; the preset's [shading] overrides them.
#[test]
fn callisto_parameters_from_gltf_extras_and_presets() {
    let dir = std::env::temp_dir().join(format!("gilab-extras-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let text = std::fs::read_to_string("scenes/box-room/box-room.gltf").unwrap();
    let doc: serde_json::Value = serde_json::from_str(&text).unwrap();
    let name = doc["materials"][0]["name"].as_str().unwrap().to_string();
    let write = |extras: serde_json::Value, file: &str| {
        let mut d = doc.clone();
        d["materials"][0]["extras"] = extras;
        let p = dir.join(file);
        std::fs::write(&p, d.to_string()).unwrap();
        p
    };
    let good = write(
        serde_json::json!({"gilab_callisto": {"retroreflection": 3.0, "diffuse_fresnel_tint": [1.0, 0.8, 0.7]}, "other_tool": 1}),
        "extras.gltf",
    );
    let scene = gltf_load::load(&good).unwrap();
    let m = scene.materials.iter().find(|m| m.name == name).unwrap();
    assert_eq!(m.callisto.retroreflection, 3.0);
    assert_eq!(m.callisto.diffuse_fresnel_tint, [1.0, 0.8, 0.7]);
    assert_eq!(m.callisto.smooth_terminator, 0.0);

    let typo = write(
        serde_json::json!({"gilab_callisto": {"retro": 3.0}}),
        "typo.gltf",
    );
    let err = format!("{:#}", gltf_load::load(&typo).unwrap_err());
    assert!(err.contains(&name) && err.contains("retro"), "{err}");
    let range = write(
        serde_json::json!({"gilab_callisto": {"smooth_terminator": 3.0}}),
        "range.gltf",
    );
    let err = format!("{:#}", gltf_load::load(&range).unwrap_err());
    assert!(
        err.contains("smooth_terminator") && err.contains("[-1, 1]"),
        "{err}"
    );

    // A preset's [shading] sets the model everywhere and overrides per material.
    let preset_file = dir.join("p.toml");
    std::fs::write(
        &preset_file,
        format!(
            "[scene]\nsource = \"{}\"\n[shading]\nbrdf = \"callisto-proxima\"\n[shading.materials.\"{name}\"]\nretroreflection = 5.0\n",
            good.display()
        ),
    )
    .unwrap();
    let p = gilab::preset::LoadedPreset::load(&preset_file).unwrap();
    let scene = p.load_scene().unwrap();
    let m = scene.materials.iter().find(|m| m.name == name).unwrap();
    assert_eq!(m.brdf, gilab::scene::shading::BrdfModel::CallistoProxima);
    assert_eq!(m.callisto.retroreflection, 5.0);
    assert_eq!(m.callisto.diffuse_fresnel_tint, [1.0, 0.8, 0.7]);
    std::fs::write(
        &preset_file,
        format!(
            "[scene]\nsource = \"{}\"\n[shading.materials.nope]\nretroreflection = 5.0\n",
            good.display()
        ),
    )
    .unwrap();
    let err = format!(
        "{:#}",
        gilab::preset::LoadedPreset::load(&preset_file)
            .and_then(|p| p.load_scene())
            .unwrap_err()
    );
    assert!(err.contains("nope") && err.contains(&name), "{err}");
}

/// The parallel BVH build (rayon) gives the sequential build's BVH bit for bit: on a random
/// soup large enough for parallel jobs and reductions, on a scene of identical triangles (the
/// degenerate split path), and on the built-in many-lights hall; and it still finds what brute
/// force finds.
#[test]
fn parallel_bvh_build_equals_sequential() {
    use gilab::scene::bvh::{brute_force_closest, Bvh};
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 40) as f32 / (1u64 << 24) as f32
    };
    let mut soup = Vec::new();
    for _ in 0..200_000 {
        let c = Vec3::new(next(), next(), next()) * 100.0;
        let d = |n: &mut dyn FnMut() -> f32| Vec3::new(n() - 0.5, n() - 0.5, n() - 0.5);
        soup.push([c, c + d(&mut next), c + d(&mut next)]);
    }
    let same = vec![[Vec3::ZERO, Vec3::X, Vec3::Y]; 70_000];
    let hall = builtin::many_lights(1024, 7).triangle_positions();
    for (name, tris) in [
        ("random soup", &soup),
        ("identical", &same),
        ("many-lights", &hall),
    ] {
        let t0 = std::time::Instant::now();
        let seq = Bvh::build_sequential(tris);
        let t1 = std::time::Instant::now();
        let par = Bvh::build(tris);
        let t2 = std::time::Instant::now();
        eprintln!(
            "{name}: {} triangles, {} nodes, depth {}: sequential {:.1} ms, parallel {:.1} ms ({} threads)",
            tris.len(),
            seq.nodes.len(),
            seq.depth,
            (t1 - t0).as_secs_f64() * 1e3,
            (t2 - t1).as_secs_f64() * 1e3,
            rayon::current_num_threads()
        );
        assert_eq!(seq.order, par.order, "{name}: triangle order");
        assert_eq!(seq.depth, par.depth, "{name}: depth");
        assert_eq!(
            bytemuck::cast_slice::<_, u8>(&seq.nodes),
            bytemuck::cast_slice::<_, u8>(&par.nodes),
            "{name}: nodes"
        );
    }
    // Traversal of the parallel BVH against brute force on random rays through the soup.
    let part = &soup[..20_000];
    let bvh = Bvh::build(part);
    for _ in 0..300 {
        let o = Vec3::new(next(), next(), next()) * 120.0 - Vec3::splat(10.0);
        let d = (Vec3::new(next(), next(), next()) - Vec3::splat(0.5)).normalize();
        let a = bvh.closest_hit(part, o, d, f32::MAX);
        let b = brute_force_closest(part, o, d);
        assert_eq!(a.map(|h| h.1), b.map(|h| h.1), "ray {o} {d}");
    }
}

/// Lenient loading: an image that cannot be read is skipped (its material falls back to the
/// factor), an unknown extension that is only used is ignored, one that is required is refused
/// naming it; a file with no light at all gets the default sky.
#[test]
fn gltf_optional_parts_are_skipped_with_warnings() {
    let dir = std::env::temp_dir().join(format!("gilab-lenient-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let text = std::fs::read_to_string("scenes/box-room/box-room.gltf").unwrap();
    let doc: serde_json::Value = serde_json::from_str(&text).unwrap();
    let write = |d: &serde_json::Value, file: &str| {
        let p = dir.join(file);
        std::fs::write(&p, d.to_string()).unwrap();
        p
    };
    let whole = gltf_load::load(&write(&doc, "whole.gltf")).unwrap();
    assert!(whole.materials[0].base_color_texture.is_some());

    let mut d = doc.clone();
    d["images"][0] = serde_json::json!({"uri": "no-such-image.png"});
    let scene = gltf_load::load(&write(&d, "missing-image.gltf")).unwrap();
    assert_eq!(scene.textures.len(), 0);
    assert!(scene.materials[0].base_color_texture.is_none());
    assert_eq!(scene.triangles.len(), whole.triangles.len());

    let mut d = doc.clone();
    d["extensionsUsed"]
        .as_array_mut()
        .unwrap()
        .push("EXT_not_known_here".into());
    gltf_load::load(&write(&d, "used.gltf")).unwrap();
    d["extensionsRequired"] = serde_json::json!(["EXT_not_known_here"]);
    let err = format!(
        "{:#}",
        gltf_load::load(&write(&d, "required.gltf")).unwrap_err()
    );
    assert!(err.contains("EXT_not_known_here"), "{err}");

    // No light: drop the punctual lights and the emission.
    let mut d = doc.clone();
    for n in d["nodes"].as_array_mut().unwrap() {
        if let Some(o) = n.as_object_mut() {
            o.remove("extensions");
        }
    }
    for m in d["materials"].as_array_mut().unwrap() {
        let o = m.as_object_mut().unwrap();
        o.remove("emissiveFactor");
    }
    assert_eq!(whole.sky, Vec3::ZERO);
    let dark = gltf_load::load(&write(&d, "no-light.gltf")).unwrap();
    assert!(dark.lights.is_empty());
    assert_eq!(dark.sky, Vec3::splat(gltf_load::DEFAULT_SKY));
    // An environment map (a preset's scene.environment) lights it: no default sky then.
    let lit = gltf_load::load_lit(&write(&d, "no-light-env.gltf"), true).unwrap();
    assert_eq!(lit.sky, Vec3::ZERO);
}

/// The large scene: at its default detail at least a million triangles (with 64 local lights,
/// a sun and a sky); its parallel BVH equals the sequential one bit for bit and finds what brute
/// force finds on random rays. Its procedural textures (issue 19): count, size, valid normal
/// maps, the cloth alpha-masked and double-sided with holes, a tangent on every normal-mapped
/// vertex (agreeing with MikkTSpace), the same bytes on every generation and through PNG; its
/// repeated meshes are recorded as exact instances. A low-detail atrium renders finite on the
/// GPU elsewhere (CI runs the generator at a small setting there).
#[test]
fn atrium_has_a_million_triangles_and_its_bvh_is_exact() {
    let scene = builtin::build("atrium", &toml::Table::new()).unwrap();
    let tris = scene.triangle_positions();
    let locals = scene
        .lights
        .iter()
        .filter(|l| l.kind != gilab::scene::PunctualKind::Directional)
        .count();
    let lamp_spheres = scene
        .materials
        .iter()
        .position(|m| m.name == "lamp")
        .map(|lamp| {
            let n = scene
                .triangle_material
                .iter()
                .filter(|&&m| m as usize == lamp)
                .count();
            n / 144 // triangles per lamp sphere (6 rings x 12 segments x 2)
        })
        .unwrap_or(0);
    eprintln!(
        "atrium: {} triangles, {} point lights + {} lamp spheres, sky {:?}",
        tris.len(),
        locals,
        lamp_spheres,
        scene.sky
    );
    assert!(tris.len() >= 1_000_000, "{}", tris.len());
    assert_eq!(locals + lamp_spheres, 64);
    assert!(scene
        .lights
        .iter()
        .any(|l| l.kind == gilab::scene::PunctualKind::Directional));
    assert!(scene.sky.max_element() > 0.0);
    let t0 = std::time::Instant::now();
    let par = bvh::Bvh::build(&tris);
    let t1 = std::time::Instant::now();
    let seq = bvh::Bvh::build_sequential(&tris);
    let t2 = std::time::Instant::now();
    eprintln!(
        "atrium BVH: parallel {:.0} ms, sequential {:.0} ms, {} nodes, depth {}",
        (t1 - t0).as_secs_f64() * 1e3,
        (t2 - t1).as_secs_f64() * 1e3,
        par.nodes.len(),
        par.depth
    );
    assert_eq!(seq.order, par.order);
    assert_eq!(
        bytemuck::cast_slice::<_, u8>(&seq.nodes),
        bytemuck::cast_slice::<_, u8>(&par.nodes)
    );
    let (lo, hi) = scene.bounds();
    let mut hits = 0;
    for (o, d) in random_rays(200, lo, hi, 11) {
        let a = par.closest_hit(&tris, o, d, f32::MAX);
        let b = bvh::brute_force_closest(&tris, o, d);
        match (a, b) {
            (None, None) => {}
            (Some(a), Some(b)) => {
                hits += 1;
                assert!(
                    (a.0 - b.0).abs() <= 1e-4 * b.0.max(1.0),
                    "t {} vs {}",
                    a.0,
                    b.0
                );
            }
            _ => panic!("BVH {a:?} vs brute force {b:?} for ray {o} {d}"),
        }
    }
    assert!(hits > 100, "only {hits} of 200 rays hit");

    // Issue 19: textured, alpha-masked cloth, instanced details.
    use gilab::scene::{atrium, AlphaMode};
    assert_eq!(scene.textures.len(), atrium::TEXTURES.len());
    assert_eq!(atrium::texture_size(1.0), 512);
    assert_eq!(atrium::texture_size(0.05), 64);
    for (t, name) in scene.textures.iter().zip(atrium::TEXTURES) {
        assert_eq!((t.width, t.height), (512, 512), "{name}");
        assert_eq!(t.rgba8.len(), 512 * 512 * 4, "{name}");
        // Not flat: every texture varies in some channel.
        let (lo, hi) = t
            .rgba8
            .iter()
            .fold((255u8, 0u8), |(l, h), &b| (l.min(b), h.max(b)));
        assert!(hi - lo > 20, "{name}: values {lo}..{hi}");
    }
    let texture = |name: &str| {
        let i = atrium::TEXTURES.iter().position(|n| *n == name).unwrap();
        &scene.textures[i]
    };
    // Normal maps: unit vectors (to 8-bit rounding) facing out, bumpy somewhere.
    for name in atrium::TEXTURES.iter().filter(|n| n.ends_with("_normal")) {
        let mut tilted = 0;
        for px in texture(name).rgba8.chunks_exact(4) {
            let n = Vec3::new(px[0] as f32, px[1] as f32, px[2] as f32) / 127.5 - Vec3::ONE;
            assert!((n.length() - 1.0).abs() < 0.02 && n.z > 0.2, "{name}: {n}");
            tilted += (n.z < 0.995) as usize;
        }
        assert!(tilted > 100, "{name}: only {tilted} tilted texels");
    }
    // Cloth: alpha-masked, double-sided, with holes (and a fringe) covering a fair share.
    let cloths: Vec<_> = scene
        .materials
        .iter()
        .filter(|m| m.name.starts_with("cloth"))
        .collect();
    assert_eq!(cloths.len(), 3);
    for m in &cloths {
        assert_eq!(m.alpha_mode, AlphaMode::Mask, "{}", m.name);
        assert!(m.double_sided && m.alpha_tested(), "{}", m.name);
        let t = &scene.textures[m.base_color_texture.unwrap().texture];
        let holes = t.rgba8.chunks_exact(4).filter(|p| p[3] < 128).count();
        let share = holes as f64 / (t.width * t.height) as f64;
        assert!(
            (0.03..0.2).contains(&share),
            "{}: {share:.3} of the cloth is holes",
            m.name
        );
    }
    // Every other material is opaque, and every textured material's texture exists.
    for m in &scene.materials {
        if !m.name.starts_with("cloth") {
            assert_eq!(m.alpha_mode, AlphaMode::Opaque, "{}", m.name);
        }
    }
    let textured = scene
        .materials
        .iter()
        .filter(|m| m.base_color_texture.is_some())
        .count();
    assert_eq!(
        textured,
        scene.materials.len() - 1,
        "all but the lamp are textured"
    );
    // Tangents: every vertex of a normal-mapped triangle has a unit one with a sign.
    assert_eq!(scene.tangents.len(), scene.positions.len());
    let mut mapped = 0;
    for (t, &m) in scene.triangles.iter().zip(&scene.triangle_material) {
        if scene.materials[m as usize].normal_texture.is_some() {
            mapped += 1;
            for &v in t {
                let tg = scene.tangents[v as usize];
                assert!(
                    (tg.truncate().length() - 1.0).abs() < 1e-3 && tg.w.abs() == 1.0,
                    "vertex {v} of a {} triangle: tangent {tg}",
                    scene.materials[m as usize].name
                );
            }
        }
    }
    assert!(
        mapped > scene.triangles.len() / 2,
        "{mapped} normal-mapped triangles"
    );
    // The floor's UVs are world x, z: tangent +X, bitangent (w N x T) towards -v (-Z).
    let floor = scene
        .materials
        .iter()
        .position(|m| m.name == "floor tiles")
        .unwrap();
    let fv = scene.triangles[scene
        .triangle_material
        .iter()
        .position(|&m| m as usize == floor)
        .unwrap()][0];
    let ft = scene.tangents[fv as usize];
    assert!(
        (ft.truncate() - Vec3::X).length() < 1e-3 && ft.w == 1.0,
        "floor tangent {ft}"
    );
    // Deterministic textures: the same bytes generated again, and through PNG and back.
    let again = atrium::textures(1.0);
    for ((a, b), name) in scene.textures.iter().zip(&again).zip(atrium::TEXTURES) {
        assert!(a.rgba8 == b.rgba8, "{name} differs between two generations");
    }
    let dir = std::env::temp_dir().join(format!("gilab-atrium-{}", std::process::id()));
    let paths = atrium::write_textures(&dir).unwrap();
    assert_eq!(paths.len(), atrium::TEXTURES.len());
    for (p, t) in paths.iter().zip(&again) {
        let png = image::open(p).unwrap().to_rgba8();
        assert_eq!(png.dimensions(), (t.width, t.height));
        assert!(png.as_raw() == &t.rgba8, "{}", p.display());
    }
    std::fs::remove_dir_all(&dir).ok();
    // Instances: each repeat is its prototype moved (vertices, UVs, normals, materials, indices).
    let low = atrium::build(0.05);
    assert_eq!(low.scene.textures[0].width, 64);
    let count = |p: &str| low.instances.iter().filter(|i| i.prototype == p).count();
    assert_eq!(
        ["column lower", "column upper", "arch", "vase", "lamp"].map(count),
        [26, 26, 48, 52, 32]
    );
    let s = &low.scene;
    for i in &low.instances {
        let p = low
            .instances
            .iter()
            .find(|j| j.prototype == i.prototype)
            .unwrap();
        assert_eq!(
            (i.triangle_count, i.vertex_count),
            (p.triangle_count, p.vertex_count)
        );
        for k in 0..i.vertex_count as usize {
            let (a, b) = (i.first_vertex as usize + k, p.first_vertex as usize + k);
            let (la, lb) = (
                s.positions[a] - i.translation,
                s.positions[b] - p.translation,
            );
            assert!(
                (la - lb).length() < 1e-4,
                "{}: vertex {k}: {la} vs {lb}",
                i.prototype
            );
            assert!((s.normals[a] - s.normals[b]).length() < 1e-5);
            assert_eq!(s.uvs[a], s.uvs[b]);
        }
        for k in 0..i.triangle_count as usize {
            let (a, b) = (i.first_triangle as usize + k, p.first_triangle as usize + k);
            let shift = i.first_vertex - p.first_vertex;
            assert_eq!(s.triangles[a], s.triangles[b].map(|v| v + shift));
            assert_eq!(s.triangle_material[a], s.triangle_material[b]);
        }
    }
    // The atrium's analytic tangents agree with MikkTSpace's.
    let mapped: Vec<[u32; 3]> = s
        .triangles
        .iter()
        .zip(&s.triangle_material)
        .filter(|(_, &m)| s.materials[m as usize].normal_texture.is_some())
        .map(|(t, _)| *t)
        .collect();
    let mikk = gilab::scene::tangents::generate(&s.positions, &s.normals, &s.uvs, &mapped);
    let (mut worst, mut signs, mut sum, mut count) = (1.0f32, 0, 0.0f64, 0);
    for &v in mapped.iter().flatten() {
        let (a, b) = (s.tangents[v as usize], mikk[v as usize]);
        let cos = a.truncate().dot(b.truncate());
        worst = worst.min(cos);
        sum += cos.clamp(-1.0, 1.0).acos().to_degrees() as f64;
        count += 1;
        signs += (a.w != b.w) as usize;
    }
    eprintln!(
        "atrium tangents vs MikkTSpace: mean {:.3} deg, worst {:.2} deg, {signs} signs differ",
        sum / count as f64,
        worst.clamp(-1.0, 1.0).acos().to_degrees()
    );
    assert_eq!(signs, 0);
    assert!(worst > 0.9998, "worst cosine {worst}");
    let instanced: u32 = low.instances.iter().map(|i| i.triangle_count).sum();
    eprintln!(
        "atrium detail 0.05: {} triangles, {} in {} instances",
        s.triangles.len(),
        instanced,
        low.instances.len()
    );
}

/// Scenes choose their shader variant: the any-hit alpha test is compiled into traversal only
/// where a material is alpha-tested (it costs ~3x on lavapipe even when it never runs).
#[test]
fn shader_variant_follows_the_scene() {
    use gilab::scene::gpu_scene::SceneData;
    let cornell = SceneData::new(&builtin::build("cornell", &toml::Table::new()).unwrap());
    assert!(!cornell.shader_variant().alpha_test);
    assert!(
        !cornell.shader_variant().instances,
        "no instances: a flat tree"
    );
    let mut detail = toml::Table::new();
    detail.insert("detail".into(), toml::Value::Float(0.05));
    let atrium = SceneData::new(&builtin::build("atrium", &detail).unwrap());
    assert!(
        atrium.shader_variant().alpha_test,
        "the atrium's cloth is alpha-masked"
    );
    assert!(
        atrium.shader_variant().instances,
        "the atrium's columns are instances"
    );
    // The library composes the def: the opaque variant has no alpha lookup in traversal.
    let lib = ShaderLibrary::discover();
    let with = lib.compose("bench/trace_rays.wgsl").unwrap();
    let without = lib
        .with_variant(cornell.shader_variant())
        .compose("bench/trace_rays.wgsl")
        .unwrap();
    let has_alpha_hole = |m: &naga::Module| {
        m.functions
            .iter()
            .any(|(_, f)| f.name.as_deref().is_some_and(|n| n.contains("alpha_hole")))
    };
    assert!(has_alpha_hole(&with));
    assert!(!has_alpha_hole(&without));
}

/// The two-level BVH finds the same closest hit as brute force, with rotated, non-uniformly
/// scaled and mirrored (winding-flipped) instances; instances that do not match their mesh (an
/// edited copy) or overlap another are traced as ordinary triangles, still exactly.
#[test]
fn instanced_bvh_matches_brute_force() {
    use gilab::scene::MeshInstance;
    use glam::{Mat4, Quat};
    // A mesh: a bumpy closed blob (an octahedron split 3 times, radius varying).
    let mut mesh: Vec<[Vec3; 3]> = vec![];
    let p = [
        Vec3::X,
        Vec3::NEG_X,
        Vec3::Y,
        Vec3::NEG_Y,
        Vec3::Z,
        Vec3::NEG_Z,
    ];
    for (a, b) in [(0, 2), (2, 1), (1, 3), (3, 0)] {
        mesh.push([p[a], p[b], p[4]]);
        mesh.push([p[b], p[a], p[5]]);
    }
    for _ in 0..3 {
        mesh = mesh
            .iter()
            .flat_map(|t| {
                let m = |a: Vec3, b: Vec3| ((a + b) * 0.5).normalize();
                let (ab, bc, ca) = (m(t[0], t[1]), m(t[1], t[2]), m(t[2], t[0]));
                [[t[0], ab, ca], [ab, t[1], bc], [ca, bc, t[2]], [ab, bc, ca]]
            })
            .collect();
    }
    let bump = |v: Vec3| v * (1.0 + 0.2 * (5.0 * v.x).sin() * (3.0 * v.y).cos());
    let mesh: Vec<[Vec3; 3]> = mesh.iter().map(|t| t.map(bump)).collect();
    // The rest of the scene: a floor of 2 x 20 x 20 triangles.
    let mut tris = Vec::new();
    for i in 0..20 {
        for j in 0..20 {
            let c = Vec3::new(i as f32 - 10.0, -2.0, j as f32 - 10.0);
            let (a, b, d) = (c + Vec3::X, c + Vec3::X + Vec3::Z, c + Vec3::Z);
            tris.push([c, a, b]);
            tris.push([c, b, d]);
        }
    }
    let mut instances = Vec::new();
    let mut place = |tris: &mut Vec<[Vec3; 3]>, m: Mat4, mirrored: bool| {
        let first = tris.len() as u32;
        for t in &mesh {
            let w = t.map(|v| m.transform_point3(v));
            // A mirroring node flips the winding (as the glTF loader does).
            tris.push(if mirrored { [w[0], w[2], w[1]] } else { w });
        }
        instances.push(MeshInstance {
            mesh: 7,
            transform: m,
            first_triangle: first,
            triangle_count: mesh.len() as u32,
        });
    };
    for k in 0..24 {
        let f = k as f32;
        let m = Mat4::from_scale_rotation_translation(
            Vec3::new(0.5 + 0.1 * (k % 3) as f32, 0.4 + 0.05 * (k % 5) as f32, 0.6),
            Quat::from_euler(glam::EulerRot::XYZ, f * 0.7, f * 1.3, f * 0.4),
            Vec3::new(
                (k % 6) as f32 * 3.0 - 8.0,
                (k / 6) as f32 * 1.5 - 1.0,
                (f * 2.3) % 9.0 - 4.5,
            ),
        );
        place(&mut tris, m, false);
    }
    place(&mut tris, Mat4::from_scale(Vec3::new(-0.8, 0.7, 0.7)), true);
    // An edited copy: one vertex moved, so it no longer matches the mesh.
    place(
        &mut tris,
        Mat4::from_translation(Vec3::new(6.0, 2.0, 6.0)),
        false,
    );
    let last = tris.len() - 1;
    tris[last][0] += Vec3::splat(0.3);
    // An instance whose range overlaps another's.
    let mut overlapping = instances[3];
    overlapping.first_triangle += 5;
    instances.push(overlapping);

    // Point queries prune by 1 / the largest singular value of the world-to-object matrix.
    for (m, sigma) in [
        (Mat4::IDENTITY, 1.0),
        (
            Mat4::from_scale_rotation_translation(
                Vec3::new(2.0, 3.0, 0.5),
                Quat::from_rotation_y(0.7),
                Vec3::ONE,
            ),
            3.0,
        ),
        (Mat4::from_scale(Vec3::new(-0.25, 4.0, 1.0)), 4.0),
    ] {
        let r = bvh::InstanceRecord::new(m, 0, 0, 0);
        let want = 1.0 / sigma;
        assert!(
            r.distance_scale <= want && r.distance_scale > want * 0.9999,
            "{} vs {want}",
            r.distance_scale
        );
    }
    let bvh = bvh::Bvh::build_instanced(&tris, &instances);
    assert_eq!(
        bvh.instances, 25,
        "24 placed + the mirrored one; edited and overlapping dropped"
    );
    assert_eq!(bvh.instanced_meshes, 1);
    // Every triangle appears once in the traversal order.
    let mut seen = vec![0; tris.len()];
    bvh.order.iter().for_each(|&t| seen[t as usize] += 1);
    assert!(seen.iter().all(|&c| c == 1));
    let flat = bvh::Bvh::build(&tris);
    assert!(
        bvh.nodes.len() < flat.nodes.len() / 3,
        "{} vs {} nodes",
        bvh.nodes.len(),
        flat.nodes.len()
    );
    let (mut hits, mut total) = (0, 0);
    // Random rays, and as many aimed at the instances' centres (a little off).
    let mut rays = random_rays(
        4000,
        Vec3::new(-10.0, -2.5, -6.0),
        Vec3::new(10.0, 6.0, 6.0),
        11,
    );
    let aimed: Vec<(Vec3, Vec3)> = rays
        .iter()
        .enumerate()
        .map(|(k, &(o, d))| {
            let centre = instances[k % 24].transform.w_axis.truncate() + d * 0.3;
            (o, (centre - o).normalize_or(Vec3::X))
        })
        .collect();
    rays.extend(aimed);
    for (o, d) in rays {
        let a = bvh.closest_hit(&tris, o, d, f32::MAX);
        let b = bvh::brute_force_closest(&tris, o, d);
        total += 1;
        match (a, b) {
            (None, None) => {}
            (Some(a), Some(b)) => {
                // Hits on instances (the floor's 800 triangles come first).
                hits += (b.1 >= 800) as usize;
                assert!((a.0 - b.0).abs() <= 1e-5 * b.0.max(1.0), "t {a:?} vs {b:?}");
            }
            _ => panic!("two-level BVH {a:?} vs brute force {b:?} from {o} along {d}"),
        }
    }
    assert!(
        hits > total / 3,
        "{hits}/{total} rays hit instances: the test must exercise them"
    );

    // The atrium's 184 repeats: same hits as brute force.
    let atrium = gilab::scene::atrium::build(0.05).scene;
    let tris = atrium.triangle_positions();
    let start = std::time::Instant::now();
    let bvh = bvh::Bvh::build_instanced(&tris, &atrium.instances);
    let two_level_ms = start.elapsed().as_secs_f64() * 1e3;
    let start = std::time::Instant::now();
    let flat = bvh::Bvh::build(&tris);
    let flat_ms = start.elapsed().as_secs_f64() * 1e3;
    assert_eq!((bvh.instances, bvh.instanced_meshes), (184, 5));
    eprintln!(
        "atrium detail 0.05: two-level {} nodes in {two_level_ms:.0} ms, flat {} nodes in {flat_ms:.0} ms",
        bvh.nodes.len(),
        flat.nodes.len()
    );
    let (lo, hi) = atrium.bounds();
    for (o, d) in random_rays(400, lo, hi, 5) {
        let a = bvh.closest_hit(&tris, o, d, f32::MAX).map(|h| h.0);
        let b = bvh::brute_force_closest(&tris, o, d).map(|h| h.0);
        match (a, b) {
            (None, None) => {}
            (Some(a), Some(b)) => assert!((a - b).abs() <= 1e-5 * b.max(1.0), "{a} vs {b}"),
            _ => panic!("atrium: two-level {a:?} vs brute force {b:?}"),
        }
    }
}

/// glTF animations posed at a time (issue 36): the box room with an animation added in the
/// test. "slide" moves the panel (LINEAR translation), turns the cube (LINEAR rotation, slerp)
/// and carries the lamp (CUBICSPLINE translation); "blink" scales the cube (STEP). At
/// t = 0.5 s the nodes hold hand-computed values, and the scene equals, bit for bit, the same
/// file with those transforms written into its nodes and no animation.
#[test]
fn gltf_animation_poses_nodes() {
    use gilab::scene::animation::PoseRequest;
    use glam::{Quat, Vec4};
    let dir = std::env::temp_dir().join(format!("gilab-anim-{}", std::process::id()));
    let (animated, data) = common::animated_box_room(&dir);
    let base: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string("scenes/box-room/box-room.gltf").unwrap())
            .unwrap();
    let quat_y = |deg: f32| Quat::from_rotation_y(deg.to_radians());
    let pose = |time: f32, clip: Option<&str>| {
        gltf_load::load_posed(
            &animated,
            false,
            Some(&PoseRequest {
                time,
                clip: clip.map(str::to_string),
            }),
        )
    };
    let rest = gltf_load::load(&animated).unwrap();
    assert_eq!(rest.animations.len(), 2);
    assert_eq!(rest.animations[0].name, "slide");
    assert_eq!(rest.animations[0].duration, 2.0);
    let posed = pose(0.5, None).unwrap();

    // By hand at t = 0.5 (u = 0.25 of [0, 2]): the panel 0.5 along x; the cube turned 67.5°
    // (a quarter of the way from 45° to 135°) and scaled 0.5 (STEP: the key at 0.25); the lamp
    // on the Hermite curve: x = -1.5 h00 + 1 * 2 h10 + 0.5 h01 + (-1) * 2 h11 with h00 =
    // 0.84375, h10 = 0.140625, h01 = 0.15625, h11 = -0.046875, so -0.8125.
    let panel_vertex = |s: &gilab::scene::Scene| {
        let t = (0..s.triangles.len())
            .find(|&t| s.materials[s.triangle_material[t] as usize].name == "panel light")
            .unwrap();
        s.positions[s.triangles[t][0] as usize]
    };
    let panel_shift = panel_vertex(&posed) - panel_vertex(&rest);
    assert!(
        (panel_shift - Vec3::new(0.5, 0.0, 0.0)).length() < 1e-5,
        "{panel_shift}"
    );
    let lamp = posed.lights[0].position;
    assert!(
        (lamp - Vec3::new(-0.8125, 1.5, 1.0)).length() < 1e-5,
        "{lamp}"
    );
    assert_eq!(posed.posed_at, Some(0.5));

    // The same file with the sampled transforms written into the nodes, no animation.
    let clips = {
        // The library's own samples, so that the written floats are the ones it posed with.
        use gilab::scene::animation::{Interpolation, Keyframes, Property};
        let s = |k: usize, i| {
            let (v, comps, _) = &data[k];
            let vals: Vec<Vec4> = v
                .chunks(*comps)
                .map(|c| {
                    Vec4::new(
                        c[0],
                        *c.get(1).unwrap_or(&0.0),
                        *c.get(2).unwrap_or(&0.0),
                        *c.get(3).unwrap_or(&0.0),
                    )
                })
                .collect();
            Keyframes::new(data[if k == 5 { 4 } else { 0 }].0.clone(), vals, i).unwrap()
        };
        (
            s(1, Interpolation::Linear).sample(0.5, Property::Translation),
            s(2, Interpolation::Linear).sample(0.5, Property::Rotation),
            s(3, Interpolation::CubicSpline).sample(0.5, Property::Translation),
            s(5, Interpolation::Step).sample(0.5, Property::Scale),
        )
    };
    let (panel_t, cube_r, lamp_t, cube_s) = clips;
    let expect_r = quat_y(67.5);
    assert!(
        Quat::from_vec4(cube_r).abs_diff_eq(expect_r, 1e-6),
        "{cube_r}"
    );
    assert_eq!(cube_s.truncate(), Vec3::splat(0.5));
    let mut baked = base;
    baked["nodes"][2]["translation"] = serde_json::json!(panel_t.truncate().to_array());
    baked["nodes"][3]["rotation"] = serde_json::json!(cube_r.to_array());
    baked["nodes"][3]["scale"] = serde_json::json!(cube_s.truncate().to_array());
    baked["nodes"][4]["translation"] = serde_json::json!(lamp_t.truncate().to_array());
    let baked_path = dir.join("baked.gltf");
    std::fs::write(&baked_path, baked.to_string()).unwrap();
    let baked = gltf_load::load(&baked_path).unwrap();
    assert_eq!(
        posed.positions, baked.positions,
        "posed geometry differs from the baked file"
    );
    assert_eq!(posed.normals, baked.normals);
    assert_eq!(posed.lights, baked.lights);
    assert_ne!(posed.positions, rest.positions);

    // One clip alone: "blink" scales the cube; the panel stays where the file put it.
    let blink = pose(0.5, Some("blink")).unwrap();
    assert_eq!(panel_vertex(&blink), panel_vertex(&rest));
    // Looping: "blink" lasts 1 s, so 1.5 s poses it as 0.5 s does.
    assert_eq!(pose(1.5, Some("blink")).unwrap().positions, blink.positions);
    let err = format!("{:#}", pose(0.5, Some("walk")).unwrap_err());
    assert!(
        err.contains("walk") && err.contains("slide, blink"),
        "{err}"
    );
}

/// Playback (issue 36): the box room's animations re-posed by the scene's `Motion` equal, bit
/// for bit, the file loaded at that time (vertices, normals, lights, instance transforms). The
/// animated meshes (panel light, cube) are instances of their own, so the BVH's top level alone
/// is rebuilt over their new transforms (`Bvh::rebuild_top`, bottom levels kept), and that tree
/// finds the same closest hits as a flat BVH of the posed triangles on 10,000 rays.
#[test]
fn playback_reposes_like_a_load_and_rebuilds_only_the_top_level() {
    use gilab::scene::animation::PoseRequest;
    let dir = std::env::temp_dir().join(format!("gilab-playback-{}", std::process::id()));
    let (animated, _) = common::animated_box_room(&dir);
    let rest = gltf_load::load(&animated).unwrap();
    let motion = rest
        .motion
        .clone()
        .expect("the panel, the cube and the lamp move");
    assert_eq!(motion.moving_instances(), 2, "panel and cube");
    let mut bvh = bvh::Bvh::build_instanced(&rest.triangle_positions(), &rest.instances);
    assert!(bvh.top.is_some(), "two levels");
    let bottom = bvh.nodes[bvh.top.as_ref().unwrap().nodes..].to_vec();
    let mut playing = rest.clone();
    for t in [0.25f32, 0.5] {
        let moved = motion.apply(&mut playing, t).unwrap();
        assert_eq!(moved.instances.len(), 2, "t = {t}");
        assert!(moved.lights, "the lamp moves");
        assert!(bvh.rebuild_top(&playing.instances, &moved.instances));
    }
    let posed = gltf_load::load_posed(
        &animated,
        false,
        Some(&PoseRequest {
            time: 0.5,
            clip: None,
        }),
    )
    .unwrap();
    assert_eq!(playing.positions, posed.positions);
    assert_eq!(playing.normals, posed.normals);
    assert_eq!(playing.lights, posed.lights);
    assert_eq!(playing.instances, posed.instances);
    // Bottom levels untouched (the records after them hold the new transforms).
    let top = bvh.top.as_ref().unwrap();
    let words = |n: &[bvh::BvhNode]| bytemuck::cast_slice::<_, u32>(n).to_vec();
    assert_eq!(
        words(&bvh.nodes[top.nodes..top.records_at]),
        words(&bottom[..top.records_at - top.nodes])
    );
    let tris = playing.triangle_positions();
    let flat = bvh::Bvh::build(&tris);
    let (lo, hi) = playing.bounds();
    let mut hits = 0;
    for (o, d) in random_rays(10_000, lo, hi, 7) {
        let a = bvh.closest_hit(&tris, o, d, f32::MAX).map(|h| h.0);
        let b = flat.closest_hit(&tris, o, d, f32::MAX).map(|h| h.0);
        match (a, b) {
            (None, None) => {}
            (Some(a), Some(b)) => {
                assert!((a - b).abs() <= 1e-5 * b.max(1.0), "{a} vs {b}");
                hits += 1;
            }
            _ => panic!("re-posed two-level {a:?} vs flat {b:?}"),
        }
    }
    eprintln!("playback: {hits} of 10000 rays hit, the same t as the flat BVH of the pose");
    assert!(hits > 2_000, "{hits}");
}

/// A Cornell preset with `[[scene.animate]]` tables (after `[scene] source = "cornell"`).
fn animated_cornell(tables: &str, extra_scene: &str) -> Result<gilab::scene::Scene, String> {
    let text = format!("[scene]\nsource = \"cornell\"\n{extra_scene}\n{tables}");
    LoadedPreset::from_text(&text, Some(Path::new("p.toml")))
        .and_then(|p| p.load_scene())
        .map_err(|e| e.to_string())
}

/// The positions of a named object's triangles, corner by corner.
fn object_corners(scene: &gilab::scene::Scene, name: &str) -> Vec<Vec3> {
    let o = scene
        .objects
        .iter()
        .find(|o| o.name == name)
        .unwrap_or_else(|| panic!("no object {name}"));
    let first = o.first_triangle as usize;
    scene.triangle_positions()[first..first + o.triangle_count as usize]
        .iter()
        .flatten()
        .copied()
        .collect()
}

#[test]
fn preset_keyframes_move_named_objects_of_builtins() {
    let still = builtin::cornell();
    // Naming adds no triangle: the objects cover the scene's 34 triangles in order.
    let names: Vec<(&str, u32, u32)> = still
        .objects
        .iter()
        .map(|o| (o.name.as_str(), o.first_triangle, o.triangle_count))
        .collect();
    assert_eq!(
        names,
        [
            ("floor", 0, 2),
            ("ceiling", 2, 2),
            ("back wall", 4, 2),
            ("green wall", 6, 2),
            ("red wall", 8, 2),
            ("light", 10, 2),
            ("short box", 12, 12),
            ("tall box", 24, 12)
        ]
    );
    assert_eq!(still.triangles.len(), 36);
    let loaded = LoadedPreset::load_or_default(None)
        .unwrap()
        .load_scene()
        .unwrap();
    assert!(loaded.instances.is_empty() && loaded.motion.is_none());
    assert_eq!(loaded.triangle_positions(), still.triangle_positions());

    let tables = r#"
[[scene.animate]]
object = "tall box"
times = [0.0, 1.0]
rotation_deg = [[0, 0, 0], [0, 90, 0]]

[[scene.animate]]
object = "light"
times = [0.0, 2.0]
translation = [[0, 0, 0], [1.0, -1.0, 0]]

[[scene.animate]]
object = "short box"
times = [0.0, 1.0, 2.0]
translation = [[0, 0, 0], [0, 0.5, 0], [0, 1, 0]]
interpolation = "step"

[[scene.animate]]
object = "back wall"
times = [0.0, 1.0, 2.0]
translation = [[0, 0, 0], [0, 1, 0], [0, 0, 0]]
interpolation = "cubicspline"
"#;
    let t = 0.5f32;
    let posed = animated_cornell(tables, &format!("time = {t}")).unwrap();
    assert_eq!(posed.triangles.len(), still.triangles.len());
    assert_eq!(posed.triangle_material, still.triangle_material);
    assert_eq!(posed.instances.len(), 4, "one instance per animated object");
    let close = |a: &[Vec3], b: &[Vec3], what: &str| {
        assert_eq!(a.len(), b.len());
        for (p, q) in a.iter().zip(b) {
            assert!(p.distance(*q) < 1e-5, "{what}: {p} vs {q}");
        }
    };
    // LINEAR rotation: 45° about +Y at 0.5 s, about the box's bounding-box centre.
    let rest = object_corners(&still, "tall box");
    let (lo, hi) = rest.iter().fold(
        (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
        |(l, h), p| (l.min(*p), h.max(*p)),
    );
    let pivot = (lo + hi) * 0.5;
    let turn = glam::Quat::from_rotation_y(45f32.to_radians());
    let want: Vec<Vec3> = rest.iter().map(|p| pivot + turn * (*p - pivot)).collect();
    close(&object_corners(&posed, "tall box"), &want, "tall box");
    // LINEAR translation: a quarter of the way at 0.5 s of 2; an emitter like any other.
    let want: Vec<Vec3> = object_corners(&still, "light")
        .iter()
        .map(|p| *p + Vec3::new(0.25, -0.25, 0.0))
        .collect();
    close(&object_corners(&posed, "light"), &want, "light");
    // STEP: the first key's value until 1 s.
    close(
        &object_corners(&posed, "short box"),
        &object_corners(&still, "short box"),
        "short box at 0.5 s",
    );
    let at = |t: f32| animated_cornell(tables, &format!("time = {t}")).unwrap();
    let later = at(1.5);
    let want: Vec<Vec3> = object_corners(&still, "short box")
        .iter()
        .map(|p| *p + Vec3::new(0.0, 0.5, 0.0))
        .collect();
    close(
        &object_corners(&later, "short box"),
        &want,
        "short box at 1.5 s",
    );
    // CUBICSPLINE, Catmull-Rom tangents: keys 0, 1, 0 at 0, 1, 2 s; at 0.5 s the tangents are
    // 1 (one-sided) and 0, so y = 0.125 + 0.5 = 0.625.
    let want: Vec<Vec3> = object_corners(&still, "back wall")
        .iter()
        .map(|p| *p + Vec3::new(0.0, 0.625, 0.0))
        .collect();
    close(&object_corners(&posed, "back wall"), &want, "back wall");
    // Everything else is the still scene's, bit for bit.
    let moved: Vec<usize> = posed
        .instances
        .iter()
        .flat_map(|i| i.first_triangle as usize..(i.first_triangle + i.triangle_count) as usize)
        .collect();
    let (a, b) = (posed.triangle_positions(), still.triangle_positions());
    for k in (0..a.len()).filter(|k| !moved.contains(k)) {
        assert_eq!(a[k], b[k], "triangle {k}");
    }
    // Without `time` the scene is at 0; `time_scale` plays the clip "animate", and a frame
    // re-posed to t equals the preset posed at t.
    let mut playing = animated_cornell(tables, "time_scale = 1.0").unwrap();
    close(
        &object_corners(&playing, "tall box"),
        &object_corners(&still, "tall box"),
        "tall box at 0",
    );
    let motion = playing.motion.clone().unwrap();
    assert_eq!(motion.time_scale, 1.0);
    assert_eq!(playing.animations.len(), 1);
    assert_eq!(playing.animations[0].name, "animate");
    let moved = motion.apply(&mut playing, 1.5).unwrap();
    assert_eq!(moved.instances.len(), 4);
    assert_eq!(playing.positions, later.positions);
    assert_eq!(playing.instances, later.instances);
    // Spheres share vertices: the object gets vertices of its own, appended.
    let glossy = r#"
[[scene.animate]]
object = "sphere r0.3"
times = [0.0, 1.0]
translation = [[0, 0, 0], [0, 2, 0]]
"#;
    let text = format!("[scene]\nsource = \"glossy\"\ntime = 0.5\n{glossy}");
    let posed = LoadedPreset::from_text(&text, None)
        .unwrap()
        .load_scene()
        .unwrap();
    let rest = builtin::build("glossy", &Default::default()).unwrap();
    let want: Vec<Vec3> = object_corners(&rest, "sphere r0.3")
        .iter()
        .map(|p| *p + Vec3::Y)
        .collect();
    close(&object_corners(&posed, "sphere r0.3"), &want, "sphere");
    assert_eq!(
        object_corners(&posed, "sphere r0.7"),
        object_corners(&rest, "sphere r0.7")
    );
}

#[test]
fn preset_keyframe_errors_are_clear() {
    let entry = |body: &str| format!("[[scene.animate]]\nobject = \"tall box\"\n{body}\n");
    let cases = [
        (entry("times = [0.0]\ntranslation = [[0, 0, 0]]").replace("tall box", "tall bx"), "p.toml:4: scene.animate (object \"tall bx\"): the scene 'cornell' has no such object (it has: floor, ceiling, back wall, green wall, red wall, light, short box, tall box)"),
        (entry("times = [0.0, 1.0, 1.0]\ntranslation = [[0, 0, 0], [1, 0, 0], [2, 0, 0]]"), "`times` must increase strictly: key 2 (1) is not after key 1 (1)"),
        (entry("times = [0.0, 1.0]\ntranslation = [[0, 0, 0]]"), "`translation` has 1 values for 2 key times (one per key)"),
        (entry("times = [0.0, 1.0]\nscale = [[1, 1, 1], [1, 1]]"), "`scale` value 1 has 2 numbers, expected 3 ([x, y, z])"),
        (entry("times = [0.0]\nrotation = [[0, 0, 1]]"), "`rotation` value 0 has 3 numbers, expected 4 ([x, y, z, w])"),
        (entry("times = [0.0]\nrotation = [[0, 0, 1, 0]]\nrotation_deg = [[0, 0, 0]]"), "give `rotation` (quaternions) or `rotation_deg`, not both"),
        (entry("times = [0.0, 1.0]"), "nothing to animate"),
        (entry("times = [0.0]\nscale = [[1, 1, 1]]\ninterpolation = \"cubic\""), "unknown variant `cubic`"),
        (entry("times = [0.0]\ntranslation = [[0, 0, 0]]\n[[scene.animate]]\nobject = \"tall box\"\ntimes = [1.0]\ntranslation = [[1, 0, 0]]"), "its translation is animated twice"),
    ];
    for (tables, want) in cases {
        let err = animated_cornell(&tables, "").unwrap_err();
        eprintln!("{err}");
        assert!(err.contains(want), "{err}\n  wanted: {want}");
        assert!(!err.contains('\n'), "{err}");
    }
    // Malformed tables are reported where they are written (line and column).
    let err = animated_cornell(
        &entry("times = [1.0, 0.5]\nscale = [[1, 1, 1], [2, 2, 2]]"),
        "",
    )
    .unwrap_err();
    assert!(err.starts_with("p.toml:4:"), "{err}");
    // Scenes that name no object, and glTF files, are told what to do.
    let text = format!(
        "[scene]\nsource = \"furnace\"\n{}",
        entry("times = [0.0]\nscale = [[1, 1, 1]]")
    );
    let err = LoadedPreset::from_text(&text, None)
        .unwrap()
        .load_scene()
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("'furnace' names none (cornell, glossy and material-balls do)"),
        "{err}"
    );
    let dir = std::env::temp_dir().join(format!("gilab-animate-{}", std::process::id()));
    let (file, _) = common::animated_box_room(&dir);
    let text = format!(
        "[scene]\nsource = {:?}\n{}",
        file.display().to_string(),
        entry("times = [0.0]\nscale = [[1, 1, 1]]")
    );
    let err = LoadedPreset::from_text(&text, None)
        .unwrap()
        .load_scene()
        .unwrap_err()
        .to_string();
    assert!(err.contains("come from the file"), "{err}");
    // Still refused on a built-in without motion and without keyframes.
    let err = animated_cornell("", "time_scale = 1.0").unwrap_err();
    assert!(
        err.contains("the built-in scene 'cornell' has none"),
        "{err}"
    );
}

/// The registry of caches GI paths end in (`parts::gi_cache::CACHES`) is what `gi_terminate`
/// offers, and each entry's key for a set of parameters is the key of the cache it makes: a
/// cache once built is kept while the parameters do not change (a mismatch would rebuild it
/// every frame and restart its history). For every registered cache and a few parameter sets.
#[test]
fn registered_caches_make_what_their_key_says() {
    use gilab::parts::gi_cache::{CacheSettings, CACHES};
    use gilab::parts::restir::GiTerminate;
    use gilab::parts::world_regir::WorldRegirSettings;
    assert_eq!(GiTerminate::NAMES[0], "path");
    assert_eq!(GiTerminate::NAMES.len(), CACHES.len() + 1);
    let light = WorldRegirSettings::from_params(&gilab::render::params::Params::new(
        "restir",
        gilab::parts::restir::PARAMS,
    ));
    for (k, kind) in CACHES.iter().enumerate() {
        assert_eq!(GiTerminate::NAMES[k + 1], kind.name);
        let t = GiTerminate::from_index(k as u32 + 1);
        assert_eq!(t.name(), kind.name);
        assert!(t.cache());
        for (atlas_size, update, ray_budget) in [(512, 0.25, 4096), (1024, 1.0, 16384)] {
            let s = CacheSettings {
                atlas_size,
                update,
                ray_budget,
                light,
            };
            let cache = (kind.new)(&s).unwrap();
            assert_eq!(cache.key(), (kind.key)(&s), "{}", kind.name);
            assert_eq!(cache.key().name, kind.name);
            assert!(!(kind.describe)(&s, 1).is_empty());
        }
    }
    assert!(!GiTerminate::from_index(0).cache());
    assert_eq!(GiTerminate::from_index(99), GiTerminate::PATH);
}

/// A light's own geometry, to say whether it can light a point (the tree's bounds only bound
/// it).
#[derive(Clone, Copy)]
enum TreeTestLight {
    Triangle([Vec3; 3], bool),
    Point(Vec3),
    Spot(Vec3, Vec3, f32),
}

impl TreeTestLight {
    /// Whether some point of the light sends light to `p` from above the plane of normal `n`
    /// (zero: any direction), with a small margin against rounding at the boundary.
    fn reaches(&self, p: Vec3, n: Vec3) -> bool {
        let above = |x: Vec3| n == Vec3::ZERO || (x - p).normalize().dot(n) > 1e-4;
        match *self {
            TreeTestLight::Triangle(v, two_sided) => {
                let ng = (v[1] - v[0]).cross(v[2] - v[0]).normalize();
                (two_sided || (p - v[0]).dot(ng) > 1e-4) && v.iter().any(|&x| above(x))
            }
            TreeTestLight::Point(c) => above(c),
            TreeTestLight::Spot(c, d, cos_outer) => {
                above(c) && (p - c).normalize().dot(d.normalize()) > cos_outer + 1e-4
            }
        }
    }
}

/// Lights of every kind the tree holds: one- and two-sided triangles facing every way, points
/// and spots, spread over a room (a fixed pseudo-random pattern), with their geometry.
fn light_tree_test_lights() -> (
    Vec<gilab::parts::light_tree::LightBounds>,
    Vec<TreeTestLight>,
) {
    use gilab::parts::light_tree::LightBounds;
    let mut rng = 0x1234_5678u32;
    let mut next = move || {
        rng ^= rng << 13;
        rng ^= rng >> 17;
        rng ^= rng << 5;
        rng as f32 / u32::MAX as f32
    };
    let (mut lights, mut geometry) = (Vec::new(), Vec::new());
    for i in 0..300 {
        let c = Vec3::new(next() * 10.0 - 5.0, next() * 4.0, next() * 10.0 - 5.0);
        let phi = 0.1 + 10.0 * next().powi(3);
        match i % 5 {
            0 => {
                lights.push(LightBounds::point(c, phi));
                geometry.push(TreeTestLight::Point(c));
            }
            1 => {
                let d = Vec3::new(next() - 0.5, -1.0, next() - 0.5);
                let outer = 0.2 + next();
                lights.push(LightBounds::spot(c, d, outer, phi));
                geometry.push(TreeTestLight::Spot(c, d, outer.cos()));
            }
            k => {
                let e1 = Vec3::new(next() - 0.5, next() - 0.5, next() - 0.5) * 0.4;
                let e2 = Vec3::new(next() - 0.5, next() - 0.5, next() - 0.5) * 0.4;
                let v = [c, c + e1, c + e2];
                lights.push(LightBounds::triangle(&v, phi, k == 4));
                geometry.push(TreeTestLight::Triangle(v, k == 4));
            }
        }
    }
    (lights, geometry)
}

#[test]
fn light_tree_descent_pmf_equals_the_trail_pmf() {
    use gilab::parts::light_tree::LightTree;
    // A built-in scene's pool (1,400 small emitters) and a mixed set of every light kind.
    let scene = builtin::build("many-lights", &toml::from_str("lights = 1400").unwrap()).unwrap();
    let data = gilab::scene::gpu_scene::SceneData::new(&scene);
    let pool_geometry: Vec<TreeTestLight> = data
        .lights
        .iter()
        .map(|l| {
            let g = &data.tri_geom[l.tri as usize];
            let v0 = Vec3::from_slice(&g.v0[..3]);
            let v = [
                v0,
                v0 + Vec3::from_slice(&g.e1[..3]),
                v0 + Vec3::from_slice(&g.e2[..3]),
            ];
            TreeTestLight::Triangle(v, false)
        })
        .collect();
    let (mixed_bounds, mixed_geometry) = light_tree_test_lights();
    let mixed = LightTree::build(&mixed_bounds);
    for (name, tree, geometry) in [
        ("many-lights 1400", &data.light_tree, &pool_geometry),
        ("mixed", &mixed, &mixed_geometry),
    ] {
        let lights = geometry.len();
        assert_eq!(
            tree.nodes.len(),
            2 * lights - 1,
            "{name}: one leaf per light"
        );
        assert!(tree.depth < 64, "{name}: depth {}", tree.depth);
        let mut rng = 99u32;
        let mut next = move || {
            rng = rng.wrapping_mul(747_796_405).wrapping_add(2_891_336_453);
            (rng >> 8) as f32 / 16_777_216.0
        };
        let (mut worst, mut sums) = (0.0f32, Vec::new());
        for q in 0..200 {
            let p = Vec3::new(next() * 24.0 - 12.0, next() * 6.0, next() * 24.0 - 12.0);
            let n = if q % 4 == 0 {
                Vec3::ZERO
            } else {
                Vec3::new(next() - 0.5, next() - 0.5, next() - 0.5).normalize()
            };
            for _ in 0..20 {
                if let Some((light, pmf)) = tree.sample(p, n, next()) {
                    let evaluated = tree.pmf(light, p, n);
                    worst = worst.max((pmf - evaluated).abs() / pmf);
                    assert!(pmf > 0.0);
                }
            }
            // Every light that can light p has a probability (the bounds are conservative),
            // and all of them together at most one (a descent can end where neither child
            // reaches p: no light, no sample).
            let mut total = 0.0f64;
            for (l, g) in geometry.iter().enumerate() {
                let pmf = tree.pmf(l as u32, p, n);
                assert!(
                    pmf > 0.0 || !g.reaches(p, n),
                    "{name}: light {l} reaches {p} (normal {n}) but the tree never picks it"
                );
                total += pmf as f64;
            }
            if total > 0.0 {
                sums.push(total);
            }
        }
        println!(
            "{name}: depth {}, worst |descent - trail| / pmf {worst:.2e}, pmf sums in [{:.4}, {:.4}]",
            tree.depth,
            sums.iter().cloned().fold(f64::INFINITY, f64::min),
            sums.iter().cloned().fold(0.0, f64::max)
        );
        assert!(
            worst <= 1e-5,
            "{name}: the descent's pmf and the trail's differ by {worst}"
        );
        assert!(
            sums.len() > 150,
            "{name}: lights reach only {} query points",
            sums.len()
        );
        for s in &sums {
            assert!(
                *s <= 1.0 + 1e-4,
                "{name}: the pmfs of all lights sum to {s}"
            );
        }
    }
}

/// Irradiance at `p` (normal `n`) from one of the mixed lights, all visible, point-like:
/// phi / d^2 times the receiving cosine, zero outside its emission cone.
fn light_tree_test_irradiance(l: &gilab::parts::light_tree::LightBounds, p: Vec3, n: Vec3) -> f64 {
    let d = l.centroid() - p;
    let wi = d.normalize();
    // Emission cone: inside the cone of normals, or within pi/2 of it for surfaces.
    let cos_l = l.axis.dot(-wi);
    let cos_l = if l.two_sided { cos_l.abs() } else { cos_l };
    let emits = if l.cos_theta_o <= -1.0 {
        1.0
    } else if l.cos_theta_o >= 1.0 {
        cos_l.max(0.0) as f64
    } else if cos_l >= l.cos_theta_o {
        1.0
    } else {
        0.0
    };
    l.phi as f64 * emits * n.dot(wi).max(0.0) as f64 / d.length_squared() as f64
}

/// Irradiance at a point from the mixed lights (all visible; point-like: phi / d^2 times the
/// receiving cosine, zero behind a one-sided emitter), estimated by the tree's samples with a
/// pmf: the exact sum and the estimate's mean and standard error.
fn light_tree_irradiance_estimate(
    lights: &[gilab::parts::light_tree::LightBounds],
    tree: &gilab::parts::light_tree::LightTree,
    p: Vec3,
    n: Vec3,
    pmf_of: &dyn Fn(u32, f32) -> f32,
) -> (f64, f64, f64) {
    let f = |i: usize| light_tree_test_irradiance(&lights[i], p, n);
    let exact: f64 = (0..lights.len()).map(f).sum();
    let (mut sum, mut sum2, n_samples) = (0.0f64, 0.0f64, 200_000);
    for k in 0..n_samples {
        let u = (k as f64 + 0.5) as f32 / n_samples as f32;
        // Stratified u: the estimate's error is far below its iid standard error, which keeps
        // the check conservative.
        if let Some((light, pmf)) = tree.sample(p, n, u) {
            let x = f(light as usize) / pmf_of(light, pmf) as f64;
            sum += x;
            sum2 += x * x;
        }
    }
    let mean = sum / n_samples as f64;
    let se = ((sum2 / n_samples as f64 - mean * mean).max(0.0) / n_samples as f64).sqrt();
    (exact, mean, se)
}

#[test]
fn light_tree_sampling_is_unbiased_and_a_wrong_pmf_is_caught() {
    use gilab::parts::light_tree::LightTree;
    let (lights, _) = light_tree_test_lights();
    let tree = LightTree::build(&lights);
    let queries = [
        (Vec3::new(0.0, 0.0, 0.0), Vec3::Y),
        (
            Vec3::new(3.0, 2.0, -1.0),
            Vec3::new(-1.0, 0.2, 0.3).normalize(),
        ),
        (Vec3::new(-4.5, 3.9, 4.0), Vec3::NEG_Y),
    ];
    for (p, n) in queries {
        let (exact, mean, se) = light_tree_irradiance_estimate(&lights, &tree, p, n, &|_, pmf| pmf);
        // The negative control: the pmf of the descent without the receiving normal, a plausible
        // slip (sampling with the normal, weighting without it).
        let (_, wrong, wrong_se) = light_tree_irradiance_estimate(&lights, &tree, p, n, &|l, _| {
            tree.pmf(l, p, Vec3::ZERO)
        });
        println!(
            "p {p}: exact {exact:.5}, tree {mean:.5} ± {se:.5}, wrong pmf {wrong:.5} ± {wrong_se:.5}"
        );
        assert!(
            (mean - exact).abs() <= 4.0 * se + 1e-4 * exact,
            "tree sampling is biased at {p}: {mean} against {exact} (se {se})"
        );
        assert!(
            (wrong - exact).abs() > 4.0 * wrong_se + 1e-4 * exact,
            "the check cannot see a wrong pmf at {p}: {wrong} against {exact}"
        );
    }
}

/// The local lights under node `at` of a light tree.
fn light_tree_lights_under(tree: &gilab::parts::light_tree::LightTree, at: usize) -> Vec<u32> {
    let (mut out, mut stack) = (Vec::new(), vec![at]);
    while let Some(i) = stack.pop() {
        let node = &tree.nodes[i];
        if node.leaf == 1 {
            out.push(node.index);
        } else {
            stack.extend([i + 1, node.index as usize]);
        }
    }
    out
}

/// Issue 60: the stochastic lightcut (`cache_direct = "lightcut"`, GIBS's "lightcut 4"). Its
/// cut holds every light that can reach the point exactly once and at most `size` nodes; the
/// sum of one descent below each cut node is an unbiased irradiance estimate (stratified, 4
/// standard errors, at three points of the mixed lights); a cut that loses a node is caught
/// (the negative control). Printed, not asserted: the variance of one lightcut estimate against
/// the mean of as many independent tree descents (the same shadow rays). It is not always lower:
/// each cut node gets its ray however little it gives (docs/light-tree.md).
#[test]
fn light_tree_lightcut_covers_every_light_once_and_is_unbiased() {
    use gilab::parts::light_tree::LightTree;
    let (lights, geometry) = light_tree_test_lights();
    let tree = LightTree::build(&lights);
    let f = |i: u32, p: Vec3, n: Vec3| light_tree_test_irradiance(&lights[i as usize], p, n);
    // Mean and variance of one descent's estimate below node `at` (stratified u).
    let node_estimate = |at: usize, p: Vec3, n: Vec3| -> (f64, f64) {
        let samples = 100_000;
        let (mut sum, mut sum2) = (0.0f64, 0.0f64);
        for k in 0..samples {
            let u = (k as f64 + 0.5) as f32 / samples as f32;
            if let Some((light, pmf)) = tree.sample_from(at, p, n, u) {
                let x = f(light, p, n) / pmf as f64;
                sum += x;
                sum2 += x * x;
            }
        }
        let mean = sum / samples as f64;
        (mean, (sum2 / samples as f64 - mean * mean).max(0.0))
    };
    let queries = [
        (Vec3::new(0.0, 0.0, 0.0), Vec3::Y),
        (
            Vec3::new(3.0, 2.0, -1.0),
            Vec3::new(-1.0, 0.2, 0.3).normalize(),
        ),
        (Vec3::new(-4.5, 3.9, 4.0), Vec3::NEG_Y),
    ];
    for (p, n) in queries {
        let exact: f64 = (0..lights.len() as u32).map(|i| f(i, p, n)).sum();
        let (_, tree_var) = node_estimate(0, p, n);
        for size in [1usize, 2, 4, 8] {
            let cut = tree.lightcut(p, n, size);
            assert!(
                !cut.is_empty() && cut.len() <= size,
                "cut of {} nodes for size {size}",
                cut.len()
            );
            // Every light that reaches p lies under exactly one node of the cut.
            let mut seen = vec![0u32; lights.len()];
            for &(at, w) in &cut {
                assert!(w > 0.0);
                for l in light_tree_lights_under(&tree, at) {
                    seen[l as usize] += 1;
                }
            }
            for (l, g) in geometry.iter().enumerate() {
                assert!(seen[l] <= 1, "light {l} lies under two cut nodes");
                assert!(
                    seen[l] == 1 || !g.reaches(p, n),
                    "light {l} reaches {p} but no cut node holds it (size {size})"
                );
            }
            let parts: Vec<(f64, f64)> =
                cut.iter().map(|&(at, _)| node_estimate(at, p, n)).collect();
            let mean: f64 = parts.iter().map(|e| e.0).sum();
            let var: f64 = parts.iter().map(|e| e.1).sum();
            // The stratified mean's error is far below this iid standard error.
            let se = (var / 100_000.0).sqrt();
            assert!(
                (mean - exact).abs() <= 4.0 * se + 1e-4 * exact,
                "lightcut {size} is biased at {p}: {mean} against {exact} (se {se})"
            );
            // The negative control: the cut without its last node.
            if cut.len() > 1 {
                let lost: f64 = parts[..parts.len() - 1].iter().map(|e| e.0).sum();
                assert!(
                    (lost - exact).abs() > 4.0 * se + 1e-4 * exact,
                    "the check cannot see a cut that loses a node at {p}: {lost} against {exact}"
                );
            }
            let rays = size as f64;
            println!(
                "p {p}, lightcut {size}: {} nodes, estimate {mean:.5} (exact {exact:.5}), variance of one estimate {var:.4e}; {size} tree descents averaged {:.4e} ({:.1}x)",
                cut.len(),
                tree_var / rays,
                tree_var / rays / var.max(1e-30)
            );
        }
    }
}

/// Copies of `name` once every call is inlined into `module`'s entry point, as drivers do
/// (Mesa inlines every function): the number of call paths from the entry to it.
fn inlined_copies(module: &naga::Module, name: &str) -> u64 {
    use naga::{Block, Function, Handle, Statement};
    fn calls(block: &Block, out: &mut Vec<Handle<Function>>) {
        for statement in block.iter() {
            match statement {
                Statement::Call { function, .. } => out.push(*function),
                Statement::Block(b) => calls(b, out),
                Statement::If { accept, reject, .. } => {
                    calls(accept, out);
                    calls(reject, out);
                }
                Statement::Switch { cases, .. } => cases.iter().for_each(|c| calls(&c.body, out)),
                Statement::Loop {
                    body, continuing, ..
                } => {
                    calls(body, out);
                    calls(continuing, out);
                }
                _ => {}
            }
        }
    }
    fn copies_in(
        module: &naga::Module,
        body: &Block,
        is_target: &dyn Fn(&str) -> bool,
        memo: &mut std::collections::HashMap<Handle<Function>, u64>,
    ) -> u64 {
        let mut callees = Vec::new();
        calls(body, &mut callees);
        let mut n = 0;
        for f in callees {
            if let Some(&c) = memo.get(&f) {
                n += c;
                continue;
            }
            let function = &module.functions[f];
            let own = u64::from(function.name.as_deref().is_some_and(is_target));
            let c = own + copies_in(module, &function.body, is_target, memo);
            memo.insert(f, c);
            n += c;
        }
        n
    }
    // naga_oil names an imported function `NAMEX_naga_oil_mod_X…`.
    let mangled = format!("{name}X_naga_oil_mod_");
    let is_target = |f: &str| f == name || f.starts_with(&mangled);
    let entry = &module.entry_points[0].function;
    copies_in(module, &entry.body, &is_target, &mut Default::default())
}

/// Lavapipe compiles a pipeline at its first dispatch, after inlining every call, so its
/// compile time grows with the copies of the largest functions (measured first frame on
/// cornell at 8², shader cache off, 2026-11-30): ReSTIR DI's initial candidates took 38-48 s
/// with 19 copies of the contribution and 4 shadow rays, 16 s with 10 and 2; its spatial reuse
/// 6.8 s with 6, 3.1 s with 3; ReSTIR PT's reuse passes 25-26 s each with two copies of the
/// shift, 8.3-8.5 s with one; Callisto's shadow pass (interior) 8.3 s with nine copies of the
/// BVH traversal, 5.7 s with three. The bounds keep a new call site from undoing it.
#[test]
fn the_largest_functions_are_inlined_few_times() {
    let lib = ShaderLibrary::discover();
    let cases = [
        ("parts/restir/initial_temporal.wgsl", "contribution", 10),
        ("parts/restir/initial_temporal.wgsl", "unoccluded", 2),
        ("parts/restir/spatial.wgsl", "contribution", 3),
        ("restir_pt/temporal.wgsl", "shift_path", 1),
        ("restir_pt/spatial.wgsl", "shift_path", 1),
        ("callisto_shadows/shadows.wgsl", "traverse", 3),
    ];
    let mut report = Vec::new();
    for (entry, function, bound) in cases {
        let module = lib.compose(entry).unwrap_or_else(|e| panic!("{e}"));
        let copies = inlined_copies(&module, function);
        println!("{entry}: {copies} inlined copies of {function} (bound {bound})");
        if copies > bound || copies == 0 {
            report.push(format!(
                "{entry}: {copies} copies of {function}, bound {bound}"
            ));
        }
    }
    assert!(report.is_empty(), "{}", report.join("\n"));
}

/// Where a footprint Rust file (`common::in_reference_footprint`) names a module outside the
/// footprint: `crate::app`, a part other than the light tree, another technique, or (from the
/// light tree) its parent `super::`. The registry (`techniques/mod.rs`, which makes a technique
/// by id) and the CLI (`view` and `bench` open the viewer) are the two entries allowed to.
fn footprint_escapes(rel: &str, source: &str) -> Vec<String> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut out = Vec::new();
    for (line, text) in source.lines().enumerate() {
        let code = text.split("//").next().unwrap_or("");
        let mut rest = code;
        while let Some(at) = rest.find("crate::") {
            rest = &rest[at + "crate::".len()..];
            let path: Vec<&str> = rest
                .split(|c: char| !(c.is_alphanumeric() || c == '_' || c == ':'))
                .next()
                .unwrap_or("")
                .split("::")
                .collect();
            let escapes = match path.as_slice() {
                ["app", ..] => !rel.starts_with("src/cli/"),
                ["parts", part, ..] => *part != "light_tree",
                ["techniques", t, ..] => {
                    let module = root.join("src/techniques").join(t);
                    let is_module = module.is_dir() || module.with_extension("rs").is_file();
                    is_module && *t != "reference" && rel != "src/techniques/mod.rs"
                }
                _ => false,
            };
            if escapes {
                out.push(format!("{rel}:{}: crate::{}", line + 1, path.join("::")));
            }
        }
        if rel == "src/parts/light_tree.rs" && code.contains("super::") {
            out.push(format!("{rel}:{}: super::", line + 1));
        }
    }
    out
}

/// The reference's footprint (the files the shared and shipped references are keyed by,
/// `common::in_reference_footprint`) is closed: no Rust file in it names a module outside it,
/// so a change outside cannot reach a reference render but through the technique registry,
/// which makes the reference alone there. (The shaders:
/// `gpu::shipped_references_are_what_these_sources_render`.)
#[test]
fn reference_footprint_is_closed() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let files = common::source_files();
    let footprint: Vec<&String> = files
        .iter()
        .filter(|f| common::in_reference_footprint(f))
        .collect();
    // What it holds and leaves out, so that a rule gone wrong shows.
    for must in [
        "Cargo.lock",
        "src/render/engine.rs",
        "src/techniques/reference/mod.rs",
        "src/parts/light_tree.rs",
        "shaders/reference/path_trace.wgsl",
        "shaders/common/path.wgsl",
    ] {
        assert!(footprint.iter().any(|f| *f == must), "{must} is in it");
    }
    for never in [
        "src/techniques/lumen/mod.rs",
        "src/parts/world_cache.rs",
        "src/app/mod.rs",
        "shaders/lumen/apply.wgsl",
        "shaders/parts/world_cache/update.wgsl",
    ] {
        assert!(files.iter().any(|f| f == never), "{never} exists");
        assert!(!common::in_reference_footprint(never), "{never} is not");
    }
    let mut escapes = Vec::new();
    for rel in footprint.iter().filter(|f| f.ends_with(".rs")) {
        let source = std::fs::read_to_string(root.join(rel)).unwrap();
        escapes.extend(footprint_escapes(rel, &source));
    }
    assert!(
        escapes.is_empty(),
        "footprint files reach outside it (a reference could depend on a file its key leaves out: widen common::in_reference_footprint or cut the dependency):\n{}",
        escapes.join("\n")
    );
    // The check can fail: each kind of escape is found.
    let planted = "use crate::techniques::lumen::Lumen;\nlet c = crate::parts::SurfaceCache::new(); // crate::app\nuse crate::app::run;\n";
    assert_eq!(
        footprint_escapes("src/render/engine.rs", planted),
        [
            "src/render/engine.rs:1: crate::techniques::lumen::Lumen",
            "src/render/engine.rs:2: crate::parts::SurfaceCache::new",
            "src/render/engine.rs:3: crate::app::run",
        ]
    );
    assert!(footprint_escapes(
        "src/techniques/reference/mod.rs",
        "use crate::techniques::create_technique;"
    )
    .is_empty());
}
