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
