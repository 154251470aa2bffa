//! glTF materials (issue 19), Khronos-sample style: scenes written as glTF by
//! tests/common/gltf_writer.rs, loaded through `gltf_load`, and for the `gpu_` tests rendered
//! by the reference path tracer (lavapipe in CI; small images, direct light only, delta lights
//! so that most pixels carry no noise) and compared against closed forms and predicted pixels.
//! The `loader_` tests need no GPU.

mod common;

use common::gltf_writer::{
    solid_rgba8, tex, GltfBuilder, MaterialDesc, MeshData, Place, TexRef, TexTransform,
};
use gilab::compare::Image;
use gilab::scene::{gltf_load, AlphaMode, Scene, TextureRef, UvTransform};
use glam::{Mat4, Quat, Vec2, Vec3, Vec4};
use std::f32::consts::{FRAC_PI_2, PI};
use std::path::PathBuf;
use std::sync::Mutex;

// ---------------------------------------------------------------------------------------------
// Helpers

fn dir(name: &str) -> PathBuf {
    common::tmp_dir("materials", name)
}

/// Warnings logged by the library, captured so tests can check what a lenient load says.
static LOGS: Mutex<Vec<String>> = Mutex::new(Vec::new());
struct Capture;
impl log::Log for Capture {
    fn enabled(&self, m: &log::Metadata) -> bool {
        m.level() <= log::Level::Warn
    }
    fn log(&self, r: &log::Record) {
        if self.enabled(r.metadata()) {
            LOGS.lock()
                .unwrap_or_else(|e| e.into_inner())
                .push(r.args().to_string());
        }
    }
    fn flush(&self) {}
}
fn capture_logs() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let _ = log::set_logger(&Capture);
        log::set_max_level(log::LevelFilter::Warn);
    });
}
/// Captured warnings mentioning `needle` (a file path keeps tests running in parallel apart).
fn warnings_with(needle: &str) -> Vec<String> {
    LOGS.lock()
        .unwrap_or_else(|e| e.into_inner())
        .iter()
        .filter(|w| w.contains(needle))
        .cloned()
        .collect()
}

/// Renders with the reference path tracer: `spp` samples in one frame, direct light only.
fn render(scene: Scene, size: u32, spp: u32) -> Image {
    let r = common::render_reference(scene, [size, size], spp, spp, 7, 1);
    assert_eq!(r.image.non_finite_count(), 0);
    assert_eq!(r.rays.invalid_samples, 0);
    r.image
}

/// For a camera at height `h` above a horizontal plane looking straight down (up = -Z, so
/// right = +X and image rows run toward +Z) with vertical field of view `fov_deg`: the (x, z)
/// on the plane of a position given in pixels (fractional, 0..size) of a square image.
fn plane_point(px: f32, py: f32, size: u32, h: f32, fov_deg: f32) -> Vec2 {
    let t = (fov_deg.to_radians() * 0.5).tan();
    let ndc_x = 2.0 * px / size as f32 - 1.0;
    let ndc_y = 1.0 - 2.0 * py / size as f32;
    Vec2::new(ndc_x * t * h, -ndc_y * t * h)
}

fn srgb_to_linear(c: u8) -> f32 {
    let c = c as f32 / 255.0;
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

fn lambert(name: &str, a: f32) -> MaterialDesc {
    MaterialDesc::lambert(name, [a; 3])
}

// ---------------------------------------------------------------------------------------------
// a. Normal mapping: a Lambert plane lit at a grazing angle.

const ELEVATION_DEG: f32 = 10.0;
const TILT_DEG: f32 = 30.0;

/// The RGB8 texel of a tangent-space normal (x, y, z) and the unit vector it decodes to.
fn encode_normal(n: Vec3) -> ([u8; 4], Vec3) {
    let q = n
        .normalize()
        .to_array()
        .map(|c| ((c * 0.5 + 0.5) * 255.0).round() as u8);
    let decoded = Vec3::new(q[0] as f32, q[1] as f32, q[2] as f32) / 255.0 * 2.0 - Vec3::ONE;
    ([q[0], q[1], q[2], 255], decoded)
}

struct NormalCase {
    name: &'static str,
    /// Tangent-space normal of the (constant) map; None: no normal texture.
    map: Option<Vec3>,
    normal_scale: Option<f32>,
    /// The file gives TANGENT = (+X, w = +1) (else the loader generates MikkTSpace tangents).
    file_tangents: bool,
    /// The plane's node mirrors x (scale -1, 1, 1).
    mirrored: bool,
    /// Azimuth of the light in the XZ plane: the light comes from (cos a, 0, sin a) (tilted up
    /// by the elevation).
    light_azimuth_deg: f32,
    /// KHR_texture_transform rotation of the normal texture (degrees): the map's axes turn
    /// with it (its +X follows dP/du' with uv' = M uv).
    rotation_deg: f32,
}

/// Plane y = 0 (UV u along +X, v along +Z: tangent +X, bitangent -Z in glTF's convention),
/// albedo 0.5, directional light of irradiance 2 pi (so albedo / pi x E = 1) at 10 degrees
/// elevation, camera 2 m above looking straight down with a narrow field of view.
fn normal_scene(c: &NormalCase) -> (Scene, f64) {
    let mut b = GltfBuilder::new();
    let mut mat = lambert("plane", 0.5);
    let mut decoded = Vec3::Z;
    if let Some(n) = c.map {
        let (texel, d) = encode_normal(n);
        decoded = d;
        let t = b.texture_rgba8(4, 4, &solid_rgba8(4, 4, texel));
        let mut r = tex(t);
        if c.rotation_deg != 0.0 {
            r.transform = Some(TexTransform {
                offset: None,
                rotation: Some(c.rotation_deg.to_radians()),
                scale: None,
                tex_coord: None,
            });
        }
        mat.normal_texture = Some(r);
        mat.normal_scale = c.normal_scale;
    }
    let m = b.material(&mat);
    let mut plane = MeshData::quad_xz(50.0, 0.0, |x, z| Vec2::new(x / 4.0, z / 4.0));
    if c.file_tangents {
        plane.tangents = Some(vec![Vec4::new(1.0, 0.0, 0.0, 1.0); 4]);
    }
    let mesh = b.mesh(&plane, Some(m));
    let scale = if c.mirrored {
        Vec3::new(-1.0, 1.0, 1.0)
    } else {
        Vec3::ONE
    };
    b.node(mesh, Place::Trs(Vec3::ZERO, Quat::IDENTITY, scale));
    let (e, a) = (ELEVATION_DEG.to_radians(), c.light_azimuth_deg.to_radians());
    let to_light = Vec3::new(e.cos() * a.cos(), e.sin(), e.cos() * a.sin());
    b.directional_light(-to_light, [1.0; 3], 2.0 * PI);
    b.camera(Vec3::new(0.0, 2.0, 0.0), Vec3::ZERO, Vec3::NEG_Z, 10.0);
    let path = b.write(&dir(&format!("normal-{}", c.name)), "scene");
    let scene = gltf_load::load(&path).unwrap();

    // Expected: albedo / pi x E x cos(shading normal, light) with the glTF formula
    // n = normalize(T x + B y + N z), (x, y) scaled by normalTexture.scale, B = w cross(N, T).
    let s = c.normal_scale.unwrap_or(1.0);
    let ts = (decoded * Vec3::new(s, s, 1.0)).normalize();
    let (t, w) = if c.mirrored {
        (Vec3::NEG_X, -1.0)
    } else {
        (Vec3::X, 1.0)
    };
    let nrm = Vec3::Y;
    let bit = w * nrm.cross(t);
    // The map's axes: dP/du' and -dP/dv' with uv' = M uv (dP/du = t, dP/dv = -bit).
    let m = gilab::scene::UvTransform {
        rotation: c.rotation_deg.to_radians(),
        ..Default::default()
    }
    .rows();
    let det = m[0][0] * m[1][1] - m[0][1] * m[1][0];
    let inv = [
        [m[1][1] / det, -m[0][1] / det],
        [-m[1][0] / det, m[0][0] / det],
    ];
    let (dpdu, dpdv) = (t, -bit);
    let map_t = (inv[0][0] * dpdu + inv[1][0] * dpdv).normalize();
    let map_b = -(inv[0][1] * dpdu + inv[1][1] * dpdv).normalize();
    let n = (map_t * ts.x + map_b * ts.y + nrm * ts.z).normalize();
    let expected = 0.5 / PI as f64 * 2.0 * PI as f64 * n.dot(to_light).max(0.0) as f64;
    (scene, expected)
}

#[test]
fn gpu_normal_map_tilts_shading_as_gltf_specifies() {
    let (sa, ca) = (TILT_DEG.to_radians().sin(), TILT_DEG.to_radians().cos());
    let red = Vec3::new(sa, 0.0, ca); // toward the tangent (+U)
    let green = Vec3::new(0.0, sa, ca); // toward the bitangent (image up, -V)
    let cases = [
        NormalCase {
            name: "no-map",
            map: None,
            normal_scale: None,
            file_tangents: false,
            mirrored: false,
            light_azimuth_deg: 0.0,
            rotation_deg: 0.0,
        },
        NormalCase {
            name: "red-generated",
            map: Some(red),
            normal_scale: None,
            file_tangents: false,
            mirrored: false,
            light_azimuth_deg: 0.0,
            rotation_deg: 0.0,
        },
        // Green tilts toward -Z (image up is -V): with the light there the plane brightens;
        // a flipped green channel or bitangent sign would turn it away (cos < 0: black).
        NormalCase {
            name: "green-generated",
            map: Some(green),
            normal_scale: None,
            file_tangents: false,
            mirrored: false,
            light_azimuth_deg: -90.0,
            rotation_deg: 0.0,
        },
        NormalCase {
            name: "green-scale-half",
            map: Some(green),
            normal_scale: Some(0.5),
            file_tangents: false,
            mirrored: false,
            light_azimuth_deg: -90.0,
            rotation_deg: 0.0,
        },
        NormalCase {
            name: "red-file-tangents",
            map: Some(red),
            normal_scale: None,
            file_tangents: true,
            mirrored: false,
            light_azimuth_deg: 0.0,
            rotation_deg: 0.0,
        },
        // Mirrored node: the tangent turns to -X and its sign to -1; the red tilt follows.
        NormalCase {
            name: "red-file-tangents-mirrored",
            map: Some(red),
            normal_scale: None,
            file_tangents: true,
            mirrored: true,
            light_azimuth_deg: 180.0,
            rotation_deg: 0.0,
        },
        NormalCase {
            name: "green-generated-mirrored",
            map: Some(green),
            normal_scale: None,
            file_tangents: false,
            mirrored: true,
            light_azimuth_deg: -90.0,
            rotation_deg: 0.0,
        },
        // Rotated 90 degrees: the red tilt's +X now follows dP/du' = +Z (u' = v): the light at
        // +Z brightens the plane; a map read in the unrotated frame would tilt toward +X.
        NormalCase {
            name: "red-rotated-90",
            map: Some(red),
            normal_scale: None,
            file_tangents: false,
            mirrored: false,
            light_azimuth_deg: 90.0,
            rotation_deg: 90.0,
        },
        NormalCase {
            name: "green-rotated-30",
            map: Some(green),
            normal_scale: None,
            file_tangents: false,
            mirrored: false,
            light_azimuth_deg: -60.0,
            rotation_deg: 30.0,
        },
    ];
    let mut report = Vec::new();
    let mut failures = Vec::new();
    for c in &cases {
        let (scene, expected) = normal_scene(c);
        if c.map.is_some() {
            assert_eq!(scene.tangents.len(), scene.positions.len(), "{}", c.name);
        }
        let img = render(scene, 16, 4);
        let got = img.mean()[1];
        let err = (got - expected).abs() / expected;
        report.push(format!(
            "{}: {got:.4} vs analytic {expected:.4} ({:+.2}%)",
            c.name,
            (got / expected - 1.0) * 100.0
        ));
        if err > 0.01 {
            failures.push(c.name);
        }
    }
    eprintln!(
        "normal mapping at {ELEVATION_DEG} degrees elevation, {TILT_DEG} degrees tilt:\n  {}",
        report.join("\n  ")
    );
    assert!(
        failures.is_empty(),
        "cases off by more than 1%: {failures:?}\n{}",
        report.join("\n")
    );
}

// ---------------------------------------------------------------------------------------------
// b. Alpha mask: holes let shadow rays and camera rays through.

/// 64x64 alpha texture of 16x16 cells of 4 texels; cell (i, j) is a hole (alpha 0.3) when
/// both are even, else covered (alpha 0.7): hole fraction 1/4. Row 0 is v = 0.
fn checker_alpha() -> Vec<u8> {
    let mut px = Vec::new();
    for y in 0..64u32 {
        for x in 0..64u32 {
            let hole = (x / 4) % 2 == 0 && (y / 4) % 2 == 0;
            px.extend([255, 255, 255, if hole { 77 } else { 179 }]);
        }
    }
    px
}

/// Whether the masked quad (y = 1, x and z in [-2, 2], u = (x + 2) / 4, v = (z + 2) / 4) has a
/// hole at (x, z): cell i = floor(16 u), j = floor(16 v).
fn hole_at(x: f32, z: f32) -> bool {
    let i = ((x + 2.0) * 4.0).floor() as i32;
    let j = ((z + 2.0) * 4.0).floor() as i32;
    i % 2 == 0 && j % 2 == 0
}

/// The fraction of the floor under the camera (x, z in [-0.5, 0.5]) lit through the holes when
/// the alpha texture is filtered bilinearly (texel centres at half-integers, alpha quantised
/// to 8 bits as in the file) and thresholded at 0.5.
fn lit_fraction_bilinear() -> f64 {
    let alpha = |tx: i32, ty: i32| {
        let hole = (tx.rem_euclid(64) / 4) % 2 == 0 && (ty.rem_euclid(64) / 4) % 2 == 0;
        if hole {
            77.0 / 255.0
        } else {
            179.0 / 255.0
        }
    };
    let n = 1024;
    let mut lit = 0usize;
    for j in 0..n {
        for i in 0..n {
            let x = -0.5 + (i as f32 + 0.5) / n as f32;
            let z = -0.5 + (j as f32 + 0.5) / n as f32;
            let (cx, cy) = ((x + 2.0) * 16.0 - 0.5, (z + 2.0) * 16.0 - 0.5);
            let (x0, y0) = (cx.floor(), cy.floor());
            let (fx, fy) = (cx - x0, cy - y0);
            let (x0, y0) = (x0 as i32, y0 as i32);
            let a = (1.0 - fx) * (1.0 - fy) * alpha(x0, y0)
                + fx * (1.0 - fy) * alpha(x0 + 1, y0)
                + (1.0 - fx) * fy * alpha(x0, y0 + 1)
                + fx * fy * alpha(x0 + 1, y0 + 1);
            lit += (a < 0.5) as usize;
        }
    }
    lit as f64 / (n * n) as f64
}

/// Distance (in metres) from (x, z) to the nearest cell edge of the quad's pattern.
fn edge_distance(x: f32, z: f32) -> f32 {
    let d = |c: f32| {
        let f = ((c + 2.0) * 4.0).fract();
        f.min(1.0 - f) / 4.0
    };
    d(x).min(d(z))
}

/// The masked quad (and optionally a floor under it), a directional light straight down of
/// irradiance 2 pi, the camera at `camera_y` looking down with a 90-degree field of view.
fn alpha_scene(
    name: &str,
    mode: Option<&'static str>,
    cutoff: Option<f32>,
    floor: bool,
    camera_y: f32,
) -> Scene {
    let mut b = GltfBuilder::new();
    let t = b.texture_rgba8(64, 64, &checker_alpha());
    let mask = b.material(&MaterialDesc {
        base_color_texture: Some(tex(t)),
        alpha_mode: mode,
        alpha_cutoff: cutoff,
        double_sided: true,
        ..lambert("mask", 0.5)
    });
    let quad = b.mesh(
        &MeshData::quad_xz(2.0, 1.0, |x, z| Vec2::new((x + 2.0) / 4.0, (z + 2.0) / 4.0)),
        Some(mask),
    );
    b.node(quad, Place::IDENTITY);
    if floor {
        let f = b.material(&lambert("floor", 0.5));
        let m = b.mesh(&MeshData::quad_xz(10.0, 0.0, Vec2::new), Some(f));
        b.node(m, Place::IDENTITY);
    }
    b.directional_light(Vec3::NEG_Y, [1.0; 3], 2.0 * PI);
    b.camera(
        Vec3::new(0.0, camera_y, 0.0),
        Vec3::new(0.0, -10.0, 0.0),
        Vec3::NEG_Z,
        90.0,
    );
    let path = b.write(&dir(&format!("alpha-{name}")), "scene");
    gltf_load::load(&path).unwrap()
}

#[test]
fn gpu_alpha_mask_lets_shadow_rays_through_its_holes() {
    const N: u32 = 32;
    // Camera between the quad (y = 1) and the floor (y = 0), 0.5 m above the floor: it sees
    // x, z in [-0.5, 0.5], 4 x 4 cells of 0.25 m of which 4 are holes.
    let mut report = Vec::new();
    for (name, mode, cutoff, passes) in [
        ("mask", Some("MASK"), None, true),
        ("blend-as-mask", Some("BLEND"), None, true),
        ("mask-cutoff-0.2", Some("MASK"), Some(0.2), false),
        ("opaque", None, None, false),
    ] {
        let scene = alpha_scene(name, mode, cutoff, true, 0.5);
        let expected_mode = match mode {
            Some("MASK") => AlphaMode::Mask,
            Some("BLEND") => AlphaMode::Blend,
            _ => AlphaMode::Opaque,
        };
        assert_eq!(scene.materials[0].alpha_mode, expected_mode);
        let img = render(scene, N, 16);
        let unoccluded = 1.0; // albedo / pi x E
        let (nearest, bilinear) = if passes {
            (0.25, lit_fraction_bilinear())
        } else {
            (0.0, 0.0)
        };
        let mean = img.mean()[1];
        report.push(format!(
            "{name}: floor mean {mean:.4}; (1 - coverage) x unoccluded {unoccluded}: {:.4} with the \
             holes' corners rounded by bilinear filtering, {:.4} with square holes",
            bilinear * unoccluded,
            nearest * unoccluded
        ));
        // Bilinear filtering (what the renderer does) rounds each hole's corners: a corner
        // texel of alpha 0.3 among three of 0.7 interpolates to 0.6 at the corner, so 2.4% of
        // the hole area is lost; 16 spp leave about 0.001 of noise at those corners.
        assert!(
            (mean - bilinear * unoccluded).abs() < 0.004,
            "{name}: floor mean {mean:.4} vs (1 - coverage) x unoccluded = {:.4} (square holes: {:.4})",
            bilinear * unoccluded,
            nearest * unoccluded
        );
        // Per pixel: lit exactly under the holes (light straight down), black elsewhere.
        let mut wrong = Vec::new();
        for y in 0..N {
            for x in 0..N {
                let p = plane_point(x as f32 + 0.5, y as f32 + 0.5, N, 0.5, 90.0);
                if edge_distance(p.x, p.y) < 0.5 / N as f32 * 1.5 {
                    continue;
                }
                let lit = passes && hole_at(p.x, p.y);
                let v = img.pixel(x, y)[1];
                let ok = if lit {
                    (v - 1.0).abs() < 0.02
                } else {
                    v < 0.01
                };
                if !ok {
                    wrong.push((x, y, v, lit));
                }
            }
        }
        assert!(
            wrong.is_empty(),
            "{name}: pixels off the shadow pattern (x, y, value, lit expected): {wrong:?}"
        );
    }
    eprintln!("alpha mask, shadow rays:\n  {}", report.join("\n  "));
}

#[test]
fn gpu_alpha_mask_lets_camera_rays_through_its_holes() {
    const N: u32 = 32;
    const SKY: f32 = 0.2;
    // Camera 0.5 m above the quad, no floor: holes show the sky, the quad shows its lit top
    // (albedo / pi x E = 1, plus albedo x sky = 0.1 of skylight: nothing is above it).
    let mut report = Vec::new();
    for (name, mode, passes) in [("mask", Some("MASK"), true), ("opaque", None, false)] {
        let mut scene = alpha_scene(&format!("camera-{name}"), mode, None, false, 1.5);
        scene.sky = Vec3::splat(SKY);
        let img = render(scene, N, 8);
        let (mut holes, mut quad, mut wrong) = (0, 0, Vec::new());
        let (mut lo, mut hi) = (f32::MAX, f32::MIN);
        for y in 0..N {
            for x in 0..N {
                let p = plane_point(x as f32 + 0.5, y as f32 + 0.5, N, 0.5, 90.0);
                if edge_distance(p.x, p.y) < 0.5 / N as f32 * 1.5 {
                    continue;
                }
                let v = img.pixel(x, y)[1];
                if passes && hole_at(p.x, p.y) {
                    holes += 1;
                    if (v - SKY).abs() > 1e-3 {
                        wrong.push((x, y, v, "sky"));
                    }
                } else {
                    quad += 1;
                    lo = lo.min(v);
                    hi = hi.max(v);
                    if (v - (1.0 + 0.5 * SKY)).abs() > 0.01 {
                        wrong.push((x, y, v, "quad"));
                    }
                }
            }
        }
        report.push(format!(
            "{name}: {holes} hole pixels (sky {SKY}), {quad} quad pixels in [{lo:.4}, {hi:.4}], {} wrong",
            wrong.len()
        ));
        assert!(
            wrong.is_empty(),
            "{name}: (x, y, value, expected): {wrong:?}"
        );
        if passes {
            assert!(
                holes > 100 && quad > 300,
                "{name}: {holes} holes, {quad} quad"
            );
        }
    }
    eprintln!("alpha mask, camera rays:\n  {}", report.join("\n  "));
}

// ---------------------------------------------------------------------------------------------
// c. KHR_texture_transform and TEXCOORD_1.

const TEX: u32 = 16;
/// The marked texels of the test texture: x in [3, 10), y in [2, 8) (rows from the top).
fn marked(tx: i32, ty: i32) -> bool {
    let (tx, ty) = (tx.rem_euclid(TEX as i32), ty.rem_euclid(TEX as i32));
    (3..10).contains(&tx) && (2..8).contains(&ty)
}
const GREY: u8 = 188;
fn marked_texture() -> Vec<u8> {
    let mut px = Vec::new();
    for y in 0..TEX as i32 {
        for x in 0..TEX as i32 {
            px.extend(if marked(x, y) {
                [255, 0, 0, 255]
            } else {
                [GREY, GREY, GREY, 255]
            });
        }
    }
    px
}

/// Which pixels of a camera 2 m above the quad x, z in [-1, 1] (seeing exactly it) are
/// wholly marked (Some(true)), wholly unmarked (Some(false)) or mixed (None), for the
/// quad's UV `uv(x, z)` through `transform`. A pixel's footprint is taken one texel wider on
/// each side (bilinear filtering reaches half a texel).
fn predicted(n: u32, uv: impl Fn(Vec2) -> Vec2, transform: UvTransform) -> Vec<Option<bool>> {
    let fov = 2.0 * 0.5f32.atan().to_degrees();
    let mut out = Vec::new();
    for y in 0..n {
        for x in 0..n {
            let mut lo = Vec2::splat(f32::MAX);
            let mut hi = Vec2::splat(f32::MIN);
            for (dx, dy) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)] {
                let p = plane_point(x as f32 + dx, y as f32 + dy, n, 2.0, fov);
                let t = transform.apply(uv(p)) * TEX as f32;
                lo = lo.min(t);
                hi = hi.max(t);
            }
            let (lo, hi) = (lo - Vec2::ONE, hi + Vec2::ONE);
            let mut any = false;
            let mut all = true;
            for ty in lo.y.floor() as i32..=hi.y.floor() as i32 {
                for tx in lo.x.floor() as i32..=hi.x.floor() as i32 {
                    let m = marked(tx, ty);
                    any |= m;
                    all &= m;
                }
            }
            out.push(if all {
                Some(true)
            } else if !any {
                Some(false)
            } else {
                None
            });
        }
    }
    out
}

/// Compares a render with the prediction: marked pixels are red (green channel under 3% of
/// red), unmarked ones grey (green = red within 3%, at `grey` within 3%). Returns counts.
fn check_marks(name: &str, img: &Image, pred: &[Option<bool>], grey: f32) -> (usize, usize) {
    let (mut m, mut u, mut wrong) = (0, 0, Vec::new());
    for (i, p) in pred.iter().enumerate() {
        let (x, y) = (i as u32 % img.width, i as u32 / img.width);
        let [r, g, _] = img.pixel(x, y);
        match p {
            Some(true) => {
                m += 1;
                if !(r > 0.5 * grey && g < 0.03 * r) {
                    wrong.push((x, y, r, g, "marked"));
                }
            }
            Some(false) => {
                u += 1;
                if !((g - r).abs() < 0.03 * r && (r - grey).abs() < 0.03 * grey) {
                    wrong.push((x, y, r, g, "unmarked"));
                }
            }
            None => {}
        }
    }
    assert!(
        wrong.is_empty(),
        "{name}: {} of {} predicted pixels differ (x, y, r, g, expected): {wrong:?}",
        wrong.len(),
        m + u
    );
    assert!(
        m >= 12 && u >= 100,
        "{name}: too few decided pixels ({m} marked, {u} unmarked)"
    );
    (m, u)
}

struct TransformCase {
    name: &'static str,
    /// Base colour (lit) or emissive (unlit) slot.
    emissive: bool,
    tex_ref: TexRef,
    /// (x, z) -> TEXCOORD_0 and TEXCOORD_1 of the quad.
    uv0: fn(Vec2) -> Vec2,
    uv1: Option<fn(Vec2) -> Vec2>,
}

fn straight(p: Vec2) -> Vec2 {
    (p + Vec2::ONE) * 0.5
}
fn swapped(p: Vec2) -> Vec2 {
    Vec2::new(p.y + 1.0, p.x + 1.0) * 0.5
}
fn constant_grey(_: Vec2) -> Vec2 {
    Vec2::new(0.95, 0.95)
}

#[test]
fn gpu_texture_transform_and_texcoord1_place_the_texture() {
    const N: u32 = 32;
    let cases = [
        TransformCase {
            name: "base-colour-transform",
            emissive: false,
            tex_ref: TexRef {
                texture: 0,
                tex_coord: 0,
                transform: Some(TexTransform {
                    offset: Some([0.3, -0.2]),
                    rotation: Some(0.6),
                    scale: Some([1.2, 0.9]),
                    tex_coord: None,
                }),
            },
            uv0: straight,
            uv1: None,
        },
        // The transform's texCoord overrides the textureInfo's (0): UV set 1 is read.
        TransformCase {
            name: "emissive-transform-texcoord-override",
            emissive: true,
            tex_ref: TexRef {
                texture: 0,
                tex_coord: 0,
                transform: Some(TexTransform {
                    offset: Some([0.1, 0.35]),
                    rotation: Some(-0.4),
                    scale: Some([0.7, 1.1]),
                    tex_coord: Some(1),
                }),
            },
            uv0: constant_grey,
            uv1: Some(swapped),
        },
        TransformCase {
            name: "base-colour-texcoord1",
            emissive: false,
            tex_ref: TexRef {
                texture: 0,
                tex_coord: 1,
                transform: None,
            },
            uv0: constant_grey,
            uv1: Some(swapped),
        },
    ];
    let mut report = Vec::new();
    for c in &cases {
        let mut b = GltfBuilder::new();
        let t = b.texture_rgba8(TEX, TEX, &marked_texture());
        assert_eq!(t, 0);
        let mat = if c.emissive {
            MaterialDesc {
                emissive: Some([1.0; 3]),
                emissive_texture: Some(c.tex_ref),
                ..lambert("quad", 0.0)
            }
        } else {
            MaterialDesc {
                base_color_texture: Some(c.tex_ref),
                ..lambert("quad", 1.0)
            }
        };
        let m = b.material(&mat);
        let mut quad = MeshData::quad_xz(1.0, 0.0, |x, z| (c.uv0)(Vec2::new(x, z)));
        if let Some(uv1) = c.uv1 {
            quad.uv1 = Some(
                quad.positions
                    .iter()
                    .map(|p| uv1(Vec2::new(p.x, p.z)))
                    .collect(),
            );
        }
        let mesh = b.mesh(&quad, Some(m));
        b.node(mesh, Place::IDENTITY);
        if !c.emissive {
            // Irradiance pi straight down: radiance = linear base colour.
            b.directional_light(Vec3::NEG_Y, [1.0; 3], PI);
        }
        let fov = 2.0 * 0.5f32.atan().to_degrees();
        b.camera(Vec3::new(0.0, 2.0, 0.0), Vec3::ZERO, Vec3::NEG_Z, fov);
        let scene = gltf_load::load(&b.write(&dir(c.name), "scene")).unwrap();
        let m = &scene.materials[0];
        let r = if c.emissive {
            m.emissive_texture
        } else {
            m.base_color_texture
        }
        .unwrap();
        let set = r.tex_coord;
        let uv_of = if set == 1 { c.uv1.unwrap() } else { c.uv0 };
        let pred = predicted(N, uv_of, r.transform);
        let img = render(scene, N, 2);
        let (mk, un) = check_marks(c.name, &img, &pred, srgb_to_linear(GREY));
        report.push(format!(
            "{}: UV set {set}, {mk} marked and {un} unmarked pixels as predicted",
            c.name
        ));
    }
    eprintln!("texture transform:\n  {}", report.join("\n  "));
}

/// glTF samplers: a 4 x 4 emissive texture on a quad whose UVs run from -0.75 to 2.25, read
/// with each wrap mode (repeat, clamp to edge, mirrored repeat; u and v differently) and with
/// magFilter NEAREST. Every pixel matches a CPU model of the sampler averaged over the pixel;
/// the same model with the wrong mode misses by far, so the test tells the modes apart.
#[test]
fn gpu_samplers_wrap_and_filter_as_gltf_specifies() {
    const N: u32 = 32;
    const REPEAT: u32 = 10497;
    const CLAMP: u32 = 33071;
    const MIRROR: u32 = 33648;
    let (r_bytes, g_bytes) = ([40u8, 100, 170, 250], [30u8, 90, 160, 240]);
    let mut rgba = Vec::new();
    for g in g_bytes {
        for r in r_bytes {
            rgba.extend([r, g, 0, 255]);
        }
    }
    let uv_of = |p: Vec2| (p + Vec2::ONE) * 1.5 - Vec2::splat(0.75);
    // The sampler's model: wrap codes 0 repeat, 1 clamp, 2 mirror (as the shader).
    let wrap = |i: i32, mode: u32| -> usize {
        let n = 4;
        (match mode {
            0 => i.rem_euclid(n),
            1 => i.clamp(0, n - 1),
            _ => {
                let p = i.rem_euclid(2 * n);
                if p >= n {
                    2 * n - 1 - p
                } else {
                    p
                }
            }
        }) as usize
    };
    let sample = |uv: Vec2, mu: u32, mv: u32, nearest: bool| -> Vec2 {
        let p = uv * 4.0 - Vec2::splat(0.5);
        let f = p.floor();
        let mut s = p - f;
        if nearest {
            s = Vec2::new((s.x >= 0.5) as u32 as f32, (s.y >= 0.5) as u32 as f32);
        }
        let texel = |dx: i32, dy: i32| {
            let (x, y) = (wrap(f.x as i32 + dx, mu), wrap(f.y as i32 + dy, mv));
            Vec2::new(srgb_to_linear(r_bytes[x]), srgb_to_linear(g_bytes[y]))
        };
        let a = texel(0, 0).lerp(texel(1, 0), s.x);
        let b = texel(0, 1).lerp(texel(1, 1), s.x);
        a.lerp(b, s.y)
    };
    let fov = 2.0 * 0.5f32.atan().to_degrees();
    // The model over a pixel (the renderer jitters camera rays within it): its mean, and the
    // standard deviation of the mean of SPP jittered samples (large where a seam or texel
    // edge crosses the pixel).
    const SPP: u32 = 32;
    let expected = |x: u32, y: u32, mu: u32, mv: u32, nearest: bool| -> (Vec2, f32) {
        let (mut sum, mut sum2) = (Vec2::ZERO, Vec2::ZERO);
        for j in 0..8 {
            for i in 0..8 {
                let (px, py) = (
                    x as f32 + (i as f32 + 0.5) / 8.0,
                    y as f32 + (j as f32 + 0.5) / 8.0,
                );
                let v = sample(uv_of(plane_point(px, py, N, 2.0, fov)), mu, mv, nearest);
                sum += v;
                sum2 += v * v;
            }
        }
        let mean = sum / 64.0;
        let var = (sum2 / 64.0 - mean * mean).max(Vec2::ZERO);
        (mean, (var.max_element() / SPP as f32).sqrt())
    };
    let mut report = Vec::new();
    for (name, s, t, mag, (mu, mv, nearest), wrong) in [
        ("repeat", REPEAT, REPEAT, None, (0, 0, false), (1, 1, false)),
        (
            "clamp-u-mirror-v",
            CLAMP,
            MIRROR,
            None,
            (1, 2, false),
            (0, 0, false),
        ),
        (
            "mirror-u-clamp-v",
            MIRROR,
            CLAMP,
            None,
            (2, 1, false),
            (1, 2, false),
        ),
        (
            "repeat-nearest",
            REPEAT,
            REPEAT,
            Some(9728),
            (0, 0, true),
            (0, 0, false),
        ),
    ] {
        let mut b = GltfBuilder::new();
        let tex = b.texture_rgba8(4, 4, &rgba);
        b.sampler(tex, s, t, mag);
        let m = b.material(&MaterialDesc {
            emissive: Some([1.0; 3]),
            emissive_texture: Some(TexRef {
                texture: tex,
                tex_coord: 0,
                transform: None,
            }),
            ..lambert("quad", 0.0)
        });
        let quad = MeshData::quad_xz(1.0, 0.0, |x, z| uv_of(Vec2::new(x, z)));
        let mesh = b.mesh(&quad, Some(m));
        b.node(mesh, Place::IDENTITY);
        b.camera(Vec3::new(0.0, 2.0, 0.0), Vec3::ZERO, Vec3::NEG_Z, fov);
        let scene = gltf_load::load(&b.write(&dir(&format!("sampler-{name}")), "scene")).unwrap();
        let img = render(scene, N, SPP);
        // Worst error in units of the pixel's tolerance: 0.01 plus 4 sigma of jitter noise.
        let (mut worst, mut worst_wrong_mode) = (0.0f32, 0.0f32);
        for y in 0..N {
            for x in 0..N {
                let [r, g, _] = img.pixel(x, y);
                let got = Vec2::new(r, g);
                let (e, sigma) = expected(x, y, mu, mv, nearest);
                let tolerance = 0.01 + 4.0 * sigma;
                worst = worst.max((got - e).abs().max_element() / tolerance);
                let (other, sigma) = expected(x, y, wrong.0, wrong.1, wrong.2);
                let tolerance = 0.01 + 4.0 * sigma;
                worst_wrong_mode =
                    worst_wrong_mode.max((got - other).abs().max_element() / tolerance);
            }
        }
        report.push(format!(
            "{name}: worst pixel at {worst:.2} x its tolerance (the model with the wrong mode: {worst_wrong_mode:.1} x)"
        ));
        assert!(
            worst < 1.0,
            "{name}: a pixel is off the sampler model ({worst:.2} x tolerance)"
        );
        assert!(
            worst_wrong_mode > 3.0,
            "{name}: the wrong mode fits too ({worst_wrong_mode:.2} x)"
        );
    }
    eprintln!("samplers:\n  {}", report.join("\n  "));
}

// ---------------------------------------------------------------------------------------------
// d. The loader alone (no GPU).

/// The KHR_texture_transform README's examples: offset (0, 1), rotation pi/2, scale 0.5 "uses
/// only the lower left quadrant of the source image, rotated clockwise 90 degrees"; offset
/// (0, 1), scale (1, -1) "inverts the T axis".
#[test]
fn loader_uv_transform_follows_the_extension_examples() {
    let t = UvTransform {
        offset: Vec2::new(0.0, 1.0),
        rotation: FRAC_PI_2,
        scale: Vec2::splat(0.5),
    };
    for uv in [Vec2::ZERO, Vec2::X, Vec2::Y, Vec2::ONE, Vec2::splat(0.5)] {
        let o = t.apply(uv);
        assert!(
            (-1e-6..=0.5 + 1e-6).contains(&o.x) && (0.5 - 1e-6..=1.0 + 1e-6).contains(&o.y),
            "{uv} -> {o}: outside the lower left quadrant"
        );
    }
    // Clockwise in the image (v down): the top edge (v = 0) of the quad ends on the left.
    assert!((t.apply(Vec2::ZERO) - Vec2::new(0.0, 1.0)).length() < 1e-6);
    assert!((t.apply(Vec2::X) - Vec2::new(0.0, 0.5)).length() < 1e-6);
    let flip = UvTransform {
        offset: Vec2::new(0.0, 1.0),
        rotation: 0.0,
        scale: Vec2::new(1.0, -1.0),
    };
    assert!((flip.apply(Vec2::new(0.25, 0.2)) - Vec2::new(0.25, 0.8)).length() < 1e-6);
}

/// Every material field the loader reads, from a written file.
#[test]
fn loader_reads_every_material_field() {
    capture_logs();
    let mut b = GltfBuilder::new();
    let base = b.texture_rgba8(2, 2, &solid_rgba8(2, 2, [10, 20, 30, 40]));
    let mr = b.texture_rgba8(2, 2, &solid_rgba8(2, 2, [0, 128, 255, 255]));
    let normal = b.texture_rgba8(2, 2, &solid_rgba8(2, 2, [128, 128, 255, 255]));
    let emissive = b.texture_rgba8(2, 2, &solid_rgba8(2, 2, [255, 255, 255, 255]));
    let occlusion = b.texture_rgba8(2, 2, &solid_rgba8(2, 2, [200, 0, 0, 255]));
    // 16-bit PNG: converted to 8 bits (0x8080 -> 128, 0xffff -> 255, 0x0101 -> 1).
    let deep = b.texture_rgba16(1, 2, &[0x8080, 0xffff, 0x0101, 0xffff, 0, 0, 0, 0x8000]);
    let full = MaterialDesc {
        name: "full".into(),
        base_color: Some([0.9, 0.8, 0.7, 0.6]),
        base_color_texture: Some(TexRef {
            texture: base,
            tex_coord: 1,
            transform: Some(TexTransform {
                offset: Some([0.25, 0.5]),
                rotation: Some(0.3),
                scale: Some([2.0, 3.0]),
                tex_coord: None,
            }),
        }),
        metallic: Some(0.4),
        roughness: Some(0.6),
        metallic_roughness_texture: Some(TexRef {
            texture: mr,
            tex_coord: 0,
            transform: Some(TexTransform {
                tex_coord: Some(1),
                ..Default::default()
            }),
        }),
        normal_texture: Some(TexRef {
            texture: normal,
            tex_coord: 0,
            transform: Some(TexTransform {
                offset: Some([0.1, 0.2]),
                rotation: Some(-0.5),
                scale: Some([4.0, 4.0]),
                tex_coord: None,
            }),
        }),
        normal_scale: Some(0.7),
        occlusion_texture: Some(TexRef {
            texture: occlusion,
            tex_coord: 1,
            transform: Some(TexTransform {
                rotation: Some(0.5),
                ..Default::default()
            }),
        }),
        occlusion_strength: Some(0.6),
        emissive: Some([1.0, 0.5, 0.25]),
        emissive_texture: Some(tex(emissive)),
        emissive_strength: Some(4.0),
        alpha_mode: Some("MASK"),
        alpha_cutoff: Some(0.3),
        double_sided: true,
        ior: Some(1.33),
        specular: Some(0.5),
    };
    let full_idx = b.material(&full);
    let blend = b.material(&MaterialDesc {
        name: "blend".into(),
        alpha_mode: Some("BLEND"),
        base_color_texture: Some(tex(deep)),
        ..Default::default()
    });
    // TEXCOORD_2 is not read: the texture is dropped with a warning, the rest kept.
    let set2 = b.material(&MaterialDesc {
        name: "set2".into(),
        base_color_texture: Some(TexRef {
            texture: base,
            tex_coord: 2,
            transform: None,
        }),
        normal_texture: Some(TexRef {
            texture: normal,
            tex_coord: 0,
            transform: Some(TexTransform {
                tex_coord: Some(2),
                ..Default::default()
            }),
        }),
        roughness: Some(0.25),
        ..Default::default()
    });
    let mut with_uv1 = MeshData::quad_xz(1.0, 0.0, Vec2::new);
    with_uv1.uv1 = Some(vec![
        Vec2::new(0.1, 0.2),
        Vec2::new(0.3, 0.4),
        Vec2::new(0.5, 0.6),
        Vec2::new(0.7, 0.8),
    ]);
    let m0 = b.mesh(&with_uv1, Some(full_idx));
    let m1 = b.mesh(&MeshData::quad_xz(1.0, 1.0, Vec2::new), Some(blend));
    let m2 = b.mesh(&MeshData::quad_xz(1.0, 2.0, Vec2::new), Some(set2));
    b.node(m0, Place::IDENTITY);
    b.node(m1, Place::IDENTITY);
    b.node(m2, Place::IDENTITY);
    b.point_light(Vec3::new(0.0, 5.0, 0.0), [1.0; 3], 10.0);
    let path = b.write(&dir("fields"), "scene");
    let s = gltf_load::load(&path).unwrap();

    let m = &s.materials[full_idx];
    assert_eq!(m.name, "full");
    assert_eq!(m.base_color, Vec4::new(0.9, 0.8, 0.7, 0.6));
    let bt = m.base_color_texture.unwrap();
    assert_eq!(bt.texture, base);
    assert_eq!(bt.tex_coord, 1);
    assert_eq!(
        bt.transform,
        UvTransform {
            offset: Vec2::new(0.25, 0.5),
            rotation: 0.3,
            scale: Vec2::new(2.0, 3.0)
        }
    );
    assert_eq!((m.metallic, m.roughness), (0.4, 0.6));
    let mrt = m.metallic_roughness_texture.unwrap();
    assert_eq!((mrt.texture, mrt.tex_coord), (mr, 1), "texCoord override");
    assert_eq!(mrt.transform, UvTransform::default());
    let nt = m.normal_texture.unwrap();
    assert_eq!((nt.texture, nt.tex_coord), (normal, 0));
    assert_eq!(
        nt.transform,
        UvTransform {
            offset: Vec2::new(0.1, 0.2),
            rotation: -0.5,
            scale: Vec2::splat(4.0)
        },
        "normalTexture's KHR_texture_transform"
    );
    assert_eq!(m.normal_scale, 0.7);
    let ot = m.occlusion_texture.unwrap();
    assert_eq!(
        (ot.texture, ot.tex_coord, ot.transform.rotation),
        (occlusion, 1, 0.5)
    );
    assert_eq!(m.occlusion_strength, 0.6);
    assert_eq!(m.emissive, Vec3::new(4.0, 2.0, 1.0), "emissive x strength");
    assert_eq!(m.emissive_texture, Some(TextureRef::new(emissive)));
    assert_eq!((m.alpha_mode, m.alpha_cutoff), (AlphaMode::Mask, 0.3));
    assert!(m.alpha_tested() && m.double_sided);
    assert_eq!((m.ior, m.specular), (1.33, 0.5));

    let bl = &s.materials[blend];
    assert_eq!((bl.alpha_mode, bl.alpha_cutoff), (AlphaMode::Blend, 0.5));
    assert!(bl.alpha_tested());
    assert_eq!(
        (bl.ior, bl.specular, bl.normal_scale, bl.occlusion_strength),
        (1.5, 1.0, 1.0, 1.0)
    );
    let d = &s.textures[bl.base_color_texture.unwrap().texture];
    assert_eq!((d.width, d.height), (1, 2));
    assert_eq!(
        d.rgba8,
        vec![128, 255, 1, 255, 0, 0, 0, 128],
        "16-bit texture to 8 bits"
    );
    assert_eq!(s.textures[base].rgba8[..4], [10, 20, 30, 40]);

    let s2 = &s.materials[set2];
    assert!(s2.base_color_texture.is_none() && s2.normal_texture.is_none());
    assert_eq!(s2.roughness, 0.25);
    let file = path.display().to_string();
    let w = warnings_with(&file);
    assert!(
        w.iter().filter(|w| w.contains("TEXCOORD_2")).count() == 2,
        "warnings about TEXCOORD_2: {w:#?}"
    );

    // UV set 1 materialised for all vertices: the quad's values, zero for the others.
    assert_eq!(s.uvs1.len(), s.positions.len());
    let full_verts: Vec<usize> = s
        .triangles
        .iter()
        .zip(&s.triangle_material)
        .filter(|(_, &m)| m as usize == full_idx)
        .flat_map(|(t, _)| t.map(|i| i as usize))
        .collect();
    assert_eq!(full_verts.len(), 6);
    for &v in &full_verts {
        let k = with_uv1
            .positions
            .iter()
            .position(|p| (*p - s.positions[v]).length() < 1e-6)
            .unwrap();
        assert_eq!(s.uvs1[v], with_uv1.uv1.as_ref().unwrap()[k]);
    }
    for v in 0..s.positions.len() {
        if !full_verts.contains(&v) {
            assert_eq!(s.uvs1[v], Vec2::ZERO);
        }
    }
    // Generated tangents (no TANGENT in the file) for the normal-mapped quad only: u = x,
    // v = z gives tangent +X, sign +1.
    assert_eq!(s.tangents.len(), s.positions.len());
    for v in 0..s.positions.len() {
        if full_verts.contains(&v) {
            assert!(
                (s.tangents[v] - Vec4::new(1.0, 0.0, 0.0, 1.0)).length() < 1e-5,
                "{}",
                s.tangents[v]
            );
        } else {
            assert_eq!(s.tangents[v], Vec4::ZERO);
        }
    }
}

/// TANGENT from the file is transformed by the node (sign flipped by a mirror); generated
/// tangents agree with the file's on the same geometry; a rotated node turns them.
#[test]
fn loader_tangents_from_file_and_generated_agree() {
    let build = |file_tangents: bool, place: Place, name: &str| {
        let mut b = GltfBuilder::new();
        let n = b.texture_rgba8(1, 1, &[128, 128, 255, 255]);
        let m = b.material(&MaterialDesc {
            normal_texture: Some(tex(n)),
            ..lambert("m", 0.5)
        });
        let mut q = MeshData::quad_xz(1.0, 0.0, Vec2::new);
        if file_tangents {
            q.tangents = Some(vec![Vec4::new(2.0, 0.0, 0.0, 1.0); 4]); // normalised on load
        }
        let mesh = b.mesh(&q, Some(m));
        b.node(mesh, place);
        b.point_light(Vec3::Y, [1.0; 3], 1.0);
        gltf_load::load(&b.write(&dir(&format!("tangents-{name}")), "scene")).unwrap()
    };
    let mirror = Place::Trs(Vec3::ZERO, Quat::IDENTITY, Vec3::new(-1.0, 1.0, 1.0));
    let turn = Place::Trs(Vec3::ZERO, Quat::from_rotation_y(FRAC_PI_2), Vec3::ONE);
    for (place, name, expected) in [
        (Place::IDENTITY, "plain", Vec4::new(1.0, 0.0, 0.0, 1.0)),
        (mirror, "mirror", Vec4::new(-1.0, 0.0, 0.0, -1.0)),
        // Rotation by +90 degrees about Y takes +X to -Z.
        (turn, "turn", Vec4::new(0.0, 0.0, -1.0, 1.0)),
    ] {
        for file in [true, false] {
            let s = build(file, place, &format!("{name}-{file}"));
            assert_eq!(s.tangents.len(), s.positions.len());
            for (i, t) in s.tangents.iter().enumerate() {
                assert!(
                    (*t - expected).length() < 1e-5,
                    "{name}, tangents from the file: {file}: vertex {i}: {t} vs {expected}"
                );
                // The bitangent stays along -Z x the rotation (image up = -V = -Z here).
                let n = s.normals[i];
                assert!((n - Vec3::Y).length() < 1e-5);
            }
            // Winding stays front-facing toward +Y under the mirror.
            let [a, b, c] = s.triangles[0].map(|i| s.positions[i as usize]);
            assert!((b - a).cross(c - a).y > 0.0, "{name}: winding");
        }
    }
}

/// EXT_mesh_gpu_instancing (required by the file): every instance is a copy of the mesh at
/// node x instance(T, R, S); ROTATION as normalized shorts too. A malformed one draws the mesh
/// once with a warning.
#[test]
fn loader_reads_mesh_instancing_as_instances() {
    capture_logs();
    let tri = MeshData {
        positions: vec![Vec3::ZERO, Vec3::X, Vec3::Z],
        normals: Some(vec![Vec3::Y; 3]),
        uv0: Some(vec![Vec2::ZERO, Vec2::X, Vec2::Y]),
        ..Default::default()
    };
    let translations = [
        Vec3::ZERO,
        Vec3::new(1.0, 0.0, 0.0),
        Vec3::new(0.0, 2.0, 0.0),
    ];
    let rotations = [
        Quat::IDENTITY,
        Quat::from_rotation_y(FRAC_PI_2),
        Quat::from_rotation_x(0.3),
    ];
    let scales = [Vec3::ONE, Vec3::splat(2.0), Vec3::new(1.0, 1.0, 3.0)];
    let node = Place::Trs(Vec3::new(10.0, 0.0, 0.0), Quat::IDENTITY, Vec3::ONE);
    for snorm in [false, true] {
        let mut b = GltfBuilder::new();
        let m = b.material(&lambert("m", 0.5));
        let mesh = b.mesh(&tri, Some(m));
        b.instanced_node(
            mesh,
            node,
            Some(&translations),
            Some(&rotations),
            Some(&scales),
            snorm,
        );
        b.point_light(Vec3::Y, [1.0; 3], 1.0);
        let path = b.write(&dir(&format!("instancing-{snorm}")), "scene");
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.contains("extensionsRequired"));
        let s = gltf_load::load(&path).unwrap();
        assert_eq!(s.triangles.len(), 3, "one triangle per instance");
        assert_eq!(
            s.instances.len(),
            3,
            "each placement a MeshInstance of one mesh"
        );
        for (k, t) in s.triangles.iter().enumerate() {
            let inst = Mat4::from_translation(Vec3::new(10.0, 0.0, 0.0))
                * Mat4::from_scale_rotation_translation(scales[k], rotations[k], translations[k]);
            let i = &s.instances[k];
            assert_eq!(
                (i.mesh, i.first_triangle, i.triangle_count),
                (0, k as u32, 1)
            );
            assert!(
                i.transform.abs_diff_eq(inst, 2e-4 * 12.0),
                "{} vs {inst}",
                i.transform
            );
            for (c, &v) in t.iter().enumerate() {
                let want = inst.transform_point3(tri.positions[c]);
                let got = s.positions[v as usize];
                let tol = if snorm { 2e-4 } else { 1e-5 } * want.length().max(1.0);
                assert!(
                    (got - want).length() < tol,
                    "snorm {snorm}: instance {k} corner {c}: {got} vs {want}"
                );
            }
        }
    }
    // Counts that differ: drawn once, at the node.
    let mut b = GltfBuilder::new();
    let m = b.material(&lambert("m", 0.5));
    let mesh = b.mesh(&tri, Some(m));
    b.instanced_node(
        mesh,
        node,
        Some(&translations),
        Some(&rotations[..2]),
        None,
        false,
    );
    b.point_light(Vec3::Y, [1.0; 3], 1.0);
    let path = b.write(&dir("instancing-bad"), "scene");
    let s = gltf_load::load(&path).unwrap();
    assert_eq!(s.triangles.len(), 1);
    assert!((s.positions[s.triangles[0][1] as usize] - Vec3::new(11.0, 0.0, 0.0)).length() < 1e-6);
    let w = warnings_with(&path.display().to_string());
    assert!(
        w.iter().any(|w| w.contains("EXT_mesh_gpu_instancing")),
        "{w:#?}"
    );
}

/// A 2 m quad on y = 0 whose material reads `texture` as base colour, under a point light.
fn lit_textured_quad(b: &mut GltfBuilder, texture: usize) {
    let m = b.material(&MaterialDesc {
        base_color_texture: Some(tex(texture)),
        ..lambert("m", 0.5)
    });
    let mesh = b.mesh(&MeshData::quad_xz(1.0, 0.0, Vec2::new), Some(m));
    b.node(mesh, Place::IDENTITY);
    b.point_light(Vec3::Y, [1.0; 3], 1.0);
}

/// An unknown required extension refuses the file naming it; an unknown used one and a
/// missing image are skipped with warnings naming them.
#[test]
fn loader_refuses_unknown_required_extensions_and_skips_missing_images() {
    capture_logs();
    let build = || {
        let mut b = GltfBuilder::new();
        let t = b.texture_missing("no-such-image.png");
        lit_textured_quad(&mut b, t);
        b
    };
    let mut b = build();
    b.use_extension("KHR_draco_mesh_compression", true);
    let err = format!(
        "{:#}",
        gltf_load::load(&b.write(&dir("required"), "scene")).unwrap_err()
    );
    assert!(err.contains("KHR_draco_mesh_compression"), "{err}");

    let mut b = build();
    b.use_extension("EXT_not_known_here", false);
    let path = b.write(&dir("missing-image"), "scene");
    let s = gltf_load::load(&path).unwrap();
    assert!(s.textures.is_empty());
    assert!(s.materials[0].base_color_texture.is_none());
    let w = warnings_with(&path.display().to_string());
    assert!(w.iter().any(|w| w.contains("no-such-image.png")), "{w:#?}");
    assert!(w.iter().any(|w| w.contains("EXT_not_known_here")), "{w:#?}");

    // Supported extensions may be required (the gltf crate alone would refuse some of them).
    let mut b = build();
    for e in [
        "KHR_texture_transform",
        "KHR_materials_ior",
        "KHR_materials_specular",
    ] {
        b.use_extension(e, true);
    }
    gltf_load::load(&b.write(&dir("required-supported"), "scene")).unwrap();
}

/// Validation refuses only what the scene needs: an unused texture whose `source` points past
/// the end of `images` (or with no `images` array at all) is dropped with a warning naming it,
/// and the file renders exactly as the same file without that texture; the same fault in a
/// texture a material uses refuses the file, naming the texture.
#[test]
fn loader_drops_invalid_unused_textures_and_refuses_used_ones() {
    capture_logs();
    let folder = dir("unused-invalid");
    let mut b = GltfBuilder::new();
    let t = b.texture_rgba8(2, 2, &solid_rgba8(2, 2, [200, 120, 40, 255]));
    lit_textured_quad(&mut b, t);
    b.camera(Vec3::new(0.0, 2.0, 0.0), Vec3::ZERO, Vec3::NEG_Z, 60.0);
    let clean = b.write(&folder, "clean");
    let broken = b.write_with(&folder, "broken", |j| {
        let bad = serde_json::json!({"name": "stray", "source": 7});
        j["textures"].as_array_mut().unwrap().push(bad);
    });
    let a = gltf_load::load(&clean).unwrap();
    let s = gltf_load::load(&broken).unwrap();
    assert_eq!(a.materials, s.materials);
    assert_eq!(a.textures.len(), s.textures.len());
    let w = warnings_with(&broken.display().to_string());
    assert!(
        w.iter()
            .any(|w| w.contains("textures[1] ('stray')") && w.contains("dropped")),
        "{w:#?}"
    );
    assert_eq!(render(a, 32, 4).rgb, render(s, 32, 4).rgb);

    // No `images` array at all, and an unused texture pointing into it.
    let mut b = GltfBuilder::new();
    let m = b.material(&lambert("plain", 0.5));
    let mesh = b.mesh(&MeshData::quad_xz(1.0, 0.0, Vec2::new), Some(m));
    b.node(mesh, Place::IDENTITY);
    b.point_light(Vec3::Y, [1.0; 3], 1.0);
    let no_images = b.write_with(&folder, "no-images", |j| {
        j["textures"] = serde_json::json!([{"source": 0}]);
    });
    let s = gltf_load::load(&no_images).unwrap();
    assert_eq!(s.triangles.len(), 2);
    let w = warnings_with(&no_images.display().to_string());
    assert!(w.iter().any(|w| w.contains("textures[0]")), "{w:#?}");

    // The same fault in a texture the material reads refuses the file and names it.
    let used = b.write_with(&folder, "used", |j| {
        j["textures"] = serde_json::json!([{"name": "needed", "source": 3}]);
        j["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"] =
            serde_json::json!({"index": 0});
    });
    let err = format!("{:#}", gltf_load::load(&used).unwrap_err());
    assert!(
        err.contains("textures[0] ('needed') is used by the scene") && err.contains("source"),
        "{err}"
    );
}

/// Invalid optional parts: a malformed texture transform on the normal texture (raw JSON) is
/// dropped with a warning, an invalid IOR falls back to 1.5.
#[test]
fn loader_skips_invalid_optional_parts() {
    capture_logs();
    let mut b = GltfBuilder::new();
    let n = b.texture_rgba8(1, 1, &[128, 128, 255, 255]);
    let m = b.material(&MaterialDesc {
        normal_texture: Some(tex(n)),
        ior: Some(0.5),
        ..lambert("m", 0.5)
    });
    let mesh = b.mesh(&MeshData::quad_xz(1.0, 0.0, Vec2::new), Some(m));
    b.node(mesh, Place::IDENTITY);
    b.point_light(Vec3::Y, [1.0; 3], 1.0);
    let path = b.write_with(&dir("invalid-parts"), "scene", |j| {
        j["materials"][0]["normalTexture"]["extensions"] =
            serde_json::json!({"KHR_texture_transform": {"offset": "up"}});
    });
    let s = gltf_load::load(&path).unwrap();
    let m = &s.materials[0];
    assert_eq!(m.normal_texture.unwrap().transform, UvTransform::default());
    assert_eq!(m.ior, 1.5);
    let w = warnings_with(&path.display().to_string());
    assert!(
        w.iter().any(|w| w.contains("KHR_texture_transform")),
        "{w:#?}"
    );
    assert!(w.iter().any(|w| w.contains("ior")), "{w:#?}");
}

/// The loader's own parsing (validation after the required-extension check) reads .glb and
/// .gltf alike: the committed box room gives the same scene both ways.
#[test]
fn loader_reads_glb_and_gltf_alike() {
    let a = gltf_load::load(std::path::Path::new("scenes/box-room/box-room.gltf")).unwrap();
    let b = gltf_load::load(std::path::Path::new("scenes/box-room/box-room.glb")).unwrap();
    assert_eq!(a.triangles.len(), 16);
    assert_eq!(a.positions, b.positions);
    assert_eq!(a.uvs, b.uvs);
    assert_eq!(a.materials, b.materials);
    assert_eq!(a.textures.len(), 1);
    assert_eq!(a.textures[0].rgba8, b.textures[0].rgba8);
    assert!(a.uvs1.is_empty() && a.tangents.is_empty());
}

// ---------------------------------------------------------------------------------------------
// e. Mip levels: box-filtered in linear light, chosen by the ray cone.

#[test]
fn mip_chain_halves_sizes_and_averages_colour_in_linear_light() {
    use gilab::scene::gpu_scene::mip_chain;
    use gilab::scene::Texture;
    // 5x3, black and white columns alternating: odd sizes fold the last column in.
    let (w, h) = (5u32, 3u32);
    let rgba8: Vec<u8> = (0..w * h)
        .flat_map(|i| {
            let v = if (i % w) % 2 == 0 { 255 } else { 0 };
            [v, v, v, 255]
        })
        .collect();
    let t = Texture {
        width: w,
        height: h,
        rgba8,
    };
    let srgb = mip_chain(&t, true);
    let sizes: Vec<(u32, u32)> = srgb.iter().map(|l| (l.0, l.1)).collect();
    assert_eq!(sizes, vec![(5, 3), (2, 1), (1, 1)]);
    // Level 1 texel 0 covers columns 0-1 (white, black): linear mean 0.5 -> sRGB 188.
    let l1 = &srgb[1].2;
    assert_eq!(l1[0], 188, "sRGB average of black and white is linear 0.5");
    assert_eq!(l1[3], 255, "alpha stays linear");
    // The same data read as linear (a normal or metallic-roughness map) averages to 128.
    let linear = mip_chain(&t, false);
    assert_eq!(linear[1].2[0], 128);
    // Last level: the mean of level 1's two texels (columns 0-1: 0.5; columns 2-4, the odd
    // one folded in: 2/3) in linear light, each level made from the one before.
    let expected = ((0.5f32 + 2.0 / 3.0) * 0.5).powf(1.0 / 2.4) * 1.055 * 255.0 - 0.055 * 255.0;
    assert!(
        (srgb[2].2[0] as f32 - expected).abs() <= 1.0,
        "{} vs {expected}",
        srgb[2].2[0]
    );
}

/// A one-texel checker seen from far away: with mip levels chosen by the ray cone every pixel
/// reads the same grey at 1 spp; read at the finest level the pixels would be black or white.
#[test]
fn gpu_ray_cones_pick_blurred_levels_for_distant_texels() {
    let (mean, std, _) = distant_checker(10.0);
    println!("checker seen from afar, 1 spp: mean {mean:.4}, std {std:.4}");
    assert!(
        (mean - 0.5).abs() < 0.03,
        "mean {mean}: linear average of the checker is 0.5"
    );
    assert!(std < 0.05, "std {std}: finest-level reads would give ~0.5");
}

/// Trilinear filtering: where the ray cone asks for level ~0.7 (1.62 texels per pixel: camera
/// 2.23 m above the checker) a pixel is 0.3 x level 0 (the checker, bilinear) + 0.7 x level 1
/// (uniform grey): values within 0.5 +- 0.15 but a contrast left; reading the nearest level
/// (1) would leave none. At level ~0.3 (1.69 m) 0.7 x the checker: values within 0.5 +- 0.35,
/// where level 0 alone reaches 0 and 1.
#[test]
fn gpu_trilinear_blends_the_two_levels_around_the_cone() {
    for (height, lod, half_range) in [(2.23, 0.7, 0.15), (1.69, 0.3, 0.35)] {
        let (mean, std, range) = distant_checker(height);
        println!(
            "checker at level ~{lod}, 1 spp: mean {mean:.4}, std {std:.4}, range {:.3}..{:.3}",
            range.0, range.1
        );
        assert!((mean - 0.5).abs() < 0.03, "mean {mean}");
        assert!(
            std > 0.02,
            "level ~{lod}: std {std}: no contrast left, level 1 alone"
        );
        assert!(
            range.0 > 0.5 - half_range - 0.03 && range.1 < 0.5 + half_range + 0.03,
            "level ~{lod}: range {range:?} wider than the blend allows"
        );
    }
}

/// A 1-texel checker (256 texels over an 8 m plane) seen straight down from `height` m at
/// 32 x 32 px, 40 degrees, 1 spp, lit by a white sky: (mean, std, (min, max)) of the central
/// 16 x 16 pixels.
fn distant_checker(height: f32) -> (f64, f64, (f64, f64)) {
    use gilab::scene::{Camera, Material, Texture};
    let n = 256u32;
    let rgba8: Vec<u8> = (0..n * n)
        .flat_map(|i| {
            let v = if (i % n + i / n).is_multiple_of(2) {
                255
            } else {
                0
            };
            [v, v, v, 255]
        })
        .collect();
    let mut s = Scene::new("mips");
    s.textures.push(Texture {
        width: n,
        height: n,
        rgba8,
    });
    let m = s.add_material(Material {
        base_color_texture: Some(TextureRef::new(0)),
        ..Material::lambert("checker", Vec3::ONE)
    });
    // An 8 m square plane at y = 0 facing up, UVs 0..1 across it: 32 texels per metre.
    let half = 4.0;
    let corners = [
        (Vec3::new(-half, 0.0, -half), Vec2::new(0.0, 0.0)),
        (Vec3::new(-half, 0.0, half), Vec2::new(0.0, 1.0)),
        (Vec3::new(half, 0.0, half), Vec2::new(1.0, 1.0)),
        (Vec3::new(half, 0.0, -half), Vec2::new(1.0, 0.0)),
    ];
    for (p, uv) in corners {
        s.positions.push(p);
        s.normals.push(Vec3::Y);
        s.uvs.push(uv);
    }
    s.triangles.push([0, 1, 2]);
    s.triangles.push([0, 2, 3]);
    s.triangle_material.extend([m, m]);
    // Lit by a white sky only: a Lambert plane open to it has radiance = its albedo.
    s.sky = Vec3::ONE;
    // 10 m above, 40 degrees: about 7 texels per pixel at 32 px, level 3 (8x8 texels, grey).
    s.camera = Some(Camera {
        position: Vec3::new(0.0, height, 0.0),
        target: Vec3::ZERO,
        up: Vec3::NEG_Z,
        fov_y: 40.0,
    });
    let size = 32;
    let img = render(s, size, 1);
    let mut values = Vec::new();
    for y in 8..24 {
        for x in 8..24 {
            values.push(img.pixel(x, y)[1] as f64);
        }
    }
    let mean = values.iter().sum::<f64>() / values.len() as f64;
    let std = (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / values.len() as f64).sqrt();
    let range = values
        .iter()
        .fold((f64::MAX, f64::MIN), |(lo, hi), &v| (lo.min(v), hi.max(v)));
    (mean, std, range)
}
