//! Shared helpers for the integration tests: two GPU devices per test binary, small renders.
#![allow(dead_code)]

pub mod gltf_writer;
pub mod targets;

use gilab::compare::Image;
use gilab::gpu::{shaders::ShaderLibrary, BackendChoice, Gpu};
use gilab::render::{engine::Engine, engine::EngineSettings, RayCounts};
use gilab::scene::Scene;
use gilab::techniques::create_technique;
use std::sync::{Arc, OnceLock};

/// The device a GPU test renders on (lavapipe in CI). Tests fail, not skip, without one.
///
/// A binary has two devices (`GILAB_TEST_DEVICES`, 1 or 2, default 2), and each test thread
/// keeps the one that fewer running tests held when it first asked. Lavapipe compiles a shader
/// variant at its first dispatch on its queue's thread: with one device, a compile (up to 19 s
/// for the largest passes on a fresh machine, whose shader cache is empty) held up the other
/// test thread's work, and one of the two cores stood idle.
pub fn gpu() -> Arc<Gpu> {
    use std::sync::atomic::{AtomicUsize, Ordering};
    static GPUS: [OnceLock<Arc<Gpu>>; 2] = [OnceLock::new(), OnceLock::new()];
    static HOLDERS: [AtomicUsize; 2] = [AtomicUsize::new(0), AtomicUsize::new(0)];
    static CHOOSING: std::sync::Mutex<()> = std::sync::Mutex::new(());
    /// A test thread's hold on device `.0`, given up when the thread ends.
    struct Held(usize);
    impl Drop for Held {
        fn drop(&mut self) {
            HOLDERS[self.0].fetch_sub(1, Ordering::SeqCst);
        }
    }
    thread_local! {
        static HELD: std::cell::OnceCell<Held> = const { std::cell::OnceCell::new() };
    }
    let devices = match std::env::var("GILAB_TEST_DEVICES").as_deref() {
        Ok("1") => 1,
        _ => 2,
    };
    let slot = HELD.with(|held| {
        held.get_or_init(|| {
            let _choosing = CHOOSING.lock().unwrap_or_else(|e| e.into_inner());
            let slot = (0..devices)
                .min_by_key(|&i| HOLDERS[i].load(Ordering::SeqCst))
                .unwrap();
            HOLDERS[slot].fetch_add(1, Ordering::SeqCst);
            Held(slot)
        })
        .0
    });
    GPUS[slot]
        .get_or_init(|| {
            let gpu = Gpu::new(BackendChoice::Auto)
                .expect("a GPU adapter (install mesa-vulkan-drivers for lavapipe)");
            eprintln!("test adapter {slot}: {}", gpu.summary);
            Arc::new(gpu)
        })
        .clone()
}

pub struct Render {
    pub image: Image,
    pub variance: Option<Image>,
    pub rays: RayCounts,
    pub engine: Engine,
}

/// An engine for a technique with parameters on a scene's default camera.
pub fn engine(
    technique: &str,
    params: toml::Table,
    scene: Scene,
    size: [u32; 2],
    seed: u32,
) -> Engine {
    let mut t = create_technique(technique).unwrap();
    t.set_params_from_table(&params).unwrap();
    let camera = scene.default_camera();
    let settings = EngineSettings {
        extent: size,
        seed,
        camera,
    };
    Engine::new(gpu(), ShaderLibrary::discover(), scene, t, settings).unwrap()
}

/// Runs `f` on every item, two items at a time on two threads, and returns the results in the
/// items' order (a panic in `f` fails the test). For tests that go through independent cases
/// one after another: each thread keeps its own device (`gpu()`), so on a fresh machine, whose
/// shader cache is empty, two cases compile their passes at once (lavapipe compiles a variant
/// at its first dispatch, on the device's queue thread) instead of one core standing idle.
pub fn on_two_threads<T: Sync, R: Send>(items: &[T], f: impl Fn(&T) -> R + Sync) -> Vec<R> {
    use std::sync::atomic::{AtomicUsize, Ordering};
    let next = AtomicUsize::new(0);
    let results: std::sync::Mutex<Vec<Option<R>>> =
        std::sync::Mutex::new(items.iter().map(|_| None).collect());
    std::thread::scope(|scope| {
        for _ in 0..2 {
            scope.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::SeqCst);
                let Some(item) = items.get(i) else { break };
                let r = f(item);
                results.lock().unwrap_or_else(|e| e.into_inner())[i] = Some(r);
            });
        }
    });
    results
        .into_inner()
        .unwrap_or_else(|e| e.into_inner())
        .into_iter()
        .map(|r| r.expect("every item ran"))
        .collect()
}

/// Copies a directory tree (a shader folder a test edits).
pub fn copy_dir(from: &std::path::Path, to: &std::path::Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap().flatten() {
        let p = e.path();
        if p.is_dir() {
            copy_dir(&p, &to.join(e.file_name()));
        } else {
            std::fs::copy(&p, to.join(e.file_name())).unwrap();
        }
    }
}

/// Renders `frames` frames of a technique (after a reset, with FrameUniforms `flags`) and
/// returns the accumulated image and ray counts; fails on NaN/Inf samples.
pub fn render_technique(
    technique: &str,
    params: toml::Table,
    scene: Scene,
    size: [u32; 2],
    frames: u32,
    seed: u32,
    flags: u32,
) -> (Image, RayCounts) {
    let mut e = engine(technique, params, scene, size, seed);
    e.flags = flags;
    e.reset();
    for _ in 0..frames {
        e.render_frame().unwrap();
    }
    let rays = e.ray_counts().unwrap();
    assert_eq!(rays.invalid_samples, 0, "NaN/Inf samples");
    (e.read_output().unwrap(), rays)
}

/// `warmup` frames (the technique's caches fill), the accumulation reset, then `frames`
/// accumulated; fails on NaN/Inf samples. The image, the accumulated run's rays, the engine.
pub fn render_after_warmup(
    technique: &str,
    params: toml::Table,
    scene: Scene,
    size: [u32; 2],
    warmup: u32,
    frames: u32,
    seed: u32,
) -> (Image, RayCounts, Engine) {
    let mut e = engine(technique, params, scene, size, seed);
    for _ in 0..warmup {
        e.render_frame().unwrap();
    }
    e.reset();
    for _ in 0..frames {
        e.render_frame().unwrap();
    }
    let rays = e.ray_counts().unwrap();
    assert_eq!(rays.invalid_samples, 0, "NaN/Inf samples");
    (e.read_output().unwrap(), rays, e)
}

/// Renders `scene` with the reference path tracer: `spp` samples per pixel in frames of `spf`.
pub fn render_reference(
    scene: Scene,
    size: [u32; 2],
    spp: u32,
    spf: u32,
    seed: u32,
    max_depth: u32,
) -> Render {
    let mut params = toml::Table::new();
    params.insert("samples_per_frame".into(), (spf as i64).into());
    params.insert("max_depth".into(), (max_depth as i64).into());
    let mut engine = engine("reference", params, scene, size, seed);
    for _ in 0..spp.div_ceil(spf) {
        engine.render_frame().unwrap();
    }
    let image = engine.read_output().unwrap();
    let variance = engine.read_variance().unwrap();
    let rays = engine.ray_counts().unwrap();
    Render {
        image,
        variance,
        rays,
        engine,
    }
}

/// A converged reference image (the reference path tracer, `spp` samples per pixel in frames of
/// at most 64, `max_depth` 0 = unbounded, FrameUniforms `flags`), rendered once and shared by
/// every test and every test binary: kept in memory per binary and as a lossless float EXR under
/// cargo's `target/tmp/gilab-references/`, or read from the repository's shipped ones
/// (`shipped_references`). The file name hashes everything the image depends
/// on: the scene's content (`scene_content_hash`), the arguments, and every file of the
/// reference's footprint (`in_reference_footprint`), so a change to what the reference runs
/// renders it again. On
/// lavapipe a 128² Cornell box at 1,024 spp costs about 110 s: several binaries share it.
pub fn shared_reference(
    scene: Scene,
    size: [u32; 2],
    spp: u32,
    seed: u32,
    max_depth: u32,
    flags: u32,
) -> Image {
    static MEMORY: std::sync::Mutex<Vec<(u64, Image)>> = std::sync::Mutex::new(Vec::new());
    let key = shared_reference_key(&scene, size, spp, seed, max_depth, flags);
    // Held while rendering: a second test asking for the same truth waits for it.
    let mut memory = MEMORY.lock().unwrap_or_else(|e| e.into_inner());
    if let Some((_, img)) = memory.iter().find(|(k, _)| *k == key) {
        return img.clone();
    }
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("gilab-references");
    let name = format!("{key:016x}.exr");
    let file = dir.join(&name);
    let read = |path: &std::path::Path| {
        gilab::compare::io::read_exr(path)
            .ok()
            .filter(|img| [img.width, img.height] == size)
    };
    let img = match read(&file).or_else(|| read(&shipped_references().join(&name))) {
        Some(img) => img,
        None => {
            let (img, _) = reference_render(scene, size, spp, seed, max_depth, flags);
            // Written under another name and renamed: a reader never sees half a file.
            std::fs::create_dir_all(&dir).unwrap();
            let part = dir.join(format!("{key:016x}.{}.part.exr", std::process::id()));
            gilab::compare::io::write_exr(&part, &img).unwrap();
            std::fs::rename(&part, &file).unwrap();
            img
        }
    };
    if std::env::var_os("GILAB_SHIP_REFERENCES").is_some() {
        ship_reference(&name, &img);
    }
    memory.push((key, img.clone()));
    img
}

/// Images a test renders with the reference path tracer alone and cannot ask `shared_reference`
/// for (several depths of one render, a variance): rendered by `render` once, then read back,
/// kept and shipped like `shared_reference`'s. The names hash the footprint's sources
/// (`source_hash`), the scene's content and `what`, which must name every other setting of the
/// render (size, samples, seed, parameters).
pub fn shared_reference_images(
    what: &str,
    scene: &Scene,
    render: impl FnOnce() -> Vec<Image>,
) -> Vec<Image> {
    use std::hash::{Hash, Hasher};
    let mut h = fnv::FnvHasher::default();
    source_hash().hash(&mut h);
    scene_content_hash(scene, 1).hash(&mut h);
    what.hash(&mut h);
    let key = h.finish();
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("gilab-references");
    let names_from = |count: usize| -> Vec<String> {
        (0..count).map(|i| format!("{key:016x}-{i}.exr")).collect()
    };
    // The count is written beside the images: a reader takes all of them or renders again.
    let count_file = format!("{key:016x}.count");
    let read_all = |base: &std::path::Path| -> Option<Vec<Image>> {
        let count: usize = std::fs::read_to_string(base.join(&count_file))
            .ok()?
            .trim()
            .parse()
            .ok()?;
        names_from(count)
            .iter()
            .map(|n| gilab::compare::io::read_exr(&base.join(n)).ok())
            .collect()
    };
    let images = match read_all(&dir).or_else(|| read_all(&shipped_references())) {
        Some(images) => images,
        None => {
            let images = render();
            std::fs::create_dir_all(&dir).unwrap();
            for (name, img) in names_from(images.len()).iter().zip(&images) {
                let part = dir.join(format!("{name}.{}.part.exr", std::process::id()));
                gilab::compare::io::write_exr(&part, img).unwrap();
                std::fs::rename(&part, dir.join(name)).unwrap();
            }
            std::fs::write(dir.join(&count_file), images.len().to_string()).unwrap();
            images
        }
    };
    if std::env::var_os("GILAB_SHIP_REFERENCES").is_some() {
        for (name, img) in names_from(images.len()).iter().zip(&images) {
            ship_reference(name, img);
        }
        let shipped = shipped_references().join(&count_file);
        std::fs::write(shipped, images.len().to_string()).unwrap();
    }
    images
}

/// The name (without `.exr`) of `shared_reference`'s image of these arguments: a hash of the
/// sources, the scene's content and the arguments.
pub fn shared_reference_key(
    scene: &Scene,
    size: [u32; 2],
    spp: u32,
    seed: u32,
    max_depth: u32,
    flags: u32,
) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut h = fnv::FnvHasher::default();
    source_hash().hash(&mut h);
    let frames = spp.div_ceil(spp.min(64));
    scene_content_hash(scene, frames).hash(&mut h);
    (size, spp, seed, max_depth, flags).hash(&mut h);
    h.finish()
}

/// The references shipped with the repository (`tests/data/references/`): the EXRs
/// `shared_reference` renders, under the same names, committed at the sources they were
/// rendered from, so that a fresh checkout (CI) reads them instead of rendering them again
/// (most of half an hour of lavapipe). The name hashes the reference's footprint
/// (`in_reference_footprint`), so a change there misses them and renders as before. `tools/ship-references.sh`
/// makes them; `shipped_references_are_what_these_sources_render` (gpu) renders one again.
pub fn shipped_references() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/references")
}

/// With `GILAB_SHIP_REFERENCES` set, every reference a test reads is also written to the
/// shipped folder. The folder holds one source state: `SOURCE` names it, and the first
/// reference of another state empties the folder first.
fn ship_reference(name: &str, img: &Image) {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _guard = LOCK.lock().unwrap_or_else(|e| e.into_inner());
    let dir = shipped_references();
    let stamp = dir.join("SOURCE");
    let source = format!("{:016x}\n", source_hash());
    if std::fs::read_to_string(&stamp).ok().as_deref() != Some(source.as_str()) {
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(&stamp, &source).unwrap();
    }
    let file = dir.join(name);
    if !file.exists() {
        std::fs::create_dir_all(file.parent().unwrap()).unwrap();
        gilab::compare::io::write_exr(&file, img).unwrap();
    }
}

/// The reference path tracer at `spp` samples per pixel (in frames of at most 64), `max_depth`
/// (0 = unbounded) and FrameUniforms `flags`: the image and its ray counts.
pub fn reference_render(
    scene: Scene,
    size: [u32; 2],
    spp: u32,
    seed: u32,
    max_depth: u32,
    flags: u32,
) -> (Image, RayCounts) {
    let spf = spp.min(64);
    let mut params = toml::Table::new();
    params.insert("samples_per_frame".into(), (spf as i64).into());
    params.insert("max_depth".into(), (max_depth as i64).into());
    render_technique(
        "reference",
        params,
        scene,
        size,
        spp.div_ceil(spf),
        seed,
        flags,
    )
}

/// A hash of everything in `scene` that a reference image of it depends on: geometry and its
/// attributes (positions, normals, both UV sets, tangents), triangles and their materials,
/// materials, textures and the environment map by content, punctual lights, camera, sky,
/// instances and named objects, the pose, and, for a scene that plays, the pose of each of the
/// `frames` frames a render takes (positions, instance transforms and lights at each frame's
/// scene time, as the engine plays it).
pub fn scene_content_hash(scene: &Scene, frames: u32) -> u64 {
    use std::hash::{Hash, Hasher};
    fn floats<H: Hasher>(h: &mut H, v: impl IntoIterator<Item = f32>) {
        for x in v {
            x.to_bits().hash(h);
        }
    }
    fn geometry<H: Hasher>(h: &mut H, s: &Scene) {
        floats(h, s.positions.iter().flat_map(|p| p.to_array()));
        s.instances.len().hash(h);
        for i in &s.instances {
            (i.mesh, i.first_triangle, i.triangle_count).hash(h);
            floats(h, i.transform.to_cols_array());
        }
        format!("{:?} {:?}", s.lights, s.posed_at).hash(h);
    }
    let mut h = fnv::FnvHasher::default();
    scene.name.hash(&mut h);
    geometry(&mut h, scene);
    floats(&mut h, scene.normals.iter().flat_map(|p| p.to_array()));
    floats(&mut h, scene.uvs.iter().flat_map(|p| p.to_array()));
    floats(&mut h, scene.uvs1.iter().flat_map(|p| p.to_array()));
    floats(&mut h, scene.tangents.iter().flat_map(|p| p.to_array()));
    scene.triangles.hash(&mut h);
    scene.triangle_material.hash(&mut h);
    for t in &scene.textures {
        (t.width, t.height, &t.rgba8).hash(&mut h);
    }
    format!(
        "{:?} {:?} {:?} {:?} {:?}",
        scene.materials, scene.camera, scene.sky, scene.objects, scene.animations
    )
    .hash(&mut h);
    if let Some(env) = &scene.environment {
        (env.width(), env.height()).hash(&mut h);
        floats(&mut h, [env.rotation_deg, env.intensity]);
        floats(&mut h, env.texels().iter().flatten().copied());
    }
    if let Some(motion) = &scene.motion {
        format!("{:?} {:?}", motion.time_scale, motion.play_until).hash(&mut h);
        // Frame k is shown at time_after(t0, k): the poses the render will see.
        let t0 = scene.posed_at.unwrap_or(0.0);
        let mut posed = scene.clone();
        for k in 0..frames.max(1) {
            let t = motion.time_after(t0, k, gilab::render::engine::PLAYBACK_FPS);
            motion.apply(&mut posed, t).unwrap();
            geometry(&mut h, &posed);
        }
    }
    h.finish()
}

/// Whether a reference render can depend on the file at `rel` (a path from the repository root,
/// `/`-separated): the reference path tracer's **footprint**. Every file of `src/` and
/// `shaders/` is in it but the other techniques' folders, the parts other than the light tree
/// (which the reference's NEE can use), and the viewer (`src/app/`); in `shaders/`, the shared
/// modules and the reference's, frame and compare folders. `Cargo.lock` and `Cargo.toml` are in
/// it. So a change to another technique or part keeps the references (shipped ones included),
/// and a change to anything a reference runs renders them again. Two tests hold the footprint
/// to the code: `cpu::reference_footprint_is_closed` (no footprint Rust file names an excluded
/// module but the technique registry and the viewer's entry) and
/// `gpu::shipped_references_are_what_these_sources_render` (every shader file a reference engine
/// compiles, and every module those import, lies in it).
pub fn in_reference_footprint(rel: &str) -> bool {
    if rel == "Cargo.lock" || rel == "Cargo.toml" {
        return true;
    }
    if let Some(src) = rel.strip_prefix("src/") {
        if let Some(technique) = src.strip_prefix("techniques/") {
            return technique == "mod.rs" || technique.starts_with("reference/");
        }
        if let Some(part) = src.strip_prefix("parts/") {
            return part == "light_tree.rs";
        }
        return !src.starts_with("app/");
    }
    if let Some(shader) = rel.strip_prefix("shaders/") {
        return ["common/", "reference/", "frame/", "compare/"]
            .iter()
            .any(|d| shader.starts_with(d))
            || shader == "parts/light_tree.wgsl";
    }
    false
}

/// Every file of `src/`, `shaders/`, `Cargo.lock` and `Cargo.toml`, as sorted paths from the
/// repository root.
pub fn source_files() -> Vec<String> {
    fn walk(dir: &std::path::Path, files: &mut Vec<std::path::PathBuf>) {
        for entry in std::fs::read_dir(dir).unwrap().flatten() {
            let path = entry.path();
            if path.is_dir() {
                walk(&path, files);
            } else {
                files.push(path);
            }
        }
    }
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    walk(&root.join("src"), &mut files);
    walk(&root.join("shaders"), &mut files);
    files.push(root.join("Cargo.lock"));
    files.push(root.join("Cargo.toml"));
    let mut rel: Vec<String> = files
        .iter()
        .map(|f| {
            f.strip_prefix(root)
                .unwrap()
                .to_string_lossy()
                .replace('\\', "/")
        })
        .collect();
    rel.sort();
    rel
}

/// Hash of the reference's footprint (`in_reference_footprint`: paths and contents), once per
/// binary: what the shared and shipped references are rendered from.
fn source_hash() -> u64 {
    static HASH: OnceLock<u64> = OnceLock::new();
    *HASH.get_or_init(|| {
        use std::hash::Hasher;
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let mut h = fnv::FnvHasher::default();
        for rel in source_files()
            .into_iter()
            .filter(|f| in_reference_footprint(f))
        {
            h.write(rel.as_bytes());
            h.write(&std::fs::read(root.join(&rel)).unwrap());
        }
        h.finish()
    })
}

pub fn luminance(p: [f64; 3]) -> f64 {
    0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]
}

/// Form factor from a differential area to a parallel rectangle a × b at distance h, the area
/// lying under one of the rectangle's corners. Signed sizes subtract, so four of them give any
/// point under (or beside) a rectangle.
pub fn corner_form_factor(a: f64, b: f64, h: f64) -> f64 {
    let (x, y) = (a.abs() / h, b.abs() / h);
    let (sx, sy) = ((1.0 + x * x).sqrt(), (1.0 + y * y).sqrt());
    let f = (x / sx * (y / sx).atan() + y / sy * (x / sy).atan()) / (2.0 * std::f64::consts::PI);
    f * a.signum() * b.signum()
}

/// Negative controls for an energy-ratio bound and a relMSE bound of `img` against `truth`
/// (issue 55): the same checks must fail on `img` with a known bias injected. Every channel
/// 1.5 bounds off (away from 1, so the image's own deviation cannot hide it) must leave the
/// energy bound; the 32×32 block at the image's centre set to black must exceed the relMSE
/// bound. These checks are coarse: a 2% bias on one channel moves luminance by at most 1.4%,
/// and on ReSTIR's Cornell box at 128² a black 16×16 block read relMSE 7.9e-3, under its 1e-2
/// bound (2026-11-28). Local and per-channel errors are what the block checks of the Mitsuba
/// comparison and of ReSTIR PT's unbiasedness test see.
pub fn assert_energy_and_error_controls_fail(
    img: &Image,
    truth: &Image,
    energy_bound: f64,
    rel_mse_bound: f64,
) {
    let energy = |i: &Image| luminance(i.mean());
    let ratio = energy(img) / energy(truth);
    let f = if ratio >= 1.0 {
        1.0 + 1.5 * energy_bound
    } else {
        1.0 - 1.5 * energy_bound
    };
    let mut scaled = img.clone();
    scaled.rgb.iter_mut().for_each(|v| *v *= f as f32);
    let biased = energy(&scaled) / energy(truth);
    assert!(
        (biased - 1.0).abs() >= energy_bound,
        "control: an image {f:.3}x as bright passes the energy bound ({biased:.4})"
    );
    let mut dark = img.clone();
    let (cx, cy) = (img.width as usize / 2, img.height as usize / 2);
    for y in cy - 16..cy + 16 {
        for x in cx - 16..cx + 16 {
            let i = 3 * (y * img.width as usize + x);
            dark.rgb[i..i + 3].fill(0.0);
        }
    }
    let rel = gilab::compare::metrics::compare(&dark, truth)
        .unwrap()
        .rel_mse;
    assert!(
        rel >= rel_mse_bound,
        "control: a black 32x32 block passes the relMSE bound ({rel:.3e})"
    );
}

/// A fresh folder for one test's outputs: `gilab-<binary>-<pid>-<name>` in the temp dir.
pub fn tmp_dir(binary: &str, name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("gilab-{binary}-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// One reference cache per test binary: references are rendered once. It starts with the
/// experiments' references shipped for these sources (`tests/data/references/experiments/`:
/// the app's cache keys leave the sources out, so they are read only while the shipped folder's
/// `SOURCE` is these sources).
pub fn reference_cache(binary: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("gilab-{binary}-{}-cache", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    if shipped_references_are_current() {
        let shipped = shipped_references().join("experiments");
        for e in std::fs::read_dir(shipped).into_iter().flatten().flatten() {
            let _ = std::fs::copy(e.path(), d.join(e.file_name()));
        }
    }
    d
}

/// A line for CI's report (`.ci/run` sets `GILAB_CI_NOTES` and prints the file after the tests;
/// libtest keeps a passing test's output to itself).
pub fn ci_note(line: &str) {
    use std::io::Write;
    if let Some(path) = std::env::var_os("GILAB_CI_NOTES") {
        if let Ok(mut f) = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)
        {
            let _ = writeln!(f, "{line}");
        }
    }
}

/// Whether the shipped references are of these sources (their `SOURCE` stamp).
pub fn shipped_references_are_current() -> bool {
    let stamp = std::fs::read_to_string(shipped_references().join("SOURCE")).unwrap_or_default();
    stamp.trim() == format!("{:016x}", source_hash())
}

/// With `GILAB_SHIP_REFERENCES` set, the reference EXRs an experiment left in `cache` are
/// shipped too (beside `shared_reference`'s, under `experiments/`).
fn ship_experiment_references(cache: &std::path::Path) {
    if std::env::var_os("GILAB_SHIP_REFERENCES").is_none() {
        return;
    }
    for e in std::fs::read_dir(cache).into_iter().flatten().flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        if name.ends_with(".exr") {
            if let Ok(img) = gilab::compare::io::read_exr(&e.path()) {
                ship_reference(&format!("experiments/{name}"), &img);
            }
        }
    }
}

/// One GPU experiment at a time in a binary: lavapipe shares the two CPU cores, and timing
/// checks would measure the other tests' load.
pub fn serial() -> std::sync::MutexGuard<'static, ()> {
    static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());
    SERIAL.lock().unwrap_or_else(|e| e.into_inner())
}

/// Runs `gilab converge` on a preset into `out` (quiet, the binary's reference cache) and
/// reads back its summary and rows.
pub fn converge_into(
    binary: &str,
    p: &gilab::preset::LoadedPreset,
    out: &std::path::Path,
    shard: Option<gilab::experiment::Shard>,
) -> anyhow::Result<(
    gilab::experiment::run::Summary,
    Vec<gilab::experiment::run::Row>,
)> {
    use gilab::experiment::run;
    let opts = run::ConvergeOptions {
        out: out.to_path_buf(),
        cache: reference_cache(binary),
        shard,
        quiet: true,
    };
    run::converge(gpu(), p, &opts)?;
    ship_experiment_references(&opts.cache);
    run::read_output_dir(out)
}

/// The mean of each 2×2 block: a 2w×2h truth as a w×h image (each pixel of an image is the
/// average over its footprint, so this is the truth of the half-size render).
pub fn half(img: &Image) -> Image {
    let (w, h) = (img.width / 2, img.height / 2);
    let mut out = Image::new(w, h);
    for y in 0..h as usize {
        for x in 0..w as usize {
            for c in 0..3 {
                let at = |dx: usize, dy: usize| {
                    img.rgb[((2 * y + dy) * img.width as usize + 2 * x + dx) * 3 + c]
                };
                out.rgb[(y * w as usize + x) * 3 + c] =
                    0.25 * (at(0, 0) + at(1, 0) + at(0, 1) + at(1, 1));
            }
        }
    }
    out
}

/// The Cornell truth at 128² (512 spp) that Lumen's, ReSTIR's, the surfels' and the
/// denoiser's tests share.
pub fn cornell_truth_128() -> Image {
    shared_reference(gilab::scene::builtin::cornell(), [128, 128], 512, 11, 0, 0)
}

/// The Cornell truth at 64²: the shared 128² one, halved, so 2,048 paths per 64² pixel and no
/// second render.
pub fn cornell_truth_64() -> Image {
    half(&cornell_truth_128())
}

/// Minimal base64 for test fixtures (standard alphabet, padded).
pub mod base64 {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    pub fn decode(s: &str) -> Vec<u8> {
        let val = |c: u8| A.iter().position(|&a| a == c).unwrap() as u32;
        let clean: Vec<u8> = s.bytes().filter(|&c| c != b'=').collect();
        let mut out = Vec::new();
        for chunk in clean.chunks(4) {
            let mut n = 0u32;
            for (i, &c) in chunk.iter().enumerate() {
                n |= val(c) << (18 - 6 * i);
            }
            let bytes = [(n >> 16) as u8, (n >> 8) as u8, n as u8];
            out.extend_from_slice(&bytes[..chunk.len() - 1]);
        }
        out
    }
    pub fn encode(b: &[u8]) -> String {
        let mut out = String::new();
        for chunk in b.chunks(3) {
            let n = (chunk[0] as u32) << 16
                | (*chunk.get(1).unwrap_or(&0) as u32) << 8
                | *chunk.get(2).unwrap_or(&0) as u32;
            for i in 0..4 {
                if i <= chunk.len() {
                    out.push(A[((n >> (18 - 6 * i)) & 63) as usize] as char);
                } else {
                    out.push('=');
                }
            }
        }
        out
    }
}

/// Keyframe data of `animated_box_room`, one accessor each: (floats, components, type).
pub type KeyData = Vec<(Vec<f32>, usize, &'static str)>;

/// The box room (scenes/box-room) with two animations added, written into `dir`: "slide"
/// moves the panel light (node 2, LINEAR translation 0 -> 2 along x over 2 s), turns the cube
/// (node 3, LINEAR rotation 45° -> 135° about y) and carries the lamp (node 4, CUBICSPLINE
/// translation); "blink" scales the cube (STEP: 1.5, 0.5, 0.5 at 0, 0.25, 1 s). The file's path
/// and the keyframe data.
pub fn animated_box_room(dir: &std::path::Path) -> (std::path::PathBuf, KeyData) {
    use glam::Quat;
    std::fs::create_dir_all(dir).unwrap();
    let text = std::fs::read_to_string("scenes/box-room/box-room.gltf").unwrap();
    let base: serde_json::Value = serde_json::from_str(&text).unwrap();
    let quat_y = |deg: f32| Quat::from_rotation_y(deg.to_radians());
    let (r0, r1) = (quat_y(45.0), quat_y(135.0));
    // Keyframe data, one accessor each: (floats, components, type).
    let f = |v: &[f32]| v.to_vec();
    let data: KeyData = vec![
        (f(&[0.0, 2.0]), 1, "SCALAR"),
        (f(&[0.0, 3.0, 0.0, 2.0, 3.0, 0.0]), 3, "VEC3"),
        ([r0.to_array(), r1.to_array()].concat(), 4, "VEC4"),
        // CUBICSPLINE: in-tangent, value, out-tangent per key.
        (
            f(&[
                0.0, 0.0, 0.0, -1.5, 1.5, 1.0, 1.0, 0.0, 0.0, //
                -1.0, 0.0, 0.0, 0.5, 1.5, 1.0, 0.0, 0.0, 0.0,
            ]),
            3,
            "VEC3",
        ),
        (f(&[0.0, 0.25, 1.0]), 1, "SCALAR"),
        (f(&[1.5, 1.5, 1.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5]), 3, "VEC3"),
    ];
    let mut doc = base.clone();
    let mut bytes = Vec::new();
    let buffer = doc["buffers"].as_array().unwrap().len();
    let first_accessor = doc["accessors"].as_array().unwrap().len();
    for (floats, comps, ty) in &data {
        let offset = bytes.len();
        bytes.extend(floats.iter().flat_map(|x| x.to_le_bytes()));
        let view = doc["bufferViews"].as_array().unwrap().len();
        doc["bufferViews"]
            .as_array_mut()
            .unwrap()
            .push(serde_json::json!({
                "buffer": buffer, "byteOffset": offset, "byteLength": floats.len() * 4
            }));
        let mut acc = serde_json::json!({
            "bufferView": view, "componentType": 5126, "count": floats.len() / comps, "type": ty
        });
        if *ty == "SCALAR" {
            acc["min"] = serde_json::json!([floats[0]]);
            acc["max"] = serde_json::json!([floats[floats.len() - 1]]);
        }
        doc["accessors"].as_array_mut().unwrap().push(acc);
    }
    doc["buffers"]
        .as_array_mut()
        .unwrap()
        .push(serde_json::json!({
            "byteLength": bytes.len(),
            "uri": format!("data:application/octet-stream;base64,{}", base64::encode(&bytes))
        }));
    let a = |i: usize| first_accessor + i;
    // Nodes: 2 panel, 3 cube, 4 lamp.
    doc["animations"] = serde_json::json!([
        {
            "name": "slide",
            "samplers": [
                {"input": a(0), "output": a(1), "interpolation": "LINEAR"},
                {"input": a(0), "output": a(2), "interpolation": "LINEAR"},
                {"input": a(0), "output": a(3), "interpolation": "CUBICSPLINE"}
            ],
            "channels": [
                {"sampler": 0, "target": {"node": 2, "path": "translation"}},
                {"sampler": 1, "target": {"node": 3, "path": "rotation"}},
                {"sampler": 2, "target": {"node": 4, "path": "translation"}}
            ]
        },
        {
            "name": "blink",
            "samplers": [{"input": a(4), "output": a(5), "interpolation": "STEP"}],
            "channels": [{"sampler": 0, "target": {"node": 3, "path": "scale"}}]
        }
    ]);
    let animated = dir.join("animated.gltf");
    std::fs::write(&animated, doc.to_string()).unwrap();
    (animated, data)
}

/// Distance from `p` to triangle `t` (closest point on the triangle).
pub fn point_triangle_distance(p: glam::Vec3, t: &[glam::Vec3; 3]) -> f32 {
    let (a, b, c) = (t[0], t[1], t[2]);
    let n = (b - a).cross(c - a);
    if n.length_squared() > 0.0 {
        let n = n.normalize();
        let q = p - n * (p - a).dot(n);
        let inside = [(a, b), (b, c), (c, a)]
            .iter()
            .all(|(u, v)| (*v - *u).cross(q - *u).dot(n) >= 0.0);
        if inside {
            return (p - q).length();
        }
    }
    [(a, b), (b, c), (c, a)]
        .iter()
        .map(|(u, v)| {
            let e = *v - *u;
            let s = ((p - *u).dot(e) / e.length_squared().max(1e-30)).clamp(0.0, 1.0);
            (p - (*u + e * s)).length()
        })
        .fold(f32::MAX, f32::min)
}

/// The distances (> 1 cm) to the nearest triangle of the points that lie off every surface:
/// caches on moving objects must stay on them.
pub fn off_surface(points: &[glam::Vec3], tris: &[[glam::Vec3; 3]]) -> Vec<f32> {
    points
        .iter()
        .map(|p| {
            tris.iter()
                .map(|t| point_triangle_distance(*p, t))
                .fold(f32::MAX, f32::min)
        })
        .filter(|d| *d > 0.01)
        .collect()
}

/// The thin-wall leak sequence of the caches' tests (the surfels' one, issue 55): `technique`
/// renders 48 frames of thin-wall (interior light off: its reference inside is exactly 0) from
/// outside, facing the sunlit wall, then is moved inside with its history kept and renders 8
/// frames accumulated. Returns the luminance of the outside view and of the inside view (the
/// leak), both 48².
pub fn thin_wall_leak(technique: &str, params: toml::Table) -> (f64, f64) {
    let scene = gilab::scene::builtin::thin_wall(0.0);
    let inside = scene.default_camera();
    let mut e = engine(technique, params, scene, [48, 48], 1);
    e.set_camera(gilab::scene::Camera {
        position: glam::Vec3::new(0.0, 1.5, -6.0),
        target: glam::Vec3::new(0.0, 0.5, -2.0),
        up: glam::Vec3::Y,
        fov_y: 60.0,
    });
    for _ in 0..48 {
        e.render_frame().unwrap();
    }
    let outside = luminance(e.read_output().unwrap().mean());
    e.move_camera(inside);
    for _ in 0..8 {
        e.render_frame().unwrap();
    }
    (outside, luminance(e.read_output().unwrap().mean()))
}

/// `technique` on the hard cases (emission 1e6, degenerate triangles, grazing angles), 48²,
/// seed 7, 6 frames, twice: both runs' images (no NaN/Inf sample counted in either).
pub fn hard_cases_twice(technique: &str) -> (Image, Image) {
    let run = || {
        let scene = gilab::scene::builtin::hard_cases(1e6);
        let mut e = engine(technique, toml::Table::new(), scene, [48, 48], 7);
        for _ in 0..6 {
            e.render_frame().unwrap();
        }
        assert_eq!(e.ray_counts().unwrap().invalid_samples, 0, "{technique}");
        e.read_output().unwrap()
    };
    (run(), run())
}
