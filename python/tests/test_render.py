"""render() gives gilab shot's pixels; the Frame carries what shot's JSON records."""

from __future__ import annotations

import numpy as np
import pytest

import gilab

from conftest import SIZE


@pytest.mark.parametrize(
    "technique, frames, seed",
    [("reference", 3, 7), ("restir", 2, 5)],
)
def test_render_equals_shot_bit_identical(session, run_cli, tmp_path, technique, frames, seed):
    frame = session.render(technique, frames=frames, seed=seed)
    specs = {p["name"]: p for p in session.params(technique)}
    spf = specs["samples_per_frame"]["default"] if "samples_per_frame" in specs else 1
    spp = int(frames * spf)
    run_cli(
        "shot", "presets/cornell.toml", "--technique", technique, "--size",
        f"{SIZE[0]}x{SIZE[1]}", "--seed", str(seed), "--spp", str(spp), "--out", str(tmp_path),
    )
    cli_exr = tmp_path / "cornell" / f"{technique}.exr"
    py_exr = tmp_path / "python.exr"
    frame.save(py_exr)
    assert py_exr.read_bytes() == cli_exr.read_bytes()
    assert np.array_equal(gilab.read_exr(cli_exr), frame.image)
    assert frame.samples == spp and frame.frames == frames


def test_frame_contents(session):
    frame = session.render("reference", frames=4, seed=1)
    h, w = SIZE[1], SIZE[0]
    assert frame.image.shape == (h, w, 3) and frame.image.dtype == np.float32
    assert frame.variance.shape == (h, w, 3) and frame.variance.dtype == np.float32
    assert np.isfinite(frame.image).all() and frame.image.mean() > 0
    # Four samples per pixel: the sample variance is defined and non-negative somewhere positive.
    assert (frame.variance >= 0).all() and frame.variance.max() > 0
    assert frame.rays["camera"] == 4 * w * h
    assert frame.timings and all(ms >= 0 for ms in frame.timings.values())
    assert frame.clock_check is None
    assert repr(frame).startswith(f"<gilab.Frame reference {w}x{h}, 4 frames, 4 spp,")


def test_debug_views_and_denoise(session):
    frame = session.render("restir", frames=2, denoise=True)
    assert frame.debug_views, "ReSTIR has debug views"
    view = frame.debug(frame.debug_views[0])
    assert view.shape == (SIZE[1], SIZE[0]) and np.isfinite(view).all()
    assert frame.meta["passes"] and any("denoise" in p for p in frame.timings)
    with pytest.raises(ValueError, match="no debug view 'nope'"):
        frame.debug("nope")


def test_clock_check(session):
    frame = session.render("reference", frames=1, clock_check=True)
    check = frame.clock_check
    assert check["kernel_ms_before"] > 0 and check["kernel_ms_after"] > 0
    assert check["timing"] in ("Timestamps", "Wall", "WallTimestampsImplausible")
    assert isinstance(check["flagged"], bool)


def test_params_and_techniques(session):
    ids = [t["id"] for t in session.techniques()]
    assert ids[0] == "reference" and "restir" in ids
    specs = {p["name"]: p for p in session.params("reference")}
    assert specs["max_depth"]["kind"] == "int" and specs["max_depth"]["max"] >= 1
    assert specs["max_depth"]["doc"]
    # A parameter changes the image: one bounce is darker than unbounded paths.
    full = session.render("reference", frames=4).image.mean()
    direct = session.render("reference", frames=4, params={"max_depth": 1}).image.mean()
    assert direct < full


def test_camera_get_set(session):
    cam = session.camera
    before = session.render("reference", frames=1).image
    try:
        moved = gilab.Camera(cam.position, cam.target, cam.up, cam.fov * 0.5)
        session.camera = moved
        assert session.camera.fov == pytest.approx(cam.fov * 0.5)
        after = session.render("reference", frames=1).image
        assert not np.array_equal(before, after)
    finally:
        session.camera = cam
    assert np.array_equal(session.render("reference", frames=1).image, before)


def test_scene_edits():
    with gilab.Session("presets/cornell.toml", size=(16, 16)) as s:
        lit = s.render("reference", frames=2).image.mean()
        # The Cornell box's ceiling light is the emissive material "light": off leaves black.
        s.edit_material("light", emissive=[0, 0, 0])
        assert s.events and s.events[0]["material"] == "light"
        dark = s.render("reference", frames=2).image.mean()
        assert dark < 0.01 * lit
        with pytest.raises(ValueError, match="no material 'nope'"):
            s.edit_material("nope", emissive=[1, 1, 1])
        assert len(s.events) == 1, "a rejected edit leaves the session as it was"
    with gilab.Session(size=(16, 16)) as s:
        base = s.render("reference", frames=2).image.mean()
        # The built-in Cornell box's back-wall lamp (scene.params.lamp) adds light.
        s.set_scene_param("lamp", 50.0)
        assert s.preset["scene"]["params"]["lamp"] == 50.0
        assert s.render("reference", frames=2).image.mean() > base
        with pytest.raises(ValueError, match="no_such_param"):
            s.set_scene_param("no_such_param", 1)


def test_render_entry_equals_shot_of_the_preset(run_cli, tmp_path):
    """A preset's entry (its parameters, label) as `gilab shot PRESET` renders it."""
    with gilab.Session("presets/cornell.toml", size=16, overrides={"render.spp": 3}) as s:
        assert [e.get("label", e["name"]) for e in s.entries][:2] == ["reference", "restir"]
        frame = s.render_entry("reference-2-bounces")
        with pytest.raises(ValueError, match="no technique entry 'nope'"):
            s.render_entry("nope")
    run_cli("shot", "presets/cornell.toml", "--size", "16", "--spp", "3", "--out", str(tmp_path))
    cli = gilab.read_exr(tmp_path / "cornell" / "reference-2-bounces.exr")
    assert frame.frames == 3 and np.array_equal(frame.image, cli)


def test_run_steps_equal_one_render(session):
    """Frames on a kept engine accumulate as one render's: step(2) + step(1) = render(3)."""
    run = session.start("restir", seed=4)
    run.step(2)
    stepped = run.step(1)
    assert run.frames == 3 and stepped.frames == 3
    assert np.array_equal(stepped.image, session.render("restir", frames=3, seed=4).image)
    run.reset()
    assert run.frames == 0
    with pytest.raises(ValueError, match="reference has no parameter"):
        session.start("reference", params={"nope": 1})


def test_run_edit_mid_run(session):
    """A light switched off mid-run (an experiment's event): the next frames go dark while
    the run's counters carry on; the session's own scene is not edited."""
    run = session.start("reference")
    lit = run.step(2).image.mean()
    run.edit_material("light", emissive=[0, 0, 0])
    dark = run.step(2)
    assert dark.frames == 4 and dark.image.mean() < 0.01 * lit
    assert session.events == []
    cam = run.camera
    run.camera = gilab.Camera(cam.position, cam.target, cam.up, cam.fov * 0.8)
    assert run.camera.fov == pytest.approx(cam.fov * 0.8)
    with pytest.raises(ValueError, match="light 99 does not exist"):
        run.edit_light(99, intensity=[0, 0, 0])
