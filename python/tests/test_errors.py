"""Bad input raises Python exceptions carrying the library's message."""

from __future__ import annotations

import numpy as np
import pytest

import gilab


def test_unknown_technique(session):
    with pytest.raises(ValueError, match=r"unknown technique 'nope' \(available: reference, restir"):
        session.render("nope")
    with pytest.raises(ValueError, match="unknown technique"):
        gilab.params("nope")


def test_parameter_out_of_range(session):
    with pytest.raises(ValueError, match=r"'max_depth' must be an integer in 0..=1024, got 5000"):
        session.render("reference", params={"max_depth": 5000})
    with pytest.raises(ValueError, match="reference has no parameter .no_such_knob. \\(known: samples_per_frame"):
        session.render("reference", params={"no_such_knob": 1})
    with pytest.raises(ValueError, match="frames"):
        session.render("reference", frames=0)


def test_missing_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="cannot read preset .*missing.toml"):
        gilab.Session(tmp_path / "missing.toml")
    with pytest.raises(FileNotFoundError, match="missing.exr"):
        gilab.read_exr(tmp_path / "missing.exr")
    with pytest.raises(FileNotFoundError, match="missing.exr"):
        gilab.metrics.mse(tmp_path / "missing.exr", np.zeros((2, 2, 3), np.float32))
    with pytest.raises(FileNotFoundError):
        gilab.converge(tmp_path / "missing.toml", out=tmp_path / "out")


def test_bad_preset_values(tmp_path):
    with pytest.raises(ValueError, match="invalid size"):
        gilab.Session(size=(0, 4))
    with pytest.raises(ValueError, match="unknown built-in scene 'nope'"):
        gilab.Session(scene="nope", size=8)
    bad = tmp_path / "bad.toml"
    bad.write_text("[render]\nsize = [8, 8]\nnot_a_key = 1\n")
    with pytest.raises(ValueError, match="bad.toml:3:1: unknown field"):
        gilab.Session(bad)
    with pytest.raises(ValueError, match="backend"):
        gilab.Session(size=8, backend="metal2000")


def test_image_shapes_and_camera(session):
    with pytest.raises(ValueError, match=r"shape \(height, width, 3\)"):
        gilab.metrics.mse(np.zeros((4, 4)), np.zeros((4, 4)))
    with pytest.raises(ValueError, match="image sizes differ"):
        gilab.metrics.mse(np.zeros((4, 4, 3)), np.zeros((2, 4, 3)))
    cam = session.camera
    with pytest.raises(ValueError, match="fov"):
        session.camera = gilab.Camera(cam.position, cam.target, cam.up, 0.0)
    with pytest.raises(ValueError, match="target must differ"):
        session.camera = gilab.Camera(cam.position, cam.position, cam.up, cam.fov)
    assert session.camera == cam


def test_closed_session():
    s = gilab.Session(size=8)
    s.close()
    assert s.closed
    with pytest.raises(gilab.GilabError, match="closed"):
        s.render("reference")
    with pytest.raises(gilab.GilabError, match="closed"):
        s.camera
    assert repr(s).endswith("closed>")
