"""Error against GPU time for two techniques on the Cornell box, plotted with matplotlib.

A notebook-style script: one session, one cached reference, one run per technique whose error
is read after 1, 2, 4 ... frames, relMSE against GPU time on log-log axes.

    python examples/error_vs_time.py --size 64 --frames 16 --out out/python-examples
"""

import argparse
import os

import matplotlib

matplotlib.use("Agg")  # headless: CI and machines without a display
import matplotlib.pyplot as plt  # noqa: E402

import gilab  # noqa: E402

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--preset", default="presets/cornell.toml")
parser.add_argument("--size", type=int, default=64)
parser.add_argument("--frames", type=int, default=16, help="most frames per technique")
parser.add_argument("--reference-spp", type=int, default=256)
parser.add_argument("--techniques", nargs=2, default=["reference", "restir"])
parser.add_argument("--out", default="out/python-examples")
args = parser.parse_args()
os.makedirs(args.out, exist_ok=True)

# %% One GPU context and the scene, kept for every render below.
session = gilab.Session(args.preset, size=args.size)
print(session, session.adapter["name"])
reference = session.reference(spp=args.reference_spp)

# %% Each technique on one engine (a Run), the error read after 1, 2, 4 ... frames against the
# GPU time spent so far.
curves, last = {}, {}
for technique in args.techniques:
    run = session.start(technique)
    points = []
    while run.frames < args.frames:
        frame = run.step(max(1, run.frames))  # doubles the frames so far
        points.append((frame.meta["gpu_ms_total"], gilab.metrics.relmse(frame.image, reference)))
    curves[technique], last[technique] = points, frame
    print(technique, " ".join(f"{ms:.1f} ms: {err:.4f}" for ms, err in points))

# %% The plot: error against GPU time, and the last image of each technique beside it.
fig, axes = plt.subplots(1, 1 + len(curves), figsize=(4 * (1 + len(curves)), 4))
for technique, points in curves.items():
    ms, err = zip(*points)
    axes[0].loglog(ms, err, marker="o", label=technique)
axes[0].set_xlabel("GPU time (ms)")
axes[0].set_ylabel("relMSE")
axes[0].legend()
axes[0].set_title(f"{session.scene_name}, {args.size}x{args.size}")
for ax, (technique, frame) in zip(axes[1:], last.items()):
    ax.imshow(gilab.tonemap(frame.image))
    ax.set_title(f"{technique}, {frame.frames} frames")
    ax.axis("off")
fig.tight_layout()
path = os.path.join(args.out, "error_vs_time.png")
fig.savefig(path, dpi=100)
session.close()
print(f"plot: {path}")
