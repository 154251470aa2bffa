"""Resources and cost: RSS stays flat over 100 renders in one session; the time of a small
render from Python against the CLI's (printed; run pytest with -s to see the numbers)."""

from __future__ import annotations

import gc
import time

import numpy as np

import gilab

# Allowed RSS growth over 100 renders after a warm-up. A leak of one engine per render (its
# buffers and per-engine state, several MB at any size) would exceed it within 100 renders.
RSS_GROWTH_LIMIT_MB = 24.0


def rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    raise RuntimeError("no VmRSS in /proc/self/status")


def test_100_renders_do_not_grow_rss():
    with gilab.Session("presets/cornell.toml", size=(16, 16)) as s:
        for _ in range(10):  # warm-up: pipelines compiled and cached, allocator settled
            s.render("reference", frames=1)
        gc.collect()
        before = rss_mb()
        means = []
        for i in range(100):
            frame = s.render("reference", frames=1, seed=i)
            means.append(float(frame.image.mean()))
            del frame
        gc.collect()
        after = rss_mb()
    growth = after - before
    print(f"\nRSS over 100 renders (16x16 reference, 1 frame): {before:.1f} -> {after:.1f} MB "
          f"({growth:+.1f} MB)")
    assert len(set(means)) > 50, "the renders used their seeds"
    assert growth < RSS_GROWTH_LIMIT_MB


def test_overhead_against_cli(run_cli, tmp_path):
    args = ("shot", "presets/cornell.toml", "--technique", "reference", "--size", "32",
            "--seed", "2", "--spp", "4", "--out", str(tmp_path))
    run_cli(*args)  # warm the driver's on-disk state, if any, for both sides alike
    start = time.perf_counter()
    run_cli(*args)
    cli_s = time.perf_counter() - start

    start = time.perf_counter()
    with gilab.Session("presets/cornell.toml", size=32) as s:
        cold = s.render("reference", frames=4, seed=2)
        cold_s = time.perf_counter() - start
        warm = []
        for _ in range(5):
            t = time.perf_counter()
            frame = s.render("reference", frames=4, seed=2)
            warm.append(time.perf_counter() - t)
        gpu_s = frame.meta["wall_ms_total"] / 1e3
    warm_s = float(np.median(warm))
    print(f"\n32x32 reference, 4 frames: CLI `gilab shot` {cli_s * 1e3:.0f} ms (process, device, "
          f"scene, pipelines, render, files); Python new Session + render {cold_s * 1e3:.0f} ms; "
          f"render in an open Session {warm_s * 1e3:.1f} ms (frames' wall time {gpu_s * 1e3:.1f} "
          f"ms, overhead {1e3 * (warm_s - gpu_s):.1f} ms)")
    assert np.array_equal(frame.image, cold.image)
    # An open session skips what every CLI call pays (process, device, scene upload).
    assert warm_s < cli_s


def test_closed_sessions_release_the_device():
    """A closed session drops its device and scene buffers: opening and closing sessions does
    not pile up memory."""

    def open_render_close():
        s = gilab.Session("presets/cornell.toml", size=16)
        s.render("reference", frames=1)
        s.close()

    for _ in range(3):
        open_render_close()
    gc.collect()
    before = rss_mb()
    for _ in range(10):
        open_render_close()
    gc.collect()
    growth = rss_mb() - before
    print(f"\nRSS over 10 sessions opened, rendered and closed: {growth:+.1f} MB")
    assert growth < RSS_GROWTH_LIMIT_MB
