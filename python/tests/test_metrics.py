"""gilab.metrics gives `gilab compare`'s numbers; tonemap gives shot's PNG pixels."""

from __future__ import annotations

import re

import numpy as np
import pytest

import gilab


def test_metrics_equal_compare(session, run_cli, tmp_path):
    image = session.render("restir", frames=2)
    reference = session.render("reference", frames=8, seed=11)
    a, b = tmp_path / "a.exr", tmp_path / "b.exr"
    image.save(a)
    reference.save(b)
    out = run_cli("compare", str(a), str(b))
    found = dict(re.findall(r"(MSE|relMSE|SMAPE|FLIP) (\S+)", out))
    ours = {
        "MSE": gilab.metrics.mse(image.image, reference.image),
        "relMSE": gilab.metrics.relmse(image.image, reference.image),
        "SMAPE": gilab.metrics.smape(image.image, reference.image),
        "FLIP": gilab.metrics.flip(image.image, reference.image),
    }
    # The CLI prints {:.6e}: our numbers rounded to the same 7 digits are its numbers.
    assert {k: float(f"{v:.6e}") for k, v in ours.items()} == {
        k: float(v) for k, v in found.items()
    }
    assert all(v > 0 for v in ours.values())
    # Paths work too, and compare() returns all four.
    both = gilab.metrics.compare(a, b)
    assert both["relmse"] == ours["relMSE"] and both["flip"] == ours["FLIP"]


def test_metric_definitions():
    rng = np.random.default_rng(3)
    x = rng.random((8, 4, 3), dtype=np.float32)
    y = rng.random((8, 4, 3), dtype=np.float32)
    xd, yd = x.astype(np.float64), y.astype(np.float64)
    assert gilab.metrics.mse(x, y) == pytest.approx(np.mean((xd - yd) ** 2), rel=1e-12)
    assert gilab.metrics.relmse(x, y) == pytest.approx(
        np.mean((xd - yd) ** 2 / (yd**2 + 0.01)), rel=1e-12
    )
    assert gilab.metrics.smape(x, y) == pytest.approx(
        np.mean(np.abs(xd - yd) / (np.abs(xd) + np.abs(yd) + 0.01)), rel=1e-12
    )
    assert gilab.metrics.flip(x, x) == 0.0


def test_tonemap_matches_shot_png(session, run_cli, tmp_path):
    # `gilab shot` writes each technique's linear EXR and the PNG of the preset's tonemap
    # (cornell: aces, exposure 0): gilab.tonemap of the EXR is that PNG, pixel for pixel.
    from PIL import Image as PILImage

    run_cli(
        "shot", "presets/cornell.toml", "--technique", "reference", "--size", "32x32",
        "--spp", "2", "--out", str(tmp_path),
    )
    exrs = sorted(tmp_path.rglob("*.exr"))
    assert exrs, f"shot wrote no EXR under {tmp_path}"
    for exr in exrs:
        png = exr.with_suffix(".png")
        shot_png = np.asarray(PILImage.open(png).convert("RGB"))
        ours = gilab.tonemap(gilab.read_exr(exr), operator="aces", exposure=0.0)
        assert ours.shape == shot_png.shape
        assert np.array_equal(ours, shot_png), (
            f"{png.name}: {int((ours != shot_png).any(axis=2).sum())} pixels differ, "
            f"largest difference {int(np.abs(ours.astype(int) - shot_png.astype(int)).max())}"
        )
    # Negative control: another exposure is not shot's PNG.
    assert not np.array_equal(gilab.tonemap(gilab.read_exr(exrs[0]), exposure=1.0), shot_png)

    frame = session.render("reference", frames=2)
    ldr = gilab.tonemap(frame.image, operator="aces")
    assert ldr.dtype == np.uint8 and ldr.shape == frame.image.shape
    assert ldr.max() > 0
    # Exposure brightens; each operator is a different curve.
    assert gilab.tonemap(frame.image, exposure=2.0).astype(int).sum() > ldr.astype(int).sum()
    assert not np.array_equal(gilab.tonemap(frame.image, operator="reinhard"), ldr)
    with pytest.raises(ValueError, match="operator"):
        gilab.tonemap(frame.image, operator="nope")
