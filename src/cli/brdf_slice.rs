//! `gilab brdf-slice`: BRDF slice images (θh across, θd down, at azimuth φd) of the shading
//! models, evaluated by the same WGSL every technique shades with (the Callisto talk compares
//! models and fits this way).

use crate::compare::brdf_probe::{seed_material, BrdfProbe, ProbeMaterial, SEED_MATERIALS};
use crate::compare::{io, tonemap, Image};
use crate::gpu::{shaders::ShaderLibrary, BackendChoice, Gpu};
use crate::scene::shading::{BrdfModel, CallistoOverrides};
use anyhow::{anyhow, bail, Context, Result};
use glam::Vec3;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct SliceArgs {
    /// Models, comma-separated: lambert-ggx, callisto, callisto-proxima.
    #[arg(long, default_value = "lambert-ggx,callisto,callisto-proxima")]
    pub brdf: String,
    /// Start from one of the talk's Callisto fits: black-soft-plastic, blue-fabric,
    /// yellow-phenolic, yellow-plastic, gold-metallic-paint, light-red-paint.
    #[arg(long)]
    pub material: Option<String>,
    /// Perceptual roughness (GGX alpha = roughness²); default 0.5 or the fit's.
    #[arg(long)]
    pub roughness: Option<f32>,
    /// Base colour, linear: one value or R,G,B; default 0.5 or the fit's.
    #[arg(long)]
    pub base: Option<String>,
    #[arg(long)]
    pub metallic: Option<f32>,
    /// KHR_materials_specular factor (0 = no dielectric specular lobe).
    #[arg(long)]
    pub specular: Option<f32>,
    /// A Callisto parameter, as in a preset's [shading.callisto]: `retroreflection=3`,
    /// `diffuse_fresnel_tint=[1,0.85,0.7]`.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Image size in pixels (square).
    #[arg(long, default_value_t = 256)]
    pub size: u32,
    /// Azimuth of the light around the half vector, degrees (90: Burley's slice).
    #[arg(long, default_value_t = 90.0)]
    pub phi_d: f32,
    /// Display exposure in EV stops (PNG only; the EXR holds f·π).
    #[arg(long, default_value_t = 0.0)]
    pub exposure: f32,
    #[arg(long, default_value = "out/brdf-slice")]
    pub out: PathBuf,
}

impl SliceArgs {
    /// The material to slice, before the model is chosen (bad input fails before GPU work).
    fn material(&self) -> Result<(String, ProbeMaterial)> {
        let (name, mut m) = match &self.material {
            Some(n) => (
                n.clone(),
                seed_material(n).ok_or_else(|| {
                    anyhow!(
                        "unknown material '{n}' (available: {})",
                        SEED_MATERIALS.join(", ")
                    )
                })?,
            ),
            None => (
                "custom".to_string(),
                ProbeMaterial::new(BrdfModel::Callisto, Vec3::splat(0.5), 0.5),
            ),
        };
        if let Some(r) = self.roughness {
            m.roughness = r;
        }
        if let Some(b) = &self.base {
            let v: Vec<f32> = b
                .split(',')
                .map(|s| s.trim().parse::<f32>())
                .collect::<Result<_, _>>()
                .with_context(|| format!("--base '{b}': expected a number or R,G,B"))?;
            m.base = match v.as_slice() {
                [g] => Vec3::splat(*g),
                [r, g, b] => Vec3::new(*r, *g, *b),
                _ => bail!("--base '{b}': expected a number or R,G,B"),
            };
        }
        if let Some(v) = self.metallic {
            m.metallic = v;
        }
        if let Some(v) = self.specular {
            m.specular = v;
        }
        let table = self.set.join("\n");
        let o: CallistoOverrides =
            toml::from_str(&table).map_err(|e| anyhow!("--set: {}", e.message()))?;
        o.apply(&mut m.callisto);
        m.callisto.check()?;
        for (what, v) in [
            ("roughness", m.roughness),
            ("metallic", m.metallic),
            ("specular", m.specular),
        ] {
            if !(0.0..=1.0).contains(&v) {
                bail!("--{what} {v} is outside [0, 1]");
            }
        }
        if m.base.min_element() < 0.0 || m.base.max_element() > 1.0 {
            bail!("--base must lie in [0, 1]");
        }
        Ok((name, m))
    }
}

fn to_png(img: &Image, exposure: f32) -> Vec<u8> {
    let scale = 2f32.powf(exposure);
    img.rgb
        .chunks_exact(3)
        .flat_map(|p| {
            let c =
                |v: f32| (tonemap::linear_to_srgb((v * scale).clamp(0.0, 1.0)) * 255.0 + 0.5) as u8;
            [c(p[0]), c(p[1]), c(p[2]), 255]
        })
        .collect()
}

pub fn run(args: &SliceArgs, backend: BackendChoice) -> Result<()> {
    let models: Vec<BrdfModel> = args
        .brdf
        .split(',')
        .map(|s| BrdfModel::parse(s.trim()))
        .collect::<Result<_>>()?;
    let (name, base) = args.material()?;
    if !(8..=2048).contains(&args.size) {
        bail!("--size {} must lie in 8..=2048", args.size);
    }
    let gpu = Gpu::new(backend)?;
    println!("adapter: {}", gpu.summary);
    let probe = BrdfProbe::new(&gpu, &ShaderLibrary::discover())?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let size = args.size;
    let gap = 4;
    let strip_w = models.len() as u32 * (size + gap) - gap;
    let mut strip = vec![255u8; (strip_w * size * 4) as usize];
    for (k, model) in models.iter().enumerate() {
        let m = ProbeMaterial {
            brdf: *model,
            ..base
        };
        let img = probe.slice(&gpu, &m, size, args.phi_d.to_radians())?;
        let stem = format!("{name}-{}-r{}", model.name(), m.roughness);
        let png = to_png(&img, args.exposure);
        for y in 0..size {
            let src = (y * size * 4) as usize;
            let dst = ((y * strip_w + k as u32 * (size + gap)) * 4) as usize;
            strip[dst..dst + (size * 4) as usize]
                .copy_from_slice(&png[src..src + (size * 4) as usize]);
        }
        let png_path = args.out.join(format!("{stem}.png"));
        io::write_png_rgba(&png_path, size, size, png)?;
        io::write_exr(&args.out.join(format!("{stem}.exr")), &img)?;
        let max = img.rgb.iter().cloned().fold(0.0f32, f32::max);
        println!(
            "{}: f·π max {max:.3} (θh → right, θd → down, φd {}°)",
            png_path.display(),
            args.phi_d
        );
    }
    if models.len() > 1 {
        let path = args
            .out
            .join(format!("{name}-r{}-models.png", base.roughness));
        io::write_png_rgba(&path, strip_w, size, strip)?;
        let names: Vec<&str> = models.iter().map(|m| m.name()).collect();
        println!("{}: {} left to right", path.display(), names.join(", "));
    }
    Ok(())
}
