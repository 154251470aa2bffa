//! The shading models of shaders/common/brdf.wgsl (lambert-ggx, callisto, callisto-proxima),
//! evaluated on the GPU through the BRDF probe (the same `bsdf_eval` every technique calls):
//! Callisto's defaults reproduce Lambert + GGX; reciprocity where the model is meant to be
//! reciprocal (and the measured asymmetry where it is not); Proxima against a numerical
//! integration of the microfacet diffuse it approximates (Heitz 2014 with G2 = 1, GGX normals);
//! the BRDF slice's geometry. Sampling (chi-square) and energy (white furnace) are in brdf.rs.

mod common;

use gilab::compare::brdf_probe::{
    seed_material, slice_directions, BrdfProbe, ProbeMaterial, Query, SEED_MATERIALS,
};
use gilab::gpu::shaders::ShaderLibrary;
use gilab::scene::shading::{BrdfModel, CallistoParams};
use glam::Vec3;

fn probe() -> (std::sync::Arc<gilab::gpu::Gpu>, BrdfProbe) {
    let gpu = common::gpu();
    let probe = BrdfProbe::new(&gpu, &ShaderLibrary::discover()).unwrap();
    (gpu, probe)
}

/// SplitMix64: a fixed-seed stream for test directions.
struct Rng(u64);

impl Rng {
    fn uniform(&mut self) -> f32 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
    }
}

fn hemisphere(rng: &mut Rng) -> Vec3 {
    // Uniform in cos θ within [0.02, 1] (not exactly grazing), uniform in φ.
    let c = 0.02 + 0.98 * rng.uniform();
    let phi = rng.uniform() * std::f32::consts::TAU;
    let s = (1.0 - c * c).sqrt();
    Vec3::new(s * phi.cos(), s * phi.sin(), c)
}

fn random_pairs(n: usize, materials: u32, seed: u64) -> Vec<Query> {
    let mut rng = Rng(seed);
    (0..n)
        .map(|i| Query {
            material: i as u32 % materials,
            wo: hemisphere(&mut rng),
            wi: hemisphere(&mut rng),
        })
        .collect()
}

fn rel_diff(a: Vec3, b: Vec3) -> f32 {
    ((a - b).abs() / a.abs().max(b.abs()).max(Vec3::splat(1e-6))).max_element()
}

#[test]
fn callisto_defaults_reproduce_lambert_ggx() {
    let (gpu, probe) = probe();
    let mut mats = Vec::new();
    for (base, metallic, roughness, specular) in [
        (Vec3::new(0.8, 0.5, 0.3), 0.0, 1.0, 0.0),
        (Vec3::new(0.2, 0.6, 0.3), 0.0, 0.4, 1.0),
        (Vec3::new(0.95, 0.64, 0.54), 1.0, 0.3, 1.0),
        (Vec3::new(0.7, 0.7, 0.2), 0.5, 0.6, 0.5),
    ] {
        for brdf in [BrdfModel::LambertGgx, BrdfModel::Callisto] {
            mats.push(ProbeMaterial {
                metallic,
                specular,
                ..ProbeMaterial::new(brdf, base, roughness)
            });
        }
    }
    let pairs = random_pairs(4096, 4, 11);
    // Each pair evaluated for the lambert-ggx material (even index) and its callisto twin.
    let queries: Vec<Query> = pairs
        .iter()
        .flat_map(|q| {
            [0, 1].map(|k| Query {
                material: q.material * 2 + k,
                ..*q
            })
        })
        .collect();
    let e = probe.eval(&gpu, &mats, &queries).unwrap();
    let mut worst = (0.0f32, 0.0f32);
    for pair in e.chunks_exact(2) {
        worst.0 = worst.0.max(rel_diff(pair[0].f, pair[1].f));
        worst.1 = worst
            .1
            .max((pair[0].pdf - pair[1].pdf).abs() / pair[0].pdf.max(1e-6));
    }
    eprintln!(
        "callisto at its defaults vs lambert-ggx: max relative difference f {:.2e}, pdf {:.2e}",
        worst.0, worst.1
    );
    assert!(worst.0 < 1e-4 && worst.1 < 1e-4, "{worst:?}");

    // And a non-default parameter does change it (the comparison can fail).
    let mut m = mats[3];
    m.callisto.retroreflection = 3.0;
    let q = |material| Query {
        material,
        wo: Vec3::new(0.8, 0.0, 0.6),
        wi: Vec3::new(0.8, 0.0, 0.6),
    };
    let moved = probe.eval(&gpu, &[mats[2], m], &[q(0), q(1)]).unwrap();
    assert!(rel_diff(moved[0].f, moved[1].f) > 1e-2, "{moved:?}");
}

/// f(wo, wi) = f(wi, wo) for every part designed to be reciprocal: Lambert, GGX (single and dual,
/// with the Fresnel falloff: it depends on v·h = l·h), Callisto's c1 (symmetric in θd, θh).
/// Not reciprocal by construction, and measured: lambert-ggx's diffuse weight 1 − F(n·v) (the
/// usual energy split), Callisto's smooth terminator (a function of θi only) and Proxima (a fit
/// along V = N with 1/cos θi). The test asserts the first list and that the second list really
/// is asymmetric (so the comparison can fail).
#[test]
fn reciprocity_where_the_models_are_reciprocal() {
    let (gpu, probe) = probe();
    let white = Vec3::splat(0.9);
    let mut reciprocal = vec![
        (
            "lambert (specular 0)".to_string(),
            ProbeMaterial {
                specular: 0.0,
                ..ProbeMaterial::new(BrdfModel::LambertGgx, white, 1.0)
            },
        ),
        (
            "ggx metal r0.4".to_string(),
            ProbeMaterial {
                metallic: 1.0,
                ..ProbeMaterial::new(BrdfModel::LambertGgx, white, 0.4)
            },
        ),
    ];
    for name in SEED_MATERIALS {
        let mut m = seed_material(name).unwrap();
        m.callisto.smooth_terminator = 0.0;
        // Diffuse part alone (c1 x Lambert): specular 0 removes the 1 − F(n·v) weight.
        let diffuse = ProbeMaterial {
            specular: 0.0,
            metallic: 0.0,
            ..m
        };
        // Specular part alone (dual GGX with the falloff Fresnel).
        let spec = ProbeMaterial { metallic: 1.0, ..m };
        reciprocal.push((format!("{name} diffuse (c1 x Lambert)"), diffuse));
        reciprocal.push((format!("{name} specular (dual GGX, falloff)"), spec));
    }
    let asymmetric = vec![
        (
            "lambert-ggx dielectric (1 - F(n.v))".to_string(),
            ProbeMaterial::new(BrdfModel::LambertGgx, white, 0.5),
        ),
        (
            "callisto yellow-phenolic (smooth terminator 0.25)".to_string(),
            seed_material("yellow-phenolic").unwrap(),
        ),
        (
            "callisto-proxima r1 (specular 0)".to_string(),
            ProbeMaterial {
                specular: 0.0,
                ..ProbeMaterial::new(BrdfModel::CallistoProxima, white, 1.0)
            },
        ),
    ];
    let all: Vec<ProbeMaterial> = reciprocal
        .iter()
        .chain(&asymmetric)
        .map(|(_, m)| *m)
        .collect();
    let n_mat = all.len() as u32;
    let forward = random_pairs(2000 * n_mat as usize, n_mat, 5);
    let backward: Vec<Query> = forward
        .iter()
        .map(|q| Query {
            wo: q.wi,
            wi: q.wo,
            ..*q
        })
        .collect();
    let a = probe.eval(&gpu, &all, &forward).unwrap();
    let b = probe.eval(&gpu, &all, &backward).unwrap();
    let mut worst = vec![0.0f32; all.len()];
    for ((q, fa), fb) in forward.iter().zip(&a).zip(&b) {
        // Values below 1e-4 of a white Lambertian are noise in f32, whatever their ratio.
        if fa.f.max_element() < 1e-5 && fb.f.max_element() < 1e-5 {
            continue;
        }
        let w = &mut worst[q.material as usize];
        *w = w.max(rel_diff(fa.f, fb.f));
    }
    let mut failures = Vec::new();
    for (k, (name, _)) in reciprocal.iter().chain(&asymmetric).enumerate() {
        let expected = k < reciprocal.len();
        eprintln!(
            "{name:>50}: max |f(i,o) - f(o,i)| / f = {:.2e} ({})",
            worst[k],
            if expected {
                "reciprocal"
            } else {
                "not reciprocal by design"
            }
        );
        if expected && worst[k] > 2e-3 {
            failures.push(format!("{name}: not reciprocal ({:.2e})", worst[k]));
        }
        if !expected && worst[k] < 1e-2 {
            failures.push(format!(
                "{name}: expected measurable asymmetry, got {:.2e}",
                worst[k]
            ));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// Heitz 2014's microfacet diffuse with G2 = 1 and GGX normals (what the talk's 3D LUT and
/// Proxima approximate), times π: (1 / (cos θo cos θi)) ∫ <wo,m><wi,m> D(m) dm, integrated with
/// m drawn from D(m) cos θm on a stratified grid (an independent CPU implementation, f64).
fn heitz_diffuse_times_pi(alpha: f64, wo: [f64; 3], wi: [f64; 3]) -> f64 {
    const N: usize = 384;
    let mut sum = 0.0;
    for a in 0..N {
        let u1 = (a as f64 + 0.5) / N as f64;
        let theta = (alpha * (u1 / (1.0 - u1)).sqrt()).atan();
        let (st, ct) = theta.sin_cos();
        for b in 0..N {
            let phi = (b as f64 + 0.5) / N as f64 * std::f64::consts::TAU;
            let m = [st * phi.cos(), st * phi.sin(), ct];
            let dot = |v: [f64; 3]| (v[0] * m[0] + v[1] * m[1] + v[2] * m[2]).max(0.0);
            sum += dot(wo) * dot(wi) / ct;
        }
    }
    sum / (N * N) as f64 / (wo[2] * wi[2])
}

#[test]
fn proxima_matches_the_microfacet_diffuse_it_approximates() {
    let (gpu, probe) = probe();
    let roughness: Vec<f32> = (1..=10).map(|k| k as f32 * 0.1).collect();
    let mats: Vec<ProbeMaterial> = roughness
        .iter()
        .map(|&r| ProbeMaterial {
            specular: 0.0,
            ..ProbeMaterial::new(BrdfModel::CallistoProxima, Vec3::ONE, r)
        })
        .collect();
    let dir = |theta_deg: f32, phi: f32| {
        let t = theta_deg.to_radians();
        Vec3::new(t.sin() * phi.cos(), t.sin() * phi.sin(), t.cos())
    };
    // (θo, θi, φ between them): V = N is the fit's region; other views are reported.
    let theta_i: Vec<f32> = (0..=8).map(|k| k as f32 * 10.0).collect();
    let mut configs = Vec::new();
    for theta_o in [0.0f32, 40.0, 70.0] {
        for &ti in &theta_i {
            for phi in [0.0f32, std::f32::consts::PI] {
                if theta_o == 0.0 && phi != 0.0 {
                    continue;
                }
                configs.push((theta_o, ti, phi));
            }
        }
    }
    let queries: Vec<Query> = (0..mats.len() as u32)
        .flat_map(|m| {
            configs.iter().map(move |&(to, ti, phi)| Query {
                material: m,
                wo: dir(to, 0.0),
                wi: dir(ti, phi),
            })
        })
        .collect();
    let evals = probe.eval(&gpu, &mats, &queries).unwrap();
    // Per view angle: (mean |err| Proxima, max |err| Proxima, mean |err| Lambert, max Lambert).
    let mut stats = std::collections::BTreeMap::<i32, (f64, f64, f64, f64, usize)>::new();
    for (q, e) in queries.iter().zip(&evals) {
        let alpha = (roughness[q.material as usize] as f64).powi(2);
        let h = heitz_diffuse_times_pi(alpha, q.wo.as_dvec3().into(), q.wi.as_dvec3().into());
        let proxima = e.f.x as f64 * std::f64::consts::PI;
        let ep = (proxima - h).abs() / h;
        let el = (1.0 - h).abs() / h;
        let s = stats
            .entry(q.wo.z.acos().to_degrees().round() as i32)
            .or_default();
        s.0 += ep;
        s.1 = s.1.max(ep);
        s.2 += el;
        s.3 = s.3.max(el);
        s.4 += 1;
    }
    for (to, s) in &stats {
        eprintln!(
            "θo = {to:>2}°, θi 0-80°, roughness 0.1-1 (coplanar): relative error against the microfacet diffuse: Proxima mean {:.1}% max {:.1}%, Lambert mean {:.1}% max {:.1}%",
            100.0 * s.0 / s.4 as f64,
            100.0 * s.1,
            100.0 * s.2 / s.4 as f64,
            100.0 * s.3
        );
    }
    // The fit's region (view along the normal): within 8% (5.6% measured, at θi = 80°), and far
    // closer than Lambert.
    let v = stats[&0];
    let (mean_p, max_p, mean_l) = (v.0 / v.4 as f64, v.1, v.2 / v.4 as f64);
    assert!(max_p < 0.08, "Proxima max error at V = N: {max_p:.3}");
    assert!(
        mean_p < 0.3 * mean_l,
        "Proxima {mean_p:.3} vs Lambert {mean_l:.3}"
    );
}

/// The slice image puts θh along x and θd along y: a white Lambertian is 1 wherever both
/// directions are above the horizon; retroreflection brightens only the large-θh, small-θd
/// corner and diffuse Fresnel only the large-θd, small-θh corner, as the talk's slices show.
#[test]
fn brdf_slice_shows_the_callisto_lobes_where_the_talk_puts_them() {
    let (gpu, probe) = probe();
    let lambert = ProbeMaterial {
        specular: 0.0,
        ..ProbeMaterial::new(BrdfModel::Callisto, Vec3::ONE, 0.5)
    };
    let size = 32;
    let at = |img: &gilab::compare::Image, th: f32, td: f32| {
        let x = (th / 90.0 * size as f32) as usize;
        let y = (td / 90.0 * size as f32) as usize;
        img.rgb[(y * size as usize + x) * 3]
    };
    let base = probe
        .slice(&gpu, &lambert, size, std::f32::consts::FRAC_PI_2)
        .unwrap();
    assert!((at(&base, 20.0, 20.0) - 1.0).abs() < 1e-4);
    assert!((at(&base, 80.0, 5.0) - 1.0).abs() < 1e-4);
    let with = |p: CallistoParams| {
        probe
            .slice(
                &gpu,
                &ProbeMaterial {
                    callisto: p,
                    ..lambert
                },
                size,
                std::f32::consts::FRAC_PI_2,
            )
            .unwrap()
    };
    let retro = with(CallistoParams {
        retroreflection: 3.0,
        ..CallistoParams::default()
    });
    let fresnel = with(CallistoParams {
        diffuse_fresnel: 3.0,
        ..CallistoParams::default()
    });
    eprintln!(
        "slice f·π: retro 3 at (θh 80°, θd 5°) {:.3}, at (5°, 80°) {:.3}; diffuse Fresnel 3 at (5°, 80°) {:.3}, at (80°, 5°) {:.3}",
        at(&retro, 80.0, 5.0),
        at(&retro, 5.0, 80.0),
        at(&fresnel, 5.0, 80.0),
        at(&fresnel, 80.0, 5.0)
    );
    assert!(at(&retro, 80.0, 5.0) > 1.5 && (at(&retro, 5.0, 80.0) - 1.0).abs() < 0.05);
    assert!(at(&fresnel, 5.0, 80.0) > 1.5 && (at(&fresnel, 80.0, 5.0) - 1.0).abs() < 0.05);
    // Geometry sanity on the CPU side.
    let (wo, wi) = slice_directions(0.0, 0.0, 0.0);
    assert!((wo - Vec3::Z).length() < 1e-6 && (wi - Vec3::Z).length() < 1e-6);
}

fn with_shading(mut scene: gilab::scene::Scene, toml_text: &str) -> gilab::scene::Scene {
    let s: gilab::scene::shading::ShadingSettings = toml::from_str(toml_text).unwrap();
    s.apply(&mut scene).unwrap();
    scene
}

/// End to end through the scene upload and every technique's shading: the reference renders the
/// same image under callisto at its defaults as under lambert-ggx (same seed), and a different
/// one under the talk's fits (material-balls).
#[test]
fn the_preset_model_reaches_the_renderers() {
    use gilab::scene::builtin;
    let size = [48, 32];
    let render =
        |scene| common::render_technique("reference", toml::Table::new(), scene, size, 4, 3, 0).0;
    let lambert = render(with_shading(builtin::cornell(), "brdf = \"lambert-ggx\""));
    let callisto = render(with_shading(builtin::cornell(), "brdf = \"callisto\""));
    let same = gilab::compare::metrics::compare(&callisto, &lambert)
        .unwrap()
        .rel_mse;
    let balls_l = render(with_shading(
        builtin::material_balls(),
        "brdf = \"lambert-ggx\"",
    ));
    let balls_c = render(with_shading(
        builtin::material_balls(),
        "brdf = \"callisto\"",
    ));
    let differ = gilab::compare::metrics::compare(&balls_c, &balls_l)
        .unwrap()
        .rel_mse;
    eprintln!("relMSE callisto-defaults vs lambert-ggx on cornell {same:.2e}; fitted materials on material-balls {differ:.2e}");
    assert!(same < 1e-6, "{same}");
    assert!(differ > 1e-3, "{differ}");
}

/// Rule 2 with the new models: every technique stays finite on hard-cases (roughness 0/1,
/// degenerate triangles, emission 1e6) and material-balls under callisto-proxima with the
/// parameters at the ends of their ranges.
#[test]
fn every_technique_stays_finite_under_extreme_callisto_parameters() {
    use gilab::scene::builtin;
    let extreme = r#"
        brdf = "callisto-proxima"
        [callisto]
        diffuse_fresnel = 256.0
        diffuse_fresnel_falloff = 0.0
        retroreflection = 256.0
        retroreflection_tangent_falloff = 0.0
        smooth_terminator = -1.0
        smooth_terminator_length = 1.0
        specular_fresnel_falloff = 1.0
        dual_specular_roughness_scale = 16.0
        dual_specular_opacity = 1.0
    "#;
    // Two techniques at a time (on a fresh machine this test is mostly shader compiles).
    common::on_two_threads(&["reference", "restir", "surfels", "lumen"], |&technique| {
        for (name, scene) in [
            ("hard-cases", builtin::hard_cases(1e6)),
            ("material-balls", builtin::material_balls()),
        ] {
            // render_technique fails on NaN/Inf samples counted by the shaders.
            let (img, _) = common::render_technique(
                technique,
                toml::Table::new(),
                with_shading(scene, extreme),
                [32, 32],
                3,
                1,
                0,
            );
            eprintln!("{technique} on {name}: max pixel {:.3e}", img.max_value());
            assert_eq!(img.non_finite_count(), 0, "{technique} on {name}");
        }
    });
}
