"""Session.reference() is `gilab reference`: the same cache key, file and pixels."""

from __future__ import annotations

import re

import numpy as np

import gilab


def test_reference_cached_as_cli(session, run_cli, tmp_path):
    cache = tmp_path / "cache"
    out = run_cli(
        "reference", "presets/cornell.toml", "--size", "32", "--set", "render.reference_spp=16",
        "--cache", str(cache),
    )
    cli_path = re.findall(r"^reference: (\S+\.exr)$", out, re.M)[-1]
    assert session.reference_path(spp=16, cache=cache) == cli_path
    cli_bytes = open(cli_path, "rb").read()
    # Cached: read back, not rendered again (the file stays as the CLI wrote it).
    image = session.reference(spp=16, cache=cache, progress=False)
    assert np.array_equal(image, gilab.read_exr(cli_path))
    # Rendered by Python into an empty cache: the same bytes as the CLI's.
    fresh = tmp_path / "fresh"
    again = session.reference(spp=16, cache=fresh, progress=False)
    assert open(session.reference_path(spp=16, cache=fresh), "rb").read() == cli_bytes
    assert np.array_equal(again, image)


def test_edited_scene_has_its_own_reference(tmp_path):
    with gilab.Session("presets/cornell.toml", size=16) as s:
        plain = s.reference_path(spp=4, cache=tmp_path)
        s.edit_material("light", emissive=[0, 0, 0])
        edited = s.reference_path(spp=4, cache=tmp_path)
        assert edited != plain
        assert s.reference(spp=4, cache=tmp_path, progress=False).max() < 1e-3
