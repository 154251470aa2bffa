//! The command line as a user meets it: exit codes, one-line errors, files written.

use std::path::PathBuf;
use std::process::Command;

fn gilab(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_gilab"))
        .args(args)
        .env("RUST_BACKTRACE", "1")
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into(),
        String::from_utf8_lossy(&out.stderr).into(),
    )
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("gilab-cli-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn assert_clean_failure(code: i32, stderr: &str, needle: &str) {
    assert_ne!(code, 0);
    assert!(
        !stderr.contains("panicked") && !stderr.contains("stack backtrace"),
        "{stderr}"
    );
    let lines: Vec<&str> = stderr.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(lines.len(), 1, "{stderr}");
    assert!(lines[0].contains(needle), "{stderr}");
}

#[test]
fn bad_inputs_fail_with_one_line_errors() {
    let d = tmp("bad");
    let glb = std::fs::read("scenes/box-room/box-room.glb").unwrap();
    let truncated = d.join("truncated.glb");
    std::fs::write(&truncated, &glb[..100]).unwrap();
    let (code, _, err) = gilab(&[
        "shot",
        "--scene",
        truncated.to_str().unwrap(),
        "--size",
        "8",
        "--spp",
        "1",
        "--out",
        d.to_str().unwrap(),
    ]);
    assert_clean_failure(code, &err, "truncated.glb");

    let preset = d.join("typo.toml");
    std::fs::write(
        &preset,
        "[scene]\nsource = \"cornell\"\n[render]\nszie = [8, 8]\n",
    )
    .unwrap();
    let (code, _, err) = gilab(&["shot", preset.to_str().unwrap()]);
    assert_clean_failure(code, &err, &format!("{}:4:1:", preset.display()));

    let (code, _, err) = gilab(&["shot", "--technique", "nope", "--size", "8"]);
    assert_clean_failure(code, &err, "unknown technique 'nope'");
    let (code, _, err) = gilab(&["compare", "missing-a.exr", "missing-b.exr"]);
    assert_clean_failure(code, &err, "missing-a.exr");
}

fn copy_dir(from: &std::path::Path, to: &std::path::Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let target = to.join(entry.file_name());
        if entry.file_type().unwrap().is_dir() {
            copy_dir(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), &target).unwrap();
        }
    }
}

/// A shader edited under `GILAB_SHADERS` so that it compiles but no longer fits the engine's
/// buffers (the frame uniforms grown by 1 KiB) fails validation at its dispatch, and wgpu drops
/// the submission. The error must say why, not only that the device poll found no such
/// submission (what it said until 2026-11-27, while the reason went to the log).
#[test]
fn a_shader_that_no_longer_fits_names_the_validation_error() {
    let d = tmp("shader-fit");
    let shaders = d.join("shaders");
    copy_dir(std::path::Path::new("shaders"), &shaders);
    let frame = shaders.join("common/frame.wgsl");
    let text = std::fs::read_to_string(&frame).unwrap();
    let grown = text.replacen(
        "    pad: vec2<u32>,\n}",
        "    pad: vec2<u32>,\n    extra: array<vec4<f32>, 64>,\n}",
        1,
    );
    assert_ne!(
        grown, text,
        "the frame uniforms' layout changed: update this test"
    );
    std::fs::write(&frame, grown).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_gilab"))
        .args([
            "shot",
            "--technique",
            "reference",
            "--size",
            "16",
            "--spp",
            "1",
            "--out",
        ])
        .arg(d.join("out"))
        .env("GILAB_SHADERS", &shaders)
        .env("RUST_LOG", "off")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_clean_failure(
        out.status.code().unwrap_or(-1),
        &err,
        "GPU error: Validation Error",
    );
    assert!(err.contains("where the shader expects"), "{err}");
}

#[test]
fn shot_writes_png_exr_json_and_compare_reads_them() {
    let d = tmp("shot");
    let out = d.to_str().unwrap();
    let (code, stdout, err) = gilab(&[
        "shot",
        "presets/cornell.toml",
        "--size",
        "16",
        "--spp",
        "4",
        "--out",
        out,
        "--verbose",
    ]);
    assert_eq!(code, 0, "{stdout}\n{err}");
    assert!(stdout.contains("adapter:"), "{stdout}");
    assert!(stdout.contains("emissive triangles 2"), "{stdout}");
    let base = d.join("cornell");
    for ext in ["png", "exr", "json"] {
        assert!(
            base.join(format!("reference.{ext}")).is_file(),
            "reference.{ext} missing"
        );
    }
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(base.join("reference.json")).unwrap())
            .unwrap();
    assert_eq!(meta["spp"], 4);
    assert_eq!(meta["rays_by_kind"]["camera"], 16 * 16 * 4);
    assert_eq!(meta["non_finite_pixels"], 0);
    assert_eq!(meta["scene_features"]["emissive_triangle_count"], 2);
    assert!(meta["adapter"]["name"].as_str().is_some());

    let exr = base.join("reference.exr");
    let (code, stdout, _) = gilab(&["compare", exr.to_str().unwrap(), exr.to_str().unwrap()]);
    assert_eq!(code, 0);
    assert!(
        stdout.starts_with("MSE 0.000000e0  relMSE 0.000000e0"),
        "{stdout}"
    );

    // The reference cache: a second call finds the file it wrote.
    let cache = d.join("cache");
    let args = [
        "reference",
        "presets/cornell.toml",
        "--spp",
        "2",
        "--size",
        "8",
        "--cache",
        cache.to_str().unwrap(),
    ];
    let (code, first, err) = gilab(&args);
    assert_eq!(code, 0, "{err}");
    let (_, second, _) = gilab(&args);
    assert!(second.contains("cached"), "{first}\n{second}");
}
