//! Direct light on a diffuse floor 0.05–1 units under a small square area light, against the
//! analytic solution. Shadow rays aimed from an offset origin at an un-offset light point hit the
//! light itself when a surface is this close (the reference lost 30–50% of its indirect light to
//! it); this test sees that loss directly, for the reference and for ReSTIR DI.

mod common;

use gilab::compare::Image;
use gilab::scene::{Camera, Material, Scene};
use glam::Vec3;

const LIGHT_HALF_SIZE: f32 = 0.1;
const RADIANCE: f32 = 10.0;
const ALBEDO: f32 = 0.5;
const FOV_Y_DEG: f32 = 20.0;
const SIZE: u32 = 32;

/// A floor at y = 0 and a square light at height `h` facing down; the camera halfway between,
/// looking straight down at the floor under the light's centre.
fn scene(h: f32) -> Scene {
    let mut s = Scene::new("near-light");
    let floor = s.add_material(Material::lambert("floor", Vec3::splat(ALBEDO)));
    let light = s.add_material(Material::emitter("light", Vec3::splat(RADIANCE)));
    let f = 5.0;
    s.add_quad(
        Vec3::new(-f, 0.0, -f),
        Vec3::new(-f, 0.0, f),
        Vec3::new(f, 0.0, f),
        Vec3::new(f, 0.0, -f),
        floor,
    );
    let l = LIGHT_HALF_SIZE;
    // Wound to face down (-y).
    s.add_quad(
        Vec3::new(-l, h, -l),
        Vec3::new(l, h, -l),
        Vec3::new(l, h, l),
        Vec3::new(-l, h, l),
        light,
    );
    s.camera = Some(Camera {
        position: Vec3::new(0.0, 0.5 * h, 0.0),
        target: Vec3::ZERO,
        up: Vec3::Z,
        fov_y: FOV_Y_DEG,
    });
    s
}

/// Radiance leaving the floor at (x, z): albedo · L · form factor to the light.
fn analytic_radiance(x: f64, z: f64, h: f64) -> f64 {
    let s = LIGHT_HALF_SIZE as f64;
    let mut f = 0.0;
    for a in [s - x, s + x] {
        for b in [s - z, s + z] {
            f += common::corner_form_factor(a, b, h);
        }
    }
    ALBEDO as f64 * RADIANCE as f64 * f
}

/// The analytic image, box-filtered over each pixel (the renderers jitter uniformly). The
/// solution is symmetric in x and z, so the camera's handedness does not matter.
fn analytic_image(h: f32) -> Vec<f64> {
    let n = SIZE as usize;
    let half_extent = 0.5 * h as f64 * (FOV_Y_DEG as f64 * 0.5).to_radians().tan();
    let sub = 4;
    let mut img = vec![0.0; n * n];
    for (i, v) in img.iter_mut().enumerate() {
        let (px, py) = ((i % n) as f64, (i / n) as f64);
        let mut sum = 0.0;
        for a in 0..sub {
            for b in 0..sub {
                let u = 2.0 * (px + (a as f64 + 0.5) / sub as f64) / n as f64 - 1.0;
                let w = 2.0 * (py + (b as f64 + 0.5) / sub as f64) / n as f64 - 1.0;
                sum += analytic_radiance(u * half_extent, w * half_extent, h as f64);
            }
        }
        *v = sum / (sub * sub) as f64;
    }
    img
}

fn render(technique: &str, params: toml::Table, h: f32, frames: u32) -> Image {
    common::render_technique(technique, params, scene(h), [SIZE, SIZE], frames, 5, 0).0
}

/// Worst 8×8-block ratio (green channel; the scene is grey) and the image-mean ratio.
fn compare(img: &Image, truth: &[f64]) -> (f64, f64) {
    let n = SIZE as usize;
    let mut worst: f64 = 1.0;
    for by in 0..n / 8 {
        for bx in 0..n / 8 {
            let (mut a, mut b) = (0.0, 0.0);
            for y in by * 8..by * 8 + 8 {
                for x in bx * 8..bx * 8 + 8 {
                    a += img.rgb[(y * n + x) * 3 + 1] as f64;
                    b += truth[y * n + x];
                }
            }
            let r = a / b;
            if (r - 1.0).abs() > (worst - 1.0).abs() {
                worst = r;
            }
        }
    }
    let mean: f64 = img
        .rgb
        .iter()
        .skip(1)
        .step_by(3)
        .map(|&g| g as f64)
        .sum::<f64>();
    (worst, mean / truth.iter().sum::<f64>())
}

const HEIGHTS: [f32; 4] = [0.05, 0.15, 0.4, 1.0];

#[test]
fn reference_direct_light_near_an_area_light_is_analytic() {
    let mut failures = Vec::new();
    for h in HEIGHTS {
        let params: toml::Table = toml::toml! { max_depth = 1
        samples_per_frame = 64 };
        let img = render("reference", params, h, 4);
        let (worst, mean) = compare(&img, &analytic_image(h));
        eprintln!("reference, light {h} above the floor: image mean / analytic {mean:.4}, worst 8×8 block {worst:.4}");
        if (mean - 1.0).abs() > 0.01 || (worst - 1.0).abs() > 0.03 {
            failures.push(format!(
                "h = {h}: mean ratio {mean:.4}, worst block {worst:.4}"
            ));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn restir_di_near_an_area_light_is_analytic() {
    let mut failures = Vec::new();
    for h in HEIGHTS {
        let img = render("restir", toml::toml! { gi = false }, h, 128);
        let (worst, mean) = compare(&img, &analytic_image(h));
        eprintln!("ReSTIR DI, light {h} above the floor: image mean / analytic {mean:.4}, worst 8×8 block {worst:.4}");
        if (mean - 1.0).abs() > 0.02 || (worst - 1.0).abs() > 0.05 {
            failures.push(format!(
                "h = {h}: mean ratio {mean:.4}, worst block {worst:.4}"
            ));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
