//! Lumen-style GI on lavapipe, small sizes: the global distance field against exact distances
//! and against BVH hits, scrolling, the surface cache's direct light against the reference, the
//! furnace, the Cornell box against the reference in both tracing modes and both final gathers
//! (screen probes against part 1's per-pixel gather at equal rays, product against uniform
//! probe sampling, ray reassignment against the CDF draw and uniform on Cornell and courtyard,
//! screen traces against world traces only), leaks through a thin wall,
//! stability, determinism, debug views and parameter errors.

mod common;

use common::{engine, luminance, shared_reference};
use gilab::compare::{metrics, Image};
use gilab::render::engine::Engine;
use gilab::render::params::ParamValue;
use gilab::scene::{builtin, bvh::Bvh, Scene};
use gilab::techniques::lumen::{Lumen, QueryMode};
use glam::Vec3;

fn lumen(e: &Engine) -> &Lumen {
    let any: &dyn std::any::Any = e.technique.as_any();
    any.downcast_ref::<Lumen>().expect("a lumen engine")
}

fn frames(e: &mut Engine, n: u32) {
    for _ in 0..n {
        e.render_frame().unwrap();
    }
}

fn energy(img: &Image) -> f64 {
    luminance(img.mean())
}

/// Small settings every test starts from (64^3 clipmaps, a 512^2 atlas).
/// Test-sized Lumen: small clipmaps and atlas, and no debug views unless a test reads them (at
/// 128² they are three quarters of the apply pass: one more SDF trace per pixel).
fn small(extra: toml::Table) -> toml::Table {
    let mut t = toml::toml! { clipmap_resolution = 64
    atlas_size = 512
    debug_views = false };
    t.extend(extra);
    t
}

fn query(e: &Engine, mode: QueryMode, inputs: &[([f32; 3], [f32; 3])]) -> Vec<[[f32; 4]; 2]> {
    e.inspect(|ctx, t| {
        let any: &dyn std::any::Any = t.as_any();
        any.downcast_ref::<Lumen>()
            .unwrap()
            .query(ctx, mode, inputs)
            .unwrap()
    })
}

/// Plays the engine's scene clip: `time_scale` scene seconds per second of frames (60 frames a
/// second, so 60 moves the clip a second a frame).
fn play(e: &mut Engine, time_scale: f32) {
    std::sync::Arc::make_mut(
        std::sync::Arc::make_mut(&mut e.scene)
            .motion
            .as_mut()
            .unwrap(),
    )
    .time_scale = time_scale;
}

/// The surfaces the camera sees (position, geometric normal): origins for `QueryMode::CacheRay`.
fn visible_surfaces(e: &Engine) -> Vec<([f32; 3], [f32; 3])> {
    e.read_primary_surfaces()
        .unwrap()
        .unwrap()
        .iter()
        .filter(|s| s.pos[3] > 0.5)
        .map(|s| {
            let p = [s.pos[0], s.pos[1], s.pos[2]];
            let n = [s.geo_specular[0], s.geo_specular[1], s.geo_specular[2]];
            (p, n)
        })
        .collect()
}

/// xorshift: the tests' own random points, independent of the GPU's generator.
struct Rand(u64);
impl Rand {
    fn next(&mut self) -> f32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 40) as f32 / (1u64 << 24) as f32
    }
    fn in_box(&mut self, lo: Vec3, hi: Vec3) -> Vec3 {
        lo + (hi - lo) * Vec3::new(self.next(), self.next(), self.next())
    }
    fn dir(&mut self) -> Vec3 {
        loop {
            let v = Vec3::new(self.next(), self.next(), self.next()) * 2.0 - 1.0;
            if v.length_squared() > 1e-4 && v.length_squared() <= 1.0 {
                return v.normalize();
            }
        }
    }
}

/// Closest point on a triangle and whether it lies inside the face (not on an edge or vertex).
fn closest_on_triangle(p: Vec3, t: &[Vec3; 3]) -> (Vec3, bool) {
    let (a, b, c) = (t[0], t[1], t[2]);
    let n = (b - a).cross(c - a);
    let q = p - n * (p - a).dot(n) / n.length_squared();
    let inside = [(a, b), (b, c), (c, a)]
        .iter()
        .all(|(u, v)| (*v - *u).cross(q - *u).dot(n) >= 0.0);
    if inside {
        return (q, true);
    }
    let seg = |u: Vec3, v: Vec3| {
        let d = v - u;
        u + d * ((p - u).dot(d) / d.length_squared()).clamp(0.0, 1.0)
    };
    let best = [seg(a, b), seg(b, c), seg(c, a)]
        .into_iter()
        .min_by(|x, y| x.distance(p).total_cmp(&y.distance(p)))
        .unwrap();
    (best, false)
}

/// Exact distance to the scene (every triangle, no acceleration).
fn exact_distance(tris: &[[Vec3; 3]], p: Vec3) -> f32 {
    tris.iter()
        .map(|t| closest_on_triangle(p, t).0.distance(p))
        .fold(f32::MAX, f32::min)
}

/// The seed's sign, decided on the CPU with 256 random rays (the GPU casts `sign_rays`): inside
/// when most hits are back faces and at least 3/4 of the rays hit; None where either vote is
/// close (back faces between 15% and 85% of hits, hits between 60% and 90% of rays: the GPU's 16
/// rays cannot settle those).
fn robust_inside(bvh: &Bvh, tris: &[[Vec3; 3]], p: Vec3, rng: &mut Rand) -> Option<bool> {
    let (mut hits, mut back) = (0, 0);
    for _ in 0..256 {
        let d = rng.dir();
        if let Some((_, tri)) = bvh.closest_hit(tris, p, d, f32::MAX) {
            let t = &tris[tri as usize];
            hits += 1;
            back += ((t[1] - t[0]).cross(t[2] - t[0]).dot(d) > 0.0) as u32;
        }
    }
    let f = back as f32 / hits.max(1) as f32;
    let enclosed = hits as f32 / 256.0;
    match hits {
        0 => Some(false),
        _ if enclosed < 0.6 => Some(false),
        _ if enclosed < 0.9 => None,
        _ if f > 0.85 => Some(true),
        _ if f < 0.15 => Some(false),
        _ => None,
    }
}

fn scene_tris(s: &Scene) -> Vec<[Vec3; 3]> {
    s.triangles
        .iter()
        .map(|t| t.map(|i| s.positions[i as usize]))
        .collect()
}

/// 10,000 random points per scene: in the narrow band the distance is within one voxel of the
/// level that answered. The sign is checked where the field stores it, at voxel centres (the
/// same points snapped): outside a half-voxel shell it must match the back-face vote taken on the
/// CPU with 256 rays, wherever that vote is clear. Between centres trilinear filtering can flip
/// it within about half a voxel of a second surface; that count is reported.
#[test]
fn sdf_matches_exact_distances() {
    for (name, scene) in [
        ("cornell", builtin::cornell()),
        ("glossy", builtin::glossy()),
        ("thin-wall", builtin::thin_wall(1.0)),
    ] {
        let tris = scene_tris(&scene);
        let bvh = Bvh::build(&tris);
        let (lo, hi) = scene.bounds();
        let mut e = engine("lumen", small(toml::Table::new()), scene, [32, 32], 1);
        frames(&mut e, 1);
        let clip = lumen(&e).clipmaps().unwrap().clone();
        let mut rng = Rand(0x9e3779b97f4a7c15);
        let pad = (hi - lo) * 0.05;
        let points: Vec<Vec3> = (0..10_000)
            .map(|_| rng.in_box(lo - pad, hi + pad))
            .collect();
        let inputs: Vec<_> = points.iter().map(|p| (p.to_array(), [0.0; 3])).collect();
        let out: Vec<[f32; 4]> = query(&e, QueryMode::SdfDistance, &inputs)
            .iter()
            .map(|q| q[1])
            .collect();
        let centres: Vec<Vec3> = points
            .iter()
            .zip(&out)
            .map(|(p, o)| {
                let v = clip.voxel((o[2] as u32).min(clip.built - 1));
                ((*p / v).floor() + 0.5) * v
            })
            .collect();
        let inputs: Vec<_> = centres.iter().map(|p| (p.to_array(), [0.0; 3])).collect();
        let at_centres: Vec<[f32; 4]> = query(&e, QueryMode::SdfDistance, &inputs)
            .iter()
            .map(|q| q[1])
            .collect();
        let (mut band, mut worst, mut between_wrong, mut between_checked) = (0, 0.0f32, 0, 0);
        let (mut sign_checked, mut sign_wrong, mut over_one) = (0, 0, 0);
        for (i, (p, o)) in points.iter().zip(&out).enumerate() {
            let level = o[2] as u32;
            if level >= clip.built {
                continue;
            }
            let voxel = clip.voxel(level);
            let exact = exact_distance(&tris, *p);
            if exact >= 4.0 * voxel {
                // Outside the band the field only bounds the distance from below.
                assert!(
                    o[0] <= exact + voxel,
                    "{name}: {p} bound {} > exact {exact}",
                    o[0]
                );
                continue;
            }
            band += 1;
            let err = (o[0].abs() - exact).abs() / voxel;
            over_one += (err > 1.0) as u32;
            worst = worst.max(err);
            if exact > 0.5 * voxel {
                if let Some(inside) = robust_inside(&bvh, &tris, *p, &mut rng) {
                    between_checked += 1;
                    between_wrong += ((o[0] < 0.0) != inside) as u32;
                }
            }
            let c = at_centres[i];
            let exact_c = exact_distance(&tris, centres[i]);
            if exact_c <= 0.5 * voxel || c[2] as u32 != level || exact_c >= 4.0 * voxel {
                continue;
            }
            if let Some(inside) = robust_inside(&bvh, &tris, centres[i], &mut rng) {
                sign_checked += 1;
                sign_wrong += ((c[0] < 0.0) != inside) as u32;
            }
        }
        eprintln!(
            "{name}: levels {} (voxels {:.3}..{:.3}); {band} of 10000 points in the band, worst error {worst:.3} voxels; \
             sign wrong at {sign_wrong} of {sign_checked} voxel centres, at {between_wrong} of {between_checked} points between centres",
            clip.built,
            clip.voxel(0),
            clip.voxel(clip.built - 1)
        );
        assert!(band > 500, "{name}: too few points in the band ({band})");
        // Measured: worst 0.58 voxel, no wrong sign (the vote needs an enclosed point: behind
        // an open scene's walls there is no inside to flip to). Trilinear filtering at a convex
        // edge stays within a voxel.
        assert!(
            over_one == 0,
            "{name}: {over_one} of {band} points over a voxel off"
        );
        assert!(worst <= 1.0, "{name}: error {worst} voxels");
        assert!(
            sign_wrong == 0,
            "{name}: {sign_wrong} wrong signs at centres"
        );
        assert!(
            between_wrong * 200 <= between_checked,
            "{name}: {between_wrong} wrong signs"
        );
    }
}

/// Rays from random points in the Cornell box's free space, at least one voxel (of the finest
/// level holding them: the technique's surface bias) from every surface, sphere traced as the
/// technique does (with the expand), against the BVH's hits on the same rays. Asserted: no ray
/// passes through a surface (the SDF stops no later than 1.5 voxels past the BVH hit) and every
/// stop is on geometry (within 1.5 voxels of a triangle), for 99% of rays both hit. Reported: the
/// share within 1.5 voxels of the BVH hit's plane (the metric), which the expand lowers
/// by design: a grazing ray stops up to 0.87 voxel from a surface it passes. At the default 128^3.
#[test]
fn sdf_hits_match_bvh_hits() {
    let scene = builtin::cornell();
    let tris = scene_tris(&scene);
    let (lo, hi) = scene.bounds();
    let params = toml::toml! { clipmap_resolution = 128
    atlas_size = 512 };
    let mut e = engine("lumen", params, scene, [32, 32], 1);
    frames(&mut e, 1);
    let clip = lumen(&e).clipmaps().unwrap().clone();
    let mut rng = Rand(7);
    let inset = (hi - lo) * 0.1;
    let points: Vec<_> = (0..6000)
        .map(|_| (rng.in_box(lo + inset, hi - inset).to_array(), [0.0; 3]))
        .collect();
    let levels = query(&e, QueryMode::SdfDistance, &points);
    let rays: Vec<_> = points
        .iter()
        .zip(&levels)
        .filter(|((p, _), q)| {
            let l = (q[1][2] as u32).min(clip.built - 1);
            exact_distance(&tris, Vec3::from(*p)) >= clip.voxel(l)
        })
        .map(|((p, _), _)| (*p, rng.dir().to_array()))
        .take(4096)
        .collect();
    let bvh = query(&e, QueryMode::BvhTrace, &rays);
    let sdf = query(&e, QueryMode::SdfTraceExpanded, &rays);
    let (mut both, mut inside, mut close, mut through, mut off_surface) = (0, 0, 0, 0, 0);
    for ((ray, s), b) in rays.iter().zip(&sdf).zip(&bvh) {
        let (s, b, n) = (s[0], b[0], Vec3::from_slice(&b[1][..3]));
        let (o, d) = (Vec3::from(ray.0), Vec3::from(ray.1));
        if s[1] < 0.5 || b[1] < 0.5 {
            continue;
        }
        if n.dot(d) > 0.0 {
            // The BVH met a back face: the origin is inside a block, not in free space.
            inside += 1;
            continue;
        }
        both += 1;
        let voxel = clip.voxel((s[3] as u32).min(clip.built - 1));
        let plane = ((o + d * s[0]) - (o + d * b[0])).dot(n).abs() / voxel;
        close += (plane <= 1.5) as u32;
        through += (s[0] > b[0] + 1.5 * voxel) as u32;
        off_surface += (exact_distance(&tris, o + d * s[0]) > 1.5 * voxel) as u32;
    }
    eprintln!(
        "SDF (as traced) vs BVH hits, cornell 128^3: {} rays from free space, {both} hit in both ({inside} started inside a block); \
         {close} ({:.2}%) within 1.5 voxels of the BVH hit's plane, {through} passed through a surface, {off_surface} stopped over 1.5 voxels from any triangle",
        rays.len(),
        100.0 * close as f64 / both as f64
    );
    assert!(both > 2500, "{both}");
    assert!(through * 100 <= both, "{through} of {both} passed through");
    assert!(
        off_surface * 100 <= both,
        "{off_surface} of {both} stopped in empty space"
    );
    assert!(
        close * 10 >= both * 9,
        "{close} of {both} near the BVH hit's plane"
    );
}

/// Moving the camera scrolls the clipmaps (only new slabs are rebuilt); the field afterwards
/// equals one built from scratch at the new position, at every sampled point.
#[test]
fn scrolled_sdf_equals_a_fresh_build() {
    let scene = builtin::cornell();
    let (lo, hi) = scene.bounds();
    let mut moved = engine(
        "lumen",
        small(toml::Table::new()),
        scene.clone(),
        [32, 32],
        1,
    );
    frames(&mut moved, 1);
    let mut camera = moved.camera;
    let step = Vec3::new(0.7, 0.2, 1.3);
    camera.position += step;
    camera.target += step;
    moved.move_camera(camera);
    frames(&mut moved, 1);
    let mut fresh = engine("lumen", small(toml::Table::new()), scene, [32, 32], 1);
    fresh.set_camera(camera);
    frames(&mut fresh, 1);
    let (a, b) = (
        lumen(&moved).clipmaps().unwrap(),
        lumen(&fresh).clipmaps().unwrap(),
    );
    assert_eq!(a.brick_origins, b.brick_origins);
    let mut rng = Rand(11);
    let points: Vec<_> = (0..10_000)
        .map(|_| (rng.in_box(lo - 1.0, hi + 1.0).to_array(), [0.0; 3]))
        .collect();
    let qa: Vec<[f32; 4]> = query(&moved, QueryMode::SdfDistance, &points)
        .iter()
        .map(|q| q[1])
        .collect();
    let qb: Vec<[f32; 4]> = query(&fresh, QueryMode::SdfDistance, &points)
        .iter()
        .map(|q| q[1])
        .collect();
    let differ = qa.iter().zip(&qb).filter(|(x, y)| x != y).count();
    eprintln!("scrolled vs fresh SDF: {differ} of 10000 samples differ");
    assert_eq!(differ, 0);
}

/// The cache's direct light, seen through the pixels' surfaces (debug channel 1: albedo x
/// direct irradiance / pi), against the reference's direct light (one bounce, no emission seen
/// by the camera) over the image: relative error of the mean and per-pixel relMSE reported.
#[test]
fn cache_direct_light_matches_reference() {
    let size = [64, 64];
    let mut truth = engine(
        "reference",
        toml::toml! { samples_per_frame = 16
        max_depth = 1 },
        builtin::cornell(),
        size,
        3,
    );
    truth.flags = gilab::render::FLAG_NO_PRIMARY_EMISSION;
    truth.reset();
    frames(&mut truth, 16);
    let reference = truth.read_output().unwrap();
    let px = (size[0] * size[1]) as usize;
    let mut results = Vec::new();
    for mode in ["bvh", "sdf"] {
        let mut t = toml::Table::new();
        t.insert("tracing".into(), mode.into());
        t.insert("direct_texels_per_frame".into(), 16_777_216.into());
        // A 256² atlas (512² before 2026-11-26, for CI time: every texel is relit each frame,
        // so the atlas's area is the cost); the checks are image means.
        t.insert("atlas_size".into(), 256.into());
        t.insert("debug_views".into(), true.into());
        let mut e = engine("lumen", small(t), builtin::cornell(), size, 3);
        frames(&mut e, 40);
        let debug = e.read_debug().unwrap().unwrap();
        let cache = gilab::render::debug_channel(&debug, px, 1);
        let (mut sum_c, mut sum_r, mut err, mut n) = (0.0, 0.0, 0.0, 0);
        for (i, c) in cache.iter().enumerate() {
            let p = reference.pixel(i as u32 % size[0], i as u32 / size[0]);
            let r = luminance([p[0] as f64, p[1] as f64, p[2] as f64]);
            if r <= 0.0 || *c <= 0.0 {
                continue;
            }
            sum_c += *c as f64;
            sum_r += r;
            err += ((*c as f64 - r) / r).powi(2);
            n += 1;
        }
        let rel = sum_c / sum_r - 1.0;
        eprintln!(
            "cache direct ({mode}) vs reference direct, cornell 64²: mean {:+.2}%, per-pixel relMSE {:.3e} over {n} pixels",
            rel * 100.0,
            err / n as f64
        );
        results.push((mode, rel, n));
    }
    // BVH shadow rays: within 10% (measured +1.2%). SDF shadow rays over-occlude (the expand, a
    // 0.6-unit voxel at this size): measured -9.0%, bounded at 15%.
    for (mode, rel, n) in results {
        assert!(n as f64 > 0.4 * px as f64, "{mode}: {n} pixels");
        let bound = if mode == "bvh" { 0.1 } else { 0.15 };
        assert!(rel.abs() < bound, "{mode}: {rel}");
    }
}

/// Rays as the gather traces them (cosine directions from the surfaces the camera sees, 80²
/// pixels): where a ray hits a front face, the surface cache must answer (a card covers the hit
/// and its depth matches). Failed lookups lose that ray's energy; the seed accepts that for
/// coverage holes, but every surface of these scenes has cards. Counted in both tracing modes.
/// SDF hits whose card lookup fails (7.0% on the Cornell box: back faces where a probe sits in a
/// concave corner or a ray grazes an edge, hits given a neighbour's object) read the voxel
/// lighting, as in the seed (issue 38 item 2: under 1% left unlit, measured 0.77%), which where
/// both answer agrees with the cards.
#[test]
fn cache_lookups_at_hits_find_the_surface() {
    // Unlit share allowed per (scene, mode).
    let cases = [
        (builtin::furnace(0.8, 1.0, 2), [0.01, 0.01]),
        (builtin::cornell(), [0.01, 0.01]),
    ];
    for (scene, bounds) in cases {
        let name = scene.name.clone();
        for (mode, bound) in ["sdf", "bvh"].into_iter().zip(bounds) {
            let mut t = toml::Table::new();
            t.insert("tracing".into(), mode.into());
            let mut e = engine("lumen", small(t), scene.clone(), [80, 80], 1);
            frames(&mut e, 2);
            let inputs = visible_surfaces(&e);
            let out = query(&e, QueryMode::CacheRay, &inputs);
            let hits = out.iter().filter(|o| o[0][1] > 0.5).count();
            let back = out.iter().filter(|o| o[0][2] > 0.5).count();
            let empty = out
                .iter()
                .filter(|o| o[0][1] > 0.5 && o[0][2] < 0.5 && o[0][3] <= 1e-4)
                .count();
            // Answered by neither the cards (1) nor the voxel lighting (2), which also lights SDF
            // hits whose gradient runs along the ray (grazed edges, concave corners).
            let dark = out
                .iter()
                .filter(|o| o[0][1] > 0.5 && o[1][3] != 1.0 && o[1][3] != 2.0)
                .count();
            eprintln!(
                "{name} ({mode}): {hits} of {} rays hit; {back} on a back face, {empty} with no card answer; {dark} lit by neither the cards nor the voxel lighting",
                inputs.len()
            );
            assert!(hits > 1000, "{name} ({mode}): {hits}");
            let missed = (back + empty) as f64 / hits as f64;
            let lost = dark as f64 / hits as f64;
            eprintln!(
                "{name} ({mode}): {:.2}% of hits miss their card, {:.2}% lost",
                100.0 * missed,
                100.0 * lost
            );
            assert!(
                lost <= bound,
                "{name} ({mode}): {:.2}% of hits lost",
                100.0 * lost
            );
            if mode == "sdf" {
                voxel_lighting_against_cards(&name, &query(&e, QueryMode::VoxelRay, &inputs));
            }
        }
    }
}

/// Where both answer (front SDF hits, the same rays), the voxel lighting's luminance against the
/// cards' and the share of hits the voxels cover (over 90%). In the furnace (uniform light) the
/// means agree within 5% (measured -0.1%); on the Cornell box at these 64³ clipmaps the box lies
/// in the coarsest level (lighting voxels 1.2 units, under 5 across the box) and the voxels read
/// about a third darker than the cards (printed: docs/lumen.md).
fn voxel_lighting_against_cards(name: &str, out: &[[[f32; 4]; 2]]) {
    let front = out.iter().filter(|o| o[0][1] > 0.5 && o[0][2] < 0.5);
    let both: Vec<_> = front
        .clone()
        .filter(|o| o[0][3] > 0.0 && o[1][2] > 1e-4)
        .map(|o| (o[1][0] as f64, o[1][1] as f64))
        .collect();
    let (voxels, cards) = both
        .iter()
        .fold((0.0, 0.0), |(a, b), (v, c)| (a + v, b + c));
    let covered = both.len() as f64 / front.count().max(1) as f64;
    let spread = both.iter().map(|(v, c)| (v - c).abs()).sum::<f64>() / cards.max(1e-12);
    eprintln!(
        "{name}: voxel lighting answers {:.1}% of front SDF hits; where the cards answer too, its mean luminance {:.4} against theirs {:.4} ({:+.1}%), mean |difference| {:.1}% of theirs",
        100.0 * covered,
        voxels / both.len().max(1) as f64,
        cards / both.len().max(1) as f64,
        100.0 * (voxels / cards - 1.0),
        100.0 * spread
    );
    assert!(covered > 0.9, "{name}: voxel lighting covers {covered:.3}");
    if name == "furnace" {
        assert!(
            (voxels / cards - 1.0).abs() < 0.05,
            "{name}: voxel lighting {voxels:.3} against the cards' {cards:.3}"
        );
    }
}

/// White furnace (closed sphere, albedo 0.8, emission 1): converges to 1 / 0.2 = 5 once the
/// cache's feedback has carried enough bounces. First the shipped defaults (SDF tracing at 128³
/// clipmaps, screen probes, world radiance cache: issue 38's 3%, issue 55), then both tracing
/// modes with part 1's per-pixel gather, and the screen probes (BVH) with and without the world
/// radiance cache.
#[test]
fn furnace_converges_in_both_modes() {
    // (label, parameters, bound on |mean / 5 - 1|). Every run but the first starts from
    // `small` (64³ clipmaps); the first is the shipped defaults.
    let runs = [
        (
            "defaults (sdf, probes with world cache)",
            toml::Table::new(),
            0.03,
        ),
        (
            "sdf, pixels",
            toml::toml! { tracing = "sdf" final_gather = "pixels" },
            0.01,
        ),
        (
            "bvh, pixels",
            toml::toml! { tracing = "bvh" final_gather = "pixels" },
            0.01,
        ),
        (
            "bvh, probes",
            toml::toml! { tracing = "bvh" world_cache = false },
            0.03,
        ),
        (
            "bvh, probes with world cache",
            toml::toml! { tracing = "bvh" },
            0.03,
        ),
    ];
    let mut means = Vec::new();
    for (label, mut t, _) in runs.clone() {
        t.insert("indirect_texels_per_frame".into(), 16_777_216.into());
        t.insert("direct_texels_per_frame".into(), 16_777_216.into());
        // A 128² atlas (512² before 2026-11-26, then 256², for CI time): the
        // furnace is uniform, so texel resolution changes nothing it measures.
        t.insert("atlas_size".into(), 128.into());
        // The defaults but for the cache's budget and atlas above, which set how fast the
        // uniform furnace converges, not where.
        let params = if label.starts_with("defaults") {
            t
        } else {
            small(t)
        };
        let mut e = engine("lumen", params, builtin::furnace(0.8, 1.0, 2), [32, 32], 1);
        // 128 frames (48 before 2026-11-27, sixth session): the cache adds a bounce a frame
        // and 0.8^n needs about 25 of them, which the probes' and pixels' temporal filters slow
        // further. At 48 frames the per-pixel gathers read 4.85 and the probes 4.56.
        frames(&mut e, 128);
        // Restart the average (not the caches): what the converged technique shows.
        let camera = e.camera;
        e.move_camera(camera);
        frames(&mut e, 8);
        let img = e.read_output().unwrap();
        let m = img.mean();
        eprintln!(
            "lumen furnace ({label}): {:.4} {:.4} {:.4} vs 5 ({:+.2}%)",
            m[0],
            m[1],
            m[2],
            100.0 * (m[1] / 5.0 - 1.0)
        );
        means.push(m[1]);
        assert_eq!(e.ray_counts().unwrap().invalid_samples, 0);
    }
    // Measured 2026-11-27 (sixth session), 128 frames: SDF 4.995, BVH 4.999 with the per-pixel
    // gather; BVH screen probes 4.903 without the world cache, 4.888 (-2.3%) with it (-3.7%
    // before the probes' irradiance was normalised: shaders/lumen/integrate.wgsl). SDF probes
    // (4.810 at 160 frames, -3.8%) are in docs/lumen.md, not run here (CI time).
    let error = (means[0] / 5.0 - 1.0).abs();
    common::targets::check(
        "lumen-default-furnace",
        common::targets::Better::Lower,
        runs[0].2,
        error,
        "|furnace / 5 - 1|, Lumen's defaults",
    );
    for ((label, _, tolerance), mean) in runs.iter().zip(&means).skip(1) {
        assert!((mean / 5.0 - 1.0).abs() < *tolerance, "{label}: {mean}");
    }
    // The world radiance cache lags the surface cache while the feedback still brightens it:
    // within 3% of the probes without it (issue 38). Measured 2026-11-26: 4.164 (-8.3%) with a
    // 16-update mean and 64 probes a frame round robin; 4.340 (-4.4%) with 2 updates.
    let cache_loss = means[4] / means[3] - 1.0;
    eprintln!(
        "world radiance cache in the furnace: {:+.2}% against none",
        cache_loss * 100.0
    );
    assert!(cache_loss.abs() < 0.03, "world cache loses {cache_loss:.4}");
}

fn cornell_run_frames(params: toml::Table, n: u32) -> (Image, gilab::render::RayCounts) {
    let mut t = toml::toml! { atlas_size = 256 };
    t.extend(params);
    let mut e = engine("lumen", small(t), builtin::cornell(), [128, 128], 1);
    frames(&mut e, n);
    let img = e.read_output().unwrap();
    let rays = e.ray_counts().unwrap();
    assert_eq!(rays.invalid_samples, 0);
    (img, rays)
}

/// What the converged technique shows: `warm` frames from a cold start (their accumulated mean
/// is returned too: the warm-up's energy), then the average restarts (not the caches, probes or
/// temporal histories: the same camera) and `n` frames are accumulated. Ray counts cover all
/// `warm + n` frames.
fn cornell_run_steady(
    params: toml::Table,
    warm: u32,
    n: u32,
) -> (Image, Image, gilab::render::RayCounts) {
    let mut t = toml::toml! { atlas_size = 256 };
    t.extend(params);
    let mut e = engine("lumen", small(t), builtin::cornell(), [128, 128], 1);
    frames(&mut e, warm);
    let cold = e.read_output().unwrap();
    let camera = e.camera;
    e.move_camera(camera);
    frames(&mut e, n);
    let img = e.read_output().unwrap();
    let rays = e.ray_counts().unwrap();
    assert_eq!(rays.invalid_samples, 0);
    (img, cold, rays)
}

fn rays_per_pixel_frame(rays: &gilab::render::RayCounts, frames: u32) -> f64 {
    rays.total() as f64 / (128.0 * 128.0 * frames as f64)
}

fn kind(rays: &gilab::render::RayCounts, name: &str) -> u64 {
    rays.kind(name)
}

/// Cornell box at 128² against a 512-spp reference (shared with ReSTIR's and the surfels' tests).
///
/// Part 1's per-pixel gather at default budgets in both tracing modes: energy within 10%. The
/// bias comes from the cache (diffuse only, texel resolution, probe interpolation, 4-frame
/// blend) and, with `sdf`, from the distance field's hit positions and over-occlusion.
///
/// The screen-probe gather (with cache budgets high enough that the cache has converged, so what
/// is measured is the gather), converged (a warm-up, then the average restarts): energy within
/// 3% with the SDF at its default 128³ clipmaps (issue 38), within 5% with the BVH; a frame's relMSE below the
/// per-pixel gather's at about equal rays per pixel; product and uniform probe sampling agree
/// on the mean; screen traces take rays off the world trace and leave the energy within 2%.
#[test]
fn cornell_against_reference_both_gathers() {
    // 512 spp (2,048 before 2026-11-25, 1,024 before 2026-11-26, for CI time; the same truth
    // ReSTIR's and the surfels' Cornell tests read): the checks are image means and
    // single-frame errors, far above the reference's own noise either way.
    let truth = shared_reference(builtin::cornell(), [128, 128], 512, 11, 0, 0);
    let report = |label: &str, img: &Image, rays: &gilab::render::RayCounts, frames: u32| {
        let m = metrics::compare(img, &truth).unwrap();
        let ratio = energy(img) / energy(&truth);
        eprintln!(
            "lumen {label}, cornell 128², {frames} frames: energy ratio {ratio:.4}, relMSE {:.3e}, {:.2} rays/px/frame ({:?})",
            m.rel_mse,
            rays_per_pixel_frame(rays, frames),
            rays.named()
        );
        (ratio, m.rel_mse)
    };
    // Accumulated runs take 48 frames (the screen probes' temporal filters slow the feedback:
    // at 32 frames BVH probes measured 0.927, outside the 7% bound); a single frame is judged
    // after 16, when the cache (every texel updated every frame) has converged (48 before
    // 2026-11-26, for CI time).
    let (slow, fast, single, warm) = (48, 48, 16, 32);
    // The per-pixel gather at default budgets through the BVH (through the SDF too before
    // 2026-11-26; the SDF per-pixel gather's energy is still checked on the furnace).
    let (img, rays) = cornell_run_frames(
        toml::toml! { tracing = "bvh" final_gather = "pixels" },
        slow,
    );
    let (ratio, _) = report("pixels (bvh), default budgets", &img, &rays, slow);
    assert!((ratio - 1.0).abs() < 0.1, "bvh: energy ratio {ratio}");
    let converged = |mut t: toml::Table| {
        t.insert("indirect_texels_per_frame".into(), 4_194_304.into());
        t.insert("direct_texels_per_frame".into(), 4_194_304.into());
        t
    };
    // The screen probes (the default final gather) as they converge: 32 frames from a cold start,
    // then 48 accumulated. Until 2026-11-27 (sixth session) the 48 frames were accumulated from
    // the cold start, and the mean carried the warm-up: the surface cache adds a bounce a frame
    // and the probes' and pixels' temporal filters (1/(n+1) down to 1/4 and 1/10) hold the dark
    // first frames for about 25 more; SDF read 0.9665 that way and 0.98 converged. The SDF runs
    // at the default 128³ clipmaps: at this file's 64³ the Cornell box lies in 0.6-unit voxels,
    // whose grazing and rim hits bring back 22% more light per ray than the BVH's from the same
    // cache (`sdf_hits_against_exact_hits`), and the probes read 1.01 by two errors cancelling.
    let mut probes = Vec::new();
    for (mode, bound) in [("sdf", 0.03), ("bvh", 0.05)] {
        let mut t = toml::toml! { tracing = mode };
        if mode == "sdf" {
            t.insert("clipmap_resolution".into(), 128.into());
        }
        let (img, cold, rays) = cornell_run_steady(converged(t), warm, fast);
        let cold_ratio = energy(&cold) / energy(&truth);
        let (ratio, _) = report(
            &format!("screen probes ({mode}), after {warm} frames"),
            &img,
            &rays,
            warm + fast,
        );
        eprintln!("  ({mode}: the first {warm} frames from a cold start read {cold_ratio:.4})");
        // Issue 38: SDF within 3% (measured 0.980-0.983 over seeds, 0.985 since the probes'
        // irradiance is normalised), BVH within 5% (0.965-0.969, then 0.970; the cold-start mean
        // read 0.9415).
        assert!((ratio - 1.0).abs() < bound, "{mode}: energy ratio {ratio}");
        probes.push((img, rays, ratio));
    }
    // The world radiance cache (on by default) against none: what its lookups lose (issue 38:
    // within 3%; measured 2026-11-26 at 256 probes a frame: -3.3% before the lookups waited a
    // probe diagonal, -0.9% after).
    let (img, _, rays) = cornell_run_steady(
        converged(toml::toml! { tracing = "bvh" world_cache = false }),
        warm,
        fast,
    );
    let (no_cache, _) = report(
        "screen probes (bvh), no world cache, converged",
        &img,
        &rays,
        warm + fast,
    );
    let cache_loss = probes[1].2 / no_cache - 1.0;
    eprintln!(
        "world radiance cache on Cornell: {:+.2}% of the light against none",
        cache_loss * 100.0
    );
    assert!(
        cache_loss.abs() < 0.03,
        "world cache changes Cornell's light by {cache_loss:.4}"
    );
    let (probe_img, probe_rays, _) = &probes[1];
    // What a real-time frame shows (no accumulation over frames: the probes' own temporal
    // filters are part of the technique): part 1's gather at one ray per pixel costs about what
    // the probes, their adaptive extras and the cache updates cost together at this size.
    let frame_only = |mut t: toml::Table| {
        t.insert("accumulate".into(), false.into());
        converged(t)
    };
    // Without the world cache: its fixed 128 probes a frame are 2 cache rays per pixel at 128²
    // (0.016 at 1080p), which would leave the comparison at unequal rays.
    let (img, rays) = cornell_run_frames(
        frame_only(toml::toml! { tracing = "bvh" world_cache = false }),
        single,
    );
    let (_, probe_rel) = report("screen probes (bvh), last frame only", &img, &rays, single);
    let (img, pixel_rays) = cornell_run_frames(
        frame_only(toml::toml! { tracing = "bvh" final_gather = "pixels" rays_per_pixel = 1 }),
        single,
    );
    let (_, pixel_rel) = report(
        "pixels (bvh), 1 ray per pixel, last frame only",
        &img,
        &pixel_rays,
        single,
    );
    assert!(
        rays_per_pixel_frame(&rays, single) <= rays_per_pixel_frame(&pixel_rays, single) * 1.05,
        "the comparison is not at equal rays"
    );
    assert!(
        probe_rel < pixel_rel,
        "screen probes relMSE {probe_rel:.3e} not below the per-pixel gather's {pixel_rel:.3e}"
    );
    // Both samplers estimate the same irradiance (each divides by the pdf it drew with): their
    // 16-frame means agree (filters off; measured +0.06% at 48 frames against a 1.5% bound; 24
    // frames before 2026-11-26, for CI time); each one's single-frame noise against its own
    // mean is reported after 12 frames, when the cache (4 M texels per frame) has converged (product sampling with the CDF draw was measured
    // noisier on this scene; with ray reassignment, the default, 1.93e-2 against 2.03e-2: docs/lumen.md).
    let bare = |sampling: &str, accumulate: bool| {
        let mut t = toml::toml! { tracing = "bvh" spatial_filter = false temporal_filter = false contact_ao = false };
        t.insert("probe_sampling".into(), sampling.into());
        t.insert("accumulate".into(), accumulate.into());
        cornell_run_frames(converged(t), if accumulate { 16 } else { 12 })
    };
    let (product_mean, _) = bare("product", true);
    // The spatial filter and contact AO each against the same 16 frames without them (issue 38,
    // 2026-11-27): the filter moves a neighbour's sample to the cell its hit falls in instead of
    // dropping it on the seed's angle test (which kept mostly far hits: -1.76% here, now
    // -0.61%); contact AO counts blocked directions with Jimenez's multi-bounce fit instead of
    // as black (-1.22%, now -0.65%).
    for (label, filter, ao, bound) in [
        ("spatial filter", true, false, 0.012),
        ("contact AO", false, true, 0.01),
    ] {
        let t = toml::toml! { tracing = "bvh" temporal_filter = false spatial_filter = filter contact_ao = ao };
        let (img, _) = cornell_run_frames(converged(t), 16);
        let change = energy(&img) / energy(&product_mean) - 1.0;
        eprintln!("{label}: {:+.2}% of the light without it", 100.0 * change);
        assert!(
            change.abs() < bound,
            "{label} changes the energy by {change:+.4}"
        );
    }
    let (uniform_mean, _) = bare("uniform", true);
    let (img, product_rays) = bare("product", false);
    let product_noise = metrics::compare(&img, &product_mean).unwrap().rel_mse;
    let (img, uniform_rays) = bare("uniform", false);
    let uniform_noise = metrics::compare(&img, &uniform_mean).unwrap().rel_mse;
    let agree = energy(&product_mean) / energy(&uniform_mean) - 1.0;
    eprintln!(
        "probe sampling: 16-frame means differ by {agree:+.4}; one frame (the 12th) against its mean (relMSE): product {product_noise:.3e} ({} probe rays in 12 frames), uniform {uniform_noise:.3e} ({} probe rays)",
        kind(&product_rays, "probe"),
        kind(&uniform_rays, "probe")
    );
    assert!(
        agree.abs() < 0.015,
        "product and uniform sampling disagree by {agree:+.4}"
    );
    let (img, _, rays) = cornell_run_steady(
        converged(toml::toml! { tracing = "bvh" screen_traces = false }),
        warm,
        fast,
    );
    report(
        "screen probes (bvh), no screen traces, converged",
        &img,
        &rays,
        warm + fast,
    );
    let (with, without) = (kind(probe_rays, "probe"), kind(&rays, "probe"));
    eprintln!("world-traced probe rays: {with} with screen traces, {without} without");
    assert!(
        (with as f64) < 0.8 * without as f64,
        "screen traces resolved too few rays: {with} against {without}"
    );
    let drift = energy(probe_img) / energy(&img) - 1.0;
    assert!(
        drift.abs() < 0.02,
        "screen traces change the energy by {drift:.4}"
    );
}

/// relMSE of 8×8-pixel block means: the probes' error (a probe serves 16² pixels), with the
/// per-pixel noise of direct light averaged out.
fn block_rel_mse(img: &Image, truth: &Image) -> f64 {
    let (bw, bh) = (img.width / 8, img.height / 8);
    let mut sum = 0.0;
    for by in 0..bh {
        for bx in 0..bw {
            let (mut a, mut b) = (0.0, 0.0);
            for y in by * 8..by * 8 + 8 {
                for x in bx * 8..bx * 8 + 8 {
                    a += luminance(img.pixel(x, y).map(f64::from));
                    b += luminance(truth.pixel(x, y).map(f64::from));
                }
            }
            let (a, b) = (a / 64.0, b / 64.0);
            sum += (a - b) * (a - b) / (b * b + 1e-2);
        }
    }
    sum / (bw * bh) as f64
}

/// The seed's ray reassignment (issue 38, `probe_ray_reassignment`) at 64², BVH, probe filters
/// off: no NaN/Inf; on Cornell the 10-frame mean within 3% of the CDF draw's (both unbiased for
/// the pdf they draw from); one frame's relMSE (whole image, and 8×8 block means: the probes'
/// share) against a 128-spp reference at equal rays, mean over frames 6-10, on Cornell and courtyard:
/// reassignment's block error below the CDF draw's on both (an unmet target on courtyard:
/// docs/known-issues.md) and below
/// uniform sampling's on courtyard (measured with 3 seeds: Cornell 2.85e-2 / 3.50e-2 / 2.88e-2, courtyard
/// 4.77e-2 / 8.27e-2 / 6.14e-2); against uniform on Cornell it is printed (about equal).
#[test]
fn probe_ray_reassignment_keeps_the_energy() {
    let size = [64, 64];
    // Frames 1-10; one frame's error is read after each of frames 6-10 when not accumulating.
    let run = |scene: &Scene, sampling: &str, reassign: bool, accumulate: bool| {
        let mut t = toml::toml! { tracing = "bvh" atlas_size = 256 world_cache = false
        spatial_filter = false temporal_filter = false contact_ao = false
        indirect_texels_per_frame = 4_194_304 direct_texels_per_frame = 4_194_304 };
        t.insert("probe_sampling".into(), sampling.into());
        t.insert("probe_ray_reassignment".into(), reassign.into());
        t.insert("accumulate".into(), accumulate.into());
        let mut e = engine("lumen", small(t), scene.clone(), size, 1);
        frames(&mut e, 5);
        let mut imgs = Vec::new();
        for _ in 0..5 {
            frames(&mut e, 1);
            let img = e.read_output().unwrap();
            assert!(
                img.mean().iter().all(|v| v.is_finite()),
                "{sampling} {reassign}"
            );
            imgs.push(img);
        }
        let rays = e.ray_counts().unwrap();
        assert_eq!(rays.invalid_samples, 0, "{sampling} {reassign}");
        (imgs, rays.total())
    };
    let cornell = builtin::cornell();
    let truth = shared_reference(cornell.clone(), size, 128, 11, 0, 0);
    let (on, _) = run(&cornell, "product", true, true);
    let (off, _) = run(&cornell, "product", false, true);
    let (on, off) = (on.last().unwrap(), off.last().unwrap());
    let drift = energy(on) / energy(off) - 1.0;
    eprintln!(
        "reassignment: 10-frame mean {:.4} of the reference's energy, CDF draw {:.4} ({drift:+.4})",
        energy(on) / energy(&truth),
        energy(off) / energy(&truth)
    );
    assert!(
        drift.abs() < 0.03,
        "reassignment changes the energy by {drift:+.4}"
    );
    for (name, scene) in [
        ("cornell", cornell),
        ("courtyard", builtin::courtyard(15.0, 1.0, 1.0)),
    ] {
        let truth = shared_reference(scene.clone(), size, 128, 11, 0, 0);
        let mut blocks = Vec::new();
        for (sampling, reassign) in [("product", true), ("product", false), ("uniform", false)] {
            let (imgs, rays) = run(&scene, sampling, reassign, false);
            let n = imgs.len() as f64;
            let rel: f64 = imgs
                .iter()
                .map(|i| metrics::compare(i, &truth).unwrap().rel_mse)
                .sum::<f64>()
                / n;
            let block: f64 = imgs.iter().map(|i| block_rel_mse(i, &truth)).sum::<f64>() / n;
            eprintln!("{name}, one frame (mean over frames 6-10), {sampling} reassignment {reassign}: relMSE {rel:.4e}, 8x8 blocks {block:.4e} ({rays} rays in 10 frames)");
            blocks.push(block);
        }
        // Against the CDF draw, on both scenes (issue 55: on courtyard it was only printed from
        // 2026-11-27, sixth session, when the probes' irradiance was normalised and left out
        // the cells below a probe's surface: the CDF draw's block error there fell from 1.23e-1
        // to 1.01e-1 and reassignment's stayed at 1.02e-1, docs/lumen.md).
        common::targets::check(
            if name == "cornell" {
                "lumen-reassignment-vs-cdf-cornell"
            } else {
                "lumen-reassignment-vs-cdf-courtyard"
            },
            common::targets::Better::Lower,
            1.0,
            blocks[0] / blocks[1],
            "reassignment's 8x8 block relMSE / the CDF draw's",
        );
        if name == "courtyard" {
            assert!(
                blocks[0] < blocks[2],
                "{name}: reassignment {:.3e} not below uniform {:.3e}",
                blocks[0],
                blocks[2]
            );
        }
    }
}

/// The seed's known weakness: light through thin walls. The thin-wall room with its interior
/// light off is exactly black in the reference; Lumen's defaults leak under 0.05 (the SDF
/// modes' bound); the leak in SDF mode is reported next to BVH
/// mode, with part 1's per-pixel gather and with the screen probes (whose world radiance cache
/// interpolates probes, the one path by which BVH mode can leak).
#[test]
fn thin_wall_leak_sdf_against_bvh() {
    let size = [48, 48];
    // The shipped defaults first (SDF tracing at 128³ clipmaps, screen probes, world cache),
    // with the indirect budget below so the cache has relit in 24 frames: the SDF's bound.
    let defaults = {
        let mut e = engine(
            "lumen",
            toml::toml! { indirect_texels_per_frame = 16_777_216 },
            builtin::thin_wall(0.0),
            size,
            1,
        );
        frames(&mut e, 24);
        energy(&e.read_output().unwrap())
    };
    eprintln!("thin-wall interior luminance (reference 0), Lumen's defaults: {defaults:.5}");
    common::targets::check(
        "lumen-default-thin-wall-leak",
        common::targets::Better::Lower,
        0.05,
        defaults,
        "thin-wall room's interior luminance, Lumen's defaults",
    );
    let mut leaks = Vec::new();
    for gather in ["pixels", "screen_probes"] {
        for mode in ["sdf", "bvh"] {
            let mut t = toml::toml! { tracing = mode final_gather = gather world_cache = true };
            t.insert("indirect_texels_per_frame".into(), 16_777_216.into());
            let mut e = engine("lumen", small(t), builtin::thin_wall(0.0), size, 1);
            frames(&mut e, 24);
            leaks.push(energy(&e.read_output().unwrap()));
        }
        let n = leaks.len();
        eprintln!(
            "thin-wall interior luminance (reference 0), {gather}: sdf {:.5}, bvh {:.5}",
            leaks[n - 2],
            leaks[n - 1]
        );
    }
    assert!(leaks[1] <= 1e-6, "BVH mode leaks: {}", leaks[1]);
    assert!(leaks[0] < 0.05, "SDF mode leaks: {}", leaks[0]);
    assert!(
        leaks[3] < 1e-3,
        "BVH mode leaks through the world cache: {}",
        leaks[3]
    );
    assert!(
        leaks[2] < 0.05,
        "SDF mode with screen probes leaks: {}",
        leaks[2]
    );
}

/// No NaN/Inf on the hard cases and the glossy scene; a fixed seed gives identical images, on
/// Cornell and in the playing `moving` scene (SDF tracing).
#[test]
fn stable_and_deterministic() {
    for (name, scene) in [
        ("hard-cases", builtin::hard_cases(1.0)),
        ("glossy", builtin::glossy()),
    ] {
        for gather in ["screen_probes", "pixels"] {
            let t = toml::toml! { final_gather = gather world_cache = true };
            let mut e = engine("lumen", small(t), scene.clone(), [48, 48], 1);
            frames(&mut e, 6);
            let img = e.read_output().unwrap();
            assert_eq!(
                e.ray_counts().unwrap().invalid_samples,
                0,
                "{name} {gather}"
            );
            assert!(img.mean().iter().all(|v| v.is_finite()), "{name} {gather}");
        }
    }
    let run = || {
        let mut e = engine(
            "lumen",
            small(toml::Table::new()),
            builtin::cornell(),
            [32, 32],
            5,
        );
        frames(&mut e, 4);
        e.read_output().unwrap()
    };
    let (a, b) = (run(), run());
    assert_eq!(
        metrics::compare(&a, &b).unwrap().rel_mse,
        0.0,
        "not deterministic"
    );
    // A playing scene, traced through the distance field: bricks around the moving objects are
    // refilled every frame from pool entries taken in atomic order. Until 2026-11-27 the surface
    // cache's SDF rays read those entries' voxel lighting before this frame's voxel lighting
    // pass had written it (the radiance of whichever brick held the entry last): two runs
    // differed in most pixels (here too, at 32³ and 3 frames).
    let played = || {
        let scene = builtin::build("moving", &toml::Table::new()).unwrap();
        // 32³ clipmaps (the smallest): the refill is most of these frames' cost.
        let t = toml::toml! { clipmap_resolution = 32 };
        let mut e = engine("lumen", small(t), scene, [32, 32], 5);
        play(&mut e, 60.0);
        frames(&mut e, 3);
        e.read_output().unwrap()
    };
    let (a, b) = (played(), played());
    assert!(a.mean().iter().all(|v| v.is_finite()));
    assert_eq!(
        metrics::compare(&a, &b).unwrap().rel_mse,
        0.0,
        "SDF-traced Lumen in a playing scene is not deterministic"
    );
}

#[test]
fn bad_parameters_give_clear_errors() {
    let mut t = gilab::techniques::create_technique("lumen").unwrap();
    let err = t
        .set_params_from_table(&toml::toml! { clipmap_resolution = 100 })
        .unwrap_err()
        .to_string();
    assert!(err.contains("multiple of 8"), "{err}");
    let err = t
        .set_params_from_table(&toml::toml! { atlas_size = 1000 })
        .unwrap_err()
        .to_string();
    assert!(err.contains("page"), "{err}");
    let err = t
        .set_params_from_table(&toml::toml! { tracing = "voxels" })
        .unwrap_err()
        .to_string();
    assert!(err.contains("tracing"), "{err}");
    // A rejected change leaves the previous values.
    assert_eq!(t.params()["clipmap_resolution"].as_integer(), Some(128));
}

/// A ray-budget change (the viewer's slider) keeps the distance field, cards and atlas; a
/// change of a size (the atlas) rebuilds them.
#[test]
fn budget_changes_keep_the_scene_representation() {
    let mut e = engine(
        "lumen",
        small(toml::toml! { final_gather = "pixels" }),
        builtin::cornell(),
        [32, 32],
        1,
    );
    frames(&mut e, 2);
    assert!(lumen(&e).clipmaps().unwrap().valid[0]);
    let gather_rays = |e: &Engine| {
        let named = e.ray_counts().unwrap().named();
        named
            .iter()
            .find(|(n, _)| *n == "indirect")
            .map_or(0, |(_, c)| *c)
    };
    let before = gather_rays(&e);
    e.set_params_from_table(&toml::toml! { rays_per_pixel = 6 })
        .unwrap();
    assert!(
        lumen(&e).clipmaps().unwrap().valid[0],
        "rays_per_pixel rebuilt the distance field"
    );
    frames(&mut e, 1);
    let after = gather_rays(&e);
    // Counters run since the last reset (set_params resets): two frames before, one after.
    let ratio = after as f64 / (before as f64 / 2.0);
    assert!(
        (ratio - 3.0).abs() < 0.1,
        "gather rays per frame x{ratio} at 6 per pixel against 2"
    );
    e.set_params_from_table(&toml::toml! { atlas_size = 1024 })
        .unwrap();
    assert!(
        !lumen(&e).clipmaps().unwrap().valid[0],
        "atlas_size did not rebuild"
    );
    frames(&mut e, 1);
    assert!(e
        .read_output()
        .unwrap()
        .mean()
        .iter()
        .all(|v| v.is_finite()));
}

/// Screen probes: `probe_spacing` sets the probe rays (64 per uniform probe: a quarter of the
/// spacing, four times the rays), the ray-budget slider picks the spacing, and a spacing change
/// keeps the distance field.
#[test]
fn probe_spacing_sets_the_probe_rays() {
    let bare = toml::toml! { adaptive_probes = false world_cache = false screen_traces = false };
    let mut e = engine("lumen", small(bare), builtin::cornell(), [64, 64], 1);
    frames(&mut e, 3);
    let before = kind(&e.ray_counts().unwrap(), "probe") as f64 / 3.0;
    e.set_params_from_table(&toml::toml! { probe_spacing = 8 })
        .unwrap();
    assert!(
        lumen(&e).clipmaps().unwrap().valid[0],
        "probe_spacing rebuilt the distance field"
    );
    frames(&mut e, 3);
    let after = kind(&e.ray_counts().unwrap(), "probe") as f64 / 3.0;
    // Directions below a probe's surface are not traced, so the ratio is statistical.
    let ratio = after / before;
    eprintln!("probe rays per frame: {before:.0} at spacing 16, {after:.0} at 8 (x{ratio:.2})");
    assert!((3.5..4.5).contains(&ratio), "x{ratio}");
    // Say 3 rays per pixel were measured at spacing 8 (1 of them a probe ray): a budget of 6
    // asks for 4 probe rays per pixel, spacing 4; a budget of 3 keeps spacing 8.
    let spacing = |budget: f64| {
        e.technique
            .params_for_ray_budget(budget, Some(3.0))
            .and_then(|t| match t.get("probe_spacing") {
                Some(ParamValue::Int(i)) => Some(i),
                _ => None,
            })
    };
    assert_eq!(
        spacing(6.0),
        Some(4),
        "4 probe rays per pixel should give spacing 4"
    );
    assert_eq!(
        spacing(3.0),
        None,
        "the measured budget should keep spacing 8"
    );
}

/// The screen-probe debug views: placement marks uniform (1) and adaptive (2) probes, probe
/// radiance, the share of screen-trace hits (0..1) and the world cache are finite and not black.
#[test]
fn probe_debug_views_show_the_gather() {
    let t = toml::toml! { world_cache = true
    debug_views = true };
    let mut e = engine("lumen", small(t), builtin::cornell(), [64, 64], 1);
    frames(&mut e, 4);
    let stats = e
        .inspect(|ctx, t| {
            let any: &dyn std::any::Any = t.as_any();
            any.downcast_ref::<Lumen>()
                .unwrap()
                .probe_stats(ctx.gpu)
                .unwrap()
        })
        .expect("probe counters");
    eprintln!("{stats:?}");
    assert!(stats.screen_hits > 0 && stats.world_rays > 0 && stats.world_cache_reads > 0);
    let data = e.read_debug().unwrap().expect("lumen has a debug buffer");
    let pixels = 64 * 64;
    let channel = |c| gilab::render::debug_channel(&data, pixels, c);
    let placement = channel(8);
    let count = |v: f32| placement.iter().filter(|x| **x == v).count();
    eprintln!(
        "probe placement: {} uniform, {} adaptive pixels marked",
        count(1.0),
        count(2.0)
    );
    assert!(
        count(1.0) > 0 && count(2.0) > 0,
        "placement view lacks uniform or adaptive probes"
    );
    for (c, name) in [
        (9, "probe radiance"),
        (10, "screen-trace share"),
        (11, "world cache"),
    ] {
        let v = channel(c);
        let mean = v.iter().map(|x| *x as f64).sum::<f64>() / v.len() as f64;
        eprintln!("debug view {name}: mean {mean:.4}");
        assert!(v.iter().all(|x| x.is_finite()), "{name}");
        assert!(mean > 0.0, "{name} is black");
        if c == 10 {
            assert!(
                v.iter().all(|x| (0.0..=1.0).contains(x)),
                "{name} outside 0..1"
            );
        }
    }
}

/// The distance field is built by point queries through the BVH: with instances (a two-level
/// tree: scaled, rotated spheres in the Cornell box) it must equal the field built through a
/// flat tree over the same triangles.
#[test]
fn sdf_through_instances_equals_sdf_through_a_flat_tree() {
    use gilab::scene::MeshInstance;
    use glam::{Mat4, Quat};
    let mut scene = builtin::cornell();
    let material = scene.triangle_material[0];
    // One sphere mesh at the origin, placed four times (non-uniform scales, rotations).
    let mut proto = Scene::new("sphere");
    builtin::add_uv_sphere(&mut proto, Vec3::ZERO, 1.0, material, 8, 12);
    let (lo, hi) = scene.bounds();
    let size = hi - lo;
    for k in 0..4 {
        let f = k as f32;
        let at = lo
            + size
                * Vec3::new(
                    0.25 + 0.5 * (k % 2) as f32,
                    0.3 + 0.1 * f,
                    0.3 + 0.4 * (k / 2) as f32,
                );
        let m = Mat4::from_scale_rotation_translation(
            size.min_element() * Vec3::new(0.08 + 0.02 * f, 0.06, 0.1),
            Quat::from_euler(glam::EulerRot::XYZ, f, 2.0 * f, 0.5 * f),
            at,
        );
        let base = scene.positions.len() as u32;
        let first = scene.triangles.len() as u32;
        scene
            .positions
            .extend(proto.positions.iter().map(|&p| m.transform_point3(p)));
        scene.normals.extend(
            proto
                .normals
                .iter()
                .map(|&n| m.transform_vector3(n).normalize_or_zero()),
        );
        scene.uvs.extend(&proto.uvs);
        scene
            .triangles
            .extend(proto.triangles.iter().map(|t| t.map(|v| v + base)));
        scene.triangle_material.extend(&proto.triangle_material);
        scene.instances.push(MeshInstance {
            mesh: 0,
            transform: m,
            first_triangle: first,
            triangle_count: proto.triangles.len() as u32,
        });
    }
    scene.validate().unwrap();
    let mut flat = scene.clone();
    flat.instances.clear();
    let (lo, hi) = scene.bounds();
    let mut rng = Rand(0x51ed);
    let inputs: Vec<_> = (0..4000)
        .map(|_| (rng.in_box(lo, hi).to_array(), [0.0; 3]))
        .collect();
    let field = |scene: Scene| {
        let mut e = engine("lumen", small(toml::Table::new()), scene, [32, 32], 1);
        frames(&mut e, 1);
        let data = &e.gpu_scene.data;
        let levels = (data.bvh.instances, lumen(&e).clipmaps().unwrap().voxel(0));
        (query(&e, QueryMode::SdfDistance, &inputs), levels)
    };
    let (a, (instances, voxel)) = field(scene);
    let (b, (none, _)) = field(flat);
    assert_eq!((instances, none), (4, 0));
    let mut worst = 0.0f32;
    for (qa, qb) in a.iter().zip(&b) {
        assert_eq!(qa[1][2], qb[1][2], "same clipmap level answers");
        worst = worst.max((qa[1][0] - qb[1][0]).abs());
    }
    eprintln!(
        "SDF through instances vs flat: worst difference {worst:.2e} (finest voxel {voxel:.3})"
    );
    assert!(worst <= 1e-3 * voxel, "fields differ by {worst}");
}

/// `moving` (issue 36) played at `time_scale = 60` (1 s a frame: the door opens, the ball
/// rolls, the lamp goes round), Lumen with its distance field: every re-posing re-places the
/// moved objects' cards (`Refresh::Moved`), so the card set, every static card and most of the
/// cache's lighting of static cards carry over (a reset would clear it); and the distance field after the motion equals a fresh build of the posed
/// scene (the seed: "SDF bricks after motion equal a fresh build at the new pose") around the
/// moved objects' old and new places, and everywhere else.
#[test]
fn playing_keeps_the_cache_and_rebuilds_the_sdf_where_objects_moved() {
    use gilab::parts::surface_cache::{cards::NO_INSTANCE, Refresh};
    let scene = builtin::build("moving", &toml::Table::new()).unwrap();
    let start = scene_tris(&scene);
    // Held still while the cache lights up (4,096 texels of the 512² atlas a frame), then played.
    let params = small(toml::toml! { direct_texels_per_frame = 262144 });
    let mut e = engine("lumen", params, scene, [32, 32], 1);
    frames(&mut e, 10);
    play(&mut e, 60.0);
    frames(&mut e, 2);
    let first = lumen(&e).card_set().unwrap().clone();
    let gpu = e.gpu.clone();
    let static_texels = |c: &gilab::parts::surface_cache::cards::CardSet| -> Vec<usize> {
        let atlas = 512;
        c.cards
            .iter()
            .filter(|k| c.object_instance[k.object() as usize] == NO_INSTANCE)
            .flat_map(|k| {
                let [x, y, w, h] = k.rect;
                (y..y + h).flat_map(move |ty| (x..x + w).map(move |tx| (ty * atlas + tx) as usize))
            })
            .collect()
    };
    let texels = static_texels(&first);
    let before = lumen(&e).cache_direct(&gpu).unwrap().unwrap();
    frames(&mut e, 1);
    let after = lumen(&e).cache_direct(&gpu).unwrap().unwrap();
    frames(&mut e, 1);
    let l = lumen(&e);
    assert_eq!(l.last_refresh(), Some(Refresh::Moved));
    assert!(
        l.world_invalidated() > 0,
        "world probes around the moved objects start again"
    );
    let now = l.card_set().unwrap();
    assert_eq!(now.cards.len(), first.cards.len());
    let mut replaced = 0;
    for (a, b) in first.cards.iter().zip(&now.cards) {
        let moving = first.object_instance[a.object() as usize] != NO_INSTANCE;
        if !moving {
            assert_eq!(a, b, "a static card stays as built");
        } else {
            assert_eq!(
                (a.rect, a.draw),
                (b.rect, b.draw),
                "a moved card keeps its texels"
            );
            replaced += (a.box_min != b.box_min) as usize;
        }
    }
    let lit = texels.iter().filter(|&&t| before[t][0] > 0.0).count();
    let kept = texels
        .iter()
        .filter(|&&t| before[t][0] > 0.0 && before[t] == after[t])
        .count();
    eprintln!(
        "{} cards, {replaced} moved; static texels lit before a re-posing: {lit} of {}, unchanged after it: {kept}; {} world probes invalidated",
        now.cards.len(),
        texels.len(),
        l.world_invalidated()
    );
    assert!(replaced > 0, "the moving objects' cards follow them");
    assert!(lit > texels.len() / 4, "{lit} of {} lit", texels.len());
    // Only the round robin's 4,096 texels relit static cards (a reset would leave none kept).
    assert!(
        lit - kept <= 4096,
        "{kept} of {lit} kept: the cache was reset"
    );

    // The distance field against a fresh build of the pose, held still.
    let mut posed = (*e.scene).clone();
    std::sync::Arc::make_mut(posed.motion.as_mut().unwrap()).time_scale = 0.0;
    let end = scene_tris(&posed);
    let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for (a, b) in start.iter().zip(&end) {
        if a != b {
            for p in a.iter().chain(b) {
                lo = lo.min(*p);
                hi = hi.max(*p);
            }
        }
    }
    assert!(lo.x < hi.x, "something moved");
    let mut fresh = engine("lumen", small(toml::Table::new()), posed, [32, 32], 1);
    frames(&mut fresh, 1);
    let (a, b) = (
        lumen(&e).clipmaps().unwrap(),
        lumen(&fresh).clipmaps().unwrap(),
    );
    assert_eq!(a.brick_origins, b.brick_origins);
    let voxel = a.voxel(0);
    let (slo, shi) = e.scene.bounds();
    let mut rng = Rand(36);
    let near: Vec<_> = (0..4000)
        .map(|_| (rng.in_box(lo - 0.3, hi + 0.3).to_array(), [0.0; 3]))
        .collect();
    let anywhere: Vec<_> = (0..4000)
        .map(|_| (rng.in_box(slo, shi).to_array(), [0.0; 3]))
        .collect();
    for (name, points) in [("around the moved objects", near), ("anywhere", anywhere)] {
        let qa = query(&e, QueryMode::SdfDistance, &points);
        let qb = query(&fresh, QueryMode::SdfDistance, &points);
        let mut worst = 0.0f32;
        let mut differ = 0;
        for (x, y) in qa.iter().zip(&qb) {
            assert_eq!(x[1][2], y[1][2], "same clipmap level answers");
            let d = (x[1][0] - y[1][0]).abs();
            worst = worst.max(d);
            differ += (d > 1e-3 * voxel) as usize;
        }
        eprintln!(
            "played vs fresh SDF {name}: {differ} of {} samples differ, worst {worst:.2e} (finest voxel {voxel:.3})",
            points.len()
        );
        assert_eq!(differ, 0, "{name}");
    }
    // Sphere-traced rays read the coarse volume too (updated near the edits only).
    let rays: Vec<_> = (0..2000)
        .map(|_| (rng.in_box(slo, shi).to_array(), rng.dir().to_array()))
        .collect();
    let (ta, tb) = (
        query(&e, QueryMode::SdfTrace, &rays),
        query(&fresh, QueryMode::SdfTrace, &rays),
    );
    let differ = ta.iter().zip(&tb).filter(|(x, y)| x[1] != y[1]).count();
    eprintln!("played vs fresh SDF: {differ} of 2000 traced rays differ");
    assert_eq!(differ, 0);

    // The moved objects' surfaces find their cards as well as in a fresh build: rays shot at
    // each of their triangles from just outside it.
    let c = lumen(&e).card_set().unwrap();
    let tris = &e.gpu_scene.data.tris;
    let inputs: Vec<_> = tris
        .iter()
        .enumerate()
        .filter(|(t, _)| c.object_instance[c.tri_object[*t] as usize] != NO_INSTANCE)
        .filter_map(|(_, t)| {
            let n = (t[1] - t[0]).cross(t[2] - t[0]).try_normalize()?;
            let centre = (t[0] + t[1] + t[2]) / 3.0;
            Some(((centre + n * 0.02).to_array(), (-n).to_array()))
        })
        .collect();
    let lookups = |e: &Engine| {
        let out = query(e, QueryMode::CacheRay, &inputs);
        let hits = out
            .iter()
            .filter(|o| o[0][1] > 0.5 && o[0][2] < 0.5)
            .count();
        let empty = out
            .iter()
            .filter(|o| o[0][1] > 0.5 && o[0][2] < 0.5 && o[0][3] <= 1e-4)
            .count();
        (hits, empty)
    };
    let ((hits, empty), (fresh_hits, fresh_empty)) = (lookups(&e), lookups(&fresh));
    eprintln!(
        "rays at the moved objects ({}): played {empty} of {hits} front hits without a cache answer, fresh {fresh_empty} of {fresh_hits}",
        inputs.len()
    );
    assert!(hits > inputs.len() / 2, "{hits} of {} hit", inputs.len());
    assert!(
        empty <= fresh_empty + hits / 100,
        "moved cards miss their surfaces: {empty} against {fresh_empty}"
    );
    // The voxel lighting around the moved objects: its visibility is traced again with the
    // bricks their motion rebuilt, so their new places light SDF hits as in a fresh build.
    let voxel_lit = |e: &Engine| {
        let out = query(e, QueryMode::VoxelRay, &inputs);
        out.iter()
            .filter(|o| o[0][1] > 0.5 && o[0][2] < 0.5 && o[0][3] > 0.0)
            .count()
    };
    let (played, fresh_lit) = (voxel_lit(&e), voxel_lit(&fresh));
    eprintln!(
        "rays at the moved objects: the voxel lighting answers {played} of {hits} front hits played, {fresh_lit} of {fresh_hits} fresh"
    );
    assert!(
        played + hits / 100 >= fresh_lit,
        "moved objects' voxels not refreshed: {played} against {fresh_lit}"
    );
}

/// The same cosine rays from the surfaces the camera sees (Cornell, 80², 2 rays each), traced
/// through the distance field and through the BVH and shaded from the same converged surface
/// cache (`CacheRayBvh`): what global-SDF tracing itself changes in the light a gather ray brings
/// back. The expand (half a voxel diagonal, the seed's guard against thin-wall leaks) stops rays
/// that graze a wall or pass a rim within it: they bring back the wall's light instead of what
/// lies beyond. Rays the BVH sends out of the box's open side (black) come back lit, and rays
/// from the ceiling meet the lit upper walls early. Measured 2026-11-27: +22.1% per ray at 64³
/// (the box in 0.6-unit voxels), +7.7% at the default 128³; the SDF's over-occluded direct light
/// (`cache_direct_light_matches_reference`) pulls the other way. Asserted: the excess shrinks with the
/// resolution and stays under 12% at the default.
#[test]
fn sdf_hits_against_exact_hits() {
    let mut excess = Vec::new();
    for res in [64i64, 128] {
        let mut t = toml::toml! { tracing = "sdf" atlas_size = 256 indirect_texels_per_frame = 4194304 direct_texels_per_frame = 4194304 };
        t.insert("clipmap_resolution".into(), res.into());
        let mut e = engine("lumen", small(t), builtin::cornell(), [80, 80], 1);
        frames(&mut e, 16);
        let surfaces = visible_surfaces(&e);
        // Directions are hashed from the query's index: the second copy draws new ones.
        let inputs: Vec<_> = surfaces.iter().chain(&surfaces).cloned().collect();
        let sdf = query(&e, QueryMode::CacheRay, &inputs);
        let bvh = query(&e, QueryMode::CacheRayBvh, &inputs);
        // Per region of the surface the ray starts on: (SDF sum, BVH sum, rays).
        let names = ["ceiling", "floor and box tops", "walls and box sides"];
        let mut sums = [[0.0f64; 3]; 3];
        let (mut escaped, mut escaped_light, mut total) = (0usize, 0.0f64, 0.0f64);
        for ((input, s), b) in inputs.iter().zip(&sdf).zip(&bvh) {
            let region = match input.1[1] {
                y if y < -0.9 => 0,
                y if y > 0.9 => 1,
                _ => 2,
            };
            sums[region][0] += s[1][0] as f64;
            sums[region][1] += b[1][0] as f64;
            sums[region][2] += 1.0;
            total += b[1][0] as f64;
            if b[0][1] < 0.5 {
                escaped += 1;
                escaped_light += s[1][0] as f64;
            }
        }
        for (name, [a, b, n]) in names.iter().zip(sums) {
            eprintln!(
                "{res}³: rays from the {name} ({n}): SDF {:.5}, BVH {:.5} per ray ({:+.1}%)",
                a / n,
                b / n,
                100.0 * (a / b - 1.0)
            );
        }
        let (a, b) = sums
            .iter()
            .fold((0.0, 0.0), |(x, y), s| (x + s[0], y + s[1]));
        let ratio = a / b - 1.0;
        eprintln!(
            "{res}³: SDF rays bring back {:+.1}% of the BVH's light; of {escaped} rays that leave the box (BVH), the SDF lights some with {:.1}% of the BVH total",
            100.0 * ratio,
            100.0 * escaped_light / total
        );
        assert!(ratio.is_finite(), "{res}: {ratio}");
        excess.push(ratio);
    }
    assert!(
        excess[1].abs() < excess[0].abs(),
        "SDF error does not shrink with resolution: {excess:?}"
    );
    assert!(excess[1].abs() < 0.12, "128³: {:+.3}", excess[1]);
}
