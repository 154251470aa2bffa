//! Environment maps (src/scene/environment.rs, shaders/common/sky.wgsl): the mapping
//! convention, luminance importance sampling against its pdf (CPU), the GPU lookup against the
//! CPU one, a constant map against the constant sky, a small bright sun with and without
//! next-event estimation of the map against the irradiance integrated on the CPU, ReSTIR's sky
//! class with the map, loading (.exr, .hdr) and its errors.

mod common;

use gilab::compare::Image;
use gilab::preset::LoadedPreset;
use gilab::render::RayCounts;
use gilab::scene::environment::{self, Environment, FLAG_NO_SKY_NEE};
use gilab::scene::{Camera, Material, Scene};
use glam::{Vec2, Vec3};
use std::f64::consts::PI;
use std::path::Path;

/// A small deterministic generator (xorshift64*), uniform in [0, 1).
struct Rand(u64);
impl Rand {
    fn next(&mut self) -> f32 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        ((self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 40) as f32) / (1u64 << 24) as f32
    }
}

/// A sky-blue gradient, a dark ground and a sun of angular radius `sun_deg` (radiance `sun`)
/// towards `sun_dir` (map space).
fn sun_map(w: u32, h: u32, sun_dir: Vec3, sun_deg: f32, sun: f32) -> Environment {
    let s = sun_dir.normalize();
    let cos_r = sun_deg.to_radians().cos();
    Environment::from_fn(w, h, |d| {
        let sky = if d.y > 0.0 {
            Vec3::new(0.3, 0.4, 0.6) * (0.5 + 0.5 * d.y)
        } else {
            Vec3::splat(0.05)
        };
        if d.dot(s) >= cos_r {
            sky + Vec3::new(1.0, 0.95, 0.85) * sun
        } else {
            sky
        }
    })
    .unwrap()
}

/// ∫ f(dir) dω over the sphere (or the upper hemisphere) by the midpoint rule on an (θ, φ) grid.
fn integrate(n_theta: usize, n_phi: usize, upper_only: bool, f: impl Fn(Vec3) -> f64) -> f64 {
    let theta_max = if upper_only { PI / 2.0 } else { PI };
    let (dt, dp) = (theta_max / n_theta as f64, 2.0 * PI / n_phi as f64);
    let mut sum = 0.0;
    for a in 0..n_theta {
        let t = (a as f64 + 0.5) * dt;
        let (st, ct) = t.sin_cos();
        for b in 0..n_phi {
            let p = (b as f64 + 0.5) * dp;
            let d = Vec3::new((st * p.cos()) as f32, ct as f32, (st * p.sin()) as f32);
            sum += f(d) * st * dt * dp;
        }
    }
    sum
}

fn lum(c: Vec3) -> f64 {
    (0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z) as f64
}

/// The mapping convention docs/scenes.md and the module state.
#[test]
fn mapping_convention() {
    let env = Environment::new(8, 4, vec![[1.0; 3]; 32]).unwrap();
    let close = |a: Vec3, b: Vec3| (a - b).length() < 1e-5;
    assert!(close(env.uv_to_direction(Vec2::new(0.5, 0.5)), Vec3::NEG_Z));
    assert!(close(env.uv_to_direction(Vec2::new(0.75, 0.5)), Vec3::X));
    assert!(close(
        env.uv_to_direction(Vec2::new(0.25, 0.5)),
        Vec3::NEG_X
    ));
    assert!(close(env.uv_to_direction(Vec2::new(0.0, 0.5)), Vec3::Z));
    assert!(close(env.uv_to_direction(Vec2::new(0.3, 0.0)), Vec3::Y));
    assert!(close(env.uv_to_direction(Vec2::new(0.3, 1.0)), Vec3::NEG_Y));
    // A rotation of 90 degrees turns +X towards -Z: the image centre (map -Z) is seen towards -X.
    let mut r = env.clone();
    r.rotation_deg = 90.0;
    assert!(close(r.uv_to_direction(Vec2::new(0.5, 0.5)), Vec3::NEG_X));
    assert!(close(r.uv_to_direction(Vec2::new(0.75, 0.5)), Vec3::NEG_Z));
    let uv = r.direction_to_uv(Vec3::NEG_X);
    assert!((uv - Vec2::new(0.5, 0.5)).length() < 1e-5, "{uv}");
    // Round trips.
    let mut rng = Rand(7);
    for _ in 0..1000 {
        let uv = Vec2::new(rng.next(), 0.01 + 0.98 * rng.next());
        let back = r.direction_to_uv(r.uv_to_direction(uv));
        let du = (back.x - uv.x).abs();
        assert!(
            du.min(1.0 - du) < 1e-4 && (back.y - uv.y).abs() < 1e-4,
            "{uv} -> {back}"
        );
    }
    // A map that is bright only in its top-left texel lights the zenith side, not the nadir.
    let mut texels = vec![[0.0; 3]; 32];
    texels[0] = [1.0; 3];
    let e = Environment::new(8, 4, texels).unwrap();
    assert!(
        e.radiance(e.uv_to_direction(Vec2::new(1.0 / 16.0, 1.0 / 8.0)))
            .x
            > 0.99
    );
    assert_eq!(e.radiance(Vec3::NEG_Y), Vec3::ZERO);
}

/// (a) Importance sampling on the CPU: the pdf integrates to 1 over the sphere, the pdf of each
/// sample's direction equals the pdf returned with it, and a histogram of 2^20 samples matches
/// the pdf integrated over each bin (chi-square). Also: the pdf is non-zero wherever the
/// (bilinear) radiance is.
#[test]
fn sampling_pdf_is_normalised_and_matches_histogram() {
    let mut env = sun_map(64, 32, Vec3::new(0.4, 0.5, -0.6), 5.0, 500.0);
    env.rotation_deg = 30.0;
    let total = integrate(1024, 2048, false, |d| env.pdf(d) as f64);
    eprintln!("integral of the pdf over the sphere: {total:.5}");
    assert!((total - 1.0).abs() < 2e-3, "pdf integrates to {total}");

    // Bins in world (u, v): 32 x 16 (2 x 2 texels, shifted by the rotation).
    let (bu, bv) = (32usize, 16usize);
    let n = 1usize << 20;
    let mut counts = vec![0u64; bu * bv];
    let mut rng = Rand(12345);
    // A sample within f32 rounding of a texel edge can read back as its neighbour: counted,
    // and the pdfs must agree everywhere else.
    let (mut worst, mut edge) = (0.0f64, 0usize);
    for _ in 0..n {
        let (dir, pdf) = env.sample(Vec2::new(rng.next(), rng.next()));
        assert!(pdf > 0.0 && (dir.length() - 1.0).abs() < 1e-4);
        let again = env.pdf(dir);
        let diff = ((again - pdf) / pdf).abs() as f64;
        if diff > 1e-3 {
            edge += 1;
        } else {
            worst = worst.max(diff);
        }
        let uv = env.direction_to_uv(dir);
        let i = ((uv.x * bu as f32) as usize).min(bu - 1);
        let j = ((uv.y * bv as f32) as usize).min(bv - 1);
        counts[j * bu + i] += 1;
    }
    eprintln!(
        "pdf(sample direction) against the sample's pdf: largest relative difference {worst:.2e}, {edge} of {n} samples on a texel edge"
    );
    assert!(
        worst < 1e-4 && edge * 10_000 < n,
        "pdf(sample.dir) differs from sample.pdf: {worst}, {edge} samples"
    );

    // Expected counts: the pdf of `model` integrated over each bin (32 x 32 points per bin),
    // the bins in `env`'s world (u, v); then Pearson's chi-square, bins expecting fewer than
    // 20 samples pooled.
    let p_value = |model: &Environment| -> (f64, i64, f64) {
        let sub = 32usize;
        let mut expected = vec![0.0f64; bu * bv];
        for j in 0..bv * sub {
            let v = (j as f64 + 0.5) / (bv * sub) as f64;
            let d_omega = 2.0 * PI * PI * (PI * v).sin() / ((bu * sub) as f64 * (bv * sub) as f64);
            for i in 0..bu * sub {
                let u = (i as f64 + 0.5) / (bu * sub) as f64;
                let dir = env.uv_to_direction(Vec2::new(u as f32, v as f32));
                expected[(j / sub) * bu + i / sub] += model.pdf(dir) as f64 * d_omega * n as f64;
            }
        }
        let (mut chi2, mut dof, mut pool_o, mut pool_e) = (0.0, 0i64, 0.0, 0.0);
        for (o, e) in counts.iter().zip(&expected) {
            if *e < 20.0 {
                pool_o += *o as f64;
                pool_e += e;
            } else {
                chi2 += (*o as f64 - e).powi(2) / e;
                dof += 1;
            }
        }
        if pool_e > 0.0 {
            chi2 += (pool_o - pool_e).powi(2) / pool_e.max(1.0);
            dof += 1;
        }
        use statrs::distribution::{ChiSquared, ContinuousCDF};
        let p = 1.0 - ChiSquared::new((dof - 1) as f64).unwrap().cdf(chi2);
        (chi2, dof, p)
    };
    let (chi2, dof, p) = p_value(&env);
    eprintln!("histogram: chi2 {chi2:.1} over {dof} bins, p-value {p:.3}");
    assert!(
        p > 0.001,
        "samples do not follow the pdf: chi2 {chi2}, {dof} bins, p {p}"
    );
    // The test has power: the pdf of the same map turned 2 degrees further is rejected.
    let mut turned = env.clone();
    turned.rotation_deg += 2.0;
    let (chi2, dof, p) = p_value(&turned);
    eprintln!(
        "against the map turned by 2 more degrees: chi2 {chi2:.1} over {dof} bins, p-value {p:.1e}"
    );
    assert!(p < 1e-6, "a wrong pdf passes: p {p}");

    // Support: every direction with radiance has a pdf (bilinear radiance spreads half a texel).
    let mut rng = Rand(99);
    for _ in 0..100_000 {
        let z = 1.0 - 2.0 * rng.next();
        let r = (1.0 - z * z).max(0.0).sqrt();
        let phi = 2.0 * std::f32::consts::PI * rng.next();
        let d = Vec3::new(r * phi.cos(), z, r * phi.sin());
        if env.radiance(d).max_element() > 0.0 && z.abs() < 0.999 {
            assert!(env.pdf(d) > 0.0, "radiance without pdf towards {d}");
        }
    }
}

/// The GPU buffer: header words, sizes, and a black map that cannot be sampled.
#[test]
fn gpu_buffer_layout() {
    let none = environment::gpu_bytes(None);
    assert_eq!(none.len(), environment::HEADER_WORDS * 4);
    assert!(none.iter().all(|&b| b == 0));
    let env = sun_map(16, 8, Vec3::Y, 10.0, 100.0);
    let bytes = environment::gpu_bytes(Some(&env));
    let words: &[u32] = bytemuck::cast_slice(&bytes);
    assert_eq!(words.len(), 16 + 2 * 128 + 8 + 128);
    assert_eq!((words[0], words[1], words[2], words[3]), (16, 8, 1, 1));
    assert_eq!(
        f32::from_bits(words[16 + 2 * 128 + 7]),
        1.0,
        "marginal CDF ends at 1"
    );
    let black = Environment::new(4, 2, vec![[0.0; 3]; 8]).unwrap();
    let w: Vec<u32> = bytemuck::cast_slice(&environment::gpu_bytes(Some(&black))).to_vec();
    assert_eq!((w[2], w[3]), (1, 0));
    assert_eq!(black.sample(Vec2::new(0.3, 0.3)).1, 0.0);
    // Texels brighter than half floats hold are stored scaled.
    let hot = Environment::new(2, 1, vec![[1e6, 1.0, 0.0], [0.5; 3]]).unwrap();
    let w: Vec<u32> = bytemuck::cast_slice(&environment::gpu_bytes(Some(&hot))).to_vec();
    let scale = f32::from_bits(w[12]);
    assert!((scale - 1e6 / 32768.0).abs() < 1e-2 * scale);
    let r = half::f16::from_bits((w[16] & 0xffff) as u16).to_f32() * f32::from_bits(w[8]);
    assert!((r - 1e6).abs() < 1e3, "{r}");
}

/// Engine helpers: the reference with `flags`, returning the image, the per-pixel sample
/// variance and the ray counts.
fn reference(
    scene: Scene,
    size: [u32; 2],
    spp: u32,
    max_depth: u32,
    seed: u32,
    flags: u32,
) -> (Image, Image, RayCounts) {
    let spf = spp.min(64);
    let mut params = toml::Table::new();
    params.insert("samples_per_frame".into(), (spf as i64).into());
    params.insert("max_depth".into(), (max_depth as i64).into());
    let mut e = common::engine("reference", params, scene, size, seed);
    e.flags = flags;
    e.reset();
    for _ in 0..spp.div_ceil(spf) {
        e.render_frame().unwrap();
    }
    let rays = e.ray_counts().unwrap();
    assert_eq!(rays.invalid_samples, 0, "NaN/Inf samples");
    let (img, var) = e.read_output_and_variance().unwrap();
    (img, var.expect("variance"), rays)
}

/// An unoccluded Lambert floor (100 x 100) seen straight down by a 1-degree camera.
fn floor_scene(albedo: f32) -> Scene {
    let mut s = Scene::new("floor");
    let m = s.add_material(Material::lambert("floor", Vec3::splat(albedo)));
    let v = Vec3::new;
    s.add_quad(
        v(-50.0, 0.0, -50.0),
        v(-50.0, 0.0, 50.0),
        v(50.0, 0.0, 50.0),
        v(50.0, 0.0, -50.0),
        m,
    );
    s.camera = Some(Camera {
        position: v(0.0, 0.5, 0.0),
        target: Vec3::ZERO,
        up: Vec3::Z,
        fov_y: 1.0,
    });
    s
}

/// A floor, a box and a tilted wall seen at an angle: shadows and interreflection.
fn box_scene() -> Scene {
    let mut s = floor_scene(0.5);
    let v = Vec3::new;
    let b = s.add_material(Material::lambert("box", Vec3::new(0.7, 0.6, 0.5)));
    let (lo, hi) = (v(-0.5, 0.0, -0.5), v(0.5, 1.0, 0.5));
    s.add_box(
        [
            v(lo.x, lo.y, lo.z),
            v(hi.x, lo.y, lo.z),
            v(hi.x, lo.y, hi.z),
            v(lo.x, lo.y, hi.z),
            v(lo.x, hi.y, lo.z),
            v(hi.x, hi.y, lo.z),
            v(hi.x, hi.y, hi.z),
            v(lo.x, hi.y, hi.z),
        ],
        b,
    );
    let wall = s.add_material(Material::glossy("wall", Vec3::splat(0.8), 1.0, 0.4));
    s.add_quad(
        v(-2.0, 0.0, -1.5),
        v(2.0, 0.0, -1.5),
        v(2.0, 2.0, -2.0),
        v(-2.0, 2.0, -2.0),
        wall,
    );
    s.camera = Some(Camera {
        position: v(1.5, 2.5, 3.5),
        target: v(0.0, 0.4, 0.0),
        up: Vec3::Y,
        fov_y: 50.0,
    });
    s
}

/// Mean of the per-pixel sample variances (over channels) and the standard error of the image
/// mean (pixels independent) for `spp` samples per pixel.
fn variance_stats(var: &Image, spp: u32) -> (f64, f64) {
    let n = (var.width * var.height) as f64;
    let mean_var = var.rgb.iter().map(|&v| v as f64).sum::<f64>() / (3.0 * n);
    (mean_var, (mean_var / (spp as f64 * n)).sqrt())
}

/// GPU lookups against the CPU's: a camera inside a smooth map (no geometry in view) renders
/// the radiance towards each pixel; each pixel is compared with the CPU radiance averaged over
/// the pixel's footprint. Checks the mapping, rotation, bilinear lookup and intensity on the GPU.
#[test]
fn gpu_lookup_matches_cpu() {
    let _guard = common::serial();
    let mut env = Environment::from_fn(96, 48, |d| {
        Vec3::new(
            1.0 + 0.8 * d.x + 0.3 * (4.0 * d.z).sin(),
            1.0 + 0.6 * d.y,
            1.0 - 0.7 * d.z + 0.2 * (3.0 * d.x).cos(),
        )
    })
    .unwrap();
    env.rotation_deg = 40.0;
    env.intensity = 1.5;
    let mut s = Scene::new("sky only");
    let m = s.add_material(Material::lambert("speck", Vec3::splat(0.5)));
    let v = Vec3::new;
    // A speck far below so that the scene is not empty; the camera never sees it.
    s.add_triangle(
        [v(0.0, -1e3, 0.0), v(0.01, -1e3, 0.0), v(0.0, -1e3, 0.01)],
        m,
    );
    let camera = Camera {
        position: Vec3::ZERO,
        target: v(1.0, 0.3, -1.0),
        up: Vec3::Y,
        fov_y: 90.0,
    };
    s.camera = Some(camera);
    s.environment = Some(env.clone());
    let size = [48u32, 32u32];
    let (img, _, _) = reference(s, size, 64, 1, 3, 0);
    let (right, up, fwd) = camera.basis();
    let tan = (camera.fov_y.to_radians() * 0.5).tan();
    let aspect = size[0] as f32 / size[1] as f32;
    let mut worst = 0.0f32;
    for y in 0..size[1] {
        for x in 0..size[0] {
            let mut cpu = Vec3::ZERO;
            let k = 6;
            for sy in 0..k {
                for sx in 0..k {
                    let px = x as f32 + (sx as f32 + 0.5) / k as f32;
                    let py = y as f32 + (sy as f32 + 0.5) / k as f32;
                    let ndc = Vec2::new(
                        2.0 * px / size[0] as f32 - 1.0,
                        1.0 - 2.0 * py / size[1] as f32,
                    );
                    let d = (fwd + ndc.x * right * tan * aspect + ndc.y * up * tan).normalize();
                    cpu += env.radiance(d);
                }
            }
            cpu /= (k * k) as f32;
            let gpu = Vec3::from(img.pixel(x, y));
            worst = worst.max(((gpu - cpu) / cpu).abs().max_element());
        }
    }
    eprintln!(
        "GPU sky lookup against the CPU's, worst pixel: {:.3}%",
        worst * 100.0
    );
    assert!(worst < 0.01, "GPU lookup differs from the CPU's by {worst}");
}

/// (b) A constant map of radiance c renders like the constant sky c: on the open floor (radiance
/// albedo x c exactly, a white-furnace-like case) and on a scene with shadows and
/// interreflection (image means and 8x8 blocks within noise).
#[test]
fn constant_map_equals_constant_sky() {
    let _guard = common::serial();
    let c = Vec3::new(0.8, 0.9, 1.0);
    let constant_map = || Environment::new(8, 4, vec![c.to_array(); 32]).unwrap();

    let albedo = 0.5;
    let mut sky_floor = floor_scene(albedo);
    sky_floor.sky = c;
    let mut env_floor = floor_scene(albedo);
    env_floor.environment = Some(constant_map());
    for (name, scene) in [("constant sky", sky_floor), ("constant map", env_floor)] {
        let spp = 256;
        let (img, var, rays) = reference(scene, [32, 32], spp, 0, 5, 0);
        let m = img.mean();
        let (_, stderr) = variance_stats(&var, spp);
        eprintln!(
            "open floor under the {name}: mean {:.5} {:.5} {:.5} (analytic {:.5} {:.5} {:.5}, stderr {stderr:.1e}), shadow rays {}",
            m[0], m[1], m[2], albedo * c.x, albedo * c.y, albedo * c.z, rays.by_kind[1]
        );
        for ch in 0..3 {
            let want = (albedo * c[ch]) as f64;
            // Half-float texels: 0.8 and 0.9 are stored 0.03% and 0.01% low.
            assert!(
                (m[ch] - want).abs() < 4.0 * stderr + 5e-4 * want,
                "{name}: channel {ch} {} vs {want}",
                m[ch]
            );
        }
    }

    let size = [32u32, 32u32];
    let spp = 128;
    let mut a = box_scene();
    a.sky = c;
    let mut b = box_scene();
    b.environment = Some(constant_map());
    let (ia, va, _) = reference(a, size, spp, 0, 7, 0);
    let (ib, vb, _) = reference(b, size, spp, 0, 8, 0);
    let (ma, mb) = (ia.mean(), ib.mean());
    let (_, sa) = variance_stats(&va, spp);
    let (_, sb) = variance_stats(&vb, spp);
    let sigma = (sa * sa + sb * sb).sqrt();
    eprintln!(
        "box scene: constant sky mean {:.5} {:.5} {:.5}, constant map {:.5} {:.5} {:.5} (sigma of the difference {sigma:.2e})",
        ma[0], ma[1], ma[2], mb[0], mb[1], mb[2]
    );
    for ch in 0..3 {
        assert!(
            (ma[ch] - mb[ch]).abs() < 4.0 * sigma + 1e-3 * ma[ch],
            "channel {ch}: {} vs {}",
            ma[ch],
            mb[ch]
        );
    }
    // 8x8 blocks: difference against the blocks' own noise.
    let mut worst = 0.0f64;
    for by in 0..size[1] / 8 {
        for bx in 0..size[0] / 8 {
            let (mut da, mut db, mut v) = (0.0, 0.0, 0.0);
            for y in by * 8..by * 8 + 8 {
                for x in bx * 8..bx * 8 + 8 {
                    let (pa, pb) = (ia.pixel(x, y), ib.pixel(x, y));
                    let (qa, qb) = (va.pixel(x, y), vb.pixel(x, y));
                    da += lum(Vec3::from(pa));
                    db += lum(Vec3::from(pb));
                    v += lum(Vec3::from(qa)) + lum(Vec3::from(qb));
                }
            }
            let z = (da - db).abs() / (v / spp as f64).sqrt();
            worst = worst.max(z);
        }
    }
    eprintln!("box scene: worst 8x8 block difference {worst:.2} sigma");
    assert!(worst < 4.5, "a block differs by {worst} sigma");
}

/// (c) A map with a small bright sun: the open floor's radiance is albedo / pi x the irradiance
/// integrated over the map on the CPU. The path tracer converges to it with the map in NEE and
/// without (BSDF sampling alone, FLAG_NO_SKY_NEE), and NEE's per-sample variance is far lower.
#[test]
fn sun_map_nee_converges_with_lower_variance() {
    let _guard = common::serial();
    let dir = common::tmp_dir("environment", "sun");
    let path = dir.join("sun.exr");
    let sun_dir = Vec3::new(0.5, 0.65, -0.6).normalize();
    let src = sun_map(128, 64, sun_dir, 6.0, 1000.0);
    write_exr(&path, &src);
    let env = Environment::load(&path, 25.0, 0.8).unwrap();
    assert_eq!((env.width(), env.height()), (128, 64));

    let albedo = 0.5f32;
    let irradiance = integrate(1024, 4096, true, |d| lum(env.radiance(d)) * d.y as f64);
    let expected = albedo as f64 / PI * irradiance;
    let mut scene = floor_scene(albedo);
    scene.environment = Some(env);
    let size = [64u32, 64u32];
    let spp = 256;
    let mut results = Vec::new();
    for (name, flags) in [
        ("NEE + BSDF (MIS)", 0),
        ("BSDF sampling alone", FLAG_NO_SKY_NEE),
    ] {
        let (img, var, rays) = reference(scene.clone(), size, spp, 1, 21, flags);
        let mean = lum(Vec3::from(img.mean().map(|v| v as f32)));
        let (mean_var, stderr) = variance_stats(&var, spp);
        eprintln!(
            "sun map, {name}: floor radiance {mean:.4} vs CPU {expected:.4} ({:+.2}%, {:.2} sigma), per-sample variance {mean_var:.3}, shadow rays/px {:.2}",
            (mean / expected - 1.0) * 100.0,
            (mean - expected) / stderr,
            rays.by_kind[1] as f64 / (size[0] * size[1] * spp) as f64
        );
        // Half-float texels and the CPU quadrature agree to ~0.1%.
        assert!(
            (mean - expected).abs() < 4.0 * stderr + 3e-3 * expected,
            "{name}: {mean} vs {expected} (stderr {stderr})"
        );
        results.push(mean_var);
    }
    let ratio = results[1] / results[0];
    eprintln!("variance of BSDF sampling alone / with the map in NEE: {ratio:.1}");
    assert!(ratio > 20.0, "NEE variance ratio only {ratio}");
}

/// ReSTIR's sky class with an environment map (BSDF, cosine and map candidates) converges to
/// the reference's direct light.
#[test]
fn restir_sky_class_with_map_converges() {
    let _guard = common::serial();
    let mut scene = box_scene();
    scene.environment = Some(sun_map(64, 32, Vec3::new(0.3, 0.7, 0.5), 6.0, 300.0));
    let size = [32u32, 32u32];
    let (truth, _, _) = reference(scene.clone(), size, 512, 1, 31, 0);
    let params: toml::Table = toml::toml! { gi = false
    sky_candidates = 4 };
    let (di, _) = common::render_technique("restir", params, scene, size, 64, 1, 0);
    let e = |img: &Image| lum(Vec3::from(img.mean().map(|v| v as f32)));
    let ratio = e(&di) / e(&truth);
    let m = gilab::compare::metrics::compare(&di, &truth).unwrap();
    eprintln!(
        "ReSTIR DI, sky class on a sun map, 64 frames: energy ratio {ratio:.4}, relMSE {:.2e}",
        m.rel_mse
    );
    assert!((ratio - 1.0).abs() < 0.03, "energy ratio {ratio}");
}

fn write_exr(path: &Path, env: &Environment) {
    let w = env.width() as usize;
    let t = env.texels();
    exr::prelude::write_rgb_file(path, w, env.height() as usize, |x, y| {
        let p = t[y * w + x];
        (p[0], p[1], p[2])
    })
    .unwrap();
}

/// Loading: EXR and Radiance HDR files, invalid texels clamped, presets with the three keys
/// (paths relative to the preset), and the scene's features naming the map.
#[test]
fn loads_exr_and_hdr_from_presets() {
    let dir = common::tmp_dir("environment", "load");
    // EXR with a NaN, an infinity and a negative texel.
    let w = 8usize;
    exr::prelude::write_rgb_file(dir.join("sky.exr"), w, 4, |x, y| match (x, y) {
        (1, 0) => (f32::NAN, 1.0, 1.0),
        (2, 1) => (f32::INFINITY, 1.0, 1.0),
        (3, 2) => (1.0, -2.0, 1.0),
        _ => (0.5 + x as f32 * 0.1, 0.25, y as f32),
    })
    .unwrap();
    let env = Environment::load(&dir.join("sky.exr"), 0.0, 1.0).unwrap();
    assert_eq!((env.width(), env.height(), env.invalid_texels()), (8, 4, 3));
    assert_eq!(env.texels()[1], [0.0, 1.0, 1.0]);
    assert_eq!(env.texels()[2 * w + 3], [1.0, 0.0, 1.0]);
    assert_eq!(env.texels()[w + 5], [1.0, 0.25, 1.0]);

    // Radiance HDR (RGBE: about 1% precision).
    let mut img = image::Rgb32FImage::new(6, 3);
    for (x, y, p) in img.enumerate_pixels_mut() {
        *p = image::Rgb([1.0 + x as f32, 0.5 * y as f32 + 0.1, 3.0]);
    }
    img.save(dir.join("sky.hdr")).unwrap();
    let hdr = Environment::load(&dir.join("sky.hdr"), 0.0, 1.0).unwrap();
    assert_eq!((hdr.width(), hdr.height()), (6, 3));
    let t = hdr.texels()[2 * 6 + 4];
    assert!(
        (t[0] - 5.0).abs() < 0.05 && (t[1] - 1.1).abs() < 0.02 && (t[2] - 3.0).abs() < 0.03,
        "{t:?}"
    );

    // A preset: path relative to the preset file, rotation and intensity.
    let preset_path = dir.join("open.toml");
    let text = "[scene]\nsource = \"courtyard\"\nenvironment = \"sky.exr\"\nenvironment_rotation = 30\nenvironment_intensity = 2.5\n";
    std::fs::write(&preset_path, text).unwrap();
    let p = LoadedPreset::load(&preset_path).unwrap();
    let scene = p.load_scene().unwrap();
    let e = scene.environment.as_ref().expect("environment");
    assert_eq!((e.rotation_deg, e.intensity, e.width()), (30.0, 2.5, 8));
    assert!((scene.sky_mean() - env.mean_radiance() * 2.5).length() < 1e-5);
    assert_eq!(scene.sky_label(), "environment map 8x4");
    let data = gilab::scene::gpu_scene::SceneData::new(&scene);
    assert!(data.features.sky_visible);
    assert_eq!(data.features.environment, Some([8, 4]));
    assert!(data
        .features
        .summary()
        .contains("environment map 8x4 visible true"));
    // The reference cache key changes with the map (and only then).
    let plain =
        LoadedPreset::from_text("[scene]\nsource = \"courtyard\"\n", Some(&preset_path)).unwrap();
    assert_ne!(
        gilab::jobs::reference_key(&p).unwrap(),
        gilab::jobs::reference_key(&plain).unwrap()
    );
    assert!(plain.load_scene().unwrap().environment.is_none());
    // --set scene.environment_intensity=... applies.
    let mut q = LoadedPreset::load(&preset_path).unwrap();
    q.apply(&gilab::preset::Overrides {
        set: vec!["scene.environment_intensity=0.5".into()],
        ..Default::default()
    })
    .unwrap();
    assert_eq!(q.load_scene().unwrap().environment.unwrap().intensity, 0.5);
    // A black map is no sky.
    exr::prelude::write_rgb_file(dir.join("black.exr"), 4, 2, |_, _| (0.0, 0.0, 0.0)).unwrap();
    std::fs::write(
        &preset_path,
        "[scene]\nsource = \"courtyard\"\nenvironment = \"black.exr\"\n",
    )
    .unwrap();
    let black = LoadedPreset::load(&preset_path)
        .unwrap()
        .load_scene()
        .unwrap();
    assert!(
        !gilab::scene::gpu_scene::SceneData::new(&black)
            .features
            .sky_visible
    );
}

/// (d) Clear errors: a missing file, an unsupported format, a file that is not an EXR, bad
/// values in the preset (with line and column), rotation or intensity without a map.
#[test]
fn bad_environment_gives_clear_errors() {
    let dir = common::tmp_dir("environment", "errors");
    let preset_path = dir.join("bad.toml");
    let load = |text: &str| -> String {
        std::fs::write(&preset_path, text).unwrap();
        let err = match LoadedPreset::load(&preset_path) {
            Err(e) => e,
            Ok(p) => p.load_scene().expect_err("an error"),
        };
        format!("{err:#}")
    };
    let e = load("[scene]\nsource = \"cornell\"\nenvironment = \"missing.exr\"\n");
    eprintln!("{e}");
    assert!(
        e.contains("missing.exr") && e.contains("file not found"),
        "{e}"
    );
    assert!(e.contains("bad.toml"), "names the preset: {e}");

    std::fs::write(dir.join("sky.png"), b"not an image").unwrap();
    let e = load("[scene]\nsource = \"cornell\"\nenvironment = \"sky.png\"\n");
    eprintln!("{e}");
    assert!(
        e.contains("sky.png") && e.contains("unsupported format 'png'"),
        "{e}"
    );

    std::fs::write(dir.join("broken.exr"), b"definitely not an exr file").unwrap();
    let e = load("[scene]\nsource = \"cornell\"\nenvironment = \"broken.exr\"\n");
    eprintln!("{e}");
    assert!(
        e.contains("broken.exr") && e.contains("not a readable RGB(A) EXR"),
        "{e}"
    );

    std::fs::write(dir.join("broken.hdr"), b"#?RADIANCE\nnonsense").unwrap();
    let e = load("[scene]\nsource = \"cornell\"\nenvironment = \"broken.hdr\"\n");
    eprintln!("{e}");
    assert!(e.contains("broken.hdr"), "{e}");

    let e = load(
        "[scene]\nsource = \"cornell\"\nenvironment = \"sky.exr\"\nenvironment_intensity = -1\n",
    );
    eprintln!("{e}");
    assert!(
        e.contains("bad.toml:4:")
            && e.contains("environment_intensity -1: expected a finite number >= 0"),
        "{e}"
    );

    let e = load(
        "[scene]\nsource = \"cornell\"\nenvironment = \"sky.exr\"\nenvironment_rotation = nan\n",
    );
    eprintln!("{e}");
    assert!(
        e.contains("bad.toml:4:")
            && e.contains("environment_rotation NaN: expected a finite number"),
        "{e}"
    );

    let e = load("[scene]\nsource = \"cornell\"\nenvironment = 3\n");
    eprintln!("{e}");
    assert!(e.contains("bad.toml:3:"), "{e}");

    let e = load("[scene]\nsource = \"cornell\"\nenvironment_rotation = 10\n");
    eprintln!("{e}");
    assert!(
        e.contains("bad.toml") && e.contains("need scene.environment"),
        "{e}"
    );

    let e = load("[scene]\nsource = \"cornell\"\nenviroment = \"sky.exr\"\n");
    eprintln!("{e}");
    assert!(e.contains("bad.toml:3:") && e.contains("enviroment"), "{e}");
}
